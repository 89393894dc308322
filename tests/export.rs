//! `surface.obj` + `surface.mtl` + `atlas.png` checked the way a renderer sees them: only
//! the written files are parsed (OBJ text, PNG pixels) and compared with the exact limit
//! surface; nothing here reuses the exporter's own UV or gutter code.

mod common;

use common::data;
use glam::DVec3;
use std::collections::HashMap;
use std::path::Path;
use subdiv::{DomainId, Surface};
use surfsynth::io::atlas::{ATLAS_NAME, MTL_NAME, OBJ_NAME};
use surfsynth::io::export::{export, ExportOptions};
use surfsynth::io::exr::FaceMaps;

fn load(rel: &str) -> Surface {
    Surface::load_obj(data(rel)).unwrap()
}

/// Independent sRGB encoding (IEC 61966-2-1) for expected pixel values.
fn srgb(c: f64) -> f64 {
    let c = c.clamp(0.0, 1.0);
    255.0
        * if c <= 0.0031308 {
            12.92 * c
        } else {
            1.055 * c.powf(1.0 / 2.4) - 0.055
        }
}

/// Independent sRGB decoding of an 8-bit value.
fn linear(b: f64) -> f64 {
    let s = b / 255.0;
    if s <= 0.04045 {
        s / 12.92
    } else {
        ((s + 0.055) / 1.055).powf(2.4)
    }
}

/// Maps whose texels hold `field(limit position at the texel centre)`.
fn maps_from(
    surface: &Surface,
    n: usize,
    alpha: bool,
    field: impl Fn(usize, usize, usize, DVec3) -> [f32; 4],
) -> FaceMaps {
    let names: &[&str] = if alpha {
        &["R", "G", "B", "A"]
    } else {
        &["R", "G", "B"]
    };
    let mut m = FaceMaps::new(surface.num_domains(), n, names);
    let mut samples = vec![Default::default(); n * n];
    for d in 0..surface.num_domains() {
        surface.eval_texels(DomainId::from_idx(d), n, &mut samples);
        for y in 0..n {
            for x in 0..n {
                let c = field(d, x, y, samples[y * n + x].p);
                let i = m.index(d, x, y);
                for (k, (_, data)) in m.channels.iter_mut().enumerate() {
                    data[i] = c[k];
                }
            }
        }
    }
    m
}

/// A smooth colour field over space: three plane waves of wavelength `lambda`.
fn smooth(lambda: f64) -> impl Fn(usize, usize, usize, DVec3) -> [f32; 4] {
    move |_, _, _, p| {
        let w = std::f64::consts::TAU / lambda;
        let dirs = [
            DVec3::new(0.8, 0.5, 0.3),
            DVec3::new(-0.3, 0.9, 0.2),
            DVec3::new(0.1, -0.4, 0.9),
        ];
        let mut c = [0f32; 4];
        for k in 0..3 {
            c[k] = (0.5 + 0.4 * (w * dirs[k].normalize().dot(p) + k as f64).sin()) as f32;
        }
        c[3] = (0.6 + 0.3 * (w * p.x).cos()) as f32;
        c
    }
}

/// Texel noise: independent values per (domain, x, y), from a fixed hash.
fn noise(d: usize, x: usize, y: usize, _: DVec3) -> [f32; 4] {
    let mut h = (d as u64) << 40 ^ (y as u64) << 20 ^ x as u64;
    let mut c = [0f32; 4];
    for v in c.iter_mut() {
        h = h.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = h;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^= z >> 31;
        *v = (z >> 40) as f32 / (1u64 << 24) as f32;
    }
    c
}

/// The surface whose control mesh is `s`'s level-1 mesh: all quads, same valences.
fn refined_once(s: &Surface) -> Surface {
    let b = &s.base;
    let pos = (0..b.num_vertices())
        .map(|v| b.pos(subdiv::VertexId::from_idx(v)))
        .collect();
    let faces: Vec<&[u32]> = (0..b.num_faces())
        .map(|f| b.face_vertices(subdiv::FaceId::from_idx(f)))
        .collect();
    Surface::new(subdiv::ControlMesh::from_faces(pos, &faces).unwrap())
}

struct Obj {
    /// Position tokens as written (exact text: identical text = identical point).
    v: Vec<[String; 3]>,
    vt: Vec<[f64; 2]>,
    vn: Vec<[f64; 3]>,
    /// (v, vt, vn), 0-based.
    faces: Vec<Vec<(usize, usize, usize)>>,
    mtllib: Vec<String>,
    usemtl: Vec<String>,
}

fn parse_obj(text: &str) -> Obj {
    let mut o = Obj {
        v: vec![],
        vt: vec![],
        vn: vec![],
        faces: vec![],
        mtllib: vec![],
        usemtl: vec![],
    };
    for line in text.lines() {
        let t: Vec<&str> = line.split_whitespace().collect();
        match t.first().copied() {
            Some("v") => {
                assert_eq!(t.len(), 4, "{line}");
                o.v.push([t[1].into(), t[2].into(), t[3].into()]);
            }
            Some("vt") => o.vt.push([t[1].parse().unwrap(), t[2].parse().unwrap()]),
            Some("vn") => o.vn.push([
                t[1].parse().unwrap(),
                t[2].parse().unwrap(),
                t[3].parse().unwrap(),
            ]),
            Some("f") => o.faces.push(
                t[1..]
                    .iter()
                    .map(|c| {
                        let i: Vec<usize> = c.split('/').map(|s| s.parse().unwrap()).collect();
                        assert_eq!(i.len(), 3, "{line}");
                        (i[0] - 1, i[1] - 1, i[2] - 1)
                    })
                    .collect(),
            ),
            Some("mtllib") => o.mtllib.push(t[1].into()),
            Some("usemtl") => o.usemtl.push(t[1].into()),
            Some("#") | None => {}
            Some(other) => panic!("unexpected OBJ statement {other}"),
        }
    }
    o
}

fn pos(o: &Obj, i: usize) -> DVec3 {
    let p = &o.v[i];
    DVec3::new(
        p[0].parse().unwrap(),
        p[1].parse().unwrap(),
        p[2].parse().unwrap(),
    )
}

struct Png {
    w: usize,
    h: usize,
    k: usize,
    data: Vec<u8>,
}

fn read_png(path: &Path) -> Png {
    let img = image::ImageReader::open(path).unwrap().decode().unwrap();
    let (w, h) = (img.width() as usize, img.height() as usize);
    match img {
        image::DynamicImage::ImageRgb8(b) => Png {
            w,
            h,
            k: 3,
            data: b.into_raw(),
        },
        image::DynamicImage::ImageRgba8(b) => Png {
            w,
            h,
            k: 4,
            data: b.into_raw(),
        },
        other => panic!("unexpected PNG colour type {:?}", other.color()),
    }
}

impl Png {
    fn px(&self, x: usize, y: usize) -> &[u8] {
        &self.data[(y * self.w + x) * self.k..(y * self.w + x + 1) * self.k]
    }

    /// Bilinear lookup at OBJ texture coordinates (GL convention: t = 0 at the bottom,
    /// pixel centres at +0.5, clamp to edge) the way an sRGB texture is filtered on a GPU:
    /// colour decoded to linear, filtered, and (for comparison in display units) encoded
    /// again; alpha filtered as stored. Result in 8-bit units.
    fn bilinear(&self, s: f64, t: f64) -> [f64; 4] {
        let x = (s * self.w as f64 - 0.5).clamp(0.0, self.w as f64 - 1.0);
        let y = ((1.0 - t) * self.h as f64 - 0.5).clamp(0.0, self.h as f64 - 1.0);
        let (x0, y0) = (x.floor() as usize, y.floor() as usize);
        let (x1, y1) = ((x0 + 1).min(self.w - 1), (y0 + 1).min(self.h - 1));
        let (fx, fy) = (x - x0 as f64, y - y0 as f64);
        let mut out = [0.0; 4];
        for (c, o) in out.iter_mut().enumerate().take(self.k) {
            let g = |x: usize, y: usize| {
                let b = self.px(x, y)[c] as f64;
                if c == 3 {
                    b / 255.0
                } else {
                    linear(b)
                }
            };
            let top = g(x0, y0) * (1.0 - fx) + g(x1, y0) * fx;
            let bot = g(x0, y1) * (1.0 - fx) + g(x1, y1) * fx;
            let l = top * (1.0 - fy) + bot * fy;
            *o = if c == 3 { l * 255.0 } else { srgb(l) };
        }
        out
    }
}

/// Colour differences (max over channels, 8-bit units) between the two sides of every
/// edge the OBJ shares between different tiles, sampled at `LAMBDAS` along each tessellation
/// segment, 1e-3 pixel inside each face.
#[derive(Debug, Default)]
struct SeamStats {
    samples: usize,
    mean: f64,
    max: f64,
    /// Max over samples at least 1.5 texels from every tile corner.
    max_off_corner: f64,
    /// Number of tile pairs (adjacent domains) seen.
    domain_pairs: usize,
    /// Samples differing by more than one 8-bit level.
    over_one: usize,
}

const LAMBDAS: [f64; 7] = [0.0, 0.05, 0.25, 0.5, 0.75, 0.95, 1.0];

fn seam_stats(o: &Obj, png: &Png, n: usize, gutter: usize) -> SeamStats {
    let tile = (n + 2 * gutter) as f64;
    // Tile of a face from its UV centroid (the exporter's own domain list is not used).
    let tile_of = |f: &Vec<(usize, usize, usize)>| {
        let c = f.iter().fold([0.0, 0.0], |a, &(_, t, _)| {
            [a[0] + o.vt[t][0], a[1] + o.vt[t][1]]
        });
        let x = c[0] / f.len() as f64 * png.w as f64;
        let y = (1.0 - c[1] / f.len() as f64) * png.h as f64;
        ((x / tile).floor() as usize, (y / tile).floor() as usize)
    };
    // Edges keyed by the exact text of their end points.
    type Key<'a> = (&'a [String; 3], &'a [String; 3]);
    let mut edges: HashMap<Key, Vec<(usize, usize, usize)>> = HashMap::new();
    for (fi, f) in o.faces.iter().enumerate() {
        for c in 0..f.len() {
            let (a, b) = (f[c].0, f[(c + 1) % f.len()].0);
            let key = if o.v[a] < o.v[b] {
                (&o.v[a], &o.v[b])
            } else {
                (&o.v[b], &o.v[a])
            };
            edges
                .entry(key)
                .or_default()
                .push((fi, c, (c + 1) % f.len()));
        }
    }
    let mut st = SeamStats::default();
    let mut pairs = std::collections::HashSet::new();
    let mut sum = 0.0;
    for uses in edges.values() {
        if uses.len() != 2 {
            continue;
        }
        let (fa, fb) = (&o.faces[uses[0].0], &o.faces[uses[1].0]);
        let (ta, tb) = (tile_of(fa), tile_of(fb));
        if ta == tb {
            continue;
        }
        pairs.insert(if ta < tb { (ta, tb) } else { (tb, ta) });
        // Side A goes a0 -> a1; side B has the same edge the other way round.
        let side = |u: (usize, usize, usize), f: &Vec<(usize, usize, usize)>, lam: f64| {
            let (p0, p1) = (o.vt[f[u.1].1], o.vt[f[u.2].1]);
            let cen = f.iter().fold([0.0, 0.0], |a, &(_, t, _)| {
                [
                    a[0] + o.vt[t][0] / f.len() as f64,
                    a[1] + o.vt[t][1] / f.len() as f64,
                ]
            });
            let e = [p0[0] + (p1[0] - p0[0]) * lam, p0[1] + (p1[1] - p0[1]) * lam];
            let dir = [cen[0] - e[0], cen[1] - e[1]];
            let len = (dir[0] * png.w as f64).hypot(dir[1] * png.h as f64);
            let eps = 1e-3 / len; // 1e-3 pixel
            let uv = [e[0] + dir[0] * eps, e[1] + dir[1] * eps];
            // Distance (texels) to the nearest tile-interior corner.
            let (x, y) = (uv[0] * png.w as f64, (1.0 - uv[1]) * png.h as f64);
            let (lx, ly) = (x % tile - gutter as f64, y % tile - gutter as f64);
            let dc = lx.min(n as f64 - lx).hypot(ly.min(n as f64 - ly));
            (png.bilinear(uv[0], uv[1]), dc)
        };
        for &lam in &LAMBDAS {
            let (ca, da) = side(uses[0], fa, lam);
            // The same surface point is at 1 - lam along B's (reversed) edge.
            let (cb, db) = side(uses[1], fb, 1.0 - lam);
            let diff = (0..png.k)
                .map(|c| (ca[c] - cb[c]).abs())
                .fold(0.0, f64::max);
            st.samples += 1;
            sum += diff;
            st.max = st.max.max(diff);
            st.over_one += (diff > 1.0) as usize;
            if da.min(db) >= 1.5 {
                st.max_off_corner = st.max_off_corner.max(diff);
            }
        }
    }
    st.mean = sum / st.samples.max(1) as f64;
    st.domain_pairs = pairs.len();
    st
}

/// Overwrites every gutter pixel of the PNG with the nearest interior pixel of its own tile
/// (what an exporter without neighbour gutters would do): the baseline the real gutters must
/// beat.
fn clamp_gutters(png: &mut Png, n: usize, gutter: usize) {
    let t = n + 2 * gutter;
    let src = png.data.clone();
    for y in 0..png.h {
        for x in 0..png.w {
            let (tx, ty) = (x / t, y / t);
            let cx = (x % t).clamp(gutter, gutter + n - 1) + tx * t;
            let cy = (y % t).clamp(gutter, gutter + n - 1) + ty * t;
            let (d, s) = ((y * png.w + x) * png.k, (cy * png.w + cx) * png.k);
            png.data[d..d + png.k].copy_from_slice(&src[s..s + png.k]);
        }
    }
}

fn run_export(
    surface: &Surface,
    maps: &FaceMaps,
    opts: &ExportOptions,
) -> (tempfile::TempDir, Obj, Png) {
    let dir = tempfile::tempdir().unwrap();
    export(dir.path(), surface, maps, opts).unwrap();
    let obj = parse_obj(&std::fs::read_to_string(dir.path().join(OBJ_NAME)).unwrap());
    let png = read_png(&dir.path().join(ATLAS_NAME));
    (dir, obj, png)
}

fn diag(surface: &Surface) -> f64 {
    let (lo, hi) = surface.bounds();
    (hi - lo).length()
}

/// A smooth field must look continuous across every shared edge, on meshes with
/// extraordinary vertices (cube: valence 3; pole8: valence 8), T-junctions between quads
/// and n-gon sub-faces (nonquads), an open boundary (cube_no_bottom) and Spot.
#[test]
fn smooth_field_is_seamless_across_every_shared_edge() {
    let n = 16;
    for (mesh, bound_max, bound_mean) in [
        ("opensubdiv-reference/catmark_cube.obj", 1.5, 0.3),
        ("opensubdiv-reference/catmark_torus.obj", 1.5, 0.3),
        ("opensubdiv-reference/catmark_pole8.obj", 3.0, 0.3),
        ("opensubdiv-reference/catmark_nonquads.obj", 3.0, 0.5),
        ("meshes/cube_no_bottom.obj", 1.0, 0.1),
        ("meshes/spot_control_mesh.obj", 6.0, 0.3),
    ] {
        let s = load(mesh);
        // A wavelength of about two faces (32 texels): ~20 sRGB levels per texel at the
        // steepest, so any misplaced gutter shows, yet smooth enough that both sides of an
        // edge should agree up to bilinear reconstruction error.
        let lambda = diag(&s) / (s.num_domains() as f64).sqrt() * 2.0;
        let maps = maps_from(&s, n, false, smooth(lambda));
        let opts = ExportOptions::default();
        let (_d, obj, png) = run_export(&s, &maps, &opts);
        let st = seam_stats(&obj, &png, n, opts.gutter);
        let mut base = Png {
            w: png.w,
            h: png.h,
            k: png.k,
            data: png.data.clone(),
        };
        clamp_gutters(&mut base, n, opts.gutter);
        let bs = seam_stats(&obj, &base, n, opts.gutter);
        println!(
            "{mesh}: {} domain pairs, {} samples: max {:.2} mean {:.3} (off corners {:.2}); clamped gutters: max {:.2} mean {:.3}",
            st.domain_pairs, st.samples, st.max, st.mean, st.max_off_corner, bs.max, bs.mean
        );
        assert!(st.domain_pairs > 0);
        assert!(
            st.max <= bound_max,
            "{mesh}: max seam difference {}",
            st.max
        );
        assert!(
            st.mean <= bound_mean,
            "{mesh}: mean seam difference {}",
            st.mean
        );
        // The test has teeth: without neighbour gutters the same samples differ clearly.
        assert!(
            bs.mean > 4.0 * st.mean.max(0.05),
            "{mesh}: baseline mean {}",
            bs.mean
        );
    }
}

/// Texel noise has no smoothness to hide behind: across edges whose texel grids line up
/// (all-quad meshes), the gutters must be exact copies of the neighbour's texels, so both
/// sides filter to the same colour; at extraordinary vertices the corner rule makes the
/// vertex colour agree.
#[test]
fn noise_gutters_copy_the_neighbours_texels() {
    let n = 8;
    // Bounds (8-bit levels) at vertices: exact agreement needs a diagonal gutter value
    // inside [0, 1] for every tile around the vertex, which noise at valence >= 5 can
    // rule out (see the atlas module); everywhere else the agreement is exact.
    for (mesh, bound) in [
        ("opensubdiv-reference/catmark_cube.obj", 0.5),
        ("opensubdiv-reference/catmark_torus.obj", 0.5),
        ("opensubdiv-reference/catmark_pole8.obj", 24.0),
        ("meshes/double_torus_genus2.obj", 24.0),
    ] {
        // Once-refined copies are all quads with the original valences (3 to 8).
        let s = refined_once(&load(mesh));
        let maps = maps_from(&s, n, true, noise);
        let opts = ExportOptions {
            gutter: 3,
            level: Some(2),
            ..Default::default()
        };
        let (_d, obj, png) = run_export(&s, &maps, &opts);
        assert_eq!(png.k, 4);
        let st = seam_stats(&obj, &png, n, opts.gutter);
        println!(
            "{mesh} (noise, N={n}, g=3): {} samples: max {:.2} mean {:.3}, off corners max {:.2}, {} over 1 level",
            st.samples, st.max, st.mean, st.max_off_corner, st.over_one
        );
        assert!(
            st.over_one * 200 <= st.samples,
            "{mesh}: {} samples over 1 level",
            st.over_one
        );
        assert!(st.max_off_corner <= 0.5, "{mesh}: {}", st.max_off_corner);
        assert!(st.max <= bound, "{mesh}: {}", st.max);
    }
}

#[test]
fn obj_is_crack_free_on_the_limit_surface_with_consistent_counts() {
    for (mesh, n) in [
        ("opensubdiv-reference/catmark_nonquads.obj", 8usize),
        ("meshes/cube_no_bottom.obj", 5),
        ("opensubdiv-reference/catmark_pole8.obj", 32),
    ] {
        let s = load(mesh);
        let maps = maps_from(&s, n, false, smooth(1.0));
        let opts = ExportOptions::default();
        let (dir, obj, png) = run_export(&s, &maps, &opts);
        let level = surfsynth::io::atlas::level_for_resolution(n);
        let g = opts.gutter;
        let t = n + 2 * g;

        // Counts: one vn per v; quads = base quads x 4^(level-1); vt = a grid per domain.
        let base_quads = s.num_base_quads();
        assert_eq!(obj.faces.len(), base_quads << (2 * (level - 1)), "{mesh}");
        assert!(obj.faces.iter().all(|f| f.len() == 4));
        assert_eq!(obj.v.len(), obj.vn.len());
        let per_base = 1usize << (level - 1);
        let want_vt: usize = (0..s.num_domains())
            .map(|d| {
                let m = match s.domain(DomainId::from_idx(d)) {
                    subdiv::Domain::Quad { .. } => 2 * per_base,
                    subdiv::Domain::SubFace { .. } => per_base,
                };
                (m + 1) * (m + 1)
            })
            .sum();
        assert_eq!(obj.vt.len(), want_vt, "{mesh}");
        for f in &obj.faces {
            for &(v, tt, vn) in f {
                assert!(v < obj.v.len() && tt < obj.vt.len() && vn < obj.vn.len());
            }
        }
        assert_eq!(obj.mtllib, vec![MTL_NAME.to_string()]);
        assert_eq!(obj.usemtl.len(), 1);
        let mtl = std::fs::read_to_string(dir.path().join(MTL_NAME)).unwrap();
        assert!(mtl.contains(&format!("newmtl {}", obj.usemtl[0])));
        assert!(mtl.contains("map_Kd atlas.png") && !mtl.contains("map_d"));
        assert_eq!(png.k, 3);

        // Crack-free: every edge (by the text of its end points) is used by two faces,
        // except the refined open-boundary edges, counted from the control OBJ itself.
        let text = std::fs::read_to_string(data(mesh)).unwrap();
        let mut ctrl: HashMap<(usize, usize), usize> = HashMap::new();
        for line in text.lines().filter(|l| l.starts_with("f ")) {
            let ids: Vec<usize> = line[2..]
                .split_whitespace()
                .map(|t| t.split('/').next().unwrap().parse().unwrap())
                .collect();
            for i in 0..ids.len() {
                let (a, b) = (ids[i], ids[(i + 1) % ids.len()]);
                *ctrl.entry((a.min(b), a.max(b))).or_default() += 1;
            }
        }
        let open_ctrl = ctrl.values().filter(|&&c| c == 1).count();
        let mut uses: HashMap<(&[String; 3], &[String; 3]), usize> = HashMap::new();
        for f in &obj.faces {
            for c in 0..4 {
                let (a, b) = (&obj.v[f[c].0], &obj.v[f[(c + 1) % 4].0]);
                *uses.entry(if a < b { (a, b) } else { (b, a) }).or_default() += 1;
            }
        }
        let once = uses.values().filter(|&&c| c == 1).count();
        assert!(
            uses.values().all(|&c| c <= 2),
            "{mesh}: an edge used 3+ times"
        );
        assert_eq!(once, open_ctrl * 2 * per_base, "{mesh}: open edges");

        // Every corner lies on the limit surface at the point its UV names, with the limit
        // normal there (tolerance: f32 printing).
        let scale = diag(&s);
        let mut worst: f64 = 0.0;
        for f in &obj.faces {
            let cen = f.iter().fold([0.0, 0.0], |a, &(_, tt, _)| {
                [a[0] + obj.vt[tt][0] / 4.0, a[1] + obj.vt[tt][1] / 4.0]
            });
            let (col, row) = (
                (cen[0] * png.w as f64 / t as f64) as usize,
                ((1.0 - cen[1]) * png.h as f64 / t as f64) as usize,
            );
            let d = row * ((png.w) / t) + col;
            for &(v, tt, vn) in f {
                let x = obj.vt[tt][0] * png.w as f64 - (col * t + g) as f64;
                let y = (1.0 - obj.vt[tt][1]) * png.h as f64 - (row * t + g) as f64;
                let (u, w) = (x / n as f64, y / n as f64);
                assert!((-1e-5..=1.0 + 1e-5).contains(&u) && (-1e-5..=1.0 + 1e-5).contains(&w));
                let e = s.eval(DomainId::from_idx(d), u.clamp(0.0, 1.0), w.clamp(0.0, 1.0));
                let err = (e.p - pos(&obj, v)).length() / scale;
                worst = worst.max(err);
                let nn = DVec3::from_array(obj.vn[vn]);
                assert!(nn.dot(e.n) > 0.9999, "{mesh}: normal {nn} vs {}", e.n);
            }
        }
        println!("{mesh}: worst position error {worst:.2e} of the diagonal");
        assert!(worst < 1e-5, "{mesh}: {worst}");
    }
}

/// Interior pixels are the maps' values, sRGB-encoded; alpha is linear; the MTL gets map_d.
#[test]
fn atlas_interior_is_the_maps_and_alpha_gets_map_d() {
    let s = load("opensubdiv-reference/catmark_nonquads.obj");
    let n = 6;
    let maps = maps_from(&s, n, true, noise);
    let opts = ExportOptions {
        gutter: 2,
        level: None,
        ..Default::default()
    };
    let (dir, _obj, png) = run_export(&s, &maps, &opts);
    assert_eq!(png.k, 4);
    let t = n + 4;
    let cols = png.w / t;
    let mut worst: f64 = 0.0;
    for d in 0..s.num_domains() {
        for y in 0..n {
            for x in 0..n {
                let px = png.px((d % cols) * t + 2 + x, (d / cols) * t + 2 + y);
                for (c, name) in ["R", "G", "B", "A"].iter().enumerate() {
                    let v = maps.channel(name).unwrap()[maps.index(d, x, y)] as f64;
                    let want = if c == 3 { v * 255.0 } else { srgb(v) };
                    worst = worst.max((px[c] as f64 - want).abs());
                }
            }
        }
    }
    assert!(worst <= 0.5 + 1e-3, "{worst}");
    let mtl = std::fs::read_to_string(dir.path().join(MTL_NAME)).unwrap();
    assert!(mtl.contains("map_d") && mtl.contains("atlas.png"), "{mtl}");
}

#[test]
fn export_is_deterministic_and_fails_cleanly() {
    let s = load("opensubdiv-reference/catmark_pole8.obj");
    let maps = maps_from(&s, 8, false, smooth(0.7));
    let a = tempfile::tempdir().unwrap();
    let b = tempfile::tempdir().unwrap();
    export(a.path(), &s, &maps, &ExportOptions::default()).unwrap();
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap();
    pool.install(|| export(b.path(), &s, &maps, &ExportOptions::default()))
        .unwrap();
    for name in [OBJ_NAME, MTL_NAME, ATLAS_NAME] {
        assert!(
            std::fs::read(a.path().join(name)).unwrap()
                == std::fs::read(b.path().join(name)).unwrap(),
            "{name}"
        );
    }

    let names = |p: &Path| -> Vec<String> {
        let mut v: Vec<String> = std::fs::read_dir(p)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into())
            .collect();
        v.sort();
        v
    };
    // Missing output directory: one-line error naming the file, nothing written.
    let missing = a.path().join("nope");
    let e = export(&missing, &s, &maps, &ExportOptions::default())
        .unwrap_err()
        .to_string();
    assert!(e.contains("nope") && !e.contains('\n'), "{e}");
    // Maps for another mesh, maps without colour, zero gutter: errors, no files.
    let c = tempfile::tempdir().unwrap();
    let other = load("opensubdiv-reference/catmark_cube.obj");
    let e = export(c.path(), &other, &maps, &ExportOptions::default())
        .unwrap_err()
        .to_string();
    assert!(e.contains("domains"), "{e}");
    let grey = FaceMaps::new(s.num_domains(), 8, &["Y"]);
    let e = export(c.path(), &s, &grey, &ExportOptions::default())
        .unwrap_err()
        .to_string();
    assert!(e.contains("'R'"), "{e}");
    let e = export(
        c.path(),
        &s,
        &maps,
        &ExportOptions {
            gutter: 0,
            level: None,
            ..Default::default()
        },
    )
    .unwrap_err()
    .to_string();
    assert!(e.contains("gutter"), "{e}");
    assert!(names(c.path()).is_empty(), "{:?}", names(c.path()));
}
