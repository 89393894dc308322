//! K×K surface neighbourhoods at step δ: the one sampler interface both synthesizers use.
//!
//! `Sampler::sample(centre, δ, K, kind, out)` writes, for every pattern offset (l, m) with
//! l, m = −h..h (K = 2h + 1, any odd K), the surface point reached from `centre` by
//! l·δ·v1 + m·δ·v2 — as a (domain, u, v) — or `None` where that point is off the surface
//! (past an open boundary). Offsets are stored row by row: `out[(m + h)·K + (l + h)]`; the
//! centre is `out[h·K + h]`. l runs along v1 (the example's x, columns), m along v2 =
//! n × v1 (the example's y, rows).
//!
//! Two samplers (see docs/sampling.md):
//! - [`SamplerKind::Chart`]: chart sampling (000 §4.2, [`chart`]); where the pattern does
//!   not fit any vertex chart around the centre it falls back to marching, and the fallback
//!   is counted ([`SamplerStats::fallbacks`]).
//! - [`SamplerKind::March`]: surface marching (000 §4.1, [`march`]) on the field's limit
//!   mesh.
//!
//! No allocation per pattern or sample: the caller owns `out`; statistics are atomics, so one
//! `Sampler` is shared by all threads (results never depend on the thread count — each
//! pattern is computed independently of the others).

pub mod chart;
pub mod geodesic;
pub mod march;

use crate::field::{Frame, OrientationField};
pub use chart::PatternOrder;
use glam::DVec3;
use march::{MarchMesh, PathEnd};
use std::sync::atomic::{AtomicU64, Ordering::Relaxed};
use std::sync::OnceLock;
use subdiv::surface::LeafHint;
use subdiv::{BaseLocation, Charts, DomainLocation, Surface, VertexId};

/// Default relative spacing tolerance of accepted chart patterns (4%: inside the 5% that
/// issue 3 asks of every pattern, with room for the 3D-vs-surface distance difference).
pub const DEFAULT_TOLERANCE: f64 = 0.04;

/// Longest integration step (in δ) of marching paths on the exact limit surface next to
/// extraordinary vertices.
const EXACT_STEP: f64 = 0.5;

/// Which sampler to use.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum SamplerKind {
    /// Chart sampling, marching where the pattern fits no chart.
    Chart,
    /// Surface marching.
    March,
}

impl std::str::FromStr for SamplerKind {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "chart" => Ok(SamplerKind::Chart),
            "march" => Ok(SamplerKind::March),
            _ => Err(format!("unknown sampler '{s}' (expected chart or march)")),
        }
    }
}

impl SamplerKind {
    pub fn name(self) -> &'static str {
        match self {
            SamplerKind::Chart => "chart",
            SamplerKind::March => "march",
        }
    }
}

/// How one pattern was sampled.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Method {
    /// In the chart of this base-mesh vertex.
    Chart(VertexId),
    /// By marching (asked for, or as the fallback of chart sampling).
    March,
}

/// What [`Sampler::sample`] did for one pattern.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PatternInfo {
    pub method: Method,
    /// Chart sampling was asked for but the pattern fit no chart.
    pub fallback: bool,
    /// Samples off the surface (`None`).
    pub missing: usize,
}

/// Counters over all patterns sampled so far (sums, so independent of the thread count).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct SamplerStats {
    pub patterns: u64,
    /// Patterns asked for with [`SamplerKind::Chart`].
    pub chart_requests: u64,
    /// ... of which fit no chart and were marched.
    pub fallbacks: u64,
    pub samples: u64,
    pub missing: u64,
    /// Marching paths that hit the crossing cap (should stay 0).
    pub stalled: u64,
}

impl SamplerStats {
    /// Share of chart requests that fell back to marching.
    pub fn fallback_rate(&self) -> f64 {
        if self.chart_requests == 0 {
            0.0
        } else {
            self.fallbacks as f64 / self.chart_requests as f64
        }
    }
}

#[derive(Default)]
struct Counters {
    patterns: AtomicU64,
    chart_requests: AtomicU64,
    fallbacks: AtomicU64,
    samples: AtomicU64,
    missing: AtomicU64,
    stalled: AtomicU64,
}

/// Neighbourhood sampler over one surface and orientation field.
pub struct Sampler<'a> {
    surface: &'a Surface,
    field: &'a OrientationField,
    charts: Charts,
    march: OnceLock<MarchMesh>,
    counters: Counters,
    order: PatternOrder,
    tolerance: Option<f64>,
    /// Limit positions of the extraordinary, open-boundary and crease vertices of the field's limit
    /// mesh, where chart patterns are marched instead (built on first use).
    irregular: OnceLock<Option<kiddo::ImmutableKdTree<f64, 3>>>,
}

/// Chart patterns whose reach comes within this many steps δ (beyond the pattern's
/// corner, h·√2·δ) of an extraordinary or open-boundary vertex, or of an infinitely sharp
/// crease, are marched instead: the chart's Christoffel symbols are singular at an
/// extraordinary vertex and the grid is cut by an open boundary, so chart patterns there
/// drifted 5–22% of δ from the exact exponential map, while marching follows it to ~2%
/// (docs/sampling.md); across a crease the metric jumps, so a chart must not straddle one:
/// marching unfolds across it instead.
pub const EXTRAORDINARY_MARGIN: f64 = 2.0;

/// Base point used for derivatives: a corner (a possible extraordinary vertex, where Df and
/// DΦ are singular) is moved 1e-7 inside; the chart map g = f∘Φ⁻¹ is C¹ there, so the
/// pattern is the limit of the patterns of nearby points.
fn regular_point(loc: BaseLocation) -> BaseLocation {
    const EPS: f64 = 1e-7;
    let near = |x: f64| !(EPS..=1.0 - EPS).contains(&x);
    if near(loc.s) && near(loc.t) {
        BaseLocation {
            quad: loc.quad,
            s: loc.s.clamp(EPS, 1.0 - EPS),
            t: loc.t.clamp(EPS, 1.0 - EPS),
        }
    } else {
        loc
    }
}

impl<'a> Sampler<'a> {
    /// Builds the vertex charts; the marching mesh is built on first use of marching.
    pub fn new(surface: &'a Surface, field: &'a OrientationField) -> Self {
        Sampler {
            surface,
            field,
            charts: Charts::new(surface),
            march: OnceLock::new(),
            counters: Counters::default(),
            order: PatternOrder::default(),
            tolerance: Some(DEFAULT_TOLERANCE),
            irregular: OnceLock::new(),
        }
    }

    /// Distance from `p` to the nearest extraordinary or open-boundary vertex (∞ if none).
    fn irregular_vertex_distance(&self, p: DVec3) -> f64 {
        let tree = self.irregular.get_or_init(|| {
            let lm = self.field.limit_mesh();
            let pts: Vec<[f64; 3]> = (0..lm.mesh.num_vertices())
                .filter(|&v| {
                    let v = VertexId::from_idx(v);
                    !lm.mesh.is_regular_vertex(v) || lm.mesh.is_boundary_vertex(v) || lm.is_sided(v)
                })
                .map(|v| lm.position[v].to_array())
                .collect();
            if pts.is_empty() {
                None
            } else {
                kiddo::ImmutableKdTree::new_from_slice(&pts).ok()
            }
        });
        match tree {
            None => f64::INFINITY,
            Some(t) => t
                .query(&p.to_array())
                .nearest_one::<kiddo::SquaredEuclidean<f64>>()
                .execute()
                .distance
                .sqrt(),
        }
    }

    /// Chart patterns whose adjacent samples are not δ·(1 ± tol) apart (or that fold) are
    /// rejected (next chart, then marching); `None` accepts every pattern that fits a
    /// chart, as the paper does. Default [`DEFAULT_TOLERANCE`].
    pub fn with_tolerance(mut self, tol: Option<f64>) -> Self {
        self.tolerance = tol;
        self
    }

    /// How closely chart patterns follow geodesics (default [`PatternOrder::Geodesic`];
    /// [`PatternOrder::Linear`] is the paper's step 3 as printed).
    pub fn with_order(mut self, order: PatternOrder) -> Self {
        self.order = order;
        self
    }

    pub fn surface(&self) -> &Surface {
        self.surface
    }

    pub fn field(&self) -> &OrientationField {
        self.field
    }

    /// The triangulated limit mesh marching walks on.
    pub fn march_mesh(&self) -> &MarchMesh {
        self.march
            .get_or_init(|| MarchMesh::new(self.field.limit_mesh()))
    }

    /// The field's frame at a domain point.
    pub fn frame(&self, centre: DomainLocation) -> Frame {
        self.field
            .frame(self.surface, centre.domain, centre.u, centre.v)
    }

    /// The frame [`Self::sample`] orients the pattern of `centre` by (at an extraordinary
    /// corner, the limit of the frames of nearby points).
    pub fn pattern_frame(&self, centre: DomainLocation) -> Frame {
        let loc = regular_point(self.surface.base_location(centre));
        let e = self.surface.eval_base(loc.quad, loc.s, loc.t);
        self.field
            .frame_at(self.surface.base_location(centre), e.n, e.du)
    }

    /// The K×K neighbourhood of `centre` at step `delta` (see the module doc), oriented by
    /// the field. `out.len()` must be at least K², K odd.
    pub fn sample(
        &self,
        centre: DomainLocation,
        delta: f64,
        k: usize,
        kind: SamplerKind,
        out: &mut [Option<DomainLocation>],
    ) -> PatternInfo {
        self.sample_impl(centre, None, delta, k, kind, false, out)
    }

    /// As [`Self::sample`] with a given frame (e.g. from
    /// [`OrientationField::texel_frames`]; only v1, v2 are used).
    pub fn sample_with_frame(
        &self,
        centre: DomainLocation,
        frame: &Frame,
        delta: f64,
        k: usize,
        kind: SamplerKind,
        out: &mut [Option<DomainLocation>],
    ) -> PatternInfo {
        self.sample_impl(centre, Some(frame), delta, k, kind, false, out)
    }

    /// As [`Self::sample_with_frame`], but only the samples of the *sparse* K×K block need
    /// be laid out: those within K/4 steps of the centre (both offsets) and those whose
    /// offsets are both even ([`sparse_keeps`]; K = 9: the inner 5x5 and every other
    /// sample of the outer rings, 41 of 81); the others may be `None`. *Why*: marching
    /// walks one path per primitive direction (l, m); a sparse block needs only the 16
    /// with |l|, |m| ≤ K/4 (each kept sample of the outer rings is a multiple of one of
    /// them), a third of a 9x9 block's 48 paths of the same reach.
    pub fn sample_sparse(
        &self,
        centre: DomainLocation,
        frame: &Frame,
        delta: f64,
        k: usize,
        kind: SamplerKind,
        out: &mut [Option<DomainLocation>],
    ) -> PatternInfo {
        self.sample_impl(centre, Some(frame), delta, k, kind, true, out)
    }

    #[allow(clippy::too_many_arguments)]
    fn sample_impl(
        &self,
        centre: DomainLocation,
        frame: Option<&Frame>,
        delta: f64,
        k: usize,
        kind: SamplerKind,
        sparse: bool,
        out: &mut [Option<DomainLocation>],
    ) -> PatternInfo {
        assert!(k % 2 == 1, "pattern size {k} must be odd");
        assert!(
            out.len() >= k * k,
            "output buffer holds {} < {k}x{k}",
            out.len()
        );
        let loc = self.surface.base_location(centre);
        let reg = regular_point(loc);
        let e = self.surface.eval_base(reg.quad, reg.s, reg.t);
        let own;
        let frame = match frame {
            Some(f) => f,
            None => {
                own = self.field.frame_at(loc, e.n, e.du);
                &own
            }
        };
        let c = &self.counters;
        c.patterns.fetch_add(1, Relaxed);
        c.samples.fetch_add((k * k) as u64, Relaxed);
        let mut info = PatternInfo {
            method: Method::March,
            fallback: false,
            missing: 0,
        };
        if kind == SamplerKind::Chart {
            c.chart_requests.fetch_add(1, Relaxed);
            let h = (k / 2) as f64;
            let reach = (h * std::f64::consts::SQRT_2 + EXTRAORDINARY_MARGIN) * delta;
            let chart = if self.irregular_vertex_distance(e.p) <= reach {
                None
            } else {
                chart::sample_pattern(
                    self.surface,
                    &self.charts,
                    centre,
                    reg,
                    e.du,
                    e.dv,
                    frame,
                    delta,
                    k,
                    self.order,
                    self.tolerance,
                    out,
                )
            };
            match chart {
                Some(v) => info.method = Method::Chart(v),
                None => {
                    c.fallbacks.fetch_add(1, Relaxed);
                    info.fallback = true;
                }
            }
        }
        if info.method == Method::March {
            if sparse {
                // Samples the sparse paths do not reach stay None, not a chart's leftovers.
                out[..k * k].fill(None);
            }
            let stalled = self.march_pattern(centre, loc, e.p, e.n, frame, delta, k, sparse, out);
            if stalled > 0 {
                c.stalled.fetch_add(stalled as u64, Relaxed);
            }
        }
        let h = (k / 2) as i64;
        info.missing = out[..k * k]
            .iter()
            .enumerate()
            .filter(|&(i, s)| {
                let (l, m) = (i as i64 % k as i64 - h, i as i64 / k as i64 - h);
                s.is_none() && (!sparse || sparse_keeps(k, l, m))
            })
            .count();
        if info.missing > 0 {
            c.missing.fetch_add(info.missing as u64, Relaxed);
        }
        info
    }

    /// Marches every offset of the pattern; returns the number of stalled paths.
    #[allow(clippy::too_many_arguments)]
    fn march_pattern(
        &self,
        centre: DomainLocation,
        loc: BaseLocation,
        centre_pos: DVec3,
        n: DVec3,
        frame: &Frame,
        delta: f64,
        k: usize,
        sparse: bool,
        out: &mut [Option<DomainLocation>],
    ) -> usize {
        let mm = self.march_mesh();
        let lm = self.field.limit_mesh();
        let (f, fs, ft) = lm.locate(loc.quad, loc.s, loc.t);
        // The mesh point at the centre's face parameter can be a good part of a face away
        // from the centre next to an extraordinary vertex (the parameterisation is far from
        // affine there): start from the mesh point nearest the exact centre instead, one
        // short walk away.
        let mut p0 = mm.point_in_face(f, fs, ft);
        let (ex, ey, _) = mm.tri_axes(p0.tri);
        let d = centre_pos - mm.position(lm, p0);
        let d2 = glam::DVec2::new(d.dot(ex), d.dot(ey));
        let len = d2.length();
        if len > 0.0 && len.is_finite() {
            if let march::PathEnd::At(p) = mm.walk(p0, d2 / len, len) {
                p0 = p;
            }
        }
        let a1 = mm.to_local(p0.tri, n, frame.v1);
        let a2 = mm.to_local(p0.tri, n, frame.v2);
        // Next to an extraordinary vertex the paths follow geodesics of the exact limit
        // surface (march::EXACT_RINGS); from a centre there, from the start.
        let exact_start = mm.near_extraordinary(p0.tri);
        let max_step = delta * EXACT_STEP;
        let h = (k / 2) as i64;
        let idx = |l: i64, m: i64| ((m + h) as usize) * k + (l + h) as usize;
        out[idx(0, 0)] = Some(centre);
        let mut stalled = 0;
        // The patch of the last point evaluated, carried from sample to sample: a path's
        // samples are close, so most evaluations skip the descent of the patch tree.
        let mut hint = LeafHint::default();
        // A mesh path's end as a domain point (stalled paths are counted).
        let mut finish = |end: PathEnd, hint: &mut LeafHint| match end {
            PathEnd::At(p) => Some(mm.to_domain(self.surface, lm, p, hint)),
            PathEnd::Boundary => None,
            PathEnd::Stalled(p) => {
                stalled += 1;
                Some(mm.to_domain(self.surface, lm, p, hint))
            }
        };
        if exact_start {
            // Every geodesic starts at the centre: its limit sample once. One geodesic per
            // primitive direction (l0, m0) (gcd 1), its multiples (j·l0, j·m0) read off
            // along the way, as below.
            let e0 = self
                .surface
                .eval_base_derivs(loc.quad, loc.s, loc.t, &mut hint)
                .sample();
            let h0 = hint;
            for m0 in -h..=h {
                for l0 in -h..=h {
                    if geodesic::gcd(l0.unsigned_abs(), m0.unsigned_abs()) != 1
                        || (sparse && l0.abs().max(m0.abs()) > h / 2)
                    {
                        continue;
                    }
                    let reps = h / l0.abs().max(m0.abs());
                    let v = (frame.v1 * l0 as f64 + frame.v2 * m0 as f64) * delta;
                    let vt = v - n * n.dot(v);
                    let vt = vt * (v.length() / vt.length().max(1e-300));
                    let dir = (a1 * l0 as f64 + a2 * m0 as f64).normalize();
                    let s = self.surface;
                    geodesic::geodesic_ends_from(
                        s,
                        loc,
                        &e0,
                        vt,
                        reps as usize,
                        max_step,
                        h0,
                        |j, b| {
                            let j = j as i64;
                            out[idx(l0 * j, m0 * j)] = match b {
                                Some(b) => Some(s.base_to_domain(b.quad, b.s, b.t)),
                                // Off the surface or a failed projection: the mesh path decides.
                                None => finish(mm.walk(p0, dir, v.length() * j as f64), &mut hint),
                            };
                        },
                    );
                }
            }
            return stalled;
        }
        // One path per primitive direction (l0, m0) (gcd 1); its multiples (j·l0, j·m0) are
        // read off along the way (the same paths as one walk per sample, ~25% less walking
        // at K = 9).
        for m0 in -h..=h {
            for l0 in -h..=h {
                // A sparse block's samples are multiples of the directions within h/2
                // ([`sparse_keeps`]): a primitive direction beyond reaches one sample
                // only, an odd offset outside the block.
                if geodesic::gcd(l0.unsigned_abs(), m0.unsigned_abs()) != 1
                    || (sparse && l0.abs().max(m0.abs()) > h / 2)
                {
                    continue;
                }
                let reps = h / l0.abs().max(m0.abs());
                // a1, a2 are not unit (moved along n into the triangle's plane): the
                // direction is theirs, the length the tangent vector's.
                let dir = (a1 * l0 as f64 + a2 * m0 as f64).normalize();
                let step = (frame.v1 * l0 as f64 + frame.v2 * m0 as f64).length() * delta;
                let (mut at, mut d) = (p0, dir);
                // Where the path entered the neighbourhood of an extraordinary vertex: (entry,
                // the geodesic on from there, its length to the sample). One geodesic reads
                // off every further multiple, as from an exact centre.
                let mut entry: Option<(march::Entered, geodesic::GeodesicPath, f64)> = None;
                let mut done: Option<PathEnd> = None;
                for j in 1..=reps {
                    let i = idx(l0 * j, m0 * j);
                    if let Some(end) = done {
                        out[i] = finish(end, &mut hint);
                        continue;
                    }
                    // Arc length of the geodesic from the previous sample (or the entry).
                    let len = if let Some(en) = entry.as_mut() {
                        en.2 += step;
                        step
                    } else {
                        match mm.walk_on(at, d, step) {
                            Ok((PathEnd::At(p), dp)) => {
                                (at, d) = (p, dp);
                                out[i] = finish(PathEnd::At(p), &mut hint);
                                continue;
                            }
                            Ok((end, _)) => {
                                done = Some(end);
                                out[i] = finish(end, &mut hint);
                                continue;
                            }
                            Err(e) => {
                                let b = mm.to_base(self.surface, lm, e.at, &mut hint);
                                // Newton's last point was next to b: the hint mostly holds.
                                let eb = self
                                    .surface
                                    .eval_base_derivs(b.quad, b.s, b.t, &mut hint)
                                    .sample();
                                let t = mm.to_3d(e.at.tri, e.dir);
                                let t = (t - eb.n * eb.n.dot(t)).normalize_or_zero();
                                let v = t * e.rest;
                                let path = geodesic::GeodesicPath::new(b, &eb, v, max_step, hint);
                                entry = Some((e, path, e.rest));
                                v.length()
                            }
                        }
                    };
                    // Next to an extraordinary vertex: on along the exact limit surface.
                    let Some((e, path, rest)) = entry.as_mut() else {
                        continue;
                    };
                    out[i] = match path.advance(self.surface, len) {
                        Some(b) => Some(self.surface.base_to_domain(b.quad, b.s, b.t)),
                        // Off the surface or a failed projection: the mesh path decides.
                        None => finish(mm.walk(e.at, e.dir, *rest), &mut hint),
                    };
                }
            }
        }
        stalled
    }

    /// Counters so far.
    pub fn stats(&self) -> SamplerStats {
        let c = &self.counters;
        SamplerStats {
            patterns: c.patterns.load(Relaxed),
            chart_requests: c.chart_requests.load(Relaxed),
            fallbacks: c.fallbacks.load(Relaxed),
            samples: c.samples.load(Relaxed),
            missing: c.missing.load(Relaxed),
            stalled: c.stalled.load(Relaxed),
        }
    }

    /// Sets all counters to zero.
    pub fn reset_stats(&self) {
        let c = &self.counters;
        for a in [
            &c.patterns,
            &c.chart_requests,
            &c.fallbacks,
            &c.samples,
            &c.missing,
            &c.stalled,
        ] {
            a.store(0, Relaxed);
        }
    }
}

/// Whether sample (l, m) (offsets from the centre, |l|, |m| ≤ K/2) is in the sparse K×K
/// block: within K/4 (rounded down) of the centre in both offsets, or both offsets even.
/// K = 9: the inner 5x5 and every other sample of the rings at 3 and 4 — 41 of 81 samples
/// with the same reach; the even ones are where the coarser level's 5x5 block (twice the
/// step) samples. Meant for K = 4j + 1 (5, 9, 13): with K/2 odd the outermost ring would
/// be left out.
pub fn sparse_keeps(k: usize, l: i64, m: i64) -> bool {
    let inner = (k / 2) as i64 / 2;
    l.abs().max(m.abs()) <= inner || (l % 2 == 0 && m % 2 == 0)
}

/// Median distance between the limit positions of horizontally or vertically adjacent texel
/// centres of one face at resolution `n` (BRIEF.md's h).
pub fn median_texel_spacing(surface: &Surface, n: usize) -> f64 {
    let mut d = Vec::new();
    let mut buf = vec![Default::default(); n * n];
    for dom in 0..surface.num_domains() {
        surface.eval_texels(subdiv::DomainId::from_idx(dom), n, &mut buf);
        for y in 0..n {
            for x in 0..n {
                let p: DVec3 = buf[y * n + x].p;
                if x + 1 < n {
                    d.push((buf[y * n + x + 1].p - p).length());
                }
                if y + 1 < n {
                    d.push((buf[(y + 1) * n + x].p - p).length());
                }
            }
        }
    }
    if d.is_empty() {
        return 0.0;
    }
    let mid = d.len() / 2;
    *d.select_nth_unstable_by(mid, |a, b| a.total_cmp(b)).1
}
