//! Gaussian pyramids of multi-channel images (the example, and 2D synthesis outputs).
//!
//! Multiscale synthesis (paper 000 §4, after Wei & Levoy) matches neighbourhoods level by
//! level from coarse to fine, so the example and the target both need a pyramid whose
//! level `l` samples the same content at spacing `2^l`.
//!
//! **Kernel.** Each level is the previous one filtered with the separable binomial kernel
//! `[1 3 3 1] / 8` and decimated by 2, output pixel `i` taking input pixels `2i-1 .. 2i+2`.
//! The even-length kernel is centred *between* input pixels `2i` and `2i+1`, which is exactly
//! where the centre of output pixel `i` lies under the pixel-centres-at-+0.5 convention
//! used everywhere (`source.u/v`, face-map texels): pixel `i` of level `l` is centred at
//! `(i + 0.5) * 2^l` level-0 pixels. The classic Burt–Adelson `[1 4 6 4 1] / 16` kernel is
//! centred *on* pixel `2i` and would shift every level by a quarter of its own pixel, so a
//! source position found at a coarse level would point at a different place at the fine
//! one. `[1 3 3 1]` has a frequency response of `cos³(ω/2)`: zero at Nyquist, −3.9 dB at
//! half-Nyquist — blurrier than an ideal low-pass, which neighbourhood matching tolerates
//! well (the coarse levels only steer the layout).
//!
//! **Borders** are clamped (edge pixels repeat), like [`crate::example::Example`]'s
//! lookups: examples are not tileable, so wrapping would blend unrelated opposite edges.
//! An odd size `n` halves to `ceil(n / 2)`; the last output pixel's taps beyond the edge
//! clamp.

use crate::example::Example;

/// A dense multi-channel float image: row-major, top row first, channels interleaved.
#[derive(Clone, Debug, PartialEq)]
pub struct Image {
    pub width: usize,
    pub height: usize,
    pub channels: usize,
    /// `width * height * channels` values.
    pub data: Vec<f32>,
}

impl Image {
    /// A zero-filled image.
    pub fn new(width: usize, height: usize, channels: usize) -> Self {
        Self {
            width,
            height,
            channels,
            data: vec![0.0; width * height * channels],
        }
    }

    /// All channels of an example, in [`Example::channel_names`] order (R, G, B, then A and
    /// height when present), so that alpha and height are synthesized jointly with colour.
    pub fn from_example(ex: &Example) -> Self {
        let c = ex.num_channels();
        let mut img = Self::new(ex.width, ex.height, c);
        for j in 0..ex.height {
            for i in 0..ex.width {
                let k = (j * ex.width + i) * c;
                ex.pixel(i, j, &mut img.data[k..k + c]);
            }
        }
        img
    }

    /// The channels of pixel (x, y) (column, row).
    #[inline]
    pub fn pixel(&self, x: usize, y: usize) -> &[f32] {
        let k = (y * self.width + x) * self.channels;
        &self.data[k..k + self.channels]
    }

    /// Mutable channels of pixel (x, y).
    #[inline]
    pub fn pixel_mut(&mut self, x: usize, y: usize) -> &mut [f32] {
        let k = (y * self.width + x) * self.channels;
        &mut self.data[k..k + self.channels]
    }

    /// Bilinear lookup at continuous position (x, y) (pixel centres at +0.5), clamped to the
    /// image, all channels into `out`.
    #[inline]
    pub fn bilinear(&self, x: f32, y: f32, out: &mut [f32]) {
        let fx = (x - 0.5).clamp(0.0, (self.width - 1) as f32);
        let fy = (y - 0.5).clamp(0.0, (self.height - 1) as f32);
        let (x0, y0) = (fx as usize, fy as usize);
        let (x1, y1) = ((x0 + 1).min(self.width - 1), (y0 + 1).min(self.height - 1));
        let (tx, ty) = (fx - x0 as f32, fy - y0 as f32);
        let c = self.channels;
        let (a, b) = (self.pixel(x0, y0), self.pixel(x1, y0));
        let (d, e) = (self.pixel(x0, y1), self.pixel(x1, y1));
        for k in 0..c {
            let top = a[k] + (b[k] - a[k]) * tx;
            let bot = d[k] + (e[k] - d[k]) * tx;
            out[k] = top + (bot - top) * ty;
        }
    }

    /// One pyramid step: `[1 3 3 1] / 8` separable filter and decimation by 2 (see the
    /// module documentation for why this kernel).
    pub fn downsample(&self) -> Image {
        let c = self.channels;
        let (w, h) = (self.width, self.height);
        let (w2, h2) = (w.div_ceil(2), h.div_ceil(2));
        const K: [f32; 4] = [1.0 / 8.0, 3.0 / 8.0, 3.0 / 8.0, 1.0 / 8.0];
        let clampi = |i: isize, n: usize| i.clamp(0, n as isize - 1) as usize;
        // Horizontal pass: w2 x h.
        let mut tmp = vec![0.0f32; w2 * h * c];
        for y in 0..h {
            for x in 0..w2 {
                let o = (y * w2 + x) * c;
                for (t, &kw) in K.iter().enumerate() {
                    let sx = clampi(2 * x as isize - 1 + t as isize, w);
                    let s = self.pixel(sx, y);
                    for k in 0..c {
                        tmp[o + k] += kw * s[k];
                    }
                }
            }
        }
        // Vertical pass: w2 x h2.
        let mut out = Image::new(w2, h2, c);
        for y in 0..h2 {
            for (t, &kw) in K.iter().enumerate() {
                let sy = clampi(2 * y as isize - 1 + t as isize, h);
                let src = &tmp[sy * w2 * c..(sy + 1) * w2 * c];
                let dst = &mut out.data[y * w2 * c..(y + 1) * w2 * c];
                for (d, s) in dst.iter_mut().zip(src) {
                    *d += kw * s;
                }
            }
        }
        out
    }
}

/// A Gaussian pyramid: `levels[0]` is the input, each next level half the size.
#[derive(Clone, Debug)]
pub struct Pyramid {
    pub levels: Vec<Image>,
}

impl Pyramid {
    /// Builds `n_levels` levels (at least 1) from `img`.
    pub fn build(img: Image, n_levels: usize) -> Self {
        let mut levels = vec![img];
        while levels.len() < n_levels.max(1) {
            let next = levels.last().expect("non-empty").downsample();
            levels.push(next);
        }
        Self { levels }
    }

    /// Number of levels.
    pub fn len(&self) -> usize {
        self.levels.len()
    }

    /// Always false (a pyramid has at least its input level).
    pub fn is_empty(&self) -> bool {
        self.levels.is_empty()
    }

    /// Level `l` (0 = finest).
    pub fn level(&self, l: usize) -> &Image {
        &self.levels[l]
    }
}

/// How many levels fit when the coarsest level's shorter side must stay at least
/// `min_side` pixels (and no more than `max_levels`): one plus the number of halvings of
/// `min(width, height)` that keep it `>= min_side`. Returns at least 1.
pub fn levels_for(width: usize, height: usize, min_side: usize, max_levels: usize) -> usize {
    let mut side = width.min(height);
    let mut n = 1;
    while n < max_levels && side.div_ceil(2) >= min_side {
        side = side.div_ceil(2);
        n += 1;
    }
    n
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ramp(w: usize, h: usize) -> Image {
        let mut img = Image::new(w, h, 2);
        for y in 0..h {
            for x in 0..w {
                let p = img.pixel_mut(x, y);
                p[0] = x as f32 + 0.5; // pixel centre, level-0 units
                p[1] = 3.0;
            }
        }
        img
    }

    #[test]
    fn decimation_keeps_pixel_centres_registered() {
        // A linear ramp equal to the x coordinate of the pixel centre must come out, away
        // from the clamped border, as the centre of the coarse pixel in level-0 units:
        // (i + 0.5) * 2. A kernel centred on pixel 2i would give 2i + 0.5 instead.
        let img = ramp(16, 4);
        let d = img.downsample();
        assert_eq!((d.width, d.height), (8, 2));
        for i in 1..7 {
            let v = d.pixel(i, 1)[0];
            assert!((v - (i as f32 + 0.5) * 2.0).abs() < 1e-5, "{i}: {v}");
            assert!(
                (d.pixel(i, 1)[1] - 3.0).abs() < 1e-6,
                "constants are preserved"
            );
        }
        let dd = d.downsample();
        for i in 1..3 {
            let v = dd.pixel(i, 0)[0];
            assert!((v - (i as f32 + 0.5) * 4.0).abs() < 1e-5, "{i}: {v}");
        }
    }

    #[test]
    fn odd_sizes_round_up_and_levels_are_counted() {
        let p = Pyramid::build(ramp(13, 7), 3);
        let sizes: Vec<_> = p.levels.iter().map(|l| (l.width, l.height)).collect();
        assert_eq!(sizes, vec![(13, 7), (7, 4), (4, 2)]);
        assert_eq!(levels_for(64, 64, 16, 10), 3); // 64, 32, 16
        assert_eq!(levels_for(192, 192, 16, 10), 4); // 192, 96, 48, 24
        assert_eq!(levels_for(512, 300, 16, 4), 4);
        assert_eq!(levels_for(10, 10, 16, 10), 1);
    }

    #[test]
    fn bilinear_interpolates_between_centres() {
        let img = ramp(8, 2);
        let mut o = [0.0; 2];
        img.bilinear(2.25, 1.0, &mut o);
        assert!((o[0] - 2.25).abs() < 1e-6);
        img.bilinear(-3.0, 1.0, &mut o); // clamped to the first centre
        assert!((o[0] - 0.5).abs() < 1e-6);
    }
}
