//! `surfsynth bake` end to end: the binary's geometry.exr against OpenSubdiv's reference
//! values at texel centres, the BRIEF's file layout, and determinism across thread counts.

use std::path::{Path, PathBuf};
use std::process::Command;
use surfsynth::io::exr::{read_face_maps, TileLayout};

mod common;
use common::shared;

fn reference(name: &str) -> PathBuf {
    shared().join("data/opensubdiv-reference").join(name)
}

fn bake(mesh: &Path, n: usize, out: &Path, extra: &[&str]) -> String {
    let o = Command::new(env!("CARGO_BIN_EXE_surfsynth"))
        .args(extra)
        .arg("bake")
        .arg("--mesh")
        .arg(mesh)
        .arg("--resolution")
        .arg(n.to_string())
        .arg("--out")
        .arg(out)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "bake failed: {stderr}");
    assert!(
        stderr.is_empty(),
        "no progress bar when not a terminal: {stderr}"
    );
    String::from_utf8(o.stdout).unwrap()
}

/// One row of `NAME.texels.csv`.
struct Ref {
    face: usize,
    x: usize,
    y: usize,
    p: [f64; 3],
    n: [f64; 3],
    flag: bool,
}

fn read_texels_csv(path: &Path) -> Vec<Ref> {
    let text = std::fs::read_to_string(path).unwrap();
    text.lines()
        .skip(1)
        .map(|l| {
            let c: Vec<f64> = l.split(',').map(|v| v.parse().unwrap()).collect();
            Ref {
                face: c[0] as usize,
                x: c[1] as usize,
                y: c[2] as usize,
                p: [c[3], c[4], c[5]],
                n: [c[6], c[7], c[8]],
                flag: c[11] != 0.0,
            }
        })
        .collect()
}

/// Bakes `name` at N = 8 and compares every texel with the OpenSubdiv reference.
/// Positions: f32 rounding only (<= 1e-6 of the bounding-box diagonal). Normals: <= 0.01°
/// (f32 unit vectors are good to ~1e-5°), loose only where the reference flags them.
fn check_against_reference(name: &str) {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    let summary = bake(&reference(&format!("{name}.obj")), 8, &out, &[]);
    let refs = read_texels_csv(&reference(&format!("{name}.texels.csv")));
    let faces = refs.iter().map(|r| r.face).max().unwrap() + 1;
    assert!(
        summary.starts_with(&format!("bake: {faces} domains, {} texels", faces * 64)),
        "{summary}"
    );
    assert_eq!(summary.lines().count(), 1, "one-line summary: {summary}");

    let maps = read_face_maps(out.join("geometry.exr")).unwrap();
    assert_eq!((maps.faces(), maps.uniform_n()), (faces, Some(8)));
    let ch = |c: &str| maps.channel(c).unwrap_or_else(|| panic!("channel {c}"));
    let (px, py, pz) = (ch("P.X"), ch("P.Y"), ch("P.Z"));
    let (nx, ny, nz) = (ch("N.X"), ch("N.Y"), ch("N.Z"));

    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for r in &refs {
        for k in 0..3 {
            lo[k] = lo[k].min(r.p[k]);
            hi[k] = hi[k].max(r.p[k]);
        }
    }
    let diag = (0..3).map(|k| (hi[k] - lo[k]).powi(2)).sum::<f64>().sqrt();
    let (mut worst_p, mut worst_n) = (0f64, 0f64);
    for r in &refs {
        let i = maps.index(r.face, r.x, r.y);
        let p = [px[i] as f64, py[i] as f64, pz[i] as f64];
        let e = (0..3).map(|k| (p[k] - r.p[k]).powi(2)).sum::<f64>().sqrt() / diag;
        worst_p = worst_p.max(e);
        let n = [nx[i] as f64, ny[i] as f64, nz[i] as f64];
        let dot: f64 = (0..3).map(|k| n[k] * r.n[k]).sum();
        let len = (0..3).map(|k| n[k] * n[k]).sum::<f64>().sqrt();
        assert!((len - 1.0).abs() < 1e-6, "{name}: normal not unit at {i}");
        // atan2(|a x b|, a.b): acos is ill-conditioned near 0° (f32 rounding alone would
        // read as 0.03°).
        let cross = [
            n[1] * r.n[2] - n[2] * r.n[1],
            n[2] * r.n[0] - n[0] * r.n[2],
            n[0] * r.n[1] - n[1] * r.n[0],
        ];
        let sin = cross.iter().map(|c| c * c).sum::<f64>().sqrt();
        let angle = sin.atan2(dot).to_degrees();
        if !r.flag {
            worst_n = worst_n.max(angle);
        } else {
            assert!(angle < 5.0, "{name}: flagged normal off by {angle}°");
        }
    }
    assert!(
        worst_p <= 1e-6,
        "{name}: position error {worst_p:e} of the diagonal"
    );
    assert!(worst_n <= 0.01, "{name}: normal error {worst_n}°");
}

#[test]
fn catmark_cube_matches_opensubdiv_at_texel_centres() {
    check_against_reference("catmark_cube");
}

#[test]
fn other_reference_shapes_match_opensubdiv() {
    let dir = reference("");
    let mut names: Vec<String> = std::fs::read_dir(&dir)
        .unwrap()
        .filter_map(|e| {
            let n = e.unwrap().file_name().to_string_lossy().into_owned();
            n.strip_suffix(".texels.csv").map(str::to_string)
        })
        .filter(|n| n != "catmark_cube")
        .collect();
    names.sort();
    assert!(names.len() >= 5, "reference shapes found: {names:?}");
    for n in names {
        check_against_reference(&n);
    }
}

/// The file layout as BRIEF states it, read with the exr crate's generic reader (a
/// different code path from our tile reader).
#[test]
fn geometry_exr_has_the_brief_layout() {
    use exr::prelude::*;
    let dir = tempfile::tempdir().unwrap();
    // 4 quads + a pentagon (5 sub-faces) etc.: catmark_nonquads has n-gons.
    let mesh = reference("catmark_nonquads.obj");
    bake(&mesh, 4, dir.path(), &[]);
    let refs = read_texels_csv(&reference("catmark_nonquads.texels.csv"));
    let faces = refs.iter().map(|r| r.face).max().unwrap() + 1;
    let layout = TileLayout::new(faces, 4);
    let img = read_all_flat_layers_from_file(dir.path().join("geometry.exr")).unwrap();
    assert_eq!(img.layer_data.len(), 1, "single part");
    let layer = &img.layer_data[0];
    let c = (faces as f64).sqrt().ceil() as usize;
    let rows = faces.div_ceil(c);
    assert_eq!(layer.size, Vec2(c * 4, rows * 4));
    assert_eq!(layer.encoding.blocks, Blocks::Tiles(Vec2(4, 4)));
    let attr = |k: &str| layer.attributes.other.get(&Text::from(k)).cloned();
    assert_eq!(
        attr("surfsynth.faces"),
        Some(AttributeValue::I32(faces as i32))
    );
    assert_eq!(attr("surfsynth.resolution"), Some(AttributeValue::I32(4)));
    let names: Vec<String> = layer
        .channel_data
        .list
        .iter()
        .map(|c| c.name.to_string())
        .collect();
    assert_eq!(names, ["N.X", "N.Y", "N.Z", "P.X", "P.Y", "P.Z"]);
    // Tile of domain f at (f mod C, f div C); texel (x, y) at (u, v) = ((x+.5)/N, (y+.5)/N)
    // with y from the top: compare P.X through the image layout with a fresh evaluation.
    let surface = subdiv::Surface::load_obj(&mesh).unwrap();
    let FlatSamples::F32(px) = &layer.channel_data.list[3].sample_data else {
        panic!("P.X is not f32")
    };
    let width = c * 4;
    for f in 0..layout.tile_count() {
        let (ox, oy) = ((f % c) * 4, (f / c) * 4);
        for y in 0..4 {
            for x in 0..4 {
                let got = px[(oy + y) * width + ox + x];
                if f < faces {
                    let s = surface.eval(
                        subdiv::DomainId(f as u32),
                        (x as f64 + 0.5) / 4.0,
                        (y as f64 + 0.5) / 4.0,
                    );
                    assert_eq!(got, s.p.x as f32, "domain {f} texel ({x},{y})");
                } else {
                    assert_eq!(got, 0.0, "unused tile {f} must be zero");
                }
            }
        }
    }
}

#[test]
fn output_is_bit_identical_for_any_thread_count() {
    let dir = tempfile::tempdir().unwrap();
    let mesh = shared().join("data/meshes/spot_control_mesh.obj");
    let mut files = Vec::new();
    for t in ["1", "2", "3"] {
        let out = dir.path().join(format!("t{t}"));
        bake(&mesh, 16, &out, &["--threads", t]);
        files.push(std::fs::read(out.join("geometry.exr")).unwrap());
    }
    assert!(files[0] == files[1], "--threads 1 and 2 differ");
    assert!(files[0] == files[2], "--threads 1 and 3 differ");
}

#[test]
fn creates_out_dir_and_leaves_only_the_result() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("a/b/c");
    bake(&reference("catmark_cube.obj"), 2, &out, &[]);
    let names: Vec<String> = std::fs::read_dir(&out)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert_eq!(names, ["geometry.exr"]);
    // Re-baking over an existing result replaces it.
    bake(&reference("catmark_cube.obj"), 3, &out, &[]);
    assert_eq!(
        read_face_maps(out.join("geometry.exr"))
            .unwrap()
            .uniform_n()
            .unwrap(),
        3
    );
}

#[test]
fn every_compression_stores_the_same_values() {
    let dir = tempfile::tempdir().unwrap();
    let mesh = reference("catmark_pole8.obj");
    let mut maps = Vec::new();
    for c in ["none", "rle", "zip", "zips", "piz"] {
        let out = dir.path().join(c);
        let o = Command::new(env!("CARGO_BIN_EXE_surfsynth"))
            .args(["bake", "--resolution", "5", "--compression", c, "--mesh"])
            .arg(&mesh)
            .arg("--out")
            .arg(&out)
            .output()
            .unwrap();
        assert!(o.status.success());
        maps.push(read_face_maps(out.join("geometry.exr")).unwrap());
    }
    for m in &maps[1..] {
        assert!(m == &maps[0]);
    }
}
