//! Fuzzing the two readers of untrusted files (issue 6, item 3): the OBJ reader
//! (`subdiv::ControlMesh::parse_obj` + `subdiv::Surface::new`) and the example loader
//! (`surfsynth::example::Example::load` / `load_with_height`). Properties:
//!
//! - nothing panics: every input gives `Ok` or an `Err` with a one-line message;
//! - a mesh that is accepted builds a surface whose limit evaluates to finite positions
//!   and derivatives everywhere (and finite unit normals where the surface is not
//!   degenerate), at corners, edges and inside every domain;
//! - an example that is accepted is at least 8x8, has one linear RGB value in 0..1 per
//!   pixel (alpha and height likewise).
//!
//! Inputs are generated from an OBJ grammar with hostile tokens, by mutating valid meshes
//! and images (byte edits, truncation, splicing; PNG chunk CRCs are repaired afterwards so
//! the mutations reach the decoder instead of stopping at the checksum), and as raw bytes.
//!
//! Runs in CI with a small case count (3000 per OBJ property, 1500 per example property;
//! ~15 s on 2 cores). For a long local run set `FUZZ_CASES` (cases per property, 8
//! properties; `--nocapture` prints accepted/refused counts), e.g.
//! `FUZZ_CASES=200000 FUZZ_SEED=random cargo test --release --test fuzz_inputs -- --nocapture`
//! (without `FUZZ_SEED` the seed is fixed, so CI explores the same inputs every run).
//! The cargo-fuzz targets in fuzz/ exercise the same entry points (docs/robustness.md).

use proptest::prelude::*;
use proptest::test_runner::{Config, RngSeed};
use std::cell::RefCell;
use std::path::PathBuf;
use subdiv::{ControlMesh, DomainId, Surface};
use surfsynth::example::Example;

/// Cases per property: `FUZZ_CASES` or `default`.
fn cases(default: u32) -> u32 {
    std::env::var("FUZZ_CASES")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(default)
}

/// The random seed: fixed by default so CI runs the same inputs every time; `FUZZ_SEED`
/// sets another (`FUZZ_SEED=random` for a fresh one per run, as long runs should).
fn seed() -> RngSeed {
    match std::env::var("FUZZ_SEED") {
        Ok(s) if s == "random" => RngSeed::Random,
        Ok(s) => RngSeed::Fixed(s.parse().expect("FUZZ_SEED: a number or 'random'")),
        Err(_) => RngSeed::Fixed(0x5EED_5EED),
    }
}

fn config(default: u32) -> Config {
    let cases = cases(default);
    Config {
        rng_seed: seed(),
        cases,
        // Failures print the minimal input; do not write regression files into the tree.
        failure_persistence: None,
        // Shrinking a generated mesh can take many minutes; a few thousand steps suffice.
        max_shrink_iters: 4096,
        ..Config::default()
    }
}

/// Accepted / refused counts per property, printed (with `--nocapture`) when a property
/// has run all its cases: a fuzzer whose inputs are all refused at the first check tests
/// little, so the counts are part of the output.
struct Stats {
    name: &'static str,
    cases: u32,
    ok: std::sync::atomic::AtomicU32,
    err: std::sync::atomic::AtomicU32,
}

impl Stats {
    const fn new(name: &'static str) -> Self {
        Self {
            name,
            cases: 0,
            ok: std::sync::atomic::AtomicU32::new(0),
            err: std::sync::atomic::AtomicU32::new(0),
        }
    }

    fn count(&self, accepted: bool, default_cases: u32) {
        use std::sync::atomic::Ordering::Relaxed;
        let _ = self.cases;
        if accepted {
            self.ok.fetch_add(1, Relaxed);
        } else {
            self.err.fetch_add(1, Relaxed);
        }
        let (ok, err) = (self.ok.load(Relaxed), self.err.load(Relaxed));
        if ok + err == cases(default_cases) {
            println!(
                "fuzz {}: {} cases, {ok} accepted, {err} refused",
                self.name,
                ok + err
            );
        }
    }
}

// ------------------------------------------------------------------------------ meshes

/// Parses `text`; when accepted, builds the surface and checks its limit evaluation:
/// finite positions and derivatives; normals finite and either unit or exactly zero (the
/// library's "no tangent plane here" at degenerate points, e.g. coincident vertices) —
/// with `strict`, for meshes that cannot be degenerate, always unit.
/// Returns whether the mesh was accepted.
fn check_obj(text: &str, strict: bool) -> Result<bool, TestCaseError> {
    let control = match ControlMesh::parse_obj(text) {
        Ok(c) => c,
        Err(e) => {
            let msg = e.to_string();
            prop_assert!(!msg.is_empty() && !msg.contains('\n'), "message {msg:?}");
            return Ok(false);
        }
    };
    let big = control
        .mesh
        .positions
        .iter()
        .map(|p| p.abs().max_element())
        .fold(0.0f64, f64::max);
    prop_assert!(big.is_finite(), "accepted a non-finite coordinate");
    let surface = Surface::new(control);
    let domains = surface.num_domains();
    prop_assert!(domains > 0);
    // Coordinates near f64::MAX may legitimately overflow in the subdivision sums.
    if big > 1e150 {
        return Ok(true);
    }
    let params = [0.0, 1e-9, 0.25, 0.5, 0.999_999, 1.0];
    for d in (0..domains).step_by(domains.div_ceil(12)) {
        for &u in &params {
            for &v in &params {
                let s = surface.eval(DomainId(d as u32), u, v);
                prop_assert!(
                    s.p.is_finite() && s.du.is_finite() && s.dv.is_finite(),
                    "domain {d} ({u}, {v}): {s:?}"
                );
                let len = s.n.length();
                let unit = (len - 1.0).abs() < 1e-6;
                prop_assert!(
                    s.n.is_finite() && (unit || (len == 0.0 && !strict)),
                    "domain {d} ({u}, {v}): normal {:?}",
                    s.n
                );
            }
        }
    }
    Ok(true)
}

/// A number token: mostly ordinary, sometimes hostile.
fn coord() -> impl Strategy<Value = String> {
    prop_oneof![
        8 => (-4.0f64..4.0).prop_map(|x| format!("{x}")),
        2 => (-3i32..4).prop_map(|x| x.to_string()),
        1 => prop::sample::select(vec![
            "nan", "NaN", "inf", "-inf", "infinity", "1e400", "-1e400", "1e308", "1e-320",
            "-0", "0x10", "1.5.2", "", "abc", "+3", ".5", "5.", "1e", "--1", "1_000",
        ])
        .prop_map(String::from),
    ]
}

/// A face-vertex reference.
fn index() -> impl Strategy<Value = String> {
    prop_oneof![
        10 => (1i64..12).prop_map(|i| i.to_string()),
        2 => (-12i64..0).prop_map(|i| i.to_string()),
        2 => ((1i64..12), (1i64..5)).prop_map(|(i, t)| format!("{i}/{t}")),
        1 => ((1i64..12), (1i64..5)).prop_map(|(i, n)| format!("{i}//{n}")),
        1 => ((1i64..12), (1i64..5), (1i64..5)).prop_map(|(i, t, n)| format!("{i}/{t}/{n}")),
        1 => prop::sample::select(vec![
            "0", "99999999999999999999", "4294967296", "-4294967297", "-", "/", "1/", "/1",
            "a", "1.5", "", "+2",
        ])
        .prop_map(String::from),
    ]
}

fn obj_line() -> impl Strategy<Value = String> {
    prop_oneof![
        6 => prop::collection::vec(coord(), 3..=4).prop_map(|c| format!("v {}", c.join(" "))),
        1 => prop::collection::vec(coord(), 0..=5).prop_map(|c| format!("v {}", c.join(" "))),
        5 => prop::collection::vec(index(), 3..=6).prop_map(|f| format!("f {}", f.join(" "))),
        1 => prop::collection::vec(index(), 0..=9).prop_map(|f| format!("f {}", f.join(" "))),
        1 => prop::sample::select(vec![
            "", "# comment", "vt 0 0", "vn 0 0 1", "g group", "o object", "s off",
            "usemtl m", "mtllib m.mtl", "t crease 2/1/0 1 2 5.0", "f", "v", "l 1 2",
            "vv 1 2 3", "f# 1 2 3", "\t", "v 1 2 3 # trailing", "\u{feff}v 0 0 0",
        ])
        .prop_map(String::from),
    ]
}

/// Valid meshes to mutate: closed, open, with triangles, n-gons and extraordinary
/// vertices.
const SEEDS: [&str; 5] = [
    // Cube (valence-3 corners).
    "v -1 -1 -1\nv 1 -1 -1\nv 1 1 -1\nv -1 1 -1\nv -1 -1 1\nv 1 -1 1\nv 1 1 1\nv -1 1 1\n\
     f 1 4 3 2\nf 1 2 6 5\nf 2 3 7 6\nf 3 4 8 7\nf 4 1 5 8\nf 5 6 7 8\n",
    // Cube whose top is a fan of triangles.
    "v -1 -1 -1\nv 1 -1 -1\nv 1 1 -1\nv -1 1 -1\nv -1 -1 1\nv 1 -1 1\nv 1 1 1\nv -1 1 1\n\
     v 0 0 1.3\nf 1 4 3 2\nf 1 2 6 5\nf 2 3 7 6\nf 3 4 8 7\nf 4 1 5 8\nf 5 6 9\nf 6 7 9\n\
     f 7 8 9\nf 8 5 9\n",
    // Open 2x2 grid.
    "v 0 0 0\nv 1 0 0\nv 2 0 0\nv 0 1 0\nv 1 1 0.3\nv 2 1 0\nv 0 2 0\nv 1 2 0\nv 2 2 0\n\
     f 1 2 5 4\nf 2 3 6 5\nf 4 5 8 7\nf 5 6 9 8\n",
    // One triangle, with texture coordinates and normals.
    "v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 0 1\nvn 0 0 1\nf 1/1/1 2/2/1 3/3/1\n",
    // Pentagon and quads sharing edges, negative indices.
    "v 0 0 0\nv 2 0 0\nv 3 1.5 0\nv 1 3 0\nv -1 1.5 0\nv 2 -2 0\nv 0 -2 0\n\
     f 1 2 3 4 5\nf -1 -2 2 1\n",
];

#[derive(Clone, Debug)]
enum Edit {
    /// Delete `len` bytes at `at` (positions are taken modulo the length).
    Delete { at: usize, len: usize },
    /// Insert bytes at `at`.
    Insert { at: usize, bytes: Vec<u8> },
    /// Overwrite one byte.
    Set { at: usize, byte: u8 },
    /// Flip one bit.
    Flip { at: usize, bit: u8 },
    /// Cut everything after `at`.
    Truncate { at: usize },
    /// Copy a range to another place (duplicates lines, chunks, tokens).
    Splice { from: usize, len: usize, to: usize },
}

fn edit() -> impl Strategy<Value = Edit> {
    let at = any::<usize>();
    prop_oneof![
        3 => (at, 1usize..16).prop_map(|(at, len)| Edit::Delete { at, len }),
        3 => (at, prop::collection::vec(edit_byte(), 1..8))
            .prop_map(|(at, bytes)| Edit::Insert { at, bytes }),
        3 => (at, edit_byte()).prop_map(|(at, byte)| Edit::Set { at, byte }),
        2 => (at, 0u8..8).prop_map(|(at, bit)| Edit::Flip { at, bit }),
        1 => at.prop_map(|at| Edit::Truncate { at }),
        2 => (at, 1usize..64, at).prop_map(|(from, len, to)| Edit::Splice { from, len, to }),
    ]
}

/// Bytes that matter to parsers more often than uniformly random ones.
fn edit_byte() -> impl Strategy<Value = u8> {
    prop_oneof![
        2 => any::<u8>(),
        3 => prop::sample::select(
            b"0123456789-+.eE \t\n\r/#vfnai\x00\xff".to_vec()
        ),
    ]
}

fn apply(data: &mut Vec<u8>, e: &Edit) {
    let n = data.len();
    let pos = |p: usize| if n == 0 { 0 } else { p % (n + 1) };
    match e {
        Edit::Delete { at, len } => {
            if n > 0 {
                let a = at % n;
                data.drain(a..(a + len).min(n));
            }
        }
        Edit::Insert { at, bytes } => {
            let a = pos(*at);
            data.splice(a..a, bytes.iter().copied());
        }
        Edit::Set { at, byte } => {
            if n > 0 {
                data[at % n] = *byte;
            }
        }
        Edit::Flip { at, bit } => {
            if n > 0 {
                data[at % n] ^= 1 << bit;
            }
        }
        Edit::Truncate { at } => data.truncate(pos(*at)),
        Edit::Splice { from, len, to } => {
            if n > 0 {
                let a = from % n;
                let piece: Vec<u8> = data[a..(a + len).min(n)].to_vec();
                let t = pos(*to);
                data.splice(t..t, piece);
            }
        }
    }
}

/// A generated mesh: a grid of nx x ny cells, optionally wrapped into a cylinder or a
/// torus, each cell a quad, two triangles, a reversed quad (orientation conflict) or a
/// hole; vertex heights random, sometimes snapped to a few values (coincident and
/// collinear points); now and then a hostile line. About half of these are valid meshes
/// with boundaries, holes, triangles and extraordinary vertices.
#[derive(Clone, Debug)]
struct GridMesh {
    nx: usize,
    ny: usize,
    wrap_x: bool,
    wrap_y: bool,
    cells: Vec<u8>,
    heights: Vec<f64>,
    snap: bool,
    negative_refs: bool,
    junk: Option<(usize, String)>,
}

fn grid_mesh() -> impl Strategy<Value = GridMesh> {
    (1usize..6, 1usize..6, any::<bool>(), any::<bool>()).prop_flat_map(|(nx, ny, wx, wy)| {
        let cell = prop_oneof![10 => Just(0u8), 4 => Just(1u8), 1 => Just(2u8), 1 => Just(3u8)];
        (
            prop::collection::vec(cell, nx * ny),
            prop::collection::vec(-1.0f64..1.0, (nx + 1) * (ny + 1)),
            prop::bool::weighted(0.15),
            any::<bool>(),
            prop::option::weighted(0.1, (any::<usize>(), obj_line())),
        )
            .prop_map(
                move |(cells, heights, snap, negative_refs, junk)| GridMesh {
                    nx,
                    ny,
                    // Wrapping needs 3 cells around, or the mesh is not manifold anyway.
                    wrap_x: wx && nx >= 3,
                    wrap_y: wy && ny >= 3,
                    cells,
                    heights,
                    snap,
                    negative_refs,
                    junk,
                },
            )
    })
}

impl GridMesh {
    fn obj(&self) -> String {
        let (nx, ny) = (self.nx, self.ny);
        let mut lines = Vec::new();
        let vid = |i: usize, j: usize| {
            let i = if self.wrap_x { i % nx } else { i };
            let j = if self.wrap_y { j % ny } else { j };
            j * (nx + 1) + i
        };
        let tau = std::f64::consts::TAU;
        for j in 0..=ny {
            for i in 0..=nx {
                let mut z = self.heights[j * (nx + 1) + i];
                if self.snap {
                    z = (z * 2.0).round() * 0.5;
                }
                let (x, y) = (i as f64, j as f64);
                let p = match (self.wrap_x, self.wrap_y) {
                    (false, false) => [x, y, z],
                    (true, false) => {
                        let a = tau * x / nx as f64;
                        let r = 2.0 + 0.3 * z;
                        [r * a.cos(), r * a.sin(), y]
                    }
                    (_, true) => {
                        let (a, b) = (tau * x / nx as f64, tau * y / ny as f64);
                        let r = 3.0 + (1.0 + 0.2 * z) * b.cos();
                        [r * a.cos(), r * a.sin(), (1.0 + 0.2 * z) * b.sin()]
                    }
                };
                lines.push(format!("v {} {} {}", p[0], p[1], p[2]));
            }
        }
        let nv = (nx + 1) * (ny + 1);
        let r = |v: usize| {
            if self.negative_refs {
                format!("-{}", nv - v)
            } else {
                (v + 1).to_string()
            }
        };
        for j in 0..ny {
            for i in 0..nx {
                let (a, b, c, d) = (vid(i, j), vid(i + 1, j), vid(i + 1, j + 1), vid(i, j + 1));
                match self.cells[j * nx + i] {
                    0 => lines.push(format!("f {} {} {} {}", r(a), r(b), r(c), r(d))),
                    1 => {
                        lines.push(format!("f {} {} {}", r(a), r(b), r(c)));
                        lines.push(format!("f {} {} {}", r(a), r(c), r(d)));
                    }
                    2 => lines.push(format!("f {} {} {} {}", r(d), r(c), r(b), r(a))),
                    _ => {}
                }
            }
        }
        if let Some((at, line)) = &self.junk {
            lines.insert(at % (lines.len() + 1), line.clone());
        }
        lines.join("\n")
    }
}

/// Default cases per OBJ property.
const OBJ_CASES: u32 = 3000;
static OBJ_GRAMMAR: Stats = Stats::new("obj_from_grammar");
static OBJ_GRID: Stats = Stats::new("obj_grid_meshes");
static OBJ_MUTATED: Stats = Stats::new("obj_mutated");
static OBJ_BYTES: Stats = Stats::new("obj_random_bytes");

proptest! {
    #![proptest_config(config(OBJ_CASES))]

    /// Grammar-generated OBJ text with hostile numbers and references.
    #[test]
    fn obj_from_grammar(lines in prop::collection::vec(obj_line(), 0..40), crlf in any::<bool>()) {
        let text = lines.join(if crlf { "\r\n" } else { "\n" });
        OBJ_GRAMMAR.count(check_obj(&text, false)?, OBJ_CASES);
    }

    /// Generated grids, cylinders and tori with triangles, holes and flipped faces.
    #[test]
    fn obj_grid_meshes(m in grid_mesh()) {
        // Distinct x, y per vertex and smooth heights: never degenerate unless snapped or
        // a junk line adds a face (e.g. `f 3 2 1` folds a triangle onto a quad: a closed
        // surface of zero volume, whose normal is zero at some points).
        OBJ_GRID.count(check_obj(&m.obj(), !m.snap && m.junk.is_none())?, OBJ_CASES);
    }

    /// Valid meshes with byte-level edits.
    #[test]
    fn obj_mutated(seed in 0..SEEDS.len(), edits in prop::collection::vec(edit(), 1..6)) {
        let mut data = SEEDS[seed].as_bytes().to_vec();
        for e in &edits {
            apply(&mut data, e);
        }
        OBJ_MUTATED.count(check_obj(&String::from_utf8_lossy(&data), false)?, OBJ_CASES);
    }

    /// Arbitrary bytes.
    #[test]
    fn obj_random_bytes(data in prop::collection::vec(any::<u8>(), 0..512)) {
        OBJ_BYTES.count(check_obj(&String::from_utf8_lossy(&data), false)?, OBJ_CASES);
    }
}

// ---------------------------------------------------------------------------- examples

thread_local! {
    /// One scratch directory per test thread; files are overwritten case after case.
    static SCRATCH: RefCell<Option<tempfile::TempDir>> = const { RefCell::new(None) };
}

fn scratch_file(name: &str, bytes: &[u8]) -> PathBuf {
    SCRATCH.with(|s| {
        let mut s = s.borrow_mut();
        let dir = s.get_or_insert_with(|| tempfile::tempdir().unwrap());
        let p = dir.path().join(name);
        std::fs::write(&p, bytes).unwrap();
        p
    })
}

/// Loads `bytes` as an example (and, when given, `height` as its height map) and checks
/// the result or the error. Returns whether it was accepted.
fn check_example(bytes: &[u8], height: Option<&[u8]>) -> Result<bool, TestCaseError> {
    let ex = scratch_file("example.png", bytes);
    let h = height.map(|b| scratch_file("height.png", b));
    let accepted = match Example::load_with_height(&ex, h.as_ref()) {
        Err(e) => {
            let msg = e.to_string();
            prop_assert!(!msg.contains('\n'), "one line: {msg:?}");
            prop_assert!(
                msg.contains("example.png") || msg.contains("height.png"),
                "{msg}"
            );
            false
        }
        Ok(e) => {
            let px = e.width * e.height;
            prop_assert!(e.width >= 8 && e.height >= 8, "{}x{}", e.width, e.height);
            prop_assert_eq!(e.rgb.len(), px);
            let unit = |v: f32| (0.0..=1.0).contains(&v);
            prop_assert!(e.rgb.iter().flatten().all(|&v| unit(v)), "rgb outside 0..1");
            if let Some(a) = &e.alpha {
                prop_assert_eq!(a.len(), px);
                prop_assert!(a.iter().all(|&v| unit(v)));
            }
            prop_assert_eq!(e.height_map().is_some(), height.is_some());
            if let Some(hm) = e.height_map() {
                prop_assert_eq!(hm.len(), px);
                prop_assert!(hm.iter().all(|&v| unit(v)));
            }
            let mut out = vec![0f32; e.num_channels()];
            e.bilinear(e.width as f32 * 0.37, e.height as f32 * 0.61, &mut out);
            prop_assert!(out.iter().all(|v| v.is_finite()));
            true
        }
    };
    Ok(accepted)
}

/// A small image of `kind` (gray, gray+alpha, RGB, RGBA; 8 or 16 bit) encoded as PNG
/// (or, for kind 8, JPEG).
fn encode(w: u32, h: u32, kind: u8, seed: u64) -> Vec<u8> {
    use image::{DynamicImage as D, ImageBuffer};
    let f = |x: u32, y: u32, c: u32| {
        let v = (x as u64 * 0x9E37 + y as u64 * 0x7F4A + c as u64 * 0x1234 + seed)
            .wrapping_mul(0x2545_F491_4F6C_DD1D);
        (v >> 40) as u16
    };
    let img = match kind % 9 {
        0 => D::ImageLuma8(ImageBuffer::from_fn(w, h, |x, y| {
            image::Luma([f(x, y, 0) as u8])
        })),
        1 => D::ImageLumaA8(ImageBuffer::from_fn(w, h, |x, y| {
            image::LumaA([f(x, y, 0) as u8, f(x, y, 1) as u8])
        })),
        2 => D::ImageRgb8(ImageBuffer::from_fn(w, h, |x, y| {
            image::Rgb([0, 1, 2].map(|c| f(x, y, c) as u8))
        })),
        3 => D::ImageRgba8(ImageBuffer::from_fn(w, h, |x, y| {
            image::Rgba([0, 1, 2, 3].map(|c| f(x, y, c) as u8))
        })),
        4 => D::ImageLuma16(ImageBuffer::from_fn(w, h, |x, y| image::Luma([f(x, y, 0)]))),
        5 => D::ImageLumaA16(ImageBuffer::from_fn(w, h, |x, y| {
            image::LumaA([f(x, y, 0), f(x, y, 1)])
        })),
        6 => D::ImageRgb16(ImageBuffer::from_fn(w, h, |x, y| {
            image::Rgb([0, 1, 2].map(|c| f(x, y, c)))
        })),
        7 => D::ImageRgba16(ImageBuffer::from_fn(w, h, |x, y| {
            image::Rgba([0, 1, 2, 3].map(|c| f(x, y, c)))
        })),
        _ => D::ImageRgb8(ImageBuffer::from_fn(w, h, |x, y| {
            image::Rgb([0, 1, 2].map(|c| f(x, y, c) as u8))
        })),
    };
    let format = if kind % 9 == 8 {
        image::ImageFormat::Jpeg
    } else {
        image::ImageFormat::Png
    };
    let mut v = Vec::new();
    img.write_to(&mut std::io::Cursor::new(&mut v), format)
        .unwrap();
    v
}

fn crc32(data: &[u8]) -> u32 {
    let mut c = 0xFFFF_FFFFu32;
    for &b in data {
        c ^= b as u32;
        for _ in 0..8 {
            c = if c & 1 != 0 {
                0xEDB8_8320 ^ (c >> 1)
            } else {
                c >> 1
            };
        }
    }
    !c
}

/// Recomputes the CRC of every complete PNG chunk, so that edits inside chunk data reach
/// the decoder instead of failing the checksum.
fn fix_png_crcs(data: &mut [u8]) {
    if data.len() < 8 || &data[..8] != b"\x89PNG\r\n\x1a\n" {
        return;
    }
    let mut at = 8;
    while at + 12 <= data.len() {
        let len = u32::from_be_bytes(data[at..at + 4].try_into().unwrap()) as usize;
        let end = match (at + 8).checked_add(len) {
            Some(e) if e + 4 <= data.len() => e,
            _ => return,
        };
        let crc = crc32(&data[at + 4..end]);
        data[end..end + 4].copy_from_slice(&crc.to_be_bytes());
        at = end + 4;
    }
}

fn png_chunk(kind: &[u8; 4], body: &[u8]) -> Vec<u8> {
    let mut v = (body.len() as u32).to_be_bytes().to_vec();
    let start = v.len();
    v.extend_from_slice(kind);
    v.extend_from_slice(body);
    let crc = crc32(&v[start..]);
    v.extend_from_slice(&crc.to_be_bytes());
    v
}

/// A zlib stream of `data` in stored (uncompressed) blocks.
fn zlib_stored(data: &[u8]) -> Vec<u8> {
    let mut v = vec![0x78, 0x01];
    let mut chunks = data.chunks(65535).peekable();
    if chunks.peek().is_none() {
        v.extend([1, 0, 0, 0xFF, 0xFF]);
    }
    while let Some(c) = chunks.next() {
        v.push(chunks.peek().is_none() as u8);
        let n = c.len() as u16;
        v.extend(n.to_le_bytes());
        v.extend((!n).to_le_bytes());
        v.extend_from_slice(c);
    }
    let (mut a, mut b) = (1u32, 0u32);
    for &x in data {
        a = (a + x as u32) % 65521;
        b = (b + a) % 65521;
    }
    v.extend(((b << 16) | a).to_be_bytes());
    v
}

/// Default cases per example property.
const EXAMPLE_CASES: u32 = 1500;
static EX_MUTATED: Stats = Stats::new("example_mutated");
static EX_STRUCTURE: Stats = Stats::new("example_png_structure");
static EX_HEIGHT: Stats = Stats::new("example_with_height");
static EX_BYTES: Stats = Stats::new("example_random_bytes");

/// Random filtered image data of the size a PNG header implies (a filter byte, `0..filters`,
/// before every row; Adam7 passes when interlaced); 3000 random bytes for headers that
/// are invalid or imply more than 1 MiB.
fn png_data(
    w: u32,
    h: u32,
    color: u8,
    depth: u8,
    interlace: u8,
    seed: u64,
    filters: u8,
) -> Vec<u8> {
    let channels = match color {
        0 | 3 => 1,
        2 => 3,
        4 => 2,
        6 => 4,
        _ => return noise(3000, seed),
    };
    let bits = channels * depth as u64;
    let row = |pw: u64| 1 + (pw * bits).div_ceil(8);
    let (w, h) = (w as u64, h as u64);
    // (row length, row count) of each pass.
    let passes: Vec<(u64, u64)> = match interlace {
        0 => vec![(row(w), h)],
        1 => [
            (0, 0, 8, 8),
            (4, 0, 8, 8),
            (0, 4, 4, 8),
            (2, 0, 4, 4),
            (0, 2, 2, 4),
            (1, 0, 2, 2),
            (0, 1, 1, 2),
        ]
        .iter()
        .map(|&(x0, y0, dx, dy)| {
            let pw = w.saturating_sub(x0).div_ceil(dx);
            let ph = h.saturating_sub(y0).div_ceil(dy);
            if pw == 0 || ph == 0 {
                (0, 0)
            } else {
                (row(pw), ph)
            }
        })
        .collect(),
        _ => return noise(3000, seed),
    };
    let total = passes
        .iter()
        .map(|(l, n)| l.saturating_mul(*n))
        .fold(0u64, u64::saturating_add);
    if total > 1 << 20 {
        return noise(3000, seed);
    }
    let mut data = noise(total as usize, seed);
    let mut at = 0usize;
    for (len, n) in passes {
        for _ in 0..n {
            data[at] %= filters;
            at += len as usize;
        }
    }
    data
}

/// Deterministic pseudo-random bytes (xorshift).
fn noise(len: usize, seed: u64) -> Vec<u8> {
    let mut s = seed | 1;
    (0..len)
        .map(|_| {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            (s >> 24) as u8
        })
        .collect()
}

proptest! {
    #![proptest_config(config(EXAMPLE_CASES))]

    /// Valid PNG/JPEG examples with byte edits (CRCs repaired half the time).
    #[test]
    fn example_mutated(
        w in 1u32..40, h in 1u32..40, kind in 0u8..9, seed in any::<u64>(),
        edits in prop::collection::vec(edit(), 0..5), fix in any::<bool>(),
    ) {
        let mut data = encode(w, h, kind, seed);
        for e in &edits {
            apply(&mut data, e);
        }
        if fix {
            fix_png_crcs(&mut data);
        }
        EX_MUTATED.count(check_example(&data, None)?, EXAMPLE_CASES);
    }

    /// Hand-built PNGs: header fields (size, bit depth, colour type, interlace) valid or
    /// not, and random image data that inflates to the size the header implies (or a few
    /// bytes more or less), with random filter bytes, so the decoder's row logic and our
    /// conversion of every pixel format are reached.
    #[test]
    fn example_png_structure(
        w in prop_oneof![6 => 1u32..40, 1 => Just(0u32), 1 => any::<u32>()],
        h in prop_oneof![6 => 1u32..40, 1 => Just(0u32), 1 => any::<u32>()],
        (color, depth) in prop_oneof![
            8 => prop::sample::select(vec![
                (0u8, 1u8), (0, 2), (0, 4), (0, 8), (0, 16), (2, 8), (2, 16), (3, 1), (3, 2),
                (3, 4), (3, 8), (4, 8), (4, 16), (6, 8), (6, 16),
            ]),
            1 => (0u8..8, prop::sample::select(vec![0u8, 1, 2, 3, 4, 8, 16, 32])),
        ],
        interlace in prop_oneof![6 => Just(0u8), 3 => Just(1u8), 1 => 2u8..255],
        seed in any::<u64>(),
        delta in prop_oneof![8 => Just(0i64), 1 => -8i64..8],
        filters in prop_oneof![4 => Just(5u8), 1 => Just(255u8)],
        plte in prop::option::of(1usize..300),
        trns in prop::option::of(prop::collection::vec(any::<u8>(), 0..8)),
    ) {
        let mut rows = png_data(w, h, color, depth, interlace, seed, filters);
        let len = (rows.len() as i64 + delta).max(0) as usize;
        rows.resize(len, 0x55);
        let plte: Option<Vec<u8>> = plte.map(|n| noise(3 * n.min(256) + n / 256, seed ^ 7));
        let mut ihdr = Vec::new();
        ihdr.extend(w.to_be_bytes());
        ihdr.extend(h.to_be_bytes());
        ihdr.extend([depth, color, 0, 0, interlace]);
        let mut data = b"\x89PNG\r\n\x1a\n".to_vec();
        data.extend(png_chunk(b"IHDR", &ihdr));
        if let Some(p) = &plte {
            data.extend(png_chunk(b"PLTE", p));
        }
        if let Some(t) = &trns {
            data.extend(png_chunk(b"tRNS", t));
        }
        data.extend(png_chunk(b"IDAT", &zlib_stored(&rows)));
        let _ = &trns;
        data.extend(png_chunk(b"IEND", &[]));
        EX_STRUCTURE.count(check_example(&data, None)?, EXAMPLE_CASES);
    }

    /// Example + height map pairs: sizes that match or not, height files mutated.
    #[test]
    fn example_with_height(
        w in 6u32..20, h in 6u32..20, dw in 0u32..2, kind in 0u8..9, hkind in 0u8..9,
        seed in any::<u64>(), edits in prop::collection::vec(edit(), 0..3),
    ) {
        let ex = encode(w, h, kind, seed);
        let mut hm = encode(w + dw, h, hkind, seed ^ 1);
        for e in &edits {
            apply(&mut hm, e);
        }
        fix_png_crcs(&mut hm);
        EX_HEIGHT.count(check_example(&ex, Some(&hm))?, EXAMPLE_CASES);
    }

    /// Arbitrary bytes behind a PNG or JPEG signature (or none).
    #[test]
    fn example_random_bytes(
        sig in 0u8..3, data in prop::collection::vec(any::<u8>(), 0..1024),
    ) {
        let mut bytes = match sig {
            0 => b"\x89PNG\r\n\x1a\n".to_vec(),
            1 => vec![0xFF, 0xD8, 0xFF],
            _ => Vec::new(),
        };
        bytes.extend(data);
        EX_BYTES.count(check_example(&bytes, None)?, EXAMPLE_CASES);
    }
}
