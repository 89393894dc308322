//! File input and output: face-map EXR files ([`exr`]), atomic writes ([`atomic`]) through
//! a writer around the page cache ([`direct`]),
//! transactional output directories ([`txn`]) and clean-up on SIGINT / SIGTERM
//! ([`interrupt`]). Other writers (atlas, OBJ, the displaced OBJ of shape synthesis) live
//! beside them and go through [`atomic`] and [`txn`] too.

pub mod atlas;
pub mod atomic;
pub mod decimate;
pub mod direct;
pub mod displace;
pub mod export;
pub mod exr;
pub mod gltf;
pub mod interrupt;
pub mod materials;
pub mod names;
pub mod png;
pub mod ptex;
pub mod tangent;
pub mod txn;

/// A small mixed test mesh for the writers' tests: a strip of two quads with a triangle
/// and a pentagon attached (n-gon sub-faces, corners of every valence, one open
/// boundary), its control points at height `z(x, y)`.
#[cfg(test)]
pub(crate) fn mixed_test_surface(z: impl Fn(f64, f64) -> f64) -> subdiv::Surface {
    let p: Vec<glam::DVec3> = [
        (0.0, 0.0),
        (1.0, 0.0),
        (2.0, 0.0),
        (0.0, 1.0),
        (1.0, 1.0),
        (2.0, 1.0),
        (1.0, 2.0),
        (2.5, 0.5),
        (3.0, 1.5),
        (2.0, 2.0),
    ]
    .iter()
    .map(|&(x, y)| glam::DVec3::new(x, y, z(x, y)))
    .collect();
    let faces: [&[u32]; 4] = [&[0, 1, 4, 3], &[1, 2, 5, 4], &[3, 4, 6], &[2, 7, 8, 9, 5]];
    subdiv::Surface::new(subdiv::ControlMesh::from_faces(p, &faces).unwrap())
}
