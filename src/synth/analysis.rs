//! The example side of synthesis, computed once: every per-example analysis a method
//! needs (appearance space, jump maps, k-coherence lists) is asked for through an
//! [`Analyses`] store, which keeps it in memory for further runs of the same process (a
//! prepared session re-synthesizing with another seed or method) and in the on-disk cache
//! of [`crate::cache`] for further processes.
//!
//! A method names what it needs by a [`Key`] built from the pixels and parameters the
//! analysis depends on, and gives the function that computes it; the store returns the
//! shared result, saying in [`Analyses::events`] whether it came from memory, from the
//! disk cache, or was built (and why: no entry, or an entry that failed its checks and was
//! rebuilt). report.json carries those events.

use crate::cache::{self, CacheDir, Key, Lookup, Persist, Reader, Writer};
use serde::{Deserialize, Serialize};
use std::any::Any;
use std::collections::HashMap;
use std::path::PathBuf;
use std::sync::{Arc, Mutex};
use std::time::Instant;

/// Where an analysis came from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Source {
    /// Already in this process (e.g. an earlier run of the same session).
    Memory,
    /// Loaded from the disk cache.
    Hit,
    /// Computed: no cache entry (saved afterwards when there is a cache and the value is
    /// worth a file, [`crate::cache::Persist::worth_saving`]).
    Miss,
    /// Computed: the entry was truncated, corrupt or of another version (rewritten).
    Rebuilt,
    /// Computed without a disk cache.
    Off,
}

/// One analysis a run used (report.json `cache.entries`).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Event {
    /// What was analysed ("jumpmap", "multiscale-model", ...).
    pub kind: String,
    pub source: Source,
    /// Seconds spent getting it (loading or computing, and saving).
    pub seconds: f64,
    /// Bytes of the saved entry (0 when nothing was read or written).
    pub bytes: u64,
}

/// What report.json says about the cache.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct CacheReport {
    /// The cache folder, `null` without one.
    pub dir: Option<String>,
    /// True when every analysis of the run came from memory or the disk cache.
    pub hit: bool,
    pub entries: Vec<Event>,
}

type Shared = Arc<dyn Any + Send + Sync>;

/// Where an analysis being built reports how far it is: `(done, total)`, in whatever unit
/// it counts (pixels, lists); `(0, 1)` when it starts and `(1, 1)` when it is done.
pub type BuildProgress = Arc<dyn Fn(usize, usize) + Send + Sync>;

/// Per-example analyses of one process (see the module docs). Cheap to share: clone the
/// `Arc` around it, or keep one per example.
pub struct Analyses {
    dir: Option<PathBuf>,
    memo: Mutex<HashMap<(String, Key), Shared>>,
    events: Mutex<Vec<Event>>,
    /// A save already failed and said so: a folder that cannot be written costs one
    /// warning per store, not one per analysis (the pf summary saves three banks).
    save_warned: std::sync::atomic::AtomicBool,
    /// Told about analyses being built ([`Analyses::set_progress`]): a first run with a
    /// large example can spend minutes here (a 1024² example's jump map: ~150 CPU-s), and
    /// a progress bar that stood still that long looked like a hang.
    progress: Mutex<Option<BuildProgress>>,
}

impl std::fmt::Debug for Analyses {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Analyses")
            .field("dir", &self.dir)
            .finish_non_exhaustive()
    }
}

impl Default for Analyses {
    /// No disk cache.
    fn default() -> Self {
        Self::new(&CacheDir::Off)
    }
}

impl Analyses {
    /// A store saving into `dir` ([`CacheDir::resolve`]).
    pub fn new(dir: &CacheDir) -> Self {
        Self {
            dir: dir.resolve(),
            memo: Mutex::new(HashMap::new()),
            save_warned: Default::default(),
            events: Mutex::new(Vec::new()),
            progress: Mutex::new(None),
        }
    }

    /// Sets (or, with `None`, clears) where analyses built from now on report their
    /// progress. A session sets it for the span of one synthesis.
    pub fn set_progress(&self, hook: Option<BuildProgress>) {
        *self.progress.lock().unwrap_or_else(|e| e.into_inner()) = hook;
    }

    /// Reports `(done, total)` of the analysis being built (nothing without a hook):
    /// what a long builder calls as it goes.
    pub fn progress(&self, done: usize, total: usize) {
        let hook = self
            .progress
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .clone();
        if let Some(h) = hook {
            h(done, total);
        }
    }

    /// The disk cache folder.
    pub fn dir(&self) -> Option<&std::path::Path> {
        self.dir.as_deref()
    }

    /// The analysis of `kind` under `key`: from memory, else the disk cache, else
    /// `build()` (then saved). A bad entry is reported with one warning line on stderr and
    /// rebuilt.
    pub fn get<T, F>(&self, kind: &str, key: Key, build: F) -> Arc<T>
    where
        T: Persist + Send + Sync + 'static,
        F: FnOnce() -> T,
    {
        self.try_get(kind, key, || Ok::<T, std::convert::Infallible>(build()))
            .unwrap_or_else(|e| match e {})
    }

    /// [`Analyses::get`] with a fallible build (its error is returned, nothing saved).
    pub fn try_get<T, E, F>(&self, kind: &str, key: Key, build: F) -> Result<Arc<T>, E>
    where
        T: Persist + Send + Sync + 'static,
        F: FnOnce() -> Result<T, E>,
    {
        let t0 = Instant::now();
        let id = (kind.to_string(), key);
        let memo = self
            .memo
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .get(&id)
            .cloned();
        if let Some(v) = memo.and_then(|v| v.downcast::<T>().ok()) {
            self.record(kind, Source::Memory, t0, 0);
            return Ok(v);
        }
        let mut source = Source::Off;
        if let Some(dir) = &self.dir {
            source = Source::Miss;
            match cache::load(dir, kind, key) {
                Lookup::Hit(bytes) => {
                    let mut r = Reader::new(&bytes);
                    match T::load(&mut r).filter(|_| r.at_end()) {
                        Some(v) => {
                            let v = Arc::new(v);
                            self.remember(id, v.clone());
                            self.record(kind, Source::Hit, t0, bytes.len() as u64);
                            return Ok(v);
                        }
                        None => {
                            warn_corrupt(dir, kind, key, "its contents do not decode");
                            source = Source::Rebuilt;
                        }
                    }
                }
                Lookup::Miss => {}
                Lookup::Corrupt(why) => {
                    warn_corrupt(dir, kind, key, &why);
                    source = Source::Rebuilt;
                }
            }
        }
        self.progress(0, 1);
        let v = Arc::new(build()?);
        self.progress(1, 1);
        let mut bytes = 0;
        if let Some(dir) = self.dir.as_ref().filter(|_| v.worth_saving()) {
            let mut w = Writer::default();
            v.save(&mut w);
            match cache::store(dir, kind, key, &w.0) {
                Ok(_) => bytes = w.0.len() as u64,
                Err(e) => {
                    if !self
                        .save_warned
                        .swap(true, std::sync::atomic::Ordering::Relaxed)
                    {
                        eprintln!(
                            "warning: cannot save the {kind} analysis in the cache folder {}: {e} (the run goes on without it)",
                            dir.display()
                        )
                    }
                }
            }
        }
        if v.worth_saving() {
            self.remember(id, v.clone());
        }
        self.record(kind, source, t0, bytes);
        Ok(v)
    }

    fn remember(&self, id: (String, Key), v: Shared) {
        self.memo
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .insert(id, v);
    }

    fn record(&self, kind: &str, source: Source, t0: Instant, bytes: u64) {
        self.events
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .push(Event {
                kind: kind.into(),
                source,
                seconds: t0.elapsed().as_secs_f64(),
                bytes,
            });
    }

    /// Every look-up so far, in order.
    pub fn events(&self) -> Vec<Event> {
        self.events
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .clone()
    }

    /// Takes the events recorded so far (one run's share, for its report).
    pub fn take_events(&self) -> Vec<Event> {
        std::mem::take(&mut *self.events.lock().unwrap_or_else(|e| e.into_inner()))
    }

    /// The report of `events` (usually one run's [`Analyses::take_events`]).
    pub fn report(&self, events: Vec<Event>) -> CacheReport {
        CacheReport {
            dir: self.dir.as_ref().map(|d| d.display().to_string()),
            hit: !events.is_empty()
                && events
                    .iter()
                    .all(|e| matches!(e.source, Source::Memory | Source::Hit)),
            entries: events,
        }
    }
}

fn warn_corrupt(dir: &std::path::Path, kind: &str, key: Key, why: &str) {
    eprintln!(
        "warning: cache entry {} is not usable ({why}); rebuilding it",
        cache::entry_path(dir, kind, key).display()
    );
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A value to store: a number, worth saving (and keeping) when `KEEP`.
    struct Value<const KEEP: bool>(u64);
    impl<const KEEP: bool> Persist for Value<KEEP> {
        fn save(&self, w: &mut Writer) {
            w.u64(self.0);
        }
        fn load(r: &mut Reader<'_>) -> Option<Self> {
            r.u64().map(Value)
        }
        fn worth_saving(&self) -> bool {
            KEEP
        }
    }
    type N = Value<true>;
    type Big = Value<false>;

    /// A build is announced (0 of 1), may report its own counts through
    /// [`Analyses::progress`], and ends with 1 of 1; a value from memory reports nothing,
    /// and neither does anything once the hook is cleared.
    #[test]
    fn builds_report_progress_and_memory_hits_do_not() {
        let a = Analyses::default();
        let seen = Arc::new(Mutex::new(Vec::new()));
        let log = seen.clone();
        a.set_progress(Some(Arc::new(move |d, t| log.lock().unwrap().push((d, t)))));
        let key = crate::cache::KeyBuilder::new("test").u64(1).finish();
        let v = a.get("test", key, || -> N {
            a.progress(5, 10);
            Value(7)
        });
        assert_eq!(v.0, 7);
        assert_eq!(*seen.lock().unwrap(), [(0, 1), (5, 10), (1, 1)]);
        let again = a.get("test", key, || -> N { Value(8) });
        assert_eq!(again.0, 7, "from memory");
        assert_eq!(seen.lock().unwrap().len(), 3);
        a.set_progress(None);
        let other = crate::cache::KeyBuilder::new("test").u64(2).finish();
        a.get("test", other, || -> N { Value(9) });
        assert_eq!(seen.lock().unwrap().len(), 3);
    }

    /// A value too large to keep (here: any, `worth_saving` false) is neither saved nor
    /// remembered: asked again, it is built again.
    #[test]
    fn values_not_worth_saving_are_built_each_time() {
        let dir = std::env::temp_dir().join(format!("surfsynth-big-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let a = Analyses::new(&CacheDir::Dir(dir.clone()));
        let key = crate::cache::KeyBuilder::new("big").u64(1).finish();
        assert_eq!(a.get("big", key, || -> Big { Value(1) }).0, 1);
        assert_eq!(
            a.get("big", key, || -> Big { Value(2) }).0,
            2,
            "built again"
        );
        let files = std::fs::read_dir(&dir).map(|d| d.count()).unwrap_or(0);
        assert_eq!(files, 0, "nothing saved");
        let _ = std::fs::remove_dir_all(&dir);
    }
}
