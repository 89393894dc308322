#!/usr/bin/env python3
"""bench/pgp_oracle.py — an oracle for issue 13's open step, not part of CI.

How far would a *lattice phase* carry a periodic example on a curved surface? This maps
the example onto an existing result's texels by a periodic global parametrisation alone —
no synthesis: two phases θ1, θ2 (one per dual vector of the example's lattice) solved on
the texels as the smallest eigenvector of a connection Laplacian (Knöppel et al. 2015's
stripes, two at once as in Ray et al. 2006's periodic global parametrisation), then
source = L · θ / 2π, moved into the example by a lattice vector. It writes a result
directory that `surfsynth eval` and `render` read (docs/synthesis.md, "A lattice phase,
measured by an oracle").

Usage: bench/pgp_oracle.py RESULT_DIR EXAMPLE.png OUT_DIR [LATTICE_JSON]
  RESULT_DIR  a `synth` output (its geometry.exr must have the field's T channels)
  LATTICE     the example's lattice as two vectors in pixels, default the weave of
              gimpx_greyweave.png: [[60, 60], [60, -60]] (its autocorrelation's peaks)
Needs numpy, scipy, pillow and the OpenEXR Python module (pip install OpenEXR).
Spot at N = 32 (258k texels) takes ~5 min, most of it two sparse LU factorisations.
"""
import sys, json, shutil, os, numpy as np, OpenEXR
from PIL import Image
from scipy.spatial import cKDTree
import scipy.sparse as sp, scipy.sparse.linalg as sla
src, exf, out = sys.argv[1:4]
LAT = np.array([[60.0, 60.0], [60.0, -60.0]]).T   # columns a, b (example px)
if len(sys.argv) > 4: LAT = np.array(json.loads(sys.argv[4]), float).T
os.makedirs(out, exist_ok=True)
for f in ('geometry.exr', 'report.json'): shutil.copy(f'{src}/{f}', f'{out}/{f}')
rep = json.load(open(f'{src}/report.json')); S = rep['scale']
G = OpenEXR.File(f'{src}/geometry.exr').channels()
P = np.stack([G[c].pixels for c in ('P.X', 'P.Y', 'P.Z')], -1).astype(np.float64)
Nn = np.stack([G[c].pixels for c in ('N.X', 'N.Y', 'N.Z')], -1).astype(np.float64)
T = np.stack([G[c].pixels for c in ('T.X', 'T.Y', 'T.Z')], -1).astype(np.float64)
H, W = P.shape[:2]
valid = np.isfinite(P).all(-1) & (np.abs(P).sum(-1) > 0)
idx = np.flatnonzero(valid.ravel())
p = P.reshape(-1, 3)[idx] / S; n = Nn.reshape(-1, 3)[idx]; t = T.reshape(-1, 3)[idx]
m = len(idx); print('texels', m)
tree = cKDTree(p); K = 9
d, nb = tree.query(p, K)
a = np.repeat(np.arange(m), K - 1); b = nb[:, 1:].ravel()
keep = a < b; a, b = a[keep], b[keep]
# frame at the edge: mean tangent, made orthogonal to the mean normal (the field is a
# 1-vector field: no sign matching needed away from singularities)
nm = n[a] + n[b]; nm /= np.linalg.norm(nm, axis=1, keepdims=True)
tm = t[a] + t[b]; tm -= (tm * nm).sum(1, keepdims=True) * nm
tm /= np.maximum(np.linalg.norm(tm, axis=1, keepdims=True), 1e-12)
vm = np.cross(nm, tm)  # v2 = n x v1: image rows (the Tiles handedness)
D = p[b] - p[a]
dx = np.stack([(D * tm).sum(1), (D * vm).sum(1)], 1)  # example px along x (v1), y (v2)
dual = np.linalg.inv(LAT)  # rows: d_i with d_i . a_j = delta_ij
w = 1.0 / np.maximum(np.linalg.norm(D, axis=1), 1e-6) ** 2
phases = []
for i in range(2):
    rho = 2 * np.pi * (dx @ dual[i])
    off = -w * np.exp(1j * rho)
    A = sp.coo_matrix((np.r_[off, off.conj()], (np.r_[b, a], np.r_[a, b])), shape=(m, m)).tocsr()
    deg = np.bincount(np.r_[a, b], weights=np.r_[w, w], minlength=m)
    A = A + sp.diags(deg)
    # smallest eigenvector by inverse iteration with a sparse LU of A + eps I
    lu = sla.splu((A + 1e-6 * sp.identity(m)).tocsc())
    rng = np.random.default_rng(1); x = rng.standard_normal(m) + 1j * rng.standard_normal(m)
    for it in range(12):
        x = lu.solve(x); x /= np.linalg.norm(x)
    e = np.vdot(x, A @ x).real
    print('phase', i, 'eigenvalue', e, '|psi| p5', np.percentile(np.abs(x) * np.sqrt(m), 5))
    phases.append(np.angle(x))
th = np.stack(phases, 1) / (2 * np.pi)          # lattice coordinates mod 1
xe = th @ LAT.T                                  # example px, mod lattice
ex = np.asarray(Image.open(exf).convert('RGB'), np.float64) / 255.0
lin = np.where(ex <= 0.04045, ex / 12.92, ((ex + 0.055) / 1.055) ** 2.4)
eh, ew = lin.shape[:2]
# move into the example's centre: subtract the lattice point nearest (xe - centre)
c = np.array([ew / 2, eh / 2])
k = np.round(np.linalg.solve(LAT, (xe - c).T)).T
xe = xe - k @ LAT.T
def bil(x, y):
    x = np.clip(x - 0.5, 0, ew - 1.001); y = np.clip(y - 0.5, 0, eh - 1.001)
    x0 = np.floor(x).astype(int); y0 = np.floor(y).astype(int); fx = (x - x0)[:, None]; fy = (y - y0)[:, None]
    return (lin[y0, x0] * (1 - fx) * (1 - fy) + lin[y0, x0 + 1] * fx * (1 - fy) + lin[y0 + 1, x0] * (1 - fx) * fy + lin[y0 + 1, x0 + 1] * fx * fy)
col = bil(xe[:, 0], xe[:, 1])
F = OpenEXR.File(f'{src}/facemaps.exr')
hdr = F.header(); ch = F.channels()
rgb = np.array(ch['RGB'].pixels, dtype=np.float32); su = np.array(ch['source.u'].pixels); sv = np.array(ch['source.v'].pixels)
rgb.reshape(-1, 3)[idx] = col.astype(np.float32)
su.ravel()[idx] = xe[:, 0]; sv.ravel()[idx] = xe[:, 1]
OpenEXR.File(hdr, {'RGB': rgb, 'source.u': su.astype(np.float32), 'source.v': sv.astype(np.float32)}).write(f'{out}/facemaps.exr')
print('written', out)
