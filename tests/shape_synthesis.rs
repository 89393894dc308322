//! Shape synthesis through the binary (`synth --height H --displace AMOUNT`, paper 000 §6):
//! displaced.obj is the limit surface at texel resolution moved along the limit normal by
//! AMOUNT x (height − 0.5). Checked vertex by vertex against the limit surface (subdiv,
//! itself checked against OpenSubdiv) and the height texels of facemaps.exr.

use glam::DVec3;
use std::path::{Path, PathBuf};
use std::process::Command;
use subdiv::{ControlMesh, Surface};

const GRAVEL: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/fixtures/gravel.png");

/// A 4x4 grid of unit quads, bent so that normals vary.
fn bent_grid(dir: &Path) -> PathBuf {
    let mut obj = String::new();
    for y in 0..=4 {
        for x in 0..=4 {
            let z = 0.4 * ((x as f64) * 0.7).sin() * ((y as f64) * 0.5).cos();
            obj += &format!("v {x} {y} {z}\n");
        }
    }
    for y in 0..4 {
        for x in 0..4 {
            let i = y * 5 + x + 1;
            obj += &format!("f {} {} {} {}\n", i, i + 1, i + 6, i + 5);
        }
    }
    let mesh = dir.join("grid.obj");
    std::fs::write(&mesh, obj).unwrap();
    mesh
}

fn synth(mesh: &Path, out: &Path, extra: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_surfsynth"))
        .args(["synth", "--mesh"])
        .arg(mesh)
        .args(["--example", GRAVEL, "--resolution", "16", "--seed", "5"])
        .args(extra)
        .arg("--out")
        .arg(out)
        .output()
        .unwrap()
}

fn obj_vertices(path: &Path) -> Vec<DVec3> {
    std::fs::read_to_string(path)
        .unwrap()
        .lines()
        .filter_map(|l| l.strip_prefix("v "))
        .map(|l| {
            let c: Vec<f64> = l.split_whitespace().map(|x| x.parse().unwrap()).collect();
            DVec3::new(c[0], c[1], c[2])
        })
        .collect()
}

#[test]
fn displaced_obj_moves_limit_points_along_the_normal_by_height() {
    let dir = tempfile::tempdir().unwrap();
    let mesh = bent_grid(dir.path());
    let out = dir.path().join("out");
    let amount = 0.3;
    let o = synth(
        &mesh,
        &out,
        &["--height", GRAVEL, "--displace", &amount.to_string()],
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap();
    assert_eq!(report["displace"], amount);

    let verts = obj_vertices(&out.join("displaced.obj"));
    let maps = surfsynth::io::exr::read_face_maps(out.join("facemaps.exr")).unwrap();
    let height = maps.channel("height").unwrap();
    let n = maps.resolution;
    let surface = Surface::new(ControlMesh::load_obj(&mesh).unwrap());
    // All quads at N = 16: the level with 16 segments per domain side, one vertex per
    // texel corner.
    let lm = surface.limit_mesh(4);
    assert_eq!(verts.len(), lm.position.len());
    let mut checked = 0;
    let mut worst = 0.0f64;
    let mut sum_h = 0.0;
    for (k, v) in verts.iter().enumerate() {
        let d = *v - lm.position[k];
        let nrm = lm.normal[k];
        // Only along the normal, never more than amount / 2.
        assert!(
            d.cross(nrm).length() < 1e-5,
            "vertex {k}: tangential move {d}"
        );
        assert!(d.length() <= amount / 2.0 + 1e-5, "vertex {k}: moved {d}");
        // Inside a domain a vertex sits on a texel corner: the mean of the four texels.
        let b = lm.vertex_location[k];
        let loc = surface.base_to_domain(b.quad, b.s, b.t);
        let (x, y) = (loc.u * n as f64, loc.v * n as f64);
        let (xi, yi) = (x.round() as usize, y.round() as usize);
        if (x - xi as f64).abs() > 1e-9 || (y - yi as f64).abs() > 1e-9 {
            continue;
        }
        if xi == 0 || yi == 0 || xi >= n || yi >= n {
            continue;
        }
        let f = loc.domain.idx();
        let h = [(xi - 1, yi - 1), (xi, yi - 1), (xi - 1, yi), (xi, yi)]
            .iter()
            .map(|&(a, c)| height[maps.index(f, a, c)] as f64)
            .sum::<f64>()
            / 4.0;
        let expected = amount * (h - 0.5);
        worst = worst.max((d.dot(nrm) - expected).abs());
        sum_h += h;
        checked += 1;
    }
    assert!(checked > 16 * 15 * 15 / 2, "{checked} interior vertices");
    // f32 text coordinates on a surface of size ~4: ~1e-6.
    assert!(worst < 1e-5, "displacement off by {worst}");
    // The height channel is really there (gravel: not uniform).
    let mean = sum_h / checked as f64;
    assert!((0.2..0.8).contains(&mean), "mean height {mean}");
}

#[test]
fn displace_needs_a_height_channel_and_leaves_nothing_behind() {
    let dir = tempfile::tempdir().unwrap();
    let mesh = bent_grid(dir.path());
    let out = dir.path().join("out");
    let o = synth(&mesh, &out, &["--displace", "0.1"]);
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(err.trim().lines().count(), 1, "{err}");
    assert!(
        err.contains("--height") && err.contains("gravel.png"),
        "{err}"
    );
    assert!(!out.exists() || std::fs::read_dir(&out).unwrap().next().is_none());

    let o = synth(&mesh, &out, &["--height", GRAVEL, "--displace", "nan"]);
    assert!(!o.status.success());
}
