//! Characteristic-map vertex charts (Ying et al. 2001, end of §4.2; names follow the paper).
//!
//! For every vertex v of the base-quad mesh, the chart map Φ^v sends each base quad U_i
//! around v into one planar domain V. Construction, as in the paper: a regular planar
//! k-gonal star gives the 1-ring of v (edge neighbours at radius 1, face neighbours at
//! radius √2, sector angle α = 2π/k), an extra layer of similar quads surrounds it (the
//! 5x5 grid of the regular case, bent by the same polar map), and Catmull-Clark subdivision
//! of these 2D coordinates gives Φ everywhere on the U_i. For k = 4 the net is the square
//! grid and Φ is affine. Boundary vertices get the half-star: m faces spread over π
//! (α = π/m; a corner with one face keeps the quadrant, α = π/2).
//!
//! We evaluate Φ *exactly*, with the same patch trees as the surface itself: the planar net
//! is a [`ControlMesh`] whose first k faces are the inner quads, so Φ on sector j is
//! [`Surface::eval`] of net domain j. Nets depend only on (interior/boundary, k), so they
//! are built once per kind and shared.
//!
//! The parameter of a base quad with v at corner c is rotated into the *corner frame* of v
//! (v at (0,0), first axis toward corner c+1, second toward corner c-1): the same rotation as
//! the refinement child map, halved.
//!
//! Each chart *serves* the quarter of each incident quad nearest to v (corner-frame
//! parameter in [0, 0.5]^2): every surface point has a home chart, at least half a base
//! quad away from that chart's edge. Φ⁻¹ is point location by sector angle followed by
//! Newton's method on the exact Φ.

use crate::adjacency::BaseLocation;
use crate::ids::{BaseQuadId, DomainId, FaceId, VertexId};
use crate::mesh::ControlMesh;
use crate::surface::{from_child, mul_child, quadrant, to_child, Surface};
use glam::{DMat2, DVec2, DVec3};
use std::collections::HashMap;
use std::f64::consts::{FRAC_PI_2, PI};
use std::sync::Arc;

/// A point of a chart domain V with the differential of Φ at it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ChartPoint {
    /// Φ(x).
    pub y: DVec2,
    /// DΦ: columns are dΦ/ds and dΦ/dt of the base quad's own parameter.
    pub jacobian: DMat2,
}

/// The planar net of one chart kind, with its sector angle.
#[derive(Debug)]
struct ChartNet {
    surface: Surface,
    sectors: usize,
    alpha: f64,
    boundary: bool,
}

/// The chart of one vertex: the base quads around it, counter-clockwise.
#[derive(Clone, Debug)]
pub struct VertexChart {
    net: Arc<ChartNetHandle>,
    /// Sector j: the base quad and the corner of it that is v.
    pub sectors: Vec<(BaseQuadId, u8)>,
}

#[derive(Debug)]
struct ChartNetHandle(ChartNet);

/// All vertex charts of a surface.
#[derive(Debug)]
pub struct Charts {
    charts: Vec<Option<VertexChart>>,
}

impl Charts {
    /// Builds the chart of every base-mesh vertex.
    pub fn new(surface: &Surface) -> Self {
        let m = &surface.base;
        let mut nets: HashMap<(bool, usize), Arc<ChartNetHandle>> = HashMap::new();
        let mut charts = Vec::with_capacity(m.num_vertices());
        for v in 0..m.num_vertices() {
            let vid = VertexId::from_idx(v);
            let outs: Vec<u32> = m.outgoing(vid).collect();
            if outs.is_empty() {
                charts.push(None);
                continue;
            }
            let boundary = m.is_boundary_vertex(vid);
            let key = (boundary, outs.len());
            let net = nets
                .entry(key)
                .or_insert_with(|| Arc::new(ChartNetHandle(ChartNet::new(boundary, outs.len()))))
                .clone();
            let sectors = outs
                .iter()
                .map(|&h| {
                    let f = m.face_of(h);
                    (BaseQuadId(f.0), (h - m.face_he(f)) as u8)
                })
                .collect();
            charts.push(Some(VertexChart { net, sectors }));
        }
        Charts { charts }
    }

    /// The chart of base vertex `v`.
    pub fn chart(&self, v: VertexId) -> Option<&VertexChart> {
        self.charts[v.idx()].as_ref()
    }

    /// The vertex whose chart serves `loc` (the corner of its base quad nearest in
    /// parameter), followed by the other three corners, nearest first: callers whose pattern
    /// does not fit the home chart try the others.
    pub fn candidates(surface: &Surface, loc: BaseLocation) -> [VertexId; 4] {
        let vs = surface.base.face_vertices(FaceId(loc.quad.0));
        let home = quadrant(loc.s, loc.t);
        // Corners adjacent to home, the nearer first, then the opposite one.
        let (a, b) = ((home + 1) % 4, (home + 3) % 4);
        let (sa, ta) = CORNERS[a];
        let (sb, tb) = CORNERS[b];
        let da = (loc.s - sa).abs() + (loc.t - ta).abs();
        let db = (loc.s - sb).abs() + (loc.t - tb).abs();
        let (first, second) = if da <= db { (a, b) } else { (b, a) };
        [home, first, second, (home + 2) % 4].map(|c| VertexId(vs[c]))
    }
}

const CORNERS: [(f64, f64); 4] = [(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0)];

impl VertexChart {
    fn net(&self) -> &ChartNet {
        &self.net.0
    }

    /// Number of base quads around the vertex.
    pub fn valence(&self) -> usize {
        self.sectors.len()
    }

    pub fn is_boundary(&self) -> bool {
        self.net().boundary
    }

    /// The sector of base quad `b`, if `b` is around this vertex.
    pub fn sector_of(&self, b: BaseQuadId) -> Option<usize> {
        self.sectors.iter().position(|&(q, _)| q == b)
    }

    /// Φ and DΦ at a base point; `None` if its quad is not around this vertex.
    pub fn phi(&self, loc: BaseLocation) -> Option<ChartPoint> {
        let j = self.sector_of(loc.quad)?;
        let c = self.sectors[j].1 as usize;
        let (a, b) = to_child(c, loc.s, loc.t);
        let (a, b) = (0.5 * a, 0.5 * b);
        let e = self.net().surface.eval(DomainId(j as u32), a, b);
        // d(corner frame)/d(s,t) is the child rotation, halved.
        let r = mul_child(c, &[[0.5, 0.0], [0.0, 0.5]]);
        let da = DVec2::new(e.du.x, e.du.y);
        let db = DVec2::new(e.dv.x, e.dv.y);
        let ds = da * r[0][0] + db * r[1][0];
        let dt = da * r[0][1] + db * r[1][1];
        Some(ChartPoint {
            y: DVec2::new(e.p.x, e.p.y),
            jacobian: DMat2::from_cols(ds, dt),
        })
    }

    /// Φ⁻¹: the base point mapped to `y`, or `None` if `y` is outside the chart's image
    /// (beyond its 1-ring of quads, or across an open boundary).
    pub fn phi_inv(&self, y: DVec2) -> Option<BaseLocation> {
        let net = self.net();
        let r = y.length();
        if r > 2.0 * std::f64::consts::SQRT_2 {
            return None;
        }
        let mut theta = y.y.atan2(y.x);
        if theta < 0.0 && !net.boundary {
            theta += 2.0 * PI;
        }
        let span = net.alpha * net.sectors as f64;
        if net.boundary && (theta < -1e-12 || theta > span + 1e-12) {
            // Below the boundary line of a half-star (or outside a corner's quadrant).
            if r > 1e-12 {
                return None;
            }
        }
        let mut j = ((theta.max(0.0) / net.alpha) as usize).min(net.sectors - 1);
        let phi = (theta - j as f64 * net.alpha) / net.alpha * FRAC_PI_2;
        let mut guess = DVec2::new(r * phi.cos(), r * phi.sin()).clamp(DVec2::ZERO, DVec2::ONE);
        let tol = 1e-12;
        for _attempt in 0..net.sectors + 1 {
            let (p, converged) = net.newton(j, y, guess);
            let out_lo_t = p.y < -tol;
            let out_lo_s = p.x < -tol;
            if converged && !out_lo_t && !out_lo_s {
                if p.x > 1.0 + tol || p.y > 1.0 + tol {
                    return None;
                }
                let (qa, qb) = (p.x.clamp(0.0, 1.0), p.y.clamp(0.0, 1.0));
                let (quad, c) = self.sectors[j];
                let (s, t) = from_child(c as usize, 2.0 * qa, 2.0 * qb);
                return Some(BaseLocation { quad, s, t });
            }
            // Edge t=0 of sector j is edge s=0 of sector j-1; edge s=0 is t=0 of j+1.
            let k = net.sectors;
            if out_lo_t || (!converged && p.y < p.x) {
                if net.boundary && j == 0 {
                    return None;
                }
                j = (j + k - 1) % k;
                guess = DVec2::new(0.0, p.x.clamp(0.0, 1.0));
            } else {
                if net.boundary && j + 1 == k {
                    return None;
                }
                j = (j + 1) % k;
                guess = DVec2::new(p.y.clamp(0.0, 1.0), 0.0);
            }
        }
        None
    }
}

impl ChartNet {
    /// The planar net: regular k-star plus an extra layer (see the module doc).
    fn new(boundary: bool, k: usize) -> Self {
        let alpha = match (boundary, k) {
            (false, k) => 2.0 * PI / k as f64,
            (true, 1) => FRAC_PI_2,
            (true, m) => PI / m as f64,
        };
        let spokes = if boundary { k + 1 } else { k };
        // Polar map of the regular grid's first quadrant onto sector j.
        let place = |j: usize, x: f64, y: f64| -> DVec3 {
            let r = (x * x + y * y).sqrt();
            let phi = y.atan2(x);
            let theta = j as f64 * alpha + phi / FRAC_PI_2 * alpha;
            DVec3::new(r * theta.cos(), r * theta.sin(), 0.0)
        };
        let mut pos = vec![DVec3::ZERO];
        // Spoke i: e_i (grid (1,0) of sector i) and R2_i (grid (2,0)).
        let e = |i: usize| (1 + 2 * (i % spokes)) as u32;
        let r2 = |i: usize| (2 + 2 * (i % spokes)) as u32;
        for i in 0..spokes {
            pos.push(place(i, 1.0, 0.0));
            pos.push(place(i, 2.0, 0.0));
        }
        let base = pos.len() as u32;
        // Sector j: f_j (1,1), R21_j (2,1), R22_j (2,2), R12_j (1,2).
        let f = |j: usize| base + 4 * j as u32;
        for j in 0..k {
            pos.push(place(j, 1.0, 1.0));
            pos.push(place(j, 2.0, 1.0));
            pos.push(place(j, 2.0, 2.0));
            pos.push(place(j, 1.0, 2.0));
        }
        let mut faces: Vec<[u32; 4]> = Vec::new();
        for j in 0..k {
            faces.push([0, e(j), f(j), e(j + 1)]);
        }
        for j in 0..k {
            let (fj, r21, r22, r12) = (f(j), f(j) + 1, f(j) + 2, f(j) + 3);
            faces.push([e(j), r2(j), r21, fj]);
            faces.push([fj, r21, r22, r12]);
            faces.push([e(j + 1), fj, r12, r2(j + 1)]);
        }
        let refs: Vec<&[u32]> = faces.iter().map(|f| f.as_slice()).collect();
        let cm = ControlMesh::from_faces(pos, &refs).expect("chart net is a valid mesh");
        ChartNet {
            surface: Surface::new(cm),
            sectors: k,
            alpha,
            boundary,
        }
    }

    /// Solves Φ_j(p) = y for p (corner-frame parameter of sector j) by Newton's method,
    /// allowing p to leave [0,1]^2 slightly so the caller can tell which neighbour to try.
    fn newton(&self, j: usize, y: DVec2, mut p: DVec2) -> (DVec2, bool) {
        for _ in 0..40 {
            let e = self
                .surface
                .eval(DomainId(j as u32), p.x.clamp(0.0, 1.0), p.y.clamp(0.0, 1.0));
            // Outside [0,1]^2 extrapolate linearly from the clamped point.
            let q = p.clamp(DVec2::ZERO, DVec2::ONE);
            let jac = DMat2::from_cols(DVec2::new(e.du.x, e.du.y), DVec2::new(e.dv.x, e.dv.y));
            let val = DVec2::new(e.p.x, e.p.y) + jac * (p - q);
            let r = y - val;
            if r.length() < 1e-14 {
                return (p, true);
            }
            let det = jac.determinant();
            if det.abs() < 1e-300 || !det.is_finite() {
                // At the extraordinary centre itself: nudge inward.
                p = (p + DVec2::splat(1e-6)).min(DVec2::ONE);
                continue;
            }
            let step = jac.inverse() * r;
            p += step;
            if !p.is_finite() {
                return (q, false);
            }
            // Keep far excursions bounded: beyond this the point is in another sector.
            p = p.clamp(DVec2::splat(-0.5), DVec2::splat(1.5));
            if step.length() < 1e-15 {
                return (p, true);
            }
        }
        let e = self
            .surface
            .eval(DomainId(j as u32), p.x.clamp(0.0, 1.0), p.y.clamp(0.0, 1.0));
        let inside = (0.0..=1.0).contains(&p.x) && (0.0..=1.0).contains(&p.y);
        (p, inside && (DVec2::new(e.p.x, e.p.y) - y).length() < 1e-9)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn regular_net_is_the_square_grid() {
        let net = ChartNet::new(false, 4);
        for (a, b) in [(0.1, 0.2), (0.5, 0.5), (0.9, 0.3)] {
            let e = net.surface.eval(DomainId(0), a, b);
            assert!((e.p - DVec3::new(a, b, 0.0)).length() < 1e-14, "{}", e.p);
            assert!((e.du - DVec3::X).length() < 1e-13 && (e.dv - DVec3::Y).length() < 1e-13);
        }
    }

    #[test]
    fn nets_have_no_folds_over_the_served_quarter() {
        // Dense sampling for the common valences, sparser up to the accepted maximum.
        let cases = [
            (false, 2..=12usize, 20),
            (true, 1..=12, 20),
            (false, 13..=64, 6),
            (true, 13..=63, 6),
        ];
        for (boundary, ks, steps) in cases {
            for k in ks {
                let net = ChartNet::new(boundary, k);
                for j in 0..k {
                    for ia in 0..=steps {
                        for ib in 0..=steps {
                            let (a, b) = (
                                ia as f64 / (2 * steps) as f64,
                                ib as f64 / (2 * steps) as f64,
                            );
                            if a + b < 1e-9 {
                                continue;
                            }
                            let e = net.surface.eval(DomainId(j as u32), a, b);
                            let det = e.du.x * e.dv.y - e.du.y * e.dv.x;
                            assert!(
                                det > 0.0,
                                "boundary={boundary} k={k} sector {j} ({a},{b}): det {det}"
                            );
                        }
                    }
                }
            }
        }
    }
}
