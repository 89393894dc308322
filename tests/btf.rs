//! BTF synthesis with surface textons (issue 15 item 3, paper 003): a sample ray-traced from
//! a height field (as 003 Fig. 8), synthesized onto Spot; the result relit under two sample
//! lights differs where the height field casts shadows, and under each light matches the
//! sample's image in pf4 within 1.2x of a plain synthesis of that image; bit-identical for
//! any thread count; the analysis is cached; bad btf.json inputs are one-line errors that
//! leave nothing in `--out`.

mod common;

use common::data;
use glam::DVec3;
use std::path::{Path, PathBuf};
use surfsynth::btf::generate::{self, HeightField};
use surfsynth::btf::BtfSample;
use surfsynth::cache::CacheDir;
use surfsynth::io::exr::FaceMaps;
use surfsynth::synthesizer::{ExampleSource, Method, Synthesizer};

const SPOT: &str = "meshes/spot_control_mesh.obj";
/// CI-sized: 48² sample, 16 lights (two rings: 20° and 75° elevation), Spot at N = 16.
const SIZE: usize = 48;
const LIGHTS: usize = 16;
const N: usize = 16;

/// The krita relief's central crop, 5 pixels deep, under [`LIGHTS`] lights: written as a
/// BTF folder in `dir`; returns the json and the shadow flags per image.
fn krita_sample(dir: &Path) -> (PathBuf, Vec<Vec<bool>>) {
    let hf = HeightField::load(&data("textures/krita_bump_relief.png"), Some(SIZE), 5.0).unwrap();
    let (s, shadows) = generate::sample(&hf, &generate::light_directions(LIGHTS));
    let json = generate::write(&dir.join("sample"), &s, serde_json::json!({"test": true})).unwrap();
    (json, shadows)
}

/// `maps` with R, G, B replaced by the sample under image `i`'s light at every texel's
/// source position (the light the same in every texel's frame: what a view of the
/// surface BTF under that light, with the macro-shading taken out, shows).
fn relit(maps: &FaceMaps, s: &BtfSample, i: usize) -> FaceMaps {
    let su = maps.channel("source.u").unwrap().to_vec();
    let sv = maps.channel("source.v").unwrap().to_vec();
    let w = s.blend_weights(s.lights[i]);
    assert_eq!(
        w,
        vec![(i, 1.0)],
        "a sample light blends its own image only"
    );
    let mut out = maps.clone();
    for (name, data) in out.channels.iter_mut() {
        let c = match name.as_str() {
            "R" => 0,
            "G" => 1,
            "B" => 2,
            _ => continue,
        };
        for (t, v) in data.iter_mut().enumerate() {
            *v = s.colour(&w, su[t], sv[t])[c];
        }
    }
    out
}

fn pf4(
    colour: &FaceMaps,
    geometry: &FaceMaps,
    ex: &surfsynth::example::Example,
    scale: f64,
) -> f64 {
    surfsynth::eval::patch_fidelities(colour, geometry, ex, Some(scale))
        .pf4
        .unwrap()
}

/// pf4 of a plain synthesis (`method`, seed 2) of one light's image `ex` alone: what a BTF
/// result relit under that light is held against.
fn plain_pf4(
    method: Method,
    ex: &surfsynth::example::Example,
    geometry: &FaceMaps,
    scale: f64,
) -> f64 {
    let plain = Synthesizer::new(data(SPOT), ex.clone())
        .method(method)
        .resolution(N)
        .seed(2)
        .cache(CacheDir::Off)
        .run()
        .unwrap();
    pf4(&plain.maps, geometry, ex, scale)
}

#[test]
fn relit_textons_differ_under_shadows_and_match_each_light_like_a_plain_synthesis() {
    let tmp = tempfile::tempdir().unwrap();
    let (json, shadows) = krita_sample(tmp.path());
    let sample = BtfSample::load(&json).unwrap();
    let out = tmp.path().join("run");
    let (r, report) = Synthesizer::new(data(SPOT), ExampleSource::Btf(json.clone()))
        .method(Method::Textons)
        .resolution(N)
        .seed(2)
        .cache(CacheDir::Off)
        .run_to(&out)
        .unwrap();
    assert_eq!(report.method, Method::Textons);
    let geometry = r.geometry_maps();
    let scale = report.scale;
    // Two low lights from opposite sides (first ring: 20° elevation, azimuths 0° and 180°).
    let (a, b) = (0, LIGHTS / 4);
    assert!(sample.lights[a].dot(sample.lights[b]) < -0.5);
    let (ma, mb) = (relit(&r.maps, &sample, a), relit(&r.maps, &sample, b));

    // Where a source pixel is shadowed under one light and lit under the other, the two
    // relit results differ much more than where both light it.
    let (sd, ld) = shadow_contrast(&r.maps, &sample, &shadows, (a, b));
    assert!(
        sd > 2.0 * ld && sd > 0.1,
        "shadow difference {sd} vs lit {ld}"
    );

    // Each light: pf4 against that light's image, within 1.2x of a plain (multiscale)
    // synthesis of the image alone.
    for i in [a, b] {
        let ex = sample.images[i].clone();
        let ours = pf4(if i == a { &ma } else { &mb }, &geometry, &ex, scale);
        let theirs = plain_pf4(Method::Multiscale, &ex, &geometry, scale);
        eprintln!("light {i}: textons pf4 {ours:.3}, plain multiscale {theirs:.3}");
        assert!(
            ours <= 1.2 * theirs,
            "light {i}: pf4 {ours} > 1.2 x {theirs}"
        );
    }

    // The pictures `render --light` draws differ too.
    let opts = |l: DVec3| surfsynth::render::RenderOptions {
        width: 96,
        height: 72,
        light: Some(l.to_array()),
        ..Default::default()
    };
    let la = DVec3::new(1.0, 1.0, 0.4);
    let (pa, _) = surfsynth::render::render_dir(&out, &opts(la)).unwrap();
    let (pb, _) =
        surfsynth::render::render_dir(&out, &opts(la * DVec3::new(-1.0, 1.0, -1.0))).unwrap();
    let differ = pa
        .rgb
        .iter()
        .zip(&pb.rgb)
        .filter(|(x, y)| (0..3).any(|c| (x[c] - y[c]).abs() > 0.05))
        .count();
    assert!(
        differ > pa.rgb.len() / 10,
        "{differ} of {} pixels differ",
        pa.rgb.len()
    );
}

#[test]
fn textons_do_not_depend_on_the_thread_count_and_are_cached() {
    let tmp = tempfile::tempdir().unwrap();
    let hf = HeightField::bumps(32, 4.0, 3);
    let (s, _) = generate::sample(&hf, &generate::light_directions(8));
    let json = generate::write(&tmp.path().join("s"), &s, serde_json::json!({})).unwrap();
    let cache = tmp.path().join("cache");
    let run = |threads: usize, cache: CacheDir| {
        Synthesizer::new(data(SPOT), ExampleSource::Btf(json.clone()))
            .method(Method::Textons)
            .resolution(8)
            .seed(5)
            .threads(threads)
            .cache(cache)
            .run()
            .unwrap()
    };
    let one = run(1, CacheDir::Off).maps;
    let three = run(3, CacheDir::Dir(cache.clone())).maps;
    for ((na, da), (nb, db)) in one.channels.iter().zip(&three.channels) {
        assert_eq!(na, nb);
        assert!(
            da.iter().zip(db).all(|(x, y)| x.to_bits() == y.to_bits()),
            "channel {na} differs between 1 and 3 threads"
        );
    }
    let names: Vec<String> = std::fs::read_dir(&cache)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    for kind in ["textons-", "texton-model-"] {
        assert!(
            names.iter().any(|n| n.starts_with(kind)),
            "no {kind} entry in {names:?}"
        );
    }
    // From the cache: the same result.
    let again = run(2, CacheDir::Dir(cache)).maps;
    assert_eq!(again.channels, one.channels);
}

/// Runs the binary's `synth --btf JSON`; returns (exit code, stderr).
fn synth_btf(json: &Path, out: &Path) -> (i32, String) {
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_surfsynth"))
        .args(["synth", "--mesh"])
        .arg(data(SPOT))
        .arg("--btf")
        .arg(json)
        .args(["--resolution", "4", "--no-cache", "--out"])
        .arg(out)
        .output()
        .unwrap();
    (
        o.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&o.stderr).into_owned(),
    )
}

fn png(path: &Path, w: u32, h: u32) {
    image::RgbImage::from_pixel(w, h, image::Rgb([90, 120, 150]))
        .save(path)
        .unwrap();
}

#[test]
fn bad_btf_inputs_are_one_line_errors_naming_the_file_and_leave_no_output() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    png(&d.join("a.png"), 16, 16);
    png(&d.join("b.png"), 17, 16);
    let cases: [(&str, &str, &str); 4] = [
        (
            "malformed.json",
            "{ \"images\": [ {\"file\": \"a.png\", ",
            "malformed.json",
        ),
        (
            "missing.json",
            r#"{"images": [{"file": "a.png", "light": [0, 0, 1]}, {"file": "nope.png", "light": [1, 0, 1]}]}"#,
            "nope.png",
        ),
        (
            "sizes.json",
            r#"{"images": [{"file": "a.png", "light": [0, 0, 1]}, {"file": "b.png", "light": [1, 0, 1]}]}"#,
            "b.png",
        ),
        (
            "light.json",
            r#"{"images": [{"file": "a.png", "light": [0, 0, 0]}]}"#,
            "light.json",
        ),
    ];
    for (name, text, named) in cases {
        let json = d.join(name);
        std::fs::write(&json, text).unwrap();
        let out = d.join(format!("out-{name}"));
        let (code, err) = synth_btf(&json, &out);
        assert_eq!(code, 1, "{name}: {err}");
        let lines: Vec<&str> = err.lines().collect();
        assert_eq!(lines.len(), 1, "{name}: {err}");
        assert!(
            lines[0].starts_with("error: ") && lines[0].contains(named),
            "{name}: {err}"
        );
        assert!(!out.exists(), "{name}: {} was created", out.display());
    }
    // Multiscale matches one image: refused before any work, naming the way out.
    let good = d.join("good.json");
    std::fs::write(
        &good,
        r#"{"images": [{"file": "a.png", "light": [0, 0, 1]}]}"#,
    )
    .unwrap();
    let out = d.join("out-multiscale");
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_surfsynth"))
        .args(["synth", "--mesh"])
        .arg(data(SPOT))
        .arg("--btf")
        .arg(&good)
        .args([
            "--method",
            "multiscale",
            "--resolution",
            "4",
            "--no-cache",
            "--out",
        ])
        .arg(&out)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_ne!(o.status.code(), Some(0), "{err}");
    assert_eq!(err.lines().count(), 1, "{err}");
    assert!(err.contains("--method textons"), "{err}");
    assert!(!out.exists(), "{} was created", out.display());
}

#[test]
fn a_session_with_the_sample_equals_the_one_shot_btf_run() {
    // Merged with prepared sessions: `--btf` is the session's synthesis with
    // `Settings::btf` set, so a session given the loaded sample is bit-identical.
    use std::sync::Arc;
    use surfsynth::synth::Analyses;
    use surfsynth::synthesizer::{MeshSettings, Session, SynthParams};
    let tmp = tempfile::tempdir().unwrap();
    let hf = HeightField::bumps(32, 4.0, 3);
    let (s, _) = generate::sample(&hf, &generate::light_directions(8));
    let json = generate::write(&tmp.path().join("s"), &s, serde_json::json!({})).unwrap();
    let one_shot = Synthesizer::new(data(SPOT), ExampleSource::Btf(json.clone()))
        .orientation(MeshSettings::default().orientation)
        .resolution(8)
        .seed(5)
        .method(Method::Textons)
        .cache(CacheDir::Off)
        .run()
        .unwrap();
    let settings = MeshSettings {
        resolution: 8,
        ..MeshSettings::default()
    };
    let session = Session::prepare(data(SPOT), &settings)
        .unwrap()
        .with_analyses(Arc::new(Analyses::new(&CacheDir::Off)));
    let sample = BtfSample::load(&json).unwrap();
    let mut params = SynthParams {
        seed: 5,
        ..SynthParams::new(Method::Textons)
    };
    params.settings.btf = Some(Arc::new(sample.clone()));
    let a = session.synthesize(&sample.example(), &params).unwrap();
    assert_eq!(a.maps.channels.len(), one_shot.maps.channels.len());
    for ((na, da), (nb, db)) in a.maps.channels.iter().zip(&one_shot.maps.channels) {
        assert_eq!(na, nb);
        assert!(
            da.iter().zip(db).all(|(x, y)| x.to_bits() == y.to_bits()),
            "channel {na} differs between the session and the one-shot run"
        );
    }
    assert!(one_shot.report.inputs.btf.is_some());
    assert_eq!(a.report.inputs.btf, one_shot.report.inputs.btf);
    let details = |r: &surfsynth::synthesizer::SynthResult| {
        let mut v = serde_json::to_value(&r.report.details).unwrap();
        // Seconds are not part of the result.
        strip_seconds(&mut v);
        v
    };
    assert_eq!(details(&a), details(&one_shot));
    assert!(
        serde_json::to_string(&a.report.details)
            .unwrap()
            .contains("textons"),
        "the report names the texton stats"
    );
}

fn strip_seconds(v: &mut serde_json::Value) {
    match v {
        serde_json::Value::Object(m) => {
            m.retain(|k, _| !k.contains("seconds"));
            m.values_mut().for_each(strip_seconds);
        }
        serde_json::Value::Array(a) => a.iter_mut().for_each(strip_seconds),
        _ => {}
    }
}

/// Measurement, not a check (`--ignored`): texton synthesis per embedding dimension count
/// (`TextonParams::dims`; `TEXTON_DIMS`, default "8,4") against a plain multiscale synthesis
/// of each light's image, on Spot and the double torus, seeds 1–2, at the benchmark's size
/// (the krita relief's 64² crop, 32 lights, N = 32; `BTF_SIZE`, `BTF_LIGHTS`, `BTF_N`
/// override). Prints pf4 and pf8 of the result relit under lights 0 and L/4 (20°
/// elevation, opposite azimuths: the acceptance test's pair) and the synthesis seconds;
/// docs/btf.md has the table.
#[test]
#[ignore]
fn texton_dims_per_light_measured() {
    let dims: Vec<usize> = std::env::var("TEXTON_DIMS")
        .unwrap_or_else(|_| "8,4".into())
        .split(',')
        .map(|s| s.trim().parse().unwrap())
        .collect();
    let size = common::env_or("BTF_SIZE", 64usize);
    let lights = common::env_or("BTF_LIGHTS", 32usize);
    let n = common::env_or("BTF_N", 32usize);
    let tmp = tempfile::tempdir().unwrap();
    let hf = HeightField::load(&data("textures/krita_bump_relief.png"), Some(size), 5.0).unwrap();
    let (s, _) = generate::sample(&hf, &generate::light_directions(lights));
    let json = generate::write(&tmp.path().join("sample"), &s, serde_json::json!({})).unwrap();
    let sample = BtfSample::load(&json).unwrap();
    let pair = [0, lights / 4];
    for mesh in [SPOT, "meshes/double_torus_genus2.obj"] {
        for seed in [1u64, 2] {
            let mut plain = Vec::new();
            for &i in &pair {
                let ex = sample.images[i].clone();
                let r = Synthesizer::new(data(mesh), ex.clone())
                    .method(Method::Multiscale)
                    .resolution(n)
                    .seed(seed)
                    .cache(CacheDir::Off)
                    .run()
                    .unwrap();
                let g = r.geometry_maps();
                let pf = surfsynth::eval::patch_fidelities(&r.maps, &g, &ex, Some(r.report.scale));
                plain.push((pf.pf4.unwrap(), pf.pf8.unwrap()));
            }
            for &d in &dims {
                let b = Synthesizer::new(data(mesh), ExampleSource::Btf(json.clone()))
                    .method(Method::Textons)
                    .resolution(n)
                    .seed(seed)
                    .cache(CacheDir::Off);
                let mut settings = b.current_settings().clone();
                settings.textons.dims = d;
                let t0 = std::time::Instant::now();
                let r = b.settings(settings).run().unwrap();
                let secs = t0.elapsed().as_secs_f64();
                let g = r.geometry_maps();
                for (k, &i) in pair.iter().enumerate() {
                    let ex = sample.images[i].clone();
                    let pf = surfsynth::eval::patch_fidelities(
                        &relit(&r.maps, &sample, i),
                        &g,
                        &ex,
                        Some(r.report.scale),
                    );
                    let (p4, p8) = (pf.pf4.unwrap(), pf.pf8.unwrap());
                    println!(
                        "{mesh} seed {seed} dims {d} light {i}: pf4 {p4:.3} pf8 {p8:.3} | plain {:.3} {:.3} | ratio pf4 {:.2} pf8 {:.2} | {secs:.1} s",
                        plain[k].0,
                        plain[k].1,
                        p4 / plain[k].0,
                        p8 / plain[k].1
                    );
                }
            }
        }
    }
}

/// The shadow test of every BTF result: where a source pixel is shadowed under light `a` and lit under `b` (or
/// the reverse), the two relit results differ much more than where both light it. Returns
/// (mean difference in shadow-changing texels, mean difference in lit texels).
fn shadow_contrast(
    maps: &FaceMaps,
    sample: &BtfSample,
    shadows: &[Vec<bool>],
    (a, b): (usize, usize),
) -> (f64, f64) {
    let (ma, mb) = (relit(maps, sample, a), relit(maps, sample, b));
    let su = maps.channel("source.u").unwrap();
    let sv = maps.channel("source.v").unwrap();
    let lum = |m: &FaceMaps, t: usize| {
        m.channel("R").unwrap()[t] + m.channel("G").unwrap()[t] + m.channel("B").unwrap()[t]
    };
    let (mut sd, mut sn, mut ld, mut ln) = (0f64, 0usize, 0f64, 0usize);
    for t in 0..su.len() {
        let (x, y) = (su[t] as usize, sv[t] as usize);
        let p = y.min(SIZE - 1) * SIZE + x.min(SIZE - 1);
        let d = (lum(&ma, t) - lum(&mb, t)).abs() as f64;
        match (shadows[a][p], shadows[b][p]) {
            (true, false) | (false, true) => {
                sd += d;
                sn += 1
            }
            (false, false) => {
                ld += d;
                ln += 1
            }
            _ => {}
        }
    }
    assert!(sn > su.len() / 20, "too few shadowed texels: {sn}");
    (sd / sn as f64, ld / ln as f64)
}

/// Texture optimisation over a BTF sample (`--btf --method optimise`: every image matched
/// at once in the reflectance space, `synth::matching::reflectance`): one mesostructure
/// under every light (the shadow test above), and under each light pf4 within 1.2x of a
/// plain texture optimisation of that light's image alone — and no worse than texton
/// synthesis of the same sample.
#[test]
fn optimise_over_a_btf_keeps_one_structure_under_every_light() {
    let tmp = tempfile::tempdir().unwrap();
    let (json, shadows) = krita_sample(tmp.path());
    let sample = BtfSample::load(&json).unwrap();
    let run = |method: Method| {
        Synthesizer::new(data(SPOT), ExampleSource::Btf(json.clone()))
            .method(method)
            .resolution(N)
            .seed(2)
            .cache(CacheDir::Off)
            .run()
            .unwrap()
    };
    let r = run(Method::Optimise);
    assert_eq!(r.report.method, Method::Optimise);
    let geometry = r.geometry_maps();
    let scale = r.report.scale;
    let (a, b) = (0, LIGHTS / 4);
    let (sd, ld) = shadow_contrast(&r.maps, &sample, &shadows, (a, b));
    assert!(
        sd > 2.0 * ld && sd > 0.1,
        "shadow difference {sd} vs lit {ld}"
    );
    let textons = run(Method::Textons);
    for i in [a, b] {
        let ex = sample.images[i].clone();
        let ours = pf4(&relit(&r.maps, &sample, i), &geometry, &ex, scale);
        let theirs = plain_pf4(Method::Optimise, &ex, &geometry, scale);
        let tex = pf4(&relit(&textons.maps, &sample, i), &geometry, &ex, scale);
        eprintln!("light {i}: optimise over the BTF pf4 {ours:.3}, plain optimise {theirs:.3}, textons {tex:.3}");
        assert!(
            ours <= 1.2 * theirs,
            "light {i}: pf4 {ours} > 1.2 x {theirs}"
        );
        assert!(ours <= tex, "light {i}: pf4 {ours} > textons' {tex}");
    }
}

/// Every appearance-space method over a BTF sample gives the same bits for any thread
/// count; a sample of one image is matched exactly as that image alone; multiscale, whose
/// pyramid sees one image, is refused with a pointer to textons.
#[test]
fn methods_over_a_btf_are_deterministic_and_one_image_is_the_plain_example() {
    let tmp = tempfile::tempdir().unwrap();
    let hf = HeightField::bumps(32, 4.0, 3);
    let (s, _) = generate::sample(&hf, &generate::light_directions(8));
    let json = generate::write(&tmp.path().join("s"), &s, serde_json::json!({})).unwrap();
    let run = |source: ExampleSource, method: Method, threads: usize| {
        Synthesizer::new(data(SPOT), source)
            .method(method)
            .resolution(8)
            .seed(5)
            .threads(threads)
            .cache(CacheDir::Off)
            .run()
    };
    for method in [
        Method::Optimise,
        Method::Patches,
        Method::Coherent,
        Method::Jump,
    ] {
        let one = run(ExampleSource::Btf(json.clone()), method, 1).unwrap();
        let two = run(ExampleSource::Btf(json.clone()), method, 2).unwrap();
        assert_eq!(
            one.maps.channels, two.maps.channels,
            "{method:?}: 1 vs 2 threads"
        );
        let info = one.report.appearance.reflectance.expect("reported");
        assert_eq!((info.images, info.dims), (8, 8), "{method:?}");
        assert!(info.kept_variance > 0.9, "{method:?}: {info:?}");
    }
    // `--appearance rgb` compares the leading 5 values of the reflectance vectors.
    let rgb = Synthesizer::new(data(SPOT), ExampleSource::Btf(json.clone()))
        .method(Method::Optimise)
        .appearance(surfsynth::synthesizer::AppearanceMode::Rgb)
        .resolution(8)
        .seed(5)
        .cache(CacheDir::Off)
        .run()
        .unwrap();
    assert_eq!(rgb.report.appearance.reflectance.map(|r| r.dims), Some(5));
    // One image: its reflectance is its colour, so the run is the plain example's.
    let single = BtfSample::from_images(vec![s.images[3].clone()], vec![s.lights[3]]).unwrap();
    let json1 = generate::write(&tmp.path().join("one"), &single, serde_json::json!({})).unwrap();
    let btf = run(ExampleSource::Btf(json1.clone()), Method::Optimise, 2).unwrap();
    let plain = run(
        ExampleSource::from(BtfSample::load(&json1).unwrap().example()),
        Method::Optimise,
        2,
    )
    .unwrap();
    let src = |m: &FaceMaps| {
        (
            m.channel("source.u").unwrap().to_vec(),
            m.channel("source.v").unwrap().to_vec(),
        )
    };
    assert_eq!(src(&btf.maps), src(&plain.maps));
    let err = run(ExampleSource::Btf(json), Method::Multiscale, 2)
        .unwrap_err()
        .to_string();
    assert!(err.contains("--method textons"), "{err}");
    assert!(!err.contains('\n'), "{err}");
}

/// Measurement, not a check (`--ignored`): every method over a BTF sample (`BTF_METHODS`,
/// default all five), relit under lights 0 and L/4, against a plain synthesis of that
/// light's image with the same method (textons: multiscale), on Spot and the double torus
/// (seed `BTF_SEED`, default 1). The sample: `BTF_HEIGHT` (a grayscale texture of
/// ../shared, default the krita relief) cropped to `BTF_SIZE` (64), `BTF_DEPTH` pixels deep
/// (5), `BTF_LIGHTS` lights (32); N = `BTF_N` (32). docs/btf.md has the table.
#[test]
#[ignore]
fn btf_methods_per_light_measured() {
    let methods: Vec<String> = std::env::var("BTF_METHODS")
        .unwrap_or_else(|_| "optimise,patches,coherent,jump,textons".into())
        .split(',')
        .map(|s| s.trim().to_string())
        .collect();
    let height =
        std::env::var("BTF_HEIGHT").unwrap_or_else(|_| "textures/krita_bump_relief.png".into());
    let size = common::env_or("BTF_SIZE", 64usize);
    let depth = common::env_or("BTF_DEPTH", 5.0f32);
    let lights = common::env_or("BTF_LIGHTS", 32usize);
    let n = common::env_or("BTF_N", 32usize);
    let seed = common::env_or("BTF_SEED", 1u64);
    let tmp = tempfile::tempdir().unwrap();
    let hf = HeightField::load(&data(&height), Some(size), depth).unwrap();
    let (s, _) = generate::sample(&hf, &generate::light_directions(lights));
    let json = generate::write(&tmp.path().join("sample"), &s, serde_json::json!({})).unwrap();
    let sample = BtfSample::load(&json).unwrap();
    let pair = [0, lights / 4];
    let parse = |m: &str| match m {
        "optimise" => Method::Optimise,
        "patches" => Method::Patches,
        "coherent" => Method::Coherent,
        "jump" => Method::Jump,
        "textons" => Method::Textons,
        _ => panic!("unknown method {m}"),
    };
    for mesh in [SPOT, "meshes/double_torus_genus2.obj"] {
        for m in &methods {
            let method = parse(m);
            let t0 = std::time::Instant::now();
            let r = Synthesizer::new(data(mesh), ExampleSource::Btf(json.clone()))
                .method(method)
                .resolution(n)
                .seed(seed)
                .cache(CacheDir::Off)
                .run()
                .unwrap();
            let secs = t0.elapsed().as_secs_f64();
            let g = r.geometry_maps();
            for &i in &pair {
                let ex = sample.images[i].clone();
                let plain_method = if method == Method::Textons {
                    Method::Multiscale
                } else {
                    method
                };
                let p = Synthesizer::new(data(mesh), ex.clone())
                    .method(plain_method)
                    .resolution(n)
                    .seed(seed)
                    .cache(CacheDir::Off)
                    .run()
                    .unwrap();
                let pp = surfsynth::eval::patch_fidelities(&p.maps, &g, &ex, Some(r.report.scale));
                let pf = surfsynth::eval::patch_fidelities(
                    &relit(&r.maps, &sample, i),
                    &g,
                    &ex,
                    Some(r.report.scale),
                );
                let (p4, p8) = (pf.pf4.unwrap(), pf.pf8.unwrap());
                let (q4, q8) = (pp.pf4.unwrap(), pp.pf8.unwrap());
                println!(
                    "{mesh} {m} light {i}: pf4 {p4:.3} pf8 {p8:.3} | plain {q4:.3} {q8:.3} | ratio pf4 {:.2} pf8 {:.2} | {secs:.1} s",
                    p4 / q4,
                    p8 / q8
                );
            }
        }
    }
}
