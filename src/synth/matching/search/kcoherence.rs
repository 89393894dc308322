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
                let pi = &proj[i * PRUNE_DIMS..(i + 1) * PRUNE_DIMS];
                lbs.clear();
                for (j, pj) in proj.chunks_exact(PRUNE_DIMS).enumerate() {
                    if j != i {
                        let mut lb = 0.0f32;
                        for t in 0..PRUNE_DIMS {
                            let d = pi[t] - pj[t];
                            lb += d * d;
                        }
                        lbs.push((lb, j as u32));
                    }
                }
                let mut top = TopK::new(len);
                // The pixel itself first (distance 0 and lowest possible key).
                top.push(-1.0, i as u32);
                measure_pruned(f, qi, lbs, 4 * len, &mut top);
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
    /// rest only where their bound beats the current `len`-th best. Why: the full distance
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
        lists.par_chunks_mut(len).enumerate().for_each_init(
            || {
                (
                    Vec::<u32>::new(),
                    Vec::<(f32, u32)>::new(),
                    vec![0.0f32; dim],
                )
            },
            |(cands, lbs, qi), (i, out)| {
                let (x, y) = fine.pixel(i as u32);
                // Parent pixel centre in coarse pixels: (x + 0.5) / 2.
                let parent = coarse.nearest_index((x as f32 + 0.5) / 2.0, (y as f32 + 0.5) / 2.0);
                cands.clear();
                for &c in coarse_lists.list(parent as usize) {
                    let (cx, cy) = coarse.pixel(c);
                    for (a, b) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                        let (fx, fy) = (2 * cx + a, 2 * cy + b);
                        if fx >= fine.margin
                            && fy >= fine.margin
                            && fx < fine.margin + fine.cols
                            && fy < fine.margin + fine.rows
                        {
                            let j = ((fy - fine.margin) * fine.cols + fx - fine.margin) as u32;
                            if j as usize != i {
                                cands.push(j);
                            }
                        }
                    }
                }
                cands.sort_unstable();
                cands.dedup();
                let pi = &proj[i * PRUNE_DIMS..(i + 1) * PRUNE_DIMS];
                lbs.clear();
                lbs.extend(cands.iter().map(|&j| {
                    let pj = &proj[j as usize * PRUNE_DIMS..(j as usize + 1) * PRUNE_DIMS];
                    let mut lb = 0.0f32;
                    for t in 0..PRUNE_DIMS {
                        let d = pi[t] - pj[t];
                        lb += d * d;
                    }
                    (lb, j)
                }));
                fine.vector_into(i, qi);
                let mut top = TopK::new(len);
                top.push(-1.0, i as u32);
                measure_pruned(fine, qi, lbs, len, &mut top);
                // Too few candidates (tiny levels): pad with the pixel itself; duplicates
                // are removed when candidate sets are assembled.
                for (t, o) in out.iter_mut().enumerate() {
                    *o = top.items.get(t).map_or(i as u32, |&(_, idx)| idx);
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

/// The directions the list computations prune with: the first [`PRUNE_DIMS`] principal
/// directions of some level's features. Squared distances between projections are lower
/// bounds of the squared feature distances for *any* orthonormal directions (projecting
/// onto a subspace never lengthens a vector), so the lists do not depend on which
/// features the directions were fitted to — only how much is pruned does. One fit serves
/// every level of a model ([`super::model`]): the fit is serial, ~0.3 s on 850-number
/// neighbourhoods, and the levels' neighbourhoods share their shape and statistics.
pub struct Pruning {
    pca: Pca,
}

impl Pruning {
    /// Fitted to `f`'s features.
    pub fn fit(f: &Features) -> Self {
        let dim = f.dim();
        Self {
            pca: Pca::fit(&f.pca_rows(), dim, PRUNE_DIMS.min(dim)),
        }
    }

    /// Dimension of the features these directions fit.
    pub fn dim(&self) -> usize {
        self.pca.dim
    }

    /// Every feature of `f` projected, in rows of [`PRUNE_DIMS`] (zero-padded).
    fn project(&self, f: &Features) -> Vec<f32> {
        let dim = f.dim();
        assert_eq!(dim, self.pca.dim, "pruning directions of another shape");
        let pd = self.pca.k;
        let mut proj = vec![0.0f32; f.len() * PRUNE_DIMS];
        proj.par_chunks_mut(PRUNE_DIMS).enumerate().for_each_init(
            || vec![0.0f32; dim],
            |v, (i, o)| {
                f.vector_into(i, v);
                self.pca.project(v, &mut o[..pd]);
            },
        );
        proj
    }
}

/// Measures the candidates `lbs` ((lower bound, feature)) against `qi` into `top`: the
/// `seeds` with the lowest bounds first, so that the bound is tight from the start, then
/// the rest only where the lower bound does not rule them out (with a margin for rounding
/// in the projection). The result is the one measuring every candidate would give.
fn measure_pruned(f: &Features, qi: &[f32], lbs: &mut [(f32, u32)], seeds: usize, top: &mut TopK) {
    let len = top.cap;
    let seeds = seeds.min(lbs.len());
    if seeds > 0 && seeds < lbs.len() {
        lbs.select_nth_unstable_by(seeds, |a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
    }
    for (t, &(lb, j)) in lbs.iter().enumerate() {
        if t >= seeds && lb * (1.0 - 1e-4) > top.bound() {
            continue;
        }
        let d = f.distance_to(qi, None, j as usize, top.bound());
        if d < top.bound() || top.items.len() < len {
            top.push(d, j);
        }
    }
}

/// Per-thread buffers for [`search`]: a generation-stamped "seen" array for deduplication.
#[derive(Clone, Debug, Default)]
pub struct KScratch {
    stamp: Vec<u32>,
    generation: u32,
    cands: Vec<u32>,
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
    for &s in seeds {
        for &c in &lists.list(s as usize)[..k] {
            let st = &mut scratch.stamp[c as usize];
            if *st != g {
                *st = g;
                scratch.cands.push(c);
            }
        }
    }
    top.clear();
    features.rerank(q, &scratch.cands, top);
    scratch.cands.len()
}
