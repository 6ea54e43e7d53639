"""Circulant embedding of the field covariance: exact Gaussian samples on the field
cells from white noise by one rfft2/irfft2 pair; the dense Cholesky check for tests."""
from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np
import scipy.fft as sfft

from fem_rmpm.random_field.memory import bytes_cached
from fem_rmpm.random_field.model import MarkovModel
from fem_rmpm.random_field.quadrature import lattice_covariance

__all__ = ["Embedding", "SingleVariable", "circulant_embedding", "dense_covariance",
           "sample_dense"]


@dataclass(frozen=True, eq=False)
class Embedding:
    """Circulant embedding of the field covariance on a periodic ``m1 x m2`` lattice.

    Arrays are indexed ``[j, i]`` (y, x) so ``ravel()`` gives the grid's cell order.
    """
    model: MarkovModel
    cell: tuple[float, float]
    shape: tuple[int, int]              # (n1, n2) field cells along x, y
    padded: tuple[int, int]             # (m1, m2)
    averaging: bool
    table: np.ndarray                   # (m2, m1) covariance at wrapped lags
    eig: np.ndarray                     # (m2, m1 // 2 + 1) eigenvalues (rfft2 of table)
    sqrt_eig: np.ndarray                # sqrt of the clipped eigenvalues
    lambda_min: float                   # smallest eigenvalue before clipping
    lambda_max: float
    clipped: float                      # sum |negative eigenvalues| / sum eigenvalues (0: exact)
    attempts: int                       # padding attempts needed
    setup_seconds: float

    @property
    def variance(self) -> float:
        """Variance of a cell value (1, or gamma(T1, T2) with local averaging)."""
        return float(self.table[0, 0])

    def covariance(self, dk, dl) -> np.ndarray:
        """C at integer lags inside the field (``|dk| < n1``, ``|dl| < n2``) from the table."""
        m1, m2 = self.padded
        return self.table[np.asarray(dl) % m2, np.asarray(dk) % m1]

    def white_noise(self, seed) -> np.ndarray:
        m1, m2 = self.padded
        return np.random.default_rng(seed).standard_normal((m2, m1))

    def sample(self, seed) -> np.ndarray:
        """One realization (n2, n1) of the standard Gaussian field from ``seed`` alone."""
        return self.from_noise(self.white_noise(seed))

    def from_noise(self, eps: np.ndarray) -> np.ndarray:
        m1, m2 = self.padded
        n1, n2 = self.shape
        z = sfft.irfft2(self.sqrt_eig * sfft.rfft2(eps), s=(m2, m1))
        return np.ascontiguousarray(z[:n2, :n1])

    def convolve(self, weights: np.ndarray) -> np.ndarray:
        """``sum_d C(x - x_d) w_d`` for a weight array (n2, n1) on the field (exact lags)."""
        m1, m2 = self.padded
        n1, n2 = self.shape
        W = np.zeros((m2, m1))
        W[:n2, :n1] = weights
        return sfft.irfft2(self.eig * sfft.rfft2(W), s=(m2, m1))[:n2, :n1]

    def implied_covariance(self) -> np.ndarray:
        """(m2, m1) covariance table of the generated field (inverse FFT of the used spectrum)."""
        m1, m2 = self.padded
        return sfft.irfft2(self.sqrt_eig ** 2, s=(m2, m1))


@dataclass(frozen=True, eq=False)
class SingleVariable:
    """The perfectly correlated limit: one standard normal variable on every field cell.

    Used when the correlation between the two farthest field cells is at least
    ``1 - 2 r_max`` with ``r_max = 0.01`` (e.g. theta = 1e4 m on a 65 m x 20 m slope; the
    circulant embedding of such a field is not non-negative definite).  The field it
    replaces differs from a constant by less than ``sqrt(4 r_max) = 0.2`` of its standard
    deviation anywhere.  Same interface as :class:`Embedding` for sampling."""
    shape: tuple[int, int]
    padded: tuple[int, int] = (1, 1)
    variance: float = 1.0
    lambda_min: float = 1.0
    lambda_max: float = 1.0
    clipped: float = 0.0
    R_MAX = 0.01

    def white_noise(self, seed) -> np.ndarray:
        return np.random.default_rng(seed).standard_normal((self.padded[1], self.padded[0]))

    def from_noise(self, eps: np.ndarray) -> np.ndarray:
        n1, n2 = self.shape
        return np.full((n2, n1), float(np.asarray(eps).ravel()[0]))

    def sample(self, seed) -> np.ndarray:
        return self.from_noise(self.white_noise(seed))


def _wrapped_lags(m: int) -> np.ndarray:
    k = np.arange(m)
    return np.where(k > m // 2, k - m, k)


def _table(model, cell, m1, m2, averaging) -> np.ndarray:
    """Symmetric covariance table on the periodic lattice (lags wrapped, Nyquist averaged)."""
    k, l = _wrapped_lags(m1), _wrapped_lags(m2)
    # compute the rows 0 <= l <= m2/2, the others by symmetry C(k, l) = C(-k, -l)
    lh = np.arange(m2 // 2 + 1)
    KK, LL = np.meshgrid(k, lh)
    half = lattice_covariance(model, cell, KK, LL, averaging)
    tab = np.empty((m2, m1))
    tab[:m2 // 2 + 1] = half
    # C(k, -l) = C(-k, l)
    neg = -l[m2 // 2 + 1:]                               # positive lags of the rows l < 0
    tab[m2 // 2 + 1:] = half[neg][:, (-np.arange(m1)) % m1]
    if m1 % 2 == 0:   # lag m1/2 stands for +m1/2 and -m1/2: average the two
        col = m1 // 2
        tab[:, col] = 0.5 * (tab[:, col] + tab[(-np.arange(m2)) % m2, col])
    if m2 % 2 == 0:
        row = m2 // 2
        tab[row, :] = 0.5 * (tab[row, :] + tab[row, (-np.arange(m1)) % m1])
    return tab


@bytes_cached
def _embedding_cached(mkey, cell, shape, averaging, pad_thetas,
                      min_padded=(0, 0)) -> Embedding:
    t0 = time.perf_counter()
    model = MarkovModel(*mkey)
    n1, n2 = shape
    ext = model.extent()
    pads = [min(int(math.ceil(pad_thetas * ext[a] / cell[a])), 2 * shape[a] + 64) for a in (0, 1)]
    for attempt in range(1, 7):
        m1 = sfft.next_fast_len(max(2 * (n1 - 1) + pads[0], 2, min_padded[0]), real=True)
        m2 = sfft.next_fast_len(max(2 * (n2 - 1) + pads[1], 2, min_padded[1]), real=True)
        tab = _table(model, cell, m1, m2, averaging)
        eig = sfft.rfft2(tab).real
        lmin, lmax = float(eig.min()), float(eig.max())
        if lmin >= -1e-10 * lmax:
            break
        pads = [2 * p + 8 for p in pads]
    if not lmax > 0:             # every eigenvalue 0 (or NaN): no variance left to sample
        raise ValueError(f"theta_v {model.theta_v:g} m, theta_h {model.theta_h:g} m are so far "
                         f"below the field cells ({cell[0]:g} x {cell[1]:g} m) that the cell "
                         "averages keep no variance (the covariance underflows to 0); allowed: "
                         "scales of at least ~1/1000 of the field cell")
    neg = -eig[eig < 0].sum()
    clipped = float(neg / np.abs(eig).sum())
    if lmin < -1e-10 * lmax and clipped > 1e-6:
        raise ValueError(f"circulant embedding of {n1} x {n2} cells is not non-negative "
                         f"definite even with padding to {m1} x {m2} (lambda_min/lambda_max = "
                         f"{lmin / lmax:.2e}); allowed: smaller theta relative to the field cells "
                         "or a finer cell_size")
    eigc = np.maximum(eig, 0.0)
    for a in (tab, eig):
        a.setflags(write=False)
    sq = np.sqrt(eigc)
    sq.setflags(write=False)
    return Embedding(model=model, cell=cell, shape=shape, padded=(m1, m2), averaging=averaging,
                     table=tab, eig=eig, sqrt_eig=sq, lambda_min=lmin, lambda_max=lmax,
                     clipped=clipped if lmin < 0 else 0.0, attempts=attempt,
                     setup_seconds=time.perf_counter() - t0)


def circulant_embedding(model: MarkovModel, cell, shape, averaging: bool = True,
                        pad_thetas: float = 2.0, min_padded=(0, 0)) -> Embedding:
    """The (cached) embedding of a field of ``shape = (n1, n2)`` cells of size ``cell`` (m);
    a :class:`SingleVariable` when the field is perfectly correlated across its extent.
    ``min_padded``: the smallest periodic lattice ``(m1, m2)`` (several properties share
    one, so that their noises can be mixed)."""
    cell = (float(cell[0]), float(cell[1]))
    shape = (int(shape[0]), int(shape[1]))
    if min(shape) < 1 or min(cell) <= 0:
        raise ValueError(f"field needs >= 1 cell of positive size, got {shape}, {cell}")
    ext = np.array([shape[0] * cell[0], shape[1] * cell[1]])
    if float(np.max(model.scaled_norm(np.array([ext[0], ext[0]]), np.array([ext[1], -ext[1]])))) \
            <= SingleVariable.R_MAX:
        return SingleVariable(shape, padded=(max(min_padded[0], 1), max(min_padded[1], 1)))
    return _embedding_cached(model.key(), cell, shape, bool(averaging), float(pad_thetas),
                             (int(min_padded[0]), int(min_padded[1])))



def dense_covariance(model: MarkovModel, cell, shape, averaging: bool = True) -> np.ndarray:
    """Full (N, N) covariance of the N = n1 n2 field cells (small grids; order j * n1 + i)."""
    n1, n2 = shape
    i, j = np.meshgrid(np.arange(n1), np.arange(n2))
    i, j = i.ravel(), j.ravel()
    dk = i[:, None] - i[None, :]
    dl = j[:, None] - j[None, :]
    uk, inv = np.unique(np.stack([dk.ravel(), dl.ravel()], 1), axis=0, return_inverse=True)
    vals = lattice_covariance(model, cell, uk[:, 0], uk[:, 1], averaging)
    return vals[inv.ravel()].reshape(dk.shape)


def sample_dense(cov: np.ndarray, rng: np.random.Generator, size: int) -> np.ndarray:
    """``size`` realizations (size, N) by Cholesky factorisation of ``cov``."""
    Lc = np.linalg.cholesky(cov)
    return rng.standard_normal((size, len(cov))) @ Lc.T

