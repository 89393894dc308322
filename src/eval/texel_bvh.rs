//! The texel point cloud's neighbour index for pf ([`super::surface`]): nearest texel and
//! texels within a radius of a point, over every valid texel of every domain.
//!
//! Why not a k-d tree over the texels: pf's summary at the end of `synth` draws 256
//! windows, but a k-d tree over all texels costs a sort of every texel position (5 M on the
//! bunny at N = 16: ~40% of the summary's time, more than the windows themselves). The texels
//! of a face already come in a grid, so the index groups them in [`BLOCK`] x [`BLOCK`]
//! blocks of their face, bounds each block with a box (one pass over the positions, no
//! sort of texels) and builds a bounding-volume tree over the blocks only (1/16 of the
//! items). A query descends the tree by box distance and reads the positions of the blocks
//! it reaches where they already are.
//!
//! Same answers as the k-d tree it replaced (kiddo's `ImmutableKdTree`, squared Euclidean,
//! f64 coordinates of the f32 positions): `within` keeps the texels whose squared distance,
//! summed as ((dx² + dy²) + dz²), is at most the bound, and lists them in texel order;
//! `nearest` returns the texel of least squared distance, the lowest texel index among
//! exact ties (the k-d tree took whichever its leaf order met first). An exact tie needs a
//! point exactly as far from two texels in floating point, such as the midpoint of two
//! texels in a straight line: walks do not land there but by coincidence.

use crate::layout::TexelLayout;
use glam::DVec3;
use rayon::prelude::*;
use std::sync::atomic::{AtomicU32, Ordering};
use std::sync::OnceLock;

/// Side of a block of texels (the last block of a face row or column may be narrower).
pub const BLOCK: usize = 4;

/// Depth-first stacks of the queries: a balanced tree (median splits) of up to 2³² blocks
/// is at most 33 levels deep, and a query keeps at most one pending sibling per level (two
/// for `within`'s last push).
const STACK: usize = 72;

/// Below this many blocks a subtree is built on the current thread.
const PARALLEL_BLOCKS: usize = 4096;

/// Texels `start + y * stride + x`, x < w, y < h.
#[derive(Clone, Copy, Debug)]
struct Block {
    start: u32,
    stride: u32,
    w: u8,
    h: u8,
}

/// A tree node: the box of its blocks; a leaf holds one block, an inner node's left child
/// is the next node and its right child `right`.
///
/// The box is kept in f32 (32 B a node instead of 56: 3 B per texel less at the end of a
/// `synth` run, where this index is part of the peak): its corners are minima and maxima
/// of f32 texel positions, so f32 holds them exactly and every distance and split is the
/// one computed from f64 corners.
#[derive(Clone, Copy, Debug)]
struct Node {
    lo: [f32; 3],
    hi: [f32; 3],
    right: u32,
    /// The block of a leaf, [`INNER`] for an inner node.
    block: u32,
}

const INNER: u32 = u32::MAX;

/// A block's box: lowest and highest corner.
type Corners = ([f32; 3], [f32; 3]);

const EMPTY: Node = Node {
    lo: [f32::INFINITY; 3],
    hi: [f32::NEG_INFINITY; 3],
    right: 0,
    block: INNER,
};

/// The neighbour index (module docs).
pub(crate) struct TexelBvh<'a> {
    pos: Xyz<'a>,
    blocks: Vec<Block>,
    /// 2 x blocks - 1 nodes, the root first (empty without blocks).
    nodes: Vec<Node>,
    /// Which texels count, one bit each; `None`: all of them (the usual case, no lookups).
    valid: Option<Vec<u64>>,
    /// Per face: its first texel, first block, texels and blocks per row
    /// ([`TexelBvh::block_of`]).
    faces: Vec<FaceBlocks>,
    /// The leaf node of each block (`u32::MAX`: no counted texel, not in the tree).
    leaf: Vec<u32>,
    /// Per block, once asked for: the blocks near it ([`TexelBvh::near_blocks`]).
    near: Vec<OnceLock<Box<[Near]>>>,
    /// Per block, once its near list is known: its clearance ([`TexelBvh::clearance`]),
    /// as f32 bits, [`UNKNOWN`] before.
    clear: Vec<AtomicU32>,
}

/// [`TexelBvh::clearance`] not computed yet (a NaN pattern).
const UNKNOWN: u32 = u32::MAX;

/// A block near another ([`TexelBvh::near_blocks`]): its leaf node and the distance
/// between the two blocks' boxes (rounded to f32, which the scan's margin allows for).
#[derive(Clone, Copy, Debug)]
struct Near {
    node: u32,
    gap: f32,
}

/// Where a face's texels and blocks start, and their rows.
#[derive(Clone, Copy, Debug)]
struct FaceBlocks {
    texel: u32,
    block: u32,
    nu: u32,
    blocks_per_row: u32,
}

/// Relative margin of the local search's test ([`TexelBvh::nearest_local`]), far above
/// the rounding of a few f64 operations.
const LOCAL_MARGIN: f64 = 1.0 - 1e-6;

/// [`TexelBvh::nearest_outside`]'s pruning margin over the best distance squared: far
/// above the few ulps by which a square whose root rounds to the best may exceed it.
const TIE_MARGIN: f64 = 1.0 + 1e-9;

/// Squared distance of `q` from `p`, summed in the k-d tree's order.
#[inline(always)]
fn dist2(p: &[f64; 3], q: DVec3) -> f64 {
    let (dx, dy, dz) = (q.x - p[0], q.y - p[1], q.z - p[2]);
    dx * dx + dy * dy + dz * dz
}

/// Squared distance of `p` from a box: a lower bound of [`dist2`] of every point in it
/// (rounding is monotonic, so the bound holds in floating point too).
///
/// Per axis the gap is `lo − x` below the box, `x − hi` above it, else 0: written as the
/// largest of the three (without branches, which a descent mispredicts often), the same
/// value — the other two are ≤ 0 — and 0 for a NaN coordinate, as the comparisons gave.
#[inline(always)]
fn box_dist2(p: &[f64; 3], n: &Node) -> f64 {
    let mut acc = 0.0;
    for ((&x, &lo), &hi) in p.iter().zip(&n.lo).zip(&n.hi) {
        let (lo, hi) = (lo as f64, hi as f64);
        let d = (lo - x).max(x - hi).max(0.0);
        acc += d * d;
    }
    acc
}

/// How far from its box a block's near blocks reach ([`TexelBvh::near_blocks`]): its
/// box's longest side, about three texel spacings for 4 x 4 texels, where a walk point's
/// nearest texel is rarely more than one spacing away.
#[inline]
fn reach(n: &Node) -> f64 {
    (0..3)
        .map(|k| n.hi[k] as f64 - n.lo[k] as f64)
        .fold(0.0, f64::max)
}

/// Squared distance between two boxes: a lower bound of the distance of any point of one
/// from any point of the other.
#[inline]
fn box_box_dist2(a: &Node, b: &Node) -> f64 {
    let mut acc = 0.0;
    for k in 0..3 {
        let d = (a.lo[k] as f64 - b.hi[k] as f64)
            .max(b.lo[k] as f64 - a.hi[k] as f64)
            .max(0.0);
        acc += d * d;
    }
    acc
}

impl<'a> TexelBvh<'a> {
    /// The index over the texels of `layout` at `pos` for which `valid` holds (`all_valid`:
    /// every texel, without asking). Deterministic: the same tree for any thread count.
    pub fn build(
        layout: &TexelLayout,
        pos: Xyz<'a>,
        all_valid: bool,
        valid: impl Fn(usize) -> bool + Sync,
    ) -> Self {
        let blocks: Vec<Block> = (0..layout.faces())
            .flat_map(|f| {
                let (nu, nv) = layout.dims(f);
                let start = layout.start(f);
                (0..nv.div_ceil(BLOCK)).flat_map(move |by| {
                    (0..nu.div_ceil(BLOCK)).map(move |bx| {
                        let (x0, y0) = (bx * BLOCK, by * BLOCK);
                        Block {
                            start: (start + y0 * nu + x0) as u32,
                            stride: nu as u32,
                            w: (nu - x0).min(BLOCK) as u8,
                            h: (nv - y0).min(BLOCK) as u8,
                        }
                    })
                })
            })
            .collect();
        let valid = (!all_valid).then(|| {
            (0..layout.len().div_ceil(64))
                .into_par_iter()
                .map(|w| {
                    let lo = w * 64;
                    (lo..(lo + 64).min(layout.len()))
                        .filter(|&i| valid(i))
                        .fold(0u64, |m, i| m | 1 << (i - lo))
                })
                .collect()
        });
        let mut first_block = 0;
        let faces = (0..layout.faces())
            .map(|f| {
                let (nu, nv) = layout.dims(f);
                let fb = FaceBlocks {
                    texel: layout.start(f) as u32,
                    block: first_block,
                    nu: nu as u32,
                    blocks_per_row: nu.div_ceil(BLOCK) as u32,
                };
                first_block += (nu.div_ceil(BLOCK) * nv.div_ceil(BLOCK)) as u32;
                fb
            })
            .collect();
        let mut s = Self {
            pos,
            near: (0..blocks.len()).map(|_| OnceLock::new()).collect(),
            leaf: vec![u32::MAX; blocks.len()],
            clear: (0..blocks.len()).map(|_| AtomicU32::new(UNKNOWN)).collect(),
            blocks,
            nodes: Vec::new(),
            valid,
            faces,
        };
        // Leaf boxes (empty boxes for blocks without a valid texel: left out), in f32:
        // exact, the corners are f32 positions (`Node`).
        let boxes: Vec<Corners> = s
            .blocks
            .par_iter()
            .map(|b| {
                let (mut lo, mut hi) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
                s.each(b, |_, q| {
                    for k in 0..3 {
                        lo[k] = lo[k].min(q[k]);
                        hi[k] = hi[k].max(q[k]);
                    }
                });
                (lo.map(|v| v as f32), hi.map(|v| v as f32))
            })
            .collect();
        let mut items: Vec<Item> = (0..s.blocks.len() as u32)
            .filter(|&b| boxes[b as usize].0[0] <= boxes[b as usize].1[0])
            .map(|b| {
                let (lo, hi) = &boxes[b as usize];
                Item {
                    centre: std::array::from_fn(|k| 0.5 * (lo[k] as f64 + hi[k] as f64)),
                    block: b,
                }
            })
            .collect();
        if !items.is_empty() {
            let mut nodes = vec![EMPTY; 2 * items.len() - 1];
            build_tree(&mut nodes, &mut items, &boxes);
            for (k, n) in nodes.iter().enumerate().filter(|(_, n)| n.block != INNER) {
                s.leaf[n.block as usize] = k as u32;
            }
            s.nodes = nodes;
        }
        s
    }

    /// Texel `i` counts.
    #[inline(always)]
    fn counts(&self, i: usize) -> bool {
        i < self.pos.len()
            && self
                .valid
                .as_ref()
                .is_none_or(|v| v[i / 64] >> (i % 64) & 1 != 0)
    }

    /// Calls `f(texel, position)` for the counted texels of block `b`.
    #[inline(always)]
    fn each(&self, b: &Block, mut f: impl FnMut(usize, DVec3)) {
        for y in 0..b.h as usize {
            let row = b.start as usize + y * b.stride as usize;
            for i in row..row + b.w as usize {
                if self
                    .valid
                    .as_ref()
                    .is_none_or(|v| v[i / 64] >> (i % 64) & 1 != 0)
                {
                    f(i, self.pos.get(i));
                }
            }
        }
    }

    /// The counted texel nearest to `p` (lowest index among exact ties), `None` without
    /// texels. `hint`, a counted texel likely near `p` (a walk's previous nearest texel),
    /// only makes the search prune earlier: the answer is the least (distance, index) over
    /// all counted texels whatever the hint and the order of the visit.
    #[cfg(test)]
    pub fn nearest(&self, p: DVec3, hint: Option<usize>) -> Option<usize> {
        self.nearest_seeded(p, hint.as_slice())
    }

    /// [`TexelBvh::nearest`] with several hints (`seeds`, e.g. a walk's previous nearest
    /// texel and its grid neighbours): the least (distance, index) among them is the first
    /// bound, so a query whose nearest texel is among them visits only the nodes that
    /// could hold a tie. Why: a walk step moves at most one texel spacing, so its nearest
    /// texel is almost always next to the previous one, and the bound of the previous one
    /// alone (up to ~1.75 spacings away) let the descent open several times more blocks
    /// (the walks' nearest-texel queries were ~30% of the pf summary). The same answer
    /// whatever the seeds: the texel of least (distance, index) is never pruned.
    pub fn nearest_seeded(&self, p: DVec3, seeds: &[usize]) -> Option<usize> {
        let q = p.to_array();
        let (mut best, mut best_i) = (f64::INFINITY, usize::MAX);
        if self.nodes.is_empty() {
            return None;
        }
        for &h in seeds {
            if !self.counts(h) {
                continue;
            }
            let d2 = dist2(&q, self.pos.get(h));
            // A NaN distance (a NaN point) is no bound.
            if d2 < best || (d2 == best && h < best_i) {
                (best, best_i) = (d2, h);
            }
        }
        if best_i != usize::MAX {
            if let Some(i) = self.nearest_local(&q, best, best_i) {
                return Some(i);
            }
        }
        self.descend_nearest(&q, best, |b| {
            self.each(b, |i, x| {
                let d2 = dist2(&q, x);
                if d2 < best || (d2 == best && i < best_i) {
                    (best, best_i) = (d2, i);
                }
            });
            best
        });
        (best_i != usize::MAX).then_some(best_i)
    }

    /// [`TexelBvh::nearest_seeded`] without the descent from the root, when it can be
    /// decided near the seed: `best` is the squared distance of counted texel `seed` from
    /// `q`. Every texel at most that far from `q` is within reach of the seed's block B
    /// (its box's distance from `q` plus √best, by the triangle inequality), so when that
    /// is no more than B's reach, the blocks near B ([`TexelBvh::near_blocks`]) hold every
    /// candidate, ties included. Why: a walk step's nearest texel is next to the previous
    /// one, yet the descent from the root tested ~50 boxes to prove it (the walks'
    /// nearest-texel queries were the pf summary's largest cost). `None`: not decidable
    /// here (then the caller descends).
    fn nearest_local(&self, q: &[f64; 3], best: f64, seed: usize) -> Option<usize> {
        let b = self.block_of(seed);
        let own = self.nodes.get(*self.leaf.get(b)? as usize)?;
        let own_gap = box_dist2(q, own).sqrt();
        let mut gap = own_gap + best.sqrt();
        // A NaN point fails the test.
        if gap.is_nan() || gap > reach(own) * LOCAL_MARGIN {
            return None;
        }
        let (mut best, mut best_i) = (best, seed);
        let mut scan = |c: usize, best: &mut f64| {
            self.each(&self.blocks[c], |i, x| {
                let d2 = dist2(q, x);
                if d2 < *best || (d2 == *best && i < best_i) {
                    (*best, best_i) = (d2, i);
                }
            })
        };
        // Only B within reach (the triangle inequality below): its texels alone decide.
        // Why: the common case (a walk point inside B, its nearest texel half a spacing
        // away, the blocks beside B a spacing away), which then reads neither B's near
        // list nor the boxes in it (their memory, not their tests, was most of the query).
        if gap < self.clearance(b) * LOCAL_MARGIN {
            scan(b, &mut best);
            return Some(best_i);
        }
        // A texel x within √best of q lies in a block C whose box is within
        // |q − B| + |q − x| ≤ `gap` of B's box (the triangle inequality through q's nearest
        // point on B's box): the near blocks come nearest first, so the scan stops at the
        // first one farther than that, and `gap` shrinks with `best`. Why: the list holds
        // ~14 blocks (the 3 x 3 of the face and those of faces across), but a walk point
        // inside B with its nearest texel half a spacing away needs only B and the blocks
        // touching it; testing every box was most of the query.
        for e in self.near_blocks(b) {
            if e.gap as f64 * LOCAL_MARGIN > gap {
                break;
            }
            let n = &self.nodes[e.node as usize];
            if box_dist2(q, n) > best {
                continue;
            }
            scan(n.block as usize, &mut best);
            gap = own_gap + best.sqrt();
        }
        Some(best_i)
    }

    /// The block holding texel `i` (a texel of the layout the index was built on).
    fn block_of(&self, i: usize) -> usize {
        let f = self.faces.partition_point(|f| f.texel as usize <= i) - 1;
        let fb = &self.faces[f];
        let r = i - fb.texel as usize;
        let (x, y) = (r % fb.nu as usize, r / fb.nu as usize);
        fb.block as usize + (y / BLOCK) * fb.blocks_per_row as usize + x / BLOCK
    }

    /// The blocks in the tree whose box is within [`reach`] of block `b`'s box (`b`
    /// included), nearest first (ties by node), computed the first time they are asked
    /// for: a run's walks touch a small part of the surface.
    fn near_blocks(&self, b: usize) -> &[Near] {
        self.near[b].get_or_init(|| {
            let own = &self.nodes[self.leaf[b] as usize];
            let r = reach(own);
            let mut out = Vec::new();
            self.visit_blocks(
                |n| box_box_dist2(own, n) > r * r,
                |k, n| {
                    out.push(Near {
                        node: k,
                        gap: box_box_dist2(own, n).sqrt() as f32,
                    })
                },
            );
            out.sort_unstable_by(|a, b| a.gap.total_cmp(&b.gap).then(a.node.cmp(&b.node)));
            out.into_boxed_slice()
        })
    }

    /// How far block `b`'s box is from every other block's box: the least distance to a
    /// box in its near list other than its own, at most its [`reach`] (the blocks not in
    /// the list are farther). Rounded to f32, which [`LOCAL_MARGIN`] allows for; computed
    /// with the near list, kept apart from it (4 B per block) so that the common query
    /// reads only this.
    fn clearance(&self, b: usize) -> f64 {
        let known = self.clear[b].load(Ordering::Relaxed);
        if known != UNKNOWN {
            return f32::from_bits(known) as f64;
        }
        let own = self.leaf[b];
        let r = reach(&self.nodes[own as usize]) as f32;
        let c = self
            .near_blocks(b)
            .iter()
            .filter(|e| e.node != own)
            .fold(r, |m, e| m.min(e.gap));
        self.clear[b].store(c.to_bits(), Ordering::Relaxed);
        c as f64
    }

    /// Among the counted texels that [`TexelBvh::within`] `r2` of `p` lists, those outside
    /// `skip` (a range of texels: one face's), the one of least (distance, index), with
    /// that distance: `(x − p).length()`, the square root of the squared distance (so two
    /// texels whose squared distances differ in the last bit may tie, and then the lower
    /// index wins, as when every texel within `r2` is listed and compared). `None`: no
    /// such texel.
    ///
    /// Why: a face-border texel's cover ([`super::surface`]) wants the nearest texel of
    /// another face within 4 spacings; listing all texels within that radius (half of
    /// them its own face's) and sorting them by face cost ~13% of the pf summary. This
    /// descent skips the face's blocks whole and prunes by the best distance so far.
    pub fn nearest_outside(
        &self,
        p: DVec3,
        r2: f64,
        skip: std::ops::Range<usize>,
    ) -> Option<(usize, f64)> {
        if self.nodes.is_empty() {
            return None;
        }
        let q = p.to_array();
        let (mut best, mut best_i) = (f64::INFINITY, usize::MAX);
        // Squared distances above this cannot tie with `best` once rooted (a correctly
        // rounded square root at most `best` comes from a square within a few ulps of
        // best², far inside the margin); at most `r2` (the radius search's own test).
        let mut bound = r2;
        self.descend_nearest(&q, r2, |b| {
            // A block lies in one face: out of `skip` whole or not at all.
            if !skip.contains(&(b.start as usize)) {
                self.each(b, |i, x| {
                    let d2 = dist2(&q, x);
                    if d2 > r2 {
                        return;
                    }
                    let dist = d2.sqrt();
                    if dist < best || (dist == best && i < best_i) {
                        (best, best_i) = (dist, i);
                        bound = r2.min(best * best * TIE_MARGIN);
                    }
                });
            }
            bound
        });
        (best_i != usize::MAX).then_some((best_i, best))
    }

    /// The nearest-first descent of [`Self::nearest_seeded`] and [`Self::nearest_outside`]:
    /// depth first, the nearer child on top, every node whose box is within the current
    /// bound (equal bounds are visited: they may hold a tie of lower index). `leaf` scans a
    /// block and returns the bound after it (`bound` at the start). At most one pending
    /// sibling per level of a balanced tree (median splits), so a fixed stack, no
    /// allocation per query.
    #[inline(always)]
    fn descend_nearest(&self, q: &[f64; 3], bound: f64, mut leaf: impl FnMut(&Block) -> f64) {
        let mut bound = bound;
        let mut stack = [(0usize, 0f64); STACK];
        stack[0] = (0, box_dist2(q, &self.nodes[0]));
        let mut top = 1;
        while top > 0 {
            top -= 1;
            let (k, d) = stack[top];
            if d > bound {
                continue;
            }
            let n = &self.nodes[k];
            if n.block != INNER {
                bound = leaf(&self.blocks[n.block as usize]);
                continue;
            }
            let (l, r) = (k + 1, k + n.right as usize);
            let (dl, dr) = (box_dist2(q, &self.nodes[l]), box_dist2(q, &self.nodes[r]));
            // A child farther than the bound is not pushed.
            let (near, far) = if dl <= dr {
                ((l, dl), (r, dr))
            } else {
                ((r, dr), (l, dl))
            };
            if far.1 <= bound {
                stack[top] = far;
                top += 1;
            }
            if near.1 <= bound {
                stack[top] = near;
                top += 1;
            }
        }
    }

    /// The counted texels whose squared distance from `p` is at most `r2`, in texel order.
    pub fn within(&self, p: DVec3, r2: f64) -> Vec<usize> {
        let mut out = Vec::new();
        self.for_within(p, r2, |i, _| out.push(i));
        out.sort_unstable();
        out
    }

    /// Calls `f(texel, position)` for the texels [`TexelBvh::within`] lists, in the order
    /// of the visit (not texel order): for callers that keep only a few of them and sort
    /// those (pf's disc samples), instead of listing and sorting all.
    pub fn for_within(&self, p: DVec3, r2: f64, mut f: impl FnMut(usize, DVec3)) {
        let q = p.to_array();
        self.visit_blocks(
            |n| box_dist2(&q, n) > r2,
            |_, n| {
                self.each(&self.blocks[n.block as usize], |i, x| {
                    if dist2(&q, x) <= r2 {
                        f(i, x);
                    }
                })
            },
        );
    }

    /// Depth first, left child first: every leaf (its node and the node) under the nodes
    /// that `prune` does not cut off, handed to `block`. The one pruned walk of the radius
    /// searches ([`Self::for_within`], [`Self::near_blocks`]), which differ only in what
    /// prunes.
    fn visit_blocks(
        &self,
        mut prune: impl FnMut(&Node) -> bool,
        mut block: impl FnMut(u32, &Node),
    ) {
        if self.nodes.is_empty() {
            return;
        }
        let mut stack = [0usize; STACK];
        let mut top = 1;
        while top > 0 {
            top -= 1;
            let k = stack[top];
            let n = &self.nodes[k];
            if prune(n) {
                continue;
            }
            if n.block != INNER {
                block(k as u32, n);
                continue;
            }
            stack[top] = k + n.right as usize;
            stack[top + 1] = k + 1;
            top += 2;
        }
    }
}

/// Builds the subtree of `items` (blocks, with their centres) into `nodes` (exactly 2 x items - 1 of
/// them, this subtree's root first, the right child's offset from its parent in `right`):
/// split at the median of the block centres along the longest side of their bounds, ties
/// by block index, so the tree depends on nothing but the boxes.
fn build_tree(nodes: &mut [Node], items: &mut [Item], boxes: &[Corners]) {
    debug_assert_eq!(nodes.len(), 2 * items.len() - 1);
    if items.len() == 1 {
        let (lo, hi) = boxes[items[0].block as usize];
        nodes[0] = Node {
            lo,
            hi,
            right: 0,
            block: items[0].block,
        };
        return;
    }
    let (mut lo, mut hi) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
    for it in items.iter() {
        for k in 0..3 {
            lo[k] = lo[k].min(it.centre[k]);
            hi[k] = hi[k].max(it.centre[k]);
        }
    }
    let axis = (0..3)
        .max_by(|&a, &b| (hi[a] - lo[a]).total_cmp(&(hi[b] - lo[b])).then(b.cmp(&a)))
        .unwrap_or(0);
    let mid = items.len() / 2;
    // A strict total order (ties by block number): the halves are the same sets whatever
    // order the items come in, so the tree is the same as well.
    items.select_nth_unstable_by(mid, |a, b| {
        a.centre[axis]
            .total_cmp(&b.centre[axis])
            .then(a.block.cmp(&b.block))
    });
    let (left_items, right_items) = items.split_at_mut(mid);
    let (root, rest) = nodes.split_first_mut().expect("at least 3 nodes");
    let (left, right) = rest.split_at_mut(2 * left_items.len() - 1);
    if left_items.len() + right_items.len() >= PARALLEL_BLOCKS {
        rayon::join(
            || build_tree(left, left_items, boxes),
            || build_tree(right, right_items, boxes),
        );
    } else {
        build_tree(left, left_items, boxes);
        build_tree(right, right_items, boxes);
    }
    let (l, r) = (&left[0], &right[0]);
    *root = Node {
        lo: std::array::from_fn(|k| l.lo[k].min(r.lo[k])),
        hi: std::array::from_fn(|k| l.hi[k].max(r.hi[k])),
        right: 2 * left_items.len() as u32,
        block: INNER,
    };
}

/// A block being placed in the tree, with its box's centre beside it: the splits read
/// the centres in place instead of looking each block's box up in comparisons (at 4 M
/// texels, ~250 k blocks, those scattered reads were most of the tree's build).
#[derive(Clone, Copy, Debug)]
struct Item {
    centre: [f64; 3],
    block: u32,
}

/// Three f32 values per texel, read as f64 (exact): the planes of geometry maps
/// (geometry.exr's `P.X P.Y P.Z`) or the packed vectors of the texel geometry in memory.
#[derive(Clone, Copy, Debug)]
pub enum Xyz<'a> {
    Planar([&'a [f32]; 3]),
    Packed(&'a [glam::Vec3]),
}

impl Xyz<'_> {
    #[inline]
    pub(crate) fn get(&self, i: usize) -> DVec3 {
        match self {
            Xyz::Planar([x, y, z]) => DVec3::new(x[i] as f64, y[i] as f64, z[i] as f64),
            Xyz::Packed(v) => v[i].as_dvec3(),
        }
    }

    pub(crate) fn len(&self) -> usize {
        match self {
            Xyz::Planar([x, y, z]) => x.len().min(y.len()).min(z.len()),
            Xyz::Packed(v) => v.len(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use kiddo::{ImmutableKdTree, SquaredEuclidean};

    /// A curved sheet of `faces` faces of n x n texels, or (`flat`) an exactly regular grid
    /// whose texels have many exact ties.
    fn sheet(faces: usize, n: usize, flat: bool) -> (TexelLayout, Vec<glam::Vec3>) {
        let l = TexelLayout::uniform(faces, n);
        let mut p = vec![glam::Vec3::ZERO; l.len()];
        for f in 0..faces {
            for y in 0..n {
                for x in 0..n {
                    let (u, v) = ((f * n + x) as f32 * 0.125, y as f32 * 0.125);
                    p[l.index(f, x, y)] = if flat {
                        glam::Vec3::new(u, v, 0.0)
                    } else {
                        glam::Vec3::new(u.sin() * 3.0, v, u.cos() * 3.0 + 0.1 * (u * v).sin())
                    };
                }
            }
        }
        (l, p)
    }

    /// Nearest and within agree with the k-d tree they replaced: the same sets, the same
    /// nearest distance (the texel may differ on exact ties: then it is the lowest index).
    /// Half the queries sit on texels or midpoints of two, where ties are.
    #[test]
    fn answers_as_the_kd_tree() {
        for (faces, n, flat) in [(7, 16, false), (5, 9, true), (3, 1, false), (40, 5, false)] {
            let (l, p) = sheet(faces, n, flat);
            let pos = Xyz::Packed(&p);
            let bvh = TexelBvh::build(&l, pos, true, |_| true);
            let tree: ImmutableKdTree<f64, 3> =
                ImmutableKdTree::new_from_source(&p, |q, d| q[d] as f64, |i, _| i as u32).unwrap();
            let mut rng = 12345u64;
            let mut next = || {
                rng = rng
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                (rng >> 11) as f64 / (1u64 << 53) as f64
            };
            for q in 0..2000 {
                // Half the queries on texels and midpoints (ties), half anywhere near.
                let pt = if q % 2 == 0 {
                    let (i, j) = (
                        (next() * p.len() as f64) as usize,
                        (next() * p.len() as f64) as usize,
                    );
                    let (a, b) = (p[i].as_dvec3(), p[j.min(i + 1).min(p.len() - 1)].as_dvec3());
                    if q % 4 == 0 {
                        a
                    } else {
                        (a + b) * 0.5
                    }
                } else {
                    DVec3::new(next() * 8.0 - 4.0, next() * 2.5 - 0.3, next() * 8.0 - 4.0)
                };
                let r = next() * 0.5;
                let mut want: Vec<usize> = tree
                    .query(&pt.to_array())
                    .within::<SquaredEuclidean<f64>>(r * r)
                    .unsorted()
                    .execute()
                    .iter()
                    .map(|h| h.item as usize)
                    .collect();
                want.sort_unstable();
                assert_eq!(bvh.within(pt, r * r), want, "within {r} of {pt}");
                let k = tree
                    .query(&pt.to_array())
                    .nearest_one::<SquaredEuclidean<f64>>()
                    .execute();
                let got = bvh.nearest(pt, None).unwrap();
                // Any hint, the same answer.
                let hint = (next() * p.len() as f64) as usize;
                assert_eq!(bvh.nearest(pt, Some(hint)), Some(got));
                // Any seeds (the answer among them, or not, or out of range), the same.
                let seeds = [hint, got, got.saturating_sub(1), got + 1, p.len() + 3];
                for k in 0..=seeds.len() {
                    assert_eq!(bvh.nearest_seeded(pt, &seeds[..k]), Some(got));
                    assert_eq!(bvh.nearest_seeded(pt, &seeds[k..]), Some(got));
                }
                let mut seen: Vec<usize> = Vec::new();
                bvh.for_within(pt, r * r, |i, x| {
                    assert_eq!(x, p[i].as_dvec3());
                    seen.push(i);
                });
                seen.sort_unstable();
                assert_eq!(seen, want);
                assert_eq!(dist2(&pt.to_array(), p[got].as_dvec3()), k.distance);
                let lowest = (0..p.len())
                    .find(|&i| dist2(&pt.to_array(), p[i].as_dvec3()) == k.distance)
                    .unwrap();
                assert_eq!(got, lowest);
            }
        }
    }

    /// Walk-like queries (a texel moved up to a spacing, texel midpoints: exact ties),
    /// seeded with a texel and its grid neighbours as the walks seed them, get the least
    /// (distance, index) over all texels, as brute force: the local search near the seed
    /// never misses a nearer texel of its own or another face.
    #[test]
    fn seeded_near_the_answer_as_brute_force() {
        for (faces, n, flat) in [(7, 16, false), (5, 9, true), (40, 5, false), (6, 2, true)] {
            let (l, p) = sheet(faces, n, flat);
            let bvh = TexelBvh::build(&l, Xyz::Packed(&p), true, |_| true);
            let mut rng = 99u64;
            let mut next = || {
                rng = rng
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                (rng >> 11) as f64 / (1u64 << 53) as f64
            };
            for t in (0..p.len()).step_by(3) {
                let (f, x, y) = l.coords(t);
                let nb = |dx: isize, dy: isize| {
                    let (xx, yy) = (x as isize + dx, y as isize + dy);
                    (xx >= 0 && yy >= 0 && (xx as usize) < n && (yy as usize) < n)
                        .then(|| l.index(f, xx as usize, yy as usize))
                };
                let seeds: Vec<usize> = (-1..=1)
                    .flat_map(|dy| (-1..=1).map(move |dx| (dx, dy)))
                    .filter_map(|(dx, dy)| nb(dx, dy))
                    .collect();
                let other = nb(1, 0).or(nb(0, 1)).unwrap_or(t);
                let (a, b) = (p[t].as_dvec3(), p[other].as_dvec3());
                let step = 0.125 * (next() - 0.5) * DVec3::new(2.0, 2.0, 1.0);
                for q in [a, (a + b) * 0.5, a + step, b + step * 1.5] {
                    let want = (0..p.len())
                        .min_by(|&i, &j| {
                            let (di, dj) = (
                                dist2(&q.to_array(), p[i].as_dvec3()),
                                dist2(&q.to_array(), p[j].as_dvec3()),
                            );
                            di.total_cmp(&dj).then(i.cmp(&j))
                        })
                        .unwrap();
                    assert_eq!(bvh.nearest_seeded(q, &seeds), Some(want), "{q}");
                }
            }
        }
    }

    /// The nearest texel outside a face within a radius is the one a listing of the radius
    /// search finds: least (rooted distance, index) among the listed texels of other faces.
    #[test]
    fn nearest_outside_as_the_listing() {
        for (faces, n, flat) in [(7, 16, false), (5, 9, true), (40, 5, false), (6, 2, true)] {
            let (l, p) = sheet(faces, n, flat);
            let bvh = TexelBvh::build(&l, Xyz::Packed(&p), true, |_| true);
            for t in (0..p.len()).step_by(2) {
                let f = l.domain_of(t);
                let (a, b) = (p[t].as_dvec3(), p[(t + 1) % p.len()].as_dvec3());
                for (q, r) in [(a, 0.5), ((a + b) * 0.5, 0.3), (a, 0.125), (a, 2.0)] {
                    let want = bvh
                        .within(q, r * r)
                        .into_iter()
                        .filter(|&j| l.domain_of(j) != f)
                        .map(|j| ((p[j].as_dvec3() - q).length(), j))
                        .min_by(|x, y| x.0.total_cmp(&y.0).then(x.1.cmp(&y.1)))
                        .map(|(d, j)| (j, d));
                    assert_eq!(bvh.nearest_outside(q, r * r, l.range(f)), want, "{q} {r}");
                }
            }
        }
    }

    /// The branch-free box gap is the gap of the comparisons, bit for bit (NaN: 0).
    #[test]
    fn box_gap_as_the_comparisons() {
        let n = Node {
            lo: [-1.0, 0.5, 2.0],
            hi: [1.0, 0.5, 3.0],
            right: 0,
            block: 0,
        };
        let gap = |x: f64, lo: f32, hi: f32| {
            let (lo, hi) = (lo as f64, hi as f64);
            if x < lo {
                lo - x
            } else if x > hi {
                x - hi
            } else {
                0.0
            }
        };
        let xs = [
            -3.0,
            -1.0,
            -0.25,
            0.0,
            0.5,
            0.7,
            1.0,
            2.5,
            3.0,
            1e300,
            -1e-300,
            f64::NAN,
        ];
        for &x in &xs {
            for &y in &xs {
                for &z in &xs {
                    let want: f64 = [x, y, z]
                        .iter()
                        .enumerate()
                        .map(|(k, &v)| gap(v, n.lo[k], n.hi[k]))
                        .fold(0.0, |a, d| a + d * d);
                    assert_eq!(box_dist2(&[x, y, z], &n).to_bits(), want.to_bits());
                }
            }
        }
    }

    /// Texels that do not count are never answered.
    #[test]
    fn invalid_texels_left_out() {
        let (l, p) = sheet(4, 8, false);
        let bvh = TexelBvh::build(&l, Xyz::Packed(&p), false, |i: usize| !i.is_multiple_of(3));
        for i in (0..p.len()).step_by(5) {
            let q = p[i].as_dvec3();
            let k = bvh.nearest(q, Some(i)).unwrap();
            assert_eq!(bvh.nearest(q, None), Some(k));
            assert!(!k.is_multiple_of(3));
            assert_eq!(k == i, !i.is_multiple_of(3));
            assert!(bvh.within(q, 1.0).iter().all(|&j| !j.is_multiple_of(3)));
        }
        let none = TexelBvh::build(&l, Xyz::Packed(&p), false, |_| false);
        assert_eq!(none.nearest(DVec3::ZERO, Some(3)), None);
        assert!(none.within(DVec3::ZERO, 1e9).is_empty());
    }
}
