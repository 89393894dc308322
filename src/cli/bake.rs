//! `surfsynth bake --mesh M --resolution N --out DIR`: geometry maps only.

use super::{parse_positive, parse_resolution, ExrCompression};
use clap::Args;
use std::path::PathBuf;
use std::time::Instant;
use surfsynth::bake::{bake_to_file, GEOMETRY_FILE};
use surfsynth::io::txn::{OutputTxn, BAKE_OUTPUTS};
use surfsynth::progress;

#[derive(Args, Debug)]
pub struct BakeArgs {
    /// Control mesh (OBJ: quads, triangles, n-gons; open boundaries allowed).
    #[arg(long, value_name = "M.obj")]
    pub mesh: PathBuf,
    /// Texels per side of every face map.
    #[arg(long, value_name = "N", default_value_t = 32, value_parser = parse_resolution, allow_negative_numbers = true)]
    pub resolution: usize,
    /// Surface length per texel: per-face power-of-two resolutions instead of N (as
    /// `synth --texel-size`).
    #[arg(long, value_name = "L", value_parser = parse_positive, allow_negative_numbers = true, conflicts_with = "resolution")]
    pub texel_size: Option<f64>,
    /// Output directory (created if missing); receives geometry.exr.
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
    /// EXR compression (lossless).
    #[arg(long, value_enum, default_value_t = ExrCompression::None)]
    pub compression: ExrCompression,
    /// Refuse to start when the estimated peak memory is above this (e.g. 512M, 4G,
    /// unlimited; default: 75% of physical memory).
    #[arg(long, value_name = "SIZE", value_parser = surfsynth::memory::parse_size, allow_hyphen_values = true)]
    pub max_memory: Option<u64>,
}

pub fn run(a: BakeArgs) -> anyhow::Result<()> {
    let t0 = Instant::now();
    let spin = progress::spinner("mesh");
    surfsynth::memory::set_limit(a.max_memory);
    let job = surfsynth::memory::Job::Bake {
        threads: rayon::current_num_threads(),
    };
    let (surface, layout) = match a.texel_size {
        None => (
            surfsynth::memory::load_surface_checked(&a.mesh, a.resolution, &job)?,
            None,
        ),
        Some(l) => {
            let c = surfsynth::memory::load_control_checked_texel_size(&a.mesh, l, &job)?;
            let side = surfsynth::memory::texel_size_side(&c, l);
            let surface = surfsynth::memory::build_surface(c, side);
            let layout = surfsynth::layout::TexelLayout::for_texel_size(&surface, l);
            let what = a.mesh.display().to_string();
            surfsynth::memory::check_layout(&what, &surface.control, &layout, &job)?;
            (surface, Some(std::sync::Arc::new(layout)))
        }
    };
    spin.finish_and_clear();
    let load_s = t0.elapsed().as_secs_f64();
    // Inputs are valid: only now check --out; geometry.exr is written into a staging
    // folder and moved into place when complete (surfsynth::io::txn).
    let txn = OutputTxn::begin(&a.out, BAKE_OUTPUTS)?;
    let path = a.out.join(GEOMETRY_FILE);
    let bar = progress::bar(surface.num_domains() as u64, "bake");
    let stats = match layout {
        None => bake_to_file(
            &surface,
            a.resolution,
            txn.dir().join(GEOMETRY_FILE),
            a.compression.to_exr(),
            &bar,
        ),
        Some(layout) => surfsynth::bake::bake_layout_to_file(
            &surface,
            layout,
            txn.dir().join(GEOMETRY_FILE),
            a.compression.to_exr(),
            &bar,
        ),
    }
    .map_err(|e| txn.explain(e))?;
    txn.commit()?;
    println!(
        "bake: {} domains, {} texels ({each}) in {:.2} s ({} texels/s; mesh load {:.2} s) -> {}",
        stats.domains,
        stats.texels,
        stats.seconds,
        progress::si(stats.texels_per_second()),
        load_s,
        path.display(),
        each = match a.texel_size {
            None => format!("{n}x{n} each", n = stats.resolution),
            Some(l) => format!("texel size {l}, up to {n}x{n}", n = stats.resolution),
        },
    );
    Ok(())
}
