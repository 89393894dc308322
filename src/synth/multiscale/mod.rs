//! Multiscale synthesis on the surface (paper 000 §4, after Wei & Levoy), with ANN or
//! k-coherence search (paper 003 §5.2).
//!
//! **Levels.** Synthesis level `i` pairs example pyramid level `j0 + i` (pixel length
//! `S·2^(j0+i)` on the surface, S = `--scale`) with face maps of `R_i` texels per side,
//! chosen so that one texel covers about one example pixel of that level:
//! `R_i = round(N·h / (S·2^(j0+i)))` (N = `--resolution`, h = median texel spacing at N).
//! `j0 = max(0, round(log2(h / S)))` skips example levels finer than the output texels can
//! show (a texture scaled down). Levels stop when the example's shorter side would drop
//! below 16 pixels or a domain below 2x2 texels. With the default scale (S = h) this is the
//! plain pyramid: `R_i = N / 2^i`, example level `i`, sampling step δ_i = h·2^i — the step
//! doubles per level. `docs/multiscale.md` has worked examples.
//!
//! **Per-face resolutions** (`--texel-size`, [`TexelLayout`] per face): the plan above is
//! made for the typical side (the root mean square side, [`typical_side`]), and level i
//! halves *every* face's resolution, per side, as often as that plan's level i halves N
//! (never below one texel: [`TexelLayout::coarsened`]; [`level_layouts`]). Texel sets,
//! patterns, fetches, the schedule's domain ranges and the resampling to the output texels
//! all go through the level's layout, so one N is just the layout with every face alike
//! (and gives exactly the results it always gave).
//!
//! **Coarsest level**: domains in breadth-first order, texels in scan-line order;
//! neighbourhoods marched on the surface (000 §4.1; patterns do not fit charts at coarse
//! levels); exhaustive search under the Gaussian-weighted l2 over the generated samples,
//! fetched with the paper's rule (bilinear when all four texels are generated, the nearest
//! one when some are and it is, skipped otherwise: [`level::nearest_is_generated`]).
//!
//! **Finer levels**, two passes: pass 1 matches the 5x5 block of the coarser level only
//! (every texel independent); pass 2 refines with the 9x9 block of the level plus the same
//! 5x5 coarser block, in scan-line order inside each domain. Patterns inside a domain use
//! the domain as the chart; patterns crossing edges use the vertex charts (which march where
//! no chart fits) — see [`level::pattern`]. At the finest level pass 2 prefers the
//! continuation of an already refined neighbour when it matches nearly as well
//! ([`COHERENCE`], Ashikhmin's coherent choice), refining each domain from the edges of
//! finished domains inwards (`growth_order`).
//!
//! **Output**: each texel copies the centre pixel of the chosen example neighbourhood, and
//! its source position is recorded. When the finest synthesis level is not the output
//! resolution (`--scale` different from h), output texels continue the patch of the nearest
//! synthesized texel: source = its source + the tangent offset / S, the continuation rule of
//! coherent synthesis (000 §5).
//!
//! **Determinism**: random choices hash (seed, level, pass, texel). Domains run in the
//! waves of [`crate::synth::schedule`]; a domain reads other domains as they were when its
//! wave started and its own texels as it writes them ([`level::View`]), so results are
//! bit-identical for any thread count.

pub mod level;

use crate::error::{Error, Result};
use crate::example::Example;
use crate::field::OrientationField;
use crate::layout::TexelLayout;
use crate::pyramid::{levels_for, Image};
use crate::random::hash;
use crate::sampling::{sparse_keeps, Sampler, SamplerKind, SamplerStats};
use crate::synth::matching::appearance::{
    Appearance, AppearanceInfo, AppearanceMode, DIMS, WINDOW,
};
use crate::synth::matching::search::model::{ExampleModel, Method, ModelParams, Pass, Scratch};
use crate::synth::matching::search::{pick, Prepared, Query};
use crate::synth::schedule::{inward_order, Schedule};
use level::{
    nearest_texel, pattern, Anchors, LevelGeometry, Lookup, Own, PatternScratch, PatternStats, View,
};
use rayon::prelude::*;
use serde::Serialize;
use std::sync::atomic::{AtomicUsize, Ordering::AcqRel};
use std::sync::{Arc, OnceLock};
use std::time::Instant;
use subdiv::{DomainLocation, Surface};

/// Smallest example side at the coarsest synthesis level.
pub const MIN_EXAMPLE_SIDE: usize = 16;
/// Smallest face-map side at the coarsest synthesis level ("down to a size where domains are
/// a few texels"; measured: stopping at 4 instead of 2 lost the large-scale layout at N = 12,
/// seam ratio 1.56 instead of 0.81 on Blub with the leopard example).
pub const MIN_RESOLUTION: usize = 2;

/// Settings of multiscale synthesis.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MultiscaleParams {
    /// Neighbourhood sizes and search method.
    pub model: ModelParams,
    /// At most this many levels (0: as many as fit).
    pub max_levels: usize,
    /// Spacing tolerance of vertex-chart patterns ([`Sampler::with_tolerance`]); `None`
    /// accepts every pattern that fits a chart, as the paper does.
    pub sampler_tolerance: Option<f64>,
    /// Spacing tolerance of the parameter-space patterns ([`level::pattern`]).
    pub pattern_tolerance: f64,
    /// κ of the coherent choice at the finest level ([`COHERENCE`]); `None`: the
    /// paper's randomised choice there too.
    pub coherence: Option<f32>,
    /// Pass 2 compares the level's own block at the samples of the sparse block only
    /// ([`sparse_gains`]; sides 9, 13, ...), else at every sample. On by default: 0.90x
    /// the CPU of a Spot N = 32 run, and over seeds 1–3 on Spot, the double torus and
    /// the flat grid with bricks, scales and gravel every mean pf1/pf4/pf8 within the
    /// seeds' spread or below it (bricks pf8 on Spot 0.134 → 0.129), seams alike
    /// (docs/multiscale.md, "Speed, second round"). Textons keep the full block (not
    /// measured there).
    pub sparse: bool,
    /// The finest level starts pass 2 from its texels' continuations of the coarser level
    /// (`continued`) instead of pass 1's matches. On by default for the same reason and
    /// measured the same way: pass 1 at the finest level was a fifth of a run, and
    /// bricks came out better without it (pf4 on Spot 0.081 → 0.073, double torus
    /// 0.098 → 0.084), scales and gravel within the spread. Textons keep pass 1.
    pub continue_finest: bool,
}

/// κ of the finest level's coherent choice (Ashikhmin 2001; the κ of Hertzmann et al.'s
/// image analogies): in pass 2 of the finest level a texel takes the best of its settled
/// neighbours' continuations (neighbours already refined in this pass, or in a finished
/// domain) when it is within (1 + κ)² of the best match's distance, else the randomised
/// choice ([`pick`]). Why: on a brick's face every place of the example looks alike, so
/// the randomised choice among near-equal matches landed anywhere, often 2–4 pixels beside
/// the continuation: BRIEF counts such a pair as a continued patch and reads the jump as
/// stretch (scale fidelity p90 2.8 on Spot and 3.0 on the double torus with bricks), and
/// the eye sees lost grain. The finest level is refined from the edges of finished
/// domains inwards (`growth_order`) so that the neighbours' patches continue across
/// them. Measured (N = 32, seed 1, `eval`): p90 2.76 → 1.05 (Spot) and 3.03 → 1.04 (double
/// torus), bricks pf8 0.151 → 0.138 and 0.177 → 0.151. Only at the finest level: at every
/// level the seams of scales and gravel rose (double torus scales 0.84 → 1.22) and their
/// pf8 by 3–10%. Continuations of neighbours not yet refined are left out (taking them
/// left p90 at 1.18: they change after). κ: 0.3 left Blub's bricks at p90 1.102 and the
/// double torus's gravel at seam 1.17, 0.5 raised the double torus's scales seam to 1.15
/// and the flat grid's gravel pf8 by 7%; 0.4 kept every measured case inside both bars.
/// docs/multiscale.md, "Coherent choice".
pub const COHERENCE: f32 = 0.4;

impl Default for MultiscaleParams {
    fn default() -> Self {
        Self {
            model: ModelParams::default(),
            max_levels: 0,
            sampler_tolerance: Some(crate::sampling::DEFAULT_TOLERANCE),
            pattern_tolerance: level::PATTERN_TOLERANCE,
            coherence: Some(COHERENCE),
            sparse: true,
            continue_finest: true,
        }
    }
}

/// What the synthesizer needs besides the example.
#[derive(Clone, Copy)]
pub struct Inputs<'a> {
    pub surface: &'a Surface,
    pub field: &'a OrientationField,
    /// The output texels: N per side on every domain (`--resolution`), or every face's own
    /// resolution (`--texel-size`).
    pub layout: &'a Arc<TexelLayout>,
    /// Median texel spacing of the output texels (h).
    pub spacing: f64,
    /// Surface length of one example pixel (S).
    pub scale: f64,
    /// The scale map's factor (`--scale-map`): each texel samples at its level's step ×
    /// the factor there; levels are planned for S × the smallest factor.
    pub scale_field: Option<&'a crate::scale_field::ScaleField>,
    pub seed: u64,
    /// Matching weight per example channel ([`crate::synth::Weights::per_channel`]).
    pub weights: &'a [f32],
    /// What neighbourhoods compare: the weighted channels, or every level's appearance
    /// vectors ([`crate::synth::matching::appearance`]).
    pub appearance: AppearanceMode,
    /// Weight of the feature-distance channel matched beside the weighted channels (in
    /// appearance space only; 0: none; [`crate::synth::matching::feature_distance`]).
    pub feature_distance: f32,
}

/// One synthesis level (reported).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct LevelPlan {
    /// Example pyramid level.
    pub example_level: usize,
    /// Its size in pixels.
    pub example_size: [usize; 2],
    /// Face-map texels per side (per-face resolutions: the root mean square side,
    /// [`typical_side`]).
    pub resolution: usize,
    /// Sampling step δ (surface length of one pixel of that example level).
    pub step: f64,
}

/// Counters and times of a run (reported).
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct Stats {
    /// "brute", "ann" or "kcoherence".
    pub search: String,
    /// Coarsest last.
    pub levels: Vec<LevelPlan>,
    /// Neighbourhood searches.
    pub queries: u64,
    /// Candidate distances evaluated.
    pub candidates: u64,
    /// Coarsest-level texels with no generated sample around (a random example pixel).
    pub seeded: u64,
    pub patterns: PatternStats,
    pub sampler: SamplerStats,
    /// Finest-level texels whose source was made continuous from neighbours of the same
    /// patch ([`PATCH_TOLERANCE`]).
    pub continued: u64,
    /// Output texels continued from a synthesis level of another resolution.
    pub resampled: u64,
    /// Seconds: example analysis (pyramid, features, search structures).
    pub model_seconds: f64,
    /// Seconds: texel geometry and frames of all levels.
    pub geometry_seconds: f64,
    /// Seconds: searching and copying.
    pub search_seconds: f64,
    /// What was matched (the finest level's appearance space).
    pub appearance: AppearanceInfo,
}

/// Source position per output texel (level-0 example pixels, centres at +0.5) and stats.
#[derive(Clone, Debug)]
pub struct Output {
    pub source: Vec<[f32; 2]>,
    pub stats: Stats,
}

/// Synthesis levels for an example of `ex_w x ex_h` pixels: `j0` and, finest first, the
/// face-map resolution of each level (see the module documentation).
pub fn plan_levels(
    ex_w: usize,
    ex_h: usize,
    n: usize,
    spacing: f64,
    scale: f64,
    max_levels: usize,
) -> Result<(usize, Vec<usize>)> {
    if !(spacing > 0.0 && scale > 0.0 && spacing.is_finite() && scale.is_finite()) {
        return Err(Error::invalid(format!(
            "multiscale synthesis needs a positive texel spacing and scale, got {spacing} and {scale}"
        )));
    }
    let ex_levels = levels_for(ex_w, ex_h, MIN_EXAMPLE_SIDE, 16);
    let j0 = ((spacing / scale).log2().round().max(0.0) as usize).min(ex_levels - 1);
    let cap = if max_levels == 0 {
        usize::MAX
    } else {
        max_levels
    };
    let mut res = Vec::new();
    for j in j0..ex_levels {
        // The exact size, not the rounded one, decides: N = 12 would otherwise get a 1.5
        // texel level rounded up to 2 (a third too many texels for the example's pixels).
        let exact = n as f64 * spacing / (scale * (1u64 << j) as f64);
        let r = (exact.round() as usize).max(1);
        if !res.is_empty() && exact < MIN_RESOLUTION as f64 {
            break;
        }
        res.push(r);
        if res.len() >= cap {
            break;
        }
    }
    Ok((j0, res))
}

/// The typical texels per side of `layout`: N for one N, else the root mean square side
/// (√(texels / faces), rounded), what the level plan of per-face resolutions halves (as
/// texture optimisation's does).
pub fn typical_side(layout: &TexelLayout) -> usize {
    layout.uniform_n().unwrap_or_else(|| {
        ((layout.len() as f64 / layout.faces().max(1) as f64)
            .sqrt()
            .round() as usize)
            .max(1)
    })
}

/// The texels of every synthesis level, finest first, for the output texels `out` and the
/// plan `res` of [`plan_levels`] (made for the typical side, [`typical_side`]). One N:
/// `res[i]` per side on every domain, as always. Per-face resolutions: every face's own
/// resolution halved per level and per side (never below one texel: [`TexelLayout::coarsened`]);
/// the finest synthesis level is the output halved k₀ times, k₀ = round(log2(S·2^j0 / h))
/// (0 at the default scale; more for a texture larger than the texels), so that level i's
/// texels cover about one pixel of example level j0 + i on every face, as `res[i]` does for
/// one N.
pub fn level_layouts(
    out: &Arc<TexelLayout>,
    res: &[usize],
    j0: usize,
    spacing: f64,
    scale: f64,
) -> Vec<Arc<TexelLayout>> {
    match out.uniform_n() {
        Some(_) => res
            .iter()
            .map(|&r| Arc::new(TexelLayout::uniform(out.faces(), r)))
            .collect(),
        None => {
            let k0 = (scale * (1u64 << j0) as f64 / spacing)
                .log2()
                .round()
                .max(0.0) as u32;
            (0..res.len() as u32)
                .map(|i| match k0 + i {
                    0 => out.clone(),
                    k => Arc::new(out.coarsened(k)),
                })
                .collect()
        }
    }
}

/// Domains sharing an edge, or an edge with a domain that does: the domains whose texels
/// one domain's 9x9 patterns can reach at one-texel steps, used to colour the waves.
fn conflicts(adj: &[Vec<u32>]) -> Vec<Vec<u32>> {
    adj.iter()
        .enumerate()
        .map(|(d, a)| {
            let mut v: Vec<u32> = a.clone();
            for &e in a {
                v.extend(adj[e as usize].iter().copied());
            }
            v.sort_unstable();
            v.dedup();
            v.retain(|&e| e as usize != d);
            v
        })
        .collect()
}

/// The scale map's factor per texel of one level (`None`: no scale map, 1 everywhere).
struct Factors(Option<Vec<f64>>);

impl Factors {
    fn of(inputs: &Inputs<'_>, geo: &LevelGeometry) -> Self {
        Factors(
            inputs
                .scale_field
                .map(|f| f.factors(inputs.surface, geo.len(), |t| geo.location(t))),
        )
    }

    /// `base` (a level's step) at texel `t`.
    #[inline]
    fn step(&self, base: f64, t: usize) -> f64 {
        match &self.0 {
            None => base,
            Some(f) => base * f[t],
        }
    }
}

/// One level's synthesized state: the example feature index each texel was copied from
/// (its values, the weighted example channels there, are read through [`Lookup`]).
struct State {
    src: Vec<u32>,
}

/// Per-thread working buffers.
struct Work {
    scratch: Scratch,
    q: Query,
    prep: Prepared,
    seeds: Vec<u32>,
    /// Pass 2's continuations of settled neighbours ([`COHERENCE`]).
    coherent: Vec<u32>,
    locs: Vec<Option<DomainLocation>>,
    pat: PatternScratch,
    val: Vec<f32>,
    pst: PatternStats,
    queries: u64,
    candidates: u64,
    seeded: u64,
}

impl Work {
    fn new(model: &ExampleModel, level: usize, pass: Pass) -> Self {
        let shape = model.shape(level, pass);
        Self {
            scratch: Scratch::default(),
            q: Query::new(shape),
            prep: Prepared::default(),
            seeds: Vec::new(),
            coherent: Vec::new(),
            locs: vec![
                None;
                81.max(shape.fine * shape.fine)
                    .max(shape.coarse * shape.coarse)
            ],
            pat: PatternScratch::default(),
            val: vec![0.0; shape.channels],
            pst: PatternStats::default(),
            queries: 0,
            candidates: 0,
            seeded: 0,
        }
    }
}

/// Everything shared by the level passes.
struct Ctx<'a> {
    model: &'a ExampleModel,
    sampler: &'a Sampler<'a>,
    seed: u64,
    /// Sampling step of each synthesis level.
    steps: Vec<f64>,
    kwindow: Option<usize>,
    /// [`MultiscaleParams::coherence`].
    coherence: Option<f32>,
    channels: usize,
    pattern_tolerance: f64,
    /// [`MultiscaleParams::sparse`].
    sparse: bool,
}

impl Ctx<'_> {
    fn key(&self, level: usize, pass: Pass, t: usize) -> u64 {
        hash(self.seed, &[level as u64, pass.id(), t as u64])
    }

    /// Searches with the prepared query in `w` and returns the chosen feature index.
    fn choose(&self, level: usize, pass: Pass, t: usize, w: &mut Work) -> u32 {
        let model = self.model;
        let f = &model.searcher(level, pass).features;
        if matches!(model.params.method, Method::Ann(_)) {
            f.prepare(&w.q, &mut w.prep);
        } else {
            f.prepare_distances(&w.q, &mut w.prep);
        }
        let n = model.search(level, pass, &w.prep, &w.seeds, &mut w.scratch);
        w.queries += 1;
        w.candidates += n as u64;
        let key = self.key(level, pass, t);
        let top = w.scratch.top.as_slice();
        // `w.coherent` is filled only in pass 2 of the finest level ([`COHERENCE`]).
        let Some(kappa) = self
            .coherence
            .filter(|_| !w.coherent.is_empty() && !top.is_empty())
        else {
            return pick(top, key).index;
        };
        let bound = top[0].dist2 * (1.0 + kappa) * (1.0 + kappa);
        let mut best: Option<(f32, u32)> = None;
        for &c in &w.coherent {
            // What the search measured, where that settles it (`KScratch::measured`).
            let d = match w.scratch.kcoh.measured(c) {
                Some((d, b)) if d <= b => d,
                Some((_, b)) if b >= bound => continue,
                _ => f.distance(&w.prep, c as usize, bound),
            };
            if d <= bound && best.is_none_or(|(bd, bi)| d < bd || (d == bd && c < bi)) {
                best = Some((d, c));
            }
        }
        best.map_or_else(|| pick(top, key).index, |(_, c)| c)
    }

    /// The K×K pattern of texel `t` of `geo` at step `delta` into `w.locs`
    /// ([`level::pattern`] with this run's sampler and tolerance and `w`'s scratch).
    #[allow(clippy::too_many_arguments)]
    fn pattern(
        &self,
        geo: &LevelGeometry,
        t: usize,
        delta: f64,
        k: usize,
        kind: SamplerKind,
        sparse: bool,
        w: &mut Work,
    ) {
        pattern(
            geo,
            self.sampler,
            t,
            delta,
            k,
            kind,
            sparse,
            self.pattern_tolerance,
            &mut w.locs,
            &mut w.pat,
            &mut w.pst,
        );
    }

    /// The values (weighted channels) of every feature of `level`, for a [`View`].
    fn lookup(&self, level: usize) -> Lookup<'_> {
        let f = &self.model.searcher(level, Pass::Two).features;
        let img = self.model.pyramid.level(level);
        Lookup {
            data: &img.data,
            width: img.width,
            margin: f.margin,
            cols: f.cols,
            channels: img.channels,
        }
    }

    /// Continuous position of feature `index` at `level` (that level's pixels).
    fn position(&self, level: usize, index: u32) -> [f32; 2] {
        let (x, y) = self.model.pixel(level, index);
        [x as f32 + 0.5, y as f32 + 0.5]
    }
}

/// The example side of a run: the search model over the (appearance-space) pyramid and
/// what was matched. Saved in the cache as its pyramid and k-coherence lists
/// ([`crate::cache::Persist`]); the features are gathered again on load.
pub struct Model {
    pub model: ExampleModel,
    pub appearance: AppearanceInfo,
}

/// Where [`run_with`] gets its [`Model`]: `models(key, build)` returns the model of `key`
/// (a hash of everything it depends on), calling `build` when it has none.
pub type ModelSource<'a> =
    dyn Fn(crate::cache::Key, &dyn Fn() -> Result<Model>) -> Result<std::sync::Arc<Model>> + 'a;

/// Runs multiscale synthesis of `example` on the surface. `progress(done, total)` counts
/// texel passes over all levels.
pub fn run(
    example: &Example,
    inputs: &Inputs<'_>,
    params: &MultiscaleParams,
    progress: &(dyn Fn(u64, u64) + Sync),
) -> Result<Output> {
    run_with(
        example,
        inputs,
        params,
        &|_, build| build().map(std::sync::Arc::new),
        progress,
    )
}

/// [`run`] with the example analysis from `models` (e.g. [`crate::synth::Analyses`]: kept
/// for later runs and in the disk cache).
pub fn run_with(
    example: &Example,
    inputs: &Inputs<'_>,
    params: &MultiscaleParams,
    models: &ModelSource<'_>,
    progress: &(dyn Fn(u64, u64) + Sync),
) -> Result<Output> {
    let c = example.num_channels();
    if inputs.weights.len() != c {
        return Err(Error::invalid(format!(
            "{} channel weights for an example with {c} channels",
            inputs.weights.len()
        )));
    }
    let build = |j0: usize, n_levels: usize| -> Result<std::sync::Arc<Model>> {
        // Example analysis: weighted channels (so that plain l2 is the weighted distance),
        // pyramid from level j0.
        let mut img = crate::synth::matching::features::weighted(example, inputs.weights);
        if inputs.feature_distance > 0.0 && inputs.appearance == AppearanceMode::Pca {
            img = crate::synth::matching::feature_distance::with_feature_distance(
                &img,
                inputs.feature_distance,
            );
        }
        for _ in 0..j0 {
            img = img.downsample();
        }
        let key = model_key(&img, n_levels, inputs.appearance, &params.model);
        models(key, &|| {
            // Appearance space per level: each level's own 5x5 neighbourhoods, projected.
            let mut pyramid = crate::pyramid::Pyramid::build(img.clone(), n_levels);
            let mut appearance = None;
            if inputs.appearance == AppearanceMode::Pca {
                for level in &mut pyramid.levels {
                    let a = Appearance::build(level, AppearanceMode::Pca, WINDOW, DIMS);
                    appearance.get_or_insert(a.info);
                    *level = a.image;
                }
            }
            let appearance = appearance.unwrap_or(AppearanceInfo {
                dims: c,
                window: 1,
                kept_variance: 1.0,
                feature_distance: 0.0,
                reflectance: None,
            });
            Ok(Model {
                model: ExampleModel::from_pyramid(pyramid, params.model)?,
                appearance,
            })
        })
    };
    run_on_model(
        [example.width, example.height],
        inputs,
        params,
        &build,
        progress,
    )
}

/// Where [`run_on_model`] gets its model: `build(j0, levels)` returns the search model of
/// `levels` pyramid levels starting at example level `j0` (the first level finer than the
/// texels can show skipped).
pub type ModelBuilder<'a> = dyn Fn(usize, usize) -> Result<std::sync::Arc<Model>> + 'a;

/// The synthesis itself, on any example-side model of an example of `size` pixels: what
/// [`run_with`] does after building the (appearance-space) pyramid, and what texton
/// synthesis ([`crate::synth::textons`]) runs on its pyramid of texton embeddings.
pub fn run_on_model(
    size: [usize; 2],
    inputs: &Inputs<'_>,
    params: &MultiscaleParams,
    build: &ModelBuilder<'_>,
    progress: &(dyn Fn(u64, u64) + Sync),
) -> Result<Output> {
    let out_layout = inputs.layout;
    let surface = inputs.surface;
    if out_layout.faces() != surface.num_domains() || out_layout.is_empty() {
        return Err(Error::invalid(format!(
            "multiscale synthesis: a texel layout of {} domains ({} texels) for a surface of {}",
            out_layout.faces(),
            out_layout.len(),
            surface.num_domains()
        )));
    }
    // N, or with per-face resolutions the typical side: what the level plan halves.
    let n = typical_side(out_layout);
    let reference = match inputs.scale_field {
        None => inputs.scale,
        Some(f) => inputs.scale * f.range().0,
    };
    let (j0, res) = plan_levels(
        size[0],
        size[1],
        n,
        inputs.spacing,
        reference,
        params.max_levels,
    )?;
    let n_levels = res.len();
    let layouts = level_layouts(out_layout, &res, j0, inputs.spacing, reference);
    let t0 = Instant::now();
    let built = build(j0, n_levels)?;
    let (model, appearance) = (&built.model, built.appearance);
    let model_seconds = t0.elapsed().as_secs_f64();

    let steps: Vec<f64> = (0..n_levels)
        .map(|i| inputs.scale * (1u64 << (j0 + i)) as f64)
        .collect();
    let sampler = Sampler::new(surface, inputs.field).with_tolerance(params.sampler_tolerance);
    let ctx = Ctx {
        model,
        sampler: &sampler,
        seed: inputs.seed,
        steps,
        kwindow: match params.model.method {
            Method::KCoherence(k) => Some(k.window),
            _ => None,
        },
        coherence: params.coherence,
        channels: model.pyramid.level(0).channels,
        pattern_tolerance: params.pattern_tolerance,
        sparse: params.sparse,
    };
    let adj = crate::texels::domain_edge_adjacency(surface);
    let conflicts = conflicts(&adj);
    let schedule = Schedule::plan(&adj, &conflicts);
    let order = DomainOrder::new(&schedule, &conflicts);
    let total: u64 = layouts
        .iter()
        .enumerate()
        .map(|(i, l)| l.len() as u64 * if i + 1 == n_levels { 1 } else { 2 })
        .sum();
    let mut done = 0u64;
    let mut stats = Stats {
        search: params.model.method.name().into(),
        levels: layouts
            .iter()
            .enumerate()
            .map(|(i, l)| {
                let im = model.pyramid.level(i);
                LevelPlan {
                    example_level: j0 + i,
                    example_size: [im.width, im.height],
                    resolution: typical_side(l),
                    step: ctx.steps[i],
                }
            })
            .collect(),
        model_seconds,
        appearance,
        ..Stats::default()
    };

    let mut geometry_seconds = 0.0;
    let mut search_seconds = 0.0;
    let top = n_levels - 1;
    let t0 = Instant::now();
    let corners = std::sync::Arc::new(level::regular_corners(surface));
    let mut geo =
        LevelGeometry::with_layout(surface, inputs.field, layouts[top].clone(), corners.clone());
    let mut fac = Factors::of(inputs, &geo);
    geometry_seconds += t0.elapsed().as_secs_f64();
    let t0 = Instant::now();
    let mut state = coarsest(&ctx, top, &geo, &fac, &order, &mut stats);
    search_seconds += t0.elapsed().as_secs_f64();
    done += geo.len() as u64;
    progress(done, total);
    for i in (0..top).rev() {
        let t0 = Instant::now();
        let fine =
            LevelGeometry::with_layout(surface, inputs.field, layouts[i].clone(), corners.clone());
        let fine_fac = Factors::of(inputs, &fine);
        geometry_seconds += t0.elapsed().as_secs_f64();
        let t0 = Instant::now();
        let (s1, anchors) = if i == 0 && params.continue_finest {
            (continued(&ctx, i, &fine, &fine_fac, &geo, &state), None)
        } else {
            pass_one(&ctx, i, &fine, &fine_fac, &geo, &state, &mut stats)
        };
        done += fine.len() as u64;
        progress(done, total);
        let s2 = pass_two(
            &ctx, surface, i, &fine, &fine_fac, &geo, &state, &order, s1, anchors, &mut stats,
        );
        search_seconds += t0.elapsed().as_secs_f64();
        done += fine.len() as u64;
        progress(done, total);
        geo = fine;
        fac = fine_fac;
        state = s2;
    }

    // Sources in level-0 example pixels, made continuous.
    let State { src } = state;
    let up = (1u64 << j0) as f32;
    let discrete: Vec<[f32; 2]> = src
        .iter()
        .map(|&s| {
            let p = ctx.position(0, s);
            [p[0] * up, p[1] * up]
        })
        .collect();
    drop(src);
    let finest = continuous_sources(surface, &geo, &fac, &discrete, inputs.scale, up, &mut stats);
    drop(discrete);
    let source = if geo.texels() == &**out_layout && j0 == 0 {
        finest
    } else {
        let t0 = Instant::now();
        let out_geo =
            LevelGeometry::with_layout(surface, inputs.field, out_layout.clone(), corners.clone());
        let out_fac = Factors::of(inputs, &out_geo);
        geometry_seconds += t0.elapsed().as_secs_f64();
        stats.resampled = out_geo.len() as u64;
        resample(&out_geo, &out_fac, &geo, &finest, inputs.scale, size)
    };
    stats.geometry_seconds = geometry_seconds;
    stats.search_seconds = search_seconds;
    stats.sampler = sampler.stats();
    Ok(Output { source, stats })
}

/// Largest distance (in pixels of the finest synthesis level) between a texel's own
/// source and a neighbour's continuation for the two to count as one patch in
/// `continuous_sources`.
pub const PATCH_TOLERANCE: f32 = 1.5;

/// Smoothing steps of `continuous_sources` after the tree layout.
pub const CONTINUATION_ITERATIONS: usize = 4;

/// Continuous source positions for the finest level.
///
/// Multiscale synthesis copies whole example pixels, so a texel's source is a pixel
/// centre. Where texels are denser or sparser than example pixels (faces of different
/// sizes, N·h/S not a power of two), neighbouring texels of one copied patch then step by
/// 0 or 2 pixels where 1.3 would be right: a wrong local scale (measured on a creased
/// frustum: scale fidelity median 1.06, p10–p90 0.0–1.89; the 3x3 mean of continuations
/// used before brought it only to 0.68–1.37, and the issue saw 0.62–2.07 on a penguin),
/// shown as blocky magnification and stretched copies. So each *patch* — texels whose
/// discrete sources continue each other: a neighbour's source minus the offset between
/// them, in example pixels (the rule of coherent synthesis, 000 §5), within
/// [`PATCH_TOLERANCE`] pixels — is laid out anew as an exact continuation: breadth-first
/// from its first texel, each texel at its tree parent's source plus their offset, then
/// moved as a whole to fit its discrete sources on average (where the synthesis put it).
/// [`CONTINUATION_ITERATIONS`] half-Jacobi steps then spread what the field's curl leaves
/// between tree branches. Measured after: median 1.000, p10–p90 0.97–1.06. Texels with no
/// coherent neighbour keep their pixel centre. Colours are looked up bilinearly at these
/// positions, so patches are resampled rather than repeated or skipped.
fn continuous_sources(
    surface: &Surface,
    geo: &LevelGeometry,
    fac: &Factors,
    src: &[[f32; 2]],
    scale: f64,
    up: f32,
    stats: &mut Stats,
) -> Vec<[f32; 2]> {
    let texels = geo.texels();
    let tol = PATCH_TOLERANCE * up;
    let tol2 = tol * tol;
    let n_t = geo.len();
    // The offset e(t, q) from texel t to its neighbour q in example pixels (t's frame and
    // step): recomputed where needed rather than stored with every link.
    let offset = |t: usize, q: usize| geo.offset_pixels(t, q, fac.step(scale, t));
    // Coherent neighbours of every texel, at most 8, found in parallel into fixed slots and
    // then packed into one list with per-texel starts (a Vec of (neighbour, offset) per
    // texel, and one of back links, cost ~270 B/texel in headers, allocations and
    // offsets; this is 4 B per link each way).
    const SLOTS: usize = 8;
    let mut slots = vec![0u32; n_t * SLOTS];
    let mut counts = vec![0u8; n_t];
    slots
        .par_chunks_mut(SLOTS)
        .zip(counts.par_iter_mut())
        .enumerate()
        .for_each(|(t, (out, count))| {
            let loc = geo.location(t);
            let (nu, nv) = texels.dims(loc.domain.idx());
            let p = src[t];
            let mut len = 0;
            for b in -1i32..=1 {
                for a in -1i32..=1 {
                    if a == 0 && b == 0 {
                        continue;
                    }
                    let (du, dv) = (a as f64 / nu as f64, b as f64 / nv as f64);
                    let Some(l) = surface.walk(loc, du, dv) else {
                        continue;
                    };
                    let Some(q) = nearest_texel(&geo.layout.taps(l)) else {
                        continue;
                    };
                    if q == t || out[..len].iter().any(|&o| o as usize == q) {
                        continue;
                    }
                    let e = offset(t, q);
                    let c = [src[q][0] - e[0], src[q][1] - e[1]];
                    let (dx, dy) = (c[0] - p[0], c[1] - p[1]);
                    if dx * dx + dy * dy <= tol2 {
                        out[len] = q as u32;
                        len += 1;
                    }
                }
            }
            *count = len as u8;
        });
    // Pack in place (entries only move towards the front).
    let mut link_start = Vec::with_capacity(n_t + 1);
    let mut at = 0usize;
    for (t, &k) in counts.iter().enumerate() {
        link_start.push(at as u32);
        slots.copy_within(t * SLOTS..t * SLOTS + k as usize, at);
        at += k as usize;
    }
    link_start.push(at as u32);
    drop(counts);
    slots.truncate(at);
    slots.shrink_to_fit();
    let links = Flat {
        start: link_start,
        items: slots,
    };
    stats.continued = (0..n_t).filter(|&t| !links.of(t).is_empty()).count() as u64;
    // Each connected patch (over links in either direction) is laid out by a breadth-first
    // tree from its first texel — exact continuation along the tree — and moved as a whole
    // to fit its discrete sources on average; Jacobi steps then spread what the field's
    // curl leaves between tree branches.
    //
    // t's link to q with offset e(t, q): q's link back to t has offset ≈ −e. Back links of
    // q in increasing t.
    let back = {
        let mut start = vec![0u32; n_t + 1];
        for &q in &links.items {
            start[q as usize + 1] += 1;
        }
        for i in 0..n_t {
            start[i + 1] += start[i];
        }
        let mut fill: Vec<u32> = start[..n_t].to_vec();
        let mut items = vec![0u32; links.items.len()];
        for t in 0..n_t {
            for &q in links.of(t) {
                let f = &mut fill[q as usize];
                items[*f as usize] = t as u32;
                *f += 1;
            }
        }
        Flat { start, items }
    };
    let linked = |t: usize| !(links.of(t).is_empty() && back.of(t).is_empty());
    // Every neighbour of t over links in either direction, with the offset from t: links
    // first, then back links (whose offset is minus the other texel's).
    let around = |t: usize| {
        let fwd = links
            .of(t)
            .iter()
            .map(move |&q| (q as usize, offset(t, q as usize)));
        let bwd = back.of(t).iter().map(move |&o| {
            let e = offset(o as usize, t);
            (o as usize, [-e[0], -e[1]])
        });
        fwd.chain(bwd)
    };
    // `cur` holds the tree layout (relative to the root) of a patch's members while it is
    // laid out, then their positions.
    let mut cur: Vec<[f64; 2]> = src.iter().map(|s| [s[0] as f64, s[1] as f64]).collect();
    let mut seen = vec![false; n_t];
    let mut queue = std::collections::VecDeque::new();
    let mut members = Vec::new();
    for root in 0..n_t {
        if seen[root] || !linked(root) {
            continue;
        }
        seen[root] = true;
        members.clear();
        queue.push_back(root);
        cur[root] = [0.0f64, 0.0f64];
        while let Some(t) = queue.pop_front() {
            members.push(t);
            let st = cur[t];
            for (q, e) in around(t) {
                if !seen[q] {
                    seen[q] = true;
                    // s(q) = s(t) + e(t, q).
                    cur[q] = [st[0] + e[0] as f64, st[1] + e[1] as f64];
                    queue.push_back(q);
                }
            }
        }
        let (mut dx, mut dy) = (0.0f64, 0.0f64);
        for &t in &members {
            let p = cur[t];
            dx += src[t][0] as f64 - p[0];
            dy += src[t][1] as f64 - p[1];
        }
        let m = members.len() as f64;
        for &t in &members {
            let p = cur[t];
            cur[t] = [p[0] + dx / m, p[1] + dy / m];
        }
    }
    drop(seen);
    for _ in 0..CONTINUATION_ITERATIONS {
        cur = (0..n_t)
            .into_par_iter()
            .map(|t| {
                if !linked(t) {
                    return cur[t];
                }
                let (mut sx, mut sy, mut w) = (0.0f64, 0.0f64, 0.0f64);
                for (q, e) in around(t) {
                    let c = cur[q];
                    sx += c[0] - e[0] as f64;
                    sy += c[1] - e[1] as f64;
                    w += 1.0;
                }
                // Half a step: keeps the tree's layout where the links agree.
                [0.5 * (cur[t][0] + sx / w), 0.5 * (cur[t][1] + sy / w)]
            })
            .collect();
    }
    cur.into_iter()
        .map(|c| [c[0] as f32, c[1] as f32])
        .collect()
}

/// Per-texel lists packed into one: texel `t`'s are `items[start[t]..start[t + 1]]`.
struct Flat<T> {
    start: Vec<u32>,
    items: Vec<T>,
}

impl<T> Flat<T> {
    #[inline]
    fn of(&self, t: usize) -> &[T] {
        &self.items[self.start[t] as usize..self.start[t + 1] as usize]
    }
}

/// Output texel sources continued from the nearest texel of the finest synthesis level.
fn resample(
    out: &LevelGeometry,
    out_fac: &Factors,
    syn: &LevelGeometry,
    src: &[[f32; 2]],
    scale: f64,
    size: [usize; 2],
) -> Vec<[f32; 2]> {
    let (hi_x, hi_y) = (size[0] as f32 - 0.5, size[1] as f32 - 0.5);
    (0..out.len())
        .into_par_iter()
        .map(|t| {
            let loc = out.location(t);
            let q = nearest_texel(&syn.layout.taps(loc)).unwrap_or(0);
            let d = (out.pos[t] - syn.pos[q]).as_dvec3();
            let f = out.frame(t);
            let scale = out_fac.step(scale, t);
            let e = [(d.dot(f.v1) / scale) as f32, (-d.dot(f.v2) / scale) as f32];
            let s = src[q];
            [
                (s[0] + e[0]).clamp(0.5, hi_x),
                (s[1] + e[1]).clamp(0.5, hi_y),
            ]
        })
        .collect()
}

/// Results of one domain task: its texels' sources and counters. Not its [`Work`]: that
/// holds the search scratch (k-coherence's stamp per example feature, 64 KB for a 128²
/// example, 1 MB for 512²), and kept for every domain until the pass ends it was the
/// run's peak on many-domain meshes (2.5 GB for the bunny's 19,794 domains at N = 8).
struct DomainOut {
    src: Vec<u32>,
    counts: Counts,
}

/// A domain task's counters (see [`Work`]).
#[derive(Clone, Copy)]
struct Counts {
    queries: u64,
    candidates: u64,
    seeded: u64,
    pst: PatternStats,
}

impl Work {
    fn counts(&self) -> Counts {
        Counts {
            queries: self.queries,
            candidates: self.candidates,
            seeded: self.seeded,
            pst: self.pst,
        }
    }
}

/// The order domains are synthesized in and who waits for whom: a domain starts once every
/// earlier domain of the sequential order it conflicts with ([`conflicts`]) is finished,
/// and reads exactly those finished (everything else as it was before the pass; see
/// [`View`]). That is the schedule's wave semantics without the barriers between waves:
/// a thread that finishes a domain starts whichever domain that made ready, so uneven
/// domains (the costly ones next to extraordinary vertices) and small waves no longer
/// leave cores idle.
pub(crate) struct DomainOrder {
    /// Per domain, the earlier conflicting domains (readable when it runs).
    earlier: Vec<Vec<u32>>,
    /// Per domain, the later conflicting domains (waiting for it).
    later: Vec<Vec<u32>>,
    /// Domains in sequential order.
    order: Vec<u32>,
}

impl DomainOrder {
    fn new(schedule: &Schedule, conflicts: &[Vec<u32>]) -> Self {
        let nd = conflicts.len();
        let mut rank = vec![0usize; nd];
        for (i, &d) in schedule.order.iter().enumerate() {
            rank[d as usize] = i;
        }
        let split = |later: bool| -> Vec<Vec<u32>> {
            (0..nd)
                .map(|d| {
                    conflicts[d]
                        .iter()
                        .copied()
                        .filter(|&e| (rank[e as usize] > rank[d]) == later)
                        .collect()
                })
                .collect()
        };
        Self {
            earlier: split(false),
            later: split(true),
            order: schedule.order.clone(),
        }
    }

    /// Runs `task(d, done)` for every domain as soon as its earlier conflicting domains are
    /// finished (`done[e]` is set for those); returns the results per domain.
    fn run<T: Send + Sync>(&self, task: &(dyn Fn(usize, &[OnceLock<T>]) -> T + Sync)) -> Vec<T> {
        let nd = self.order.len();
        let pending: Vec<AtomicUsize> = self
            .earlier
            .iter()
            .map(|e| AtomicUsize::new(e.len()))
            .collect();
        let done: Vec<OnceLock<T>> = (0..nd).map(|_| OnceLock::new()).collect();
        struct Run<'a, T> {
            order: &'a DomainOrder,
            pending: &'a [AtomicUsize],
            done: &'a [OnceLock<T>],
            task: &'a (dyn Fn(usize, &[OnceLock<T>]) -> T + Sync),
        }
        impl<'a, T: Send + Sync> Run<'a, T> {
            fn start(&'a self, s: &rayon::Scope<'a>, d: usize) {
                s.spawn(move |s| {
                    let out = (self.task)(d, self.done);
                    if self.done[d].set(out).is_err() {
                        unreachable!("domain {d} ran twice");
                    }
                    for &e in &self.order.later[d] {
                        if self.pending[e as usize].fetch_sub(1, AcqRel) == 1 {
                            self.start(s, e as usize);
                        }
                    }
                });
            }
        }
        let r = Run {
            order: self,
            pending: &pending,
            done: &done,
            task,
        };
        rayon::scope(|s| {
            for &d in &self.order {
                if self.earlier[d as usize].is_empty() {
                    r.start(s, d as usize);
                }
            }
        });
        done.into_iter()
            .map(|c| c.into_inner().expect("every domain runs"))
            .collect()
    }

    /// Per domain, the sources a task for `d` may read (its earlier conflicting domains').
    fn visible<'a>(&self, d: usize, done: &'a [OnceLock<DomainOut>]) -> Vec<Option<&'a [u32]>> {
        let mut v = vec![None; done.len()];
        for &e in &self.earlier[d] {
            v[e as usize] = Some(done[e as usize].get().expect("finished").src.as_slice());
        }
        v
    }
}

/// The coarsest level: marched neighbourhoods of generated texels, exhaustive search.
fn coarsest(
    ctx: &Ctx<'_>,
    level: usize,
    geo: &LevelGeometry,
    fac: &Factors,
    order: &DomainOrder,
    stats: &mut Stats,
) -> State {
    let c = ctx.channels;
    let texels = geo.texels();
    let shape = ctx.model.shape(level, Pass::Coarsest);
    let k = shape.fine;
    let delta = ctx.steps[level];
    let lookup = ctx.lookup(level);
    let outs = order.run(&|d, done| {
        let (start, nn) = (texels.start(d), texels.count(d));
        let finished = order.visible(d, done);
        let mut w = Work::new(ctx.model, level, Pass::Coarsest);
        let mut own_gen = vec![false; nn];
        let mut own_src = vec![0u32; nn];
        for li in 0..nn {
            let t = start + li;
            ctx.pattern(
                geo,
                t,
                fac.step(delta, t),
                k,
                SamplerKind::March,
                false,
                &mut w,
            );
            let view = View {
                channels: c,
                texels,
                lookup,
                before: &[],
                before_generated: false,
                finished: &finished,
                own: Some(Own {
                    start,
                    len: nn,
                    src: &own_src,
                    generated: &own_gen,
                    all_generated: false,
                }),
            };
            w.q.clear_all();
            for s in 0..k * k {
                if let Some(loc) = w.locs[s] {
                    if view.fetch_at(&geo.layout, loc, &mut w.val) {
                        w.q.set(s, &w.val);
                    }
                }
            }
            let index = if w.q.present_count() == 0 {
                w.seeded += 1;
                (ctx.key(level, Pass::Coarsest, t) % ctx.model.candidates(level) as u64) as u32
            } else {
                w.seeds.clear();
                ctx.choose(level, Pass::Coarsest, t, &mut w)
            };
            own_src[li] = index;
            own_gen[li] = true;
        }
        DomainOut {
            src: own_src,
            counts: w.counts(),
        }
    });
    let mut src = vec![0u32; geo.len()];
    for (d, o) in outs.iter().enumerate() {
        src[texels.range(d)].copy_from_slice(&o.src);
        absorb(stats, &o.counts);
    }
    State { src }
}

fn absorb(stats: &mut Stats, w: &Counts) {
    stats.queries += w.queries;
    stats.candidates += w.candidates;
    stats.seeded += w.seeded;
    stats.patterns.add(&w.pst);
}

/// k-coherence seeds from the coarser level: the forward-shifted sources of the coarse
/// texels nearest to the central `window x window` samples of the coarse pattern, scaled
/// to this level.
#[allow(clippy::too_many_arguments)]
fn coarse_seeds(
    ctx: &Ctx<'_>,
    level: usize,
    fine: &LevelGeometry,
    fine_fac: &Factors,
    coarse: &LevelGeometry,
    coarse_src: &[u32],
    t: usize,
    locs: &[Option<DomainLocation>],
    k: usize,
    window: usize,
    seeds: &mut Vec<u32>,
) {
    seeds.clear();
    let h = (k / 2) as i64;
    let r = (window / 2) as i64;
    let delta = fine_fac.step(ctx.steps[level + 1], t);
    for dy in -r..=r {
        for dx in -r..=r {
            let Some(loc) = locs[((dy + h) * k as i64 + dx + h) as usize] else {
                continue;
            };
            let Some(q) = nearest_texel(&coarse.layout.taps(loc)) else {
                continue;
            };
            let d = (coarse.pos[q] - fine.pos[t]).as_dvec3();
            let f = fine.frame(t);
            let e = [d.dot(f.v1) / delta, -d.dot(f.v2) / delta];
            let s = ctx.position(level + 1, coarse_src[q]);
            let (x, y) = ((s[0] as f64 - e[0]) * 2.0, (s[1] as f64 - e[1]) * 2.0);
            seeds.push(ctx.model.nearest_index(level, x as f32, y as f32));
        }
    }
}

/// The coarser level's K×K block around texel `t` of `fine` into `w.q` (missing where
/// nothing is there): what pass 1 matches alone and pass 2 appends to
/// the level's own block. `w.locs` holds the block's pattern afterwards. Pass 2 gathers it
/// again rather than keeping pass 1's (keeping them all cost 25 samples x (channels + 1) x
/// 4 bytes per texel of the finest level, 825 B with 8 appearance dimensions, the run's
/// peak), from the every other sample of its own pattern where the blocks reach equally
/// far ([`coarse_from_fine`]), else with this function.
#[allow(clippy::too_many_arguments)]
fn coarse_block(
    ctx: &Ctx<'_>,
    level: usize,
    fine: &LevelGeometry,
    fine_fac: &Factors,
    coarse: &LevelGeometry,
    view: &View<'_>,
    t: usize,
    w: &mut Work,
) {
    let k = ctx.model.shape(level, Pass::One).coarse;
    let delta = fine_fac.step(ctx.steps[level + 1], t);
    ctx.pattern(fine, t, delta, k, SamplerKind::Chart, false, w);
    for s in 0..k * k {
        match w.locs[s] {
            Some(loc) if view.fetch_at(&coarse.layout, loc, &mut w.val) => {
                w.q.set(s, &w.val);
            }
            _ => w.q.clear(s),
        }
    }
}

/// Whether pass 2 takes its coarser block's pattern from the level's own `k`×`k` pattern:
/// when the coarser `kc`×`kc` block (step 2δ) reaches exactly as far as the fine one (step
/// δ), `k = 2·kc − 1` (the default 9 and 5), its samples are the fine pattern's every
/// other sample — the same tangent offsets, so parameter-space patterns put them at the
/// same parameters bit for bit ((2i)·δ = i·(2δ) exactly). *Why*: the coarser block's
/// pattern was otherwise laid out a second time per texel (pass 1 lays it out too), an
/// eighth of a Spot run's time in pattern sampling alone (issue 14). Where the patterns
/// come from the vertex-chart sampler or were moved from a block's anchor, the two differ
/// by those patterns' own errors (the sampler walks δ rather than 2δ per step).
fn coarse_from_fine(k: usize, kc: usize) -> bool {
    kc > 0 && k == 2 * kc - 1
}

/// Whether pass 2's own `k`×`k` block can be made sparse: k = 4j + 1 ≥ 9, so that the
/// samples with both offsets even reach the block's edge ([`sparse_keeps`]).
pub fn sparse_block(k: usize) -> bool {
    k >= 9 && k % 4 == 1
}

/// The sparse block ([`MultiscaleParams::sparse`]): which samples of pass 2's own `k`×`k`
/// block are compared, and the factors of their Gaussian weights ([`Query::gain`], over
/// the `k`² + `kc`² samples of the pass-2 shape; the coarser block's are 1).
///
/// The block keeps its inner (k/4)-ring whole and every other sample beyond
/// ([`sparse_keeps`]): 41 of 81 samples at k = 9, the same reach. The kept outer samples
/// carry the weight of the whole outer part (each its share of it), so the block's reach
/// weighs in the distance as much as the full block's does. *Why*: the 9x9 block's reach
/// carries the lines of structured examples (a 5x5 or 7x7 block broke mortar lines into
/// short pieces, docs/multiscale.md), but its 81 samples cost pass 2 its distances, its
/// fetches and — near extraordinary vertices — a marched path for each of 48 directions
/// ([`crate::sampling::Sampler::sample_sparse`]: 16 suffice for the sparse block).
pub fn sparse_gains(k: usize, kc: usize) -> (Vec<bool>, Vec<f32>) {
    let h = (k / 2) as i64;
    let inner = h / 2;
    let sigma = k as f64 / 4.0;
    let mut keep = Vec::with_capacity(k * k);
    let (mut all, mut kept) = (0.0f64, 0.0f64);
    for m in -h..=h {
        for l in -h..=h {
            let kp = sparse_keeps(k, l, m);
            keep.push(kp);
            if l.abs().max(m.abs()) > inner {
                let w = (-((l * l + m * m) as f64) / (2.0 * sigma * sigma)).exp();
                all += w;
                if kp {
                    kept += w;
                }
            }
        }
    }
    let g = if kept > 0.0 { (all / kept) as f32 } else { 1.0 };
    let mut gain = Vec::with_capacity(k * k + kc * kc);
    for (i, &kp) in keep.iter().enumerate() {
        let (l, m) = (i as i64 % k as i64 - h, i as i64 / k as i64 - h);
        gain.push(match (kp, l.abs().max(m.abs()) > inner) {
            (false, _) => 0.0,
            (true, true) => g,
            (true, false) => 1.0,
        });
    }
    gain.resize(k * k + kc * kc, 1.0);
    (keep, gain)
}

/// The view of a finished coarser level (every texel generated, no domain in progress).
fn finished_view<'a>(
    ctx: &'a Ctx<'_>,
    level: usize,
    coarse: &'a LevelGeometry,
    cstate: &'a State,
) -> View<'a> {
    View {
        channels: ctx.channels,
        texels: coarse.texels(),
        lookup: ctx.lookup(level + 1),
        before: &cstate.src,
        before_generated: true,
        finished: &[],
        own: None,
    }
}

/// Pass 1: every texel from the coarser level's 5x5 block alone (all independent). Also
/// returns the block's anchor patterns laid out by the sampler when pass 2 lays out the
/// same block again ([`Anchors`]; not when it takes it from its own pattern,
/// [`coarse_from_fine`]).
fn pass_one(
    ctx: &Ctx<'_>,
    level: usize,
    fine: &LevelGeometry,
    fine_fac: &Factors,
    coarse: &LevelGeometry,
    cstate: &State,
    stats: &mut Stats,
) -> (State, Option<Arc<Anchors>>) {
    let k = ctx.model.shape(level, Pass::One).coarse;
    let keep = !coarse_from_fine(ctx.model.shape(level, Pass::Two).fine, k);
    let texels = fine.texels();
    let view = finished_view(ctx, level, coarse, cstate);
    // Per domain: chosen features, counters, anchor patterns.
    let results: Vec<(Vec<u32>, Counts, Option<Anchors>)> = (0..texels.faces())
        .into_par_iter()
        .map(|d| {
            let mut w = Work::new(ctx.model, level, Pass::One);
            if keep {
                w.pat.record = Some(Anchors::default());
            }
            let start = texels.start(d);
            let mut src = vec![0u32; texels.count(d)];
            for (li, out) in src.iter_mut().enumerate() {
                let t = start + li;
                coarse_block(ctx, level, fine, fine_fac, coarse, &view, t, &mut w);
                if let Some(win) = ctx.kwindow {
                    let mut seeds = std::mem::take(&mut w.seeds);
                    coarse_seeds(
                        ctx,
                        level,
                        fine,
                        fine_fac,
                        coarse,
                        &cstate.src,
                        t,
                        &w.locs,
                        k,
                        win,
                        &mut seeds,
                    );
                    w.seeds = seeds;
                }
                *out = ctx.choose(level, Pass::One, t, &mut w);
            }
            (src, w.counts(), w.pat.record.take())
        })
        .collect();
    let mut src = Vec::with_capacity(fine.len());
    let mut parts = Vec::new();
    for (s, w, a) in results {
        src.extend_from_slice(&s);
        absorb(stats, &w);
        parts.extend(a);
    }
    let anchors = keep.then(|| Arc::new(Anchors::merge(parts)));
    (State { src }, anchors)
}

/// What pass 2 of a level starts from when pass 1 is left out
/// ([`MultiscaleParams::continue_finest`]): each texel continues the source of its nearest
/// coarser texel (that source, minus the offset between the two, at twice the
/// resolution — the candidate pass 1's k-coherence search starts from), with no search.
/// *Why*: pass 1 matches every texel against the coarser block alone, and at the finest
/// level that is a fifth of a run (Spot N = 32), while pass 2 replaces every one of its
/// choices; what pass 2 needs from it is the not-yet-refined neighbours of each texel,
/// which the continued coarse patches give as well (Lefebvre & Hoppe 2005's
/// upsampling of coordinates).
fn continued(
    ctx: &Ctx<'_>,
    level: usize,
    fine: &LevelGeometry,
    fine_fac: &Factors,
    coarse: &LevelGeometry,
    cstate: &State,
) -> State {
    let src = (0..fine.len())
        .into_par_iter()
        .map_init(Vec::new, |seeds, t| {
            let at = [Some(fine.location(t))];
            coarse_seeds(
                ctx,
                level,
                fine,
                fine_fac,
                coarse,
                &cstate.src,
                t,
                &at,
                1,
                1,
                seeds,
            );
            seeds.first().copied().unwrap_or(0)
        })
        .collect();
    State { src }
}

/// Pass 2: refine with the level's 9x9 block plus the coarser block (gathered again,
/// [`coarse_block`]); scan-line order inside each domain (at the finest level with the
/// coherent choice, [`growth_order`]), domains in the schedule's order ([`DomainOrder`]).
#[allow(clippy::too_many_arguments)]
fn pass_two(
    ctx: &Ctx<'_>,
    surface: &Surface,
    level: usize,
    geo: &LevelGeometry,
    fac: &Factors,
    coarse: &LevelGeometry,
    cstate: &State,
    order: &DomainOrder,
    mut state: State,
    anchors: Option<Arc<Anchors>>,
    stats: &mut Stats,
) -> State {
    let c = ctx.channels;
    let shape = ctx.model.shape(level, Pass::Two);
    let k = shape.fine;
    let nf = k * k;
    let texels = geo.texels();
    let coarse_view = finished_view(ctx, level, coarse, cstate);
    let lookup = ctx.lookup(level);
    let delta = ctx.steps[level];
    let largest = (0..texels.faces())
        .map(|d| texels.count(d))
        .max()
        .unwrap_or(0);
    let all_gen = vec![true; largest];
    let before = &state;
    // Which samples of the own block are compared, and their weights' factors.
    let sparse = (ctx.sparse && sparse_block(k)).then(|| sparse_gains(k, shape.coarse));
    let keep = sparse.as_ref().map(|(keep, _)| &keep[..]);
    let is_sparse = sparse.is_some();
    let outs = order.run(&|d, done| {
        let (start, nn) = (texels.start(d), texels.count(d));
        let finished = order.visible(d, done);
        let mut w = Work::new(ctx.model, level, Pass::Two);
        if let Some((_, gain)) = &sparse {
            w.q.gain = gain.clone();
        }
        // The coarser block's samples are every other sample of the level's own pattern
        // when the blocks reach equally far ([`coarse_from_fine`]); otherwise pass 1's
        // pattern calls again, with a scratch (and counters) of their own.
        let kc = shape.coarse;
        let from_fine = coarse_from_fine(k, kc);
        let mut wc = (!from_fine).then(|| {
            let mut wc = Work::new(ctx.model, level, Pass::One);
            wc.pat.known = anchors.clone();
            wc
        });
        let mut own_src = before.src[start..start + nn].to_vec();
        let coherent_choice = level == 0 && ctx.coherence.is_some();
        let visit = if coherent_choice {
            growth_order(surface, geo, d, &finished)
        } else {
            (0..nn as u32).collect()
        };
        let mut settled_here = vec![false; nn];
        for &li in &visit {
            let li = li as usize;
            let t = start + li;
            let delta = fac.step(delta, t);
            ctx.pattern(geo, t, delta, k, SamplerKind::Chart, is_sparse, &mut w);
            let view = View {
                channels: c,
                texels,
                lookup,
                before: &before.src,
                before_generated: true,
                finished: &finished,
                own: Some(Own {
                    start,
                    len: nn,
                    src: &own_src,
                    generated: &all_gen[..nn],
                    all_generated: true,
                }),
            };
            for s in 0..nf {
                if keep.is_some_and(|keep| !keep[s]) {
                    w.q.clear(s);
                    continue;
                }
                match w.locs[s] {
                    Some(loc) => {
                        view.fetch_at(&geo.layout, loc, &mut w.val);
                        w.q.set(s, &w.val);
                    }
                    None => w.q.clear(s),
                }
            }
            if let Some(wc) = wc.as_mut() {
                coarse_block(ctx, level, geo, fac, coarse, &coarse_view, t, wc);
                for s in 0..kc * kc {
                    if wc.q.present[s] {
                        let v = &wc.q.values[s * c..(s + 1) * c];
                        w.q.set(nf + s, v);
                    } else {
                        w.q.clear(nf + s);
                    }
                }
            } else {
                // Coarse sample (cx, cy) of the block is fine sample (2cx, 2cy).
                for cy in 0..kc {
                    for cx in 0..kc {
                        let s = nf + cy * kc + cx;
                        match w.locs[2 * cy * k + 2 * cx] {
                            Some(loc) if coarse_view.fetch_at(&coarse.layout, loc, &mut w.val) => {
                                w.q.set(s, &w.val);
                            }
                            _ => w.q.clear(s),
                        }
                    }
                }
            }
            w.seeds.clear();
            w.coherent.clear();
            // k-coherence's proposing window; the coherent choice's 3x3 at the finest level
            // for the other searches.
            let window = ctx.kwindow.or(coherent_choice.then_some(3));
            if let Some(win) = window {
                let h = (k / 2) as i64;
                let r = (win / 2) as i64;
                for dy in -r..=r {
                    for dx in -r..=r {
                        let Some(loc) = w.locs[((dy + h) * k as i64 + dx + h) as usize] else {
                            continue;
                        };
                        let Some(q) = nearest_texel(&geo.layout.taps(loc)) else {
                            continue;
                        };
                        let e = texels.domain_of(q);
                        let (sq, settled) = if e == d {
                            (own_src[q - start], settled_here[q - start])
                        } else if finished[e].is_some() {
                            (
                                done[e].get().expect("finished").src[q - texels.start(e)],
                                true,
                            )
                        } else {
                            (before.src[q], false)
                        };
                        let off = geo.offset_pixels(t, q, delta);
                        let s = ctx.position(level, sq);
                        let c = ctx.model.nearest_index(level, s[0] - off[0], s[1] - off[1]);
                        if ctx.kwindow.is_some() {
                            w.seeds.push(c);
                        }
                        if coherent_choice && settled && !w.coherent.contains(&c) {
                            w.coherent.push(c);
                        }
                    }
                }
            }
            let index = ctx.choose(level, Pass::Two, t, &mut w);
            own_src[li] = index;
            settled_here[li] = true;
        }
        DomainOut {
            src: own_src,
            counts: w.counts(),
        }
    });
    for (d, o) in outs.iter().enumerate() {
        state.src[texels.range(d)].copy_from_slice(&o.src);
        absorb(stats, &o.counts);
    }
    state
}

/// The finest level's refinement order inside domain `d` (local texel indices): inwards
/// from the texels that touch an already finished domain ([`inward_order`], as coherent
/// synthesis orders its domains), plain scan order when no neighbour is finished. Why: with
/// the coherent choice ([`COHERENCE`]) a domain's patches grow from where its refinement
/// starts; in scan-line order they grew from its first corner and met the finished
/// neighbours' patches along the shared edge, so every domain edge became a patch border
/// (seams rose: double torus bricks 1.16 → 1.53). Grown from the finished edges, the
/// neighbours' patches continue across them. A border texel touches a domain when the
/// texel one step outside it lies there (the walk [`continuous_sources`] links by).
fn growth_order(
    surface: &Surface,
    geo: &LevelGeometry,
    d: usize,
    finished: &[Option<&[u32]>],
) -> Vec<u32> {
    let texels = geo.texels();
    let (start, nn) = (texels.start(d), texels.count(d));
    let (nu, nv) = texels.dims(d);
    inward_order(nu, nv, |x, y| {
        let loc = geo.location(start + y * nu + x);
        let outward = [
            (x == 0, -1.0, 0.0),
            (x + 1 == nu, 1.0, 0.0),
            (y == 0, 0.0, -1.0),
            (y + 1 == nv, 0.0, 1.0),
        ];
        outward.iter().any(|&(at, a, b)| {
            at && surface
                .walk(loc, a / nu as f64, b / nv as f64)
                .and_then(|l| nearest_texel(&geo.layout.taps(l)))
                .map(|q| texels.domain_of(q))
                .is_some_and(|e| e != d && finished[e].is_some())
        })
    })
    .unwrap_or_else(|| (0..nn as u32).collect())
}

/// The cache key of a [`Model`]: the weighted example level it starts from, the number of
/// levels, what is matched and every search parameter.
fn model_key(
    img: &Image,
    n_levels: usize,
    appearance: AppearanceMode,
    p: &ModelParams,
) -> crate::cache::Key {
    let mut k = crate::cache::KeyBuilder::new("multiscale-model")
        .image(img)
        .u64(n_levels as u64)
        .str(appearance.name())
        .u64(p.fine as u64)
        .u64(p.coarse as u64)
        .u64(p.coarsest as u64)
        .str(p.method.name());
    match p.method {
        Method::Brute => {}
        Method::Ann(a) => k = k.u64(a.dims as u64).u64(a.candidates as u64),
        Method::KCoherence(kp) => {
            k = k
                .u64(kp.k as u64)
                .u64(kp.m as u64)
                .u64(kp.exact_max as u64)
                .u64(kp.window as u64)
        }
    }
    k.finish()
}

impl crate::cache::Persist for Model {
    /// The pyramid (already in appearance space), the parameters and every level's
    /// k-coherence lists; the neighbourhood features are gathered again on load (cheap
    /// next to the lists, and several times their size).
    fn save(&self, w: &mut crate::cache::Writer) {
        let m = &self.model;
        let p = &m.params;
        w.usize(p.fine);
        w.usize(p.coarse);
        w.usize(p.coarsest);
        match p.method {
            Method::Brute => w.usize(0),
            Method::Ann(a) => {
                w.usize(1);
                w.usize(a.dims);
                w.usize(a.candidates);
            }
            Method::KCoherence(kp) => {
                w.usize(2);
                for v in [kp.k, kp.m, kp.exact_max, kp.window] {
                    w.usize(v);
                }
            }
        }
        w.usize(self.appearance.dims);
        w.usize(self.appearance.window);
        w.f64(self.appearance.kept_variance);
        w.usize(m.pyramid.len());
        for (l, lists) in m.lists().into_iter().enumerate() {
            w.image(m.pyramid.level(l));
            match lists {
                None => w.bool(false),
                Some(k) => {
                    w.bool(true);
                    w.usize(k.len);
                    w.bool(k.exact);
                    w.u32s(&k.lists);
                }
            }
        }
    }

    fn load(r: &mut crate::cache::Reader<'_>) -> Option<Self> {
        use crate::synth::matching::search::{ann::AnnParams, kcoherence};
        let (fine, coarse, coarsest) = (r.usize()?, r.usize()?, r.usize()?);
        let method = match r.usize()? {
            0 => Method::Brute,
            1 => Method::Ann(AnnParams {
                dims: r.usize()?,
                candidates: r.usize()?,
            }),
            2 => Method::KCoherence(kcoherence::KParams {
                k: r.usize()?,
                m: r.usize()?,
                exact_max: r.usize()?,
                window: r.usize()?,
            }),
            _ => return None,
        };
        let appearance = AppearanceInfo {
            dims: r.usize()?,
            window: r.usize()?,
            kept_variance: r.f64()?,
            feature_distance: 0.0,
            reflectance: None,
        };
        let n = r.usize_max(64)?;
        let mut levels = Vec::with_capacity(n);
        let mut lists = Vec::with_capacity(n);
        for _ in 0..n {
            let img = r.image()?;
            if img.data.iter().any(|v| !v.is_finite()) {
                return None;
            }
            levels.push(img);
            lists.push(if r.bool()? {
                Some(kcoherence::KnnLists {
                    len: r.usize()?,
                    exact: r.bool()?,
                    lists: r.u32s()?,
                })
            } else {
                None
            });
        }
        if n == 0 {
            return None;
        }
        let params = ModelParams {
            fine,
            coarse,
            coarsest,
            method,
        };
        let model = ExampleModel::with_lists(crate::pyramid::Pyramid { levels }, params, lists)?;
        Some(Self { model, appearance })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_sparse_block_keeps_its_reach_and_its_weight() {
        assert!(sparse_block(9) && sparse_block(13));
        assert!(!sparse_block(5) && !sparse_block(7) && !sparse_block(11));
        let (keep, gain) = sparse_gains(9, 5);
        assert_eq!(keep.len(), 81);
        assert_eq!(gain.len(), 81 + 25);
        assert_eq!(keep.iter().filter(|&&k| k).count(), 41);
        // The corners and edge midpoints of the block are kept; (3, 0) and (4, 1) are not.
        let at = |l: i64, m: i64| ((m + 4) * 9 + l + 4) as usize;
        for (l, m) in [(4, 4), (-4, 4), (4, 0), (0, -4), (2, 2), (1, 2), (-4, 2)] {
            assert!(keep[at(l, m)], "({l}, {m})");
        }
        for (l, m) in [(3, 0), (4, 1), (-3, 3), (1, 4)] {
            assert!(!keep[at(l, m)], "({l}, {m})");
        }
        // Every sample the coarser 5x5 block takes from the fine pattern is kept.
        for cy in 0..5 {
            for cx in 0..5 {
                assert!(keep[2 * cy * 9 + 2 * cx]);
            }
        }
        // The kept samples weigh what the full block weighs.
        let sc = crate::synth::matching::search::Shape::new(9, 5, 1).sample_scales();
        let full: f64 = sc[..81].iter().map(|&s| (s as f64).powi(2)).sum();
        let sparse: f64 = (0..81)
            .filter(|&i| keep[i])
            .map(|i| (sc[i] as f64).powi(2) * gain[i] as f64)
            .sum();
        assert!((full - sparse).abs() < 1e-5, "{full} vs {sparse}");
        assert!(gain[81..].iter().all(|&g| g == 1.0));
    }

    #[test]
    fn levels_follow_the_scale() {
        let plan = |w, n, h, s, max| plan_levels(w, w, n, h, s, max).unwrap();
        // Default scale: the plain pyramid, R halving with the example; the example's
        // 16-pixel floor ends it.
        assert_eq!(plan(64, 64, 0.01, 0.01, 0), (0, vec![64, 32, 16]));
        assert_eq!(plan(192, 60, 0.01, 0.01, 0), (0, vec![60, 30, 15, 8]));
        // Texture twice as large (S = 2h): half the texels per side at every level.
        assert_eq!(plan(64, 64, 0.01, 0.02, 0), (0, vec![32, 16, 8]));
        // Texture four times smaller (S = h/4): example levels 0 and 1 are finer than the
        // texels and are skipped; 256 px has levels 256..16, so levels 2, 3, 4 remain.
        assert_eq!(plan(256, 32, 0.01, 0.0025, 0), (2, vec![32, 16, 8]));
        // Small maps stop at 2x2 texels; max_levels caps.
        assert_eq!(plan(512, 16, 0.01, 0.01, 0), (0, vec![16, 8, 4, 2]));
        // The exact size decides: N = 12 stops at 3, not at 1.5 rounded up to 2.
        assert_eq!(plan(128, 12, 0.01, 0.01, 0), (0, vec![12, 6, 3]));
        assert_eq!(plan(512, 64, 0.01, 0.01, 2), (0, vec![64, 32]));
        assert!(plan_levels(64, 64, 8, 0.0, 0.01, 0).is_err());
    }

    #[test]
    fn per_face_levels_halve_every_face() {
        use crate::layout::Resolution;
        let r = |a, b| Resolution::new(a, b).unwrap();
        let out = Arc::new(TexelLayout::per_face(vec![r(5, 3), r(1, 1), r(4, 4)]));
        // (16·16 + 4 + 256) / 3 texels per face: typical side 13.
        assert_eq!(typical_side(&out), 13);
        let (j0, res) = plan_levels(64, 64, 13, 0.01, 0.01, 0).unwrap();
        assert_eq!((j0, res.len()), (0, 3));
        let ls = level_layouts(&out, &res, j0, 0.01, 0.01);
        assert!(Arc::ptr_eq(&ls[0], &out), "the finest level is the output");
        assert_eq!(ls[1].dims(0), (16, 4));
        assert_eq!(ls[2].dims(0), (8, 2));
        assert_eq!(ls[2].dims(1), (1, 1), "never below one texel");
        // A texture twice as large (S = 2h) starts one halving down.
        let ls = level_layouts(&out, &res, 0, 0.01, 0.02);
        assert_eq!(ls[0].dims(2), (8, 8));
        // One N: the plan's sides.
        let u = Arc::new(TexelLayout::uniform(3, 16));
        let ls = level_layouts(&u, &[16, 8, 4], 0, 0.01, 0.01);
        assert_eq!(ls[2].uniform_n(), Some(4));
    }
}
