//! What every synthesis method matches with, below the methods themselves: appearance
//! space ([`appearance`]) with its optional feature-distance channel
//! ([`feature_distance`]), the example tables matchers read ([`features`]), similar-place
//! lists for k-coherence ([`similar`]), and neighbourhood vectors and nearest-neighbour
//! search ([`search`]: brute force, PCA + kd-tree, k-coherence), the jump maps of
//! paper 002 ([`jumpmap`]), copies put on the example's pixel centres ([`pixel_grid`]), and
//! the reflectance space a BTF sample is matched in ([`reflectance`]).

pub mod appearance;
pub mod exemplar;
pub mod feature_distance;
pub mod features;
pub mod jumpmap;
pub mod pixel_grid;
pub mod reflectance;
pub mod search;
pub mod similar;
