//! Tangent frames of the textured outputs: a tangent-space normal map re-expressed in the
//! frame renderers rebuild from `surface.obj`'s texture coordinates.
//!
//! facemaps.exr keeps the normal map in the orientation field's frame (T, N × T, N) — the
//! frame synthesis lays the example along, continuous over the surface. A renderer knows
//! nothing of the field: it derives tangents from the mesh's UVs (MikkTSpace and the like:
//! per triangle, T = ∂P/∂s and B = ∂P/∂t from the UV derivatives, made orthonormal to the
//! interpolated vertex normal). On every atlas tile that frame is the domain's (u, −v)
//! directions, which turn against the field's from tile to tile. So `atlas_normal.png`
//! (and surface.glb's normal texture) hold the same world-space normals as facemaps.exr,
//! written in each pixel's *renderer* frame: [`UvFrames`] is exactly the per-triangle
//! frame of the tessellation written to surface.obj (the same triangles, (0, 1, 2) and
//! (0, 2, 3) of every quad, as OBJ readers and our glTF split them), so decoding with it
//! gives back the world normal up to quantisation.
//!
//! Gutter pixels are filled from the neighbouring domain in world space (continuous across
//! the edge) and expressed in the frame of the tile's nearest border point, the frame a
//! renderer filtering into the gutter from inside the tile uses.

use crate::error::Result;
use crate::io::atlas::{build_atlas_of, uv_grids, Atlas, AtlasLayout, SurfaceMesh};
use crate::io::exr::FaceMaps;
use glam::{DVec3, Vec3};
use rayon::prelude::*;
use subdiv::Surface;

/// The field's frame per texel (global texel order): unit v1 and the unit limit normal.
#[derive(Clone, Copy, Debug)]
pub struct FieldFrames<'a> {
    pub tangent: &'a [[f32; 3]],
    pub normal: &'a [Vec3],
}

/// The tangent frame a renderer derives from a tessellation's UVs: MikkTSpace's — per
/// triangle ∂P/∂s and ∂P/∂t, summed at each vertex (per tile: vertices on a domain edge
/// have one UV per tile), made orthogonal to the vertex normal, interpolated over the
/// triangle, bitangent ±N × T. These are exactly the TANGENT vectors surface.glb carries
/// ([`crate::io::gltf::tangents`]). Interpolated frames are continuous inside a tile,
/// where frames of single triangles jump at every diagonal: a texel centre on a diagonal
/// (half of them, on a grid of segments that are whole texels) would have two frames.
pub struct UvFrames<'a> {
    mesh: &'a SurfaceMesh,
    /// Per texture coordinate of `mesh`: unit tangent and handedness w (glTF's layout).
    tangents: Vec<[f32; 4]>,
    layout: AtlasLayout,
    /// Per domain: first UV index and segments per side.
    grids: Vec<crate::io::decimate::DomainGrid>,
    /// Per domain, the quad covering each grid cell (row-major, `m²` cells), from `start`.
    cells: Vec<u32>,
    start: Vec<usize>,
}

impl<'a> UvFrames<'a> {
    /// The frames of `mesh` (a [`crate::io::atlas::tessellate`] of `surface` into `layout`).
    pub fn new(surface: &Surface, mesh: &'a SurfaceMesh, layout: AtlasLayout) -> Self {
        let grids = uv_grids(surface, mesh.level);
        let mut start = Vec::with_capacity(grids.len() + 1);
        let mut total = 0usize;
        for g in &grids {
            start.push(total);
            total += (g.m * g.m) as usize;
        }
        start.push(total);
        let mut cells = vec![u32::MAX; total];
        for (q, quad) in mesh.quads.iter().enumerate() {
            let d = mesh.quad_domain[q] as usize;
            let g = grids[d];
            let (mut i, mut j) = (u32::MAX, u32::MAX);
            for &(_, t) in quad {
                let local = t - g.first;
                i = i.min(local % (g.m + 1));
                j = j.min(local / (g.m + 1));
            }
            cells[start[d] + (j * g.m + i) as usize] = q as u32;
        }
        let tri = crate::io::gltf::TriMesh::from(mesh);
        let tangents = crate::io::gltf::tangents(&tri);
        Self {
            mesh,
            tangents,
            layout,
            grids,
            cells,
            start,
        }
    }

    /// The renderer's orthonormal frame (T, B, N) at domain point (u, v) of domain `d`
    /// (clamped to the domain): in the triangle of surface.obj holding that UV, the vertex
    /// tangents and normals interpolated.
    pub fn frame(&self, d: usize, u: f64, v: f64) -> [DVec3; 3] {
        let (u, v) = (u.clamp(0.0, 1.0), v.clamp(0.0, 1.0));
        let g = self.grids[d];
        let m = g.m as f64;
        let i = ((u * m).floor() as u32).min(g.m - 1);
        let j = ((v * m).floor() as u32).min(g.m - 1);
        let q = self.cells[self.start[d] + (j * g.m + i) as usize] as usize;
        let quad = &self.mesh.quads[q];
        let (s, t) = self.layout.obj_uv(d, u, v);
        let corner = |k: usize| {
            let (pv, tv) = quad[k];
            let t = self.tangents[tv as usize];
            (
                DVec3::new(t[0] as f64, t[1] as f64, t[2] as f64),
                DVec3::from_array(self.mesh.normals[pv as usize]),
                self.mesh.uvs[tv as usize],
            )
        };
        let tri = |a: usize, b: usize, c: usize| [corner(a), corner(b), corner(c)];
        let bary = |tr: &[(DVec3, DVec3, [f64; 2]); 3]| {
            let (a, b, c) = (tr[0].2, tr[1].2, tr[2].2);
            let det = (b[0] - a[0]) * (c[1] - a[1]) - (c[0] - a[0]) * (b[1] - a[1]);
            let l1 = ((s - a[0]) * (c[1] - a[1]) - (c[0] - a[0]) * (t - a[1])) / det;
            let l2 = ((b[0] - a[0]) * (t - a[1]) - (s - a[0]) * (b[1] - a[1])) / det;
            [1.0 - l1 - l2, l1, l2]
        };
        let first = tri(0, 1, 2);
        let second = tri(0, 2, 3);
        let (b1, b2) = (bary(&first), bary(&second));
        let min = |b: [f64; 3]| b[0].min(b[1]).min(b[2]);
        let (tr, b) = if min(b1) >= min(b2) {
            (first, b1)
        } else {
            (second, b2)
        };
        let b = b.map(|x| x.max(0.0));
        let n = (tr[0].1 * b[0] + tr[1].1 * b[1] + tr[2].1 * b[2])
            .try_normalize()
            .unwrap_or(tr[0].1);
        // The handedness w is one per tile (a tile's UVs are never mirrored within it).
        let w = self.tangents[quad[0].1 as usize][3] as f64;
        let t = tr[0].0 * b[0] + tr[1].0 * b[1] + tr[2].0 * b[2];
        let t = (t - n * n.dot(t))
            .try_normalize()
            .unwrap_or_else(|| n.any_orthonormal_vector());
        [t, n.cross(t) * w, n]
    }
}

/// World-space normal of a tangent-space value `c` (0..1 per component, as stored) in the
/// frame (t, b, n).
pub fn decode(c: [f32; 3], t: DVec3, b: DVec3, n: DVec3) -> DVec3 {
    let x = 2.0 * c[0] as f64 - 1.0;
    let y = 2.0 * c[1] as f64 - 1.0;
    let z = 2.0 * c[2] as f64 - 1.0;
    t * x + b * y + n * z
}

/// The normal map of `maps` (`normal.R normal.G normal.B`, in the field's frame) as an
/// atlas in the frames of `uv` (values 0..1 as stored in an image); `None` without a
/// normal map.
pub fn normal_atlas(
    surface: &Surface,
    maps: &FaceMaps,
    field: FieldFrames<'_>,
    uv: &UvFrames<'_>,
    gutter: usize,
) -> Result<Option<Atlas>> {
    let (Some(r), Some(g), Some(b)) = (
        maps.channel("normal.R"),
        maps.channel("normal.G"),
        maps.channel("normal.B"),
    ) else {
        return Ok(None);
    };
    let len = r.len();
    if field.tangent.len() != len || field.normal.len() != len {
        return Err(crate::Error::invalid(format!(
            "tangent frames for {} texels, but the face maps have {len}",
            field.tangent.len().min(field.normal.len())
        )));
    }
    // World space first: continuous across domain edges, so the gutters fetch it
    // unchanged from the neighbouring tile.
    let world: Vec<[f32; 3]> = (0..len)
        .into_par_iter()
        .map(|i| {
            let n = field.normal[i].as_dvec3();
            let t = DVec3::from_array(field.tangent[i].map(f64::from));
            let w = decode([r[i], g[i], b[i]], t, n.cross(t), n);
            w.normalize_or(n).as_vec3().to_array()
        })
        .collect();
    let split: [Vec<f32>; 3] = std::array::from_fn(|c| world.iter().map(|w| w[c]).collect());
    let chans: Vec<&[f32]> = split.iter().map(|v| v.as_slice()).collect();
    let mut atlas = build_atlas_of(surface, &chans, maps, gutter)?;
    let layout = &atlas.layout;
    let (w, h) = (layout.width(), layout.height());
    // The domain of every atlas pixel (tiles of any size, shelf-packed for per-face
    // resolutions); pixels outside every tile stay the flat normal.
    let mut owner = vec![u32::MAX; w * h];
    for d in 0..layout.faces() {
        let (x0, y0) = layout.interior_origin(d);
        let (tw, th) = layout.tile(d);
        let (x0, y0) = (x0 - gutter, y0 - gutter);
        for y in y0..y0 + th {
            owner[y * w + x0..y * w + x0 + tw].fill(d as u32);
        }
    }
    let texels = layout.texels.clone();
    let origins: Vec<(usize, usize)> = (0..layout.faces())
        .map(|d| layout.interior_origin(d))
        .collect();
    atlas
        .pixels
        .par_chunks_mut(3 * w)
        .zip(owner.par_chunks(w))
        .enumerate()
        .for_each(|(py, (row, own))| {
            for (px, out) in row.chunks_exact_mut(3).enumerate() {
                let d = own[px];
                if d == u32::MAX {
                    out.copy_from_slice(&[0.5, 0.5, 1.0]);
                    continue;
                }
                let d = d as usize;
                let (x0, y0) = origins[d];
                let (nu, nv) = texels.dims(d);
                let tx = px as f64 - x0 as f64 + 0.5;
                let ty = py as f64 - y0 as f64 + 0.5;
                let [t, bt, nn] = uv.frame(d, tx / nu as f64, ty / nv as f64);
                let wv = DVec3::new(out[0] as f64, out[1] as f64, out[2] as f64).normalize_or(nn);
                let c = [wv.dot(t), wv.dot(bt), wv.dot(nn)];
                for (o, c) in out.iter_mut().zip(c) {
                    *o = (0.5 * (c + 1.0)).clamp(0.0, 1.0) as f32;
                }
            }
        });
    Ok(Some(atlas))
}
