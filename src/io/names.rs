//! The file names of a result directory (BRIEF, "Output directory of `synth`"): one
//! home for what the writers write and the readers (`eval`, `render`, relighting) look
//! for, so the two sides cannot drift apart.

/// The per-face texture maps as EXR tiles.
pub const FACEMAPS_FILE: &str = "facemaps.exr";
/// Limit position, normal (and the field's tangent) per texel.
pub const GEOMETRY_FILE: &str = "geometry.exr";
/// Inputs, parameters, counts and stage times of the run (the source of `eval`'s default
/// scale).
pub const REPORT_FILE: &str = "report.json";
