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
//! are built once per kind and shared. Φ⁻¹ runs Newton's method on Φ, so an irregular net
//! also tabulates Φ on first use: outside a 2^-16 neighbourhood of v each square of its
//! patch tree is one bicubic polynomial, fitted to that exact evaluation (agreeing to
//! ~1e-15) and evaluated ~3x cheaper than the 3D patch tree (`NetTable`).
//!
//! The parameter of a base quad with v at corner c is rotated into the *corner frame* of v
//! (v at (0,0), first axis toward corner c+1, second toward corner c-1): the same rotation as
//! the refinement child map, halved.
//!
//! Each chart *serves* the quarter of each incident quad nearest to v (corner-frame
//! parameter in [0, 0.5]^2): every surface point has a home chart, at least half a base
//! quad away from that chart's edge. Φ⁻¹ is point location by sector angle followed by
//! Newton's method on Φ.

use crate::adjacency::BaseLocation;
use crate::ids::{BaseQuadId, DomainId, FaceId, VertexId};
use crate::mesh::ControlMesh;
use crate::surface::{from_child, mul_child, quadrant, to_child, Surface};
use glam::{DMat2, DVec2, DVec3};
use std::collections::HashMap;
use std::f64::consts::{FRAC_PI_2, PI};
use std::sync::{Arc, OnceLock};

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
    /// Φ_j as bicubic polynomials on the squares of the patch tree (not for the affine net),
    /// built on first use: see [`NetTable`].
    table: OnceLock<NetTable>,
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
        // Valid by construction; the centre's valence is that of any vertex of the base-quad
        // mesh, which exceeds the input cap at the face point of a large n-gon.
        let cm = ControlMesh::from_faces_trusted(pos, &refs);
        ChartNet {
            surface: Surface::new(cm),
            sectors: k,
            alpha,
            boundary,
            affine: !boundary && k == 4,
            table: OnceLock::new(),
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
        match self.table().eval(j, p) {
            Some(r) => r,
            None => self.eval_exact(j, p),
        }
    }

    /// [`Self::eval`] by the net's limit surface (a 3D patch-tree evaluation): the
    /// reference the [`NetTable`] is fitted to, and what it falls back to.
    fn eval_exact(&self, j: usize, p: DVec2) -> (DVec2, DMat2) {
        let e = self.surface.eval(DomainId(j as u32), p.x, p.y);
        (
            DVec2::new(e.p.x, e.p.y),
            DMat2::from_cols(DVec2::new(e.du.x, e.du.y), DVec2::new(e.dv.x, e.dv.y)),
        )
    }

    /// The table, built by the first caller (the same values whichever thread that is).
    fn table(&self) -> &NetTable {
        self.table.get_or_init(|| NetTable::build(self))
    }
}

/// Levels of the patch tree in a [`NetTable`]: points of a sector with max(a, b) < 2^-16
/// (within 2^-15 of the vertex in base-quad parameter) keep the patch-tree evaluation.
/// Together with the exact vertex and points outside [0, 1]² that was 0.16% of the net
/// evaluations of chart sampling on Spot (tests/chart_bench.rs, K = 5).
const TABLE_LEVELS: usize = 16;

/// Φ_j of a non-affine net as bicubic polynomials: ~130 instructions for Φ_j and DΦ_j
/// instead of ~425 for the patch tree of the net's 3D surface (Φ⁻¹ of irregular charts is
/// Newton's method on Φ_j, and the net evaluations were a third of chart sampling's
/// instructions on meshes with many extraordinary vertices).
///
/// Away from the extraordinary vertex the net's limit map is piecewise bicubic on the
/// squares of the patch tree: at level n (m = max(a, b) ∈ [2^-(n+1), 2^-n], h = 2^-(n+1))
/// the squares [h,2h]×[0,h], [h,2h]×[h,2h] and [0,h]×[h,2h] are regular quads of the
/// refined net, each one bicubic B-spline patch. Each square's polynomial is fitted to
/// the exact Φ_j, DΦ_j at a 4×4 grid and checked against them at other points when built;
/// a square that fails (none has, for the nets of valence 1–12 tested) keeps the
/// patch-tree evaluation.
///
/// Interior nets are rotationally symmetric (the k sectors are one placed k times, and
/// subdivision commutes with rotations), so Φ_j = R(jα) Φ_0 and only sector 0 is stored:
/// 16 levels × 3 squares × 264 bytes ≈ 12.4 KiB plus 32 bytes per sector. Boundary nets
/// are not: they store every sector, ≈ 12.4 KiB each.
#[derive(Debug)]
struct NetTable {
    /// Square q of level n of stored sector s at `(s * TABLE_LEVELS + n) * 3 + q`; `None`
    /// where Φ is not one polynomial.
    squares: Vec<Option<Bicubic>>,
    /// Interior nets: R(jα) for each sector j (only sector 0 is stored). Empty for boundary
    /// nets.
    rotations: Vec<DMat2>,
}

impl NetTable {
    /// Fits every square of the stored sectors (~25 patch-tree evaluations each).
    fn build(net: &ChartNet) -> Self {
        let (rotations, stored) = if net.boundary {
            (Vec::new(), net.sectors)
        } else {
            let r = (0..net.sectors)
                .map(|j| DMat2::from_angle(j as f64 * net.alpha))
                .collect();
            (r, 1)
        };
        let mut squares = Vec::with_capacity(stored * TABLE_LEVELS * 3);
        for j in 0..stored {
            for n in 0..TABLE_LEVELS {
                for q in 0..3 {
                    let sq = Square::new(n, q);
                    squares.push(sq.fit(|p| net.eval_exact(j, p)));
                }
            }
        }
        NetTable { squares, rotations }
    }

    /// Φ_j and DΦ_j at `p`, or `None` where the table does not apply (max(a, b) < 2^-16,
    /// p outside [0, 1]², or in a square that is not one polynomial).
    #[inline]
    fn eval(&self, j: usize, p: DVec2) -> Option<(DVec2, DMat2)> {
        let (n, q, w, z, scale) = Square::locate(p)?;
        let stored = if self.rotations.is_empty() { j } else { 0 };
        let poly = self.squares[(stored * TABLE_LEVELS + n) * 3 + q].as_ref()?;
        let (y, dw, dz) = poly.eval(w, z);
        let jac = DMat2::from_cols(dw * scale, dz * scale);
        Some(match self.rotations.get(j) {
            Some(r) => (*r * y, *r * jac),
            None => (y, jac),
        })
    }
}

/// Square q (0: [h,2h]×[0,h], 1: [h,2h]×[h,2h], 2: [0,h]×[h,2h]) of level n of a sector,
/// h = 2^-(n+1), with the local parameter (w, z) ∈ [-1, 1]² (centred: the power basis is
/// far better conditioned there than on [0, 1]²).
#[derive(Clone, Copy, Debug)]
struct Square {
    origin: DVec2,
    h: f64,
}

impl Square {
    fn new(n: usize, q: usize) -> Self {
        let h = 0.5f64.powi(n as i32 + 1);
        let origin = [DVec2::new(h, 0.0), DVec2::splat(h), DVec2::new(0.0, h)][q];
        Square { origin, h }
    }

    /// The sector point of local parameter (w, z).
    fn point(&self, w: f64, z: f64) -> DVec2 {
        self.origin + 0.5 * self.h * DVec2::new(w + 1.0, z + 1.0)
    }

    /// The square holding `p`: level n, square q, local (w, z) and d(w, z)/d(a, b) = 2/h.
    /// The level comes from the exponent bits of max(a, b) (no logarithm), and scaling by
    /// 2/h is exact.
    #[inline]
    fn locate(p: DVec2) -> Option<(usize, usize, f64, f64, f64)> {
        let m = p.x.max(p.y);
        // Also rejects NaN.
        if !(p.x >= 0.0 && p.y >= 0.0 && m <= 1.0) {
            return None;
        }
        // m ∈ [2^-(n+1), 2^-n) has biased exponent 1022 - n; m = 1 joins level 0.
        let biased = ((m.to_bits() >> 52) & 0x7ff) as usize;
        let n = 1022usize.saturating_sub(biased);
        if n >= TABLE_LEVELS {
            return None;
        }
        // 2/h = 2^(n+2); (a, b) · 2/h ∈ [0, 4]², the square's centre at 1 or 3.
        let scale = f64::from_bits(((1025 + n) as u64) << 52);
        let (x, y) = (p.x * scale, p.y * scale);
        Some(match (x >= 2.0, y >= 2.0) {
            (true, false) => (n, 0, x - 3.0, y - 1.0, scale),
            (true, true) => (n, 1, x - 3.0, y - 3.0, scale),
            _ => (n, 2, x - 1.0, y - 3.0, scale),
        })
    }

    /// The polynomial of this square fitted to `exact` (Φ_j, DΦ_j at a sector point), if
    /// Φ_j is one polynomial here.
    ///
    /// Only the constant term comes from values: the others come from the partials, which
    /// the patch tree gives to full relative precision even where Φ is far smaller than
    /// the net's control points (deep squares of a net without an extraordinary vertex, as
    /// the corner k = 1); fitted to values alone, DΦ there lost 4 digits.
    fn fit(&self, exact: impl Fn(DVec2) -> (DVec2, DMat2)) -> Option<Bicubic> {
        let half_h = 0.5 * self.h;
        let samples: [[(DVec2, DMat2); 4]; 4] = std::array::from_fn(|iz| {
            std::array::from_fn(|iw| exact(self.point(NODES[iw], NODES[iz])))
        });
        let value = interpolate(|iw, iz| samples[iz][iw].0);
        let dw = interpolate(|iw, iz| samples[iz][iw].1.col(0) * half_h);
        let dz = interpolate(|iw, iz| samples[iz][iw].1.col(1) * half_h);
        // d/dw of Σ c_ij w^i z^j has c_ij · i at w^(i-1) z^j (its w^3 terms are zero).
        let mut c = [DVec2::ZERO; 16];
        c[0] = value[0];
        for j in 0..4 {
            for i in 1..4 {
                c[4 * j + i] = dw[4 * j + i - 1] / i as f64;
            }
        }
        for j in 1..4 {
            c[4 * j] = dz[4 * (j - 1)] / j as f64;
        }
        let poly = Bicubic(c);
        self.agrees(&poly, &exact).then_some(poly)
    }

    /// Whether `poly` matches `exact` at the square's corners and a point in each of its
    /// quarters (a square made of several polynomials differs from the fit in one of them).
    fn agrees(&self, poly: &Bicubic, exact: impl Fn(DVec2) -> (DVec2, DMat2)) -> bool {
        const CHECKS: [(f64, f64); 9] = [
            (-1.0, -1.0),
            (1.0, -1.0),
            (1.0, 1.0),
            (-1.0, 1.0),
            (-0.46, -0.38),
            (0.54, -0.62),
            (0.38, 0.66),
            (-0.72, 0.16),
            (0.0, 0.0),
        ];
        let scale = 2.0 / self.h;
        CHECKS.iter().all(|&(w, z)| {
            let (y, jac) = exact(self.point(w, z));
            let (py, dw, dz) = poly.eval(w, z);
            let d = jac.col(0).length().max(jac.col(1).length());
            (py - y).length() <= FIT_VALUE_TOL
                && (dw * scale - jac.col(0)).length() <= FIT_DERIV_TOL * d
                && (dz * scale - jac.col(1)).length() <= FIT_DERIV_TOL * d
        })
    }
}

/// Largest difference in Φ between a square's polynomial and the patch tree accepted when
/// building (the unit tests ask for 1e-13).
const FIT_VALUE_TOL: f64 = 1e-14;
/// The same for DΦ, relative to its largest column (the unit tests ask for 1e-11).
const FIT_DERIV_TOL: f64 = 1e-12;

/// Interpolation nodes in [-1, 1]: Chebyshev points, inside the square (each evaluated by
/// the square's own patch) and well conditioned.
const NODES: [f64; 4] = [
    -0.9238795325112867,
    -0.3826834323650898,
    0.3826834323650898,
    0.9238795325112867,
];

/// Power-basis coefficients (`c[4 * j + i]` of w^i z^j) of the bicubic polynomial taking
/// the values `f(iw, iz)` at (NODES[iw], NODES[iz]).
fn interpolate(f: impl Fn(usize, usize) -> DVec2) -> [DVec2; 16] {
    // l[i][e]: coefficient of t^e in the Lagrange polynomial of node i.
    let l: [[f64; 4]; 4] = std::array::from_fn(|i| {
        let mut c = [1.0, 0.0, 0.0, 0.0];
        for (m, &tm) in NODES.iter().enumerate() {
            if m != i {
                // c · (t - tm) / (t_i - tm), highest power first to read the old c.
                let d = NODES[i] - tm;
                for e in (0..4).rev() {
                    let lower = if e > 0 { c[e - 1] } else { 0.0 };
                    c[e] = (lower - tm * c[e]) / d;
                }
            }
        }
        c
    });
    let mut c = [DVec2::ZERO; 16];
    for (j, row) in c.chunks_exact_mut(4).enumerate() {
        for (i, cij) in row.iter_mut().enumerate() {
            for (iz, lz) in l.iter().enumerate() {
                for (iw, lw) in l.iter().enumerate() {
                    *cij += f(iw, iz) * (lw[i] * lz[j]);
                }
            }
        }
    }
    c
}

/// A bicubic polynomial map [-1, 1]² → R² in the power basis: `c[4 * j + i]` multiplies
/// w^i z^j.
#[derive(Clone, Copy, Debug)]
struct Bicubic([DVec2; 16]);

impl Bicubic {
    /// Value and partials d/dw, d/dz at (w, z), by Horner's rule.
    #[inline(always)]
    fn eval(&self, w: f64, z: f64) -> (DVec2, DVec2, DVec2) {
        let row = |j: usize| {
            let r = &self.0[4 * j..4 * j + 4];
            let val = ((r[3] * w + r[2]) * w + r[1]) * w + r[0];
            let dw = (r[3] * (3.0 * w) + r[2] * 2.0) * w + r[1];
            (val, dw)
        };
        let (r0, d0) = row(0);
        let (r1, d1) = row(1);
        let (r2, d2) = row(2);
        let (r3, d3) = row(3);
        let val = ((r3 * z + r2) * z + r1) * z + r0;
        let dw = ((d3 * z + d2) * z + d1) * z + d0;
        let dz = (r3 * (3.0 * z) + r2 * 2.0) * z + r1;
        (val, dw, dz)
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

    /// Test points of a sector (xorshift, fixed seed): random ones at every scale down to
    /// 2^-20, on square borders and at level boundaries (max(a, b) exactly 2^-n), next to
    /// and at the vertex, and on the far edges.
    fn table_test_points() -> Vec<DVec2> {
        let mut state = 0x9e37_79b9_7f4a_7c15u64;
        let mut rnd = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        let mut pts = vec![
            DVec2::ZERO,
            DVec2::ONE,
            DVec2::X,
            DVec2::Y,
            DVec2::new(1.0, 0.5),
            DVec2::new(0.5, 1.0),
        ];
        for n in 0..TABLE_LEVELS + 3 {
            let h = 0.5f64.powi(n as i32 + 1);
            let (r, s) = (rnd(), rnd());
            pts.extend([
                // Level boundary 2^-n, from both squares and the diagonal.
                DVec2::new(2.0 * h, r * 2.0 * h),
                DVec2::new(s * 2.0 * h, 2.0 * h),
                DVec2::splat(2.0 * h),
                DVec2::new(2.0 * h, 0.0),
                DVec2::new(0.0, 2.0 * h),
                // Just below it (the level below).
                DVec2::new(2.0 * h * (1.0 - f64::EPSILON), r * h),
                // Borders between the squares of level n.
                DVec2::new(h, r * h),
                DVec2::new(h, h + s * h),
                DVec2::new(h + r * h, h),
                DVec2::new(s * h, h),
                DVec2::splat(h),
            ]);
        }
        for _ in 0..300 {
            let scale = 0.5f64.powf(20.0 * rnd());
            pts.push(DVec2::new(rnd(), rnd()) * scale);
        }
        pts
    }

    /// The tabulated Φ_j, DΦ_j match the net's limit surface everywhere in every sector
    /// (the rotated sector 0 for interior nets, each sector for boundary ones), and every
    /// square of these nets is one polynomial (the claim the table rests on).
    #[test]
    fn table_matches_the_net_surface() {
        let kinds = [
            (false, 3),
            (false, 5),
            (false, 6),
            (false, 7),
            (false, 8),
            (false, 12),
            (true, 1),
            (true, 2),
            (true, 3),
            (true, 5),
        ];
        let pts = table_test_points();
        for (boundary, k) in kinds {
            let net = ChartNet::new(boundary, k);
            let table = net.table();
            assert!(
                table.squares.iter().all(Option::is_some),
                "boundary={boundary} k={k}: a square is not one polynomial"
            );
            let (mut worst_y, mut worst_d, mut tabulated) = (0.0f64, 0.0f64, 0);
            for j in 0..k {
                for &p in &pts {
                    let m = p.x.max(p.y);
                    let inside = m >= 0.5f64.powi(TABLE_LEVELS as i32);
                    assert_eq!(table.eval(j, p).is_some(), inside, "{p}");
                    tabulated += inside as usize;
                    let (y, jac) = net.eval(j, p);
                    let (ye, jace) = net.eval_exact(j, p);
                    let scale = jace.col(0).length().max(jace.col(1).length());
                    let dy = (y - ye).length();
                    let dd = (0..2)
                        .map(|c| (jac.col(c) - jace.col(c)).length() / scale)
                        .fold(0.0, f64::max);
                    let at = format!("boundary={boundary} k={k} sector {j} {p:?}");
                    assert!(dy <= 1e-13, "{at}: Φ {y} vs {ye}");
                    assert!(dd <= 1e-11, "{at}: DΦ {jac} vs {jace}");
                    (worst_y, worst_d) = (worst_y.max(dy), worst_d.max(dd));
                }
            }
            assert!(tabulated > k * pts.len() * 3 / 4);
            println!("boundary={boundary} k={k}: Φ within {worst_y:.1e}, DΦ {worst_d:.1e}");
        }
    }

    /// The build-time check rejects what is not one polynomial: the quad at the
    /// extraordinary vertex, [0, h]², is not (the characteristic map is not polynomial
    /// there), while at a regular vertex (interior k = 4, boundary k = 2, the corner k = 1)
    /// it is.
    #[test]
    fn table_check_rejects_the_quad_at_an_extraordinary_vertex() {
        for (boundary, k, polynomial) in [
            (false, 3, false),
            (false, 5, false),
            (true, 3, false),
            (false, 4, true),
            (true, 2, true),
            (true, 1, true),
        ] {
            let net = ChartNet::new(boundary, k);
            for n in [1, 4, 12] {
                let sq = Square {
                    origin: DVec2::ZERO,
                    h: 0.5f64.powi(n),
                };
                let fit = sq.fit(|p| net.eval_exact(0, p));
                assert_eq!(
                    fit.is_some(),
                    polynomial,
                    "boundary={boundary} k={k} h=2^-{n}"
                );
            }
        }
    }

    /// The level and square of a point come from exponent bits: check them against the
    /// definition (m = max(a, b) ∈ [2^-(n+1), 2^-n), m = 1 in level 0).
    #[test]
    fn squares_are_located_by_exponent() {
        for p in table_test_points() {
            let m = p.x.max(p.y);
            match Square::locate(p) {
                None => assert!(m < 0.5f64.powi(TABLE_LEVELS as i32), "{p}"),
                Some((n, q, w, z, scale)) => {
                    let sq = Square::new(n, q);
                    assert_eq!(scale, 2.0 / sq.h);
                    assert!(m >= sq.h && (m < 2.0 * sq.h || m == 1.0), "{p}: level {n}");
                    let unit = -1.0..=1.0;
                    assert!(unit.contains(&w) && unit.contains(&z), "{p}: square {q}");
                    assert!((sq.point(w, z) - p).length() <= f64::EPSILON * m, "{p}");
                }
            }
        }
        assert!(Square::locate(DVec2::new(-1e-3, 0.5)).is_none());
        assert!(Square::locate(DVec2::new(0.5, 1.0 + 1e-12)).is_none());
        assert!(Square::locate(DVec2::new(f64::NAN, 0.5)).is_none());
    }

    /// Build time of [`Charts::new`] on Spot and of the tables of its irregular net kinds
    /// (`cargo test --release -p subdiv --lib charts_build_time -- --ignored --nocapture`).
    #[test]
    #[ignore]
    fn charts_build_time() {
        let s = Surface::load_obj(crate::test_data::opensubdiv_reference(
            "spot_control_mesh.obj",
        ))
        .unwrap();
        for _ in 0..3 {
            let t0 = std::time::Instant::now();
            let charts = Charts::new(&s);
            let built = t0.elapsed();
            let mut kinds: Vec<(bool, usize)> = Vec::new();
            let t1 = std::time::Instant::now();
            for c in charts.charts.iter().flatten() {
                let key = (c.is_boundary(), c.valence());
                if !c.net().affine && !kinds.contains(&key) {
                    kinds.push(key);
                    c.net().table();
                }
            }
            println!(
                "Charts::new {:.2} ms; tables of the irregular kinds {kinds:?}: {:.2} ms",
                built.as_secs_f64() * 1e3,
                t1.elapsed().as_secs_f64() * 1e3
            );
        }
    }
}
