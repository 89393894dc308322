//! `facemaps.ptx` read back with Disney's reference Ptex library (issue 16, item 2).
//!
//! The tests build `ptxinfo` with `../shared/tools/ptex/build.sh` and our own query tool
//! `tests/ptex/ptxcheck.cpp` (same library sources, g++), once per source version, cached
//! under `target/tmp/ptex-tools-*`. They compare, for results of the real pipeline:
//!
//! - face count and resolutions (`ptxinfo -f`) with the mesh's domains and N;
//! - adjacency (`ptxinfo -f`, and `ptxinfo -c`, the library's own consistency check) with
//!   the mesh *geometrically*: the limit surface at the ends of every edge must be where
//!   Ptex says the neighbour's edge ends are — nothing is compared with our own adjacency
//!   code's output;
//! - texels (`ptxcheck data`, exact; `ptxinfo -d`, 3 decimals) with facemaps.exr, and the
//!   reductions with 2×2 means of facemaps.exr;
//! - the reference bilinear filter on both sides of every face edge: continuous.
//!
//! Where g++ is missing they skip, saying so.

mod common;

use glam::DVec3;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::OnceLock;
use subdiv::{DomainId, DomainLocation, Surface};
use surfsynth::io::exr::{read_face_maps, FaceMaps};
use surfsynth::io::ptex::{write_ptex, PtexImage, PtexOptions, Res};

struct Tools {
    ptxinfo: PathBuf,
    ptxcheck: PathBuf,
}

fn fnv(bytes: &[u8], mut h: u64) -> u64 {
    for b in bytes {
        h = (h ^ *b as u64).wrapping_mul(0x100_0000_01b3);
    }
    h
}

fn run_ok(cmd: &mut Command, what: &str) {
    let out = cmd.output().unwrap_or_else(|e| panic!("{what}: {e}"));
    assert!(
        out.status.success(),
        "{what} failed: {}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
}

/// Builds (once) ptxinfo and ptxcheck; `None` when there is no g++.
fn build_tools() -> Option<Tools> {
    if Command::new("g++").arg("--version").output().is_err() {
        eprintln!("skipped: g++ not found, so the reference Ptex library cannot be built");
        return None;
    }
    let ptex = common::shared().join("tools/ptex");
    let checker = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/ptex/ptxcheck.cpp");
    let mut key = 0xcbf2_9ce4_8422_2325u64;
    for f in [
        ptex.join("build.sh"),
        ptex.join("SOURCE_COMMIT"),
        checker.clone(),
    ] {
        key = fnv(
            &std::fs::read(&f).unwrap_or_else(|e| panic!("{}: {e}", f.display())),
            key,
        );
    }
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join(format!("ptex-tools-{key:016x}"));
    let tools = Tools {
        ptxinfo: dir.join("ptxinfo"),
        ptxcheck: dir.join("ptxcheck"),
    };
    if tools.ptxinfo.exists() && tools.ptxcheck.exists() {
        return Some(tools);
    }
    let work = dir.with_extension(format!("tmp-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&work);
    std::fs::create_dir_all(work.join("src")).unwrap();
    // ptxinfo with the shared script; ptxcheck with the same compiler line, in parallel.
    let mut info = Command::new("bash")
        .arg(ptex.join("build.sh"))
        .arg(&work)
        .stdout(Stdio::null())
        .spawn()
        .expect("run build.sh");
    let src = work.join("src");
    for e in std::fs::read_dir(ptex.join("src/ptex")).unwrap() {
        let e = e.unwrap();
        std::fs::copy(e.path(), src.join(e.file_name())).unwrap();
    }
    let version = std::fs::read_to_string(src.join("PtexVersion.h.in"))
        .unwrap()
        .replace("@PTEX_MAJOR_VERSION@", "2")
        .replace("@PTEX_MINOR_VERSION@", "4");
    std::fs::write(src.join("PtexVersion.h"), version).unwrap();
    let mut g = Command::new("g++");
    g.args(["-O2", "-std=c++17", "-DPTEX_STATIC", "-w", "-I"])
        .arg(&src);
    for e in std::fs::read_dir(&src).unwrap() {
        let p = e.unwrap().path();
        let name = p.file_name().unwrap().to_string_lossy().into_owned();
        if name.ends_with(".cpp") && !name.contains("HalfTableGen") {
            g.arg(p);
        }
    }
    g.arg(&checker)
        .args(["-lz", "-lpthread", "-o"])
        .arg(work.join("ptxcheck"));
    run_ok(&mut g, "g++ ptxcheck");
    let status = info.wait().unwrap();
    assert!(
        status.success(),
        "build.sh failed (needs g++ and zlib headers)"
    );
    let _ = std::fs::remove_dir_all(work.join("src"));
    if std::fs::rename(&work, &dir).is_err() {
        // Built meanwhile by another process.
        let _ = std::fs::remove_dir_all(&work);
    }
    Some(tools)
}

fn tools() -> Option<&'static Tools> {
    static T: OnceLock<Option<Tools>> = OnceLock::new();
    T.get_or_init(build_tools).as_ref()
}

fn ptxinfo(t: &Tools, args: &[&str], file: &Path) -> (bool, String) {
    let out = Command::new(&t.ptxinfo)
        .args(args)
        .arg(file)
        .output()
        .unwrap();
    let mut s = String::from_utf8_lossy(&out.stdout).into_owned();
    s.push_str(&String::from_utf8_lossy(&out.stderr));
    (out.status.success(), s)
}

/// Answers of ptxcheck to `queries`, one vector per query (`premultiply`: open the file
/// as renderers do for textures with alpha).
fn ptxcheck(t: &Tools, file: &Path, queries: &[String], premultiply: bool) -> Vec<Vec<f32>> {
    let mut child = Command::new(&t.ptxcheck)
        .arg(file)
        .args(premultiply.then_some("premultiply"))
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut stdin = child.stdin.take().unwrap();
    let text = queries.join("\n") + "\n";
    let writer = std::thread::spawn(move || stdin.write_all(text.as_bytes()));
    let out = child.wait_with_output().unwrap();
    writer.join().unwrap().unwrap();
    assert!(
        out.status.success(),
        "ptxcheck: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let lines: Vec<Vec<f32>> = String::from_utf8(out.stdout)
        .unwrap()
        .lines()
        .map(|l| {
            assert!(!l.starts_with("error"), "ptxcheck: {l}");
            l.split_whitespace().map(|v| v.parse().unwrap()).collect()
        })
        .collect();
    assert_eq!(lines.len(), queries.len());
    lines
}

/// Per face of `ptxinfo -f`: (ulog2, vlog2, adjfaces, adjedges, flags text).
type Row = (u8, u8, [i32; 4], [u8; 4], String);

fn face_rows(info: &str) -> Vec<Row> {
    let mut rows = Vec::new();
    for l in info.lines().filter(|l| l.starts_with("face ")) {
        let w: Vec<&str> = l.split_whitespace().collect();
        // face I: res: U V (A x B) adjface: 4 x int adjedge: 4 x int flags: ...
        let at = |k: &str| w.iter().position(|x| *x == k).unwrap();
        let r = at("res:");
        let af = at("adjface:");
        let ae = at("adjedge:");
        let fl = at("flags:");
        let nums =
            |s: usize| -> [i32; 4] { std::array::from_fn(|i| w[s + 1 + i].parse().unwrap()) };
        let e = nums(ae);
        rows.push((
            w[r + 1].parse().unwrap(),
            w[r + 2].parse().unwrap(),
            nums(af),
            e.map(|x| x as u8),
            w[fl + 1..].join(" "),
        ));
    }
    rows
}

/// Domain corners of Ptex edge e, in the edge's direction (counter-clockwise).
fn edge_ends(e: usize) -> [(f64, f64); 2] {
    const C: [(f64, f64); 4] = [(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0)];
    [C[e], C[(e + 1) % 4]]
}

fn at(s: &Surface, d: usize, (u, v): (f64, f64)) -> DVec3 {
    s.eval(DomainId::from_idx(d), u, v).p
}

/// Checks Ptex's adjacency rows against the limit surface: across edge e of face f lies
/// face g's edge e' running the other way (equal ends), or, between a quad and a sub-face,
/// half of it (sharing one end, the other at the quad edge's midpoint); -1 only where the
/// surface has an open boundary.
fn check_adjacency_against_mesh(s: &Surface, rows: &[Row]) {
    let tol = 1e-9;
    for (f, row) in rows.iter().enumerate() {
        let sub_f = row.4.contains("subface");
        for e in 0..4 {
            let [a, b] = edge_ends(e).map(|p| at(s, f, p));
            let g = row.2[e];
            if g < 0 {
                let m = edge_ends(e);
                let (u, v) = (0.5 * (m[0].0 + m[1].0), 0.5 * (m[0].1 + m[1].1));
                let inward = (0.5 - u, 0.5 - v);
                let start = DomainLocation {
                    domain: DomainId::from_idx(f),
                    u: u + 1e-3 * inward.0,
                    v: v + 1e-3 * inward.1,
                };
                assert!(
                    s.walk(start, -4e-3 * inward.0, -4e-3 * inward.1).is_none(),
                    "face {f} edge {e}: no neighbour in the file, but the surface goes on"
                );
                continue;
            }
            let g = g as usize;
            let [c, d] = edge_ends(row.3[e] as usize).map(|p| at(s, g, p));
            let sub_g = rows[g].4.contains("subface");
            let ok = if sub_f == sub_g {
                (a - d).length() < tol && (b - c).length() < tol
            } else if sub_g {
                // f is a quad and g the sub-face at the start a of f's edge: g's edge runs
                // from the edge's midpoint to a.
                let m = s
                    .eval(
                        DomainId::from_idx(f),
                        0.5 * (edge_ends(e)[0].0 + edge_ends(e)[1].0),
                        0.5 * (edge_ends(e)[0].1 + edge_ends(e)[1].1),
                    )
                    .p;
                (c - m).length() < tol && (d - a).length() < tol
            } else {
                // f is a sub-face on half of quad g's edge (c -> d): it shares one end and
                // the other is the edge's (parametric) midpoint.
                let [g0, g1] = edge_ends(row.3[e] as usize);
                let m = at(s, g, (0.5 * (g0.0 + g1.0), 0.5 * (g0.1 + g1.1)));
                ((a - d).length() < tol && (b - m).length() < tol)
                    || ((a - m).length() < tol && (b - c).length() < tol)
            };
            assert!(ok, "face {f} edge {e} -> face {g} edge {}: the edges do not meet on the surface: {a} {b} vs {c} {d} ({:?} / {:?})", row.3[e], s.domain(DomainId::from_idx(f)), s.domain(DomainId::from_idx(g)));
        }
    }
}

/// A synthesis result written by the real pipeline into a temporary directory.
fn synth(mesh: &Path, example: &Path, n: usize) -> (tempfile::TempDir, Surface, FaceMaps) {
    let dir = tempfile::tempdir().unwrap();
    let r = surfsynth::synthesizer::Synthesizer::new(mesh, example)
        .resolution(n)
        .seed(5)
        .threads(2)
        .run()
        .unwrap();
    r.write(dir.path()).unwrap();
    let maps = read_face_maps(dir.path().join("facemaps.exr")).unwrap();
    (dir, std::sync::Arc::unwrap_or_clone(r.surface), maps)
}

/// The 2×2 mean of face `f`, channel `k`, level-0 texels (x, y) at N, reduced once (Ptex
/// premultiplies colour by alpha before reducing; `alpha` is that channel's data).
fn reduced(
    maps: &FaceMaps,
    data: &[f32],
    alpha: Option<&[f32]>,
    f: usize,
    x: usize,
    y: usize,
) -> f32 {
    let t = |xx: usize, yy: usize| {
        let i = maps.index(f, xx, yy);
        data[i] * alpha.map_or(1.0, |a| a[i])
    };
    0.25 * (t(2 * x, 2 * y) + t(2 * x + 1, 2 * y) + t(2 * x, 2 * y + 1) + t(2 * x + 1, 2 * y + 1))
}

/// Everything the module doc lists, for one result.
fn check_result(t: &Tools, dir: &Path, s: &Surface, maps: &FaceMaps) -> Vec<String> {
    let ptx = dir.join("facemaps.ptx");
    let n = maps.uniform_n().expect("uniform maps");
    let log2 = n.trailing_zeros() as u8;
    let (ok, info) = ptxinfo(t, &["-f", "-m"], &ptx);
    assert!(ok, "ptxinfo: {info}");
    assert!(
        info.contains("meshType: quad") && info.contains("dataType: float32"),
        "{info}"
    );
    assert!(
        info.contains(&format!("numChannels: {}", maps.channels.len())),
        "{info}"
    );
    assert!(
        info.contains(&format!("numFaces: {}", s.num_domains())),
        "{info}"
    );
    assert!(info.contains("hasMipMaps: yes") == (log2 > 2), "{info}");
    // Channel names from the meta data; the EXR reader returns them sorted, the Ptex file
    // keeps the synthesizer's order (R G B ... source.u source.v).
    let line = info
        .lines()
        .find(|l| l.contains("surfsynth.channels type=string"))
        .expect("channel names");
    let names: Vec<&str> = line.split('"').nth(1).unwrap().split(',').collect();
    let mut sorted = names.clone();
    sorted.sort();
    assert_eq!(sorted, maps.names(), "the Ptex file has every channel");
    assert_eq!(&names[..3], ["R", "G", "B"]);
    let chan = |k: usize| maps.channel(names[k]).unwrap();
    let rows = face_rows(&info);
    assert_eq!(rows.len(), s.num_domains());
    for (f, r) in rows.iter().enumerate() {
        assert_eq!((r.0, r.1), (log2, log2), "face {f} resolution");
        let sub = !matches!(s.domain(DomainId::from_idx(f)), subdiv::Domain::Quad { .. });
        assert_eq!(r.4.contains("subface"), sub, "face {f} flags {}", r.4);
    }
    check_adjacency_against_mesh(s, &rows);
    let (ok, check) = ptxinfo(t, &["-c"], &ptx);
    assert!(
        ok && check.contains("Adjacency information appears consistent"),
        "ptxinfo -c: {check}"
    );

    // Texels: level 0 exactly, the first reduction as 2x2 means, all faces.
    let c = names.len();
    let alpha = maps.channel("A");
    let alpha_k = names.iter().position(|&x| x == "A");
    let mut q = Vec::new();
    for f in 0..maps.faces() {
        q.push(format!("data {f} {log2} {log2}"));
        if log2 > 2 {
            q.push(format!("data {f} {} {}", log2 - 1, log2 - 1));
        }
    }
    let answers = ptxcheck(t, &ptx, &q, false);
    let mut a = answers.iter();
    for f in 0..maps.faces() {
        let full = a.next().unwrap();
        for y in 0..n {
            for x in 0..n {
                for (k, name) in names.iter().enumerate() {
                    let got = full[(y * n + x) * c + k];
                    let want = chan(k)[maps.index(f, x, y)];
                    assert_eq!(
                        got.to_bits(),
                        want.to_bits(),
                        "face {f} texel ({x},{y}) {name}: {got} vs {want}"
                    );
                }
            }
        }
        if log2 > 2 {
            let half = a.next().unwrap();
            let h = n / 2;
            for y in 0..h {
                for x in 0..h {
                    for k in 0..c {
                        let premult = alpha_k.is_some_and(|ak| k < ak);
                        let want =
                            reduced(maps, chan(k), if premult { alpha } else { None }, f, x, y);
                        let got = half[(y * h + x) * c + k];
                        assert!(
                            (got - want).abs() <= 1e-6 * want.abs().max(1.0),
                            "face {f} reduction ({x},{y}) ch {k}: {got} vs {want}"
                        );
                    }
                }
            }
        }
    }
    // ptxinfo's own dump (3 decimals) of level 0.
    let (ok, dump) = ptxinfo(t, &["-d"], &ptx);
    assert!(ok);
    let mut face = 0usize;
    let mut checked = 0;
    for l in dump.lines() {
        let l = l.trim();
        if let Some(rest) = l.strip_prefix("face ") {
            face = rest.split(':').next().unwrap().parse().unwrap();
        } else if l.starts_with('(') && l.contains("):") {
            let (xy, vals) = l.split_once("):").unwrap();
            let (x, y) = xy.trim_start_matches('(').split_once(", ").unwrap();
            let (x, y): (usize, usize) = (x.parse().unwrap(), y.parse().unwrap());
            for (k, v) in vals.split_whitespace().enumerate() {
                let v: f64 = v.parse().unwrap();
                let want = chan(k)[maps.index(face, x, y)] as f64;
                assert!(
                    (v - want).abs() <= 5.01e-4,
                    "ptxinfo -d face {face} ({x},{y}) ch {k}: {v} vs {want}"
                );
                checked += 1;
            }
        }
    }
    assert_eq!(
        checked,
        maps.faces() * n * n * c,
        "ptxinfo -d printed every texel"
    );

    names.iter().map(|s| s.to_string()).collect()
}

/// Filter continuity for a synthesized (noisy) texture.
fn check_noisy_continuity(t: &Tools, ptx: &Path, s: &Surface, maps: &FaceMaps, names: &[String]) {
    let names: Vec<&str> = names.iter().map(|s| s.as_str()).collect();
    let j = filter_jumps(t, ptx, s, maps, &names);
    // Texel noise: without blending the two sides differ like neighbouring texels; with
    // it, where the texel grids match, the lookups agree up to the texture's change over
    // the 2e-3 texels between the two lookup points.
    assert!(
        j.unblended > 0.02,
        "the test must see texel differences without blending"
    );
    assert!(
        j.matching.1 < 2e-3 && j.matching.0 < 0.01 * j.unblended,
        "bilinear lookups jump across face edges"
    );
    // At T-junctions Ptex blends a 2x2 mean of the sub-faces' denser texels with the
    // quad's, so noise does not cancel exactly (a smooth field does: see below).
    assert!(j.tee.0 < 0.3 * j.unblended);
}

/// The reference bilinear filter just inside both sides of every face edge, at several
/// places along it: the colour must agree (the filter blends across edges through the
/// adjacency), where the same lookups with edge blending off differ like neighbouring
/// texels do.
/// Jumps of the reference bilinear filter across face edges: (mean, max) over edges whose
/// two sides have matching texel grids, the same over T-junctions (a quad beside n-gon
/// sub-faces, where Ptex blends texel grids of different density), and the mean with
/// edge blending off.
struct Jumps {
    matching: (f64, f32),
    tee: (f64, f32),
    unblended: f64,
}

fn filter_jumps(t: &Tools, ptx: &Path, s: &Surface, maps: &FaceMaps, names: &[&str]) -> Jumps {
    let n = maps.uniform_n().expect("uniform maps") as f64;
    let eps = 1e-3 / n;
    let mut pairs = Vec::new();
    for f in 0..maps.faces() {
        for e in 0..4 {
            let [p0, p1] = edge_ends(e);
            for along in [0.21, 0.37, 0.62, 0.83] {
                let (u, v) = (p0.0 + along * (p1.0 - p0.0), p0.1 + along * (p1.1 - p0.1));
                let inward = (0.5 - u, 0.5 - v);
                let len = (inward.0 * inward.0 + inward.1 * inward.1).sqrt();
                let dir = (inward.0 / len, inward.1 / len);
                // Straight across: move along the edge normal in parameter space.
                let normal = match e {
                    0 => (0.0, 1.0),
                    1 => (-1.0, 0.0),
                    2 => (0.0, -1.0),
                    _ => (1.0, 0.0),
                };
                let _ = dir;
                let inside = DomainLocation {
                    domain: DomainId::from_idx(f),
                    u: u + eps * normal.0,
                    v: v + eps * normal.1,
                };
                if let Some(out) = s.walk(inside, -2.0 * eps * normal.0, -2.0 * eps * normal.1) {
                    if out.domain.idx() != f {
                        pairs.push((inside, out));
                    }
                }
            }
        }
    }
    assert!(!pairs.is_empty());
    let mut q = Vec::new();
    for (a, b) in &pairs {
        for (cmd, l) in [("filter", a), ("filter", b), ("noblend", a), ("noblend", b)] {
            q.push(format!("{cmd} {} {:.9} {:.9}", l.domain.idx(), l.u, l.v));
        }
    }
    // Premultiplied when there is alpha: the stored reductions the filter blends in are.
    let ans = ptxcheck(t, ptx, &q, names.contains(&"A"));
    let colour: Vec<usize> = ["R", "G", "B"]
        .iter()
        .map(|c| names.iter().position(|x| x == c).unwrap())
        .collect();
    let (mut worst, mut sum_blend, mut sum_noblend) = (0f32, 0f64, 0f64);
    let (mut worst_t, mut sum_t, mut count_t) = (0f32, 0f64, 0usize);
    let quad = |l: &DomainLocation| matches!(s.domain(l.domain), subdiv::Domain::Quad { .. });
    for k in 0..pairs.len() {
        let [fa, fb, na, nb] = [
            &ans[4 * k],
            &ans[4 * k + 1],
            &ans[4 * k + 2],
            &ans[4 * k + 3],
        ];
        let tee = quad(&pairs[k].0) != quad(&pairs[k].1);
        for &c in &colour {
            let d = (fa[c] - fb[c]).abs();
            if tee {
                worst_t = worst_t.max(d);
                sum_t += d as f64;
                count_t += 1;
            } else {
                worst = worst.max(d);
                sum_blend += d as f64;
            }
            sum_noblend += (na[c] - nb[c]).abs() as f64;
        }
    }
    let m = (pairs.len() * 3) as f64;
    let j = Jumps {
        matching: (sum_blend / (m - count_t as f64).max(1.0), worst),
        tee: (sum_t / count_t.max(1) as f64, worst_t),
        unblended: sum_noblend / m,
    };
    eprintln!(
        "filter across {} edge points: |jump| mean {:.2e} max {:.2e}; at T-junctions ({} lookups) mean {:.2e} max {:.2e}; without edge blending mean {:.2e}",
        pairs.len(),
        j.matching.0,
        j.matching.1,
        count_t,
        j.tee.0,
        j.tee.1,
        j.unblended
    );
    j
}

#[test]
fn nonquads_result_matches_facemaps_exr_in_the_reference_reader() {
    let Some(t) = tools() else { return };
    let mesh = common::data("opensubdiv-reference/catmark_nonquads.obj");
    let example = common::data("textures/etr_gravel.png");
    let (dir, s, maps) = synth(&mesh, &example, 8);
    let names = check_result(t, dir.path(), &s, &maps);
    check_noisy_continuity(t, &dir.path().join("facemaps.ptx"), &s, &maps, &names);
}

/// Maps holding a smooth function of the limit position, with alpha.
fn smooth_maps(s: &Surface, n: usize) -> FaceMaps {
    let names = ["R", "G", "B", "A", "height"];
    let mut m = FaceMaps::new(s.num_domains(), n, &names);
    let (lo, hi) = s.control.bounds();
    let ext = (hi - lo).max_element();
    let mut samples = vec![Default::default(); n * n];
    for d in 0..s.num_domains() {
        s.eval_texels(DomainId::from_idx(d), n, &mut samples);
        for (i, smp) in samples.iter().enumerate() {
            let p = (smp.p - lo) / ext;
            let vals = [
                0.2 + 0.6 * p.x,
                0.2 + 0.6 * p.y,
                0.2 + 0.6 * p.z,
                0.6 + 0.3 * (p.x - p.y),
                p.x * p.y,
            ];
            let idx = d * n * n + i;
            for (k, (_, data)) in m.channels.iter_mut().enumerate() {
                data[idx] = vals[k] as f32;
            }
        }
    }
    m
}

#[test]
fn smooth_maps_filter_continuously_across_every_edge_including_t_junctions() {
    let Some(t) = tools() else { return };
    for (mesh, n) in [
        ("opensubdiv-reference/catmark_nonquads.obj", 16),
        ("meshes/cube_no_bottom.obj", 8),
    ] {
        let s = common::load(mesh);
        let maps = smooth_maps(&s, n);
        let dir = tempfile::tempdir().unwrap();
        let ptx = dir.path().join("facemaps.ptx");
        surfsynth::io::ptex::write_face_maps_ptex(&ptx, &s, &maps, &PtexOptions::default())
            .unwrap();
        // The EXR reader's channel order is the sorted one; compare through it.
        surfsynth::io::exr::write_face_maps(dir.path().join("facemaps.exr"), &maps).unwrap();
        let back = read_face_maps(dir.path().join("facemaps.exr")).unwrap();
        let names = check_result(t, dir.path(), &s, &back);
        let names: Vec<&str> = names.iter().map(|s| s.as_str()).collect();
        let j = filter_jumps(t, &ptx, &s, &back, &names);
        // A field linear in position is reproduced by bilinear filtering on either side,
        // whatever the texel densities: wrong adjacency (face, edge or sub-face half)
        // would show as jumps of the field's change over a face.
        assert!(
            j.matching.1 < 2e-3 && j.tee.1 < 5e-3,
            "{mesh}: jumps {:?} / {:?}",
            j.matching,
            j.tee
        );
    }
}

#[test]
fn per_face_resolutions_tiles_and_constant_faces_as_the_reference_reads_them() {
    let Some(t) = tools() else { return };
    // A 3x3 grid: face 8 (a corner) has its own data at 256 x 64 texels — 128 KiB of two
    // float channels, so it is tiled (two tiles of 128 x 64, the second constant); the
    // others are one constant value, so those not touching face 8 at any corner have a
    // constant neighbourhood: faces 0, 1, 2, 3, 6.
    let s = Surface::new(subdiv::ControlMesh::grid(3));
    let mut infos = surfsynth::io::ptex::face_infos(&s, |_| Res::new(3, 2));
    infos[8].res = Res::new(8, 6);
    let value = |f: usize, x: usize, y: usize, k: usize| -> f32 {
        if f != 8 {
            [0.25, 0.75][k]
        } else if x >= 128 {
            [-1.0, 2.0][k]
        } else {
            (x as f32 + 300.0 * y as f32) * [1.0, -0.5][k]
        }
    };
    let img = PtexImage {
        faces: &infos,
        channels: 2,
        alpha: None,
        meta: vec![],
    };
    // Stored blocks (the default: sizes known before encoding) and deflate level 6.
    for zlib_level in [0, 6] {
        check_grid_file(t, &s, &infos, &img, &value, zlib_level);
    }
}

fn check_grid_file(
    t: &Tools,
    s: &Surface,
    infos: &[surfsynth::io::ptex::FaceInfo],
    img: &PtexImage,
    value: &(dyn Fn(usize, usize, usize, usize) -> f32 + Sync),
    zlib_level: u32,
) {
    let dir = tempfile::tempdir().unwrap();
    let ptx = dir.path().join("t.ptx");
    let opts = PtexOptions {
        zlib_level,
        mipmaps: true,
    };
    let sum = write_ptex(&ptx, img, &opts, |f, buf| {
        let r = infos[f].res;
        for k in 0..2 {
            for y in 0..r.v() {
                for x in 0..r.u() {
                    buf[k * r.size() + y * r.u() + x] = value(f, x, y, k);
                }
            }
        }
    })
    .unwrap();
    assert_eq!((sum.faces, sum.levels, sum.constant_faces), (9, 5, 8));
    let (ok, info) = ptxinfo(t, &["-f", "-t"], &ptx);
    assert!(ok, "{info}");
    let rows = face_rows(&info);
    check_adjacency_against_mesh(s, &rows);
    for (f, r) in rows.iter().enumerate() {
        let want = match f {
            8 => "(none)",
            0 | 1 | 2 | 3 | 6 => "constant nbconstant",
            _ => "constant",
        };
        assert_eq!(r.4, want, "face {f} flags");
        assert_eq!((r.0, r.1), if f == 8 { (8, 6) } else { (3, 2) });
    }
    assert!(
        info.contains("tiling: ntiles = 2, res = 7 6 (128 x 64)"),
        "{info}"
    );
    let q: Vec<String> = [
        "data 8 8 6",
        "data 8 7 5",
        "data 8 5 3",
        "data 4 3 2",
        "const 8",
        "const 2",
    ]
    .iter()
    .map(|s| s.to_string())
    .collect();
    let a = ptxcheck(t, &ptx, &q, false);
    for y in 0..64 {
        for x in 0..256 {
            for k in 0..2 {
                assert_eq!(
                    a[0][(y * 256 + x) * 2 + k],
                    value(8, x, y, k),
                    "({x},{y}) ch {k}"
                );
            }
        }
    }
    let box2 = |x: usize, y: usize, k: usize| {
        0.25 * (value(8, 2 * x, 2 * y, k)
            + value(8, 2 * x + 1, 2 * y, k)
            + value(8, 2 * x, 2 * y + 1, k)
            + value(8, 2 * x + 1, 2 * y + 1, k))
    };
    for y in 0..32 {
        for x in 0..128 {
            for k in 0..2 {
                assert_eq!(a[1][(y * 128 + x) * 2 + k], box2(x, y, k));
            }
        }
    }
    // Three levels down (stored level 3), the mean of 8 x 8 blocks.
    let mean = |x0: usize, y0: usize, w: usize, k: usize| -> f64 {
        let mut s = 0.0;
        for y in y0..y0 + w {
            for x in x0..x0 + w {
                s += value(8, x, y, k) as f64;
            }
        }
        s / (w * w) as f64
    };
    for y in 0..8 {
        for x in 0..32 {
            let got = a[2][(y * 32 + x) * 2] as f64;
            let want = mean(8 * x, 8 * y, 8, 0);
            assert!(
                (got - want).abs() <= 1e-5 * want.abs().max(1.0),
                "level 3 ({x},{y}): {got} vs {want}"
            );
        }
    }
    assert_eq!(a[3], [0.25, 0.75].repeat(32));
    for (k, &got) in a[4].iter().enumerate() {
        // The mean of the whole face (of its last, 16 x 4 reduction).
        let want = (0..4).map(|i| mean(64 * i, 0, 64, k)).sum::<f64>() / 4.0;
        assert!(
            (got as f64 - want).abs() <= 1e-4 * want.abs().max(1.0),
            "const ch {k}: {got} vs {want}"
        );
    }
    assert_eq!(a[5], [0.25, 0.75]);
}

#[test]
fn a_resolution_that_is_not_a_power_of_two_is_resampled_to_the_next() {
    let Some(t) = tools() else { return };
    let s = common::load("opensubdiv-reference/catmark_nonquads.obj");
    let n = 6;
    let maps = smooth_maps(&s, n);
    let dir = tempfile::tempdir().unwrap();
    let ptx = dir.path().join("facemaps.ptx");
    surfsynth::io::ptex::write_face_maps_ptex(&ptx, &s, &maps, &PtexOptions::default()).unwrap();
    let (ok, info) = ptxinfo(t, &["-f", "-m"], &ptx);
    assert!(ok, "{info}");
    assert!(
        info.contains("surfsynth.resolution type=int32  6"),
        "{info}"
    );
    assert!(
        face_rows(&info).iter().all(|r| (r.0, r.1) == (3, 3)),
        "8 x 8 faces"
    );
    // The field is linear in position: the resampled texels are the field at the 8 x 8
    // texel centres, to bilinear-interpolation accuracy.
    let q: Vec<String> = (0..s.num_domains())
        .map(|f| format!("data {f} 3 3"))
        .collect();
    let a = ptxcheck(t, &ptx, &q, false);
    let fine = smooth_maps(&s, 8);
    let mut worst = 0f32;
    for f in 0..s.num_domains() {
        for i in 0..64 {
            for (k, (_, data)) in fine.channels.iter().enumerate() {
                worst = worst.max((a[f][i * 5 + k] - data[f * 64 + i]).abs());
            }
        }
    }
    assert!(worst < 0.02, "resampled texels off by {worst}");
}

/// `--texel-size` (per-face resolutions, u and v separately): the reference reader sees
/// every face at its own resolution (the log2 sides of facemaps.exr's header), the
/// adjacency of the mesh, and level 0 bit for bit equal to facemaps.exr.
#[test]
fn texel_size_result_has_per_face_resolutions_in_the_reference_reader() {
    let Some(t) = tools() else { return };
    let mesh = common::data("meshes/spot_control_mesh.obj");
    let example = common::data("textures/etr_gravel.png");
    let dir = tempfile::tempdir().unwrap();
    let s0 = Surface::load_obj(&mesh).unwrap();
    let l = surfsynth::texels::TexelGeometry::compute(&s0, 8).median_spacing(&s0);
    let r = surfsynth::synthesizer::Synthesizer::new(&mesh, &example)
        .method(surfsynth::synthesizer::Method::Coherent)
        .texel_size(l)
        .seed(5)
        .run()
        .unwrap();
    r.write(dir.path()).unwrap();
    let (s, maps) = (
        r.surface,
        read_face_maps(dir.path().join("facemaps.exr")).unwrap(),
    );
    let res = maps.layout.resolutions().expect("per-face layout").to_vec();
    let mut distinct: Vec<(u8, u8)> = res.iter().map(|r| (r.log2_u(), r.log2_v())).collect();
    distinct.sort_unstable();
    distinct.dedup();
    assert!(distinct.len() >= 3, "{distinct:?}");
    assert!(
        distinct.iter().any(|(a, b)| a != b),
        "some faces are not square"
    );
    let ptx = dir.path().join("facemaps.ptx");
    let (ok, info) = ptxinfo(t, &["-f", "-m"], &ptx);
    assert!(ok, "ptxinfo: {info}");
    assert!(
        info.contains(&format!("numFaces: {}", s.num_domains())),
        "{info}"
    );
    let rows = face_rows(&info);
    assert_eq!(rows.len(), s.num_domains());
    for (f, row) in rows.iter().enumerate() {
        assert_eq!(
            (row.0, row.1),
            (res[f].log2_u(), res[f].log2_v()),
            "face {f}"
        );
    }
    check_adjacency_against_mesh(&s, &rows);
    let (ok, check) = ptxinfo(t, &["-c"], &ptx);
    assert!(
        ok && check.contains("Adjacency information appears consistent"),
        "ptxinfo -c: {check}"
    );
    let line = info
        .lines()
        .find(|l| l.contains("surfsynth.channels type=string"))
        .expect("channel names");
    let names: Vec<&str> = line.split('"').nth(1).unwrap().split(',').collect();
    let c = names.len();
    let q: Vec<String> = (0..maps.faces())
        .map(|f| format!("data {f} {} {}", res[f].log2_u(), res[f].log2_v()))
        .collect();
    let answers = ptxcheck(t, &ptx, &q, false);
    for (f, full) in answers.iter().enumerate() {
        let (nu, nv) = maps.layout.dims(f);
        assert_eq!(full.len(), nu * nv * c, "face {f}");
        for y in 0..nv {
            for x in 0..nu {
                for (k, name) in names.iter().enumerate() {
                    let got = full[(y * nu + x) * c + k];
                    let want = maps.channel(name).unwrap()[maps.index(f, x, y)];
                    assert_eq!(got.to_bits(), want.to_bits(), "face {f} ({x},{y}) {name}");
                }
            }
        }
    }
}
