//! The library's front door: a builder that loads the inputs, synthesizes, and writes the
//! output directory of BRIEF ("Output directory of `synth`").
//!
//! ```no_run
//! use surfsynth::synthesizer::{Method, Synthesizer};
//!
//! # fn main() -> surfsynth::Result<()> {
//! let result = Synthesizer::new("spot_control_mesh.obj", "gravel.png")
//!     .method(Method::Optimise)
//!     .resolution(32)
//!     .seed(7)
//!     .run()?;
//! println!("{} texels at scale {}", result.report.texels, result.report.scale);
//! result.write("out/spot")?; // facemaps.exr/.ptx, geometry.exr, surface.*, report.json
//! # Ok(())
//! # }
//! ```
//!
//! In-memory inputs work too (no files needed), which is what the doctest below runs:
//!
//! ```
//! use surfsynth::example::Example;
//! use surfsynth::synthesizer::Synthesizer;
//! use subdiv::{ControlMesh, Surface};
//! use glam::DVec3;
//!
//! # fn main() -> surfsynth::Result<()> {
//! // A unit cube and a 16x16 checkerboard example.
//! let p: Vec<DVec3> = (0..8)
//!     .map(|i| DVec3::new((i & 1) as f64, ((i >> 1) & 1) as f64, (i >> 2) as f64))
//!     .collect();
//! let faces: [&[u32]; 6] =
//!     [&[0, 2, 3, 1], &[4, 5, 7, 6], &[0, 1, 5, 4], &[2, 6, 7, 3], &[0, 4, 6, 2], &[1, 3, 7, 5]];
//! let surface = Surface::new(ControlMesh::from_faces(p, &faces).unwrap());
//! let rgb = (0..256).map(|i| if (i % 16 / 4 + i / 64) % 2 == 0 { [1.0; 3] } else { [0.0; 3] });
//! let example = Example::from_linear(16, 16, rgb.collect());
//!
//! let r = Synthesizer::new(surface, example).resolution(8).seed(3).run()?;
//! assert_eq!(r.report.faces, 6);
//! assert_eq!(r.maps.channel("source.u").unwrap().len(), 6 * 8 * 8);
//! # Ok(())
//! # }
//! ```
//!
//! For many syntheses on one mesh (an interactive tool, a seed sweep), [`Session`] keeps
//! the mesh-side stages (surface, texel geometry, field, graphs) and the per-example
//! analysis between them; the builder above is a session used once (module
//! [`session`]).
//!
//! Errors are [`crate::Error`]s with one-line messages that name the file and the problem
//! (a missing or corrupt example, a height map of another size, resolution 0, ...). Nothing
//! is written until [`SynthResult::write`], which writes every file atomically and removes
//! what it wrote if a later file fails, so a failed run leaves no partial output.

use crate::error::{Error, Result};
use crate::example::{Example, PendingImage};
use crate::field::Orientation;
use crate::io::exr::{FaceMaps, TileThreads};
use crate::io::txn::OutputTxn;
use crate::report::Report;
use crate::texels::TexelGeometry;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;
use subdiv::Surface;

pub mod session;
pub use session::{MeshSettings, PrepareSeconds, Session, SynthParams};

pub use crate::cache::CacheDir;
pub use crate::synth::matching::appearance::AppearanceMode;
pub use crate::synth::{
    Analyses, CoherentParams, JumpParams, Method, MultiscaleParams, OptimiseParams, PatchParams,
    Settings, Vote, Weights,
};

pub use crate::conventions::{Handedness, NormalConvention};

/// geometry.exr channels of the field's unit direction v1, written by `synth` after P and
/// N (`bake` has no field).
pub const TANGENT_CHANNELS: [&str; 3] = ["T.X", "T.Y", "T.Z"];
/// geometry.exr header attribute: [`Handedness::bitangent_sign`].
pub const TANGENT_HANDEDNESS: &str = "tangentHandedness";
/// geometry.exr channel of a `--scale-map` run: the requested local scale at each texel
/// (surface length per example pixel, the global scale × the map's factor, user units).
pub const LOCAL_SCALE_CHANNEL: &str = crate::scale_field::CHANNEL;

/// Neighbourhood search of the multiscale method (`--search`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Search {
    /// PCA-projected kd-tree, re-ranked by the exact distance (000 §4 with ANN).
    Ann,
    /// k-coherence candidate sets (003 §5.2): the default, faster at equal quality
    /// (docs/multiscale.md has the comparison).
    KCoherence,
}

impl Search {
    /// This search with the default parameters of its kind.
    pub fn method(self) -> crate::synth::matching::search::model::Method {
        use crate::synth::matching::search::model::Method as M;
        match self {
            Search::Ann => M::Ann(Default::default()),
            Search::KCoherence => M::KCoherence(Default::default()),
        }
    }
}

/// Output file names.
pub use crate::io::names::{FACEMAPS_FILE, GEOMETRY_FILE};

/// Where the mesh comes from.
#[derive(Clone, Debug)]
pub enum MeshSource {
    Path(PathBuf),
    Surface(Box<Surface>),
}

impl From<&str> for MeshSource {
    fn from(p: &str) -> Self {
        MeshSource::Path(p.into())
    }
}
impl From<&Path> for MeshSource {
    fn from(p: &Path) -> Self {
        MeshSource::Path(p.into())
    }
}
impl From<PathBuf> for MeshSource {
    fn from(p: PathBuf) -> Self {
        MeshSource::Path(p)
    }
}
impl From<&PathBuf> for MeshSource {
    fn from(p: &PathBuf) -> Self {
        MeshSource::Path(p.clone())
    }
}
impl From<String> for MeshSource {
    fn from(p: String) -> Self {
        MeshSource::Path(p.into())
    }
}
impl From<Surface> for MeshSource {
    fn from(s: Surface) -> Self {
        MeshSource::Surface(Box::new(s))
    }
}

/// Where the example comes from.
#[derive(Clone, Debug)]
pub enum ExampleSource {
    Path(PathBuf),
    Example(Box<Example>),
    /// A BTF sample's btf.json ([`crate::btf`]): the example is its default image, and
    /// every method but multiscale matches all its images at once ([`Method::Textons`]
    /// over textons, the others in appearance space: `synth::matching::reflectance`).
    Btf(PathBuf),
}

impl From<&str> for ExampleSource {
    fn from(p: &str) -> Self {
        ExampleSource::Path(p.into())
    }
}
impl From<&Path> for ExampleSource {
    fn from(p: &Path) -> Self {
        ExampleSource::Path(p.into())
    }
}
impl From<PathBuf> for ExampleSource {
    fn from(p: PathBuf) -> Self {
        ExampleSource::Path(p)
    }
}
impl From<&PathBuf> for ExampleSource {
    fn from(p: &PathBuf) -> Self {
        ExampleSource::Path(p.clone())
    }
}
impl From<String> for ExampleSource {
    fn from(p: String) -> Self {
        ExampleSource::Path(p.into())
    }
}
impl From<Example> for ExampleSource {
    fn from(e: Example) -> Self {
        ExampleSource::Example(Box::new(e))
    }
}

/// Pipeline stages, for progress reporting.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Stage {
    Load,
    Geometry,
    Field,
    Graph,
    /// An analysis of the example being built (not found in memory or the cache):
    /// progress in the analysis's own unit (e.g. example pixels).
    Analysis,
    /// Progress counts domains.
    Synthesis,
    Maps,
    Write,
}

impl Stage {
    /// Short label for progress bars.
    pub fn label(self) -> &'static str {
        match self {
            Stage::Load => "load",
            Stage::Geometry => "geometry",
            Stage::Field => "field",
            Stage::Graph => "graph",
            Stage::Analysis => "analysis",
            Stage::Synthesis => "synthesis",
            Stage::Maps => "maps",
            Stage::Write => "write",
        }
    }
}

/// Progress callback: (stage, done, total). Called with done = 0 when a stage starts and
/// done = total when it ends; the synthesis stage also reports every wave.
pub type Progress = dyn Fn(Stage, usize, usize) + Send + Sync;

/// Where a scale map comes from ([`Synthesizer::scale_map`]).
#[derive(Clone, Debug)]
enum ScaleMapInput {
    Path(PathBuf),
    Map(crate::scale_field::ScaleMap),
    /// The lengths of the orientation constraints file's `vertex` directions
    /// ([`Synthesizer::scale_from_orientation`]).
    FromOrientation,
}

/// Builder for one synthesis run (see the module docs).
pub struct Synthesizer {
    mesh: MeshSource,
    example: ExampleSource,
    /// `--map NAME=FILE` (and `--height`, the map `height`), in the order given.
    maps: Vec<(String, PathBuf)>,
    normal_convention: NormalConvention,
    settings: Settings,
    resolution: usize,
    texel_size: Option<f64>,
    scale: Option<f64>,
    /// `--scale-map`: a file, read in the load stage, or constraints given in memory.
    scale_map: Option<ScaleMapInput>,
    /// `None`: the method's own ([`Method::default_orientation`]).
    orientation: Option<Orientation>,
    seed: u64,
    threads: Option<usize>,
    displace: Option<f64>,
    handedness: Handedness,
    write_options: WriteOptions,
    progress: Option<std::sync::Arc<Progress>>,
    cache: CacheDir,
    analyses: Option<std::sync::Arc<Analyses>>,
}

impl std::fmt::Debug for Synthesizer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Synthesizer")
            .field("mesh", &self.mesh_label())
            .field("example", &self.example_label())
            .field("method", &self.settings.method)
            .field("resolution", &self.resolution)
            .field("scale", &self.scale)
            .field("seed", &self.seed)
            .finish_non_exhaustive()
    }
}

/// Everything a run produced, in memory.
#[derive(Debug)]
pub struct SynthResult {
    /// facemaps.exr content: R G B \[A\] \[height\] source.u source.v.
    pub maps: FaceMaps,
    /// Limit position and normal per texel (geometry.exr content); shared with the
    /// [`Session`] that produced it.
    pub geometry: Arc<TexelGeometry>,
    /// The orientation field's unit v1 per texel (geometry.exr `T.X T.Y T.Z`): with the
    /// normal N, the frame (T, N x T, N) that facemaps.exr's `normal.*` is expressed in.
    pub tangents: Vec<[f32; 3]>,
    /// With a scale map, the requested local scale per texel (geometry.exr `scale`:
    /// surface length per example pixel, user units) — what `eval`'s scale fidelity
    /// divides by. `None` without one (geometry.exr then has no `scale` channel).
    pub local_scale: Option<Vec<f32>>,
    /// Which way the example's rows run (geometry.exr `tangentHandedness`).
    pub handedness: Handedness,
    /// The surface (for exporters that need topology, e.g. the atlas); shared with the
    /// [`Session`].
    pub surface: Arc<Surface>,
    /// The example as loaded (linear).
    pub example: Example,
    /// report.json content; `seconds.write`, `seconds.total` and the rates are completed
    /// by [`SynthResult::write`].
    pub report: Report,
    /// `--displace` amount: [`SynthResult::write`] also writes displaced.glb.
    displace: Option<f64>,
    /// How [`SynthResult::write`] writes the renderer outputs (from
    /// [`Synthesizer::write_options`]; may be changed before writing).
    pub write_options: WriteOptions,
    /// Time the run started (for the total).
    started: Instant,
}

impl Synthesizer {
    /// A run on `mesh` (an OBJ path or a [`Surface`]) with `example` (a PNG/JPEG path or an
    /// [`Example`]). Defaults: [`Method::DEFAULT`], resolution 32, scale = median texel spacing,
    /// the method's orientation ([`Method::default_orientation`]: `upright` for optimise),
    /// seed 1, all threads of the current rayon pool.
    pub fn new(mesh: impl Into<MeshSource>, example: impl Into<ExampleSource>) -> Self {
        Self {
            mesh: mesh.into(),
            example: example.into(),
            maps: Vec::new(),
            normal_convention: NormalConvention::default(),
            settings: Settings::default(),
            resolution: 32,
            texel_size: None,
            scale: None,
            scale_map: None,
            orientation: None,
            seed: 1,
            threads: None,
            displace: None,
            handedness: Handedness::default(),
            write_options: WriteOptions::default(),
            progress: None,
            cache: CacheDir::Default,
            analyses: None,
        }
    }

    /// A height example of the same size, synthesized jointly (`--height`: the map
    /// `height`).
    pub fn height(self, path: impl Into<PathBuf>) -> Self {
        self.map(crate::example::HEIGHT, path)
    }
    /// A further map of the material (`--map NAME=FILE`), the example's size, copied from
    /// the same source positions; matched only with a weight ([`Weights::maps`]).
    pub fn map(mut self, name: &str, path: impl Into<PathBuf>) -> Self {
        self.maps.push((name.to_string(), path.into()));
        self
    }
    /// How the green channel of the `normal` map is to be read (`--normal-convention`).
    pub fn normal_convention(mut self, c: NormalConvention) -> Self {
        self.normal_convention = c;
        self
    }
    /// Synthesis method (default [`Method::DEFAULT`], texture optimisation; see
    /// docs/synthesis.md for what each is for).
    pub fn method(mut self, m: Method) -> Self {
        self.settings.method = m;
        self
    }
    /// Texels per side of every face map (>= 1).
    pub fn resolution(mut self, n: usize) -> Self {
        self.resolution = n;
        self
    }
    /// Per-face resolutions for a texel spacing of about `l` surface units
    /// (`--texel-size`, [`crate::layout::TexelLayout::for_texel_size`]) instead of one
    /// [`Synthesizer::resolution`] for all faces; `None` = the resolution.
    pub fn texel_size(mut self, l: impl Into<Option<f64>>) -> Self {
        self.texel_size = l.into();
        self
    }
    /// Surface length covered by one example pixel; `None` = median texel spacing.
    pub fn scale(mut self, s: impl Into<Option<f64>>) -> Self {
        self.scale = s.into();
        self
    }
    /// Spatially varying scale (`--scale-map FILE`, docs/formats.md): factors at control
    /// vertices or surface points, interpolated smoothly over the surface
    /// ([`crate::scale_field`]), multiply the scale locally. Read in the load stage;
    /// errors name the file and line.
    pub fn scale_map(mut self, path: impl Into<PathBuf>) -> Self {
        self.scale_map = Some(ScaleMapInput::Path(path.into()));
        self
    }
    /// [`Synthesizer::scale_map`] with constraints made in memory
    /// ([`crate::scale_field::ScaleMap::parse`] or built directly).
    pub fn scale_map_constraints(mut self, map: crate::scale_field::ScaleMap) -> Self {
        self.scale_map = Some(ScaleMapInput::Map(map));
        self
    }
    /// Spatially varying scale from the orientation constraints file (`--orient FILE
    /// --scale-from-orient`): each `vertex I DX DY DZ` line's length |d| is vertex I's scale
    /// factor, exactly as the scale-map line `vertex I |d|` would be
    /// ([`crate::scale_field::ScaleMap::from_orientation`]); replaces any scale map. The
    /// orientation must be a constraints file ([`Orientation::Constraints`]); errors name
    /// the file and line, before `--out` is opened.
    pub fn scale_from_orientation(mut self) -> Self {
        self.scale_map = Some(ScaleMapInput::FromOrientation);
        self
    }
    /// Orientation field (`--orient`); `None` gives the method's own
    /// ([`Method::default_orientation`]).
    pub fn orientation(mut self, o: impl Into<Option<Orientation>>) -> Self {
        self.orientation = o.into();
        self
    }

    /// The orientation this run uses: the one given, else the method's.
    fn resolved_orientation(&self) -> Orientation {
        self.orientation
            .clone()
            .unwrap_or_else(|| self.settings.method.default_orientation())
    }
    /// Random seed; the same seed gives bit-identical maps for any thread count.
    pub fn seed(mut self, seed: u64) -> Self {
        self.seed = seed;
        self
    }
    /// Worker threads for this run (a private pool); `None` = the current rayon pool.
    pub fn threads(mut self, t: impl Into<Option<usize>>) -> Self {
        self.threads = t.into();
        self
    }
    /// Matching weights of colour, alpha, height and the other maps ([`Weights::maps`]:
    /// maps not named there are copied, not matched).
    pub fn weights(mut self, w: Weights) -> Self {
        self.settings.weights = w;
        self
    }
    /// Tuning of the coherent method.
    pub fn coherent_params(mut self, p: CoherentParams) -> Self {
        self.settings.coherent = p;
        self
    }
    /// Tuning of the multiscale method (neighbourhood sizes, search, levels).
    pub fn multiscale_params(mut self, p: MultiscaleParams) -> Self {
        self.settings.multiscale = p;
        self
    }
    /// Tuning of patch sampling.
    pub fn patch_params(mut self, p: PatchParams) -> Self {
        self.settings.patches = p;
        self
    }
    /// Tuning of texture optimisation.
    pub fn optimise_params(mut self, p: OptimiseParams) -> Self {
        self.settings.optimise = p;
        self
    }
    /// Tuning of jump-map synthesis.
    pub fn jump_params(mut self, p: JumpParams) -> Self {
        self.settings.jump = p;
        self
    }
    /// Where per-example analysis is saved (`--cache DIR`, `--no-cache`; default: the
    /// platform's user cache folder, [`crate::cache`]).
    pub fn cache(mut self, c: CacheDir) -> Self {
        self.cache = c;
        self
    }
    /// Shares one store of per-example analysis between runs of this process (its own
    /// cache folder then applies instead of [`Synthesizer::cache`]).
    pub fn analyses(mut self, a: std::sync::Arc<Analyses>) -> Self {
        self.analyses = Some(a);
        self
    }
    /// The synthesis settings as configured so far.
    pub fn current_settings(&self) -> &Settings {
        &self.settings
    }
    /// What matchers compare (`--appearance`): appearance space (default) or raw channels.
    pub fn appearance(mut self, a: AppearanceMode) -> Self {
        self.settings.appearance = a;
        self
    }
    /// Weight of the feature-distance channel (`--feature-distance`, 0: none): the signed
    /// distance to the example's bright/dark borders matched beside its colours, which
    /// keeps thin features such as mortar joints (see
    /// [`crate::synth::matching::feature_distance`]).
    pub fn feature_distance(mut self, weight: f32) -> Self {
        self.settings.feature_distance = weight;
        self
    }
    /// All synthesis settings at once.
    pub fn settings(mut self, s: Settings) -> Self {
        self.settings = s;
        self
    }
    /// Neighbourhood search of the multiscale method (`--search`), default parameters.
    pub fn search(mut self, s: Search) -> Self {
        self.settings.multiscale.model.method = s.method();
        self
    }
    /// The side of multiscale's (and textons') own-level neighbourhood block
    /// (`--neighbourhood K`, odd), with the coarser level's block reaching as far
    /// ([`crate::synth::matching::search::model::ModelParams::with_side`]).
    pub fn neighbourhood(mut self, k: usize) -> Self {
        let m = &mut self.settings.multiscale.model;
        *m = m.with_side(k);
        self
    }
    /// Multiscale's pass 2 compares its own block at the samples of the sparse block only
    /// (`--neighbourhood-samples sparse`: 41 of the 9x9 block's 81, the same reach;
    /// [`crate::synth::multiscale::sparse_gains`]) or at all of them (`full`).
    pub fn sparse_neighbourhood(mut self, sparse: bool) -> Self {
        self.settings.multiscale.sparse = sparse;
        self
    }
    /// Multiscale's finest level starts from its texels' continuations of the coarser level
    /// (`--finest-start continued`) rather than from pass 1's matches (`matched`)
    /// ([`crate::synth::multiscale::MultiscaleParams::continue_finest`]).
    pub fn continue_finest(mut self, on: bool) -> Self {
        self.settings.multiscale.continue_finest = on;
        self
    }
    /// k-coherence's k for multiscale and textons (`--kcoherence-k K`): how many entries of
    /// each proposing neighbour's list become candidates. No effect with another search.
    pub fn kcoherence_k(mut self, k: usize) -> Self {
        use crate::synth::matching::search::model::Method as M;
        if let M::KCoherence(p) = &mut self.settings.multiscale.model.method {
            p.k = k;
        }
        self
    }
    /// Shape synthesis (`--displace AMOUNT`, 000 §6): [`SynthResult::write`] also writes
    /// `displaced.glb`, the limit surface tessellated at texel resolution and moved along
    /// the limit normal by `amount · (height − 0.5)`. Needs a height channel.
    pub fn displace(mut self, amount: impl Into<Option<f64>>) -> Self {
        self.displace = amount.into();
        self
    }
    /// `--decimate TOL`: displaced.glb decimated where the displaced surface is flat
    /// within TOL mesh units (see [`WriteOptions::decimate`]).
    pub fn decimate(mut self, tol: impl Into<Option<f64>>) -> Self {
        self.write_options.decimate = tol.into();
        self
    }
    /// How [`SynthResult::write`] writes the renderer outputs.
    pub fn write_options(mut self, o: WriteOptions) -> Self {
        self.write_options = o;
        self
    }
    /// Which way round the example is laid on the surface (see [`Handedness`]).
    pub fn handedness(mut self, h: Handedness) -> Self {
        self.handedness = h;
        self
    }
    /// Progress callback (see [`Progress`]).
    pub fn on_progress(mut self, f: impl Fn(Stage, usize, usize) + Send + Sync + 'static) -> Self {
        self.progress = Some(std::sync::Arc::new(f));
        self
    }

    fn mesh_label(&self) -> String {
        mesh_source_label(&self.mesh)
    }

    fn example_label(&self) -> String {
        match &self.example {
            ExampleSource::Path(p) => p.display().to_string(),
            ExampleSource::Example(e) if !e.path.as_os_str().is_empty() => {
                e.path.display().to_string()
            }
            ExampleSource::Example(_) => "<in memory>".into(),
            ExampleSource::Btf(p) => p.display().to_string(),
        }
    }

    /// Checks parameters that need no file (cheap; `run` calls it first).
    pub fn validate(&self) -> Result<()> {
        MeshSettings {
            resolution: self.resolution,
            texel_size: self.texel_size,
            scale: self.scale,
            orientation: Orientation::Auto,
            scale_map: None,
        }
        .validate()?;
        if self.threads == Some(0) {
            return Err(Error::invalid("threads must be at least 1"));
        }
        if let Some(t) = self.write_options.decimate {
            if !(t.is_finite() && t >= 0.0) {
                return Err(Error::invalid(format!(
                    "decimation tolerance {t} is not a non-negative length"
                )));
            }
            if self.displace.is_none() {
                return Err(Error::invalid(
                    "--decimate applies to the displaced mesh: pass --displace AMOUNT",
                ));
            }
        }
        if let Some(a) = self.displace {
            if !a.is_finite() {
                return Err(Error::invalid(format!(
                    "displacement amount {a} is not a finite number"
                )));
            }
        }
        Ok(())
    }

    /// Loads, synthesizes and returns the result in memory.
    pub fn run(self) -> Result<SynthResult> {
        self.run_in_pool(None, |result, _| Ok(result))
    }

    /// Loads the inputs, checks `dir` and opens it as a transaction ([`OutputTxn`]) — only
    /// once the inputs are known to be good, so bad inputs leave nothing behind, and before
    /// the expensive part, so a bad `--out` fails in a moment — then synthesizes and writes
    /// everything into the transaction's staging folder ([`SynthResult::write`]) and moves
    /// it into place. Returns the result and the final report.
    pub fn run_to(self, dir: impl AsRef<Path>) -> Result<(SynthResult, Report)> {
        self.run_to_with(dir, |_| |_: &mut Report| {})
    }

    /// [`Synthesizer::run_to`] with `measure` run on the result while its files are
    /// written (e.g. a quality measure for its report: `synth`'s pf summary); what it
    /// returns edits the report before report.json is written, once, with the rest, and
    /// everything lands in `dir` together. Its time is part of the run's: the run is not
    /// done before it is (`seconds.total`; its own wall in `seconds.pf`). It runs only
    /// once the result's maps and texel geometry are checked finite (issue 18: nothing is
    /// written otherwise).
    pub fn run_to_with<E: FnOnce(&mut Report) + Send>(
        self,
        dir: impl AsRef<Path>,
        measure: impl FnOnce(&SynthResult) -> E + Send,
    ) -> Result<(SynthResult, Report)> {
        let dir = dir.as_ref();
        let progress = self.progress.clone();
        // The writing runs in the run's pool too, so that `threads(Some(t))` bounds the
        // whole run, its end included.
        self.run_in_pool(Some(dir), move |result, txn| {
            let txn = txn.expect("run_in_pool opens the transaction when given a directory");
            if let Some(p) = &progress {
                p(Stage::Write, 0, 1);
            }
            let report = result.write_measured_into(&txn, || measure(&result))?;
            txn.commit()?;
            if let Some(p) = &progress {
                p(Stage::Write, 1, 1);
            }
            Ok((result, report))
        })
    }

    /// Runs the synthesis and then `then` on its result, both in the run's pool: a pool of
    /// `threads` workers when set, else the caller's.
    fn run_in_pool<R: Send>(
        self,
        out: Option<&Path>,
        then: impl FnOnce(SynthResult, Option<OutputTxn>) -> Result<R> + Send,
    ) -> Result<R> {
        self.validate()?;
        let threads = self.threads;
        let go = move || {
            let (result, txn) = self.run_here(out)?;
            then(result, txn)
        };
        match threads {
            None => go(),
            Some(t) => {
                let pool = rayon::ThreadPoolBuilder::new()
                    .num_threads(t)
                    .build()
                    .map_err(|e| Error::invalid(format!("cannot start {t} worker threads: {e}")))?;
                pool.install(go)
            }
        }
    }

    fn run_here(self, out_dir: Option<&Path>) -> Result<(SynthResult, Option<OutputTxn>)> {
        let started = Instant::now();
        let progress = |s: Stage, d: usize, t: usize| {
            if let Some(p) = &self.progress {
                p(s, d, t)
            }
        };
        let mesh_label = self.mesh_label();
        let example_label = self.example_label();
        let orientation = self.resolved_orientation();
        let n = self.resolution;

        // Load: example first (cheap, most likely to be wrong), then the mesh.
        progress(Stage::Load, 0, 1);
        let t0 = Instant::now();
        // Image headers first: sizes and memory are checked before a pixel is decoded (an
        // image bomb is refused here, naming the image).
        let btf = match &self.example {
            ExampleSource::Btf(p) => {
                if let Some((_, m)) = self.maps.first() {
                    return Err(Error::file(
                        m,
                        format!(
                            "a height or map file cannot be combined with the BTF sample {}",
                            p.display()
                        ),
                    ));
                }
                Some(std::sync::Arc::new(crate::btf::BtfSample::load(p)?))
            }
            _ => None,
        };
        let pending = match self.example {
            ExampleSource::Btf(_) => None,
            ExampleSource::Path(ref p) => {
                let ex = PendingImage::open(p)?;
                let mut maps = Vec::with_capacity(self.maps.len());
                for (name, file) in &self.maps {
                    maps.push((name.clone(), PendingImage::open(file)?));
                }
                Some((ex, maps))
            }
            ExampleSource::Example(_) => {
                if let Some((_, m)) = self.maps.first() {
                    return Err(Error::file(
                        m,
                        "a map file cannot be combined with an in-memory example; add it with Example::with_map instead",
                    ));
                }
                None
            }
        };
        let (ex_channels, map_channels, ex_pixels, has_height) = match (&pending, &self.example) {
            (Some((ex, maps)), _) => {
                let i = ex.info();
                let alpha = (i.channels == 2 || i.channels == 4) as usize;
                // As Example::from_pending decodes them: height and grayscale data maps
                // one channel, the rest three.
                let mc: usize = maps
                    .iter()
                    .map(|(name, m)| {
                        let gray = m.info().channels <= 2;
                        if name == crate::example::HEIGHT
                            || (gray
                                && crate::conventions::MapKind::for_name(name)
                                    == crate::conventions::MapKind::Data)
                        {
                            1
                        } else {
                            3
                        }
                    })
                    .sum();
                let height = maps.iter().any(|(n, _)| n == crate::example::HEIGHT);
                (3 + alpha + mc + height as usize, mc, i.pixels(), height)
            }
            (None, ExampleSource::Example(e)) => {
                let mc: usize = e.maps.iter().map(|m| m.channels).sum();
                let height = e.height_map().is_some();
                (
                    e.num_channels() + height as usize,
                    mc,
                    (e.width * e.height) as u64,
                    height,
                )
            }
            (None, ExampleSource::Btf(_)) => {
                let b = btf.as_ref().expect("a BTF source is loaded above");
                (3, 0, (b.width * b.height * b.images.len()) as u64, false)
            }
            (None, ExampleSource::Path(_)) => unreachable!("a path example has a header"),
        };
        if self.displace.is_some() && !has_height {
            return Err(Error::invalid(format!(
                "--displace needs a height channel, and {example_label} has none: pass --height H.png"
            )));
        }
        // Memory guard (crate::memory): refuse before the surface and the maps are built.
        let job = crate::memory::Job::Synth {
            channels: ex_channels + 2,
            example_pixels: ex_pixels.min(usize::MAX as u64) as usize,
            method: self.settings.method,
            displace: self.displace.is_some(),
            scale_map: self.scale_map.is_some(),
        };
        if let Some((ex, maps)) = &pending {
            for (name, m) in maps {
                crate::example::check_same_size(ex, name, m)?;
            }
            let i = ex.info();
            let decode = maps.iter().fold(i.decode_bytes(), |s, (_, m)| {
                s.saturating_add(m.info().decode_bytes())
            });
            // The maps' linear copies, beside the example's own (counted per pixel).
            let decode = decode.saturating_add(i.pixels().saturating_mul(4 * map_channels as u64));
            crate::memory::check_example(
                &format!(
                    "{}: image is {}x{} pixels",
                    ex.path().display(),
                    i.width,
                    i.height
                ),
                &job,
                &crate::memory::example_estimate(i.pixels(), decode, &job),
            )?;
        }
        let control = match self.mesh {
            MeshSource::Path(ref p) => Some(match self.texel_size {
                None => crate::memory::load_control_checked(p, n, &job)?,
                Some(l) => crate::memory::load_control_checked_texel_size(p, l, &job)?,
            }),
            MeshSource::Surface(ref s) => {
                match self.texel_size {
                    None => crate::memory::check_surface(s, n, &job)?,
                    Some(l) => crate::memory::check_surface_texel_size(s, l, &job)?,
                }
                None
            }
        };
        // The patch depth follows the finest texels (with a texel size: the longest control
        // edge over the texel size, an upper bound of any face's side).
        let n_depth = match (self.texel_size, &control, &self.mesh) {
            (None, _, _) => n,
            (Some(l), Some(c), _) => crate::memory::texel_size_side(c, l),
            (Some(l), None, MeshSource::Surface(s)) => {
                crate::memory::texel_size_side(&s.control, l)
            }
            (Some(_), None, MeshSource::Path(_)) => unreachable!("a path mesh is read above"),
        };
        // Both fit: decode the example, then build the surface.
        let example = match (pending, &self.example) {
            (Some((ex, maps)), _) => Example::from_pending(ex, maps)?,
            (None, ExampleSource::Example(e)) => (**e).clone(),
            (None, ExampleSource::Btf(_)) => btf.as_ref().expect("loaded above").example(),
            (None, ExampleSource::Path(_)) => unreachable!("a path example has a header"),
        };
        self.settings.weights.check(&example)?;
        // Any scale works: a mesh far from unit size is divided by a power of two
        // (`unit`, exact) and processed near unit size; results are reported and written
        // in the user's units (the session rebuilds the surface and geometry for writing).
        let (user_control, unit) = session::units(control, &self.mesh, &mesh_label)?;
        if let Some(a) = self.displace {
            let control = match (&user_control, &self.mesh) {
                (Some(c), _) => c,
                (None, MeshSource::Surface(s)) => &s.control,
                (None, MeshSource::Path(_)) => unreachable!("a path mesh is read above"),
            };
            crate::memory::check_displace(&mesh_label, a, crate::memory::extent(control))?;
        }
        // The scale map: read and checked against the control mesh before --out is opened.
        let scale_map = match &self.scale_map {
            None => None,
            Some(input) => {
                let m = match input {
                    ScaleMapInput::Path(p) => crate::scale_field::ScaleMap::load(p)?,
                    ScaleMapInput::Map(m) => m.clone(),
                    ScaleMapInput::FromOrientation => match &orientation {
                        Orientation::Constraints(p) => {
                            crate::scale_field::ScaleMap::load_orientation(p)?
                        }
                        other => {
                            return Err(Error::invalid(format!(
                                "--scale-from-orient takes the scale from the directions of an orientation constraints file, but the orientation is `{}`: pass --orient FILE",
                                other.label()
                            )))
                        }
                    },
                };
                let control = match (&user_control, &self.mesh) {
                    (Some(c), _) => c,
                    (None, MeshSource::Surface(s)) => &s.control,
                    (None, MeshSource::Path(_)) => unreachable!("a path mesh is read above"),
                };
                m.check(control.mesh.num_vertices())?;
                Some(m)
            }
        };
        let (surface, user_control) =
            session::working_surface(user_control, unit, self.mesh, n_depth);
        // The texel layout: one N, or per-face resolutions from the texel size (in the
        // surface's working units), checked against the guard with its real texel total.
        let layout = session::texel_layout(&surface, n, self.texel_size, unit, &mesh_label, &job)?;
        // Inputs are good: check --out and open it (nothing appears in it until the end).
        let txn = match out_dir {
            Some(dir) => Some(OutputTxn::begin(dir, crate::io::txn::SYNTH_OUTPUTS)?),
            None => None,
        };
        let load = t0.elapsed().as_secs_f64();
        progress(Stage::Load, 1, 1);

        // The mesh-side stages (geometry, field, graph) and the synthesis are a session's,
        // prepared here for one synthesis.
        let analyses = self
            .analyses
            .clone()
            .unwrap_or_else(|| std::sync::Arc::new(Analyses::new(&self.cache)));
        let mesh_settings = MeshSettings {
            resolution: n,
            texel_size: self.texel_size,
            scale: self.scale,
            orientation,
            scale_map,
        };
        let loaded = session::Loaded {
            mesh_label,
            surface,
            user_control,
            unit,
            layout,
            n_depth,
            load_seconds: load,
        };
        let session = Session::from_loaded(
            loaded,
            &mesh_settings,
            Some(self.settings.method),
            analyses,
            self.progress.clone(),
        )?;
        // Mesh-side orders are set-up, not synthesis: counted in the graph stage.
        let mut seconds = session.prepare_seconds();
        seconds.graph += session.prepare_method(self.settings.method);
        // A BTF run hands every image to the method (the session turns them as it turns
        // the example).
        let mut settings = self.settings;
        if btf.is_some() {
            settings.btf = btf;
        }
        let params = SynthParams {
            settings,
            seed: self.seed,
            handedness: self.handedness,
            normal_convention: self.normal_convention,
            displace: self.displace,
            write_options: self.write_options,
        };
        let labels = session::Labels {
            example: example_label,
            height: self
                .maps
                .iter()
                .rev()
                .find(|(n, _)| n == crate::example::HEIGHT)
                .map(|(_, h)| h.display().to_string()),
        };
        let result = session.run_once(example, &params, labels, started, seconds)?;
        Ok((result, txn))
    }
}

/// How reports and messages name a mesh source.
fn mesh_source_label(mesh: &MeshSource) -> String {
    match mesh {
        MeshSource::Path(p) => p.display().to_string(),
        MeshSource::Surface(s) => s
            .control
            .path
            .as_ref()
            .map(|p| p.display().to_string())
            .unwrap_or_else(|| "<in memory>".into()),
    }
}

fn orientation_label(o: &Orientation) -> String {
    match o {
        Orientation::Auto => "auto".into(),
        Orientation::Straight => "straight".into(),
        Orientation::Axis(a) => format!("axis ({}, {}, {})", a.x, a.y, a.z),
        Orientation::Up(a) => format!("up ({}, {}, {})", a.x, a.y, a.z),
        Orientation::Upright(a) => format!("upright ({}, {}, {})", a.x, a.y, a.z),
        Orientation::Constraints(p) => p.display().to_string(),
    }
}

/// [`check_size`] for a per-face layout.
fn check_texels(what: &str, layout: &crate::layout::TexelLayout) -> Result<()> {
    if layout.len() as u128 >= u32::MAX as u128 {
        return Err(Error::invalid(format!(
            "{what}: {} face domains at this texel size are {} texels; at most {} are supported: raise --texel-size",
            layout.faces(),
            layout.len(),
            u32::MAX - 1
        )));
    }
    Ok(())
}

/// Refuses sizes whose maps would not fit an EXR image or u32 texel indices.
fn check_size(faces: usize, n: usize) -> Result<()> {
    let texels = faces as u128 * (n * n) as u128;
    if texels >= u32::MAX as u128 {
        return Err(Error::invalid(format!(
            "{faces} face domains at resolution {n} are {texels} texels; at most {} are supported",
            u32::MAX - 1
        )));
    }
    Ok(())
}

impl SynthResult {
    /// The geometry maps (geometry.exr content).
    pub fn geometry_maps(&self) -> FaceMaps {
        let mut m = crate::synth::geometry_maps(&self.geometry);
        if let Some(s) = &self.local_scale {
            m.channels.push((LOCAL_SCALE_CHANNEL.into(), s.clone()));
        }
        m
    }

    /// Writes BRIEF's output directory into `dir` (created if missing): facemaps.exr,
    /// geometry.exr, facemaps.ptx ([`crate::io::ptex`]), surface.obj + surface.mtl +
    /// atlas.png and surface.glb ([`crate::io::atlas`], [`crate::io::gltf`]), displaced.glb
    /// when the run was given [`Synthesizer::displace`] ([`crate::io::displace`], decimated
    /// with [`WriteOptions::decimate`]), and report.json, last. Every file is written
    /// atomically into a staging folder and the set is moved into place only when
    /// complete ([`OutputTxn`]): if anything fails, `dir` is left exactly as it was.
    pub fn write(&self, dir: impl AsRef<Path>) -> Result<Report> {
        self.write_with(dir, |d| self.write_renderer_outputs(d))
    }

    /// [`SynthResult::write`] into an open transaction (its staging folder); the caller
    /// commits.
    pub fn write_into(&self, txn: &OutputTxn) -> Result<Report> {
        self.write_measured_into(txn, || |_: &mut Report| {})
    }

    /// [`SynthResult::write_into`] with `measure` run beside the writing
    /// ([`Synthesizer::run_to_with`]).
    fn write_measured_into<E: FnOnce(&mut Report) + Send>(
        &self,
        txn: &OutputTxn,
        measure: impl FnOnce() -> E + Send,
    ) -> Result<Report> {
        self.write_staged(
            txn.dir(),
            |d| self.write_ptx(d),
            measure,
            |d| self.write_textured(d),
        )
        .map_err(|e| txn.explain(e))
    }

    /// facemaps.ptx beside the textured meshes (independent, so side by side: PNG encoding
    /// and OBJ text are single-threaded). Cleans up after its own errors.
    fn write_renderer_outputs(&self, d: &Path) -> Result<Vec<PathBuf>> {
        let (textured, ptx) = rayon::join(|| self.write_textured(d), || self.write_ptx(d));
        match (ptx, textured) {
            (Ok(mut a), Ok(b)) => {
                a.extend(b);
                Ok(a)
            }
            (Err(e), other) | (other, Err(e)) => {
                if let Ok(w) = other {
                    remove_all(&w);
                }
                Err(e)
            }
        }
    }

    /// facemaps.ptx.
    fn write_ptx(&self, d: &Path) -> Result<Vec<PathBuf>> {
        use crate::io::ptex;
        let p = d.join(ptex::PTEX_FILE);
        ptex::write_face_maps_ptex(&p, &self.surface, &self.maps, &self.write_options.ptex)?;
        Ok(vec![p])
    }

    /// The textured meshes: surface.obj + mtl + atlases, surface.glb (and displaced.glb).
    /// Cleans up after its own errors.
    fn write_textured(&self, d: &Path) -> Result<Vec<PathBuf>> {
        use crate::io::{atlas, displace};
        let frames = (self.tangents.len() == self.geometry.normal.len()).then_some(
            crate::io::tangent::FieldFrames {
                tangent: &self.tangents,
                normal: &self.geometry.normal,
            },
        );
        let (_, images) = crate::io::export::export_with_frames(
            d,
            &self.surface,
            &self.maps,
            &Default::default(),
            frames,
        )?;
        let mut written: Vec<PathBuf> = [
            atlas::OBJ_NAME,
            atlas::MTL_NAME,
            atlas::ATLAS_NAME,
            atlas::GLB_NAME,
        ]
        .iter()
        .map(|n| d.join(n))
        .chain(images.maps.iter().map(|m| d.join(m.file_name())))
        .collect();
        if let Some(amount) = self.displace {
            let decimate = self.write_options.decimate;
            match displace::write_displaced(d, &self.surface, &self.maps, amount, decimate, &images)
                .and_then(|f| f.commit())
            {
                Ok(()) => written.push(d.join(displace::DISPLACED_GLB)),
                Err(e) => {
                    remove_all(&written);
                    return Err(e);
                }
            }
        }
        Ok(written)
    }

    /// Like [`SynthResult::write`] with other extra outputs: `extra(dir)` writes them into
    /// the staging folder `dir` (while the EXR files are written, before the report; its
    /// time counts as writing) and returns their paths. They are moved into place with the
    /// rest, or not at all.
    pub fn write_with(
        &self,
        dir: impl AsRef<Path>,
        extra: impl FnOnce(&Path) -> Result<Vec<PathBuf>> + Send,
    ) -> Result<Report> {
        let txn = OutputTxn::begin(dir, crate::io::txn::SYNTH_OUTPUTS)?;
        let report = self
            .write_staged(txn.dir(), extra, || |_: &mut Report| {}, |_| Ok(Vec::new()))
            .map_err(|e| txn.explain(e))?;
        txn.commit()?;
        Ok(report)
    }

    /// Writes every file into `dir` (a staging folder), and runs `measure` beside them:
    /// what it returns edits the report before report.json is written (once, last).
    /// `extra` writes outputs beside `measure`, `after` once it is done.
    fn write_staged<E: FnOnce(&mut Report) + Send>(
        &self,
        dir: &Path,
        extra: impl FnOnce(&Path) -> Result<Vec<PathBuf>> + Send,
        measure: impl FnOnce() -> E + Send,
        after: impl FnOnce(&Path) -> Result<Vec<PathBuf>> + Send,
    ) -> Result<Report> {
        let t0 = Instant::now();
        self.check_finite_exr()?;
        // Everything side by side: the two EXR files, the extra outputs, and `measure` (the
        // pf summary of `synth`, which only reads the result). Their bytes do not depend on
        // the order or the threads; report.json waits for all.
        //
        // The EXR files get a thread of their own beside the pool, one after the other:
        // their tiles are copies, and most of their time is spent waiting for the disk
        // (`O_DIRECT`), which on a pool worker left its core idle — on the bunny (N = 16,
        // 290 MB) ~0.4 s of one of the two workers, while the other ran the pf summary and
        // the atlas alone (docs/benchmarks.md, "The bunny's coherent run, ninth session").
        // Here the waiting blocks that thread only, and the pool's workers take the rest:
        // `measure` and `extra` (synth: the pf summary and facemaps.ptx), then `after`
        // (synth: the textured meshes) where `measure` ends — after it, not beside it: the
        // atlas and the summary's point cloud at once raised the end-of-run peak (Spot
        // N = 128: +30 MiB); the worker that finishes first helps the other meanwhile.
        // One thread for both EXR files, not one each: the disk takes them one at a time
        // anyway.
        let exr_files = || {
            let fm = (self.write_facemaps_exr(dir), t0.elapsed());
            (fm, (self.write_geometry_exr(dir), t0.elapsed()))
        };
        let rest = || {
            rayon::join(
                || {
                    let t = Instant::now();
                    let edit = measure();
                    let measured = t.elapsed();
                    (edit, measured, (after(dir), t0.elapsed()))
                },
                || (extra(dir), t0.elapsed()),
            )
        };
        // With one worker (`--threads 1`) the EXR files stay on it, after the rest: on a
        // thread of their own they would compete with the only worker for its core (their
        // tiles are filled there).
        let ((fm, geo), ((edit, measured, after), extra)) = if rayon::current_num_threads() <= 1 {
            let rest = rest();
            (exr_files(), rest)
        } else {
            std::thread::scope(|s| {
                let exr = s.spawn(exr_files);
                let rest = rest();
                let exr = exr.join().unwrap_or_else(|p| std::panic::resume_unwind(p));
                (exr, rest)
            })
        };
        // Writing ends when its last file does.
        let files = fm.1.max(geo.1).max(extra.1).max(after.1);
        let mut written: Vec<PathBuf> = Vec::new();
        let mut first_err = None;
        for r in [
            fm.0.map(|p| vec![p]),
            geo.0.map(|p| vec![p]),
            extra.0,
            after.0,
        ] {
            match r {
                Ok(p) => written.extend(p),
                Err(e) => {
                    first_err.get_or_insert(e);
                }
            }
        }
        let result = (|| {
            if let Some(e) = first_err {
                return Err(e);
            }
            // The files' background fsyncs (in a transaction's staging folder) count as
            // writing.
            let t_sync = Instant::now();
            crate::io::atomic::finish_syncs_in(dir)?;
            let mut report = self.report.clone();
            edit(&mut report);
            report.seconds.write = (files + t_sync.elapsed()).as_secs_f64();
            report.seconds.pf = measured.as_secs_f64();
            report.seconds.total = self.started.elapsed().as_secs_f64();
            report.peak_memory_bytes = crate::report::peak_memory_bytes();
            report.update_rates();
            report.write(dir)?;
            written.push(dir.join(crate::io::names::REPORT_FILE));
            Ok(report)
        })();
        if result.is_err() {
            remove_all(&written);
        }
        result
    }

    /// The last guard before the EXR files (issue 18): no NaN or ±inf in what synth
    /// writes. Checked on the pool before they are written, each on a thread of its own
    /// ([`SynthResult::write_staged`]), so nothing is written when one fails.
    fn check_finite_exr(&self) -> Result<()> {
        use crate::io::exr::{check_finite, check_finite_by};
        for (name, data) in &self.maps.channels {
            check_finite(
                &format!("face map channel '{name}'"),
                data,
                &self.maps.layout,
            )?;
        }
        let g = &self.geometry;
        check_finite_by(
            "texel position",
            g.pos.len(),
            |i| g.pos[i].is_finite(),
            &g.layout,
        )?;
        check_finite_by(
            "texel normal",
            g.normal.len(),
            |i| g.normal[i].is_finite(),
            &g.layout,
        )?;
        check_finite_by(
            "field tangent",
            self.tangents.len(),
            |i| self.tangents[i].iter().all(|v| v.is_finite()),
            &g.layout,
        )
    }

    /// facemaps.exr, its tiles filled on the calling thread.
    fn write_facemaps_exr(&self, dir: &Path) -> Result<PathBuf> {
        let p = dir.join(FACEMAPS_FILE);
        crate::io::exr::write_face_maps_on(&p, &self.maps, TileThreads::Caller)?;
        Ok(p)
    }

    /// geometry.exr: positions, normals, the field's tangents (and the local scale), its
    /// tiles filled on the calling thread.
    fn write_geometry_exr(&self, dir: &Path) -> Result<PathBuf> {
        // Streamed from the texel geometry (the same bytes as writing
        // `geometry_maps()`, without a second copy of the maps).
        let p = dir.join(GEOMETRY_FILE);
        let g = &self.geometry;
        let mut names = crate::bake::GEOMETRY_CHANNELS.to_vec();
        names.extend(TANGENT_CHANNELS);
        if self.local_scale.is_some() {
            names.push(LOCAL_SCALE_CHANNEL);
        }
        crate::io::exr::write_tiles_with_attributes(
            &p,
            crate::io::exr::TileLayout::of(g.layout.clone()),
            &names,
            crate::io::exr::compression_for(&g.layout),
            &[(TANGENT_HANDEDNESS, self.handedness.bitangent_sign())],
            |f, tile| {
                let r = g.layout.range(f);
                for (c, out) in tile.chunks_exact_mut(r.len()).enumerate() {
                    if c == 9 {
                        let s = self.local_scale.as_ref().expect("named above");
                        out.copy_from_slice(&s[r.clone()]);
                        continue;
                    }
                    if c >= 6 {
                        for (o, t) in out.iter_mut().zip(&self.tangents[r.clone()]) {
                            *o = t[c % 3];
                        }
                        continue;
                    }
                    let src = if c < 3 { &g.pos } else { &g.normal };
                    for (o, v) in out.iter_mut().zip(&src[r.clone()]) {
                        *o = v[c % 3];
                    }
                }
            },
            &|_| {},
            TileThreads::Caller,
        )?;
        Ok(p)
    }
}

/// Removes files written by a run that failed later (best effort: they were ours).
fn remove_all(paths: &[PathBuf]) {
    for p in paths {
        let _ = std::fs::remove_file(p);
    }
}

/// What [`SynthResult::write`] writes beyond BRIEF's fixed set, and how.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct WriteOptions {
    /// `--decimate TOL`: displaced.glb keeps only the vertices needed where the displaced
    /// surface is flat within TOL mesh units ([`crate::io::decimate`]); `None`: one vertex
    /// per texture coordinate of the texel-resolution tessellation.
    pub decimate: Option<f64>,
    /// How facemaps.ptx is written.
    pub ptex: crate::io::ptex::PtexOptions,
}

/// The `synth` command in plain types (the CLI's argument struct maps onto it).
#[derive(Clone, Debug)]
pub struct SynthCommand {
    pub mesh: PathBuf,
    pub example: PathBuf,
    /// `--btf B.json` (instead of `example`).
    pub btf: Option<PathBuf>,
    pub height: Option<PathBuf>,
    /// `--map NAME=FILE`, in the order given.
    pub maps: Vec<(String, PathBuf)>,
    /// `--match NAME=WEIGHT`.
    pub matches: Vec<(String, f32)>,
    /// `--normal-convention`.
    pub normal_convention: NormalConvention,
    pub method: Method,
    pub resolution: usize,
    /// `--texel-size L` (per-face resolutions instead of `resolution`).
    pub texel_size: Option<f64>,
    pub scale: Option<f64>,
    /// `--scale-map FILE`.
    pub scale_map: Option<PathBuf>,
    /// `--scale-from-orient`: the scale from the lengths of the `--orient FILE` directions.
    pub scale_from_orient: bool,
    /// `--orient` (`None`: the method's own).
    pub orientation: Option<Orientation>,
    pub seed: u64,
    /// `--search` (multiscale only; `None` = the default, k-coherence).
    pub search: Option<Search>,
    /// `--neighbourhood K` (multiscale and textons; `None`: the default,
    /// [`crate::synth::matching::search::model::ModelParams`]).
    pub neighbourhood: Option<usize>,
    /// `--kcoherence-k K` (k-coherence's k; `None`: the default).
    pub kcoherence_k: Option<usize>,
    /// `--neighbourhood-samples sparse|full` (multiscale; `None`: the default).
    pub sparse: Option<bool>,
    /// `--finest-start continued|matched` (multiscale; `None`: the default).
    pub continue_finest: Option<bool>,
    /// `--jump-blend W` (jump; 0: off; `None`: the default,
    /// [`crate::synth::JumpParams::blend`]).
    pub jump_blend: Option<f32>,
    /// `--displace AMOUNT`.
    pub displace: Option<f64>,
    /// `--appearance`.
    pub appearance: AppearanceMode,
    /// `--feature-distance W` (0: none).
    pub feature_distance: f32,
    /// `--decimate TOL`.
    pub decimate: Option<f64>,
    /// `--patch-size` (patches, and the start of optimise; `None`: automatic).
    pub patch_size: Option<usize>,
    /// `--handedness`.
    pub handedness: Handedness,
    /// `--cache DIR` / `--no-cache`.
    pub cache: CacheDir,
    pub out: PathBuf,
}

impl SynthCommand {
    /// The builder for this command (threads: the current rayon pool, which the CLI sizes
    /// with `--threads`).
    pub fn synthesizer(&self) -> Synthesizer {
        let example = match &self.btf {
            Some(b) => ExampleSource::Btf(b.clone()),
            None => ExampleSource::Path(self.example.clone()),
        };
        let mut s = Synthesizer::new(&self.mesh, example)
            .method(self.method)
            .resolution(self.resolution)
            .texel_size(self.texel_size)
            .scale(self.scale)
            .orientation(self.orientation.clone())
            .seed(self.seed)
            .displace(self.displace)
            .appearance(self.appearance)
            .feature_distance(self.feature_distance)
            .decimate(self.decimate)
            .handedness(self.handedness)
            .cache(self.cache.clone());
        if let Some(h) = &self.height {
            s = s.height(h);
        }
        if let Some(m) = &self.scale_map {
            s = s.scale_map(m);
        }
        if self.scale_from_orient {
            s = s.scale_from_orientation();
        }
        for (name, file) in &self.maps {
            s = s.map(name, file);
        }
        s = s.normal_convention(self.normal_convention);
        if !self.matches.is_empty() {
            let mut w = s.current_settings().weights.clone();
            w.maps.extend(self.matches.iter().cloned());
            s = s.weights(w);
        }
        if let Some(search) = self.search {
            s = s.search(search);
        }
        if let Some(k) = self.neighbourhood {
            s = s.neighbourhood(k);
        }
        if let Some(k) = self.kcoherence_k {
            s = s.kcoherence_k(k);
        }
        if let Some(sparse) = self.sparse {
            s = s.sparse_neighbourhood(sparse);
        }
        if let Some(on) = self.continue_finest {
            s = s.continue_finest(on);
        }
        if let Some(w) = self.jump_blend {
            let mut p = s.current_settings().jump;
            p.blend = (w > 0.0).then_some(w);
            s = s.jump_params(p);
        }
        if self.patch_size.is_some() {
            let mut settings = s.current_settings().clone();
            settings.patches.size = self.patch_size;
            settings.optimise.start.size = self.patch_size;
            s = s.settings(settings);
        }
        s
    }
}

/// Runs a [`SynthCommand`] with a progress bar per stage on stderr (when it is a
/// terminal), measures pf1/pf4/pf8 of the result in memory while its files are written
/// (recorded in report.json as `patch_fidelity`; its time is in `seconds.pf` and in
/// `seconds.total`, the wall the user waits) and prints the end summary on stdout.
pub fn run_command(c: &SynthCommand) -> Result<Report> {
    let bars = StageBars::default();
    let (_, report) = c
        .synthesizer()
        .on_progress(move |s, d, t| bars.update(s, d, t))
        .run_to_with(&c.out, |r| {
            // Beside writing (it only reads the result), so report.json, written once
            // after both, has it. pf reads the texel geometry in place (not a copy as
            // geometry maps: 24 B per texel less at the run's peak, the pf point cloud).
            // The example banks through the analysis cache (`--cache`, `--no-cache`).
            let banks = Analyses::new(&c.cache);
            let pf = crate::eval::summary_fidelity_cached(
                &r.maps,
                crate::eval::TexelPoints::of_geometry(&r.geometry, r.local_scale.as_deref()),
                &r.example,
                r.report.scale,
                &banks,
                // `write_staged` has checked every map and the texel positions finite
                // before `measure` runs (issue 18).
                true,
            );
            move |report: &mut Report| report.patch_fidelity = Some(pf)
        })?;
    println!("{}", summary_line(&report, &c.out));
    Ok(report)
}

/// One line: domains, texels, seconds, texels/s (whole run and synthesis alone), and
/// pf1/pf4/pf8 when measured.
pub fn summary_line(r: &Report, out: &Path) -> String {
    use crate::progress::si;
    let pf = r.patch_fidelity.as_ref().map_or(String::new(), |p| {
        let f = |v: Option<f64>| v.map_or("n/a".to_string(), |v| format!("{v:.3}"));
        format!("; pf1 {} pf4 {} pf8 {}", f(p.pf1), f(p.pf4), f(p.pf8))
    });
    let each = match r.texel_size {
        None => format!("{n}x{n} each", n = r.resolution),
        Some(l) => format!("texel size {l}, up to {n}x{n}", n = r.resolution),
    };
    // `upright` lying flat is worth a word: the user asked for (or defaulted to) an upright
    // example and gets the smooth field.
    let field = match &r.orientation_choice {
        Some(c) if c.chosen == "auto" => c.level_fraction.map_or(String::new(), |f| {
            format!(
                "; field auto: {:.0}% of the surface is level, no up to follow",
                100.0 * f
            )
        }),
        _ => String::new(),
    };
    format!(
        "synth: {} domains, {} texels ({each}) in {:.2} s ({} texels/s; synthesis {:.2} s, {} texels/s){pf}{field} -> {}",
        r.faces,
        r.texels,
        r.seconds.total,
        si(r.texels_per_second),
        r.seconds.synthesis,
        si(r.synthesis_texels_per_second),
        out.display(),
    )
}

/// indicatif bars, one per stage, driven by [`Progress`] callbacks; when stderr is not a
/// terminal (a log file, CI), plain lines instead: one when a stage starts and, in a stage,
/// one every [`LOG_EVERY`] seconds with its count, so the log of a long run shows where it
/// is. Runs shorter than [`LOG_AFTER`] print none (stderr then holds at most the one-line
/// error).
struct StageBars {
    current: std::sync::Mutex<Option<(Stage, indicatif::ProgressBar)>>,
    lines: Option<std::sync::Mutex<LineLog>>,
}

/// Seconds into a run before progress lines are written off a terminal (the environment
/// variable `SURFSYNTH_PROGRESS_AFTER` overrides it: 0 logs every run).
pub const LOG_AFTER: f64 = 1.0;
/// Seconds between progress lines within a stage.
pub const LOG_EVERY: f64 = 10.0;

struct LineLog {
    started: Instant,
    after: f64,
    /// The stage whose start line was written, and when the last line was.
    stage: Option<Stage>,
    last: f64,
}

impl Default for StageBars {
    fn default() -> Self {
        Self {
            current: Default::default(),
            lines: (!crate::progress::enabled()).then(|| {
                std::sync::Mutex::new(LineLog {
                    started: Instant::now(),
                    after: std::env::var("SURFSYNTH_PROGRESS_AFTER")
                        .ok()
                        .and_then(|v| v.parse::<f64>().ok())
                        .filter(|v| *v >= 0.0)
                        .unwrap_or(LOG_AFTER),
                    stage: None,
                    last: 0.0,
                })
            }),
        }
    }
}

impl StageBars {
    fn update(&self, stage: Stage, done: usize, total: usize) {
        if let Some(log) = &self.lines {
            let mut log = log.lock().unwrap_or_else(|e| e.into_inner());
            let now = log.started.elapsed().as_secs_f64();
            if now < log.after {
                return;
            }
            let count = if total > 1 {
                format!(" {done}/{total}")
            } else {
                String::new()
            };
            if log.stage != Some(stage) {
                log.stage = Some(stage);
                log.last = now;
                eprintln!("synth: {}{count} at {now:.1} s", stage.label());
            } else if now - log.last >= LOG_EVERY && done < total {
                log.last = now;
                eprintln!("synth: {}{count} at {now:.1} s", stage.label());
            }
            return;
        }
        let mut cur = self.current.lock().unwrap_or_else(|e| e.into_inner());
        if cur.as_ref().map(|(s, _)| *s) != Some(stage) {
            if let Some((_, b)) = cur.take() {
                b.finish_and_clear();
            }
            *cur = Some((stage, crate::progress::bar(total as u64, stage.label())));
        }
        if let Some((_, b)) = cur.as_ref() {
            // An analysis reports its start as 0 of 1, then its own count.
            b.set_length(total as u64);
            b.set_position(done as u64);
            if done >= total {
                b.finish_and_clear();
                // A later report of the same stage (the next analysis) gets a new bar.
                *cur = None;
            }
        }
    }
}
