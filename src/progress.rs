//! Progress bars and end-of-run summaries on the terminal.
//!
//! Bars go to stderr and only when stderr is a terminal: piped or captured runs (CI, tests,
//! `2> log`) get no escape codes, and stderr stays reserved for the one-line error contract.
//! Every long stage should use [`bar`] so the look is the same across subcommands.

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use std::io::IsTerminal;
use std::time::Instant;

/// True when progress bars will be drawn.
pub fn enabled() -> bool {
    std::io::stderr().is_terminal()
}

/// A bar counting `len` items of a stage called `label` (e.g. "bake", "domains").
/// Hidden when stderr is not a terminal.
pub fn bar(len: u64, label: &str) -> ProgressBar {
    if !enabled() {
        return ProgressBar::hidden();
    }
    let style = ProgressStyle::with_template(
        "{prefix:>10.bold} [{bar:32}] {pos}/{len} {msg} ({elapsed}, eta {eta})",
    )
    .expect("static template is valid")
    .progress_chars("=> ");
    ProgressBar::with_draw_target(Some(len), ProgressDrawTarget::stderr())
        .with_style(style)
        .with_prefix(label.to_string())
}

/// A spinner for a stage of unknown length.
pub fn spinner(label: &str) -> ProgressBar {
    if !enabled() {
        return ProgressBar::hidden();
    }
    let style = ProgressStyle::with_template("{prefix:>10.bold} {spinner} {msg} ({elapsed})")
        .expect("static template is valid");
    let pb = ProgressBar::with_draw_target(None, ProgressDrawTarget::stderr())
        .with_style(style)
        .with_prefix(label.to_string());
    pb.enable_steady_tick(std::time::Duration::from_millis(120));
    pb
}

/// Named wall-clock stage times, in the order they ran (for summaries and report.json).
#[derive(Clone, Debug, Default)]
pub struct StageTimes {
    pub stages: Vec<(String, f64)>,
}

impl StageTimes {
    pub fn new() -> Self {
        Self::default()
    }

    /// Runs `f` as stage `name` and records its duration.
    pub fn time<T>(&mut self, name: &str, f: impl FnOnce() -> T) -> T {
        let t = Instant::now();
        let v = f();
        self.stages
            .push((name.to_string(), t.elapsed().as_secs_f64()));
        v
    }

    /// Sum of all stages.
    pub fn total(&self) -> f64 {
        self.stages.iter().map(|(_, s)| s).sum()
    }

    /// Seconds of one stage (0 when it did not run).
    pub fn get(&self, name: &str) -> f64 {
        self.stages
            .iter()
            .filter(|(n, _)| n == name)
            .map(|(_, s)| s)
            .sum()
    }
}

/// Formats a rate like `5.21M` (texels/s and the like), for one-line summaries.
pub fn si(v: f64) -> String {
    let a = v.abs();
    if a >= 1e9 {
        format!("{:.2}G", v / 1e9)
    } else if a >= 1e6 {
        format!("{:.2}M", v / 1e6)
    } else if a >= 1e3 {
        format!("{:.1}k", v / 1e3)
    } else {
        format!("{v:.0}")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn si_and_stage_times() {
        assert_eq!(si(5_210_000.0), "5.21M");
        assert_eq!(si(1500.0), "1.5k");
        assert_eq!(si(12.0), "12");
        let mut s = StageTimes::new();
        let v = s.time("a", || 3);
        assert_eq!(v, 3);
        assert_eq!(s.stages.len(), 1);
        assert!(s.get("a") >= 0.0 && s.get("b") == 0.0);
    }
}
