//! surfsynth: texture synthesis directly on Catmull-Clark subdivision surfaces
//! (Ying, Hertzmann, Biermann, Zorin 2001).
//!
//! Data flows one way: `subdiv` (mesh → base quads → exact limit surface → charts) →
//! [`field`] (orientation) and [`maps`]/[`example`] → [`sampling`] → [`synth`] (every
//! synthesis method, over the shared matching of [`synth::matching`] and [`pyramid`]) →
//! [`io`] writers, [`eval`], [`render`]. See docs/architecture.md.

pub mod bake;
pub mod bench;
pub mod btf;
pub mod cache;
pub mod conventions;
pub mod demo;
pub mod error;
pub mod eval;
pub mod example;
pub mod field;
pub mod io;
pub mod layout;
pub mod maps;
pub mod memory;
pub mod method;
pub mod probe;
pub mod process;
pub mod progress;
pub mod pyramid;
pub mod random;
pub mod relight;
pub mod render;
pub mod report;
pub mod sampling;
pub mod scale_field;
pub mod synth;
pub mod synthesizer;
pub mod texel_frames;
pub mod texels;

pub use error::{Error, Result};
