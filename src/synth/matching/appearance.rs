//! Appearance space (Lefebvre & Hoppe 2006, as used by paper 001 §4.1.1).
//!
//! l2 distance between single pixels — or between small windows of them — is a poor
//! measure of whether two places of an example look alike: a mortar line one pixel to the
//! left is as far from a brick as a different brick. Appearance space replaces every
//! example pixel by the PCA projection of its whole 5x5 neighbourhood of *all* matched
//! channels (weighted colour, alpha, height), so each "pixel" already says what is around
//! it, and comparing a few of them compares much larger neighbourhoods. Every matcher of
//! [`crate::synth`] then compares appearance vectors instead of raw channels.
//!
//! - **Neighbourhood**: `window x window` pixels (default 5), each channel premultiplied by
//!   the square root of its matching weight (so the plain l2 of the vectors is the weighted
//!   distance), and the samples by a Gaussian of σ = window / 4 (the centre matters most,
//!   as in Lefebvre & Hoppe), borders clamped (edge pixels repeat, like every other lookup
//!   of the example).
//! - **Projection**: the leading [`DIMS`] principal directions of those vectors, fitted on
//!   an evenly spaced subset of the pixels ([`super::search::pca`]). Projection is
//!   orthonormal, so appearance distances are lower bounds of the neighbourhood distances
//!   and equal to them up to the dropped variance, which is reported
//!   (`Appearance::kept_variance`; 5x5 RGB neighbourhoods of the bundled examples keep
//!   ~90–97% in 8 dimensions).
//! - **Pyramids**: multi-resolution methods build one appearance space per pyramid level
//!   from that level's pixels (its own PCA), so a coarse level's vectors summarise its own
//!   (larger) neighbourhoods.
//!
//! `--appearance rgb` keeps the raw weighted channels instead ([`AppearanceMode::Rgb`]),
//! for comparison.

use super::search::pca::Pca;
use crate::pyramid::Image;
use rayon::prelude::*;
use serde::Serialize;

/// Appearance-space dimension: 8, as Lefebvre & Hoppe's colour examples. More dimensions
/// keep little more variance on 5x5 neighbourhoods and cost every distance.
pub const DIMS: usize = 8;

/// Side of the neighbourhood summarised by an appearance vector.
pub const WINDOW: usize = 5;

/// What matchers compare (`--appearance`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum AppearanceMode {
    /// The weighted channels themselves (colour, alpha, height): the old behaviour.
    Rgb,
    /// PCA-projected 5x5 neighbourhoods ([`DIMS`] dimensions): the default.
    #[default]
    Pca,
}

impl AppearanceMode {
    /// The name used on the command line and in report.json.
    pub fn name(self) -> &'static str {
        match self {
            AppearanceMode::Rgb => "rgb",
            AppearanceMode::Pca => "pca",
        }
    }
}

/// What was kept of one level's neighbourhoods (reported).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct AppearanceInfo {
    pub dims: usize,
    pub window: usize,
    /// Share of the neighbourhoods' variance the projection keeps (1 for `rgb`).
    pub kept_variance: f64,
    /// Weight of the feature-distance channel among the matched channels
    /// ([`super::feature_distance`], `--feature-distance`); 0: none.
    pub feature_distance: f32,
    /// With a BTF sample, the reflectance vectors the neighbourhoods are made of
    /// ([`super::reflectance`]); `None`: the example's weighted channels.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub reflectance: Option<super::reflectance::ReflectanceInfo>,
}

/// An example level transformed to appearance space: `width x height` pixels of `dims`
/// values, row-major.
#[derive(Clone, Debug)]
pub struct Appearance {
    pub image: Image,
    pub info: AppearanceInfo,
}

impl Appearance {
    /// The appearance space of `weighted` (an example level whose channels are already
    /// premultiplied by the square roots of their weights) in `mode`: for [`AppearanceMode::Pca`]
    /// `dims` PCA dimensions of `window x window` neighbourhoods, for
    /// [`AppearanceMode::Rgb`] the image itself.
    pub fn build(weighted: &Image, mode: AppearanceMode, window: usize, dims: usize) -> Self {
        match mode {
            AppearanceMode::Rgb => Self {
                image: weighted.clone(),
                info: AppearanceInfo {
                    dims: weighted.channels,
                    window: 1,
                    kept_variance: 1.0,
                    feature_distance: 0.0,
                    reflectance: None,
                },
            },
            AppearanceMode::Pca => Self::pca(weighted, window, dims),
        }
    }

    fn pca(img: &Image, window: usize, dims: usize) -> Self {
        assert!(window % 2 == 1, "appearance window must be odd");
        let (w, h, c) = (img.width, img.height, img.channels);
        let r = (window / 2) as isize;
        let sigma = window as f32 / 4.0;
        let gauss: Vec<f32> = (-r..=r)
            .flat_map(|dy| (-r..=r).map(move |dx| (dx * dx + dy * dy) as f32))
            .map(|d2| (-d2 / (2.0 * sigma * sigma)).exp().sqrt())
            .collect();
        let dim = window * window * c;
        let neighbourhood = |x: usize, y: usize, out: &mut [f32]| {
            let mut k = 0;
            for dy in -r..=r {
                let sy = (y as isize + dy).clamp(0, h as isize - 1) as usize;
                for dx in -r..=r {
                    let sx = (x as isize + dx).clamp(0, w as isize - 1) as usize;
                    let g = gauss[k / c];
                    for &v in img.pixel(sx, sy) {
                        out[k] = v * g;
                        k += 1;
                    }
                }
            }
        };
        let mut data = vec![0.0f32; w * h * dim];
        data.par_chunks_mut(w * dim)
            .enumerate()
            .for_each(|(y, row)| {
                for x in 0..w {
                    neighbourhood(x, y, &mut row[x * dim..(x + 1) * dim]);
                }
            });
        let k = dims.min(dim);
        let pca = Pca::fit(&data, dim, k);
        let mut out = Image::new(w, h, dims);
        out.data
            .par_chunks_mut(dims)
            .zip(data.par_chunks(dim))
            .for_each(|(o, v)| pca.project(v, &mut o[..k]));
        Self {
            image: out,
            info: AppearanceInfo {
                dims,
                window,
                kept_variance: pca.kept_variance(),
                feature_distance: 0.0,
                reflectance: None,
            },
        }
    }
}

impl crate::cache::Persist for Appearance {
    fn save(&self, w: &mut crate::cache::Writer) {
        w.image(&self.image);
        w.usize(self.info.dims);
        w.usize(self.info.window);
        w.f64(self.info.kept_variance);
    }
    fn load(r: &mut crate::cache::Reader<'_>) -> Option<Self> {
        let image = r.image()?;
        let info = AppearanceInfo {
            dims: r.usize()?,
            window: r.usize()?,
            kept_variance: r.f64()?,
            feature_distance: 0.0,
            reflectance: None,
        };
        (info.dims == image.channels && image.data.iter().all(|v| v.is_finite()))
            .then_some(Self { image, info })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn stripes(w: usize, h: usize) -> Image {
        let mut img = Image::new(w, h, 3);
        for y in 0..h {
            for x in 0..w {
                let v = if (x / 3) % 2 == 0 { 1.0 } else { 0.0 };
                img.pixel_mut(x, y).copy_from_slice(&[v, 0.5 * v, 0.2]);
            }
        }
        img
    }

    #[test]
    fn rgb_mode_is_the_image() {
        let img = stripes(16, 8);
        let a = Appearance::build(&img, AppearanceMode::Rgb, WINDOW, DIMS);
        assert_eq!(a.image, img);
        assert_eq!(a.info.kept_variance, 1.0);
    }

    /// Pixels with the same colour but different surroundings (the first and last column
    /// of a stripe) are equal in RGB and told apart in appearance space; pixels with the
    /// same surroundings (one period apart) stay equal.
    #[test]
    fn pca_mode_sees_the_neighbourhood() {
        let img = stripes(36, 12);
        let a = Appearance::build(&img, AppearanceMode::Pca, WINDOW, DIMS);
        assert_eq!(a.image.channels, DIMS);
        assert!(a.info.kept_variance > 0.99, "{}", a.info.kept_variance);
        let d = |p: (usize, usize), q: (usize, usize)| -> f32 {
            let (u, v) = (a.image.pixel(p.0, p.1), a.image.pixel(q.0, q.1));
            u.iter().zip(v).map(|(x, y)| (x - y) * (x - y)).sum()
        };
        // Columns 6 and 8 are both in a bright stripe (6..9), at its left and right edge.
        assert!(d((6, 6), (8, 6)) > 0.1, "{}", d((6, 6), (8, 6)));
        // One period (6 px) apart, away from the clamped border: the same neighbourhood.
        assert!(d((12, 6), (18, 6)) < 1e-8);
    }
}
