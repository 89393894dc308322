//! Sampling throughput, for `surfsynth bench` and docs/benchmarks.md.
//!
//! Single thread on purpose: the target is samples per second *per core*, and
//! patterns are independent, so throughput scales with cores.

use super::{Sampler, SamplerKind};
use crate::field::OrientationField;
use serde::Serialize;
use std::time::Instant;
use subdiv::{DomainId, DomainLocation, Surface};

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
}

/// Samples `patterns` K×K neighbourhoods at texel centres spread over all domains of an
/// `n`×`n` layout, δ = `step_texels` × the median texel spacing, with each sampler, on one
/// thread. Returns one entry per sampler.
pub fn bench_sampling(
    surface: &Surface,
    field: &OrientationField,
    n: usize,
    step_texels: f64,
    k: usize,
    patterns: usize,
) -> Vec<SamplingRate> {
    let delta = step_texels * super::median_texel_spacing(surface, n);
    let nd = surface.num_domains();
    let total = nd * n * n;
    // A fixed stride through all texels (coprime with typical sizes) spreads the centres.
    let centres: Vec<DomainLocation> = (0..patterns)
        .map(|i| {
            let t = (i * 7919 + 13) % total;
            let (d, r) = (t / (n * n), t % (n * n));
            DomainLocation {
                domain: DomainId::from_idx(d),
                u: ((r % n) as f64 + 0.5) / n as f64,
                v: ((r / n) as f64 + 0.5) / n as f64,
            }
        })
        .collect();
    let mut out = vec![None; k * k];
    let mut rates = Vec::new();
    for (name, kind, tol) in [
        ("chart", SamplerKind::Chart, Some(super::DEFAULT_TOLERANCE)),
        ("chart-unchecked", SamplerKind::Chart, None),
        ("march", SamplerKind::March, None),
    ] {
        let sampler = Sampler::new(surface, field).with_tolerance(tol);
        // Warm-up (builds the marching mesh outside the timed loop).
        sampler.sample(centres[0], delta, k, SamplerKind::March, &mut out);
        sampler.reset_stats();
        let t0 = Instant::now();
        for c in &centres {
            sampler.sample(*c, delta, k, kind, &mut out);
        }
        let secs = t0.elapsed().as_secs_f64();
        let st = sampler.stats();
        rates.push(SamplingRate {
            sampler: name.into(),
            k,
            step_texels,
            patterns,
            samples_per_second: (patterns * k * k) as f64 / secs.max(1e-12),
            fallback_rate: st.fallback_rate(),
        });
    }
    rates
}
