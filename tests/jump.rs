//! Jump-map synthesis (issue 14, paper 002) and the saved analysis cache: BRIEF's quality
//! bar on shared meshes, thread-count independence, sinks and sources in the field, and
//! cache hits, misses and corrupt entries.

mod common;

use common::data;
use glam::DVec3;
use std::path::{Path, PathBuf};
use std::sync::{Arc, OnceLock};
use subdiv::{ControlMesh, Surface};
use surfsynth::field::Orientation;
use surfsynth::synth::analysis::Source;
use surfsynth::synth::Analyses;
use surfsynth::synthesizer::{CacheDir, MeshSource, Method, SynthResult, Synthesizer};

fn fixture(rel: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("fixtures")
        .join(rel)
}

/// One store of jump maps for every run of this binary (no disk cache): each example is
/// analysed once.
fn analyses() -> Arc<Analyses> {
    static A: OnceLock<Arc<Analyses>> = OnceLock::new();
    A.get_or_init(|| Arc::new(Analyses::new(&CacheDir::Off)))
        .clone()
}

fn run(
    mesh: impl Into<MeshSource>,
    example: impl AsRef<Path>,
    n: usize,
    orientation: Orientation,
    seed: u64,
) -> SynthResult {
    Synthesizer::new(mesh, example.as_ref())
        .method(Method::Jump)
        .resolution(n)
        .orientation(orientation)
        .seed(seed)
        .analyses(analyses())
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

/// BRIEF's bar (issue 14): coverage 1, seam ratio ≤ `seam_max` (1.2), scale fidelity
/// median 1 ± 0.05.
fn assert_bar_with(what: &str, r: &SynthResult, seam_max: f64) {
    let q = quality(r);
    let seam = q.seam_ratio.unwrap();
    let sf = q.scale_fidelity.unwrap();
    eprintln!(
        "{what}: coverage {} seam {seam:.3} scale median {:.4} p10-p90 {:.3}-{:.3} coherent {:.3} pf1 {:.3} pf4 {:.3} pf8 {:.3}",
        q.coverage,
        sf.median,
        sf.p10,
        sf.p90,
        q.coherent_fraction.unwrap(),
        q.pf1.unwrap_or(f64::NAN),
        q.pf4.unwrap_or(f64::NAN),
        q.pf8.unwrap_or(f64::NAN),
    );
    assert_eq!(q.coverage, 1.0, "{what}");
    assert!(seam <= seam_max, "{what}: seam ratio {seam}");
    assert!((sf.median - 1.0).abs() <= 0.05, "{what}: {sf:?}");
}

fn assert_bar(what: &str, r: &SynthResult) {
    assert_bar_with(what, r, 1.2);
}

fn stats(r: &SynthResult) -> surfsynth::synth::jump::Stats {
    match &r.report.details {
        surfsynth::synth::Details::Jump { stats, .. } => stats.clone(),
        d => panic!("not a jump report: {d:?}"),
    }
}

/// The inputs: the flat 16x16 grid at N = 32 along +x and Spot, with a brick, a
/// reptile-scale and a gravel example (pf1/pf4/pf8 printed, docs/jump.md has them beside
/// the other methods).
#[test]
fn jump_meets_the_bar_on_the_flat_grid_and_spot() {
    let examples = [
        data("textures/skimage_brick.png"),
        data("textures/krita_reptile_scales.png"),
        fixture("gravel.png"),
    ];
    for example in &examples {
        let name = example.file_name().unwrap().to_string_lossy();
        let grid = Surface::new(ControlMesh::grid(16));
        let r = run(grid, example, 32, Orientation::Axis(DVec3::X), 1);
        assert_bar(&format!("grid N = 32 +x, {name}"), &r);
        let r = run(
            fixture("spot_control_mesh.obj").as_path(),
            example,
            32,
            Orientation::Auto,
            1,
        );
        // The smooth, high-contrast reptile example measured 1.37–1.49 on Spot while the
        // growth filled one face after another (its regions met along face edges); grown
        // by geodesic distance, 0.95 (docs/jump.md, "Growth order"): the bar holds.
        assert_bar(&format!("spot N = 32, {name}"), &r);
        let s = stats(&r);
        assert_eq!(s.texels, r.report.texels);
        assert!(s.jumps > 0 && s.continuations > s.jumps * 10, "{s:?}");
    }
}

/// Other shared meshes (open boundaries, genus 2) at a low resolution.
#[test]
fn jump_meets_the_bar_on_other_shared_meshes() {
    for (mesh, example) in [
        (
            data("meshes/double_torus_genus2.obj"),
            fixture("gravel.png"),
        ),
        (
            data("meshes/cube_no_bottom.obj"),
            data("textures/gimp_burlap_weave.png"),
        ),
    ] {
        let r = run(mesh.as_path(), &example, 16, Orientation::Auto, 3);
        assert_bar(&mesh.display().to_string(), &r);
    }
}

#[test]
fn jump_is_bit_identical_for_any_thread_count() {
    let go = |t: usize| {
        Synthesizer::new(fixture("spot_control_mesh.obj"), fixture("gravel.png"))
            .method(Method::Jump)
            .resolution(12)
            .seed(9)
            .threads(t)
            .cache(CacheDir::Off)
            .run()
            .unwrap()
    };
    let (a, b) = (go(1), go(2));
    for c in ["R", "G", "B", "source.u", "source.v"] {
        let (x, y) = (a.maps.channel(c).unwrap(), b.maps.channel(c).unwrap());
        assert!(
            x.iter().zip(y).all(|(p, q)| p.to_bits() == q.to_bits()),
            "channel {c} differs"
        );
    }
    // Another seed is another texture.
    let c = Synthesizer::new(fixture("spot_control_mesh.obj"), fixture("gravel.png"))
        .method(Method::Jump)
        .resolution(12)
        .seed(10)
        .cache(CacheDir::Off)
        .run()
        .unwrap();
    assert_ne!(a.maps.channel("source.u"), c.maps.channel("source.u"));
}

/// 002 §3: sinks and sources place the field's singularities; the continuation rule must
/// keep the scale around them.
#[test]
fn jump_with_sinks_and_sources() {
    let dir = tempfile::tempdir().unwrap();
    let c = dir.path().join("spot.field");
    // Spot's head is towards +x... a sink at the nose, a source at the tail.
    std::fs::write(&c, "sink 0.7 0.3 0.0\nsource -0.6 0.3 0.0\n").unwrap();
    let r = Synthesizer::new(fixture("spot_control_mesh.obj"), fixture("gravel.png"))
        .method(Method::Jump)
        .resolution(16)
        .orientation(Orientation::Constraints(c))
        .cache(CacheDir::Off)
        .run()
        .unwrap();
    assert_bar("spot with a sink and a source", &r);
}

/// The centre 64x64 of the bundled gravel, in memory: the cache's behaviour does not depend
/// on the example's size, and multiscale's model of the whole 128² takes most of this file's
/// time otherwise.
fn small_gravel() -> surfsynth::example::Example {
    let g = surfsynth::example::Example::load(fixture("gravel.png")).unwrap();
    let (s, x0, y0) = (64, (g.width - 64) / 2, (g.height - 64) / 2);
    let rgb = (0..s * s)
        .map(|i| g.rgb[(y0 + i / s) * g.width + x0 + i % s])
        .collect();
    surfsynth::example::Example::from_linear(s, s, rgb)
}

fn cached(dir: &Path, method: Method) -> SynthResult {
    Synthesizer::new(fixture("spot_control_mesh.obj"), small_gravel())
        .method(method)
        .resolution(8)
        .seed(4)
        .cache(CacheDir::Dir(dir.to_path_buf()))
        .run()
        .unwrap()
}

fn sources(r: &SynthResult) -> Vec<Source> {
    r.report.cache.entries.iter().map(|e| e.source).collect()
}

#[test]
fn cache_hits_and_rebuilds_corrupt_entries() {
    let dir = tempfile::tempdir().unwrap();
    // Coherent first: its appearance space is the jump map's too, which then hits.
    for method in [Method::Coherent, Method::Jump, Method::Multiscale] {
        let first = cached(dir.path(), method);
        assert!(
            !first.report.cache.hit,
            "{method:?}: {:?}",
            first.report.cache
        );
        assert!(sources(&first).contains(&Source::Miss), "{method:?}");
        let second = cached(dir.path(), method);
        assert!(
            second.report.cache.hit,
            "{method:?}: {:?}",
            second.report.cache
        );
        assert_eq!(
            first.maps.channel("source.u"),
            second.maps.channel("source.u"),
            "{method:?}: a cached analysis gives the same result"
        );
    }
    // Damage every entry in a different way: truncated, a flipped payload byte, garbage.
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "bin"))
        .collect();
    files.sort();
    assert!(files.len() >= 3, "{files:?}");
    for (i, f) in files.iter().enumerate() {
        let mut b = std::fs::read(f).unwrap();
        match i % 3 {
            0 => b.truncate(b.len() / 2),
            1 => {
                let k = b.len() - 7;
                b[k] ^= 0x10;
            }
            _ => b = b"not a cache file at all".to_vec(),
        }
        std::fs::write(f, b).unwrap();
    }
    for method in [Method::Jump, Method::Multiscale] {
        let clean = Synthesizer::new(fixture("spot_control_mesh.obj"), small_gravel())
            .method(method)
            .resolution(8)
            .seed(4)
            .cache(CacheDir::Off)
            .run()
            .unwrap();
        let r = cached(dir.path(), method);
        assert!(
            sources(&r).contains(&Source::Rebuilt),
            "{method:?}: {:?}",
            r.report.cache
        );
        assert_eq!(clean.maps.channel("source.u"), r.maps.channel("source.u"));
        // Rewritten: the next run hits.
        assert!(cached(dir.path(), method).report.cache.hit);
    }
}

fn cli(args: &[&std::ffi::OsStr]) -> std::process::Output {
    std::process::Command::new(env!("CARGO_BIN_EXE_surfsynth"))
        .args(args)
        .output()
        .unwrap()
}

/// From the command line: a second run hits (report.json says so), a corrupted entry is
/// rebuilt with exactly one warning line and the same result.
#[test]
fn cli_cache_hit_and_one_warning_for_a_corrupt_entry() {
    let tmp = tempfile::tempdir().unwrap();
    let cache = tmp.path().join("cache");
    let synth = |out: &str| {
        let out = tmp.path().join(out);
        let mesh = fixture("spot_control_mesh.obj");
        let example = fixture("gravel.png");
        let o = cli(&[
            "synth".as_ref(),
            "--mesh".as_ref(),
            mesh.as_os_str(),
            "--example".as_ref(),
            example.as_os_str(),
            "--method".as_ref(),
            "jump".as_ref(),
            "--resolution".as_ref(),
            "8".as_ref(),
            "--cache".as_ref(),
            cache.as_os_str(),
            "--out".as_ref(),
            out.as_os_str(),
        ]);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let report = surfsynth::report::read(&out).unwrap();
        let warnings: Vec<String> = String::from_utf8_lossy(&o.stderr)
            .lines()
            .filter(|l| l.starts_with("warning:"))
            .map(String::from)
            .collect();
        (report, warnings)
    };
    let (first, w) = synth("a");
    assert_eq!(first["cache"]["hit"], false);
    assert!(w.is_empty(), "{w:?}");
    let (second, w) = synth("b");
    assert_eq!(second["cache"]["hit"], true, "{}", second["cache"]);
    assert!(w.is_empty(), "{w:?}");
    let map = std::fs::read_dir(&cache)
        .unwrap()
        .map(|e| e.unwrap().path())
        .find(|p| {
            p.file_name()
                .unwrap()
                .to_string_lossy()
                .starts_with("jumpmap-")
        })
        .expect("a saved jump map");
    let mut bytes = std::fs::read(&map).unwrap();
    let k = bytes.len() / 2;
    bytes[k] ^= 0x55;
    std::fs::write(&map, bytes).unwrap();
    let (third, w) = synth("c");
    assert_eq!(w.len(), 1, "{w:?}");
    assert!(w[0].contains("rebuilding"), "{w:?}");
    assert_eq!(third["cache"]["hit"], false);
    let sources: Vec<&str> = third["cache"]["entries"]
        .as_array()
        .unwrap()
        .iter()
        .map(|e| e["source"].as_str().unwrap())
        .collect();
    assert_eq!(sources, ["hit", "rebuilt"]);
    let maps = |d: &str| std::fs::read(tmp.path().join(d).join("facemaps.exr")).unwrap();
    assert_eq!(maps("a"), maps("c"));
}

/// The memory guard's jump estimate against the measured peak (as g02 in
/// bad_input_matrix.rs does for the default method): Spot, N = 32, a cache miss.
#[test]
fn jump_memory_estimate_is_close_to_the_peak() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("out");
    let mesh = fixture("spot_control_mesh.obj");
    let example = fixture("gravel.png");
    let o = cli(&[
        "synth".as_ref(),
        "--mesh".as_ref(),
        mesh.as_os_str(),
        "--example".as_ref(),
        example.as_os_str(),
        "--method".as_ref(),
        "jump".as_ref(),
        "--resolution".as_ref(),
        "32".as_ref(),
        "--no-cache".as_ref(),
        "--out".as_ref(),
        out.as_os_str(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let report = surfsynth::report::read(&out).unwrap();
    let Some(peak) = report["peak_memory_bytes"].as_u64() else {
        return; // no /proc: nothing to compare with
    };
    let control = ControlMesh::load_obj(&mesh).unwrap();
    let size = surfsynth::memory::MeshSize::of(&control);
    let job = surfsynth::memory::Job::Synth {
        channels: 5,
        example_pixels: 128 * 128,
        method: Method::Jump,
        displace: false,
        scale_map: false,
    };
    let est = surfsynth::memory::estimate(&size, 32, &job).bytes;
    let ratio = est as f64 / peak as f64;
    assert!(
        (0.8..1.6).contains(&ratio),
        "estimate {est} vs measured peak {peak}: ratio {ratio:.2}"
    );
}
