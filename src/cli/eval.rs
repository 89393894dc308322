//! `surfsynth eval DIR` (quality measures of a result as JSON, issue 4) and
//! `surfsynth eval --image OUT.png --example E.png` (pfS of a 2D image, e.g. a peer's
//! output, measured by the same code as a flat grid); the work is in `surfsynth::eval`.

use super::parse_positive;
use anyhow::bail;
use clap::Args;
use std::path::PathBuf;

#[derive(Args, Debug)]
pub struct EvalArgs {
    /// A synthesis output directory (not with --image).
    #[arg(
        value_name = "DIR",
        required_unless_present = "image",
        conflicts_with = "image"
    )]
    pub dir: Option<PathBuf>,
    /// Scale S used for scale fidelity and the pfS windows (default: the one in
    /// DIR/report.json, or with a scale map geometry.exr's local `scale` per texel, which
    /// this replaces).
    #[arg(long, value_name = "S", value_parser = parse_positive, allow_negative_numbers = true)]
    pub scale: Option<f64>,
    /// Example image for pf1/pf4/pf8 (default: report.json's inputs.example when that file
    /// exists; see docs/eval.md).
    #[arg(long, value_name = "E.png")]
    pub example: Option<PathBuf>,
    /// Measure a 2D image instead of a result directory (needs --example).
    #[arg(long, value_name = "OUT.png", requires = "example")]
    pub image: Option<PathBuf>,
    /// Also write every pf window as CSV (its centre's face, u, v and position, or pixel
    /// with --image, and its own pf1/pf4/pf8): where structure is lost (docs/eval.md).
    #[arg(long, value_name = "FILE.csv")]
    pub windows: Option<PathBuf>,
}

pub fn run(a: EvalArgs) -> anyhow::Result<()> {
    match (&a.image, &a.dir) {
        (Some(img), _) => match &a.example {
            Some(e) => surfsynth::eval::run_image_cli(img, e, a.windows.as_deref()),
            None => bail!("--image needs --example E.png"),
        },
        (None, Some(dir)) => {
            surfsynth::eval::run_cli(dir, a.scale, a.example, a.windows.as_deref())
        }
        (None, None) => bail!("give a result directory DIR or --image OUT.png"),
    }
}
