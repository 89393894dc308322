//! Geometry maps: limit position and normal at every texel centre of every face domain
//! (`geometry.exr`, channels `P.X P.Y P.Z N.X N.Y N.Z`).
//!
//! Domains are independent, so they are evaluated in parallel, one domain per task, each
//! straight into its f32 tile. Nothing depends on which thread did what, so the output is
//! bit-identical for any thread count. [`bake_to_file`] streams: a domain is evaluated,
//! converted to f32 and compressed while others are being written, so peak memory does not
//! grow with the mesh (only the surface itself and a bounded batch of tiles are held);
//! [`bake_geometry`] is the in-memory variant for stages that need the maps afterwards.

use crate::error::Result;
use crate::io::exr::{write_tiles, Compression, FaceMaps, TileLayout};
use indicatif::ProgressBar;
use rayon::prelude::*;
use std::path::Path;
use std::time::Instant;
use subdiv::{DomainId, LimitSample, Surface};

/// Channel names of geometry maps, in the order [`eval_domain`] fills them.
pub const GEOMETRY_CHANNELS: [&str; 6] = ["P.X", "P.Y", "P.Z", "N.X", "N.Y", "N.Z"];

pub use crate::io::names::GEOMETRY_FILE;

/// Up to this resolution a domain is evaluated with `Surface::eval_texels` into a per-thread
/// scratch of N² f64 samples (25 MB at 512); above, texel by texel with the same
/// arithmetic, so that huge N does not need gigabytes of scratch.
const WHOLE_DOMAIN_MAX_N: usize = 512;

/// Patch-tree depth to store for maps of resolution `n` (`SurfaceOptions::max_depth`).
///
/// The surface stores its patch trees around extraordinary vertices down to a fixed depth
/// and refines deeper on demand (exact either way). A texel centre is at least 1/(2N) of a
/// domain away from a corner, i.e. 1/N of a base quad, so depth ceil(log2 N) + 1 already
/// reaches a regular leaf for every texel, and no level that no texel visits is stored
/// (on triangle meshes, where every base quad has an extraordinary corner, those levels
/// would be most of the surface's memory). Capped at [`MAX_PATCH_DEPTH`]: beyond N = 512
/// the few texels nearest extraordinary vertices are refined on demand (still exact).
pub fn patch_depth_for(n: usize) -> u32 {
    let log2 = usize::BITS - n.max(1).saturating_sub(1).leading_zeros();
    (log2 + 1).clamp(1, MAX_PATCH_DEPTH)
}

/// Deepest patch tree `bake` stores (enough for every texel centre up to N = 512).
pub const MAX_PATCH_DEPTH: u32 = 10;

/// Loads a control mesh and builds its surface with the patch depth `n` needs.
pub fn load_surface_for(path: impl AsRef<Path>, n: usize) -> Result<Surface> {
    Ok(surface_for(subdiv::ControlMesh::load_obj(path)?, n))
}

/// The surface of `control` with the patch depth maps of resolution `n` need.
pub fn surface_for(control: subdiv::ControlMesh, n: usize) -> Surface {
    Surface::with_options(
        control,
        subdiv::surface::SurfaceOptions {
            max_depth: patch_depth_for(n),
        },
    )
}

/// Evaluates domain `d` at its N x N texel centres ((x+0.5)/N, (y+0.5)/N) into `out`:
/// six channel-major arrays of N² f32 in [`GEOMETRY_CHANNELS`] order, row-major (y outer).
/// `scratch` is reused between calls to avoid an allocation per domain.
pub fn eval_domain(
    surface: &Surface,
    d: usize,
    n: usize,
    scratch: &mut Vec<LimitSample>,
    out: &mut [f32],
) {
    eval_domain_impl(surface, d, n, scratch, out, WHOLE_DOMAIN_MAX_N)
}

fn eval_domain_impl(
    surface: &Surface,
    d: usize,
    n: usize,
    scratch: &mut Vec<LimitSample>,
    out: &mut [f32],
    whole_max: usize,
) {
    let nn = n * n;
    assert_eq!(out.len(), 6 * nn);
    let (p, rest) = out.split_at_mut(3 * nn);
    let mut put = |i: usize, s: &LimitSample| {
        p[i] = s.p.x as f32;
        p[nn + i] = s.p.y as f32;
        p[2 * nn + i] = s.p.z as f32;
        rest[i] = s.n.x as f32;
        rest[nn + i] = s.n.y as f32;
        rest[2 * nn + i] = s.n.z as f32;
    };
    if n <= whole_max {
        scratch.resize(nn, LimitSample::default());
        surface.eval_texels(DomainId(d as u32), n, scratch);
        for (i, s) in scratch.iter().enumerate() {
            put(i, s);
        }
    } else {
        // Same parameter arithmetic as `Surface::eval_texels`.
        let inv = 1.0 / n as f64;
        for y in 0..n {
            let v = (y as f64 + 0.5) * inv;
            for x in 0..n {
                let u = (x as f64 + 0.5) * inv;
                put(y * n + x, &surface.eval(DomainId(d as u32), u, v));
            }
        }
    }
}

/// Geometry maps of every domain, in memory (F*N² texels x 6 channels x 4 bytes, with no
/// second copy: each domain is evaluated into a small buffer and copied to its place).
pub fn bake_geometry(surface: &Surface, n: usize) -> FaceMaps {
    let faces = surface.num_domains();
    let nn = n * n;
    let mut maps = FaceMaps::new(faces, n, &GEOMETRY_CHANNELS);
    let mut ch = maps.channels.iter_mut().map(|(_, d)| d.as_mut_slice());
    let mut next = || ch.next().expect("six channels").par_chunks_mut(nn);
    let tiles = next()
        .zip(next())
        .zip(next())
        .zip(next())
        .zip(next())
        .zip(next());
    tiles.enumerate().for_each_init(
        || (Vec::new(), vec![0f32; 6 * nn]),
        |(scratch, buf), (d, (((((a, b), c), e), f), g))| {
            eval_domain(surface, d, n, scratch, buf);
            for (k, dst) in [a, b, c, e, f, g].into_iter().enumerate() {
                dst.copy_from_slice(&buf[k * nn..(k + 1) * nn]);
            }
        },
    );
    maps
}

/// What a bake did.
#[derive(Clone, Debug, PartialEq)]
pub struct BakeStats {
    pub domains: usize,
    pub resolution: usize,
    pub texels: u64,
    /// Wall time of evaluation + writing (not loading the mesh).
    pub seconds: f64,
}

impl BakeStats {
    pub fn texels_per_second(&self) -> f64 {
        self.texels as f64 / self.seconds.max(1e-9)
    }
}

/// Evaluates and writes `path` (normally `DIR/geometry.exr`) in one streaming pass;
/// `progress` advances by one per domain written.
pub fn bake_to_file(
    surface: &Surface,
    n: usize,
    path: impl AsRef<Path>,
    compression: Compression,
    progress: &ProgressBar,
) -> Result<BakeStats> {
    let t = Instant::now();
    let faces = surface.num_domains();
    let layout = TileLayout::new(faces, n);
    progress.set_length(faces as u64);
    write_tiles(
        path,
        layout,
        &GEOMETRY_CHANNELS,
        compression,
        |d, out| SCRATCH.with(|s| eval_domain(surface, d, n, &mut s.borrow_mut(), out)),
        &|done| progress.set_position(done as u64),
    )?;
    progress.finish_and_clear();
    Ok(BakeStats {
        domains: faces,
        resolution: n,
        texels: (faces * n * n) as u64,
        seconds: t.elapsed().as_secs_f64(),
    })
}

/// [`bake_to_file`] for per-face resolutions (`bake --texel-size`): domain d's texel
/// centres ((x+0.5)/nu, (y+0.5)/nv), same channel order.
pub fn bake_layout_to_file(
    surface: &Surface,
    layout: std::sync::Arc<crate::layout::TexelLayout>,
    path: impl AsRef<Path>,
    compression: Compression,
    progress: &ProgressBar,
) -> Result<BakeStats> {
    let t = Instant::now();
    let faces = surface.num_domains();
    let tiles = TileLayout::of(layout.clone());
    progress.set_length(faces as u64);
    write_tiles(
        path,
        tiles,
        &GEOMETRY_CHANNELS,
        compression,
        |d, out| {
            let (nu, nv) = layout.dims(d);
            let nn = nu * nv;
            for y in 0..nv {
                let v = (y as f64 + 0.5) / nv as f64;
                for x in 0..nu {
                    let s = surface.eval(DomainId(d as u32), (x as f64 + 0.5) / nu as f64, v);
                    let i = y * nu + x;
                    for (k, c) in [s.p.x, s.p.y, s.p.z, s.n.x, s.n.y, s.n.z]
                        .iter()
                        .enumerate()
                    {
                        out[k * nn + i] = *c as f32;
                    }
                }
            }
        },
        &|done| progress.set_position(done as u64),
    )?;
    progress.finish_and_clear();
    let (a, b) = layout.max_dims();
    Ok(BakeStats {
        domains: faces,
        resolution: a.max(b),
        texels: layout.len() as u64,
        seconds: t.elapsed().as_secs_f64(),
    })
}

/// Evaluates every domain without keeping or writing anything (the benchmark's
/// "evaluation alone"); returns a checksum so the work cannot be optimised away.
pub fn eval_only(surface: &Surface, n: usize) -> f64 {
    (0..surface.num_domains())
        .into_par_iter()
        .map_init(
            || (Vec::new(), vec![0f32; 6 * n * n]),
            |(scratch, out), d| {
                eval_domain(surface, d, n, scratch, out);
                out.iter().map(|&v| v as f64).sum::<f64>()
            },
        )
        .sum()
}

thread_local! {
    /// Per-thread f64 sample scratch for [`bake_to_file`] (the tile callback has no state).
    static SCRATCH: std::cell::RefCell<Vec<LimitSample>> = const { std::cell::RefCell::new(Vec::new()) };
}

#[cfg(test)]
mod tests {
    use super::*;
    use subdiv::ControlMesh;

    fn cube() -> Surface {
        Surface::new(ControlMesh::cuboid(
            glam::DVec3::splat(-1.0),
            glam::DVec3::splat(1.0),
        ))
    }

    #[test]
    fn both_evaluation_paths_are_bit_identical() {
        let s = cube();
        for n in [1, 3, 8] {
            let mut a = vec![0f32; 6 * n * n];
            let mut b = a.clone();
            let mut scratch = Vec::new();
            for d in 0..s.num_domains() {
                eval_domain_impl(&s, d, n, &mut scratch, &mut a, usize::MAX);
                eval_domain_impl(&s, d, n, &mut scratch, &mut b, 0);
                assert!(a.iter().zip(&b).all(|(x, y)| x.to_bits() == y.to_bits()));
            }
        }
    }

    #[test]
    fn shallow_patch_trees_give_bit_identical_texels() {
        assert_eq!(
            [1, 2, 3, 4, 8, 16, 17, 32, 128, 129, 8192].map(patch_depth_for),
            [1, 2, 3, 3, 4, 5, 6, 6, 8, 9, 10]
        );
        // A triangle and a pentagon next to quads: every kind of extraordinary corner.
        let p = [
            [0., 0., 0.],
            [1., 0., 0.],
            [2., 0., 0.],
            [0., 1., 0.],
            [1., 1., 0.3],
            [2., 1., 0.],
            [0.5, 2., 0.],
            [1.5, 2.2, 0.1],
            [2.5, 1.8, 0.],
        ]
        .map(glam::DVec3::from_array)
        .to_vec();
        let f: [&[u32]; 4] = [&[0, 1, 4, 3], &[1, 2, 5, 4], &[3, 4, 6], &[4, 5, 8, 7, 6]];
        let control = ControlMesh::from_faces(p, &f).unwrap();
        let deep = Surface::new(control.clone());
        for n in [1, 2, 3, 5, 8, 16, 33] {
            let shallow = Surface::with_options(
                control.clone(),
                subdiv::surface::SurfaceOptions {
                    max_depth: patch_depth_for(n),
                },
            );
            let a = bake_geometry(&deep, n);
            let b = bake_geometry(&shallow, n);
            for ((_, x), (_, y)) in a.channels.iter().zip(&b.channels) {
                assert!(
                    x.iter().zip(y).all(|(u, v)| u.to_bits() == v.to_bits()),
                    "N = {n}"
                );
            }
        }
    }

    #[test]
    fn in_memory_and_streamed_bakes_agree() {
        let s = cube();
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join(GEOMETRY_FILE);
        let stats = bake_to_file(&s, 5, &p, Compression::ZIP16, &ProgressBar::hidden()).unwrap();
        assert_eq!((stats.domains, stats.texels), (6, 150));
        let read = crate::io::exr::read_face_maps(&p).unwrap();
        let mem = bake_geometry(&s, 5);
        for name in GEOMETRY_CHANNELS {
            assert_eq!(read.channel(name).unwrap(), mem.channel(name).unwrap());
        }
        // Normals are unit, positions inside the control cage.
        let nx = mem.channel("N.X").unwrap();
        let ny = mem.channel("N.Y").unwrap();
        let nz = mem.channel("N.Z").unwrap();
        for i in 0..nx.len() {
            let l = (nx[i] * nx[i] + ny[i] * ny[i] + nz[i] * nz[i]).sqrt();
            assert!((l - 1.0).abs() < 1e-6);
        }
        assert!(mem.channel("P.X").unwrap().iter().all(|v| v.abs() < 1.0));
        assert!(eval_only(&s, 5).is_finite());
    }
}
