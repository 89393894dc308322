//! Surface patches: where the texels of the surface sit inside a square example patch laid
//! on the surface along the orientation field — the "resampling patches" of paper 001
//! (§3.2, §4.2), shared by texture optimisation ([`super::optimise`]) and patch sampling
//! ([`super::patches`]).
//!
//! A patch is a centre texel `c` and a half-size `r` in example pixels. Every texel `t`
//! near `c` gets *local coordinates* `l(t)` ∈ ℝ², in example pixels, such that copying
//! example pixel `z + l(t)` to every `t` pastes the example patch centred at `z` onto the
//! surface, undistorted and turned with the field; the footprint is the set of texels with
//! `|l(t)|∞ ≤ r`.
//!
//! **How `l` is found.** Texels are flooded from the centre over the texel graph
//! ([`crate::texels::TexelGraph`], which crosses domain edges, T-junctions and
//! extraordinary corners), nearest first by path length (Dijkstra). A texel reached from
//! `s` gets `l(t) = l(s) + e(s, t)`, `e` the displacement `P(t) − P(s)` expressed in `s`'s
//! field frame in example pixels, `e = ((P(t) − P(s))·v1, −(P(t) − P(s))·v2) / δ` — the
//! continuation rule of coherent synthesis (000 §5), applied along a shortest path. The
//! minus sign makes image rows run along −v2 (docs/coherent.md, "handedness").
//! Because each step is a chord of ~one texel projected on the tangent plane, `l` follows
//! the surface (a geodesic-polar-like map), not the 3D chord from the centre, and it turns
//! with the field, so two overlapping patches agree on the texture's orientation where
//! they meet. Where the field curls, coordinates reached along different branches of the
//! shortest-path tree can disagree slightly; one Jacobi smoothing pass per texel (the mean
//! of the continuations from all its already-placed neighbours in the footprint) spreads
//! that disagreement instead of leaving a crack.
//!
//! This works on the texels themselves rather than on a K×K grid of surface samples
//! ([`crate::sampling`]) because the texture is stored per texel: each texel's place in
//! each patch is then known exactly, so a method can paste a patch or copy a source
//! position into every texel it covers without resampling, and texel density may vary
//! freely (denser small faces just get more texels per example pixel).
//!
//! Footprints are computed once per level and reused by every iteration.

use super::texel_table::TexelTable;
use crate::field::OrientationField;
use crate::layout::TexelLayout;
use crate::texels::{EdgeGraph, TexelGeometry, TexelGraph};
use glam::Vec3;
use rayon::prelude::*;
use std::cmp::Ordering;
use std::collections::BinaryHeap;
use std::sync::Arc;
use subdiv::Surface;

/// Local stretch beyond which a texel ends its patch: |Δl| / |ΔP| (in example pixels)
/// between it and an already placed edge neighbour must lie in this range. Wider than
/// scale fidelity's p10–p90 target (0.9–1.1) on purpose: one-step ratios are noisy at
/// texel scale where domains meet at extraordinary vertices, and a tight bound cuts
/// patches into fragments whose many joins raised the seam ratio (Spot N = 16, patches:
/// 0.66–1.25 over seeds at 0.9–1.1) without improving the spread, which stayed at
/// p10–p90 0.97–1.03 with this range.
const STRETCH_MIN: f32 = 0.8;
const STRETCH_MAX: f32 = 1.25;

/// The texels of one synthesis level: where they are, who their neighbours are, and the
/// field's frame at each.
pub struct LevelTexels {
    /// Shared: a prepared session hands it to every result for writing.
    pub geometry: std::sync::Arc<TexelGeometry>,
    /// The 5x5-block neighbourhood graph, built on first use ([`LevelTexels::graph`]):
    /// coherent synthesis and patch sampling's filling of uncovered texels read it, texture
    /// optimisation's floods do not (at N = 4 every texel is a border texel and building
    /// it walked ~200 times per domain: ~3 s of a 200k-quad torus run).
    graph: std::sync::OnceLock<TexelGraph>,
    /// (v1, v2) per texel.
    pub frames: Vec<[Vec3; 2]>,
    /// Surface length of one example pixel of this level (δ) where the scale map's factor
    /// is 1 (everywhere without a scale map).
    pub step: f64,
    /// The scale map's factor per texel ([`crate::scale_field`]): the local step at texel
    /// `t` is `step × factor[t]` ([`LevelTexels::step_at`]). `None` without a scale map —
    /// then every method runs exactly the arithmetic it ran before scale maps existed, so
    /// results without `--scale-map` are bit-identical to earlier versions. f64 so that a
    /// constant factor k gives the same local step, bit for bit, as the global scale S·k.
    pub factor: Option<Vec<f64>>,
    /// The grid's 4-neighbourhood across domains: floods and seams run on it. `None` for
    /// texels prepared for one coherent synthesis (which never reads it) and after
    /// [`Self::drop_edges`]: [`Self::edges`] then says so instead of handing out an empty
    /// graph that would read as "no neighbours anywhere".
    edges: Option<EdgeGraph>,
}

impl LevelTexels {
    /// Evaluates everything for `n`×`n` maps.
    pub fn new(surface: &Surface, field: &OrientationField, n: usize, step: f64) -> Self {
        let geometry = TexelGeometry::compute(surface, n);
        let frames = crate::texel_frames::texel_frames_f32(field, surface, n);
        Self::from_parts(surface, geometry, frames, step)
    }

    /// Evaluates everything for the maps of `layout` (per-face resolutions).
    pub fn with_layout(
        surface: &Surface,
        field: &OrientationField,
        layout: Arc<TexelLayout>,
        step: f64,
    ) -> Self {
        let geometry = TexelGeometry::compute_layout(surface, layout);
        let frames = crate::texel_frames::layout_frames(field, surface, &geometry.layout);
        Self::from_parts(surface, geometry, frames, step)
    }

    /// From parts already computed (the builder's output-resolution texels).
    pub fn from_parts(
        surface: &Surface,
        geometry: TexelGeometry,
        frames: Vec<[Vec3; 2]>,
        step: f64,
    ) -> Self {
        let edges = EdgeGraph::build(surface, &geometry);
        Self::from_built(geometry, frames, step, Some(edges), None)
    }

    /// From parts already computed, the edge graph (and the texel graph, if given) too:
    /// a session builds them beside the orientation field, which they do not need.
    pub fn from_built(
        geometry: TexelGeometry,
        frames: Vec<[Vec3; 2]>,
        step: f64,
        edges: Option<EdgeGraph>,
        graph: Option<TexelGraph>,
    ) -> Self {
        let cell = std::sync::OnceLock::new();
        if let Some(g) = graph {
            let _ = cell.set(g);
        }
        Self {
            geometry: std::sync::Arc::new(geometry),
            graph: cell,
            frames,
            step,
            factor: None,
            edges,
        }
    }

    /// The texel graph ([`TexelGraph`]) of these texels on `surface` (the surface they
    /// were made on), built on the first call.
    pub fn graph(&self, surface: &Surface) -> &TexelGraph {
        self.graph
            .get_or_init(|| TexelGraph::build(surface, &self.geometry))
    }

    /// Frees the texel graph (built again if asked for).
    pub fn drop_graph(&mut self) {
        self.graph = std::sync::OnceLock::new();
    }

    /// The same texels with the scale map's factor at each (`None`: no scale map).
    pub fn with_scale(
        mut self,
        surface: &Surface,
        scale: Option<&crate::scale_field::ScaleField>,
    ) -> Self {
        self.factor = scale.map(|f| f.layout_factors(surface, &self.geometry.layout));
        self
    }

    /// Surface length of one example pixel at texel `t` (the local step).
    #[inline]
    pub fn step_at(&self, t: usize) -> f64 {
        match &self.factor {
            None => self.step,
            Some(f) => self.step * f[t],
        }
    }

    /// Example pixels per surface length at texel `t`, as the methods use it (f32).
    #[inline]
    pub fn inv_step_at(&self, t: usize) -> f32 {
        (1.0 / self.step_at(t)) as f32
    }

    /// The largest local step (the step without a scale map).
    pub fn max_step(&self) -> f64 {
        match &self.factor {
            None => self.step,
            Some(f) => self.step * f.iter().copied().fold(f64::MIN_POSITIVE, f64::max),
        }
    }

    /// The texels' edge neighbours.
    ///
    /// # Panics
    /// On texels made without them (a session prepared for one coherent synthesis) or
    /// after [`Self::drop_edges`]: a programming error, not an input one.
    pub fn edges(&self) -> &EdgeGraph {
        self.edges.as_ref().expect(
            "texels without an edge graph (prepared for coherent synthesis only, or dropped)",
        )
    }

    /// Frees the edge graph (a one-shot run once its synthesis is done).
    pub fn drop_edges(&mut self) {
        self.edges = None;
    }

    /// Where the texels are.
    pub fn layout(&self) -> &Arc<TexelLayout> {
        &self.geometry.layout
    }

    /// Number of texels.
    pub fn len(&self) -> usize {
        self.geometry.len()
    }

    /// True without texels.
    pub fn is_empty(&self) -> bool {
        self.geometry.is_empty()
    }

    /// `P(t) − P(s)` in `s`'s frame, in example pixels of this level (at `s`'s local step).
    #[inline]
    pub fn offset(&self, s: usize, t: usize) -> [f32; 2] {
        let d = self.geometry.pos[t] - self.geometry.pos[s];
        let [v1, v2] = self.frames[s];
        let k = self.inv_step_at(s);
        [d.dot(v1) * k, -d.dot(v2) * k]
    }
}

/// Patch centres: a maximal Poisson-disk sample of the texels (paper 001 §4.2: "randomly
/// and uniformly select some vertices"), visiting texels in a seeded hash order, two
/// centres at least `pixels` example pixels apart: in 3D, `pixels` × the local step, and
/// between texels of different local steps (a scale map) the mean of theirs — so where the
/// texture is smaller, centres are denser (001 §4.2: "more vertices are selected where the
/// local vectors are short") and every patch still overlaps its neighbours by the same
/// share. Every texel (of `mask`, when given) lies within its own distance of some centre.
pub fn centres(level: &LevelTexels, pixels: f64, seed: u64, mask: Option<&[bool]>) -> Vec<u32> {
    let pos = &level.geometry.pos;
    let n = pos.len();
    let mut order: Vec<(u64, u32)> = (0..n as u32)
        .filter(|&t| mask.is_none_or(|m| m[t as usize]))
        .map(|t| (crate::random::hash(seed, &[0xCE47, t as u64]), t))
        .collect();
    order.par_sort_unstable();
    // The minimum distance at texel t; the grid's cells are the largest of them.
    let radius = |t: usize| (pixels * level.step_at(t)).max(1e-30);
    let cell = (pixels * level.max_step()).max(1e-30) as f32;
    let key = |p: Vec3| -> [i64; 3] {
        [
            (p.x / cell).floor() as i64,
            (p.y / cell).floor() as i64,
            (p.z / cell).floor() as i64,
        ]
    };
    // The greedy pass below is serial (each decision depends on the earlier ones), so
    // what it reads per visited texel is gathered beforehand, in parallel and in visiting
    // order: the pass then streams through memory instead of jumping to a random texel.
    let visits: Vec<Visit> = order
        .par_iter()
        .filter_map(|&(_, t)| {
            let p = pos[t as usize];
            p.is_finite().then(|| Visit {
                p,
                r: radius(t as usize),
                cell: key(p),
                t,
            })
        })
        .collect();
    drop(order);
    let mut grid = CentreGrid::new();
    let mut out = Vec::new();
    // Blocks of visits: first, in parallel, drop the visits that a centre of an earlier
    // block already rules out (the greedy pass would reject them too: its test is "no
    // earlier centre within reach"); then the greedy pass over the rest of the block. The
    // same centres as one serial pass, and once the surface is covered (after a few
    // blocks) nearly every visit is dropped in the parallel part.
    let mut at = 0;
    let mut block = 1 << 12;
    while at < visits.len() {
        let part = &visits[at..(at + block).min(visits.len())];
        let open: Vec<bool> = if grid.items.is_empty() {
            vec![true; part.len()]
        } else {
            part.par_iter()
                .with_min_len(1 << 10)
                .map(|v| grid.free(v))
                .collect()
        };
        for (v, _) in part.iter().zip(&open).filter(|(_, &o)| o) {
            if grid.free(v) {
                grid.insert(*v);
                out.push(v.t);
            }
        }
        at += part.len();
        block = (block * 2).min(1 << 16);
    }
    out
}

/// About `count` texels of a footprint spread evenly over its patch, as indices into the
/// footprint: the square of half-size `half` is cut into G×G cells (G = ⌈√(count / a)⌉,
/// `a` the share of the footprint's texels that `among` holds) and each cell gives the texel
/// of `among` (footprint indices, e.g. the texels already synthesized) with the lowest hash
/// of (`key`, index) — jittered stratified sampling. Every index of `among` when there are
/// no more than `count`. Appended to `out` in cell order.
///
/// Why not every k-th texel in flood order (what the methods took before): the flood visits
/// texels by path length, and on a texel lattice whose two spacings differ even slightly —
/// 0.05% on a flat grid, and always on curved surfaces — the order runs along the shorter
/// axis first, so a stride picks the same few columns of every ring and a mortar line
/// between them is invisible to the match. Measured with texture optimisation (bricks,
/// flat 16x16 grid, N = 32, seeds 1–3): on an exact grid pf8 0.025–0.033 either way; with
/// the grid's rows 0.2% closer than its columns 0.073–0.091 with the stride, 0.030–0.043
/// measuring every texel (docs/synthesis.md, "Which texels a match measures").
pub fn spread(
    coords: &[[f32; 2]],
    among: impl Iterator<Item = usize> + Clone,
    half: f32,
    count: usize,
    key: u64,
    out: &mut Vec<u32>,
) {
    let count = count.max(1);
    if among.clone().nth(count).is_none() {
        out.extend(among.map(|i| i as u32));
        return;
    }
    // Cells over the whole square, as many as make about `count` of them hold a texel of
    // `among` when it covers only part of the patch (an overlap band: with a grid of `count`
    // cells it would get only the few cells it crosses).
    let share = among.clone().count() as f64 / coords.len().max(1) as f64;
    let g = ((count as f64 / share.max(1e-3)).sqrt().ceil() as usize).max(1);
    let cell = (2.0 * half.max(1e-6)) / g as f32;
    let mut best = vec![(u64::MAX, u32::MAX); g * g];
    for i in among {
        let l = coords[i];
        let cx = (((l[0] + half) / cell) as usize).min(g - 1);
        let cy = (((l[1] + half) / cell) as usize).min(g - 1);
        let h = crate::random::hash(key, &[i as u64]);
        let b = &mut best[cy * g + cx];
        if h < b.0 {
            *b = (h, i as u32);
        }
    }
    out.extend(best.iter().filter(|b| b.1 != u32::MAX).map(|b| b.1));
}

/// A texel visited by [`centres`]: its position, minimum distance and grid cell.
#[derive(Clone, Copy)]
struct Visit {
    p: Vec3,
    r: f64,
    cell: [i64; 3],
    t: u32,
}

/// The centres chosen so far by grid cell: a hash table of chains, the cells hashed to
/// `head.len()` (a power of two) buckets. A bucket may chain centres of other cells; only
/// those of the asked cell are visited, so the answers are those of a map from cell to
/// centres (it replaced a `HashMap` of `Vec`s, whose SipHash and allocations made the
/// serial pass of [`centres`] the largest part of a 200k-quad torus run at N = 4).
struct CentreGrid {
    head: Vec<u32>,
    next: Vec<u32>,
    items: Vec<Visit>,
}

impl CentreGrid {
    const NONE: u32 = u32::MAX;

    fn new() -> Self {
        Self {
            head: vec![Self::NONE; 1 << 12],
            next: Vec::new(),
            items: Vec::new(),
        }
    }

    #[inline]
    fn bucket(&self, c: [i64; 3]) -> usize {
        let h = (c[0] as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
            ^ (c[1] as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F)
            ^ (c[2] as u64).wrapping_mul(0x1656_67B1_9E37_79F9);
        ((h ^ (h >> 29)) as usize) & (self.head.len() - 1)
    }

    /// Whether no centre is within reach of `v`: closer than the mean of their minimum
    /// distances (the own cell first, where one is likeliest).
    fn free(&self, v: &Visit) -> bool {
        let [i, j, k] = v.cell;
        let near = |q: &Visit| {
            // (r + r) / 2 is r exactly: one factor everywhere is one scale.
            let r = 0.5 * (v.r + q.r);
            q.p.distance_squared(v.p) < (r * r) as f32
        };
        if self.any_in(v.cell, near) {
            return false;
        }
        for a in i - 1..=i + 1 {
            for b in j - 1..=j + 1 {
                for c in k - 1..=k + 1 {
                    if [a, b, c] != v.cell && self.any_in([a, b, c], near) {
                        return false;
                    }
                }
            }
        }
        true
    }

    /// Whether `f` holds for a centre in cell `c`.
    #[inline]
    fn any_in(&self, c: [i64; 3], f: impl Fn(&Visit) -> bool) -> bool {
        let mut e = self.head[self.bucket(c)];
        while e != Self::NONE {
            let q = &self.items[e as usize];
            if q.cell == c && f(q) {
                return true;
            }
            e = self.next[e as usize];
        }
        false
    }

    fn insert(&mut self, v: Visit) {
        if self.items.len() >= self.head.len() / 2 {
            // Grow: twice the buckets, every chain rebuilt.
            let len = self.head.len() * 2;
            self.head = vec![Self::NONE; len];
            for e in 0..self.items.len() {
                let b = self.bucket(self.items[e].cell);
                self.next[e] = self.head[b];
                self.head[b] = e as u32;
            }
        }
        let e = self.items.len() as u32;
        let b = self.bucket(v.cell);
        self.items.push(v);
        self.next.push(self.head[b]);
        self.head[b] = e;
    }
}

/// Cosine of the angle between neighbouring normals beyond which a step is taken to cross
/// a crease (~8°; smooth surfaces turn by well under a degree per texel).
const CREASE_COS: f32 = 0.99;

/// `e1` carried from a point with normal `from` to one with normal `to` by the smallest
/// rotation taking `from` to `to` (parallel transport over one step; across a sharp crease
/// this is the unfolding about the crease line, where projecting onto the new tangent
/// plane would lose a direction that points across the crease).
fn transport(e1: Vec3, from: Vec3, to: Vec3) -> Vec3 {
    let axis = from.cross(to);
    let s = axis.length();
    let c = from.dot(to);
    let r = if s > 1e-7 {
        // Rodrigues' rotation about axis / s by the angle with sin s and cos c.
        let k = axis / s;
        e1 * c + k.cross(e1) * s + k * k.dot(e1) * (1.0 - c)
    } else {
        e1
    };
    let t = r - to * r.dot(to);
    if t.length_squared() > 1e-12 {
        t.normalize()
    } else {
        e1
    }
}

/// The step `dp` from a point with normal `a` to one with normal `b`, as it runs *on the
/// surface*, expressed in `a`'s tangent plane. On smooth parts this is `dp` itself (the
/// chord of one texel differs from the arc by (h·κ)²/24). Across a sharp crease the chord
/// cuts the corner: the surface path runs along `a`'s plane to the crease line and on
/// along `b`'s plane, so the part of `dp` across the crease is split into its two in-plane
/// legs (directions `u_a`, `u_b` perpendicular to the crease line `d = a × b`), whose
/// lengths are summed along `u_a` — the step unfolded into `a`'s plane.
fn unfolded(dp: Vec3, a: Vec3, b: Vec3) -> Vec3 {
    if a.dot(b) >= CREASE_COS {
        return dp;
    }
    let d = a.cross(b);
    let dl = d.length();
    if dl < 1e-6 {
        return dp;
    }
    let d = d / dl;
    let (ua, ub) = (d.cross(a), d.cross(b));
    let along = dp.dot(d);
    let perp = dp - d * along;
    // perp = α·ua + β·ub.
    let (g11, g12, g22) = (1.0, ua.dot(ub), 1.0);
    let (r1, r2) = (perp.dot(ua), perp.dot(ub));
    let det = g11 * g22 - g12 * g12;
    if det.abs() < 1e-6 {
        return dp;
    }
    let alpha = (r1 * g22 - r2 * g12) / det;
    let beta = (g11 * r2 - g12 * r1) / det;
    d * along + ua * (alpha + beta)
}

/// A patch given as its centre and its (texel, local coordinates), for tests.
#[cfg(test)]
pub(crate) type PatchList = (u32, Vec<(u32, [f32; 2])>);

/// The footprints of a set of patches (CSR): texels and their local coordinates.
pub struct Footprints {
    /// Half-size r in example pixels: footprints hold the texels with |l|∞ ≤ r.
    pub half: f32,
    pub centres: Vec<u32>,
    start: Vec<usize>,
    texels: Vec<u32>,
    coords: Vec<[f32; 2]>,
    /// Per texel of a footprint, its turn β: the angle from the field's v1 at the texel to
    /// the patch's frame there (transported from the centre, where β = 0). The example
    /// pasted by the patch runs at β against the field at that texel — what a texel's
    /// source orientation is ([`Footprints::turns`]).
    turns: Vec<Turn>,
    /// Patch indices by centre texel ([`Footprints::by_centre`]).
    order: Vec<u32>,
}

/// Indices of `centres` sorted by texel (centres are distinct texels).
fn by_texel(centres: &[u32]) -> Vec<u32> {
    let mut order: Vec<u32> = (0..centres.len() as u32).collect();
    order.sort_unstable_by_key(|&i| centres[i as usize]);
    order
}

/// Dijkstra queue entry: path length, texel (min-heap by length, then texel index).
#[derive(Clone, Copy, PartialEq)]
struct Entry(f32, u32);
impl Eq for Entry {}
impl Ord for Entry {
    fn cmp(&self, o: &Self) -> Ordering {
        o.0.total_cmp(&self.0).then(o.1.cmp(&self.1))
    }
}
impl PartialOrd for Entry {
    fn partial_cmp(&self, o: &Self) -> Option<Ordering> {
        Some(self.cmp(o))
    }
}

/// Per-thread flood state: the texels one flood has reached ([`TexelTable`]: a few
/// hundred to a few thousand, not a node per texel of the level per thread).
pub struct Flood {
    nodes: TexelTable<Node>,
    heap: BinaryHeap<Entry>,
    reached: Vec<u32>,
    /// The finalised neighbours of the texel being placed: step length, coordinates.
    near: Vec<(f32, [f32; 2])>,
}

/// One texel's flood state, kept together: a flood step reads all of it for the texel
/// and each of its neighbours.
#[derive(Clone, Copy)]
struct Node {
    dist: f32,
    parent: u32,
    done: bool,
    coord: [f32; 2],
    /// First axis of the frame transported from the centre.
    e1: Vec3,
}

impl Default for Node {
    /// Not reached yet: not done, at an infinite distance.
    fn default() -> Self {
        Self {
            dist: f32::INFINITY,
            parent: 0,
            done: false,
            coord: [0.0; 2],
            e1: Vec3::ZERO,
        }
    }
}

impl Flood {
    fn new() -> Self {
        Self {
            nodes: TexelTable::new(),
            heap: BinaryHeap::new(),
            reached: Vec::new(),
            near: Vec::new(),
        }
    }
}

/// Per-thread flood state for [`Footprints::build_with`], kept between builds so that
/// each thread's table and heap are allocated once.
#[derive(Default)]
pub struct FloodScratch(super::per_thread::PerThread<Flood>);

impl Footprints {
    /// Floods every centre's footprint of half-size `half` (example pixels of `level`).
    pub fn build(level: &LevelTexels, centres: Vec<u32>, half: f32) -> Self {
        Self::build_with(level, centres, half, &FloodScratch::default())
    }

    /// [`Footprints::build`] with flood state `scratch` (of builds on the same `level`).
    pub fn build_with(
        level: &LevelTexels,
        centres: Vec<u32>,
        half: f32,
        scratch: &FloodScratch,
    ) -> Self {
        // Flooded in the order of the centres' texels, where neighbouring patches (which
        // overlap) follow one another and find their texels' state still in the caches
        // (the centres come in a hashed order: each flood started cold). Stored in the
        // centres' order, as before.
        let order = by_texel(&centres);
        let mut per: Vec<Flooded> = order
            .par_iter()
            .map(|&i| centres[i as usize])
            .map(|c| {
                scratch
                    .0
                    .with(Flood::new, |fl| flood(level, fl, c as usize, half))
            })
            .collect();
        let mut rank = vec![0u32; order.len()];
        for (k, &i) in order.iter().enumerate() {
            rank[i as usize] = k as u32;
        }
        let mut start = Vec::with_capacity(per.len() + 1);
        start.push(0);
        let total: usize = per.iter().map(|p| p.texels.len()).sum();
        let mut texels = Vec::with_capacity(total);
        let mut coords = Vec::with_capacity(total);
        let mut turns = Vec::with_capacity(total);
        for &k in &rank {
            let f = std::mem::take(&mut per[k as usize]);
            texels.extend_from_slice(&f.texels);
            coords.extend_from_slice(&f.coords);
            turns.extend_from_slice(&f.turns);
            start.push(texels.len());
        }
        Self {
            half,
            centres,
            start,
            texels,
            coords,
            turns,
            order,
        }
    }

    /// Footprints given directly, one `(centre, [(texel, l)])` per patch (the centre's own
    /// entry first): for tests of what is done with footprints.
    #[cfg(test)]
    pub(crate) fn from_lists(half: f32, patches: Vec<PatchList>) -> Self {
        let mut start = vec![0];
        let (mut texels, mut coords, mut centres) = (Vec::new(), Vec::new(), Vec::new());
        for (c, list) in patches {
            centres.push(c);
            for (t, l) in list {
                texels.push(t);
                coords.push(l);
            }
            start.push(texels.len());
        }
        let order = by_texel(&centres);
        let turns = vec![Turn::ZERO; coords.len()];
        Self {
            half,
            centres,
            start,
            texels,
            coords,
            turns,
            order,
        }
    }

    /// The patches in the order of their centre texels (a cache-friendly order to visit
    /// them in: overlapping patches come together).
    pub fn by_centre(&self) -> &[u32] {
        &self.order
    }

    /// Number of patches.
    pub fn len(&self) -> usize {
        self.centres.len()
    }

    /// True without patches.
    pub fn is_empty(&self) -> bool {
        self.centres.is_empty()
    }

    /// Texels and local coordinates of patch `p` (the centre first, at (0, 0)).
    #[inline]
    pub fn get(&self, p: usize) -> (&[u32], &[[f32; 2]]) {
        let (a, b) = (self.start[p], self.start[p + 1]);
        (&self.texels[a..b], &self.coords[a..b])
    }

    /// The turns β of patch `p`'s texels, parallel to [`Footprints::get`]'s (the centre's
    /// is 0): a texel that copies patch `p` has source orientation β against the field.
    #[inline]
    pub fn turns(&self, p: usize) -> &[Turn] {
        &self.turns[self.start[p]..self.start[p + 1]]
    }

    /// Total (texel, patch) memberships.
    pub fn memberships(&self) -> usize {
        self.texels.len()
    }

    /// Bytes held.
    pub fn heap_bytes(&self) -> usize {
        self.texels.len() * 14 + self.start.len() * 8 + self.centres.len() * 4
    }

    /// For every texel, the patches whose footprint holds it (CSR: starts, patch list),
    /// each list ascending.
    pub fn covering(&self, texels: usize) -> (Vec<u32>, Vec<u32>) {
        let c = self.covering_impl(texels, false);
        (c.start, c.patch)
    }

    /// [`Footprints::covering`] with, parallel to its list, the texel's local coordinates
    /// and turn in each patch.
    pub fn covering_coords(&self, texels: usize) -> Covering {
        self.covering_impl(texels, true)
    }

    fn covering_impl(&self, texels: usize, with_coords: bool) -> Covering {
        let mut count = vec![0u32; texels + 1];
        for &t in &self.texels {
            count[t as usize + 1] += 1;
        }
        for i in 1..count.len() {
            count[i] += count[i - 1];
        }
        let mut fill = count.clone();
        let mut list = vec![0u32; self.texels.len()];
        let kept = if with_coords { list.len() } else { 0 };
        let mut coords = vec![[0.0f32; 2]; kept];
        let mut turns = vec![Turn::ZERO; kept];
        for p in 0..self.len() {
            let (ts, ls) = self.get(p);
            for ((&t, &l), &b) in ts.iter().zip(ls).zip(self.turns(p)) {
                let k = &mut fill[t as usize];
                list[*k as usize] = p as u32;
                if with_coords {
                    coords[*k as usize] = l;
                    turns[*k as usize] = b;
                }
                *k += 1;
            }
        }
        Covering {
            start: count,
            patch: list,
            coords,
            turns,
        }
    }
}

/// For every texel, the patches whose footprint holds it ([`Footprints::covering_coords`]):
/// texel `t`'s are `patch[start[t]..start[t + 1]]` (ascending), with `t`'s coordinates and
/// turn in each at the same indices of `coords` and `turns`.
pub struct Covering {
    pub start: Vec<u32>,
    pub patch: Vec<u32>,
    pub coords: Vec<[f32; 2]>,
    pub turns: Vec<Turn>,
}

/// A turn — an angle in (−π, π] — in 16 bits: 2π / 65,536 ≈ 1e-4 rad, 0.002 px at the edge of
/// a 32-pixel patch. Footprints hold one per membership (four or so per texel) and the
/// synthesis one per texel, so a float there cost ~30 B per texel at the finest level.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Turn(i16);

impl Turn {
    pub const ZERO: Turn = Turn(0);

    /// The turn nearest `a` radians (a in [−π, π]).
    pub fn from_radians(a: f32) -> Self {
        let q = (a * (32768.0 / std::f32::consts::PI)).round();
        Turn(q.clamp(-32768.0, 32767.0) as i16)
    }

    /// In radians.
    pub fn radians(self) -> f32 {
        self.0 as f32 * (std::f32::consts::PI / 32768.0)
    }
}

/// The offset `e` (example pixels, in the field's frame at a texel) turned by the texel's
/// source orientation `psi`: where the example continues from the texel's source, for a
/// texture that runs at `psi` against the field there. A zero turn gives `e` exactly.
#[inline]
pub fn turned(e: [f32; 2], psi: Turn) -> [f32; 2] {
    if psi == Turn::ZERO {
        return e;
    }
    let (s, c) = psi.radians().sin_cos();
    [c * e[0] - s * e[1], s * e[0] + c * e[1]]
}

/// One flooded footprint: texels, coordinates and turns.
#[derive(Default)]
struct Flooded {
    texels: Vec<u32>,
    coords: Vec<[f32; 2]>,
    turns: Vec<Turn>,
}

/// One footprint (see the module docs).
fn flood(level: &LevelTexels, fl: &mut Flood, c: usize, half: f32) -> Flooded {
    fl.nodes.clear();
    let pos = &level.geometry.pos;
    let normal = &level.geometry.normal;
    // Paths run over the edge graph (the 4-neighbourhood), so a path to a texel is at most
    // √2 times its straight distance; the patch's half-diagonal is √2·half: paths longer
    // than 2·half (plus two texels) cannot end inside the patch (at the largest step).
    let limit = ((2.0 * half + 2.0) as f64 * level.max_step()) as f32;
    let edges = level.edges();
    let keep = half + 1.0;
    fl.heap.clear();
    fl.reached.clear();
    let (nc, _) = fl.nodes.entry(c as u32);
    nc.dist = 0.0;
    nc.parent = c as u32;
    fl.heap.push(Entry(0.0, c as u32));
    // A finalised neighbour's coordinates and transported axis, if it has usable ones.
    let placed = |nodes: &TexelTable<Node>, q: u32| {
        nodes
            .get(q)
            .filter(|n| n.done && n.coord[0].is_finite())
            .map(|n| (n.coord, n.e1))
    };
    while let Some(Entry(d, s32)) = fl.heap.pop() {
        let s = s32 as usize;
        let ns = *fl.nodes.at(s32);
        if ns.done || d > ns.dist {
            continue;
        }
        // Finalise s: frame transported from its parent, coordinates averaged over the
        // continuations from its finalised neighbours ("upwind averaging").
        let (e1, coord) = if s == c {
            (level.frames[c][0], [0.0, 0.0])
        } else {
            let p = ns.parent as usize;
            let np = *fl.nodes.at(ns.parent);
            // Steps into s are measured at s's local step (the scale map's factor there):
            // the coordinates are then the integral of the surface length over the local
            // step along the paths, so the example is laid at each texel's own scale.
            let inv_step = level.inv_step_at(s);
            let e1 = transport(np.e1, normal[p], normal[s]);
            let nb = edges.of(s);
            // The placed neighbours' step lengths and coordinates, for the stretch test
            // below (one table look-up per neighbour).
            fl.near.clear();
            let (mut sx, mut sy, mut sw) = (0.0f32, 0.0f32, 0.0f32);
            for &q in nb.iter() {
                let Some((lq, qe1)) = placed(&fl.nodes, q) else {
                    continue;
                };
                let q = q as usize;
                let dp = unfolded(pos[s] - pos[q], normal[q], normal[s]);
                let len = dp.length();
                fl.near.push((len, lq));
                if len <= 0.0 {
                    continue;
                }
                let (e1, e2) = (qe1, normal[q].cross(qe1));
                let w = 1.0 / len;
                let cx = lq[0] + dp.dot(e1) * inv_step;
                let cy = lq[1] - dp.dot(e2) * inv_step;
                sx += w * cx;
                sy += w * cy;
                sw += w;
            }
            let l = if sw > 0.0 {
                [sx / sw, sy / sw]
            } else {
                np.coord
            };
            // Where paths around a strongly curved part (a thin fin, an ear, a saddle) meet
            // from two sides, their continuations disagree, and the averaged coordinates
            // are squeezed or stretched against the surface: the patch would fold or smear
            // there. Such texels end the patch (smaller patches cover them later).
            let bad = fl.near.iter().any(|&(len, lq)| {
                let dp = len * inv_step;
                let dl = (l[0] - lq[0]).hypot(l[1] - lq[1]);
                dp > 0.0 && !(STRETCH_MIN..=STRETCH_MAX).contains(&(dl / dp))
            });
            if bad {
                let n = fl.nodes.at(s32);
                n.e1 = e1;
                n.done = true;
                n.coord = [f32::INFINITY, f32::INFINITY];
                continue;
            }
            (e1, l)
        };
        let n = fl.nodes.at(s32);
        n.e1 = e1;
        n.coord = coord;
        n.done = true;
        fl.reached.push(s32);
        if coord[0].abs().max(coord[1].abs()) > keep {
            continue; // outside the patch: not expanded further
        }
        for t in edges.of(s) {
            let nd = d + pos[s].distance(pos[t as usize]);
            if nd > limit || !nd.is_finite() {
                continue;
            }
            let (nt, _) = fl.nodes.entry(t);
            if !nt.done && nd < nt.dist {
                nt.dist = nd;
                nt.parent = s32;
                fl.heap.push(Entry(nd, t));
            }
        }
    }
    let order = std::mem::take(&mut fl.reached);
    let mut out = Flooded::default();
    for &t in &order {
        let node = fl.nodes.get(t).expect("reached texels are in the table");
        let l = node.coord;
        if l[0].abs() <= half && l[1].abs() <= half {
            out.texels.push(t);
            out.coords.push(l);
            // β: the transported frame's v1 against the field's frame at t.
            let [v1, v2] = level.frames[t as usize];
            out.turns.push(if t as usize == c {
                Turn::ZERO
            } else {
                Turn::from_radians(node.e1.dot(v2).atan2(node.e1.dot(v1)))
            });
        }
    }
    fl.reached = order;
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn turns_round_trip_and_turn_offsets_the_right_way() {
        for a in [0.0f32, 0.3, -1.2, 3.1, -3.1] {
            let t = Turn::from_radians(a);
            assert!((t.radians() - a).abs() < 1e-4, "{a}");
        }
        assert_eq!(Turn::from_radians(std::f32::consts::PI).0, i16::MAX);
        // A zero turn leaves the offset exactly; a quarter turn takes +x to +y.
        assert_eq!(turned([1.5, -2.0], Turn::ZERO), [1.5, -2.0]);
        let q = turned([1.0, 0.0], Turn::from_radians(std::f32::consts::FRAC_PI_2));
        assert!((q[0]).abs() < 1e-4 && (q[1] - 1.0).abs() < 1e-4, "{q:?}");
    }

    /// The turn β a footprint records at a texel is what makes the field's offsets into the
    /// patch's own: between neighbouring texels s, t of one footprint, l(t) − l(s) is the
    /// offset from s to t in the field's frame turned by β(s) — on a curved mesh, where β
    /// reaches tens of degrees; without the turn the offsets would miss by that angle.
    #[test]
    fn footprint_turns_carry_field_offsets_into_the_patch_frame() {
        let p = std::env::var_os("SURFSYNTH_SHARED")
            .map(std::path::PathBuf::from)
            .unwrap_or_else(|| std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared"))
            .join("data/meshes/spot_control_mesh.obj");
        let surface = Surface::load_obj(p).unwrap();
        let field = OrientationField::compute(&surface, &crate::field::Orientation::Auto).unwrap();
        let n = 8;
        let probe = TexelGeometry::compute(&surface, n);
        let step = probe.median_spacing(&surface);
        let level = LevelTexels::new(&surface, &field, n, step);
        let cs: Vec<u32> = (0..level.len() as u32).step_by(97).collect();
        let fp = Footprints::build(&level, cs, 8.0);
        let (mut turned_err, mut plain_err, mut largest) = (0.0f64, 0.0f64, 0.0f32);
        let mut pairs = 0usize;
        for p in 0..fp.len() {
            let (ts, ls) = fp.get(p);
            let bs = fp.turns(p);
            let at: std::collections::HashMap<u32, usize> =
                ts.iter().enumerate().map(|(i, &t)| (t, i)).collect();
            for (i, &s) in ts.iter().enumerate() {
                largest = largest.max(bs[i].radians().abs());
                for t in level.edges().of(s as usize) {
                    let Some(&j) = at.get(&t) else { continue };
                    let dl = [ls[j][0] - ls[i][0], ls[j][1] - ls[i][1]];
                    let e = level.offset(s as usize, t as usize);
                    let r = turned(e, bs[i]);
                    turned_err += ((dl[0] - r[0]).hypot(dl[1] - r[1])) as f64;
                    plain_err += ((dl[0] - e[0]).hypot(dl[1] - e[1])) as f64;
                    pairs += 1;
                }
            }
        }
        let (turned_err, plain_err) = (turned_err / pairs as f64, plain_err / pairs as f64);
        eprintln!("{pairs} pairs, largest turn {largest:.2} rad: mean miss {turned_err:.4} px turned, {plain_err:.4} px not");
        assert!(pairs > 10_000, "{pairs} pairs");
        assert!(largest > 0.3, "the test needs turns: largest {largest} rad");
        assert!(
            turned_err < 0.05,
            "turned offsets miss by {turned_err} px on average"
        );
        assert!(
            plain_err > 4.0 * turned_err,
            "unturned {plain_err} vs {turned_err}"
        );
    }

    /// A 33x33 patch of texels whose rows are 0.2% closer than its columns, in the order a
    /// flood reaches them (path length from the centre, then index).
    fn anisotropic_patch() -> Vec<[f32; 2]> {
        let mut ls: Vec<[f32; 2]> = (-16..=16)
            .flat_map(|y| (-16..=16).map(move |x| [x as f32, y as f32 * 0.998]))
            .collect();
        ls.sort_by(|a, b| {
            let (da, db) = (a[0].abs() + a[1].abs(), b[0].abs() + b[1].abs());
            da.total_cmp(&db)
        });
        ls
    }

    /// Distinct texel columns among the picked texels.
    fn columns(ls: &[[f32; 2]], pick: impl Iterator<Item = usize>) -> usize {
        let mut xs: Vec<i32> = pick.map(|i| ls[i][0] as i32).collect();
        xs.sort_unstable();
        xs.dedup();
        xs.len()
    }

    #[test]
    fn spread_picks_one_texel_per_cell_all_over_the_patch() {
        let ls = anisotropic_patch();
        let mut pick = Vec::new();
        spread(&ls, 0..ls.len(), 16.0, 128, 7, &mut pick);
        // A 12x12 grid of cells, each holding texels: one pick each, all distinct.
        assert_eq!(pick.len(), 144);
        let mut d = pick.clone();
        d.sort_unstable();
        d.dedup();
        assert_eq!(d.len(), pick.len());
        // Spread over the columns and rows of the patch (33 each), whatever the order
        // the texels came in.
        let rows = {
            let mut ys: Vec<i32> = pick
                .iter()
                .map(|&i| (ls[i as usize][1] / 0.998).round() as i32)
                .collect();
            ys.sort_unstable();
            ys.dedup();
            ys.len()
        };
        let cols = columns(&ls, pick.iter().map(|&i| i as usize));
        assert!(
            cols >= 28 && rows >= 28,
            "{cols} columns, {rows} rows of 33"
        );
        let mut again = Vec::new();
        spread(&ls, 0..ls.len(), 16.0, 128, 7, &mut again);
        assert_eq!(pick, again);
    }

    #[test]
    fn spread_keeps_every_texel_of_a_small_set_and_only_those_given() {
        let ls = anisotropic_patch();
        let mut pick = Vec::new();
        spread(&ls, (0..ls.len()).step_by(97), 16.0, 64, 1, &mut pick);
        assert_eq!(pick.len(), ls.len().div_ceil(97));
        // Only texels of `among` (here the upper half of the patch), still about `count`
        // of them: the grid is finer (6x6 cells) so that its upper half holds 18.
        let upper = |i: &usize| ls[*i][1] > 0.0;
        let mut pick = Vec::new();
        spread(&ls, (0..ls.len()).filter(upper), 16.0, 16, 1, &mut pick);
        assert!(pick.iter().all(|&i| upper(&(i as usize))), "{pick:?}");
        assert_eq!(pick.len(), 18);
    }
}
