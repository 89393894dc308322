//! Jump-map synthesis on the surface (paper 002, Zelinka & Garland 2003, §4), on texels
//! instead of mesh vertices: every texel is assigned a position in the example by
//! continuing an already synthesized neighbour's position across the edge between them,
//! now and then taking one of the jumps the [`JumpMap`] stores there. No neighbourhood is
//! compared at synthesis time, which is what makes it fast (tens of millions of texels per
//! second).
//!
//! - **Vertices and edges** are the texels and the texel grid's 4-neighbourhood across
//!   domain edges, T-junctions and extraordinary corners ([`crate::texels::EdgeGraph`]).
//! - **Order** (§4.1, region growing), by *geodesic distance*: texels in the order of
//!   their shortest-path distance over the edge graph from one seed texel per connected
//!   component (the centre texel of its lowest domain), so the synthesized region grows as
//!   a round front. 002 grows by "the unsynthesized vertex whose proportion of
//!   already-synthesized neighbours is greatest"; on texels that fills a face before it
//!   crosses into the next (a texel across a face edge has one synthesized neighbour of
//!   four), so the places where separately grown regions meet — where the texture breaks —
//!   ran along face edges, and the seam ratio with high-contrast examples reached 1.4–1.8
//!   (docs/jump.md, "Growth order"). It depends only on the mesh and the resolution, so it
//!   is computed once per prepared mesh ([`growth_order`]) and synthesis runs through it
//!   sequentially: the result is the same for any thread count. With it the prepared mesh
//!   keeps a [`Plan`]: per texel, in that order, its earlier neighbours' ranks and edge
//!   offsets and its validity margin, so the sequential pass reads its data in order
//!   (5.7–6.1 → 17–22 M texels/s on Spot, N = 32–128; the same output).
//! - **Edge offsets** (§4.2.2, figure 4): the edge s→t is projected on the tangent plane
//!   whose basis is the average of the endpoints' field frames — û = normalize(v1_s + v1_t),
//!   v̂ = the part of (v2_s + v2_t) perpendicular to û, normalized — and divided by the scale:
//!   d(s→t) = ((P_t − P_s)·û, −(P_t − P_s)·v̂) / S in example pixels (the minus: image rows
//!   grow downwards, as in coherent synthesis). Each endpoint sees the opposite offset.
//! - **Selection table** (§4.2.5, figure 6): every synthesized neighbour s with address
//!   a_s contributes its continuation a_s + d(s→t), weight
//!   [`JumpParams::continuation`] / |d| ("explicitly divide the continuation weights by
//!   the length of the corresponding edge offset"), times a ramp from 0 at the example's
//!   border to 1 at [`JumpParams::border`] of its size ("to encourage a jump away from the
//!   boundary"); and its floating-point jump list (§4.2.3: the jumps of the four pixels
//!   around a_s, bilinearly weighted, each destination moved by a_s's sub-pixel offset)
//!   continued by d(s→t). One random number picks an entry by weight; several neighbours
//!   proposing the same place add up ("probabilistically good matching"), and — beyond
//!   002 — only the continuations the most neighbours agree on keep their weight
//!   ([`JumpParams::consensus`]).
//! - **Validity** (§4.2.4): an address is valid for t when the box of t's incident edge
//!   offsets around it stays inside the example's pixel-centre rectangle (for edges to
//!   texels not yet synthesized the chord length stands in for the offset: it bounds both
//!   of its components, and saves projecting an edge nobody continues). Invalid entries
//!   are filtered out by rejection: a drawn invalid entry is drawn again (another random
//!   number), which samples exactly the table of valid entries without building it, so the
//!   common case (a continuation is drawn) never looks at the jump lists at all. "In the
//!   rare event that there are still no valid entries, a random valid address is
//!   assigned" (after [`MAX_DRAWS`] draws), as is the seed texel of every component.
//!
//! - **Texture blending** (§4.4, [`JumpParams::blend`]): where a neighbour's
//!   continuation into a texel disagrees with the texel's source (a jump, two fronts
//!   meeting), the example there is mixed into the texel's value ([`super::Blend`],
//!   mixed in by [`super::face_maps_blended`]), so a break ramps over the two texels
//!   beside it instead of cutting between them; inside a continued copy nothing changes.
//!
//! Randomness is the counter-based hash of (seed, texel, draw) of coherent synthesis.

use super::blend::Blend;
use super::footprint::LevelTexels;
use super::matching::jumpmap::JumpMap;
use crate::layout::TexelLayout;
use crate::random::random2;
use crate::texels::EdgeGraph;
use glam::Vec3;
use serde::Serialize;

/// Draws from a texel's table before it gets a random valid address.
pub const MAX_DRAWS: u64 = 8;

/// Tuning of jump-map synthesis (defaults measured, docs/synthesis.md "Jump maps").
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct JumpParams {
    /// Weight of a continuation across a one-pixel edge: the desired mean number of texels
    /// between jumps (§4.2.5; jump weights sum to at most 1 per pixel).
    pub continuation: f32,
    /// Share of the example's width/height over which continuations lose weight towards
    /// its border (§4.2.1).
    pub border: f32,
    /// How the jump map is built.
    pub map: super::matching::jumpmap::JumpMapParams,
    /// Consensus (example pixels): where a texel's synthesized neighbours propose
    /// different continuations, only those agreed by the most others (within this
    /// distance of each other) keep their weight; the jumps keep theirs. 002 lets
    /// agreeing neighbours' weights add up ("probabilistically good matching"), which
    /// still gives a lone front a third or a quarter of the draws where two fronts meet;
    /// each such draw puts a break between the texel and its other neighbours. With the
    /// consensus (1.5 px), seed 1–3 means: seam ratio bunny N = 16 1.58 → 1.24, Spot
    /// 1.13 → 0.85, open cube 1.12 → 0.92 (docs/jump.md, "Consensus"). `None`: 002's table
    /// as it is.
    pub consensus: Option<f32>,
    /// Texture blending across breaks (002 §4.4, "All results use texture blending";
    /// [`super::blend`]): each neighbour's continuation into a texel weighs this much
    /// against the texel's own source's 1 (a cross neighbour's twice as much) where the
    /// two disagree (`blend`). Default 0.5: seed 1–3 means, seam ratio bunny N = 16
    /// with reptile scales 1.28 → 1.18 (under issue 14's 1.2), pf1 −30–40%, pf4/pf8
    /// −1–4% on the bunny, Spot, the double torus and Blub (docs/jump.md, "Texture
    /// blending"). `None`: every texel's value is the look-up at its source, byte for
    /// byte as before.
    pub blend: Option<f32>,
}

impl Default for JumpParams {
    fn default() -> Self {
        Self {
            continuation: 100.0,
            border: 0.1,
            map: Default::default(),
            consensus: Some(CONSENSUS_PX),
            blend: Some(BLEND_WEIGHT),
        }
    }
}

/// [`JumpParams::blend`]'s default: each neighbour's continuation weighs half the texel's
/// own source (0.25 and 1 measured: the same seams within ±0.03, pf1 lower the more it
/// blends; docs/jump.md, "Texture blending").
pub const BLEND_WEIGHT: f32 = 0.5;

/// [`JumpParams::consensus`]'s default: continuations closer than this (example pixels)
/// agree (1 and 3 measured: the bunny's seam ratio, seed 1, 1.24 and 1.25 against 1.23).
pub const CONSENSUS_PX: f32 = 1.5;

/// Keeps the continuation weight only of the entries of `table` whose continuations the
/// most entries' continuations agree with (within `tau` pixels, each entry with itself);
/// nothing changes where every entry has as many agreements as the best (none, or all
/// alike). Returns whether a weight changed. `counts` is scratch.
///
/// Entries of edge neighbours are counted first; those of cross neighbours
/// ([`Entry::cross`]) only break ties between equal edge counts. Counted alike, a border
/// texel's two or three cross neighbours in a face whose texels are smaller outvoted its
/// own face's neighbours wherever two patches met near the edge, so the break between them
/// was pulled to the face's border row: straight breaks along face edges, the double
/// torus's seam ratio with bricks 1.54 at seed 6 (docs/jump.md, "Cross neighbours' votes").
/// Without any vote (continuations only) the bunny's seams rose from 1.04 to 1.21: there
/// the cross neighbours decide ties that keep the two sides of an edge together.
fn keep_consensus(table: &mut [Entry], tau: f32, counts: &mut Vec<u64>) -> bool {
    let tau2 = tau * tau;
    counts.clear();
    for e in table.iter() {
        let c = [e.a[0] + e.d[0], e.a[1] + e.d[1]];
        // (edge agreements, cross agreements), compared in that order.
        let (mut edge, mut cross) = (0u64, 0u64);
        for f in table.iter() {
            let (dx, dy) = (f.a[0] + f.d[0] - c[0], f.a[1] + f.d[1] - c[1]);
            if dx * dx + dy * dy < tau2 {
                if f.cross {
                    cross += 1;
                } else {
                    edge += 1;
                }
            }
        }
        counts.push(edge << 32 | cross);
    }
    let best = counts.iter().copied().max().unwrap_or(0);
    let mut changed = false;
    for (e, &n) in table.iter_mut().zip(counts.iter()) {
        if n < best && e.cont != 0.0 {
            e.cont = 0.0;
            changed = true;
        }
    }
    changed
}

/// Counters of a run (reported).
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct Stats {
    pub texels: u64,
    /// Texels that continued a neighbour's position.
    pub continuations: u64,
    /// Texels that took a jump.
    pub jumps: u64,
    /// Texels with synthesized neighbours but no valid entry drawn: a random valid address.
    pub restarts: u64,
    /// First texels of connected components: a random valid address.
    pub seeded: u64,
    /// Entries drawn invalid and drawn again.
    pub redraws: u64,
    /// What the jump map holds.
    pub map: super::matching::jumpmap::JumpMapStats,
    /// Seconds of the texel pass alone (no analysis, no set-up): the jump-synthesis stage.
    pub seconds: f64,
    /// `texels / seconds`.
    pub texels_per_second: f64,
    /// Texels whose value is blended ([`JumpParams::blend`]): some neighbour's
    /// continuation into them disagrees with their own source.
    pub blended: u64,
    /// Extra sources of those texels ([`super::Blend::len`]).
    pub blend_entries: u64,
    /// Seconds spent finding them (after the texel pass, not in [`Stats::seconds`]).
    pub blend_seconds: f64,
}

/// What the jump method's [`Plan`] needs from the texels alone, before any orientation
/// field: the growth order ([`growth_order`]) and the cross neighbours
/// (`cross_neighbours`). A prepared session computes it beside the field.
#[derive(Debug)]
pub struct Growth {
    /// Texel indices in synthesis order.
    pub order: Vec<u32>,
    /// Cross neighbours (CSR: starts, list).
    cross: (Vec<u32>, Vec<u32>),
}

impl Growth {
    /// Both parts side by side: the order is one serial pass, the cross neighbours'
    /// queries run in parallel beside it (they were a third of the plan's time on the
    /// bunny at N = 16, after the field, when no other work was left to share the cores
    /// with). The same result for any thread count.
    pub fn compute(edges: &EdgeGraph, layout: &TexelLayout, pos: &[Vec3]) -> Growth {
        let (order, cross) = rayon::join(
            || growth_order(edges, layout, pos),
            || cross_neighbours(layout, pos, edges),
        );
        Growth { order, cross }
    }
}

/// The region-growing order (§4.1) over the edge graph: texel indices in synthesis order,
/// by shortest-path distance from each component's seed ([`growth_order`]'s module docs).
///
/// Distances are Euclidean edge lengths summed along paths over `edges`; the queue is a
/// bucket queue of width `BUCKET` × the median edge length (Dial's algorithm), first in
/// first out inside a bucket, stale entries skipped: O(1) per texel and edge, and the same
/// order for any thread count. A texel is taken from the lowest bucket holding its current
/// distance, so the order is Dijkstra's up to ties within a bucket.
pub fn growth_order(edges: &EdgeGraph, layout: &TexelLayout, pos: &[Vec3]) -> Vec<u32> {
    let texels = layout.len();
    let width = bucket_width(edges, pos);
    let mut dist = vec![f32::INFINITY; texels];
    let mut done = vec![false; texels];
    let mut buckets: Vec<Vec<u32>> = Vec::new();
    let mut order = Vec::with_capacity(texels);
    let mut next_root = 0usize;
    let bucket = |d: f32| (d / width) as usize;
    while order.len() < texels {
        // A new component: its lowest domain's centre texel (or its lowest texel).
        while done[next_root] {
            next_root += 1;
        }
        let d = layout.domain_of(next_root);
        let (nu, nv) = layout.dims(d);
        let c = layout.index(d, nu / 2, nv / 2);
        let seed = if done[c] || dist[c].is_finite() {
            next_root
        } else {
            c
        };
        dist[seed] = 0.0;
        buckets.clear();
        buckets.push(vec![seed as u32]);
        let mut b = 0;
        while b < buckets.len() {
            let mut i = 0;
            while i < buckets[b].len() {
                let t = buckets[b][i] as usize;
                i += 1;
                if done[t] || bucket(dist[t]) != b {
                    continue; // already taken, or queued again at a lower distance
                }
                done[t] = true;
                order.push(t as u32);
                for s in edges.of(t) {
                    let s = s as usize;
                    if done[s] {
                        continue;
                    }
                    let nd = dist[t] + pos[t].distance(pos[s]);
                    if nd < dist[s] {
                        dist[s] = nd;
                        let k = bucket(nd).max(b);
                        if buckets.len() <= k {
                            buckets.resize_with(k + 1, Vec::new);
                        }
                        buckets[k].push(s as u32);
                    }
                }
            }
            buckets[b] = Vec::new();
            b += 1;
        }
    }
    order
}

/// Width of the growth queue's buckets, in median edge lengths. The order is Dijkstra's up
/// to ties within a bucket (first in, first out there); measured on the double torus, the
/// triangulated Spot, Blub and Spot with reptile scales (docs/jump.md, "Growth order"),
/// half an edge gave seam ratios 0.87–1.39 and a sixteenth 0.76–1.27, as an exact heap did.
const BUCKET: f32 = 1.0 / 16.0;

/// [`BUCKET`] times the median length of a sample of edges (every 97th texel's); positive
/// and finite.
fn bucket_width(edges: &EdgeGraph, pos: &[Vec3]) -> f32 {
    let mut lens: Vec<f32> = (0..pos.len())
        .step_by(97)
        .flat_map(|t| {
            edges
                .of(t)
                .into_iter()
                .map(move |s| pos[t].distance(pos[s as usize]))
        })
        .filter(|l| l.is_finite() && *l > 0.0)
        .collect();
    if lens.is_empty() {
        return 1.0;
    }
    let mid = lens.len() / 2;
    let m = *lens.select_nth_unstable_by(mid, f32::total_cmp).1;
    (BUCKET * m).max(f32::MIN_POSITIVE)
}

/// Edge offset d(s→t) in example pixels (see the module docs).
#[inline(always)]
fn offset(pos: &[Vec3], frames: &[[Vec3; 2]], s: usize, t: usize, inv_scale: f32) -> [f32; 2] {
    let d = pos[t] - pos[s];
    let [a1, a2] = frames[s];
    let [b1, b2] = frames[t];
    let u = (a1 + b1).normalize_or_zero();
    let v2 = a2 + b2;
    let v = (v2 - u * u.dot(v2)).normalize_or_zero();
    [d.dot(u) * inv_scale, -d.dot(v) * inv_scale]
}

/// One table entry per synthesized neighbour: its address, its continuation, the weight
/// of that continuation and of its whole jump list.
#[derive(Clone, Copy)]
struct Entry {
    a: [f32; 2],
    d: [f32; 2],
    cont: f32,
    jumps: f32,
    /// Proposed by a cross neighbour: its agreement only breaks ties in the consensus.
    cross: bool,
}

/// What the texel pass reads, laid out in synthesis order, built once per prepared mesh.
///
/// Walked in [`growth_order`], the texel pass touched each texel's edge list, position,
/// frame and its neighbours' sources at scattered places (the order jumps about the
/// texel arrays): at Spot N = 64 (1 M texels) it ran at 3.7 M texels/s, stalled on those
/// loads. Here rank k's data is the k-th entry, and its synthesized neighbours are earlier
/// ranks, mostly a growth front's width back, so the pass reads almost sequentially. The
/// order fixes which neighbours are synthesized when a texel's turn comes, so their
/// offsets and the validity margin can be computed before any synthesis.
#[derive(Debug)]
pub struct Plan {
    /// Texel indices in synthesis order ([`growth_order`]).
    pub order: Vec<u32>,
    /// How many earlier neighbours each rank has: rank k's are the `count[k]` entries of
    /// `earlier` after those of ranks 0..k. The synthesis pass walks the ranks in order and
    /// keeps the running offset, so a count of 2 B per texel does what starts of 4 B did.
    count: Vec<u16>,
    /// In the edge graph's order of the texel's edges (as the selection table lists them).
    earlier: Vec<Earlier>,
    /// Per rank, in surface units: the largest |component| of the offsets from earlier
    /// neighbours and chord to later ones (× 1/S: the validity margin in example pixels).
    reach: Vec<f32>,
    /// The entries' offsets are in surface units × 2^e, e the power of two nearest to
    /// 1 / the level's step (so about a pixel, well inside half's range); this is 2^−e.
    /// A power of two, not the step itself, so that rounding to half commutes with it: a
    /// constant scale-map factor k and `--scale S·k` give the same offsets bit for bit.
    unscale: f32,
}

/// A neighbour synthesized before the texel: its rank, whether it is a cross neighbour
/// ([`cross_neighbours`]) rather than an edge of the graph, and the edge offset d(s→t) in
/// surface units × [`Plan::unscale`]⁻¹ (about example pixels).
///
/// The offset is a half float: offsets are a pixel or two, so half's 11 bits keep them to
/// ~0.001 px, and an entry is 8 B instead of 12 — the plan's entries (~2 per texel) are
/// the largest array of jump's peak, the plan's making (issue 14 item 6). Scaled to about
/// a pixel so that tiny or huge meshes do not fall out of half's range.
#[derive(Clone, Copy, Debug)]
struct Earlier {
    /// The rank, with [`Earlier::CROSS`] set for a cross neighbour (ranks are below 2³¹:
    /// the flag costs no memory, the plan being ~2 entries a texel).
    rank_cross: u32,
    d: [half::f16; 2],
}

impl Earlier {
    const CROSS: u32 = 1 << 31;

    fn new(rank: u32, cross: bool, d: [f32; 2]) -> Self {
        debug_assert!(rank < Self::CROSS);
        Self {
            rank_cross: rank | if cross { Self::CROSS } else { 0 },
            d: d.map(half::f16::from_f32),
        }
    }

    /// The offset in surface units × [`Plan::unscale`]⁻¹.
    #[inline]
    fn d(self) -> [f32; 2] {
        self.d.map(half::f16::to_f32)
    }

    fn rank(self) -> usize {
        (self.rank_cross & !Self::CROSS) as usize
    }

    fn cross(self) -> bool {
        self.rank_cross & Self::CROSS != 0
    }
}

impl Plan {
    /// The plan of `level` in `growth`'s order. Parallel over blocks of ranks; the same for any
    /// thread count.
    pub fn new(level: &LevelTexels, growth: Growth) -> Self {
        let Growth {
            order,
            cross: (xstart, xlist),
        } = growth;
        use rayon::prelude::*;
        let n = order.len();
        assert!(
            n < Earlier::CROSS as usize,
            "{n} texels: ranks need 31 bits"
        );
        let mut rank = vec![0u32; n];
        for (k, t) in order.iter().enumerate() {
            rank[*t as usize] = k as u32;
        }
        let (pos, frames, edges) = (&level.geometry.pos, &level.frames, level.edges());
        let e = (-level.step.log2()).round().clamp(-100.0, 100.0) as i32;
        let (scale_up, unscale) = (2f32.powi(e), 2f32.powi(-e));
        let near = |t: usize| &xlist[xstart[t] as usize..xstart[t + 1] as usize];
        const CHUNK: usize = 4096;
        let mut count = vec![0u32; n];
        count
            .par_chunks_mut(CHUNK)
            .enumerate()
            .for_each(|(c, out)| {
                for (i, o) in out.iter_mut().enumerate() {
                    let t = c * CHUNK + i;
                    let k = rank[t];
                    *o = edges
                        .of(t)
                        .iter()
                        .chain(near(t))
                        .filter(|&&s| rank[s as usize] < k)
                        .count() as u32;
                }
            });
        let mut first = vec![0u32; n + 1];
        first[1..]
            .par_iter_mut()
            .zip(order.par_iter())
            .for_each(|(f, &t)| *f = count[t as usize]);
        for k in 0..n {
            first[k + 1] += first[k];
        }
        // The entries are computed in blocks of 2^BLOCK_SHIFT consecutive ranks, each block's
        // texels in storage order. Walking all texels in storage order wrote each rank's
        // entries, its reach and read its `first` at scattered places of 120 MB (bunny
        // N = 16: three cache and TLB misses a texel, the plan ~14% of a jump run's
        // samples); walking the ranks read each texel's data at a scattered place and cost
        // 2.4x as long (Spot N = 128). Within a block the writes stay in a window of a few
        // hundred KiB, and the reads sweep the growth front's band in storage order.
        // Each block sorts its ranks' texels (a slice of `order`) in a scratch vector:
        // grouping all texels by block beforehand held another 4 B a texel at the plan's
        // making, the peak of a jump run (bunny N = 16: +15 MiB).
        const BLOCK_SHIFT: u32 = 14;
        let blocks = n.div_ceil(1 << BLOCK_SHIFT);
        drop(count);
        // Left uninitialised: the blocks write every entry exactly once (checked rank by
        // rank below). Filling it first was a serial pass over ~2 entries a texel (bunny
        // N = 16: 80 MB with its page faults, ~2% of a jump run on one core).
        let total = first[n] as usize;
        let mut earlier: Vec<Earlier> = Vec::with_capacity(total);
        let mut reach = vec![0.0f32; n];
        let mut parts = Vec::with_capacity(blocks);
        {
            let mut e_rest = &mut earlier.spare_capacity_mut()[..total];
            let mut r_rest = &mut reach[..];
            for b in 0..blocks {
                let (k0, k1) = (b << BLOCK_SHIFT, ((b + 1) << BLOCK_SHIFT).min(n));
                let len = (first[k1] - first[k0]) as usize;
                let (e, er) = std::mem::take(&mut e_rest).split_at_mut(len);
                let (r, rr) = std::mem::take(&mut r_rest).split_at_mut(k1 - k0);
                parts.push((k0, e, r));
                (e_rest, r_rest) = (er, rr);
            }
        }
        parts
            .into_par_iter()
            .for_each_init(Vec::new, |texels, (k0, e, r_out)| {
                texels.clear();
                texels.extend_from_slice(&order[k0..k0 + r_out.len()]);
                texels.sort_unstable();
                let e0 = first[k0] as usize;
                for &t in texels.iter() {
                    let t = t as usize;
                    let k = rank[t];
                    let mut slot = first[k as usize] as usize - e0;
                    let mut r = 0.0f32;
                    let own = edges.of(t);
                    let graph_edges = own.len();
                    for (i, &s) in own.iter().chain(near(t)).enumerate() {
                        let (s, rs) = (s as usize, rank[s as usize]);
                        if rs < k {
                            let d = offset(pos, frames, s, t, 1.0);
                            r = r.max(d[0].abs()).max(d[1].abs());
                            let up = [d[0] * scale_up, d[1] * scale_up];
                            e[slot].write(Earlier::new(rs, i >= graph_edges, up));
                            slot += 1;
                        } else {
                            r = r.max(pos[s].distance(pos[t]));
                        }
                    }
                    // Every entry of rank k written: the count above is of exactly these
                    // neighbours (the safety of `set_len` below).
                    assert_eq!(slot, first[k as usize + 1] as usize - e0);
                    r_out[k as usize - k0] = r;
                }
            });
        // SAFETY: each block's part of `earlier` (ranks k0..k1: entries first[k0] ..
        // first[k1]) was written entry by entry, every rank's entries asserted complete
        // above, and the blocks cover 0..total; `Earlier` is `Copy`.
        unsafe { earlier.set_len(total) };
        let count = first
            .windows(2)
            .map(|w| u16::try_from(w[1] - w[0]).expect("under 2^16 earlier neighbours a texel"))
            .collect();
        Self {
            order,
            count,
            earlier,
            reach,
            unscale,
        }
    }

    /// Every rank's earlier neighbours, rank by rank.
    fn by_rank(&self) -> impl Iterator<Item = &[Earlier]> + '_ {
        let mut at = 0usize;
        self.count.iter().map(move |&c| {
            let e = &self.earlier[at..at + c as usize];
            at += c as usize;
            e
        })
    }

    /// Texels in the plan.
    pub fn len(&self) -> usize {
        self.order.len()
    }

    /// Whether the plan has no texels.
    pub fn is_empty(&self) -> bool {
        self.order.is_empty()
    }
}

/// Texels near each border texel in other domains that the edge graph does not join to it
/// (CSR: starts, list): within [`CROSS_REACH`] × its longest edge. Where several domains
/// meet (n-gon centres, extraordinary vertices, a triangle mesh's every corner) texels of
/// different domains lie a texel apart without an edge between them, so two growth fronts
/// reach them along unrelated paths and their sources disagree — on faces' borders, which
/// is what the seam ratio measures. Continuations from them too make such texels agree;
/// in the consensus their agreement only breaks ties ([`keep_consensus`]).
fn cross_neighbours(layout: &TexelLayout, pos: &[Vec3], edges: &EdgeGraph) -> (Vec<u32>, Vec<u32>) {
    use kiddo::{ImmutableKdTree, SquaredEuclidean};
    use rayon::prelude::*;
    let n = pos.len();
    let border = |t: usize| {
        let (d, x, y) = layout.coords(t);
        let (nu, nv) = layout.dims(d);
        x == 0 || y == 0 || x + 1 == nu || y + 1 == nv
    };
    let list: Vec<u32> = (0..n as u32).filter(|&t| border(t as usize)).collect();
    let pts: Vec<[f32; 3]> = list.iter().map(|&t| pos[t as usize].to_array()).collect();
    let mut start = vec![0u32; n + 1];
    let Ok(tree) = ImmutableKdTree::<f32, 3>::new_from_slice(&pts) else {
        return (start, Vec::new());
    };
    let per: Vec<Vec<u32>> = list
        .par_iter()
        .map(|&t| {
            let t = t as usize;
            let own = edges.of(t);
            let reach = own
                .iter()
                .map(|&s| pos[s as usize].distance(pos[t]))
                .fold(0.0f32, f32::max)
                * CROSS_REACH;
            let d = layout.domain_of(t);
            // Visited rather than collected: the query's own result vector was an
            // allocation per border texel (1.2 M on the bunny at N = 16) for the few
            // texels kept; the same texels either way, sorted below.
            let mut near: Vec<u32> = Vec::new();
            tree.query(&pos[t].to_array())
                .within::<SquaredEuclidean<f32>>(reach * reach)
                .unsorted()
                .visit(|r| {
                    let s = list[r.item as usize];
                    if layout.domain_of(s as usize) != d && !own.contains(&s) {
                        near.push(s);
                    }
                });
            near.sort_unstable();
            near
        })
        .collect();
    let mut out = Vec::new();
    let mut it = per.into_iter();
    for t in 0..n {
        if border(t) {
            out.extend(it.next().expect("one list per border texel"));
        }
        start[t + 1] = out.len() as u32;
    }
    (start, out)
}

/// [`cross_neighbours`]' radius in edge lengths. 1.3 reached the seam ratio's band (1.25
/// median spacings) for texels of the median size but not the diagonal pairs across a
/// border of smaller texels (√2 of their edge), where the excess of the bunny and of the
/// double torus with bricks was (docs/jump.md, "Where the bunny's excess is"); with texture
/// blending those pairs now join too. 1.8 measured against 1.3 over 24 runs (six meshes
/// and the flat grid, bricks and reptile scales, seeds 1–3 for most): the highest seam
/// ratio 1.30 → 1.17, pf4 lower in 21 and pf8 in 18 of them; time +0.1 s on the bunny,
/// memory the same (docs/jump.md, "Cross neighbours' reach").
const CROSS_REACH: f32 = 1.8;

/// Runs jump-map synthesis over `level` with its [`Plan`].
pub fn run(
    map: &JumpMap,
    level: &LevelTexels,
    plan: &Plan,
    params: &JumpParams,
    seed: u64,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> (Vec<[f32; 2]>, Option<Blend>, Stats) {
    let started = std::time::Instant::now();
    let total = level.len();
    assert_eq!(plan.len(), total);
    let inv_global = (1.0 / level.step) as f32;
    let (w, h) = (map.width as f32, map.height as f32);
    let (bx, by) = ((params.border * w).max(1e-3), (params.border * h).max(1e-3));
    let cw = params.continuation.max(0.0);
    // Sources by rank; scattered to texel order at the end.
    let mut src = vec![[f32::NAN; 2]; total];
    let mut stats = Stats {
        map: map.stats,
        ..Stats::default()
    };
    let mut table: Vec<Entry> = Vec::with_capacity(16);
    let mut counts: Vec<u64> = Vec::with_capacity(16);
    let step = (total / 64).max(1);
    for ((k, &t), earlier) in plan.order.iter().enumerate().zip(plan.by_rank()) {
        if k % step == 0 {
            progress(k, total);
        }
        let t = t as usize;
        table.clear();
        let mut sum = 0.0f32;
        // Offsets into t are measured at t's local step (the scale map's factor there).
        let inv_scale = match &level.factor {
            None => inv_global,
            Some(_) => level.inv_step_at(t),
        };
        // The chord to a texel not yet synthesized bounds both components of its projected
        // offset (validity box).
        let margin = plan.reach[k] * inv_scale;
        // unscale is a power of two: (d × unscale) × inv_scale and d × to_px round alike.
        let to_px = plan.unscale * inv_scale;
        for e in earlier {
            let a = src[e.rank()];
            let d = e.d().map(|x| x * to_px);
            let c = [a[0] + d[0], a[1] + d[1]];
            let len = (d[0] * d[0] + d[1] * d[1]).sqrt().max(0.25);
            // Border ramp on the continuation (distance from the pixel-centre rectangle).
            let ex = (c[0] - 0.5).min(w - 0.5 - c[0]);
            let ey = (c[1] - 0.5).min(h - 0.5 - c[1]);
            let ramp = (ex / bx).min(ey / by).clamp(0.0, 1.0);
            let e = Entry {
                a,
                d,
                cont: cw / len * ramp,
                jumps: map.total_at(a[0], a[1]),
                cross: e.cross(),
            };
            sum += e.cont + e.jumps;
            table.push(e);
        }
        // With two entries both agree or neither does: nothing to choose.
        if let (Some(tau), true) = (params.consensus, table.len() > 2) {
            if keep_consensus(&mut table, tau, &mut counts) {
                sum = table.iter().map(|e| e.cont + e.jumps).sum();
            }
        }
        // Valid addresses: the box of t's offsets stays inside the pixel-centre rectangle.
        let (lo_x, hi_x) = (0.5 + margin, w - 0.5 - margin);
        let (lo_y, hi_y) = (0.5 + margin, h - 0.5 - margin);
        let valid = |p: [f32; 2]| p[0] >= lo_x && p[0] <= hi_x && p[1] >= lo_y && p[1] <= hi_y;
        let random_valid = |draw: u64| -> [f32; 2] {
            let (a, b) = random2(seed, t as u64, draw);
            let (cx, cy) = ((lo_x + hi_x) * 0.5, (lo_y + hi_y) * 0.5);
            // A box wider than the example (huge offsets): its centre.
            let px = if hi_x > lo_x {
                lo_x + a * (hi_x - lo_x)
            } else {
                cx
            };
            let py = if hi_y > lo_y {
                lo_y + b * (hi_y - lo_y)
            } else {
                cy
            };
            [px, py]
        };
        stats.texels += 1;
        if table.is_empty() {
            stats.seeded += 1;
            src[k] = random_valid(0);
            continue;
        }
        let mut chosen = None;
        if sum > 0.0 {
            for draw in 0..MAX_DRAWS {
                let (r, r2) = random2(seed, t as u64, draw + 1);
                let mut x = r * sum;
                let mut pick = None;
                for e in &table {
                    if x < e.cont {
                        pick = Some(([e.a[0] + e.d[0], e.a[1] + e.d[1]], false));
                        break;
                    }
                    x -= e.cont;
                    if x < e.jumps {
                        // Which jump of this neighbour's list: a second number.
                        let mut y = r2 * e.jumps;
                        let mut dest = None;
                        map.for_each_jump(e.a[0], e.a[1], |wt, jx, jy| {
                            if dest.is_none() {
                                if y < wt {
                                    dest = Some([jx + e.d[0], jy + e.d[1]]);
                                }
                                y -= wt;
                            }
                        });
                        pick = dest.map(|p| (p, true));
                        break;
                    }
                    x -= e.jumps;
                }
                match pick {
                    Some((p, jumped)) if valid(p) => {
                        chosen = Some(p);
                        if jumped {
                            stats.jumps += 1;
                        } else {
                            stats.continuations += 1;
                        }
                        break;
                    }
                    _ => stats.redraws += 1,
                }
            }
        }
        src[k] = chosen.unwrap_or_else(|| {
            stats.restarts += 1;
            random_valid(MAX_DRAWS + 1)
        });
    }
    stats.seconds = started.elapsed().as_secs_f64();
    stats.texels_per_second = stats.texels as f64 / stats.seconds.max(1e-9);
    let mut by_texel = vec![[0.0f32; 2]; total];
    for (&t, a) in plan.order.iter().zip(&src) {
        by_texel[t as usize] = *a;
    }
    // The blend reads the sources by texel, so that the rank-ordered copy is gone before
    // its proposals are gathered (the end of this pass was the jump run's peak: 4 B a texel
    // less there, Spot N = 128).
    drop(src);
    let src = by_texel;
    let blend = params.blend.map(|weight| {
        let t0 = std::time::Instant::now();
        let b = blend(level, plan, &src, weight, [w, h]);
        stats.blended = b.texels() as u64;
        stats.blend_entries = b.len() as u64;
        stats.blend_seconds = t0.elapsed().as_secs_f64();
        b
    });
    progress(total, total);
    (src, blend, stats)
}

/// Proposals closer than this to a texel's own source (example pixels) agree with it and
/// leave its value alone: inside a continued copy, continuations along different paths
/// differ by a fraction of a pixel where the field turns, and mixing those only blurs
/// (3 px measured: the same seams within ±0.01).
pub const BLEND_AGREE_PX: f32 = 1.0;

/// A cross neighbour's (`cross_neighbours`) weight in the blend, in edge neighbours'.
/// The seam ratio's excess is between texels close in space across face borders that no
/// edge joins (docs/jump.md, "Where the bunny's excess is"); weighing the cross
/// neighbours as edges left those breaks blended less than the ones inside faces (Spot
/// with scales, seed 2: seams 1.02 → 1.23); 2 and 4 measured alike (1.20, 1.19), the
/// bunny 1.18 and 1.19 (docs/jump.md, "Texture blending").
pub const BLEND_CROSS: f32 = CROSS_UNITS as f32;

/// [`BLEND_CROSS`] as the whole number of edge weights the blend counts it as.
const CROSS_UNITS: u16 = 2;

/// The blend of a synthesized texel set ([`JumpParams::blend`], [`super::blend`]): the
/// 1-ring kernel of the texel graph and the cross neighbours. For every edge of the plan
/// (an earlier neighbour s of k, offset d), s proposes src_s + d to k and k proposes
/// src_k − d to s, with weight w (× [`BLEND_CROSS`] for a cross neighbour); the
/// receiver's own source weighs 1. A proposal more than [`BLEND_AGREE_PX`] from the
/// receiver's own source becomes an extra source with share w / (1 + the receiver's
/// summed weights); agreeing ones only count in the sum (they stand for its own value).
/// Proposals outside the example's pixel-centre rectangle are left out (a clamped
/// look-up smears the border). A break between two texels becomes a ramp over both.
///
/// The kernel applied twice (two rings: a break ramps over four texels, and texels two
/// graph steps apart — diagonal pairs across borders — mix) lowered the bunny's seams
/// further (seed 1: 1.13 against 1.18) but made 4.7x as many entries (2 a texel on the
/// bunny: +340 MB at its peak), so one ring it is (docs/jump.md, "Texture blending").
///
/// Serial over the plan in rank order, then a sort of the entries by their contents: the
/// same for any thread count. Memory while it runs: 4 B a texel for the weights and 16 B
/// per entry (entries ∝ the broken edges: 0.43 a texel on the bunny).
fn blend(
    level: &LevelTexels,
    plan: &Plan,
    by_texel: &[[f32; 2]],
    weight: f32,
    size: [f32; 2],
) -> Blend {
    let n = plan.len();
    let inv_global = (1.0 / level.step) as f32;
    let uniform = plan.unscale * inv_global;
    let to_px = |k: usize| match &level.factor {
        None => uniform,
        Some(_) => plan.unscale * level.inv_step_at(plan.order[k] as usize),
    };
    let inside =
        |p: [f32; 2]| p[0] >= 0.5 && p[0] <= size[0] - 0.5 && p[1] >= 0.5 && p[1] <= size[1] - 0.5;
    let agree2 = BLEND_AGREE_PX * BLEND_AGREE_PX;
    // The source of rank k.
    let src = |k: usize| by_texel[plan.order[k] as usize];
    // Per rank: the weight of the proposals it receives, in units of `weight` (an edge
    // neighbour's one, a cross neighbour's [`CROSS_UNITS`]): 2 B a texel where an f32 sum
    // took 4 (the blend is the jump run's peak), and the same number in any order. For
    // the default weight (½) units × weight is the f32 sum bit for bit.
    let mut received = vec![0u16; n];
    // Room for one entry a texel (~2x what breaks make) without moving it while it grows;
    // pages never written are never resident.
    let mut entries: Vec<(u32, [f32; 2], f32)> = Vec::with_capacity(n);
    // Offers `p` to rank `r` with weight `w`: counted in `received[r]`, kept when it
    // disagrees with r's own source.
    let mut offer = |received: &mut [u16], r: usize, p: [f32; 2], units: u16| {
        if !inside(p) {
            return;
        }
        received[r] = received[r].saturating_add(units);
        let w = units as f32 * weight;
        let a_r = src(r);
        let (dx, dy) = (p[0] - a_r[0], p[1] - a_r[1]);
        if dx * dx + dy * dy > agree2 {
            entries.push((r as u32, p, w));
        }
    };
    for (k, earlier) in plan.by_rank().enumerate() {
        let (a_k, to_k) = (src(k), to_px(k));
        for e in earlier {
            let s = e.rank();
            let (a_s, d, to_s) = (src(s), e.d(), to_px(s));
            let w = if e.cross() { CROSS_UNITS } else { 1 };
            // s → k: a_s + d at k's step; k → s: a_k − d at s's step.
            offer(
                &mut received,
                k,
                [a_s[0] + d[0] * to_k, a_s[1] + d[1] * to_k],
                w,
            );
            offer(
                &mut received,
                s,
                [a_k[0] - d[0] * to_s, a_k[1] - d[1] * to_s],
                w,
            );
        }
    }
    for e in &mut entries {
        let r = e.0 as usize;
        e.2 /= 1.0 + received[r] as f32 * weight;
        e.0 = plan.order[r];
    }
    drop(received);
    Blend::from_entries(entries)
}

#[cfg(test)]
mod tests {
    use super::*;
    use subdiv::{ControlMesh, Surface};

    #[test]
    fn the_consensus_keeps_only_the_continuations_most_neighbours_agree_on() {
        let entry = |a: [f32; 2], d: [f32; 2]| Entry {
            a,
            d,
            cont: 1.0,
            jumps: 0.25,
            cross: false,
        };
        // Two neighbours continue to about (10, 10), a third to (40, 10).
        let mut table = vec![
            entry([9.0, 10.0], [1.0, 0.0]),
            entry([10.0, 9.2], [0.0, 1.0]),
            entry([39.0, 10.0], [1.0, 0.0]),
        ];
        let mut counts = Vec::new();
        assert!(keep_consensus(&mut table, CONSENSUS_PX, &mut counts));
        let cont: Vec<f32> = table.iter().map(|e| e.cont).collect();
        assert_eq!(
            cont,
            [1.0, 1.0, 0.0],
            "the lone front loses its continuation"
        );
        assert!(
            table.iter().all(|e| e.jumps == 0.25),
            "jumps keep their weight"
        );
        // No two agree: the table is 002's.
        let mut table = vec![
            entry([0.0, 0.0], [1.0, 0.0]),
            entry([20.0, 0.0], [1.0, 0.0]),
        ];
        assert!(!keep_consensus(&mut table, CONSENSUS_PX, &mut counts));
        assert!(table.iter().all(|e| e.cont == 1.0));
    }

    /// Cross neighbours never outvote edge neighbours; they decide between equal counts.
    #[test]
    fn cross_neighbours_only_break_ties_in_the_consensus() {
        let entry = |a: [f32; 2], cross: bool| Entry {
            a,
            d: [1.0, 0.0],
            cont: 1.0,
            jumps: 0.25,
            cross,
        };
        let mut counts = Vec::new();
        let cont = |t: &[Entry]| t.iter().map(|e| e.cont).collect::<Vec<_>>();
        // Two edge neighbours of the texel's own face agree (about (10, 10)); across the
        // edge one edge neighbour and two cross neighbours agree on another place.
        let mut table = vec![
            entry([9.0, 10.0], false),
            entry([9.3, 10.2], false),
            entry([39.0, 10.0], false),
            entry([39.2, 10.0], true),
            entry([38.9, 9.9], true),
        ];
        assert!(keep_consensus(&mut table, CONSENSUS_PX, &mut counts));
        assert_eq!(
            cont(&table),
            [1.0, 1.0, 0.0, 0.0, 0.0],
            "two edges beat one and two crosses"
        );
        // One edge neighbour each side: the cross neighbours decide.
        let mut table = vec![
            entry([9.0, 10.0], false),
            entry([39.0, 10.0], false),
            entry([39.2, 10.0], true),
        ];
        assert!(keep_consensus(&mut table, CONSENSUS_PX, &mut counts));
        assert_eq!(cont(&table), [0.0, 1.0, 1.0]);
    }

    /// A flat grid (4x4 faces, N = 8, one example pixel per texel) with its plan, and
    /// sources by rank continued from the first texel along the plan: a continued copy.
    fn continued_copy() -> (LevelTexels, Plan, Vec<[f32; 2]>) {
        let surface = Surface::new(ControlMesh::grid(4));
        let field =
            crate::field::OrientationField::compute(&surface, &crate::field::Orientation::Auto)
                .unwrap();
        let level = LevelTexels::new(&surface, &field, 8, 0.125);
        let growth = Growth::compute(level.edges(), level.layout(), &level.geometry.pos);
        let plan = Plan::new(&level, growth);
        let to_px = plan.unscale * (1.0 / level.step) as f32;
        let mut src = vec![[40.0f32, 64.0]; plan.len()];
        for (k, earlier) in plan.by_rank().enumerate().skip(1) {
            let e = earlier[0];
            let (a, d) = (src[e.rank()], e.d());
            src[k] = [a[0] + d[0] * to_px, a[1] + d[1] * to_px];
        }
        (level, plan, src)
    }

    /// 256² grey example: 0 left of column 90, 1 from it on.
    fn step_example() -> crate::example::Example {
        let rgb = (0..256 * 256)
            .map(|i| if i % 256 >= 90 { [1.0; 3] } else { [0.0; 3] })
            .collect();
        crate::example::Example::from_linear(256, 256, rgb)
    }

    fn by_texel(plan: &Plan, src: &[[f32; 2]]) -> Vec<[f32; 2]> {
        let mut out = vec![[0.0f32; 2]; src.len()];
        for (&t, a) in plan.order.iter().zip(src) {
            out[t as usize] = *a;
        }
        out
    }

    /// Inside a continued copy every proposal agrees: no entry, and the face maps are
    /// those without blending, bit for bit.
    #[test]
    fn blending_leaves_a_continued_copy_exactly_as_looked_up() {
        let (level, plan, src) = continued_copy();
        let b = blend(&level, &plan, &by_texel(&plan, &src), 0.5, [256.0, 256.0]);
        assert!(b.is_empty(), "{} entries in a continued copy", b.len());
        let ex = step_example();
        let s = by_texel(&plan, &src);
        let layout = &level.geometry.layout;
        let plain = crate::synth::face_maps(&ex, &s, layout);
        let blended = crate::synth::face_maps_blended(&ex, &s, Some(&b), layout);
        assert_eq!(plain.channels, blended.channels);
    }

    /// Across a break (the right half's sources moved 100 px) the values ramp over the
    /// two texels beside it — 1/6 and 5/6 where one of four neighbours is across — and
    /// every other texel, and every source.u/v, stays as it was.
    #[test]
    fn blending_ramps_values_across_a_break() {
        let (level, plan, mut src) = continued_copy();
        let pos = &level.geometry.pos;
        // The break runs through the middle of a column of faces, where texels have no
        // cross neighbours (those are at faces' borders), so each texel's proposals are
        // its four edge neighbours'.
        let right = |t: usize| pos[t].x > 1.5;
        for (k, &t) in plan.order.iter().enumerate() {
            if right(t as usize) {
                src[k][0] += 100.0;
            }
        }
        let b = blend(&level, &plan, &by_texel(&plan, &src), 0.5, [256.0, 256.0]);
        assert!(!b.is_empty());
        let ex = step_example();
        let s = by_texel(&plan, &src);
        let layout = &level.geometry.layout;
        let plain = crate::synth::face_maps(&ex, &s, layout);
        let blended = crate::synth::face_maps_blended(&ex, &s, Some(&b), layout);
        let (r0, r1) = (plain.channel("R").unwrap(), blended.channel("R").unwrap());
        let edges = level.edges();
        // Texels on a face's border also have diagonal cross neighbours across it, which
        // propose too (at twice an edge's weight): their shares are checked only for being
        // a mix, the others' exactly.
        let (xs, xl) = cross_neighbours(level.layout(), &level.geometry.pos, edges);
        let cross = |t: usize| &xl[xs[t] as usize..xs[t + 1] as usize];
        let mut ramped = 0;
        for t in 0..level.len() {
            let want = if right(t) { 1.0 } else { 0.0 };
            assert_eq!(r0[t], want, "texel {t}: the break is between 0 and 1");
            let nb = edges.of(t);
            let across = nb
                .iter()
                .filter(|&&n| right(n as usize) != right(t))
                .count();
            let cross_across = cross(t).iter().any(|&n| right(n as usize) != right(t));
            if across == 0 && !cross_across {
                assert_eq!(
                    r1[t].to_bits(),
                    r0[t].to_bits(),
                    "texel {t} away from the break"
                );
                continue;
            }
            ramped += 1;
            if !cross(t).is_empty() {
                assert!(
                    r1[t] > 0.0 && r1[t] < 1.0,
                    "texel {t}: {} is not a mix",
                    r1[t]
                );
                continue;
            }
            // Its own source weighs 1, each of its edge neighbours 0.5: 0.5 across /
            // (1 + 0.5 · count).
            let share = across as f32 * 0.5 / (1.0 + 0.5 * nb.len() as f32);
            let expect = if right(t) { 1.0 - share } else { share };
            assert!(
                (r1[t] - expect).abs() < 1e-5,
                "texel {t}: {} vs {expect}",
                r1[t]
            );
        }
        assert!(ramped >= 2 * 32, "{ramped} texels beside the break");
        for c in ["source.u", "source.v"] {
            assert_eq!(plain.channel(c), blended.channel(c));
        }
    }

    /// The blend is the same for any thread count (a serial pass and a stable sort).
    #[test]
    fn blending_is_thread_count_independent() {
        let (level, plan, mut src) = continued_copy();
        for (k, a) in src.iter_mut().enumerate() {
            if k % 7 == 3 {
                a[1] += 30.0;
            }
        }
        let run = |threads| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| blend(&level, &plan, &by_texel(&plan, &src), 0.5, [256.0, 256.0]))
        };
        let one = run(1);
        assert!(one.len() > 100);
        assert_eq!(one, run(2));
    }

    #[test]
    fn growth_order_visits_every_texel_once_and_grows_from_a_seed() {
        let s = Surface::new(ControlMesh::grid(3));
        let n = 6;
        let g = crate::texels::TexelGeometry::compute(&s, n);
        let e = EdgeGraph::build(&s, &g);
        let order = growth_order(&e, &g.layout, &g.pos);
        let mut seen = vec![false; g.len()];
        for &t in &order {
            assert!(!seen[t as usize]);
            seen[t as usize] = true;
        }
        assert!(seen.iter().all(|&b| b));
        // Every texel after the first touches an earlier one (one component).
        let mut done = vec![false; g.len()];
        for (k, &t) in order.iter().enumerate() {
            if k > 0 {
                assert!(e.of(t as usize).iter().any(|&s| done[s as usize]));
            }
            done[t as usize] = true;
        }
    }

    /// The plan holds, rank by rank, exactly what walking the order would find: the
    /// neighbours synthesized before (in edge order, then the near texels of other
    /// domains, with their offsets) and the margin — on a flat grid and on a mesh with a
    /// triangle and a pentagon, whose sub-faces meet around their centres.
    #[test]
    fn plan_lists_each_texels_earlier_neighbours_in_edge_order() {
        let obj = "v 0 0 0\nv 1 0 0\nv 2 0 0\nv 0 1 0\nv 1 1 0\nv 2 1 0\nv 1.5 1.8 0\n\
                   f 1 2 5 4\nf 2 3 6 5\nf 4 5 7\nf 5 6 7\n";
        let ngons = ControlMesh::parse_obj(obj).unwrap();
        // The last: 36,864 texels, three blocks of ranks (the last one partial).
        for (mesh, n) in [
            (ControlMesh::grid(3), 6),
            (ngons, 6),
            (ControlMesh::grid(8), 24),
        ] {
            let surface = Surface::new(mesh);
            let field =
                crate::field::OrientationField::compute(&surface, &crate::field::Orientation::Auto)
                    .unwrap();
            let level = LevelTexels::new(&surface, &field, n, 0.01);
            assert!(n == 6 || level.len() > 2 << 14);
            let e = level.edges();
            let (xs, xl) = cross_neighbours(level.layout(), &level.geometry.pos, e);
            let growth = Growth::compute(e, level.layout(), &level.geometry.pos);
            assert_eq!((&xs, &xl), (&growth.cross.0, &growth.cross.1));
            let order = growth_order(e, level.layout(), &level.geometry.pos);
            assert_eq!(order, growth.order);
            let plan = Plan::new(&level, growth);
            let lists: Vec<&[Earlier]> = plan.by_rank().collect();
            let (pos, frames) = (&level.geometry.pos, &level.frames);
            let ex = (-level.step.log2()).round() as i32;
            let mut done = vec![false; level.len()];
            let mut rank = vec![0; level.len()];
            for (k, &t) in order.iter().enumerate() {
                rank[t as usize] = k;
            }
            for (k, &t) in order.iter().enumerate() {
                let t = t as usize;
                let mut want = Vec::new();
                let mut reach = 0.0f32;
                let near = &xl[xs[t] as usize..xs[t + 1] as usize];
                for &s in e.of(t).iter().chain(near) {
                    let s = s as usize;
                    if done[s] {
                        let d = offset(pos, frames, s, t, 1.0);
                        reach = reach.max(d[0].abs()).max(d[1].abs());
                        // Stored × 2^e, as half floats.
                        let px = [d[0] * 2f32.powi(ex), d[1] * 2f32.powi(ex)]
                            .map(|x| half::f16::from_f32(x).to_f32());
                        want.push((rank[s], px));
                    } else {
                        reach = reach.max(pos[s].distance(pos[t]));
                    }
                }
                let got: Vec<_> = lists[k].iter().map(|x| (x.rank(), x.d())).collect();
                assert_eq!(got, want, "rank {k}");
                assert_eq!(plan.reach[k].to_bits(), reach.to_bits());
                done[t] = true;
            }
        }
    }

    /// Near texels across borders: other domains only, never an edge's other end; none on
    /// a flat grid (its diagonals are √2 texels away), some around the triangles' centres.
    #[test]
    fn cross_neighbours_join_nearby_texels_of_other_domains_only() {
        let obj = "v 0 0 0\nv 1 0 0\nv 0.5 0.9 0\nv 1.5 0.9 0\nv -0.5 0.9 0\n\
                   f 1 2 3\nf 2 4 3\nf 1 3 5\n";
        let field_of = |s: &Surface| {
            crate::field::OrientationField::compute(s, &crate::field::Orientation::Auto).unwrap()
        };
        let grid = Surface::new(ControlMesh::grid(3));
        let level = LevelTexels::new(&grid, &field_of(&grid), 8, 0.01);
        let cross_of = |l: &LevelTexels| cross_neighbours(l.layout(), &l.geometry.pos, l.edges());
        // On a flat grid the only texels of other domains within reach are the diagonal
        // ones across a border (√2 texels away; the reach is 1.8 edges).
        let (start, list) = cross_of(&level);
        assert!(!list.is_empty());
        for t in 0..level.len() {
            for &s in &list[start[t] as usize..start[t + 1] as usize] {
                let d = level.geometry.pos[s as usize] - level.geometry.pos[t];
                assert!(
                    d.x.abs() > 1e-3 && d.y.abs() > 1e-3,
                    "{t} -> {s}: {d} is not diagonal"
                );
            }
        }
        let tris = Surface::new(ControlMesh::parse_obj(obj).unwrap());
        let level = LevelTexels::new(&tris, &field_of(&tris), 8, 0.01);
        let (start, list) = cross_of(&level);
        assert!(!list.is_empty(), "none around the triangles' centres");
        let layout = level.layout();
        for t in 0..level.len() {
            for &s in &list[start[t] as usize..start[t + 1] as usize] {
                assert_ne!(layout.domain_of(s as usize), layout.domain_of(t));
                assert!(!level.edges().of(t).contains(&s));
            }
        }
        // The lists are those of the collected query (the form before visiting): the
        // same texels, within CROSS_REACH of each border texel by kiddo's own rule.
        let want = {
            use kiddo::{ImmutableKdTree, SquaredEuclidean};
            let (pos, edges) = (&level.geometry.pos, level.edges());
            let border = |t: usize| {
                let (d, x, y) = layout.coords(t);
                let (nu, nv) = layout.dims(d);
                x == 0 || y == 0 || x + 1 == nu || y + 1 == nv
            };
            let border_list: Vec<u32> = (0..level.len() as u32)
                .filter(|&t| border(t as usize))
                .collect();
            let pts: Vec<[f32; 3]> = border_list
                .iter()
                .map(|&t| pos[t as usize].to_array())
                .collect();
            let tree = ImmutableKdTree::<f32, 3>::new_from_slice(&pts).unwrap();
            let mut all = Vec::new();
            for &t in &border_list {
                let t = t as usize;
                let own = edges.of(t);
                let reach = own
                    .iter()
                    .map(|&s| pos[s as usize].distance(pos[t]))
                    .fold(0.0f32, f32::max)
                    * CROSS_REACH;
                let mut near: Vec<u32> = tree
                    .query(&pos[t].to_array())
                    .within::<SquaredEuclidean<f32>>(reach * reach)
                    .unsorted()
                    .execute()
                    .iter()
                    .map(|r| border_list[r.item as usize])
                    .filter(|&s| {
                        layout.domain_of(s as usize) != layout.domain_of(t) && !own.contains(&s)
                    })
                    .collect();
                near.sort_unstable();
                all.push((t, near));
            }
            all
        };
        for (t, near) in want {
            assert_eq!(
                &list[start[t] as usize..start[t + 1] as usize],
                &near[..],
                "texel {t}"
            );
        }
    }
}
