"""The compiled per-step kernels of the implicit scheme against the numpy code they replace.

Each kernel must give the numpy result to the last bit (same operations, same order), so a
run does not change when they are used: the Q4 basis and host cells
(:func:`fem_rmpm.discretise.basis.q4_at_points`, :func:`fem_rmpm.schemes.locking.host_cells`),
the nodal sums of the Newmark predictor (:meth:`StepSystem.mass_and_momenta`), the body
force, the point interpolation of free-DOF vectors and the point check
(:func:`fem_rmpm.schemes.common.check_points`).
"""
from __future__ import annotations

import numpy as np
import pytest

from fem_rmpm.discretise.basis import q4_at_points
from fem_rmpm.discretise.grid import make_grid
from fem_rmpm.discretise.points import seed_particles
from fem_rmpm.scene import load_scene
from fem_rmpm.schemes.common import RunRecord, check_points
from fem_rmpm.schemes.implicit import step_kernels as sk
from fem_rmpm.schemes.implicit.assembly import StepSystem
from fem_rmpm.schemes.locking import host_cells

from conftest import ROOT


@pytest.fixture(scope="module")
def slope():
    scene = load_scene(ROOT / "meshes" / "slope_elastic.toml")
    grid = make_grid(scene)
    pts = seed_particles(scene, grid)
    rng = np.random.default_rng(3)
    # moved points, some exactly on cell edges and nodes, one at the grid's far corner
    x = pts.x + rng.uniform(-0.3, 0.3, pts.x.shape)
    x[:50] = np.round(x[:50] / grid.cell) * grid.cell + grid.origin % grid.cell
    x[50] = grid.upper
    x = np.clip(x, grid.origin, grid.upper)
    return grid, pts, x


def test_q4_step_basis_is_the_numpy_basis_bitwise(slope):
    grid, _, x = slope
    S = StepSystem(grid, x)
    cell, nodes, N, dN, _ = q4_at_points(grid, x)
    assert np.array_equal(S.nodes, nodes) and S.nodes.dtype == nodes.dtype
    assert np.array_equal(S.N, N) and np.array_equal(S.dN, dN)
    assert np.array_equal(S.host, host_cells(grid, x))
    rank = np.unique(S.host, return_inverse=True)[1].ravel()
    assert np.array_equal(S.cell, rank) and S.n_host == len(np.unique(S.host))
    used = np.zeros(grid.n_nodes, dtype=bool)
    touch = (N != 0) | (dN[:, :, 0] != 0) | (dN[:, :, 1] != 0)
    used[nodes[touch]] = True
    assert np.array_equal(S.used, used)


def test_free_dof_sums_and_interpolation_bitwise(slope):
    grid, pts, x = slope
    S = StepSystem(grid, x, halo=True)
    rng = np.random.default_rng(4)
    v, a = rng.normal(size=(pts.n, 2)), rng.normal(size=(pts.n, 2))
    m, mv, ma = S.mass_and_momenta(pts.mass, v, a)
    nf = S.n_free
    v_n, a_n, m_free = np.empty(nf), np.empty(nf), np.empty(nf)
    m_min = 0.3 * float(np.median(m[m > 0]))
    work = np.zeros(grid.n_nodes)
    light = sk.newmark_start(S.nodes, S.N, pts.mass, v, a, S.fnum, S.free_dofs, S.used_nodes,
                             m_min, 1e-14, work, np.zeros(nf), np.zeros(nf), v_n, a_n, m_free)
    m_dof = m[S.free_dofs // 2]
    inv = np.where(m_dof > 1e-14, 1.0 / np.where(m_dof > 1e-14, m_dof, 1.0), 0.0)
    assert np.array_equal(v_n, mv.ravel()[S.free_dofs] * inv)
    assert np.array_equal(a_n, ma.ravel()[S.free_dofs] * inv)
    assert np.array_equal(m_free, np.maximum(m_dof, m_min))
    assert light == np.count_nonzero(m[S.used] < m_min) and light > 0
    assert not work.any()                                   # left zeroed for the next step
    f = sk.free_body_force(S.nodes, S.N, pts.mass, 0.5, -9.81, S.fnum, np.zeros(nf))
    g = np.array([0.5, -9.81])
    nodal_force = np.bincount(S.point_dofs.ravel(),
                              (S.N[:, :, None] * pts.mass[:, None, None] * g).ravel(),
                              minlength=2 * grid.n_nodes)
    assert np.array_equal(f, nodal_force[S.free_dofs])
    vec = rng.normal(size=nf)
    assert np.array_equal(sk.interpolate_free(vec, S.fnum, S.nodes, S.N, np.empty((pts.n, 2))),
                          S.interpolate(S.to_nodes(vec)))
    # the Newmark commit: FLIP 0.7 blended with PIC, accelerations, largest PIC speed
    vel, acc = rng.normal(size=(pts.n, 2)), np.zeros((pts.n, 2))
    dv, an = rng.normal(size=nf), rng.normal(size=nf)
    expect = 0.7 * (vel + S.interpolate(S.to_nodes(dv))) + (1 - 0.7) * S.interpolate(
        S.to_nodes(vec))
    vmax = sk.newmark_commit(np.arange(pts.n), vec, dv, an, S.fnum, S.nodes, S.N, 0.7, vel,
                             acc)
    pic = S.interpolate(S.to_nodes(vec))
    assert np.array_equal(vel, expect)
    assert np.array_equal(acc, S.interpolate(S.to_nodes(an)))
    assert vmax == np.sqrt(np.max(np.sum(pic * pic, 1)))


def test_step_limits_as_numpy():
    rng = np.random.default_rng(5)
    u = rng.normal(size=(300, 2))
    dF = np.eye(2) + 0.05 * rng.normal(size=(300, 2, 2))
    J = dF[:, 0, 0] * dF[:, 1, 1] - dF[:, 0, 1] * dF[:, 1, 0]
    disp, jmin, jmax, worst = sk.step_limits(u, dF)
    assert disp == np.sqrt(np.max(np.sum(u * u, 1)))
    assert (jmin, jmax) == (J.min(initial=1.0), J.max(initial=1.0))
    assert worst == np.argmax(np.abs(np.log(J)))


@pytest.mark.parametrize("spoil", ["none", "nan_stress", "inf_velocity", "left", "frozen_left"])
def test_points_fine_finds_what_check_points_reports(slope, spoil):
    grid, pts, _ = slope
    x, v, stress = pts.x.copy(), np.zeros((pts.n, 2)), pts.stress.copy()
    active = np.ones(pts.n, dtype=bool)
    if spoil == "nan_stress":
        stress[17, 2] = np.nan
    elif spoil == "inf_velocity":
        v[5, 1] = np.inf
    elif spoil in ("left", "frozen_left"):
        x[9, 0] = grid.upper[0] + 1e-9
        active[9] = spoil == "left"
    lo, hi = grid.origin, grid.upper
    fine = sk.points_fine(active, x, v, stress, lo[0], lo[1], hi[0], hi[1])
    assert fine == (spoil in ("none", "frozen_left"))

    class P:                        # the fields check_points reads
        pass
    p = P()
    p.x, p.velocity, p.stress, p.active, p.x0 = x, v, stress, active, pts.x0
    rec = RunRecord(scheme="implicit")
    try:
        check_points(grid, p, 1, 0.1, "freeze", rec)
        reported = bool(rec.frozen_points)
    except Exception:
        reported = True
    assert reported == (not fine)
