//! The example as the matcher sees it: all matched channels interleaved per pixel and
//! pre-multiplied by the square roots of their weights, so that a plain squared l2 distance
//! between two feature vectors is the weighted distance of §5 step 4, and one bilinear
//! lookup touches four contiguous small arrays. `K` (3 to 5: RGB, + alpha, + height) is a
//! const parameter so the inner loops unroll.
//!
//! The output values are *not* taken from here: they are looked up in the unweighted
//! [`crate::example::Example`] at the recorded source position, so every channel comes from
//! the same place.

use crate::example::Example;

/// Squared l2 distance between two feature vectors: the weighted distance, since the
/// features carry the square roots of the weights (see the module docs).
#[inline(always)]
pub fn dist2<const K: usize>(a: &[f32; K], b: &[f32; K]) -> f32 {
    let mut s = 0.0;
    for k in 0..K {
        let d = a[k] - b[k];
        s += d * d;
    }
    s
}

/// `example`'s channels premultiplied by the square roots of `weights` (one per channel of
/// [`Example::channel_names`]), so that a plain squared l2 distance is the weighted one:
/// the image every appearance space and pyramid of the matchers is built from.
pub fn weighted(example: &Example, weights: &[f32]) -> crate::pyramid::Image {
    let mut img = crate::pyramid::Image::from_example(example);
    let sw: Vec<f32> = weights.iter().map(|w| w.max(0.0).sqrt()).collect();
    let c = img.channels;
    for px in img.data.chunks_exact_mut(c) {
        for (v, s) in px.iter_mut().zip(&sw) {
            *v *= s;
        }
    }
    img
}

/// Weighted, interleaved example features (see the module docs).
#[derive(Clone, Debug)]
pub struct Features<const K: usize> {
    pub width: usize,
    pub height: usize,
    data: Vec<[f32; K]>,
    /// Largest valid coordinate minus 0.5 (as f32), per axis.
    max_x: f32,
    max_y: f32,
}

impl<const K: usize> Features<K> {
    /// Builds the table from `example`; `weights` has one entry per channel of
    /// [`Example::channel_names`] (K of them).
    pub fn new(example: &Example, weights: &[f32]) -> Self {
        assert_eq!(example.num_channels(), K);
        assert_eq!(weights.len(), K);
        let sw: Vec<f32> = weights.iter().map(|w| w.max(0.0).sqrt()).collect();
        let mut data = vec![[0.0f32; K]; example.width * example.height];
        let mut px = [0.0f32; 8];
        for j in 0..example.height {
            for i in 0..example.width {
                example.pixel(i, j, &mut px[..K]);
                let v = &mut data[j * example.width + i];
                for k in 0..K {
                    v[k] = px[k] * sw[k];
                }
            }
        }
        Self {
            width: example.width,
            height: example.height,
            data,
            max_x: (example.width - 1) as f32,
            max_y: (example.height - 1) as f32,
        }
    }

    /// The table of an image whose `K` channels are already the matched values (e.g. an
    /// [`super::appearance::Appearance`] image, or weighted channels).
    pub fn from_image(img: &crate::pyramid::Image) -> Self {
        assert_eq!(
            img.channels, K,
            "image has {} channels, not {K}",
            img.channels
        );
        let data = img
            .data
            .chunks_exact(K)
            .map(|c| c.try_into().expect("K channels"))
            .collect();
        Self {
            width: img.width,
            height: img.height,
            data,
            max_x: (img.width - 1) as f32,
            max_y: (img.height - 1) as f32,
        }
    }

    /// The stored vector of pixel (x, y).
    #[inline(always)]
    pub fn at(&self, x: usize, y: usize) -> &[f32; K] {
        &self.data[y * self.width + x]
    }

    /// All vectors, row by row, `K` values each (for kernels that load them directly).
    #[inline(always)]
    pub fn flat(&self) -> &[f32] {
        self.data.as_flattened()
    }

    /// The bilinear lookup at (x, y) that [`Features::sample`] blends: the indices of its
    /// four pixels (x0 y0, x1 y0, x0 y1, x1 y1) and its weights tx, ty — also for kernels
    /// that blend the four vectors themselves, so that they read what `sample` reads.
    #[inline(always)]
    pub fn taps(&self, x: f32, y: f32) -> ([usize; 4], f32, f32) {
        let fx = (x - 0.5).clamp(0.0, self.max_x);
        let fy = (y - 0.5).clamp(0.0, self.max_y);
        // `as usize` of a NaN is 0, so a NaN position reads pixel 0 instead of garbage.
        let x0 = fx as usize;
        let y0 = fy as usize;
        let tx = fx - x0 as f32;
        let ty = fy - y0 as f32;
        let x1 = (x0 + 1).min(self.width - 1);
        let y1 = (y0 + 1).min(self.height - 1);
        let w = self.width;
        ([y0 * w + x0, y0 * w + x1, y1 * w + x0, y1 * w + x1], tx, ty)
    }

    /// [`Features::sample`] at (x, y) for 8 values, in one AVX2 register: the same taps
    /// ([`Features::taps`]) and the same arithmetic per value (no fused multiply-add), so
    /// the lanes are `sample`'s values bit for bit — what the 8-value kernels of patch
    /// sampling and coherent synthesis measure with.
    ///
    /// # Safety
    /// AVX2 must be available, and `K` must be 8.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    #[inline]
    pub unsafe fn sample8_avx2(&self, x: f32, y: f32) -> std::arch::x86_64::__m256 {
        use std::arch::x86_64::*;
        debug_assert_eq!(K, 8);
        let flat = self.flat();
        let load = |i: usize| _mm256_loadu_ps(flat[i * 8..i * 8 + 8].as_ptr());
        let ([a, b, c, d], tx, ty) = self.taps(x, y);
        let (a, b, c, d) = (load(a), load(b), load(c), load(d));
        let txv = _mm256_set1_ps(tx);
        let top = _mm256_add_ps(a, _mm256_mul_ps(txv, _mm256_sub_ps(b, a)));
        let bot = _mm256_add_ps(c, _mm256_mul_ps(txv, _mm256_sub_ps(d, c)));
        _mm256_add_ps(
            top,
            _mm256_mul_ps(_mm256_set1_ps(ty), _mm256_sub_ps(bot, top)),
        )
    }

    /// Bilinear feature at continuous position (x, y) (pixel centres at +0.5), clamped to
    /// the image: outside it the border pixels repeat (see [`Example::bilinear_taps`] for
    /// why clamping, not wrapping).
    #[inline(always)]
    pub fn sample(&self, x: f32, y: f32) -> [f32; K] {
        let ([ia, ib, ic, id], tx, ty) = self.taps(x, y);
        let (a, b, c, d) = (
            &self.data[ia],
            &self.data[ib],
            &self.data[ic],
            &self.data[id],
        );
        let mut out = [0.0f32; K];
        for k in 0..K {
            let top = a[k] + tx * (b[k] - a[k]);
            let bot = c[k] + tx * (d[k] - c[k]);
            out[k] = top + ty * (bot - top);
        }
        out
    }
}

/// Lane j of the result: the sum over k, in order, of `sq[j]`'s lane k — [`dist2`] of
/// position j, given its eight squared differences, in `dist2`'s order (so the kernels'
/// errors are the scalar ones bit for bit): the sum of the 8-value kernels of patch
/// sampling and coherent synthesis.
///
/// # Safety
/// AVX2 must be available.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[inline]
pub(crate) unsafe fn dist2_lanes(sq: &[std::arch::x86_64::__m256; 8]) -> std::arch::x86_64::__m256 {
    use std::arch::x86_64::_mm256_add_ps;
    let tr = super::search::transpose8(sq);
    let mut d2 = tr[0];
    for v in &tr[1..] {
        d2 = _mm256_add_ps(d2, *v);
    }
    d2
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `taps` is `sample`'s lookup: blending its four pixels as `sample` does gives
    /// `sample`'s value bit for bit, inside, on and beyond the edges, and for NaN.
    #[test]
    fn taps_blend_to_sample() {
        let mut img = crate::pyramid::Image::new(7, 5, 2);
        for (i, v) in img.data.iter_mut().enumerate() {
            *v = ((i * 37) % 11) as f32 * 0.13 - 0.4;
        }
        let f = Features::<2>::from_image(&img);
        let flat = f.flat();
        for &(x, y) in &[
            (3.3f32, 2.7f32),
            (0.5, 0.5),
            (-2.0, 9.0),
            (6.99, 4.51),
            (100.0, -3.0),
            (f32::NAN, 1.2),
        ] {
            let ([a, b, c, d], tx, ty) = f.taps(x, y);
            let s = f.sample(x, y);
            for k in 0..2 {
                let (a, b, c, d) = (
                    flat[a * 2 + k],
                    flat[b * 2 + k],
                    flat[c * 2 + k],
                    flat[d * 2 + k],
                );
                let top = a + tx * (b - a);
                let bot = c + tx * (d - c);
                let v = top + ty * (bot - top);
                assert_eq!(v.to_bits(), s[k].to_bits(), "({x}, {y}) value {k}");
            }
        }
    }

    #[test]
    fn sample_is_bilinear_weighted_and_clamped() {
        let mut rgb = vec![[0.0f32; 3]; 64];
        for j in 0..8 {
            for i in 0..8 {
                rgb[j * 8 + i] = [i as f32 / 8.0, j as f32 / 8.0, 0.5];
            }
        }
        let ex = Example::from_linear(8, 8, rgb);
        let f = Features::<3>::new(&ex, &[1.0, 4.0, 0.0]);
        // Pixel centre (2, 3) at (2.5, 3.5); halfway to the next column.
        let v = f.sample(3.0, 3.5);
        assert!((v[0] - 2.5 / 8.0).abs() < 1e-6);
        assert!(
            (v[1] - 2.0 * 3.0 / 8.0).abs() < 1e-6,
            "weight 4 scales by 2"
        );
        assert_eq!(v[2], 0.0);
        // Outside: border pixels repeat.
        assert_eq!(f.sample(-3.0, 0.5)[0], 0.0);
        assert!((f.sample(100.0, 0.5)[0] - 7.0 / 8.0).abs() < 1e-6);
        // The unweighted example agrees at any position.
        let mut o = [0.0f32; 3];
        ex.bilinear(5.3, 2.7, &mut o);
        assert!((f.sample(5.3, 2.7)[0] - o[0]).abs() < 1e-6);
    }
}
