//! Texel geometry and the texel neighbourhood graph.
//!
//! Every face domain carries an `nu x nv` map ([`crate::layout::TexelLayout`]: one N for
//! all faces, or per-face powers of two under `--texel-size`); texel (x, y) of domain d
//! sits at the domain point ((x+0.5)/nu, (y+0.5)/nv) and has the global index
//! `start(d) + y*nu + x` (the [`crate::io::exr::FaceMaps`] order). [`TexelGeometry`] holds the exact limit position and
//! normal of every texel centre.
//!
//! [`TexelGraph`] answers step 1 of coherent synthesis (Ying et al. 2001, §5): "collect all
//! samples which are no more than 2 samples away from x. In the interior of the texture map
//! this corresponds to a 5x5 neighbourhood ... near the boundary we also retrieve samples in
//! the texture map sharing the boundary ... near a corner we also collect adjacent samples
//! from all texture maps sharing the corner."
//!
//! How the cross-domain part is found, and why:
//! - **Edges**: every offset (a, b) of the 5x5 block that leaves the domain is followed with
//!   [`Surface::walk`], a straight move in parameter space that crosses domain edges with
//!   the exact rigid change of coordinates, and the nearest texel where it lands is taken.
//!   Walking (instead of a 3D radius search) follows the surface's topology, so parts of the
//!   surface that merely come close in space (a leg touching a belly) are never neighbours,
//!   and it needs no tolerance. The walk measures in the *starting* domain's parameter, so
//!   at Ptex T-junctions — an n-gon's sub-face spans half of the shared edge with N texels,
//!   so its texels are half as long along that edge as the quad's — a quad texel reaches
//!   every other sub-face texel and a sub-face texel may reach the same quad texel twice
//!   (deduplicated). Both are "texels within 2 of *my* samples", which is what matching
//!   needs: displacements are measured in 3D afterwards, not assumed. Domains of
//!   different resolution (`--texel-size`) meet the same way at any ratio: the walk is a
//!   step of the starting domain's texels, and lands on the nearest texel of the other
//!   domain's own grid.
//!   Walks that leave through an open boundary simply yield nothing. Many walks of a
//!   domain aim at the same cell beside one of its sides; where the crossing is rigid
//!   (see `Landings`) the first walk's texel is kept for the others: the same lists.
//! - **Corners**: straight walks around an extraordinary vertex (valence k != 4) reach only
//!   some of the k domains, because the parameter plane covers 4 right angles. So a texel
//!   in the 2x2 corner block of its domain also gets, from *every* domain sharing that corner
//!   vertex (found by rotating around the vertex in the refined base mesh), the corner texel,
//!   and the corner texel itself gets the whole 2x2 corner block of each. Corners that are
//!   T-junctions (a sub-face corner at the middle of a quad's edge) are no domain corner of
//!   the quad; the edge walks already cover them.
//!
//! Storage is compact: texels at least 2 away from every border ("interior") use the fixed
//! 5x5 block and store nothing; the others store their whole list (in-domain and foreign,
//! deduplicated, nearest first by 3D distance) in CSR arrays. The lists are built per domain
//! in parallel and concatenated in domain order, so the graph does not depend on the number
//! of threads.

use crate::layout::TexelLayout;
use glam::{DVec3, Vec3};
use rayon::prelude::*;
use std::sync::Arc;
use subdiv::{BaseQuadId, DomainId, DomainLocation, FaceId, LimitSample, Surface, VertexId};

/// Limit position and unit normal of every texel centre, f32 (the precision of
/// `geometry.exr`; displacements between neighbours are ~1e-3 of the model and keep ~4
/// significant digits, far more than matching needs).
#[derive(Clone, Debug, PartialEq)]
pub struct TexelGeometry {
    /// Where every texel is (per-face resolutions, global order).
    pub layout: Arc<TexelLayout>,
    /// Limit position per texel (global texel order).
    pub pos: Vec<Vec3>,
    /// Unit limit normal per texel.
    pub normal: Vec<Vec3>,
}

/// Every texel's exact (f64) unit normal of an `n`×`n` layout, held in the array that
/// becomes the texel frames ([`crate::synth::frames_from_slots`] overwrites each slot in
/// place with the frame's (v1, v2) in f32).
///
/// Why: the frames need the f64 normal (the f32 one of [`TexelGeometry`] would round
/// some frames differently), at the very texel centres the geometry pass evaluates, but
/// the field they also need is computed beside that pass and is ready later. Evaluating
/// the surface a second time for the frames was ~6% of a bunny run (N = 16, jump); a
/// separate array of f64 normals would add 24 B a texel to the set-up's memory. A
/// frame's slot (two f32 vectors) is exactly 24 B: it carries the normal's bits until
/// the field is there, so keeping them costs only allocating the frames earlier.
#[derive(Debug)]
pub struct FrameSlots {
    slots: Vec<[Vec3; 2]>,
    n: usize,
}

impl FrameSlots {
    /// `n`'s bits in one slot: each f64 as two f32 bit patterns (low half first). Only
    /// moved, never computed with, so any pattern (NaN ones too) comes back unchanged.
    #[inline]
    pub fn encode(n: DVec3) -> [Vec3; 2] {
        let halves = |x: f64| {
            let b = x.to_bits();
            (f32::from_bits(b as u32), f32::from_bits((b >> 32) as u32))
        };
        let ((a, b), (c, d), (e, f)) = (halves(n.x), halves(n.y), halves(n.z));
        [Vec3::new(a, b, c), Vec3::new(d, e, f)]
    }

    /// The normal [`Self::encode`] stored, bit for bit.
    #[inline]
    pub fn decode(slot: &[Vec3; 2]) -> DVec3 {
        let join =
            |lo: f32, hi: f32| f64::from_bits(lo.to_bits() as u64 | (hi.to_bits() as u64) << 32);
        let [a, b] = *slot;
        DVec3::new(join(a.x, a.y), join(a.z, b.x), join(b.y, b.z))
    }

    /// Texels per side of the (uniform) layout.
    pub fn resolution(&self) -> usize {
        self.n
    }

    /// The slots, in global texel order, each still holding its encoded normal.
    pub fn into_inner(self) -> Vec<[Vec3; 2]> {
        self.slots
    }
}

/// The limit samples at the texel centres of domain `id` with `nu` x `nv` texels, row by
/// row, into `buf` (reused between domains): the regular-grid evaluation for square
/// domains, point by point for the others (per-face resolutions differ per side).
pub fn eval_domain_texels(
    surface: &Surface,
    id: DomainId,
    nu: usize,
    nv: usize,
    buf: &mut Vec<LimitSample>,
) {
    if nu == nv {
        buf.resize(nu * nu, LimitSample::default());
        surface.eval_texels(id, nu, buf);
    } else {
        buf.clear();
        for y in 0..nv {
            let v = (y as f64 + 0.5) / nv as f64;
            for x in 0..nu {
                buf.push(surface.eval(id, (x as f64 + 0.5) / nu as f64, v));
            }
        }
    }
}

impl TexelGeometry {
    /// Evaluates all texel centres of `surface` at resolution `n` (uniform layout).
    pub fn compute(surface: &Surface, n: usize) -> Self {
        assert!(n >= 1, "resolution must be at least 1");
        Self::compute_layout(
            surface,
            Arc::new(TexelLayout::uniform(surface.num_domains(), n)),
        )
    }

    /// Evaluates all texel centres of `surface` in `layout` (in parallel, per domain).
    pub fn compute_layout(surface: &Surface, layout: Arc<TexelLayout>) -> Self {
        Self::evaluate(surface, layout, false).0
    }

    /// [`Self::compute_layout`] that also keeps every texel's exact normal, for the texel
    /// frames ([`FrameSlots`]): the same geometry.
    ///
    /// `layout` must be uniform (the frames of per-face resolutions are evaluated at
    /// `(x + 0.5) / n` rather than the geometry's `(x + 0.5) · (1 / n)`: not always the
    /// same point).
    pub fn compute_keeping_normals(
        surface: &Surface,
        layout: Arc<TexelLayout>,
    ) -> (Self, FrameSlots) {
        let n = layout
            .uniform_n()
            .expect("normals are kept for uniform layouts only");
        let (geometry, slots) = Self::evaluate(surface, layout, true);
        let slots = slots.expect("slots were asked for");
        (geometry, FrameSlots { slots, n })
    }

    /// All texel centres, per domain in parallel; with `keep_normals`, every exact normal
    /// encoded in a frame slot too ([`FrameSlots::encode`]).
    ///
    /// The arrays are written once, uninitialised before: filling them first (`vec![v;
    /// n]` of a non-primitive is a serial loop) was a serial pass over 24 B a texel (48 B
    /// keeping the normals) before the parallel one, on the texel side's critical path.
    fn evaluate(
        surface: &Surface,
        layout: Arc<TexelLayout>,
        keep_normals: bool,
    ) -> (Self, Option<Vec<[Vec3; 2]>>) {
        use std::mem::MaybeUninit;
        assert_eq!(layout.faces(), surface.num_domains());
        let total = layout.len();
        let mut pos: Vec<Vec3> = Vec::with_capacity(total);
        let mut normal: Vec<Vec3> = Vec::with_capacity(total);
        let mut slots: Vec<[Vec3; 2]> = Vec::with_capacity(if keep_normals { total } else { 0 });
        let slot_parts: Vec<Option<&mut [MaybeUninit<[Vec3; 2]>]>> = if keep_normals {
            let s = &mut slots.spare_capacity_mut()[..total];
            layout.split_mut(s, 1).into_iter().map(Some).collect()
        } else {
            (0..layout.faces()).map(|_| None).collect()
        };
        layout
            .split_mut(&mut pos.spare_capacity_mut()[..total], 1)
            .into_par_iter()
            .zip(layout.split_mut(&mut normal.spare_capacity_mut()[..total], 1))
            .zip(slot_parts)
            .enumerate()
            .for_each_init(
                Vec::new,
                |buf: &mut Vec<LimitSample>, (d, ((p, nrm), slot))| {
                    let (nu, nv) = layout.dims(d);
                    eval_domain_texels(surface, DomainId::from_idx(d), nu, nv, buf);
                    // Every element of the domain's part is written (the safety of
                    // `set_len` below).
                    assert_eq!(buf.len(), p.len());
                    for (i, s) in buf.iter().enumerate() {
                        p[i].write(s.p.as_vec3());
                        nrm[i].write(s.n.as_vec3());
                    }
                    if let Some(slot) = slot {
                        for (o, s) in slot.iter_mut().zip(buf.iter()) {
                            o.write(FrameSlots::encode(s.n));
                        }
                    }
                },
            );
        // SAFETY: the domains' parts cover 0..total (`split_mut`), and every part was
        // written in full (asserted above), within the capacities; `Vec3` needs no drop.
        unsafe {
            pos.set_len(total);
            normal.set_len(total);
            if keep_normals {
                slots.set_len(total);
            }
        }
        let geometry = Self {
            layout,
            pos,
            normal,
        };
        (geometry, keep_normals.then_some(slots))
    }

    /// Number of face domains F.
    pub fn faces(&self) -> usize {
        self.layout.faces()
    }

    /// Total number of texels.
    pub fn len(&self) -> usize {
        self.pos.len()
    }

    /// True when there are no texels.
    pub fn is_empty(&self) -> bool {
        self.pos.is_empty()
    }

    /// Domain of a global texel index.
    #[inline]
    pub fn domain_of(&self, t: usize) -> usize {
        self.layout.domain_of(t)
    }

    /// Every domain's adjacent in-domain texel distances (horizontal and vertical pairs),
    /// in domain order; empty for a domain of one texel.
    pub fn domain_spacings(&self, d: usize) -> Vec<f64> {
        let (nu, nv) = self.layout.dims(d);
        let mut v = Vec::with_capacity(2 * nu * nv);
        self.each_spacing(d, |x| v.push(x as f64));
        v
    }

    /// Calls `f` with [`Self::domain_spacings`]' distances of domain `d`, in its order.
    #[inline]
    fn each_spacing(&self, d: usize, mut f: impl FnMut(f32)) {
        let (nu, nv) = self.layout.dims(d);
        let p = &self.pos[self.layout.range(d)];
        for y in 0..nv {
            for x in 0..nu {
                let i = y * nu + x;
                if x + 1 < nu {
                    f(p[i].distance(p[i + 1]));
                }
                if y + 1 < nv {
                    f(p[i].distance(p[i + nu]));
                }
            }
        }
    }

    /// h: the median distance between centres of horizontally or vertically adjacent
    /// texels of the same domain — BRIEF's definition, used as the default `--scale` so
    /// that one texel step samples about one example pixel. With N = 1 there are no such
    /// pairs; then the median over domains of |∂P/∂u|/N and |∂P/∂v|/N at the centre (the
    /// same quantity to first order) is used.
    pub fn median_spacing(&self, surface: &Surface) -> f64 {
        if let Some(h) = self.median_of_spacings() {
            return h;
        }
        let mut d: Vec<f64> = (0..self.faces())
            .into_par_iter()
            .flat_map_iter(|f| {
                let s = surface.eval(DomainId::from_idx(f), 0.5, 0.5);
                [s.du.length(), s.dv.length()]
            })
            .collect();
        median(&mut d)
    }

    /// [`median`] of every domain's [`Self::domain_spacings`] (`None` when there are
    /// none), without holding them: they are 2 per texel (76 MB of f64 for the bunny at
    /// N = 16, whose allocation and selection were a fifth of the texel side's set-up).
    /// The distances are f32, so their order is that of [`total_key`]: a histogram of the
    /// keys' upper 16 bits finds the buckets of the middle ranks, and only the distances
    /// in those are gathered and sorted. The same value as [`median`], exactly; counts
    /// are integers, so it does not depend on the thread count either.
    fn median_of_spacings(&self) -> Option<f64> {
        const BUCKETS: usize = 1 << 16;
        const FACES_PER_JOB: usize = 512;
        let faces = self.faces();
        let jobs = faces.div_ceil(FACES_PER_JOB);
        let faces_of = move |j: usize| j * FACES_PER_JOB..((j + 1) * FACES_PER_JOB).min(faces);
        let hist = (0..jobs)
            .into_par_iter()
            .map(|j| {
                let mut h = vec![0u64; BUCKETS];
                for d in faces_of(j) {
                    self.each_spacing(d, |x| h[(total_key(x) >> 16) as usize] += 1);
                }
                h
            })
            .reduce(
                || vec![0u64; BUCKETS],
                |mut a, b| {
                    a.iter_mut().zip(&b).for_each(|(x, y)| *x += y);
                    a
                },
            );
        let n: u64 = hist.iter().sum();
        if n == 0 {
            return None;
        }
        // Bucket of the distance of rank k (ascending) and its rank inside the bucket.
        let locate = |k: u64| {
            let mut below = 0;
            for (b, &c) in hist.iter().enumerate() {
                if k < below + c {
                    return (b as u32, (k - below) as usize);
                }
                below += c;
            }
            unreachable!("rank {k} of {n}")
        };
        let (b_hi, r_hi) = locate(n / 2);
        let (b_lo, r_lo) = locate(if n.is_multiple_of(2) {
            n / 2 - 1
        } else {
            n / 2
        });
        let mut keys: Vec<u32> = (0..jobs)
            .into_par_iter()
            .flat_map_iter(|j| {
                let mut v = Vec::new();
                for d in faces_of(j) {
                    self.each_spacing(d, |x| {
                        let k = total_key(x);
                        if k >> 16 == b_lo || k >> 16 == b_hi {
                            v.push(k);
                        }
                    });
                }
                v
            })
            .collect();
        keys.sort_unstable();
        // Bucket b_lo's keys come first (b_lo <= b_hi).
        let lo_len = keys.partition_point(|k| k >> 16 == b_lo && b_lo != b_hi);
        let at = |b: u32, r: usize| {
            let k = if b == b_lo { keys[r] } else { keys[lo_len + r] };
            from_total_key(k) as f64
        };
        let hi = at(b_hi, r_hi);
        Some(if !n.is_multiple_of(2) {
            hi
        } else {
            0.5 * (at(b_lo, r_lo) + hi)
        })
    }
}

/// A u32 whose order is `f32::total_cmp`'s.
#[inline]
fn total_key(x: f32) -> u32 {
    let b = x.to_bits();
    if b >> 31 == 1 {
        !b
    } else {
        b | 1 << 31
    }
}

/// The f32 of a [`total_key`].
#[inline]
fn from_total_key(k: u32) -> f32 {
    f32::from_bits(if k >> 31 == 1 { k & !(1 << 31) } else { !k })
}

/// Median (mean of the two middle values for even counts); 0 for an empty slice.
pub fn median(v: &mut [f64]) -> f64 {
    let n = v.len();
    if n == 0 {
        return 0.0;
    }
    let (_, hi, _) = v.select_nth_unstable_by(n / 2, |a, b| a.total_cmp(b));
    let hi = *hi;
    if n % 2 == 1 {
        hi
    } else {
        let lo = v[..n / 2]
            .iter()
            .copied()
            .max_by(|a, b| a.total_cmp(b))
            .unwrap_or(hi);
        0.5 * (lo + hi)
    }
}

/// Offsets of the 5x5 block without the centre, nearest first (then by row, column):
/// the interior neighbourhood of §5 step 1.
pub const BLOCK: [(i32, i32); 24] = {
    // Sorted by (a²+b², b, a); written out because const sorting is awkward.
    [
        (0, -1),
        (-1, 0),
        (1, 0),
        (0, 1),
        (-1, -1),
        (1, -1),
        (-1, 1),
        (1, 1),
        (0, -2),
        (-2, 0),
        (2, 0),
        (0, 2),
        (-1, -2),
        (1, -2),
        (-2, -1),
        (2, -1),
        (-2, 1),
        (2, 1),
        (-1, 2),
        (1, 2),
        (-2, -2),
        (2, -2),
        (-2, 2),
        (2, 2),
    ]
};

/// Domain corners in (u, v), corner c = 0..3 (the base-quad corner order too).
const CORNER_UV: [(f64, f64); 4] = [(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0)];

/// The neighbourhood graph over all texels (see the module docs).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TexelGraph {
    /// Where every texel is.
    pub layout: Arc<TexelLayout>,
    /// CSR starts, one per texel + 1; interior texels have empty ranges.
    start: Vec<u32>,
    /// Concatenated neighbour lists of the border texels.
    list: Vec<u32>,
}

impl TexelGraph {
    /// Builds the graph (in parallel per domain; the result does not depend on the number
    /// of threads).
    ///
    /// In blocks of domains (~2^18 texels each): a block's lists are made in parallel and
    /// copied in parallel onto the end of the joined list, then dropped, so the lists are
    /// held twice only one block at a time. Making every domain's lists first and joining
    /// them after held them twice in full (bunny N = 16: ~230 MB more at the set-up's
    /// peak). The list grows by reallocation, which moves no bytes for an allocation this
    /// large (glibc remaps it).
    pub fn build(surface: &Surface, geom: &TexelGeometry) -> Self {
        const BLOCK_TEXELS: usize = 1 << 18;
        let layout = geom.layout.clone();
        let faces = layout.faces();
        assert_eq!(faces, surface.num_domains());
        let mut start = vec![0u32; layout.len() + 1];
        let mut list: Vec<u32> = Vec::new();
        let mut starts_rest = &mut start[1..];
        let mut d0 = 0;
        while d0 < faces {
            let mut d1 = d0;
            let mut texels = 0;
            while d1 < faces && (d1 == d0 || texels + layout.count(d1) <= BLOCK_TEXELS) {
                texels += layout.count(d1);
                d1 += 1;
            }
            let per_domain: Vec<(Vec<u32>, Vec<u32>)> = (d0..d1)
                .into_par_iter()
                .map(|d| domain_lists(surface, geom, d))
                .collect();
            let block: usize = per_domain.iter().map(|(_, l)| l.len()).sum();
            assert!(
                list.len() + block < u32::MAX as usize,
                "texel graph larger than 2^32 entries"
            );
            list.reserve(block);
            // Each domain's part written in place from its offsets, in parallel: joining
            // the lists (~40 B per texel at N = 16) on one thread was a serial stretch of
            // ~0.5 s on the bunny (5 M texels).
            let mut parts = Vec::with_capacity(d1 - d0);
            let mut base = list.len() as u32;
            let mut spare = &mut list.spare_capacity_mut()[..block];
            for (counts, l) in &per_domain {
                let (st, sr) = std::mem::take(&mut starts_rest).split_at_mut(counts.len());
                let (o, lr) = std::mem::take(&mut spare).split_at_mut(l.len());
                (starts_rest, spare) = (sr, lr);
                parts.push((st, o, counts, l, base));
                base += l.len() as u32;
            }
            parts.into_par_iter().for_each(|(st, o, counts, l, base)| {
                let mut last = base;
                for (out, c) in st.iter_mut().zip(counts) {
                    last += c;
                    *out = last;
                }
                for (o, &v) in o.iter_mut().zip(l) {
                    o.write(v);
                }
            });
            // SAFETY: the parts cover the block's `block` spare slots after `len` (their
            // lengths sum to it) and each was written in full (`o` and `l` have the same
            // length), within the capacity reserved above.
            unsafe { list.set_len(list.len() + block) };
            d0 = d1;
        }
        list.shrink_to_fit();
        Self {
            layout,
            start,
            list,
        }
    }

    /// Total number of texels.
    pub fn len(&self) -> usize {
        self.start.len() - 1
    }

    /// True when there are no texels.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Whether texel (x, y) of a domain of `nu`×`nv` texels is at least 2 texels away from
    /// every border of its domain (its neighbourhood is the plain 5x5 block).
    #[inline]
    pub fn is_interior(nu: usize, nv: usize, x: usize, y: usize) -> bool {
        x >= 2 && y >= 2 && x + 2 < nu && y + 2 < nv
    }

    /// Appends the neighbours of texel `t` to `out`, nearest first.
    #[inline]
    pub fn neighbours(&self, t: usize, out: &mut Vec<u32>) {
        let (s, e) = (self.start[t] as usize, self.start[t + 1] as usize);
        if s == e {
            // Interior (border texels always have neighbours: at least their own block's).
            let (d, x, y) = self.layout.coords(t);
            let (nu, nv) = self.layout.dims(d);
            if Self::is_interior(nu, nv, x, y) {
                let t = t as i64;
                let nu = nu as i64;
                out.extend(
                    BLOCK
                        .iter()
                        .map(|&(a, b)| (t + a as i64 + b as i64 * nu) as u32),
                );
            }
        } else {
            out.extend_from_slice(&self.list[s..e]);
        }
    }

    /// The explicit (border) list of texel `t`; empty for interior texels.
    pub fn border_list(&self, t: usize) -> &[u32] {
        &self.list[self.start[t] as usize..self.start[t + 1] as usize]
    }

    /// For every domain, the other domains some of its texels are neighbours of, or that
    /// have texels listing it (symmetric, sorted). Two domains not related here can be
    /// synthesized at the same time: neither reads the other's texels.
    pub fn domain_conflicts(&self) -> Vec<Vec<u32>> {
        let l = &self.layout;
        let mut out: Vec<Vec<u32>> = (0..l.faces())
            .into_par_iter()
            .map(|d| {
                let r = l.range(d);
                // A domain names a handful of others, in runs: a linear set beats sorting
                // its ~10 entries per border texel.
                let mut v: Vec<u32> = Vec::with_capacity(16);
                let mut last = d as u32;
                for &t in &self.list[self.start[r.start] as usize..self.start[r.end] as usize] {
                    // Most entries are the domain's own texels: a range test, not a
                    // division (or a search with per-face resolutions), for those.
                    if r.contains(&(t as usize)) {
                        last = d as u32;
                        continue;
                    }
                    let e = l.domain_of(t as usize) as u32;
                    if e != last && e as usize != d && !v.contains(&e) {
                        v.push(e);
                    }
                    last = e;
                }
                v.sort_unstable();
                v
            })
            .collect();
        // Symmetrise: T-junctions make the texel relation one-sided.
        let pairs: Vec<(u32, u32)> = out
            .iter()
            .enumerate()
            .flat_map(|(d, v)| v.iter().map(move |&e| (e, d as u32)))
            .collect();
        for (e, d) in pairs {
            out[e as usize].push(d);
        }
        for v in &mut out {
            v.sort_unstable();
            v.dedup();
        }
        out
    }

    /// Memory held by the graph, in bytes.
    pub fn heap_bytes(&self) -> usize {
        4 * (self.start.len() + self.list.len())
    }
}

/// The texels' *edge* neighbours: the 4-neighbourhood of the texel grid, continued across
/// domain edges by the same straight walks as [`TexelGraph`] (so across T-junctions,
/// around extraordinary corners and between domains of different resolution too),
/// symmetric, CSR, each list ascending.
///
/// Floods and seams run on it: a flood over nearest-first lists can jump diagonally, and
/// a cut over them finds domain borders cheaper to cut along wherever the lists on the
/// two sides of a border are not symmetric (measured on the double torus: 3x as many
/// cut pairs on domain borders as inside, seam ratio 1.28). Between a coarse and a k
/// times finer domain, the coarse texel's step lands on one fine texel, but every fine
/// border texel's step lands on a coarse one, and symmetry adds the pair: each coarse
/// border texel ends up joined to the k fine texels along it.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct EdgeGraph {
    /// Per texel: [`EdgeGraph::GRID`] | its domain's row stride when its edges are its
    /// four grid neighbours (every interior texel but those a finer neighbour's walks
    /// reach), else where its list starts in `lists`.
    entry: Vec<u32>,
    /// The listed texels' edges, each list its length first, then the neighbours
    /// ascending. Only border texels (and the few interior ones that walks from a coarser
    /// neighbour land on) have one: 4 B per texel plus ~5 B per border texel, where a list
    /// for every texel took 20 B per texel (issue 14 item 6, memory per texel).
    lists: Vec<u32>,
}

/// One texel's edge neighbours, ascending ([`EdgeGraph::of`]): a slice of the graph's
/// lists, or the four grid neighbours computed from the row stride.
#[derive(Clone, Copy, Debug)]
pub enum Edges<'a> {
    /// An interior texel's neighbours: up, left, right, down.
    Grid([u32; 4]),
    /// A listed texel's neighbours.
    Listed(&'a [u32]),
}

impl std::ops::Deref for Edges<'_> {
    type Target = [u32];
    #[inline]
    fn deref(&self) -> &[u32] {
        match self {
            Edges::Grid(a) => a,
            Edges::Listed(s) => s,
        }
    }
}

impl<'a> IntoIterator for Edges<'a> {
    type Item = u32;
    type IntoIter = EdgesIter<'a>;
    #[inline]
    fn into_iter(self) -> EdgesIter<'a> {
        match self {
            Edges::Grid(a) => EdgesIter::Grid(a.into_iter()),
            Edges::Listed(s) => EdgesIter::Listed(s.iter().copied()),
        }
    }
}

/// The neighbours of [`Edges`] by value.
#[derive(Clone, Debug)]
pub enum EdgesIter<'a> {
    Grid(std::array::IntoIter<u32, 4>),
    Listed(std::iter::Copied<std::slice::Iter<'a, u32>>),
}

impl Iterator for EdgesIter<'_> {
    type Item = u32;
    #[inline]
    fn next(&mut self) -> Option<u32> {
        match self {
            EdgesIter::Grid(i) => i.next(),
            EdgesIter::Listed(i) => i.next(),
        }
    }
}

impl EdgeGraph {
    /// Flag of an entry that holds a row stride (a texel with its four grid neighbours).
    const GRID: u32 = 1 << 31;

    /// Builds the graph (in parallel per domain; independent of the thread count).
    ///
    /// Within a domain the grid's 4-neighbourhood is symmetric by itself, so only the
    /// walks across domain edges (from border texels) are collected and symmetrised; an
    /// interior texel that no walk reaches keeps its row stride instead of a list. The
    /// peak is the graph itself plus the border edges (it was 16 pairs of 8 B per texel,
    /// twice: 128 B per texel at the graph stage, issue 14 item 6).
    pub fn build(surface: &Surface, geom: &TexelGeometry) -> Self {
        let layout = &geom.layout;
        let faces = layout.faces();
        let total = geom.len();
        // Walked edges (t, u) from the border texels, both ways round. With per-face
        // resolutions u may be an interior texel of a finer neighbour; the lists below look
        // the walked edges up for every texel.
        let walked: Vec<Vec<(u32, u32)>> = (0..faces)
            .into_par_iter()
            .map(|d| {
                let (nu, nv) = layout.dims(d);
                let (iu, iv) = (1.0 / nu as f64, 1.0 / nv as f64);
                let base = layout.start(d);
                let mut out = Vec::new();
                for y in 0..nv {
                    for x in 0..nu {
                        if x > 0 && y > 0 && x + 1 < nu && y + 1 < nv {
                            continue;
                        }
                        let t = (base + y * nu + x) as u32;
                        for (a, b) in [(1i64, 0i64), (-1, 0), (0, 1), (0, -1)] {
                            let (xa, yb) = (x as i64 + a, y as i64 + b);
                            if (0..nu as i64).contains(&xa) && (0..nv as i64).contains(&yb) {
                                continue;
                            }
                            let from = DomainLocation {
                                domain: DomainId::from_idx(d),
                                u: (x as f64 + 0.5) * iu,
                                v: (y as f64 + 0.5) * iv,
                            };
                            if let Some(to) = surface.walk(from, a as f64 * iu, b as f64 * iv) {
                                let u = layout.texel_at(to.domain.idx(), to.u, to.v) as u32;
                                if u != t {
                                    out.push((t, u));
                                    out.push((u, t));
                                }
                            }
                        }
                    }
                }
                out
            })
            .collect();
        let mut extra: Vec<(u32, u32)> = walked.into_iter().flatten().collect();
        extra.par_sort_unstable();
        extra.dedup();
        // Per domain (in place in `entry`, lists apart): a texel's grid neighbours and its
        // walked edges, ascending, unique. `lo` walks `extra` (sorted by texel) along the
        // domain's texels, which are visited in order.
        let mut entry = vec![0u32; total];
        let per_domain: Vec<Vec<u32>> = layout
            .split_mut(&mut entry, 1)
            .into_par_iter()
            .enumerate()
            .map(|(d, out)| {
                let (nu, nv) = layout.dims(d);
                let base = layout.start(d);
                let mut lo = extra.partition_point(|p| (p.0 as usize) < base);
                let mut lists = Vec::new();
                let mut buf = Vec::with_capacity(16);
                for (i, o) in out.iter_mut().enumerate() {
                    let t = base + i;
                    let (x, y) = (i % nu, i / nu);
                    let walked = extra.get(lo).is_some_and(|p| p.0 as usize == t);
                    if !walked && x > 0 && y > 0 && x + 1 < nu && y + 1 < nv {
                        *o = Self::GRID | nu as u32;
                        continue;
                    }
                    buf.clear();
                    for (a, b) in [(1i64, 0i64), (-1, 0), (0, 1), (0, -1)] {
                        let (xa, yb) = (x as i64 + a, y as i64 + b);
                        if (0..nu as i64).contains(&xa) && (0..nv as i64).contains(&yb) {
                            buf.push((base + yb as usize * nu + xa as usize) as u32);
                        }
                    }
                    while extra.get(lo).is_some_and(|p| p.0 as usize == t) {
                        buf.push(extra[lo].1);
                        lo += 1;
                    }
                    buf.sort_unstable();
                    buf.dedup();
                    // Local offset; the domain's base in `lists` is added below.
                    *o = lists.len() as u32;
                    lists.push(buf.len() as u32);
                    lists.extend_from_slice(&buf);
                }
                lists
            })
            .collect();
        let mut offsets = Vec::with_capacity(faces + 1);
        let mut sum = 0usize;
        for l in &per_domain {
            offsets.push(sum);
            sum += l.len();
        }
        assert!(
            sum < Self::GRID as usize,
            "edge graph lists larger than 2^31 entries"
        );
        layout
            .split_mut(&mut entry, 1)
            .into_par_iter()
            .enumerate()
            .for_each(|(d, out)| {
                for o in out.iter_mut().filter(|o| **o & Self::GRID == 0) {
                    *o += offsets[d] as u32;
                }
            });
        let lists = per_domain.concat();
        Self { entry, lists }
    }

    /// The edge neighbours of texel `t`, ascending.
    #[inline]
    pub fn of(&self, t: usize) -> Edges<'_> {
        let e = self.entry[t];
        if e & Self::GRID != 0 {
            let (t, nu) = (t as u32, e & !Self::GRID);
            Edges::Grid([t - nu, t - 1, t + 1, t + nu])
        } else {
            let s = e as usize;
            let n = self.lists[s] as usize;
            Edges::Listed(&self.lists[s + 1..s + 1 + n])
        }
    }

    /// Number of texels.
    pub fn len(&self) -> usize {
        self.entry.len()
    }

    /// No texels.
    pub fn is_empty(&self) -> bool {
        self.entry.is_empty()
    }

    /// Bytes held.
    pub fn heap_bytes(&self) -> usize {
        4 * (self.entry.len() + self.lists.len())
    }
}

/// Where the 5x5 block's walks out of one domain land ([`domain_lists`]), found once per
/// landing cell instead of once per walk.
///
/// Offset (a, b) of texel (x, y) aims at the cell (X, Y) = (x + a, y + b) of the domain's
/// texel lattice. When exactly one of X, Y is outside 0..N (a cell beside one side, not
/// diagonally off a corner), every straight walk to it from a texel centre of the domain
/// crosses that one side, strictly between its corners (the other coordinate stays within
/// the centres' range), and ends at most 1.5 texels deep in the neighbour, inside it for
/// N ≥ 2. Where the neighbour is of the same kind (two quads: whole edges; two sub-faces:
/// whole half-edges or sibling edges) and, with one N everywhere, the same resolution, the
/// change of coordinates is rigid and maps the lattice of texel centres onto the
/// neighbour's: in exact arithmetic every such walk ends at the same texel centre, half a
/// texel from any texel border, so the rounded walk's nearest texel is that texel whichever
/// centre it started from. The first walk to the cell is made as before and its texel
/// kept for the others. Off a corner, across a T-junction (quad and sub-face: the
/// parameter scales by 2, centres land on texel borders), with per-face resolutions or
/// N < 4 every walk is made. An open boundary (no neighbour) is the same for every walk
/// across that side: kept as none.
struct Landings {
    /// One N, ≥ 4, for the cells to be kept.
    n: Option<usize>,
    d: usize,
    quad: bool,
    /// Per cell (X + 2, Y + 2) of the (N + 4)² lattice around the domain.
    cells: Vec<Cell>,
}

/// What [`Landings`] knows of the walks to one cell.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Cell {
    /// No walk to it yet.
    Unknown,
    /// Every walk leaves the surface through an open boundary.
    Open,
    /// Walks to it may land on different texels (another kind of neighbour): walk each.
    Walk,
    /// Every walk to it lands on this texel.
    Texel(u32),
}

impl Landings {
    fn new(surface: &Surface, layout: &TexelLayout, d: usize) -> Self {
        let n = layout.uniform_n().filter(|&n| n >= 4);
        let quad = matches!(
            surface.domain(DomainId::from_idx(d)),
            subdiv::Domain::Quad { .. }
        );
        let cells = n.map_or_else(Vec::new, |n| vec![Cell::Unknown; (n + 4) * (n + 4)]);
        Self { n, d, quad, cells }
    }

    /// The texel the walk from texel `(x, y)` by `(a, b)` texels lands on (`None`: out
    /// through an open boundary), as [`Surface::walk`] and [`TexelLayout::texel_at`] give it.
    #[inline]
    fn texel(
        &mut self,
        surface: &Surface,
        layout: &TexelLayout,
        (x, y): (usize, usize),
        (a, b): (i32, i32),
    ) -> Option<u32> {
        let walk = || {
            let (nu, nv) = layout.dims(self.d);
            let (iu, iv) = (1.0 / nu as f64, 1.0 / nv as f64);
            let from = DomainLocation {
                domain: DomainId::from_idx(self.d),
                u: (x as f64 + 0.5) * iu,
                v: (y as f64 + 0.5) * iv,
            };
            surface.walk(from, a as f64 * iu, b as f64 * iv).map(|to| {
                (
                    to.domain,
                    layout.texel_at(to.domain.idx(), to.u, to.v) as u32,
                )
            })
        };
        let Some(n) = self.n else {
            return walk().map(|(_, t)| t);
        };
        let (cx, cy) = (x as i64 + a as i64, y as i64 + b as i64);
        let inside = |c: i64| (0..n as i64).contains(&c);
        if inside(cx) == inside(cy)
            || !(-2..n as i64 + 2).contains(&cx)
            || !(-2..n as i64 + 2).contains(&cy)
        {
            return walk().map(|(_, t)| t);
        }
        let k = (cy + 2) as usize * (n + 4) + (cx + 2) as usize;
        match self.cells[k] {
            Cell::Unknown => {
                let r = walk();
                self.cells[k] = match r {
                    None => Cell::Open,
                    Some((e, t)) => {
                        let same =
                            matches!(surface.domain(e), subdiv::Domain::Quad { .. }) == self.quad;
                        if same {
                            Cell::Texel(t)
                        } else {
                            Cell::Walk
                        }
                    }
                };
                r.map(|(_, t)| t)
            }
            Cell::Open => None,
            Cell::Walk => walk().map(|(_, t)| t),
            Cell::Texel(t) => Some(t),
        }
    }
}

/// Per-texel counts and the concatenated lists of domain `d` (interior texels: count 0).
fn domain_lists(surface: &Surface, geom: &TexelGeometry, d: usize) -> (Vec<u32>, Vec<u32>) {
    domain_lists_with(
        surface,
        geom,
        d,
        &mut Landings::new(surface, &geom.layout, d),
    )
}

/// [`domain_lists`] with the walks' landings found by `landings`.
fn domain_lists_with(
    surface: &Surface,
    geom: &TexelGeometry,
    d: usize,
    landings: &mut Landings,
) -> (Vec<u32>, Vec<u32>) {
    let layout = &geom.layout;
    let (nu, nv) = layout.dims(d);
    let base = layout.start(d);
    let fans: [Vec<(usize, usize)>; 4] = std::array::from_fn(|c| corner_fan(surface, d, c));
    let mut counts = vec![0u32; nu * nv];
    // ~24 neighbours per border texel (a few more at corners).
    let border = nu * nv - nu.saturating_sub(4) * nv.saturating_sub(4);
    let mut list = Vec::with_capacity(border * 25);
    let mut buf: Vec<u32> = Vec::with_capacity(64);
    let mut keyed: Vec<u64> = Vec::with_capacity(64);
    for y in 0..nv {
        for x in 0..nu {
            if TexelGraph::is_interior(nu, nv, x, y) {
                continue;
            }
            let t = base + y * nu + x;
            buf.clear();
            for &(a, b) in &BLOCK {
                let (xa, yb) = (x as i64 + a as i64, y as i64 + b as i64);
                if (0..nu as i64).contains(&xa) && (0..nv as i64).contains(&yb) {
                    buf.push((base + yb as usize * nu + xa as usize) as u32);
                    continue;
                }
                if let Some(u) = landings.texel(surface, layout, (x, y), (a, b)) {
                    buf.push(u);
                }
            }
            // Corner fans: see the module docs.
            for (c, fan) in fans.iter().enumerate() {
                let (ci, cj) = corner_offsets(c, x, y, nu, nv);
                if ci > 1 || cj > 1 {
                    continue;
                }
                let whole_block = ci == 0 && cj == 0;
                for &(e, ec) in fan {
                    let (eu, ev) = layout.dims(e);
                    for j in 0..2usize.min(ev) {
                        for i in 0..2usize.min(eu) {
                            if !whole_block && (i > 0 || j > 0) {
                                continue;
                            }
                            let (ex, ey) = corner_texel(ec, i, j, eu, ev);
                            buf.push(layout.index(e, ex, ey) as u32);
                        }
                    }
                }
            }
            // Nearest first, ties by index, each neighbour once: a repeated index has the
            // same key, so the repeats end up side by side and are dropped after the one
            // sort; the kept keys are distinct (the indices are), so any sort gives this
            // one order. The key is one u64, the distance's `total_key` above the index:
            // its integer order is (distance by `f32::total_cmp`, index).
            let p = geom.pos[t];
            keyed.clear();
            keyed.extend(buf.iter().filter(|&&u| u as usize != t).map(|&u| {
                let d2 = p.distance_squared(geom.pos[u as usize]);
                (total_key(d2) as u64) << 32 | u as u64
            }));
            keyed.sort_unstable();
            keyed.dedup();
            counts[y * nu + x] = keyed.len() as u32;
            list.extend(keyed.iter().map(|&k| k as u32));
        }
    }
    (counts, list)
}

/// Distances in texels (0 = the corner texel) of texel (x, y) from corner `c` of a
/// domain of `nu`×`nv` texels.
#[inline]
fn corner_offsets(c: usize, x: usize, y: usize, nu: usize, nv: usize) -> (usize, usize) {
    let fx = if c == 1 || c == 2 { nu - 1 - x } else { x };
    let fy = if c >= 2 { nv - 1 - y } else { y };
    (fx, fy)
}

/// The texel (i, j) texels away from corner `c` of a domain of `nu`×`nv` texels.
#[inline]
fn corner_texel(c: usize, i: usize, j: usize, nu: usize, nv: usize) -> (usize, usize) {
    let i = i.min(nu - 1);
    let j = j.min(nv - 1);
    let x = if c == 1 || c == 2 { nu - 1 - i } else { i };
    let y = if c >= 2 { nv - 1 - j } else { j };
    (x, y)
}

/// Every (domain, corner) whose corner is the same surface point as corner `c` of domain
/// `d`, excluding (d, c) itself. Found by rotating around the corresponding vertex of the
/// refined base mesh; base-quad corners that are not domain corners (T-junctions, quad
/// centres) are skipped.
pub fn corner_fan(surface: &Surface, d: usize, c: usize) -> Vec<(usize, usize)> {
    let (cu, cv) = CORNER_UV[c];
    let (b, s, t, _) = surface.domain_to_base(DomainId::from_idx(d), cu, cv);
    let bc = corner_of(s, t).expect("a domain corner is a base-quad corner");
    let bv = surface.base.face_vertices(FaceId(b.0))[bc];
    let mut out = Vec::new();
    for h in surface.base.outgoing(VertexId(bv)) {
        let f = surface.base.face_of(h);
        let k = (h - surface.base.face_he(f)) as usize;
        let (s2, t2) = CORNER_UV[k];
        let loc = surface.base_to_domain(BaseQuadId(f.0), s2, t2);
        if let Some(c2) = corner_of(loc.u, loc.v) {
            let e = loc.domain.idx();
            if (e, c2) != (d, c) {
                out.push((e, c2));
            }
        }
    }
    out.sort_unstable();
    out.dedup();
    out
}

/// The corner index of a parameter point that is a corner of [0,1]², if it is one.
fn corner_of(u: f64, v: f64) -> Option<usize> {
    let near = |a: f64, b: f64| (a - b).abs() < 1e-9;
    let iu = if near(u, 0.0) {
        0
    } else if near(u, 1.0) {
        1
    } else {
        return None;
    };
    let iv = if near(v, 0.0) {
        0
    } else if near(v, 1.0) {
        1
    } else {
        return None;
    };
    Some(match (iu, iv) {
        (0, 0) => 0,
        (1, 0) => 1,
        (1, 1) => 2,
        _ => 3,
    })
}

/// For every domain, the domains across its edges (sorted): the adjacency the
/// breadth-first synthesis order walks (§4: "we iterate over the surface texture maps in
/// breadth-first order").
pub fn domain_edge_adjacency(surface: &Surface) -> Vec<Vec<u32>> {
    (0..surface.num_domains())
        .map(|d| {
            let mut v = Vec::new();
            for b in domain_base_quads(surface, d) {
                for e in 0..4 {
                    if let Some((nb, _)) = surface.base_neighbor(b, e) {
                        let other = surface.base_to_domain(nb, 0.5, 0.5).domain.idx();
                        if other != d {
                            v.push(other as u32);
                        }
                    }
                }
            }
            v.sort_unstable();
            v.dedup();
            v
        })
        .collect()
}

/// The base quads a domain is made of (4 for a quad, 1 for a sub-face).
fn domain_base_quads(surface: &Surface, d: usize) -> Vec<BaseQuadId> {
    match surface.domain(DomainId::from_idx(d)) {
        subdiv::Domain::Quad { face } => {
            let h = surface.control.mesh.face_he(face);
            (0..4).map(|c| BaseQuadId(h + c)).collect()
        }
        subdiv::Domain::SubFace { face, corner } => {
            vec![BaseQuadId(surface.control.mesh.face_he(face) + corner)]
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::DVec3;
    use subdiv::ControlMesh;

    fn grid(n: usize) -> Surface {
        Surface::new(ControlMesh::grid(n))
    }

    fn cube() -> Surface {
        Surface::new(ControlMesh::cuboid(DVec3::ZERO, DVec3::ONE))
    }

    fn shared(path: &str) -> Surface {
        // $SURFSYNTH_SHARED when set, as the integration tests (tests/common).
        let p = std::env::var_os("SURFSYNTH_SHARED")
            .map(std::path::PathBuf::from)
            .unwrap_or_else(|| std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared"))
            .join("data/meshes")
            .join(path);
        Surface::load_obj(p).unwrap()
    }

    /// A normal comes out of its frame slot bit for bit, whatever the bits: ordinary
    /// unit vectors, signed zeros, subnormals, and halves that are f32 NaN patterns
    /// (signalling ones too), which are only moved, never computed with.
    #[test]
    fn frame_slots_keep_every_bit() {
        let specials = [
            0.0,
            -0.0,
            f64::MIN_POSITIVE / 3.0,
            f64::from_bits(0x7fa0_0000_7f80_0001),
            f64::from_bits(0xffc0_0001_ff80_0002),
            f64::NAN,
            -1.0,
            0.577_350_269_189_625_8,
        ];
        let mut x = 0x9e37_79b9_7f4a_7c15u64;
        let mut next = || {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            x
        };
        let mut vs: Vec<DVec3> = specials
            .iter()
            .flat_map(|&a| specials.iter().map(move |&b| DVec3::new(a, b, -a)))
            .collect();
        vs.extend((0..1000).map(|_| {
            DVec3::new(
                f64::from_bits(next()),
                f64::from_bits(next()),
                f64::from_bits(next()),
            )
        }));
        vs.extend((0..1000).map(|i| DVec3::new(i as f64, 1.0, 0.3).normalize()));
        for v in vs {
            let slot = FrameSlots::encode(v);
            let back = FrameSlots::decode(&std::hint::black_box(slot));
            assert_eq!(
                back.to_array().map(f64::to_bits),
                v.to_array().map(f64::to_bits)
            );
        }
    }

    /// The slots hold the normals of the texel evaluation (the f64 ones the f32
    /// geometry rounds), and the geometry is `compute_layout`'s.
    #[test]
    fn kept_normals_are_the_evaluated_ones() {
        for s in [cube(), grid(2)] {
            for n in [1, 4] {
                let layout = Arc::new(TexelLayout::uniform(s.num_domains(), n));
                let (g, slots) = TexelGeometry::compute_keeping_normals(&s, layout.clone());
                assert_eq!(g, TexelGeometry::compute_layout(&s, layout));
                assert_eq!(slots.resolution(), n);
                let slots = slots.into_inner();
                let mut buf = vec![LimitSample::default(); n * n];
                for d in 0..s.num_domains() {
                    s.eval_texels(DomainId::from_idx(d), n, &mut buf);
                    for (i, e) in buf.iter().enumerate() {
                        let t = d * n * n + i;
                        assert_eq!(FrameSlots::decode(&slots[t]), e.n);
                        assert_eq!(g.normal[t], e.n.as_vec3());
                    }
                }
            }
        }
    }

    /// The edge graph as it was first built (every edge as two pairs, sorted): the
    /// in-place build must give the same lists.
    fn edge_graph_by_pairs(surface: &Surface, geom: &TexelGeometry) -> Vec<Vec<u32>> {
        let layout = &geom.layout;
        let mut all = Vec::new();
        for d in 0..layout.faces() {
            let (nu, nv) = layout.dims(d);
            let (iu, iv) = (1.0 / nu as f64, 1.0 / nv as f64);
            let base = layout.start(d);
            for y in 0..nv {
                for x in 0..nu {
                    let t = (base + y * nu + x) as u32;
                    for (a, b) in [(1i64, 0i64), (-1, 0), (0, 1), (0, -1)] {
                        let (xa, yb) = (x as i64 + a, y as i64 + b);
                        let u = if (0..nu as i64).contains(&xa) && (0..nv as i64).contains(&yb) {
                            (base + yb as usize * nu + xa as usize) as u32
                        } else {
                            let from = DomainLocation {
                                domain: DomainId::from_idx(d),
                                u: (x as f64 + 0.5) * iu,
                                v: (y as f64 + 0.5) * iv,
                            };
                            match surface.walk(from, a as f64 * iu, b as f64 * iv) {
                                Some(to) => layout.texel_at(to.domain.idx(), to.u, to.v) as u32,
                                None => continue,
                            }
                        };
                        if u != t {
                            all.push((t, u));
                            all.push((u, t));
                        }
                    }
                }
            }
        }
        all.sort_unstable();
        all.dedup();
        let mut lists = vec![Vec::new(); geom.len()];
        for (a, b) in all {
            lists[a as usize].push(b);
        }
        lists
    }

    /// Every texel's list of `e`.
    fn lists_of(e: &EdgeGraph) -> Vec<Vec<u32>> {
        (0..e.len()).map(|t| e.of(t).to_vec()).collect()
    }

    #[test]
    fn edge_graph_is_the_symmetric_pair_graph() {
        // Triangles and an n-gon (T-junctions between quad and n-gon domains), an open
        // grid (boundaries), the cube (valence-3 corners); N = 1 (every texel a corner).
        let fan = ControlMesh::parse_obj(
            "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 2 0 0\nv 2 1 0\nv 0.5 0.5 1\n\
             f 1 2 7\nf 2 3 7\nf 3 4 7\nf 4 1 7\nf 2 5 6 3\n",
        )
        .unwrap();
        for (s, ns) in [
            (Surface::new(fan), &[1usize, 2, 5][..]),
            (grid(3), &[1, 4][..]),
            (cube(), &[1, 3, 8][..]),
        ] {
            for &n in ns {
                let g = TexelGeometry::compute(&s, n);
                assert_eq!(
                    lists_of(&EdgeGraph::build(&s, &g)),
                    edge_graph_by_pairs(&s, &g),
                    "N = {n}"
                );
            }
            // Per-face resolutions (ratios up to 8:1, non-square domains).
            let g = TexelGeometry::compute_layout(&s, mixed_layout(&s));
            assert_eq!(
                lists_of(&EdgeGraph::build(&s, &g)),
                edge_graph_by_pairs(&s, &g),
                "per-face"
            );
        }
    }

    /// Per-face resolutions over `s`: ratios up to 8:1 between neighbours, non-square
    /// domains.
    fn mixed_layout(s: &Surface) -> Arc<TexelLayout> {
        let res = (0..s.num_domains())
            .map(|d| crate::layout::Resolution::new((d % 4) as u8, ((d / 2) % 4) as u8).unwrap())
            .collect();
        Arc::new(TexelLayout::per_face(res))
    }

    #[test]
    fn median_is_exact() {
        assert_eq!(median(&mut [3.0, 1.0, 2.0]), 2.0);
        assert_eq!(median(&mut [4.0, 1.0, 3.0, 2.0]), 2.5);
        assert_eq!(median(&mut []), 0.0);
    }

    #[test]
    fn median_spacing_is_the_median_of_all_spacings() {
        // Odd and even counts, one bucket or several (the cube's spacings vary little,
        // Spot's a lot), per-face resolutions, and the N = 1 fallback.
        let by_list = |g: &TexelGeometry| {
            let mut d: Vec<f64> = (0..g.faces()).flat_map(|f| g.domain_spacings(f)).collect();
            median(&mut d)
        };
        for (s, ns) in [
            (cube(), &[2usize, 3, 8][..]),
            (shared("spot_control_mesh.obj"), &[2, 5][..]),
        ] {
            for &n in ns {
                let g = TexelGeometry::compute(&s, n);
                assert_eq!(
                    g.median_spacing(&s).to_bits(),
                    by_list(&g).to_bits(),
                    "N = {n}"
                );
            }
            let g = TexelGeometry::compute_layout(&s, mixed_layout(&s));
            assert_eq!(
                g.median_spacing(&s).to_bits(),
                by_list(&g).to_bits(),
                "per-face"
            );
            let g = TexelGeometry::compute(&s, 1);
            assert!(g.median_of_spacings().is_none());
            assert!(g.median_spacing(&s) > 0.0);
        }
        for x in [0.0f32, -0.0, 1e-30, 2.5, -3.0, f32::INFINITY] {
            assert_eq!(from_total_key(total_key(x)).to_bits(), x.to_bits());
        }
        assert!(total_key(-1.0) < total_key(-0.0) && total_key(-0.0) < total_key(0.0));
        assert!(total_key(0.0) < total_key(1e-30) && total_key(1e-30) < total_key(2.0));
    }

    #[test]
    fn interior_grid_texel_has_the_5x5_block_across_domains() {
        // On a flat 4x4 grid, a texel next to the edge between domains 5 and 6 must see the
        // same 24 texels, at the same 3D offsets, as an interior texel.
        let s = grid(4);
        let n = 8;
        let g = TexelGeometry::compute(&s, n);
        let graph = TexelGraph::build(&s, &g);
        let t = 5 * n * n + 4 * n + (n - 1); // domain 5, x = N-1, y = 4
        let mut v = Vec::new();
        graph.neighbours(t, &mut v);
        assert_eq!(v.len(), 24);
        let h = g.pos[t].distance(g.pos[t - 1]);
        let mut offs: Vec<(i32, i32)> = v
            .iter()
            .map(|&j| {
                let d = (g.pos[j as usize] - g.pos[t]) / h;
                (d.x.round() as i32, d.y.round() as i32)
            })
            .collect();
        offs.sort_unstable();
        let mut want: Vec<(i32, i32)> = BLOCK.to_vec();
        want.sort_unstable();
        assert_eq!(offs, want);
        // Nearest first.
        let d: Vec<f32> = v
            .iter()
            .map(|&j| g.pos[j as usize].distance(g.pos[t]))
            .collect();
        assert!(d.windows(2).all(|w| w[0] <= w[1] + 1e-6));
        assert!((d[0] - h).abs() < 1e-3 * h && (d[23] - 8f32.sqrt() * h).abs() < 1e-2 * h);
    }

    #[test]
    fn open_boundary_and_corner_texels_keep_only_existing_neighbours() {
        let s = grid(2);
        let n = 4;
        let g = TexelGeometry::compute(&s, n);
        let graph = TexelGraph::build(&s, &g);
        // Domain 0 corner texel (0,0) sits at the mesh corner: only the 3x3 quarter of the
        // block exists (8 texels; nothing outside the mesh).
        let mut v = Vec::new();
        graph.neighbours(0, &mut v);
        assert_eq!(v.len(), 8);
        // Texel (3,3) of domain 0 touches the interior vertex shared by all four domains:
        // the whole 5x5 block exists (24) and includes the diagonal domain 3's corner block.
        v.clear();
        graph.neighbours(3 * n + 3, &mut v);
        assert_eq!(v.len(), 24);
        assert!(v.contains(&(3 * 16)));
        assert!(v.contains(&(3 * 16 + n as u32 + 1)));
    }

    #[test]
    fn valence3_corners_collect_every_domain_sharing_the_corner() {
        // Cube corners have valence 3: the corner texel of each face must list the corner
        // texels of both other faces at that corner, and stay within ~2.5 samples.
        let s = cube();
        let n = 8;
        let g = TexelGeometry::compute(&s, n);
        let graph = TexelGraph::build(&s, &g);
        let h = g.median_spacing(&s) as f32;
        let nn = n * n;
        for d in 0..6 {
            for c in 0..4 {
                let (x, y) = corner_texel(c, 0, 0, n, n);
                let t = d * nn + y * n + x;
                let mut v = Vec::new();
                graph.neighbours(t, &mut v);
                let fan = corner_fan(&s, d, c);
                assert_eq!(fan.len(), 2, "valence 3");
                for (e, ec) in fan {
                    let (ex, ey) = corner_texel(ec, 0, 0, n, n);
                    assert!(v.contains(&((e * nn + ey * n + ex) as u32)));
                }
                let far = v
                    .iter()
                    .map(|&j| g.pos[j as usize].distance(g.pos[t]) / h)
                    .fold(0.0f32, f32::max);
                assert!(far < 3.5, "farthest neighbour {far} samples");
                // Every neighbour lies on the same side (normals agree).
                for &j in &v {
                    assert!(g.normal[j as usize].dot(g.normal[t]) > 0.5);
                }
            }
        }
    }

    #[test]
    fn spot_graph_reaches_all_domains_around_extraordinary_corners() {
        // Spot has valence-3 and -5 vertices, triangles and pentagons (T-junctions).
        let s = shared("spot_control_mesh.obj");
        let n = 8;
        let g = TexelGeometry::compute(&s, n);
        let graph = TexelGraph::build(&s, &g);
        let nn = n * n;
        let mut worst = 0.0f32;
        let mut counts = Vec::new();
        for t in 0..g.len() {
            let mut v = Vec::new();
            graph.neighbours(t, &mut v);
            counts.push(v.len());
            let d = t / nn;
            let (x, y) = (t % n, (t / n) % n);
            for c in 0..4 {
                if corner_offsets(c, x, y, n, n) == (0, 0) {
                    for (e, ec) in corner_fan(&s, d, c) {
                        let (ex, ey) = corner_texel(ec, 0, 0, n, n);
                        assert!(v.contains(&((e * nn + ey * n + ex) as u32)));
                    }
                }
            }
            // Distances in local samples: the larger in-domain step at this texel.
            let mut local = 0.0f32;
            for (a, b) in [(1i64, 0i64), (-1, 0), (0, 1), (0, -1)] {
                let (xa, yb) = (x as i64 + a, y as i64 + b);
                if (0..n as i64).contains(&xa) && (0..n as i64).contains(&yb) {
                    let j = d * nn + yb as usize * n + xa as usize;
                    local = local.max(g.pos[j].distance(g.pos[t]));
                }
            }
            for &j in &v {
                let r = g.pos[j as usize].distance(g.pos[t]) / local;
                worst = worst.max(r);
            }
        }
        // Closed mesh: every texel has at least the in-domain part of its block.
        assert!(counts.iter().all(|&c| c >= 15), "{:?}", counts.iter().min());
        // Nothing far away. The worst case is a sub-face corner texel taking a quad's 2x2
        // corner block across a T-junction corner: quad texels are twice as long there, so
        // its far texel is ~(0.5 + 2·1.5)·√2 ≈ 5 local samples away, plus distortion.
        assert!(worst < 6.5, "farthest neighbour {worst} samples");
        // Conflicts are symmetric and include edge neighbours.
        let conf = graph.domain_conflicts();
        let adj = domain_edge_adjacency(&s);
        for d in 0..g.faces() {
            for &e in &adj[d] {
                assert!(conf[d].binary_search(&e).is_ok());
                assert!(conf[e as usize].binary_search(&(d as u32)).is_ok());
            }
        }
    }

    #[test]
    fn graphs_join_domains_of_any_resolution_ratio() {
        // A flat 4x4 grid with sides 2 to 16 per domain and direction (ratios up to 8:1
        // between neighbours): the edge graph is symmetric and connected, every border
        // texel has a neighbour across each interior edge, and no neighbour is far away.
        use crate::layout::Resolution;
        let s = grid(4);
        let res = (0..s.num_domains())
            .map(|d| Resolution::new(1 + (d % 4) as u8, 1 + ((d / 3) % 4) as u8).unwrap())
            .collect();
        let layout = Arc::new(TexelLayout::per_face(res));
        let g = TexelGeometry::compute_layout(&s, layout.clone());
        let e = EdgeGraph::build(&s, &g);
        let mut seen = vec![false; g.len()];
        let mut stack = vec![0usize];
        seen[0] = true;
        while let Some(t) = stack.pop() {
            for u in e.of(t) {
                assert!(e.of(u as usize).contains(&(t as u32)), "not symmetric");
                if !seen[u as usize] {
                    seen[u as usize] = true;
                    stack.push(u as usize);
                }
            }
        }
        assert!(seen.iter().all(|&v| v), "edge graph not connected");
        let graph = TexelGraph::build(&s, &g);
        let mut v = Vec::new();
        for t in 0..g.len() {
            v.clear();
            graph.neighbours(t, &mut v);
            let d = layout.domain_of(t);
            let step = |d: usize| {
                let (nu, nv) = layout.dims(d);
                1.0 / nu.min(nv) as f32
            };
            assert!(!v.is_empty());
            for &j in &v {
                let far = 3.5 * step(d).max(step(layout.domain_of(j as usize)));
                let dist = g.pos[j as usize].distance(g.pos[t]);
                assert!(dist < far, "{t} -> {j}: {dist} > {far}");
            }
        }
    }

    /// Every domain's lists with the landings kept per cell ([`Landings`]) are the lists
    /// walking every offset: triangles, quads and an n-gon (T-junctions, where nothing is
    /// kept), an open boundary, extraordinary corners, odd and even N (with odd N a
    /// quad's centre line holds texel centres), and shared meshes of every kind.
    #[test]
    fn kept_landings_are_the_walks() {
        let fan = ControlMesh::parse_obj(
            "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 2 0 0\nv 2 1 0\nv 0.5 0.5 1\n\
             v 3 0 0\nv 3 1 0\nv 2.5 1.5 0.3\nv 3.5 -0.5 0.2\n\
             f 1 2 7\nf 2 3 7\nf 3 4 7\nf 4 1 7\nf 2 5 6 3\nf 5 8 9 10 6\nf 5 11 8\n",
        )
        .unwrap();
        let mut meshes = vec![
            (Surface::new(fan), vec![1usize, 2, 3, 4, 5, 7, 8]),
            (grid(3), vec![4, 5]),
            (cube(), vec![4, 7]),
        ];
        for m in [
            "spot_control_mesh.obj",
            "spot_triangulated.obj",
            "cube_no_bottom.obj",
            "hand_lowres.obj",
        ] {
            meshes.push((shared(m), vec![4, 5]));
        }
        for (s, ns) in &meshes {
            for &n in ns {
                let g = TexelGeometry::compute(s, n);
                let mut kept = 0;
                for d in 0..s.num_domains() {
                    let mut walking = Landings {
                        n: None,
                        ..Landings::new(s, &g.layout, d)
                    };
                    let mut keeping = Landings::new(s, &g.layout, d);
                    assert_eq!(
                        domain_lists_with(s, &g, d, &mut keeping),
                        domain_lists_with(s, &g, d, &mut walking),
                        "N = {n}, domain {d}"
                    );
                    kept += keeping
                        .cells
                        .iter()
                        .filter(|c| matches!(c, Cell::Texel(_)))
                        .count();
                }
                assert_eq!(kept > 0, n >= 4, "N = {n}");
            }
        }
    }

    #[test]
    fn graph_is_identical_for_any_thread_count() {
        let s = shared("spot_control_mesh.obj");
        let build = |threads| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| {
                    let g = TexelGeometry::compute(&s, 4);
                    let gr = TexelGraph::build(&s, &g);
                    (g, gr)
                })
        };
        assert_eq!(build(1), build(2));
    }
}
