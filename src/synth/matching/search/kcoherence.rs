//! k-coherence search (paper 003, Tong et al. 2002, §5.2).
//!
//! Precompute, for every example pixel, its `k` nearest example pixels by neighbourhood
//! distance (itself first). To synthesize a target sample, every already-synthesized
//! neighbour `q` proposes the *forward-shifted* position of its source, `source(q) + (p -
//! q)` — where the example patch `q` was copied from continues to `p` (Ashikhmin's
//! coherence) — and the candidate set is the union of the `k`-lists of those positions.
//! With `k = 1` this is Ashikhmin's algorithm; the paper reports `k = 11` as "practically
//! the same as the full search". The candidates are re-ranked with the exact weighted
//! distance, so the search is as precise as the candidate set is good.
//!
//! **Precomputation.** For levels of at most [`KParams::exact_max`] pixels (64x64, as in
//! 003) the lists are exact: every valid pixel against every other, with early exit
//! once a partial distance exceeds the current k-th best. Larger levels use 003's two-level
//! scheme: the `m = 100` nearest of the *parent* pixel in the next coarser level (lists
//! computed the same way, recursively) each contribute their four children, and the
//! `k` nearest among those `≤ 4m` candidates (plus the pixel itself) are kept. Lists of a
//! level that serves as the coarse level for another are `m` long; synthesis uses the first
//! `k`. The coarse level's lists are built with its own neighbourhood distance, which is
//! what 003 does ("compute m initial candidates for p(a/2, b/2) in the low-resolution
//! version"). Fine pixels whose parent lies outside the coarse level's valid region use
//! the nearest valid parent.

use super::pca::Pca;
use super::{Features, Prepared, TopN};
use rayon::prelude::*;

/// k-coherence settings.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct KParams {
    /// Neighbours per list used for candidates (003: 11).
    pub k: usize,
    /// Coarse candidates per parent in the two-level precomputation (003: 100).
    pub m: usize,
    /// Levels with at most this many pixels get exact lists (003: 64x64).
    pub exact_max: usize,
    /// Side of the window of synthesized neighbours that propose candidates (odd).
    pub window: usize,
}

impl Default for KParams {
    /// `k = 11`, `m = 100`, exact up to 64x64 as in 003; a 3x3 proposing window: as good
    /// as 5x5 in patch fidelity at half the candidates (`docs/multiscale.md`).
    fn default() -> Self {
        Self {
            k: 11,
            m: 100,
            exact_max: 64 * 64,
            window: 3,
        }
    }
}

/// Projection dimension used to prune the exact list computation.
pub const PRUNE_DIMS: usize = 16;

/// Sorted list of the best `cap` (index, distance) pairs, ties by index.
struct TopK {
    cap: usize,
    items: Vec<(f32, u32)>,
}

impl TopK {
    fn new(cap: usize) -> Self {
        Self {
            cap,
            items: Vec::with_capacity(cap + 1),
        }
    }
    #[inline]
    fn bound(&self) -> f32 {
        if self.items.len() < self.cap {
            f32::INFINITY
        } else {
            self.items[self.cap - 1].0
        }
    }
    #[inline]
    fn push(&mut self, d: f32, i: u32) {
        if self.items.len() == self.cap {
            let last = self.items[self.cap - 1];
            if (d, i) >= last {
                return;
            }
            self.items.pop();
        }
        let pos = self.items.partition_point(|&(dd, ii)| (dd, ii) < (d, i));
        self.items.insert(pos, (d, i));
    }
}

/// Per-pixel nearest-neighbour lists of one example level.
#[derive(Clone, Debug)]
pub struct KnnLists {
    /// Entries per list (`k` or `m`).
    pub len: usize,
    /// `features.len() x len` feature indices, nearest first (the pixel itself first).
    pub lists: Vec<u32>,
    /// True when computed by exhaustive search.
    pub exact: bool,
}

impl KnnLists {
    /// Exhaustive lists of length `len` (capped at the number of pixels).
    ///
    /// Exact, but pruned: distances between PCA projections (onto [`PRUNE_DIMS`]
    /// orthonormal directions) are lower bounds of the true distances, because projecting
    /// onto a subspace never lengthens a vector; only pairs whose bound beats the current
    /// `len`-th best are measured in full.
    pub fn exact(f: &Features, len: usize) -> Self {
        Self::exact_pruned(f, len, &Pruning::fit(f))
    }

    /// [`KnnLists::exact`] pruned along given directions (the same lists).
    pub fn exact_pruned(f: &Features, len: usize, pruning: &Pruning) -> Self {
        let n = f.len();
        let len = len.min(n);
        let dim = f.dim();
        let proj = pruning.project(f);
        let mut lists = vec![0u32; n * len];
        lists.par_chunks_mut(len).enumerate().for_each_init(
            || (Vec::<(f32, u32)>::new(), vec![0.0f32; dim]),
            |(lbs, qi), (i, out)| {
                f.vector_into(i, qi);
                let pi = proj.row(i);
                lbs.clear();
                for (j, pj) in proj.rows.chunks_exact(PRUNE_DIMS).enumerate() {
                    if j != i {
                        lbs.push((lower_bound(pi, pj), j as u32));
                    }
                }
                let mut top = TopK::new(len);
                // The pixel itself first (distance 0 and lowest possible key).
                top.push(-1.0, i as u32);
                measure_pruned(f, qi, lbs, &proj, &mut top);
                for (o, &(_, idx)) in out.iter_mut().zip(&top.items) {
                    *o = idx;
                }
            },
        );
        Self {
            len,
            lists,
            exact: true,
        }
    }

    /// Two-level lists of length `len` for `fine` from the lists of the next coarser level
    /// (`coarse_lists` over `coarse`; its lists' length is the `m` of 003).
    ///
    /// Pruned as [`KnnLists::exact`] is, with the same result: every fine feature is
    /// projected once onto [`PRUNE_DIMS`] principal directions (a lower bound of every
    /// distance), the `len` candidates with the lowest bounds are measured first, and the
    /// rest, nearest bound first, only while their bound beats the current `len`-th best.
    /// The directions must fit `fine` (its own level's appearance space) to prune much.
    /// Why: the full distance
    /// (the 9x9 + 5x5 neighbourhood, ~850 numbers) of each of the ≤ 4m = 400 candidates was
    /// most of the analysis of a large example (issue 14: a 512² example's lists took
    /// 24 s of a 44 s first run); most candidates are far, and 16 numbers say so.
    pub fn two_level(
        fine: &Features,
        coarse: &Features,
        coarse_lists: &KnnLists,
        len: usize,
    ) -> Self {
        Self::two_level_pruned(fine, coarse, coarse_lists, len, &Pruning::fit(fine))
    }

    /// [`KnnLists::two_level`] pruned along given directions (the same lists).
    pub fn two_level_pruned(
        fine: &Features,
        coarse: &Features,
        coarse_lists: &KnnLists,
        len: usize,
        pruning: &Pruning,
    ) -> Self {
        let n = fine.len();
        let len = len.min(n);
        let dim = fine.dim();
        let proj = pruning.project(fine);
        let mut lists = vec![0u32; n * len];
        let cols = fine.cols;
        let one = |s: &mut Candidates, i: usize, out: &mut [u32]| {
            let (x, y) = fine.pixel(i as u32);
            // Parent pixel centre in coarse pixels: (x + 0.5) / 2.
            let parent = coarse.nearest_index((x as f32 + 0.5) / 2.0, (y as f32 + 0.5) / 2.0);
            if parent != s.parent {
                // The children of the parent's list's distinct entries (distinct
                // coarse pixels have distinct children: no duplicates), shared by the
                // (up to four) fine pixels of one parent that follow each other.
                s.parents.clear();
                s.parents
                    .extend_from_slice(coarse_lists.list(parent as usize));
                s.parents.sort_unstable();
                s.parents.dedup();
                s.children.clear();
                for &c in &s.parents {
                    let (cx, cy) = coarse.pixel(c);
                    for (a, b) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                        let (fx, fy) = (2 * cx + a, 2 * cy + b);
                        if fx >= fine.margin
                            && fy >= fine.margin
                            && fx < fine.margin + fine.cols
                            && fy < fine.margin + fine.rows
                        {
                            s.children
                                .push(((fy - fine.margin) * fine.cols + fx - fine.margin) as u32);
                        }
                    }
                }
                // Their projections side by side: read scattered once per parent, then
                // in order by each of its pixels.
                s.rows.clear();
                for &j in &s.children {
                    s.rows.extend_from_slice(proj.row(j as usize));
                }
                s.parent = parent;
            }
            let pi = proj.row(i);
            s.lbs.clear();
            for (&j, pj) in s.children.iter().zip(s.rows.chunks_exact(PRUNE_DIMS)) {
                if j as usize != i {
                    s.lbs.push((lower_bound(pi, pj), j));
                }
            }
            fine.vector_into(i, &mut s.qi);
            let mut top = TopK::new(len);
            top.push(-1.0, i as u32);
            measure_pruned(fine, &s.qi, &mut s.lbs, &proj, &mut top);
            // Too few candidates (tiny levels): pad with the pixel itself; duplicates
            // are removed when candidate sets are assembled.
            for (t, o) in out.iter_mut().enumerate() {
                *o = top.items.get(t).map_or(i as u32, |&(_, idx)| idx);
            }
        };
        // Two rows at a time, column by column: the (up to four) pixels of one parent,
        // which share their candidates, follow each other, so the candidates' pixels
        // read for the first are still in cache for the others.
        lists
            .par_chunks_mut(2 * cols * len)
            .enumerate()
            .for_each_init(
                || Candidates {
                    parent: u32::MAX,
                    parents: Vec::new(),
                    children: Vec::new(),
                    rows: Vec::new(),
                    lbs: Vec::new(),
                    qi: vec![0.0f32; dim],
                },
                |s, (r, rows)| {
                    let nrows = rows.len() / (cols * len);
                    for x in 0..cols {
                        for dy in 0..nrows {
                            let at = (dy * cols + x) * len;
                            one(s, (2 * r + dy) * cols + x, &mut rows[at..at + len]);
                        }
                    }
                },
            );
        Self {
            len,
            lists,
            exact: false,
        }
    }

    /// The list of feature `i`.
    #[inline]
    pub fn list(&self, i: usize) -> &[u32] {
        &self.lists[i * self.len..(i + 1) * self.len]
    }
}

/// Per-thread state of [`KnnLists::two_level_pruned`]: the candidates of the last parent.
struct Candidates {
    parent: u32,
    parents: Vec<u32>,
    children: Vec<u32>,
    /// The children's projected rows, in the children's order.
    rows: Vec<f32>,
    lbs: Vec<(f32, u32)>,
    qi: Vec<f32>,
}

/// The directions the list computations prune with: the first [`PRUNE_DIMS`] principal
/// directions of some level's features. Squared distances between projections are lower
/// bounds of the squared feature distances for *any* orthonormal directions (projecting
/// onto a subspace never lengthens a vector), so the lists do not depend on which
/// features the directions were fitted to — only how much is pruned does, and that is a
/// great deal: fitted to the level's own features, 16 directions of a 512² brick's
/// finest level (in appearance space) keep 99% of its variance and leave ~29 of ~400
/// two-level candidates to be measured; fitted to another level's (each level has an
/// appearance space of its own) they keep almost nothing and leave ~387
/// ([`super::model`] fits one per level).
pub struct Pruning {
    pca: Pca,
    /// Bound on how far the fitted rows are from orthonormal: ‖B x‖² ≤ (1 + ortho)‖x‖².
    ortho: f64,
}

impl Pruning {
    /// Fitted to `f`'s features.
    pub fn fit(f: &Features) -> Self {
        let dim = f.dim();
        let pca = Pca::fit(&f.pca_rows(), dim, PRUNE_DIMS.min(dim));
        // ‖B Bᵀ − I‖_F bounds the spread of B's singular values around 1.
        let (k, b) = (pca.k, &pca.basis);
        let mut dev = 0.0f64;
        for r in 0..k {
            for s in 0..k {
                let dot: f64 = (0..dim)
                    .map(|t| b[r * dim + t] as f64 * b[s * dim + t] as f64)
                    .sum();
                let e = dot - if r == s { 1.0 } else { 0.0 };
                dev += e * e;
            }
        }
        Self {
            pca,
            ortho: dev.sqrt(),
        }
    }

    /// Dimension of the features these directions fit.
    pub fn dim(&self) -> usize {
        self.pca.dim
    }

    /// Every feature of `f` projected, in rows of [`PRUNE_DIMS`] (zero-padded), with the
    /// slack its rounding calls for.
    fn project(&self, f: &Features) -> Projection {
        let dim = f.dim();
        assert_eq!(dim, self.pca.dim, "pruning directions of another shape");
        let pd = self.pca.k;
        let mut rows = vec![0.0f32; f.len() * PRUNE_DIMS];
        let mut norms = vec![0.0f32; f.len()];
        rows.par_chunks_mut(PRUNE_DIMS)
            .zip(norms.par_iter_mut())
            .enumerate()
            .for_each_init(
                || (vec![0.0f32; dim], vec![0.0f32; dim]),
                |(v, c), (i, (o, norm))| {
                    f.vector_into(i, v);
                    project_centred(&self.pca, v, c, &mut o[..pd], norm);
                },
            );
        // Each projected coordinate is a sum of `dim` products in 8 lanes: its rounding
        // error is at most γ·Σ|b||x − μ| ≤ γ‖x − μ‖ (unit rows), with γ = n·u for the
        // n ≈ dim / 8 + 10 roundings along the longest path (centring, products, lane
        // sums, the sum of the lanes), doubled for safety; the rows' error at most √pd
        // times that.
        let u = f32::EPSILON as f64 / 2.0;
        let gamma = 2.0 * (dim as f64 / 8.0 + 10.0) * u;
        let max_norm = norms.iter().fold(0.0f32, |a, &b| a.max(b)) as f64;
        // The norms themselves are rounded (relative error far below 1%).
        let row_err = gamma * (pd as f64).sqrt() * max_norm * 1.01;
        Projection {
            rows,
            slack: 2.0 * row_err,
            scale: 1.0 + self.ortho + 1e-4,
        }
    }
}

/// `v − μ` into `c`, its norm into `norm`, and its coordinates along the rows of `pca` into
/// `out` (8 lanes per row, like [`Pca::project`]).
#[inline]
fn project_centred(pca: &Pca, v: &[f32], c: &mut [f32], out: &mut [f32], norm: &mut f32) {
    let mut n2 = [0.0f32; 8];
    for ((cc, vv), mm) in c
        .chunks_exact_mut(8)
        .zip(v.chunks_exact(8))
        .zip(pca.mean.chunks_exact(8))
    {
        for t in 0..8 {
            cc[t] = vv[t] - mm[t];
            n2[t] += cc[t] * cc[t];
        }
    }
    let r = v.len() / 8 * 8;
    let mut n2s: f32 = n2.iter().sum();
    for t in r..v.len() {
        c[t] = v[t] - pca.mean[t];
        n2s += c[t] * c[t];
    }
    *norm = n2s.sqrt();
    for (j, o) in out.iter_mut().enumerate() {
        let b = &pca.basis[j * pca.dim..(j + 1) * pca.dim];
        let mut acc = [0.0f32; 8];
        for (bb, cc) in b.chunks_exact(8).zip(c.chunks_exact(8)) {
            for t in 0..8 {
                acc[t] += bb[t] * cc[t];
            }
        }
        let mut s: f32 = acc.iter().sum();
        for t in r..v.len() {
            s += b[t] * c[t];
        }
        *o = s;
    }
}

/// The features of one level projected for pruning.
struct Projection {
    /// [`PRUNE_DIMS`] coordinates per feature.
    rows: Vec<f32>,
    /// Bound on the rounding error of the distance between two rows (in distance units,
    /// not squared).
    slack: f64,
    /// Factor covering the directions' deviation from orthonormality and the rounding of
    /// squared sums (bounds and distances), with a wide margin.
    scale: f64,
}

impl Projection {
    #[inline]
    fn row(&self, i: usize) -> &[f32] {
        &self.rows[i * PRUNE_DIMS..(i + 1) * PRUNE_DIMS]
    }

    /// The largest lower bound (as [`lower_bound`] computes it) a candidate whose full
    /// distance is at most `bound` can have: candidates above it are certainly farther.
    #[inline]
    fn cutoff(&self, bound: f32) -> f32 {
        if bound.is_infinite() {
            return f32::INFINITY;
        }
        let r = (bound.max(0.0) as f64).sqrt() + self.slack;
        (r * r * self.scale) as f32
    }
}

/// Squared distance between two projected rows (8 lanes, then their sum): a lower bound
/// of the squared feature distance up to [`Projection::cutoff`]'s margins.
#[inline]
fn lower_bound(a: &[f32], b: &[f32]) -> f32 {
    let mut acc = [0.0f32; 8];
    for (x, y) in a.chunks_exact(8).zip(b.chunks_exact(8)) {
        for t in 0..8 {
            let d = x[t] - y[t];
            acc[t] += d * d;
        }
    }
    acc.iter().sum()
}

/// Measures the candidates `lbs` ((lower bound, feature)) against `qi` into `top`: the
/// `top.cap` with the lowest bounds first, so that the `cap`-th best distance is known
/// early, then — nearest bound first — those the bound does not rule out, stopping at the
/// first it does. The result is the one measuring every candidate would give: `top` keeps
/// the best by (distance, index), whatever the order of the offers.
fn measure_pruned(
    f: &Features,
    qi: &[f32],
    lbs: &mut [(f32, u32)],
    proj: &Projection,
    top: &mut TopK,
) {
    let by_bound = |a: &(f32, u32), b: &(f32, u32)| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1));
    let seeds = top.cap.min(lbs.len());
    if seeds < lbs.len() {
        lbs.select_nth_unstable_by(seeds, by_bound);
    }
    let (head, rest) = lbs.split_at_mut(seeds);
    for &(_, j) in head.iter() {
        let d = f.distance_to(qi, None, j as usize, top.bound());
        top.push(d, j);
    }
    // The others that can still enter, nearest bound first.
    let cut = proj.cutoff(top.bound());
    let mut kept = 0;
    for t in 0..rest.len() {
        if rest[t].0 <= cut {
            rest[kept] = rest[t];
            kept += 1;
        }
    }
    let rest = &mut rest[..kept];
    rest.sort_unstable_by(by_bound);
    let mut bound = top.bound();
    let mut cut = proj.cutoff(bound);
    for &(lb, j) in rest.iter() {
        if lb > cut {
            break;
        }
        let d = f.distance_to(qi, None, j as usize, bound);
        top.push(d, j);
        if top.bound() != bound {
            bound = top.bound();
            cut = proj.cutoff(bound);
        }
    }
}

/// Per-thread buffers for [`search`]: a generation-stamped "seen" array for deduplication.
#[derive(Clone, Debug, Default)]
pub struct KScratch {
    stamp: Vec<u32>,
    generation: u32,
    cands: Vec<u32>,
    /// Per feature: its place in `cands` (valid where `stamp` is the generation).
    slot: Vec<u32>,
    /// Per candidate of the last search: the distance returned and the bound given.
    measured: Vec<(f32, f32)>,
    /// Whether the last search of this scratch's owner was a k-coherence one (else
    /// `measured` belongs to an older query).
    current: bool,
}

impl KScratch {
    /// Forgets the last search (the next query's search is not a k-coherence one).
    pub fn invalidate(&mut self) {
        self.current = false;
    }

    /// What the last search measured for feature `c`, if it was a candidate: the value
    /// [`Features::distance`] returned and the bound it was given. *Why*: the finest
    /// level's coherent choice measures its neighbours' continuations against the best
    /// match right after the search, and they are almost always among its candidates. The
    /// distance is a deterministic sum of non-negative terms with an early exit once it
    /// exceeds the bound, so the value returned within its bound is the full distance
    /// whatever bound a new call gets (compared with that bound it gives the same
    /// verdict), and a value beyond a bound at least as large as the new one says the
    /// full distance is beyond the new bound too. Only a candidate cut off by a smaller
    /// bound has to be measured again.
    #[inline]
    pub fn measured(&self, c: u32) -> Option<(f32, f32)> {
        let c = c as usize;
        if !self.current || self.stamp.get(c) != Some(&self.generation) {
            return None;
        }
        Some(self.measured[self.slot[c] as usize])
    }
}

/// The best matches of `q` among the first `k` entries of the lists of the `seeds`
/// (feature indices of forward-shifted source positions) into `top` (cleared first).
/// Returns the number of distinct candidates examined.
pub fn search(
    features: &Features,
    lists: &KnnLists,
    k: usize,
    q: &Prepared,
    seeds: &[u32],
    scratch: &mut KScratch,
    top: &mut TopN,
) -> usize {
    let n = features.len();
    if scratch.stamp.len() != n {
        scratch.stamp = vec![0; n];
        scratch.slot = vec![0; n];
        scratch.generation = 0;
    }
    scratch.generation = scratch.generation.wrapping_add(1);
    if scratch.generation == 0 {
        scratch.stamp.iter_mut().for_each(|s| *s = 0);
        scratch.generation = 1;
    }
    let g = scratch.generation;
    scratch.cands.clear();
    let k = k.min(lists.len);
    // Rank by rank over the seeds (every seed's first entry, then every seed's second, ...)
    // rather than seed by seed. *Why*: the best match is most often a seed's own
    // continuation or one of its nearest, so the pick bound ([`TopN::pick_bound`]) tightens
    // after the first few distances and the later candidates' early exits come sooner.
    // Which matches [`super::pick`] can choose does not depend on the order (every
    // candidate within the final limit is kept, sorted with ties by index), so the choice
    // is the same as seed by seed.
    for r in 0..k {
        for &s in seeds {
            let c = lists.list(s as usize)[r];
            let st = &mut scratch.stamp[c as usize];
            if *st != g {
                *st = g;
                scratch.slot[c as usize] = scratch.cands.len() as u32;
                scratch.cands.push(c);
            }
        }
    }
    top.clear();
    features.rerank_measured(q, &scratch.cands, top, &mut scratch.measured);
    scratch.current = true;
    scratch.cands.len()
}

#[cfg(test)]
mod tests {
    use super::super::Shape;
    use super::*;
    use crate::pyramid::{Image, Pyramid};
    use crate::random::hash;

    /// A `w x h` image of `c` channels: random values, or (`period`) a tiling of a small
    /// random tile, whose repeated neighbourhoods are at exactly equal distances.
    fn image(w: usize, h: usize, c: usize, seed: u64, period: Option<(usize, usize)>) -> Image {
        let mut img = Image::new(w, h, c);
        for y in 0..h {
            for x in 0..w {
                let (u, v) = period.map_or((x, y), |(pw, ph)| (x % pw, y % ph));
                for k in 0..c {
                    let r = hash(seed, &[u as u64, v as u64, k as u64]) % 10_000;
                    img.pixel_mut(x, y)[k] = r as f32 / 1e4;
                }
            }
        }
        img
    }

    /// The `len - 1` nearest of `cands` to `i` by (full distance, index).
    fn ranked(f: &Features, i: usize, cands: impl Iterator<Item = u32>, len: usize) -> Vec<u32> {
        let qi = f.vector(i);
        let mut d: Vec<(f32, u32)> = cands
            .filter(|&j| j as usize != i)
            .map(|j| (f.distance_to(&qi, None, j as usize, f32::INFINITY), j))
            .collect();
        d.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        d.iter().take(len - 1).map(|x| x.1).collect()
    }

    #[test]
    fn lists_are_the_full_ranking_even_with_ties() {
        // Tiled images have many neighbourhoods at exactly the same distance (0 among
        // copies): the lists must still be the first by (distance, index), whatever order
        // the candidates were measured in. 8 channels take the AVX2 kernel where there is
        // one, 3 the portable one.
        for (c, period) in [(8, Some((5, 3))), (3, Some((4, 4))), (8, None), (3, None)] {
            let pyr = Pyramid::build(image(30, 28, c, 7, period), 2);
            let shape = Shape::new(5, 3, c);
            let f0 = Features::build(&pyr, 0, shape, 2).unwrap();
            let f1 = Features::build(&pyr, 1, Shape::new(3, 0, c), 2).unwrap();
            let len = 9;
            let exact = KnnLists::exact(&f0, len);
            let parents = KnnLists::exact(&f1, 6);
            let two = KnnLists::two_level(&f0, &f1, &parents, len);
            for i in 0..f0.len() {
                let l = exact.list(i);
                assert_eq!(l[0] as usize, i);
                let want = ranked(&f0, i, 0..f0.len() as u32, len);
                assert_eq!(&l[1..], &want[..], "exact, {c} channels, pixel {i}");
                // The two-level candidates: children of the parent's list.
                let (x, y) = f0.pixel(i as u32);
                let p = f1.nearest_index((x as f32 + 0.5) / 2.0, (y as f32 + 0.5) / 2.0);
                let mut cands = Vec::new();
                for &q in parents.list(p as usize) {
                    let (cx, cy) = f1.pixel(q);
                    for (a, b) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                        let (fx, fy) = (2 * cx + a, 2 * cy + b);
                        if (f0.margin..f0.margin + f0.cols).contains(&fx)
                            && (f0.margin..f0.margin + f0.rows).contains(&fy)
                        {
                            cands.push(((fy - f0.margin) * f0.cols + fx - f0.margin) as u32);
                        }
                    }
                }
                cands.sort_unstable();
                cands.dedup();
                let mut want = ranked(&f0, i, cands.into_iter(), len);
                while want.len() < len - 1 {
                    want.push(i as u32);
                }
                assert_eq!(
                    &two.list(i)[1..],
                    &want[..],
                    "two-level, {c} channels, pixel {i}"
                );
            }
        }
    }

    #[test]
    fn pruning_bounds_stay_below_the_distances() {
        // Every pair's bound is within the cutoff of its full distance (what makes pruning
        // exact), and the cutoff's margin is small: the bounds prune.
        for c in [8, 3] {
            // Smooth, like a texture's neighbourhoods (white noise has no leading
            // directions to prune with).
            let mut img = image(40, 36, c, 3, None);
            for y in 0..36 {
                for x in 0..40 {
                    for (k, v) in img.pixel_mut(x, y).iter_mut().enumerate() {
                        let t = 0.1 * (k + 1) as f32 * x as f32 + 0.23 * y as f32 + k as f32;
                        *v = t.sin() + 0.05 * *v;
                    }
                }
            }
            let pyr = Pyramid::build(img, 2);
            let f = Features::build(&pyr, 0, Shape::new(9, 5, c), 0).unwrap();
            let proj = Pruning::fit(&f).project(&f);
            let (mut pruned, mut pairs) = (0, 0);
            for i in (0..f.len()).step_by(5) {
                let qi = f.vector(i);
                for j in (0..f.len()).step_by(3) {
                    let d = f.distance_to(&qi, None, j, f32::INFINITY);
                    let lb = lower_bound(proj.row(i), proj.row(j));
                    assert!(lb <= proj.cutoff(d), "{i} {j}: {lb} > cutoff of {d}");
                    assert!(proj.cutoff(d) <= d * 1.01 + 1e-6);
                    pairs += 1;
                    pruned += (lb > proj.cutoff(0.5 * d)) as usize;
                }
            }
            assert!(pruned * 10 > pairs, "{c} channels: {pruned} of {pairs}");
        }
    }
}
