//! Synthetic BTF samples, made as paper 003 made Fig. 8's: a height field ray-traced with
//! self-shadowing under many light directions (no measured BTF ships with the project;
//! tests, `demo` and `surfsynth bench btf-sample` use these).
//!
//! The material is Lambertian with an albedo that darkens slightly in the valleys (so the
//! overhead image is not flat grey), shaded with the height field's own normals; a pixel is
//! in shadow when the ray towards the light passes below the height field (marched in
//! half-pixel steps, bilinear heights, toroidal wrap so a tile's edge shadows like its
//! inside), plus a small ambient term so shadows are dark but not black.

use super::{BtfSample, Description, ImageEntry, FORMAT};
use crate::error::{Error, Result};
use crate::example::Example;
use glam::DVec3;
use std::path::{Path, PathBuf};

/// A height field in pixels (row-major, top row first).
#[derive(Clone, Debug, PartialEq)]
pub struct HeightField {
    pub width: usize,
    pub height: usize,
    /// Height of every pixel, in pixel units.
    pub h: Vec<f32>,
    /// Whether the field tiles (procedural reliefs): lookups outside wrap around; else
    /// they are clamped to the border (a crop of a picture does not tile, and wrapping it
    /// would draw a false ridge along its edges).
    pub wrap: bool,
}

/// Ambient light fraction (shadows keep this much of the unshadowed overhead brightness).
pub const AMBIENT: f32 = 0.06;

impl HeightField {
    /// A grayscale PNG (0..1, linear: height maps are data) cropped to its central
    /// `size` x `size` pixels (the whole image when `None`), scaled to `depth` pixels
    /// between its lowest and highest value.
    pub fn load(path: &Path, size: Option<usize>, depth: f32) -> Result<Self> {
        let img = image::open(path)
            .map_err(|e| Error::file(path, format!("cannot read height field: {e}")))?
            .to_luma32f();
        let (w, h) = (img.width() as usize, img.height() as usize);
        let s = size.unwrap_or(w.min(h));
        if s == 0 || s > w || s > h {
            return Err(Error::file(
                path,
                format!("image is {w}x{h}, too small for a {s}x{s} sample"),
            ));
        }
        let (x0, y0) = ((w - s) / 2, (h - s) / 2);
        let mut v = Vec::with_capacity(s * s);
        for y in 0..s {
            for x in 0..s {
                v.push(img.get_pixel((x0 + x) as u32, (y0 + y) as u32)[0]);
            }
        }
        Ok(Self::normalised(s, s, v, depth))
    }

    /// A procedural relief of `size`² pixels: round bumps of a few sizes on a jittered
    /// grid (deterministic for `seed`), `depth` pixels high — for the demo, which ships no
    /// height image.
    pub fn bumps(size: usize, depth: f32, seed: u64) -> Self {
        let hash = |i: u64| crate::random::hash(seed, &[i]);
        let unit = |i: u64| (hash(i) >> 11) as f32 / (1u64 << 53) as f32;
        let cell = (size / 6).max(4);
        let cells = size.div_ceil(cell);
        let mut centres = Vec::new();
        for cy in 0..cells {
            for cx in 0..cells {
                let i = (cy * cells + cx) as u64 * 4;
                let r = cell as f32 * (0.25 + 0.3 * unit(i + 2));
                centres.push((
                    (cx as f32 + 0.2 + 0.6 * unit(i)) * cell as f32,
                    (cy as f32 + 0.2 + 0.6 * unit(i + 1)) * cell as f32,
                    r,
                ));
            }
        }
        let s = size as f32;
        let mut h = vec![0f32; size * size];
        for y in 0..size {
            for x in 0..size {
                let (px, py) = (x as f32 + 0.5, y as f32 + 0.5);
                let mut v = 0f32;
                for &(cx, cy, r) in &centres {
                    // Toroidal distance, so the relief tiles.
                    let dx = (px - cx).abs().min(s - (px - cx).abs());
                    let dy = (py - cy).abs().min(s - (py - cy).abs());
                    let d2 = (dx * dx + dy * dy) / (r * r);
                    if d2 < 1.0 {
                        v = v.max((1.0 - d2).sqrt());
                    }
                }
                h[y * size + x] = v;
            }
        }
        Self {
            wrap: true,
            ..Self::normalised(size, size, h, depth)
        }
    }

    fn normalised(width: usize, height: usize, mut h: Vec<f32>, depth: f32) -> Self {
        let (lo, hi) = h
            .iter()
            .fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), &v| {
                (a.min(v), b.max(v))
            });
        let span = (hi - lo).max(1e-6);
        for v in &mut h {
            *v = (*v - lo) / span * depth;
        }
        Self {
            width,
            height,
            h,
            wrap: false,
        }
    }

    fn at(&self, x: i64, y: i64) -> f32 {
        let (w, h) = (self.width as i64, self.height as i64);
        let (x, y) = if self.wrap {
            (x.rem_euclid(w), y.rem_euclid(h))
        } else {
            (x.clamp(0, w - 1), y.clamp(0, h - 1))
        };
        self.h[(y * w + x) as usize]
    }

    /// Bilinear height at continuous (x, y) (pixel centres at +0.5), wrapping.
    fn bilinear(&self, x: f64, y: f64) -> f64 {
        let (fx, fy) = (x - 0.5, y - 0.5);
        let (x0, y0) = (fx.floor(), fy.floor());
        let (tx, ty) = (fx - x0, fy - y0);
        let (x0, y0) = (x0 as i64, y0 as i64);
        let a = self.at(x0, y0) as f64 * (1.0 - tx) + self.at(x0 + 1, y0) as f64 * tx;
        let b = self.at(x0, y0 + 1) as f64 * (1.0 - tx) + self.at(x0 + 1, y0 + 1) as f64 * tx;
        a * (1.0 - ty) + b * ty
    }

    /// Unit normal at pixel (x, y) in the sample frame (x right, y up the image, z out).
    fn normal(&self, x: usize, y: usize) -> DVec3 {
        let (x, y) = (x as i64, y as i64);
        let dx = (self.at(x + 1, y) - self.at(x - 1, y)) as f64 * 0.5;
        // Image rows go down; the frame's y goes up.
        let dy = (self.at(x, y - 1) - self.at(x, y + 1)) as f64 * 0.5;
        DVec3::new(-dx, -dy, 1.0).normalize()
    }

    /// Whether the ray from pixel (x, y)'s surface point towards `l` (unit, sample frame)
    /// passes below the height field.
    pub fn shadowed(&self, x: usize, y: usize, l: DVec3) -> bool {
        self.shadowed_below(x, y, l, self.top())
    }

    fn top(&self) -> f64 {
        self.h.iter().fold(0f32, |a, &b| a.max(b)) as f64
    }

    fn shadowed_below(&self, x: usize, y: usize, l: DVec3, top: f64) -> bool {
        if l.z <= 0.0 {
            return true;
        }
        let (px, py) = (x as f64 + 0.5, y as f64 + 0.5);
        let h0 = self.h[y * self.width + x] as f64;
        let horiz = (l.x * l.x + l.y * l.y).sqrt();
        if horiz < 1e-9 {
            return false;
        }
        // Half-pixel steps along the light's ground direction until above every height.
        let step = 0.5;
        let rise = l.z / horiz * step;
        let (sx, sy) = (l.x / horiz * step, -l.y / horiz * step);
        let mut t = 1;
        loop {
            let z = h0 + rise * t as f64 + 1e-3;
            if z > top {
                return false;
            }
            if self.bilinear(px + sx * t as f64, py + sy * t as f64) > z {
                return true;
            }
            t += 1;
        }
    }

    /// The image under light `l` (sample frame) seen from above, linear RGB, and each
    /// pixel's shadow flag.
    pub fn render(&self, l: DVec3) -> (Vec<[f32; 3]>, Vec<bool>) {
        use rayon::prelude::*;
        let l = l.normalize();
        let top = self.h.iter().fold(1e-6f32, |a, &b| a.max(b));
        let ceiling = self.top();
        (0..self.width * self.height)
            .into_par_iter()
            .map(|i| {
                let (x, y) = (i % self.width, i / self.width);
                // Warm albedo, darker in the valleys.
                let t = self.h[i] / top;
                let albedo = [0.35 + 0.45 * t, 0.30 + 0.38 * t, 0.22 + 0.28 * t];
                let shadow = self.shadowed_below(x, y, l, ceiling);
                let lambert = if shadow {
                    0.0
                } else {
                    self.normal(x, y).dot(l).max(0.0) as f32
                };
                let e = AMBIENT + (1.0 - AMBIENT) * lambert;
                ([albedo[0] * e, albedo[1] * e, albedo[2] * e], shadow)
            })
            .unzip()
    }
}

/// `n` light directions over the upper hemisphere, in rings of elevation 20°–75° with
/// azimuths staggered between rings (deterministic; every ring has at least 4), so that any
/// direction above 20° has sample lights around it for blending.
pub fn light_directions(n: usize) -> Vec<DVec3> {
    let n = n.max(1);
    if n == 1 {
        return vec![DVec3::Z];
    }
    let rings = (n / 8).clamp(1, 4);
    let mut out = Vec::with_capacity(n);
    let mut left = n;
    for r in 0..rings {
        let count = left / (rings - r);
        left -= count;
        let elev = if rings == 1 {
            45f64
        } else {
            20.0 + 55.0 * r as f64 / (rings - 1) as f64
        }
        .to_radians();
        for a in 0..count {
            let az = std::f64::consts::TAU * (a as f64 + 0.5 * (r % 2) as f64) / count as f64;
            out.push(DVec3::new(
                elev.cos() * az.cos(),
                elev.cos() * az.sin(),
                elev.sin(),
            ));
        }
    }
    out
}

/// A sample of `hf` under `lights`, in memory, and per image the shadow flags.
pub fn sample(hf: &HeightField, lights: &[DVec3]) -> (BtfSample, Vec<Vec<bool>>) {
    let mut images = Vec::new();
    let mut shadows = Vec::new();
    for &l in lights {
        let (rgb, s) = hf.render(l);
        images.push(Example::from_linear(hf.width, hf.height, rgb));
        shadows.push(s);
    }
    let s = BtfSample::from_images(images, lights.to_vec()).expect("one light per image");
    (s, shadows)
}

/// File name of image `i` in a generated sample.
pub fn image_name(i: usize) -> String {
    format!("light_{i:02}.png")
}

/// Writes `sample` as a BTF folder: `light_NN.png` (8-bit sRGB) and `btf.json`, all at
/// once into `dir` (a transaction: nothing appears if anything fails). Returns the json's
/// path. `source` is recorded in the json.
pub fn write(dir: &Path, sample: &BtfSample, source: serde_json::Value) -> Result<PathBuf> {
    let mut names: Vec<String> = (0..sample.images.len()).map(image_name).collect();
    names.push("btf.json".into());
    let refs: Vec<&str> = names.iter().map(String::as_str).collect();
    let txn = crate::io::txn::OutputTxn::begin(dir, &refs)?;
    let staged = txn.dir().to_path_buf();
    let r = (|| -> Result<()> {
        for (i, im) in sample.images.iter().enumerate() {
            write_png(&staged.join(image_name(i)), im)?;
        }
        let desc = Description {
            format: Some(FORMAT.into()),
            images: sample
                .lights
                .iter()
                .enumerate()
                .map(|(i, l)| ImageEntry {
                    file: image_name(i),
                    light: l.to_array(),
                    view: None,
                })
                .collect(),
            default: Some(sample.default),
            source: Some(source),
        };
        let text = serde_json::to_string_pretty(&desc)
            .map_err(|e| Error::invalid(format!("cannot encode btf.json: {e}")))?;
        crate::io::atomic::write_bytes_atomic(staged.join("btf.json"), text.as_bytes())
    })();
    r.map_err(|e| txn.explain(e))?;
    txn.commit()?;
    Ok(dir.join("btf.json"))
}

/// `surfsynth bench btf-sample`: the height field of `height` (or [`HeightField::bumps`]),
/// `size`² pixels, `depth` pixels deep, under [`light_directions`]`(lights)`, written into
/// `out` by [`write()`].
pub fn write_sample_cli(
    height: Option<&Path>,
    lights: usize,
    size: usize,
    depth: f32,
    out: &Path,
) -> Result<PathBuf> {
    let hf = match height {
        Some(p) => HeightField::load(p, Some(size), depth)?,
        None => HeightField::bumps(size, depth, 1),
    };
    let (s, _) = sample(&hf, &light_directions(lights));
    let source = serde_json::json!({
        "generator": "surfsynth bench btf-sample",
        "height": height.map_or("procedural bumps (seed 1)".to_string(), |p| p.display().to_string()),
        "size": size,
        "depth_pixels": depth,
        "lights": lights,
        "ambient": AMBIENT,
    });
    write(out, &s, source)
}

fn write_png(path: &Path, im: &Example) -> Result<()> {
    use image::codecs::png::PngEncoder;
    use image::{ExtendedColorType, ImageEncoder};
    let bytes: Vec<u8> = im
        .rgb
        .iter()
        .flat_map(|c| c.map(crate::io::atlas::linear_to_srgb8))
        .collect();
    let mut f = crate::io::atomic::AtomicFile::create(path)?;
    PngEncoder::new(f.writer())
        .write_image(
            &bytes,
            im.width as u32,
            im.height as u32,
            ExtendedColorType::Rgb8,
        )
        .map_err(|e| Error::file(path, format!("cannot write PNG: {e}")))?;
    f.commit()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_wall_casts_a_shadow_away_from_the_light() {
        // A ridge along column 8: light from +x shadows the pixels at x < 8, not x > 8.
        let mut h = vec![0f32; 16 * 16];
        for y in 0..16 {
            h[y * 16 + 8] = 6.0;
        }
        let hf = HeightField {
            width: 16,
            height: 16,
            h,
            wrap: false,
        };
        let l = DVec3::new(1.0, 0.0, 0.5).normalize();
        assert!(hf.shadowed(6, 4, l));
        assert!(!hf.shadowed(10, 4, l));
        assert!(!hf.shadowed(6, 4, DVec3::Z));
    }

    #[test]
    fn lights_cover_the_hemisphere() {
        for n in [1, 8, 16, 32] {
            let l = light_directions(n);
            assert_eq!(l.len(), n);
            assert!(l
                .iter()
                .all(|d| d.z > 0.0 && (d.length() - 1.0).abs() < 1e-12));
        }
    }
}
