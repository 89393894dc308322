//! The main job from a library program: a texture synthesized on a subdivision surface by
//! the default method (texture optimisation), written as every output the command line
//! writes (facemaps.exr, geometry.exr, facemaps.ptx, surface.glb, surface.obj + atlas,
//! report.json).
//!
//! ```sh
//! cargo run --release --example 01_synthesize -- out/example-synthesize
//! ```
//!
//! The same as `surfsynth synth --mesh fixtures/spot_control_mesh.obj --example
//! fixtures/gravel.png --resolution 32 --seed 7 --out DIR`.

use surfsynth::synthesizer::Synthesizer;

fn main() -> surfsynth::Result<()> {
    let out = std::env::args()
        .nth(1)
        .unwrap_or_else(|| "out/example-synthesize".into());
    let fixtures = concat!(env!("CARGO_MANIFEST_DIR"), "/fixtures");
    let (result, report) = Synthesizer::new(
        format!("{fixtures}/spot_control_mesh.obj"),
        format!("{fixtures}/gravel.png"),
    )
    .resolution(32) // texels per side of every face map
    .seed(7) // same seed => bit-identical maps, for any thread count
    .on_progress(|stage, done, total| {
        if done == total {
            eprintln!("{stage:?} done");
        }
    })
    .run_to(&out)?; // checks `out` before the expensive part, then writes every file
    println!(
        "{out}: {} faces x {}² texels by {} in {:.2} s ({:.0} texels/s)",
        report.faces,
        report.resolution,
        report.method.name(),
        report.seconds.total,
        report.texels_per_second
    );
    // The maps are also in memory: one channel set per face domain.
    let rgb = result.maps.channel("R").expect("colour channels");
    println!("first texel's red: {:.3}", rgb[0]);
    Ok(())
}
