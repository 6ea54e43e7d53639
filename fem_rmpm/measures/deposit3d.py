"""Measures of a three-dimensional realization: the plane-strain measures taken slice by
slice along the strike, and their maxima and means.

**Which points count** is the plane-strain rule of :mod:`fem_rmpm.measures.deposit` in
three dimensions, on the whole deposit (:func:`deposit_points_3d`): frozen points never
count; the active points are binned by their current position into the grid's cells; the
occupied cells that touch (26-neighbour: faces, edges or corners) form connected bodies; a
body holds at least ``MIN_BODY_FRACTION`` (1 %) of the active points' current volume (the
largest always counts); a point counts when its cell belongs to a body, and is ``stray``
otherwise.  The rule is applied to the whole deposit, not slice by slice, because a point
belongs to the deposit by touching it in any direction: material that moved across a slice
boundary, or a film one cell thick along the strike, stays connected to its body, and a
point thrown off the deposit is an empty cell away from it in 3-D as in its slice.  On a
plane-strain slab (every slice alike) the two agree.  A point slides when the distance it
moved since the end of the geostatic phase, ``|x - x0|``, exceeds the failure displacement
(the plane-strain ``d_p``: the in-situ settlement of a geostatic phase is no sliding;
``max_displacement`` is the largest ``d_p`` of a counted point).  ``X`` is the true
horizontal coordinate in the x-y plane (the grid frame turned by ``frame_angle_deg``).
The strike is cut into slices one grid cell long (by each point's initial z); in each
slice:

* run-out = max X of its counted points now minus max X0 of all its points at the start
  (>= 0), as the plane-strain ``runout_distance``;
* retrogression = X of its crest (the most down-slope point of its top cell layer at the
  start) minus min X0 of its sliding points (>= 0; 0 without sliding points).

``runout_distance`` and ``retrogression_distance`` are the largest over the slices (with
``_mean`` the mean and ``_profile`` the list [(z, value)]); ``sliding_volume`` (m3) is the
initial volume of the sliding points and ``sliding_area`` (m2/m) that volume per metre of
the strike length of the soil (its slices), the plane-strain figure of an extruded slope.

**Failure** follows the plane-strain rule slice by slice: a realization fails when its
sliding volume is at least ``failure_area`` (m2/m, ``[montecarlo] failure_area``) times
one slice's strike length ``hz``, i.e. at least one slice's worth of the failure area
(on a plane-strain slab, where every slice alike, this is the 2-D rule; 0: any sliding
point).  The **slides** along the strike (:func:`~.slides3d.slides_along_strike`) are the
runs of consecutive slices each holding at least that volume (``failure_area x hz``) of
sliding points; an empty slice separates two: ``slide_count``, ``slide_length_max`` (m,
slices x hz), ``slide_volume_max`` (m3) and ``slides`` [(z0, z1, volume)].  A failed
realization has at least one slide unless its sliding volume is spread thinner than the
failure area over every slice.
``intact_blocks`` counts the 3-D connected components of the cells of sliding intact
points (:func:`intact_blocks_3d`).  ``excluded_frozen_*`` and ``excluded_stray_*`` give the
excluded points per reason (count, and initial volume per metre of strike, m2/m, as the
plane-strain measures).
"""
from __future__ import annotations

import math

import numpy as np
from scipy import ndimage

from fem_rmpm.measures.deposit import MIN_BODY_FRACTION
from fem_rmpm.measures.slides3d import slides_along_strike

__all__ = ["compute_measures_3d", "deposit_points_3d", "intact_blocks_3d", "INTACT_STRAIN",
           "failure_volume_3d"]

#: A point is intact below this plastic shear strain (-), as in plane strain.
INTACT_STRAIN = 0.1


def deposit_points_3d(x: np.ndarray, volume: np.ndarray, active: np.ndarray, origin,
                      cell, min_body_fraction: float = MIN_BODY_FRACTION
                      ) -> tuple[np.ndarray, np.ndarray]:
    """Which points count (module docstring): ``(counted, stray)``, two (n,) bool masks;
    frozen points (``~active``) are in neither.  ``x`` (n, 3) current grid-frame positions
    (m), ``volume`` (n,) current volumes (m3), ``origin`` and ``cell`` (3,) the grid's
    corner and cell size (m)."""
    n = len(x)
    counted, stray = np.zeros(n, dtype=bool), np.zeros(n, dtype=bool)
    act = np.nonzero(active)[0]
    if len(act) == 0:
        return counted, stray
    ijk = np.floor((x[act] - np.asarray(origin, float)) / np.asarray(cell, float)
                   ).astype(np.int64)
    ijk -= ijk.min(axis=0)
    idx = (ijk[:, 0], ijk[:, 1], ijk[:, 2])
    vol = np.zeros(tuple(ijk.max(axis=0) + 1))
    np.add.at(vol, idx, volume[act])
    labels, nlab = ndimage.label(vol > 0, structure=np.ones((3, 3, 3), dtype=bool))
    body_vol = np.bincount(labels.ravel(), vol.ravel(), minlength=nlab + 1)
    is_body = body_vol >= min_body_fraction * volume[act].sum()
    is_body[1 + int(np.argmax(body_vol[1:]))] = True          # the largest always counts
    is_body[0] = False
    inside = is_body[labels[idx]]
    counted[act[inside]] = True
    stray[act[~inside]] = True
    return counted, stray


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


def _profiles(pts, grid, frame_angle_deg: float, counted: np.ndarray, sliding: np.ndarray):
    X, X0 = _true_horizontal(pts.x, frame_angle_deg), _true_horizontal(pts.x0, frame_angle_deg)
    k, zs = _slices(pts, grid)
    runout, retro = [], []
    for s in np.unique(k):
        here = k == s
        now = here & counted
        r = max(float(X[now].max() - X0[here].max()), 0.0) if now.any() else 0.0
        top = here & (pts.x0[:, 1] > pts.x0[here, 1].max() - grid.cell[1])
        crest = float(X0[top][np.argmax(pts.x0[top, 0])])
        slid = here & sliding
        q = max(crest - float(X0[slid].min()), 0.0) if slid.any() else 0.0
        runout.append((float(zs[s]), r))
        retro.append((float(zs[s]), q))
    return runout, retro


def failure_volume_3d(failure_area: float, grid) -> float:
    """The least sliding volume (m3) of a failed 3-D realization: ``failure_area`` (m2/m)
    times one slice's strike length (the grid's hz, m)."""
    return float(failure_area) * float(grid.cell[2])


def _slides(pts, grid, sliding: np.ndarray, least: float) -> list:
    k, _ = _slices(pts, grid)
    lo = grid.origin[2] + float(k.min()) * grid.cell[2]
    hi = grid.origin[2] + float(k.max() + 1) * grid.cell[2]
    return slides_along_strike(pts.x0[:, 2], pts.volume0, sliding, float(grid.cell[2]),
                               z_range=(lo, hi), min_volume=least)


def compute_measures_3d(pts, grid, frame_angle_deg: float, threshold: float,
                        time_to_rest: float | None, least_block_area: float = 1.0,
                        failure_area: float = 0.0) -> dict:
    """The measures (module docstring) of points ``pts`` on ``grid``; ``threshold`` the
    failure displacement (m), ``time_to_rest`` (s or None), ``least_block_area`` (m2) of
    :func:`intact_blocks_3d`, ``failure_area`` (m2/m) the failure rule's."""
    d = np.linalg.norm(pts.x - pts.x0, axis=1)     # moved since the geostatic phase
    counted, stray = deposit_points_3d(pts.x, pts.volume, pts.active, grid.origin, grid.cell)
    sliding = counted & (d > threshold)
    runout, retro = _profiles(pts, grid, frame_angle_deg, counted, sliding)
    k, _ = _slices(pts, grid)
    length = float(len(np.unique(k)) * grid.cell[2])       # strike length of the soil, m
    volume = float(pts.volume0[sliding].sum())
    frozen = ~pts.active
    least = failure_volume_3d(failure_area, grid)
    slides = _slides(pts, grid, sliding, least) if sliding.any() else []
    return {
        "failed": bool(sliding.any()) and volume >= least,
        "runout_distance": max(v for _, v in runout),
        "runout_distance_mean": float(np.mean([v for _, v in runout])),
        "retrogression_distance": max(v for _, v in retro),
        "retrogression_distance_mean": float(np.mean([v for _, v in retro])),
        "sliding_volume": volume,
        "sliding_area": volume / length,
        "slide_count": len(slides),
        "slide_length_max": max((s.b1 - s.b0 for s in slides), default=0.0),
        "slide_volume_max": max((s.volume for s in slides), default=0.0),
        "slides": [(float(s.b0), float(s.b1), float(s.volume)) for s in slides],
        "max_displacement": float(d[counted].max(initial=0.0)),
        "time_to_rest": time_to_rest,
        "intact_blocks": intact_blocks_3d(pts, grid, threshold, least_block_area),
        "runout_profile": runout,
        "retrogression_profile": retro,
        "strike_length": length,
        "failure_displacement": float(threshold),
        "excluded_frozen_points": int(frozen.sum()),
        "excluded_frozen_volume": float(pts.volume0[frozen].sum()) / length,
        "excluded_stray_points": int(stray.sum()),
        "excluded_stray_volume": float(pts.volume0[stray].sum()) / length,
    }
