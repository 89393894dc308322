//! Helpers shared by the subdiv crate's integration tests: each test file says `mod common;`.
//! Cargo compiles `tests/common/mod.rs` into every test that names it and does not build it
//! as a test binary of its own. Not every test uses every helper, so each item allows
//! `dead_code` rather than the test binaries that leave it unused.

use std::path::PathBuf;
use subdiv::Surface;

/// The shared data checkout (meshes, OpenSubdiv reference values), which is not part of
/// this repository: `$SURFSYNTH_SHARED` when set, else `../../shared` relative to this
/// crate, i.e. a `shared` directory beside the workspace checkout.
#[allow(dead_code)]
pub fn shared() -> PathBuf {
    std::env::var_os("SURFSYNTH_SHARED")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared"))
}

/// The limit surface of `data/<rel>` in the shared checkout; panics when it does not load.
#[allow(dead_code)]
pub fn load(rel: &str) -> Surface {
    Surface::load_obj(shared().join("data").join(rel)).unwrap()
}

/// A seeded linear congruential generator (Knuth's MMIX constants), so that random test
/// points are the same on every run and machine without a `rand` dependency.
#[allow(dead_code)]
pub struct Lcg(pub u64);

#[allow(dead_code)]
impl Lcg {
    /// The next number, uniform in [0, 1) (the top 53 bits of the state).
    pub fn next(&mut self) -> f64 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (self.0 >> 11) as f64 / (1u64 << 53) as f64
    }
}
