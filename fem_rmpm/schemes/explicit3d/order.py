"""Point order of the three-dimensional explicit step: the points kept sorted by cell, so
that the map, the map back and the stress pass, which take the points in array order,
read and write the nodal rows of one cell after another (cache lines already loaded)
instead of jumping across the grid as the points move away from their seeded order.

:class:`PointOrder` permutes every per-point array of the run together (the points'
dataclass, their material rows, the step's workspace) in place, so every reference to
them stays valid, and keeps ``ids``: the seeded index (the point's id) of the point at
each position.  The time loop (:mod:`.loop`) sorts every :data:`SORT_EVERY` steps and
after each output, and puts the points back in id order before each output and at the
end of the run (also when it stops on an error), so outputs, measures and the points
handed back are per id as before.
The order of the nodal sums changes with the order of the points: a sorted run differs
from an unsorted one by round-off (``validation/plane_strain_3d.py``).
"""
from __future__ import annotations

from dataclasses import fields

import numpy as np

from fem_rmpm.runtime.compiled import kernel

__all__ = ["PointOrder", "SORT_EVERY"]

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


class PointOrder:
    """The order of the points of a run (module docstring): ``ids[i]`` is the id of the
    point at position ``i``; ``sorts`` counts the sorts done."""

    def __init__(self, n: int):
        self.ids = np.arange(n)
        self.sorts = 0

    @property
    def in_id_order(self) -> bool:
        return bool(np.array_equal(self.ids, np.arange(len(self.ids))))

    def _permute(self, pts, work, perm: np.ndarray) -> None:
        """Every per-point array ``a[:] = a[perm]`` in place, the float arrays through one
        scratch of :data:`_CHUNK` numbers per point (a few columns at a time)."""
        n = len(perm)
        tmp = np.empty(n * _CHUNK)
        for a in _per_point_arrays(pts, work):
            if a.dtype == np.float64:
                a2 = a.reshape(n, -1) if a.ndim == 1 else a
                for j in range(0, a2.shape[1], _CHUNK):
                    _permute_rows(a2[:, j:j + _CHUNK], perm, tmp)
            else:
                a[...] = a[perm]
        self.ids = self.ids[perm]

    def sort(self, pts, work) -> None:
        """Sort the points of ``pts`` (:class:`~fem_rmpm.discretise.points3d.Particles3D`)
        and the per-point arrays of ``work`` (:class:`.loop.Workspace3D`: stretch, Lame
        columns, each point's cell) by cell, stably, the inactive points last; the
        cells are those of the last map (``cellbase``)."""
        cb = work.scratch.cellbase
        key = np.where(pts.active, cb, np.iinfo(np.int64).max)
        self._permute(pts, work, np.argsort(key, kind="stable"))
        self.sorts += 1

    def restore(self, pts, work) -> None:
        """Put the points back in id order (nothing to do when they are)."""
        if not self.in_id_order:
            self._permute(pts, work, np.argsort(self.ids))
