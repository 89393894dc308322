//! Measuring a result with BRIEF's quality measures — what `surfsynth eval DIR --example
//! E.png` prints — from a library program: coverage, seam ratio, scale fidelity and patch
//! fidelity pf1/pf4/pf8, for a result directory on disk.
//!
//! ```sh
//! cargo run --release --example 01_synthesize -- out/example-synthesize
//! cargo run --release --example 04_evaluate -- out/example-synthesize fixtures/gravel.png
//! ```
//!
//! Without arguments it synthesizes a small result first. For maps in memory,
//! `eval::evaluate_maps` and `eval::patch_fidelities` take them directly (examples 02, 03).

use surfsynth::eval::{evaluate_with, EvalOptions, FACEMAPS_FILE};
use surfsynth::synthesizer::Synthesizer;

fn main() -> surfsynth::Result<()> {
    let fixtures = concat!(env!("CARGO_MANIFEST_DIR"), "/fixtures");
    let mut args = std::env::args().skip(1);
    let dir = args.next().unwrap_or_else(|| "out/example-evaluate".into());
    let example = args
        .next()
        .unwrap_or_else(|| format!("{fixtures}/gravel.png"));
    let dir = std::path::Path::new(&dir);
    if !dir.join(FACEMAPS_FILE).is_file() {
        Synthesizer::new(
            format!("{fixtures}/spot_control_mesh.obj"),
            example.as_str(),
        )
        .resolution(16)
        .run_to(dir)?;
    }
    // The scale (surface length per example pixel) comes from the run's report.json; the
    // example is needed for pf1/pf4/pf8 (report.json names the one the run used).
    let opts = EvalOptions {
        scale: None,
        example: Some(example.into()),
    };
    let q = evaluate_with(dir, &opts)?;
    println!("coverage {:.4} (must be 1)", q.coverage);
    if let (Some(seam), Some(s)) = (q.seam_ratio, q.scale_fidelity) {
        println!("seam ratio {seam:.3} (1: faces join as smoothly as texels inside faces)");
        println!(
            "scale fidelity median {:.4}, p10-p90 {:.3}-{:.3} (1: no stretch)",
            s.median, s.p10, s.p90
        );
    }
    println!(
        "pf1 {:.3} pf4 {:.3} pf8 {:.3} (0: every window a copy of the example; 1: random)",
        q.pf1.unwrap_or(f64::NAN),
        q.pf4.unwrap_or(f64::NAN),
        q.pf8.unwrap_or(f64::NAN)
    );
    // Everything, as `surfsynth eval` prints it: `surfsynth::eval::to_json(&q)`.
    Ok(())
}
