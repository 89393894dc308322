//! Texton analysis of a BTF sample (paper 003 §4), level by level of its pyramid.
//!
//! 1. **Filter responses**: every image of the level through a small filter bank —
//!    Gaussian-smoothed R, G, B (σ = 1) and, on the luminance, the x and y Gaussian
//!    derivatives at σ = 1 and σ = 2 and the Laplacian of Gaussian at σ = 2: [`FILTERS`] = 8
//!    responses per image (003 uses 48 Gaussian-derivative filters on 3600 images; with 16–64
//!    images a smaller bank keeps the vectors short, and the colour terms keep textons apart
//!    that differ only in hue). A pixel's *response vector* concatenates its responses in
//!    every image (003 selects n_s representative images first because it has thousands; all
//!    images are used here, n_s = n ≤ [`crate::btf::MAX_IMAGES`]).
//! 2. **3D textons**: k-means of the response vectors (Lloyd iterations from k-means++
//!    seeds drawn with a fixed counter hash, so the textons are a function of the pixels
//!    alone: deterministic and cacheable). [`TextonParams::textons`] at the finest level, a
//!    quarter per coarser level (003 §5.1), at least [`MIN_TEXTONS`].
//! 3. **Texton map** t_in: every pixel's nearest texton; **dot-product matrix** Γ (γ_ij =
//!    t_i · t_j of the textons' appearance vectors). The appearance vectors are then
//!    discarded: everything synthesis needs is Γ and the map (003 §4, "surface textons").
//!
//! **Distances from Γ.** 003 computes ‖s(p) − t_j‖² for interpolated surface textons
//! s = Σ w_i t_i as quadratic forms in Γ. The same numbers come from any vectors e_i with
//! e_i · e_j = γ_ij (up to a common translation, which differences cancel), so
//! [`TextonLevel::embedding`] factorises the centred Γ once (eigen-decomposition, weighted
//! by how many pixels carry each texton) into [`TextonParams::dims`]-dimensional
//! coordinates, and neighbourhood distances become plain l2 over those coordinates — which
//! lets the project's k-coherence search (k-NN lists, multiscale two-level neighbourhoods)
//! run on textons unchanged. Kept: the leading `dims` eigenvalues' share of the trace
//! (reported as `kept_variance`); with all n_t dimensions the distances are exactly Γ's.

use crate::btf::BtfSample;
use crate::pyramid::Image;
use crate::random::hash;
use crate::synth::matching::search::pca::top_eigen;
use rayon::prelude::*;
use serde::Serialize;

/// Filter responses per image (see the module docs).
pub const FILTERS: usize = 8;
/// Fewest textons of any level.
pub const MIN_TEXTONS: usize = 8;

/// Settings of texton analysis.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct TextonParams {
    /// Textons n_t at the finest level (003: 400 for 3600 images of 64²; measured here on
    /// 64² samples of 32 images: see docs/btf.md).
    pub textons: usize,
    /// Lloyd iterations at most (stops earlier when no label changes).
    pub iterations: usize,
    /// Dimensions of the Γ embedding the neighbourhoods compare. 4: every candidate
    /// distance of the search (the largest share of the run's time) and every neighbourhood
    /// fetch cost half what 8 did, and the leading four eigenvalues already hold most of
    /// the centred Γ's trace (krita relief, 64², 32 lights: see report `kept_variance`);
    /// pf4/pf8 per light were the same or better than with 8 on Spot and the double torus,
    /// seeds 1–2 (docs/btf.md, "Embedding dimensions").
    pub dims: usize,
}

impl Default for TextonParams {
    fn default() -> Self {
        Self {
            textons: 96,
            iterations: 12,
            dims: 4,
        }
    }
}

/// One level's textons.
#[derive(Clone, Debug, PartialEq)]
pub struct TextonLevel {
    pub width: usize,
    pub height: usize,
    /// n_t.
    pub textons: usize,
    /// The 2D texton map t_in: a texton per pixel, row-major.
    pub labels: Vec<u32>,
    /// Γ, n_t x n_t row-major: dot products of the textons' appearance vectors.
    pub gamma: Vec<f64>,
}

/// Every level's textons, finest first.
#[derive(Clone, Debug, PartialEq)]
pub struct Textons {
    pub levels: Vec<TextonLevel>,
}

/// What the analysis found (report.json `textons.analysis`).
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct TextonInfo {
    /// n_t per level, finest first.
    pub textons: Vec<usize>,
    /// Response vector length (images x [`FILTERS`]).
    pub response_dims: usize,
    /// Share of Γ's (centred, pixel-weighted) trace the embedding keeps, per level.
    pub kept_variance: Vec<f64>,
}

/// Separable 1D kernels of radius ⌈3σ⌉: Gaussian, first and second derivative.
fn kernels(sigma: f64) -> [Vec<f32>; 3] {
    let r = (3.0 * sigma).ceil() as i64;
    let g: Vec<f64> = (-r..=r)
        .map(|x| (-(x * x) as f64 / (2.0 * sigma * sigma)).exp())
        .collect();
    let s: f64 = g.iter().sum();
    let g: Vec<f64> = g.iter().map(|v| v / s).collect();
    let d1: Vec<f32> = (-r..=r)
        .zip(&g)
        .map(|(x, v)| (-(x as f64) / (sigma * sigma) * v) as f32)
        .collect();
    let d2: Vec<f32> = (-r..=r)
        .zip(&g)
        .map(|(x, v)| (((x * x) as f64 / sigma.powi(4) - 1.0 / (sigma * sigma)) * v) as f32)
        .collect();
    [g.iter().map(|&v| v as f32).collect(), d1, d2]
}

/// `img` (one channel, w x h) convolved with `kx` along rows and `ky` along columns,
/// borders clamped.
fn separable(img: &[f32], w: usize, h: usize, kx: &[f32], ky: &[f32]) -> Vec<f32> {
    let rx = (kx.len() / 2) as i64;
    let ry = (ky.len() / 2) as i64;
    let mut tmp = vec![0f32; w * h];
    for y in 0..h {
        for x in 0..w {
            let mut s = 0f32;
            for (i, k) in kx.iter().enumerate() {
                let sx = (x as i64 + i as i64 - rx).clamp(0, w as i64 - 1) as usize;
                s += k * img[y * w + sx];
            }
            tmp[y * w + x] = s;
        }
    }
    let mut out = vec![0f32; w * h];
    for y in 0..h {
        for x in 0..w {
            let mut s = 0f32;
            for (i, k) in ky.iter().enumerate() {
                let sy = (y as i64 + i as i64 - ry).clamp(0, h as i64 - 1) as usize;
                s += k * tmp[sy * w + x];
            }
            out[y * w + x] = s;
        }
    }
    out
}

/// The [`FILTERS`] responses of one RGB image (3 channels), as `FILTERS` planes.
fn responses(img: &Image) -> Vec<Vec<f32>> {
    let (w, h) = (img.width, img.height);
    let plane = |c: usize| -> Vec<f32> { img.data.chunks_exact(3).map(|p| p[c]).collect() };
    let lum: Vec<f32> = img
        .data
        .chunks_exact(3)
        .map(|p| 0.2126 * p[0] + 0.7152 * p[1] + 0.0722 * p[2])
        .collect();
    let [g1, d1, _] = kernels(1.0);
    let [g2, e1, e2] = kernels(2.0);
    let mut out = Vec::with_capacity(FILTERS);
    for c in 0..3 {
        out.push(separable(&plane(c), w, h, &g1, &g1));
    }
    out.push(separable(&lum, w, h, &d1, &g1));
    out.push(separable(&lum, w, h, &g1, &d1));
    out.push(separable(&lum, w, h, &e1, &g2));
    out.push(separable(&lum, w, h, &g2, &e1));
    let xx = separable(&lum, w, h, &e2, &g2);
    let yy = separable(&lum, w, h, &g2, &e2);
    out.push(xx.iter().zip(&yy).map(|(a, b)| a + b).collect());
    out
}

/// Response vectors of every pixel (row-major, `images.len() * FILTERS` each).
fn response_vectors(images: &[Image]) -> (Vec<f32>, usize) {
    let (w, h) = (images[0].width, images[0].height);
    let dim = images.len() * FILTERS;
    let planes: Vec<Vec<Vec<f32>>> = images.par_iter().map(responses).collect();
    let mut v = vec![0f32; w * h * dim];
    v.par_chunks_mut(dim).enumerate().for_each(|(p, row)| {
        for (i, im) in planes.iter().enumerate() {
            for (f, pl) in im.iter().enumerate() {
                row[i * FILTERS + f] = pl[p];
            }
        }
    });
    (v, dim)
}

fn dist2(a: &[f32], b: &[f32]) -> f32 {
    let mut acc = [0f32; 8];
    let (ca, cb) = (a.chunks_exact(8), b.chunks_exact(8));
    let (ra, rb) = (ca.remainder(), cb.remainder());
    for (x, y) in ca.zip(cb) {
        for k in 0..8 {
            let d = x[k] - y[k];
            acc[k] += d * d;
        }
    }
    let mut s: f32 = acc.iter().sum();
    for (x, y) in ra.iter().zip(rb) {
        s += (x - y) * (x - y);
    }
    s
}

/// Nearest centre of every row (ties: the lower index) and its squared distance.
fn assign(data: &[f32], dim: usize, centres: &[f32]) -> Vec<(u32, f32)> {
    let k = centres.len() / dim;
    data.par_chunks(dim)
        .map(|row| {
            let mut best = (0u32, f32::INFINITY);
            for c in 0..k {
                let d = dist2(row, &centres[c * dim..(c + 1) * dim]);
                if d < best.1 {
                    best = (c as u32, d);
                }
            }
            best
        })
        .collect()
}

/// k-means of the rows of `data` into `k` centres: k-means++ seeds from a fixed counter
/// hash (`salt`), then Lloyd iterations; an emptied cluster is re-seeded at the row
/// farthest from its centre. Deterministic for any thread count (rows are assigned
/// independently; sums run in row order).
pub fn kmeans(data: &[f32], dim: usize, k: usize, iterations: usize, salt: u64) -> Vec<f32> {
    let n = data.len() / dim;
    let k = k.min(n).max(1);
    let row = |i: usize| &data[i * dim..(i + 1) * dim];
    let unit = |i: u64| (hash(0x7E7_0A5 ^ salt, &[i]) >> 11) as f64 / (1u64 << 53) as f64;
    let mut centres: Vec<f32> = Vec::with_capacity(k * dim);
    let first = ((unit(0) * n as f64) as usize).min(n - 1);
    centres.extend_from_slice(row(first));
    let mut d2: Vec<f32> = data.par_chunks(dim).map(|r| dist2(r, row(first))).collect();
    for c in 1..k {
        let total: f64 = d2.iter().map(|&v| v as f64).sum();
        let pick = if total <= 0.0 {
            c % n
        } else {
            let target = unit(c as u64) * total;
            let mut acc = 0.0;
            let mut pick = n - 1;
            for (i, &v) in d2.iter().enumerate() {
                acc += v as f64;
                if acc >= target && v > 0.0 {
                    pick = i;
                    break;
                }
            }
            pick
        };
        centres.extend_from_slice(row(pick));
        let new = &centres[c * dim..(c + 1) * dim];
        d2.par_chunks_mut(1024).enumerate().for_each(|(b, chunk)| {
            for (j, v) in chunk.iter_mut().enumerate() {
                *v = v.min(dist2(row(b * 1024 + j), new));
            }
        });
    }
    let mut labels: Vec<u32> = vec![u32::MAX; n];
    for _ in 0..iterations {
        let a = assign(data, dim, &centres);
        let changed = a.iter().zip(&labels).any(|(x, &l)| x.0 != l);
        labels = a.iter().map(|x| x.0).collect();
        if !changed {
            break;
        }
        let mut sums = vec![0f64; k * dim];
        let mut counts = vec![0usize; k];
        for (i, &l) in labels.iter().enumerate() {
            let l = l as usize;
            counts[l] += 1;
            for (s, &v) in sums[l * dim..(l + 1) * dim].iter_mut().zip(row(i)) {
                *s += v as f64;
            }
        }
        let mut far: Vec<usize> = (0..n).collect();
        far.sort_by(|&x, &y| a[y].1.total_cmp(&a[x].1).then(x.cmp(&y)));
        let mut far = far.into_iter();
        for c in 0..k {
            let dst = &mut centres[c * dim..(c + 1) * dim];
            if counts[c] == 0 {
                let r = far.next().unwrap_or(c % n);
                dst.copy_from_slice(&data[r * dim..(r + 1) * dim]);
            } else {
                for (d, s) in dst.iter_mut().zip(&sums[c * dim..(c + 1) * dim]) {
                    *d = (*s / counts[c] as f64) as f32;
                }
            }
        }
    }
    centres
}

impl TextonLevel {
    /// Textons of one level's images (all of one size, 3 channels).
    pub fn analyse(images: &[Image], textons: usize, iterations: usize, salt: u64) -> Self {
        let (w, h) = (images[0].width, images[0].height);
        let (data, dim) = response_vectors(images);
        let centres = kmeans(&data, dim, textons, iterations, salt);
        let labels: Vec<u32> = assign(&data, dim, &centres)
            .into_iter()
            .map(|x| x.0)
            .collect();
        // Keep only textons some pixel carries (a re-seeded centre may end up empty),
        // renumbered in order.
        let k = centres.len() / dim;
        let mut used = vec![false; k];
        for &l in &labels {
            used[l as usize] = true;
        }
        let mut new_id = vec![u32::MAX; k];
        let mut kept = Vec::new();
        for c in 0..k {
            if used[c] {
                new_id[c] = kept.len() as u32;
                kept.push(c);
            }
        }
        let labels: Vec<u32> = labels.iter().map(|&l| new_id[l as usize]).collect();
        let nt = kept.len();
        let v = |c: usize| &centres[kept[c] * dim..(kept[c] + 1) * dim];
        let mut gamma = vec![0f64; nt * nt];
        for i in 0..nt {
            for j in 0..=i {
                let d: f64 = v(i)
                    .iter()
                    .zip(v(j))
                    .map(|(a, b)| *a as f64 * *b as f64)
                    .sum();
                gamma[i * nt + j] = d;
                gamma[j * nt + i] = d;
            }
        }
        Self {
            width: w,
            height: h,
            textons: nt,
            labels,
            gamma,
        }
    }

    /// Pixels per texton.
    pub fn counts(&self) -> Vec<usize> {
        let mut c = vec![0usize; self.textons];
        for &l in &self.labels {
            c[l as usize] += 1;
        }
        c
    }

    /// `dims`-dimensional coordinates e_i of the textons with e_i · e_j ≈ the centred γ_ij
    /// (module docs), and the share of the trace kept. The centring and weights use how many
    /// pixels carry each texton, so the dimensions dropped are those that matter least to
    /// the sample's pixels.
    pub fn embedding(&self, dims: usize) -> (Vec<f32>, f64) {
        let nt = self.textons;
        let counts = self.counts();
        let total = self.labels.len() as f64;
        let p: Vec<f64> = counts.iter().map(|&c| c as f64 / total).collect();
        let g = &self.gamma;
        // Centred Gram matrix G = Γ − a 1ᵀ − 1 aᵀ + c (a_i = Σ_k p_k γ_ik, c = Σ p_k a_k):
        // the dot products of the textons after subtracting the pixels' mean vector.
        let a: Vec<f64> = (0..nt)
            .map(|i| (0..nt).map(|k| p[k] * g[i * nt + k]).sum())
            .collect();
        let c: f64 = (0..nt).map(|k| p[k] * a[k]).sum();
        let sp: Vec<f64> = p.iter().map(|v| v.sqrt()).collect();
        // M = P^½ G P^½: its eigenvectors are the directions of most pixel variance.
        let mut m = vec![0f64; nt * nt];
        for i in 0..nt {
            for j in 0..nt {
                m[i * nt + j] = sp[i] * sp[j] * (g[i * nt + j] - a[i] - a[j] + c);
            }
        }
        let trace: f64 = (0..nt).map(|i| m[i * nt + i].max(0.0)).sum();
        let k = dims.min(nt);
        let (vals, vecs) = top_eigen(&m, nt, k);
        let kept: f64 = vals.iter().sum();
        let mut e = vec![0f32; nt * dims];
        for i in 0..nt {
            for d in 0..k {
                e[i * dims + d] = (vecs[d * nt + i] * vals[d].max(0.0).sqrt() / sp[i]) as f32;
            }
        }
        let share = if trace > 0.0 {
            (kept / trace).min(1.0)
        } else {
            1.0
        };
        (e, share)
    }

    /// The texton map as an image of embedding coordinates (`dims` channels): what the
    /// k-coherence search compares.
    pub fn embedded_image(&self, dims: usize) -> (Image, f64) {
        let (e, kept) = self.embedding(dims);
        let mut img = Image::new(self.width, self.height, dims);
        for (px, &l) in img.data.chunks_exact_mut(dims).zip(&self.labels) {
            px.copy_from_slice(&e[l as usize * dims..(l as usize + 1) * dims]);
        }
        (img, kept)
    }
}

impl Textons {
    /// Texton analysis of `sample`, `levels` pyramid levels starting `j0` levels down (the
    /// levels multiscale synthesis will use).
    pub fn analyse(sample: &BtfSample, j0: usize, levels: usize, p: &TextonParams) -> Self {
        let mut images: Vec<Image> = sample.images.iter().map(Image::from_example).collect();
        for _ in 0..j0 {
            images = images.par_iter().map(Image::downsample).collect();
        }
        let mut out = Vec::with_capacity(levels);
        let mut nt = p.textons.max(MIN_TEXTONS);
        for l in 0..levels {
            if l > 0 {
                images = images.par_iter().map(Image::downsample).collect();
            }
            let px = images[0].width * images[0].height;
            let k = nt.min(px.div_ceil(4)).max(1);
            out.push(TextonLevel::analyse(&images, k, p.iterations, l as u64));
            nt = (nt / 4).max(MIN_TEXTONS);
        }
        Self { levels: out }
    }
}

impl crate::cache::Persist for Textons {
    /// Per level: size, n_t, the texton map and Γ (the appearance vectors are discarded, as
    /// in 003).
    fn save(&self, w: &mut crate::cache::Writer) {
        w.usize(self.levels.len());
        for l in &self.levels {
            w.usize(l.width);
            w.usize(l.height);
            w.usize(l.textons);
            w.u32s(&l.labels);
            for &g in &l.gamma {
                w.f64(g);
            }
        }
    }

    fn load(r: &mut crate::cache::Reader<'_>) -> Option<Self> {
        let n = r.usize_max(64)?;
        let mut levels = Vec::with_capacity(n);
        for _ in 0..n {
            let (width, height) = (r.usize_max(1 << 16)?, r.usize_max(1 << 16)?);
            let textons = r.usize_max(1 << 16)?;
            let labels = r.u32s()?;
            if labels.len() != width * height || labels.iter().any(|&l| l as usize >= textons) {
                return None;
            }
            let mut gamma = Vec::with_capacity(textons * textons);
            for _ in 0..textons * textons {
                let g = r.f64()?;
                if !g.is_finite() {
                    return None;
                }
                gamma.push(g);
            }
            levels.push(TextonLevel {
                width,
                height,
                textons,
                labels,
                gamma,
            });
        }
        (n > 0).then_some(Self { levels })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn kmeans_separates_two_clusters_and_gamma_is_their_dot_products() {
        // Two images: left half dark, right half bright; one texton each.
        let mut a = Image::new(8, 8, 3);
        for y in 0..8 {
            for x in 4..8 {
                a.pixel_mut(x, y).copy_from_slice(&[0.9, 0.9, 0.9]);
            }
        }
        let t = TextonLevel::analyse(&[a.clone(), a], 2, 10, 0);
        assert_eq!(t.textons, 2);
        assert_ne!(t.labels[0], t.labels[7]);
        assert_eq!(t.labels[0], t.labels[8 * 7]);
        let (e, kept) = t.embedding(2);
        // Distances from the embedding equal those from Γ.
        let g = |i: usize, j: usize| t.gamma[i * 2 + j];
        let dg = g(0, 0) + g(1, 1) - 2.0 * g(0, 1);
        let de: f32 = (0..2).map(|d| (e[d] - e[2 + d]).powi(2)).sum();
        assert!((de as f64 - dg).abs() < 1e-3 * dg, "{de} {dg}");
        assert!(kept > 0.999);
    }

    #[test]
    fn kmeans_does_not_depend_on_the_thread_count() {
        let data: Vec<f32> = (0..4000)
            .map(|i| ((hash(9, &[i]) >> 40) as f32) / (1u64 << 24) as f32)
            .collect();
        let one = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .unwrap()
            .install(|| kmeans(&data, 8, 20, 10, 0));
        let three = rayon::ThreadPoolBuilder::new()
            .num_threads(3)
            .build()
            .unwrap()
            .install(|| kmeans(&data, 8, 20, 10, 0));
        assert_eq!(one, three);
    }
}
