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
//!
//! Beside those, every map of the face maps gets its own image, `atlas_NAME.png`: colour
//! maps 8-bit sRGB like `atlas.png`, data maps 16-bit linear (roughness steps of 1/255
//! band visibly under a sharp highlight, and normals need the precision more), the normal
//! map re-expressed in the renderer's UV tangent frame ([`crate::io::tangent`]) when the
//! field's frames are known.

use crate::conventions::MapKind;
use crate::error::Result;
use crate::io::atlas::{
    build_atlas_8bit, build_atlas_8bit_of, build_atlas_of, encode_png, encode_png16, Atlas,
    AtlasLayout,
};
use crate::io::exr::FaceMaps;
use crate::io::gltf::Orm;
use rayon::prelude::*;
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
    /// One image per map of the face maps (`atlas_NAME.png`), in channel-name order.
    pub maps: Vec<MapImage>,
}

/// The atlas image of one map (`atlas_NAME.png`).
#[derive(Clone, Debug)]
pub struct MapImage {
    pub name: String,
    pub kind: MapKind,
    /// PNG bytes: 8-bit sRGB for colour maps, 16-bit linear for data maps.
    pub png: Vec<u8>,
}

impl MapImage {
    /// Its file name, `atlas_NAME.png`.
    pub fn file_name(&self) -> String {
        format!("atlas_{}.png", self.name)
    }
}

/// The maps of `maps` by name: `NAME.R NAME.G NAME.B` (all three) or `NAME.Y`, in the order
/// of their first channel (the colour channels R G B A and `source.*` are not maps).
pub fn map_channels(maps: &FaceMaps) -> Vec<(String, Vec<&[f32]>)> {
    let mut out: Vec<(String, Vec<&[f32]>)> = Vec::new();
    for (name, _) in &maps.channels {
        let Some((map, c)) = name.rsplit_once('.') else {
            continue;
        };
        if map == "source" || out.iter().any(|(m, _)| m == map) {
            continue;
        }
        let chans: Option<Vec<&[f32]>> = match c {
            "Y" => maps.channel(name).map(|y| vec![y]),
            "R" | "G" | "B" => ["R", "G", "B"]
                .iter()
                .map(|c| maps.channel(&format!("{map}.{c}")))
                .collect(),
            _ => None,
        };
        if let Some(ch) = chans {
            out.push((map.to_string(), ch));
        }
    }
    out
}

/// A scalar map: `NAME.Y`, else `NAME.R`.
fn scalar<'a>(maps: &'a FaceMaps, name: &str) -> Option<&'a [f32]> {
    maps.channel(&format!("{name}.Y"))
        .or_else(|| maps.channel(&format!("{name}.R")))
}

/// Builds and encodes the atlases of `maps` (the images in parallel). `normal_uv`: the
/// normal map already in the renderer's UV frame ([`crate::io::tangent::normal_atlas`]);
/// without it, `normal.*` is taken to be in that frame already.
pub fn material_images(
    surface: &Surface,
    maps: &FaceMaps,
    gutter: usize,
    normal_uv: Option<&Atlas>,
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
        scalar(maps, "occlusion").or_else(|| scalar(maps, "ao")),
        scalar(maps, "roughness"),
        scalar(maps, "metallic"),
    );
    let orm = Orm {
        occlusion: occ.is_some(),
        roughness: rough.is_some(),
        metallic: metal.is_some(),
    };
    let len = maps.layout.len();
    // Independent atlases; PNG encoding is single-threaded, so they run side by side.
    let per_map = || -> Result<Vec<MapImage>> {
        map_channels(maps)
            .into_par_iter()
            .map(|(name, chans)| {
                let kind = MapKind::for_name(&name);
                let owned;
                let a = match (name.as_str(), normal_uv) {
                    ("normal", Some(a)) if chans.len() == 3 => a,
                    _ => {
                        owned = build_atlas_of(surface, &chans, maps, gutter)?;
                        &owned
                    }
                };
                let mut png = Vec::new();
                match kind {
                    MapKind::Colour => {
                        encode_png(&a.to_8bit_with(a.channels), &layout, a.channels, &mut png)
                    }
                    MapKind::Data => encode_png16(&a.to_16bit(), &layout, a.channels, &mut png),
                }
                .map_err(|e| crate::Error::invalid(format!("cannot encode PNG: {e}")))?;
                Ok(MapImage { name, kind, png })
            })
            .collect()
    };
    let ((base, (normal, orm_png)), map_images) = rayon::join(
        || {
            rayon::join(
                || -> Result<(Vec<u8>, bool)> {
                    let (pixels, channels) = build_atlas_8bit(surface, maps, gutter)?;
                    Ok((png(pixels, channels)?, channels == 4))
                },
                || {
                    rayon::join(
                        || -> Result<Option<Vec<u8>>> {
                            let Some(chans) = &normal_chans else {
                                return Ok(None);
                            };
                            if let Some(a) = normal_uv {
                                return png(a.to_8bit_with(0), 3).map(Some);
                            }
                            let (_, pixels) = build_atlas_8bit_of(surface, chans, maps, gutter, 0)?;
                            png(pixels, 3).map(Some)
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
                            let (_, pixels) =
                                build_atlas_8bit_of(surface, &chans, maps, gutter, 0)?;
                            png(pixels, 3).map(Some)
                        },
                    )
                },
            )
        },
        per_map,
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
        maps: map_images?,
    })
}
