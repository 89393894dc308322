//! Texture synthesis on the surface's face maps: every method, behind one interface
//! ([`synthesize`]).
//!
//! Methods (siblings, each a module):
//! - [`coherent`]: the single-pass coherent method of Ying et al. 2001, §5 — the fast
//!   preview.
//! - [`multiscale`]: the multiscale method of Ying et al. 2001, §4 (Wei–Levoy on the
//!   surface), with its 2D reference [`synth2d`].
//! - [`patches`]: patch sampling along the field (paper 001 §5.2).
//! - [`optimise`]: texture optimisation over surface patches, multilevel (paper 001
//!   §4.2–4.4, after Kwatra et al. 2005) — the default, which keeps structure best.
//! - [`jump`]: jump-map synthesis (paper 002, Zelinka & Garland): no matching at
//!   synthesis time, the example analysed once ([`matching::jumpmap`]).
//! - [`textons`]: BTF synthesis with surface textons (paper 003): one source per texel for
//!   every image of a BTF sample ([`crate::btf`]), multiscale k-coherence over textons.
//!
//! Below them, what they share:
//! - [`matching`]: appearance space, example tables, similar-place lists, neighbourhood
//!   search;
//! - [`footprint`]: surface patches (texels with their coordinates in an example patch laid
//!   along the field) and the per-level texel sets; [`mincut`]: seams between patches;
//! - [`schedule`]: domain orders and deterministic parallel waves; [`per_thread`]: scratch;
//! - [`analysis`]: per-example analysis computed once per process and saved in the cache
//!   ([`crate::cache`]).
//!
//! Every method takes the same [`Target`] (the surface's texels at the output resolution,
//! the field, the scale) and the example, and returns a source position per texel
//! ([`Output`]): the output channels are then looked up in the example at those positions
//! ([`face_maps`]), so every channel comes from the same place. The builder in
//! [`crate::synthesizer`] strings this together with loading and writing; this module is
//! the pure computation (no files).

pub mod analysis;
pub mod blend;
pub mod coherent;
pub mod footprint;
pub mod jump;
pub mod matching;
pub mod mincut;
pub mod multiscale;
pub mod optimise;
pub mod patches;
pub mod per_thread;
pub mod schedule;
pub mod synth2d;
pub mod texel_table;
pub mod textons;

pub use analysis::Analyses;
pub use blend::Blend;
pub use coherent::{CoherentParams, DomainOrder, Order};
pub use jump::JumpParams;
pub use multiscale::MultiscaleParams;
pub use optimise::{OptimiseParams, Vote};
pub use patches::PatchParams;
pub use textons::TextonParams;

use crate::error::Result;
use crate::example::Example;
use crate::field::OrientationField;
use crate::io::exr::FaceMaps;
use crate::pyramid::Image;
use crate::texels::TexelGeometry;
use footprint::LevelTexels;
use glam::Vec3;
use matching::appearance::{Appearance, AppearanceInfo, AppearanceMode, DIMS, WINDOW};
use matching::exemplar::Exemplar;
use matching::features::Features;
use rayon::prelude::*;
use serde::Serialize;
use subdiv::Surface;

pub use crate::method::Method;
/// The field's frames at the texel centres (a module of their own, below the methods).
pub use crate::texel_frames::{frames_f32, frames_from_slots, layout_frames, texel_frames_f32};

/// The surface as every method sees it: texels at the output resolution (positions,
/// normals, neighbourhood graph, field frames), the field itself (for methods that work on
/// other resolutions too), and the scale.
pub struct Target<'a> {
    pub surface: &'a Surface,
    pub field: &'a OrientationField,
    /// Texels of the output maps; `texels.step` is the scale S (surface length per example
    /// pixel).
    pub texels: &'a LevelTexels,
    /// h: median distance between adjacent texel centres at the output resolution.
    pub spacing: f64,
    pub seed: u64,
    /// What methods derive from the texels alone, kept for later runs on the same mesh.
    pub derived: &'a Derived,
    /// The scale map's interpolated factor (`--scale-map`; [`crate::scale_field`]): the
    /// local step is [`Target::scale`] × factor. Methods that build texels of their own
    /// (coarser levels) evaluate it there; `texels.factor` holds it at the output texels.
    pub scale_field: Option<&'a crate::scale_field::ScaleField>,
}

/// Mesh-side structures some methods derive from [`Target::texels`] on first use and keep
/// (a prepared session computes each once for all its runs).
#[derive(Debug, Default)]
pub struct Derived {
    /// The jump method's region-growing order ([`jump::growth_order`]) and what its texel
    /// pass reads, in that order.
    pub jump: std::sync::OnceLock<jump::Plan>,
}

impl Derived {
    /// The jump method's plan of `texels`.
    pub fn jump_plan(&self, texels: &LevelTexels) -> &jump::Plan {
        self.jump.get_or_init(|| {
            let growth =
                jump::Growth::compute(texels.edges(), texels.layout(), &texels.geometry.pos);
            jump::Plan::new(texels, growth)
        })
    }

    /// The jump method's plan of `texels` from what it needs of them computed beforehand
    /// (`jump::Growth` of the same texels: a session computes it beside the orientation
    /// field, which it does not need; the plan reads the field's frames).
    pub fn jump_plan_from(&self, texels: &LevelTexels, growth: jump::Growth) -> &jump::Plan {
        self.jump.get_or_init(|| jump::Plan::new(texels, growth))
    }
}

impl Target<'_> {
    /// Surface length per example pixel where the scale map's factor is 1 (everywhere
    /// without a scale map).
    pub fn scale(&self) -> f64 {
        self.texels.step
    }

    /// The scale level plans are made for: [`Target::scale`] × the scale map's smallest
    /// factor (the finest local step), so that no level's texels are coarser than its
    /// example pixels anywhere. Without a scale map, [`Target::scale`].
    pub fn reference_scale(&self) -> f64 {
        match self.scale_field {
            None => self.scale(),
            Some(f) => self.scale() * f.range().0,
        }
    }
}

/// How to synthesize: the method, what matchers compare, and each method's tuning.
#[derive(Clone, Debug, PartialEq)]
pub struct Settings {
    pub method: Method,
    pub weights: Weights,
    pub appearance: AppearanceMode,
    pub coherent: CoherentParams,
    pub multiscale: MultiscaleParams,
    pub patches: PatchParams,
    pub optimise: OptimiseParams,
    pub jump: JumpParams,
    pub textons: TextonParams,
    /// Weight of the feature-distance channel ([`matching::feature_distance`],
    /// `--feature-distance`) appended to the matched channels before the appearance-space
    /// PCA; 0 (the default): none. Every method that matches in appearance space uses it
    /// (not textons, whose BTF sample has its own analysis).
    pub feature_distance: f32,
    /// The BTF sample of a `--btf` run (images under several lights; the example is its
    /// default image, which the outputs show). Every method finds one source per texel
    /// for all its images: texton synthesis over its textons, optimise, patches, coherent
    /// and jump over its reflectance vectors in appearance space
    /// ([`matching::reflectance`]); multiscale refuses a sample.
    pub btf: Option<std::sync::Arc<crate::btf::BtfSample>>,
}

impl Default for Settings {
    fn default() -> Self {
        Self {
            method: Method::DEFAULT,
            weights: Weights::default(),
            appearance: AppearanceMode::default(),
            coherent: CoherentParams::default(),
            multiscale: MultiscaleParams::default(),
            patches: PatchParams::default(),
            optimise: OptimiseParams::default(),
            jump: JumpParams::default(),
            textons: TextonParams::default(),
            feature_distance: 0.0,
            btf: None,
        }
    }
}

/// What the method did, with the parameters it ran with (report.json: a key named after
/// the method).
#[derive(Clone, Debug, PartialEq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Details {
    Coherent {
        params: CoherentParams,
        schedule: schedule::ScheduleInfo,
        stats: coherent::Stats,
    },
    Multiscale(multiscale::Stats),
    Patches {
        params: PatchParams,
        stats: patches::Stats,
    },
    Optimise {
        params: OptimiseParams,
        stats: optimise::Stats,
    },
    Jump {
        params: JumpParams,
        stats: jump::Stats,
    },
    Textons {
        params: TextonParams,
        stats: textons::Stats,
    },
}

/// A method's result: the source position of every texel (example pixels, centres at
/// +0.5; global texel order), what the matchers compared, and the method's details.
#[derive(Clone, Debug)]
pub struct Output {
    pub source: Vec<[f32; 2]>,
    /// Extra sources mixed into some texels' values across breaks ([`blend`]; jump maps
    /// with [`JumpParams::blend`]); `None`: every value is the look-up at its source.
    pub blend: Option<Blend>,
    pub appearance: AppearanceInfo,
    pub details: Details,
}

/// The example's channels premultiplied by the square roots of their weights, so that a
/// plain squared l2 distance is the weighted one.
pub fn weighted_image(example: &Example, weights: &Weights) -> Image {
    matching::features::weighted(example, &weights.per_channel(example))
}

/// Calls `$f::<K>(args)` with `K` the matching dimension of `$mode` for an example of
/// `$channels` channels: [`DIMS`] in appearance space, the channel count for raw channels.
/// (The inner loops are compiled per `K`.)
macro_rules! with_dims {
    ($mode:expr, $channels:expr, $f:ident($($arg:expr),*)) => {
        match ($mode, $channels) {
            (AppearanceMode::Pca, _) => $f::<DIMS>($($arg),*),
            (AppearanceMode::Rgb, 3) => $f::<3>($($arg),*),
            (AppearanceMode::Rgb, 4) => $f::<4>($($arg),*),
            (AppearanceMode::Rgb, 5) => $f::<5>($($arg),*),
            (_, k) => unreachable!("examples have 3 to 5 channels, not {k}"),
        }
    };
}

/// Synthesizes `example` over `target` with `settings` (the one interface of every
/// method). Per-example analysis (appearance space, jump maps, k-coherence lists) is
/// asked of `analyses`, which keeps it for later runs and in the disk cache.
/// `progress(done, total)` reports the method's own units (domains, patches, texel
/// passes).
pub fn synthesize(
    example: &Example,
    target: &Target<'_>,
    settings: &Settings,
    analyses: &Analyses,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<Output> {
    settings.weights.check(example)?;
    // The matchers see the colour and the weighted maps only; every map is copied later
    // from the sources they find ([`face_maps`]).
    let matched = settings.weights.matched(example);
    let example = &matched;
    // A BTF sample: the appearance-space methods compare pixels by their look under every
    // image (`matching::reflectance`); multiscale's own pyramid sees one image, so over a
    // sample it is texton synthesis.
    let (weighted, reflectance) = match (&settings.btf, settings.method) {
        (Some(sample), Method::Optimise | Method::Patches | Method::Coherent | Method::Jump) => {
            // `--appearance rgb` compares the values themselves, at most 5 of them.
            let dims = match settings.appearance {
                AppearanceMode::Pca => matching::reflectance::DIMS,
                AppearanceMode::Rgb => 5,
            };
            let (img, info) = matching::reflectance::reflectance(sample, dims);
            (img, Some(info))
        }
        (Some(_), m) if m.btf_refusal().is_some() => {
            return Err(crate::Error::invalid(m.btf_refusal().unwrap_or_default()));
        }
        _ => (weighted_image(example, &settings.weights), None),
    };
    let mode = settings.appearance;
    let fd = settings.feature_distance;
    if !(fd.is_finite() && fd >= 0.0) {
        return Err(crate::Error::invalid(format!(
            "the feature-distance weight must be a finite number >= 0, not {fd}"
        )));
    }
    if fd > 0.0 && (mode == AppearanceMode::Rgb || settings.method == Method::Textons) {
        return Err(crate::Error::invalid(format!(
            "--feature-distance is matched in appearance space by optimise, patches, coherent, jump and multiscale; not with --method {} --appearance {}",
            settings.method.name(),
            mode.name()
        )));
    }
    // Multiscale weighs its own pyramid and adds the channel there
    // (`multiscale::Inputs::feature_distance`).
    let weighted = if fd > 0.0 && settings.method != Method::Multiscale {
        matching::feature_distance::with_feature_distance(&weighted, fd)
    } else {
        weighted
    };
    if mode == AppearanceMode::Rgb
        && weighted.channels > 5
        && !matches!(settings.method, Method::Multiscale | Method::Jump)
    {
        return Err(crate::Error::invalid(format!(
            "--appearance rgb compares at most 5 channels with --method {}, and the example with its weighted maps has {}; use --appearance pca (the default) or weigh fewer maps",
            settings.method.name(),
            weighted.channels
        )));
    }
    let out = match settings.method {
        Method::Coherent => Ok(with_dims!(
            mode,
            weighted.channels,
            coherent_output(&weighted, target, settings, analyses, progress)
        )),
        Method::Jump => {
            let k = match mode {
                AppearanceMode::Pca => DIMS,
                AppearanceMode::Rgb => weighted.channels,
            };
            let p = settings.jump;
            let app = appearance(analyses, &weighted, mode, k);
            let key = crate::cache::KeyBuilder::new("jumpmap")
                .image(&app.image)
                .u64(p.map.jumps as u64)
                .u64(p.map.spacing as u64)
                .u64(p.map.exclude as u64)
                .u64(p.map.candidates as u64)
                .finish();
            let map = analyses.get("jumpmap", key, || {
                matching::jumpmap::JumpMap::from_appearance_with(
                    &app.image,
                    app.info,
                    p.map,
                    &|d, t| analyses.progress(d, t),
                )
            });
            let plan = target.derived.jump_plan(target.texels);
            let (source, blend, stats) =
                jump::run(&map, target.texels, plan, &p, target.seed, progress);
            Ok(Output {
                source,
                blend,
                appearance: map.appearance,
                details: Details::Jump { params: p, stats },
            })
        }
        Method::Multiscale => {
            let weights = settings.weights.per_channel(example);
            let inputs = multiscale::Inputs {
                surface: target.surface,
                field: target.field,
                layout: target.texels.layout(),
                spacing: target.spacing,
                scale: target.scale(),
                scale_field: target.scale_field,
                seed: target.seed,
                weights: &weights,
                appearance: mode,
                feature_distance: fd,
            };
            let models = |key: crate::cache::Key, build: &dyn Fn() -> Result<multiscale::Model>| {
                analyses.try_get("multiscale-model", key, build)
            };
            let out =
                multiscale::run_with(example, &inputs, &settings.multiscale, &models, &|d, t| {
                    progress(d as usize, t as usize)
                })?;
            Ok(Output {
                source: out.source,
                blend: None,
                appearance: out.stats.appearance,
                details: Details::Multiscale(out.stats),
            })
        }
        Method::Textons => {
            let one;
            let sample = match &settings.btf {
                Some(s) => &**s,
                None => {
                    let mut ex = example.clone();
                    ex.alpha = None;
                    ex.maps.clear();
                    one = crate::btf::BtfSample::from_images(vec![ex], vec![Vec3::Z.as_dvec3()])?;
                    &one
                }
            };
            let p = settings.textons;
            let (source, stats) =
                textons::run(sample, target, &p, &settings.multiscale, analyses, progress)?;
            Ok(Output {
                source,
                blend: None,
                appearance: stats.synthesis.appearance,
                details: Details::Textons { params: p, stats },
            })
        }
        Method::Patches => Ok(with_dims!(
            mode,
            weighted.channels,
            run_patches(&weighted, target, settings, analyses, progress)
        )),
        Method::Optimise => Ok(with_dims!(
            mode,
            weighted.channels,
            run_optimise(&weighted, target, settings, progress)
        )),
    };
    out.map(|mut o| {
        o.appearance.feature_distance = fd;
        o.appearance.reflectance = reflectance;
        o
    })
}

/// The appearance space of `weighted` in `mode` with `k` values per pixel, through the
/// analyses (memory, then the disk cache).
pub fn appearance(
    analyses: &Analyses,
    weighted: &Image,
    mode: AppearanceMode,
    k: usize,
) -> std::sync::Arc<Appearance> {
    let key = appearance_key(weighted, mode, k);
    analyses.get("appearance", key, || {
        Appearance::build(weighted, mode, WINDOW, k)
    })
}

/// The cache key of an appearance space. It hashes the weighted image itself, so the
/// maps that are matched and their weights are in it (a material with the normal map at
/// weight 1 and one at weight 2 are different analyses); maps that are only copied are not
/// (they change nothing the analysis computes, and leaving them out lets a material reuse
/// the analysis of its colour alone).
pub fn appearance_key(weighted: &Image, mode: AppearanceMode, k: usize) -> crate::cache::Key {
    crate::cache::KeyBuilder::new("appearance")
        .image(weighted)
        .str(mode.name())
        .u64(k as u64)
        .u64(WINDOW as u64)
        .finish()
}

fn coherent_output<const K: usize>(
    weighted: &Image,
    target: &Target<'_>,
    settings: &Settings,
    analyses: &Analyses,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Output {
    let app = appearance(analyses, weighted, settings.appearance, K);
    let features = Features::<K>::from_image(&app.image);
    let t = target.texels;
    let params = &settings.coherent;
    let graph = t.graph(target.surface);
    let schedule = coherent::schedule_for(params.domain_order, target.surface, &t.geometry, graph);
    let inputs = coherent::Inputs {
        geometry: &t.geometry,
        graph,
        frames: &t.frames,
        schedule: &schedule,
        scale: t.step,
        factor: t.factor.as_deref(),
        seed: target.seed,
    };
    let faces = t.geometry.faces();
    let out = coherent::run(&features, inputs, params, &|d| progress(d, faces));
    Output {
        source: out.source,
        blend: None,
        appearance: app.info,
        details: Details::Coherent {
            params: params.clone(),
            schedule: schedule.info(),
            stats: out.stats,
        },
    }
}

fn run_patches<const K: usize>(
    weighted: &Image,
    target: &Target<'_>,
    settings: &Settings,
    analyses: &Analyses,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Output {
    let app = appearance(analyses, weighted, settings.appearance, K);
    let ex = Exemplar::<K>::from_appearance(&app);
    let out = patches::run(
        &ex,
        target.surface,
        target.texels,
        &settings.patches,
        target.seed,
        progress,
    );
    Output {
        source: out.source,
        blend: None,
        appearance: ex.info,
        details: Details::Patches {
            params: settings.patches,
            stats: out.stats,
        },
    }
}

fn run_optimise<const K: usize>(
    weighted: &Image,
    target: &Target<'_>,
    settings: &Settings,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Output {
    let (out, appearance) = optimise::run::<K>(
        weighted,
        settings.appearance,
        target,
        &settings.optimise,
        progress,
    );
    Output {
        source: out.source,
        blend: None,
        appearance,
        details: Details::Optimise {
            params: settings.optimise.clone(),
            stats: out.stats,
        },
    }
}

/// Runs coherent synthesis directly on the raw weighted channels of `example` (any of its
/// channel layouts), with the caller's own inputs — for diagnostics that need the
/// per-texel [`coherent::Output::kind`]s (`--appearance rgb` runs match it bit for bit).
pub fn run_coherent(
    example: &Example,
    weights: &Weights,
    inputs: coherent::Inputs<'_>,
    params: &CoherentParams,
    progress: &(dyn Fn(usize) + Sync),
) -> coherent::Output {
    let img = weighted_image(example, weights);
    match img.channels {
        3 => coherent::run(&Features::<3>::from_image(&img), inputs, params, progress),
        4 => coherent::run(&Features::<4>::from_image(&img), inputs, params, progress),
        5 => coherent::run(&Features::<5>::from_image(&img), inputs, params, progress),
        k => unreachable!("examples have 3 to 5 channels, not {k}"),
    }
}

/// Weights of the matched channels in the l2 distance.
///
/// All channels are in 0..1 (linear RGB, alpha, maps scaled to the file's range), so
/// weight 1 means "a full-range step in this channel counts as much as a full-range step in
/// one colour channel". Alpha defaults to 1: transparency edges are as visible as colour
/// edges. Height defaults to 3: it is one channel against three colour channels, and a
/// height map's structure (bumps, grooves) is what it is for; with 3 it weighs as much as
/// the colour together, so colour and relief stay aligned.
///
/// Other maps of a material (`--map`) are matched only when given a weight (`--match
/// NAME=WEIGHT`, per channel like `color`): a roughness or normal map usually follows the
/// colour's structure, so comparing it costs time without changing what is found, and a
/// map that is not matched is still copied from the same source positions.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Weights {
    pub color: f32,
    pub alpha: f32,
    /// The height map's weight when [`Weights::maps`] does not name it.
    pub height: f32,
    /// `--match NAME=WEIGHT`: the weight of each channel of map NAME (the last one given
    /// counts).
    pub maps: Vec<(String, f32)>,
}

impl Default for Weights {
    fn default() -> Self {
        Self {
            color: 1.0,
            alpha: 1.0,
            height: 3.0,
            maps: Vec::new(),
        }
    }
}

impl Weights {
    /// The weight of each channel of the map named `name` (0: copied, not matched).
    pub fn map(&self, name: &str) -> f32 {
        self.maps
            .iter()
            .rev()
            .find(|(n, _)| n == name)
            .map(|m| m.1)
            .unwrap_or(if name == crate::example::HEIGHT {
                self.height
            } else {
                0.0
            })
    }

    /// Refuses weights of maps `example` does not have, and weights that are not finite
    /// non-negative numbers (one line naming the map).
    pub fn check(&self, example: &Example) -> Result<()> {
        for (name, w) in &self.maps {
            if example.map(name).is_none() {
                let have: Vec<&str> = example.maps.iter().map(|m| m.name.as_str()).collect();
                return Err(crate::Error::invalid(format!(
                    "--match {name}: there is no map named '{name}' (maps given: {})",
                    if have.is_empty() {
                        "none; add --map NAME=FILE".to_string()
                    } else {
                        have.join(", ")
                    }
                )));
            }
            if !(w.is_finite() && *w >= 0.0) {
                return Err(crate::Error::invalid(format!(
                    "--match {name}={w}: a weight is a finite number >= 0"
                )));
            }
        }
        Ok(())
    }

    /// What the matchers see of `example`: its colour (and alpha) and the maps with a
    /// positive weight.
    pub fn matched(&self, example: &Example) -> Example {
        example.with_maps_where(|m| self.map(&m.name) > 0.0)
    }

    /// One weight per channel of [`Example::channel_names`].
    pub fn per_channel(&self, example: &Example) -> Vec<f32> {
        let mut w = vec![self.color; 3];
        if example.alpha.is_some() {
            w.push(self.alpha);
        }
        for m in &example.maps {
            let mw = self.map(&m.name);
            w.extend(std::iter::repeat_n(mw, m.channels));
        }
        w
    }
}

/// Names of the channels of `facemaps.exr` for `example`: R G B \[A\], every map's
/// (`NAME.R NAME.G NAME.B` or `NAME.Y`), `height` again when there is a height map (the
/// name BRIEF's first contract and `--displace` use), source.u source.v.
pub fn output_channels(example: &Example) -> Vec<String> {
    let mut v = example.channel_names();
    if example.height_map().is_some() {
        v.push(crate::example::HEIGHT.into());
    }
    v.extend(["source.u".into(), "source.v".into()]);
    v
}

/// The `facemaps.exr` content: every channel looked up bilinearly in the (unweighted)
/// example at the texel's source position — all channels of all maps from the same place
/// — plus the source position itself.
pub fn face_maps(
    example: &Example,
    source: &[[f32; 2]],
    layout: &std::sync::Arc<crate::layout::TexelLayout>,
) -> FaceMaps {
    face_maps_blended(example, source, None, layout)
}

/// [`face_maps`] with texture blending: a texel with entries in `blend` gets
/// v + Σ share_i (E(p_i) − v), v the look-up at its own source and E(p_i) at its extra
/// sources, every channel with the same shares (the maps stay aligned with the colour);
/// every other texel, and `source.u/v` of every texel, as [`face_maps`].
pub fn face_maps_blended(
    example: &Example,
    source: &[[f32; 2]],
    blend: Option<&Blend>,
    layout: &std::sync::Arc<crate::layout::TexelLayout>,
) -> FaceMaps {
    let names = output_channels(example);
    let k = example.num_channels();
    // The height alias: the channel of the height map, copied.
    let alias = example.height_map().map(|_| {
        let mut c = 3 + example.alpha.is_some() as usize;
        for m in &example.maps {
            if m.name == crate::example::HEIGHT {
                break;
            }
            c += m.channels;
        }
        c
    });
    let kk = k + alias.is_some() as usize;
    let faces = layout.faces();
    assert_eq!(source.len(), layout.len());
    let name_refs: Vec<&str> = names.iter().map(|s| s.as_str()).collect();
    let mut maps = FaceMaps::with_layout(layout.clone(), &name_refs);
    // Written in place, one domain's slice of every channel per task (no second copy of
    // the maps: issue 14, item 6); a domain's slice is its layout range (per-face sizes).
    let mut per_face: Vec<Vec<&mut [f32]>> =
        (0..faces).map(|_| Vec::with_capacity(kk + 2)).collect();
    for (_, data) in maps.channels.iter_mut() {
        let mut rest: &mut [f32] = data.as_mut_slice();
        for (f, slot) in per_face.iter_mut().enumerate() {
            let (chunk, tail) = std::mem::take(&mut rest).split_at_mut(layout.range(f).len());
            slot.push(chunk);
            rest = tail;
        }
    }
    per_face
        .into_par_iter()
        .enumerate()
        .for_each(|(f, mut ch)| {
            let r = layout.range(f);
            let mut v = vec![0.0f32; k];
            let (mut own, mut extra) = (vec![0.0f32; k], vec![0.0f32; k]);
            let mut entries = blend.map_or(0..0, |b| b.range(r.clone()));
            for i in 0..r.len() {
                let s = source[r.start + i];
                example.bilinear(s[0], s[1], &mut v);
                if let Some(b) = blend {
                    // v + Σ share (E(p) − v), each difference from the value as looked up
                    // (the shares are of the texel's own value).
                    let mut first = true;
                    while entries.start < entries.end {
                        let (t, p, share) = b.entry(entries.start);
                        if t != r.start + i {
                            break;
                        }
                        if first {
                            own.copy_from_slice(&v);
                            first = false;
                        }
                        example.bilinear(p[0], p[1], &mut extra);
                        for c in 0..k {
                            v[c] += share * (extra[c] - own[c]);
                        }
                        entries.start += 1;
                    }
                }
                for c in 0..k {
                    ch[c][i] = v[c];
                }
                if let Some(a) = alias {
                    ch[k][i] = v[a];
                }
                ch[kk][i] = s[0];
                ch[kk + 1][i] = s[1];
            }
        });
    maps
}

/// The `geometry.exr` content (P.X P.Y P.Z N.X N.Y N.Z), from already evaluated texels.
pub fn geometry_maps(geom: &TexelGeometry) -> FaceMaps {
    let names = crate::bake::GEOMETRY_CHANNELS;
    let mut maps = FaceMaps::with_layout(geom.layout.clone(), &names);
    for (c, (_, data)) in maps.channels.iter_mut().enumerate() {
        let src = if c < 3 { &geom.pos } else { &geom.normal };
        let axis = c % 3;
        data.par_iter_mut()
            .zip(src.par_iter())
            .for_each(|(o, v)| *o = v[axis]);
    }
    maps
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::example::MaterialMap;

    fn material() -> Example {
        let rgb = (0..256)
            .map(|i| [(i % 16) as f32 / 16.0, 0.5, 0.2])
            .collect();
        let nrm = (0..256 * 3).map(|i| (i % 7) as f32 / 7.0).collect();
        let rough = (0..256).map(|i| (i / 16) as f32 / 16.0).collect();
        Example::from_linear(16, 16, rgb)
            .with_map(MaterialMap::from_linear("normal", 3, nrm))
            .unwrap()
            .with_map(MaterialMap::from_linear("roughness", 1, rough))
            .unwrap()
    }

    /// The analysis key changes with the matched maps and their weights, not with maps that
    /// are only copied.
    #[test]
    fn appearance_key_follows_matched_maps_and_weights() {
        let ex = material();
        let key = |w: &Weights| {
            let m = w.matched(&ex);
            appearance_key(&weighted_image(&m, w), AppearanceMode::Pca, DIMS)
        };
        let plain = Weights::default();
        let colour_only = Example::from_linear(16, 16, ex.rgb.clone());
        assert_eq!(
            key(&plain),
            appearance_key(
                &weighted_image(&colour_only, &plain),
                AppearanceMode::Pca,
                DIMS
            )
        );
        let mut w1 = plain.clone();
        w1.maps.push(("normal".into(), 1.0));
        let mut w2 = plain.clone();
        w2.maps.push(("normal".into(), 2.0));
        let mut w3 = plain.clone();
        w3.maps.push(("roughness".into(), 1.0));
        let keys = [key(&plain), key(&w1), key(&w2), key(&w3)];
        for i in 0..4 {
            for j in 0..i {
                assert_ne!(keys[i], keys[j], "{i} vs {j}");
            }
        }
        assert_eq!(w1.per_channel(&ex), [1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 0.0]);
        assert_eq!(w1.matched(&ex).num_channels(), 6);
    }

    /// Blended face maps mix every channel — colour and every map — with the same shares,
    /// keep source.u/v, and leave texels without entries as [`face_maps`] writes them.
    #[test]
    fn blending_mixes_every_channel_with_the_same_shares() {
        let ex = material();
        let layout = std::sync::Arc::new(crate::layout::TexelLayout::uniform(1, 4));
        let source: Vec<[f32; 2]> = (0..16).map(|i| [1.5 + i as f32 * 0.7, 3.25]).collect();
        let blend = Blend::from_entries(vec![
            (5, [12.5, 9.5], 0.25),
            (5, [2.5, 14.5], 0.125),
            (11, [7.5, 1.5], 0.2),
        ]);
        let plain = face_maps(&ex, &source, &layout);
        let mixed = face_maps_blended(&ex, &source, Some(&blend), &layout);
        let k = ex.num_channels();
        let names = output_channels(&ex);
        let look = |p: [f32; 2]| {
            let mut v = vec![0.0f32; k];
            ex.bilinear(p[0], p[1], &mut v);
            v
        };
        for (t, &src) in source.iter().enumerate() {
            let own = look(src);
            let mut want = own.clone();
            for (_, p, share) in (0..blend.len())
                .map(|i| blend.entry(i))
                .filter(|e| e.0 == t)
            {
                let e = look(p);
                for c in 0..k {
                    want[c] += share * (e[c] - own[c]);
                }
            }
            for (c, name) in names.iter().take(k).enumerate() {
                let got = mixed.channel(name).unwrap()[t];
                assert_eq!(got.to_bits(), want[c].to_bits(), "texel {t} {name}");
                if t != 5 && t != 11 {
                    assert_eq!(got.to_bits(), plain.channel(name).unwrap()[t].to_bits());
                }
            }
        }
        // Texel 5 really mixes: its colour and its maps move.
        for name in ["R", "normal.R", "roughness.Y"] {
            assert_ne!(
                mixed.channel(name).unwrap()[5],
                plain.channel(name).unwrap()[5],
                "{name}"
            );
        }
        for c in ["source.u", "source.v"] {
            assert_eq!(mixed.channel(c), plain.channel(c));
        }
    }

    #[test]
    fn unknown_match_names_are_refused() {
        let ex = material();
        let mut w = Weights::default();
        w.maps.push(("metalness".into(), 1.0));
        let e = w.check(&ex).unwrap_err().to_string();
        assert!(
            e.contains("metalness") && e.contains("normal, roughness"),
            "{e}"
        );
        assert!(!e.contains('\n'));
    }
}
