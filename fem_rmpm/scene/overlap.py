"""Do two simple polygons share area?  (Touching along an edge or at a point is fine.)

Slab decomposition: the x-coordinates of both polygons' vertices and of the crossings of
an edge of one with an edge of the other cut the plane into vertical slabs in which no
edge starts, ends or crosses another.  Within a slab the length of the overlap of the two
polygons along a vertical line is then linear in x, so the overlap has positive area in
that slab exactly when it has positive length on the slab's middle line.  The middle of
that overlap is a point inside both polygons (the witness a message can name).
"""
from __future__ import annotations

import numpy as np

__all__ = ["overlap_point"]


def _edges(poly: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return poly, np.roll(poly, -1, axis=0)


def _crossing_xs(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """x-coordinates (m) where an edge of ``p`` crosses an edge of ``q`` (proper
    crossings of non-parallel edges)."""
    a, b = _edges(p)
    c, d = _edges(q)
    xs = []
    for i in range(len(a)):                       # one edge of p against all edges of q
        r, s = b[i] - a[i], d - c
        den = r[0] * s[:, 1] - r[1] * s[:, 0]
        ok = np.abs(den) > 0
        w = c - a[i]
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (w[:, 0] * s[:, 1] - w[:, 1] * s[:, 0]) / den
            u = (w[:, 0] * r[1] - w[:, 1] * r[0]) / den
        hit = ok & (t > 0) & (t < 1) & (u > 0) & (u < 1)
        xs.append(a[i][0] + t[hit] * r[0])
    return np.concatenate(xs) if xs else np.empty(0)


def _intervals(poly: np.ndarray, x: float) -> np.ndarray:
    """The intervals ``[[y0, y1], ...]`` (m) of the vertical line at ``x`` inside ``poly``
    (``x`` is not a vertex's x-coordinate, so every crossing is a proper one)."""
    a, b = _edges(poly)
    span = (np.minimum(a[:, 0], b[:, 0]) < x) & (x < np.maximum(a[:, 0], b[:, 0]))
    a, b = a[span], b[span]
    y = np.sort(a[:, 1] + (x - a[:, 0]) * (b[:, 1] - a[:, 1]) / (b[:, 0] - a[:, 0]))
    return y.reshape(-1, 2)


def overlap_point(p, q) -> tuple[float, float] | None:
    """A point (x, y) in m inside both simple polygons ``p`` and ``q`` (``[(x, y), ...]``,
    m) where they overlap with positive area, or None when they do not (disjoint, or
    touching along edges or at points only)."""
    p, q = np.asarray(p, dtype=float), np.asarray(q, dtype=float)
    lo, hi = np.maximum(p.min(axis=0), q.min(axis=0)), np.minimum(p.max(axis=0), q.max(axis=0))
    if np.any(lo >= hi):                          # bounding boxes share no area
        return None
    xs = np.concatenate([p[:, 0], q[:, 0], _crossing_xs(p, q)])
    xs = np.unique(xs[(xs >= lo[0]) & (xs <= hi[0])])
    scale = float(max(np.ptp(p, axis=0).max(), np.ptp(q, axis=0).max()))
    for x0, x1 in zip(xs[:-1], xs[1:]):
        if x1 - x0 <= 1e-12 * scale:
            continue
        x = 0.5 * (x0 + x1)
        ip, iq = _intervals(p, x), _intervals(q, x)
        y0 = np.maximum(ip[:, None, 0], iq[None, :, 0])
        y1 = np.minimum(ip[:, None, 1], iq[None, :, 1])
        gap = y1 - y0
        if gap.size and gap.max() > 1e-9 * scale:
            k = np.unravel_index(np.argmax(gap), gap.shape)
            return float(x), float(0.5 * (y0[k] + y1[k]))
    return None
