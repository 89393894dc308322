//! Principal component analysis of neighbourhood vectors, for the ANN search.
//!
//! A 9x9 + 5x5 RGB neighbourhood is a 318-dimensional vector; kd-trees degrade to worse
//! than brute force at that dimension (measured: ~3x slower on 32-D uniform data, see
//! BRIEF.md). Texture neighbourhoods are far from uniform: neighbouring pixels are
//! correlated, so a handful of principal directions hold most of the variance. Projecting
//! onto them gives a space where a kd-tree is fast, and re-ranking its candidates with the
//! exact distance ([`super::ann`]) recovers the accuracy lost by projecting.
//!
//! The top components come from subspace iteration with Rayleigh–Ritz on the covariance of
//! at most [`MAX_ROWS`] evenly spaced rows: a few hundred thousand flops per iteration
//! instead of the cubic cost of a full eigendecomposition, which matters because a
//! multiscale run fits one PCA per level and pass. Everything is deterministic (fixed start
//! basis, fixed row subset, sequential accumulation order).

/// Rows used to estimate the covariance. 2048 rows estimate a 318x318 covariance's leading
/// eigenvectors well (the leading eigenvalues hold most of the variance and are separated),
/// and keep the fit at a few tens of milliseconds. Any orthonormal basis keeps the search
/// correct (re-ranking is exact and projected distances are true lower bounds); a better
/// basis only makes it faster.
pub const MAX_ROWS: usize = 2048;

/// The rows of `n` that [`Pca::fit`] estimates the covariance from: all of them, or
/// [`MAX_ROWS`] evenly spaced. A caller that makes its rows on demand (e.g. the
/// reflectance vectors of a BTF sample, `matching::reflectance`) makes only these and
/// fits on them: the same projection.
pub fn fit_rows(n: usize) -> Vec<usize> {
    if n <= MAX_ROWS {
        (0..n).collect()
    } else {
        (0..MAX_ROWS).map(|i| i * n / MAX_ROWS).collect()
    }
}

/// A fitted projection onto the leading `k` principal directions.
#[derive(Clone, Debug)]
pub struct Pca {
    pub dim: usize,
    pub k: usize,
    /// Mean of the fitted rows.
    pub mean: Vec<f32>,
    /// `k x dim`, row-major, orthonormal rows, by decreasing eigenvalue.
    pub basis: Vec<f32>,
    /// Variance along each kept direction.
    pub eigenvalues: Vec<f64>,
    /// Total variance (trace of the covariance).
    pub total_variance: f64,
}

impl Pca {
    /// Fits `k` components to `data` (`n x dim`, row-major).
    pub fn fit(data: &[f32], dim: usize, k: usize) -> Self {
        assert!(dim > 0 && k > 0 && k <= dim);
        let n = data.len() / dim;
        assert!(n > 0, "PCA needs at least one row");
        let rows = fit_rows(n);
        let m = rows.len() as f64;
        // Mean.
        let mut mean = vec![0.0f64; dim];
        for &r in &rows {
            for (a, &x) in mean.iter_mut().zip(&data[r * dim..(r + 1) * dim]) {
                *a += x as f64;
            }
        }
        mean.iter_mut().for_each(|a| *a /= m);
        let meanf: Vec<f32> = mean.iter().map(|&x| x as f32).collect();
        // Covariance (upper triangle), accumulated in f32 over blocks of rows and then in
        // f64, which keeps the inner loop vectorised without losing precision over
        // thousands of rows.
        let mut cov = vec![0.0f64; dim * dim];
        let mut block = vec![0.0f32; dim * dim];
        let mut centred = vec![0.0f32; dim];
        for chunk in rows.chunks(128) {
            block.iter_mut().for_each(|b| *b = 0.0);
            for &r in chunk {
                for (c, (&x, &mu)) in centred
                    .iter_mut()
                    .zip(data[r * dim..(r + 1) * dim].iter().zip(&meanf))
                {
                    *c = x - mu;
                }
                for i in 0..dim {
                    let ci = centred[i];
                    let row = &mut block[i * dim + i..(i + 1) * dim];
                    for (b, &cj) in row.iter_mut().zip(&centred[i..]) {
                        *b += ci * cj;
                    }
                }
            }
            for i in 0..dim {
                for j in i..dim {
                    cov[i * dim + j] += block[i * dim + j] as f64;
                }
            }
        }
        for i in 0..dim {
            for j in i..dim {
                let v = cov[i * dim + j] / m;
                cov[i * dim + j] = v;
                cov[j * dim + i] = v;
            }
        }
        let total_variance: f64 = (0..dim).map(|i| cov[i * dim + i]).sum();
        let (eigenvalues, vecs) = top_eigen(&cov, dim, k);
        let basis = vecs.iter().map(|&x| x as f32).collect();
        Self {
            dim,
            k,
            mean: meanf,
            basis,
            eigenvalues,
            total_variance,
        }
    }

    /// Fraction of the total variance along the kept directions (of the fitted rows).
    pub fn kept_variance(&self) -> f64 {
        if self.total_variance <= 0.0 {
            1.0
        } else {
            (self.eigenvalues.iter().sum::<f64>() / self.total_variance).min(1.0)
        }
    }

    /// Projects `v` (length `dim`) into `out` (length `k`).
    #[inline]
    pub fn project(&self, v: &[f32], out: &mut [f32]) {
        for (j, o) in out.iter_mut().enumerate().take(self.k) {
            let b = &self.basis[j * self.dim..(j + 1) * self.dim];
            let mut acc = [0.0f32; 8];
            let mut ib = b.chunks_exact(8);
            let mut iv = v.chunks_exact(8);
            let mut im = self.mean.chunks_exact(8);
            for ((bb, vv), mm) in (&mut ib).zip(&mut iv).zip(&mut im) {
                for t in 0..8 {
                    acc[t] += bb[t] * (vv[t] - mm[t]);
                }
            }
            let mut s: f32 = acc.iter().sum();
            for ((bb, vv), mm) in ib
                .remainder()
                .iter()
                .zip(iv.remainder())
                .zip(im.remainder())
            {
                s += bb * (vv - mm);
            }
            *o = s;
        }
    }

    /// Projects `v` treating dimensions with `mask == 0` as equal to the mean (they add
    /// nothing): the least-committal stand-in for samples a target neighbourhood lacks.
    #[inline]
    pub fn project_masked(&self, v: &[f32], mask: &[f32], out: &mut [f32]) {
        for (j, o) in out.iter_mut().enumerate().take(self.k) {
            let b = &self.basis[j * self.dim..(j + 1) * self.dim];
            let mut s = 0.0f32;
            for t in 0..self.dim {
                s += mask[t] * b[t] * (v[t] - self.mean[t]);
            }
            *o = s;
        }
    }
}

/// Leading `k` eigenpairs of the symmetric `n x n` matrix `a` by subspace iteration with
/// Rayleigh–Ritz (`p = k + 8` vectors for faster convergence of the last wanted ones).
/// Returns eigenvalues (descending) and `k x n` eigenvectors.
pub(crate) fn top_eigen(a: &[f64], n: usize, k: usize) -> (Vec<f64>, Vec<f64>) {
    let p = (k + 8).min(n);
    // Deterministic start: pseudo-random vectors from the counter hash.
    let mut q: Vec<f64> = (0..p * n)
        .map(|i| {
            (crate::random::hash(0x5EED, &[i as u64]) >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        })
        .collect();
    orthonormalise(&mut q, n, p);
    let mut z = vec![0.0f64; p * n];
    let mut vals = vec![0.0f64; p];
    for iter in 0..30 {
        // z = A q (row vectors: z_j = A q_j).
        for j in 0..p {
            let qj = &q[j * n..(j + 1) * n];
            for i in 0..n {
                let row = &a[i * n..(i + 1) * n];
                z[j * n + i] = dot(row, qj);
            }
        }
        std::mem::swap(&mut q, &mut z);
        orthonormalise(&mut q, n, p);
        if iter % 10 == 9 {
            // Rayleigh–Ritz: H = Q A Qᵀ (p x p), diagonalise, rotate Q.
            let mut aq = vec![0.0f64; p * n];
            for j in 0..p {
                let qj = &q[j * n..(j + 1) * n];
                for i in 0..n {
                    let row = &a[i * n..(i + 1) * n];
                    aq[j * n + i] = dot(row, qj);
                }
            }
            let mut h = vec![0.0f64; p * p];
            for r in 0..p {
                for c in 0..p {
                    h[r * p + c] = dot(&q[r * n..(r + 1) * n], &aq[c * n..(c + 1) * n]);
                }
            }
            let (ev, vecs) = jacobi_eigen(&mut h, p);
            let mut rotated = vec![0.0f64; p * n];
            for (r, &(_, src)) in ev.iter().enumerate() {
                for c in 0..p {
                    let w = vecs[c * p + src];
                    if w != 0.0 {
                        for i in 0..n {
                            rotated[r * n + i] += w * q[c * n + i];
                        }
                    }
                }
            }
            q = rotated;
            for (r, &(v, _)) in ev.iter().enumerate() {
                vals[r] = v.max(0.0);
            }
        }
    }
    (vals[..k].to_vec(), q[..k * n].to_vec())
}

/// Dot product with eight independent partial sums (a single running sum is a serial
/// dependency chain the compiler may not reorder; this one vectorises).
#[inline]
fn dot(a: &[f64], b: &[f64]) -> f64 {
    let mut acc = [0.0f64; 8];
    let mut ia = a.chunks_exact(8);
    let mut ib = b.chunks_exact(8);
    for (x, y) in (&mut ia).zip(&mut ib) {
        for k in 0..8 {
            acc[k] += x[k] * y[k];
        }
    }
    let mut s: f64 = acc.iter().sum();
    for (x, y) in ia.remainder().iter().zip(ib.remainder()) {
        s += x * y;
    }
    s
}

/// Modified Gram–Schmidt on the `p` rows of `q` (length `n` each). A row that collapses
/// (rank-deficient data) is replaced by a unit coordinate vector orthogonalised again.
fn orthonormalise(q: &mut [f64], n: usize, p: usize) {
    for j in 0..p {
        for attempt in 0..=n {
            for i in 0..j {
                let d = dot(&q[i * n..(i + 1) * n], &q[j * n..(j + 1) * n]);
                for t in 0..n {
                    q[j * n + t] -= d * q[i * n + t];
                }
            }
            let norm = dot(&q[j * n..(j + 1) * n], &q[j * n..(j + 1) * n]).sqrt();
            if norm > 1e-12 {
                q[j * n..(j + 1) * n].iter_mut().for_each(|x| *x /= norm);
                break;
            }
            let row = &mut q[j * n..(j + 1) * n];
            row.iter_mut().for_each(|x| *x = 0.0);
            row[(j + attempt) % n] = 1.0;
        }
    }
}

/// Eigenpairs of a small symmetric `p x p` matrix by cyclic Jacobi rotations. Returns
/// (eigenvalue, column index) sorted by decreasing eigenvalue and the eigenvector matrix
/// (column `c` of `v` is the eigenvector of diagonal entry `c`).
fn jacobi_eigen(h: &mut [f64], p: usize) -> (Vec<(f64, usize)>, Vec<f64>) {
    let mut v = vec![0.0f64; p * p];
    for i in 0..p {
        v[i * p + i] = 1.0;
    }
    for _sweep in 0..100 {
        let off: f64 = (0..p)
            .flat_map(|r| (0..p).filter(move |&c| c != r).map(move |c| (r, c)))
            .map(|(r, c)| h[r * p + c].powi(2))
            .sum();
        let diag: f64 = (0..p).map(|i| h[i * p + i].powi(2)).sum();
        if off <= 1e-30 * diag.max(1e-300) {
            break;
        }
        for a in 0..p {
            for b in a + 1..p {
                let hab = h[a * p + b];
                if hab == 0.0 {
                    continue;
                }
                let theta = (h[b * p + b] - h[a * p + a]) / (2.0 * hab);
                let t = theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt());
                let t = if theta == 0.0 { 1.0 } else { t };
                let c = 1.0 / (t * t + 1.0).sqrt();
                let s = t * c;
                for k in 0..p {
                    let (hka, hkb) = (h[k * p + a], h[k * p + b]);
                    h[k * p + a] = c * hka - s * hkb;
                    h[k * p + b] = s * hka + c * hkb;
                }
                for k in 0..p {
                    let (hak, hbk) = (h[a * p + k], h[b * p + k]);
                    h[a * p + k] = c * hak - s * hbk;
                    h[b * p + k] = s * hak + c * hbk;
                }
                for k in 0..p {
                    let (vka, vkb) = (v[k * p + a], v[k * p + b]);
                    v[k * p + a] = c * vka - s * vkb;
                    v[k * p + b] = s * vka + c * vkb;
                }
            }
        }
    }
    let mut ev: Vec<(f64, usize)> = (0..p).map(|i| (h[i * p + i], i)).collect();
    ev.sort_by(|x, y| y.0.total_cmp(&x.0).then(x.1.cmp(&y.1)));
    (ev, v)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn recovers_known_principal_directions() {
        // Points on a 3-D subspace of R^12 with variances 9, 4, 1 plus tiny noise.
        let dim = 12;
        let dirs = [
            [
                1.0f32, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0,
            ],
            [0.0, 0.0, 1.0, -1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
            [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 1.0],
        ];
        let sd = [3.0f32, 2.0, 1.0];
        let n = 3000;
        let mut data = vec![0.0f32; n * dim];
        let g = |i: u64| {
            // Uniform in [-sqrt3, sqrt3]: unit variance.
            let u = (crate::random::hash(9, &[i]) >> 11) as f32 / (1u64 << 53) as f32;
            (u - 0.5) * 2.0 * 3f32.sqrt()
        };
        for r in 0..n {
            for (k, d) in dirs.iter().enumerate() {
                let a = g((r * 3 + k) as u64) * sd[k] / 2f32.sqrt();
                for t in 0..dim {
                    data[r * dim + t] += a * d[t];
                }
            }
            for t in 0..dim {
                data[r * dim + t] += 1e-3 * g((1_000_000 + r * dim + t) as u64) + 5.0;
            }
        }
        let pca = Pca::fit(&data, dim, 3);
        let ratios: Vec<f64> = pca.eigenvalues.iter().map(|e| e / 9.0).collect();
        assert!((ratios[0] - 1.0).abs() < 0.1, "{ratios:?}");
        assert!((ratios[1] - 4.0 / 9.0).abs() < 0.05, "{ratios:?}");
        assert!((ratios[2] - 1.0 / 9.0).abs() < 0.02, "{ratios:?}");
        assert!(pca.kept_variance() > 0.9999, "{}", pca.kept_variance());
        // First direction is ±(1,1,0..)/sqrt2.
        let b0 = &pca.basis[..dim];
        assert!(
            (b0[0].abs() - std::f32::consts::FRAC_1_SQRT_2).abs() < 1e-2
                && (b0[0] - b0[1]).abs() < 1e-2
        );
        // Projection of the mean is zero; masked projection with a full mask agrees.
        let mut o = [0.0f32; 3];
        pca.project(&pca.mean, &mut o);
        assert!(o.iter().all(|x| x.abs() < 1e-5));
        let (mut a, mut b) = ([0.0f32; 3], [0.0f32; 3]);
        pca.project(&data[..dim], &mut a);
        pca.project_masked(&data[..dim], &[1.0; 12], &mut b);
        assert!(a.iter().zip(&b).all(|(x, y)| (x - y).abs() < 1e-5));
    }

    #[test]
    fn rank_deficient_data_still_gives_an_orthonormal_basis() {
        let dim = 6;
        let data: Vec<f32> = (0..50)
            .flat_map(|i| [i as f32, 0.0, 0.0, 0.0, 0.0, 1.0])
            .collect();
        let pca = Pca::fit(&data, dim, 4);
        for a in 0..4 {
            for b in 0..4 {
                let d: f32 = (0..dim)
                    .map(|t| pca.basis[a * dim + t] * pca.basis[b * dim + t])
                    .sum();
                assert!((d - (a == b) as i32 as f32).abs() < 1e-4, "{a} {b} {d}");
            }
        }
        assert!((pca.kept_variance() - 1.0).abs() < 1e-9);
        assert!(pca.eigenvalues[1].abs() < 1e-9);
    }
}
