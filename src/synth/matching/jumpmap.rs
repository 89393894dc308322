//! Jump maps (Zelinka & Garland 2002, "Towards real-time texture synthesis with the jump
//! map"; used on surfaces by paper 002, §2 and §4.2): for every example pixel, up to
//! [`MAX_JUMPS`] other pixels whose neighbourhoods look like its own, each with a weight
//! from that similarity. Synthesis ([`crate::synth::jump`]) then walks through the example
//! copying successive pixels and now and then takes one of the stored jumps, so it never
//! compares a neighbourhood at synthesis time: all the matching is done here, once per
//! example (and saved, [`crate::cache`]).
//!
//! **Neighbourhoods.** Every pixel's appearance vector ([`super::appearance`]: the PCA of
//! its 5x5 neighbourhood, 8 dimensions) is already a small neighbourhood; a jump map can
//! afford larger ones ("since jump maps are constructed offline ... we can afford to use
//! relatively large neighbourhoods", 002 §5), so a pixel is described by the appearance
//! vectors on a 3x3 lattice [`JumpMapParams::spacing`] pixels apart around it (with the
//! 5x5 windows, 13x13 pixels at spacing 4), Gaussian-weighted towards the centre, borders
//! clamped.
//!
//! **Search** (ANN, as Z&G): the lattice vectors are projected on their leading
//! [`TREE_DIMS`] principal directions, a kd-tree over the projections gives each pixel's
//! [`JumpMapParams::candidates`] nearest, and those are re-ranked by the exact lattice
//! distance. Pixels within [`JumpMapParams::exclude`] (Chebyshev) of the query are left out
//! — they look alike only because their neighbourhoods overlap, and a jump of a pixel or
//! two is no jump — and so are candidates within that distance of a better one already
//! kept, so the jumps of a pixel lead to different places.
//!
//! **Weights** (Z&G: "normalized to sum to one, or a lower value if the jumps at that
//! pixel were not very good"): with d the lattice distance of a jump and σ the median over
//! the example of every pixel's best-jump distance (what a good jump costs in this
//! example), q = exp(−d² / 2σ²) and the weights are q / max(1, Σq). A jump as good as a
//! typical best jump weighs 0.61, one twice as far 0.14, three times 0.01.
//!
//! Results do not depend on the thread count: the tree is built from a fixed slice, every
//! query's candidates are sorted by (distance, index), and per-pixel results are written
//! to their own slot.

use super::appearance::{Appearance, AppearanceInfo, AppearanceMode};
use super::search::pca::Pca;
use crate::cache::{Persist, Reader, Writer};
use crate::pyramid::Image;
use kiddo::{ImmutableKdTree, SquaredEuclidean};
use rayon::prelude::*;
use serde::Serialize;
use std::num::NonZeroUsize;

/// Most jumps stored per pixel (002 §2: "a few similar pixels").
pub const MAX_JUMPS: usize = 4;
/// Dimensions of the kd-tree over the projected lattice vectors.
pub const TREE_DIMS: usize = 8;
/// Marks an unused jump slot.
pub const NONE: u32 = u32::MAX;

/// How the jump map is built (part of the cache key).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct JumpMapParams {
    /// Jumps kept per pixel (1 to [`MAX_JUMPS`]).
    pub jumps: usize,
    /// Lattice step of the neighbourhood, pixels.
    pub spacing: usize,
    /// Chebyshev radius (pixels) around the query, and around kept jumps, that is left out.
    pub exclude: usize,
    /// Nearest projected neighbours re-ranked exactly.
    pub candidates: usize,
}

impl Default for JumpMapParams {
    fn default() -> Self {
        Self {
            jumps: MAX_JUMPS,
            spacing: 4,
            exclude: 3,
            candidates: 64,
        }
    }
}

/// What the analysis found (reported).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct JumpMapStats {
    /// Mean number of jumps per pixel.
    pub mean_jumps: f64,
    /// σ: median best-jump distance (lattice l2).
    pub sigma: f64,
    /// Mean weight sum per pixel (≤ 1).
    pub mean_weight: f64,
    /// Share of the lattice vectors' variance the tree's projection keeps.
    pub tree_kept_variance: f64,
}

/// The jump map of one example (see the module docs).
#[derive(Clone, Debug, PartialEq)]
pub struct JumpMap {
    pub width: usize,
    pub height: usize,
    /// Per pixel (y·width + x): target pixel indices, best first, [`NONE`] where unused.
    pub targets: Vec<[u32; MAX_JUMPS]>,
    /// Per pixel: the weights of those jumps (sum ≤ 1; 0 where unused).
    pub weights: Vec<[f32; MAX_JUMPS]>,
    /// Per pixel: the sum of its weights.
    pub total: Vec<f32>,
    pub params: JumpMapParams,
    /// What was matched (appearance space or raw channels).
    pub appearance: AppearanceInfo,
    pub stats: JumpMapStats,
}

impl JumpMap {
    /// Builds the jump map of `weighted` (channels premultiplied by the square roots of
    /// their weights) matched in `mode` with `k` values per pixel ([`super::appearance::DIMS`]
    /// for [`AppearanceMode::Pca`], the channel count for raw channels).
    pub fn build(weighted: &Image, mode: AppearanceMode, k: usize, params: JumpMapParams) -> Self {
        let app = Appearance::build(weighted, mode, super::appearance::WINDOW, k);
        Self::from_appearance(&app.image, app.info, params)
    }

    /// The jump map of an image already in the matched space.
    pub fn from_appearance(img: &Image, appearance: AppearanceInfo, params: JumpMapParams) -> Self {
        Self::from_appearance_with(img, appearance, params, &|_, _| {})
    }

    /// [`JumpMap::from_appearance`], telling `progress(done, total)` how many pixels'
    /// jumps are found as it goes (the searches are most of the work: ~150 µs a pixel of a
    /// 1024² example). The result does not depend on it.
    pub fn from_appearance_with(
        img: &Image,
        appearance: AppearanceInfo,
        params: JumpMapParams,
        progress: &(dyn Fn(usize, usize) + Sync),
    ) -> Self {
        let (w, h, c) = (img.width, img.height, img.channels);
        let n = w * h;
        let jumps = params.jumps.clamp(1, MAX_JUMPS);
        let sp = params.spacing.max(1) as isize;
        // Lattice vectors: 3x3 samples, sqrt Gaussian weights (σ = one lattice step).
        let lattice: Vec<(isize, isize, f32)> = (-1..=1)
            .flat_map(|j| (-1..=1).map(move |i| (i, j)))
            .map(|(i, j)| (i * sp, j * sp, ((-(i * i + j * j) as f32) / 4.0).exp()))
            .collect();
        let dim = lattice.len() * c;
        let mut vecs = vec![0.0f32; n * dim];
        vecs.par_chunks_mut(w * dim)
            .enumerate()
            .for_each(|(y, row)| {
                for x in 0..w {
                    let out = &mut row[x * dim..(x + 1) * dim];
                    for (s, &(dx, dy, g)) in lattice.iter().enumerate() {
                        let sx = (x as isize + dx).clamp(0, w as isize - 1) as usize;
                        let sy = (y as isize + dy).clamp(0, h as isize - 1) as usize;
                        for (o, v) in out[s * c..(s + 1) * c].iter_mut().zip(img.pixel(sx, sy)) {
                            *o = v * g;
                        }
                    }
                }
            });
        let mut targets = vec![[NONE; MAX_JUMPS]; n];
        let mut dists = vec![[f32::INFINITY; MAX_JUMPS]; n];
        let mut kept_variance = 1.0;
        if n > 1 {
            let kd = TREE_DIMS.min(dim);
            let pca = Pca::fit(&vecs, dim, kd);
            kept_variance = pca.kept_variance();
            let mut proj = vec![[0.0f32; TREE_DIMS]; n];
            proj.par_iter_mut()
                .enumerate()
                .for_each(|(i, p)| pca.project(&vecs[i * dim..(i + 1) * dim], &mut p[..kd]));
            let tree: ImmutableKdTree<f32, TREE_DIMS> =
                ImmutableKdTree::new_from_slice(&proj).expect("finite example vectors");
            let ask = NonZeroUsize::new(params.candidates.max(jumps).min(n)).expect("n > 1");
            let ex = params.exclude as isize;
            // Progress every PROGRESS_PIXELS pixels (counted per pixel, reported per step).
            const PROGRESS_PIXELS: usize = 1 << 14;
            let found = std::sync::atomic::AtomicUsize::new(0);
            targets
                .par_iter_mut()
                .zip(dists.par_iter_mut())
                .enumerate()
                .for_each_init(Vec::new, |cands, (i, (tg, ds))| {
                    if i % PROGRESS_PIXELS == PROGRESS_PIXELS - 1 {
                        let done =
                            found.fetch_add(PROGRESS_PIXELS, std::sync::atomic::Ordering::Relaxed);
                        progress(done + PROGRESS_PIXELS, n);
                    }
                    let (x, y) = ((i % w) as isize, (i / w) as isize);
                    let far = |j: usize, px: isize, py: isize| {
                        let (jx, jy) = ((j % w) as isize, (j / w) as isize);
                        (jx - px).abs().max((jy - py).abs()) > ex
                    };
                    cands.clear();
                    let q = &vecs[i * dim..(i + 1) * dim];
                    for r in tree
                        .query(&proj[i])
                        .nearest_n::<SquaredEuclidean<f32>>(ask)
                        .execute()
                    {
                        let j = r.item as usize;
                        if far(j, x, y) {
                            let v = &vecs[j * dim..(j + 1) * dim];
                            let d: f32 = q.iter().zip(v).map(|(a, b)| (a - b) * (a - b)).sum();
                            cands.push((d, j as u32));
                        }
                    }
                    cands.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
                    let mut m = 0;
                    for &(d, j) in cands.iter() {
                        let (jx, jy) = ((j as usize % w) as isize, (j as usize / w) as isize);
                        if tg[..m].iter().all(|&o| far(o as usize, jx, jy)) {
                            tg[m] = j;
                            ds[m] = d.sqrt();
                            m += 1;
                            if m == jumps {
                                break;
                            }
                        }
                    }
                });
        }
        progress(n, n);
        // σ: the median best-jump distance.
        let mut best: Vec<f32> = dists
            .iter()
            .map(|d| d[0])
            .filter(|d| d.is_finite())
            .collect();
        let sigma = if best.is_empty() {
            1.0
        } else {
            let mid = best.len() / 2;
            let (_, m, _) = best.select_nth_unstable_by(mid, f32::total_cmp);
            m.max(1e-6)
        };
        let mut weights = vec![[0.0f32; MAX_JUMPS]; n];
        let mut total = vec![0.0f32; n];
        for ((wt, tot), ds) in weights.iter_mut().zip(&mut total).zip(&dists) {
            let mut q = [0.0f32; MAX_JUMPS];
            for (qi, &d) in q.iter_mut().zip(ds) {
                if d.is_finite() {
                    *qi = (-(d * d) / (2.0 * sigma * sigma)).exp();
                }
            }
            let s: f32 = q.iter().sum();
            let norm = s.max(1.0);
            for (o, qi) in wt.iter_mut().zip(q) {
                *o = qi / norm;
            }
            *tot = wt.iter().sum();
        }
        let count: usize = targets
            .iter()
            .map(|t| t.iter().filter(|&&j| j != NONE).count())
            .sum();
        let stats = JumpMapStats {
            mean_jumps: count as f64 / n.max(1) as f64,
            sigma: sigma as f64,
            mean_weight: total.iter().map(|&t| t as f64).sum::<f64>() / n.max(1) as f64,
            tree_kept_variance: kept_variance,
        };
        Self {
            width: w,
            height: h,
            targets,
            weights,
            total,
            params,
            appearance,
            stats,
        }
    }

    /// Bytes held.
    pub fn heap_bytes(&self) -> usize {
        self.targets.len() * (4 * MAX_JUMPS * 2 + 4)
    }

    /// Sum of the jump weights at continuous position (x, y) (pixel centres at +0.5): the
    /// bilinear blend of the four surrounding pixels' sums (002 §4.2.3).
    #[inline]
    pub fn total_at(&self, x: f32, y: f32) -> f32 {
        let t = self.taps(x, y);
        t.iter().map(|&(i, b)| b * self.total[i]).sum()
    }

    /// The four pixels around (x, y) with their bilinear weights (clamped at the border).
    #[inline]
    pub fn taps(&self, x: f32, y: f32) -> [(usize, f32); 4] {
        let fx = (x - 0.5).clamp(0.0, (self.width - 1) as f32);
        let fy = (y - 0.5).clamp(0.0, (self.height - 1) as f32);
        let (x0, y0) = (fx as usize, fy as usize);
        let (tx, ty) = (fx - x0 as f32, fy - y0 as f32);
        let x1 = (x0 + 1).min(self.width - 1);
        let y1 = (y0 + 1).min(self.height - 1);
        let w = self.width;
        [
            (y0 * w + x0, (1.0 - tx) * (1.0 - ty)),
            (y0 * w + x1, tx * (1.0 - ty)),
            (y1 * w + x0, (1.0 - tx) * ty),
            (y1 * w + x1, tx * ty),
        ]
    }

    /// The jump list at continuous position (x, y) (002 §4.2.3, figure 5): the entries of
    /// the four surrounding pixels with bilinearly filtered weights, each destination moved
    /// by (x, y)'s offset from the pixel it is stored at. Calls `f(weight, dest_x, dest_y)`.
    #[inline]
    pub fn for_each_jump(&self, x: f32, y: f32, mut f: impl FnMut(f32, f32, f32)) {
        let w = self.width;
        for (p, b) in self.taps(x, y) {
            if b <= 0.0 {
                continue;
            }
            let (px, py) = ((p % w) as f32, (p / w) as f32);
            for (&j, &wt) in self.targets[p].iter().zip(&self.weights[p]) {
                if j == NONE {
                    break;
                }
                let (jx, jy) = ((j as usize % w) as f32, (j as usize / w) as f32);
                f(b * wt, jx + (x - px), jy + (y - py));
            }
        }
    }
}

impl Persist for JumpMap {
    fn save(&self, w: &mut Writer) {
        w.usize(self.width);
        w.usize(self.height);
        let t: Vec<u32> = self.targets.iter().flatten().copied().collect();
        let wt: Vec<f32> = self.weights.iter().flatten().copied().collect();
        w.u32s(&t);
        w.f32s(&wt);
        let p = &self.params;
        for v in [p.jumps, p.spacing, p.exclude, p.candidates] {
            w.usize(v);
        }
        w.usize(self.appearance.dims);
        w.usize(self.appearance.window);
        w.f64(self.appearance.kept_variance);
        let s = &self.stats;
        for v in [s.mean_jumps, s.sigma, s.mean_weight, s.tree_kept_variance] {
            w.f64(v);
        }
    }

    fn load(r: &mut Reader<'_>) -> Option<Self> {
        let width = r.usize()?;
        let height = r.usize()?;
        let n = width.checked_mul(height)?;
        let t = r.u32s()?;
        let wt = r.f32s()?;
        if n == 0 || t.len() != n * MAX_JUMPS || wt.len() != n * MAX_JUMPS {
            return None;
        }
        if t.iter().any(|&j| j != NONE && j as usize >= n) {
            return None;
        }
        let targets: Vec<[u32; MAX_JUMPS]> = t
            .chunks_exact(MAX_JUMPS)
            .map(|c| c.try_into().expect("MAX_JUMPS"))
            .collect();
        let weights: Vec<[f32; MAX_JUMPS]> = wt
            .chunks_exact(MAX_JUMPS)
            .map(|c| c.try_into().expect("MAX_JUMPS"))
            .collect();
        if weights
            .iter()
            .flatten()
            .any(|w| !(w.is_finite() && *w >= 0.0))
        {
            return None;
        }
        let total = weights.iter().map(|w| w.iter().sum()).collect();
        let params = JumpMapParams {
            jumps: r.usize()?,
            spacing: r.usize()?,
            exclude: r.usize()?,
            candidates: r.usize()?,
        };
        let appearance = AppearanceInfo {
            dims: r.usize()?,
            window: r.usize()?,
            kept_variance: r.f64()?,
            feature_distance: 0.0,
            reflectance: None,
        };
        let stats = JumpMapStats {
            mean_jumps: r.f64()?,
            sigma: r.f64()?,
            mean_weight: r.f64()?,
            tree_kept_variance: r.f64()?,
        };
        Some(Self {
            width,
            height,
            targets,
            weights,
            total,
            params,
            appearance,
            stats,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// On a periodic image the jumps of a pixel are its copies one period away.
    #[test]
    fn jumps_of_a_periodic_image_are_its_copies() {
        let (w, h, p) = (48, 48, 12);
        let mut img = Image::new(w, h, 3);
        for y in 0..h {
            for x in 0..w {
                let (a, b) = ((x % p) as f32 / p as f32, (y % p) as f32 / p as f32);
                img.pixel_mut(x, y)
                    .copy_from_slice(&[a, b, (a * 7.0 + b * 3.0).sin()]);
            }
        }
        let m = JumpMap::build(&img, AppearanceMode::Pca, 8, JumpMapParams::default());
        for &(x, y) in &[(20usize, 20usize), (17, 30), (25, 22)] {
            let t = &m.targets[y * w + x];
            assert!(t[0] != NONE);
            for &j in t.iter().filter(|&&j| j != NONE) {
                let (jx, jy) = (j as usize % w, j as usize / w);
                // Interior copies are exact; those near the border see clamped lattices.
                if (6..w - 6).contains(&jx) && (6..h - 6).contains(&jy) {
                    assert_eq!((jx % p, jy % p), (x % p, y % p), "({x},{y}) -> ({jx},{jy})");
                }
                assert!(jx.abs_diff(x).max(jy.abs_diff(y)) > 3);
            }
            let s: f32 = m.weights[y * w + x].iter().sum();
            assert!(s <= 1.0 + 1e-6 && s > 0.0);
        }
        // Persisted and read back exactly.
        let mut wr = Writer::default();
        m.save(&mut wr);
        let mut r = Reader::new(&wr.0);
        assert_eq!(JumpMap::load(&mut r).as_ref(), Some(&m));
        assert!(r.at_end());
    }
}
