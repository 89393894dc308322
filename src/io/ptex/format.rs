//! The Ptex file format's records, byte for byte as the reference library lays them out
//! (Disney Ptex 2.4, `PtexIO.h` and `Ptexture.h`; `../shared/tools/ptex/src`).
//!
//! Everything is little-endian and packed. A file is: [`Header`] (64 bytes),
//! [`ExtHeader`] (40), the zipped face-info array ([`FaceInfo`], 20 bytes per face), the
//! zipped constant-data array (one pixel per face), the level-info array ([`LevelInfo`], 16
//! bytes per level, not zipped), the levels (each a zipped array of face-data headers,
//! then the face blocks in that order), the zipped small meta data, an 8-byte zero
//! "compatibility barrier", the zipped large-meta-data headers and the large meta data
//! blocks. Every "zipped" block is a complete zlib stream (the reference resets its
//! `z_stream` after each block), so any deflate level — including stored blocks — is
//! read the same way.

use flate2::write::ZlibEncoder;
use std::io::Write;

/// `'P' | 't' << 8 | 'e' << 16 | 'x' << 24`.
pub const MAGIC: u32 = u32::from_le_bytes(*b"Ptex");
/// File format version the reference reader accepts (it refuses anything else).
pub const VERSION: u32 = 1;
/// Minor version written by the reference writer of Ptex 2.4.
pub const MINOR_VERSION: u32 = 4;
pub const HEADER_SIZE: usize = 64;
pub const EXT_HEADER_SIZE: usize = 40;
pub const LEVEL_INFO_SIZE: usize = 16;
pub const FACE_INFO_SIZE: usize = 20;
/// Faces larger than twice this (uncompressed bytes) are split into tiles (`TileSize`).
pub const TILE_SIZE: u64 = 65536;
/// Reductions stop when the smaller side would drop below 2^this texels
/// (`PtexWriter::MinReductionLog2`).
pub const MIN_REDUCTION_LOG2: u8 = 2;
/// Meta data entries above this many bytes go to their own blocks (`MetaDataThreshold`).
pub const METADATA_THRESHOLD: usize = 1024;

/// `Ptex::MeshType::mt_quad`: every face (and n-gon sub-face) is a quad.
pub const MESH_QUAD: u32 = 1;
/// `Ptex::DataType::dt_float`.
pub const DATA_FLOAT: u32 = 3;

/// Face flags (`FaceInfo::flag_*`).
pub const FLAG_CONSTANT: u8 = 1;
pub const FLAG_NBCONSTANT: u8 = 4;
pub const FLAG_SUBFACE: u8 = 8;

/// Face-data block encodings (`Ptex::Encoding`), in bits 30..31 of a data header.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Encoding {
    Constant = 0,
    Zipped = 1,
    Tiled = 3,
}

/// Largest block size a face-data header can hold (30 bits).
pub const MAX_BLOCK: u64 = 0x3fff_ffff;

/// A face-data header: block size in bits 0..29, encoding in bits 30..31.
pub fn data_header(size: u32, enc: Encoding) -> u32 {
    (size & 0x3fff_ffff) | ((enc as u32) << 30)
}

/// Block size of a face-data header.
pub fn block_size(fdh: u32) -> u32 {
    fdh & 0x3fff_ffff
}

/// Meta data types (`Ptex::MetaDataType`).
pub const MDT_STRING: u8 = 0;
pub const MDT_INT32: u8 = 3;
pub const MDT_FLOAT: u8 = 4;

/// Resolution of a face map: 2^ulog2 texels along u, 2^vlog2 along v (Ptex stores the
/// logs, so every resolution is a power of two, chosen per face and per axis).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct Res {
    pub ulog2: u8,
    pub vlog2: u8,
}

impl Res {
    pub fn new(ulog2: u8, vlog2: u8) -> Self {
        Self { ulog2, vlog2 }
    }
    /// Square 2^log2 × 2^log2.
    pub fn square(log2: u8) -> Self {
        Self::new(log2, log2)
    }
    /// Texels along u.
    pub fn u(self) -> usize {
        1 << self.ulog2
    }
    /// Texels along v.
    pub fn v(self) -> usize {
        1 << self.vlog2
    }
    /// Texels in all.
    pub fn size(self) -> usize {
        self.u() * self.v()
    }
    /// The smaller log2 side (what reductions are counted by).
    pub fn min_log2(self) -> u8 {
        self.ulog2.min(self.vlog2)
    }
    /// Both sides halved `k` times.
    pub fn reduced(self, k: u8) -> Self {
        Self::new(self.ulog2 - k, self.vlog2 - k)
    }
}

/// Per-face record of the file: resolution, the four neighbours and flags.
///
/// Edges are numbered as Ptex does, counter-clockwise from the bottom: 0 = v = 0 (from
/// (0,0) to (1,0)), 1 = u = 1, 2 = v = 1, 3 = u = 0. `adj_faces[e]` is the face across
/// edge e (−1 on an open boundary) and `adj_edges[e]` that face's edge id for the shared
/// edge.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FaceInfo {
    pub res: Res,
    pub adj_faces: [i32; 4],
    pub adj_edges: [u8; 4],
    /// One of the quad sub-faces of an n-gon (n ≠ 4).
    pub subface: bool,
}

impl FaceInfo {
    /// The 20 bytes of `Ptex::FaceInfo` with `flags` (subface is added here).
    pub fn to_bytes(&self, flags: u8) -> [u8; FACE_INFO_SIZE] {
        let mut b = [0u8; FACE_INFO_SIZE];
        b[0] = self.res.ulog2;
        b[1] = self.res.vlog2;
        b[2] = self
            .adj_edges
            .iter()
            .enumerate()
            .fold(0u8, |acc, (e, &a)| acc | ((a & 3) << (2 * e)));
        b[3] = flags | if self.subface { FLAG_SUBFACE } else { 0 };
        for (e, f) in self.adj_faces.iter().enumerate() {
            b[4 + 4 * e..8 + 4 * e].copy_from_slice(&f.to_le_bytes());
        }
        b
    }
}

/// `PtexIO::Header`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Header {
    pub alphachan: i32,
    pub nchannels: u16,
    pub nlevels: u16,
    pub nfaces: u32,
    pub faceinfosize: u32,
    pub constdatasize: u32,
    pub levelinfosize: u32,
    pub leveldatasize: u64,
    pub metadatazipsize: u32,
    pub metadatamemsize: u32,
}

impl Header {
    pub fn to_bytes(&self) -> [u8; HEADER_SIZE] {
        let mut w = Vec::with_capacity(HEADER_SIZE);
        for v in [MAGIC, VERSION, MESH_QUAD, DATA_FLOAT] {
            w.extend_from_slice(&v.to_le_bytes());
        }
        w.extend_from_slice(&self.alphachan.to_le_bytes());
        w.extend_from_slice(&self.nchannels.to_le_bytes());
        w.extend_from_slice(&self.nlevels.to_le_bytes());
        for v in [
            self.nfaces,
            EXT_HEADER_SIZE as u32,
            self.faceinfosize,
            self.constdatasize,
            self.levelinfosize,
            MINOR_VERSION,
        ] {
            w.extend_from_slice(&v.to_le_bytes());
        }
        w.extend_from_slice(&self.leveldatasize.to_le_bytes());
        w.extend_from_slice(&self.metadatazipsize.to_le_bytes());
        w.extend_from_slice(&self.metadatamemsize.to_le_bytes());
        w.try_into().expect("header is 64 bytes")
    }
}

/// `PtexIO::ExtHeader` (border modes clamp, edge filter mode none).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ExtHeader {
    pub lmdheaderzipsize: u32,
    pub lmdheadermemsize: u32,
    pub lmddatasize: u64,
    pub editdatapos: u64,
}

impl ExtHeader {
    pub fn to_bytes(&self) -> [u8; EXT_HEADER_SIZE] {
        let mut w = Vec::with_capacity(EXT_HEADER_SIZE);
        // ubordermode, pad, vbordermode, edgefiltermode: clamp (0), 0, clamp, none (0).
        w.extend_from_slice(&[0u8; 8]);
        w.extend_from_slice(&self.lmdheaderzipsize.to_le_bytes());
        w.extend_from_slice(&self.lmdheadermemsize.to_le_bytes());
        w.extend_from_slice(&self.lmddatasize.to_le_bytes());
        w.extend_from_slice(&0u64.to_le_bytes()); // editdatasize: no edits
        w.extend_from_slice(&self.editdatapos.to_le_bytes());
        w.try_into().expect("extended header is 40 bytes")
    }
}

/// `PtexIO::LevelInfo`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct LevelInfo {
    pub leveldatasize: u64,
    pub levelheadersize: u32,
    pub nfaces: u32,
}

impl LevelInfo {
    pub fn to_bytes(&self) -> [u8; LEVEL_INFO_SIZE] {
        let mut b = [0u8; LEVEL_INFO_SIZE];
        b[..8].copy_from_slice(&self.leveldatasize.to_le_bytes());
        b[8..12].copy_from_slice(&self.levelheadersize.to_le_bytes());
        b[12..].copy_from_slice(&self.nfaces.to_le_bytes());
        b
    }
}

/// Largest stored deflate block.
const STORED_BLOCK: usize = 65535;

/// Length of the zlib stream [`zip_into`] writes for `n` bytes at level 0: the 2-byte
/// header, 5 bytes per stored block of at most 65535 bytes (at least one block), the data,
/// the 4-byte Adler-32. Known without looking at the data, so the writer's first pass need
/// not encode anything at level 0.
pub fn stored_len(n: usize) -> usize {
    2 + n + 5 * n.div_ceil(STORED_BLOCK).max(1) + 4
}

/// `data` as a zlib stream of stored blocks (RFC 1950/1951), appended to `out`.
fn stored_into(data: &[u8], out: &mut Vec<u8>) {
    out.reserve(stored_len(data.len()));
    // CMF: deflate, 32 KiB window; FLG: no dictionary, fastest, check bits for 31.
    out.extend_from_slice(&[0x78, 0x01]);
    let mut blocks = data.chunks(STORED_BLOCK).peekable();
    if blocks.peek().is_none() {
        out.extend_from_slice(&[1, 0, 0, 0xff, 0xff]);
    }
    while let Some(b) = blocks.next() {
        let last = blocks.peek().is_none();
        let len = b.len() as u16;
        out.push(last as u8);
        out.extend_from_slice(&len.to_le_bytes());
        out.extend_from_slice(&(!len).to_le_bytes());
        out.extend_from_slice(b);
    }
    let mut a = simd_adler32::Adler32::new();
    a.write(data);
    out.extend_from_slice(&a.finish().to_be_bytes());
}

/// Appends `data` to `out` as one complete zlib stream at deflate `level` (0: stored
/// blocks, [`stored_len`] bytes) and returns the number of bytes appended.
pub fn zip_into(data: &[u8], level: u32, out: &mut Vec<u8>) -> usize {
    let start = out.len();
    if level == 0 {
        stored_into(data, out);
        return out.len() - start;
    }
    DEFLATE.with_borrow_mut(|slot| {
        let enc = match slot {
            Some((l, e)) if *l == level => e,
            _ => {
                let fresh = ZlibEncoder::new(Vec::new(), flate2::Compression::new(level));
                &mut slot.insert((level, fresh)).1
            }
        };
        // Exactly a fresh encoder's calls (write, then finish) on a reset one, writing
        // into `out`; `reset` hands back the previous output and starts a new stream.
        // Writing into a Vec cannot fail.
        enc.reset(std::mem::take(out))
            .expect("in-memory compression");
        enc.write_all(data).expect("in-memory compression");
        enc.try_finish().expect("in-memory compression");
        *out = enc.reset(Vec::new()).expect("in-memory compression");
    });
    out.len() - start
}

thread_local! {
    /// One zlib compressor per thread, reset for each stream instead of made anew: the
    /// writer compresses a small stream per face (its tiles' headers), and a new
    /// compressor's state (~0.3 MiB: window and hash tables) was a fresh mapping to fault in
    /// and give back every time (docs/benchmarks.md, "Ptex writing without fresh
    /// buffers"). The same calls as a fresh `ZlibEncoder` on a reset one, so the same
    /// bytes: feeding the compressor otherwise (all input in one call with a large output
    /// buffer) gave other bytes for the bunny's large tables.
    static DEFLATE: std::cell::RefCell<Option<(u32, ZlibEncoder<Vec<u8>>)>> =
        const { std::cell::RefCell::new(None) };
}

/// `data` as one zlib stream.
pub fn zip(data: &[u8], level: u32) -> Vec<u8> {
    let mut v = Vec::with_capacity(data.len() / 2 + 64);
    zip_into(data, level, &mut v);
    v
}

/// `PtexUtils::floor_log2`, with floor_log2(0) = 0 as there.
pub fn floor_log2(x: u64) -> u32 {
    if x == 0 {
        0
    } else {
        63 - x.leading_zeros()
    }
}

/// `PtexWriterBase::calcTileRes`: the tile resolution for a face of `res` with
/// `pixel_size`-byte pixels, or `None` when the face is written as one block.
pub fn tile_res(res: Res, pixel_size: usize) -> Option<Res> {
    let facesize = res.size() as u64 * pixel_size as u64;
    let ntileslog2 = floor_log2(facesize / TILE_SIZE) as i32;
    if ntileslog2 == 0 {
        return None;
    }
    let n = res.ulog2 as i32 + res.vlog2 as i32 - ntileslog2;
    let ulog2 = ((n + 1) / 2).min(res.ulog2 as i32);
    let vlog2 = (n - ulog2).min(res.vlog2 as i32);
    Some(Res::new(ulog2 as u8, vlog2 as u8))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn record_sizes_and_fields() {
        let h = Header {
            alphachan: -1,
            nchannels: 5,
            nlevels: 4,
            nfaces: 7,
            ..Default::default()
        }
        .to_bytes();
        assert_eq!(&h[..4], b"Ptex");
        assert_eq!(u32::from_le_bytes(h[4..8].try_into().unwrap()), 1);
        assert_eq!(i32::from_le_bytes(h[16..20].try_into().unwrap()), -1);
        assert_eq!(u16::from_le_bytes(h[20..22].try_into().unwrap()), 5);
        assert_eq!(u32::from_le_bytes(h[28..32].try_into().unwrap()), 40);
        assert_eq!(u32::from_le_bytes(h[44..48].try_into().unwrap()), 4);
        let f = FaceInfo {
            res: Res::new(5, 4),
            adj_faces: [-1, 3, 9, 0x1234_5678],
            adj_edges: [0, 2, 1, 3],
            subface: true,
        }
        .to_bytes(FLAG_CONSTANT);
        assert_eq!(f[..4], [5, 4, 0b11_01_10_00, FLAG_CONSTANT | FLAG_SUBFACE]);
        assert_eq!(i32::from_le_bytes(f[4..8].try_into().unwrap()), -1);
        assert_eq!(
            i32::from_le_bytes(f[16..20].try_into().unwrap()),
            0x1234_5678
        );
        assert_eq!(block_size(data_header(1234, Encoding::Tiled)), 1234);
        assert_eq!(data_header(1, Encoding::Tiled) >> 30, 3);
    }

    #[test]
    fn tiles_follow_the_reference_rule() {
        // 32² x 7 floats = 28 KiB: one block. 128² x 7 floats = 448 KiB: 7 tiles' worth,
        // floor_log2 = 2, so 4 tiles of 64².
        assert_eq!(tile_res(Res::square(5), 28), None);
        assert_eq!(tile_res(Res::square(7), 28), Some(Res::square(6)));
        // Exactly 2 x TILE_SIZE is the first tiled size.
        assert_eq!(tile_res(Res::new(7, 7), 8), Some(Res::new(7, 6)));
        assert_eq!(tile_res(Res::new(7, 6), 8), None);
        assert_eq!(floor_log2(0), 0);
        assert_eq!(floor_log2(7), 2);
    }

    /// The per-thread compressor, reset between streams and switched between levels,
    /// writes the bytes a fresh encoder writes (so files do not depend on which streams a
    /// thread compressed before).
    #[test]
    fn a_reused_compressor_writes_what_a_fresh_one_writes() {
        let data: Vec<u8> = (0..300_000u32).map(|i| (i * i % 253) as u8).collect();
        // Table-like records (face infos: resolutions, flags, neighbour ids), the kind of
        // large stream the bunny's tables are.
        let records: Vec<u8> = (0..60_000u32)
            .flat_map(|i| {
                let mut r = [0u8; 20];
                r[0] = 4;
                r[1] = 4;
                r[4..8].copy_from_slice(&(i.wrapping_mul(2_654_435_761) % 19_794).to_le_bytes());
                r[8..12].copy_from_slice(&(i ^ (i >> 3)).to_le_bytes());
                r[12..16].copy_from_slice(&((i * 3 + 1) % 19_794).to_le_bytes());
                r[16] = (i % 7) as u8;
                r
            })
            .collect();
        let fresh = |d: &[u8], level: u32| {
            let mut e =
                flate2::write::ZlibEncoder::new(Vec::new(), flate2::Compression::new(level));
            e.write_all(d).unwrap();
            e.finish().unwrap()
        };
        for (level, len) in [
            (6, 300_000),
            (6, 10),
            (6, 0),
            (1, 70_000),
            (6, 40_000),
            (9, 5),
        ] {
            let mut out = vec![7u8; 3];
            let n = zip_into(&data[..len], level, &mut out);
            let mut again = Vec::new();
            zip_into(&records, level, &mut again);
            assert_eq!(again, fresh(&records, level), "records, level {level}");
            assert_eq!(&out[..3], &[7, 7, 7]);
            assert_eq!(
                &out[3..],
                &fresh(&data[..len], level)[..],
                "level {level}, {len} bytes"
            );
            assert_eq!(n, out.len() - 3);
        }
    }

    #[test]
    fn zip_blocks_are_zlib_streams() {
        use std::io::Read;
        let data: Vec<u8> = (0..100_000u32).map(|i| (i * 7 % 251) as u8).collect();
        for (level, data) in [
            (0, &data[..]),
            (0, &data[..65535]),
            (0, &data[..65536]),
            (0, &[][..]),
            (1, &data[..]),
            (6, &data[..]),
        ] {
            let z = zip(data, level);
            if level == 0 {
                assert_eq!(z.len(), stored_len(data.len()));
            }
            let mut back = Vec::new();
            flate2::read::ZlibDecoder::new(&z[..])
                .read_to_end(&mut back)
                .unwrap();
            assert_eq!(back, data, "level {level}");
        }
    }
}
