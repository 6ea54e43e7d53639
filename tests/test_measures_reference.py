"""The deposit and mechanism measures against independent brute-force references, on random
point sets (they also serve mutation testing of :mod:`fem_rmpm.measures`).

The references below are written from the definitions in :mod:`fem_rmpm.measures.table` and
the module docstring of :mod:`fem_rmpm.measures.deposit`, in plain Python (dicts of cells,
breadth-first search), sharing no code with the vectorised module: a point belongs to the
cell ``floor((x - origin) / cell)``; occupied cells form bodies by 8-neighbour contact
(deposit) or 4-neighbour contact (intact blocks, cells clipped into the grid); a body counts
when it holds at least 1 % of the active volume, and the largest always counts. The random
sets use an origin that is not a multiple of the cell and rectangular cells, so a sign or an
axis mix-up in the binning changes the answer. The hand-made cases pin the boundaries the
random sets rarely hit (a body of exactly 1 %, more than 100 bodies, an empty deposit).
"""
from __future__ import annotations

import math
from collections import deque
from types import SimpleNamespace

import numpy as np
import pytest

from fem_rmpm.measures.blocks import intact_blocks
from fem_rmpm.measures.deposit import compute_measures, deposit_points, excluded_summary
from fem_rmpm.measures.geometry import slip_surface_height
from tests.test_measures_details import _points

N8 = [(a, b) for a in (-1, 0, 1) for b in (-1, 0, 1) if (a, b) != (0, 0)]
N4 = [(1, 0), (-1, 0), (0, 1), (0, -1)]


def _components(cells: set, neighbours) -> list[set]:
    """Connected components of a set of (i, j) cells (breadth-first search)."""
    left, out = set(cells), []
    while left:
        seed = left.pop()
        comp, todo = {seed}, deque([seed])
        while todo:
            i, j = todo.popleft()
            for a, b in neighbours:
                c = (i + a, j + b)
                if c in left:
                    left.remove(c)
                    comp.add(c)
                    todo.append(c)
        out.append(comp)
    return out


def _reference_deposit(x, volume, active, origin, cell, frac=0.01):
    cell_of = {}
    for k in np.nonzero(active)[0]:
        cell_of[k] = (math.floor((x[k, 0] - origin[0]) / cell[0]),
                      math.floor((x[k, 1] - origin[1]) / cell[1]))
    comps = _components(set(cell_of.values()), N8)
    vol = [sum(volume[k] for k, c in cell_of.items() if c in comp) for comp in comps]
    total = sum(volume[k] for k in cell_of)
    body = [v >= frac * total for v in vol]
    if comps:
        body[int(np.argmax(vol))] = True
    counted = np.zeros(len(x), bool)
    for k, c in cell_of.items():
        counted[k] = any(b and c in comp for b, comp in zip(body, comps))
    stray = np.zeros(len(x), bool)
    stray[list(cell_of)] = ~counted[list(cell_of)]
    return counted, stray


def _reference_blocks(x, x0, gamma_p, threshold, origin, cell, shape, intact=0.1, min_area=1.0):
    """Groups of 4-neighbour cells of sliding intact points whose area (cells x cell area)
    reaches ``min_area`` (m2)."""
    cells = set()
    for k in range(len(x)):
        if math.dist(x[k], x0[k]) > threshold and gamma_p[k] < intact:
            i = math.floor((x[k, 0] - origin[0]) / cell[0])
            j = math.floor((x[k, 1] - origin[1]) / cell[1])
            cells.add((min(max(i, 0), shape[0] - 1), min(max(j, 0), shape[1] - 1)))
    return sum(len(c) * cell[0] * cell[1] >= min_area - 1e-12 for c in _components(cells, N4))


def _random_cloud(rng, n_blobs=4):
    """Blobs of points of random size and place plus scattered single points."""
    parts = [rng.normal(rng.uniform(0, 12, 2), rng.uniform(0.3, 1.5), (rng.integers(5, 60), 2))
             for _ in range(n_blobs)]
    parts.append(rng.uniform(-2, 14, (rng.integers(3, 12), 2)))
    x = np.vstack(parts)
    return x, rng.uniform(0.01, 0.3, len(x)), rng.random(len(x)) > 0.05


@pytest.mark.parametrize("seed", range(12))
def test_deposit_points_equals_the_brute_force_reference(seed):
    """12 random clouds (N = 12 configurations, 20 to 250 points each), origin off the
    cell lattice, cells 0.7 x 0.45 m: the counted and stray masks equal the reference's
    exactly, and no point is both."""
    rng = np.random.default_rng(seed)
    x, vol, active = _random_cloud(rng)
    origin, cell = np.array([-3.37, 1.91]), np.array([0.7, 0.45])
    counted, stray = deposit_points(x, vol, active, origin, cell)
    ref_c, ref_s = _reference_deposit(x, vol, active, origin, cell)
    assert np.array_equal(counted, ref_c) and np.array_equal(stray, ref_s)
    assert not (counted & stray).any() and not (counted | stray)[~active].any()


def test_deposit_a_body_of_exactly_one_percent_counts():
    """A 99-volume body and a separate 1-volume point (exactly 1 % of 100): counted (>=)."""
    body = np.array([[i + 0.5, j + 0.5] for i in range(9) for j in range(11)])
    x = np.vstack([body, [[20.5, 0.5]]])
    vol = np.ones(len(x))
    counted, stray = deposit_points(x, vol, np.ones(len(x), bool), np.zeros(2), np.ones(2))
    assert counted.all() and not stray.any()


def test_deposit_with_more_than_a_hundred_bodies_counts_only_the_largest():
    """150 isolated points, each below 1 % of the volume; the largest (1.5 against 1.0) is
    the last in raster order: it alone counts, the others are stray."""
    x = np.array([[3.0 * i + 0.5, 0.5] for i in range(150)])
    vol = np.ones(150)
    vol[-1] = 1.5
    counted, stray = deposit_points(x, vol, np.ones(150, bool), np.zeros(2), np.ones(2))
    assert np.nonzero(counted)[0].tolist() == [149] and stray[:149].all()


@pytest.mark.parametrize("seed", range(8))
def test_intact_blocks_equal_the_brute_force_reference(seed):
    """8 random sets of moved points (N = 8), origin off the lattice, cells 0.6 x 0.4 m on a
    30 x 25 grid, some points exactly on the grid's far edges, in its first row and
    column and beyond its lower-left corner (clipped into cell (0, 0)): the block count equals the reference's
    (least block 1 m2, i.e. 5 cells of 0.24 m2, and 0.24 / 0.5 / 0.96 m2; 4 cells, the
    old rule, leave at least one block in every set)."""
    rng = np.random.default_rng(100 + seed)
    origin, cell, shape = np.array([-1.13, 0.37]), np.array([0.6, 0.4]), (30, 25)
    far = origin + cell * shape
    x = rng.uniform(origin, far, (400, 2))
    x[:20, 0] = far[0]                                    # on the right edge: last column
    x[20:40, 1] = far[1]                                  # on the top edge: last row
    x[40:60, 0] = origin[0] + rng.uniform(0, cell[0], 20)  # first column
    x[60:80, 1] = origin[1] + rng.uniform(0, cell[1], 20)  # first row
    x[80:85] = origin - [0.3, 0.2]                          # beyond the corner: clipped in
    x0 = x - rng.choice([0.0, 1.0], (400, 1)) * [0.8, 0.0]
    gam = rng.choice([0.0, 0.05, 0.5], 400)
    got = intact_blocks(x, x0, gam, 0.5, origin, cell, shape)      # least block 1 m2: 5 cells
    assert got == _reference_blocks(x, x0, gam, 0.5, origin, cell, shape)
    for area in (0.24, 0.5, 0.96):                         # 1, 3 and 4 cells of 0.24 m2
        got = intact_blocks(x, x0, gam, 0.5, origin, cell, shape, min_area=area)
        assert got == _reference_blocks(x, x0, gam, 0.5, origin, cell, shape, min_area=area)
    assert got > 0 and got == intact_blocks(x, x0, gam, 0.5, origin, cell, shape, min_cells=4)


def test_slip_surface_height_uses_the_cell_width():
    """Columns of 0.5 m: column 0 (x = 0.25) slid above y = 0.25 (height 0.25), column 1
    (x = 0.75) slid entirely (height 0): mean 0.125 m.  With 1 m columns both points
    pairs would be one column of height 0."""
    x0 = np.array([[0.25, 0.25], [0.25, 0.75], [0.75, 0.25], [0.75, 0.75]])
    sliding = np.array([False, True, True, True])
    assert slip_surface_height(x0, sliding, 0.5) == pytest.approx(0.125, abs=1e-15)
    assert slip_surface_height(x0, sliding, 1.0) == 0.0


def test_compute_measures_bins_on_the_grid_and_its_cells():
    """Cells 0.5 x 1 m.  On a grid with origin (0.25, 0) the points at x = 0.45 and 1.05 lie
    in the touching cells 0 and 1: one body; binned from the origin 0 (no grid given) they
    lie in cells 0 and 2, an empty cell between, and the small one is stray.  The slip
    surface uses the cell width 0.5 (cell[0]), not its height."""
    grid = SimpleNamespace(origin=np.array([0.25, 0.0]), cell=np.array([0.5, 1.0]),
                           shape=(20, 10))
    x0 = np.array([[0.45, 0.5], [1.05, 0.5]])
    pts = _points(x0, x0, volume0=[1.0, 0.001])
    m = compute_measures(pts, 0.0, 0.5, grid.cell, None, grid=grid)
    assert m["excluded_stray_points"] == 0
    m0 = compute_measures(pts, 0.0, 0.5, grid.cell, None)
    assert m0["excluded_stray_points"] == 1
    x0 = np.array([[0.25, 0.25], [0.25, 0.75], [0.75, 0.25], [0.75, 0.75]])
    x = x0 + [[0.0, 0.0], [2.0, 0.0], [2.0, 0.0], [2.0, 0.0]]
    pts = _points(x0, x, volume0=np.full(4, 0.25))
    cell = np.array([0.5, 1.0])
    m = compute_measures(pts, 0.0, 0.5, cell, None)
    assert m["slip_surface_height"] == pytest.approx(0.125, abs=1e-15)


def test_retrogression_below_one_metre_and_the_empty_deposit():
    """Retrogression of 0.4 m is 0.4 m (not rounded up); with every point frozen the
    deposit is empty: not failed, run-out 0, maximum displacement 0, nothing counted."""
    x0 = np.array([[0.5, 0.5], [1.5, 0.5], [1.1, 0.5]])
    pts = _points(x0, x0 + [[0.0, 0.0], [2.0, 0.0], [2.0, 0.0]])
    m = compute_measures(pts, 0.0, 0.5, np.array([1.0, 1.0]), None)
    assert m["retrogression_distance"] == pytest.approx(1.5 - 1.1, abs=1e-12)
    tall = np.array([[0.5, 8.0], [1.5, 9.0]])                 # highest y above highest x
    frozen = _points(tall, tall + [5.0, 0.0], active=[False, False])
    m = compute_measures(frozen, 0.0, 0.5, np.array([1.0, 1.0]), None)
    assert (m["failed"], m["runout_distance"], m["max_displacement"]) == (False, 0.0, 0.0)
    assert m["excluded_frozen_points"] == 2 and m["final_profile"] == []


def test_early_sliding_area_per_point_and_strict_threshold():
    """Snapshot displacements 0, exactly 0.5 (the threshold: not moving) and 2 m of points
    away from the origin: only the last point's volume is the early sliding area."""
    grid = SimpleNamespace(origin=np.zeros(2), cell=np.array([1.0, 1.0]), shape=(20, 20))
    x0 = np.array([[3.0, 2.0], [5.0, 2.0], [7.0, 2.0]])
    xs = x0 + [[0.0, 0.0], [0.5, 0.0], [2.0, 0.0]]
    pts = _points(x0, xs, volume0=[0.1, 0.2, 0.4])
    g = np.zeros(3)
    m = compute_measures(pts, 0.0, 0.5, grid.cell, None, snapshots=[(3.0, xs, g)], grid=grid)
    assert m["sliding_area_early"] == pytest.approx(0.4, abs=1e-15)


def test_excluded_summary_rule_text():
    """The rule string written to summary.json, word for word."""
    m = {f"excluded_{w}_{k}": 0 for w in ("frozen", "stray") for k in ("points", "volume")}
    assert excluded_summary(m)["rule"] == (
        "frozen: frozen at the grid edge; stray: active but in no connected body "
        "(8-neighbour occupied grid cells) holding >= 1% of the active volume; "
        "volume = initial, m2/m")
