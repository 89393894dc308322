//! Shape synthesis through the binary (`synth --height H --displace AMOUNT`, paper 000 §6):
//! displaced.glb is the limit surface at texel resolution moved along the limit normal by
//! AMOUNT x (height − 0.5). Checked vertex by vertex against the limit surface (subdiv,
//! itself checked against OpenSubdiv) and the height texels of facemaps.exr; with
//! `--decimate TOL`, flat regions take fewer triangles, without cracks, within TOL.

mod common;

use common::{glb, gltf_validator};
use glam::DVec3;
use std::path::{Path, PathBuf};
use std::process::Command;
use subdiv::{ControlMesh, Surface};

const GRAVEL: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/fixtures/gravel.png");

/// A 4x4 grid of unit quads, bent so that normals vary.
fn bent_grid(dir: &Path) -> PathBuf {
    let mut obj = String::new();
    for y in 0..=4 {
        for x in 0..=4 {
            let z = 0.4 * ((x as f64) * 0.7).sin() * ((y as f64) * 0.5).cos();
            obj += &format!("v {x} {y} {z}\n");
        }
    }
    for y in 0..4 {
        for x in 0..4 {
            let i = y * 5 + x + 1;
            obj += &format!("f {} {} {} {}\n", i, i + 1, i + 6, i + 5);
        }
    }
    let mesh = dir.join("grid.obj");
    std::fs::write(&mesh, obj).unwrap();
    mesh
}

fn synth(mesh: &Path, out: &Path, extra: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_surfsynth"))
        .args(["synth", "--mesh"])
        .arg(mesh)
        .args(["--example", GRAVEL, "--resolution", "16", "--seed", "5"])
        .args(extra)
        .arg("--out")
        .arg(out)
        .output()
        .unwrap()
}

/// glTF vertices of `path` with the domain point each is at (texture coordinates into
/// the atlas of N-texel tiles, snapped to the dyadic tessellation grid).
fn glb_vertices(
    path: &Path,
    surface: &Surface,
    n: usize,
) -> (glb::Glb, Vec<(DVec3, usize, f64, f64)>) {
    let g = glb::read(path);
    let layout = surfsynth::io::atlas::AtlasLayout::new(
        surface.num_domains(),
        n,
        surfsynth::io::atlas::DEFAULT_GUTTER,
    );
    let pos = g.attribute("POSITION").unwrap();
    let uv = g.attribute("TEXCOORD_0").unwrap();
    let v = pos
        .iter()
        .zip(&uv)
        .map(|(p, uv)| {
            let (x, y) = (
                uv[0] * layout.width() as f64,
                uv[1] * layout.height() as f64,
            );
            let d = layout
                .domain_at(x.floor() as usize, y.floor() as usize)
                .expect("inside a tile");
            let (x0, y0) = layout.interior_origin(d);
            let snap = |a: f64| (a * 1024.0).round() / 1024.0;
            let (u, w) = (
                snap((x - x0 as f64) / n as f64),
                snap((y - y0 as f64) / n as f64),
            );
            (DVec3::new(p[0], p[1], p[2]), d, u, w)
        })
        .collect();
    (g, v)
}

#[test]
fn displaced_glb_moves_limit_points_along_the_normal_by_height() {
    let dir = tempfile::tempdir().unwrap();
    let mesh = bent_grid(dir.path());
    let out = dir.path().join("out");
    let amount = 0.3;
    let o = synth(
        &mesh,
        &out,
        &["--height", GRAVEL, "--displace", &amount.to_string()],
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap();
    assert_eq!(report["displace"], amount);
    assert!(!out.join("displaced.obj").exists());
    gltf_validator::assert_clean(&out.join("displaced.glb"));

    let maps = surfsynth::io::exr::read_face_maps(out.join("facemaps.exr")).unwrap();
    let height = maps.channel("height").unwrap();
    let n = maps.uniform_n().unwrap();
    let surface = Surface::new(ControlMesh::load_obj(&mesh).unwrap());
    let (g, verts) = glb_vertices(&out.join("displaced.glb"), &surface, n);
    // All quads at N = 16: 16 segments per domain side, one vertex per texel corner and
    // per tile.
    assert_eq!(verts.len(), 16 * 17 * 17);
    assert_eq!(g.triangles().len(), 16 * 16 * 16 * 2);
    assert_eq!(
        g.material()["pbrMetallicRoughness"]["baseColorTexture"]["index"],
        0
    );
    let mut checked = 0;
    let mut worst = 0.0f64;
    let mut sum_h = 0.0;
    for (k, &(v, f, u, w)) in verts.iter().enumerate() {
        let e = surface.eval(subdiv::DomainId::from_idx(f), u, w);
        let d = v - e.p;
        let nrm = e.n;
        // Only along the normal, never more than amount / 2.
        assert!(
            d.cross(nrm).length() < 1e-5,
            "vertex {k}: tangential move {d}"
        );
        assert!(d.length() <= amount / 2.0 + 1e-5, "vertex {k}: moved {d}");
        // Inside a domain a vertex sits on a texel corner: the mean of the four texels.
        let (x, y) = (u * n as f64, w * n as f64);
        let (xi, yi) = (x.round() as usize, y.round() as usize);
        if xi == 0 || yi == 0 || xi >= n || yi >= n {
            continue;
        }
        let h = [(xi - 1, yi - 1), (xi, yi - 1), (xi - 1, yi), (xi, yi)]
            .iter()
            .map(|&(a, c)| height[maps.index(f, a, c)] as f64)
            .sum::<f64>()
            / 4.0;
        let expected = amount * (h - 0.5);
        worst = worst.max((d.dot(nrm) - expected).abs());
        sum_h += h;
        checked += 1;
    }
    assert_eq!(checked, 16 * 15 * 15, "interior vertices");
    // f32 coordinates on a surface of size ~4: ~1e-6.
    assert!(worst < 1e-5, "displacement off by {worst}");
    // The height channel is really there (gravel: not uniform).
    let mean = sum_h / checked as f64;
    assert!((0.2..0.8).contains(&mean), "mean height {mean}");
}

/// Edges of a triangle mesh by position (bit patterns), with how many triangles use each.
fn edge_uses(g: &glb::Glb) -> std::collections::HashMap<[u64; 6], usize> {
    let pos = g.attribute("POSITION").unwrap();
    let key = |i: usize| {
        [
            pos[i][0].to_bits(),
            pos[i][1].to_bits(),
            pos[i][2].to_bits(),
        ]
    };
    let mut uses = std::collections::HashMap::new();
    for t in g.triangles() {
        for k in 0..3 {
            let (a, b) = (key(t[k]), key(t[(k + 1) % 3]));
            let e = if a < b {
                [a, b].concat()
            } else {
                [b, a].concat()
            };
            *uses.entry(e.try_into().unwrap()).or_insert(0) += 1;
        }
    }
    uses
}

#[test]
fn decimate_merges_flat_regions_without_cracks_within_the_tolerance() {
    let dir = tempfile::tempdir().unwrap();
    // A flat 4x4 grid and a uniform mid-grey height: the displaced surface is a plane, so
    // every quad domain becomes two triangles.
    let mut obj = String::new();
    for y in 0..=4 {
        for x in 0..=4 {
            obj += &format!("v {x} {y} 0\n");
        }
    }
    for y in 0..4 {
        for x in 0..4 {
            let i = y * 5 + x + 1;
            obj += &format!("f {} {} {} {}\n", i, i + 1, i + 6, i + 5);
        }
    }
    let flat = dir.path().join("flat.obj");
    std::fs::write(&flat, obj).unwrap();
    let grey = dir.path().join("grey.png");
    image::GrayImage::from_pixel(128, 128, image::Luma([128]))
        .save(&grey)
        .unwrap();
    let out = dir.path().join("flat");
    let o = synth(
        &flat,
        &out,
        &[
            "--height",
            grey.to_str().unwrap(),
            "--displace",
            "0.3",
            "--decimate",
            "1e-6",
        ],
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    gltf_validator::assert_clean(&out.join("displaced.glb"));
    let g = glb::read(&out.join("displaced.glb"));
    assert_eq!(g.triangles().len(), 16 * 2, "two triangles per flat domain");

    // The bent grid with gravel: fewer triangles where flat enough, none where not; no
    // cracks (interior edges used twice, border edges once, by position); every vertex of
    // the full tessellation within ~TOL of the decimated surface at its own (u, v).
    let mesh = bent_grid(dir.path());
    let surface = Surface::new(ControlMesh::load_obj(&mesh).unwrap());
    let (full, dec) = (dir.path().join("full"), dir.path().join("dec"));
    let tol = 0.01;
    for (o, extra) in [(&full, None), (&dec, Some(tol))] {
        let t = extra.map(|t: f64| t.to_string());
        let mut args = vec!["--height", GRAVEL, "--displace", "0.05"];
        if let Some(t) = &t {
            args.extend(["--decimate", t.as_str()]);
        }
        let r = synth(&mesh, o, &args);
        assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    }
    gltf_validator::assert_clean(&dec.join("displaced.glb"));
    let (gf, vf) = glb_vertices(&full.join("displaced.glb"), &surface, 16);
    let (gd, vd) = glb_vertices(&dec.join("displaced.glb"), &surface, 16);
    let (nf, nd) = (gf.triangles().len(), gd.triangles().len());
    assert!(nd < nf / 2 && nd > 16 * 2, "{nd} of {nf} triangles");
    let uses = edge_uses(&gd);
    let border = uses.values().filter(|&&c| c == 1).count();
    assert!(
        uses.values().all(|&c| c == 1 || c == 2),
        "an edge used more than twice"
    );
    // Open border only: 4 sides x 4 domains; decimated border edges are at most 16 per
    // domain side and at least one.
    assert!((16..=4 * 4 * 16).contains(&border), "{border} border edges");
    let border_full = edge_uses(&gf).values().filter(|&&c| c == 1).count();
    assert_eq!(border_full, 4 * 4 * 16);
    // Error at the full tessellation's vertices.
    let tris = gd.triangles();
    let mut worst = 0.0f64;
    for &(p, d, u, w) in &vf {
        let mut best: Option<DVec3> = None;
        for t in &tris {
            let [a, b, c] = t.map(|k| vd[k]);
            if a.1 != d {
                continue;
            }
            // Barycentric coordinates in (u, v).
            let det = (b.2 - a.2) * (c.3 - a.3) - (c.2 - a.2) * (b.3 - a.3);
            let l1 = ((u - a.2) * (c.3 - a.3) - (c.2 - a.2) * (w - a.3)) / det;
            let l2 = ((b.2 - a.2) * (w - a.3) - (u - a.2) * (b.3 - a.3)) / det;
            let l0 = 1.0 - l1 - l2;
            if l0 >= -1e-9 && l1 >= -1e-9 && l2 >= -1e-9 {
                best = Some(a.0 * l0 + b.0 * l1 + c.0 * l2);
                break;
            }
        }
        let q = best.expect("every (u, v) is covered by a decimated triangle");
        worst = worst.max((q - p).length());
    }
    assert!(
        worst <= 2.0 * tol,
        "decimated surface off by {worst} (tolerance {tol})"
    );
}

#[test]
fn displace_needs_a_height_channel_and_leaves_nothing_behind() {
    let dir = tempfile::tempdir().unwrap();
    let mesh = bent_grid(dir.path());
    let out = dir.path().join("out");
    let o = synth(&mesh, &out, &["--displace", "0.1"]);
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(err.trim().lines().count(), 1, "{err}");
    assert!(
        err.contains("--height") && err.contains("gravel.png"),
        "{err}"
    );
    assert!(!out.exists() || std::fs::read_dir(&out).unwrap().next().is_none());

    let o = synth(&mesh, &out, &["--height", GRAVEL, "--displace", "nan"]);
    assert!(!o.status.success());
}
