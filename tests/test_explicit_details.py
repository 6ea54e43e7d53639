"""Exact checks of the explicit step's numpy stages and of its time loop (written so that
the mutants of ``python validation/mutation.py explicit`` fail them).

References written out here: the CFL step ``dt = cfl h / (c_p + |v|max)`` with
``c_p = sqrt((K + 4G/3) / rho)`` over the active points; the lumped-mass momentum
balance ``a = f / m`` with Cundall's local damping ``f - alpha |f| sign(v)``, nodes
without mass at rest and prescribed components zero; the point-to-node sums of mass,
momentum and force (``f = -sigma grad N V + N m g``); the loop's bookkeeping (output at
t = 0, every ``output_interval`` and at the end; energy every 20 steps; the stop reason;
the geostatic switch; the at-rest test of :func:`fem_rmpm.schemes.common.at_rest`).
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from fem_rmpm.discretise.grid import make_grid
from fem_rmpm.discretise.points import seed_particles
from fem_rmpm.scene import load_scene, with_values
from fem_rmpm.schemes.common import RunRecord, SimulationError, at_rest, check_points
from fem_rmpm.schemes.explicit.loop import explicit_step, run_explicit
from fem_rmpm.schemes.explicit.reference import map_to_nodes, solve_on_mesh, stable_time_step

MESHES = Path(__file__).resolve().parents[1] / "meshes"


@pytest.fixture
def column():
    scene = load_scene(MESHES / "column.toml")
    grid = make_grid(scene)
    return scene, grid, seed_particles(scene, grid)


def test_stable_time_step_is_the_cfl_formula_over_active_points(column):
    """dt = cfl min(h) / (max c_p + max |v|); an inactive point (fast, stiff) is ignored."""
    scene, grid, pts = column
    pts.velocity[:] = 0.0
    pts.velocity[3] = [0.3, -0.4]                            # |v| = 0.5 m/s
    rho = pts.mass / pts.volume
    M = pts.soil.bulk_modulus + 4.0 / 3.0 * pts.soil.shear_modulus
    cp = np.sqrt(M / rho).max()
    h = float(np.min(grid.cell))
    assert stable_time_step(pts, grid.cell, 0.4) == pytest.approx(0.4 * h / (cp + 0.5),
                                                                  rel=1e-14)
    pts.active[5] = False
    pts.velocity[5] = [100.0, 0.0]
    pts.mass[5] *= 1e-6                                      # c_p x 1000 if it counted
    assert stable_time_step(pts, grid.cell, 0.4) == pytest.approx(0.4 * h / (cp + 0.5),
                                                                  rel=1e-14)


def test_solve_on_mesh_lumped_mass_damping_and_fixed_components():
    """Three nodes: m = (2, 1e-16, 4) t, node 2 fixed in x.  v_old = p/m (0 where m is
    below 1e-14), damped force f - alpha |f| sign(v_old), a = f/m, v_new = v_old + a dt."""
    m = np.array([2.0, 1e-16, 4.0])
    p = np.array([[2.0, -4.0], [1e-16, 0.0], [8.0, 0.0]])
    f = np.array([[3.0, 2.0], [5.0, 5.0], [-2.0, 6.0]])
    fixed = np.array([[False, False], [False, False], [True, False]])
    v_old, v_new, a = solve_on_mesh(m, p, f, fixed, 0.1, 0.5)
    assert np.array_equal(v_old, [[1.0, -2.0], [0.0, 0.0], [0.0, 0.0]])
    f_d = np.array([[3.0 - 1.5, 2.0 + 1.0], [5.0, 5.0], [0.0, 6.0]])   # sign(0) = 0
    assert np.allclose(a, [f_d[0] / 2.0, [0.0, 0.0], f_d[2] / 4.0], rtol=1e-15, atol=0)
    assert np.allclose(v_new, v_old + 0.1 * a, rtol=1e-15, atol=0)
    _, _, a0 = solve_on_mesh(m, p, f, fixed, 0.1, 0.0)
    assert np.allclose(a0[0], f[0] / 2.0, rtol=1e-15)


def test_map_to_nodes_sums_mass_momentum_and_force():
    """Two points, three nodes, written out: m_I = sum N m, p_I = sum N m v,
    f_I = -(sigma_xx dN_x + sigma_xy dN_y, sigma_xy dN_x + sigma_yy dN_y) V + N m g."""
    nodes = np.array([[0, 1], [1, 2]])
    N = np.array([[0.25, 0.75], [0.6, 0.4]])
    dN = np.array([[[-1.0, 0.5], [1.0, -0.5]], [[-2.0, 0.25], [2.0, -0.25]]])
    mass, vol = np.array([2.0, 3.0]), np.array([0.5, 0.25])
    v = np.array([[1.0, -1.0], [0.5, 2.0]])
    s = np.array([[10.0, -20.0, 0.0, 4.0], [-6.0, 8.0, 0.0, -2.0]])
    g = np.array([0.0, -9.81])
    m, p, f = map_to_nodes(nodes, N, dN, mass, v, s, vol, g, 3)
    ref_m = np.zeros(3)
    ref_p, ref_f = np.zeros((3, 2)), np.zeros((3, 2))
    for q in range(2):
        for a in range(2):
            i = nodes[q, a]
            ref_m[i] += N[q, a] * mass[q]
            ref_p[i] += N[q, a] * mass[q] * v[q]
            gx, gy = dN[q, a]
            ref_f[i, 0] += -(s[q, 0] * gx + s[q, 3] * gy) * vol[q] + N[q, a] * mass[q] * g[0]
            ref_f[i, 1] += -(s[q, 3] * gx + s[q, 1] * gy) * vol[q] + N[q, a] * mass[q] * g[1]
    assert np.allclose(m, ref_m, rtol=1e-15) and np.allclose(p, ref_p, rtol=1e-15)
    assert np.allclose(f, ref_f, rtol=1e-14, atol=1e-14)


def test_unknown_kernel_is_refused_with_the_allowed_ones(column):
    scene, grid, pts = column
    with pytest.raises(ValueError, match=r"kernel 'fortran' not allowed; allowed: numba \| numpy"):
        explicit_step(grid, pts, 1e-4, np.array([0.0, -9.81]), 0.0, kernel="fortran")
    with pytest.raises(ValueError, match="allowed: numba | numpy"):
        run_explicit(scene, grid, pts, kernel="fortran")


@pytest.mark.parametrize("kernel", ["numpy", "numba"])
def test_time_loop_bookkeeping(column, kernel):
    """t_end = 0.05 s, output every 0.02 s, no geostatic phase: outputs at t = 0, each
    interval and at the end (times increasing, the last = the end time); energy sampled
    every 20th step; progress called with it (numpy; numba: at the compiled driver's
    returns, steps increasing); dt_min <= dt_max both the CFL step (the
    last step may be shorter); stop reason "t_end reached"; steps and time recorded."""
    scene, _, _ = column
    sc = with_values(scene, {"solver.t_end": 0.05, "solver.output_interval": 0.02,
                             "solver.gravity_phase": "dynamic"})
    grid = make_grid(sc)
    pts = seed_particles(sc, grid)
    dt0 = stable_time_step(pts, grid.cell, sc.solver.cfl)
    outs, prog = [], []
    rec = run_explicit(sc, grid, pts, on_output=lambda t, p: outs.append(t),
                       progress=lambda t, s: prog.append((t, s)), kernel=kernel)
    assert rec.stop_reason == "t_end reached" and rec.time == pytest.approx(0.05, abs=1e-12)
    assert outs[0] == 0.0 and outs[-1] == pytest.approx(rec.time, abs=1e-12)
    assert [round(t / 0.02 - 1e-9) for t in outs[1:-1]] == [1, 2]
    assert all(b > a for a, b in zip(outs, outs[1:]))
    assert len(rec.energy) == rec.steps // 20
    assert all(b[0] > a[0] for a, b in zip(rec.energy, rec.energy[1:]))
    steps = [s for _, s in prog]
    assert all(b > a for a, b in zip(steps, steps[1:])) and set(steps) <= set(range(rec.steps + 1))
    if kernel == "numpy":            # every step from Python: progress at every record
        assert steps == [20 * (k + 1) for k in range(len(prog))]
        assert [t for t, _ in rec.energy] == [t for t, _ in prog]
    assert 0 < rec.dt_min <= rec.dt_max <= dt0 * (1 + 1e-9)
    assert rec.steps >= 0.05 / rec.dt_max - 1e-9 and rec.steps <= 0.05 / rec.dt_min + 1
    assert np.isnan(pts.F).all()     # not tracked by the explicit scheme: not left as current


def test_geostatic_phase_ends_at_rest_then_stops_at_rest(column):
    """The column: the geostatic phase comes to rest (recorded with its end time), the
    large-deformation phase then stops "at rest" at once; the record says both."""
    scene, grid, pts = column
    rec = run_explicit(scene, grid, pts)
    assert rec.solver["geostatic_at_rest"] is True
    t_geo = rec.solver["geostatic_end_time"]
    assert scene.solver.gravity_ramp_time <= t_geo < rec.time < scene.solver.t_end
    assert rec.stop_reason == "at rest"


def test_geostatic_phase_ends_at_its_time_limit(column):
    """geostatic_time shorter than the time to rest: the phase ends at that time, not at
    rest, and the large-deformation phase continues to t_end."""
    scene, _, _ = column
    sc = with_values(scene, {"solver.geostatic_time": 0.1, "solver.t_end": 0.15})
    grid = make_grid(sc)
    pts = seed_particles(sc, grid)
    rec = run_explicit(sc, grid, pts)
    assert rec.solver["geostatic_at_rest"] is False
    assert rec.solver["geostatic_end_time"] == pytest.approx(0.1, abs=2 * rec.dt_max)
    assert rec.solver["geostatic_end_time"] >= 0.1 - 1e-12
    assert rec.stop_reason == "t_end reached"


@pytest.mark.parametrize("t, speed, ke, expected", [
    (1.0, 0.5e-5, 1e-9, True),      # both criteria, gravity on
    (0.4, 0.5e-5, 1e-9, False),     # gravity still ramping (ramp 0.5 s)
    (0.5, 0.5e-5, 1e-9, True),      # t == ramp time counts as on
    (1.0, 1e-5, 1e-9, False),       # speed not below the limit (strict)
    (1.0, 0.5e-5, 1e-8, True),      # energy equal to ratio x peak counts
    (1.0, 0.5e-5, 1.1e-8, False),   # energy above
])
def test_at_rest_boundaries(t, speed, ke, expected):
    """at_rest(t, ramp 0.5 s, speed, ke, peak 1, v_rest 1e-5 m/s, ratio 1e-8)."""
    assert at_rest(t, 0.5, speed, ke, 1.0, 1e-5, 1e-8) is expected


def test_check_points_freezes_or_stops_and_names_the_point(column):
    """A point beyond the top edge: policy freeze makes it inactive with zero velocity
    and lists it; policy stop raises naming the point and the fix; a NaN stress raises
    naming the point's start position."""
    scene, grid, pts = column
    pts.x[7] = [0.1, grid.upper[1] + 0.2]
    pts.velocity[7] = [0.0, 3.0]
    rec = RunRecord(scheme="explicit")
    check_points(grid, pts, 12, 0.5, "freeze", rec)
    assert not pts.active[7] and pts.active.sum() == pts.n - 1
    assert np.array_equal(pts.velocity[7], [0.0, 0.0]) and rec.frozen_points == [7]
    pts.active[7] = True
    with pytest.raises(SimulationError, match=r"step 12 \(t = 0.5 s\): 1 material point\(s\) "
                                              r"left the grid, first point 7"):
        check_points(grid, pts, 12, 0.5, "stop", RunRecord(scheme="explicit"))
    pts.x[7] = pts.x0[7]
    pts.stress[9, 1] = math.nan
    with pytest.raises(SimulationError, match=rf"non-finite state at material point 9 "
                                              rf"\(started at x = {pts.x0[9, 0]:.3f}"):
        check_points(grid, pts, 3, 0.1, "freeze", RunRecord(scheme="explicit"))
