//! Sampling throughput, for `surfsynth bench` and docs/benchmarks.md.
//!
//! Single thread on purpose: the target is samples per second *per core*, and
//! patterns are independent, so throughput scales with cores.

use crate::field::OrientationField;
use crate::sampling::{Method, Sampler, SamplerKind};
use serde::Serialize;
use std::time::Instant;
use subdiv::{DomainId, DomainLocation, Surface};

/// Passes over the centres per sampler; the fastest is reported. On a shared machine a
/// single pass varied by ±30% from run to run (other load, clock changes), and
/// interference only ever slows a pass down, so the fastest is the least disturbed.
pub const ROUNDS: usize = 3;

/// Seconds and pattern counts of one pass, by the method each pattern got.
#[derive(Clone, Copy, Debug, Default)]
struct Times {
    total_s: f64,
    chart_s: f64,
    chart_n: usize,
    march_s: f64,
    march_n: usize,
}

impl Times {
    /// Each time the smaller of the two passes' (the counts are the same: sampling is
    /// deterministic).
    fn min(&self, o: &Times) -> Times {
        debug_assert_eq!((self.chart_n, self.march_n), (o.chart_n, o.march_n));
        Times {
            total_s: self.total_s.min(o.total_s),
            chart_s: self.chart_s.min(o.chart_s),
            march_s: self.march_s.min(o.march_s),
            ..*self
        }
    }
}

/// One measured configuration.
#[derive(Clone, Debug, Serialize)]
pub struct SamplingRate {
    /// `chart` (with the 3D check), `chart-unchecked` (the paper's acceptance), `march`.
    pub sampler: String,
    pub k: usize,
    /// δ in texel spacings at the benchmark resolution.
    pub step_texels: f64,
    pub patterns: usize,
    pub samples_per_second: f64,
    /// Share of chart patterns that were marched instead.
    pub fallback_rate: f64,
    /// Chart samplers: samples/s over the patterns that were chart-sampled alone (each
    /// pattern is timed; the fallbacks are marching, reported by `marched_samples_per_second`).
    pub chart_sampled_samples_per_second: Option<f64>,
    /// Chart samplers: samples/s over the patterns that fell back to marching.
    pub marched_samples_per_second: Option<f64>,
}

/// The pattern centres the benchmark samples: `count` texel centres of an `n`×`n` layout,
/// spread over all domains by a fixed stride through the texels (coprime with typical
/// sizes), so that every run and tests/chart_bench.rs see the same ones.
pub fn bench_centres(surface: &Surface, n: usize, count: usize) -> Vec<DomainLocation> {
    let total = surface.num_domains() * n * n;
    (0..count)
        .map(|i| {
            let t = (i * 7919 + 13) % total;
            let (d, r) = (t / (n * n), t % (n * n));
            DomainLocation {
                domain: DomainId::from_idx(d),
                u: ((r % n) as f64 + 0.5) / n as f64,
                v: ((r / n) as f64 + 0.5) / n as f64,
            }
        })
        .collect()
}

/// Samples `patterns` K×K neighbourhoods at texel centres spread over all domains of an
/// `n`×`n` layout, δ = `step_texels` × the median texel spacing, with each sampler, on one
/// thread, [`ROUNDS`] times (the fastest pass counts). Returns one entry per sampler.
pub fn bench_sampling(
    surface: &Surface,
    field: &OrientationField,
    n: usize,
    step_texels: f64,
    k: usize,
    patterns: usize,
) -> Vec<SamplingRate> {
    let delta = step_texels * crate::sampling::median_texel_spacing(surface, n);
    let centres = bench_centres(surface, n, patterns);
    let mut out = vec![None; k * k];
    let mut rates = Vec::new();
    for (name, kind, tol) in [
        (
            "chart",
            SamplerKind::Chart,
            Some(crate::sampling::DEFAULT_TOLERANCE),
        ),
        ("chart-unchecked", SamplerKind::Chart, None),
        ("march", SamplerKind::March, None),
    ] {
        let sampler = Sampler::new(surface, field).with_tolerance(tol);
        // Warm-up (builds the marching mesh outside the timed loop).
        sampler.sample(centres[0], delta, k, SamplerKind::March, &mut out);
        sampler.reset_stats();
        // Per-method time (one clock read per pattern: ~1% of a 5×5 pattern's cost), best
        // of `ROUNDS` passes over the same centres.
        let mut best = Times::default();
        for round in 0..ROUNDS {
            if round > 0 {
                sampler.reset_stats();
            }
            let mut t = Times::default();
            let t0 = Instant::now();
            let mut last = t0;
            for c in &centres {
                let info = sampler.sample(*c, delta, k, kind, &mut out);
                let now = Instant::now();
                let dt = (now - last).as_secs_f64();
                last = now;
                match info.method {
                    Method::Chart(_) => (t.chart_s, t.chart_n) = (t.chart_s + dt, t.chart_n + 1),
                    Method::March => (t.march_s, t.march_n) = (t.march_s + dt, t.march_n + 1),
                }
            }
            t.total_s = t0.elapsed().as_secs_f64();
            best = if round == 0 { t } else { best.min(&t) };
        }
        let Times {
            total_s: secs,
            chart_s,
            chart_n,
            march_s,
            march_n,
        } = best;
        let st = sampler.stats();
        let rate = |n: usize, s: f64| (n > 0).then(|| (n * k * k) as f64 / s.max(1e-12));
        let chart = kind == SamplerKind::Chart;
        rates.push(SamplingRate {
            sampler: name.into(),
            k,
            step_texels,
            patterns,
            samples_per_second: (patterns * k * k) as f64 / secs.max(1e-12),
            fallback_rate: st.fallback_rate(),
            chart_sampled_samples_per_second: rate(chart_n, chart_s).filter(|_| chart),
            marched_samples_per_second: rate(march_n, march_s).filter(|_| chart),
        });
    }
    rates
}
