//! Where every texel of every face domain lives: the per-face resolution and the global
//! texel order shared by the texel geometry, the maps and every writer.
//!
//! Two kinds of layout exist, and [`TexelLayout`] can only be built as one of them:
//!
//! - **Uniform** (`--resolution N`): every domain has N×N texels, N any integer in
//!   1..=[`MAX_SIDE`]. This is the layout of BRIEF.md and of every run before issue 16;
//!   indices, files and results are exactly what they were.
//! - **Per face** (`--texel-size L`): domain d has 2^a × 2^b texels ([`Resolution`]: u and
//!   v separately, powers of two, as Ptex stores per-face resolutions), chosen so that the
//!   texel spacing is about L everywhere ([`TexelLayout::for_texel_size`]). With one N
//!   for all faces, spacing on the Spot fixture at N = 32 ranged 0.0009–0.0101 (11x), and a
//!   renderer showed sharpness jumping at face borders.
//!
//! Texel (x, y) of domain d (x along u, y along v, 0 ≤ x < nu, 0 ≤ y < nv) has the global
//! index `start(d) + y·nu + x` and sits at the domain point ((x + 0.5)/nu, (y + 0.5)/nv):
//! domain-major, row-major inside a domain. With a uniform N that is `(d·N + y)·N + x`,
//! today's order.

use subdiv::{DomainId, DomainLocation, Surface};

/// Largest texels per side of a domain (both layouts): far beyond practical use (8192² f32
/// texels are 256 MiB per channel per face), a guard against typos.
pub const MAX_SIDE: usize = 8192;
/// log2 of [`MAX_SIDE`].
pub const MAX_LOG2: u8 = 13;
/// Smallest per-face side a texel size gives (log2): 2 texels, so that every face has
/// adjacent texel pairs in both directions (its texel spacing is defined, and a 1-texel
/// face would have no interior at all for the neighbourhood matchers).
pub const MIN_LOG2: u8 = 1;

/// One face's resolution under a texel size: 2^log2_u × 2^log2_v texels. The fields are
/// private so that only powers of two up to [`MAX_SIDE`] can exist: Ptex stores exactly
/// this (one byte of log2 per direction).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Resolution {
    log2_u: u8,
    log2_v: u8,
}

impl Resolution {
    /// 2^log2_u × 2^log2_v, or `None` when a side would exceed [`MAX_SIDE`].
    pub fn new(log2_u: u8, log2_v: u8) -> Option<Self> {
        (log2_u <= MAX_LOG2 && log2_v <= MAX_LOG2).then_some(Self { log2_u, log2_v })
    }

    pub fn log2_u(self) -> u8 {
        self.log2_u
    }

    pub fn log2_v(self) -> u8 {
        self.log2_v
    }

    /// Texels along u.
    pub fn u(self) -> usize {
        1 << self.log2_u
    }

    /// Texels along v.
    pub fn v(self) -> usize {
        1 << self.log2_v
    }

    /// Halved `k` times per side, but never below one texel.
    pub fn coarsened(self, k: u8) -> Self {
        Self {
            log2_u: self.log2_u.saturating_sub(k),
            log2_v: self.log2_v.saturating_sub(k),
        }
    }
}

#[derive(Clone, Debug, PartialEq, Eq)]
enum Kind {
    Uniform(usize),
    PerFace(Vec<Resolution>),
}

/// The texel layout of all face domains (see the module docs).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct TexelLayout {
    kind: Kind,
    faces: usize,
    /// First global index of every domain, F + 1 entries (the last is the total).
    start: Vec<usize>,
}

impl Default for TexelLayout {
    /// No domains (what an emptied texel graph holds).
    fn default() -> Self {
        Self {
            kind: Kind::Uniform(1),
            faces: 0,
            start: vec![0],
        }
    }
}

impl TexelLayout {
    /// `faces` domains of `n`×`n` texels (n ≥ 1).
    pub fn uniform(faces: usize, n: usize) -> Self {
        assert!(n >= 1, "a map needs at least one texel per side");
        Self {
            kind: Kind::Uniform(n),
            faces,
            start: (0..=faces).map(|d| d * n * n).collect(),
        }
    }

    /// One [`Resolution`] per domain, in domain order.
    pub fn per_face(res: Vec<Resolution>) -> Self {
        let mut start = Vec::with_capacity(res.len() + 1);
        let mut s = 0usize;
        start.push(0);
        for r in &res {
            s += r.u() * r.v();
            start.push(s);
        }
        Self {
            faces: res.len(),
            kind: Kind::PerFace(res),
            start,
        }
    }

    /// The per-face layout of `surface` for a texel size of `l` surface units per texel:
    /// per domain and direction, the side is the power of two nearest (in log scale) to
    /// the domain's length in that direction divided by `l`, clamped to
    /// 2^[`MIN_LOG2`]..=2^[`MAX_LOG2`]. Rounding in log scale puts every domain's spacing
    /// within √2 of `l` either way, hence within 2x over the surface (apart from clamped
    /// faces and the variation of spacing inside a domain). Lengths are the mean, over 9
    /// lines of constant v (u), of the chord length along 8 segments of the limit surface.
    /// `l` must be positive and finite (the caller checks, to name the option).
    pub fn for_texel_size(surface: &Surface, l: f64) -> Self {
        use rayon::prelude::*;
        let res: Vec<Resolution> = (0..surface.num_domains())
            .into_par_iter()
            .map(|d| {
                let (lu, lv) = domain_lengths(surface, DomainId::from_idx(d));
                let side = |len: f64| -> u8 {
                    let k = (len / l).log2().round();
                    if k.is_nan() {
                        MIN_LOG2
                    } else {
                        k.clamp(MIN_LOG2 as f64, MAX_LOG2 as f64) as u8
                    }
                };
                Resolution::new(side(lu), side(lv)).expect("clamped to MAX_LOG2")
            })
            .collect();
        Self::per_face(res)
    }

    /// The same layout with every side halved `k` times (uniform: ceil(N / 2^k); per face:
    /// down to one texel): the coarser levels of multilevel methods.
    pub fn coarsened(&self, k: u32) -> Self {
        match &self.kind {
            Kind::Uniform(n) => Self::uniform(self.faces, n.div_ceil(1 << k).max(1)),
            Kind::PerFace(r) => Self::per_face(r.iter().map(|r| r.coarsened(k as u8)).collect()),
        }
    }

    /// Number of face domains F.
    pub fn faces(&self) -> usize {
        self.faces
    }

    /// Total number of texels.
    pub fn len(&self) -> usize {
        self.start[self.faces]
    }

    /// True without texels.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// N when every domain has N×N texels (`--resolution`), else `None`.
    pub fn uniform_n(&self) -> Option<usize> {
        match self.kind {
            Kind::Uniform(n) => Some(n),
            Kind::PerFace(_) => None,
        }
    }

    /// The per-face resolutions of a texel-size layout, else `None`.
    pub fn resolutions(&self) -> Option<&[Resolution]> {
        match &self.kind {
            Kind::Uniform(_) => None,
            Kind::PerFace(r) => Some(r),
        }
    }

    /// (texels along u, texels along v) of domain `d`.
    #[inline]
    pub fn dims(&self, d: usize) -> (usize, usize) {
        match &self.kind {
            Kind::Uniform(n) => (*n, *n),
            Kind::PerFace(r) => (r[d].u(), r[d].v()),
        }
    }

    /// The largest side along u and along v over all domains (the EXR tile size).
    pub fn max_dims(&self) -> (usize, usize) {
        match &self.kind {
            Kind::Uniform(n) => (*n, *n),
            Kind::PerFace(r) => r
                .iter()
                .fold((1, 1), |(a, b), r| (a.max(r.u()), b.max(r.v()))),
        }
    }

    /// The largest side of any domain (N for a uniform layout): what the patch depth and
    /// texel-resolution tessellations follow.
    pub fn largest_side(&self) -> usize {
        let (a, b) = self.max_dims();
        a.max(b)
    }

    /// Global index of the first texel of domain `d`.
    #[inline]
    pub fn start(&self, d: usize) -> usize {
        self.start[d]
    }

    /// Global indices of domain `d`'s texels.
    #[inline]
    pub fn range(&self, d: usize) -> std::ops::Range<usize> {
        self.start[d]..self.start[d + 1]
    }

    /// Texels of domain `d`.
    #[inline]
    pub fn count(&self, d: usize) -> usize {
        self.start[d + 1] - self.start[d]
    }

    /// `v` (`per_texel` values per texel, global order) cut into one slice per domain, for
    /// parallel work per domain.
    pub fn split_mut<'a, T>(&self, v: &'a mut [T], per_texel: usize) -> Vec<&'a mut [T]> {
        assert_eq!(v.len(), self.len() * per_texel);
        let mut out = Vec::with_capacity(self.faces);
        let mut rest = v;
        for d in 0..self.faces {
            let (a, b) = std::mem::take(&mut rest).split_at_mut(self.count(d) * per_texel);
            out.push(a);
            rest = b;
        }
        out
    }

    /// Domain of global texel `t`.
    #[inline]
    pub fn domain_of(&self, t: usize) -> usize {
        match self.kind {
            Kind::Uniform(n) => t / (n * n),
            Kind::PerFace(_) => self.start.partition_point(|&s| s <= t) - 1,
        }
    }

    /// Global index of texel (x, y) of domain `d`.
    #[inline]
    pub fn index(&self, d: usize, x: usize, y: usize) -> usize {
        self.start[d] + y * self.dims(d).0 + x
    }

    /// (domain, x, y) of global texel `t`.
    #[inline]
    pub fn coords(&self, t: usize) -> (usize, usize, usize) {
        let d = self.domain_of(t);
        let nu = self.dims(d).0;
        let r = t - self.start[d];
        (d, r % nu, r / nu)
    }

    /// Domain point of the centre of global texel `t`.
    #[inline]
    pub fn location(&self, t: usize) -> DomainLocation {
        let (d, x, y) = self.coords(t);
        let (nu, nv) = self.dims(d);
        DomainLocation {
            domain: DomainId::from_idx(d),
            u: (x as f64 + 0.5) / nu as f64,
            v: (y as f64 + 0.5) / nv as f64,
        }
    }

    /// The texel of domain `d` containing the domain point (u, v) (clamped to the domain).
    #[inline]
    pub fn texel_at(&self, d: usize, u: f64, v: f64) -> usize {
        let (nu, nv) = self.dims(d);
        let c = |t: f64, n: usize| ((t * n as f64).floor().max(0.0) as usize).min(n - 1);
        self.index(d, c(u, nu), c(v, nv))
    }

    /// For reports and errors: "N = 32", or "4 to 4096 texels per face" with per-face resolutions.
    pub fn describe(&self) -> String {
        match &self.kind {
            Kind::Uniform(n) => format!("N = {n}"),
            Kind::PerFace(r) => {
                let min = r.iter().map(|r| r.u() * r.v()).min().unwrap_or(0);
                let max = r.iter().map(|r| r.u() * r.v()).max().unwrap_or(0);
                format!("{min} to {max} texels per face")
            }
        }
    }
}

/// (length along u, length along v) of a domain on the limit surface (see
/// [`TexelLayout::for_texel_size`]).
pub fn domain_lengths(surface: &Surface, d: DomainId) -> (f64, f64) {
    const S: usize = 8;
    let mut p = [[glam::DVec3::ZERO; S + 1]; S + 1];
    for (j, row) in p.iter_mut().enumerate() {
        for (i, q) in row.iter_mut().enumerate() {
            *q = surface.eval(d, i as f64 / S as f64, j as f64 / S as f64).p;
        }
    }
    let (mut lu, mut lv) = (0.0, 0.0);
    for (j, row) in p.iter().enumerate() {
        for i in 0..S {
            lu += row[i].distance(row[i + 1]);
            lv += p[i][j].distance(p[i + 1][j]);
        }
    }
    (lu / (S + 1) as f64, lv / (S + 1) as f64)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn uniform_indices_are_the_old_ones() {
        let l = TexelLayout::uniform(5, 3);
        assert_eq!(l.len(), 45);
        assert_eq!(l.index(2, 1, 2), (2 * 3 + 2) * 3 + 1);
        assert_eq!(l.coords(l.index(4, 2, 1)), (4, 2, 1));
        assert_eq!(l.domain_of(44), 4);
        assert_eq!(l.coarsened(1).uniform_n(), Some(2));
    }

    #[test]
    fn per_face_indices_round_trip() {
        let r = |a, b| Resolution::new(a, b).unwrap();
        let l = TexelLayout::per_face(vec![r(1, 2), r(3, 0), r(0, 0)]);
        assert_eq!(l.len(), 8 + 8 + 1);
        assert_eq!(l.dims(1), (8, 1));
        for t in 0..l.len() {
            let (d, x, y) = l.coords(t);
            assert_eq!(l.index(d, x, y), t);
            let loc = l.location(t);
            assert_eq!(l.texel_at(d, loc.u, loc.v), t);
        }
        assert_eq!(l.max_dims(), (8, 4));
        assert!(Resolution::new(14, 0).is_none());
        assert_eq!(l.coarsened(2).dims(0), (1, 1));
    }

    #[test]
    fn texel_size_evens_out_spacing_on_a_stretched_grid() {
        // A 4x1 grid scaled to 8 x 1: domains 2 long in x and 1 in y get 2:1 texels.
        let mut c = subdiv::ControlMesh::grid(2);
        for p in &mut c.mesh.positions {
            p.x *= 4.0;
        }
        let s = Surface::new(c);
        let l = TexelLayout::for_texel_size(&s, 0.05);
        for d in 0..l.faces() {
            let (nu, nv) = l.dims(d);
            let (lu, lv) = domain_lengths(&s, DomainId::from_idx(d));
            for (len, n) in [(lu, nu), (lv, nv)] {
                let h = len / n as f64;
                assert!(h > 0.05 / 2f64.sqrt() - 1e-9 && h < 0.05 * 2f64.sqrt() + 1e-9);
            }
        }
    }
}
