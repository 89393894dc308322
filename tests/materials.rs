//! Material sets (issue 15 items 1–2): every map copied from the same source position by
//! every method, the normal map re-expressed in the atlas's UV tangent frames, and bad
//! material inputs refused in one line with nothing left in `--out`.

mod common;

use common::data;
use glam::DVec3;
use std::path::{Path, PathBuf};
use std::process::Command;
use surfsynth::example::Example;
use surfsynth::io::exr::{read_face_maps, FaceMaps};
use surfsynth::synthesizer::{CacheDir, Handedness, Method, NormalConvention, Synthesizer};

const SIZE: u32 = 64;

/// A 64² material in `dir`: base colour (a crop of the gravel photograph), a 16-bit height,
/// a tangent-space normal map derived from it (OpenGL: +Y up the image), roughness and
/// metallic (8-bit gray); and the normal map in DirectX's convention (green flipped).
fn material(dir: &Path) -> Vec<(String, PathBuf)> {
    let img = image::open(data("textures/etr_gravel.png"))
        .unwrap()
        .to_rgb8();
    let base = image::imageops::crop_imm(&img, 40, 60, SIZE, SIZE).to_image();
    base.save(dir.join("base.png")).unwrap();
    let h: Vec<f64> = base
        .pixels()
        .map(|p| (p.0[0] as f64 + p.0[1] as f64 + p.0[2] as f64) / (3.0 * 255.0))
        .collect();
    let at = |x: i64, y: i64| {
        let (x, y) = (x.clamp(0, SIZE as i64 - 1), y.clamp(0, SIZE as i64 - 1));
        h[(y * SIZE as i64 + x) as usize]
    };
    image::ImageBuffer::from_fn(SIZE, SIZE, |x, y| {
        image::Luma([(at(x as i64, y as i64) * 65535.0) as u16])
    })
    .save(dir.join("height.png"))
    .unwrap();
    let normal = |green_down: bool| {
        image::ImageBuffer::from_fn(SIZE, SIZE, |x, y| {
            let (x, y) = (x as i64, y as i64);
            // Slopes of 6 x height: normals up to ~60° from the surface normal.
            let gx = 3.0 * (at(x + 1, y) - at(x - 1, y));
            let gy = 3.0 * (at(x, y - 1) - at(x, y + 1)); // up the image
            let n = DVec3::new(-gx, -gy, 1.0).normalize();
            let g = if green_down { -n.y } else { n.y };
            image::Rgb([n.x, g, n.z].map(|c| ((c * 0.5 + 0.5) * 65535.0).round() as u16))
        })
    };
    normal(false).save(dir.join("normal.png")).unwrap();
    normal(true).save(dir.join("normal_dx.png")).unwrap();
    image::ImageBuffer::from_fn(SIZE, SIZE, |x, y| {
        image::Luma([(255.0 * (1.0 - at(x as i64, y as i64))) as u8])
    })
    .save(dir.join("roughness.png"))
    .unwrap();
    image::ImageBuffer::from_fn(SIZE, SIZE, |x, y| {
        image::Luma([if (x / 8 + y / 8) % 2 == 0 { 255u8 } else { 30 }])
    })
    .save(dir.join("metallic.png"))
    .unwrap();
    ["normal", "roughness", "height", "metallic"]
        .iter()
        .map(|n| (n.to_string(), dir.join(format!("{n}.png"))))
        .collect()
}

fn synthesizer(dir: &Path, maps: &[(String, PathBuf)], method: Method) -> Synthesizer {
    let mut s = Synthesizer::new(data("meshes/spot_control_mesh.obj"), dir.join("base.png"))
        .method(method)
        .resolution(common::env_or("MATERIALS_N", 8))
        .seed(5)
        .cache(CacheDir::Off);
    for (n, f) in maps {
        s = s.map(n, f);
    }
    s
}

/// For every texel and every method, each map's channels equal that map's bilinear sample
/// at (source.u, source.v) within 1e-4 (normal.G in the field's frame: 1 − G for tiles).
/// Jump maps without their texture blending: with it a texel beside a break mixes in
/// other places too, every channel with the same shares (`synth::face_maps_blended`'s
/// unit test checks that).
#[test]
fn every_map_is_copied_from_the_same_source_by_every_method() {
    let dir = tempfile::tempdir().unwrap();
    let maps = material(dir.path());
    let full = Example::load_with_maps(dir.path().join("base.png"), &maps).unwrap();
    let names = full.channel_names();
    assert_eq!(
        names,
        [
            "R",
            "G",
            "B",
            "normal.R",
            "normal.G",
            "normal.B",
            "roughness.Y",
            "height.Y",
            "metallic.Y"
        ]
    );
    for method in Method::ALL {
        let mut w = surfsynth::synthesizer::Weights::default();
        w.maps.push(("normal".into(), 0.5));
        let r = synthesizer(dir.path(), &maps, method)
            .weights(w)
            .jump_params(surfsynth::synth::JumpParams {
                blend: None,
                ..Default::default()
            })
            .run()
            .unwrap();
        let (su, sv) = (
            r.maps.channel("source.u").unwrap(),
            r.maps.channel("source.v").unwrap(),
        );
        let chans: Vec<&[f32]> = names.iter().map(|n| r.maps.channel(n).unwrap()).collect();
        let mut v = vec![0f32; names.len()];
        let mut worst = 0f32;
        for i in 0..su.len() {
            full.bilinear(su[i], sv[i], &mut v);
            for (c, name) in names.iter().enumerate() {
                let want = if name == "normal.G" { 1.0 - v[c] } else { v[c] };
                let err = (chans[c][i] - want).abs();
                worst = worst.max(err);
                assert!(
                    err <= 1e-4,
                    "{}: {name} at texel {i}: {} vs {want}",
                    method.name(),
                    chans[c][i]
                );
            }
        }
        assert_eq!(r.maps.channel("height"), r.maps.channel("height.Y"));
        // Sources vary (the maps are not constant copies of one pixel).
        let distinct = su.iter().filter(|&&u| (u - su[0]).abs() > 1.0).count();
        assert!(distinct > su.len() / 4, "{}: sources vary", method.name());
        eprintln!("{}: worst map error {worst:e}", method.name());
    }
}

/// A minimal OBJ reader: positions, texture coordinates, normals, faces (v/vt/vn).
struct Obj {
    v: Vec<DVec3>,
    vt: Vec<[f64; 2]>,
    vn: Vec<DVec3>,
    /// Triangles of the quads split (0, 1, 2), (0, 2, 3), as OBJ readers do: (v, vt, vn).
    tris: Vec<[(usize, usize, usize); 3]>,
}

fn read_obj(path: &Path) -> Obj {
    let text = std::fs::read_to_string(path).unwrap();
    let mut o = Obj {
        v: vec![],
        vt: vec![],
        vn: vec![],
        tris: vec![],
    };
    for line in text.lines() {
        let mut it = line.split_whitespace();
        let nums = |it: std::str::SplitWhitespace| -> Vec<f64> {
            it.map(|x| x.parse::<f64>().unwrap()).collect()
        };
        match it.next() {
            Some("v") => {
                let p = nums(it);
                o.v.push(DVec3::new(p[0], p[1], p[2]));
            }
            Some("vt") => {
                let p = nums(it);
                o.vt.push([p[0], p[1]]);
            }
            Some("vn") => {
                let p = nums(it);
                o.vn.push(DVec3::new(p[0], p[1], p[2]));
            }
            Some("f") => {
                let c: Vec<(usize, usize, usize)> = it
                    .map(|t| {
                        let k: Vec<usize> = t.split('/').map(|x| x.parse().unwrap()).collect();
                        (k[0] - 1, k[1] - 1, k[2] - 1)
                    })
                    .collect();
                for k in 1..c.len() - 1 {
                    o.tris.push([c[0], c[k], c[k + 1]]);
                }
            }
            _ => {}
        }
    }
    o
}

fn read_png16(path: &Path) -> (u32, u32, Vec<[f64; 3]>) {
    let img = image::open(path).unwrap();
    assert!(
        matches!(img, image::DynamicImage::ImageRgb16(_)),
        "{} is 16-bit RGB",
        path.display()
    );
    let b = img.to_rgb16();
    let px = b
        .pixels()
        .map(|p| p.0.map(|c| c as f64 / 65535.0))
        .collect();
    (b.width(), b.height(), px)
}

fn decode(c: [f64; 3], t: DVec3, b: DVec3, n: DVec3) -> DVec3 {
    (t * (2.0 * c[0] - 1.0) + b * (2.0 * c[1] - 1.0) + n * (2.0 * c[2] - 1.0)).normalize()
}

/// World normals decoded from facemaps.exr with (T, N x T, N) of geometry.exr, and from
/// atlas_normal.png with tangents from surface.obj's UVs (per triangle T = dP/ds and
/// B = dP/dt, summed per vertex, interpolated, orthonormal to the interpolated vertex
/// normal: MikkTSpace's construction), at every texel centre of every domain —
/// chart borders and n-gon sub-faces included. Returns (max angle in degrees, fraction of
/// texels whose stored value differs between the two files by > 0.05).
fn normal_agreement(out: &Path) -> (f64, f64) {
    let fm = read_face_maps(out.join("facemaps.exr")).unwrap();
    let geo = read_face_maps(out.join("geometry.exr")).unwrap();
    let obj = read_obj(&out.join("surface.obj"));
    let (w, h, atlas) = read_png16(&out.join("atlas_normal.png"));
    let layout = surfsynth::io::atlas::AtlasLayout::of(
        fm.layout.clone(),
        surfsynth::io::atlas::DEFAULT_GUTTER,
    );
    assert_eq!((w as usize, h as usize), (layout.width(), layout.height()));
    // The domain of every atlas pixel (tiles of any size).
    let g = surfsynth::io::atlas::DEFAULT_GUTTER;
    let mut owner = vec![usize::MAX; (w * h) as usize];
    for d in 0..fm.faces() {
        let (x0, y0) = layout.interior_origin(d);
        let (tw, th) = layout.tile(d);
        for y in y0 - g..y0 - g + th {
            owner[y * w as usize + x0 - g..y * w as usize + x0 - g + tw].fill(d);
        }
    }
    let tile_of = |px: f64, py: f64| owner[py as usize * w as usize + px as usize];
    // Triangles bucketed by atlas tile (their UV centroid).
    let mut by_tile: Vec<Vec<usize>> = vec![Vec::new(); fm.faces()];
    for (k, t) in obj.tris.iter().enumerate() {
        let c = t.iter().fold([0.0; 2], |a, &(_, vt, _)| {
            [a[0] + obj.vt[vt][0] / 3.0, a[1] + obj.vt[vt][1] / 3.0]
        });
        let (px, py) = (c[0] * w as f64, (1.0 - c[1]) * h as f64);
        by_tile[tile_of(px, py)].push(k);
    }
    // MikkTSpace-like vertex tangents: per triangle dP/ds and dP/dt from the UV
    // derivatives, summed per texture-coordinate vertex.
    let tri_tangents = |tri: [(usize, usize, usize); 3]| {
        let p = tri.map(|(v, _, _)| obj.v[v]);
        let uv = tri.map(|(_, vt, _)| obj.vt[vt]);
        let (e1, e2) = (p[1] - p[0], p[2] - p[0]);
        let (s1, t1) = (uv[1][0] - uv[0][0], uv[1][1] - uv[0][1]);
        let (s2, t2) = (uv[2][0] - uv[0][0], uv[2][1] - uv[0][1]);
        let r = 1.0 / (s1 * t2 - s2 * t1);
        ((e1 * t2 - e2 * t1) * r, (e2 * s1 - e1 * s2) * r)
    };
    let mut ds = vec![DVec3::ZERO; obj.vt.len()];
    let mut dt = vec![DVec3::ZERO; obj.vt.len()];
    let mut vnormal = vec![DVec3::ZERO; obj.vt.len()];
    for &tri in &obj.tris {
        let (a, b) = tri_tangents(tri);
        for (_, vt, vn) in tri {
            ds[vt] += a;
            dt[vt] += b;
            vnormal[vt] = obj.vn[vn];
        }
    }
    let vtan: Vec<DVec3> = (0..obj.vt.len())
        .map(|k| (ds[k] - vnormal[k] * vnormal[k].dot(ds[k])).normalize_or_zero())
        .collect();
    let vsign: Vec<f64> = (0..obj.vt.len())
        .map(|k| {
            if vnormal[k].cross(vtan[k]).dot(dt[k]) < 0.0 {
                -1.0
            } else {
                1.0
            }
        })
        .collect();
    let mut worst_tri = 0f64;
    let ch = |m: &FaceMaps, n: &str| m.channel(n).unwrap().to_vec();
    let (nr, ng, nb) = (
        ch(&fm, "normal.R"),
        ch(&fm, "normal.G"),
        ch(&fm, "normal.B"),
    );
    let nrm: Vec<Vec<f32>> = ["N.X", "N.Y", "N.Z"].iter().map(|c| ch(&geo, c)).collect();
    let tan: Vec<Vec<f32>> = ["T.X", "T.Y", "T.Z"].iter().map(|c| ch(&geo, c)).collect();
    let (mut worst, mut differ, mut count) = (0f64, 0usize, 0usize);
    for d in 0..fm.faces() {
        let (x0, y0) = layout.interior_origin(d);
        let (nu, nv) = fm.layout.dims(d);
        for y in 0..nv {
            for x in 0..nu {
                let i = fm.layout.start(d) + y * nu + x;
                let g =
                    |v: &Vec<Vec<f32>>| DVec3::new(v[0][i] as f64, v[1][i] as f64, v[2][i] as f64);
                let (nn, t) = (g(&nrm), g(&tan));
                let stored = [nr[i] as f64, ng[i] as f64, nb[i] as f64];
                let wf = decode(stored, t, nn.cross(t), nn);
                // The atlas pixel of this texel and the triangle holding its UV.
                let (px, py) = (x0 + x, y0 + y);
                let c = atlas[py * w as usize + px];
                let (s, tt) = (
                    (px as f64 + 0.5) / w as f64,
                    1.0 - (py as f64 + 0.5) / h as f64,
                );
                let mut found = None;
                for &k in &by_tile[tile_of(px as f64, py as f64)] {
                    let tri = obj.tris[k];
                    let [a, b, cc] = tri.map(|(_, vt, _)| obj.vt[vt]);
                    let det = (b[0] - a[0]) * (cc[1] - a[1]) - (cc[0] - a[0]) * (b[1] - a[1]);
                    let l1 = ((s - a[0]) * (cc[1] - a[1]) - (cc[0] - a[0]) * (tt - a[1])) / det;
                    let l2 = ((b[0] - a[0]) * (tt - a[1]) - (s - a[0]) * (b[1] - a[1])) / det;
                    let l = [1.0 - l1 - l2, l1, l2];
                    if l.iter().all(|&v| v >= -1e-9) {
                        found = Some((tri, l));
                        break;
                    }
                }
                let (tri, l) = found.unwrap_or_else(|| panic!("no triangle at texel {i}"));
                let vn =
                    (obj.vn[tri[0].2] * l[0] + obj.vn[tri[1].2] * l[1] + obj.vn[tri[2].2] * l[2])
                        .normalize();

                // Per triangle (the frame jumps at the diagonal a texel centre may lie on).
                let (tu, bu) = tri_tangents(tri);
                let tu = (tu - vn * vn.dot(tu)).normalize();
                let bu = (bu - vn * vn.dot(bu) - tu * tu.dot(bu)).normalize();
                let wt = decode(c, tu, bu, vn);
                worst_tri = worst_tri.max(wt.dot(wf).clamp(-1.0, 1.0).acos().to_degrees());
                // Vertex tangents interpolated (MikkTSpace; surface.glb's TANGENT).
                let ti = tri.map(|(_, vt, _)| vt);
                let tv = vtan[ti[0]] * l[0] + vtan[ti[1]] * l[1] + vtan[ti[2]] * l[2];
                let tv = (tv - vn * vn.dot(tv)).normalize();
                let bv = vn.cross(tv) * vsign[ti[0]];
                let wa = decode(c, tv, bv, vn);
                let angle = wa.dot(wf).clamp(-1.0, 1.0).acos().to_degrees();
                worst = worst.max(angle);
                if (0..3).any(|k| (c[k] - stored[k]).abs() > 0.05) {
                    differ += 1;
                }
                count += 1;
            }
        }
    }
    eprintln!("per-triangle frames: worst {worst_tri:.2}°");
    (worst, differ as f64 / count as f64)
}

/// The normal decoded from atlas_normal.png in surface.obj's own UV frames is the one
/// facemaps.exr holds in the field's frame, within 2° at every texel (both handednesses;
/// Spot has triangles and pentagons, so n-gon sub-faces are in it), and the atlas is not
/// merely a copy of the face maps (the frames differ).
#[test]
fn atlas_normals_match_the_field_frame_normals_in_world_space() {
    let dir = tempfile::tempdir().unwrap();
    let maps = material(dir.path());
    let surface = common::load("meshes/spot_control_mesh.obj");
    assert!((0..surface.num_domains()).any(|d| matches!(
        surface.domain(subdiv::DomainId::from_idx(d)),
        subdiv::Domain::SubFace { .. }
    )));
    for h in [Handedness::Tiles, Handedness::Outside] {
        let out = dir.path().join(format!("out-{h:?}"));
        synthesizer(dir.path(), &maps[..1], Method::Coherent)
            .handedness(h)
            .run_to(&out)
            .unwrap();
        let (worst, differ) = normal_agreement(&out);
        eprintln!(
            "{h:?}: worst {worst:.3}°, {:.0}% of texels re-expressed",
            100.0 * differ
        );
        assert!(worst <= 2.0, "{h:?}: {worst}°");
        assert!(
            differ > 0.3,
            "{h:?}: only {differ} of the atlas differs from the face maps"
        );
        // geometry.exr says which way the rows run.
        let bytes = std::fs::read(out.join("geometry.exr")).unwrap();
        let key = b"tangentHandedness\0int\0";
        let at = bytes
            .windows(key.len())
            .position(|w| w == key)
            .expect("tangentHandedness attribute");
        let v = i32::from_le_bytes(
            bytes[at + key.len() + 4..at + key.len() + 8]
                .try_into()
                .unwrap(),
        );
        assert_eq!(v, h.bitangent_sign());
    }
}

/// The same agreement on per-face resolutions (`--texel-size`): tiles of different sizes,
/// shelf-packed, and UV frames across 2:1 and larger resolution steps.
#[test]
fn atlas_normals_match_on_per_face_resolutions() {
    let dir = tempfile::tempdir().unwrap();
    let maps = material(dir.path());
    let surface = common::load("meshes/spot_control_mesh.obj");
    let l = surfsynth::texels::TexelGeometry::compute(&surface, 16).median_spacing(&surface);
    let out = dir.path().join("out-per-face");
    synthesizer(dir.path(), &maps[..1], Method::Coherent)
        .texel_size(l)
        .run_to(&out)
        .unwrap();
    let fm = read_face_maps(out.join("facemaps.exr")).unwrap();
    assert!(
        fm.uniform_n().is_none(),
        "--texel-size gives per-face resolutions"
    );
    let (worst, differ) = normal_agreement(&out);
    eprintln!(
        "per face: worst {worst:.3}°, {:.0}% re-expressed",
        100.0 * differ
    );
    assert!(worst <= 2.0, "{worst}°");
    assert!(differ > 0.3, "only {differ} of the atlas differs");
}

/// A DirectX normal map (green down) gives the same face maps as its OpenGL twin.
#[test]
fn directx_convention_flips_green() {
    let dir = tempfile::tempdir().unwrap();
    let maps = material(dir.path());
    let run = |file: &str, c: NormalConvention| {
        synthesizer(
            dir.path(),
            &[("normal".to_string(), dir.path().join(file))],
            Method::Coherent,
        )
        .normal_convention(c)
        .run()
        .unwrap()
        .maps
    };
    let gl = run("normal.png", NormalConvention::OpenGl);
    let dx = run("normal_dx.png", NormalConvention::DirectX);
    assert_eq!(gl.channel("source.u"), dx.channel("source.u"));
    let (a, b) = (
        gl.channel("normal.G").unwrap(),
        dx.channel("normal.G").unwrap(),
    );
    let worst = a
        .iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0f32, f32::max);
    assert!(worst < 1e-4, "{worst}");
    let _ = maps;
}

fn cli(args: &[&std::ffi::OsStr]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_surfsynth"))
        .args(args)
        .env("SURFSYNTH_PROGRESS_AFTER", "1000")
        .output()
        .unwrap()
}

/// Maps of another size, a missing map file, an unknown `--match` name, a bad NAME=FILE,
/// a repeated name: one line naming the file (or flag) and the problem, nothing in --out.
#[test]
fn bad_material_inputs_are_one_line_errors_and_leave_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let maps = material(dir.path());
    image::ImageBuffer::from_fn(32, 64, |_, _| image::Luma([9u8]))
        .save(dir.path().join("narrow.png"))
        .unwrap();
    let mesh = data("meshes/cube_no_bottom.obj");
    let base = dir.path().join("base.png");
    let narrow = dir.path().join("narrow.png");
    let missing = dir.path().join("missing.png");
    let normal = &maps[0].1;
    let arg = |k: &str, p: &Path| format!("{k}={}", p.display());
    let cases: Vec<(Vec<String>, Vec<String>)> = vec![
        (
            vec!["--map".into(), arg("roughness", &narrow)],
            vec![
                narrow.display().to_string(),
                "32x64".into(),
                "same size".into(),
            ],
        ),
        (
            vec!["--map".into(), arg("roughness", &missing)],
            vec![missing.display().to_string(), "cannot read".into()],
        ),
        (
            vec![
                "--map".into(),
                arg("normal", normal),
                "--match".into(),
                "rough=1".into(),
            ],
            vec![
                "--match rough".into(),
                "no map named".into(),
                "normal".into(),
            ],
        ),
        (
            vec!["--map".into(), "normal.png".into()],
            vec!["normal.png".into(), "NAME=FILE".into()],
        ),
        (
            vec!["--map".into(), format!("bad/name={}", normal.display())],
            vec!["bad/name".into(), "letters, digits".into()],
        ),
        (
            vec![
                "--map".into(),
                arg("normal", normal),
                "--map".into(),
                arg("normal", normal),
            ],
            vec!["normal".into(), "twice".into()],
        ),
        (
            vec![
                "--map".into(),
                arg("normal", &dir.path().join("roughness.png")),
            ],
            vec!["roughness.png".into(), "grayscale".into()],
        ),
    ];
    for (k, (extra, want)) in cases.iter().enumerate() {
        let out = dir.path().join(format!("out{k}"));
        let mut args: Vec<std::ffi::OsString> = vec![
            "synth".into(),
            "--mesh".into(),
            mesh.clone().into(),
            "--example".into(),
            base.clone().into(),
            "--resolution".into(),
            "4".into(),
            "--no-cache".into(),
            "--out".into(),
            out.clone().into(),
        ];
        args.extend(extra.iter().map(Into::into));
        let refs: Vec<&std::ffi::OsStr> = args.iter().map(|a| a.as_os_str()).collect();
        let o = cli(&refs);
        let err = String::from_utf8_lossy(&o.stderr).trim().to_string();
        assert!(!o.status.success(), "case {k} succeeded");
        assert_eq!(err.lines().count(), 1, "case {k}: {err}");
        for w in want {
            assert!(err.contains(w.as_str()), "case {k}: '{w}' not in: {err}");
        }
        assert!(!out.exists(), "case {k}: {} was created", out.display());
    }
}

/// A material run writes the same bytes for 1 and 2 threads (geometry.exr's extra header
/// attribute included: the exr crate's attribute map iterates in a random order).
#[test]
fn material_outputs_are_bit_identical_for_any_thread_count() {
    let dir = tempfile::tempdir().unwrap();
    let maps = material(dir.path());
    let mut files = Vec::new();
    for t in [1, 2] {
        let out = dir.path().join(format!("t{t}"));
        synthesizer(dir.path(), &maps, Method::Patches)
            .threads(t)
            .run_to(&out)
            .unwrap();
        let mut names: Vec<String> = std::fs::read_dir(&out)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .filter(|n| n != "report.json")
            .collect();
        names.sort();
        let bytes: Vec<(String, Vec<u8>)> = names
            .into_iter()
            .map(|n| {
                let b = std::fs::read(out.join(&n)).unwrap();
                (n, b)
            })
            .collect();
        files.push(bytes);
    }
    let names: Vec<&str> = files[0].iter().map(|f| f.0.as_str()).collect();
    for n in [
        "atlas_normal.png",
        "atlas_roughness.png",
        "atlas_height.png",
        "atlas_metallic.png",
    ] {
        assert!(names.contains(&n), "{n} in {names:?}");
    }
    assert_eq!(files[0].len(), files[1].len());
    for (a, b) in files[0].iter().zip(&files[1]) {
        assert_eq!(a.0, b.0);
        assert!(a.1 == b.1, "{} differs between 1 and 2 threads", a.0);
    }
    let mtl = String::from_utf8(
        files[0]
            .iter()
            .find(|f| f.0 == "surface.mtl")
            .unwrap()
            .1
            .clone(),
    )
    .unwrap();
    for line in [
        "norm atlas_normal.png",
        "map_Pr atlas_roughness.png",
        "map_Pm atlas_metallic.png",
        "disp atlas_height.png",
    ] {
        assert!(mtl.contains(line), "{line} in {mtl}");
    }
    // 16-bit data maps.
    let img = image::open(dir.path().join("t1/atlas_roughness.png")).unwrap();
    assert!(matches!(img, image::DynamicImage::ImageLuma16(_)));
}
