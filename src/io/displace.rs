//! Shape synthesis (paper 000 §6, Figs. 5–6): the synthesized height channel as a
//! displacement of the limit surface, written as `displaced.glb` (binary glTF with the
//! material of `surface.glb`; OBJ text was 136 MB for Spot at N = 32, the GLB is a third of
//! that), optionally decimated where the displaced surface is flat ([`crate::io::decimate`]).
//!
//! The limit surface is tessellated at texel resolution — at least N segments per domain
//! side: `2^level` for a quad domain, `2^(level-1)` for an n-gon sub-face — and every
//! vertex moves along its unit limit normal by
//! `amount · (height − 0.5)`, height being the face maps' `height` channel fetched
//! bilinearly at the vertex (across face edges through [`crate::maps::MapLayout`]'s ring).
//! Mid-grey is the undisplaced surface, so a height map's neutral level stays put.
//!
//! The tessellation is the limit mesh ([`subdiv::Surface::limit_mesh`]), which has one
//! vertex per surface point: a vertex on a shared edge is computed once, from one location,
//! so displaced edges cannot crack. Texture coordinates and the material are those of
//! `surface.obj` (same atlas layout), so the displaced mesh renders with `atlas.png`.
//! [`SurfaceMesh::write_obj`] still writes the mesh as OBJ for callers that want text.
//! Normals are recomputed from the displaced quads (area-weighted), since displacement
//! changes them.

use crate::error::{Error, Result};
use crate::io::atlas::{
    tessellate_limit_mesh, uv_grids, AtlasLayout, SurfaceMesh, DEFAULT_GUTTER, MATERIAL,
};
use crate::io::atomic::AtomicFile;
use crate::io::exr::FaceMaps;
use crate::io::gltf::{write_glb_uncommitted, Material, TriMesh};
use crate::io::materials::MaterialImages;
use crate::maps::{self, MapLayout};
use rayon::prelude::*;
use std::path::Path;
use std::sync::Arc;
use subdiv::Surface;

/// File name of the displaced mesh.
pub const DISPLACED_GLB: &str = "displaced.glb";

/// Refinement level whose tessellation has at least `n` segments per side on every domain
/// (capped at 10: a quad domain then has 1024 segments per side).
pub fn level_for_texels(surface: &Surface, n: usize) -> u32 {
    let has_subfaces = (0..surface.num_domains()).any(|d| {
        matches!(
            surface.domain(subdiv::DomainId::from_idx(d)),
            subdiv::Domain::SubFace { .. }
        )
    });
    let mut level = 1u32;
    loop {
        let segments = if has_subfaces {
            1usize << (level - 1)
        } else {
            1usize << level
        };
        if segments >= n || level >= 10 {
            return level;
        }
        level += 1;
    }
}

/// The displaced tessellation of `surface` for the `height` channel of `facemaps`.
pub fn displaced_mesh(surface: &Surface, facemaps: &FaceMaps, amount: f64) -> Result<SurfaceMesh> {
    let height = facemaps
        .channel("height")
        .ok_or_else(|| Error::invalid("--displace needs a height channel: pass --height H.png"))?;
    if !amount.is_finite() {
        return Err(Error::invalid(format!(
            "displacement amount {amount} is not a finite number"
        )));
    }
    let n = facemaps.layout.largest_side();
    let layout = Arc::new(MapLayout::with_layout(surface, facemaps.layout.clone()));
    let hmap = maps::FaceMaps::from_data(layout, 1, height.to_vec());
    let level = level_for_texels(surface, n);
    let atlas = AtlasLayout::of(facemaps.layout.clone(), DEFAULT_GUTTER);
    // One limit mesh: the tessellation's vertices, and where each of them is.
    let lm = surface.limit_mesh(level);
    let mut mesh = tessellate_limit_mesh(surface, &atlas, &lm);
    mesh.positions
        .par_iter_mut()
        .enumerate()
        .for_each(|(i, p)| {
            let b = lm.vertex_location[i];
            let loc = surface.base_to_domain(b.quad, b.s, b.t);
            let mut h = [0.0f32];
            hmap.sample(loc, &mut h);
            let off = amount * (h[0] as f64 - 0.5);
            let nrm = lm.normal[i];
            let q = lm.position[i] + nrm * off;
            *p = q.to_array();
        });
    // Area-weighted normals of the displaced quads (cross product of the diagonals).
    let mut normals = vec![glam::DVec3::ZERO; mesh.positions.len()];
    for q in &mesh.quads {
        let p = |k: usize| glam::DVec3::from_array(mesh.positions[q[k].0 as usize]);
        let nq = (p(2) - p(0)).cross(p(3) - p(1));
        for &(v, _) in q {
            normals[v as usize] += nq;
        }
    }
    for (o, (nv, orig)) in mesh.normals.iter_mut().zip(normals.iter().zip(&lm.normal)) {
        let n = if nv.length_squared() > 0.0 {
            nv.normalize()
        } else {
            *orig
        };
        *o = n.to_array();
    }
    Ok(mesh)
}

/// The displaced tessellation as a glTF mesh: one vertex per texture coordinate, or, with
/// `decimate = Some(tol)`, only the vertices [`crate::io::decimate`] keeps where the surface
/// is flat within `tol` (mesh units). Tangents when `tangents` (a normal map needs them).
pub fn displaced_trimesh(
    surface: &Surface,
    facemaps: &FaceMaps,
    amount: f64,
    decimate: Option<f64>,
    tangents: bool,
) -> Result<TriMesh> {
    if let Some(t) = decimate {
        if !(t.is_finite() && t >= 0.0) {
            return Err(Error::invalid(format!(
                "decimation tolerance {t} is not a non-negative length"
            )));
        }
    }
    let mesh = displaced_mesh(surface, facemaps, amount)?;
    let mut tri = TriMesh::from(&mesh);
    if let Some(tol) = decimate {
        let grids = uv_grids(surface, mesh.level);
        let mut vertex_of = vec![0u32; mesh.uvs.len()];
        for q in &mesh.quads {
            for &(v, t) in q {
                vertex_of[t as usize] = v;
            }
        }
        let d = crate::io::decimate::decimate(
            &grids,
            |g| glam::DVec3::from_array(mesh.positions[vertex_of[g as usize] as usize]),
            |g| vertex_of[g as usize],
            mesh.positions.len(),
            tol,
        );
        tri = TriMesh {
            positions: d
                .vertices
                .iter()
                .map(|&g| tri.positions[g as usize])
                .collect(),
            normals: d
                .vertices
                .iter()
                .map(|&g| tri.normals[g as usize])
                .collect(),
            tangents: Vec::new(),
            uvs: d.vertices.iter().map(|&g| tri.uvs[g as usize]).collect(),
            triangles: d.triangles,
        };
    }
    if tangents {
        tri.tangents = crate::io::gltf::tangents(&tri);
    }
    Ok(tri)
}

/// Writes `dir/displaced.glb` with the material `images` (those of `surface.glb`), not yet
/// published: the caller commits it with the other outputs.
pub fn write_displaced(
    dir: impl AsRef<Path>,
    surface: &Surface,
    facemaps: &FaceMaps,
    amount: f64,
    decimate: Option<f64>,
    images: &MaterialImages,
) -> Result<AtomicFile> {
    let tri = displaced_trimesh(surface, facemaps, amount, decimate, images.normal.is_some())?;
    let path = dir.as_ref().join(DISPLACED_GLB);
    let material = Material {
        name: MATERIAL,
        base_colour: &images.base_colour,
        alpha: images.alpha,
        normal: images.normal.as_deref(),
        orm: images.orm.as_ref().map(|(p, o)| (p.as_slice(), *o)),
    };
    write_glb_uncommitted(&path, &tri, &material)
}
