//! One step of Catmull-Clark refinement with the EDGE_AND_CORNER boundary rule.
//!
//! Rules (as in `shared/data/opensubdiv-reference/README.md`):
//! - face point: centroid;
//! - interior edge point: (v0 + v1 + F0 + F1) / 4; boundary edge point: midpoint;
//! - interior vertex point: (Q + 2R + (n-3) S) / n, Q mean of adjacent face points,
//!   R mean of incident edge midpoints, n the valence;
//! - boundary vertex: (prev + 6 S + next) / 8; a corner (one face) stays fixed.
//!
//! Child vertices are numbered like OpenSubdiv: vertex points by parent vertex, then face
//! points by parent face, then edge points by parent edge. Child faces are quads numbered by
//! parent face and corner: child `face_start[f] + c` = (vertex point of corner c, edge point
//! of edge (c, c+1), face point, edge point of edge (c-1, c)). That is exactly the Ptex
//! sub-face c of an n-gon, with (u, v) = (0, 0) at the corner.

use crate::ids::{FaceId, VertexId};
use crate::topology::{Check, PolyMesh};
use glam::DVec3;

/// Refines `m` once. Vertices whose neighbourhood is incomplete (the cut boundary of a local
/// submesh) get *some* value: callers only read vertices whose full 1-ring is present.
pub fn refine(m: &PolyMesh) -> PolyMesh {
    let nv = m.num_vertices();
    let nf = m.num_faces();
    let ne = m.num_edges();
    let mut pos = vec![DVec3::ZERO; nv + nf + ne];
    let (vpts, rest) = pos.split_at_mut(nv);
    let (fpts, epts) = rest.split_at_mut(nf);

    for (f, fp) in fpts.iter_mut().enumerate() {
        let vs = m.face_vertices(FaceId::from_idx(f));
        let sum: DVec3 = vs.iter().map(|&v| m.positions[v as usize]).sum();
        *fp = sum / vs.len() as f64;
    }
    for (e, ep) in epts.iter_mut().enumerate() {
        let h = m.edge_half_edge(e);
        let a = m.pos(m.origin(h));
        let b = m.pos(m.dest(h));
        *ep = match m.twin(h) {
            Some(t) => (a + b + fpts[m.face_of(h).idx()] + fpts[m.face_of(t).idx()]) * 0.25,
            None => (a + b) * 0.5,
        };
    }
    for (v, vp) in vpts.iter_mut().enumerate() {
        *vp = vertex_point(m, VertexId::from_idx(v), fpts);
    }

    let nh = m.num_half_edges();
    let mut face_start = Vec::with_capacity(nh + 1);
    let mut face_verts = Vec::with_capacity(nh * 4);
    face_start.push(0u32);
    for f in 0..nf {
        let fid = FaceId::from_idx(f);
        let h0 = m.face_he(fid);
        let n = m.face_size(fid) as u32;
        for c in 0..n {
            let h = h0 + c;
            let hp = m.prev(h);
            face_verts.extend([
                m.origin(h).0,
                (nv + nf + m.edge_of(h)) as u32,
                (nv + f) as u32,
                (nv + nf + m.edge_of(hp)) as u32,
            ]);
            face_start.push(face_verts.len() as u32);
        }
    }
    PolyMesh::new(pos, face_start, face_verts, Check::Trusted)
        .expect("refinement of a valid mesh is valid")
}

fn vertex_point(m: &PolyMesh, v: VertexId, fpts: &[DVec3]) -> DVec3 {
    let s = m.pos(v);
    let nfaces = m.vertex_faces(v);
    if nfaces == 0 {
        return s;
    }
    if m.is_boundary_vertex(v) {
        if nfaces == 1 {
            return s; // corner
        }
        let first = m
            .vertex_out(v)
            .expect("vertex with faces has an outgoing half-edge");
        let last = m.outgoing(v).last().unwrap_or(first);
        let a = m.pos(m.dest(first));
        let b = m.pos(m.origin(m.prev(last)));
        return (a + 6.0 * s + b) * 0.125;
    }
    let n = nfaces as f64;
    let mut q = DVec3::ZERO;
    let mut r = DVec3::ZERO;
    for h in m.outgoing(v) {
        q += fpts[m.face_of(h).idx()];
        r += (s + m.pos(m.dest(h))) * 0.5;
    }
    (q / n + 2.0 * r / n + (n - 3.0) * s) / n
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ControlMesh;

    #[test]
    fn cube_refines_to_24_quads_with_expected_points() {
        let p = |x, y, z| DVec3::new(x, y, z);
        let pos = vec![
            p(-1., -1., 1.),
            p(1., -1., 1.),
            p(-1., 1., 1.),
            p(1., 1., 1.),
            p(-1., 1., -1.),
            p(1., 1., -1.),
            p(-1., -1., -1.),
            p(1., -1., -1.),
        ];
        let faces: [&[u32]; 6] = [
            &[0, 1, 3, 2],
            &[2, 3, 5, 4],
            &[4, 5, 7, 6],
            &[6, 7, 1, 0],
            &[1, 7, 5, 3],
            &[6, 0, 2, 4],
        ];
        let cm = ControlMesh::from_faces(pos, &faces).unwrap();
        let r = refine(&cm.mesh);
        assert_eq!(r.num_faces(), 24);
        assert_eq!(r.num_vertices(), 8 + 6 + 12);
        // Valence-3 corner of a cube: (Q + 2R + 0*S)/3 with Q = (1/3,1/3,1/3)*... known value 5/9.
        let v0 = r.positions[0];
        assert!(
            (v0 - p(-5. / 9., -5. / 9., 5. / 9.)).length() < 1e-15,
            "{v0}"
        );
        // Face point of face 0 is its centre.
        assert!((r.positions[8] - p(0., 0., 1.)).length() < 1e-15);
        // Edge point of an edge: (a+b+F0+F1)/4 = 3/4 along the edge's midpoint direction.
        assert!(
            (r.positions[14] - p(0., -0.75, 0.75)).length() < 1e-15,
            "{}",
            r.positions[14]
        );
    }
}
