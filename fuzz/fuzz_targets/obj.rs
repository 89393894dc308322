//! OBJ reader + surface: `ControlMesh::parse_obj` must return Ok or Err for any bytes, and
//! an accepted mesh must build a surface whose limit evaluates to finite values, with
//! normals that are unit or exactly zero (degenerate points). Same properties as
//! tests/fuzz_inputs.rs.
#![no_main]

use libfuzzer_sys::fuzz_target;
use subdiv::{ControlMesh, DomainId, Surface};

fuzz_target!(|data: &[u8]| {
    let text = String::from_utf8_lossy(data);
    let Ok(control) = ControlMesh::parse_obj(&text) else {
        return;
    };
    let big = control
        .mesh
        .positions
        .iter()
        .map(|p| p.abs().max_element())
        .fold(0.0f64, f64::max);
    assert!(big.is_finite(), "accepted a non-finite coordinate");
    // Keep each input cheap; coordinates near f64::MAX may overflow legitimately.
    if control.mesh.num_faces() > 4000 || big > 1e150 {
        return;
    }
    let surface = Surface::new(control);
    let domains = surface.num_domains();
    assert!(domains > 0);
    let params = [0.0, 1e-9, 0.25, 0.5, 0.999_999, 1.0];
    for d in (0..domains).step_by(domains.div_ceil(12)) {
        for &u in &params {
            for &v in &params {
                let s = surface.eval(DomainId(d as u32), u, v);
                assert!(
                    s.p.is_finite() && s.du.is_finite() && s.dv.is_finite() && s.n.is_finite(),
                    "domain {d} ({u}, {v}): {s:?}"
                );
                let len = s.n.length();
                assert!(len == 0.0 || (len - 1.0).abs() < 1e-6, "normal {:?}", s.n);
            }
        }
    }
});
