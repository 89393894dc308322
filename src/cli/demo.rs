//! `surfsynth demo`: the full pipeline on bundled fixtures (issue 4). The handler is a
//! placeholder until synthesis lands.

use super::not_implemented;
use clap::Args;
use std::path::PathBuf;

#[derive(Args, Debug)]
pub struct DemoArgs {
    /// Output directory (created if missing).
    #[arg(long, value_name = "DIR", default_value = "out/demo")]
    pub out: PathBuf,
}

pub fn run(a: DemoArgs) -> anyhow::Result<()> {
    let _ = a;
    not_implemented("demo")
}
