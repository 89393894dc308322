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

/// A warm start for [`VertexChart::phi_inv_hinted`]: an earlier solution in the chart's
/// net (sector, corner-frame parameter, chart point, inverse differential).
#[derive(Clone, Copy, Debug)]
pub struct ChartHint {
    sector: usize,
    p: DVec2,
    y: DVec2,
    inv_jac: DMat2,
}

/// The planar net of one chart kind, with its sector angle.
#[derive(Debug)]
struct ChartNet {
    surface: Surface,
    sectors: usize,
    alpha: f64,
    boundary: bool,
    /// Φ is the rotation R_j of the corner-frame parameter on sector j (the regular interior
    /// net: its inner patches are uniform bicubic B-splines of a square grid, which
    /// reproduce linear functions). Evaluated in closed form: most charts of a typical mesh
    /// are regular, and Φ, Φ⁻¹ dominate chart sampling's cost otherwise.
    affine: bool,
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
        let (y, jac) = self.net().eval(j, DVec2::new(a, b));
        Some(ChartPoint {
            y,
            jacobian: base_jacobian(c, jac),
        })
    }

    /// Φ⁻¹ with Φ and DΦ at the point found (saves the caller a [`Self::phi`]; DΦ is the
    /// one of Newton's last iterate, within ~1e-6 of the point).
    pub fn phi_inv_point(&self, y: DVec2) -> Option<(BaseLocation, ChartPoint)> {
        self.phi_inv_hinted(y, &mut None)
    }

    /// As [`Self::phi_inv_point`], with Newton's method started from `hint` (the
    /// solution of a nearby earlier call, updated here on success) instead of the polar
    /// guess: next to an earlier point one or two iterations suffice. The result is the same
    /// to ~1e-12 either way (Φ is injective; Newton stops after a step below 1e-6, which
    /// leaves an error of its square).
    pub fn phi_inv_hinted(
        &self,
        y: DVec2,
        hint: &mut Option<ChartHint>,
    ) -> Option<(BaseLocation, ChartPoint)> {
        let start = hint.map(|h| (h.sector, h.p + h.inv_jac * (y - h.y)));
        let found = match self.locate(y, start) {
            None if start.is_some() => self.locate(y, None),
            r => r,
        };
        let (loc, j, p, jac) = found?;
        if !self.net().affine {
            let det = jac.determinant();
            *hint = (det.abs() > 1e-300 && det.is_finite()).then(|| ChartHint {
                sector: j,
                p,
                y,
                inv_jac: jac.inverse(),
            });
        }
        let c = self.sectors[j].1 as usize;
        Some((
            loc,
            ChartPoint {
                y,
                jacobian: base_jacobian(c, jac),
            },
        ))
    }

    /// Φ⁻¹: the base point mapped to `y`, or `None` if `y` is outside the chart's image
    /// (beyond its 1-ring of quads, or across an open boundary).
    pub fn phi_inv(&self, y: DVec2) -> Option<BaseLocation> {
        self.locate(y, None).map(|(loc, ..)| loc)
    }

    /// Φ⁻¹(y): the base point, the sector it lies in, its corner-frame parameter there and
    /// the corner-frame differential of Φ_j at it. Newton's method starts from `start`
    /// (sector, parameter) when given, else from the polar guess.
    fn locate(
        &self,
        y: DVec2,
        start: Option<(usize, DVec2)>,
    ) -> Option<(BaseLocation, usize, DVec2, DMat2)> {
        let net = self.net();
        let r = y.length();
        if r > 2.0 * std::f64::consts::SQRT_2 {
            return None;
        }
        if net.affine {
            // Sector by quadrant (half-open, as the angle rule below), then R_j⁻¹.
            let j = if y.x > 0.0 && y.y >= 0.0 {
                0
            } else if y.x <= 0.0 && y.y > 0.0 {
                1
            } else if y.x < 0.0 && y.y <= 0.0 {
                2
            } else if y.x >= 0.0 && y.y < 0.0 {
                3
            } else {
                0
            };
            let rot = rotation(j);
            let p = rot.transpose() * y;
            if p.x > 1.0 + 1e-12 || p.y > 1.0 + 1e-12 {
                return None;
            }
            let (qa, qb) = (p.x.clamp(0.0, 1.0), p.y.clamp(0.0, 1.0));
            let (quad, c) = self.sectors[j];
            let (s, t) = from_child(c as usize, 2.0 * qa, 2.0 * qb);
            return Some((BaseLocation { quad, s, t }, j, DVec2::new(qa, qb), rot));
        }
        let theta = || {
            let theta = y.y.atan2(y.x);
            if theta < 0.0 && !net.boundary {
                theta + 2.0 * PI
            } else {
                theta
            }
        };
        if net.boundary {
            let (theta, span) = (theta(), net.alpha * net.sectors as f64);
            if (theta < -1e-12 || theta > span + 1e-12) && r > 1e-12 {
                // Below the boundary line of a half-star (or outside a corner's quadrant).
                return None;
            }
        }
        let (mut j, mut guess) = match start {
            Some((j, p)) if j < net.sectors && p.is_finite() => {
                (j, p.clamp(DVec2::splat(-0.5), DVec2::splat(1.5)))
            }
            _ => {
                let theta = theta();
                let j = ((theta.max(0.0) / net.alpha) as usize).min(net.sectors - 1);
                let phi = (theta - j as f64 * net.alpha) / net.alpha * FRAC_PI_2;
                let g = DVec2::new(r * phi.cos(), r * phi.sin()).clamp(DVec2::ZERO, DVec2::ONE);
                (j, g)
            }
        };
        let tol = 1e-12;
        for _attempt in 0..net.sectors + 1 {
            let (p, converged, jac) = net.newton(j, y, guess);
            let out_lo_t = p.y < -tol;
            let out_lo_s = p.x < -tol;
            if converged && !out_lo_t && !out_lo_s {
                if p.x > 1.0 + tol || p.y > 1.0 + tol {
                    return None;
                }
                let (qa, qb) = (p.x.clamp(0.0, 1.0), p.y.clamp(0.0, 1.0));
                let (quad, c) = self.sectors[j];
                let (s, t) = from_child(c as usize, 2.0 * qa, 2.0 * qb);
                return Some((BaseLocation { quad, s, t }, j, DVec2::new(qa, qb), jac));
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

/// Rotation by j·π/2 (sector j of the regular net).
#[inline]
fn rotation(j: usize) -> DMat2 {
    match j & 3 {
        0 => DMat2::IDENTITY,
        1 => DMat2::from_cols(DVec2::Y, -DVec2::X),
        2 => -DMat2::IDENTITY,
        _ => DMat2::from_cols(-DVec2::Y, DVec2::X),
    }
}

/// DΦ with respect to the base quad's own (s, t) from the corner-frame differential `jac`
/// (corner frame = the child rotation of corner `c`, halved).
#[inline]
fn base_jacobian(c: usize, jac: DMat2) -> DMat2 {
    let r = mul_child(c, &[[0.5, 0.0], [0.0, 0.5]]);
    let (da, db) = (jac.col(0), jac.col(1));
    DMat2::from_cols(da * r[0][0] + db * r[1][0], da * r[0][1] + db * r[1][1])
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
            affine: !boundary && k == 4,
        }
    }

    /// Solves Φ_j(p) = y for p (corner-frame parameter of sector j) by Newton's method,
    /// allowing p to leave [0,1]^2 slightly so the caller can tell which neighbour to try.
    fn newton(&self, j: usize, y: DVec2, mut p: DVec2) -> (DVec2, bool, DMat2) {
        let mut jac;
        for _ in 0..40 {
            let q = p.clamp(DVec2::ZERO, DVec2::ONE);
            let (yq, jq) = self.eval(j, q);
            jac = jq;
            // Outside [0,1]^2 extrapolate linearly from the clamped point.
            let val = yq + jac * (p - q);
            let r = y - val;
            if r.length() < 1e-14 {
                return (p, true, jac);
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
                return (q, false, jac);
            }
            // Keep far excursions bounded: beyond this the point is in another sector.
            p = p.clamp(DVec2::splat(-0.5), DVec2::splat(1.5));
            // Quadratic convergence: after a step this short the error is ~1e-12.
            if step.length() < 1e-6 {
                return (p, true, jac);
            }
        }
        let (yp, jac) = self.eval(j, p.clamp(DVec2::ZERO, DVec2::ONE));
        let inside = (0.0..=1.0).contains(&p.x) && (0.0..=1.0).contains(&p.y);
        (p, inside && (yp - y).length() < 1e-9, jac)
    }

    /// Φ_j and its differential at corner-frame parameter `p` ∈ [0, 1]² of sector j.
    #[inline]
    fn eval(&self, j: usize, p: DVec2) -> (DVec2, DMat2) {
        if self.affine {
            let r = rotation(j);
            return (r * p, r);
        }
        let e = self.surface.eval(DomainId(j as u32), p.x, p.y);
        (
            DVec2::new(e.p.x, e.p.y),
            DMat2::from_cols(DVec2::new(e.du.x, e.du.y), DVec2::new(e.dv.x, e.dv.y)),
        )
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

    /// The closed form used for regular interior charts is the net's own limit map, and
    /// Newton's Φ⁻¹ on the net agrees with it.
    #[test]
    fn affine_regular_net_matches_its_subdivision_surface() {
        let net = ChartNet::new(false, 4);
        assert!(net.affine);
        let mut newton = ChartNet::new(false, 4);
        newton.affine = false;
        for j in 0..4 {
            for (a, b) in [(0.0, 0.0), (0.1, 0.2), (0.5, 0.5), (0.9, 0.3), (1.0, 1.0)] {
                let p = DVec2::new(a, b);
                let (y, jac) = net.eval(j, p);
                let (y2, jac2) = newton.eval(j, p);
                assert!((y - y2).length() < 1e-13, "sector {j} {p}: {y} vs {y2}");
                let d = jac - jac2;
                assert!(
                    d.col(0).length() + d.col(1).length() < 1e-12,
                    "sector {j} {p}"
                );
            }
        }
        let chart = |net: ChartNet| VertexChart {
            net: Arc::new(ChartNetHandle(net)),
            sectors: (0..4).map(|j| (BaseQuadId(j), (j % 4) as u8)).collect(),
        };
        let (fast, slow) = (chart(net), chart(newton));
        for i in 0..400 {
            let t = i as f64 * 0.7391;
            let r = 3.0 * ((i * 37 % 101) as f64 / 100.0);
            let y = DVec2::new(r * t.cos(), r * t.sin());
            match (fast.phi_inv_point(y), slow.phi_inv_point(y)) {
                (None, None) => {}
                // On a sector edge either side is right: compare the chart points.
                (Some((a, _)), Some((b, _))) if a.quad != b.quad => {
                    let (pa, pb) = (fast.phi(a).unwrap().y, slow.phi(b).unwrap().y);
                    assert!(
                        (pa - y).length() < 1e-12 && (pb - y).length() < 1e-12,
                        "{y}"
                    );
                }
                (Some((a, ca)), Some((b, cb))) => {
                    assert!((a.s - b.s).abs() + (a.t - b.t).abs() < 1e-11, "{y}");
                    let d = ca.jacobian - cb.jacobian;
                    assert!(d.col(0).length() + d.col(1).length() < 1e-6, "{y}");
                }
                (a, b) => panic!("{y}: {a:?} vs {b:?}"),
            }
        }
    }

    /// Warm-started Φ⁻¹ finds the same points as the cold one, along a path through all
    /// sectors and out of the chart and back, for irregular and boundary nets.
    #[test]
    fn hinted_inverse_matches_the_cold_one() {
        for (boundary, k) in [(false, 3), (false, 5), (false, 7), (true, 1), (true, 3)] {
            let chart = VertexChart {
                net: Arc::new(ChartNetHandle(ChartNet::new(boundary, k))),
                sectors: (0..k)
                    .map(|j| (BaseQuadId(j as u32), (j % 4) as u8))
                    .collect(),
            };
            let mut hint = None;
            let mut found = 0;
            for i in 0..2000 {
                let t = i as f64 * 0.0123;
                let r = 1.2 + 0.9 * (t * 1.7).sin();
                let y = DVec2::new(r * t.cos(), r * t.sin());
                let cold = chart.phi_inv_point(y);
                let warm = chart.phi_inv_hinted(y, &mut hint);
                match (cold, warm) {
                    (None, None) => {}
                    (Some((a, ca)), Some((b, cb))) => {
                        found += 1;
                        let (pa, pb) = (chart.phi(a).unwrap().y, chart.phi(b).unwrap().y);
                        assert!((pa - y).length() < 1e-10 && (pb - y).length() < 1e-10);
                        if a.quad == b.quad {
                            assert!((a.s - b.s).abs() + (a.t - b.t).abs() < 1e-10, "{y}");
                            let d = ca.jacobian - cb.jacobian;
                            assert!(d.col(0).length() + d.col(1).length() < 1e-5, "{y}");
                        }
                    }
                    (a, b) => panic!("boundary={boundary} k={k} {y}: {a:?} vs {b:?}"),
                }
            }
            assert!(found > 100, "boundary={boundary} k={k}: {found}");
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
