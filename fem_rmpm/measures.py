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


def compute_measures(pts: Particles, frame_angle_deg: float, threshold: float,
                     cell: np.ndarray, time_to_rest: float | None) -> dict:
    """All measures of DESIGN section 5 as a plain dict (see module docstring)."""
    X0 = to_true_frame(pts.x0, frame_angle_deg)
    X = to_true_frame(pts.x, frame_angle_deg)
    d = np.linalg.norm(pts.x - pts.x0, axis=1)
    sliding = d > threshold
    crest = to_true_frame(crest_position(pts, float(cell[1]))[None], frame_angle_deg)[0]
    retro = float(max(0.0, crest[0] - X0[sliding, 0].min())) if sliding.any() else 0.0
    return {
        "failed": bool(sliding.any()),
        "sliding_area": float(pts.volume0[sliding].sum()),
        "runout_distance": float(max(0.0, X[:, 0].max() - X0[:, 0].max())),
        "retrogression_distance": retro,
        "max_displacement": float(d.max(initial=0.0)),
        "time_to_rest": time_to_rest,
        "failure_displacement": threshold,
        "final_profile": surface_profile(X, float(np.min(cell))),
        "initial_profile": surface_profile(X0, float(np.min(cell))),
    }
