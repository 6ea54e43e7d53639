"""Which points count in the 3-D measures: the plane-strain deposit rule
(:mod:`fem_rmpm.measures.deposit`) in three dimensions, on the whole deposit."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from fem_rmpm.measures.deposit import deposit_points
from fem_rmpm.measures.deposit3d import compute_measures_3d, deposit_points_3d


def test_3d_rule_on_one_slice_equals_the_plane_strain_rule():
    """Points in a single layer of cells: the 3-D rule (26-neighbour bodies) gives the 2-D
    rule's (8-neighbour) counted and stray masks exactly."""
    rng = np.random.default_rng(3)
    x = np.vstack([rng.uniform(0, 10, (2000, 2)), [[30.0, 30.0], [12.5, 1.0]]])
    v = rng.uniform(0.5, 1.5, len(x))
    active = np.ones(len(x), bool)
    active[:5] = False
    c2, s2 = deposit_points(x, v, active, (0, 0), (1, 1))
    x3 = np.column_stack([x, np.full(len(x), 0.5)])
    c3, s3 = deposit_points_3d(x3, v, active, (0, 0, 0), (1, 1, 1))
    assert np.array_equal(c2, c3) and np.array_equal(s2, s3)
    assert s3.sum() == 2 and not (c3[:5] | s3[:5]).any()


def test_diagonal_neighbours_across_the_strike_join_the_body():
    """A point touching the body only by a cell edge or corner across the strike counts;
    one an empty cell away is stray (each holds 0.15 % of the volume, below the 1 % of a
    body of its own)."""
    body = np.array([[i + 0.5, j + 0.5, k + 0.5] for i in range(4) for j in range(4)
                     for k in range(4)])
    x = np.vstack([body, [[4.5, 4.5, 4.5], [6.5, 0.5, 0.5]]])
    v = np.ones(len(x))
    v[-2:] = 0.1
    c, s = deposit_points_3d(x, v, np.ones(len(x), bool), (0, 0, 0), (1, 1, 1))
    assert c[:-1].all() and s[-1] and s.sum() == 1


def _slab(extra_x: float | None):
    """A 4 x 2 x 2 m block of points (0.5 m cells, 2 per cell per axis) that slid 1 m down
    x, and optionally one point thrown to x = ``extra_x``."""
    h = 0.25
    g = np.arange(h / 2, 4.0, h)
    x0 = np.array([[a, b, c] for a in g for b in np.arange(h / 2, 2.0, h)
                   for c in np.arange(h / 2, 2.0, h)])
    x = x0 + [1.0, 0.0, 0.0]
    if extra_x is not None:
        x[np.argmax(x0[:, 0] + x0[:, 1] + x0[:, 2])] = [extra_x, 1.9, 1.9]
    n = len(x)
    pts = SimpleNamespace(x=x, x0=x0, volume=np.full(n, h ** 3), volume0=np.full(n, h ** 3),
                          active=np.ones(n, bool), displacement=x - x0,
                          plastic_shear_strain=np.zeros(n))
    grid = SimpleNamespace(origin=np.zeros(3), cell=np.full(3, 0.5), shape=(40, 8, 4))
    return compute_measures_3d(pts, grid, 0.0, 0.5, None)


def test_a_stray_point_does_not_move_the_3d_runout():
    """Run-out of a block moved 1 m: 1 m (closed form) in every slice, with or without a
    point thrown 10 m ahead of it (which is reported as stray, one point)."""
    plain, thrown = _slab(None), _slab(15.0)
    assert abs(plain["runout_distance"] - 1.0) < 1e-12
    assert abs(thrown["runout_distance"] - 1.0) < 1e-12
    assert abs(thrown["runout_distance_mean"] - 1.0) < 1e-12
    assert plain["excluded_stray_points"] == 0 and thrown["excluded_stray_points"] == 1
    # per metre of strike, as the 2-D measure (m2/m): one point of 0.25**3 m3 over the
    # block's 2 m of strike
    assert thrown["excluded_stray_volume"] == pytest.approx(0.25 ** 3 / 2.0, rel=1e-12)
