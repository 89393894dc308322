//! Chart sampling (Ying et al. 2001, §4.2, the five steps; names follow the paper).
//!
//! For a centre x in base quad U_1 with parameterisation f (Df = [∂f/∂s ∂f/∂t]) and a
//! vertex chart Φ = Φ^v:
//! 1. y = Φ(x);
//! 2. w_j solves Df·w_j = v_j (least squares; exact since v_j is tangent), τ_j = DΦ·w_j;
//! 3. y_lm = y + l·τ_1·δ + m·τ_2·δ for l, m = −h..h (K = 2h + 1), bent onto the
//!    geodesics (below);
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
//! **Geodesics.** The paper's step 3 is linear: it is exact only where the chart is an
//! isometry up to a linear map. Characteristic-map charts are not (their metric varies by
//! ~10% across half a base quad next to a valence-3 vertex), so adjacent samples at the rim
//! of a 9×9 pattern drifted 5–10% from δ. We place y_lm on the *geodesic* through y with
//! initial velocity l·τ_1 + m·τ_2 (what marching follows too): the geodesic equation
//! z'' = −Γ(z', z') is integrated (RK4) in pattern coordinates z (y = y + z.x·T1 + z.y·T2,
//! T_j = δ·τ_j), with the Christoffel symbols Γ = (AᵀA)⁻¹Aᵀ·∂A of the surface F = f∘Φ⁻¹
//! (A = DF) from differences of A on a grid of nodes over the pattern, interpolated
//! bilinearly. Grids are nested (`Nodes`): 3×3 and 5×5 first, 9×9 where those two
//! disagree (`ACCEPT_5`); each node costs one Φ⁻¹ and one limit evaluation, none per
//! sample. `PatternOrder::Quadratic`/`Cubic` keep the older Taylor terms (from a 3×3
//! stencil) and `Linear` the paper's step 3.
//!
//! **Check.** Optionally (on by default in [`crate::sampling::Sampler`]) the finished
//! pattern is checked — adjacent samples δ·(1 ± tol) apart on the surface, no flipped
//! cell — and a chart that fails is treated like one the pattern does not fit: the next
//! candidate is tried, then marching. This is where the linearisation the paper relies on
//! ("the sampling neighbourhood is small enough that various maps can be replaced by their
//! linearized versions") does not hold: at coarse pattern scales, and next to
//! extraordinary vertices whose curvature is unbounded. Each chord comes from the grid's
//! metric (no evaluation) where the grid is known around it, else from limit evaluations
//! at its two samples.
//!
//! The four corner samples are mapped first, so a pattern that does not fit is usually
//! rejected after four Φ⁻¹ instead of K².

use crate::field::Frame;
use glam::{DMat2, DVec2, DVec3};
use std::cell::RefCell;
use std::f64::consts::FRAC_PI_2;
use subdiv::surface::LeafHint;
use subdiv::{BaseLocation, ChartHint, Charts, DomainLocation, Surface, VertexChart, VertexId};

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
    SCRATCH.with_borrow_mut(|scratch| {
        sample_pattern_in(
            scratch, surface, charts, centre, loc, ds, dt, frame, delta, k, order, tolerance, out,
        )
    })
}

/// [`sample_pattern`] with its working memory.
#[allow(clippy::too_many_arguments)]
fn sample_pattern_in(
    scratch: &mut Scratch,
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
    let Scratch {
        zs,
        za,
        g: node_g,
        metric: node_metric,
        hints: node_hints,
        gamma,
        pos,
    } = scratch;
    'charts: for v in candidates(surface, loc) {
        let Some(chart) = charts.chart(v) else {
            continue;
        };
        let Some(cp) = chart.phi(loc) else {
            continue;
        };
        let (t1, t2) = chart_axes(cp.jacobian, w1, w2);
        let (t1, t2) = (t1 * delta, t2 * delta);
        let idx = |l: i64, m: i64| ((m + h) as usize) * k + (l + h) as usize;
        // Pattern coordinates z of every sample (chart point y = y0 + z.x·T1 + z.y·T2):
        // `zs`.
        let mut nodes;
        let grid = if order == PatternOrder::Geodesic && k <= MAX_ODE_K && h > 0 {
            nodes = Nodes::new(
                surface,
                chart,
                cp.y,
                t1,
                t2,
                h as f64,
                (node_g, node_metric, node_hints),
            );
            // The box's corners are the first nodes: one beyond the chart (not merely off
            // the surface) means the pattern does not fit, before any grid is built.
            if nodes.corners_outside_chart() == Some(true) {
                continue 'charts;
            }
            geodesic_pattern(&mut nodes, k, zs, za, gamma)
        } else {
            None
        };
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
                let z = zs[idx(l, m)];
                cp.y + t1 * z.x + t2 * z.y
            } else {
                cp.y + g.offset(t1, t2, l as f64, m as f64)
            }
        };
        // Φ⁻¹ warm-started from the grid node nearest the sample (or the previous sample).
        let mut hint = None;
        let mut map = |l: i64, m: i64| {
            let y = y_at(l, m);
            if let Some(grid) = &grid {
                hint = grid.hint_near(zs[idx(l, m)]).or(hint);
            }
            match chart.phi_inv_hinted(y, &mut hint) {
                Some((b, _)) => Some(Some(surface.base_to_domain(b.quad, b.s, b.t))),
                None if off_surface(chart, y) => Some(None),
                None => None,
            }
        };
        // Corners first: a pattern that does not fit fails fast.
        if h > 0 {
            for (l, m) in [(-h, -h), (h, -h), (-h, h), (h, h)] {
                match map(l, m) {
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
                match map(l, m) {
                    Some(s) => out[idx(l, m)] = s,
                    None => continue 'charts,
                }
            }
        }
        if let Some(tol) = tolerance {
            let square = match &grid {
                Some(grid) => {
                    grid.pattern_is_square(surface, &zs[..k * k], &out[..k * k], pos, k, delta, tol)
                }
                _ => pattern_is_square(surface, &out[..k * k], k, delta, tol),
            };
            if !square {
                continue 'charts;
            }
        }
        return Some(v);
    }
    None
}

/// Working memory of [`sample_pattern`] (~60 KB), one per thread: zeroing these arrays
/// for every pattern cost 5–11% of chart sampling (callgrind). Nothing in it carries over
/// from one pattern to the next (`Nodes::state` says which node values are current), so
/// results do not depend on which thread sampled what before.
struct Scratch {
    /// Pattern coordinates of the samples.
    zs: [DVec2; MAX_ODE_K * MAX_ODE_K],
    /// The main rays' rim ends on the coarsest grid (compared with `zs`'s, [`ACCEPT_5`]).
    za: [DVec2; MAX_ODE_K * MAX_ODE_K],
    /// [`Nodes`]' values and Φ⁻¹ warm starts.
    g: [[DVec3; 2]; NODES * NODES],
    metric: [[f64; 3]; NODES * NODES],
    hints: [Option<ChartHint>; NODES * NODES],
    /// Christoffel symbols of the three nested grids.
    gamma: [GammaStore; 3],
    /// Limit positions of samples, where the check needs them.
    pos: [Option<DVec3>; MAX_ODE_K * MAX_ODE_K],
}

thread_local! {
    static SCRATCH: RefCell<Box<Scratch>> = RefCell::new(Box::new(Scratch {
        zs: [DVec2::ZERO; MAX_ODE_K * MAX_ODE_K],
        za: [DVec2::ZERO; MAX_ODE_K * MAX_ODE_K],
        g: [[DVec3::ZERO; 2]; NODES * NODES],
        metric: [[0.0; 3]; NODES * NODES],
        hints: [None; NODES * NODES],
        gamma: std::array::from_fn(|_| GammaStore {
            node: [[DVec2::ZERO; 3]; NODES * NODES],
            cell: [[[DVec2::ZERO; 4]; 3]; (NODES - 1) * (NODES - 1)],
        }),
        pos: [None; MAX_ODE_K * MAX_ODE_K],
    }));
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
/// Nodes per side of the finest Christoffel grid (the lattice [`Nodes`] evaluates on).
const NODES: usize = 9;
/// How far (pattern units) samples may lie outside the grid's box for the metric check.
const COVER_MARGIN: f64 = 0.25;
/// Lattice strides of the nested grids: 3, 5 and 9 nodes per side.
const STRIDES: [usize; 3] = [4, 2, 1];
/// A 5-node grid is accepted when the rim ends of its main rays differ from the 3-node
/// grid's by at most this (pattern units ≈ δ): grid errors fall as spacing², so the
/// 5-node grid is then about a third of it (0.2% of δ) off the geodesics; otherwise the
/// 9-node grid is used. The 3-node side is integrated in one RK4 step per ray (one cell),
/// so its step error is part of what is compared: measured against comparing every main
/// sample with unit steps, the same figures in the tests except Spot K = 5, whose chart
/// vs march fell 0.9 → 0.7% (δ 1) and 1.3 → 0.8% of δ (δ 2), and 4–5% fewer instructions.
const ACCEPT_5: f64 = 0.006;

/// Storage of [`Nodes`]: values, metric, warm starts.
type NodeStorage<'a> = (
    &'a mut [[DVec3; 2]; NODES * NODES],
    &'a mut [[f64; 3]; NODES * NODES],
    &'a mut [Option<ChartHint>; NODES * NODES],
);

/// ∂F/∂l, ∂F/∂m (F = f∘Φ⁻¹ in pattern coordinates z, chart point y = y0 + z.x·T1 +
/// z.y·T2) at the nodes of a NODES×NODES lattice over the pattern box [−h, h]²,
/// evaluated on demand one nested level at a time, so a coarse grid's evaluations are
/// reused by the finer ones.
struct Nodes<'a> {
    surface: &'a Surface,
    chart: &'a VertexChart,
    y0: DVec2,
    t1: DVec2,
    t2: DVec2,
    h: f64,
    /// Valid where `state` is 1.
    g: &'a mut [[DVec3; 2]; NODES * NODES],
    /// The metric in pattern coordinates, g_ab = ∂_aF·∂_bF: (ll, lm, mm), where `state` is 1.
    metric: &'a mut [[f64; 3]; NODES * NODES],
    /// 0: not evaluated, 1: on the surface, 2: outside the chart or off the surface.
    state: [u8; NODES * NODES],
    /// The Φ⁻¹ solution per node (`None` where `state` is 2): a warm start for nearby
    /// points. Valid where `state` is not 0.
    hints: &'a mut [Option<ChartHint>; NODES * NODES],
    /// The patch of the last node's limit evaluation: neighbouring nodes mostly share it,
    /// and their evaluations then skip the patch-tree descent (and the normal, which no
    /// node needs).
    leaf: LeafHint,
}

impl<'a> Nodes<'a> {
    /// Nodes over the pattern box, none evaluated yet; `storage` holds `g`, `metric` and
    /// `hints`.
    fn new(
        surface: &'a Surface,
        chart: &'a VertexChart,
        y0: DVec2,
        t1: DVec2,
        t2: DVec2,
        h: f64,
        storage: NodeStorage<'a>,
    ) -> Self {
        let (g, metric, hints) = storage;
        Nodes {
            surface,
            chart,
            y0,
            t1,
            t2,
            h,
            g,
            metric,
            state: [0; NODES * NODES],
            hints,
            leaf: LeafHint::default(),
        }
    }

    /// Evaluates the four corners of the pattern box first and tells whether one lies
    /// outside the chart (as opposed to on the surface or beyond an open boundary): then
    /// the pattern cannot fit and no other node is needed. A third of Spot's patterns
    /// that end in a regular chart are first tried in an extraordinary one (those come
    /// first, [`candidates`]) and fail here. `None` where the chart differential is
    /// singular.
    fn corners_outside_chart(&mut self) -> Option<bool> {
        let last = NODES - 1;
        let mut hint = None;
        for (i, j) in [(0, 0), (last, 0), (0, last), (last, last)] {
            self.eval_node(i, j, &mut hint)?;
            if self.state[j * NODES + i] == 2 && !off_surface(self.chart, self.chart_point(i, j)) {
                return Some(true);
            }
        }
        Some(false)
    }

    /// Lattice spacing in pattern units.
    fn spacing(&self) -> f64 {
        2.0 * self.h / (NODES - 1) as f64
    }

    /// The chart point of lattice node (i, j).
    #[inline]
    fn chart_point(&self, i: usize, j: usize) -> DVec2 {
        let step = self.spacing();
        let z = DVec2::new(-self.h + i as f64 * step, -self.h + j as f64 * step);
        self.y0 + self.t1 * z.x + self.t2 * z.y
    }

    /// Evaluates every node on the lattice lines of `stride` not evaluated yet. `None`
    /// where the chart differential is singular.
    fn ensure(&mut self, stride: usize) -> Option<()> {
        let mut hint = None;
        for j in (0..NODES).step_by(stride) {
            // Warm start from the row's first node on the level below.
            if j >= stride {
                hint = self.hints[(j - stride) * NODES].or(hint);
            }
            for i in (0..NODES).step_by(stride) {
                let n = j * NODES + i;
                if self.state[n] != 0 {
                    hint = self.hints[n].or(hint);
                    continue;
                }
                self.eval_node(i, j, &mut hint)?;
            }
        }
        Some(())
    }

    /// Evaluates lattice node (i, j) (Φ⁻¹ warm-started from `hint`, which it updates).
    /// `None` where the chart differential is singular.
    #[inline]
    fn eval_node(&mut self, i: usize, j: usize, hint: &mut Option<ChartHint>) -> Option<()> {
        let n = j * NODES + i;
        let Some((x, cp)) = self.chart.phi_inv_hinted(self.chart_point(i, j), hint) else {
            self.state[n] = 2;
            self.hints[n] = None;
            return Some(());
        };
        self.hints[n] = *hint;
        let e = self
            .surface
            .eval_base_derivs(x.quad, x.s, x.t, &mut self.leaf);
        let a = chart_differential(e.du, e.dv, cp.jacobian)?;
        let (t1, t2) = (self.t1, self.t2);
        let (gl, gm) = (a[0] * t1.x + a[1] * t1.y, a[0] * t2.x + a[1] * t2.y);
        self.g[n] = [gl, gm];
        self.metric[n] = [gl.dot(gl), gl.dot(gm), gm.dot(gm)];
        self.state[n] = 1;
        Some(())
    }
}

/// The geodesic pattern (pattern coordinates into `zs`) on the coarsest nested grid that
/// is accurate enough (see [`ACCEPT_5`]), and that grid; `None` if no grid can be built.
/// `za` and `gamma` are storage (`gamma[i]` for the grid of stride `STRIDES[i]`).
fn geodesic_pattern<'n, 'a>(
    nodes: &'n mut Nodes<'a>,
    k: usize,
    zs: &mut [DVec2],
    za: &mut [DVec2],
    gamma: &'n mut [GammaStore; 3],
) -> Option<ChristoffelGrid<'n, 'a>> {
    let [coarse, mid, fine] = STRIDES;
    let [g_coarse, g_mid, g_fine] = gamma;
    nodes.ensure(coarse)?;
    nodes.ensure(mid)?;
    // Whether the 5-node grid is accepted, and then whether all its nodes are on the surface.
    let accepted = {
        let nodes: &Nodes = nodes;
        match (
            ChristoffelGrid::new(nodes, coarse, g_coarse),
            ChristoffelGrid::new(nodes, mid, &mut *g_mid),
        ) {
            (Some(c), Some(m)) => {
                c.pattern(k, Rays::MainEnds, za);
                m.pattern(k, Rays::Main, zs);
                // Only the main rays' rim ends are compared (the rest of `za` is stale).
                let h = (k / 2) as i64;
                let close = [-h, h].iter().all(|&t| {
                    [(t, 0), (0, t), (t, t), (t, -t)].iter().all(|&(l, m)| {
                        let i = ((m + h) as usize) * k + (l + h) as usize;
                        (za[i] - zs[i]).length() <= ACCEPT_5
                    })
                });
                close.then_some(m.complete)
            }
            _ => None,
        }
    };
    if let Some(complete) = accepted {
        // The main rays are already integrated on this grid, whose Γ is in `g_mid`.
        let grid = ChristoffelGrid::with_gamma(nodes, mid, g_mid, complete);
        grid.pattern(k, Rays::Others, zs);
        Some(grid)
    } else {
        nodes.ensure(fine)?;
        let grid = ChristoffelGrid::new(nodes, fine, g_fine)?;
        grid.pattern(k, Rays::All, zs);
        Some(grid)
    }
}

/// Which geodesics of the pattern [`ChristoffelGrid::pattern`] integrates.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Rays {
    All,
    /// Axes and diagonals (where the nested grids are compared).
    Main,
    /// The rim ends of the axes and diagonals only, each ray integrated in steps of a grid
    /// cell (the coarsest grid's side of the comparison).
    MainEnds,
    /// All but the main ones.
    Others,
}

/// Γ of one nested grid, per node and per cell.
struct GammaStore {
    /// Per node: Γ(e_l, e_l), Γ(e_l, e_m), Γ(e_m, e_m) (the first n² entries).
    node: [[DVec2; 3]; NODES * NODES],
    /// Per cell (row-major, the first (n−1)² entries) and component: a, b, c, d of the
    /// bilinear interpolant a + b·x + (c + d·x)·y in the cell's local coordinates: the
    /// geodesic ODE evaluates Γ ~170 times per 5×5 pattern, and this form takes fewer
    /// operations than weighting four nodes (Spot K 9 −3% instructions, K 5 −1%).
    cell: [[[DVec2; 4]; 3]; (NODES - 1) * (NODES - 1)],
}

impl GammaStore {
    /// The cells' coefficients from the nodes' Γ (`nn` nodes per side).
    fn fill_cells(&mut self, nn: usize) {
        for iy in 0..nn - 1 {
            for ix in 0..nn - 1 {
                let i0 = iy * nn + ix;
                let (g00, g10, g01, g11) = (
                    &self.node[i0],
                    &self.node[i0 + 1],
                    &self.node[i0 + nn],
                    &self.node[i0 + nn + 1],
                );
                self.cell[iy * (nn - 1) + ix] = std::array::from_fn(|t| {
                    [
                        g00[t],
                        g10[t] - g00[t],
                        g01[t] - g00[t],
                        g11[t] - g10[t] - g01[t] + g00[t],
                    ]
                });
            }
        }
    }
}

/// Christoffel symbols of the surface in *pattern* coordinates z = (l, m) on the nodes of
/// one level of [`Nodes`] (every `stride`-th lattice node: 3, 5 or 9 per side over
/// [−h, h]²), bilinearly interpolated: the geodesic through the centre with initial
/// velocity (l, m) reaches sample (l, m) at time 1.
struct ChristoffelGrid<'n, 'a> {
    nodes: &'n Nodes<'a>,
    stride: usize,
    h: f64,
    step: f64,
    /// Nodes per side.
    n: usize,
    gamma: &'n GammaStore,
    /// 1 / step.
    inv_step: f64,
    /// Every node is on the surface (none copied from a neighbour).
    complete: bool,
}

impl<'n, 'a> ChristoffelGrid<'n, 'a> {
    /// The grid of lattice stride `stride` (its nodes must have been evaluated), its Γ
    /// computed into `gamma`.
    fn new(nodes: &'n Nodes<'a>, stride: usize, store: &'n mut GammaStore) -> Option<Self> {
        let gamma = &mut store.node;
        let nn = (NODES - 1) / stride + 1;
        let step = nodes.spacing() * stride as f64;
        let at = |i: usize, j: usize| (j * NODES + i) * stride;
        let valid = |i: isize, j: isize| {
            (0..nn as isize).contains(&i)
                && (0..nn as isize).contains(&j)
                && nodes.state[at(i as usize, j as usize)] == 1
        };
        let c = nn / 2;
        if !valid(c as isize, c as isize) {
            return None;
        }
        let pinv = |i: usize, j: usize| {
            let n = at(i, j);
            Pinv::with_gram(nodes.g[n], nodes.metric[n])
        };
        let mut complete = true;
        if (0..nn).all(|j| (0..nn).all(|i| nodes.state[at(i, j)] == 1)) {
            // Every node is on the surface (the common case): the stencils of `diff` below
            // by position alone, without its neighbour tests.
            for j in 0..nn {
                for i in 0..nn {
                    let dl = line_diff(|t| nodes.g[at(t, j)], i, nn, step);
                    let dm = line_diff(|t| nodes.g[at(i, t)], j, nn, step);
                    gamma[j * nn + i] = christoffel(&pinv(i, j)?, dl, dm);
                }
            }
        } else {
            // Derivative along a grid line through node (i, j) in direction (di, dj):
            // central where both neighbours exist, else second-order one-sided, else
            // first-order.
            let diff = |i: isize, j: isize, di: isize, dj: isize| -> Option<[DVec3; 2]> {
                let ok = |t: isize| valid(i + t * di, j + t * dj);
                let v = |t: isize| nodes.g[at((i + t * di) as usize, (j + t * dj) as usize)];
                Some(if ok(-1) && ok(1) {
                    stencil([(v(1), 1.0), (v(-1), -1.0)], 2.0 * step)
                } else if ok(1) && ok(2) {
                    stencil([(v(1), 4.0), (v(0), -3.0), (v(2), -1.0)], 2.0 * step)
                } else if ok(-1) && ok(-2) {
                    stencil([(v(0), 3.0), (v(-1), -4.0), (v(-2), 1.0)], 2.0 * step)
                } else if ok(1) {
                    stencil([(v(1), 1.0), (v(0), -1.0)], step)
                } else if ok(-1) {
                    stencil([(v(0), 1.0), (v(-1), -1.0)], step)
                } else {
                    return None;
                })
            };
            for j in 0..nn as isize {
                for i in 0..nn as isize {
                    if !valid(i, j) {
                        complete = false;
                        continue;
                    }
                    let (dl, dm) = (diff(i, j, 1, 0)?, diff(i, j, 0, 1)?);
                    let p = pinv(i as usize, j as usize)?;
                    gamma[j as usize * nn + i as usize] = christoffel(&p, dl, dm);
                }
            }
        }
        if !complete {
            // Nodes outside the chart or off the surface take the Γ of the nearest node
            // that has one (samples there are missing, or the pattern does not fit).
            for n in 0..nn * nn {
                let (i, j) = ((n % nn) as isize, (n / nn) as isize);
                if valid(i, j) {
                    continue;
                }
                let near = (0..nn * nn)
                    .filter(|&q| valid((q % nn) as isize, (q / nn) as isize))
                    .min_by_key(|&q| {
                        let (a, b) = ((q % nn) as isize, (q / nn) as isize);
                        (a - i).pow(2) + (b - j).pow(2)
                    })?;
                gamma[n] = gamma[near];
            }
        }
        if !gamma[..nn * nn].iter().flatten().all(|v| v.is_finite()) {
            return None;
        }
        store.fill_cells(nn);
        Some(Self::with_gamma(nodes, stride, store, complete))
    }

    /// A grid with Γ already computed (by [`Self::new`] for the same nodes and stride,
    /// which also found whether every node is on the surface: `complete`).
    fn with_gamma(
        nodes: &'n Nodes<'a>,
        stride: usize,
        gamma: &'n GammaStore,
        complete: bool,
    ) -> Self {
        let step = nodes.spacing() * stride as f64;
        ChristoffelGrid {
            nodes,
            stride,
            h: nodes.h,
            step,
            inv_step: 1.0 / step,
            n: (NODES - 1) / stride + 1,
            gamma,
            complete,
        }
    }

    /// The pattern: `zs[(m+h)·K + (l+h)]` = the geodesic's point for sample (l, m), for
    /// the samples on the chosen rays (primitive directions and their multiples).
    fn pattern(&self, k: usize, rays: Rays, zs: &mut [DVec2]) {
        let h = (k / 2) as i64;
        let idx = |l: i64, m: i64| ((m + h) as usize) * k + (l + h) as usize;
        zs[idx(0, 0)] = DVec2::ZERO;
        for m0 in -h..=h {
            for l0 in -h..=h {
                let main = l0.abs() <= 1 && m0.abs() <= 1;
                if gcd(l0.unsigned_abs(), m0.unsigned_abs()) != 1
                    || (matches!(rays, Rays::Main | Rays::MainEnds) && !main)
                    || (rays == Rays::Others && main)
                {
                    continue;
                }
                let reps = (h / l0.abs().max(m0.abs())) as usize;
                if rays == Rays::MainEnds {
                    let v = DVec2::new((l0 * h) as f64, (m0 * h) as f64);
                    self.ray(v, 1, |_, z| zs[idx(l0 * h, m0 * h)] = z);
                    continue;
                }
                self.ray(DVec2::new(l0 as f64, m0 as f64), reps, |r, z| {
                    zs[idx(l0 * r as i64, m0 * r as i64)] = z;
                });
            }
        }
    }
    /// Cell of pattern point z: its column and row and the local coordinates in it.
    #[inline]
    fn cell_xy(&self, z: DVec2) -> (usize, usize, f64, f64) {
        let nn = self.n;
        // Clamped to the last cell (weights up to 1 at its far side); i32 because a float
        // to usize conversion costs ~4 times as many instructions.
        let last = (nn - 2) as i32;
        let fx = ((z.x + self.h) * self.inv_step).clamp(0.0, (nn - 1) as f64);
        let fy = ((z.y + self.h) * self.inv_step).clamp(0.0, (nn - 1) as f64);
        let (ix, iy) = ((fx as i32).min(last), (fy as i32).min(last));
        (ix as usize, iy as usize, fx - ix as f64, fy - iy as f64)
    }

    /// The Φ⁻¹ warm start of the node nearest pattern point z.
    #[inline]
    fn hint_near(&self, z: DVec2) -> Option<ChartHint> {
        let n = (self.n - 1) as f64;
        let i = ((z.x + self.h) * self.inv_step).round().clamp(0.0, n) as usize;
        let j = ((z.y + self.h) * self.inv_step).round().clamp(0.0, n) as usize;
        self.nodes.hints[(j * NODES + i) * self.stride]
    }

    /// Whether every pair of adjacent samples is δ·(1 ± tol) apart and no cell is flipped,
    /// from the surface's metric on the grid where it is known instead of limit
    /// evaluations at the samples: the chord between adjacent samples is ∂F/∂z (bilinear
    /// between nodes) at their midpoint times their pattern offset (second-order accurate:
    /// the chord differs from it by O(|Δz|³) and the nodes are a sample step or less
    /// apart), and a cell of the pattern is flipped on the surface exactly when it is
    /// flipped in pattern coordinates (F is orientation-preserving there). Where the
    /// midpoint lies more than [`COVER_MARGIN`] outside the grid's box (strongly distorted
    /// charts carry rim geodesics past it: half of Spot's K = 9 patterns) or a node of its
    /// cell is not on the surface, the chord is measured between the two samples' limit
    /// positions instead (`pos`: storage for them). Samples off the surface (`None`) are
    /// skipped.
    #[allow(clippy::too_many_arguments)]
    fn pattern_is_square(
        &self,
        surface: &Surface,
        zs: &[DVec2],
        out: &[Option<DomainLocation>],
        pos: &mut [Option<DVec3>],
        k: usize,
        delta: f64,
        tol: f64,
    ) -> bool {
        let (lo, hi) = ((delta * (1.0 - tol)).powi(2), (delta * (1.0 + tol)).powi(2));
        pos[..k * k].fill(None);
        let mut exact = |i: usize, j: usize| {
            let mut at = |i: usize| {
                *pos[i].get_or_insert_with(|| {
                    let x = out[i].expect("only samples on the surface are measured");
                    surface.eval(x.domain, x.u, x.v).p
                })
            };
            (at(j) - at(i)).length_squared()
        };
        let r = self.h + COVER_MARGIN;
        let nn = self.n;
        let known = |i0: usize| {
            [i0, i0 + 1, i0 + nn, i0 + nn + 1].iter().all(|&n| {
                let (i, j) = (n % nn, n / nn);
                self.nodes.state[(j * NODES + i) * self.stride] == 1
            })
        };
        let metric = |a: DVec2, b: DVec2| -> Option<f64> {
            let mid = (a + b) * 0.5;
            if mid.x.abs() > r || mid.y.abs() > r {
                return None;
            }
            let (ix, iy, ax, ay) = self.cell_xy(mid);
            if !self.complete && !known(iy * nn + ix) {
                return None;
            }
            // Lattice indices of the cell's corners.
            let (n0, di, dj) = (
                (iy * NODES + ix) * self.stride,
                self.stride,
                NODES * self.stride,
            );
            let m = &self.nodes.metric;
            let (c00, c10, c01, c11) = (&m[n0], &m[n0 + di], &m[n0 + dj], &m[n0 + dj + di]);
            let w = [
                (1.0 - ax) * (1.0 - ay),
                ax * (1.0 - ay),
                (1.0 - ax) * ay,
                ax * ay,
            ];
            let g = |c: usize| c00[c] * w[0] + c10[c] * w[1] + c01[c] * w[2] + c11[c] * w[3];
            let d = b - a;
            Some(g(0) * d.x * d.x + 2.0 * g(1) * d.x * d.y + g(2) * d.y * d.y)
        };
        let mut chord = |i: usize, j: usize| metric(zs[i], zs[j]).unwrap_or_else(|| exact(i, j));
        for m in 0..k {
            for l in 0..k {
                let i = m * k + l;
                if out[i].is_none() {
                    continue;
                }
                if l > 0 && out[i - 1].is_some() && !(lo..=hi).contains(&chord(i - 1, i)) {
                    return false;
                }
                if m > 0 && out[i - k].is_some() && !(lo..=hi).contains(&chord(i - k, i)) {
                    return false;
                }
                // Cell with corner (l-1, m-1).
                if l > 0 && m > 0 && out[i - k - 1].is_some() && out[i - k].is_some() {
                    let a = zs[i - k - 1];
                    let (b, c) = (zs[i - k], zs[i - 1]);
                    if out[i - 1].is_some() && (b - a).perp_dot(c - a) <= 0.0 {
                        return false;
                    }
                }
            }
        }
        true
    }

    /// The geodesic acceleration −Γ(w, w) at pattern point z.
    #[inline]
    fn accel(&self, z: DVec2, w: DVec2) -> DVec2 {
        let (ix, iy, ax, ay) = self.cell_xy(z);
        let cell = &self.gamma.cell[iy * (self.n - 1) + ix];
        let q = [w.x * w.x, 2.0 * w.x * w.y, w.y * w.y];
        let mut a = DVec2::ZERO;
        for (&[c0, c1, c2, c3], q) in cell.iter().zip(q) {
            a += (c0 + c1 * ax + (c2 + c3 * ax) * ay) * q;
        }
        -a
    }

    /// Integrates the geodesic from z = 0 with velocity `v` (pattern units) for `reps`
    /// units of time and writes the point at each whole time into `out` (via `put`).
    fn ray(&self, v: DVec2, reps: usize, mut put: impl FnMut(usize, DVec2)) {
        // One RK4 step per sample step or per grid cell, whichever is longer (max norm):
        // the geodesics bend by a few % of δ per step, so the RK4 error is far below the
        // grid's (halving the step changed no sample by more than 0.03% of δ). Half as
        // many steps everywhere was too coarse (Spot K = 5: 1.3 → 3.8% of δ off the exact
        // map); on the 5-node grid of a K = 9 pattern, whose cells are two sample steps
        // wide (Γ is bilinear within a cell), a step per cell moved no sample by more than
        // 1.1e-3 δ, left every test figure as it was and saved 7% of the instructions.
        let sub = ((v.x.abs().max(v.y.abs()) / self.step.max(1.0)).ceil() as usize).max(1);
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

    /// [`Self::new`] with the Gram matrix AᵀA already known (`gram`: a₀·a₀, a₀·a₁, a₁·a₁,
    /// as [`Nodes`] stores it): the same numbers without the three dot products.
    fn with_gram(a: [DVec3; 2], gram: [f64; 3]) -> Option<Self> {
        let g = DMat2::from_cols(DVec2::new(gram[0], gram[1]), DVec2::new(gram[1], gram[2]));
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

/// Σ w·g over a finite-difference stencil of node values, divided by `d`: one function
/// for [`ChristoffelGrid::new`]'s complete and general grids, so both do the same
/// floating-point operations in the same order.
#[inline]
fn stencil<const N: usize>(terms: [([DVec3; 2], f64); N], d: f64) -> [DVec3; 2] {
    let mut r = [DVec3::ZERO; 2];
    for (g, w) in terms {
        r[0] += g[0] * w;
        r[1] += g[1] * w;
    }
    [r[0] / d, r[1] / d]
}

/// Derivative at node `i` of a grid line of `nn` ≥ 3 nodes, all on the surface (`v(t)`:
/// the value at node t): central inside, second-order one-sided at the ends.
#[inline]
fn line_diff(v: impl Fn(usize) -> [DVec3; 2], i: usize, nn: usize, step: f64) -> [DVec3; 2] {
    if i == 0 {
        stencil([(v(1), 4.0), (v(0), -3.0), (v(2), -1.0)], 2.0 * step)
    } else if i == nn - 1 {
        stencil([(v(i), 3.0), (v(i - 1), -4.0), (v(i - 2), 1.0)], 2.0 * step)
    } else {
        stencil([(v(i + 1), 1.0), (v(i - 1), -1.0)], 2.0 * step)
    }
}

/// Γ(e_l, e_l), Γ(e_l, e_m), Γ(e_m, e_m) at a node from ∂_l G and ∂_m G (G = [∂F/∂l
/// ∂F/∂m]): the tangential parts of F's second derivatives, in pattern coordinates.
#[inline]
fn christoffel(p: &Pinv, dl: [DVec3; 2], dm: [DVec3; 2]) -> [DVec2; 3] {
    let flm = (dl[1] + dm[0]) * 0.5;
    [p.apply(dl[0]), p.apply(flm), p.apply(dm[1])]
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
