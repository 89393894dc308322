//! `surfsynth bench <what>`: performance benchmarks whose figures go into
//! docs/benchmarks.md. Add further benchmarks as variants of [`BenchCommand`].

use super::{parse_resolution, ExrCompression};
use clap::{Args, Subcommand};
use std::path::PathBuf;
use surfsynth::bench::{bake_bench, exr_bench, BenchMesh};
use surfsynth::io::atomic::prepare_out_dir;

#[derive(Args, Debug)]
pub struct BenchArgs {
    #[command(subcommand)]
    pub what: BenchCommand,
}

#[derive(Subcommand, Debug)]
pub enum BenchCommand {
    /// Geometry baking: evaluation alone and with EXR writing, texels/s and peak memory.
    Bake(BenchBakeArgs),
    /// EXR writing and reading speed and file size per compression.
    Exr(BenchExrArgs),
    /// Coherent synthesis on Spot: synthesis stage and whole run, texels/s and peak memory.
    Synth(BenchSynthArgs),
    /// Multiscale synthesis: the paper's Torus rows (000 §6: 32-face torus, N = 60,
    /// 115,200 texels) or any mesh; ANN and k-coherence side by side.
    Multiscale(BenchMultiscaleArgs),
    /// Neighbourhood sampling (000 §4): chart sampling and marching, samples/s on one
    /// thread, K×K patterns at texel centres spread over the surface.
    Sampling(BenchSamplingArgs),
    /// Writes the flat K×K unit-quad grid OBJ of the peer comparison (bench/peer.sh).
    Grid(BenchGridArgs),
    /// Writes a square crop of an image as PNG, values unchanged (bench/peer.sh).
    Crop(BenchCropArgs),
    /// Writes a synthetic BTF sample (003 Fig. 8): a height field ray-traced with
    /// self-shadowing under --lights directions, as light_NN.png + btf.json.
    BtfSample(BenchBtfSampleArgs),
}

#[derive(Args, Debug)]
pub struct BenchBtfSampleArgs {
    /// Height field (grayscale PNG, linear; its central --size² crop is used). Default: a
    /// procedural relief of round bumps.
    #[arg(long, value_name = "H.png")]
    pub height: Option<PathBuf>,
    /// Light directions (rings over the hemisphere, 20°-75° elevation).
    #[arg(long, value_name = "L", default_value_t = 32, value_parser = clap::value_parser!(u32).range(1..=1024))]
    pub lights: u32,
    /// Sample side in pixels.
    #[arg(long, value_name = "S", default_value_t = 64, value_parser = clap::value_parser!(u32).range(4..=4096))]
    pub size: u32,
    /// Relief depth in pixels between the lowest and highest height.
    #[arg(long, value_name = "D", default_value_t = 6.0, value_parser = super::parse_positive, allow_negative_numbers = true)]
    pub depth: f64,
    /// Output folder (light_NN.png and btf.json; written all at once).
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
}

#[derive(Args, Debug)]
pub struct BenchGridArgs {
    /// Quads per side (BRIEF: 16).
    #[arg(long, value_name = "K", default_value_t = 16, value_parser = clap::value_parser!(u32).range(1..=4096))]
    pub size: u32,
    /// Output OBJ.
    #[arg(long, value_name = "grid.obj")]
    pub out: PathBuf,
}

#[derive(Args, Debug)]
pub struct BenchCropArgs {
    /// Input image (PNG or JPEG).
    #[arg(value_name = "IMAGE")]
    pub image: PathBuf,
    /// Top-left pixel of the crop.
    #[arg(long, value_name = "X,Y", value_delimiter = ',', default_values_t = [0u32, 0])]
    pub at: Vec<u32>,
    /// Side of the square crop in pixels.
    #[arg(long, value_name = "S", value_parser = super::parse_pixels)]
    pub size: u32,
    /// Output PNG.
    #[arg(long, value_name = "OUT.png")]
    pub out: PathBuf,
}

#[derive(Args, Debug)]
pub struct BenchSamplingArgs {
    /// Memory limit (e.g. 512M, 4G, unlimited; default: 75% of physical memory): runs
    /// whose memory is sure to exceed it are refused before they start.
    #[arg(long, value_name = "SIZE", value_parser = surfsynth::memory::parse_size, allow_hyphen_values = true)]
    pub max_memory: Option<u64>,
    /// Mesh (default: the bundled Spot control mesh, as in `surfsynth demo`).
    #[arg(long, value_name = "M.obj")]
    pub mesh: Option<PathBuf>,
    /// Pattern sizes K (odd).
    #[arg(long, value_name = "K", value_delimiter = ',', default_values_t = [5usize, 9])]
    pub size: Vec<usize>,
    /// Steps δ, in median texel spacings at --resolution.
    #[arg(long, value_name = "T", value_delimiter = ',', default_values_t = [1.0f64])]
    pub step: Vec<f64>,
    /// Texels per side of every face map (sets the texel spacing δ is measured in).
    #[arg(long, value_name = "N", default_value_t = 32, value_parser = parse_resolution, allow_negative_numbers = true)]
    pub resolution: usize,
    /// Patterns per measurement.
    #[arg(long, value_name = "P", default_value_t = 4000)]
    pub patterns: usize,
}

#[derive(Args, Debug)]
pub struct BenchMultiscaleArgs {
    /// Memory limit (e.g. 512M, 4G, unlimited; default: 75% of physical memory): runs
    /// whose memory is sure to exceed it are refused before they start.
    #[arg(long, value_name = "SIZE", value_parser = surfsynth::memory::parse_size, allow_hyphen_values = true)]
    pub max_memory: Option<u64>,
    /// Mesh (default: the generated quad torus with --domains faces).
    #[arg(long, value_name = "M.obj")]
    pub mesh: Option<PathBuf>,
    /// Faces of the generated torus.
    #[arg(long, value_name = "D", default_value_t = 32)]
    pub domains: usize,
    /// Texels per side of every face map.
    #[arg(long, value_name = "N", default_value_t = 60, value_parser = parse_resolution, allow_negative_numbers = true)]
    pub resolution: usize,
    /// Example (default: the bundled 128x128 gravel).
    #[arg(long, value_name = "E.png")]
    pub example: Option<PathBuf>,
    /// Example side in pixels: the example is halved (Gaussian pyramid) while at least
    /// twice this wide, then cropped to a square (the paper's rows: 64 and 192).
    #[arg(long, value_name = "S", default_value_t = 64)]
    pub example_size: usize,
    /// Searches to measure (default: both).
    #[arg(long, value_enum, value_delimiter = ',')]
    pub search: Vec<super::synth::Search>,
    /// Random seed.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
}

#[derive(Args, Debug)]
pub struct BenchSynthArgs {
    /// Memory limit (e.g. 512M, 4G, unlimited; default: 75% of physical memory): runs
    /// whose memory is sure to exceed it are refused before they start.
    #[arg(long, value_name = "SIZE", value_parser = surfsynth::memory::parse_size, allow_hyphen_values = true)]
    pub max_memory: Option<u64>,
    /// Runs per case (the median is reported).
    #[arg(long, value_name = "R", default_value_t = 3)]
    pub repeats: usize,
}

#[derive(Args, Debug)]
pub struct BenchExrArgs {
    /// Memory limit (e.g. 512M, 4G, unlimited; default: 75% of physical memory): runs
    /// whose memory is sure to exceed it are refused before they start.
    #[arg(long, value_name = "SIZE", value_parser = surfsynth::memory::parse_size, allow_hyphen_values = true)]
    pub max_memory: Option<u64>,
    /// Number of face domains (generated torus).
    #[arg(long, value_name = "D", default_value_t = 20_000)]
    pub domains: usize,
    /// Texels per side of every face map.
    #[arg(long, value_name = "N", default_value_t = 16, value_parser = parse_resolution, allow_negative_numbers = true)]
    pub resolution: usize,
    /// Compressions to measure (default: all lossless ones).
    #[arg(long, value_enum, value_delimiter = ',')]
    pub compression: Vec<ExrCompression>,
}

#[derive(Args, Debug)]
pub struct BenchBakeArgs {
    /// Memory limit (e.g. 512M, 4G, unlimited; default: 75% of physical memory): runs
    /// whose memory is sure to exceed it are refused before they start.
    #[arg(long, value_name = "SIZE", value_parser = surfsynth::memory::parse_size, allow_hyphen_values = true)]
    pub max_memory: Option<u64>,
    /// Mesh to bake, refined uniformly until it has --domains domains
    /// (default: a generated quad torus with --domains faces).
    #[arg(long, value_name = "M.obj")]
    pub mesh: Option<PathBuf>,
    /// Minimum number of face domains.
    #[arg(long, value_name = "D", default_value_t = 20_000)]
    pub domains: usize,
    /// Texels per side of every face map.
    #[arg(long, value_name = "N", default_value_t = 16, value_parser = parse_resolution, allow_negative_numbers = true)]
    pub resolution: usize,
    /// EXR compression (lossless).
    #[arg(long, value_enum, default_value_t = ExrCompression::None)]
    pub compression: ExrCompression,
    /// Patch-tree depth stored around extraordinary vertices (default: what N needs).
    #[arg(long, value_name = "L", value_parser = clap::value_parser!(u32).range(1..=16))]
    pub max_depth: Option<u32>,
    /// Keep geometry.exr in this directory (default: a temporary directory, removed).
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,
    /// Compare the generated torus without and with creases (every third loop tagged),
    /// R rounds of each, interleaved; prints both reports and the medians of the ratios.
    #[arg(long, value_name = "R", conflicts_with = "mesh")]
    pub creases: Option<usize>,
}

pub fn run(a: BenchArgs) -> anyhow::Result<()> {
    match a.what {
        BenchCommand::Bake(b) => bake(b),
        BenchCommand::Exr(b) => exr(b),
        BenchCommand::Synth(b) => synth(b),
        BenchCommand::Multiscale(b) => multiscale(b),
        BenchCommand::Sampling(b) => sampling(b),
        BenchCommand::Grid(b) => {
            let obj = surfsynth::eval::peer::grid_obj(b.size as usize);
            surfsynth::io::atomic::write_bytes_atomic(&b.out, obj.as_bytes())?;
            Ok(())
        }
        BenchCommand::BtfSample(b) => {
            let path = surfsynth::btf::generate::write_sample_cli(
                b.height.as_deref(),
                b.lights as usize,
                b.size as usize,
                b.depth as f32,
                &b.out,
            )?;
            println!(
                "btf-sample: {} lights, {}x{} -> {}",
                b.lights,
                b.size,
                b.size,
                path.display()
            );
            Ok(())
        }
        BenchCommand::Crop(b) => {
            let [x, y] = b.at[..] else {
                anyhow::bail!("--at takes two numbers X,Y, got {}", b.at.len());
            };
            Ok(surfsynth::eval::peer::crop_image(
                &b.image, &b.out, x, y, b.size,
            )?)
        }
    }
}

fn sampling(a: BenchSamplingArgs) -> anyhow::Result<()> {
    use surfsynth::field::{Orientation, OrientationField};
    if a.patterns == 0 || a.patterns > 10_000_000 {
        anyhow::bail!("--patterns {} must be between 1 and 10000000", a.patterns);
    }
    if let Some(k) = a.size.iter().find(|&&k| k % 2 == 0 || k > 99) {
        anyhow::bail!("--size {k}: pattern sizes must be odd and at most 99");
    }
    if let Some(t) = a
        .step
        .iter()
        .find(|t| !(t.is_finite() && **t > 0.0 && **t <= 64.0))
    {
        anyhow::bail!("--step {t}: steps must be in (0, 64] texel spacings");
    }
    // Default: the bundled Spot (built into the binary, as the demo's).
    surfsynth::memory::set_limit(a.max_memory);
    let (control, name) = match &a.mesh {
        Some(p) => (bench_control(p)?, p.display().to_string()),
        None => (
            surfsynth::demo::control_mesh(),
            surfsynth::demo::MESH_NAME.to_string(),
        ),
    };
    bench_guard(
        &format!("bench sampling on {name} --resolution {}", a.resolution),
        &surfsynth::bench::sampling_bench_estimate(
            &surfsynth::memory::MeshSize::of(&control),
            a.resolution,
        ),
        "use a smaller mesh or raise --max-memory",
    )?;
    let surface = surfsynth::bake::surface_for(control, a.resolution);
    let field = OrientationField::compute(&surface, &Orientation::Auto)
        .map_err(|e| anyhow::anyhow!("{name}: {e}"))?;
    let mut rows = Vec::new();
    for &k in &a.size {
        for &t in &a.step {
            rows.extend(surfsynth::bench::sampling::bench_sampling(
                &surface,
                &field,
                a.resolution,
                t,
                k,
                a.patterns,
            ));
        }
    }
    println!("{}", serde_json::to_string_pretty(&rows)?);
    Ok(())
}

fn multiscale(a: BenchMultiscaleArgs) -> anyhow::Result<()> {
    use surfsynth::bench::multiscale as bench;
    use surfsynth::synth::multiscale::MultiscaleParams;
    if a.domains == 0 || a.domains > 10_000_000 {
        anyhow::bail!("--domains {} must be between 1 and 10000000", a.domains);
    }
    surfsynth::memory::set_limit(a.max_memory);
    let control = match &a.mesh {
        Some(p) => Some(bench_control(p)?),
        None => None,
    };
    let (size, name) = match (&control, &a.mesh) {
        (Some(c), Some(p)) => (
            surfsynth::memory::MeshSize::of(c),
            format!("on {}", p.display()),
        ),
        _ => (
            surfsynth::bench::torus_size(a.domains),
            format!("--domains {}", a.domains),
        ),
    };
    let job = surfsynth::memory::Job::Synth {
        channels: 5,
        example_pixels: a.example_size.saturating_mul(a.example_size),
        method: surfsynth::synth::Method::Multiscale,
        displace: false,
        scale_map: false,
    };
    bench_guard(
        &format!(
            "bench multiscale {name} --resolution {} --example-size {}",
            a.resolution, a.example_size
        ),
        &surfsynth::memory::estimate(&size, a.resolution, &job),
        "lower --domains, --resolution or --example-size, or raise --max-memory",
    )?;
    let example = match &a.example {
        Some(p) => surfsynth::example::Example::load(p)?,
        None => {
            // The bundled example, through a file like any other.
            let dir =
                std::env::temp_dir().join(format!("surfsynth-bench-ms-{}", std::process::id()));
            prepare_out_dir(&dir)?;
            let p = dir.join(surfsynth::demo::EXAMPLE_NAME);
            let e = surfsynth::io::atomic::write_bytes_atomic(&p, surfsynth::demo::EXAMPLE_PNG)
                .and_then(|_| surfsynth::example::Example::load(&p));
            let _ = std::fs::remove_dir_all(&dir);
            e?
        }
    };
    let example = bench::square_example(&example, a.example_size)?;
    let surface = control.map(|c| surfsynth::bake::surface_for(c, a.resolution));
    let searches = if a.search.is_empty() {
        vec![super::synth::Search::Kcoherence, super::synth::Search::Ann]
    } else {
        a.search
    };
    let mut rows = Vec::new();
    for s in searches {
        let mut params = MultiscaleParams::default();
        params.model.method = match s {
            super::synth::Search::Ann => surfsynth::synthesizer::Search::Ann,
            super::synth::Search::Kcoherence => surfsynth::synthesizer::Search::KCoherence,
        }
        .method();
        let r = match &surface {
            Some(surface) => {
                bench::bench_surface(surface, a.resolution, &example, &params, a.seed)?
            }
            None => bench::bench_torus(a.domains, a.resolution, &example, &params, a.seed)?,
        };
        eprintln!(
            "{}: {} texels from {}x{} in {:.2} s wall, {} CPU-s ({:.0} texels/s)",
            r.search,
            r.texels,
            r.example[0],
            r.example[1],
            r.total_seconds,
            r.cpu_seconds.map_or("?".into(), |c| format!("{c:.2}")),
            r.texels_per_second
        );
        rows.push(r);
    }
    println!("{}", serde_json::to_string_pretty(&rows)?);
    Ok(())
}

fn synth(a: BenchSynthArgs) -> anyhow::Result<()> {
    surfsynth::memory::set_limit(a.max_memory);
    bench_guard(
        "bench synth",
        &surfsynth::bench::synth::synth_bench_estimate(),
        "raise --max-memory",
    )?;
    // The benchmark lives in the library (surfsynth::bench::synth).
    let dir = std::env::temp_dir().join(format!("surfsynth-bench-synth-{}", std::process::id()));
    let rows = surfsynth::bench::synth::synth_bench(&dir, a.repeats, &|l| eprintln!("{l}"));
    let _ = std::fs::remove_dir_all(&dir);
    println!("{}", serde_json::to_string_pretty(&rows?)?);
    Ok(())
}

/// The memory guard of a benchmark: `subject` (the command and the flags that size it)
/// is refused with one line when its estimate `e` is above the limit in force.
fn bench_guard(subject: &str, e: &surfsynth::memory::Estimate, advice: &str) -> anyhow::Result<()> {
    Ok(surfsynth::memory::check_bench(subject, e, advice)?)
}

/// The control mesh at `path` for a benchmark's estimate, read like `synth` reads it (at
/// most a quarter of the limit in bytes).
fn bench_control(path: &std::path::Path) -> anyhow::Result<subdiv::ControlMesh> {
    let control =
        subdiv::ControlMesh::load_obj_limited(path, surfsynth::memory::limit().bytes / 4)?;
    surfsynth::memory::check_coordinate_range(&path.display().to_string(), &control)?;
    Ok(control)
}

fn exr(a: BenchExrArgs) -> anyhow::Result<()> {
    if a.domains == 0 || a.domains > 50_000_000 {
        anyhow::bail!("--domains {} must be between 1 and 50000000", a.domains);
    }
    // Geometry (6 channels) and colour maps (5) held, plus one read back (6).
    surfsynth::memory::set_limit(a.max_memory);
    bench_guard(
        &format!(
            "bench exr --domains {} --resolution {}",
            a.domains, a.resolution
        ),
        &surfsynth::bench::exr_bench_estimate(a.domains, a.resolution),
        "lower --domains or --resolution, or raise --max-memory",
    )?;
    let list = if a.compression.is_empty() {
        vec![
            ExrCompression::None,
            ExrCompression::Rle,
            ExrCompression::Zip,
            ExrCompression::Zips,
            ExrCompression::Piz,
        ]
    } else {
        a.compression
    };
    let exr: Vec<_> = list.iter().map(|c| c.to_exr()).collect();
    let dir = std::env::temp_dir().join(format!("surfsynth-bench-exr-{}", std::process::id()));
    prepare_out_dir(&dir)?;
    let rows = exr_bench(a.domains, a.resolution, &exr, &dir);
    let _ = std::fs::remove_dir_all(&dir);
    println!("{}", serde_json::to_string_pretty(&rows?)?);
    Ok(())
}

fn bake(a: BenchBakeArgs) -> anyhow::Result<()> {
    if a.domains == 0 || a.domains > 50_000_000 {
        anyhow::bail!("--domains {} must be between 1 and 50000000", a.domains);
    }
    // The streamed bake itself (its tiles and scratch); the maps are not held.
    surfsynth::memory::set_limit(a.max_memory);
    let size = match &a.mesh {
        Some(p) => surfsynth::bench::refined_size(
            surfsynth::memory::MeshSize::of(&bench_control(p)?),
            a.domains,
        ),
        None => surfsynth::bench::torus_size(a.domains),
    };
    bench_guard(
        &format!(
            "bench bake --domains {} --resolution {}",
            a.domains, a.resolution
        ),
        &surfsynth::bench::bake_bench_estimate(&size, a.resolution),
        "lower --domains or --resolution, or raise --max-memory",
    )?;
    let mesh = match a.mesh.clone() {
        Some(p) => BenchMesh::File(p, a.domains),
        None => BenchMesh::Torus(a.domains),
    };
    let (dir, temporary) = match a.out.clone() {
        Some(d) => (d, false),
        None => (
            std::env::temp_dir().join(format!("surfsynth-bench-{}", std::process::id())),
            true,
        ),
    };
    prepare_out_dir(&dir)?;
    if let Some(rounds) = a.creases {
        let r = crease_rounds(&a, rounds.max(1), &dir);
        if temporary {
            let _ = std::fs::remove_dir_all(&dir);
        }
        println!("{}", serde_json::to_string_pretty(&r?)?);
        return Ok(());
    }
    let report = bake_bench(
        &mesh,
        a.resolution,
        a.compression.to_exr(),
        a.max_depth,
        &dir,
    );
    if temporary {
        let _ = std::fs::remove_dir_all(&dir);
    }
    println!("{}", serde_json::to_string_pretty(&report?)?);
    Ok(())
}

/// `bench bake --creases R`: the plain and the creased torus, alternately, R times each (so
/// both see the same machine load), with the medians of the per-round throughput ratios.
/// (Peak memory is the whole process's, so it is not compared here: run each mesh alone.)
fn crease_rounds(
    a: &BenchBakeArgs,
    rounds: usize,
    dir: &std::path::Path,
) -> anyhow::Result<serde_json::Value> {
    let (mut plain, mut creased) = (Vec::new(), Vec::new());
    for _ in 0..rounds {
        for (mesh, out) in [
            (BenchMesh::Torus(a.domains), &mut plain),
            (BenchMesh::CreasedTorus(a.domains), &mut creased),
        ] {
            out.push(bake_bench(
                &mesh,
                a.resolution,
                a.compression.to_exr(),
                a.max_depth,
                dir,
            )?);
        }
    }
    let median = |f: &dyn Fn(&surfsynth::bench::BakeBenchReport) -> f64| {
        let mut r: Vec<f64> = plain
            .iter()
            .zip(&creased)
            .map(|(p, c)| f(c) / f(p))
            .collect();
        r.sort_by(f64::total_cmp);
        r[r.len() / 2]
    };
    let ratios = serde_json::json!({
        "bake_texels_per_second": median(&|r| r.bake_texels_per_second),
        "bake_texels_per_cpu_second": median(&|r| r.texels as f64 / r.bake_cpu_seconds.max(1e-9)),
        "eval_texels_per_second": median(&|r| r.eval_texels_per_second),
        "eval_texels_per_cpu_second": median(&|r| r.texels as f64 / r.eval_cpu_seconds.max(1e-9)),
        "surface_build_seconds": median(&|r| r.surface_build_seconds),
    });
    Ok(serde_json::json!({ "plain": plain, "creased": creased, "creased_over_plain": ratios }))
}
