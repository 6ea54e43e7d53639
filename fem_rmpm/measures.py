"""Measures of a realization (DESIGN section 5), in the true (not grid) frame.

Definitions (``d_p`` = distance point p moved since the end of the geostatic
phase, ``X`` = true horizontal coordinate, pointing down-slope; threshold
``failure_displacement`` from ``[montecarlo]``, default 0.5 m):

* ``sliding_area`` (m2 per m): total initial volume of the points with ``d_p > threshold``.
* ``failed``: ``sliding_area > 0`` — at least one material point moved more than the threshold.
* ``runout_distance`` (m): ``max X`` of the points now minus ``max X`` at the start
  (how far the toe front travelled beyond the original toe), >= 0.
* ``retrogression_distance`` (m): ``X_crest - min X0`` over the sliding points,
  where ``X_crest`` is the initial true-horizontal position of the slope crest
  (the most down-slope point of the top soil layer in the grid frame), >= 0: how
  far behind the original crest the failure reached.
* ``time_to_rest`` (s): simulated time at which the run stopped at rest (None otherwise).
* ``slip_surface_height`` (m): how high above the base (grid y, normal to the
  bedrock) the failure surface lies, averaged over the failed part of the slope:
  per column of one cell (initial x), the highest initial y of a point that stayed
  (``d_p <= threshold``) below the lowest sliding point; 0 where the whole column slid.
  (The literature's xi = 48 case fails about a third of the depth above the base.)
* ``intact_blocks``: at ``mechanism_time`` (default 3 s), the number of intact
  blocks the sliding mass has broken into: connected groups (4-neighbour cells of
  the grid) of at least 4 cells holding sliding points with ``gamma_p < 0.1``
  (the literature's "sub-blocks"; most for mid-range anisotropy).
* ``sliding_area_early`` (m2): the sliding area at ``mechanism_time``: how fast it fails.
* ``final_profile``: the surface (max Y per X bin of one cell width) now and at the start.
"""
from __future__ import annotations

import numpy as np

from .output import to_true_frame
from .particles import Particles

__all__ = ["compute_measures", "surface_profile"]


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


def intact_blocks(x: np.ndarray, x0: np.ndarray, gamma_p: np.ndarray, threshold: float,
                  origin: np.ndarray, cell: np.ndarray, shape: tuple[int, int],
                  intact_strain: float = 0.1, min_cells: int = 4) -> int:
    """Connected groups (>= ``min_cells`` grid cells, 4-neighbour) of sliding, intact points."""
    from scipy import ndimage
    sel = (np.linalg.norm(x - x0, axis=1) > threshold) & (gamma_p < intact_strain)
    if not sel.any():
        return 0
    ij = np.floor((x[sel] - origin) / cell).astype(np.int64)
    ij[:, 0] = np.clip(ij[:, 0], 0, shape[0] - 1)
    ij[:, 1] = np.clip(ij[:, 1], 0, shape[1] - 1)
    img = np.zeros(shape, dtype=bool)
    img[ij[:, 0], ij[:, 1]] = True
    labels, n = ndimage.label(img)
    sizes = np.bincount(labels.ravel())[1:]
    return int((sizes >= min_cells).sum())


def compute_measures(pts: Particles, frame_angle_deg: float, threshold: float,
                     cell: np.ndarray, time_to_rest: float | None, snapshots=None,
                     grid=None, mechanism_time: float = 3.0) -> dict:
    """All measures of DESIGN section 5 as a plain dict (see module docstring).

    ``snapshots`` [(t, x, gamma_p)] and ``grid`` give the mechanism measures at
    ``mechanism_time`` (s; the snapshot nearest to it); without them they are None.
    """
    X0 = to_true_frame(pts.x0, frame_angle_deg)
    X = to_true_frame(pts.x, frame_angle_deg)
    d = np.linalg.norm(pts.x - pts.x0, axis=1)
    sliding = d > threshold
    crest = to_true_frame(crest_position(pts, float(cell[1]))[None], frame_angle_deg)[0]
    retro = float(max(0.0, crest[0] - X0[sliding, 0].min())) if sliding.any() else 0.0
    early_area = blocks = None
    if snapshots and grid is not None:
        t_snap = np.array([t for t, *_ in snapshots])
        _, xs, gs = snapshots[int(np.argmin(np.abs(t_snap - mechanism_time)))]
        moved = np.linalg.norm(xs - pts.x0, axis=1) > threshold
        early_area = float(pts.volume0[moved].sum())
        blocks = intact_blocks(xs, pts.x0, gs, threshold, grid.origin, grid.cell, grid.shape)
    return {
        "failed": bool(sliding.any()),
        "slip_surface_height": slip_surface_height(pts.x0, sliding, float(cell[0])),
        "intact_blocks": blocks,
        "sliding_area_early": early_area,
        "mechanism_time": mechanism_time,
        "sliding_area": float(pts.volume0[sliding].sum()),
        "runout_distance": float(max(0.0, X[:, 0].max() - X0[:, 0].max())),
        "retrogression_distance": retro,
        "max_displacement": float(d.max(initial=0.0)),
        "time_to_rest": time_to_rest,
        "failure_displacement": threshold,
        "final_profile": surface_profile(X, float(np.min(cell))),
        "initial_profile": surface_profile(X0, float(np.min(cell))),
    }
