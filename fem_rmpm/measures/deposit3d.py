"""Measures of a three-dimensional realization: the plane-strain measures taken slice by
slice along the strike, and their maxima and means.

The points counted are the active ones (frozen points excluded; the plane-strain scheme's
stray-point rule, by connected bodies, is not applied in 3-D).  A point slides when its
displacement |u| exceeds the failure displacement.  ``X`` is the true horizontal
coordinate in the x-y plane (the grid frame turned by ``frame_angle_deg``).  The strike
is cut into slices one grid cell long (by each point's initial z); in each slice:

* run-out = max X of its counted points now minus max X0 of all its points at the start
  (>= 0), as the plane-strain ``runout_distance``;
* retrogression = X of its crest (the most down-slope point of its top cell layer at the
  start) minus min X0 of its sliding points (>= 0; 0 without sliding points).

``runout_distance`` and ``retrogression_distance`` are the largest over the slices (with
``_mean`` the mean and ``_profile`` the list [(z, value)]); ``sliding_volume`` (m3) is the
initial volume of the sliding points and ``sliding_area`` (m2/m) that volume per metre of
the strike length of the soil (its slices), the plane-strain figure of an extruded slope;
``intact_blocks`` counts the 3-D connected components of the cells of sliding intact
points (:func:`intact_blocks_3d`).
"""
from __future__ import annotations

import math

import numpy as np
from scipy import ndimage

__all__ = ["compute_measures_3d", "intact_blocks_3d", "INTACT_STRAIN"]

#: A point is intact below this plastic shear strain (-), as in plane strain.
INTACT_STRAIN = 0.1


def intact_blocks_3d(pts, grid, threshold: float, least_area: float) -> int:
    """Connected groups (face-neighbour grid cells, 3-D connected components) of cells
    holding sliding (moved more than ``threshold``, m), intact (``gamma_p`` below
    :data:`INTACT_STRAIN`) active points, of at least the volume of a cube whose face is
    the least block area ``least_area`` (m2, ``[montecarlo] intact_block_area``)."""
    sel = pts.active & (np.linalg.norm(pts.x - pts.x0, axis=1) > threshold) \
        & (pts.plastic_shear_strain < INTACT_STRAIN)
    if not sel.any():
        return 0
    ijk = np.clip(np.floor((pts.x[sel] - grid.origin) / grid.cell).astype(np.int64), 0,
                  np.array(grid.shape) - 1)
    img = np.zeros(grid.shape, dtype=bool)
    img[ijk[:, 0], ijk[:, 1], ijk[:, 2]] = True
    labels, _ = ndimage.label(img)
    sizes = np.bincount(labels.ravel())[1:]
    least = max(1, math.ceil(least_area ** 1.5 / float(np.prod(grid.cell)) - 1e-9))
    return int((sizes >= least).sum())


def _true_horizontal(x: np.ndarray, frame_angle_deg: float) -> np.ndarray:
    a = math.radians(frame_angle_deg)
    return math.cos(a) * x[:, 0] + math.sin(a) * x[:, 1]


def _slices(pts, grid) -> tuple[np.ndarray, np.ndarray]:
    """Slice index per point (n,) and the slices' mid z (n_slices,), m."""
    k = np.clip(np.floor((pts.x0[:, 2] - grid.origin[2]) / grid.cell[2]).astype(np.int64),
                0, grid.shape[2] - 1)
    return k, grid.origin[2] + (np.arange(grid.shape[2]) + 0.5) * grid.cell[2]


def _profiles(pts, grid, frame_angle_deg: float, sliding: np.ndarray):
    X, X0 = _true_horizontal(pts.x, frame_angle_deg), _true_horizontal(pts.x0, frame_angle_deg)
    k, zs = _slices(pts, grid)
    runout, retro = [], []
    for s in np.unique(k):
        here = k == s
        counted = here & pts.active
        r = max(float(X[counted].max() - X0[here].max()), 0.0) if counted.any() else 0.0
        top = here & (pts.x0[:, 1] > pts.x0[here, 1].max() - grid.cell[1])
        crest = float(X0[top][np.argmax(pts.x0[top, 0])])
        slid = here & sliding
        q = max(crest - float(X0[slid].min()), 0.0) if slid.any() else 0.0
        runout.append((float(zs[s]), r))
        retro.append((float(zs[s]), q))
    return runout, retro


def compute_measures_3d(pts, grid, frame_angle_deg: float, threshold: float,
                        time_to_rest: float | None, least_block_area: float = 1.0) -> dict:
    """The measures (module docstring) of points ``pts`` on ``grid``; ``threshold`` the
    failure displacement (m), ``time_to_rest`` (s or None), ``least_block_area`` (m2) of
    :func:`intact_blocks_3d`."""
    d = np.linalg.norm(pts.displacement, axis=1)
    counted = pts.active
    sliding = counted & (d > threshold)
    runout, retro = _profiles(pts, grid, frame_angle_deg, sliding)
    k, _ = _slices(pts, grid)
    length = float(len(np.unique(k)) * grid.cell[2])       # strike length of the soil, m
    volume = float(pts.volume0[sliding].sum())
    frozen = ~pts.active
    return {
        "failed": bool(d[counted].max(initial=0.0) > threshold),
        "runout_distance": max(v for _, v in runout),
        "runout_distance_mean": float(np.mean([v for _, v in runout])),
        "retrogression_distance": max(v for _, v in retro),
        "retrogression_distance_mean": float(np.mean([v for _, v in retro])),
        "sliding_volume": volume,
        "sliding_area": volume / length,
        "max_displacement": float(d[counted].max(initial=0.0)),
        "time_to_rest": time_to_rest,
        "intact_blocks": intact_blocks_3d(pts, grid, threshold, least_block_area),
        "runout_profile": runout,
        "retrogression_profile": retro,
        "strike_length": length,
        "excluded_frozen_points": int(frozen.sum()),
        "excluded_frozen_volume": float(pts.volume0[frozen].sum()),
    }
