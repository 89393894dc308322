//! `surfsynth demo`: the whole pipeline on bundled inputs, so a fresh checkout (or just the
//! binary) shows a result with one command.
//!
//! The fixtures are compiled into the binary (`include_bytes!`), so the demo works from
//! any directory and cannot pick up a stale or edited copy. They are written next to the
//! result, into `DIR/inputs/`, so the run can be repeated or varied with `surfsynth synth`
//! and `report.json` points at files that exist. Licences: fixtures/LICENSES.txt (Spot is
//! public domain, the gravel and brick examples CC0).
//!
//! Three runs: gravel (a stochastic example) into `DIR/`, a brick wall (a structured one:
//! what the default method is for — courses that stay level and continuous, joints that
//! meet) into `DIR/bricks/`, and a BTF (one relief under many lights, every image matched
//! at once by the default method) into `DIR/btf/`; each with a preview picture.

use crate::error::Error;
use crate::io::atomic::{prepare_out_dir, write_bytes_atomic};
use crate::report::Report;
use crate::synthesizer::{run_command, Method, SynthCommand};
use std::path::Path;

/// Keenan Crane's Spot control mesh (quads, triangles and pentagons: exercises T-junctions
/// and extraordinary vertices).
pub const MESH_OBJ: &[u8] = include_bytes!("../fixtures/spot_control_mesh.obj");
/// File name of the mesh in `DIR/inputs/`.
pub const MESH_NAME: &str = "spot_control_mesh.obj";

/// The bundled mesh, parsed (for commands that default to it without a file on disk).
pub fn control_mesh() -> subdiv::ControlMesh {
    let text = std::str::from_utf8(MESH_OBJ).expect("the bundled mesh is UTF-8");
    subdiv::ControlMesh::parse_obj(text).expect("the bundled mesh parses")
}
/// 128x128 gravel (scikit-image, CC0), a stochastic texture coherent synthesis handles well.
pub const EXAMPLE_PNG: &[u8] = include_bytes!("../fixtures/gravel.png");
/// File name of the example in `DIR/inputs/`.
pub const EXAMPLE_NAME: &str = "gravel.png";
/// 128x128 brick wall (scikit-image, CC0; horizontal courses ~17 pixels apart): the
/// structured example, synthesized with the default method into `DIR/bricks/`.
pub const BRICKS_PNG: &[u8] = include_bytes!("../fixtures/bricks.png");
/// File name of the brick example in `DIR/inputs/`.
pub const BRICKS_NAME: &str = "bricks.png";
/// Texels per side: 252 domains x 32² = 258,048 texels, about a second.
pub const RESOLUTION: usize = 32;
/// Seed of the demo run.
pub const SEED: u64 = 1;

/// The `synth` command the demo runs for output directory `out`.
pub fn command(out: &Path) -> SynthCommand {
    let inputs = out.join("inputs");
    SynthCommand {
        mesh: inputs.join(MESH_NAME),
        example: inputs.join(EXAMPLE_NAME),
        btf: None,
        height: None,
        maps: Vec::new(),
        matches: Vec::new(),
        normal_convention: Default::default(),
        method: Method::DEFAULT,
        resolution: RESOLUTION,
        texel_size: None,
        scale: None,
        scale_map: None,
        scale_from_orient: false,
        orientation: None,
        seed: SEED,
        search: None,
        neighbourhood: None,
        kcoherence_k: None,
        sparse: None,
        continue_finest: None,
        jump_blend: None,
        displace: None,
        appearance: Default::default(),
        feature_distance: 0.0,
        decimate: None,
        patch_size: None,
        handedness: Default::default(),
        cache: Default::default(),
        out: out.to_path_buf(),
    }
}

/// Writes the fixtures to `out/inputs/`, runs [`command`] (progress bars, summary line),
/// renders `preview.png` and prints the quality measures of BRIEF.md on one line; then the
/// same for the brick wall ([`bricks`]) and the BTF part ([`btf`]), and a last line naming
/// the pictures to look at.
pub fn run(out: &Path) -> anyhow::Result<Report> {
    prepare_out_dir(out)?;
    let inputs = out.join("inputs");
    std::fs::create_dir_all(&inputs)
        .map_err(|e| Error::io(&inputs, "cannot create directory", e))?;
    write_bytes_atomic(inputs.join(MESH_NAME), MESH_OBJ)?;
    write_bytes_atomic(inputs.join(EXAMPLE_NAME), EXAMPLE_PNG)?;
    write_bytes_atomic(inputs.join(BRICKS_NAME), BRICKS_PNG)?;
    let report = run_command(&command(out))?;
    preview_and_eval(out)?;
    bricks(out)?;
    btf(out)?;
    let pictures = [
        out.join("preview.png"),
        out.join("bricks").join("preview.png"),
        out.join("btf").join(BTF_PREVIEW_LIGHTS[0].0),
        out.join("btf").join(BTF_PREVIEW_LIGHTS[1].0),
    ];
    let pictures: Vec<String> = pictures.iter().map(|p| p.display().to_string()).collect();
    println!("demo: look at {}", pictures.join(", "));
    Ok(report)
}

/// Renders `dir`'s `preview.png` and prints its quality measures on one line.
fn preview_and_eval(dir: &Path) -> anyhow::Result<()> {
    // The render's summary shows its own peak beside its estimate, not the synthesis's.
    crate::process::reset_peak_rss();
    crate::render::run_cli(dir, None, &crate::render::RenderOptions::default())?;
    let q = crate::eval::evaluate(dir, None)?;
    println!("{}", eval_summary(&q));
    Ok(())
}

/// The structured part of the demo: the bundled brick wall over Spot with the default
/// method (texture optimisation, the example upright: courses run level around the body)
/// into `DIR/bricks/`, with its preview and quality line. Bricks show at a glance what a
/// stochastic example cannot: whether mortar lines stay straight and meet.
pub fn bricks(out: &Path) -> anyhow::Result<()> {
    let dir = out.join("bricks");
    let mut c = command(&dir);
    c.mesh = out.join("inputs").join(MESH_NAME);
    c.example = out.join("inputs").join(BRICKS_NAME);
    run_command(&c)?;
    preview_and_eval(&dir)
}

/// Texels per side of the demo's BTF run (252 domains x 32² texels: the gravel's; the
/// default method over the sample takes a few seconds).
pub const BTF_RESOLUTION: usize = 32;
/// Lights of the demo's BTF sample.
pub const BTF_LIGHTS: usize = 32;
/// The two lights of the demo's BTF previews (world directions towards the light).
pub const BTF_PREVIEW_LIGHTS: [(&str, [f64; 3]); 2] = [
    ("preview_light_left.png", [1.0, 1.2, 0.4]),
    ("preview_light_right.png", [0.4, 1.2, -1.0]),
];

/// The BTF part of the demo (paper 003): a procedural relief ray-traced under
/// [`BTF_LIGHTS`] lights into `DIR/inputs/btf/` (as `surfsynth bench btf-sample` writes
/// it), synthesized onto Spot with the default method (every image matched at once in
/// appearance space: one source per texel for all of them; docs/btf.md) into `DIR/btf/`,
/// rendered under two lights: the shadows of the relief move with the light.
pub fn btf(out: &Path) -> anyhow::Result<()> {
    use crate::btf::generate;
    let inputs = out.join("inputs");
    let hf = generate::HeightField::bumps(128, 6.0, SEED);
    let (sample, _) = generate::sample(&hf, &generate::light_directions(BTF_LIGHTS));
    let json = generate::write(
        &inputs.join("btf"),
        &sample,
        serde_json::json!({"generator": "surfsynth demo", "height": "procedural bumps"}),
    )?;
    let dir = out.join("btf");
    let mut c = command(&dir);
    c.mesh = inputs.join(MESH_NAME);
    c.btf = Some(json);
    c.resolution = BTF_RESOLUTION;
    run_command(&c)?;
    for (name, l) in BTF_PREVIEW_LIGHTS {
        let opts = crate::render::RenderOptions {
            light: Some(l),
            ..Default::default()
        };
        crate::process::reset_peak_rss();
        crate::render::run_cli(&dir, Some(&dir.join(name)), &opts)?;
    }
    Ok(())
}

/// One line of the headline quality measures (the full set: `surfsynth eval DIR`).
pub fn eval_summary(q: &crate::eval::Quality) -> String {
    let opt = |x: Option<f64>| x.map_or("n/a".to_string(), |v| format!("{v:.3}"));
    let scale = q.scale_fidelity.as_ref().map_or("n/a".to_string(), |s| {
        format!("{:.3} (p10 {:.3}, p90 {:.3})", s.median, s.p10, s.p90)
    });
    format!(
        "eval: coverage {:.3}, seam ratio {}, scale fidelity {scale}, coherent fraction {}",
        q.coverage,
        opt(q.seam_ratio),
        opt(q.coherent_fraction)
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bundled_fixtures_are_the_files_in_fixtures() {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures");
        assert_eq!(std::fs::read(dir.join(MESH_NAME)).unwrap(), MESH_OBJ);
        assert_eq!(std::fs::read(dir.join(EXAMPLE_NAME)).unwrap(), EXAMPLE_PNG);
        assert_eq!(std::fs::read(dir.join(BRICKS_NAME)).unwrap(), BRICKS_PNG);
        // Small, as the licence file promises.
        for name in [EXAMPLE_NAME, BRICKS_NAME] {
            let ex = crate::example::Example::load(dir.join(name)).unwrap();
            assert_eq!((ex.width, ex.height), (128, 128), "{name}");
        }
        // The parsed bundled mesh is the file's mesh (252 domains, as the demo reports).
        assert_eq!(control_mesh().num_domains(), 252);
        let licences = std::fs::read_to_string(dir.join("LICENSES.txt")).unwrap();
        for name in [MESH_NAME, EXAMPLE_NAME, BRICKS_NAME] {
            assert!(licences.contains(name), "{name} has a licence entry");
        }
        assert!(licences.contains("Public domain") && licences.contains("CC0-1.0"));
    }
}
