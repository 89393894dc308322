//! Multiscale synthesis on surfaces (issue 5), measured with the project's evaluator on
//! shared meshes and textures: coverage, seam ratio, scale fidelity, patch fidelity on a
//! flat grid against the 2D reference synthesizer, determinism across thread counts,
//! `--scale` handling, joint alpha/height synthesis and displacement.

mod common;

use common::{data, texture};
use std::path::Path;
use subdiv::Surface;
use surfsynth::example::Example;
use surfsynth::field::{Orientation, OrientationField};
use surfsynth::io::exr::FaceMaps;
use surfsynth::pyramid::Image;
use surfsynth::synth::matching::search::ann::AnnParams;
use surfsynth::synth::matching::search::kcoherence::KParams;
use surfsynth::synth::matching::search::model::Method;
use surfsynth::synth::multiscale::{self, Inputs, MultiscaleParams, Output};
use surfsynth::texels::TexelGeometry;

/// A flat k x k grid of unit quads in the z = 0 plane.
fn flat_grid(k: usize) -> Surface {
    Surface::new(subdiv::ControlMesh::grid(k))
}

struct Run {
    maps: FaceMaps,
    geometry: FaceMaps,
    scale: f64,
    out: Output,
}

fn kcoherence() -> Method {
    Method::KCoherence(KParams::default())
}

/// Runs multiscale synthesis; `scale_factor` multiplies the default scale h.
fn run(
    surface: &Surface,
    ex: &Example,
    n: usize,
    method: Method,
    seed: u64,
    scale_factor: f64,
    orient: &Orientation,
) -> Run {
    let field = OrientationField::compute(surface, orient).unwrap();
    let geom = TexelGeometry::compute(surface, n);
    let spacing = geom.median_spacing(surface);
    let scale = spacing * scale_factor;
    let mut params = MultiscaleParams::default();
    params.model.method = method;
    let weights = vec![1.0f32; ex.num_channels()];
    let inputs = Inputs {
        appearance: surfsynth::synth::matching::appearance::AppearanceMode::Rgb,
        feature_distance: 0.0,
        surface,
        field: &field,
        layout: &geom.layout,
        spacing,
        scale,
        scale_field: None,
        seed,
        weights: &weights,
    };
    // The example's model is shared by every run of the binary with the same example and
    // levels (common::analyses): the runs below differ in seed, mesh and resolution.
    let analyses = common::analyses();
    let models = |key, build: &dyn Fn() -> surfsynth::error::Result<multiscale::Model>| {
        analyses.try_get("multiscale-model", key, build)
    };
    let out = multiscale::run_with(ex, &inputs, &params, &models, &|_, _| {}).unwrap();
    let maps = surfsynth::synth::face_maps(ex, &out.source, &geom.layout);
    let geometry = surfsynth::synth::geometry_maps(&geom);
    Run {
        maps,
        geometry,
        scale,
        out,
    }
}

/// `run` as every flat-grid test calls it: k-coherence search, the field along x.
fn run_along_x(surface: &Surface, ex: &Example, n: usize, seed: u64, scale_factor: f64) -> Run {
    run(
        surface,
        ex,
        n,
        kcoherence(),
        seed,
        scale_factor,
        &Orientation::Axis(glam::DVec3::X),
    )
}

fn quality(r: &Run, example: Option<&Example>) -> surfsynth::eval::Quality {
    surfsynth::eval::evaluate_maps(&r.maps, &r.geometry, Some(r.scale), example).unwrap()
}

#[test]
fn flat_grid_matches_2d_multiscale_patch_fidelity() {
    let ex = texture("etr_gravel.png", 64);
    let (k, n) = (6, 24);
    let r = run_along_x(&flat_grid(k), &ex, n, 3, 1.0);
    // multiscale::run lays image rows along −v2 (the builder's Handedness::Outside frame),
    // so the tiles are the example's mirror image: compare them with it upside down.
    let q = quality(&r, Some(&ex.flipped_rows()));
    let as_stored = quality(&r, Some(&ex)).patch_fidelity.unwrap();
    // The 2D reference at the same size, same example, search and seed, measured by the
    // same evaluator (one domain holding the whole picture).
    let pf2 = patch_fidelity_2d(&ex, k * n, 3);
    let pf = q.patch_fidelity.unwrap();
    let s = q.scale_fidelity.unwrap();
    eprintln!(
        "flat {k}x{k} N={n}: patch fidelity {pf:.3} (2D {pf2:.3}, ratio {:.3}; unmirrored {as_stored:.3}), seam {:?}, scale {s:?}, stats {:?}",
        pf / pf2,
        q.seam_ratio,
        r.out.stats
    );
    assert_eq!(q.coverage, 1.0);
    assert!(pf <= 1.1 * pf2, "patch fidelity {pf:.3} vs 2D {pf2:.3}");
    // The orientation check: the texture as seen from outside is the example, not its
    // mirror image (gravel is lit from one side, so the mirror matches worse).
    assert!(as_stored > 1.2 * pf, "mirrored {as_stored:.3} vs {pf:.3}");
    assert!(
        q.seam_ratio.unwrap() <= 1.15,
        "seam ratio {:?}",
        q.seam_ratio
    );
    assert!((s.median - 1.0).abs() <= 0.05, "{s:?}");
    assert!(s.p10 >= 0.8 && s.p90 <= 1.2, "{s:?}");
    // Flat, regular grid: every pattern is laid out in a chart, none needs the sampler's
    // marching except the coarsest level, which the paper marches.
    let ps = r.out.stats.patterns;
    assert_eq!(ps.sampler_chart, 0);
    assert_eq!(
        ps.sampler_march as usize,
        k * k * 6 * 6,
        "coarsest level 6x6 texels"
    );
}

/// 2D multiscale patch fidelity of `ex` at `size`², seed `seed`, one domain.
fn patch_fidelity_2d(ex: &Example, size: usize, seed: u64) -> f64 {
    let mut p2 = surfsynth::synth::synth2d::Params2d::new(size, size);
    p2.seed = seed;
    let o = surfsynth::synth::synth2d::synthesize(&Image::from_example(ex), &p2).unwrap();
    surfsynth::eval::image_patch_fidelity(&o.image, ex).unwrap()
}

/// [`patch_fidelity_2d`] over `seeds`, the example model built once (the seeds differ only
/// in the synthesis).
fn mean_patch_fidelity_2d(ex: &Example, size: usize, seeds: std::ops::RangeInclusive<u64>) -> f64 {
    use surfsynth::synth::matching::search::model::ExampleModel;
    use surfsynth::synth::synth2d::{auto_levels, synthesize_with, Params2d};
    let p = Params2d::new(size, size);
    let levels = auto_levels(ex.width, ex.height);
    let model = ExampleModel::build(Image::from_example(ex), levels, p.model).unwrap();
    let count = seeds.clone().count() as f64;
    seeds
        .map(|seed| {
            let o = synthesize_with(&model, &Params2d { seed, ..p }).unwrap();
            surfsynth::eval::image_patch_fidelity(&o.image, ex).unwrap()
        })
        .sum::<f64>()
        / count
}

#[test]
fn small_domains_match_2d_patch_fidelity() {
    // Issue 5's bar with domains of 24 and 12 texels (144² in all, the fixture's 128²
    // gravel: 4 example levels, coarsest domains 3 and 2-rounded-from-1.5 texels before the
    // fix). Means over 8 seeds: single seeds range 0.18-0.37 in 2D alone. Before the fix
    // (any generated texel as "nearest generated", levels stopped on the rounded size) the
    // ratios were 1.15 (K = 6) and 1.26 (K = 12) over 8 seeds; docs/multiscale.md.
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/fixtures/gravel.png");
    let ex = Example::load(path).unwrap();
    let mirrored = ex.flipped_rows();
    const SEEDS: u64 = 8;
    let seeds = 1..=SEEDS;
    let pf2 = mean_patch_fidelity_2d(&ex, 144, seeds.clone());
    for (k, n) in [(6usize, 24usize), (12, 12)] {
        let surface = flat_grid(k);
        let mut pf = 0.0;
        for seed in seeds.clone() {
            let r = run_along_x(&surface, &ex, n, seed, 1.0);
            let q = quality(&r, Some(&mirrored));
            assert_eq!(q.coverage, 1.0);
            assert!(q.seam_ratio.unwrap() <= 1.15, "{:?}", q.seam_ratio);
            pf += q.patch_fidelity.unwrap() / SEEDS as f64;
        }
        eprintln!(
            "flat {k}x{k} N={n}: patch fidelity {pf:.3}, 2D {pf2:.3}, ratio {:.3}",
            pf / pf2
        );
        assert!(pf <= 1.1 * pf2, "K={k} N={n}: {pf:.3} vs 2D {pf2:.3}");
    }
}

#[test]
fn curved_meshes_meet_the_quality_bar() {
    // An open mesh of triangles (every domain an n-gon sub-face, extraordinary vertices
    // at every face centre). Blub and the double torus are measured in docs/multiscale.md;
    // they take longer than a test should. A stochastic example: periodic ones (bricks)
    // whose period divides the texel grid, or examples with a 2-pixel parity
    // (gimp_coffee_beans), make the seam ratio measure the texture's phase at the domain
    // border rather than seams (docs/multiscale.md).
    let (mesh, tex, n, seed) = ("meshes/cube_no_bottom.obj", "etr_gravel.png", 12, 5);
    {
        let surface = surfsynth::bake::load_surface_for(data(mesh), n).unwrap();
        let ex = texture(tex, 64);
        let r = run(
            &surface,
            &ex,
            n,
            kcoherence(),
            seed,
            1.0,
            &Orientation::Auto,
        );
        let q = quality(&r, None);
        let s = q.scale_fidelity.unwrap();
        eprintln!(
            "{mesh} N={n}: seam {:?}, scale {s:?}, coherent {:?}, stats {:?}",
            q.seam_ratio, q.coherent_fraction, r.out.stats
        );
        assert_eq!(q.coverage, 1.0, "{mesh}");
        assert!(
            q.seam_ratio.unwrap() <= 1.15,
            "{mesh}: seam ratio {:?}",
            q.seam_ratio
        );
        assert!((s.median - 1.0).abs() <= 0.05, "{mesh}: {s:?}");
    }
}

#[test]
fn output_is_identical_for_any_thread_count() {
    // A coarse torus: every level crosses domain edges, and at this resolution most
    // patterns are marched — all the machinery that could depend on scheduling.
    let n = 8;
    let surface = Surface::new(surfsynth::bench::torus_mesh(8));
    let ex = texture("gimp_coffee_beans.png", 48);
    let field = OrientationField::compute(&surface, &Orientation::Auto).unwrap();
    let geom = TexelGeometry::compute(&surface, n);
    let spacing = geom.median_spacing(&surface);
    let weights = [1.0f32; 3];
    let inputs = Inputs {
        appearance: surfsynth::synth::matching::appearance::AppearanceMode::Rgb,
        feature_distance: 0.0,
        surface: &surface,
        field: &field,
        layout: &geom.layout,
        spacing,
        scale: spacing,
        scale_field: None,
        seed: 11,
        weights: &weights,
    };
    for method in [kcoherence(), Method::Ann(AnnParams::default())] {
        let mut params = MultiscaleParams::default();
        params.model.method = method;
        let runs: Vec<Output> = [1, 2]
            .iter()
            .map(|&t| {
                rayon::ThreadPoolBuilder::new()
                    .num_threads(t)
                    .build()
                    .unwrap()
                    .install(|| multiscale::run(&ex, &inputs, &params, &|_, _| {}).unwrap())
            })
            .collect();
        let bits = |o: &Output| -> Vec<u32> {
            o.source
                .iter()
                .flat_map(|s| [s[0].to_bits(), s[1].to_bits()])
                .collect()
        };
        assert_eq!(bits(&runs[0]), bits(&runs[1]), "{method:?}");
        // Counters are sums, so they agree too.
        assert_eq!(runs[0].stats.candidates, runs[1].stats.candidates);
        assert_eq!(runs[0].stats.patterns, runs[1].stats.patterns);
    }
}

#[test]
fn scale_picks_levels_and_keeps_the_texture_size() {
    // S = 2h: the texture twice as large; synthesis at half the texels per side, output
    // texels continue the nearest synthesized texel's patch.
    let ex = texture("gimp_leopard.png", 48);
    let (k, n) = (4, 24);
    let r = run_along_x(&flat_grid(k), &ex, n, 1, 2.0);
    let st = &r.out.stats;
    let res: Vec<usize> = st.levels.iter().map(|l| l.resolution).collect();
    assert_eq!(res, vec![12, 6]);
    assert_eq!(st.levels[0].example_level, 0);
    assert!(
        (st.levels[0].step - r.scale).abs() < 1e-12
            && (st.levels[1].step - 2.0 * r.scale).abs() < 1e-12
    );
    assert_eq!(st.resampled as usize, k * k * n * n);
    let s = quality(&r, None).scale_fidelity.unwrap();
    eprintln!("S = 2h: scale {s:?}");
    assert!((s.median - 1.0).abs() <= 0.05, "{s:?}");
}

#[test]
fn alpha_and_height_are_synthesized_jointly_and_displace_the_surface() {
    // RGBA stripes (the stripes are in alpha; colour is flat) with a height map derived
    // from the alpha (same size, as --height requires).
    let ex = Example::load(data("textures/gimp_stripes_alpha.png")).unwrap();
    assert!(ex.alpha.is_some());
    let hmap: Vec<f32> = ex
        .alpha
        .as_ref()
        .unwrap()
        .iter()
        .map(|a| 0.2 + 0.6 * a)
        .collect();
    let ex = ex
        .with_map(surfsynth::example::MaterialMap::from_linear(
            "height", 1, hmap,
        ))
        .unwrap();
    let (k, n) = (2, 16);
    let surface = flat_grid(k);
    let r = run_along_x(&surface, &ex, n, 4, 1.0);
    assert_eq!(
        r.maps.names(),
        vec!["R", "G", "B", "A", "height.Y", "height", "source.u", "source.v"]
    );
    // Every channel comes from the same example position.
    let (a, h, su, sv) = (
        r.maps.channel("A").unwrap(),
        r.maps.channel("height").unwrap(),
        r.maps.channel("source.u").unwrap(),
        r.maps.channel("source.v").unwrap(),
    );
    let mut v = [0.0f32; 5];
    for i in (0..a.len()).step_by(7) {
        ex.bilinear(su[i], sv[i], &mut v);
        assert_eq!((v[3], v[4]), (a[i], h[i]));
    }
    // Alpha varies (the stripes are partly transparent) and is synthesized, not constant.
    let (amin, amax) = a
        .iter()
        .fold((f32::MAX, f32::MIN), |(lo, hi), &x| (lo.min(x), hi.max(x)));
    assert!(amin < 0.2 && amax > 0.8, "alpha {amin}..{amax}");

    // Displacement: z = amount · (height − 0.5) along the +z normal, one shared vertex per
    // surface point (no cracks).
    let amount = 0.25;
    let mesh = surfsynth::io::displace::displaced_mesh(&surface, &r.maps, amount).unwrap();
    let level = surfsynth::io::displace::level_for_texels(&surface, n);
    assert_eq!(level, 4); // 16 segments per quad domain side
    let side = k * (1 << level) + 1;
    assert_eq!(mesh.positions.len(), side * side);
    let layout = std::sync::Arc::new(surfsynth::maps::MapLayout::new(&surface, n));
    let hm = surfsynth::maps::FaceMaps::from_data(layout, 1, h.to_vec());
    let mut zmin = f64::MAX;
    let mut zmax = f64::MIN;
    for p in &mesh.positions {
        // On the flat grid, domain (x, y) covers [x, x+1] x [y, y+1].
        let (fx, fy) = (p[0].min(k as f64 - 1e-9), p[1].min(k as f64 - 1e-9));
        let d = subdiv::DomainId::from_idx(fy as usize * k + fx as usize);
        let loc = subdiv::DomainLocation {
            domain: d,
            u: p[0] - fx.floor(),
            v: p[1] - fy.floor(),
        };
        let mut hv = [0.0f32];
        hm.sample(loc, &mut hv);
        let want = amount * (hv[0] as f64 - 0.5);
        assert!((p[2] - want).abs() < 1e-5, "{p:?}: want z = {want}");
        zmin = zmin.min(p[2]);
        zmax = zmax.max(p[2]);
    }
    assert!(zmax - zmin > 0.05, "relief {zmin}..{zmax}");
    // Missing height channel: a one-line error.
    let plain = run_along_x(&surface, &texture("etr_gravel.png", 32), 8, 1, 1.0);
    let e = surfsynth::io::displace::displaced_mesh(&surface, &plain.maps, 0.1)
        .unwrap_err()
        .to_string();
    assert!(e.contains("height") && !e.contains('\n'), "{e}");
}

/// Figures for docs/benchmarks.md, not a test (timings depend on the machine and its
/// load): `cargo test --release --test multiscale figures -- --ignored --nocapture`.
/// `MS_FIGURES` picks rows: `spot` (Spot N 32, the `synth`/`demo` gravel fixture), `t64`,
/// `t192` (Torus rows, k-coherence and ANN); default all. `MS_SEARCH=ann|kcoherence`
/// restricts the Torus rows to one search. Each row runs in a fresh thread pool of
/// `RAYON_NUM_THREADS` (default: all cores).
#[test]
#[ignore]
fn figures() {
    let rows = std::env::var("MS_FIGURES").unwrap_or_else(|_| "spot,t64,t192".into());
    let search = std::env::var("MS_SEARCH").ok();
    let methods: Vec<Method> = [kcoherence(), Method::Ann(AnnParams::default())]
        .into_iter()
        .filter(|m| {
            search
                .as_deref()
                .is_none_or(|s| (s == "ann") == matches!(m, Method::Ann(_)))
        })
        .collect();
    for row in rows.split(',') {
        let (ex, faces, n): (Example, Option<usize>, usize) = match row {
            "spot" => (
                Example::load(Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/gravel.png"))
                    .unwrap(),
                None,
                32,
            ),
            "t64" => (texture("etr_gravel.png", 64), Some(32), 60),
            "t192" => (texture("etr_gravel.png", 192), Some(32), 60),
            other => panic!("unknown row {other}"),
        };
        let list = if faces.is_some() {
            methods.clone()
        } else {
            vec![kcoherence()]
        };
        for method in list {
            let mut params = MultiscaleParams::default();
            params.model.method = method;
            let r = match faces {
                Some(f) => {
                    surfsynth::bench::multiscale::bench_torus(f, n, &ex, &params, 1).unwrap()
                }
                None => {
                    let surface =
                        surfsynth::bake::load_surface_for(data("meshes/spot_control_mesh.obj"), n)
                            .unwrap();
                    surfsynth::bench::multiscale::bench_surface(&surface, n, &ex, &params, 1)
                        .unwrap()
                }
            };
            let load = std::fs::read_to_string("/proc/loadavg").unwrap_or_default();
            println!(
                "FIGURES {row} {}: wall {:.2} s, cpu {:?} s, synthesis {:.2} s, model {:.2} s, \
                 geometry {:.2} s, search {:.2} s, {:.0} texels/s, {:.1} distances/query, \
                 peak {:?} B/texel, threads {}, load {}",
                r.search,
                r.total_seconds,
                r.cpu_seconds.map(|c| (c * 100.0).round() / 100.0),
                r.synthesis_seconds,
                r.stats.model_seconds,
                r.stats.geometry_seconds,
                r.stats.search_seconds,
                r.texels_per_second,
                r.stats.candidates as f64 / r.stats.queries as f64,
                r.peak_bytes_per_texel.map(|b| b.round()),
                r.threads,
                load.trim()
            );
            println!(
                "FIGURES {row} patterns {:?} sampler {:?}",
                r.stats.patterns, r.stats.sampler
            );
        }
    }
}

/// Accuracy of the parameter-space patterns against the vertex-chart sampler on Spot, for
/// docs/multiscale.md: `cargo test --release --test multiscale pattern_accuracy --
/// --ignored --nocapture`. Per level of a N = 32 run (9x9 at that level's step), texels
/// bucketed by the spacing error the parameter pattern's check sees (interpolated texel
/// positions); per bucket the true spacing error (limit evaluation) of the parameter
/// pattern and of the sampler's pattern on the same texels, and how often the sampler
/// marched.
#[test]
#[ignore]
fn pattern_accuracy() {
    use surfsynth::sampling::{Method as SMethod, Sampler, SamplerKind};
    use surfsynth::synth::multiscale::level::{
        parameter_pattern, regular_corners, shift_pattern, spacing_error,
    };
    let mesh = std::env::var("MS_MESH").unwrap_or_else(|_| "meshes/spot_control_mesh.obj".into());
    let n = 32;
    let surface = surfsynth::bake::load_surface_for(data(&mesh), n).unwrap();
    let field = OrientationField::compute(&surface, &Orientation::Auto).unwrap();
    let h = TexelGeometry::compute(&surface, n).median_spacing(&surface);
    let sampler = Sampler::new(&surface, &field);
    let corners = std::sync::Arc::new(regular_corners(&surface));
    let k = 9;
    let bounds = [0.04, 0.08, 0.15, 0.25, f64::INFINITY];
    for (level, r) in [(0usize, 32usize), (1, 16), (2, 8)] {
        let delta = h * (1 << level) as f64;
        let geo = multiscale::level::LevelGeometry::new(&surface, &field, r, corners.clone());
        let stride = if r >= 32 { 7 } else { 1 };
        // Per bucket: (param true errors, sampler true errors, marched count); last bucket:
        // parameter pattern not applicable.
        let mut buckets: Vec<(Vec<f64>, Vec<f64>, usize)> =
            vec![(Vec::new(), Vec::new(), 0); bounds.len() + 1];
        let mut locs = vec![None; k * k];
        let mut buf = vec![None; k * k];
        let mut pts = Vec::new();
        let mut truth = vec![glam::Vec3::NAN; k * k];
        let true_error =
            |locs: &[Option<subdiv::DomainLocation>], truth: &mut Vec<glam::Vec3>, nrm| {
                for (p, l) in truth.iter_mut().zip(locs) {
                    *p = match l {
                        Some(l) => surface.eval(l.domain, l.u, l.v).p.as_vec3(),
                        None => glam::Vec3::NAN,
                    };
                }
                spacing_error(truth, k, delta, nrm, f64::INFINITY)
            };
        for t in (0..geo.len()).step_by(stride) {
            let nrm = geo.frame(t).n.as_vec3();
            let p = parameter_pattern(
                &geo,
                &surface,
                t,
                delta,
                k,
                f64::INFINITY,
                &mut locs,
                &mut pts,
            );
            let (b, pe) = match p {
                Some(p) => (
                    bounds.iter().position(|&x| p.error <= x).unwrap(),
                    Some(true_error(&locs, &mut truth, nrm)),
                ),
                None => (bounds.len(), None),
            };
            let info = sampler.sample_with_frame(
                geo.location(t),
                &geo.frame(t),
                delta,
                k,
                SamplerKind::Chart,
                &mut buf,
            );
            // Sampler rows run along +v2: flip to our order for the flip check.
            let mut ours = vec![None; k * k];
            for m in 0..k {
                ours[(k - 1 - m) * k..(k - m) * k].copy_from_slice(&buf[m * k..(m + 1) * k]);
            }
            let se = true_error(&ours, &mut truth, nrm);
            let e = &mut buckets[b];
            if let Some(pe) = pe {
                e.0.push(pe);
            }
            e.1.push(se);
            if info.method == SMethod::March {
                e.2 += 1;
            }
        }
        // Shifted patterns: the sampler's pattern at the centre of the texel's 3x3 block
        // moved to the texel, against the sampler's own pattern there (sample distance
        // in units of δ).
        let mut dev = Vec::new();
        let mut anchor = vec![None; k * k];
        let mut moved = vec![None; k * k];
        let sample = |t: usize, out: &mut Vec<Option<subdiv::DomainLocation>>| {
            let mut raw = vec![None; k * k];
            sampler.sample_with_frame(
                geo.location(t),
                &geo.frame(t),
                delta,
                k,
                SamplerKind::Chart,
                &mut raw,
            );
            for m in 0..k {
                out[(k - 1 - m) * k..(k - m) * k].copy_from_slice(&raw[m * k..(m + 1) * k]);
            }
        };
        for t in (0..geo.len()).step_by(stride * 3 + 1) {
            let li = t % (r * r);
            let (x, y) = (li % r, li / r);
            let a = t - li + (3 * (y / 3) + 1).min(r - 1) * r + (3 * (x / 3) + 1).min(r - 1);
            if a == t {
                continue;
            }
            sample(a, &mut anchor);
            sample(t, &mut buf);
            if !shift_pattern(&geo, &surface, a, t, &anchor, &mut moved) {
                continue;
            }
            for (m, d) in moved.iter().zip(&buf) {
                if let (Some(m), Some(d)) = (m, d) {
                    let pm = surface.eval(m.domain, m.u, m.v).p;
                    let pd = surface.eval(d.domain, d.u, d.v).p;
                    dev.push((pm - pd).length() / delta);
                }
            }
        }
        dev.sort_by(|a, b| a.total_cmp(b));
        println!(
            "ACCURACY r={r} shifted: {} samples, distance to the sampler's own / δ: mean {:.4} p95 {:.4} max {:.4}",
            dev.len(),
            dev.iter().sum::<f64>() / dev.len().max(1) as f64,
            dev[dev.len() * 95 / 100],
            dev[dev.len() - 1]
        );
        let summary = |v: &mut Vec<f64>| -> String {
            if v.is_empty() {
                return "-".into();
            }
            v.sort_by(|a, b| a.total_cmp(b));
            let fin: Vec<f64> = v.iter().copied().filter(|x| x.is_finite()).collect();
            let mean = fin.iter().sum::<f64>() / fin.len().max(1) as f64;
            format!(
                "mean {:.3} p95 {:.3} max {:.3} flipped {}",
                mean,
                v[(v.len() * 95 / 100).min(v.len() - 1)],
                v[v.len() - 1],
                v.len() - fin.len()
            )
        };
        for (i, (pe, se, marched)) in buckets.iter_mut().enumerate() {
            let label = if i < bounds.len() {
                format!("check <= {}", bounds[i])
            } else {
                "not applicable".into()
            };
            println!(
                "ACCURACY r={r} {label}: {} patterns; parameter {}; sampler {} ({} marched)",
                se.len(),
                summary(pe),
                summary(se),
                marched
            );
        }
    }
}
