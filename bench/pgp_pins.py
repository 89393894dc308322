#!/usr/bin/env python3
"""bench/pgp_pins.py — pins for the lattice-pins experiment (docs/synthesis.md, "Lattice pins").

Usage: bench/pgp_pins.py ORACLE_DIR RESULT_DIR BOUND OUT.pins [CLEAN_ITERATIONS]
  ORACLE_DIR  bench/pgp_oracle.py's output (its facemaps.exr holds the phase's sources)
  RESULT_DIR  the synth result the oracle was made from (geometry.exr, report.json)
  BOUND       largest deviation of the local map's singular values from 1 (e.g. 0.10)
Writes the oracle's sources where its local map is within BOUND (the mask opened and closed
on the tile image), NaN elsewhere, as F x N x N x 2 little-endian f32 (face, row, column):
the SURFSYNTH_PINS file of bench/lattice_pins.patch. Uniform N only. Not part of CI.
"""
import sys, json, numpy as np, OpenEXR
from scipy.spatial import cKDTree
from scipy import ndimage
pgp, dflt, b, out = sys.argv[1], sys.argv[2], float(sys.argv[3]), sys.argv[4]
rep = json.load(open(dflt + '/report.json')); N = rep['resolution']; F = rep['faces']; S = rep['scale']
G = OpenEXR.File(f'{dflt}/geometry.exr').channels()
P = np.stack([G[c].pixels for c in ('P.X','P.Y','P.Z')], -1).astype(np.float64)
Nn = np.stack([G[c].pixels for c in ('N.X','N.Y','N.Z')], -1).astype(np.float64)
H, W = P.shape[:2]
valid = np.isfinite(P).all(-1) & (np.abs(P).sum(-1) > 0)
idx = np.flatnonzero(valid.ravel())
p = P.reshape(-1,3)[idx]/S; n = Nn.reshape(-1,3)[idx]
Fp = OpenEXR.File(f'{pgp}/facemaps.exr').channels()
su = np.asarray(Fp['source.u'].pixels, np.float32); sv = np.asarray(Fp['source.v'].pixels, np.float32)
s = np.stack([su.ravel()[idx], sv.ravel()[idx]], 1).astype(np.float64)
tree = cKDTree(p); d, nb = tree.query(p, 9)
e1 = np.cross(n, [0.3, 0.5, 0.7]); e1 /= np.linalg.norm(e1, axis=1, keepdims=True); e2 = np.cross(n, e1)
D = p[nb[:, 1:]] - p[:, None, :]
Q = np.stack([(D*e1[:, None]).sum(-1), (D*e2[:, None]).sum(-1)], -1)
Y = s[nb[:, 1:]] - s[:, None, :]
ok = (np.linalg.norm(Y, axis=-1) < 6).astype(float)[..., None]
A = np.einsum('mki,mkj->mij', Q*ok, Q); B = np.einsum('mki,mkj->mij', Q*ok, Y)
J = np.linalg.solve(A + 1e-9*np.eye(2), B)
sv_ = np.linalg.svd(J, compute_uv=False)
good = (sv_[:, 1] > 1-b) & (sv_[:, 0] < 1+b) & (ok[..., 0].sum(1) >= 5)
print('within +-%.2f: %.1f%%' % (b, 100*good.mean()))
M = np.zeros(H*W, bool); M[idx] = good; M = M.reshape(H, W)
it = int(sys.argv[5]) if len(sys.argv) > 5 else 2
M = ndimage.binary_opening(M, iterations=it); M = ndimage.binary_closing(M, iterations=it)
M &= valid
print('after cleaning %.1f%%' % (100*M.ravel()[idx].mean()))
C = int(np.ceil(np.sqrt(F)))
o = np.full((F, N, N, 2), np.nan, np.float32)
for f in range(F):
    r, c = divmod(f, C)
    m = M[r*N:(r+1)*N, c*N:(c+1)*N]
    o[f, :, :, 0] = np.where(m, su[r*N:(r+1)*N, c*N:(c+1)*N], np.nan)
    o[f, :, :, 1] = np.where(m, sv[r*N:(r+1)*N, c*N:(c+1)*N], np.nan)
o.astype('<f4').tofile(out)
