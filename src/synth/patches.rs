//! Patch sampling on the surface (paper 001 §5.2, after Liang et al. 2001 and Efros &
//! Freeman 2001): whole example patches pasted along the orientation field, each chosen by
//! how well it matches the texture already on the surface where it overlaps, joined to it
//! along a minimum-error cut. Structure inside a patch is the example's own, so bricks stay
//! whole and mortar lines straight; only the joins need care.
//!
//! 1. **Patches** ([`super::footprint`]): centres a Poisson-disk sample of the texels,
//!    [`PatchParams::spacing`] × the patch side apart (001: half the patch size, so each
//!    texel is covered by about two patches); each footprint the texels with their local
//!    coordinates `l` in example pixels, laid along the field.
//! 2. **Order**: breadth-first over patches that overlap (001 notes breadth-first works as
//!    well as random; it needs no coarse estimate of the untextured boundary), so every
//!    patch but the first of a connected surface overlaps texture already pasted.
//! 3. **Choice** (001 step 3, "select a patch whose boundary is closest"): the error of an
//!    example position `z` is the squared appearance-space distance
//!    ([`super::matching::appearance`]) between the texels already synthesized inside the
//!    footprint and the example at `z + l`, over up to [`PatchParams::eval_samples`] of
//!    them. Candidates (k-coherence, paper 003 §5.2, instead of an ANN over boundary
//!    zones, because the overlap's shape differs from patch to patch on a surface):
//!    - *continuations*: an overlapped texel `t` with source `s(t)` proposes `s(t) − l(t)`,
//!      the position that continues `t`'s patch exactly;
//!    - *similar places*: the [`super::matching::similar`] list of each continuation;
//!    - a few random positions.
//!
//!    As Liang et al., one is drawn at random among those within [`PatchParams::tolerance`]
//!    of the best error, so the result does not collapse onto one continuation.
//! 4. **Join** ([`super::mincut`]): over the footprint, texels already synthesized and
//!    touching the outside are tied to the old texture, texels not yet synthesized and the
//!    patch's core to the new patch, and every edge of the texel graph inside costs
//!    `|old − new|` at both its ends (Kwatra et al. 2003); the minimum cut decides which
//!    texels take the new patch.
//! 5. Texels no footprint reached (rare: only where the field's charts fold tightly)
//!    continue a synthesized neighbour.
//!
//! Each texel ends with one source position — all channels from the same place, no blur.
//!
//! **Determinism and parallelism**: a patch reads and writes only texels of its own
//! footprint. So a patch starts once every earlier patch (in breadth-first order) whose
//! footprint shares a texel with it is pasted, and later ones that share a texel wait for
//! it: each patch sees exactly the patches before it that it overlaps, as in the sequential
//! order, and each texel is written in that order, whatever the thread count. Random draws
//! hash (seed, patch, draw).

use super::footprint::{centres, spread, turned, Footprints, LevelTexels, Turn};
use super::matching::exemplar::Exemplar;
#[cfg(target_arch = "x86_64")]
use super::matching::features::dist2_lanes;
use super::matching::features::{dist2, Features};
use super::matching::pixel_grid;
use super::mincut::CutGraph;
use super::texel_table::TexelTable;
use crate::random::hash;
use rayon::prelude::*;
use std::sync::atomic::{AtomicU32, Ordering};
use std::sync::{PoisonError, RwLock};

use serde::Serialize;

/// Tuning of patch sampling (defaults measured, see docs/synthesis.md).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct PatchParams {
    /// Patch side in example pixels; `None`: [`AUTO_SIZE`], at most half the example's
    /// shorter side (so that a patch can be placed at many positions). Clamped to the
    /// example either way.
    pub size: Option<usize>,
    /// Distance between patch centres as a fraction of the side.
    pub spacing: f32,
    /// A candidate is eligible when its error is at most (1 + tolerance) × the best.
    pub tolerance: f32,
    /// Random candidates per patch.
    pub random: u32,
    /// Overlapped texels proposing continuations, per patch.
    pub proposers: u32,
    /// Overlapped texels the error is measured on, per patch.
    pub eval_samples: u32,
    /// Step (example pixels) of the coarse exhaustive search over all positions; 0: none.
    pub grid_step: u32,
    /// Overlapped texels the coarse search measures.
    pub grid_samples: u32,
    /// Best positions of the coarse search kept as candidates.
    pub grid_keep: u32,
    /// Best candidates refined by a local search of ±2 pixels.
    pub refine: u32,
}

impl Default for PatchParams {
    fn default() -> Self {
        Self {
            size: None,
            spacing: 0.5,
            tolerance: 0.1,
            random: 8,
            proposers: 24,
            eval_samples: 192,
            grid_step: 3,
            grid_samples: 24,
            grid_keep: 8,
            refine: 3,
        }
    }
}

/// Texels within this fraction of the half-size of a patch's centre always take the new
/// patch: every patch contributes its core, so later patches cannot be swallowed whole
/// by earlier ones that happen to match their overlap well.
const CORE: f32 = 0.25;

/// Largest automatic patch side (example pixels): larger patches keep more structure
/// (measured on the flat grid: pf8 0.029 at 64 against 0.041 at 32 on bricks) but fold on
/// curved parts more often (those parts get smaller patches, see [`MIN_SIZE`]).
pub const AUTO_SIZE: usize = 64;

/// Smallest patch side of the hole-filling passes (example pixels).
pub const MIN_SIZE: usize = 8;

/// Counters (reported).
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct Stats {
    /// Patch side of the first pass (example pixels).
    pub size: usize,
    /// (patch side, patches) of every pass: later passes cover what larger patches could
    /// not reach.
    pub passes: Vec<(usize, u64)>,
    pub patches: u64,
    /// Patches in the longest chain of overlapping patches, summed over passes: the waves
    /// a schedule with a barrier between waves would need.
    pub waves: u64,
    /// Candidate positions whose error was measured.
    pub candidates: u64,
    /// Patches pasted with no texture around (first of a connected surface).
    pub seeded: u64,
    /// Texels that took a new patch over texture pasted before (inside cuts).
    pub replaced: u64,
    /// Texels no footprint reached, continued from a neighbour.
    pub filled: u64,
    /// Bytes of the footprints.
    pub footprint_bytes: u64,
}

/// Source position per texel and counters.
pub struct Output {
    pub source: Vec<[f32; 2]>,
    /// Each texel's source orientation ψ against the field: the turn β the patch it copies
    /// has there ([`Footprints::turns`]). What continues its source to a neighbour: source
    /// + the offset turned by ψ ([`turned`]); texture optimisation's levels use it.
    pub turn: Vec<Turn>,
    pub stats: Stats,
}

/// The patch side used for an example of `w x h` pixels: the requested side (or the
/// automatic one, see [`PatchParams::size`]), at most the example's shorter side minus 2 (a
/// patch must fit with its bilinear taps), even, at least 4.
pub fn effective_size(requested: Option<usize>, w: usize, h: usize) -> usize {
    let short = w.min(h);
    let size = requested.unwrap_or(AUTO_SIZE.min(short / 2));
    (size.min(short.saturating_sub(2)) & !1).max(4)
}

/// Where a patch goes: searched (patch sampling), or given by texture optimisation —
/// joined as given, or settled between the given position and continuations ([`settle`]).
#[derive(Clone, Copy)]
enum Placement<'a, const K: usize> {
    Search,
    Fixed(&'a [[f32; 2]]),
    /// The given positions and the optimised texture (appearance per texel) they were
    /// chosen for.
    Guided(&'a [[f32; 2]], &'a [[f32; K]]),
}

struct Ctx<'a, const K: usize> {
    ex: &'a Exemplar<K>,
    level: &'a LevelTexels,
    fp: &'a Footprints,
    params: &'a PatchParams,
    seed: u64,
    /// How each patch's position is found.
    placement: Placement<'a, K>,
    /// Valid patch centres: [lo, hi_x] × [lo, hi_y].
    lo: f32,
    hi_x: f32,
    hi_y: f32,
}

/// Per-thread scratch.
struct Scratch {
    /// Each footprint texel's index in the footprint (only this patch's texels: a
    /// [`TexelTable`], not an entry per texel of the level per thread).
    local: TexelTable<u32>,
    cands: Vec<[f32; 2]>,
    errs: Vec<(f32, u32)>,
    graph: CutGraph,
    side: Vec<bool>,
    diff: Vec<f32>,
    class: Vec<u8>,
    index: Vec<u32>,
}

impl Scratch {
    fn new() -> Self {
        Self {
            local: TexelTable::new(),
            cands: Vec::new(),
            errs: Vec::new(),
            graph: CutGraph::default(),
            side: Vec::new(),
            diff: Vec::new(),
            class: Vec::new(),
            index: Vec::new(),
        }
    }
}

/// What one patch writes: texels taking the new patch, with their sources and turns.
struct Paste {
    /// The position the patch was pasted at.
    z: [f32; 2],
    texels: Vec<u32>,
    sources: Vec<[f32; 2]>,
    turns: Vec<Turn>,
    candidates: u64,
    seeded: bool,
    replaced: u64,
}

/// Runs patch sampling over the texels of `level` (its step is the surface length of one
/// pixel of `ex`). `progress(done, total)` counts patches.
pub fn run<const K: usize>(
    ex: &Exemplar<K>,
    surface: &subdiv::Surface,
    level: &LevelTexels,
    params: &PatchParams,
    seed: u64,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Output {
    let n = level.len();
    let mut size = effective_size(params.size, ex.width(), ex.height());
    let mut state = State::new(n);
    let mut covered = vec![false; n];
    let mut stats = Stats {
        size,
        ..Stats::default()
    };
    let scratch = super::per_thread::PerThread::<Scratch>::new();
    // Passes of halving patch size: each covers what the larger patches could not reach
    // (open boundaries, thin curved parts where a large patch would fold).
    for pass in 0u64.. {
        let half = size as f32 / 2.0;
        // Centres this many example pixels apart (at each texel's local step).
        let spacing = params.spacing as f64 * size as f64;
        let mask = (pass > 0).then(|| covered.iter().map(|&c| !c).collect::<Vec<bool>>());
        let cs = centres(
            level,
            spacing,
            seed ^ pass.wrapping_mul(0x9E37),
            mask.as_deref(),
        );
        if cs.is_empty() {
            break;
        }
        let fp = Footprints::build(level, cs, half);
        for p in 0..fp.len() {
            for &t in fp.get(p).0 {
                covered[t as usize] = true;
            }
        }
        let ctx = Ctx {
            ex,
            level,
            fp: &fp,
            params,
            seed: seed ^ pass.wrapping_mul(0x51ED),
            placement: Placement::Search,
            lo: 0.5 + half,
            hi_x: ex.width() as f32 - 0.5 - half,
            hi_y: ex.height() as f32 - 0.5 - half,
        };
        let plan = plan(&fp, n);
        stats.patches += fp.len() as u64;
        stats.waves += plan.depth as u64;
        stats.passes.push((size, fp.len() as u64));
        stats.footprint_bytes = stats.footprint_bytes.max(fp.heap_bytes() as u64);
        paste_all(
            &ctx, &plan, &mut state, &scratch, &mut stats, None, progress,
        );
        if covered.iter().all(|&c| c) || size <= MIN_SIZE {
            break;
        }
        size = (size / 2).max(MIN_SIZE);
    }
    stats.filled = fill_uncovered(surface, level, &mut state, ex);
    Output {
        source: state.src,
        turn: state.turn,
        stats,
    }
}

/// The texture pasted so far: source, source orientation, whether set, and appearance per
/// texel.
struct State<const K: usize> {
    src: Vec<[f32; 2]>,
    turn: Vec<Turn>,
    set: Vec<bool>,
    app: Vec<[f32; K]>,
}

impl<const K: usize> State<K> {
    fn new(n: usize) -> Self {
        Self {
            src: vec![[0.0; 2]; n],
            turn: vec![Turn::ZERO; n],
            set: vec![false; n],
            app: vec![[0.0; K]; n],
        }
    }
}

/// What patch `p` reads of the texture pasted so far: the sources, whether set, and the
/// appearance of its footprint's texels, in footprint order. A copy, taken once every
/// earlier patch it overlaps is pasted: a patch reads and writes only texels of its own
/// footprint, so the copy holds what the sequential order would show it (see the module
/// docs), and patches running meanwhile write only texels outside it.
struct Seen<const K: usize> {
    src: Vec<[f32; 2]>,
    set: Vec<bool>,
    app: Vec<[f32; K]>,
}

impl<const K: usize> Seen<K> {
    fn of(state: &State<K>, texels: &[u32]) -> Self {
        Self {
            src: texels.iter().map(|&t| state.src[t as usize]).collect(),
            set: texels.iter().map(|&t| state.set[t as usize]).collect(),
            app: texels.iter().map(|&t| state.app[t as usize]).collect(),
        }
    }
}

/// What the patches running in parallel share: the texture, the counters, and where each
/// patch went.
struct Pasted<'a, const K: usize> {
    state: &'a mut State<K>,
    stats: &'a mut Stats,
    positions: Option<&'a mut [[f32; 2]]>,
    done: usize,
}

/// Runs the patches of one pass as their dependencies allow ([`Runner::patch`]).
struct Runner<'a, const K: usize> {
    ctx: &'a Ctx<'a, K>,
    plan: &'a Plan,
    /// Per patch: earlier overlapping patches not yet pasted.
    waiting: Vec<AtomicU32>,
    pasted: RwLock<Pasted<'a, K>>,
    scratch: &'a super::per_thread::PerThread<Scratch>,
    progress: &'a (dyn Fn(usize, usize) + Sync),
}

impl<'a, const K: usize> Runner<'a, K> {
    /// Pastes patch `p` (every earlier patch it overlaps is pasted), then starts each later
    /// overlapping patch that no longer waits for another.
    fn patch<'s>(&'s self, scope: &rayon::Scope<'s>, p: usize) {
        let c = self.ctx;
        let seen = {
            let pasted = self.pasted.read().unwrap_or_else(PoisonError::into_inner);
            Seen::of(pasted.state, c.fp.get(p).0)
        };
        let r = self.scratch.with(Scratch::new, |s| paste(c, p, &seen, s));
        let apps: Vec<[f32; K]> = r
            .sources
            .iter()
            .map(|s| c.ex.features.sample(s[0], s[1]))
            .collect();
        {
            let mut g = self.pasted.write().unwrap_or_else(PoisonError::into_inner);
            let g = &mut *g;
            if let Some(z) = g.positions.as_deref_mut() {
                z[p] = r.z;
            }
            let state = &mut *g.state;
            for (((&t, &s), &o), a) in r.texels.iter().zip(&r.sources).zip(&r.turns).zip(apps) {
                let t = t as usize;
                state.src[t] = s;
                state.turn[t] = o;
                state.set[t] = true;
                state.app[t] = a;
            }
            g.stats.candidates += r.candidates;
            g.stats.seeded += r.seeded as u64;
            g.stats.replaced += r.replaced;
            g.done += 1;
            (self.progress)(g.done, self.plan.later.len());
        }
        for &q in &self.plan.later[p] {
            if self.waiting[q as usize].fetch_sub(1, Ordering::AcqRel) == 1 {
                scope.spawn(move |scope| self.patch(scope, q as usize));
            }
        }
    }
}

/// Pastes the patches of `ctx`, each as soon as the earlier patches it overlaps are pasted
/// (see the module docs); `positions`, when given, receives the position each patch was
/// pasted at.
///
/// *Why not waves*: a pass's ~240 patches form ~80 waves of ~3, so with a barrier after
/// each wave one of two cores often waited for the other; here a core takes the next
/// patch whose earlier neighbours are pasted.
fn paste_all<const K: usize>(
    ctx: &Ctx<'_, K>,
    plan: &Plan,
    state: &mut State<K>,
    scratch: &super::per_thread::PerThread<Scratch>,
    stats: &mut Stats,
    positions: Option<&mut [[f32; 2]]>,
    progress: &(dyn Fn(usize, usize) + Sync),
) {
    let runner = Runner {
        ctx,
        plan,
        waiting: plan.earlier.iter().map(|&e| AtomicU32::new(e)).collect(),
        pasted: RwLock::new(Pasted {
            state,
            stats,
            positions,
            done: 0,
        }),
        scratch,
        progress,
    };
    let runner = &runner;
    rayon::scope(|scope| {
        for (p, &e) in plan.earlier.iter().enumerate() {
            if e == 0 {
                scope.spawn(move |scope| runner.patch(scope, p));
            }
        }
    });
}

/// Joins patches at given positions — texture optimisation's final assembly — in the
/// breadth-first order of patch sampling: each patch of `fp` is pasted at `positions[p]`
/// and cut into what is already there, so patches meet along seams of least error
/// instead of along the boundaries of whichever patch weighs most. Texels no footprint
/// covers keep `fallback`'s source. With `blend`, joins between patches that nearly
/// continue each other are smoothed (`blend_joins`). `progress(done, total)` counts
/// patches pasted.
#[allow(clippy::too_many_arguments)]
pub fn assemble<const K: usize>(
    ex: &Exemplar<K>,
    level: &LevelTexels,
    fp: &Footprints,
    positions: &[[f32; 2]],
    fallback: &[[f32; 2]],
    guide: Option<&[[f32; K]]>,
    blend: Option<f32>,
    seed: u64,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Vec<[f32; 2]> {
    let n = level.len();
    let params = PatchParams::default();
    let half = fp.half;
    let ctx = Ctx {
        ex,
        level,
        fp,
        params: &params,
        seed,
        placement: match guide {
            Some(g) => Placement::Guided(positions, g),
            None => Placement::Fixed(positions),
        },
        lo: 0.5 + half,
        hi_x: ex.width() as f32 - 0.5 - half,
        hi_y: ex.height() as f32 - 0.5 - half,
    };
    let mut state = State::new(n);
    let mut stats = Stats::default();
    let scratch = super::per_thread::PerThread::new();
    // Where each patch was pasted (settling may move it), for blending its joins.
    let mut pasted = blend.map(|_| vec![[0.0; 2]; fp.len()]);
    paste_all(
        &ctx,
        &plan(fp, n),
        &mut state,
        &scratch,
        &mut stats,
        pasted.as_deref_mut(),
        progress,
    );
    for ((src, &set), &fb) in state.src.iter_mut().zip(&state.set).zip(fallback) {
        if !set {
            *src = fb;
        }
    }
    if let (Some(tau), Some(pasted)) = (blend, &pasted) {
        blend_joins(fp, pasted, &state.set, &mut state.src, tau);
    }
    state.src
}

/// Smooths the joins between patches that nearly continue each other. On a curved surface
/// two overlapping patches laid from different centres disagree by a pixel or two across
/// their overlap (the field turns between the centres; docs/synthesis.md, "Known limits"),
/// so a cut between two copies that continue each other still steps a mortar line
/// sideways. Here every texel's source becomes the weighted mean of the sources the
/// patches covering it give it (`positions[q] + l_q(t)`), over those within `tau` pixels
/// of its own: the weight `(1 − d²/τ²)² · w(l)`, with `w` a window that falls to 0 at the
/// footprint's edge, so the mean changes continuously where a patch begins or ends and is
/// the same on both sides of a cut between two agreeing patches — the step becomes a
/// gentle bend. Patches further apart than `tau` (a join between unrelated copies) are
/// left to the cut. Each texel still copies the example at one position, so every
/// channel comes from the same place.
fn blend_joins(
    fp: &Footprints,
    positions: &[[f32; 2]],
    set: &[bool],
    src: &mut [[f32; 2]],
    tau: f32,
) {
    let n = src.len();
    let cover = fp.covering_coords(n);
    let (start, list, coords) = (&cover.start, &cover.patch, &cover.coords);
    let half = fp.half;
    let out: Vec<[f32; 2]> = (0..n)
        .into_par_iter()
        .map(|t| {
            let s0 = src[t];
            if !set[t] {
                return s0;
            }
            let (mut sx, mut sy, mut sw) = (0.0f64, 0.0f64, 0.0f64);
            for k in start[t] as usize..start[t + 1] as usize {
                let q = list[k] as usize;
                let l = coords[k];
                let s = [positions[q][0] + l[0], positions[q][1] + l[1]];
                let d2 = (s[0] - s0[0]).powi(2) + (s[1] - s0[1]).powi(2);
                if d2 >= tau * tau {
                    continue;
                }
                let a = 1.0 - d2 / (tau * tau);
                let u = 1.0 - (l[0] / half).powi(2).min(1.0);
                let v = 1.0 - (l[1] / half).powi(2).min(1.0);
                let w = (a * a * u * u * v * v) as f64;
                sx += w * s[0] as f64;
                sy += w * s[1] as f64;
                sw += w;
            }
            if sw > 0.0 {
                [(sx / sw) as f32, (sy / sw) as f32]
            } else {
                s0
            }
        })
        .collect();
    src.copy_from_slice(&out);
}

/// The breadth-first order over overlapping patches (see the module docs), as what each
/// patch waits for.
struct Plan {
    /// Per patch: how many earlier patches overlap it.
    earlier: Vec<u32>,
    /// Per patch: the later patches that overlap it (they wait for it).
    later: Vec<Vec<u32>>,
    /// Patches in the longest chain of overlapping patches, each later than the one before
    /// (reported as [`Stats::waves`]).
    depth: usize,
}

/// Plans the order of the patches of `fp` over a level of `texels` texels.
fn plan(fp: &Footprints, texels: usize) -> Plan {
    let np = fp.len();
    let (start, list) = fp.covering(texels);
    // The patches overlapping each patch, ascending, without itself: gathered once and in
    // parallel (both passes below read them; they were gathered twice, serially, with a
    // sort of every membership of the footprint: ~1 s of a 200k-quad torus run at N = 4).
    let adj: Vec<Vec<u32>> = (0..np)
        .into_par_iter()
        .map_init(
            || vec![u32::MAX; np],
            |seen, p| {
                let mut out = Vec::new();
                for &t in fp.get(p).0 {
                    let t = t as usize;
                    for &q in &list[start[t] as usize..start[t + 1] as usize] {
                        if q as usize != p && seen[q as usize] != p as u32 {
                            seen[q as usize] = p as u32;
                            out.push(q);
                        }
                    }
                }
                out.sort_unstable();
                out
            },
        )
        .collect();
    drop((start, list));
    let mut rank = vec![u32::MAX; np];
    let mut order = Vec::with_capacity(np);
    for root in 0..np {
        if rank[root] != u32::MAX {
            continue;
        }
        rank[root] = order.len() as u32;
        order.push(root as u32);
        let mut head = order.len() - 1;
        while head < order.len() {
            let p = order[head] as usize;
            head += 1;
            for &q in &adj[p] {
                if rank[q as usize] == u32::MAX {
                    rank[q as usize] = order.len() as u32;
                    order.push(q);
                }
            }
        }
    }
    let mut earlier = vec![0u32; np];
    let mut later: Vec<Vec<u32>> = vec![Vec::new(); np];
    let mut chain = vec![0usize; np];
    for &p in &order {
        let p = p as usize;
        for &q in adj[p].iter().filter(|&&q| rank[q as usize] < rank[p]) {
            earlier[p] += 1;
            later[q as usize].push(p as u32);
            chain[p] = chain[p].max(chain[q as usize] + 1);
        }
    }
    Plan {
        earlier,
        later,
        depth: chain.iter().max().map_or(0, |&d| d + 1),
    }
}

/// Chooses and joins patch `p` (read-only on the state): its position is searched, or
/// given ([`Ctx::fixed`]).
fn paste<const K: usize>(c: &Ctx<'_, K>, p: usize, seen: &Seen<K>, s: &mut Scratch) -> Paste {
    let (z, candidates, seeded) = match c.placement {
        Placement::Fixed(zs) => (zs[p], 0, false),
        Placement::Guided(zs, g) => settle(c, p, zs[p], g, seen),
        Placement::Search => choose(c, p, seen, s),
    };
    let (texels, coords) = c.fp.get(p);
    // On the pixel lattice (flat grids), the copy's texels become exact example pixels.
    let z = pixel_grid::align(z, coords);
    if seeded {
        return Paste {
            z,
            texels: texels.to_vec(),
            sources: coords.iter().map(|l| [z[0] + l[0], z[1] + l[1]]).collect(),
            turns: c.fp.turns(p).to_vec(),
            candidates,
            seeded: true,
            replaced: 0,
        };
    }
    let (texels, sources, turns, replaced) = join(c, p, z, seen, s);
    Paste {
        z,
        texels,
        sources,
        turns,
        candidates,
        seeded: false,
        replaced,
    }
}

impl<const K: usize> Ctx<'_, K> {
    /// Whether `z` is a valid patch centre (the whole patch inside the example).
    fn valid(&self, z: [f32; 2]) -> bool {
        z[0] >= self.lo && z[0] <= self.hi_x && z[1] >= self.lo && z[1] <= self.hi_y
    }
}

/// Whether `z` is within half a pixel of a position already in `list`.
fn near_any(list: &[[f32; 2]], z: [f32; 2]) -> bool {
    list.iter()
        .any(|o| (o[0] - z[0]).abs() < 0.5 && (o[1] - z[1]).abs() < 0.5)
}

/// About `count` of patch `p`'s overlapped texels (`known`: indices into its footprint),
/// spread over the patch ([`spread`]); `salt` tells the uses apart.
fn spread_known<const K: usize>(
    c: &Ctx<'_, K>,
    p: usize,
    known: &[usize],
    count: u32,
    salt: u64,
) -> Vec<u32> {
    let mut pick = Vec::new();
    spread(
        c.fp.get(p).1,
        known.iter().copied(),
        c.fp.half,
        count as usize,
        hash(c.seed, &[salt, p as u64]),
        &mut pick,
    );
    pick
}

/// The positions continuing patch `p`'s overlapped texels (`known`: indices into its
/// footprint), from at most [`PatchParams::proposers`] of them: texel `t` with source
/// `s(t)` at coordinates `l(t)` proposes `s(t) − l(t)`. `src`: the sources in footprint
/// order ([`Seen::src`]).
fn continuations<'a, const K: usize>(
    c: &'a Ctx<'_, K>,
    p: usize,
    known: &[usize],
    src: &'a [[f32; 2]],
) -> impl Iterator<Item = [f32; 2]> + 'a {
    let coords = c.fp.get(p).1;
    spread_known(c, p, known, c.params.proposers, 0xC047)
        .into_iter()
        .map(move |i| {
            let i = i as usize;
            [src[i][0] - coords[i][0], src[i][1] - coords[i][1]]
        })
}

/// The position of patch `p` in a guided assembly: its optimised position `z0`, or a
/// position continuing a neighbour already pasted, whichever matches best the texture the
/// patch will sit in — the pasted texels where they are set, the optimised texture
/// (`guide`) elsewhere. Where two optimised patches disagree in their overlap (each
/// matched the blurred average, not the other), no cut joins them well; continuing the
/// neighbour then joins seamlessly if the rest of the footprint allows it.
fn settle<const K: usize>(
    c: &Ctx<'_, K>,
    p: usize,
    z0: [f32; 2],
    guide: &[[f32; K]],
    seen: &Seen<K>,
) -> ([f32; 2], u64, bool) {
    let (texels, coords) = c.fp.get(p);
    let m = texels.len();
    let f = &c.ex.features;
    let known: Vec<usize> = (0..m).filter(|&i| seen.set[i]).collect();
    if known.is_empty() {
        return (z0, 0, false);
    }
    let mut cands = vec![z0];
    for z in continuations(c, p, &known, &seen.src) {
        if c.valid(z) && !near_any(&cands, z) {
            cands.push(z);
        }
    }
    // Every k-th texel in flood order, weighting texels (not area) like the seam measure;
    // see `choose`.
    let estep = m.div_ceil(c.params.eval_samples.max(1) as usize).max(1);
    let mut best = (f32::INFINITY, z0);
    for &z in &cands {
        let mut e = 0.0f32;
        for i in (0..m).step_by(estep) {
            let l = coords[i];
            let want = if seen.set[i] {
                &seen.app[i]
            } else {
                &guide[texels[i] as usize]
            };
            e += dist2(want, &f.sample(z[0] + l[0], z[1] + l[1]));
            if e >= best.0 {
                break;
            }
        }
        if e < best.0 {
            best = (e, z);
        }
    }
    (best.1, cands.len() as u64, false)
}

/// The position of patch `p` (001 step 3): the error over the overlap, among the
/// candidates of the module docs, one drawn among those within the tolerance. Returns
/// (position, candidates measured, whether nothing was there to match).
fn choose<const K: usize>(
    c: &Ctx<'_, K>,
    p: usize,
    seen: &Seen<K>,
    s: &mut Scratch,
) -> ([f32; 2], u64, bool) {
    let (texels, coords) = c.fp.get(p);
    let m = texels.len();
    let f = &c.ex.features;
    let valid = |z: [f32; 2]| c.valid(z);
    let random = |k: u64| -> [f32; 2] {
        let h = hash(c.seed, &[0x9A7C, p as u64, k]);
        let a = (h >> 40) as f32 / (1u64 << 24) as f32;
        let b = ((h >> 8) & 0xFF_FFFF) as f32 / (1u64 << 24) as f32;
        [c.lo + a * (c.hi_x - c.lo), c.lo + b * (c.hi_y - c.lo)]
    };
    let known: Vec<usize> = (0..m).filter(|&i| seen.set[i]).collect();
    if known.is_empty() {
        return (random(0), 0, true);
    }
    let app = &seen.app;
    // Candidates.
    s.cands.clear();
    let push = |cands: &mut Vec<[f32; 2]>, z: [f32; 2]| {
        if valid(z) && !near_any(cands, z) {
            cands.push(z);
        }
    };
    let mut conts: Vec<[f32; 2]> = Vec::new();
    for z in continuations(c, p, &known, &seen.src) {
        if !near_any(&conts, z) {
            conts.push(z);
        }
    }
    for &z in &conts {
        push(&mut s.cands, z);
    }
    let (w, h) = (f.width, f.height);
    for &z in &conts {
        let (px, py) = (z[0].floor(), z[1].floor());
        if !(px >= 0.0 && py >= 0.0 && (px as usize) < w && (py as usize) < h) {
            continue;
        }
        let (fx, fy) = (z[0] - px, z[1] - py);
        for (jx, jy) in c.ex.similar.of(px as usize, py as usize) {
            push(&mut s.cands, [jx as f32 + fx, jy as f32 + fy]);
        }
    }
    for k in 0..c.params.random as u64 {
        push(&mut s.cands, random(k + 1));
    }
    if c.params.grid_step > 0 {
        let gsub: Vec<(usize, [f32; 2])> =
            spread_known(c, p, known.as_slice(), c.params.grid_samples, 0x6A1D)
                .iter()
                .map(|&i| (i as usize, coords[i as usize]))
                .collect();
        let keep = c.params.grid_keep as usize;
        let g = c.params.grid_step as f32;
        let top = grid_top(f, app, &gsub, [c.lo, c.hi_x, c.hi_y], g, keep);
        for (_, z) in top {
            push(&mut s.cands, z);
        }
    }
    if s.cands.is_empty() {
        s.cands.push(random(0));
    }
    // Errors on every k-th texel of the overlap in flood order. Not `spread`: that weighs
    // area, and where texel density varies (the all-triangle Spot at N = 8) the texels of
    // dense small faces then count for little in the choice, while the seam measure counts
    // texel pairs — seam ratio 0.97–1.07 with the stride, 1.15–1.37 spread (seeds 1–3).
    let estep = known
        .len()
        .div_ceil(c.params.eval_samples.max(1) as usize)
        .max(1);
    let sub: Vec<usize> = known.iter().copied().step_by(estep).collect();
    s.errs.clear();
    // Errors of positions over the subset, eight at a time ([`measure`]); a position is
    // eligible when its error is within (1 + tol) × the best so far, in candidate order.
    let tol1 = 1.0 + c.params.tolerance;
    let pts: Vec<(usize, [f32; 2])> = sub.iter().map(|&i| (i, coords[i])).collect();
    let mut es = Vec::with_capacity(8);
    let mut best = f32::INFINITY;
    for (g, zs) in s.cands.chunks(8).enumerate() {
        measure(f, app, &pts, zs, best * tol1, &mut es);
        for (j, &e) in es.iter().enumerate() {
            let bound = best * tol1;
            if e <= bound {
                s.errs.push((e, (g * 8 + j) as u32));
                best = best.min(e);
            }
        }
    }
    // Local refinement of the best few: ±2 pixels.
    if c.params.refine > 0 {
        let mut order: Vec<(f32, u32)> = s.errs.clone();
        order.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        let mut around = Vec::with_capacity(24);
        for &(_, ci) in order.iter().take(c.params.refine as usize) {
            let z0 = s.cands[ci as usize];
            around.clear();
            for dy in -2i32..=2 {
                for dx in -2i32..=2 {
                    if dx == 0 && dy == 0 {
                        continue;
                    }
                    let z = [z0[0] + dx as f32, z0[1] + dy as f32];
                    if valid(z) {
                        around.push(z);
                    }
                }
            }
            for zs in around.chunks(8) {
                measure(f, app, &pts, zs, best * tol1, &mut es);
                for (&z, &e) in zs.iter().zip(&es) {
                    let bound = best * tol1;
                    if e <= bound {
                        s.cands.push(z);
                        s.errs.push((e, (s.cands.len() - 1) as u32));
                        best = best.min(e);
                    }
                }
            }
        }
    }
    let limit = best * (1.0 + c.params.tolerance) + 1e-12;
    s.errs.retain(|&(e, _)| e <= limit);
    s.errs
        .sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
    let pick = (hash(c.seed, &[0x51C7, p as u64]) % s.errs.len() as u64) as usize;
    (
        s.cands[s.errs[pick].1 as usize],
        s.cands.len() as u64,
        false,
    )
}

/// The errors of up to eight positions `zs` over `pts` (index into `app`, `l`): for each, the sum
/// over `pts` in order of [`dist2`] between the texel's appearance and the example sampled
/// at `z + l` — exactly, or cut short once above `bound` (then the value returned is some
/// partial sum above `bound`). [`choose`] passes the bound the first of the eight would
/// have had; the bound only falls from one position to the next, so a sum cut short is
/// refused as the sequential loop refused it, and a sum not cut short is its value.
///
/// *Why eight at a time*: with 8 matched values the eight positions are measured side by
/// side ([`measure8_avx2`]: a sample's eight squared differences per position transposed,
/// so each sum runs over the values in [`dist2`]'s order), which was most of the cost of
/// choosing a patch after the grid search (docs/benchmarks.md, "Patch sampling speed").
fn measure<const K: usize>(
    f: &Features<K>,
    app: &[[f32; K]],
    pts: &[(usize, [f32; 2])],
    zs: &[[f32; 2]],
    bound: f32,
    out: &mut Vec<f32>,
) {
    debug_assert!(zs.len() <= 8);
    out.clear();
    #[cfg(target_arch = "x86_64")]
    if K == 8 && !zs.is_empty() && std::arch::is_x86_feature_detected!("avx2") {
        // Unused lanes repeat the last position.
        let z8: [[f32; 2]; 8] = std::array::from_fn(|j| zs[j.min(zs.len() - 1)]);
        // SAFETY: AVX2 is available (checked just above) and K == 8.
        let e = unsafe { measure8_avx2(f, app.as_flattened(), pts, &z8, bound) };
        out.extend_from_slice(&e[..zs.len()]);
        return;
    }
    for &z in zs {
        let mut e = 0.0f32;
        for &(t, l) in pts {
            e += dist2(&app[t], &f.sample(z[0] + l[0], z[1] + l[1]));
            if e > bound {
                break;
            }
        }
        out.push(e);
    }
}

/// [`measure`] for 8 values per pixel and eight positions; `app` is the texels'
/// appearance, 8 values each. The bilinear lookup is [`Features::sample8_avx2`],
/// `Features::sample`'s values bit for bit, so every sum is the scalar one.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn measure8_avx2<const K: usize>(
    f: &Features<K>,
    app: &[f32],
    pts: &[(usize, [f32; 2])],
    zs: &[[f32; 2]; 8],
    bound: f32,
) -> [f32; 8] {
    use std::arch::x86_64::*;
    let bv = _mm256_set1_ps(bound);
    let mut e = _mm256_setzero_ps();
    let mut sq = [_mm256_setzero_ps(); 8];
    for &(t, l) in pts {
        let q = _mm256_loadu_ps(app[t * 8..t * 8 + 8].as_ptr());
        for j in 0..8 {
            let v = f.sample8_avx2(zs[j][0] + l[0], zs[j][1] + l[1]);
            let dv = _mm256_sub_ps(q, v);
            sq[j] = _mm256_mul_ps(dv, dv);
        }
        e = _mm256_add_ps(e, dist2_lanes(&sq));
        if _mm256_movemask_ps(_mm256_cmp_ps::<_CMP_GT_OQ>(e, bv)) == 0xFF {
            break;
        }
    }
    let mut out = [0.0f32; 8];
    _mm256_storeu_ps(out.as_mut_ptr(), e);
    out
}

/// The coarse search of [`choose`]: the `keep` positions of the grid of step `g` over
/// `[lo, hi_x] × [lo, hi_y]` (`bounds`) whose error over `gsub` (index into `app`, `l`) against the
/// example's pixels is lowest, best first, ties in scan order (rows, then columns).
///
/// *Why a kernel*: this scan measures a few thousand positions per patch and was the
/// largest part of choosing one (docs/benchmarks.md, "Patch sampling speed"). With 8
/// matched values ([`super::matching::appearance`]'s default) eight positions of a row are
/// measured side by side ([`grid_row8_avx2`]), each sum in the scalar order, so the result
/// is bit for bit the scalar scan's ([`grid_row_scalar`]).
fn grid_top<const K: usize>(
    f: &Features<K>,
    app: &[[f32; K]],
    gsub: &[(usize, [f32; 2])],
    bounds: [f32; 3],
    g: f32,
    keep: usize,
) -> Vec<(f32, [f32; 2])> {
    let [lo, hi_x, hi_y] = bounds;
    let mut top: Vec<(f32, [f32; 2])> = Vec::with_capacity(keep + 1);
    // The row's positions, accumulated as the scan always did (x += g).
    let mut xs = Vec::new();
    let mut x = lo;
    while x <= hi_x {
        xs.push(x);
        x += g;
    }
    #[cfg(target_arch = "x86_64")]
    let simd = K == 8
        && f.width * f.height * K < i32::MAX as usize
        && std::arch::is_x86_feature_detected!("avx2");
    #[cfg(target_arch = "x86_64")]
    let queries: Vec<f32> = if simd {
        gsub.iter().flat_map(|&(t, _)| app[t]).collect()
    } else {
        Vec::new()
    };
    let mut y = lo;
    while y <= hi_y {
        #[cfg(target_arch = "x86_64")]
        if simd {
            // SAFETY: AVX2 is available (checked above), K == 8 and every offset fits i32.
            unsafe {
                grid_row8_avx2(
                    f.flat(),
                    f.width,
                    f.height,
                    &queries,
                    gsub,
                    &xs,
                    y,
                    keep,
                    &mut top,
                )
            };
            y += g;
            continue;
        }
        grid_row_scalar(f, app, gsub, &xs, y, keep, &mut top);
        y += g;
    }
    top
}

/// Offers position (x, y) with error `e` to `top` (the `keep` best so far, ascending; an
/// equal error goes after those already there, so earlier positions win ties).
#[inline]
fn offer(top: &mut Vec<(f32, [f32; 2])>, keep: usize, e: f32, z: [f32; 2]) {
    if e < bound_of(top, keep) {
        let pos = top.partition_point(|o| o.0 <= e);
        top.insert(pos, (e, z));
        top.truncate(keep);
    }
}

/// The error a position must stay below to enter `top`.
#[inline]
fn bound_of(top: &[(f32, [f32; 2])], keep: usize) -> f32 {
    if top.len() == keep {
        top[keep - 1].0
    } else {
        f32::INFINITY
    }
}

/// One row of [`grid_top`]'s scan, position by position; each sum stops once it can no
/// longer enter `top`.
#[allow(clippy::too_many_arguments)]
fn grid_row_scalar<const K: usize>(
    f: &Features<K>,
    app: &[[f32; K]],
    gsub: &[(usize, [f32; 2])],
    xs: &[f32],
    y: f32,
    keep: usize,
    top: &mut Vec<(f32, [f32; 2])>,
) {
    let (w, h) = (f.width, f.height);
    for &x in xs {
        let bound = bound_of(top, keep);
        let mut e = 0.0f32;
        for &(t, l) in gsub {
            let (px, py) = ((x + l[0]) as usize, (y + l[1]) as usize);
            e += dist2(&app[t], f.at(px.min(w - 1), py.min(h - 1)));
            if e >= bound {
                break;
            }
        }
        offer(top, keep, e, [x, y]);
    }
}

/// [`grid_row_scalar`] for 8 values per pixel, eight positions at a time: each position's
/// sum is kept in one lane, and one sample's eight squared differences per position are
/// summed by [`dist2_lanes`] so that their sum runs over the values in [`dist2`]'s order
/// — every lane's total is the scalar one, bit for bit. A group stops once all eight
/// totals are at or above the bound `top` had when it began; the totals are then offered
/// to `top` one by one, in scan order, as the scalar scan does. A total cut short that way
/// is above that bound and so above any later one (the bound only falls): it is refused
/// as the scalar scan refuses it, and a total not cut short is the scalar's exactly.
/// `flat`: the example's vectors ([`Features::flat`]); `queries`: the 8 values of each
/// sample of `gsub`, in order.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[allow(clippy::too_many_arguments)]
unsafe fn grid_row8_avx2(
    flat: &[f32],
    w: usize,
    h: usize,
    queries: &[f32],
    gsub: &[(usize, [f32; 2])],
    xs: &[f32],
    y: f32,
    keep: usize,
    top: &mut Vec<(f32, [f32; 2])>,
) {
    use std::arch::x86_64::*;
    let n = gsub.len();
    // Each sample's row start (in values), as the scalar scan clamps it.
    let rows: Vec<i32> = gsub
        .iter()
        .map(|&(_, l)| (((y + l[1]) as usize).min(h - 1) * w * 8) as i32)
        .collect();
    let wmax = _mm256_set1_ps((w - 1) as f32);
    let zero = _mm256_setzero_ps();
    let mut i0 = 0;
    while i0 + 8 <= xs.len() {
        let bound = bound_of(top, keep);
        let bv = _mm256_set1_ps(bound);
        let xv = _mm256_loadu_ps(xs[i0..i0 + 8].as_ptr());
        let mut e = _mm256_setzero_ps();
        let mut at = [0i32; 8];
        for s in 0..n {
            let l0 = gsub[s].1[0];
            // (x + l0) as usize, then .min(w − 1): clamping in floats first gives the same
            // column for every finite value (and 0 for NaN, as `as usize` does).
            let px = _mm256_min_ps(
                _mm256_max_ps(_mm256_add_ps(xv, _mm256_set1_ps(l0)), zero),
                wmax,
            );
            let off = _mm256_add_epi32(
                _mm256_slli_epi32::<3>(_mm256_cvttps_epi32(px)),
                _mm256_set1_epi32(rows[s]),
            );
            _mm256_storeu_si256(at.as_mut_ptr() as *mut __m256i, off);
            let q = _mm256_loadu_ps(queries[s * 8..s * 8 + 8].as_ptr());
            let mut sq = [zero; 8];
            for j in 0..8 {
                let a = at[j] as usize;
                let d = _mm256_sub_ps(q, _mm256_loadu_ps(flat[a..a + 8].as_ptr()));
                sq[j] = _mm256_mul_ps(d, d);
            }
            e = _mm256_add_ps(e, dist2_lanes(&sq));
            if _mm256_movemask_ps(_mm256_cmp_ps::<_CMP_GE_OQ>(e, bv)) == 0xFF {
                break;
            }
        }
        let mut es = [0.0f32; 8];
        _mm256_storeu_ps(es.as_mut_ptr(), e);
        for j in 0..8 {
            offer(top, keep, es[j], [xs[i0 + j], y]);
        }
        i0 += 8;
    }
    // The row's last positions, fewer than eight.
    for &x in &xs[i0..] {
        let bound = bound_of(top, keep);
        let mut e = 0.0f32;
        for s in 0..n {
            let l0 = gsub[s].1[0];
            let px = ((x + l0) as usize).min(w - 1);
            let a = rows[s] as usize + px * 8;
            let q: &[f32; 8] = queries[s * 8..s * 8 + 8].try_into().expect("8 values");
            let v: &[f32; 8] = flat[a..a + 8].try_into().expect("8 values");
            e += dist2(q, v);
            if e >= bound {
                break;
            }
        }
        offer(top, keep, e, [x, y]);
    }
}

/// Joins patch `p` at position `z` to the texture already there by a minimum cut; returns
/// the texels that take the new patch, their sources, and how many replaced old texture.
fn join<const K: usize>(
    c: &Ctx<'_, K>,
    p: usize,
    z: [f32; 2],
    seen: &Seen<K>,
    s: &mut Scratch,
) -> (Vec<u32>, Vec<[f32; 2]>, Vec<Turn>, u64) {
    let (set, app) = (&seen.set, &seen.app);
    let (texels, coords) = c.fp.get(p);
    let m = texels.len();
    let f = &c.ex.features;
    // Minimum-error cut over the footprint.
    s.local.clear();
    for (i, &t) in texels.iter().enumerate() {
        s.local.insert(t, i as u32);
    }
    s.diff.clear();
    for (i, &l) in coords.iter().enumerate() {
        s.diff.push(if set[i] {
            dist2(&app[i], &f.sample(z[0] + l[0], z[1] + l[1])).sqrt()
        } else {
            f32::NAN
        });
    }
    // Terminal-tied texels are contracted into their terminal, so the max-flow only
    // sees the free part of the overlap: texels already synthesized that touch the
    // outside keep the old texture (source); texels not yet synthesized and the patch's
    // core take the new one (sink).
    const FREE: u8 = 0;
    const OLD: u8 = 1;
    const NEW: u8 = 2;
    let edges = c.level.edges();
    let core = CORE * c.fp.half;
    s.class.clear();
    s.index.clear();
    let mut free = 0usize;
    for i in 0..m {
        let t = texels[i] as usize;
        let l = coords[i];
        let class = if !set[i] || (l[0].abs() <= core && l[1].abs() <= core) {
            NEW
        } else if edges.of(t).iter().any(|&u| !s.local.contains(u)) {
            OLD
        } else {
            FREE
        };
        s.class.push(class);
        s.index.push(free as u32);
        if class == FREE {
            free += 1;
        }
    }
    s.graph.reset(free);
    for (i, &t) in texels.iter().enumerate().take(m) {
        let ci = s.class[i];
        let t = t as usize;
        for u in edges.of(t) {
            // Each edge once (from its lower texel), inside the footprint.
            if (u as usize) < t {
                continue;
            }
            let Some(&j) = s.local.get(u) else {
                continue;
            };
            let j = j as usize;
            let cj = s.class[j];
            if ci != FREE && cj != FREE {
                continue; // within one terminal, or a constant cost between the two
            }
            let (da, db) = (s.diff[i], s.diff[j]);
            let cap = match (da.is_nan(), db.is_nan()) {
                (false, false) => da + db,
                (false, true) => 2.0 * da,
                (true, false) => 2.0 * db,
                (true, true) => 0.0,
            };
            let cap = cap + 1e-6;
            let (a, b) = (s.index[i] as usize, s.index[j] as usize);
            match (ci, cj) {
                (FREE, FREE) => s.graph.edge(a, b, cap),
                (FREE, OLD) => s.graph.terminal(a, cap, 0.0),
                (FREE, _) => s.graph.terminal(a, 0.0, cap),
                (OLD, _) => s.graph.terminal(b, cap, 0.0),
                _ => s.graph.terminal(b, 0.0, cap),
            }
        }
    }
    let mut side = std::mem::take(&mut s.side);
    s.graph.solve(&mut side);
    let mut out_t = Vec::new();
    let mut out_s = Vec::new();
    let mut out_o = Vec::new();
    let turns = c.fp.turns(p);
    let mut replaced = 0;
    for i in 0..m {
        let keep_old = match s.class[i] {
            OLD => true,
            NEW => false,
            _ => side[s.index[i] as usize],
        };
        if !keep_old {
            if set[i] {
                replaced += 1;
            }
            out_t.push(texels[i]);
            out_s.push([z[0] + coords[i][0], z[1] + coords[i][1]]);
            out_o.push(turns[i]);
        }
    }
    s.side = side;
    (out_t, out_s, out_o, replaced)
}

/// Gives every texel no footprint reached the continuation of a synthesized neighbour
/// (breadth-first, nearest neighbour first), in that neighbour's source orientation;
/// isolated texels get the example's centre. Returns how many were filled.
fn fill_uncovered<const K: usize>(
    surface: &subdiv::Surface,
    level: &LevelTexels,
    state: &mut State<K>,
    ex: &Exemplar<K>,
) -> u64 {
    let State { src, turn, set, .. } = state;
    let n = src.len();
    let mut filled = 0u64;
    let mut frontier: Vec<usize> = (0..n).filter(|&t| !set[t]).collect();
    if frontier.is_empty() {
        return 0; // the texel graph is not needed (nor built)
    }
    let graph = level.graph(surface);
    let mut nb = Vec::new();
    let (w, h) = (ex.width() as f32, ex.height() as f32);
    while !frontier.is_empty() {
        let mut next = Vec::new();
        let mut updates = Vec::new();
        for &t in &frontier {
            nb.clear();
            graph.neighbours(t, &mut nb);
            match nb.iter().map(|&u| u as usize).find(|&u| set[u]) {
                Some(u) => {
                    let e = turned(level.offset(u, t), turn[u]);
                    let s = [
                        (src[u][0] + e[0]).clamp(0.5, w - 0.5),
                        (src[u][1] + e[1]).clamp(0.5, h - 0.5),
                    ];
                    updates.push((t, s, turn[u]));
                }
                None => next.push(t),
            }
        }
        if updates.is_empty() {
            for &t in &next {
                src[t] = [w / 2.0, h / 2.0];
                set[t] = true;
                filled += 1;
            }
            break;
        }
        for (t, s, o) in updates {
            src[t] = s;
            turn[t] = o;
            set[t] = true;
            filled += 1;
        }
        frontier = next;
    }
    filled
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Two patches along a row of 41 texels (texel t at x = t), centred at 12 and 28 with
    /// half-size 12, pasted at positions that disagree by `gap` pixels; the texels left of
    /// 20 took the first, the others the second (a cut at 20).
    fn two_patches(gap: f32) -> (Footprints, Vec<[f32; 2]>, Vec<[f32; 2]>) {
        let patch = |c: u32| {
            let list = (c.saturating_sub(12)..=(c + 12).min(40))
                .map(|t| (t, [t as f32 - c as f32, 0.0]))
                .collect::<Vec<_>>();
            // The centre's entry first.
            let mut list = list;
            list.sort_by_key(|&(t, _)| t != c);
            (c, list)
        };
        let fp = Footprints::from_lists(12.0, vec![patch(12), patch(28)]);
        let positions = vec![[50.0, 50.0], [66.0 + gap, 50.0]];
        let src = (0..41)
            .map(|t| {
                let (z, c) = if t < 20 {
                    (positions[0], 12)
                } else {
                    (positions[1], 28)
                };
                [z[0] + (t - c) as f32, z[1]]
            })
            .collect();
        (fp, positions, src)
    }

    /// The grid search's kernel gives the scalar scan's positions and errors bit for bit,
    /// ties included (the example repeats every 9 × 7 pixels, so positions 9 apart along a
    /// row have equal sums; the values are not on a lattice, so the order of a sum's terms
    /// shows in its bits), for samples reaching past the example's edges and rows whose
    /// length is not a multiple of 8.
    #[test]
    fn grid_search_kernel_matches_the_scalar_scan() {
        let (w, h) = (61, 53);
        let mut img = crate::pyramid::Image::new(w, h, 8);
        let rnd = |a: u64| {
            let r = a
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            let r = (r ^ (r >> 29)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
            ((r >> 40) as f32 / (1u64 << 24) as f32) - 0.5
        };
        for y in 0..h {
            for x in 0..w {
                for k in 0..8 {
                    img.data[(y * w + x) * 8 + k] = rnd((((x % 9) * 7 + y % 7) * 8 + k) as u64);
                }
            }
        }
        let f = Features::<8>::from_image(&img);
        let app: Vec<[f32; 8]> = (0..40)
            .map(|i| std::array::from_fn(|k| rnd(1000 + i * 8 + k as u64)))
            .collect();
        for (ns, half, g, keep) in [
            (24, 12.0f32, 3.0f32, 8),
            (7, 20.0, 1.0, 3),
            (1, 5.0, 2.0, 1),
        ] {
            let gsub: Vec<(usize, [f32; 2])> = (0..ns)
                .map(|i| {
                    let a = i as f32 * 2.39996;
                    let rr = half * 1.3 * ((i + 1) as f32 / ns as f32).sqrt();
                    (i % app.len(), [rr * a.cos(), rr * a.sin()])
                })
                .collect();
            let (lo, hi_x, hi_y) = (0.5 + half, w as f32 - 0.5 - half, h as f32 - 0.5 - half);
            let got = grid_top(&f, &app, &gsub, [lo, hi_x, hi_y], g, keep);
            let mut xs = Vec::new();
            let mut x = lo;
            while x <= hi_x {
                xs.push(x);
                x += g;
            }
            let mut want = Vec::new();
            let mut y = lo;
            while y <= hi_y {
                grid_row_scalar(&f, &app, &gsub, &xs, y, keep, &mut want);
                y += g;
            }
            assert_eq!(got.len(), keep);
            for (a, b) in got.iter().zip(&want) {
                assert_eq!(a.0.to_bits(), b.0.to_bits(), "{got:?} vs {want:?}");
                assert_eq!(a.1, b.1, "{got:?} vs {want:?}");
            }
        }
    }

    /// The candidates' kernel gives the scalar errors bit for bit without a bound, and with
    /// one, every error either exactly or cut short above the bound (never below it), for
    /// positions near and beyond the example's edges and fewer than eight at a time.
    #[test]
    fn measure_kernel_matches_the_scalar_errors() {
        let (w, h) = (45, 38);
        let mut img = crate::pyramid::Image::new(w, h, 8);
        let mut r = 0x9E37_79B9u64;
        let mut next = || {
            r = r
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (r >> 40) as f32 / (1u64 << 24) as f32
        };
        for v in img.data.iter_mut() {
            *v = next() - 0.5;
        }
        let f = Features::<8>::from_image(&img);
        let app: Vec<[f32; 8]> = (0..30)
            .map(|_| std::array::from_fn(|_| next() - 0.5))
            .collect();
        let pts: Vec<(usize, [f32; 2])> = (0..50)
            .map(|i| (i % 30, [next() * 24.0 - 12.0, next() * 24.0 - 12.0]))
            .collect();
        let zs: Vec<[f32; 2]> = (0..13)
            .map(|_| {
                [
                    next() * (w as f32 + 10.0) - 5.0,
                    next() * (h as f32 + 10.0) - 5.0,
                ]
            })
            .collect();
        let scalar = |z: [f32; 2]| {
            let mut e = 0.0f32;
            for &(t, l) in &pts {
                e += dist2(&app[t], &f.sample(z[0] + l[0], z[1] + l[1]));
            }
            e
        };
        let mut out = Vec::new();
        for n in [8, 5, 1] {
            for chunk in zs.chunks(n) {
                measure(&f, &app, &pts, chunk, f32::INFINITY, &mut out);
                assert_eq!(out.len(), chunk.len());
                for (&z, &e) in chunk.iter().zip(&out) {
                    assert_eq!(e.to_bits(), scalar(z).to_bits(), "{z:?}");
                }
                let bound = scalar(chunk[0]) * 0.9;
                measure(&f, &app, &pts, chunk, bound, &mut out);
                for (&z, &e) in chunk.iter().zip(&out) {
                    let full = scalar(z);
                    assert!(
                        e.to_bits() == full.to_bits() || (e > bound && e <= full),
                        "{z:?}: {e} vs {full}, bound {bound}"
                    );
                    if full <= bound {
                        assert_eq!(e.to_bits(), full.to_bits());
                    }
                }
            }
        }
    }

    /// A patch waits for the earlier patches (breadth-first) that share a texel with it,
    /// and only for those: a chain of three overlapping patches runs in order, a patch
    /// apart from them waits for nothing.
    #[test]
    fn patches_wait_for_the_earlier_patches_they_overlap() {
        let patch = |c: u32, texels: std::ops::RangeInclusive<u32>| {
            let mut list: Vec<(u32, [f32; 2])> =
                texels.map(|t| (t, [t as f32 - c as f32, 0.0])).collect();
            list.sort_by_key(|&(t, _)| t != c);
            (c, list)
        };
        let fp = Footprints::from_lists(
            6.0,
            vec![
                patch(5, 0..=10),
                patch(24, 18..=30),
                patch(13, 8..=19),
                patch(35, 32..=38),
            ],
        );
        let plan = plan(&fp, 40);
        assert_eq!(plan.earlier, [0, 1, 1, 0]);
        assert_eq!(plan.later, [vec![2], vec![], vec![1], vec![]]);
        assert_eq!(plan.depth, 3);
    }

    #[test]
    fn blended_joins_bend_a_small_step_and_leave_single_patches_and_large_steps_alone() {
        let (fp, z, mut src) = two_patches(0.8);
        let before = src.clone();
        assert!(
            (before[20][0] - before[19][0] - 1.8).abs() < 1e-5,
            "a 0.8 px step at the cut"
        );
        blend_joins(&fp, &z, &[true; 41], &mut src, 4.0);
        // Where one patch alone covers a texel nothing moves.
        for t in (0..16).chain(25..41) {
            assert_eq!(src[t], before[t], "texel {t}");
        }
        // The step is spread: no neighbour step differs from one pixel by more than a
        // quarter of the gap, and the row still runs from one patch to the other.
        for t in 0..40 {
            let d = src[t + 1][0] - src[t][0];
            assert!((d - 1.0).abs() < 0.2, "step {d} at texel {t}");
            assert_eq!(src[t][1], 50.0);
        }
        // Patches further apart than tau are left to the cut.
        let (fp, z, mut src) = two_patches(5.0);
        let before = src.clone();
        blend_joins(&fp, &z, &[true; 41], &mut src, 4.0);
        assert_eq!(src, before);
    }
}
