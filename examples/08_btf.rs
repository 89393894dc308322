//! BTF synthesis with surface textons (paper 003, `synth --btf`): a synthetic BTF sample
//! (a height field ray-traced with self-shadowing under 32 lights, as 003 Fig. 8), one
//! source position per texel for all 32 images at once, and the result shaded under two
//! lights — the relief's shadows move with the light.
//!
//! ```sh
//! cargo run --release --example 08_btf -- out/btf
//! ```
//!
//! Writes `out/btf/sample/` (light_NN.png + btf.json), `out/btf/run/` (the usual outputs;
//! facemaps.exr's colour is the sample's overhead image) and `out/btf/run/light_*.png`.

use surfsynth::btf::generate::{self, HeightField};
use surfsynth::render::RenderOptions;
use surfsynth::synth::Details;
use surfsynth::synthesizer::{ExampleSource, Method, Synthesizer};

fn main() -> anyhow::Result<()> {
    let out = std::path::PathBuf::from(std::env::args().nth(1).unwrap_or_else(|| "out/btf".into()));
    let mesh =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/spot_control_mesh.obj");

    // The sample: 64² procedural bumps, 6 pixels deep, 32 lights over the hemisphere.
    let hf = HeightField::bumps(64, 6.0, 1);
    let (sample, _) = generate::sample(&hf, &generate::light_directions(32));
    let json = generate::write(
        &out.join("sample"),
        &sample,
        serde_json::json!({"example": "08_btf"}),
    )?;

    // Texton analysis + multiscale k-coherence over the textons.
    let (result, report) = Synthesizer::new(mesh.as_path(), ExampleSource::Btf(json))
        .method(Method::Textons)
        .resolution(32)
        .run_to(out.join("run"))?;
    if let Details::Textons { stats, .. } = &result.report.details {
        println!(
            "{} images, textons per level {:?} (kept {:.3} of Γ), analysis {:.2} s, synthesis {:.2} s, whole run {:.2} s",
            stats.images,
            stats.analysis.textons,
            stats.analysis.kept_variance[0],
            stats.analysis_seconds,
            report.seconds.synthesis,
            report.seconds.total,
        );
    }

    // The surface BTF under two lights (world directions towards the light).
    for (name, l) in [
        ("light_left.png", [1.0, 1.2, 0.4]),
        ("light_right.png", [0.4, 1.2, -1.0]),
    ] {
        let opts = RenderOptions {
            light: Some(l),
            ..Default::default()
        };
        surfsynth::render::run_cli(&out.join("run"), Some(&out.join("run").join(name)), &opts)?;
    }
    Ok(())
}
