//! Per-face texel maps and bilinear fetch at any (domain, u, v), across face edges and
//! corners (Ying et al. 2001, §5 step 1: "neighbouring domains' texels are used near
//! borders").
//!
//! Layout ([`TexelLayout`]): F domains of nu×nv texels (one N for all, or per-face under
//! `--texel-size`) × C f32 channels, texel (x, y) of domain d at global index
//! start(d) + y·nu + x, centre (u, v) = ((x + 0.5)/nu, (y + 0.5)/nv) — the same layout as
//! `facemaps.exr` tiles and [`crate::texels::TexelGeometry`].
//!
//! A bilinear fetch near a border needs texel centres just outside [0, 1]², which belong to
//! a neighbouring domain (possibly rotated, possibly at a different scale where a quad
//! domain meets an n-gon sub-face, possibly around an extraordinary corner). [`MapLayout`]
//! precomputes, once per layout, a *ring* of 2(nu + nv) + 4 such outside centres per domain:
//! each is found by walking straight from the nearest inside centre across the edge
//! ([`subdiv::Surface::walk`]) and stored as the (edge-clamped) bilinear taps of the
//! neighbour at the point reached. A fetch is then at most 4 × 4 table reads, with no walk
//! and no allocation. Outside an open boundary the ring repeats the nearest inside texel.

use crate::layout::TexelLayout;
use rayon::prelude::*;
use std::sync::Arc;
use subdiv::{DomainId, DomainLocation, Surface};

/// `x.floor()`, bit for bit, without a call. *Why*: the baseline x86-64 target has no
/// rounding instruction (SSE4.1's `roundsd`), so `f64::floor` is a call into the
/// compiler's soft implementation — ~2% of a multiscale run, where every fetch and every
/// pattern sample's position floors two coordinates (issue 14). Below 2^52 in magnitude
/// truncation toward zero is exact; one step down for negative non-integers gives the
/// floor; zeros keep their sign (floor(−0) = −0); everything else (NaN, huge values) takes
/// `f64::floor`.
#[inline(always)]
pub fn floor(x: f64) -> f64 {
    const BIG: f64 = 4_503_599_627_370_496.0; // 2^52
    if x > -BIG && x < BIG && x != 0.0 {
        let t = (x as i64) as f64;
        if t > x {
            t - 1.0
        } else {
            t
        }
    } else {
        x.floor()
    }
}

/// Texel-index and weight pairs whose weighted sum is a bilinear fetch.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Taps {
    pub idx: [u32; 16],
    pub w: [f32; 16],
    pub len: usize,
}

impl Taps {
    #[inline]
    fn push(&mut self, i: u32, w: f32) {
        if w != 0.0 {
            self.idx[self.len] = i;
            self.w[self.len] = w;
            self.len += 1;
        }
    }

    /// The (index, weight) pairs.
    pub fn iter(&self) -> impl Iterator<Item = (usize, f32)> + '_ {
        self.idx[..self.len]
            .iter()
            .zip(&self.w[..self.len])
            .map(|(&i, &w)| (i as usize, w))
    }
}

/// Neighbour taps of one ring texel (weights sum to 1).
#[derive(Clone, Copy, Debug, PartialEq)]
struct Ring {
    idx: [u32; 4],
    w: [f32; 4],
}

/// Texel layout ([`TexelLayout`]: one N, or per-face resolutions), with the cross-face
/// ring (see the module doc).
#[derive(Clone, Debug)]
pub struct MapLayout {
    texels: Arc<TexelLayout>,
    /// First ring slot of every domain (F + 1 entries): 2(nu + 2) + 2nv per domain (see
    /// [`ring_slot`]).
    ring_start: Vec<usize>,
    ring: Vec<Ring>,
}

/// Position of outside texel (x, y) ∈ [−1, nu] × [−1, nv] \ [0, nu) × [0, nv) in a domain's
/// ring: the row y = −1 (x = −1..=nu), the row y = nv, then the columns x = −1 and x = nu
/// (y = 0..nv).
#[inline]
fn ring_slot(nu: usize, nv: usize, x: i64, y: i64) -> usize {
    let (nu, nv) = (nu as i64, nv as i64);
    (if y < 0 {
        x + 1
    } else if y >= nv {
        nu + 2 + x + 1
    } else if x < 0 {
        2 * (nu + 2) + y
    } else {
        2 * (nu + 2) + nv + y
    }) as usize
}

/// Clamped bilinear taps of a point of domain `d` (texel centres outside are clamped to the
/// border row/column: used for ring texels, whose points lie within half a texel of an
/// edge of their own domain).
fn clamped_taps(layout: &TexelLayout, d: usize, u: f64, v: f64) -> Ring {
    let (nu, nv) = layout.dims(d);
    let base = layout.start(d) as u32;
    let axis = |t: f64, n: usize| -> (usize, usize, f64) {
        let f = (t * n as f64 - 0.5).clamp(0.0, (n - 1) as f64);
        let i0 = (f.floor() as usize).min(n.saturating_sub(2));
        let i1 = (i0 + 1).min(n - 1);
        (i0, i1, (f - i0 as f64).clamp(0.0, 1.0))
    };
    let (x0, x1, ax) = axis(u, nu);
    let (y0, y1, ay) = axis(v, nv);
    let at = |x: usize, y: usize| base + (y * nu + x) as u32;
    Ring {
        idx: [at(x0, y0), at(x1, y0), at(x0, y1), at(x1, y1)],
        w: [
            ((1.0 - ax) * (1.0 - ay)) as f32,
            (ax * (1.0 - ay)) as f32,
            ((1.0 - ax) * ay) as f32,
            (ax * ay) as f32,
        ],
    }
}

impl MapLayout {
    /// Builds the layout and ring for `n`×`n` maps on every domain of `surface`.
    pub fn new(surface: &Surface, n: usize) -> Self {
        assert!(n >= 1, "map resolution must be at least 1");
        Self::with_layout(
            surface,
            Arc::new(TexelLayout::uniform(surface.num_domains(), n)),
        )
    }

    /// Builds the ring for the maps of `texels` on every domain of `surface` (parallel;
    /// the result does not depend on the thread count). Neighbours may have any
    /// resolution: a ring texel is a point reached by a walk of one of *this* domain's
    /// texels, and it is looked up bilinearly in the neighbour's own grid.
    pub fn with_layout(surface: &Surface, texels: Arc<TexelLayout>) -> Self {
        let faces = surface.num_domains();
        assert_eq!(faces, texels.faces());
        let mut ring_start = Vec::with_capacity(faces + 1);
        ring_start.push(0);
        for d in 0..faces {
            let (nu, nv) = texels.dims(d);
            ring_start.push(ring_start[d] + 2 * (nu + 2) + 2 * nv);
        }
        let mut ring = vec![
            Ring {
                idx: [0; 4],
                w: [0.0; 4],
            };
            ring_start[faces]
        ];
        let mut chunks: Vec<&mut [Ring]> = Vec::with_capacity(faces);
        let mut rest = ring.as_mut_slice();
        for d in 0..faces {
            let (a, b) = std::mem::take(&mut rest).split_at_mut(ring_start[d + 1] - ring_start[d]);
            chunks.push(a);
            rest = b;
        }
        let layout = &texels;
        chunks.into_par_iter().enumerate().for_each(|(d, slots)| {
            let (nu, nv) = layout.dims(d);
            let (iu, iv) = (1.0 / nu as f64, 1.0 / nv as f64);
            let (niu, niv) = (nu as i64, nv as i64);
            let base = layout.start(d) as u32;
            let mut fill = |x: i64, y: i64| {
                let cx = x.clamp(0, niu - 1);
                let cy = y.clamp(0, niv - 1);
                let start = DomainLocation {
                    domain: DomainId::from_idx(d),
                    u: (cx as f64 + 0.5) * iu,
                    v: (cy as f64 + 0.5) * iv,
                };
                let du = (x - cx) as f64 * iu;
                let dv = (y - cy) as f64 * iv;
                slots[ring_slot(nu, nv, x, y)] = match surface.walk(start, du, dv) {
                    Some(l) => clamped_taps(layout, l.domain.idx(), l.u, l.v),
                    None => Ring {
                        idx: [base + (cy * niu + cx) as u32, 0, 0, 0],
                        w: [1.0, 0.0, 0.0, 0.0],
                    },
                };
            };
            for x in -1..=niu {
                fill(x, -1);
                fill(x, niv);
            }
            for y in 0..niv {
                fill(-1, y);
                fill(niu, y);
            }
        });
        MapLayout {
            texels,
            ring_start,
            ring,
        }
    }

    /// The texel layout.
    pub fn texels_layout(&self) -> &Arc<TexelLayout> {
        &self.texels
    }

    /// Texels per side when every domain has the same N (`--resolution`).
    pub fn uniform_n(&self) -> Option<usize> {
        self.texels.uniform_n()
    }

    /// (texels along u, along v) of domain `d`.
    pub fn dims(&self, d: usize) -> (usize, usize) {
        self.texels.dims(d)
    }

    /// Number of face domains.
    pub fn faces(&self) -> usize {
        self.texels.faces()
    }

    /// Total number of texels.
    pub fn texels(&self) -> usize {
        self.texels.len()
    }

    /// Global index of texel (x, y) of domain `d`.
    #[inline]
    pub fn texel_index(&self, d: DomainId, x: usize, y: usize) -> usize {
        self.texels.index(d.idx(), x, y)
    }

    /// Domain and texel-centre location of a global texel index.
    #[inline]
    pub fn texel_location(&self, i: usize) -> DomainLocation {
        self.texels.location(i)
    }

    /// Bilinear taps at a domain point: the four texel centres around (u, v), those outside
    /// the domain taken from the neighbours through the ring. (u, v) is clamped to [0, 1]².
    #[inline]
    pub fn taps(&self, loc: DomainLocation) -> Taps {
        let d = loc.domain.idx();
        let (nu, nv) = self.texels.dims(d);
        let (niu, niv) = (nu as i64, nv as i64);
        let fx = loc.u.clamp(0.0, 1.0) * nu as f64 - 0.5;
        let fy = loc.v.clamp(0.0, 1.0) * nv as f64 - 0.5;
        let (x0, y0) = (floor(fx) as i64, floor(fy) as i64);
        let (ax, ay) = ((fx - x0 as f64) as f32, (fy - y0 as f64) as f32);
        let mut t = Taps {
            idx: [0; 16],
            w: [0.0; 16],
            len: 0,
        };
        let base = self.texels.start(d) as u32;
        let ring = &self.ring[self.ring_start[d]..self.ring_start[d + 1]];
        for (dy, wy) in [(0, 1.0 - ay), (1, ay)] {
            for (dx, wx) in [(0, 1.0 - ax), (1, ax)] {
                let w = wx * wy;
                if w == 0.0 {
                    continue;
                }
                let (x, y) = (x0 + dx, y0 + dy);
                if (0..niu).contains(&x) && (0..niv).contains(&y) {
                    t.push(base + (y * niu + x) as u32, w);
                } else {
                    let r = &ring[ring_slot(nu, nv, x, y)];
                    for k in 0..4 {
                        t.push(r.idx[k], w * r.w[k]);
                    }
                }
            }
        }
        t
    }
}

/// All domains' texels × C channels of f32 (layout in the module doc).
#[derive(Clone, Debug)]
pub struct FaceMaps {
    layout: Arc<MapLayout>,
    channels: usize,
    data: Vec<f32>,
}

impl FaceMaps {
    /// Zero-filled maps.
    pub fn new(layout: Arc<MapLayout>, channels: usize) -> Self {
        let len = layout.texels() * channels;
        FaceMaps {
            layout,
            channels,
            data: vec![0.0; len],
        }
    }

    /// Maps over existing data (`data.len()` must be texels × channels).
    pub fn from_data(layout: Arc<MapLayout>, channels: usize, data: Vec<f32>) -> Self {
        assert_eq!(
            data.len(),
            layout.texels() * channels,
            "map data does not match {} texels x {channels} channels",
            layout.texels()
        );
        FaceMaps {
            layout,
            channels,
            data,
        }
    }

    pub fn layout(&self) -> &Arc<MapLayout> {
        &self.layout
    }

    pub fn channels(&self) -> usize {
        self.channels
    }

    pub fn data(&self) -> &[f32] {
        &self.data
    }

    pub fn data_mut(&mut self) -> &mut [f32] {
        &mut self.data
    }

    /// Channels of global texel `i`.
    #[inline]
    pub fn texel(&self, i: usize) -> &[f32] {
        &self.data[i * self.channels..(i + 1) * self.channels]
    }

    #[inline]
    pub fn texel_mut(&mut self, i: usize) -> &mut [f32] {
        let c = self.channels;
        &mut self.data[i * c..(i + 1) * c]
    }

    /// Bilinear fetch of all channels at `loc` into `out` (length ≥ channels).
    #[inline]
    pub fn sample(&self, loc: DomainLocation, out: &mut [f32]) {
        let c = self.channels;
        out[..c].fill(0.0);
        let t = self.layout.taps(loc);
        for (i, w) in t.iter() {
            let src = &self.data[i * c..(i + 1) * c];
            for (o, s) in out[..c].iter_mut().zip(src) {
                *o += w * s;
            }
        }
    }

    /// The paper's fetch during synthesis (000 §4): bilinear if every texel involved is
    /// `valid`, else the valid texel with the largest bilinear weight, else nothing
    /// (returns false and leaves `out` unspecified).
    #[inline]
    pub fn sample_valid(
        &self,
        loc: DomainLocation,
        valid: impl Fn(usize) -> bool,
        out: &mut [f32],
    ) -> bool {
        let c = self.channels;
        let t = self.layout.taps(loc);
        let mut all = true;
        let mut best: Option<(usize, f32)> = None;
        for (i, w) in t.iter() {
            if valid(i) {
                if best.is_none_or(|(_, bw)| w > bw) {
                    best = Some((i, w));
                }
            } else {
                all = false;
            }
        }
        if all && t.len > 0 {
            self.sample(loc, out);
            return true;
        }
        match best {
            Some((i, _)) => {
                out[..c].copy_from_slice(self.texel(i));
                true
            }
            None => false,
        }
    }
}

#[cfg(test)]
mod floor_tests {
    #[test]
    fn floor_is_f64_floor_bit_for_bit() {
        let mut xs = vec![
            0.0,
            -0.0,
            0.5,
            -0.5,
            1.0,
            -1.0,
            -1.5,
            2.999_999_999,
            -2.000_000_001,
            f64::MIN_POSITIVE,
            -f64::MIN_POSITIVE,
            4_503_599_627_370_495.5,
            -4_503_599_627_370_495.5,
            4_503_599_627_370_496.0,
            1e300,
            -1e300,
            f64::INFINITY,
            f64::NEG_INFINITY,
        ];
        // A deterministic spread of values around texel coordinates.
        let mut z = 0x9E37_79B9_7F4A_7C15u64;
        for _ in 0..100_000 {
            z ^= z << 13;
            z ^= z >> 7;
            z ^= z << 17;
            xs.push((z as f64 / u64::MAX as f64 - 0.5) * 300.0);
        }
        for x in xs {
            assert_eq!(super::floor(x).to_bits(), x.floor().to_bits(), "{x}");
        }
        assert!(super::floor(f64::NAN).is_nan());
    }
}
