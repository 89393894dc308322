//! Benchmarks behind `surfsynth bench ...`.
//!
//! They live in the binary (not only `cargo bench`) so the figures in docs/benchmarks.md
//! can be reproduced with the release build alone, on any machine, with one command, and so
//! that peak memory is measured for exactly the process that does the work.

use crate::bake::{bake_to_file, eval_only, GEOMETRY_FILE};
use crate::error::{Error, Result};
use crate::io::exr::Compression;
use crate::memory::{self, Estimate, MeshSize};
use glam::DVec3;
use indicatif::ProgressBar;
use serde::Serialize;
use std::f64::consts::TAU;
use std::path::{Path, PathBuf};
use std::time::Instant;
use subdiv::surface::SurfaceOptions;
use subdiv::{ControlMesh, Surface};

pub mod multiscale;
pub mod sampling;
pub mod synth;

use crate::process::{cpu_seconds, current_rss_bytes, peak_rss_bytes};

/// A closed quad-grid torus with about `min_domains` faces (rows x 2 rows), major radius 1,
/// minor radius 0.35. All vertices are regular, so it measures the fast path of evaluation.
pub fn torus_mesh(min_domains: usize) -> ControlMesh {
    let rows = ((min_domains as f64 / 2.0).sqrt().ceil() as usize).max(3);
    let cols = 2 * rows;
    let (big, small) = (1.0, 0.35);
    let mut positions = Vec::with_capacity(rows * cols);
    for i in 0..cols {
        let a = TAU * i as f64 / cols as f64;
        for j in 0..rows {
            let b = TAU * j as f64 / rows as f64;
            let r = big + small * b.cos();
            positions.push(DVec3::new(r * a.cos(), r * a.sin(), small * b.sin()));
        }
    }
    let id = |i: usize, j: usize| ((i % cols) * rows + (j % rows)) as u32;
    let mut face_start = vec![0u32];
    let mut verts = Vec::with_capacity(4 * rows * cols);
    for i in 0..cols {
        for j in 0..rows {
            verts.extend_from_slice(&[id(i, j), id(i + 1, j), id(i + 1, j + 1), id(i, j + 1)]);
            face_start.push(verts.len() as u32);
        }
    }
    ControlMesh::from_polygons(positions, face_start, verts).expect("torus is a valid mesh")
}

/// [`torus_mesh`] with creases, a panelled hard surface: every third meridian loop and
/// every third parallel loop is tagged, alternately infinitely sharp and semi-sharp (2.5
/// on meridians, 1.5 on parallels), so two thirds of the quads touch a crease, with
/// corners where sharp loops cross and semi-sharp values that decay only at level 3.
pub fn creased_torus_mesh(min_domains: usize) -> ControlMesh {
    let m = torus_mesh(min_domains);
    let rows = ((min_domains as f64 / 2.0).sqrt().ceil() as usize).max(3);
    let cols = 2 * rows;
    let id = |i: usize, j: usize| ((i % cols) * rows + (j % rows)) as u32;
    let mut edges = Vec::new();
    for i in 0..cols {
        for j in 0..rows {
            // Meridian loop i (around the tube) and parallel loop j (around the axis).
            match i % 6 {
                0 => edges.push((id(i, j), id(i, j + 1), 10.0)),
                3 => edges.push((id(i, j), id(i, j + 1), 2.5)),
                _ => {}
            }
            match j % 6 {
                0 => edges.push((id(i, j), id(i + 1, j), 10.0)),
                3 => edges.push((id(i, j), id(i + 1, j), 1.5)),
                _ => {}
            }
        }
    }
    m.with_sharpness(&edges, &[])
        .expect("torus loops are edges")
}

/// Uniform Catmull-Clark refinement of the control mesh until it has at least
/// `min_domains` face domains (each step turns every domain into four quads; crease tags
/// carry over, one sharper level spent per step).
pub fn refine_to(mut mesh: ControlMesh, min_domains: usize) -> ControlMesh {
    while mesh.num_domains() < min_domains {
        mesh = mesh.refined();
    }
    mesh
}

/// The size of [`torus_mesh`]`(min_domains)` for the memory guard, without building it.
pub fn torus_size(min_domains: usize) -> MeshSize {
    let rows = ((min_domains as f64 / 2.0).sqrt().ceil() as usize).max(3);
    let domains = rows.saturating_mul(rows.saturating_mul(2));
    MeshSize {
        domains,
        base_quads: domains.saturating_mul(4),
        irregular_base_quads: 0,
        semi_sharp_base_quads: 0,
        semi_sharp_levels: 0,
    }
}

/// The size of a mesh of `size` after [`refine_to`]`(.., min_domains)`: every step makes
/// each base quad a face of four base quads; the quads at extraordinary vertices stay as
/// many (a vertex keeps its valence, an n-gon's centre becomes a vertex of valence n),
/// semi-sharp values decay a level per step.
pub fn refined_size(mut size: MeshSize, min_domains: usize) -> MeshSize {
    while size.domains < min_domains && size.domains > 0 {
        size.domains = size.base_quads;
        size.base_quads = size.base_quads.saturating_mul(4);
        size.semi_sharp_levels = size
            .semi_sharp_levels
            .saturating_sub(size.semi_sharp_base_quads);
        if size.semi_sharp_levels == 0 {
            size.semi_sharp_base_quads = 0;
        }
    }
    size
}

/// `bench exr`, per texel: the geometry maps (6 channels) and the colour maps (5) held
/// together, one read back at a time (up to 6 more) and the compressor's buffers; and per
/// tile the reader has in flight (each a compressed chunk and a decoded block with their
/// allocations; all of them at N = 4). Fitted to the peaks of 20,000 domains at N = 16,
/// 2,048 at N = 64 and 50,562 at N = 4 (511 / 657 / 427 MiB): 80 B and 3.6 KB.
const EXR_BENCH_TEXEL: u64 = 80;
const EXR_BENCH_TILE: u64 = 3600;

/// Peak-memory estimate of [`bake_bench`] on a mesh of `size` (after refinement) at `n`:
/// the streamed bake's ([`crate::memory::estimate`] for `bake`).
pub fn bake_bench_estimate(size: &MeshSize, n: usize) -> Estimate {
    let threads = rayon::current_num_threads();
    let mut e = memory::estimate(size, n, &memory::Job::Bake { threads });
    // Plus the evaluation-only pass before it: per thread the six channels of a domain
    // and, up to N = 512, its own whole-domain scratch (the bake's stays with its threads).
    let nn = (n as u64).saturating_mul(n as u64);
    let per_texel = if n <= 512 { 24 + 96 } else { 24 };
    e.parts.push((
        "evaluation-only pass",
        (threads as u64).saturating_mul(nn.saturating_mul(per_texel)),
    ));
    e.parts.sort_by_key(|p| std::cmp::Reverse(p.1));
    e.bytes = e.parts.iter().fold(0u64, |s, p| s.saturating_add(p.1));
    e
}

/// Peak-memory estimate of [`exr_bench`]`(min_domains, n, ..)`: the surface and the maps
/// held, written and read back.
pub fn exr_bench_estimate(min_domains: usize, n: usize) -> Estimate {
    let size = torus_size(min_domains);
    let mut e = bake_bench_estimate(&size, n);
    let texels = (size.domains as u64).saturating_mul((n as u64).saturating_mul(n as u64));
    let in_flight = crate::io::exr::read_batch_tiles(6, (n, n)).min(size.domains) as u64;
    e.parts.retain(|p| p.0 == "process" || p.0 == "surface");
    e.parts
        .push(("maps held", texels.saturating_mul(EXR_BENCH_TEXEL)));
    e.parts.push((
        "tiles read at once",
        in_flight.saturating_mul(EXR_BENCH_TILE),
    ));
    e.parts.sort_by_key(|p| std::cmp::Reverse(p.1));
    e.bytes = e.parts.iter().fold(0u64, |s, p| s.saturating_add(p.1));
    e.shape = format!("{} domains x {n}² texels x 17 channels", size.domains);
    e
}

/// `bench sampling`, per face of the orientation field's limit mesh on top of the field
/// itself: the chart sampler's and the marching sampler's structures over it (Spot,
/// 187,392 field faces: 189 MiB peak at N = 32, 192 MiB at N = 128).
const SAMPLING_FIELD_FACE: u64 = 480;

/// Peak-memory estimate of `bench sampling` on a mesh of `size` at `n`: the surface, the
/// orientation field and the samplers over its limit mesh.
pub fn sampling_bench_estimate(size: &MeshSize, n: usize) -> Estimate {
    let faces = memory::field_faces(size.base_quads, None);
    let mut parts = vec![
        ("process", memory::BASELINE),
        ("surface", memory::surface_bytes(size, n)),
        (
            "orientation field and samplers",
            faces.saturating_mul(memory::FIELD_FACE + SAMPLING_FIELD_FACE),
        ),
    ];
    parts.sort_by_key(|p| std::cmp::Reverse(p.1));
    Estimate {
        bytes: parts.iter().fold(0u64, |s, p| s.saturating_add(p.1)),
        parts,
        shape: format!("{} domains, {faces} field faces", size.domains),
    }
}

/// Where the benchmark mesh comes from.
#[derive(Clone, Debug)]
pub enum BenchMesh {
    /// [`torus_mesh`] with this many domains (at least).
    Torus(usize),
    /// [`creased_torus_mesh`] with this many domains (at least).
    CreasedTorus(usize),
    /// An OBJ file, refined with [`refine_to`] until it has this many domains (at least).
    File(PathBuf, usize),
}

/// Figures of one `bench bake` run (printed as JSON).
#[derive(Clone, Debug, Serialize)]
pub struct BakeBenchReport {
    pub mesh: String,
    pub domains: usize,
    pub resolution: usize,
    pub texels: u64,
    pub threads: usize,
    pub compression: String,
    /// Stored patch-tree depth around extraordinary vertices (`SurfaceOptions::max_depth`).
    pub patch_depth: u32,
    pub surface_build_seconds: f64,
    pub eval_seconds: f64,
    pub eval_texels_per_second: f64,
    pub eval_cpu_seconds: f64,
    pub bake_seconds: f64,
    pub bake_texels_per_second: f64,
    pub bake_cpu_seconds: f64,
    pub file_bytes: u64,
    /// Resident memory after building the surface, before baking.
    pub rss_before_bake_bytes: u64,
    pub peak_rss_bytes: u64,
    pub peak_bytes_per_texel: f64,
    /// (peak - before bake) / texels: what baking itself costs per texel.
    pub bake_overhead_bytes_per_texel: f64,
}

/// Builds the mesh, then times evaluation alone and the streaming bake into
/// `out_dir/geometry.exr`, and reads peak memory.
pub fn bake_bench(
    mesh: &BenchMesh,
    resolution: usize,
    compression: Compression,
    max_depth: Option<u32>,
    out_dir: &Path,
) -> Result<BakeBenchReport> {
    let t = Instant::now();
    let (name, control) = match mesh {
        BenchMesh::Torus(d) => (format!("generated torus (>= {d} quads)"), torus_mesh(*d)),
        BenchMesh::CreasedTorus(d) => (
            format!("generated creased torus (>= {d} quads)"),
            creased_torus_mesh(*d),
        ),
        BenchMesh::File(p, d) => {
            let m = ControlMesh::load_obj(p)?;
            (
                format!("{} refined to >= {d} domains", p.display()),
                refine_to(m, *d),
            )
        }
    };
    let opts = SurfaceOptions {
        max_depth: max_depth.unwrap_or_else(|| crate::bake::patch_depth_for(resolution)),
    };
    let surface = Surface::with_options(control, opts);
    let surface_build_seconds = t.elapsed().as_secs_f64();
    let domains = surface.num_domains();
    let texels = (domains * resolution * resolution) as u64;
    let rss_before = current_rss_bytes().unwrap_or(0);

    let (t, c) = (Instant::now(), cpu_seconds().unwrap_or(0.0));
    std::hint::black_box(eval_only(&surface, resolution));
    let eval_seconds = t.elapsed().as_secs_f64();
    let eval_cpu_seconds = cpu_seconds().unwrap_or(0.0) - c;

    let path = out_dir.join(GEOMETRY_FILE);
    let c = cpu_seconds().unwrap_or(0.0);
    let stats = bake_to_file(
        &surface,
        resolution,
        &path,
        compression,
        &ProgressBar::hidden(),
    )?;
    let bake_cpu_seconds = cpu_seconds().unwrap_or(0.0) - c;
    let file_bytes = std::fs::metadata(&path)
        .map_err(|e| Error::io(&path, "cannot stat", e))?
        .len();
    let peak = peak_rss_bytes().unwrap_or(0);
    Ok(BakeBenchReport {
        mesh: name,
        domains,
        resolution,
        texels,
        threads: rayon::current_num_threads(),
        compression: compression.to_string(),
        patch_depth: opts.max_depth,
        surface_build_seconds,
        eval_seconds,
        eval_texels_per_second: texels as f64 / eval_seconds.max(1e-9),
        eval_cpu_seconds,
        bake_seconds: stats.seconds,
        bake_texels_per_second: stats.texels_per_second(),
        bake_cpu_seconds,
        file_bytes,
        rss_before_bake_bytes: rss_before,
        peak_rss_bytes: peak,
        peak_bytes_per_texel: peak as f64 / texels as f64,
        bake_overhead_bytes_per_texel: peak.saturating_sub(rss_before) as f64 / texels as f64,
    })
}

/// One row of `bench exr`: writing and reading one kind of face maps with one compression.
#[derive(Clone, Debug, Serialize)]
pub struct ExrBenchRow {
    /// "geometry" (P, N: 6 float channels) or "facemaps" (R G B source.u source.v).
    pub data: String,
    pub compression: String,
    pub texels: u64,
    pub raw_bytes: u64,
    pub file_bytes: u64,
    /// file / raw.
    pub ratio: f64,
    pub write_seconds: f64,
    pub write_texels_per_second: f64,
    pub write_raw_mb_per_second: f64,
    pub read_seconds: f64,
}

/// Colour maps that look like coherent synthesis output: every domain is a patch copied
/// from a procedural 8-bit "photo" (sRGB-decoded, so 256 levels per channel) at a
/// pseudo-random offset, with the matching `source.u`/`source.v`.
pub fn synthetic_facemaps(faces: usize, n: usize) -> crate::io::exr::FaceMaps {
    use crate::example::srgb_to_linear;
    let names = ["R", "G", "B", "source.u", "source.v"];
    let mut m = crate::io::exr::FaceMaps::new(faces, n, &names);
    let size = 128usize;
    let photo: Vec<[f32; 3]> = (0..size * size)
        .map(|i| {
            let (x, y) = ((i % size) as f32, (i / size) as f32);
            let a = (x * 0.21).sin() * (y * 0.13).cos() + 0.3 * ((x + 2.0 * y) * 0.05).sin();
            let noise = ((i as u32).wrapping_mul(2_654_435_761) >> 24) as f32 / 255.0;
            let v = |k: f32| {
                let q = ((0.5 + 0.35 * (a + k) + 0.15 * noise).clamp(0.0, 1.0) * 255.0).round();
                srgb_to_linear(q / 255.0)
            };
            [v(0.0), v(0.2), v(-0.3)]
        })
        .collect();
    let nn = n * n;
    let mut chans: Vec<Vec<f32>> = m
        .channels
        .iter_mut()
        .map(|(_, d)| std::mem::take(d))
        .collect();
    for f in 0..faces {
        let h = (f as u64 + 1).wrapping_mul(0x9E37_79B9_7F4A_7C15);
        let (ox, oy) = ((h >> 20) as usize % size, (h >> 40) as usize % size);
        for y in 0..n {
            for x in 0..n {
                let (sx, sy) = ((ox + x) % size, (oy + y) % size);
                let c = photo[sy * size + sx];
                let i = f * nn + y * n + x;
                chans[0][i] = c[0];
                chans[1][i] = c[1];
                chans[2][i] = c[2];
                chans[3][i] = sx as f32 + 0.5;
                chans[4][i] = sy as f32 + 0.5;
            }
        }
    }
    for ((_, d), c) in m.channels.iter_mut().zip(chans) {
        *d = c;
    }
    m
}

/// Writes and reads geometry maps (baked from a generated torus) and synthetic colour maps
/// with each lossless compression, in `out_dir`.
pub fn exr_bench(
    domains: usize,
    resolution: usize,
    compressions: &[Compression],
    out_dir: &Path,
) -> Result<Vec<ExrBenchRow>> {
    let surface = Surface::new(torus_mesh(domains));
    let geometry = crate::bake::bake_geometry(&surface, resolution);
    let colour = synthetic_facemaps(surface.num_domains(), resolution);
    let mut rows = Vec::new();
    for (label, maps) in [("geometry", &geometry), ("facemaps", &colour)] {
        let texels = maps.layout.len() as u64;
        let raw = texels * maps.channels.len() as u64 * 4;
        for &c in compressions {
            let path = out_dir.join(format!("{label}.exr"));
            let t = Instant::now();
            crate::io::exr::write_face_maps_with(&path, maps, c)?;
            let write_seconds = t.elapsed().as_secs_f64();
            let file_bytes = std::fs::metadata(&path)
                .map_err(|e| Error::io(&path, "cannot stat", e))?
                .len();
            let t = Instant::now();
            let back = crate::io::exr::read_face_maps(&path)?;
            let read_seconds = t.elapsed().as_secs_f64();
            assert_eq!(back.faces(), maps.faces());
            rows.push(ExrBenchRow {
                data: label.to_string(),
                compression: format!("{c:?}"),
                texels,
                raw_bytes: raw,
                file_bytes,
                ratio: file_bytes as f64 / raw as f64,
                write_seconds,
                write_texels_per_second: texels as f64 / write_seconds.max(1e-9),
                write_raw_mb_per_second: raw as f64 / 1e6 / write_seconds.max(1e-9),
                read_seconds,
            });
        }
    }
    Ok(rows)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn generated_and_refined_meshes_have_enough_domains() {
        let t = torus_mesh(200);
        assert!(t.num_domains() >= 200 && t.num_domains() < 260);
        let r = refine_to(torus_mesh(20), 300);
        assert!(r.num_domains() >= 300);
        let c = creased_torus_mesh(200);
        assert_eq!(c.num_domains(), t.num_domains());
        assert!(c.mesh.has_tags());
        assert!(refine_to(c, 300).mesh.has_tags());
        assert!(peak_rss_bytes().unwrap_or(1) > 0);
        assert!(cpu_seconds().is_some_and(|c| c >= 0.0));
    }

    #[test]
    fn bench_runs_small() {
        let d = tempfile::tempdir().unwrap();
        let r = bake_bench(&BenchMesh::Torus(50), 4, Compression::ZIP16, None, d.path()).unwrap();
        assert_eq!(r.texels, r.domains as u64 * 16);
        assert!(r.file_bytes > 0 && r.eval_texels_per_second > 0.0);
        let rows = exr_bench(30, 4, &[Compression::ZIP16], d.path()).unwrap();
        assert_eq!(rows.len(), 2);
        assert!(rows.iter().all(|r| r.file_bytes > 0 && r.ratio < 1.5));
    }
}
