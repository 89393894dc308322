//! Renderer-ready export: `surface.obj` + `surface.mtl` + `atlas.png` (BRIEF, "Output
//! directory of `synth`"; layout and gutters are described in docs/outputs.md).
//!
//! Per-face maps are the natural result of synthesis on a subdivision surface, but no DCC
//! tool reads Ptex-style EXR tiles with our conventions. So we also write the limit surface
//! as an ordinary polygon mesh whose UVs point into one packed image:
//!
//! - **Atlas**: one tile of (N+2g)×(N+2g) pixels per face domain, in the same column/row
//!   order as `facemaps.exr` (C = ceil(sqrt(F)) columns). The N×N interior is the domain's
//!   map; the g-pixel *gutter* around it holds the colours that lie just across the domain's
//!   edges on the surface, found by walking the gutter texel's centre across the edge in
//!   parameter space ([`subdiv::Surface::walk`]) and fetching the neighbouring domain's map
//!   there bilinearly. A renderer filtering bilinearly near a tile's border therefore blends
//!   the same colours the neighbouring tile shows on the other side of the edge: no seams.
//!   Where the walk leaves the surface (open boundary) the gutter repeats the border texel.
//! - **Mesh**: the exact limit surface refined `level` times ([`subdiv::Surface::limit_mesh`]),
//!   one shared vertex per surface point, so positions along shared edges are not merely
//!   close but the same vertex: no cracks by construction. Texture coordinates are per
//!   domain (a point on an edge has one UV in each tile), and they map the domain's unit
//!   square onto the tile *interior*, so the UV (u, v) lands on the texel grid exactly where
//!   the per-face map has it: texel centre ((x+0.5)/N, (y+0.5)/N) is atlas pixel centre
//!   (g+x+0.5, g+y+0.5) inside the tile.
//!
//! Colours are linear in the maps and sRGB-encoded (8 bit) in the PNG, as image viewers and
//! DCC tools expect for colour textures; alpha is stored straight (not premultiplied) and
//! linearly. All three files go through [`crate::io::atomic`] and are published only after
//! all three were written, so an error leaves none of them behind.

use crate::error::{Error, Result};
use crate::io::exr::FaceMaps;
use crate::layout::TexelLayout;
use rayon::prelude::*;
use std::io::Write;
use std::sync::Arc;
use subdiv::{BaseQuadId, DomainId, DomainLocation, FaceId, LimitMesh, Surface, VertexId};

/// Default gutter width in pixels. Bilinear filtering needs one; two keep the first
/// mip level (where a renderer averages 2×2 pixels) free of bleeding from other tiles.
pub const DEFAULT_GUTTER: usize = 2;

/// Names of the files [`crate::io::export::export`] writes.
pub const OBJ_NAME: &str = "surface.obj";
/// See [`OBJ_NAME`].
pub const MTL_NAME: &str = "surface.mtl";
/// See [`OBJ_NAME`].
pub const ATLAS_NAME: &str = "atlas.png";
/// The glTF binary of the same surface and material ([`crate::io::gltf`]).
pub const GLB_NAME: &str = "surface.glb";
/// Material name used in the MTL file.
pub const MATERIAL: &str = "surfsynth";

/// Where the tiles of F domains sit in the atlas: one tile of (nu + 2g) x (nv + 2g) pixels
/// per domain. With one resolution N the tiles form the grid of `facemaps.exr` (C =
/// ceil(sqrt(F)) columns, domain f at column f mod C, row f div C). With per-face
/// resolutions (`--texel-size`) the tiles are packed in shelves: domains sorted by tile
/// height (tallest first, then by index), placed left to right in rows as wide as the
/// square root of the total tile area (at least the widest tile), each row as tall as its
/// first tile — simple, deterministic, and within ~10% of the tiles' own area on the
/// measured meshes (docs/outputs.md).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct AtlasLayout {
    /// Per-domain resolutions.
    pub texels: Arc<TexelLayout>,
    /// Gutter width g in pixels on each side of a tile.
    pub gutter: usize,
    /// Top-left pixel of every domain's tile (gutter included).
    origin: Vec<(usize, usize)>,
    width: usize,
    height: usize,
}

impl AtlasLayout {
    /// Layout for `faces` domains of `resolution`² texels with `gutter` pixels around each.
    pub fn new(faces: usize, resolution: usize, gutter: usize) -> Self {
        Self::of(
            Arc::new(TexelLayout::uniform(faces, resolution.max(1))),
            gutter,
        )
    }

    /// Layout for the domains of `texels` with `gutter` pixels around each.
    pub fn of(texels: Arc<TexelLayout>, gutter: usize) -> Self {
        let faces = texels.faces();
        let tile = |d: usize| {
            let (u, v) = texels.dims(d);
            (u + 2 * gutter, v + 2 * gutter)
        };
        if let Some(n) = texels.uniform_n() {
            let t = crate::io::exr::TileLayout::new(faces, n);
            let side = n + 2 * gutter;
            return Self {
                origin: (0..faces)
                    .map(|f| ((f % t.columns) * side, (f / t.columns) * side))
                    .collect(),
                width: t.columns * side,
                height: t.rows * side,
                texels,
                gutter,
            };
        }
        let area: usize = (0..faces).map(|d| tile(d).0 * tile(d).1).sum();
        let widest = (0..faces).map(|d| tile(d).0).max().unwrap_or(1);
        let width = ((area as f64).sqrt().ceil() as usize).max(widest);
        let mut order: Vec<usize> = (0..faces).collect();
        order.sort_by_key(|&d| (std::cmp::Reverse(tile(d).1), d));
        let mut origin = vec![(0, 0); faces];
        let (mut x, mut y, mut row_h, mut used_w) = (0usize, 0usize, 0usize, 0usize);
        for d in order {
            let (tw, th) = tile(d);
            if x + tw > width {
                y += row_h;
                x = 0;
                row_h = 0;
            }
            origin[d] = (x, y);
            x += tw;
            used_w = used_w.max(x);
            row_h = row_h.max(th);
        }
        Self {
            texels,
            gutter,
            origin,
            width: used_w.max(1),
            height: (y + row_h).max(1),
        }
    }

    /// Number of face domains F.
    pub fn faces(&self) -> usize {
        self.texels.faces()
    }

    /// Tile size (nu + 2g, nv + 2g) of domain `f`.
    pub fn tile(&self, f: usize) -> (usize, usize) {
        let (u, v) = self.texels.dims(f);
        (u + 2 * self.gutter, v + 2 * self.gutter)
    }

    /// Atlas width in pixels.
    pub fn width(&self) -> usize {
        self.width
    }

    /// Atlas height in pixels.
    pub fn height(&self) -> usize {
        self.height
    }

    /// Pixel position of domain `f`'s texel (0, 0) (the top-left of its tile interior).
    pub fn interior_origin(&self, f: usize) -> (usize, usize) {
        let (x, y) = self.origin[f];
        (x + self.gutter, y + self.gutter)
    }

    /// The domain whose tile holds atlas pixel (x, y), if any (a linear search: for tests
    /// and tools).
    pub fn domain_at(&self, x: usize, y: usize) -> Option<usize> {
        (0..self.faces()).find(|&f| {
            let (x0, y0) = self.origin[f];
            let (tw, th) = self.tile(f);
            (x0..x0 + tw).contains(&x) && (y0..y0 + th).contains(&y)
        })
    }

    /// Continuous atlas pixel coordinates (x right, y down, pixel centres at +0.5) of
    /// domain point (u, v).
    pub fn pixel(&self, f: usize, u: f64, v: f64) -> (f64, f64) {
        let (x0, y0) = self.interior_origin(f);
        let (nu, nv) = self.texels.dims(f);
        (x0 as f64 + u * nu as f64, y0 as f64 + v * nv as f64)
    }

    /// OBJ texture coordinates (origin at the image's bottom-left) of domain point (u, v).
    pub fn obj_uv(&self, f: usize, u: f64, v: f64) -> (f64, f64) {
        let (x, y) = self.pixel(f, u, v);
        (x / self.width() as f64, 1.0 - y / self.height() as f64)
    }
}

/// The atlas in linear colour, before encoding.
#[derive(Clone, Debug, PartialEq)]
pub struct Atlas {
    pub layout: AtlasLayout,
    /// 3 (RGB) or 4 (RGBA).
    pub channels: usize,
    /// Row-major, interleaved, linear values (alpha straight).
    pub pixels: Vec<f32>,
}

/// The colour channels of `maps` (R, G, B and A if present), checked for presence.
fn colour_channels(maps: &FaceMaps) -> Result<Vec<&[f32]>> {
    let mut out = Vec::with_capacity(4);
    for name in ["R", "G", "B"] {
        out.push(maps.channel(name).ok_or_else(|| {
            Error::invalid(format!(
                "face maps have no '{name}' channel; an atlas needs colour"
            ))
        })?);
    }
    if let Some(a) = maps.channel("A") {
        out.push(a);
    }
    Ok(out)
}

/// Bilinear lookup of every channel of domain `d` at domain point (u, v), clamping to the
/// domain's own border texels (the caller has already walked into the right domain).
fn fetch_in_domain(chans: &[&[f32]], l: &TexelLayout, d: usize, u: f64, v: f64, out: &mut [f32]) {
    let (nu, nv) = l.dims(d);
    let (fu, fv) = (nu as f64, nv as f64);
    let px = (u * fu - 0.5).clamp(0.0, fu - 1.0);
    let py = (v * fv - 0.5).clamp(0.0, fv - 1.0);
    let x0 = (px.floor() as usize).min(nu - 1);
    let y0 = (py.floor() as usize).min(nv - 1);
    let x1 = (x0 + 1).min(nu - 1);
    let y1 = (y0 + 1).min(nv - 1);
    let fx = (px - x0 as f64) as f32;
    let fy = (py - y0 as f64) as f32;
    let base = l.start(d);
    for (c, ch) in chans.iter().enumerate() {
        let t = |x: usize, y: usize| ch[base + y * nu + x];
        let top = t(x0, y0) + (t(x1, y0) - t(x0, y0)) * fx;
        let bot = t(x0, y1) + (t(x1, y1) - t(x0, y1)) * fx;
        out[c] = top + (bot - top) * fy;
    }
}

/// Where the gutter texel at tile-interior position (x, y) (outside 0..N on at least one
/// axis, for a domain of nu x nv texels) lies on the surface: the domain point reached by
/// walking from the nearest texel centre of domain `d` by the texel offset (in `d`'s own
/// texels: a neighbour of another resolution is sampled wherever the walk lands). When the straight walk leaves the surface
/// (open boundary), the offset is tried one axis at a time, which amounts to clamping
/// along the boundary; when that fails too, the nearest texel of `d` itself is used.
pub fn gutter_location(
    surface: &Surface,
    (nu, nv): (usize, usize),
    d: usize,
    x: isize,
    y: isize,
) -> DomainLocation {
    let (xc, yc) = (x.clamp(0, nu as isize - 1), y.clamp(0, nv as isize - 1));
    let (fu, fv) = (nu as f64, nv as f64);
    let start = DomainLocation {
        domain: DomainId::from_idx(d),
        u: (xc as f64 + 0.5) / fu,
        v: (yc as f64 + 0.5) / fv,
    };
    let du = (x - xc) as f64 / fu;
    let dv = (y - yc) as f64 / fv;
    surface
        .walk(start, du, dv)
        .or_else(|| {
            if du != 0.0 && dv != 0.0 {
                surface
                    .walk(start, du, 0.0)
                    .or_else(|| surface.walk(start, 0.0, dv))
            } else {
                None
            }
        })
        .unwrap_or(start)
}

/// Domain corners in (u, v), in quad corner order.
const CORNERS: [(f64, f64); 4] = [(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0)];

/// All domain corners at the surface vertex at corner `corner` of domain `d`, as (domain,
/// u, v) with u, v in {0, 1}, one per face around the vertex (the whole fan at an open
/// boundary), sorted so that every domain of the ring sees the same list. `None` when the
/// vertex is not a corner of every domain around it (the middle of a quad domain's edge at a
/// T-junction with n-gon sub-faces).
fn corner_ring(surface: &Surface, d: usize, corner: usize) -> Option<Vec<(usize, f64, f64)>> {
    let (u, v) = CORNERS[corner];
    let b = surface.base_location(DomainLocation {
        domain: DomainId::from_idx(d),
        u,
        v,
    });
    let c = CORNERS.iter().position(|&st| st == (b.s, b.t))?;
    let base = &surface.base;
    let vert = VertexId(base.face_vertices(FaceId(b.quad.0))[c]);
    let mut ring = Vec::new();
    for h in base.outgoing(vert) {
        let q = base.face_of(h);
        let (s, t) = CORNERS[(h - base.face_he(q)) as usize];
        let loc = surface.base_to_domain(BaseQuadId(q.0), s, t);
        let corner = |w: f64| w == 0.0 || w == 1.0;
        if !corner(loc.u) || !corner(loc.v) {
            return None;
        }
        ring.push((loc.domain.idx(), loc.u, loc.v));
    }
    ring.sort_by(|a, b| a.partial_cmp(b).expect("corner coordinates are 0 or 1"));
    Some(ring)
}

/// Tile-interior coordinates of the corner texel of corner (u, v) (u, v in {0, 1}) and of
/// the gutter texels beside it along x, along y and diagonally.
fn corner_texels((nu, nv): (usize, usize), u: f64, v: f64) -> [(isize, isize); 4] {
    let (x, sx) = if u == 0.0 {
        (0, -1)
    } else {
        (nu as isize - 1, 1)
    };
    let (y, sy) = if v == 0.0 {
        (0, -1)
    } else {
        (nv as isize - 1, 1)
    };
    [(x, y), (x + sx, y), (x, y + sy), (x + sx, y + sy)]
}

/// Makes every tile around a vertex agree on the vertex's colour.
///
/// Bilinear filtering exactly at a domain corner averages four pixels: the corner texel C,
/// the two edge-gutter texels beside it (G1, G2: the neighbours' texels across the two
/// edges, or C again across an open boundary) and the diagonal gutter texel X. With k
/// domains around the vertex there is a true diagonal only when k = 4; otherwise whatever
/// the walk picks differs from tile to tile and the vertex colour would jump. X is the one
/// free value, so we choose one target T for the whole ring and set X = 4T - (C + G1 + G2)
/// in every tile: all tiles then filter to T at the vertex. T is the mean M of the k corner
/// texels (for k = 4 that reproduces the true diagonal; for k = 3, X = M), moved as little
/// as needed so that every tile's X stays inside [0, 1] (widened to the ring's own range for
/// values outside it): a stored 8-bit texel cannot leave that range, and an overshooting
/// extrapolation would have to be clamped per tile, breaking the agreement. Only if no
/// such T exists (extreme contrast at a high-valence vertex) is X clamped. X only ever gets
/// bilinear weight within half a texel of the vertex.
#[allow(clippy::too_many_arguments)]
fn fix_corner_gutter(
    surface: &Surface,
    chans: &[&[f32]],
    l: &TexelLayout,
    gutter: usize,
    d: usize,
    corner: usize,
    tile: &mut [f32],
) {
    let Some(ring) = corner_ring(surface, d, corner) else {
        return;
    };
    let k = chans.len();
    let t = l.dims(d).0 + 2 * gutter;
    // Per ring member: its corner texel and C + G1 + G2, computed by the same walks and
    // fetches that filled the gutters, so each tile's own sum is bit-identical to its pixels.
    let mut corner_vals = vec![0f32; ring.len() * k];
    let mut sums = vec![0f32; ring.len() * k];
    let mut tmp = [0f32; 4];
    for (r, &(dr, u, v)) in ring.iter().enumerate() {
        let [c, g1, g2, _] = corner_texels(l.dims(dr), u, v);
        let i = l.index(dr, c.0 as usize, c.1 as usize);
        for (ch, data) in chans.iter().enumerate() {
            corner_vals[r * k + ch] = data[i];
            sums[r * k + ch] = data[i];
        }
        for g in [g1, g2] {
            let loc = gutter_location(surface, l.dims(dr), dr, g.0, g.1);
            fetch_in_domain(chans, l, loc.domain.idx(), loc.u, loc.v, &mut tmp[..k]);
            for ch in 0..k {
                sums[r * k + ch] += tmp[ch];
            }
        }
    }
    let me = ring
        .iter()
        .position(|&(dr, u, v)| dr == d && (u, v) == CORNERS[corner])
        .expect("a domain is in the ring of its own corner");
    let [_, _, _, x] = corner_texels(l.dims(d), CORNERS[corner].0, CORNERS[corner].1);
    let px = ((x.1 + gutter as isize) as usize * t + (x.0 + gutter as isize) as usize) * k;
    for ch in 0..k {
        let vals = (0..ring.len()).map(|r| corner_vals[r * k + ch]);
        let m = vals.clone().sum::<f32>() / ring.len() as f32;
        let lo = vals.clone().fold(0.0, f32::min);
        let hi = vals.fold(1.0, f32::max);
        let s = (0..ring.len()).map(|r| sums[r * k + ch]);
        let t_lo = s.clone().fold(f32::NEG_INFINITY, f32::max) + lo;
        let t_hi = s.fold(f32::INFINITY, f32::min) + hi;
        let target = if t_lo <= t_hi {
            m.clamp(t_lo / 4.0, t_hi / 4.0)
        } else {
            m
        };
        let val = 4.0 * target - sums[me * k + ch];
        tile[px + ch] = if val.is_finite() {
            val.clamp(lo, hi)
        } else {
            m
        };
    }
}
/// The checks every writer of the atlas and its mesh makes first.
pub(crate) fn check_maps(surface: &Surface, maps: &FaceMaps, gutter: usize) -> Result<()> {
    if maps.faces() != surface.num_domains() {
        return Err(Error::invalid(format!(
            "face maps have {} domains but the mesh has {}",
            maps.faces(),
            surface.num_domains()
        )));
    }
    if gutter == 0 {
        return Err(Error::invalid("atlas gutter must be at least 1 pixel"));
    }
    colour_channels(maps).map(|_| ())
}

/// Builds the atlas (linear colours) for `maps` on `surface` with a gutter of `gutter`
/// pixels (at least 1). Tiles are independent, so they are filled in parallel; the result
/// does not depend on the number of threads.
pub fn build_atlas(surface: &Surface, maps: &FaceMaps, gutter: usize) -> Result<Atlas> {
    build_atlas_of(surface, &colour_channels(maps)?, maps, gutter)
}

/// [`build_atlas`]`(..).to_8bit()` without the f32 atlas ([`build_atlas_8bit_of`]): the
/// 8-bit pixels and their channel count (3, or 4 with alpha).
pub fn build_atlas_8bit(
    surface: &Surface,
    maps: &FaceMaps,
    gutter: usize,
) -> Result<(Vec<u8>, usize)> {
    let chans = colour_channels(maps)?;
    let k = chans.len();
    let (_, pixels) = build_atlas_8bit_of(surface, &chans, maps, gutter, k.min(3))?;
    Ok((pixels, k))
}

/// [`build_atlas`] of any 1 to 4 channels of `maps` (the data maps of a material: normal,
/// roughness, ...), in the order given.
pub fn build_atlas_of(
    surface: &Surface,
    chans: &[&[f32]],
    maps: &FaceMaps,
    gutter: usize,
) -> Result<Atlas> {
    let (layout, pixels) = fill_atlas(surface, chans, maps, gutter, |tile, out| {
        out.copy_from_slice(tile)
    })?;
    Ok(Atlas {
        layout,
        channels: chans.len(),
        pixels,
    })
}

/// The 8-bit pixels of [`build_atlas_of`]`(surface, chans, maps, gutter)` converted as
/// [`Atlas::to_8bit_with`]`(srgb)` converts them, byte for byte, without the f32 atlas: each
/// tile is converted as it is copied into place. For the PNGs, which want only the bytes:
/// the bunny's f32 atlas (N = 16, 2820² RGB) was 95 MB of fresh memory and a pass over it
/// at the end of the run, when the atlas is the last writer left.
pub fn build_atlas_8bit_of(
    surface: &Surface,
    chans: &[&[f32]],
    maps: &FaceMaps,
    gutter: usize,
    srgb: usize,
) -> Result<(AtlasLayout, Vec<u8>)> {
    let k = chans.len();
    fill_atlas(surface, chans, maps, gutter, |tile, out| {
        to_8bit_pixels(tile, out, k, srgb)
    })
}

/// Pixels of `k` channels to 8 bits, the first `srgb` channels sRGB-encoded
/// ([`to_8bit_value`]).
fn to_8bit_pixels(px: &[f32], out: &mut [u8], k: usize, srgb: usize) {
    for (o, px) in out.chunks_exact_mut(k).zip(px.chunks_exact(k)) {
        for (c, (b, &v)) in o.iter_mut().zip(px).enumerate() {
            *b = to_8bit_value(v, c < srgb);
        }
    }
}

/// One channel value of [`Atlas::to_8bit_with`]: sRGB-encoded or linear, NaN as 0.
#[inline]
fn to_8bit_value(v: f32, srgb: bool) -> u8 {
    if srgb {
        linear_to_srgb8(v)
    } else {
        let v = if v.is_nan() { 0.0 } else { v.clamp(0.0, 1.0) };
        (v * 255.0 + 0.5).floor() as u8
    }
}

/// The atlas of `chans` with each tile row written through `put(tile row, atlas row)`
/// (interleaved, `chans.len()` values a pixel); pixels outside every tile stay
/// `T::default()`, what an all-zero f32 atlas converts to.
fn fill_atlas<T: Copy + Default + Send>(
    surface: &Surface,
    chans: &[&[f32]],
    maps: &FaceMaps,
    gutter: usize,
    put: impl Fn(&[f32], &mut [T]) + Sync,
) -> Result<(AtlasLayout, Vec<T>)> {
    if chans.is_empty() || chans.len() > 4 {
        return Err(Error::invalid("an atlas has 1 to 4 channels"));
    }
    check_maps(surface, maps, gutter)?;
    let l = &*maps.layout;
    let k = chans.len();
    let layout = AtlasLayout::of(maps.layout.clone(), gutter);
    let w = layout.width();
    let mut pixels = vec![T::default(); w * layout.height() * k];
    // Tiles sit in shelves (rows of tiles sharing their top row, each shelf's rows below
    // the previous shelf's), so the atlas splits into disjoint bands of rows, one per
    // shelf, filled in parallel: each tile in a reused scratch buffer, then put into its
    // band. One buffer per tile, joined afterwards by one thread, cost the bunny (N = 16,
    // 19,794 tiles) ~95 MB of fresh memory and a serial copy of the whole atlas.
    let mut shelves: Vec<usize> = (0..maps.faces()).collect();
    shelves.sort_by_key(|&d| (layout.origin[d].1, d));
    let mut bands: Vec<(&[usize], &mut [T])> = Vec::new();
    let (mut rest, mut top) = (pixels.as_mut_slice(), 0usize);
    for group in shelves.chunk_by(|&a, &b| layout.origin[a].1 == layout.origin[b].1) {
        let y0 = layout.origin[group[0]].1;
        let rows = group.iter().map(|&d| layout.tile(d).1).max().unwrap_or(0);
        let (_, below) = std::mem::take(&mut rest).split_at_mut((y0 - top) * w * k);
        let (band, below) = below.split_at_mut(rows * w * k);
        bands.push((group, band));
        (rest, top) = (below, y0 + rows);
    }
    bands.into_par_iter().for_each(|(group, band)| {
        let mut tile = Vec::new();
        for &d in group {
            let (nu, nv) = l.dims(d);
            let (tw, th) = layout.tile(d);
            tile.clear();
            tile.resize(tw * th * k, 0f32);
            let g = gutter as isize;
            for ty in 0..th {
                for tx in 0..tw {
                    let (x, y) = (tx as isize - g, ty as isize - g);
                    let px = &mut tile[(ty * tw + tx) * k..(ty * tw + tx + 1) * k];
                    if (0..nu as isize).contains(&x) && (0..nv as isize).contains(&y) {
                        let i = l.index(d, x as usize, y as usize);
                        for (c, ch) in chans.iter().enumerate() {
                            px[c] = ch[i];
                        }
                    } else {
                        let loc = gutter_location(surface, (nu, nv), d, x, y);
                        fetch_in_domain(chans, l, loc.domain.idx(), loc.u, loc.v, px);
                    }
                }
            }
            for corner in 0..4 {
                fix_corner_gutter(surface, chans, l, gutter, d, corner, &mut tile);
            }
            let x0 = layout.origin[d].0;
            for ty in 0..th {
                let dst = (ty * w + x0) * k;
                put(
                    &tile[ty * tw * k..(ty + 1) * tw * k],
                    &mut band[dst..dst + tw * k],
                );
            }
        }
    });
    Ok((layout, pixels))
}

/// Linear [0, 1] → 8-bit sRGB (IEC 61966-2-1); NaN and negatives give 0.
///
/// Encoding the atlas pixel by pixel with `powf` took ~170 ms at Spot N = 128, more than
/// compressing the PNG. This is a table lookup instead, exact: the 255 smallest inputs of
/// each code are found once by bisection on the formula itself
/// ([`linear_to_srgb8_exact`]); inputs are bucketed by the top 17 bits of their f32 bit
/// pattern, and no bucket holds more than one of those thresholds (checked when the
/// table is built; tested on every 61st f32 in [0, 1]), so a lookup is one table read and
/// one comparison.
#[inline]
pub fn linear_to_srgb8(c: f32) -> u8 {
    const SHIFT: u32 = 15;
    struct Table {
        code: Vec<u8>,
        threshold: Vec<f32>,
    }
    static T: std::sync::OnceLock<Table> = std::sync::OnceLock::new();
    let t = T.get_or_init(|| {
        let thresholds: Vec<f32> = (0..255)
            .map(|k| {
                // Smallest c in [0, 1] whose code is > k (codes are non-decreasing in c).
                let (mut lo, mut hi) = (0u32, 1.0f32.to_bits());
                while lo < hi {
                    let mid = lo + (hi - lo) / 2;
                    if linear_to_srgb8_exact(f32::from_bits(mid)) as usize > k {
                        hi = mid;
                    } else {
                        lo = mid + 1;
                    }
                }
                f32::from_bits(lo)
            })
            .collect();
        let buckets = (1.0f32.to_bits() >> SHIFT) as usize + 1;
        let mut code = vec![0u8; buckets];
        let mut threshold = vec![f32::INFINITY; buckets];
        for b in 0..buckets {
            let start = f32::from_bits((b as u32) << SHIFT);
            let k = thresholds.partition_point(|&x| x <= start);
            code[b] = k as u8;
            if let Some(&x) = thresholds.get(k) {
                if (x.to_bits() >> SHIFT) as usize == b {
                    threshold[b] = x;
                    assert!(
                        thresholds
                            .get(k + 1)
                            .is_none_or(|y| (y.to_bits() >> SHIFT) as usize != b),
                        "two sRGB thresholds in one bucket"
                    );
                }
            }
        }
        Table { code, threshold }
    });
    if c.is_nan() || c <= 0.0 {
        return 0;
    }
    if c >= 1.0 {
        return 255;
    }
    let b = (c.to_bits() >> SHIFT) as usize;
    t.code[b] + (c >= t.threshold[b]) as u8
}

/// The sRGB formula [`linear_to_srgb8`] tabulates.
pub fn linear_to_srgb8_exact(c: f32) -> u8 {
    let c = if c.is_nan() { 0.0 } else { c.clamp(0.0, 1.0) };
    let s = if c <= 0.003_130_8 {
        12.92 * c
    } else {
        1.055 * c.powf(1.0 / 2.4) - 0.055
    };
    (s * 255.0 + 0.5).floor().clamp(0.0, 255.0) as u8
}

/// 8-bit sRGB → linear [0, 1].
pub fn srgb8_to_linear(b: u8) -> f32 {
    let s = b as f32 / 255.0;
    if s <= 0.040_45 {
        s / 12.92
    } else {
        ((s + 0.055) / 1.055).powf(2.4)
    }
}

impl Atlas {
    /// 8-bit pixels as stored in the PNG: colour sRGB-encoded, alpha linear.
    pub fn to_8bit(&self) -> Vec<u8> {
        self.to_8bit_with(self.channels.min(3))
    }

    /// 8-bit pixels with the first `srgb` channels sRGB-encoded and the others linear
    /// (data maps such as normals and roughness are all linear: `srgb` = 0).
    pub fn to_8bit_with(&self, srgb: usize) -> Vec<u8> {
        let k = self.channels;
        let mut out = vec![0u8; self.pixels.len()];
        out.par_chunks_mut(k * 4096)
            .zip(self.pixels.par_chunks(k * 4096))
            .for_each(|(o, px)| to_8bit_pixels(px, o, k, srgb));
        out
    }

    /// 16-bit linear values (data maps: normals, roughness, heights), NaN as 0.
    pub fn to_16bit(&self) -> Vec<u16> {
        self.pixels
            .par_iter()
            .map(|&v| {
                let v = if v.is_nan() { 0.0 } else { v.clamp(0.0, 1.0) };
                (v * 65535.0 + 0.5).floor() as u16
            })
            .collect()
    }

    /// PNG bytes of [`Self::to_8bit`] (deterministic: fixed compression and filter).
    pub fn encode_png(&self, out: &mut impl Write) -> std::result::Result<(), String> {
        encode_png(&self.to_8bit(), &self.layout, self.channels, out)
    }
}

/// PNG of 8-bit pixels (1 to 4 channels) of an atlas of `layout`, deterministic: deflate
/// level 3 with adaptive filtering, in parallel bands ([`crate::io::png`]). Measured at
/// Spot N = 128 (2112² RGB): level 3 is 0.5% larger than level 6 and a quarter faster;
/// through miniz_oxide the default level took 6× as long (docs/benchmarks.md).
pub fn encode_png(
    pixels: &[u8],
    layout: &AtlasLayout,
    channels: usize,
    out: &mut impl Write,
) -> std::result::Result<(), String> {
    crate::io::png::encode(
        pixels,
        layout.width() as u32,
        layout.height() as u32,
        channels,
        png::BitDepth::Eight,
        out,
    )
}

/// [`encode_png`] of 16-bit pixels (stored big-endian, as PNG wants).
pub fn encode_png16(
    pixels: &[u16],
    layout: &AtlasLayout,
    channels: usize,
    out: &mut impl Write,
) -> std::result::Result<(), String> {
    let bytes: Vec<u8> = pixels.iter().flat_map(|v| v.to_be_bytes()).collect();
    crate::io::png::encode(
        &bytes,
        layout.width() as u32,
        layout.height() as u32,
        channels,
        png::BitDepth::Sixteen,
        out,
    )
}

/// A tessellated limit surface with per-domain texture coordinates (OBJ-ready, 0-based).
#[derive(Clone, Debug, PartialEq)]
pub struct SurfaceMesh {
    /// Limit positions, one per surface point (shared by all faces touching it).
    pub positions: Vec<[f64; 3]>,
    /// Unit limit normals, parallel to `positions`.
    pub normals: Vec<[f64; 3]>,
    /// OBJ texture coordinates (bottom-left origin), a grid per domain.
    pub uvs: Vec<[f64; 2]>,
    /// Quads: (position/normal index, uv index) per corner, counter-clockwise like the
    /// control mesh.
    pub quads: Vec<[(u32, u32); 4]>,
    /// The domain each quad belongs to (parallel to `quads`).
    pub quad_domain: Vec<u32>,
    /// Refinement level of the tessellation (see [`tessellate`]).
    pub level: u32,
}

/// The refinement level [`crate::io::export::export`] uses for resolution `n`: a quad domain gets 2^level
/// segments per side (an n-gon sub-face half that), aiming at about one segment per four
/// texels — finer adds file size but no visible smoothness, the limit surface being C² almost
/// everywhere — clamped to 2..=5 (4 to 32 segments per quad domain side).
pub fn level_for_resolution(n: usize) -> u32 {
    let target = n.div_ceil(4).max(1);
    let mut level = 0;
    while (1usize << level) < target {
        level += 1;
    }
    level.clamp(2, 5)
}

/// Domains from which the smoothness floor of [`level_for_resolution`] drops from 2 to 1:
/// a control mesh this dense is smooth at level 1 already (>= 262,144 quads, 20x Spot's
/// level-3 tessellation), and its faces are a few texels wide at the low N where the floor
/// applies (N <= 8). Measured on a 200,704-quad torus at N = 4: surface.obj 655 -> 171 MB,
/// surface.glb 332 -> 120 MB, the write stage 12.6 -> 5.7 s (docs/benchmarks.md,
/// "Orientation field").
pub const DENSE_DOMAINS: usize = 65_536;

/// The level [`crate::io::export::export`] uses for a face-map layout: [`level_for_resolution`] of
/// [`side_for_level`], but at least 1 instead of 2 on a control mesh with
/// [`DENSE_DOMAINS`] or more domains (the floor is for the smoothness of coarse meshes; the
/// UVs are exact at any level, being the domain parameters).
pub fn level_for_layout(l: &TexelLayout) -> u32 {
    let side = side_for_level(l);
    if l.faces() >= DENSE_DOMAINS && side <= 8 {
        1
    } else {
        level_for_resolution(side)
    }
}

/// The side [`level_for_resolution`] follows: N, or under a texel size the root mean
/// square side (the tessellation is uniform over the surface and is about smooth shape,
/// not texels: the largest face's side would refine every face for the few largest ones —
/// 3x the file on the Spot fixture).
pub fn side_for_level(l: &TexelLayout) -> usize {
    l.uniform_n().unwrap_or_else(|| {
        ((l.len() as f64 / l.faces().max(1) as f64).sqrt().round() as usize).max(1)
    })
}

/// The domain of every face of a limit mesh and the domain (u, v) of its four corners (in
/// the face's vertex order). A limit-mesh face lies inside one base quad and so inside one
/// domain; its corners are dyadic, so the (u, v) are exact.
pub fn face_domain_corners(surface: &Surface, lm: &LimitMesh) -> Vec<(u32, [(f64, f64); 4])> {
    (0..lm.mesh.num_faces())
        .into_par_iter()
        .map(|f| {
            let fid = FaceId::from_idx(f);
            let mut uv = [(0.0, 0.0); 4];
            let mut domain = 0;
            for (c, &(s, t)) in CORNERS.iter().enumerate() {
                let b = lm.to_base(fid, s, t);
                let loc = surface.base_to_domain(b.quad, b.s, b.t);
                uv[c] = (loc.u, loc.v);
                domain = loc.domain.0;
            }
            (domain, uv)
        })
        .collect()
}

/// The texture-coordinate grid of every domain in [`tessellate`]'s numbering: domain after
/// domain, `(M+1)²` points each, row by row (v outer), M = 2^level segments per side for a
/// quad domain and 2^(level−1) for an n-gon sub-face.
pub fn uv_grids(surface: &Surface, level: u32) -> Vec<crate::io::decimate::DomainGrid> {
    let per_base = 1u32 << (level.max(1) - 1);
    let mut first = 0u32;
    (0..surface.num_domains())
        .map(|d| {
            let m = match surface.domain(DomainId::from_idx(d)) {
                subdiv::Domain::Quad { .. } => 2 * per_base,
                subdiv::Domain::SubFace { .. } => per_base,
            };
            let g = crate::io::decimate::DomainGrid { first, m };
            first += (m + 1) * (m + 1);
            g
        })
        .collect()
}

/// Tessellates the limit surface at `level` (>= 1; see [`level_for_resolution`]) with UVs
/// into `layout`.
pub fn tessellate(surface: &Surface, layout: &AtlasLayout, level: u32) -> SurfaceMesh {
    tessellate_limit_mesh(surface, layout, &surface.limit_mesh(level.max(1)))
}

/// [`tessellate`] of a limit mesh the caller already has (`surface.limit_mesh(level)`), for
/// callers that also need its vertex locations (displacement).
pub fn tessellate_limit_mesh(
    surface: &Surface,
    layout: &AtlasLayout,
    lm: &LimitMesh,
) -> SurfaceMesh {
    let level = lm.level;
    let per_base = 1usize << (level - 1);
    // UV grid per domain: (M+1)² points, M = segments per domain side.
    let segments = |d: usize| match surface.domain(DomainId::from_idx(d)) {
        subdiv::Domain::Quad { .. } => 2 * per_base,
        subdiv::Domain::SubFace { .. } => per_base,
    };
    let mut uv_start = Vec::with_capacity(layout.faces() + 1);
    let mut uvs = Vec::new();
    for d in 0..layout.faces() {
        uv_start.push(uvs.len() as u32);
        let m = segments(d);
        for j in 0..=m {
            for i in 0..=m {
                let (a, b) = layout.obj_uv(d, i as f64 / m as f64, j as f64 / m as f64);
                uvs.push([a, b]);
            }
        }
    }
    let corners = face_domain_corners(surface, lm);
    let mut quads = Vec::with_capacity(corners.len());
    let mut quad_domain = Vec::with_capacity(corners.len());
    for (f, &(d, uv)) in corners.iter().enumerate() {
        let verts = lm.mesh.face_vertices(FaceId::from_idx(f));
        let m = segments(d as usize);
        let mut q = [(0u32, 0u32); 4];
        for c in 0..4 {
            // Corners of level faces are dyadic, so these are exact integers.
            let i = (uv[c].0 * m as f64).round() as u32;
            let j = (uv[c].1 * m as f64).round() as u32;
            q[c] = (verts[c], uv_start[d as usize] + j * (m as u32 + 1) + i);
        }
        quads.push(q);
        quad_domain.push(d);
    }
    SurfaceMesh {
        positions: lm.position.iter().map(|p| p.to_array()).collect(),
        normals: lm.normal.iter().map(|p| p.to_array()).collect(),
        uvs,
        quads,
        quad_domain,
        level,
    }
}

impl SurfaceMesh {
    /// Writes the mesh as OBJ text referencing `mtl` and [`MATERIAL`]. Coordinates are
    /// printed as f32 in shortest round-trip form (zmij): exact enough for any renderer, half the
    /// size of f64, and identical text for identical values (the shared vertex already
    /// guarantees crack-free edges; the text form keeps them crack-free after parsing).
    pub fn write_obj(&self, out: &mut impl Write, mtl: &str) -> std::io::Result<()> {
        writeln!(
            out,
            "# surfsynth: Catmull-Clark limit surface, level {} tessellation",
            self.level
        )?;
        writeln!(
            out,
            "# {} vertices, {} texture coordinates, {} quads",
            self.positions.len(),
            self.uvs.len(),
            self.quads.len()
        )?;
        writeln!(out, "mtllib {mtl}")?;
        // Formatting numbers is most of the cost: lines are formatted in parallel chunks
        // and written in order (the same bytes for any thread count).
        fn chunks<T: Sync>(
            items: &[T],
            out: &mut impl Write,
            line: impl Fn(&mut Vec<u8>, &T) -> std::io::Result<()> + Sync,
        ) -> std::io::Result<()> {
            let parts: Vec<std::io::Result<Vec<u8>>> = items
                .par_chunks(16384)
                .map(|c| {
                    let mut b = Vec::with_capacity(c.len() * 32);
                    for it in c {
                        line(&mut b, it)?;
                    }
                    Ok(b)
                })
                .collect();
            for p in parts {
                out.write_all(&p?)?;
            }
            Ok(())
        }
        // Shortest round-trip digits (zmij, as serde_json prints floats: 3-4x faster than
        // `{}`; 0.5 and 1e-8 print as "0.5" and "1e-8", integers as "1.0").
        fn line(b: &mut Vec<u8>, tag: &[u8], xs: &[f64]) -> std::io::Result<()> {
            let mut z = zmij::Buffer::new();
            b.extend_from_slice(tag);
            for &x in xs {
                b.push(b' ');
                b.extend_from_slice(z.format(x as f32).as_bytes());
            }
            b.push(b'\n');
            Ok(())
        }
        chunks(&self.positions, out, |b, p| line(b, b"v", p))?;
        chunks(&self.uvs, out, |b, t| line(b, b"vt", t))?;
        chunks(&self.normals, out, |b, n| line(b, b"vn", n))?;
        writeln!(out, "usemtl {MATERIAL}")?;
        chunks(&self.quads, out, |b, q| {
            let mut i = itoa::Buffer::new();
            b.push(b'f');
            for &(v, t) in q {
                b.push(b' ');
                b.extend_from_slice(i.format(v + 1).as_bytes());
                b.push(b'/');
                b.extend_from_slice(i.format(t + 1).as_bytes());
                b.push(b'/');
                b.extend_from_slice(i.format(v + 1).as_bytes());
            }
            b.push(b'\n');
            Ok(())
        })
    }
}

/// MTL text for the atlas; `alpha` adds `map_d` (cut-outs) from the atlas's alpha.
pub fn mtl_text(atlas: &str, alpha: bool) -> String {
    mtl_text_with_maps(atlas, alpha, &[])
}

/// [`mtl_text`] with the atlases of a material's maps, `(NAME, FILE)`: the PBR extension's
/// statements where one exists (`norm` and `map_Bump` for the normal map — Blender's and
/// most readers' names —, `map_Pr` roughness, `map_Pm` metallic, `disp` height, `map_Ke`
/// emission), a comment naming the file for the others (occlusion has no MTL statement).
pub fn mtl_text_with_maps(atlas: &str, alpha: bool, maps: &[(String, String)]) -> String {
    let mut s = format!(
        "# surfsynth material\nnewmtl {MATERIAL}\nKa 0 0 0\nKd 1 1 1\nKs 0 0 0\nd 1\nillum 1\nmap_Kd {atlas}\n"
    );
    if alpha {
        s.push_str(&format!("map_d -imfchan m {atlas}\n"));
    }
    for (name, file) in maps {
        let line = match name.as_str() {
            "normal" => format!("norm {file}\nmap_Bump -bm 1 {file}\n"),
            "roughness" => format!("map_Pr {file}\n"),
            "metallic" | "metalness" => format!("map_Pm {file}\n"),
            "height" => format!("disp {file}\n"),
            "emissive" | "emission" => format!("map_Ke {file}\n"),
            _ => format!("# map {name} {file}\n"),
        };
        s.push_str(&line);
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn srgb_round_trips_every_byte() {
        for b in 0..=255u8 {
            assert_eq!(linear_to_srgb8(srgb8_to_linear(b)), b);
        }
        assert_eq!(linear_to_srgb8(f32::NAN), 0);
        assert_eq!(linear_to_srgb8(2.0), 255);
        // Reference value: linear 0.5 is sRGB 0.7354 → 188.
        assert_eq!(linear_to_srgb8(0.5), 188);
    }

    #[test]
    fn srgb_table_gives_the_formula_bytes() {
        let one = 1.0f32.to_bits();
        let mut bits = 0u32;
        while bits <= one {
            let c = f32::from_bits(bits);
            assert_eq!(linear_to_srgb8(c), linear_to_srgb8_exact(c), "{c:e}");
            bits += 61;
        }
        for c in [
            -1.0,
            -0.0,
            0.0,
            1.0,
            1.5,
            f32::INFINITY,
            f32::NEG_INFINITY,
            f32::NAN,
        ] {
            assert_eq!(linear_to_srgb8(c), linear_to_srgb8_exact(c), "{c}");
        }
    }

    #[test]
    fn eight_bit_atlas_is_the_f32_atlas_converted() {
        // Quads, a triangle and a pentagon (sub-faces, corners of every valence).
        let s = crate::io::mixed_test_surface(|x, y| 0.1 * x * y);
        for names in [&["R", "G", "B"][..], &["R", "G", "B", "A"][..]] {
            let mut maps = FaceMaps::new(s.num_domains(), 5, names);
            for (c, (_, v)) in maps.channels.iter_mut().enumerate() {
                for (i, x) in v.iter_mut().enumerate() {
                    // Values in and out of [0, 1], and a NaN now and then.
                    *x = match (i * 7 + c * 3) % 23 {
                        0 => f32::NAN,
                        k => (k as f32 - 2.0) / 17.0,
                    };
                }
            }
            for gutter in [1, 3] {
                let a = build_atlas(&s, &maps, gutter).unwrap();
                let (bytes, k) = build_atlas_8bit(&s, &maps, gutter).unwrap();
                assert_eq!((bytes, k), (a.to_8bit(), a.channels));
                let chans: Vec<&[f32]> = maps.channels.iter().map(|(_, v)| &v[..]).collect();
                for srgb in 0..=chans.len() {
                    let a = build_atlas_of(&s, &chans, &maps, gutter).unwrap();
                    let (layout, bytes) =
                        build_atlas_8bit_of(&s, &chans, &maps, gutter, srgb).unwrap();
                    assert_eq!(layout, a.layout);
                    assert_eq!(bytes, a.to_8bit_with(srgb));
                }
            }
        }
    }

    #[test]
    fn layout_maps_texel_centres_to_pixel_centres() {
        let l = AtlasLayout::new(7, 4, 2);
        assert_eq!(l.tile(0), (8, 8));
        assert_eq!((l.width(), l.height()), (24, 24));
        // Domain 4 is column 1, row 1: interior starts at (8+2, 8+2).
        assert_eq!(l.interior_origin(4), (10, 10));
        let (x, y) = l.pixel(4, 2.5 / 4.0, 0.5 / 4.0);
        assert_eq!((x, y), (12.5, 10.5));
        let (s, t) = l.obj_uv(4, 0.0, 0.0);
        assert_eq!((s, t), (10.0 / 24.0, 1.0 - 10.0 / 24.0));
        assert_eq!(l.domain_at(9, 9), Some(4));
    }

    #[test]
    fn per_face_tiles_are_packed_without_overlap() {
        let r = |a, b| crate::layout::Resolution::new(a, b).unwrap();
        let texels = Arc::new(TexelLayout::per_face(vec![
            r(3, 3),
            r(1, 1),
            r(4, 2),
            r(2, 4),
            r(1, 0),
            r(5, 5),
        ]));
        let l = AtlasLayout::of(texels.clone(), 2);
        let mut seen = vec![u8::MAX; l.width() * l.height()];
        let mut area = 0;
        for d in 0..texels.faces() {
            let (x0, y0) = l.interior_origin(d);
            let (x0, y0) = (x0 - 2, y0 - 2);
            let (tw, th) = l.tile(d);
            area += tw * th;
            for y in y0..y0 + th {
                for x in x0..x0 + tw {
                    assert!(x < l.width() && y < l.height());
                    assert_eq!(seen[y * l.width() + x], u8::MAX, "tiles overlap at {x} {y}");
                    seen[y * l.width() + x] = d as u8;
                }
            }
            let (px, py) = l.pixel(
                d,
                0.5 / texels.dims(d).0 as f64,
                0.5 / texels.dims(d).1 as f64,
            );
            assert_eq!((px, py), (x0 as f64 + 2.5, y0 as f64 + 2.5));
        }
        // Shelves waste some room, not most of it.
        assert!(
            area * 2 > l.width() * l.height(),
            "{area} of {}x{}",
            l.width(),
            l.height()
        );
    }

    #[test]
    fn level_follows_resolution() {
        assert_eq!(level_for_resolution(1), 2);
        assert_eq!(level_for_resolution(16), 2);
        assert_eq!(level_for_resolution(32), 3);
        assert_eq!(level_for_resolution(64), 4);
        assert_eq!(level_for_resolution(4096), 5);
        let dense = |f: usize, n: usize| level_for_layout(&TexelLayout::uniform(f, n));
        assert_eq!(dense(DENSE_DOMAINS - 1, 4), 2);
        assert_eq!(dense(DENSE_DOMAINS, 4), 1);
        assert_eq!(dense(DENSE_DOMAINS, 8), 1);
        assert_eq!(dense(DENSE_DOMAINS, 9), 2);
        assert_eq!(dense(DENSE_DOMAINS, 32), 3);
    }
}
