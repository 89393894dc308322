//! Writing a result for renderers from a library program: `facemaps.ptx` (Ptex, for
//! RenderMan, Arnold, V-Ray, pbrt-v4) and `surface.glb` (glTF 2.0 with the atlas as its PBR
//! material, for viewers, engines and Blender), without the command line.
//!
//! ```sh
//! cargo run --release --example 05_export_ptex_gltf -- out/example
//! ```
//!
//! `SynthResult::write` writes these (and every other output) in one call; this shows the
//! writers one by one, for maps that come from elsewhere or with other options.

use glam::DVec3;
use subdiv::{ControlMesh, Surface};
use surfsynth::example::Example;
use surfsynth::io::export::{export, ExportOptions};
use surfsynth::io::ptex::{write_face_maps_ptex, PtexOptions, PTEX_FILE};
use surfsynth::synthesizer::Synthesizer;

fn main() -> surfsynth::Result<()> {
    let out = std::env::args()
        .nth(1)
        .unwrap_or_else(|| "out/export-example".into());
    std::fs::create_dir_all(&out).map_err(|e| surfsynth::Error::io(&out, "cannot create", e))?;

    // A cube whose top is a fan of four triangles (so the Ptex file has n-gon sub-faces),
    // and a 16x16 checkerboard example.
    let p: Vec<DVec3> = [
        (-1., -1., -1.),
        (1., -1., -1.),
        (1., 1., -1.),
        (-1., 1., -1.),
        (-1., -1., 1.),
        (1., -1., 1.),
        (1., 1., 1.),
        (-1., 1., 1.),
        (0., 0., 1.3),
    ]
    .iter()
    .map(|&(x, y, z)| DVec3::new(x, y, z))
    .collect();
    let faces: [&[u32]; 9] = [
        &[0, 3, 2, 1],
        &[0, 1, 5, 4],
        &[1, 2, 6, 5],
        &[2, 3, 7, 6],
        &[3, 0, 4, 7],
        &[4, 5, 8],
        &[5, 6, 8],
        &[6, 7, 8],
        &[7, 4, 8],
    ];
    let surface = Surface::new(ControlMesh::from_faces(p, &faces)?);
    let rgb = (0..256).map(|i| {
        if (i % 16 / 4 + i / 64) % 2 == 0 {
            [0.9, 0.8, 0.2]
        } else {
            [0.1, 0.2, 0.6]
        }
    });
    let example = Example::from_linear(16, 16, rgb.collect());
    let result = Synthesizer::new(surface, example)
        .resolution(16)
        .seed(3)
        .run()?;

    // Ptex: one face per face domain, adjacency from the mesh, mip levels. Deflate level 0
    // (stored) is the default; level 6 trades write time for ~13% smaller files.
    let ptx = std::path::Path::new(&out).join(PTEX_FILE);
    let opts = PtexOptions {
        zlib_level: 6,
        ..Default::default()
    };
    let summary = write_face_maps_ptex(&ptx, &result.surface, &result.maps, &opts)?;
    println!(
        "{}: {} faces, {} levels",
        ptx.display(),
        summary.faces,
        summary.levels
    );

    // surface.obj + surface.mtl + atlas.png + surface.glb (the same mesh and atlas).
    let e = export(
        &out,
        &result.surface,
        &result.maps,
        &ExportOptions::default(),
    )?;
    println!(
        "{out}/surface.glb: {} quads of the limit surface, atlas {}x{}",
        e.quads, e.atlas_width, e.atlas_height
    );
    Ok(())
}
