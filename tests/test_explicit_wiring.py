"""The explicit step's arguments and the time loop's solver options reach the physics
(written so that the mutants of ``python validation/mutation.py explicit`` fail them).

References written out here: the documented defaults of :func:`explicit_step` (FLIP 1,
standard Q4 shape functions, large deformation, one thread, a workspace made on demand);
inactive (frozen) points take no part in a step and keep their state; the gravity ramp
``g(t) = min(1, t / gravity_ramp_time) g`` applied at the end of the step, so that
after the first step of a body at rest with zero stress every point whose nodes are
all free has ``v = dt * (dt / T) * g`` exactly (lumped mass, ``a = f / m`` at the nodes,
``v = v0 + dt sum_a N_a a_a`` with ``sum_a N_a = 1``); the loop's documented rules: the
run ends when every point has left the grid (edge_policy "freeze") or at the first point
that leaves ("stop", the step named); progress and the energy record every 20 steps; the
at-rest test against the running peak of the kinetic energy.
"""
from __future__ import annotations

import inspect
import re
from pathlib import Path

import numpy as np
import pytest

import fem_rmpm.schemes.explicit.loop as ex
from fem_rmpm.discretise.basis import shape_at_points
from fem_rmpm.discretise.grid import make_grid
from fem_rmpm.discretise.points import seed_particles
from fem_rmpm.scene import load_scene, with_values
from fem_rmpm.schemes.common import SimulationError, at_rest
from fem_rmpm.schemes.explicit.loop import Workspace, explicit_step, run_explicit
from fem_rmpm.schemes.explicit.reference import (
    explicit_step_numpy,
    map_to_nodes,
    stable_time_step,
)

MESHES = Path(__file__).resolve().parents[1] / "meshes"
FIELDS = ("x", "velocity", "stress", "log_strain", "state", "volume")


def _column(**values):
    scene = load_scene(MESHES / "column.toml")
    if values:
        scene = with_values(scene, values)
    grid = make_grid(scene)
    return scene, grid, seed_particles(scene, grid)


def _python_loop(monkeypatch):
    """Every step from Python (as with a non-local soil): the tests below spy on the calls
    the loop makes per step; the compiled driver that otherwise runs the ordinary steps is
    checked bitwise against this loop in ``tests/test_advance.py``."""
    monkeypatch.setattr(ex, "has_nonlocal", lambda soil: True)


def _moved(pts):
    """Points given a velocity pattern so that a step deforms them (m/s)."""
    rng = np.random.default_rng(11)
    pts.velocity[:] = rng.normal(scale=0.05, size=pts.velocity.shape)
    return pts


@pytest.mark.parametrize("kernel", ["numba", "numpy"])
def test_explicit_step_defaults_are_the_documented_ones(kernel):
    """A call with the defaults is bitwise the call that spells them out (flip 1.0,
    "standard", large deformation, fbar off, one thread, a fresh workspace)."""
    scene, grid, pts = _column()
    a, b = _moved(pts), _moved(pts.copy())
    g = np.array(scene.gravity_vector) * 5.0
    dt = stable_time_step(a, grid.cell, 0.5)
    explicit_step(grid, a, dt, g, 0.3, kernel=kernel)
    spelled = dict(flip=1.0, shape="standard", geostatic=False, kernel=kernel, fbar=False)
    if kernel == "numba":
        spelled.update(work=Workspace.for_grid(grid, b.n), threads=1)
    explicit_step(grid, b, dt, g, 0.3, **spelled)
    assert np.abs(a.x - a.x0).max() > 1e-5          # the points moved (not geostatic)
    for f in FIELDS:
        assert np.array_equal(getattr(a, f), getattr(b, f)), f


def test_numpy_step_with_frozen_points_equals_numba_and_leaves_them_alone():
    """Points 0-3 (the column's base row) inactive: both kernels step only the others,
    agree to 1e-12, and the frozen points keep position, velocity and stress."""
    scene, grid, pts = _column()
    pts = _moved(pts)
    pts.active[:4] = False
    a, b = pts.copy(), pts.copy()
    g = np.array(scene.gravity_vector) * 5.0
    dt = stable_time_step(a, grid.cell, 0.5)
    work = Workspace.for_grid(grid, b.n)
    for _ in range(3):
        sa = explicit_step(grid, a, dt, g, 0.3, kernel="numpy")
        sb = explicit_step(grid, b, dt, g, 0.3, kernel="numba", work=work)
        assert sa.max_speed == pytest.approx(sb.max_speed, rel=1e-12)     # ~0.1 m/s
        assert sa.kinetic_energy == pytest.approx(sb.kinetic_energy, rel=1e-12)
    for f in FIELDS:
        ref, got = getattr(a, f), getattr(b, f)
        assert np.abs(got - ref).max() <= 1e-12 * max(np.abs(ref).max(), 1e-30), f
        assert np.array_equal(ref[:4], getattr(pts, f)[:4]), f
    assert np.abs(a.x[4:] - pts.x[4:]).max() > 1e-6


def test_gravity_ramp_on_the_first_step():
    """Column at rest, zero stress, dynamic phase, ramp T = 0.5 s, one step of dt: the
    points of the top cell (all four nodes free in y) get v_y = -dt (dt / T) g exactly;
    points on the fixed base row get less."""
    scene, grid, pts = _column(**{"solver.gravity_phase": "dynamic",
                                  "solver.gravity_ramp_time": 0.5})
    assert np.all(pts.stress == 0.0) and np.all(pts.velocity == 0.0)
    dt = stable_time_step(pts, grid.cell, scene.solver.cfl)
    scene = with_values(scene, {"solver.t_end": dt})
    rec = run_explicit(scene, grid, pts)
    assert rec.steps == 1
    expected = dt * (dt / 0.5) * scene.gravity_vector[1]
    top = pts.x0[:, 1] > 4.75
    assert top.sum() == 4
    assert np.allclose(pts.velocity[top, 1], expected, rtol=1e-12, atol=0)
    assert np.all(pts.velocity[:, 0] == 0.0)
    assert np.all(pts.velocity[pts.x0[:, 1] < 0.25, 1] > expected)


def _flying_column(policy):
    """The column thrown upwards at 50 m/s through its free top (dynamic, undamped)."""
    scene, grid, pts = _column(**{"solver.gravity_phase": "dynamic", "solver.damping": 0.0,
                                  "solver.edge_policy": policy, "solver.t_end": 2.0})
    pts.velocity[:, 1] = 50.0
    return scene, grid, pts


def test_all_points_leaving_the_grid_end_the_run_with_its_reason():
    """edge_policy "freeze": every point leaves through the free top within ~0.16 s; the run
    returns its record with that stop reason, every point frozen and listed once."""
    scene, grid, pts = _flying_column("freeze")
    rec = run_explicit(scene, grid, pts)
    assert rec is not None and rec.stop_reason == "all points left the grid"
    assert not pts.active.any() and sorted(rec.frozen_points) == list(range(pts.n))
    assert 0.05 < rec.time < 1.0 and rec.steps > 10


def test_point_leaving_with_stop_policy_names_the_step():
    """edge_policy "stop": the run ends with the step number, not at t_end."""
    scene, grid, pts = _flying_column("stop")
    with pytest.raises(SimulationError) as e:
        run_explicit(scene, grid, pts)
    assert re.match(r"step [1-9][0-9]* \(t = 0\.0[0-9]+ s\): [0-9]+ material point\(s\) left "
                    r"the grid, first point [0-9]+ at x = ", str(e.value))


@pytest.mark.parametrize("driven", [False, True])
def test_progress_and_energy_record_every_20_steps(monkeypatch, driven):
    """The column to rest: the energy record at steps 20, 40, ... (times increasing);
    stepped from Python, ``progress(t, step)`` at the same steps (same times), none in
    between; with the compiled driver, progress at the driver's returns (steps increasing;
    the driver's records are checked bitwise against the Python loop's in
    ``tests/test_advance.py``)."""
    if not driven:
        _python_loop(monkeypatch)
    scene, grid, pts = _column()
    calls = []
    rec = run_explicit(scene, grid, pts, progress=lambda t, s: calls.append((t, s)))
    assert rec.stop_reason == "at rest" and rec.steps > 400
    assert len(rec.energy) == rec.steps // 20
    assert all(b[0] > a[0] for a, b in zip(rec.energy, rec.energy[1:]))
    assert all(0.0 < t <= rec.time for t, _ in calls + rec.energy)
    steps = [s for _, s in calls]
    if driven:
        assert steps[-1] == rec.steps and all(b > a for a, b in zip(steps, steps[1:]))
    else:
        assert steps == list(range(20, rec.steps + 1, 20))
        assert [t for t, _ in calls] == [t for t, _ in rec.energy]


def test_rest_test_gets_the_running_peak_of_the_kinetic_energy(monkeypatch):
    """The at-rest test compares the kinetic energy with its peak so far: the peak passed
    is the running maximum of the energies passed (the column's peak is 0.25 kJ/m, so a
    peak that starts at 1 would stop the run early)."""
    seen = []

    def spy(t, ramp, speed, ke, ke_peak, v_rest, ratio):
        seen.append((ke, ke_peak))
        return at_rest(t, ramp, speed, ke, ke_peak, v_rest, ratio)

    monkeypatch.setattr(ex, "at_rest", spy)
    _python_loop(monkeypatch)
    scene, grid, pts = _column()
    run_explicit(scene, grid, pts)
    running = np.maximum.accumulate([ke for ke, _ in seen])
    assert np.array_equal([p for _, p in seen], running)
    assert 0.05 < running[-1] < 1.0


def test_nonlocal_averaging_follows_every_step_with_the_runs_grid(monkeypatch):
    """The loop calls the non-local averaging once after each step with the run's own
    grid and points (it needs the grid's cells for its stencil; a no-op for local soils)."""
    calls = []
    real = ex.average_softening

    def spy(grid, pts, *args, **kwargs):
        calls.append((grid, pts))
        return real(grid, pts, *args, **kwargs)

    monkeypatch.setattr(ex, "average_softening", spy)
    _python_loop(monkeypatch)
    scene, grid, pts = _column(**{"solver.t_end": 0.02})
    rec = run_explicit(scene, grid, pts)
    assert len(calls) == rec.steps > 3
    assert all(g is grid and p is pts for g, p in calls)


@pytest.mark.parametrize("options", [
    {"solver.kernel": "numpy", "solver.shape": "gimp", "solver.fbar": True,
     "solver.flip": 0.9, "solver.threads": 1},
    # a von Mises soil that stays elastic: the model does not change what reaches a step,
    # and these two-thread kernels are the ones tests/test_advance.py's reference runs use
    {"solver.kernel": "numba", "solver.shape": "standard", "solver.fbar": False,
     "solver.flip": 1.0, "solver.threads": 2, "soil.model": "von_mises_softening",
     "soil.cohesion_peak": 200.0, "soil.cohesion_residual": 100.0,
     "soil.softening_strain": 0.5},
])
def test_solver_options_reach_every_step(monkeypatch, options):
    """``[solver] kernel, shape, fbar, flip, threads`` are what each explicit step gets;
    the numba kernel reuses one workspace for the whole run, the numpy one needs none;
    the record states the thread count."""
    calls = []
    real = ex.explicit_step
    sig = inspect.signature(real)

    def spy(*args, **kwargs):
        calls.append(sig.bind(*args, **kwargs).arguments)
        return real(*args, **kwargs)

    monkeypatch.setattr(ex, "explicit_step", spy)
    _python_loop(monkeypatch)
    scene, grid, pts = _column(**options, **{"solver.t_end": 0.02})
    rec = run_explicit(scene, grid, pts)
    assert len(calls) == rec.steps > 3
    for c in calls:
        assert c["kernel"] == options["solver.kernel"]
        assert c["shape"] == options["solver.shape"] and c["fbar"] is options["solver.fbar"]
        assert c["flip"] == options["solver.flip"]
        assert c["threads"] == options["solver.threads"]
    works = {id(c["work"]) for c in calls}
    if options["solver.kernel"] == "numba":
        assert len(works) == 1 and isinstance(calls[0]["work"], Workspace)
    else:
        assert all(c["work"] is None for c in calls)
    assert rec.solver["threads"] == options["solver.threads"]


def test_numpy_step_defaults_and_map_to_nodes_without_halves():
    """``explicit_step_numpy`` called with its own defaults is bitwise the dispatcher's
    numpy call; ``map_to_nodes(second=None)`` (one sum in point order) returns one entry per
    grid node even when the last nodes (the column's empty top row) get nothing, and equals
    the two-half sum to round-off."""
    scene, grid, pts = _column()
    a, b = _moved(pts), _moved(pts.copy())
    g = np.array(scene.gravity_vector)
    dt = stable_time_step(a, grid.cell, 0.5)
    explicit_step_numpy(grid, a, dt, g, 0.3)
    explicit_step(grid, b, dt, g, 0.3, kernel="numpy")
    for f in FIELDS:
        assert np.array_equal(getattr(a, f), getattr(b, f)), f
    _, nodes, N, dN, _ = shape_at_points(grid, pts.x, "standard", pts.half_width)
    args = (nodes, N, dN, pts.mass, pts.velocity, pts.stress, pts.volume, g, grid.n_nodes)
    one = map_to_nodes(*args)
    two = map_to_nodes(*args, second=np.arange(pts.n) >= pts.n // 2)
    assert nodes.max() < grid.n_nodes - 1
    for x, y in zip(one, two):
        assert len(x) == grid.n_nodes
        assert np.allclose(x, y, rtol=1e-13, atol=1e-13 * np.abs(y).max())


def test_the_time_loop_runs_without_automatic_garbage_collection():
    """Python's automatic collection is off inside :func:`run_explicit` (as the loop's
    progress calls see it) and back as it was afterwards: on after a run that returns and
    after one that raises; off if the caller had turned it off.  (Without the pause,
    loading the driver from numba's cache triggered a full collection in the first step.)"""
    import gc
    enabled = []
    scene, grid, pts = _column(**{"solver.t_end": 0.2})
    run_explicit(scene, grid, pts, progress=lambda t, s: enabled.append(gc.isenabled()))
    assert enabled and not any(enabled) and gc.isenabled()
    with pytest.raises(SimulationError):
        run_explicit(*_flying_column("stop"))
    assert gc.isenabled()
    gc.disable()
    try:
        run_explicit(*_column(**{"solver.t_end": 0.05}))
        assert not gc.isenabled()
    finally:
        gc.enable()
