//! What every synthesis method matches with, below the methods themselves: the weighted
//! example tables ([`features`]), neighbourhood vectors and nearest-neighbour search
//! ([`search`]: brute force, PCA + kd-tree, k-coherence).

pub mod features;
pub mod search;
