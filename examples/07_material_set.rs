//! A whole material synthesized together (`--map NAME=FILE`): base colour, a height map and
//! the tangent-space normal map derived from it, and a roughness map — every map copied from
//! the same source position, the normal map kept in the field's frame in facemaps.exr and
//! re-expressed in the atlas's own tangent frames for atlas_normal.png and surface.glb.
//!
//! ```sh
//! cargo run --release --example 07_material_set -- out/material
//! ```
//!
//! The maps are built in memory from the bundled gravel photograph (a real material set
//! comes as files: `Synthesizer::map("normal", "N.png")`, or `synth --map normal=N.png`).

use surfsynth::example::{Example, MaterialMap};
use surfsynth::synthesizer::{Synthesizer, Weights};

fn main() -> surfsynth::Result<()> {
    let out = std::path::PathBuf::from(
        std::env::args()
            .nth(1)
            .unwrap_or_else(|| "out/material".into()),
    );
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let mesh = root.join("fixtures/spot_control_mesh.obj");
    let colour = Example::load(root.join("fixtures/gravel.png"))?;
    let (w, h) = (colour.width, colour.height);

    // Height: the colour's luminance; normal: its slopes (OpenGL convention, +Y up the
    // image); roughness: rough where low.
    let height: Vec<f32> = colour
        .rgb
        .iter()
        .map(|c| 0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2])
        .collect();
    let at = |x: isize, y: isize| {
        height[(y.clamp(0, h as isize - 1) as usize) * w + x.clamp(0, w as isize - 1) as usize]
    };
    let mut normal = Vec::with_capacity(3 * w * h);
    for y in 0..h as isize {
        for x in 0..w as isize {
            let gx = 2.0 * (at(x + 1, y) - at(x - 1, y));
            let gy = 2.0 * (at(x, y - 1) - at(x, y + 1));
            let n = glam::Vec3::new(-gx, -gy, 1.0).normalize();
            normal.extend([n.x, n.y, n.z].map(|c| 0.5 * c + 0.5));
        }
    }
    let roughness = height.iter().map(|v| 1.0 - v).collect();
    let example = colour
        .with_map(MaterialMap::from_linear("normal", 3, normal))?
        .with_map(MaterialMap::from_linear("roughness", 1, roughness))?
        .with_map(MaterialMap::from_linear("height", 1, height))?;

    // Match the colour, the height (weight 3 by default) and the normal map; roughness is
    // only copied.
    let mut weights = Weights::default();
    weights.maps.push(("normal".into(), 1.0));
    let (result, report) = Synthesizer::new(mesh.as_path(), example)
        .resolution(32)
        .weights(weights)
        .run_to(&out)?;
    println!(
        "{} texels in {:.2} s; facemaps.exr channels: {}",
        report.texels,
        report.seconds.total,
        result.maps.names().join(" ")
    );
    println!(
        "wrote {} (atlas_normal.png, atlas_roughness.png, atlas_height.png, surface.glb with normal and roughness textures)",
        out.display()
    );
    Ok(())
}
