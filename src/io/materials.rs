//! The material of the textured outputs as PNG atlases: base colour always, and the data
//! maps a material may carry (`--map NAME=FILE`, BRIEF: channels `NAME.R NAME.G NAME.B`
//! or `NAME.Y`) when the face maps have them:
//!
//! - `normal.R normal.G normal.B`: a tangent-space normal map, as stored in an image (0..1
//!   per component), in each domain's frame with x along +u and y toward −v ("up" in the
//!   atlas, glTF's convention); written linear;
//! - `occlusion`, `roughness`, `metallic` (`.Y`, or `.R` of a colour file): packed into one
//!   linear image, occlusion in R, roughness in G, metallic in B (glTF's layout; absent
//!   ones are 1, 1 and 0).
//!
//! Every atlas has the layout and gutters of `atlas.png` ([`crate::io::atlas`]), so one set
//! of texture coordinates serves them all.

use crate::error::Result;
use crate::io::atlas::{build_atlas, build_atlas_of, encode_png, AtlasLayout};
use crate::io::exr::FaceMaps;
use crate::io::gltf::Orm;
use subdiv::Surface;

/// Encoded images of a material.
#[derive(Clone, Debug)]
pub struct MaterialImages {
    pub layout: AtlasLayout,
    /// sRGB PNG, RGB or RGBA (the content of `atlas.png`).
    pub base_colour: Vec<u8>,
    pub alpha: bool,
    /// Linear RGB PNG.
    pub normal: Option<Vec<u8>>,
    /// Linear RGB PNG and which channels are real.
    pub orm: Option<(Vec<u8>, Orm)>,
}

/// A scalar map: `NAME.Y`, else `NAME.R`.
fn scalar<'a>(maps: &'a FaceMaps, name: &str) -> Option<&'a [f32]> {
    maps.channel(&format!("{name}.Y"))
        .or_else(|| maps.channel(&format!("{name}.R")))
}

/// Builds and encodes the atlases of `maps` (the images in parallel).
pub fn material_images(
    surface: &Surface,
    maps: &FaceMaps,
    gutter: usize,
) -> Result<MaterialImages> {
    let layout = AtlasLayout::of(maps.layout.clone(), gutter);
    let png = |pixels: Vec<u8>, channels: usize| -> Result<Vec<u8>> {
        let mut out = Vec::new();
        encode_png(&pixels, &layout, channels, &mut out)
            .map_err(|e| crate::Error::invalid(format!("cannot encode PNG: {e}")))?;
        Ok(out)
    };
    let normal_chans: Option<Vec<&[f32]>> = ["normal.R", "normal.G", "normal.B"]
        .iter()
        .map(|c| maps.channel(c))
        .collect();
    let (occ, rough, metal) = (
        scalar(maps, "occlusion"),
        scalar(maps, "roughness"),
        scalar(maps, "metallic"),
    );
    let orm = Orm {
        occlusion: occ.is_some(),
        roughness: rough.is_some(),
        metallic: metal.is_some(),
    };
    let len = maps.layout.len();
    // Three independent atlases; PNG encoding is single-threaded, so they run side by side.
    let (base, (normal, orm_png)) = rayon::join(
        || -> Result<(Vec<u8>, bool)> {
            let a = build_atlas(surface, maps, gutter)?;
            Ok((png(a.to_8bit(), a.channels)?, a.channels == 4))
        },
        || {
            rayon::join(
                || -> Result<Option<Vec<u8>>> {
                    let Some(chans) = &normal_chans else {
                        return Ok(None);
                    };
                    let a = build_atlas_of(surface, chans, maps, gutter)?;
                    png(a.to_8bit_with(0), 3).map(Some)
                },
                || -> Result<Option<Vec<u8>>> {
                    if orm == Orm::default() {
                        return Ok(None);
                    }
                    let (ones, zeros) = (vec![1.0f32; len], vec![0.0f32; len]);
                    let chans = [
                        occ.unwrap_or(&ones),
                        rough.unwrap_or(&ones),
                        metal.unwrap_or(&zeros),
                    ];
                    let a = build_atlas_of(surface, &chans, maps, gutter)?;
                    png(a.to_8bit_with(0), 3).map(Some)
                },
            )
        },
    );
    let (base_colour, alpha) = base?;
    let normal = normal?;
    let orm = orm_png?.map(|p| (p, orm));
    Ok(MaterialImages {
        layout,
        base_colour,
        alpha,
        normal,
        orm,
    })
}
