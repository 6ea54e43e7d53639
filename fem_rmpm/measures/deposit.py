"""Measures of a realization, taken on the *deposit* in the true (not grid) frame.

**Which points count.**  Numerical debris must not move a risk number, so every
measure below is taken over the *counted* points only (:func:`deposit_points`):

1. a point frozen at the grid edge (``active = 0``) never counts (reason ``frozen``);
2. the active points are binned by their current position into the cells of the
   background grid; a cell holding at least one active point is *occupied*;
3. occupied cells that touch (8-neighbour: sides or corners) form connected
   bodies of material; a *body* holds at least ``min_body_fraction`` (default 1 %)
   of the active points' current volume;
4. a point counts when its cell belongs to a body; every other active point is
   ``stray``: a point or a small group separated from every body by at least one
   empty cell (debris thrown off or climbed away from the deposit).

A continuous film, even one point thick (such as the run-up on the valley side),
is part of the body it touches; a stray point is at least one empty cell away, so
adding stray points beyond the deposit does not move the run-out.
The largest connected group is always a body.  How many
points were excluded and their initial volume (m2 per m), per reason, is reported in
the keys ``excluded_frozen_points``, ``excluded_frozen_volume``, ``excluded_stray_points``,
``excluded_stray_volume`` (and by :func:`excluded_summary` as
``{"frozen": {"points", "volume"}, "stray": {...}, "rule": ...}`` in ``summary.json``).

Definitions (``d_p`` = distance point p moved since the end of the geostatic
phase, ``X`` = true horizontal coordinate, pointing down-slope; threshold
``failure_displacement`` from ``[montecarlo]``, default 0.5 m; *sliding* = counted
and ``d_p > threshold``):

* ``sliding_area`` (m2 per m): total initial volume of the sliding points.
* ``failed``: ``sliding_area > 0`` — at least one counted point moved more than the threshold.
* ``runout_distance`` (m): ``max X`` of the counted points now minus ``max X`` of all
  points at the start (how far the deposit's front travelled beyond the original
  toe), >= 0.
* ``retrogression_distance`` (m): ``X_crest - min X0`` over the sliding points,
  where ``X_crest`` is the initial true-horizontal position of the slope crest
  (the most down-slope point of the top soil layer in the grid frame), >= 0: how
  far behind the original crest the failure reached.
* ``max_displacement`` (m): the largest ``d_p`` of a counted point.
* ``time_to_rest`` (s): simulated time at which the run stopped at rest (None otherwise).
* ``slip_surface_height`` (m): how high above the base (grid y, normal to the
  bedrock) the failure surface lies, averaged over the failed part of the slope:
  per column of one cell (initial x), the highest initial y of a counted point that
  stayed (``d_p <= threshold``) below the lowest sliding point; 0 where the whole
  column slid.  (The literature's xi = 48 case fails about a third of the depth above
  the base.)
* ``intact_blocks``: at ``mechanism_time`` (default 3 s; runs take it 3 s after the end
  of a geostatic phase, when the points start to move), the number of intact
  blocks the sliding mass has broken into: connected groups (4-neighbour cells of
  the grid) of cells holding sliding points with ``gamma_p < 0.1`` (the literature's
  "sub-blocks"; most for mid-range anisotropy) whose area (cells x cell area) is at
  least ``intact_block_area`` (m2, ``[montecarlo] intact_block_area``, default
  :data:`INTACT_BLOCK_AREA` = 1 m2; reported as the measure ``intact_block_area``).  The
  least block is a physical area, so counts compare across meshes: 1 m2 is 4 cells of
  0.5 m (the coarsest mesh that resolves it with a few cells; the risk study's mesh),
  16 of 0.25 m and 64 of 0.125 m.  (Earlier versions counted groups of at least 4
  cells whatever their size: 1 m2 at 0.5 m but 0.25 m2 at 0.25 m and 0.06 m2 at
  0.125 m, so finer meshes counted smaller fragments; a record without the
  ``intact_block_area`` key holds a count of that definition.)
* ``sliding_area_early`` (m2): the initial volume of the points moved more than the
  threshold at ``mechanism_time`` (points frozen by the end excluded): how fast it fails.
* ``final_profile``: the surface (max Y per X bin of one cell width) of the counted
  points now; ``initial_profile`` that of all points at the start.
"""
from __future__ import annotations

import math

import numpy as np
from scipy import ndimage

from fem_rmpm.discretise.points import Particles
from fem_rmpm.io.output import to_true_frame

__all__ = ["compute_measures", "surface_profile", "deposit_points", "excluded_summary",
           "moved_area", "UNITS",
           "MIN_BODY_FRACTION", "INTACT_BLOCK_AREA", "intact_blocks", "least_cells"]

#: Units of the scalar measures (and of the other ``results.csv`` columns).
UNITS = {"failed": "0/1", "sliding_area": "m2 per m", "runout_distance": "m",
         "retrogression_distance": "m", "max_displacement": "m", "time_to_rest": "s",
         "slip_surface_height": "m", "intact_blocks": "count", "intact_block_area": "m2",
         "sliding_area_early": "m2 per m",
         "mechanism_time": "s", "failure_displacement": "m",
         "excluded_frozen_points": "count", "excluded_frozen_volume": "m2 per m (initial)",
         "excluded_stray_points": "count", "excluded_stray_volume": "m2 per m (initial)",
         "case": "-", "index": "-", "seed": "-", "status": "ok | failed", "stop_reason": "-",
         "steps": "count", "simulated_time": "s", "particles": "count",
         "frozen_points": "count", "scheme": "-", "error": "-"}
MIN_BODY_FRACTION = 0.01   #: a body holds at least this fraction of the active volume
INTACT_BLOCK_AREA = 1.0    #: m2: least area of an intact block (4 cells of 0.5 m)


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


def moved_area(x: np.ndarray, x0: np.ndarray, volume0: np.ndarray, active: np.ndarray,
               threshold: float) -> float:
    """Initial volume (m2 per m) of the active points that have moved more than
    ``threshold`` (m) from ``x0``; ``x``, ``x0`` (n, 2) m, ``volume0`` (n,), ``active`` (n,)
    bool.  The early sliding area at the mechanism time, and the area that decides a
    failure in a campaign's runs stopped once decided."""
    moved = (np.linalg.norm(x - x0, axis=1) > threshold) & active
    return float(volume0[moved].sum())


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
                  intact_strain: float = 0.1, min_cells: int | None = None,
                  min_area: float = INTACT_BLOCK_AREA) -> int:
    """Connected groups (4-neighbour grid cells) of sliding, intact points whose area is at
    least ``min_area`` (m2; a group of k cells has the area k x cell area).  ``min_cells``,
    if given, replaces the area by a least number of cells (earlier versions: 4 cells)."""
    if min_cells is None:
        min_cells = least_cells(min_area, cell)
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


def least_cells(area: float, cell) -> int:
    """Fewest grid cells of size ``cell`` (m, (2,)) whose area reaches ``area`` (m2), >= 1
    (a relative 1e-9 absorbs rounding: 1 m2 is exactly 16 cells of 0.25 m)."""
    cell_area = float(np.prod(np.asarray(cell, dtype=float)))
    return max(1, int(math.ceil(area / cell_area * (1.0 - 1e-9))))


def deposit_points(x: np.ndarray, volume: np.ndarray, active: np.ndarray, origin,
                   cell, min_body_fraction: float = MIN_BODY_FRACTION
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Which points count (see the module docstring): returns ``(counted, stray)``, two
    (n,) bool masks; frozen points (``~active``) are in neither.  ``x`` (n, 2) current
    grid-frame positions (m), ``volume`` (n,) current volumes (m2 per m), ``origin``
    and ``cell`` (2,) the grid's corner and cell size (m)."""
    n = len(x)
    counted, stray = np.zeros(n, dtype=bool), np.zeros(n, dtype=bool)
    act = np.nonzero(active)[0]
    if len(act) == 0:
        return counted, stray
    ij = np.floor((x[act] - np.asarray(origin, float)) / np.asarray(cell, float)).astype(np.int64)
    ij -= ij.min(axis=0)
    vol = np.zeros(tuple(ij.max(axis=0) + 1))
    np.add.at(vol, (ij[:, 0], ij[:, 1]), volume[act])
    occupied = np.zeros(vol.shape, dtype=bool)
    occupied[ij[:, 0], ij[:, 1]] = True
    labels, nlab = ndimage.label(occupied, structure=np.ones((3, 3), dtype=bool))
    body_vol = np.bincount(labels.ravel(), vol.ravel(), minlength=nlab + 1)
    is_body = body_vol >= min_body_fraction * volume[act].sum()
    is_body[1 + int(np.argmax(body_vol[1:]))] = True          # the largest always counts
    is_body[0] = False
    inside = is_body[labels[ij[:, 0], ij[:, 1]]]
    counted[act[inside]] = True
    stray[act[~inside]] = True
    return counted, stray


def excluded_summary(measures: dict) -> dict:
    """The excluded points of a realization per reason, with the rule, for summary.json."""
    out = {why: {k: measures[f"excluded_{why}_{k}"] for k in ("points", "volume")}
           for why in ("frozen", "stray")}
    out["rule"] = ("frozen: frozen at the grid edge; stray: active but in no connected body "
                   "(8-neighbour occupied grid cells) holding >= "
                   f"{MIN_BODY_FRACTION:.0%} of the active volume; volume = initial, m2 per m")
    return out


def _excluded(pts: Particles, stray: np.ndarray) -> dict:
    frozen = ~pts.active
    out = {}
    for why, mask in (("frozen", frozen), ("stray", stray)):
        out[why] = {"points": int(mask.sum()), "volume": float(pts.volume0[mask].sum())}
    return out


def compute_measures(pts: Particles, frame_angle_deg: float, threshold: float,
                     cell: np.ndarray, time_to_rest: float | None, snapshots=None,
                     grid=None, mechanism_time: float = 3.0,
                     intact_block_area: float = INTACT_BLOCK_AREA) -> dict:
    """All measures of a realization as a plain dict (see the module docstring).

    ``snapshots`` [(t, x, gamma_p)] and ``grid`` give the mechanism measures at
    ``mechanism_time`` (s; the snapshot nearest to it); without them they are None.
    ``intact_block_area`` (m2): the least intact block.
    The deposit is binned on ``grid`` (or on cells of size ``cell`` from the origin).
    """
    origin = grid.origin if grid is not None else np.zeros(2)
    counted, stray = deposit_points(pts.x, pts.volume, pts.active, origin, cell)
    X0 = to_true_frame(pts.x0, frame_angle_deg)
    X = to_true_frame(pts.x[counted], frame_angle_deg)
    d = np.linalg.norm(pts.x - pts.x0, axis=1)
    moved = d > threshold
    sliding = counted & moved
    crest = to_true_frame(crest_position(pts, float(cell[1]))[None], frame_angle_deg)[0]
    retro = float(max(0.0, crest[0] - X0[sliding, 0].min())) if sliding.any() else 0.0
    early_area = blocks = None
    if snapshots and grid is not None:
        t_snap = np.array([t for t, *_ in snapshots])
        _, xs, gs = snapshots[int(np.argmin(np.abs(t_snap - mechanism_time)))]
        early_area = moved_area(xs, pts.x0, pts.volume0, pts.active, threshold)
        blocks = intact_blocks(xs, pts.x0, gs, threshold, grid.origin, grid.cell, grid.shape,
                               min_area=intact_block_area)
    excluded = _excluded(pts, stray)
    front = float(X[:, 0].max()) if len(X) else float(X0[:, 0].max())
    return {
        "failed": bool(sliding.any()),
        "slip_surface_height": slip_surface_height(pts.x0[counted], sliding[counted],
                                                   float(cell[0])),
        "intact_blocks": blocks,
        "intact_block_area": intact_block_area,
        "sliding_area_early": early_area,
        "mechanism_time": mechanism_time,
        "sliding_area": float(pts.volume0[sliding].sum()),
        "runout_distance": float(max(0.0, front - X0[:, 0].max())),
        "retrogression_distance": retro,
        "max_displacement": float(d[counted].max(initial=0.0)),
        "time_to_rest": time_to_rest,
        "failure_displacement": threshold,
        **{f"excluded_{why}_{k}": v for why, e in excluded.items() for k, v in e.items()},
        "final_profile": surface_profile(X, float(np.min(cell))),
        "initial_profile": surface_profile(X0, float(np.min(cell))),
    }
