//! Writes a Ptex file from per-face planar f32 data, streaming.
//!
//! The format puts every table before the data it describes (face infos, which carry the
//! constant flag, then constant values, then per level the block sizes, then the blocks),
//! and what a table holds is known only once every face's data was looked at. The
//! reference writer therefore writes all data to a temporary file and copies it behind the
//! tables. We instead make two passes over the faces, both parallel and deterministic:
//!
//! 1. *plan*: fill each face, test it for constancy, build its reduction chain and its
//!    constant value, and encode every block to learn its size — keeping only the blocks of
//!    levels ≥ 2 (together 1/12 of the data);
//! 2. *write*: the tables, then the blocks in file order, levels 0 and 1 encoded again in
//!    batches (the face data filled anew) while the previous batch is written.
//!
//! Memory stays at two batches of blocks plus the small levels, whatever the number of
//! faces, and the bytes do not depend on the number of threads. Encoding twice costs only
//! a copy with the default stored deflate blocks (level 0, see docs/formats.md).

use super::format::{self, *};
use super::neighbourhood::constant_neighbourhood;
use super::texels;
use crate::error::{Error, Result};
use crate::io::atomic::AtomicFile;
use rayon::prelude::*;
use std::io::Write;
use std::path::Path;

/// How to write the file.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PtexOptions {
    /// Deflate level of the face data, 0 (stored blocks: fastest, the size of the raw
    /// floats) to 9. Level 0 is the default: on synthesized float maps levels 1–9 save
    /// 12–13% at 50–60 MB/s per core (docs/formats.md). The small tables are always
    /// compressed.
    pub zlib_level: u32,
    /// Store the reductions (mip levels) down to 4 texels on the smaller side, as the
    /// reference writer does by default; renderers filter from them.
    pub mipmaps: bool,
}

impl Default for PtexOptions {
    fn default() -> Self {
        Self {
            zlib_level: 0,
            mipmaps: true,
        }
    }
}

/// A meta data value (`PtexMetaData` types the project uses).
#[derive(Clone, Debug, PartialEq)]
pub enum MetaValue {
    String(String),
    Int32(Vec<i32>),
    Float(Vec<f32>),
}

impl MetaValue {
    fn encode(&self) -> (u8, Vec<u8>) {
        match self {
            MetaValue::String(s) => {
                let mut b = s.as_bytes().to_vec();
                b.push(0);
                (MDT_STRING, b)
            }
            MetaValue::Int32(v) => (MDT_INT32, v.iter().flat_map(|x| x.to_le_bytes()).collect()),
            MetaValue::Float(v) => (MDT_FLOAT, v.iter().flat_map(|x| x.to_le_bytes()).collect()),
        }
    }
}

/// A Ptex texture to write: per-face records and the channel layout. The texels come
/// from a callback, so per-face resolutions (each face its own `res`, u and v apart) need
/// no common storage.
#[derive(Clone, Debug)]
pub struct PtexImage<'a> {
    /// One record per face, in face id order (see [`super::face_infos`]).
    pub faces: &'a [FaceInfo],
    /// Channels per texel (all f32).
    pub channels: usize,
    /// The alpha channel, if any: colour channels are premultiplied for the reductions.
    pub alpha: Option<usize>,
    /// Meta data entries, written in this order.
    pub meta: Vec<(String, MetaValue)>,
}

/// What [`write_ptex`] wrote.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct PtexSummary {
    pub faces: usize,
    /// Resolution levels (1 = no reductions).
    pub levels: usize,
    pub constant_faces: usize,
    /// File size.
    pub bytes: u64,
}

/// Pass-1 result for one face.
struct Plan {
    constant: bool,
    /// The constant value (for constant faces the texel itself, else the mean of the last
    /// reduction, un-premultiplied).
    value: Vec<f32>,
    /// Data header per level the face is in (level 0 first).
    fdh: Vec<u32>,
    /// Encoded blocks of levels 2, 3, … (kept: small).
    small: Vec<Vec<u8>>,
}

thread_local! {
    /// The tiled encoding's scratch for a face's tile bytes, reused by each thread from
    /// face to face: at N = 128 it grows to ~0.3 MiB, above the allocator's mapping
    /// threshold (`memory::tune_allocator`), so a fresh vector per face was mapped, faulted
    /// in page by page and unmapped again every time.
    static BODY: std::cell::Cell<Vec<u8>> = const { std::cell::Cell::new(Vec::new()) };
}

/// Encodes one face (or reduction) of planar data as the reference's `writeFaceData`
/// does: one zipped block, or tiles when it is large. Returns the data header. With
/// `out = None` only the size is wanted: at level 0 (stored blocks) it follows from the
/// data's length, so nothing is encoded.
fn encode(
    data: &[f32],
    res: Res,
    nch: usize,
    level: u32,
    out: Option<&mut Vec<u8>>,
) -> Result<u32> {
    if out.is_none() && level == 0 && format::tile_res(res, nch * 4).is_none() {
        let size = format::stored_len(data.len() * 4) as u64;
        return Ok(data_header(size as u32, Encoding::Zipped));
    }
    let mut scratch = Vec::new();
    let measure_only = out.is_none();
    let out = out.unwrap_or(&mut scratch);
    let start = out.len();
    let enc = match format::tile_res(res, nch * 4) {
        None => {
            zip_into(&texels::le_bytes(data), level, out);
            Encoding::Zipped
        }
        Some(t) => {
            let (nu, nv) = (res.u() / t.u(), res.v() / t.v());
            let mut headers = Vec::with_capacity(nu * nv * 4);
            // The tiles' bytes, kept per thread between faces (see `BODY`).
            let mut body = BODY.take();
            body.clear();
            for tv in 0..nv {
                for tu in 0..nu {
                    let tile = texels::tile(data, res, t, tu, tv);
                    let fdh = if texels::is_constant(&tile, t.size()) {
                        body.extend_from_slice(&texels::bytes(&texels::pixel(&tile, t.size(), 0)));
                        data_header((nch * 4) as u32, Encoding::Constant)
                    } else if measure_only && level == 0 {
                        data_header(format::stored_len(tile.len() * 4) as u32, Encoding::Zipped)
                    } else {
                        let n = zip_into(&texels::le_bytes(&tile), level, &mut body);
                        data_header(n as u32, Encoding::Zipped)
                    };
                    headers.extend_from_slice(&fdh.to_le_bytes());
                }
            }
            let zipped_headers = zip(&headers, 6);
            out.push(t.ulog2);
            out.push(t.vlog2);
            out.extend_from_slice(&(zipped_headers.len() as u32).to_le_bytes());
            out.extend_from_slice(&zipped_headers);
            if measure_only {
                // The tiles' sizes are in their headers; their bytes are not needed.
                let body_len: u64 = headers
                    .chunks_exact(4)
                    .map(|h| block_size(u32::from_le_bytes(h.try_into().unwrap())) as u64)
                    .sum();
                let size = (out.len() - start) as u64 + body_len;
                if size > MAX_BLOCK {
                    return Err(Error::invalid(format!(
                        "a Ptex face block of {size} bytes exceeds the format's {MAX_BLOCK}"
                    )));
                }
                BODY.set(body);
                return Ok(data_header(size as u32, Encoding::Tiled));
            }
            out.extend_from_slice(&body);
            BODY.set(body);
            Encoding::Tiled
        }
    };
    let size = (out.len() - start) as u64;
    if size > MAX_BLOCK {
        return Err(Error::invalid(format!(
            "a Ptex face block of {size} bytes exceeds the format's {MAX_BLOCK}"
        )));
    }
    Ok(data_header(size as u32, enc))
}

/// Levels a non-constant face of `res` appears in (1 + its reductions).
fn face_levels(res: Res, mipmaps: bool) -> usize {
    let m = res.min_log2();
    if mipmaps && m > MIN_REDUCTION_LOG2 {
        1 + (m - MIN_REDUCTION_LOG2) as usize
    } else {
        1
    }
}

/// Pass 1 for face `f` (see the module doc).
fn plan_face(
    img: &PtexImage,
    opts: &PtexOptions,
    f: usize,
    fill: &(impl Fn(usize, &mut [f32]) + Sync),
    scratch: &mut Vec<f32>,
) -> Result<Plan> {
    let res = img.faces[f].res;
    let (nch, npix) = (img.channels, res.size());
    let data = filled(scratch, nch * npix, f, fill);
    if texels::is_constant(data, npix) {
        return Ok(Plan {
            constant: true,
            value: texels::pixel(data, npix, 0),
            fdh: vec![0],
            small: Vec::new(),
        });
    }
    let mut fdh = vec![encode(data, res, nch, opts.zlib_level, None)?];
    if let Some(a) = img.alpha {
        texels::premultiply(data, npix, nch, a);
    }
    let mut small = Vec::new();
    let mut cur: std::borrow::Cow<[f32]> = std::borrow::Cow::Borrowed(data);
    let mut cur_res = res;
    for level in 1..face_levels(res, opts.mipmaps) {
        cur = texels::reduce(&cur, cur_res, nch).into();
        cur_res = cur_res.reduced(1);
        if level >= 2 {
            let mut block = Vec::new();
            fdh.push(encode(
                &cur,
                cur_res,
                nch,
                opts.zlib_level,
                Some(&mut block),
            )?);
            small.push(block);
        } else {
            fdh.push(encode(&cur, cur_res, nch, opts.zlib_level, None)?);
        }
    }
    let mut value = texels::average(&cur, cur_res.size());
    if let Some(a) = img.alpha {
        texels::divide_alpha(&mut value, a);
    }
    Ok(Plan {
        constant: false,
        value,
        fdh,
        small,
    })
}

/// Face `f`'s texels from `fill`, in `scratch` (a thread's buffer, reused from face to
/// face: zeroed to `len` values as `fill` expects, without a fresh allocation — at N = 128
/// one face is ~0.3 MiB, which the allocator maps and unmaps anew every time).
fn filled<'s>(
    scratch: &'s mut Vec<f32>,
    len: usize,
    f: usize,
    fill: &(impl Fn(usize, &mut [f32]) + Sync),
) -> &'s mut [f32] {
    scratch.clear();
    scratch.resize(len, 0.0);
    fill(f, scratch);
    scratch
}

/// Level 0 or 1 block of face `f` again (pass 2): `size` bytes, into `out` (cleared; a
/// buffer recycled from an earlier batch, so that at N = 128 a face's ~0.3 MiB is not a
/// fresh mapping faulted in page by page every time).
#[allow(clippy::too_many_arguments)]
fn block(
    img: &PtexImage,
    opts: &PtexOptions,
    level: usize,
    f: usize,
    fill: &(impl Fn(usize, &mut [f32]) + Sync),
    scratch: &mut Vec<f32>,
    size: usize,
    out: &mut Vec<u8>,
) -> Result<()> {
    let res = img.faces[f].res;
    let (nch, npix) = (img.channels, res.size());
    let data = filled(scratch, nch * npix, f, fill);
    out.clear();
    out.reserve(size);
    if level == 0 {
        encode(data, res, nch, opts.zlib_level, Some(out))?;
    } else {
        if let Some(a) = img.alpha {
            texels::premultiply(data, npix, nch, a);
        }
        let r = texels::reduce(data, res, nch);
        encode(&r, res.reduced(1), nch, opts.zlib_level, Some(out))?;
    }
    Ok(())
}

fn check(img: &PtexImage) -> Result<()> {
    if img.faces.is_empty() || img.faces.len() > i32::MAX as usize {
        return Err(Error::invalid(format!(
            "a Ptex file needs 1 to {} faces, not {}",
            i32::MAX,
            img.faces.len()
        )));
    }
    if img.channels == 0 || img.channels > u16::MAX as usize {
        return Err(Error::invalid("a Ptex file needs 1 to 65535 channels"));
    }
    if img.alpha.is_some_and(|a| a >= img.channels) {
        return Err(Error::invalid(
            "the Ptex alpha channel is not one of the channels",
        ));
    }
    for (f, i) in img.faces.iter().enumerate() {
        if i.res.ulog2 > 15 || i.res.vlog2 > 15 {
            return Err(Error::invalid(format!(
                "Ptex face {f}: resolution 2^{} x 2^{} is above 2^15",
                i.res.ulog2, i.res.vlog2
            )));
        }
        if i.adj_faces.iter().any(|&a| a >= img.faces.len() as i32) {
            return Err(Error::invalid(format!(
                "Ptex face {f}: adjacent face out of range"
            )));
        }
    }
    for (k, _) in &img.meta {
        if k.is_empty() || k.len() > 254 || k.contains('\0') {
            return Err(Error::invalid(format!(
                "Ptex meta data key '{k}' is not 1 to 254 bytes"
            )));
        }
    }
    Ok(())
}

/// Texel bytes per batch of levels 0 and 1 in [`write_ptex`]. Two batches are in flight
/// (one written while the next is encoded), and at the end of `synth` they add to the maps,
/// the texel geometry, both EXR writers and the pf summary: 8 MiB (was 32) keeps a dozen
/// faces per thread at N = 128 and ~48 MiB off the end-of-run peak (docs/benchmarks.md,
/// "Spot at N = 128"). The file's bytes do not depend on it.
const BATCH_BYTES: usize = 8 << 20;

/// Writes `img` to `path` atomically; `fill(f, buf)` must put face f's texels into `buf`
/// (zeroed, `channels × u × v` values: channel-major, each channel row-major with u
/// fastest, row 0 at v = 0). `fill` is called from several threads, two or three times per
/// face, and must give the same texels every time.
pub fn write_ptex<F>(
    path: impl AsRef<Path>,
    img: &PtexImage,
    opts: &PtexOptions,
    fill: F,
) -> Result<PtexSummary>
where
    F: Fn(usize, &mut [f32]) + Sync,
{
    let path = path.as_ref();
    check(img)?;
    let nfaces = img.faces.len();
    let nch = img.channels;

    // Pass 1.
    let plans: Vec<Plan> = (0..nfaces)
        .into_par_iter()
        .map_init(Vec::new, |scratch, f| {
            plan_face(img, opts, f, &fill, scratch)
        })
        .collect::<Result<_>>()?;

    // Flags, including the constant neighbourhoods.
    let mut flags: Vec<u8> = plans
        .iter()
        .map(|p| if p.constant { FLAG_CONSTANT } else { 0 })
        .collect();
    let same = |a: usize, b: usize| {
        plans[a]
            .value
            .iter()
            .map(|v| v.to_bits())
            .eq(plans[b].value.iter().map(|v| v.to_bits()))
    };
    let nb: Vec<bool> = (0..nfaces)
        .map(|f| plans[f].constant && constant_neighbourhood(img.faces, &flags, f, same))
        .collect();
    for (fl, nb) in flags.iter_mut().zip(nb) {
        if nb {
            *fl |= FLAG_NBCONSTANT;
        }
    }

    // Reduction order: faces by decreasing smaller side (constant faces count as 2^1),
    // stable, as PtexUtils::genRfaceids — readers recompute it from the face infos.
    let key = |f: usize| {
        if plans[f].constant {
            1
        } else {
            img.faces[f].res.min_log2()
        }
    };
    let mut rfaces: Vec<usize> = (0..nfaces).collect();
    rfaces.sort_by_key(|&f| std::cmp::Reverse(key(f)));
    let nlevels = plans.iter().map(|p| p.fdh.len()).max().unwrap_or(1);
    // Level i holds the prefix of rfaces that has an i-th reduction.
    let level_faces: Vec<&[usize]> = (0..nlevels)
        .map(|i| {
            if i == 0 {
                &rfaces[..0]
            } else {
                let n = rfaces
                    .iter()
                    .take_while(|&&f| plans[f].fdh.len() > i)
                    .count();
                &rfaces[..n]
            }
        })
        .collect();
    let level_order = |i: usize| -> Vec<usize> {
        if i == 0 {
            (0..nfaces).collect()
        } else {
            level_faces[i].to_vec()
        }
    };

    // Tables.
    let mut face_bytes = Vec::with_capacity(nfaces * FACE_INFO_SIZE);
    for (info, &fl) in img.faces.iter().zip(&flags) {
        face_bytes.extend_from_slice(&info.to_bytes(fl));
    }
    let face_zip = zip(&face_bytes, 6);
    let const_bytes: Vec<u8> = plans.iter().flat_map(|p| texels::bytes(&p.value)).collect();
    let const_zip = zip(&const_bytes, 6);
    let mut levels = Vec::with_capacity(nlevels);
    for i in 0..nlevels {
        let order = level_order(i);
        let headers: Vec<u8> = order
            .iter()
            .flat_map(|&f| plans[f].fdh[i].to_le_bytes())
            .collect();
        let header_zip = zip(&headers, 6);
        let data: u64 = order
            .iter()
            .map(|&f| block_size(plans[f].fdh[i]) as u64)
            .sum();
        levels.push((
            LevelInfo {
                leveldatasize: header_zip.len() as u64 + data,
                levelheadersize: header_zip.len() as u32,
                nfaces: order.len() as u32,
            },
            header_zip,
            order,
        ));
    }

    // Meta data: small entries in one block, large ones in blocks of their own.
    let mut small_meta = Vec::new();
    let mut lmd_headers = Vec::new();
    let mut lmd_blocks = Vec::new();
    for (key, value) in &img.meta {
        let (t, data) = value.encode();
        if data.is_empty() {
            continue;
        }
        let entry_head = |buf: &mut Vec<u8>| {
            buf.push(key.len() as u8 + 1);
            buf.extend_from_slice(key.as_bytes());
            buf.push(0);
            buf.push(t);
            buf.extend_from_slice(&(data.len() as u32).to_le_bytes());
        };
        if data.len() > METADATA_THRESHOLD {
            let z = zip(&data, 6);
            entry_head(&mut lmd_headers);
            lmd_headers.extend_from_slice(&(z.len() as u32).to_le_bytes());
            lmd_blocks.push(z);
        } else {
            entry_head(&mut small_meta);
            small_meta.extend_from_slice(&data);
        }
    }
    let meta_zip = if small_meta.is_empty() {
        Vec::new()
    } else {
        zip(&small_meta, 6)
    };
    let lmd_zip = if lmd_headers.is_empty() {
        Vec::new()
    } else {
        zip(&lmd_headers, 6)
    };
    let lmd_data: u64 = lmd_blocks.iter().map(|b| b.len() as u64).sum();

    let leveldatasize: u64 = levels.iter().map(|l| l.0.leveldatasize).sum();
    let header = Header {
        alphachan: img.alpha.map_or(-1, |a| a as i32),
        nchannels: nch as u16,
        nlevels: nlevels as u16,
        nfaces: nfaces as u32,
        faceinfosize: face_zip.len() as u32,
        constdatasize: const_zip.len() as u32,
        levelinfosize: (LEVEL_INFO_SIZE * nlevels) as u32,
        leveldatasize,
        metadatazipsize: meta_zip.len() as u32,
        metadatamemsize: small_meta.len() as u32,
    };
    let total = (HEADER_SIZE + EXT_HEADER_SIZE + face_zip.len() + const_zip.len()) as u64
        + header.levelinfosize as u64
        + leveldatasize
        + meta_zip.len() as u64
        + 8
        + lmd_zip.len() as u64
        + lmd_data;
    let ext = ExtHeader {
        lmdheaderzipsize: lmd_zip.len() as u32,
        lmdheadermemsize: lmd_headers.len() as u32,
        lmddatasize: lmd_data,
        editdatapos: total,
    };

    // Pass 2: write.
    let mut file = AtomicFile::create(path)?;
    let io = |e: std::io::Error| Error::io(path, "cannot write", e);
    {
        let w = file.writer();
        w.write_all(&header.to_bytes()).map_err(io)?;
        w.write_all(&ext.to_bytes()).map_err(io)?;
        w.write_all(&face_zip).map_err(io)?;
        w.write_all(&const_zip).map_err(io)?;
        for (info, _, _) in &levels {
            w.write_all(&info.to_bytes()).map_err(io)?;
        }
    }
    for (i, (_, header_zip, order)) in levels.iter().enumerate() {
        file.writer().write_all(header_zip).map_err(io)?;
        if i >= 2 {
            for &f in order {
                file.writer()
                    .write_all(&plans[f].small[i - 2])
                    .map_err(io)?;
            }
            continue;
        }
        // Levels 0 and 1: encode again, batch by batch (~BATCH_BYTES of texels each),
        // while the previous batch is written.
        let units: Vec<usize> = order
            .iter()
            .copied()
            .filter(|&f| !plans[f].constant)
            .collect();
        let mut batches = Vec::new();
        let mut start = 0;
        while start < units.len() {
            let mut bytes = 0usize;
            let mut end = start;
            while end < units.len() && (end == start || bytes < BATCH_BYTES) {
                bytes += (img.faces[units[end]].res.size() * nch * 4) >> (2 * i);
                end += 1;
            }
            batches.push(&units[start..end]);
            start = end;
        }
        // Each batch's blocks go into buffers recycled from the batch before the last
        // (two sets in flight: one written while the other is encoded).
        let compute = |b: &[usize], mut blocks: Vec<Vec<u8>>| -> Result<Vec<Vec<u8>>> {
            blocks.resize_with(b.len().max(blocks.len()), Vec::new);
            blocks.truncate(b.len());
            b.par_iter().zip(blocks.par_iter_mut()).try_for_each_init(
                Vec::new,
                |scratch, (&f, out)| {
                    let size = block_size(plans[f].fdh[i]) as usize;
                    block(img, opts, i, f, &fill, scratch, size, out)
                },
            )?;
            Ok(blocks)
        };
        let mut spare = Vec::new();
        let mut pending = batches.first().map(|b| (*b, compute(b, Vec::new())));
        let mut k = 1;
        while let Some((units_done, blocks)) = pending.take() {
            let blocks = blocks?;
            let recycled = std::mem::take(&mut spare);
            let (written, next) = rayon::join(
                || -> Result<()> {
                    for (&f, b) in units_done.iter().zip(&blocks) {
                        if b.len() != block_size(plans[f].fdh[i]) as usize {
                            return Err(Error::file(
                                path,
                                format!("face {f} level {i} encoded to a different size twice (the fill callback is not deterministic)"),
                            ));
                        }
                        file.writer().write_all(b).map_err(io)?;
                    }
                    Ok(())
                },
                || batches.get(k).map(|b| (*b, compute(b, recycled))),
            );
            written?;
            spare = blocks;
            pending = next;
            k += 1;
        }
    }
    {
        let w = file.writer();
        w.write_all(&meta_zip).map_err(io)?;
        w.write_all(&[0u8; 8]).map_err(io)?;
        w.write_all(&lmd_zip).map_err(io)?;
        for b in &lmd_blocks {
            w.write_all(b).map_err(io)?;
        }
    }
    file.commit()?;
    Ok(PtexSummary {
        faces: nfaces,
        levels: nlevels,
        constant_faces: plans.iter().filter(|p| p.constant).count(),
        bytes: total,
    })
}
