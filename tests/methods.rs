//! Every synthesis method against BRIEF's quality measures (issue 13): structure (patch
//! fidelity pf4/pf8) on the flat grid against the peer's figures, and coverage, seams and
//! stretch on curved meshes with quads, triangles (n-gon sub-faces), open boundaries and
//! genus 2; bit-identical results for any thread count.
//!
//! The peer (Embark texture-synthesis 0.8.2, default settings, 512² output) cannot run in
//! CI: its figures were measured with `bench/peer.sh` on the same crops (the lowest of
//! three seeds, so the bound is the peer at its best) and are written down below. Ours
//! are measured in the test, on BRIEF's flat 16x16 grid at N = 32 with `--orient +x`.

mod common;

use common::data;
use surfsynth::example::Example;
use surfsynth::field::Orientation;
use surfsynth::synthesizer::{Method, SynthResult, Synthesizer};

/// A structured example from the shared data, cropped as `bench/peer.sh` crops it.
struct Structured {
    name: &'static str,
    file: &'static str,
    /// Top-left corner and side of the square crop (`None`: the whole image).
    crop: Option<(usize, usize, usize)>,
    /// The peer's pf4 and pf8 on its 512² output of this example (best of seeds 1–3).
    peer_pf4: f64,
    peer_pf8: f64,
}

const STRUCTURED: [Structured; 3] = [
    Structured {
        name: "bricks",
        file: "textures/skimage_brick.png",
        crop: Some((128, 128, 256)),
        peer_pf4: 0.035,
        peer_pf8: 0.093,
    },
    Structured {
        name: "reptile scales",
        file: "textures/krita_reptile_scales.png",
        crop: Some((128, 128, 256)),
        peer_pf4: 0.074,
        peer_pf8: 0.240,
    },
    Structured {
        name: "gravel",
        file: "textures/etr_gravel.png",
        crop: None,
        peer_pf4: 0.156,
        peer_pf8: 0.269,
    },
];

fn load(s: &Structured) -> Example {
    let ex = Example::load(data(s.file)).unwrap();
    let Some((x0, y0, side)) = s.crop else {
        return ex;
    };
    let rgb = (0..side * side)
        .map(|i| ex.rgb[(y0 + i / side) * ex.width + x0 + i % side])
        .collect();
    Example::from_linear(side, side, rgb)
}

struct Measured {
    pf4: f64,
    pf8: f64,
    q: surfsynth::eval::Quality,
}

fn measure(r: &SynthResult) -> Measured {
    let geometry = r.geometry_maps();
    let q = surfsynth::eval::evaluate_maps(&r.maps, &geometry, Some(r.report.scale), None).unwrap();
    let pf =
        surfsynth::eval::patch_fidelities(&r.maps, &geometry, &r.example, Some(r.report.scale));
    Measured {
        pf4: pf.pf4.unwrap(),
        pf8: pf.pf8.unwrap(),
        q,
    }
}

/// BRIEF's stretch bar as the project holds it: scale fidelity median within 1 ± 0.03 and
/// p10–p90 inside `spread` — [0.9, 1.1] (issue 13) for every method but coherent
/// synthesis, [0.85, 1.15] for that one, whose sources are only pieced together into
/// continuations (docs/synthesis.md).
fn unstretched(q: &surfsynth::eval::Quality, spread: (f64, f64)) -> bool {
    let s = q.scale_fidelity.unwrap();
    (s.median - 1.0).abs() <= 0.03 && s.p10 >= spread.0 && s.p90 <= spread.1
}

fn spread_of(method: Method) -> (f64, f64) {
    match method {
        Method::Coherent => (0.85, 1.15),
        _ => (0.9, 1.1),
    }
}

/// Issue 13's seam bar (≤ 1.10) for the methods that copy whole patches. The per-texel
/// methods are regression-guarded only: coherent at the older bar of tests/synth.rs
/// (≤ 1.2), multiscale at what it measures — 0.76–1.33 over seeds 1–3 on the open cube
/// at N = 32, its cuts at face borders matching worse than inside faces (docs/synthesis.md,
/// known limits) — and jump maps at what they measure with these scales at seed 2 since
/// their texels grow by geodesic distance: 1.09 (Spot), 0.95 (double torus), 1.23 (open
/// cube), 1.27 (triangulated Spot) — 1.14, 1.26, 1.66 and 1.28 when the growth filled one
/// face after another; nothing matches across the lines where growth fronts meet
/// (docs/jump.md, "Growth order").
fn seam_bar(method: Method) -> f64 {
    match method {
        Method::Coherent => 1.2,
        Method::Multiscale => 1.35,
        Method::Jump => 1.35,
        _ => 1.10,
    }
}

fn assert_unstretched(what: &str, q: &surfsynth::eval::Quality) {
    assert!(
        unstretched(q, (0.9, 1.1)),
        "{what}: scale fidelity {:?}",
        q.scale_fidelity
    );
}

/// The acceptance of issue 13 on the flat grid, for the methods made to keep structure:
/// pf4 ≤ the peer's and pf8 ≤ 0.9x the peer's on every structured example, with no
/// stretch and full coverage. (Measured, seed 1: patches pf8 0.024 / 0.12 / 0.19,
/// optimise 0.023 / 0.10 / 0.13 for bricks / scales / gravel.)
#[test]
fn structure_methods_beat_the_peer_on_the_flat_grid() {
    for s in &STRUCTURED {
        let ex = load(s);
        for method in [Method::Patches, Method::Optimise] {
            let r = Synthesizer::new(
                subdiv::Surface::new(subdiv::ControlMesh::grid(16)),
                ex.clone(),
            )
            .method(method)
            .resolution(32)
            .orientation(Orientation::Axis(glam::DVec3::X))
            .seed(1)
            .analyses(common::analyses())
            .run()
            .unwrap();
            let m = measure(&r);
            let what = format!(
                "{} on the flat grid, {}: pf4 {:.3} (peer {:.3}), pf8 {:.3} (peer {:.3})",
                method.name(),
                s.name,
                m.pf4,
                s.peer_pf4,
                m.pf8,
                s.peer_pf8
            );
            println!("{what}");
            assert_eq!(m.q.coverage, 1.0, "{what}");
            assert!(m.pf4 <= s.peer_pf4, "{what}");
            assert!(m.pf8 <= 0.9 * s.peer_pf8, "{what}");
            assert_unstretched(&what, &m.q);
            // Copies sit on the example's pixel centres: exact pixels, not blends of
            // neighbours (`synth::matching::pixel_grid`; 0.41–0.55 before it).
            let on = on_pixel_centres(&r);
            assert!(on >= 0.98, "{what}: {on:.3} of the texels on pixel centres");
        }
    }
}

/// Share of texels whose source position is an example pixel's centre (within 0.01 px).
fn on_pixel_centres(r: &SynthResult) -> f64 {
    let (u, v) = (
        r.maps.channel("source.u").unwrap(),
        r.maps.channel("source.v").unwrap(),
    );
    let centred = |x: f32| (x - 0.5 - (x - 0.5).round()).abs() <= 0.01;
    let n = u
        .iter()
        .zip(v)
        .filter(|(a, b)| centred(**a) && centred(**b))
        .count();
    n as f64 / u.len() as f64
}

/// Every method on curved meshes of every kind the reader takes: coverage 1, seam ratio
/// ([`seam_bar`]), no stretch ([`spread_of`]). Resolutions are kept small for CI; the structure
/// methods are also held to a pf8 bound there (reptile scales: the peer's flat pf8 x 1.1,
/// the acceptance of issue 13, on Spot and the double torus).
#[test]
fn every_method_meets_the_bar_on_curved_meshes() {
    let scales = load(&STRUCTURED[1]);
    let mut failures = Vec::new();
    let cases: [(&str, usize); 4] = [
        ("meshes/spot_control_mesh.obj", 16),
        ("meshes/double_torus_genus2.obj", 16),
        // Five domains: at N = 16 a few hundred seam pairs, too few for a stable ratio.
        ("meshes/cube_no_bottom.obj", 32),
        // 17,568 triangle sub-faces; at N = 4 every texel is a border texel.
        ("meshes/spot_triangulated.obj", 8),
    ];
    for (mesh, n) in cases {
        for method in Method::ALL {
            if method == Method::Multiscale && n < 16 {
                continue; // multiscale needs a few levels of maps (docs/multiscale.md)
            }
            let r = Synthesizer::new(data(mesh), scales.clone())
                .method(method)
                .resolution(n)
                .seed(2)
                .analyses(common::analyses())
                .run()
                .unwrap();
            let m = measure(&r);
            let what = format!(
                "{} on {mesh} N={n}: coverage {}, seam {:?}, pf4 {:.3}, pf8 {:.3}",
                method.name(),
                m.q.coverage,
                m.q.seam_ratio,
                m.pf4,
                m.pf8
            );
            println!("{what}: scale fidelity {:?}", m.q.scale_fidelity);
            if m.q.coverage != 1.0
                || m.q.seam_ratio.unwrap() > seam_bar(method)
                || !unstretched(&m.q, spread_of(method))
            {
                failures.push(format!("{what}: scale fidelity {:?}", m.q.scale_fidelity));
            }
        }
    }
    // Structure on curved surfaces at the acceptance's resolution.
    for mesh in [
        "meshes/spot_control_mesh.obj",
        "meshes/double_torus_genus2.obj",
    ] {
        let r = Synthesizer::new(data(mesh), scales.clone())
            .method(Method::DEFAULT)
            .resolution(32)
            .seed(1)
            .analyses(common::analyses())
            .run()
            .unwrap();
        let m = measure(&r);
        let bound = 1.1 * STRUCTURED[1].peer_pf8;
        println!(
            "default on {mesh} N=32: pf8 {:.3} (bound {bound:.3})",
            m.pf8
        );
        if m.pf8 > bound {
            failures.push(format!("default on {mesh}: pf8 {:.3} > {bound:.3}", m.pf8));
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

/// Multiscale with a brick example on a curved mesh, where a brick's face looks alike
/// everywhere: without the finest level's coherent choice its randomised choice put
/// neighbouring texels' sources 2–4 pixels apart, which BRIEF reads as stretch (Spot,
/// N = 16, seed 2: p10–p90 0.97–2.81; with it 0.96–1.06; docs/multiscale.md, "Coherent
/// choice").
#[test]
fn multiscale_keeps_bricks_unstretched_on_a_curved_mesh() {
    let r = Synthesizer::new(data("meshes/spot_control_mesh.obj"), load(&STRUCTURED[0]))
        .method(Method::Multiscale)
        .resolution(16)
        .seed(2)
        .analyses(common::analyses())
        .run()
        .unwrap();
    let m = measure(&r);
    let what = format!(
        "multiscale bricks on Spot N=16: seam {:?}, pf8 {:.3}, scale fidelity {:?}",
        m.q.seam_ratio, m.pf8, m.q.scale_fidelity
    );
    println!("{what}");
    assert_eq!(m.q.coverage, 1.0, "{what}");
    assert!(
        m.q.seam_ratio.unwrap() <= seam_bar(Method::Multiscale),
        "{what}"
    );
    assert!(unstretched(&m.q, (0.9, 1.1)), "{what}");
}

/// The structure methods give bit-identical maps for 1 and 2 threads.
#[test]
fn structure_methods_do_not_depend_on_the_thread_count() {
    let ex = load(&STRUCTURED[0]);
    for method in [Method::Patches, Method::Optimise] {
        let run = |threads: usize| {
            Synthesizer::new(data("meshes/spot_control_mesh.obj"), ex.clone())
                .method(method)
                .resolution(12)
                .seed(4)
                .threads(threads)
                .analyses(common::analyses())
                .run()
                .unwrap()
                .maps
        };
        let (a, b) = (run(1), run(2));
        for ((na, da), (nb, db)) in a.channels.iter().zip(&b.channels) {
            assert_eq!(na, nb);
            assert!(
                da.iter().zip(db).all(|(x, y)| x.to_bits() == y.to_bits()),
                "{}: channel {na} differs between 1 and 2 threads",
                method.name()
            );
        }
    }
}

/// Share of `r`'s texels whose source lies on the example's *short* joints: pixels
/// brighter than its 85th percentile of luminance (the mortar of the brick crop) on runs
/// of at least 11 pixels along one axis, the axis whose runs cover less (the head joints
/// between the bricks of a course; the long runs are the courses' bed joints). Returns
/// (example share, result share).
fn short_joint_share(ex: &Example, r: &SynthResult) -> (f64, f64) {
    let (w, h) = (ex.width, ex.height);
    let lum: Vec<f32> = ex.rgb.iter().map(|p| (p[0] + p[1] + p[2]) / 3.0).collect();
    let mut sorted = lum.clone();
    sorted.sort_by(f32::total_cmp);
    let cut = sorted[sorted.len() * 85 / 100];
    let bright = |x: isize, y: isize| {
        lum[y.rem_euclid(h as isize) as usize * w + x.rem_euclid(w as isize) as usize] > cut
    };
    // On a run of 11 bright pixels centred on (x, y) along x (runs_x) or y.
    let run = |dx: isize, dy: isize| -> Vec<bool> {
        (0..w * h)
            .map(|i| {
                let (x, y) = ((i % w) as isize, (i / w) as isize);
                (-5..=5).all(|k| bright(x + k * dx, y + k * dy))
            })
            .collect()
    };
    let (along_x, along_y) = (run(1, 0), run(0, 1));
    let share = |m: &[bool]| m.iter().filter(|&&b| b).count() as f64 / m.len() as f64;
    let short: Vec<bool> = if share(&along_x) < share(&along_y) {
        along_x
            .iter()
            .zip(&along_y)
            .map(|(&a, &b)| a && !b)
            .collect()
    } else {
        along_y
            .iter()
            .zip(&along_x)
            .map(|(&a, &b)| a && !b)
            .collect()
    };
    let (u, v) = (
        r.maps.channel("source.u").unwrap(),
        r.maps.channel("source.v").unwrap(),
    );
    let on = u
        .iter()
        .zip(v)
        .filter(|(u, v)| {
            let (x, y) = ((**u as usize).min(w - 1), (**v as usize).min(h - 1));
            short[y * w + x]
        })
        .count();
    (share(&short), on as f64 / u.len() as f64)
}

/// `--feature-distance` (issue 13 item 2's optional channel): on a curved mesh, texture
/// optimisation drops most of the bricks' head joints without it (bricks three times as
/// long as the example's) and keeps more of them with it; on the flat grid it still
/// meets the acceptance against the peer. (Measured, Spot N = 32, seed 1: short-joint
/// share 0.010 → 0.021, the example 0.029; docs/synthesis.md, "Feature distance".)
#[test]
fn feature_distance_keeps_head_joints() {
    let s = &STRUCTURED[0];
    let ex = load(s);
    let run = |mesh: Synthesizer, fd: f32| {
        mesh.method(Method::Optimise)
            .resolution(32)
            .seed(1)
            .feature_distance(fd)
            .analyses(common::analyses())
            .run()
            .unwrap()
    };
    let spot = || Synthesizer::new(data("meshes/spot_control_mesh.obj"), ex.clone());
    let (example, without) = short_joint_share(&ex, &run(spot(), 0.0));
    let (_, with) = short_joint_share(&ex, &run(spot(), 0.5));
    println!("short joints: example {example:.4}, Spot without {without:.4}, with {with:.4}");
    assert!(with >= 1.5 * without, "{with} vs {without}");
    assert!(with >= 0.5 * example, "{with} vs the example's {example}");
    let grid = Synthesizer::new(
        subdiv::Surface::new(subdiv::ControlMesh::grid(16)),
        ex.clone(),
    )
    .orientation(Orientation::Axis(glam::DVec3::X));
    let r = run(grid, 0.5);
    let m = measure(&r);
    let what = format!(
        "flat grid with the feature distance: pf4 {:.3}, pf8 {:.3}",
        m.pf4, m.pf8
    );
    println!("{what}");
    assert_eq!(r.report.appearance.feature_distance, 0.5);
    assert!(m.pf4 <= s.peer_pf4 && m.pf8 <= 0.9 * s.peer_pf8, "{what}");
}

/// A bumpy terrain lying level: 16 x 16 quads over 8 x 8 units, heights within ±0.55, no
/// slope steeper than ~25°.
fn terrain() -> subdiv::Surface {
    let n = 16;
    let mut p = Vec::new();
    for j in 0..=n {
        for i in 0..=n {
            let (x, z) = (i as f64 * 8.0 / n as f64, j as f64 * 8.0 / n as f64);
            let y = 0.35 * (0.9 * x).sin() * (0.7 * z).cos() + 0.2 * (0.4 * x + 1.1 * z).sin();
            p.push(glam::DVec3::new(x, y, z));
        }
    }
    let mut faces = Vec::new();
    for j in 0..n {
        for i in 0..n {
            let a = (j * (n + 1) + i) as u32;
            let k = n as u32;
            faces.push(vec![a, a + k + 1, a + k + 2, a + 1]);
        }
    }
    let faces: Vec<&[u32]> = faces.iter().map(|f| f.as_slice()).collect();
    subdiv::Surface::new(subdiv::ControlMesh::from_faces(p, &faces).unwrap())
}

/// The default orientation of texture optimisation (`upright`) on level ground: `up` would
/// draw the bricks in contour rings around every hilltop (the projected up points uphill),
/// so the default lays the example flat (the smooth field) and keeps the courses straight.
/// (Measured at N = 32, seed 1: pf8 0.108 with `up`, 0.037 by default; docs/field.md.)
#[test]
fn the_default_lays_bricks_flat_on_level_ground() {
    let s = &STRUCTURED[0];
    let ex = load(s);
    let run = |o: Option<Orientation>| {
        let mut r = Synthesizer::new(terrain(), ex.clone())
            .resolution(16)
            .seed(1)
            .analyses(common::analyses());
        if let Some(o) = o {
            r = r.orientation(o);
        }
        r.run().unwrap()
    };
    let default = run(None);
    let up = run(Some(Orientation::Up(glam::DVec3::Y)));
    let chosen = default.report.orientation_choice.as_ref().unwrap();
    assert_eq!(chosen.chosen, "auto", "{chosen:?}");
    assert!(chosen.level_fraction.unwrap() > 0.99, "{chosen:?}");
    let (md, mu) = (measure(&default), measure(&up));
    let what = format!(
        "terrain, bricks: pf8 {:.3} by default, {:.3} with up (peer's flat {:.3})",
        md.pf8, mu.pf8, s.peer_pf8
    );
    println!("{what}");
    assert!(md.pf8 <= 0.6 * mu.pf8, "{what}");
    assert!(md.pf8 <= 1.1 * s.peer_pf8, "{what}");
    assert_eq!(md.q.coverage, 1.0, "{what}");
    assert_unstretched(&what, &md.q);
}

/// Texture optimisation's progress covers its final assembly too (per wave of patches),
/// not only the EM iterations: on a big mesh the assembly runs for seconds after the last
/// iteration. The synthesis stage's counts only grow, end at the total, and take more
/// distinct values than the iterations alone could give (Spot at N = 8: 3 levels x 2 patch
/// sizes x 3 iterations = 18).
#[test]
fn optimise_progress_reaches_the_end_through_the_final_assembly() {
    use std::sync::{Arc, Mutex};
    use surfsynth::synthesizer::Stage;
    let seen = Arc::new(Mutex::new(Vec::new()));
    let log = seen.clone();
    Synthesizer::new(
        data("meshes/spot_control_mesh.obj"),
        data("textures/etr_gravel.png"),
    )
    .method(Method::Optimise)
    .resolution(8)
    .on_progress(move |s, d, t| {
        if s == Stage::Synthesis {
            log.lock().unwrap().push((d, t));
        }
    })
    .run()
    .unwrap();
    let seen = seen.lock().unwrap();
    let total = seen.last().unwrap().1;
    assert!(seen.windows(2).all(|w| w[0].0 <= w[1].0), "{seen:?}");
    assert_eq!(seen.last().unwrap().0, total, "{seen:?}");
    let mut distinct: Vec<usize> = seen.iter().map(|p| p.0).collect();
    distinct.dedup();
    assert!(
        distinct.len() > 18 + 2,
        "{} distinct: {distinct:?}",
        distinct.len()
    );
}
