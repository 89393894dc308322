//! Everything precomputed about an example for multiscale synthesis: its pyramid, the
//! neighbourhood features of every level and pass, and the search structures over them.
//! Shared by the 2D reference synthesizer and the surface synthesizer, so that the two
//! differ only in how target neighbourhoods are sampled.
//!
//! Levels and passes (paper 000 §4):
//! * the coarsest level is synthesized once, by exhaustive search, with a
//!   `coarsest x coarsest` neighbourhood of the level itself (samples not yet generated
//!   are missing);
//! * every other level in two passes: pass 1 with only the `coarse x coarse` block of the
//!   next coarser level, pass 2 with the `fine x fine` block of the level plus that coarse
//!   block — with ANN, k-coherence, or exhaustive search ([`Method`]).

use super::ann::{AnnIndex, AnnParams, AnnScratch};
use super::kcoherence::{self, KParams, KScratch, KnnLists};
use super::{Features, Prepared, Shape, TopN};
use crate::error::{Error, Result};
use crate::pyramid::{Image, Pyramid};

/// How the finer levels search the example.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Method {
    /// Exhaustive (exact; slow, for reference and tests).
    Brute,
    /// PCA + kd-tree + exact re-ranking ([`super::ann`]).
    Ann(AnnParams),
    /// k-coherence ([`super::kcoherence`], paper 003 §5.2).
    KCoherence(KParams),
}

impl Method {
    /// Short name for reports ("brute", "ann", "kcoherence").
    pub fn name(&self) -> &'static str {
        match self {
            Method::Brute => "brute",
            Method::Ann(_) => "ann",
            Method::KCoherence(_) => "kcoherence",
        }
    }
}

/// Neighbourhood sizes and search method.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ModelParams {
    /// Current-level block of pass 2 (000: 9).
    pub fine: usize,
    /// Coarser-level block of both passes (000: 5).
    pub coarse: usize,
    /// Block of the coarsest level (the paper does not say; see `docs/multiscale.md`).
    pub coarsest: usize,
    pub method: Method,
}

impl Default for ModelParams {
    fn default() -> Self {
        Self {
            fine: 9,
            coarse: 5,
            coarsest: 5,
            method: Method::KCoherence(KParams::default()),
        }
    }
}

impl ModelParams {
    /// These parameters with a `k`×`k` block of the current level (odd); the coarser
    /// level's block is kept (it carries the layout).
    pub fn with_side(self, k: usize) -> Self {
        Self { fine: k, ..self }
    }
}

/// Which neighbourhood a search uses.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Pass {
    /// The single exhaustive pass of the coarsest level.
    Coarsest,
    /// Coarser-level block only.
    One,
    /// Current-level block plus coarser-level block.
    Two,
}

impl Pass {
    /// Stable number for hashing.
    pub fn id(self) -> u64 {
        match self {
            Pass::Coarsest => 0,
            Pass::One => 1,
            Pass::Two => 2,
        }
    }
}

/// Features of one (level, pass) and the ANN index over them when ANN is used.
#[derive(Debug)]
pub struct Searcher {
    pub features: Features,
    pub ann: Option<AnnIndex>,
}

/// The searchers of one level.
#[derive(Debug)]
pub struct LevelModel {
    /// Pass 1 searcher (absent at the coarsest level).
    pub pass1: Option<Searcher>,
    /// Pass 2 searcher, or the coarsest level's.
    pub pass2: Searcher,
    /// k-coherence lists over `pass2`'s pixels (built with pass 2's distance, used by both
    /// passes: the pixels are the same, and the full neighbourhood is the better judge of
    /// which pixels are alike).
    pub lists: Option<KnnLists>,
}

/// The example side of multiscale synthesis.
#[derive(Debug)]
pub struct ExampleModel {
    pub pyramid: Pyramid,
    pub params: ModelParams,
    pub levels: Vec<LevelModel>,
}

/// Per-thread buffers for [`ExampleModel::search`].
#[derive(Clone, Debug, Default)]
pub struct Scratch {
    pub ann: AnnScratch,
    pub kcoh: KScratch,
    pub top: TopN,
}

impl ExampleModel {
    /// Builds the pyramid (`n_levels` levels) and all search structures.
    pub fn build(img: Image, n_levels: usize, params: ModelParams) -> Result<Self> {
        if n_levels == 0 {
            return Err(Error::invalid(
                "multiscale synthesis needs at least one level",
            ));
        }
        Self::from_pyramid(Pyramid::build(img, n_levels), params)
    }

    /// The model of an already built pyramid (e.g. one whose levels were transformed to
    /// appearance space, [`crate::synth::matching::appearance`]): its levels are what is
    /// matched and what synthesized texels hold.
    pub fn from_pyramid(pyramid: Pyramid, params: ModelParams) -> Result<Self> {
        Self::assemble(pyramid, params, None)
    }

    /// The model of a pyramid whose k-coherence lists were computed before (saved in the
    /// cache, [`ExampleModel::lists`]): the features are gathered again (cheap), the lists
    /// are taken as they are. `None` when they do not fit the pyramid and parameters.
    pub fn with_lists(
        pyramid: Pyramid,
        params: ModelParams,
        lists: Vec<Option<KnnLists>>,
    ) -> Option<Self> {
        Self::assemble(pyramid, params, Some(lists)).ok()
    }

    /// Every level's k-coherence lists (`None` where a level has none).
    pub fn lists(&self) -> Vec<Option<&KnnLists>> {
        self.levels.iter().map(|l| l.lists.as_ref()).collect()
    }

    fn assemble(
        pyramid: Pyramid,
        params: ModelParams,
        saved: Option<Vec<Option<KnnLists>>>,
    ) -> Result<Self> {
        let n_levels = pyramid.len();
        if n_levels == 0 {
            return Err(Error::invalid(
                "multiscale synthesis needs at least one level",
            ));
        }
        for (name, v) in [
            ("fine", params.fine),
            ("coarse", params.coarse),
            ("coarsest", params.coarsest),
        ] {
            if v % 2 == 0 {
                return Err(Error::invalid(format!(
                    "{name} neighbourhood side must be odd, got {v}"
                )));
            }
        }
        let c = pyramid.level(0).channels;
        let coarsest = n_levels - 1;
        let s1 = Shape::new(0, params.coarse, c);
        let s2 = Shape::new(params.fine, params.coarse, c);
        let sc = Shape::new(params.coarsest, 0, c);
        let margin = s1.reach().max(s2.reach());
        let ann_params = match params.method {
            Method::Ann(a) => Some(a),
            _ => None,
        };
        let mk = |f: Features| -> Result<Searcher> {
            let ann = match ann_params {
                Some(a) => Some(AnnIndex::build(&f, a)?),
                None => None,
            };
            Ok(Searcher { features: f, ann })
        };
        let mut levels = Vec::with_capacity(n_levels);
        for l in 0..n_levels {
            let lm = if l == coarsest {
                LevelModel {
                    pass1: None,
                    pass2: Searcher {
                        features: Features::build(&pyramid, l, sc, 0)?,
                        ann: None,
                    },
                    lists: None,
                }
            } else {
                // Both passes gather from the same level and upsampled coarser level.
                let f2 = Features::build(&pyramid, l, s2, margin)?;
                let f1 = Features::build_sharing(&pyramid, l, s1, margin, Some(&f2))?;
                LevelModel {
                    pass1: Some(mk(f1)?),
                    pass2: mk(f2)?,
                    lists: None,
                }
            };
            levels.push(lm);
        }
        if let Some(saved) = saved {
            let bad = || Error::invalid("saved k-coherence lists do not fit the example");
            if saved.len() != n_levels {
                return Err(bad());
            }
            for (lm, l) in levels.iter_mut().zip(saved) {
                if let Some(l) = &l {
                    let n = lm.pass2.features.len();
                    if l.len == 0
                        || l.lists.len() != n * l.len
                        || l.lists.iter().any(|&i| i as usize >= n)
                    {
                        return Err(bad());
                    }
                }
                lm.lists = l;
            }
        } else if let Method::KCoherence(kp) = params.method {
            if kp.k == 0 || kp.window % 2 == 0 {
                return Err(Error::invalid(format!(
                    "k-coherence needs k >= 1 and an odd window, got k = {} and window = {}",
                    kp.k, kp.window
                )));
            }
            let pixels = |l: usize| {
                let im = pyramid.level(l);
                im.width * im.height
            };
            let two_level = |l: usize| pixels(l) > kp.exact_max && l < coarsest;
            let needed_as_parent = |l: usize| l > 0 && two_level(l - 1);
            let with_lists: Vec<usize> = (0..n_levels)
                .filter(|&l| l < coarsest || needed_as_parent(l))
                .collect();
            // Pruning directions fitted to each level's own features: every level has an
            // appearance space of its own, so directions fitted to another level prune
            // almost nothing (a 512² brick's finest level: ~387 of ~400 candidates
            // measured in full, against ~29). The fits are serial; run them side by side.
            let prunings: Vec<kcoherence::Pruning> = {
                use rayon::prelude::*;
                with_lists
                    .par_iter()
                    .map(|&l| kcoherence::Pruning::fit(&levels[l].pass2.features))
                    .collect()
            };
            // Coarse to fine, so each level's parent lists exist when it needs them.
            for (&l, pruning) in with_lists.iter().zip(&prunings).rev() {
                let len = if needed_as_parent(l) {
                    kp.m.max(kp.k)
                } else {
                    kp.k
                };
                let lists = if two_level(l) {
                    let parent = levels[l + 1]
                        .lists
                        .as_ref()
                        .expect("parent lists built first");
                    KnnLists::two_level_pruned(
                        &levels[l].pass2.features,
                        &levels[l + 1].pass2.features,
                        parent,
                        len,
                        pruning,
                    )
                } else {
                    KnnLists::exact_pruned(&levels[l].pass2.features, len, pruning)
                };
                levels[l].lists = Some(lists);
            }
        }
        Ok(Self {
            pyramid,
            params,
            levels,
        })
    }

    /// Number of levels.
    pub fn n_levels(&self) -> usize {
        self.levels.len()
    }

    /// Index of the coarsest level.
    pub fn coarsest(&self) -> usize {
        self.levels.len() - 1
    }

    /// The searcher of (level, pass).
    pub fn searcher(&self, level: usize, pass: Pass) -> &Searcher {
        let lm = &self.levels[level];
        match pass {
            Pass::One => lm
                .pass1
                .as_ref()
                .expect("pass 1 exists below the coarsest level"),
            Pass::Coarsest | Pass::Two => &lm.pass2,
        }
    }

    /// The neighbourhood shape of (level, pass).
    pub fn shape(&self, level: usize, pass: Pass) -> Shape {
        self.searcher(level, pass).features.shape
    }

    /// The feature index of the valid pixel nearest to continuous position (x, y) of
    /// `level` (where k-coherence seeds land).
    pub fn nearest_index(&self, level: usize, x: f32, y: f32) -> u32 {
        self.levels[level].pass2.features.nearest_index(x, y)
    }

    /// Pixel (column, row) of feature `index` at `level` (the same for both passes).
    pub fn pixel(&self, level: usize, index: u32) -> (usize, usize) {
        self.levels[level].pass2.features.pixel(index)
    }

    /// Number of candidate pixels at `level`.
    pub fn candidates(&self, level: usize) -> usize {
        self.levels[level].pass2.features.len()
    }

    /// The best matches of the prepared query into `scratch.top`. `seeds` (feature indices
    /// of forward-shifted source positions) are used by k-coherence only; with none, or at
    /// the coarsest level, or for [`Method::Brute`], the search is exhaustive. Returns the
    /// number of candidates whose distance was evaluated.
    pub fn search(
        &self,
        level: usize,
        pass: Pass,
        q: &Prepared,
        seeds: &[u32],
        scratch: &mut Scratch,
    ) -> usize {
        let s = self.searcher(level, pass);
        let f = &s.features;
        scratch.kcoh.invalidate();
        if pass == Pass::Coarsest || level == self.coarsest() {
            f.brute_force(q, &mut scratch.top);
            return f.len();
        }
        match self.params.method {
            Method::Brute => {
                f.brute_force(q, &mut scratch.top);
                f.len()
            }
            Method::Ann(a) => {
                let idx = s.ann.as_ref().expect("ANN index built");
                idx.search(f, q, &mut scratch.ann, &mut scratch.top);
                a.candidates
            }
            Method::KCoherence(kp) => {
                if seeds.is_empty() {
                    f.brute_force(q, &mut scratch.top);
                    return f.len();
                }
                let lists = self.levels[level].lists.as_ref().expect("lists built");
                kcoherence::search(
                    f,
                    lists,
                    kp.k,
                    q,
                    seeds,
                    &mut scratch.kcoh,
                    &mut scratch.top,
                )
            }
        }
    }
}
