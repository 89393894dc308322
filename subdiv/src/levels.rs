//! Uniformly refined copies of the surface with exact limit positions and normals: the
//! "tessellated copy of the limit surface" that the orientation field is optimised on and
//! surface marching walks over. Where an infinitely sharp crease makes the normal of a
//! vertex two-sided, each face's own side is kept too ([`LimitMesh::corner_normal`]).

use crate::adjacency::BaseLocation;
use crate::ids::{BaseQuadId, FaceId, VertexId};
use crate::refine::refine;
use crate::surface::LimitSample;
use crate::surface::{from_child, quadrant, to_child, Surface};
use crate::topology::PolyMesh;
use glam::DVec3;
use rayon::prelude::*;
use std::collections::HashMap;

/// The base mesh refined to `level` (level 1 = the base quads themselves), with every vertex
/// moved to its exact limit position.
#[derive(Clone, Debug)]
pub struct LimitMesh {
    pub level: u32,
    /// Connectivity (its `positions` are the refined control points, not limit points).
    pub mesh: PolyMesh,
    /// Exact limit position of every vertex.
    pub position: Vec<DVec3>,
    /// Exact unit limit normal of every vertex.
    pub normal: Vec<DVec3>,
    /// Where every vertex is, as a base-quad point (one of possibly several).
    pub vertex_location: Vec<BaseLocation>,
    /// The face corner (4·face + corner) `position`, `normal` and `vertex_location` of
    /// every vertex were evaluated at (its first face in face order).
    pub vertex_corner: Vec<u32>,
    /// Whether a vertex's normal is not unique (it lies on an infinitely sharp crease or
    /// corner: one normal per side, [`PolyMesh::normal_is_unique`]); empty when no vertex
    /// is such.
    pub sided: Vec<bool>,
    /// At such vertices, the normal on each face's own side, by face corner 4·face + corner.
    sided_normal: HashMap<u32, DVec3>,
}

impl LimitMesh {
    /// Number of level faces per base quad: 4^(level-1).
    pub fn faces_per_base(&self) -> usize {
        1 << (2 * (self.level - 1))
    }

    /// The level face holding base point (s, t) of `b`, and the point's parameter in it.
    /// Children of face f are faces 4f..4f+3 at the next level (see [`crate::refine`]).
    pub fn locate(&self, b: BaseQuadId, s: f64, t: f64) -> (FaceId, f64, f64) {
        let (mut s, mut t) = (s.clamp(0.0, 1.0), t.clamp(0.0, 1.0));
        let mut f = b.0 as usize;
        for _ in 1..self.level {
            let c = quadrant(s, t);
            (s, t) = to_child(c, s, t);
            f = 4 * f + c;
        }
        (FaceId::from_idx(f), s, t)
    }

    /// Whether vertex `v` has one normal per side ([`Self::sided`]).
    #[inline]
    pub fn is_sided(&self, v: VertexId) -> bool {
        !self.sided.is_empty() && self.sided[v.idx()]
    }

    /// The limit normal at corner `c` of level face `f` on that face's side: `normal` of
    /// the corner's vertex unless its normal is not unique.
    #[inline]
    pub fn corner_normal(&self, f: FaceId, c: usize) -> DVec3 {
        let v = self.mesh.face_vertices(f)[c] as usize;
        if self.is_sided(VertexId(v as u32)) {
            self.sided_normal[&(4 * f.0 + c as u32)]
        } else {
            self.normal[v]
        }
    }

    /// The base-quad parameter of point (s, t) of level face `f`.
    pub fn to_base(&self, f: FaceId, s: f64, t: f64) -> BaseLocation {
        let (mut s, mut t) = (s, t);
        let mut f = f.idx();
        for _ in 1..self.level {
            let c = f % 4;
            (s, t) = from_child(c, s, t);
            f /= 4;
        }
        BaseLocation {
            quad: BaseQuadId::from_idx(f),
            s,
            t,
        }
    }
}

impl Surface {
    /// The surface refined to `level` >= 1 with exact limit positions and normals.
    pub fn limit_mesh(&self, level: u32) -> LimitMesh {
        assert!(level >= 1);
        let mut mesh = self.base.clone();
        for _ in 1..level {
            mesh = refine(&mesh);
        }
        let nv = mesh.num_vertices();
        let sided: Vec<bool> = if mesh.has_tags() {
            (0..nv)
                .map(|v| !mesh.normal_is_unique(VertexId::from_idx(v)))
                .collect()
        } else {
            Vec::new()
        };
        let sided = if sided.contains(&true) {
            sided
        } else {
            Vec::new()
        };
        let mut lm = LimitMesh {
            level,
            position: vec![DVec3::ZERO; nv],
            normal: vec![DVec3::ZERO; nv],
            vertex_location: vec![
                BaseLocation {
                    quad: BaseQuadId(0),
                    s: 0.0,
                    t: 0.0
                };
                nv
            ],
            vertex_corner: vec![0; nv],
            sided,
            sided_normal: HashMap::new(),
            mesh,
        };
        const CORNER: [(f64, f64); 4] = [(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0)];
        // Every vertex is evaluated at its first face corner in face order (found first,
        // in one pass), each on its own: in parallel, the same values as one loop (the
        // per-thread cache of deep levels gives the same bits as refining anew).
        let mut first = vec![u32::MAX; nv];
        for f in 0..lm.mesh.num_faces() {
            for (c, &v) in lm
                .mesh
                .face_vertices(FaceId::from_idx(f))
                .iter()
                .enumerate()
            {
                if first[v as usize] == u32::MAX {
                    first[v as usize] = 4 * f as u32 + c as u32;
                }
            }
        }
        let at = |lm: &LimitMesh, k: u32| {
            let (cs, ct) = CORNER[(k % 4) as usize];
            let loc = lm.to_base(FaceId(k / 4), cs, ct);
            (loc, self.eval_base(loc.quad, loc.s, loc.t))
        };
        let evaluated: Vec<Option<(BaseLocation, LimitSample)>> = {
            let lm = &lm;
            first
                .par_iter()
                .with_min_len(1024)
                .map(|&k| (k != u32::MAX).then(|| at(lm, k)))
                .collect()
        };
        for (v, e) in evaluated.into_iter().enumerate() {
            if let Some((loc, e)) = e {
                lm.position[v] = e.p;
                lm.normal[v] = e.n;
                lm.vertex_location[v] = loc;
                lm.vertex_corner[v] = first[v];
            }
        }
        // Every face corner's own normal where a vertex has one per side.
        if !lm.sided.is_empty() {
            for f in 0..lm.mesh.num_faces() {
                for c in 0..4 {
                    let v = lm.mesh.face_vertices(FaceId::from_idx(f))[c];
                    if lm.is_sided(VertexId(v)) {
                        let k = 4 * f as u32 + c as u32;
                        let n = at(&lm, k).1.n;
                        lm.sided_normal.insert(k, n);
                    }
                }
            }
        }
        lm
    }
}

#[cfg(test)]
mod tests {
    use crate::{ControlMesh, Surface};

    #[test]
    fn limit_mesh_vertices_lie_on_the_surface_and_locate_inverts() {
        let s = Surface::new(
            ControlMesh::load_obj(crate::test_data::opensubdiv_reference("catmark_pole8.obj"))
                .unwrap(),
        );
        let lm = s.limit_mesh(3);
        assert_eq!(lm.mesh.num_faces(), s.num_base_quads() * 16);
        for (v, loc) in lm.vertex_location.iter().enumerate() {
            let e = s.eval_base(loc.quad, loc.s, loc.t);
            assert!((e.p - lm.position[v]).length() < 1e-12);
            assert!(
                (lm.normal[v].length() - 1.0).abs() < 1e-9,
                "vertex {v} normal {}",
                lm.normal[v]
            );
        }
        let (f, a, b) = lm.locate(crate::BaseQuadId(5), 0.3, 0.8);
        let back = lm.to_base(f, a, b);
        assert_eq!(back.quad.0, 5);
        assert!((back.s - 0.3).abs() < 1e-14 && (back.t - 0.8).abs() < 1e-14);
    }
}
