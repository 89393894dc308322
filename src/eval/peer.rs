//! Inputs of the peer benchmark (`bench/peer.sh`, docs/benchmarks.md, "Peer"): BRIEF's flat
//! grid and square crops of the shared examples, written by `surfsynth bench grid` and
//! `surfsynth bench crop`, so that the script needs no Python or image tools.

use crate::error::{Error, Result};
use std::fmt::Write;
use std::path::Path;

/// The flat K x K grid of unit quads in the xy plane (z = 0), faces row by row from the
/// origin, each counter-clockwise seen from +z: face (i, j) has u along +x and v along +y,
/// so with `--orient +x` its tiles are crops of the example as stored (BRIEF's peer
/// comparison uses K = 16 at N = 32: a 512² texel grid).
pub fn grid_obj(k: usize) -> String {
    let mut s = format!("# surfsynth bench grid: {k}x{k} unit quads in the xy plane\n");
    for y in 0..=k {
        for x in 0..=k {
            let _ = writeln!(s, "v {x} {y} 0");
        }
    }
    let w = k + 1;
    for y in 0..k {
        for x in 0..k {
            let a = y * w + x + 1; // OBJ indices are 1-based
            let _ = writeln!(s, "f {} {} {} {}", a, a + 1, a + 1 + w, a + w);
        }
    }
    s
}

/// Writes the `size` x `size` crop of `input` whose top-left pixel is (x, y) to `output`
/// as PNG, pixel values, bit depth and channels unchanged (no colour conversion).
pub fn crop_image(input: &Path, output: &Path, x: u32, y: u32, size: u32) -> Result<()> {
    let img = image::open(input).map_err(|e| Error::file(input, format!("cannot read: {e}")))?;
    let (w, h) = (img.width(), img.height());
    if size == 0
        || x.checked_add(size).is_none_or(|r| r > w)
        || y.checked_add(size).is_none_or(|b| b > h)
    {
        return Err(Error::file(
            input,
            format!("is {w}x{h}: a {size}x{size} crop at ({x}, {y}) does not fit"),
        ));
    }
    img.crop_imm(x, y, size, size)
        .save_with_format(output, image::ImageFormat::Png)
        .map_err(|e| Error::file(output, format!("cannot write: {e}")))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_grid_is_controlmesh_grid() {
        // The same vertices and faces as the grid the tests use.
        let a = subdiv::ControlMesh::parse_obj(&grid_obj(3)).unwrap();
        let b = subdiv::ControlMesh::grid(3);
        assert_eq!(a.mesh.num_faces(), 9);
        assert_eq!(a.mesh.num_faces(), b.mesh.num_faces());
        let sa = subdiv::Surface::new(a);
        let sb = subdiv::Surface::new(b);
        let (mut ta, mut tb) = (vec![Default::default(); 16], vec![Default::default(); 16]);
        for d in 0..9 {
            sa.eval_texels(subdiv::DomainId::from_idx(d), 4, &mut ta);
            sb.eval_texels(subdiv::DomainId::from_idx(d), 4, &mut tb);
            for (x, y) in ta.iter().zip(&tb) {
                let (x, y): (&subdiv::LimitSample, &subdiv::LimitSample) = (x, y);
                assert!((x.p - y.p).length() < 1e-12);
            }
        }
    }
}
