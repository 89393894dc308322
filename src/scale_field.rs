//! Spatially varying scale: "progressively variant" textures (paper 001 §3.1 — the field's
//! "magnitude ... will be used to determine the local scale of the texture" — and §4.2).
//!
//! A *scale map* (`synth --scale-map FILE`, docs/formats.md) gives a factor at some control
//! vertices or surface points; the factor multiplies the global scale S (`--scale`, or the
//! median texel spacing), so the example pixel at a point of the surface covers
//! S × factor(point) of surface length: a factor 3 makes the texture three times as large
//! there. [`ScaleField`] interpolates the factors smoothly over the whole surface and every
//! synthesis method samples the example with that local step (`synth::footprint::LevelTexels`
//! holds it per texel).
//!
//! # How the factors are interpolated
//! In log space, so that factors multiply (halfway between 1 and 4 is 2, and a map and its
//! inverse give reciprocal textures), on a limit mesh of the surface (exact limit positions,
//! [`subdiv::LimitMesh`]: the finest level with at most [`MAX_FACES`] faces, level 2 on
//! Spot; the scale varies slowly, so that resolves it), with the constrained vertices held
//! at their log factors:
//! 1. **Harmonic start**: the minimiser of the Dirichlet energy `Σ w_ij (x_i − x_j)²` (L the
//!    cotangent Laplacian, averaged over both diagonals of every quad so that none is
//!    favoured), by Jacobi-preconditioned conjugate gradients. It is smooth between the
//!    constraints and stays within their range, but a harmonic function pinned at an
//!    isolated vertex has a logarithmic cusp there (point constraints have no capacity in
//!    2D): one `vertex 12 3` alone would make a small cone of large texture.
//! 2. **Thin-plate smoothing**: [`SMOOTHING_ITERATIONS`] conjugate-gradient steps on the
//!    biharmonic energy `Σ_i (L x)_i² / m_i` (m_i the vertex area) from that start — the
//!    mesh counterpart of the radial basis functions paper 001 §3.1 interpolates with. CG
//!    removes the cusps' high-frequency part in its first steps (measured: the one-sided
//!    slopes at an isolated pin fall from the steepest of the row to a fifth of it); run to
//!    convergence it needs thousands of steps (its condition number grows as h⁻⁴) for a
//!    change of the smooth part of well under 1%, so it is stopped there: the result is
//!    defined by the fixed step count, deterministic, and costs ~0.1 s.
//! 3. **Clamped** to the range of the given factors (thin-plate solutions can overshoot), so
//!    the texture never gets larger or smaller than asked.
//!
//! Inside the mesh's faces the log factor is blended bilinearly (as the orientation field,
//! [`crate::field`]). Sums run in a fixed order: the field does not depend on the thread
//! count. On an open boundary both energies' natural condition is a zero slope across it,
//! so a sheet constrained at two opposite edges ramps in a gentle S rather than a straight
//! line in log.
//!
//! Parts of the mesh (connected components) with no constraint keep factor 1 (the global
//! scale). A map whose factors are all equal (and reach every part) is that factor exactly,
//! everywhere — no interpolation, no rounding: `--scale-map` with `vertex 0 2` is
//! `--scale 2S` to the bit (tests/scale_map.rs).
//!
//! This module sits beside [`crate::field`]: it needs the surface only, and synthesis reads it.

use crate::error::{Error, Result};
use glam::DVec3;
use rayon::prelude::*;
use std::path::{Path, PathBuf};
use subdiv::{BaseLocation, DomainLocation, FaceId, LimitMesh, Surface};

/// geometry.exr channel of a run with a scale map: the requested local scale at each texel
/// (surface length per example pixel: the global scale × the factor, user units). `eval`
/// measures scale fidelity against it.
pub const CHANNEL: &str = "scale";

/// Largest ratio between the largest and the smallest factor. Beyond it the methods' single
/// resolution per synthesis level (multiscale, optimise) holds 16x more texels per example
/// pixel in one place than in another, and patches laid along the field stretch across too
/// much change of scale to stay whole.
pub const MAX_RATIO: f64 = 16.0;

/// Face budget of the interpolation mesh (the finest limit-mesh level within it is used).
pub const MAX_FACES: usize = 4096;

/// Conjugate-gradient iterations at most of the harmonic start.
const HARMONIC_ITERATIONS: usize = 4000;

/// Conjugate-gradient iterations of the thin-plate energy from the harmonic start (module
/// docs, step 2).
pub const SMOOTHING_ITERATIONS: usize = 400;

/// Relative residual at which a level's solve stops.
const TOLERANCE: f64 = 1e-10;

/// A point constraint farther than this fraction of the bounding-box diagonal from the
/// nearest vertex of the interpolation mesh is refused (it is not on the surface).
const POINT_DISTANCE: f64 = 0.05;

/// Where a constraint applies.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum At {
    /// A control vertex (0-based, OBJ `v` order).
    Vertex(usize),
    /// A point on (or near) the surface, in the mesh's units; it acts on the nearest vertex
    /// of the interpolation mesh.
    Point(DVec3),
}

/// One line of a scale map.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Constraint {
    pub at: At,
    /// Finite, > 0: multiplies the global scale.
    pub factor: f64,
    /// 1-based line in the file (0 when not from a file).
    pub line: usize,
}

/// Where a scale map's factors were read from (report.json `scale_map.from`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum ScaleSource {
    /// A scale map file (`--scale-map FILE`), or constraints made in memory.
    #[default]
    ScaleMap,
    /// The lengths of the `vertex I DX DY DZ` directions of an orientation constraints file
    /// (`--orient FILE --scale-from-orient`; 001 §3.1: the field's "magnitude ... will be
    /// used to determine the local scale").
    OrientLengths,
}

impl ScaleSource {
    /// What its numbers are called in messages.
    fn noun(self) -> (&'static str, &'static str) {
        match self {
            ScaleSource::ScaleMap => ("factor", "factors"),
            ScaleSource::OrientLengths => ("direction length", "direction lengths"),
        }
    }
}

/// A parsed scale map (format in docs/formats.md).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ScaleMap {
    pub constraints: Vec<Constraint>,
    /// The file read (for messages and the report).
    pub path: Option<PathBuf>,
    /// What the file was: a scale map, or orientation constraints whose lengths are the
    /// factors.
    pub source: ScaleSource,
}

/// What report.json records of a scale map (`scale_map`).
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct ScaleMapInfo {
    /// The file, as given.
    pub file: String,
    /// What it is: `scale_map` (`--scale-map`) or `orient_lengths` (the lengths of an
    /// orientation constraints file's `vertex` directions, `--scale-from-orient`).
    pub from: ScaleSource,
    /// `vertex` and `point` lines.
    pub vertices: usize,
    pub points: usize,
    /// Smallest and largest factor over the surface (the given ones, and 1 where a part of
    /// the mesh has no constraint).
    pub min_factor: f64,
    pub max_factor: f64,
    /// The same as local scales: surface length per example pixel, user units.
    pub min_scale: f64,
    pub max_scale: f64,
    /// Limit-mesh level the factors were interpolated on (0: constant, no interpolation).
    pub level: u32,
    /// Parts of the mesh with no constraint (factor 1 there).
    pub unconstrained_parts: usize,
}

impl ScaleMap {
    /// Reads a scale map; errors are one line naming the file (and line).
    pub fn load(path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path)
            .map_err(|e| Error::io(path, "cannot read scale map", e))?;
        let mut m = Self::parse(&text).map_err(|e| Error::file(path, e))?;
        m.path = Some(path.to_path_buf());
        Ok(m)
    }

    /// Parses the text of a scale map; the error is "line N: problem".
    pub fn parse(text: &str) -> std::result::Result<Self, String> {
        let mut m = ScaleMap::default();
        for (ln, raw) in text.lines().enumerate() {
            let line = ln + 1;
            let body = raw.split('#').next().unwrap_or("").trim();
            if body.is_empty() {
                continue;
            }
            let mut it = body.split_whitespace();
            let key = it.next().unwrap_or("");
            let args: Vec<&str> = it.collect();
            let num = |s: &str| -> std::result::Result<f64, String> {
                let v: f64 = s
                    .parse()
                    .map_err(|_| format!("line {line}: '{s}' is not a number"))?;
                if !v.is_finite() {
                    return Err(format!("line {line}: '{s}' is not a finite number"));
                }
                Ok(v)
            };
            let factor = |s: &str| -> std::result::Result<f64, String> {
                let f = s
                    .parse::<f64>()
                    .map_err(|_| format!("line {line}: factor '{s}' is not a number"))?;
                if !(f.is_finite() && f > 0.0) {
                    return Err(format!(
                        "line {line}: factor {s} must be a finite number > 0 (it multiplies the scale)"
                    ));
                }
                Ok(f)
            };
            let c = match key {
                "vertex" | "v" => {
                    if args.len() != 2 {
                        return Err(format!(
                            "line {line}: expected `vertex INDEX FACTOR`, got `{body}`"
                        ));
                    }
                    let i: usize = args[0].parse().map_err(|_| {
                        format!(
                            "line {line}: vertex index '{}' is not a whole number",
                            args[0]
                        )
                    })?;
                    Constraint {
                        at: At::Vertex(i),
                        factor: factor(args[1])?,
                        line,
                    }
                }
                "point" | "p" => {
                    if args.len() != 4 {
                        return Err(format!(
                            "line {line}: expected `point X Y Z FACTOR`, got `{body}`"
                        ));
                    }
                    Constraint {
                        at: At::Point(DVec3::new(num(args[0])?, num(args[1])?, num(args[2])?)),
                        factor: factor(args[3])?,
                        line,
                    }
                }
                other => {
                    return Err(format!(
                        "line {line}: unknown keyword '{other}' (expected vertex or point)"
                    ))
                }
            };
            m.push(c)?;
        }
        if m.constraints.is_empty() {
            return Err(
                "has no constraints (expected `vertex INDEX FACTOR` or `point X Y Z FACTOR` lines)"
                    .into(),
            );
        }
        m.check_ratio()?;
        Ok(m)
    }

    /// Adds `c`, refusing a vertex given a different factor on an earlier line.
    fn push(&mut self, c: Constraint) -> std::result::Result<(), String> {
        if let At::Vertex(i) = c.at {
            if let Some(o) = self
                .constraints
                .iter()
                .find(|o| o.at == At::Vertex(i) && o.factor != c.factor)
            {
                return Err(format!(
                    "line {}: vertex {i} has {} {} here and {} on line {}",
                    c.line,
                    self.source.noun().0,
                    c.factor,
                    o.factor,
                    o.line
                ));
            }
        }
        self.constraints.push(c);
        Ok(())
    }

    /// Refuses factors more than [`MAX_RATIO`] apart.
    fn check_ratio(&self) -> std::result::Result<(), String> {
        let (lo, hi) = self.extremes();
        if hi.factor / lo.factor > MAX_RATIO {
            return Err(format!(
                "{} {} (line {}) and {} (line {}) are {:.3}x apart; at most {MAX_RATIO}x is supported",
                self.source.noun().1,
                lo.factor,
                lo.line,
                hi.factor,
                hi.line,
                hi.factor / lo.factor
            ));
        }
        Ok(())
    }

    /// The scale map an orientation constraints file implies (`--scale-from-orient`): each
    /// `vertex I DX DY DZ` line's length |d| is vertex I's factor, exactly as a scale-map
    /// line `vertex I |d|` would be (001 §3.1 takes the local scale from the magnitude of
    /// the direction field a user draws; here the user's pinned directions are that field's
    /// samples). `sink`, `source` and `axis` lines carry no scale. The same checks as a scale
    /// map's: lengths finite (zero lengths are refused by the constraints parser already), a
    /// vertex given two lengths, at most [`MAX_RATIO`] between the largest and smallest.
    pub fn from_orientation(c: &crate::field::Constraints) -> Result<Self> {
        let mut m = ScaleMap {
            constraints: Vec::with_capacity(c.vertices.len()),
            path: c.path.clone(),
            source: ScaleSource::OrientLengths,
        };
        let at = m.at();
        for (k, &(i, _)) in c.vertices.iter().enumerate() {
            let line = c.vertex_lines.get(k).copied().unwrap_or(0);
            let len = c.vertex_lengths.get(k).copied().unwrap_or(1.0);
            if !(len.is_finite() && len > 0.0) {
                return Err(Error::invalid(format!(
                    "{at}line {line}: direction length {len} of vertex {i} must be a finite number > 0 (--scale-from-orient takes it as the scale factor)"
                )));
            }
            m.push(Constraint {
                at: At::Vertex(i),
                factor: len,
                line,
            })
            .map_err(|e| Error::invalid(format!("{at}{e}")))?;
        }
        if m.constraints.is_empty() {
            return Err(Error::invalid(format!(
                "{at}has no `vertex INDEX DX DY DZ` lines, so --scale-from-orient has no lengths to take the scale from"
            )));
        }
        m.check_ratio()
            .map_err(|e| Error::invalid(format!("{at}{e}")))?;
        Ok(m)
    }

    /// [`ScaleMap::from_orientation`] of the constraints file at `path`; errors are one line
    /// naming the file (and line).
    pub fn load_orientation(path: &Path) -> Result<Self> {
        let c =
            crate::field::Constraints::load(path).map_err(|e| Error::invalid(format!("{e:#}")))?;
        Self::from_orientation(&c)
    }

    /// The constraints with the smallest and the largest factor (first of equals).
    fn extremes(&self) -> (Constraint, Constraint) {
        let mut lo = self.constraints[0];
        let mut hi = lo;
        for &c in &self.constraints {
            if c.factor < lo.factor {
                lo = c;
            }
            if c.factor > hi.factor {
                hi = c;
            }
        }
        (lo, hi)
    }

    /// "FILE: " for messages ("" for a map made in memory).
    fn at(&self) -> String {
        self.path
            .as_ref()
            .map_or(String::new(), |p| format!("{}: ", p.display()))
    }

    /// The file as given, or `<in memory>`.
    pub fn label(&self) -> String {
        self.path
            .as_ref()
            .map_or("<in memory>".into(), |p| p.display().to_string())
    }

    /// Refuses vertex indices the mesh (of `vertices` control vertices) does not have, and
    /// a map without constraints; one line naming the file and line.
    pub fn check(&self, vertices: usize) -> Result<()> {
        if self.constraints.is_empty() {
            return Err(Error::invalid(format!(
                "{}scale map has no constraints",
                self.at()
            )));
        }
        for c in &self.constraints {
            if let At::Vertex(i) = c.at {
                if i >= vertices {
                    return Err(Error::invalid(format!(
                        "{}line {}: vertex {i}, but the mesh has {vertices} vertices (0-based)",
                        self.at(),
                        c.line
                    )));
                }
            }
        }
        Ok(())
    }
}

/// The interpolated factor over the surface (module docs).
#[derive(Clone, Debug)]
pub struct ScaleField {
    /// All factors equal (and every part constrained): exactly this everywhere.
    constant: Option<f64>,
    /// The interpolation mesh and the log factor at each of its vertices.
    mesh: Option<LimitMesh>,
    log: Vec<f64>,
    min: f64,
    max: f64,
    unconstrained_parts: usize,
    label: String,
    counts: (usize, usize),
    from: ScaleSource,
}

impl ScaleField {
    /// Interpolates `map` over `surface`. `unit`: the surface is the user's mesh divided by
    /// it (points are in the user's units and are divided by it too).
    pub fn compute(surface: &Surface, map: &ScaleMap, unit: f64) -> Result<Self> {
        map.check(surface.control.mesh.num_vertices())?;
        let unit = if unit.is_finite() && unit > 0.0 {
            unit
        } else {
            1.0
        };
        let counts = (
            map.constraints
                .iter()
                .filter(|c| matches!(c.at, At::Vertex(_)))
                .count(),
            map.constraints
                .iter()
                .filter(|c| matches!(c.at, At::Point(_)))
                .count(),
        );
        let mut level = 1u32;
        while surface.num_base_quads() << (2 * level) <= MAX_FACES && level < 8 {
            level += 1;
        }
        let (lo_c, hi_c) = map.extremes();
        let (lo, hi) = (lo_c.factor.ln(), hi_c.factor.ln());
        // Constraints on vertices of the finest level (points: nearest vertex).
        let finest = surface.limit_mesh(level);
        let (bmin, bmax) = surface.bounds();
        let diag = (bmax - bmin).length();
        let targets = |lm: &LimitMesh, check: bool| -> Result<Vec<(usize, f64)>> {
            let mut v = Vec::with_capacity(map.constraints.len());
            for c in &map.constraints {
                let i = match c.at {
                    At::Vertex(i) => i,
                    At::Point(p) => {
                        let p = p / unit;
                        let (i, d) = nearest_vertex(lm, p);
                        if check && d > POINT_DISTANCE * diag {
                            return Err(Error::invalid(format!(
                                "{}line {}: point ({}, {}, {}) is {:.4} from the surface (more than {}% of the mesh's size); points must lie on the surface",
                                map.at(),
                                c.line,
                                p.x * unit,
                                p.y * unit,
                                p.z * unit,
                                d * unit,
                                POINT_DISTANCE * 100.0
                            )));
                        }
                        i
                    }
                };
                v.push((i, c.factor.ln()));
            }
            Ok(v)
        };
        let fine_targets = targets(&finest, true)?;
        // Parts without a constraint keep factor 1.
        let comp = components(&finest);
        let parts = comp.iter().copied().max().map_or(0, |m| m + 1);
        let mut constrained = vec![false; parts];
        for &(i, _) in &fine_targets {
            constrained[comp[i]] = true;
        }
        let unconstrained_parts = constrained.iter().filter(|c| !**c).count();
        let (mut min, mut max) = (lo_c.factor, hi_c.factor);
        if unconstrained_parts > 0 {
            min = min.min(1.0);
            max = max.max(1.0);
            if max / min > MAX_RATIO {
                return Err(Error::invalid(format!(
                    "{}{unconstrained_parts} part(s) of the mesh have no constraint and keep factor 1, which is more than {MAX_RATIO}x from factor {} (line {}); constrain every part",
                    map.at(),
                    if hi_c.factor > 1.0 { hi_c.factor } else { lo_c.factor },
                    if hi_c.factor > 1.0 { hi_c.line } else { lo_c.line },
                )));
            }
        }
        let label = map.label();
        if lo_c.factor == hi_c.factor && unconstrained_parts == 0 {
            return Ok(ScaleField {
                constant: Some(lo_c.factor),
                mesh: None,
                log: Vec::new(),
                min,
                max,
                unconstrained_parts,
                label,
                counts,
                from: map.source,
            });
        }
        let lm = finest;
        let t = fine_targets;
        let nv = lm.position.len();
        // Fixed vertices: the constraints (several on one vertex: their mean) and every
        // vertex of an unconstrained part (log 0).
        let mut fixed = vec![false; nv];
        let mut value = vec![0.0f64; nv];
        let mut count = vec![0u32; nv];
        for &(i, x) in &t {
            fixed[i] = true;
            value[i] += x;
            count[i] += 1;
        }
        for i in 0..nv {
            if count[i] > 1 {
                value[i] /= count[i] as f64;
            }
            if !constrained[comp[i]] {
                fixed[i] = true;
                value[i] = 0.0;
            }
        }
        let mean = t.iter().map(|c| c.1).sum::<f64>() / t.len() as f64;
        let mut x: Vec<f64> = (0..nv)
            .map(|i| if fixed[i] { value[i] } else { mean })
            .collect();
        let op = Operator::new(&lm);
        op.solve(&mut x, &fixed, Energy::Dirichlet, HARMONIC_ITERATIONS);
        op.solve(&mut x, &fixed, Energy::ThinPlate, SMOOTHING_ITERATIONS);
        let (mesh, mut log) = (lm, x);
        for (i, v) in log.iter_mut().enumerate() {
            if constrained.get(comp[i]).copied().unwrap_or(false) {
                *v = v.clamp(lo, hi);
            } else {
                *v = 0.0;
            }
        }
        Ok(ScaleField {
            constant: None,
            mesh: Some(mesh),
            log,
            min,
            max,
            unconstrained_parts,
            label,
            counts,
            from: map.source,
        })
    }

    /// The factor at a base-quad point.
    #[inline]
    pub fn factor_at(&self, loc: BaseLocation) -> f64 {
        match (self.constant, &self.mesh) {
            (Some(k), _) => k,
            (None, Some(m)) => blend(m, &self.log, loc).exp(),
            (None, None) => 1.0,
        }
    }

    /// The factor at a domain point.
    pub fn factor(&self, surface: &Surface, loc: DomainLocation) -> f64 {
        match self.constant {
            Some(k) => k,
            None => self.factor_at(surface.base_location(loc)),
        }
    }

    /// The factor at `n` texel centres (`location(t)`); parallel, the same for any thread
    /// count.
    pub fn factors(
        &self,
        surface: &Surface,
        n: usize,
        location: impl Fn(usize) -> DomainLocation + Sync,
    ) -> Vec<f64> {
        (0..n)
            .into_par_iter()
            .map(|t| self.factor(surface, location(t)))
            .collect()
    }

    /// The factor at every texel centre of `layout`.
    pub fn layout_factors(
        &self,
        surface: &Surface,
        layout: &crate::layout::TexelLayout,
    ) -> Vec<f64> {
        self.factors(surface, layout.len(), |t| layout.location(t))
    }

    /// Smallest and largest factor over the surface.
    pub fn range(&self) -> (f64, f64) {
        (self.min, self.max)
    }

    /// Whether the factor is the same everywhere (then exactly that value).
    pub fn constant(&self) -> Option<f64> {
        self.constant
    }

    /// report.json's record, with `scale` the global scale in the user's units.
    pub fn info(&self, scale: f64) -> ScaleMapInfo {
        ScaleMapInfo {
            file: self.label.clone(),
            from: self.from,
            vertices: self.counts.0,
            points: self.counts.1,
            min_factor: self.min,
            max_factor: self.max,
            min_scale: scale * self.min,
            max_scale: scale * self.max,
            level: self.mesh.as_ref().map_or(0, |m| m.level),
            unconstrained_parts: self.unconstrained_parts,
        }
    }
}

/// Nearest vertex of `lm` to `p` (first of equals) and its distance.
fn nearest_vertex(lm: &LimitMesh, p: DVec3) -> (usize, f64) {
    let mut best = (0usize, f64::INFINITY);
    for (i, q) in lm.position.iter().enumerate() {
        let d = q.distance_squared(p);
        if d < best.1 {
            best = (i, d);
        }
    }
    (best.0, best.1.sqrt())
}

/// Connected component of every vertex (over face edges), numbered in vertex order.
fn components(lm: &LimitMesh) -> Vec<usize> {
    let nv = lm.position.len();
    let mut parent: Vec<usize> = (0..nv).collect();
    fn find(p: &mut [usize], mut i: usize) -> usize {
        while p[i] != i {
            p[i] = p[p[i]];
            i = p[i];
        }
        i
    }
    for f in 0..lm.mesh.num_faces() {
        let vs = lm.mesh.face_vertices(FaceId::from_idx(f));
        for w in vs.windows(2) {
            let (a, b) = (
                find(&mut parent, w[0] as usize),
                find(&mut parent, w[1] as usize),
            );
            if a != b {
                parent[a.max(b)] = a.min(b);
            }
        }
    }
    let mut id = vec![usize::MAX; nv];
    let mut next = 0;
    (0..nv)
        .map(|i| {
            let r = find(&mut parent, i);
            if id[r] == usize::MAX {
                id[r] = next;
                next += 1;
            }
            id[r]
        })
        .collect()
}

/// Bilinear blend of per-vertex values over the level face holding a base point.
fn blend(lm: &LimitMesh, x: &[f64], loc: BaseLocation) -> f64 {
    let (f, s, t) = lm.locate(loc.quad, loc.s, loc.t);
    let vs = lm.mesh.face_vertices(f);
    let w = [(1.0 - s) * (1.0 - t), s * (1.0 - t), s * t, (1.0 - s) * t];
    vs.iter()
        .zip(w)
        .map(|(&v, w)| x[v as usize] * w)
        .sum::<f64>()
}

/// Which energy a solve minimises.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Energy {
    /// Σ w_ij (x_i − x_j)²: harmonic interpolation (A = −L).
    Dirichlet,
    /// Σ (L x)_i² / m_i: thin plate (A = L M⁻¹ L).
    ThinPlate,
}

/// The thin-plate operator `A = L M⁻¹ L` of a limit mesh (module docs), as the cotangent
/// Laplacian L (CSR, off-diagonal weights) and the vertex areas.
struct Operator {
    start: Vec<usize>,
    nbr: Vec<u32>,
    w: Vec<f64>,
    /// Σ_j w_ij per vertex (L_ii = −diag).
    diag: Vec<f64>,
    inv_mass: Vec<f64>,
}

impl Operator {
    fn new(lm: &LimitMesh) -> Self {
        let nv = lm.position.len();
        let p = &lm.position;
        let mut trip: Vec<(u32, u32, f64)> = Vec::with_capacity(lm.mesh.num_faces() * 24);
        let mut mass = vec![0.0f64; nv];
        // Cotangent of the angle at `o` in triangle (a, b, o), guarded against degenerate
        // triangles (a sliver's cotangent is clamped rather than infinite).
        let cot = |a: DVec3, b: DVec3, o: DVec3| {
            let (u, v) = (a - o, b - o);
            let c = u.cross(v).length();
            let d = u.dot(v);
            (d / c.max(1e-12 * u.length() * v.length() + 1e-300)).clamp(-1e3, 1e3)
        };
        for f in 0..lm.mesh.num_faces() {
            let vs = lm.mesh.face_vertices(FaceId::from_idx(f));
            if vs.len() != 4 {
                continue;
            }
            let q = [
                vs[0] as usize,
                vs[1] as usize,
                vs[2] as usize,
                vs[3] as usize,
            ];
            // Both triangulations, each with weight 1/2.
            for tri in [[0, 1, 2], [0, 2, 3], [0, 1, 3], [1, 2, 3]] {
                let [a, b, c] = tri.map(|k| q[k]);
                for (i, j, o) in [(a, b, c), (b, c, a), (c, a, b)] {
                    let w = 0.25 * cot(p[i], p[j], p[o]);
                    trip.push((i as u32, j as u32, w));
                    trip.push((j as u32, i as u32, w));
                }
                let area = 0.5 * (p[b] - p[a]).cross(p[c] - p[a]).length();
                for k in [a, b, c] {
                    mass[k] += 0.5 * area / 3.0;
                }
            }
        }
        trip.sort_by_key(|t| (t.0, t.1));
        let mut start = vec![0usize; nv + 1];
        let mut nbr = Vec::with_capacity(trip.len() / 2);
        let mut w = Vec::with_capacity(trip.len() / 2);
        let mut k = 0;
        for i in 0..nv {
            while k < trip.len() && trip[k].0 as usize == i {
                let j = trip[k].1;
                let mut s = 0.0;
                while k < trip.len() && trip[k].0 as usize == i && trip[k].1 == j {
                    s += trip[k].2;
                    k += 1;
                }
                nbr.push(j);
                w.push(s);
            }
            start[i + 1] = nbr.len();
        }
        let diag = (0..nv)
            .map(|i| w[start[i]..start[i + 1]].iter().sum())
            .collect();
        let mean = mass.iter().sum::<f64>() / nv.max(1) as f64;
        let inv_mass = mass
            .iter()
            .map(|&m| 1.0 / m.max(1e-9 * mean).max(1e-300))
            .collect();
        Self {
            start,
            nbr,
            w,
            diag,
            inv_mass,
        }
    }

    /// y = L x.
    fn laplacian(&self, x: &[f64], y: &mut [f64]) {
        y.par_iter_mut().enumerate().for_each(|(i, yi)| {
            let r = self.start[i]..self.start[i + 1];
            let mut s = -self.diag[i] * x[i];
            for (j, w) in self.nbr[r.clone()].iter().zip(&self.w[r]) {
                s += w * x[*j as usize];
            }
            *yi = s;
        });
    }

    /// y = L M⁻¹ L x, zero where `fixed`.
    fn apply(&self, x: &[f64], fixed: &[bool], tmp: &mut [f64], y: &mut [f64]) {
        self.laplacian(x, tmp);
        tmp.par_iter_mut()
            .zip(self.inv_mass.par_iter())
            .for_each(|(t, m)| *t *= m);
        self.laplacian(tmp, y);
        y.par_iter_mut().zip(fixed.par_iter()).for_each(|(v, &f)| {
            if f {
                *v = 0.0
            }
        });
    }

    /// y = A x for `energy`, zero where `fixed`.
    fn apply_energy(
        &self,
        energy: Energy,
        x: &[f64],
        fixed: &[bool],
        tmp: &mut [f64],
        y: &mut [f64],
    ) {
        match energy {
            Energy::ThinPlate => self.apply(x, fixed, tmp, y),
            Energy::Dirichlet => {
                self.laplacian(x, y);
                y.par_iter_mut().zip(fixed.par_iter()).for_each(|(v, &f)| {
                    *v = if f { 0.0 } else { -*v };
                });
            }
        }
    }

    /// The diagonal of A (Jacobi preconditioner).
    fn a_diag(&self) -> Vec<f64> {
        (0..self.diag.len())
            .map(|i| {
                let mut s = self.diag[i] * self.diag[i] * self.inv_mass[i];
                let r = self.start[i]..self.start[i + 1];
                for (j, w) in self.nbr[r.clone()].iter().zip(&self.w[r]) {
                    s += w * w * self.inv_mass[*j as usize];
                }
                s
            })
            .collect()
    }

    /// Lowers `energy` over the free vertices of `x` (the fixed ones keep their values):
    /// at most `iterations` steps of preconditioned conjugate gradients on
    /// `A_ff x_f = −A_fc x_c`, from `x`.
    fn solve(&self, x: &mut [f64], fixed: &[bool], energy: Energy, iterations: usize) {
        let n = x.len();
        let mut tmp = vec![0.0; n];
        let mut r = vec![0.0; n];
        // r = −A x (masked): the residual of the current x.
        self.apply_energy(energy, x, fixed, &mut tmp, &mut r);
        r.iter_mut().for_each(|v| *v = -*v);
        let d = match energy {
            Energy::ThinPlate => self.a_diag(),
            Energy::Dirichlet => self.diag.clone(),
        };
        let pre: Vec<f64> = d
            .iter()
            .zip(fixed)
            .map(|(&a, &f)| if f || a <= 0.0 { 0.0 } else { 1.0 / a })
            .collect();
        // The scale of the problem: the residual A x would have with x = 0 at the free
        // vertices (what the constraints push).
        let mut x0 = x.to_vec();
        for (v, &f) in x0.iter_mut().zip(fixed) {
            if !f {
                *v = 0.0;
            }
        }
        let mut b = vec![0.0; n];
        self.apply_energy(energy, &x0, fixed, &mut tmp, &mut b);
        let bnorm = dot(&b, &b).sqrt();
        if bnorm == 0.0 {
            return;
        }
        let mut z: Vec<f64> = r.iter().zip(&pre).map(|(a, p)| a * p).collect();
        let mut p = z.clone();
        let mut rz = dot(&r, &z);
        let mut ap = vec![0.0; n];
        for _ in 0..iterations {
            if dot(&r, &r).sqrt() <= TOLERANCE * bnorm {
                break;
            }
            self.apply_energy(energy, &p, fixed, &mut tmp, &mut ap);
            let pap = dot(&p, &ap);
            if pap <= 0.0 || !pap.is_finite() {
                break;
            }
            let alpha = rz / pap;
            for i in 0..n {
                x[i] += alpha * p[i];
                r[i] -= alpha * ap[i];
            }
            for i in 0..n {
                z[i] = r[i] * pre[i];
            }
            let rz2 = dot(&r, &z);
            let beta = rz2 / rz;
            rz = rz2;
            for i in 0..n {
                p[i] = z[i] + beta * p[i];
            }
        }
    }
}

/// Σ a_i b_i in index order (the same for any thread count).
fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

#[cfg(test)]
mod tests {
    use super::*;
    use subdiv::ControlMesh;

    /// A flat `k`×`k` grid of unit quads in the xy plane.
    fn grid(k: usize) -> Surface {
        let mut p = Vec::new();
        for y in 0..=k {
            for x in 0..=k {
                p.push(DVec3::new(x as f64, y as f64, 0.0));
            }
        }
        let mut faces: Vec<Vec<u32>> = Vec::new();
        for y in 0..k {
            for x in 0..k {
                let i = (y * (k + 1) + x) as u32;
                let k1 = (k + 1) as u32;
                faces.push(vec![i, i + 1, i + 1 + k1, i + k1]);
            }
        }
        let f: Vec<&[u32]> = faces.iter().map(|f| f.as_slice()).collect();
        Surface::new(ControlMesh::from_faces(p, &f).unwrap())
    }

    #[test]
    fn orientation_lengths_are_the_scale_map_of_their_lengths() {
        use crate::field::Constraints;
        let c = Constraints::parse(
            "axis 0 1 0\nvertex 3 0 2 0 # length 2\nsink 0 0 0\nvertex 9 3 0 4\n",
        )
        .unwrap();
        let m = ScaleMap::from_orientation(&c).unwrap();
        let want = ScaleMap::parse("vertex 3 2\nvertex 9 5\n").unwrap();
        assert_eq!(m.source, ScaleSource::OrientLengths);
        let pairs = |m: &ScaleMap| -> Vec<(At, f64)> {
            m.constraints.iter().map(|c| (c.at, c.factor)).collect()
        };
        assert_eq!(pairs(&m), pairs(&want));
        assert_eq!(
            m.constraints.iter().map(|c| c.line).collect::<Vec<_>>(),
            [2, 4]
        );
        // The same vertex twice: one length is fine, two are refused (naming both lines).
        let twice = |t: &str| ScaleMap::from_orientation(&Constraints::parse(t).unwrap());
        assert!(twice("vertex 1 1 0 0\nvertex 1 0 1 0\n").is_ok());
        let e = twice("vertex 1 1 0 0\nvertex 1 0 2 0\n")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("line 2: vertex 1 has direction length 2 here and 1 on line 1"),
            "{e}"
        );
        let e = twice("vertex 1 1 0 0\nvertex 2 17 0 0\n")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("direction lengths 1 (line 1) and 17 (line 2)"),
            "{e}"
        );
        let e = twice("vertex 1 1e300 1e300 0\n").unwrap_err().to_string();
        assert!(e.contains("line 1: direction length inf"), "{e}");
        let e = twice("axis 1 0 0\n").unwrap_err().to_string();
        assert!(e.contains("has no `vertex"), "{e}");
    }

    #[test]
    fn parse_accepts_both_spellings_and_comments() {
        let m =
            ScaleMap::parse("# a map\nvertex 3 2\nv 4 0.5 # half\n\np 0 1 2 3\npoint 1 1 1 1e0\n")
                .unwrap();
        assert_eq!(m.constraints.len(), 4);
        assert_eq!(m.constraints[0].at, At::Vertex(3));
        assert_eq!(m.constraints[1].factor, 0.5);
        assert_eq!(m.constraints[2].at, At::Point(DVec3::new(0.0, 1.0, 2.0)));
        assert_eq!(m.constraints[3].line, 6);
    }

    #[test]
    fn parse_errors_name_the_line_and_problem() {
        let e = |t: &str| ScaleMap::parse(t).unwrap_err();
        assert!(
            e("vertex 1 0\n").contains("line 1: factor 0 must be"),
            "{}",
            e("vertex 1 0\n")
        );
        assert!(e("\nvertex 1 -2\n").starts_with("line 2: factor -2"));
        assert!(e("vertex 1 NaN\n").contains("factor NaN must be a finite"));
        assert!(e("vertex 1 inf\n").contains("must be a finite"));
        assert!(e("vertex 1\n").contains("expected `vertex INDEX FACTOR`"));
        assert!(e("vertex -1 2\n").contains("vertex index '-1' is not a whole number"));
        assert!(e("point 0 0 2\n").contains("expected `point X Y Z FACTOR`"));
        assert!(e("point 0 x 0 2\n").contains("'x' is not a number"));
        assert!(e("scale 2\n").contains("unknown keyword 'scale'"));
        assert!(e("# nothing\n").contains("has no constraints"));
        let r = e("v 0 0.5\nv 1 10\n");
        assert!(
            r.contains("line 1") && r.contains("line 2") && r.contains("20.000x"),
            "{r}"
        );
        let d = e("v 0 2\nv 0 3\n");
        assert!(
            d.contains("line 2: vertex 0 has factor 3 here and 2 on line 1"),
            "{d}"
        );
        assert!(ScaleMap::parse("v 0 2\nv 0 2\n").is_ok());
        assert!(ScaleMap::parse("v 0 1\nv 1 16\n").is_ok());
        for t in ["v 0 0\n", "x\n", "v 0 1\nv 1 17\n"] {
            assert!(!e(t).contains('\n'));
        }
    }

    #[test]
    fn vertex_out_of_range_names_file_and_line() {
        let mut m = ScaleMap::parse("v 0 1\n\nv 99 2\n").unwrap();
        m.path = Some("s.txt".into());
        let e = m.check(16).unwrap_err().to_string();
        assert_eq!(
            e,
            "s.txt: line 3: vertex 99, but the mesh has 16 vertices (0-based)"
        );
    }

    #[test]
    fn constant_map_is_exactly_constant() {
        let s = grid(3);
        let m = ScaleMap::parse("v 0 2.5\n").unwrap();
        let f = ScaleField::compute(&s, &m, 1.0).unwrap();
        assert_eq!(f.constant(), Some(2.5));
        let loc = DomainLocation {
            domain: subdiv::DomainId(4),
            u: 0.3,
            v: 0.7,
        };
        assert_eq!(f.factor(&s, loc), 2.5);
    }

    /// Factors 1 along x = 0 and 4 along x = k of an open sheet: the factor grows
    /// monotonically from one end to the other, symmetrically in log (f(x)·f(k − x) = 4),
    /// exactly the given values at the constrained vertices. (Not exactly 4^(x/k): the
    /// energy's natural condition at the open boundary is a zero slope across it, so the
    /// ramp is S-shaped; docs/formats.md says so.)
    #[test]
    fn two_ends_give_a_monotone_ramp() {
        let k = 4;
        let s = grid(k);
        let mut t = String::new();
        for y in 0..=k {
            t += &format!("v {} 1\nv {} 4\n", y * (k + 1), y * (k + 1) + k);
        }
        let f = ScaleField::compute(&s, &ScaleMap::parse(&t).unwrap(), 1.0).unwrap();
        assert_eq!(f.constant(), None);
        assert_eq!(f.range(), (1.0, 4.0));
        let at = |x: f64, y: f64| {
            // Domain of the control quad holding (x, y), and the point's (u, v) in it.
            let (cx, cy) = (
                (x.floor() as usize).min(k - 1),
                (y.floor() as usize).min(k - 1),
            );
            let loc = DomainLocation {
                domain: subdiv::DomainId::from_idx(cy * k + cx),
                u: x - cx as f64,
                v: y - cy as f64,
            };
            assert!((s.eval(loc.domain, loc.u, loc.v).p - DVec3::new(x, y, 0.0)).length() < 1e-9);
            f.factor(&s, loc)
        };
        for y in [0.0, 1.3, 4.0] {
            let mut last = 0.0;
            for i in 0..=40 {
                let x = i as f64 / 10.0;
                let v = at(x, y);
                assert!(
                    v >= last - 1e-12,
                    "not monotone at ({x}, {y}): {v} after {last}"
                );
                last = v;
                let sym = v * at(k as f64 - x, y);
                assert!(
                    (sym - 4.0).abs() < 1e-4,
                    "f({x}) f({}) = {sym}",
                    k as f64 - x
                );
            }
            // Exact at the constrained control vertices (between them the edge is free).
            if y.fract() == 0.0 {
                assert!((at(0.0, y) - 1.0).abs() < 1e-9 && (at(4.0, y) - 4.0).abs() < 1e-6);
            }
            let mid = at(1.0, y);
            assert!((1.1..1.5).contains(&mid), "f(1) = {mid}");
        }
    }

    /// One pinned vertex in the middle, the corners at 1: smooth, never beyond the given
    /// range, exactly the pin's value at the pin.
    #[test]
    fn single_pins_are_smooth_and_clamped() {
        let k = 6;
        let s = grid(k);
        let c = (k / 2) * (k + 1) + k / 2;
        let t = format!(
            "v 0 1\nv {k} 1\nv {} 1\nv {} 1\nv {c} 3\n",
            k * (k + 1),
            (k + 1) * (k + 1) - 1
        );
        let f = ScaleField::compute(&s, &ScaleMap::parse(&t).unwrap(), 1.0).unwrap();
        let mesh = f.mesh.as_ref().unwrap();
        assert!((f.log[c].exp() - 3.0).abs() < 1e-9);
        assert!(f
            .log
            .iter()
            .all(|&l| (0.0..=3f64.ln() + 1e-12).contains(&l)));
        // Neighbouring vertices along the row through the pin: no cusp (the two one-sided
        // slopes at the pin nearly cancel, against a harmonic pin's opposite slopes).
        let pos = &mesh.position;
        let row: Vec<(f64, f64)> = (0..pos.len())
            .filter(|&i| (pos[i].y - pos[c].y).abs() < 1e-9)
            .map(|i| (pos[i].x, f.log[i]))
            .collect();
        let mut row = row;
        row.sort_by(|a, b| a.0.total_cmp(&b.0));
        let at = row
            .iter()
            .position(|r| (r.0 - pos[c].x).abs() < 1e-9)
            .unwrap();
        let slope = |i: usize| (row[i + 1].1 - row[i].1) / (row[i + 1].0 - row[i].0);
        let at_pin = slope(at - 1).abs().max(slope(at).abs());
        let steepest = (0..row.len() - 1)
            .map(slope)
            .fold(0.0f64, |m, s| m.max(s.abs()));
        eprintln!(
            "pin slopes {} {} steepest {steepest}",
            slope(at - 1),
            slope(at)
        );
        assert!(
            at_pin < 0.5 * steepest,
            "at the pin {at_pin}, steepest {steepest}"
        );
    }

    #[test]
    fn unconstrained_parts_keep_factor_one() {
        // Two separate squares; only the first is constrained.
        let p: Vec<DVec3> = [
            (0., 0.),
            (1., 0.),
            (1., 1.),
            (0., 1.),
            (3., 0.),
            (4., 0.),
            (4., 1.),
            (3., 1.),
        ]
        .iter()
        .map(|&(x, y)| DVec3::new(x, y, 0.0))
        .collect();
        let faces: [&[u32]; 2] = [&[0, 1, 2, 3], &[4, 5, 6, 7]];
        let s = Surface::new(ControlMesh::from_faces(p, &faces).unwrap());
        let f = ScaleField::compute(&s, &ScaleMap::parse("v 0 2\nv 2 3\n").unwrap(), 1.0).unwrap();
        assert_eq!(f.range(), (1.0, 3.0));
        assert_eq!(f.info(1.0).unconstrained_parts, 1);
        let loc = |d: u32| DomainLocation {
            domain: subdiv::DomainId(d),
            u: 0.5,
            v: 0.5,
        };
        assert_eq!(f.factor(&s, loc(1)), 1.0);
        let a = f.factor(&s, loc(0));
        assert!((2.0..=3.0).contains(&a), "{a}");
        // Constant but not reaching every part: not constant.
        let g = ScaleField::compute(&s, &ScaleMap::parse("v 0 2\n").unwrap(), 1.0).unwrap();
        assert_eq!(g.constant(), None);
        // 1 and 20 in one map: refused.
        let e = ScaleField::compute(&s, &ScaleMap::parse("v 0 12\nv 1 16\n").unwrap(), 1.0);
        assert!(e.is_ok());
        let e = ScaleField::compute(&s, &ScaleMap::parse("v 0 17\n").unwrap(), 1.0).unwrap_err();
        assert!(
            e.to_string().contains("no constraint and keep factor 1"),
            "{e}"
        );
    }

    #[test]
    fn points_snap_to_the_surface_or_are_refused() {
        let s = grid(2);
        let f = ScaleField::compute(&s, &ScaleMap::parse("p 0 0 0 1\np 2 2 0 2\n").unwrap(), 1.0)
            .unwrap();
        let corner = DomainLocation {
            domain: subdiv::DomainId(3),
            u: 1.0,
            v: 1.0,
        };
        assert!((f.factor(&s, corner) - 2.0).abs() < 1e-9);
        let mut m = ScaleMap::parse("p 0 0 5 1\n").unwrap();
        m.path = Some("m.txt".into());
        let e = ScaleField::compute(&s, &m, 1.0).unwrap_err().to_string();
        assert!(
            e.starts_with("m.txt: line 1: point (0, 0, 5) is 5.0000 from the surface"),
            "{e}"
        );
        // Points are in the user's units: a mesh divided by 4 divides them too.
        let m = ScaleMap::parse("p 2 2 0 3\np 0 0 0 1\n").unwrap();
        let mut c = s.control.clone();
        for p in &mut c.mesh.positions {
            *p *= 0.25;
        }
        let small = Surface::new(c);
        let g = ScaleField::compute(&small, &m, 4.0).unwrap();
        assert!((g.factor(&small, corner) - 3.0).abs() < 1e-9);
    }

    #[test]
    fn the_field_does_not_depend_on_the_thread_count() {
        let s = grid(5);
        let m = ScaleMap::parse("v 0 1\nv 35 5\nv 17 2\n").unwrap();
        let run = |t: usize| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(t)
                .build()
                .unwrap()
                .install(|| {
                    let f = ScaleField::compute(&s, &m, 1.0).unwrap();
                    let layout = crate::layout::TexelLayout::uniform(s.num_domains(), 8);
                    (f.log.clone(), f.layout_factors(&s, &layout))
                })
        };
        assert_eq!(run(1), run(3));
    }
}
