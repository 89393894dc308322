//! `surfsynth eval`: the quality measures of BRIEF ("Quality measures"), computed from a
//! result directory alone (docs/eval.md has the definitions and conventions).
//!
//! Submodules: [`pf`] (patch fidelity pfS on a pixel grid: disc blur, windows, the exact
//! nearest-window search, result types) and [`surface`] (pfS windows walked on any
//! surface, and the lattice test that sends flat aligned grids to the pixel-grid code), and
//! [`peer`] (inputs of the peer benchmark, bench/peer.sh).
//!
//! Everything is measured on the written files — `facemaps.exr` (colour, `source.u/v`) and
//! `geometry.exr` (`P.X/Y/Z`, `N.X/Y/Z`) — never on in-memory state of the synthesizer, so
//! the numbers judge exactly what a user gets, and any program writing the same layout can
//! be judged the same way. [`evaluate_maps`] exposes the same computation on maps already in
//! memory (for tests that synthesize without writing).
//!
//! Conventions the BRIEF leaves open, fixed here (and in docs/eval.md):
//! - "adjacent texels of one face": horizontal or vertical neighbours (x±1 or y±1) in the
//!   same domain; every unordered pair counted once.
//! - percentiles (median, p10, p90, and the median h) interpolate linearly between order
//!   statistics (numpy's default): `p(q) = v[i] + (v[i+1] - v[i]) (q (n-1) - i)`.
//! - seam pairs: unordered pairs of border texels (x or y in {0, N-1}) of different domains
//!   with 0.5h <= |P_a - P_b| <= 1.25h, found with a k-d tree over border texel positions.
//! - non-finite values are left out of every measure except coverage, which counts them.
//! - sums are accumulated per domain and added in domain order, so the output does not
//!   depend on the number of threads.

pub mod peer;
pub mod pf;
pub mod surface;
mod texel_bvh;

use crate::error::{Error, Result};
use crate::example::Example;
use crate::io::exr::{read_face_maps, FaceMaps};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

pub use pf::{
    image_patch_fidelities, PatchFidelity, PfDetail, PfMethod, PfOptions, PfScale, Rgb, PF_SAMPLES,
    PF_SCALES, PF_SUMMARY_SAMPLES,
};
pub use surface::{patch_fidelities_of, patch_fidelities_with, TexelPoints};
pub use texel_bvh::Xyz;

/// The pfS figures `synth` prints at the end of a run and records in report.json
/// (`patch_fidelity`): measured like `eval`'s, on fewer drawn texels.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PfSummary {
    pub pf1: Option<f64>,
    pub pf4: Option<f64>,
    pub pf8: Option<f64>,
    pub method: PfMethod,
    /// Texels drawn ([`PF_SUMMARY_SAMPLES`] unless the maps have fewer).
    pub samples: usize,
    /// Wall-clock seconds of the measurement (`synth`: also `seconds.pf`, beside writing,
    /// and part of `seconds.total`).
    pub seconds: f64,
    /// Where the example banks came from, one per spacing with windows, sorted (`synth`:
    /// the analysis cache, `hit` from the second run with an example on; empty when not
    /// asked).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub bank_sources: Vec<crate::synth::analysis::Source>,
}

/// [`PfSummary`] of maps in memory: [`PF_SUMMARY_SAMPLES`] drawn texels, so that it costs
/// a fraction of a second next to a synthesis run (the figures differ from `eval`'s
/// 1024-texel ones by sampling noise, a few percent).
pub fn summary_fidelity(
    colour: &FaceMaps,
    geometry: &FaceMaps,
    example: &Example,
    scale: f64,
) -> PfSummary {
    let t0 = std::time::Instant::now();
    let p = match TexelPoints::of_maps(geometry) {
        Some(g) => summary_pf(colour, g, example, scale, None, false),
        None => PatchFidelity::empty(PfMethod::Surface),
    };
    summary_of(p, t0)
}

/// [`summary_fidelity`] on texel geometry wherever it is: `synth` measures its result
/// with the texel geometry in place (no geometry-map copy at the run's peak).
pub fn summary_fidelity_of(
    colour: &FaceMaps,
    geometry: TexelPoints,
    example: &Example,
    scale: f64,
) -> PfSummary {
    let t0 = std::time::Instant::now();
    summary_of(
        summary_pf(colour, geometry, example, scale, None, false),
        t0,
    )
}

/// [`summary_fidelity_of`] with the example-side banks (one per spacing S) taken from
/// `banks` — memory, else its disk cache, else built and saved (kind `pf-bank`) — as
/// `synth` does: they depend on the example alone and were most of the summary's time on
/// small meshes. The same figures; `bank_sources` says where the banks came from.
/// `finite`: the caller has checked that every texel position and colour is finite
/// (`synth` checks them before its write stage, issue 18), so the point cloud skips its
/// own scan of them (which would find every texel valid: the same figures).
pub fn summary_fidelity_cached(
    colour: &FaceMaps,
    geometry: TexelPoints,
    example: &Example,
    scale: f64,
    banks: &crate::synth::Analyses,
    finite: bool,
) -> PfSummary {
    let t0 = std::time::Instant::now();
    let mut s = summary_of(
        summary_pf(colour, geometry, example, scale, Some(banks), finite),
        t0,
    );
    // The spacings run side by side: sorted, so the list does not depend on the threads.
    s.bank_sources = banks.take_events().into_iter().map(|e| e.source).collect();
    s.bank_sources.sort();
    s
}

fn summary_pf(
    colour: &FaceMaps,
    geometry: TexelPoints,
    example: &Example,
    scale: f64,
    banks: Option<&crate::synth::Analyses>,
    finite: bool,
) -> PatchFidelity {
    let opts = PfOptions {
        samples: PF_SUMMARY_SAMPLES,
        ..Default::default()
    };
    surface::patch_fidelities_in(colour, geometry, example, Some(scale), &opts, banks, finite)
}

fn summary_of(p: PatchFidelity, t0: std::time::Instant) -> PfSummary {
    PfSummary {
        pf1: p.pf1,
        pf4: p.pf4,
        pf8: p.pf8,
        method: p.detail.method,
        samples: p.detail.drawn,
        seconds: t0.elapsed().as_secs_f64(),
        bank_sources: Vec::new(),
    }
}

/// pf1, pf4, pf8 of face maps in memory (BRIEF's pfS; docs/eval.md) with `eval`'s
/// settings: [`PF_SAMPLES`] drawn texels, the lattice on flat aligned grids, else the
/// surface method. `colour` needs R, G, B (and `source.u/v` for the surface method's
/// directions), `geometry` needs P.X/Y/Z (N.X/Y/Z used when present); `scale` is the
/// surface length per example pixel (`None`: the median texel spacing).
pub fn patch_fidelities(
    colour: &FaceMaps,
    geometry: &FaceMaps,
    example: &Example,
    scale: Option<f64>,
) -> PatchFidelity {
    patch_fidelities_with(colour, geometry, example, scale, &PfOptions::default())
}

pub use crate::io::names::{FACEMAPS_FILE, GEOMETRY_FILE, REPORT_FILE};

/// Adjacent texels whose source positions differ by at most this many example pixels
/// continue one patch (BRIEF).
pub const COHERENT_PIXELS: f64 = 4.0;
/// Side of the patches compared by the legacy `patch_fidelity` (BRIEF: 7x7).
pub const PATCH: usize = 7;
/// Output patches sampled for the legacy `patch_fidelity`.
pub const PATCH_SAMPLES: usize = 1024;
/// Random example patch pairs averaged for the legacy `patch_fidelity`'s denominator.
pub const PATCH_PAIRS: usize = 4096;
/// Largest angle (degrees) between any normal and the mean normal for a mesh to count as
/// flat for the legacy `patch_fidelity`.
pub const FLAT_DEGREES: f64 = 1.0;

/// Median and 10th/90th percentiles of a sample, with its size.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Spread {
    pub median: f64,
    pub p10: f64,
    pub p90: f64,
    /// Number of values.
    pub count: usize,
}

/// The quality measures of one result (serialised as the JSON `eval` prints).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Quality {
    /// Face domains F.
    pub faces: usize,
    /// Texels per domain side N (with per-face resolutions: the largest side).
    pub resolution: usize,
    /// F·N² (with per-face resolutions: their sum).
    pub texels: usize,
    /// Texel-density spread: the 95th over the 5th percentile ([`percentile`]) of the
    /// faces' median adjacent-texel distances (`--texel-size` keeps it within 2; one N
    /// gives 11x on Spot). `None` without two faces with adjacent texel pairs.
    #[serde(default)]
    pub spacing_spread: Option<f64>,
    /// [`Quality::seam_ratio`] over only the seam pairs between faces of different
    /// resolution (per-face resolutions), with the same interior mean. `None` without such
    /// pairs.
    #[serde(default)]
    pub seam_ratio_mixed: Option<f64>,
    /// Number of those pairs.
    #[serde(default)]
    pub seam_pairs_mixed: usize,
    /// [`Quality::seam_ratio`] over only the seam pairs that lie along a grid axis of their
    /// first texel (within 23° of its u or v step), with the same interior mean — a
    /// diagnostic, not BRIEF's measure. The interior pairs are u- and v-neighbours, but
    /// BRIEF's 0.5h–1.25h band also takes diagonal pairs across a border wherever texels
    /// are smaller than h (√2 × 0.88h < 1.25h), and a diagonal pair differs more (it is
    /// farther, and crosses both a structure's rows and columns). On a closed cube with
    /// bricks (optimise, N = 32) 41% of the seam pairs were diagonal and 93% of those
    /// continued their copy: the seam ratio 1.22 was 0.75 along the axes
    /// (docs/synthesis.md, "Known limits"). `None` without such pairs.
    #[serde(default)]
    pub seam_ratio_axis: Option<f64>,
    /// Number of those pairs.
    #[serde(default)]
    pub seam_pairs_axis: usize,
    /// Fraction of texels whose colour (R, G, B) and position are all finite. Must be 1.
    pub coverage: f64,
    /// h: median distance between centres of adjacent texels of one face (`None` when
    /// N = 1 or no positions are finite).
    pub texel_spacing: Option<f64>,
    /// Mean |C_a - C_b|² over seam pairs divided by the same over adjacent pairs inside
    /// faces. `None` when undefined: no seam pairs, or no colour variation inside faces
    /// while seams vary (then the ratio is infinite). 1 when both means are 0.
    pub seam_ratio: Option<f64>,
    /// Number of seam pairs (different domains, 0.5h..1.25h apart).
    pub seam_pairs: usize,
    /// Mean |C_a - C_b|² over seam pairs (`None` without seam pairs).
    pub seam_mean_sq: Option<f64>,
    /// Number of adjacent pairs inside faces with finite colours.
    pub interior_pairs: usize,
    /// Mean |C_a - C_b|² over adjacent pairs inside faces (`None` without pairs).
    pub interior_mean_sq: Option<f64>,
    /// The scale S used (surface length per example pixel), when known.
    pub scale: Option<f64>,
    /// r = |source_a - source_b|·S/|P_a - P_b| over adjacent pairs continuing a patch.
    /// With a scale map (geometry.exr has `scale`, and no `--scale` was given) S is the
    /// requested local scale, the mean of the pair's two values, so a result that follows
    /// the map scores 1. `None` without `source.u`/`source.v` channels or without
    /// continued pairs.
    pub scale_fidelity: Option<Spread>,
    /// The smallest and largest requested local scale (geometry.exr `scale`) when scale
    /// fidelity was measured against it; `None` with one scale S.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub local_scale: Option<[f64; 2]>,
    /// Share of adjacent pairs (finite sources) whose sources are at most 4 px apart.
    pub coherent_fraction: Option<f64>,
    /// BRIEF's patch fidelity at S = 1 (pixel noise); `None` without an example or
    /// when no window could be laid (docs/eval.md).
    pub pf1: Option<f64>,
    /// pfS at S = 4 (structure).
    pub pf4: Option<f64>,
    /// pfS at S = 8 (larger structure).
    pub pf8: Option<f64>,
    /// How pf1/pf4/pf8 were measured: method (`lattice` or `surface`), texels drawn,
    /// fallback directions, and per S the windows laid and skipped and both means.
    #[serde(default)]
    pub pf_detail: Option<PfDetail>,
    /// The example the pfS were measured against (`--example`, or report.json's
    /// `inputs.example` when that file exists).
    #[serde(default)]
    pub example: Option<String>,
    /// Legacy (issue 5) measure, kept while tests compare against it: mean l2 (not
    /// squared) distance of 7x7 texel windows inside one domain to their nearest example
    /// window over the same mean for random example windows. Flat meshes only (`None` on
    /// curved ones); superseded by pf1/pf4/pf8.
    pub patch_fidelity: Option<f64>,
}

/// What to evaluate beyond the files.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct EvalOptions {
    /// Scale S; `None` reads `scale` from DIR/report.json (only needed when the maps carry
    /// source positions). Given, it replaces geometry.exr's local `scale` channel (a
    /// scale-map result measured against one scale).
    pub scale: Option<f64>,
    /// Example image for patch fidelity; `None` takes report.json's `inputs.example`
    /// when that file exists.
    pub example: Option<PathBuf>,
}

/// Evaluates the result in `dir` with the scale given or taken from its report.
pub fn evaluate(dir: &Path, scale: Option<f64>) -> anyhow::Result<Quality> {
    Ok(evaluate_with(
        dir,
        &EvalOptions {
            scale,
            example: None,
        },
    )?)
}

/// Evaluates the result in `dir` with all options.
pub fn evaluate_with(dir: &Path, opts: &EvalOptions) -> Result<Quality> {
    evaluate_loaded(dir, opts).map(|(q, _)| q)
}

/// [`evaluate_with`], keeping the geometry maps it read (for [`windows_csv`]).
fn evaluate_loaded(dir: &Path, opts: &EvalOptions) -> Result<(Quality, FaceMaps)> {
    if let Some(s) = opts.scale {
        check_scale(s)?;
    }
    match std::fs::metadata(dir) {
        Ok(m) if m.is_dir() => {}
        Ok(_) => {
            return Err(Error::file(
                dir,
                "not a directory (expected a result directory)",
            ))
        }
        Err(e) => return Err(Error::io(dir, "cannot open result directory", e)),
    }
    let colour_path = dir.join(FACEMAPS_FILE);
    let geometry_path = dir.join(GEOMETRY_FILE);
    let colour = read_face_maps(&colour_path)?;
    let geometry = read_face_maps(&geometry_path)?;
    if colour.layout != geometry.layout {
        return Err(Error::file(
            &geometry_path,
            format!(
                "has {} faces at {}, but {} has {} faces at {}",
                geometry.faces(),
                geometry.layout.describe(),
                colour_path.display(),
                colour.faces(),
                colour.layout.describe()
            ),
        ));
    }
    for name in ["R", "G", "B"] {
        if colour.channel(name).is_none() {
            return Err(Error::file(
                &colour_path,
                format!("has no '{name}' channel"),
            ));
        }
    }
    for name in ["P.X", "P.Y", "P.Z"] {
        if geometry.channel(name).is_none() {
            return Err(Error::file(
                &geometry_path,
                format!("has no '{name}' channel"),
            ));
        }
    }
    let has_source = colour.channel("source.u").is_some() && colour.channel("source.v").is_some();
    let scale = match opts.scale {
        Some(s) => Some(s),
        None if has_source => Some(report_scale(&dir.join(REPORT_FILE))?),
        None => None,
    };
    let example_path = match &opts.example {
        Some(p) => Some(p.clone()),
        None => report_example(dir),
    };
    let example = match &example_path {
        Some(p) => Some(Example::load(p)?),
        None => None,
    };
    let local = match opts.scale {
        Some(_) => None,
        None => geometry.channel(crate::scale_field::CHANNEL),
    };
    let mut q = evaluate_maps_local(&colour, &geometry, scale, local, example.as_ref())
        .map_err(|e| Error::file(&colour_path, e))?;
    q.scale = scale;
    q.example = example_path.map(|p| p.display().to_string());
    Ok((q, geometry))
}

/// Every pf window of `detail` as CSV, one row per drawn centre in drawing order, so that
/// what pfS averages can be seen where it is (docs/eval.md, "Per window"): with the
/// result's `geometry`, `face,u,v,x,y,z,pf1,pf4,pf8` (the centre texel's domain, its
/// (u, v) in the domain and its limit position); without (an image), `x,y,pf1,pf4,pf8` in
/// pixels of an image `width` wide. Each pfS cell is that window's own score, empty where
/// no window was laid; the mean of a column is the pfS `eval` reports.
pub fn windows_csv(detail: &PfDetail, geometry: Option<&FaceMaps>, width: usize) -> String {
    use std::fmt::Write;
    let score = |s: usize, k: usize| -> String {
        detail
            .scales
            .iter()
            .find(|x| x.s == s)
            .and_then(|x| x.per_window.get(k).copied().flatten())
            .map(|v| format!("{v}"))
            .unwrap_or_default()
    };
    let pos =
        geometry.and_then(|g| Some((g.channel("P.X")?, g.channel("P.Y")?, g.channel("P.Z")?)));
    let mut out = String::new();
    out.push_str(match geometry {
        Some(_) => "face,u,v,x,y,z,pf1,pf4,pf8\n",
        None => "x,y,pf1,pf4,pf8\n",
    });
    for (k, &c) in detail.centres.iter().enumerate() {
        match (geometry, pos) {
            (Some(g), Some((px, py, pz))) => {
                let l = g.layout.location(c);
                let _ = write!(
                    out,
                    "{},{},{},{},{},{},",
                    l.domain.idx(),
                    l.u,
                    l.v,
                    px[c],
                    py[c],
                    pz[c]
                );
            }
            _ => {
                let _ = write!(out, "{},{},", c % width.max(1), c / width.max(1));
            }
        }
        let _ = writeln!(out, "{},{},{}", score(1, k), score(4, k), score(8, k));
    }
    out
}

/// The example named by DIR/report.json (`inputs.example`), when that file exists: as
/// written (relative to the current directory), else relative to DIR. `None` when the
/// report is missing or unreadable (the scale's own check reports that when it matters),
/// names an in-memory example, or the file is gone.
pub fn report_example(dir: &Path) -> Option<PathBuf> {
    let text = std::fs::read_to_string(dir.join(REPORT_FILE)).ok()?;
    let v: serde_json::Value = serde_json::from_str(&text).ok()?;
    let name = v.get("inputs")?.get("example")?.as_str()?;
    if name.is_empty() || name.starts_with('<') {
        return None;
    }
    let p = PathBuf::from(name);
    if p.is_file() {
        return Some(p);
    }
    let q = dir.join(&p);
    (p.is_relative() && q.is_file()).then_some(q)
}

fn check_scale(s: f64) -> Result<()> {
    if !(s.is_finite() && s > 0.0) {
        return Err(Error::invalid(format!(
            "scale must be a positive number, got {s}"
        )));
    }
    Ok(())
}

/// The `scale` of a report.json.
fn report_scale(path: &Path) -> Result<f64> {
    let text = std::fs::read_to_string(path).map_err(|e| {
        Error::file(
            path,
            format!("cannot read ({e}); it gives the scale — or pass --scale S"),
        )
    })?;
    let v: serde_json::Value = serde_json::from_str(&text)
        .map_err(|e| Error::file(path, format!("not valid JSON: {e}")))?;
    match v.get("scale").and_then(|s| s.as_f64()) {
        Some(s) if s.is_finite() && s > 0.0 => Ok(s),
        Some(s) => Err(Error::file(
            path,
            format!("'scale' is {s}, not a positive number"),
        )),
        None => Err(Error::file(path, "has no numeric 'scale' — pass --scale S")),
    }
}

/// Whether the legacy `patch_fidelity` applies: every normal within [`FLAT_DEGREES`] of
/// the mean normal, or no normals to tell (maps built in memory without them).
fn is_flat(geometry: &FaceMaps) -> bool {
    let (Some(x), Some(y), Some(z)) = (
        geometry.channel("N.X"),
        geometry.channel("N.Y"),
        geometry.channel("N.Z"),
    ) else {
        return true;
    };
    let mut mean = [0f64; 3];
    for i in 0..x.len() {
        let n = [x[i] as f64, y[i] as f64, z[i] as f64];
        if n.iter().all(|c| c.is_finite()) {
            for k in 0..3 {
                mean[k] += n[k];
            }
        }
    }
    let len = (mean[0] * mean[0] + mean[1] * mean[1] + mean[2] * mean[2]).sqrt();
    if len.is_nan() || len <= 0.0 {
        return false;
    }
    let cos_limit = FLAT_DEGREES.to_radians().cos();
    (0..x.len()).all(|i| {
        let n = [x[i] as f64, y[i] as f64, z[i] as f64];
        let l = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
        l.is_nan()
            || l <= 0.0
            || (n[0] * mean[0] + n[1] * mean[1] + n[2] * mean[2]) / (l * len) >= cos_limit
    })
}

/// Linear-interpolation percentile of sorted values, q in [0, 1].
pub fn percentile(sorted: &[f64], q: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    let pos = q.clamp(0.0, 1.0) * (sorted.len() - 1) as f64;
    let i = pos.floor() as usize;
    let j = (i + 1).min(sorted.len() - 1);
    sorted[i] + (sorted[j] - sorted[i]) * (pos - i as f64)
}

fn spread(mut v: Vec<f64>) -> Option<Spread> {
    if v.is_empty() {
        return None;
    }
    v.sort_by(f64::total_cmp);
    Some(Spread {
        median: percentile(&v, 0.5),
        p10: percentile(&v, 0.1),
        p90: percentile(&v, 0.9),
        count: v.len(),
    })
}

/// Per-domain partial results of the pass over adjacent pairs.
#[derive(Default)]
struct FacePass {
    finite: usize,
    distances: Vec<f64>,
    colour_sum: f64,
    colour_pairs: usize,
    ratios: Vec<f64>,
    source_pairs: usize,
    coherent_pairs: usize,
}

/// The measures on maps in memory: `colour` needs R, G, B (and `source.u`/`source.v` for
/// scale fidelity and coherence), `geometry` needs P.X, P.Y, P.Z. `scale` is required for
/// scale fidelity; `example` enables pf1/pf4/pf8 (any mesh) and the legacy
/// `patch_fidelity` (flat meshes).
pub fn evaluate_maps(
    colour: &FaceMaps,
    geometry: &FaceMaps,
    scale: Option<f64>,
    example: Option<&Example>,
) -> std::result::Result<Quality, String> {
    let local = geometry.channel(crate::scale_field::CHANNEL);
    evaluate_maps_local(colour, geometry, scale, local, example)
}

/// [`evaluate_maps`] with the requested local scale per texel given (`local`, e.g.
/// geometry.exr's `scale`) or not: with it, scale fidelity divides each pair's
/// |Δsource|/|ΔP| by the mean of the pair's local scales instead of `scale`.
pub fn evaluate_maps_local(
    colour: &FaceMaps,
    geometry: &FaceMaps,
    scale: Option<f64>,
    local: Option<&[f32]>,
    example: Option<&Example>,
) -> std::result::Result<Quality, String> {
    let l = &*colour.layout;
    let f = l.faces();
    let n = l.largest_side();
    if geometry.layout != colour.layout {
        return Err("colour and geometry maps differ in faces or resolution".into());
    }
    let ch = |m: &FaceMaps, name: &str| -> std::result::Result<Vec<f32>, String> {
        m.channel(name)
            .map(|c| c.to_vec())
            .ok_or_else(|| format!("no '{name}' channel"))
    };
    let (r, g, b) = (ch(colour, "R")?, ch(colour, "G")?, ch(colour, "B")?);
    let (px, py, pz) = (
        ch(geometry, "P.X")?,
        ch(geometry, "P.Y")?,
        ch(geometry, "P.Z")?,
    );
    let src = match (colour.channel("source.u"), colour.channel("source.v")) {
        (Some(u), Some(v)) => Some((u, v)),
        _ => None,
    };
    if let Some(s) = scale {
        if !(s.is_finite() && s > 0.0) {
            return Err(format!("scale must be a positive number, got {s}"));
        }
    }
    let texels = l.len();
    if let Some(ls) = local {
        if ls.len() != texels {
            return Err(format!(
                "the '{}' channel has {} values for {texels} texels",
                crate::scale_field::CHANNEL,
                ls.len()
            ));
        }
    }
    let local_range = local.map(|ls| {
        let it = ls.iter().filter(|v| v.is_finite() && **v > 0.0);
        [
            it.clone().fold(f64::INFINITY, |m, &v| m.min(v as f64)),
            it.fold(0.0f64, |m, &v| m.max(v as f64)),
        ]
    });
    let col = |i: usize| [r[i] as f64, g[i] as f64, b[i] as f64];
    let pos = |i: usize| [px[i] as f64, py[i] as f64, pz[i] as f64];
    let finite = |a: &[f64; 3]| a.iter().all(|c| c.is_finite());
    let dist2 = |a: &[f64; 3], b: &[f64; 3]| {
        (a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)
    };

    // One pass over every domain's adjacent pairs.
    let passes: Vec<FacePass> = (0..f)
        .into_par_iter()
        .map(|d| {
            let mut p = FacePass::default();
            let base = l.start(d);
            let (nu, nv) = l.dims(d);
            for i in l.range(d) {
                if finite(&col(i)) && finite(&pos(i)) {
                    p.finite += 1;
                }
            }
            for y in 0..nv {
                for x in 0..nu {
                    let a = base + y * nu + x;
                    let mut pair = |bi: usize| {
                        let (pa, pb) = (pos(a), pos(bi));
                        let dp = if finite(&pa) && finite(&pb) {
                            let d = dist2(&pa, &pb).sqrt();
                            p.distances.push(d);
                            Some(d)
                        } else {
                            None
                        };
                        let (ca, cb) = (col(a), col(bi));
                        if finite(&ca) && finite(&cb) {
                            p.colour_sum += dist2(&ca, &cb);
                            p.colour_pairs += 1;
                        }
                        if let Some((su, sv)) = src {
                            let ds = ((su[a] - su[bi]) as f64).hypot((sv[a] - sv[bi]) as f64);
                            if ds.is_finite() {
                                p.source_pairs += 1;
                                if ds <= COHERENT_PIXELS {
                                    p.coherent_pairs += 1;
                                    let s = match local {
                                        Some(ls) => {
                                            let m = 0.5 * (ls[a] as f64 + ls[bi] as f64);
                                            (m.is_finite() && m > 0.0).then_some(m)
                                        }
                                        None => scale,
                                    };
                                    if let (Some(s), Some(dp)) = (s, dp) {
                                        if dp > 0.0 {
                                            p.ratios.push(ds * s / dp);
                                        }
                                    }
                                }
                            }
                        }
                    };
                    if x + 1 < nu {
                        pair(a + 1);
                    }
                    if y + 1 < nv {
                        pair(a + nu);
                    }
                }
            }
            p
        })
        .collect();

    let finite_texels: usize = passes.iter().map(|p| p.finite).sum();
    let mut face_medians: Vec<f64> = passes
        .iter()
        .filter(|p| !p.distances.is_empty())
        .map(|p| {
            let mut d = p.distances.clone();
            d.sort_by(f64::total_cmp);
            percentile(&d, 0.5)
        })
        .collect();
    face_medians.sort_by(f64::total_cmp);
    let spacing_spread = (face_medians.len() >= 2)
        .then(|| percentile(&face_medians, 0.95) / percentile(&face_medians, 0.05));
    let mut distances: Vec<f64> = Vec::with_capacity(2 * texels);
    let (mut colour_sum, mut colour_pairs) = (0.0, 0usize);
    let mut ratios = Vec::new();
    let (mut source_pairs, mut coherent_pairs) = (0usize, 0usize);
    for p in &passes {
        distances.extend_from_slice(&p.distances);
        colour_sum += p.colour_sum;
        colour_pairs += p.colour_pairs;
        ratios.extend_from_slice(&p.ratios);
        source_pairs += p.source_pairs;
        coherent_pairs += p.coherent_pairs;
    }
    drop(passes);
    distances.sort_by(f64::total_cmp);
    let h = percentile(&distances, 0.5);
    drop(distances);

    // Seam pairs: border texels of different domains 0.5h..1.25h apart.
    let seams = if h.is_finite() && h > 0.0 {
        seam_pairs_sum(l, h, &pos, &col)
    } else {
        SeamSums::default()
    };
    let (seam_sum, seam_pairs) = (seams.all.sum, seams.all.count);
    let interior_mean_sq = if colour_pairs > 0 {
        colour_sum / colour_pairs as f64
    } else {
        f64::NAN
    };
    let seam_mean_sq = if seam_pairs > 0 {
        seam_sum / seam_pairs as f64
    } else {
        f64::NAN
    };
    let seam_ratio = if seam_pairs == 0 || colour_pairs == 0 {
        None
    } else if interior_mean_sq > 0.0 {
        Some(seam_mean_sq / interior_mean_sq)
    } else if seam_mean_sq == 0.0 {
        Some(1.0)
    } else {
        None
    };

    let interior = if colour_pairs > 0 {
        interior_mean_sq
    } else {
        0.0
    };
    let (seam_ratio_mixed, seam_pairs_mixed) = (seams.mixed.ratio(interior), seams.mixed.count);
    let (seam_ratio_axis, seam_pairs_axis) = (seams.axis.ratio(interior), seams.axis.count);
    let pfs = example.map(|e| patch_fidelities(colour, geometry, e, scale));
    let patch_fidelity = example
        .filter(|_| is_flat(geometry))
        .and_then(|e| patch_fidelity(colour, e));
    Ok(Quality {
        faces: f,
        resolution: n,
        texels,
        spacing_spread,
        seam_ratio_mixed,
        seam_pairs_mixed,
        seam_ratio_axis,
        seam_pairs_axis,
        coverage: finite_texels as f64 / texels.max(1) as f64,
        texel_spacing: h.is_finite().then_some(h),
        seam_ratio,
        seam_pairs,
        seam_mean_sq: (seam_pairs > 0).then_some(seam_mean_sq),
        interior_pairs: colour_pairs,
        interior_mean_sq: (colour_pairs > 0).then_some(interior_mean_sq),
        scale,
        scale_fidelity: spread(ratios),
        local_scale: local_range,
        coherent_fraction: src
            .filter(|_| source_pairs > 0)
            .map(|_| coherent_pairs as f64 / source_pairs as f64),
        pf1: pfs.as_ref().and_then(|p| p.pf1),
        pf4: pfs.as_ref().and_then(|p| p.pf4),
        pf8: pfs.as_ref().and_then(|p| p.pf8),
        pf_detail: pfs.map(|p| p.detail),
        example: None,
        patch_fidelity,
    })
}

/// |C_a - C_b|² summed over a set of pairs, and their number.
#[derive(Clone, Copy, Debug, Default)]
struct PairSum {
    sum: f64,
    count: usize,
}

impl PairSum {
    fn add(&mut self, e: f64) {
        self.sum += e;
        self.count += 1;
    }

    fn merge(self, o: PairSum) -> PairSum {
        PairSum {
            sum: self.sum + o.sum,
            count: self.count + o.count,
        }
    }

    /// The set's mean over `interior` (the interior pairs' mean), when both are defined.
    fn ratio(self, interior: f64) -> Option<f64> {
        (self.count > 0 && interior > 0.0).then(|| self.sum / self.count as f64 / interior)
    }
}

/// The seam pairs' sums: all of them; those whose faces differ in resolution; those along
/// a grid axis of their first texel ([`Quality::seam_ratio_axis`]).
#[derive(Clone, Copy, Debug, Default)]
struct SeamSums {
    all: PairSum,
    mixed: PairSum,
    axis: PairSum,
}

/// A seam pair lies along a grid axis of a texel when its direction is within this angle's
/// cosine (23°) of the texel's u or v step.
const AXIS_COS: f64 = 0.92;

/// Sums of |C_a - C_b|² over the seam pairs ([`SeamSums`]).
fn seam_pairs_sum(
    l: &crate::layout::TexelLayout,
    h: f64,
    pos: &(impl Fn(usize) -> [f64; 3] + Sync),
    col: &(impl Fn(usize) -> [f64; 3] + Sync),
) -> SeamSums {
    use kiddo::{ImmutableKdTree, SquaredEuclidean};
    // Border texels (each once) with finite positions.
    let mut border: Vec<usize> = Vec::new();
    for d in 0..l.faces() {
        let (nu, nv) = l.dims(d);
        for y in 0..nv {
            for x in 0..nu {
                if x == 0 || y == 0 || x + 1 == nu || y + 1 == nv {
                    let i = l.index(d, x, y);
                    if pos(i).iter().all(|c| c.is_finite()) {
                        border.push(i);
                    }
                }
            }
        }
    }
    if border.is_empty() {
        return SeamSums::default();
    }
    let points: Vec<[f64; 3]> = border.iter().map(|&i| pos(i)).collect();
    let tree: ImmutableKdTree<f64, 3> =
        ImmutableKdTree::new_from_slice(&points).expect("finite border points build a tree");
    let (lo2, hi2) = ((0.5 * h).powi(2), (1.25 * h).powi(2));
    let sub = |a: [f64; 3], b: [f64; 3]| [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
    let dot = |a: [f64; 3], b: [f64; 3]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    // The steps to the texel's neighbours along u and v inside its own face (toward the
    // inside at the face's far edges).
    let steps = |a: usize| -> [[f64; 3]; 2] {
        let (d, x, y) = l.coords(a);
        let (nu, nv) = l.dims(d);
        let step = |(x1, y1): (usize, usize), (x0, y0): (usize, usize)| {
            sub(pos(l.index(d, x1, y1)), pos(l.index(d, x0, y0)))
        };
        let u = match (x + 1 < nu, x > 0) {
            (true, _) => step((x + 1, y), (x, y)),
            (false, true) => step((x, y), (x - 1, y)),
            _ => [0.0; 3],
        };
        let v = match (y + 1 < nv, y > 0) {
            (true, _) => step((x, y + 1), (x, y)),
            (false, true) => step((x, y), (x, y - 1)),
            _ => [0.0; 3],
        };
        [u, v]
    };
    // Per border texel: pairs with later border texels only (each pair once); results
    // collected in order and summed sequentially for thread-count independence.
    let per: Vec<SeamSums> = (0..border.len())
        .into_par_iter()
        .map(|k| {
            let a = border[k];
            let ca = col(a);
            let mut sums = SeamSums::default();
            let hits = tree
                .query(&points[k])
                .within::<SquaredEuclidean<f64>>(hi2)
                .unsorted()
                .execute();
            let mut js: Vec<(u32, f64)> = hits.iter().map(|r| (r.item, r.distance)).collect();
            js.sort_by_key(|j| j.0);
            let mut axes = None;
            for (j, d2) in js {
                let j = j as usize;
                if j <= k || d2 < lo2 || d2 > hi2 {
                    continue;
                }
                let b = border[j];
                let (da, db) = (l.domain_of(a), l.domain_of(b));
                if da == db {
                    continue;
                }
                let cb = col(b);
                if ca.iter().chain(cb.iter()).all(|c| c.is_finite()) {
                    let e =
                        (ca[0] - cb[0]).powi(2) + (ca[1] - cb[1]).powi(2) + (ca[2] - cb[2]).powi(2);
                    sums.all.add(e);
                    if l.dims(da) != l.dims(db) {
                        sums.mixed.add(e);
                    }
                    let [u, v] = *axes.get_or_insert_with(|| steps(a));
                    let ab = sub(points[j], points[k]);
                    let along = |t: [f64; 3]| {
                        let n = (dot(t, t) * d2).sqrt();
                        n > 0.0 && dot(t, ab).abs() >= AXIS_COS * n
                    };
                    if along(u) || along(v) {
                        sums.axis.add(e);
                    }
                }
            }
            sums
        })
        .collect();
    per.iter().fold(SeamSums::default(), |t, p| SeamSums {
        all: t.all.merge(p.all),
        mixed: t.mixed.merge(p.mixed),
        axis: t.axis.merge(p.axis),
    })
}

/// Patch fidelity of a square 2D image (e.g. a [`crate::synth::synth2d`] result, the reference
/// issue 5 compares flat-grid results with), measured exactly as for face maps: the image
/// is one domain. Its first three channels are R, G, B.
pub fn image_patch_fidelity(image: &crate::pyramid::Image, ex: &Example) -> Option<f64> {
    if image.width != image.height || image.channels < 3 {
        return None;
    }
    let mut maps = FaceMaps::new(1, image.width, &["R", "G", "B"]);
    for c in 0..3 {
        for (i, v) in maps.channels[c].1.iter_mut().enumerate() {
            *v = image.data[i * image.channels + c];
        }
    }
    patch_fidelity(&maps, ex)
}

/// Patch fidelity (see [`Quality::patch_fidelity`]); `None` when the maps have no 7x7
/// window (N < 7) or the example is smaller than 7x7.
fn patch_fidelity(colour: &FaceMaps, ex: &Example) -> Option<f64> {
    let l = &*colour.layout;
    let (w, hgt) = (ex.width, ex.height);
    if w < PATCH || hgt < PATCH {
        return None;
    }
    let dims = PATCH * PATCH * 3;
    let r = colour.channel("R")?;
    let g = colour.channel("G")?;
    let b = colour.channel("B")?;
    // Output windows: every 7x7 window fully inside a domain, on a stride-7 grid, thinned
    // evenly to at most PATCH_SAMPLES.
    let all: Vec<(usize, usize, usize)> = (0..l.faces())
        .flat_map(|d| {
            let (nu, nv) = l.dims(d);
            let per = |n: usize| {
                if n < PATCH {
                    0
                } else {
                    (n - PATCH) / PATCH + 1
                }
            };
            let (pu, pv) = (per(nu), per(nv));
            (0..pv).flat_map(move |j| (0..pu).map(move |i| (d, i * PATCH, j * PATCH)))
        })
        .collect();
    let step = all.len().div_ceil(PATCH_SAMPLES).max(1);
    let outputs: Vec<Vec<f32>> = all
        .iter()
        .step_by(step)
        .map(|&(d, x0, y0)| {
            let mut v = Vec::with_capacity(dims);
            for y in y0..y0 + PATCH {
                for x in x0..x0 + PATCH {
                    let i = colour.index(d, x, y);
                    v.extend_from_slice(&[r[i], g[i], b[i]]);
                }
            }
            v
        })
        .filter(|v| v.iter().all(|c| c.is_finite()))
        .collect();
    if outputs.is_empty() {
        return None;
    }
    let ex_patch = |x0: usize, y0: usize, out: &mut Vec<f32>| {
        out.clear();
        for y in y0..y0 + PATCH {
            for x in x0..x0 + PATCH {
                out.extend_from_slice(&ex.rgb[y * w + x]);
            }
        }
    };
    // The nearest example window: pfS's exact search at S = 1 (the same windows: every
    // 7x7 window of the example; the same f32 row sums, so the same minimum).
    let bank = pf::Bank::build(&Rgb::from_example(ex), 1, 0, 0)?;
    let nearest: Vec<f64> = outputs
        .par_iter()
        .map(|o| (bank.nearest_sq(o).max(0.0) as f64).sqrt())
        .collect();
    let numerator = nearest.iter().sum::<f64>() / nearest.len() as f64;
    let (ew, eh) = (w - PATCH + 1, hgt - PATCH + 1);
    let mut state = 0x5EED_0F7A_7C4E_5A11_u64;
    let mut sum = 0.0;
    let (mut pa, mut pb) = (Vec::with_capacity(dims), Vec::with_capacity(dims));
    for _ in 0..PATCH_PAIRS {
        let a = (crate::random::splitmix(&mut state) % (ew * eh) as u64) as usize;
        let b = (crate::random::splitmix(&mut state) % (ew * eh) as u64) as usize;
        ex_patch(a % ew, a / ew, &mut pa);
        ex_patch(b % ew, b / ew, &mut pb);
        sum += pa
            .iter()
            .zip(&pb)
            .map(|(x, y)| ((x - y) as f64).powi(2))
            .sum::<f64>()
            .sqrt();
    }
    let denominator = sum / PATCH_PAIRS as f64;
    (denominator > 0.0).then(|| numerator / denominator)
}

/// pfS of a 2D image (`eval --image`): the JSON keys of [`Quality`] that apply to an image.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ImageQuality {
    pub width: usize,
    pub height: usize,
    pub pf1: Option<f64>,
    pub pf4: Option<f64>,
    pub pf8: Option<f64>,
    pub pf_detail: Option<PfDetail>,
    pub example: Option<String>,
}

/// Measures a 2D image (PNG/JPEG, sRGB-decoded like every example) against an example:
/// windows on its pixel grid, exactly as the lattice of a flat grid result.
pub fn evaluate_image(image: &Path, example: &Path) -> Result<ImageQuality> {
    let img = Example::load(image)?;
    let ex = Example::load(example)?;
    let pf = image_patch_fidelities(
        &Rgb::from_example(&img),
        &Rgb::from_example(&ex),
        &PfOptions::default(),
    );
    Ok(ImageQuality {
        width: img.width,
        height: img.height,
        pf1: pf.pf1,
        pf4: pf.pf4,
        pf8: pf.pf8,
        pf_detail: Some(pf.detail),
        example: Some(example.display().to_string()),
    })
}

/// `surfsynth eval`: evaluates `dir` and prints the measures as pretty JSON on stdout;
/// with `windows`, also writes every pf window's score there ([`windows_csv`]).
pub fn run_cli(
    dir: &Path,
    scale: Option<f64>,
    example: Option<PathBuf>,
    windows: Option<&Path>,
) -> anyhow::Result<()> {
    let (q, geometry) = evaluate_loaded(dir, &EvalOptions { scale, example })?;
    if let Some(path) = windows {
        write_windows(path, q.pf_detail.as_ref(), Some(&geometry), 0)?;
    }
    println!("{}", to_json(&q));
    Ok(())
}

/// `surfsynth eval --image OUT.png --example E.png`: prints [`ImageQuality`] as JSON;
/// with `windows`, also writes every pf window's score there ([`windows_csv`]).
pub fn run_image_cli(image: &Path, example: &Path, windows: Option<&Path>) -> anyhow::Result<()> {
    let q = evaluate_image(image, example)?;
    if let Some(path) = windows {
        write_windows(path, q.pf_detail.as_ref(), None, q.width)?;
    }
    println!(
        "{}",
        serde_json::to_string_pretty(&q).expect("ImageQuality serialises")
    );
    Ok(())
}

/// Writes [`windows_csv`] to `path` (a temporary name, then renamed); an error when no pf
/// was measured (no example), since an empty table would read as a result.
fn write_windows(
    path: &Path,
    detail: Option<&PfDetail>,
    geometry: Option<&FaceMaps>,
    width: usize,
) -> Result<()> {
    let detail = detail.filter(|d| !d.centres.is_empty()).ok_or_else(|| {
        Error::file(
            path,
            "no pf windows to write: pf1/pf4/pf8 were not measured (no example: pass --example E.png)",
        )
    })?;
    crate::io::atomic::write_bytes_atomic(path, windows_csv(detail, geometry, width).as_bytes())
}

/// The JSON text `eval` prints (pretty, stable key order; undefined values are `null`).
pub fn to_json(q: &Quality) -> String {
    serde_json::to_string_pretty(q).expect("Quality serialises")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn percentiles_interpolate_like_numpy() {
        let v = [1.0, 2.0, 3.0, 4.0];
        assert_eq!(percentile(&v, 0.5), 2.5);
        assert!((percentile(&v, 0.1) - 1.3).abs() < 1e-12);
        assert!((percentile(&v, 0.9) - 3.7).abs() < 1e-12);
        assert_eq!(percentile(&[5.0], 0.9), 5.0);
        assert!(percentile(&[], 0.5).is_nan());
    }
}
