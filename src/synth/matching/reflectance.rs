//! The reflectance space of a BTF sample: what the appearance-space methods (texture
//! optimisation, patch sampling, coherent synthesis, jump maps) match when they synthesize
//! a BTF (`--btf` with `--method optimise|patches|coherent|jump`).
//!
//! *Why*: texton synthesis (paper 003, [`crate::synth::textons`]) picks one source per
//! texel for every image at once, so the surface BTF is one mesostructure under every
//! light — but it is multiscale synthesis underneath, which breaks the rows of a brick
//! relief the default method keeps (docs/synthesis.md). The other methods already find one
//! source per texel and copy every channel from it; they only need to *compare* pixels by
//! their look under all lights. A pixel's reflectance vector — its linear RGB in every
//! image, each image weighted 1/L so that a squared distance is the mean over the L images
//! of the squared colour difference — is that look (003 §3's "appearance vector" without
//! the filter bank: the appearance space's 5x5 neighbourhoods, built on top, see the
//! spatial structure). With 3L values per pixel (96 for 32 lights) it is reduced by PCA to
//! [`DIMS`] values first, so that the appearance space's neighbourhood vectors stay short
//! (5 x 5 x 8 = 200 instead of 2,400); the kept share of the variance is reported.
//!
//! A sample of one image is its RGB unchanged: the same matching as the plain example.

use super::search::pca::{fit_rows, Pca};
use crate::btf::BtfSample;
use crate::pyramid::Image;
use rayon::prelude::*;
use serde::Serialize;

/// Values per pixel kept of the reflectance vectors (when a sample has more than this
/// many channels, i.e. three or more images).
pub const DIMS: usize = 8;

/// What the reduction kept (reported as `appearance.reflectance`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct ReflectanceInfo {
    /// Images of the sample (L).
    pub images: usize,
    /// Values per pixel matched (min(3L, [`DIMS`])).
    pub dims: usize,
    /// Share of the reflectance vectors' variance those values keep (1 when nothing is
    /// dropped).
    pub kept_variance: f64,
}

/// The sample's pixels as reflectance vectors, reduced to at most `dims` values each
/// (the image every appearance-space method is handed instead of the weighted example).
pub fn reflectance(sample: &BtfSample, dims: usize) -> (Image, ReflectanceInfo) {
    let (w, h, l) = (sample.width, sample.height, sample.images.len());
    let c = 3 * l;
    // Each image weighted 1/L in squared distance: values scaled by 1/√L.
    let s = 1.0 / (l as f32).sqrt();
    let vector = |p: usize, v: &mut [f32]| {
        for (i, im) in sample.images.iter().enumerate() {
            for k in 0..3 {
                v[3 * i + k] = im.rgb[p][k] * s;
            }
        }
    };
    let n = w * h;
    if c <= dims {
        let mut image = Image::new(w, h, c);
        image
            .data
            .par_chunks_mut(c)
            .enumerate()
            .for_each(|(p, v)| vector(p, v));
        let info = ReflectanceInfo {
            images: l,
            dims: c,
            kept_variance: 1.0,
        };
        return (image, info);
    }
    // The rows `Pca::fit` would pick, made alone: the vectors of every pixel are never
    // held at once (3L floats a pixel: a sample of many images is already most of a run's
    // memory).
    let rows = fit_rows(n);
    let mut fit = vec![0.0f32; rows.len() * c];
    fit.par_chunks_mut(c)
        .zip(&rows)
        .for_each(|(v, &p)| vector(p, v));
    let pca = Pca::fit(&fit, c, dims);
    drop(fit);
    let mut image = Image::new(w, h, dims);
    image.data.par_chunks_mut(dims).enumerate().for_each_init(
        || vec![0.0f32; c],
        |v, (p, o)| {
            vector(p, v);
            pca.project(v, o);
        },
    );
    let info = ReflectanceInfo {
        images: l,
        dims,
        kept_variance: pca.kept_variance(),
    };
    (image, info)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::example::Example;
    use glam::DVec3;

    fn image(w: usize, h: usize, f: impl Fn(usize, usize) -> [f32; 3]) -> Example {
        let mut rgb = Vec::with_capacity(w * h);
        for y in 0..h {
            for x in 0..w {
                rgb.push(f(x, y));
            }
        }
        Example {
            path: "t.png".into(),
            width: w,
            height: h,
            rgb,
            alpha: None,
            maps: Vec::new(),
        }
    }

    #[test]
    fn one_image_is_its_rgb_unchanged() {
        let ex = image(7, 5, |x, y| [x as f32 * 0.1, y as f32 * 0.2, 0.5]);
        let s = BtfSample::from_images(vec![ex.clone()], vec![DVec3::Z]).unwrap();
        let (img, info) = reflectance(&s, DIMS);
        assert_eq!((img.channels, info.dims, info.kept_variance), (3, 3, 1.0));
        assert_eq!(
            img.data,
            ex.rgb.iter().flatten().copied().collect::<Vec<_>>()
        );
    }

    /// Distances in the reduced space are the mean over images of the squared colour
    /// differences, up to the variance PCA drops (none here: the images vary along two
    /// directions only, so 8 components keep everything).
    #[test]
    fn distances_are_the_mean_over_images() {
        let lights: Vec<DVec3> = (0..6)
            .map(|i| DVec3::new((i as f64).cos(), (i as f64).sin(), 1.0).normalize())
            .collect();
        let imgs: Vec<Example> = (0..6)
            .map(|i| {
                let a = i as f32 * 0.3;
                image(9, 9, move |x, y| {
                    let (u, v) = (x as f32 / 8.0, y as f32 / 8.0);
                    [u * a.cos() + v, u * a.sin(), v * (1.0 + a)]
                })
            })
            .collect();
        let s = BtfSample::from_images(imgs.clone(), lights).unwrap();
        let (img, info) = reflectance(&s, DIMS);
        assert_eq!((img.channels, info.images), (DIMS, 6));
        assert!(info.kept_variance > 0.999_999, "{}", info.kept_variance);
        for (p, q) in [(0usize, 80usize), (3, 40), (17, 62)] {
            let want: f32 = imgs
                .iter()
                .map(|im| {
                    (0..3)
                        .map(|k| (im.rgb[p][k] - im.rgb[q][k]).powi(2))
                        .sum::<f32>()
                })
                .sum::<f32>()
                / 6.0;
            let got: f32 = (0..DIMS)
                .map(|k| (img.data[p * DIMS + k] - img.data[q * DIMS + k]).powi(2))
                .sum();
            assert!(
                (got - want).abs() < 1e-4 * want.max(1e-3),
                "{got} vs {want}"
            );
        }
    }
}
