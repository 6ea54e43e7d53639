"""Geometry of the deposit and of the failure: surface profile, crest, slip surface, moved
area.  Pure functions of point arrays (grid or true frame as each says; m, m2/m)."""
from __future__ import annotations

import numpy as np

from fem_rmpm.discretise.points import Particles

__all__ = ["surface_profile", "crest_position", "slip_surface_height", "moved_area"]


def surface_profile(X: np.ndarray, bin_width: float) -> list[tuple[float, float]]:
    """Surface as (x bin centre, max y) pairs of points X (n, 2) in the true frame."""
    if len(X) == 0:
        return []
    k = np.floor(X[:, 0] / bin_width).astype(np.int64)
    order = np.argsort(k)
    k, y = k[order], X[order, 1]
    starts = np.r_[0, np.nonzero(np.diff(k))[0] + 1]
    tops = np.maximum.reduceat(y, starts)
    return [((float(kk) + 0.5) * bin_width, float(t)) for kk, t in zip(k[starts], tops)]


def crest_position(pts: Particles, cell_height: float) -> np.ndarray:
    """Initial grid-frame position of the crest: the most down-slope top-layer point."""
    top = pts.x0[:, 1] > pts.x0[:, 1].max() - cell_height
    i = np.nonzero(top)[0][np.argmax(pts.x0[top, 0])]
    return pts.x0[i]


def slip_surface_height(x0: np.ndarray, sliding: np.ndarray, cell_width: float) -> float:
    """Mean height (grid y) of the failure surface over the columns that slid (m)."""
    cols = np.floor(x0[:, 0] / cell_width).astype(np.int64)
    heights = []
    for c in np.unique(cols[sliding]):
        in_col = cols == c
        lowest_sliding = x0[in_col & sliding, 1].min()
        stayed_below = in_col & ~sliding & (x0[:, 1] < lowest_sliding)
        heights.append(x0[stayed_below, 1].max() if stayed_below.any() else 0.0)
    return float(np.mean(heights)) if heights else 0.0


def moved_area(x: np.ndarray, x0: np.ndarray, volume0: np.ndarray, active: np.ndarray,
               threshold: float) -> float:
    """Initial volume (m2/m) of the active points that have moved more than
    ``threshold`` (m) from ``x0``; ``x``, ``x0`` (n, 2) m, ``volume0`` (n,), ``active`` (n,)
    bool.  The early sliding area at the mechanism time, and the area that decides a
    failure in a campaign's runs stopped once decided."""
    moved = (np.linalg.norm(x - x0, axis=1) > threshold) & active
    return float(volume0[moved].sum())
