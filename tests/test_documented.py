"""Documented behaviour that had no test (issue 21): each test below checks one sentence of
README.md ("The commands", "Scene files", "Outputs", "The method") and fails if the code
stops doing what that sentence says.  All run through the public API or the command line.
"""
from __future__ import annotations

import json
import math
from pathlib import Path

import meshio
import numpy as np
import pytest

from fem_rmpm import api
from fem_rmpm.cli import main
from fem_rmpm.grid import make_grid
from fem_rmpm.scene import load_scene, scene_from_dict, scene_to_dict, with_values

MESHES = Path(__file__).resolve().parents[1] / "meshes"


def _column(**changes):
    scene = load_scene(MESHES / "column.toml")
    return with_values(scene, changes) if changes else scene


def _toml_value(v) -> str:
    if isinstance(v, bool):
        return str(v).lower()
    if isinstance(v, float) and math.isinf(v):
        return "inf" if v > 0 else "-inf"
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    return json.dumps(v)


def write_scene(path: Path, scene) -> Path:
    """Write a scene as a TOML file (the inverse of load_scene, for command-line tests)."""
    lines = []
    for sec, body in scene_to_dict(scene).items():
        for item in (body if isinstance(body, list) else [body]):
            lines.append(f"[[{sec}]]" if isinstance(body, list) else f"[{sec}]")
            lines += [f"{k} = {_toml_value(v)}" for k, v in item.items() if v is not None]
    path.write_text("\n".join(lines) + "\n")
    return path


def _one_line_error(capsys) -> str:
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    return err


# ----------------------------------------------------------------------------- exit codes
def test_interrupt_exits_130_and_keeps_finished_output(tmp_path, capsys, monkeypatch):
    """README "The commands": exit code 130 when interrupted; output up to then is kept.
    A KeyboardInterrupt raised while the second snapshot is written (as Ctrl-C would) ends
    `fem-rmpm run` with 130, one line on stderr, and the first snapshot and the .pvd that
    lists it stay readable."""
    from fem_rmpm.output import PvdSeries
    original = PvdSeries.add
    calls = []

    def add(self, t, pts):
        calls.append(t)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return original(self, t, pts)

    monkeypatch.setattr(PvdSeries, "add", add)
    out = tmp_path / "run"
    code = main(["run", str(MESHES / "column.toml"), "--out", str(out), "--quiet"])
    err = _one_line_error(capsys)
    assert code == 130 and "interrupted" in err
    assert len(calls) == 2
    first = meshio.read(out / "particles_0000.vtu")
    assert first.points.shape == (80, 3)
    assert "particles_0000.vtu" in (out / "particles.pvd").read_text()
    assert not (out / "particles_0001.vtu").exists()


def test_writer_refuses_nan_and_the_run_exits_3(tmp_path, capsys, monkeypatch):
    """README "Outputs": no file is ever written with NaN or Inf: the writer refuses, and
    the command exits 3 naming the field.  A NaN put into one point's plastic shear strain
    (a field no run-time guard looks at) just before the second snapshot: the snapshot
    file is not written (nor left half-written), the first one is intact."""
    from fem_rmpm.output import OutputError, PvdSeries, write_particles
    original = PvdSeries.add
    calls = []

    def add(self, t, pts):
        calls.append(t)
        if len(calls) == 2:
            pts.plastic_shear_strain[3] = np.nan
        return original(self, t, pts)

    monkeypatch.setattr(PvdSeries, "add", add)
    out = tmp_path / "run"
    code = main(["run", str(MESHES / "column.toml"), "--out", str(out), "--quiet"])
    err = _one_line_error(capsys)
    assert code == 3 and "non-finite" in err and "plastic_shear_strain" in err
    assert sorted(p.name for p in out.glob("*.vtu")) == ["grid.vtu", "particles_0000.vtu"]
    assert not list(out.glob(".*tmp*"))
    assert np.all(np.isfinite(meshio.read(out / "particles_0000.vtu").point_data["stress"]))
    # the writer itself, for every field and for the positions, and for +-Inf too
    grid, pts = api.prepare(_column())
    for name, bad in (("stress", np.inf), ("velocity", -np.inf), ("x", np.nan)):
        p = pts.copy()
        getattr(p, name)[0, 0] = bad
        with pytest.raises(OutputError, match="non-finite"):
            write_particles(tmp_path / f"bad_{name}.vtu", p)
        assert not (tmp_path / f"bad_{name}.vtu").exists()


# ----------------------------------------------------------------------------- [grid] file
def _quad_mesh(path: Path, xs, ys, drop_cell: bool = False, kind: str = "quad") -> Path:
    X, Y = np.meshgrid(xs, ys, indexing="xy")
    pts = np.stack([X.ravel(), Y.ravel(), np.zeros(X.size)], axis=1)
    nx = len(xs)
    quads = [[j * nx + i, j * nx + i + 1, (j + 1) * nx + i + 1, (j + 1) * nx + i]
             for j in range(len(ys) - 1) for i in range(nx - 1)]
    if drop_cell:
        del quads[len(quads) // 2]               # a hole in the middle: every node still used
    cells = [("quad", np.array(quads))] if kind == "quad" else \
        [("triangle", np.array([[q[0], q[1], q[2]] for q in quads]))]
    meshio.write(path, meshio.Mesh(pts, cells))
    return path


def _column_with_grid_file(tmp_path, mesh_name: str) -> Path:
    text = (MESHES / "column.toml").read_text()
    text = text.replace("origin = [0.0, 0.0]     # m\nsize = [0.25, 5.5]      # m (0.5 m of "
                        "empty room above the soil)\ncell = 0.25             # m",
                        f'file = "{mesh_name}"')
    assert f'file = "{mesh_name}"' in text
    p = tmp_path / "column_file.toml"
    p.write_text(text)
    return p


def test_grid_file_is_the_same_grid_and_the_same_run(tmp_path):
    """README "Scene files": `[grid] file` = a structured quad mesh read by meshio.  The
    column's 1 x 22 cells of 0.25 m written as a .vtu give the grid of `origin/size/cell`
    (nodes, cells, fixed DOFs) and, through a whole explicit run, the same stresses to
    round-off (both are the same arithmetic; achieves 0, asserts exact equality)."""
    _quad_mesh(tmp_path / "col.vtu", np.linspace(0, 0.25, 2), np.linspace(0, 5.5, 23))
    scene_file = load_scene(_column_with_grid_file(tmp_path, "col.vtu"))
    ref = _column()
    g1, g2 = make_grid(scene_file), make_grid(ref)
    assert g1.shape == g2.shape == (1, 22)
    np.testing.assert_allclose(g1.nodes, g2.nodes, atol=1e-12)
    np.testing.assert_array_equal(g1.cells, g2.cells)
    np.testing.assert_array_equal(g1.fixed, g2.fixed)
    r1, r2 = api.run(scene_file), api.run(ref)
    np.testing.assert_array_equal(r1.particles.stress, r2.particles.stress)
    assert r1.record.steps == r2.record.steps


@pytest.mark.parametrize("case,needle", [
    ("missing", "not found"),
    ("garbage", "cannot read"),
    ("triangles", "holds no quad cells"),
    ("uneven", "not a complete axis-aligned grid of equal cells"),
    ("incomplete", "not a complete axis-aligned grid of equal cells"),
])
def test_grid_file_errors_are_one_line_exit_2(tmp_path, capsys, case, needle):
    """README "Scene files" / the bad-input rule: the four ways a `[grid] file` can be
    wrong (missing, unreadable, no quads, not a structured grid of equal cells, including
    one with a cell missing) each give exit 2, one line naming the scene file, the key
    and the mesh, and no output directory."""
    mesh = tmp_path / "m.vtu"
    if case == "garbage":
        mesh.write_bytes(b"\x00\x01 not a mesh")
    elif case == "triangles":
        _quad_mesh(mesh, np.linspace(0, 0.25, 2), np.linspace(0, 5.5, 23), kind="triangle")
    elif case == "uneven":
        _quad_mesh(mesh, np.linspace(0, 0.25, 2), np.r_[np.linspace(0, 5.0, 21), 5.5])
    elif case == "incomplete":
        _quad_mesh(mesh, np.linspace(0, 0.25, 2), np.linspace(0, 5.5, 23), drop_cell=True)
    scene = _column_with_grid_file(tmp_path, "m.vtu")
    out = tmp_path / "out"
    assert main(["run", str(scene), "--out", str(out), "--quiet"]) == 2
    err = _one_line_error(capsys)
    assert needle in err and str(scene) in err and "grid.file" in err and "m.vtu" in err
    assert not out.exists()


# ----------------------------------------------------------------------------- [[bedrock]]
def _rel_l2(a, b, w):
    return float(np.sqrt(np.sum((a - b) ** 2 * w) / np.sum(b ** 2 * w)))


def test_bedrock_fixes_its_nodes_and_holds_no_points(tmp_path):
    """README "Scene files": `[[bedrock]]` is a rigid region; every grid node in or on it is
    fixed and no particles are placed in it, even where a soil polygon overlaps it.  The
    5 m column with bedrock over its lowest 1 m is a 4 m column on a fixed base: 64 points
    (not 80), all above y = 1 m; the nodes at y <= 1 m fixed in x and y, the others free in
    y; at rest sigma_yy is the Q4 solution of the 4 m column, h / (2 H') = 3.125e-2 from
    -gamma (5 - y) in the relative L2 norm (achieves that to 3e-8, asserts 2e-7), and the
    top point settles -(gamma / M) (H' s - s^2 / 2), s = y - 1 m (achieves 7.0e-4, of
    which 6.5e-4 is the linear interpolation between exact nodal values; asserts 1.5e-3)."""
    text = (MESHES / "column.toml").read_text()
    scene_path = tmp_path / "bedrock.toml"
    scene_path.write_text(text + "\n[[bedrock]]\npolygon = [[0.0, 0.0], [0.25, 0.0], "
                          "[0.25, 1.0], [0.0, 1.0]]\n")
    scene = load_scene(scene_path)
    grid, pts = api.prepare(scene)
    assert pts.n == 64 and pts.x0[:, 1].min() > 1.0
    low = grid.nodes[:, 1] <= 1.0 + 1e-9
    assert grid.fixed[low].all() and not grid.fixed[~low, 1].any()
    res = api.run(scene)
    p = res.particles
    assert res.record.stop_reason == "at rest"
    err = _rel_l2(p.stress[:, 1], -20.0 * (5.0 - p.x0[:, 1]), p.volume0)
    assert abs(err - 0.25 / (2 * 4.0)) < 2e-7
    M = scene.soils[0].constrained_modulus
    top = np.argmax(p.x0[:, 1])
    s = p.x0[top, 1] - 1.0
    assert abs(p.displacement[top, 1] / (-(20.0 / M) * (4.0 * s - s * s / 2)) - 1) < 1.5e-3
