//! Chart sampling (Ying et al. 2001, §4.2, the five steps; names follow the paper).
//!
//! For a centre x in base quad U_1 with parameterisation f (Df = [∂f/∂s ∂f/∂t]) and a
//! vertex chart Φ = Φ^v:
//! 1. y = Φ(x);
//! 2. w_j solves Df·w_j = v_j (least squares; exact since v_j is tangent), τ_j = DΦ·w_j;
//! 3. y_lm = y + l·τ_1·δ + m·τ_2·δ for l, m = −h..h (K = 2h + 1), plus a second-order
//!    term (below);
//! 4. x_lm = Φ⁻¹(y_lm), mapped to (domain, u, v);
//! 5. (the texture fetch is the caller's: [`crate::maps`]).
//!
//! The pattern must fit in one chart: the home chart of x is tried first, then the charts
//! of the other corners of x's base quad ([`subdiv::Charts::candidates`]); the first chart
//! that holds every sample wins. A sample of a *boundary* chart that lies beyond the chart's
//! boundary rays (the images of the open boundary edges: the half-plane y ≥ 0, or the first
//! quadrant at a corner vertex) is off the surface: it is reported missing and the pattern
//! still fits. If no chart holds the pattern the caller marches instead.
//!
//! **Second-order term.** The paper's step 3 is linear: it is exact only where the chart is
//! an isometry up to a linear map. Characteristic-map charts are not (their metric varies
//! by ~10% across half a base quad next to a valence-3 vertex), so adjacent samples at the
//! rim of a 9×9 pattern drifted 5–10% from δ. We therefore place y_lm on the *geodesic*
//! through y with initial velocity t = l·τ_1 + m·τ_2 (what marching follows too), to
//! second order: y_lm = y + δ·t − ½δ²·Γ(t, t), where Γ(t, t) = (AᵀA)⁻¹Aᵀ·∂²F/∂t² is the
//! Christoffel term of the surface F = f∘Φ⁻¹ in chart coordinates, A = DF(y). ∂A is taken
//! by central differences of A = Df·DΦ⁻¹ at Φ⁻¹(y ± h·e_k) (4 extra Φ⁻¹ per *pattern*,
//! none per sample). Γ is bilinear, so the per-sample cost is unchanged.
//!
//! **Check.** Optionally (on by default in [`crate::sampling::Sampler`]) the finished
//! pattern is checked in 3D — adjacent samples δ·(1 ± tol) apart, no flipped cell — and a
//! chart that fails is treated like one the pattern does not fit: the next candidate is
//! tried, then marching. This is where the linearisation the paper relies on ("the
//! sampling neighbourhood is small enough that various maps can be replaced by their
//! linearized versions") does not hold: at coarse pattern scales, and next to
//! extraordinary vertices whose curvature is unbounded. It costs one limit evaluation
//! per sample.
//!
//! The four corner samples are mapped first, so a pattern that does not fit is usually
//! rejected after four Φ⁻¹ instead of K².

use crate::field::Frame;
use glam::{DMat2, DVec2, DVec3};
use std::f64::consts::FRAC_PI_2;
use subdiv::{BaseLocation, Charts, DomainLocation, Surface, VertexChart, VertexId};

/// τ_1, τ_2 of step 2 for a chart point with differential `dphi`.
#[inline]
pub fn chart_axes(dphi: DMat2, w1: DVec2, w2: DVec2) -> (DVec2, DVec2) {
    (dphi * w1, dphi * w2)
}

/// w_1, w_2 of step 2: the parameter-space vectors (base quad (s, t)) that f maps to v1, v2.
/// `None` when Df is singular (never at a point other than an extraordinary vertex itself).
#[inline]
pub fn parameter_axes(ds: DVec3, dt: DVec3, frame: &Frame) -> Option<(DVec2, DVec2)> {
    let g = DMat2::from_cols(
        DVec2::new(ds.dot(ds), dt.dot(ds)),
        DVec2::new(ds.dot(dt), dt.dot(dt)),
    );
    let det = g.determinant();
    if !det.is_finite() || det.abs() <= 1e-300 {
        return None;
    }
    let gi = g.inverse();
    let w1 = gi * DVec2::new(ds.dot(frame.v1), dt.dot(frame.v1));
    let w2 = gi * DVec2::new(ds.dot(frame.v2), dt.dot(frame.v2));
    Some((w1, w2))
}

/// Charts to try, best first: [`Charts::candidates`] (home chart, then the other corners of
/// the base quad), except that extraordinary corners come first. Next to an extraordinary
/// vertex every *other* chart sees the surface through f's singular parameterisation
/// (its derivatives vanish or blow up at the vertex), which bends the pattern by 10–30% of
/// δ; the vertex's own characteristic-map chart absorbs exactly that singularity.
fn candidates(surface: &Surface, loc: BaseLocation) -> [VertexId; 4] {
    let mut c = Charts::candidates(surface, loc);
    let regular = |v: VertexId| surface.base.is_regular_vertex(v);
    // Stable partition: extraordinary first, order otherwise kept.
    c.sort_by_key(|&v| regular(v));
    c
}

/// Whether chart point `y` lies beyond a boundary chart's boundary rays (off the surface).
#[inline]
fn off_surface(chart: &VertexChart, y: DVec2) -> bool {
    if !chart.is_boundary() {
        return false;
    }
    // Half-star over π (spokes 0 and k at angles 0 and π), or a corner's quadrant (π/2).
    let span = if chart.valence() == 1 {
        FRAC_PI_2
    } else {
        std::f64::consts::PI
    };
    if span == FRAC_PI_2 {
        y.x < 0.0 || y.y < 0.0
    } else {
        y.y < 0.0
    }
}

/// Maps one sample through `chart`: Some(Some(loc)) found, Some(None) off the surface,
/// None outside the chart.
#[inline]
fn map_sample(surface: &Surface, chart: &VertexChart, y: DVec2) -> Option<Option<DomainLocation>> {
    match chart.phi_inv(y) {
        Some(b) => Some(Some(surface.base_to_domain(b.quad, b.s, b.t))),
        None if off_surface(chart, y) => Some(None),
        None => None,
    }
}

/// Steps 1–4 for the K×K pattern around `loc` (the centre's base point; `centre` is written
/// at offset (0, 0)). `ds`, `dt` are ∂f/∂s, ∂f/∂t at `loc`. Writes `out[(m+h)·K + (l+h)]`
/// and returns the chart used, or `None` when the pattern fits no candidate chart (then
/// `out` is unspecified).
#[allow(clippy::too_many_arguments)]
pub fn sample_pattern(
    surface: &Surface,
    charts: &Charts,
    centre: DomainLocation,
    loc: BaseLocation,
    ds: DVec3,
    dt: DVec3,
    frame: &Frame,
    delta: f64,
    k: usize,
    order: PatternOrder,
    tolerance: Option<f64>,
    out: &mut [Option<DomainLocation>],
) -> Option<VertexId> {
    debug_assert!(k % 2 == 1 && out.len() >= k * k);
    let h = (k / 2) as i64;
    let (w1, w2) = parameter_axes(ds, dt, frame)?;
    'charts: for v in candidates(surface, loc) {
        let Some(chart) = charts.chart(v) else {
            continue;
        };
        let Some(cp) = chart.phi(loc) else {
            continue;
        };
        let (t1, t2) = chart_axes(cp.jacobian, w1, w2);
        let (t1, t2) = (t1 * delta, t2 * delta);
        let grid = if order == PatternOrder::Geodesic && k <= MAX_ODE_K && h > 0 {
            ChristoffelGrid::new(surface, chart, cp.y, t1, t2, h as f64, grid_nodes(h))
        } else {
            None
        };
        let mut ode = [DVec2::ZERO; MAX_ODE_K * MAX_ODE_K];
        if let Some(grid) = &grid {
            for m0 in -h..=h {
                for l0 in -h..=h {
                    if gcd(l0.unsigned_abs(), m0.unsigned_abs()) != 1 {
                        continue;
                    }
                    let reps = (h / l0.abs().max(m0.abs())) as usize;
                    grid.ray(DVec2::new(l0 as f64, m0 as f64), reps, |r, z| {
                        let (l, m) = (l0 * r as i64, m0 * r as i64);
                        ode[((m + h) as usize) * k + (l + h) as usize] = cp.y + t1 * z.x + t2 * z.y;
                    });
                }
            }
        }
        let g = match order {
            _ if grid.is_some() => GeodesicTerms::default(),
            PatternOrder::Linear => GeodesicTerms::default(),
            _ => geodesic_terms(
                surface,
                chart,
                cp.y,
                ds,
                dt,
                cp.jacobian,
                t1,
                t2,
                order,
                h as f64,
            ),
        };
        let y_at = |l: i64, m: i64| {
            if grid.is_some() {
                ode[((m + h) as usize) * k + (l + h) as usize]
            } else {
                cp.y + g.offset(t1, t2, l as f64, m as f64)
            }
        };
        let idx = |l: i64, m: i64| ((m + h) as usize) * k + (l + h) as usize;
        // Corners first: a pattern that does not fit fails fast.
        if h > 0 {
            for (l, m) in [(-h, -h), (h, -h), (-h, h), (h, h)] {
                match map_sample(surface, chart, y_at(l, m)) {
                    Some(s) => out[idx(l, m)] = s,
                    None => continue 'charts,
                }
            }
        }
        for m in -h..=h {
            for l in -h..=h {
                if l.abs() == h && m.abs() == h && h > 0 {
                    continue;
                }
                if l == 0 && m == 0 {
                    out[idx(0, 0)] = Some(centre);
                    continue;
                }
                match map_sample(surface, chart, y_at(l, m)) {
                    Some(s) => out[idx(l, m)] = s,
                    None => continue 'charts,
                }
            }
        }
        if let Some(tol) = tolerance {
            if !pattern_is_square(surface, &out[..k * k], k, delta, tol) {
                continue 'charts;
            }
        }
        return Some(v);
    }
    None
}

/// Whether every pair of adjacent samples is δ·(1 ± tol) apart in 3D and no cell is
/// flipped (against the normal at its corner). One limit evaluation per sample, two rows
/// of positions on the stack (K ≤ 128).
fn pattern_is_square(
    surface: &Surface,
    out: &[Option<DomainLocation>],
    k: usize,
    delta: f64,
    tol: f64,
) -> bool {
    const MAX_K: usize = 128;
    if k > MAX_K {
        return true;
    }
    let (lo, hi) = ((delta * (1.0 - tol)).powi(2), (delta * (1.0 + tol)).powi(2));
    let ok = |a: DVec3, b: DVec3| (lo..=hi).contains(&(b - a).length_squared());
    let mut prev = [(DVec3::NAN, DVec3::NAN); MAX_K];
    let mut cur = [(DVec3::NAN, DVec3::NAN); MAX_K];
    for m in 0..k {
        for l in 0..k {
            cur[l] = match out[m * k + l] {
                Some(x) => {
                    let e = surface.eval(x.domain, x.u, x.v);
                    (e.p, e.n)
                }
                None => (DVec3::NAN, DVec3::NAN),
            };
            let (p, n) = cur[l];
            if p.is_nan() {
                continue;
            }
            if l > 0 && !cur[l - 1].0.is_nan() && !ok(cur[l - 1].0, p) {
                return false;
            }
            if m > 0 && !prev[l].0.is_nan() && !ok(prev[l].0, p) {
                return false;
            }
            // Cell with corner (l-1, m-1): flipped?
            if l > 0 && m > 0 {
                let (a, na) = prev[l - 1];
                let (b, c) = (prev[l].0, cur[l - 1].0);
                if !a.is_nan() && !b.is_nan() && !c.is_nan() && (b - a).cross(c - a).dot(na) <= 0.0
                {
                    return false;
                }
            }
            let _ = n;
        }
        std::mem::swap(&mut prev, &mut cur);
    }
    true
}

/// How far the chart pattern follows the geodesics from the centre (module doc).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum PatternOrder {
    /// The paper's step 3 as printed: y + l·τ_1·δ + m·τ_2·δ.
    Linear,
    /// Plus the Christoffel (second-order) term.
    Quadratic,
    /// Plus the third-order term.
    Cubic,
    /// The geodesics themselves: integrated in chart coordinates (RK4) with Christoffel
    /// symbols from a 7×7 or 9×9 grid of chart points over the pattern (default; patterns up to
    /// [`MAX_ODE_K`], larger ones and grids that leave the chart use the cubic terms).
    #[default]
    Geodesic,
}

/// Largest K for [`PatternOrder::Geodesic`] (the pattern's chart points are kept on the
/// stack).
pub const MAX_ODE_K: usize = 15;
/// Most grid nodes per side for the Christoffel symbols of [`PatternOrder::Geodesic`]
/// (see [`grid_nodes`]).
const NODES: usize = 9;

/// Christoffel symbols of the surface in *pattern* coordinates z = (l, m) (chart point
/// y = y0 + l·T1 + m·T2) on a NODES×NODES grid over [−h, h]², bilinearly interpolated:
/// the geodesic through the centre with initial velocity (l, m) reaches sample (l, m) at
/// time 1.
struct ChristoffelGrid {
    h: f64,
    step: f64,
    /// Nodes per side (≤ [`NODES`]).
    n: usize,
    /// Per node: Γ(e_l, e_l), Γ(e_l, e_m), Γ(e_m, e_m).
    gamma: [[DVec2; 3]; NODES * NODES],
}

impl ChristoffelGrid {
    #[allow(clippy::too_many_arguments)]
    fn new(
        surface: &Surface,
        chart: &VertexChart,
        y0: DVec2,
        t1: DVec2,
        t2: DVec2,
        h: f64,
        nodes: usize,
    ) -> Option<Self> {
        let nn = nodes;
        let step = 2.0 * h / (nn - 1) as f64;
        // ∂F/∂l, ∂F/∂m at every node on the surface (nodes beyond an open boundary or
        // outside the chart are left out: their Γ is copied from the nearest node that has
        // one; samples there are missing or the pattern does not fit anyway).
        let mut g = [[DVec3::ZERO; 2]; NODES * NODES];
        let mut valid = [false; NODES * NODES];
        for j in 0..nn {
            for i in 0..nn {
                let z = DVec2::new(-h + i as f64 * step, -h + j as f64 * step);
                let y = y0 + t1 * z.x + t2 * z.y;
                let Some(x) = chart.phi_inv(y) else {
                    continue;
                };
                let cp = chart.phi(x)?;
                let e = surface.eval_base(x.quad, x.s, x.t);
                let a = chart_differential(e.du, e.dv, cp.jacobian)?;
                g[j * nn + i] = [a[0] * t1.x + a[1] * t1.y, a[0] * t2.x + a[1] * t2.y];
                valid[j * nn + i] = true;
            }
        }
        let c = nn / 2;
        if !valid[c * nn + c] {
            return None;
        }
        // Differences along a grid line: central where both neighbours exist, else
        // second-order one-sided, else first-order.
        let diff = |idx: &dyn Fn(usize) -> usize, i: usize, b: usize| -> Option<DVec3> {
            let ok = |k: isize| (0..nn as isize).contains(&k) && valid[idx(k as usize)];
            let v = |k: isize| g[idx(k as usize)][b];
            let i = i as isize;
            Some(if ok(i - 1) && ok(i + 1) {
                (v(i + 1) - v(i - 1)) / (2.0 * step)
            } else if ok(i + 1) && ok(i + 2) {
                (v(i + 1) * 4.0 - v(i) * 3.0 - v(i + 2)) / (2.0 * step)
            } else if ok(i - 1) && ok(i - 2) {
                (v(i) * 3.0 - v(i - 1) * 4.0 + v(i - 2)) / (2.0 * step)
            } else if ok(i + 1) {
                (v(i + 1) - v(i)) / step
            } else if ok(i - 1) {
                (v(i) - v(i - 1)) / step
            } else {
                return None;
            })
        };
        let mut gamma = [[DVec2::ZERO; 3]; NODES * NODES];
        for j in 0..nn {
            for i in 0..nn {
                if !valid[j * nn + i] {
                    continue;
                }
                let row = |k: usize| j * nn + k;
                let col = |k: usize| k * nn + i;
                // ∂_l G_b and ∂_m G_b.
                let dl = [diff(&row, i, 0)?, diff(&row, i, 1)?];
                let dm = [diff(&col, j, 0)?, diff(&col, j, 1)?];
                let fll = dl[0];
                let fmm = dm[1];
                let flm = (dl[1] + dm[0]) * 0.5;
                let p = Pinv::new(g[j * nn + i])?;
                gamma[j * nn + i] = [p.apply(fll), p.apply(flm), p.apply(fmm)];
            }
        }
        for n in 0..nn * nn {
            if !valid[n] {
                let (i, j) = ((n % nn) as i64, (n / nn) as i64);
                let near = (0..nn * nn).filter(|&q| valid[q]).min_by_key(|&q| {
                    let (a, b) = ((q % nn) as i64, (q / nn) as i64);
                    (a - i).pow(2) + (b - j).pow(2)
                })?;
                gamma[n] = gamma[near];
            }
        }
        if !gamma.iter().flatten().all(|v| v.is_finite()) {
            return None;
        }
        Some(ChristoffelGrid {
            h,
            step,
            n: nn,
            gamma,
        })
    }

    /// The geodesic acceleration −Γ(w, w) at pattern point z.
    #[inline]
    fn accel(&self, z: DVec2, w: DVec2) -> DVec2 {
        let nn = self.n;
        let n = (nn - 1) as f64;
        let fx = ((z.x + self.h) / self.step).clamp(0.0, n);
        let fy = ((z.y + self.h) / self.step).clamp(0.0, n);
        let (ix, iy) = ((fx as usize).min(nn - 2), (fy as usize).min(nn - 2));
        let (ax, ay) = (fx - ix as f64, fy - iy as f64);
        let i0 = iy * nn + ix;
        let w00 = (1.0 - ax) * (1.0 - ay);
        let w10 = ax * (1.0 - ay);
        let w01 = (1.0 - ax) * ay;
        let w11 = ax * ay;
        let (c00, c10, c01, c11) = (
            &self.gamma[i0],
            &self.gamma[i0 + 1],
            &self.gamma[i0 + nn],
            &self.gamma[i0 + nn + 1],
        );
        let q = [w.x * w.x, 2.0 * w.x * w.y, w.y * w.y];
        let mut a = DVec2::ZERO;
        for t in 0..3 {
            a += (c00[t] * w00 + c10[t] * w10 + c01[t] * w01 + c11[t] * w11) * q[t];
        }
        -a
    }

    /// Integrates the geodesic from z = 0 with velocity `v` (pattern units) for `reps`
    /// units of time and writes the point at each whole time into `out` (via `put`).
    fn ray(&self, v: DVec2, reps: usize, mut put: impl FnMut(usize, DVec2)) {
        let sub = ((2.0 * v.x.abs().max(v.y.abs())).ceil() as usize).max(1);
        let dt = 1.0 / sub as f64;
        let (mut z, mut w) = (DVec2::ZERO, v);
        for r in 1..=reps {
            for _ in 0..sub {
                let k1z = w;
                let k1w = self.accel(z, w);
                let k2z = w + k1w * (0.5 * dt);
                let k2w = self.accel(z + k1z * (0.5 * dt), k2z);
                let k3z = w + k2w * (0.5 * dt);
                let k3w = self.accel(z + k2z * (0.5 * dt), k3z);
                let k4z = w + k3w * dt;
                let k4w = self.accel(z + k3z * dt, k4z);
                z += (k1z + (k2z + k3z) * 2.0 + k4z) * (dt / 6.0);
                w += (k1w + (k2w + k3w) * 2.0 + k4w) * (dt / 6.0);
            }
            put(r, z);
        }
    }
}

/// Grid nodes per side for a pattern of half-width `h`: 7 up to 7×7 patterns, 9 above
/// (one node per sample step for 9×9). Measured against the exact map on Spot: 5 nodes
/// left 7% of δ at K = 9 and 0.7% at K = 5, 9 and 7 nodes 1.8% and 0.3%, at about 30%
/// lower rates (a 3×3 grid for 5×5 patterns was 9% of δ off next to open boundaries).
fn grid_nodes(h: i64) -> usize {
    if h >= 4 {
        NODES
    } else {
        7
    }
}

fn gcd(a: u64, b: u64) -> u64 {
    if b == 0 {
        a
    } else {
        gcd(b, a % b)
    }
}

/// Nonlinear terms of the pattern in chart coordinates, as polynomials in (l, m):
/// y_lm − y = l·T1 + m·T2 − ½(l²Q11 + 2lm·Q12 + m²Q22) + ⅙(l³a + 3l²m·b + 3lm²·c + m³d),
/// where T_j = δ·τ_j.
#[derive(Clone, Copy, Debug, Default)]
struct GeodesicTerms {
    q: [DVec2; 3],
    c: [DVec2; 4],
}

impl GeodesicTerms {
    #[inline]
    fn offset(&self, t1: DVec2, t2: DVec2, l: f64, m: f64) -> DVec2 {
        let [q11, q12, q22] = self.q;
        let [a, b, c, d] = self.c;
        t1 * l + t2 * m - (q11 * (l * l) + q12 * (2.0 * l * m) + q22 * (m * m)) * 0.5
            + (a * (l * l * l) + b * (3.0 * l * l * m) + c * (3.0 * l * m * m) + d * (m * m * m))
                * (1.0 / 6.0)
    }

    fn scaled(mut self, s: f64) -> Self {
        for v in self.q.iter_mut().chain(self.c.iter_mut()) {
            *v *= s;
        }
        self
    }
}

/// DF = Df·DΦ⁻¹ (columns ∂F/∂y_1, ∂F/∂y_2) from the base-quad derivatives.
#[inline]
fn chart_differential(ds: DVec3, dt: DVec3, dphi: DMat2) -> Option<[DVec3; 2]> {
    let det = dphi.determinant();
    if !det.is_finite() || det.abs() <= 1e-300 {
        return None;
    }
    let inv = dphi.inverse();
    let (c0, c1) = (inv.col(0), inv.col(1));
    Some([ds * c0.x + dt * c0.y, ds * c1.x + dt * c1.y])
}

/// P = (AᵀA)⁻¹Aᵀ: the chart-coordinate components of a 3D vector's tangential part.
#[derive(Clone, Copy)]
struct Pinv {
    a: [DVec3; 2],
    gi: DMat2,
}

impl Pinv {
    fn new(a: [DVec3; 2]) -> Option<Self> {
        let g = DMat2::from_cols(
            DVec2::new(a[0].dot(a[0]), a[1].dot(a[0])),
            DVec2::new(a[0].dot(a[1]), a[1].dot(a[1])),
        );
        let det = g.determinant();
        if !det.is_finite() || det.abs() <= 1e-300 {
            return None;
        }
        Some(Pinv { a, gi: g.inverse() })
    }
    #[inline]
    fn apply(&self, v: DVec3) -> DVec2 {
        self.gi * DVec2::new(self.a[0].dot(v), self.a[1].dot(v))
    }
}

#[allow(clippy::needless_range_loop)]
/// The geodesic terms at chart point `y` for the pattern axes `t1`, `t2` (already × δ),
/// from A = DF on a 3×3 stencil around y (central differences: F's second
/// derivatives for Γ, third derivatives for ∂Γ). Falls back to lower order where stencil
/// points leave the chart, and scales the nonlinear terms down where they could fold the
/// pattern (next to extraordinary vertices, where curvature is unbounded): the Jacobian
/// of the nonlinear part relative to [T1 T2] is kept below 1/2 in norm over |l|, |m| ≤ h,
/// so the pattern's cells keep their orientation.
#[allow(clippy::too_many_arguments)]
fn geodesic_terms(
    surface: &Surface,
    chart: &VertexChart,
    y: DVec2,
    ds: DVec3,
    dt: DVec3,
    dphi: DMat2,
    t1: DVec2,
    t2: DVec2,
    order: PatternOrder,
    h: f64,
) -> GeodesicTerms {
    // Differences are taken at the pattern's own scale (one sample step in the chart), not
    // infinitesimally: the terms are then the best fit of the geodesics over the pattern,
    // which stays meaningful next to extraordinary vertices, where the surface is not C²
    // and infinitesimal derivatives blow up.
    let step = 0.5 * (t1.length() + t2.length());
    let zero = GeodesicTerms::default();
    let Some(a0) = chart_differential(ds, dt, dphi) else {
        return zero;
    };
    let Some(p0) = Pinv::new(a0) else {
        return zero;
    };
    let at = |i: i32, j: i32| -> Option<[DVec3; 2]> {
        let x = chart.phi_inv(y + DVec2::new(i as f64, j as f64) * step)?;
        let cp = chart.phi(x)?;
        let e = surface.eval_base(x.quad, x.s, x.t);
        chart_differential(e.du, e.dv, cp.jacobian)
    };
    // A at y ± step·e_1, y ± step·e_2.
    let (Some(xp), Some(xm), Some(yp), Some(ym)) = (at(1, 0), at(-1, 0), at(0, 1), at(0, -1))
    else {
        return zero;
    };
    // F_ab = ∂_a A_b (symmetrised).
    let d1 = [
        [
            (xp[0] - xm[0]) / (2.0 * step),
            (xp[1] - xm[1]) / (2.0 * step),
        ],
        [
            (yp[0] - ym[0]) / (2.0 * step),
            (yp[1] - ym[1]) / (2.0 * step),
        ],
    ];
    let f01 = (d1[0][1] + d1[1][0]) * 0.5;
    let fab = [[d1[0][0], f01], [f01, d1[1][1]]];
    let second = |u: DVec2, v: DVec2| -> DVec3 {
        let mut s = DVec3::ZERO;
        for (ia, ua) in [u.x, u.y].into_iter().enumerate() {
            for (ib, vb) in [v.x, v.y].into_iter().enumerate() {
                s += fab[ia][ib] * (ua * vb);
            }
        }
        s
    };
    let gamma = |u: DVec2, v: DVec2| p0.apply(second(u, v));
    let q = [gamma(t1, t1), gamma(t1, t2), gamma(t2, t2)];
    let mut terms = GeodesicTerms {
        q,
        c: [DVec2::ZERO; 4],
    };

    if matches!(order, PatternOrder::Cubic | PatternOrder::Geodesic) {
        let corners = [at(1, 1), at(1, -1), at(-1, 1), at(-1, -1)];
        let pins = [Pinv::new(xp), Pinv::new(xm), Pinv::new(yp), Pinv::new(ym)];
        if let (
            [Some(pp), Some(mp), Some(pm), Some(mm)],
            [Some(px), Some(mx), Some(py), Some(my)],
        ) = (corners, pins)
        {
            // ∂_a∂_m A_b: d2[b][a][m].
            let mut d2 = [[[DVec3::ZERO; 2]; 2]; 2];
            for b in 0..2 {
                d2[b][0][0] = (xp[b] - a0[b] * 2.0 + xm[b]) / (step * step);
                d2[b][1][1] = (yp[b] - a0[b] * 2.0 + ym[b]) / (step * step);
                let mixed = (pp[b] - pm[b] - mp[b] + mm[b]) / (4.0 * step * step);
                d2[b][0][1] = mixed;
                d2[b][1][0] = mixed;
            }
            // Third derivatives F_abm, symmetrised over the three indices.
            let third = |u: DVec2, v: DVec2, w: DVec2| -> DVec3 {
                let c = |x: DVec2, i: usize| if i == 0 { x.x } else { x.y };
                let mut s = DVec3::ZERO;
                for i in 0..2 {
                    for j in 0..2 {
                        for k in 0..2 {
                            let sym = (d2[i][j][k] + d2[j][k][i] + d2[k][i][j]) * (1.0 / 3.0);
                            s += sym * (c(u, i) * c(v, j) * c(w, k));
                        }
                    }
                }
                s
            };
            // ∂_w Γ(u, v) = (∂_w P) F(u, v) + P F(u, v, w).
            let dgamma = |u: DVec2, v: DVec2, w: DVec2| -> DVec2 {
                let f = second(u, v);
                let dp = (px.apply(f) - mx.apply(f)) * (w.x / (2.0 * step))
                    + (py.apply(f) - my.apply(f)) * (w.y / (2.0 * step));
                dp + p0.apply(third(u, v, w))
            };
            let t = [t1, t2];
            let cterm = |i: usize, j: usize, k: usize| -> DVec2 {
                -dgamma(t[i], t[j], t[k]) + gamma(gamma(t[i], t[j]), t[k]) * 2.0
            };
            let sym3 = |i: usize, j: usize, k: usize| {
                (cterm(i, j, k) + cterm(j, k, i) + cterm(k, i, j)) * (1.0 / 3.0)
            };
            terms.c = [sym3(0, 0, 0), sym3(0, 0, 1), sym3(0, 1, 1), sym3(1, 1, 1)];
        }
    }
    if !terms.q.iter().chain(terms.c.iter()).all(|v| v.is_finite()) {
        return zero;
    }
    // Fold guard (see the doc above).
    let tm = DMat2::from_cols(t1, t2);
    if tm.determinant().abs() < 1e-300 {
        return zero;
    }
    let ti = tm.inverse();
    let nrm = |v: DVec2| (ti * v).length();
    let [q11, q12, q22] = terms.q;
    let [ca, cb, cc, cd] = terms.c;
    let rho_l = h * (nrm(q11) + nrm(q12)) + 0.5 * h * h * (nrm(ca) + 2.0 * nrm(cb) + nrm(cc));
    let rho_m = h * (nrm(q12) + nrm(q22)) + 0.5 * h * h * (nrm(cb) + 2.0 * nrm(cc) + nrm(cd));
    let rho = (rho_l * rho_l + rho_m * rho_m).sqrt();
    if rho > 0.5 {
        terms = terms.scaled(0.5 / rho);
    }
    terms
}
