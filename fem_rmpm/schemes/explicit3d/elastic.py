"""Compiled three-dimensional linear elastic stress update: small strain (the geostatic
phase) and the finite-strain Hencky update with a 3x3 spectral log / exp.

Tensors are six components ``[xx, yy, zz, xy, yz, xz]`` (the VTK order of the point
files); strains hold tensor (not engineering) shear components.  The finite-strain
update (Simo 1992, the 3-D form of :mod:`fem_rmpm.materials.hencky`): trial elastic left
Cauchy-Green ``b = dF exp(2 eps) dF^T``, new elastic log strain ``eps = log(b) / 2``,
Kirchhoff stress ``tau = lam tr(eps) I + 2 mu eps`` (kPa).  The spectral functions use a
cyclic Jacobi eigen-solver of the symmetric 3x3 matrix (robust for repeated eigenvalues,
as at rest, where closed forms lose their eigenvectors), to round-off (``tests/test_3d_elastic.py``
checks it against ``numpy.linalg.eigh`` and the step against a uniaxial closed form).
"""
from __future__ import annotations

import math

import numpy as np

from fem_rmpm.runtime.compiled import inline, jit

__all__ = ["sym_eig3", "hencky_elastic_3d", "small_strain_elastic_3d", "spectral_3d"]

_SWEEPS = 30


@inline
def sym_eig3(A, w, Q):
    """Eigenvalues ``w`` (3,) and eigenvectors (columns of ``Q`` (3, 3)) of the symmetric
    ``A`` (3, 3), overwritten (cyclic Jacobi rotations until the off-diagonal part is below
    1e-15 of the norm)."""
    for i in range(3):
        for j in range(3):
            Q[i, j] = 1.0 if i == j else 0.0
    norm = 0.0
    for i in range(3):
        for j in range(3):
            norm += A[i, j] * A[i, j]
    for _ in range(_SWEEPS):
        off = A[0, 1] * A[0, 1] + A[0, 2] * A[0, 2] + A[1, 2] * A[1, 2]
        if off <= 1e-30 * norm or off == 0.0:
            break
        for p, q in ((0, 1), (0, 2), (1, 2)):
            if A[p, q] == 0.0:
                continue
            theta = (A[q, q] - A[p, p]) / (2.0 * A[p, q])
            t = (1.0 if theta >= 0 else -1.0) / (abs(theta) + math.sqrt(theta * theta + 1.0))
            c = 1.0 / math.sqrt(t * t + 1.0)
            s = t * c
            for k in range(3):              # A <- A J (columns p, q)
                akp, akq = A[k, p], A[k, q]
                A[k, p] = c * akp - s * akq
                A[k, q] = s * akp + c * akq
            for k in range(3):              # A <- J^T A (rows p, q)
                apk, aqk = A[p, k], A[q, k]
                A[p, k] = c * apk - s * aqk
                A[q, k] = s * apk + c * aqk
            for k in range(3):              # Q <- Q J
                qkp, qkq = Q[k, p], Q[k, q]
                Q[k, p] = c * qkp - s * qkq
                Q[k, q] = s * qkp + c * qkq
    for i in range(3):
        w[i] = A[i, i]


@inline
def _compose(Q, f, out6):
    """``out6`` = the six components of Q diag(f) Q^T."""
    for m, (i, j) in enumerate(((0, 0), (1, 1), (2, 2), (0, 1), (1, 2), (0, 2))):
        out6[m] = Q[i, 0] * f[0] * Q[j, 0] + Q[i, 1] * f[1] * Q[j, 1] + Q[i, 2] * f[2] * Q[j, 2]


@inline
def _full(v6, A):
    A[0, 0], A[1, 1], A[2, 2] = v6[0], v6[1], v6[2]
    A[0, 1] = A[1, 0] = v6[3]
    A[1, 2] = A[2, 1] = v6[4]
    A[0, 2] = A[2, 0] = v6[5]


@inline
def _elastic_tau(eps, lam, mu, tau):
    tr = eps[0] + eps[1] + eps[2]
    for m in range(6):
        tau[m] = 2.0 * mu * eps[m] + (lam * tr if m < 3 else 0.0)


@inline
def small_strain_elastic_3d(L, dt, eps, lam, mu, tau):
    """Geostatic step: ``eps += sym(L) dt`` (L (3, 3) 1/s), ``tau`` (6,) kPa."""
    eps[0] += L[0, 0] * dt
    eps[1] += L[1, 1] * dt
    eps[2] += L[2, 2] * dt
    eps[3] += 0.5 * (L[0, 1] + L[1, 0]) * dt
    eps[4] += 0.5 * (L[1, 2] + L[2, 1]) * dt
    eps[5] += 0.5 * (L[0, 2] + L[2, 0]) * dt
    _elastic_tau(eps, lam, mu, tau)


@inline
def hencky_elastic_3d(dF, eps, lam, mu, tau, A, B, Q, w, f):
    """Finite-strain step from the increment ``dF`` (3, 3): ``eps`` (6,) updated, ``tau``
    (6,) kPa; ``A``, ``B``, ``Q`` (3, 3), ``w``, ``f`` (3,) scratch."""
    _full(eps, A)
    sym_eig3(A, w, Q)
    for k in range(3):
        f[k] = math.exp(2.0 * w[k])
    for i in range(3):                       # A = exp(2 eps) = Q diag(f) Q^T
        for j in range(3):
            A[i, j] = Q[i, 0] * f[0] * Q[j, 0] + Q[i, 1] * f[1] * Q[j, 1] \
                + Q[i, 2] * f[2] * Q[j, 2]
    for i in range(3):                       # B = dF A
        for j in range(3):
            B[i, j] = dF[i, 0] * A[0, j] + dF[i, 1] * A[1, j] + dF[i, 2] * A[2, j]
    for i in range(3):                       # A = B dF^T (the trial b, symmetric)
        for j in range(i, 3):
            A[i, j] = B[i, 0] * dF[j, 0] + B[i, 1] * dF[j, 1] + B[i, 2] * dF[j, 2]
            A[j, i] = A[i, j]
    sym_eig3(A, w, Q)
    for k in range(3):
        f[k] = 0.5 * math.log(w[k])
    _compose(Q, f, eps)
    _elastic_tau(eps, lam, mu, tau)


@jit
def spectral_3d(v6: np.ndarray, kind: int) -> np.ndarray:
    """Test hook: eigenvalues (kind 0), or the six components of exp (1) / log (2) of the
    symmetric tensor ``v6`` (6,)."""
    A, Q, w, f = np.empty((3, 3)), np.empty((3, 3)), np.empty(3), np.empty(3)
    _full(v6, A)
    sym_eig3(A, w, Q)
    if kind == 0:
        return w.copy()
    for k in range(3):
        f[k] = math.exp(w[k]) if kind == 1 else math.log(w[k])
    out = np.empty(6)
    _compose(Q, f, out)
    return out
