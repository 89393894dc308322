//! The limit surface, evaluated exactly at any parameter.
//!
//! The control mesh is refined once; its quads are the *base quads* (conforming, all quads,
//! numbered like the control mesh's half-edges: base quad `face_start[f] + c` is corner `c`
//! of control face `f`). Each base quad gets a *patch tree*:
//! - a quad whose corners are all regular is a bicubic B-spline patch ([`BSplinePatch`]);
//! - otherwise its 1-ring submesh is refined locally (with the same [`refine`] code) and the
//!   quad splits into four children, recursively. Only the children touching an
//!   extraordinary corner stay irregular, so every point other than the extraordinary vertex
//!   itself ends in a regular patch after log2(1/distance) levels — this is the classic exact
//!   evaluation by subdivision (Stam 1998 does the same with eigenvectors). Levels beyond
//!   `max_depth` are not stored in the surface but refined on demand; each thread keeps
//!   the levels it refined in a small bounded cache (`deep.rs`; bit-identical
//!   values, nothing added to the surface's memory).
//! - exactly at an extraordinary vertex the limit masks of [`crate::limit`] apply.
//!
//! Positions are exact to rounding; derivatives are scaled by 2 per level.

use crate::deep::{self, CacheId, DeepCache, DeepNode, DeepTree, DEEP_CACHE};
use crate::error::MeshError;
use crate::ids::{BaseQuadId, FaceId};
use crate::limit::corner_limit;
use crate::mesh::ControlMesh;
use crate::patch::{BSplinePatch, PatchPoint};
use crate::refine::refine;
use crate::submesh::{extract_submesh, is_regular_quad};
use crate::topology::{Check, PolyMesh};
use glam::DVec3;

/// Limit-surface geometry at a parameter point.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct LimitSample {
    /// Limit position.
    pub p: DVec3,
    /// Partial derivatives with respect to the two parameters. At an extraordinary vertex
    /// they are singular; there they are the unit limit tangents along the two parameter
    /// directions instead.
    pub du: DVec3,
    pub dv: DVec3,
    /// Unit limit normal, `normalize(du x dv)` (outward for counter-clockwise faces).
    pub n: DVec3,
}

/// Limit position and parametric derivatives, with the normal computed on demand
/// ([`Surface::eval_base_derivs`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LimitDerivs {
    pub p: DVec3,
    pub du: DVec3,
    pub dv: DVec3,
    /// The normal where it is not `normalize(du x dv)` (at an extraordinary vertex).
    n: Option<DVec3>,
}

impl LimitDerivs {
    /// The full sample: what [`Surface::eval_base`] returns at the same point.
    #[inline]
    pub fn sample(&self) -> LimitSample {
        LimitSample {
            p: self.p,
            du: self.du,
            dv: self.dv,
            n: self
                .n
                .unwrap_or_else(|| self.du.cross(self.dv).normalize_or_zero()),
        }
    }
}

impl From<LimitSample> for LimitDerivs {
    fn from(e: LimitSample) -> Self {
        LimitDerivs {
            p: e.p,
            du: e.du,
            dv: e.dv,
            n: Some(e.n),
        }
    }
}

/// Where the descent of a base-quad point ends.
enum Leaf {
    /// In regular patch `patch`, at its local (s, t); `jac` maps base-parameter
    /// differentials to local ones.
    Patch {
        patch: PatchRef,
        s: f64,
        t: f64,
        jac: [[f64; 2]; 2],
    },
    /// No stored patch: the point evaluated (at an extraordinary vertex or below the
    /// stored depth).
    Sample(LimitSample),
}

/// The regular patch of the last [`Surface::eval_base_derivs`] that descended the patch
/// tree, so that the next evaluation inside it skips the descent (next to an extraordinary
/// vertex up to `max_depth` levels).
///
/// Why it is exact: every step of the descent, (s, t) ↦ (2s, 2t), (2t, 2 − 2s), … applied
/// in the child containing the point, is exact in floating point (2 − 2s with s ≥ 1/2 by
/// Sterbenz), so a leaf's local parameter is an exact affine function of the base one:
/// local = jac · base + off, jac entries 0 or ±2^depth and off integers. Computed as
/// (jac · base) + off the products are exact and the sum, being representable, is too:
/// the same bits as the descent. Only points strictly inside the leaf are taken (on its
/// boundary the descent's tie-breaking decides).
#[derive(Clone, Copy, Debug)]
pub struct LeafHint {
    /// Surface (its cache key) and base quad of the leaf; `u64::MAX` when empty.
    surface: u64,
    quad: BaseQuadId,
    patch: PatchRef,
    jac: [[f64; 2]; 2],
    off: [f64; 2],
}

impl Default for LeafHint {
    fn default() -> Self {
        LeafHint {
            surface: u64::MAX,
            quad: BaseQuadId(u32::MAX),
            patch: PatchRef { chunk: 0, index: 0 },
            jac: [[0.0; 2]; 2],
            off: [0.0; 2],
        }
    }
}

impl LeafHint {
    /// The leaf of base point (s, t), which descended to local (ls, lt) of `patch`.
    #[allow(clippy::too_many_arguments)]
    fn new(
        surface: u64,
        quad: BaseQuadId,
        s: f64,
        t: f64,
        patch: PatchRef,
        ls: f64,
        lt: f64,
        jac: [[f64; 2]; 2],
    ) -> Self {
        let [ms, mt] = Self::linear(&jac, s, t);
        LeafHint {
            surface,
            quad,
            patch,
            jac,
            off: [ls - ms, lt - mt],
        }
    }

    /// jac · (s, t): one of each row's terms is zero, the other exact.
    #[inline]
    fn linear(jac: &[[f64; 2]; 2], s: f64, t: f64) -> [f64; 2] {
        [jac[0][0] * s + jac[0][1] * t, jac[1][0] * s + jac[1][1] * t]
    }

    /// Patch, local parameter and Jacobian of clamped base point (s, t) if it lies strictly
    /// inside the remembered leaf.
    #[inline]
    fn find(
        &self,
        surface: u64,
        quad: BaseQuadId,
        s: f64,
        t: f64,
    ) -> Option<(PatchRef, f64, f64, [[f64; 2]; 2])> {
        if self.surface != surface || self.quad != quad {
            return None;
        }
        let [ms, mt] = Self::linear(&self.jac, s, t);
        let (ls, lt) = (ms + self.off[0], mt + self.off[1]);
        let inside = |x: f64| x > 0.0 && x < 1.0;
        (inside(ls) && inside(lt)).then_some((self.patch, ls, lt, self.jac))
    }
}

/// Options for building a [`Surface`].
#[derive(Clone, Copy, Debug)]
pub struct SurfaceOptions {
    /// Levels of the patch tree stored around extraordinary vertices (deeper points are
    /// refined on demand). 6 covers texel centres of maps up to 32 texels per side on
    /// n-gon sub-faces and 64 on quads without on-demand refinement; `bake` raises it to
    /// what its resolution needs.
    pub max_depth: u32,
}

impl Default for SurfaceOptions {
    fn default() -> Self {
        Self { max_depth: 6 }
    }
}

/// A stored regular patch: `Surface::patches[chunk][index]`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct PatchRef {
    chunk: u32,
    index: u32,
}

#[derive(Clone, Debug)]
enum Node {
    Regular(PatchRef),
    /// Four children (in child-corner order) and, for each corner of this quad that is an
    /// extraordinary vertex, an index into `limits`.
    Split {
        children: [u32; 4],
        corner_limit: [u32; 4],
    },
    /// Below the stored depth: refined on demand from the base mesh along the descent path
    /// (nothing is stored, which keeps memory per extraordinary corner small); the refined
    /// levels are cached per thread, keyed by this node's index ([`crate::deep`]).
    Deep,
}

const NO_LIMIT: u32 = u32::MAX;

/// A Catmull-Clark limit surface: control mesh, base quads and their patch trees.
#[derive(Clone, Debug)]
pub struct Surface {
    pub control: ControlMesh,
    /// The level-1 mesh (all quads).
    pub base: PolyMesh,
    roots: Vec<u32>,
    nodes: Vec<Node>,
    /// Regular patches by chunk of base quads, as the chunks were built in parallel:
    /// copying them into one vector (most of the surface's memory) was a tenth of the
    /// build on one thread, most of it first touches of the new memory.
    patches: Vec<Vec<BSplinePatch>>,
    limits: Vec<(DVec3, DVec3)>,
    max_depth: u32,
    pub(crate) domain_start: Vec<u32>,
    pub(crate) domain_face: Vec<u32>,
    /// Key of this surface in the per-thread cache of levels below the stored depth.
    cache_id: CacheId,
}

impl Surface {
    pub fn new(control: ControlMesh) -> Self {
        Self::with_options(control, SurfaceOptions::default())
    }

    pub fn with_options(control: ControlMesh, opts: SurfaceOptions) -> Self {
        // The descent path of a Deep evaluation is kept in a fixed array of 64.
        let opts = SurfaceOptions {
            max_depth: opts.max_depth.min(60),
        };
        let base = refine(&control.mesh);
        let mut s = Surface {
            roots: Vec::with_capacity(base.num_faces()),
            nodes: Vec::new(),
            patches: Vec::new(),
            limits: Vec::new(),
            max_depth: opts.max_depth,
            domain_start: Vec::new(),
            domain_face: Vec::new(),
            cache_id: CacheId::fresh(),
            control,
            base: PolyMesh::new(vec![], vec![0], vec![], Check::Trusted).unwrap(),
        };
        // Trees are independent per base quad: build them in parallel chunks, then merge
        // the chunks in order, so the result is the same for any number of threads.
        use rayon::prelude::*;
        const CHUNK: usize = 128;
        let nq = base.num_faces();
        let arenas: Vec<Arena> = (0..nq.div_ceil(CHUNK))
            .into_par_iter()
            .map(|c| {
                let mut a = Arena {
                    chunk: c as u32,
                    ..Arena::default()
                };
                for q in c * CHUNK..((c + 1) * CHUNK).min(nq) {
                    let root = a.build(&base, FaceId::from_idx(q), 0, opts.max_depth);
                    a.roots.push(root);
                }
                a
            })
            .collect();
        s.patches.reserve_exact(arenas.len());
        s.nodes
            .reserve_exact(arenas.iter().map(|a| a.nodes.len()).sum());
        for a in arenas {
            s.append(a);
        }
        s.base = base;
        s.init_domains();
        s
    }

    /// Reads, validates and builds in one go.
    pub fn load_obj(path: impl AsRef<std::path::Path>) -> Result<Self, MeshError> {
        Ok(Self::new(ControlMesh::load_obj(path)?))
    }

    /// Appends a chunk's trees, shifting its node and limit indices past what is already
    /// stored (its patches are kept as they are, as the next chunk).
    fn append(&mut self, a: Arena) {
        debug_assert_eq!(a.chunk as usize, self.patches.len());
        let (n0, l0) = (self.nodes.len() as u32, self.limits.len() as u32);
        self.roots.extend(a.roots.iter().map(|r| r + n0));
        self.nodes.extend(a.nodes.into_iter().map(|n| match n {
            Node::Regular(r) => Node::Regular(r),
            Node::Split {
                children,
                corner_limit,
            } => Node::Split {
                children: children.map(|c| c + n0),
                corner_limit: corner_limit.map(|l| if l == NO_LIMIT { l } else { l + l0 }),
            },
            Node::Deep => Node::Deep,
        }));
        self.patches.push(a.patches);
        self.limits.extend(a.limits);
    }

    pub fn num_base_quads(&self) -> usize {
        self.roots.len()
    }

    /// Evaluates base quad `b` at (s, t) in [0, 1]²; derivatives are with respect to s, t.
    pub fn eval_base(&self, b: BaseQuadId, s: f64, t: f64) -> LimitSample {
        self.eval_base_impl(b, s, t, true)
    }

    /// [`Self::eval_base`] without the per-thread cache of levels below the stored depth
    /// (every such evaluation refined from the base mesh): the reference the cache is
    /// tested against.
    pub fn eval_base_uncached(&self, b: BaseQuadId, s: f64, t: f64) -> LimitSample {
        self.eval_base_impl(b, s, t, false)
    }

    /// [`Self::eval_base`] with the normal left until asked for ([`LimitDerivs::sample`]),
    /// starting from the regular patch `hint` remembers when (s, t) lies inside it.
    /// Bit-identical to `eval_base`. For iterations that evaluate many nearby points and
    /// need the normal of few (Newton's method on the surface): next to an extraordinary
    /// vertex the descent of the patch tree and the normal were ~40% of an evaluation.
    pub fn eval_base_derivs(
        &self,
        b: BaseQuadId,
        s: f64,
        t: f64,
        hint: &mut LeafHint,
    ) -> LimitDerivs {
        let (s, t) = (s.clamp(0.0, 1.0), t.clamp(0.0, 1.0));
        let (patch, ls, lt, jac) = match hint.find(self.cache_id.0, b, s, t) {
            Some(hit) => hit,
            None => match self.leaf(b, s, t, true) {
                Leaf::Patch {
                    patch,
                    s: ls,
                    t: lt,
                    jac,
                } => {
                    *hint = LeafHint::new(self.cache_id.0, b, s, t, patch, ls, lt, jac);
                    (patch, ls, lt, jac)
                }
                Leaf::Sample(e) => return LimitDerivs::from(e),
            },
        };
        derivs(self.patch(patch).eval(ls, lt), &jac)
    }

    #[inline]
    fn patch(&self, r: PatchRef) -> &BSplinePatch {
        &self.patches[r.chunk as usize][r.index as usize]
    }

    fn eval_base_impl(&self, b: BaseQuadId, s: f64, t: f64, cached: bool) -> LimitSample {
        match self.leaf(b, s, t, cached) {
            Leaf::Patch { patch, s, t, jac } => derivs(self.patch(patch).eval(s, t), &jac).sample(),
            Leaf::Sample(e) => e,
        }
    }

    /// Descends the patch tree of base quad `b` to the regular patch containing (s, t), or
    /// evaluates the point where no stored patch does (an extraordinary vertex, or below
    /// the stored depth).
    fn leaf(&self, b: BaseQuadId, s: f64, t: f64, cached: bool) -> Leaf {
        let mut node = self.roots[b.idx()];
        let (s0, t0) = (s.clamp(0.0, 1.0), t.clamp(0.0, 1.0));
        let (mut s, mut t) = (s0, t0);
        // jac maps base (s,t) differentials to local ones: d(local) = jac * d(base).
        let mut jac = [[1.0f64, 0.0], [0.0, 1.0]];
        // Child corners taken so far (to rebuild a Deep node's submesh).
        let mut path = [0u8; 64];
        let mut depth = 0;
        loop {
            match &self.nodes[node as usize] {
                Node::Regular(i) => {
                    return Leaf::Patch {
                        patch: *i,
                        s,
                        t,
                        jac,
                    }
                }
                Node::Split {
                    children,
                    corner_limit,
                } => {
                    if let Some(c) = exact_corner(s, t) {
                        let li = corner_limit[c];
                        if li != NO_LIMIT {
                            return Leaf::Sample(self.at_extraordinary(
                                b,
                                s0,
                                t0,
                                li as usize,
                                cached,
                            ));
                        }
                    }
                    let c = quadrant(s, t);
                    (s, t) = to_child(c, s, t);
                    jac = mul_child(c, &jac);
                    node = children[c];
                    path[depth] = c as u8;
                    depth += 1;
                }
                Node::Deep => {
                    let root = || {
                        let mut m = extract_submesh(&self.base, FaceId(b.0));
                        for &c in &path[..depth] {
                            m = extract_submesh(&refine(&m), FaceId::from_idx(c as usize));
                        }
                        m
                    };
                    if cached {
                        if let Some(r) = self.eval_deep_cached(node, root, s, t, jac) {
                            return Leaf::Sample(r);
                        }
                    }
                    return Leaf::Sample(self.eval_deep(&root(), s, t, jac));
                }
            }
        }
    }

    /// At an extraordinary vertex (a corner (s0, t0) of the base quad): position and normal
    /// from limit masks; unit tangents from the surface just inside the base quad, since
    /// the parametric derivatives themselves are singular there. The probe sits at
    /// 2^-max_depth along the diagonal, which the stored tree reaches without on-demand
    /// refinement (at 1e-9 every call refined ~30 levels). Not deeper than the tree for
    /// trees of depth 3 and more: at 2^-6 a tree of depth 5 (maps of N ≤ 16) refined every
    /// probe on demand, and the limit meshes evaluate every extraordinary vertex — the
    /// field of the bunny at N = 16 took 3.0 s instead of 1.7 s. Depth 1–2 trees (N ≤ 2)
    /// still probe at 1/8, so that the tangents do not come from the quad's middle.
    fn at_extraordinary(
        &self,
        b: BaseQuadId,
        s0: f64,
        t0: f64,
        li: usize,
        cached: bool,
    ) -> LimitSample {
        let (p, n) = self.limits[li];
        let eps = 0.5f64.powi(self.max_depth.max(3) as i32);
        let inward = |x: f64| if x < 0.5 { eps } else { 1.0 - eps };
        let q = self.eval_base_impl(b, inward(s0), inward(t0), cached);
        let du = (q.du - n * n.dot(q.du)).normalize_or_zero();
        let dv = (q.dv - n * n.dot(q.dv)).normalize_or_zero();
        LimitSample { p, du, dv, n }
    }

    /// [`Self::eval_deep`] through the per-thread cache ([`crate::deep`]): the same
    /// operations on the same inputs, each done once per thread and Deep node. `None` if
    /// the cache is busy (re-entrant call) or the point is within 2^-64 of the
    /// extraordinary vertex (the uncached evaluation decides then).
    fn eval_deep_cached(
        &self,
        node: u32,
        root: impl FnOnce() -> PolyMesh,
        mut s: f64,
        mut t: f64,
        mut jac: [[f64; 2]; 2],
    ) -> Option<LimitSample> {
        DEEP_CACHE.with(|cache| {
            let mut cache = cache.try_borrow_mut().ok()?;
            if cache.nodes > deep::CAPACITY {
                cache.trees.clear();
                cache.nodes = 0;
            }
            let DeepCache { trees, nodes } = &mut *cache;
            let tree = trees.entry((self.cache_id.0, node)).or_insert_with(|| {
                *nodes += 1;
                DeepTree {
                    nodes: vec![DeepNode::classify(root())],
                }
            });
            let mut i = 0;
            for _ in 0..64 {
                let m = match &tree.nodes[i] {
                    DeepNode::Patch(p) => return Some(finish(p.eval(s, t), &jac)),
                    DeepNode::Mesh { m, .. } => m,
                };
                if let Some(c) = exact_corner(s, t) {
                    if needs_limit(m, FaceId(0), c) {
                        return Some(limit_sample(m, FaceId(0), c));
                    }
                }
                let c = quadrant(s, t);
                (s, t) = to_child(c, s, t);
                jac = mul_child(c, &jac);
                let (next, added) = tree.child(i, c);
                *nodes += added;
                i = next;
            }
            None
        })
    }

    fn eval_deep(
        &self,
        m0: &PolyMesh,
        mut s: f64,
        mut t: f64,
        mut jac: [[f64; 2]; 2],
    ) -> LimitSample {
        let mut m = m0.clone();
        for _ in 0..64 {
            let q = FaceId(0);
            if is_regular_quad(&m, q) {
                if let Some(p) = BSplinePatch::gather(&m, q) {
                    return finish(p.eval(s, t), &jac);
                }
            }
            if let Some(c) = exact_corner(s, t) {
                if needs_limit(&m, q, c) {
                    return limit_sample(&m, q, c);
                }
            }
            let r = refine(&m);
            let c = quadrant(s, t);
            (s, t) = to_child(c, s, t);
            jac = mul_child(c, &jac);
            m = extract_submesh(&r, FaceId::from_idx(c));
        }
        // Within 2^-64 of the extraordinary vertex: its limit point.
        let c = (0..4)
            .find(|&c| !m.corner_is_regular(m.face_he(FaceId(0)) + c as u32))
            .unwrap_or(0);
        limit_sample(&m, FaceId(0), c)
    }

    /// Axis-aligned bounds of the control points (the limit surface lies inside).
    pub fn bounds(&self) -> (DVec3, DVec3) {
        self.control.bounds()
    }
}

/// Patch trees of some base quads, with node and limit indices local to this arena; its
/// patches are chunk `chunk` of the surface's.
#[derive(Default)]
struct Arena {
    chunk: u32,
    roots: Vec<u32>,
    nodes: Vec<Node>,
    patches: Vec<BSplinePatch>,
    limits: Vec<(DVec3, DVec3)>,
}

impl Arena {
    fn build(&mut self, m: &PolyMesh, q: FaceId, depth: u32, max_depth: u32) -> u32 {
        if is_regular_quad(m, q) {
            if let Some(p) = BSplinePatch::gather(m, q) {
                self.patches.push(p);
                return self.push(Node::Regular(PatchRef {
                    chunk: self.chunk,
                    index: self.patches.len() as u32 - 1,
                }));
            }
        }
        if depth >= max_depth {
            return self.push(Node::Deep);
        }
        let sub = extract_submesh(m, q);
        let mut corner_limit = [NO_LIMIT; 4];
        for (i, slot) in corner_limit.iter_mut().enumerate() {
            if needs_limit(m, q, i) {
                let l = crate::limit::corner_limit(m, m.face_he(q) + i as u32);
                self.limits.push((l.position, l.normal));
                *slot = self.limits.len() as u32 - 1;
            }
        }
        let r = refine(&sub);
        sub.recycle();
        let id = self.push(Node::Split {
            children: [0; 4],
            corner_limit,
        });
        let mut children = [0u32; 4];
        for (c, slot) in children.iter_mut().enumerate() {
            *slot = self.build(&r, FaceId::from_idx(c), depth + 1, max_depth);
        }
        r.recycle();
        if let Node::Split { children: ch, .. } = &mut self.nodes[id as usize] {
            *ch = children;
        }
        id
    }

    fn push(&mut self, n: Node) -> u32 {
        self.nodes.push(n);
        self.nodes.len() as u32 - 1
    }
}

/// Whether corner `c` of quad `q` is a point no patch of the tree reaches, whose value
/// the limit masks give: an irregular corner with no semi-sharp value left (where one is
/// left, the tree refines further first; there its rule still changes).
#[inline]
pub(crate) fn needs_limit(m: &PolyMesh, q: FaceId, c: usize) -> bool {
    let h = m.face_he(q) + c as u32;
    !m.corner_is_regular(h) && !m.has_semi_sharp_at(m.origin(h))
}

/// The limit sample at corner `c` of quad `q` (position, normal on the quad's side, unit
/// tangents).
fn limit_sample(m: &PolyMesh, q: FaceId, c: usize) -> LimitSample {
    let l = corner_limit(m, m.face_he(q) + c as u32);
    LimitSample {
        p: l.position,
        du: l.tangent1,
        dv: l.tangent2,
        n: l.normal,
    }
}

/// Which corner (0..4, in quad corner order) (s, t) sits on exactly, if any.
#[inline]
fn exact_corner(s: f64, t: f64) -> Option<usize> {
    match (s, t) {
        (0.0, 0.0) => Some(0),
        (1.0, 0.0) => Some(1),
        (1.0, 1.0) => Some(2),
        (0.0, 1.0) => Some(3),
        _ => None,
    }
}

/// The child quad (by corner) that contains (s, t).
#[inline]
pub(crate) fn quadrant(s: f64, t: f64) -> usize {
    match (s < 0.5, t < 0.5) {
        (true, true) => 0,
        (false, true) => 1,
        (false, false) => 2,
        (true, false) => 3,
    }
}

/// Parameter of (s, t) in child quad `c`. Child c has (0,0) at parent corner c, its s axis
/// toward parent corner c+1 and its t axis toward parent corner c-1 (see [`crate::refine`]).
#[inline]
pub(crate) fn to_child(c: usize, s: f64, t: f64) -> (f64, f64) {
    match c {
        0 => (2.0 * s, 2.0 * t),
        1 => (2.0 * t, 2.0 - 2.0 * s),
        2 => (2.0 - 2.0 * s, 2.0 - 2.0 * t),
        _ => (2.0 - 2.0 * t, 2.0 * s),
    }
}

/// Inverse of [`to_child`].
#[inline]
pub(crate) fn from_child(c: usize, s: f64, t: f64) -> (f64, f64) {
    match c {
        0 => (0.5 * s, 0.5 * t),
        1 => (1.0 - 0.5 * t, 0.5 * s),
        2 => (1.0 - 0.5 * s, 1.0 - 0.5 * t),
        _ => (0.5 * t, 1.0 - 0.5 * s),
    }
}

/// Linear part of [`to_child`] composed after `jac`.
#[inline]
pub(crate) fn mul_child(c: usize, jac: &[[f64; 2]; 2]) -> [[f64; 2]; 2] {
    let r: [[f64; 2]; 2] = match c {
        0 => [[2.0, 0.0], [0.0, 2.0]],
        1 => [[0.0, 2.0], [-2.0, 0.0]],
        2 => [[-2.0, 0.0], [0.0, -2.0]],
        _ => [[0.0, -2.0], [2.0, 0.0]],
    };
    [
        [
            r[0][0] * jac[0][0] + r[0][1] * jac[1][0],
            r[0][0] * jac[0][1] + r[0][1] * jac[1][1],
        ],
        [
            r[1][0] * jac[0][0] + r[1][1] * jac[1][0],
            r[1][0] * jac[0][1] + r[1][1] * jac[1][1],
        ],
    ]
}

#[inline]
fn finish(pp: PatchPoint, jac: &[[f64; 2]; 2]) -> LimitSample {
    derivs(pp, jac).sample()
}

/// Position and base-parameter derivatives of a patch point whose local parameter has
/// Jacobian `jac` with respect to the base quad's.
#[inline]
fn derivs(pp: PatchPoint, jac: &[[f64; 2]; 2]) -> LimitDerivs {
    // dP/ds_base = dP/ds' * ds'/ds + dP/dt' * dt'/ds.
    LimitDerivs {
        p: pp.p,
        du: pp.ds * jac[0][0] + pp.dt * jac[1][0],
        dv: pp.ds * jac[0][1] + pp.dt * jac[1][1],
        n: None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Points below the stored depth are refined on demand from the base mesh: a tree
    /// stored to depth 1 must give exactly what a tree stored to depth 10 gives.
    #[test]
    fn on_demand_levels_match_stored_levels() {
        for shape in [
            "catmark_nonquads",
            "catmark_edgecorner",
            "catmark_pole8",
            "catmark_single_crease",
            "catmark_cubes_infsharp",
            "catmark_pyramid_creases1",
        ] {
            let cm = crate::ControlMesh::load_obj(crate::test_data::shape(shape)).unwrap();
            let shallow = Surface::with_options(cm.clone(), SurfaceOptions { max_depth: 1 });
            let deep = Surface::with_options(cm, SurfaceOptions { max_depth: 10 });
            for b in 0..deep.num_base_quads() {
                for &(s, t) in &[
                    (0.3, 0.01),
                    (1e-3, 2e-3),
                    (0.999, 0.9995),
                    (0.0, 0.0),
                    (1.0, 1.0),
                    (0.02, 0.97),
                ] {
                    let a = shallow.eval_base(BaseQuadId(b as u32), s, t);
                    let d = deep.eval_base(BaseQuadId(b as u32), s, t);
                    assert_eq!(a.p, d.p, "{shape} base {b} ({s},{t})");
                    assert_eq!(a.n, d.n, "{shape} base {b} ({s},{t})");
                }
            }
        }
    }

    /// The per-thread cache of levels below the stored depth (crate::deep) must give
    /// bit-identical values to refining from the base mesh on every evaluation, whether a
    /// value is computed or read back, in any call order and on any thread, and across
    /// the cache being emptied when full.
    #[test]
    fn deep_cache_matches_uncached_refinement() {
        for (shape, depth) in [
            ("catmark_nonquads", 1),
            ("catmark_edgecorner", 2),
            ("catmark_pole8", 1),
            ("catmark_cube", 3),
            ("catmark_cube_creases1", 1),
            ("catmark_inf_crease0", 2),
        ] {
            let cm = crate::ControlMesh::load_obj(crate::test_data::shape(shape)).unwrap();
            let s = Surface::with_options(cm, SurfaceOptions { max_depth: depth });
            // Points spiralling into every corner (down to 2^-30 of it), the corners
            // themselves and a few interior points: every depth below the stored one.
            let mut pts = Vec::new();
            for b in 0..s.num_base_quads() as u32 {
                for (cs, ct) in [(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0)] {
                    pts.push((b, cs, ct));
                    for k in 1..=30 {
                        let r = 0.5f64.powi(k) * 0.9;
                        let a = 0.37 * k as f64;
                        let (ds, dt) = (r * a.cos().abs(), r * a.sin().abs());
                        let s_ = if cs == 0.0 { ds } else { 1.0 - ds };
                        let t_ = if ct == 0.0 { dt } else { 1.0 - dt };
                        pts.push((b, s_, t_));
                    }
                }
                pts.push((b, 0.3, 0.01));
                pts.push((b, 0.5, 0.5));
            }
            let want: Vec<LimitSample> = pts
                .iter()
                .map(|&(b, u, v)| s.eval_base_uncached(BaseQuadId(b), u, v))
                .collect();
            let check = |order: &mut dyn Iterator<Item = usize>| {
                for i in order {
                    let (b, u, v) = pts[i];
                    let got = s.eval_base(BaseQuadId(b), u, v);
                    assert_eq!(got, want[i], "{shape} base {b} ({u},{v})");
                }
            };
            // Forward twice (computed, then read back), backward, and on other threads.
            check(&mut (0..pts.len()));
            check(&mut (0..pts.len()));
            check(&mut (0..pts.len()).rev());
            std::thread::scope(|sc| {
                sc.spawn(|| check(&mut (0..pts.len()).rev().step_by(3)));
                sc.spawn(|| check(&mut (0..pts.len()).step_by(7)));
            });
        }
    }

    /// Evaluations through a [`LeafHint`] (the descent skipped inside the last patch, the
    /// normal on demand) must be bit-identical to `eval_base`, for points inside the
    /// remembered patch, on its boundary, in other patches and other base quads.
    #[test]
    fn hinted_derivs_match_eval_base() {
        for shape in [
            "catmark_pole8",
            "catmark_nonquads",
            "catmark_edgecorner",
            "catmark_chaikin0",
            "catmark_cubes_infsharp",
        ] {
            let cm = crate::ControlMesh::load_obj(crate::test_data::shape(shape)).unwrap();
            let s = Surface::with_options(cm, SurfaceOptions { max_depth: 4 });
            let mut hint = LeafHint::default();
            for b in 0..s.num_base_quads() as u32 {
                // A path spiralling into corner (0, 0) and out again (every depth, the
                // corner itself, points on leaf boundaries), then across the quad.
                let mut pts: Vec<(f64, f64)> = (0..40)
                    .map(|k| {
                        let r = 0.8 * 0.7f64.powi(k);
                        let a = 0.41 * k as f64;
                        (r * a.cos().abs(), r * a.sin().abs())
                    })
                    .collect();
                pts.extend([(0.0, 0.0), (0.25, 0.125), (0.5, 0.5), (0.125, 0.0625)]);
                pts.extend((0..40).map(|k| (0.013 * k as f64, 0.7 - 0.011 * k as f64)));
                pts.push((1.2, -0.1));
                for (u, v) in pts {
                    let want = s.eval_base(BaseQuadId(b), u, v);
                    let got = s.eval_base_derivs(BaseQuadId(b), u, v, &mut hint);
                    assert_eq!(got.sample(), want, "{shape} base {b} ({u},{v})");
                    assert_eq!((got.p, got.du, got.dv), (want.p, want.du, want.dv));
                }
            }
        }
    }

    /// Submeshes and refinements take their twins from the parent's (`PolyMesh::from_twins`):
    /// every field must be what building the same faces from scratch gives, down a few
    /// levels of the patch trees of tagged and untagged shapes, with boundaries and n-gons.
    #[test]
    fn derived_topology_matches_rebuilt() {
        let rebuilt = |m: &PolyMesh| {
            let mut r = PolyMesh::new(
                m.positions.clone(),
                m.face_starts().to_vec(),
                m.half_edge_vertices().to_vec(),
                Check::Trusted,
            )
            .unwrap();
            let faces: Vec<FaceId> = (0..m.num_faces()).map(FaceId::from_idx).collect();
            let verts: Vec<(u32, u32)> = (0..m.num_vertices() as u32).map(|v| (v, v)).collect();
            r.inherit_tags(m, &faces, &verts);
            r
        };
        fn walk(m: &PolyMesh, q: FaceId, depth: u32, check: &dyn Fn(&PolyMesh)) {
            let sub = extract_submesh(m, q);
            check(&sub);
            let r = refine(&sub);
            check(&r);
            if depth > 0 {
                for c in 0..4 {
                    walk(&r, FaceId::from_idx(c), depth - 1, check);
                }
            }
        }
        for shape in [
            "catmark_nonquads",
            "catmark_edgecorner",
            "catmark_pole8",
            "catmark_cube_creases1",
            "catmark_cubes_infsharp",
            "catmark_chaikin0",
            "catmark_dart_edgecorner",
            "catmark_cube_corner4",
            "catmark_torus_creases0",
        ] {
            let cm = crate::ControlMesh::load_obj(crate::test_data::shape(shape)).unwrap();
            assert!(cm.mesh.is_clean(), "{shape}");
            let base = refine(&cm.mesh);
            base.assert_same(&rebuilt(&base));
            let check = |m: &PolyMesh| {
                assert!(m.is_clean());
                m.assert_same(&rebuilt(m));
            };
            for q in 0..base.num_faces().min(48) {
                walk(&base, FaceId::from_idx(q), 2, &check);
            }
        }
    }

    #[test]
    fn child_maps_invert() {
        for c in 0..4 {
            let (s, t) = (0.3, 0.1);
            let (a, b) = to_child(c, s, t);
            let (x, y) = from_child(c, a, b);
            assert!((x - s).abs() < 1e-15 && (y - t).abs() < 1e-15);
        }
    }
}
