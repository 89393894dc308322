//! BTF samples (paper 003): images of one patch of material under several light (and
//! optionally view) directions, read from a `btf.json` description (docs/btf.md).
//!
//! A BTF is what a plain texture cannot be: the shadows and occlusions of a material's
//! mesostructure move with the light. Synthesis ([`crate::synth::textons`]) picks one
//! source position per texel for *all* images at once, so the surface BTF is the sample
//! indexed by `source.u/v` (003 §3), and any light is shaded afterwards ([`BtfSample::shade`],
//! `render --light`) by blending the sample's images of the nearest light directions (003
//! §6).
//!
//! **Directions** are in the sample's own frame: x along the image's columns (left to
//! right), y up the image (towards row 0), z out of the material. On the surface that frame
//! is the field's frame (v1, v2, n) as the example is laid ([`crate::synthesizer::Handedness`]:
//! `outside` lays image up along +v2, `tiles` — the default, which mirrors the example —
//! along −v2; [`local_light`] turns a world light into the sample's frame for either).
//!
//! [`generate`] builds test samples the way 003 Fig. 8 did: a height field ray-traced with
//! self-shadowing under many light directions.

pub mod generate;

use crate::error::{Error, Result};
use crate::example::{Example, PendingImage};
use glam::DVec3;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// The `format` value of a btf.json (optional in the file; checked when present).
pub const FORMAT: &str = "surfsynth-btf";
/// Most images one sample may have (003's measured samples have a few hundred; each image
/// costs its pixels in memory and a block of the texton vectors).
pub const MAX_IMAGES: usize = 1024;

/// One image of a btf.json.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct ImageEntry {
    /// PNG/JPEG file (sRGB), relative to the json's folder unless absolute.
    pub file: String,
    /// Direction towards the light, in the sample's frame (need not be unit).
    pub light: [f64; 3],
    /// Direction towards the viewer (default straight above, (0, 0, 1)).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub view: Option<[f64; 3]>,
}

/// A btf.json, as written (docs/btf.md).
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct Description {
    #[serde(default)]
    pub format: Option<String>,
    pub images: Vec<ImageEntry>,
    /// Index of the image used for facemaps.exr's colour (default: the one lit most
    /// nearly from straight above, seen most nearly from above).
    #[serde(default)]
    pub default: Option<usize>,
    /// Free-form note on where the sample came from (the generator writes its settings).
    #[serde(default)]
    pub source: Option<serde_json::Value>,
}

/// A loaded BTF sample: every image linear RGB, all of one size.
#[derive(Clone, Debug, PartialEq)]
pub struct BtfSample {
    /// The btf.json it came from.
    pub path: PathBuf,
    pub width: usize,
    pub height: usize,
    /// Unit light directions, one per image (sample frame).
    pub lights: Vec<DVec3>,
    /// Unit view directions, one per image.
    pub views: Vec<DVec3>,
    /// The images, one [`Example`] each (RGB only).
    pub images: Vec<Example>,
    /// The image facemaps.exr's colour comes from.
    pub default: usize,
}

fn unit(v: [f64; 3], path: &Path, what: &str) -> Result<DVec3> {
    let d = DVec3::from_array(v);
    if !d.is_finite() || d.length_squared() < 1e-24 {
        return Err(Error::file(
            path,
            format!("{what} is not a finite nonzero direction: {v:?}"),
        ));
    }
    Ok(d.normalize())
}

impl BtfSample {
    /// Reads `path` (btf.json) and every image it names. Errors are one line naming the
    /// file: a malformed json, a missing or unreadable image, images of different sizes.
    /// Image headers are all read (and sizes compared) before any image is decoded.
    pub fn load(path: impl AsRef<Path>) -> Result<Self> {
        let path = path.as_ref();
        let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, "cannot read", e))?;
        let desc: Description = serde_json::from_str(&text)
            .map_err(|e| Error::file(path, format!("not a BTF description: {e}")))?;
        if let Some(f) = &desc.format {
            if f != FORMAT {
                return Err(Error::file(
                    path,
                    format!("format is '{f}', expected '{FORMAT}'"),
                ));
            }
        }
        if desc.images.is_empty() {
            return Err(Error::file(path, "names no images"));
        }
        if desc.images.len() > MAX_IMAGES {
            return Err(Error::file(
                path,
                format!(
                    "names {} images; at most {MAX_IMAGES} are supported",
                    desc.images.len()
                ),
            ));
        }
        let base = path.parent().unwrap_or(Path::new(""));
        let mut lights = Vec::new();
        let mut views = Vec::new();
        let mut pending = Vec::new();
        for (i, e) in desc.images.iter().enumerate() {
            lights.push(unit(e.light, path, &format!("images[{i}].light"))?);
            views.push(unit(
                e.view.unwrap_or([0.0, 0.0, 1.0]),
                path,
                &format!("images[{i}].view"),
            )?);
            let p = Path::new(&e.file);
            let p = if p.is_absolute() {
                p.to_path_buf()
            } else {
                base.join(p)
            };
            let img = PendingImage::open(&p)?;
            if let Some(first) = pending.first() {
                let first: &PendingImage = first;
                let (a, b) = (first.info(), img.info());
                if (a.width, a.height) != (b.width, b.height) {
                    return Err(Error::file(
                        &p,
                        format!(
                            "image is {}x{} but {} is {}x{}: every image of a BTF sample must have one size",
                            b.width,
                            b.height,
                            first.path().display(),
                            a.width,
                            a.height
                        ),
                    ));
                }
            }
            pending.push(img);
        }
        let default = match desc.default {
            Some(d) if d < pending.len() => d,
            Some(d) => {
                return Err(Error::file(
                    path,
                    format!("default image {d} is out of range (0..{})", pending.len()),
                ))
            }
            None => most_overhead(&lights, &views),
        };
        let mut images = Vec::with_capacity(pending.len());
        for p in pending {
            let mut ex = Example::from_pending(p, Vec::new())?;
            // Only colour is a BTF value; alpha of a file is dropped.
            ex.alpha = None;
            images.push(ex);
        }
        let (width, height) = (images[0].width, images[0].height);
        Ok(Self {
            path: path.to_path_buf(),
            width,
            height,
            lights,
            views,
            images,
            default,
        })
    }

    /// A sample from images in memory (tests, the generator).
    pub fn from_images(images: Vec<Example>, lights: Vec<DVec3>) -> Result<Self> {
        if images.is_empty() || images.len() != lights.len() {
            return Err(Error::invalid(format!(
                "a BTF sample needs one light per image ({} images, {} lights)",
                images.len(),
                lights.len()
            )));
        }
        let (width, height) = (images[0].width, images[0].height);
        if images
            .iter()
            .any(|i| (i.width, i.height) != (width, height))
        {
            return Err(Error::invalid(
                "every image of a BTF sample must have one size",
            ));
        }
        let lights: Vec<DVec3> = lights.iter().map(|l| l.normalize()).collect();
        let views = vec![DVec3::Z; lights.len()];
        let default = most_overhead(&lights, &views);
        Ok(Self {
            path: PathBuf::new(),
            width,
            height,
            lights,
            views,
            images,
            default,
        })
    }

    /// The example every other output is made from: the default image (facemaps.exr's
    /// colour, the atlas, eval), named after its file.
    pub fn example(&self) -> Example {
        self.images[self.default].clone()
    }

    /// The sample upside down (every image; light and view directions mirrored in y), for
    /// [`crate::synthesizer::Handedness::Tiles`] runs that synthesize the flipped example.
    pub fn flipped_rows(&self) -> Self {
        let flip = |d: &DVec3| DVec3::new(d.x, -d.y, d.z);
        Self {
            path: self.path.clone(),
            width: self.width,
            height: self.height,
            lights: self.lights.iter().map(flip).collect(),
            views: self.views.iter().map(flip).collect(),
            images: self.images.iter().map(Example::flipped_rows).collect(),
            default: self.default,
        }
    }

    /// The images to blend for a light `l` (sample frame, unit) and their weights: the
    /// (up to) [`BLEND`] nearest sample lights by angle (003 §6 takes the 4 nearest), each
    /// weighted by the inverse square of its angle to `l`, so a sample light itself gets its
    /// own image exactly. Views are not interpolated: samples with several views are
    /// blended over the images seen most nearly from above.
    pub fn blend_weights(&self, l: DVec3) -> Vec<(usize, f32)> {
        let best_view = self
            .views
            .iter()
            .map(|v| v.z)
            .fold(f64::NEG_INFINITY, f64::max);
        let mut near: Vec<(f64, usize)> = self
            .lights
            .iter()
            .enumerate()
            .filter(|(i, _)| self.views[*i].z >= best_view - 1e-9)
            .map(|(i, s)| (s.dot(l).clamp(-1.0, 1.0).acos(), i))
            .collect();
        near.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        near.truncate(BLEND);
        if near[0].0 < 1e-6 {
            return vec![(near[0].1, 1.0)];
        }
        let w: Vec<f64> = near.iter().map(|(a, _)| 1.0 / (a * a)).collect();
        let sum: f64 = w.iter().sum();
        near.iter()
            .zip(&w)
            .map(|(&(_, i), &w)| (i, (w / sum) as f32))
            .collect()
    }

    /// The sample's colour at continuous position (x, y) (pixels, centres at +0.5: a
    /// texel's `source.u/v`) under the blend `weights` ([`BtfSample::blend_weights`]).
    pub fn colour(&self, weights: &[(usize, f32)], x: f32, y: f32) -> [f32; 3] {
        let mut c = [0f32; 3];
        for &(i, w) in weights {
            let v = self.images[i].bilinear_rgb(x, y);
            for k in 0..3 {
                c[k] += w * v[k];
            }
        }
        c
    }

    /// The sample at (x, y) lit from `l` (sample frame; below the horizon: black).
    pub fn shade(&self, l: DVec3, x: f32, y: f32) -> [f32; 3] {
        if l.z <= 0.0 {
            return [0.0; 3];
        }
        self.colour(&self.blend_weights(l.normalize()), x, y)
    }

    /// Every image's pixels, concatenated (cache keys: the texton analysis depends on them
    /// all, bit for bit).
    pub fn key_pixels(&self) -> Vec<f32> {
        let mut v = Vec::with_capacity(self.images.len() * self.width * self.height * 3);
        for im in &self.images {
            v.extend(im.rgb.iter().flatten());
        }
        v
    }
}

/// Sample images blended per light direction by [`BtfSample::blend_weights`].
pub const BLEND: usize = 4;

/// Index of the image lit most nearly from straight above and seen most nearly from above
/// (lowest index on ties): the default colour of a BTF result.
fn most_overhead(lights: &[DVec3], views: &[DVec3]) -> usize {
    let mut best = 0;
    for i in 1..lights.len() {
        let a = (views[i].z, lights[i].z);
        let b = (views[best].z, lights[best].z);
        if a.0 > b.0 + 1e-12 || ((a.0 - b.0).abs() <= 1e-12 && a.1 > b.1 + 1e-12) {
            best = i;
        }
    }
    best
}

/// A world-space light direction `l` in the sample's frame at a texel with field frame
/// (v1, v2, n): x = l·v1, y = ±l·v2 (+ for `outside`, − for `tiles`, see the module docs),
/// z = l·n.
pub fn local_light(l: DVec3, v1: DVec3, v2: DVec3, n: DVec3, tiles: bool) -> DVec3 {
    let y = l.dot(v2);
    DVec3::new(l.dot(v1), if tiles { -y } else { y }, l.dot(n))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn flat(v: f32) -> Example {
        Example::from_linear(4, 4, vec![[v; 3]; 16])
    }

    #[test]
    fn a_sample_light_gets_its_own_image() {
        let lights = vec![
            DVec3::Z,
            DVec3::new(1.0, 0.0, 1.0),
            DVec3::new(-1.0, 0.0, 1.0),
        ];
        let s = BtfSample::from_images(vec![flat(0.5), flat(0.9), flat(0.1)], lights).unwrap();
        assert_eq!(s.default, 0);
        let l = DVec3::new(1.0, 0.0, 1.0).normalize();
        assert_eq!(s.shade(l, 2.0, 2.0), [0.9; 3]);
        // Half way between two lights: between their colours, nearer the nearer one.
        let mid = DVec3::new(0.4, 0.0, 1.0).normalize();
        let c = s.shade(mid, 2.0, 2.0)[0];
        assert!(c > 0.5 && c < 0.9, "{c}");
        assert_eq!(s.shade(DVec3::new(0.0, 0.0, -1.0), 2.0, 2.0), [0.0; 3]);
    }

    #[test]
    fn local_light_follows_handedness() {
        let l = DVec3::new(0.0, 1.0, 1.0);
        let o = local_light(l, DVec3::X, DVec3::Y, DVec3::Z, false);
        let t = local_light(l, DVec3::X, DVec3::Y, DVec3::Z, true);
        assert_eq!(o, DVec3::new(0.0, 1.0, 1.0));
        assert_eq!(t, DVec3::new(0.0, -1.0, 1.0));
    }
}
