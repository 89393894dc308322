//! `surfsynth demo`: the full pipeline on bundled fixtures (issue 4).

use clap::Args;
use std::path::PathBuf;

#[derive(Args, Debug)]
pub struct DemoArgs {
    /// Output directory (created if missing).
    #[arg(long, value_name = "DIR", default_value = "out/demo")]
    pub out: PathBuf,
}

pub fn run(a: DemoArgs) -> anyhow::Result<()> {
    // The handler lives in the library (surfsynth::demo).
    surfsynth::demo::run(&a.out)?;
    Ok(())
}
