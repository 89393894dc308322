//! Prepared sessions (issue 14, item 4): one prepared mesh, many syntheses, each
//! bit-identical to the one-shot run with the same inputs — for several methods and two
//! seeds, syntheses interleaved so that nothing one leaves behind can change the next.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use surfsynth::cache::CacheDir;
use surfsynth::example::Example;
use surfsynth::synth::Analyses;
use surfsynth::synthesizer::{
    MeshSettings, Method, Session, SynthParams, SynthResult, Synthesizer,
};

const N: usize = 12;

/// A cube whose top face is a fan of four triangles around a centre vertex: valence-3
/// corners, triangles (n-gon domains), 17 domains (small, so every method runs fast).
const CUBE_FAN: &str = "\
v -1 -1 -1\nv 1 -1 -1\nv 1 1 -1\nv -1 1 -1\n\
v -1 -1 1\nv 1 -1 1\nv 1 1 1\nv -1 1 1\nv 0 0 1.3\n\
f 1 4 3 2\nf 1 2 6 5\nf 2 3 7 6\nf 3 4 8 7\nf 4 1 5 8\n\
f 5 6 9\nf 6 7 9\nf 7 8 9\nf 8 5 9\n";

fn fixture(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("fixtures")
        .join(name)
}

/// The mesh, written once per process.
fn mesh() -> PathBuf {
    static DIR: std::sync::OnceLock<tempfile::TempDir> = std::sync::OnceLock::new();
    let dir = DIR.get_or_init(|| {
        let d = tempfile::tempdir().unwrap();
        std::fs::write(d.path().join("cube_fan.obj"), CUBE_FAN).unwrap();
        d
    });
    dir.path().join("cube_fan.obj")
}

/// The one-shot runs share an analysis store of their own (the session has another), so
/// only the first run of a method analyses the example.
fn one_shot(method: Method, seed: u64) -> SynthResult {
    static ANALYSES: std::sync::OnceLock<Arc<Analyses>> = std::sync::OnceLock::new();
    let analyses = ANALYSES.get_or_init(|| Arc::new(Analyses::new(&CacheDir::Off)));
    // The session's field (a prepared mesh has one, whatever the method), not the method's own.
    Synthesizer::new(mesh(), example())
        .method(method)
        .orientation(MeshSettings::default().orientation)
        .resolution(N)
        .seed(seed)
        .analyses(analyses.clone())
        .run()
        .unwrap()
}

/// The centre 48x48 of the bundled gravel (in memory: small, so multiscale is quick).
fn example() -> Example {
    let g = Example::load(fixture("gravel.png")).unwrap();
    let (s, x0, y0) = (48, (g.width - 48) / 2, (g.height - 48) / 2);
    let rgb = (0..s * s)
        .map(|i| g.rgb[(y0 + i / s) * g.width + x0 + i % s])
        .collect();
    Example::from_linear(s, s, rgb)
}

fn session() -> Session {
    let settings = MeshSettings {
        resolution: N,
        ..MeshSettings::default()
    };
    Session::prepare(mesh(), &settings)
        .unwrap()
        .with_analyses(Arc::new(Analyses::new(&CacheDir::Off)))
}

/// Every channel, bit for bit.
fn bits(r: &SynthResult) -> Vec<(String, Vec<u32>)> {
    r.maps
        .channels
        .iter()
        .map(|(name, data)| (name.clone(), data.iter().map(|v| v.to_bits()).collect()))
        .collect()
}

#[test]
fn session_outputs_equal_one_shot_runs() {
    let s = session();
    let example = example();
    let mut seen: Vec<Vec<(String, Vec<u32>)>> = Vec::new();
    for seed in [1, 7] {
        for method in [
            Method::Jump,
            Method::Coherent,
            Method::Patches,
            Method::Optimise,
            Method::Multiscale,
        ] {
            let params = SynthParams {
                seed,
                ..SynthParams::new(method)
            };
            let a = s.synthesize(&example, &params).unwrap();
            let b = one_shot(method, seed);
            assert_eq!(a.report.method, method);
            assert_eq!(a.report.texels, b.report.texels);
            assert_eq!(a.report.scale, b.report.scale);
            assert!(
                bits(&a) == bits(&b),
                "{} seed {seed}: session maps differ from the one-shot run",
                method.name()
            );
            assert_eq!(a.geometry.pos, b.geometry.pos);
            assert_eq!(a.geometry.normal, b.geometry.normal);
            // The prepared stages are not paid again.
            assert_eq!(a.report.seconds.field, 0.0);
            seen.push(bits(&a));
        }
    }
    // Not a constant: another seed gives other maps for every method.
    for m in 0..5 {
        assert!(seen[m] != seen[m + 5], "method {m}: seeds 1 and 7 agree");
    }
}

#[test]
fn session_files_equal_one_shot_files() {
    let s = session();
    let example = example();
    let dir = tempfile::tempdir().unwrap();
    let (a, b) = (dir.path().join("session"), dir.path().join("one-shot"));
    let params = SynthParams {
        seed: 3,
        ..SynthParams::new(Method::Coherent)
    };
    s.synthesize(&example, &params).unwrap().write(&a).unwrap();
    one_shot(Method::Coherent, 3).write(&b).unwrap();
    for f in [
        "facemaps.exr",
        "geometry.exr",
        "facemaps.ptx",
        "atlas.png",
        "surface.obj",
    ] {
        let (x, y) = (
            std::fs::read(a.join(f)).unwrap(),
            std::fs::read(b.join(f)).unwrap(),
        );
        assert!(
            x == y,
            "{f} differs between the session and the one-shot run"
        );
    }
}

#[test]
fn a_second_synthesis_reuses_the_example_analysis() {
    let s = session();
    let example = example();
    let params = SynthParams::new(Method::Jump);
    let first = s.synthesize(&example, &params).unwrap();
    assert!(!first.report.cache.hit, "nothing was analysed before");
    let second = s
        .synthesize(
            &example,
            &SynthParams {
                seed: 2,
                ..params.clone()
            },
        )
        .unwrap();
    assert!(second.report.cache.hit, "{:?}", second.report.cache);
    // The session shares its mesh data with its results instead of copying it.
    assert!(Arc::ptr_eq(&first.geometry, &second.geometry));
}

/// Building the example's analysis shows as its own stage, counting the jump map's pixels
/// up to all of them, before the domains; a synthesis that finds the analysis in memory
/// goes straight to the domains.
#[test]
fn analyses_being_built_report_progress() {
    use std::sync::Mutex;
    use surfsynth::synthesizer::Stage;
    let seen: Arc<Mutex<Vec<(Stage, usize, usize)>>> = Arc::default();
    let log = seen.clone();
    let s = session().on_progress(move |st, d, t| log.lock().unwrap().push((st, d, t)));
    let example = example();
    let params = SynthParams::new(Method::Jump);
    s.synthesize(&example, &params).unwrap();
    let first = std::mem::take(&mut *seen.lock().unwrap());
    let analysis: Vec<(usize, usize)> = first
        .iter()
        .filter(|e| e.0 == Stage::Analysis)
        .map(|e| (e.1, e.2))
        .collect();
    let pixels = example.width * example.height;
    assert!(analysis.contains(&(pixels, pixels)), "{analysis:?}");
    assert_eq!(analysis.last(), Some(&(1, 1)), "{analysis:?}");
    let first_domains = first.iter().position(|e| e.0 == Stage::Synthesis).unwrap();
    let last_analysis = first.iter().rposition(|e| e.0 == Stage::Analysis).unwrap();
    assert!(first_domains < last_analysis, "announced, then analysed");
    assert!(first.iter().rposition(|e| e.0 == Stage::Synthesis).unwrap() > last_analysis);
    s.synthesize(&example, &SynthParams { seed: 2, ..params })
        .unwrap();
    let second = seen.lock().unwrap();
    assert!(second.iter().all(|e| e.0 != Stage::Analysis), "{second:?}");
    assert!(second.iter().any(|e| e.0 == Stage::Synthesis));
}

#[test]
fn session_errors_are_one_line() {
    let settings = MeshSettings {
        resolution: 0,
        ..MeshSettings::default()
    };
    let e = Session::prepare(mesh(), &settings).unwrap_err();
    assert!(
        e.to_string().contains("resolution 0 is out of range"),
        "{e}"
    );
    let e = Session::prepare(fixture("nowhere.obj"), &MeshSettings::default()).unwrap_err();
    assert!(!e.to_string().contains('\n'), "{e}");
    // --displace without a height channel, refused by the session as by the CLI.
    let s = session();
    let example = example();
    let params = SynthParams {
        displace: Some(0.1),
        ..SynthParams::new(Method::Coherent)
    };
    let e = s.synthesize(&example, &params).unwrap_err();
    assert!(e.to_string().contains("needs a height channel"), "{e}");
}

#[test]
fn a_mesh_far_from_unit_size_gives_the_one_shot_result_in_its_own_units() {
    // Scaled by 2^20: processed at unit size, written in the user's units (the session
    // rebuilds the surface and geometry for writing once, on first use).
    let dir = tempfile::tempdir().unwrap();
    let big = dir.path().join("big.obj");
    let text: String = CUBE_FAN
        .lines()
        .map(|l| match l.strip_prefix("v ") {
            Some(v) => {
                let c: Vec<String> = v
                    .split_whitespace()
                    .map(|x| (x.parse::<f64>().unwrap() * 1048576.0).to_string())
                    .collect();
                format!("v {}\n", c.join(" "))
            }
            None => format!("{l}\n"),
        })
        .collect();
    std::fs::write(&big, text).unwrap();
    let settings = MeshSettings {
        resolution: N,
        ..MeshSettings::default()
    };
    let s = Session::prepare(big.as_path(), &settings)
        .unwrap()
        .with_analyses(Arc::new(Analyses::new(&CacheDir::Off)));
    let params = SynthParams::new(Method::Jump);
    let a = s.synthesize(&example(), &params).unwrap();
    let b = Synthesizer::new(big.as_path(), example())
        .method(Method::Jump)
        .orientation(settings.orientation.clone())
        .resolution(N)
        .cache(CacheDir::Off)
        .run()
        .unwrap();
    assert!(bits(&a) == bits(&b));
    assert_eq!(a.geometry.pos, b.geometry.pos);
    assert_eq!(a.report.scale, b.report.scale);
    assert!(a.geometry.pos.iter().any(|p| p.x.abs() > 1e5), "user units");
}

/// Per-face resolutions (`--texel-size`) flow through the session: every method gives the
/// one-shot run's maps and files bit for bit, in the user's units for a mesh far from unit
/// size too.
#[test]
fn texel_size_sessions_equal_one_shot_runs() {
    const L: f64 = 0.15;
    let dir = tempfile::tempdir().unwrap();
    let big = dir.path().join("big.obj");
    let text: String = CUBE_FAN
        .lines()
        .map(|l| match l.strip_prefix("v ") {
            Some(v) => {
                let c: Vec<String> = v
                    .split_whitespace()
                    .map(|x| (x.parse::<f64>().unwrap() * 1048576.0).to_string())
                    .collect();
                format!("v {}\n", c.join(" "))
            }
            None => format!("{l}\n"),
        })
        .collect();
    std::fs::write(&big, text).unwrap();
    let example = example();
    for (mesh, l) in [(mesh(), L), (big.clone(), L * 1048576.0)] {
        let settings = MeshSettings {
            texel_size: Some(l),
            ..MeshSettings::default()
        };
        let s = Session::prepare(mesh.as_path(), &settings)
            .unwrap()
            .with_analyses(Arc::new(Analyses::new(&CacheDir::Off)));
        assert!(s.layout().uniform_n().is_none(), "per-face resolutions");
        for method in [
            Method::Jump,
            Method::Coherent,
            Method::Patches,
            Method::Optimise,
            Method::Multiscale,
            Method::Textons,
        ] {
            let params = SynthParams {
                seed: 5,
                ..SynthParams::new(method)
            };
            let a = s.synthesize(&example, &params).unwrap();
            let b = Synthesizer::new(mesh.as_path(), example.clone())
                .method(method)
                .orientation(settings.orientation.clone())
                .texel_size(l)
                .seed(5)
                .cache(CacheDir::Off)
                .run()
                .unwrap();
            assert_eq!(a.report.texels, b.report.texels);
            assert_eq!(a.report.texels, s.texels() as u64);
            assert_eq!(a.report.texel_size, Some(l));
            assert_eq!(a.report.scale, b.report.scale);
            assert!(
                bits(&a) == bits(&b),
                "{} at texel size {l}: session maps differ from the one-shot run",
                method.name()
            );
            assert_eq!(a.geometry.layout, b.geometry.layout);
            assert_eq!(a.geometry.pos, b.geometry.pos);
            assert_eq!(a.geometry.normal, b.geometry.normal);
            if method == Method::Coherent {
                let out = tempfile::tempdir().unwrap();
                let (x, y) = (out.path().join("session"), out.path().join("one-shot"));
                a.write(&x).unwrap();
                b.write(&y).unwrap();
                for f in [
                    "facemaps.exr",
                    "geometry.exr",
                    "facemaps.ptx",
                    "atlas.png",
                    "surface.obj",
                ] {
                    assert!(
                        std::fs::read(x.join(f)).unwrap() == std::fs::read(y.join(f)).unwrap(),
                        "{f} differs between the session and the one-shot run"
                    );
                }
            }
        }
    }
    let e = Session::prepare(
        mesh(),
        &MeshSettings {
            texel_size: Some(-1.0),
            ..MeshSettings::default()
        },
    )
    .unwrap_err();
    assert!(e.to_string().contains("texel size -1"), "{e}");
}

/// `threads(Some(t))` bounds the whole run, its writing included: the measure that runs
/// beside the writers sees the run's pool of `t` workers (it saw the caller's pool before
/// the writing moved into it). Three, so that no machine's default pool passes by chance
/// unless it has exactly three cores.
#[test]
fn a_private_pool_holds_the_writing_too() {
    use std::sync::atomic::{AtomicUsize, Ordering};
    let out = tempfile::tempdir().unwrap();
    let seen = AtomicUsize::new(0);
    Synthesizer::new(mesh(), example())
        .method(Method::Coherent)
        .resolution(N)
        .seed(1)
        .threads(3)
        .run_to_with(out.path().join("result"), |_| {
            seen.store(rayon::current_num_threads(), Ordering::SeqCst);
            |_: &mut surfsynth::report::Report| {}
        })
        .unwrap();
    assert_eq!(seen.load(Ordering::SeqCst), 3);
}
