//! Half-edge topology of a polygon mesh.
//!
//! Half-edge `h` is corner `h - face_start[f]` of face `f`: it leaves that corner's vertex
//! and runs to the next vertex of the face. `next`/`prev` stay inside the face; `twin` is the
//! opposite half-edge of the neighbouring face, absent on a boundary. Rotating
//! `h -> twin(prev(h))` walks the outgoing half-edges of a vertex counter-clockwise (seen
//! from the side the faces' normals point to).

use crate::crease::{Rule, Sharpness};
use crate::error::{MeshError, MeshProblem};
use crate::ids::{FaceId, VertexId};
use crate::pool;
use glam::DVec3;

/// Marks an absent half-edge (boundary twin, unused vertex).
pub const NONE: u32 = u32::MAX;

/// Largest valence accepted in input meshes. Cylinder caps triangulated as fans have poles
/// of valence 100–1000; OpenSubdiv takes them, and so do we: limit positions and normals
/// at a valence-360 pole match OpenSubdiv's to 4e-13 (`tests/opensubdiv_creases.rs`), and
/// every method synthesizes a valence-1000 cone (docs/subdivision.md). The cap keeps the
/// per-vertex work (masks, charts, patch trees of O(valence) faces) bounded on absurd input.
pub const MAX_VALENCE: usize = 1024;

/// A polygon mesh with positions and half-edge connectivity.
#[derive(Clone, Debug)]
pub struct PolyMesh {
    pub positions: Vec<DVec3>,
    face_start: Vec<u32>,
    /// Origin vertex of every half-edge.
    he_vert: Vec<u32>,
    he_face: Vec<u32>,
    he_twin: Vec<u32>,
    /// Edge index of every half-edge; edges are numbered in order of first appearance.
    he_edge: Vec<u32>,
    /// First half-edge of every edge.
    edge_he: Vec<u32>,
    /// An outgoing half-edge per vertex: for a boundary vertex the clockwise-most one (its
    /// twin is absent), so that a counter-clockwise walk visits the whole fan.
    vert_out: Vec<u32>,
    vert_faces: Vec<u32>,
    vert_boundary: Vec<bool>,
    /// Tagged sharpness per edge (OpenSubdiv's `t crease`), or empty when no edge has any:
    /// the smooth case, which every caller can then skip cheaply.
    edge_sharp: Vec<Sharpness>,
    /// Tagged sharpness per vertex (`t corner`), or empty when no vertex has any.
    vert_sharp: Vec<Sharpness>,
    /// Every face has three or more distinct vertices, and the half-edges joining any two
    /// vertices are one, or two opposite ones that are twins: then the twins of a submesh
    /// or a refinement follow from these ([`Self::from_twins`]) instead of a search.
    clean: bool,
}

/// How strictly to check a mesh when building its topology.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Check {
    /// Input meshes: every manifold condition is checked and reported.
    Strict,
    /// Meshes made by this crate (refined levels, local submeshes cut out of a larger mesh,
    /// whose cut may leave vertices with several fans that are never evaluated).
    Trusted,
}

impl PolyMesh {
    /// Builds topology for faces given as vertex-index lists (`face_start` has F+1 entries).
    pub fn new(
        positions: Vec<DVec3>,
        face_start: Vec<u32>,
        face_verts: Vec<u32>,
        check: Check,
    ) -> Result<Self, MeshError> {
        let nf = face_start.len() - 1;
        let nv = positions.len();
        let nh = face_verts.len();
        if check == Check::Strict {
            if nf == 0 {
                return Err(MeshProblem::NoFaces.into());
            }
            for (i, p) in positions.iter().enumerate() {
                if !p.is_finite() {
                    return Err(MeshProblem::NonFiniteCoordinate { vertex: i }.into());
                }
            }
            for f in 0..nf {
                let vs = &face_verts[face_start[f] as usize..face_start[f + 1] as usize];
                if vs.len() < 3 {
                    return Err(MeshProblem::TooFewVertices {
                        face: f,
                        count: vs.len(),
                    }
                    .into());
                }
                for (i, &v) in vs.iter().enumerate() {
                    if v as usize >= nv {
                        return Err(MeshProblem::IndexOutOfRange {
                            face: f,
                            vertex: v as usize,
                            count: nv,
                        }
                        .into());
                    }
                    if vs[..i].contains(&v) {
                        return Err(MeshProblem::RepeatedVertex {
                            face: f,
                            vertex: v as usize,
                        }
                        .into());
                    }
                }
            }
        }
        let mut he_face = vec![0u32; nh];
        for f in 0..nf {
            for h in face_start[f]..face_start[f + 1] {
                he_face[h as usize] = f as u32;
            }
        }
        let mut m = PolyMesh {
            positions,
            face_start,
            he_vert: face_verts,
            he_face,
            he_twin: vec![NONE; nh],
            he_edge: vec![NONE; nh],
            edge_he: Vec::with_capacity(nh / 2 + 8),
            vert_out: vec![NONE; nv],
            vert_faces: vec![0; nv],
            vert_boundary: vec![false; nv],
            edge_sharp: Vec::new(),
            vert_sharp: Vec::new(),
            clean: false,
        };
        let faces_simple = (0..nf).all(|f| {
            let vs = &m.he_vert[m.face_start[f] as usize..m.face_start[f + 1] as usize];
            vs.len() >= 3 && (1..vs.len()).all(|i| !vs[..i].contains(&vs[i]))
        });
        m.clean = m.link_twins(check)? && faces_simple;
        m.build_vertex_fans(check)?;
        Ok(m)
    }

    /// [`Self::new`] for faces whose half-edges' twins the caller knows (`he_twin`, [`NONE`]
    /// where absent), derived from a [clean](Self::is_clean) mesh's: the faces of a submesh
    /// (twins kept where both faces are kept) or of a refinement. Gives exactly what `new`
    /// with [`Check::Trusted`] gives for the same faces, without pairing half-edges by their
    /// vertices: edges are numbered by their first half-edge, as there.
    pub(crate) fn from_twins(
        positions: Vec<DVec3>,
        face_start: Vec<u32>,
        face_verts: Vec<u32>,
        he_twin: Vec<u32>,
    ) -> Self {
        let nf = face_start.len() - 1;
        let nv = positions.len();
        let nh = face_verts.len();
        debug_assert_eq!(he_twin.len(), nh);
        let mut he_face = pool::ints(nh);
        for f in 0..nf {
            let n = (face_start[f + 1] - face_start[f]) as usize;
            he_face.extend(std::iter::repeat_n(f as u32, n));
        }
        let (he_edge, edge_he) = Self::number_edges(&he_twin);
        let mut m = PolyMesh {
            positions,
            face_start,
            he_vert: face_verts,
            he_face,
            he_twin,
            he_edge,
            edge_he,
            vert_out: pool::ints_filled(nv, NONE),
            vert_faces: pool::ints_filled(nv, 0),
            vert_boundary: {
                let mut b = pool::flags(nv);
                b.resize(nv, false);
                b
            },
            edge_sharp: Vec::new(),
            vert_sharp: Vec::new(),
            clean: true,
        };
        m.build_vertex_fans(Check::Trusted)
            .expect("trusted meshes are not checked");
        m
    }

    /// The topology of this clean mesh's Catmull-Clark refinement (faces as
    /// [`crate::refine::refine`] numbers them: child face h of parent half-edge h, vertex
    /// points, then face points, then edge points), derived from this mesh's instead of
    /// searched: exactly what [`Self::new`] with [`Check::Trusted`] gives for those faces.
    ///
    /// Child face h (half-edge h at corner c of face f) has half-edges 4h + k: k = 0 from
    /// the vertex point of origin(h) to the edge point of h, 1 on to the face point, 2 on
    /// to the edge point of prev(h), 3 back. Those inside f pair with the neighbouring
    /// corners' (1 with 2 of next(h)); those along a parent edge with the children of its
    /// twin t: 0 with 3 of next(t), 3 with 0 of twin(prev(h)).
    pub(crate) fn refined_topology(
        &self,
        positions: Vec<DVec3>,
        face_start: Vec<u32>,
        face_verts: Vec<u32>,
    ) -> Self {
        debug_assert!(self.clean);
        let (nv, nf, nh) = (self.num_vertices(), self.num_faces(), self.num_half_edges());
        let twin = |h: u32| self.he_twin[h as usize];
        let mut he_twin = pool::ints(4 * nh);
        for h in 0..nh as u32 {
            let (hn, hp) = (self.next(h), self.prev(h));
            let (t, tp) = (twin(h), twin(hp));
            he_twin.extend([
                if t == NONE {
                    NONE
                } else {
                    4 * self.next(t) + 3
                },
                4 * hn + 2,
                4 * hp + 1,
                if tp == NONE { NONE } else { 4 * tp },
            ]);
        }
        let mut he_face = pool::ints(4 * nh);
        he_face.extend((0..4 * nh as u32).map(|h| h / 4));
        let (he_edge, edge_he) = Self::number_edges(&he_twin);
        // Fans: a vertex point's mirrors its vertex's (outgoing half-edge 4h for h, same
        // order, same twins); a face point's is its face's corners; an edge point's is the
        // four (two at a boundary) child faces at the edge's half-edges.
        let cv = positions.len();
        debug_assert_eq!(cv, nv + nf + self.num_edges());
        let mut vert_out = pool::ints(cv);
        let mut vert_faces = pool::ints(cv);
        let mut vert_boundary = pool::flags(cv);
        vert_out.extend(
            self.vert_out
                .iter()
                .map(|&h| if h == NONE { NONE } else { 4 * h }),
        );
        vert_faces.extend_from_slice(&self.vert_faces);
        vert_boundary.extend_from_slice(&self.vert_boundary);
        for f in 0..nf {
            vert_out.push(4 * self.face_start[f] + 2);
            vert_faces.push(self.face_start[f + 1] - self.face_start[f]);
            vert_boundary.push(false);
        }
        for &g in &self.edge_he {
            let t = twin(g);
            if t == NONE {
                vert_out.push(4 * self.next(g) + 3);
                vert_faces.push(2);
                vert_boundary.push(true);
            } else {
                let first = (4 * g + 1)
                    .min(4 * self.next(g) + 3)
                    .min(4 * t + 1)
                    .min(4 * self.next(t) + 3);
                vert_out.push(first);
                vert_faces.push(4);
                vert_boundary.push(false);
            }
        }
        PolyMesh {
            positions,
            face_start,
            he_vert: face_verts,
            he_face,
            he_twin,
            he_edge,
            edge_he,
            vert_out,
            vert_faces,
            vert_boundary,
            edge_sharp: Vec::new(),
            vert_sharp: Vec::new(),
            clean: true,
        }
    }

    /// Edge numbers from twins, as [`Self::link_twins`] numbers them: in order of each
    /// edge's first half-edge (`he_edge`, `edge_he`).
    fn number_edges(he_twin: &[u32]) -> (Vec<u32>, Vec<u32>) {
        // Without branches (whether a twin comes later is a coin flip): half-edge h starts
        // an edge when its twin is later or absent (NONE is larger than any h); otherwise
        // it takes its twin's edge. Every slot of `edge_he` up to the count is written.
        let nh = he_twin.len();
        let mut he_edge = pool::ints_filled(nh, 0);
        let mut edge_he = pool::ints_filled(nh, 0);
        let mut count = 0u32;
        for (h, &t) in he_twin.iter().enumerate() {
            let first = t as usize > h;
            let earlier = he_edge[(t as usize).min(h)];
            he_edge[h] = if first { count } else { earlier };
            edge_he[count as usize] = h as u32;
            count += first as u32;
        }
        edge_he.truncate(count as usize);
        (he_edge, edge_he)
    }

    /// Gives this mesh's buffers to the per-thread pool the next small meshes are built
    /// from ([`crate::pool`]); for the many short-lived meshes of the patch trees.
    pub(crate) fn recycle(self) {
        pool::give_points(self.positions);
        for v in [
            self.face_start,
            self.he_vert,
            self.he_face,
            self.he_twin,
            self.he_edge,
            self.edge_he,
            self.vert_out,
            self.vert_faces,
        ] {
            pool::give_ints(v);
        }
        pool::give_flags(self.vert_boundary);
    }

    /// Whether the mesh is clean (see the field): always for meshes that pass
    /// [`Check::Strict`], and their refinements and submeshes.
    #[inline]
    pub fn is_clean(&self) -> bool {
        self.clean
    }

    /// Pairs twins and numbers edges; whether every group of half-edges joining two
    /// vertices is one half-edge or a pair of twins.
    fn link_twins(&mut self, check: Check) -> Result<bool, MeshError> {
        // Pair half-edges by sorting (min vertex, max vertex, half-edge): cheaper than a hash
        // map for the many tiny submeshes of the patch trees, and within one edge the
        // half-edges stay in input order, so errors name the same faces either way.
        // (Indices are validated before this in strict mode.)
        let nh = self.he_vert.len();
        let nv = self.positions.len();
        // Counting sort by the smaller vertex (buckets are valence-sized), then a small
        // insertion sort by (larger vertex, half-edge) inside each bucket: linear overall.
        let mut start = vec![0u32; nv + 1];
        for h in 0..nh as u32 {
            let a = self.he_vert[h as usize];
            let b = self.dest_raw(h);
            start[a.min(b) as usize + 1] += 1;
        }
        for i in 0..nv {
            start[i + 1] += start[i];
        }
        let mut fill = start.clone();
        let mut keys: Vec<(u32, u32, u32)> = vec![(0, 0, 0); nh];
        for h in 0..nh as u32 {
            let a = self.he_vert[h as usize];
            let b = self.dest_raw(h);
            let lo = a.min(b) as usize;
            keys[fill[lo] as usize] = (lo as u32, a.max(b), h);
            fill[lo] += 1;
        }
        for v in 0..nv {
            let bucket = &mut keys[start[v] as usize..start[v + 1] as usize];
            for i in 1..bucket.len() {
                let mut j = i;
                while j > 0 && (bucket[j - 1].1, bucket[j - 1].2) > (bucket[j].1, bucket[j].2) {
                    bucket.swap(j - 1, j);
                    j -= 1;
                }
            }
        }
        // Edges are numbered in order of their first half-edge, as a scan would meet them.
        let mut first_of_edge: Vec<u32> = Vec::with_capacity(nh / 2 + 8);
        let strict = check == Check::Strict;
        let mut clean = true;
        let mut i = 0;
        while i < keys.len() {
            let mut j = i + 1;
            while j < keys.len() && keys[j].0 == keys[i].0 && keys[j].1 == keys[i].1 {
                j += 1;
            }
            let group = &keys[i..j];
            let g = group[0].2;
            first_of_edge.push(g);
            if group.len() >= 2 {
                let h = group[1].2;
                clean &= group.len() == 2;
                if group.len() > 2 && strict {
                    return Err(MeshProblem::NonManifoldEdge {
                        a: group[0].0 as usize,
                        b: group[0].1 as usize,
                        face: self.he_face[group[2].2 as usize] as usize,
                    }
                    .into());
                }
                if self.he_vert[g as usize] == self.he_vert[h as usize] {
                    clean = false;
                    if strict {
                        return Err(MeshProblem::InconsistentOrientation {
                            a: self.he_vert[g as usize] as usize,
                            b: self.dest_raw(g) as usize,
                            face_a: self.he_face[g as usize] as usize,
                            face_b: self.he_face[h as usize] as usize,
                        }
                        .into());
                    }
                } else {
                    self.he_twin[g as usize] = h;
                    self.he_twin[h as usize] = g;
                }
            }
            i = j;
        }
        // Number edges by their first half-edge in input order (a scan, not a sort).
        let mut is_first = vec![false; nh];
        for &g in &first_of_edge {
            is_first[g as usize] = true;
        }
        self.edge_he = Vec::with_capacity(first_of_edge.len());
        for (h, &first) in is_first.iter().enumerate() {
            if first {
                self.he_edge[h] = self.edge_he.len() as u32;
                self.edge_he.push(h as u32);
            }
        }
        for h in 0..nh {
            if self.he_edge[h] == NONE {
                let t = self.he_twin[h];
                // Unpaired extra half-edges (only in trusted, never-evaluated regions) keep
                // the edge of their group's first half-edge.
                self.he_edge[h] = if t != NONE {
                    self.he_edge[t as usize]
                } else {
                    NONE
                };
            }
        }
        if self.he_edge.contains(&NONE) {
            // Extra half-edges of a non-manifold group in a trusted mesh: give them edges.
            for h in 0..nh {
                if self.he_edge[h] == NONE {
                    self.he_edge[h] = self.edge_he.len() as u32;
                    self.edge_he.push(h as u32);
                }
            }
        }
        Ok(clean)
    }

    fn build_vertex_fans(&mut self, check: Check) -> Result<(), MeshError> {
        let nh = self.he_vert.len();
        let nv = self.positions.len();
        let mut corners = pool::ints_filled(nv, 0);
        for h in 0..nh {
            let v = self.he_vert[h] as usize;
            corners[v] += 1;
            // Prefer a half-edge with no twin: it starts the fan of a boundary vertex.
            if self.vert_out[v] == NONE || self.he_twin[h] == NONE {
                self.vert_out[v] = h as u32;
            }
        }
        for (v, &corner_count) in corners.iter().enumerate() {
            let start = self.vert_out[v];
            if start == NONE {
                continue;
            }
            let boundary = self.he_twin[start as usize] == NONE;
            let mut count = 0u32;
            let mut h = start;
            loop {
                count += 1;
                let p = self.prev(h);
                let t = self.he_twin[p as usize];
                if t == NONE || t == start || count > corner_count {
                    break;
                }
                h = t;
            }
            self.vert_faces[v] = count;
            self.vert_boundary[v] = boundary;
            if check == Check::Strict {
                if count != corner_count {
                    // The faces at v do not form one fan: count the fans for the message.
                    let fans = self.count_fans(v as u32);
                    return Err(MeshProblem::NonManifoldVertex { vertex: v, fans }.into());
                }
                let valence = count as usize + boundary as usize;
                if valence > MAX_VALENCE {
                    return Err(MeshProblem::ValenceTooHigh {
                        vertex: v,
                        valence,
                        max: MAX_VALENCE,
                    }
                    .into());
                }
            }
        }
        pool::give_ints(corners);
        Ok(())
    }

    fn count_fans(&self, v: u32) -> usize {
        let outgoing: Vec<u32> = (0..self.he_vert.len() as u32)
            .filter(|&h| self.he_vert[h as usize] == v)
            .collect();
        let mut seen = vec![false; outgoing.len()];
        let mut fans = 0;
        for i in 0..outgoing.len() {
            if seen[i] {
                continue;
            }
            fans += 1;
            // Flood the fan both ways.
            let mut stack = vec![outgoing[i]];
            while let Some(h) = stack.pop() {
                let Some(k) = outgoing.iter().position(|&g| g == h) else {
                    continue;
                };
                if seen[k] {
                    continue;
                }
                seen[k] = true;
                let t = self.he_twin[self.prev(h) as usize];
                if t != NONE {
                    stack.push(t);
                }
                let t = self.he_twin[h as usize];
                if t != NONE {
                    stack.push(self.next(t));
                }
            }
        }
        fans.max(2)
    }

    #[inline]
    fn dest_raw(&self, h: u32) -> u32 {
        self.he_vert[self.next(h) as usize]
    }

    pub fn num_faces(&self) -> usize {
        self.face_start.len() - 1
    }
    pub fn num_vertices(&self) -> usize {
        self.positions.len()
    }
    pub fn num_edges(&self) -> usize {
        self.edge_he.len()
    }
    pub fn num_half_edges(&self) -> usize {
        self.he_vert.len()
    }

    /// Number of vertices of face `f`.
    #[inline]
    pub fn face_size(&self, f: FaceId) -> usize {
        (self.face_start[f.idx() + 1] - self.face_start[f.idx()]) as usize
    }
    /// First half-edge of face `f` (the one leaving its first vertex).
    #[inline]
    pub fn face_he(&self, f: FaceId) -> u32 {
        self.face_start[f.idx()]
    }
    /// The vertices of face `f`, in order.
    #[inline]
    pub fn face_vertices(&self, f: FaceId) -> &[u32] {
        &self.he_vert[self.face_start[f.idx()] as usize..self.face_start[f.idx() + 1] as usize]
    }
    #[inline]
    pub fn face_of(&self, h: u32) -> FaceId {
        FaceId(self.he_face[h as usize])
    }
    #[inline]
    pub fn next(&self, h: u32) -> u32 {
        let f = self.he_face[h as usize] as usize;
        if h + 1 == self.face_start[f + 1] {
            self.face_start[f]
        } else {
            h + 1
        }
    }
    #[inline]
    pub fn prev(&self, h: u32) -> u32 {
        let f = self.he_face[h as usize] as usize;
        if h == self.face_start[f] {
            self.face_start[f + 1] - 1
        } else {
            h - 1
        }
    }
    /// The opposite half-edge, or `None` on a boundary.
    #[inline]
    pub fn twin(&self, h: u32) -> Option<u32> {
        let t = self.he_twin[h as usize];
        (t != NONE).then_some(t)
    }
    #[inline]
    pub fn origin(&self, h: u32) -> VertexId {
        VertexId(self.he_vert[h as usize])
    }
    #[inline]
    pub fn dest(&self, h: u32) -> VertexId {
        VertexId(self.dest_raw(h))
    }
    #[inline]
    pub fn edge_of(&self, h: u32) -> usize {
        self.he_edge[h as usize] as usize
    }
    /// A half-edge of edge `e` (either direction).
    #[inline]
    pub fn edge_half_edge(&self, e: usize) -> u32 {
        self.edge_he[e]
    }
    #[inline]
    pub fn pos(&self, v: VertexId) -> DVec3 {
        self.positions[v.idx()]
    }
    /// Number of faces around `v` (its fan).
    #[inline]
    pub fn vertex_faces(&self, v: VertexId) -> usize {
        self.vert_faces[v.idx()] as usize
    }
    #[inline]
    pub fn is_boundary_vertex(&self, v: VertexId) -> bool {
        self.vert_boundary[v.idx()]
    }
    /// The first outgoing half-edge of `v` (clockwise-most for boundary vertices).
    #[inline]
    pub fn vertex_out(&self, v: VertexId) -> Option<u32> {
        let h = self.vert_out[v.idx()];
        (h != NONE).then_some(h)
    }
    /// Outgoing half-edges of `v`, counter-clockwise, starting at [`Self::vertex_out`].
    pub fn outgoing(&self, v: VertexId) -> Outgoing<'_> {
        Outgoing {
            mesh: self,
            start: self.vert_out[v.idx()],
            cur: self.vert_out[v.idx()],
            left: self.vert_faces[v.idx()],
        }
    }
    /// Number of edges at `v`.
    #[inline]
    pub fn valence(&self, v: VertexId) -> usize {
        self.vertex_faces(v) + self.is_boundary_vertex(v) as usize
    }
    /// A vertex where a Catmull-Clark patch is a regular bicubic B-spline: interior with 4
    /// faces, boundary with 2 faces, or a corner with 1 face (EDGE_AND_CORNER rules).
    #[inline]
    pub fn is_regular_vertex(&self, v: VertexId) -> bool {
        let n = self.vertex_faces(v);
        if self.is_boundary_vertex(v) {
            n == 1 || n == 2
        } else {
            n == 4
        }
    }
    /// Whether all faces are quads.
    pub fn all_quads(&self) -> bool {
        self.face_start.windows(2).all(|w| w[1] - w[0] == 4)
    }
    pub fn face_starts(&self) -> &[u32] {
        &self.face_start
    }
    pub fn half_edge_vertices(&self) -> &[u32] {
        &self.he_vert
    }

    // --- Sharpness (see `crate::crease`) ---

    /// Whether any edge or vertex carries a tagged sharpness (boundaries do not count: their
    /// sharpness is implied by the topology).
    #[inline]
    pub fn has_tags(&self) -> bool {
        !self.edge_sharp.is_empty() || !self.vert_sharp.is_empty()
    }

    /// Sets the tagged sharpness of every edge and vertex (`edges` by edge index, `verts`
    /// by vertex; either may be empty for "all smooth"). All-smooth lists are stored empty,
    /// so a mesh tagged with zeros is exactly the untagged mesh.
    pub fn set_sharpness(&mut self, edges: Vec<Sharpness>, verts: Vec<Sharpness>) {
        debug_assert!(edges.is_empty() || edges.len() == self.num_edges());
        debug_assert!(verts.is_empty() || verts.len() == self.num_vertices());
        let any = |v: &[Sharpness]| v.iter().any(|s| s.is_sharp());
        self.edge_sharp = if any(&edges) { edges } else { Vec::new() };
        self.vert_sharp = if any(&verts) { verts } else { Vec::new() };
    }

    /// The tagged sharpness of edge `e` (smooth if untagged; boundaries not included).
    #[inline]
    pub fn tagged_edge_sharpness(&self, e: usize) -> Sharpness {
        self.edge_sharp.get(e).copied().unwrap_or(Sharpness::SMOOTH)
    }

    /// The tagged sharpness of vertex `v` (smooth if untagged; corners not included).
    #[inline]
    pub fn tagged_vertex_sharpness(&self, v: VertexId) -> Sharpness {
        self.vert_sharp
            .get(v.idx())
            .copied()
            .unwrap_or(Sharpness::SMOOTH)
    }

    /// Sharpness of the edge of half-edge `h`: infinite on a boundary (EDGE_AND_CORNER),
    /// else as tagged.
    #[inline]
    pub fn edge_sharpness(&self, h: u32) -> Sharpness {
        if self.he_twin[h as usize] == NONE {
            Sharpness::INFINITE
        } else {
            self.tagged_edge_sharpness(self.edge_of(h))
        }
    }

    /// Sharpness of vertex `v`: infinite at a boundary vertex with one face (a corner, kept
    /// fixed by EDGE_AND_CORNER), else as tagged.
    #[inline]
    pub fn vertex_sharpness(&self, v: VertexId) -> Sharpness {
        if self.vert_boundary[v.idx()] && self.vert_faces[v.idx()] == 1 {
            Sharpness::INFINITE
        } else {
            self.tagged_vertex_sharpness(v)
        }
    }

    /// The edges at `v` counter-clockwise, as half-edges whose edge it is, each with the
    /// vertex at its other end: the outgoing half-edges, then (at a boundary vertex) the
    /// incoming boundary half-edge that closes the fan.
    pub fn vertex_edges(&self, v: VertexId) -> impl Iterator<Item = (u32, VertexId)> + '_ {
        let closing = if self.is_boundary_vertex(v) {
            self.outgoing(v).last().map(|h| {
                let p = self.prev(h);
                (p, self.origin(p))
            })
        } else {
            None
        };
        self.outgoing(v).map(|h| (h, self.dest(h))).chain(closing)
    }

    /// The subdivision rule of vertex `v` (`Rule::of` its sharpness and its sharp edges).
    pub fn vertex_rule(&self, v: VertexId) -> Rule {
        if !self.has_tags() {
            return self.untagged_rule(v);
        }
        let sharp = self
            .vertex_edges(v)
            .filter(|&(h, _)| self.edge_sharpness(h).is_sharp())
            .count();
        Rule::of(self.vertex_sharpness(v), sharp)
    }

    /// [`Self::vertex_rule`] without tags: smooth inside, crease along a boundary, corner
    /// at a boundary vertex with one face.
    #[inline]
    fn untagged_rule(&self, v: VertexId) -> Rule {
        match (self.vert_boundary[v.idx()], self.vert_faces[v.idx()]) {
            (false, _) => Rule::Smooth,
            (true, 1) => Rule::Corner,
            (true, _) => Rule::Crease,
        }
    }

    /// Whether a semi-sharp value sits at `v` (its own or an incident edge's): its
    /// neighbourhood still changes rules with refinement, so neither a regular patch nor a
    /// limit mask describes the surface there yet.
    pub fn has_semi_sharp_at(&self, v: VertexId) -> bool {
        if !self.has_tags() {
            return false;
        }
        self.vertex_sharpness(v).is_semi_sharp()
            || self
                .vertex_edges(v)
                .any(|(h, _)| self.edge_sharpness(h).is_semi_sharp())
    }

    /// The opposite half-edge on the same side of every infinitely sharp edge: `None` on a
    /// boundary and across an infinitely sharp crease, where the limit surface on either
    /// side is the one of a mesh cut open there.
    #[inline]
    pub fn smooth_twin(&self, h: u32) -> Option<u32> {
        let t = self.twin(h)?;
        (self.edge_sharp.is_empty() || !self.tagged_edge_sharpness(self.edge_of(h)).is_infinite())
            .then_some(t)
    }

    /// The *sector* of the face of `h` at its origin v: the faces around v reached from it
    /// without crossing an infinitely sharp edge or a boundary. On either side of such an
    /// edge the limit surface is the one of the mesh cut open there, so a sector is what
    /// a boundary vertex's fan is without tags.
    pub fn sector(&self, h: u32) -> Sector {
        let v = self.origin(h);
        let total = self.vertex_faces(v);
        // Clockwise (h -> next(twin(h)), across edge h) to the first sharp edge.
        let mut first = h;
        for _ in 0..total {
            let Some(t) = self.smooth_twin(first) else {
                break;
            };
            let cw = self.next(t);
            if cw == h {
                return Sector {
                    first: self.vertex_out(v).unwrap_or(h),
                    faces: total,
                    closed: true,
                };
            }
            first = cw;
        }
        // Counter-clockwise (h -> twin(prev(h))) to the next one.
        let (mut faces, mut cur) = (1, first);
        while faces < total {
            let Some(t) = self.smooth_twin(self.prev(cur)) else {
                break;
            };
            cur = t;
            faces += 1;
        }
        Sector {
            first,
            faces,
            closed: false,
        }
    }

    /// Whether the corner of the face of `h` at its origin is one where a regular bicubic
    /// B-spline patch is exact (with [`BSplinePatch::gather`](crate::patch::BSplinePatch)'s
    /// ghost points across sharp edges): no semi-sharp value at the vertex, and on the
    /// face's side of every infinitely sharp edge the configuration of a regular interior
    /// (smooth, 4 faces), boundary (crease rule, 2 faces in the sector) or corner (corner
    /// rule, 1 face) vertex. Without tags this is [`Self::is_regular_vertex`].
    pub fn corner_is_regular(&self, h: u32) -> bool {
        let v = self.origin(h);
        if !self.has_tags() {
            return self.is_regular_vertex(v);
        }
        if self.has_semi_sharp_at(v) {
            return false;
        }
        match self.vertex_rule(v) {
            Rule::Smooth => self.vertex_faces(v) == 4,
            Rule::Dart => false,
            Rule::Crease => self.sector(h).faces == 2,
            Rule::Corner => self.sector(h).faces == 1,
        }
    }

    /// Whether the limit normal at `v` is one vector: not where infinitely sharp edges
    /// split its faces into several sectors (a crease or corner of the surface), nor at an
    /// infinitely sharp vertex with two or more faces (a cone point).
    pub fn normal_is_unique(&self, v: VertexId) -> bool {
        if !self.has_tags() {
            return true;
        }
        let Some(h) = self.vertex_out(v) else {
            return true;
        };
        if self.vertex_sharpness(v).is_infinite() && self.vertex_faces(v) >= 2 {
            return false;
        }
        self.sector(h).faces == self.vertex_faces(v)
    }

    /// Copies the tags of `parent` onto this mesh, made of `parent`'s faces `faces` (face
    /// k here is `faces[k]` there, with the same corner order) and vertices
    /// `(parent vertex, vertex here)`. For the small meshes cut out of a larger one.
    pub(crate) fn inherit_tags(
        &mut self,
        parent: &PolyMesh,
        faces: &[FaceId],
        vertices: &[(u32, u32)],
    ) {
        if !parent.has_tags() {
            return;
        }
        let mut edges = Vec::new();
        if !parent.edge_sharp.is_empty() {
            edges = vec![Sharpness::SMOOTH; self.num_edges()];
            for (k, &f) in faces.iter().enumerate() {
                let (h, g) = (self.face_start[k], parent.face_he(f));
                for i in 0..self.face_size(FaceId::from_idx(k)) as u32 {
                    edges[self.edge_of(h + i)] =
                        parent.tagged_edge_sharpness(parent.edge_of(g + i));
                }
            }
        }
        let mut verts = Vec::new();
        if !parent.vert_sharp.is_empty() {
            verts = vec![Sharpness::SMOOTH; self.num_vertices()];
            for &(p, l) in vertices {
                verts[l as usize] = parent.tagged_vertex_sharpness(VertexId(p));
            }
        }
        self.set_sharpness(edges, verts);
    }

    /// Panics unless `other` has the same faces, positions, topology and tags (to test
    /// [`Self::from_twins`] against [`Self::new`]).
    #[cfg(test)]
    pub(crate) fn assert_same(&self, other: &PolyMesh) {
        assert_eq!(self.positions, other.positions);
        assert_eq!(self.face_start, other.face_start);
        assert_eq!(self.he_vert, other.he_vert);
        assert_eq!(self.he_face, other.he_face);
        assert_eq!(self.he_twin, other.he_twin);
        assert_eq!(self.he_edge, other.he_edge);
        assert_eq!(self.edge_he, other.edge_he);
        assert_eq!(self.vert_out, other.vert_out);
        assert_eq!(self.vert_faces, other.vert_faces);
        assert_eq!(self.vert_boundary, other.vert_boundary);
        assert_eq!(self.edge_sharp, other.edge_sharp);
        assert_eq!(self.vert_sharp, other.vert_sharp);
        assert_eq!(self.clean, other.clean);
    }

    /// The edge joining vertices `a` and `b`, as one of its half-edges.
    pub fn find_edge(&self, a: VertexId, b: VertexId) -> Option<u32> {
        if a.idx() >= self.num_vertices() || b.idx() >= self.num_vertices() {
            return None;
        }
        self.vertex_edges(a).find(|&(_, w)| w == b).map(|(h, _)| h)
    }
}

/// The faces around a vertex between two infinitely sharp edges ([`PolyMesh::sector`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Sector {
    /// The clockwise-most outgoing half-edge of the sector (its edge is the sector's
    /// leading sharp edge, unless `closed`).
    pub first: u32,
    /// Number of faces.
    pub faces: usize,
    /// No sharp edge bounds it: the whole fan of an interior vertex (then `first` is
    /// [`PolyMesh::vertex_out`]).
    pub closed: bool,
}

/// Iterator over the outgoing half-edges of a vertex, counter-clockwise.
pub struct Outgoing<'a> {
    mesh: &'a PolyMesh,
    start: u32,
    cur: u32,
    left: u32,
}

impl Iterator for Outgoing<'_> {
    type Item = u32;
    fn next(&mut self) -> Option<u32> {
        if self.left == 0 || self.cur == NONE {
            return None;
        }
        self.left -= 1;
        let h = self.cur;
        let t = self.mesh.he_twin[self.mesh.prev(h) as usize];
        self.cur = if t == self.start { NONE } else { t };
        Some(h)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn quad_grid(n: usize) -> PolyMesh {
        let mut pos = Vec::new();
        for y in 0..=n {
            for x in 0..=n {
                pos.push(DVec3::new(x as f64, y as f64, 0.0));
            }
        }
        let mut fs = vec![0u32];
        let mut fv = Vec::new();
        for y in 0..n {
            for x in 0..n {
                let i = (y * (n + 1) + x) as u32;
                let w = (n + 1) as u32;
                fv.extend([i, i + 1, i + 1 + w, i + w]);
                fs.push(fv.len() as u32);
            }
        }
        PolyMesh::new(pos, fs, fv, Check::Strict).unwrap()
    }

    #[test]
    fn clean_only_without_odd_edges_or_faces() {
        let m = quad_grid(2);
        assert!(m.is_clean());
        let pos = vec![DVec3::ZERO; 6];
        let mesh = |fv: Vec<u32>| {
            let mut fs = vec![0u32];
            fs.extend((1..=fv.len() / 3).map(|k| 3 * k as u32));
            PolyMesh::new(pos.clone(), fs, fv, Check::Trusted).unwrap()
        };
        assert!(mesh(vec![0, 1, 2, 2, 1, 3]).is_clean());
        // Inconsistent orientation, three faces on an edge, a repeated vertex.
        assert!(!mesh(vec![0, 1, 2, 1, 2, 3]).is_clean());
        assert!(!mesh(vec![0, 1, 2, 1, 0, 3, 0, 1, 4]).is_clean());
        assert!(!mesh(vec![0, 1, 1, 2, 1, 3]).is_clean());
    }

    /// A fan of `k` triangles round vertex 0 (a cone: the apex and a ring of `k` vertices).
    fn fan(k: usize) -> Result<PolyMesh, MeshError> {
        let mut pos = vec![DVec3::Z];
        let ring = |i: usize| 2.0 * std::f64::consts::PI * i as f64 / k as f64;
        pos.extend((0..k).map(|i| DVec3::new(ring(i).cos(), ring(i).sin(), 0.0)));
        let mut fs = vec![0u32];
        let mut fv = Vec::new();
        for i in 0..k {
            fv.extend([0, 1 + i as u32, 1 + ((i + 1) % k) as u32]);
            fs.push(fv.len() as u32);
        }
        PolyMesh::new(pos, fs, fv, Check::Strict)
    }

    #[test]
    fn valence_up_to_the_cap_is_accepted_and_above_it_named() {
        // A closed fan: the apex has k faces and k edges.
        let m = fan(MAX_VALENCE).unwrap();
        assert_eq!(m.vertex_faces(VertexId(0)), MAX_VALENCE);
        let e = fan(MAX_VALENCE + 1).unwrap_err().to_string();
        assert_eq!(
            e,
            format!(
                "<mesh>: vertex 1 has valence {}; at most {MAX_VALENCE} is supported",
                MAX_VALENCE + 1
            )
        );
    }

    #[test]
    fn grid_valences_and_boundary() {
        let m = quad_grid(3);
        // Centre vertex (1,1) is interior with 4 faces; corner (0,0) has 1 face.
        assert_eq!(m.vertex_faces(VertexId(5)), 4);
        assert!(!m.is_boundary_vertex(VertexId(5)));
        assert_eq!(m.vertex_faces(VertexId(0)), 1);
        assert!(m.is_boundary_vertex(VertexId(0)));
        assert_eq!(m.vertex_faces(VertexId(1)), 2);
        assert_eq!(m.num_edges(), 24);
        // The counter-clockwise walk visits every outgoing half-edge once.
        let outs: Vec<u32> = m.outgoing(VertexId(5)).collect();
        assert_eq!(outs.len(), 4);
        for w in outs.windows(2) {
            let a = m.dest(w[0]).idx() as i64;
            let b = m.dest(w[1]).idx() as i64;
            let pa = m.positions[a as usize] - m.positions[5];
            let pb = m.positions[b as usize] - m.positions[5];
            assert!(pa.x * pb.y - pa.y * pb.x > 0.0, "walk is counter-clockwise");
        }
    }
}
