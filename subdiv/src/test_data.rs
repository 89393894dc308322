//! Where the unit tests find the shared data checkout (not part of this repository):
//! `$SURFSYNTH_SHARED` when set, else `../shared` beside the workspace — the same rule as
//! the integration tests' `common::shared()`.

use std::path::PathBuf;

/// `data/opensubdiv-reference/<file>` in the shared checkout.
pub(crate) fn opensubdiv_reference(file: &str) -> PathBuf {
    std::env::var_os("SURFSYNTH_SHARED")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared"))
        .join("data/opensubdiv-reference")
        .join(file)
}
