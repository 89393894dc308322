//! Jump-map synthesis (paper 002, `--method jump`) from a library program: the example is
//! analysed once (its jump map), then every further run with it — another seed here —
//! costs only the set-up of the mesh and the texel pass.
//!
//! ```sh
//! cargo run --release --example 06_jump -- out/jump
//! ```
//!
//! Writes `out/jump/seed-1` and `out/jump/seed-2` (the usual outputs, report.json with
//! the jump statistics and where the analysis came from).

use std::sync::Arc;
use surfsynth::cache::CacheDir;
use surfsynth::synth::{Analyses, Details};
use surfsynth::synthesizer::{Method, Synthesizer};

fn main() -> surfsynth::Result<()> {
    let out =
        std::path::PathBuf::from(std::env::args().nth(1).unwrap_or_else(|| "out/jump".into()));
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let mesh = root.join("fixtures/spot_control_mesh.obj");
    let example = root.join("fixtures/gravel.png");

    // One store of per-example analysis for both runs (memory; no disk cache here —
    // `CacheDir::Default` would also keep it for the next process).
    let analyses = Arc::new(Analyses::new(&CacheDir::Off));
    for seed in [1, 2] {
        let (result, report) = Synthesizer::new(mesh.as_path(), example.as_path())
            .method(Method::Jump)
            .resolution(32)
            .seed(seed)
            .analyses(analyses.clone())
            .run_to(out.join(format!("seed-{seed}")))?;
        if let Details::Jump { stats, .. } = &result.report.details {
            println!(
                "seed {seed}: {} texels, {} jumps, texel pass {:.1} ms ({:.1} M texels/s), whole run {:.2} s",
                stats.texels,
                stats.jumps,
                stats.seconds * 1e3,
                stats.texels_per_second / 1e6,
                report.seconds.total,
            );
        }
        for e in &report.cache.entries {
            println!("  {}: {:?} in {:.3} s", e.kind, e.source, e.seconds);
        }
    }
    Ok(())
}
