//! `surfsynth eval DIR`: quality measures as JSON (issue 4). Arguments are final; the
//! handler is a placeholder until the evaluator lands.

use super::{not_implemented, parse_positive};
use clap::Args;
use std::path::PathBuf;

#[derive(Args, Debug)]
pub struct EvalArgs {
    /// A synthesis output directory.
    #[arg(value_name = "DIR")]
    pub dir: PathBuf,
    /// Scale S used for scale fidelity (default: the one in DIR/report.json).
    #[arg(long, value_name = "S", value_parser = parse_positive)]
    pub scale: Option<f64>,
}

pub fn run(a: EvalArgs) -> anyhow::Result<()> {
    let _ = a;
    not_implemented("eval")
}
