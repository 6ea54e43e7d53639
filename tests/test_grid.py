"""The background grid's geometry helpers (:mod:`fem_rmpm.discretise.grid`): which cells are soil or
bedrock, which nodes are fixed, and the cell centres, on large grids without testing every
cell against every polygon."""
from __future__ import annotations

import numpy as np
from matplotlib.path import Path as MplPath

from fem_rmpm.discretise.grid import Grid, _on_or_in_polygon, _structured_mesh, points_in_polygon

#: A concave polygon (an L with a notch), m.
POLY = np.array([[0.0, 0.0], [6.0, 0.0], [6.0, 1.5], [2.0, 1.5], [3.0, 3.0], [0.5, 4.0],
                 [0.0, 2.0]])


def test_points_in_polygon_agrees_with_matplotlib_away_from_the_edges():
    """Against an independent implementation (matplotlib's ``Path.contains_points``) on
    20 000 random points in a box 3x the polygon's, dropping the points within 1e-9 m of
    an edge (where the two rules may differ by rounding); most of the box lies outside
    the polygon's bounding box, which the bounding-box filter must get right too."""
    rng = np.random.default_rng(7)
    pts = rng.uniform([-6.0, -4.0], [12.0, 8.0], size=(20_000, 2))
    near_edge = np.zeros(len(pts), dtype=bool)
    for a, b in zip(POLY, np.roll(POLY, -1, axis=0)):
        ab = b - a
        t = np.clip(((pts - a) @ ab) / (ab @ ab), 0.0, 1.0)
        near_edge |= np.linalg.norm(pts - (a + t[:, None] * ab), axis=1) < 1e-9
    got = points_in_polygon(pts, POLY)
    want = MplPath(POLY).contains_points(pts)
    assert np.array_equal(got[~near_edge], want[~near_edge])
    assert 0.03 < got.mean() < 0.2                     # both inside and outside were tested


def test_on_or_in_polygon_includes_points_within_tol_beyond_the_bounding_box():
    """A point within ``tol`` of an edge counts, also where that is outside the polygon's
    bounding box (the filter's margin); one at 2 tol does not."""
    tol = 1e-3
    pts = np.array([[6.0 + 0.5 * tol, 0.7], [3.0, -0.5 * tol], [6.0 + 2 * tol, 0.7],
                    [3.0, -2 * tol], [1.0, 1.0]])
    assert _on_or_in_polygon(pts, POLY, tol).tolist() == [True, True, False, False, True]


def test_cell_centres_are_the_mean_of_the_cells_nodes_bitwise():
    """From the axes, bitwise the mean of each cell's four nodes in the mesh's order (the
    membership of a centre on a polygon edge must not change with how it is computed)."""
    origin, cell, shape = np.array([0.1, -3.7]), np.array([1 / 30, 0.07]), (37, 23)
    mesh = _structured_mesh(origin, cell, shape)
    want = mesh.p.T[mesh.t.T].mean(axis=1)
    grid = Grid(origin=origin, cell=cell, shape=shape, mesh=mesh,
                fixed=np.zeros((mesh.p.shape[1], 2), dtype=bool))
    assert np.array_equal(grid.cell_centres(), want)
    some = np.array([0, 5, 36, 37, 400, 37 * 23 - 1])
    assert np.array_equal(grid.cell_centres(some), want[some])
