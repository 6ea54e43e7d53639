"""The points of a 3-D run kept sorted by cell (:mod:`fem_rmpm.schemes.explicit3d.order`):
a sort and its restore give back every per-point array bit for bit, the sorted points
are in cell order, and a run with sorts equals one without within round-off (the order
of the nodal sums changes), with the points handed back in their seeded order.  The case:
the extruded reference slope (von Mises softening, 36 448 points) for its first 0.4 s."""
from __future__ import annotations

from pathlib import Path

import numba
import numpy as np
import pytest

from fem_rmpm import api
from fem_rmpm.schemes.explicit3d import loop as L
from fem_rmpm.schemes.explicit3d import step as S
from fem_rmpm.schemes.explicit3d.order import (_per_point_arrays, permute_points_3d,
                                                point_order_3d)

MESHES = Path(__file__).parents[1] / "meshes"
NAMES = ("x", "velocity", "stress", "log_strain", "volume", "state", "u_geostatic")


def _run(monkeypatch, sort_every: int, t_end: float = 0.4, perm=None):
    """The slab to ``t_end`` s, sorted every ``sort_every`` steps, its points handed to
    the run in the order ``perm`` of the seeded ones (all per-point arrays permuted)."""
    monkeypatch.setattr(L, "SORT_EVERY", sort_every)
    scene = api.with_value(api.load_scene(MESHES / "slope_extruded_3d.toml"), "solver.t_end",
                           t_end)
    grid, pts = api.prepare(scene)
    if perm is not None:
        permute_points_3d(pts, L.Workspace3D(grid, pts), perm)
    x0 = pts.x0.copy()
    rec = L.run_explicit_3d(scene, grid, pts)
    return rec, grid, pts, x0


def _map(work):
    S._map_half(work.points, work.grid, work.scratch, 0)
    S._map_half(work.points, work.grid, work.scratch, 1)


def test_sort_then_restore_gives_back_every_array_bitwise(monkeypatch):
    """From the slab at 0.2 s with its points shuffled: the sort puts the active points
    in cell order and the restore gives back every per-point array (points, material
    rows, stretch, Lame columns, cells and local coordinates) of the seeded order."""
    _, grid, pts, _ = _run(monkeypatch, 10**9, 0.2)
    work = L.Workspace3D(grid, pts)
    _map(work)
    before = [a.copy() for a in _per_point_arrays(pts, work)]
    order = point_order_3d(pts, work)
    perm = np.random.default_rng(2).permutation(pts.n)
    permute_points_3d(pts, work, perm)
    order.ids = order.ids[perm]                        # (as a sort would record it)
    _map(work)
    order.sort()
    assert (np.diff(work.scratch.cellbase[pts.active]) >= 0).all()      # cell order
    assert not order.in_id_order
    order.restore()
    assert order.in_id_order
    after = _per_point_arrays(pts, work)
    assert len(after) == len(before) >= 20
    for a, b in zip(before, after):
        np.testing.assert_array_equal(a, b)            # (NaN where NaN)


def test_sorted_run_equals_unsorted_run_within_round_off(monkeypatch):
    """The points handed to the run shuffled, then sorted by cell five times in 0.4 s (43
    steps), against the seeded order never sorted: the same steps, every state array
    within 1e-12 of its largest value (round-off of reordered nodal sums; 1.7e-13 reached;
    an array left out of the permutation would give a wrong state, not round-off), and
    the points handed back in the order they were given (initial positions equal)."""
    r0, _, p0, x0 = _run(monkeypatch, 10**9)
    perm = np.random.default_rng(4).permutation(len(x0))
    r1, _, p1, x1 = _run(monkeypatch, 8, perm=perm)
    assert r0.solver["point_sorts"] == 0 and r1.solver["point_sorts"] >= 5
    assert r0.steps == r1.steps
    assert np.array_equal(p0.x0, x0) and np.array_equal(p1.x0, x1)
    back = np.argsort(perm)
    for name in NAMES:
        a, b = getattr(p0, name), getattr(p1, name)[back]
        np.testing.assert_array_equal(np.isnan(a), np.isnan(b))
        err, scale = np.nanmax(np.abs(a - b)), np.nanmax(np.abs(a))
        print(name, err, scale)
        assert err <= 1e-12 * scale, name
    assert np.abs(p0.x - p1.x[back]).max() > 0        # the order of the sums did change


@pytest.mark.skipif(numba.config.NUMBA_NUM_THREADS < 2, reason="numba has one thread")
def test_sorted_run_on_two_threads_is_the_one_thread_run_bitwise(monkeypatch):
    """From a shuffled start, sorted five times: two threads give the one-thread run bit
    for bit (the sort and the halves it makes are the same on both)."""
    perm = np.random.default_rng(4).permutation(36448)
    before = numba.get_num_threads()
    monkeypatch.setattr(api, "load_scene", _with_threads(1))
    r1, _, p1, _ = _run(monkeypatch, 8, perm=perm)
    numba.set_num_threads(2)
    try:
        monkeypatch.setattr(api, "load_scene", _with_threads(2))
        r2, _, p2, _ = _run(monkeypatch, 8, perm=perm)
    finally:
        numba.set_num_threads(before)
    assert r1.solver["threads"] == 1 and r2.solver["threads"] == 2
    assert r1.solver["point_sorts"] == r2.solver["point_sorts"] >= 5
    for name in NAMES:
        assert np.array_equal(getattr(p1, name), getattr(p2, name)), name


_LOAD = api.load_scene


def _with_threads(threads: int):
    """``api.load_scene`` with ``[solver] threads`` set."""
    def loader(path):
        return api.with_value(_LOAD(path), "solver.threads", threads)
    return loader
