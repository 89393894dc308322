//! Texture synthesis on the surface's face maps.
//!
//! - [`coherent`]: the single-pass coherent method of Ying et al. 2001, §5.
//! - [`schedule`]: breadth-first order of the domains and the deterministic parallel waves.
//! - [`multiscale`]: the multiscale method of Ying et al. 2001, §4 (Wei–Levoy on the
//!   surface), with its 2D reference [`synth2d`].
//! - [`matching`]: what the methods match with (weighted example tables, neighbourhood
//!   search).
//!
//! The builder in [`crate::synthesizer`] strings these together with loading, the
//! orientation field and writing; this module is the pure computation (no files).

pub mod bench;
pub mod coherent;
pub mod matching;
pub mod multiscale;
pub mod schedule;
pub mod synth2d;

pub use coherent::{CoherentParams, Stats};

use crate::example::Example;
use crate::field::Frame;
use crate::io::exr::FaceMaps;
use crate::texels::TexelGeometry;
use matching::features::Features;
use glam::Vec3;
use rayon::prelude::*;
use serde::Serialize;

/// Synthesis method (`--method`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Method {
    /// Ying et al. 2001 §5: single pass, continues coherent patches (Ashikhmin).
    Coherent,
    /// Ying et al. 2001 §4: multiscale (Wei-Levoy), with k-coherence or ANN search.
    Multiscale,
}

impl Method {
    /// The name used on the command line and in report.json.
    pub fn name(self) -> &'static str {
        match self {
            Method::Coherent => "coherent",
            Method::Multiscale => "multiscale",
        }
    }
}

/// Weights of the matched channels in the l2 distance.
///
/// All channels are in 0..1 (linear RGB, alpha, height scaled to the file's range), so
/// weight 1 means "a full-range step in this channel counts as much as a full-range step in
/// one colour channel". Alpha defaults to 1: transparency edges are as visible as colour
/// edges. Height defaults to 3: it is one channel against three colour channels, and a
/// height map's structure (bumps, grooves) is what it is for; with 3 it weighs as much as
/// the colour together, so colour and relief stay aligned.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Weights {
    pub color: f32,
    pub alpha: f32,
    pub height: f32,
}

impl Default for Weights {
    fn default() -> Self {
        Self {
            color: 1.0,
            alpha: 1.0,
            height: 3.0,
        }
    }
}

impl Weights {
    /// One weight per channel of [`Example::channel_names`].
    pub fn per_channel(&self, example: &Example) -> Vec<f32> {
        let mut w = vec![self.color; 3];
        if example.alpha.is_some() {
            w.push(self.alpha);
        }
        if example.height_map.is_some() {
            w.push(self.height);
        }
        w
    }
}

/// Frames as the synthesizer stores them: (v1, v2) in f32.
pub fn frames_f32(frames: &[Frame]) -> Vec<[Vec3; 2]> {
    frames
        .par_iter()
        .map(|f| [f.v1.as_vec3(), f.v2.as_vec3()])
        .collect()
}

/// Runs coherent synthesis for `example` (any of its channel layouts).
pub fn run_coherent(
    example: &Example,
    weights: &Weights,
    inputs: coherent::Inputs<'_>,
    params: &CoherentParams,
    progress: &(dyn Fn(usize) + Sync),
) -> coherent::Output {
    let w = weights.per_channel(example);
    match example.num_channels() {
        3 => coherent::run(&Features::<3>::new(example, &w), inputs, params, progress),
        4 => coherent::run(&Features::<4>::new(example, &w), inputs, params, progress),
        5 => coherent::run(&Features::<5>::new(example, &w), inputs, params, progress),
        k => unreachable!("examples have 3 to 5 channels, not {k}"),
    }
}

/// Names of the channels of `facemaps.exr` for `example`: R G B \[A\] \[height\] source.u
/// source.v.
pub fn output_channels(example: &Example) -> Vec<&'static str> {
    let mut v = example.channel_names();
    v.extend(["source.u", "source.v"]);
    v
}

/// The `facemaps.exr` content: every channel looked up bilinearly in the (unweighted)
/// example at the texel's source position — all channels from the same place — plus the
/// source position itself.
pub fn face_maps(example: &Example, source: &[[f32; 2]], faces: usize, n: usize) -> FaceMaps {
    let names = output_channels(example);
    let k = example.num_channels();
    let nn = n * n;
    assert_eq!(source.len(), faces * nn);
    // Per domain, channel-major tiles; then scattered into the named channels.
    let tiles: Vec<Vec<f32>> = (0..faces)
        .into_par_iter()
        .map(|f| {
            let mut tile = vec![0.0f32; (k + 2) * nn];
            let mut v = [0.0f32; 8];
            for i in 0..nn {
                let s = source[f * nn + i];
                example.bilinear(s[0], s[1], &mut v[..k]);
                for c in 0..k {
                    tile[c * nn + i] = v[c];
                }
                tile[k * nn + i] = s[0];
                tile[(k + 1) * nn + i] = s[1];
            }
            tile
        })
        .collect();
    let mut maps = FaceMaps::new(faces, n, &names);
    for (c, (_, data)) in maps.channels.iter_mut().enumerate() {
        for (f, tile) in tiles.iter().enumerate() {
            data[f * nn..(f + 1) * nn].copy_from_slice(&tile[c * nn..(c + 1) * nn]);
        }
    }
    maps
}

/// The `geometry.exr` content (P.X P.Y P.Z N.X N.Y N.Z), from already evaluated texels.
pub fn geometry_maps(geom: &TexelGeometry) -> FaceMaps {
    let names = crate::bake::GEOMETRY_CHANNELS;
    let mut maps = FaceMaps::new(geom.faces, geom.resolution, &names);
    for (c, (_, data)) in maps.channels.iter_mut().enumerate() {
        let src = if c < 3 { &geom.pos } else { &geom.normal };
        let axis = c % 3;
        data.par_iter_mut()
            .zip(src.par_iter())
            .for_each(|(o, v)| *o = v[axis]);
    }
    maps
}
