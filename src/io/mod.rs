//! File input and output: face-map EXR files ([`exr`]) and atomic writes ([`atomic`]).
//! Other writers (atlas, OBJ, the displaced OBJ of shape synthesis) live beside them and
//! go through [`atomic`] too.

pub mod atlas;
pub mod atomic;
pub mod decimate;
pub mod displace;
pub mod exr;
pub mod gltf;
pub mod materials;
pub mod ptex;
