"""The deposit of a realization, in the true (not grid) frame, and its measures.

**Which points count.**  Numerical debris must not move a risk number, so every
measure is taken over the *counted* points only (:func:`deposit_points`):

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
points were excluded and their initial volume (m2/m), per reason, is reported in
the measures ``excluded_frozen_points``, ``excluded_frozen_volume``, ``excluded_stray_points``,
``excluded_stray_volume`` (and by :func:`excluded_summary` as
``{"frozen": {"points", "volume"}, "stray": {...}, "rule": ...}`` in ``summary.json``).

**The measures** are declared in :data:`fem_rmpm.measures.table.MEASURES` (name, unit,
definition, how each is computed from a :class:`Deposit`); :func:`compute_measures`
computes them in the table's order.  The mechanism measures (intact blocks, early sliding
area) are taken on the snapshot nearest the mechanism time (default 3 s; runs take it 3 s
after the end of a geostatic phase, when the points start to move).  The least intact
block is a physical area (``[montecarlo] intact_block_area``, default
:data:`INTACT_BLOCK_AREA` = 1 m2), so counts compare across meshes: 1 m2 is 4 cells of
0.5 m (the coarsest mesh that resolves it with a few cells), 16 of 0.25 m and 64 of
0.125 m.  (The literature's xi = 48 case fails about a third of the depth above the base:
``slip_surface_height``.)
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import Any

import numpy as np
from scipy import ndimage

from fem_rmpm.discretise.points import Particles
from fem_rmpm.io.output import to_true_frame
from fem_rmpm.measures.blocks import INTACT_BLOCK_AREA, intact_blocks, least_cells
from fem_rmpm.measures.geometry import (
    crest_position,
    moved_area,
    slip_surface_height,
    surface_profile,
)
from fem_rmpm.measures.table import MEASURES, unit

__all__ = ["compute_measures", "Deposit", "deposit_points", "excluded_summary",
           "MIN_BODY_FRACTION", "surface_profile", "moved_area", "crest_position",
           "slip_surface_height", "INTACT_BLOCK_AREA", "intact_blocks", "least_cells"]

MIN_BODY_FRACTION = 0.01   #: a body holds at least this fraction of the active volume


def deposit_points(x: np.ndarray, volume: np.ndarray, active: np.ndarray, origin,
                   cell, min_body_fraction: float = MIN_BODY_FRACTION
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Which points count (see the module docstring): returns ``(counted, stray)``, two
    (n,) bool masks; frozen points (``~active``) are in neither.  ``x`` (n, 2) current
    grid-frame positions (m), ``volume`` (n,) current volumes (m2/m), ``origin``
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
                   f"{MIN_BODY_FRACTION:.0%} of the active volume; volume = initial, "
                   f"{unit('excluded_frozen_volume')}")
    return out


@dataclass
class Deposit:
    """A realization's final state and what every measure is computed from.

    ``pts`` the material points (grid frame); ``frame_angle_deg`` the scene's frame angle
    (deg); ``threshold`` the failure displacement (m); ``cell`` (2,) the cell size (m);
    ``time_to_rest`` (s or None); ``snapshots`` [(t, x, gamma_p)] and ``grid`` give the
    mechanism snapshot (nearest ``mechanism_time``, s); ``intact_block_area`` (m2).  The
    derived arrays (:attr:`counted`, :attr:`sliding`, ...) are computed once, when a
    measure first asks for them."""
    pts: Particles
    frame_angle_deg: float
    threshold: float
    cell: np.ndarray
    time_to_rest: float | None = None
    snapshots: list | None = None
    grid: Any = None
    mechanism_time: float = 3.0
    intact_block_area: float = INTACT_BLOCK_AREA
    failure_area: float = 0.0

    @cached_property
    def _deposit(self) -> tuple[np.ndarray, np.ndarray]:
        origin = self.grid.origin if self.grid is not None else np.zeros(2)
        return deposit_points(self.pts.x, self.pts.volume, self.pts.active, origin, self.cell)

    @property
    def counted(self) -> np.ndarray:
        """(n,) bool: the points of the deposit (:func:`deposit_points`)."""
        return self._deposit[0]

    @property
    def stray(self) -> np.ndarray:
        """(n,) bool: active points in no body of the deposit."""
        return self._deposit[1]

    @property
    def frozen(self) -> np.ndarray:
        """(n,) bool: points frozen at the grid edge."""
        return ~self.pts.active

    @cached_property
    def X0(self) -> np.ndarray:
        """(n, 2) initial positions of all points, true frame (m)."""
        return to_true_frame(self.pts.x0, self.frame_angle_deg)

    @cached_property
    def X(self) -> np.ndarray:
        """(k, 2) current positions of the counted points, true frame (m)."""
        return to_true_frame(self.pts.x[self.counted], self.frame_angle_deg)

    @cached_property
    def displacement(self) -> np.ndarray:
        """(n,) distance d_p each point moved (m)."""
        return np.linalg.norm(self.pts.x - self.pts.x0, axis=1)

    @cached_property
    def sliding(self) -> np.ndarray:
        """(n,) bool: counted points that moved more than the threshold."""
        return self.counted & (self.displacement > self.threshold)

    @cached_property
    def mechanism(self) -> tuple[np.ndarray, np.ndarray] | None:
        """(x (n, 2), gamma_p (n,)) of the snapshot nearest the mechanism time; None without
        snapshots or grid."""
        if not self.snapshots or self.grid is None:
            return None
        t_snap = np.array([t for t, *_ in self.snapshots])
        _, xs, gs = self.snapshots[int(np.argmin(np.abs(t_snap - self.mechanism_time)))]
        return xs, gs


def compute_measures(pts: Particles, frame_angle_deg: float, threshold: float,
                     cell: np.ndarray, time_to_rest: float | None, snapshots=None,
                     grid=None, mechanism_time: float = 3.0,
                     intact_block_area: float = INTACT_BLOCK_AREA,
                     failure_area: float = 0.0) -> dict:
    """Every measure of :data:`~fem_rmpm.measures.table.MEASURES` that has a ``compute``
    function, in table order, as a plain dict (arguments: the fields of :class:`Deposit`).

    ``snapshots`` [(t, x, gamma_p)] and ``grid`` give the mechanism measures at
    ``mechanism_time`` (s; the snapshot nearest to it); without them they are None.
    ``intact_block_area`` (m2): the least intact block; ``failure_area`` (m2/m): the least
    sliding area that is a failure (0: any sliding point).
    The deposit is binned on ``grid`` (or on cells of size ``cell`` from the origin).
    """
    deposit = Deposit(pts, frame_angle_deg, threshold, cell, time_to_rest, snapshots, grid,
                      mechanism_time, intact_block_area, failure_area)
    return {m.name: m.compute(deposit) for m in MEASURES.values() if m.compute is not None}
