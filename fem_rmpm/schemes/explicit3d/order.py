"""Point order of the three-dimensional explicit step: the points kept sorted by cell, so
that the map, the map back and the stress pass, which take the points in array order,
read and write the nodal rows of one cell after another (cache lines already loaded)
instead of jumping across the grid as the points move away from their seeded order.

The schedule and the bookkeeping are the plane-strain loop's
(:class:`fem_rmpm.discretise.point_order.PointOrder`); :func:`point_order_3d` gives them
the three-dimensional key (each point's cell in the last map, the inactive points last)
and permutation: :func:`permute_points_3d` reorders every per-point array of the run
together (the points' dataclass, their material rows, the step's workspace) in place, so
every reference to them stays valid, through a scratch of three numbers per point rather
than a full copy of each array (24 B per point, which counts at millions of points).
The time loop (:mod:`.loop`) sorts every :data:`SORT_EVERY` steps after the gravity
phase and after each output, and puts the points back in id order before each output
and at the end of the run (also when it stops on an error), so outputs, measures and the
points handed back are per id as before.
The order of the nodal sums changes with the order of the points: a sorted run differs
from an unsorted one by round-off (``validation/plane_strain_3d.py``).
"""
from __future__ import annotations

from dataclasses import fields

import numpy as np

from fem_rmpm.discretise.point_order import PointOrder
from fem_rmpm.runtime.compiled import kernel

__all__ = ["SORT_EVERY", "permute_points_3d", "point_order_3d"]

#: Steps between two sorts (besides the sort after each output): the points cross a few
#: cells in that time, and a sort costs about two steps.
SORT_EVERY = 200


#: Columns permuted at a time (the scratch's numbers per point).
_CHUNK = 3


@kernel
def _permute_rows(a, perm, tmp):
    """``a[:] = a[perm]`` for a 2-D float array (any layout) through ``tmp`` (at least
    ``a.size``)."""
    n, k = a.shape
    for i in range(n):
        p = perm[i]
        for j in range(k):
            tmp[i * k + j] = a[p, j]
    for i in range(n):
        for j in range(k):
            a[i, j] = tmp[i * k + j]


def _per_point_arrays(pts, work) -> list:
    """Every per-point array of the run: each field of the points (a dataclass whose
    fields are all per point, the arrays of its material rows ``soil`` included) and
    the workspace's stretch, Lame columns, cells and local coordinates."""
    out = []
    for f in fields(pts):
        v = getattr(pts, f.name)
        out.extend([v] if isinstance(v, np.ndarray) else
                   [w for w in vars(v).values() if isinstance(w, np.ndarray)])
    out += [work.be, work.lam, work.mu, work.scratch.cellbase, work.scratch.cellxi]
    n = len(pts.mass)
    if any(a.shape[0] != n for a in out):
        raise RuntimeError("a per-point array of another length than the points")
    return out


def permute_points_3d(pts, work, perm: np.ndarray) -> None:
    """Every per-point array of the run (:func:`_per_point_arrays`) ``a[:] = a[perm]`` in
    place, the float arrays through one scratch of :data:`_CHUNK` numbers per point (a
    few columns at a time)."""
    n = len(perm)
    tmp = np.empty(n * _CHUNK)
    for a in _per_point_arrays(pts, work):
        if a.dtype == np.float64:
            a2 = a.reshape(n, -1) if a.ndim == 1 else a
            for j in range(0, a2.shape[1], _CHUNK):
                _permute_rows(a2[:, j:j + _CHUNK], perm, tmp)
        else:
            a[...] = a[perm]


def point_order_3d(pts, work, every: int = SORT_EVERY) -> PointOrder:
    """The order of the points ``pts`` (:class:`~fem_rmpm.discretise.points3d.Particles3D`)
    and the per-point arrays of ``work`` (:class:`.loop.Workspace3D`: stretch, Lame
    columns, each point's cell): keyed by the cell of the last map (``cellbase``), the
    inactive points last; the first sort after ``every`` steps."""
    def key() -> np.ndarray:
        return np.where(pts.active, work.scratch.cellbase, np.iinfo(np.int64).max)

    return PointOrder(len(pts.mass), key, lambda perm: permute_points_3d(pts, work, perm),
                      every, first=every)
