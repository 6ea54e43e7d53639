"""Three-dimensional scenes: the grid keys' shapes, the extrusion keys, and every
inconsistent or not-yet-supported combination refused on the command line with exit 2,
one line naming the key, nothing written; a 3-D scene over the memory limit is refused
from its estimate before anything is allocated."""
from __future__ import annotations

import tracemalloc
from pathlib import Path

import pytest

from fem_rmpm.cli import main
from fem_rmpm.runtime.budget import estimate_run
from fem_rmpm.scene import load_scene, scene_from_dict, scene_to_dict, with_values

MESHES = Path(__file__).parents[1] / "meshes"
COLUMN = (MESHES / "column_3d.toml").read_text()


def _bad(capsys, tmp_path, text, *words, seed: int | None = None):
    """``fem-rmpm run`` (with ``--seed`` when given) of the scene ``text``: exit 2, one
    line holding every one of ``words``, nothing written; returns the line."""
    path = tmp_path / "bad.toml"
    path.write_text(text)
    out = tmp_path / "out"
    seeded = [] if seed is None else ["--seed", str(seed)]
    code = main(["run", str(path), "--out", str(out), "--quiet", *seeded])
    err = capsys.readouterr().err.strip()
    assert code == 2, err
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    for w in words:
        assert w in err, err
    assert not out.exists()
    return err


def test_three_sizes_make_a_3d_grid_with_default_origin_and_cubic_cells():
    scene = load_scene(MESHES / "column_3d.toml")
    assert scene.grid.dimension == 3 and scene.grid.cell == (0.25, 0.25, 0.25)
    data = scene_to_dict(scene)
    del data["grid"]["origin"]
    again = scene_from_dict(data)
    assert again.grid.origin == (0.0, 0.0, 0.0) and again == scene_from_dict(scene_to_dict(
        scene))
    changed = with_values(scene, {"solver.cfl": 0.4})    # the --set round trip keeps 3-D
    assert changed.grid == scene.grid and changed.solver.cfl == 0.4


@pytest.mark.parametrize("old, new, key", [
    ("cell = 0.25               # m (cubic cells)", "cell = [0.25, 0.25]", "grid.cell"),
    ("origin = [0.0, 0.0, 0.0]  # m", "origin = [0.0, 0.0]", "grid.origin"),
    ("size = [0.25, 5.5, 0.25]", "size = [0.25, 5.5, 0.25, 1.0]", "grid.size"),
    ("size = [0.25, 5.5, 0.25]", "size = [0.25, 5.5, 0.3]", "grid.cell"),
    ('model = "linear_elastic"', 'model = "von_mises_softening"\ncohesion_peak = 20.0\n'
     'cohesion_residual = 4.0\nregularisation = "nonlocal"', "soil[0].regularisation"),
    ('scheme = "explicit"', 'scheme = "implicit"', "solver.scheme"),
    ("cfl = 0.5", 'cfl = 0.5\nshape = "gimp"', "solver.shape"),
    ("cfl = 0.5", "cfl = 0.5\nfbar = true", "solver.fbar"),
    ('name = "clay"', 'name = "clay"\nstrike = [0.2, 0.1]', "soil[0].strike"),
    ('name = "clay"', 'name = "clay"\nplan = [[0, 0], [9, 0], [9, 9]]', "soil[0].plan"),
    ('polygon = [[0.0, 0.0], [0.25, 0.0], [0.25, 5.0], [0.0, 5.0]]',
     'polygon = [[0.0, 0.0, 0.0], [0.25, 0.0, 0.0], [0.25, 5.0, 0.0]]', "soil.polygon"),
    ('front = "roller"', 'front = "glued"', "boundary.front"),
])
def test_inconsistent_or_unsupported_3d_scene_exits_2(capsys, tmp_path, old, new, key):
    assert old in COLUMN
    _bad(capsys, tmp_path, COLUMN.replace(old, new), f"[{key}")


def test_a_3d_random_field_of_a_property_the_3d_points_do_not_read_is_refused(capsys,
                                                                               tmp_path):
    text = COLUMN + "\n[random_field]\nproperty = \"youngs_modulus\"\n"
    _bad(capsys, tmp_path, text, "[random_field.property]", "three-dimensional",
         "'cohesion_peak'")


@pytest.mark.parametrize("line, key", [("front = \"roller\"", "boundary.front"),
                                       ("strike = [0.0, 1.0]", "soil[0].strike")])
def test_3d_keys_in_a_2d_scene_exit_2(capsys, tmp_path, line, key):
    text = (MESHES / "column.toml").read_text()
    anchor = 'top = "free"' if key.startswith("boundary") else 'name = "clay"'
    _bad(capsys, tmp_path, text.replace(anchor, anchor + "\n" + line), f"[{key}]",
         "three-dimensional")


def test_huge_3d_scene_is_refused_at_once_with_its_estimate(capsys, tmp_path):
    """10^12 cells: refused from the scene's arithmetic before anything is allocated (the
    command's peak of traced memory below 16 MiB, 0.1 MiB measured, against the TiB of the
    estimate)."""
    text = COLUMN.replace("size = [0.25, 5.5, 0.25]", "size = [1000.0, 5.5, 1000.0]").replace(
        "[[0.0, 0.0], [0.25, 0.0], [0.25, 5.0], [0.0, 5.0]]",
        "[[0.0, 0.0], [1000.0, 0.0], [1000.0, 5.0], [0.0, 5.0]]").replace(
        "cell = 0.25               # m (cubic cells)", "cell = 0.01")
    tracemalloc.start()
    try:
        err = _bad(capsys, tmp_path, text, "[grid.cell] run too large", "material points")
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 16 * 2**20, (peak, err)
    assert "TiB" in err or "PiB" in err or "GiB" in err


def test_3d_estimate_counts_the_points_of_an_extruded_section():
    """Points = section area x strike length / cell volume x 8: the column's 160."""
    est = estimate_run(load_scene(MESHES / "column_3d.toml"))
    assert est.points == 160 and est.nodes == 2 * 23 * 2 and est.cells == 22


def test_shipped_3d_scenes_seed_their_extruded_sections():
    """Every 3-D scene in meshes/ seeds points inside its grid whose initial volume is the
    soil's: section area x strike length for the plain extrusions (the column, exactly;
    the extruded reference slope within the half-cell band of its section's perimeter,
    as the plane-strain check of tests/test_scene.py), less for a plan cut."""
    import numpy as np

    from fem_rmpm import api
    from fem_rmpm.runtime.budget import _polygon_area
    files = sorted(MESHES.glob("*3d*.toml"))
    assert len(files) >= 3
    for f in files:
        scene = load_scene(f)
        grid, pts = api.prepare(scene)
        assert np.all(pts.x0 >= grid.origin) and np.all(pts.x0 <= grid.upper), f.name
        so = scene.soils[0]
        area = _polygon_area(so.polygon, grid.origin[:2], grid.upper[:2])
        full = area * scene.grid.size[2]
        if so.plan is not None:
            assert pts.volume0.sum() < full, f.name
            continue
        poly = np.array(so.polygon)
        perimeter = np.linalg.norm(np.roll(poly, -1, 0) - poly, axis=1).sum()
        band = perimeter * float(np.max(grid.cell)) / 2 * scene.grid.size[2]
        assert abs(pts.volume0.sum() - full) <= 0.1 * band, (f.name, pts.volume0.sum(), full)


def test_fem_command_solves_a_3d_scene_and_fs_refuses_it(tmp_path, capsys):
    """``fem-rmpm fem`` on the 3-D column: the top settlement of the closed form
    u_y(H) = -gamma H^2 / (2 M) (M the constrained modulus) within the trilinear
    element's error (exact at the nodes for this 1-D problem: 1e-9);
    ``api.factor_of_safety`` refuses a 3-D scene with a one-line SceneError."""
    import json

    from fem_rmpm import api
    from fem_rmpm.scene import SceneError

    out = tmp_path / "fem"
    assert main(["fem", str(MESHES / "column_3d.toml"), "--out", str(out)]) == 0
    s = json.loads((out / "summary.json").read_text())
    M = 1000.0 * 0.67 / (1.33 * 0.34)
    assert abs(s["max_displacement"] / (20.0 * 25.0 / (2 * M)) - 1) < 1e-9
    assert (out / "fem.vtu").exists()
    with pytest.raises(SceneError, match="plane strain only"):
        api.factor_of_safety(load_scene(MESHES / "column_3d.toml"))


@pytest.mark.parametrize("command", [["fs"], ["field"], ["converge", "--cells", "1,0.5"]])
def test_plane_strain_only_commands_refuse_a_3d_scene(capsys, tmp_path, command):
    """``fs``, ``field`` and ``converge`` work on plane-strain scenes only: a 3-D scene
    exits 2 with one line naming the command, nothing written."""
    out = tmp_path / "out"
    code = main([command[0], str(MESHES / "slope_extruded_3d.toml"), "--out", str(out),
                 *command[1:]])
    err = capsys.readouterr().err.strip()
    assert code == 2, err
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    assert f"'fem-rmpm {command[0]}' does not support 3-D scenes yet" in err, err
    assert "[grid.size]" in err and not out.exists()


def test_3d_estimate_prices_an_elastic_scene_by_the_elastic_step():
    """The elastic column is priced (and labelled) by the linear elastic step's cost per
    point-step, the extruded von Mises slab by the von Mises step's."""
    from fem_rmpm.runtime.budget3d import NS_PER_POINT_STEP_3D, NS_PER_POINT_STEP_3D_ELASTIC
    elastic = estimate_run(load_scene(MESHES / "column_3d.toml"))
    plastic = estimate_run(load_scene(MESHES / "slope_extruded_3d.toml"))
    assert elastic.ns_per_point_step == NS_PER_POINT_STEP_3D_ELASTIC
    assert "linear elastic" in elastic.machine
    assert plastic.ns_per_point_step == NS_PER_POINT_STEP_3D and "von Mises" in plastic.machine
