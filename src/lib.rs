//! surfsynth: texture synthesis directly on Catmull-Clark subdivision surfaces
//! (Ying, Hertzmann, Biermann, Zorin 2001).

pub mod error;
pub mod example;
pub mod field;
pub mod io;

pub use error::{Error, Result};
pub mod texels;
