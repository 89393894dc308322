//! A prepared session (what an interactive tool calls): Spot's mesh is prepared once —
//! surface, texel geometry, orientation field, texel graph — then synthesized three times
//! with other seeds and methods, each costing only the synthesis.
//!
//! ```sh
//! cargo run --release --example 10_session -- out/session
//! # the benchmark of docs/benchmarks.md: re-synthesis times, median of R runs each
//! cargo run --release --example 10_session -- --repeats 10 [--mesh M.obj] [--resolution N]
//! ```
//!
//! Writes `out/session/jump-1`, `jump-2` and `coherent-1` (the usual outputs) when given
//! a folder.

use std::time::Instant;
use surfsynth::example::Example;
use surfsynth::synthesizer::{MeshSettings, Method, Session, SynthParams};

fn main() -> surfsynth::Result<()> {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut mesh = root.join("fixtures/spot_control_mesh.obj");
    let mut settings = MeshSettings::default(); // N = 32, scale = texel spacing, auto field
    let (mut out, mut repeats) = (None, 1usize);
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        let mut value = || args.next().expect("a value after the flag");
        match a.as_str() {
            "--mesh" => mesh = value().into(),
            "--resolution" => settings.resolution = value().parse().expect("a number"),
            "--repeats" => repeats = value().parse().expect("a number"),
            _ => out = Some(std::path::PathBuf::from(a)),
        }
    }

    let t = Instant::now();
    let session = Session::prepare(mesh.as_path(), &settings)?;
    // What the jump method derives from the mesh (its region-growing order), now too.
    session.prepare_method(Method::Jump);
    let p = session.prepare_seconds();
    println!(
        "prepared {} domains, {} texels in {:.2} s (load {:.2}, geometry {:.2}, field {:.2}, graph {:.2})",
        session.faces(),
        session.texels(),
        t.elapsed().as_secs_f64(),
        p.load,
        p.geometry,
        p.field,
        p.graph
    );
    // The first synthesis analyses the example (or reads the analysis from the user cache
    // folder); later ones find it in the session.
    let example = Example::load(root.join("fixtures/gravel.png"))?;
    for (method, seed) in [(Method::Jump, 1), (Method::Jump, 2), (Method::Coherent, 1)] {
        let params = SynthParams {
            seed,
            ..SynthParams::new(method)
        };
        let mut times = Vec::new();
        let mut last = None;
        for _ in 0..repeats.max(1) {
            let t = Instant::now();
            last = Some(session.synthesize(&example, &params)?);
            times.push(t.elapsed().as_secs_f64());
        }
        let result = last.expect("at least one run");
        let first = times[0];
        times.sort_by(f64::total_cmp);
        println!(
            "{} seed {seed}: {:.3} s (median of {}: {:.3} s; synthesis {:.3} s, maps {:.3} s; analysis from the cache: {})",
            method.name(),
            first,
            times.len(),
            times[times.len() / 2],
            result.report.seconds.synthesis,
            result.report.seconds.maps,
            result.report.cache.hit,
        );
        if let Some(dir) = &out {
            result.write(dir.join(format!("{}-{seed}", method.name())))?;
        }
    }
    Ok(())
}
