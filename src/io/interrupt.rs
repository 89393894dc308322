//! SIGINT and SIGTERM: what is half-written is removed, one line says so, exit 130 / 143.
//!
//! Without a handler the kernel ends the process on the spot and leaves whatever was being
//! written behind (a 58 MB `.facemaps.exr.tmp-PID`, a half-new set of files). Unwinding
//! from a signal is not possible in Rust, and the work runs on rayon threads that cannot be
//! cancelled cooperatively everywhere, so instead:
//!
//! - everything that would be *partial* if the process stopped now — temporary files
//!   ([`crate::io::atomic::AtomicFile`]), staging folders ([`crate::io::txn::OutputTxn`]),
//!   parent folders a run created, scratch folders of benchmarks — is `register`ed while
//!   it exists;
//! - [`install`] (called first thing by the command line) starts one thread that waits for
//!   the signals (signal-hook's self-pipe iterator: nothing runs inside the signal handler
//!   itself). On a signal it records it ([`interrupted`]), waits until no output directory
//!   is in the middle of being swapped into place ([`commit_lock`]: a commit that sees the
//!   signal rolls back first), removes what is registered, prints one line and exits with
//!   128 + the signal number.
//!
//! Library users who do not call [`install`] keep the default behaviour; the registry then
//! costs a mutex per file.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicI32, AtomicU64, Ordering};
use std::sync::{Mutex, MutexGuard};

/// What a registration removes.
#[derive(Clone, Debug)]
enum Kind {
    /// A file (a temporary).
    File,
    /// A folder and everything in it (staging, benchmark scratch).
    Tree,
    /// A folder only if it is empty (a parent a run created for its output).
    EmptyDir,
}

struct Entry {
    id: u64,
    path: PathBuf,
    kind: Kind,
    /// For the interruption message: an output directory left as it was.
    untouched: Option<PathBuf>,
}

static REGISTRY: Mutex<Vec<Entry>> = Mutex::new(Vec::new());
static NEXT_ID: AtomicU64 = AtomicU64::new(1);
static SIGNAL: AtomicI32 = AtomicI32::new(0);
static COMMIT: Mutex<()> = Mutex::new(());

fn registry() -> MutexGuard<'static, Vec<Entry>> {
    REGISTRY.lock().unwrap_or_else(|e| e.into_inner())
}

/// A registration; dropping it unregisters (the path is then the owner's business again).
#[derive(Debug)]
pub struct Registered(u64);

impl Drop for Registered {
    fn drop(&mut self) {
        registry().retain(|e| e.id != self.0);
    }
}

fn add(path: &Path, kind: Kind, untouched: Option<&Path>) -> Registered {
    let id = NEXT_ID.fetch_add(1, Ordering::Relaxed);
    registry().push(Entry {
        id,
        path: path.to_path_buf(),
        kind,
        untouched: untouched.map(Path::to_path_buf),
    });
    Registered(id)
}

/// Removes `path` (a file) if the process is interrupted while the registration lives.
pub fn register_file(path: &Path) -> Registered {
    add(path, Kind::File, None)
}

/// Removes the folder `path` with its contents if the process is interrupted.
pub fn register_tree(path: &Path) -> Registered {
    add(path, Kind::Tree, None)
}

/// Like [`register_tree`] for the staging folder of output directory `out`: the message
/// then says that `out` was left as it was.
pub fn register_staging(path: &Path, out: &Path) -> Registered {
    add(path, Kind::Tree, Some(out))
}

/// Removes the folder `path` if it is empty when the process is interrupted.
pub fn register_empty_dir(path: &Path) -> Registered {
    add(path, Kind::EmptyDir, None)
}

/// The signal number once SIGINT or SIGTERM has arrived (work in progress may check it to
/// stop early; commits check it to roll back).
pub fn interrupted() -> Option<i32> {
    match SIGNAL.load(Ordering::SeqCst) {
        0 => None,
        s => Some(s),
    }
}

/// Held while an output directory is being swapped into place, so that an interruption
/// waits for the commit to finish or roll back instead of cleaning up half-way through it.
pub fn commit_lock() -> MutexGuard<'static, ()> {
    COMMIT.lock().unwrap_or_else(|e| e.into_inner())
}

fn signal_name(sig: i32) -> &'static str {
    match sig {
        signal_hook::consts::SIGINT => "SIGINT",
        signal_hook::consts::SIGTERM => "SIGTERM",
        _ => "a signal",
    }
}

/// Removes everything registered (latest first, so files go before the folders they are
/// in, and created parents after their children) and returns the output directories that
/// were left as they were.
fn clean_up() -> Vec<PathBuf> {
    let entries: Vec<(PathBuf, Kind, Option<PathBuf>)> = registry()
        .iter()
        .rev()
        .map(|e| (e.path.clone(), e.kind.clone(), e.untouched.clone()))
        .collect();
    let mut untouched = Vec::new();
    for (path, kind, out) in entries {
        match kind {
            Kind::File => {
                let _ = std::fs::remove_file(&path);
            }
            Kind::Tree => {
                // A worker thread may still be creating a file inside: retry a few times.
                for _ in 0..50 {
                    match std::fs::remove_dir_all(&path) {
                        Err(e) if e.kind() != std::io::ErrorKind::NotFound => {
                            std::thread::sleep(std::time::Duration::from_millis(2))
                        }
                        _ => break,
                    }
                }
            }
            Kind::EmptyDir => {
                let _ = std::fs::remove_dir(&path);
            }
        }
        untouched.extend(out);
    }
    untouched
}

/// Starts the thread that handles SIGINT and SIGTERM (see the module docs). Call once, at
/// the start of the program; an error means the handlers could not be installed (the
/// default behaviour then stays).
pub fn install() -> std::io::Result<()> {
    use signal_hook::consts::{SIGINT, SIGTERM};
    let mut signals = signal_hook::iterator::Signals::new([SIGINT, SIGTERM])?;
    std::thread::Builder::new()
        .name("signals".into())
        .spawn(move || {
            if let Some(sig) = signals.forever().next() {
                SIGNAL.store(sig, Ordering::SeqCst);
                // A commit in progress sees the signal and rolls back (or has passed the
                // point of no return and finishes); either way it releases this lock.
                let _commit = commit_lock();
                let untouched = clean_up();
                let what = match untouched.first() {
                    Some(out) => format!("; {} was left as it was", out.display()),
                    None => String::new(),
                };
                eprintln!("error: interrupted by {}{what}", signal_name(sig));
                std::process::exit(128 + sig);
            }
        })?;
    Ok(())
}

/// For code that returns after noticing [`interrupted`]: waits for the signal thread to
/// end the process (it prints the one line and chooses the exit code), so that the caller
/// does not print a second message.
pub fn wait_for_exit() -> ! {
    loop {
        std::thread::sleep(std::time::Duration::from_secs(1));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn registrations_come_and_go() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("x");
        let r = register_file(&p);
        assert!(registry().iter().any(|e| e.path == p));
        drop(r);
        assert!(!registry().iter().any(|e| e.path == p));
        assert_eq!(interrupted(), None);
    }
}
