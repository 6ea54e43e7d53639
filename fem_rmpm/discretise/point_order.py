"""Spatial order of the material points inside the explicit time loop.

As a slope breaks up, neighbouring points in memory drift apart on the grid: the map to
nodes and the map back then read and write nodal arrays all over the mesh (cache
misses), and the two halves of the points that the threaded step runs on two threads
(:mod:`fem_rmpm.schemes.explicit.kernels.transfer`) come to touch the same nodes, which both halves
then solve.  :class:`PointOrder` sorts the points by their host cell every few hundred steps (cells
numbered row by row, as the grid numbers its nodes: the order the points are
seeded in) and restores the original order before anyone outside the time loop looks at
the points: at every output, at a guard and at the end of the run.  (Column by column
would suit the two halves of a long slope better, but on a fine grid it walks the nodal
arrays a row apart, one memory page per node, and is much slower.)  A point's index is therefore its
identity everywhere outside the kernels (VTK frames, snapshots, measures, frozen-point
lists, error messages).

The sort is a stable sort of the cell numbers of the current positions: a pure function
of the state, the same on any number of threads.  It changes the order of the nodal
sums, so a sorted run agrees with an unsorted one to round-off, not bitwise.
"""
from __future__ import annotations

import numpy as np

from fem_rmpm.discretise.grid import Grid, locate
from fem_rmpm.discretise.points import Particles
from fem_rmpm.schemes.regularisation import forget_plan

__all__ = ["SORT_EVERY", "permute_points", "PointOrder"]

#: Steps between two sorts of the points (besides the sort after every output).
SORT_EVERY = 500


def _point_arrays(pts: Particles) -> list[np.ndarray]:
    """Every per-point array of ``pts`` and of its material (first axis = the points)."""
    n = pts.n
    return [v for v in (*vars(pts).values(), pts.soil.model, pts.soil.params)
            if isinstance(v, np.ndarray) and v.ndim and v.shape[0] == n]


def permute_points(pts: Particles, idx: np.ndarray, buffers: dict | None = None) -> None:
    """Reorder every per-point array of ``pts`` (and of its material) in place: slot
    ``s`` takes the point that was in slot ``idx[s]``.  In place, so that arrays bound
    elsewhere (the compiled step's workspace) stay valid.  ``buffers``: work arrays kept
    between calls, ``{(dtype, shape, Fortran order): array}`` (a gather into a kept buffer
    and a copy back is a few times faster than ``a[...] = a[idx]``).  The column-major
    arrays (the material's parameter rows and the state) are gathered column by column,
    several times faster than numpy's row gather of a column-major array."""
    buffers = {} if buffers is None else buffers
    for a in _point_arrays(pts):
        key = (a.dtype.str, a.shape, a.flags.f_contiguous)
        buf = buffers.get(key)
        if buf is None:
            buf = buffers[key] = np.empty_like(a)          # (the same memory order)
        if a.ndim == 2 and a.flags.f_contiguous and not a.flags.c_contiguous:
            np.take(a.T, idx, axis=1, out=buf.T)            # column by column
        else:
            np.take(a, idx, axis=0, out=buf)
        a[...] = buf
    forget_plan(pts.soil)          # its cached point indices of non-local soils


class PointOrder:
    """The points' order in the time loop: :meth:`sort` by host cell, :meth:`restore`
    the original order, :meth:`sort_if_due` after a step.  ``every``: steps between two
    sorts (0: never sort; every method is then a no-op).  ``order[s]``: the original
    index of the point in slot ``s`` (None while the points are in their original order);
    ``sorted``: True from a :meth:`sort` to the next :meth:`restore`."""

    def __init__(self, every: int = SORT_EVERY) -> None:
        self.every = int(every)
        self.order: np.ndarray | None = None
        self.sorted = False
        self.next_sort = 0
        self._buffers: dict = {}

    def sort(self, grid: Grid, pts: Particles) -> None:
        """Sort the points by host cell, :func:`fem_rmpm.discretise.grid.locate`'s number (row by
        row, ``j nx + i``, as the grid numbers its cells and nodes; points outside the grid in its
        edge cells), stably: ties keep their current order."""
        if self.every <= 0:
            return
        self.sorted = True
        key = locate(grid, pts.x)[0]
        if bool((key[1:] >= key[:-1]).all()):
            return
        idx = np.argsort(key, kind="stable")
        permute_points(pts, idx, self._buffers)
        self.order = idx if self.order is None else self.order[idx]

    def sort_if_due(self, grid: Grid, pts: Particles, step: int) -> None:
        """After step ``step``: sort if the points were restored since the last sort (an
        output, a guard) or ``every`` steps have passed."""
        if self.every > 0 and (not self.sorted or step >= self.next_sort):
            self.sort(grid, pts)
            self.next_sort = step + self.every

    def due_step(self) -> float:
        """The first step after which :meth:`sort_if_due` sorts: 0 (any step) while the
        points are unsorted, the next sort's step, or inf when sorting is off."""
        if self.every <= 0:
            return float("inf")
        return float(self.next_sort) if self.sorted else 0.0

    def restore(self, pts: Particles) -> None:
        """Put the points back in their original order."""
        self.sorted = False
        if self.order is None:
            return
        inverse = np.empty_like(self.order)
        inverse[self.order] = np.arange(len(self.order))
        permute_points(pts, inverse, self._buffers)
        self.order = None
