//! The surface half of pfS (docs/eval.md, "Patch fidelity"): windows laid on any mesh —
//! curved, with n-gon sub-faces, with open boundaries — and the lattice test that sends
//! flat aligned grids to the 2D code instead.
//!
//! Why a point cloud: the texel centres of all domains, in one k-d tree, are the surface as
//! the maps sample it. A window that crosses a face edge simply finds the next face's
//! texels; no domain adjacency or chart is needed, and any program that writes the same
//! maps is measured the same way.
//!
//! For a drawn texel t:
//! 1. **Directions.** A least-squares fit of t's source position against the limit
//!    positions of its *coherent* neighbours (texels within [`FIT_RADIUS`] local spacings,
//!    in any face, whose source is within 4 px per unit of grid distance of t's, BRIEF's
//!    threshold) gives the 2x2 Jacobian M = d(source)/d(tangent coordinates); the columns
//!    of M⁻¹ are a and b, the tangent vectors along which t's source advances by one pixel
//!    in u and in v. A fit is usable when it has ≥ 3 neighbours spanning the plane, an RMS
//!    residual ≤ 1 px, anisotropy σ₁/σ₂ ≤ 4 and pixel lengths within a factor 4 of the
//!    scale. Otherwise (no source channels, isolated texel, noise) the **fallback**: the
//!    face's own texel directions (x and y neighbours in t's domain) scaled to the scale —
//!    on a flat grid with `--orient +x`, exactly the pixel grid.
//! 2. **Walk.** The centre row is walked from t along ±a, 3 samples S pixels apart each way,
//!    then from every row sample the column along ±b. Each walk advances in steps of at most
//!    one texel spacing (at most 64 steps per sample spacing); after each step the point is projected onto the tangent plane of
//!    its nearest texel and a, b are projected onto that plane (lengths kept): a discrete
//!    parallel transport, so a window on a curved surface is geodesic-like, not a chord.
//!    Row and column walks go on ⌊S/2⌋ pixels past the outer samples (their discs). A walk
//!    point farther than [`OFF_SURFACE`] local spacings (the largest distance from the
//!    nearest texel to its in-face neighbours) from its nearest texel, measured in that
//!    texel's tangent plane, has left the surface: the window is skipped.
//! 3. **Samples.** S = 1: the colour of the texel nearest to the sample point. S > 1: the
//!    mean colour of the texels whose offset from the sample point, written as αa + βb in
//!    the transported directions, has α² + β² ≤ (S/2)² — the disc of diameter S example
//!    pixels as t's source map sees it — leaving out texels of other sheets (normal offset
//!    above half the disc radius plus half a spacing, or normal turned by more than 60°).
//!    An empty disc takes the nearest texel.

use super::pf::{
    draw, draw_from, image_patch_fidelities_as, score_scale, PatchFidelity, PfMethod, PfOptions,
    Rgb, DIMS, PF_SCALES, WINDOW,
};
use super::texel_bvh::{TexelBvh, Xyz};
use crate::example::Example;
use crate::io::exr::FaceMaps;
use glam::DVec3;
use rayon::prelude::*;
use std::sync::atomic::{AtomicU32, Ordering};

/// Neighbours within this many local texel spacings enter a texel's fit (its 5x5 block
/// without the corners on a regular grid).
pub const FIT_RADIUS: f64 = 2.05;
/// BRIEF's coherence threshold: source positions within 4 px per unit of grid distance.
pub const COHERENT_PER_TEXEL: f64 = 4.0;
/// Fewest coherent neighbours of a usable fit.
const MIN_FIT_NEIGHBOURS: usize = 3;
/// Largest ratio of the fit's singular values.
const MAX_ANISOTROPY: f64 = 4.0;
/// Largest factor between a fitted pixel length and the scale (either way).
const MAX_STRETCH: f64 = 4.0;
/// Largest RMS residual of a usable fit, in pixels.
const MAX_RESIDUAL_PX: f64 = 1.0;
/// A walk point farther than this many local spacings from its nearest texel (in the
/// texel's tangent plane) is off the surface. On the surface a point is at most √2/2 of
/// the larger spacing from a texel centre (a cell's centre, or a corner of the half-cell
/// strip between the outer texels and the boundary); a point past an open boundary is at
/// least half a spacing plus its distance beyond from every texel. So a sample that the
/// pixel grid would not have (a full spacing beyond the last texel) is refused, as on the
/// lattice.
pub const OFF_SURFACE: f64 = 0.75;
/// Most sub-steps of one walk call (one sample spacing or one disc radius).
const MAX_STEPS: usize = 64;
/// Relative band around a threshold within which a disc sample's tests computed another
/// way (without divisions or roots) defer to the module's own formulas: far above their
/// few ulps of difference ([`Cloud::turned`], the disc test in `sample`).
const RIM: f64 = 1e-9;
/// Largest relative deviation of a lattice (texel positions, axes, spacing vs scale).
const LATTICE_TOL: f64 = 0.02;
/// Largest deviation of the median source step from one pixel per texel along the axes.
const LATTICE_SOURCE_TOL: f64 = 0.05;

/// Tangent directions of one pixel step in u (`a`) and v (`b`) at a texel.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Frame {
    pub a: DVec3,
    pub b: DVec3,
    pub fallback: bool,
}

/// A point walked on the surface with its transported frame.
#[derive(Clone, Copy, Debug)]
struct State {
    p: DVec3,
    a: DVec3,
    b: DVec3,
    n: DVec3,
    /// A texel near `p` (the nearest one to the point before its last projection): where
    /// the next nearest-texel search starts ([`TexelBvh::nearest`]'s hint).
    near: usize,
}

/// The texel geometry pf reads: positions, normals (optional) and the requested local
/// scale (a scale-map result, optional), each borrowed where it already is. `synth`'s
/// summary reads its texel geometry in place ([`TexelPoints::of_geometry`]) instead of a
/// second copy as geometry maps (24 B per texel at the run's peak, issue 14 item 6).
#[derive(Clone, Copy, Debug)]
pub struct TexelPoints<'a> {
    pub layout: &'a std::sync::Arc<crate::layout::TexelLayout>,
    pub pos: Xyz<'a>,
    pub normal: Option<Xyz<'a>>,
    /// geometry.exr's `scale` channel ([`crate::scale_field::CHANNEL`]).
    pub local_scale: Option<&'a [f32]>,
}

impl<'a> TexelPoints<'a> {
    /// Geometry maps: `None` without `P.X P.Y P.Z`; normals when all of `N.X N.Y N.Z` are
    /// there.
    pub fn of_maps(geometry: &'a FaceMaps) -> Option<Self> {
        let ch = |n: &str| geometry.channel(n);
        Some(Self {
            layout: &geometry.layout,
            pos: Xyz::Planar([ch("P.X")?, ch("P.Y")?, ch("P.Z")?]),
            normal: match (ch("N.X"), ch("N.Y"), ch("N.Z")) {
                (Some(x), Some(y), Some(z)) => Some(Xyz::Planar([x, y, z])),
                _ => None,
            },
            local_scale: ch(crate::scale_field::CHANNEL),
        })
    }

    /// The texel geometry in memory (the same values its geometry maps hold).
    pub fn of_geometry(
        geometry: &'a crate::texels::TexelGeometry,
        local_scale: Option<&'a [f32]>,
    ) -> Self {
        Self {
            layout: &geometry.layout,
            pos: Xyz::Packed(&geometry.pos),
            normal: Some(Xyz::Packed(&geometry.normal)),
            local_scale,
        }
    }
}

/// The texel point cloud of one result.
///
/// Per texel it holds only the lazily computed cover spacing (4 B) and its share of the
/// neighbour index ([`TexelBvh`]: two tree nodes of 32 B per 4x4 block of texels, ~4 B
/// per texel);
/// positions, normals and colours are read where they already are (the maps or the texel
/// geometry) and converted on use (exactly: f32 to f64, the normal normalised as before).
/// It used to copy them as f64 beside the tree (~110 B per texel), which made pf the peak
/// of a whole `synth` run (issue 14 item 6), and then kept a k-d tree over all texels
/// (28 B per texel, and a sort of all of them: most of the summary's time).
pub(crate) struct Cloud<'a> {
    layout: std::sync::Arc<crate::layout::TexelLayout>,
    pos: Xyz<'a>,
    /// Given normals (normalised on use; [`grid_normal`] where absent or zero).
    given: Option<Xyz<'a>>,
    col: [&'a [f32]; 3],
    src: Option<(&'a [f32], &'a [f32])>,
    /// Nearest texel and texels within a radius.
    index: TexelBvh<'a>,
    /// Every texel has a finite position and colour (the usual case).
    all_valid: bool,
    /// Per texel, the spacing that decides whether a point nearest to it is on the
    /// surface ([`Cloud::cover`]), computed on first use: 0 while unknown, else the
    /// complement of the f32 bits. Only texels walked near are asked (a few per window); at
    /// small N most texels are border texels, whose cover costs a search each (a bounded
    /// nearest search for an edge texel, a radius query for a corner), and computing all of
    /// them took most of pf's time on a 200k-quad torus at N = 4. Zero as "unknown" lets
    /// the array come from zeroed memory ([`zeroed_atomics`]): at 4 M texels it was 16 MB
    /// written with a marker before the first window, and resident to the end.
    cover: Vec<AtomicU32>,
    /// Median adjacent spacing h.
    pub h: f64,
    /// Surface length per example pixel.
    pub scale: f64,
    /// The requested local scale per texel (geometry.exr `scale`, a scale-map result):
    /// replaces `scale` in the fit's stretch bound and the fallback directions.
    local: Option<&'a [f32]>,
}

/// [`Cloud::cover`] not computed yet, as stored (the complement of a NaN pattern: a
/// computed cover with those very bits would only be computed again, to the same value).
const COVER_UNKNOWN: u32 = 0;

/// `n` atomics, all zero, from memory the allocator hands out zeroed: `vec![0u32; n]` is
/// `calloc`, which for a large array maps fresh pages (zero, untouched until used) instead
/// of writing every element as collecting `AtomicU32::new(0)` does.
fn zeroed_atomics(n: usize) -> Vec<AtomicU32> {
    const _: () = assert!(
        std::mem::size_of::<u32>() == std::mem::size_of::<AtomicU32>()
            && std::mem::align_of::<u32>() == std::mem::align_of::<AtomicU32>()
    );
    let mut v = std::mem::ManuallyDrop::new(vec![0u32; n]);
    // SAFETY: `AtomicU32` has the size and bit validity of `u32` (std docs) and, checked
    // above, its alignment: the allocation (from the global allocator, of `capacity` u32s),
    // length and capacity describe a valid `Vec<AtomicU32>` of zeros; `v` is not dropped.
    unsafe { Vec::from_raw_parts(v.as_mut_ptr().cast::<AtomicU32>(), v.len(), v.capacity()) }
}

fn channel<'a>(m: &'a FaceMaps, name: &str) -> Option<&'a [f32]> {
    m.channel(name)
}

impl<'a> Cloud<'a> {
    /// `None` without R, G, B or P channels, mismatched maps, or no finite texel.
    /// `finite`: the caller knows every texel's position and colour to be finite (`synth`
    /// checks them before writing), so they are not scanned again (4 M texels at Spot
    /// N = 128: 96 MB read) — the scan would find every texel valid.
    pub fn build(
        colour: &'a FaceMaps,
        geometry: TexelPoints<'a>,
        scale: Option<f64>,
        finite: bool,
    ) -> Option<Self> {
        let layout = colour.layout.clone();
        if *geometry.layout != colour.layout {
            return None;
        }
        let col = [
            channel(colour, "R")?,
            channel(colour, "G")?,
            channel(colour, "B")?,
        ];
        let total = layout.len();
        if geometry.pos.len() < total || col.iter().any(|c| c.len() < total) {
            return None;
        }
        let src = match (colour.channel("source.u"), colour.channel("source.v")) {
            (Some(u), Some(v)) => Some((u, v)),
            _ => None,
        };
        let pos = geometry.pos;
        let valid = |i: usize| pos.get(i).is_finite() && col.iter().all(|c| c[i].is_finite());
        let all_valid = finite || (0..total).into_par_iter().all(valid);
        debug_assert!(!finite || (0..total).into_par_iter().all(valid));
        let h = median_spacing(&layout, pos, all_valid, &valid)?;
        let index = TexelBvh::build(&layout, pos, all_valid, valid);
        Some(Self {
            pos,
            given: geometry.normal.filter(|n| n.len() >= total),
            col,
            src,
            index,
            all_valid,
            cover: zeroed_atomics(total),
            h,
            scale: scale.filter(|s| s.is_finite() && *s > 0.0).unwrap_or(h),
            local: geometry.local_scale.filter(|c| c.len() == total),
            layout,
        })
    }

    /// Texel `i`'s position.
    #[inline]
    fn pos(&self, i: usize) -> DVec3 {
        self.pos.get(i)
    }

    /// Texel `i`'s colour.
    #[inline]
    fn col(&self, i: usize) -> [f32; 3] {
        [self.col[0][i], self.col[1][i], self.col[2][i]]
    }

    /// A finite position and colour.
    #[inline]
    fn valid(&self, i: usize) -> bool {
        self.pos(i).is_finite() && self.col(i).iter().all(|c| c.is_finite())
    }

    /// Texel `i`'s unit normal: the given one normalised, else from its in-face
    /// neighbours ([`grid_normal`]).
    #[inline]
    fn nrm(&self, i: usize) -> DVec3 {
        self.given
            .and_then(|n| n.get(i).try_normalize())
            .unwrap_or_else(|| grid_normal(self, i))
    }

    /// Texel `i`'s normal is turned by more than 60° from the unit vector `m`:
    /// `nrm(i).dot(m) < 0.5` (a NaN product is not turned), decided without normalising
    /// where it can be. Given a normal n with 0 < |n|² < ∞, nrm(i) is n/|n| and its
    /// product with m is n·m/|n| within a few ulps: below 0.5 when n·m ≤ 0, else when
    /// 4(n·m)² < |n|², which [`RIM`] away from equality decides the same as the
    /// normalised product. Why: a disc sample asks this for ~57 texels, and the
    /// normalisation (a root and a division each) was a tenth of the disc's time.
    #[inline]
    fn turned(&self, i: usize, m: DVec3) -> bool {
        if let Some(g) = &self.given {
            let n = g.get(i);
            let (l2, u) = (n.length_squared(), n.dot(m));
            if l2.is_finite() && l2 > 0.0 && u.is_finite() {
                if u <= 0.0 {
                    return true;
                }
                let w = 4.0 * (u * u);
                if w < l2 * (1.0 - RIM) {
                    return true;
                }
                if w > l2 * (1.0 + RIM) {
                    return false;
                }
            }
        }
        self.nrm(i).dot(m) < 0.5
    }

    /// The spacing that decides whether a point nearest to texel `i` is on the surface:
    /// its own [`Cloud::local_spacing`], and at a face border the largest of those of the
    /// texels across. Where faces of different texel density meet, the gap between their
    /// outer texel rows is half of each spacing: a point in it may be farther from the
    /// denser face's texel than that face's own spacing allows; around a vertex where many
    /// faces meet, the vertex is farther from the corner texels than they are from each
    /// other. So a border texel takes the largest of its spacing and, per other domain
    /// within 4 of its spacings (none at an open boundary), the distance to that domain's
    /// nearest texel and its spacing — the nearest domain for an edge texel, every domain
    /// for a corner texel. The same value whichever thread computes it first.
    fn cover(&self, i: usize) -> f32 {
        let known = self.cover[i].load(Ordering::Relaxed);
        if known != COVER_UNKNOWN {
            return f32::from_bits(!known);
        }
        let c = self.cover_of(i);
        self.cover[i].store(!c.to_bits(), Ordering::Relaxed);
        c
    }

    fn cover_of(&self, i: usize) -> f32 {
        let l = &self.layout;
        let own_i = self.local_spacing(i);
        let (d, x, y) = l.coords(i);
        let (nu, nv) = l.dims(d);
        let (bx, by) = (x == 0 || x + 1 == nu, y == 0 || y + 1 == nv);
        if !(bx || by) || !self.valid(i) {
            return own_i as f32;
        }
        let pi = self.pos(i);
        let r = 4.0 * own_i;
        if !(bx && by) {
            // An edge texel: the least (distance, domain) over the domains' nearest texels
            // is the least (distance, texel) over all texels of other domains (a domain's
            // texels are numbered after the lower domains'), which one bounded search
            // finds without listing the radius.
            return match self.index.nearest_outside(pi, r * r, l.range(d)) {
                Some((j, dist)) => own_i.max(dist.max(self.local_spacing(j))),
                None => own_i,
            } as f32;
        }
        // A corner texel: the nearest texel of each other domain: (domain, distance, texel).
        let mut per: Vec<(usize, f64, usize)> = Vec::new();
        // In the order of the visit, not listed and sorted: per domain the least
        // (distance, texel) is kept, and what follows takes a maximum, so the order does
        // not matter.
        self.index.for_within(pi, r * r, |j, pj| {
            let dj = l.domain_of(j);
            if dj == d {
                return;
            }
            let dist = (pj - pi).length();
            match per.iter_mut().find(|e| e.0 == dj) {
                Some(e) if dist < e.1 || (dist == e.1 && j < e.2) => *e = (dj, dist, j),
                Some(_) => {}
                None => per.push((dj, dist, j)),
            }
        });
        let take = |e: &(usize, f64, usize)| e.1.max(self.local_spacing(e.2));
        per.iter().map(take).fold(own_i, f64::max) as f32
    }

    /// Texels that can be window centres.
    pub fn candidates(&self) -> Vec<usize> {
        (0..self.layout.len()).filter(|&i| self.valid(i)).collect()
    }

    /// `count` window centres drawn among [`Cloud::candidates`] ([`draw`]), without
    /// listing them when every texel is one.
    pub fn draw_centres(&self, count: usize, seed: u64) -> Vec<usize> {
        if self.all_valid {
            draw_from(self.layout.len(), |i| i, count, seed)
        } else {
            draw(self.candidates(), count, seed)
        }
    }

    /// The texel nearest to `p`; `near` and its in-face 3x3 neighbours seed the search
    /// ([`TexelBvh::nearest_seeded`]: the same answer, found sooner).
    #[inline]
    fn nearest(&self, p: DVec3, near: usize) -> usize {
        let mut seeds = [near; 9];
        let mut k = 1;
        if near < self.layout.len() {
            let (d, x, y) = self.layout.coords(near);
            let (nu, nv) = self.layout.dims(d);
            let row0 = near - x;
            for yy in y.saturating_sub(1)..(y + 2).min(nv) {
                let row = row0 + yy * nu - y * nu;
                for xx in x.saturating_sub(1)..(x + 2).min(nu) {
                    if (xx, yy) != (x, y) {
                        seeds[k] = row + xx;
                        k += 1;
                    }
                }
            }
        }
        // A cloud has a valid texel (`build`); a NaN point finds none: the first texel.
        self.index.nearest_seeded(p, &seeds[..k]).unwrap_or(0)
    }

    /// Texels within `radius` of `p`, in texel order.
    fn within(&self, p: DVec3, radius: f64) -> Vec<usize> {
        self.index.within(p, radius * radius)
    }

    /// Largest distance to the texel's valid in-face 4-neighbours (h when it has none).
    fn local_spacing(&self, i: usize) -> f64 {
        let (d, x, y) = self.layout.coords(i);
        let (n, nv) = self.layout.dims(d);
        let mut max = 0f64;
        let pi = self.pos(i);
        let mut add = |j: usize| {
            if self.valid(j) {
                max = max.max((self.pos(j) - pi).length());
            }
        };
        if x > 0 {
            add(i - 1);
        }
        if x + 1 < n {
            add(i + 1);
        }
        if y > 0 {
            add(i - n);
        }
        if y + 1 < nv {
            add(i + n);
        }
        if max > 0.0 {
            max
        } else {
            self.h
        }
    }

    /// Surface length per example pixel at texel t (the local scale where there is one).
    fn scale_at(&self, t: usize) -> f64 {
        match &self.local {
            Some(l) if l[t].is_finite() && l[t] > 0.0 => l[t] as f64,
            _ => self.scale,
        }
    }

    /// t's pixel directions: the least-squares fit, or the fallback (module docs).
    pub fn frame(&self, t: usize) -> Frame {
        self.fit(t).unwrap_or_else(|| self.fallback_frame(t))
    }

    fn fit(&self, t: usize) -> Option<Frame> {
        let (su, sv) = self.src?;
        let st = [su[t] as f64, sv[t] as f64];
        if !(st[0].is_finite() && st[1].is_finite()) {
            return None;
        }
        let nt = self.nrm(t);
        let (e1, e2) = nt.any_orthonormal_pair();
        let ht = self.local_spacing(t);
        let p0 = self.pos(t);
        let mut pairs: Vec<([f64; 2], [f64; 2])> = Vec::new();
        for k in self.within(p0, FIT_RADIUS * ht) {
            if k == t {
                continue;
            }
            let sk = [su[k] as f64, sv[k] as f64];
            let ds = [sk[0] - st[0], sk[1] - st[1]];
            if !(ds[0].is_finite() && ds[1].is_finite()) {
                continue;
            }
            let dp = self.pos(k) - p0;
            let grid = (dp.length() / ht).max(1.0);
            if ds[0].hypot(ds[1]) > COHERENT_PER_TEXEL * grid {
                continue;
            }
            pairs.push(([dp.dot(e1), dp.dot(e2)], ds));
        }
        if pairs.len() < MIN_FIT_NEIGHBOURS {
            return None;
        }
        // Normal equations: M = Ssq · Sqq⁻¹ with Sqq = Σ q qᵀ, Ssq = Σ Δs qᵀ.
        let (mut q11, mut q12, mut q22) = (0.0, 0.0, 0.0);
        let mut sq = [[0.0f64; 2]; 2];
        for (q, ds) in &pairs {
            q11 += q[0] * q[0];
            q12 += q[0] * q[1];
            q22 += q[1] * q[1];
            for r in 0..2 {
                sq[r][0] += ds[r] * q[0];
                sq[r][1] += ds[r] * q[1];
            }
        }
        let det_q = q11 * q22 - q12 * q12;
        let tr_q = q11 + q22;
        // Neighbours must span the plane: smallest eigenvalue ≥ 5% of the largest.
        let disc = ((q11 - q22).powi(2) + 4.0 * q12 * q12).sqrt();
        let (lmax, lmin) = ((tr_q + disc) / 2.0, (tr_q - disc) / 2.0);
        if !(det_q > 0.0 && lmin >= 0.05 * lmax) {
            return None;
        }
        let inv_q = [[q22 / det_q, -q12 / det_q], [-q12 / det_q, q11 / det_q]];
        let mut m = [[0.0f64; 2]; 2];
        for r in 0..2 {
            for c in 0..2 {
                m[r][c] = sq[r][0] * inv_q[0][c] + sq[r][1] * inv_q[1][c];
            }
        }
        let mut res = 0.0;
        for (q, ds) in &pairs {
            for r in 0..2 {
                let e = ds[r] - (m[r][0] * q[0] + m[r][1] * q[1]);
                res += e * e;
            }
        }
        if (res / pairs.len() as f64).sqrt() > MAX_RESIDUAL_PX {
            return None;
        }
        // Singular values of M (pixels per surface length).
        let t2 = m[0][0].powi(2) + m[0][1].powi(2) + m[1][0].powi(2) + m[1][1].powi(2);
        let det = m[0][0] * m[1][1] - m[0][1] * m[1][0];
        let root = (t2 * t2 - 4.0 * det * det).max(0.0).sqrt();
        let (s1, s2) = (
            ((t2 + root) / 2.0).sqrt(),
            ((t2 - root) / 2.0).max(0.0).sqrt(),
        );
        if !(s2 > 0.0 && det != 0.0 && s1 / s2 <= MAX_ANISOTROPY) {
            return None;
        }
        // Pixel lengths 1/σ within a factor MAX_STRETCH of the scale.
        let scale = self.scale_at(t);
        if !(scale * s2 >= 1.0 / MAX_STRETCH && scale * s1 <= MAX_STRETCH) {
            return None;
        }
        let inv = [
            [m[1][1] / det, -m[0][1] / det],
            [-m[1][0] / det, m[0][0] / det],
        ];
        let a = e1 * inv[0][0] + e2 * inv[1][0];
        let b = e1 * inv[0][1] + e2 * inv[1][1];
        Some(Frame {
            a,
            b,
            fallback: false,
        })
    }

    /// The face's texel directions at t, scaled to one pixel (the scale).
    fn fallback_frame(&self, t: usize) -> Frame {
        let (d, x, y) = self.layout.coords(t);
        let (n, nv) = self.layout.dims(d);
        let nt = self.nrm(t);
        let dir = |lo: Option<usize>, hi: Option<usize>| -> Option<DVec3> {
            let pick = |j: Option<usize>| j.filter(|&j| self.valid(j)).map(|j| self.pos(j));
            let (a, b) = (
                pick(lo).unwrap_or(self.pos(t)),
                pick(hi).unwrap_or(self.pos(t)),
            );
            let d = b - a;
            (d - nt * d.dot(nt)).try_normalize()
        };
        let du = dir((x > 0).then(|| t - 1), (x + 1 < n).then_some(t + 1));
        let dv = dir((y > 0).then(|| t - n), (y + 1 < nv).then_some(t + n));
        let (e1, e2) = nt.any_orthonormal_pair();
        let (a, b) = match (du, dv) {
            (Some(a), Some(b)) => (a, b),
            (Some(a), None) => (a, nt.cross(a)),
            (None, Some(b)) => (b.cross(nt), b),
            (None, None) => (e1, e2),
        };
        Frame {
            a: a * self.scale_at(t),
            b: b * self.scale_at(t),
            fallback: true,
        }
    }

    /// Walks `px` pixels from `st` along its a (or b) times `sign` (module docs, step 2).
    fn walk(&self, st: &State, along_b: bool, sign: f64, px: f64) -> Option<State> {
        let (la, lb) = (st.a.length(), st.b.length());
        let len = px * if along_b { lb } else { la };
        // Steps of at most one spacing, but at most MAX_STEPS per call (a scale far above
        // the texel spacing would otherwise cost thousands of steps per sample).
        let steps = (len / self.h).ceil().clamp(1.0, MAX_STEPS as f64) as usize;
        let d = len / steps as f64;
        let mut cur = *st;
        for _ in 0..steps {
            let v = if along_b { cur.b } else { cur.a };
            let p = cur.p + v.normalize_or_zero() * (sign * d);
            let k = self.nearest(p, cur.near);
            let nk = self.nrm(k);
            let off = p - self.pos(k);
            let dn = off.dot(nk);
            if (off - nk * dn).length() > OFF_SURFACE * self.cover(k) as f64 {
                return None;
            }
            cur.p = p - nk * dn;
            cur.a = transport(cur.a, nk, la);
            cur.b = transport(cur.b, nk, lb);
            cur.n = nk;
            cur.near = k;
        }
        Some(cur)
    }

    /// One sample's colour at spacing `s` (module docs, step 3).
    fn sample(&self, st: &State, s: usize) -> [f32; 3] {
        // The nearest texel's colour: S = 1's sample, and for a disc only the fallback (an
        // empty disc or degenerate directions), so searched for only then (it was a ninth
        // of the nearest-texel queries).
        let nearest = || self.col(self.nearest(st.p, st.near));
        if s <= 1 {
            return nearest();
        }
        let r = s as f64 / 2.0;
        let radius = r * (st.a.length_squared() + st.b.length_squared()).sqrt() * 1.001;
        let (g11, g12, g22) = (st.a.dot(st.a), st.a.dot(st.b), st.b.dot(st.b));
        let det = g11 * g22 - g12 * g12;
        if det.is_nan() || det <= 0.0 {
            return nearest();
        }
        let sheet = 0.5 * radius + 0.5 * self.h;
        let lim = r * r + 1e-3;
        // α and β by one reciprocal instead of two divisions per texel: within a few ulps
        // of the quotients, so the disc test is theirs except within [`RIM`] of the rim,
        // where the quotients decide. Only for a finite reciprocal (a det so small that
        // 1/det overflows could hold a tiny α that the product makes infinite).
        let inv_det = 1.0 / det;
        let fast = inv_det.is_finite();
        // The texels of the disc, summed in texel order. The tests are pure, so their
        // order is free: the normal (a normalisation per texel) only for texels in the disc.
        let mut inside: Vec<usize> = Vec::with_capacity(64);
        self.index.for_within(st.p, radius * radius, |j, pj| {
            let d = pj - st.p;
            let dn = d.dot(st.n);
            if dn.abs() > sheet {
                return;
            }
            let dt = d - st.n * dn;
            let (ra, rb) = (dt.dot(st.a), dt.dot(st.b));
            let (na, nb) = (g22 * ra - g12 * rb, g11 * rb - g12 * ra);
            let quotients = || {
                let (alpha, beta) = (na / det, nb / det);
                alpha * alpha + beta * beta <= lim
            };
            let in_disc = if fast {
                let (alpha, beta) = (na * inv_det, nb * inv_det);
                let q = alpha * alpha + beta * beta;
                // NaN: neither, the quotients decide.
                q <= lim * (1.0 - RIM) || (q <= lim * (1.0 + RIM) && quotients())
            } else {
                quotients()
            };
            if in_disc && !self.turned(j, st.n) {
                inside.push(j);
            }
        });
        if inside.is_empty() {
            return nearest();
        }
        inside.sort_unstable();
        let mut acc = [0f64; 3];
        for &j in &inside {
            for (a, c) in acc.iter_mut().zip(self.col(j)) {
                *a += c as f64;
            }
        }
        let cnt = inside.len();
        let inv = 1.0 / cnt as f64;
        [
            (acc[0] * inv) as f32,
            (acc[1] * inv) as f32,
            (acc[2] * inv) as f32,
        ]
    }

    /// The window of texel t at spacing `s`, `None` when it leaves the surface.
    pub fn window(&self, t: usize, fr: &Frame, s: usize) -> Option<Vec<f32>> {
        let half = WINDOW / 2;
        let start = State {
            p: self.pos(t),
            a: fr.a,
            b: fr.b,
            n: self.nrm(t),
            near: t,
        };
        let (sp, ext) = (s as f64, (s / 2) as f64);
        let line = |from: &State, along_b: bool| -> Option<[State; WINDOW]> {
            let mut out = [*from; WINDOW];
            for sign in [1.0f64, -1.0] {
                let mut cur = *from;
                for i in 1..=half {
                    cur = self.walk(&cur, along_b, sign, sp)?;
                    let idx = if sign > 0.0 { half + i } else { half - i };
                    out[idx] = cur;
                }
                if ext > 0.0 {
                    self.walk(&cur, along_b, sign, ext)?;
                }
            }
            Some(out)
        };
        let row = line(&start, false)?;
        let mut grid = [[start; WINDOW]; WINDOW];
        for (i, r) in row.iter().enumerate() {
            let col = line(r, true)?;
            for (j, st) in col.iter().enumerate() {
                grid[j][i] = *st;
            }
        }
        let mut v = Vec::with_capacity(DIMS);
        for row in &grid {
            for st in row {
                v.extend_from_slice(&self.sample(st, s));
            }
        }
        Some(v)
    }
}

/// Projects `v` onto the plane of normal `n`, keeping its length `len`.
#[inline]
fn transport(v: DVec3, n: DVec3, len: f64) -> DVec3 {
    let w = v - n * v.dot(n);
    let l = w.length();
    if l > 0.0 {
        w * (len / l)
    } else {
        v
    }
}

/// Normal from the texel's in-face neighbours (one-sided at the border).
fn grid_normal(c: &Cloud, i: usize) -> DVec3 {
    let l = &c.layout;
    let (d, x, y) = l.coords(i);
    let (n, nv) = l.dims(d);
    let pick = |j: usize| if c.valid(j) { c.pos(j) } else { c.pos(i) };
    let du = pick(if x + 1 < n { i + 1 } else { i }) - pick(if x > 0 { i - 1 } else { i });
    let dv = pick(if y + 1 < nv { i + n } else { i }) - pick(if y > 0 { i - n } else { i });
    du.cross(dv).try_normalize().unwrap_or(DVec3::Z)
}

/// Median distance between horizontally or vertically adjacent valid texels of one face.
///
/// Exactly the median of all those distances, without listing them all (10 M on the bunny
/// at N = 16: 80 MB written and selected in, ~15% of the summary's time): a sample of
/// every [`SPACING_SAMPLE`]-th texel's spacings brackets the median, one pass over the
/// faces counts the spacings below the bracket and keeps those in it, and the median is
/// selected among the kept ones. Should the bracket miss (it cannot be sure to hold it),
/// all spacings are listed as before. Faces in parallel: neither the counts nor the set of
/// kept values depend on the order.
fn median_spacing(
    l: &crate::layout::TexelLayout,
    pos: Xyz,
    all_valid: bool,
    valid: &(impl Fn(usize) -> bool + Sync),
) -> Option<f64> {
    let ok = |i: usize| all_valid || valid(i);
    // Texel i's spacings to its +x and +y neighbours in its face, squared: the root is
    // monotonic, so the median of the squares is the square of the median (the same
    // texel pair's, rooted once at the end instead of 8 M times at 4 M texels), and a
    // bracket in squares holds the median as well as one in lengths does.
    let spacings = |i: usize, x: usize, y: usize, n: usize, nv: usize, f: &mut dyn FnMut(f64)| {
        if !ok(i) {
            return;
        }
        let pi = pos.get(i);
        if x + 1 < n && ok(i + 1) {
            f((pos.get(i + 1) - pi).length_squared());
        }
        if y + 1 < nv && ok(i + n) {
            f((pos.get(i + n) - pi).length_squared());
        }
    };
    let each_face = |face: usize, f: &mut dyn FnMut(f64)| {
        let (n, nv) = l.dims(face);
        for y in 0..nv {
            for x in 0..n {
                spacings(l.index(face, x, y), x, y, n, nv, f);
            }
        }
    };
    let median =
        |d: &mut [f64], rank: usize| -> f64 { *d.select_nth_unstable_by(rank, f64::total_cmp).1 };
    let result = |m2: f64| {
        let m = m2.sqrt();
        (m.is_finite() && m > 0.0).then_some(m)
    };
    // The bracket from a sample.
    let mut sample: Vec<f64> = (0..l.len())
        .into_par_iter()
        .step_by(SPACING_SAMPLE)
        .flat_map_iter(|i| {
            let (face, x, y) = l.coords(i);
            let (n, nv) = l.dims(face);
            let mut v = Vec::with_capacity(2);
            spacings(i, x, y, n, nv, &mut |s| v.push(s));
            v
        })
        .collect();
    if sample.len() >= 1000 {
        sample.sort_unstable_by(f64::total_cmp);
        let m = sample.len() as f64;
        let half = (4.0 * m.sqrt()) as usize + 8;
        let mid = sample.len() / 2;
        let (lo, hi) = (
            sample[mid.saturating_sub(half)],
            sample[(mid + half).min(sample.len() - 1)],
        );
        let (below, total, mut kept) = (0..l.faces())
            .into_par_iter()
            .fold(
                || (0usize, 0usize, Vec::new()),
                |(mut below, mut total, mut kept), face| {
                    each_face(face, &mut |s| {
                        total += 1;
                        if s.total_cmp(&lo).is_lt() {
                            below += 1;
                        } else if s.total_cmp(&hi).is_le() {
                            kept.push(s);
                        }
                    });
                    (below, total, kept)
                },
            )
            .reduce(
                || (0, 0, Vec::new()),
                |mut a, b| {
                    a.2.extend(b.2);
                    (a.0 + b.0, a.1 + b.1, a.2)
                },
            );
        let mid = total / 2;
        if below <= mid && mid < below + kept.len() {
            return result(median(&mut kept, mid - below));
        }
    }
    let mut d: Vec<f64> = (0..l.faces())
        .into_par_iter()
        .flat_map_iter(|face| {
            let mut d = Vec::new();
            each_face(face, &mut |s| d.push(s));
            d
        })
        .collect();
    if d.is_empty() {
        return None;
    }
    let mid = d.len() / 2;
    result(median(&mut d, mid))
}

/// One texel in this many lends its spacings to [`median_spacing`]'s bracket (prime, so
/// that the sample does not follow the texel rows).
const SPACING_SAMPLE: usize = 61;

/// The maps as one image when their texel centres form a square lattice, tile by tile,
/// and the source positions step one pixel per texel along it (or, without sources, the
/// scale equals the lattice spacing): then "the window is the pixel grid". `None`
/// otherwise (docs/eval.md, "Lattice"). With the image, the texel of each pixel.
pub(crate) fn lattice_image(
    colour: &FaceMaps,
    geometry: TexelPoints,
    scale: Option<f64>,
) -> Option<(Rgb, Vec<u32>)> {
    // The lattice is one resolution's pixel grid: per-face resolutions have none.
    let n = colour.uniform_n()?;
    let f = colour.faces();
    if n < 2 || *geometry.layout != colour.layout || geometry.pos.len() < colour.layout.len() {
        return None;
    }
    let (r, g, b) = (
        colour.channel("R")?,
        colour.channel("G")?,
        colour.channel("B")?,
    );
    let p = |i: usize| geometry.pos.get(i);
    let idx = |d: usize, x: usize, y: usize| (d * n + y) * n + x;
    let o0 = p(0);
    let eu = (p(idx(0, n - 1, 0)) - o0) / (n - 1) as f64;
    let ev = (p(idx(0, 0, n - 1)) - o0) / (n - 1) as f64;
    let hl = eu.length();
    if !(hl.is_finite() && hl > 0.0)
        || (ev.length() - hl).abs() > LATTICE_TOL * hl
        || eu.dot(ev).abs() > LATTICE_TOL * hl * hl
    {
        return None;
    }
    let (uu, vv) = (eu / (hl * hl), ev / ev.length_squared());
    let mut tiles: Vec<(i64, i64)> = Vec::with_capacity(f);
    for d in 0..f {
        let o = p(idx(d, 0, 0)) - o0;
        let (tx, ty) = (o.dot(uu) / n as f64, o.dot(vv) / n as f64);
        let (rx, ry) = (tx.round(), ty.round());
        if !((tx - rx).abs() * n as f64 <= LATTICE_TOL && (ty - ry).abs() * n as f64 <= LATTICE_TOL)
        {
            return None;
        }
        let (ix, iy) = (rx as i64, ry as i64);
        let base = o0 + eu * (ix * n as i64) as f64 + ev * (iy * n as i64) as f64;
        for y in 0..n {
            for x in 0..n {
                let q = base + eu * x as f64 + ev * y as f64;
                let dev = (p(idx(d, x, y)) - q).length();
                if dev.is_nan() || dev > LATTICE_TOL * hl {
                    return None;
                }
            }
        }
        tiles.push((ix, iy));
    }
    let (minx, maxx) = (
        tiles.iter().map(|t| t.0).min()?,
        tiles.iter().map(|t| t.0).max()?,
    );
    let (miny, maxy) = (
        tiles.iter().map(|t| t.1).min()?,
        tiles.iter().map(|t| t.1).max()?,
    );
    let (cols, rows) = ((maxx - minx + 1) as usize, (maxy - miny + 1) as usize);
    if cols * rows != f {
        return None;
    }
    let mut seen = vec![false; f];
    for t in &tiles {
        let k = (t.1 - miny) as usize * cols + (t.0 - minx) as usize;
        if std::mem::replace(&mut seen[k], true) {
            return None;
        }
    }
    // The example's pixel grid: sources step (1, 0) along x and (0, 1) along y.
    match source_steps(colour) {
        Some([ux, vx, uy, vy]) => {
            let t = LATTICE_SOURCE_TOL;
            if !((ux - 1.0).abs() <= t && vx.abs() <= t && uy.abs() <= t && (vy - 1.0).abs() <= t) {
                return None;
            }
        }
        None => {
            if let Some(s) = scale {
                if (hl / s - 1.0).abs() > LATTICE_TOL {
                    return None;
                }
            }
        }
    }
    let (w, h) = (cols * n, rows * n);
    let mut img = vec![[f32::NAN; 3]; w * h];
    let mut texel = vec![0u32; w * h];
    for (d, t) in tiles.iter().enumerate() {
        let (ox, oy) = ((t.0 - minx) as usize * n, (t.1 - miny) as usize * n);
        for y in 0..n {
            for x in 0..n {
                let i = idx(d, x, y);
                img[(oy + y) * w + ox + x] = [r[i], g[i], b[i]];
                texel[(oy + y) * w + ox + x] = i as u32;
            }
        }
    }
    Some((
        Rgb {
            width: w,
            height: h,
            px: img,
        },
        texel,
    ))
}

/// Medians of (Δu, Δv) over coherent x-adjacent and y-adjacent texel pairs of one face:
/// [Δu_x, Δv_x, Δu_y, Δv_y]; `None` without sources or coherent pairs.
fn source_steps(colour: &FaceMaps) -> Option<[f64; 4]> {
    let (su, sv) = (colour.channel("source.u")?, colour.channel("source.v")?);
    let l = &*colour.layout;
    let mut v: [Vec<f64>; 4] = Default::default();
    for d in 0..l.faces() {
        let (n, nv) = l.dims(d);
        for y in 0..nv {
            for x in 0..n {
                let i = l.index(d, x, y);
                for (j, k) in [(i + 1, 0usize), (i + n, 2)] {
                    if (k == 0 && x + 1 >= n) || (k == 2 && y + 1 >= nv) {
                        continue;
                    }
                    let (du, dv) = ((su[j] - su[i]) as f64, (sv[j] - sv[i]) as f64);
                    if du.is_finite() && dv.is_finite() && du.hypot(dv) <= COHERENT_PER_TEXEL {
                        v[k].push(du);
                        v[k + 1].push(dv);
                    }
                }
            }
        }
    }
    let mut out = [0.0; 4];
    for (o, vals) in out.iter_mut().zip(v.iter_mut()) {
        if vals.is_empty() {
            return None;
        }
        let mid = vals.len() / 2;
        *o = *vals.select_nth_unstable_by(mid, f64::total_cmp).1;
    }
    Some(out)
}

/// pf1/pf4/pf8 of face maps (module docs; docs/eval.md). The lattice, when it applies
/// (and `opts.force_surface` is off), else the surface method.
pub fn patch_fidelities_with(
    colour: &FaceMaps,
    geometry: &FaceMaps,
    example: &Example,
    scale: Option<f64>,
    opts: &PfOptions,
) -> PatchFidelity {
    match TexelPoints::of_maps(geometry) {
        Some(g) => patch_fidelities_of(colour, g, example, scale, opts),
        None => PatchFidelity::empty(PfMethod::Surface),
    }
}

/// [`patch_fidelities_with`] on texel geometry wherever it is ([`TexelPoints`]).
pub fn patch_fidelities_of(
    colour: &FaceMaps,
    geometry: TexelPoints,
    example: &Example,
    scale: Option<f64>,
    opts: &PfOptions,
) -> PatchFidelity {
    patch_fidelities_in(colour, geometry, example, scale, opts, None, false)
}

/// [`patch_fidelities_of`] with the example banks through `banks` (memory and the disk
/// cache, [`super::pf::BANK_KIND`]), when given: the same figures. `finite`: every texel
/// position and colour is known finite ([`Cloud::build`]).
pub(crate) fn patch_fidelities_in(
    colour: &FaceMaps,
    geometry: TexelPoints,
    example: &Example,
    scale: Option<f64>,
    opts: &PfOptions,
    banks: Option<&crate::synth::Analyses>,
    finite: bool,
) -> PatchFidelity {
    let ex = Rgb::from_example(example);
    if !opts.force_surface {
        if let Some((img, texel)) = lattice_image(colour, geometry, scale) {
            let mut pf = image_patch_fidelities_as(&img, &ex, opts, PfMethod::Lattice, banks);
            for c in &mut pf.detail.centres {
                *c = texel[*c] as usize;
            }
            return pf;
        }
    }
    let Some(cloud) = Cloud::build(colour, geometry, scale, finite) else {
        return PatchFidelity::empty(PfMethod::Surface);
    };
    let drawn = cloud.draw_centres(opts.samples, opts.seed);
    let frames: Vec<Frame> = drawn.par_iter().map(|&t| cloud.frame(t)).collect();
    let fallbacks = frames.iter().filter(|f| f.fallback).count();
    // The three spacings side by side (each builds its own example bank; the same values
    // in any order).
    let scales = PF_SCALES
        .par_iter()
        .map(|&s| {
            let windows: Vec<Option<Vec<f32>>> = drawn
                .par_iter()
                .zip(frames.par_iter())
                .map(|(&t, fr)| cloud.window(t, fr, s))
                .collect();
            score_scale(s, &windows, &ex, opts, banks)
        })
        .collect();
    PatchFidelity::from_scales(PfMethod::Surface, drawn, fallbacks, scales)
}
