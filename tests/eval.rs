//! `eval` on hand-built result directories whose answers are known: a hand-computed tiny
//! case (every number exact), a flat grid with an exact affine copy of an example (scale
//! fidelity exactly 1), texel noise (seam ratio 1 in expectation), per-face colour jumps
//! (seam ratio far above 1), the legacy patch fidelity 0 for copied patches, and the error
//! cases. pf1/pf4/pf8 have their own file, tests/eval_pf.rs.

mod common;

use common::data;
use glam::DVec3;
use std::path::Path;
use subdiv::{ControlMesh, DomainId, Surface};
use surfsynth::eval::{evaluate, evaluate_with, EvalOptions, Quality};
use surfsynth::io::exr::{write_face_maps, FaceMaps};

fn grid_surface(k: usize) -> Surface {
    Surface::new(ControlMesh::grid(k))
}

/// geometry.exr maps (P, N at texel centres) of a surface.
fn geometry(s: &Surface, n: usize) -> FaceMaps {
    let mut g = FaceMaps::new(
        s.num_domains(),
        n,
        &["P.X", "P.Y", "P.Z", "N.X", "N.Y", "N.Z"],
    );
    let mut t = vec![Default::default(); n * n];
    for d in 0..s.num_domains() {
        s.eval_texels(DomainId::from_idx(d), n, &mut t);
        for (j, smp) in t.iter().enumerate() {
            let i = d * n * n + j;
            let v = [smp.p.x, smp.p.y, smp.p.z, smp.n.x, smp.n.y, smp.n.z];
            for (k, (_, data)) in g.channels.iter_mut().enumerate() {
                data[i] = v[k] as f32;
            }
        }
    }
    g
}

fn write_dir(dir: &Path, colour: &FaceMaps, geo: &FaceMaps, scale: Option<f64>) {
    write_face_maps(dir.join("facemaps.exr"), colour).unwrap();
    write_face_maps(dir.join("geometry.exr"), geo).unwrap();
    if let Some(s) = scale {
        std::fs::write(
            dir.join("report.json"),
            format!("{{\"method\": \"coherent\", \"scale\": {s}, \"seed\": 1}}"),
        )
        .unwrap();
    }
}

fn hash(mut h: u64) -> f32 {
    h = h.wrapping_add(0x9E37_79B9_7F4A_7C15);
    h = (h ^ (h >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    h = (h ^ (h >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    ((h ^ (h >> 31)) >> 40) as f32 / (1u64 << 24) as f32
}

/// A procedural "example": a smooth colour at example position (su, sv) in pixels.
fn example_colour(su: f64, sv: f64) -> [f32; 3] {
    let t = std::f64::consts::TAU;
    [
        (0.5 + 0.3 * (t * su / 11.0).sin() * (t * sv / 7.0).cos()) as f32,
        (0.5 + 0.3 * (t * (su + sv) / 13.0).sin()) as f32,
        (0.5 + 0.3 * (t * (su - 0.5 * sv) / 9.0).cos()) as f32,
    ]
}

/// Colour maps where texel i gets `f(domain, x, y, P)` = (colour, source).
fn colour_maps(
    s: &Surface,
    geo: &FaceMaps,
    f: impl Fn(usize, usize, usize, DVec3) -> ([f32; 3], [f32; 2]),
) -> FaceMaps {
    let n = geo.uniform_n().unwrap();
    let mut m = FaceMaps::new(s.num_domains(), n, &["R", "G", "B", "source.u", "source.v"]);
    let (px, py, pz) = (
        geo.channel("P.X").unwrap().to_vec(),
        geo.channel("P.Y").unwrap().to_vec(),
        geo.channel("P.Z").unwrap().to_vec(),
    );
    for d in 0..s.num_domains() {
        for y in 0..n {
            for x in 0..n {
                let i = m.index(d, x, y);
                let p = DVec3::new(px[i] as f64, py[i] as f64, pz[i] as f64);
                let (c, src) = f(d, x, y, p);
                let vals = [c[0], c[1], c[2], src[0], src[1]];
                for (k, (_, data)) in m.channels.iter_mut().enumerate() {
                    data[i] = vals[k];
                }
            }
        }
    }
    m
}

/// Source = example position of P under a rotation by 30 degrees, scale 1/S, offset.
fn affine_source(p: DVec3, s: f64) -> [f64; 2] {
    let (sn, cs) = 30f64.to_radians().sin_cos();
    [
        100.0 + (cs * p.x - sn * p.y) / s,
        50.0 + (sn * p.x + cs * p.y) / s,
    ]
}

fn print(name: &str, q: &Quality) {
    println!("{name}: {}", serde_json::to_string(q).unwrap());
}

#[test]
fn hand_computed_two_face_case() {
    // Two unit squares side by side, N = 2: texel centres 0.5 apart, so h = 0.5. Face 0 has
    // R = x (0 or 1), face 1 has R = 3. Sources: face 0 u = 5 + 2x (2 px per texel), face 1
    // u = 100 + 10x (10 px: not a continued patch); v = 7 + y everywhere.
    let n = 2;
    let mut geo = FaceMaps::new(2, n, &["P.X", "P.Y", "P.Z"]);
    let mut col = FaceMaps::new(2, n, &["R", "G", "B", "source.u", "source.v"]);
    for d in 0..2 {
        for y in 0..n {
            for x in 0..n {
                let i = geo.index(d, x, y);
                geo.channels[0].1[i] = d as f32 + 0.25 + 0.5 * x as f32;
                geo.channels[1].1[i] = 0.25 + 0.5 * y as f32;
                col.channels[0].1[i] = if d == 0 { x as f32 } else { 3.0 };
                col.channels[3].1[i] = if d == 0 {
                    5.0 + 2.0 * x as f32
                } else {
                    100.0 + 10.0 * x as f32
                };
                col.channels[4].1[i] = 7.0 + y as f32;
            }
        }
    }
    let dir = tempfile::tempdir().unwrap();
    write_dir(dir.path(), &col, &geo, Some(0.25));
    let q = evaluate(dir.path(), None).unwrap();
    print("two faces", &q);
    assert_eq!((q.faces, q.resolution, q.texels), (2, 2, 8));
    assert_eq!(q.coverage, 1.0);
    assert_eq!(q.texel_spacing, Some(0.5));
    // Interior: face 0 has two horizontal pairs with |dR|^2 = 1, the other six pairs 0.
    assert_eq!(q.interior_pairs, 8);
    assert_eq!(q.interior_mean_sq, Some(0.25));
    // Seams: (0.75, y) against (1.25, y), R 1 vs 3; the diagonals (0.707 > 1.25h) are out.
    assert_eq!(q.seam_pairs, 2);
    assert_eq!(q.seam_mean_sq, Some(4.0));
    assert_eq!(q.seam_ratio, Some(16.0));
    // Both seam pairs run along the u axis of their texels.
    assert_eq!((q.seam_pairs_axis, q.seam_ratio_axis), (2, Some(16.0)));
    // r = |ds| S / |dP|: face 0 horizontal 2*0.25/0.5 = 1 (x2), vertical 0.5 (x2); face 1
    // vertical 0.5 (x2); face 1 horizontal is not continued. Sorted [.5 .5 .5 .5 1 1].
    let sf = q.scale_fidelity.unwrap();
    assert_eq!((sf.count, sf.median, sf.p10, sf.p90), (6, 0.5, 0.5, 1.0));
    assert_eq!(q.coherent_fraction, Some(0.75));
    assert_eq!(q.scale, Some(0.25));
    // --scale overrides the report: r doubles.
    let q2 = evaluate(dir.path(), Some(0.5)).unwrap();
    assert_eq!(q2.scale_fidelity.unwrap().p90, 2.0);

    // A NaN position: coverage 7/8, and its pairs leave the distance and ratio sets.
    let i = geo.index(1, 1, 1);
    geo.channels[0].1[i] = f32::NAN;
    write_dir(dir.path(), &col, &geo, Some(0.25));
    let q = evaluate(dir.path(), None).unwrap();
    assert_eq!(q.coverage, 0.875);
    assert_eq!(q.scale_fidelity.unwrap().count, 5);
}

#[test]
fn affine_copy_on_a_flat_grid_has_scale_fidelity_one() {
    let s = grid_surface(6);
    let n = 16;
    let geo = geometry(&s, n);
    let scale = 1.0 / 16.0;
    let col = colour_maps(&s, &geo, |_, _, _, p| {
        let [su, sv] = affine_source(p, scale);
        (example_colour(su, sv), [su as f32, sv as f32])
    });
    let dir = tempfile::tempdir().unwrap();
    write_dir(dir.path(), &col, &geo, Some(scale));
    let q = evaluate(dir.path(), None).unwrap();
    print("affine copy", &q);
    assert_eq!(q.coverage, 1.0);
    let sf = q.scale_fidelity.unwrap();
    // Exact up to f32 storage of positions and sources.
    for v in [sf.median, sf.p10, sf.p90] {
        assert!((v - 1.0).abs() < 1e-4, "{sf:?}");
    }
    assert_eq!(sf.count, q.interior_pairs);
    assert_eq!(q.coherent_fraction, Some(1.0));
    let seam = q.seam_ratio.unwrap();
    assert!((0.85..=1.15).contains(&seam), "seam ratio {seam}");
    // h: interior texels are 1/16 apart; the boundary rows of the limit surface are a bit
    // compressed, so the median is just below.
    let h = q.texel_spacing.unwrap();
    assert!((h - 1.0 / 16.0).abs() < 0.005, "{h}");
    // 5 interior edges per row and column, 6 rows, 2 directions, 16 texel pairs each.
    assert_eq!(q.seam_pairs, 2 * 5 * 6 * 16);
}

/// BRIEF's seam band (0.5h–1.25h) takes diagonal pairs across borders wherever texels are
/// smaller than h; they are farther apart than the u/v pairs inside faces, so they differ
/// more even where the texture is continuous. The ratio along the texels' axes compares
/// like with like.
#[test]
fn diagonal_seam_pairs_are_told_apart_on_uneven_texels() {
    // The open cube: flat sides, its texels smaller along the rounded edges.
    let s = Surface::new(ControlMesh::load_obj(data("meshes/cube_no_bottom.obj")).unwrap());
    let n = 16;
    let geo = geometry(&s, n);
    let wave = colour_maps(&s, &geo, |_, _, _, p| {
        let k = 9.0;
        let c = [(k * p.x).sin(), (k * p.y).sin(), (k * p.z).sin()];
        ([c[0] as f32, c[1] as f32, c[2] as f32], [0.0, 0.0])
    });
    let dir = tempfile::tempdir().unwrap();
    write_dir(dir.path(), &wave, &geo, Some(1.0));
    let q = evaluate(dir.path(), None).unwrap();
    print("smooth waves on a cube", &q);
    // Measured: 3,233 of 6,040 seam pairs along the axes; ratios 1.007 (all), 0.877.
    let (all, axis) = (q.seam_ratio.unwrap(), q.seam_ratio_axis.unwrap());
    let share = q.seam_pairs_axis as f64 / q.seam_pairs as f64;
    assert!((0.4..=0.7).contains(&share), "share along the axes {share}");
    assert!(
        all > axis + 0.1,
        "all seam pairs {all}, along the axes {axis}"
    );
    assert!((0.8..=1.0).contains(&axis), "along the axes {axis}");
}

#[test]
fn texel_noise_has_seam_ratio_one_and_face_jumps_do_not() {
    let s = grid_surface(8);
    let n = 16;
    let geo = geometry(&s, n);
    let noise = colour_maps(&s, &geo, |d, x, y, _| {
        let k = ((d * 64 + y) * 64 + x) as u64 * 3;
        ([hash(k), hash(k + 1), hash(k + 2)], [0.0, 0.0])
    });
    let dir = tempfile::tempdir().unwrap();
    write_dir(dir.path(), &noise, &geo, Some(1.0));
    let q = evaluate(dir.path(), None).unwrap();
    print("noise", &q);
    let r = q.seam_ratio.unwrap();
    assert!((0.9..=1.1).contains(&r), "noise seam ratio {r}");
    // Noise: E|dC|^2 = 3 * 2 * var(U) = 0.5 per pair.
    let m = q.interior_mean_sq.unwrap();
    assert!((m - 0.5).abs() < 0.01, "{m}");
    // Every source equal: all pairs "continue" a patch at zero stretch.
    assert_eq!(q.coherent_fraction, Some(1.0));
    assert_eq!(q.scale_fidelity.unwrap().median, 0.0);

    // A smooth texture (magnified 4x: a quarter pixel per texel) plus a per-face offset:
    // steps at every face edge.
    let jumps = colour_maps(&s, &geo, |d, _, _, p| {
        let [su, sv] = affine_source(p, 1.0 / 4.0);
        let c = example_colour(su, sv);
        let o = 0.3 * (hash(d as u64) - 0.5);
        ([c[0] + o, c[1] + o, c[2] + o], [su as f32, sv as f32])
    });
    write_dir(dir.path(), &jumps, &geo, Some(1.0 / 4.0));
    let q = evaluate(dir.path(), None).unwrap();
    print("face jumps", &q);
    let r = q.seam_ratio.unwrap();
    assert!(r > 10.0, "jump seam ratio {r}");
    // The jumps leave the geometry of the copy alone.
    assert!((q.scale_fidelity.unwrap().median - 1.0).abs() < 1e-4);
}

#[test]
fn evaluation_does_not_depend_on_thread_count() {
    let s = Surface::load_obj(data("meshes/spot_control_mesh.obj")).unwrap();
    let geo = geometry(&s, 8);
    let col = colour_maps(&s, &geo, |d, x, y, p| {
        let k = ((d * 64 + y) * 64 + x) as u64 * 3;
        (
            [hash(k), (p.x as f32).sin(), hash(k + 1)],
            [(p.x * 40.0) as f32, (p.y * 40.0) as f32],
        )
    });
    let dir = tempfile::tempdir().unwrap();
    write_dir(dir.path(), &col, &geo, Some(0.025));
    let run = |t: usize| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(t)
            .build()
            .unwrap();
        pool.install(|| evaluate(dir.path(), None).unwrap())
    };
    let (a, b) = (run(1), run(2));
    print("spot", &a);
    assert_eq!(
        serde_json::to_string(&a).unwrap(),
        serde_json::to_string(&b).unwrap()
    );
    assert!(a.seam_pairs > 0 && a.coverage == 1.0);
}

fn write_png(path: &Path, w: usize, h: usize, f: impl Fn(usize, usize) -> [u8; 3]) {
    let mut buf = Vec::with_capacity(w * h * 3);
    for y in 0..h {
        for x in 0..w {
            buf.extend_from_slice(&f(x, y));
        }
    }
    image::save_buffer(
        path,
        &buf,
        w as u32,
        h as u32,
        image::ExtendedColorType::Rgb8,
    )
    .unwrap();
}

#[test]
fn patch_fidelity_is_zero_for_copied_patches_and_near_one_for_shuffled_pixels() {
    let dir = tempfile::tempdir().unwrap();
    let ex_path = dir.path().join("example.png");
    let (w, h) = (40usize, 40usize);
    write_png(&ex_path, w, h, |x, y| {
        let k = (y * w + x) as u64 * 3;
        [
            (hash(k) * 255.0) as u8,
            (hash(k + 1) * 255.0) as u8,
            (hash(k + 2) * 255.0) as u8,
        ]
    });
    let ex = surfsynth::example::Example::load(&ex_path).unwrap();
    let s = grid_surface(3);
    let n = 16;
    let geo = geometry(&s, n);
    // Copy: face d shows the example translated by a per-face offset (1:1, axis-aligned).
    let copy = colour_maps(&s, &geo, |d, x, y, _| {
        let (ox, oy) = (d * 3 % 24, d * 5 % 24);
        let c = ex.rgb[(oy + y) * w + ox + x];
        (c, [(ox + x) as f32 + 0.5, (oy + y) as f32 + 0.5])
    });
    let out = dir.path().join("copy");
    std::fs::create_dir(&out).unwrap();
    write_dir(&out, &copy, &geo, Some(1.0 / 16.0));
    let opts = EvalOptions {
        scale: None,
        example: Some(ex_path.clone()),
    };
    let q = evaluate_with(&out, &opts).unwrap();
    print("copied patches", &q);
    assert_eq!(q.patch_fidelity, Some(0.0));
    // Shuffled example pixels: same colours, no patch structure.
    let shuffled = colour_maps(&s, &geo, |d, x, y, _| {
        let k = ((d * 64 + y) * 64 + x) as u64;
        let i = ((hash(k) * (w * h) as f32) as usize).min(w * h - 1);
        (ex.rgb[i], [0.0, 0.0])
    });
    write_dir(&out, &shuffled, &geo, Some(1.0 / 16.0));
    let q = evaluate_with(&out, &opts).unwrap();
    print("shuffled", &q);
    let pf = q.patch_fidelity.unwrap();
    assert!((0.7..1.0).contains(&pf), "{pf}");
}

fn err(dir: &Path, opts: &EvalOptions) -> String {
    let e = evaluate_with(dir, opts).unwrap_err().to_string();
    assert!(!e.contains('\n'), "not one line: {e}");
    e
}

#[test]
fn bad_inputs_give_one_line_errors_naming_the_file() {
    let s = grid_surface(2);
    let geo = geometry(&s, 4);
    let col = colour_maps(&s, &geo, |_, x, y, _| ([0.5; 3], [x as f32, y as f32]));
    let tmp = tempfile::tempdir().unwrap();
    let none = EvalOptions::default();

    let e = err(&tmp.path().join("missing"), &none);
    assert!(e.contains("missing") && e.contains("cannot open"), "{e}");
    let file = tmp.path().join("file");
    std::fs::write(&file, b"x").unwrap();
    assert!(err(&file, &none).contains("not a directory"));

    // Only geometry: facemaps.exr is named.
    let d = tmp.path().join("d");
    std::fs::create_dir(&d).unwrap();
    write_face_maps(d.join("geometry.exr"), &geo).unwrap();
    assert!(err(&d, &none).contains("facemaps.exr"));
    // Corrupt facemaps.
    std::fs::write(d.join("facemaps.exr"), b"this is not an EXR file").unwrap();
    let e = err(&d, &none);
    assert!(e.contains("facemaps.exr") && e.contains("OpenEXR"), "{e}");
    // Truncated facemaps.
    write_face_maps(d.join("facemaps.exr"), &col).unwrap();
    let bytes = std::fs::read(d.join("facemaps.exr")).unwrap();
    std::fs::write(d.join("facemaps.exr"), &bytes[..bytes.len() / 2]).unwrap();
    assert!(err(&d, &none).contains("facemaps.exr"));
    // Resolution mismatch between the two files.
    write_face_maps(d.join("facemaps.exr"), &col).unwrap();
    write_face_maps(d.join("geometry.exr"), &geometry(&s, 5)).unwrap();
    let e = err(&d, &none);
    assert!(e.contains("geometry.exr") && e.contains("N = 5"), "{e}");
    write_face_maps(d.join("geometry.exr"), &geo).unwrap();
    // No report and no --scale while sources are present.
    let e = err(&d, &none);
    assert!(e.contains("report.json") && e.contains("--scale"), "{e}");
    // Bad reports.
    std::fs::write(d.join("report.json"), b"{ not json").unwrap();
    assert!(err(&d, &none).contains("not valid JSON"));
    std::fs::write(d.join("report.json"), b"{\"scale\": -2}").unwrap();
    assert!(err(&d, &none).contains("not a positive number"));
    std::fs::write(d.join("report.json"), b"{\"seed\": 1}").unwrap();
    assert!(err(&d, &none).contains("'scale'"));
    // A bad --scale is refused before reading anything.
    let e = err(
        &d,
        &EvalOptions {
            scale: Some(0.0),
            example: None,
        },
    );
    assert!(e.contains("scale"), "{e}");
    assert!(evaluate(&d, Some(0.1)).is_ok());
    // Missing colour channel.
    let grey = FaceMaps::new(s.num_domains(), 4, &["Y"]);
    write_face_maps(d.join("facemaps.exr"), &grey).unwrap();
    assert!(err(&d, &none).contains("'R'"));
    // Patch fidelity on a curved mesh: pfS by the surface method, no legacy measure.
    let cube = Surface::load_obj(data("opensubdiv-reference/catmark_cube.obj")).unwrap();
    let cg = geometry(&cube, 8);
    let cc = colour_maps(&cube, &cg, |_, x, _, _| {
        ([x as f32 / 8.0, 0.5, 0.5], [0.0, 0.0])
    });
    write_dir(&d, &cc, &cg, Some(1.0));
    let png = tmp.path().join("e.png");
    write_png(&png, 16, 16, |x, _| [x as u8 * 10, 0, 0]);
    let q = evaluate_with(
        &d,
        &EvalOptions {
            scale: None,
            example: Some(png),
        },
    )
    .unwrap();
    assert_eq!(q.patch_fidelity, None);
    assert!(q.pf1.is_some(), "{q:?}");
    assert_eq!(
        q.pf_detail.as_ref().unwrap().method,
        surfsynth::eval::PfMethod::Surface
    );
    let e = err(
        &d,
        &EvalOptions {
            scale: None,
            example: Some(tmp.path().join("nope.png")),
        },
    );
    assert!(e.contains("nope.png"), "{e}");
}

#[test]
fn command_line_prints_json_or_one_error_line() {
    let exe = env!("CARGO_BIN_EXE_surfsynth");
    let s = grid_surface(2);
    let geo = geometry(&s, 4);
    let col = colour_maps(&s, &geo, |_, x, y, _| ([0.5; 3], [x as f32, y as f32]));
    let tmp = tempfile::tempdir().unwrap();
    write_dir(tmp.path(), &col, &geo, Some(0.25));
    let out = std::process::Command::new(exe)
        .args(["eval", tmp.path().to_str().unwrap(), "--scale", "0.25"])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let q: Quality = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(q.coverage, 1.0);
    assert_eq!(q.scale, Some(0.25));
    // Constant colour: both means are 0, which counts as seamless.
    assert_eq!(q.seam_ratio, Some(1.0));

    let missing = tmp.path().join("nothing-here");
    let out = std::process::Command::new(exe)
        .args(["eval", missing.to_str().unwrap()])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(1));
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(err.trim_end().lines().count(), 1, "{err}");
    assert!(
        err.starts_with("error: ") && err.contains("nothing-here"),
        "{err}"
    );
    assert!(out.stdout.is_empty());
}
