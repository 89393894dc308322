//! The paper's Torus rows (000 §6: 114,688 texels, multiscale, 64x64 example in 1.5 min
//! and 192x192 in 290 min on 2001 hardware) on this machine, for docs/benchmarks.md.
//!
//! Everything a `synth --method multiscale` run computes before writing is timed: texel
//! geometry and the orientation field (as the builder does them), the example analysis,
//! and synthesis. Not a test: timings depend on the machine and its load, so they are
//! reported, never asserted.

use crate::error::Result;
use crate::example::Example;
use crate::field::{Orientation, OrientationField};
use crate::synth::multiscale::{run, Inputs, MultiscaleParams, Stats};
use crate::texels::TexelGeometry;
use serde::Serialize;
use std::time::Instant;
use subdiv::Surface;

/// Figures of one benchmark run.
#[derive(Clone, Debug, Serialize)]
pub struct BenchResult {
    pub faces: usize,
    pub resolution: usize,
    pub texels: usize,
    pub example: [usize; 2],
    pub search: String,
    pub threads: usize,
    /// Texel geometry and orientation field (done by the builder for every method).
    pub setup_seconds: f64,
    /// Multiscale synthesis: example analysis, level geometry, search.
    pub synthesis_seconds: f64,
    pub total_seconds: f64,
    /// Process CPU time over the whole run (user + system), when available.
    pub cpu_seconds: Option<f64>,
    pub texels_per_second: f64,
    pub synthesis_texels_per_second: f64,
    /// Peak resident memory of the process divided by the texels, when available.
    pub peak_bytes_per_texel: Option<f64>,
    pub stats: Stats,
}

/// The example as the paper's rows use it: halved (Gaussian pyramid) while at least twice
/// `size` wide, then cropped to a square of `size` pixels (colour only).
pub fn square_example(example: &Example, size: usize) -> Result<Example> {
    let mut img = crate::pyramid::Image::from_example(example);
    while img.width >= 2 * size && img.height >= 2 * size {
        img = img.downsample();
    }
    if size < 16 || img.width < size || img.height < size {
        return Err(crate::Error::invalid(format!(
            "cannot make a {size}x{size} example (at least 16) from {}x{} pixels",
            example.width, example.height
        )));
    }
    let c = img.channels;
    let rgb = (0..size * size)
        .map(|i| {
            let p = img.pixel(i % size, i / size);
            [p[0], p[1 % c], p[2 % c]]
        })
        .collect();
    let mut e = Example::from_linear(size, size, rgb);
    e.path = example.path.clone();
    Ok(e)
}

/// Synthesizes `example` on the closed quad torus of [`crate::bench::torus_mesh`] with
/// `min_domains` faces at resolution `n` and reports the figures.
pub fn bench_torus(
    min_domains: usize,
    n: usize,
    example: &Example,
    params: &MultiscaleParams,
    seed: u64,
) -> Result<BenchResult> {
    let surface = Surface::new(crate::bench::torus_mesh(min_domains));
    bench_surface(&surface, n, example, params, seed)
}

/// The same figures on any surface (e.g. Spot, loaded with
/// [`crate::bake::load_surface_for`]), with the default scale and orientation (`Auto`).
pub fn bench_surface(
    surface: &Surface,
    n: usize,
    example: &Example,
    params: &MultiscaleParams,
    seed: u64,
) -> Result<BenchResult> {
    let cpu0 = crate::process::cpu_seconds();
    let t0 = Instant::now();
    let geom = TexelGeometry::compute(surface, n);
    let field = OrientationField::compute(surface, &Orientation::Auto)
        .map_err(|e| crate::Error::invalid(format!("orientation field: {e:#}")))?;
    let spacing = geom.median_spacing(surface);
    let setup_seconds = t0.elapsed().as_secs_f64();
    let weights = crate::synth::Weights::default().per_channel(example);
    let layout = geom.layout.clone();
    let inputs = Inputs {
        appearance: Default::default(),
        surface,
        field: &field,
        layout: &layout,
        spacing,
        scale: spacing,
        scale_field: None,
        seed,
        weights: &weights,
        feature_distance: 0.0,
    };
    let t1 = Instant::now();
    let out = run(example, &inputs, params, &|_, _| {})?;
    let synthesis_seconds = t1.elapsed().as_secs_f64();
    let total_seconds = t0.elapsed().as_secs_f64();
    let texels = geom.len();
    let cpu_seconds = match (cpu0, crate::process::cpu_seconds()) {
        (Some(a), Some(b)) => Some(b - a),
        _ => None,
    };
    Ok(BenchResult {
        faces: surface.num_domains(),
        resolution: n,
        texels,
        example: [example.width, example.height],
        search: out.stats.search.clone(),
        threads: rayon::current_num_threads(),
        setup_seconds,
        synthesis_seconds,
        total_seconds,
        cpu_seconds,
        texels_per_second: texels as f64 / total_seconds,
        synthesis_texels_per_second: texels as f64 / synthesis_seconds,
        peak_bytes_per_texel: crate::process::peak_rss_bytes().map(|b| b as f64 / texels as f64),
        stats: out.stats,
    })
}
