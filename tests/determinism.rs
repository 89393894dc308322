//! Determinism of `surfsynth synth` (issue 6, item 5): the same inputs and seed give
//! byte-identical output files whatever the number of threads and however often it runs;
//! another seed gives another texture. report.json is excluded (it holds timings and the
//! thread count).
//!
//! Small on purpose (a 17-domain mesh with extraordinary vertices and triangles, N = 16) so
//! it runs in a few seconds; tests/synth.rs checks facemaps.exr on the Spot fixture too.

use std::path::{Path, PathBuf};
use std::process::Command;

/// The files that must not depend on threads or on the run.
const FILES: [&str; 7] = [
    "facemaps.exr",
    "geometry.exr",
    "atlas.png",
    "surface.obj",
    "surface.mtl",
    "facemaps.ptx",
    "surface.glb",
];

/// A cube whose top face is a fan of four triangles around a centre vertex: valence-3
/// corners, triangles (n-gon domains), 5 + 4 x 3 = 17 domains.
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

/// FNV-1a, 64 bits: a stable hash to print (equality is checked on the bytes).
fn fnv(bytes: &[u8]) -> u64 {
    bytes.iter().fold(0xcbf2_9ce4_8422_2325u64, |h, &b| {
        (h ^ b as u64).wrapping_mul(0x0000_0100_0000_01b3)
    })
}

/// Runs `synth` and returns the bytes of [`FILES`].
fn synth(
    mesh: &Path,
    example: &Path,
    extra: &[&str],
    threads: u32,
    seed: u64,
    out: &Path,
) -> Vec<Vec<u8>> {
    let o = Command::new(env!("CARGO_BIN_EXE_surfsynth"))
        .arg("--threads")
        .arg(threads.to_string())
        .arg("synth")
        .arg("--mesh")
        .arg(mesh)
        .arg("--example")
        .arg(example)
        .args(["--resolution", "16", "--seed", &seed.to_string()])
        .args(extra)
        .arg("--out")
        .arg(out)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let report = surfsynth::report::read(out).unwrap();
    assert_eq!(
        report["threads"], threads as u64,
        "ran on {threads} threads"
    );
    assert_eq!(report["seed"], seed);
    FILES
        .iter()
        .map(|f| std::fs::read(out.join(f)).unwrap_or_else(|e| panic!("{f}: {e}")))
        .collect()
}

fn assert_same(a: &[Vec<u8>], b: &[Vec<u8>], what: &str) {
    for ((name, x), y) in FILES.iter().zip(a).zip(b) {
        assert!(!x.is_empty(), "{name} is empty");
        assert!(
            x == y,
            "{name} differs ({what}): {} bytes, hash {:016x} vs {} bytes, hash {:016x}",
            x.len(),
            fnv(x),
            y.len(),
            fnv(y)
        );
    }
}

#[test]
fn same_seed_gives_identical_files_for_any_thread_count_and_run() {
    let dir = tempfile::tempdir().unwrap();
    let mesh = dir.path().join("cube_fan.obj");
    std::fs::write(&mesh, CUBE_FAN).unwrap();
    let ex = fixture("gravel.png");
    let run =
        |t: u32, seed: u64, name: &str| synth(&mesh, &ex, &[], t, seed, &dir.path().join(name));

    let one = run(1, 7, "t1");
    let two = run(2, 7, "t2");
    let again = run(2, 7, "t2-again");
    assert_same(&one, &two, "--threads 1 vs --threads 2");
    assert_same(&two, &again, "two runs with --threads 2");

    // Another seed: other facemaps (a different texture), the same geometry.
    let other = run(2, 8, "seed8");
    assert!(one[0] != other[0], "facemaps.exr must depend on the seed");
    assert_eq!(one[1], other[1], "geometry.exr does not depend on the seed");
    // Not just a header difference: most texels' colours differ.
    let maps = |name: &str| {
        surfsynth::io::exr::read_face_maps(dir.path().join(name).join("facemaps.exr")).unwrap()
    };
    let (a, b) = (maps("t1"), maps("seed8"));
    let (ra, rb) = (a.channel("R").unwrap(), b.channel("R").unwrap());
    assert_eq!(ra.len(), 17 * 16 * 16);
    let differ = ra.iter().zip(rb).filter(|(x, y)| x != y).count();
    assert!(
        differ * 2 > ra.len(),
        "only {differ} of {} texels differ",
        ra.len()
    );
}

#[test]
fn alpha_and_height_channels_are_deterministic_too() {
    let dir = tempfile::tempdir().unwrap();
    let mesh = dir.path().join("cube_fan.obj");
    std::fs::write(&mesh, CUBE_FAN).unwrap();
    // A 32x32 RGBA example and a height map of the same size, generated.
    let ex = dir.path().join("rgba.png");
    let h = dir.path().join("height.png");
    image::RgbaImage::from_fn(32, 32, |x, y| {
        let v = ((x * 37 + y * 11) ^ (x * y)) as u8;
        image::Rgba([v, v.wrapping_mul(3), 255 - v, 128 + (v >> 1)])
    })
    .save(&ex)
    .unwrap();
    image::GrayImage::from_fn(32, 32, |x, y| image::Luma([((x + 2 * y) * 4) as u8]))
        .save(&h)
        .unwrap();
    let hs = h.to_str().unwrap();
    let one = synth(&mesh, &ex, &["--height", hs], 1, 3, &dir.path().join("t1"));
    let two = synth(&mesh, &ex, &["--height", hs], 2, 3, &dir.path().join("t2"));
    assert_same(&one, &two, "RGBA + height, --threads 1 vs 2");
    let maps =
        surfsynth::io::exr::read_face_maps(dir.path().join("t1").join("facemaps.exr")).unwrap();
    for c in ["A", "height"] {
        assert!(maps.channel(c).is_some(), "facemaps.exr has {c}");
    }
}

/// The feature-distance channel (`--feature-distance`) for the two kinds of matcher that
/// take it differently: through the weighted example (optimise) and through multiscale's
/// own pyramid.
#[test]
fn feature_distance_is_deterministic_too() {
    let dir = tempfile::tempdir().unwrap();
    let mesh = dir.path().join("cube_fan.obj");
    std::fs::write(&mesh, CUBE_FAN).unwrap();
    let ex = fixture("gravel.png");
    for method in ["optimise", "multiscale"] {
        let extra = [
            "--method",
            method,
            "--feature-distance",
            "0.5",
            "--no-cache",
        ];
        let run = |t: u32| {
            synth(
                &mesh,
                &ex,
                &extra,
                t,
                3,
                &dir.path().join(format!("{method}{t}")),
            )
        };
        assert_same(
            &run(1),
            &run(2),
            &format!("{method}: --threads 1 vs --threads 2"),
        );
    }
}
