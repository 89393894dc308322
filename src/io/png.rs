//! PNG encoding in parallel bands: the atlas PNG was the last serial stretch of the write
//! stage (bunny N = 16, a 2820² RGB atlas: ~0.6 s with one core busy after every other
//! writer had finished).
//!
//! Rows are filtered as the `png` crate's adaptive filter does (per row the first of Up,
//! Sub, Average, Paeth with the least sum of absolute signed bytes), so the filtered bytes
//! are the ones it wrote. They are cut into bands of a fixed byte size (never of the thread
//! count: the file is the same for any number of threads), each deflated on its own at
//! level 3 and ended with a sync flush (an empty stored block, byte-aligned), the last one
//! finished; the bands joined behind one zlib header, with the Adler-32 of all the filtered
//! bytes, make one zlib stream, as pigz writes it. Back-references do not cross bands:
//! files grow by ~0.1% (measured below in docs/benchmarks.md), pixels are unchanged.

use rayon::prelude::*;
use std::io::Write;

/// Filtered bytes per band (a band holds whole rows, at least one).
const BAND_BYTES: usize = 1 << 20;

/// Deflate level (the atlas's choice: 0.5% larger than level 6 and a quarter faster).
const LEVEL: u32 = 3;

/// Writes a PNG of `data` (rows of `width` pixels, `channels` samples of `depth`, samples
/// of 16 bits big-endian) to `out`.
pub fn encode(
    data: &[u8],
    width: u32,
    height: u32,
    channels: usize,
    depth: ::png::BitDepth,
    out: &mut impl Write,
) -> std::result::Result<(), String> {
    let bytes_per_sample = if depth == ::png::BitDepth::Sixteen {
        2
    } else {
        1
    };
    let bpp = channels * bytes_per_sample;
    let row = width as usize * bpp;
    if data.len() != row * height as usize {
        return Err(format!(
            "PNG of {width}x{height} pixels needs {} bytes, got {}",
            row * height as usize,
            data.len()
        ));
    }
    let mut e = ::png::Encoder::new(out, width, height);
    e.set_color(match channels {
        1 => ::png::ColorType::Grayscale,
        2 => ::png::ColorType::GrayscaleAlpha,
        3 => ::png::ColorType::Rgb,
        _ => ::png::ColorType::Rgba,
    });
    e.set_depth(depth);
    let mut w = e.write_header().map_err(|e| e.to_string())?;
    let rows_per_band = (BAND_BYTES / (row + 1)).max(1);
    let bands: Vec<(Vec<u8>, u32)> = (0..(height as usize).div_ceil(rows_per_band))
        .into_par_iter()
        .map(|b| {
            let rows = b * rows_per_band..((b + 1) * rows_per_band).min(height as usize);
            let last = rows.end == height as usize;
            let filtered = filter_rows(data, row, bpp, rows);
            let adler = adler32(&filtered);
            (deflate_band(&filtered, last), adler)
        })
        .collect();
    // Adler-32 of the whole from the bands' (zlib's adler32_combine).
    let mut adler = 1u32;
    let mut rows_left = height as usize;
    for (_, a) in &bands {
        let len = rows_per_band.min(rows_left) * (row + 1);
        rows_left -= rows_per_band.min(rows_left);
        adler = adler32_combine(adler, *a, len);
    }
    // zlib header: deflate, 32 KiB window, FLEVEL 1 (levels 2-5), FCHECK for % 31 == 0.
    let mut idat = Vec::with_capacity(2 + bands.iter().map(|(b, _)| b.len()).sum::<usize>() + 4);
    idat.extend_from_slice(&[0x78, 0x5E]);
    for (b, _) in &bands {
        idat.extend_from_slice(b);
    }
    idat.extend_from_slice(&adler.to_be_bytes());
    for chunk in idat.chunks(u32::MAX as usize >> 1) {
        w.write_chunk(::png::chunk::IDAT, chunk)
            .map_err(|e| e.to_string())?;
    }
    w.finish().map_err(|e| e.to_string())
}

/// The filter-type byte and filtered bytes of `rows` (each `row` bytes of `data`).
fn filter_rows(data: &[u8], row: usize, bpp: usize, rows: std::ops::Range<usize>) -> Vec<u8> {
    let zero = vec![0u8; row];
    let mut out = Vec::with_capacity(rows.len() * (row + 1));
    let mut scratch = vec![0u8; row];
    let mut best = vec![0u8; row];
    for y in rows {
        let cur = &data[y * row..(y + 1) * row];
        let prev = if y == 0 {
            &zero[..]
        } else {
            &data[(y - 1) * row..y * row]
        };
        // As `png`'s adaptive filter: Up, Sub, Average, Paeth in this order, the last of
        // equal cost kept, stopping at a cost of 0.
        let mut min = u64::MAX;
        let mut kind = 0u8;
        for f in [2u8, 1, 3, 4] {
            apply(f, bpp, prev, cur, &mut scratch);
            let cost = cost(&scratch);
            if cost <= min {
                min = cost;
                kind = f;
                std::mem::swap(&mut best, &mut scratch);
                if cost == 0 {
                    break;
                }
            }
        }
        out.push(kind);
        out.extend_from_slice(&best);
    }
    out
}

/// Sum of the bytes as signed magnitudes (`png`'s adaptive cost). Summed in u32 over
/// pieces of 64 KiB (at most 2^23 each, no overflow), which the compiler vectorizes.
fn cost(buf: &[u8]) -> u64 {
    buf.chunks(1 << 16)
        .map(|c| {
            c.iter()
                .map(|&b| u32::from((b as i8).unsigned_abs()))
                .sum::<u32>() as u64
        })
        .sum()
}

/// PNG filter `f` (1 Sub, 2 Up, 3 Average, 4 Paeth) of `cur` above `prev` into `out`.
/// The first `bpp` bytes (no left neighbour: a = c = 0) apart, each loop runs over
/// zipped slices without index checks or branches, so the compiler vectorizes it; the
/// bytes are the filters' of PNG spec 9.2 (tested against the per-byte definition).
fn apply(f: u8, bpp: usize, prev: &[u8], cur: &[u8], out: &mut [u8]) {
    let n = cur.len();
    let h = bpp.min(n);
    let (out0, out1) = out[..n].split_at_mut(h);
    match f {
        1 => {
            out0.copy_from_slice(&cur[..h]);
            for ((o, &x), &a) in out1.iter_mut().zip(&cur[h..]).zip(&cur[..n - h]) {
                *o = x.wrapping_sub(a);
            }
        }
        2 => {
            for ((o, &x), &b) in out[..n].iter_mut().zip(cur).zip(prev) {
                *o = x.wrapping_sub(b);
            }
        }
        3 => {
            for ((o, &x), &b) in out0.iter_mut().zip(&cur[..h]).zip(&prev[..h]) {
                *o = x.wrapping_sub(b / 2);
            }
            for (((o, &x), &a), &b) in out1
                .iter_mut()
                .zip(&cur[h..])
                .zip(&cur[..n - h])
                .zip(&prev[h..])
            {
                *o = x.wrapping_sub(((a as u16 + b as u16) >> 1) as u8);
            }
        }
        _ => {
            for ((o, &x), &b) in out0.iter_mut().zip(&cur[..h]).zip(&prev[..h]) {
                *o = x.wrapping_sub(paeth(0, b, 0));
            }
            for ((((o, &x), &a), &b), &c) in out1
                .iter_mut()
                .zip(&cur[h..])
                .zip(&cur[..n - h])
                .zip(&prev[h..])
                .zip(&prev[..n - h])
            {
                *o = x.wrapping_sub(paeth(a, b, c));
            }
        }
    }
}

/// The Paeth predictor (PNG spec 9.4), without branches: pa = |b − c|, pb = |a − c|,
/// pc = |a + b − 2c| (p = a + b − c), a if pa ≤ pb and pa ≤ pc, else b if pb ≤ pc, else c.
#[inline]
fn paeth(a: u8, b: u8, c: u8) -> u8 {
    let (a16, b16, c16) = (a as i16, b as i16, c as i16);
    let pa = (b16 - c16).abs();
    let pb = (a16 - c16).abs();
    let pc = (a16 + b16 - 2 * c16).abs();
    let bc = if pb <= pc { b } else { c };
    if pa <= pb && pa <= pc {
        a
    } else {
        bc
    }
}

/// Raw deflate of one band: ended by a sync flush (more bands follow) or finished.
fn deflate_band(input: &[u8], last: bool) -> Vec<u8> {
    use flate2::{Compress, Compression, FlushCompress, Status};
    let mut c = Compress::new(Compression::new(LEVEL), false);
    let mut out = Vec::with_capacity(input.len() + input.len() / 64 + 64);
    let flush = if last {
        FlushCompress::Finish
    } else {
        FlushCompress::Sync
    };
    loop {
        let done = c.total_in() as usize;
        if out.len() == out.capacity() {
            out.reserve(out.capacity() / 2 + 64);
        }
        let status = c
            .compress_vec(&input[done..], &mut out, flush)
            .expect("deflate of a buffer in memory");
        let all_in = c.total_in() as usize == input.len();
        match status {
            Status::StreamEnd => break,
            // A sync flush is complete once all input is in and output space remained.
            _ if !last && all_in && out.len() < out.capacity() => break,
            _ => {}
        }
    }
    out
}

fn adler32(data: &[u8]) -> u32 {
    let mut a = simd_adler32::Adler32::new();
    a.write(data);
    a.finish()
}

/// Adler-32 of A followed by B (`len_b` bytes) from their checksums (zlib's
/// `adler32_combine`).
fn adler32_combine(a: u32, b: u32, len_b: usize) -> u32 {
    const MOD: u64 = 65521;
    let rem = (len_b as u64) % MOD;
    let (a1, a2) = ((a & 0xffff) as u64, (a >> 16) as u64);
    let (b1, b2) = ((b & 0xffff) as u64, (b >> 16) as u64);
    let s1 = (a1 + b1 + MOD - 1) % MOD;
    let s2 = (a2 + b2 + rem * a1 + MOD * 2 - rem) % MOD;
    ((s2 << 16) | s1) as u32
}

#[cfg(test)]
mod tests {
    use super::*;

    fn decode(png: &[u8]) -> (Vec<u8>, u32, u32) {
        let d = ::png::Decoder::new(std::io::Cursor::new(png));
        let mut r = d.read_info().unwrap();
        let mut buf = vec![0; r.output_buffer_size().unwrap()];
        let info = r.next_frame(&mut buf).unwrap();
        buf.truncate(info.buffer_size());
        (buf, info.width, info.height)
    }

    /// Pixels survive in every band layout (one band, many, a last band of one row), and
    /// the filtered bytes are `png`'s: its own encoder's file inflates to the same stream.
    #[test]
    fn round_trips_and_matches_png_filtering() {
        for (w, h, ch) in [
            (7u32, 5u32, 3usize),
            (300, 1000, 4),
            (1031, 700, 1),
            (2, 3000, 2),
        ] {
            let data: Vec<u8> = (0..w as usize * h as usize * ch)
                .map(|i| ((i * 2654435761usize) >> 13) as u8 ^ (i / 7) as u8)
                .collect();
            let mut ours = Vec::new();
            encode(&data, w, h, ch, ::png::BitDepth::Eight, &mut ours).unwrap();
            let (px, dw, dh) = decode(&ours);
            assert_eq!((dw, dh), (w, h));
            assert_eq!(px, data);
            // The reference: png's encoder with its adaptive filter.
            let mut theirs = Vec::new();
            {
                let mut e = ::png::Encoder::new(&mut theirs, w, h);
                e.set_color(match ch {
                    1 => ::png::ColorType::Grayscale,
                    2 => ::png::ColorType::GrayscaleAlpha,
                    3 => ::png::ColorType::Rgb,
                    _ => ::png::ColorType::Rgba,
                });
                e.set_filter(::png::Filter::Adaptive);
                let mut wr = e.write_header().unwrap();
                wr.write_image_data(&data).unwrap();
            }
            assert_eq!(inflate_idat(&ours), inflate_idat(&theirs));
        }
    }

    /// The filters and their cost as PNG spec 9.2-9.4 define them byte by byte (the code
    /// before the loops were written for vectorizing), for comparison.
    fn apply_by_definition(f: u8, bpp: usize, prev: &[u8], cur: &[u8]) -> Vec<u8> {
        (0..cur.len())
            .map(|i| {
                let a = if i >= bpp { cur[i - bpp] } else { 0 };
                let c = if i >= bpp { prev[i - bpp] } else { 0 };
                let b = prev[i];
                let pred = match f {
                    1 => a,
                    2 => b,
                    3 => ((a as u16 + b as u16) / 2) as u8,
                    _ => {
                        let p = a as i16 + b as i16 - c as i16;
                        let (pa, pb, pc) = (
                            (p - a as i16).abs(),
                            (p - b as i16).abs(),
                            (p - c as i16).abs(),
                        );
                        if pa <= pb && pa <= pc {
                            a
                        } else if pb <= pc {
                            b
                        } else {
                            c
                        }
                    }
                };
                cur[i].wrapping_sub(pred)
            })
            .collect()
    }

    /// Every filter gives the definition's bytes and cost for every pixel size, rows
    /// shorter than a pixel included, on smooth, flat, noisy and extreme rows (ties of the
    /// Paeth predictor and every difference sign).
    #[test]
    fn filters_are_the_definitions() {
        let patterns: Vec<Box<dyn Fn(usize) -> u8>> = vec![
            Box::new(|i| ((i * 2654435761usize) >> 13) as u8),
            Box::new(|i| (i / 5) as u8),
            Box::new(|_| 7),
            Box::new(|i| if i % 3 == 0 { 255 } else { 0 }),
            Box::new(|i| (i % 4) as u8 * 85),
        ];
        for bpp in 1..=8usize {
            for n in [0usize, 1, bpp.saturating_sub(1), bpp, bpp + 1, 97, 1000] {
                for (pi, p) in patterns.iter().enumerate() {
                    for (qi, q) in patterns.iter().enumerate() {
                        let cur: Vec<u8> = (0..n).map(p).collect();
                        let prev: Vec<u8> = (0..n).map(|i| q(i + 11)).collect();
                        for f in 1..=4u8 {
                            let mut out = vec![0u8; n];
                            apply(f, bpp, &prev, &cur, &mut out);
                            let want = apply_by_definition(f, bpp, &prev, &cur);
                            assert_eq!(out, want, "filter {f} bpp {bpp} n {n} rows {pi} {qi}");
                            let by_def: u64 = want
                                .iter()
                                .map(|&b| u64::from((b as i8).unsigned_abs()))
                                .sum();
                            assert_eq!(cost(&out), by_def);
                        }
                    }
                }
            }
        }
        for (a, b, c) in (0..=255u8).step_by(3).flat_map(|a| {
            (0..=255u8)
                .step_by(5)
                .flat_map(move |b| (0..=255u8).step_by(7).map(move |c| (a, b, c)))
        }) {
            let want = apply_by_definition(4, 1, &[c, b], &[a, 0])[1];
            assert_eq!(0u8.wrapping_sub(paeth(a, b, c)), want);
        }
    }

    #[test]
    fn sixteen_bit_round_trips() {
        let (w, h) = (129u32, 77u32);
        let data: Vec<u8> = (0..w as usize * h as usize * 3 * 2)
            .map(|i| (i * 31 % 251) as u8)
            .collect();
        let mut ours = Vec::new();
        encode(&data, w, h, 3, ::png::BitDepth::Sixteen, &mut ours).unwrap();
        assert_eq!(decode(&ours).0, data);
    }

    /// The zlib stream of a PNG's IDAT chunks, inflated (checks the Adler-32 too).
    fn inflate_idat(png: &[u8]) -> Vec<u8> {
        let mut z = Vec::new();
        let mut i = 8;
        while i < png.len() {
            let len = u32::from_be_bytes(png[i..i + 4].try_into().unwrap()) as usize;
            if &png[i + 4..i + 8] == b"IDAT" {
                z.extend_from_slice(&png[i + 8..i + 8 + len]);
            }
            i += 12 + len;
        }
        let mut out = Vec::new();
        std::io::Read::read_to_end(&mut flate2::read::ZlibDecoder::new(&z[..]), &mut out).unwrap();
        out
    }

    #[test]
    fn adler_combines() {
        let a = b"hello, ";
        let b = b"world and more bytes";
        let whole = adler32(&[&a[..], &b[..]].concat());
        let c = adler32_combine(adler32(a), adler32(b), b.len());
        assert_eq!(c, whole);
    }
}
