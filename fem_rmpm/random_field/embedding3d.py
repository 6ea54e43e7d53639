"""Circulant embedding of a 3-D field covariance: exact Gaussian samples on a lattice of
hexahedral field cells by one rfftn/irfftn pair, with the memory estimated before
anything is allocated.

The covariance at the wrapped lags of a periodic ``m1 x m2 x m3`` lattice
(``m >= 2 (n - 1) + padding`` per axis, padding two correlation lengths capped at
``2 n + 64`` cells, doubled while an eigenvalue is negative, as in 2-D) is tabulated plane
by plane (``z`` lags ``0 .. m3/2``; the rest by the symmetries ``C(K, L, M) = C(-K, -L, M)
= C(K, L, -M)`` of a layering turned about the strike axis; Nyquist planes averaged), its
eigenvalues are its rfftn, and a realization is ``irfftn(sqrt(lambda) rfftn(eps))`` on the
first ``n1 x n2 x n3`` points (Dietrich & Newsam 1997).  Only ``sqrt(lambda)`` is kept
(``m1 m2 (m3/2 + 1)`` float64, about 4 B per lattice point).

Memory (:func:`estimate_embedding_3d`, B, ``P = m1 m2 m3`` lattice points, ``H = m1 m2
(m3/2 + 1)``): set-up ``8 P + 24 H`` (table, complex spectrum, eigenvalues, about
``20 P``) + one plane of quadrature work arrays; sampling ``16 P + 16 H`` (noise, spectrum
multiplied in place, inverse; about ``24 P``) + the kept ``8 H``; the peak is the larger.
Measured with ``tracemalloc`` on 135 x 72 x 96 (0.93 M points): set-up 20.6 MiB
(estimate 19.2), sampling with the kept array 25.3 MiB (estimate 25.7).  The estimate is
for the first padding; a field needing more padding (``attempts > 1``) takes more.  The estimate is
compared with the ``tracemalloc`` peak in ``tests/test_random_field_3d.py``.
"""
from __future__ import annotations

import math
import sys
import time
from dataclasses import dataclass

import numpy as np
import scipy.fft as sfft

from fem_rmpm.random_field.memory import bytes_cached
from fem_rmpm.random_field.model3d import MarkovModel3D
from fem_rmpm.random_field.quadrature3d import lattice_covariance_3d
from fem_rmpm.runtime.budget import BudgetError, memory_limit_bytes

__all__ = ["Embedding3D", "SingleVariable3D", "EmbeddingEstimate", "FieldTooLarge",
           "circulant_embedding_3d", "estimate_embedding_3d", "padded_shape_3d", "REPORT_BYTES"]

#: Estimates above this many bytes are printed (stderr) before the embedding is set up.
REPORT_BYTES = 256 * 2**20
#: Work arrays of one plane of lags in the covariance quadrature (float64 each).
QUADRATURE_ARRAYS = 32


class FieldTooLarge(BudgetError, MemoryError):
    """The field's embedding would exceed the memory limit (one line with the estimate);
    a :class:`~fem_rmpm.runtime.budget.BudgetError` (a scene error: exit 2 on the command
    line) and a ``MemoryError``."""


@dataclass(frozen=True)
class EmbeddingEstimate:
    """Memory of a 3-D embedding (B) before it is set up."""
    shape: tuple[int, int, int]
    padded: tuple[int, int, int]
    setup_bytes: float
    sample_bytes: float
    kept_bytes: float

    @property
    def peak_bytes(self) -> float:
        """Set-up (its eigenvalues become the kept array) or sampling with the kept array."""
        return max(self.setup_bytes, self.sample_bytes + self.kept_bytes)

    def describe(self) -> str:
        m = " x ".join(str(v) for v in self.padded)
        n = " x ".join(str(v) for v in self.shape)
        return (f"3-D random field of {n} cells: circulant embedding on a {m} lattice "
                f"({math.prod(self.padded):,} points), estimated peak memory "
                f"{_fmt(self.peak_bytes)} ({_fmt(self.kept_bytes)} kept per configuration)")


def _fmt(b: float) -> str:
    for unit, f in (("TiB", 2**40), ("GiB", 2**30), ("MiB", 2**20)):
        if b >= f:
            return f"{b / f:.3g} {unit}"
    return f"{b / 2**10:.3g} KiB"


def padded_shape_3d(model: MarkovModel3D, cell, shape, pad_thetas: float = 2.0,
                    attempt: int = 1, min_padded=(0, 0, 0)) -> tuple[int, int, int]:
    """The periodic lattice of padding attempt ``attempt`` (1: two correlation lengths)."""
    ext = model.extent()
    pads = [min(int(math.ceil(pad_thetas * ext[a] / cell[a])), 2 * shape[a] + 64)
            for a in range(3)]
    for _ in range(attempt - 1):
        pads = [2 * p + 8 for p in pads]
    return tuple(int(sfft.next_fast_len(max(2 * (shape[a] - 1) + pads[a], 2, min_padded[a]),
                                        real=True)) for a in range(3))


def estimate_embedding_3d(model: MarkovModel3D, cell, shape, pad_thetas: float = 2.0,
                          min_padded=(0, 0, 0)) -> EmbeddingEstimate:
    """Memory of the embedding at its first padding (arithmetic only, microseconds)."""
    m = padded_shape_3d(model, cell, shape, pad_thetas, 1, min_padded)
    P = float(math.prod(m))
    half = float(m[0] * m[1] * (m[2] // 2 + 1))
    kept = 8.0 * half
    plane = 8.0 * QUADRATURE_ARRAYS * m[0] * (m[1] // 2 + 1)
    setup = 8.0 * P + 16.0 * half + 8.0 * half + plane       # table, spectrum, eigenvalues
    sample = 8.0 * P + 16.0 * half + 8.0 * P + 8.0 * math.prod(shape)   # noise, spectrum, out
    return EmbeddingEstimate(tuple(int(s) for s in shape), m, setup, sample, kept)


@dataclass(frozen=True, eq=False)
class Embedding3D:
    """Circulant embedding on a periodic ``m1 x m2 x m3`` lattice; arrays indexed
    ``[i, j, k]`` (x, y, z)."""
    model: MarkovModel3D
    cell: tuple[float, float, float]
    shape: tuple[int, int, int]         # (n1, n2, n3) field cells along x, y, z
    padded: tuple[int, int, int]        # (m1, m2, m3)
    averaging: bool
    sqrt_eig: np.ndarray                # (m1, m2, m3 // 2 + 1) sqrt of the clipped eigenvalues
    variance: float                     # C(0): 1, or the variance function with averaging
    lambda_min: float
    lambda_max: float
    clipped: float                      # sum |negative eigenvalues| / sum |eigenvalues|
    attempts: int
    setup_seconds: float

    def covariance(self, dk, dl, dm) -> np.ndarray:
        """C at integer lags (exact, from the quadrature)."""
        return lattice_covariance_3d(self.model, self.cell, dk, dl, dm, self.averaging)

    def white_noise(self, seed) -> np.ndarray:
        return np.random.default_rng(seed).standard_normal(self.padded)

    def sample(self, seed) -> np.ndarray:
        """One realization (n1, n2, n3) of the standard Gaussian field from ``seed``."""
        return self.from_noise(self.white_noise(seed))

    def from_noise(self, eps: np.ndarray) -> np.ndarray:
        n1, n2, n3 = self.shape
        spec = sfft.rfftn(eps)
        spec *= self.sqrt_eig
        z = sfft.irfftn(spec, s=self.padded)
        del spec
        return np.ascontiguousarray(z[:n1, :n2, :n3])

    def convolve(self, weights: np.ndarray) -> np.ndarray:
        """``sum_d C(x - x_d) w_d`` for weights (n1, n2, n3) on the field (exact lags)."""
        n1, n2, n3 = self.shape
        W = np.zeros(self.padded)
        W[:n1, :n2, :n3] = weights
        spec = sfft.rfftn(W)
        spec *= self.sqrt_eig ** 2
        return sfft.irfftn(spec, s=self.padded)[:n1, :n2, :n3]


@dataclass(frozen=True, eq=False)
class SingleVariable3D:
    """The perfectly correlated limit (as :class:`~.embedding.SingleVariable`): one
    standard normal on every cell, used when the correlation between the farthest cells is
    at least ``1 - 2 r_max``, ``r_max = 0.01``."""
    shape: tuple[int, int, int]
    padded: tuple[int, int, int] = (1, 1, 1)
    variance: float = 1.0
    lambda_min: float = 1.0
    lambda_max: float = 1.0
    clipped: float = 0.0
    R_MAX = 0.01

    def white_noise(self, seed) -> np.ndarray:
        return np.random.default_rng(seed).standard_normal(self.padded)

    def from_noise(self, eps: np.ndarray) -> np.ndarray:
        return np.full(self.shape, float(np.asarray(eps).ravel()[0]))

    def sample(self, seed) -> np.ndarray:
        return self.from_noise(self.white_noise(seed))


def _table_3d(model, cell, m, averaging) -> np.ndarray:
    """Symmetric covariance table (m1, m2, m3) at wrapped lags, Nyquist planes averaged."""
    m1, m2, m3 = m
    k = np.arange(m1)
    k = np.where(k > m1 // 2, k - m1, k).astype(float)
    lh = np.arange(m2 // 2 + 1, dtype=float)
    KK, LL = np.meshgrid(k, lh, indexing="ij")
    tab = np.empty(m)
    negk = (-np.arange(m1)) % m1
    for mz in range(m3 // 2 + 1):
        half = lattice_covariance_3d(model, cell, KK, LL, np.full(KK.shape, float(mz)),
                                     averaging)
        plane = tab[:, :, mz]
        plane[:, :m2 // 2 + 1] = half
        if m2 > m2 // 2 + 1:                 # rows l < 0: C(k, l) = C(-k, -l)
            neg = np.arange(m2 // 2 + 1, m2)
            plane[:, neg] = half[negk][:, m2 - neg]
        if m1 % 2 == 0:
            plane[m1 // 2, :] = 0.5 * (plane[m1 // 2, :] + plane[m1 // 2, (-np.arange(m2)) % m2])
        if m2 % 2 == 0:
            plane[:, m2 // 2] = 0.5 * (plane[:, m2 // 2] + plane[negk, m2 // 2])
        if 0 < mz and m3 - mz != mz:
            tab[:, :, m3 - mz] = plane
    return tab


@bytes_cached
def _embedding_3d_cached(mkey, cell, shape, averaging, pad_thetas, min_padded) -> Embedding3D:
    t0 = time.perf_counter()
    model = MarkovModel3D(*mkey)
    for attempt in range(1, 7):
        m = padded_shape_3d(model, cell, shape, pad_thetas, attempt, min_padded)
        tab = _table_3d(model, cell, m, averaging)
        variance = float(tab[0, 0, 0])
        spec = sfft.rfftn(tab)
        del tab
        eig = spec.real.copy()
        del spec
        lmin, lmax = float(eig.min()), float(eig.max())
        if lmin >= -1e-10 * lmax:
            break
    if not lmax > 0:
        raise ValueError(f"theta_v {model.theta_v:g} m, theta_h {model.theta_h:g} m, theta_z "
                         f"{model.theta_z:g} m are so far below the field cells "
                         f"({' x '.join(f'{c:g}' for c in cell)} m) that the cell averages keep "
                         "no variance; allowed: scales of at least ~1/1000 of the field cell")
    neg = -eig[eig < 0].sum()
    clipped = float(neg / np.abs(eig).sum())
    if lmin < -1e-10 * lmax and clipped > 1e-6:
        raise ValueError(f"circulant embedding of {' x '.join(map(str, shape))} cells is not "
                         f"non-negative definite even with padding to "
                         f"{' x '.join(map(str, m))} (lambda_min/lambda_max = "
                         f"{lmin / lmax:.2e}); allowed: smaller scales relative to the field "
                         "cells or a finer cell_size")
    np.maximum(eig, 0.0, out=eig)
    np.sqrt(eig, out=eig)
    eig.setflags(write=False)
    return Embedding3D(model=model, cell=cell, shape=shape, padded=m, averaging=averaging,
                       sqrt_eig=eig, variance=variance, lambda_min=lmin, lambda_max=lmax,
                       clipped=clipped if lmin < 0 else 0.0, attempts=attempt,
                       setup_seconds=time.perf_counter() - t0)


def circulant_embedding_3d(model: MarkovModel3D, cell, shape, averaging: bool = True,
                           pad_thetas: float = 2.0, min_padded=(0, 0, 0),
                           limit_bytes: float | None = None, report=None):
    """The (cached) embedding of a field of ``shape = (n1, n2, n3)`` cells of size ``cell``
    (m); a :class:`SingleVariable3D` when the field is perfectly correlated across it.

    The memory is estimated first (:func:`estimate_embedding_3d`): above ``limit_bytes``
    (default the memory limit, :func:`fem_rmpm.runtime.budget.memory_limit_bytes`)
    :class:`FieldTooLarge` carrying the estimate is raised at once; above
    :data:`REPORT_BYTES` the estimate is passed to ``report`` (default: a line on stderr)."""
    cell = tuple(float(c) for c in cell)
    shape = tuple(int(s) for s in shape)
    if len(cell) != 3 or len(shape) != 3 or min(shape) < 1 or min(cell) <= 0:
        raise ValueError(f"field needs >= 1 cell of positive size per axis, got {shape}, {cell}")
    ext = np.array(shape) * np.array(cell)
    corners = np.array([[ext[0], s1 * ext[1], s2 * ext[2]] for s1 in (1, -1) for s2 in (1, -1)])
    if float(np.max(model.scaled_norm(*corners.T))) <= SingleVariable3D.R_MAX:
        return SingleVariable3D(shape, padded=tuple(max(int(v), 1) for v in min_padded))
    est = estimate_embedding_3d(model, cell, shape, pad_thetas, min_padded)
    if limit_bytes is None:
        limit_bytes = memory_limit_bytes()
    if est.peak_bytes > limit_bytes:
        raise FieldTooLarge(f"[random_field.cell_size] {est.describe()}; this exceeds the "
                            f"memory limit of {_fmt(limit_bytes)}; allowed: a coarser "
                            "cell_size, a smaller box or a higher limit with "
                            "FEM_RMPM_MEMORY_LIMIT_GB=<GiB>")
    if est.peak_bytes > REPORT_BYTES:
        (report or (lambda s: print(s, file=sys.stderr, flush=True)))(est.describe())
    return _embedding_3d_cached(model.key(), cell, shape, bool(averaging), float(pad_thetas),
                                tuple(int(v) for v in min_padded))
