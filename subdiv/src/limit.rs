//! Limit masks: the exact limit position and normal at a vertex of an all-quad mesh.
//!
//! Used only where patch evaluation cannot reach: exactly *at* an extraordinary vertex
//! (interior valence != 4, or a boundary vertex with 3 or more faces). Everywhere else the
//! bicubic patches of [`crate::patch`] are exact.

use crate::ids::VertexId;
use crate::topology::PolyMesh;
use glam::DVec3;
use std::f64::consts::PI;

/// Limit position, unit normal and two unit tangents (the first toward the vertex's first
/// edge neighbour, see [`PolyMesh::vertex_out`]).
#[derive(Clone, Copy, Debug)]
pub struct VertexLimit {
    pub position: DVec3,
    pub normal: DVec3,
    pub tangent1: DVec3,
    pub tangent2: DVec3,
}

/// Limit position and normal of vertex `v` of a quad mesh with its whole 1-ring present.
pub fn vertex_limit(m: &PolyMesh, v: VertexId) -> VertexLimit {
    let s = m.pos(v);
    let outs: Vec<u32> = m.outgoing(v).collect();
    let n = outs.len();
    let e: Vec<DVec3> = outs.iter().map(|&h| m.pos(m.dest(h))).collect();
    let f: Vec<DVec3> = outs.iter().map(|&h| m.pos(m.dest(m.next(h)))).collect();
    if m.is_boundary_vertex(v) {
        // The boundary is a cubic B-spline curve: position (a + 4S + b)/6, tangent b - a.
        let a = e[0];
        let b = m.pos(m.origin(m.prev(*outs.last().unwrap())));
        let position = (a + 4.0 * s + b) / 6.0;
        if n == 1 {
            let t1 = a - s;
            let t2 = b - s;
            return finish(s, t1, t2);
        }
        // Cross-boundary tangent: Catmull-Clark boundary mask (Biermann, Levin, Zorin 2000,
        // Table 1 with smooth boundary, theta_k = pi / k over k = n faces). The along-boundary
        // tangent is exact; the cross tangent gives the direction, which is what the normal
        // needs (OpenSubdiv's own normals at such vertices are not unique either).
        let k = n as f64;
        let theta = PI / k;
        let mut t2 = DVec3::ZERO;
        // Interior edge neighbours e[1..n] and face points f[0..n].
        let mut w0 = 0.0;
        for (i, ei) in e.iter().enumerate().skip(1) {
            let w = (i as f64 * theta).sin();
            t2 += w * (*ei - s);
            w0 += w;
        }
        for (i, fi) in f.iter().enumerate() {
            let w = ((i as f64 + 0.5) * theta).sin() * 0.5;
            t2 += w * (*fi - s);
            w0 += w;
        }
        let _ = w0;
        let along = a - b;
        let mut r = finish(position, along, t2);
        r.position = position;
        return r;
    }
    let nf = n as f64;
    let mut sum_e = DVec3::ZERO;
    let mut sum_f = DVec3::ZERO;
    for i in 0..n {
        sum_e += e[i];
        sum_f += f[i];
    }
    let position = (nf * nf * s + 4.0 * sum_e + sum_f) / (nf * (nf + 5.0));
    if n == 2 {
        // Valence 2: the standard tangent masks vanish. The limit tangent plane is spanned
        // by the two face-diagonal directions relative to the edge line.
        let t1 = e[0] - e[1];
        let t2 = (f[0] - f[1]) - (e[0] - e[1]) * 0.0;
        return finish(position, t1, t2);
    }
    let a = 1.0
        + (2.0 * PI / nf).cos()
        + (PI / nf).cos() * (2.0 * (9.0 + (2.0 * PI / nf).cos())).sqrt();
    let mut t1 = DVec3::ZERO;
    let mut t2 = DVec3::ZERO;
    for i in 0..n {
        let c0 = (2.0 * PI * i as f64 / nf).cos();
        let c1 = (2.0 * PI * (i + 1) as f64 / nf).cos();
        let s0 = (2.0 * PI * i as f64 / nf).sin();
        let s1 = (2.0 * PI * (i + 1) as f64 / nf).sin();
        t1 += a * c0 * e[i] + (c0 + c1) * f[i];
        t2 += a * s0 * e[i] + (s0 + s1) * f[i];
    }
    finish(position, t1, t2)
}

fn finish(position: DVec3, t1: DVec3, t2: DVec3) -> VertexLimit {
    let normal = t1.cross(t2).normalize_or_zero();
    let tangent1 = (t1 - normal * normal.dot(t1)).normalize_or_zero();
    let tangent2 = normal.cross(tangent1);
    VertexLimit {
        position,
        normal,
        tangent1,
        tangent2,
    }
}
