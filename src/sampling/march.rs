//! Surface marching (Ying et al. 2001, §4.1) on a triangulated copy of the limit surface.
//!
//! The mesh is the field's [`LimitMesh`] (exact limit positions at its vertices), every
//! level face split along its (0,0)–(1,1) diagonal. A sample at pattern offset (l, m) is
//! reached by a straight path from the centre in the direction l·v1 + m·v2 of length
//! |(l, m)|·δ. Inside a triangle the path is a straight segment; where it crosses an edge
//! its 3D direction T turns only along the *limit-surface* normal N at the crossing point
//! (T2 − T1 ∥ N, N interpolated linearly from the limit normals at the edge's ends), as
//! the tangent of a geodesic of the limit surface does. (Ying et al. unfold the neighbour
//! into the current plane — the same angle to the edge, T2 − T1 ∥ the edge's normal — which
//! makes the path a straightest geodesic of the *polyhedron*: its curvature sits at the
//! vertices as angle deficits, and a path is deflected by a vertex's deficit or not
//! depending on which side of it passes. On Spot's level-5 mesh that turned paths by up
//! to 0.3°, an error that jumps between neighbouring directions: 2.4–2.8% of δ at the rim
//! of a 9×9 pattern. With the limit normals the turning is continuous along the path; with
//! the start direction also moved along the normal ([`MarchMesh::to_local`]) marching is
//! within 0.8% of δ of the exact exponential map there. docs/sampling.md.)
//!
//! Across an infinitely sharp crease the limit normal jumps, so the rule has nothing to
//! interpolate: there the path is unfolded (the same angle to the crease on both sides),
//! which is what a geodesic crossing a crease does; the corner normals of every triangle are
//! those of its own side ([`LimitMesh::corner_normal`]).
//!
//! Each triangle keeps 2D coordinates of its corners (P0 = (0,0), P1 = (x1, 0),
//! P2 = (x2, y2)); the walk state is a barycentric point and a 2D direction, so there is no
//! 3D projection (and no drift off the surface) along the way. Robustness:
//! - a path through a vertex is moved off it by 1e-9 of the edge, so it passes the vertex
//!   on one side (which side is deterministic) and cannot loop around it;
//! - at most [`MAX_CROSSINGS`] edge crossings per path (a path of a few δ crosses tens);
//!   reaching the cap ends the path where it is and is counted, never an endless loop;
//! - degenerate triangles cannot produce NaN: lengths are floored before dividing.

use glam::{DVec2, DVec3};
use subdiv::surface::LeafHint;
use subdiv::{BaseLocation, DomainLocation, FaceId, LimitMesh, Surface};

/// Safety cap on edge crossings of one path.
pub const MAX_CROSSINGS: usize = 1 << 16;
const NONE: u32 = u32::MAX;
/// Paths are kept this far (in barycentric units) from triangle corners.
const VERTEX_EPS: f64 = 1e-9;

/// Corner parameters (in the level face) of the two triangles of a face.
const TRI_PARAM: [[(f64, f64); 3]; 2] = [
    [(0.0, 0.0), (1.0, 0.0), (1.0, 1.0)],
    [(0.0, 0.0), (1.0, 1.0), (0.0, 1.0)],
];
/// Quad corners of the two triangles of a face.
const TRI_CORNERS: [[usize; 3]; 2] = [[0, 1, 2], [0, 2, 3]];
/// Quad edge q of a face → (triangle k of the face, local edge j of that triangle).
const QUAD_EDGE: [(usize, usize); 4] = [(0, 0), (0, 1), (1, 1), (1, 2)];

#[derive(Clone, Copy, Debug)]
struct TriGeo {
    x1: f64,
    x2: f64,
    y2: f64,
    /// 3D axes of the local 2D frame (ex along P0→P1; ey = n × ex).
    ex: DVec3,
    ey: DVec3,
    /// Unit normal (ex × ey).
    n: DVec3,
    /// Unit direction of each local edge j (corner j → j + 1), in the 2D frame.
    edge: [DVec2; 3],
    /// Per local edge: (neighbour triangle << 2) | its local edge, or NONE.
    adj: [u32; 3],
    /// Bit j: local edge j lies on an infinitely sharp crease (crossed by unfolding).
    crease: u8,
    /// Limit normals at the corners (the crossing rule, see the module doc).
    corner_normals: [DVec3; 3],
    /// Within [`EXACT_RINGS`] rings of an extraordinary vertex, where the polyhedral mesh
    /// is a poor stand-in for the limit surface (its cone angles there deflect straightest
    /// paths by up to the vertex's angle deficit, a few degrees).
    near_extraordinary: bool,
}

/// A point of the triangulated mesh.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TriPoint {
    pub tri: u32,
    pub bary: [f64; 3],
}

/// The triangulated limit mesh with unfolding data.
#[derive(Clone, Debug)]
pub struct MarchMesh {
    /// Per triangle, everything a path crossing it reads (one record: a crossing costs
    /// ~200 instructions, and separate arrays added a bounds check and an address each).
    geo: Vec<TriGeo>,
}

/// Rings of level faces around an extraordinary vertex in which paths continue on the
/// exact limit surface instead of the mesh (see docs/sampling.md).
pub const EXACT_RINGS: u32 = 3;

/// A path that entered the neighbourhood of an extraordinary vertex: where, in which
/// direction (2D, in the triangle's frame) and how much length was left.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Entered {
    pub at: TriPoint,
    pub dir: DVec2,
    pub rest: f64,
}

/// Result of one path.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum PathEnd {
    /// Ended at this point.
    At(TriPoint),
    /// Left the surface through an open boundary.
    Boundary,
    /// Hit [`MAX_CROSSINGS`] (ends where it was).
    Stalled(TriPoint),
}

impl MarchMesh {
    /// Triangulates `lm` and precomputes each triangle's 2D frame and neighbours.
    pub fn new(lm: &LimitMesh) -> Self {
        let m = &lm.mesh;
        let nf = m.num_faces();
        let mut geo: Vec<TriGeo> = Vec::with_capacity(2 * nf);
        for f in 0..nf {
            let fid = FaceId::from_idx(f);
            let vs = m.face_vertices(fid);
            let corners = [[vs[0], vs[1], vs[2]], [vs[0], vs[2], vs[3]]];
            for (k, tv) in corners.iter().enumerate() {
                let p: [DVec3; 3] = tv.map(|v| lm.position[v as usize]);
                let e1 = p[1] - p[0];
                let e2 = p[2] - p[0];
                let x1 = e1.length().max(1e-300);
                let ex = e1 / x1;
                // Triangle normal from the cross product; fall back to the limit normal for
                // a degenerate triangle.
                let mut n = e1.cross(e2);
                if n.length_squared() < 1e-300 {
                    n = lm.normal[tv[0] as usize];
                }
                let n = n.normalize_or(DVec3::Z);
                let ey = n.cross(ex);
                let (x2, y2) = (e2.dot(ex), e2.dot(ey).max(1e-300));
                let c = [DVec2::ZERO, DVec2::new(x1, 0.0), DVec2::new(x2, y2)];
                let edge = [0, 1, 2].map(|j| (c[(j + 1) % 3] - c[j]).normalize_or(DVec2::X));
                let mut adj = [NONE; 3];
                // The diagonal joins the face's two triangles.
                if k == 0 {
                    adj[2] = ((2 * f + 1) as u32) << 2;
                } else {
                    adj[0] = (((2 * f) as u32) << 2) | 2;
                }
                geo.push(TriGeo {
                    x1,
                    x2,
                    y2,
                    ex,
                    ey,
                    n,
                    edge,
                    adj,
                    crease: 0,
                    corner_normals: TRI_CORNERS[k].map(|c| lm.corner_normal(fid, c)),
                    near_extraordinary: false,
                });
            }
            for (q, &(k, j)) in QUAD_EDGE.iter().enumerate() {
                let h = m.face_he(fid) + q as u32;
                if let Some(t) = m.twin(h) {
                    let g = m.face_of(t);
                    let q2 = (t - m.face_he(g)) as usize;
                    let (k2, j2) = QUAD_EDGE[q2];
                    geo[2 * f + k].adj[j] = (((2 * g.idx() + k2) as u32) << 2) | j2 as u32;
                    if m.has_tags() && m.edge_sharpness(h).is_infinite() {
                        geo[2 * f + k].crease |= 1 << j;
                    }
                }
            }
        }
        // Vertex ring distance to the nearest extraordinary vertex (face-connected rings).
        let nv = m.num_vertices();
        let mut dist = vec![u32::MAX; nv];
        for (v, d) in dist.iter_mut().enumerate() {
            if !m.is_regular_vertex(subdiv::VertexId::from_idx(v)) {
                *d = 0;
            }
        }
        for _ in 0..EXACT_RINGS {
            for f in 0..nf {
                let vs = m.face_vertices(FaceId::from_idx(f));
                let d = vs
                    .iter()
                    .map(|&v| dist[v as usize])
                    .min()
                    .unwrap_or(u32::MAX);
                if d < u32::MAX {
                    for &v in vs {
                        dist[v as usize] = dist[v as usize].min(d + 1);
                    }
                }
            }
        }
        for f in 0..nf {
            let vs = m.face_vertices(FaceId::from_idx(f));
            let near = vs.iter().any(|&v| dist[v as usize] < EXACT_RINGS);
            geo[2 * f].near_extraordinary = near;
            geo[2 * f + 1].near_extraordinary = near;
        }
        MarchMesh { geo }
    }

    /// Whether `tri` is near an extraordinary vertex (see [`EXACT_RINGS`]).
    pub fn near_extraordinary(&self, tri: u32) -> bool {
        self.geo[tri as usize].near_extraordinary
    }

    /// 3D direction of a 2D direction in `tri`'s frame.
    pub fn to_3d(&self, tri: u32, d: DVec2) -> DVec3 {
        let g = &self.geo[tri as usize];
        g.ex * d.x + g.ey * d.y
    }

    /// The triangle point of a level-face point (kept strictly inside its triangle).
    pub fn point_in_face(&self, f: FaceId, s: f64, t: f64) -> TriPoint {
        let s = s.clamp(VERTEX_EPS, 1.0 - VERTEX_EPS);
        let t = t.clamp(VERTEX_EPS, 1.0 - VERTEX_EPS);
        let (tri, bary) = if s >= t {
            (2 * f.idx(), [1.0 - s, s - t, t])
        } else {
            (2 * f.idx() + 1, [1.0 - t, s, t - s])
        };
        TriPoint {
            tri: tri as u32,
            bary,
        }
    }

    /// The level-face point of a triangle point.
    pub fn face_point(&self, p: TriPoint) -> (FaceId, f64, f64) {
        let k = (p.tri & 1) as usize;
        let f = FaceId(p.tri >> 1);
        let mut s = 0.0;
        let mut t = 0.0;
        for (b, (cs, ct)) in p.bary.iter().zip(TRI_PARAM[k]) {
            s += b * cs;
            t += b * ct;
        }
        (f, s.clamp(0.0, 1.0), t.clamp(0.0, 1.0))
    }

    /// Triangle normal and 3D axes of the local 2D frame of `tri`.
    pub fn tri_axes(&self, tri: u32) -> (DVec3, DVec3, DVec3) {
        let g = &self.geo[tri as usize];
        (g.ex, g.ey, g.n)
    }

    /// A 3D tangent direction at a point with unit normal `n`, moved along `n` into the
    /// plane of triangle `tri` (the crossing rule's T − d ∥ n; linear in `d`, not unit), in
    /// the triangle's 2D frame. Where the triangle is nearly perpendicular to `n` it is
    /// turned by the smallest rotation taking `n` to the triangle's normal instead.
    ///
    /// Not the rotation everywhere: rotating keeps angles between directions, but the mesh
    /// below a surface geodesic runs along its projection along the normal, and the two
    /// differ by the square of the triangle's tilt — on Spot up to 0.2° of start direction
    /// (a sin 2θ pattern, 1.8% of δ at the rim of a 9×9 pattern).
    pub fn to_local(&self, tri: u32, n: DVec3, d: DVec3) -> DVec2 {
        let (ex, ey, nt) = self.tri_axes(tri);
        let c = n.dot(nt);
        if c > 1e-3 {
            let r = d - n * (d.dot(nt) / c);
            return DVec2::new(r.dot(ex), r.dot(ey));
        }
        let r = if c > -0.999_999 {
            let v = n.cross(nt);
            d * c + v.cross(d) + v * (v.dot(d) / (1.0 + c))
        } else {
            d
        };
        DVec2::new(r.dot(ex), r.dot(ey))
    }

    /// Walks from `start` along the 2D direction `dir` (unit, in the start triangle's frame)
    /// for `length`.
    pub fn walk(&self, start: TriPoint, dir: DVec2, length: f64) -> PathEnd {
        match self.walk_impl(start, dir, length, false) {
            Ok((end, _)) => end,
            Err(e) => PathEnd::At(e.at),
        }
    }

    /// As [`Self::walk`], but stops as soon as the path is in a triangle near an
    /// extraordinary vertex (including the start triangle): `Err(Entered)`.
    pub fn walk_until_extraordinary(
        &self,
        start: TriPoint,
        dir: DVec2,
        length: f64,
    ) -> Result<PathEnd, Entered> {
        self.walk_impl(start, dir, length, true).map(|(end, _)| end)
    }

    /// As [`Self::walk_until_extraordinary`], also returning the direction at the end (in
    /// the end triangle's frame), so that a path can be continued where it ended: walking
    /// on from an `At` end with that direction is the same path as one longer walk.
    pub fn walk_on(
        &self,
        start: TriPoint,
        dir: DVec2,
        length: f64,
    ) -> Result<(PathEnd, DVec2), Entered> {
        self.walk_impl(start, dir, length, true)
    }

    fn walk_impl(
        &self,
        start: TriPoint,
        dir: DVec2,
        length: f64,
        stop: bool,
    ) -> Result<(PathEnd, DVec2), Entered> {
        let mut tri = start.tri as usize;
        let mut b = start.bary;
        let mut d = dir;
        let mut rest = length;
        if rest.is_nan() || rest <= 0.0 || !d.is_finite() {
            return Ok((PathEnd::At(start), d));
        }
        for _ in 0..MAX_CROSSINGS {
            let g = &self.geo[tri];
            if stop && g.near_extraordinary {
                return Err(Entered {
                    at: TriPoint {
                        tri: tri as u32,
                        bary: clean(b),
                    },
                    dir: d,
                    rest,
                });
            }
            // Barycentric rate of change per unit length along d.
            let db2 = d.y / g.y2;
            let db1 = (d.x - g.x2 * db2) / g.x1;
            let db = [-db1 - db2, db1, db2];
            let mut lambda = f64::INFINITY;
            let mut hit = 3;
            for c in 0..3 {
                if db[c] < 0.0 {
                    let l = b[c].max(0.0) / -db[c];
                    if l < lambda {
                        lambda = l;
                        hit = c;
                    }
                }
            }
            if hit == 3 || lambda >= rest {
                for c in 0..3 {
                    b[c] += db[c] * rest;
                }
                return Ok((
                    PathEnd::At(TriPoint {
                        tri: tri as u32,
                        bary: clean(b),
                    }),
                    d,
                ));
            }
            rest -= lambda;
            for c in 0..3 {
                b[c] += db[c] * lambda;
            }
            // Leaves through the edge opposite corner `hit`: local edge j = hit + 1, from
            // corner j to corner j + 1; `a` is the position along it.
            let j = (hit + 1) % 3;
            let j1 = (j + 1) % 3;
            let (bj, bj1) = (b[j].max(0.0), b[j1].max(0.0));
            let a = (bj1 / (bj + bj1).max(1e-300)).clamp(VERTEX_EPS, 1.0 - VERTEX_EPS);
            let link = g.adj[j];
            if link == NONE {
                return Ok((PathEnd::Boundary, d));
            }
            let (ntri, nj) = ((link >> 2) as usize, (link & 3) as usize);
            // Direction relative to the edge: along (α) and across (β, negative: leaving).
            let (e, w) = edge_axes(g, j);
            let (alpha, beta) = (d.dot(e), d.dot(w));
            let g2 = &self.geo[ntri];
            let (e2, w2) = edge_axes(g2, nj);
            // The shared edge runs the other way in the neighbour.
            // The 3D direction turns only along the surface normal at the crossing point
            // (T2 − T1 ∥ N, N interpolated from the limit normals at the edge's ends), as
            // a geodesic's does; exact unfolding (the shared edge runs the other way in the
            // neighbour) only where that fails.
            let cn = &g.corner_normals;
            let nc = cn[j] * (1.0 - a) + cn[j1] * a;
            let t1 = g.ex * d.x + g.ey * d.y;
            let den = nc.dot(g2.n);
            let mut d2 = DVec2::ZERO;
            // (On a crease d2 stays zero: unfolded below.)
            if g.crease & (1 << j) == 0 && den > 1e-3 * nc.length() {
                let t2 = t1 - nc * (t1.dot(g2.n) / den);
                d2 = DVec2::new(t2.dot(g2.ex), t2.dot(g2.ey));
            }
            // Must point into the neighbour.
            let inward = d2.dot(w2);
            if inward.is_nan() || inward <= 0.0 {
                d2 = -alpha * e2 - beta * w2;
            }
            d = unit_or(d2, w2);
            let mut nb = [0.0; 3];
            nb[nj] = a;
            nb[(nj + 1) % 3] = 1.0 - a;
            b = nb;
            tri = ntri;
        }
        Ok((
            PathEnd::Stalled(TriPoint {
                tri: tri as u32,
                bary: clean(b),
            }),
            d,
        ))
    }

    /// 3D point of a triangle point on the piecewise-linear mesh.
    pub fn position(&self, lm: &LimitMesh, p: TriPoint) -> DVec3 {
        let k = (p.tri & 1) as usize;
        let vs = lm.mesh.face_vertices(FaceId(p.tri >> 1));
        let corners = if k == 0 { [0, 1, 2] } else { [0, 2, 3] };
        corners
            .iter()
            .zip(p.bary)
            .map(|(&c, b)| lm.position[vs[c] as usize] * b)
            .sum()
    }

    /// Domain location of a triangle point: the face parameter of the point (affine in the
    /// triangle) refined to the limit-surface point nearest the mesh point. The refinement
    /// matters next to extraordinary vertices, where the limit surface's parameterisation
    /// is far from affine across one face (up to 30% of a face at level 5), while the mesh
    /// itself is within a hair of the surface.
    ///
    /// `hint` is the patch of the last point evaluated, in and out: the samples of one path
    /// are close, so a hint carried along it mostly skips the descent of the patch tree.
    pub fn to_domain(
        &self,
        surface: &Surface,
        lm: &LimitMesh,
        p: TriPoint,
        hint: &mut LeafHint,
    ) -> DomainLocation {
        let loc = self.to_base(surface, lm, p, hint);
        surface.base_to_domain(loc.quad, loc.s, loc.t)
    }

    /// [`Self::to_domain`] as a base-quad point.
    pub fn to_base(
        &self,
        surface: &Surface,
        lm: &LimitMesh,
        p: TriPoint,
        hint: &mut LeafHint,
    ) -> BaseLocation {
        let (f, s, t) = self.face_point(p);
        let mut loc = lm.to_base(f, s, t);
        let target = self.position(lm, p);
        // Never move further than the face is wide (a safeguard at singular points).
        let cap = 1.0 / lm.faces_per_base().isqrt() as f64;
        // Only position and derivatives are needed; successive points share a patch.
        for _ in 0..4 {
            let e = surface.eval_base_derivs(loc.quad, loc.s, loc.t, hint);
            let r = target - e.p;
            // Gauss–Newton step for min |f(s,t) − target|².
            let (a, b, c) = (e.du.dot(e.du), e.du.dot(e.dv), e.dv.dot(e.dv));
            let det = a * c - b * b;
            if !det.is_finite() || det <= 1e-300 {
                break;
            }
            let (gu, gv) = (e.du.dot(r), e.dv.dot(r));
            let ds = (c * gu - b * gv) / det;
            let dt = (a * gv - b * gu) / det;
            if !(ds.is_finite() && dt.is_finite()) {
                break;
            }
            let len = (ds * ds + dt * dt).sqrt();
            let scale = if len > cap { cap / len } else { 1.0 };
            match surface.walk_base(loc, ds * scale, dt * scale) {
                Some((next, _)) => loc = next,
                None => break,
            }
            // Converged: the step just taken was under 1e-4 of a level face, so what is
            // left is second order in it (1e-12 moved the samples by < 2e-7 δ and took
            // 4 evaluations where this takes 2.3 on average).
            if len < 1e-4 * cap {
                break;
            }
        }
        loc
    }
}

/// Unit direction of local edge j (corner j → j+1) and the unit normal into the triangle.
#[inline]
fn edge_axes(g: &TriGeo, j: usize) -> (DVec2, DVec2) {
    let e = g.edge[j];
    // Corners are counter-clockwise, so the interior is to the left of every edge.
    (e, DVec2::new(-e.y, e.x))
}

/// `d.normalize_or(fallback)` with the finiteness test as two comparisons (the same
/// results; glam's bit test was ~10 of the ~200 instructions of an edge crossing).
#[inline]
fn unit_or(d: DVec2, fallback: DVec2) -> DVec2 {
    let rcp = 1.0 / d.length();
    if rcp > 0.0 && rcp < f64::INFINITY {
        d * rcp
    } else {
        fallback
    }
}

/// Clamps rounding errors so the coordinates stay a convex combination.
#[inline]
fn clean(mut b: [f64; 3]) -> [f64; 3] {
    for x in b.iter_mut() {
        *x = x.max(0.0);
    }
    let s = b[0] + b[1] + b[2];
    if s > 0.0 && s.is_finite() {
        for x in b.iter_mut() {
            *x /= s;
        }
        b
    } else {
        [1.0 / 3.0; 3]
    }
}
