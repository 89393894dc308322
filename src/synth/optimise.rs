//! Texture optimisation on the surface (Kwatra et al. 2005, as generalised to surfaces and
//! vector fields in paper 001 §4.2–4.4).
//!
//! The texture energy is `E = Σ_p ω_p ‖X_p − Z_p‖²` over surface patches `p`: `X_p` the
//! texels of the patch's footprint ([`super::footprint`]: texels with their coordinates
//! `l` in an example patch laid along the field), `Z_p` the example patch at position
//! `z_p` read at the same coordinates. It is minimised by alternating
//! - **E-step** (choose `Z_p`): for every patch, the position `z_p` whose example patch is
//!   nearest to the current texels, in appearance space ([`super::matching::appearance`]).
//!   Search: k-coherence (paper 003 §5.2) — the patch's own previous position, the
//!   positions that continue its texels' current sources, the [`super::matching::similar`]
//!   places of those, and a few random ones — re-ranked by the exact distance over a
//!   subset of the footprint. (Measured against PCA + kd-tree over whole patch vectors and
//!   k-means clustering in docs/synthesis.md: the surface's footprints have no fixed shape,
//!   so a precomputed index over patch vectors needs resampling to a grid, which costs
//!   more than the candidates save.)
//! - **M-step** (choose `X`): every texel becomes the robust weighted average of the
//!   example patches covering it, read at its own coordinates in each (bilinear lookups at
//!   float positions): weights `ω_p = (‖X_p − Z_p‖² / n_p)^((r − 2)/2)` with `r = 0.8`
//!   (iteratively reweighted least squares for the `r`-norm, as Kwatra et al.), times a
//!   Gaussian falloff from the patch centre so that texels are decided by the patches they
//!   are central to.
//!
//! **Multilevel** (001 §4.4): coarse to fine over face-map resolutions (texels per side
//! halving with the example's pyramid levels, each level matched in its own appearance
//! space) and, per level, patch sizes from large to small ([`OptimiseParams::sizes`], in
//! that level's pixels: a 32-pixel patch two levels up spans 128 output pixels, which is
//! what keeps large structure). The coarsest level starts from patch sampling
//! ([`super::patches`]) instead of noise — the same energy, reached in fewer iterations;
//! finer levels start from the coarser level's sources, doubled and continued to each texel
//! (the rule of coherent synthesis).
//!
//! **Final pass**: the last patches are pasted at their optimised positions and joined
//! along minimum cuts (`patches::assemble`), so every texel copies the example at one
//! position, `source.u/v` is exact and every channel (colour, alpha, height) comes from the
//! same place, with no blur. Optionally ([`OptimiseParams::guided_assembly`]) a patch may
//! continue a neighbour already pasted where that fits the optimised texture better.
//!
//! **Determinism**: patches and texels are independent within a step (E-steps read `X`,
//! M-steps read the chosen positions), so parallel loops give the same result for any
//! thread count; random candidates hash (seed, level, size, iteration, patch).

use super::footprint::{centres, spread, turned, Footprints, LevelTexels, Turn};
use super::matching::exemplar::Exemplar;
use super::matching::features::dist2;
use super::patches::{self, PatchParams};
use super::Target;
use crate::pyramid::Image;
use crate::random::hash;
use rayon::prelude::*;
use serde::Serialize;

/// Tuning of texture optimisation (defaults measured, see docs/synthesis.md).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct OptimiseParams {
    /// Synthesis levels at most (coarse levels keep large structure).
    pub levels: usize,
    /// Patch sides per level, large to small, in that level's example pixels (clamped to
    /// half the example level's shorter side).
    pub sizes: Vec<usize>,
    /// EM iterations per level and patch size.
    pub iterations: usize,
    /// Distance between patch centres as a fraction of the side (001 and Kwatra et al.:
    /// a quarter, so each texel is covered by about four patches).
    pub spacing: f32,
    /// The robust norm's exponent r (Kwatra et al.: 0.8).
    pub r: f32,
    /// Texels of a footprint the E-step measures, per patch.
    pub eval_samples: u32,
    /// Random candidates per patch and iteration.
    pub random: u32,
    /// Footprint texels proposing continuations, per patch.
    pub proposers: u32,
    /// Patch sampling that starts the coarsest level.
    pub start: PatchParams,
    /// Also measure every example position on a grid of this step (pixels) in each
    /// E-step: the exhaustive search k-coherence is compared against (docs/synthesis.md, "E-step").
    /// `None` (the default) searches only the k-coherence candidates.
    pub exhaustive: Option<u32>,
    /// Final assembly: a patch whose optimised position disagrees with the patches pasted
    /// before it may continue one of them instead (see `patches::settle`). On by default,
    /// with the `up` field ([`super::Method::default_orientation`]): with `--orient up` it
    /// took the double torus's seam case (scales, N = 16, seed 2) from 1.29 to 1.05 and
    /// lowered pf8 on 7 of 12 curved mesh × example pairs (by up to 6%, bricks most),
    /// raised it on 3 by ≤ 2%, and raised the flat grid's pf8 by 0–5%
    /// (docs/synthesis.md, "Guided final assembly").
    pub guided_assembly: bool,
    /// How the M-step turns the votes of the patches covering a texel into its value, at
    /// the output level.
    pub vote: Vote,
    /// The same at the coarser levels. The mode there (the default) and the mean at the
    /// output level: measured over seeds 1–3 on eight mesh × example pairs (Spot, the
    /// double torus, Blub, the open cube, the all-triangle Spot, the flat grid; bricks,
    /// reptile scales, a weave), pf8 fell in every pair, by 0–7% (the open cube's scales
    /// 7%, bricks 4% on the double torus and Blub), and the mean seam ratio fell or held
    /// in seven (double torus N = 16, scales, seeds 1–5: 1.01 → 0.92); docs/synthesis.md,
    /// "The M-step's vote, per level".
    pub coarse_vote: Vote,
    /// Final assembly: where patches that nearly continue each other meet (their sources
    /// for a texel within this many pixels of the final level), the texel's source is
    /// their weighted mean instead of one side of the cut (`patches::blend_joins`). `None`
    /// keeps the cut as it is.
    pub join_blend: Option<f32>,
}

/// How the M-step combines the example patches covering a texel (its *votes*).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Vote {
    /// Kwatra et al.'s robust weighted average (IRLS with r = 0.8); the heaviest vote gives
    /// the source. The default at the output level: [`Vote::Mode`] raised seams there
    /// (below).
    #[default]
    Mean,
    /// The weighted medoid: the vote nearest (in appearance space, L2) to all the others,
    /// weighted — the dominant mode of the votes, as Wexler, Shechtman & Irani (2007)
    /// take with mean shift. The texel's value and source are one real vote's, never a
    /// blend. Why one would: on a curved surface overlapping patches disagree by a pixel or
    /// two (the field turns between their centres), and the average of a thin line seen at
    /// two places is a faint wide smear that the next E-step then matches — a texture no
    /// example patch has. With the mode, bricks' pf8 fell 7–13% on the double torus and
    /// 0–8% on Spot (N = 32). Why it is not the default at the output level: where
    /// neighbouring texels' votes nearly agree, which one is the medoid flips from texel
    /// to texel, and the sources with it; seams rose past the bar on the scales of
    /// tests/methods.rs (double torus N = 16: 1.06 → 1.18; open cube N = 32: 1.00 →
    /// 1.12). It is the default at the coarser levels ([`OptimiseParams::coarse_vote`]),
    /// whose sources only start the next level. docs/synthesis.md, "The M-step's vote".
    Mode,
}

/// One patch's vote for a texel: the example at `source`, weighted.
struct Ballot<const K: usize> {
    weight: f32,
    source: [f32; 2],
    /// The source orientation the vote's patch gives the texel (its turn β there).
    turn: Turn,
    value: [f32; K],
}

impl Vote {
    /// The texel's value, and its source with that source's orientation, from its
    /// (non-empty) votes.
    fn count<const K: usize>(self, votes: &[Ballot<K>]) -> ([f32; K], [f32; 2], Turn) {
        match self {
            Vote::Mean => {
                let mut acc = [0.0f32; K];
                let mut wsum = 0.0f32;
                let mut best = (f32::NEG_INFINITY, 0);
                for (i, v) in votes.iter().enumerate() {
                    for (a, x) in acc.iter_mut().zip(&v.value) {
                        *a += v.weight * x;
                    }
                    wsum += v.weight;
                    if v.weight > best.0 {
                        best = (v.weight, i);
                    }
                }
                for a in &mut acc {
                    *a /= wsum;
                }
                (acc, votes[best.1].source, votes[best.1].turn)
            }
            Vote::Mode => {
                let mut best = (f32::INFINITY, 0);
                for (i, a) in votes.iter().enumerate() {
                    let mut cost = 0.0f32;
                    for b in votes {
                        cost += b.weight * dist2(&a.value, &b.value).sqrt();
                        if cost >= best.0 {
                            break;
                        }
                    }
                    if cost < best.0 {
                        best = (cost, i);
                    }
                }
                let v = &votes[best.1];
                (v.value, v.source, v.turn)
            }
        }
    }
}

impl Default for OptimiseParams {
    fn default() -> Self {
        Self {
            levels: 3,
            sizes: vec![32, 16],
            iterations: 3,
            spacing: 0.5,
            r: 0.8,
            eval_samples: 128,
            random: 2,
            proposers: 8,
            start: PatchParams::default(),
            exhaustive: None,
            guided_assembly: true,
            vote: Vote::Mean,
            coarse_vote: Vote::Mode,
            join_blend: Some(JOIN_BLEND),
        }
    }
}

/// [`OptimiseParams::join_blend`]'s default, in pixels: about a mortar line's width in
/// the bricks example (docs/synthesis.md, "Blended joins": 4 and 8 measured).
pub const JOIN_BLEND: f32 = 4.0;

/// One level's plan and counters (reported).
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct LevelStats {
    /// Example pyramid level.
    pub example_level: usize,
    /// Face-map texels per side.
    pub resolution: usize,
    /// (patch side, patches) per size.
    pub patches: Vec<(usize, u64)>,
    /// Mean squared patch distance (per texel) after the last iteration of each size.
    pub energy: Vec<f64>,
}

/// Counters (reported).
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct Stats {
    /// Coarsest first.
    pub levels: Vec<LevelStats>,
    /// Candidate positions measured over all E-steps.
    pub candidates: u64,
    /// The patch sampling that started the coarsest level.
    pub start: patches::Stats,
}

/// Source position per output texel and counters.
pub struct Output {
    pub source: Vec<[f32; 2]>,
    pub stats: Stats,
}

/// Smallest example side at the coarsest level, and smallest face-map side.
const MIN_EXAMPLE_SIDE: usize = 24;
/// Progress units per EM iteration (so that the final assembly can report fractions).
const PROGRESS_STEP: usize = 100;
/// The final assembly's share of the progress, in EM iterations (measured on the hand at
/// N = 32: ~2.5 iterations of the output level).
const ASSEMBLY_ITERATIONS: usize = 3;
const MIN_RESOLUTION: usize = 2;

/// Runs texture optimisation of `weighted` (the example's channels premultiplied by the
/// square roots of their weights) over `target`. `K` is the matching dimension of
/// `mode`. `progress(done, total)` counts EM iterations and the final assembly in
/// `PROGRESS_STEP`ths of an iteration.
pub fn run<const K: usize>(
    weighted: &Image,
    mode: super::matching::appearance::AppearanceMode,
    target: &Target<'_>,
    params: &OptimiseParams,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> (Output, super::matching::appearance::AppearanceInfo) {
    let out_layout = target.texels.layout();
    // The typical side: N, or (per-face resolutions) the root mean square side, which is
    // what the level plan below halves.
    let n = out_layout
        .uniform_n()
        .unwrap_or_else(|| {
            ((out_layout.len() as f64 / out_layout.faces() as f64).sqrt()).round() as usize
        })
        .max(1);
    // With a scale map the levels are planned for its smallest factor (the finest local
    // step: no texel of a level is coarser than that level's example pixels anywhere);
    // each texel then samples at its own step (`LevelTexels::step_at`).
    let scale = target.reference_scale();
    // Example levels: j0 skips levels finer than the output texels (a texture scaled
    // down); then halve while the example and the maps stay large enough.
    let j0 = ((target.spacing / scale).log2().round().max(0.0)) as usize;
    let mut pyramid = vec![weighted.clone()];
    while pyramid.len() < j0 + params.levels.max(1) {
        let last = pyramid.last().expect("non-empty");
        let next = last.downsample();
        if next.width.min(next.height) < MIN_EXAMPLE_SIDE && pyramid.len() > j0 {
            break;
        }
        pyramid.push(next);
    }
    let j0 = j0.min(pyramid.len() - 1);
    let mut plan: Vec<(usize, usize)> = Vec::new(); // (example level, resolution), finest first
    for (i, j) in (j0..pyramid.len()).enumerate() {
        let r = if i == 0 {
            n
        } else {
            (n as f64 * target.spacing / (scale * (1u64 << j) as f64)).round() as usize
        };
        if i > 0 && r < MIN_RESOLUTION {
            break;
        }
        plan.push((j, r.max(1)));
        if plan.len() == params.levels.max(1) {
            break;
        }
    }
    let total_iters = plan.len() * params.sizes.len().max(1) * params.iterations;
    let mut done_iters = 0;
    // The final assembly weighs as much as [`ASSEMBLY_ITERATIONS`] iterations of the
    // output level, and reports per patch pasted: on a big mesh it runs for several
    // seconds after the last iteration (the hand at N = 32: ~12 s), which a bar counting
    // iterations alone would show as a stall.
    let total = (total_iters + ASSEMBLY_ITERATIONS) * PROGRESS_STEP;
    let mut stats = Stats::default();
    let mut info = None;
    let mut prev: Option<(LevelTexels, Vec<[f32; 2]>, Vec<Turn>)> = None;
    for (li, &(j, r)) in plan.iter().enumerate().rev() {
        let ex = Exemplar::<K>::build(&pyramid[j], mode);
        if li == 0 {
            info = Some(ex.info);
        }
        // The step where the scale map's factor is 1 (the factor multiplies it per texel).
        let step = target.scale() * (1u64 << j) as f64;
        // The output level reuses the target's texels unless its pixels are coarser.
        let owned = (li > 0 || j > 0).then(|| {
            match out_layout.uniform_n() {
                Some(_) => LevelTexels::new(target.surface, target.field, r, step),
                None => {
                    // Per-face sides scaled like the typical one, in whole halvings.
                    let k = (n as f64 / r.max(1) as f64).log2().round().max(0.0) as u32;
                    LevelTexels::with_layout(
                        target.surface,
                        target.field,
                        std::sync::Arc::new(out_layout.coarsened(k)),
                        step,
                    )
                }
            }
            .with_scale(target.surface, target.scale_field)
        });
        let level: &LevelTexels = owned.as_ref().unwrap_or(target.texels);
        // Start: patch sampling at the coarsest level, else the coarser level continued.
        let (mut src, mut turn) = match prev.take() {
            None => {
                let out = patches::run(
                    &ex,
                    target.surface,
                    level,
                    &params.start,
                    target.seed,
                    &|_, _| {},
                );
                stats.start = out.stats;
                (out.source, out.turn)
            }
            Some((coarse, csrc, cturn)) => upsample(&coarse, &csrc, &cturn, level, &ex),
        };
        let mut lstats = LevelStats {
            example_level: j,
            resolution: r,
            ..LevelStats::default()
        };
        let mut last = None;
        let scratch = super::footprint::FloodScratch::default();
        for (si, &size) in params.sizes.iter().enumerate() {
            let size = size.min(ex.width().min(ex.height()) / 2).max(4);
            let key = hash(target.seed, &[0x0971, li as u64, si as u64]);
            // Only the last size's footprints and texture serve the final assembly: the
            // previous size's are not held while this one builds its own.
            drop(last.take());
            let res = optimise_size(
                &ex,
                level,
                (&src, &turn),
                size,
                params,
                key,
                if li == 0 {
                    params.vote
                } else {
                    params.coarse_vote
                },
                &scratch,
                &mut || {
                    done_iters += 1;
                    progress(done_iters * PROGRESS_STEP, total);
                },
            );
            src = res.source;
            turn = res.turn;
            lstats.patches.push((size, res.patches));
            lstats.energy.push(res.energy);
            stats.candidates += res.candidates;
            last = Some((res.footprints, res.positions, res.texture));
        }
        drop(scratch); // not held through the final assembly
        stats.levels.push(lstats);
        if li == 0 {
            // Final pass: the last patches joined at their optimised positions by cuts.
            if let Some((fp, z, x)) = last {
                let guide = params.guided_assembly.then_some(&x[..]);
                src = patches::assemble(
                    &ex,
                    level,
                    &fp,
                    &z,
                    &src,
                    guide,
                    params.join_blend,
                    target.seed,
                    &|d, t| {
                        let part = ASSEMBLY_ITERATIONS * PROGRESS_STEP * d / t.max(1);
                        progress(total_iters * PROGRESS_STEP + part, total);
                    },
                );
            }
            // Sources in level-j pixels, to level-0 example pixels.
            let up = (1u64 << j) as f32;
            let source = src.iter().map(|s| [s[0] * up, s[1] * up]).collect();
            return (Output { source, stats }, info.expect("set above"));
        }
        prev = Some((owned.expect("coarse levels own their texels"), src, turn));
    }
    unreachable!("the plan has at least one level")
}

/// What one patch size of one level produced.
struct SizeResult<const K: usize> {
    source: Vec<[f32; 2]>,
    /// Each texel's source orientation (the turn of the patch its source came from).
    turn: Vec<Turn>,
    /// The optimised texture (appearance per texel) after the last M-step.
    texture: Vec<[f32; K]>,
    footprints: Footprints,
    positions: Vec<[f32; 2]>,
    energy: f64,
    patches: u64,
    candidates: u64,
}

/// EM iterations with patches of side `size` over `level`, starting from sources `src`
/// (positions and orientations).
#[allow(clippy::too_many_arguments)]
fn optimise_size<const K: usize>(
    ex: &Exemplar<K>,
    level: &LevelTexels,
    (src, src_turn): (&[[f32; 2]], &[Turn]),
    size: usize,
    params: &OptimiseParams,
    key: u64,
    vote: Vote,
    scratch: &super::footprint::FloodScratch,
    tick: &mut dyn FnMut(),
) -> SizeResult<K> {
    let n = level.len();
    let f = &ex.features;
    let half = size as f32 / 2.0;
    let spacing = params.spacing as f64 * size as f64;
    let fp = Footprints::build_with(level, centres(level, spacing, key, None), half, scratch);
    let np = fp.len();
    let (lo, hi_x, hi_y) = (
        0.5 + half,
        f.width as f32 - 0.5 - half,
        f.height as f32 - 0.5 - half,
    );
    let clamp = |z: [f32; 2]| [z[0].clamp(lo, hi_x.max(lo)), z[1].clamp(lo, hi_y.max(lo))];
    // Memberships per texel (patch, local coordinates, turn), for the M-step.
    let cover = fp.covering_coords(n);
    let (mstart, mlist, mcoord, mturn) = (&cover.start, &cover.patch, &cover.coords, &cover.turns);
    let sigma2 = (0.8 * half) * (0.8 * half);
    let falloff = |l: [f32; 2]| (-(l[0] * l[0] + l[1] * l[1]) / (2.0 * sigma2)).exp();
    // Initial state: the example at the given sources; patch positions continue the
    // sources at their centres.
    let mut x: Vec<[f32; K]> = src.par_iter().map(|s| f.sample(s[0], s[1])).collect();
    let mut source: Vec<[f32; 2]> = src.to_vec();
    let mut turn: Vec<Turn> = src_turn.to_vec();
    let mut z: Vec<[f32; 2]> = fp.centres.iter().map(|&c| clamp(src[c as usize])).collect();
    let mut err = vec![0.0f32; np];
    let mut candidates = 0u64;
    // What each patch's E-step measures and which of its texels propose continuations:
    // subsets spread over the patch (`footprint::spread`), fixed for this patch size.
    let subsets = |count: u32, salt: u64| -> (Vec<usize>, Vec<u32>) {
        let per: Vec<Vec<u32>> = (0..np)
            .into_par_iter()
            .map(|p| {
                let (ts, ls) = fp.get(p);
                let mut out = Vec::new();
                spread(
                    ls,
                    0..ts.len(),
                    half,
                    count as usize,
                    hash(key, &[salt, p as u64]),
                    &mut out,
                );
                out
            })
            .collect();
        let mut start = Vec::with_capacity(np + 1);
        start.push(0);
        let mut list = Vec::with_capacity(per.iter().map(Vec::len).sum());
        for v in per {
            list.extend_from_slice(&v);
            start.push(list.len());
        }
        (start, list)
    };
    let (estart, elist) = subsets(params.eval_samples, 0xE5);
    let (pstart, plist) = subsets(params.proposers, 0x9F);
    for it in 0..params.iterations {
        // E-step: per patch, the nearest example patch among the candidates (visited in
        // the order of their centres, so that overlapping patches read `x` together).
        let order = fp.by_centre();
        let chosen: Vec<([f32; 2], f32, u64)> = order
            .par_iter()
            .map(|&p| {
                let p = p as usize;
                let (ts, ls) = fp.get(p);
                let measured_texels = &elist[estart[p]..estart[p + 1]];
                let mut cands: Vec<[f32; 2]> = Vec::with_capacity(48);
                let push = |c: &mut Vec<[f32; 2]>, q: [f32; 2]| {
                    let q = clamp(q);
                    if !c
                        .iter()
                        .any(|o| (o[0] - q[0]).abs() < 0.5 && (o[1] - q[1]).abs() < 0.5)
                    {
                        c.push(q);
                    }
                };
                push(&mut cands, z[p]);
                for &i in &plist[pstart[p]..pstart[p + 1]] {
                    let i = i as usize;
                    let s = source[ts[i] as usize];
                    push(&mut cands, [s[0] - ls[i][0], s[1] - ls[i][1]]);
                }
                let base = cands.clone();
                for q in base {
                    let (px, py) = (q[0].floor(), q[1].floor());
                    if px >= 0.0 && py >= 0.0 && (px as usize) < f.width && (py as usize) < f.height
                    {
                        let (fx, fy) = (q[0] - px, q[1] - py);
                        for (jx, jy) in ex.similar.of(px as usize, py as usize) {
                            push(&mut cands, [jx as f32 + fx, jy as f32 + fy]);
                        }
                    }
                }
                for k in 0..params.random as u64 {
                    let h = hash(key, &[it as u64, p as u64, k]);
                    let a = (h >> 40) as f32 / (1u64 << 24) as f32;
                    let b = ((h >> 8) & 0xFF_FFFF) as f32 / (1u64 << 24) as f32;
                    push(&mut cands, [lo + a * (hi_x - lo), lo + b * (hi_y - lo)]);
                }
                let mut best = (f32::INFINITY, z[p]);
                let mut measure = |q: [f32; 2]| {
                    let mut e = 0.0f32;
                    for &i in measured_texels {
                        let (t, l) = (ts[i as usize], ls[i as usize]);
                        e += dist2(&x[t as usize], &f.sample(q[0] + l[0], q[1] + l[1]));
                        if e >= best.0 {
                            break;
                        }
                    }
                    if e < best.0 {
                        best = (e, q);
                    }
                };
                for &q in &cands {
                    measure(q);
                }
                let mut measured = cands.len() as u64;
                if let Some(step) = params.exhaustive {
                    let step = step.max(1) as f32;
                    let mut qy = lo;
                    while qy <= hi_y.max(lo) {
                        let mut qx = lo;
                        while qx <= hi_x.max(lo) {
                            measure([qx, qy]);
                            measured += 1;
                            qx += step;
                        }
                        qy += step;
                    }
                }
                let samples = measured_texels.len() as f32;
                (best.1, best.0 / samples.max(1.0), measured)
            })
            .collect();
        for (&p, (q, e, c)) in order.iter().zip(chosen) {
            let p = p as usize;
            z[p] = q;
            err[p] = e;
            candidates += c;
        }
        // M-step: per texel, the votes of the patches covering it (`vote`: the level's).
        let expo = (params.r - 2.0) / 2.0;
        let omega: Vec<f32> = err.iter().map(|&e| (e + 1e-6).powf(expo)).collect();
        // In place: a texel's new value reads only its own state and the patches'
        // positions, so no per-texel copy of the state is held beside it.
        x.par_iter_mut()
            .zip(source.par_iter_mut())
            .zip(turn.par_iter_mut())
            .enumerate()
            .for_each_init(
                Vec::new,
                |votes: &mut Vec<Ballot<K>>, (t, ((xt, st), ot))| {
                    let (a, b) = (mstart[t] as usize, mstart[t + 1] as usize);
                    if a == b {
                        return;
                    }
                    votes.clear();
                    votes.extend((a..b).map(|k| {
                        let p = mlist[k] as usize;
                        let l = mcoord[k];
                        let s = [z[p][0] + l[0], z[p][1] + l[1]];
                        Ballot {
                            weight: omega[p] * falloff(l),
                            source: s,
                            turn: mturn[k],
                            value: f.sample(s[0], s[1]),
                        }
                    }));
                    (*xt, *st, *ot) = vote.count(votes);
                },
            );
        tick();
    }
    let energy = err.iter().map(|&e| e as f64).sum::<f64>() / np.max(1) as f64;
    SizeResult {
        source,
        turn,
        texture: x,
        footprints: fp,
        positions: z,
        energy,
        patches: np as u64,
        candidates,
    }
}

/// Sources of a finer level from a coarser one: each fine texel continues the nearest
/// coarse texel of its domain (same domain point scaled), doubled to the finer pixels.
/// The continuation follows the coarse texel's source orientation ψ: its source was laid
/// by a patch whose frame runs at ψ against the field there (the field turns against the
/// patch's transported frame away from its centre), so the offset in the field's frame is
/// turned by ψ first ([`turned`]); the fine texel keeps ψ. Measured (N = 32, `eval`, seeds
/// 1–4 on Spot, 1–2 or 1–3 elsewhere, bricks pf8 means): Spot 0.1025 → 0.0997 (courses
/// level) and 0.1058 → 0.1030, double torus 0.1084 → 0.1066 with its worst seam ratio
/// 1.24 → 0.98, the flat grid unchanged (ψ = 0 there), Blub 0.113 → 0.115, scales equal.
fn upsample<const K: usize>(
    coarse: &LevelTexels,
    csrc: &[[f32; 2]],
    cturn: &[Turn],
    fine: &LevelTexels,
    ex: &Exemplar<K>,
) -> (Vec<[f32; 2]>, Vec<Turn>) {
    let (lc, lf) = (coarse.layout(), fine.layout());
    let (w, h) = (ex.width() as f32, ex.height() as f32);
    (0..fine.len())
        .into_par_iter()
        .map(|t| {
            let (d, x, y) = lf.coords(t);
            let ((cu, cv), (fu, fv)) = (lc.dims(d), lf.dims(d));
            let cx = ((x as f64 + 0.5) * cu as f64 / fu as f64) as usize;
            let cy = ((y as f64 + 0.5) * cv as f64 / fv as f64) as usize;
            let q = lc.index(d, cx.min(cu - 1), cy.min(cv - 1));
            let dp = fine.geometry.pos[t] - coarse.geometry.pos[q];
            let [v1, v2] = coarse.frames[q];
            let k = coarse.inv_step_at(q);
            let e = turned([dp.dot(v1) * k, -dp.dot(v2) * k], cturn[q]);
            let s = [2.0 * (csrc[q][0] + e[0]), 2.0 * (csrc[q][1] + e[1])];
            (
                [s[0].clamp(0.5, w - 0.5), s[1].clamp(0.5, h - 0.5)],
                cturn[q],
            )
        })
        .unzip()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ballot(weight: f32, value: f32, source: f32) -> Ballot<2> {
        Ballot {
            weight,
            source: [source, 0.0],
            turn: Turn::from_radians(source / 100.0),
            value: [value, 0.0],
        }
    }

    #[test]
    fn the_mode_vote_takes_one_real_vote_of_the_heaviest_cluster_and_the_mean_averages() {
        // Three votes see a line (value 1), two see plain brick (0), all weighted alike.
        let votes = [
            ballot(1.0, 0.0, 10.0),
            ballot(1.0, 1.0, 20.0),
            ballot(1.0, 0.98, 21.0),
            ballot(1.0, 0.0, 11.0),
            ballot(1.0, 1.02, 22.0),
        ];
        let (v, s, o) = Vote::Mode.count(&votes);
        assert_eq!(
            o,
            Turn::from_radians(s[0] / 100.0),
            "the chosen vote's orientation goes with its source"
        );
        assert!(
            v[0] > 0.9 && s[0] >= 20.0,
            "one of the line's votes: {v:?} at {s:?}"
        );
        let real = votes.iter().any(|b| b.value == v && b.source == s);
        assert!(real, "a vote as it was, not a blend");
        let (v, s, o) = Vote::Mean.count(&votes);
        assert_eq!(
            o,
            Turn::from_radians(0.1),
            "the heaviest vote's orientation"
        );
        assert!((v[0] - 0.6).abs() < 1e-6, "the smear {v:?}");
        assert_eq!(s, [10.0, 0.0], "the first heaviest vote's source");
        // Weight decides: the two brick votes carrying most weight win.
        let mut heavy = votes;
        heavy[0].weight = 4.0;
        heavy[3].weight = 4.0;
        assert_eq!(Vote::Mode.count(&heavy).1, [10.0, 0.0]);
    }
}
