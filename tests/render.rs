//! `render` on hand-made result directories: pictures are checked for holes, framing,
//! texture continuity across face edges (a screen-space seam ratio, with a per-face-jump
//! control that must fail it), displacement, determinism and clean errors.

mod common;

use common::data;
use glam::DVec3;
use std::path::Path;
use std::sync::Arc;
use subdiv::{DomainId, Surface};
use surfsynth::io::exr::{write_face_maps, FaceMaps};
use surfsynth::maps::{FaceMaps as TexelMaps, MapLayout};
use surfsynth::render::{render_dir, Picture, RenderOptions, Scene};

/// Colour maps (R, G, B and optionally A, height) with `field(domain, x, y, P)`.
fn maps_from(
    s: &Surface,
    n: usize,
    names: &[&str],
    field: impl Fn(usize, usize, usize, DVec3) -> [f32; 5],
) -> FaceMaps {
    let mut m = FaceMaps::new(s.num_domains(), n, names);
    let mut t = vec![Default::default(); n * n];
    for d in 0..s.num_domains() {
        s.eval_texels(DomainId::from_idx(d), n, &mut t);
        for y in 0..n {
            for x in 0..n {
                let c = field(d, x, y, t[y * n + x].p);
                let i = m.index(d, x, y);
                for (k, (_, data)) in m.channels.iter_mut().enumerate() {
                    data[i] = c[k];
                }
            }
        }
    }
    m
}

fn result_dir(mesh: &Path, maps: &FaceMaps) -> tempfile::TempDir {
    let dir = tempfile::tempdir().unwrap();
    write_face_maps(dir.path().join("facemaps.exr"), maps).unwrap();
    let report = serde_json::json!({ "inputs": { "mesh": mesh.to_str().unwrap() }, "scale": 1.0 });
    std::fs::write(dir.path().join("report.json"), report.to_string()).unwrap();
    dir
}

fn small(w: u32, h: u32) -> RenderOptions {
    RenderOptions {
        width: w,
        height: h,
        ..Default::default()
    }
}

fn smooth(lambda: f64) -> impl Fn(usize, usize, usize, DVec3) -> [f32; 5] {
    move |_, _, _, p| {
        let w = std::f64::consts::TAU / lambda;
        let f = |d: DVec3, ph: f64| (0.5 + 0.35 * (w * d.normalize().dot(p) + ph).sin()) as f32;
        [
            f(DVec3::new(0.8, 0.5, 0.3), 0.0),
            f(DVec3::new(-0.3, 0.9, 0.2), 1.0),
            f(DVec3::new(0.1, -0.4, 0.9), 2.0),
            1.0,
            0.5,
        ]
    }
}

fn hash(mut h: u64) -> f32 {
    h = h.wrapping_add(0x9E37_79B9_7F4A_7C15);
    h = (h ^ (h >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    h = (h ^ (h >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    ((h ^ (h >> 31)) >> 40) as f32 / (1u64 << 24) as f32
}

fn diag(s: &Surface) -> f64 {
    let (lo, hi) = s.bounds();
    (hi - lo).length()
}

/// Pixels that missed although all four neighbours hit: holes in the surface.
fn holes(p: &Picture) -> usize {
    let (w, h) = (p.width as usize, p.height as usize);
    let hit = |x: usize, y: usize| p.domain[y * w + x] != u32::MAX;
    let mut n = 0;
    for y in 1..h - 1 {
        for x in 1..w - 1 {
            if !hit(x, y) && hit(x - 1, y) && hit(x + 1, y) && hit(x, y - 1) && hit(x, y + 1) {
                n += 1;
            }
        }
    }
    n
}

/// Screen-space seam ratio: over adjacent pixel pairs (a, b) whose first hits are in
/// different domains, the sum of |C_a - C_b|² divided by the sum over the pairs just before
/// and after it in the same direction, (a-1, a) and (b, b+1), when those lie inside one
/// domain. Comparing each seam pair with its own neighbours keeps the measure local: regions
/// where the texture changes fast on screen (grazing angles, where projected domain edges
/// crowd) weigh the same in numerator and denominator. All pixels involved must hit at
/// nearly the same depth (relative 0.5%), which leaves out occlusion boundaries. A smooth
/// texture gives about 1; a jump at face edges gives more.
fn screen_seam_ratio(p: &Picture) -> (f64, usize) {
    let (w, h) = (p.width as usize, p.height as usize);
    let d2 = |a: usize, b: usize| -> f64 {
        (0..3)
            .map(|c| (p.rgb[a][c] as f64 - p.rgb[b][c] as f64).powi(2))
            .sum()
    };
    let near = |a: usize, b: usize| {
        let (ta, tb) = (p.depth[a], p.depth[b]);
        ta.is_finite() && tb.is_finite() && (ta - tb).abs() <= 0.005 * ta.min(tb)
    };
    let (mut seam, mut inner, mut pairs) = (0.0, 0.0, 0usize);
    for y in 2..h - 2 {
        for x in 2..w - 2 {
            let a = y * w + x;
            for step in [1, w] {
                let (a0, b, b1) = (a - step, a + step, a + 2 * step);
                let dom = |i: usize| p.domain[i];
                if dom(a) == u32::MAX || dom(b) == u32::MAX || dom(a) == dom(b) {
                    continue;
                }
                if dom(a0) != dom(a) || dom(b1) != dom(b) {
                    continue;
                }
                if !(near(a0, a) && near(a, b) && near(b, b1)) {
                    continue;
                }
                seam += d2(a, b);
                inner += 0.5 * (d2(a0, a) + d2(b, b1));
                pairs += 1;
            }
        }
    }
    (seam / inner, pairs)
}

#[test]
fn pictures_are_hole_free_and_framed() {
    for rel in [
        "opensubdiv-reference/catmark_cube.obj",
        "opensubdiv-reference/catmark_nonquads.obj",
        "meshes/cube_no_bottom.obj",
        "meshes/spot_control_mesh.obj",
        "meshes/double_torus_genus2.obj",
    ] {
        let mesh = data(rel);
        let s = Surface::load_obj(&mesh).unwrap();
        let maps = maps_from(&s, 8, &["R", "G", "B"], |_, _, _, _| [0.5; 5]);
        let dir = result_dir(&mesh, &maps);
        let (pic, st) = render_dir(dir.path(), &small(320, 240)).unwrap();
        // Framing: the hit pixels span most of the picture in at least one direction.
        let (mut x0, mut x1, mut y0, mut y1) = (u32::MAX, 0, u32::MAX, 0);
        for (i, &d) in pic.domain.iter().enumerate() {
            if d != u32::MAX {
                let (x, y) = (i as u32 % 320, i as u32 / 320);
                x0 = x0.min(x);
                x1 = x1.max(x);
                y0 = y0.min(y);
                y1 = y1.max(y);
            }
        }
        let span = ((x1 - x0) as f64 / 320.0).max((y1 - y0) as f64 / 240.0);
        let h = holes(&pic);
        // Lit grey: never black, never NaN.
        let darkest = pic
            .rgb
            .iter()
            .zip(&pic.domain)
            .filter(|(_, &d)| d != u32::MAX)
            .map(|(c, _)| c[0])
            .fold(f32::INFINITY, f32::min);
        println!(
            "{rel}: {} triangles (level {}), coverage {:.3}, span {span:.2}, holes {h}, darkest {darkest:.3}",
            st.triangles, st.level, st.coverage
        );
        assert_eq!(h, 0, "{rel}");
        assert!(span > 0.75 && span <= 1.0, "{rel}: span {span}");
        assert!(
            st.coverage > 0.1 && st.coverage < 0.9,
            "{rel}: {}",
            st.coverage
        );
        assert!(darkest >= 0.01 && darkest.is_finite(), "{rel}: {darkest}");
    }
}

#[test]
fn texture_is_continuous_across_face_edges() {
    for rel in [
        "meshes/spot_control_mesh.obj",
        "opensubdiv-reference/catmark_nonquads.obj",
        "opensubdiv-reference/catmark_pole8.obj",
    ] {
        let mesh = data(rel);
        let s = Surface::load_obj(&mesh).unwrap();
        let lambda = diag(&s) / 6.0;
        let n = 16;
        let names = ["R", "G", "B"];
        let good = maps_from(&s, n, &names, smooth(lambda));
        let dir = result_dir(&mesh, &good);
        let (pic, _) = render_dir(dir.path(), &small(480, 360)).unwrap();
        let (r, pairs) = screen_seam_ratio(&pic);
        // Control: the same texture with a per-face colour offset.
        let f = smooth(lambda);
        let bad = maps_from(&s, n, &names, |d, x, y, p| {
            let mut c = f(d, x, y, p);
            let o = 0.6 * (hash(d as u64) - 0.5);
            c[0] += o;
            c[1] += o;
            c[2] += o;
            c
        });
        let dir2 = result_dir(&mesh, &bad);
        let (pic2, _) = render_dir(dir2.path(), &small(480, 360)).unwrap();
        let (r2, _) = screen_seam_ratio(&pic2);
        println!("{rel}: screen seam ratio {r:.3} over {pairs} pairs; with per-face jumps {r2:.2}");
        assert!(r < 1.25, "{rel}: {r}");
        assert!(r2 > 2.0 * r, "{rel}: control {r2} vs {r}");
    }
}

#[test]
fn picture_does_not_depend_on_thread_count_and_png_is_written() {
    let mesh = data("opensubdiv-reference/catmark_pole8.obj");
    let s = Surface::load_obj(&mesh).unwrap();
    let maps = maps_from(&s, 8, &["R", "G", "B", "A"], |d, x, y, _| {
        let k = ((d * 64 + y) * 64 + x) as u64 * 4;
        [hash(k), hash(k + 1), hash(k + 2), hash(k + 3), 0.0]
    });
    let dir = result_dir(&mesh, &maps);
    let run = |t: usize| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(t)
            .build()
            .unwrap();
        pool.install(|| render_dir(dir.path(), &small(200, 150)).unwrap().0)
    };
    let (a, b) = (run(1), run(2));
    assert!(a == b, "pictures differ between 1 and 2 threads");
    let out = dir.path().join("p.png");
    a.write_png(&out).unwrap();
    let img = image::open(&out).unwrap().to_rgb8();
    assert_eq!(img.dimensions(), (200, 150));
    assert_eq!(img.into_raw(), a.to_srgb8());
}

#[test]
fn displacement_moves_vertices_along_the_normal() {
    let mesh = data("opensubdiv-reference/catmark_cube.obj");
    let s = Surface::load_obj(&mesh).unwrap();
    let n = 8;
    // Interleaved R, G, B, A, height with height 1 everywhere.
    let layout = Arc::new(MapLayout::new(&s, n));
    let mut data = vec![0.5f32; layout.texels() * 5];
    data.chunks_mut(5).for_each(|t| t[4] = 1.0);
    let maps = TexelMaps::from_data(layout, 5, data);
    let amount = 0.2;
    let (scene, _, _) = Scene::build(&s, &maps, 3, Some(amount));
    let lm = s.limit_mesh(3);
    let mut worst: f64 = 0.0;
    for (v, p) in scene.positions().iter().enumerate() {
        let want = lm.position[v] + lm.normal[v] * (amount * 0.5);
        worst = worst.max((DVec3::new(p.x as f64, p.y as f64, p.z as f64) - want).length());
    }
    assert!(worst < 1e-5, "{worst}");

    // Through the directory: needs a height channel.
    let flat = maps_from(&s, n, &["R", "G", "B"], |_, _, _, _| [0.5; 5]);
    let dir = result_dir(&mesh, &flat);
    let mut opts = small(160, 120);
    opts.displace = Some(0.1);
    let e = render_dir(dir.path(), &opts).unwrap_err().to_string();
    assert!(e.contains("height") && e.contains("facemaps.exr"), "{e}");
    let bumpy = maps_from(&s, n, &["R", "G", "B", "height"], |_, x, y, _| {
        [0.6, 0.6, 0.6, ((x / 2 + y / 2) % 2) as f32, 0.0]
    });
    let dir = result_dir(&mesh, &bumpy);
    let (plain, _) = render_dir(dir.path(), &small(160, 120)).unwrap();
    let (disp, st) = render_dir(dir.path(), &opts).unwrap();
    assert!(st.level >= 3);
    assert_eq!(holes(&disp), 0);
    assert!(plain != disp);
}

#[test]
fn bad_inputs_give_one_line_errors() {
    let mesh = data("opensubdiv-reference/catmark_cube.obj");
    let s = Surface::load_obj(&mesh).unwrap();
    let maps = maps_from(&s, 4, &["R", "G", "B"], |_, _, _, _| [0.5; 5]);
    let one_line = |e: surfsynth::Error| {
        let t = e.to_string();
        assert!(!t.contains('\n'), "{t}");
        t
    };
    let tmp = tempfile::tempdir().unwrap();
    let o = small(64, 48);
    let e = one_line(render_dir(&tmp.path().join("none"), &o).unwrap_err());
    assert!(e.contains("none"), "{e}");
    // A directory without results.
    let e = one_line(render_dir(tmp.path(), &o).unwrap_err());
    assert!(e.contains("facemaps.exr"), "{e}");
    // Maps but no report and no --mesh.
    write_face_maps(tmp.path().join("facemaps.exr"), &maps).unwrap();
    let e = one_line(render_dir(tmp.path(), &o).unwrap_err());
    assert!(e.contains("report.json") && e.contains("--mesh"), "{e}");
    // A report naming a missing mesh.
    std::fs::write(
        tmp.path().join("report.json"),
        r#"{"inputs": {"mesh": "gone.obj"}}"#,
    )
    .unwrap();
    let e = one_line(render_dir(tmp.path(), &o).unwrap_err());
    assert!(e.contains("gone.obj"), "{e}");
    // The wrong mesh.
    let mut wrong = o.clone();
    wrong.mesh = Some(data("opensubdiv-reference/catmark_pole8.obj"));
    let e = one_line(render_dir(tmp.path(), &wrong).unwrap_err());
    assert!(
        e.contains("catmark_pole8.obj") && e.contains("domains"),
        "{e}"
    );
    // The right one given explicitly works.
    let mut right = o.clone();
    right.mesh = Some(mesh.clone());
    let (pic, _) = render_dir(tmp.path(), &right).unwrap();
    // Bad sizes and output paths; nothing left behind.
    let e = one_line(render_dir(tmp.path(), &small(0, 10)).unwrap_err());
    assert!(e.contains("width"), "{e}");
    let e = one_line(pic.write_png(&tmp.path().join("p.jpg")).unwrap_err());
    assert!(e.contains("p.jpg") && e.contains(".png"), "{e}");
    let e = one_line(pic.write_png(&tmp.path().join("no/p.png")).unwrap_err());
    assert!(e.contains("no/p.png"), "{e}");
    let mut names: Vec<String> = std::fs::read_dir(tmp.path())
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into())
        .collect();
    names.sort();
    assert_eq!(names, vec!["facemaps.exr", "report.json"]);
}

#[test]
fn command_line_writes_the_picture_or_one_error_line() {
    let exe = env!("CARGO_BIN_EXE_surfsynth");
    let mesh = data("opensubdiv-reference/catmark_cube.obj");
    let s = Surface::load_obj(&mesh).unwrap();
    let maps = maps_from(&s, 4, &["R", "G", "B"], |_, _, _, _| [0.5; 5]);
    let dir = result_dir(&mesh, &maps);
    let out = std::process::Command::new(exe)
        .args([
            "render",
            dir.path().to_str().unwrap(),
            "--width",
            "64",
            "--height",
            "48",
            "--yaw",
            "-30",
            "--pitch",
            "10",
        ])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let img = image::open(dir.path().join("preview.png")).unwrap();
    assert_eq!((img.width(), img.height()), (64, 48));

    let out = std::process::Command::new(exe)
        .args(["render", dir.path().join("missing").to_str().unwrap()])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(1));
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(err.trim_end().lines().count(), 1, "{err}");
    assert!(
        err.starts_with("error: ") && err.contains("missing"),
        "{err}"
    );
}
