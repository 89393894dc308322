//! Ptex face domains (OpenSubdiv convention) on top of base quads.
//!
//! Domains are numbered walking control faces in OBJ order: a quad is one domain with
//! (u, v) = (0,0) at its 1st vertex, u toward the 2nd, v toward the 4th; an n-gon (n != 4)
//! gives n sub-face domains, sub-face c with (0,0) at vertex c, u toward vertex c+1 (u = 1 is
//! that edge's midpoint), v toward vertex c-1, (1,1) at the face centre.
//!
//! A sub-face *is* base quad c of its face, parameter for parameter. A quad domain is four
//! base quads: base quad c covers the quarter at corner c, reached by the same child map as
//! one refinement step ([`crate::surface`]'s `to_child`). Both maps are exact, so domain
//! evaluation inherits the exactness of the patch trees, for any resolution.

use crate::ids::{BaseQuadId, DomainId, FaceId};
use crate::mesh::ptex_count;
use crate::surface::{from_child, mul_child, quadrant, to_child, LeafHint, LimitSample, Surface};

/// What a domain is made of.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Domain {
    /// A control quad (four base quads).
    Quad { face: FaceId },
    /// Sub-face `corner` of a control n-gon (one base quad).
    SubFace { face: FaceId, corner: u32 },
}

/// A point of the surface in domain coordinates.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DomainLocation {
    pub domain: DomainId,
    pub u: f64,
    pub v: f64,
}

impl Surface {
    pub(crate) fn init_domains(&mut self) {
        let m = &self.control.mesh;
        self.domain_start = Vec::with_capacity(m.num_faces() + 1);
        self.domain_face = Vec::new();
        self.domain_start.push(0);
        for f in 0..m.num_faces() {
            let k = ptex_count(m.face_size(FaceId::from_idx(f)));
            for _ in 0..k {
                self.domain_face.push(f as u32);
            }
            self.domain_start.push(self.domain_face.len() as u32);
        }
    }

    pub fn num_domains(&self) -> usize {
        self.domain_face.len()
    }

    pub fn domain(&self, d: DomainId) -> Domain {
        let f = self.domain_face[d.idx()];
        let face = FaceId(f);
        if self.control.mesh.face_size(face) == 4 {
            Domain::Quad { face }
        } else {
            Domain::SubFace {
                face,
                corner: d.0 - self.domain_start[f as usize],
            }
        }
    }

    /// The first domain of control face `f`.
    pub fn face_domain(&self, f: FaceId) -> DomainId {
        DomainId(self.domain_start[f.idx()])
    }

    /// The base quad holding domain point (u, v), its parameter there, and the linear map
    /// `jac` with d(s,t) = jac * d(u,v).
    pub fn domain_to_base(
        &self,
        d: DomainId,
        u: f64,
        v: f64,
    ) -> (BaseQuadId, f64, f64, [[f64; 2]; 2]) {
        match self.domain(d) {
            Domain::SubFace { face, corner } => {
                let b = self.control.mesh.face_he(face) + corner;
                (BaseQuadId(b), u, v, [[1.0, 0.0], [0.0, 1.0]])
            }
            Domain::Quad { face } => {
                let c = quadrant(u, v);
                let (s, t) = to_child(c, u, v);
                let b = self.control.mesh.face_he(face) + c as u32;
                (BaseQuadId(b), s, t, mul_child(c, &[[1.0, 0.0], [0.0, 1.0]]))
            }
        }
    }

    /// The domain point of base quad `b` at (s, t).
    pub fn base_to_domain(&self, b: BaseQuadId, s: f64, t: f64) -> DomainLocation {
        let face = self.base_face(b);
        let corner = b.0 - self.control.mesh.face_he(face);
        let d0 = self.face_domain(face);
        if self.control.mesh.face_size(face) == 4 {
            let (u, v) = from_child(corner as usize, s, t);
            DomainLocation { domain: d0, u, v }
        } else {
            DomainLocation {
                domain: DomainId(d0.0 + corner),
                u: s,
                v: t,
            }
        }
    }

    /// The control face base quad `b` belongs to. Base vertex 2 of every base quad is its
    /// parent's face point, numbered after the control vertices ([`crate::refine`]).
    pub fn base_face(&self, b: BaseQuadId) -> FaceId {
        let fp = self.base.face_vertices(FaceId(b.0))[2];
        FaceId(fp - self.control.mesh.num_vertices() as u32)
    }

    /// Exact limit position, normal and derivatives with respect to (u, v) at a domain point.
    pub fn eval(&self, d: DomainId, u: f64, v: f64) -> LimitSample {
        let (b, s, t, jac) = self.domain_to_base(d, u, v);
        domain_derivs(self.eval_base(b, s, t), &jac)
    }

    /// [`Self::eval`] starting from the regular patch `hint` remembers
    /// ([`Surface::eval_base_derivs`]): the same bits. Neighbouring points (a row of texel
    /// centres) mostly lie in one patch, and the descent of the patch tree is then skipped.
    pub fn eval_hinted(&self, d: DomainId, u: f64, v: f64, hint: &mut LeafHint) -> LimitSample {
        let (b, s, t, jac) = self.domain_to_base(d, u, v);
        domain_derivs(self.eval_base_derivs(b, s, t, hint).sample(), &jac)
    }

    /// Evaluates the `n x n` texel centres of domain `d`, ((x+0.5)/n, (y+0.5)/n), row by row
    /// (y outer, x inner) into `out` (length n*n).
    pub fn eval_texels(&self, d: DomainId, n: usize, out: &mut [LimitSample]) {
        assert_eq!(out.len(), n * n);
        let inv = 1.0 / n as f64;
        let mut hint = LeafHint::default();
        for y in 0..n {
            let v = (y as f64 + 0.5) * inv;
            for x in 0..n {
                let u = (x as f64 + 0.5) * inv;
                out[y * n + x] = self.eval_hinted(d, u, v, &mut hint);
            }
        }
    }
}

/// A base-quad sample with its derivatives turned into domain ones (`jac`: d(s,t) =
/// jac · d(u,v)).
#[inline]
fn domain_derivs(mut r: LimitSample, jac: &[[f64; 2]; 2]) -> LimitSample {
    let (ds, dt) = (r.du, r.dv);
    r.du = ds * jac[0][0] + dt * jac[1][0];
    r.dv = ds * jac[0][1] + dt * jac[1][1];
    r
}

#[cfg(test)]
mod tests {
    use crate::surface::SurfaceOptions;
    use crate::{DomainId, Surface};

    /// Texel grids evaluated through the hint (`eval_texels`) are `eval`'s bits, also at
    /// extraordinary vertices, n-gon sub-faces and below the stored depth.
    #[test]
    fn texels_match_eval() {
        for shape in [
            "catmark_pole8",
            "catmark_nonquads",
            "catmark_cubes_infsharp",
        ] {
            let cm = crate::ControlMesh::load_obj(crate::test_data::shape(shape)).unwrap();
            let s = Surface::with_options(cm, SurfaceOptions { max_depth: 2 });
            for n in [1, 3, 8, 20] {
                let mut out = vec![Default::default(); n * n];
                for d in 0..s.num_domains() {
                    let d = DomainId::from_idx(d);
                    s.eval_texels(d, n, &mut out);
                    for (i, got) in out.iter().enumerate() {
                        let inv = 1.0 / n as f64;
                        let (u, v) = ((i % n) as f64 + 0.5, (i / n) as f64 + 0.5);
                        let want = s.eval(d, u * inv, v * inv);
                        assert_eq!(*got, want, "{shape} N = {n} domain {d:?} texel {i}");
                    }
                }
            }
        }
    }
}
