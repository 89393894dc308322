//! `facemaps.ptx`: the face maps as a Ptex file, for renderers that read per-face textures
//! as Ptex (RenderMan, Arnold, V-Ray, pbrt-v4), written in pure Rust (zlib via flate2).
//!
//! What is in the file (docs/formats.md has the byte layout):
//!
//! - quad mesh type, one face per face domain in domain order (a control quad is one face,
//!   an n-gon n sub-faces, flagged as such), so Ptex face ids are our domain ids;
//! - every channel of the maps as f32, in the maps' order (`R G B [A] [height] source.u
//!   source.v`), `A` as the alpha channel; names in the meta data `surfsynth.channels`;
//! - per-face resolutions, u and v apart ([`Res`]; the maps have N × N everywhere today);
//! - adjacency derived from the control mesh by Ptex's rules for quads and n-gon sub-faces
//!   ([`face_infos`]);
//! - the reduction levels (mip maps) and constant values and flags exactly as the
//!   reference writer computes them, and the control mesh as the standard meta data
//!   `PtexFaceVertCounts`, `PtexFaceVertIndices`, `PtexVertPositions`.
//!
//! Ptex resolutions are powers of two; for another N the maps are resampled to the next
//! power of two (bilinear, across face edges), and `surfsynth.resolution` records N.
//!
//! Checked against the reference library (`tests/ptex.rs`): faces, resolutions, adjacency
//! and texels as read by `ptxinfo`, reductions and filtered lookups across face edges.

pub mod adjacency;
pub mod format;
mod neighbourhood;
mod texels;
mod writer;

pub use adjacency::face_infos;
pub use format::{FaceInfo, Res};
pub use writer::{write_ptex, MetaValue, PtexImage, PtexOptions, PtexSummary};

use crate::error::{Error, Result};
use crate::io::exr::FaceMaps;
use std::path::Path;
use std::sync::Arc;
use subdiv::{DomainId, DomainLocation, Surface};

/// File name in the output directory.
pub const PTEX_FILE: &str = "facemaps.ptx";

/// Meta data naming the channels (comma-separated, in channel order).
pub const META_CHANNELS: &str = "surfsynth.channels";
/// Meta data holding the maps' resolution N (the Ptex faces have the next power of two).
pub const META_RESOLUTION: &str = "surfsynth.resolution";

/// The control mesh as Ptex's standard meta data (what `ptxview` and DCC tools read to
/// show the texture on its mesh).
pub fn mesh_meta(surface: &Surface) -> Vec<(String, MetaValue)> {
    let m = &surface.control.mesh;
    let counts = (0..m.num_faces())
        .map(|f| m.face_size(subdiv::FaceId::from_idx(f)) as i32)
        .collect();
    let indices = (0..m.num_faces())
        .flat_map(|f| {
            m.face_vertices(subdiv::FaceId::from_idx(f))
                .iter()
                .map(|&v| v as i32)
        })
        .collect();
    let positions = surface
        .control
        .mesh
        .positions
        .iter()
        .flat_map(|p| [p.x as f32, p.y as f32, p.z as f32])
        .collect();
    vec![
        ("PtexFaceVertCounts".into(), MetaValue::Int32(counts)),
        ("PtexFaceVertIndices".into(), MetaValue::Int32(indices)),
        ("PtexVertPositions".into(), MetaValue::Float(positions)),
    ]
}

/// Writes `maps` (on `surface`) as a Ptex file at `path`, atomically.
pub fn write_face_maps_ptex(
    path: impl AsRef<Path>,
    surface: &Surface,
    maps: &FaceMaps,
    opts: &PtexOptions,
) -> Result<PtexSummary> {
    let path = path.as_ref();
    maps.validate()?;
    if maps.faces() != surface.num_domains() {
        return Err(Error::invalid(format!(
            "face maps have {} domains but the mesh has {}",
            maps.faces(),
            surface.num_domains()
        )));
    }
    let names = maps.names();
    let mut meta = vec![(
        META_CHANNELS.to_string(),
        MetaValue::String(names.join(",")),
    )];
    let Some(n) = maps.uniform_n() else {
        // Per-face resolutions (`--texel-size`) are powers of two already: Ptex's own
        // per-face resolution fields, texels copied as they are.
        let res = maps
            .layout
            .resolutions()
            .expect("a layout is uniform or per face");
        let infos = face_infos(surface, |d| Res::new(res[d].log2_u(), res[d].log2_v()));
        meta.extend(mesh_meta(surface));
        let img = PtexImage {
            faces: &infos,
            channels: names.len(),
            alpha: names.iter().position(|&c| c == "A"),
            meta,
        };
        return write_ptex(path, &img, opts, |f, buf| {
            let r = maps.layout.range(f);
            let nn = r.len();
            for (k, (_, data)) in maps.channels.iter().enumerate() {
                buf[k * nn..(k + 1) * nn].copy_from_slice(&data[r.clone()]);
            }
        });
    };
    let r = n.next_power_of_two();
    let log2 = r.trailing_zeros() as u8;
    let infos = face_infos(surface, |_| Res::square(log2));
    meta.push((
        META_RESOLUTION.to_string(),
        MetaValue::Int32(vec![n as i32]),
    ));
    meta.extend(mesh_meta(surface));
    let img = PtexImage {
        faces: &infos,
        channels: names.len(),
        alpha: names.iter().position(|&c| c == "A"),
        meta,
    };
    let nn = n * n;
    if r == n {
        write_ptex(path, &img, opts, |f, buf| {
            for (k, (_, data)) in maps.channels.iter().enumerate() {
                buf[k * nn..(k + 1) * nn].copy_from_slice(&data[f * nn..(f + 1) * nn]);
            }
        })
    } else {
        // Resample with the cross-face bilinear fetch, so faces still meet continuously.
        let c = names.len();
        let mut inter = vec![0f32; maps.faces() * nn * c];
        for (k, (_, data)) in maps.channels.iter().enumerate() {
            for (i, v) in data.iter().enumerate() {
                inter[i * c + k] = *v;
            }
        }
        let layout = Arc::new(crate::maps::MapLayout::new(surface, n));
        let tex = crate::maps::FaceMaps::from_data(layout, c, inter);
        let rr = r * r;
        write_ptex(path, &img, opts, |f, buf| {
            let mut px = vec![0f32; c];
            for y in 0..r {
                for x in 0..r {
                    let loc = DomainLocation {
                        domain: DomainId::from_idx(f),
                        u: (x as f64 + 0.5) / r as f64,
                        v: (y as f64 + 0.5) / r as f64,
                    };
                    tex.sample(loc, &mut px);
                    for k in 0..c {
                        buf[k * rr + y * r + x] = px[k];
                    }
                }
            }
        })
    }
}
