"""``[random_field]`` in a three-dimensional scene: the realization of a seed on the
points (a pure function of scene and seed), the box rule (the same field on every mesh),
the strike scale ``theta_strike``, and the bad input refused with exit 2, one line,
nothing written: 3-D keys in a 2-D scene and the reverse, and a field over the memory
limit (from the embedding's estimate, before anything is allocated)."""
from __future__ import annotations

import tracemalloc
from pathlib import Path

import numpy as np
import pytest

from fem_rmpm import api
from fem_rmpm.cli import main
from fem_rmpm.random_field import model_from_spec_3d
from fem_rmpm.scene import load_scene, with_values
from tests.test_3d_scene import _bad as refused_run

MESHES = Path(__file__).parents[1] / "meshes"
SMALL = MESHES / "slope_small_3d.toml"
TEXT = SMALL.read_text()


def _bad(capsys, tmp_path, text, *words):
    """A seeded run of the scene ``text`` refused (:func:`tests.test_3d_scene._bad`)."""
    return refused_run(capsys, tmp_path, text, *words, seed=1)


def _cohesion(scene, seed):
    grid, pts = api.prepare(scene, seed)
    return grid, pts, pts.soil.cohesion_peak


def test_a_3d_realization_is_a_function_of_scene_and_seed():
    """The same seed draws the same cohesions bitwise, another seed others; the residual
    keeps the soil's residual/peak ratio and the compiled step's rows follow the drawn
    values; the median of ln c is the lognormal's m_ln (mean 20 kPa... here the soil's
    mean) within a few standard errors of the field's ~20 independent cells."""
    scene = load_scene(SMALL)
    _, pts, c = _cohesion(scene, 3)
    _, _, again = _cohesion(scene, 3)
    _, _, other = _cohesion(scene, 4)
    assert np.array_equal(c, again) and not np.allclose(c, other)
    so = scene.soils[0]
    ratio = so.value("cohesion_residual") / so.value("cohesion_peak")
    assert np.allclose(pts.soil.cohesion_residual / c, ratio, rtol=1e-12)
    assert np.array_equal(pts.plastic[:, 0], c) and np.allclose(pts.plastic[:, 1], ratio * c)
    rf = scene.random_field
    s_ln = np.sqrt(np.log(1 + rf.cov ** 2))
    m_ln = np.log(so.value("cohesion_peak")) - s_ln ** 2 / 2
    logs = np.log(np.concatenate([_cohesion(scene, k)[2] for k in range(8)]))
    assert abs(np.median(logs) - m_ln) < 3 * s_ln / np.sqrt(8 * 4)
    assert 0.3 * s_ln < logs.std() < 1.1 * s_ln     # local averaging lowers the variance


def test_points_of_one_grid_cell_share_its_field_value():
    """Without a box the field lattice is the grid over the soil cells: the 8 points of a
    cell take one value, neighbouring cells (mostly) others."""
    _, pts, c = _cohesion(load_scene(SMALL), 1)
    per_cell = [np.ptp(c[pts.cell0 == k]) for k in np.unique(pts.cell0)]
    assert max(per_cell) == 0.0
    assert len(np.unique(c)) == len(np.unique(pts.cell0))


def test_a_long_strike_scale_makes_the_field_constant_along_the_strike():
    """theta_strike twice the slope's strike: the six cells of an x-y column along the
    strike vary little (rho(dz) = exp(-2 dz / theta) >= 0.43 over the column, 0.85
    between neighbours: their spread of ln c is 0.24 of the field's, measured); a short
    one (a tenth of the cell) leaves them nearly independent: their spread is nearly that
    of the whole field (0.88, the six values' sample deviation).  The model's strike
    scale is the key's value, else theta_h."""
    scene = load_scene(SMALL)
    rf = scene.random_field
    assert model_from_spec_3d(rf).theta_z == rf.theta_strike
    assert model_from_spec_3d(with_values(scene, {"random_field.theta_strike": None})
                              .random_field).theta_z == rf.anisotropy * rf.theta_v

    def spread_along_strike(theta):
        sc = with_values(scene, {"random_field.theta_strike": theta})
        _, pts, c = _cohesion(sc, 2)
        key = np.round(pts.x0[:, :2], 6)
        _, inv = np.unique(key, axis=0, return_inverse=True)
        ln = np.log(c)
        return np.mean([np.std(ln[inv.ravel() == k]) for k in range(inv.max() + 1)]), ln.std()

    long_z, total_long = spread_along_strike(6.0)
    short_z, total_short = spread_along_strike(0.05)
    assert long_z < 0.4 * total_long
    assert short_z > 0.7 * total_short


def test_box_rule_draws_the_same_field_on_two_meshes():
    """With box and cell_size the field lives on a fixed lattice: a point at the same place
    on the 0.5 m and on the 0.25 m grid takes the same value (realization i is the same
    field on every mesh)."""
    scene = with_values(load_scene(SMALL), {"random_field.cell_size": 0.5,
                                            "random_field.box": [0.0, 0.0, 0.0, 6.0, 2.0, 3.0]})
    _, coarse, c1 = _cohesion(scene, 7)
    _, fine, c2 = _cohesion(with_values(scene, {"grid.cell": 0.25}), 7)
    lattice_cell = lambda x: tuple(map(tuple, np.floor(x / 0.5).astype(int)))   # noqa: E731
    a = dict(zip(lattice_cell(coarse.x0), c1))
    b = dict(zip(lattice_cell(fine.x0), c2))
    common = set(a) & set(b)
    assert len(common) > 0.9 * len(a)
    assert all(a[k] == b[k] for k in common)


def test_run_of_a_3d_scene_with_a_seed_records_it(tmp_path):
    """``fem-rmpm run`` of the 3-D scene with ``--seed``: summary.json records the seed and
    the run's measures; the same seed again gives the same measures bitwise."""
    import json

    scene = with_values(load_scene(SMALL), {"solver.t_end": 0.5, "solver.geostatic_time": 0.3})
    runs = []
    for k in (1, 2):
        out = tmp_path / f"r{k}"
        runs.append(api.run(scene, out=out, seed=11, vtk=False))
        s = json.loads((out / "summary.json").read_text())
        assert s["seed"] == 11 and s["dimension"] == 3 and s["status"] == "ok"
    assert runs[0].measures["max_displacement"] == runs[1].measures["max_displacement"]
    assert np.array_equal(runs[0].particles.x, runs[1].particles.x)


@pytest.mark.parametrize("old, new, key", [
    ("theta_strike = 2.0", "theta_strike = 2.0\nbox = [0.0, 0.0, 6.0, 2.0]\ncell_size = 0.5",
     "random_field.box"),
    ('property = "cohesion_peak"', 'property = "poisson_ratio"', "random_field.property"),
    ("theta_strike = 2.0", 'theta_strike = 2.0\ndata = "cpt.csv"', "random_field.data"),
    ("theta_strike = 2.0", "theta_strike = -1.0", "random_field.theta_strike"),
    ("theta_strike = 2.0", "theta_strike = 2.0\nbox = [0.0, 0.0, 0.0, 6.0, 2.0, -3.0]\n"
     "cell_size = 0.5", "random_field.box"),
])
def test_bad_3d_field_keys_exit_2(capsys, tmp_path, old, new, key):
    assert old in TEXT
    _bad(capsys, tmp_path, TEXT.replace(old, new), f"[{key}]")


@pytest.mark.parametrize("line, key", [
    ("theta_strike = 3.0", "random_field.theta_strike"),
    ("box = [0.0, 0.0, 0.0, 60.0, 5.0, 1.0]", "random_field.box"),
])
def test_3d_field_keys_in_a_2d_scene_exit_2(capsys, tmp_path, line, key):
    text = (MESHES / "slope_risk.toml").read_text().replace(
        "box = [0.0, 0.0, 60.5, 5.0]", line)
    _bad(capsys, tmp_path, text, f"[{key}]")


def test_a_3d_field_over_the_memory_limit_exits_2_at_once(capsys, tmp_path):
    """A 1 cm field lattice over the small slope's box: ~1.7e9 embedding points, refused
    from the estimate (arithmetic) with the estimate in the line, before anything is
    allocated: the command's peak of traced memory stays below 16 MiB (0.1 MiB measured)
    against the tens of GiB the field would take."""
    text = TEXT.replace("theta_strike = 2.0", "theta_strike = 2.0\ncell_size = 0.01\n"
                        "box = [0.0, 0.0, 0.0, 14.0, 4.0, 3.0]")
    tracemalloc.start()
    try:
        err = _bad(capsys, tmp_path, text, "[random_field.cell_size]", "memory limit", "GiB",
                   "bad.toml")
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 16 * 2**20, (peak, err)
