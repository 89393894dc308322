//! One example level as the patch-based methods match it: its appearance-space table
//! ([`super::appearance`], or the raw weighted channels) and, for every pixel, the places
//! that look most like it ([`super::similar`], [`super::similar::K`] of them).

use super::appearance::{Appearance, AppearanceInfo, AppearanceMode};
use super::features::Features;
use super::similar::Similar;
use crate::pyramid::Image;

/// Pixels closer than this (Chebyshev) are not proposed as similar (see
/// [`super::similar`]).
pub const SIMILAR_EXCLUDE: usize = 2;

/// Lists are built for every second pixel in each direction (see `Similar::build`).
pub const SIMILAR_STRIDE: usize = 2;

/// An example level ready for matching: `K` values per pixel.
#[derive(Debug)]
pub struct Exemplar<const K: usize> {
    pub features: Features<K>,
    pub similar: Similar<K>,
    pub info: AppearanceInfo,
}

impl<const K: usize> Exemplar<K> {
    /// The exemplar of `weighted` (channels premultiplied by the square roots of their
    /// weights). `K` must be [`super::appearance::DIMS`] for [`AppearanceMode::Pca`] and the
    /// channel count for [`AppearanceMode::Rgb`].
    pub fn build(weighted: &Image, mode: AppearanceMode) -> Self {
        Self::from_appearance(&Appearance::build(
            weighted,
            mode,
            super::appearance::WINDOW,
            K,
        ))
    }

    /// The exemplar of an appearance space already built (e.g. loaded from the cache,
    /// [`crate::synth::appearance`]); the similar-place lists start empty and fill lazily.
    pub fn from_appearance(app: &Appearance) -> Self {
        let features = Features::<K>::from_image(&app.image);
        let similar = Similar::new(&features, SIMILAR_EXCLUDE, SIMILAR_STRIDE);
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
