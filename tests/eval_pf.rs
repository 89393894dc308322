//! pf1/pf4/pf8 (BRIEF's patch fidelity pfS, docs/eval.md) on results whose answers are
//! known: an exact copy of the example scores 0; its 8x8 blocks permuted score far worse,
//! most at S = 8; pixel noise scores about 1 or more; a smooth isometric continuation on a
//! curved open surface (a cylinder, where geodesic windows and chords differ) scores low;
//! and the three ways of laying windows agree: the 2D image path (`eval --image`), the
//! lattice of a flat grid, and the surface walk on the same flat grid.

mod common;

use common::{data, Lcg};
use glam::DVec3;
use image::GenericImageView;
use std::path::Path;
use subdiv::{ControlMesh, DomainId, Surface};
use surfsynth::eval::{
    evaluate_image, patch_fidelities_with, windows_csv, PatchFidelity, PfMethod, PfOptions, Quality,
};
use surfsynth::example::Example;
use surfsynth::io::exr::{write_face_maps, FaceMaps};

/// Fewer centres than `eval`'s 1024 keep the file fast; the figures move by a few percent.
fn opts(force_surface: bool) -> PfOptions {
    PfOptions {
        samples: 512,
        force_surface,
        ..Default::default()
    }
}

/// Side of the examples used here: the top-left crop of the shared textures (the
/// example windows, and so the cost, are about half those of the 256² originals).
const SIDE: usize = 192;

fn crop(name: &str) -> Example {
    let e = Example::load(data(&format!("textures/{name}"))).unwrap();
    let rgb = (0..SIDE * SIDE)
        .map(|i| e.rgb[(i / SIDE) * e.width + i % SIDE])
        .collect();
    Example::from_linear(SIDE, SIDE, rgb)
}

fn gravel() -> Example {
    crop("etr_gravel.png")
}

/// Reptile scales: structure (whole scales, ~30 px) where gravel has little beyond its
/// ~6 px stones.
fn scales() -> Example {
    crop("krita_reptile_scales.png")
}

/// The example's top-left SIDE² as 8-bit sRGB bytes (decoding them gives `gravel()`).
fn gravel_bytes() -> image::RgbImage {
    image::open(data("textures/etr_gravel.png"))
        .unwrap()
        .to_rgb8()
        .view(0, 0, SIDE as u32, SIDE as u32)
        .to_image()
}

/// geometry.exr maps (P, N at texel centres) of a surface.
fn geometry(s: &Surface, n: usize) -> FaceMaps {
    let mut g = FaceMaps::new(
        s.num_domains(),
        n,
        &["P.X", "P.Y", "P.Z", "N.X", "N.Y", "N.Z"],
    );
    let mut t = vec![Default::default(); n * n];
    for d in 0..s.num_domains() {
        s.eval_texels(DomainId::from_idx(d), n, &mut t);
        for (j, smp) in t.iter().enumerate() {
            let i = d * n * n + j;
            let v = [smp.p.x, smp.p.y, smp.p.z, smp.n.x, smp.n.y, smp.n.z];
            for (k, (_, data)) in g.channels.iter_mut().enumerate() {
                data[i] = v[k] as f32;
            }
        }
    }
    g
}

/// Colour maps where texel i (domain d, x, y, limit position P) gets `f` = (colour, source).
fn colour_maps(
    geo: &FaceMaps,
    f: impl Fn(usize, usize, usize, DVec3) -> ([f32; 3], [f32; 2]),
) -> FaceMaps {
    let n = geo.uniform_n().unwrap();
    let mut m = FaceMaps::new(geo.faces(), n, &["R", "G", "B", "source.u", "source.v"]);
    let (px, py, pz) = (
        geo.channel("P.X").unwrap().to_vec(),
        geo.channel("P.Y").unwrap().to_vec(),
        geo.channel("P.Z").unwrap().to_vec(),
    );
    for d in 0..geo.faces() {
        for y in 0..n {
            for x in 0..n {
                let i = m.index(d, x, y);
                let p = DVec3::new(px[i] as f64, py[i] as f64, pz[i] as f64);
                let (c, src) = f(d, x, y, p);
                let vals = [c[0], c[1], c[2], src[0], src[1]];
                for (k, (_, data)) in m.channels.iter_mut().enumerate() {
                    data[i] = vals[k];
                }
            }
        }
    }
    m
}

/// A flat K x K grid at resolution N: texel (d, x, y) is pixel (X, Y) of a (K·N)² image
/// (faces row by row from the origin, u along +x, v along +y).
struct Flat {
    k: usize,
    n: usize,
    geo: FaceMaps,
}

impl Flat {
    fn new(k: usize, n: usize) -> Self {
        Self {
            k,
            n,
            geo: geometry(&Surface::new(ControlMesh::grid(k)), n),
        }
    }

    fn pixel(&self, d: usize, x: usize, y: usize) -> (usize, usize) {
        ((d % self.k) * self.n + x, (d / self.k) * self.n + y)
    }

    fn scale(&self) -> f64 {
        1.0 / self.n as f64
    }

    /// Maps showing example pixel `at(X, Y)` at output pixel (X, Y).
    fn maps(&self, ex: &Example, at: impl Fn(usize, usize) -> (usize, usize)) -> FaceMaps {
        colour_maps(&self.geo, |d, x, y, _| {
            let (px, py) = self.pixel(d, x, y);
            let (ex_x, ex_y) = at(px, py);
            (
                ex.rgb[ex_y * ex.width + ex_x],
                [ex_x as f32 + 0.5, ex_y as f32 + 0.5],
            )
        })
    }
}

/// The copy: output pixel (X, Y) is example pixel (X + 20, Y + 30).
fn copy_at(x: usize, y: usize) -> (usize, usize) {
    (x + 20, y + 30)
}

/// 8x8 blocks of the copy permuted (a fixed shuffle of the (side/8)² blocks).
fn shuffled_blocks(side: usize) -> impl Fn(usize, usize) -> (usize, usize) {
    let nb = side / 8;
    let mut perm: Vec<usize> = (0..nb * nb).collect();
    let mut rng = Lcg(17);
    for i in (1..perm.len()).rev() {
        let j = (rng.next() * (i + 1) as f64) as usize;
        perm.swap(i, j);
    }
    move |x, y| {
        let b = perm[(y / 8) * nb + x / 8];
        copy_at((b % nb) * 8 + x % 8, (b / nb) * 8 + y % 8)
    }
}

fn show(name: &str, p: &PatchFidelity) {
    let d = &p.detail;
    let windows: Vec<usize> = d.scales.iter().map(|s| s.windows).collect();
    println!(
        "{name}: pf1 {:?} pf4 {:?} pf8 {:?} ({:?}, {} drawn, {} fallbacks, windows {windows:?})",
        p.pf1, p.pf4, p.pf8, d.method, d.drawn, d.fallbacks
    );
}

fn all(p: &PatchFidelity) -> [f64; 3] {
    [p.pf1.unwrap(), p.pf4.unwrap(), p.pf8.unwrap()]
}

#[test]
fn a_copy_scores_zero_and_shuffled_blocks_score_far_worse_at_large_s() {
    let ex = gravel();
    let flat = Flat::new(5, 32); // 160² texels inside the 256² example
    let copy = flat.maps(&ex, copy_at);
    let s = Some(flat.scale());
    let lattice = patch_fidelities_with(&copy, &flat.geo, &ex, s, &opts(false));
    let walked = patch_fidelities_with(&copy, &flat.geo, &ex, s, &opts(true));
    show("copy, lattice", &lattice);
    show("copy, surface", &walked);
    assert_eq!(lattice.detail.method, PfMethod::Lattice);
    assert_eq!(walked.detail.method, PfMethod::Surface);
    assert_eq!(walked.detail.fallbacks, 0);
    // The lattice windows are example windows bit for bit.
    assert_eq!(all(&lattice), [0.0; 3]);
    for v in all(&walked) {
        assert!(v < 1e-4, "copy by the surface walk: {v}");
    }

    // 8x8 blocks permuted: S = 1 windows straddle one or two seams and still half-match;
    // S = 4 and 8 see that the structure is broken. Gravel has little structure beyond
    // its stones (its own S = 8 windows are nearly independent samples), the scales have
    // much; either way the nearest of ~40,000 example windows keeps random-looking
    // windows well below 1 (measured 0.36 and 0.39).
    for (name, ex, floor) in [("gravel", gravel(), 0.25), ("scales", scales(), 0.3)] {
        let shuffled = flat.maps(&ex, shuffled_blocks(160));
        let sh = patch_fidelities_with(&shuffled, &flat.geo, &ex, s, &opts(false));
        show(&format!("{name}, 8x8 blocks shuffled"), &sh);
        let [p1, p4, p8] = all(&sh);
        assert!(p8 > floor, "{name}: pf8 {p8}");
        assert!(p4 > 1.5 * p1 && p8 > 1.5 * p1, "{name}: {p1} {p4} {p8}");
    }
}

/// `eval --windows`: each drawn centre's own score. Their mean must be the pfS reported
/// (for the lattice, whose centres are pixels mapped back to texels, and for the surface
/// walk), and they must say *where* structure is lost: left half a copy, right half its
/// 8x8 blocks shuffled.
#[test]
fn per_window_scores_average_to_pf_and_find_the_damaged_half() {
    let ex = scales();
    let flat = Flat::new(5, 32);
    let shuffled = shuffled_blocks(160);
    let maps = flat.maps(&ex, |x, y| {
        if x < 80 {
            copy_at(x, y)
        } else {
            shuffled(x, y)
        }
    });
    let s = Some(flat.scale());
    for force_surface in [false, true] {
        let pf = patch_fidelities_with(&maps, &flat.geo, &ex, s, &opts(force_surface));
        let d = &pf.detail;
        assert_eq!(d.centres.len(), d.drawn);
        let csv = windows_csv(d, Some(&flat.geo), 0);
        let mut lines = csv.lines();
        assert_eq!(lines.next(), Some("face,u,v,x,y,z,pf1,pf4,pf8"));
        let rows: Vec<Vec<&str>> = lines.map(|l| l.split(',').collect()).collect();
        assert_eq!(rows.len(), d.drawn);
        for (col, reported) in [(6, pf.pf1), (7, pf.pf4), (8, pf.pf8)] {
            let v: Vec<f64> = rows
                .iter()
                .filter(|r| !r[col].is_empty())
                .map(|r| r[col].parse().unwrap())
                .collect();
            let mean = v.iter().sum::<f64>() / v.len() as f64;
            let reported = reported.unwrap();
            assert!(
                (mean - reported).abs() <= 1e-9 * reported.max(1e-12),
                "{:?} column {col}: mean {mean} against {reported}",
                d.method
            );
        }
        // pf8 by the centre's x (the grid spans x in [0, 5]; the halves meet at 2.5,
        // a window reaches ~0.9 either side): clear of the join, the copy scores ~0.
        let side = |lo: f64, hi: f64| {
            let v: Vec<f64> = rows
                .iter()
                .filter(|r| !r[8].is_empty())
                .filter(|r| (lo..hi).contains(&r[3].parse::<f64>().unwrap()))
                .map(|r| r[8].parse().unwrap())
                .collect();
            assert!(v.len() > 20, "{lo}..{hi}: {} windows", v.len());
            v.iter().sum::<f64>() / v.len() as f64
        };
        let (copy, broken) = (side(0.0, 1.5), side(3.5, 5.0));
        println!(
            "{:?}: pf8 copy half {copy:.4}, shuffled half {broken:.4}",
            d.method
        );
        assert!(copy < 0.01 && broken > 0.2, "{copy} {broken}");
    }
}

#[test]
fn noise_scores_about_one_or_more() {
    let ex = surfsynth::eval::Rgb::from_example(&gravel());
    let (w, h) = (160usize, 160usize);
    let mut rng = Lcg(5);
    let noise = surfsynth::eval::Rgb {
        width: w,
        height: h,
        px: (0..w * h)
            .map(|_| {
                let v = [rng.next(), rng.next(), rng.next()];
                v.map(|c| surfsynth::example::srgb_to_linear(c as f32))
            })
            .collect(),
    };
    // 256 centres: noise is the search's worst case (no window is near, few are pruned).
    let few = PfOptions {
        samples: 256,
        ..Default::default()
    };
    let q = surfsynth::eval::image_patch_fidelities(&noise, &ex, &few);
    show("pixel noise", &q);
    // The nearest of ~30,000 example windows is a little closer than a random one.
    let pf1 = q.pf1.unwrap();
    assert!(pf1 > 0.75, "pixel noise pf1 {pf1}");
    // Blurred by the disc, pixel noise becomes a flat grey that some smooth example
    // windows resemble: pf4/pf8 of pixel noise are ~0.3, not near 1. Block noise (one
    // random colour per 8x8 block) is noise at the scales pf4 and pf8 look at (and, being
    // flat inside its blocks, resembles smooth example windows at S = 1). Through PNG
    // files and `evaluate_image`, as `eval --image` measures.
    let dir = tempfile::tempdir().unwrap();
    let (png, ex_png) = (dir.path().join("noise.png"), dir.path().join("ex.png"));
    gravel_bytes().save(&ex_png).unwrap();
    let blocks: Vec<u8> = (0..h)
        .flat_map(|y| (0..w).map(move |x| (x / 8, y / 8)))
        .flat_map(|(bx, by)| {
            let mut r = Lcg((by * 1000 + bx) as u64 + 1);
            [r.next(), r.next(), r.next()].map(|v| (v * 256.0) as u8)
        })
        .collect();
    image::save_buffer(
        &png,
        &blocks,
        w as u32,
        h as u32,
        image::ExtendedColorType::Rgb8,
    )
    .unwrap();
    let q = evaluate_image(&png, &ex_png).unwrap();
    println!("block noise: {:?} {:?} {:?}", q.pf1, q.pf4, q.pf8);
    let (pf4, pf8) = (q.pf4.unwrap(), q.pf8.unwrap());
    assert!(pf4 > 0.75 && pf8 > 0.9, "block noise pf4 {pf4} pf8 {pf8}");
}

/// An open cylinder of `sides` quads around and `rows` quads high (unit radius, square
/// quads), axis +z; `triangles` splits every quad into two triangles (three quad
/// sub-faces each, an extraordinary vertex at every centre).
fn cylinder(sides: usize, rows: usize) -> Surface {
    cylinder_mesh(sides, rows, false)
}

fn cylinder_mesh(sides: usize, rows: usize, triangles: bool) -> Surface {
    let edge = 2.0 * (std::f64::consts::PI / sides as f64).sin();
    let mut p = Vec::new();
    for r in 0..=rows {
        for i in 0..sides {
            let t = std::f64::consts::TAU * i as f64 / sides as f64;
            p.push(DVec3::new(t.cos(), t.sin(), r as f64 * edge));
        }
    }
    let s = sides as u32;
    let faces: Vec<[u32; 4]> = (0..rows as u32)
        .flat_map(|r| {
            (0..s).map(move |i| {
                let j = (i + 1) % s;
                [r * s + i, r * s + j, (r + 1) * s + j, (r + 1) * s + i]
            })
        })
        .collect();
    let tris: Vec<[u32; 3]> = faces
        .iter()
        .flat_map(|f| [[f[0], f[1], f[2]], [f[0], f[2], f[3]]])
        .collect();
    let refs: Vec<&[u32]> = if triangles {
        tris.iter().map(|f| f.as_slice()).collect()
    } else {
        faces.iter().map(|f| f.as_slice()).collect()
    };
    Surface::new(ControlMesh::from_faces(p, &refs).unwrap())
}

/// A smooth colour field, periodic with period `pu` pixels in u.
fn smooth(u: f64, v: f64, pu: f64) -> [f32; 3] {
    let t = std::f64::consts::TAU;
    [
        (0.45 + 0.3 * (t * u / pu).sin() * (t * v / 23.0).cos()) as f32,
        (0.4 + 0.25 * (t * (u / pu + v / 31.0)).sin()) as f32,
        (0.5 + 0.3 * (t * (2.0 * u / pu - v / 17.0)).cos()) as f32,
    ]
}

#[test]
fn a_smooth_isometric_continuation_on_a_cylinder_scores_low() {
    // A cylinder is curved but unrolls onto the plane without stretch: source = (arc
    // length around, height) / S is an isometry, and only geodesic windows (not chords)
    // follow it. Its open ends must skip the windows that leave the surface.
    let surface = cylinder(16, 4);
    let n = 24;
    let geo = geometry(&surface, n);
    // Mean radius of the limit surface and the scale: one pixel per texel spacing.
    let (px, py) = (geo.channel("P.X").unwrap(), geo.channel("P.Y").unwrap());
    let radius = px
        .iter()
        .zip(py)
        .map(|(&x, &y)| (x as f64).hypot(y as f64))
        .sum::<f64>()
        / px.len() as f64;
    let h = std::f64::consts::TAU * radius / (16 * n) as f64;
    let circumference = (16 * n) as f64; // pixels around
    let pu = circumference / 20.0; // 20 periods around: seamless where θ wraps
    let ex = Example::from_linear(
        160,
        160,
        (0..160 * 160)
            .map(|i| smooth((i % 160) as f64 + 0.5, (i / 160) as f64 + 0.5, pu))
            .collect(),
    );
    let maps = colour_maps(&geo, |_, _, _, p| {
        let theta = p.y.atan2(p.x).rem_euclid(std::f64::consts::TAU);
        let (u, v) = (radius * theta / h, p.z / h + 20.0);
        (smooth(u, v, pu), [u as f32, v as f32])
    });
    let r = patch_fidelities_with(&maps, &geo, &ex, Some(h), &opts(false));
    show("cylinder", &r);
    assert_eq!(r.detail.method, PfMethod::Surface);
    let [p1, p4, p8] = all(&r);
    assert!(p1 < 0.05 && p4 < 0.05 && p8 < 0.05, "{p1} {p4} {p8}");
    // Where θ wraps the sources jump: those texels fit from one side only, no fallback.
    assert!(r.detail.fallbacks <= r.detail.drawn / 50, "{:?}", r.detail);
    // The open ends: 4 rows of 24 texels, windows of 6·8 + 8 pixels at S = 8 fit only
    // around the middle, while S = 1 windows fit almost everywhere.
    let sc = &r.detail.scales;
    assert!(sc[2].skipped > sc[2].windows / 2, "{sc:?}");
    assert!(sc[0].skipped < sc[0].windows / 5, "{sc:?}");

    // The same maps on 1 and 2 threads: bit-identical.
    let run = |t: usize| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(t)
            .build()
            .unwrap()
            .install(|| patch_fidelities_with(&maps, &geo, &ex, Some(h), &opts(false)))
    };
    assert_eq!(run(1), run(2));
}

#[test]
fn triangles_work_too() {
    // The cylinder as triangles: every domain is a quad sub-face, texel density varies and
    // the limit surface is only nearly a cylinder, so the continuation is nearly isometric.
    let surface = cylinder_mesh(16, 4, true);
    let n = 12;
    let geo = geometry(&surface, n);
    let (px, py) = (geo.channel("P.X").unwrap(), geo.channel("P.Y").unwrap());
    let radius = px
        .iter()
        .zip(py)
        .map(|(&x, &y)| (x as f64).hypot(y as f64))
        .sum::<f64>()
        / px.len() as f64;
    let h = std::f64::consts::TAU * radius / (16 * 2 * n) as f64;
    let pu = (16 * 2 * n) as f64 / 20.0;
    let ex = Example::from_linear(
        160,
        160,
        (0..160 * 160)
            .map(|i| smooth((i % 160) as f64 + 0.5, (i / 160) as f64 + 0.5, pu))
            .collect(),
    );
    let maps = colour_maps(&geo, |_, _, _, p| {
        let theta = p.y.atan2(p.x).rem_euclid(std::f64::consts::TAU);
        let (u, v) = (radius * theta / h, p.z / h + 20.0);
        (smooth(u, v, pu), [u as f32, v as f32])
    });
    let r = patch_fidelities_with(&maps, &geo, &ex, Some(h), &opts(false));
    show("triangulated cylinder", &r);
    assert_eq!(r.detail.method, PfMethod::Surface);
    assert!(r.detail.fallbacks <= r.detail.drawn / 20, "{:?}", r.detail);
    for v in all(&r) {
        assert!(v < 0.1, "{v}");
    }
}

#[test]
fn image_lattice_and_surface_paths_agree_on_a_flat_grid() {
    let ex = gravel();
    let flat = Flat::new(5, 32);
    let at = shuffled_blocks(160);
    let maps = flat.maps(&ex, &at);
    let s = Some(flat.scale());
    let lattice = patch_fidelities_with(&maps, &flat.geo, &ex, s, &opts(false));
    let walked = patch_fidelities_with(&maps, &flat.geo, &ex, s, &opts(true));
    show("lattice", &lattice);
    show("surface", &walked);
    assert_eq!(lattice.detail.method, PfMethod::Lattice);
    for (a, b) in all(&lattice).iter().zip(all(&walked)) {
        // Different texels are drawn (pixel order vs texel order): sampling noise only.
        assert!(
            (a - b).abs() <= 0.1 * a.max(b),
            "lattice {a} vs surface {b}"
        );
    }

    // The same picture as a PNG (the example's own sRGB bytes, so decoding gives the same
    // linear values) through the 2D path: identical figures.
    let dir = tempfile::tempdir().unwrap();
    let raw = image::open(data("textures/etr_gravel.png"))
        .unwrap()
        .to_rgb8();
    let mut buf = Vec::with_capacity(160 * 160 * 3);
    for y in 0..160 {
        for x in 0..160 {
            let (ex_x, ex_y) = at(x, y);
            buf.extend_from_slice(&raw.get_pixel(ex_x as u32, ex_y as u32).0);
        }
    }
    let png = dir.path().join("out.png");
    image::save_buffer(&png, &buf, 160, 160, image::ExtendedColorType::Rgb8).unwrap();
    let img = Example::load(&png).unwrap();
    let rgb = surfsynth::eval::Rgb::from_example(&img);
    let two_d = surfsynth::eval::image_patch_fidelities(
        &rgb,
        &surfsynth::eval::Rgb::from_example(&ex),
        &opts(false),
    );
    show("2D image", &two_d);
    assert_eq!(two_d.detail.method, PfMethod::Image);
    assert_eq!(
        (two_d.pf1, two_d.pf4, two_d.pf8),
        (lattice.pf1, lattice.pf4, lattice.pf8)
    );
}

#[test]
fn a_mirrored_or_rescaled_flat_grid_is_walked_not_read_as_the_pixel_grid() {
    // Rows of the example along −v (handedness "outside"): the lattice would compare the
    // mirror image; the sources say so, and the surface walk follows them.
    let ex = gravel();
    let flat = Flat::new(5, 32);
    let mirrored = flat.maps(&ex, |x, y| copy_at(x, 159 - y));
    let s = Some(flat.scale());
    let r = patch_fidelities_with(&mirrored, &flat.geo, &ex, s, &opts(false));
    show("mirrored copy", &r);
    assert_eq!(r.detail.method, PfMethod::Surface);
    for v in all(&r) {
        assert!(v < 1e-4, "{v}");
    }
    // Without sources the scale decides: one texel per pixel is the lattice, two are not.
    let mut plain = flat.maps(&ex, copy_at);
    plain
        .channels
        .retain(|(name, _)| !name.starts_with("source"));
    let r = patch_fidelities_with(&plain, &flat.geo, &ex, s, &opts(false));
    assert_eq!(r.detail.method, PfMethod::Lattice);
    let r = patch_fidelities_with(
        &plain,
        &flat.geo,
        &ex,
        Some(2.0 * flat.scale()),
        &opts(false),
    );
    assert_eq!(r.detail.method, PfMethod::Surface);
    assert_eq!(r.detail.fallbacks, r.detail.drawn);
}

fn write_dir(dir: &Path, colour: &FaceMaps, geo: &FaceMaps, scale: f64, example: &Path) {
    write_face_maps(dir.join("facemaps.exr"), colour).unwrap();
    write_face_maps(dir.join("geometry.exr"), geo).unwrap();
    let report = serde_json::json!({
        "method": "coherent",
        "scale": scale,
        "seed": 1,
        "inputs": { "mesh": "grid.obj", "example": example.display().to_string() },
    });
    std::fs::write(dir.join("report.json"), report.to_string()).unwrap();
}

#[test]
fn command_line_finds_the_example_in_the_report_and_measures_images() {
    let exe = env!("CARGO_BIN_EXE_surfsynth");
    let ex_path = data("textures/etr_gravel.png");
    let ex = Example::load(&ex_path).unwrap();
    let flat = Flat::new(2, 32);
    let maps = flat.maps(&ex, copy_at);
    let tmp = tempfile::tempdir().unwrap();
    write_dir(tmp.path(), &maps, &flat.geo, flat.scale(), &ex_path);
    let out = std::process::Command::new(exe)
        .arg("eval")
        .arg(tmp.path())
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let q: Quality = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!((q.pf1, q.pf4, q.pf8), (Some(0.0), Some(0.0), Some(0.0)));
    assert_eq!(q.example.as_deref(), Some(ex_path.to_str().unwrap()));
    let d = q.pf_detail.unwrap();
    assert_eq!((d.method, d.drawn), (PfMethod::Lattice, 1024));

    // A report naming a missing example: no pfS, no error.
    write_dir(
        tmp.path(),
        &maps,
        &flat.geo,
        flat.scale(),
        Path::new("gone.png"),
    );
    let out = std::process::Command::new(exe)
        .arg("eval")
        .arg(tmp.path())
        .output()
        .unwrap();
    assert!(out.status.success());
    let q: Quality = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!((q.pf1, q.example), (None, None));
    // ... and `--windows` there is a one-line error that writes nothing.
    let csv = tmp.path().join("windows.csv");
    let out = std::process::Command::new(exe)
        .arg("eval")
        .arg(tmp.path())
        .arg("--windows")
        .arg(&csv)
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(err.trim().lines().count(), 1, "{err}");
    assert!(err.contains("windows.csv") && !csv.exists(), "{err}");
    // With the example given, one row per drawn window.
    let out = std::process::Command::new(exe)
        .arg("eval")
        .arg(tmp.path())
        .arg("--example")
        .arg(&ex_path)
        .arg("--windows")
        .arg(&csv)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = std::fs::read_to_string(&csv).unwrap();
    assert!(
        text.starts_with("face,u,v,x,y,z,pf1,pf4,pf8\n"),
        "{text:.80}"
    );
    assert_eq!(text.lines().count(), 1 + 1024);

    // --image: the example itself scores 0.
    let out = std::process::Command::new(exe)
        .args(["eval", "--image"])
        .arg(&ex_path)
        .arg("--example")
        .arg(&ex_path)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    for k in ["pf1", "pf4", "pf8"] {
        assert_eq!(v[k].as_f64(), Some(0.0), "{k}: {v}");
    }
    assert_eq!(v["pf_detail"]["method"], "image");
    // --image without --example, or a missing image: one line, non-zero exit.
    for args in [
        vec!["eval", "--image", "x.png"],
        vec![
            "eval",
            "--image",
            "nope.png",
            "--example",
            ex_path.to_str().unwrap(),
        ],
    ] {
        let out = std::process::Command::new(exe)
            .args(&args)
            .output()
            .unwrap();
        assert!(!out.status.success());
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(err.trim_end().lines().count(), 1, "{err}");
    }
}
