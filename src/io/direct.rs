//! The buffered writer behind every output file ([`crate::io::atomic::AtomicFile`]):
//! whole, aligned 8 MiB blocks go to the disk directly (`O_DIRECT` on Linux), around the
//! page cache; everything else (a file's unaligned tail, bytes rewritten after a seek) is
//! written the ordinary way.
//!
//! Why: every output is fsynced before it is published anyway, so the bytes have to reach
//! the disk before the run ends; through the page cache the kernel first copies them there
//! (allocating and charging ~115 k fresh pages for the bunny's 460 MB), which was a quarter
//! of the end of a run's CPU samples on our machines (docs/benchmarks.md, "The bunny's
//! whole run, third round"). The bytes of the file are the same either way.
//!
//! Where direct writes are not available (another OS, a file system that refuses
//! `O_DIRECT` on open or on the first write), everything goes the ordinary way. Writes and
//! read-backs are positioned (`pwrite`, `pread` on Unix; a seek and an ordinary write or
//! read elsewhere, so the crate still builds off Unix).

use std::fs::File;
use std::io::{self, Seek, SeekFrom, Write};
use std::path::Path;

/// Alignment of direct writes: offsets, lengths and the memory they come from (the
/// largest logical block size of common disks).
const ALIGN: usize = 4096;

/// Bytes held before they are written: large enough that each direct write is cheap per
/// byte, small enough to stay in cache.
const CAPACITY: usize = 8 << 20;

/// A `Write + Seek` writer of one newly created file, writing through `ALIGN`-aligned
/// blocks of `CAPACITY` bytes.
#[derive(Debug)]
pub struct DirectWriter {
    /// The file opened the ordinary way (unaligned writes, read-backs, fsync).
    plain: File,
    /// The same file opened for direct writes, while they work.
    direct: Option<File>,
    /// Storage: `CAPACITY` bytes from `start` on are aligned to `ALIGN`.
    storage: Vec<u8>,
    start: usize,
    /// Bytes held, destined for the file from offset `at` on.
    held: usize,
    at: u64,
    /// The file's length so far (the furthest byte written or held past).
    end: u64,
}

impl DirectWriter {
    /// Wraps `plain`, a file just created (empty) at `path`, opening `path` a second time
    /// for direct writes where possible. `capacity` is rounded up to a multiple of
    /// `ALIGN` (tests use small ones).
    pub fn new(plain: File, path: &Path) -> Self {
        Self::with_capacity(plain, open_direct(path), CAPACITY)
    }

    fn with_capacity(plain: File, direct: Option<File>, capacity: usize) -> Self {
        let capacity = capacity.max(1).div_ceil(ALIGN) * ALIGN;
        let storage = vec![0u8; capacity + ALIGN];
        let start = storage.as_ptr().align_offset(ALIGN).min(ALIGN);
        Self {
            plain,
            direct,
            storage,
            start,
            held: 0,
            at: 0,
            end: 0,
        }
    }

    /// Whether whole blocks still go to the disk directly.
    pub fn is_direct(&self) -> bool {
        self.direct.is_some()
    }

    fn capacity(&self) -> usize {
        self.storage.len() - ALIGN
    }

    /// The stream position: where the next byte goes.
    fn position(&self) -> u64 {
        self.at + self.held as u64
    }

    /// Writes the held bytes to the file (the aligned whole blocks directly, the rest the
    /// ordinary way) and holds nothing.
    fn write_held(&mut self) -> io::Result<()> {
        if self.held == 0 {
            return Ok(());
        }
        let bytes = &self.storage[self.start..self.start + self.held];
        let mut done = 0;
        if let Some(d) = &self.direct {
            let whole = if self.at.is_multiple_of(ALIGN as u64) {
                self.held / ALIGN * ALIGN
            } else {
                0
            };
            if whole > 0 {
                match write_all_at(d, &bytes[..whole], self.at) {
                    Ok(()) => done = whole,
                    // Refused (alignment or the file system): ordinary writes from now
                    // on, this block included.
                    Err(e) if e.raw_os_error() == Some(EINVAL) => self.direct = None,
                    Err(e) => return Err(e),
                }
            }
        }
        write_all_at(&self.plain, &bytes[done..], self.at + done as u64)?;
        self.at += self.held as u64;
        self.held = 0;
        Ok(())
    }

    /// Before holding new bytes at an unaligned offset: holds the bytes of its block
    /// before it, read back from the file (zeros past its end), so the block can still
    /// be written directly.
    fn align_start(&mut self) -> io::Result<()> {
        let head = (self.at % ALIGN as u64) as usize;
        if self.held != 0 || head == 0 || self.direct.is_none() {
            return Ok(());
        }
        let from = self.at - head as u64;
        let buf = &mut self.storage[self.start..self.start + head];
        let mut got = 0;
        while got < head {
            match read_at(&self.plain, &mut buf[got..], from + got as u64) {
                Ok(0) => break,
                Ok(n) => got += n,
                Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
                Err(e) => return Err(e),
            }
        }
        buf[got..].fill(0);
        self.at = from;
        self.held = head;
        Ok(())
    }

    /// Writes everything held and gives back the ordinary file (to be fsynced; the
    /// direct one is closed).
    pub fn into_file(mut self) -> io::Result<File> {
        self.write_held()?;
        self.direct = None;
        Ok(self.plain)
    }

    /// Writes `len` bytes that `fill` puts straight into the held block, as `write_all` of
    /// them would, without a buffer of the caller's and its copy into the block. `fill`
    /// must set every one of the `len` bytes (what it leaves is unspecified). `false`,
    /// nothing written and `fill` not called, when they do not fit in the block's room
    /// left: the caller then writes them the ordinary way.
    pub fn write_in_place(&mut self, len: usize, fill: impl FnOnce(&mut [u8])) -> io::Result<bool> {
        if len == 0 {
            return Ok(true);
        }
        self.align_start()?;
        if len > self.capacity() - self.held {
            return Ok(false);
        }
        let at = self.start + self.held;
        fill(&mut self.storage[at..at + len]);
        self.held += len;
        self.end = self.end.max(self.position());
        if self.held == self.capacity() {
            self.write_held()?;
        }
        Ok(true)
    }
}

impl Write for DirectWriter {
    fn write(&mut self, data: &[u8]) -> io::Result<usize> {
        if data.is_empty() {
            return Ok(0);
        }
        self.align_start()?;
        let n = data.len().min(self.capacity() - self.held);
        let at = self.start + self.held;
        self.storage[at..at + n].copy_from_slice(&data[..n]);
        self.held += n;
        self.end = self.end.max(self.position());
        if self.held == self.capacity() {
            self.write_held()?;
        }
        Ok(n)
    }

    fn flush(&mut self) -> io::Result<()> {
        self.write_held()
    }
}

impl Seek for DirectWriter {
    fn seek(&mut self, to: SeekFrom) -> io::Result<u64> {
        let here = self.position();
        let target = match to {
            SeekFrom::Start(p) => Some(p),
            SeekFrom::Current(d) => here.checked_add_signed(d),
            SeekFrom::End(d) => self.end.checked_add_signed(d),
        }
        .ok_or_else(|| {
            io::Error::new(
                io::ErrorKind::InvalidInput,
                "seek to a negative or overflowing position",
            )
        })?;
        if target != here {
            self.write_held()?;
            self.at = target;
        }
        Ok(target)
    }
}

#[cfg(target_os = "linux")]
const EINVAL: i32 = libc::EINVAL;
#[cfg(not(target_os = "linux"))]
const EINVAL: i32 = 22;

/// Positioned writes and reads: `pwrite`/`pread` on Unix; elsewhere a seek of the plain
/// handle, which only this writer uses, then an ordinary write or read.
#[cfg(unix)]
fn write_all_at(f: &File, buf: &[u8], at: u64) -> io::Result<()> {
    std::os::unix::fs::FileExt::write_all_at(f, buf, at)
}

#[cfg(unix)]
fn read_at(f: &File, buf: &mut [u8], at: u64) -> io::Result<usize> {
    std::os::unix::fs::FileExt::read_at(f, buf, at)
}

#[cfg(not(unix))]
fn write_all_at(mut f: &File, buf: &[u8], at: u64) -> io::Result<()> {
    f.seek(SeekFrom::Start(at))?;
    f.write_all(buf)
}

#[cfg(not(unix))]
fn read_at(mut f: &File, buf: &mut [u8], at: u64) -> io::Result<usize> {
    use std::io::Read;
    f.seek(SeekFrom::Start(at))?;
    f.read(buf)
}

/// `path` opened for direct writes, if the OS and the file system allow it.
#[cfg(target_os = "linux")]
fn open_direct(path: &Path) -> Option<File> {
    use std::os::unix::fs::OpenOptionsExt;
    std::fs::OpenOptions::new()
        .write(true)
        .custom_flags(libc::O_DIRECT)
        .open(path)
        .ok()
}

#[cfg(not(target_os = "linux"))]
fn open_direct(_: &Path) -> Option<File> {
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A writer on a new file in `dir`, direct when `direct`, with a small capacity.
    fn writer(dir: &Path, direct: bool, capacity: usize) -> (DirectWriter, std::path::PathBuf) {
        let p = dir.join("out.bin");
        let plain = std::fs::OpenOptions::new()
            .read(true)
            .write(true)
            .create(true)
            .truncate(true)
            .open(&p)
            .unwrap();
        let d = if direct { open_direct(&p) } else { None };
        (DirectWriter::with_capacity(plain, d, capacity), p)
    }

    /// Bytes that differ at every offset (a pattern of period 251).
    fn bytes(n: usize, salt: u8) -> Vec<u8> {
        (0..n).map(|i| (i % 251) as u8 ^ salt).collect()
    }

    #[test]
    fn the_file_holds_what_was_written_in_any_pieces() {
        for direct in [true, false] {
            for capacity in [ALIGN, 3 * ALIGN] {
                for (len, piece) in [(0, 7), (1, 1), (ALIGN, 100), (5 * ALIGN + 17, 4097)] {
                    let dir = tempfile::tempdir().unwrap();
                    let (mut w, p) = writer(dir.path(), direct, capacity);
                    let data = bytes(len, 3);
                    for c in data.chunks(piece) {
                        w.write_all(c).unwrap();
                    }
                    w.into_file().unwrap().sync_all().unwrap();
                    assert_eq!(
                        std::fs::read(&p).unwrap(),
                        data,
                        "{direct} {capacity} {len}"
                    );
                }
            }
        }
    }

    #[test]
    fn bytes_filled_in_place_are_the_bytes_written() {
        // Pieces that fit, fill a block exactly, and straddle its end (refused, then
        // written the ordinary way), after an unaligned start.
        for direct in [true, false] {
            let dir = tempfile::tempdir().unwrap();
            let (mut w, p) = writer(dir.path(), direct, 2 * ALIGN);
            let mut expect = bytes(5, 9);
            w.write_all(&expect).unwrap();
            for (k, len) in [0, 100, 2 * ALIGN - 105, 3000, 3000, ALIGN, 1]
                .into_iter()
                .enumerate()
            {
                let b = bytes(len, k as u8);
                let put = |out: &mut [u8]| out.copy_from_slice(&b);
                if !w.write_in_place(len, put).unwrap() {
                    assert!(len > 0);
                    w.write_all(&b).unwrap();
                }
                expect.extend_from_slice(&b);
            }
            w.into_file().unwrap().sync_all().unwrap();
            assert_eq!(std::fs::read(&p).unwrap(), expect, "direct {direct}");
        }
    }

    /// Seeks to `at` and writes `b`, doing the same to `expect`.
    fn put(w: &mut DirectWriter, expect: &mut Vec<u8>, at: usize, b: &[u8]) {
        assert_eq!(w.seek(SeekFrom::Start(at as u64)).unwrap(), at as u64);
        w.write_all(b).unwrap();
        if expect.len() < at + b.len() {
            expect.resize(at + b.len(), 0);
        }
        expect[at..at + b.len()].copy_from_slice(b);
    }

    #[test]
    fn seeks_back_and_forward_rewrite_like_a_plain_file() {
        // The EXR writer's pattern: a header, a placeholder table, the chunks, then the
        // table written over its placeholder; also a seek past the end (a hole).
        for direct in [true, false] {
            let dir = tempfile::tempdir().unwrap();
            let (mut w, p) = writer(dir.path(), direct, 2 * ALIGN);
            let mut expect = Vec::new();
            let e = &mut expect;
            put(&mut w, e, 0, &bytes(333, 1));
            put(&mut w, e, 333, &[0; 1000]);
            put(&mut w, e, 1333, &bytes(3 * ALIGN + 5, 2));
            put(&mut w, e, 333, &bytes(1000, 4));
            let end = w.seek(SeekFrom::End(0)).unwrap() as usize;
            assert_eq!(end, e.len());
            put(&mut w, e, end + 10, &bytes(ALIGN, 5));
            assert_eq!(w.stream_position().unwrap() as usize, e.len());
            put(&mut w, e, 2 * ALIGN - 3, &bytes(7, 6));
            assert!(w.seek(SeekFrom::Current(-(10 * ALIGN as i64))).is_err());
            w.flush().unwrap();
            drop(w);
            assert_eq!(std::fs::read(&p).unwrap(), expect, "direct {direct}");
        }
    }
}
