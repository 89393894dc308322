//! The renderer-ready export: `surface.obj` + `surface.mtl` + `atlas.png` (and the
//! material's other atlases) and `surface.glb`, written atomically as one set. It stands
//! above the pieces it puts together — the atlas and tessellation ([`crate::io::atlas`]),
//! the material images ([`crate::io::materials`]), the normal atlas in UV tangent frames
//! ([`crate::io::tangent`]) and glTF ([`crate::io::gltf`]) — none of which imports it.

use crate::error::{Error, Result};
use crate::io::atlas::{
    check_maps, level_for_layout, mtl_text_with_maps, tessellate, AtlasLayout, ATLAS_NAME,
    DEFAULT_GUTTER, GLB_NAME, MATERIAL, MTL_NAME, OBJ_NAME,
};
use crate::io::atomic::AtomicFile;
use crate::io::exr::FaceMaps;
use std::io::Write;
use std::path::Path;
use subdiv::Surface;

/// Options of [`export`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ExportOptions {
    /// Gutter width in pixels (>= 1; [`DEFAULT_GUTTER`]).
    pub gutter: usize,
    /// Tessellation level; `None` picks [`level_for_layout`].
    pub level: Option<u32>,
    /// Also write `surface.glb` (default).
    pub gltf: bool,
}

impl Default for ExportOptions {
    fn default() -> Self {
        Self {
            gutter: DEFAULT_GUTTER,
            level: None,
            gltf: true,
        }
    }
}

/// What [`export`] wrote.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ExportSummary {
    pub atlas_width: usize,
    pub atlas_height: usize,
    pub vertices: usize,
    pub quads: usize,
    pub level: u32,
    pub alpha: bool,
}

/// Writes `DIR/surface.obj`, `DIR/surface.mtl`, `DIR/atlas.png` and (with
/// [`ExportOptions::gltf`]) `DIR/surface.glb` for `maps` (which need `R`, `G`, `B` and may
/// have `A`, and the data maps of [`crate::io::materials`]) on `surface`. The directory
/// must exist. Nothing is published unless all files were written.
///
/// The atlases (PNG encoding is single-threaded) are made while the surface is
/// tessellated, and the OBJ text while the glTF mesh is built.
pub fn export(
    dir: impl AsRef<Path>,
    surface: &Surface,
    maps: &FaceMaps,
    opts: &ExportOptions,
) -> Result<ExportSummary> {
    export_images(dir, surface, maps, opts).map(|(summary, _)| summary)
}

/// [`export`], also returning the encoded material images (for other outputs with the same
/// material: `displaced.glb`).
pub fn export_images(
    dir: impl AsRef<Path>,
    surface: &Surface,
    maps: &FaceMaps,
    opts: &ExportOptions,
) -> Result<(ExportSummary, crate::io::materials::MaterialImages)> {
    export_with_frames(dir, surface, maps, opts, None)
}

/// [`export_images`] for face maps whose `normal.*` is in the orientation field's frame
/// (`frames`; facemaps.exr as `synth` writes it): the normal atlases are re-expressed in
/// the tangent frames renderers derive from surface.obj's UVs ([`crate::io::tangent`]).
pub fn export_with_frames(
    dir: impl AsRef<Path>,
    surface: &Surface,
    maps: &FaceMaps,
    opts: &ExportOptions,
    frames: Option<crate::io::tangent::FieldFrames<'_>>,
) -> Result<(ExportSummary, crate::io::materials::MaterialImages)> {
    let dir = dir.as_ref();
    check_maps(surface, maps, opts.gutter)?;
    let level = opts.level.unwrap_or_else(|| level_for_layout(&maps.layout));
    let layout = AtlasLayout::of(maps.layout.clone(), opts.gutter);
    let (images, mesh) = match frames.filter(|_| maps.channel("normal.R").is_some()) {
        // The normal atlas needs the tessellation's triangles first.
        Some(f) => {
            let mesh = tessellate(surface, &layout, level);
            let uv = crate::io::tangent::UvFrames::new(surface, &mesh, layout.clone());
            let normal = crate::io::tangent::normal_atlas(surface, maps, f, &uv, opts.gutter)?;
            (
                crate::io::materials::material_images(surface, maps, opts.gutter, normal.as_ref()),
                mesh,
            )
        }
        None => rayon::join(
            || crate::io::materials::material_images(surface, maps, opts.gutter, None),
            || tessellate(surface, &layout, level),
        ),
    };
    let images = images?;
    let alpha = images.alpha;
    // The last guard before the meshes (issue 18): never a `v inf inf inf`.
    if let Some(k) = mesh
        .positions
        .iter()
        .chain(&mesh.normals)
        .position(|p| !p.iter().all(|v| v.is_finite()))
    {
        return Err(Error::file(
            dir.join(OBJ_NAME),
            format!(
                "surface {} {} is not finite; nothing was written",
                if k < mesh.positions.len() {
                    "point"
                } else {
                    "normal"
                },
                k % mesh.positions.len().max(1)
            ),
        ));
    }

    let mut map_files = Vec::with_capacity(images.maps.len());
    let mut map_list = Vec::with_capacity(images.maps.len());
    for m in &images.maps {
        let path = dir.join(m.file_name());
        let mut f = AtomicFile::create(&path)?;
        f.writer()
            .write_all(&m.png)
            .map_err(|e| Error::io(&path, "cannot write", e))?;
        map_files.push(f);
        map_list.push((m.name.clone(), m.file_name()));
    }

    let png_path = dir.join(ATLAS_NAME);
    let mut png = AtomicFile::create(&png_path)?;
    png.writer()
        .write_all(&images.base_colour)
        .map_err(|e| Error::io(&png_path, "cannot write", e))?;

    let mtl_path = dir.join(MTL_NAME);
    let mut mtl = AtomicFile::create(&mtl_path)?;
    mtl.writer()
        .write_all(mtl_text_with_maps(ATLAS_NAME, alpha, &map_list).as_bytes())
        .map_err(|e| Error::io(&mtl_path, "cannot write", e))?;

    let obj_path = dir.join(OBJ_NAME);
    let glb_path = dir.join(GLB_NAME);
    let (obj, glb) = rayon::join(
        || -> Result<AtomicFile> {
            let mut obj = AtomicFile::create(&obj_path)?;
            mesh.write_obj(obj.writer(), MTL_NAME)
                .map_err(|e| Error::io(&obj_path, "cannot write", e))?;
            Ok(obj)
        },
        || -> Result<Option<AtomicFile>> {
            if !opts.gltf {
                return Ok(None);
            }
            let mut tri = crate::io::gltf::TriMesh::from(&mesh);
            tri.tangents = crate::io::gltf::tangents(&tri);
            let material = crate::io::gltf::Material {
                name: MATERIAL,
                base_colour: &images.base_colour,
                alpha,
                normal: images.normal.as_deref(),
                orm: images.orm.as_ref().map(|(p, o)| (p.as_slice(), *o)),
            };
            crate::io::gltf::write_glb_uncommitted(&glb_path, &tri, &material).map(Some)
        },
    );
    let (obj, glb) = (obj?, glb?);

    // The OBJ refers to the MTL, which refers to the PNGs: publish in that dependency order.
    for f in map_files {
        f.commit()?;
    }
    png.commit()?;
    mtl.commit()?;
    obj.commit()?;
    if let Some(glb) = glb {
        glb.commit()?;
    }
    let summary = ExportSummary {
        atlas_width: layout.width(),
        atlas_height: layout.height(),
        vertices: mesh.positions.len(),
        quads: mesh.quads.len(),
        level,
        alpha,
    };
    Ok((summary, images))
}
