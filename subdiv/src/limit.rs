//! Limit masks: the exact limit position and normal at a vertex of an all-quad mesh.
//!
//! Used only where patch evaluation cannot reach: exactly *at* an extraordinary vertex
//! (interior valence != 4, a boundary vertex with 3 or more faces, or a vertex that
//! infinitely sharp edges make irregular: a dart, a crease or corner whose sector is not
//! the regular one). Everywhere else the bicubic patches of [`crate::patch`] are exact.
//! No semi-sharp value may be left at the vertex (the patch trees refine until it decays).
//!
//! By rule (OpenSubdiv's `Sdc::Scheme<CATMARK>` limit masks): smooth, the interior masks
//! below; crease, the cubic B-spline along the crease, (a + 4S + b) / 6; corner, S. A dart
//! has no closed-form mask here: its sharp edge changes the subdivision matrix, and the
//! smooth mask OpenSubdiv applies there moves with the level it is applied at (its own
//! README of the reference data measures 4e-7..5e-5 between levels 8 and 10). We refine the
//! 1-ring until the centre has converged instead. Where sharp edges split the faces into
//! sectors, the normal is the one of the face's sector (one-sided).

use crate::crease::Rule;
use crate::ids::{FaceId, VertexId};
use crate::refine::refine;
use crate::topology::Check;
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

/// Limit position of the origin of half-edge `h` (a vertex of a quad mesh with its whole
/// 1-ring present) and normal and tangents on the side of the face of `h` (its sector).
pub fn corner_limit(m: &PolyMesh, h: u32) -> VertexLimit {
    let v = m.origin(h);
    if !m.has_tags() {
        return vertex_limit(m, v);
    }
    let s = m.pos(v);
    let k = m
        .outgoing(v)
        .position(|g| g == h)
        .expect("h leaves its origin");
    let rule = m.vertex_rule(v);
    let sector = m.sector(h);
    match rule {
        Rule::Smooth => vertex_limit(m, v),
        Rule::Dart => {
            let position = position_by_refinement(m, v);
            let normal = normal_near_corner(m, h);
            with_normal(position, normal, m.pos(m.dest(sector.first)) - s)
        }
        Rule::Crease | Rule::Corner => {
            let mut ends = m
                .vertex_edges(v)
                .filter(|&(g, _)| m.edge_sharpness(g).is_sharp())
                .map(|(_, w)| m.pos(w));
            let position = if rule == Rule::Crease {
                let a = ends.next().expect("a crease has two sharp edges");
                let b = ends.next().expect("a crease has two sharp edges");
                (a + 4.0 * s + b) / 6.0
            } else {
                s
            };
            // The sector's leading and trailing edges: its first outgoing edge and the
            // edge closing its last face.
            let lead = m.pos(m.dest(sector.first));
            let mut last = sector.first;
            for _ in 1..sector.faces {
                last = m.twin(m.prev(last)).expect("faces of a sector are joined");
            }
            let trail = m.pos(m.origin(m.prev(last)));
            if rule == Rule::Corner && sector.faces == 1 {
                return finish(s, lead - s, trail - s);
            }
            // A cone point (sharp vertex, smooth edges) has no tangent plane: there the
            // face's own normal at the corner. Otherwise the sector is refined like a
            // boundary fan (also the one face between the two halves of a crease curve,
            // which narrows like the square of the distance toward the vertex: its own
            // normal there is lost to rounding).
            let normal = if sector.closed {
                normal_near_corner(m, h)
            } else {
                // A sector whose faces fold back onto each other (two faces on the same
                // four vertices, opposite ways round: the double-sided sheets of
                // non-manifold input) has no fan normal; then the face's own, as there.
                normal_by_refinement(m, v, position, k)
                    .try_normalize()
                    .unwrap_or_else(|| normal_near_corner(m, h))
            };
            // Along the crease (leading minus trailing edge); around a cone point (a
            // sharp vertex with no sharp edge) toward the first edge neighbour.
            let along = if sector.closed {
                lead - s
            } else {
                lead - trail
            };
            with_normal(position, normal, along)
        }
    }
}

/// Limit position and normal of vertex `v` of an untagged quad mesh with its whole 1-ring
/// present (see [`corner_limit`] for tagged meshes).
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
        // No closed-form cross-boundary mask is used here: the tangent plane comes from
        // the subdivision itself (see `normal_by_refinement`); the along-boundary tangent
        // b - a is exact.
        let normal = normal_by_refinement(m, v, position, 0);
        let along = a - b;
        let t2 = normal.cross(along);
        return finish(position, along, t2);
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
        // Valence 2: the closed-form tangent masks vanish; take the plane from refinement.
        let normal = normal_by_refinement(m, v, position, 0);
        let t1 = e[0] - e[1];
        return finish(position, t1, normal.cross(t1));
    }
    let computed;
    let mask = match TANGENT_MASKS.get_or_init(tangent_masks).get(n) {
        Some(mask) => mask,
        None => {
            computed = TangentMask::new(n);
            &computed
        }
    };
    let (a, cos, sin) = (mask.a, &mask.cos, &mask.sin);
    let mut t1 = DVec3::ZERO;
    let mut t2 = DVec3::ZERO;
    for i in 0..n {
        let (c0, c1, s0, s1) = (cos[i], cos[i + 1], sin[i], sin[i + 1]);
        t1 += a * c0 * e[i] + (c0 + c1) * f[i];
        t2 += a * s0 * e[i] + (s0 + s1) * f[i];
    }
    finish(position, t1, t2)
}

/// The coefficients of the interior tangent masks of valence n: a(n) and the cosines and
/// sines of 2πi/n for i in 0..=n. The same expressions as computing them at every vertex
/// (the same bits), once per valence: the trigonometry was a tenth of building the patch
/// trees of an all-triangle mesh.
struct TangentMask {
    a: f64,
    cos: Vec<f64>,
    sin: Vec<f64>,
}

impl TangentMask {
    fn new(n: usize) -> Self {
        let nf = n as f64;
        let a = 1.0
            + (2.0 * PI / nf).cos()
            + (PI / nf).cos() * (2.0 * (9.0 + (2.0 * PI / nf).cos())).sqrt();
        let angle = |i: usize| 2.0 * PI * i as f64 / nf;
        TangentMask {
            a,
            cos: (0..=n).map(|i| angle(i).cos()).collect(),
            sin: (0..=n).map(|i| angle(i).sin()).collect(),
        }
    }
}

/// Valences whose [`TangentMask`]s are tabled: the common ones. Rarer, higher valences
/// (up to [`crate::topology::MAX_VALENCE`]) compute theirs at the vertex — the same bits —
/// rather than every run holding ~8 MB of masks of valences up to 1024.
const TABLED_VALENCE: usize = 64;

/// [`TangentMask`]s of every valence up to [`TABLED_VALENCE`].
static TANGENT_MASKS: std::sync::OnceLock<Vec<TangentMask>> = std::sync::OnceLock::new();

fn tangent_masks() -> Vec<TangentMask> {
    (0..=TABLED_VALENCE).map(TangentMask::new).collect()
}

/// The limit with a known unit normal, `dir` projected on its tangent plane as the first
/// tangent.
fn with_normal(position: DVec3, normal: DVec3, dir: DVec3) -> VertexLimit {
    let tangent1 = (dir - normal * normal.dot(dir))
        .try_normalize()
        .unwrap_or_else(|| normal.any_orthonormal_vector());
    VertexLimit {
        position,
        normal,
        tangent1,
        tangent2: normal.cross(tangent1),
    }
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

/// The limit normal at `v` from repeated local refinement of its 1-ring: the ring points
/// minus the limit point converge onto the tangent plane (the components along the two
/// subdominant eigenvectors shrink slowest), so after enough steps the plane of consecutive
/// ring vectors is the limit tangent plane. The error falls like (λ3/λ2)^L while rounding
/// grows like 1/λ^L; measured against the exact interior masks, L = 18 is best (worst
/// 1e-5° over Spot, pole8 and the cube; 6e-4° at L = 24, 67° at L = 40).
const REFINEMENT_STEPS: usize = 18;

/// See `REFINEMENT_STEPS`. The normal of the sector (see [`PolyMesh::sector`]) of the
/// `k`-th face around `v` (counter-clockwise from [`PolyMesh::vertex_out`]): sectors are
/// refined together, and the refined faces keep their order around the centre.
pub fn normal_by_refinement(m: &PolyMesh, v: VertexId, limit: DVec3, k: usize) -> DVec3 {
    let mut ring = one_ring(m, v);
    let mut center = VertexId(0);
    for _ in 0..REFINEMENT_STEPS {
        let r = refine(&ring);
        // Keep the child of each face at the corner `center` (vertex points keep their
        // index, so the centre stays vertex 0 after re-extraction).
        ring = one_ring(&r, center);
        center = VertexId(0);
    }
    // The sector's ring in counter-clockwise order, edge and face neighbours interleaved
    // (with edge neighbours alone, valence 2 would give two cancelling cross products),
    // closed by its trailing edge unless it goes all the way round.
    let hk = ring
        .outgoing(center)
        .nth(k)
        .expect("the ring keeps its faces");
    let sector = ring.sector(hk);
    let mut d: Vec<DVec3> = Vec::with_capacity(2 * sector.faces + 1);
    let mut h = sector.first;
    for i in 0..sector.faces {
        d.push(ring.pos(ring.dest(h)) - limit);
        d.push(ring.pos(ring.dest(ring.next(h))) - limit);
        if i + 1 < sector.faces {
            h = ring
                .twin(ring.prev(h))
                .expect("faces of a sector are joined");
        }
    }
    // (A sector cut once, by a sharp edge that ends here, repeats its first vector last.)
    let open = !sector.closed;
    if open {
        d.push(ring.pos(ring.origin(ring.prev(h))) - limit);
    }
    let scale = d.iter().map(|x| x.length()).fold(0.0, f64::max).max(1e-300);
    let mut n = DVec3::ZERO;
    let pairs = if open { d.len() - 1 } else { d.len() };
    for j in 0..pairs {
        n += (d[j] / scale).cross(d[(j + 1) % d.len()] / scale);
    }
    n.normalize_or_zero()
}

/// Levels of [`normal_near_corner`]: the normal is read 2^-(L+1) of a quad from the
/// vertex. It approaches the limit like a power ~0.85 of that distance at a dart (measured
/// on `catmark_cubes_infsharp`), while rounding grows like 1e-16 / distance; L = 30 leaves
/// both near 1e-7 rad.
const NEAR_LEVELS: usize = 30;

/// The unit normal of the face of `h` at its corner `origin(h)`, as the limit of the face's
/// own normals: the quad (of an all-quad mesh) refined `NEAR_LEVELS` times toward that
/// corner, then the normal of the regular patch diagonally next to the corner's quad, at its
/// corner nearest the vertex.
///
/// For darts, where the 1-ring of [`normal_by_refinement`] converges onto a plane 6.7° off
/// the surface's (on `catmark_cubes_infsharp`; the surface's normals themselves converge,
/// from every face, to one vector: the tip of a dart is smooth), and for cone points,
/// which have no tangent plane.
pub fn normal_near_corner(m: &PolyMesh, h: u32) -> DVec3 {
    use crate::patch::BSplinePatch;
    use crate::submesh::{extract_submesh, is_regular_quad};
    let q = m.face_of(h);
    let mut c = (h - m.face_he(q)) as usize;
    let mut sub = extract_submesh(m, q);
    for _ in 0..NEAR_LEVELS {
        // Child c of face 0 has the vertex at its corner 0.
        sub = extract_submesh(&refine(&sub), FaceId::from_idx(c));
        c = 0;
    }
    // Child 2 of face 0: opposite the vertex, its corner 2 is face 0's centre.
    let last = extract_submesh(&refine(&sub), FaceId(2));
    let q0 = FaceId(0);
    let p = is_regular_quad(&last, q0)
        .then(|| BSplinePatch::gather(&last, q0))
        .flatten();
    match p {
        Some(p) => {
            let e = p.eval(1.0, 1.0);
            e.ds.cross(e.dt).normalize_or_zero()
        }
        // Not reached for a manifold quad mesh; the ring is the next best answer.
        None => normal_by_refinement(m, m.origin(h), m.pos(m.origin(h)), 0),
    }
}

/// Steps of [`position_by_refinement`]: the centre converges like the subdominant
/// eigenvalue of the local subdivision matrix to the power of the level (≤ 0.6 for the
/// darts of the reference shapes, so 64 steps leave < 1e-14).
const POSITION_STEPS: usize = 64;

/// The limit position of `v` as the limit of its own vertex points: the 1-ring refined
/// `POSITION_STEPS` times (for rules without a closed-form mask here: darts).
pub fn position_by_refinement(m: &PolyMesh, v: VertexId) -> DVec3 {
    let mut ring = one_ring(m, v);
    for _ in 0..POSITION_STEPS {
        ring = one_ring(&refine(&ring), VertexId(0));
    }
    ring.pos(VertexId(0))
}

/// The faces around `v` as a mesh of their own with `v` as vertex 0.
fn one_ring(m: &PolyMesh, v: VertexId) -> PolyMesh {
    let mut map: Vec<(u32, u32)> = vec![(v.0, 0)];
    let mut positions = vec![m.pos(v)];
    let mut face_start = vec![0u32];
    let mut face_verts = Vec::new();
    let faces: Vec<FaceId> = m.outgoing(v).map(|h| m.face_of(h)).collect();
    for &f in &faces {
        for &w in m.face_vertices(f) {
            let l = match map.iter().find(|(g, _)| *g == w) {
                Some(&(_, l)) => l,
                None => {
                    positions.push(m.positions[w as usize]);
                    map.push((w, positions.len() as u32 - 1));
                    positions.len() as u32 - 1
                }
            };
            face_verts.push(l);
        }
        face_start.push(face_verts.len() as u32);
    }
    let mut ring = PolyMesh::new(positions, face_start, face_verts, Check::Trusted)
        .expect("1-ring of a valid mesh");
    ring.inherit_tags(m, &faces, &map);
    ring
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ControlMesh;

    /// At interior vertices the closed-form masks are exact; the refinement normal must agree.
    #[test]
    fn refinement_normal_agrees_with_interior_masks() {
        for shape in ["catmark_pole8", "spot_control_mesh", "catmark_cube"] {
            let cm = ControlMesh::load_obj(crate::test_data::opensubdiv_reference(&format!(
                "{shape}.obj"
            )))
            .unwrap();
            let base = refine(&cm.mesh);
            for v in 0..base.num_vertices() {
                let v = VertexId(v as u32);
                if base.is_boundary_vertex(v) || base.vertex_faces(v) == 4 {
                    continue;
                }
                let l = vertex_limit(&base, v);
                let n = normal_by_refinement(&base, v, l.position, 0);
                let ang = n.dot(l.normal).clamp(-1.0, 1.0).acos().to_degrees();
                assert!(ang < 1e-4, "{shape} v{}: {ang}°", v.0);
            }
        }
    }
}
