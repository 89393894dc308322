//! Neighbourhood vectors and nearest-neighbour search over an example level.
//!
//! Multiscale synthesis (paper 000 §4, after Wei & Levoy) copies, for every target sample,
//! the centre of the example neighbourhood that best matches the target's neighbourhood
//! under a Gaussian-weighted l2 distance. This module owns what is shared by the 2D
//! reference synthesizer ([`crate::synth::synth2d`]) and the surface one:
//!
//! * [`Shape`]: which samples a neighbourhood holds — a square `fine x fine` block from the
//!   level being synthesized and/or a `coarse x coarse` block from the next coarser level
//!   (offsets in that level's pixels, centred on the same point) — and their Gaussian
//!   weights.
//! * [`Features`]: the weighted vector of every example pixel whose whole neighbourhood lies
//!   inside the example (the *valid* pixels; clamped or wrapped windows would invent
//!   neighbourhoods that do not occur in the example).
//! * [`Query`]/[`Prepared`]: a target neighbourhood with possibly missing samples (not yet
//!   generated, or off an open surface). Missing samples are left out of the distance, as
//!   the paper prescribes ("undefined values are discarded").
//! * Three searches returning the [`BEST_N`] best matches: exact brute force
//!   ([`Features::brute_force`], used at the coarsest level as in the paper), PCA + kd-tree
//!   ([`ann`]) and k-coherence ([`kcoherence`], paper 003 §5.2), and the paper's
//!   randomised choice among them ([`pick`]).
//!
//! **Weights.** "Samples are weighted with a Gaussian kernel in image space" (000 §4). Each
//! block uses `exp(-(dx² + dy²) / (2σ²))` with `σ = K / 4` in its own pixels (K the block
//! side: a 9x9 block gets σ = 2.25, so its corners weigh 0.04 and its edge midpoints 0.21
//! of the centre), normalised so that each block's weights sum to 1. Per-block
//! normalisation keeps the 25 coarse samples from being drowned by the 81 fine ones: the
//! coarse block carries the layout, the fine block the detail, and both matter. Vectors are
//! stored premultiplied by the square roots of the weights, so the weighted distance is a
//! plain squared Euclidean distance — which is what lets PCA and a kd-tree work on them.
//!
//! **Sample order** (the vector layout every caller must follow): the fine block first, then
//! the coarse block; each row-major with `dy` from `-r` to `r` (image rows, down) outer and
//! `dx` from `-r` to `r` (image columns, right) inner; all channels of a sample together.

pub mod ann;
pub mod kcoherence;
pub mod model;
pub mod pca;

use crate::error::{Error, Result};
use crate::pyramid::Pyramid;

/// How many best matches a search returns, from which [`pick`] chooses (000 §4: "we locate
/// the eight nearest matches").
pub const BEST_N: usize = 8;

/// Matches whose distance exceeds the best one's by more than this factor are discarded
/// before the random choice (000 §4: "worse than the best match by a factor of 0.1").
/// Applied to the distance (the square root of the weighted squared distance).
pub const TOLERANCE: f32 = 0.1;

/// The samples of a neighbourhood: `fine x fine` from the current level and
/// `coarse x coarse` from the next coarser one (either may be 0; sides are odd).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Shape {
    pub fine: usize,
    pub coarse: usize,
    pub channels: usize,
}

/// One sample of a [`Shape`]: offset in its level's pixels and which level.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Offset {
    pub dx: i32,
    pub dy: i32,
    /// True for the coarser level's block.
    pub coarse: bool,
}

impl Shape {
    /// A shape; panics on even or all-zero sides (a programming error, not an input).
    pub fn new(fine: usize, coarse: usize, channels: usize) -> Self {
        assert!(fine % 2 == 1 || fine == 0, "fine side must be odd");
        assert!(coarse % 2 == 1 || coarse == 0, "coarse side must be odd");
        assert!(fine + coarse > 0 && channels > 0);
        Self {
            fine,
            coarse,
            channels,
        }
    }

    /// Number of samples.
    pub fn samples(&self) -> usize {
        self.fine * self.fine + self.coarse * self.coarse
    }

    /// Vector length: samples times channels.
    pub fn dim(&self) -> usize {
        self.samples() * self.channels
    }

    /// The sample offsets in vector order (see the module documentation).
    pub fn offsets(&self) -> Vec<Offset> {
        let mut v = Vec::with_capacity(self.samples());
        for (side, coarse) in [(self.fine, false), (self.coarse, true)] {
            let r = (side / 2) as i32;
            if side == 0 {
                continue;
            }
            for dy in -r..=r {
                for dx in -r..=r {
                    v.push(Offset { dx, dy, coarse });
                }
            }
        }
        v
    }

    /// Square roots of the Gaussian sample weights, in vector order (see the module
    /// documentation for σ and the per-block normalisation).
    pub fn sample_scales(&self) -> Vec<f32> {
        let mut v = Vec::with_capacity(self.samples());
        for side in [self.fine, self.coarse] {
            if side == 0 {
                continue;
            }
            let r = (side / 2) as i32;
            let sigma = side as f64 / 4.0;
            let w: Vec<f64> = (-r..=r)
                .flat_map(|dy| (-r..=r).map(move |dx| (dx, dy)))
                .map(|(dx, dy)| (-((dx * dx + dy * dy) as f64) / (2.0 * sigma * sigma)).exp())
                .collect();
            let sum: f64 = w.iter().sum();
            v.extend(w.iter().map(|x| (x / sum).sqrt() as f32));
        }
        v
    }

    /// How far (in current-level pixels) the neighbourhood reaches from its centre: `r` for
    /// the fine block, `2r` for the coarse one (its pixels are twice as large).
    pub fn reach(&self) -> usize {
        (self.fine / 2).max(2 * (self.coarse / 2))
    }
}

/// A best match: index into [`Features`] and weighted squared distance.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Match {
    pub index: u32,
    pub dist2: f32,
}

impl Match {
    #[inline]
    fn before(&self, o: &Match) -> bool {
        // Ties broken by index so that results never depend on visiting order.
        self.dist2 < o.dist2 || (self.dist2 == o.dist2 && self.index < o.index)
    }
}

/// The [`BEST_N`] best matches seen so far, sorted ascending.
#[derive(Clone, Debug)]
pub struct TopN {
    items: [Match; BEST_N],
    len: usize,
}

impl Default for TopN {
    fn default() -> Self {
        Self::new()
    }
}

impl TopN {
    pub fn new() -> Self {
        Self {
            items: [Match {
                index: u32::MAX,
                dist2: f32::INFINITY,
            }; BEST_N],
            len: 0,
        }
    }

    pub fn clear(&mut self) {
        self.len = 0;
    }

    /// The distance a candidate must beat to enter (infinite until full).
    #[inline]
    pub fn bound(&self) -> f32 {
        if self.len < BEST_N {
            f32::INFINITY
        } else {
            self.items[BEST_N - 1].dist2
        }
    }

    /// The distance a candidate must beat to be one [`pick`] can still choose: at most
    /// [`Self::bound`], and at most [`pick_limit`] of the best so far. *Why*: the
    /// randomised choice only ever takes matches within [`TOLERANCE`] of the best, and the
    /// best only improves, so a candidate beyond the limit of the best *so far* can never
    /// be chosen; the distances' early exit then gives up on it after a few samples
    /// instead of summing all of them (issue 14: most of a multiscale run's distances ran
    /// to the end against an 8th best far above the best). What `pick` returns is
    /// unchanged: every match within the final limit is still kept, in the same order
    /// (what follows them in the list is no longer the rest of the eight best).
    #[inline]
    pub fn pick_bound(&self) -> f32 {
        if self.len == 0 {
            f32::INFINITY
        } else {
            self.bound().min(pick_limit(self.items[0].dist2))
        }
    }

    /// Offers a candidate (the caller guarantees no duplicates).
    #[inline]
    pub fn push(&mut self, m: Match) {
        if self.len == BEST_N && !m.before(&self.items[BEST_N - 1]) {
            return;
        }
        let mut i = self.len.min(BEST_N - 1);
        while i > 0 && m.before(&self.items[i - 1]) {
            self.items[i] = self.items[i - 1];
            i -= 1;
        }
        self.items[i] = m;
        self.len = (self.len + 1).min(BEST_N);
    }

    /// The matches, best first.
    pub fn as_slice(&self) -> &[Match] {
        &self.items[..self.len]
    }
}

/// The paper's randomised choice (000 §4, after De Bonet and Wei & Levoy): among the best
/// matches (sorted, best first) drop those whose distance exceeds the best's by more than
/// [`TOLERANCE`], then pick one uniformly with the counter-based hash `key` — so the choice
/// depends only on (seed, level, pass, sample), never on threads or visiting order.
pub fn pick(best: &[Match], key: u64) -> Match {
    assert!(!best.is_empty(), "pick needs at least one match");
    let limit = pick_limit(best[0].dist2);
    let n = best.iter().take_while(|m| m.dist2 <= limit).count().max(1);
    best[(key % n as u64) as usize]
}

/// The largest squared distance [`pick`] accepts beside a best match at `best` (monotone
/// in `best`, as [`TopN::pick_bound`] relies on).
#[inline]
pub fn pick_limit(best: f32) -> f32 {
    best * (1.0 + TOLERANCE) * (1.0 + TOLERANCE)
}

/// A target neighbourhood in [`Shape`] order, raw (unweighted) values, with a presence flag
/// per sample.
#[derive(Clone, Debug)]
pub struct Query {
    pub shape: Shape,
    pub values: Vec<f32>,
    pub present: Vec<bool>,
    /// Per-sample factors of the Gaussian weights ([`Shape`] order) for a *sparse* query,
    /// one that leaves samples out on purpose and lets the ones it keeps carry their
    /// weight (multiscale's sparse 9x9 block, `level::sparse_gains`). Empty: every factor
    /// 1 and [`Features::distance`] reads every stored sample as before. Non-empty: the
    /// prepared query keeps only its present samples ([`Prepared::offs`]), so distances
    /// cost what the present samples cost.
    pub gain: Vec<f32>,
}

impl Query {
    /// All samples missing.
    pub fn new(shape: Shape) -> Self {
        Self {
            shape,
            values: vec![0.0; shape.dim()],
            present: vec![false; shape.samples()],
            gain: Vec::new(),
        }
    }

    /// Sets sample `s` to `vals` (all channels) and marks it present.
    #[inline]
    pub fn set(&mut self, s: usize, vals: &[f32]) {
        let c = self.shape.channels;
        if c == 8 {
            // Two moves instead of a call to memcpy (appearance space's 8 channels): as
            // one 8-float value, which the optimiser does not fold back into the general
            // copy as it did a `copy_from_slice` of 8.
            let v: [f32; 8] = vals[..8].try_into().expect("8 channels");
            let dst: &mut [f32; 8] = (&mut self.values[s * 8..s * 8 + 8])
                .try_into()
                .expect("8 channels");
            *dst = v;
        } else {
            self.values[s * c..(s + 1) * c].copy_from_slice(&vals[..c]);
        }
        self.present[s] = true;
    }

    /// Marks sample `s` missing.
    #[inline]
    pub fn clear(&mut self, s: usize) {
        self.present[s] = false;
    }

    /// Marks all samples missing.
    pub fn clear_all(&mut self) {
        self.present.iter_mut().for_each(|p| *p = false);
    }

    /// Number of present samples.
    pub fn present_count(&self) -> usize {
        self.present.iter().filter(|&&p| p).count()
    }
}

/// A query ready for distances: weighted values (0 where missing), a per-dimension 0/1 mask
/// and whether all samples are present (what projections read, [`ann`]); and for the
/// searches' distances ([`Features::distance`]) the raw values in storage order (0 where
/// missing) with one squared weight per sample (0 where missing).
#[derive(Clone, Debug, Default)]
pub struct Prepared {
    pub v: Vec<f32>,
    pub mask: Vec<f32>,
    pub complete: bool,
    pub present: usize,
    /// Raw (unweighted) values in storage order, 0 where missing.
    pub raw: Vec<f32>,
    /// Per stored sample: its Gaussian weight (the square of its [`Features::scales`]
    /// entry), 0 where missing.
    pub w2: Vec<f32>,
    /// Empty, or for a sparse query ([`Query::gain`]) the offsets (as
    /// `Features::offsets`) of its present samples only, in storage order; `raw` and
    /// `w2` then hold those samples only, `w2` times the query's gain.
    pub offs: Vec<isize>,
}

/// The weighted neighbourhood vectors of the valid pixels of one example level, gathered
/// on the fly from the level's pixels.
///
/// Valid pixels are those at least [`Shape::reach`] pixels from every border (the
/// *margin*), so their whole neighbourhood is real example content. Feature `i` is valid
/// pixel `(margin + i % cols, margin + i / cols)`.
///
/// Vectors (and [`Prepared`] queries) hold the samples by *decreasing weight* (`order`),
/// not in [`Shape`] order: distances are summed in blocks with an early exit once the
/// partial sum exceeds the k-th best so far, and with the heavy centre samples first most
/// hopeless candidates are rejected after the first block instead of after the light
/// corners. Measured on a 64x64 example: exact k-NN lists 2.6x faster. The order is
/// internal; callers fill [`Query`] in [`Shape`] order.
///
/// **Why gathered, not stored.** A stored vector is `shape.dim()` floats per pixel: 848
/// (3.4 KB) for the 9x9 + 5x5 block over 8 appearance dimensions, 330 MB for the passes
/// of a 256² example, which dominated the multiscale method's peak memory. Every sample
/// is a pixel of the level itself or, for the coarse block, a pixel of the coarser level
/// *upsampled* to this level's pixels (the bilinear value at `(x + 0.5) / 2 + dx` is the
/// upsampled image at `x + 2dx`: the same float arithmetic), so `2 x channels` floats per
/// pixel (`Self::source`) and one offset and weight per dimension give every vector. The
/// gathered values are the stored ones bit for bit (the same products), and distances are
/// summed in the same blocks and lanes, so searches return exactly what they did. Reading
/// a few small images instead of streaming 3.4 KB rows also made the k-coherence lists
/// about twice as fast to build.
#[derive(Clone, Debug)]
pub struct Features {
    pub shape: Shape,
    /// Pyramid level these features were taken from.
    pub level: usize,
    /// Size of that level.
    pub width: usize,
    pub height: usize,
    pub margin: usize,
    /// Size of the valid region.
    pub cols: usize,
    pub rows: usize,
    /// Per-sample square-root weights ([`Shape::sample_scales`]), in [`Shape`] order.
    pub scales: Vec<f32>,
    /// Storage order: `order[t]` is the [`Shape`] sample stored at position `t`.
    pub order: Vec<usize>,
    /// Unweighted values the vectors are gathered from: the level's `width x height`
    /// pixels, then (with a coarse block) the coarser level upsampled bilinearly to the
    /// same pixels; `channels` floats each. Shared by the features of one level's passes.
    source: std::sync::Arc<Vec<f32>>,
    /// Per stored sample (storage order): offset in `source` of its first channel from the
    /// first channel of the feature's own pixel in the level's image (its `channels`
    /// values follow).
    offsets: Vec<isize>,
    /// Per stored sample: its square-root weight.
    weights: Vec<f32>,
}

impl Features {
    /// The features of pyramid level `level` for `shape`; the coarse block (if any) comes
    /// from level `level + 1`, sampled bilinearly at the exact position of each sample
    /// centre (the fine pixel's centre `(x + 0.5) / 2` plus the offset, in coarse pixels) —
    /// the same rule the targets use, so neither side is favoured by a half-pixel shift.
    ///
    /// `margin` overrides [`Shape::reach`] when larger, so that the features of several
    /// shapes on one level (the two passes) index the same pixels.
    pub fn build(pyr: &Pyramid, level: usize, shape: Shape, margin: usize) -> Result<Self> {
        Self::build_sharing(pyr, level, shape, margin, None)
    }

    /// [`Self::build`], reusing the gathered-from values of `other` (features of the same
    /// level with a coarse block) when it has them.
    pub fn build_sharing(
        pyr: &Pyramid,
        level: usize,
        shape: Shape,
        margin: usize,
        other: Option<&Features>,
    ) -> Result<Self> {
        let img = pyr.level(level);
        if shape.channels != img.channels {
            return Err(Error::invalid(format!(
                "neighbourhood has {} channels but the example level has {}",
                shape.channels, img.channels
            )));
        }
        if shape.coarse > 0 && level + 1 >= pyr.len() {
            return Err(Error::invalid(format!(
                "level {level} needs a coarser level but the pyramid has {} levels",
                pyr.len()
            )));
        }
        let margin = margin.max(shape.reach());
        let (w, h) = (img.width, img.height);
        if w < 2 * margin + 1 || h < 2 * margin + 1 {
            return Err(Error::invalid(format!(
                "example level {level} is {w}x{h} pixels, too small for a {}x{} neighbourhood (needs at least {}x{})",
                shape.fine.max(shape.coarse),
                shape.fine.max(shape.coarse),
                2 * margin + 1,
                2 * margin + 1
            )));
        }
        let (cols, rows) = (w - 2 * margin, h - 2 * margin);
        let scales = shape.sample_scales();
        let order = weight_order(&scales);
        let c = shape.channels;
        let plane = w * h * c;
        let source = match other {
            Some(o)
                if o.level == level
                    && o.width == w
                    && o.height == h
                    && o.shape.channels == c
                    && (shape.coarse == 0 || o.source.len() == 2 * plane) =>
            {
                o.source.clone()
            }
            _ => {
                let mut v = Vec::with_capacity(if shape.coarse > 0 { 2 * plane } else { plane });
                v.extend_from_slice(&img.data);
                if shape.coarse > 0 {
                    // The coarser level at this level's pixel centres: U(x, y) is its
                    // bilinear value at ((x + 0.5) / 2, (y + 0.5) / 2).
                    let ci = pyr.level(level + 1);
                    v.resize(2 * plane, 0.0);
                    let up = &mut v[plane..];
                    use rayon::prelude::*;
                    up.par_chunks_mut(w * c).enumerate().for_each(|(y, row)| {
                        for (x, px) in row.chunks_exact_mut(c).enumerate() {
                            ci.bilinear((x as f32 + 0.5) / 2.0, (y as f32 + 0.5) / 2.0, px);
                        }
                    });
                }
                std::sync::Arc::new(v)
            }
        };
        let all = shape.offsets();
        let mut offsets = Vec::with_capacity(shape.samples());
        let mut weights = Vec::with_capacity(shape.samples());
        for &s in &order {
            let o = all[s];
            // A coarse sample (dx, dy) in coarse pixels is the upsampled image 2(dx, dy)
            // fine pixels away: ((x + 2dx) + 0.5) / 2 = (x + 0.5) / 2 + dx exactly.
            let (dx, dy, at) = if o.coarse {
                (2 * o.dx as isize, 2 * o.dy as isize, plane as isize)
            } else {
                (o.dx as isize, o.dy as isize, 0)
            };
            offsets.push(at + (dy * w as isize + dx) * c as isize);
            weights.push(scales[s]);
        }
        Ok(Self {
            shape,
            level,
            width: w,
            height: h,
            margin,
            cols,
            rows,
            scales,
            order,
            source,
            offsets,
            weights,
        })
    }

    /// Number of feature vectors (valid pixels).
    pub fn len(&self) -> usize {
        self.cols * self.rows
    }

    /// True when there are no valid pixels (never, for a built instance).
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Vector length.
    pub fn dim(&self) -> usize {
        self.shape.dim()
    }

    /// Bytes held (the gathered-from values count once per level when shared).
    pub fn heap_bytes(&self) -> usize {
        4 * self.source.len() + 12 * self.offsets.len()
    }

    /// Offset in [`Self::source`] of the first channel of feature `i`'s pixel.
    #[inline]
    fn base(&self, i: usize) -> usize {
        let (x, y) = (self.margin + i % self.cols, self.margin + i / self.cols);
        (y * self.width + x) * self.shape.channels
    }

    /// The weighted vector of feature `i` into `out` (`dim()` long).
    #[inline]
    pub fn vector_into(&self, i: usize, out: &mut [f32]) {
        let c = self.shape.channels;
        let base = self.base(i) as isize;
        for ((o, &off), &w) in out
            .chunks_exact_mut(c)
            .zip(&self.offsets)
            .zip(&self.weights)
        {
            let at = (base + off) as usize;
            for (o, &x) in o.iter_mut().zip(&self.source[at..at + c]) {
                *o = x * w;
            }
        }
    }

    /// Weighted vector of feature `i` (allocates; see [`Self::vector_into`]).
    pub fn vector(&self, i: usize) -> Vec<f32> {
        let mut v = vec![0.0; self.dim()];
        self.vector_into(i, &mut v);
        v
    }

    /// The vectors of the rows [`pca::Pca::fit`] uses (all up to [`pca::MAX_ROWS`], else
    /// that many evenly spaced), row-major: fitting on them is fitting on all vectors.
    pub fn pca_rows(&self) -> Vec<f32> {
        let n = self.len();
        let dim = self.dim();
        let rows: Vec<usize> = if n <= pca::MAX_ROWS {
            (0..n).collect()
        } else {
            (0..pca::MAX_ROWS).map(|i| i * n / pca::MAX_ROWS).collect()
        };
        let mut out = vec![0.0f32; rows.len() * dim];
        for (o, &r) in out.chunks_exact_mut(dim).zip(&rows) {
            self.vector_into(r, o);
        }
        out
    }

    /// Pixel (column, row) of feature `i` in its level.
    #[inline]
    pub fn pixel(&self, i: u32) -> (usize, usize) {
        let i = i as usize;
        (self.margin + i % self.cols, self.margin + i / self.cols)
    }

    /// The feature of the valid pixel nearest to continuous position (x, y) (level pixels,
    /// centres at +0.5), clamping into the valid region: where forward-shifted source
    /// positions (k-coherence) land.
    #[inline]
    pub fn nearest_index(&self, x: f32, y: f32) -> u32 {
        let clampf = |v: f32, lo: usize, n: usize| -> usize {
            let p = if v.is_nan() { 0.0 } else { v.floor() };
            (p.max(lo as f32) as usize).min(lo + n - 1)
        };
        let px = clampf(x, self.margin, self.cols) - self.margin;
        let py = clampf(y, self.margin, self.rows) - self.margin;
        (py * self.cols + px) as u32
    }

    /// Applies the weights and mask of `q` into `out`.
    pub fn prepare(&self, q: &Query, out: &mut Prepared) {
        self.prepare_impl(q, out, true);
    }

    /// [`Self::prepare`] for [`Self::distance`] only: `raw`, `w2` (and `offs`), not the
    /// weighted vector and mask that projections read (left empty). *Why*: k-coherence and
    /// exhaustive searches never project, and filling `v` and `mask` was most of
    /// preparing a query — ~4% of a multiscale run (issue 14).
    pub fn prepare_distances(&self, q: &Query, out: &mut Prepared) {
        self.prepare_impl(q, out, false);
    }

    fn prepare_impl(&self, q: &Query, out: &mut Prepared, projections: bool) {
        assert_eq!(
            q.shape, self.shape,
            "query shape differs from the features'"
        );
        let c = self.shape.channels;
        let dim = self.dim();
        if projections {
            out.v.resize(dim, 0.0);
            out.mask.resize(dim, 0.0);
        } else {
            out.v.clear();
            out.mask.clear();
        }
        // A sparse query keeps its present samples only, in storage order (the same
        // order and blocks as a complete query when every sample is present).
        let sparse = !q.gain.is_empty();
        out.raw.clear();
        out.w2.clear();
        out.offs.clear();
        let mut present = 0;
        for (t, &s) in self.order.iter().enumerate() {
            let p = q.present[s];
            let sc = self.scales[s];
            if projections {
                for k in 0..c {
                    if p {
                        out.v[t * c + k] = q.values[s * c + k] * sc;
                        out.mask[t * c + k] = 1.0;
                    } else {
                        out.v[t * c + k] = 0.0;
                        out.mask[t * c + k] = 0.0;
                    }
                }
            }
            present += p as usize;
            if p {
                out.raw.extend_from_slice(&q.values[s * c..(s + 1) * c]);
                if sparse {
                    out.w2.push(sc * sc * q.gain[s]);
                    out.offs.push(self.offsets[t]);
                } else {
                    out.w2.push(sc * sc);
                }
            } else if !sparse {
                out.raw.extend(std::iter::repeat_n(0.0, c));
                out.w2.push(0.0);
            }
        }
        out.present = present;
        out.complete = present == q.present.len();
    }

    /// Squared distance from the weighted vector `a` (`dim()` long, storage order) to
    /// feature `i`, over the dimensions where `mask` (if any) is 1, giving up (returning a
    /// value `> bound`) once the partial sum exceeds `bound`. Bit for bit
    /// [`dist_bounded`] / [`dist_masked_bounded`] of `a` and the stored vector.
    #[inline]
    pub fn distance_to(&self, a: &[f32], mask: Option<&[f32]>, i: usize, bound: f32) -> f32 {
        gather_dispatch(a, mask, self, self.base(i), bound)
    }

    /// Weighted squared distance from `q` to feature `i`, over present samples, giving up
    /// (returning a value `> bound`) once the partial sum exceeds `bound`.
    ///
    /// Summed as Σ w·(q − x)² over the raw values, the weight w applied on the query's
    /// side once per sample ([`Prepared::w2`]; missing samples weigh 0), rather than as
    /// (√w·q − √w·x)² over weighted vectors as [`Self::distance_to`] does. *Why*: a
    /// candidate's samples are then read straight from the example level (`channels`
    /// consecutive floats each, one vector load with 8 appearance dimensions) with no
    /// weighted copy and no mask, and complete and partial queries take one path. This is
    /// the searches' inner loop (a third of a multiscale run's time, issue 14); the same
    /// value up to rounding. The k-coherence lists keep [`Self::distance_to`], so saved
    /// lists stay valid.
    #[inline]
    pub fn distance(&self, q: &Prepared, i: usize, bound: f32) -> f32 {
        let offs = if q.offs.is_empty() {
            &self.offsets[..]
        } else {
            &q.offs[..]
        };
        weighted_dispatch(&q.raw, &q.w2, offs, self, self.base(i), bound)
    }

    /// Exact search over every valid pixel (the paper's coarsest-level search) into `top`:
    /// the best match and those [`pick`] may choose beside it, sorted, possibly followed
    /// by some it may not ([`TopN::pick_bound`]).
    pub fn brute_force(&self, q: &Prepared, top: &mut TopN) {
        top.clear();
        for i in 0..self.len() {
            let b = top.pick_bound();
            let d = self.distance(q, i, b);
            if d <= b {
                top.push(Match {
                    index: i as u32,
                    dist2: d,
                });
            }
        }
    }

    /// Exact re-ranking of a candidate list (no duplicates) into `top`, which is not
    /// cleared: the best match and those [`pick`] may choose beside it, sorted, possibly
    /// followed by some it may not ([`TopN::pick_bound`]).
    pub fn rerank(&self, q: &Prepared, candidates: &[u32], top: &mut TopN) {
        self.rerank_each(q, candidates, top, |_, _| {});
    }

    /// [`Self::rerank`], also keeping per candidate what [`Self::distance`] returned and
    /// the bound it was given (`measured`, in the order of `candidates`; cleared first):
    /// what a later distance of the same candidate would say (see
    /// [`kcoherence::KScratch::measured`]).
    pub fn rerank_measured(
        &self,
        q: &Prepared,
        candidates: &[u32],
        top: &mut TopN,
        measured: &mut Vec<(f32, f32)>,
    ) {
        measured.clear();
        self.rerank_each(q, candidates, top, |d, b| measured.push((d, b)));
    }

    /// The loop of [`Self::rerank`], telling `seen` each candidate's distance and the
    /// bound it was measured with.
    #[inline]
    fn rerank_each(
        &self,
        q: &Prepared,
        candidates: &[u32],
        top: &mut TopN,
        mut seen: impl FnMut(f32, f32),
    ) {
        for &i in candidates {
            let b = top.pick_bound();
            let d = self.distance(q, i as usize, b);
            seen(d, b);
            if d <= b {
                top.push(Match { index: i, dist2: d });
            }
        }
    }
}

/// Sample indices sorted by decreasing weight (ties by index): the storage order of
/// [`Features`].
fn weight_order(scales: &[f32]) -> Vec<usize> {
    let mut order: Vec<usize> = (0..scales.len()).collect();
    order.sort_by(|&a, &b| scales[b].total_cmp(&scales[a]).then(a.cmp(&b)));
    order
}

/// Dimensions summed between early-exit checks: long enough to vectorise, short enough to
/// save most of the work on hopeless candidates.
const BLOCK: usize = 32;

/// Lanes of the partial sums. Both the portable and the AVX2 kernels accumulate the same 16
/// lanes in the same order (no fused multiply-add), so they return bit-identical results:
/// the output never depends on which CPU features were detected.
const LANES: usize = 16;

/// One block's partial sum: 16 lanes, each the running sum of its dimensions in order,
/// then the lanes summed in order.
#[inline(always)]
fn block_sum(ca: &[f32], cb: &[f32], cm: Option<&[f32]>) -> f32 {
    let mut acc = [0.0f32; LANES];
    let mut ia = ca.chunks_exact(LANES);
    let mut ib = cb.chunks_exact(LANES);
    match cm {
        None => {
            for (x, y) in (&mut ia).zip(&mut ib) {
                for k in 0..LANES {
                    let d = x[k] - y[k];
                    acc[k] += d * d;
                }
            }
            for (k, (x, y)) in ia.remainder().iter().zip(ib.remainder()).enumerate() {
                let d = x - y;
                acc[k] += d * d;
            }
        }
        Some(cm) => {
            let mut im = cm.chunks_exact(LANES);
            for ((x, y), w) in (&mut ia).zip(&mut ib).zip(&mut im) {
                for k in 0..LANES {
                    let d = x[k] - y[k];
                    acc[k] += w[k] * (d * d);
                }
            }
            for (k, ((x, y), w)) in ia
                .remainder()
                .iter()
                .zip(ib.remainder())
                .zip(im.remainder())
                .enumerate()
            {
                let d = x - y;
                acc[k] += w * (d * d);
            }
        }
    }
    let mut s = 0.0f32;
    for v in acc {
        s += v;
    }
    s
}

#[inline(always)]
fn dist_kernel(a: &[f32], b: &[f32], m: Option<&[f32]>, bound: f32) -> f32 {
    let n = a.len().min(b.len());
    let (a, b) = (&a[..n], &b[..n]);
    let mut total = 0.0f32;
    let mut start = 0;
    while start < n {
        let end = (start + BLOCK).min(n);
        total += block_sum(&a[start..end], &b[start..end], m.map(|m| &m[start..end]));
        if total > bound {
            return total;
        }
        start = end;
    }
    total
}

/// [`dist_kernel`] against the vector of `f` at `base` ([`Features::distance_to`]),
/// gathered one block at a time: the same blocks, lanes and early exit. `C` is the
/// channel count when a block holds whole samples (`BLOCK % C == 0`: one fixed-length copy
/// per sample), 0 for any other count (runs of channels split at block ends).
#[inline]
fn gather_kernel<const C: usize>(
    a: &[f32],
    m: Option<&[f32]>,
    f: &Features,
    base: usize,
    bound: f32,
) -> f32 {
    let c = f.shape.channels;
    debug_assert!(C == 0 || C == c);
    let n = a.len().min(f.offsets.len() * c);
    let src = &f.source[..];
    let base = base as isize;
    let mut buf = [0.0f32; BLOCK];
    let mut total = 0.0f32;
    let mut start = 0;
    while start < n {
        let end = (start + BLOCK).min(n);
        // (C = 0 takes the general path; checked_div folds away for a constant C.)
        if let (Some(s0), Some(s1)) = (start.checked_div(C), end.checked_div(C)) {
            for ((o, &off), &w) in buf
                .chunks_exact_mut(C)
                .zip(&f.offsets[s0..s1])
                .zip(&f.weights[s0..s1])
            {
                let at = (base + off) as usize;
                let x = &src[at..at + C];
                for k in 0..C {
                    o[k] = x[k] * w;
                }
            }
        } else {
            // Dimensions start..end: runs of consecutive channels of one sample each.
            let mut d = start;
            while d < end {
                let (s, k) = (d / c, d % c);
                let len = (c - k).min(end - d);
                let at = (base + f.offsets[s]) as usize + k;
                let w = f.weights[s];
                for (o, &x) in buf[d - start..d - start + len]
                    .iter_mut()
                    .zip(&src[at..at + len])
                {
                    *o = x * w;
                }
                d += len;
            }
        }
        let b = &buf[..end - start];
        total += block_sum(&a[start..end], b, m.map(|m| &m[start..end]));
        if total > bound {
            return total;
        }
        start = end;
    }
    total
}

/// [`gather_kernel`] for the channel count of `f`.
#[inline]
fn gather_any(a: &[f32], m: Option<&[f32]>, f: &Features, base: usize, bound: f32) -> f32 {
    match f.shape.channels {
        8 => gather_kernel::<8>(a, m, f, base, bound),
        4 => gather_kernel::<4>(a, m, f, base, bound),
        2 => gather_kernel::<2>(a, m, f, base, bound),
        1 => gather_kernel::<1>(a, m, f, base, bound),
        _ => gather_kernel::<0>(a, m, f, base, bound),
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn gather_avx2(a: &[f32], m: Option<&[f32]>, f: &Features, base: usize, bound: f32) -> f32 {
    gather_any(a, m, f, base, bound)
}

#[inline]
fn gather_dispatch(a: &[f32], m: Option<&[f32]>, f: &Features, base: usize, bound: f32) -> f32 {
    #[cfg(target_arch = "x86_64")]
    {
        if std::arch::is_x86_feature_detected!("avx2") {
            if m.is_none() && f.shape.channels == 8 {
                // SAFETY: the CPU supports AVX2 (checked just above).
                return unsafe { gather8_avx2(a, f, base, bound) };
            }
            // SAFETY: the CPU supports AVX2 (checked just above).
            return unsafe { gather_avx2(a, m, f, base, bound) };
        }
    }
    gather_any(a, m, f, base, bound)
}

/// [`gather_kernel`] for 8 channels without a mask (the k-coherence lists' distance in
/// appearance space), bit for bit, eight blocks at a time.
///
/// *Why*: summing a block's 16 lanes in order is a chain of 16 dependent additions, and it
/// was most of the cost of a distance (issue 14: ~87 cycles per 32-dimension block in a
/// 512² example's lists). Here the lanes of eight blocks are summed side by side: their
/// accumulators (sample `t` of a block into lanes 0–7 when `t` is even, 8–15 when odd: the
/// lanes of [`block_sum`] for 8 channels) are transposed so that each vector holds one lane
/// of eight blocks, and sixteen vector additions give the eight blocks' sums, each in the
/// same order as [`block_sum`]'s. The blocks' sums are then added to the total one by one
/// with the same early exit, so the value returned (even on an early exit) is
/// [`gather_kernel`]'s; at most seven blocks' work past the exit is wasted.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn gather8_avx2(a: &[f32], f: &Features, base: usize, bound: f32) -> f32 {
    use std::arch::x86_64::*;
    const C: usize = 8;
    const PER: usize = BLOCK / C;
    let ns = (a.len() / C).min(f.offsets.len());
    let nb = ns.div_ceil(PER);
    let src = &f.source[..];
    let base = base as isize;
    let mut total = 0.0f32;
    let mut b0 = 0;
    while b0 < nb {
        let g = (nb - b0).min(8);
        let mut lo = [_mm256_setzero_ps(); 8];
        let mut hi = [_mm256_setzero_ps(); 8];
        for j in 0..g {
            let s0 = (b0 + j) * PER;
            let s1 = (s0 + PER).min(ns);
            let (mut l, mut h) = (_mm256_setzero_ps(), _mm256_setzero_ps());
            for t in s0..s1 {
                let at = (base + f.offsets[t]) as usize;
                let x = _mm256_loadu_ps(src[at..at + C].as_ptr());
                let w = _mm256_set1_ps(f.weights[t]);
                let q = _mm256_loadu_ps(a[t * C..t * C + C].as_ptr());
                let d = _mm256_sub_ps(q, _mm256_mul_ps(x, w));
                let sq = _mm256_mul_ps(d, d);
                if (t - s0).is_multiple_of(2) {
                    l = _mm256_add_ps(l, sq);
                } else {
                    h = _mm256_add_ps(h, sq);
                }
            }
            lo[j] = l;
            hi[j] = h;
        }
        // s[j] = ((lo_j[0] + lo_j[1]) + … + lo_j[7]) + hi_j[0] + … + hi_j[7], in order.
        let tl = transpose8(&lo);
        let th = transpose8(&hi);
        let mut s = tl[0];
        for v in &tl[1..] {
            s = _mm256_add_ps(s, *v);
        }
        for v in &th {
            s = _mm256_add_ps(s, *v);
        }
        let mut sums = [0.0f32; 8];
        _mm256_storeu_ps(sums.as_mut_ptr(), s);
        for &sj in &sums[..g] {
            total += sj;
            if total > bound {
                return total;
            }
        }
        b0 += g;
    }
    total
}

/// The 8x8 transpose: `out[k]`'s lane `j` is `r[j]`'s lane `k`.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
pub(crate) unsafe fn transpose8(
    r: &[std::arch::x86_64::__m256; 8],
) -> [std::arch::x86_64::__m256; 8] {
    use std::arch::x86_64::*;
    let t0 = _mm256_unpacklo_ps(r[0], r[1]);
    let t1 = _mm256_unpackhi_ps(r[0], r[1]);
    let t2 = _mm256_unpacklo_ps(r[2], r[3]);
    let t3 = _mm256_unpackhi_ps(r[2], r[3]);
    let t4 = _mm256_unpacklo_ps(r[4], r[5]);
    let t5 = _mm256_unpackhi_ps(r[4], r[5]);
    let t6 = _mm256_unpacklo_ps(r[6], r[7]);
    let t7 = _mm256_unpackhi_ps(r[6], r[7]);
    let u0 = _mm256_shuffle_ps::<0x44>(t0, t2);
    let u1 = _mm256_shuffle_ps::<0xEE>(t0, t2);
    let u2 = _mm256_shuffle_ps::<0x44>(t1, t3);
    let u3 = _mm256_shuffle_ps::<0xEE>(t1, t3);
    let u4 = _mm256_shuffle_ps::<0x44>(t4, t6);
    let u5 = _mm256_shuffle_ps::<0xEE>(t4, t6);
    let u6 = _mm256_shuffle_ps::<0x44>(t5, t7);
    let u7 = _mm256_shuffle_ps::<0xEE>(t5, t7);
    [
        _mm256_permute2f128_ps::<0x20>(u0, u4),
        _mm256_permute2f128_ps::<0x20>(u1, u5),
        _mm256_permute2f128_ps::<0x20>(u2, u6),
        _mm256_permute2f128_ps::<0x20>(u3, u7),
        _mm256_permute2f128_ps::<0x31>(u0, u4),
        _mm256_permute2f128_ps::<0x31>(u1, u5),
        _mm256_permute2f128_ps::<0x31>(u2, u6),
        _mm256_permute2f128_ps::<0x31>(u3, u7),
    ]
}

/// [`Features::distance`]'s kernel: Σ over stored samples of `w2[s]`·Σ_channels (q − x)²,
/// `C` channels per sample (0: any count, read from `f`), with the early exit of
/// [`gather_kernel`] after every [`BLOCK`] dimensions' worth of samples. Deterministic:
/// one fixed summation order, no fused multiply-add, so the result does not depend on the
/// CPU features detected.
#[inline(always)]
fn weighted_kernel<const C: usize>(
    q: &[f32],
    w2: &[f32],
    offs: &[isize],
    f: &Features,
    base: usize,
    bound: f32,
) -> f32 {
    let c = if C == 0 { f.shape.channels } else { C };
    let ns = w2.len().min(offs.len()).min(q.len() / c);
    let per = (BLOCK / c).max(1);
    let src = &f.source[..];
    let base = base as isize;
    let mut total = 0.0f32;
    let mut s = 0;
    while s < ns {
        let e = (s + per).min(ns);
        let mut sum = 0.0f32;
        if C > 0 {
            let mut acc = [0.0f32; LANES];
            for t in s..e {
                let at = (base + offs[t]) as usize;
                let x = &src[at..at + C];
                let qq = &q[t * C..t * C + C];
                let w = w2[t];
                for k in 0..C {
                    let d = qq[k] - x[k];
                    acc[k] += w * (d * d);
                }
            }
            for v in &acc[..C.min(LANES)] {
                sum += v;
            }
        } else {
            for t in s..e {
                let at = (base + offs[t]) as usize;
                let x = &src[at..at + c];
                let qq = &q[t * c..t * c + c];
                let mut a = 0.0f32;
                for k in 0..c {
                    let d = qq[k] - x[k];
                    a += d * d;
                }
                sum += w2[t] * a;
            }
        }
        total += sum;
        if total > bound {
            return total;
        }
        s = e;
    }
    total
}

/// [`weighted_kernel`] for the channel count of `f`.
#[inline]
fn weighted_any(
    q: &[f32],
    w2: &[f32],
    offs: &[isize],
    f: &Features,
    base: usize,
    bound: f32,
) -> f32 {
    match f.shape.channels {
        8 => weighted_kernel::<8>(q, w2, offs, f, base, bound),
        4 => weighted_kernel::<4>(q, w2, offs, f, base, bound),
        _ => weighted_kernel::<0>(q, w2, offs, f, base, bound),
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn weighted_avx2(
    q: &[f32],
    w2: &[f32],
    offs: &[isize],
    f: &Features,
    base: usize,
    bound: f32,
) -> f32 {
    weighted_any(q, w2, offs, f, base, bound)
}

#[inline]
fn weighted_dispatch(
    q: &[f32],
    w2: &[f32],
    offs: &[isize],
    f: &Features,
    base: usize,
    bound: f32,
) -> f32 {
    #[cfg(target_arch = "x86_64")]
    {
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU supports AVX2 (checked just above).
            return unsafe { weighted_avx2(q, w2, offs, f, base, bound) };
        }
    }
    weighted_any(q, w2, offs, f, base, bound)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn dist_avx2(a: &[f32], b: &[f32], m: Option<&[f32]>, bound: f32) -> f32 {
    dist_kernel(a, b, m, bound)
}

#[inline]
fn dist_dispatch(a: &[f32], b: &[f32], m: Option<&[f32]>, bound: f32) -> f32 {
    #[cfg(target_arch = "x86_64")]
    {
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU supports AVX2 (checked just above).
            return unsafe { dist_avx2(a, b, m, bound) };
        }
    }
    dist_kernel(a, b, m, bound)
}

/// Squared Euclidean distance with early exit: once a block's partial sum exceeds `bound`
/// the (larger) partial sum is returned.
#[inline]
pub fn dist_bounded(a: &[f32], b: &[f32], bound: f32) -> f32 {
    dist_dispatch(a, b, None, bound)
}

/// Masked squared Euclidean distance (`m` is 0/1 per dimension) with early exit.
#[inline]
pub fn dist_masked_bounded(a: &[f32], m: &[f32], b: &[f32], bound: f32) -> f32 {
    dist_dispatch(a, b, Some(m), bound)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pyramid::Image;
    use crate::random::hash;

    #[test]
    fn weights_are_gaussian_and_normalised_per_block() {
        let s = Shape::new(9, 5, 3);
        assert_eq!(s.samples(), 106);
        assert_eq!(s.dim(), 318);
        assert_eq!(s.reach(), 4);
        let w: Vec<f64> = s
            .sample_scales()
            .iter()
            .map(|&x| (x as f64).powi(2))
            .collect();
        assert!((w[..81].iter().sum::<f64>() - 1.0).abs() < 1e-5);
        assert!((w[81..].iter().sum::<f64>() - 1.0).abs() < 1e-5);
        // Corner of the 9x9 block relative to its centre: exp(-32 / (2 * 2.25^2)).
        let ratio = w[0] / w[40];
        assert!((ratio - (-32.0f64 / 10.125).exp()).abs() < 1e-5, "{ratio}");
        let o = s.offsets();
        assert_eq!((o[0].dx, o[0].dy, o[0].coarse), (-4, -4, false));
        assert_eq!((o[1].dx, o[1].dy), (-3, -4));
        assert_eq!((o[81].dx, o[81].dy, o[81].coarse), (-2, -2, true));
    }

    #[test]
    fn pick_discards_matches_beyond_ten_percent() {
        let m = |i, d: f32| Match {
            index: i,
            dist2: d * d,
        };
        let best = [m(5, 1.0), m(6, 1.05), m(7, 1.1), m(8, 1.2), m(9, 3.0)];
        let mut seen = std::collections::BTreeSet::new();
        for k in 0..200u64 {
            seen.insert(pick(&best, hash(1, &[k])).index);
        }
        assert_eq!(seen.into_iter().collect::<Vec<_>>(), vec![5, 6, 7]);
        // Exact zero best distance keeps only exact ties.
        assert_eq!(pick(&[m(3, 0.0), m(4, 0.01)], 7).index, 3);
    }

    #[test]
    fn pruning_to_what_pick_can_choose_changes_no_choice() {
        // Random example and queries: the matches `pick` can choose (those within its
        // limit of the best) are the same with rerank's pick bound as with every candidate
        // measured in full into the eight best.
        let (w, h) = (24, 22);
        let mut img = Image::new(w, h, 2);
        for y in 0..h {
            for x in 0..w {
                let p = img.pixel_mut(x, y);
                p[0] = (hash(5, &[x as u64, y as u64]) % 1000) as f32 / 1e3;
                p[1] = (hash(6, &[x as u64, y as u64]) % 1000) as f32 / 1e3;
            }
        }
        let pyr = Pyramid::build(img, 2);
        let shape = Shape::new(5, 3, 2);
        let f = Features::build(&pyr, 0, shape, 0).unwrap();
        let all: Vec<u32> = (0..f.len() as u32).collect();
        let mut p = Prepared::default();
        for qi in 0..40u64 {
            let mut q = Query::new(shape);
            for s in 0..shape.samples() {
                if !hash(qi, &[s as u64, 9]).is_multiple_of(7) {
                    let v = [
                        (hash(qi, &[s as u64, 1]) % 1000) as f32 / 1e3,
                        (hash(qi, &[s as u64, 2]) % 1000) as f32 / 1e3,
                    ];
                    q.set(s, &v);
                }
            }
            f.prepare(&q, &mut p);
            let mut full = TopN::new();
            for &i in &all {
                let d = f.distance(&p, i as usize, f32::INFINITY);
                if d <= full.bound() {
                    full.push(Match { index: i, dist2: d });
                }
            }
            let mut pruned = TopN::new();
            f.rerank(&p, &all, &mut pruned);
            let limit = pick_limit(full.as_slice()[0].dist2);
            let within = |t: &TopN| -> Vec<u32> {
                t.as_slice()
                    .iter()
                    .take_while(|m| m.dist2 <= limit)
                    .map(|m| m.index)
                    .collect()
            };
            assert_eq!(within(&full), within(&pruned), "query {qi}");
            for key in 0..16 {
                assert_eq!(pick(full.as_slice(), key), pick(pruned.as_slice(), key));
            }
        }
    }

    #[test]
    fn the_eight_channel_kernel_is_the_portable_one_bit_for_bit() {
        // gather8_avx2 against gather_any: the same value for every feature, with no bound
        // and with bounds that stop it at every block (the value returned on an early exit
        // included), for neighbourhoods whose last block is full and partial.
        #[cfg(target_arch = "x86_64")]
        {
            if !std::arch::is_x86_feature_detected!("avx2") {
                return;
            }
            for (fine, coarse) in [(9, 5), (5, 3), (7, 0), (3, 3), (0, 5)] {
                let (w, h) = (26, 23);
                let mut img = Image::new(w, h, 8);
                for y in 0..h {
                    for x in 0..w {
                        for c in 0..8 {
                            let r = hash(11, &[x as u64, y as u64, c as u64]) % 100_000;
                            img.pixel_mut(x, y)[c] = r as f32 / 7e3 - 5.0;
                        }
                    }
                }
                let pyr = Pyramid::build(img, 2);
                let shape = Shape::new(fine, coarse, 8);
                let f = Features::build(&pyr, 0, shape, 0).unwrap();
                let n = f.len();
                for qi in [0, 3, n / 2, n - 1] {
                    let a = f.vector(qi);
                    for j in (0..n).step_by(7) {
                        let base = f.base(j);
                        let full = gather_any(&a, None, &f, base, f32::INFINITY);
                        // SAFETY: AVX2 checked above.
                        let fast = unsafe { gather8_avx2(&a, &f, base, f32::INFINITY) };
                        assert_eq!(full.to_bits(), fast.to_bits(), "{fine} {coarse} {qi} {j}");
                        for frac in [0.0, 0.01, 0.1, 0.3, 0.5, 0.7, 0.9, 0.999, 1.0] {
                            let b = full * frac;
                            let want = gather_any(&a, None, &f, base, b);
                            // SAFETY: AVX2 checked above.
                            let got = unsafe { gather8_avx2(&a, &f, base, b) };
                            assert_eq!(want.to_bits(), got.to_bits(), "bound {b}");
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn topn_keeps_the_eight_best_with_index_tie_break() {
        let mut t = TopN::new();
        for i in (0..20u32).rev() {
            t.push(Match {
                index: i,
                dist2: (i / 2) as f32,
            });
        }
        let idx: Vec<u32> = t.as_slice().iter().map(|m| m.index).collect();
        assert_eq!(idx, vec![0, 1, 2, 3, 4, 5, 6, 7]);
    }

    #[test]
    fn a_sparse_query_measures_its_present_samples_with_their_gains() {
        // A sparse query (gains set) reads only its present samples; its distance is the
        // dense one over the same samples with each weight times its gain.
        let (w, h) = (24, 22);
        let mut img = Image::new(w, h, 8);
        for y in 0..h {
            for x in 0..w {
                for c in 0..8 {
                    img.pixel_mut(x, y)[c] =
                        (hash(5, &[x as u64, y as u64, c as u64]) % 1000) as f32 / 1e3;
                }
            }
        }
        let pyr = Pyramid::build(img.clone(), 2);
        let shape = Shape::new(9, 5, 8);
        let f = Features::build(&pyr, 0, shape, 0).unwrap();
        let mut q = Query::new(shape);
        for s in 0..shape.samples() {
            let v: Vec<f32> = (0..8)
                .map(|c| (hash(9, &[s as u64, c]) % 1000) as f32 / 1e3)
                .collect();
            if s % 3 != 1 {
                q.set(s, &v);
            }
        }
        let gain: Vec<f32> = (0..shape.samples())
            .map(|s| 1.0 + (s % 4) as f32 * 0.5)
            .collect();
        let (mut dense, mut sparse) = (Prepared::default(), Prepared::default());
        f.prepare(&q, &mut dense);
        let mut qs = q.clone();
        qs.gain = gain.clone();
        f.prepare(&qs, &mut sparse);
        assert_eq!(sparse.offs.len(), q.present_count());
        for i in [0, 7, 100, f.len() - 1] {
            let d = f.distance(&sparse, i, f32::INFINITY);
            // The reference: Σ gain·w·(q − x)² over present samples.
            let v = f.vector(i);
            let mut want = 0.0f64;
            for (t, &s) in f.order.iter().enumerate() {
                if !q.present[s] {
                    continue;
                }
                let sc = f.scales[s] as f64;
                for c in 0..8 {
                    let x = v[t * 8 + c] as f64 / sc;
                    let e = q.values[s * 8 + c] as f64 - x;
                    want += gain[s] as f64 * sc * sc * e * e;
                }
            }
            assert!(
                (d as f64 - want).abs() <= 1e-4 * want.max(1.0),
                "{d} vs {want}"
            );
            // Without gains (all 1) it is the dense distance up to rounding.
            let dd = f.distance(&dense, i, f32::INFINITY);
            assert!(dd.is_finite() && dd >= 0.0);
        }
        // Prepared for distances only: the same distances, no projection vectors.
        let mut only = Prepared::default();
        f.prepare_distances(&qs, &mut only);
        assert!(only.v.is_empty() && only.mask.is_empty());
        f.prepare_distances(&q, &mut dense);
        for i in [0, 7, 100] {
            assert_eq!(
                f.distance(&only, i, f32::INFINITY),
                f.distance(&sparse, i, f32::INFINITY)
            );
        }
        f.prepare(&q, &mut dense);
        // A dense query prepared after a sparse one reads every stored sample again.
        f.prepare(&q, &mut sparse);
        assert!(sparse.offs.is_empty());
        assert_eq!(
            f.distance(&sparse, 5, f32::INFINITY),
            f.distance(&dense, 5, f32::INFINITY)
        );
    }

    #[test]
    fn features_hold_weighted_neighbourhoods_and_brute_force_finds_itself() {
        let (w, h) = (20, 18);
        let mut img = Image::new(w, h, 1);
        for y in 0..h {
            for x in 0..w {
                img.pixel_mut(x, y)[0] = (hash(3, &[x as u64, y as u64]) % 1000) as f32 / 1e3;
            }
        }
        let pyr = Pyramid::build(img.clone(), 2);
        let shape = Shape::new(5, 3, 1);
        let f = Features::build(&pyr, 0, shape, 0).unwrap();
        assert_eq!(f.margin, 2);
        assert_eq!((f.cols, f.rows), (16, 14));
        // Query = the neighbourhood of pixel (9, 7), raw values.
        let mut q = Query::new(shape);
        let mut buf = [0.0];
        for (s, o) in shape.offsets().iter().enumerate() {
            if o.coarse {
                pyr.level(1).bilinear(
                    (9.5) / 2.0 + o.dx as f32,
                    (7.5) / 2.0 + o.dy as f32,
                    &mut buf,
                );
                q.set(s, &buf);
            } else {
                q.set(s, img.pixel((9 + o.dx) as usize, (7 + o.dy) as usize));
            }
        }
        let mut p = Prepared::default();
        f.prepare(&q, &mut p);
        let mut top = TopN::new();
        f.brute_force(&p, &mut top);
        assert_eq!(f.pixel(top.as_slice()[0].index), (9, 7));
        assert_eq!(top.as_slice()[0].dist2, 0.0);
        // Nothing else is at distance 0 (what pick's tolerance keeps beside an exact
        // match); matches pushed before it was found may stay in the list.
        assert!(top.as_slice()[1..].iter().all(|m| m.dist2 > 0.0));
        // Dropping half the samples still finds it, with the masked path.
        for s in 0..shape.samples() / 2 {
            q.clear(s);
        }
        f.prepare(&q, &mut p);
        assert!(!p.complete);
        f.brute_force(&p, &mut top);
        assert_eq!(f.pixel(top.as_slice()[0].index), (9, 7));
        assert_eq!(f.nearest_index(9.9, 7.2), top.as_slice()[0].index);
        assert_eq!(f.pixel(f.nearest_index(-5.0, 100.0)), (2, 15));
    }
}
