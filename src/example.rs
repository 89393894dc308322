//! The example texture: loading PNG/JPEG into linear floats, and bilinear lookups.
//!
//! Synthesis compares and blends colours, which is only meaningful on linear values, so
//! colour channels are decoded from sRGB here (the `image` crate returns the encoded values
//! unchanged). Alpha is coverage, not light, and a height map is a geometric quantity: both
//! stay as stored (scaled to 0..1). 8- and 16-bit files are read at full precision;
//! grayscale examples are expanded to equal R, G and B so that every later stage can assume
//! three colour channels.
//!
//! A material set adds named maps of the example's size (`--map NAME=FILE`,
//! [`MaterialMap`]): maps that hold light (named like colour: base colour, albedo,
//! emission) are sRGB-decoded like the example; data maps (normal, roughness, metallic,
//! height, occlusion and any other name) are values, not light, and stay as stored. Each
//! keeps its channel count (1 or 3) explicitly so that writers name its channels
//! `NAME.Y` or `NAME.R NAME.G NAME.B` without guessing.
//!
//! Coordinates are continuous pixel positions from the top-left corner of the image, pixel
//! centres at +0.5 (pixel (i, j) covers [i, i+1) x [j, j+1)), the same convention as the
//! `source.u`/`source.v` channels of `facemaps.exr`.

use crate::conventions::MapKind;
use crate::error::{Error, Result};
use image::DynamicImage;
use std::path::{Path, PathBuf};

/// Smallest accepted example side: a 5x5 neighbourhood plus a margin must fit.
pub const MIN_SIZE: usize = 8;

/// A loaded example: linear RGB, optional alpha and the further maps of a material, all
/// row-major with the top row first, `width * height` pixels each.
#[derive(Clone, Debug, PartialEq)]
pub struct Example {
    /// The file it came from (for messages and reports).
    pub path: PathBuf,
    pub width: usize,
    pub height: usize,
    /// Linear RGB (decoded from sRGB).
    pub rgb: Vec<[f32; 3]>,
    /// Alpha in 0..1 when the file has an alpha channel (RGBA or gray+alpha).
    pub alpha: Option<Vec<f32>>,
    /// Further maps of the material (`--map NAME=FILE`; `--height` is the map `height`),
    /// in the order given; names are unique.
    pub maps: Vec<MaterialMap>,
}

/// Name of the height map (`--height H.png` is `--map height=H.png`).
pub const HEIGHT: &str = "height";
/// Name of the tangent-space normal map.
pub const NORMAL: &str = "normal";

/// One further map of a material: `channels` (1 or 3) values per pixel, interleaved,
/// linear (colour maps decoded from sRGB, data maps as stored, scaled to 0..1).
#[derive(Clone, Debug, PartialEq)]
pub struct MaterialMap {
    /// `NAME` of `--map NAME=FILE`: letters, digits, `_` and `-`.
    pub name: String,
    pub kind: MapKind,
    /// 1 (a grayscale file, and always for `height`) or 3.
    pub channels: usize,
    /// `width * height * channels` values.
    pub data: Vec<f32>,
    /// The file it came from (empty for maps built in memory).
    pub path: PathBuf,
}

impl MaterialMap {
    /// A map built in memory (tests, generated materials); `channels` is 1 or 3.
    pub fn from_linear(name: &str, channels: usize, data: Vec<f32>) -> Self {
        assert!(channels == 1 || channels == 3, "a map has 1 or 3 channels");
        Self {
            name: name.to_string(),
            kind: MapKind::for_name(name),
            channels,
            data,
            path: PathBuf::new(),
        }
    }

    /// Its channel names in facemaps.exr: `NAME.Y`, or `NAME.R NAME.G NAME.B`.
    pub fn channel_names(&self) -> Vec<String> {
        if self.channels == 1 {
            vec![format!("{}.Y", self.name)]
        } else {
            ["R", "G", "B"]
                .iter()
                .map(|c| format!("{}.{c}", self.name))
                .collect()
        }
    }
}

/// Checks a map name of `--map NAME=FILE`: non-empty, letters, digits, `_` and `-` only
/// (it becomes part of channel and file names: `NAME.R`, `atlas_NAME.png`).
pub fn check_map_name(name: &str) -> std::result::Result<(), String> {
    if name.is_empty() {
        return Err("the map name is empty (expected NAME=FILE, e.g. normal=N.png)".into());
    }
    if let Some(c) = name
        .chars()
        .find(|c| !(c.is_ascii_alphanumeric() || *c == '_' || *c == '-'))
    {
        return Err(format!(
            "map name '{name}' has '{c}'; use letters, digits, '_' and '-' only"
        ));
    }
    if name == "source" {
        // facemaps.exr's source.u / source.v are the sources, not a map.
        return Err("map name 'source' is reserved (facemaps.exr's source.u/source.v)".into());
    }
    Ok(())
}

/// sRGB transfer function, decoded (IEC 61966-2-1), for values in 0..1.
#[inline]
pub fn srgb_to_linear(v: f32) -> f32 {
    if v <= 0.04045 {
        v / 12.92
    } else {
        ((v + 0.055) / 1.055).powf(2.4)
    }
}

/// Inverse of [`srgb_to_linear`] (for writing previews and atlases).
#[inline]
pub fn linear_to_srgb(v: f32) -> f32 {
    let v = v.clamp(0.0, 1.0);
    if v <= 0.0031308 {
        v * 12.92
    } else {
        1.055 * v.powf(1.0 / 2.4) - 0.055
    }
}

/// What an image file's header says, read before a single pixel is decoded (a 389 KB PNG
/// can claim 20000x20000 pixels and a 3 KB JPEG 12000x12000: decoding them first would
/// allocate gigabytes before any check could refuse them).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ImageInfo {
    pub width: u32,
    pub height: u32,
    /// Bytes per pixel of the decoded image (channels x bytes per channel).
    pub bytes_per_pixel: u32,
    /// Channels of the decoded image (1 gray, 2 gray+alpha, 3 RGB, 4 RGBA).
    pub channels: u32,
}

impl ImageInfo {
    /// Pixels in the image.
    pub fn pixels(&self) -> u64 {
        self.width as u64 * self.height as u64
    }

    /// Peak bytes of decoding it into an [`Example`]: the decoder's buffer, the converted
    /// 8- or 16-bit copy and the linear f32 channels (3 for colour, 1 more for alpha or a
    /// height map).
    pub fn decode_bytes(&self) -> u64 {
        let px = self.pixels();
        let linear = 4 * if self.channels == 2 || self.channels == 4 {
            4
        } else {
            3
        };
        px.saturating_mul(2 * self.bytes_per_pixel as u64 + linear)
    }
}

/// Where the bytes come from: a regular file is read by the decoder itself (seekable); a
/// pipe or device is read into memory first (at most the memory limit allows).
enum Source {
    File,
    Bytes(Vec<u8>),
}

/// Opens `path`, checks that it is a PNG or JPEG and returns its header and its source.
fn open_image(path: &Path) -> Result<(ImageInfo, image::ImageFormat, Source)> {
    use image::ImageDecoder;
    use std::io::Read;
    let meta = std::fs::metadata(path).map_err(|e| Error::io(path, "cannot read image", e))?;
    if meta.is_dir() {
        return Err(Error::file(path, "is a directory, not an image file"));
    }
    let regular = meta.is_file();
    if regular && meta.len() == 0 {
        return Err(Error::file(path, "image file is empty (0 bytes)"));
    }
    let mut f = std::fs::File::open(path).map_err(|e| Error::io(path, "cannot read image", e))?;
    // Decide the format from the content, not the name: a text file called .png should be
    // reported as "not an image", not as a PNG with a bad signature.
    let mut head = Vec::with_capacity(8);
    (&mut f)
        .take(8)
        .read_to_end(&mut head)
        .map_err(|e| Error::io(path, "cannot read image", e))?;
    if head.is_empty() {
        return Err(Error::file(path, "image file is empty (0 bytes)"));
    }
    let format = if head == *b"\x89PNG\r\n\x1a\n" {
        image::ImageFormat::Png
    } else if head.len() >= 3 && head[..3] == [0xFF, 0xD8, 0xFF] {
        image::ImageFormat::Jpeg
    } else {
        return Err(Error::file(
            path,
            "not a PNG or JPEG image (unrecognised file signature)",
        ));
    };
    let source = if regular {
        Source::File
    } else {
        // A pipe or a device: the rest of the stream, bounded by the memory limit.
        let cap = crate::memory::limit().bytes / 2;
        let mut bytes = head;
        (&mut f)
            .take(cap.saturating_add(1))
            .read_to_end(&mut bytes)
            .map_err(|e| Error::io(path, "cannot read image", e))?;
        if bytes.len() as u64 > cap {
            return Err(Error::file(
                path,
                format!(
                    "image stream is larger than {} (half the memory limit; see --max-memory)",
                    crate::memory::format_bytes(cap)
                ),
            ));
        }
        Source::Bytes(bytes)
    };
    let reader = reader_for(path, format, &source)?;
    let decoder = match reader {
        Reader::File(r) => r.into_decoder().map(|d| {
            let c = d.color_type();
            (d.dimensions(), c)
        }),
        Reader::Bytes(r) => r.into_decoder().map(|d| {
            let c = d.color_type();
            (d.dimensions(), c)
        }),
    };
    let ((width, height), colour) =
        decoder.map_err(|e| Error::file(path, format!("cannot decode image: {e}")))?;
    let info = ImageInfo {
        width,
        height,
        bytes_per_pixel: colour.bytes_per_pixel() as u32,
        channels: colour.channel_count() as u32,
    };
    Ok((info, format, source))
}

enum Reader<'a> {
    File(image::ImageReader<std::io::BufReader<std::fs::File>>),
    Bytes(image::ImageReader<std::io::Cursor<&'a [u8]>>),
}

fn reader_for<'a>(
    path: &Path,
    format: image::ImageFormat,
    source: &'a Source,
) -> Result<Reader<'a>> {
    // The decoder may use all the memory the guard allows (its own default, 512 MiB,
    // would refuse large examples that fit); the guard has already checked the size.
    let mut limits = image::Limits::default();
    limits.max_alloc = Some(crate::memory::limit().bytes);
    Ok(match source {
        Source::File => {
            let mut r = image::ImageReader::open(path)
                .map_err(|e| Error::io(path, "cannot read image", e))?;
            r.set_format(format);
            r.limits(limits);
            Reader::File(r)
        }
        Source::Bytes(b) => {
            let mut r = image::ImageReader::new(std::io::Cursor::new(b.as_slice()));
            r.set_format(format);
            r.limits(limits);
            Reader::Bytes(r)
        }
    })
}

/// An image whose header has been read but whose pixels have not been decoded yet (see
/// [`ImageInfo`]); a pipe's bytes are kept, so it is read once.
pub struct PendingImage {
    path: PathBuf,
    info: ImageInfo,
    format: image::ImageFormat,
    source: Source,
}

impl PendingImage {
    /// Reads the header of the PNG or JPEG at `path`, with one-line errors naming the file
    /// (missing, a directory, empty, not an image, a corrupt header).
    pub fn open(path: impl AsRef<Path>) -> Result<Self> {
        let path = path.as_ref();
        let (info, format, source) = open_image(path)?;
        Ok(Self {
            path: path.to_path_buf(),
            info,
            format,
            source,
        })
    }

    pub fn info(&self) -> &ImageInfo {
        &self.info
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Decodes it (after the minimum size and the decoding memory are checked).
    fn decode(self) -> Result<DynamicImage> {
        let path = &self.path;
        check_min_size(path, self.info.width as usize, self.info.height as usize)?;
        check_decode(path, &self.info)?;
        let decoded = match reader_for(path, self.format, &self.source)? {
            Reader::File(r) => r.decode(),
            Reader::Bytes(r) => r.decode(),
        };
        decoded.map_err(|e| Error::file(path, format!("cannot decode image: {e}")))
    }
}

/// Refuses a map (`name`: `height`, `normal`, ...) whose size differs from the example's,
/// from their headers (the example's own minimum size is checked first).
pub fn check_same_size(example: &PendingImage, name: &str, map: &PendingImage) -> Result<()> {
    let (ew, eh) = (example.info.width as usize, example.info.height as usize);
    let (hw, hh) = (map.info.width as usize, map.info.height as usize);
    if (hw, hh) != (ew, eh) {
        check_min_size(&example.path, ew, eh)?;
        return Err(Error::file(
            &map.path,
            format!(
                "{name} map is {hw}x{hh} pixels but the example {} is {ew}x{eh}; they must be the same size",
                example.path.display()
            ),
        ));
    }
    Ok(())
}

/// Reads the header of the PNG or JPEG at `path` without decoding it.
pub fn probe(path: impl AsRef<Path>) -> Result<ImageInfo> {
    PendingImage::open(path).map(|p| p.info)
}

/// Refuses an image whose decoding alone would exceed the memory limit (every caller of
/// [`Example::load`] gets this; `synth` checks its whole job before, naming the image).
fn check_decode(path: &Path, info: &ImageInfo) -> Result<()> {
    let lim = crate::memory::limit();
    let need = info.decode_bytes();
    if need > lim.bytes {
        return Err(Error::file(
            path,
            format!(
                "image is {}x{} pixels: decoding it would need about {} of memory, more than the limit of {} from {}; use a smaller image or raise --max-memory",
                info.width,
                info.height,
                crate::memory::format_bytes(need),
                crate::memory::format_bytes(lim.bytes),
                lim.source
            ),
        ));
    }
    Ok(())
}

fn check_min_size(path: &Path, w: usize, h: usize) -> Result<()> {
    if w < MIN_SIZE || h < MIN_SIZE {
        return Err(Error::file(
            path,
            format!("image is {w}x{h} pixels; at least {MIN_SIZE}x{MIN_SIZE} are required"),
        ));
    }
    Ok(())
}

fn check_size(path: &Path, img: &DynamicImage) -> Result<(usize, usize)> {
    let (w, h) = (img.width() as usize, img.height() as usize);
    check_min_size(path, w, h)?;
    Ok((w, h))
}

impl Example {
    /// Loads an example without further maps.
    pub fn load(path: impl AsRef<Path>) -> Result<Self> {
        Self::load_with_maps(path, &[])
    }

    /// Loads an example and, optionally, a height map of the same size (the map `height`).
    pub fn load_with_height(
        path: impl AsRef<Path>,
        height_path: Option<impl AsRef<Path>>,
    ) -> Result<Self> {
        let maps: Vec<(String, PathBuf)> = height_path
            .map(|h| (HEIGHT.to_string(), h.as_ref().to_path_buf()))
            .into_iter()
            .collect();
        Self::load_with_maps(path, &maps)
    }

    /// Loads an example and the further maps of its material, `(NAME, FILE)` each.
    pub fn load_with_maps(path: impl AsRef<Path>, maps: &[(String, PathBuf)]) -> Result<Self> {
        let example = PendingImage::open(path)?;
        let mut pending = Vec::with_capacity(maps.len());
        for (name, file) in maps {
            pending.push((name.clone(), PendingImage::open(file)?));
        }
        Self::from_pending(example, pending)
    }

    /// Decodes an example and its maps whose headers were read with
    /// [`PendingImage::open`]: a map of another size, a bad or repeated name, or maps that
    /// would not fit in memory together are refused before any of them is decoded.
    pub fn from_pending(example: PendingImage, maps: Vec<(String, PendingImage)>) -> Result<Self> {
        let path = example.path.clone();
        let mut total = example.info.decode_bytes();
        for (i, (name, m)) in maps.iter().enumerate() {
            check_map_name(name).map_err(|e| Error::file(&m.path, e))?;
            if maps[..i].iter().any(|(n, _)| n == name) {
                return Err(Error::file(
                    &m.path,
                    format!("map '{name}' is given twice; each --map NAME must be unique"),
                ));
            }
            check_same_size(&example, name, m)?;
            if name == NORMAL && m.info.channels < 3 {
                return Err(Error::file(
                    &m.path,
                    "normal map is grayscale; a tangent-space normal map needs RGB",
                ));
            }
            total = total.saturating_add(m.info.decode_bytes());
        }
        if !maps.is_empty() {
            // All decoded at once must fit too.
            let lim = crate::memory::limit();
            if total > lim.bytes {
                return Err(Error::file(
                    &path,
                    format!(
                        "the example and its {} maps would need about {} of memory to decode, more than the limit of {} from {}; use smaller images or raise --max-memory",
                        maps.len(),
                        crate::memory::format_bytes(total),
                        crate::memory::format_bytes(lim.bytes),
                        lim.source
                    ),
                ));
            }
        }
        let img = example.decode()?;
        let (width, height_px) = check_size(&path, &img)?;
        let (rgb, alpha) = to_linear(img);
        let mut out = Vec::with_capacity(maps.len());
        for (name, m) in maps {
            let mpath = m.path.clone();
            let kind = MapKind::for_name(&name);
            let img = m.decode()?;
            let (channels, data) = if name == HEIGHT {
                (1, to_height(img))
            } else {
                match kind {
                    MapKind::Colour => (3, to_linear(img).0.into_iter().flatten().collect()),
                    MapKind::Data => to_data(img),
                }
            };
            out.push(MaterialMap {
                name,
                kind,
                channels,
                data,
                path: mpath,
            });
        }
        Ok(Self {
            path,
            width,
            height: height_px,
            rgb,
            alpha,
            maps: out,
        })
    }

    /// Builds an example from linear data (tests, generated examples).
    pub fn from_linear(width: usize, height: usize, rgb: Vec<[f32; 3]>) -> Self {
        assert!(width >= 1 && height >= 1);
        assert_eq!(rgb.len(), width * height);
        Self {
            path: PathBuf::new(),
            width,
            height,
            rgb,
            alpha: None,
            maps: Vec::new(),
        }
    }

    /// This example with `map` added (or replacing the map of its name); its size must be
    /// the example's.
    pub fn with_map(mut self, map: MaterialMap) -> Result<Self> {
        check_map_name(&map.name).map_err(Error::invalid)?;
        if map.channels != 1 && map.channels != 3 {
            return Err(Error::invalid(format!(
                "map '{}' has {} channels; a map has 1 or 3",
                map.name, map.channels
            )));
        }
        if map.data.len() != self.width * self.height * map.channels {
            return Err(Error::invalid(format!(
                "map '{}' has {} values; the example is {}x{} pixels, so {} channel(s) need {}",
                map.name,
                map.data.len(),
                self.width,
                self.height,
                map.channels,
                self.width * self.height * map.channels
            )));
        }
        match self.maps.iter_mut().find(|m| m.name == map.name) {
            Some(m) => *m = map,
            None => self.maps.push(map),
        }
        Ok(self)
    }

    /// The map named `name`.
    pub fn map(&self, name: &str) -> Option<&MaterialMap> {
        self.maps.iter().find(|m| m.name == name)
    }

    /// The height map (`--height`, or `--map height=`), one value per pixel.
    pub fn height_map(&self) -> Option<&[f32]> {
        self.map(HEIGHT)
            .filter(|m| m.channels == 1)
            .map(|m| m.data.as_slice())
    }

    /// The example with only the maps `keep` accepts (what the matchers see: the example
    /// and the maps given a weight; the rest are copied but never compared).
    pub fn with_maps_where(&self, keep: impl Fn(&MaterialMap) -> bool) -> Self {
        Self {
            path: self.path.clone(),
            width: self.width,
            height: self.height,
            rgb: self.rgb.clone(),
            alpha: self.alpha.clone(),
            maps: self.maps.iter().filter(|m| keep(m)).cloned().collect(),
        }
    }

    /// The example upside down (row y becomes row height − 1 − y; every channel). A
    /// continuous position (x, y) of the original is (x, height − y) in the copy, and
    /// bilinear lookups agree there exactly.
    pub fn flipped_rows(&self) -> Self {
        let (w, h) = (self.width, self.height);
        fn flip<T: Copy>(v: &[T], w: usize, h: usize) -> Vec<T> {
            (0..h)
                .rev()
                .flat_map(|y| v[y * w..(y + 1) * w].iter().copied())
                .collect()
        }
        Self {
            path: self.path.clone(),
            width: w,
            height: h,
            rgb: flip(&self.rgb, w, h),
            alpha: self.alpha.as_ref().map(|a| flip(a, w, h)),
            maps: self
                .maps
                .iter()
                .map(|m| MaterialMap {
                    data: flip(&m.data, w * m.channels, h),
                    ..m.clone()
                })
                .collect(),
        }
    }

    /// Names of the channels [`Example::bilinear`] fills, in its order: `R G B`, then `A`
    /// when present, then every map's ([`MaterialMap::channel_names`]; the facemaps.exr
    /// channel names).
    pub fn channel_names(&self) -> Vec<String> {
        let mut v: Vec<String> = ["R", "G", "B"].iter().map(|s| s.to_string()).collect();
        if self.alpha.is_some() {
            v.push("A".into());
        }
        for m in &self.maps {
            v.extend(m.channel_names());
        }
        v
    }

    /// Number of channels of [`Example::channel_names`].
    pub fn num_channels(&self) -> usize {
        3 + self.alpha.is_some() as usize + self.maps.iter().map(|m| m.channels).sum::<usize>()
    }

    /// Pixel (i, j) (column, row from the top), all channels into `out`.
    #[inline]
    pub fn pixel(&self, i: usize, j: usize, out: &mut [f32]) {
        let k = j * self.width + i;
        out[..3].copy_from_slice(&self.rgb[k]);
        let mut c = 3;
        if let Some(a) = &self.alpha {
            out[c] = a[k];
            c += 1;
        }
        for m in &self.maps {
            let n = m.channels;
            out[c..c + n].copy_from_slice(&m.data[k * n..(k + 1) * n]);
            c += n;
        }
    }

    /// The four pixels and weights around continuous position (x, y), clamped to the image.
    ///
    /// Clamping (rather than wrapping) because examples are photographs or crops that are
    /// generally not tileable: wrapping would blend the unrelated opposite edge into
    /// lookups near the border and create seams inside the synthesized texture. With
    /// clamping a lookup just outside the image repeats the border pixels, which is the
    /// least surprising value; synthesizers keep their source positions inside the image
    /// anyway.
    #[inline]
    pub fn bilinear_taps(&self, x: f32, y: f32) -> ([usize; 4], [f32; 4]) {
        let fx = (x - 0.5).clamp(0.0, (self.width - 1) as f32);
        let fy = (y - 0.5).clamp(0.0, (self.height - 1) as f32);
        // NaN positions clamp to NaN; treat them as the top-left pixel rather than
        // indexing with garbage.
        let (fx, fy) = (
            if fx.is_nan() { 0.0 } else { fx },
            if fy.is_nan() { 0.0 } else { fy },
        );
        let (x0, y0) = (fx.floor() as usize, fy.floor() as usize);
        let (x1, y1) = ((x0 + 1).min(self.width - 1), (y0 + 1).min(self.height - 1));
        let (tx, ty) = (fx - x0 as f32, fy - y0 as f32);
        let w = self.width;
        (
            [y0 * w + x0, y0 * w + x1, y1 * w + x0, y1 * w + x1],
            [
                (1.0 - tx) * (1.0 - ty),
                tx * (1.0 - ty),
                (1.0 - tx) * ty,
                tx * ty,
            ],
        )
    }

    /// Bilinear linear RGB at continuous position (x, y) (pixel centres at +0.5).
    #[inline]
    pub fn bilinear_rgb(&self, x: f32, y: f32) -> [f32; 3] {
        let (k, w) = self.bilinear_taps(x, y);
        self.rgb_at_taps(&k, &w)
    }

    #[inline]
    fn rgb_at_taps(&self, k: &[usize; 4], w: &[f32; 4]) -> [f32; 3] {
        let mut c = [0.0f32; 3];
        for (&i, &wt) in k.iter().zip(w) {
            let p = self.rgb[i];
            c[0] += wt * p[0];
            c[1] += wt * p[1];
            c[2] += wt * p[2];
        }
        c
    }

    /// Bilinear lookup of all channels ([`Example::channel_names`] order) into `out`.
    #[inline]
    pub fn bilinear(&self, x: f32, y: f32, out: &mut [f32]) {
        let (k, w) = self.bilinear_taps(x, y);
        let lerp = |d: &[f32]| w[0] * d[k[0]] + w[1] * d[k[1]] + w[2] * d[k[2]] + w[3] * d[k[3]];
        out[..3].copy_from_slice(&self.rgb_at_taps(&k, &w));
        let mut c = 3;
        if let Some(a) = &self.alpha {
            out[c] = lerp(a);
            c += 1;
        }
        for m in &self.maps {
            let n = m.channels;
            for (j, o) in out[c..c + n].iter_mut().enumerate() {
                let d = |t: usize| m.data[k[t] * n + j];
                *o = w[0] * d(0) + w[1] * d(1) + w[2] * d(2) + w[3] * d(3);
            }
            c += n;
        }
    }
}

/// Colour to linear RGB (+ alpha when the image has one). 8-bit goes through a table.
fn to_linear(img: DynamicImage) -> (Vec<[f32; 3]>, Option<Vec<f32>>) {
    let lut8: Vec<f32> = (0..256).map(|i| srgb_to_linear(i as f32 / 255.0)).collect();
    let d16 = |v: u16| srgb_to_linear(v as f32 / 65535.0);
    match img {
        DynamicImage::ImageLuma8(b) => (
            b.pixels().map(|p| [lut8[p.0[0] as usize]; 3]).collect(),
            None,
        ),
        DynamicImage::ImageLumaA8(b) => (
            b.pixels().map(|p| [lut8[p.0[0] as usize]; 3]).collect(),
            Some(b.pixels().map(|p| p.0[1] as f32 / 255.0).collect()),
        ),
        DynamicImage::ImageRgb8(b) => (
            b.pixels().map(|p| p.0.map(|v| lut8[v as usize])).collect(),
            None,
        ),
        DynamicImage::ImageRgba8(b) => (
            b.pixels()
                .map(|p| [p.0[0], p.0[1], p.0[2]].map(|v| lut8[v as usize]))
                .collect(),
            Some(b.pixels().map(|p| p.0[3] as f32 / 255.0).collect()),
        ),
        DynamicImage::ImageLuma16(b) => (b.pixels().map(|p| [d16(p.0[0]); 3]).collect(), None),
        DynamicImage::ImageLumaA16(b) => (
            b.pixels().map(|p| [d16(p.0[0]); 3]).collect(),
            Some(b.pixels().map(|p| p.0[1] as f32 / 65535.0).collect()),
        ),
        DynamicImage::ImageRgb16(b) => (b.pixels().map(|p| p.0.map(d16)).collect(), None),
        DynamicImage::ImageRgba16(b) => (
            b.pixels()
                .map(|p| [p.0[0], p.0[1], p.0[2]].map(d16))
                .collect(),
            Some(b.pixels().map(|p| p.0[3] as f32 / 65535.0).collect()),
        ),
        // Float or future formats: treat values as sRGB-encoded 0..1 like the rest.
        other => {
            let has_alpha = other.color().has_alpha();
            let b = other.to_rgba32f();
            (
                b.pixels()
                    .map(|p| [p.0[0], p.0[1], p.0[2]].map(srgb_to_linear))
                    .collect(),
                has_alpha.then(|| b.pixels().map(|p| p.0[3]).collect()),
            )
        }
    }
}

/// Height values in 0..1: the gray value as stored; for a colour file its Rec. 709 luma
/// (of the stored values: heights are data, not light). Alpha is ignored.
fn to_height(img: DynamicImage) -> Vec<f32> {
    let luma = |r: f32, g: f32, b: f32| 0.2126 * r + 0.7152 * g + 0.0722 * b;
    match img {
        DynamicImage::ImageLuma8(b) => b.pixels().map(|p| p.0[0] as f32 / 255.0).collect(),
        DynamicImage::ImageLumaA8(b) => b.pixels().map(|p| p.0[0] as f32 / 255.0).collect(),
        DynamicImage::ImageLuma16(b) => b.pixels().map(|p| p.0[0] as f32 / 65535.0).collect(),
        DynamicImage::ImageLumaA16(b) => b.pixels().map(|p| p.0[0] as f32 / 65535.0).collect(),
        other => other
            .to_rgb32f()
            .pixels()
            .map(|p| luma(p.0[0], p.0[1], p.0[2]))
            .collect(),
    }
}

/// A data map's values as stored, scaled to 0..1: one channel for a grayscale file, three
/// for a colour one (alpha is ignored: data maps carry no coverage).
fn to_data(img: DynamicImage) -> (usize, Vec<f32>) {
    match img {
        DynamicImage::ImageLuma8(b) => (1, b.pixels().map(|p| p.0[0] as f32 / 255.0).collect()),
        DynamicImage::ImageLumaA8(b) => (1, b.pixels().map(|p| p.0[0] as f32 / 255.0).collect()),
        DynamicImage::ImageLuma16(b) => (1, b.pixels().map(|p| p.0[0] as f32 / 65535.0).collect()),
        DynamicImage::ImageLumaA16(b) => (1, b.pixels().map(|p| p.0[0] as f32 / 65535.0).collect()),
        DynamicImage::ImageRgb8(b) => (
            3,
            b.pixels()
                .flat_map(|p| p.0.map(|v| v as f32 / 255.0))
                .collect(),
        ),
        DynamicImage::ImageRgba8(b) => (
            3,
            b.pixels()
                .flat_map(|p| [p.0[0], p.0[1], p.0[2]].map(|v| v as f32 / 255.0))
                .collect(),
        ),
        DynamicImage::ImageRgb16(b) => (
            3,
            b.pixels()
                .flat_map(|p| p.0.map(|v| v as f32 / 65535.0))
                .collect(),
        ),
        DynamicImage::ImageRgba16(b) => (
            3,
            b.pixels()
                .flat_map(|p| [p.0[0], p.0[1], p.0[2]].map(|v| v as f32 / 65535.0))
                .collect(),
        ),
        other => (3, other.to_rgb32f().pixels().flat_map(|p| p.0).collect()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use image::{ImageBuffer, Luma, LumaA, Rgb, Rgba};

    fn dir() -> tempfile::TempDir {
        tempfile::tempdir().unwrap()
    }

    #[test]
    fn srgb_round_trip_and_known_values() {
        assert_eq!(srgb_to_linear(0.0), 0.0);
        assert!((srgb_to_linear(1.0) - 1.0).abs() < 1e-6);
        // 188/255 is the sRGB code closest to 50% linear light.
        assert!((srgb_to_linear(188.0 / 255.0) - 0.5029).abs() < 1e-3);
        for i in 0..=255 {
            let v = i as f32 / 255.0;
            assert!((linear_to_srgb(srgb_to_linear(v)) - v).abs() < 1e-5);
        }
    }

    #[test]
    fn rgb8_is_decoded_and_laid_out_row_major() {
        let d = dir();
        let p = d.path().join("a.png");
        let img = ImageBuffer::from_fn(9, 8, |x, y| Rgb([x as u8 * 20, y as u8 * 30, 188]));
        img.save(&p).unwrap();
        let e = Example::load(&p).unwrap();
        assert_eq!((e.width, e.height), (9, 8));
        assert!(e.alpha.is_none() && e.maps.is_empty());
        let px = e.rgb[3 * 9 + 2];
        assert!((px[0] - srgb_to_linear(40.0 / 255.0)).abs() < 1e-7);
        assert!((px[1] - srgb_to_linear(90.0 / 255.0)).abs() < 1e-7);
        assert!((px[2] - 0.5029).abs() < 1e-3);
        assert_eq!(e.channel_names(), vec!["R", "G", "B"]);
    }

    #[test]
    fn alpha_gray_and_16_bit() {
        let d = dir();
        let p = d.path().join("rgba.png");
        ImageBuffer::from_fn(8, 8, |x, _| Rgba([255u8, 0, 0, x as u8 * 30]))
            .save(&p)
            .unwrap();
        let e = Example::load(&p).unwrap();
        let a = e.alpha.as_ref().unwrap();
        assert!(
            (a[5] - 150.0 / 255.0).abs() < 1e-7,
            "alpha is not sRGB-decoded"
        );
        assert_eq!(e.channel_names(), vec!["R", "G", "B", "A"]);

        let p = d.path().join("la.png");
        ImageBuffer::from_fn(8, 8, |_, _| LumaA([188u8, 255]))
            .save(&p)
            .unwrap();
        let e = Example::load(&p).unwrap();
        assert_eq!(e.rgb[0][0], e.rgb[0][1]);
        assert!((e.rgb[0][2] - 0.5029).abs() < 1e-3);
        assert_eq!(e.alpha.unwrap()[0], 1.0);

        let p = d.path().join("g16.png");
        ImageBuffer::from_fn(8, 8, |x, _| Luma([x as u16 * 9000]))
            .save(&p)
            .unwrap();
        let e = Example::load(&p).unwrap();
        assert!((e.rgb[7][1] - srgb_to_linear(63000.0 / 65535.0)).abs() < 1e-6);
    }

    #[test]
    fn jpeg_loads() {
        let d = dir();
        let p = d.path().join("a.jpg");
        ImageBuffer::from_fn(16, 16, |_, _| Rgb([128u8, 128, 128]))
            .save(&p)
            .unwrap();
        let e = Example::load(&p).unwrap();
        assert!((e.rgb[0][0] - srgb_to_linear(128.0 / 255.0)).abs() < 0.01);
    }

    #[test]
    fn height_map_is_raw_and_must_match() {
        let d = dir();
        let p = d.path().join("c.png");
        ImageBuffer::from_fn(8, 8, |_, _| Rgb([1u8, 2, 3]))
            .save(&p)
            .unwrap();
        let h = d.path().join("h.png");
        ImageBuffer::from_fn(8, 8, |x, _| Luma([x as u16 * 1000]))
            .save(&h)
            .unwrap();
        let e = Example::load_with_height(&p, Some(&h)).unwrap();
        assert_eq!(e.height_map().unwrap()[3], 3000.0 / 65535.0);
        assert_eq!(e.channel_names(), vec!["R", "G", "B", "height.Y"]);
        let h2 = d.path().join("h2.png");
        ImageBuffer::from_fn(9, 8, |_, _| Luma([0u8]))
            .save(&h2)
            .unwrap();
        let err = Example::load_with_height(&p, Some(&h2))
            .unwrap_err()
            .to_string();
        assert!(err.starts_with(&h2.display().to_string()), "{err}");
        assert!(err.contains("same size"), "{err}");
    }

    #[test]
    fn bad_files_give_one_line_errors_naming_the_file() {
        let d = dir();
        let cases: Vec<(&str, Vec<u8>, &str)> = vec![
            ("empty.png", vec![], "empty"),
            (
                "text.png",
                b"hello, I am text\n".to_vec(),
                "not a PNG or JPEG",
            ),
            ("small.png", Vec::new(), "at least 8x8"),
            ("trunc.png", Vec::new(), "cannot decode"),
        ];
        // Real PNGs for the last two cases.
        let small = d.path().join("small.png");
        ImageBuffer::from_fn(4, 9, |_, _| Rgb([0u8, 0, 0]))
            .save(&small)
            .unwrap();
        let full = d.path().join("full.png");
        ImageBuffer::from_fn(64, 64, |x, y| Rgb([x as u8, y as u8, (x * y) as u8]))
            .save(&full)
            .unwrap();
        let bytes = std::fs::read(&full).unwrap();
        std::fs::write(d.path().join("trunc.png"), &bytes[..bytes.len() / 2]).unwrap();
        for (name, content, want) in cases {
            let p = d.path().join(name);
            if !content.is_empty() || name == "empty.png" {
                std::fs::write(&p, content).unwrap();
            }
            let err = Example::load(&p).unwrap_err().to_string();
            assert!(err.starts_with(&p.display().to_string()), "{err}");
            assert!(err.contains(want), "{name}: {err}");
            assert!(!err.contains('\n'), "{err}");
        }
        let err = Example::load(d.path().join("missing.png"))
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("missing.png") && err.contains("cannot read"),
            "{err}"
        );
    }

    /// Every texture shipped in ../shared loads, with alpha exactly for the RGBA ones and
    /// linear values in 0..1.
    #[test]
    fn shared_textures_load() {
        let dir = std::env::var_os("SURFSYNTH_SHARED")
            .map(PathBuf::from)
            .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared"))
            .join("data/textures");
        let mut count = 0;
        for entry in std::fs::read_dir(&dir).unwrap() {
            let p = entry.unwrap().path();
            if p.extension().and_then(|e| e.to_str()) != Some("png") {
                continue;
            }
            let e = Example::load(&p).unwrap();
            let name = p.file_name().unwrap().to_string_lossy().into_owned();
            assert!(e.width >= MIN_SIZE && e.height >= MIN_SIZE, "{name}");
            assert_eq!(e.rgb.len(), e.width * e.height);
            assert!(
                e.rgb.iter().flatten().all(|v| (0.0..=1.0).contains(v)),
                "{name}"
            );
            if name.contains("alpha") {
                let a = e
                    .alpha
                    .as_ref()
                    .unwrap_or_else(|| panic!("{name} has alpha"));
                assert!(a.iter().any(|&v| v < 1.0), "{name}: some transparency");
            }
            count += 1;
        }
        assert!(count >= 10, "found {count} textures in {}", dir.display());
        // The 16-bit height map keeps more than 256 levels.
        let h = dir.join("mpl_jacksboro_dem_height16.png");
        if h.exists() {
            let ex = Example::load(&h).unwrap();
            let mut levels: Vec<u32> = ex.rgb.iter().map(|p| p[0].to_bits()).collect();
            levels.sort_unstable();
            levels.dedup();
            assert!(
                levels.len() > 256,
                "16-bit precision kept: {} levels",
                levels.len()
            );
        }
    }

    #[test]
    fn bilinear_hits_pixel_centres_and_clamps() {
        let rgb: Vec<[f32; 3]> = (0..64).map(|i| [i as f32, 0.0, 1.0]).collect();
        let e = Example::from_linear(8, 8, rgb);
        // Pixel centre (2, 3) at (2.5, 3.5).
        assert_eq!(e.bilinear_rgb(2.5, 3.5)[0], 26.0);
        // Halfway between (2,3) and (3,3), and between rows 3 and 4.
        assert!((e.bilinear_rgb(3.0, 3.5)[0] - 26.5).abs() < 1e-6);
        assert!((e.bilinear_rgb(2.5, 4.0)[0] - 30.0).abs() < 1e-6);
        // Clamped outside the image, including NaN.
        assert_eq!(e.bilinear_rgb(-5.0, -5.0)[0], 0.0);
        assert_eq!(e.bilinear_rgb(100.0, 100.0)[0], 63.0);
        assert_eq!(e.bilinear_rgb(f32::NAN, 0.5)[0], 0.0);
        let mut out = [0.0; 3];
        e.bilinear(7.9, 0.2, &mut out);
        assert_eq!(out[0], 7.0);
    }
}
