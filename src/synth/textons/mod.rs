//! BTF synthesis with surface textons (paper 003, Tong et al. 2002): one source position per
//! texel chosen for *every* image of a BTF sample at once, so the surface BTF — the sample
//! indexed by `source.u/v` — keeps one consistent mesostructure under every light.
//!
//! 1. **Texton analysis** ([`analysis`], 003 §4): per level of the sample's pyramid, the
//!    images' filter responses clustered into textons; the texton map t_in and the
//!    dot-product matrix Γ. Saved in the analysis cache ([`crate::cache`]; kind
//!    `textons`), keyed by every image's pixels and the parameters.
//! 2. **Synthesis** (003 §5): the multiscale synthesis of [`crate::synth::multiscale`] —
//!    two passes per level, pass 2 with two-level neighbourhoods (9x9 of the level and 5x5
//!    of the coarser one), k-coherence search (003 §5.2: k = 11 nearest per pixel by the
//!    same two-level distance) — run on the texton pyramid: neighbourhoods hold textons,
//!    and their distances are Γ's ([`analysis`] explains the factorisation that makes them
//!    plain l2). The k-NN lists are cached too (kind `texton-model`).
//!
//! Texel graph, sampling (charts and marching), schedule and the continuous-source
//! layout are multiscale's, unchanged: only what a pixel *is* differs (a texton instead of
//! an appearance vector), which is 003's point.

pub mod analysis;

pub use analysis::{TextonInfo, TextonParams, Textons};

use crate::btf::BtfSample;
use crate::error::Result;
use crate::synth::matching::appearance::{AppearanceInfo, AppearanceMode};
use crate::synth::matching::search::model::ExampleModel;
use crate::synth::multiscale::{self, Model, MultiscaleParams};
use crate::synth::{Analyses, Target};
use serde::Serialize;
use std::sync::{Arc, Mutex};

/// What texton synthesis did (report.json `textons`).
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct Stats {
    /// Images of the sample.
    pub images: usize,
    /// The image facemaps.exr's colour comes from.
    pub default_image: usize,
    pub analysis: TextonInfo,
    /// Seconds of texton analysis (0 when it came from the cache).
    pub analysis_seconds: f64,
    /// The multiscale synthesis over the texton pyramid.
    pub synthesis: multiscale::Stats,
}

/// The key of the texton analysis of `sample` for levels `j0..j0 + levels`.
fn textons_key(
    sample: &BtfSample,
    j0: usize,
    levels: usize,
    p: &TextonParams,
) -> crate::cache::Key {
    crate::cache::KeyBuilder::new("textons")
        .u64(sample.width as u64)
        .u64(sample.height as u64)
        .u64(sample.images.len() as u64)
        .f32s(&sample.key_pixels())
        .u64(j0 as u64)
        .u64(levels as u64)
        .u64(p.textons as u64)
        .u64(p.iterations as u64)
        .u64(analysis::FILTERS as u64)
        .finish()
}

/// Synthesizes `sample` over `target`: a source position per texel (level-0 sample
/// pixels, centres at +0.5).
pub fn run(
    sample: &BtfSample,
    target: &Target<'_>,
    params: &TextonParams,
    ms: &MultiscaleParams,
    analyses: &Analyses,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<(Vec<[f32; 2]>, Stats)> {
    let weights = [1.0f32; 3];
    let inputs = multiscale::Inputs {
        surface: target.surface,
        field: target.field,
        layout: target.texels.layout(),
        spacing: target.spacing,
        scale: target.scale(),
        scale_field: target.scale_field,
        seed: target.seed,
        weights: &weights,
        appearance: AppearanceMode::Pca,
        feature_distance: 0.0,
    };
    let found: Mutex<(TextonInfo, f64)> = Mutex::new(Default::default());
    let build = |j0: usize, levels: usize| -> Result<Arc<Model>> {
        let t0 = std::time::Instant::now();
        let key = textons_key(sample, j0, levels, params);
        let mut built = false;
        let textons = analyses.get("textons", key, || {
            built = true;
            Textons::analyse(sample, j0, levels, params)
        });
        let seconds = if built {
            t0.elapsed().as_secs_f64()
        } else {
            0.0
        };
        let mut kept = Vec::new();
        let pyramid = crate::pyramid::Pyramid {
            levels: textons
                .levels
                .iter()
                .map(|l| {
                    let (img, k) = l.embedded_image(params.dims);
                    kept.push(k);
                    img
                })
                .collect(),
        };
        let info = TextonInfo {
            textons: textons.levels.iter().map(|l| l.textons).collect(),
            response_dims: sample.images.len() * analysis::FILTERS,
            kept_variance: kept.clone(),
        };
        *found.lock().unwrap_or_else(|e| e.into_inner()) = (info, seconds);
        let mut key = crate::cache::KeyBuilder::new("texton-model");
        for l in &pyramid.levels {
            key = key.image(l);
        }
        let m = &ms.model;
        key = key
            .u64(m.fine as u64)
            .u64(m.coarse as u64)
            .u64(m.coarsest as u64)
            .str(&format!("{:?}", m.method));
        let appearance = AppearanceInfo {
            dims: params.dims,
            window: 1,
            kept_variance: kept.first().copied().unwrap_or(1.0),
            feature_distance: 0.0,
            reflectance: None,
        };
        analyses.try_get("texton-model", key.finish(), || {
            Ok(Model {
                model: ExampleModel::from_pyramid(pyramid.clone(), ms.model)?,
                appearance,
            })
        })
    };
    // The sparse block and the continued finest start were measured for multiscale
    // synthesis of single images only: textons keep the full block and pass 1.
    let ms = &MultiscaleParams {
        sparse: false,
        continue_finest: false,
        ..*ms
    };
    let out = multiscale::run_on_model(
        [sample.width, sample.height],
        &inputs,
        ms,
        &build,
        &|d, t| progress(d as usize, t as usize),
    )?;
    let (analysis, analysis_seconds) = found.into_inner().unwrap_or_else(|e| e.into_inner());
    Ok((
        out.source,
        Stats {
            images: sample.images.len(),
            default_image: sample.default,
            analysis,
            analysis_seconds,
            synthesis: out.stats,
        },
    ))
}
