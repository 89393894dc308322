//! Similar places of an example: for a pixel, the `k` pixels whose matching vectors
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
//! Exact nearest neighbours by a kd-tree over the `K`-dimensional vectors (kiddo), ties
//! broken by index, so a list is a pure function of the example. Lists are computed on
//! first use and kept (one `OnceLock` per grid pixel): patch methods ask for a few thousand
//! of them, far fewer than an example has pixels, so building all up front would cost more
//! than the synthesis (measured: 0.2 s for a 256² example), while the result does not
//! depend on which thread asked first.

use super::features::Features;
use kiddo::{ImmutableKdTree, SquaredEuclidean};
use std::num::NonZeroUsize;
use std::sync::OnceLock;

/// Entries per list.
pub const K: usize = 8;

/// Lazily built lists of similar pixels of one example level (`D` = vector dimension).
pub struct Similar<const D: usize> {
    pub width: usize,
    pub height: usize,
    /// Chebyshev radius (pixels) of the excluded surroundings of each pixel.
    pub exclude: usize,
    /// Lists are kept for every `stride`-th pixel in each direction.
    pub stride: usize,
    grid_width: usize,
    points: Vec<[f32; D]>,
    tree: Option<ImmutableKdTree<f32, D>>,
    /// Per grid pixel: up to [`K`] pixel indices (y * width + x), most similar first,
    /// padded with the pixel itself.
    lists: Vec<OnceLock<[u32; K]>>,
}

impl<const D: usize> std::fmt::Debug for Similar<D> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Similar")
            .field("width", &self.width)
            .field("height", &self.height)
            .field("exclude", &self.exclude)
            .field("stride", &self.stride)
            .finish_non_exhaustive()
    }
}

impl<const D: usize> Similar<D> {
    /// The lists of `f`, for the pixels of a grid of step `stride` (1: every pixel). With a
    /// stride, a pixel's list is its grid pixel's shifted by the pixel's offset from it
    /// ([`Similar::of`]): the place that looks like my grid neighbour, shifted like me,
    /// looks like me — and there are stride² fewer lists to compute.
    pub fn new(f: &Features<D>, exclude: usize, stride: usize) -> Self {
        let (w, h) = (f.width, f.height);
        let stride = stride.max(1);
        let (gw, gh) = (w.div_ceil(stride), h.div_ceil(stride));
        let points: Vec<[f32; D]> = (0..w * h).map(|i| *f.at(i % w, i / w)).collect();
        let tree = (points.len() > 1)
            .then(|| ImmutableKdTree::new_from_slice(&points).expect("finite example vectors"));
        Self {
            width: w,
            height: h,
            exclude,
            stride,
            grid_width: gw,
            points,
            tree,
            lists: (0..gw * gh).map(|_| OnceLock::new()).collect(),
        }
    }

    fn compute(&self, x: usize, y: usize) -> [u32; K] {
        let w = self.width;
        let i = y * w + x;
        let mut out = [i as u32; K];
        let Some(tree) = &self.tree else {
            return out;
        };
        // Enough extra results to survive the excluded square around the query.
        let extra = (2 * self.exclude + 1).pow(2);
        let ask = NonZeroUsize::new((K + extra).min(self.points.len())).expect("> 1 point");
        let mut hits = tree
            .query(&self.points[i])
            .nearest_n::<SquaredEuclidean<f32>>(ask)
            .execute();
        hits.sort_by(|a, b| a.distance.total_cmp(&b.distance).then(a.item.cmp(&b.item)));
        let (x, y) = (x as isize, y as isize);
        let mut m = 0;
        for r in hits {
            let j = r.item as usize;
            let (jx, jy) = ((j % w) as isize, (j / w) as isize);
            if (jx - x).abs().max((jy - y).abs()) as usize <= self.exclude {
                continue;
            }
            out[m] = j as u32;
            m += 1;
            if m == K {
                break;
            }
        }
        out
    }

    /// The places most similar to pixel (x, y), most similar first, as pixel positions
    /// (column, row); with a stride they are shifted by (x, y)'s offset from its grid pixel
    /// and may fall outside the example (callers check).
    pub fn of(&self, x: usize, y: usize) -> impl Iterator<Item = (i64, i64)> + '_ {
        let (gx, gy) = (x / self.stride, y / self.stride);
        let (dx, dy) = ((x - gx * self.stride) as i64, (y - gy * self.stride) as i64);
        let list = self.lists[gy * self.grid_width + gx]
            .get_or_init(|| self.compute(gx * self.stride, gy * self.stride));
        let w = self.width;
        list.iter()
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
            let s = Similar::new(&f, 2, stride);
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
