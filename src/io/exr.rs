//! Per-face maps as one tiled OpenEXR image (BRIEF, "Output directory of `synth`").
//!
//! Layout: a single-part tiled image, tile size N x N, one tile per face domain. With F
//! domains and C = ceil(sqrt(F)) tile columns, domain f is the tile at column f mod C, row
//! f div C (rows from the top); the data window is C*N x ceil(F/C)*N; unused tiles are zero.
//! The header carries the ints `surfsynth.faces` (F) and `surfsynth.resolution` (N). Inside a
//! tile, texel (x, y) (x from the left, y from the top) is (u, v) = ((x+0.5)/N, (y+0.5)/N).
//!
//! With per-face resolutions (`--texel-size`, [`crate::layout`]) the tile is as large as
//! the largest domain along u and along v, each domain's nu x nv texels sit at its tile's
//! top-left (the rest is zero), and the header holds [`ATTR_RESOLUTIONS`] instead of
//! [`ATTR_RESOLUTION`]; OIIO and OpenEXR read it as an ordinary tiled image.
//!
//! Why tiles: one tile per domain makes each domain one contiguous, independently compressed
//! block, so a domain can be produced (or read) alone. [`write_tiles`] exploits that: it
//! asks a callback for one domain at a time, in parallel batches, and streams compressed
//! tiles to disk in file order — `bake` never holds the whole mesh's maps in memory.
//!
//! In memory ([`FaceMaps`]) every channel is a flat `Vec<f32>` of F*N*N values, domain-major
//! and row-major inside a domain (index `(f*N + y)*N + x`), the same order as
//! `subdiv::Surface::eval_texels`. OpenEXR stores channels sorted by name; we sort on
//! writing and [`read_face_maps`] returns them in that (file) order, so look channels up by
//! name ([`FaceMaps::channel`]).
//!
//! Compression: [`DEFAULT_COMPRESSION`] is none (measured, see docs/formats.md).

use crate::error::{Error, Result};
use crate::io::atomic::write_atomic;
use crate::layout::{Resolution, TexelLayout};
use exr::block::chunk::Chunk;
use exr::block::reader::ChunksReader;
use exr::block::writer::ChunksWriter;
use exr::block::{BlockIndex, UncompressedBlock};
use exr::math::{RoundingMode, Vec2};
use exr::meta::attribute::{
    AttributeValue, ChannelDescription, LevelMode, LineOrder, SampleType, Text, TileDescription,
};
use exr::meta::header::Header;
use exr::meta::{BlockDescription, MetaData};
use exr::prelude::SmallVec;
use rayon::prelude::*;
use std::fs::File;
use std::io::BufReader;
use std::path::Path;
use std::sync::Arc;

pub use exr::compression::Compression;

/// Header attribute holding the number of face domains F.
pub const ATTR_FACES: &str = "surfsynth.faces";
/// Header attribute holding the tile resolution N (uniform layouts).
pub const ATTR_RESOLUTION: &str = "surfsynth.resolution";
/// Header attribute holding the per-face resolutions of a `--texel-size` layout, in place of
/// [`ATTR_RESOLUTION`]: a string of two hexadecimal digits per domain, log2 of its texels
/// along u then along v ("5443" = domain 0 32x16, domain 1 16x8). A string because OpenEXR
/// has no integer-array attribute, and every reader (OIIO, Blender) passes strings through.
pub const ATTR_RESOLUTIONS: &str = "surfsynth.resolutions";

/// Compression used unless a caller asks for another one: none. Measured (docs/formats.md):
/// on float maps RLE and PIZ shrink nothing, and ZIP saves 25% (geometry) to 37% (colour
/// maps) of the bytes but writes 3-7x slower — on 2 cores a ZIP-compressed bake runs at
/// well under half the speed of evaluation. Users who prefer small files pass
/// `--compression zip`; every reader handles all of them.
pub const DEFAULT_COMPRESSION: Compression = Compression::Uncompressed;

/// The compression [`write_face_maps`] and the synthesizer use for maps of `layout`:
/// [`DEFAULT_COMPRESSION`] with one N; RLE with per-face resolutions, whose tiles are as
/// large as the largest face and zero beyond each face's texels — RLE stores those runs
/// almost for free at about the speed of no compression (Spot, texel size 0.004, 393k
/// texels: geometry.exr 25.2 MB uncompressed, 9.9 MB RLE, 9.3 MB ZIP at 4.5x the time).
pub fn compression_for(layout: &TexelLayout) -> Compression {
    match layout.uniform_n() {
        Some(_) => DEFAULT_COMPRESSION,
        None => Compression::RLE,
    }
}

/// Largest supported resolution (texels per tile side). Far beyond any practical use
/// (8192² texels per face is 256 MiB per channel per face); a guard against typos.
pub const MAX_RESOLUTION: usize = 8192;

/// Where the tiles of F domains sit in the image: one tile per domain, the tile as large
/// as the largest domain along u and along v (N x N with `--resolution N`), each domain's
/// texels at its tile's top-left corner.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct TileLayout {
    /// Per-domain resolutions.
    pub texels: Arc<TexelLayout>,
    /// Tile width and height in pixels.
    pub tile: (usize, usize),
    /// Tile columns C = ceil(sqrt(F)).
    pub columns: usize,
    /// Tile rows ceil(F / C).
    pub rows: usize,
}

impl TileLayout {
    /// The layout for `faces` domains of `resolution`² texels (both must be at least 1).
    pub fn new(faces: usize, resolution: usize) -> Self {
        Self::of(Arc::new(TexelLayout::uniform(faces, resolution.max(1))))
    }

    /// The layout for the domains of `texels`.
    pub fn of(texels: Arc<TexelLayout>) -> Self {
        let faces = texels.faces();
        let columns = ceil_sqrt(faces).max(1);
        Self {
            tile: texels.max_dims(),
            texels,
            columns,
            rows: faces.div_ceil(columns).max(1),
        }
    }

    /// Number of face domains F.
    pub fn faces(&self) -> usize {
        self.texels.faces()
    }

    /// Data window width in pixels, C * tile width.
    pub fn width(&self) -> usize {
        self.columns * self.tile.0
    }

    /// Data window height in pixels, ceil(F/C) * tile height.
    pub fn height(&self) -> usize {
        self.rows * self.tile.1
    }

    /// (column, row) of domain `f`'s tile.
    pub fn tile_of(&self, f: usize) -> (usize, usize) {
        (f % self.columns, f / self.columns)
    }

    /// Pixel position of the top-left texel of domain `f`'s tile.
    pub fn tile_origin(&self, f: usize) -> (usize, usize) {
        let (c, r) = self.tile_of(f);
        (c * self.tile.0, r * self.tile.1)
    }

    /// Total tiles, including the unused ones at the end of the last row.
    pub fn tile_count(&self) -> usize {
        self.columns * self.rows
    }
}

/// Smallest c with c*c >= n.
fn ceil_sqrt(n: usize) -> usize {
    let mut c = (n as f64).sqrt() as usize;
    while c * c < n {
        c += 1;
    }
    while c > 0 && (c - 1) * (c - 1) >= n {
        c -= 1;
    }
    c
}

/// Named f32 maps over all face domains (see the module docs for the memory layout).
#[derive(Clone, Debug, PartialEq)]
pub struct FaceMaps {
    /// Where every texel is (per-face resolutions, global order).
    pub layout: Arc<TexelLayout>,
    /// (name, one value per texel), domain-major, row-major inside a domain.
    pub channels: Vec<(String, Vec<f32>)>,
}

impl FaceMaps {
    /// Zero-filled `resolution`² maps per domain with the given channel names.
    pub fn new(faces: usize, resolution: usize, names: &[&str]) -> Self {
        Self::with_layout(
            Arc::new(TexelLayout::uniform(faces, resolution.max(1))),
            names,
        )
    }

    /// Zero-filled maps in `layout` with the given channel names.
    pub fn with_layout(layout: Arc<TexelLayout>, names: &[&str]) -> Self {
        let len = layout.len();
        Self {
            layout,
            channels: names
                .iter()
                .map(|n| (n.to_string(), vec![0.0; len]))
                .collect(),
        }
    }

    /// Number of face domains F.
    pub fn faces(&self) -> usize {
        self.layout.faces()
    }

    /// N when every domain has N x N texels (`--resolution`).
    pub fn uniform_n(&self) -> Option<usize> {
        self.layout.uniform_n()
    }

    /// The tile layout these maps are written with.
    pub fn tiles(&self) -> TileLayout {
        TileLayout::of(self.layout.clone())
    }

    /// Index of texel (x, y) of domain `face` in every channel's data.
    #[inline]
    pub fn index(&self, face: usize, x: usize, y: usize) -> usize {
        self.layout.index(face, x, y)
    }

    /// A channel's data by name.
    pub fn channel(&self, name: &str) -> Option<&[f32]> {
        self.channels
            .iter()
            .find(|(n, _)| n == name)
            .map(|(_, d)| d.as_slice())
    }

    /// A channel's data by name, mutable.
    pub fn channel_mut(&mut self, name: &str) -> Option<&mut [f32]> {
        self.channels
            .iter_mut()
            .find(|(n, _)| n == name)
            .map(|(_, d)| d.as_mut_slice())
    }

    /// Channel names in storage order.
    pub fn names(&self) -> Vec<&str> {
        self.channels.iter().map(|(n, _)| n.as_str()).collect()
    }

    /// Checks sizes and names; `write_face_maps` calls it.
    pub fn validate(&self) -> Result<()> {
        check_shape(&self.tiles())?;
        let len = self.layout.len();
        for (name, data) in &self.channels {
            if data.len() != len {
                return Err(Error::invalid(format!(
                    "face map channel '{name}' has {} values, expected {len} ({} faces at {})",
                    data.len(),
                    self.faces(),
                    self.layout.describe()
                )));
            }
        }
        check_names(&self.names())
    }
}

fn check_shape(layout: &TileLayout) -> Result<()> {
    let faces = layout.faces();
    if faces == 0 {
        return Err(Error::invalid("face maps need at least one face domain"));
    }
    let (tw, th) = layout.tile;
    if tw == 0 || th == 0 || tw > MAX_RESOLUTION || th > MAX_RESOLUTION {
        return Err(Error::invalid(format!(
            "resolution {tw}x{th} is out of range 1..={MAX_RESOLUTION}"
        )));
    }
    if layout.width() > i32::MAX as usize / 2 || layout.height() > i32::MAX as usize / 2 {
        return Err(Error::invalid(format!(
            "{faces} faces at {} exceed the size an EXR image can have",
            layout.texels.describe()
        )));
    }
    Ok(())
}

fn check_names(names: &[&str]) -> Result<()> {
    if names.is_empty() {
        return Err(Error::invalid("face maps need at least one channel"));
    }
    for (i, n) in names.iter().enumerate() {
        if n.is_empty() || n.len() > 255 || !n.is_ascii() {
            return Err(Error::invalid(format!(
                "channel name '{n}' must be 1 to 255 ASCII characters"
            )));
        }
        if names[..i].contains(n) {
            return Err(Error::invalid(format!("channel name '{n}' is repeated")));
        }
    }
    Ok(())
}

/// Summary of a face-map file's header (cheap: does not read pixels).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct FaceMapsInfo {
    pub faces: usize,
    /// N of a uniform layout; `None` for per-face resolutions.
    pub resolution: Option<usize>,
    /// Channel names in file (sorted) order.
    pub channels: Vec<String>,
    pub compression: String,
}

/// Writes `maps` to `path` (atomically) with [`compression_for`] its layout.
pub fn write_face_maps(path: impl AsRef<Path>, maps: &FaceMaps) -> Result<()> {
    write_face_maps_with(path, maps, compression_for(&maps.layout))
}

/// Writes `maps` to `path` (atomically) with the given compression. Only lossless
/// compressions are accepted: the maps hold positions and source coordinates, not pictures.
pub fn write_face_maps_with(
    path: impl AsRef<Path>,
    maps: &FaceMaps,
    compression: Compression,
) -> Result<()> {
    write_face_maps_by(path.as_ref(), maps, compression, TileThreads::Pool)
}

/// [`write_face_maps`] with the tiles filled by `threads` (the same bytes).
pub fn write_face_maps_on(
    path: impl AsRef<Path>,
    maps: &FaceMaps,
    threads: TileThreads,
) -> Result<()> {
    write_face_maps_by(path.as_ref(), maps, compression_for(&maps.layout), threads)
}

fn write_face_maps_by(
    path: &Path,
    maps: &FaceMaps,
    compression: Compression,
    threads: TileThreads,
) -> Result<()> {
    maps.validate()?;
    let names = maps.names();
    write_tiles_with_attributes(
        path,
        maps.tiles(),
        &names,
        compression,
        &[],
        |f, tile| {
            let r = maps.layout.range(f);
            let nn = r.len();
            for (k, (_, data)) in maps.channels.iter().enumerate() {
                tile[k * nn..(k + 1) * nn].copy_from_slice(&data[r.clone()]);
            }
        },
        &|_| {},
        threads,
    )
}

/// Refuses a non-finite value in per-texel `data` (global texel order of `layout`), naming
/// the first one's face and texel. The last guard before `synth`'s files: whatever went
/// wrong upstream (an extreme input the checks missed, a bug), NaN or ±inf must never reach
/// a renderer (issue 18), and an error that says where beats a file that looks fine. Not
/// in [`write_face_maps`] itself: a generic writer may store NaN as "no value" (eval reads
/// such files and counts them as uncovered).
pub fn check_finite(what: &str, data: &[f32], layout: &TexelLayout) -> Result<()> {
    check_finite_by(what, data.len(), |i| data[i].is_finite(), layout)
}

/// Texels per work item of [`check_finite_by`]: rayon's per-item searches cost ~10 ns a
/// texel (0.23 s for Spot's five face-map channels at N = 128), a plain loop over a chunk
/// well under one.
const FINITE_CHUNK: usize = 1 << 15;

/// [`check_finite`] for per-texel values of any type (`finite(i)` says whether texel `i`'s
/// value is finite).
pub fn check_finite_by(
    what: &str,
    len: usize,
    finite: impl Fn(usize) -> bool + Sync,
    layout: &TexelLayout,
) -> Result<()> {
    use rayon::prelude::*;
    let span = |k: usize| k * FINITE_CHUNK..((k + 1) * FINITE_CHUNK).min(len);
    // `fold`, not `all`: no early exit in the common all-finite case, so the loop stays
    // branch-free.
    let Some(k) = (0..len.div_ceil(FINITE_CHUNK))
        .into_par_iter()
        .position_first(|k| !span(k).fold(true, |ok, i| ok & finite(i)))
    else {
        return Ok(());
    };
    let i = span(k)
        .find(|&i| !finite(i))
        .expect("the chunk holds a non-finite value");
    let (d, x, y) = layout.coords(i);
    Err(Error::invalid(format!(
        "{what} is not finite at face domain {d}, texel ({x}, {y}); nothing was written"
    )))
}

/// Bytes of tiles per batch of [`write_tiles`]. Two batches per file are in flight (one
/// written while the next is filled), each held twice for a moment (the filled tile and its
/// interleaved block), and `synth` writes facemaps.exr and geometry.exr at once, beside the
/// pf summary and the atlas: at the end of a run these buffers add to the maps and the texel
/// geometry. 8 MiB (was 32) still gives every thread a dozen tiles at N = 128 and keeps
/// the end-of-run peak ~100 MiB lower when both files are being written (docs/benchmarks.md,
/// "Spot at N = 128").
pub const BATCH_BYTES: usize = 8 << 20;

/// Which threads fill the tiles of an uncompressed file
/// ([`write_tiles_with_attributes`], [`write_face_maps_on`]); the bytes are the same.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TileThreads {
    /// The current rayon pool's, one batch while the calling thread writes the one before.
    Pool,
    /// The calling thread alone: each batch filled, then written. For a file given a
    /// thread of its own beside the pool: filling uncompressed tiles is copying, and most
    /// of the file's time is spent waiting for the disk (`O_DIRECT`, [`crate::io::direct`]),
    /// which then blocks that thread instead of one of the pool's workers. Compressed
    /// files are compressed on the pool either way.
    Caller,
}

/// Streams a face-map file: `fill(f, tile)` is called once per domain f (in parallel on
/// the current rayon pool) and must write the domain's nu·nv texels of every channel into
/// `tile` (zeroed, length `names.len()·nu·nv`, channel-major in the order of `names`, each
/// channel row-major, nu wide). The writer places them at the top-left of the domain's
/// tile and zero-fills the rest of it. `progress(done)` gets the number of domains written so far.
///
/// Memory stays bounded by two batches of tiles (about [`BATCH_BYTES`] each, at least one tile per
/// thread), and output bytes do not depend on the number of threads: tiles are filled
/// independently and written in file order.
pub fn write_tiles<F>(
    path: impl AsRef<Path>,
    layout: TileLayout,
    names: &[&str],
    compression: Compression,
    fill: F,
    progress: &(dyn Fn(usize) + Sync),
) -> Result<()>
where
    F: Fn(usize, &mut [f32]) + Sync,
{
    write_tiles_with_attributes(
        path,
        layout,
        names,
        compression,
        &[],
        fill,
        progress,
        TileThreads::Pool,
    )
}

/// The exr crate keeps custom attributes in a `HashMap` and writes them in its iteration
/// order, which depends on a per-map random seed: with more than one attribute in a map,
/// two runs would write different bytes. Each fresh map gets a different seed, so maps are
/// built until one iterates in name order (for two or three attributes a few tries): the
/// same bytes every run.
fn name_ordered(
    attrs: Vec<(Text, AttributeValue)>,
) -> std::collections::HashMap<Text, AttributeValue> {
    let mut sorted = attrs;
    sorted.sort_by(|a, b| a.0.as_slice().cmp(b.0.as_slice()));
    let mut map = std::collections::HashMap::new();
    for _ in 0..100_000 {
        map = sorted.iter().cloned().collect();
        if map
            .keys()
            .map(|k| k.as_slice())
            .eq(sorted.iter().map(|a| a.0.as_slice()))
        {
            break;
        }
    }
    map
}

/// [`write_tiles`] with extra integer header attributes (e.g. geometry.exr's
/// `tangentHandedness`), written in name order beside the layer's `faces`, the tiles
/// filled by `threads`.
#[allow(clippy::too_many_arguments)]
pub fn write_tiles_with_attributes<F>(
    path: impl AsRef<Path>,
    layout: TileLayout,
    names: &[&str],
    compression: Compression,
    attributes: &[(&str, i32)],
    fill: F,
    progress: &(dyn Fn(usize) + Sync),
    threads: TileThreads,
) -> Result<()>
where
    F: Fn(usize, &mut [f32]) + Sync,
{
    write_tiles_by(
        path.as_ref(),
        layout,
        names,
        compression,
        attributes,
        fill,
        progress,
        (BATCH_BYTES, false, threads),
    )
}

/// [`write_tiles_with_attributes`] in batches of about `batch_bytes`; `via_crate` sends
/// uncompressed tiles through the exr crate's chunk writer too (the tests compare the two),
/// which fills them on the pool whatever `on` says.
#[allow(clippy::too_many_arguments)]
fn write_tiles_by<F>(
    path: &Path,
    layout: TileLayout,
    names: &[&str],
    compression: Compression,
    attributes: &[(&str, i32)],
    fill: F,
    progress: &(dyn Fn(usize) + Sync),
    (batch_bytes, via_crate, on): (usize, bool, TileThreads),
) -> Result<()>
where
    F: Fn(usize, &mut [f32]) + Sync,
{
    check_shape(&layout)?;
    check_names(names)?;
    if compression.may_loose_data() {
        return Err(Error::invalid(format!(
            "compression {compression} is lossy; face maps need a lossless one"
        )));
    }
    let (tw, th) = layout.tile;

    // OpenEXR requires channels sorted by name (byte order).
    let mut order: Vec<usize> = (0..names.len()).collect();
    order.sort_by(|&a, &b| names[a].as_bytes().cmp(names[b].as_bytes()));
    let channels: SmallVec<[ChannelDescription; 5]> = order
        .iter()
        .map(|&k| ChannelDescription::new(Text::from(names[k]), SampleType::F32, false))
        .collect();

    let mut header = Header::new(
        Text::from("surfsynth"),
        Vec2(layout.width(), layout.height()),
        channels,
    )
    .with_encoding(
        compression,
        BlockDescription::Tiles(TileDescription {
            tile_size: Vec2(tw, th),
            level_mode: LevelMode::Singular,
            rounding_mode: RoundingMode::Down,
        }),
        LineOrder::Increasing,
    );
    // A single-part file needs no part name; leaving it out keeps other readers from
    // treating the file as multi-part.
    header.own_attributes.layer_name = None;
    header.own_attributes.software_name = Some(Text::from("surfsynth"));
    // The exr crate writes custom attributes in HashMap order, which is random per map:
    // with both ints in one map, two runs would write different bytes. One attribute per
    // map makes the order fixed (layer map first, then the image map); readers see both as
    // ordinary header attributes.
    let mut own = vec![(
        Text::from(ATTR_FACES),
        AttributeValue::I32(layout.faces() as i32),
    )];
    own.extend(
        attributes
            .iter()
            .map(|(k, v)| (Text::from(*k), AttributeValue::I32(*v))),
    );
    header.own_attributes.other = name_ordered(own);
    let (key, value) = match (layout.texels.uniform_n(), layout.texels.resolutions()) {
        (Some(n), _) => (ATTR_RESOLUTION, AttributeValue::I32(n as i32)),
        (None, Some(r)) => (
            ATTR_RESOLUTIONS,
            AttributeValue::Text(Text::from(encode_resolutions(r).as_str())),
        ),
        (None, None) => unreachable!("a layout is uniform or per face"),
    };
    header
        .shared_attributes
        .other
        .insert(Text::from(key), value);
    let headers: exr::meta::Headers = SmallVec::from_elem(header, 1);

    let tile_bytes = names.len() * tw * th * 4;
    let threads = rayon::current_num_threads().max(1);
    // Two batches are in flight (one being written, one being computed).
    let batch_of = |bytes: usize| (bytes / tile_bytes.max(1)).clamp(threads, 4096).max(1);
    let batch = batch_of(batch_bytes);
    let total = layout.tile_count();

    if compression == Compression::Uncompressed && cfg!(target_endian = "little") && !via_crate {
        // A quarter of the batch: the two buffers are fresh memory held for the whole
        // file (two files at once at the end of `synth`), where the crate's vectors of
        // small tiles were reused from memory the allocator already held.
        let batch = batch_of(batch_bytes / 4);
        return write_uncompressed_tiles(
            path, &headers, &layout, &order, batch, fill, progress, on,
        );
    }

    write_atomic(path, |w| {
        exr::block::write(w, headers, true, |meta, writer| {
            // Fill and compress one batch of tiles on all threads.
            let compute = |start: usize| -> (usize, Vec<exr::error::Result<Chunk>>) {
                let end = (start + batch).min(total);
                let chunks = (start..end)
                    .into_par_iter()
                    .map_init(
                        || vec![0f32; names.len() * tw * th],
                        |buf, t| {
                            let mut data = vec![0u8; tile_bytes];
                            tile_block(&layout, &order, &fill, t, buf, &mut data);
                            let block = UncompressedBlock {
                                index: block_index(&layout, t),
                                data,
                            };
                            block.compress_to_chunk(&meta.headers)
                        },
                    )
                    .collect();
                (start, chunks)
            };
            // Pipeline: one thread writes batch k (in file order) while the others
            // compute batch k+1, so the writer is never the only thing running.
            let mut pending = Some(compute(0));
            let mut next = batch;
            while let Some((start, chunks)) = pending.take() {
                let count = chunks.len();
                let (written, following) = rayon::join(
                    || -> exr::error::UnitResult {
                        for (i, chunk) in chunks.into_iter().enumerate() {
                            writer.write_chunk(start + i, chunk?)?;
                        }
                        Ok(())
                    },
                    || (next < total).then(|| compute(next)),
                );
                written?;
                progress((start + count).min(layout.faces()));
                pending = following;
                next += batch;
            }
            Ok(())
        })
        .map_err(|e| Error::file(path, format!("cannot write EXR: {e}")))
    })
}

fn block_index(layout: &TileLayout, t: usize) -> BlockIndex {
    let (tw, th) = layout.tile;
    BlockIndex {
        layer: 0,
        pixel_position: Vec2((t % layout.columns) * tw, (t / layout.columns) * th),
        pixel_size: Vec2(tw, th),
        level: Vec2(0, 0),
    }
}

/// Uncompressed tiles written without the exr crate's chunk writer, the same bytes: the
/// crate takes every chunk's pixels as a vector of its own, and at N = 128 each tile (0.3
/// MiB for facemaps.exr, 0.6 MiB for geometry.exr) is above the allocator's 128 KiB
/// mapping threshold ([`crate::memory::tune_allocator`]) — a fresh mapping per tile, faulted
/// in page by page and unmapped again. Uncompressed chunks all have the same size, so the
/// offset table is known up front: the header (the crate's own validation and header
/// writer), the table, then the chunks, each batch filled in file layout (tile
/// coordinates, level, byte count, pixels) into one of two buffers allocated once and
/// reused, one written while the other is filled (on the pool; filled by the calling
/// thread between writes with [`TileThreads::Caller`]).
#[allow(clippy::too_many_arguments)]
fn write_uncompressed_tiles<F>(
    path: &Path,
    headers: &[Header],
    layout: &TileLayout,
    order: &[usize],
    batch: usize,
    fill: F,
    progress: &(dyn Fn(usize) + Sync),
    threads: TileThreads,
) -> Result<()>
where
    F: Fn(usize, &mut [f32]) + Sync,
{
    use std::io::Write;
    let exr_err = |e: exr::error::Error| Error::file(path, format!("cannot write EXR: {e}"));
    let io_err = |e: std::io::Error| Error::io(path, "cannot write", e);
    let (tw, th) = layout.tile;
    let channels = order.len();
    let tile_bytes = channels * tw * th * 4;
    let size = i32::try_from(tile_bytes)
        .map_err(|_| Error::file(path, "cannot write EXR: a tile of more than 2 GiB"))?;
    // Tile x, tile y, level x, level y, byte count: five little-endian i32.
    const CHUNK_HEAD: usize = 20;
    let chunk_bytes = CHUNK_HEAD + tile_bytes;
    let total = layout.tile_count();

    let mut head = Vec::new();
    let requirements = MetaData::validate(headers, true).map_err(exr_err)?;
    exr::meta::magic_number::write(&mut head).map_err(exr_err)?;
    requirements.write(&mut head).map_err(exr_err)?;
    Header::write_all(headers, &mut head, requirements.has_multiple_layers).map_err(exr_err)?;
    let first = head.len() + total * 8;
    for t in 0..total {
        head.extend_from_slice(&((first + t * chunk_bytes) as u64).to_le_bytes());
    }

    // Chunk of tile t: its head (tile coordinates, level, byte count) and pixels.
    let fill_chunk = |t: usize, buf: &mut Vec<f32>, chunk: &mut [u8]| {
        let (c, r) = (t % layout.columns, t / layout.columns);
        let (head, data) = chunk.split_at_mut(CHUNK_HEAD);
        for (d, v) in head
            .chunks_exact_mut(4)
            .zip([c as i32, r as i32, 0, 0, size])
        {
            d.copy_from_slice(&v.to_le_bytes());
        }
        tile_block(layout, order, &fill, t, buf, data);
    };
    let scratch = || vec![0f32; channels * tw * th];
    let compute = |start: usize, out: &mut Vec<u8>| {
        let end = (start + batch).min(total);
        out.resize((end - start) * chunk_bytes, 0);
        out.par_chunks_mut(chunk_bytes)
            .enumerate()
            .for_each_init(scratch, |buf, (i, chunk)| fill_chunk(start + i, buf, chunk));
    };

    write_atomic(path, |w| {
        w.write_all(&head).map_err(io_err)?;
        if threads == TileThreads::Caller {
            // Each chunk filled straight into the writer's block (no batch buffers, no
            // copy of every byte from them into the block); the few that straddle the
            // end of a block through a chunk-sized buffer.
            let (mut buf, mut spill) = (scratch(), Vec::new());
            for t in 0..total {
                let put = |chunk: &mut [u8]| fill_chunk(t, &mut buf, chunk);
                if !w.write_in_place(chunk_bytes, put).map_err(io_err)? {
                    spill.resize(chunk_bytes, 0);
                    fill_chunk(t, &mut buf, &mut spill);
                    w.write_all(&spill).map_err(io_err)?;
                }
                if (t + 1) % batch == 0 || t + 1 == total {
                    progress((t + 1).min(layout.faces()));
                }
            }
            return w.flush().map_err(io_err);
        }
        let (mut current, mut following) = (Vec::new(), Vec::new());
        compute(0, &mut current);
        let mut start = 0;
        while start < total {
            let next = start + batch;
            let fill_next = || {
                if next < total {
                    compute(next, &mut following);
                }
            };
            rayon::join(|| w.write_all(&current), fill_next)
                .0
                .map_err(io_err)?;
            progress(next.min(total).min(layout.faces()));
            std::mem::swap(&mut current, &mut following);
            start = next;
        }
        w.flush().map_err(io_err)
    })
}

/// Tile `t`'s pixel bytes into `out`: its domain's texels from `fill` (nothing past the
/// last face: padding tiles are zero), in EXR block order ([`interleave_rows`]). `buf` is
/// scratch of a whole tile's floats.
fn tile_block<F>(
    layout: &TileLayout,
    order: &[usize],
    fill: &F,
    t: usize,
    buf: &mut [f32],
    out: &mut [u8],
) where
    F: Fn(usize, &mut [f32]),
{
    let dims = if t < layout.faces() {
        layout.texels.dims(t)
    } else {
        (0, 0)
    };
    let buf = &mut buf[..order.len() * dims.0 * dims.1];
    buf.fill(0.0);
    if t < layout.faces() {
        fill(t, buf);
    }
    interleave_rows(buf, order, dims, layout.tile, out);
}

/// EXR block byte order: for each of the tile's rows, each channel (sorted) contributes
/// its tile-width samples, native-endian (the exr crate converts to little-endian while
/// compressing; [`write_uncompressed_tiles`] writes them as they are, little-endian
/// machines only). `buf` holds the domain's `(nu, nv)` texels per channel; the rest of the
/// tile (`out`, `order.len()·tw·th·4` bytes) is set to zero.
fn interleave_rows(
    buf: &[f32],
    order: &[usize],
    (nu, nv): (usize, usize),
    (tw, th): (usize, usize),
    out: &mut [u8],
) {
    let nn = nu * nv;
    debug_assert_eq!(out.len(), order.len() * tw * th * 4);
    // Padding (texels beyond the domain) is zeroed; each row's samples are copied into
    // place 4 bytes at a time over zipped slices (vectorized).
    if (nu, nv) != (tw, th) {
        out.fill(0);
    }
    for (y, row) in out
        .chunks_exact_mut(order.len() * tw * 4)
        .take(nv)
        .enumerate()
    {
        for (&k, dst) in order.iter().zip(row.chunks_exact_mut(tw * 4)) {
            let src = &buf[k * nn + y * nu..k * nn + (y + 1) * nu];
            for (d, v) in dst.chunks_exact_mut(4).zip(src) {
                d.copy_from_slice(&v.to_ne_bytes());
            }
        }
    }
}

/// The [`ATTR_RESOLUTIONS`] string of per-face resolutions.
pub fn encode_resolutions(r: &[Resolution]) -> String {
    const HEX: &[u8; 16] = b"0123456789abcdef";
    let mut s = String::with_capacity(2 * r.len());
    for r in r {
        s.push(HEX[r.log2_u() as usize] as char);
        s.push(HEX[r.log2_v() as usize] as char);
    }
    s
}

/// Parses an [`ATTR_RESOLUTIONS`] string of `faces` domains.
pub fn decode_resolutions(s: &str, faces: usize) -> std::result::Result<Vec<Resolution>, String> {
    let b = s.as_bytes();
    if b.len() != 2 * faces {
        return Err(format!(
            "{ATTR_RESOLUTIONS} has {} digits, expected 2 per face ({})",
            b.len(),
            2 * faces
        ));
    }
    b.chunks_exact(2)
        .map(|p| {
            let digit = |c: u8| (c as char).to_digit(16).map(|d| d as u8);
            match (digit(p[0]), digit(p[1])) {
                (Some(a), Some(b)) => Resolution::new(a, b),
                _ => None,
            }
            .ok_or_else(|| {
                format!(
                    "{ATTR_RESOLUTIONS} has '{}{}', not two log2 sides up to 2^{}",
                    p[0] as char,
                    p[1] as char,
                    crate::layout::MAX_LOG2
                )
            })
        })
        .collect()
}

fn open(path: &Path) -> Result<exr::block::reader::Reader<BufReader<File>>> {
    let file = File::open(path).map_err(|e| Error::io(path, "cannot open", e))?;
    exr::block::read(BufReader::new(file), false)
        .map_err(|e| Error::file(path, format!("not a readable OpenEXR file: {e}")))
}

/// Checks that the header describes face maps and returns their description.
fn face_maps_header(path: &Path, headers: &[Header]) -> Result<(TileLayout, FaceMapsInfo)> {
    let bad = |what: String| Error::file(path, format!("not a surfsynth face-map file: {what}"));
    if headers.len() != 1 {
        return Err(bad(format!("{} parts, expected 1", headers.len())));
    }
    let h = &headers[0];
    let get_int = |name: &str| -> Result<usize> {
        let key = Text::from(name);
        match h
            .own_attributes
            .other
            .get(&key)
            .or_else(|| h.shared_attributes.other.get(&key))
        {
            Some(AttributeValue::I32(v)) if *v >= 1 => Ok(*v as usize),
            Some(v) => Err(bad(format!("header attribute {name} is {v:?}"))),
            None => Err(bad(format!("header attribute {name} is missing"))),
        }
    };
    let faces = get_int(ATTR_FACES)?;
    let per_face = h
        .own_attributes
        .other
        .get(&Text::from(ATTR_RESOLUTIONS))
        .or_else(|| h.shared_attributes.other.get(&Text::from(ATTR_RESOLUTIONS)));
    let texels = match per_face {
        Some(AttributeValue::Text(t)) => {
            TexelLayout::per_face(decode_resolutions(&t.to_string(), faces).map_err(bad)?)
        }
        Some(v) => return Err(bad(format!("header attribute {ATTR_RESOLUTIONS} is {v:?}"))),
        None => {
            let resolution = get_int(ATTR_RESOLUTION)?;
            if resolution > MAX_RESOLUTION {
                return Err(bad(format!("resolution {resolution} is too large")));
            }
            TexelLayout::uniform(faces, resolution)
        }
    };
    let resolution = texels.uniform_n();
    let layout = TileLayout::of(Arc::new(texels));
    let (tw, th) = layout.tile;
    match h.blocks {
        BlockDescription::Tiles(t)
            if t.tile_size == Vec2(tw, th) && t.level_mode == LevelMode::Singular => {}
        _ => return Err(bad(format!("expected single-level tiles of {tw}x{th}"))),
    }
    if h.layer_size != Vec2(layout.width(), layout.height()) || h.deep {
        return Err(bad(format!(
            "data window is {}x{}, expected {}x{} for {faces} faces at {}",
            h.layer_size.0,
            h.layer_size.1,
            layout.width(),
            layout.height(),
            layout.texels.describe()
        )));
    }
    let info = FaceMapsInfo {
        faces,
        resolution,
        channels: h.channels.list.iter().map(|c| c.name.to_string()).collect(),
        compression: h.compression.to_string(),
    };
    Ok((layout, info))
}

/// Reads only the header of a face-map file.
pub fn read_face_maps_info(path: impl AsRef<Path>) -> Result<FaceMapsInfo> {
    let path = path.as_ref();
    let reader = open(path)?;
    Ok(face_maps_header(path, reader.headers())?.1)
}

/// Reads only the header of a face-map file: its tile layout (which texels the maps have)
/// and description, without a pixel (what `render`'s memory guard estimates from).
pub fn read_face_maps_layout(path: impl AsRef<Path>) -> Result<(TileLayout, FaceMapsInfo)> {
    let path = path.as_ref();
    let reader = open(path)?;
    face_maps_header(path, reader.headers())
}

/// Tiles [`read_face_maps`] decodes at once: ~64 MiB of them, at least one per thread.
pub fn read_batch_tiles(channels: usize, tile: (usize, usize)) -> usize {
    (((64usize << 20) / (channels * tile.0 * tile.1 * 4).max(1)).max(rayon::current_num_threads()))
        .max(1)
}

/// Reads a face-map file written by [`write_face_maps`] / [`write_tiles`] (or any file with
/// the same layout; f16 and u32 channels are converted to f32). Channels come back in file
/// (name-sorted) order.
pub fn read_face_maps(path: impl AsRef<Path>) -> Result<FaceMaps> {
    let path = path.as_ref();
    let reader = open(path)?;
    let (layout, info) = face_maps_header(path, reader.headers())?;
    let exr_err = |e: exr::error::Error| Error::file(path, format!("corrupt OpenEXR data: {e}"));
    let chunks = reader.all_chunks(false).map_err(exr_err)?;
    let meta: MetaData = chunks.meta_data().clone();
    let header = &meta.headers[0];
    let names: Vec<&str> = info.channels.iter().map(|s| s.as_str()).collect();
    let mut maps = FaceMaps::with_layout(layout.texels.clone(), &names);
    let (tw, th) = layout.tile;
    let batch = read_batch_tiles(names.len(), (tw, th));
    let mut seen = vec![false; layout.tile_count()];

    let mut chunks = chunks.peekable();
    while chunks.peek().is_some() {
        let raw: Vec<Chunk> = chunks
            .by_ref()
            .take(batch)
            .collect::<exr::error::Result<_>>()
            .map_err(exr_err)?;
        let blocks: Vec<exr::error::Result<UncompressedBlock>> = raw
            .into_par_iter()
            .map(|c| UncompressedBlock::decompress_chunk(c, &meta, false))
            .collect();
        for block in blocks {
            let block = block.map_err(exr_err)?;
            let Vec2(px, py) = block.index.pixel_position;
            if block.index.pixel_size != Vec2(tw, th) || px % tw != 0 || py % th != 0 {
                return Err(Error::file(path, "tile does not match the face-map layout"));
            }
            let t = (py / th) * layout.columns + px / tw;
            if t >= seen.len() || seen[t] {
                return Err(Error::file(path, "duplicate or misplaced tile"));
            }
            seen[t] = true;
            if t >= layout.faces() {
                continue;
            }
            let (nu, nv) = layout.texels.dims(t);
            let start = layout.texels.start(t);
            let mut row = vec![0f32; tw];
            for line in block.lines(&header.channels) {
                let k = line.location.channel;
                let y = line.location.position.1 - py;
                if y >= nv {
                    continue;
                }
                let whole = nu == tw;
                let dst: &mut [f32] = if whole {
                    &mut maps.channels[k].1[start + y * nu..start + (y + 1) * nu]
                } else {
                    &mut row
                };
                match header.channels.list[k].sample_type {
                    SampleType::F32 => line.read_samples_into_slice(dst).map_err(exr_err)?,
                    SampleType::F16 => {
                        for (d, s) in dst.iter_mut().zip(line.read_samples::<exr::prelude::f16>()) {
                            *d = s.map_err(exr_err)?.to_f32();
                        }
                    }
                    SampleType::U32 => {
                        for (d, s) in dst.iter_mut().zip(line.read_samples::<u32>()) {
                            *d = s.map_err(exr_err)? as f32;
                        }
                    }
                }
                if !whole {
                    maps.channels[k].1[start + y * nu..start + (y + 1) * nu]
                        .copy_from_slice(&row[..nu]);
                }
            }
        }
    }
    if let Some(t) = seen.iter().position(|s| !s) {
        return Err(Error::file(
            path,
            format!("file is truncated: tile {t} is missing"),
        ));
    }
    Ok(maps)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The EXR block order by its definition (every row: each channel's tile-width
    /// samples, zeros beyond the domain), against `interleave_rows`, for tiles larger
    /// than the domain along u, v and both, and channels in any order.
    #[test]
    fn interleaved_rows_follow_the_block_order() {
        for ((nu, nv), (tw, th), order) in [
            ((4, 4), (4, 4), vec![0usize, 1, 2]),
            ((3, 2), (4, 4), vec![2, 0, 1]),
            ((1, 5), (8, 5), vec![1, 0]),
            ((6, 1), (6, 3), vec![0]),
        ] {
            let nn = nu * nv;
            let buf: Vec<f32> = (0..order.len() * nn)
                .map(|i| i as f32 * 1.5 - 7.0)
                .collect();
            let mut want = Vec::new();
            for y in 0..th {
                for &k in &order {
                    for x in 0..tw {
                        let v = if x < nu && y < nv {
                            buf[k * nn + y * nu + x]
                        } else {
                            0.0
                        };
                        want.extend_from_slice(&v.to_ne_bytes());
                    }
                }
            }
            // Into a buffer holding other bytes: padding is zeroed.
            let mut out = vec![0xA5u8; want.len()];
            interleave_rows(&buf, &order, (nu, nv), (tw, th), &mut out);
            assert_eq!(out, want);
        }
    }

    #[test]
    fn a_non_finite_value_is_found_naming_its_texel() {
        for bad in [f32::NAN, f32::INFINITY, f32::NEG_INFINITY] {
            let mut m = FaceMaps::new(3, 4, &["R", "G"]);
            m.channel_mut("G").unwrap()[2 * 16 + 4 + 3] = bad;
            let e = check_finite("channel 'G'", m.channel("G").unwrap(), &m.layout)
                .unwrap_err()
                .to_string();
            assert!(
                e.contains("'G'") && e.contains("domain 2") && e.contains("(3, 1)"),
                "{e}"
            );
        }
        let m = FaceMaps::new(3, 4, &["R"]);
        assert!(check_finite("R", m.channel("R").unwrap(), &m.layout).is_ok());
        // Beyond the first work chunk, two bad values: the first one is named.
        let mut m = FaceMaps::new(3, 128, &["R"]);
        let r = m.channel_mut("R").unwrap();
        r[2 * 128 * 128 + 56 * 128 + 32] = f32::NAN;
        r[2 * 128 * 128 + 60 * 128] = f32::NAN;
        let e = check_finite("R", m.channel("R").unwrap(), &m.layout)
            .unwrap_err()
            .to_string();
        assert!(e.contains("domain 2") && e.contains("(32, 56)"), "{e}");
    }

    #[test]
    fn layout_follows_the_brief() {
        let l = TileLayout::new(6, 8);
        assert_eq!(l.tile, (8, 8));
        assert_eq!((l.columns, l.rows, l.width(), l.height()), (3, 2, 24, 16));
        assert_eq!(l.tile_origin(4), (8, 8));
        let l = TileLayout::new(10, 4);
        assert_eq!((l.columns, l.rows), (4, 3));
        assert_eq!(TileLayout::new(1, 3).tile_count(), 1);
        for f in 1..2000usize {
            let c = ceil_sqrt(f);
            assert!(c * c >= f && (c - 1) * (c - 1) < f, "{f}");
        }
    }

    fn sample_maps(faces: usize, n: usize) -> FaceMaps {
        // Deliberately unsorted names, with values that identify (channel, face, x, y).
        let mut m = FaceMaps::new(faces, n, &["source.u", "R", "height", "B", "A", "G"]);
        for (k, (_, d)) in m.channels.iter_mut().enumerate() {
            for (i, v) in d.iter_mut().enumerate() {
                *v = (k as f32 * 1000.0 + i as f32).sqrt() * if i % 3 == 0 { -1.0 } else { 1.0 };
            }
        }
        m
    }

    #[test]
    fn round_trip_every_lossless_compression() {
        let d = tempfile::tempdir().unwrap();
        for (faces, n) in [(7usize, 5usize), (1, 1), (16, 4), (3, 16)] {
            let m = sample_maps(faces, n);
            for c in [
                Compression::Uncompressed,
                Compression::RLE,
                Compression::ZIP1,
                Compression::ZIP16,
                Compression::PIZ,
            ] {
                let p = d.path().join(format!("m{faces}_{n}_{c:?}.exr"));
                write_face_maps_with(&p, &m, c).unwrap();
                let r = read_face_maps(&p).unwrap();
                assert_eq!((r.faces(), r.uniform_n()), (faces, Some(n)));
                assert_eq!(r.names(), vec!["A", "B", "G", "R", "height", "source.u"]);
                for (name, data) in &m.channels {
                    let got = r.channel(name).unwrap();
                    assert!(
                        got.iter()
                            .zip(data)
                            .all(|(a, b)| a.to_bits() == b.to_bits()),
                        "{name} {c:?}"
                    );
                }
                let info = read_face_maps_info(&p).unwrap();
                assert_eq!((info.faces, info.resolution), (faces, Some(n)));
            }
        }
    }

    /// Reads our file with the exr crate's high-level reader (a separate code path from
    /// our block-level reader) and checks layout, attributes and zeroed unused tiles.
    #[test]
    fn generic_reader_sees_the_brief_layout() {
        use exr::prelude::*;
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("g.exr");
        let (faces, n) = (7usize, 3usize);
        let m = sample_maps(faces, n);
        write_face_maps(&p, &m).unwrap();
        let img = read_all_flat_layers_from_file(&p).unwrap();
        assert_eq!(img.layer_data.len(), 1);
        let layer = &img.layer_data[0];
        assert_eq!(layer.size, Vec2(9, 9)); // C = 3, rows = 3
        assert_eq!(
            layer.attributes.other.get(&Text::from(ATTR_FACES)),
            Some(&AttributeValue::I32(7))
        );
        assert_eq!(
            layer.attributes.other.get(&Text::from(ATTR_RESOLUTION)),
            Some(&AttributeValue::I32(3))
        );
        assert_eq!(
            layer.encoding.blocks,
            Blocks::Tiles(Vec2(3, 3)),
            "one tile per face"
        );
        let layout = TileLayout::new(faces, n);
        for ch in &layer.channel_data.list {
            let name = ch.name.to_string();
            let src = m.channel(&name).unwrap();
            let FlatSamples::F32(flat) = &ch.sample_data else {
                panic!("{name} is not f32")
            };
            for py in 0..9 {
                for px in 0..9 {
                    let (col, row) = (px / n, py / n);
                    let f = row * layout.columns + col;
                    let want = if f < faces {
                        src[m.index(f, px % n, py % n)]
                    } else {
                        0.0
                    };
                    assert_eq!(
                        flat[py * 9 + px].to_bits(),
                        want.to_bits(),
                        "{name} {px} {py}"
                    );
                }
            }
        }
    }

    #[test]
    fn per_face_resolutions_round_trip_and_sit_at_their_tiles_top_left() {
        use exr::prelude::*;
        let r = |a, b| Resolution::new(a, b).unwrap();
        let texels = Arc::new(TexelLayout::per_face(vec![
            r(2, 1),
            r(0, 0),
            r(3, 3),
            r(1, 3),
        ]));
        let mut m = FaceMaps::with_layout(texels.clone(), &["R", "source.u"]);
        for (k, (_, d)) in m.channels.iter_mut().enumerate() {
            for (i, v) in d.iter_mut().enumerate() {
                *v = 1.0 + k as f32 * 100.0 + i as f32;
            }
        }
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("v.exr");
        write_face_maps(&p, &m).unwrap();
        let back = read_face_maps(&p).unwrap();
        assert_eq!(back.layout, texels);
        assert_eq!(back.channel("R"), m.channel("R"));
        assert_eq!(back.channel("source.u"), m.channel("source.u"));
        let info = read_face_maps_info(&p).unwrap();
        assert_eq!((info.faces, info.resolution), (4, None));
        // The generic reader: tiles of the largest face (8x8), 2x2 of them, each face's
        // texels at the top-left, zero elsewhere, the resolutions in the header.
        let img = read_all_flat_layers_from_file(&p).unwrap();
        let layer = &img.layer_data[0];
        assert_eq!(layer.size, Vec2(16, 16));
        assert_eq!(layer.encoding.blocks, Blocks::Tiles(Vec2(8, 8)));
        assert_eq!(
            layer.attributes.other.get(&Text::from(ATTR_RESOLUTIONS)),
            Some(&AttributeValue::Text(Text::from("21003313")))
        );
        let ch = layer
            .channel_data
            .list
            .iter()
            .find(|c| c.name.eq("R"))
            .unwrap();
        let FlatSamples::F32(flat) = &ch.sample_data else {
            panic!("not f32")
        };
        let tiles = TileLayout::of(texels.clone());
        for f in 0..4 {
            let (x0, y0) = tiles.tile_origin(f);
            let (nu, nv) = texels.dims(f);
            for y in 0..8 {
                for x in 0..8 {
                    let got = flat[(y0 + y) * 16 + x0 + x];
                    let want = if x < nu && y < nv {
                        m.channel("R").unwrap()[texels.index(f, x, y)]
                    } else {
                        0.0
                    };
                    assert_eq!(got, want, "face {f} ({x}, {y})");
                }
            }
        }
        // A damaged resolution string is a one-line error, not a panic.
        assert!(decode_resolutions("21z0", 2).is_err());
        assert!(decode_resolutions("210", 2).is_err());
        assert!(decode_resolutions("e0", 1).is_err());
    }

    /// The uncompressed tiles written directly are the exr crate's bytes: uniform maps
    /// (with unused tiles in the last row), per-face resolutions (padded tiles), an extra
    /// attribute, batches of one tile and of many, 1 and 3 threads, tiles filled on the
    /// pool and on the calling thread.
    #[test]
    fn direct_uncompressed_tiles_are_the_crates_bytes() {
        let d = tempfile::tempdir().unwrap();
        let uniform = sample_maps(23, 6);
        let per_face = {
            let r: Vec<Resolution> = (0..7u8)
                .map(|f| Resolution::new(f % 3 + 1, f % 2 + 1).unwrap())
                .collect();
            let mut m = FaceMaps::with_layout(Arc::new(TexelLayout::per_face(r)), &["Y", "A"]);
            for (k, (_, d)) in m.channels.iter_mut().enumerate() {
                for (i, v) in d.iter_mut().enumerate() {
                    *v = i as f32 * 0.25 - k as f32;
                }
            }
            m
        };
        for maps in [&uniform, &per_face] {
            let names = maps.names();
            let fill = |f: usize, tile: &mut [f32]| {
                let r = maps.layout.range(f);
                let nn = r.len();
                for (k, (_, data)) in maps.channels.iter().enumerate() {
                    tile[k * nn..(k + 1) * nn].copy_from_slice(&data[r.clone()]);
                }
            };
            for (threads, batch_bytes) in [(1, BATCH_BYTES), (3, BATCH_BYTES), (2, 1000)] {
                let pool = rayon::ThreadPoolBuilder::new()
                    .num_threads(threads)
                    .build()
                    .unwrap();
                let mut files = Vec::new();
                for (via_crate, on) in [
                    (false, TileThreads::Pool),
                    (true, TileThreads::Pool),
                    (false, TileThreads::Caller),
                ] {
                    let p = d.path().join(format!("{via_crate}-{on:?}.exr"));
                    pool.install(|| {
                        write_tiles_by(
                            &p,
                            maps.tiles(),
                            &names,
                            Compression::Uncompressed,
                            &[("zz.extra", -3)],
                            fill,
                            &|_| {},
                            (batch_bytes, via_crate, on),
                        )
                    })
                    .unwrap();
                    files.push(std::fs::read(&p).unwrap());
                }
                assert!(files[0] == files[1], "direct and crate bytes differ");
                assert!(files[0] == files[2], "tiles filled by the caller differ");
                let back = read_face_maps(d.path().join("false-Pool.exr")).unwrap();
                assert_eq!(back.layout, maps.layout);
            }
        }
    }

    #[test]
    fn streaming_output_is_independent_of_thread_count() {
        let d = tempfile::tempdir().unwrap();
        let m = sample_maps(23, 6);
        let mut files = Vec::new();
        for threads in [1, 2, 3] {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            let p = d.path().join(format!("t{threads}.exr"));
            pool.install(|| write_face_maps(&p, &m)).unwrap();
            files.push(std::fs::read(&p).unwrap());
        }
        assert!(files[0] == files[1], "1 vs 2 threads differ");
        assert!(files[0] == files[2], "1 vs 3 threads differ");
    }

    #[test]
    fn bad_inputs_are_reported() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("x.exr");
        let mut m = sample_maps(2, 2);
        m.channels[0].1.pop();
        assert!(write_face_maps(&p, &m).is_err());
        assert!(!p.exists());
        let m = FaceMaps::new(2, 2, &["R", "R"]);
        assert!(write_face_maps(&p, &m).is_err());
        std::fs::write(&p, b"not an exr").unwrap();
        let e = read_face_maps(&p).unwrap_err().to_string();
        assert!(e.starts_with(&p.display().to_string()), "{e}");
        let e = read_face_maps(d.path().join("missing.exr"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("cannot open"), "{e}");
        // A truncated file is an error, not a panic.
        let m = sample_maps(5, 4);
        write_face_maps_with(&p, &m, Compression::Uncompressed).unwrap();
        let bytes = std::fs::read(&p).unwrap();
        std::fs::write(&p, &bytes[..bytes.len() - 100]).unwrap();
        assert!(read_face_maps(&p).is_err());
    }
}
