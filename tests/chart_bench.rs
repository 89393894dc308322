//! Instruction-count harness for chart sampling (the marched side is tests/march_bench.rs).
//!
//! Wall time on a shared 2-core machine is ±15–20%, so changes to the chart sampler were
//! measured in instructions: the chart-sampled patterns at the `bench sampling` centres
//! are collected once, then [`chart_loop`] samples them 4 times, and callgrind counts
//! only that loop:
//!
//! ```sh
//! cargo test --release --test chart_bench --no-run
//! CB_K=9 valgrind --tool=callgrind --toggle-collect='*chart_loop*' \
//!     target/release/deps/chart_bench-<hash> chart_patterns --ignored --nocapture
//! ```
//!
//! Settings (environment): `CB_MESH` (a path; default the bundled Spot), `CB_K` (5),
//! `CB_N` (centres tried, 1500), `CB_ONLY=reg|irr` (only patterns whose chart is that of a
//! regular / extraordinary vertex), `CB_REF=path` (store every sample's position at
//! `path_K.bin` on the first run, report the largest difference from it on later runs:
//! refactors must show 0).
mod common;

use common::env_or;
use glam::DVec3;
use subdiv::DomainLocation;
use surfsynth::bench::sampling::bench_centres;
use surfsynth::field::{Orientation, OrientationField};
use surfsynth::sampling::{median_texel_spacing, Method, Sampler, SamplerKind};

#[inline(never)]
fn chart_loop(
    s: &Sampler,
    cs: &[DomainLocation],
    delta: f64,
    k: usize,
    out: &mut [Option<DomainLocation>],
) -> usize {
    let mut n = 0;
    for _ in 0..4 {
        for c in cs {
            if let Method::Chart(_) = s.sample(*c, delta, k, SamplerKind::Chart, out).method {
                n += 1;
            }
        }
    }
    n
}

#[test]
#[ignore]
fn chart_patterns() {
    let (k, tried, n) = (env_or("CB_K", 5usize), env_or("CB_N", 1500usize), 32);
    let surface = match std::env::var("CB_MESH") {
        Ok(p) => surfsynth::bake::load_surface_for(std::path::Path::new(&p), n).unwrap(),
        Err(_) => surfsynth::bake::surface_for(surfsynth::demo::control_mesh(), n),
    };
    let field = OrientationField::compute(&surface, &Orientation::Auto).unwrap();
    let delta = median_texel_spacing(&surface, n);
    let sampler = Sampler::new(&surface, &field);
    let mut out = vec![None; k * k];
    // The centres of `surfsynth bench sampling` (bench::sampling), chart-sampled ones only.
    let only = std::env::var("CB_ONLY").unwrap_or_default();
    let centres: Vec<DomainLocation> = bench_centres(&surface, n, tried)
        .into_iter()
        .filter(|c| {
            match sampler
                .sample(*c, delta, k, SamplerKind::Chart, &mut out)
                .method
            {
                Method::Chart(v) => match only.as_str() {
                    "reg" => surface.base.is_regular_vertex(v),
                    "irr" => !surface.base.is_regular_vertex(v),
                    _ => true,
                },
                Method::March => false,
            }
        })
        .collect();
    let mut pos = Vec::with_capacity(centres.len() * k * k);
    for c in &centres {
        sampler.sample(*c, delta, k, SamplerKind::Chart, &mut out);
        pos.extend(
            out.iter()
                .map(|o| o.map_or(DVec3::NAN, |x| surface.eval(x.domain, x.u, x.v).p)),
        );
    }
    if let Ok(r) = std::env::var("CB_REF") {
        let path = format!("{r}_{k}.bin");
        match std::fs::read(&path) {
            Ok(bytes) => {
                let old: Vec<f64> = bytes
                    .chunks(8)
                    .map(|b| f64::from_le_bytes(b.try_into().unwrap()))
                    .collect();
                assert_eq!(old.len(), 3 * pos.len(), "{path}: another set of patterns");
                let worst = pos
                    .iter()
                    .zip(old.chunks(3))
                    .map(|(p, q)| (*p - DVec3::new(q[0], q[1], q[2])).length() / delta)
                    .filter(|d| !d.is_nan())
                    .fold(0.0, f64::max);
                println!("largest difference from {path}: {worst:.2e} δ");
            }
            Err(_) => {
                let b: Vec<u8> = pos
                    .iter()
                    .flat_map(|p| p.to_array())
                    .flat_map(f64::to_le_bytes)
                    .collect();
                std::fs::write(&path, b).unwrap();
                println!("stored {path}");
            }
        }
    }
    let t0 = std::time::Instant::now();
    let sampled = chart_loop(&sampler, &centres, delta, k, &mut out);
    let secs = t0.elapsed().as_secs_f64();
    println!(
        "{} chart-sampled patterns (K = {k}) x 4 = {sampled}: {:.2} M samples/s",
        centres.len(),
        (sampled * k * k) as f64 / secs / 1e6
    );
    assert_eq!(sampled, 4 * centres.len());
}
