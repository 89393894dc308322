//! Tangent orientation field (v1, v2 = n × v1) over the surface (Ying et al. 2001, §3
//! "Surface orientation" and footnote 2; sinks and sources after Zelinka & Garland 2003, §3).
//!
//! # What is optimised
//! The field lives on the vertices of a [`LimitMesh`] (the surface uniformly refined to level
//! L, vertices at exact limit positions). Every vertex i has a tangent frame (e_i, n_i × e_i)
//! and the field there is the angle θ_i, held as the unit complex number z_i = e^{iθ_i}. For
//! an edge i→j, φ_ij and φ_ji are the angles of the *same* edge vector x_j − x_i projected on
//! the tangent planes of i and of j. The field is parallel along the edge when
//! θ_i − φ_ij = θ_j − φ_ji, so the energy of footnote 2 (the vector, not the 4-symmetric,
//! variant) is minimised in the form
//!
//! E = Σ_edges 1 − cos((θ_i − φ_ij) − (θ_j − φ_ji))  +  λ Σ_i |a_i| (1 − cos(θ_i − arg a_i)),
//!
//! where a_i is an optional *target* (an axis projected on the tangent plane, or the pull of
//! sinks and sources) and λ its weight. E ≥ 0; 0 is a parallel field that meets every target.
//!
//! # How
//! Coarse to fine over levels 1..=L (the levels are nested, so each is a good start for the
//! next): on level 1 a linear relaxation gives the start — the smallest eigenvector of the
//! connection Laplacian by inverse iteration for `auto` (Knöppel et al. 2013: this puts
//! singularities only where topology forces them), or the quadratic relaxation of E with
//! the targets — then on every level *nonlinear multigrid*: the exact local minimiser
//! z_i = normalize(Σ_j c_ij z_j + λ a_i) as smoother (red-black: refined meshes are
//! bipartite, so one colour class is updated in parallel with the same result as in
//! sequence), and coarse corrections on a greedy-aggregation hierarchy of the level's own
//! graph. Why: plain Gauss–Seidel removes smooth errors only by O(h²) per sweep, so it
//! needed 60 sweeps per level and never converged, and the CG relaxation over a big level 1
//! grew faster than the mesh (a 200k-quad torus did not finish in 120 s). The coarse
//! unknown is a turn r_A of every vertex of aggregate A; E(z·r) has the same form on the
//! aggregate graph (see `coarse_problem`), so coarse levels are solved the same way and
//! every coarse decrease is the fine one: E never rises (recorded per cycle in
//! [`OrientationField::history`]) and the result does not depend on the thread count. A
//! level 1 above `EXACT_MAX` vertices gets its relaxation on its own aggregates (`fmg`).
//! docs/field.md has the measurements.
//!
//! # Across infinitely sharp creases
//! A vertex on such a crease (or corner) has one tangent plane per *sector* (the faces
//! between two sharp edges). It keeps one θ_i, measured in a frame per sector: at a crease
//! (two sectors meeting along two sharp edges) every sector's frame starts from the
//! crease's own tangent, which lies in both planes, so the same θ_i on either side is the
//! direction *unfolded* across the crease (same angle to the crease), as a geodesic crossing
//! it continues. Edges use the frame of the sector they lie in, and field vectors inside a
//! face use the frame of the face's side. At corners (three or more sectors) each sector's
//! frame starts from its first sharp edge: the field is singular there anyway.
//!
//! # Inside faces
//! [`OrientationField::frame`] blends the four corner vectors of the level face holding the
//! point bilinearly (in 3D), projects on the exact tangent plane and normalises. Two faces
//! sharing an edge blend the same two vectors along it, so the field is continuous across
//! face and domain edges (except at singularities, where no continuous field exists).

use anyhow::{bail, Context};
use glam::{DVec2, DVec3};
use rayon::prelude::*;
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use subdiv::surface::LeafHint;
use subdiv::{BaseLocation, DomainId, FaceId, LimitMesh, Surface, VertexId};

mod choice;
pub use choice::{bent_fraction, level_fraction, Choice, Why};

/// Example pixels over which `straight` wants the field straight: half the extent of BRIEF's
/// pf8 window (7 samples 8 px apart plus the discs), so a window centred anywhere sees rows
/// bend by at most `choice::TURN` on either side.
pub const STRUCTURE_PIXELS: f64 = 28.0;

/// How the field is chosen.
#[derive(Clone, Debug, PartialEq)]
pub enum Orientation {
    /// The smoothest field (singularities only where topology forces them).
    Auto,
    /// The straightest of the smooth field and the three world-axis fields, scored on a
    /// coarse level by the area where the frame turns fast over the structure length
    /// ([`FieldOptions::structure_length`]; module `choice` says why and how).
    Straight,
    /// Closest to a world axis projected on the tangent planes, then smoothed.
    Axis(DVec3),
    /// The example's up (image rows towards row 0, +v2) along a world axis projected on the
    /// tangent planes: the axis field turned a quarter, so v1 runs across the axis (`up`:
    /// +y, the convention of OBJ exporters; `up+z` for Z-up meshes). A brick wall's courses
    /// stay level, scales point down, whatever the mesh's shape.
    Up(DVec3),
    /// [`Orientation::Up`] where the surface has an up, else [`Orientation::Auto`]: `up`
    /// unless more than half of the surface's area is level against the axis (terrain, a
    /// floor, a shallow dome), where `up` would draw the example in contour rings around
    /// every summit (`choice::upright` says why and what was measured). The default of
    /// texture optimisation.
    Upright(DVec3),
    /// Constraints from a file (see docs/field.md).
    Constraints(std::path::PathBuf),
}

impl Orientation {
    /// Parses the `--orient` value: `auto`, `+x|-x|+y|-y|+z|-z`, or a constraints file path.
    pub fn parse(s: &str) -> Self {
        let axis = |v: DVec3| Orientation::Axis(v);
        match s.trim() {
            "auto" => Orientation::Auto,
            "straight" => Orientation::Straight,
            "up" | "up+y" => Orientation::Up(DVec3::Y),
            "up-y" => Orientation::Up(DVec3::NEG_Y),
            "up+x" => Orientation::Up(DVec3::X),
            "up-x" => Orientation::Up(DVec3::NEG_X),
            "up+z" => Orientation::Up(DVec3::Z),
            "up-z" => Orientation::Up(DVec3::NEG_Z),
            "upright" | "upright+y" => Orientation::Upright(DVec3::Y),
            "upright-y" => Orientation::Upright(DVec3::NEG_Y),
            "upright+x" => Orientation::Upright(DVec3::X),
            "upright-x" => Orientation::Upright(DVec3::NEG_X),
            "upright+z" => Orientation::Upright(DVec3::Z),
            "upright-z" => Orientation::Upright(DVec3::NEG_Z),
            "+x" | "x" => axis(DVec3::X),
            "-x" => axis(DVec3::NEG_X),
            "+y" | "y" => axis(DVec3::Y),
            "-y" => axis(DVec3::NEG_Y),
            "+z" | "z" => axis(DVec3::Z),
            "-z" => axis(DVec3::NEG_Z),
            other => Orientation::Constraints(PathBuf::from(other)),
        }
    }

    /// The short name used in reports: `auto`, `+x`..., or the file path.
    pub fn label(&self) -> String {
        match self {
            Orientation::Auto => "auto".into(),
            Orientation::Straight => "straight".into(),
            Orientation::Axis(a) => {
                let names = [
                    (DVec3::X, "+x"),
                    (DVec3::NEG_X, "-x"),
                    (DVec3::Y, "+y"),
                    (DVec3::NEG_Y, "-y"),
                    (DVec3::Z, "+z"),
                    (DVec3::NEG_Z, "-z"),
                ];
                names
                    .iter()
                    .find(|(v, _)| *v == *a)
                    .map(|(_, n)| n.to_string())
                    .unwrap_or_else(|| format!("axis({}, {}, {})", a.x, a.y, a.z))
            }
            Orientation::Up(a) if *a == DVec3::Y => "up".into(),
            Orientation::Up(a) => format!(
                "up{}",
                Orientation::Axis(*a).label().trim_start_matches("axis")
            ),
            Orientation::Upright(a) if *a == DVec3::Y => "upright".into(),
            Orientation::Upright(a) => format!(
                "upright{}",
                Orientation::Axis(*a).label().trim_start_matches("axis")
            ),
            Orientation::Constraints(p) => p.display().to_string(),
        }
    }
}

/// An orthonormal tangent frame: v1, v2 tangent, n the unit normal, v2 = n × v1.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct Frame {
    pub v1: DVec3,
    pub v2: DVec3,
    pub n: DVec3,
}

impl Frame {
    /// The frame with v1 = `dir` projected on the plane of `n` (normalised); if `dir` is
    /// (nearly) normal, `fallback` projected instead.
    pub fn from_direction(dir: DVec3, n: DVec3, fallback: DVec3) -> Frame {
        Self::from_direction_with(dir, n, || fallback)
    }

    /// [`Self::from_direction`] computing `fallback` only when it is used (the same
    /// arithmetic): where the caller would have to evaluate the surface for it.
    #[inline]
    pub fn from_direction_with(dir: DVec3, n: DVec3, fallback: impl FnOnce() -> DVec3) -> Frame {
        let mut t = dir - n * n.dot(dir);
        if t.length_squared() < 1e-24 {
            let fallback = fallback();
            t = fallback - n * n.dot(fallback);
        }
        if t.length_squared() < 1e-24 {
            t = n.any_orthonormal_vector();
        }
        let v1 = t.normalize();
        Frame {
            v1,
            v2: n.cross(v1),
            n,
        }
    }
}

/// Knobs of [`OrientationField::compute_with`]. The defaults are what `compute` uses.
#[derive(Clone, Debug)]
pub struct FieldOptions {
    /// Refinement level of the limit mesh the field lives on. `None`: the finest level in
    /// 1..=[`Self::max_level`] with at most [`Self::max_faces`] faces.
    pub level: Option<u32>,
    /// Highest automatic level. Level 5 has 256 faces per base quad (16 per side of a base
    /// quad, 32 per side of a quad domain): finer than the 2-texel steps marching is used
    /// for at 32 texels per side.
    pub max_level: u32,
    /// Face budget of the automatic level (memory and time grow linearly with it).
    pub max_faces: usize,
    /// Texels the field will be evaluated at (the run's texel count). With it the automatic
    /// level also stops at the first level with a face per [`TEXELS_PER_FACE`] texels: the
    /// field is smooth and blended bilinearly inside faces, so a finer mesh than the texels
    /// need only costs time (docs/field.md, "Level"). `None`: the face budget alone.
    pub texels: Option<u64>,
    /// λ, the weight of axis hints and sinks/sources against smoothness (per vertex; a
    /// vertex has about four edges, so 8 makes a target twice as strong as its neighbours).
    pub target_weight: f64,
    /// Gauss–Seidel sweeps at most on the coarsest multigrid level per visit (10x as many
    /// on its first visit, and on a limit mesh small enough to need no coarser level).
    pub max_sweeps: usize,
    /// V-cycles at most on the limit mesh (at least 2).
    pub max_cycles: usize,
    /// Relaxation and cycles stop when one lowers E by less than this fraction.
    pub tolerance: f64,
    /// The length over which `straight` wants the field straight (the builder: 28 example
    /// pixels, half of pf8's window). `None`: 1/16 of the bounding-box diagonal.
    pub structure_length: Option<f64>,
    /// The surface is the user's mesh divided by this (the power of two the synthesizer
    /// normalises far-from-unit meshes by): points and radii of a constraints file, in the
    /// user's units, are divided by it too, so the field does not depend on the mesh's scale.
    pub unit: f64,
}

impl Default for FieldOptions {
    fn default() -> Self {
        Self {
            level: None,
            max_level: 5,
            max_faces: 400_000,
            texels: None,
            target_weight: 8.0,
            max_sweeps: 60,
            max_cycles: 10,
            tolerance: 1e-7,
            structure_length: None,
            unit: 1.0,
        }
    }
}

/// One optimisation step's energy, for inspection and tests.
#[derive(Clone, Debug, PartialEq)]
pub struct LevelHistory {
    pub level: u32,
    pub vertices: usize,
    /// E after initialisation, then after every half-sweep (one colour class updated).
    pub energy: Vec<f64>,
}

/// A singular face of the discrete field: the field turns `index` times around it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Singularity {
    pub face: FaceId,
    pub index: i32,
    /// Limit position of the face's centre (mean of its corners).
    pub position: DVec3,
}

/// A tangent field, defined at every (domain, u, v).
#[derive(Clone, Debug)]
pub struct OrientationField {
    mesh: LimitMesh,
    /// Unit tangent v1 at every vertex of `mesh` (at a vertex with one normal per side:
    /// on the side of its `vertex_corner`).
    v1: Vec<DVec3>,
    /// v1 on each face's side at the vertices with one normal per side, by face corner
    /// 4·face + corner ([`LimitMesh::is_sided`]); empty without such vertices.
    corner_v1: HashMap<u32, DVec3>,
    history: Vec<LevelHistory>,
    label: String,
    /// What `straight` or `upright` chose (None for every other orientation).
    choice: Option<Choice>,
}

/// A parsed constraints file (docs/field.md).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Constraints {
    /// (control vertex index, 3D direction): v1 is pinned there.
    pub vertices: Vec<(usize, DVec3)>,
    /// (point, radius, +1 source / -1 sink).
    pub points: Vec<(DVec3, Option<f64>, f64)>,
    /// Global axis hints (direction, weight factor).
    pub axes: Vec<(DVec3, f64)>,
    /// Global "up" hints (direction, weight factor): the target is the projected axis
    /// turned a quarter (× n), so that v2 — the example's up — follows the axis.
    pub ups: Vec<(DVec3, f64)>,
    /// The file's 1-based line of each entry of `vertices` (empty when not from a file),
    /// for messages about indices the mesh does not have.
    pub vertex_lines: Vec<usize>,
    /// |d| of each entry of `vertices` as written (the field uses only its direction):
    /// `--scale-from-orient` takes the local scale from it
    /// ([`crate::scale_field::ScaleMap::from_orientation`]).
    pub vertex_lengths: Vec<f64>,
    /// The file read, for the same messages.
    pub path: Option<PathBuf>,
}

impl Constraints {
    /// Reads a constraints file; errors are one line naming the file and line.
    pub fn load(path: &Path) -> anyhow::Result<Self> {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("{}: cannot read constraints file", path.display()))?;
        let mut c = Self::parse(&text).with_context(|| format!("{}", path.display()))?;
        c.path = Some(path.to_path_buf());
        Ok(c)
    }

    /// Parses the text of a constraints file (format in docs/field.md).
    pub fn parse(text: &str) -> anyhow::Result<Self> {
        let mut c = Constraints::default();
        for (ln, raw) in text.lines().enumerate() {
            let line = raw.split('#').next().unwrap_or("").trim();
            if line.is_empty() {
                continue;
            }
            let mut it = line.split_whitespace();
            let key = it.next().unwrap_or("");
            let nums: Vec<&str> = it.collect();
            let num = |i: usize| -> anyhow::Result<f64> {
                let s = nums[i];
                let v: f64 = s
                    .parse()
                    .map_err(|_| anyhow::anyhow!("line {}: '{s}' is not a number", ln + 1))?;
                if !v.is_finite() {
                    bail!("line {}: '{s}' is not a finite number", ln + 1);
                }
                Ok(v)
            };
            let raw3 = |i: usize| -> anyhow::Result<DVec3> {
                Ok(DVec3::new(num(i)?, num(i + 1)?, num(i + 2)?))
            };
            let dir3 = |i: usize| -> anyhow::Result<DVec3> {
                let d = raw3(i)?;
                if d.length() < 1e-12 {
                    bail!(
                        "line {}: direction ({}, {}, {}) has zero length",
                        ln + 1,
                        d.x,
                        d.y,
                        d.z
                    );
                }
                Ok(d.normalize())
            };
            match key {
                "vertex" => {
                    if nums.len() != 4 {
                        bail!(
                            "line {}: expected `vertex INDEX DX DY DZ`, got `{line}`",
                            ln + 1
                        );
                    }
                    let idx: usize = nums[0].parse().map_err(|_| {
                        anyhow::anyhow!(
                            "line {}: vertex index '{}' is not a whole number",
                            ln + 1,
                            nums[0]
                        )
                    })?;
                    c.vertices.push((idx, dir3(1)?));
                    c.vertex_lines.push(ln + 1);
                    c.vertex_lengths.push(raw3(1)?.length());
                }
                "sink" | "source" => {
                    if nums.len() != 3 && nums.len() != 4 {
                        bail!(
                            "line {}: expected `{key} X Y Z [RADIUS]`, got `{line}`",
                            ln + 1
                        );
                    }
                    let p = DVec3::new(num(0)?, num(1)?, num(2)?);
                    let r = if nums.len() == 4 {
                        let r = num(3)?;
                        if r <= 0.0 {
                            bail!("line {}: radius {r} must be positive", ln + 1);
                        }
                        Some(r)
                    } else {
                        None
                    };
                    c.points
                        .push((p, r, if key == "source" { 1.0 } else { -1.0 }));
                }
                "axis" => {
                    if nums.len() != 3 && nums.len() != 4 {
                        bail!(
                            "line {}: expected `axis DX DY DZ [WEIGHT]`, got `{line}`",
                            ln + 1
                        );
                    }
                    let w = if nums.len() == 4 { num(3)? } else { 1.0 };
                    if w < 0.0 {
                        bail!("line {}: weight {w} must not be negative", ln + 1);
                    }
                    c.axes.push((dir3(0)?, w));
                }
                other => bail!(
                    "line {}: unknown keyword '{other}' (expected vertex, sink, source or axis)",
                    ln + 1
                ),
            }
        }
        Ok(c)
    }
}

// ---- complex numbers as DVec2 (x + iy) ----

#[inline]
fn cmul(a: DVec2, b: DVec2) -> DVec2 {
    DVec2::new(a.x * b.x - a.y * b.y, a.x * b.y + a.y * b.x)
}

#[inline]
fn conj(a: DVec2) -> DVec2 {
    DVec2::new(a.x, -a.y)
}

/// The limit mesh of the field: its graph, connection and vertex frames.
struct LevelProblem {
    graph: Graph,
    /// Per CSR entry, c_ij such that a neighbour transported to i is c_ij z_j
    /// (c_ji = conj(c_ij)).
    coef: Vec<DVec2>,
    /// Tangent frame per vertex: e_i and f_i = n_i × e_i (at a vertex with one normal per
    /// side, the frame of its `vertex_corner`'s side).
    e: Vec<DVec3>,
    f: Vec<DVec3>,
    /// At vertices with one normal per side: the frame of every face corner's side
    /// (4·face + corner), see the module doc.
    corner_frames: HashMap<u32, (DVec3, DVec3)>,
    /// λ a_i in the vertex frame.
    target: Vec<DVec2>,
    /// Pinned values (NaN = free).
    pinned: Vec<DVec2>,
}

impl LevelProblem {
    fn new(lm: &LimitMesh) -> Self {
        let m = &lm.mesh;
        let nv = m.num_vertices();
        // Every vertex's frame and every row below alone: in parallel (the rows in fixed
        // blocks joined in order), the same values as one loop.
        let (mut e, mut f): (Vec<DVec3>, Vec<DVec3>) = (0..nv)
            .into_par_iter()
            .with_min_len(4096)
            .map(|v| {
                let n = lm.normal[v];
                // Reference direction: the first outgoing edge projected (any tangent would
                // do; energies and the result do not depend on it).
                let mut t = DVec3::ZERO;
                if let Some(h) = m.vertex_out(VertexId::from_idx(v)) {
                    let d = lm.position[m.dest(h).idx()] - lm.position[v];
                    t = d - n * n.dot(d);
                }
                if t.length_squared() < 1e-30 {
                    t = n.any_orthonormal_vector();
                }
                let ev = t.normalize();
                (ev, n.cross(ev))
            })
            .unzip();
        let corner_frames = sided_frames(lm);
        for (v, (ev, fv)) in e.iter_mut().zip(f.iter_mut()).enumerate() {
            if lm.is_sided(VertexId::from_idx(v)) {
                (*ev, *fv) = corner_frames[&lm.vertex_corner[v]];
            }
        }
        // The frame of vertex `v` on the side of face `face`, corner `c`.
        let frame = |v: usize, face: FaceId, c: usize| {
            if lm.is_sided(VertexId::from_idx(v)) {
                corner_frames[&(4 * face.0 + c as u32)]
            } else {
                (e[v], f[v])
            }
        };
        let row = |v: usize, nbr: &mut Vec<u32>, coef: &mut Vec<DVec2>| {
            let vid = VertexId::from_idx(v);
            // Edge v → j of face `face`, where v is corner `cv` and j corner `cj`.
            let mut push = |j: usize, face: FaceId, cv: usize, cj: usize| {
                let d = lm.position[j] - lm.position[v];
                let (ev, fv) = frame(v, face, cv);
                let (ej, fj) = frame(j, face, cj);
                let ai = DVec2::new(d.dot(ev), d.dot(fv));
                let aj = DVec2::new(d.dot(ej), d.dot(fj));
                // c_ij = e^{i(φ_ij − φ_ji)}: rotates j's frame angle into i's.
                let c = if ai.length_squared() > 0.0 && aj.length_squared() > 0.0 {
                    cmul(ai.normalize(), conj(aj.normalize()))
                } else {
                    DVec2::X
                };
                nbr.push(j as u32);
                coef.push(c);
            };
            let mut last = None;
            for h in m.outgoing(vid) {
                let face = m.face_of(h);
                let c = (h - m.face_he(face)) as usize;
                push(m.dest(h).idx(), face, c, (c + 1) % 4);
                last = Some(h);
            }
            // A boundary vertex's fan misses the edge arriving along the boundary.
            if m.is_boundary_vertex(vid) {
                if let Some(h) = last {
                    let p = m.prev(h);
                    let face = m.face_of(p);
                    let c = (p - m.face_he(face)) as usize;
                    push(m.origin(p).idx(), face, (c + 1) % 4, c);
                }
            }
        };
        // Rows `vs`: every row's end (counted from the block's start), neighbours and
        // coefficients.
        let rows = |vs: std::ops::Range<usize>| {
            let mut ends = Vec::with_capacity(vs.len());
            let mut nbr = Vec::new();
            let mut coef = Vec::new();
            for v in vs {
                row(v, &mut nbr, &mut coef);
                ends.push(nbr.len() as u32);
            }
            (ends, nbr, coef)
        };
        const BLOCK: usize = 4096;
        let blocks: Vec<_> = (0..nv.div_ceil(BLOCK))
            .into_par_iter()
            .map(|b| rows(b * BLOCK..((b + 1) * BLOCK).min(nv)))
            .collect();
        let total = blocks.iter().map(|b| b.1.len()).sum();
        let mut start = Vec::with_capacity(nv + 1);
        let mut nbr = Vec::with_capacity(total);
        let mut coef = Vec::with_capacity(total);
        start.push(0u32);
        for (ends, n, c) in blocks {
            let base = nbr.len() as u32;
            start.extend(ends.iter().map(|&x| base + x));
            nbr.extend_from_slice(&n);
            coef.extend_from_slice(&c);
        }
        LevelProblem {
            graph: Graph::new(start, nbr),
            coef,
            e,
            f,
            corner_frames,
            target: vec![DVec2::ZERO; nv],
            pinned: vec![DVec2::NAN; nv],
        }
    }

    fn nv(&self) -> usize {
        self.e.len()
    }

    fn to_complex(&self, v: usize, t: DVec3) -> DVec2 {
        DVec2::new(t.dot(self.e[v]), t.dot(self.f[v]))
    }

    fn to_3d(&self, v: usize, z: DVec2) -> DVec3 {
        self.e[v] * z.x + self.f[v] * z.y
    }

    /// v1 on every face corner's side at the vertices with one normal per side.
    fn corner_v1(&self, lm: &LimitMesh, z: &[DVec2]) -> HashMap<u32, DVec3> {
        self.corner_frames
            .iter()
            .map(|(&k, &(e, f))| {
                let v = lm.mesh.face_vertices(FaceId(k / 4))[(k % 4) as usize] as usize;
                (k, e * z[v].x + f * z[v].y)
            })
            .collect()
    }

    /// The problem of the module doc on this mesh (every edge of weight 1).
    fn problem(&self) -> Problem<'_> {
        let n = self.nv();
        Problem {
            g: &self.graph,
            coef: self.coef.clone(),
            wgt: vec![1.0; self.coef.len()],
            diag: (0..n).map(|i| self.graph.row(i).len() as f64).collect(),
            mass: vec![1.0; n],
            target: self.target.clone(),
            pinned: self.pinned.clone(),
        }
    }
}

/// Nodes at most on the coarsest multigrid level, where the linear relaxation is solved
/// directly (conjugate gradients, cheap at this size).
const COARSEST: usize = 256;
/// Level 1 of the limit meshes up to this many vertices gets the linear relaxation solved
/// on itself (conjugate gradients, superlinear but fast at this size); above, on its
/// multigrid levels ([`fmg`]). Was 32,768: the bunny's level 1 (19,796 vertices) then
/// took its eigenvector by inverse iteration, ~3,900 CG iterations and ~1 s of one core
/// (its two smallest eigenvalues are close, so 30 solves were needed), three quarters
/// of its whole field. Full multigrid finds the same four singularities there, E at the
/// finest level 62.03 instead of 60.62, and the same texture quality (docs/field.md);
/// the field stage takes about a quarter as long.
const EXACT_MAX: usize = 16_384;
/// Gauss–Seidel sweeps before and after each coarse correction of a V-cycle.
const SMOOTHING: usize = 2;
/// Cycles on each coarse level per visit (2: a W-cycle).
const CYCLE_INDEX: usize = 2;
/// Stretch factors of the coarse correction tried besides 1 (see [`vcycle`]).
const OVER_CORRECTION: [f64; 4] = [1.5, 2.0, 3.0, 4.0];
/// Weight of a pinned vertex in a coarse problem built before any field exists (the first
/// descent of [`fmg`]): a target this strong holds the aggregate to the pin.
const PIN_WEIGHT: f64 = 1e4;

/// A graph of the optimisation: CSR adjacency (symmetric) and the colour classes of the
/// Gauss–Seidel sweeps.
struct Graph {
    start: Vec<u32>,
    nbr: Vec<u32>,
    /// Independent sets (no edge inside a class) covering every node: updating one class
    /// in parallel is exactly a sequential sweep over it, for any thread count.
    classes: Vec<Vec<u32>>,
}

impl Graph {
    fn new(start: Vec<u32>, nbr: Vec<u32>) -> Self {
        let classes = colour(&start, &nbr);
        Graph {
            start,
            nbr,
            classes,
        }
    }

    fn nv(&self) -> usize {
        self.start.len() - 1
    }

    #[inline]
    fn row(&self, i: usize) -> std::ops::Range<usize> {
        self.start[i] as usize..self.start[i + 1] as usize
    }
}

/// The energy of the module doc on one graph — the limit mesh's vertices, or aggregates of
/// a finer graph's nodes (a multigrid level) — for unit complex values z:
///
/// E(z) = Σ_edges |c_ij| − Re(z̄_i c_ij z_j) + Σ_i |a_i| − Re(z̄_i a_i).
///
/// On the limit mesh |c_ij| = 1 and a_i = λ × target; on a coarse level c_ij and a_i are
/// sums over the fine edges and nodes an aggregate pair holds (see [`coarse_problem`]).
struct Problem<'g> {
    g: &'g Graph,
    /// Per CSR entry: a neighbour transported to i is c_ij z_j (c_ji = conj(c_ij)).
    coef: Vec<DVec2>,
    /// |c_ij| (exactly 1 on a limit mesh).
    wgt: Vec<f64>,
    /// Diagonal of the quadratic relaxation z^H (D − C) z: the degree on a limit mesh,
    /// the Galerkin diagonal on coarse levels.
    diag: Vec<f64>,
    /// Fine vertices per node (the mass matrix of the relaxation's eigenproblem).
    mass: Vec<f64>,
    /// a_i (already weighted), in the node's frame.
    target: Vec<DVec2>,
    /// Pinned values (NaN = free).
    pinned: Vec<DVec2>,
}

impl Problem<'_> {
    fn nv(&self) -> usize {
        self.g.nv()
    }

    /// E of one node's edges to higher-numbered neighbours and its target, in the
    /// well-conditioned form ½|c|·|z_i − ĉ z_j|² (= |c| − Re(z̄_i c z_j) for unit z), so
    /// small energies are not lost to cancellation.
    #[inline]
    fn node_energy(&self, i: usize, z: &[DVec2]) -> f64 {
        let zi = z[i];
        let mut s = 0.0;
        for k in self.g.row(i) {
            let j = self.g.nbr[k] as usize;
            let w = self.wgt[k];
            if j > i && w > 0.0 {
                let d = zi * w - cmul(self.coef[k], z[j]);
                s += 0.5 * d.length_squared() / w;
            }
        }
        let a = self.target[i];
        let l = a.length();
        if l > 0.0 {
            s += 0.5 * l * (zi - a / l).length_squared();
        }
        s
    }

    /// E (module doc). Partial sums over fixed blocks, added in order: the same value for
    /// any thread count.
    fn energy(&self, z: &[DVec2]) -> f64 {
        const BLOCK: usize = 4096;
        let n = self.nv();
        let parts: Vec<f64> = (0..n.div_ceil(BLOCK))
            .into_par_iter()
            .map(|b| {
                (b * BLOCK..((b + 1) * BLOCK).min(n))
                    .map(|i| self.node_energy(i, z))
                    .sum()
            })
            .collect();
        parts.iter().sum()
    }

    /// The exact minimiser of E over z_i with the neighbours fixed.
    #[inline]
    fn local_optimum(&self, i: usize, z: &[DVec2]) -> DVec2 {
        if !self.pinned[i].x.is_nan() {
            return self.pinned[i];
        }
        let mut s = self.target[i];
        for k in self.g.row(i) {
            s += cmul(self.coef[k], z[self.g.nbr[k] as usize]);
        }
        let l = s.length();
        if l > 1e-300 {
            s / l
        } else {
            z[i]
        }
    }

    /// One nonlinear Gauss–Seidel sweep, class after class; E never rises.
    fn sweep(&self, z: &mut [DVec2], buf: &mut Vec<DVec2>) {
        for class in &self.g.classes {
            if class.len() < 2048 {
                // No edge inside a class: in place is the same as all at once.
                for &i in class {
                    z[i as usize] = self.local_optimum(i as usize, z);
                }
            } else {
                buf.clear();
                buf.resize(class.len(), DVec2::ZERO);
                let zr: &[DVec2] = z;
                buf.par_iter_mut()
                    .with_min_len(1024)
                    .zip(class.par_iter())
                    .for_each(|(out, &i)| *out = self.local_optimum(i as usize, zr));
                for (k, &i) in class.iter().enumerate() {
                    z[i as usize] = buf[k];
                }
            }
        }
    }

    /// Sweeps until E stalls (a sweep lowers it by at most `tol` of itself); returns E
    /// after the start and after every sweep.
    fn relax(&self, z: &mut [DVec2], sweeps: usize, tol: f64) -> Vec<f64> {
        let mut hist = vec![self.energy(z)];
        let mut buf = Vec::new();
        for _ in 0..sweeps {
            let before = *hist.last().unwrap();
            self.sweep(z, &mut buf);
            let after = self.energy(z);
            hist.push(after);
            if before - after <= tol * before.max(1e-300) {
                break;
            }
        }
        hist
    }

    /// y = (D + W − C) x, with `dw` = the diagonal D + W: the relaxation's Hermitian form
    /// plus a diagonal. Returns Re⟨x, y⟩, summed in index order as `Iterator::sum` would
    /// (from −0.0): conjugate gradients needs it right after the product, so it is taken
    /// in the same pass (the same bits as a separate dot product).
    fn apply(&self, dw: &[f64], x: &[DVec2], y: &mut [DVec2]) -> f64 {
        let g = self.g;
        let mut xy = -0.0;
        for (i, (yi, &di)) in y.iter_mut().zip(dw).enumerate() {
            let xi = x[i];
            let mut s = xi * di;
            let row = g.row(i);
            for (c, &j) in self.coef[row.clone()].iter().zip(&g.nbr[row]) {
                s -= cmul(*c, x[j as usize]);
            }
            *yi = s;
            xy += xi.dot(s);
        }
        xy
    }

    /// Conjugate gradients for the Hermitian positive definite (D + W − C) x = b.
    ///
    /// The vector updates are fused into as few passes as the recurrence allows (the same
    /// operations in the same order as one loop per update: the same bits); the solves of
    /// the level-1 eigenvector are the longest serial stretch of the field.
    fn solve(&self, w: &[f64], b: &[DVec2], x: &mut [DVec2], iters: usize, tol: f64) {
        let n = self.nv();
        let dot = |a: &[DVec2], b: &[DVec2]| -> f64 {
            // Re <a, b>; for Hermitian systems the imaginary parts cancel in CG.
            a.iter().zip(b).map(|(p, q)| p.dot(*q)).sum()
        };
        let dw: Vec<f64> = self.diag.iter().zip(w).map(|(d, w)| d + w).collect();
        let mut r = vec![DVec2::ZERO; n];
        self.apply(&dw, x, &mut r);
        for (ri, bi) in r.iter_mut().zip(b) {
            *ri = *bi - *ri;
        }
        let mut p = r.clone();
        let mut ap = vec![DVec2::ZERO; n];
        let mut rr = dot(&r, &r);
        let bb = dot(b, b).max(1e-300);
        for _ in 0..iters {
            if rr <= tol * tol * bb {
                break;
            }
            let pap = self.apply(&dw, &p, &mut ap);
            if pap <= 0.0 {
                break;
            }
            let alpha = rr / pap;
            let mut rr2 = -0.0;
            for (((xi, ri), pi), api) in x.iter_mut().zip(r.iter_mut()).zip(&p).zip(&ap) {
                *xi += *pi * alpha;
                *ri -= *api * alpha;
                rr2 += ri.dot(*ri);
            }
            let beta = rr2 / rr;
            rr = rr2;
            for (pi, ri) in p.iter_mut().zip(&r) {
                *pi = *ri + *pi * beta;
            }
        }
    }

    /// The linear relaxation on the coarsest level (see the module doc).
    fn initial(&self) -> Vec<DVec2> {
        let n = self.nv();
        let has_targets = self.target.iter().any(|a| *a != DVec2::ZERO)
            || self.pinned.iter().any(|p| !p.x.is_nan());
        let mut z: Vec<DVec2> = (0..n)
            .map(|i| {
                // Deterministic pseudo-random start (a hash of the index).
                let h = (i as u64 + 1).wrapping_mul(0x9E37_79B9_7F4A_7C15);
                let a = (h >> 11) as f64 / (1u64 << 53) as f64 * std::f64::consts::TAU;
                DVec2::new(a.cos(), a.sin())
            })
            .collect();
        if has_targets {
            // min z^H L z + Σ w_i |z_i − â_i|^2  →  (L + W) z = W â = target.
            let mut w = vec![0.0; n];
            let mut b = vec![DVec2::ZERO; n];
            for i in 0..n {
                if !self.pinned[i].x.is_nan() {
                    w[i] = 1e4;
                    b[i] = self.pinned[i] * 1e4;
                } else {
                    w[i] = self.target[i].length();
                    b[i] = self.target[i];
                }
                w[i] += 1e-9;
            }
            self.solve(&w, &b, &mut z, 4 * n + 100, 1e-10);
        } else {
            // Inverse iteration: the smallest eigenvector of L x = μ M x.
            let w: Vec<f64> = self.mass.iter().map(|m| 1e-6 * m).collect();
            let mut x = vec![DVec2::ZERO; n];
            let mut b = vec![DVec2::ZERO; n];
            // 1 − |⟨z_k, z_k+1⟩| of the last step (unit vectors): how far from converged.
            let mut change = 1.0f64;
            for _ in 0..30 {
                let norm = z.iter().map(|c| c.length_squared()).sum::<f64>().sqrt();
                for c in z.iter_mut() {
                    *c /= norm;
                }
                x.copy_from_slice(&z);
                for i in 0..n {
                    b[i] = z[i] * self.mass[i];
                }
                // Inexact inverse iteration: each solve only as exact as the eigenvector
                // estimate is, down to the old fixed 1e-8 once it has converged. The first
                // solves from the random start took 500 CG iterations each for a vector
                // that was still mostly wrong (bunny, level 1 with 19,796 vertices: 6,500
                // iterations in all, 0.81 s; now ~4,000, 0.51 s; E at the finest level the
                // same to 1e-10).
                let tol = (0.1 * change).clamp(1e-8, 1e-2);
                self.solve(&w, &b, &mut x, 2 * n + 100, tol);
                let nx = x.iter().map(|c| c.length_squared()).sum::<f64>().sqrt();
                // z is a unit vector here; Hermitian ⟨z, x⟩ = Σ conj(z_i) x_i.
                let ip = z
                    .iter()
                    .zip(&x)
                    .fold(DVec2::ZERO, |a, (p, q)| {
                        a + DVec2::new(p.x * q.x + p.y * q.y, p.x * q.y - p.y * q.x)
                    })
                    .length();
                change = if nx > 0.0 { 1.0 - ip / nx } else { 1.0 };
                std::mem::swap(&mut z, &mut x);
            }
        }
        for (i, c) in z.iter_mut().enumerate() {
            let l = c.length();
            *c = if !self.pinned[i].x.is_nan() {
                self.pinned[i]
            } else if l > 1e-300 && l.is_finite() {
                *c / l
            } else {
                DVec2::X
            };
        }
        z
    }
}

/// One multigrid coarsening: nodes grouped into aggregates (a node and its free
/// neighbours, the rest joining a neighbouring aggregate; Vaněk et al.'s greedy
/// aggregation), and the graph of aggregates. It depends on the graph only; the coarse
/// problem's values are rebuilt from the current field every cycle ([`coarse_problem`]).
struct Coarsening {
    /// Aggregate of every fine node.
    agg: Vec<u32>,
    /// Fine nodes of aggregate a: members[mstart[a]..mstart[a + 1]], ascending.
    mstart: Vec<u32>,
    members: Vec<u32>,
    /// For every fine CSR entry: its coarse CSR entry, or `u32::MAX` inside an aggregate.
    map: Vec<u32>,
    /// The fine CSR entry through which a node joined its aggregate (`u32::MAX` at roots),
    /// and whether it joined the root (1) or a neighbour of it (2); 0 at roots.
    via: Vec<u32>,
    pass: Vec<u8>,
    coarse: Graph,
}

impl Coarsening {
    /// None when the graph barely shrinks (nothing left to gain). `fixed` nodes (pins)
    /// stay alone, one aggregate each, so a pin holds only itself on every level, never
    /// the aggregates around it.
    fn new(g: &Graph, fixed: &[bool]) -> Option<Self> {
        const FREE: u32 = u32::MAX;
        let n = g.nv();
        let mut agg = vec![FREE; n];
        let mut via = vec![FREE; n];
        let mut pass = vec![0u8; n];
        let mut na = 0u32;
        for i in 0..n {
            if fixed[i]
                || agg[i] != FREE
                || g.row(i).any(|k| {
                    let j = g.nbr[k] as usize;
                    !fixed[j] && agg[j] != FREE
                })
            {
                continue;
            }
            agg[i] = na;
            for k in g.row(i) {
                let j = g.nbr[k] as usize;
                if fixed[j] {
                    continue;
                }
                agg[j] = na;
                pass[j] = 1;
                via[j] = g
                    .row(j)
                    .find(|&kk| g.nbr[kk] as usize == i)
                    .expect("adjacency is symmetric") as u32;
            }
            na += 1;
        }
        // Every node still free has a neighbour aggregated above (else it would be a root).
        for i in 0..n {
            if fixed[i] {
                agg[i] = na;
                na += 1;
                continue;
            }
            if agg[i] != FREE {
                continue;
            }
            let k = g
                .row(i)
                .find(|&k| {
                    let j = g.nbr[k] as usize;
                    !fixed[j] && agg[j] != FREE && pass[j] <= 1
                })
                .expect("a free node neighbours an aggregate");
            agg[i] = agg[g.nbr[k] as usize];
            via[i] = k as u32;
            pass[i] = 2;
        }
        let na = na as usize;
        if na as f64 > 0.75 * n as f64 {
            return None;
        }
        let mut mstart = vec![0u32; na + 1];
        for &a in &agg {
            mstart[a as usize + 1] += 1;
        }
        for a in 0..na {
            mstart[a + 1] += mstart[a];
        }
        let mut fill = mstart.clone();
        let mut members = vec![0u32; n];
        for (i, &a) in agg.iter().enumerate() {
            members[fill[a as usize] as usize] = i as u32;
            fill[a as usize] += 1;
        }
        let mut map = vec![u32::MAX; g.nbr.len()];
        let mut start = Vec::with_capacity(na + 1);
        let mut nbr = Vec::new();
        let mut seen = vec![u32::MAX; na];
        let mut pos = vec![0u32; na];
        start.push(0u32);
        for a in 0..na {
            for &i in &members[mstart[a] as usize..mstart[a + 1] as usize] {
                for k in g.row(i as usize) {
                    let b = agg[g.nbr[k] as usize] as usize;
                    if b == a {
                        continue;
                    }
                    if seen[b] != a as u32 {
                        seen[b] = a as u32;
                        pos[b] = nbr.len() as u32;
                        nbr.push(b as u32);
                    }
                    map[k] = pos[b];
                }
            }
            start.push(nbr.len() as u32);
        }
        Some(Coarsening {
            agg,
            mstart,
            members,
            map,
            via,
            pass,
            coarse: Graph::new(start, nbr),
        })
    }

    fn members(&self, a: usize) -> &[u32] {
        &self.members[self.mstart[a] as usize..self.mstart[a + 1] as usize]
    }

    /// A field that is parallel inside every aggregate (each node the root's value
    /// transported along the edge it joined by), with every root at 1: the start of the
    /// first descent, where no field exists yet.
    fn transports(&self, p: &Problem) -> Vec<DVec2> {
        let n = self.agg.len();
        let mut t = vec![DVec2::X; n];
        // Roots first (1), then their neighbours, then the nodes that joined those.
        for step in 1..=2u8 {
            for i in 0..n {
                if self.pass[i] == step {
                    let k = self.via[i] as usize;
                    let j = p.g.nbr[k] as usize;
                    t[i] = cmul(p.coef[k], t[j]).try_normalize().unwrap_or(DVec2::X);
                }
            }
        }
        t
    }
}

/// The coarse problem of `p` at the field `z`: the energy of turning every aggregate by a
/// unit complex r_A (each fine z_i → z_i r_A). Inside an aggregate nothing changes; across,
/// E(z·r) = Σ_AB |C_AB| − Re(r̄_A C_AB r_B) + Σ_A |T_A| − Re(r̄_A T_A) + const, with
/// C_AB = Σ z̄_i c_ij z_j over the fine edges between A and B and T_A = Σ z̄_i a_i: the
/// same form as E, so the coarse level is solved the same way, and every decrease of the
/// coarse energy is the same decrease of the fine one. Aggregates holding a pinned vertex
/// stay at r = 1, or — with `pins_as_targets`, before any field exists — are pulled to
/// the pin by a strong target.
fn coarse_problem<'c>(
    p: &Problem,
    c: &'c Coarsening,
    z: &[DVec2],
    pins_as_targets: bool,
) -> Problem<'c> {
    let na = c.coarse.nv();
    let mut coef = vec![DVec2::ZERO; c.coarse.nbr.len()];
    // Every aggregate fills its own row (and scalars): in parallel, each in a fixed order.
    let mut rows: Vec<&mut [DVec2]> = Vec::with_capacity(na);
    let mut tail: &mut [DVec2] = &mut coef;
    for a in 0..na {
        let (row, rest) = tail.split_at_mut(c.coarse.row(a).len());
        rows.push(row);
        tail = rest;
    }
    type Scalars = (Vec<f64>, Vec<f64>);
    let ((diag, mass), (target, pinned)): (Scalars, (Vec<DVec2>, Vec<DVec2>)) = rows
        .into_par_iter()
        .enumerate()
        .with_min_len(256)
        .map(|(a, row)| {
            let base = c.coarse.start[a];
            let (mut diag, mut mass, mut target, mut pinned) = (0.0, 0.0, DVec2::ZERO, DVec2::NAN);
            for &i in c.members(a) {
                let i = i as usize;
                let zi = conj(z[i]);
                mass += p.mass[i];
                diag += p.diag[i];
                target += cmul(zi, p.target[i]);
                if !p.pinned[i].x.is_nan() {
                    if pins_as_targets {
                        target += cmul(zi, p.pinned[i]) * PIN_WEIGHT;
                    } else {
                        pinned = DVec2::X;
                    }
                }
                for k in p.g.row(i) {
                    let v = cmul(zi, cmul(p.coef[k], z[p.g.nbr[k] as usize]));
                    match c.map[k] {
                        u32::MAX => diag -= v.x,
                        m => row[(m - base) as usize] += v,
                    }
                }
            }
            ((diag, mass), (target, pinned))
        })
        .unzip();
    // Per-entry values: in parallel on the larger levels, the same values.
    let wgt = coef
        .par_iter()
        .with_min_len(4096)
        .map(|c| c.length())
        .collect();
    Problem {
        g: &c.coarse,
        coef,
        wgt,
        diag,
        mass,
        target,
        pinned,
    }
}

/// Turns every node by its aggregate's coarse value (pins stay).
fn prolong(p: &Problem, c: &Coarsening, r: &[DVec2], z: &mut [DVec2]) {
    // Every node alone: in parallel on the larger levels, the same values.
    z.par_iter_mut()
        .with_min_len(2048)
        .enumerate()
        .for_each(|(i, zi)| {
            if p.pinned[i].x.is_nan() {
                *zi = cmul(*zi, r[c.agg[i] as usize])
                    .try_normalize()
                    .unwrap_or(*zi);
            }
        });
}

/// A field from nothing, coarse to fine (full multigrid): the coarsest level gets the
/// linear relaxation, every finer one the coarse result turned onto its aggregates, then
/// one V-cycle.
fn fmg(p: &Problem, hier: &[Coarsening], opts: &FieldOptions) -> Vec<DVec2> {
    let Some((c, rest)) = hier.split_first() else {
        let mut z = p.initial();
        p.relax(&mut z, opts.max_sweeps * 10, opts.tolerance);
        return z;
    };
    let mut z = c.transports(p);
    let q = coarse_problem(p, c, &z, true);
    let r = fmg(&q, rest, opts);
    prolong(p, c, &r, &mut z);
    for (i, zi) in z.iter_mut().enumerate() {
        if !p.pinned[i].x.is_nan() {
            *zi = p.pinned[i];
        }
    }
    vcycle(p, &mut z, hier, opts);
    z
}

/// One V-cycle: smooth, correct by the coarse problem's rotations (recursively), smooth.
/// E never rises.
fn vcycle(p: &Problem, z: &mut [DVec2], hier: &[Coarsening], opts: &FieldOptions) {
    let mut buf = Vec::new();
    let Some((c, rest)) = hier.split_first() else {
        // The coarsest level (small): relaxed until E stalls.
        p.relax(z, opts.max_sweeps, opts.tolerance);
        return;
    };
    for _ in 0..SMOOTHING {
        p.sweep(z, &mut buf);
    }
    let q = coarse_problem(p, c, z, false);
    let mut r = vec![DVec2::X; q.nv()];
    for _ in 0..CYCLE_INDEX {
        vcycle(&q, &mut r, rest, opts);
    }
    // Over-correction: piecewise-constant rotations under-estimate the smooth corrections
    // (aggregation multigrid), so the turn is stretched by the best factor on the coarse
    // energy, which is the fine energy's change exactly; 1 is a candidate, so E cannot rise.
    let mut best = (q.energy(&r), 1.0);
    let mut scaled = r.clone();
    // Every node's turn alone: in parallel on the larger levels, the same values.
    let turn = |out: &mut [DVec2], alpha: f64| {
        out.par_iter_mut()
            .with_min_len(2048)
            .zip(r.par_iter())
            .zip(q.pinned.par_iter())
            .for_each(|((s, x), pin)| {
                *s = if pin.x.is_nan() {
                    let (sn, cs) = (x.y.atan2(x.x) * alpha).sin_cos();
                    DVec2::new(cs, sn)
                } else {
                    *pin
                };
            });
    };
    for alpha in OVER_CORRECTION {
        turn(&mut scaled, alpha);
        let e = q.energy(&scaled);
        if e < best.0 {
            best = (e, alpha);
        }
    }
    if best.1 != 1.0 {
        turn(&mut scaled, best.1);
        r = scaled;
    }
    prolong(p, c, &r, z);
    for _ in 0..SMOOTHING {
        p.sweep(z, &mut buf);
    }
}

/// The multigrid levels below `g`, down to [`COARSEST`] nodes; `fixed` marks its pinned
/// nodes (each stays a node of its own on every level).
fn hierarchy(g: &Graph, fixed: &[bool]) -> Vec<Coarsening> {
    let mut out: Vec<Coarsening> = Vec::new();
    let mut fixed = fixed.to_vec();
    loop {
        let cur = out.last().map_or(g, |c| &c.coarse);
        if cur.nv() <= COARSEST {
            break;
        }
        match Coarsening::new(cur, &fixed) {
            Some(c) => {
                let mut next = vec![false; c.coarse.nv()];
                for (i, &f) in fixed.iter().enumerate() {
                    if f {
                        next[c.agg[i] as usize] = true;
                    }
                }
                fixed = next;
                out.push(c);
            }
            None => break,
        }
    }
    out
}

/// Splits nodes into independent sets: two classes when the graph is bipartite (refined
/// meshes are: every edge joins an edge point to a vertex or face point), else greedy
/// colours in index order.
fn colour(start: &[u32], nbr: &[u32]) -> Vec<Vec<u32>> {
    if let Some(two) = two_colour(start, nbr) {
        return two;
    }
    let n = start.len() - 1;
    let mut col = vec![u32::MAX; n];
    let mut stamp: Vec<u32> = Vec::new();
    let mut classes: Vec<Vec<u32>> = Vec::new();
    for i in 0..n {
        for &j in &nbr[start[i] as usize..start[i + 1] as usize] {
            let cj = col[j as usize];
            if cj != u32::MAX {
                stamp[cj as usize] = i as u32;
            }
        }
        let c = (0..stamp.len())
            .find(|&c| stamp[c] != i as u32)
            .unwrap_or_else(|| {
                stamp.push(u32::MAX);
                classes.push(Vec::new());
                stamp.len() - 1
            });
        col[i] = c as u32;
        classes[c].push(i as u32);
    }
    classes
}

/// The tangent frame (e, n × e) of every face corner's side at the vertices of `lm` with one
/// normal per side (module doc, "Across infinitely sharp creases"), by 4·face + corner.
fn sided_frames(lm: &LimitMesh) -> HashMap<u32, (DVec3, DVec3)> {
    let m = &lm.mesh;
    let mut out = HashMap::new();
    for v in 0..m.num_vertices() {
        let vid = VertexId::from_idx(v);
        if !lm.is_sided(vid) {
            continue;
        }
        let x = lm.position[v];
        let corner = |h: u32| {
            let face = m.face_of(h);
            (face, (h - m.face_he(face)) as usize)
        };
        // Sectors by their first half-edge, each with its normal.
        let outs: Vec<u32> = m.outgoing(vid).collect();
        let mut sectors: Vec<(u32, DVec3)> = Vec::new();
        let sector_of: Vec<usize> = outs
            .iter()
            .map(|&h| {
                let first = m.sector(h).first;
                sectors
                    .iter()
                    .position(|s| s.0 == first)
                    .unwrap_or_else(|| {
                        let (face, c) = corner(first);
                        sectors.push((first, lm.corner_normal(face, c)));
                        sectors.len() - 1
                    })
            })
            .collect();
        // The infinitely sharp edges shared by two sectors (not on the boundary).
        let shared: Vec<DVec3> = m
            .vertex_edges(vid)
            .filter(|&(h, _)| m.twin(h).is_some() && m.edge_sharpness(h).is_infinite())
            .map(|(_, w)| lm.position[w.idx()] - x)
            .collect();
        // One tangent both sides contain where two sectors meet: along the crease.
        let common = match (sectors.as_slice(), shared.as_slice()) {
            ([(_, na), (_, nb)], [a, b]) => {
                let t = na.cross(*nb);
                let chord = *a - *b;
                Some(if t.length() > 1e-3 {
                    t * t.dot(chord).signum()
                } else {
                    chord
                })
            }
            ([_, _], [a]) => Some(*a),
            _ => None,
        };
        // Otherwise (corners, cones) the sectors are unfolded one after the other: sector
        // s starts at its leading edge, turned back by the angles of the sectors before it,
        // so the field crosses every shared edge but the one closing the fan unfolded.
        let unit = |d: DVec3, n: DVec3| {
            (d - n * n.dot(d))
                .try_normalize()
                .unwrap_or_else(|| n.any_orthonormal_vector())
        };
        let mut turned = 0.0f64;
        let mut frames: Vec<(DVec3, DVec3)> = Vec::with_capacity(sectors.len());
        for &(first, n) in &sectors {
            let lead = unit(lm.position[m.dest(first).idx()] - x, n);
            let e = match common {
                Some(d) => unit(d, n),
                None => {
                    let (sn, cs) = (-turned).sin_cos();
                    lead * cs + n.cross(lead) * sn
                }
            };
            frames.push((e, n.cross(e)));
            // This sector's angle at the vertex: from its leading to its trailing edge.
            let mut last = first;
            for _ in 1..m.sector(first).faces {
                last = m.twin(m.prev(last)).expect("faces of a sector are joined");
            }
            let trail = unit(lm.position[m.origin(m.prev(last)).idx()] - x, n);
            turned += n
                .cross(lead)
                .dot(trail)
                .atan2(lead.dot(trail))
                .rem_euclid(std::f64::consts::TAU);
        }
        for (k, &h) in outs.iter().enumerate() {
            let (face, c) = corner(h);
            out.insert(4 * face.0 + c as u32, frames[sector_of[k]]);
        }
    }
    out
}

/// `auto` leaves one freedom: E (without targets) is unchanged when every vector turns by
/// the same angle about its normal, and the eigenvector's phase is arbitrary. Fix it
/// predictably: turn the field so that it follows world +x as closely as possible (least
/// squares over the vertices), or +y, then +z where the axis is (almost) normal everywhere
/// or the field winds around it. On a flat grid in the xy plane v1 is then exactly +x, so
/// the texture lines up with the grid (and with the face maps when u runs along +x).
fn align_global_rotation(lm: &LimitMesh, v1: &mut [DVec3], corner_v1: &mut HashMap<u32, DVec3>) {
    for axis in [DVec3::X, DVec3::Y, DVec3::Z] {
        let mut sum = DVec2::ZERO;
        let mut total = 0.0;
        for (v, n) in v1.iter().zip(&lm.normal) {
            let w = n.cross(*v);
            sum += DVec2::new(axis.dot(*v), axis.dot(w));
            total += (axis - n * axis.dot(*n)).length();
        }
        // Meaningful only where the axis is not (almost) normal to the surface throughout.
        if sum.length() > 0.05 * total && total > 1e-3 * v1.len() as f64 {
            let c = sum / sum.length();
            let turn = |v: &mut DVec3, n: DVec3| {
                let r = *v * c.x + n.cross(*v) * c.y;
                *v = r.try_normalize().unwrap_or(*v);
            };
            for (v, n) in v1.iter_mut().zip(&lm.normal) {
                turn(v, *n);
            }
            // The same turn on every side (the same angle in every sector's frame).
            for (&k, v) in corner_v1.iter_mut() {
                turn(v, lm.corner_normal(FaceId(k / 4), (k % 4) as usize));
            }
            return;
        }
    }
}

/// Splits vertices into two classes with no edge inside a class (BFS), or None if the
/// graph is not bipartite.
fn two_colour(start: &[u32], nbr: &[u32]) -> Option<Vec<Vec<u32>>> {
    let n = start.len() - 1;
    let mut col = vec![u8::MAX; n];
    let mut queue = Vec::new();
    for s in 0..n {
        if col[s] != u8::MAX {
            continue;
        }
        col[s] = 0;
        queue.clear();
        queue.push(s as u32);
        let mut head = 0;
        while head < queue.len() {
            let i = queue[head] as usize;
            head += 1;
            for &j in &nbr[start[i] as usize..start[i + 1] as usize] {
                let j = j as usize;
                if col[j] == u8::MAX {
                    col[j] = 1 - col[i];
                    queue.push(j as u32);
                } else if col[j] == col[i] {
                    return None;
                }
            }
        }
    }
    let a = (0..n as u32).filter(|&i| col[i as usize] == 0).collect();
    let b = (0..n as u32).filter(|&i| col[i as usize] == 1).collect();
    Some(vec![a, b])
}

/// About this many texels per face of the field's limit mesh are enough (8 x 8): the
/// automatic level ([`auto_level`]) stops refining once every face holds no more than
/// that on average. Measured on Spot at N = 32 (level 3 instead of 5, docs/field.md):
/// field stage 0.6–0.7 → 0.06–0.12 s, pfS, seams and scale fidelity of every method within
/// their seed-to-seed spread.
pub const TEXELS_PER_FACE: u64 = 64;

/// Finest level of the smoothest field (`auto`) when it is sized by a texel count
/// ([`FieldOptions::texels`]): 64 faces per base quad. Without targets the field is the
/// smoothest one the surface allows — it turns only as the surface's shape makes it, at the
/// scale of the control mesh, not of the texels — and is blended bilinearly inside faces, so
/// a finer level than this only costs time once texels outnumber its faces. Measured on
/// Spot at N = 128 (level 4 instead of 5; docs/field.md, "Level"): the field moves by a
/// median 0.36° (p99 4.4°, near singularities), turns as little between adjacent texels
/// (0.1333° against 0.1331°), coherent's pf4/pf8/seams stay within the seeds' spread, and
/// the field stage takes about a third of its time. Fields with targets (`up`, axes,
/// constraints) follow the surface's normal and put singularities where it is level: on
/// level 4 texture optimisation with `up` lost 6% of pf8 on bricks, so they keep the
/// texel-count level.
pub const SMOOTH_MAX_LEVEL: u32 = 4;

/// The level [`OrientationField::compute_with`] puts the field of `orientation` on with
/// `opts` (the smoothest field's cap included), without computing it.
pub fn planned_level(surface: &Surface, orientation: &Orientation, opts: &FieldOptions) -> u32 {
    final_level(
        surface,
        smooth_capped(orientation, opts).as_ref().unwrap_or(opts),
    )
}

/// `opts` capped for the smoothest field sized by the texel count, which has no detail
/// finer than the surface's own shape: level [`SMOOTH_MAX_LEVEL`] at most, whatever the
/// texel count (`None`: `opts` as they are).
fn smooth_capped(orientation: &Orientation, opts: &FieldOptions) -> Option<FieldOptions> {
    (*orientation == Orientation::Auto && opts.level.is_none() && opts.texels.is_some()).then(
        || FieldOptions {
            max_level: opts.max_level.min(SMOOTH_MAX_LEVEL),
            ..opts.clone()
        },
    )
}

/// The level the field lives on: [`FieldOptions::level`], or the automatic one.
fn final_level(surface: &Surface, opts: &FieldOptions) -> u32 {
    match opts.level {
        Some(l) => l.max(1),
        None => auto_level(surface.num_base_quads(), opts),
    }
}

/// The automatic level for `base_quads` base quads: the finest in 1..=`max_level` within
/// the face budget, and no finer than the first with a face per [`TEXELS_PER_FACE`] of
/// `opts.texels` (when given).
pub fn auto_level(base_quads: usize, opts: &FieldOptions) -> u32 {
    let at = |l: u32| (base_quads as u64) << (2 * (l - 1));
    let enough = opts.texels.map(|t| t.div_ceil(TEXELS_PER_FACE));
    let mut l = 1;
    while l < opts.max_level.max(1)
        && at(l + 1) <= opts.max_faces as u64
        && enough.is_none_or(|e| at(l) < e)
    {
        l += 1;
    }
    l
}

/// Bilinear weights of corners (0,0), (1,0), (1,1), (0,1).
#[inline]
fn bilinear(s: f64, t: f64) -> [f64; 4] {
    [(1.0 - s) * (1.0 - t), s * (1.0 - t), s * t, (1.0 - s) * t]
}

/// v1 at corner `c` of level face `f`: on the face's side where the vertex has two.
#[inline]
fn corner_vector(
    lm: &LimitMesh,
    v1: &[DVec3],
    corner_v1: &HashMap<u32, DVec3>,
    f: FaceId,
    c: usize,
) -> DVec3 {
    let v = lm.mesh.face_vertices(f)[c];
    if lm.is_sided(VertexId(v)) {
        corner_v1[&(4 * f.0 + c as u32)]
    } else {
        v1[v as usize]
    }
}

/// Blend of per-vertex vectors over the level face holding a base point.
fn blend(
    lm: &LimitMesh,
    v1: &[DVec3],
    corner_v1: &HashMap<u32, DVec3>,
    loc: BaseLocation,
) -> (DVec3, DVec3) {
    let (f, s, t) = lm.locate(loc.quad, loc.s, loc.t);
    let w = bilinear(s, t);
    let mut acc = DVec3::ZERO;
    let mut best = (0.0, DVec3::ZERO);
    for (c, &wc) in w.iter().enumerate() {
        let x = corner_vector(lm, v1, corner_v1, f, c);
        acc += x * wc;
        if wc > best.0 {
            best = (wc, x);
        }
    }
    (acc, best.1)
}

impl OrientationField {
    /// Computes the field for `surface` with the default [`FieldOptions`].
    pub fn compute(surface: &Surface, orientation: &Orientation) -> anyhow::Result<Self> {
        Self::compute_with(surface, orientation, &FieldOptions::default())
    }

    /// Computes the field (see the module doc for the method); `straight` scores the
    /// candidates first (module `choice`).
    pub fn compute_with(
        surface: &Surface,
        orientation: &Orientation,
        opts: &FieldOptions,
    ) -> anyhow::Result<Self> {
        if let Orientation::Upright(a) = orientation {
            check_axis(*a)?;
            let level = choice::SCORE_LEVEL.min(final_level(surface, opts));
            let (chosen, choice) = choice::upright(surface, *a, level);
            let mut field = Self::compute_fixed(surface, &chosen, opts)?;
            field.label = orientation.label();
            field.choice = Some(choice);
            return Ok(field);
        }
        if let Some(capped) = smooth_capped(orientation, opts) {
            return Self::compute_fixed(surface, orientation, &capped);
        }
        if *orientation != Orientation::Straight {
            return Self::compute_fixed(surface, orientation, opts);
        }
        let length = opts.structure_length.unwrap_or_else(|| {
            let (lo, hi) = surface.bounds();
            (hi - lo).length() / 16.0
        });
        let level = final_level(surface, opts);
        let (chosen, choice, done) = choice::straightest(surface, opts, level, length)?;
        let mut field = match done {
            Some(f) => f,
            None => Self::compute_fixed(surface, &chosen, opts)?,
        };
        field.label = orientation.label();
        field.choice = Some(choice);
        Ok(field)
    }

    /// What `straight` chose and the candidates' scores (None for other orientations).
    pub fn choice(&self) -> Option<&Choice> {
        self.choice.as_ref()
    }

    /// The field of one orientation that needs no choosing (not `straight`).
    fn compute_fixed(
        surface: &Surface,
        orientation: &Orientation,
        opts: &FieldOptions,
    ) -> anyhow::Result<Self> {
        let constraints = match orientation {
            Orientation::Auto | Orientation::Straight => Constraints::default(),
            Orientation::Axis(a) | Orientation::Up(a) | Orientation::Upright(a) => {
                check_axis(*a)?;
                let hint = vec![(a.normalize(), 1.0)];
                match orientation {
                    // `Upright` is resolved to `Up` or `Auto` before this (compute_with).
                    Orientation::Up(_) | Orientation::Upright(_) => Constraints {
                        ups: hint,
                        ..Default::default()
                    },
                    _ => Constraints {
                        axes: hint,
                        ..Default::default()
                    },
                }
            }
            Orientation::Constraints(p) => {
                let mut c = Constraints::load(p)?;
                if opts.unit.is_finite() && opts.unit > 0.0 && opts.unit != 1.0 {
                    for (point, radius, _) in &mut c.points {
                        *point /= opts.unit;
                        *radius = radius.map(|r| r / opts.unit);
                    }
                }
                c
            }
        };
        let nctl = surface.control.mesh.num_vertices();
        for (k, &(i, _)) in constraints.vertices.iter().enumerate() {
            if i >= nctl {
                let at = match (&constraints.path, constraints.vertex_lines.get(k)) {
                    (Some(p), Some(l)) => format!("{}: line {l}: ", p.display()),
                    (Some(p), None) => format!("{}: ", p.display()),
                    _ => String::new(),
                };
                bail!("{at}constraint on vertex {i}, but the mesh has {nctl} vertices (0-based)");
            }
        }
        let level = final_level(surface, opts);
        let (lo, hi) = surface.bounds();
        let diag = (hi - lo).length().max(1e-300);

        let mut history = Vec::new();
        let mut prev: Option<(LimitMesh, Vec<DVec3>, HashMap<u32, DVec3>)> = None;
        for lev in 1..=level {
            let lm = surface.limit_mesh(lev);
            let mut lp = LevelProblem::new(&lm);
            set_targets(&mut lp, &lm, &constraints, opts.target_weight, diag)?;
            let prob = lp.problem();
            let pins: Vec<bool> = lp.pinned.iter().map(|p| !p.x.is_nan()).collect();
            let hier = hierarchy(&lp.graph, &pins);
            let (mut z, mut energy) = match &prev {
                // Level 1, small: the linear relaxation solved as it is (its eigenvector
                // places the singularities), big: the same on its multigrid levels.
                None if hier.is_empty() || prob.nv() <= EXACT_MAX => {
                    let mut z = prob.initial();
                    let e = if hier.is_empty() {
                        prob.relax(&mut z, opts.max_sweeps * 10, opts.tolerance)
                    } else {
                        vec![prob.energy(&z)]
                    };
                    (z, e)
                }
                None => {
                    let z = fmg(&prob, &hier, opts);
                    let e = vec![prob.energy(&z)];
                    (z, e)
                }
                Some((plm, pv1, pcv1)) => {
                    // Each vertex's start alone: in parallel, the same values.
                    let z: Vec<DVec2> = (0..lp.nv())
                        .into_par_iter()
                        .with_min_len(1024)
                        .map(|i| {
                            if !lp.pinned[i].x.is_nan() {
                                return lp.pinned[i];
                            }
                            let (acc, best) = blend(plm, pv1, pcv1, lm.vertex_location[i]);
                            let mut c = lp.to_complex(i, acc);
                            if c.length() < 1e-9 {
                                c = lp.to_complex(i, best);
                            }
                            c.try_normalize().unwrap_or(DVec2::X)
                        })
                        .collect();
                    let e = vec![prob.energy(&z)];
                    (z, e)
                }
            };
            if hier.is_empty() {
                if prev.is_some() {
                    energy = prob.relax(&mut z, opts.max_sweeps, opts.tolerance);
                }
            } else {
                for cycle in 0..opts.max_cycles.max(2) {
                    let before = *energy.last().unwrap();
                    vcycle(&prob, &mut z, &hier, opts);
                    let after = prob.energy(&z);
                    energy.push(after);
                    if cycle >= 1 && before - after <= opts.tolerance * before.max(1e-300) {
                        break;
                    }
                }
            }
            history.push(LevelHistory {
                level: lev,
                vertices: lp.nv(),
                energy,
            });
            let v1: Vec<DVec3> = (0..lp.nv())
                .into_par_iter()
                .with_min_len(4096)
                .map(|i| lp.to_3d(i, z[i]))
                .collect();
            let corner_v1 = lp.corner_v1(&lm, &z);
            prev = Some((lm, v1, corner_v1));
        }
        let (mesh, mut v1, mut corner_v1) = prev.expect("at least one level");
        if *orientation == Orientation::Auto {
            align_global_rotation(&mesh, &mut v1, &mut corner_v1);
        }
        Ok(OrientationField {
            mesh,
            v1,
            corner_v1,
            history,
            label: orientation.label(),
            choice: None,
        })
    }

    /// The limit mesh the field lives on (also the mesh surface marching walks on).
    pub fn limit_mesh(&self) -> &LimitMesh {
        &self.mesh
    }

    /// v1 at every vertex of [`Self::limit_mesh`] (unit, tangent).
    pub fn vertex_v1(&self) -> &[DVec3] {
        &self.v1
    }

    /// The level of the limit mesh.
    pub fn level(&self) -> u32 {
        self.mesh.level
    }

    /// Energy after every half-sweep, per level (coarse to fine).
    pub fn history(&self) -> &[LevelHistory] {
        &self.history
    }

    /// `auto`, `+x`, ... or the constraints file, as given.
    pub fn label(&self) -> &str {
        &self.label
    }

    /// The frame at a domain point.
    pub fn frame(&self, surface: &Surface, d: DomainId, u: f64, v: f64) -> Frame {
        let e = surface.eval(d, u, v);
        let loc = surface.base_location(subdiv::DomainLocation { domain: d, u, v });
        self.frame_at(loc, e.n, e.du)
    }

    /// [`Self::frame`] evaluating the surface through `hint`
    /// ([`Surface::eval_base_derivs`]): the same bits, and the same base location is not
    /// computed twice. For runs of neighbouring points (a domain's texel centres).
    pub fn frame_hinted(
        &self,
        surface: &Surface,
        d: DomainId,
        u: f64,
        v: f64,
        hint: &mut LeafHint,
    ) -> Frame {
        let (quad, s, t, jac) = surface.domain_to_base(d, u, v);
        let e = surface.eval_base_derivs(quad, s, t, hint).sample();
        let du = e.du * jac[0][0] + e.dv * jac[1][0];
        self.frame_at(BaseLocation { quad, s, t }, e.n, du)
    }

    /// The frame at a base point whose unit normal `n` is already known (saves an
    /// evaluation); `fallback` is used only where the field vanishes (at a singularity).
    pub fn frame_at(&self, loc: BaseLocation, n: DVec3, fallback: DVec3) -> Frame {
        self.frame_at_with(loc, n, || fallback)
    }

    /// [`Self::frame_at`] computing `fallback` only where it is used (the same bits).
    #[inline]
    pub fn frame_at_with(
        &self,
        loc: BaseLocation,
        n: DVec3,
        fallback: impl FnOnce() -> DVec3,
    ) -> Frame {
        let (acc, best) = blend(&self.mesh, &self.v1, &self.corner_v1, loc);
        let t = acc - n * n.dot(acc);
        let dir = if t.length_squared() > 1e-16 { t } else { best };
        Frame::from_direction_with(dir, n, fallback)
    }

    /// [`Self::frame`] at domain point (u, v) whose exact unit normal `n` is known (the
    /// bits [`Surface::eval`] gives there): the same frame without evaluating the surface,
    /// but for the derivative the frame falls back on where the field vanishes (rare). The
    /// texel geometry evaluates the surface at the texel centres anyway; evaluating it
    /// again for the frames was ~6% of a bunny run ([`crate::texels::FrameSlots`]).
    #[inline]
    pub fn frame_with_normal(
        &self,
        surface: &Surface,
        d: DomainId,
        u: f64,
        v: f64,
        n: DVec3,
    ) -> Frame {
        let loc = surface.base_location(subdiv::DomainLocation { domain: d, u, v });
        self.frame_at_with(loc, n, || surface.eval(d, u, v).du)
    }

    /// Frames at all texel centres of `n`×`n` maps: domain-major, then row (v) then column
    /// (u), i.e. index (d·n + y)·n + x for (u, v) = ((x+0.5)/n, (y+0.5)/n). Computed in
    /// parallel; the result does not depend on the thread count.
    pub fn texel_frames(&self, surface: &Surface, n: usize) -> Vec<Frame> {
        let nd = surface.num_domains();
        let mut out = vec![Frame::default(); nd * n * n];
        if n == 0 {
            return out;
        }
        out.par_chunks_mut(n * n)
            .enumerate()
            .for_each(|(d, chunk)| {
                let inv = 1.0 / n as f64;
                for y in 0..n {
                    for x in 0..n {
                        let (u, v) = ((x as f64 + 0.5) * inv, (y as f64 + 0.5) * inv);
                        chunk[y * n + x] = self.frame(surface, DomainId::from_idx(d), u, v);
                    }
                }
            });
        out
    }

    /// Singular faces of the discrete field on [`Self::limit_mesh`]: faces around which the
    /// field turns a non-zero number of times relative to parallel transport (the sum of
    /// all indices is the Euler characteristic on a closed surface).
    pub fn singularities(&self) -> Vec<Singularity> {
        let lm = &self.mesh;
        let m = &lm.mesh;
        let mut out = Vec::new();
        for f in 0..m.num_faces() {
            let fid = FaceId::from_idx(f);
            let vs = m.face_vertices(fid);
            let k = vs.len();
            // Around the loop, the angle of v1 relative to the current edge changes along
            // every edge (by the field's own turning: 0 when parallel, principal value) and
            // at every corner (by minus the corner's exterior angle ε_j). Back at the start
            // it has changed by 2π·m; a parallel field on a small face has m = -1, so the
            // index is m + 1.
            let mut along = 0.0;
            let mut corners = 0.0;
            // Normals and field vectors on this face's side.
            let n = |c: usize| lm.corner_normal(fid, c % k);
            let v1 = |c: usize| corner_vector(lm, &self.v1, &self.corner_v1, fid, c % k);
            for c in 0..k {
                let (i, j, l) = (
                    vs[c] as usize,
                    vs[(c + 1) % k] as usize,
                    vs[(c + 2) % k] as usize,
                );
                let d = lm.position[j] - lm.position[i];
                let fi = frame_along(d, n(c));
                let fj = frame_along(d, n(c + 1));
                let thi = v1(c).dot(fi.1).atan2(v1(c).dot(fi.0));
                let thj = v1(c + 1).dot(fj.1).atan2(v1(c + 1).dot(fj.0));
                along += wrap(thj - thi);
                let next = frame_along(lm.position[l] - lm.position[j], n(c + 1));
                corners += next.0.dot(fj.1).atan2(next.0.dot(fj.0));
            }
            let idx = ((along - corners) / std::f64::consts::TAU).round() as i32 + 1;
            if idx != 0 {
                let pos = vs.iter().map(|&v| lm.position[v as usize]).sum::<DVec3>() / k as f64;
                out.push(Singularity {
                    face: fid,
                    index: idx,
                    position: pos,
                });
            }
        }
        out
    }
}

/// Refuses an axis without a direction (zero or not finite).
fn check_axis(a: DVec3) -> anyhow::Result<()> {
    if a.length() < 1e-12 || !a.is_finite() {
        bail!(
            "orientation axis ({}, {}, {}) has no direction",
            a.x,
            a.y,
            a.z
        );
    }
    Ok(())
}

/// Orthonormal tangent frame at a vertex with unit normal `n` whose first axis is `d`
/// projected (d, n × d).
fn frame_along(d: DVec3, n: DVec3) -> (DVec3, DVec3) {
    let t = (d - n * n.dot(d)).normalize_or(n.any_orthonormal_vector());
    (t, n.cross(t))
}

#[inline]
fn wrap(a: f64) -> f64 {
    let mut a = a % std::f64::consts::TAU;
    if a > std::f64::consts::PI {
        a -= std::f64::consts::TAU;
    } else if a <= -std::f64::consts::PI {
        a += std::f64::consts::TAU;
    }
    a
}

/// Fills the targets (λ a_i) and pins of one level from the constraints.
fn set_targets(
    prob: &mut LevelProblem,
    lm: &LimitMesh,
    c: &Constraints,
    weight: f64,
    diag: f64,
) -> anyhow::Result<()> {
    for i in 0..prob.nv() {
        let (x, n) = (lm.position[i], lm.normal[i]);
        let mut a = DVec3::ZERO;
        for &(axis, w) in &c.axes {
            a += (axis - n * n.dot(axis)) * w;
        }
        for &(axis, w) in &c.ups {
            a += (axis - n * n.dot(axis)).cross(n) * w;
        }
        for &(p, r, sign) in &c.points {
            let r = r.unwrap_or(0.25 * diag);
            let d = (x - p) * sign;
            let t = d - n * n.dot(d);
            let l = t.length();
            if l > 1e-12 * diag {
                a += t / l * (-(d.length() / r).powi(2)).exp();
            }
        }
        prob.target[i] = prob.to_complex(i, a) * weight;
    }
    for &(v, dir) in &c.vertices {
        let n = lm.normal[v];
        let t = dir - n * n.dot(dir);
        if t.length() < 1e-6 {
            bail!(
                "constraint direction ({}, {}, {}) at vertex {v} is normal to the surface",
                dir.x,
                dir.y,
                dir.z
            );
        }
        prob.pinned[v] = prob.to_complex(v, t).normalize();
    }
    Ok(())
}
