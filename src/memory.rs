//! Memory guard: estimate the peak memory of a `synth` or `bake` run before the large
//! allocations, and refuse (one line, with the estimate and the limit) when it is above the
//! limit, instead of being killed by the kernel half-way through or swapping the machine
//! to a halt.
//!
//! The limit is `--max-memory` (e.g. `512M`, `4G`; see [`parse_size`]) or, by default, 75%
//! of the physical memory (`MemTotal` in /proc/meminfo, or the cgroup's memory limit when
//! that is lower). It is process-wide ([`set_limit`]): the command line sets it once, and
//! library users may set it too (`set_limit(Some(u64::MAX))` turns the guard off).
//!
//! The estimate is a sum of parts, each a count times a per-item cost measured on the
//! release build (docs/robustness.md has the table of estimates against measured VmHWM):
//!
//! - the subdivision surface, from the control mesh alone (base quads, and those touching
//!   an extraordinary vertex, whose patch trees grow with the stored depth);
//! - `synth`: the orientation field's limit mesh (at most 400,000 faces), per texel
//!   `domains x N²` x (fixed overhead + 4 bytes x channels) — positions, normals, frames,
//!   the neighbourhood graph, source positions, both map sets, the atlas — plus the border
//!   texels' neighbour lists, plus the example and its appearance space; patch sampling
//!   and texture optimisation add their per-texel working sets (footprints, cuts, the
//!   optimised sources and colours), the multiscale method (and texton synthesis on it)
//!   its levels per texel, its example model per example pixel and its sampler per face
//!   of the field, and jump maps a cost per example pixel (the map and what builds it);
//!   a scale map its factor and geometry.exr's `scale` channel per texel;
//! - `bake`: only the tiles in flight (two batches, see [`crate::io::exr::write_tiles`]) and
//!   the per-thread scratch: the maps are streamed, never held whole.
//!
//! The check runs after the control mesh is parsed and before the surface is built, so
//! nothing large has been allocated yet when it refuses. With `--texel-size` the texel
//! count depends on the limit surface, so there are two checks: before the surface, an
//! upper estimate from the control faces' area ([`texel_size_estimate`]: refuses absurd
//! sizes before anything is built), and after it, before any texel is allocated, the real
//! total of the per-face layout ([`check_layout`]).

use crate::error::{Error, Result};
use crate::method::Method;
use std::path::Path;
use std::sync::atomic::{AtomicU64, Ordering};
use subdiv::{ControlMesh, FaceId, Surface};

/// Makes glibc's malloc give freed memory back (the command line calls it first thing).
///
/// By default glibc raises its mmap threshold to the largest block freed (up to 32 MiB),
/// so once a per-texel array of a few MiB is freed, later blocks below that size come
/// from heaps that are trimmed only at their top: freed memory stays resident. Measured on
/// Spot N = 128 (jump), the write stage held ~80 MiB more resident than the process had
/// allocated (peak RSS 508 MiB against 428 MiB with this). Fixed thresholds (blocks from
/// the threshold up are mapped on their own and unmapped when freed; heaps are trimmed
/// above that much free) keep RSS near what is allocated; the run's time is unchanged
/// (docs/benchmarks.md). 128 KiB, was 1 MiB: the end of a run allocates many blocks of a
/// few hundred KiB (a domain's EXR tile or Ptex face, an atlas tile: 0.2–0.6 MiB at
/// N = 128) on several threads; below 1 MiB they came from per-thread heaps and stayed
/// resident once freed — coherent Spot N = 128 peaked at ~456 MiB of RSS for ~390 MiB
/// allocated, 400 MiB with 128 KiB (marginal 109 → 90 B per texel; docs/benchmarks.md,
/// "Spot at N = 128"). Skipped when `GLIBC_TUNABLES` sets malloc's own, and on other
/// platforms (whose allocators are not glibc's). Allocation only: results do not change.
pub fn tune_allocator() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    {
        if std::env::var("GLIBC_TUNABLES").is_ok_and(|t| t.contains("glibc.malloc.")) {
            return;
        }
        extern "C" {
            fn mallopt(param: i32, value: i32) -> i32;
        }
        // <malloc.h>
        const M_TRIM_THRESHOLD: i32 = -1;
        const M_MMAP_THRESHOLD: i32 = -3;
        const THRESHOLD: i32 = 128 << 10;
        // SAFETY: mallopt only sets allocator parameters; called before other threads
        // exist, and both values are within glibc's documented ranges.
        unsafe {
            mallopt(M_MMAP_THRESHOLD, THRESHOLD);
            mallopt(M_TRIM_THRESHOLD, THRESHOLD);
        }
    }
}

/// Share of physical memory used as the default limit.
pub const DEFAULT_FRACTION: f64 = 0.75;

/// Process baseline: binary, thread stacks, allocator arenas (measured: 5–7 MB for a
/// one-quad bake).
pub const BASELINE: u64 = 8 << 20;
/// Surface cost of a base quad whose four corners are regular (one bicubic patch, its
/// node, the control mesh's share), at the peak of reading and building it (the OBJ text,
/// the parsed mesh, the refined level and vectors growing by doubling): `bake` at N = 4 of
/// quad tori of 20k / 50k / 200k faces peaked at 80 / 156 / 738-766 MiB, 0.74-0.93 KB
/// per base quad (700 B, measured on smaller meshes, gave 0.71x at 200k faces).
const REGULAR_QUAD: u64 = 900;
/// Surface cost of a base quad at an extraordinary vertex: a constant plus a share per
/// stored patch-tree level (peak while building, measured on four triangle meshes:
/// 2.0–2.5 KB at depth 1, 8–12.7 KB at 3, 13.5–15.2 KB at 5, 19.2–20.5 KB at 7,
/// 28–30 KB at 10).
const IRREGULAR_QUAD: u64 = 1536;
const IRREGULAR_QUAD_PER_LEVEL: u64 = 2867;
/// Orientation field: per face of its limit mesh (positions, normals, locations, the
/// solver's arrays; most of it is kept for the texel frames), measured ~430 B.
pub const FIELD_FACE: u64 = 430;
/// `synth`, per texel, besides 4 bytes per map channel: what the largest stage holds at
/// once — during synthesis the texel geometry (24), frames (24), edge graph (4, and lists
/// at the borders; 20 before 2026-12-06), sources (8) and the method's compact state;
/// afterwards the maps, the tangents, and the tiles being written beside the pf summary's
/// block index and cover spacings (~12; a k-d tree of 32 before 2026-12-06, measured alone
/// before writing). Measured on Spot with
/// the coherent and jump methods (issue 14 item 6, 2026-12-03): whole-run peak 417–428
/// MiB at N = 128, 152–154 at N = 64, 135 at N = 32; 84 B per texel in all at 5 channels
/// puts the estimate at 1.03–1.04x at N = 128, 1.2x at N = 64 and 0.9x at N = 32, where
/// the orientation field's stage (a fixed part, not a sum with the texels) is the peak.
/// It was 160 while the pf summary copied every texel as f64 (~200 B per texel).
const SYNTH_TEXEL: u64 = 64;
/// `synth --method patches`, per texel on top of [`SYNTH_TEXEL`]: footprints (texel lists
/// and their example positions), the min-cut graphs in flight, the assembled sources.
/// Measured on Spot (2026-12-03): peak 264 MiB at N = 64, 882 at N = 128 (209 B per
/// texel between them). Since the footprint floods keep their state in a small table per
/// thread instead of a node per texel per thread (2026-12-06): 191 and 720 MiB (179 B per
/// texel between them); and the cuts' texel index too: 178 and 618 MiB (149 B per texel;
/// estimate / peak 1.05 and 1.04 at 50).
const PATCHES_TEXEL: u64 = 50;
/// `synth --method optimise`, per texel on top of [`SYNTH_TEXEL`]: the footprints of
/// every level, the per-texel accumulators of the M-step, the optimised sources and
/// colours, and the patch sampling that starts the coarsest level. Measured on Spot
/// (2026-12-03): peak 155 MiB at N = 32, 448 at N = 64 (~400 B per texel between them).
/// The source orientations (a 2-byte turn per footprint membership and per texel,
/// 2026-12-04) added ~30 B per texel: peak 1657 → 1778 MiB at N = 128 (estimate / peak
/// 0.98 → 0.91 at 300; 0.98 at 330). 2026-12-06: the M-step updates in place, the
/// previous patch size's footprints and texture are freed before the next size builds
/// its own, and the floods' state is a small table per thread (not a node per texel per
/// thread): peak 98 / 302 / 1051 MiB at N = 32 / 64 / 128 (from 134 / 443 / 1715; 254 B
/// per texel between N = 64 and 128, from 431), estimate / peak 1.01–1.06 at 170.
const OPTIMISE_TEXEL: u64 = 170;
/// `synth --method jump`, per example pixel: the jump map (4 targets, 4 weights, their
/// sum: 36 B) and, while it is built (a cache miss), the 3x3-lattice vectors (72 floats),
/// their tree projections and the kd-tree. Measured: a 512² example peaked 82 MB higher
/// on a miss than on a hit (flat grid, N = 32). Per texel, before its plan
/// ([`JUMP_TEXEL`]), jump needed nothing on top of [`SYNTH_TEXEL`]: its growth order,
/// buckets and sources (~16 B) took the room the other methods' appearance-space texels
/// take (Spot with a 128² example, `--no-cache`, N = 32, 64, 128: 124, 281, 814 MB peak, 479, 272, 197 B/texel before the compact pf
/// summary; 135, 154, 428 MiB after it, the estimate 0.91, 1.22, 1.03x of that).
const JUMP_MAP_PIXEL: u64 = 360;
/// `synth --method jump`, per texel: its plan ([`crate::synth::jump::Plan`]: rank order,
/// the earlier neighbours' ranks and offsets, ~2 per texel at 12 B, the margins) and
/// the sources scattered back to texel order. Measured (Spot, 128² example, `--no-cache`,
/// 2026-12-04): peak 464 → 538 MiB at N = 128 when the plan came, 135 MiB at N = 32; the
/// estimate without this term 441 and 124 MiB (0.82x, 0.91x), with it 1.05x and 0.97x.
const JUMP_TEXEL: u64 = 32;
/// `synth`, per border texel (4N per domain): its neighbour list across the face edges.
const SYNTH_BORDER_TEXEL: u64 = 64;
/// `synth`, per example pixel: decoded image, linear copy, alpha/height, the appearance
/// space (8 floats) and its similar-pixel lists (measured: ~220 B per pixel between a
/// 128² and a 256² example).
const EXAMPLE_PIXEL: u64 = 240;
/// `synth --method multiscale` (and texton synthesis, which runs on it), on top of the
/// parts every method has. Measured on Spot at N = 16–64 with 128², 256² and 512²
/// examples, a 10-face grid, the bunny and a 200k-face torus (docs/robustness.md):
///
/// - per texel of the output: the finest level's geometry (positions, f32 frames without
///   v2, parameter axes, Christoffel symbols: 92 B), the coarser level's (a quarter of
///   that), each level's sources (4 B), and the continuation of the sources (its links,
///   4 B each way, and positions); whole-run peak 216 MiB at N = 32 and 440 at N = 64 with
///   a 128² example (2026-12-03): 304 B per texel between them, [`SYNTH_TEXEL`]'s 84
///   included (it was 160 on top of the old 180); with the compact frames (2026-12-06)
///   214 and 418 MiB, 276 B per texel (327 before them the same day). The constant is
///   kept: the estimate is 1.06–1.12x the peak;
const MULTISCALE_TEXEL: u64 = 220;
/// - per example pixel (multiscale only): the appearance-space pyramid, the gathered-from images of the search features (the level
///   and its coarser level upsampled: 2 x 8 floats per pixel and level) and the
///   k-coherence lists (11 per pixel, 100 per pixel of the levels that parent another);
///   measured 98–161 B/pixel between 128² and 512²;
const MULTISCALE_PIXEL: u64 = 150;
/// - per face of the orientation field's limit mesh: the vertex-chart sampler's marching
///   structures over it (the coarsest level marches; ~39 MB on Spot, 184k faces);
const MULTISCALE_FIELD_FACE: u64 = 210;
/// - and a constant: the PCA that prunes the exact k-coherence lists fits the covariance
///   of the 848-dimensional 9x9 + 5x5 vectors (f64 and an f32 block: 8.6 MB).
const MULTISCALE_FIXED: u64 = 10 << 20;
/// Texton analysis per pixel of every image of the sample (`example_pixels` counts them
/// all for a BTF run): the filter responses and the k-means data, plus the search model
/// of the one texton-embedding image spread over the images (8 images of 64²: ~100 B).
const TEXTON_IMAGE_PIXEL: u64 = 100;
/// `--scale-map`, per texel: the interpolated factor (f64, kept by the session),
/// geometry.exr's `scale` channel (f32, the requested local scale) and what computes them
/// (measured on Spot: +45 B/texel at N = 64 with the coherent method).
const SCALE_MAP_TEXEL: u64 = 40;
/// `--scale-map` with the multiscale methods, per output texel, on top: their own factor
/// per texel of every level they synthesize (f64; measured on Spot at N = 32: +95 B/texel
/// in all).
const SCALE_MAP_LEVELS: u64 = 50;
/// `--displace`, per vertex of the tessellation: the limit mesh (its half-edge topology,
/// f64 positions, normals and locations) and the displaced f32 copy with texture
/// coordinates and quads. Measured: 341 MB peak with vs 108 MB without on Spot at N = 32
/// (749,570 vertices), 311 B per vertex.
const DISPLACE_VERTEX: u64 = 320;

/// Vertices of displaced.obj: the limit mesh at the level with >= N segments per domain
/// side ([`crate::io::displace::level_for_texels`]): base quads x (2^(level-1))².
/// With n-gon sub-faces (a sub-face is one base quad) quad domains get twice N per side.
pub fn displaced_vertices(size: &MeshSize, n: usize) -> u64 {
    let all_quads = size.base_quads == 4 * size.domains;
    let n = n.clamp(1, 1024) as u64;
    let per_base = if all_quads {
        (n.next_power_of_two() / 2).max(1)
    } else {
        n.next_power_of_two()
    }
    .min(512); // level_for_texels stops at level 10

    (size.base_quads as u64).saturating_mul(per_base * per_base)
}
/// `bake`: geometry channels and the per-texel scratch of a whole-domain evaluation
/// (`subdiv::LimitSample`, four f64 vectors), used up to N = 512.
const BAKE_CHANNELS: u64 = 6;
const LIMIT_SAMPLE: u64 = 96;
const BAKE_WHOLE_DOMAIN_MAX_N: u64 = 512;

static LIMIT: AtomicU64 = AtomicU64::new(0);

/// Sets the process-wide limit in bytes (`None`: back to the default).
pub fn set_limit(bytes: Option<u64>) {
    LIMIT.store(bytes.map_or(0, |b| b.max(1)), Ordering::SeqCst);
}

/// The limit in force and where it comes from (for messages).
#[derive(Clone, Debug, PartialEq)]
pub struct Limit {
    pub bytes: u64,
    /// "--max-memory 512 MiB", "75% of physical memory (31.3 GiB)" or "none".
    pub source: String,
}

/// The limit in force: [`set_limit`]'s value, or 75% of [`physical_memory`].
pub fn limit() -> Limit {
    match LIMIT.load(Ordering::SeqCst) {
        0 => match physical_memory() {
            Some(p) => Limit {
                bytes: (p as f64 * DEFAULT_FRACTION) as u64,
                source: format!(
                    "75% of physical memory ({}; set --max-memory to change)",
                    format_bytes(p)
                ),
            },
            None => Limit {
                bytes: u64::MAX,
                source: "none (physical memory unknown)".into(),
            },
        },
        u64::MAX => Limit {
            bytes: u64::MAX,
            source: "none".into(),
        },
        b => Limit {
            bytes: b,
            source: format!("--max-memory {}", format_bytes(b)),
        },
    }
}

/// Physical memory in bytes: `MemTotal` from /proc/meminfo, lowered to the cgroup's
/// memory limit (v2 `memory.max`, v1 `memory.limit_in_bytes`) when there is one. `None`
/// when neither can be read (not Linux).
pub fn physical_memory() -> Option<u64> {
    let total = std::fs::read_to_string("/proc/meminfo")
        .ok()
        .and_then(|s| meminfo_total(&s));
    let cgroup = [
        "/sys/fs/cgroup/memory.max",
        "/sys/fs/cgroup/memory/memory.limit_in_bytes",
    ]
    .iter()
    .filter_map(|p| std::fs::read_to_string(p).ok())
    .filter_map(|s| s.trim().parse::<u64>().ok())
    .find(|&b| b > 0);
    match (total, cgroup) {
        (Some(t), Some(c)) => Some(t.min(c)),
        (t, c) => t.or(c),
    }
}

/// `MemTotal:  24573892 kB` → bytes.
fn meminfo_total(s: &str) -> Option<u64> {
    let line = s.lines().find(|l| l.starts_with("MemTotal:"))?;
    let mut it = line.split_whitespace().skip(1);
    let v: u64 = it.next()?.parse().ok()?;
    let unit = match it.next() {
        None => 1,
        Some(u) if u.eq_ignore_ascii_case("kb") => 1024,
        Some(_) => return None,
    };
    v.checked_mul(unit)
}

/// Parses a memory size: a number with an optional unit K, M, G or T (powers of 1024;
/// `KB`/`KiB`, `MB`/`MiB`, ... mean the same; case does not matter; `B` or nothing means
/// bytes). Decimals are allowed (`1.5G`). `unlimited` or `none` turn the guard off
/// (`u64::MAX`). Zero and negative sizes are refused.
pub fn parse_size(s: &str) -> std::result::Result<u64, String> {
    let t = s.trim();
    if t.starts_with('-') {
        return Err(format!(
            "'{s}' is negative: the memory limit must be a positive size (e.g. 512M, 4G) or 'unlimited'"
        ));
    }
    let lower = t.to_ascii_lowercase();
    if lower == "unlimited" || lower == "none" {
        return Ok(u64::MAX);
    }
    let split = lower
        .find(|c: char| !(c.is_ascii_digit() || c == '.'))
        .unwrap_or(lower.len());
    let (num, unit) = lower.split_at(split);
    let shift = match unit.trim() {
        "" | "b" => 0,
        "k" | "kb" | "kib" => 10,
        "m" | "mb" | "mib" => 20,
        "g" | "gb" | "gib" => 30,
        "t" | "tb" | "tib" => 40,
        _ => {
            return Err(format!(
                "'{s}' is not a memory size: use a number with K, M, G or T (e.g. 512M, 4G) or 'unlimited'"
            ))
        }
    };
    let v: f64 = num.parse().map_err(|_| {
        format!("'{s}' is not a memory size: use a number with K, M, G or T (e.g. 512M, 4G) or 'unlimited'")
    })?;
    let bytes = v * (1u64 << shift) as f64;
    if bytes.is_nan() || bytes < 1.0 {
        return Err(format!("'{s}': the memory limit must be at least 1 byte"));
    }
    if bytes >= u64::MAX as f64 {
        return Err(format!("'{s}' is too large a memory size"));
    }
    Ok(bytes as u64)
}

/// Bytes in binary units with one decimal: "512.0 MiB", "4.2 GiB".
pub fn format_bytes(b: u64) -> String {
    const UNITS: [&str; 6] = ["B", "KiB", "MiB", "GiB", "TiB", "PiB"];
    let mut v = b as f64;
    let mut u = 0;
    while v >= 1024.0 && u + 1 < UNITS.len() {
        v /= 1024.0;
        u += 1;
    }
    if u == 0 {
        format!("{b} B")
    } else {
        format!("{v:.1} {}", UNITS[u])
    }
}

/// What the estimate needs to know about a control mesh.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct MeshSize {
    /// Ptex face domains.
    pub domains: usize,
    /// Base quads (level-1 faces): the sum of the face sizes.
    pub base_quads: usize,
    /// Base quads with a corner at an extraordinary vertex: every base quad of an n-gon
    /// (n != 4; its face point is extraordinary) and those at irregular control vertices,
    /// also where infinitely sharp edges make a corner irregular (a dart, a crease or
    /// corner whose sector is not the regular one).
    pub irregular_base_quads: usize,
    /// Base quads (not counted above) with a semi-sharp value left at a corner at level 1:
    /// their trees refine until it decays, ⌈s − 1⌉ levels for sharpness s ...
    pub semi_sharp_base_quads: usize,
    /// ... and the sum of those levels over them.
    pub semi_sharp_levels: usize,
}

impl MeshSize {
    pub fn of(control: &ControlMesh) -> Self {
        let m = &control.mesh;
        let (mut base, mut irregular) = (0usize, 0usize);
        let (mut semi_quads, mut semi_levels) = (0usize, 0usize);
        for f in 0..m.num_faces() {
            let vs = m.face_vertices(FaceId::from_idx(f));
            base += vs.len();
            if vs.len() != 4 {
                irregular += vs.len();
            } else {
                let h0 = m.face_he(FaceId::from_idx(f));
                for h in h0..h0 + 4 {
                    let v = m.origin(h);
                    if !m.has_tags() {
                        irregular += !m.is_regular_vertex(v) as usize;
                        continue;
                    }
                    // The largest semi-sharp value at the base quad's corners: the vertex
                    // and its edges, and the edge points of the face's two edges there.
                    let semi = |s: subdiv::Sharpness| {
                        if s.is_semi_sharp() {
                            s.value()
                        } else {
                            0.0
                        }
                    };
                    let mut top = semi(m.vertex_sharpness(v));
                    for (g, _) in m.vertex_edges(v) {
                        top = top.max(semi(m.edge_sharpness(g)));
                    }
                    let levels = (top - 1.0).max(0.0).ceil() as usize;
                    // With a semi-sharp value left, only the topology says whether the
                    // corner stays irregular after it decays (an estimate: sharp edges
                    // may still leave it irregular).
                    if (top > 0.0 && !m.is_regular_vertex(v))
                        || (top == 0.0 && !m.corner_is_regular(h))
                    {
                        irregular += 1;
                    } else if levels > 0 {
                        semi_quads += 1;
                        semi_levels += levels;
                    }
                }
            }
        }
        Self {
            domains: control.num_domains(),
            base_quads: base,
            irregular_base_quads: irregular,
            semi_sharp_base_quads: semi_quads,
            semi_sharp_levels: semi_levels,
        }
    }
}

/// The run being estimated.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Job {
    /// `synth`: `channels` of facemaps.exr (R G B \[A\] \[height\] source.u source.v) from an
    /// example of `example_pixels` pixels, by `method` (a BTF sample: the pixels of all its
    /// images).
    Synth {
        channels: usize,
        example_pixels: usize,
        method: Method,
        /// `--displace`: displaced.obj is tessellated at texel resolution.
        displace: bool,
        /// `--scale-map`: a factor per texel and geometry.exr's `scale` channel.
        scale_map: bool,
    },
    /// `bake` on `threads` worker threads.
    Bake { threads: usize },
}

impl Job {
    fn name(&self) -> &'static str {
        match self {
            Job::Synth { .. } => "synth",
            Job::Bake { .. } => "bake",
        }
    }
}

/// An estimate of peak memory, with the parts it is made of.
#[derive(Clone, Debug, PartialEq)]
pub struct Estimate {
    pub bytes: u64,
    /// (part, bytes), largest first.
    pub parts: Vec<(&'static str, u64)>,
    /// "252 domains x 64² texels x 5 channels".
    pub shape: String,
}

/// Faces of the orientation field's limit mesh for a run of `texels` texels (as
/// `field::auto_level` chooses it: the builder gives the texel count, `None` is the face
/// budget alone, as `OrientationField::compute`).
pub fn field_faces(base_quads: usize, texels: Option<u64>) -> u64 {
    let o = crate::field::FieldOptions {
        texels,
        ..Default::default()
    };
    (base_quads as u64) << (2 * (crate::field::auto_level(base_quads, &o) - 1))
}

/// How many texels a run has: F·N² at one resolution N, or the sum of the per-face
/// resolutions under a texel size.
#[derive(Clone, Debug, PartialEq)]
pub struct TexelCount {
    /// All texels.
    pub total: u64,
    /// Texels next to a domain border (their neighbour lists are stored).
    pub border: u64,
    /// The largest side: the patch depth, the tessellation level and `bake`'s tiles follow it.
    pub side: usize,
    /// "64² texels" or "4 to 4096 texels".
    pub shape: String,
}

impl TexelCount {
    /// `domains` x `n`².
    pub fn uniform(domains: usize, n: usize) -> Self {
        let n64 = n as u64;
        Self {
            total: (domains as u64).saturating_mul(n64.saturating_mul(n64)),
            border: (domains as u64).saturating_mul(4 * n64),
            side: n,
            shape: format!("{n}² texels"),
        }
    }

    /// The texels of a per-face layout.
    pub fn of_layout(layout: &crate::layout::TexelLayout) -> Self {
        let (a, b) = layout.max_dims();
        let border = (0..layout.faces())
            .map(|d| {
                let (u, v) = layout.dims(d);
                2 * (u + v) as u64
            })
            .sum();
        Self {
            total: layout.len() as u64,
            border,
            side: a.max(b),
            shape: format!("{} texels ({})", layout.len(), layout.describe()),
        }
    }
}

/// The subdivision surface of a mesh of `size` with the patch depth maps of side `n` need
/// (reading the control mesh and building its surface, at their peak).
pub fn surface_bytes(size: &MeshSize, n: usize) -> u64 {
    let sat = |a: u64, b: u64| a.saturating_mul(b);
    let depth = crate::bake::patch_depth_for(n) as u64;
    let irregular = size.irregular_base_quads as u64;
    let semi = size.semi_sharp_base_quads as u64;
    // Semi-sharp trees stop where the value has decayed (or at the stored depth).
    let semi_levels = (size.semi_sharp_levels as u64).min(sat(semi, depth));
    sat(
        (size.base_quads as u64).saturating_sub(irregular + semi),
        REGULAR_QUAD,
    )
    .saturating_add(sat(
        irregular,
        IRREGULAR_QUAD + IRREGULAR_QUAD_PER_LEVEL * depth,
    ))
    .saturating_add(sat(semi, IRREGULAR_QUAD))
    .saturating_add(sat(semi_levels, IRREGULAR_QUAD_PER_LEVEL))
}

/// Peak-memory estimate of `job` on a mesh of `size` at resolution `n`.
pub fn estimate(size: &MeshSize, n: usize, job: &Job) -> Estimate {
    estimate_texels(size, &TexelCount::uniform(size.domains, n), job)
}

/// Peak-memory estimate of `job` on a mesh of `size` with `count` texels.
pub fn estimate_texels(size: &MeshSize, count: &TexelCount, job: &Job) -> Estimate {
    let sat = |a: u64, b: u64| a.saturating_mul(b);
    let n = count.side;
    let n64 = n as u64;
    let domains = size.domains as u64;
    let texels = count.total;
    let mut parts = vec![("process", BASELINE), ("surface", surface_bytes(size, n))];
    let channels = match *job {
        Job::Synth {
            channels,
            example_pixels,
            method,
            displace,
            scale_map,
        } => {
            // Multiscale and textons add the field at the finest level within the budget
            // (`Session::field_for`).
            let fine = matches!(method, Method::Multiscale | Method::Textons);
            let field = field_faces(size.base_quads, Some(texels))
                + if fine {
                    field_faces(size.base_quads, None)
                } else {
                    0
                };
            parts.push(("orientation field", sat(field, FIELD_FACE)));
            parts.push(("texel maps", sat(texels, SYNTH_TEXEL + 4 * channels as u64)));
            parts.push(("neighbour lists", sat(count.border, SYNTH_BORDER_TEXEL)));
            parts.push(("example", sat(example_pixels as u64, EXAMPLE_PIXEL)));
            match method {
                Method::Coherent => {}
                Method::Patches => {
                    parts.push(("patch sampling", sat(texels, PATCHES_TEXEL)));
                }
                Method::Optimise => {
                    parts.push(("texture optimisation", sat(texels, OPTIMISE_TEXEL)));
                }
                Method::Jump => {
                    parts.push(("jump map", sat(example_pixels as u64, JUMP_MAP_PIXEL)));
                    parts.push(("jump plan", sat(texels, JUMP_TEXEL)));
                }
                Method::Textons | Method::Multiscale => {
                    parts.push(("multiscale levels", sat(texels, MULTISCALE_TEXEL)));
                    // Textons search one embedding image, not every image of the sample.
                    if method == Method::Multiscale {
                        parts.push((
                            "multiscale example model",
                            sat(example_pixels as u64, MULTISCALE_PIXEL),
                        ));
                    }
                    parts.push((
                        "multiscale sampler",
                        sat(field_faces(size.base_quads, None), MULTISCALE_FIELD_FACE)
                            .saturating_add(MULTISCALE_FIXED),
                    ));
                    if method == Method::Textons {
                        parts.push((
                            "texton analysis",
                            sat(example_pixels as u64, TEXTON_IMAGE_PIXEL),
                        ));
                    }
                }
            }
            if scale_map {
                let per = match method {
                    Method::Multiscale | Method::Textons => SCALE_MAP_TEXEL + SCALE_MAP_LEVELS,
                    _ => SCALE_MAP_TEXEL,
                };
                parts.push(("scale map", sat(texels, per)));
            }
            if displace {
                parts.push((
                    "displaced tessellation",
                    sat(displaced_vertices(size, n), DISPLACE_VERTEX),
                ));
            }
            channels
        }
        Job::Bake { threads } => {
            let threads = threads.max(1) as u64;
            let tile = sat(BAKE_CHANNELS * 4, sat(n64, n64));
            // As io::exr::write_tiles: batches of ~32 MiB, at least one tile per thread;
            // one batch of blocks is written while each thread fills the next (measured
            // at N = 2048: 2.0 tiles with one thread, 3.2 with two).
            let batch = ((32u64 << 20) / tile.max(1)).clamp(threads, 4096);
            let in_flight = batch.min(domains.max(1)) + threads;
            parts.push(("tiles in flight", sat(in_flight, tile)));
            if n64 <= BAKE_WHOLE_DOMAIN_MAX_N {
                parts.push((
                    "evaluation scratch",
                    sat(threads, sat(n64 * n64, LIMIT_SAMPLE)),
                ));
            }
            BAKE_CHANNELS as usize
        }
    };
    parts.sort_by_key(|p| std::cmp::Reverse(p.1));
    let bytes = parts.iter().fold(0u64, |s, p| s.saturating_add(p.1));
    Estimate {
        bytes,
        parts,
        shape: format!(
            "{} domains x {} x {channels} channels",
            size.domains, count.shape
        ),
    }
}

/// Refuses `estimate` when it is above the limit in force: one line naming `what` (the
/// mesh file), the estimate, its largest part and the limit.
pub fn check(what: &str, n: usize, job: &Job, e: &Estimate) -> Result<()> {
    check_against(&limit(), what, n, job, e)
}

/// [`check`] against an explicit limit.
pub fn check_against(lim: &Limit, what: &str, n: usize, job: &Job, e: &Estimate) -> Result<()> {
    refuse(
        lim,
        &format!("{what}: {} at --resolution {n}", job.name()),
        "",
        e,
        "lower --resolution or raise --max-memory",
    )
}

/// `Ok` when `e` fits `lim`, else the one-line refusal: "{subject} would need about X of
/// memory{scope} (estimate; shape; largest part: ...), more than the limit ...; {advice}".
fn refuse(lim: &Limit, subject: &str, scope: &str, e: &Estimate, advice: &str) -> Result<()> {
    if e.bytes <= lim.bytes {
        return Ok(());
    }
    let (part, part_bytes) = e.parts.first().copied().unwrap_or(("total", e.bytes));
    Err(Error::invalid(format!(
        "{subject} would need about {} of memory{scope} (estimate; {}; largest part: {part} {}), more than the limit of {} from {}; {advice}",
        format_bytes(e.bytes),
        e.shape,
        format_bytes(part_bytes),
        format_bytes(lim.bytes),
        lim.source,
    )))
}

/// Reads the control mesh at `path`, checks the estimate of `job` at resolution `n`
/// against the limit, and only then builds the surface (with the patch depth `n` needs,
/// as [`crate::bake::load_surface_for`]).
pub fn load_surface_checked(path: impl AsRef<Path>, n: usize, job: &Job) -> Result<Surface> {
    Ok(build_surface(load_control_checked(path, n, job)?, n))
}

/// The first half of [`load_surface_checked`]: the control mesh, read (at most a quarter
/// of the limit in bytes: a pipe or device has no size to check first) and checked.
pub fn load_control_checked(path: impl AsRef<Path>, n: usize, job: &Job) -> Result<ControlMesh> {
    let path = path.as_ref();
    let control = ControlMesh::load_obj_limited(path, limit().bytes / 4)?;
    check_coordinate_range(&path.display().to_string(), &control)?;
    let e = estimate(&MeshSize::of(&control), n, job);
    check(&path.display().to_string(), n, job, &e)?;
    Ok(control)
}

/// The largest side any face can get at texel size `l` (for the patch depth): the longest
/// control edge over `l` (a domain's side on the limit surface is at most about its
/// control edge), as a power of two, clamped to 1..=[`crate::layout::MAX_SIDE`].
pub fn texel_size_side(control: &ControlMesh, l: f64) -> usize {
    let m = &control.mesh;
    let mut longest = 0.0f64;
    for f in 0..m.num_faces() {
        let vs = m.face_vertices(FaceId::from_idx(f));
        for i in 0..vs.len() {
            let a = m.positions[vs[i] as usize];
            let b = m.positions[vs[(i + 1) % vs.len()] as usize];
            longest = longest.max(a.distance(b));
        }
    }
    let k = (longest / l).max(1.0);
    if k.is_finite() {
        (k.min(crate::layout::MAX_SIDE as f64) as usize)
            .next_power_of_two()
            .min(crate::layout::MAX_SIDE)
    } else {
        crate::layout::MAX_SIDE
    }
}

/// An upper estimate of the texels a texel size `l` gives `control`, before its surface is
/// built: twice the control faces' area over l² (rounding each side to the nearest power
/// of two makes a face at most 2x its ideal texel count; the limit surface is no larger
/// than the control polygons), plus 2x2 per domain (the smallest face).
pub fn texel_size_estimate(control: &ControlMesh, l: f64) -> TexelCount {
    let m = &control.mesh;
    let mut area = 0.0f64;
    for f in 0..m.num_faces() {
        let vs = m.face_vertices(FaceId::from_idx(f));
        let c = vs
            .iter()
            .map(|&v| m.positions[v as usize])
            .sum::<glam::DVec3>()
            / vs.len() as f64;
        for i in 0..vs.len() {
            let a = m.positions[vs[i] as usize] - c;
            let b = m.positions[vs[(i + 1) % vs.len()] as usize] - c;
            area += 0.5 * a.cross(b).length();
        }
    }
    let domains = control.num_domains() as f64;
    let total = 2.0 * area / (l * l) + 4.0 * domains;
    let total = if total.is_finite() {
        total.min(u64::MAX as f64) as u64
    } else {
        u64::MAX
    };
    let side = texel_size_side(control, l);
    TexelCount {
        total,
        // Border texels: 4 sides of sqrt(texels per domain) each.
        border: (4.0 * (total as f64 * domains).sqrt()) as u64,
        side,
        shape: format!("about {total} texels"),
    }
}

/// Reads the control mesh at `path` and checks the estimate of `job` at texel size `l`
/// (from [`texel_size_estimate`]) against the limit: an absurd texel size is refused here,
/// before the surface is built.
pub fn load_control_checked_texel_size(
    path: impl AsRef<Path>,
    l: f64,
    job: &Job,
) -> Result<ControlMesh> {
    let path = path.as_ref();
    let control = ControlMesh::load_obj_limited(path, limit().bytes / 4)?;
    check_coordinate_range(&path.display().to_string(), &control)?;
    check_texel_size_estimate(&path.display().to_string(), &control, l, job)?;
    Ok(control)
}

/// [`load_control_checked_texel_size`]'s check for a surface that is already built.
pub fn check_surface_texel_size(surface: &Surface, l: f64, job: &Job) -> Result<()> {
    let what = surface
        .control
        .path
        .as_ref()
        .map(|p| p.display().to_string())
        .unwrap_or_else(|| "<in-memory mesh>".into());
    check_texel_size_estimate(&what, &surface.control, l, job)
}

fn check_texel_size_estimate(what: &str, control: &ControlMesh, l: f64, job: &Job) -> Result<()> {
    let count = texel_size_estimate(control, l);
    let e = estimate_texels(&MeshSize::of(control), &count, job);
    refuse(
        &limit(),
        &format!("{what}: {} at --texel-size {l}", job.name()),
        "",
        &e,
        "raise --texel-size or --max-memory",
    )
}

/// The guard with the real texel total of `layout` (after the surface is built, before any
/// texel is allocated).
pub fn check_layout(
    what: &str,
    control: &ControlMesh,
    layout: &crate::layout::TexelLayout,
    job: &Job,
) -> Result<()> {
    let e = estimate_texels(&MeshSize::of(control), &TexelCount::of_layout(layout), job);
    refuse(
        &limit(),
        &format!("{what}: {} at this --texel-size", job.name()),
        "",
        &e,
        "raise --texel-size or --max-memory",
    )
}

/// The largest coordinate magnitude the outputs can hold: they store positions as 32-bit
/// floats (EXR channels, glTF, OBJ written from f32), whose largest value is 3.4e38; the
/// limit surface stays inside the control hull, and this leaves room for displacement.
pub const MAX_COORDINATE: f64 = 1e37;
/// The smallest extent (largest side of the bounding box) of a non-degenerate mesh whose
/// positions 32-bit outputs still resolve: 2^24 times the smallest normal f32.
pub const MIN_EXTENT: f64 = f32::MIN_POSITIVE as f64 * 16_777_216.0;

/// Refuses control meshes whose coordinates the outputs cannot store (|x| > 1e37, e.g. a
/// cube scaled by 1e300: its outputs would be infinite) or resolve (a mesh smaller than
/// ~2e-31 that is not a single point). Everything in between works at any scale: `synth`
/// normalises the mesh internally ([`normalising_unit`]).
pub fn check_coordinate_range(what: &str, control: &ControlMesh) -> Result<()> {
    let ps = &control.mesh.positions;
    if let Some((i, p)) = ps
        .iter()
        .enumerate()
        .find(|(_, p)| p.abs().max_element() > MAX_COORDINATE)
    {
        return Err(Error::invalid(format!(
            "{what}: vertex {} has a coordinate of magnitude {:e}, beyond what the outputs can store (32-bit floats; at most {MAX_COORDINATE:e} is supported): scale the mesh down",
            i + 1,
            p.abs().max_element()
        )));
    }
    let ext = extent(control);
    if ext > 0.0 && ext < MIN_EXTENT {
        return Err(Error::invalid(format!(
            "{what}: the mesh is {ext:e} across, too small for 32-bit outputs to resolve (at least {MIN_EXTENT:.1e} is supported): scale the mesh up"
        )));
    }
    Ok(())
}

/// The largest side of the control mesh's bounding box.
pub fn extent(control: &ControlMesh) -> f64 {
    if control.mesh.positions.is_empty() {
        return 0.0;
    }
    let (lo, hi) = control.bounds();
    (hi - lo).max_element()
}

/// The power of two by which `synth` divides the control mesh internally so that its
/// extent is near 1 (the texel geometry is 32-bit: at 1e30 its squared distances overflow,
/// at 1e-30 they underflow); 1 for meshes between 2^-16 and 2^16 across, which are
/// processed as given. A power of two makes the scaling exact.
pub fn normalising_unit(control: &ControlMesh) -> f64 {
    let ext = extent(control);
    if ext == 0.0 || !ext.is_finite() || (2f64.powi(-16)..=2f64.powi(16)).contains(&ext) {
        return 1.0;
    }
    2f64.powi(ext.log2().round() as i32)
}

/// Displacements beyond this many times the mesh's extent are refused: they turn the
/// surface into a spiky ball a thousand times its size (no picture or mesh of the
/// textured object is left), and at 1e30 overflow the 32-bit outputs and the ray tracer's
/// hierarchy.
pub const MAX_DISPLACE_PER_EXTENT: f64 = 1000.0;

/// Refuses `--displace amount` on a mesh of `extent` (see [`MAX_DISPLACE_PER_EXTENT`]).
pub fn check_displace(what: &str, amount: f64, extent: f64) -> Result<()> {
    let max = MAX_DISPLACE_PER_EXTENT * extent;
    if !amount.is_finite() || amount.abs() > max {
        return Err(Error::invalid(format!(
            "--displace {amount:e} is more than {MAX_DISPLACE_PER_EXTENT} times the size of the surface ({what} is {extent:e} across); use an amount of at most {max:e}"
        )));
    }
    Ok(())
}

/// The second half of [`load_surface_checked`]: the surface with the patch depth `n`
/// needs.
pub fn build_surface(control: ControlMesh, n: usize) -> Surface {
    crate::bake::surface_for(control, n)
}

/// The part of a `synth` estimate that the example alone is responsible for (decoding it, its appearance space and, for multiscale, its pyramid features),
/// from its header: an image bomb (a few KB claiming 20000x20000 pixels) is refused by
/// this, naming the image, before a pixel is decoded.
pub fn example_estimate(pixels: u64, decode_bytes: u64, job: &Job) -> Estimate {
    let sat = |a: u64, b: u64| a.saturating_mul(b);
    let mut parts = vec![
        ("decoding", decode_bytes),
        ("example", sat(pixels, EXAMPLE_PIXEL)),
    ];
    let mut channels = 0;
    if let Job::Synth {
        channels: c,
        method,
        ..
    } = *job
    {
        channels = c;
        match method {
            Method::Multiscale => {
                parts.push(("multiscale example model", sat(pixels, MULTISCALE_PIXEL)))
            }
            Method::Textons => parts.push(("texton analysis", sat(pixels, TEXTON_IMAGE_PIXEL))),
            _ => {}
        }
    }
    parts.sort_by_key(|p| std::cmp::Reverse(p.1));
    let bytes = parts.iter().fold(0u64, |s, p| s.saturating_add(p.1));
    Estimate {
        bytes,
        parts,
        shape: format!("{pixels} pixels x {} channels", channels.saturating_sub(2)),
    }
}

/// Refuses an example whose [`example_estimate`] alone is above the limit: one line
/// naming the image (`what`, e.g. "ex.png: image is 20000x20000 pixels").
pub fn check_example(what: &str, job: &Job, e: &Estimate) -> Result<()> {
    refuse(
        &limit(),
        &format!("{what}: {} with this example", job.name()),
        " for the example alone",
        e,
        "use a smaller example or raise --max-memory",
    )
}

/// [`check`] for a surface that is already built (in-memory inputs).
pub fn check_surface(surface: &Surface, n: usize, job: &Job) -> Result<()> {
    let what = surface
        .control
        .path
        .as_ref()
        .map(|p| p.display().to_string())
        .unwrap_or_else(|| "<in-memory mesh>".into());
    check(
        &what,
        n,
        job,
        &estimate(&MeshSize::of(&surface.control), n, job),
    )
}

// ------------------------------------------------------------------------------- render

/// `render`, per texel of the maps read (on top of 4 bytes per channel of facemaps.exr
/// while it is read): the five interleaved map values (R G B A height) the tracer
/// fetches from.
const RENDER_TEXEL: u64 = 20;
/// `render`, per slot of the cross-face fetch's border ring (2(u + 2) + 2v per domain of
/// u x v texels): 4 texel indices and 4 weights.
const RENDER_RING_TEXEL: u64 = 32;
/// `render`, per triangle of the tessellation, while it is built: the limit mesh
/// (topology, f64 positions and normals), the domain corners of its quads, the f32
/// copies, the BVH build. Measured: the cube at level 6 (49k triangles) 25 MB, Spot
/// displaced at level 5 (375k) 185 MB, a 50k-quad torus at level 2 (1.6 M) ~760 MB:
/// 470–510 B.
const RENDER_TRIANGLE_BUILD: u64 = 500;
/// ... and what the scene keeps while rays are cast (triangles in BVH order with their
/// vertices, domains and corner (u, v), f32 positions and normals, the BVH nodes).
const RENDER_TRIANGLE: u64 = 150;
/// `render`, per picture pixel: colour, domain and depth while tracing (20 B), then the
/// sRGB bytes and the PNG encoder's rows and output (the cube at 2048x1536: +49 MB over
/// 1024x768 for 2.4 M more pixels).
const RENDER_PIXEL: u64 = 24;
/// `render --light`, per texel: the texel normals and tangents, geometry.exr read whole,
/// the lit colours and the eight-channel maps built from them. Measured as the peak over
/// the same render without `--light`: a material set (colour, normal, roughness) on Spot
/// at N = 128 +506 MiB for 4.1 M texels (128 B), a 16-light BTF result at N = 64 +102 MiB
/// for 1.0 M texels (104 B); the sizes of the arrays had suggested 160 B.
const RENDER_LIGHT_TEXEL: u64 = 130;

/// What a `render` run holds, from facemaps.exr's header, the control mesh and the
/// options (see [`render_estimate`]).
#[derive(Clone, Debug, PartialEq)]
pub struct RenderJob {
    /// Texels of the maps (the layout's, not the padded data window's).
    pub texels: u64,
    /// Slots of the cross-face fetch's border ring: 2(u + 2) + 2v per domain.
    pub ring: u64,
    /// "32² texels" or "4 to 64² texels" (for messages).
    pub shape: String,
    /// The largest face-map side (the patch depth follows it).
    pub side: usize,
    /// Channels of facemaps.exr.
    pub channels: usize,
    /// Bytes of one decoded tile (all channels) and how many tiles the reader decodes at
    /// once (see [`crate::io::exr::read_face_maps`]).
    pub tile_bytes: u64,
    pub tiles_in_flight: u64,
    /// Triangles of the tessellation and its level.
    pub triangles: u64,
    pub level: u32,
    /// Picture size in pixels.
    pub width: u32,
    pub height: u32,
    /// `--light`: the texels are lit first.
    pub light: bool,
    /// `--displace`: the tessellation is at texel resolution.
    pub displace: bool,
}

/// Peak-memory estimate of a `render` of maps described by `job` on a mesh of `size`:
/// the surface and the texel maps, plus the larger of the two phases that follow each
/// other — reading facemaps.exr (its channels as f32 and the tiles in flight) and ray
/// tracing (the tessellation and its BVH, the picture).
pub fn render_estimate(size: &MeshSize, job: &RenderJob) -> Estimate {
    let sat = |a: u64, b: u64| a.saturating_mul(b);
    let texel_maps = sat(job.texels, RENDER_TEXEL)
        .saturating_add(sat(job.ring, RENDER_RING_TEXEL))
        .saturating_add(if job.light {
            sat(job.texels, RENDER_LIGHT_TEXEL)
        } else {
            0
        });
    let mut parts = vec![
        ("process", BASELINE),
        ("surface", surface_bytes(size, job.side)),
        ("texel maps", texel_maps),
    ];
    // facemaps.exr's channels are held while the texel maps are made from them; the
    // tiles in flight before, while they are read (decoded, and the compressed chunks
    // not yet decoded: Spot N = 128, 4.1 M texels, peaks at 176 MiB when the texel maps
    // are made, not while its 205 tiles of 320 KiB are in flight).
    let reading = sat(job.texels, 4 * job.channels as u64).saturating_add(
        sat(3 * job.tiles_in_flight, job.tile_bytes / 2).saturating_sub(texel_maps),
    );
    let pixels = job.width as u64 * job.height as u64;
    let build = sat(job.triangles, RENDER_TRIANGLE_BUILD);
    let kept = sat(job.triangles, RENDER_TRIANGLE);
    let picture = sat(pixels, RENDER_PIXEL);
    if reading >= build.max(kept.saturating_add(picture)) {
        parts.push(("reading facemaps.exr", reading));
    } else if build >= kept.saturating_add(picture) {
        parts.push(("tessellation", build));
    } else {
        parts.push(("ray-casting scene", kept));
        parts.push(("picture", picture));
    }
    parts.sort_by_key(|p| std::cmp::Reverse(p.1));
    let bytes = parts.iter().fold(0u64, |s, p| s.saturating_add(p.1));
    Estimate {
        bytes,
        parts,
        shape: format!(
            "{} domains x {} x {} channels, {} triangles at level {}, {}x{} pixels",
            size.domains, job.shape, job.channels, job.triangles, job.level, job.width, job.height
        ),
    }
}

/// Refuses a `render` of `what` (the result directory) whose estimate `e` is above the
/// limit: one line with the estimate, its largest part and the limit.
pub fn check_render(what: &str, job: &RenderJob, e: &Estimate) -> Result<()> {
    // Advice for what the user can change: the picture size, the displacement.
    let advice = match e.parts.first().map(|p| p.0) {
        Some("picture" | "ray-casting scene") => "lower --width/--height or raise --max-memory",
        Some("tessellation") if job.displace => "render without --displace or raise --max-memory",
        _ => "raise --max-memory",
    };
    refuse(
        &limit(),
        &format!("{what}: render at {}x{}", job.width, job.height),
        "",
        e,
        advice,
    )
}

/// Refuses a benchmark (`subject`, e.g. "bench exr --domains 50000000 --resolution 64")
/// whose estimate `e` is above the limit, with `advice` (which flags to lower).
pub fn check_bench(subject: &str, e: &Estimate, advice: &str) -> Result<()> {
    refuse(&limit(), subject, "", e, advice)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sizes_parse() {
        assert_eq!(parse_size("512M"), Ok(512 << 20));
        assert_eq!(parse_size("4G"), Ok(4 << 30));
        assert_eq!(parse_size("4g"), Ok(4 << 30));
        assert_eq!(parse_size("4GiB"), Ok(4 << 30));
        assert_eq!(parse_size("4 GB"), Ok(4 << 30));
        assert_eq!(parse_size("1.5K"), Ok(1536));
        assert_eq!(parse_size("1000"), Ok(1000));
        assert_eq!(parse_size("2T"), Ok(2 << 40));
        assert_eq!(parse_size("unlimited"), Ok(u64::MAX));
        for bad in [
            "0", "0M", "-1G", "lots", "", "G", "1.2.3M", "5Q", "nan", "1e30T",
        ] {
            assert!(parse_size(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn bytes_format() {
        assert_eq!(format_bytes(12), "12 B");
        assert_eq!(format_bytes(512 << 20), "512.0 MiB");
        assert_eq!(format_bytes(3 << 29), "1.5 GiB");
        assert_eq!(format_bytes(u64::MAX), "16384.0 PiB");
    }

    #[test]
    fn meminfo_parses() {
        let s = "MemTotal:       24573892 kB\nMemFree:        1 kB\n";
        assert_eq!(meminfo_total(s), Some(24573892 * 1024));
        assert_eq!(meminfo_total("nothing"), None);
        assert!(physical_memory().unwrap_or(1) > 0);
    }

    fn grid(k: usize) -> ControlMesh {
        let mut pos = Vec::new();
        for j in 0..=k {
            for i in 0..=k {
                pos.push(glam::DVec3::new(i as f64, j as f64, 0.0));
            }
        }
        let id = |i: usize, j: usize| (j * (k + 1) + i) as u32;
        let faces: Vec<Vec<u32>> = (0..k)
            .flat_map(|j| {
                (0..k).map(move |i| vec![id(i, j), id(i + 1, j), id(i + 1, j + 1), id(i, j + 1)])
            })
            .collect();
        let refs: Vec<&[u32]> = faces.iter().map(|f| f.as_slice()).collect();
        ControlMesh::from_faces(pos, &refs).unwrap()
    }

    #[test]
    fn mesh_size_counts_irregular_quads() {
        // A 3x3 quad grid: boundary vertices with 3 faces do not exist; every vertex is
        // regular (corners 1 face, edges 2, interior 4).
        let s = MeshSize::of(&grid(3));
        assert_eq!(
            s,
            MeshSize {
                domains: 9,
                base_quads: 36,
                irregular_base_quads: 0,
                semi_sharp_base_quads: 0,
                semi_sharp_levels: 0,
            }
        );
        // A 3x3 grid with a semi-sharp crease (2.5) along y = 1, boundary to boundary: the
        // base quads at its four vertices (2 + 4 + 4 + 2 face corners) refine
        // ⌈2.5 − 1⌉ = 2 levels; none is irregular for good.
        let creased = grid(3)
            .with_sharpness(&[(4, 5, 2.5), (5, 6, 2.5), (6, 7, 2.5)], &[])
            .unwrap();
        let s = MeshSize::of(&creased);
        assert_eq!(s.irregular_base_quads, 0);
        assert_eq!(s.semi_sharp_base_quads, 12);
        assert_eq!(s.semi_sharp_levels, 24);
        // A triangle: 3 domains, 3 base quads, all at the extraordinary face point.
        let tri = ControlMesh::parse_obj("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n").unwrap();
        let s = MeshSize::of(&tri);
        assert_eq!(
            s,
            MeshSize {
                domains: 3,
                base_quads: 3,
                irregular_base_quads: 3,
                semi_sharp_base_quads: 0,
                semi_sharp_levels: 0,
            }
        );
    }

    #[test]
    fn displaced_vertices_count_the_tessellation() {
        // Against the limit mesh displaced.obj is made of: all quads, and with n-gons.
        let spot = ControlMesh::load_obj(
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/spot_control_mesh.obj"),
        )
        .unwrap();
        for (control, n) in [(grid(4), 8), (grid(4), 5), (spot, 4)] {
            let size = MeshSize::of(&control);
            let surface = subdiv::Surface::new(control);
            let level = crate::io::displace::level_for_texels(&surface, n);
            let quads = surface.limit_mesh(level).mesh.num_faces() as u64;
            assert_eq!(displaced_vertices(&size, n), quads, "n = {n}");
        }
    }

    #[test]
    fn estimate_grows_with_resolution_and_channels() {
        let s = MeshSize::of(&grid(4));
        let job = |c| Job::Synth {
            channels: c,
            example_pixels: 128 * 128,
            method: Method::Coherent,
            displace: false,
            scale_map: false,
        };
        let a = estimate(&s, 32, &job(5));
        let b = estimate(&s, 64, &job(5));
        let c = estimate(&s, 64, &job(7));
        assert!(b.bytes > a.bytes && c.bytes > b.bytes);
        // The texel part at N = 64: 16 domains x 4096 texels x (SYNTH_TEXEL + 20) bytes.
        let texel_part = b.parts.iter().find(|p| p.0 == "texel maps").unwrap().1;
        assert_eq!(texel_part, 16 * 4096 * (SYNTH_TEXEL + 20));
        assert!(
            b.shape.contains("16 domains x 64² texels x 5 channels"),
            "{}",
            b.shape
        );
        // The other methods need more per texel (and multiscale per example pixel), in
        // the order measured: coherent < patches < optimise < multiscale.
        let cost = |method, scale_map| {
            let job = Job::Synth {
                channels: 5,
                example_pixels: 128 * 128,
                method,
                displace: false,
                scale_map,
            };
            estimate(&s, 64, &job).bytes
        };
        let by = |method| cost(method, false);
        let scaled = |method| cost(method, true);
        let costs: Vec<u64> = [
            Method::Coherent,
            Method::Patches,
            Method::Optimise,
            Method::Multiscale,
        ]
        .map(by)
        .into();
        assert_eq!(costs[0], b.bytes);
        assert!(costs.windows(2).all(|w| w[0] < w[1]), "{costs:?}");
        // Multiscale: its levels per texel, its model per example pixel, the sampler and
        // the field at the finest level within the budget beside the prepared one.
        assert_eq!(
            costs[3] - b.bytes,
            16 * 4096 * MULTISCALE_TEXEL
                + 128 * 128 * MULTISCALE_PIXEL
                + field_faces(s.base_quads, None) * (MULTISCALE_FIELD_FACE + FIELD_FACE)
                + MULTISCALE_FIXED
        );
        // A scale map adds its factor and channel per texel (more for multiscale).
        assert_eq!(
            scaled(Method::Coherent) - costs[0],
            16 * 4096 * SCALE_MAP_TEXEL
        );
        assert_eq!(
            scaled(Method::Multiscale) - costs[3],
            16 * 4096 * (SCALE_MAP_TEXEL + SCALE_MAP_LEVELS)
        );
        // Absurd sizes saturate instead of overflowing.
        let huge = estimate(
            &MeshSize {
                domains: usize::MAX,
                ..s
            },
            1 << 20,
            &job(5),
        );
        assert_eq!(huge.bytes, u64::MAX);
        // Bake holds only a bounded number of tiles, however many domains.
        let bake =
            |d: usize| estimate(&MeshSize { domains: d, ..s }, 16, &Job::Bake { threads: 2 }).bytes;
        assert_eq!(bake(100_000), bake(1_000_000));
    }

    #[test]
    fn refusal_is_one_line_with_estimate_and_limit() {
        let s = MeshSize::of(&grid(4));
        let job = Job::Bake { threads: 2 };
        let e = estimate(&s, 4096, &job);
        // An explicit limit: the process-wide one is left alone, since other unit tests
        // may be running synthesis at the same time.
        let lim = |b: u64| Limit {
            bytes: b,
            source: format!("--max-memory {}", format_bytes(b)),
        };
        let msg = check_against(&lim(1 << 20), "m.obj", 4096, &job, &e)
            .unwrap_err()
            .to_string();
        assert!(!msg.contains('\n'), "{msg}");
        assert!(
            msg.starts_with("m.obj: bake at --resolution 4096 would need about "),
            "{msg}"
        );
        assert!(msg.contains(&format_bytes(e.bytes)), "{msg}");
        assert!(
            msg.contains("limit of 1.0 MiB from --max-memory 1.0 MiB"),
            "{msg}"
        );
        assert!(check_against(&lim(e.bytes), "m.obj", 4096, &job, &e).is_ok());
        assert!(check_against(&lim(u64::MAX), "m.obj", 4096, &job, &e).is_ok());
    }
}
