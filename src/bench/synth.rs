//! `surfsynth bench synth`: speed of coherent synthesis (issue 4's performance targets).
//!
//! Two cases, both on Spot (the bundled fixture, 252 face domains, so anyone can rerun
//! them with the binary alone):
//! - **spot-n32**: N = 32 (258,048 texels) with the bundled 128x128 gravel example — the
//!   issue's target: synthesis stage >= 500k texels/s on 2 cores (goal 1M);
//! - **cow-row**: the paper's Cow row (Ying et al. 2001, §6: 369,664 texels, 96x96 example,
//!   coherent, 3 minutes in 2001): N = 38 gives 363,888 texels; the example is the centre
//!   96x96 crop of the same gravel.
//!
//! Each case runs the whole `synth` pipeline into a temporary directory (loading, field,
//! graph, synthesis, all output files) `repeats` times and reports the median of the
//! synthesis stage alone and of the whole run, as texels/s, plus peak memory per texel.
//! Results do not depend on the thread count, only the times do.

use crate::error::{Error, Result};
use crate::example::Example;
use crate::io::atomic::write_bytes_atomic;
use crate::synthesizer::Synthesizer;
use serde::Serialize;
use std::path::Path;

/// One benchmark case's figures.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct SynthBenchRow {
    pub case: String,
    pub mesh: String,
    pub example: String,
    pub example_size: [usize; 2],
    pub resolution: usize,
    pub faces: usize,
    pub texels: u64,
    pub threads: usize,
    pub repeats: usize,
    /// Median seconds of the synthesis stage.
    pub synthesis_seconds: f64,
    pub synthesis_texels_per_second: f64,
    /// Median seconds of the whole run (load to report, files written).
    pub total_seconds: f64,
    pub total_texels_per_second: f64,
    /// Median seconds per stage of the whole run: load, geometry, field, graph, synthesis,
    /// maps, write.
    pub stages: [f64; 7],
    /// Peak resident memory of the process after the case, and per texel.
    pub peak_memory_bytes: Option<u64>,
    pub peak_memory_bytes_per_texel: Option<f64>,
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(|a, b| a.total_cmp(b));
    let n = v.len();
    if n == 0 {
        0.0
    } else if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

/// The centre `size` x `size` crop of `ex`.
fn crop(ex: &Example, size: usize) -> Example {
    let (x0, y0) = ((ex.width - size) / 2, (ex.height - size) / 2);
    let mut rgb = Vec::with_capacity(size * size);
    for y in 0..size {
        for x in 0..size {
            rgb.push(ex.rgb[(y0 + y) * ex.width + x0 + x]);
        }
    }
    let mut out = Example::from_linear(size, size, rgb);
    out.path = ex.path.clone();
    out
}

/// The benchmark's cases: name, N and the centre crop of the example (`None`: whole).
const CASES: [(&str, usize, Option<usize>); 2] =
    [("spot-n32", 32, None), ("cow-row", 38, Some(96))];

/// Peak-memory estimate of [`synth_bench`]: the larger of its cases' `synth` estimates
/// (the default method on Spot, R G B source.u source.v).
pub fn synth_bench_estimate() -> crate::memory::Estimate {
    let size = crate::memory::MeshSize::of(&crate::demo::control_mesh());
    CASES
        .iter()
        .map(|&(_, n, crop_to)| {
            let side = crop_to.unwrap_or(128);
            let job = crate::memory::Job::Synth {
                channels: 5,
                example_pixels: side * side,
                method: crate::synth::Method::DEFAULT,
                displace: false,
                scale_map: false,
            };
            crate::memory::estimate(&size, n, &job)
        })
        .max_by_key(|e| e.bytes)
        .expect("two cases")
}

/// Runs both cases `repeats` times in the current rayon pool, using `work` as scratch
/// directory (created; its contents are overwritten). `progress(line)` gets a line per run.
pub fn synth_bench(
    work: &Path,
    repeats: usize,
    progress: &dyn Fn(&str),
) -> Result<Vec<SynthBenchRow>> {
    let repeats = repeats.max(1);
    crate::io::atomic::prepare_out_dir(work)?;
    let inputs = work.join("inputs");
    std::fs::create_dir_all(&inputs)
        .map_err(|e| Error::io(&inputs, "cannot create directory", e))?;
    let mesh = inputs.join(crate::demo::MESH_NAME);
    let example = inputs.join(crate::demo::EXAMPLE_NAME);
    write_bytes_atomic(&mesh, crate::demo::MESH_OBJ)?;
    write_bytes_atomic(&example, crate::demo::EXAMPLE_PNG)?;
    let gravel = Example::load(&example)?;
    let mut rows = Vec::new();
    for (case, n, crop_to) in CASES {
        let mut synth = Vec::new();
        let mut total = Vec::new();
        let mut stages: Vec<[f64; 7]> = Vec::new();
        let mut last = None;
        for r in 0..repeats {
            let builder = match crop_to {
                None => Synthesizer::new(&mesh, &example),
                Some(s) => Synthesizer::new(&mesh, crop(&gravel, s)),
            };
            let out = work.join(case);
            let (_, report) = builder.resolution(n).seed(1).run_to(&out)?;
            let s = &report.seconds;
            progress(&format!(
                "{case} run {}/{repeats}: synthesis {:.3} s, total {:.3} s",
                r + 1,
                s.synthesis,
                s.total
            ));
            synth.push(s.synthesis);
            total.push(s.total);
            stages.push([
                s.load,
                s.geometry,
                s.field,
                s.graph,
                s.synthesis,
                s.maps,
                s.write,
            ]);
            last = Some(report);
        }
        let report = last.expect("at least one repeat");
        let texels = report.texels;
        let (sm, tm) = (median(synth), median(total));
        let stage_median: [f64; 7] =
            std::array::from_fn(|k| median(stages.iter().map(|s| s[k]).collect()));
        let peak = crate::report::peak_memory_bytes();
        rows.push(SynthBenchRow {
            case: case.into(),
            mesh: crate::demo::MESH_NAME.into(),
            example: match crop_to {
                None => crate::demo::EXAMPLE_NAME.into(),
                Some(s) => format!("{} (centre {s}x{s} crop)", crate::demo::EXAMPLE_NAME),
            },
            example_size: [report.example.width, report.example.height],
            resolution: n,
            faces: report.faces,
            texels,
            threads: report.threads,
            repeats,
            synthesis_seconds: sm,
            synthesis_texels_per_second: texels as f64 / sm,
            total_seconds: tm,
            total_texels_per_second: texels as f64 / tm,
            stages: stage_median,
            peak_memory_bytes: peak,
            peak_memory_bytes_per_texel: peak.map(|p| p as f64 / texels as f64),
        });
    }
    Ok(rows)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn crop_takes_the_centre() {
        let rgb: Vec<[f32; 3]> = (0..100).map(|i| [i as f32, 0.0, 0.0]).collect();
        let ex = Example::from_linear(10, 10, rgb);
        let c = crop(&ex, 8);
        assert_eq!((c.width, c.height), (8, 8));
        assert_eq!(c.rgb[0][0], 11.0);
        assert_eq!(c.rgb[63][0], 88.0);
        assert_eq!(median(vec![3.0, 1.0, 2.0, 10.0]), 2.5);
    }
}
