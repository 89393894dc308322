//! Patch fidelity pfS (BRIEF, "Quality measures"; docs/eval.md has the full definition):
//! the 2D half — disc-blurred images, 7x7 windows on a pixel grid, the bank of example
//! windows with its exact nearest-window search — and the public result types.
//!
//! The same code measures a 2D image (a peer's PNG output), the lattice image of a flat
//! grid result, and the windows the surface method ([`super::surface`]) lays on a curved
//! surface: only where the window samples come from differs.
//!
//! Why the search is built this way: the brute-force nearest window costs
//! 147 multiply-adds × ~60,000 example windows per output window (9 GFLOP for 1024 windows
//! at three scales). Every example window is PCA-projected onto [`TREE_PCA`] orthonormal
//! directions plus one more coordinate, the norm of its residual outside them. For any
//! query q and window y, |q − y|² = |P(q − y)|² + |R(q − y)|² ≥ |Pq − Py|² + (|Rq| − |Ry|)²,
//! which is exactly the squared distance of the two 9-D points: a true lower bound (and
//! the same with 16 and 32 directions). The windows are stored in an order where
//! neighbours are alike, in groups of 64 with a box over their 9-D points; a query visits
//! the groups in increasing box bound, prunes window by window with the three bounds and
//! computes exact distances only for what survives, and stops once the next group's bound
//! reaches the best exact distance (no window left out can beat it). The residual
//! coordinate is what keeps this fast for windows far from every example window (noise):
//! their bound is dominated by the residual norm.

use crate::example::Example;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// The sample spacings S of BRIEF's pfS, in example pixels.
pub const PF_SCALES: [usize; 3] = [1, 4, 8];
/// Windows are `WINDOW` x `WINDOW` samples (BRIEF: 7x7).
pub const WINDOW: usize = 7;
/// Samples either side of the centre.
const HALF: isize = (WINDOW / 2) as isize;
/// Values per window: 7x7 samples x RGB.
pub const DIMS: usize = WINDOW * WINDOW * 3;
/// Texels (or pixels) drawn per measurement by `eval`.
pub const PF_SAMPLES: usize = 1024;
/// Texels drawn for the end-of-run summary of `synth` (cheaper; see docs/eval.md).
pub const PF_SUMMARY_SAMPLES: usize = 256;
/// Random pairs of example windows averaged for the denominator.
pub const PF_PAIRS: usize = 4096;
/// Seed of the texel draw and of the pairs (fixed: the measure is deterministic).
pub const PF_SEED: u64 = 0x9F5E_ED00_2026_0001;
/// Principal directions stored per example window for the scan's second bound.
pub const SCAN_DIMS: usize = 32;
/// Principal directions of the first bound and of the group boxes (plus the residual
/// norm: 9-D points).
pub const TREE_PCA: usize = 8;
const TREE_DIMS: usize = TREE_PCA + 1;
/// Example windows used to fit the PCA (evenly strided).
const PCA_WINDOWS: usize = 2048;
/// Block power iterations of the PCA.
const PCA_ITERATIONS: usize = 30;

/// Where the windows of a measurement were laid.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum PfMethod {
    /// A 2D image (`eval --image`): windows on its pixel grid.
    Image,
    /// A flat grid whose texel centres form a regular lattice aligned with the example's
    /// pixel grid: the maps assembled into one image, then as `Image`.
    Lattice,
    /// Windows walked over the surface along each texel's source directions.
    Surface,
}

/// One scale's figures.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PfScale {
    /// Sample spacing S in example pixels.
    pub s: usize,
    /// pfS = `nearest_mean_sq / pairs_mean_sq`; `None` when no window was laid or the
    /// example has no window at this S (or no variation).
    pub value: Option<f64>,
    /// Output windows laid (and compared).
    pub windows: usize,
    /// Drawn texels whose window could not be laid (leaves the surface or the image, or
    /// holds a non-finite colour).
    pub skipped: usize,
    /// Example windows at this S (every position where the window fits).
    pub example_windows: usize,
    /// Mean squared l2 distance of an output window to its nearest example window.
    pub nearest_mean_sq: Option<f64>,
    /// Mean squared l2 distance between random pairs of example windows.
    pub pairs_mean_sq: Option<f64>,
    /// Each drawn centre's own score, in [`PfDetail::centres`] order: its window's squared
    /// distance to the nearest example window over `pairs_mean_sq`, so that `value` is
    /// their mean; `None` where no window was laid (or nothing is measurable at this S).
    /// *Why*: pfS says how much structure is lost, this says where (`eval --windows`).
    #[serde(skip)]
    pub per_window: Vec<Option<f64>>,
}

/// How the pfS figures were obtained (the `pf_detail` object of `eval`'s JSON).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PfDetail {
    pub method: PfMethod,
    /// Texels (pixels) drawn as window centres.
    pub drawn: usize,
    /// Drawn texels whose directions came from the fallback rule (no usable least-squares
    /// fit of their source positions: no source channels, isolated texel, noise); always 0
    /// for `image` and `lattice`, where the window is the pixel grid.
    pub fallbacks: usize,
    /// Per S (1, 4, 8).
    pub scales: Vec<PfScale>,
    /// The drawn window centres: texel indices of the maps (`surface` and `lattice`) or
    /// pixel indices of the image (`image`), in the order of [`PfScale::per_window`].
    #[serde(skip)]
    pub centres: Vec<usize>,
}

/// pf1, pf4, pf8 of one result and how they were obtained.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PatchFidelity {
    pub pf1: Option<f64>,
    pub pf4: Option<f64>,
    pub pf8: Option<f64>,
    pub detail: PfDetail,
}

impl PatchFidelity {
    /// Assembles the result from per-scale figures (in [`PF_SCALES`] order).
    pub(crate) fn from_scales(
        method: PfMethod,
        centres: Vec<usize>,
        fallbacks: usize,
        scales: Vec<PfScale>,
    ) -> Self {
        let get = |s: usize| scales.iter().find(|x| x.s == s).and_then(|x| x.value);
        Self {
            pf1: get(1),
            pf4: get(4),
            pf8: get(8),
            detail: PfDetail {
                method,
                drawn: centres.len(),
                fallbacks,
                scales,
                centres,
            },
        }
    }

    /// An all-`None` result (nothing measurable).
    pub(crate) fn empty(method: PfMethod) -> Self {
        let scales = PF_SCALES
            .iter()
            .map(|&s| PfScale {
                s,
                value: None,
                windows: 0,
                skipped: 0,
                example_windows: 0,
                nearest_mean_sq: None,
                pairs_mean_sq: None,
                per_window: Vec::new(),
            })
            .collect();
        Self::from_scales(method, Vec::new(), 0, scales)
    }
}

/// Knobs of the measurement. The defaults are what `eval` uses.
#[derive(Clone, Debug, PartialEq)]
pub struct PfOptions {
    /// Texels (pixels) drawn as window centres.
    pub samples: usize,
    /// Seed of the draw and of the example pairs.
    pub seed: u64,
    /// Example window pairs of the denominator.
    pub pairs: usize,
    /// Use the surface method even where the lattice applies (for comparing the two).
    pub force_surface: bool,
}

impl Default for PfOptions {
    fn default() -> Self {
        Self {
            samples: PF_SAMPLES,
            seed: PF_SEED,
            pairs: PF_PAIRS,
            force_surface: false,
        }
    }
}

use crate::random::splitmix;

/// `count` distinct indices drawn uniformly from `candidates` (all of them, in order, when
/// there are no more): a partial Fisher–Yates shuffle with [`splitmix`], so the draw
/// depends only on the candidates and the seed.
pub(crate) fn draw(candidates: Vec<usize>, count: usize, seed: u64) -> Vec<usize> {
    if candidates.len() <= count {
        return candidates;
    }
    draw_from(candidates.len(), |i| candidates[i], count, seed)
}

/// [`draw`] from the virtual list `at(0), …, at(len − 1)`, without building it: the same
/// partial Fisher–Yates shuffle, the moved entries kept in a map. Why: the surface method
/// draws a few hundred centres among every texel, and the list of all of them (8 B per
/// texel, 4 M at N = 128 on Spot) cost more than the drawing.
pub(crate) fn draw_from(
    len: usize,
    at: impl Fn(usize) -> usize,
    count: usize,
    seed: u64,
) -> Vec<usize> {
    if len <= count {
        return (0..len).map(at).collect();
    }
    let mut moved: std::collections::HashMap<usize, usize> = Default::default();
    let get = |m: &std::collections::HashMap<usize, usize>, i: usize| {
        m.get(&i).copied().unwrap_or_else(|| at(i))
    };
    let mut state = seed;
    let mut out = Vec::with_capacity(count);
    for i in 0..count {
        let j = i + (splitmix(&mut state) % (len - i) as u64) as usize;
        let (vi, vj) = (get(&moved, i), get(&moved, j));
        out.push(vj);
        // Slot i is never read again; slot j now holds what was at i.
        moved.insert(j, vi);
    }
    out
}

/// Integer offsets of the disc of diameter `s` pixels: pixel centres within s/2 of the
/// centre, inclusive (S = 1: the pixel alone; S = 4: 13 pixels; S = 8: 49 pixels).
pub fn disc_offsets(s: usize) -> Vec<(isize, isize)> {
    let r = (s / 2) as isize;
    let r2 = (s * s) as f64 / 4.0;
    let mut v = Vec::new();
    for dy in -r..=r {
        for dx in -r..=r {
            if ((dx * dx + dy * dy) as f64) <= r2 {
                v.push((dx, dy));
            }
        }
    }
    v
}

/// Margin (pixels) a window centre keeps from the image border at spacing `s`: the outer
/// samples 3S away, and their discs (radius ⌊S/2⌋ in whole pixels) inside the image.
pub fn margin(s: usize) -> usize {
    HALF as usize * s + s / 2
}

/// An RGB image (linear), row-major, top row first.
#[derive(Clone, Debug, PartialEq)]
pub struct Rgb {
    pub width: usize,
    pub height: usize,
    pub px: Vec<[f32; 3]>,
}

impl Rgb {
    pub fn from_example(e: &Example) -> Self {
        Self {
            width: e.width,
            height: e.height,
            px: e.rgb.clone(),
        }
    }
}

/// The image blurred with the disc of diameter `s` where the disc fits (other pixels are
/// NaN: no window uses them). Each value is the mean over [`disc_offsets`], summed in
/// their fixed order.
pub fn disc_blur(img: &Rgb, s: usize) -> Vec<[f32; 3]> {
    let (w, h) = (img.width, img.height);
    if s <= 1 {
        return img.px.clone();
    }
    let offs = disc_offsets(s);
    let r = s / 2;
    let inv = 1.0 / offs.len() as f64;
    let mut out = vec![[f32::NAN; 3]; w * h];
    if w <= 2 * r || h <= 2 * r {
        return out;
    }
    out.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        if y < r || y + r >= h {
            return;
        }
        for (x, o) in row.iter_mut().enumerate().take(w - r).skip(r) {
            let mut acc = [0f64; 3];
            for &(dx, dy) in &offs {
                let p = img.px[(y as isize + dy) as usize * w + (x as isize + dx) as usize];
                for c in 0..3 {
                    acc[c] += p[c] as f64;
                }
            }
            *o = [
                (acc[0] * inv) as f32,
                (acc[1] * inv) as f32,
                (acc[2] * inv) as f32,
            ];
        }
    });
    out
}

/// The window centred at pixel (cx, cy) of a blurred image (the caller checks the margin).
#[inline]
fn image_window(blur: &[[f32; 3]], w: usize, cx: usize, cy: usize, s: usize, out: &mut [f32]) {
    let mut k = 0;
    for j in -HALF..=HALF {
        let y = (cy as isize + j * s as isize) as usize;
        for i in -HALF..=HALF {
            let x = (cx as isize + i * s as isize) as usize;
            out[k..k + 3].copy_from_slice(&blur[y * w + x]);
            k += 3;
        }
    }
}

/// Squared distance, stopping early (returning a value ≥ `bound`) once it exceeds `bound`.
#[cfg(test)]
fn dist_sq_bounded(a: &[f32], b: &[f32], bound: f32) -> f32 {
    let mut s = 0f32;
    for (ra, rb) in a.chunks_exact(WINDOW * 3).zip(b.chunks_exact(WINDOW * 3)) {
        for (x, y) in ra.iter().zip(rb) {
            let d = x - y;
            s += d * d;
        }
        if s >= bound {
            return s;
        }
    }
    s
}

/// The windows of one disc-blurred example at one S: every centre where the window fits.
struct Windows {
    s: usize,
    width: usize,
    blur: Vec<[f32; 3]>,
    /// First centre coordinate (the margin) and number of centres per row.
    m: usize,
    nx: usize,
    count: usize,
}

impl Windows {
    #[inline]
    fn centre(&self, j: usize) -> (usize, usize) {
        (self.m + j % self.nx, self.m + j / self.nx)
    }

    #[inline]
    fn window(&self, j: usize, out: &mut [f32]) {
        let (cx, cy) = self.centre(j);
        image_window(&self.blur, self.width, cx, cy, self.s, out);
    }

    /// Exact squared distance of `q` to window `j`, early exit above `bound` after any
    /// row. Summed in a fixed order (per channel and sample parity, then per row), so the
    /// value depends only on the two windows.
    #[inline]
    fn exact(&self, q: &[f32], j: usize, bound: f32) -> f32 {
        let (cx, cy) = self.centre(j);
        let s = self.s as isize;
        let w = self.width;
        let mut total = 0f32;
        let mut k = 0;
        for jj in -HALF..=HALF {
            let y = (cy as isize + jj * s) as usize;
            let row = &self.blur[y * w..(y + 1) * w];
            let mut acc = [[0f32; 3]; 2];
            for (n, ii) in (-HALF..=HALF).enumerate() {
                let p = &row[(cx as isize + ii * s) as usize];
                let a = &mut acc[n & 1];
                for c in 0..3 {
                    let d = q[k + c] - p[c];
                    a[c] += d * d;
                }
                k += 3;
            }
            total += (acc[0][0] + acc[1][0]) + (acc[0][1] + acc[1][1]) + (acc[0][2] + acc[1][2]);
            if total >= bound {
                return total;
            }
        }
        total
    }
}

/// All example windows at one S, with the exact nearest-window search (module docs).
pub(crate) struct Bank {
    win: Windows,
    /// The PCA and the windows' projections, shared with the analyses that keep them
    /// (a 2048² example's bank is ~0.6 GB: a copy per bank raised the peak by as much).
    core: std::sync::Arc<BankCore>,
    /// Per group of [`GROUP_BLOCKS`] consecutive blocks, the box of its windows' first
    /// stage ([`TREE_DIMS`] rows): the lower bound of a whole group ([`group_bound`]).
    groups: Vec<GroupBox>,
}

/// Windows per block of the scan (one SIMD-friendly row of lanes).
const LANES: usize = 8;
/// Values per window in the scan: [`SCAN_DIMS`] coordinates and one residual norm per
/// stage.
const ROWS: usize = SCAN_DIMS + STAGES.len();
/// The scan's stages: coordinates up to this many, then the residual norm outside them.
const STAGES: [usize; 3] = [TREE_PCA, 16, SCAN_DIMS];
/// Blocks per group of the scan. Why groups: the per-lane bounds of a block cost about as
/// much as one box bound, so a bound per block would save nothing; a box over 8 blocks
/// of similar windows ([`coherent_order`]) skips 64 windows for the price of 8 lanes.
const GROUP_BLOCKS: usize = 8;
/// Windows per group.
const GROUP_WINDOWS: usize = GROUP_BLOCKS * LANES;

/// Lowest and highest value of each first-stage row ([`TREE_DIMS`]) over a group's windows.
#[derive(Clone, Copy, Debug)]
struct GroupBox {
    lo: [f32; TREE_DIMS],
    hi: [f32; TREE_DIMS],
}
/// [`DIMS`] rounded up to a multiple of 8 (vectorisable dot products).
const DIMS_PAD: usize = DIMS.div_ceil(8) * 8;
/// A bound only prunes when it exceeds the best distance by this relative margin, so
/// f32 rounding of the projections never prunes the true nearest window.
const SAFETY: f32 = 1.0 - 1e-4;

/// Row of coordinate `k` (`k < SCAN_DIMS`) or of stage `st`'s residual (`SCAN_DIMS + st`)
/// in a block: each stage's new coordinates, then its residual.
const fn row_order(v: usize) -> usize {
    if v >= SCAN_DIMS {
        let st = v - SCAN_DIMS;
        STAGES[st] + st
    } else {
        let mut st = 0;
        while v >= STAGES[st] {
            st += 1;
        }
        v + st
    }
}

impl Bank {
    /// The bank of `example` at spacing `s`; `None` when no window fits the example (or
    /// its values are not finite).
    pub fn build(example: &Rgb, s: usize, pairs: usize, seed: u64) -> Option<Self> {
        let win = Self::windows(example, s)?;
        let core = BankCore::compute(&win, pairs, seed)?;
        Self::assemble(win, std::sync::Arc::new(core))
    }

    /// [`Bank::build`] through `analyses` (memory, the disk cache, else built and saved
    /// under kind [`BANK_KIND`]): the same bank, bit for bit. Its source is returned.
    pub fn build_in(
        example: &Rgb,
        s: usize,
        pairs: usize,
        seed: u64,
        analyses: &crate::synth::Analyses,
    ) -> Option<Self> {
        let win = Self::windows(example, s)?;
        let key = BankCore::key(example, s, pairs, seed);
        let core = analyses
            .try_get(BANK_KIND, key, || {
                BankCore::compute(&win, pairs, seed).ok_or(())
            })
            .ok()?;
        Self::assemble(win, core)
    }

    /// The windows of `example` at spacing `s` (`None`: none fits).
    fn windows(example: &Rgb, s: usize) -> Option<Windows> {
        let m = margin(s);
        let (w, h) = (example.width, example.height);
        if w <= 2 * m || h <= 2 * m {
            return None;
        }
        let (nx, ny) = (w - 2 * m, h - 2 * m);
        Some(Windows {
            s,
            width: w,
            blur: disc_blur(example, s),
            m,
            nx,
            count: nx * ny,
        })
    }

    /// The bank from its windows and computed part (whose blocks are already in
    /// [`coherent_order`]): the boxes of their groups.
    fn assemble(win: Windows, core: std::sync::Arc<BankCore>) -> Option<Self> {
        let padded = win.count.div_ceil(LANES) * LANES;
        if core.blocks.len() != win.count.div_ceil(LANES) * ROWS || core.slots.len() != padded {
            return None;
        }
        let groups = group_boxes(&core.blocks, &core.slots);
        Some(Self { win, core, groups })
    }
}

/// The windows in an order where consecutive ones are alike, so that the boxes of
/// [`GroupBox`] are small: median splits of their first-stage values along the widest
/// side, at multiples of [`GROUP_WINDOWS`] (then of [`LANES`] inside a group), down to
/// blocks. Padded with `u32::MAX` to whole blocks. Any order gives the same distances (the
/// search takes a minimum); this one only makes the bounds prune sooner.
fn coherent_order(points: &[[f32; TREE_DIMS]]) -> Vec<u32> {
    // The splits move the points with their indices (one array of 40-byte items), so
    // each pass over a part streams through memory: partitioning indices into a separate
    // array of points read a random point per comparison, and for the ~4 M windows of a
    // 2048² example the order took most of the end-of-run pf summary (~20 s).
    let mut items: Vec<Item> = points
        .iter()
        .enumerate()
        .map(|(i, p)| Item { p: *p, i: i as u32 })
        .collect();
    split_coherent(&mut items);
    let mut order: Vec<u32> = items.iter().map(|it| it.i).collect();
    order.resize(points.len().div_ceil(LANES) * LANES, u32::MAX);
    order
}

/// A window's first-stage values with its index ([`coherent_order`]).
#[derive(Clone, Copy)]
struct Item {
    p: [f32; TREE_DIMS],
    i: u32,
}

fn split_coherent(items: &mut [Item]) {
    if items.len() <= LANES {
        return;
    }
    let unit = if items.len() > GROUP_WINDOWS {
        GROUP_WINDOWS
    } else {
        LANES
    };
    let (mut lo, mut hi) = ([f32::MAX; TREE_DIMS], [f32::MIN; TREE_DIMS]);
    for it in items.iter() {
        for (k, &v) in it.p.iter().enumerate() {
            lo[k] = lo[k].min(v);
            hi[k] = hi[k].max(v);
        }
    }
    let axis = (0..TREE_DIMS)
        .max_by(|&a, &b| (hi[a] - lo[a]).total_cmp(&(hi[b] - lo[b])))
        .unwrap_or(0);
    let mid = (items.len() / 2).div_ceil(unit) * unit;
    items.select_nth_unstable_by(mid, |a, b| {
        a.p[axis].total_cmp(&b.p[axis]).then(a.i.cmp(&b.i))
    });
    let (left, right) = items.split_at_mut(mid);
    // The two halves are independent: split side by side while they are large.
    if left.len() > 1 << 15 {
        rayon::join(|| split_coherent(left), || split_coherent(right));
    } else {
        split_coherent(left);
        split_coherent(right);
    }
}

/// Whether `slots` names every window `0..n` exactly once, followed only by padding
/// (`u32::MAX`, fewer than [`LANES`] of it): a saved order that left a window out would
/// make the search miss it.
fn is_padded_permutation(slots: &[u32]) -> bool {
    let n = slots.iter().take_while(|&&j| j != u32::MAX).count();
    if slots.len() - n >= LANES || slots[n..].iter().any(|&j| j != u32::MAX) {
        return false;
    }
    let mut seen = vec![false; n];
    slots[..n]
        .iter()
        .all(|&j| (j as usize) < n && !std::mem::replace(&mut seen[j as usize], true))
}

/// The [`GroupBox`] of every [`GROUP_BLOCKS`] consecutive blocks (padding lanes left out).
fn group_boxes(blocks: &[[f32; LANES]], slots: &[u32]) -> Vec<GroupBox> {
    blocks
        .chunks(GROUP_BLOCKS * ROWS)
        .zip(slots.chunks(GROUP_WINDOWS))
        .map(|(grp, sl)| {
            let mut g = GroupBox {
                lo: [f32::INFINITY; TREE_DIMS],
                hi: [f32::NEG_INFINITY; TREE_DIMS],
            };
            for (blk, bs) in grp.chunks_exact(ROWS).zip(sl.chunks_exact(LANES)) {
                for (l, _) in bs.iter().enumerate().filter(|(_, &j)| j != u32::MAX) {
                    for ((lo, hi), row) in g.lo.iter_mut().zip(&mut g.hi).zip(blk) {
                        *lo = lo.min(row[l]);
                        *hi = hi.max(row[l]);
                    }
                }
            }
            g
        })
        .collect()
}

/// Lower bound of the first-stage bound of every window of a group: per row the gap from
/// the query's value to the box, summed as the lanes sum theirs ([`Bank::scan_block`]).
/// Each gap is at most the lane's |difference| in f32 too (subtraction and rounding are
/// monotonic), so the sums and the products keep the order: a group whose bound reaches
/// the best distance holds no window that the lanes would have let through.
#[inline]
fn group_bound(g: &GroupBox, qr: &[f32; ROWS]) -> f32 {
    let gap = |r: usize| (g.lo[r] - qr[r]).max(qr[r] - g.hi[r]).max(0.0);
    let mut coord = 0f32;
    for r in 0..TREE_PCA {
        let d = gap(r);
        coord += d * d;
    }
    let d = gap(TREE_PCA);
    (coord + d * d) * SAFETY
}

/// What [`Bank::build`] computes from the example windows (the PCA, every window's
/// projection, the denominator), saved in the analysis cache: on the end-of-run pf summary
/// of a small mesh it was most of the summary's time (three banks of ~50 k windows each
/// for a 256² example), and it depends on the example alone.
#[derive(Clone, Debug)]
pub(crate) struct BankCore {
    mean: Vec<f32>,
    /// [`SCAN_DIMS`] orthonormal rows of [`DIMS_PAD`] values (zero-padded), leading
    /// principal directions first.
    basis: Vec<f32>,
    /// The windows' [`ROWS`] values in blocks of [`LANES`] windows, row-major inside a
    /// block (one row = one value of 8 windows), rows in [`row_order`] order, the windows
    /// in [`coherent_order`] — the layout [`Bank::search`] scans. Padding windows of the
    /// last block hold huge values, so no bound lets them through.
    blocks: Vec<[f32; LANES]>,
    /// The window in each lane of `blocks` (`u32::MAX` for padding). Saved with the
    /// blocks: the order costs more than the projections for a large example, and a cache
    /// hit should cost neither.
    slots: Vec<u32>,
    /// Mean squared distance between random pairs of windows.
    pairs_mean_sq: f64,
}

/// Largest bank (bytes of its projections) saved in the analysis cache. Measured on Spot
/// N = 32 (busy machine): a 1024² example (three banks of ~145 MB) takes the summary 5.3 s
/// without the cache, 6.6 s when saving and 2.1 s from the cache; a 2048² one (~570 MB
/// each) 17.9 s, 30.0 s and 6.7 s.
const MAX_SAVED_BANK: usize = 256 << 20;

/// Cache kind of `BankCore`.
pub const BANK_KIND: &str = "pf-bank";
/// Bump when [`BankCore::compute`] changes what it computes (2: the blocks saved in
/// [`coherent_order`], with their slots).
const BANK_VERSION: u64 = 2;

impl BankCore {
    /// The cache key: the example's pixels, the spacing, the denominator's draw, and the
    /// constants that shape the windows and their projection.
    fn key(example: &Rgb, s: usize, pairs: usize, seed: u64) -> crate::cache::Key {
        let px: Vec<f32> = example.px.iter().flatten().copied().collect();
        crate::cache::KeyBuilder::new(BANK_KIND)
            .u64(BANK_VERSION)
            .u64(example.width as u64)
            .u64(example.height as u64)
            .f32s(&px)
            .u64(s as u64)
            .u64(pairs as u64)
            .u64(seed)
            .u64(WINDOW as u64)
            .u64(SCAN_DIMS as u64)
            .u64(TREE_PCA as u64)
            .u64(PCA_WINDOWS as u64)
            .u64(PCA_ITERATIONS as u64)
            .finish()
    }

    fn compute(win: &Windows, pairs: usize, seed: u64) -> Option<Self> {
        let s = win.s;
        let (mean, basis) = fit_pca(win);
        let count = win.count;
        // The order first, from each window's first stage alone, then every window's
        // projection written straight into its place in that order: no reordering pass
        // over the blocks (serial, a random gather per window: for the ~4 M windows of a
        // 2048² example it took longer than all the projections) and no second copy of them.
        let points: Vec<[f32; TREE_DIMS]> = (0..count)
            .into_par_iter()
            .map_init(
                || (vec![0f32; DIMS], [0f32; ROWS]),
                |(buf, vals), j| {
                    win.window(j, buf);
                    project_rows(&mean, &basis, buf, TREE_PCA, vals);
                    // Rows 0..TREE_PCA are the first coordinates, then their residual.
                    std::array::from_fn(|k| vals[if k < TREE_PCA { k } else { SCAN_DIMS }])
                },
            )
            .collect();
        let slots = coherent_order(&points);
        drop(points);
        let nblocks = count.div_ceil(LANES);
        let mut blocks = vec![[1e30f32; LANES]; nblocks * ROWS];
        blocks
            .par_chunks_mut(ROWS)
            .zip(slots.par_chunks(LANES))
            .for_each_init(
                || (vec![0f32; DIMS], [0f32; ROWS]),
                |(buf, vals), (blk, lanes)| {
                    for (l, &j) in lanes.iter().enumerate().filter(|(_, &j)| j != u32::MAX) {
                        win.window(j as usize, buf);
                        project(&mean, &basis, buf, vals);
                        for (v, &x) in vals.iter().enumerate() {
                            blk[row_order(v)][l] = x;
                        }
                    }
                },
            );
        if blocks.iter().flatten().any(|v| !v.is_finite()) {
            return None;
        }
        // Denominator: random pairs of distinct windows.
        let mut state = seed ^ 0x0A11_BA1C_0000_0000 ^ s as u64;
        let mut sum = 0f64;
        let (mut a, mut b) = (vec![0f32; DIMS], vec![0f32; DIMS]);
        let mut n = 0usize;
        for _ in 0..pairs {
            let i = (splitmix(&mut state) % count as u64) as usize;
            let mut j = (splitmix(&mut state) % count as u64) as usize;
            if j == i {
                j = (i + 1) % count;
            }
            win.window(i, &mut a);
            win.window(j, &mut b);
            sum += a
                .iter()
                .zip(&b)
                .map(|(x, y)| ((x - y) as f64).powi(2))
                .sum::<f64>();
            n += 1;
        }
        let pairs_mean_sq = if n > 0 { sum / n as f64 } else { 0.0 };
        Some(Self {
            mean,
            basis,
            blocks,
            slots,
            pairs_mean_sq,
        })
    }
}

impl crate::cache::Persist for BankCore {
    fn save(&self, w: &mut crate::cache::Writer) {
        w.f32s(&self.mean);
        w.f32s(&self.basis);
        w.f32s(self.blocks.as_flattened());
        w.u32s(&self.slots);
        w.f64(self.pairs_mean_sq);
    }

    /// Not for a large example: a 2048² example's three banks are ~1.7 GB, which took
    /// longer to write (a first run's summary +12 s) than to compute, and the disk
    /// besides — and kept in memory for the process's life they held its peak. Up to
    /// [`MAX_SAVED_BANK`] (about a 1350² example) a bank is saved and kept.
    fn worth_saving(&self) -> bool {
        std::mem::size_of_val(self.blocks.as_slice()) <= MAX_SAVED_BANK
    }

    fn load(r: &mut crate::cache::Reader<'_>) -> Option<Self> {
        let mean = r.f32s()?;
        let basis = r.f32s()?;
        let blocks: Vec<[f32; LANES]> = r.f32_arrays()?;
        let slots = r.u32s()?;
        let pairs_mean_sq = r.f64()?;
        if mean.len() != DIMS
            || basis.len() != SCAN_DIMS * DIMS_PAD
            || !blocks.len().is_multiple_of(ROWS)
            || slots.len() != blocks.len() / ROWS * LANES
            || !r.at_end()
            || !pairs_mean_sq.is_finite()
            || mean
                .iter()
                .chain(&basis)
                .chain(blocks.as_flattened())
                .any(|v| !v.is_finite())
            || !is_padded_permutation(&slots)
        {
            return None;
        }
        Some(Self {
            mean,
            basis,
            blocks,
            slots,
            pairs_mean_sq,
        })
    }
}

impl Bank {
    /// Number of example windows.
    pub fn len(&self) -> usize {
        self.win.count
    }

    /// Mean squared distance between random pairs of windows.
    pub fn pairs_mean_sq(&self) -> f64 {
        self.core.pairs_mean_sq
    }

    /// The query's values in block row order.
    fn query_rows(&self, q: &[f32]) -> [f32; ROWS] {
        let mut vals = [0f32; ROWS];
        project(&self.core.mean, &self.core.basis, q, &mut vals);
        let mut rows = [0f32; ROWS];
        for (v, &x) in vals.iter().enumerate() {
            rows[row_order(v)] = x;
        }
        rows
    }

    /// The squared distance of one query to its nearest window: the groups in increasing
    /// order of their box bound ([`group_bound`]), each group's blocks scanned
    /// ([`Bank::scan_block`]), until the next group's bound reaches the best distance —
    /// then no window left can be nearer. Visiting the nearest groups first is what makes
    /// the best distance small early, so that most groups are never opened.
    fn search(&self, q: &[f32], qr: &[f32; ROWS]) -> f32 {
        let mut order: Vec<(f32, u32)> = self
            .groups
            .iter()
            .enumerate()
            .map(|(g, gb)| (group_bound(gb, qr), g as u32))
            .collect();
        order.sort_unstable_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        let group_rows = GROUP_BLOCKS * ROWS;
        let mut best = f32::INFINITY;
        for &(bound, g) in &order {
            if bound >= best {
                break;
            }
            let g = g as usize;
            let end = ((g + 1) * group_rows).min(self.core.blocks.len());
            let blocks = &self.core.blocks[g * group_rows..end];
            for (k, blk) in blocks.chunks_exact(ROWS).enumerate() {
                self.scan_block(g * GROUP_BLOCKS + k, blk, q, qr, &mut best);
            }
        }
        best
    }

    /// One query against block `b`: each window pruned by the first of its stages' bounds
    /// that reaches the best distance; exact distances for what survives.
    #[inline]
    fn scan_block(
        &self,
        b: usize,
        blk: &[[f32; LANES]],
        q: &[f32],
        qr: &[f32; ROWS],
        best: &mut f32,
    ) {
        let bound = *best;
        let mut coord = [0f32; LANES];
        let mut alive = [0f32; LANES];
        let mut r0 = 0;
        let mut start = 0;
        for &end in &STAGES {
            let n = end - start;
            for (row, &qv) in blk[r0..r0 + n].iter().zip(&qr[r0..r0 + n]) {
                for l in 0..LANES {
                    let d = row[l] - qv;
                    coord[l] += d * d;
                }
            }
            let (row, qv) = (&blk[r0 + n], qr[r0 + n]);
            let mut lb = [0f32; LANES];
            for l in 0..LANES {
                let d = row[l] - qv;
                lb[l] = (coord[l] + d * d) * SAFETY;
            }
            // alive: the smallest bound over the stages so far (pruned ≥ bound).
            let mut any = false;
            for l in 0..LANES {
                alive[l] = if start == 0 {
                    lb[l]
                } else {
                    alive[l].max(lb[l])
                };
                any |= alive[l] < bound;
            }
            if !any {
                return;
            }
            r0 += n + 1;
            start = end;
        }
        let slots = &self.core.slots[b * LANES..(b + 1) * LANES];
        for (&a, &j) in alive.iter().zip(slots) {
            if a < *best && j != u32::MAX {
                let d = self.win.exact(q, j as usize, *best);
                if d < *best {
                    *best = d;
                }
            }
        }
    }

    /// Squared distance of each query to its nearest example window, exact up to f32
    /// rounding ([`Bank::search`]).
    pub fn nearest_all(&self, qs: &[&[f32]]) -> Vec<f32> {
        qs.par_iter()
            .map(|q| self.search(q, &self.query_rows(q)))
            .collect()
    }

    /// One query ([`Bank::nearest_all`] of one).
    pub fn nearest_sq(&self, q: &[f32]) -> f32 {
        self.nearest_all(&[q])[0]
    }
}

/// Mean and [`SCAN_DIMS`] leading principal directions of an even subsample of the
/// windows (block power iteration from a fixed start; any orthonormal basis keeps the
/// bounds valid, so convergence only affects speed).
fn fit_pca(win: &Windows) -> (Vec<f32>, Vec<f32>) {
    let step = win.count.div_ceil(PCA_WINDOWS).max(1);
    let mut buf = vec![0f32; DIMS];
    let mut rows: Vec<[f64; DIMS]> = Vec::with_capacity(PCA_WINDOWS + 1);
    for j in (0..win.count).step_by(step) {
        win.window(j, &mut buf);
        let mut r = [0f64; DIMS];
        for (d, v) in r.iter_mut().zip(&buf) {
            *d = *v as f64;
        }
        rows.push(r);
    }
    let n = rows.len() as f64;
    let mut mean = vec![0f64; DIMS];
    for r in &rows {
        for (m, v) in mean.iter_mut().zip(r) {
            *m += v;
        }
    }
    for m in &mut mean {
        *m /= n;
    }
    for r in &mut rows {
        for (v, m) in r.iter_mut().zip(&mean) {
            *v -= m;
        }
    }
    // Covariance (upper triangle), in fixed-size chunks summed in order.
    let parts: Vec<Vec<f64>> = rows
        .par_chunks(256)
        .map(|rs| {
            let mut c = vec![0f64; DIMS * DIMS];
            for r in rs {
                for i in 0..DIMS {
                    let ri = r[i];
                    let row = &mut c[i * DIMS..(i + 1) * DIMS];
                    for j in i..DIMS {
                        row[j] += ri * r[j];
                    }
                }
            }
            c
        })
        .collect();
    let mut cov = vec![0f64; DIMS * DIMS];
    for p in &parts {
        for (c, v) in cov.iter_mut().zip(p) {
            *c += v;
        }
    }
    for i in 0..DIMS {
        for j in 0..i {
            cov[i * DIMS + j] = cov[j * DIMS + i];
        }
    }
    let mut basis: Vec<[f64; DIMS]> = (0..SCAN_DIMS)
        .map(|k| {
            let mut v = [0f64; DIMS];
            let mut st = 0x00C0_FFEE_u64 + k as u64;
            for x in v.iter_mut() {
                *x = (splitmix(&mut st) >> 11) as f64 / (1u64 << 53) as f64 - 0.5;
            }
            v
        })
        .collect();
    orthonormalise(&mut basis);
    for _ in 0..PCA_ITERATIONS {
        for v in basis.iter_mut() {
            let mut nv = [0f64; DIMS];
            for (i, o) in nv.iter_mut().enumerate() {
                let row = &cov[i * DIMS..(i + 1) * DIMS];
                *o = row.iter().zip(v.iter()).map(|(a, b)| a * b).sum();
            }
            *v = nv;
        }
        orthonormalise(&mut basis);
    }
    let mut flat = vec![0f32; SCAN_DIMS * DIMS_PAD];
    for (row, b) in flat.chunks_exact_mut(DIMS_PAD).zip(&basis) {
        for (o, &x) in row.iter_mut().zip(b.iter()) {
            *o = x as f32;
        }
    }
    (mean.iter().map(|&m| m as f32).collect(), flat)
}

/// A window's [`ROWS`] values in natural order: the [`SCAN_DIMS`] coordinates, then per
/// stage the residual norm outside its coordinates. Coordinates are f32 dot products in
/// eight fixed lanes (vectorisable, deterministic); residual norms come from f64 sums.
fn project(mean: &[f32], basis: &[f32], q: &[f32], out: &mut [f32; ROWS]) {
    project_rows(mean, basis, q, SCAN_DIMS, out)
}

/// [`project`] on the first `rows` basis rows only (a multiple of a stage's end): the
/// same values there, the rest of `out` left as it was.
fn project_rows(mean: &[f32], basis: &[f32], q: &[f32], rows: usize, out: &mut [f32; ROWS]) {
    let mut c = [0f32; DIMS_PAD];
    let mut total = 0f64;
    for (i, o) in c.iter_mut().take(DIMS).enumerate() {
        *o = q[i] - mean[i];
        total += (*o as f64) * (*o as f64);
    }
    let mut kept = 0f64;
    let mut stage = 0;
    for (k, b) in basis.chunks_exact(DIMS_PAD).take(rows).enumerate() {
        let mut acc = [0f32; 8];
        for (bx, cx) in b.chunks_exact(8).zip(c.chunks_exact(8)) {
            for l in 0..8 {
                acc[l] += bx[l] * cx[l];
            }
        }
        let p = ((acc[0] + acc[1]) + (acc[2] + acc[3])) + ((acc[4] + acc[5]) + (acc[6] + acc[7]));
        out[k] = p;
        kept += (p as f64) * (p as f64);
        if k + 1 == STAGES[stage] {
            out[SCAN_DIMS + stage] = (total - kept).max(0.0).sqrt() as f32;
            stage += 1;
        }
    }
}

/// Modified Gram–Schmidt; a vector that vanishes is replaced by a unit axis.
fn orthonormalise(vs: &mut [[f64; DIMS]]) {
    for i in 0..vs.len() {
        for j in 0..i {
            let d: f64 = vs[i].iter().zip(&vs[j]).map(|(a, b)| a * b).sum();
            let vj = vs[j];
            for (a, b) in vs[i].iter_mut().zip(&vj) {
                *a -= d * b;
            }
        }
        let n = vs[i].iter().map(|a| a * a).sum::<f64>().sqrt();
        if n > 1e-300 {
            for a in vs[i].iter_mut() {
                *a /= n;
            }
        } else {
            let mut axis = [0f64; DIMS];
            axis[i % DIMS] = 1.0;
            vs[i] = axis;
            // Re-orthogonalise the replacement once against the earlier vectors.
            for j in 0..i {
                let d: f64 = vs[i].iter().zip(&vs[j]).map(|(a, b)| a * b).sum();
                let vj = vs[j];
                for (a, b) in vs[i].iter_mut().zip(&vj) {
                    *a -= d * b;
                }
            }
            let n = vs[i].iter().map(|a| a * a).sum::<f64>().sqrt().max(1e-300);
            for a in vs[i].iter_mut() {
                *a /= n;
            }
        }
    }
}

/// Compares output windows against the example at spacing `s`: `windows[k]` is `None`
/// for a drawn texel whose window was not laid.
pub(crate) fn score_scale(
    s: usize,
    windows: &[Option<Vec<f32>>],
    example: &Rgb,
    opts: &PfOptions,
    banks: Option<&crate::synth::Analyses>,
) -> PfScale {
    // The windows laid, with their places among the drawn centres.
    let (at, laid): (Vec<usize>, Vec<&Vec<f32>>) = windows
        .iter()
        .enumerate()
        .filter_map(|(k, w)| w.as_ref().map(|w| (k, w)))
        .filter(|(_, w)| w.iter().all(|v| v.is_finite()))
        .unzip();
    let skipped = windows.len() - laid.len();
    let mut out = PfScale {
        s,
        value: None,
        windows: laid.len(),
        skipped,
        example_windows: 0,
        nearest_mean_sq: None,
        pairs_mean_sq: None,
        per_window: vec![None; windows.len()],
    };
    let bank = match banks {
        Some(a) => Bank::build_in(example, s, opts.pairs, opts.seed, a),
        None => Bank::build(example, s, opts.pairs, opts.seed),
    };
    let Some(bank) = bank else {
        return out;
    };
    out.example_windows = bank.len();
    out.pairs_mean_sq = Some(bank.pairs_mean_sq());
    if laid.is_empty() {
        return out;
    }
    let qs: Vec<&[f32]> = laid.iter().map(|w| w.as_slice()).collect();
    let nearest = bank.nearest_all(&qs);
    let num = nearest.iter().map(|&d| d.max(0.0) as f64).sum::<f64>() / nearest.len() as f64;
    out.nearest_mean_sq = Some(num);
    if bank.pairs_mean_sq() > 0.0 {
        out.value = Some(num / bank.pairs_mean_sq());
        for (&k, &d) in at.iter().zip(&nearest) {
            out.per_window[k] = Some(d.max(0.0) as f64 / bank.pairs_mean_sq());
        }
    }
    out
}

/// pf1/pf4/pf8 of a 2D image against an example: centres drawn among the finite pixels,
/// windows on the pixel grid of the disc-blurred image.
pub fn image_patch_fidelities(image: &Rgb, example: &Rgb, opts: &PfOptions) -> PatchFidelity {
    image_patch_fidelities_as(image, example, opts, PfMethod::Image, None)
}

pub(crate) fn image_patch_fidelities_as(
    image: &Rgb,
    example: &Rgb,
    opts: &PfOptions,
    method: PfMethod,
    banks: Option<&crate::synth::Analyses>,
) -> PatchFidelity {
    let (w, h) = (image.width, image.height);
    let candidates: Vec<usize> = (0..w * h)
        .filter(|&i| image.px[i].iter().all(|c| c.is_finite()))
        .collect();
    let drawn = draw(candidates, opts.samples, opts.seed);
    let scales = PF_SCALES
        .iter()
        .map(|&s| {
            let blur = disc_blur(image, s);
            let m = margin(s);
            let windows: Vec<Option<Vec<f32>>> = drawn
                .iter()
                .map(|&i| {
                    let (x, y) = (i % w, i / w);
                    if x < m || y < m || x + m >= w || y + m >= h {
                        return None;
                    }
                    let mut v = vec![0f32; DIMS];
                    image_window(&blur, w, x, y, s, &mut v);
                    Some(v)
                })
                .collect();
            score_scale(s, &windows, example, opts, banks)
        })
        .collect();
    PatchFidelity::from_scales(method, drawn, 0, scales)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn noise(w: usize, h: usize, seed: u64) -> Rgb {
        let mut st = seed;
        let px = (0..w * h)
            .map(|_| {
                let mut c = [0f32; 3];
                for v in &mut c {
                    *v = (splitmix(&mut st) >> 40) as f32 / (1u64 << 24) as f32;
                }
                c
            })
            .collect();
        Rgb {
            width: w,
            height: h,
            px,
        }
    }

    #[test]
    fn discs_have_the_documented_sizes() {
        assert_eq!(disc_offsets(1).len(), 1);
        assert_eq!(disc_offsets(4).len(), 13);
        assert_eq!(disc_offsets(8).len(), 49);
        assert_eq!((margin(1), margin(4), margin(8)), (3, 14, 28));
    }

    #[test]
    fn search_is_exact() {
        // Smooth-ish example (noise blurred by the S = 4 disc) and noisy queries: the
        // bound-pruned search agrees with brute force on every query.
        let ex = noise(48, 40, 1);
        for s in [1usize, 4] {
            let bank = Bank::build(&ex, s, 256, 3).unwrap();
            let mut q = vec![0f32; DIMS];
            let mut st = 99u64;
            for t in 0..40 {
                let j = (splitmix(&mut st) % bank.len() as u64) as usize;
                bank.win.window(j, &mut q);
                for v in q.iter_mut() {
                    let e = (splitmix(&mut st) >> 40) as f32 / (1u64 << 24) as f32 - 0.5;
                    *v += e * (t as f32 / 20.0);
                }
                let fast = bank.nearest_sq(&q);
                let mut brute = f32::INFINITY;
                let mut w = vec![0f32; DIMS];
                for k in 0..bank.len() {
                    bank.win.window(k, &mut w);
                    brute = brute.min(dist_sq_bounded(&q, &w, f32::INFINITY));
                }
                assert!(
                    (fast - brute).abs() <= 1e-5 * brute.max(1.0),
                    "s {s} t {t}: {fast} vs {brute}"
                );
            }
        }
    }

    /// The smallest of `exact` over every window: what the search must return, bit for bit.
    fn brute_force(bank: &Bank, q: &[f32]) -> f32 {
        (0..bank.len())
            .map(|j| bank.win.exact(q, j, f32::INFINITY))
            .fold(f32::INFINITY, f32::min)
    }

    /// The pruned search returns exactly (bit for bit) the brute-force minimum, on random
    /// examples with and without repeated content (many windows at the same distance from a
    /// query, copies at distance 0) and on queries near, on and far from the windows.
    #[test]
    fn search_is_the_brute_force_minimum() {
        let tiled = {
            let tile = noise(5, 3, 11);
            let px = (0..44 * 38)
                .map(|i| tile.px[(i / 44 % 3) * 5 + i % 44 % 5])
                .collect();
            Rgb {
                width: 44,
                height: 38,
                px,
            }
        };
        for (ex, s) in [(noise(50, 41, 2), 1), (noise(50, 41, 2), 4), (tiled, 1)] {
            let bank = Bank::build(&ex, s, 64, 3).unwrap();
            let mut st = 7u64;
            let mut qs: Vec<Vec<f32>> = Vec::new();
            for t in 0..60 {
                let mut q = vec![0f32; DIMS];
                let j = (splitmix(&mut st) % bank.len() as u64) as usize;
                bank.win.window(j, &mut q);
                // On a window, near one, far from all; a third quantised (exact ties).
                let amp = [0.0, 0.05, 0.6][t % 3];
                for v in q.iter_mut() {
                    let e = (splitmix(&mut st) >> 40) as f32 / (1u64 << 24) as f32 - 0.5;
                    *v += e * amp;
                    if t % 2 == 0 {
                        *v = (*v * 4.0).round() / 4.0;
                    }
                }
                qs.push(q);
            }
            qs.push(vec![0.5; DIMS]);
            let refs: Vec<&[f32]> = qs.iter().map(|q| q.as_slice()).collect();
            for (q, got) in refs.iter().zip(bank.nearest_all(&refs)) {
                assert_eq!(got.to_bits(), brute_force(&bank, q).to_bits(), "s {s}");
            }
        }
    }

    /// A bank saved in the cache and read back (blocks in their search order, with the
    /// order) is the bank computed, and searches the same; a second store answers from
    /// the file. An order that misses a window or names one twice is refused.
    #[test]
    fn a_cached_bank_is_the_computed_one_and_a_bad_order_is_refused() {
        let ex = noise(40, 36, 6);
        let dir = std::env::temp_dir().join(format!("surfsynth-pf-bank-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let cache = crate::cache::CacheDir::Dir(dir.clone());
        let first = crate::synth::Analyses::new(&cache);
        let a = Bank::build_in(&ex, 4, 64, 3, &first).unwrap();
        let second = crate::synth::Analyses::new(&cache);
        let b = Bank::build_in(&ex, 4, 64, 3, &second).unwrap();
        let sources: Vec<_> = second.events().into_iter().map(|e| e.source).collect();
        assert_eq!(sources, [crate::synth::analysis::Source::Hit]);
        assert_eq!(a.core.slots, b.core.slots);
        assert_eq!(a.core.blocks, b.core.blocks);
        let fresh = Bank::build(&ex, 4, 64, 3).unwrap();
        assert_eq!(fresh.core.blocks, a.core.blocks);
        let mut q = vec![0f32; DIMS];
        for j in [0, 17, 100] {
            fresh.win.window(j, &mut q);
            q[5] += 0.3;
            assert_eq!(
                b.nearest_sq(&q).to_bits(),
                brute_force(&fresh, &q).to_bits()
            );
        }
        let _ = std::fs::remove_dir_all(&dir);

        let n = 21;
        let mut slots: Vec<u32> = (0..n).rev().collect();
        slots.resize(24, u32::MAX);
        assert!(is_padded_permutation(&slots));
        let mut twice = slots.clone();
        twice[3] = twice[4];
        assert!(!is_padded_permutation(&twice));
        let mut short = slots.clone();
        short[20] = u32::MAX;
        assert!(!is_padded_permutation(&short), "window 0 left out");
        let mut past = slots.clone();
        past[0] = 21;
        assert!(!is_padded_permutation(&past));
        let mut gap = slots.clone();
        gap.swap(5, 22);
        assert!(!is_padded_permutation(&gap), "padding inside");
        let mut long = slots.clone();
        long.extend([u32::MAX; LANES]);
        assert!(!is_padded_permutation(&long), "a whole block of padding");
    }

    /// Banks are saved up to [`MAX_SAVED_BANK`] bytes of projections and kept in memory
    /// only above it.
    #[test]
    fn large_banks_are_not_saved() {
        let core = |windows: usize| BankCore {
            mean: Vec::new(),
            basis: Vec::new(),
            blocks: vec![[0f32; LANES]; windows.div_ceil(LANES) * ROWS],
            slots: Vec::new(),
            pairs_mean_sq: 1.0,
        };
        use crate::cache::Persist;
        let per_window = ROWS * 4;
        assert!(core(MAX_SAVED_BANK / per_window / LANES * LANES).worth_saving());
        assert!(!core((MAX_SAVED_BANK / per_window + 1).next_multiple_of(LANES)).worth_saving());
    }

    /// A group's bound is at most the first-stage bound of each of its windows, as the
    /// lanes compute it (so skipping a group skips only windows the lanes would prune).
    #[test]
    fn group_bound_is_below_its_lanes() {
        let ex = noise(60, 50, 4);
        let bank = Bank::build(&ex, 1, 64, 3).unwrap();
        let mut st = 5u64;
        for _ in 0..50 {
            let q: Vec<f32> = (0..DIMS)
                .map(|_| (splitmix(&mut st) >> 40) as f32 / (1u64 << 24) as f32)
                .collect();
            let qr = bank.query_rows(&q);
            for (g, gb) in bank.groups.iter().enumerate() {
                let bound = group_bound(gb, &qr);
                let blocks = bank.core.blocks.chunks(ROWS).skip(g * GROUP_BLOCKS);
                for (b, blk) in blocks.take(GROUP_BLOCKS).enumerate() {
                    let slots = &bank.core.slots[(g * GROUP_BLOCKS + b) * LANES..][..LANES];
                    for l in (0..LANES).filter(|&l| slots[l] != u32::MAX) {
                        let mut coord = 0f32;
                        for r in 0..TREE_PCA {
                            let d = blk[r][l] - qr[r];
                            coord += d * d;
                        }
                        let d = blk[TREE_PCA][l] - qr[TREE_PCA];
                        assert!(bound <= (coord + d * d) * SAFETY);
                    }
                }
            }
        }
    }

    #[test]
    fn draw_is_distinct_and_deterministic() {
        let a = draw((0..1000).collect(), 100, 5);
        let b = draw((0..1000).collect(), 100, 5);
        assert_eq!(a, b);
        let mut s = a.clone();
        s.sort();
        s.dedup();
        assert_eq!(s.len(), 100);
        assert_eq!(draw((0..10).collect(), 100, 5), (0..10).collect::<Vec<_>>());
    }

    /// The sparse shuffle draws exactly what the shuffle of the whole list draws.
    #[test]
    fn draw_from_matches_the_full_shuffle() {
        fn full(mut c: Vec<usize>, count: usize, seed: u64) -> Vec<usize> {
            if c.len() <= count {
                return c;
            }
            let mut state = seed;
            for i in 0..count {
                let j = i + (splitmix(&mut state) % (c.len() - i) as u64) as usize;
                c.swap(i, j);
            }
            c.truncate(count);
            c
        }
        for (len, count, seed) in [(1000, 100, 5), (50, 49, 1), (7, 7, 3), (100_000, 768, 9)] {
            let list: Vec<usize> = (0..len).map(|i| 3 * i + 1).collect();
            assert_eq!(
                draw_from(len, |i| list[i], count, seed),
                full(list.clone(), count, seed),
                "len {len}, count {count}, seed {seed}"
            );
        }
    }

    /// A bank from the analysis cache is the bank built here: same denominator, same
    /// nearest distances; a damaged entry is rebuilt.
    #[test]
    fn a_cached_bank_is_the_built_bank() {
        use crate::cache::CacheDir;
        use crate::synth::analysis::Source;
        use crate::synth::Analyses;
        let dir = tempfile::tempdir().unwrap();
        let ex = noise(40, 36, 7);
        let qs: Vec<Vec<f32>> = (0..20)
            .map(|k| {
                let img = noise(WINDOW, WINDOW, 100 + k);
                img.px.iter().flatten().copied().collect()
            })
            .collect();
        let q: Vec<&[f32]> = qs.iter().map(|v| v.as_slice()).collect();
        let built = Bank::build(&ex, 4, 256, 3).unwrap();
        let want = (built.pairs_mean_sq(), built.nearest_all(&q));
        let cache = CacheDir::Dir(dir.path().to_path_buf());
        for expect in [Source::Miss, Source::Hit] {
            let a = Analyses::new(&cache);
            let b = Bank::build_in(&ex, 4, 256, 3, &a).unwrap();
            assert_eq!((b.pairs_mean_sq(), b.nearest_all(&q)), want);
            let ev = a.events();
            assert_eq!(ev.len(), 1);
            assert_eq!(ev[0].source, expect);
        }
        for f in std::fs::read_dir(dir.path()).unwrap() {
            let f = f.unwrap().path();
            let mut b = std::fs::read(&f).unwrap();
            let k = b.len() - 5;
            b[k] ^= 0x40;
            std::fs::write(&f, b).unwrap();
        }
        let a = Analyses::new(&cache);
        let b = Bank::build_in(&ex, 4, 256, 3, &a).unwrap();
        assert_eq!((b.pairs_mean_sq(), b.nearest_all(&q)), want);
        assert_eq!(a.events()[0].source, Source::Rebuilt);
    }
}
