//! Uniform texel density: `--texel-size L` instead of `--resolution N`. One N gives every
//! face N×N texels, so small faces are sampled far more finely than large ones (11x on
//! Spot at N = 32) and a renderer shows the sharpness jump at face borders; a texel size
//! gives each face its own power-of-two resolution, u and v separately (as Ptex stores
//! them), so the spacing varies at most ~2x over the surface.
//!
//! ```sh
//! cargo run --release --example 09_texel_density -- out/example-texel-density
//! surfsynth render out/example-texel-density/size   # and .../uniform, to compare
//! ```

use surfsynth::eval::evaluate;
use surfsynth::synthesizer::Synthesizer;

fn main() -> anyhow::Result<()> {
    let fixtures = concat!(env!("CARGO_MANIFEST_DIR"), "/fixtures");
    let dir = std::env::args()
        .nth(1)
        .unwrap_or_else(|| "out/example-texel-density".into());
    let dir = std::path::Path::new(&dir);
    let mesh = format!("{fixtures}/spot_control_mesh.obj");
    let example = format!("{fixtures}/gravel.png");

    // One resolution for all faces, then the texel size that is its median spacing.
    let (uniform, _) = Synthesizer::new(mesh.as_str(), example.as_str())
        .resolution(16)
        .run_to(dir.join("uniform"))?;
    let l = uniform.report.texel_spacing;
    let (sized, _) = Synthesizer::new(mesh.as_str(), example.as_str())
        .texel_size(l)
        .run_to(dir.join("size"))?;

    // The per-face resolutions are in the maps' layout (and in facemaps.exr's header).
    let layout = &sized.maps.layout;
    let mut sides: Vec<(usize, usize)> = (0..layout.faces()).map(|d| layout.dims(d)).collect();
    sides.sort_unstable();
    sides.dedup();
    println!(
        "texel size {l:.5}: {} texels in {} faces, {} distinct resolutions from {:?} to {:?}",
        layout.len(),
        layout.faces(),
        sides.len(),
        sides.first().copied().unwrap_or_default(),
        sides.last().copied().unwrap_or_default()
    );
    for (name, sub) in [("N = 16", "uniform"), ("texel size", "size")] {
        let q = evaluate(&dir.join(sub), None)?;
        println!(
            "{name}: spacing spread (p95/p5 of per-face median spacing) {:.2}, seam ratio {:.3}",
            q.spacing_spread.unwrap_or(f64::NAN),
            q.seam_ratio.unwrap_or(f64::NAN)
        );
    }
    Ok(())
}
