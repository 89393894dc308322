//! Reference exponential map on the exact limit surface (slow; for tests and measurements).
//!
//! Sample (l, m) of an ideal pattern is exp_x(δ·(l·v1 + m·v2)): the end of the geodesic
//! that leaves the centre x in direction l·v1 + m·v2 and has length |(l, m)|·δ. Both
//! samplers approximate it — marching by straightest paths on a triangulated copy of the
//! surface, chart sampling by a truncated Taylor expansion of the geodesics in chart
//! coordinates — so this module is the yardstick for both.
//!
//! The geodesic is the path of a free particle constrained to the surface; we integrate it
//! with RATTLE (the standard second-order integrator for constrained motion), on the exact
//! limit surface:
//! 1. q' = p + Δt·v + α·N(p), with α (and q' on the surface) found by Newton's method on
//!    the base-quad parameter of q' (`Surface::eval_base`; each update is a straight move
//!    in parameter space, continued across base-quad edges by `Surface::walk_base`);
//! 2. v' = P(q')·(q' − p)/Δt, P(q') the projection on the tangent plane at q'.
//!
//! The global error is O(Δt²): halving the step divides it by four
//! ([`exp_pattern`] can report the difference between n and 2n substeps). Paths that leave
//! the surface through an open boundary end there (`None`). So do paths that cross an
//! infinitely sharp crease (a step that turns the normal by more than [`CREASE_TURN_DEG`]
//! on a surface with creases): the projection along the old normal does not unfold across
//! a crease, and callers continue on the triangulated mesh, which does.

use crate::field::Frame;
use glam::DVec3;
use subdiv::surface::{LeafHint, LimitDerivs};
use subdiv::{BaseLocation, DomainLocation, LimitSample, Surface};

/// Where a geodesic ended.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GeodesicPoint {
    pub loc: BaseLocation,
    pub p: DVec3,
}

/// The constraint of one RATTLE projection: the surface point q with (q − x)·a =
/// (q − x)·b = 0 (a, b spanning the tangent plane at the previous point: q is x moved along
/// the previous normal), to within `tol` (mesh units).
struct Constraint {
    x: DVec3,
    a: DVec3,
    b: DVec3,
    tol: f64,
}

impl Constraint {
    /// The residual of surface point `p`.
    #[inline]
    fn residual(&self, p: DVec3) -> (f64, f64) {
        let r = p - self.x;
        (r.dot(self.a), r.dot(self.b))
    }
}

/// Newton's method for the point of constraint `c`, starting at `from` (whose limit sample
/// is `e_from`). `None` if the point is off the surface (beyond an open boundary) or Newton
/// does not converge. The trial points are evaluated without their normal, which only the
/// point returned needs, through `hint` (the patch of the last trial point).
///
/// `guess` is a predicted parameter move from `from`: Newton starts there instead if its
/// residual is below half of `from`'s. The flag returned tells whether the point is in
/// `from`'s base quad with no base-quad edge crossed on the way (the move is then the
/// difference of the parameters).
fn project_along(
    surface: &Surface,
    from: BaseLocation,
    e_from: &LimitSample,
    c: &Constraint,
    guess: Option<(f64, f64)>,
    hint: &mut LeafHint,
) -> Option<(BaseLocation, LimitSample, bool)> {
    let eval =
        |l: BaseLocation, hint: &mut LeafHint| surface.eval_base_derivs(l.quad, l.s, l.t, hint);
    let mut loc = from;
    let mut e = LimitDerivs::from(*e_from);
    let mut same_quad = true;
    if let Some((ds, dt)) = guess {
        if let Some((next, crossed)) = surface.walk_base(from, ds, dt) {
            let en = eval(next, hint);
            let (r0, r1) = (c.residual(e.p), c.residual(en.p));
            let g0 = r0.0.powi(2) + r0.1.powi(2);
            let g1 = r1.0.powi(2) + r1.1.powi(2);
            if g1 < 0.25 * g0 {
                (loc, e, same_quad) = (next, en, crossed == 0);
            }
        }
    }
    for _ in 0..60 {
        let g = c.residual(e.p);
        let gn = (g.0 * g.0 + g.1 * g.1).sqrt();
        if gn <= c.tol {
            return Some((loc, e.sample(), same_quad && loc.quad == from.quad));
        }
        let (a, b) = (c.a, c.b);
        let (j00, j01, j10, j11) = (a.dot(e.du), a.dot(e.dv), b.dot(e.du), b.dot(e.dv));
        let det = j00 * j11 - j01 * j10;
        if !det.is_finite() || det.abs() < 1e-300 {
            return None;
        }
        let mut ds = -(j11 * g.0 - j01 * g.1) / det;
        let mut dt = -(-j10 * g.0 + j00 * g.1) / det;
        // Cap the move (a safeguard next to extraordinary vertices, where the
        // parameterisation is singular), then backtrack until the residual falls.
        let len = (ds * ds + dt * dt).sqrt();
        if len > 0.2 {
            ds *= 0.2 / len;
            dt *= 0.2 / len;
        }
        let mut accepted = false;
        for _ in 0..30 {
            if let Some((next, crossed)) = surface.walk_base(loc, ds, dt) {
                let en = eval(next, hint);
                let rn = c.residual(en.p);
                let gn2 = (rn.0.powi(2) + rn.1.powi(2)).sqrt();
                if gn2 < gn || gn2 <= c.tol {
                    same_quad &= crossed == 0;
                    loc = next;
                    e = en;
                    accepted = true;
                    break;
                }
            }
            ds *= 0.5;
            dt *= 0.5;
        }
        if !accepted {
            // No move along the Newton direction reduces the residual: either the point is
            // beyond an open boundary or Newton stalled.
            return None;
        }
    }
    None
}

/// Projection tolerance of the marching geodesics, in units of their longest step: each
/// RATTLE point is on the surface to 1e-7 of a step (5e-8 δ). Measured: the marched
/// patterns move by at most ~5e-6 δ against 1e-10 of the geodesic's length (the
/// integration error is ~1e-3 δ), with 10–15% fewer evaluations.
const PROJECTION_TOL: f64 = 1e-7;
/// A RATTLE step whose normal turns by more than this (degrees) on a surface with crease
/// tags is taken to cross an infinitely sharp crease (see the module doc). Smooth parts turn
/// the normal by the step times the curvature, ~1° per step of 0.5 δ at texel scales.
pub const CREASE_TURN_DEG: f64 = 10.0;

/// Unit vectors spanning the plane normal to `n`.
fn plane_axes(n: DVec3) -> (DVec3, DVec3) {
    let a = n.any_orthonormal_vector();
    (a, n.cross(a))
}

/// The geodesic from `start` (whose limit sample is `e0`) with initial tangent velocity `v`
/// (its length is the arc length covered per segment), sampled after each of `segments`
/// segments of `substeps` RATTLE steps each: `out[i]` is the point at arc length
/// (i + 1)·|v|, or `None` from the first point beyond an open boundary on. `tol` is the
/// projection tolerance (mesh units).
pub fn geodesic(
    surface: &Surface,
    start: BaseLocation,
    v: DVec3,
    segments: usize,
    substeps: usize,
    tol: f64,
    out: &mut Vec<Option<GeodesicPoint>>,
) {
    out.clear();
    let e0 = surface.eval_base(start.quad, start.s, start.t);
    let mut state = Some(State::new(start, e0, v, LeafHint::default()));
    for _ in 0..segments {
        state = state.and_then(|st| st.advance(surface, substeps, tol));
        out.push(state.map(|st| GeodesicPoint {
            loc: st.loc,
            p: st.e.p,
        }));
    }
}

/// RATTLE state: point (base location and its limit sample), tangent velocity, and the
/// second-order part of the last step's parameter move.
#[derive(Clone, Copy)]
struct State {
    loc: BaseLocation,
    e: LimitSample,
    v: DVec3,
    /// The last step's parameter move less its first-order part (the Newton step from the
    /// previous point), in the base quad of `loc`; `None` at the start or after a step
    /// across a base-quad edge. It changes slowly from step to step, so the next step's
    /// Newton starts from its first-order move plus this (measured: 10% fewer evaluations
    /// per step next to Spot's extraordinary vertices; the third derivatives jump at the
    /// patch boundaries, which are dense there, so the guess is 5x better, not O(Δt³)).
    corr: Option<(f64, f64)>,
    /// The patch of the last point evaluated (consecutive steps are close).
    hint: LeafHint,
}

impl State {
    fn new(loc: BaseLocation, e: LimitSample, v: DVec3, hint: LeafHint) -> State {
        State {
            loc,
            e,
            v: v - e.n * e.n.dot(v),
            corr: None,
            hint,
        }
    }

    /// `substeps` RATTLE steps of 1/substeps of the velocity each; `None` past an open
    /// boundary or if a projection fails.
    fn advance(mut self, surface: &Surface, substeps: usize, tol: f64) -> Option<State> {
        let dt = 1.0 / substeps as f64;
        for _ in 0..substeps {
            let (a, b) = plane_axes(self.e.n);
            let d = self.v * dt;
            let x = self.e.p + d;
            // First-order parameter move: the Newton step from the current point.
            let (j00, j01) = (a.dot(self.e.du), a.dot(self.e.dv));
            let (j10, j11) = (b.dot(self.e.du), b.dot(self.e.dv));
            let det = j00 * j11 - j01 * j10;
            let (ga, gb) = (d.dot(a), d.dot(b));
            let lin = ((j11 * ga - j01 * gb) / det, (j00 * gb - j10 * ga) / det);
            let lin = (lin.0.is_finite() && lin.1.is_finite()).then_some(lin);
            let guess = match (lin, self.corr) {
                (Some(l), Some(c)) => {
                    let g = (l.0 + c.0, l.1 + c.1);
                    (g.0 * g.0 + g.1 * g.1 <= 0.04).then_some(g)
                }
                _ => None,
            };
            let c = Constraint { x, a, b, tol };
            let (nl, e, same) =
                project_along(surface, self.loc, &self.e, &c, guess, &mut self.hint)?;
            if surface.base.has_tags() && e.n.dot(self.e.n) < CREASE_TURN_DEG.to_radians().cos() {
                return None;
            }
            self.corr = match (lin, same) {
                (Some(l), true) => Some((nl.s - self.loc.s - l.0, nl.t - self.loc.t - l.1)),
                _ => None,
            };
            let vh = (e.p - self.e.p) / dt;
            self.v = vh - e.n * e.n.dot(vh);
            self.loc = nl;
            self.e = e;
        }
        Some(self)
    }
}

/// A geodesic integrated piece by piece, with steps of at most `max_step`: what marching
/// uses next to extraordinary vertices, where a path reads off several pattern samples
/// along one geodesic (integrating each from the start again would cost quadratically in
/// their number).
pub struct GeodesicPath {
    /// `None` from the first point past an open boundary (or a failed projection) on.
    state: Option<State>,
    /// Arc length per unit of integration time: the length of the last piece asked for.
    speed: f64,
    max_step: f64,
    tol: f64,
}

impl GeodesicPath {
    /// The geodesic from `start` (whose limit sample is `e0`: paths share their starts)
    /// with initial tangent `v`; `hint` is the patch of `start` (or of a point near it) if
    /// known.
    pub fn new(
        start: BaseLocation,
        e0: &LimitSample,
        v: DVec3,
        max_step: f64,
        hint: LeafHint,
    ) -> GeodesicPath {
        let speed = v.length();
        GeodesicPath {
            state: (speed.is_finite() && max_step > 0.0).then(|| State::new(start, *e0, v, hint)),
            speed,
            max_step,
            tol: PROJECTION_TOL * max_step,
        }
    }

    /// On by arc length `len`, in ⌈`len` / `max_step`⌉ RATTLE steps: where the path is
    /// then (`None` from the first point past an open boundary on).
    pub fn advance(&mut self, surface: &Surface, len: f64) -> Option<BaseLocation> {
        let mut st = self.state?;
        if len == 0.0 {
            return Some(st.loc);
        }
        if len != self.speed && self.speed > 0.0 {
            // RATTLE covers one velocity per unit time: rescale it (the geodesic's speed
            // is constant; the drift of the velocity's length is the integration error's).
            // A zero tangent stays zero: the path stays at its start.
            st.v *= len / self.speed;
            self.speed = len;
        }
        let steps = ((len / self.max_step).ceil() as usize).clamp(1, 1 << 16);
        self.state = st.advance(surface, steps, self.tol);
        self.state.map(|st| st.loc)
    }
}

/// The geodesic from `start` (whose limit sample is `e0`, its patch `hint`) with initial
/// tangent `v`, ended after each of `segments` segments of arc length |v|: `at(j, end)` for
/// j = 1..=segments, `end` `None` from the first point past an open boundary (or a failed
/// projection) on. Each segment is ⌈|v| / `max_step`⌉ RATTLE steps, so the point after j
/// segments is integrated with steps no longer than a single piece of arc length j·|v|
/// would take. What marching uses for the multiples (j·l0, j·m0) of a primitive pattern
/// direction (one path each).
#[allow(clippy::too_many_arguments)]
pub fn geodesic_ends_from(
    surface: &Surface,
    start: BaseLocation,
    e0: &LimitSample,
    v: DVec3,
    segments: usize,
    max_step: f64,
    hint: LeafHint,
    mut at: impl FnMut(usize, Option<BaseLocation>),
) {
    let len = v.length();
    let mut path = GeodesicPath::new(start, e0, v, max_step, hint);
    for j in 1..=segments {
        at(j, path.advance(surface, len));
    }
}

/// The reference pattern: `out[(m+h)·K + (l+h)]` = exp_x(δ·(l·v1 + m·v2)) (3D position and
/// domain point), `None` past an open boundary. Each primitive direction (l0, m0) (gcd 1)
/// is integrated once, with `substeps` RATTLE steps per |(l0, m0)|·δ of arc, and its
/// multiples are read off along the way. Returns the largest distance (mesh units) to the
/// same pattern computed with half the substeps when `check` is set (the integration error
/// of the half-step run is about a quarter of it), else 0.
#[allow(clippy::too_many_arguments)]
pub fn exp_pattern(
    surface: &Surface,
    centre: DomainLocation,
    frame: &Frame,
    delta: f64,
    k: usize,
    substeps: usize,
    check: bool,
    out: &mut [Option<(DomainLocation, DVec3)>],
) -> f64 {
    let h = (k / 2) as i64;
    let start = surface.base_location(centre);
    let e0 = surface.eval_base(start.quad, start.s, start.t);
    let scale = e0.p.length().max(delta).max(1.0);
    let tol = 1e-14 * scale;
    let idx = |l: i64, m: i64| ((m + h) as usize) * k + (l + h) as usize;
    out[idx(0, 0)] = Some((centre, e0.p));
    let mut path = Vec::new();
    let mut coarse = Vec::new();
    let mut diff: f64 = 0.0;
    for m0 in -h..=h {
        for l0 in -h..=h {
            if gcd(l0.unsigned_abs(), m0.unsigned_abs()) != 1 {
                continue;
            }
            let v = (frame.v1 * l0 as f64 + frame.v2 * m0 as f64) * delta;
            // Keep the length on the tangent plane of the exact centre.
            let vt = v - e0.n * e0.n.dot(v);
            let vt = vt * (v.length() / vt.length().max(1e-300));
            let reps = (h / l0.abs().max(m0.abs())) as usize;
            geodesic(surface, start, vt, reps, substeps, tol, &mut path);
            if check {
                geodesic(surface, start, vt, reps, substeps / 2, tol, &mut coarse);
                for (a, b) in path.iter().zip(&coarse) {
                    if let (Some(a), Some(b)) = (a, b) {
                        diff = diff.max((a.p - b.p).length());
                    }
                }
            }
            for (j, g) in path.iter().enumerate() {
                let j = j as i64 + 1;
                out[idx(l0 * j, m0 * j)] =
                    g.map(|g| (surface.base_to_domain(g.loc.quad, g.loc.s, g.loc.t), g.p));
            }
        }
    }
    diff
}

/// Greatest common divisor (gcd(0, 0) = 0).
pub fn gcd(a: u64, b: u64) -> u64 {
    if b == 0 {
        a
    } else {
        gcd(b, a % b)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use subdiv::{ControlMesh, DomainId};

    /// On a plane the reference is the exact square grid (convergence on curved meshes:
    /// tests/sampling_truth.rs).
    #[test]
    fn reference_is_exact_on_a_plane() {
        let s = Surface::new(ControlMesh::grid(8));
        let c = DomainLocation {
            domain: DomainId(8 * 4 + 3),
            u: 0.3,
            v: 0.6,
        };
        let e = s.eval(c.domain, c.u, c.v);
        let v1 = DVec3::new(1.0, 0.4, 0.0).normalize();
        let frame = Frame {
            v1,
            v2: e.n.cross(v1),
            n: e.n,
        };
        let mut out = vec![None; 25];
        exp_pattern(&s, c, &frame, 0.1, 5, 4, false, &mut out);
        for m in -2..=2i64 {
            for l in -2..=2i64 {
                let (_, p) = out[((m + 2) * 5 + l + 2) as usize].unwrap();
                let want = e.p + (frame.v1 * l as f64 + frame.v2 * m as f64) * 0.1;
                assert!((p - want).length() < 1e-12, "{l} {m}: {p} vs {want}");
            }
        }
    }
}
