//! Feature distance (Lefebvre & Hoppe 2006 §5; the optional channel of paper 001 §4.1.1,
//! `--feature-distance W`).
//!
//! Appearance space compares 5x5 neighbourhoods, and a thin feature — a 3-pixel mortar
//! joint — is a small part of one. Where overlapping patches disagree by a pixel or two
//! (on a curved surface the field turns between their centres), a brick course with its
//! head joints and one without them are about equally far from what the patches average
//! to, and texture optimisation's fixed point drops the joints: bricks come out three
//! times as long as the example's (docs/synthesis.md, "Bricks too long: the head
//! joints"). The *signed distance to the nearest feature border*, appended as one more
//! channel before the PCA, spreads each feature over the pixels around it: a course
//! without its joints then differs over a band of [`REACH`] pixels on either side of
//! every missing joint instead of over the joint's own three.
//!
//! - **Features**: the border between the example's bright and dark parts, split at
//!   Otsu's threshold of its luminance (the mean of its first three matched channels):
//!   mortar and bricks, grout and tiles, gaps and stones. Automatic, as a user gives only
//!   the example; Lefebvre & Hoppe also allow a painted mask.
//! - **Distance**: exact Euclidean (Felzenszwalb & Huttenlocher's two 1-D passes), from
//!   pixel centres, positive on the bright side and negative on the dark, clamped to
//!   ±[`REACH`] pixels and divided by it, times the weight.
//! - **Levels**: computed once on the full example; coarser pyramid levels filter it with
//!   the other channels (the same feature, half the pixels).
//!
//! What it does (docs/synthesis.md, "Feature distance"): more of the example's joints on
//! curved surfaces, at a higher pf8; so it is an option, off by default.

use crate::pyramid::Image;

/// Squared Euclidean distance transform of one row/column (Felzenszwalb & Huttenlocher
/// 2012): `f` holds 0 at sites and a large value elsewhere; returns min_q (p − q)² + f(q).
fn edt_1d(f: &[f32], out: &mut [f32], v: &mut [usize], z: &mut [f32]) {
    let n = f.len();
    let mut k = 0usize;
    v[0] = 0;
    z[0] = f32::NEG_INFINITY;
    z[1] = f32::INFINITY;
    for q in 1..n {
        loop {
            let p = v[k];
            let s =
                ((f[q] + (q * q) as f32) - (f[p] + (p * p) as f32)) / (2.0 * (q as f32 - p as f32));
            if s <= z[k] && k > 0 {
                k -= 1;
                continue;
            }
            if s <= z[k] {
                // k == 0: replace the only parabola.
                v[0] = q;
                z[0] = f32::NEG_INFINITY;
                z[1] = f32::INFINITY;
                break;
            }
            k += 1;
            v[k] = q;
            z[k] = s;
            z[k + 1] = f32::INFINITY;
            break;
        }
    }
    k = 0;
    for (q, o) in out.iter_mut().enumerate() {
        while z[k + 1] < q as f32 {
            k += 1;
        }
        let p = v[k];
        let d = q as f32 - p as f32;
        *o = d * d + f[p];
    }
}

/// Squared distance from every pixel to the nearest pixel where `site` is true.
fn edt(site: &[bool], w: usize, h: usize) -> Vec<f32> {
    const BIG: f32 = 1e12;
    let mut g: Vec<f32> = site.iter().map(|&s| if s { 0.0 } else { BIG }).collect();
    let n = w.max(h);
    let (mut f, mut o, mut v, mut z) = (
        vec![0.0f32; n],
        vec![0.0f32; n],
        vec![0usize; n],
        vec![0.0f32; n + 1],
    );
    for x in 0..w {
        for y in 0..h {
            f[y] = g[y * w + x];
        }
        edt_1d(&f[..h], &mut o[..h], &mut v, &mut z);
        for y in 0..h {
            g[y * w + x] = o[y];
        }
    }
    for y in 0..h {
        f[..w].copy_from_slice(&g[y * w..(y + 1) * w]);
        edt_1d(&f[..w], &mut o[..w], &mut v, &mut z);
        g[y * w..(y + 1) * w].copy_from_slice(&o[..w]);
    }
    g
}

/// Otsu's threshold of `values`: the split of their range (256 bins) with the largest
/// between-class variance.
fn otsu(values: &[f32]) -> f32 {
    let (lo, hi) = values
        .iter()
        .fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), &x| {
            (a.min(x), b.max(x))
        });
    if hi <= lo {
        return lo;
    }
    let mut hist = [0u64; 256];
    for &x in values {
        let b = (((x - lo) / (hi - lo)) * 255.0).round() as usize;
        hist[b.min(255)] += 1;
    }
    let total = values.len() as f64;
    let sum_all: f64 = hist
        .iter()
        .enumerate()
        .map(|(i, &c)| i as f64 * c as f64)
        .sum();
    // Splits between empty bins are equally good: take the middle of the best run.
    let (mut w0, mut sum0, mut best, mut first, mut last) = (0.0f64, 0.0f64, -1.0f64, 0, 0);
    for (t, &c) in hist.iter().enumerate() {
        w0 += c as f64;
        sum0 += t as f64 * c as f64;
        let w1 = total - w0;
        if w0 == 0.0 || w1 == 0.0 {
            continue;
        }
        let (m0, m1) = (sum0 / w0, (sum_all - sum0) / w1);
        let between = w0 * w1 * (m0 - m1) * (m0 - m1);
        if between > best {
            (best, first, last) = (between, t, t);
        } else if between == best && last + 1 == t {
            last = t;
        }
    }
    lo + ((first + last) as f32 / 2.0 + 0.5) / 255.0 * (hi - lo)
}

/// Pixels over which the distance grows before it is clamped: about a third of a brick's
/// width in the bundled brick crops. 16 kept more joints and raised pf8 further (Spot,
/// double torus, Blub; docs/synthesis.md, "Feature distance").
pub const REACH: f32 = 8.0;

/// Signed distance (pixels, clamped to ±`clamp`, divided by it) from every pixel centre to
/// the border between the example's bright and dark parts (Otsu's threshold of its
/// luminance): in [−1, 1], positive on the bright side.
pub fn signed_distance(img: &Image, clamp: f32) -> Vec<f32> {
    let (w, h) = (img.width, img.height);
    let c = img.channels.min(3);
    let lum: Vec<f32> = img
        .data
        .chunks_exact(img.channels)
        .map(|p| p[..c].iter().sum::<f32>() / c as f32)
        .collect();
    let t = otsu(&lum);
    let bright: Vec<bool> = lum.iter().map(|&l| l > t).collect();
    let dark: Vec<bool> = bright.iter().map(|b| !b).collect();
    let to_dark = edt(&dark, w, h);
    let to_bright = edt(&bright, w, h);
    bright
        .iter()
        .zip(to_dark.iter().zip(&to_bright))
        .map(|(&b, (&dd, &db))| {
            let d = if b {
                dd.sqrt() - 0.5
            } else {
                -(db.sqrt() - 0.5)
            };
            d.clamp(-clamp, clamp) / clamp
        })
        .collect()
}

/// `weighted` (channels premultiplied by the square roots of their weights) with the
/// feature distance appended as one more channel, times `weight` (its values then span
/// ±`weight`, against colour channels in [0, 1]).
pub fn with_feature_distance(weighted: &Image, weight: f32) -> Image {
    let d = signed_distance(weighted, REACH);
    let c = weighted.channels;
    let mut out = Image::new(weighted.width, weighted.height, c + 1);
    for ((o, p), &s) in out
        .data
        .chunks_exact_mut(c + 1)
        .zip(weighted.data.chunks_exact(c))
        .zip(&d)
    {
        o[..c].copy_from_slice(p);
        o[c] = s * weight;
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Squared distance to the nearest site by brute force.
    fn brute(site: &[bool], w: usize, h: usize) -> Vec<f32> {
        (0..w * h)
            .map(|i| {
                let (x, y) = ((i % w) as f32, (i / w) as f32);
                (0..w * h)
                    .filter(|&j| site[j])
                    .map(|j| {
                        let (u, v) = ((j % w) as f32, (j / w) as f32);
                        (x - u) * (x - u) + (y - v) * (y - v)
                    })
                    .fold(f32::INFINITY, f32::min)
            })
            .collect()
    }

    #[test]
    fn distance_transform_is_exact() {
        let (w, h) = (23, 17);
        // A few scattered sites (a fixed pseudo-random pattern), then a single one.
        let sites: Vec<bool> = (0..w * h).map(|i| (i * 2654435761usize) % 97 < 5).collect();
        assert!(sites.iter().any(|&s| s));
        assert_eq!(edt(&sites, w, h), brute(&sites, w, h));
        let mut one = vec![false; w * h];
        one[5 * w + 20] = true;
        assert_eq!(edt(&one, w, h), brute(&one, w, h));
    }

    /// A bright vertical stripe on a dark ground: the distance is signed, grows by one per
    /// pixel away from the stripe's edges and is clamped.
    #[test]
    fn signed_distance_of_a_stripe() {
        let (w, h) = (40, 6);
        let mut img = Image::new(w, h, 3);
        for y in 0..h {
            for x in 0..w {
                let v = if (10..14).contains(&x) { 0.9 } else { 0.1 };
                img.pixel_mut(x, y).copy_from_slice(&[v, v, v]);
            }
        }
        let d = signed_distance(&img, 8.0);
        let at = |x: usize| d[3 * w + x] * 8.0;
        // Inside: the edge pixels are half a pixel from the border, the middle ones 1.5.
        assert_eq!([at(10), at(11), at(12), at(13)], [0.5, 1.5, 1.5, 0.5]);
        // Outside: negative, growing away from the stripe, clamped at 8 pixels.
        assert_eq!(
            [at(9), at(8), at(5), at(14), at(16)],
            [-0.5, -1.5, -4.5, -0.5, -2.5]
        );
        assert_eq!(at(30), -8.0);
        assert_eq!(at(0), -8.0);
    }

    /// An example of one colour has no border: every value finite, clamped, the same.
    #[test]
    fn a_uniform_example_gives_a_constant_channel() {
        let mut img = Image::new(9, 7, 3);
        img.data.iter_mut().for_each(|v| *v = 0.4);
        let d = signed_distance(&img, 8.0);
        assert!(d.iter().all(|&x| x == d[0] && x.abs() == 1.0), "{d:?}");
    }

    #[test]
    fn otsu_splits_two_clusters() {
        let v: Vec<f32> = (0..100)
            .map(|i| if i < 70 { 0.2 + 0.001 * i as f32 } else { 0.8 })
            .collect();
        let t = otsu(&v);
        assert!(t > 0.3 && t < 0.8, "{t}");
    }

    #[test]
    fn the_channel_is_appended_weighted() {
        let mut img = Image::new(8, 4, 3);
        for (i, v) in img.data.iter_mut().enumerate() {
            *v = if (i / 3) % 8 < 4 { 0.0 } else { 1.0 };
        }
        let out = with_feature_distance(&img, 0.5);
        assert_eq!(out.channels, 4);
        for (o, p) in out.data.chunks_exact(4).zip(img.data.chunks_exact(3)) {
            assert_eq!(&o[..3], p);
            assert!(o[3].abs() <= 0.5 && o[3] != 0.0);
        }
        assert!(out.pixel(0, 0)[3] < 0.0 && out.pixel(7, 0)[3] > 0.0);
    }
}
