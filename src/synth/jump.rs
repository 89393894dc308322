//! Jump-map synthesis on the surface (paper 002, Zelinka & Garland 2003, §4), on texels
//! instead of mesh vertices: every texel is assigned a position in the example by
//! continuing an already synthesized neighbour's position across the edge between them,
//! now and then taking one of the jumps the [`JumpMap`] stores there. No neighbourhood is
//! compared at synthesis time, which is what makes it fast (tens of millions of texels per
//! second).
//!
//! - **Vertices and edges** are the texels and the texel grid's 4-neighbourhood across
//!   domain edges, T-junctions and extraordinary corners ([`crate::texels::EdgeGraph`]).
//! - **Order** (§4.1, region growing): "iteratively selecting the unsynthesized vertex
//!   whose proportion of already-synthesized neighbours is greatest", growing out of one
//!   seed texel per connected component (the centre texel of its lowest domain), ties
//!   first come first served. It depends only on the mesh and the resolution, so it is
//!   computed once per prepared mesh ([`growth_order`]) and synthesis runs through it
//!   sequentially: the result is the same for any thread count.
//! - **Edge offsets** (§4.2.2, figure 4): the edge s→t is projected on the tangent plane
//!   whose basis is the average of the endpoints' field frames — û = normalize(v1_s + v1_t),
//!   v̂ = the part of (v2_s + v2_t) perpendicular to û, normalized — and divided by the scale:
//!   d(s→t) = ((P_t − P_s)·û, −(P_t − P_s)·v̂) / S in example pixels (the minus: image rows
//!   grow downwards, as in coherent synthesis). Each endpoint sees the opposite offset.
//! - **Selection table** (§4.2.5, figure 6): every synthesized neighbour s with address
//!   a_s contributes its continuation a_s + d(s→t), weight
//!   [`JumpParams::continuation`] / |d| ("explicitly divide the continuation weights by
//!   the length of the corresponding edge offset"), times a ramp from 0 at the example's
//!   border to 1 at [`JumpParams::border`] of its size ("to encourage a jump away from the
//!   boundary"); and its floating-point jump list (§4.2.3: the jumps of the four pixels
//!   around a_s, bilinearly weighted, each destination moved by a_s's sub-pixel offset)
//!   continued by d(s→t). One random number picks an entry by weight; several neighbours
//!   proposing the same place add up ("probabilistically good matching").
//! - **Validity** (§4.2.4): an address is valid for t when the box of t's incident edge
//!   offsets around it stays inside the example's pixel-centre rectangle (for edges to
//!   texels not yet synthesized the chord length stands in for the offset: it bounds both
//!   of its components, and saves projecting an edge nobody continues). Invalid entries
//!   are filtered out by rejection: a drawn invalid entry is drawn again (another random
//!   number), which samples exactly the table of valid entries without building it, so the
//!   common case (a continuation is drawn) never looks at the jump lists at all. "In the
//!   rare event that there are still no valid entries, a random valid address is
//!   assigned" (after [`MAX_DRAWS`] draws), as is the seed texel of every component.
//!
//! Randomness is the counter-based hash of (seed, texel, draw) of coherent synthesis.

use super::coherent::random2;
use super::footprint::LevelTexels;
use super::matching::jumpmap::JumpMap;
use crate::layout::TexelLayout;
use crate::texels::EdgeGraph;
use glam::Vec3;
use serde::Serialize;
use std::collections::VecDeque;

/// Draws from a texel's table before it gets a random valid address.
pub const MAX_DRAWS: u64 = 8;

/// Tuning of jump-map synthesis (defaults measured, docs/synthesis.md "Jump maps").
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct JumpParams {
    /// Weight of a continuation across a one-pixel edge: the desired mean number of texels
    /// between jumps (§4.2.5; jump weights sum to at most 1 per pixel).
    pub continuation: f32,
    /// Share of the example's width/height over which continuations lose weight towards
    /// its border (§4.2.1).
    pub border: f32,
    /// How the jump map is built.
    pub map: super::matching::jumpmap::JumpMapParams,
}

impl Default for JumpParams {
    fn default() -> Self {
        Self {
            continuation: 100.0,
            border: 0.1,
            map: Default::default(),
        }
    }
}

/// Counters of a run (reported).
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct Stats {
    pub texels: u64,
    /// Texels that continued a neighbour's position.
    pub continuations: u64,
    /// Texels that took a jump.
    pub jumps: u64,
    /// Texels with synthesized neighbours but no valid entry drawn: a random valid address.
    pub restarts: u64,
    /// First texels of connected components: a random valid address.
    pub seeded: u64,
    /// Entries drawn invalid and drawn again.
    pub redraws: u64,
    /// What the jump map holds.
    pub map: super::matching::jumpmap::JumpMapStats,
    /// Seconds of the texel pass alone (no analysis, no set-up): the jump-synthesis stage.
    pub seconds: f64,
    /// `texels / seconds`.
    pub texels_per_second: f64,
}

/// The region-growing order (§4.1) over the edge graph: texel indices in synthesis order.
///
/// Buckets by the proportion of synthesized neighbours (quantised to 1/64; degrees are 2
/// to ~6, so distinct proportions stay distinct), first in first out inside a bucket, stale
/// entries skipped: O(1) per texel and edge.
pub fn growth_order(edges: &EdgeGraph, layout: &TexelLayout) -> Vec<u32> {
    const Q: usize = 64;
    let texels = layout.len();
    let mut count = vec![0u8; texels];
    let mut done = vec![false; texels];
    let mut buckets: Vec<VecDeque<u32>> = (0..=Q).map(|_| VecDeque::new()).collect();
    let mut order = Vec::with_capacity(texels);
    let level = |c: u8, deg: usize| (c as usize * Q) / deg.max(1);
    let mut next_root = 0usize;
    let mut top = 0usize;
    while order.len() < texels {
        // Highest non-empty bucket with a live entry.
        let mut picked = None;
        while picked.is_none() {
            match buckets[top].pop_front() {
                Some(t) => {
                    let t = t as usize;
                    if !done[t] && level(count[t], edges.of(t).len()) == top {
                        picked = Some(t);
                    }
                }
                None if top > 0 => top -= 1,
                None => break,
            }
        }
        let t = match picked {
            Some(t) => t,
            None => {
                // A new component: its lowest domain's centre texel (or its lowest texel).
                while done[next_root] {
                    next_root += 1;
                }
                let d = layout.domain_of(next_root);
                let (nu, nv) = layout.dims(d);
                let c = layout.index(d, nu / 2, nv / 2);
                if !done[c] && count[c] == 0 {
                    c
                } else {
                    next_root
                }
            }
        };
        done[t] = true;
        order.push(t as u32);
        for &s in edges.of(t) {
            let s = s as usize;
            if done[s] {
                continue;
            }
            count[s] = count[s].saturating_add(1);
            let b = level(count[s], edges.of(s).len()).min(Q);
            buckets[b].push_back(s as u32);
            top = top.max(b);
        }
    }
    order
}

/// Edge offset d(s→t) in example pixels (see the module docs).
#[inline(always)]
fn offset(pos: &[Vec3], frames: &[[Vec3; 2]], s: usize, t: usize, inv_scale: f32) -> [f32; 2] {
    let d = pos[t] - pos[s];
    let [a1, a2] = frames[s];
    let [b1, b2] = frames[t];
    let u = (a1 + b1).normalize_or_zero();
    let v2 = a2 + b2;
    let v = (v2 - u * u.dot(v2)).normalize_or_zero();
    [d.dot(u) * inv_scale, -d.dot(v) * inv_scale]
}

/// One table entry per synthesized neighbour: its address, its continuation, the weight
/// of that continuation and of its whole jump list.
#[derive(Clone, Copy)]
struct Entry {
    a: [f32; 2],
    d: [f32; 2],
    cont: f32,
    jumps: f32,
}

/// Runs jump-map synthesis over `level` in `order` ([`growth_order`] of its edge graph).
pub fn run(
    map: &JumpMap,
    level: &LevelTexels,
    order: &[u32],
    params: &JumpParams,
    seed: u64,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> (Vec<[f32; 2]>, Stats) {
    let started = std::time::Instant::now();
    let total = level.len();
    assert_eq!(order.len(), total);
    let pos = &level.geometry.pos;
    let frames = &level.frames;
    let edges = level.edges();
    let inv_global = (1.0 / level.step) as f32;
    let (w, h) = (map.width as f32, map.height as f32);
    let (bx, by) = ((params.border * w).max(1e-3), (params.border * h).max(1e-3));
    let cw = params.continuation.max(0.0);
    let mut src = vec![[f32::NAN; 2]; total];
    let mut stats = Stats {
        map: map.stats,
        ..Stats::default()
    };
    let mut table: Vec<Entry> = Vec::with_capacity(16);
    let step = (total / 64).max(1);
    for (k, &t) in order.iter().enumerate() {
        if k % step == 0 {
            progress(k, total);
        }
        let t = t as usize;
        table.clear();
        let mut margin = 0.0f32;
        let mut sum = 0.0f32;
        let pt = pos[t];
        // Offsets into t are measured at t's local step (the scale map's factor there).
        let inv_scale = match &level.factor {
            None => inv_global,
            Some(_) => level.inv_step_at(t),
        };
        for &s in edges.of(t) {
            let s = s as usize;
            let a = src[s];
            if a[0].is_nan() {
                // The chord bounds both components of the projected offset (validity box).
                margin = margin.max(pos[s].distance(pt) * inv_scale);
                continue;
            }
            let d = offset(pos, frames, s, t, inv_scale);
            margin = margin.max(d[0].abs()).max(d[1].abs());
            let c = [a[0] + d[0], a[1] + d[1]];
            let len = (d[0] * d[0] + d[1] * d[1]).sqrt().max(0.25);
            // Border ramp on the continuation (distance from the pixel-centre rectangle).
            let ex = (c[0] - 0.5).min(w - 0.5 - c[0]);
            let ey = (c[1] - 0.5).min(h - 0.5 - c[1]);
            let ramp = (ex / bx).min(ey / by).clamp(0.0, 1.0);
            let e = Entry {
                a,
                d,
                cont: cw / len * ramp,
                jumps: map.total_at(a[0], a[1]),
            };
            sum += e.cont + e.jumps;
            table.push(e);
        }
        // Valid addresses: the box of t's offsets stays inside the pixel-centre rectangle.
        let (lo_x, hi_x) = (0.5 + margin, w - 0.5 - margin);
        let (lo_y, hi_y) = (0.5 + margin, h - 0.5 - margin);
        let valid = |p: [f32; 2]| p[0] >= lo_x && p[0] <= hi_x && p[1] >= lo_y && p[1] <= hi_y;
        let random_valid = |draw: u64| -> [f32; 2] {
            let (a, b) = random2(seed, t as u64, draw);
            let (cx, cy) = ((lo_x + hi_x) * 0.5, (lo_y + hi_y) * 0.5);
            // A box wider than the example (huge offsets): its centre.
            let px = if hi_x > lo_x {
                lo_x + a * (hi_x - lo_x)
            } else {
                cx
            };
            let py = if hi_y > lo_y {
                lo_y + b * (hi_y - lo_y)
            } else {
                cy
            };
            [px, py]
        };
        stats.texels += 1;
        if table.is_empty() {
            stats.seeded += 1;
            src[t] = random_valid(0);
            continue;
        }
        let mut chosen = None;
        if sum > 0.0 {
            for draw in 0..MAX_DRAWS {
                let (r, r2) = random2(seed, t as u64, draw + 1);
                let mut x = r * sum;
                let mut pick = None;
                for e in &table {
                    if x < e.cont {
                        pick = Some(([e.a[0] + e.d[0], e.a[1] + e.d[1]], false));
                        break;
                    }
                    x -= e.cont;
                    if x < e.jumps {
                        // Which jump of this neighbour's list: a second number.
                        let mut y = r2 * e.jumps;
                        let mut dest = None;
                        map.for_each_jump(e.a[0], e.a[1], |wt, jx, jy| {
                            if dest.is_none() {
                                if y < wt {
                                    dest = Some([jx + e.d[0], jy + e.d[1]]);
                                }
                                y -= wt;
                            }
                        });
                        pick = dest.map(|p| (p, true));
                        break;
                    }
                    x -= e.jumps;
                }
                match pick {
                    Some((p, jumped)) if valid(p) => {
                        chosen = Some(p);
                        if jumped {
                            stats.jumps += 1;
                        } else {
                            stats.continuations += 1;
                        }
                        break;
                    }
                    _ => stats.redraws += 1,
                }
            }
        }
        src[t] = chosen.unwrap_or_else(|| {
            stats.restarts += 1;
            random_valid(MAX_DRAWS + 1)
        });
    }
    progress(total, total);
    stats.seconds = started.elapsed().as_secs_f64();
    stats.texels_per_second = stats.texels as f64 / stats.seconds.max(1e-9);
    (src, stats)
}

#[cfg(test)]
mod tests {
    use super::*;
    use subdiv::{ControlMesh, Surface};

    #[test]
    fn growth_order_visits_every_texel_once_and_grows_from_a_seed() {
        let s = Surface::new(ControlMesh::grid(3));
        let n = 6;
        let g = crate::texels::TexelGeometry::compute(&s, n);
        let e = EdgeGraph::build(&s, &g);
        let order = growth_order(&e, &g.layout);
        let mut seen = vec![false; g.len()];
        for &t in &order {
            assert!(!seen[t as usize]);
            seen[t as usize] = true;
        }
        assert!(seen.iter().all(|&b| b));
        // Every texel after the first touches an earlier one (one component).
        let mut done = vec![false; g.len()];
        for (k, &t) in order.iter().enumerate() {
            if k > 0 {
                assert!(e.of(t as usize).iter().any(|&s| done[s as usize]));
            }
            done[t as usize] = true;
        }
    }
}
