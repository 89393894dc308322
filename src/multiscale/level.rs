//! One synthesis level on the surface: texel geometry at that level's resolution, K×K
//! neighbourhood patterns, and fetches that respect what is generated so far.

use crate::field::{Frame, OrientationField};
use crate::maps::{MapLayout, Taps};
use crate::sampling::{Sampler, SamplerKind};
use glam::Vec3;
use rayon::prelude::*;
use std::sync::Arc;
use subdiv::{DomainId, DomainLocation, LimitSample, Surface};

/// Geometry of the texels of one level (resolution `r`).
pub struct LevelGeometry {
    pub r: usize,
    pub layout: Arc<MapLayout>,
    /// Limit position per texel.
    pub pos: Vec<Vec3>,
    /// The orientation field's frame per texel.
    pub frames: Vec<Frame>,
    /// Per texel, the change of (u, v) per unit surface length along v1 and along v2:
    /// `[w1.u, w1.v, w2.u, w2.v]`, from the pseudo-inverse of the Jacobian (∂P/∂u, ∂P/∂v).
    pub axes: Vec<[f64; 4]>,
    /// Per texel, the largest relative change of the metric (JᵀJ) to an adjacent texel of
    /// the same domain: how far the parameterisation is from an isometry to the plane
    /// around the texel (see [`pattern`]).
    pub bend: Vec<f32>,
    /// Per domain, whether each corner ((0,0), (1,0), (0,1), (1,1)) is a regular vertex of
    /// the base mesh (see [`pattern`]).
    pub regular_corners: Arc<Vec<[bool; 4]>>,
}

/// Per domain, whether its corners are regular base-mesh vertices (interior valence 4, or
/// a regular boundary or corner vertex): around those the parameterisations of the faces
/// meeting there join smoothly (they are one uniform bicubic B-spline), so the faces'
/// parameter planes together form a chart — the valence-4 characteristic map is the
/// parameter grid itself.
pub fn regular_corners(surface: &Surface) -> Vec<[bool; 4]> {
    (0..surface.num_domains())
        .map(|d| {
            let mut r = [false; 4];
            for (k, (u, v)) in [(0.0, 0.0), (1.0, 0.0), (0.0, 1.0), (1.0, 1.0)]
                .into_iter()
                .enumerate()
            {
                let b = surface.base_location(DomainLocation {
                    domain: DomainId::from_idx(d),
                    u,
                    v,
                });
                let corner = match (b.s > 0.5, b.t > 0.5) {
                    (false, false) => 0,
                    (true, false) => 1,
                    (true, true) => 2,
                    (false, true) => 3,
                };
                let vid = surface.base.face_vertices(subdiv::FaceId(b.quad.0))[corner];
                r[k] = surface.base.is_regular_vertex(subdiv::VertexId(vid));
            }
            r
        })
        .collect()
}

impl LevelGeometry {
    /// Evaluates everything at resolution `r` (parallel over domains; deterministic).
    pub fn new(
        surface: &Surface,
        field: &OrientationField,
        r: usize,
        regular_corners: Arc<Vec<[bool; 4]>>,
    ) -> Self {
        let layout = Arc::new(MapLayout::new(surface, r));
        let frames = field.texel_frames(surface, r);
        let nn = r * r;
        let faces = surface.num_domains();
        let mut pos = vec![Vec3::ZERO; faces * nn];
        let mut axes = vec![[0.0f64; 4]; faces * nn];
        let mut metric = vec![[0.0f64; 3]; faces * nn];
        pos.par_chunks_mut(nn)
            .zip(axes.par_chunks_mut(nn))
            .zip(metric.par_chunks_mut(nn))
            .enumerate()
            .for_each_init(
                || vec![LimitSample::default(); nn],
                |buf, (d, ((p, ax), g))| {
                    surface.eval_texels(DomainId::from_idx(d), r, buf);
                    for (i, s) in buf.iter().enumerate() {
                        p[i] = s.p.as_vec3();
                        let f = &frames[d * nn + i];
                        // (JᵀJ)⁻¹ Jᵀ v: the parameter step that moves along v to first order.
                        let (a, b, c) = (s.du.dot(s.du), s.du.dot(s.dv), s.dv.dot(s.dv));
                        g[i] = [a, b, c];
                        let det = a * c - b * b;
                        if det > 0.0 && det.is_finite() {
                            let solve = |v: glam::DVec3| {
                                let (x, y) = (s.du.dot(v), s.dv.dot(v));
                                ((c * x - b * y) / det, (a * y - b * x) / det)
                            };
                            let (w1u, w1v) = solve(f.v1);
                            let (w2u, w2v) = solve(f.v2);
                            ax[i] = [w1u, w1v, w2u, w2v];
                        } else {
                            // Degenerate derivatives (never at texel centres in practice):
                            // mark unusable so patterns go through the sampler.
                            ax[i] = [f64::INFINITY; 4];
                        }
                    }
                },
            );
        let bend = (0..faces * nn)
            .into_par_iter()
            .map(|t| {
                let (x, y) = (t % r, (t / r) % r);
                let g = metric[t];
                let norm = (g[0] * g[0] + 2.0 * g[1] * g[1] + g[2] * g[2]).sqrt();
                let mut worst = 0.0f64;
                let mut visit = |q: usize| {
                    let h = metric[q];
                    let d = ((h[0] - g[0]).powi(2)
                        + 2.0 * (h[1] - g[1]).powi(2)
                        + (h[2] - g[2]).powi(2))
                    .sqrt();
                    worst = worst.max(d / norm);
                };
                if x > 0 {
                    visit(t - 1);
                }
                if x + 1 < r {
                    visit(t + 1);
                }
                if y > 0 {
                    visit(t - r);
                }
                if y + 1 < r {
                    visit(t + r);
                }
                if norm > 0.0 && worst.is_finite() {
                    worst as f32
                } else {
                    f32::INFINITY
                }
            })
            .collect();
        Self {
            r,
            layout,
            pos,
            frames,
            axes,
            bend,
            regular_corners,
        }
    }

    /// Number of texels.
    pub fn len(&self) -> usize {
        self.pos.len()
    }

    /// True when there are no texels.
    pub fn is_empty(&self) -> bool {
        self.pos.is_empty()
    }

    /// Texels per domain.
    pub fn per_domain(&self) -> usize {
        self.r * self.r
    }

    /// Centre of texel `t`.
    #[inline]
    pub fn location(&self, t: usize) -> DomainLocation {
        self.layout.texel_location(t)
    }

    /// Offset of texel `q` from texel `t` in example pixels of a level whose pixels are
    /// `delta` long on the surface, in the frame of `t`: image x along v1, image y along
    /// −v2 (rows grow downwards while v2 = n × v1 turns counter-clockwise seen from
    /// outside — the same convention as coherent synthesis, so that both methods put the
    /// texture the same way round).
    #[inline]
    pub fn offset_pixels(&self, t: usize, q: usize, delta: f64) -> [f32; 2] {
        let d = (self.pos[q] - self.pos[t]).as_dvec3();
        let f = &self.frames[t];
        [(d.dot(f.v1) / delta) as f32, (-d.dot(f.v2) / delta) as f32]
    }
}

/// Largest estimated relative spacing error at the rim of a first-order pattern (see
/// [`pattern`]). The estimate is pessimistic: at 8% the accepted patterns measured a mean
/// spacing error of 1–2% and a 95th percentile of 3–6% on the torus, Spot and Blub
/// (`docs/multiscale.md`), against 0.1–0.2% for the vertex-chart sampler, which is ~20x
/// slower; at 4% a third of the Torus benchmark's patterns went to the sampler.
pub const BEND_TOLERANCE: f64 = 0.08;

/// How patterns were obtained (summed over texels; reported).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct PatternStats {
    /// Patterns inside the texel's own domain, sampled in its parameterisation (the
    /// domain is the chart).
    pub in_domain: u64,
    /// Patterns crossing domain edges near regular vertices only, laid out in the joint
    /// parameter plane of the faces around them (walked across edges in parameter space).
    pub regular_chart: u64,
    /// Patterns near extraordinary vertices, sampled by the vertex-chart sampler (which
    /// marches where no chart fits).
    pub sampler_chart: u64,
    /// Patterns marched (the coarsest level).
    pub sampler_march: u64,
    /// Samples off an open surface.
    pub missing: u64,
}

impl PatternStats {
    pub fn add(&mut self, o: &PatternStats) {
        self.in_domain += o.in_domain;
        self.regular_chart += o.regular_chart;
        self.sampler_chart += o.sampler_chart;
        self.sampler_march += o.sampler_march;
        self.missing += o.missing;
    }
}

/// The K×K pattern around texel `t` at step `delta`, in [`crate::search::Shape`] order
/// (`locs[(dy + h)·K + dx + h]`, dx along v1 = image columns, dy along −v2 = image rows).
///
/// Chart sampling (000 §4.2, steps 1–5) with the cheapest valid chart:
/// * a pattern inside the texel's own domain is laid out in that domain's
///   parameterisation with the first-order map (u, v) + δ·(dx·w1 − dy·w2) — the face is
///   its own chart — at no evaluation cost;
/// * a pattern that crosses domain edges but stays within one domain of its own and
///   reaches across corners only where they are regular vertices ([`regular_corners`]) is
///   laid out the same way and its outside samples are walked across the edges in
///   parameter space ([`Surface::walk`]): around regular vertices the faces' parameter
///   planes are the paper's vertex chart (the valence-4 characteristic map is the
///   parameter grid);
/// * everything else goes to the vertex charts of [`Sampler`], which marches where no
///   chart fits.
///
/// `kind` = march (the coarsest level, 000 §4) always marches.
///
/// Measured against [`Sampler`] on the same patterns in `docs/multiscale.md`.
#[allow(clippy::too_many_arguments)]
pub fn pattern(
    geo: &LevelGeometry,
    sampler: &Sampler<'_>,
    t: usize,
    delta: f64,
    k: usize,
    kind: SamplerKind,
    buf: &mut Vec<Option<DomainLocation>>,
    locs: &mut [Option<DomainLocation>],
    st: &mut PatternStats,
) {
    let h = (k / 2) as i64;
    let centre = geo.location(t);
    let [w1u, w1v, w2u, w2v] = geo.axes[t];
    let reach = h as f64 * delta;
    let (eu, ev) = (
        reach * (w1u.abs() + w2u.abs()),
        reach * (w1v.abs() + w2v.abs()),
    );
    let finite = eu.is_finite() && ev.is_finite();
    let (lo_u, hi_u) = (centre.u - eu < 0.0, centre.u + eu > 1.0);
    let (lo_v, hi_v) = (centre.v - ev < 0.0, centre.v + ev > 1.0);
    let inside = !(lo_u || hi_u || lo_v || hi_v);
    // Crossing patterns: only from domains whose four corners are all regular, and
    // reaching at most half a domain beyond their own, so that every face they touch
    // shares a regular corner with it (see the measurements in docs/multiscale.md: near
    // an extraordinary vertex the parameterisation bends too fast for a first-order
    // pattern).
    let near = finite
        && eu <= 0.5
        && ev <= 0.5
        && geo.regular_corners[centre.domain.idx()].iter().all(|&r| r);
    // First-order patterns are exact where the metric is constant; a relative metric
    // change m per texel step bends spacings at the pattern's rim by about m·(reach in
    // texels)/2. Beyond BEND_TOLERANCE the accurate sampler takes over.
    let reach_texels = eu.max(ev) * geo.r as f64;
    let straight = (geo.bend[t] as f64) * reach_texels * 0.5 <= BEND_TOLERANCE;
    if finite && straight && kind == SamplerKind::Chart && (inside || near) {
        if inside {
            st.in_domain += 1;
        } else {
            st.regular_chart += 1;
        }
        for dy in -h..=h {
            for dx in -h..=h {
                let (a, b) = (dx as f64 * delta, -dy as f64 * delta);
                let (du, dv) = (a * w1u + b * w2u, a * w1v + b * w2v);
                let (u, v) = (centre.u + du, centre.v + dv);
                let i = ((dy + h) as usize) * k + (dx + h) as usize;
                locs[i] = if (0.0..=1.0).contains(&u) && (0.0..=1.0).contains(&v) {
                    Some(DomainLocation {
                        domain: centre.domain,
                        u,
                        v,
                    })
                } else {
                    let l = sampler.surface().walk(centre, du, dv);
                    if l.is_none() {
                        st.missing += 1;
                    }
                    l
                };
            }
        }
        return;
    }
    buf.resize(k * k, None);
    let info = sampler.sample_with_frame(centre, &geo.frames[t], delta, k, kind, buf);
    match kind {
        SamplerKind::Chart => st.sampler_chart += 1,
        SamplerKind::March => st.sampler_march += 1,
    }
    st.missing += info.missing as u64;
    // The sampler's rows run along +v2 (m), ours along −v2 (dy = −m).
    for dy in -h..=h {
        let src = ((-dy + h) as usize) * k;
        let dst = ((dy + h) as usize) * k;
        locs[dst..dst + k].copy_from_slice(&buf[src..src + k]);
    }
}

/// Read access to a level's texel values while some domain is being rewritten: texels of
/// `own` (a domain's range) come from its private copy, all others from the shared state
/// as it was when the current wave started. This is what makes parallel waves give the
/// same result for any thread count: no domain ever reads another's in-progress texels.
pub struct View<'a> {
    pub channels: usize,
    pub values: &'a [f32],
    /// `None`: everything is generated.
    pub generated: Option<&'a [bool]>,
    pub own: Option<Own<'a>>,
}

/// A domain's private copy (see [`View`]).
pub struct Own<'a> {
    pub start: usize,
    pub len: usize,
    pub values: &'a [f32],
    pub generated: &'a [bool],
    /// True when every entry of `generated` is (lets fetches skip the checks).
    pub all_generated: bool,
}

impl View<'_> {
    #[inline]
    fn get(&self, i: usize) -> (&[f32], bool) {
        let c = self.channels;
        if let Some(o) = &self.own {
            if i >= o.start && i < o.start + o.len {
                let j = i - o.start;
                return (&o.values[j * c..(j + 1) * c], o.generated[j]);
            }
        }
        let g = self.generated.is_none_or(|g| g[i]);
        (&self.values[i * c..(i + 1) * c], g)
    }

    /// [`Self::fetch`] at a domain point of maps laid out by `layout`. Points whose four
    /// texels lie inside their domain (most of them) skip the cross-face ring lookup.
    #[inline]
    pub fn fetch_at(&self, layout: &MapLayout, loc: DomainLocation, out: &mut [f32]) -> bool {
        let n = layout.n();
        let fx = loc.u * n as f64 - 0.5;
        let fy = loc.v * n as f64 - 0.5;
        let (x0, y0) = (fx.floor(), fy.floor());
        if x0 >= 0.0 && y0 >= 0.0 && x0 + 1.0 < n as f64 && y0 + 1.0 < n as f64 {
            let (x0, y0) = (x0 as usize, y0 as usize);
            let (ax, ay) = ((fx - x0 as f64) as f32, (fy - y0 as f64) as f32);
            let base = layout.texel_index(loc.domain, x0, y0);
            let idx = [base, base + 1, base + n, base + n + 1];
            let w = [
                (1.0 - ax) * (1.0 - ay),
                ax * (1.0 - ay),
                (1.0 - ax) * ay,
                ax * ay,
            ];
            let c = self.channels;
            // All four texels are in one domain: one range check picks the storage, and
            // with everything generated no per-texel checks are needed. Same arithmetic,
            // in the same order, as the general path below.
            if self.generated.is_none() {
                let own = self
                    .own
                    .as_ref()
                    .filter(|o| base >= o.start && base + n + 1 < o.start + o.len);
                let (vals, off) = match own {
                    Some(o) if o.all_generated => (o.values, o.start),
                    Some(_) => (&[][..], usize::MAX),
                    None => (self.values, 0),
                };
                if off != usize::MAX {
                    out[..c].fill(0.0);
                    for k in 0..4 {
                        if w[k] != 0.0 {
                            let j = (idx[k] - off) * c;
                            for (o, s) in out[..c].iter_mut().zip(&vals[j..j + c]) {
                                *o += w[k] * s;
                            }
                        }
                    }
                    return true;
                }
            }
            let mut all = true;
            let mut best: Option<(usize, f32)> = None;
            for k in 0..4 {
                if w[k] == 0.0 {
                    continue;
                }
                if self.get(idx[k]).1 {
                    if best.is_none_or(|(_, bw)| w[k] > bw) {
                        best = Some((idx[k], w[k]));
                    }
                } else {
                    all = false;
                }
            }
            if all {
                out[..c].fill(0.0);
                for k in 0..4 {
                    if w[k] != 0.0 {
                        for (o, s) in out[..c].iter_mut().zip(self.get(idx[k]).0) {
                            *o += w[k] * s;
                        }
                    }
                }
                return true;
            }
            return match best {
                Some((i, _)) => {
                    out[..c].copy_from_slice(self.get(i).0);
                    true
                }
                None => false,
            };
        }
        self.fetch(&layout.taps(loc), out)
    }

    /// The paper's fetch (000 §4): bilinear over the four texels around `loc` when all are
    /// generated; else the generated one with the largest weight ("the nearest
    /// already-generated neighbor"); else nothing (returns false).
    #[inline]
    pub fn fetch(&self, taps: &Taps, out: &mut [f32]) -> bool {
        let c = self.channels;
        let mut all = true;
        let mut best: Option<(usize, f32)> = None;
        for (i, w) in taps.iter() {
            if self.get(i).1 {
                if best.is_none_or(|(_, bw)| w > bw) {
                    best = Some((i, w));
                }
            } else {
                all = false;
            }
        }
        if all && taps.len > 0 {
            out[..c].fill(0.0);
            for (i, w) in taps.iter() {
                for (o, s) in out[..c].iter_mut().zip(self.get(i).0) {
                    *o += w * s;
                }
            }
            return true;
        }
        match best {
            Some((i, _)) => {
                out[..c].copy_from_slice(self.get(i).0);
                true
            }
            None => false,
        }
    }
}

/// The texel with the largest weight among `taps` (ties: lowest index), if any.
#[inline]
pub fn nearest_texel(taps: &Taps) -> Option<usize> {
    let mut best: Option<(usize, f32)> = None;
    for (i, w) in taps.iter() {
        if best.is_none_or(|(bi, bw)| w > bw || (w == bw && i < bi)) {
            best = Some((i, w));
        }
    }
    best.map(|b| b.0)
}
