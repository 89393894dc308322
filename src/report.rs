//! `report.json`: what was run, with which resolved parameters, and how long it took.
//!
//! BRIEF requires the top-level keys `method`, `seed`, `scale` (the resolved value),
//! `resolution`, `faces`, `texels`, `seconds` (per-stage times) and `texels_per_second`.
//! Everything needed to repeat the run is here too (inputs, orientation, weights, tuning),
//! because a result directory is often looked at long after the command line is gone.
//! `faces` is the number of face *domains* F (the EXR tiles), as in the `surfsynth.faces`
//! header attribute; `control_faces` is the OBJ's face count.

use crate::error::{Error, Result};
use crate::io::atomic::write_bytes_atomic;
use crate::synth::matching::appearance::AppearanceInfo;
use crate::synth::{Details, Method, Weights};
use serde::Serialize;
use std::path::Path;

pub use crate::io::names::REPORT_FILE;

/// Input files.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Inputs {
    pub mesh: String,
    pub example: String,
    pub height: Option<String>,
    /// `--btf`: the sample's btf.json, absolute (what `render --light` shades with; the
    /// example is then its default image).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub btf: Option<String>,
    /// Every map of the material (`--map`, `--height` included), in the order given.
    pub maps: Vec<MapInfo>,
    /// `--normal-convention`, when there is a normal map.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub normal_convention: Option<crate::conventions::NormalConvention>,
}

/// One map of a material as it was read and matched.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct MapInfo {
    pub name: String,
    pub file: String,
    /// `colour` (sRGB-decoded) or `data` (as stored).
    pub kind: crate::conventions::MapKind,
    /// 1 (`NAME.Y`) or 3 (`NAME.R NAME.G NAME.B`).
    pub channels: usize,
    /// Matching weight per channel (0: copied, not matched).
    pub weight: f32,
}

/// The example's size and channels.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ExampleInfo {
    pub width: usize,
    pub height: usize,
    pub channels: Vec<String>,
}

/// Wall-clock seconds per stage. `total` covers everything up to writing this report,
/// the pf summary included (the wall a user of `synth` waits, but for starting and ending
/// the process). The orientation field is computed beside the texel geometry and the
/// graphs (but for `straight`), and the pf summary beside writing, so `field` overlaps
/// `geometry` and `graph`, `pf` overlaps `write`, and the stages can add up to more than
/// `total`.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct Seconds {
    /// Reading and validating the mesh and example, building the limit surface.
    pub load: f64,
    /// Limit positions and normals of all texels.
    pub geometry: f64,
    /// Orientation field and per-texel frames.
    pub field: f64,
    /// Neighbourhood graph, default scale and schedule.
    pub graph: f64,
    /// The synthesis pass alone.
    pub synthesis: f64,
    /// Looking up output channels at the source positions.
    pub maps: f64,
    /// Writing facemaps.exr, geometry.exr and any other outputs.
    pub write: f64,
    /// `synth`'s pf summary (`patch_fidelity`), measured beside writing (so it overlaps
    /// `write`); 0 when not measured.
    pub pf: f64,
    pub total: f64,
}

/// The whole report.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Report {
    pub tool: String,
    pub version: String,
    pub inputs: Inputs,
    pub method: Method,
    pub seed: u64,
    /// Surface length per example pixel, resolved.
    pub scale: f64,
    /// "median texel spacing" (the default) or "given".
    pub scale_source: String,
    /// `--scale-map`: the file, its constraints and the range of factors (absent without).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub scale_map: Option<crate::scale_field::ScaleMapInfo>,
    /// h: median distance between adjacent texel centres (BRIEF), for reference.
    pub texel_spacing: f64,
    pub resolution: usize,
    /// `--texel-size` (then `resolution` is the largest face side and the faces' own
    /// resolutions are in facemaps.exr's header).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub texel_size: Option<f64>,
    pub orientation: String,
    /// What `--orient straight` or `upright` chose, and why (absent otherwise).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub orientation_choice: Option<OrientationChoice>,
    /// Face domains F.
    pub faces: usize,
    /// Faces of the control mesh.
    pub control_faces: usize,
    pub texels: u64,
    pub example: ExampleInfo,
    /// Channels of facemaps.exr.
    pub channels: Vec<String>,
    pub weights: Weights,
    /// What the matchers compared (appearance space or raw channels).
    pub appearance: AppearanceInfo,
    /// The method's parameters and counters, under a key named after the method
    /// (`"coherent"`, `"multiscale"`, `"patches"`).
    #[serde(flatten)]
    pub details: Details,
    pub threads: usize,
    /// `--displace` amount (displaced.obj written), when given.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub displace: Option<f64>,
    /// Image rows along +v2 (`tiles`) or −v2 (`outside`), see
    /// [`crate::conventions::Handedness`].
    pub handedness: crate::conventions::Handedness,
    pub seconds: Seconds,
    /// Texels per second of the whole run (`texels / seconds.total`).
    pub texels_per_second: f64,
    /// Texels per second of the synthesis stage alone.
    pub synthesis_texels_per_second: f64,
    /// Peak resident memory of the process (bytes), where the OS tells it.
    pub peak_memory_bytes: Option<u64>,
    /// The memory guard's estimate of the run's peak (bytes; [`crate::memory`]), recorded
    /// so that it can be compared with `peak_memory_bytes`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub memory_estimate_bytes: Option<u64>,
    /// pf1/pf4/pf8 of the result (`surfsynth synth` measures them while writing;
    /// [`crate::eval::summary_fidelity`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub patch_fidelity: Option<crate::eval::PfSummary>,
    /// Per-example analysis of the run: where each came from (memory, the disk cache, or
    /// computed), and whether the cache was hit ([`crate::synth::analysis`]).
    pub cache: crate::synth::analysis::CacheReport,
}

/// What a chosen orientation decided ([`crate::field::Choice`]): `straight`'s pick among
/// candidate fields, or `upright`'s between `up` and the smooth field.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct OrientationChoice {
    /// `auto` (the smooth field), `+x`, `+y`, `+z` or `up`.
    pub chosen: String,
    /// `straight`: surface length (user units) over which straightness was scored.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub structure_length: Option<f64>,
    /// `straight`: per candidate, the fraction of the surface where the frame turns by
    /// more than 0.1 rad over the structure length (lower is straighter), in candidate
    /// order.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub bent_fraction: Vec<(String, f64)>,
    /// `upright`: the share of the surface's area whose normal is within 30° of the axis
    /// (`up` above half of it would draw contour rings; the smooth field is chosen).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub level_fraction: Option<f64>,
}

impl Report {
    /// The coherent method's counters (`None` for other methods).
    pub fn coherent_stats(&self) -> Option<&crate::synth::coherent::Stats> {
        match &self.details {
            Details::Coherent { stats, .. } => Some(stats),
            _ => None,
        }
    }

    /// Pretty JSON with a trailing newline.
    pub fn to_json(&self) -> String {
        let mut s = serde_json::to_string_pretty(self).expect("report serializes");
        s.push('\n');
        s
    }

    /// Writes `DIR/report.json` atomically.
    pub fn write(&self, dir: &Path) -> Result<()> {
        write_bytes_atomic(dir.join(REPORT_FILE), self.to_json().as_bytes())
    }

    /// Fills `texels_per_second` and `synthesis_texels_per_second` from the times.
    pub fn update_rates(&mut self) {
        let rate = |s: f64| if s > 0.0 { self.texels as f64 / s } else { 0.0 };
        self.texels_per_second = rate(self.seconds.total);
        self.synthesis_texels_per_second = rate(self.seconds.synthesis);
    }
}

/// Peak resident set size of this process (Linux `VmHWM`), `None` elsewhere.
pub fn peak_memory_bytes() -> Option<u64> {
    crate::process::peak_rss_bytes()
}

/// Reads back a report's top-level JSON (for tools and tests).
pub fn read(dir: &Path) -> Result<serde_json::Value> {
    let p = dir.join(REPORT_FILE);
    let text = std::fs::read_to_string(&p).map_err(|e| Error::io(&p, "cannot read", e))?;
    serde_json::from_str(&text).map_err(|e| Error::file(&p, format!("invalid JSON: {e}")))
}
