"""Exact properties of the random field's point lookup and data argument, written out so
that mutation testing (``python validation/mutation.py random_field``; survivors listed
in validation/mutation_survivors.md) finds them checked.

References written out here: a point's field cell is the field cell that contains its
initial position (:meth:`FieldLayout.locate`, plain geometry) — also when the field's
soil starts away from the grid origin, where the grid-cell shortcut must subtract the
field's offset (i0, j0) in grid cells; measurements passed as a
:class:`~fem_rmpm.random_field.Measurements` object condition the field exactly as the
CSV file they were read from.
"""
from __future__ import annotations

import numpy as np

from fem_rmpm import random_field as rf
from fem_rmpm.discretise.grid import make_grid
from fem_rmpm.discretise.points import seed_particles
from fem_rmpm.random_field.points import _point_field_index
from fem_rmpm.scene import scene_from_dict


def _block(polygon):
    """A von Mises clay block (``polygon``, m) in a 12 x 5 m grid of 0.25 m cells, with a
    Markov field of its peak cohesion (mean 20 kPa, COV 0.25, theta_v 0.5 m, xi 4)."""
    return scene_from_dict({
        "scene": {"name": "rf_offsets"},
        "grid": {"origin": [0.0, 0.0], "size": [12.0, 5.0], "cell": [0.25, 0.25]},
        "soil": [{"name": "clay", "polygon": polygon, "unit_weight": 20.0,
                  "youngs_modulus": 1000.0, "poisson_ratio": 0.33,
                  "model": "von_mises_softening", "cohesion_peak": 20.0,
                  "cohesion_residual": 4.0, "softening_strain": 0.5}],
        "random_field": {"cov": 0.25, "theta_v": 0.5, "anisotropy": 4.0},
    })


def test_points_take_the_field_cell_they_lie_in_away_from_the_grid_origin():
    """A soil block from (2, 1) to (10, 4) m: the field starts 8 grid cells right of and 4
    above the grid origin; every point's field index (the grid-cell shortcut) is the field
    cell that contains it, and the points' cohesion is the field's value there."""
    scene = _block([[2.0, 1.0], [10.0, 1.0], [10.0, 4.0], [2.0, 4.0]])
    grid = make_grid(scene)
    pts = seed_particles(scene, grid)
    layout = rf.field_layout(scene, grid)
    assert layout.grid_offset == (8, 4) and layout.shape == (32, 12)
    where, inside = layout.locate(pts.x0)
    assert inside.all()
    assert np.array_equal(_point_field_index(layout, grid, pts), where)
    z = rf.gaussian_field(scene, grid, 3, None, layout).ravel()
    c = rf.gaussian_to_property(z, 20.0, scene.random_field)
    values = rf.sample_point_property(scene, grid, pts, 3)
    assert np.array_equal(values, c[where])


def test_measurements_object_conditions_like_its_csv(tmp_path):
    """``data`` given as the Measurements read from a CSV gives bitwise the field that the
    CSV's path gives, and it is conditioned (the measured cell holds 31 kPa to 1e-8)."""
    scene = _block([[0.0, 0.0], [12.0, 0.0], [12.0, 5.0], [0.0, 5.0]])
    csv = tmp_path / "cpt.csv"
    csv.write_text("x,y,value\n5.1,0.6,31.0\n7.3,2.1,26.0\n")
    grid = make_grid(scene)
    layout = rf.field_layout(scene, grid)
    by_path = rf.gaussian_field(scene, grid, 1, str(csv), layout)
    by_object = rf.gaussian_field(scene, grid, 1, rf.read_measurements(csv), layout)
    assert np.array_equal(by_object, by_path)
    cell, _ = layout.locate(np.array([[5.1, 0.6]]))
    c = rf.gaussian_to_property(by_object.ravel(), 20.0, scene.random_field)
    assert abs(c[cell[0]] - 31.0) < 1e-8
