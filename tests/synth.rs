//! End-to-end tests of coherent synthesis on shared data: BRIEF's quality measures are
//! computed here from the in-memory maps (same definitions as `surfsynth eval`), plus
//! determinism across thread counts and the error contract of the CLI.

mod common;

use common::{data, env_or};
use std::path::{Path, PathBuf};
use surfsynth::field::Orientation;
use surfsynth::io::exr::FaceMaps;
use surfsynth::synth::coherent::Order;
use surfsynth::synthesizer::{
    CoherentParams, ExampleSource, MeshSource, Method, SynthResult, Synthesizer,
};

/// This file tests the coherent method (000 §5): a builder set to it.
fn coherent(mesh: impl Into<MeshSource>, example: impl Into<ExampleSource>) -> Synthesizer {
    Synthesizer::new(mesh, example).method(Method::Coherent)
}

fn fixture(rel: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("fixtures")
        .join(rel)
}

/// BRIEF's quality measures, from helper `eval` (the same code as `surfsynth eval`).
#[derive(Debug, Clone, Copy)]
#[allow(dead_code)]
struct Measures {
    coverage: f64,
    seam_ratio: f64,
    scale_median: f64,
    scale_p10: f64,
    scale_p90: f64,
    coherent_fraction: f64,
}

fn measure_result(r: &SynthResult) -> Measures {
    let q = surfsynth::eval::evaluate_maps(&r.maps, &r.geometry_maps(), Some(r.report.scale), None)
        .unwrap();
    let s = q.scale_fidelity.unwrap();
    Measures {
        coverage: q.coverage,
        seam_ratio: q.seam_ratio.unwrap(),
        scale_median: s.median,
        scale_p10: s.p10,
        scale_p90: s.p90,
        coherent_fraction: q.coherent_fraction.unwrap(),
    }
}

/// A flat k x k grid of unit quads in the z = 0 plane.
fn flat_grid(k: usize) -> subdiv::Surface {
    subdiv::Surface::new(subdiv::ControlMesh::grid(k))
}

/// The maps of a flat grid laid out as one picture (domain (x, y) of the grid at tile
/// (x, k-1-y) so that +y is up), sRGB 8-bit.
fn flat_picture(maps: &FaceMaps, k: usize) -> image::RgbImage {
    let n = maps.uniform_n().unwrap();
    let mut img = image::RgbImage::new((k * n) as u32, (k * n) as u32);
    let (r, g, b) = (
        maps.channel("R").unwrap(),
        maps.channel("G").unwrap(),
        maps.channel("B").unwrap(),
    );
    for f in 0..k * k {
        let (gx, gy) = (f % k, f / k);
        for y in 0..n {
            for x in 0..n {
                let i = maps.index(f, x, y);
                let px = gx * n + x;
                let py = (k - 1 - gy) * n + (n - 1 - y);
                let e = |v: f32| (surfsynth::example::linear_to_srgb(v) * 255.0).round() as u8;
                img.put_pixel(
                    px as u32,
                    py as u32,
                    image::Rgb([e(r[i]), e(g[i]), e(b[i])]),
                );
            }
        }
    }
    img
}

#[test]
#[ignore = "exploration: prints measures for tuning (docs/coherent.md)"]
fn explore() {
    let variants: Vec<(&str, CoherentParams)> = vec![
        (
            "scanline",
            CoherentParams {
                order: Order::Scanline,
                ..Default::default()
            },
        ),
        (
            "front, no random",
            CoherentParams {
                random_candidates: 0,
                ..Default::default()
            },
        ),
        (
            "front+1 random",
            CoherentParams {
                random_candidates: 1,
                ..Default::default()
            },
        ),
        (
            "front+4 random",
            CoherentParams {
                random_candidates: 4,
                ..Default::default()
            },
        ),
    ];
    for (mesh, ex) in [
        (
            "meshes/spot_control_mesh.obj",
            "textures/skimage_gravel.png",
        ),
        ("meshes/spot_control_mesh.obj", "textures/skimage_brick.png"),
        (
            "meshes/double_torus_genus2.obj",
            "textures/skimage_gravel.png",
        ),
        (
            "meshes/cube_no_bottom.obj",
            "textures/gimp_burlap_weave.png",
        ),
    ] {
        for (name, p) in &variants {
            let r = coherent(data(mesh), data(ex))
                .resolution(16)
                .coherent_params(p.clone())
                .seed(7)
                .run()
                .unwrap();
            let m = measure_result(&r);
            println!(
                "| {} | {} | {name} | {:.3} | {:.3} | {:.3}–{:.3} | {:.3} |",
                mesh.trim_start_matches("meshes/"),
                ex.trim_start_matches("textures/"),
                m.seam_ratio,
                m.scale_median,
                m.scale_p10,
                m.scale_p90,
                m.coherent_fraction
            );
        }
    }
}

#[test]
#[ignore = "exploration: writes /tmp/flat_*.png"]
fn explore_flat() {
    let k = 8;
    for (name, ex) in [
        ("brick", data("textures/skimage_brick.png")),
        ("gravel", fixture("gravel.png")),
        ("weave", data("textures/gimp_burlap_weave.png")),
    ] {
        for rc in [0, 1, 4] {
            let r = coherent(flat_grid(k), ex.clone())
                .resolution(32)
                .seed(3)
                .orientation(Orientation::Axis(glam::DVec3::X))
                .coherent_params(CoherentParams {
                    random_candidates: rc,
                    ..Default::default()
                })
                .run()
                .unwrap();
            let m = measure_result(&r);
            println!("flat {name} random {rc}: {m:?}");
            let pic = flat_picture(&r.maps, k);
            pic.save(format!("/tmp/flat_{name}_r{rc}.png")).unwrap();
            let z = image::imageops::resize(
                &image::imageops::crop_imm(&pic, 0, 0, 128, 128).to_image(),
                512,
                512,
                image::imageops::FilterType::Nearest,
            );
            z.save(format!("/tmp/flat_{name}_r{rc}_zoom.png")).unwrap();
        }
    }
}

/// Runs and checks BRIEF's quality bar (issue 4's acceptance numbers).
fn assert_quality(mesh: PathBuf, example: PathBuf, n: usize, seed: u64) -> Measures {
    let r = coherent(&mesh, &example)
        .resolution(n)
        .seed(seed)
        .run()
        .unwrap();
    let m = measure_result(&r);
    let what = format!("{} + {}: {m:?}", mesh.display(), example.display());
    assert_eq!(m.coverage, 1.0, "{what}");
    assert!(m.seam_ratio <= 1.2, "{what}");
    assert!((m.scale_median - 1.0).abs() <= 0.05, "{what}");
    assert!(m.scale_p10 >= 0.85 && m.scale_p90 <= 1.15, "{what}");
    // Coherent synthesis copies patches: most adjacent pairs continue one.
    assert!(m.coherent_fraction >= 0.85, "{what}");
    m
}

#[test]
fn spot_with_stochastic_gravel_meets_the_quality_bar() {
    assert_quality(
        data("meshes/spot_control_mesh.obj"),
        fixture("gravel.png"),
        16,
        7,
    );
}

#[test]
fn spot_with_structured_bricks_meets_the_quality_bar() {
    assert_quality(
        data("meshes/spot_control_mesh.obj"),
        data("textures/skimage_brick.png"),
        16,
        7,
    );
}

#[test]
fn genus2_double_torus_meets_the_quality_bar() {
    assert_quality(
        data("meshes/double_torus_genus2.obj"),
        fixture("gravel.png"),
        16,
        3,
    );
}

#[test]
fn curved_meshes_with_reptile_scales_meet_the_quality_bar() {
    // The hardest pair measured (docs/coherent.md): large smooth structures, so every
    // forced join between patches shows. With the breadth-first domain order single runs
    // varied a lot (N = 32, seeds 1-8: Blub 0.70-1.97, double torus 1.02-1.41): fronts met
    // in clusters of small, densely sampled domains. With the area-weighted order
    // (seeds 1-16): Blub 0.42-0.77, double torus 0.77-1.02. Every run is held to 1.1,
    // the median of five to 1.0, and every run keeps coverage, scale and coherence.
    let scales = data("textures/krita_reptile_scales.png");
    for mesh in [
        "meshes/blub_control_mesh.obj",
        "meshes/double_torus_genus2.obj",
    ] {
        let mut seams: Vec<f64> = (1..=5)
            .map(|seed| {
                let r = coherent(data(mesh), &scales)
                    .resolution(32)
                    .seed(seed)
                    .run()
                    .unwrap();
                let m = measure_result(&r);
                let what = format!("{mesh} seed {seed}: {m:?}");
                assert_eq!(m.coverage, 1.0, "{what}");
                assert!((m.scale_median - 1.0).abs() <= 0.05, "{what}");
                assert!(m.scale_p10 >= 0.85 && m.scale_p90 <= 1.15, "{what}");
                assert!(m.coherent_fraction >= 0.85, "{what}");
                assert!(m.seam_ratio <= 1.1, "{what}");
                m.seam_ratio
            })
            .collect();
        seams.sort_by(f64::total_cmp);
        assert!(seams[2] <= 1.0, "{mesh}: seam ratios {seams:.3?}");
    }
}

#[test]
fn open_boundary_mesh_meets_the_quality_bar() {
    assert_quality(
        data("meshes/cube_no_bottom.obj"),
        data("textures/gimp_burlap_weave.png"),
        16,
        5,
    );
}

// ---- Determinism ----

fn bits(m: &FaceMaps) -> Vec<(String, Vec<u32>)> {
    m.channels
        .iter()
        .map(|(n, d)| (n.clone(), d.iter().map(|v| v.to_bits()).collect()))
        .collect()
}

#[test]
fn library_result_is_bit_identical_for_one_and_two_threads() {
    // Bricks on Spot: T-junctions, extraordinary corners, many waves with several domains.
    let run = |t: usize| {
        coherent(
            data("meshes/spot_control_mesh.obj"),
            data("textures/skimage_brick.png"),
        )
        .resolution(12)
        .seed(11)
        .threads(t)
        .run()
        .unwrap()
    };
    let (a, b) = (run(1), run(2));
    assert_eq!(a.report.threads, 1);
    assert_eq!(b.report.threads, 2);
    assert_eq!(bits(&a.maps), bits(&b.maps));
    // And the seed matters.
    let c = coherent(
        data("meshes/spot_control_mesh.obj"),
        data("textures/skimage_brick.png"),
    )
    .resolution(12)
    .seed(12)
    .threads(2)
    .run()
    .unwrap();
    assert_ne!(bits(&a.maps), bits(&c.maps));
}

// ---- Command line ----

fn surfsynth(args: &[&std::ffi::OsStr]) -> std::process::Output {
    std::process::Command::new(env!("CARGO_BIN_EXE_surfsynth"))
        .args(args)
        .output()
        .unwrap()
}

fn synth_args<'a>(
    mesh: &'a Path,
    example: &'a Path,
    out: &'a Path,
    extra: &'a [&'a str],
) -> Vec<&'a std::ffi::OsStr> {
    let mut v: Vec<&std::ffi::OsStr> = vec![
        "synth".as_ref(),
        "--mesh".as_ref(),
        mesh.as_os_str(),
        "--example".as_ref(),
        example.as_os_str(),
        "--out".as_ref(),
        out.as_os_str(),
    ];
    v.extend(extra.iter().map(|s| std::ffi::OsStr::new(*s)));
    v
}

#[test]
fn cli_threads_1_and_2_write_bit_identical_facemaps() {
    let dir = tempfile::tempdir().unwrap();
    let mesh = fixture("spot_control_mesh.obj");
    let ex = fixture("gravel.png");
    let mut files = Vec::new();
    for t in ["1", "2"] {
        let out = dir.path().join(format!("t{t}"));
        let mut args = vec![std::ffi::OsStr::new("--threads"), t.as_ref()];
        args.extend(synth_args(
            &mesh,
            &ex,
            &out,
            &["--resolution", "8", "--seed", "5"],
        ));
        let o = surfsynth(&args);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let stdout = String::from_utf8_lossy(&o.stdout);
        assert!(
            stdout.contains("252 domains") && stdout.contains("16128 texels"),
            "{stdout}"
        );
        for name in [
            "facemaps.exr",
            "geometry.exr",
            "report.json",
            "surface.obj",
            "surface.mtl",
            "atlas.png",
        ] {
            assert!(out.join(name).is_file(), "{name}");
        }
        let report = surfsynth::report::read(&out).unwrap();
        for key in [
            "method",
            "seed",
            "scale",
            "resolution",
            "faces",
            "texels",
            "seconds",
            "texels_per_second",
        ] {
            assert!(report.get(key).is_some(), "report.json lacks {key}");
        }
        assert_eq!(report["seed"], 5);
        assert_eq!(report["texels"], 252 * 64);
        assert_eq!(report["threads"], t.parse::<u64>().unwrap());
        files.push(std::fs::read(out.join("facemaps.exr")).unwrap());
    }
    assert!(
        files[0] == files[1],
        "facemaps.exr differs between 1 and 2 threads"
    );
}

/// Every file below `dir` (recursively), or nothing when it does not exist.
fn files_below(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    if let Ok(rd) = std::fs::read_dir(dir) {
        for e in rd.flatten() {
            let p = e.path();
            if p.is_dir() {
                out.extend(files_below(&p));
            } else {
                out.push(p);
            }
        }
    }
    out
}

/// Runs `synth` expecting a clean failure: non-zero exit, exactly one line on stderr that
/// contains every string of `expect`, and no file left in `out`.
fn assert_fails(example: &Path, extra: &[&str], out: &Path, expect: &[&str]) {
    let mesh = fixture("spot_control_mesh.obj");
    let o = surfsynth(&synth_args(&mesh, example, out, extra));
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success(), "should fail: {stderr}");
    assert_ne!(o.status.code(), Some(101), "no panic: {stderr}");
    let line = stderr.trim_end();
    assert!(
        !line.is_empty() && !line.contains('\n'),
        "one line: {stderr:?}"
    );
    for e in expect {
        assert!(line.contains(e), "{line:?} should mention {e:?}");
    }
    assert!(
        files_below(out).is_empty(),
        "left files: {:?}",
        files_below(out)
    );
}

#[test]
fn missing_example_fails_cleanly() {
    let dir = tempfile::tempdir().unwrap();
    let ex = dir.path().join("nowhere.png");
    let out = dir.path().join("out");
    assert_fails(&ex, &[], &out, &["nowhere.png"]);
    assert!(!out.exists(), "nothing created for bad input");
}

#[test]
fn corrupt_example_fails_cleanly() {
    let dir = tempfile::tempdir().unwrap();
    let ex = dir.path().join("text.png");
    std::fs::write(&ex, "this is not an image\n").unwrap();
    assert_fails(
        &ex,
        &[],
        &dir.path().join("out"),
        &["text.png", "not a PNG"],
    );
    // A real PNG signature with a truncated body.
    let bad = dir.path().join("truncated.png");
    let bytes = std::fs::read(fixture("gravel.png")).unwrap();
    std::fs::write(&bad, &bytes[..bytes.len() / 3]).unwrap();
    assert_fails(&bad, &[], &dir.path().join("out2"), &["truncated.png"]);
}

#[test]
fn tiny_example_fails_cleanly() {
    let dir = tempfile::tempdir().unwrap();
    let ex = dir.path().join("tiny.png");
    image::RgbImage::from_pixel(7, 12, image::Rgb([9, 99, 199]))
        .save(&ex)
        .unwrap();
    assert_fails(
        &ex,
        &[],
        &dir.path().join("out"),
        &["tiny.png", "7x12", "8x8"],
    );
}

#[test]
fn height_of_another_size_fails_cleanly() {
    let dir = tempfile::tempdir().unwrap();
    let h = data("textures/gimp_recessed_height.png"); // 80x80 vs 128x128
    let hs = h.to_str().unwrap();
    assert_fails(
        &fixture("gravel.png"),
        &["--height", hs],
        &dir.path().join("out"),
        &["gimp_recessed_height.png", "80x80", "128x128"],
    );
}

#[test]
fn resolution_zero_fails_cleanly() {
    let dir = tempfile::tempdir().unwrap();
    assert_fails(
        &fixture("gravel.png"),
        &["--resolution", "0"],
        &dir.path().join("out"),
        &["resolution"],
    );
    // The library refuses it too, with the same kind of message.
    let e = coherent(fixture("spot_control_mesh.obj"), fixture("gravel.png"))
        .resolution(0)
        .run()
        .unwrap_err()
        .to_string();
    assert!(e.contains("resolution 0") && !e.contains('\n'), "{e}");
}

#[test]
fn unwritable_out_fails_cleanly_before_synthesis() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("plain-file");
    std::fs::write(&file, "x").unwrap();
    let out = file.join("out");
    assert_fails(&fixture("gravel.png"), &[], &out, &["plain-file"]);
    assert_eq!(std::fs::read(&file).unwrap(), b"x");
}

#[test]
fn height_and_alpha_channels_are_synthesized_from_the_same_source() {
    // Bricks with alpha (RGBA) plus a height map of the same size: every channel of a texel
    // must equal the example's bilinear value at the recorded source.
    let ex_path = data("textures/embark_bricks_alpha.png");
    let dir = tempfile::tempdir().unwrap();
    let hpath = dir.path().join("h.png");
    let ex = surfsynth::example::Example::load(&ex_path).unwrap();
    let (w, h) = (ex.width as u32, ex.height as u32);
    image::GrayImage::from_fn(w, h, |x, y| image::Luma([((x * 7 + y * 3) % 256) as u8]))
        .save(&hpath)
        .unwrap();
    let r = coherent(data("meshes/cube_no_bottom.obj"), &ex_path)
        .height(&hpath)
        .resolution(8)
        .run()
        .unwrap();
    assert_eq!(
        r.maps.names(),
        ["R", "G", "B", "A", "height.Y", "height", "source.u", "source.v"]
    );
    let full = surfsynth::example::Example::load_with_height(&ex_path, Some(&hpath)).unwrap();
    let (su, sv) = (
        r.maps.channel("source.u").unwrap(),
        r.maps.channel("source.v").unwrap(),
    );
    let mut v = [0.0f32; 5];
    for i in 0..su.len() {
        assert!(su[i] >= 0.5 && su[i] <= w as f32 - 0.5 && sv[i] >= 0.5 && sv[i] <= h as f32 - 0.5);
        full.bilinear(su[i], sv[i], &mut v);
        for (k, name) in ["R", "G", "B", "A", "height.Y"].iter().enumerate() {
            assert_eq!(r.maps.channel(name).unwrap()[i], v[k], "{name} at {i}");
        }
    }
    assert_eq!(r.maps.channel("height"), r.maps.channel("height.Y"));
    assert_eq!(r.report.example.channels, ["R", "G", "B", "A", "height.Y"]);
}

#[test]
#[ignore = "exploration: structured examples on curved meshes"]
fn explore_scales() {
    let variants: Vec<(&str, CoherentParams)> = vec![
        (
            "front, no random",
            CoherentParams {
                random_candidates: 0,
                ..Default::default()
            },
        ),
        ("front+1 random (default)", CoherentParams::default()),
    ];
    for mesh in [
        "meshes/blub_control_mesh.obj",
        "meshes/double_torus_genus2.obj",
    ] {
        for (name, p) in &variants {
            for orient in [Orientation::Auto, Orientation::Axis(glam::DVec3::Z)] {
                let r = coherent(data(mesh), data("textures/krita_reptile_scales.png"))
                    .resolution(32)
                    .orientation(orient.clone())
                    .coherent_params(p.clone())
                    .seed(1)
                    .run()
                    .unwrap();
                let q = surfsynth::eval::evaluate_maps(
                    &r.maps,
                    &r.geometry_maps(),
                    Some(r.report.scale),
                    None,
                )
                .unwrap();
                println!("{mesh} {name} {orient:?}: seam {:.3} (seam {:.5} inner {:.5}) coh {:.3} stats {:?}", q.seam_ratio.unwrap(), q.seam_mean_sq.unwrap(), q.interior_mean_sq.unwrap(), q.coherent_fraction.unwrap(), r.report.coherent_stats());
            }
        }
    }
}

// ---- Seam tail: measurement over seeds and a diagnostic of the worst seam pairs ----

/// The mesh/example pairs whose worst seed the quality work targets (N = 32).
const TAIL_SETS: [(&str, &str); 5] = [
    (
        "meshes/blub_control_mesh.obj",
        "textures/krita_reptile_scales.png",
    ),
    (
        "meshes/double_torus_genus2.obj",
        "textures/krita_reptile_scales.png",
    ),
    ("meshes/spot_control_mesh.obj", "fixtures/gravel.png"),
    ("meshes/spot_control_mesh.obj", "textures/skimage_brick.png"),
    (
        "meshes/cube_no_bottom.obj",
        "textures/gimp_burlap_weave.png",
    ),
];

fn tail_path(rel: &str) -> PathBuf {
    match rel.strip_prefix("fixtures/") {
        Some(f) => fixture(f),
        None => data(rel),
    }
}

/// Seam ratio (and the other measures) over TAIL_SEEDS seeds (default 8) from TAIL_FIRST
/// (default 1), domain order TAIL_ORDER (breadth | area, default area) for every
/// pair of [`TAIL_SETS`] whose mesh or example contains TAIL_FILTER (default all), N =
/// TAIL_N (default 32): worst and median per pair.
#[test]
#[ignore = "measurement: seam ratio over seeds (slow)"]
fn seam_tail() {
    let seeds: u64 = env_or("TAIL_SEEDS", 8);
    let first: u64 = env_or("TAIL_FIRST", 1);
    let n: usize = env_or("TAIL_N", 32);
    let filter = std::env::var("TAIL_FILTER").unwrap_or_default();
    let hand = match std::env::var("TAIL_HAND").as_deref() {
        Ok("outside") => surfsynth::synthesizer::Handedness::Outside,
        _ => surfsynth::synthesizer::Handedness::Tiles,
    };
    let domain_order = match std::env::var("TAIL_ORDER").as_deref() {
        Ok("breadth") => surfsynth::synth::coherent::DomainOrder::Breadth,
        _ => surfsynth::synth::coherent::DomainOrder::Area,
    };
    for (mesh, ex) in TAIL_SETS {
        if !(mesh.contains(&filter) || ex.contains(&filter)) {
            continue;
        }
        let mut seams = Vec::new();
        let (mut coh, mut p10, mut p90, mut secs) = (f64::INFINITY, f64::INFINITY, 0.0f64, 0.0);
        let mut waves = 0;
        for seed in first..first + seeds {
            let r = coherent(data(mesh), tail_path(ex))
                .resolution(n)
                .seed(seed)
                .handedness(hand)
                .coherent_params(CoherentParams {
                    domain_order,
                    ..Default::default()
                })
                .run()
                .unwrap();
            waves = r.report.coherent_stats().unwrap().waves;
            let m = measure_result(&r);
            assert_eq!(m.coverage, 1.0);
            assert!((m.scale_median - 1.0).abs() <= 0.05, "{m:?}");
            seams.push(m.seam_ratio);
            coh = coh.min(m.coherent_fraction);
            p10 = p10.min(m.scale_p10);
            p90 = p90.max(m.scale_p90);
            secs += r.report.seconds.synthesis;
        }
        let listed = seams.iter().map(|s| format!("{s:.2}")).collect::<Vec<_>>();
        let mut sorted = seams.clone();
        sorted.sort_by(f64::total_cmp);
        let median = 0.5 * (sorted[(sorted.len() - 1) / 2] + sorted[sorted.len() / 2]);
        println!(
            "TAIL {mesh} + {ex} N={n}: worst {:.3} median {median:.3} [{}] min coherent {coh:.3} scale p10 {p10:.3} p90 {p90:.3} synth {:.2}s, {waves} waves",
            sorted[sorted.len() - 1],
            listed.join(" "),
            secs / seeds as f64,
        );
    }
}

/// Lists the worst seam pairs of one run (DIAG_MESH, DIAG_EX relative to shared/data or
/// fixtures/, DIAG_SEED, DIAG_N) and what they have in common: domains and their
/// schedule, distance to extraordinary corners and to field singularities, how the texels
/// were chosen, whether the source continues across the seam.
#[test]
#[ignore = "diagnostic: worst seam pairs of one run"]
fn diagnose_seams() {
    use surfsynth::field::OrientationField;
    use surfsynth::synth::coherent::{self, Kind};
    use surfsynth::texels::{corner_fan, TexelGraph};
    let mesh: String = env_or("DIAG_MESH", "meshes/blub_control_mesh.obj".to_string());
    let ex: String = env_or("DIAG_EX", "textures/krita_reptile_scales.png".to_string());
    let seed: u64 = env_or("DIAG_SEED", 5);
    let n: usize = env_or("DIAG_N", 32);
    let top: usize = env_or("DIAG_TOP", 25);
    let r = coherent(data(&mesh), tail_path(&ex))
        .resolution(n)
        .seed(seed)
        .appearance(surfsynth::synthesizer::AppearanceMode::Rgb)
        .run()
        .unwrap();
    let m = measure_result(&r);
    println!(
        "{mesh} + {ex} seed {seed} N={n}: {m:?} stats {:?}",
        r.report.coherent_stats()
    );
    let surface = &r.surface;
    let geom = &r.geometry;
    let nn = n * n;
    let faces = geom.faces();
    // The same coherent run again, for the per-texel kinds.
    let field = OrientationField::compute(surface, &Orientation::Auto).unwrap();
    let frames = surfsynth::synth::frames_f32(&field.texel_frames(surface, n));
    let graph = TexelGraph::build(surface, geom);
    // The schedule the run used (ranks and waves below).
    let schedule = coherent::schedule_for(
        CoherentParams::default().domain_order,
        surface,
        geom,
        &graph,
    );
    let flipped = r.example.flipped_rows();
    let out = surfsynth::synth::run_coherent(
        &flipped,
        &Default::default(),
        coherent::Inputs {
            geometry: geom,
            graph: &graph,
            frames: &frames,
            schedule: &schedule,
            scale: r.report.scale,
            factor: None,
            seed,
        },
        &CoherentParams::default(),
        &|_| {},
    );
    let (su, sv) = (
        r.maps.channel("source.u").unwrap(),
        r.maps.channel("source.v").unwrap(),
    );
    let hgt = r.example.height as f32;
    for t in 0..faces * nn {
        assert_eq!(out.source[t][0], su[t]);
        assert_eq!(hgt - out.source[t][1], sv[t]);
    }
    let (cr, cg, cb) = (
        r.maps.channel("R").unwrap(),
        r.maps.channel("G").unwrap(),
        r.maps.channel("B").unwrap(),
    );
    let col = |i: usize| [cr[i] as f64, cg[i] as f64, cb[i] as f64];
    let d2 = |a: [f64; 3], b: [f64; 3]| (0..3).map(|k| (a[k] - b[k]).powi(2)).sum::<f64>();
    // Interior mean (as eval).
    let (mut isum, mut icount) = (0.0, 0usize);
    for d in 0..faces {
        for y in 0..n {
            for x in 0..n {
                let a = d * nn + y * n + x;
                if x + 1 < n {
                    isum += d2(col(a), col(a + 1));
                    icount += 1;
                }
                if y + 1 < n {
                    isum += d2(col(a), col(a + n));
                    icount += 1;
                }
            }
        }
    }
    let imean = isum / icount as f64;
    // Seam pairs (as eval): border texels of different domains 0.5h..1.25h apart.
    let h = r.report.texel_spacing;
    let border: Vec<usize> = (0..faces * nn)
        .filter(|&i| {
            let (x, y) = (i % n, (i / n) % n);
            x == 0 || y == 0 || x + 1 == n || y + 1 == n
        })
        .collect();
    let pts: Vec<[f64; 3]> = border
        .iter()
        .map(|&i| geom.pos[i].as_dvec3().to_array())
        .collect();
    let tree: kiddo::ImmutableKdTree<f64, 3> =
        kiddo::ImmutableKdTree::new_from_slice(&pts).unwrap();
    let mut pairs: Vec<(f64, usize, usize)> = Vec::new();
    for (k, &a) in border.iter().enumerate() {
        for nb in tree
            .query(&pts[k])
            .within::<kiddo::SquaredEuclidean<f64>>((1.25 * h).powi(2))
            .unsorted()
            .execute()
        {
            let j = nb.item as usize;
            let b = border[j];
            if j <= k || nb.distance < (0.5 * h).powi(2) || a / nn == b / nn {
                continue;
            }
            pairs.push((d2(col(a), col(b)), a, b));
        }
    }
    pairs.sort_by(|p, q| q.0.total_cmp(&p.0));
    let ssum: f64 = pairs.iter().map(|p| p.0).sum();
    println!(
        "seam pairs {} ratio {:.3}; h {h:.5}",
        pairs.len(),
        ssum / pairs.len() as f64 / imean
    );
    for frac in [0.001, 0.01, 0.05] {
        let k = ((pairs.len() as f64 * frac).ceil() as usize).max(1);
        let s: f64 = pairs[..k].iter().map(|p| p.0).sum();
        println!(
            "  top {:.1}% ({k} pairs) hold {:.1}% of the seam sum; without them the ratio is {:.3}",
            frac * 100.0,
            100.0 * s / ssum,
            (ssum - s) / (pairs.len() - k) as f64 / imean
        );
    }
    // Per domain: rank in the sequential order, wave, valence of each corner.
    let mut rank = vec![0usize; faces];
    for (i, &d) in schedule.order.iter().enumerate() {
        rank[d as usize] = i;
    }
    let mut wave = vec![0usize; faces];
    for (w, ds) in schedule.waves.iter().enumerate() {
        for &d in ds {
            wave[d as usize] = w;
        }
    }
    let valence: Vec<[usize; 4]> = (0..faces)
        .map(|d| std::array::from_fn(|c| corner_fan(surface, d, c).len() + 1))
        .collect();
    let corner_xy = |c: usize| -> (usize, usize) {
        match c {
            0 => (0, 0),
            1 => (n - 1, 0),
            2 => (n - 1, n - 1),
            _ => (0, n - 1),
        }
    };
    // Chebyshev distance (texels) to the nearest corner of valence != 4.
    let ev_dist = |t: usize| -> usize {
        let (d, x, y) = (t / nn, t % n, (t / n) % n);
        (0..4)
            .filter(|&c| valence[d][c] != 4)
            .map(|c| {
                let (cx, cy) = corner_xy(c);
                x.abs_diff(cx).max(y.abs_diff(cy))
            })
            .min()
            .unwrap_or(usize::MAX)
    };
    let sing: Vec<glam::DVec3> = field.singularities().iter().map(|s| s.position).collect();
    println!("singularities: {}", sing.len());
    let sing_dist = |t: usize| -> f64 {
        let p = geom.pos[t].as_dvec3();
        sing.iter()
            .map(|s| s.distance(p) / h)
            .fold(f64::INFINITY, f64::min)
    };
    // Sides of domain d touching domains earlier in the order (at its synthesis time).
    let mut buf = Vec::new();
    let sides_done: Vec<usize> = (0..faces)
        .map(|d| {
            (0..4)
                .filter(|&s| {
                    (0..n).any(|i| {
                        let (x, y) = match s {
                            0 => (i, 0),
                            1 => (n - 1, i),
                            2 => (i, n - 1),
                            _ => (0, i),
                        };
                        buf.clear();
                        graph.neighbours(d * nn + y * n + x, &mut buf);
                        buf.iter().any(|&j| {
                            let e = j as usize / nn;
                            e != d && rank[e] < rank[d]
                        })
                    })
                })
                .count()
        })
        .collect();
    let src = |t: usize| out.source[t];
    let sdist = |a: usize, b: usize| {
        let (p, q) = (src(a), src(b));
        (p[0] - q[0]).hypot(p[1] - q[1])
    };
    // Whether a texel continues a patch of one of its in-domain 4-neighbours.
    let inner_coherent = |t: usize| -> bool {
        let (x, y) = (t % n, (t / n) % n);
        let mut v = Vec::new();
        if x > 0 {
            v.push(t - 1);
        }
        if x + 1 < n {
            v.push(t + 1);
        }
        if y > 0 {
            v.push(t - n);
        }
        if y + 1 < n {
            v.push(t + n);
        }
        v.into_iter().any(|u| sdist(t, u) <= 4.0)
    };
    let kind_name = |k: u8| match k {
        0 => "seeded",
        1 => "cont",
        2 => "random",
        _ => "restart",
    };
    println!("worst pairs: dC2/interior | later texel (domain x,y rank wave sidesdone kind) | earlier | evdist singdist/h | src dist across | later coherent inside");
    for &(c, a, b) in pairs.iter().take(top) {
        let (late, early) = if rank[a / nn] > rank[b / nn] {
            (a, b)
        } else {
            (b, a)
        };
        let desc = |t: usize| {
            let d = t / nn;
            format!(
                "d{d} ({},{}) r{} w{} s{} {} v{:?}",
                t % n,
                (t / n) % n,
                rank[d],
                wave[d],
                sides_done[d],
                kind_name(out.kind[t]),
                valence[d]
            )
        };
        println!(
            "{:7.1} | {} | {} | ev {} sing {:.1} | {:.1} | {}",
            c / imean,
            desc(late),
            desc(early),
            ev_dist(late).min(ev_dist(early)),
            sing_dist(late).min(sing_dist(early)),
            sdist(a, b),
            inner_coherent(late)
        );
    }
    // Texel spacing per domain (median of its adjacent pairs) relative to h.
    let spacing: Vec<f64> = (0..faces)
        .map(|d| {
            let mut v: Vec<f64> = (0..n * (n - 1))
                .map(|i| {
                    let (x, y) = (i % (n - 1), i / (n - 1));
                    geom.pos[d * nn + y * n + x].distance(geom.pos[d * nn + y * n + x + 1]) as f64
                })
                .collect();
            v.sort_by(f64::total_cmp);
            v[v.len() / 2] / h
        })
        .collect();
    println!("seam sum and pairs by the denser side's spacing/h:");
    for (lo, hi) in [
        (0.0, 0.3),
        (0.3, 0.5),
        (0.5, 0.7),
        (0.7, 0.9),
        (0.9, 1.1),
        (1.1, 9.0),
    ] {
        let sel: Vec<_> = pairs
            .iter()
            .filter(|p| {
                let s = spacing[p.1 / nn].min(spacing[p.2 / nn]);
                s >= lo && s < hi
            })
            .collect();
        let s: f64 = sel.iter().map(|p| p.0).sum();
        println!(
            "  [{lo:.1},{hi:.1}): {:.1}% of pairs, {:.1}% of the sum, mean {:.2}x interior",
            100.0 * sel.len() as f64 / pairs.len() as f64,
            100.0 * s / ssum,
            s / sel.len().max(1) as f64 / imean
        );
    }
    let mut by_dom: std::collections::BTreeMap<(usize, usize), (f64, usize)> = Default::default();
    for p in &pairs {
        let k = ((p.1 / nn).min(p.2 / nn), (p.1 / nn).max(p.2 / nn));
        let e = by_dom.entry(k).or_default();
        e.0 += p.0;
        e.1 += 1;
    }
    let mut by_dom: Vec<_> = by_dom.into_iter().collect();
    by_dom.sort_by(|a, b| b.1 .0.total_cmp(&a.1 .0));
    println!("domain pairs holding most of the seam sum:");
    for ((a, b), (s, c)) in by_dom.iter().take(12) {
        println!(
            "  d{a}-d{b}: {:.1}% of the sum, {c} pairs, mean {:.1}x; spacing {:.2} {:.2}; ranks {} {}",
            100.0 * s / ssum,
            s / *c as f64 / imean,
            spacing[*a],
            spacing[*b],
            rank[*a],
            rank[*b]
        );
    }
    // The worst pair's later texel: its neighbours and what they were copied from.
    if let Some(&(_, a, b)) = pairs.first() {
        let (late, early) = if rank[a / nn] > rank[b / nn] {
            (a, b)
        } else {
            (b, a)
        };
        let p = geom.pos[late];
        let [v1, v2] = frames[late];
        let inv = 1.0 / r.report.scale as f32;
        println!(
            "worst later texel d{} ({},{}) src {:?}; early d{} ({},{}) src {:?} at {:.2}h",
            late / nn,
            late % n,
            (late / n) % n,
            src(late),
            early / nn,
            early % n,
            (early / n) % n,
            src(early),
            geom.pos[early].distance(p) as f64 / h
        );
        buf.clear();
        graph.neighbours(late, &mut buf);
        for &j in &buf {
            let j = j as usize;
            let dp = geom.pos[j] - p;
            let e = [dp.dot(v1) * inv, -dp.dot(v2) * inv];
            let s = src(j);
            println!(
                "  nb d{} ({},{}) r{} |dp|/h {:.2} e ({:.2},{:.2}) src ({:.1},{:.1}) cand ({:.1},{:.1}) {} frame dot {:.3}",
                j / nn,
                j % n,
                (j / n) % n,
                rank[j / nn],
                dp.length() as f64 / h,
                e[0],
                e[1],
                s[0],
                s[1],
                s[0] - e[0],
                s[1] - e[1],
                kind_name(out.kind[j]),
                frames[j][0].dot(v1)
            );
        }
    }
    // Aggregates: top 1% vs all pairs.
    let k1 = (pairs.len() / 100).max(1);
    for (label, set) in [("top 1%", &pairs[..k1]), ("all", &pairs[..])] {
        let cnt = set.len() as f64;
        let frac = |f: &dyn Fn(&(f64, usize, usize)) -> bool| {
            100.0 * set.iter().filter(|p| f(p)).count() as f64 / cnt
        };
        let late = |p: &(f64, usize, usize)| {
            if rank[p.1 / nn] > rank[p.2 / nn] {
                p.1
            } else {
                p.2
            }
        };
        println!(
            "{label}: ev<=2 {:.0}% ev<=4 {:.0}% sing<=3h {:.0}% | later kind cont {:.0}% random {:.0}% restart {:.0}% | later inner-coherent {:.0}% | coherent across {:.0}% | later sides done 1:{:.0}% 2:{:.0}% 3+:{:.0}% | same wave-gap 1 {:.0}%",
            frac(&|p| ev_dist(p.1).min(ev_dist(p.2)) <= 2),
            frac(&|p| ev_dist(p.1).min(ev_dist(p.2)) <= 4),
            frac(&|p| sing_dist(p.1).min(sing_dist(p.2)) <= 3.0),
            frac(&|p| out.kind[late(p)] == Kind::Continuation as u8),
            frac(&|p| out.kind[late(p)] == Kind::RandomWin as u8),
            frac(&|p| out.kind[late(p)] == Kind::Restart as u8),
            frac(&|p| inner_coherent(late(p))),
            frac(&|p| sdist(p.1, p.2) <= 4.0),
            frac(&|p| sides_done[late(p) / nn] == 1),
            frac(&|p| sides_done[late(p) / nn] == 2),
            frac(&|p| sides_done[late(p) / nn] >= 3),
            frac(&|p| wave[late(p) / nn] - wave[(p.1 + p.2 - late(p)) / nn] == 1),
        );
    }
}
