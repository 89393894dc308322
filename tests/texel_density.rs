//! Uniform texel density (issue 16 item 1): `--texel-size L` gives every face its own
//! power-of-two resolution. Checks: the spacing spread (95th / 5th percentile of the
//! per-face median spacing) ≤ 2 on Spot, the bunny, a mesh with n-gons and one with
//! boundaries, where one N gives up to 4.4x; synthesis across faces of different
//! resolution (seams between them, pfS and scale fidelity against uniform N); files that
//! read back with their per-face resolutions (and a surface.glb the glTF validator passes); the same files for any thread count; and
//! absurd texel sizes refused in one line with nothing written.

mod common;

use common::data;
use std::path::Path;
use std::process::Command;
use std::sync::Arc;
use subdiv::Surface;
use surfsynth::layout::TexelLayout;
use surfsynth::synthesizer::{Method, SynthResult, Synthesizer};
use surfsynth::texels::TexelGeometry;

/// The median adjacent spacing at one resolution N (what `--texel-size` is compared with).
fn spacing_at(s: &Surface, n: usize) -> f64 {
    TexelGeometry::compute(s, n).median_spacing(s)
}

/// 95th / 5th percentile of the per-face median spacing (the eval measure, on geometry
/// alone).
fn spread(g: &TexelGeometry) -> f64 {
    let maps = surfsynth::synth::geometry_maps(g);
    let mut colour = surfsynth::io::exr::FaceMaps::with_layout(g.layout.clone(), &["R", "G", "B"]);
    for (_, d) in colour.channels.iter_mut() {
        for (i, v) in d.iter_mut().enumerate() {
            *v = (i % 7) as f32 / 7.0;
        }
    }
    surfsynth::eval::evaluate_maps(&colour, &maps, None, None)
        .unwrap()
        .spacing_spread
        .unwrap()
}

#[test]
fn texel_size_keeps_the_spacing_spread_within_2x() {
    for (mesh, n) in [
        ("meshes/spot_control_mesh.obj", 16),
        ("meshes/stanford_bunny.obj", 4),
        ("meshes/double_torus_genus2.obj", 16),
        ("meshes/cube_no_bottom.obj", 16),
    ] {
        let s = Surface::load_obj(data(mesh)).unwrap();
        let uniform = spread(&TexelGeometry::compute(&s, n));
        let l = spacing_at(&s, n);
        let layout = Arc::new(TexelLayout::for_texel_size(&s, l));
        let g = TexelGeometry::compute_layout(&s, layout.clone());
        let sp = spread(&g);
        let sides: Vec<(usize, usize)> = (0..layout.faces()).map(|d| layout.dims(d)).collect();
        let distinct = {
            let mut v = sides.clone();
            v.sort_unstable();
            v.dedup();
            v.len()
        };
        eprintln!(
            "{mesh}: N = {n} spread {uniform:.3}; texel size {l:.5}: spread {sp:.3}, {} texels (uniform {}), {distinct} distinct resolutions",
            layout.len(),
            s.num_domains() * n * n
        );
        assert!(sp <= 2.0, "{mesh}: spread {sp}");
        // The median spacing stays the asked-for one (within the rounding's √2).
        let h = g.median_spacing(&s);
        assert!(
            h > l / 2f64.sqrt() && h < l * 2f64.sqrt(),
            "{mesh}: h {h} for {l}"
        );
    }
}

fn run(mesh: &Path, method: Method, texel_size: Option<f64>, n: usize) -> SynthResult {
    Synthesizer::new(mesh, data("textures/etr_gravel.png"))
        .method(method)
        .resolution(n)
        .texel_size(texel_size)
        .seed(3)
        .analyses(common::analyses())
        .run()
        .unwrap()
}

fn quality(r: &SynthResult) -> surfsynth::eval::Quality {
    surfsynth::eval::evaluate_maps(
        &r.maps,
        &r.geometry_maps(),
        Some(r.report.scale),
        Some(&r.example),
    )
    .unwrap()
}

/// Coherent synthesis, texture optimisation (the default), multiscale synthesis and
/// textons (multiscale's machinery on a texton pyramid; here the example as a one-image
/// sample) on Spot (triangles, pentagons, valence 3 and 5) with per-face resolutions:
/// spacing spread ≤ 2, seams between faces of different resolution no worse than 1.10 of
/// the inside, and pf4 and scale fidelity no worse than at one N of about the same texel
/// count.
#[test]
fn methods_run_across_faces_of_different_resolution() {
    let mesh = data("meshes/spot_control_mesh.obj");
    let s = Surface::load_obj(&mesh).unwrap();
    let n = 16;
    let l = spacing_at(&s, n);
    for method in [
        Method::Coherent,
        Method::Optimise,
        Method::Multiscale,
        Method::Textons,
    ] {
        let u = quality(&run(&mesh, method, None, n));
        let r = run(&mesh, method, Some(l), n);
        let q = quality(&r);
        let (su, sq) = (u.scale_fidelity.unwrap(), q.scale_fidelity.unwrap());
        eprintln!(
            "{method:?}: uniform N = {n}: spread {:.3} seam {:.3} pf1 {:.3} pf4 {:.3} scale p10-p90 {:.3}-{:.3}; texel size: spread {:.3} seam {:.3} mixed {:.3} ({} pairs) pf1 {:.3} pf4 {:.3} scale p10-p90 {:.3}-{:.3}",
            u.spacing_spread.unwrap(),
            u.seam_ratio.unwrap(),
            u.pf1.unwrap(),
            u.pf4.unwrap(),
            su.p10,
            su.p90,
            q.spacing_spread.unwrap(),
            q.seam_ratio.unwrap(),
            q.seam_ratio_mixed.unwrap(),
            q.seam_pairs_mixed,
            q.pf1.unwrap(),
            q.pf4.unwrap(),
            sq.p10,
            sq.p90,
        );
        assert_eq!(q.coverage, 1.0);
        assert!(q.spacing_spread.unwrap() <= 2.0);
        assert!(
            q.seam_pairs_mixed > 1000,
            "faces of different resolution meet"
        );
        assert!(q.seam_ratio_mixed.unwrap() <= 1.10);
        assert!(q.pf4.unwrap() <= u.pf4.unwrap() * 1.05);
        assert!(q.pf1.unwrap() <= u.pf1.unwrap() * 1.05);
        // Scale fidelity: the p10-p90 band no wider than at one N (+0.02).
        assert!(sq.p90 - sq.p10 <= su.p90 - su.p10 + 0.02);
        assert!((sq.median - 1.0).abs() <= 0.05);
    }
}

/// Multiscale synthesis and textons across faces of different resolution over more seeds
/// than the test above (seed 3): the seam bar holds for each, not on average. Measured
/// (docs/multiscale.md, "Seams across a resolution step"), seeds 1, 2, 3, 4: multiscale
/// mixed 0.965, 0.958, 1.064, 1.052; textons 1.024, 1.046, 1.045, 0.924. One more seed
/// here (two Spot runs of 98k texels): CI's 20 minutes on two cores are the limit.
#[test]
fn seams_across_resolution_steps_hold_over_seeds() {
    let mesh = data("meshes/spot_control_mesh.obj");
    let s = Surface::load_obj(&mesh).unwrap();
    let l = spacing_at(&s, 16);
    let seed = 1;
    for method in [Method::Multiscale, Method::Textons] {
        let r = Synthesizer::new(&mesh, data("textures/etr_gravel.png"))
            .method(method)
            .texel_size(l)
            .seed(seed)
            .analyses(common::analyses())
            .run()
            .unwrap();
        let q = quality(&r);
        let mixed = q.seam_ratio_mixed.unwrap();
        eprintln!(
            "{method:?} seed {seed}: seam {:.3} mixed {mixed:.3} ({} pairs)",
            q.seam_ratio.unwrap(),
            q.seam_pairs_mixed
        );
        assert!(mixed <= 1.10, "{method:?} seed {seed}: mixed {mixed}");
    }
}

/// Seam ratio of a texture with no seams at all — a colour that is a function of the limit
/// position (sums of 3D sinusoids, wavelengths 1.5–24 texel spacings) — on a layout: what
/// the seam measure gives a layout before any synthesis. Seam pairs sit at other distances
/// than the pairs inside faces, and at a resolution step the coarse side's half spacing
/// adds to the fine side's, so this is not 1 (docs/multiscale.md, "Seams across a
/// resolution step").
fn seamless_seam_ratios(s: &Surface, layout: Arc<TexelLayout>) -> (f64, Option<f64>) {
    let g = TexelGeometry::compute_layout(s, layout.clone());
    let h = g.median_spacing(s) as f32;
    let maps = surfsynth::synth::geometry_maps(&g);
    let mut colour = surfsynth::io::exr::FaceMaps::with_layout(layout, &["R", "G", "B"]);
    // Fixed directions, phases and wavelengths (a golden-angle spiral of directions).
    let waves: Vec<(glam::Vec3, f32, f32)> = (0..24)
        .map(|k| {
            let z = 1.0 - 2.0 * (k as f32 + 0.5) / 24.0;
            let a = k as f32 * 2.399_963;
            let r = (1.0 - z * z).sqrt();
            let lambda = h * 1.5 * 16f32.powf(k as f32 / 23.0);
            (
                glam::Vec3::new(r * a.cos(), r * a.sin(), z),
                lambda,
                k as f32 * 0.7,
            )
        })
        .collect();
    for (c, (_, d)) in colour.channels.iter_mut().enumerate() {
        for (v, p) in d.iter_mut().zip(&g.pos) {
            *v = waves
                .iter()
                .map(|(dir, lambda, phase)| {
                    let arg = dir.dot(*p) * std::f32::consts::TAU / lambda;
                    lambda * (arg + phase + c as f32).sin()
                })
                .sum();
        }
    }
    let q = surfsynth::eval::evaluate_maps(&colour, &maps, None, None).unwrap();
    (q.seam_ratio.unwrap(), q.seam_ratio_mixed)
}

/// The seam measure's floor on the layouts the seam bar is judged on: a seamless texture
/// must come out near 1 across faces of different resolution on Spot (else the bar of
/// 1.10 would measure the layout, not the synthesis; measured 0.948, and 0.658 at N = 16).
/// Printed for the double torus too, where the floor is higher (mixed 1.154 at L = h₁₆;
/// its seam pairs are 1.16x farther apart, in mean square, than its pairs inside faces):
/// there the bar of 1.10 is below what a texture without seams scores.
#[test]
fn a_seamless_texture_shows_the_seam_floor_of_the_layouts() {
    for (mesh, n, bound) in [
        ("meshes/spot_control_mesh.obj", 16, Some(1.05)),
        ("meshes/double_torus_genus2.obj", 16, None),
    ] {
        let s = Surface::load_obj(data(mesh)).unwrap();
        let l = spacing_at(&s, n);
        let (uniform, _) =
            seamless_seam_ratios(&s, Arc::new(TexelLayout::uniform(s.num_domains(), n)));
        let (all, mixed) = seamless_seam_ratios(&s, Arc::new(TexelLayout::for_texel_size(&s, l)));
        let mixed = mixed.unwrap();
        eprintln!(
            "{mesh}: seamless texture: N = {n} seam {uniform:.3}; texel size {l:.5}: seam {all:.3}, mixed {mixed:.3}"
        );
        if let Some(b) = bound {
            assert!(mixed <= b, "{mesh}: mixed {mixed}");
        }
    }
}

#[test]
fn files_carry_the_per_face_resolutions_and_do_not_depend_on_threads() {
    let mesh = data("meshes/cube_no_bottom.obj");
    let s = Surface::load_obj(&mesh).unwrap();
    let l = spacing_at(&s, 8);
    let dir = tempfile::tempdir().unwrap();
    let mut bytes = Vec::new();
    for threads in [1, 2] {
        let out = dir.path().join(format!("t{threads}"));
        Synthesizer::new(&mesh, data("textures/etr_gravel.png"))
            .method(Method::Patches)
            .texel_size(l)
            .threads(threads)
            .run_to(&out)
            .unwrap();
        let files: Vec<Vec<u8>> = ["facemaps.exr", "geometry.exr", "facemaps.ptx", "atlas.png"]
            .iter()
            .map(|f| std::fs::read(out.join(f)).unwrap())
            .collect();
        bytes.push(files);
    }
    assert!(
        bytes[0] == bytes[1],
        "1 and 2 threads wrote different files"
    );
    let out = dir.path().join("t1");
    let maps = surfsynth::io::exr::read_face_maps(out.join("facemaps.exr")).unwrap();
    let want = TexelLayout::for_texel_size(&s, l);
    assert_eq!(*maps.layout, want);
    assert!(want.uniform_n().is_none());
    let geo = surfsynth::io::exr::read_face_maps(out.join("geometry.exr")).unwrap();
    assert_eq!(geo.layout, maps.layout);
    // geometry.exr holds every face's texel centres at their own resolution.
    let g = TexelGeometry::compute_layout(&s, Arc::new(want));
    let px = geo.channel("P.X").unwrap();
    for (t, p) in g.pos.iter().enumerate() {
        assert!((px[t] - p.x).abs() < 1e-6, "texel {t}");
    }
    let info = surfsynth::io::exr::read_face_maps_info(out.join("facemaps.exr")).unwrap();
    assert_eq!(info.resolution, None);
    // eval reads the result directory.
    let q = surfsynth::eval::evaluate(&out, None).unwrap();
    assert!(q.spacing_spread.unwrap() <= 2.0);
    // The shelf-packed atlas as glTF: the Khronos validator finds nothing (where node runs).
    common::gltf_validator::assert_clean(&out.join("surface.glb"));
    // render reads it too.
    let o = Command::new(env!("CARGO_BIN_EXE_surfsynth"))
        .args(["render"])
        .arg(&out)
        .args(["--width", "64", "--height", "48", "--out"])
        .arg(dir.path().join("p.png"))
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}

/// Multiscale synthesis and textons on per-face resolutions (a mesh with open boundaries,
/// a small example): the same maps for 1 and 2 threads, two levels or more, the finest of
/// them the output's own layout (nothing resampled), every texel covered.
#[test]
fn multiscale_and_textons_on_per_face_resolutions_do_not_depend_on_threads() {
    let mesh = data("meshes/cube_no_bottom.obj");
    let s = Surface::load_obj(&mesh).unwrap();
    let l = spacing_at(&s, 8);
    let g = surfsynth::example::Example::load(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/gravel.png"),
    )
    .unwrap();
    let (side, x0, y0) = (48, (g.width - 48) / 2, (g.height - 48) / 2);
    let rgb = (0..side * side)
        .map(|i| g.rgb[(y0 + i / side) * g.width + x0 + i % side])
        .collect();
    let example = surfsynth::example::Example::from_linear(side, side, rgb);
    for method in [Method::Multiscale, Method::Textons] {
        let runs: Vec<SynthResult> = [1, 2]
            .into_iter()
            .map(|threads| {
                Synthesizer::new(&mesh, example.clone())
                    .method(method)
                    .texel_size(l)
                    .threads(threads)
                    .seed(7)
                    .run()
                    .unwrap()
            })
            .collect();
        let bits = |r: &SynthResult| -> Vec<u32> {
            r.maps
                .channels
                .iter()
                .flat_map(|(_, d)| d.iter().map(|v| v.to_bits()))
                .collect()
        };
        assert!(runs[0].maps.layout.uniform_n().is_none());
        assert!(
            bits(&runs[0]) == bits(&runs[1]),
            "{method:?}: 1 and 2 threads differ"
        );
        let report = serde_json::to_value(&runs[0].report).unwrap();
        let stats = match method {
            Method::Textons => &report["textons"]["stats"]["synthesis"],
            _ => &report["multiscale"],
        };
        assert!(stats["levels"].as_array().unwrap().len() >= 2, "{stats}");
        assert_eq!(stats["resampled"], 0, "{stats}");
        // (Seams are measured on Spot above: here only 252 texel pairs join faces of
        // different resolution, too few for a stable ratio.)
        let q = quality(&runs[0]);
        assert_eq!(q.coverage, 1.0);
        assert!(q.seam_pairs_mixed > 0, "faces of different resolution meet");
    }
}

#[test]
fn absurd_texel_sizes_are_refused_in_one_line_with_nothing_written() {
    let dir = tempfile::tempdir().unwrap();
    let mesh = data("meshes/spot_control_mesh.obj");
    for (l, want) in [
        ("0", "greater than 0"),
        ("-0.01", "greater than 0"),
        ("nan", "greater than 0"),
        ("1e-7", "memory"),
    ] {
        let out = dir.path().join(format!("out{l}"));
        let o = Command::new(env!("CARGO_BIN_EXE_surfsynth"))
            .args(["synth", "--mesh"])
            .arg(&mesh)
            .arg("--example")
            .arg(data("textures/etr_gravel.png"))
            .args(["--texel-size", l, "--out"])
            .arg(&out)
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success(), "{l}");
        assert_eq!(err.trim_end().lines().count(), 1, "{l}: {err}");
        assert!(err.contains(want), "{l}: {err}");
        assert!(!out.exists(), "{l}: --out was created");
    }
}
