//! Neighbourhood sampling (chart sampling, marching) and cross-face map fetch, measured.
//!
//! Meshes and tolerances follow issue 3: δ of 1 and 2 texel spacings at N = 32 (the local
//! spacing of the centre's domain), K = 5 and 9, random centres plus every domain corner
//! (all extraordinary vertices are domain corners).

use glam::DVec3;
use std::sync::Arc;
use subdiv::{ControlMesh, DomainId, DomainLocation, Surface};
use surfsynth::field::{Orientation, OrientationField};
use surfsynth::maps::{FaceMaps, MapLayout};
use surfsynth::sampling::{Method, Sampler, SamplerKind};

mod common;
use common::{centres, load, pos, spacing, Lcg};

/// A planar n×n grid of unit quads at z = 0.
fn grid(n: usize) -> Surface {
    Surface::new(ControlMesh::grid(n))
}

#[test]
fn flat_grid_is_reproduced_exactly_by_both_samplers() {
    let s = grid(8);
    let f = OrientationField::compute(&s, &Orientation::Axis(DVec3::new(1.0, 0.3, 0.0))).unwrap();
    let sam = Sampler::new(&s, &f);
    let mut worst: f64 = 0.0;
    let mut r = Lcg(3);
    for _ in 0..40 {
        // Centres well inside, so that 9×9 patterns at δ = 0.1 stay where the limit surface
        // is an affine image of the parameter (away from the boundary rows).
        let c = DomainLocation {
            domain: DomainId(8 * (2 + (r.next() * 4.0) as u32) + 2 + (r.next() * 4.0) as u32),
            u: r.next(),
            v: r.next(),
        };
        let fr = sam.frame(c);
        let p0 = s.eval(c.domain, c.u, c.v).p;
        for kind in [SamplerKind::Chart, SamplerKind::March] {
            for (k, delta) in [(5usize, 0.1), (9, 0.05)] {
                let mut out = vec![None; k * k];
                let info = sam.sample(c, delta, k, kind, &mut out);
                assert!(!info.fallback);
                let h = (k / 2) as i64;
                for m in -h..=h {
                    for l in -h..=h {
                        let i = ((m + h) as usize) * k + (l + h) as usize;
                        let p = pos(&s, &out[i]).expect("inside the grid");
                        let want = p0 + (fr.v1 * l as f64 + fr.v2 * m as f64) * delta;
                        worst = worst.max((p - want).length() / delta);
                    }
                }
            }
        }
    }
    println!("flat grid: worst |sample - exact| / δ = {worst:e}");
    assert!(worst <= 1e-6, "flat grid error {worst} δ");
    // The field there is the hint projected: (1, 0.3, 0) normalised.
    let want = DVec3::new(1.0, 0.3, 0.0).normalize();
    let v1 = f.frame(&s, DomainId(27), 0.4, 0.6).v1;
    assert!((v1 - want).length() < 1e-6, "{v1}");
}

/// Per-sampler worst cases over many patterns.
#[derive(Default, Debug)]
struct Stats {
    spacing: f64,
    pairs: usize,
    over5: usize,
    axes: f64,
    folds: usize,
    cells: usize,
    patterns: usize,
}

/// Largest |distance/δ − 1| over adjacent samples, |angle − 90°| between the centre's
/// pattern axes, and flipped cells ((e_l × e_m)·n ≤ 0).
fn judge(s: &Surface, out: &[Option<DomainLocation>], k: usize, delta: f64, st: &mut Stats) {
    let h = k / 2;
    let p: Vec<Option<DVec3>> = out.iter().map(|l| pos(s, l)).collect();
    st.patterns += 1;
    let (worst, pairs, over5) = spacing(&p, k, delta);
    st.spacing = st.spacing.max(worst);
    st.pairs += pairs;
    st.over5 += over5;
    for m in 0..k {
        for l in 0..k {
            let i = m * k + l;
            let Some(a) = p[i] else { continue };
            if l + 1 < k && m + 1 < k {
                if let (Some(x), Some(y)) = (p[i + 1], p[i + k]) {
                    let loc = out[i].unwrap();
                    let n = s.eval(loc.domain, loc.u, loc.v).n;
                    st.cells += 1;
                    if (x - a).cross(y - a).dot(n) <= 0.0 {
                        st.folds += 1;
                    }
                }
            }
        }
    }
    let g = |l: usize, m: usize| p[m * k + l];
    if let (Some(x0), Some(x1), Some(y0), Some(y1)) =
        (g(h - 1, h), g(h + 1, h), g(h, h - 1), g(h, h + 1))
    {
        let ang = (x1 - x0).angle_between(y1 - y0).to_degrees();
        st.axes = st.axes.max((ang - 90.0).abs());
    }
}

/// Largest angle between the centre normal and a sample's normal: how much the surface
/// bends under the pattern.
fn bend(s: &Surface, c: DomainLocation, out: &[Option<DomainLocation>]) -> f64 {
    let n0 = s.eval(c.domain, c.u, c.v).n;
    out.iter()
        .flatten()
        .map(|l| s.eval(l.domain, l.u, l.v).n.angle_between(n0).to_degrees())
        .fold(0.0, f64::max)
}

struct MeshReport {
    chart: Stats,
    march: Stats,
    agree: f64,
    chart_patterns: usize,
    fallbacks: usize,
    skipped: usize,
}

/// Samples K×K patterns at δ = `texels` local texel spacings around 300 random centres and
/// every domain corner. Patterns under which the surface normal turns by more than
/// `max_bend` degrees are not judged (no square grid of that size fits such a surface to
/// 5%: on a sphere the exp-map grid's spacing drifts by bend²/6) — they are counted.
fn survey(s: &Surface, sam: &Sampler, k: usize, texels: f64, max_bend: f64) -> MeshReport {
    let centres = centres(s, 300, 11);
    let mut rep = MeshReport {
        chart: Stats::default(),
        march: Stats::default(),
        agree: 0.0,
        chart_patterns: 0,
        fallbacks: 0,
        skipped: 0,
    };
    let mut a = vec![None; k * k];
    let mut b = vec![None; k * k];
    for c in centres {
        let mid = s.eval(c.domain, 0.5, 0.5);
        let delta = texels * 0.5 * (mid.du.length() + mid.dv.length()) / 32.0;
        let ia = sam.sample(c, delta, k, SamplerKind::Chart, &mut a);
        sam.sample(c, delta, k, SamplerKind::March, &mut b);
        if bend(s, c, &b) > max_bend {
            rep.skipped += 1;
            continue;
        }
        if ia.fallback {
            rep.fallbacks += 1;
        }
        judge(s, &a, k, delta, &mut rep.chart);
        judge(s, &b, k, delta, &mut rep.march);
        if let Method::Chart(_) = ia.method {
            rep.chart_patterns += 1;
            for i in 0..k * k {
                if let (Some(x), Some(y)) = (pos(s, &a[i]), pos(s, &b[i])) {
                    rep.agree = rep.agree.max((x - y).length() / delta);
                }
            }
        }
    }
    rep
}

/// Issue 3's numbers on five meshes (plus catmark_edgecorner). Every pattern of both
/// samplers: no flipped cell, centre axes 90° ± 3°, every adjacent pair δ ± 5% (the worst
/// is asserted per mesh, a little above what was measured). Chart and marching samples
/// agree within 2.5% of δ everywhere (1.2% on the cube, 1.7% on Spot at K 9, 2.5% on the
/// double torus at K 9, where chart sampling's own distance to the exact map dominates;
/// marching is within 0.8% of it, tests/sampling_truth.rs): patterns that reach an
/// extraordinary vertex or an open boundary are marched
/// ([`surfsynth::sampling::EXTRAORDINARY_MARGIN`]), and the chart's Christoffel grid has
/// 5 nodes per side where that is within ~0.2% of δ of the geodesics, else 9.
#[test]
fn samplers_produce_square_fold_free_grids_on_five_meshes() {
    // (mesh, worst spacing of either sampler, chart-vs-march bounds for K5 δ1, K5 δ2, K9 δ1;
    // measured: cube 0.20/0.58/1.15%, torus 0.16/0.16/0.31%, Spot 0.90/1.32/1.70%, double
    // torus 0.53/0.76/2.45%, cube_no_bottom 0.17/0.63/1.00%, edgecorner 0.02/0.04/0.08%)
    for (rel, spacing, agree) in [
        (
            "opensubdiv-reference/catmark_cube.obj",
            0.03,
            [0.003, 0.008, 0.015],
        ),
        (
            "opensubdiv-reference/catmark_torus.obj",
            0.02,
            [0.003, 0.003, 0.005],
        ),
        (
            "opensubdiv-reference/spot_control_mesh.obj",
            0.045,
            [0.012, 0.016, 0.021],
        ),
        (
            "meshes/double_torus_genus2.obj",
            0.045,
            [0.007, 0.010, 0.028],
        ),
        // K9 δ1 on the open cube: 0.76% with the Gauss–Seidel field, 1.00% with the multigrid one.
        ("meshes/cube_no_bottom.obj", 0.04, [0.003, 0.009, 0.012]),
        (
            "opensubdiv-reference/catmark_edgecorner.obj",
            0.04,
            [0.001, 0.001, 0.001],
        ),
    ] {
        let s = load(rel);
        let f = OrientationField::compute(&s, &Orientation::Auto).unwrap();
        let sam = Sampler::new(&s, &f);
        for (ci, (k, t)) in [(5, 1.0), (5, 2.0), (9, 1.0)].into_iter().enumerate() {
            let r = survey(&s, &sam, k, t, 20.0);
            println!(
                "{rel} K{k} δ={t}: chart max {:.4} over5 {}/{} axes {:.3}° folds {} | march max {:.4} over5 {}/{} axes {:.3}° folds {} | agree {:.4}δ | chart-sampled {} fallbacks {} | not judged (bend > 20°) {}/{}",
                r.chart.spacing, r.chart.over5, r.chart.pairs, r.chart.axes, r.chart.folds,
                r.march.spacing, r.march.over5, r.march.pairs, r.march.axes, r.march.folds,
                r.agree, r.chart_patterns, r.fallbacks, r.skipped, r.skipped + r.chart.patterns
            );
            for (name, st) in [("chart", &r.chart), ("march", &r.march)] {
                assert_eq!(st.folds, 0, "{rel} K{k} δ={t} {name}: folds");
                assert!(st.axes <= 3.0, "{rel} K{k} δ={t} {name}: axes {}", st.axes);
                assert!(
                    st.patterns >= 20,
                    "{rel}: only {} patterns judged",
                    st.patterns
                );
                assert_eq!(st.over5, 0, "{rel} K{k} δ={t} {name}: pairs off by > 5%");
                assert!(
                    st.spacing <= spacing,
                    "{rel} K{k} δ={t} {name}: {}",
                    st.spacing
                );
            }
            assert!(
                r.agree <= agree[ci],
                "{rel} K{k} δ={t}: chart vs march {}δ",
                r.agree
            );
        }
    }
}

#[test]
fn marching_never_stalls_or_returns_nan_at_extraordinary_vertices() {
    for rel in [
        "opensubdiv-reference/catmark_cube.obj",
        "meshes/double_torus_genus2.obj",
        "meshes/cube_no_bottom.obj",
    ] {
        let s = load(rel);
        let f = OrientationField::compute(&s, &Orientation::Auto).unwrap();
        let sam = Sampler::new(&s, &f);
        let mut out = vec![None; 81];
        let mut n = 0;
        for d in 0..s.num_domains() {
            for (u, v) in [(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0), (0.5, 0.5)] {
                let c = DomainLocation {
                    domain: DomainId(d as u32),
                    u,
                    v,
                };
                // Long paths (up to 4√2 · 0.3 ≈ 1.7 units) over many edges and vertices.
                sam.sample(c, 0.3, 9, SamplerKind::March, &mut out);
                for l in out.iter().flatten() {
                    assert!(l.u.is_finite() && l.v.is_finite(), "{rel}: {l:?}");
                    assert!((0.0..=1.0).contains(&l.u) && (0.0..=1.0).contains(&l.v));
                    n += 1;
                }
            }
        }
        assert_eq!(sam.stats().stalled, 0, "{rel}");
        assert!(n > 0);
    }
}

#[test]
fn chart_sampling_falls_back_to_marching_and_counts_it() {
    let s = load("opensubdiv-reference/catmark_torus.obj");
    let f = OrientationField::compute(&s, &Orientation::Auto).unwrap();
    let sam = Sampler::new(&s, &f);
    let c = DomainLocation {
        domain: DomainId(5),
        u: 0.5,
        v: 0.5,
    };
    let mut out = vec![None; 81];
    // δ of a quarter domain: a 9×9 pattern spans two domains each way, no chart holds it.
    let side = s.eval(c.domain, 0.5, 0.5).du.length();
    let info = sam.sample(c, 0.25 * side, 9, SamplerKind::Chart, &mut out);
    assert!(info.fallback && info.method == Method::March);
    assert_eq!(info.missing, 0);
    let small = sam.sample(c, 0.01 * side, 9, SamplerKind::Chart, &mut out);
    assert!(!small.fallback && matches!(small.method, Method::Chart(_)));
    let st = sam.stats();
    assert_eq!((st.patterns, st.chart_requests, st.fallbacks), (2, 2, 1));
    assert_eq!(st.fallback_rate(), 0.5);
}

#[test]
fn boundary_samples_are_missing_for_both_samplers() {
    let s = load("opensubdiv-reference/catmark_edgecorner.obj");
    let f = OrientationField::compute(&s, &Orientation::Auto).unwrap();
    let sam = Sampler::new(&s, &f);
    let mut hits = [0usize; 2];
    for d in 0..s.num_domains() {
        for (u, v) in [(0.0, 0.0), (0.5, 0.02), (0.97, 0.5)] {
            let c = DomainLocation {
                domain: DomainId(d as u32),
                u,
                v,
            };
            let side = s.eval(c.domain, 0.5, 0.5).du.length();
            for (i, kind) in [SamplerKind::Chart, SamplerKind::March]
                .into_iter()
                .enumerate()
            {
                let mut out = vec![None; 25];
                let info = sam.sample(c, side / 16.0, 5, kind, &mut out);
                hits[i] += info.missing;
            }
        }
    }
    // Both find the boundary, and about equally often.
    assert!(hits[0] > 0 && hits[1] > 0, "{hits:?}");
    let ratio = hits[0] as f64 / hits[1] as f64;
    assert!((0.9..=1.1).contains(&ratio), "{hits:?}");
}

/// A linear function of position, sampled at texel centres, is fetched back at arbitrary
/// points — including across edges and corners, T-junctions between quad and n-gon
/// domains, extraordinary corners — as accurately inside faces as across them (closed
/// meshes: at an open boundary the ring repeats the border texel).
#[test]
fn bilinear_fetch_is_as_accurate_across_faces_as_inside() {
    for rel in [
        "opensubdiv-reference/catmark_cube.obj",
        "opensubdiv-reference/spot_control_mesh.obj",
        "meshes/double_torus_genus2.obj",
    ] {
        let s = load(rel);
        let n = 16;
        let layout = Arc::new(MapLayout::new(&s, n));
        let mut maps = FaceMaps::new(layout.clone(), 3);
        for i in 0..layout.texels() {
            let l = layout.texel_location(i);
            let p = s.eval(l.domain, l.u, l.v).p;
            maps.texel_mut(i)
                .copy_from_slice(&[p.x as f32, p.y as f32, p.z as f32]);
        }
        let mut r = Lcg(5);
        let (mut inner, mut border) = (0.0f64, 0.0f64);
        let mut out = [0.0f32; 3];
        for _ in 0..20000 {
            let d = DomainId((r.next() * s.num_domains() as f64) as u32);
            let (u, v) = (r.next(), r.next());
            let loc = DomainLocation { domain: d, u, v };
            maps.sample(loc, &mut out);
            let p = s.eval(d, u, v).p;
            let err = (DVec3::new(out[0] as f64, out[1] as f64, out[2] as f64) - p).length();
            let edge = 0.5 / n as f64;
            if u < edge || v < edge || u > 1.0 - edge || v > 1.0 - edge {
                border = border.max(err);
            } else {
                inner = inner.max(err);
            }
        }
        let h = surfsynth::sampling::median_texel_spacing(&s, n);
        println!("{rel}: max error inside {inner:.2e}, across borders {border:.2e}, h {h:.3e}");
        // Inside: bilinear error of a curved surface. Across borders a little more where a
        // quad domain meets n-gon sub-faces (half the scale): the ring point then lies
        // within a quarter texel of the neighbour's own edge, where its taps are clamped.
        assert!(inner < 0.1 * h, "{rel}: inner {inner}");
        assert!(border < 0.5 * h, "{rel}: border {border} inner {inner}");
    }
}

#[test]
fn masked_fetch_uses_the_nearest_valid_texel() {
    let s = load("opensubdiv-reference/catmark_cube.obj");
    let layout = Arc::new(MapLayout::new(&s, 4));
    let data: Vec<f32> = (0..layout.texels()).map(|i| i as f32).collect();
    let maps = FaceMaps::from_data(layout.clone(), 1, data);
    let mut out = [0.0f32];
    // Between texels (1,1) and (2,1) of domain 0, nearer (2,1); only (2,1) invalid.
    let loc = DomainLocation {
        domain: DomainId(0),
        u: 2.3 / 4.0,
        v: 1.5 / 4.0,
    };
    let t21 = layout.texel_index(DomainId(0), 2, 1);
    let t11 = layout.texel_index(DomainId(0), 1, 1);
    assert!(maps.sample_valid(loc, |i| i != t21, &mut out));
    assert_eq!(out[0], t11 as f32);
    assert!(maps.sample_valid(loc, |_| true, &mut out));
    assert!((out[0] - (0.2 * t11 as f32 + 0.8 * t21 as f32)).abs() < 1e-4);
    assert!(!maps.sample_valid(loc, |_| false, &mut out));
}

/// `surfsynth bench sampling` reports one row per sampler with the chart rows split by
/// method; bad sizes are a one-line error.
#[test]
fn bench_sampling_cli_reports_every_sampler() {
    use std::process::Command;
    let o = Command::new(env!("CARGO_BIN_EXE_surfsynth"))
        .args(["bench", "sampling", "--size", "5", "--patterns", "300"])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let rows: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let rows = rows.as_array().unwrap();
    let names: Vec<&str> = rows
        .iter()
        .map(|r| r["sampler"].as_str().unwrap())
        .collect();
    assert_eq!(names, ["chart", "chart-unchecked", "march"]);
    for r in rows {
        assert_eq!(r["k"], 5);
        assert_eq!(r["patterns"], 300);
        assert!(r["samples_per_second"].as_f64().unwrap() > 0.0);
        let fb = r["fallback_rate"].as_f64().unwrap();
        assert!((0.0..=1.0).contains(&fb));
    }
    // Spot: some chart patterns are marched (next to extraordinary vertices), most not.
    let fb = rows[0]["fallback_rate"].as_f64().unwrap();
    assert!(fb > 0.0 && fb < 0.5, "fallback rate {fb}");
    assert!(
        rows[0]["chart_sampled_samples_per_second"]
            .as_f64()
            .unwrap()
            > 0.0
    );
    assert!(rows[0]["marched_samples_per_second"].as_f64().unwrap() > 0.0);
    assert!(rows[2]["chart_sampled_samples_per_second"].is_null());
    let o = Command::new(env!("CARGO_BIN_EXE_surfsynth"))
        .args(["bench", "sampling", "--size", "4"])
        .output()
        .unwrap();
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("--size 4") && err.lines().count() == 1,
        "{err}"
    );
}
