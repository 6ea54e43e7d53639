"""The explicit step's arguments and the time loop's solver options reach the physics
(issue 21, surviving mutants of ``python validation/mutation.py explicit``).

References written out here: the documented defaults of :func:`explicit_step` (FLIP 1,
standard Q4 shape functions, large deformation, one thread, a workspace made on demand);
inactive (frozen) points take no part in a step and keep their state; the gravity ramp
``g(t) = min(1, t / gravity_ramp_time) g`` applied at the end of the step, so that
after the first step of a body at rest with zero stress every point whose nodes are
all free has ``v = dt * (dt / T) * g`` exactly (lumped mass, ``a = f / m`` at the nodes,
``v = v0 + dt sum_a N_a a_a`` with ``sum_a N_a = 1``).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from fem_rmpm.explicit import Workspace, explicit_step, run_explicit, stable_time_step
from fem_rmpm.grid import make_grid
from fem_rmpm.particles import seed_particles
from fem_rmpm.scene import load_scene, with_values

MESHES = Path(__file__).resolve().parents[1] / "meshes"
FIELDS = ("x", "velocity", "stress", "log_strain", "state", "volume", "F")


def _column(**values):
    scene = load_scene(MESHES / "column.toml")
    if values:
        scene = with_values(scene, values)
    grid = make_grid(scene)
    return scene, grid, seed_particles(scene, grid)


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
        explicit_step(grid, a, dt, g, 0.3, kernel="numpy")
        explicit_step(grid, b, dt, g, 0.3, kernel="numba", work=work)
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
