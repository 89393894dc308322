//! Moving across base-quad and domain edges in parameter space.
//!
//! Base quads form a conforming quad mesh, so crossing an edge is a rigid change of
//! coordinates: edge `e` of a base quad runs from corner `e` to corner `e+1`; in its *edge
//! frame* a point has `a` (position along the edge, 0 at corner e) and `w` (distance inward).
//! The twin edge of the neighbour runs the other way, so (a, w) becomes (1 - a, -w) there.
//! Ptex domains (with their T-junctions between quads and n-gon sub-faces) ride on top.

use crate::domains::DomainLocation;
use crate::ids::{BaseQuadId, FaceId};
use crate::surface::Surface;

/// (s, t) -> (a, w) in the frame of edge `e` (see the module doc).
#[inline]
pub fn to_edge_frame(e: usize, s: f64, t: f64) -> (f64, f64) {
    match e {
        0 => (s, t),
        1 => (t, 1.0 - s),
        2 => (1.0 - s, 1.0 - t),
        _ => (1.0 - t, s),
    }
}

/// Inverse of [`to_edge_frame`].
#[inline]
pub fn from_edge_frame(e: usize, a: f64, w: f64) -> (f64, f64) {
    match e {
        0 => (a, w),
        1 => (1.0 - w, a),
        2 => (1.0 - a, 1.0 - w),
        _ => (w, 1.0 - a),
    }
}

/// A base-quad point.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BaseLocation {
    pub quad: BaseQuadId,
    pub s: f64,
    pub t: f64,
}

impl Surface {
    /// The base quad across edge `e` (0..4) of `b` and the index of the shared edge there,
    /// or `None` on an open boundary.
    pub fn base_neighbor(&self, b: BaseQuadId, e: usize) -> Option<(BaseQuadId, usize)> {
        let h = self.base.face_he(FaceId(b.0)) + e as u32;
        let t = self.base.twin(h)?;
        let nb = self.base.face_of(t);
        let ne = (t - self.base.face_he(nb)) as usize;
        Some((BaseQuadId(nb.0), ne))
    }

    /// Moves from `from` by (ds, dt) along a straight line in parameter space, continuing
    /// across base-quad edges into neighbours. Returns the end point and the number of
    /// edges crossed, or `None` if the path leaves the surface through an open boundary.
    pub fn walk_base(&self, from: BaseLocation, ds: f64, dt: f64) -> Option<(BaseLocation, u32)> {
        let BaseLocation {
            mut quad,
            mut s,
            mut t,
        } = from;
        let (mut ds, mut dt) = (ds, dt);
        for crossed in 0..1024u32 {
            let (es, et) = (s + ds, t + dt);
            if (0.0..=1.0).contains(&es) && (0.0..=1.0).contains(&et) {
                return Some((BaseLocation { quad, s: es, t: et }, crossed));
            }
            // First edge the segment leaves through, and where.
            let mut lambda = f64::INFINITY;
            let mut edge = 0;
            let mut consider = |l: f64, e: usize| {
                if l >= 0.0 && l < lambda {
                    lambda = l;
                    edge = e;
                }
            };
            if et < 0.0 {
                consider(-t / dt, 0);
            }
            if es > 1.0 {
                consider((1.0 - s) / ds, 1);
            }
            if et > 1.0 {
                consider((1.0 - t) / dt, 2);
            }
            if es < 0.0 {
                consider(-s / ds, 3);
            }
            let lambda = lambda.clamp(0.0, 1.0);
            let (xs, xt) = (s + lambda * ds, t + lambda * dt);
            let (rs, rt) = (ds * (1.0 - lambda), dt * (1.0 - lambda));
            let (nb, ne) = self.base_neighbor(quad, edge)?;
            // Map the crossing point and the remaining displacement (as a second point).
            let (a0, _) = to_edge_frame(edge, xs, xt);
            let (a1, w1) = to_edge_frame(edge, xs + rs, xt + rt);
            let (a0n, w0n) = (1.0 - a0, 0.0);
            let (a1n, w1n) = (1.0 - a1, -w1);
            let (ns, nt) = from_edge_frame(ne, a0n.clamp(0.0, 1.0), w0n);
            let (ps, pt) = from_edge_frame(ne, a1n, w1n);
            quad = nb;
            s = ns;
            t = nt;
            ds = ps - ns;
            dt = pt - nt;
        }
        None
    }

    /// [`Self::walk_base`] in domain coordinates: moves from `from` by (du, dv), measured in
    /// the starting domain's parameter, across domain edges.
    pub fn walk(&self, from: DomainLocation, du: f64, dv: f64) -> Option<DomainLocation> {
        let (b, s, t, jac) = self.domain_to_base(from.domain, from.u, from.v);
        let ds = jac[0][0] * du + jac[0][1] * dv;
        let dt = jac[1][0] * du + jac[1][1] * dv;
        let (end, _) = self.walk_base(BaseLocation { quad: b, s, t }, ds, dt)?;
        Some(self.base_to_domain(end.quad, end.s, end.t))
    }

    /// Base location of a domain point.
    pub fn base_location(&self, loc: DomainLocation) -> BaseLocation {
        let (quad, s, t, _) = self.domain_to_base(loc.domain, loc.u, loc.v);
        BaseLocation { quad, s, t }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{ControlMesh, DomainId};
    use glam::DVec3;

    #[test]
    fn edge_frames_invert() {
        for e in 0..4 {
            let (a, w) = to_edge_frame(e, 0.2, 0.7);
            let (s, t) = from_edge_frame(e, a, w);
            assert!((s - 0.2).abs() < 1e-15 && (t - 0.7).abs() < 1e-15);
        }
    }

    fn grid(n: usize) -> Surface {
        Surface::new(ControlMesh::grid(n))
    }

    #[test]
    fn walking_across_quads_follows_the_plane() {
        // On a planar grid the limit surface away from the border is an affine image of the
        // parameter, so walking by (du, dv) must move the limit point by (du, dv) * spacing.
        let s = grid(6);
        let start = DomainLocation {
            domain: DomainId(14),
            u: 0.3,
            v: 0.6,
        };
        let p0 = s.eval(start.domain, start.u, start.v).p;
        for (du, dv) in [
            (1.4, 0.0),
            (0.0, -1.2),
            (-1.1, 0.9),
            (0.7, 0.7),
            (-0.5, -1.5),
        ] {
            let end = s.walk(start, du, dv).unwrap();
            let p1 = s.eval(end.domain, end.u, end.v).p;
            assert!(
                (p1 - p0 - DVec3::new(du, dv, 0.0)).length() < 1e-12,
                "{du},{dv}: {}",
                p1 - p0
            );
        }
        // Leaving through the open boundary.
        assert!(s
            .walk(
                DomainLocation {
                    domain: DomainId(0),
                    u: 0.5,
                    v: 0.5
                },
                -1.0,
                0.0
            )
            .is_none());
    }
}
