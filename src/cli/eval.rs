//! `surfsynth eval DIR`: quality measures as JSON (issue 4); the work is in
//! `surfsynth::eval`.

use super::parse_positive;
use clap::Args;
use std::path::PathBuf;

#[derive(Args, Debug)]
pub struct EvalArgs {
    /// A synthesis output directory.
    #[arg(value_name = "DIR")]
    pub dir: PathBuf,
    /// Scale S used for scale fidelity (default: the one in DIR/report.json).
    #[arg(long, value_name = "S", value_parser = parse_positive, allow_negative_numbers = true)]
    pub scale: Option<f64>,
    /// Example image: also report patch fidelity (flat meshes only; see docs/eval.md).
    #[arg(long, value_name = "E.png")]
    pub example: Option<PathBuf>,
}

pub fn run(a: EvalArgs) -> anyhow::Result<()> {
    surfsynth::eval::run_cli(&a.dir, a.scale, a.example)
}
