//! Prepared sessions: the mesh-side stages of a run (surface, texel geometry, orientation
//! field, texel graph, what methods derive from them) done once, then any number of
//! syntheses on them — another seed, example or method costs only the synthesis. This is
//! what an interactive tool calls (issue 14, item 4).
//!
//! ```no_run
//! use surfsynth::example::Example;
//! use surfsynth::synthesizer::{Method, MeshSettings, Session, SynthParams};
//!
//! # fn main() -> surfsynth::Result<()> {
//! let session = Session::prepare("spot_control_mesh.obj", &MeshSettings::default())?;
//! let gravel = Example::load("gravel.png")?;
//! for seed in [1, 2, 3] {
//!     let params = SynthParams { seed, ..SynthParams::new(Method::Jump) };
//!     let result = session.synthesize(&gravel, &params)?;
//!     result.write(format!("out/seed-{seed}"))?;
//! }
//! # Ok(())
//! # }
//! ```
//!
//! The one-shot builder ([`super::Synthesizer`]) runs exactly these stages — it prepares
//! a session and synthesizes once — so a session's outputs are bit-identical to a
//! one-shot run with the same inputs (tests/session.rs).
//!
//! What is kept, and why it may be kept: everything here depends on the mesh, the
//! resolution, the scale (and scale map) and the orientation only ([`MeshSettings`]), never on the
//! example or the seed. Per-example analysis (appearance space, jump maps, k-coherence
//! lists) is kept by the session's [`Analyses`] (the "prepared example"), keyed by the
//! example's pixels and parameters, so a second synthesis with the same example skips it.
//! Patch footprints are laid from seeded centres and sized by the example, so they are
//! rebuilt by every synthesis.

use super::{
    check_size, check_texels, orientation_label, Handedness, MeshSource, NormalConvention,
    Progress, Stage, SynthResult, WriteOptions,
};
use crate::error::{Error, Result};
use crate::example::Example;
use crate::field::{FieldOptions, Orientation, OrientationField};
use crate::io::exr::MAX_RESOLUTION;
use crate::layout::TexelLayout;
use crate::memory::{Job, MeshSize};
use crate::report::{ExampleInfo, Inputs, Report, Seconds};
use crate::scale_field::{ScaleField, ScaleMap};
use crate::synth::footprint::LevelTexels;
use crate::synth::{Analyses, Derived, Method, Settings, Target};
use crate::texels::{EdgeGraph, FrameSlots, TexelGeometry, TexelGraph};
use glam::Vec3;
use rayon::prelude::*;
use std::sync::{Arc, Mutex, OnceLock};
use std::time::Instant;
use subdiv::{ControlMesh, Surface};

/// What a prepared mesh depends on: everything of a run that is not the example, the
/// method or the seed.
#[derive(Clone, Debug, PartialEq)]
pub struct MeshSettings {
    /// Texels per side of every face map (1 to [`MAX_RESOLUTION`]); unused when
    /// `texel_size` is set.
    pub resolution: usize,
    /// `--texel-size L`: every face gets its own power-of-two resolution, about `L`
    /// surface units per texel ([`TexelLayout::for_texel_size`]), instead of one N for all
    /// faces. `None` = `resolution` everywhere.
    pub texel_size: Option<f64>,
    /// Surface length covered by one example pixel; `None` = median texel spacing.
    pub scale: Option<f64>,
    /// Orientation field (`--orient`).
    pub orientation: Orientation,
    /// `--scale-map FILE` ([`ScaleMap::load`]): a factor per control vertex or surface
    /// point, interpolated over the surface ([`crate::scale_field`]), that multiplies
    /// `scale` locally — the texture grows where the factor is large. Mesh-side, like the
    /// orientation: it names the mesh's vertices, and its interpolation and per-texel
    /// factors are computed once per prepared mesh, as the field's frames are.
    pub scale_map: Option<ScaleMap>,
}

impl Default for MeshSettings {
    /// Resolution 32, the median texel spacing as scale, the default method's orientation
    /// (`up`; as [`super::Synthesizer::new`] with that method). A prepared mesh serves every
    /// method with one field: give `Orientation::Auto` for the per-texel methods' own.
    fn default() -> Self {
        Self {
            resolution: 32,
            texel_size: None,
            scale: None,
            orientation: crate::synth::Method::DEFAULT.default_orientation(),
            scale_map: None,
        }
    }
}

impl MeshSettings {
    /// Checks what needs no file.
    pub fn validate(&self) -> Result<()> {
        if self.resolution == 0 || self.resolution > MAX_RESOLUTION {
            return Err(Error::invalid(format!(
                "resolution {} is out of range: use 1 to {MAX_RESOLUTION} texels per side",
                self.resolution
            )));
        }
        if let Some(l) = self.texel_size {
            if !(l.is_finite() && l > 0.0) {
                return Err(Error::invalid(format!(
                    "texel size {l} is not a positive surface length per texel"
                )));
            }
        }
        if let Some(s) = self.scale {
            if !(s.is_finite() && s > 0.0) {
                return Err(Error::invalid(format!(
                    "scale {s} is not a positive surface length per example pixel"
                )));
            }
        }
        Ok(())
    }
}

/// What one synthesis on a prepared session depends on besides the example.
#[derive(Clone, Debug, PartialEq)]
pub struct SynthParams {
    /// The method and its tuning.
    pub settings: Settings,
    /// Random seed; the same seed gives bit-identical maps for any thread count.
    pub seed: u64,
    /// Which way round the example is laid on the surface.
    pub handedness: Handedness,
    /// How the green channel of the example's `normal` map is to be read
    /// (`--normal-convention`).
    pub normal_convention: NormalConvention,
    /// `--displace AMOUNT` (needs a height channel): [`SynthResult::write`] also writes
    /// displaced.glb.
    pub displace: Option<f64>,
    /// How [`SynthResult::write`] writes the renderer outputs.
    pub write_options: WriteOptions,
}

impl Default for SynthParams {
    /// [`Method::DEFAULT`] with default settings, seed 1, [`Handedness::Tiles`].
    fn default() -> Self {
        Self {
            settings: Settings::default(),
            seed: 1,
            handedness: Handedness::default(),
            normal_convention: NormalConvention::default(),
            displace: None,
            write_options: WriteOptions::default(),
        }
    }
}

impl SynthParams {
    /// The defaults with `method`.
    pub fn new(method: Method) -> Self {
        let mut p = Self::default();
        p.settings.method = method;
        p
    }
}

/// Seconds of the mesh-side stages, paid once by [`Session::prepare`]. The field is
/// computed beside the texel geometry and the graphs (not for `straight`), so `field`
/// overlaps `geometry` and `graph`: each is the time of its own work.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PrepareSeconds {
    /// Reading the mesh and building the limit surface.
    pub load: f64,
    pub geometry: f64,
    pub field: f64,
    pub graph: f64,
}

impl PrepareSeconds {
    /// All stages together (more than the wall time where they overlapped).
    pub fn total(&self) -> f64 {
        self.load + self.geometry + self.field + self.graph
    }
}

/// A prepared mesh (see the module docs): prepare once with [`Session::prepare`], then
/// [`Session::synthesize`] as often as wanted. Syntheses run in the current rayon pool
/// (wrap them in `ThreadPool::install` for another); results do not depend on its size.
pub struct Session {
    mesh_label: String,
    resolution: usize,
    /// Where every texel is: one N ([`MeshSettings::resolution`]) or per-face
    /// resolutions ([`MeshSettings::texel_size`]).
    layout: Arc<TexelLayout>,
    texel_size: Option<f64>,
    /// Subdivision depth the surfaces are built for (the finest face's side).
    n_depth: usize,
    orientation: Orientation,
    /// The surface and texels in working units (the user's divided by `unit`).
    surface: Arc<Surface>,
    /// The field at the level the texel count needs (`field::TEXELS_PER_FACE`).
    field: OrientationField,
    /// The field at the finest level within the face budget, for the methods that sample
    /// neighbourhood patterns along it (multiscale, textons), computed on first use when
    /// `field` is coarser ([`Session::field_for`]).
    fine_field: OnceLock<OrientationField>,
    texels: LevelTexels,
    derived: Derived,
    /// Median texel spacing and scale, working units.
    spacing: f64,
    scale: f64,
    scale_source: &'static str,
    /// The scale map's interpolated factor (`None` without `--scale-map`).
    scale_field: Option<Arc<ScaleField>>,
    /// Power of two the user's mesh was divided by (1 near unit size; docs/robustness.md).
    unit: f64,
    /// Far from unit size: the user's control mesh, and (built on first use, for writing)
    /// the surface and texel geometry in the user's units.
    user_control: Option<ControlMesh>,
    user: OnceLock<(Arc<Surface>, Arc<TexelGeometry>)>,
    /// Extent of the user's control mesh (displacement check).
    extent: f64,
    /// For the memory check of each synthesis (the method and example change it).
    size: MeshSize,
    seconds: PrepareSeconds,
    analyses: Arc<Analyses>,
    progress: Option<Arc<Progress>>,
}

impl std::fmt::Debug for Session {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Session")
            .field("mesh", &self.mesh_label)
            .field("layout", &self.layout.describe())
            .field("faces", &self.surface.num_domains())
            .finish_non_exhaustive()
    }
}

/// The memory job of preparing a mesh before any example or method is known: the
/// cheapest method, RGB, no example (each synthesis checks its own job again).
const MESH_JOB: Job = Job::Synth {
    channels: 5,
    example_pixels: 0,
    method: Method::Coherent,
    displace: false,
    scale_map: false,
};

/// The user's control mesh where it must be kept (a mesh far from unit size: outputs are
/// written in the user's units) and the power of two it is divided by for processing.
pub(super) fn units(
    control: Option<ControlMesh>,
    mesh: &MeshSource,
    label: &str,
) -> Result<(Option<ControlMesh>, f64)> {
    let user_control = match (control, mesh) {
        (Some(c), _) => Some(c),
        (None, MeshSource::Surface(s)) => {
            crate::memory::check_coordinate_range(label, &s.control)?;
            (crate::memory::normalising_unit(&s.control) != 1.0).then(|| s.control.clone())
        }
        (None, MeshSource::Path(_)) => unreachable!("a path mesh is read before"),
    };
    let unit = user_control
        .as_ref()
        .map_or(1.0, crate::memory::normalising_unit);
    Ok((user_control, unit))
}

/// The surface in working units, and the user's control mesh when it differs.
pub(super) fn working_surface(
    user_control: Option<ControlMesh>,
    unit: f64,
    mesh: MeshSource,
    n: usize,
) -> (Surface, Option<ControlMesh>) {
    match (user_control, mesh) {
        (Some(c), _) if unit != 1.0 => {
            let mut inner = c.clone();
            for p in &mut inner.mesh.positions {
                *p /= unit;
            }
            (crate::memory::build_surface(inner, n), Some(c))
        }
        (Some(c), _) => (crate::memory::build_surface(c, n), None),
        (None, MeshSource::Surface(s)) => (*s, None),
        (None, MeshSource::Path(_)) => unreachable!("a path mesh is read before"),
    }
}

/// The texel layout of `surface` (working units; the user's divided by `unit`): `n`×`n`
/// everywhere, or per-face resolutions for `texel_size` (in the user's units), checked
/// against the memory guard for `job` with its real texel total.
pub(super) fn texel_layout(
    surface: &Surface,
    n: usize,
    texel_size: Option<f64>,
    unit: f64,
    label: &str,
    job: &Job,
) -> Result<Arc<TexelLayout>> {
    let faces = surface.num_domains();
    Ok(Arc::new(match texel_size {
        None => {
            check_size(faces, n)?;
            TexelLayout::uniform(faces, n)
        }
        Some(l) => {
            let layout = TexelLayout::for_texel_size(surface, l / unit);
            check_texels(label, &layout)?;
            crate::memory::check_layout(label, &surface.control, &layout, job)?;
            layout
        }
    }))
}

/// The subdivision depth's resolution: `n`, or with a texel size the longest control edge
/// over the texel size (an upper bound of any face's side).
pub(super) fn depth_resolution(control: &ControlMesh, n: usize, texel_size: Option<f64>) -> usize {
    match texel_size {
        None => n,
        Some(l) => crate::memory::texel_size_side(control, l),
    }
}

/// The level of the finer field multiscale and textons sample along
/// ([`Session::field_for`]): the automatic level of default options, not sized by the
/// texel count.
fn fine_level(surface: &Surface) -> u32 {
    crate::field::auto_level(surface.num_base_quads(), &FieldOptions::default())
}

/// The surface built so far by the load stage, handed to [`Session::from_loaded`].
pub(super) struct Loaded {
    pub mesh_label: String,
    pub surface: Surface,
    pub user_control: Option<ControlMesh>,
    pub unit: f64,
    /// The texel layout ([`texel_layout`]) and the depth the surfaces are built for.
    pub layout: Arc<TexelLayout>,
    pub n_depth: usize,
    pub load_seconds: f64,
}

impl Session {
    /// Prepares `mesh` (an OBJ path or a [`Surface`]): reads it, checks the memory it
    /// needs, builds the limit surface, the texel geometry, the orientation field and the
    /// texel graph. Per-example analysis goes through an [`Analyses`] on the default cache
    /// folder ([`Session::with_analyses`] shares another).
    pub fn prepare(mesh: impl Into<MeshSource>, settings: &MeshSettings) -> Result<Session> {
        settings.validate()?;
        let t0 = Instant::now();
        let mesh = mesh.into();
        let n = settings.resolution;
        let label = super::mesh_source_label(&mesh);
        let texel_size = settings.texel_size;
        let control = match (&mesh, texel_size) {
            (MeshSource::Path(p), None) => {
                Some(crate::memory::load_control_checked(p, n, &MESH_JOB)?)
            }
            (MeshSource::Path(p), Some(l)) => Some(crate::memory::load_control_checked_texel_size(
                p, l, &MESH_JOB,
            )?),
            (MeshSource::Surface(s), None) => {
                crate::memory::check_surface(s, n, &MESH_JOB)?;
                None
            }
            (MeshSource::Surface(s), Some(l)) => {
                crate::memory::check_surface_texel_size(s, l, &MESH_JOB)?;
                None
            }
        };
        let n_depth = match (&control, &mesh) {
            (Some(c), _) => depth_resolution(c, n, texel_size),
            (None, MeshSource::Surface(s)) => depth_resolution(&s.control, n, texel_size),
            (None, MeshSource::Path(_)) => unreachable!("a path mesh is read above"),
        };
        let (user_control, unit) = units(control, &mesh, &label)?;
        let (surface, user_control) = working_surface(user_control, unit, mesh, n_depth);
        let layout = texel_layout(&surface, n, texel_size, unit, &label, &MESH_JOB)?;
        let loaded = Loaded {
            mesh_label: label,
            surface,
            user_control,
            unit,
            layout,
            n_depth,
            load_seconds: t0.elapsed().as_secs_f64(),
        };
        Self::from_loaded(
            loaded,
            settings,
            None,
            Arc::new(Analyses::new(&crate::cache::CacheDir::Default)),
            None,
        )
    }

    /// The stages after loading (geometry, field, graph), as the one-shot builder runs
    /// them. `method`: the method the session will run (the one-shot builder's), whose
    /// mesh-side orders are then prepared beside the field (see
    /// [`Session::prepare_method`]); `None` leaves them to first use. A session prepared
    /// for coherent synthesis this way has no edge graph and serves that method only.
    pub(super) fn from_loaded(
        loaded: Loaded,
        settings: &MeshSettings,
        method: Option<Method>,
        analyses: Arc<Analyses>,
        progress: Option<Arc<Progress>>,
    ) -> Result<Session> {
        let Loaded {
            mesh_label,
            surface,
            user_control,
            unit,
            layout,
            n_depth,
            load_seconds,
        } = loaded;
        let n = settings.resolution;
        let report = |s: Stage, d: usize, t: usize| {
            if let Some(p) = &progress {
                p(s, d, t)
            }
        };
        let faces = surface.num_domains();
        let extent = crate::memory::extent(user_control.as_ref().unwrap_or(&surface.control));
        let size = MeshSize::of(user_control.as_ref().unwrap_or(&surface.control));

        // The orientation field needs the surface only (but for `straight`, which scores
        // its candidates at the texel scale, below): it runs beside the texel geometry, the
        // edge graph and what `method` derives from them alone. Its level-1 eigenvector
        // solve is one long serial stretch (bunny N = 16: ~1 s with one core busy), and
        // the jump method's growth order is another; side by side they fill both cores,
        // and the jump method's parallel cross-neighbour queries (`jump::Growth`) take up
        // whichever core is free first. Each part computes exactly what it computed in
        // sequence: the same results.
        report(Stage::Geometry, 0, faces);
        let options_at = |scale: Option<f64>| FieldOptions {
            texels: Some(layout.len() as u64),
            ..match scale {
                Some(s) => field_options(s, unit),
                // Only `straight` reads the structure length.
                None => FieldOptions {
                    unit,
                    ..Default::default()
                },
            }
        };
        let compute_field = |opts: &FieldOptions| {
            let t0 = Instant::now();
            let field = OrientationField::compute_with(&surface, &settings.orientation, opts)
                .map_err(|e| Error::invalid(format!("orientation field for {mesh_label}: {e:#}")));
            (field, t0.elapsed().as_secs_f64())
        };
        // The texel frames need only the field, the surface and the layout. For the jump
        // method they follow the field in its branch, so that they share the cores with the
        // texel side's serial growth order instead of waiting for it (bunny N = 16: ~0.3 s
        // of two cores that ran after the join). Coherent synthesis builds its texel graph
        // there instead, in parallel, and frames beside it only raised its peak (bunny
        // +52 MiB): its frames wait for the join, as before.
        let early_frames = method == Some(Method::Jump);
        let field_and_frames = |opts: &FieldOptions, frames: bool| {
            let (field, field_s) = compute_field(opts);
            let t0 = Instant::now();
            let both = field.map(|f| {
                let frames =
                    frames.then(|| crate::texel_frames::layout_frames(&f, &surface, &layout));
                (f, frames)
            });
            (both, field_s + t0.elapsed().as_secs_f64())
        };
        let early = settings.orientation != Orientation::Straight;
        // On a uniform layout the early frames do not evaluate the surface again: the
        // geometry pass keeps the exact normals in the frames' array, and the frames are
        // made from them where the field's branch and the texel side meet (`FrameMeet`).
        // Coherent synthesis meets there too (its frames were the second evaluation,
        // after the join: ~8% of a bunny run's CPU); the slots, the frames' own array, are
        // then held beside its texel graph's making, whose lists are built in blocks to
        // leave room for them (docs/benchmarks.md, "The bunny's coherent run, sixth
        // session").
        let meet_frames = early_frames || method == Some(Method::Coherent);
        let meet = (early && meet_frames && layout.uniform_n().is_some())
            .then(|| FrameMeet::new(&surface));
        // Multiscale and textons sample their patterns along a finer field than the
        // prepared one ([`Session::field_for`]); named here, it is computed beside the
        // prepared field and the texel side instead of alone at the start of the synthesis
        // (Spot N = 32: ~0.5 s, much of it one core's work). The same call as
        // `field_for`'s (the structure length it passes is read by `straight` only, which
        // is not early): the same field.
        let fine_early = early
            && matches!(method, Some(Method::Multiscale | Method::Textons))
            && crate::field::planned_level(&surface, &settings.orientation, &options_at(None))
                < fine_level(&surface);
        let (early_field, texel_side) = rayon::join(
            || {
                let prepared = || {
                    early.then(|| match &meet {
                        Some(meet) => {
                            meet.field_ready(compute_field(&options_at(None)));
                            None
                        }
                        None => Some(field_and_frames(&options_at(None), early_frames)),
                    })
                };
                if !fine_early {
                    return (prepared(), None);
                }
                let t0 = Instant::now();
                let (f, fine) = rayon::join(prepared, || {
                    OrientationField::compute_with(
                        &surface,
                        &settings.orientation,
                        &field_options(1.0, unit),
                    )
                    .ok()
                });
                (f, fine.map(|fine| (fine, t0.elapsed().as_secs_f64())))
            },
            || {
                let t0 = Instant::now();
                let (geometry, slots) = match &meet {
                    Some(_) => {
                        let (g, s) =
                            TexelGeometry::compute_keeping_normals(&surface, layout.clone());
                        (g, Some(s))
                    }
                    None => (
                        TexelGeometry::compute_layout(&surface, layout.clone()),
                        None,
                    ),
                };
                let geometry_s = t0.elapsed().as_secs_f64();
                if let (Some(meet), Some(slots)) = (&meet, slots) {
                    meet.slots_ready(slots);
                }
                let spacing = geometry.median_spacing(&surface);
                let t0 = Instant::now();
                // The edge graph (floods, seams, the jump method's growth) is read by every
                // method but coherent synthesis: a session prepared for one coherent
                // synthesis (the one-shot builder's) goes without it (bunny N = 16: ~2% of
                // the run's CPU, on the texel side's path to the texel graph).
                let edges = match method {
                    Some(Method::Coherent) => None,
                    _ => Some(EdgeGraph::build(&surface, &geometry)),
                };
                let (growth, graph) = match method {
                    Some(Method::Jump) => (
                        Some(crate::synth::jump::Growth::compute(
                            edges.as_ref().expect("built for every method but coherent"),
                            &geometry.layout,
                            &geometry.pos,
                        )),
                        None,
                    ),
                    Some(Method::Coherent) => (None, Some(TexelGraph::build(&surface, &geometry))),
                    _ => (None, None),
                };
                let graph_s = t0.elapsed().as_secs_f64();
                (geometry, geometry_s, spacing, edges, growth, graph, graph_s)
            },
        );
        let (geometry, geometry_s, spacing, edges, growth, graph, mut graph_s) = texel_side;
        let (early_field, fine_field) = early_field;
        let early_field = match (early_field, meet) {
            (Some(None), Some(meet)) => Some(meet.into_field_and_frames()),
            (f, _) => f.flatten(),
        };
        report(Stage::Geometry, faces, faces);

        let (scale, scale_source) = match settings.scale {
            Some(s) => (s / unit, "given"),
            None => (spacing, "median texel spacing"),
        };
        if !(scale.is_finite() && scale > 0.0) {
            return Err(Error::invalid(format!(
                "{mesh_label}: the surface is degenerate (median texel spacing {scale}); pass --scale"
            )));
        }

        report(Stage::Field, 0, 1);
        // `straight` wants the field straight over half of pf8's window (BRIEF).
        let (field, mut field_s) = match early_field {
            Some(f) => f,
            None => field_and_frames(&options_at(Some(scale)), false),
        };
        let (field, frames) = field?;
        // The field stage lasted as long as the finer field beside it, when there was one.
        let fine_field = fine_field
            .filter(|(f, _)| f.level() > field.level())
            .map(|(f, s)| {
                field_s = field_s.max(s);
                f
            });
        let t0 = Instant::now();
        let frames =
            frames.unwrap_or_else(|| crate::texel_frames::layout_frames(&field, &surface, &layout));
        // The scale map is interpolated with the field (both are mesh-side data).
        let scale_field = match &settings.scale_map {
            None => None,
            Some(m) => Some(Arc::new(ScaleField::compute(&surface, m, unit)?)),
        };
        field_s += t0.elapsed().as_secs_f64();
        report(Stage::Field, 1, 1);

        report(Stage::Graph, 0, 1);
        let t0 = Instant::now();
        // The edge graph (floods, seams) is built above; the texel graph by the methods that
        // read it, on first use (coherent synthesis's above, when named).
        let texels = LevelTexels::from_built(geometry, frames, scale, edges, graph)
            .with_scale(&surface, scale_field.as_deref());
        let derived = Derived::default();
        if let Some(growth) = growth {
            derived.jump_plan_from(&texels, growth);
        }
        graph_s += t0.elapsed().as_secs_f64();
        report(Stage::Graph, 1, 1);

        Ok(Session {
            mesh_label,
            resolution: n,
            layout,
            texel_size: settings.texel_size,
            n_depth,
            orientation: settings.orientation.clone(),
            surface: Arc::new(surface),
            field,
            fine_field: fine_field.map_or_else(OnceLock::new, OnceLock::from),
            texels,
            derived,
            spacing,
            scale,
            scale_source,
            scale_field,
            unit,
            user_control,
            user: OnceLock::new(),
            extent,
            size,
            seconds: PrepareSeconds {
                load: load_seconds,
                geometry: geometry_s,
                field: field_s,
                graph: graph_s,
            },
            analyses,
            progress,
        })
    }

    /// Shares `analyses` (per-example analysis kept in memory and its cache folder) with
    /// other sessions or builders of this process.
    pub fn with_analyses(mut self, analyses: Arc<Analyses>) -> Self {
        self.analyses = analyses;
        self
    }

    /// Progress callback of later syntheses (see [`Progress`]).
    pub fn on_progress(mut self, f: impl Fn(Stage, usize, usize) + Send + Sync + 'static) -> Self {
        self.progress = Some(Arc::new(f));
        self
    }

    /// The per-example analyses this session keeps.
    pub fn analyses(&self) -> &Arc<Analyses> {
        &self.analyses
    }

    /// Seconds the preparation took, per stage.
    pub fn prepare_seconds(&self) -> PrepareSeconds {
        self.seconds
    }

    /// Face domains.
    pub fn faces(&self) -> usize {
        self.surface.num_domains()
    }

    /// Where every texel is (one N, or per-face resolutions).
    pub fn layout(&self) -> &Arc<TexelLayout> {
        &self.layout
    }

    /// Texels of every synthesis (domains × N², or the per-face layout's total).
    pub fn texels(&self) -> usize {
        self.texels.len()
    }

    /// Computes now what `method` derives from the mesh on its first use (the jump
    /// method's region-growing order, coherent synthesis's texel graph), so that no
    /// synthesis pays for it; returns the seconds it took. The one-shot builder calls it
    /// in its graph stage.
    pub fn prepare_method(&self, method: Method) -> f64 {
        let t0 = Instant::now();
        if method == Method::Jump {
            self.derived.jump_plan(&self.texels);
        }
        if method == Method::Coherent {
            self.texels.graph(&self.surface);
        }
        t0.elapsed().as_secs_f64()
    }

    /// The orientation field `method` runs on. Multiscale and textons sample neighbourhood
    /// patterns along the field at every texel and compare them between neighbours: they
    /// get the field at the finest level within the face budget, as before the field was
    /// sized by the texel count (on a level-3 or level-4 field their double torus pf4 rose
    /// 0.092–0.099 → 0.105–0.109 over seeds 1–3, docs/field.md). Every other method gets
    /// the prepared field.
    fn field_for(&self, method: Method) -> Result<&OrientationField> {
        if !matches!(method, Method::Multiscale | Method::Textons) {
            return Ok(&self.field);
        }
        if self.field.level() >= fine_level(&self.surface) {
            return Ok(&self.field);
        }
        if let Some(f) = self.fine_field.get() {
            return Ok(f);
        }
        let f = OrientationField::compute_with(
            &self.surface,
            &self.orientation,
            &field_options(self.scale, self.unit),
        )
        .map_err(|e| Error::invalid(format!("orientation field for {}: {e:#}", self.mesh_label)))?;
        Ok(self.fine_field.get_or_init(|| f))
    }

    /// Synthesizes `example` with `params` on the prepared mesh. The result's report has
    /// zero seconds for the prepared stages (load, geometry, field, graph: see
    /// [`Session::prepare_seconds`]) and its total counts from this call.
    pub fn synthesize(&self, example: &Example, params: &SynthParams) -> Result<SynthResult> {
        let label = if example.path.as_os_str().is_empty() {
            "<in memory>".to_string()
        } else {
            example.path.display().to_string()
        };
        // As the one-shot run names it: the height map's file.
        let height = example
            .map(crate::example::HEIGHT)
            .filter(|m| !m.path.as_os_str().is_empty())
            .map(|m| m.path.display().to_string());
        self.run(
            example.clone(),
            params,
            Labels {
                example: label,
                height,
            },
            Instant::now(),
            PrepareSeconds::default(),
        )
    }

    /// The synthesis stages (synthesis, maps) and the report: one code path for sessions
    /// and one-shot runs. `started` and `seconds` are what the report counts as the run's
    /// start and its preparation.
    pub(super) fn run(
        &self,
        example: Example,
        params: &SynthParams,
        labels: Labels,
        started: Instant,
        seconds: PrepareSeconds,
    ) -> Result<SynthResult> {
        let mut s = self.synthesis(&example, params, &labels)?;
        s.tangents = self.tangents();
        Ok(self.finish(example, params, labels, s, started, seconds))
    }

    /// [`Session::run`] for the one-shot builder: the session is used once, so what only
    /// synthesis needs (texel graphs, frames, derived orders) is freed before the maps are
    /// built — the maps stage then holds the texel geometry, the sources and the maps.
    pub(super) fn run_once(
        mut self,
        example: Example,
        params: &SynthParams,
        labels: Labels,
        started: Instant,
        seconds: PrepareSeconds,
    ) -> Result<SynthResult> {
        let mut s = self.synthesis(&example, params, &labels)?;
        self.texels.drop_graph();
        self.texels.drop_edges();
        drop(std::mem::take(&mut self.derived));
        // The tangents are taken from the frames once the graphs and orders are gone (not
        // beside them at the end of the synthesis stage: 12 B per texel off its peak).
        s.tangents = self.tangents();
        drop(std::mem::take(&mut self.texels.frames));
        Ok(self.finish(example, params, labels, s, started, seconds))
    }

    /// The requested local scale per texel, user units (geometry.exr `scale`): the global
    /// scale × the scale map's factor; `None` without a scale map.
    fn local_scale(&self) -> Option<Vec<f32>> {
        let f = self.texels.factor.as_ref()?;
        let s = self.scale * self.unit;
        Some(f.par_iter().map(|&k| (s * k) as f32).collect())
    }

    /// The scale map's interpolated factor, when the session has one.
    pub fn scale_field(&self) -> Option<&ScaleField> {
        self.scale_field.as_deref()
    }

    /// The field's v1 per texel (geometry.exr `T.X T.Y T.Z`: unit directions, the same in
    /// the user's units).
    fn tangents(&self) -> Vec<[f32; 3]> {
        self.texels
            .frames
            .par_iter()
            .map(|f| f[0].to_array())
            .collect()
    }

    /// The synthesis stage: source positions and what the method reports.
    fn synthesis(
        &self,
        example: &Example,
        params: &SynthParams,
        labels: &Labels,
    ) -> Result<Synthesized> {
        let progress = |s: Stage, d: usize, t: usize| {
            if let Some(p) = &self.progress {
                p(s, d, t)
            }
        };
        let settings = &params.settings;
        let n = self.resolution;
        let faces = self.faces();
        settings.weights.check(example)?;
        let has_height = example.height_map().is_some();
        if params.displace.is_some() && !has_height {
            return Err(Error::invalid(format!(
                "--displace needs a height channel, and {} has none: pass --height H.png",
                labels.example
            )));
        }
        if let Some(a) = params.displace {
            crate::memory::check_displace(&self.mesh_label, a, self.extent)?;
        }
        // This run's memory (the method and the example decide it; the mesh part was
        // checked when it was prepared). A BTF sample counts the pixels of all its images.
        let example_pixels = match &settings.btf {
            Some(b) => b.width * b.height * b.images.len(),
            None => example.width * example.height,
        };
        // (+ the height alias channel of facemaps.exr, + source.u source.v)
        let job = Job::Synth {
            channels: example.num_channels() + has_height as usize + 2,
            example_pixels,
            method: settings.method,
            displace: params.displace.is_some(),
            scale_map: self.scale_field.is_some(),
        };
        let memory_estimate = match self.texel_size {
            None => {
                let e = crate::memory::estimate(&self.size, n, &job);
                crate::memory::check(&self.mesh_label, n, &job, &e)?;
                e.bytes
            }
            Some(_) => {
                crate::memory::check_layout(
                    &self.mesh_label,
                    &self.surface.control,
                    &self.layout,
                    &job,
                )?;
                crate::memory::estimate_texels(
                    &self.size,
                    &crate::memory::TexelCount::of_layout(&self.layout),
                    &job,
                )
                .bytes
            }
        };

        progress(Stage::Synthesis, 0, faces);
        let t0 = Instant::now();
        // The synthesizers lay image rows along −v2 (Handedness::Outside); for Tiles they
        // get the example upside down, and the sources are turned back below.
        let flipped;
        let synth_example = match params.handedness {
            Handedness::Outside => example,
            Handedness::Tiles => {
                flipped = example.flipped_rows();
                &flipped
            }
        };
        // A BTF sample ([`Settings::btf`]) is turned as the example is.
        let btf_settings;
        let settings = match (&settings.btf, params.handedness) {
            (Some(b), Handedness::Tiles) => {
                let mut s = settings.clone();
                s.btf = Some(Arc::new(b.flipped_rows()));
                btf_settings = s;
                &btf_settings
            }
            _ => settings,
        };
        let target = Target {
            surface: &self.surface,
            field: self.field_for(settings.method)?,
            texels: &self.texels,
            spacing: self.spacing,
            seed: params.seed,
            derived: &self.derived,
            scale_field: self.scale_field.as_deref(),
        };
        // Analyses built for this synthesis (a first run with a large example can spend
        // minutes there) show as their own stage, then the domains go on.
        if let Some(p) = &self.progress {
            let p = p.clone();
            self.analyses
                .set_progress(Some(Arc::new(move |d, t| p(Stage::Analysis, d, t))));
        }
        let out =
            crate::synth::synthesize(synth_example, &target, settings, &self.analyses, &|d, t| {
                progress(Stage::Synthesis, d * faces / t.max(1), faces)
            });
        self.analyses.set_progress(None);
        let out = out?;
        let cache = self.analyses.report(self.analyses.take_events());
        let mut source = out.source;
        let mut blend = out.blend;
        if params.handedness == Handedness::Tiles {
            let h = example.height as f32;
            for s in &mut source {
                s[1] = h - s[1];
            }
            if let Some(b) = &mut blend {
                b.flip_v(h);
            }
        }
        let synthesis_s = t0.elapsed().as_secs_f64();
        Ok(Synthesized {
            source,
            blend,
            // Filled by the caller (run, run_once), which decides what is held beside them.
            tangents: Vec::new(),
            local_scale: self.local_scale(),
            appearance: out.appearance,
            details: out.details,
            cache,
            seconds: synthesis_s,
            memory_estimate,
        })
    }

    /// The maps stage and the report.
    fn finish(
        &self,
        example: Example,
        params: &SynthParams,
        labels: Labels,
        s: Synthesized,
        started: Instant,
        seconds: PrepareSeconds,
    ) -> SynthResult {
        let progress = |st: Stage, d: usize, t: usize| {
            if let Some(p) = &self.progress {
                p(st, d, t)
            }
        };
        let settings = &params.settings;
        let faces = self.faces();
        let layout = &self.layout;
        // Written in the user's units (positions, normals, displacement).
        let (surface, geometry) = if self.unit != 1.0 {
            let (s, g) = self.user.get_or_init(|| {
                let s = match &self.user_control {
                    Some(c) => crate::memory::build_surface(c.clone(), self.n_depth),
                    None => unreachable!("kept when unit != 1"),
                };
                let g = TexelGeometry::compute_layout(&s, layout.clone());
                (Arc::new(s), Arc::new(g))
            });
            (s.clone(), g.clone())
        } else {
            (self.surface.clone(), self.texels.geometry.clone())
        };
        let (scale, spacing) = (self.scale * self.unit, self.spacing * self.unit);

        progress(Stage::Maps, 0, 1);
        let t0 = Instant::now();
        let mut maps =
            crate::synth::face_maps_blended(&example, &s.source, s.blend.as_ref(), layout);
        drop(s.source);
        drop(s.blend);
        // facemaps.exr keeps the normal map in the field's frame (T, N x T, N): the file's
        // green axis is image up, which is +v2 when rows run along -v2 (outside) and -v2
        // for tiles; DirectX files have green pointing down.
        let flip_green = (params.handedness == Handedness::Tiles)
            != (params.normal_convention == NormalConvention::DirectX);
        if flip_green {
            if let Some(g) = maps.channel_mut("normal.G") {
                g.par_iter_mut().for_each(|v| *v = 1.0 - *v);
            }
        }
        let maps_s = t0.elapsed().as_secs_f64();
        progress(Stage::Maps, 1, 1);

        let mut report = Report {
            tool: "surfsynth".into(),
            version: env!("CARGO_PKG_VERSION").into(),
            inputs: Inputs {
                mesh: self.mesh_label.clone(),
                example: labels.example,
                height: labels.height,
                // `--btf` (what `render --light` shades with): the sample's btf.json,
                // absolute; none for a sample made in memory.
                btf: settings
                    .btf
                    .as_ref()
                    .filter(|b| !b.path.as_os_str().is_empty())
                    .map(|b| {
                        std::path::absolute(&b.path)
                            .unwrap_or_else(|_| b.path.clone())
                            .display()
                            .to_string()
                    }),
                maps: example
                    .maps
                    .iter()
                    .map(|m| crate::report::MapInfo {
                        name: m.name.clone(),
                        file: m.path.display().to_string(),
                        kind: m.kind,
                        channels: m.channels,
                        weight: settings.weights.map(&m.name),
                    })
                    .collect(),
                normal_convention: example
                    .map(crate::example::NORMAL)
                    .map(|_| params.normal_convention),
            },
            method: settings.method,
            seed: params.seed,
            scale,
            scale_source: self.scale_source.into(),
            scale_map: self.scale_field.as_ref().map(|f| f.info(scale)),
            texel_spacing: spacing,
            resolution: layout
                .uniform_n()
                .unwrap_or(layout.max_dims().0.max(layout.max_dims().1)),
            texel_size: self.texel_size,
            orientation: orientation_label(&self.orientation),
            orientation_choice: self.field.choice().map(|c| match &c.why {
                crate::field::Why::Straightest { scores, length } => {
                    crate::report::OrientationChoice {
                        chosen: c.chosen.clone(),
                        structure_length: Some(length * self.unit),
                        bent_fraction: scores.clone(),
                        level_fraction: None,
                    }
                }
                crate::field::Why::Level { fraction } => crate::report::OrientationChoice {
                    chosen: c.chosen.clone(),
                    structure_length: None,
                    bent_fraction: Vec::new(),
                    level_fraction: Some(*fraction),
                },
            }),
            faces,
            control_faces: surface.control.mesh.num_faces(),
            texels: layout.len() as u64,
            example: ExampleInfo {
                width: example.width,
                height: example.height,
                channels: example
                    .channel_names()
                    .iter()
                    .map(|s| s.to_string())
                    .collect(),
            },
            channels: maps.names().iter().map(|s| s.to_string()).collect(),
            weights: settings.weights.clone(),
            appearance: s.appearance,
            details: s.details,
            threads: rayon::current_num_threads(),
            displace: params.displace,
            handedness: params.handedness,
            seconds: Seconds {
                load: seconds.load,
                geometry: seconds.geometry,
                field: seconds.field,
                graph: seconds.graph,
                synthesis: s.seconds,
                maps: maps_s,
                write: 0.0,
                pf: 0.0,
                total: started.elapsed().as_secs_f64(),
            },
            texels_per_second: 0.0,
            synthesis_texels_per_second: 0.0,
            peak_memory_bytes: None,
            memory_estimate_bytes: Some(s.memory_estimate),
            patch_fidelity: None,
            cache: s.cache,
        };
        report.update_rates();
        SynthResult {
            maps,
            geometry,
            tangents: s.tangents,
            local_scale: s.local_scale,
            handedness: params.handedness,
            surface,
            example,
            report,
            displace: params.displace,
            write_options: params.write_options,
            started,
        }
    }
}

/// What the synthesis stage hands to the maps stage.
struct Synthesized {
    source: Vec<[f32; 2]>,
    /// Extra sources mixed into some texels' values ([`crate::synth::Blend`]).
    blend: Option<crate::synth::Blend>,
    /// The field's v1 per texel (taken while the frames are there: a one-shot run frees
    /// them before the maps stage).
    tangents: Vec<[f32; 3]>,
    /// geometry.exr's `scale` (with a scale map).
    local_scale: Option<Vec<f32>>,
    appearance: crate::synth::matching::appearance::AppearanceInfo,
    details: crate::synth::Details,
    cache: crate::synth::analysis::CacheReport,
    seconds: f64,
    /// The memory guard's estimate for this run (bytes).
    memory_estimate: u64,
}

/// How the report names the example and the height map.
pub(super) struct Labels {
    pub example: String,
    pub height: Option<String>,
}

/// The field options of a prepared mesh whose scale is `scale` (working units) and whose
/// user mesh was divided by `unit`: `straight` wants the field straight over half of pf8's
/// window (BRIEF).
fn field_options(scale: f64, unit: f64) -> FieldOptions {
    FieldOptions {
        structure_length: Some(crate::field::STRUCTURE_PIXELS * scale),
        unit,
        ..Default::default()
    }
}

/// Where the field's branch and the texel side of [`Session::from_loaded`] meet for the
/// jump method's frames: each leaves its part (the field; the geometry's [`FrameSlots`]),
/// and whichever arrives second turns the slots into frames. Neither waits for the other.
/// The geometry usually finishes first (bunny N = 16: 0.5 s against the field's 1.25 s),
/// so the field's branch makes the frames beside the growth order, as it did when it
/// evaluated them itself; with one thread the field comes first and the texel side makes
/// them before the edge graph. Either way the same frames
/// ([`crate::synth::frames_from_slots`]).
struct FrameMeet<'a> {
    surface: &'a Surface,
    /// The field's result and its seconds.
    field: OnceLock<(Result<OrientationField>, f64)>,
    /// Whether one side has arrived, and the slots once the texel side has.
    state: Mutex<(bool, Option<FrameSlots>)>,
    /// The frames and their seconds (none when the field failed).
    frames: OnceLock<(Vec<[Vec3; 2]>, f64)>,
}

impl<'a> FrameMeet<'a> {
    fn new(surface: &'a Surface) -> Self {
        FrameMeet {
            surface,
            field: OnceLock::new(),
            state: Mutex::new((false, None)),
            frames: OnceLock::new(),
        }
    }

    /// The field's branch arrives with the field.
    fn field_ready(&self, field: (Result<OrientationField>, f64)) {
        assert!(self.field.set(field).is_ok(), "one field");
        self.arrive(None);
    }

    /// The texel side arrives with the slots.
    fn slots_ready(&self, slots: FrameSlots) {
        self.arrive(Some(slots));
    }

    /// The second arrival makes the frames (outside the lock: the first has left).
    fn arrive(&self, slots: Option<FrameSlots>) {
        let slots = {
            let mut state = self.state.lock().unwrap_or_else(|e| e.into_inner());
            if slots.is_some() {
                state.1 = slots;
            }
            if !state.0 {
                state.0 = true;
                return;
            }
            state.1.take().expect("the texel side left its slots")
        };
        if let Some((Ok(field), _)) = self.field.get() {
            let t0 = Instant::now();
            let frames = crate::texel_frames::frames_from_slots(field, self.surface, slots);
            let _ = self.frames.set((frames, t0.elapsed().as_secs_f64()));
        }
    }

    /// What the field's branch returns without the meeting: the field with its frames,
    /// and the seconds of both. Both sides must have arrived.
    #[allow(clippy::type_complexity)]
    fn into_field_and_frames(self) -> (Result<(OrientationField, Option<Vec<[Vec3; 2]>>)>, f64) {
        let (field, field_s) = self.field.into_inner().expect("the field's branch arrived");
        let (frames, frames_s) = match self.frames.into_inner() {
            Some((f, s)) => (Some(f), s),
            None => (None, 0.0),
        };
        (field.map(|f| (f, frames)), field_s + frames_s)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn bits(v: &[[Vec3; 2]]) -> Vec<[u32; 6]> {
        v.iter()
            .map(|[a, b]| [a.x, a.y, a.z, b.x, b.y, b.z].map(f32::to_bits))
            .collect()
    }

    /// Whichever side arrives second makes the frames: the same frames either way, the
    /// evaluated ones; none when the field failed.
    #[test]
    fn frames_meet_in_either_order() {
        let surface = Surface::new(ControlMesh::cuboid(glam::DVec3::ZERO, glam::DVec3::ONE));
        let n = 5;
        let layout = Arc::new(TexelLayout::uniform(surface.num_domains(), n));
        let field = || OrientationField::compute(&surface, &Orientation::Auto).unwrap();
        let want = crate::synth::texel_frames_f32(&field(), &surface, n);
        for field_first in [true, false] {
            let meet = FrameMeet::new(&surface);
            let (_, slots) = TexelGeometry::compute_keeping_normals(&surface, layout.clone());
            if field_first {
                meet.field_ready((Ok(field()), 0.0));
                assert!(meet.frames.get().is_none());
                meet.slots_ready(slots);
            } else {
                meet.slots_ready(slots);
                assert!(meet.frames.get().is_none());
                meet.field_ready((Ok(field()), 0.0));
            }
            let (got, _) = meet.into_field_and_frames();
            let (_, frames) = got.unwrap();
            assert_eq!(
                bits(&frames.unwrap()),
                bits(&want),
                "field first: {field_first}"
            );
        }
        let meet = FrameMeet::new(&surface);
        meet.field_ready((Err(Error::invalid("no field")), 0.0));
        meet.slots_ready(TexelGeometry::compute_keeping_normals(&surface, layout).1);
        assert!(meet.into_field_and_frames().0.is_err());
    }
}
