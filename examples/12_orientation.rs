//! The orientation field (paper 000 §3, paper 002 §3): which way the example's x and y run
//! on the surface. Textures with a direction — brick courses, scales, fabric — follow it, so
//! choosing it is choosing the look: the smoothest field (`auto`), the example upright like
//! a wall (`up`, texture optimisation's default where the surface stands), or a constraints
//! file with pins, sinks and sources (docs/field.md).
//!
//! ```sh
//! cargo run --release --example 12_orientation -- out/example-orientation [EXAMPLE.png]
//! surfsynth render out/example-orientation/up   # and .../auto, .../sink
//! ```
//!
//! The bundled gravel has no direction, so the three syntheses look alike; give an example
//! with one (bricks, scales, a weave) to see the fields.
//!
//! Prints each field's singularities — the places where any tangent field on a closed
//! surface must turn around a point. Their indices always add up to the Euler
//! characteristic (Poincaré–Hopf: 2 for Spot, a sphere topologically); *where* they sit is
//! what the choice of field decides, and a sink or source puts one where the user wants it.

use std::path::Path;
use subdiv::{ControlMesh, Surface};
use surfsynth::field::{Orientation, OrientationField};
use surfsynth::synthesizer::Synthesizer;

fn main() -> anyhow::Result<()> {
    let out = std::env::args()
        .nth(1)
        .unwrap_or_else(|| "out/example-orientation".into());
    let out = Path::new(&out);
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mesh = root.join("fixtures/spot_control_mesh.obj");
    let example = std::env::args()
        .nth(2)
        .map(std::path::PathBuf::from)
        .unwrap_or_else(|| root.join("fixtures/gravel.png"));
    std::fs::create_dir_all(out)?;

    // A constraints file: v1 flows towards a point in front of Spot's snout. Paper 002 §3
    // puts sinks and sources at extremities, so that the singularities a field must have
    // sit where they are least seen: the sink pulls one onto the snout.
    let sink = glam::DVec3::new(0.0, 0.4, -0.9);
    let constraints = out.join("sink.txt");
    std::fs::write(
        &constraints,
        format!(
            "# v1 towards a point in front of the snout\nsink {} {} {} 0.6\n",
            sink.x, sink.y, sink.z
        ),
    )?;

    let surface = Surface::new(ControlMesh::load_obj(&mesh)?);
    let chi = {
        let m = &surface.control.mesh;
        m.num_vertices() as i64 - m.num_edges() as i64 + m.num_faces() as i64
    };
    for (name, orientation) in [
        ("auto", Orientation::Auto),
        ("up", Orientation::parse("up")),
        ("sink", Orientation::Constraints(constraints.clone())),
    ] {
        // The field alone (the synthesizer computes the same one for its run).
        let field = OrientationField::compute(&surface, &orientation)?;
        let singular = field.singularities();
        let sum: i32 = singular.iter().map(|s| s.index).sum();
        println!(
            "{name:>4}: {} singular faces, indices sum to {sum} (Euler characteristic {chi})",
            singular.len()
        );
        if let Some(s) = singular.iter().min_by(|a, b| {
            a.position
                .distance(sink)
                .total_cmp(&b.position.distance(sink))
        }) {
            let p = s.position;
            println!(
                "        nearest the sink's point: index {:+} at ({:.2}, {:.2}, {:.2}), {:.2} away",
                s.index,
                p.x,
                p.y,
                p.z,
                p.distance(sink)
            );
        }

        // A synthesis along it: the maps, report.json and a preview-ready directory.
        let (result, _) = Synthesizer::new(mesh.as_path(), example.as_path())
            .resolution(16)
            .orientation(orientation)
            .seed(1)
            .run_to(out.join(name))?;
        println!(
            "        synthesized {} texels along `{}` -> {}",
            result.report.texels,
            result.report.orientation,
            out.join(name).display()
        );
    }
    Ok(())
}
