"""Separate slides along the strike on synthetic point sets with known answers (the
slides are placed by construction: their count, strike ranges and volumes are exact)."""
from __future__ import annotations

import numpy as np
import pytest

from fem_rmpm.measures.slides3d import displaced_points, slides_along_strike


def _slope(length=40.0, h=0.5):
    """Points on a 0.5 m lattice over x in [0, 10], y in [0, 4], z in [0, length] m, each
    of 0.125 m3."""
    g = np.arange(h / 2, 10, h), np.arange(h / 2, 4, h), np.arange(h / 2, length, h)
    x0 = np.stack(np.meshgrid(*g, indexing="ij"), -1).reshape(-1, 3)
    return x0, h ** 3


def _move(x0, ranges, dx=2.0):
    x = x0.copy()
    for z0, z1 in ranges:
        sel = (x0[:, 2] > z0) & (x0[:, 2] < z1) & (x0[:, 0] > 5.0)
        x[sel, 0] += dx
    return x


def test_two_separate_slides_with_their_lengths_and_volumes():
    x0, v = _slope()
    x = _move(x0, [(5.0, 12.0), (25.0, 31.0)])
    disp = displaced_points(x0, x, 0.1)
    slides = slides_along_strike(x0[:, 2], v, disp, bin_width=0.5, z_range=(0, 40))
    assert len(slides) == 2
    a, b = slides
    assert (a.z0, a.z1) == (5.25, 11.75) and (b.z0, b.z1) == (25.25, 30.75)
    assert a.length == pytest.approx(6.5) and b.length == pytest.approx(5.5)
    # 10 x 8 points per z row (x > 5: 10 columns, 8 rows) of 0.125 m3; 14 and 12 z rows
    assert a.volume == pytest.approx(10 * 8 * 14 * v) and b.volume == pytest.approx(10 * 8 * 12 * v)
    assert a.points == 10 * 8 * 14


def test_one_slide_along_the_whole_slope_and_none_at_rest():
    x0, v = _slope()
    x = _move(x0, [(-1.0, 41.0)])
    slides = slides_along_strike(x0[:, 2], v, displaced_points(x0, x, 0.1), 0.5)
    assert len(slides) == 1 and slides[0].length == pytest.approx(39.5)
    assert slides_along_strike(x0[:, 2], v, displaced_points(x0, x0, 0.1), 0.5) == []


def test_a_narrow_gap_is_bridged_only_when_asked():
    """Slides at z in (5, 10) and (10.6, 15) m leave one empty 0.5 m bin between them:
    two slides with gap_bins = 1, one with gap_bins = 2."""
    x0, v = _slope()
    x = _move(x0, [(5.0, 10.0), (10.6, 15.0)])
    disp = displaced_points(x0, x, 0.1)
    assert len(slides_along_strike(x0[:, 2], v, disp, 0.5, gap_bins=1)) == 2
    one = slides_along_strike(x0[:, 2], v, disp, 0.5, gap_bins=2)
    assert len(one) == 1 and one[0].volume == pytest.approx(disp.sum() * v)


def test_sparse_stray_points_do_not_make_a_slide_with_min_points():
    x0, v = _slope()
    x = _move(x0, [(5.0, 12.0)])
    stray = np.nonzero(np.isclose(x0[:, 2], 30.25) & np.isclose(x0[:, 0], 0.25))[0][:2]
    x[stray, 1] += 1.0
    disp = displaced_points(x0, x, 0.1)
    assert len(slides_along_strike(x0[:, 2], v, disp, 0.5)) == 2
    assert len(slides_along_strike(x0[:, 2], v, disp, 0.5, min_points=5)) == 1


def test_bad_input():
    with pytest.raises(ValueError, match="bin_width must be positive"):
        slides_along_strike([0.0], 1.0, [True], 0.0)
    with pytest.raises(ValueError, match="differ in length"):
        slides_along_strike([0.0, 1.0], 1.0, [True], 0.5)
