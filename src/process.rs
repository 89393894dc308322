//! What this process has used so far: peak and current resident memory, CPU seconds
//! (Linux `/proc`; `None` elsewhere). The report's peak memory, the renders' summary and
//! the benchmarks read them.

/// A `/proc/self/status` field in bytes (Linux; `None` elsewhere).
fn proc_status_bytes(field: &str) -> Option<u64> {
    let s = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = s.lines().find(|l| l.starts_with(field))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024)
}

/// CPU time (user + system, all threads) of this process so far, in seconds (Linux; the
/// kernel reports it in USER_HZ = 100 ticks per second on every architecture we target).
/// On a shared machine CPU time is steadier than wall time: texels per CPU-second times
/// the number of idle cores bounds what a quiet machine would do.
pub fn cpu_seconds() -> Option<f64> {
    let s = std::fs::read_to_string("/proc/self/stat").ok()?;
    let after = &s[s.rfind(')')? + 1..];
    let f: Vec<&str> = after.split_whitespace().collect();
    let utime: f64 = f.get(11)?.parse().ok()?;
    let stime: f64 = f.get(12)?.parse().ok()?;
    Some((utime + stime) / 100.0)
}

/// Peak resident set size of this process so far (VmHWM).
pub fn peak_rss_bytes() -> Option<u64> {
    proc_status_bytes("VmHWM:")
}

/// Starts a new peak: VmHWM becomes the current RSS (Linux `/proc/self/clear_refs`, value
/// 5). For a stage run after others in one process — `demo`'s renders after its syntheses —
/// whose own peak is what its summary line should show beside its estimate. Does nothing
/// where the file is absent or not writable.
pub fn reset_peak_rss() {
    let _ = std::fs::write("/proc/self/clear_refs", "5");
}

/// Current resident set size (VmRSS).
pub fn current_rss_bytes() -> Option<u64> {
    proc_status_bytes("VmRSS:")
}

#[cfg(test)]
mod tests {
    #[test]
    fn reset_peak_rss_starts_a_new_peak() {
        if std::fs::metadata("/proc/self/clear_refs").is_err() {
            return; // not Linux: nothing to reset
        }
        let big = vec![1u8; 256 << 20];
        std::hint::black_box(&big);
        drop(big); // above the mmap threshold: returned to the system
        let high = super::peak_rss_bytes().unwrap();
        super::reset_peak_rss();
        let after = super::peak_rss_bytes().unwrap();
        assert!(after + (128 << 20) < high, "peak {high} -> {after}");
    }
}
