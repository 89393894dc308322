//! Orientation field: the energy of 000 footnote 2 falls monotonically, axis hints are met
//! on surfaces of revolution, auto fields have only the singularities topology forces,
//! constraints hold, and the result does not depend on the thread count.

use glam::DVec3;
use subdiv::{DomainId, Surface};
use surfsynth::field::{Constraints, FieldOptions, Orientation, OrientationField};

mod common;
use common::load;

#[test]
fn energy_falls_monotonically_on_every_level() {
    for rel in [
        "opensubdiv-reference/catmark_cube.obj",
        "opensubdiv-reference/spot_control_mesh.obj",
        "meshes/cube_no_bottom.obj",
    ] {
        let s = load(rel);
        for o in [Orientation::Auto, Orientation::Axis(DVec3::Y)] {
            let f = OrientationField::compute(&s, &o).unwrap();
            for h in f.history() {
                let e = &h.energy;
                assert!(e.len() >= 3, "{rel} level {}: {} steps", h.level, e.len());
                for w in e.windows(2) {
                    // Each half-sweep is an exact block minimisation: E never rises (up to
                    // rounding of the sum).
                    assert!(
                        w[1] <= w[0] * (1.0 + 1e-12),
                        "{rel} {o:?} L{}: {} -> {}",
                        h.level,
                        w[0],
                        w[1]
                    );
                }
                assert!(
                    e[e.len() - 1] < e[0],
                    "{rel} {o:?} L{}: no progress",
                    h.level
                );
            }
        }
    }
}

/// `up`: the example's up (v2) follows the projected axis to 2° wherever the projection
/// is not small, so v1 runs level (across the axis): the axis field turned a quarter.
#[test]
fn up_field_on_tori_puts_v2_along_the_projected_axis_within_2_degrees() {
    let s = load("meshes/torus.obj");
    let f = OrientationField::compute(&s, &Orientation::parse("up")).unwrap();
    assert_eq!(Orientation::parse("up"), Orientation::Up(DVec3::Y));
    let mut worst: f64 = 0.0;
    let mut n = 0;
    for d in 0..s.num_domains() {
        for (u, v) in [(0.13, 0.71), (0.5, 0.5), (0.9, 0.2)] {
            let fr = f.frame(&s, DomainId(d as u32), u, v);
            let p = DVec3::Y - fr.n * fr.n.dot(DVec3::Y);
            if p.length() > 0.3 {
                worst = worst.max(fr.v2.angle_between(p).to_degrees());
                assert!(
                    fr.v1.dot(DVec3::Y).abs() < 0.05,
                    "v1 not level: {:?}",
                    fr.v1
                );
                n += 1;
            }
        }
    }
    println!("up on the torus: worst {worst:.4}° over {n} points");
    assert!(n > 100 && worst < 2.0, "{worst}°");
}

/// The projected axis of a torus (axis y) is the meridian direction: v1 must follow it to
/// 2° wherever the projection is not small (it vanishes on the top and bottom circles).
#[test]
fn axis_hint_on_tori_follows_the_projected_axis_within_2_degrees() {
    for rel in ["opensubdiv-reference/catmark_torus.obj", "meshes/torus.obj"] {
        let s = load(rel);
        let f = OrientationField::compute(&s, &Orientation::Axis(DVec3::Y)).unwrap();
        let lm = f.limit_mesh();
        let mut worst: f64 = 0.0;
        let mut n = 0;
        for (i, v1) in f.vertex_v1().iter().enumerate() {
            let nrm = lm.normal[i];
            let p = DVec3::Y - nrm * nrm.dot(DVec3::Y);
            if p.length() > 0.3 {
                worst = worst.max(v1.angle_between(p).to_degrees());
                n += 1;
            }
        }
        // Also at arbitrary domain points (the interpolated field).
        for d in 0..s.num_domains().min(200) {
            for (u, v) in [(0.13, 0.71), (0.5, 0.5), (0.9, 0.2)] {
                let fr = f.frame(&s, DomainId(d as u32), u, v);
                let p = DVec3::Y - fr.n * fr.n.dot(DVec3::Y);
                if p.length() > 0.3 {
                    worst = worst.max(fr.v1.angle_between(p).to_degrees());
                }
            }
        }
        println!(
            "{rel}: level {}, worst {worst:.4}° over {n} vertices",
            f.level()
        );
        assert!(n > 1000 && worst < 2.0, "{rel}: {worst}°");
    }
}

#[test]
fn auto_fields_have_only_the_singularities_topology_forces() {
    for (rel, chi, max_count) in [
        ("opensubdiv-reference/catmark_torus.obj", 0, 0),
        ("opensubdiv-reference/catmark_cube.obj", 2, 2),
        ("meshes/double_torus_genus2.obj", -2, 2),
        ("meshes/cube_no_bottom.obj", 1, 1),
    ] {
        let s = load(rel);
        let f = OrientationField::compute(&s, &Orientation::Auto).unwrap();
        let sing = f.singularities();
        let total: i32 = sing.iter().map(|x| x.index).sum();
        println!("{rel}: {} singular faces, total index {total}", sing.len());
        // Poincaré–Hopf (closed) / boundary-tangent-free count on the open cube.
        assert_eq!(total, chi, "{rel}");
        assert!(
            sing.len() <= max_count,
            "{rel}: {} singularities",
            sing.len()
        );
    }
}

/// The synthesizer's f32 frames (evaluated through leaf hints, per domain) are the f64
/// frames of `texel_frames` rounded: the same bits.
#[test]
fn f32_texel_frames_are_the_f64_frames_rounded() {
    let s = load("opensubdiv-reference/spot_control_mesh.obj");
    let f = OrientationField::compute(&s, &Orientation::Auto).unwrap();
    for n in [1, 7] {
        let want = surfsynth::synth::frames_f32(&f.texel_frames(&s, n));
        assert_eq!(
            surfsynth::synth::texel_frames_f32(&f, &s, n),
            want,
            "N = {n}"
        );
    }
}

/// `frame_with_normal` given the surface's normal is `frame`, bit for bit.
#[test]
fn frame_with_the_normal_given_is_the_frame() {
    let s = load("opensubdiv-reference/catmark_nonquads.obj");
    let f = OrientationField::compute(&s, &Orientation::Auto).unwrap();
    let bits =
        |fr: surfsynth::field::Frame| [fr.v1, fr.v2, fr.n].map(|v| v.to_array().map(f64::to_bits));
    for d in 0..s.num_domains() {
        let d = DomainId::from_idx(d);
        for (u, v) in [
            (0.5, 0.5),
            (0.01, 0.99),
            (0.0, 0.0),
            (1.0, 0.3),
            (0.37, 0.81),
        ] {
            let n = s.eval(d, u, v).n;
            assert_eq!(
                bits(f.frame_with_normal(&s, d, u, v, n)),
                bits(f.frame(&s, d, u, v)),
                "{d:?} ({u}, {v})"
            );
        }
    }
}

/// Frames made from the normals the geometry pass kept (no second evaluation of the
/// surface) are `texel_frames_f32`'s, bit for bit: at extraordinary vertices, on n-gon
/// sub-faces, at creases and on an open boundary.
#[test]
fn frames_from_kept_normals_are_the_evaluated_frames() {
    use std::sync::Arc;
    use surfsynth::layout::TexelLayout;
    use surfsynth::texels::TexelGeometry;
    let bits = |v: &[[glam::Vec3; 2]]| -> Vec<[u32; 6]> {
        v.iter()
            .map(|[a, b]| [a.x, a.y, a.z, b.x, b.y, b.z].map(f32::to_bits))
            .collect()
    };
    for rel in [
        "opensubdiv-reference/spot_control_mesh.obj",
        "opensubdiv-reference/catmark_nonquads.obj",
        "opensubdiv-reference/catmark_pole8.obj",
        "opensubdiv-reference/catmark_edgecorner.obj",
        "meshes/cube_no_bottom.obj",
    ] {
        let s = load(rel);
        let f = OrientationField::compute(&s, &Orientation::Auto).unwrap();
        for n in [1, 3, 8] {
            let layout = Arc::new(TexelLayout::uniform(s.num_domains(), n));
            let (g, slots) = TexelGeometry::compute_keeping_normals(&s, layout.clone());
            assert_eq!(
                g,
                TexelGeometry::compute_layout(&s, layout),
                "{rel} N = {n}"
            );
            let got = surfsynth::synth::frames_from_slots(&f, &s, slots);
            let want = surfsynth::synth::texel_frames_f32(&f, &s, n);
            assert!(bits(&got) == bits(&want), "{rel} N = {n}");
        }
    }
}

#[test]
fn frames_are_orthonormal_and_continuous_across_domain_edges() {
    let s = load("opensubdiv-reference/spot_control_mesh.obj");
    let f = OrientationField::compute(&s, &Orientation::Auto).unwrap();
    let frames = f.texel_frames(&s, 8);
    assert_eq!(frames.len(), s.num_domains() * 64);
    for fr in &frames {
        assert!((fr.v1.length() - 1.0).abs() < 1e-9 && fr.v1.dot(fr.n).abs() < 1e-9);
        assert!((fr.v2 - fr.n.cross(fr.v1)).length() < 1e-12);
    }
    // The same surface point seen from two domains gets the same frame.
    let mut worst: f64 = 0.0;
    for d in 0..s.num_domains() {
        let a = subdiv::DomainLocation {
            domain: DomainId(d as u32),
            u: 0.37,
            v: 1e-12,
        };
        let inside = subdiv::DomainLocation {
            domain: a.domain,
            u: 0.37,
            v: 0.01,
        };
        let Some(b) = s.walk(inside, 0.0, -0.01 - 1e-12) else {
            continue;
        };
        let fa = f.frame(&s, a.domain, a.u, a.v);
        let fb = f.frame(&s, b.domain, b.u, b.v);
        if (s.eval(b.domain, b.u, b.v).p - s.eval(a.domain, a.u, a.v).p).length() < 1e-9 {
            worst = worst.max(fa.v1.angle_between(fb.v1).to_degrees());
        }
    }
    assert!(worst < 1e-3, "jump across an edge: {worst}°");
}

#[test]
fn constraints_file_pins_vertices_and_sinks_attract() {
    let s = load("opensubdiv-reference/catmark_cube.obj");
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("c.txt");
    // Vertex 0 of catmark_cube is at (-0.5, -0.5, 0.5); a sink at the +x face centre.
    std::fs::write(&path, "# test\nvertex 0 1 0 0\nsink 0.9 0 0 0.6\n").unwrap();
    let f = OrientationField::compute(&s, &Orientation::Constraints(path.clone())).unwrap();
    let lm = f.limit_mesh();
    let n0 = lm.normal[0];
    let want = (DVec3::X - n0 * n0.dot(DVec3::X)).normalize();
    assert!(f.vertex_v1()[0].angle_between(want).to_degrees() < 1e-6);
    // Near the sink (within 0.3 of it, away from the point itself) v1 points toward it.
    let sink = DVec3::new(0.9, 0.0, 0.0);
    let mut worst: f64 = 0.0;
    for (i, p) in lm.position.iter().enumerate() {
        let d = sink - *p;
        let n = lm.normal[i];
        let t = d - n * n.dot(d);
        if d.length() < 0.5 && t.length() > 0.1 {
            worst = worst.max(f.vertex_v1()[i].angle_between(t).to_degrees());
        }
    }
    assert!(worst < 20.0, "sink: {worst}°");
    // Errors name the line.
    std::fs::write(&path, "vertex 0 1 0\n").unwrap();
    let e = OrientationField::compute(&s, &Orientation::Constraints(path.clone())).unwrap_err();
    assert!(format!("{e:#}").contains("line 1"), "{e:#}");
    std::fs::write(&path, "vertex 99 1 0 0\n").unwrap();
    let e = OrientationField::compute(&s, &Orientation::Constraints(path)).unwrap_err();
    assert!(format!("{e:#}").contains("vertex 99"), "{e:#}");
    assert!(Constraints::parse("bogus 1 2 3").is_err());
}

#[test]
fn result_does_not_depend_on_the_thread_count() {
    let s = load("opensubdiv-reference/spot_control_mesh.obj");
    let run = |t: usize| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(t)
            .build()
            .unwrap()
            .install(|| {
                let opts = FieldOptions {
                    level: Some(4),
                    ..Default::default()
                };
                OrientationField::compute_with(&s, &Orientation::Auto, &opts).unwrap()
            })
    };
    let (a, b) = (run(1), run(3));
    assert_eq!(a.vertex_v1(), b.vertex_v1());
    assert_eq!(a.history(), b.history());
}

/// `auto` on flat grids: the smoothest field is constant, and its free global rotation is
/// fixed to follow world +x (then +y where +x is normal to the plane), so textures line up
/// with grids whose u runs along +x.
#[test]
fn auto_field_on_flat_grids_follows_world_x_then_y() {
    // (rotation applied to the xy grid, expected v1)
    let cases = [
        (glam::DMat3::IDENTITY, DVec3::X),
        // Tilted about x: still contains +x.
        (glam::DMat3::from_rotation_x(0.7), DVec3::X),
        // The yz plane: +x is normal, so +y.
        (
            glam::DMat3::from_rotation_y(std::f64::consts::FRAC_PI_2),
            DVec3::Y,
        ),
        // Turned 30° in its plane: v1 is still +x, no longer along u.
        (glam::DMat3::from_rotation_z(0.5), DVec3::X),
    ];
    for (rot, want) in cases {
        let p: Vec<DVec3> = (0..25)
            .map(|i| rot * DVec3::new((i % 5) as f64, (i / 5) as f64, 0.0))
            .collect();
        let faces: Vec<[u32; 4]> = (0..16u32)
            .map(|f| {
                let i = f / 4 * 5 + f % 4;
                [i, i + 1, i + 6, i + 5]
            })
            .collect();
        let faces: Vec<&[u32]> = faces.iter().map(|f| &f[..]).collect();
        let s = Surface::new(subdiv::ControlMesh::from_faces(p, &faces).unwrap());
        let f = OrientationField::compute(&s, &Orientation::Auto).unwrap();
        let mut worst = 0.0f64;
        for d in 0..s.num_domains() {
            for (u, v) in [(0.5, 0.5), (0.1, 0.9), (0.95, 0.05)] {
                let fr = f.frame(&s, DomainId::from_idx(d), u, v);
                worst = worst.max(fr.v1.angle_between(want).to_degrees());
            }
        }
        assert!(worst < 1e-6, "{rot:?}: v1 off {want} by {worst}°");
    }
}

/// Issue 18: the synthesizer divides a far-from-unit mesh by a power of two; constraint
/// points and radii (in the user's units) must follow (`FieldOptions::unit`), so a
/// constraints file and its mesh both scaled by 1e6 give the same field.
#[test]
fn constraints_scaled_with_the_mesh_give_the_same_field() {
    use subdiv::ControlMesh;
    let dir = tempfile::tempdir().unwrap();
    let write = |name: &str, k: f64| {
        let p = dir.path().join(name);
        std::fs::write(
            &p,
            format!(
                "sink {} {} {} {}\nsource {} {} {}\n",
                0.0,
                0.3 * k,
                0.3 * k,
                0.4 * k,
                0.0,
                -0.3 * k,
                -0.3 * k
            ),
        )
        .unwrap();
        p
    };
    let opts = FieldOptions {
        level: Some(3),
        ..Default::default()
    };
    let control = ControlMesh::load_obj(common::data("meshes/spot_control_mesh.obj")).unwrap();
    let a = OrientationField::compute_with(
        &Surface::new(control.clone()),
        &Orientation::Constraints(write("a.txt", 1.0)),
        &opts,
    )
    .unwrap();
    // The user's mesh, 1e6 times larger, normalised as the synthesizer does.
    let mut big = control;
    for p in &mut big.mesh.positions {
        *p *= 1e6;
    }
    let unit = surfsynth::memory::normalising_unit(&big);
    assert!(unit > 1e5, "{unit}");
    for p in &mut big.mesh.positions {
        *p /= unit;
    }
    let k = 1e6 / unit;
    let run = |unit: f64| {
        OrientationField::compute_with(
            &Surface::new(big.clone()),
            &Orientation::Constraints(write("b.txt", 1e6)),
            &FieldOptions {
                unit,
                ..opts.clone()
            },
        )
        .unwrap()
    };
    let b = run(unit);
    let worst = a
        .vertex_v1()
        .iter()
        .zip(b.vertex_v1())
        .map(|(x, y)| x.angle_between(*y).to_degrees())
        .fold(0.0f64, f64::max);
    println!("scale {k}: worst {worst:.2e}°");
    assert!(worst < 1e-3, "v1 differs by {worst}° at scale 1e6");
    // Without the unit the points land 2^20 times too far: the field differs.
    let c = run(1.0);
    let off = a
        .vertex_v1()
        .iter()
        .zip(c.vertex_v1())
        .map(|(x, y)| x.angle_between(*y).to_degrees())
        .fold(0.0f64, f64::max);
    assert!(off > 1.0, "the test cannot fail: {off}°");
}
