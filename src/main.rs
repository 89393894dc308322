//! The `surfsynth` command line. Only argument handling and error reporting live here;
//! the work is in the library.
//!
//! Exit codes: 0 success, 1 error (one line `error: ...` on stderr), 2 usage error (also
//! one line), 101 internal error (a bug: one line, never a panic dump), 130 / 143
//! interrupted by SIGINT / SIGTERM (one line; nothing partial left in `--out`).

mod cli;

use std::panic;
use std::sync::atomic::{AtomicBool, Ordering};

/// Installed first thing: a panic anywhere (also on rayon worker threads) prints one line
/// instead of Rust's multi-line panic report. Only the first panic is reported: rayon may
/// panic on several threads while unwinding the same failure.
fn install_panic_hook() {
    static REPORTED: AtomicBool = AtomicBool::new(false);
    panic::set_hook(Box::new(|info| {
        if REPORTED.swap(true, Ordering::SeqCst) {
            return;
        }
        let msg = info
            .payload()
            .downcast_ref::<&str>()
            .map(|s| s.to_string())
            .or_else(|| info.payload().downcast_ref::<String>().cloned())
            .unwrap_or_else(|| "unknown failure".into());
        let at = info
            .location()
            .map(|l| format!(" (at {}:{})", l.file(), l.line()))
            .unwrap_or_default();
        eprintln!(
            "error: internal error: {}{at}; please report this as a bug",
            surfsynth::error::one_line(&msg)
        );
    }));
}

fn main() {
    install_panic_hook();
    // Freed memory goes back to the system (peak RSS; surfsynth::memory::tune_allocator).
    surfsynth::memory::tune_allocator();
    // SIGINT / SIGTERM: remove staging folders and temporaries, one line, exit 130 / 143
    // (surfsynth::io::interrupt). Without it the default action (die at once) stays.
    let _ = surfsynth::io::interrupt::install();
    // Unwinding (rather than exiting inside the hook) runs destructors, so atomic output
    // files remove their temporaries even after a bug.
    let code = panic::catch_unwind(cli::main).unwrap_or(101);
    std::process::exit(code);
}
