//! Cutting the 1-ring submesh of a quad out of a mesh, and the test for a quad that is
//! one B-spline patch: what the patch trees ([`crate::surface`]), the deep levels refined
//! on demand ([`crate::deep`]) and the normals near corners ([`crate::limit`]) all refine
//! locally with, kept below all three so that none of them imports another for it.

use crate::ids::{FaceId, VertexId};
use crate::topology::{Check, PolyMesh, NONE};

/// Whether quad `q` of `m` is exactly one bicubic B-spline patch: every corner regular
/// on the quad's side of its sharp edges, no semi-sharp value left at any
/// ([`PolyMesh::corner_is_regular`]).
#[inline]
pub(crate) fn is_regular_quad(m: &PolyMesh, q: FaceId) -> bool {
    let h = m.face_he(q);
    (0..4).all(|i| m.corner_is_regular(h + i))
}

/// Where the elements of a mesh went in the submesh being cut out of it, per thread: entry
/// i is (stamp, index here), valid only when the stamp is the current call's, so nothing is
/// cleared between calls (all of it when the stamp wraps).
#[derive(Default)]
struct LocalIndex {
    stamp: u32,
    vertices: Vec<(u32, u32)>,
    faces: Vec<(u32, u32)>,
}

impl LocalIndex {
    /// Starts a new submesh of a mesh with `nv` vertices and `nf` faces.
    fn start(&mut self, nv: usize, nf: usize) {
        self.stamp = self.stamp.wrapping_add(1);
        if self.stamp == 0 {
            self.vertices.clear();
            self.faces.clear();
            self.stamp = 1;
        }
        if self.vertices.len() < nv {
            self.vertices.resize(nv, (0, 0));
        }
        if self.faces.len() < nf {
            self.faces.resize(nf, (0, 0));
        }
    }

    #[inline]
    fn get(table: &[(u32, u32)], stamp: u32, i: u32) -> Option<u32> {
        let (s, l) = table[i as usize];
        (s == stamp).then_some(l)
    }
}

thread_local! {
    static LOCAL_INDEX: std::cell::RefCell<LocalIndex> = Default::default();
}

/// The faces around the corners of quad `q`, as a new mesh whose face 0 is `q` with its
/// vertex order kept. Refining it gives exact values for everything the children of `q`
/// need (their own 1-ring submeshes).
pub(crate) fn extract_submesh(m: &PolyMesh, q: FaceId) -> PolyMesh {
    LOCAL_INDEX.with(|index| match index.try_borrow_mut() {
        Ok(mut index) => extract_submesh_with(m, q, &mut index),
        Err(_) => extract_submesh_with(m, q, &mut LocalIndex::default()),
    })
}

fn extract_submesh_with(m: &PolyMesh, q: FaceId, index: &mut LocalIndex) -> PolyMesh {
    index.start(m.num_vertices(), m.num_faces());
    let stamp = index.stamp;
    let mut faces: Vec<FaceId> = Vec::with_capacity(32);
    let mut add_face = |f: FaceId, faces: &mut Vec<FaceId>| {
        if LocalIndex::get(&index.faces, stamp, f.0).is_none() {
            index.faces[f.idx()] = (stamp, faces.len() as u32);
            faces.push(f);
        }
    };
    add_face(q, &mut faces);
    for &v in m.face_vertices(q) {
        for h in m.outgoing(VertexId(v)) {
            add_face(m.face_of(h), &mut faces);
        }
    }
    let mut map: Vec<(u32, u32)> = Vec::with_capacity(faces.len() * 4);
    let mut positions = crate::pool::points(faces.len() * 3);
    let mut face_start = crate::pool::ints(faces.len() + 1);
    let mut face_verts = crate::pool::ints(faces.len() * 4);
    face_start.push(0);
    for &f in &faces {
        for &v in m.face_vertices(f) {
            let local = match LocalIndex::get(&index.vertices, stamp, v) {
                Some(l) => l,
                None => {
                    positions.push(m.positions[v as usize]);
                    let l = positions.len() as u32 - 1;
                    map.push((v, l));
                    index.vertices[v as usize] = (stamp, l);
                    l
                }
            };
            face_verts.push(local);
        }
        face_start.push(face_verts.len() as u32);
    }
    let mut sub = if m.is_clean() {
        // A kept half-edge's twin is its parent twin's image where that face is kept too.
        let mut twins = crate::pool::ints_filled(face_verts.len(), NONE);
        for (k, &f) in faces.iter().enumerate() {
            let (h0, g0) = (face_start[k], m.face_he(f));
            for i in 0..m.face_size(f) as u32 {
                let Some(t) = m.twin(g0 + i) else { continue };
                let tf = m.face_of(t);
                if let Some(j) = LocalIndex::get(&index.faces, stamp, tf.0) {
                    twins[(h0 + i) as usize] = face_start[j as usize] + (t - m.face_he(tf));
                }
            }
        }
        PolyMesh::from_twins(positions, face_start, face_verts, twins)
    } else {
        PolyMesh::new(positions, face_start, face_verts, Check::Trusted)
            .expect("submesh of a valid mesh")
    };
    sub.inherit_tags(m, &faces, &map);
    sub
}
