//! `surfsynth render DIR`: preview picture of a result (issue 6); the work is in
//! `surfsynth::render`.

use super::{parse_finite, parse_pixels};
use clap::Args;
use std::path::PathBuf;

#[derive(Args, Debug)]
pub struct RenderArgs {
    /// A synthesis output directory (facemaps.exr + geometry.exr).
    #[arg(value_name = "DIR")]
    pub dir: PathBuf,
    /// Output picture (default: DIR/preview.png).
    #[arg(long, value_name = "FILE.png")]
    pub out: Option<PathBuf>,
    /// Picture width in pixels.
    #[arg(long, value_name = "W", default_value_t = 1024, value_parser = parse_pixels, allow_negative_numbers = true)]
    pub width: u32,
    /// Picture height in pixels.
    #[arg(long, value_name = "H", default_value_t = 768, value_parser = parse_pixels, allow_negative_numbers = true)]
    pub height: u32,
    /// Camera yaw in degrees (default: automatic 3/4 view).
    #[arg(long, value_name = "DEG", value_parser = parse_finite, allow_negative_numbers = true)]
    pub yaw: Option<f64>,
    /// Camera pitch in degrees.
    #[arg(long, value_name = "DEG", value_parser = parse_finite, allow_negative_numbers = true)]
    pub pitch: Option<f64>,
    /// Displace along the normal by AMOUNT x (height - 0.5).
    #[arg(long, value_name = "AMOUNT", value_parser = parse_finite, allow_negative_numbers = true)]
    pub displace: Option<f64>,
    /// Control mesh of the result (default: the one named in DIR/report.json).
    #[arg(long, value_name = "M.obj")]
    pub mesh: Option<PathBuf>,
    /// One light from this world direction: a BTF result is shaded with its sample's
    /// images of the nearest lights, a material set with its normal/roughness maps.
    #[arg(
        long,
        value_name = "X,Y,Z",
        value_delimiter = ',',
        // `-1,1,1` is a value, not a flag (clap's negative-number rule sees only `-1`).
        allow_hyphen_values = true
    )]
    pub light: Option<Vec<f64>>,
    /// Refuse to start when the estimated peak memory is above this (e.g. 512M, 4G,
    /// unlimited; default: 75% of physical memory).
    #[arg(long, value_name = "SIZE", value_parser = surfsynth::memory::parse_size, allow_hyphen_values = true)]
    pub max_memory: Option<u64>,
}

pub fn run(a: RenderArgs) -> anyhow::Result<()> {
    if let Some(l) = &a.light {
        if l.len() != 3 {
            return super::usage(format!(
                "--light takes three numbers X,Y,Z (a direction towards the light), got {}",
                l.len()
            ));
        }
    }
    surfsynth::memory::set_limit(a.max_memory);
    let opts = surfsynth::render::RenderOptions {
        width: a.width,
        height: a.height,
        yaw: a.yaw,
        pitch: a.pitch,
        displace: a.displace,
        mesh: a.mesh,
        light: a.light.map(|l| [l[0], l[1], l[2]]),
    };
    surfsynth::render::run_cli(&a.dir, a.out.as_deref(), &opts)
}
