//! File input and output: face-map EXR files ([`exr`]), atomic writes ([`atomic`]) through
//! a writer around the page cache ([`direct`]),
//! transactional output directories ([`txn`]) and clean-up on SIGINT / SIGTERM
//! ([`interrupt`]). Other writers (atlas, OBJ, the displaced OBJ of shape synthesis) live
//! beside them and go through [`atomic`] and [`txn`] too.

pub mod atlas;
pub mod atomic;
pub mod decimate;
pub mod direct;
pub mod displace;
pub mod exr;
pub mod gltf;
pub mod interrupt;
pub mod materials;
pub mod png;
pub mod ptex;
pub mod tangent;
pub mod txn;
