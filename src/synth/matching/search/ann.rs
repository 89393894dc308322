//! Approximate nearest-neighbour search: PCA projection, kd-tree, exact re-ranking.
//!
//! The paper accelerates the multiscale search with TSVQ or ANN (000 §4, citing Arya &
//! Mount). Here: project every example neighbourhood onto its leading principal
//! directions ([`super::pca`]), build a kiddo kd-tree over the projections, and for a query
//! take the [`AnnParams::candidates`] nearest projections and re-rank them by the exact
//! weighted distance in the full space, keeping the [`super::BEST_N`] best for the paper's
//! randomised choice. The kd-tree search itself is exact in the projected space, so the only
//! approximation is the projection: a candidate whose discarded components happen to be
//! far away can be missed. More candidates or more dimensions shrink that risk (measured in
//! `docs/multiscale.md`).
//!
//! Missing query samples (off an open surface) project as the example mean, which adds
//! nothing to the projected coordinates; the re-ranking then ignores them exactly.

use super::pca::Pca;
use super::{Features, Prepared, TopN};
use crate::error::{Error, Result};
use kiddo::{ImmutableKdTree, SquaredEuclidean};
use std::num::NonZeroUsize;

/// Dimensions the kd-tree may use (const generics need a closed set).
pub const SUPPORTED_DIMS: [usize; 6] = [4, 6, 8, 10, 12, 16];

/// ANN settings.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AnnParams {
    /// PCA dimension (one of [`SUPPORTED_DIMS`]).
    pub dims: usize,
    /// Projected nearest neighbours re-ranked exactly.
    pub candidates: usize,
}

impl Default for AnnParams {
    /// 8 dimensions and 32 candidates: see `docs/multiscale.md` for the measurements
    /// (kept variance, agreement with brute force and speed) behind these values.
    fn default() -> Self {
        Self {
            dims: 8,
            candidates: 32,
        }
    }
}

enum Tree {
    D4(ImmutableKdTree<f32, 4>),
    D6(ImmutableKdTree<f32, 6>),
    D8(ImmutableKdTree<f32, 8>),
    D10(ImmutableKdTree<f32, 10>),
    D12(ImmutableKdTree<f32, 12>),
    D16(ImmutableKdTree<f32, 16>),
}

/// A kd-tree over the PCA projections of one [`Features`] set.
pub struct AnnIndex {
    pub pca: Pca,
    pub params: AnnParams,
    tree: Tree,
}

impl std::fmt::Debug for AnnIndex {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("AnnIndex")
            .field("params", &self.params)
            .field("kept_variance", &self.pca.kept_variance())
            .finish()
    }
}

fn build_tree<const K: usize>(proj: &[f32]) -> Result<ImmutableKdTree<f32, K>> {
    let pts: Vec<[f32; K]> = proj
        .chunks_exact(K)
        .map(|c| c.try_into().expect("chunk of K"))
        .collect();
    ImmutableKdTree::<f32, K>::new_from_slice(&pts)
        .map_err(|e| Error::invalid(format!("cannot build the kd-tree: {e:?}")))
}

fn query_tree<const K: usize>(
    tree: &ImmutableKdTree<f32, K>,
    p: &[f32],
    n: NonZeroUsize,
    out: &mut Vec<u32>,
) {
    let q: [f32; K] = p[..K].try_into().expect("K coordinates");
    out.clear();
    out.extend(
        tree.query(&q)
            .nearest_n::<SquaredEuclidean<f32>>(n)
            .execute()
            .into_iter()
            .map(|r| r.item),
    );
}

impl AnnIndex {
    /// Fits the PCA and builds the tree for `features`.
    pub fn build(features: &Features, params: AnnParams) -> Result<Self> {
        if !SUPPORTED_DIMS.contains(&params.dims) {
            return Err(Error::invalid(format!(
                "ANN dimension {} is not supported (use one of {SUPPORTED_DIMS:?})",
                params.dims
            )));
        }
        if params.candidates == 0 {
            return Err(Error::invalid("ANN candidate count must be at least 1"));
        }
        let dim = features.dim();
        let k = params.dims.min(dim);
        let pca = Pca::fit(&features.pca_rows(), dim, k);
        // Pad to the tree dimension when the vectors are shorter than it.
        let kd = params.dims;
        let n = features.len();
        let mut proj = vec![0.0f32; n * kd];
        {
            use rayon::prelude::*;
            proj.par_chunks_mut(kd).enumerate().for_each_init(
                || vec![0.0f32; dim],
                |v, (i, out)| {
                    features.vector_into(i, v);
                    pca.project(v, &mut out[..k]);
                },
            );
        }
        let tree = match kd {
            4 => Tree::D4(build_tree(&proj)?),
            6 => Tree::D6(build_tree(&proj)?),
            8 => Tree::D8(build_tree(&proj)?),
            10 => Tree::D10(build_tree(&proj)?),
            12 => Tree::D12(build_tree(&proj)?),
            _ => Tree::D16(build_tree(&proj)?),
        };
        Ok(Self { pca, params, tree })
    }

    /// The best matches of `q` into `top` (cleared first). `scratch` holds the projected
    /// query and candidate list between calls.
    pub fn search(
        &self,
        features: &Features,
        q: &Prepared,
        scratch: &mut AnnScratch,
        top: &mut TopN,
    ) {
        let kd = self.params.dims;
        scratch.proj.clear();
        scratch.proj.resize(kd, 0.0);
        let k = self.pca.k;
        if q.complete {
            self.pca.project(&q.v, &mut scratch.proj[..k]);
        } else {
            self.pca
                .project_masked(&q.v, &q.mask, &mut scratch.proj[..k]);
        }
        let n = NonZeroUsize::new(self.params.candidates.min(features.len()).max(1))
            .expect("at least one");
        let out = &mut scratch.cands;
        match &self.tree {
            Tree::D4(t) => query_tree(t, &scratch.proj, n, out),
            Tree::D6(t) => query_tree(t, &scratch.proj, n, out),
            Tree::D8(t) => query_tree(t, &scratch.proj, n, out),
            Tree::D10(t) => query_tree(t, &scratch.proj, n, out),
            Tree::D12(t) => query_tree(t, &scratch.proj, n, out),
            Tree::D16(t) => query_tree(t, &scratch.proj, n, out),
        }
        // The tree's order among equal projected distances is its own business; sorting
        // makes the re-ranking input canonical.
        out.sort_unstable();
        out.dedup();
        top.clear();
        features.rerank(q, out, top);
    }
}

/// Per-thread buffers for [`AnnIndex::search`].
#[derive(Clone, Debug, Default)]
pub struct AnnScratch {
    proj: Vec<f32>,
    cands: Vec<u32>,
}
