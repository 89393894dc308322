//! One example level as the patch-based methods match it: its appearance-space table
//! ([`super::appearance`], or the raw weighted channels) and, for every pixel, the places
//! that look most like it ([`super::similar`]).

use super::appearance::{Appearance, AppearanceInfo, AppearanceMode};
use super::features::Features;
use super::similar::Similar;
use crate::pyramid::Image;

/// Similar places per pixel proposed by k-coherence (paper 003 uses 11; 8 measured as good
/// on appearance vectors, which already summarise 5x5 neighbourhoods).
pub const SIMILAR_K: usize = 8;

/// Pixels closer than this (Chebyshev) are not proposed as similar (see
/// [`super::similar`]).
pub const SIMILAR_EXCLUDE: usize = 2;

/// Lists are built for every second pixel in each direction (see [`Similar::build`]).
pub const SIMILAR_STRIDE: usize = 2;

/// An example level ready for matching: `K` values per pixel.
#[derive(Clone, Debug)]
pub struct Exemplar<const K: usize> {
    pub features: Features<K>,
    pub similar: Similar,
    pub info: AppearanceInfo,
}

impl<const K: usize> Exemplar<K> {
    /// The exemplar of `weighted` (channels premultiplied by the square roots of their
    /// weights). `K` must be [`super::appearance::DIMS`] for [`AppearanceMode::Pca`] and the
    /// channel count for [`AppearanceMode::Rgb`].
    pub fn build(weighted: &Image, mode: AppearanceMode) -> Self {
        let t0 = std::time::Instant::now();
        let app = Appearance::build(weighted, mode, super::appearance::WINDOW, K);
        let features = Features::<K>::from_image(&app.image);
        let t1 = t0.elapsed().as_secs_f64();
        let similar = Similar::build(&features, SIMILAR_K, SIMILAR_EXCLUDE, SIMILAR_STRIDE);
        eprintln!(
            "appearance {t1:.3} similar {:.3}",
            t0.elapsed().as_secs_f64() - t1
        );
        Self {
            features,
            similar,
            info: app.info,
        }
    }

    pub fn width(&self) -> usize {
        self.features.width
    }

    pub fn height(&self) -> usize {
        self.features.height
    }
}
