//! Ptex face records of a subdivision surface's face domains: which face lies across each
//! edge, and which of its edges that is, derived from the control mesh's half-edges.
//!
//! The domains are OpenSubdiv's Ptex faces ([`subdiv::Surface::domain`]): a control quad is
//! one face with (0,0) at its first vertex, so Ptex edge e of a quad is the control edge
//! from vertex e to vertex e+1. An n-gon (n ≠ 4) gives n sub-faces; sub-face c has (0,0) at
//! vertex c, u toward vertex c+1 and (1,1) at the face centre, so its edges are
//!
//! - 0 (v = 0): the half of control edge (c, c+1) at vertex c — an outer edge;
//! - 1 (u = 1): from that edge's midpoint to the centre — shared with sub-face c+1's edge 2;
//! - 2 (v = 1): from the centre to the midpoint of edge (c−1, c) — sub-face c−1's edge 1;
//! - 3 (u = 0): the half of control edge (c−1, c) at vertex c — an outer edge.
//!
//! Ptex's rules for a quad beside an n-gon (`Ptexture.h`, `PtexSeparableFilter`): the
//! sub-face records the quad and the quad's edge; the quad, whose one edge meets two
//! sub-faces, records the *first* of them met walking its edge counter-clockwise — the one
//! at the edge's start vertex (the filter reaches the other one through that sub-face's
//! edge 2), with that sub-face's edge 3. `ptxinfo -c` checks exactly these rules.

use super::format::{FaceInfo, Res};
use subdiv::{FaceId, Surface};

/// The face and edge across control half-edge `h`, seen from the half of `h` at its
/// `origin` end (`true`) or its destination end (`false`); quads see the whole edge and
/// pass `origin = true` (they record the sub-face at their edge's start).
fn across(surface: &Surface, h: u32, origin: bool) -> (i32, u8) {
    let mesh = &surface.control.mesh;
    let Some(t) = mesh.twin(h) else {
        return (-1, 0);
    };
    let g = mesh.face_of(t);
    let k = t - mesh.face_he(g);
    let first = surface.face_domain(g).0;
    let n = mesh.face_size(g) as u32;
    if n == 4 {
        return (first as i32, k as u8);
    }
    // The twin runs from G's vertex k (h's destination) to vertex k+1 (h's origin).
    if origin {
        // Near h's origin = G's vertex k+1: sub-face k+1, its edge 3.
        ((first + (k + 1) % n) as i32, 3)
    } else {
        // Near h's destination = G's vertex k: sub-face k, its edge 0.
        ((first + k) as i32, 0)
    }
}

/// The Ptex record of every face domain of `surface`, domain d with resolution `res(d)`.
pub fn face_infos(surface: &Surface, res: impl Fn(usize) -> Res) -> Vec<FaceInfo> {
    let mesh = &surface.control.mesh;
    let mut out = Vec::with_capacity(surface.num_domains());
    for f in 0..mesh.num_faces() {
        let face = FaceId::from_idx(f);
        let n = mesh.face_size(face) as u32;
        let h0 = mesh.face_he(face);
        let first = surface.face_domain(face).0;
        if n == 4 {
            let mut info = FaceInfo {
                res: res(first as usize),
                adj_faces: [-1; 4],
                adj_edges: [0; 4],
                subface: false,
            };
            for e in 0..4 {
                (info.adj_faces[e], info.adj_edges[e]) = across(surface, h0 + e as u32, true);
            }
            out.push(info);
        } else {
            for c in 0..n {
                let d = first + c;
                let (e0, e0_edge) = across(surface, h0 + c, true);
                let (e3, e3_edge) = across(surface, h0 + (c + n - 1) % n, false);
                out.push(FaceInfo {
                    res: res(d as usize),
                    adj_faces: [
                        e0,
                        (first + (c + 1) % n) as i32,
                        (first + (c + n - 1) % n) as i32,
                        e3,
                    ],
                    adj_edges: [e0_edge, 2, 1, e3_edge],
                    subface: true,
                });
            }
        }
    }
    debug_assert_eq!(out.len(), surface.num_domains());
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The rules `ptxinfo -c` checks: the neighbour across e points back across
    /// adj_edges[e], or (sub-face beside a quad) at this face's next neighbour.
    fn consistent(infos: &[FaceInfo]) {
        for (f, fi) in infos.iter().enumerate() {
            for e in 0..4 {
                let a = fi.adj_faces[e];
                if a < 0 {
                    continue;
                }
                let af = &infos[a as usize];
                let back = af.adj_faces[fi.adj_edges[e] as usize];
                let ok = back == f as i32
                    || (fi.subface && !af.subface && back == fi.adj_faces[(e + 1) % 4]);
                assert!(ok, "face {f} edge {e}: {fi:?} vs {af:?}");
            }
        }
    }

    #[test]
    fn quads_triangles_and_pentagons_follow_ptex_rules() {
        // A quad strip with a triangle and a pentagon attached, one open boundary.
        let s = crate::io::mixed_test_surface(|_, _| 0.0);
        let infos = face_infos(&s, |_| Res::square(3));
        assert_eq!(infos.len(), 1 + 1 + 3 + 5);
        consistent(&infos);
        // Quad 0's top edge (4 -> 3) meets the triangle's edge 0 (3 -> 4): the sub-face at
        // the edge's start vertex 4 is triangle sub-face 1 (domains 2, 3, 4), edge 3.
        assert_eq!((infos[0].adj_faces[2], infos[0].adj_edges[2]), (3, 3));
        // Triangle sub-face 0 (at vertex 3): edge 0 is the first half of 3 -> 4, beside
        // quad 0's edge 2; edge 3 is on the boundary (edge 6 -> 3).
        assert_eq!((infos[2].adj_faces[0], infos[2].adj_edges[0]), (0, 2));
        assert_eq!(infos[2].adj_faces[3], -1);
        // Interior edges of the n-gon go round its centre.
        assert_eq!(infos[2].adj_faces[1..3], [3, 4]);
        assert_eq!(infos[2].adj_edges[1..3], [2, 1]);
        // Quad 1's right edge (2 -> 5) is pentagon edge (5 -> 2): first sub-face at 2 is
        // the pentagon's sub-face 0 (domain 5), edge 3.
        assert_eq!((infos[1].adj_faces[1], infos[1].adj_edges[1]), (5, 3));
        // Quad 0 and quad 1 share edge 1 -> 4: quad 0's edge 1, quad 1's edge 3.
        assert_eq!((infos[0].adj_faces[1], infos[0].adj_edges[1]), (1, 3));
        assert!(infos[5].subface && !infos[0].subface);
    }
}
