//! One step of Catmull-Clark refinement with creases (OpenSubdiv's rules, uniform creasing)
//! and the EDGE_AND_CORNER boundary rule.
//!
//! Rules (as in `shared/data/opensubdiv-reference/README.md` and OpenSubdiv's
//! `Sdc::Scheme<CATMARK>`; sharpness and vertex rules in [`crate::crease`]):
//! - face point: centroid;
//! - edge point: smooth edge (v0 + v1 + F0 + F1) / 4; sharp edge (sharpness > 1, or
//!   infinite, e.g. a boundary) the midpoint; sharpness s in (0, 1] (it decays to 0 in this
//!   step) the blend s · midpoint + (1 − s) · smooth point;
//! - vertex point by the vertex's rule: smooth or dart (Q + 2R + (n−3) S) / n, Q the mean
//!   of the adjacent face points, R of the incident edge midpoints, n the valence; crease
//!   (a + 6 S + b) / 8 with a, b the far ends of its two sharp edges (a boundary vertex:
//!   its boundary neighbours); corner S (a sharp vertex, three or more sharp edges, or a
//!   boundary vertex with one face). Where the rule of the child (with every sharpness one
//!   lower) differs, the parent's and the child's points are blended by
//!   [`crate::crease::fractional_weight`].
//!
//! Sharpness is subdivided with the mesh: the two halves of an edge get its sharpness
//! minus one, edges inside a face are smooth, a vertex point gets its vertex's sharpness
//! minus one.
//!
//! Child vertices are numbered like OpenSubdiv: vertex points by parent vertex, then face
//! points by parent face, then edge points by parent edge. Child faces are quads numbered by
//! parent face and corner: child `face_start[f] + c` = (vertex point of corner c, edge point
//! of edge (c, c+1), face point, edge point of edge (c-1, c)). That is exactly the Ptex
//! sub-face c of an n-gon, with (u, v) = (0, 0) at the corner.

use crate::crease::{fractional_weight, Rule, Sharpness};
use crate::ids::{FaceId, VertexId};
use crate::topology::{Check, PolyMesh};
use glam::DVec3;

/// Refines `m` once. Vertices whose neighbourhood is incomplete (the cut boundary of a local
/// submesh) get *some* value: callers only read vertices whose full 1-ring is present.
pub fn refine(m: &PolyMesh) -> PolyMesh {
    let nv = m.num_vertices();
    let nf = m.num_faces();
    let ne = m.num_edges();
    let tagged = m.has_tags();
    let mut pos = crate::pool::points(nv + nf + ne);
    pos.resize(nv + nf + ne, DVec3::ZERO);
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
            Some(t) => {
                let smooth =
                    || (a + b + fpts[m.face_of(h).idx()] + fpts[m.face_of(t).idx()]) * 0.25;
                let s = m.tagged_edge_sharpness(e);
                if s.is_smooth() {
                    smooth()
                } else if s.value() > 1.0 {
                    (a + b) * 0.5
                } else {
                    // Crease to smooth in this step: OpenSubdiv's transitional edge mask.
                    let w = s.value() as f64;
                    (a + b) * 0.5 * w + smooth() * (1.0 - w)
                }
            }
            None => (a + b) * 0.5,
        };
    }
    for (v, vp) in vpts.iter_mut().enumerate() {
        let v = VertexId::from_idx(v);
        *vp = if tagged {
            tagged_vertex_point(m, v, fpts)
        } else {
            vertex_point(m, v, fpts)
        };
    }

    let nh = m.num_half_edges();
    let mut face_start = crate::pool::ints(nh + 1);
    let mut face_verts = crate::pool::ints(nh * 4);
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
    let mut child = if m.is_clean() {
        m.refined_topology(pos, face_start, face_verts)
    } else {
        PolyMesh::new(pos, face_start, face_verts, Check::Trusted)
            .expect("refinement of a valid mesh is valid")
    };
    if tagged {
        subdivide_sharpness(m, &mut child);
    }
    child
}

/// Sharpness of the child mesh: child half-edges 0 and 3 of child face (f, c) are the
/// halves of the parent's edges (c, c+1) and (c−1, c) at corner c; the other two lie inside
/// the face (smooth). Vertex points inherit their vertex's sharpness, one lower.
fn subdivide_sharpness(m: &PolyMesh, child: &mut PolyMesh) {
    let mut edges = Vec::new();
    if (0..m.num_edges()).any(|e| m.tagged_edge_sharpness(e).is_sharp()) {
        edges = vec![Sharpness::SMOOTH; child.num_edges()];
        for h in 0..m.num_half_edges() as u32 {
            // Child face h (numbered like the parent's half-edges).
            let ch = child.face_he(FaceId(h));
            let hp = m.prev(h);
            edges[child.edge_of(ch)] = m.tagged_edge_sharpness(m.edge_of(h)).decremented();
            edges[child.edge_of(ch + 3)] = m.tagged_edge_sharpness(m.edge_of(hp)).decremented();
        }
    }
    let mut verts = Vec::new();
    if (0..m.num_vertices()).any(|v| m.tagged_vertex_sharpness(VertexId::from_idx(v)).is_sharp()) {
        verts = vec![Sharpness::SMOOTH; child.num_vertices()];
        for (v, s) in verts.iter_mut().enumerate().take(m.num_vertices()) {
            *s = m
                .tagged_vertex_sharpness(VertexId::from_idx(v))
                .decremented();
        }
    }
    child.set_sharpness(edges, verts);
}

/// The vertex point of an untagged mesh (smooth inside, crease along a boundary, corner at
/// a boundary vertex with one face).
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
    smooth_vertex_point(m, v, fpts)
}

/// (Q + 2R + (n−3) S) / n.
fn smooth_vertex_point(m: &PolyMesh, v: VertexId, fpts: &[DVec3]) -> DVec3 {
    let s = m.pos(v);
    let n = m.vertex_faces(v) as f64;
    let mut q = DVec3::ZERO;
    let mut r = DVec3::ZERO;
    for h in m.outgoing(v) {
        q += fpts[m.face_of(h).idx()];
        r += (s + m.pos(m.dest(h))) * 0.5;
    }
    (q / n + 2.0 * r / n + (n - 3.0) * s) / n
}

/// Most edges a vertex can have here (valence is capped at `MAX_VALENCE` on input;
/// refinement never raises it).
const MAX_EDGES: usize = crate::topology::MAX_VALENCE + 1;

/// The vertex point with tags: the parent rule's point, blended with the child rule's where
/// sharpness decays in this step (OpenSubdiv's `ComputeVertexVertexMask`).
fn tagged_vertex_point(m: &PolyMesh, v: VertexId, fpts: &[DVec3]) -> DVec3 {
    let s = m.pos(v);
    if m.vertex_faces(v) == 0 {
        return s;
    }
    // Incident edges (counter-clockwise, see `PolyMesh::vertex_edges`): sharpness and far end.
    let mut sharp = [Sharpness::SMOOTH; MAX_EDGES];
    let mut far = [VertexId(0); MAX_EDGES];
    let mut k = 0;
    for (h, w) in m.vertex_edges(v).take(MAX_EDGES) {
        sharp[k] = m.edge_sharpness(h);
        far[k] = w;
        k += 1;
    }
    let (sharp, far) = (&sharp[..k], &far[..k]);
    let vs = m.vertex_sharpness(v);
    let rule_of = |vertex: Sharpness, edges: &mut dyn Iterator<Item = Sharpness>| {
        Rule::of(vertex, edges.filter(|e| e.is_sharp()).count())
    };
    let parent = rule_of(vs, &mut sharp.iter().copied());
    if parent.is_smooth_mask() {
        return smooth_vertex_point(m, v, fpts);
    }
    // The point by `rule` with the edges whose sharpness passes `is_sharp`.
    let point = |rule: Rule, is_sharp: &dyn Fn(Sharpness) -> bool| match rule {
        Rule::Smooth | Rule::Dart => smooth_vertex_point(m, v, fpts),
        Rule::Crease => {
            let mut ends = far
                .iter()
                .zip(sharp)
                .filter(|(_, &e)| is_sharp(e))
                .map(|(&w, _)| m.pos(w));
            let a = ends.next().expect("a crease has two sharp edges");
            let b = ends.next().expect("a crease has two sharp edges");
            (a + 6.0 * s + b) * 0.125
        }
        Rule::Corner => s,
    };
    let p = point(parent, &|e| e.is_sharp());
    let child = rule_of(vs.decremented(), &mut sharp.iter().map(|e| e.decremented()));
    if child == parent {
        return p;
    }
    let c = point(child, &|e| e.decremented().is_sharp());
    let w = fractional_weight(vs, sharp.iter().copied()) as f64;
    p * w + c * (1.0 - w)
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
