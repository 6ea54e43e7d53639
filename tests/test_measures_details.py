"""Exact checks of each measure on hand-made point sets (they also serve mutation testing:
``python validation/mutation.py measures``). Every expected value is worked out in the test
from the definitions in :mod:`fem_rmpm.measures.table` and :mod:`fem_rmpm.measures.deposit`:
which points count (8-neighbour bodies of occupied cells, >= 1 % of the active volume, the
largest always), sliding (counted and moved more than the threshold, strictly), run-out,
retrogression, slip surface height, intact blocks (4-neighbour, >= 4 cells, gamma_p < 0.1
strictly) and the surface profiles.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from fem_rmpm.discretise.points import Particles
from fem_rmpm.materials import MaterialPoints, model_id
from fem_rmpm.measures.blocks import intact_blocks
from fem_rmpm.measures.deposit import (
    MIN_BODY_FRACTION,
    compute_measures,
    deposit_points,
    excluded_summary,
)
from fem_rmpm.measures.geometry import crest_position, slip_surface_height, surface_profile


def _points(x0, x=None, volume0=None, active=None) -> Particles:
    x0 = np.asarray(x0, float)
    n = len(x0)
    x = x0.copy() if x is None else np.asarray(x, float)
    v0 = np.full(n, 0.25) if volume0 is None else np.asarray(volume0, float)
    soil = MaterialPoints(np.full(n, model_id("linear_elastic")),
                          np.tile([100.0, 200.0], (n, 1)))
    return Particles(x=x, x0=x0, velocity=np.zeros((n, 2)), mass=np.ones(n), volume0=v0,
                     volume=v0.copy(), log_strain=np.zeros((n, 4)), stress=np.zeros((n, 4)),
                     state=np.zeros((n, 1)), soil=soil, soil_id=np.zeros(n, dtype=np.int64),
                     cell0=np.zeros(n, dtype=np.int64),
                     active=np.ones(n, bool) if active is None else np.asarray(active, bool))


def _block(x_lo, x_hi, y_lo, y_hi, step=0.5):
    """Points at the centres of step x step squares filling the rectangle."""
    xs = np.arange(x_lo + step / 2, x_hi, step)
    ys = np.arange(y_lo + step / 2, y_hi, step)
    return np.array([(a, b) for a in xs for b in ys])


# --------------------------------------------------------------- the parts
def test_surface_profile_bins_and_tops():
    """Bins of width w from floor(X / w): centres (k + 1/2) w in increasing order (also
    for negative X), top = max Y of the bin."""
    X = np.array([[-0.3, 1.0], [0.2, 3.0], [0.4, 5.0], [2.2, -1.0], [-0.9, 4.0]])
    assert surface_profile(X, 0.5) == [(-0.75, 4.0), (-0.25, 1.0), (0.25, 5.0), (2.25, -1.0)]
    assert surface_profile(np.zeros((0, 2)), 0.5) == []


def test_crest_is_the_most_down_slope_point_of_the_top_layer():
    """Top layer = initial y within one cell height of the highest point (strictly)."""
    x0 = [[0.0, 5.0], [3.0, 4.9], [4.0, 4.5], [9.0, 1.0], [2.0, 4.76]]
    pts = _points(x0)
    assert np.array_equal(crest_position(pts, 0.25), [3.0, 4.9])
    assert np.array_equal(crest_position(pts, 0.6), [4.0, 4.5])


def test_slip_surface_height_per_column():
    """Columns of width 1: column 0 slides above y = 2 (stayed at 0.5, 1.5 and at y = 2
    itself, which is not below the lowest sliding point): height 1.5; column 1 slid
    entirely: 0; column 2 did not slide: not averaged.  Mean 0.75."""
    x0 = np.array([[0.5, 0.5], [0.5, 1.5], [0.2, 2.0], [0.5, 2.0], [0.5, 3.0],
                   [1.5, 0.5], [1.5, 1.5], [2.5, 0.5], [2.5, 1.5]])
    sliding = np.array([0, 0, 0, 1, 1, 1, 1, 0, 0], bool)
    assert slip_surface_height(x0, sliding, 1.0) == pytest.approx(0.75, abs=1e-15)
    assert slip_surface_height(x0, np.zeros(9, bool), 1.0) == 0.0


def test_intact_blocks_counts_4_neighbour_groups_of_4_cells():
    """Least block 4 m2 = 4 cells of 1 m (the default 1 m2 would be one cell here).
    Grid 10 x 10 of 1 m cells: a 2 x 2 group (1 block); an L of 3 cells (too small);
    two 2-cell groups touching only at a corner (not connected: 0); points with gamma_p
    = 0.1 or a displacement equal to the threshold do not count; a point below the grid
    is clipped into its bottom row (one beyond the right edge into the last column),
    completing a line of 4 cells."""
    x0 = []
    for c in [(1, 1), (1, 2), (2, 1), (2, 2)]:                   # block
        x0.append(c)
    for c in [(6, 1), (6, 2), (7, 1)]:                           # L of 3
        x0.append(c)
    for c in [(1, 6), (2, 6), (3, 7), (4, 7)]:                   # corner contact only
        x0.append(c)
    x0 = np.array(x0, float) + 0.5
    moved = np.array([[0.0, 0.6]] * len(x0))
    gam = np.zeros(len(x0))
    args = (np.zeros(2), np.ones(2), (10, 10), 0.1, None, 4.0)
    assert intact_blocks(x0 + moved, x0, gam, 0.5, *args) == 1
    assert intact_blocks(x0 + moved, x0, gam, 0.5, *args[:3], min_cells=4) == 1
    assert intact_blocks(x0 + moved, x0, gam, 0.5, *args[:3], min_cells=3) == 2   # + the L
    line0 = np.array([[6.5, 5.0], [7.5, 5.0], [8.5, 5.0], [9.5, 5.0]])
    line = np.array([[6.5, 0.5], [7.5, 0.5], [8.5, -3.0], [12.0, 0.5]])   # cells (6..9, 0)
    assert intact_blocks(line, line0, np.zeros(4), 0.5, *args) == 1
    assert intact_blocks(line[:3], line0[:3], np.zeros(3), 0.5, *args) == 0
    g = gam.copy()
    g[0] = 0.1                                                   # no longer intact
    assert intact_blocks(x0 + moved, x0, g, 0.5, *args) == 0
    assert intact_blocks(x0 + [[0.0, 0.5]], x0, gam, 0.5, *args) == 0   # not > threshold
    assert intact_blocks(x0, x0, gam, 0.5, *args) == 0


def test_least_intact_block_is_an_area_the_same_on_every_mesh():
    """One sliding, intact 2 x 1.5 m slab (3 m2) and one 1 x 0.5 m fragment (0.5 m2), with
    4 x 4 points per 0.125 m cell, binned on grids of 0.5, 0.25 and 0.125 m cells: the
    default least block (1 m2 = 4 / 16 / 64 cells) counts the slab only, on every mesh.
    The old 4-cell rule counts 1 / 2 / 2 (the fragment is 2 cells at 0.5 m, 8 at
    0.25 m): finer meshes counted smaller fragments.  Also: 1 m2 is exactly 16 cells of
    0.25 m (no rounding up to 17); a cell larger than the area still needs one cell."""
    from fem_rmpm.measures.blocks import INTACT_BLOCK_AREA, least_cells
    assert INTACT_BLOCK_AREA == 1.0
    assert [least_cells(1.0, [h, h]) for h in (0.5, 0.25, 0.125)] == [4, 16, 64]
    assert least_cells(1.0, [0.6, 0.4]) == 5 and least_cells(0.1, [0.5, 0.5]) == 1
    q = (np.arange(4) + 0.5) / 32.0
    slab = np.array([(a, b) for a in np.arange(0, 2, 0.125) for b in np.arange(0, 1.5, 0.125)])
    frag = np.array([(a, b) for a in np.arange(4, 5, 0.125) for b in np.arange(0, 0.5, 0.125)])
    x0 = np.concatenate([c + np.stack(np.meshgrid(q, q), -1).reshape(-1, 2)
                         for c in np.concatenate([slab, frag])]) + [0.0, 0.25]
    x = x0 + [0.0, 0.75]                                   # moved more than 0.5 m
    gam = np.zeros(len(x0))
    old = []
    for h in (0.5, 0.25, 0.125):
        grid = (np.zeros(2), np.array([h, h]), (int(8 / h), int(8 / h)))
        assert intact_blocks(x, x0, gam, 0.5, *grid) == 1, h
        old.append(intact_blocks(x, x0, gam, 0.5, *grid, min_cells=4))
    assert old == [1, 2, 2]


def test_deposit_bodies_stray_points_and_the_origin():
    """Cells of 1 m: a 4 x 2 m body (32 points); a small point (0.1 % of the volume) 2 m
    beyond it (two empty cells between): stray; a point touching the body's corner cell
    diagonally: counted (8 neighbours); a frozen point: neither; a separate group of 2 %
    of the volume: a body; one of 0.8 %: stray."""
    body = _block(0, 4, 0, 2)                                   # 32 points of 0.25 m2
    pts = np.vstack([body, [[6.5, 0.5]], [[4.5, 2.5]], [[3.5, 1.5]]])
    vol = np.full(len(pts), 0.25)
    vol[32] = 0.008
    active = np.ones(len(pts), bool)
    active[-1] = False
    counted, stray = deposit_points(pts, vol, active, np.zeros(2), np.ones(2))
    assert counted[:32].all() and stray.tolist()[32:] == [True, False, False]
    assert counted.tolist()[32:] == [False, True, False]
    assert not (counted & stray).any()
    # a second group 3 cells away: a body above 1 % of the active volume, stray below
    total = vol[active].sum()
    for frac, is_body in ((0.02, True), (0.008, False)):
        far = np.vstack([body, [[9.5, 0.5]]])
        v = np.r_[np.full(32, 0.25), frac / (1 - frac) * 8.0]
        c, s = deposit_points(far, v, np.ones(33, bool), np.zeros(2), np.ones(2))
        assert c[32] == is_body and s[32] == (not is_body), frac
    assert MIN_BODY_FRACTION == 0.01 and total > 0
    # the origin sets the cell boundaries: x = 0.4 and 1.9 touch with origin 0 (cells 0, 1)
    two = np.array([[0.4, 0.5], [1.9, 0.5]])
    big = np.array([1.0, 0.001])
    c0, _ = deposit_points(two, big, np.ones(2, bool), np.zeros(2), np.ones(2))
    c1, s1 = deposit_points(two, big, np.ones(2, bool), np.array([0.5, 0.0]), np.ones(2))
    assert c0.tolist() == [True, True] and c1.tolist() == [True, False] and s1[1]
    # the largest group always counts (here below the fraction: only one group)
    c, _ = deposit_points(two[:1], big[:1], np.ones(1, bool), np.zeros(2), np.ones(2),
                          min_body_fraction=2.0)
    assert c.tolist() == [True]
    none = deposit_points(two, big, np.zeros(2, bool), np.zeros(2), np.ones(2))
    assert not none[0].any() and not none[1].any()


def test_excluded_summary_layout():
    m = {"excluded_frozen_points": 2, "excluded_frozen_volume": 0.5,
         "excluded_stray_points": 3, "excluded_stray_volume": 0.75}
    out = excluded_summary(m)
    assert out["frozen"] == {"points": 2, "volume": 0.5}
    assert out["stray"] == {"points": 3, "volume": 0.75}
    assert "holding >= 1% of the active volume" in out["rule"]


# --------------------------------------------------------------- every measure at once
def test_compute_measures_of_a_hand_made_slide():
    """A 10 m x 2 m layer (points every 0.5 m, 0.25 m2 each) in a 0 deg frame; the part
    x0 > 6 m moves 3 m down-slope (sliding), the part 4 < x0 < 6 m 0.5 m (exactly the
    threshold: not sliding); a stray point is thrown 5 m beyond; one point is frozen.
    Expected: failed; sliding area 8 x 4 x 0.25 = 8 m2 (the frozen and stray points
    excluded); run-out = front 13 - 10 = 3 m (the stray point ignored); crest = the most
    down-slope top-layer point (9.75, 1.75): retrogression 9.75 - 6.25 = 3.5 m;
    max displacement 3 m; slip surface height 0 (whole columns slid); profiles.
    (The stray point's current volume is 0.01 m2, so it is no body of its own.)"""
    x0 = _block(0, 10, 0, 2)
    x = x0.copy()
    slide = x0[:, 0] > 6.0
    x[slide, 0] += 3.0
    x[(x0[:, 0] > 4.0) & (x0[:, 0] < 6.0), 0] += 0.5
    stray = int(np.nonzero(slide & (x0[:, 1] > 1.5))[0][-1])
    x[stray] = [18.0, 0.25]
    frozen = int(np.nonzero(slide & (x0[:, 1] < 0.5))[0][0])
    x[frozen] = [30.0, 0.0]
    active = np.ones(len(x0), bool)
    active[frozen] = False
    pts = _points(x0, x, active=active)
    pts.volume[stray] = 0.01          # now 0.05 % of the active volume: below a body's 1 %
    m = compute_measures(pts, 0.0, 0.5, np.array([1.0, 1.0]), time_to_rest=7.5)
    assert m["failed"] is True
    assert m["sliding_area"] == pytest.approx((slide.sum() - 2) * 0.25, rel=1e-14, abs=0)
    assert m["runout_distance"] == pytest.approx(13.0 - 0.25 - 9.75, abs=1e-12)
    assert m["retrogression_distance"] == pytest.approx(9.75 - 6.25, abs=1e-12)
    assert m["max_displacement"] == pytest.approx(3.0, abs=1e-12)
    assert m["slip_surface_height"] == 0.0
    assert m["time_to_rest"] == 7.5 and m["failure_displacement"] == 0.5
    assert (m["excluded_frozen_points"], m["excluded_stray_points"]) == (1, 1)
    assert m["excluded_frozen_volume"] == m["excluded_stray_volume"] == 0.25
    assert m["intact_blocks"] is None and m["sliding_area_early"] is None
    assert m["mechanism_time"] == 3.0
    assert m["initial_profile"][0] == (0.5, 1.75) and m["initial_profile"][-1] == (9.5, 1.75)
    assert m["final_profile"][-1] == (12.5, 1.75)
    assert all(abs(xc - (k + 0.5)) < 1e-12 for k, (xc, _) in enumerate(m["initial_profile"]))


def test_compute_measures_in_a_rotated_frame_and_without_failure():
    """Frame angle 30 deg: X = x cos a + y sin a.  A rigid shift of 0.4 m (< threshold):
    not failed, area and retrogression 0, run-out = the shift's true-horizontal part."""
    x0 = _block(0, 4, 0, 1)
    pts = _points(x0, x0 + [0.4, 0.0])
    m = compute_measures(pts, 30.0, 0.5, np.array([1.0, 1.0]), None)
    a = math.radians(30.0)
    assert not m["failed"] and m["sliding_area"] == 0.0 and m["retrogression_distance"] == 0.0
    assert m["runout_distance"] == pytest.approx(0.4 * math.cos(a), abs=1e-12)
    assert m["max_displacement"] == pytest.approx(0.4, abs=1e-12)
    back = _points(x0, x0 - [2.0, 0.0])
    assert compute_measures(back, 0.0, 0.5, np.array([1.0, 1.0]), None)["runout_distance"] == 0.0


def test_mechanism_measures_use_the_snapshot_nearest_the_mechanism_time():
    """Snapshots at 1, 2.9 and 6 s: the one at 2.9 s is used (nearest to 3 s): its
    displacement gives sliding_area_early (frozen points excluded) and its points the
    intact blocks (one 2 x 2 m block of intact sliding points = 16 cells of 0.5 m)."""
    from types import SimpleNamespace
    x0 = _block(0, 2, 0, 2)
    grid = SimpleNamespace(origin=np.zeros(2), cell=np.array([0.5, 0.5]), shape=(20, 20))
    moved = x0 + [1.0, 0.0]
    active = np.ones(len(x0), bool)
    active[0] = False
    pts = _points(x0, moved, active=active)
    g = np.zeros(len(x0))
    snaps = [(1.0, x0, g), (2.9, moved, g), (6.0, x0 + [4.0, 0.0], g + 1.0)]
    m = compute_measures(pts, 0.0, 0.5, grid.cell, None, snapshots=snaps, grid=grid)
    assert m["sliding_area_early"] == pytest.approx((len(x0) - 1) * 0.25, rel=1e-14, abs=0)
    assert m["intact_blocks"] == 1
    m2 = compute_measures(pts, 0.0, 0.5, grid.cell, None, snapshots=snaps, grid=grid,
                          mechanism_time=5.0)
    assert m2["intact_blocks"] == 0 and m2["mechanism_time"] == 5.0   # 6 s: all softened
