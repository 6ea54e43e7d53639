"""The explicit time loop sorts the points by host cell and shows them to everyone else in
their original order (:mod:`fem_rmpm.discretise.point_order`).

References: a permutation followed by its inverse is the identity (exactly); a sorted run
and an unsorted run of the same scene differ only by the order of the nodal sums, so by
round-off (over ~56 steps of a yielding slope, bounds a few times the measured
differences: positions 5e-14 m (7.1e-15 measured), plastic state 2e-14 (2.1e-15),
stress 1e-13 of the largest (2.5e-14)); the sort is a function of the state, so 1 and 2
threads stay bitwise equal over a whole sorted run.
"""
from __future__ import annotations

import numba
import numpy as np
import pytest

from fem_rmpm import api
from fem_rmpm.discretise.grid import locate, make_grid
from fem_rmpm.discretise.point_order import PointOrder, permute_points, plane_point_order
from fem_rmpm.discretise.points import seed_particles
from fem_rmpm.scene import load_scene, with_values
from fem_rmpm.schemes.explicit.loop import run_explicit

FIELDS = ("x", "x0", "velocity", "mass", "volume", "stress", "log_strain", "state", "F",
          "soil_id", "cell0", "active")


def _scene(meshes, **changes):
    values = {"grid.cell": [0.5, 0.5], "soil.model": "von_mises_softening",
              "soil.cohesion_peak": 3.0, "soil.cohesion_residual": 1.0,
              "soil.softening_strain": 0.05, "solver.t_end": 0.5,
              "solver.gravity_phase": "dynamic",
              "solver.output_interval": 0.1, "solver.gravity_ramp_time": 0.1}
    values.update(changes)
    return with_values(load_scene(meshes / "slope_elastic.toml"), values)


def test_sort_key_numbers_cells_row_by_row():
    """A 4 x 2 grid of 1 m cells: the key, the grid's cell number j nx + i, as the grid
    numbers its cells; a point outside is clamped into the edge cell."""
    class G:
        origin, cell, shape = np.zeros(2), np.ones(2), (4, 2)
    x = np.array([[0.5, 0.5], [0.5, 1.5], [1.5, 0.5], [3.5, 1.5], [9.0, -3.0]])
    assert locate(G, x)[0].tolist() == [0, 4, 1, 7, 3]      # the last one clamped to (3, 0)


def test_schedule_sorts_after_every_steps_and_after_a_restore():
    """The schedule both dimensions share: with ``every`` = 5 a sort after step 1 (the
    points not sorted yet), then after step 6, and at once after a restore; the restore
    permutes by the inverse of the composed sorts (ids back to 0..n-1); with ``first`` =
    5 (the three-dimensional loop) the first sort after step 5; ``every`` = 0 never."""
    perms = []
    state = {"key": np.array([3, 2, 1, 0])}

    def permute(idx):
        perms.append(idx.copy())
        state["key"] = state["key"][idx]

    order = PointOrder(4, lambda: state["key"], permute, every=5)
    sorted_after = []
    for step in range(1, 13):
        before = order.sorts
        order.sort_if_due(step)
        if order.sorts > before:
            sorted_after.append(step)
        if step == 8:
            assert order.due_step() == 11.0
            order.restore()
            assert order.in_id_order and order.due_step() == 0.0
            assert state["key"].tolist() == [3, 2, 1, 0]
    assert sorted_after == [1, 6, 9]
    assert len(perms) == 3            # the sort at step 6 found the points in order already
    late = PointOrder(4, lambda: state["key"], permute, every=5, first=5)
    first_sort = None
    for step in range(1, 7):
        late.sort_if_due(step)
        first_sort = first_sort or (step if late.sorts else None)
    assert first_sort == 5
    never = PointOrder(4, lambda: state["key"], permute, every=0)
    never.sort_if_due(1)
    assert never.sorts == 0 and never.due_step() == float("inf")


def test_permutation_and_restore_are_exact(meshes):

    scene = _scene(meshes)
    grid = make_grid(scene)
    pts = seed_particles(scene, grid)
    pts.x += np.random.default_rng(1).normal(0.0, 0.3, pts.x.shape)    # disorder
    ref = pts.copy()
    order = plane_point_order(grid, pts)
    order.sort()
    key = locate(grid, pts.x)[0]
    assert order.sorted and not order.in_id_order and (np.diff(key) >= 0).all()
    assert np.array_equal(pts.x0, ref.x0[order.ids])
    assert np.array_equal(pts.soil.params, ref.soil.params[order.ids], equal_nan=True)
    order.restore()
    assert not order.sorted and order.in_id_order
    for f in FIELDS:
        assert np.array_equal(getattr(pts, f), getattr(ref, f)), f
    assert np.array_equal(pts.soil.params, ref.soil.params, equal_nan=True)
    idx = np.random.default_rng(2).permutation(pts.n)
    permute_points(pts, idx)
    assert np.array_equal(pts.state, ref.state[idx])


@pytest.mark.parametrize("regularisation", ["local", "nonlocal"])
def test_sorted_run_equals_unsorted_run_to_round_off(meshes, regularisation):
    """The outputs see the original order (x0 at every output is the seeding's), and the
    final states of a sorted and an unsorted run agree to round-off; non-local: the
    average's cached point indices follow the sort."""
    extra = {"soil.internal_length": 1.0} if regularisation == "nonlocal" else {}
    scene = _scene(meshes, **{"solver.threads": 1, "soil.regularisation": regularisation,
                              **extra})
    runs = {}
    for every in (0, 5):
        grid, pts = api.prepare(scene)
        x0 = pts.x0.copy()
        seen = []
        rec = run_explicit(scene, grid, pts, on_output=lambda t, p: seen.append(
            np.array_equal(p.x0, x0)), sort_every=every)
        assert rec.steps > 40 and len(seen) >= 3 and all(seen)
        assert np.array_equal(pts.x0, x0)
        runs[every] = pts
    a, b = runs[0], runs[5]
    assert (a.plastic_shear_strain > 0).sum() > 50
    assert np.abs(a.x - b.x).max() < 5e-14 and np.abs(a.state - b.state).max() < 2e-14
    assert np.abs(a.stress - b.stress).max() < 1e-13 * np.abs(a.stress).max()


def test_sorted_run_bitwise_equal_on_one_and_two_threads(meshes):
    before = numba.get_num_threads()
    numba.set_num_threads(min(2, numba.config.NUMBA_NUM_THREADS))
    try:
        out = []
        for threads in (1, 2):
            scene = _scene(meshes, **{"solver.threads": threads, "solver.shape": "gimp"})
            grid = make_grid(scene)
            pts = seed_particles(scene, grid)
            rec = run_explicit(scene, grid, pts, sort_every=3)
            out.append((pts, rec))
    finally:
        numba.set_num_threads(before)
    (a, ra), (b, rb) = out
    assert ra.steps == rb.steps > 40
    for f in FIELDS:
        assert np.array_equal(getattr(a, f), getattr(b, f), equal_nan=True), f   # F: NaN


def test_frozen_points_listed_by_original_index(meshes):
    """A block thrown off the free right edge of a small grid (gravity at 60 degrees):
    the points frozen beyond the edge are listed by their seeding index, the same list
    sorted or not, and each listed point is frozen just beyond the edge."""
    scene = with_values(load_scene(meshes / "column.toml"), {
        "grid.size": [3.0, 2.0], "grid.cell": [0.25, 0.25], "boundary.right": "free",
        "boundary.bottom": "roller", "scene.frame_angle_deg": 60.0,
        "soil.polygon": [[0.5, 0.0], [1.5, 0.0], [1.5, 1.0], [0.5, 1.0]],
        "solver.gravity_phase": "dynamic", "solver.gravity_ramp_time": 0.0,
        "solver.damping": 0.0, "solver.t_end": 0.7, "solver.edge_policy": "freeze",
        "solver.output_interval": 0.02})
    grid = make_grid(scene)
    lists = []
    for every in (0, 3):
        pts = seed_particles(scene, grid)
        rec = run_explicit(scene, grid, pts, on_output=lambda t, p: None, sort_every=every)
        idx = np.array(rec.frozen_points, dtype=np.int64)
        assert 0 < len(idx) < pts.n and not pts.active[idx].any()
        beyond = pts.x[idx, 0] - grid.upper[0]
        assert pts.active.sum() == pts.n - len(idx)
        assert beyond.min() > 0 and beyond.max() < 0.5 * grid.cell[0]
        lists.append(sorted(idx.tolist()))
    assert lists[0] == lists[1]
