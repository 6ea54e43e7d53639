"""Several cross-correlated properties: one standard Gaussian field per property, the
white noises mixed by the Cholesky factor of the cross-correlation matrix.

With ``p`` properties, a realization's noise is ``eps`` of shape ``(p, m2, m1)``
(independent standard normals on the common periodic lattice of the properties'
circulant embeddings).  The noise of property ``k`` is ``eta_k = sum_j L_kj eps_j``
with ``R = L L^T`` the cross-correlation matrix (``numpy.linalg.cholesky``): ``eta``
is again white standard normal per property, with ``corr(eta_k, eta_l) = R_kl`` at
every lattice point.  Each property's field is its own embedding applied to its noise,
``Z_k = from_noise_k(eta_k)``, so each ``Z_k`` has *exactly* the covariance of its own
correlation structure (the single-property generator, unchanged), and the
cross-covariance is ``C_kl = R_kl irfft2(sqrt(lambda_k lambda_l))``.

* Shared structure (the same ``theta_v``, ``anisotropy``, correlation and layering for
  every property; the default): the embeddings are equal and the filter is linear, so
  ``Z = L G`` with ``G`` independent standard Gaussian fields -- exactly the same
  fields mixed by the Cholesky factor, with cross-correlation ``R_kl`` at every cell and
  ``R_kl rho(tau)`` at lag ``tau`` (the intrinsic coregionalization model).
* Own structures: each marginal field keeps its structure exactly; the point
  cross-correlation is ``R_kl c_kl`` with the coherence ``c_kl = sum sqrt(lambda_k
  lambda_l) / sqrt(sum lambda_k sum lambda_l) <= 1`` (Cauchy-Schwarz; 1 for equal
  structures), reported by :func:`coherence`.  A cross-correlation of exactly ``R`` with
  different structures is not always possible (``|R_kl| <= c_kl`` is necessary), so the
  generator keeps the structures and states the factor.

One property is the single-property generator itself: noise ``(m2, m1)``, no mixing, so
its fields are bitwise those of a scene without ``[[random_field.properties]]``.
"""
from __future__ import annotations

import numpy as np

from fem_rmpm.random_field.embedding import Embedding

__all__ = ["cholesky_factor", "mix_noise", "coherence"]


def cholesky_factor(R) -> np.ndarray:
    """Lower Cholesky factor ``L`` of the cross-correlation matrix (``R = L L^T``);
    the identity when ``R`` is empty (independent properties)."""
    R = np.asarray(R, dtype=float)
    return np.linalg.cholesky(R) if R.size else R


def mix_noise(L: np.ndarray, eps: np.ndarray) -> np.ndarray:
    """Noise per property ``eta_k = sum_j L_kj eps_j`` for ``eps`` (p, m2, m1)."""
    if L.size == 0:
        return eps
    return np.einsum("kj,jab->kab", L, eps)


def coherence(a: Embedding, b: Embedding) -> float:
    """Point cross-correlation of the fields of ``a`` and ``b`` per unit of ``R_kl``:
    ``sum sqrt(lambda_a lambda_b) / sqrt(sum lambda_a sum lambda_b)`` over the full
    spectrum of the common lattice (1 for equal embeddings)."""
    if not hasattr(a, "sqrt_eig") or not hasattr(b, "sqrt_eig"):
        return float("nan")
    m1 = a.padded[0]
    w = np.full(a.sqrt_eig.shape[1], 2.0)          # rfft2 half spectrum: double the interior
    w[0] = 1.0
    if m1 % 2 == 0:
        w[-1] = 1.0
    num = float(np.sum(w * a.sqrt_eig * b.sqrt_eig))
    den = float(np.sqrt(np.sum(w * a.sqrt_eig ** 2) * np.sum(w * b.sqrt_eig ** 2)))
    return num / den
