//! Creases beyond the OpenSubdiv comparisons: sharpness 0 is the smooth surface bit for bit,
//! every sharpness from 10 up is the same infinitely sharp surface, and a semi-sharp crease
//! is the infinitely sharp one but for a band that narrows by half per unit of sharpness.

mod common;

use subdiv::{ControlMesh, DomainId, LimitSample, Surface};

/// Every domain's 5x5 grid (corners and edges included) and 8x8 texel centres.
fn samples(s: &Surface) -> Vec<LimitSample> {
    let mut out = Vec::new();
    let mut buf = vec![LimitSample::default(); 64];
    for d in 0..s.num_domains() as u32 {
        for j in 0..5 {
            for i in 0..5 {
                out.push(s.eval(DomainId(d), i as f64 * 0.25, j as f64 * 0.25));
            }
        }
        s.eval_texels(DomainId(d), 8, &mut buf);
        out.extend_from_slice(&buf);
    }
    out
}

fn shape(name: &str) -> ControlMesh {
    ControlMesh::load_obj(
        common::shared()
            .join("data/opensubdiv-reference")
            .join(name),
    )
    .unwrap()
}

/// All edges of `m` as vertex pairs.
fn edges(m: &ControlMesh) -> Vec<(u32, u32)> {
    (0..m.mesh.num_edges())
        .map(|e| {
            let h = m.mesh.edge_half_edge(e);
            (m.mesh.origin(h).0, m.mesh.dest(h).0)
        })
        .collect()
}

#[test]
fn sharpness_zero_everywhere_is_the_smooth_surface_bit_for_bit() {
    for name in [
        "spot_control_mesh.obj",
        "catmark_edgecorner.obj",
        "catmark_nonquads.obj",
    ] {
        let smooth = shape(name);
        let zero_edges: Vec<(u32, u32, f32)> = edges(&smooth)
            .into_iter()
            .map(|(a, b)| (a, b, 0.0))
            .collect();
        let zero_verts: Vec<(u32, f32)> = (0..smooth.mesh.num_vertices() as u32)
            .map(|v| (v, 0.0))
            .collect();
        let tagged = smooth
            .clone()
            .with_sharpness(&zero_edges, &zero_verts)
            .unwrap();
        // And as tag lines in the file.
        let mut text = std::fs::read_to_string(
            common::shared()
                .join("data/opensubdiv-reference")
                .join(name),
        )
        .unwrap();
        for (a, b, _) in &zero_edges {
            text += &format!("t crease 2/1/0 {a} {b} 0.0\n");
        }
        text += "t corner 1/1/0 0 0\n";
        let parsed = ControlMesh::parse_obj(&text).unwrap();
        let want = samples(&Surface::new(smooth));
        assert_eq!(samples(&Surface::new(tagged)), want, "{name}");
        assert_eq!(samples(&Surface::new(parsed)), want, "{name}");
    }
}

/// The unit cube with sharpness `s` on the edge between vertices 0 and 1.
fn cube_with_crease(s: f32) -> Surface {
    let c = ControlMesh::cuboid(glam::DVec3::ZERO, glam::DVec3::ONE);
    Surface::new(c.with_sharpness(&[(0, 1, s)], &[]).unwrap())
}

#[test]
fn sharpness_ten_and_up_is_the_infinitely_sharp_surface() {
    let want = samples(&cube_with_crease(10.0));
    for s in [10.5, 1000.0, f32::INFINITY] {
        assert_eq!(samples(&cube_with_crease(s)), want, "sharpness {s}");
    }
    // And not the smooth or a semi-sharp one.
    assert_ne!(samples(&cube_with_crease(9.0)), want);
}

/// A crease of sharpness s follows the sharp rules for s levels, so it differs from the
/// infinitely sharp crease only within a few level-s faces of the edge: as s grows by one,
/// the largest difference over the texel centres of the faces along the edge drops (and
/// vanishes wherever no texel is that close), and beyond that band the two agree to
/// rounding.
#[test]
fn semi_sharp_creases_approach_the_sharp_one() {
    let sharp = cube_with_crease(10.0);
    let n = 32;
    let texels = |s: &Surface| {
        let mut all = Vec::new();
        let mut buf = vec![LimitSample::default(); n * n];
        for d in 0..s.num_domains() as u32 {
            s.eval_texels(DomainId(d), n, &mut buf);
            all.extend(buf.iter().map(|e| e.p));
        }
        all
    };
    let want = texels(&sharp);
    let mut last = f64::INFINITY;
    for s in 1..=5 {
        let got = texels(&cube_with_crease(s as f32));
        let worst = got
            .iter()
            .zip(&want)
            .map(|(a, b)| (*a - *b).length())
            .fold(0.0, f64::max);
        eprintln!("sharpness {s}: largest difference {worst:.3e}");
        assert!(worst < 0.75 * last, "sharpness {s}: {worst} after {last}");
        last = worst;
    }
    // Sharpness 9: 2^-9 of a face is under the texel spacing, so every texel centre is
    // farther from the edge than the band.
    let got = texels(&cube_with_crease(9.0));
    let worst = got
        .iter()
        .zip(&want)
        .map(|(a, b)| (*a - *b).length())
        .fold(0.0, f64::max);
    assert!(worst < 1e-14, "sharpness 9: {worst}");
}

/// Random tags on meshes with n-gons, triangles, boundaries and extraordinary vertices
/// (seeded): every sample finite with a unit normal, and every vertex of a level-4
/// refinement — where all semi-sharp values (≤ 3) have decayed — evaluated through the
/// patch trees equals the limit masks on the globally refined mesh.
#[test]
fn random_tags_agree_with_global_refinement() {
    use subdiv::limit::corner_limit;
    let mut r = common::Lcg(17);
    let values = [0.3f32, 1.0, 1.7, 2.5, 10.0];
    for name in [
        "catmark_nonquads.obj",
        "catmark_edgecorner.obj",
        "catmark_pole8.obj",
    ] {
        let c = shape(name);
        for round in 0..3 {
            let mut tags = Vec::new();
            for (a, b) in edges(&c) {
                if r.next() < 0.3 {
                    tags.push((a, b, values[(r.next() * 5.0) as usize]));
                }
            }
            let mut verts = Vec::new();
            for v in 0..c.mesh.num_vertices() as u32 {
                if r.next() < 0.1 {
                    verts.push((v, values[(r.next() * 5.0) as usize]));
                }
            }
            let s = Surface::new(c.clone().with_sharpness(&tags, &verts).unwrap());
            for e in samples(&s) {
                assert!(
                    e.p.is_finite() && (e.n.length() - 1.0).abs() < 1e-9,
                    "{name} {round}: {e:?}"
                );
            }
            let (lo, hi) = s.bounds();
            let diag = (hi - lo).length();
            let lm = s.limit_mesh(4);
            let (mut worst, mut worst_n) = (0.0f64, 0.0f64);
            for v in 0..lm.mesh.num_vertices() {
                let vid = subdiv::VertexId(v as u32);
                let Some(h) = lm.mesh.vertex_out(vid) else {
                    continue;
                };
                assert!(!lm.mesh.has_semi_sharp_at(vid));
                let l = corner_limit(&lm.mesh, h);
                worst = worst.max((l.position - lm.position[v]).length() / diag);
                // One normal (no crease side to choose), not a boundary vertex with 3+
                // faces (OpenSubdiv's "not unique"): the same normal.
                let m = &lm.mesh;
                if m.normal_is_unique(vid)
                    && !(m.is_boundary_vertex(vid) && m.vertex_faces(vid) >= 3)
                {
                    worst_n = worst_n.max(l.normal.angle_between(lm.normal[v]).to_degrees());
                }
            }
            eprintln!("{name} round {round}: position {worst:.1e}, normal {worst_n:.1e}°");
            assert!(worst < 1e-12, "{name} round {round}: position {worst:e}");
            assert!(worst_n < 1e-3, "{name} round {round}: normal {worst_n}°");
        }
    }
}
