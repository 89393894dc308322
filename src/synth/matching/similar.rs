//! Similar places of an example: for every pixel, the `k` pixels whose matching vectors
//! (appearance vectors, [`super::appearance`]) are nearest — the candidate sets of
//! k-coherence search (paper 003 §5.2; Lefebvre & Hoppe 2005 build theirs the same way on
//! appearance vectors).
//!
//! A method that knows where a neighbour's patch came from proposes that continuation;
//! the lists add the `k` places that look most like it elsewhere in the example, which is
//! where a new patch can start without a visible join. Pixels closer than
//! [`Similar::exclude`] (Chebyshev distance) to the query are left out: their vectors are
//! similar only because their neighbourhoods overlap, and proposing a shift by one pixel
//! adds nothing the continuation does not already offer.
//!
//! Exact nearest neighbours by a kd-tree over the `K`-dimensional vectors (kiddo); ties
//! and the tree's internal order are deterministic, so the lists are too.

use super::features::Features;
use kiddo::{ImmutableKdTree, SquaredEuclidean};
use rayon::prelude::*;
use std::num::NonZeroUsize;

/// Per-pixel lists of similar pixels of one example level.
#[derive(Clone, Debug)]
pub struct Similar {
    pub width: usize,
    pub height: usize,
    /// Entries per list (fewer only for examples with fewer far-enough pixels).
    pub k: usize,
    /// Chebyshev radius (pixels) of the excluded surroundings of each pixel.
    pub exclude: usize,
    /// Lists are kept for every `stride`-th pixel in each direction.
    pub stride: usize,
    grid_width: usize,
    /// `width * height * k` pixel indices (y * width + x), most similar first; lists
    /// shorter than `k` are padded with the pixel itself.
    lists: Vec<u32>,
}

impl Similar {
    /// Builds the lists over the vectors of `f`, for the pixels of a grid of step `stride`
    /// (1: every pixel). With a stride, a pixel's list is its grid pixel's, shifted by the
    /// pixel's offset from it ([`Similar::of`]): the place that looks like my grid
    /// neighbour, shifted like me, looks like me — and the kd-tree queries, the cost of
    /// building, drop by stride².
    pub fn build<const K: usize>(f: &Features<K>, k: usize, exclude: usize, stride: usize) -> Self {
        let (w, h) = (f.width, f.height);
        let stride = stride.max(1);
        let (gw, gh) = (w.div_ceil(stride), h.div_ceil(stride));
        let n = w * h;
        let pts: Vec<[f32; K]> = (0..n).map(|i| *f.at(i % w, i / w)).collect();
        let mut lists = vec![0u32; gw * gh * k];
        if k > 0 && n > 1 {
            let tree: ImmutableKdTree<f32, K> =
                ImmutableKdTree::new_from_slice(&pts).expect("finite example vectors");
            // Enough extra results to survive the excluded square around the query.
            let extra = (2 * exclude + 1).pow(2);
            let ask = NonZeroUsize::new((k + extra).min(n)).expect("n > 1");
            lists.par_chunks_mut(k).enumerate().for_each(|(g, out)| {
                let (x, y) = ((g % gw) * stride, (g / gw) * stride);
                let i = y * w + x;
                let (x, y) = (x as isize, y as isize);
                let mut hits = tree
                    .query(&pts[i])
                    .nearest_n::<SquaredEuclidean<f32>>(ask)
                    .execute();
                hits.sort_by(|a, b| a.distance.total_cmp(&b.distance).then(a.item.cmp(&b.item)));
                let mut m = 0;
                for r in hits {
                    let j = r.item as usize;
                    let (jx, jy) = ((j % w) as isize, (j / w) as isize);
                    if (jx - x).abs().max((jy - y).abs()) as usize <= exclude {
                        continue;
                    }
                    out[m] = j as u32;
                    m += 1;
                    if m == k {
                        break;
                    }
                }
                for o in &mut out[m..] {
                    *o = i as u32;
                }
            });
        }
        Self {
            width: w,
            height: h,
            k,
            exclude,
            stride,
            grid_width: gw,
            lists,
        }
    }

    /// The places most similar to pixel (x, y), most similar first, as pixel positions
    /// (column, row); with a stride they are shifted by (x, y)'s offset from its grid pixel
    /// and may fall outside the example (callers check).
    #[inline]
    pub fn of(&self, x: usize, y: usize) -> impl Iterator<Item = (i64, i64)> + '_ {
        let (gx, gy) = (x / self.stride, y / self.stride);
        let (dx, dy) = ((x - gx * self.stride) as i64, (y - gy * self.stride) as i64);
        let g = gy * self.grid_width + gx;
        let w = self.width;
        self.lists[g * self.k..(g + 1) * self.k]
            .iter()
            .map(move |&j| ((j as usize % w) as i64 + dx, (j as usize / w) as i64 + dy))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pyramid::Image;

    /// A periodic image: the most similar pixels of any pixel are its copies one period
    /// away, never its own surroundings.
    #[test]
    fn periodic_copies_are_most_similar() {
        let (w, h, p) = (40, 40, 8);
        let mut img = Image::new(w, h, 3);
        for y in 0..h {
            for x in 0..w {
                let (a, b) = ((x % p) as f32 / p as f32, (y % p) as f32 / p as f32);
                img.pixel_mut(x, y).copy_from_slice(&[a, b, a * b]);
            }
        }
        let f = Features::<3>::from_image(&img);
        for stride in [1, 2] {
            let s = Similar::build(&f, 4, 2, stride);
            for &(x, y) in &[(10usize, 10usize), (3, 30), (25, 17)] {
                for (jx, jy) in s.of(x, y) {
                    let (jx, jy) = (jx as usize, jy as usize);
                    assert_eq!((jx % p, jy % p), (x % p, y % p), "({x},{y}) -> ({jx},{jy})");
                    assert!(jx.abs_diff(x).max(jy.abs_diff(y)) > 1);
                }
            }
        }
    }
}
