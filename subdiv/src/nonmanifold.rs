//! Non-manifold input made manifold the way OpenSubdiv treats it.
//!
//! OpenSubdiv accepts edges shared by three or more faces and vertices whose faces form
//! several fans, and makes them sharp (`Far::TopologyRefinerFactoryBase::
//! prepareComponentTagsAndSharpness`, "sharpenNonManFeatures"): every non-manifold edge is
//! infinitely sharp, and every non-manifold vertex is an infinitely sharp corner — except on
//! an interior non-manifold crease (exactly two non-manifold edges, no boundary edge, more
//! faces than edges), where the two sharp edges give it the crease rule.
//!
//! Our half-edge [`PolyMesh`](crate::topology::PolyMesh) holds manifold meshes only, so the
//! non-manifold places are cut apart instead: every *sector* of a vertex (the faces that
//! reach one another across manifold edges round it) gets a vertex of its own at the same
//! position, and the uses of a non-manifold edge end up on different vertex pairs, so each
//! is a boundary edge (infinitely sharp under EDGE_AND_CORNER, as OpenSubdiv sharpens it).
//! With the vertex sharpness OpenSubdiv gives the vertex put on each of its copies, every
//! vertex, edge and face point of the refinement is computed from the same neighbours with
//! the same rule, so the limit surface is OpenSubdiv's (`tests/opensubdiv_creases.rs`
//! checks it on OpenSubdiv's non-manifold regression shapes). Faces and their numbering —
//! the Ptex domains — are unchanged; the copies are appended after the input's vertices,
//! and the first sector keeps the input's index.
//!
//! Two faces that traverse an edge in the same direction are not treated so (OpenSubdiv
//! would make that edge sharp too): that is almost always a flipped face, whose normal and
//! texture would face inwards, so it stays an error naming the two faces.

use crate::crease::Sharpness;

/// A mesh cut apart at its non-manifold places, with the sharpness OpenSubdiv gives them.
#[derive(Clone, Debug, Default)]
pub struct Split {
    /// Input positions, then one copy per extra sector.
    pub positions: Vec<glam::DVec3>,
    /// The faces over the new vertex indices (same faces, same order, same lengths).
    pub face_verts: Vec<u32>,
    /// The input vertex of every vertex (identity for the input's own).
    pub origin: Vec<u32>,
    /// Vertices (new indices) that OpenSubdiv makes infinitely sharp corners.
    pub corners: Vec<u32>,
    /// Vertex pairs (new indices) of non-manifold edges whose two uses still meet after the
    /// cut (both faces in one sector at both ends): infinitely sharp, as OpenSubdiv makes them.
    pub sharp_edges: Vec<(u32, u32)>,
    /// How many input edges and vertices were non-manifold.
    pub edges: usize,
    pub vertices: usize,
}

impl Split {
    /// Infinite sharpness per vertex for [`Self::corners`] (`nv` entries).
    pub fn corner_sharpness(&self, nv: usize) -> Vec<Sharpness> {
        let mut v = vec![Sharpness::SMOOTH; nv];
        for &c in &self.corners {
            v[c as usize] = Sharpness::INFINITE;
        }
        v
    }
}

/// Union-find with path halving over `n` items.
struct Sets(Vec<u32>);

impl Sets {
    fn new(n: usize) -> Self {
        Sets((0..n as u32).collect())
    }
    fn find(&mut self, mut i: u32) -> u32 {
        while self.0[i as usize] != i {
            let p = self.0[self.0[i as usize] as usize];
            self.0[i as usize] = p;
            i = p;
        }
        i
    }
    fn union(&mut self, a: u32, b: u32) {
        let (a, b) = (self.find(a), self.find(b));
        // The smaller root wins, so that a set's root is its first member.
        if a < b {
            self.0[b as usize] = a;
        } else if b < a {
            self.0[a as usize] = b;
        }
    }
}

/// Cuts the mesh apart where it is non-manifold (see the module doc); `None` when it is
/// manifold already (or when its faces are not well formed: the strict check reports
/// those). Faces must have ≥ 3 distinct in-range vertices.
pub fn split(positions: &[glam::DVec3], face_start: &[u32], face_verts: &[u32]) -> Option<Split> {
    let nf = face_start.len().checked_sub(1)?;
    let nv = positions.len();
    let nh = face_verts.len();
    // Half-edge h (corner h of its face) runs from face_verts[h] to the next corner's vertex.
    let mut next = vec![0u32; nh];
    let mut prev = vec![0u32; nh];
    for f in 0..nf {
        let (s, e) = (face_start[f] as usize, face_start[f + 1] as usize);
        if e < s + 3 || face_verts[s..e].iter().any(|&v| v as usize >= nv) {
            return None;
        }
        for h in s..e {
            next[h] = if h + 1 == e { s as u32 } else { h as u32 + 1 };
            prev[h] = if h == s { (e - 1) as u32 } else { h as u32 - 1 };
        }
    }
    let to = |h: u32| face_verts[next[h as usize] as usize];
    // Group half-edges by undirected edge.
    let mut keys: Vec<(u32, u32, u32)> = (0..nh as u32)
        .map(|h| {
            let (a, b) = (face_verts[h as usize], to(h));
            (a.min(b), a.max(b), h)
        })
        .collect();
    keys.sort_unstable();
    // Per half-edge: its twin across a manifold edge (two opposite uses), or NONE; and
    // whether its edge is non-manifold (three or more uses). Per vertex, for OpenSubdiv's
    // rule (counted on the input mesh): its distinct edges, and the boundary and the
    // non-manifold ones among them.
    const NONE: u32 = u32::MAX;
    let mut twin = vec![NONE; nh];
    let mut nonman = vec![false; nh];
    let mut edges = 0;
    let mut edge_count = vec![0u32; nv];
    let mut boundary_edges = vec![0u32; nv];
    let mut nm_edges = vec![0u32; nv];
    for g in keys.chunk_by(|a, b| (a.0, a.1) == (b.0, b.1)) {
        if g.len() == 2 && face_verts[g[0].2 as usize] != face_verts[g[1].2 as usize] {
            twin[g[0].2 as usize] = g[1].2;
            twin[g[1].2 as usize] = g[0].2;
        } else if g.len() >= 3 {
            edges += 1;
            for k in g {
                nonman[k.2 as usize] = true;
            }
        }
        for v in [g[0].0 as usize, g[0].1 as usize] {
            edge_count[v] += 1;
            match g.len() {
                1 => boundary_edges[v] += 1,
                n if n >= 3 => nm_edges[v] += 1,
                _ => {}
            }
        }
    }
    // Sectors: corners (half-edges by their start vertex) joined across manifold edges. At
    // corner h (vertex v), the edges at v are h (v → next) and prev(h) (prev → v); across h
    // the twin t starts at next's vertex, and its next corner is at v again.
    let mut sets = Sets::new(nh);
    for h in 0..nh as u32 {
        let t = twin[h as usize];
        if t != NONE {
            sets.union(h, next[t as usize]);
        }
    }
    // Corners of each vertex, and the sectors among them.
    let mut sectors = vec![0u32; nv];
    let mut corners_of = vec![0u32; nv];
    let mut nm_vertex = vec![false; nv];
    for h in 0..nh as u32 {
        let v = face_verts[h as usize] as usize;
        corners_of[v] += 1;
        if nonman[h as usize] || nonman[prev[h as usize] as usize] {
            nm_vertex[v] = true;
        }
    }
    // Roots are each set's first corner, so a sector's root is met first in corner order.
    let mut sector_vertex = vec![NONE; nh];
    let mut out_positions = positions.to_vec();
    let mut origin: Vec<u32> = (0..nv as u32).collect();
    let mut out_verts = face_verts.to_vec();
    for h in 0..nh as u32 {
        let v = face_verts[h as usize];
        let r = sets.find(h);
        if sector_vertex[r as usize] == NONE {
            sectors[v as usize] += 1;
            // The first sector keeps the vertex; each further one gets a copy.
            sector_vertex[r as usize] = if sectors[v as usize] == 1 {
                v
            } else {
                out_positions.push(positions[v as usize]);
                origin.push(v);
                (out_positions.len() - 1) as u32
            };
        }
        out_verts[h as usize] = sector_vertex[r as usize];
    }
    for v in 0..nv {
        if sectors[v] > 1 {
            nm_vertex[v] = true;
        }
    }
    let vertices = nm_vertex.iter().filter(|&&b| b).count();
    if edges == 0 && vertices == 0 {
        return None;
    }
    // Corners: every copy of a non-manifold vertex that is not on an interior crease.
    let corner: Vec<bool> = (0..nv)
        .map(|v| {
            let crease =
                nm_edges[v] == 2 && boundary_edges[v] == 0 && corners_of[v] > edge_count[v];
            nm_vertex[v] && !crease
        })
        .collect();
    let corners: Vec<u32> = (0..origin.len() as u32)
        .filter(|&c| corner[origin[c as usize] as usize])
        .collect();
    // Non-manifold edges whose uses still share both (new) endpoints.
    let mut meet: Vec<(u32, u32)> = (0..nh)
        .filter(|&h| nonman[h])
        .map(|h| {
            let (a, b) = (out_verts[h], out_verts[next[h] as usize]);
            (a.min(b), a.max(b))
        })
        .collect();
    meet.sort_unstable();
    let mut sharp_edges: Vec<(u32, u32)> = meet
        .windows(2)
        .filter(|w| w[0] == w[1])
        .map(|w| w[0])
        .collect();
    sharp_edges.dedup();
    Some(Split {
        positions: out_positions,
        face_verts: out_verts,
        origin,
        corners,
        sharp_edges,
        edges,
        vertices,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::DVec3;

    fn faces(fs: &[&[u32]]) -> (Vec<u32>, Vec<u32>) {
        let mut start = vec![0u32];
        let mut verts = Vec::new();
        for f in fs {
            verts.extend_from_slice(f);
            start.push(verts.len() as u32);
        }
        (start, verts)
    }

    #[test]
    fn manifold_meshes_are_left_alone() {
        let pos = vec![DVec3::ZERO; 6];
        let (s, v) = faces(&[&[0, 1, 4, 3], &[1, 2, 5, 4]]);
        assert!(split(&pos, &s, &v).is_none());
    }

    #[test]
    fn a_bowtie_vertex_gets_a_sharp_copy_per_fan() {
        // Two triangles touching at vertex 0 only.
        let pos = vec![DVec3::ZERO; 5];
        let (s, v) = faces(&[&[0, 1, 2], &[0, 3, 4]]);
        let sp = split(&pos, &s, &v).unwrap();
        assert_eq!(sp.face_verts, vec![0, 1, 2, 5, 3, 4]);
        assert_eq!(sp.origin, vec![0, 1, 2, 3, 4, 0]);
        assert_eq!((sp.vertices, sp.edges), (1, 0));
        // On a boundary: a corner, both copies.
        assert_eq!(sp.corners, vec![0, 5]);
        assert!(sp.sharp_edges.is_empty());
    }

    #[test]
    fn three_fins_on_an_edge_are_cut_apart() {
        // Three triangles on edge (0, 1), each with a boundary elsewhere.
        let pos = vec![DVec3::ZERO; 5];
        let (s, v) = faces(&[&[0, 1, 2], &[1, 0, 3], &[0, 1, 4]]);
        let sp = split(&pos, &s, &v).unwrap();
        assert_eq!(sp.edges, 1);
        assert_eq!(sp.vertices, 2);
        // Three sectors at 0 and at 1: two copies each.
        assert_eq!(sp.positions.len(), 5 + 4);
        // The three uses of (0, 1) now join different vertex pairs.
        let pairs: std::collections::HashSet<(u32, u32)> = (0..3)
            .map(|f| {
                let (a, b) = (sp.face_verts[3 * f], sp.face_verts[3 * f + 1]);
                (a.min(b), a.max(b))
            })
            .collect();
        assert_eq!(pairs.len(), 3);
        // Vertices 0 and 1 have boundary edges here (the fins' other edges): corners.
        assert_eq!(sp.corners.len(), 6);
    }
}
