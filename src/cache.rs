//! Saved per-example analysis (issue 14): jump maps, k-coherence lists, appearance-space
//! projections — everything a method computes from the example alone — kept in files so
//! that the next run with the same example and parameters skips it.
//!
//! **Keys.** An entry is named by a 128-bit hash ([`Key`], xxh3-128) of the *kind* of
//! analysis, [`FORMAT_VERSION`], the example's pixels exactly as the analysis sees them
//! (the weighted, possibly flipped channels, bit for bit) and every parameter that changes
//! the result. Two runs that would compute the same analysis find the same file; a change
//! of anything that matters gives another name, so an entry is never *stale* by content.
//!
//! **Files.** `DIR/<kind>-<32 hex digits>.bin`: a header — magic `SURFSYNC`, the format
//! version, the kind, the key, the payload length and an xxh3-64 checksum of the payload —
//! then the payload (little-endian numbers, written by the [`Persist`] implementations
//! beside each analysis type). A file that is truncated, has another version, another
//! key, or whose checksum does not match is reported ([`Lookup::Corrupt`]), rebuilt and
//! rewritten: never trusted. Entries are written to a temporary name in the same folder
//! and renamed, so two runs at once each see either no file or a whole one (whichever
//! rename lands last wins; both wrote the same bytes).
//!
//! **Where.** [`CacheDir::Default`] is the platform's user cache folder (`$SURFSYNTH_CACHE`
//! if set, else `$XDG_CACHE_HOME/surfsynth` or `~/.cache/surfsynth` on Linux,
//! `~/Library/Caches/surfsynth` on macOS, `%LOCALAPPDATA%\surfsynth\cache` on Windows);
//! `--cache DIR` picks another, `--no-cache` none. A cache folder that cannot be created
//! or written only costs the saving (one warning), never the run.
//!
//! Why hand-written little-endian instead of serde + bincode/postcard: the payloads are a
//! few large arrays of `f32`/`u32` (copied in bulk) and a handful of sizes; a derive would
//! put serde bounds on the search types for no gain, and the format must be versioned by
//! hand anyway (docs/dependencies.md).

use std::path::{Path, PathBuf};
use xxhash_rust::xxh3::{xxh3_64, Xxh3};

/// Version of every payload layout. Bump it when any [`Persist`] implementation changes:
/// old entries then get other keys and are simply never found again.
pub const FORMAT_VERSION: u32 = 1;

const MAGIC: &[u8; 8] = b"SURFSYNC";

/// Where the cache lives (`--cache DIR`, `--no-cache`, default).
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub enum CacheDir {
    /// The platform's user cache folder (see the module docs).
    #[default]
    Default,
    /// This folder.
    Dir(PathBuf),
    /// No saving or loading (analysis is still shared within one process, e.g. a session).
    Off,
}

impl CacheDir {
    /// The folder this setting means, if any.
    pub fn resolve(&self) -> Option<PathBuf> {
        match self {
            CacheDir::Off => None,
            CacheDir::Dir(p) => Some(p.clone()),
            CacheDir::Default => default_dir(),
        }
    }
}

/// The platform's user cache folder for surfsynth (module docs), `None` when the
/// environment names none.
pub fn default_dir() -> Option<PathBuf> {
    let var = |k: &str| {
        std::env::var_os(k)
            .filter(|v| !v.is_empty())
            .map(PathBuf::from)
    };
    if let Some(p) = var("SURFSYNTH_CACHE") {
        return Some(p);
    }
    if cfg!(windows) {
        return var("LOCALAPPDATA").map(|p| p.join("surfsynth").join("cache"));
    }
    if cfg!(target_os = "macos") {
        return var("HOME").map(|h| h.join("Library/Caches/surfsynth"));
    }
    var("XDG_CACHE_HOME")
        .map(|p| p.join("surfsynth"))
        .or_else(|| var("HOME").map(|h| h.join(".cache/surfsynth")))
}

/// An entry's name: xxh3-128 of kind, format version and everything hashed in.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Key(pub u128);

impl Key {
    /// 32 hex digits.
    pub fn hex(&self) -> String {
        format!("{:032x}", self.0)
    }
}

/// Builds a [`Key`] from the parts that decide an analysis.
pub struct KeyBuilder(Xxh3);

impl KeyBuilder {
    /// A key of analysis `kind` (a short file-name-safe word).
    pub fn new(kind: &str) -> Self {
        let mut h = Xxh3::new();
        h.update(MAGIC);
        h.update(&FORMAT_VERSION.to_le_bytes());
        h.update(&(kind.len() as u64).to_le_bytes());
        h.update(kind.as_bytes());
        Self(h)
    }
    pub fn u64(mut self, v: u64) -> Self {
        self.0.update(&v.to_le_bytes());
        self
    }
    pub fn f64(self, v: f64) -> Self {
        self.u64(v.to_bits())
    }
    pub fn f32s(mut self, v: &[f32]) -> Self {
        self.0.update(&(v.len() as u64).to_le_bytes());
        let mut buf = Vec::with_capacity(4 * v.len().min(1 << 16));
        for chunk in v.chunks(1 << 16) {
            buf.clear();
            for x in chunk {
                buf.extend_from_slice(&x.to_bits().to_le_bytes());
            }
            self.0.update(&buf);
        }
        self
    }
    pub fn str(mut self, s: &str) -> Self {
        self.0.update(&(s.len() as u64).to_le_bytes());
        self.0.update(s.as_bytes());
        self
    }
    /// An image's size and pixels.
    pub fn image(self, img: &crate::pyramid::Image) -> Self {
        self.u64(img.width as u64)
            .u64(img.height as u64)
            .u64(img.channels as u64)
            .f32s(&img.data)
    }
    pub fn finish(self) -> Key {
        Key(self.0.digest128())
    }
}

/// Little-endian payload writer.
#[derive(Default)]
pub struct Writer(pub Vec<u8>);

impl Writer {
    pub fn u64(&mut self, v: u64) {
        self.0.extend_from_slice(&v.to_le_bytes());
    }
    pub fn usize(&mut self, v: usize) {
        self.u64(v as u64);
    }
    pub fn f64(&mut self, v: f64) {
        self.u64(v.to_bits());
    }
    pub fn bool(&mut self, v: bool) {
        self.0.push(v as u8);
    }
    pub fn f32s(&mut self, v: &[f32]) {
        self.usize(v.len());
        self.0.reserve(4 * v.len());
        for x in v {
            self.0.extend_from_slice(&x.to_le_bytes());
        }
    }
    pub fn u32s(&mut self, v: &[u32]) {
        self.usize(v.len());
        self.0.reserve(4 * v.len());
        for x in v {
            self.0.extend_from_slice(&x.to_le_bytes());
        }
    }
    pub fn image(&mut self, img: &crate::pyramid::Image) {
        self.usize(img.width);
        self.usize(img.height);
        self.usize(img.channels);
        self.f32s(&img.data);
    }
}

/// Little-endian payload reader: every getter returns `None` past the end, so a
/// truncated or garbled payload is a failed load, never a panic.
pub struct Reader<'a> {
    data: &'a [u8],
    at: usize,
}

impl<'a> Reader<'a> {
    pub fn new(data: &'a [u8]) -> Self {
        Self { data, at: 0 }
    }
    fn take(&mut self, n: usize) -> Option<&'a [u8]> {
        let end = self.at.checked_add(n)?;
        let s = self.data.get(self.at..end)?;
        self.at = end;
        Some(s)
    }
    pub fn u64(&mut self) -> Option<u64> {
        Some(u64::from_le_bytes(self.take(8)?.try_into().ok()?))
    }
    /// A size, refused when larger than `max` (a garbled length must not allocate).
    pub fn usize_max(&mut self, max: usize) -> Option<usize> {
        let v = self.u64()?;
        (v <= max as u64).then_some(v as usize)
    }
    pub fn usize(&mut self) -> Option<usize> {
        self.usize_max(self.data.len())
    }
    pub fn f64(&mut self) -> Option<f64> {
        Some(f64::from_bits(self.u64()?))
    }
    pub fn bool(&mut self) -> Option<bool> {
        match self.take(1)?[0] {
            0 => Some(false),
            1 => Some(true),
            _ => None,
        }
    }
    pub fn f32s(&mut self) -> Option<Vec<f32>> {
        let n = self.usize_max((self.data.len() - self.at) / 4)?;
        let b = self.take(4 * n)?;
        Some(
            b.chunks_exact(4)
                .map(|c| f32::from_le_bytes(c.try_into().expect("4 bytes")))
                .collect(),
        )
    }
    /// What [`Writer::f32s`] wrote, as arrays of `N` (its length a multiple of `N`),
    /// read straight into them: no flat copy in between (a pf bank of a 2048² example is
    /// ~0.6 GB).
    pub fn f32_arrays<const N: usize>(&mut self) -> Option<Vec<[f32; N]>> {
        let n = self.usize_max((self.data.len() - self.at) / 4)?;
        if !n.is_multiple_of(N) {
            return None;
        }
        let b = self.take(4 * n)?;
        Some(
            b.chunks_exact(4 * N)
                .map(|c| {
                    std::array::from_fn(|k| {
                        f32::from_le_bytes(c[4 * k..4 * k + 4].try_into().expect("4 bytes"))
                    })
                })
                .collect(),
        )
    }
    pub fn u32s(&mut self) -> Option<Vec<u32>> {
        let n = self.usize_max((self.data.len() - self.at) / 4)?;
        let b = self.take(4 * n)?;
        Some(
            b.chunks_exact(4)
                .map(|c| u32::from_le_bytes(c.try_into().expect("4 bytes")))
                .collect(),
        )
    }
    pub fn image(&mut self) -> Option<crate::pyramid::Image> {
        let width = self.usize()?;
        let height = self.usize()?;
        let channels = self.usize()?;
        let data = self.f32s()?;
        (width.checked_mul(height)?.checked_mul(channels)? == data.len()).then_some(
            crate::pyramid::Image {
                width,
                height,
                channels,
                data,
            },
        )
    }
    /// True when every byte was read (a payload with trailing bytes is not ours).
    pub fn at_end(&self) -> bool {
        self.at == self.data.len()
    }
}

/// An analysis that can be saved: `load` must reject (return `None` for) anything
/// [`Persist::save`] did not write, and check sizes against each other.
pub trait Persist: Sized {
    fn save(&self, w: &mut Writer);
    fn load(r: &mut Reader<'_>) -> Option<Self>;
    /// Whether this value earns a file in the cache folder and a place in memory between
    /// uses (default: always). One that costs more to write and read back than to compute
    /// again, and is too large to keep for a later run of the process, says no: it is
    /// computed each time it is asked for ([`crate::synth::Analyses`]).
    fn worth_saving(&self) -> bool {
        true
    }
}

/// What a look-up found.
#[derive(Debug)]
pub enum Lookup {
    /// A whole, checked entry.
    Hit(Vec<u8>),
    /// No entry (or no cache).
    Miss,
    /// An entry that must not be trusted, and why (one line).
    Corrupt(String),
}

/// The file of entry (`kind`, `key`) in `dir`.
pub fn entry_path(dir: &Path, kind: &str, key: Key) -> PathBuf {
    dir.join(format!("{kind}-{}.bin", key.hex()))
}

fn header(kind: &str, key: Key, payload: &[u8]) -> Vec<u8> {
    let mut h = Vec::with_capacity(64);
    h.extend_from_slice(MAGIC);
    h.extend_from_slice(&FORMAT_VERSION.to_le_bytes());
    h.push(kind.len() as u8);
    h.extend_from_slice(kind.as_bytes());
    h.extend_from_slice(&key.0.to_le_bytes());
    h.extend_from_slice(&(payload.len() as u64).to_le_bytes());
    h.extend_from_slice(&xxh3_64(payload).to_le_bytes());
    h
}

/// Reads and checks entry (`kind`, `key`) from `dir`.
pub fn load(dir: &Path, kind: &str, key: Key) -> Lookup {
    let path = entry_path(dir, kind, key);
    let bytes = match std::fs::read(&path) {
        Ok(b) => b,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Lookup::Miss,
        Err(e) => return Lookup::Corrupt(format!("cannot read: {e}")),
    };
    let expected = header(kind, key, &[]);
    // Fixed part: magic, version, kind, key; then length and checksum.
    let fixed = expected.len() - 16;
    if bytes.len() < expected.len() {
        return Lookup::Corrupt(format!("truncated ({} bytes)", bytes.len()));
    }
    if bytes[..8] != expected[..8] {
        return Lookup::Corrupt("not a surfsynth cache file".into());
    }
    if bytes[8..12] != expected[8..12] {
        return Lookup::Corrupt("written by another format version".into());
    }
    if bytes[..fixed] != expected[..fixed] {
        return Lookup::Corrupt("its header names another entry".into());
    }
    let len = u64::from_le_bytes(bytes[fixed..fixed + 8].try_into().expect("8 bytes"));
    let sum = u64::from_le_bytes(bytes[fixed + 8..fixed + 16].try_into().expect("8 bytes"));
    let payload = &bytes[expected.len()..];
    if payload.len() as u64 != len {
        return Lookup::Corrupt(format!(
            "truncated or padded ({} payload bytes, header says {len})",
            payload.len()
        ));
    }
    if xxh3_64(payload) != sum {
        return Lookup::Corrupt("checksum mismatch".into());
    }
    Lookup::Hit(payload.to_vec())
}

/// Writes entry (`kind`, `key`) into `dir` (created if missing): a temporary file in the
/// same folder, then a rename, so readers never see a partial entry.
pub fn store(dir: &Path, kind: &str, key: Key, payload: &[u8]) -> std::io::Result<PathBuf> {
    use std::io::Write;
    std::fs::create_dir_all(dir)?;
    let path = entry_path(dir, kind, key);
    static COUNTER: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
    let tmp = dir.join(format!(
        ".{kind}-{}.{}.{}.tmp",
        key.hex(),
        std::process::id(),
        COUNTER.fetch_add(1, std::sync::atomic::Ordering::Relaxed)
    ));
    let result = (|| {
        let mut f = std::fs::File::create(&tmp)?;
        f.write_all(&header(kind, key, payload))?;
        f.write_all(payload)?;
        f.sync_data()?;
        drop(f);
        std::fs::rename(&tmp, &path)
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result.map(|()| path)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_and_every_kind_of_damage_is_detected() {
        let dir = tempfile::tempdir().unwrap();
        let key = KeyBuilder::new("test").u64(7).f32s(&[1.0, 2.5]).finish();
        assert_ne!(
            key,
            KeyBuilder::new("test").u64(8).f32s(&[1.0, 2.5]).finish()
        );
        assert_ne!(
            key,
            KeyBuilder::new("other").u64(7).f32s(&[1.0, 2.5]).finish()
        );
        assert!(matches!(load(dir.path(), "test", key), Lookup::Miss));
        let mut w = Writer::default();
        w.f32s(&[1.0, -2.0, 3.5]);
        w.u32s(&[7, 8]);
        w.bool(true);
        let path = store(dir.path(), "test", key, &w.0).unwrap();
        let Lookup::Hit(p) = load(dir.path(), "test", key) else {
            panic!("not a hit")
        };
        let mut r = Reader::new(&p);
        assert_eq!(r.f32s().unwrap(), vec![1.0, -2.0, 3.5]);
        assert_eq!(r.u32s().unwrap(), vec![7, 8]);
        assert_eq!(r.bool(), Some(true));
        assert!(r.at_end());
        assert_eq!(r.u64(), None, "reading past the end is None, not a panic");
        let good = std::fs::read(&path).unwrap();
        // Truncated, flipped payload byte, flipped header byte, extra bytes.
        let damage: Vec<Vec<u8>> = vec![
            good[..good.len() - 3].to_vec(),
            good[..10].to_vec(),
            {
                let mut b = good.clone();
                let i = b.len() - 5;
                b[i] ^= 0x40;
                b
            },
            {
                let mut b = good.clone();
                b[9] ^= 1;
                b
            },
            [good.clone(), vec![0]].concat(),
        ];
        for bad in damage {
            std::fs::write(&path, &bad).unwrap();
            assert!(matches!(load(dir.path(), "test", key), Lookup::Corrupt(_)));
        }
        // A garbled length never allocates absurdly.
        let mut w = Writer::default();
        w.u64(u64::MAX / 2);
        assert_eq!(Reader::new(&w.0).f32s(), None);
    }
}
