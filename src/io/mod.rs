//! File input and output: face-map EXR files ([`exr`]) and atomic writes ([`atomic`]).
//! Other writers (atlas, OBJ) live beside them and go through [`atomic`] too.

pub mod atlas;
pub mod atomic;
pub mod exr;
