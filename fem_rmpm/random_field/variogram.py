"""Scales of fluctuation from data: empirical semivariograms along rows and columns and
a Cressie-weighted least-squares fit of the Markov semivariogram."""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from fem_rmpm.scene import SceneError

__all__ = ["empirical_variogram", "FitResult", "fit_scales"]


def _levels(c: np.ndarray) -> tuple[np.ndarray, float]:
    """Group coordinates into levels (rows/columns): gaps above half the typical spacing."""
    u = np.unique(c)
    if len(u) == 1:
        return np.zeros(len(c), dtype=np.int64), 0.0
    d = np.diff(u)
    tol = 0.5 * float(np.median(d))
    lev = np.concatenate([[0], np.cumsum(d > tol)])
    return lev[np.searchsorted(u, c)], tol


def empirical_variogram(x, y, v, axis: int, max_lag: float | None = None, min_pairs: int = 30,
                        group=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Semivariogram along ``axis`` (0: x, 1: y) from pairs on the same row (column).

    Rows (columns) are clusters of the other coordinate separated by more than
    half its median spacing.  ``group`` (optional labels): pairs only within a
    group (separate sites or realizations).  Returns (lag m, gamma, pair counts);
    lags binned at the median spacing along the axis, bins with fewer than
    ``min_pairs`` pairs and lags beyond ``max_lag`` (default half the extent) dropped.
    """
    x, y, v = (np.asarray(a, float) for a in (x, y, v))
    along, across = (x, y) if axis == 0 else (y, x)
    lev, _ = _levels(across)
    if group is not None:
        _, gid = np.unique(np.asarray(group), return_inverse=True)
        lev = gid.ravel().astype(np.int64) * (int(lev.max()) + 1) + lev
    order = np.lexsort((along, lev))
    a, vv, lv = along[order], v[order], lev[order]
    bounds = np.r_[0, np.nonzero(np.diff(lv))[0] + 1, len(lv)]
    steps = [np.diff(a[s:e]) for s, e in zip(bounds[:-1], bounds[1:]) if e - s > 1]
    steps = np.concatenate(steps) if steps else np.array([])
    steps = steps[steps > 0]
    if len(steps) == 0:
        return np.array([]), np.array([]), np.array([])
    width = float(np.median(steps))
    if max_lag is None:
        max_lag = 0.5 * float(a.max() - a.min())
    nb = int(max_lag / width + 0.5) + 1
    s2 = np.zeros(nb)
    cnt = np.zeros(nb)
    for s, e in zip(bounds[:-1], bounds[1:]):
        aa, va = a[s:e], vv[s:e]
        for off in range(0, len(aa), 2000):
            blk = slice(off, off + 2000)
            h = np.abs(aa[blk, None] - aa[None, :])
            dv = (va[blk, None] - va[None, :]) ** 2
            b = np.rint(h / width).astype(np.int64)
            keep = (b >= 1) & (b < nb)
            s2 += np.bincount(b[keep], weights=dv[keep], minlength=nb)
            cnt += np.bincount(b[keep], minlength=nb)
    s2, cnt = s2 / 2.0, cnt / 2.0          # each pair counted twice
    good = cnt >= min_pairs
    good[0] = False
    lags = np.arange(nb) * width
    return lags[good], s2[good] / (2.0 * cnt[good]), cnt[good]


@dataclass(frozen=True)
class FitResult:
    theta_v: float
    theta_h: float
    sill: float
    n_points: int
    lags_x: np.ndarray
    gamma_x: np.ndarray
    pairs_x: np.ndarray
    lags_y: np.ndarray
    gamma_y: np.ndarray
    pairs_y: np.ndarray
    log: bool

    @property
    def anisotropy(self) -> float:
        return self.theta_h / self.theta_v

    def as_dict(self) -> dict:
        return {"theta_v": self.theta_v, "theta_h": self.theta_h, "anisotropy": self.anisotropy,
                "sill": self.sill, "n_points": self.n_points, "log_transformed": self.log,
                "model": "gamma(h) = sill (1 - exp(-2 h / theta))",
                "variogram_x": {"lag": self.lags_x, "gamma": self.gamma_x, "pairs": self.pairs_x},
                "variogram_y": {"lag": self.lags_y, "gamma": self.gamma_y, "pairs": self.pairs_y}}


def fit_scales(x, y, v, log: bool = False, source: str = "<data>",
               max_lag: tuple[float | None, float | None] = (None, None),
               group=None) -> FitResult:
    """Estimate ``theta_v`` and ``theta_h`` (m) by fitting the Markov semivariogram.

    ``gamma(h) = s^2 (1 - exp(-2 h / theta))`` with a common sill ``s^2`` to the
    empirical semivariograms along x (theta_h) and y (theta_v), Cressie (1985)
    weights ``N(h) (gamma_hat / gamma - 1)^2``.  Data in the grid frame with the
    layering along x; ``log``: fit ``ln v`` (lognormal field); ``group``: labels of
    independent sites (pairs are formed within a group only).
    """
    v = np.asarray(v, float)
    if log:
        if np.any(v <= 0):
            raise SceneError(f"{source}: [fit] values must be > 0 for a lognormal field; "
                             "allowed: positive values")
        v = np.log(v)
    hx, gx, nx_ = empirical_variogram(x, y, v, 0, max_lag[0], group=group)
    hy, gy, ny_ = empirical_variogram(x, y, v, 1, max_lag[1], group=group)
    if len(hx) < 2 or len(hy) < 2:
        which = "x (points on common rows)" if len(hx) < 2 else "y (points on common columns)"
        raise SceneError(f"{source}: [fit] too few pairs along {which} for a variogram "
                         f"({len(v)} points); allowed: profiles or grids with >= 30 pairs at "
                         "several lags in both directions")
    var0 = float(np.var(v))

    def model(p, h):
        return np.exp(p[0]) * -np.expm1(-2.0 * h / np.exp(p[1]))

    def resid(p):
        r1 = np.sqrt(nx_) * (gx / model([p[0], p[1]], hx) - 1.0)
        r2 = np.sqrt(ny_) * (gy / model([p[0], p[2]], hy) - 1.0)
        return np.concatenate([r1, r2])

    p0 = [math.log(max(var0, 1e-300)), math.log(max(hx[len(hx) // 3], 1e-9)),
          math.log(max(hy[len(hy) // 3], 1e-9))]
    sol = least_squares(resid, p0, method="lm")
    s2, th, tv = (float(np.exp(q)) for q in sol.x)
    return FitResult(theta_v=tv, theta_h=th, sill=s2, n_points=len(v), lags_x=hx, gamma_x=gx,
                     pairs_x=nx_, lags_y=hy, gamma_y=gy, pairs_y=ny_, log=log)

