"""The memory layouts the explicit kernels are compiled for: the column counts they promise
the compiler (``fem_rmpm.runtime.compiled.assume_columns``, undefined behaviour if false, so checked
when the arrays are bound) and the column-major material rows and state."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from fem_rmpm import api
from fem_rmpm.materials.points import new_state
from fem_rmpm.scene import load_scene, with_values
from fem_rmpm.schemes.explicit.kernels.arrays import FIXED_COLUMNS, point_arrays

SCENE = Path(__file__).resolve().parents[1] / "meshes" / "slope_reference.toml"


@pytest.fixture(scope="module")
def points():
    scene = with_values(load_scene(SCENE), {"grid.cell": [1.0, 1.0]})
    return api.prepare(scene)[1]


@pytest.mark.parametrize("name", sorted(FIXED_COLUMNS))
def test_binding_refuses_a_column_count_the_kernels_would_assume_wrongly(points, name):
    """Every promised count is checked: an array with one column more is refused with its
    name and shape (else the kernels would index it with the wrong stride, silently)."""
    attr = {"v": "velocity", "u_geo": "u_geostatic"}.get(name, name)
    pts = points.copy()
    a = getattr(pts, attr)
    setattr(pts, attr, np.zeros((a.shape[0], FIXED_COLUMNS[name] + 1)))
    with pytest.raises(ValueError, match=rf"point array {name} has shape .* needs \(n, "
                                         rf"{FIXED_COLUMNS[name]}\)"):
        point_arrays(pts, np.zeros((pts.n, 2)))
    point_arrays(points, np.zeros((points.n, 2)))          # the seeded points bind


def test_material_rows_and_state_stay_column_major(points):
    """Parameter rows and state are column-major as seeded, after ``replace`` / ``take``
    (a random field, a subset) and after a copy of the points, so the kernels compiled for
    that layout are the ones every run uses (a row-major array would compile, and stream
    whole rows, again)."""
    soil = points.soil
    assert soil.params.flags.f_contiguous and points.state.flags.f_contiguous
    assert soil.replace(cohesion_peak=np.full(len(soil), 30.0)).params.flags.f_contiguous
    assert soil.take(np.arange(0, len(soil), 3)).params.flags.f_contiguous
    assert new_state(soil).flags.f_contiguous
    copy = points.copy()
    assert copy.soil.params.flags.f_contiguous and copy.state.flags.f_contiguous
    assert np.array_equal(copy.soil.params, soil.params, equal_nan=True)
