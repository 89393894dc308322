//! A structured example (a brick wall, drawn here) on BRIEF's flat 16x16 grid with the
//! field along +x: how the default method's tuning, the appearance space and the
//! feature-distance channel (`--feature-distance`, which keeps thin joints on curved
//! meshes) act on structure. Writes each result for `surfsynth render DIR`.
//!
//! ```sh
//! cargo run --release --example 03_structure_on_a_flat_grid -- out/example-bricks
//! ```

use glam::DVec3;
use surfsynth::eval::patch_fidelities;
use surfsynth::example::Example;
use surfsynth::field::Orientation;
use surfsynth::synthesizer::{AppearanceMode, Method, OptimiseParams, Synthesizer};

/// Running-bond bricks, 24x10 px with 2 px mortar, with some colour variation per brick.
fn bricks(side: usize) -> Example {
    let rgb = (0..side * side)
        .map(|i| {
            let (x, y) = (i % side, i / side);
            let row = y / 12;
            let shift = if row % 2 == 0 { 0 } else { 13 };
            let (bx, by) = ((x + shift) % 26, y % 12);
            if bx < 2 || by < 2 {
                [0.55, 0.53, 0.50] // mortar
            } else {
                let brick = ((x + shift) / 26 * 7 + row * 13) % 5;
                let v = 0.05 * brick as f32;
                [0.45 + v, 0.16 + v / 2.0, 0.10]
            }
        })
        .collect();
    Example::from_linear(side, side, rgb)
}

fn main() -> surfsynth::Result<()> {
    let out = std::env::args()
        .nth(1)
        .unwrap_or_else(|| "out/example-bricks".into());
    let example = bricks(128);
    let grid = || subdiv::Surface::new(subdiv::ControlMesh::grid(16));
    let runs = [
        (
            "default",
            OptimiseParams::default(),
            AppearanceMode::Pca,
            0.0,
        ),
        (
            "rgb-matching",
            OptimiseParams::default(),
            AppearanceMode::Rgb,
            0.0,
        ),
        (
            "one-level",
            OptimiseParams {
                levels: 1,
                ..Default::default()
            },
            AppearanceMode::Pca,
            0.0,
        ),
        (
            "feature-distance",
            OptimiseParams::default(),
            AppearanceMode::Pca,
            0.5,
        ),
    ];
    for (name, params, appearance, feature_distance) in runs {
        let dir = format!("{out}/{name}");
        let (r, report) = Synthesizer::new(grid(), example.clone())
            .method(Method::Optimise)
            .optimise_params(params)
            .appearance(appearance)
            .feature_distance(feature_distance)
            .orientation(Orientation::Axis(DVec3::X))
            .resolution(16)
            .seed(1)
            .run_to(&dir)?;
        let pf = patch_fidelities(&r.maps, &r.geometry_maps(), &r.example, Some(report.scale));
        println!(
            "{name:<16} pf4 {:.3} pf8 {:.3} ({:.2} s) -> {dir}",
            pf.pf4.unwrap_or(f64::NAN),
            pf.pf8.unwrap_or(f64::NAN),
            report.seconds.synthesis
        );
    }
    Ok(())
}
