//! surfsynth: texture synthesis directly on Catmull-Clark subdivision surfaces
//! (Ying, Hertzmann, Biermann, Zorin 2001).

pub mod bake;
pub mod bench;
pub mod error;
pub mod example;
pub mod field;
pub mod io;
pub mod progress;
pub mod texels;

pub use error::{Error, Result};
pub mod sampling;
pub mod maps;
pub mod probe;
pub mod report;
pub mod synth;
pub mod synthesizer;
pub mod eval;
pub mod demo;
pub mod pyramid;
pub mod search;
pub mod synth2d;
pub mod render;
