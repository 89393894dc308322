//! BTF synthesis (paper 003, `synth --btf`): a synthetic BTF sample (a height field
//! ray-traced with self-shadowing under 32 lights, as 003 Fig. 8), one source position per
//! texel for all 32 images at once, and the result shaded under two lights — the relief's
//! shadows move with the light. Two ways: the default method (texture optimisation, every
//! image matched together in appearance space) and paper 003's surface textons.
//!
//! ```sh
//! cargo run --release --example 08_btf -- out/btf
//! ```
//!
//! Writes `out/btf/sample/` (light_NN.png + btf.json), `out/btf/optimise/` and
//! `out/btf/textons/` (the usual outputs; facemaps.exr's colour is the sample's overhead
//! image) with `light_*.png` in each.

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

    for method in [Method::Optimise, Method::Textons] {
        let dir = out.join(method.name());
        let (result, report) = Synthesizer::new(mesh.as_path(), ExampleSource::Btf(json.clone()))
            .method(method)
            .resolution(32)
            .run_to(&dir)?;
        match &result.report.details {
            // Texton analysis + multiscale k-coherence over the textons.
            Details::Textons { stats, .. } => println!(
                "textons: {} images, textons per level {:?} (kept {:.3} of Γ), analysis {:.2} s",
                stats.images,
                stats.analysis.textons,
                stats.analysis.kept_variance[0],
                stats.analysis_seconds,
            ),
            // Every pixel's colours under all lights, PCA-reduced, then appearance space.
            _ => {
                if let Some(r) = result.report.appearance.reflectance {
                    println!(
                        "{}: {} images matched as {} values a pixel (kept {:.3})",
                        method.name(),
                        r.images,
                        r.dims,
                        r.kept_variance
                    );
                }
            }
        }
        println!(
            "  synthesis {:.2} s, whole run {:.2} s",
            report.seconds.synthesis, report.seconds.total
        );

        // The surface BTF under two lights (world directions towards the light).
        for (name, l) in [
            ("light_left.png", [1.0, 1.2, 0.4]),
            ("light_right.png", [0.4, 1.2, -1.0]),
        ] {
            let opts = RenderOptions {
                light: Some(l),
                ..Default::default()
            };
            surfsynth::render::run_cli(&dir, Some(&dir.join(name)), &opts)?;
        }
    }
    Ok(())
}
