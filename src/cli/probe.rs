//! `surfsynth probe`: sampling pattern around a surface point as JSON (issue 3).
//! Arguments are final; the work is `surfsynth::probe::run_probe`.

use super::{parse_orient, parse_positive};
use clap::{Args, ValueEnum};
use std::path::PathBuf;
use surfsynth::field::Orientation;

#[derive(ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum Sampler {
    /// Characteristic-map vertex charts (000 §4.2), marching where the pattern leaves them.
    Chart,
    /// Surface marching (000 §4.1).
    March,
}

fn parse_odd_size(s: &str) -> Result<usize, String> {
    let k: usize = s
        .trim()
        .parse()
        .map_err(|_| format!("'{s}' is not a whole number"))?;
    if k == 0 || k.is_multiple_of(2) || k > 99 {
        return Err(format!("pattern size {k} must be odd, between 1 and 99"));
    }
    Ok(k)
}

fn parse_unit(s: &str) -> Result<f64, String> {
    let v: f64 = s
        .trim()
        .parse()
        .map_err(|_| format!("'{s}' is not a number"))?;
    if !(0.0..=1.0).contains(&v) {
        return Err(format!("{s} is outside the domain range 0..1"));
    }
    Ok(v)
}

#[derive(Args, Debug)]
pub struct ProbeArgs {
    /// Control mesh (OBJ).
    #[arg(long, value_name = "M.obj")]
    pub mesh: PathBuf,
    /// Face domain (Ptex index).
    #[arg(long, value_name = "F")]
    pub face: usize,
    /// Domain coordinates of the centre.
    #[arg(long, num_args = 2, value_names = ["U", "V"], value_parser = parse_unit, required = true, allow_negative_numbers = true)]
    pub uv: Vec<f64>,
    /// Sampling step (surface length between adjacent samples).
    #[arg(long, value_name = "D", value_parser = parse_positive, allow_negative_numbers = true)]
    pub step: f64,
    /// Pattern size K (odd): K x K samples.
    #[arg(long, value_name = "K", default_value_t = 9, value_parser = parse_odd_size, allow_negative_numbers = true)]
    pub size: usize,
    /// Sampler.
    #[arg(long, value_enum, default_value_t = Sampler::Chart)]
    pub sampler: Sampler,
    /// Orientation field: auto, +x|-x|+y|-y|+z|-z, or a constraints file.
    #[arg(long, value_name = "auto|AXIS|FILE", default_value = "auto", value_parser = parse_orient, allow_hyphen_values = true)]
    pub orient: Orientation,
}

pub fn run(a: ProbeArgs) -> anyhow::Result<()> {
    let req = surfsynth::probe::ProbeRequest {
        mesh: a.mesh,
        face: a.face,
        u: a.uv[0],
        v: a.uv[1],
        step: a.step,
        size: a.size,
        sampler: match a.sampler {
            Sampler::Chart => surfsynth::sampling::SamplerKind::Chart,
            Sampler::March => surfsynth::sampling::SamplerKind::March,
        },
        orient: a.orient,
    };
    println!("{}", surfsynth::probe::run_probe(&req)?);
    Ok(())
}
