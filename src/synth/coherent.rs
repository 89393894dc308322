//! Coherent synthesis (Ying, Hertzmann, Biermann & Zorin 2001, §5), after Ashikhmin's
//! image algorithm: instead of searching the whole example, every texel only considers
//! *continuations* of the patches its already-synthesized neighbours were copied from.
//!
//! For texel x with position P(x) and frame (v1, v2) (the orientation field):
//! 1. Its synthesized neighbours x_i come from [`crate::texels::TexelGraph`] (5x5 block,
//!    across edges and around corners); unsynthesized ones are ignored.
//! 2. Tangent displacements e_i = ((P(x_i) − P(x))·v1, −(P(x_i) − P(x))·v2) / S, in example
//!    pixels (S = scale, surface length per pixel; with a scale map, x's local step). Image rows grow *downwards* while v2 =
//!    n × v1 turns counter-clockwise seen from outside, hence the minus: without it the
//!    texture would appear mirrored on the surface.
//! 3. Candidates y'_i = x'_i − e_i, x'_i the recorded (floating point) source of x_i —
//!    "the value located in the example in the same way with respect to x'_i as x is with
//!    respect to x_i". Candidates closer than [`CoherentParams::merge_radius`] pixels to an
//!    earlier one are the same continuation seen from two neighbours and are compared once
//!    (the earlier, from the nearer neighbour, is kept). Candidates whose centre is outside
//!    the example's pixel-centre rectangle [0.5, w−0.5]×[0.5, h−0.5] are rejected: the
//!    patch has run off the example (Ashikhmin does the same); neighbourhood samples of a
//!    valid candidate that fall outside are clamped to the border (repeated border pixels),
//!    so every candidate is compared on the same number of samples and none is favoured
//!    for having fewer.
//! 4. Each candidate's neighbourhood {y'_i + e_j} is compared with the colours of the x_j
//!    by bilinear example lookups; squared l2 over all matched channels with their weights
//!    ([`super::matching::features`]). The best one is copied: x gets source y' and the features
//!    there.
//!
//! Beyond the paper:
//! - **No continuation left** (all candidates outside the example): the best of
//!   [`CoherentParams::restart_candidates`] random positions by the same neighbourhood
//!   distance starts a new patch that fits its surroundings, rather than one blind random
//!   pick.
//! - **Random candidates** ([`CoherentParams::random_candidates`] per texel, default 1):
//!   an escape from "garbage growth", where a poor patch keeps continuing because all
//!   candidates are its own continuations, and from forced joins where two grown regions
//!   meet. They only win when strictly better than every continuation (about 1% of texels),
//!   so they act where patches meet. Measured (docs/coherent.md): on curved meshes with
//!   structured examples they cut the seam ratio from up to 1.96 to below 1.0, at the cost
//!   of ~4 points of coherence; more than one only adds noise.
//! - **No neighbour at all** (the first texel of a connected component): a random position.
//!
//! Randomness is a counter-based hash of (seed, texel index, draw), so a texel's draws do
//! not depend on what ran before it or on which thread. With the wave schedule of
//! [`super::schedule`] the result is bit-identical for any number of threads.
//!
//! Scan-line order inside a domain (§4: "starting from a scan-line that is adjacent to an
//! already-synthesized texture"): the side whose outermost line has the most synthesized
//! foreign neighbours is scanned first, lines parallel to it move away from it, and each
//! line starts at the end whose perpendicular side has more synthesized texture.

#[cfg(target_arch = "x86_64")]
use super::matching::features::dist2_lanes;
use super::matching::features::{dist2, Features};
use super::matching::pixel_grid;
use super::schedule::{inward_order, Schedule};
use crate::random::random2;
use crate::texels::{TexelGeometry, TexelGraph};
use glam::Vec3;
use rayon::prelude::*;
use serde::Serialize;

/// Tuning of the coherent synthesizer (defaults measured, see docs/coherent.md).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct CoherentParams {
    /// Random candidates added to every texel's continuations.
    pub random_candidates: u32,
    /// Random candidates compared when no continuation is valid.
    pub restart_candidates: u32,
    /// Candidates closer than this (example pixels) are compared once.
    pub merge_radius: f32,
    /// Texel order inside a domain.
    pub order: Order,
    /// Order of the domains.
    pub domain_order: DomainOrder,
}

/// Order of the domains (see [`super::schedule`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum DomainOrder {
    /// The paper's breadth-first order over edge adjacency.
    Breadth,
    /// A flood by surface area ([`Schedule::plan_weighted`] with each domain's area, over
    /// the domains' texel-graph relations): small, densely sampled domains are crossed by
    /// the first front that reaches them instead of becoming the place where fronts meet.
    Area,
}

/// Texel order inside a domain.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Order {
    /// The paper's scan lines, starting from the side touching most synthesized texture.
    Scanline,
    /// Growing fronts: texels by grid distance from the border texels that touch
    /// synthesized texture (scan-line order inside each front).
    Front,
}

impl Default for CoherentParams {
    fn default() -> Self {
        Self {
            random_candidates: 1,
            restart_candidates: 16,
            merge_radius: 0.5,
            order: Order::Front,
            domain_order: DomainOrder::Area,
        }
    }
}

/// What the synthesizer needs besides the example.
#[derive(Clone, Copy, Debug)]
pub struct Inputs<'a> {
    pub geometry: &'a TexelGeometry,
    pub graph: &'a TexelGraph,
    /// (v1, v2) per texel (global texel order).
    pub frames: &'a [[Vec3; 2]],
    /// The domain order: [`schedule_for`] the run's [`CoherentParams::domain_order`].
    pub schedule: &'a Schedule,
    /// Surface length per example pixel.
    pub scale: f64,
    /// The scale map's factor per texel (`None`: 1 everywhere): texel t's neighbours are
    /// measured at the local step `scale × factor[t]`.
    pub factor: Option<&'a [f64]>,
    pub seed: u64,
}

/// Counters of what happened (reported in report.json).
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct Stats {
    /// Texels synthesized.
    pub texels: u64,
    /// Texels with no synthesized neighbour (random position).
    pub seeded: u64,
    /// Texels whose continuations all left the example (best random restart).
    pub restarts: u64,
    /// Texels where a random candidate beat every continuation.
    pub random_wins: u64,
    /// Candidate neighbourhoods compared in total.
    pub candidates: u64,
    /// Synthesized neighbours used in total.
    pub neighbours: u64,
    /// Waves of parallel domains.
    pub waves: u64,
}

impl Stats {
    fn add(&mut self, o: &Stats) {
        self.texels += o.texels;
        self.seeded += o.seeded;
        self.restarts += o.restarts;
        self.random_wins += o.random_wins;
        self.candidates += o.candidates;
        self.neighbours += o.neighbours;
    }
}

/// Source position per texel (global texel order) and counters.
#[derive(Clone, Debug)]
pub struct Output {
    pub source: Vec<[f32; 2]>,
    /// How each texel was chosen ([`Kind`] as u8, global texel order), for diagnostics.
    pub kind: Vec<u8>,
    pub stats: Stats,
}

/// How a texel's source was chosen (stored as u8 in [`Output::kind`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(u8)]
pub enum Kind {
    /// No synthesized neighbour: a random position.
    Seeded = 0,
    /// A continuation of a neighbour's patch.
    Continuation = 1,
    /// A random candidate beat every continuation.
    RandomWin = 2,
    /// No valid continuation: the best random restart.
    Restart = 3,
}

struct Ctx<'a, const K: usize> {
    feat: &'a Features<K>,
    inp: Inputs<'a>,
    params: &'a CoherentParams,
    inv_scale: f32,
    /// Whether the candidates are measured by [`measure8_avx2`] (8 values, AVX2 present).
    avx2: bool,
    /// Valid candidate centres: [lo, hi] per axis.
    lo: f32,
    hi_x: f32,
    hi_y: f32,
}

struct DomainOut<const K: usize> {
    src: Vec<[f32; 2]>,
    kind: Vec<u8>,
    feat: Vec<[f32; K]>,
    stats: Stats,
}

/// Runs coherent synthesis over all texels. `progress(done_domains)` is called after every
/// wave.
pub fn run<const K: usize>(
    features: &Features<K>,
    inputs: Inputs<'_>,
    params: &CoherentParams,
    progress: &(dyn Fn(usize) + Sync),
) -> Output {
    let layout = inputs.geometry.layout.clone();
    let faces = layout.faces();
    let total = layout.len();
    assert_eq!(inputs.frames.len(), total);
    assert_eq!(inputs.graph.len(), total);
    let ctx = Ctx {
        feat: features,
        inp: inputs,
        params,
        inv_scale: (1.0 / inputs.scale) as f32,
        avx2: has_avx2() && K == 8,
        lo: 0.5,
        hi_x: features.width as f32 - 0.5,
        hi_y: features.height as f32 - 0.5,
    };
    let mut src = vec![[0.0f32; 2]; total];
    let mut kind = vec![0u8; total];
    // A texel's feature (K floats, 32 B with appearance space) is read by later texels of
    // its own domain, which keeps its own per task, and by the texels of other domains
    // whose border lists name it: only those (`shared`, a ring a few texels deep, ~6% of
    // the texels at N = 128) are kept past their domain's task, not every texel's (issue 14
    // item 6, compact per-texel state). The values read are the same.
    let shared = shared_texels(inputs.graph);
    // Where each domain's shared texels start in `shared` (they are ascending, so a
    // domain's are one run): a lookup searches only its domain's run.
    let shared_start: Vec<u32> = (0..=faces)
        .map(|d| {
            let t = if d == faces { total } else { layout.start(d) };
            shared.partition_point(|&s| (s as usize) < t) as u32
        })
        .collect();
    let shared = Shared {
        texels: &shared,
        start: &shared_start,
    };
    let mut shared_feat = vec![[0.0f32; K]; shared.texels.len()];
    let mut done = vec![false; faces];
    let mut stats = Stats::default();
    let mut finished = 0;
    let schedule = inputs.schedule;
    stats.waves = schedule.waves.len() as u64;
    for wave in &schedule.waves {
        let results: Vec<DomainOut<K>> = wave
            .par_iter()
            .map(|&d| synth_domain(&ctx, &src, (shared, &shared_feat), &done, d as usize))
            .collect();
        for (&d, r) in wave.iter().zip(&results) {
            done[d as usize] = true;
            stats.add(&r.stats);
        }
        // The results go back in parallel: a domain's texels and its run of shared texels
        // are its own (one thread copying them was ~6% of the stage, most of it the first
        // touch of these arrays' pages).
        let mut by_domain: Vec<(u32, DomainOut<K>)> = wave.iter().copied().zip(results).collect();
        by_domain.sort_unstable_by_key(|&(d, _)| d);
        let parts = disjoint_parts(
            &mut src,
            &mut kind,
            &mut shared_feat,
            by_domain,
            |d| layout.range(d),
            |d| shared.start[d] as usize..shared.start[d + 1] as usize,
        );
        parts.into_par_iter().for_each(|(d, (src, kind, feat), r)| {
            let start = layout.start(d);
            src.copy_from_slice(&r.src);
            kind.copy_from_slice(&r.kind);
            let lo = shared.start[d] as usize;
            for (f, &t) in feat.iter_mut().zip(&shared.texels[lo..]) {
                *f = r.feat[t as usize - start];
            }
        });
        finished += wave.len();
        progress(finished);
    }
    Output {
        source: src,
        kind,
        stats,
    }
}

/// The slices of `src`, `kind` (texel `texels(d)`) and `feat` (shared texels
/// `shared(d)`) of each domain of `outs` (ascending domains, whose ranges are ascending and
/// disjoint), beside its result.
#[allow(clippy::type_complexity)]
fn disjoint_parts<'a, const K: usize>(
    src: &'a mut [[f32; 2]],
    kind: &'a mut [u8],
    feat: &'a mut [[f32; K]],
    outs: Vec<(u32, DomainOut<K>)>,
    texels: impl Fn(usize) -> std::ops::Range<usize>,
    shared: impl Fn(usize) -> std::ops::Range<usize>,
) -> Vec<(
    usize,
    (&'a mut [[f32; 2]], &'a mut [u8], &'a mut [[f32; K]]),
    DomainOut<K>,
)> {
    let (mut src, mut kind, mut feat) = ((src, 0), (kind, 0), (feat, 0));
    outs.into_iter()
        .map(|(d, r)| {
            let d = d as usize;
            let (t, f) = (texels(d), shared(d));
            let s = carve(&mut src, t.clone());
            let k = carve(&mut kind, t);
            let g = carve(&mut feat, f);
            (d, (s, k, g), r)
        })
        .collect()
}

/// The part `r` (indices of the whole slice) of what is left of a slice, `rest.0` being
/// the whole from index `rest.1` on; `rest` keeps what follows `r`. Parts must be asked
/// for in ascending, disjoint order.
fn carve<'a, T>(rest: &mut (&'a mut [T], usize), r: std::ops::Range<usize>) -> &'a mut [T] {
    let (_, tail) = std::mem::take(&mut rest.0).split_at_mut(r.start - rest.1);
    let (part, tail) = tail.split_at_mut(r.len());
    *rest = (tail, r.end);
    part
}

/// Texel area of every domain: the square of its median distance between adjacent texel
/// centres (BRIEF's h, per domain), i.e. the domain's area per texel under uniform
/// sampling; 0 for N = 1.
pub fn domain_texel_areas(geom: &TexelGeometry) -> Vec<f64> {
    (0..geom.faces())
        .into_par_iter()
        .map(|d| {
            let mut v: Vec<f32> = geom.domain_spacings(d).iter().map(|&x| x as f32).collect();
            if v.is_empty() {
                return 0.0;
            }
            let mid = v.len() / 2;
            let (_, m, _) = v.select_nth_unstable_by(mid, f32::total_cmp);
            (*m as f64).powi(2)
        })
        .collect()
}

/// The schedule of `order` (what [`Inputs::schedule`] must be for that order):
/// [`DomainOrder::Breadth`] is the paper's breadth-first plan over edge adjacency,
/// [`DomainOrder::Area`] the area-weighted flood ([`area_schedule`]).
pub fn schedule_for(
    order: DomainOrder,
    surface: &subdiv::Surface,
    geom: &TexelGeometry,
    graph: &TexelGraph,
) -> Schedule {
    match order {
        DomainOrder::Breadth => Schedule::plan(
            &crate::texels::domain_edge_adjacency(surface),
            &graph.domain_conflicts(),
        ),
        DomainOrder::Area => area_schedule(geom, graph),
    }
}

/// The area-weighted schedule ([`DomainOrder::Area`]): the flood runs over the domains'
/// conflict relation (domains sharing an edge or a corner read each other's texels).
pub fn area_schedule(geom: &TexelGeometry, graph: &TexelGraph) -> Schedule {
    let conflicts = graph.domain_conflicts();
    Schedule::plan_weighted(&conflicts, &conflicts, &domain_texel_areas(geom))
}

/// The scan order of a domain: local texel indices (y*nu + x) in synthesis order.
fn scan_order<const K: usize>(c: &Ctx<'_, K>, done_g: &[bool], d: usize) -> Vec<u32> {
    let layout = &c.inp.geometry.layout;
    let (nu, nv) = layout.dims(d);
    let base = layout.start(d);
    // Score of each side: synthesized foreign neighbours of the texels on its outer line.
    let mut score = [0u32; 4];
    let mut buf = Vec::with_capacity(64);
    let side_texel = |s: usize, i: usize| -> usize {
        match s {
            0 => i,                 // row y = 0
            1 => i * nu + (nu - 1), // column x = nu-1
            2 => (nv - 1) * nu + i, // row y = nv-1
            _ => i * nu,            // column x = 0
        }
    };
    for (s, sc) in score.iter_mut().enumerate() {
        let len = if s % 2 == 0 { nu } else { nv };
        for i in 0..len {
            buf.clear();
            c.inp.graph.neighbours(base + side_texel(s, i), &mut buf);
            *sc += buf
                .iter()
                .filter(|&&j| {
                    let e = layout.domain_of(j as usize);
                    e != d && done_g[e]
                })
                .count() as u32;
        }
    }
    let first = (0..4).fold(0, |b, s| if score[s] > score[b] { s } else { b });
    // Along each line, start at the end whose perpendicular side has more texture.
    let reverse = if first % 2 == 0 {
        score[1] > score[3]
    } else {
        score[2] > score[0]
    };
    // Lines are rows (first side 0 or 2) or columns (1 or 3).
    let (lines, along) = if first % 2 == 0 { (nv, nu) } else { (nu, nv) };
    let mut order = Vec::with_capacity(nu * nv);
    for line in 0..lines {
        for pos in 0..along {
            let p = if reverse { along - 1 - pos } else { pos };
            let (x, y) = match first {
                0 => (p, line),
                2 => (p, nv - 1 - line),
                3 => (line, p),
                _ => (nu - 1 - line, p),
            };
            order.push((y * nu + x) as u32);
        }
    }
    order
}

/// Texels by 4-neighbour grid distance from the outermost texels that have synthesized
/// foreign neighbours ([`inward_order`]); `None` when nothing around the domain is
/// synthesized yet.
fn front_order<const K: usize>(c: &Ctx<'_, K>, done_g: &[bool], d: usize) -> Option<Vec<u32>> {
    let layout = &c.inp.geometry.layout;
    let (nu, nv) = layout.dims(d);
    let base = layout.start(d);
    let mut buf = Vec::with_capacity(64);
    inward_order(nu, nv, |x, y| {
        buf.clear();
        c.inp.graph.neighbours(base + y * nu + x, &mut buf);
        buf.iter().any(|&j| {
            let e = layout.domain_of(j as usize);
            e != d && done_g[e]
        })
    })
}

/// The texels some other domain's texels have as neighbours (ascending, unique): those
/// named by a border list outside their own domain (interior texels' neighbours are all
/// in their domain).
fn shared_texels(graph: &TexelGraph) -> Vec<u32> {
    use std::sync::atomic::{AtomicU64, Ordering::Relaxed};
    // A bit per texel, set by every domain for the texels its lists name outside it: a
    // set, so the order the domains run in does not matter. Most texels are named many
    // times; a load first skips the write for those already set.
    let l = &graph.layout;
    let bits: Vec<AtomicU64> = (0..l.len().div_ceil(64))
        .map(|_| AtomicU64::new(0))
        .collect();
    (0..l.faces()).into_par_iter().for_each(|d| {
        let r = l.range(d);
        for t in r.clone() {
            for &j in graph.border_list(t) {
                let j = j as usize;
                if r.contains(&j) {
                    continue;
                }
                let (w, m) = (&bits[j / 64], 1u64 << (j % 64));
                if w.load(Relaxed) & m == 0 {
                    w.fetch_or(m, Relaxed);
                }
            }
        }
    });
    bits.par_iter()
        .enumerate()
        .flat_map_iter(|(w, b)| {
            let mut x = b.load(Relaxed);
            std::iter::from_fn(move || {
                (x != 0).then(|| {
                    let i = x.trailing_zeros();
                    x &= x - 1;
                    (w * 64) as u32 + i
                })
            })
        })
        .collect()
}

/// The shared texels ([`shared_texels`]) and where each domain's run of them starts (one
/// entry per domain + 1).
#[derive(Clone, Copy)]
struct Shared<'a> {
    texels: &'a [u32],
    start: &'a [u32],
}

impl Shared<'_> {
    /// The index in `texels` of texel `j` of domain `d`.
    #[inline]
    fn index(&self, d: usize, j: u32) -> usize {
        let lo = self.start[d] as usize;
        let run = &self.texels[lo..self.start[d + 1] as usize];
        lo + run
            .binary_search(&j)
            .expect("a neighbour in another domain is a shared texel")
    }
}

/// `shared`: [`shared_texels`] and their features (filled as their domains finish).
fn synth_domain<const K: usize>(
    c: &Ctx<'_, K>,
    src_g: &[[f32; 2]],
    (shared, feat_g): (Shared<'_>, &[[f32; K]]),
    done_g: &[bool],
    d: usize,
) -> DomainOut<K> {
    let geom = c.inp.geometry;
    let nn = geom.layout.count(d);
    let base = geom.layout.start(d);
    let mut out = DomainOut {
        src: vec![[0.0f32; 2]; nn],
        kind: vec![0u8; nn],
        feat: vec![[0.0f32; K]; nn],
        stats: Stats::default(),
    };
    let mut done = vec![false; nn];
    let order = match c.params.order {
        Order::Scanline => scan_order(c, done_g, d),
        Order::Front => front_order(c, done_g, d).unwrap_or_else(|| scan_order(c, done_g, d)),
    };
    let mut nb: Vec<u32> = Vec::with_capacity(64);
    let mut es: Vec<[f32; 2]> = Vec::with_capacity(64);
    let mut fs: Vec<[f32; K]> = Vec::with_capacity(64);
    let mut cands: Vec<[f32; 2]> = Vec::with_capacity(64);
    let r2 = c.params.merge_radius * c.params.merge_radius;
    let (w1, h1) = (c.hi_x - c.lo, c.hi_y - c.lo);
    let random_pos = |t: usize, k: u64| -> [f32; 2] {
        let (a, b) = random2(c.inp.seed, t as u64, k);
        // On a pixel centre: copies continued from it on a flat grid are then exact
        // example pixels (`pixel_grid`). The centres span [lo, hi] too.
        pixel_grid::centre([c.lo + a * w1, c.lo + b * h1])
    };
    for &li in &order {
        let li = li as usize;
        let t = base + li;
        nb.clear();
        c.inp.graph.neighbours(t, &mut nb);
        es.clear();
        fs.clear();
        cands.clear();
        let p = geom.pos[t];
        let [v1, v2] = c.inp.frames[t];
        let inv_scale = match c.inp.factor {
            None => c.inv_scale,
            Some(f) => (1.0 / (c.inp.scale * f[t])) as f32,
        };
        for &j in &nb {
            let j = j as usize;
            let (s, f) = if (base..base + nn).contains(&j) {
                let lj = j - base;
                if !done[lj] {
                    continue;
                }
                (out.src[lj], &out.feat[lj])
            } else {
                let e = geom.layout.domain_of(j);
                if !done_g[e] {
                    continue;
                }
                (src_g[j], &feat_g[shared.index(e, j as u32)])
            };
            let dp = geom.pos[j] - p;
            let e = [dp.dot(v1) * inv_scale, -dp.dot(v2) * inv_scale];
            es.push(e);
            fs.push(*f);
            // Step 3: the continuation of x_i's patch.
            let q = [s[0] - e[0], s[1] - e[1]];
            if q[0] >= c.lo && q[0] <= c.hi_x && q[1] >= c.lo && q[1] <= c.hi_y {
                let dup = cands.iter().any(|o| {
                    let (a, b) = (o[0] - q[0], o[1] - q[1]);
                    a * a + b * b < r2
                });
                if !dup {
                    cands.push(q);
                }
            }
        }
        out.stats.texels += 1;
        out.stats.neighbours += es.len() as u64;
        let mut k = Kind::Continuation;
        let chosen = if es.is_empty() {
            out.stats.seeded += 1;
            k = Kind::Seeded;
            random_pos(t, 0)
        } else {
            let coherent = cands.len();
            let extra = if coherent == 0 {
                out.stats.restarts += 1;
                c.params.restart_candidates.max(1)
            } else {
                c.params.random_candidates
            };
            for k in 0..extra as u64 {
                cands.push(random_pos(t, k + 1));
            }
            out.stats.candidates += cands.len() as u64;
            // Step 4: compare neighbourhoods; stop summing once worse than the best.
            let mut best = f32::INFINITY;
            let mut bi = 0;
            for (ci, q) in cands.iter().enumerate() {
                let sum = measure(c, &es, &fs, *q, best);
                if sum < best {
                    best = sum;
                    bi = ci;
                }
            }
            if coherent == 0 {
                k = Kind::Restart;
            } else if bi >= coherent {
                out.stats.random_wins += 1;
                k = Kind::RandomWin;
            }
            cands[bi]
        };
        out.src[li] = chosen;
        out.kind[li] = k as u8;
        out.feat[li] = c.feat.sample(chosen[0], chosen[1]);
        done[li] = true;
    }
    out
}

fn has_avx2() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx2")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// The distance of candidate `q` (step 4): the sum over the neighbours in order of
/// [`dist2`] between the example sampled at `q + e_i` and the neighbour's feature `f_i` —
/// exactly, or some partial sum once it reaches `best` (the candidate then loses: the
/// terms are not negative, so the whole sum would not be below `best` either, and which
/// partial sum is returned decides nothing).
#[inline]
fn measure<const K: usize>(
    c: &Ctx<'_, K>,
    es: &[[f32; 2]],
    fs: &[[f32; K]],
    q: [f32; 2],
    best: f32,
) -> f32 {
    #[cfg(target_arch = "x86_64")]
    if c.avx2 {
        // SAFETY: `c.avx2` is set only when AVX2 is present and K == 8.
        return unsafe { measure8_avx2(c.feat, es, fs.as_flattened(), q, best) };
    }
    measure_scalar(c.feat, es, fs, q, best)
}

/// [`measure`] one neighbour at a time, cut as soon as the sum reaches `best`.
#[inline]
fn measure_scalar<const K: usize>(
    feat: &Features<K>,
    es: &[[f32; 2]],
    fs: &[[f32; K]],
    q: [f32; 2],
    best: f32,
) -> f32 {
    let mut sum = 0.0f32;
    for (e, f) in es.iter().zip(fs) {
        sum += dist2(&feat.sample(q[0] + e[0], q[1] + e[1]), f);
        if sum >= best {
            break;
        }
    }
    sum
}

/// [`measure`] for 8 values per pixel, eight neighbours side by side: each neighbour's
/// bilinear lookup is [`Features::sample`]'s (taps and weights from [`Features::taps`],
/// the same arithmetic per value, no fused multiply-add), its eight squared differences
/// summed in [`dist2`]'s order by the transposed lane sum ([`dist2_lanes`]), and the
/// neighbours' distances added to the sum one by one in their order: the scalar sum bit
/// for bit. The test for `best` comes after every eight neighbours instead of every one
/// (a later cut, the same winner; see [`measure`]). `fs` holds 8 values per neighbour.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn measure8_avx2<const K: usize>(
    f: &Features<K>,
    es: &[[f32; 2]],
    fs: &[f32],
    q: [f32; 2],
    best: f32,
) -> f32 {
    use std::arch::x86_64::*;
    let n = es.len();
    let mut sum = 0.0f32;
    let mut sq = [_mm256_setzero_ps(); 8];
    let mut d2 = [0.0f32; 8];
    let mut g = 0;
    while g < n {
        let m = (n - g).min(8);
        for (j, s) in sq.iter_mut().enumerate() {
            // Unused lanes repeat the group's last neighbour.
            let i = g + j.min(m - 1);
            let e = es[i];
            let v = f.sample8_avx2(q[0] + e[0], q[1] + e[1]);
            let dv = _mm256_sub_ps(v, _mm256_loadu_ps(fs[i * 8..i * 8 + 8].as_ptr()));
            *s = _mm256_mul_ps(dv, dv);
        }
        _mm256_storeu_ps(d2.as_mut_ptr(), dist2_lanes(&sq));
        for &x in &d2[..m] {
            sum += x;
        }
        if sum >= best {
            break;
        }
        g += m;
    }
    sum
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The AVX2 kernel's sum is the scalar one bit for bit when not cut, and both reach
    /// `best` when either is cut (so the same candidate wins), for any neighbour count,
    /// positions inside, on and beyond the example's border.
    #[cfg(target_arch = "x86_64")]
    #[test]
    fn measure8_avx2_is_the_scalar_sum() {
        if !has_avx2() {
            return;
        }
        let mut img = crate::pyramid::Image::new(13, 9, 8);
        for (i, v) in img.data.iter_mut().enumerate() {
            *v = ((i * 7919) % 101) as f32 * 0.0173 - 0.6;
        }
        let f = Features::<8>::from_image(&img);
        for n in 0..27usize {
            let es: Vec<[f32; 2]> = (0..n)
                .map(|i| {
                    let (a, b) = random2(3, i as u64, n as u64);
                    [a * 9.0 - 4.5, b * 9.0 - 4.5]
                })
                .collect();
            let fs: Vec<[f32; 8]> = (0..n)
                .map(|i| std::array::from_fn(|k| ((i * 31 + k * 17) % 23) as f32 * 0.05 - 0.3))
                .collect();
            for (k, q) in [[6.3f32, 4.1f32], [0.5, 0.5], [12.9, 8.2], [-1.0, 3.0]]
                .into_iter()
                .enumerate()
            {
                let full = measure_scalar(&f, &es, &fs, q, f32::INFINITY);
                // SAFETY: AVX2 is present (checked above).
                let v = unsafe { measure8_avx2(&f, &es, fs.as_flattened(), q, f32::INFINITY) };
                assert_eq!(v.to_bits(), full.to_bits(), "n {n} q {k}");
                for best in [full * 0.3, full * 0.9, full, full * 1.1] {
                    let s = measure_scalar(&f, &es, &fs, q, best);
                    // SAFETY: as above.
                    let v = unsafe { measure8_avx2(&f, &es, fs.as_flattened(), q, best) };
                    assert_eq!(s < best, v < best, "n {n} q {k} best {best}");
                    if s < best {
                        assert_eq!(v.to_bits(), s.to_bits());
                    }
                }
            }
        }
    }
}
