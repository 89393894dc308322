//! Where the unit tests find the shared data checkout (not part of this repository):
//! `$SURFSYNTH_SHARED` when set, else `../shared` beside the workspace — the same rule as
//! the integration tests' `common::shared()`.

use std::path::PathBuf;

fn shared_data() -> PathBuf {
    std::env::var_os("SURFSYNTH_SHARED")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared"))
        .join("data")
}

/// `data/opensubdiv-reference/<file>` in the shared checkout.
pub(crate) fn opensubdiv_reference(file: &str) -> PathBuf {
    shared_data().join("opensubdiv-reference").join(file)
}

/// `data/opensubdiv-creases/<file>` in the shared checkout.
pub(crate) fn opensubdiv_creases(file: &str) -> PathBuf {
    shared_data().join("opensubdiv-creases").join(file)
}

/// A shape of either reference set by name: the crease set's if it has one.
pub(crate) fn shape(name: &str) -> PathBuf {
    let c = opensubdiv_creases(&format!("{name}.obj"));
    if c.exists() {
        c
    } else {
        opensubdiv_reference(&format!("{name}.obj"))
    }
}
