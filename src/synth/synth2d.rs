//! 2D reference synthesizer: Wei–Levoy multiscale synthesis on an image grid, with the
//! surface synthesizer's levels, passes, neighbourhoods and search code.
//!
//! It is the baseline the surface method is judged against (issue 5: on a flat grid, patch
//! fidelity no worse than 1.1x that of 2D multiscale synthesis of the same example at the
//! same size), and a quick way to check search changes without a mesh. Paper 000 notes
//! that "one can predict the results of the surface synthesis by running the 2D
//! algorithms"; keeping everything but neighbourhood sampling shared makes that literal.
//!
//! Procedure (000 §4 on an image):
//! * output pyramid level `l` is `ceil(W / 2^l) x ceil(H / 2^l)`, paired with example
//!   level `l`;
//! * the coarsest level is filled in scan-line order by exhaustive search with the
//!   `coarsest x coarsest` block of already generated pixels (a causal neighbourhood);
//! * each finer level gets pass 1 (coarser block only; every pixel independent) and pass 2
//!   (fine block of the level plus the coarser block), see [`Schedule`] for the order of
//!   pass 2.
//!
//! The output is not toroidal: samples outside it are missing, as they are off the edge of
//! an open surface, so the flat-grid comparison sees the same border conditions.
//!
//! Determinism: random choices hash (seed, level, pass, pixel); pass 1 and Jacobi pass 2
//! read only the previous state; the tiled pass 2 processes tiles in four fixed phases
//! whose tiles never read each other. The result is the same for any thread count.

use crate::error::{Error, Result};
use crate::pyramid::{levels_for, Image};
use crate::random::hash;
use crate::synth::matching::search::model::{ExampleModel, ModelParams, Pass, Scratch};
use crate::synth::matching::search::{pick, Prepared, Query};
use rayon::prelude::*;

/// Order of pass 2 within a level.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Schedule {
    /// Every pixel reads the pass-1 state (fully parallel; no propagation within a pass).
    Jacobi,
    /// Gauss–Seidel in scan-line order inside 16x16 tiles; tiles in four phases by
    /// (column parity, row parity), so tiles of one phase are at least 16 pixels apart —
    /// beyond any neighbourhood's reach — and run in parallel without reading each other.
    Tiled,
}

/// Side of the tiles of [`Schedule::Tiled`]; must exceed the fine block's and the
/// k-coherence window's reach (4).
pub const TILE: usize = 16;

/// Settings of a 2D run.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Params2d {
    pub width: usize,
    pub height: usize,
    /// Pyramid levels; 0 picks [`auto_levels`].
    pub levels: usize,
    pub seed: u64,
    pub model: ModelParams,
    pub schedule: Schedule,
}

impl Params2d {
    /// Defaults for a `width x height` output.
    pub fn new(width: usize, height: usize) -> Self {
        Self {
            width,
            height,
            levels: 0,
            seed: 0,
            model: ModelParams::default(),
            schedule: Schedule::Tiled,
        }
    }
}

/// Levels for an example: halve while the example's coarsest level keeps a side of at least
/// 16 pixels (room for a 9x9 block with a few candidates beside it), at most 6 levels.
pub fn auto_levels(ex_width: usize, ex_height: usize) -> usize {
    levels_for(ex_width, ex_height, 16, 6)
}

/// Counters of a run.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Stats {
    /// Neighbourhood searches.
    pub queries: u64,
    /// Candidate distances evaluated (exhaustive searches count every pixel).
    pub candidates: u64,
}

/// Result of a 2D run.
#[derive(Clone, Debug)]
pub struct Output2d {
    /// Level-0 output, example channels.
    pub image: Image,
    /// Per output pixel, the continuous level-0 example position its value was copied from
    /// (pixel centres at +0.5).
    pub source: Vec<[f32; 2]>,
    pub levels: usize,
    pub stats: Stats,
}

/// One output level: values, source pixel (in the paired example level) and whether
/// generated.
#[derive(Clone)]
struct Level {
    w: usize,
    h: usize,
    c: usize,
    vals: Vec<f32>,
    src: Vec<[u32; 2]>,
    done: Vec<bool>,
}

impl Level {
    fn new(w: usize, h: usize, c: usize) -> Self {
        Self {
            w,
            h,
            c,
            vals: vec![0.0; w * h * c],
            src: vec![[0, 0]; w * h],
            done: vec![false; w * h],
        }
    }
    #[inline]
    fn val(&self, i: usize) -> &[f32] {
        &self.vals[i * self.c..(i + 1) * self.c]
    }
    /// Bilinear value at continuous (x, y); None outside the level's extent.
    #[inline]
    fn sample(&self, x: f32, y: f32, out: &mut [f32]) -> bool {
        if !(x >= 0.0 && y >= 0.0 && x <= self.w as f32 && y <= self.h as f32) {
            return false;
        }
        let fx = (x - 0.5).clamp(0.0, (self.w - 1) as f32);
        let fy = (y - 0.5).clamp(0.0, (self.h - 1) as f32);
        let (x0, y0) = (fx as usize, fy as usize);
        let (x1, y1) = ((x0 + 1).min(self.w - 1), (y0 + 1).min(self.h - 1));
        let (tx, ty) = (fx - x0 as f32, fy - y0 as f32);
        let (a, b) = (self.val(y0 * self.w + x0), self.val(y0 * self.w + x1));
        let (d, e) = (self.val(y1 * self.w + x0), self.val(y1 * self.w + x1));
        for k in 0..self.c {
            let top = a[k] + (b[k] - a[k]) * tx;
            let bot = d[k] + (e[k] - d[k]) * tx;
            out[k] = top + (bot - top) * ty;
        }
        true
    }
}

/// Per-thread working buffers.
struct Work {
    scratch: Scratch,
    q1: Query,
    q2: Query,
    prep: Prepared,
    seeds: Vec<u32>,
    buf: Vec<f32>,
}

impl Work {
    fn new(model: &ExampleModel, level: usize) -> Self {
        let (q1, q2) = if level == model.coarsest() {
            let s = model.shape(level, Pass::Coarsest);
            (Query::new(s), Query::new(s))
        } else {
            (
                Query::new(model.shape(level, Pass::One)),
                Query::new(model.shape(level, Pass::Two)),
            )
        };
        Self {
            scratch: Scratch::default(),
            q1,
            q2,
            prep: Prepared::default(),
            seeds: Vec::new(),
            buf: vec![0.0; model.pyramid.level(0).channels],
        }
    }
}

/// Builds the example model and synthesizes.
pub fn synthesize(example: &Image, p: &Params2d) -> Result<Output2d> {
    let levels = if p.levels == 0 {
        auto_levels(example.width, example.height)
    } else {
        p.levels
    };
    let model = ExampleModel::build(example.clone(), levels, p.model)?;
    synthesize_with(&model, p)
}

/// Synthesizes with a prebuilt model (its level count and method win over `p`'s).
pub fn synthesize_with(model: &ExampleModel, p: &Params2d) -> Result<Output2d> {
    if p.width == 0 || p.height == 0 {
        return Err(Error::invalid(format!(
            "output size must be positive, got {}x{}",
            p.width, p.height
        )));
    }
    let n_levels = model.n_levels();
    let c = model.pyramid.level(0).channels;
    let mut stats = Stats::default();
    let top = model.coarsest();
    let size = |l: usize| (p.width.div_ceil(1 << l), p.height.div_ceil(1 << l));
    let (w, h) = size(top);
    let mut cur = Level::new(w, h, c);
    coarsest_level(model, top, p.seed, &mut cur, &mut stats);
    for l in (0..top).rev() {
        let (w, h) = size(l);
        let mut next = Level::new(w, h, c);
        pass_one(model, l, p.seed, &cur, &mut next, &mut stats);
        pass_two(model, l, p.seed, p.schedule, &cur, &mut next, &mut stats);
        cur = next;
    }
    let source = cur
        .src
        .iter()
        .map(|s| [s[0] as f32 + 0.5, s[1] as f32 + 0.5])
        .collect();
    Ok(Output2d {
        image: Image {
            width: cur.w,
            height: cur.h,
            channels: c,
            data: cur.vals,
        },
        source,
        levels: n_levels,
        stats,
    })
}

/// Copies example pixel `index` of `level` into output pixel `i`.
fn assign(model: &ExampleModel, level: usize, index: u32, out: &mut Level, i: usize) {
    let (x, y) = model.pixel(level, index);
    let c = out.c;
    out.vals[i * c..(i + 1) * c].copy_from_slice(model.pyramid.level(level).pixel(x, y));
    out.src[i] = [x as u32, y as u32];
    out.done[i] = true;
}

fn key(seed: u64, level: usize, pass: Pass, i: usize) -> u64 {
    hash(seed, &[level as u64, pass.id(), i as u64])
}

/// Scan-line order, exhaustive search over the generated part of the block.
fn coarsest_level(model: &ExampleModel, level: usize, seed: u64, out: &mut Level, st: &mut Stats) {
    let mut wk = Work::new(model, level);
    let shape = model.shape(level, Pass::Coarsest);
    let offs = shape.offsets();
    let f = &model.searcher(level, Pass::Coarsest).features;
    for y in 0..out.h {
        for x in 0..out.w {
            let i = y * out.w + x;
            wk.q1.clear_all();
            for (s, o) in offs.iter().enumerate() {
                let (sx, sy) = (x as i64 + o.dx as i64, y as i64 + o.dy as i64);
                if sx >= 0 && sy >= 0 && (sx as usize) < out.w && (sy as usize) < out.h {
                    let j = sy as usize * out.w + sx as usize;
                    if out.done[j] {
                        wk.q1.set(s, out.val(j));
                    }
                }
            }
            let k = key(seed, level, Pass::Coarsest, i);
            let index = if wk.q1.present_count() == 0 {
                // Nothing to match yet (the first pixel): a random example pixel.
                (k % model.candidates(level) as u64) as u32
            } else {
                f.prepare(&wk.q1, &mut wk.prep);
                st.candidates +=
                    model.search(level, Pass::Coarsest, &wk.prep, &[], &mut wk.scratch) as u64;
                st.queries += 1;
                pick(wk.scratch.top.as_slice(), k).index
            };
            assign(model, level, index, out, i);
        }
    }
}

/// Fills the coarse block of `q` for output pixel (x, y) of the finer level.
fn coarse_block(
    q: &mut Query,
    first: usize,
    offs: &[crate::synth::matching::search::Offset],
    coarse: &Level,
    x: usize,
    y: usize,
    buf: &mut [f32],
) {
    let (cx, cy) = ((x as f32 + 0.5) / 2.0, (y as f32 + 0.5) / 2.0);
    for (s, o) in offs.iter().enumerate().skip(first) {
        if coarse.sample(cx + o.dx as f32, cy + o.dy as f32, buf) {
            q.set(s, buf);
        } else {
            q.clear(s);
        }
    }
}

/// k-coherence seeds for pass 1: forward-shifted sources of the coarse pixels around the
/// parent position, scaled to this level.
fn seeds_from_coarse(
    model: &ExampleModel,
    level: usize,
    window: usize,
    coarse: &Level,
    x: usize,
    y: usize,
    seeds: &mut Vec<u32>,
) {
    seeds.clear();
    let (cx, cy) = ((x as f32 + 0.5) / 2.0, (y as f32 + 0.5) / 2.0);
    let (bx, by) = (cx.floor() as i64, cy.floor() as i64);
    let r = (window / 2) as i64;
    for qy in by - r..=by + r {
        for qx in bx - r..=bx + r {
            if qx < 0 || qy < 0 || qx as usize >= coarse.w || qy as usize >= coarse.h {
                continue;
            }
            let s = coarse.src[qy as usize * coarse.w + qx as usize];
            let px = s[0] as f32 + 0.5 + (cx - (qx as f32 + 0.5));
            let py = s[1] as f32 + 0.5 + (cy - (qy as f32 + 0.5));
            seeds.push(model.nearest_index(level, 2.0 * px, 2.0 * py));
        }
    }
}

fn kwindow(model: &ExampleModel) -> Option<usize> {
    match model.params.method {
        crate::synth::matching::search::model::Method::KCoherence(k) => Some(k.window),
        _ => None,
    }
}

/// Pass 1: each pixel from the coarser level alone.
fn pass_one(
    model: &ExampleModel,
    level: usize,
    seed: u64,
    coarse: &Level,
    out: &mut Level,
    st: &mut Stats,
) {
    let offs = model.shape(level, Pass::One).offsets();
    let f = &model.searcher(level, Pass::One).features;
    let win = kwindow(model);
    let w = out.w;
    let results: Vec<(u32, usize)> = (0..out.w * out.h)
        .into_par_iter()
        .map_init(
            || Work::new(model, level),
            |wk, i| {
                let (x, y) = (i % w, i / w);
                coarse_block(&mut wk.q1, 0, &offs, coarse, x, y, &mut wk.buf);
                f.prepare(&wk.q1, &mut wk.prep);
                if let Some(win) = win {
                    seeds_from_coarse(model, level, win, coarse, x, y, &mut wk.seeds);
                }
                let n = model.search(level, Pass::One, &wk.prep, &wk.seeds, &mut wk.scratch);
                (
                    pick(wk.scratch.top.as_slice(), key(seed, level, Pass::One, i)).index,
                    n,
                )
            },
        )
        .collect();
    for (i, &(index, n)) in results.iter().enumerate() {
        assign(model, level, index, out, i);
        st.candidates += n as u64;
    }
    st.queries += results.len() as u64;
}

/// Pass 2 for pixel (x, y): `read(x, y)` gives the current value and source of a pixel of
/// this level.
#[allow(clippy::too_many_arguments)]
fn refine_pixel<'a>(
    model: &ExampleModel,
    level: usize,
    seed: u64,
    coarse: &Level,
    w: usize,
    h: usize,
    x: usize,
    y: usize,
    offs: &[crate::synth::matching::search::Offset],
    n_fine: usize,
    read: &dyn Fn(usize) -> (&'a [f32], [u32; 2]),
    wk: &mut Work,
) -> (u32, usize) {
    let f = &model.searcher(level, Pass::Two).features;
    for (s, o) in offs.iter().enumerate().take(n_fine) {
        let (sx, sy) = (x as i64 + o.dx as i64, y as i64 + o.dy as i64);
        if sx >= 0 && sy >= 0 && (sx as usize) < w && (sy as usize) < h {
            wk.q2.set(s, read(sy as usize * w + sx as usize).0);
        } else {
            wk.q2.clear(s);
        }
    }
    coarse_block(&mut wk.q2, n_fine, offs, coarse, x, y, &mut wk.buf);
    f.prepare(&wk.q2, &mut wk.prep);
    wk.seeds.clear();
    if let Some(win) = kwindow(model) {
        let r = (win / 2) as i64;
        for qy in y as i64 - r..=y as i64 + r {
            for qx in x as i64 - r..=x as i64 + r {
                if qx < 0 || qy < 0 || qx as usize >= w || qy as usize >= h {
                    continue;
                }
                let s = read(qy as usize * w + qx as usize).1;
                let px = s[0] as f32 + 0.5 + (x as f32 - qx as f32);
                let py = s[1] as f32 + 0.5 + (y as f32 - qy as f32);
                wk.seeds.push(model.nearest_index(level, px, py));
            }
        }
    }
    let n = model.search(level, Pass::Two, &wk.prep, &wk.seeds, &mut wk.scratch);
    let i = y * w + x;
    (
        pick(wk.scratch.top.as_slice(), key(seed, level, Pass::Two, i)).index,
        n,
    )
}

/// Pass 2: refine with the level's own block plus the coarser block.
fn pass_two(
    model: &ExampleModel,
    level: usize,
    seed: u64,
    schedule: Schedule,
    coarse: &Level,
    out: &mut Level,
    st: &mut Stats,
) {
    let shape = model.shape(level, Pass::Two);
    let offs = shape.offsets();
    let n_fine = shape.fine * shape.fine;
    let (w, h) = (out.w, out.h);
    match schedule {
        Schedule::Jacobi => {
            let old = out.clone();
            let read = |j: usize| (old.val(j), old.src[j]);
            let results: Vec<(u32, usize)> = (0..w * h)
                .into_par_iter()
                .map_init(
                    || Work::new(model, level),
                    |wk, i| {
                        refine_pixel(
                            model,
                            level,
                            seed,
                            coarse,
                            w,
                            h,
                            i % w,
                            i / w,
                            &offs,
                            n_fine,
                            &read,
                            wk,
                        )
                    },
                )
                .collect();
            for (i, &(index, n)) in results.iter().enumerate() {
                assign(model, level, index, out, i);
                st.candidates += n as u64;
            }
            st.queries += results.len() as u64;
        }
        Schedule::Tiled => {
            let (tw, th) = (w.div_ceil(TILE), h.div_ceil(TILE));
            for phase in 0..4 {
                let tiles: Vec<(usize, usize)> = (0..th)
                    .flat_map(|ty| (0..tw).map(move |tx| (tx, ty)))
                    .filter(|&(tx, ty)| (tx % 2) + 2 * (ty % 2) == phase)
                    .collect();
                let snapshot: &Level = out;
                let updates: Vec<Vec<(usize, u32, usize)>> = tiles
                    .par_iter()
                    .map_init(
                        || Work::new(model, level),
                        |wk, &(tx, ty)| {
                            let (x0, y0) = (tx * TILE, ty * TILE);
                            let (x1, y1) = ((x0 + TILE).min(w), (y0 + TILE).min(h));
                            // The tile's own pixels, updated as the scan proceeds.
                            let mut local = Level::new(x1 - x0, y1 - y0, snapshot.c);
                            for yy in y0..y1 {
                                for xx in x0..x1 {
                                    let (gi, li) = (yy * w + xx, (yy - y0) * (x1 - x0) + xx - x0);
                                    local.vals[li * local.c..(li + 1) * local.c]
                                        .copy_from_slice(snapshot.val(gi));
                                    local.src[li] = snapshot.src[gi];
                                }
                            }
                            let mut ups = Vec::with_capacity((x1 - x0) * (y1 - y0));
                            for yy in y0..y1 {
                                for xx in x0..x1 {
                                    let (index, n) = {
                                        let lref = &local;
                                        let read = |j: usize| {
                                            let (jx, jy) = (j % w, j / w);
                                            if jx >= x0 && jx < x1 && jy >= y0 && jy < y1 {
                                                let li = (jy - y0) * (x1 - x0) + jx - x0;
                                                (lref.val(li), lref.src[li])
                                            } else {
                                                (snapshot.val(j), snapshot.src[j])
                                            }
                                        };
                                        refine_pixel(
                                            model, level, seed, coarse, w, h, xx, yy, &offs,
                                            n_fine, &read, wk,
                                        )
                                    };
                                    let li = (yy - y0) * (x1 - x0) + xx - x0;
                                    assign(model, level, index, &mut local, li);
                                    ups.push((yy * w + xx, index, n));
                                }
                            }
                            ups
                        },
                    )
                    .collect();
                for ups in updates {
                    for (i, index, n) in ups {
                        assign(model, level, index, out, i);
                        st.candidates += n as u64;
                        st.queries += 1;
                    }
                }
            }
        }
    }
}

/// Patch fidelity of a 2D output (BRIEF.md): the mean Euclidean distance from each
/// `patch x patch` output patch (every `stride`-th position in each direction) to its
/// nearest example patch, divided by the mean distance between `pairs` random pairs of
/// example patches. Colour channels only (the first three, or fewer). 0 means every output
/// patch occurs in the example; 1 means output patches are as far from the example as
/// random example patches are from each other.
pub fn patch_fidelity(
    output: &Image,
    example: &Image,
    patch: usize,
    stride: usize,
    pairs: usize,
    seed: u64,
) -> f64 {
    let c = output.channels.min(example.channels).min(3);
    let extract = |img: &Image, x: usize, y: usize, out: &mut Vec<f32>| {
        out.clear();
        for yy in y..y + patch {
            for xx in x..x + patch {
                out.extend_from_slice(&img.pixel(xx, yy)[..c]);
            }
        }
    };
    let (ew, eh) = (example.width + 1 - patch, example.height + 1 - patch);
    let mut ex = Vec::with_capacity(ew * eh * patch * patch * c);
    let mut buf = Vec::new();
    for y in 0..eh {
        for x in 0..ew {
            extract(example, x, y, &mut buf);
            ex.extend_from_slice(&buf);
        }
    }
    let d = patch * patch * c;
    let ne = ew * eh;
    let positions: Vec<(usize, usize)> = (0..=output.height - patch)
        .step_by(stride.max(1))
        .flat_map(|y| {
            (0..=output.width - patch)
                .step_by(stride.max(1))
                .map(move |x| (x, y))
        })
        .collect();
    let nearest: Vec<f64> = positions
        .par_iter()
        .map_init(Vec::new, |b, &(x, y)| {
            extract(output, x, y, b);
            let mut best = f32::INFINITY;
            for j in 0..ne {
                let dd =
                    crate::synth::matching::search::dist_bounded(b, &ex[j * d..(j + 1) * d], best);
                if dd < best {
                    best = dd;
                }
            }
            (best.max(0.0) as f64).sqrt()
        })
        .collect();
    let mean_nearest = nearest.iter().sum::<f64>() / nearest.len().max(1) as f64;
    let mut total = 0.0f64;
    for t in 0..pairs {
        let a = (hash(seed, &[t as u64, 0]) % ne as u64) as usize;
        let mut b = (hash(seed, &[t as u64, 1]) % ne as u64) as usize;
        if b == a {
            b = (a + 1) % ne;
        }
        let dd = crate::synth::matching::search::dist_bounded(
            &ex[a * d..(a + 1) * d],
            &ex[b * d..(b + 1) * d],
            f32::INFINITY,
        );
        total += (dd as f64).sqrt();
    }
    mean_nearest / (total / pairs.max(1) as f64)
}
