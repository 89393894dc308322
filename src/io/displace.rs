//! Shape synthesis (paper 000 §6, Figs. 5–6): the synthesized height channel as a
//! displacement of the limit surface, written as `displaced.obj`.
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
//! Normals are recomputed from the displaced quads (area-weighted), since displacement
//! changes them.

use crate::error::{Error, Result};
use crate::io::atlas::{tessellate_limit_mesh, AtlasLayout, SurfaceMesh, DEFAULT_GUTTER, MTL_NAME};
use crate::io::atomic::AtomicFile;
use crate::io::exr::FaceMaps;
use crate::maps::{self, MapLayout};
use rayon::prelude::*;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use subdiv::Surface;

/// File name of the displaced mesh.
pub const DISPLACED_OBJ: &str = "displaced.obj";

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
    let n = facemaps.resolution;
    let layout = Arc::new(MapLayout::new(surface, n));
    let hmap = maps::FaceMaps::from_data(layout, 1, height.to_vec());
    let level = level_for_texels(surface, n);
    let atlas = AtlasLayout::new(facemaps.faces, n, DEFAULT_GUTTER);
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

/// Writes `dir/displaced.obj` (atomically); returns its path.
pub fn write_displaced(
    dir: impl AsRef<Path>,
    surface: &Surface,
    facemaps: &FaceMaps,
    amount: f64,
) -> Result<PathBuf> {
    let mesh = displaced_mesh(surface, facemaps, amount)?;
    let path = dir.as_ref().join(DISPLACED_OBJ);
    let mut f = AtomicFile::create(&path)?;
    mesh.write_obj(f.writer(), MTL_NAME)
        .map_err(|e| Error::io(&path, "cannot write", e))?;
    f.commit()?;
    Ok(path)
}
