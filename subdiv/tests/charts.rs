//! Vertex charts on real meshes: Φ of quads sharing an edge agree along it, no folds over
//! the region each chart serves, and Φ⁻¹(Φ(x)) = x.

use glam::DVec2;
use subdiv::{BaseLocation, BaseQuadId, Charts, Surface, VertexId};

mod common;
use common::{shared, Lcg};

fn meshes() -> Vec<(String, Surface)> {
    let r = shared().join("data/opensubdiv-reference");
    let m = shared().join("data/meshes");
    [
        r.join("catmark_pole8.obj"),
        r.join("catmark_nonquads.obj"),
        r.join("catmark_edgecorner.obj"),
        r.join("spot_control_mesh.obj"),
        m.join("double_torus_genus2.obj"),
        m.join("cube_no_bottom.obj"),
        m.join("opensubdiv/catmark_val2_interior.obj"),
    ]
    .into_iter()
    .map(|p| {
        (
            p.file_name().unwrap().to_string_lossy().into_owned(),
            Surface::load_obj(&p).unwrap(),
        )
    })
    .collect()
}

/// Base point at corner-frame parameter (a, b) of sector (quad, corner c).
fn at(quad: BaseQuadId, c: u8, a: f64, b: f64) -> BaseLocation {
    // Corner frame: v at (0,0), first axis toward corner c+1, second toward corner c-1.
    const CORNER: [(f64, f64); 4] = [(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0)];
    const NEXT: [(f64, f64); 4] = [(1.0, 0.0), (0.0, 1.0), (-1.0, 0.0), (0.0, -1.0)];
    let c = c as usize;
    let (cs, ct) = CORNER[c];
    let (ns, nt) = NEXT[c];
    let (ps, pt) = NEXT[(c + 3) % 4];
    let (ps, pt) = (-ps, -pt);
    BaseLocation {
        quad,
        s: cs + a * ns + b * ps,
        t: ct + a * nt + b * pt,
    }
}

#[test]
fn charts_agree_along_shared_edges_and_have_no_folds() {
    for (name, s) in meshes() {
        let charts = Charts::new(&s);
        let mut edges = 0;
        for v in 0..s.base.num_vertices() {
            let Some(ch) = charts.chart(VertexId(v as u32)) else {
                continue;
            };
            let k = ch.valence();
            let pairs = if ch.is_boundary() {
                k.saturating_sub(1)
            } else {
                k
            };
            for j in 0..pairs {
                let (qa, ca) = ch.sectors[j];
                let (qb, cb) = ch.sectors[(j + 1) % k];
                for i in 0..=16 {
                    let x = i as f64 / 16.0;
                    let la = at(qa, ca, 0.0, x);
                    let lb = at(qb, cb, x, 0.0);
                    // Same surface point, same chart point.
                    let pa = s.eval_base(la.quad, la.s, la.t).p;
                    let pb = s.eval_base(lb.quad, lb.s, lb.t).p;
                    assert!(
                        (pa - pb).length() < 1e-9,
                        "{name}: v{v} sectors {j}: surface points differ"
                    );
                    let ya = ch.phi(la).unwrap().y;
                    let yb = ch.phi(lb).unwrap().y;
                    assert!(
                        (ya - yb).length() <= 1e-9,
                        "{name}: v{v} sectors {j}/{}: Φ differs by {}",
                        j + 1,
                        (ya - yb).length()
                    );
                    edges += 1;
                }
            }
            for &(q, c) in &ch.sectors {
                for ia in 0..=8 {
                    for ib in 0..=8 {
                        let (a, b) = (ia as f64 / 16.0, ib as f64 / 16.0);
                        if a + b == 0.0 {
                            continue;
                        }
                        let cp = ch.phi(at(q, c, a, b)).unwrap();
                        let det = cp.jacobian.determinant();
                        assert!(
                            det > 0.0,
                            "{name}: v{v} quad {} ({a},{b}): det DΦ = {det}",
                            q.0
                        );
                    }
                }
            }
        }
        assert!(edges > 0, "{name}");
    }
}

#[test]
fn phi_inverse_inverts_phi() {
    let mut rng = Lcg(7);
    for (name, s) in meshes() {
        let charts = Charts::new(&s);
        let mut worst: f64 = 0.0;
        for _ in 0..3000 {
            let q = BaseQuadId((rng.next() * s.num_base_quads() as f64) as u32);
            let loc = BaseLocation {
                quad: q,
                s: rng.next(),
                t: rng.next(),
            };
            for (rank, v) in Charts::candidates(&s, loc).into_iter().enumerate() {
                let ch = charts.chart(v).unwrap();
                let y = ch.phi(loc).unwrap().y;
                let back = ch
                    .phi_inv(y)
                    .unwrap_or_else(|| panic!("{name}: Φ⁻¹ failed at {loc:?} (candidate {rank})"));
                // Points on shared edges may come back in the neighbouring quad: compare on the surface.
                let p0 = s.eval_base(loc.quad, loc.s, loc.t).p;
                let p1 = s.eval_base(back.quad, back.s, back.t).p;
                if back.quad == loc.quad {
                    worst = worst
                        .max((back.s - loc.s).abs())
                        .max((back.t - loc.t).abs());
                } else {
                    assert!(
                        (p0 - p1).length() < 1e-9,
                        "{name}: {loc:?} came back as {back:?}"
                    );
                }
            }
        }
        assert!(worst <= 1e-9, "{name}: Φ⁻¹(Φ(x)) off by {worst}");
    }
}

#[test]
fn points_outside_the_chart_are_rejected() {
    let (_, s) = &meshes()[0];
    let charts = Charts::new(s);
    let ch = charts.chart(VertexId(0)).unwrap();
    assert!(ch.phi_inv(DVec2::new(10.0, 0.0)).is_none());
}
