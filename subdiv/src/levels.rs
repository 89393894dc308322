//! Uniformly refined copies of the surface with exact limit positions and normals: the
//! "tessellated copy of the limit surface" that the orientation field is optimised on and
//! surface marching walks over.

use crate::adjacency::BaseLocation;
use crate::ids::{BaseQuadId, FaceId};
use crate::refine::refine;
use crate::surface::{from_child, quadrant, to_child, Surface};
use crate::topology::PolyMesh;
use glam::DVec3;

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
            mesh,
        };
        let mut done = vec![false; nv];
        const CORNER: [(f64, f64); 4] = [(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0)];
        for f in 0..lm.mesh.num_faces() {
            let fid = FaceId::from_idx(f);
            for (c, &v) in lm.mesh.face_vertices(fid).iter().enumerate() {
                let v = v as usize;
                if done[v] {
                    continue;
                }
                done[v] = true;
                let loc = lm.to_base(fid, CORNER[c].0, CORNER[c].1);
                let e = self.eval_base(loc.quad, loc.s, loc.t);
                lm.position[v] = e.p;
                lm.normal[v] = e.n;
                lm.vertex_location[v] = loc;
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
