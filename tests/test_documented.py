"""Documented behaviour: each test below checks one sentence of the documentation
(docs/guide/commands.md, scenes.md, outputs.md; docs/method/mpm.md, explicit.md,
implicit.md) and fails if the code stops doing what that sentence says.  All run through
the public API or the command line.
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
from fem_rmpm.discretise.grid import make_grid
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
    """docs/guide/commands.md: exit code 130 when interrupted; output up to then is kept.
    A KeyboardInterrupt raised while the second snapshot is written (as Ctrl-C would) ends
    `fem-rmpm run` with 130, one line on stderr, and the first snapshot and the .pvd that
    lists it stay readable."""
    from fem_rmpm.io.output import PvdSeries
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
    """docs/guide/outputs.md: no file is ever written with NaN or Inf: the writer refuses, and
    the command exits 3 naming the field.  A NaN put into one point's plastic shear strain
    (a field no run-time guard looks at) just before the second snapshot: the snapshot
    file is not written (nor left half-written), the first one is intact."""
    from fem_rmpm.io.output import OutputError, PvdSeries, write_particles
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
    """docs/guide/scenes.md: `[grid] file` = a structured quad mesh read by meshio.  The
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
    """docs/guide/scenes.md / the bad-input rule: the four ways a `[grid] file` can be
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
    """docs/guide/scenes.md: `[[bedrock]]` is a rigid region; every grid node in or on it is
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


# ----------------------------------------------------------------------------- damping_time
def _top_history(res):
    i = int(np.argmax(res.particles.x0[:, 1]))
    t = np.array([s[0] for s in res.snapshots])
    return t, np.array([s[1][i, 1] for s in res.snapshots]) - res.particles.x0[i, 1]


def test_damping_is_switched_off_after_damping_time():
    """docs/method/explicit.md: local (Cundall) damping, switched off after `damping_time`.
    The column under suddenly applied gravity (dynamic phase, no ramp): damping_time = 0 is
    bitwise the undamped run, which overshoots to about twice the static settlement (the
    1-D wave solution of a suddenly applied load; achieves 2.11x, asserts > 1.8x); damped
    throughout it creeps to the static settlement without overshoot (achieves 0.993x,
    asserts < 1.02x); with damping_time = 0.3 s the history is the damped one up to 0.3 s,
    bitwise, and departs from it after."""
    base = _column(**{"solver.gravity_phase": "dynamic", "solver.gravity_ramp_time": 0.0,
                      "solver.t_end": 1.0, "solver.output_interval": 0.02})
    M = base.soils[0].constrained_modulus
    runs = {name: _top_history(api.run(with_values(base, ch))) for name, ch in {
        "off": {"solver.damping_time": 0.0}, "undamped": {"solver.damping": 0.0},
        "on": {"solver.damping_time": 1e9}, "switch": {"solver.damping_time": 0.3}}.items()}
    y = 5.0 - 0.25 * (0.5 - 0.5 / math.sqrt(3))                     # top Gauss point
    u_static = -(20.0 / M) * (5.0 * y - y * y / 2)
    np.testing.assert_array_equal(runs["off"][1], runs["undamped"][1])
    assert runs["undamped"][1].min() < 1.8 * u_static
    assert runs["on"][1].min() > 1.02 * u_static
    t, u = runs["switch"]
    t_on, u_on = runs["on"]
    early = t <= 0.3
    np.testing.assert_array_equal(t[early], t_on[:early.sum()])
    np.testing.assert_array_equal(u[early], u_on[:early.sum()])
    assert np.abs(u[~early][:5] - u_on[early.sum():early.sum() + 5]).max() > 1e-3


# ----------------------------------------------------------------------------- points per cell
@pytest.mark.parametrize("n", [1, 3])
def test_points_per_cell_dir_seeds_gauss_points_and_integrates_like_the_fem(n):
    """docs/method/mpm.md "Seeding": standard Q4, points at the n x n Gauss points with the
    Gauss weights as volumes (1 point: the centre, the cell area); uGIMP at the centres of n x n
    equal sub-cells.  With n = 3 the 3 x 3 Gauss rule integrates the Q4 stiffness and the weight
    exactly, like the FEM's 2 x 2, so one implicit geostatic step is the scikit-fem solution
    (achieves 2.2e-14, asserts 1e-12)."""
    from fem_rmpm.discretise.basis import q4_at_points
    from fem_rmpm.schemes.fem import solve_static
    scene = _column(**{"soil.points_per_cell_dir": n})
    grid, pts = api.prepare(scene)
    g, w = np.polynomial.legendre.leggauss(n)
    g, w = (g + 1) / 2, w / 2
    assert pts.n == 20 * n * n
    cell0 = pts.x0[: n * n]                                      # the first cell, [0, 0.25]^2
    expect = np.array([(0.25 * a, 0.25 * b) for b in g for a in g])
    np.testing.assert_allclose(np.sort(cell0, axis=0), np.sort(expect, axis=0), atol=1e-14)
    np.testing.assert_allclose(np.sort(pts.volume0[: n * n]),
                               np.sort(np.outer(w, w).ravel() * 0.0625), rtol=1e-14)
    gimp = api.prepare(with_values(scene, {"solver.shape": "gimp"}))[1]
    sub = (np.arange(n) + 0.5) / n * 0.25
    np.testing.assert_allclose(np.sort(gimp.x0[: n * n], axis=0),
                               np.sort([(a, b) for b in sub for a in sub], axis=0), atol=1e-14)
    np.testing.assert_allclose(gimp.volume0, 0.0625 / n ** 2, rtol=1e-14)
    if n == 3:
        from fem_rmpm.schemes.implicit import run_implicit
        imp = with_values(scene, {"solver.scheme": "implicit", "solver.load_steps": 1})
        grid, pts = api.prepare(imp)
        run_implicit(imp, grid, pts)
        fem = solve_static(imp, grid)
        _, nodes, N, _, _ = q4_at_points(grid, pts.x0)
        u_fem = np.einsum("pa,pak->pk", N, fem.displacement[nodes])
        assert np.linalg.norm(pts.displacement - u_fem) < 1e-12 * np.linalg.norm(u_fem)


# ----------------------------------------------------------------------------- guards
def test_half_cell_motion_guard_stops_a_finite_run():
    """docs/method/explicit.md "Guards": a point moving more than half a cell in a step stops
    the run, naming the step and saying to reduce cfl.  A 1 m block of very soft soil (E = 0.2
    kPa, so the CFL step is 0.33 s) in free fall inside an all-free 10 m grid drops 1.05 m in
    its first step: every value stays finite, so only the motion guard can stop it (the
    non-finite guard would let it run on)."""
    from fem_rmpm.schemes.common import SimulationError
    scene = _column(**{"grid.size": [10.0, 10.0], "boundary.left": "free",
                       "boundary.right": "free", "boundary.bottom": "free",
                       "boundary.top": "free", "soil.youngs_modulus": 0.2,
                       "soil.polygon": [[4.0, 6.0], [5.0, 6.0], [5.0, 7.0], [4.0, 7.0]],
                       "solver.gravity_phase": "dynamic", "solver.gravity_ramp_time": 0.0,
                       "solver.damping": 0.0})
    with pytest.raises(SimulationError, match=r"step 1 .*moved 1\.0\d m in one step "
                                              r"\(> half a cell\).*reduce \[solver\] cfl"):
        api.run(scene)


def test_at_rest_needs_both_the_speed_and_the_energy_criterion():
    """docs/method/explicit.md: the run stops at rest when the max point speed is below
    `rest_velocity` AND the grid kinetic energy is below `rest_energy_ratio` x its peak.
    The shared test function, both ways round; and in a run: the column at rest at 7.4 s
    with the defaults runs on to t_end when either criterion cannot be met."""
    from fem_rmpm.schemes.common import at_rest
    kw = dict(t=2.0, ramp_time=0.5, rest_velocity=1e-5, rest_energy_ratio=1e-8)
    assert at_rest(max_speed=1e-6, kinetic_energy=1e-9, kinetic_energy_peak=1.0, **kw)
    assert not at_rest(max_speed=1e-6, kinetic_energy=1e-7, kinetic_energy_peak=1.0, **kw)
    assert not at_rest(max_speed=1e-4, kinetic_energy=1e-9, kinetic_energy_peak=1.0, **kw)
    assert not at_rest(max_speed=1e-6, kinetic_energy=1e-9, kinetic_energy_peak=1.0,
                       **{**kw, "t": 0.4})                       # gravity still ramping
    ref = api.run(_column())
    assert ref.record.stop_reason == "at rest" and 5.0 < ref.record.time < 10.0
    for change in ({"solver.rest_energy_ratio": 0.0}, {"solver.rest_velocity": 0.0}):
        r = api.run(_column(**{"solver.t_end": 12.0, **change}))
        assert r.record.stop_reason == "t_end reached", change


def _falling_block(**changes):
    """A block thrown off the free right edge of a small grid (gravity at 60 degrees)."""
    return _column(**{
        "grid.size": [3.0, 2.0], "grid.cell": [0.25, 0.25], "boundary.right": "free",
        "boundary.bottom": "roller", "scene.frame_angle_deg": 60.0,
        "soil.polygon": [[0.5, 0.0], [1.5, 0.0], [1.5, 1.0], [0.5, 1.0]],
        "solver.gravity_phase": "dynamic", "solver.gravity_ramp_time": 0.0,
        "solver.damping": 0.0, "solver.t_end": 0.7, "solver.edge_policy": "freeze",
        "solver.output_interval": 0.02, **changes})


def test_frozen_points_stay_where_they_left_the_grid(tmp_path):
    """docs/method/explicit.md "Guards": with edge_policy = "freeze" a point that leaves through
    a free edge is frozen where it left: just beyond the edge (less than the half cell a point
    may move in a step), and it never moves again; the particle files mark it `active = 0`."""
    res = api.run(_falling_block(), out=tmp_path / "o")
    p, grid = res.particles, res.grid
    frozen = ~p.active
    assert 0 < frozen.sum() < p.n
    beyond = p.x[frozen, 0] - grid.upper[0]
    assert beyond.min() > 0 and beyond.max() < 0.5 * grid.cell[0]
    xs = np.stack([s[1] for s in res.snapshots])                    # (snapshots, n, 2)
    for i in np.nonzero(frozen)[0]:
        first = int(np.argmax(xs[:, i, 0] > grid.upper[0]))
        assert np.array_equal(xs[first:, i], np.broadcast_to(p.x[i], xs[first:, i].shape))
    last = meshio.read(sorted((tmp_path / "o").glob("particles_*.vtu"))[-1])
    np.testing.assert_array_equal(last.point_data["active"], p.active.astype(int))


# ----------------------------------------------------------------------------- output files
def test_particle_and_grid_fields_are_the_documented_ones(tmp_path):
    """docs/guide/outputs.md: the point data of the particle files and the grid file, field by
    field, on a column of two soils: a von Mises clay (c_p = 8, c_r = 4 kPa, linear
    softening over gamma_p = 0.5) below y = 2 m that yields under its own weight, and a
    linear elastic soil above.  cohesion = the softening law of the point's plastic shear
    strain (-1 for elastic points), cohesion_peak (-1 elastic), soil = the soil index,
    active = 1, stress in VTK order xx yy zz xy yz xz (kPa), 3-component displacement and
    velocity, volume and mass; grid.vtu: cell data soil_cell (1 where a soil is) and point
    data fixed (the fixed components)."""
    text = (MESHES / "column.toml").read_text().replace(
        'polygon = [[0.0, 0.0], [0.25, 0.0], [0.25, 5.0], [0.0, 5.0]]',
        'polygon = [[0.0, 0.0], [0.25, 0.0], [0.25, 2.0], [0.0, 2.0]]').replace(
        'model = "linear_elastic"', 'model = "von_mises_softening"\ncohesion_peak = 8.0\n'
        'cohesion_residual = 4.0\nsoftening_strain = 0.5')
    text += ('\n[[soil]]\nname = "fill"\npolygon = [[0.0, 2.0], [0.25, 2.0], [0.25, 5.0], '
             '[0.0, 5.0]]\nunit_weight = 20.0\nyoungs_modulus = 1000.0\npoisson_ratio = 0.33\n'
             'model = "linear_elastic"\n')
    scene_path = tmp_path / "two_soils.toml"
    scene_path.write_text(text.replace("t_end = 20.0", "t_end = 2.0"))
    res = api.run(load_scene(scene_path), out=tmp_path / "o")
    p = res.particles
    m = meshio.read(sorted((tmp_path / "o").glob("particles_*.vtu"))[-1])
    d = m.point_data
    lower = p.x0[:, 1] < 2.0
    np.testing.assert_array_equal(d["soil"], np.where(lower, 0, 1))
    gam = d["plastic_shear_strain"]
    assert gam[lower].max() > 0.01 and np.all(gam[~lower] == 0)         # the clay yields
    law = 4.0 + 4.0 * np.clip(1 - gam / 0.5, 0, 1)
    np.testing.assert_allclose(d["cohesion"], np.where(lower, law, -1.0), rtol=1e-12)
    np.testing.assert_array_equal(d["cohesion_peak"], np.where(lower, 8.0, -1.0))
    np.testing.assert_array_equal(d["active"], 1)
    np.testing.assert_allclose(d["stress"][:, :4], p.stress, rtol=1e-15)
    np.testing.assert_array_equal(d["stress"][:, 4:], 0.0)
    for k in ("displacement", "velocity"):
        assert d[k].shape == (p.n, 3) and np.all(d[k][:, 2] == 0)
    np.testing.assert_allclose(d["displacement"][:, :2], p.displacement, rtol=1e-15)
    np.testing.assert_allclose(d["volume"], p.volume, rtol=1e-15)
    np.testing.assert_allclose(d["mass"], p.mass, rtol=1e-15)
    np.testing.assert_allclose(m.points[:, :2], p.x, rtol=1e-15)
    g = meshio.read(tmp_path / "o" / "grid.vtu")
    np.testing.assert_array_equal(g.cell_data["soil_cell"][0], np.r_[np.ones(20), np.zeros(2)])
    np.testing.assert_array_equal(g.point_data["fixed"], res.grid.fixed.astype(int))


def test_summary_json_holds_the_documented_keys(tmp_path):
    """docs/guide/outputs.md: summary.json holds the scene, seed, scheme, status, steps, simulated
    time, wall time, particle count, ns per point-step, the measures (the documented ones),
    frozen points, solver statistics, the kinetic-energy history and the machine, each with
    the value of the run."""
    res = api.run(_falling_block(**{"montecarlo.failure_area": 0.1}), out=tmp_path / "o",
                  seed=4)   # a 1 m2 block, part of it frozen at the edge
    s = json.loads((tmp_path / "o" / "summary.json").read_text())
    rec, p = res.record, res.particles
    assert s["scheme"] == "explicit" and s["status"] == "ok" and s["seed"] == 4
    assert s["steps"] == rec.steps and s["simulated_time"] == pytest.approx(rec.time, rel=1e-12)
    assert s["particles"] == p.n and s["wall_time"] > 0
    assert s["ns_per_particle_step"] == pytest.approx(1e9 * s["wall_time"] / (rec.steps * p.n),
                                                      rel=1e-9)
    assert s["ns_per_particle_step_cpu"] == pytest.approx(
        1e9 * s["cpu_time"] / (rec.steps * p.n), rel=1e-9) and s["cpu_time"] > 0
    assert s["scene"]["grid"]["size"] == [3.0, 2.0] and s["scene"]["soil"][0]["name"] == "clay"
    assert s["frozen_points"]["count"] == int((~p.active).sum()) > 0
    assert s["frozen_points"]["policy"] == "freeze"
    assert isinstance(s["solver"], dict)
    ke = np.array(s["kinetic_energy"])
    assert ke.shape[1] == 2 and np.all(np.diff(ke[:, 0]) > 0) and ke[:, 1].max() > 0
    mach = s["machine"]                  # the machine its ns per point-step come from
    assert mach["cpu_model"] and 1 <= mach["usable_cores"] <= mach["logical_cores"]
    assert mach["numba"] and mach["numpy"] == np.__version__
    for key in ("sliding_area", "failed", "runout_distance", "retrogression_distance",
                "time_to_rest", "final_profile"):
        assert key in s["measures"], key
    assert s["measures"]["failed"] and s["measures"]["time_to_rest"] is None


# ----------------------------------------------------------------------------- line search
class _DenseSolver:
    """The LinearSolver interface (solve(K, b, modes, rtol)) on a small dense matrix."""

    def solve(self, K, b, modes=None, rtol=1e-10):
        return np.linalg.solve(np.atleast_2d(K), b)


def _two_cycle_problem():
    """f(u) = sign(u) sqrt(|u|) (per component): the Newton step u - f/f' = -u exactly, so
    plain Newton 2-cycles between u0 and -u0 for ever, while one halving of the step
    (u - f/f'/2 = 0) lands on the root."""
    state = {}

    def evaluate(u):
        state["u"] = u.copy()
        return -np.sign(u) * np.sqrt(np.abs(u)), 1.0, None

    def tangent():
        return np.diag(0.5 / np.sqrt(np.abs(state["u"])))
    return evaluate, tangent


def test_line_search_stops_newton_two_cycles():
    """docs/method/implicit.md: a backtracking line search stops 2-cycles (at the kinks of
    the softening law).  On a residual where the full Newton step maps u to -u, Newton with
    the default line search converges (the first halved step hits the root); with the line
    search off (line_search = 0) it cycles and fails with the cycle in its residuals."""
    from fem_rmpm.schemes.implicit import NewtonFailure, newton
    evaluate, tangent = _two_cycle_problem()
    u0 = np.array([0.25, 4.0])                  # powers of 2: every step exact in floating point
    res = newton(evaluate, tangent, u0, _DenseSolver(), max_iterations=10, tol=1e-9)
    assert np.abs(res.du).max() < 1e-12
    evaluate, tangent = _two_cycle_problem()
    with pytest.raises(NewtonFailure) as failure:
        newton(evaluate, tangent, u0, _DenseSolver(), max_iterations=10, tol=1e-9,
               line_search=0)
    r = np.array(failure.value.residuals)
    np.testing.assert_allclose(r, r[0], rtol=1e-12)                 # the same residual: a cycle
