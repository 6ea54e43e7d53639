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

:class:`PointOrder` is the schedule and the bookkeeping of both dimensions: it sorts by a
key it is given and permutes through a function it is given.  The plane-strain loop's key
is the host cell of :func:`~fem_rmpm.discretise.grid.locate` and its permutation
:func:`permute_points` (:func:`plane_point_order`); the three-dimensional loop's are in
:mod:`fem_rmpm.schemes.explicit3d.order`.
"""
from __future__ import annotations

from collections.abc import Callable

import numpy as np

from fem_rmpm.discretise.grid import Grid, locate
from fem_rmpm.discretise.points import Particles
from fem_rmpm.schemes.regularisation import forget_plan

__all__ = ["SORT_EVERY", "permute_points", "PointOrder", "plane_point_order"]

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
    """The points' order in a time loop: :meth:`sort` by a key, :meth:`restore` the
    original order, :meth:`sort_if_due` after a step.

    ``n``: the number of points; ``key()``: each slot's sort key (the host cell's number)
    for the current state; ``permute(idx)``: reorder every per-point array of the run in
    place, slot ``s`` taking the point in slot ``idx[s]``; ``every``: steps between two
    sorts (0: never sort; every method is then a no-op); ``first``: the step after which
    the first sort is due (0: the first step).  ``ids[s]``: the original index (the
    point's id) of the point in slot ``s``; ``sorted``: True from a :meth:`sort` to the next
    :meth:`restore`; ``sorts``: the sorts done."""

    def __init__(self, n: int, key: Callable[[], np.ndarray],
                 permute: Callable[[np.ndarray], None], every: int = SORT_EVERY,
                 first: int = 0) -> None:
        self.ids = np.arange(n)
        self.every = int(every)
        self.sorted = first > 0           # the seeded order serves until step ``first``
        self.next_sort = int(first)
        self.sorts = 0
        self._key, self._permute = key, permute

    @property
    def in_id_order(self) -> bool:
        """True when every point is in its original slot."""
        return bool(np.array_equal(self.ids, np.arange(len(self.ids))))

    def sort(self) -> None:
        """Sort the points by their key, stably: ties keep their current order."""
        if self.every <= 0:
            return
        self.sorted = True
        self.sorts += 1
        key = self._key()
        if bool((key[1:] >= key[:-1]).all()):
            return
        idx = np.argsort(key, kind="stable")
        self._permute(idx)
        self.ids = self.ids[idx]

    def sort_if_due(self, step: int) -> None:
        """After step ``step``: sort if the points were restored since the last sort (an
        output, a guard) or ``every`` steps have passed."""
        if self.every > 0 and (not self.sorted or step >= self.next_sort):
            self.sort()
            self.next_sort = step + self.every

    def due_step(self) -> float:
        """The first step after which :meth:`sort_if_due` sorts: 0 (any step) while the
        points are unsorted, the next sort's step, or inf when sorting is off."""
        if self.every <= 0:
            return float("inf")
        return float(self.next_sort) if self.sorted else 0.0

    def restore(self) -> None:
        """Put the points back in their original order (nothing to do when they are)."""
        self.sorted = False
        if self.in_id_order:
            return
        inverse = np.empty_like(self.ids)
        inverse[self.ids] = np.arange(len(self.ids))
        self._permute(inverse)
        self.ids = np.arange(len(self.ids))


def plane_point_order(grid: Grid, pts: Particles, every: int = SORT_EVERY) -> PointOrder:
    """The order of the plane-strain loop's points ``pts`` on ``grid``: keyed by host cell,
    :func:`fem_rmpm.discretise.grid.locate`'s number (row by row, ``j nx + i``, as the grid
    numbers its cells and nodes; points outside the grid in its edge cells), permuted by
    :func:`permute_points` through work buffers kept for the run."""
    buffers: dict = {}
    return PointOrder(pts.n, lambda: locate(grid, pts.x)[0],
                      lambda idx: permute_points(pts, idx, buffers), every)
