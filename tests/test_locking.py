"""Volumetric locking and its remedy, F-bar with cell averaging.

References: de Souza Neto, Peric, Dutko & Owen 1996 (F-bar, Int. J. Solids Struct. 33);
Coombs, Charlton, Cortis & Augarde 2018 (F-bar in MPM, CMAME 333); Nagtegaal, Parks &
Rice 1974 (locking of isochoric flow); the closed form of the column under self-weight (
sigma_yy = -gamma (H - y), sigma_xx = sigma_zz = K0 sigma_yy, K0 = nu / (1 - nu)).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import scipy.sparse as sp
from soil_points import vm_points

from fem_rmpm.discretise.grid import make_grid
from fem_rmpm.discretise.points import seed_particles
from fem_rmpm.materials import small_strain_update, stress_update
from fem_rmpm.scene import load_scene, with_values
from fem_rmpm.schemes import implicit as imp
from fem_rmpm.schemes import locking
from fem_rmpm.schemes.explicit.loop import Workspace, explicit_step, run_explicit, stable_time_step

MESHES = Path(__file__).resolve().parents[1] / "meshes"
FIELDS = ("x", "velocity", "stress", "log_strain", "plastic_shear_strain", "volume", "F",
          "u_geostatic")


def _rel(a, b):
    return float(np.max(np.abs(np.asarray(a) - np.asarray(b)))) / max(float(np.max(np.abs(b))),
                                                                       1e-300)


def _soil(n, rng):
    idx = np.arange(n)
    plastic = idx % 3 != 2
    return vm_points(shear_modulus=np.full(n, 400.0), bulk_modulus=np.full(n, 900.0),
                      cohesion_peak=np.where(plastic, 5.0, np.inf),
                      cohesion_residual=np.where(plastic, 2.0, np.inf),
                      softening_strain=np.full(n, 0.5), exponential=idx % 3 == 1)


# ------------------------------------------------------------------ the F-bar increment
def test_fbar_increment_keeps_the_isochoric_part_and_the_cell_volume():
    """de Souza Neto et al. 1996: dF_bar = (dJ_bar / dJ)^(1/2) dF has det = dJ_bar (the cell's
    volume-weighted mean) and the same isochoric part dF / det^(1/2); the volume of every
    cell, sum V dJ, is unchanged.  B-bar (geostatic): the trace becomes the cell mean, the
    deviatoric part and the cell's total volume change stay."""
    rng = np.random.default_rng(1)
    n, nc = 600, 50
    host = rng.integers(0, nc, n)
    V = rng.uniform(0.5, 1.5, n)
    dF = np.eye(2) + 0.1 * rng.normal(size=(n, 2, 2))
    dFb, J, Jbar = locking.fbar_increment(dF, V, host, nc)
    Jb = np.linalg.det(dFb)
    assert np.allclose(Jb, Jbar, rtol=1e-13)
    assert np.allclose(dFb / np.sqrt(Jb)[:, None, None], dF / np.sqrt(J)[:, None, None],
                       rtol=0, atol=1e-13)
    assert np.allclose(np.bincount(host, V * Jb, nc), np.bincount(host, V * J, nc), rtol=1e-13)
    H = 0.01 * rng.normal(size=(n, 2, 2))
    Hb = locking.bbar_gradient(H, V, host, nc)
    tr, trb = H[:, 0, 0] + H[:, 1, 1], Hb[:, 0, 0] + Hb[:, 1, 1]
    assert np.allclose(np.bincount(host, V * trb, nc), np.bincount(host, V * tr, nc), atol=1e-14)
    for c in range(nc):                                       # one trace per cell
        assert np.ptp(trb[host == c]) < 1e-15
    dev = lambda M, t: M - 0.5 * t[:, None, None] * np.eye(2)  # noqa: E731
    assert np.allclose(dev(Hb, trb), dev(H, tr), atol=1e-15)


@pytest.mark.parametrize("shape", ["standard", "gimp"])
def test_fbar_numba_step_equals_numpy_step(meshes, shape):
    """The compiled F-bar passes (kernels._fbar_gradient_pass / _fbar_apply_pass) against the
    numpy reference (explicit_step_numpy with fbar): geostatic (B-bar) then finite-strain
    (F-bar) steps of a softening, nearly incompressible slope with many plastic points, Q4
    and uGIMP; every field equal to 1e-12 (tests/test_kernels.py's bar).  The remedy does
    change the state (against the same run without it)."""
    scene = with_values(load_scene(meshes / "slope_elastic.toml"), {
        "grid.cell": [0.5, 0.5], "solver.shape": shape, "soil.model": "von_mises_softening",
        "soil.cohesion_peak": 3.0, "soil.cohesion_residual": 1.0, "soil.softening_strain": 0.05,
        "soil.poisson_ratio": 0.45})
    grid = make_grid(scene)
    a = seed_particles(scene, grid)
    b, c = a.copy(), a.copy()
    g = np.array(scene.gravity_vector) * 20.0
    wb, wc = Workspace.for_grid(grid, b.n), Workspace.for_grid(grid, c.n)
    for k in range(15):
        dt = stable_time_step(a, grid.cell, 0.5)
        explicit_step(grid, a, dt, g, 0.7, 1.0, shape, k < 3, kernel="numpy", fbar=True)
        explicit_step(grid, b, dt, g, 0.7, 1.0, shape, k < 3, kernel="numba", work=wb, fbar=True)
        explicit_step(grid, c, dt, g, 0.7, 1.0, shape, k < 3, kernel="numba", work=wc)
    assert (a.plastic_shear_strain > 0).sum() > 100 and np.abs(a.x - a.x0).max() > 1e-3
    for f in FIELDS:
        assert _rel(getattr(b, f), getattr(a, f)) < 1e-12, f
    assert _rel(c.stress, a.stress) > 1e-2


# ------------------------------------------------------------------ implicit tangent
@pytest.mark.parametrize("shape", ["standard", "gimp"])
def test_fbar_tangent_is_the_derivative_of_the_fbar_internal_force(meshes_dir_fx, shape):
    """The analytic F-bar tangent (locking module docstring: K + sum_p V0 (g Q)_p
    (gbar_c - g_p)^T) is the directional derivative of the assembled F-bar internal force
    f(du) = sum_p V0 tau(dF_bar) dF^-T grad N: central differences agree to 1e-6, for
    finite strain (F-bar) and for the geostatic small-strain step (B-bar: force
    sum_p V0 Bbar^T tau, tangent sum_p V0 Bbar^T D Bbar, symmetric), Q4 and uGIMP
    (whose cells couple up to 16 nodes); without the coupling term the error is O(1)."""
    grid = meshes_dir_fx
    rng = np.random.default_rng(2)
    n = 800
    cells = rng.choice(grid.n_cells, 200, replace=False)
    x = grid.nodes[grid.cells[np.repeat(cells, 4), 0]] + rng.random((n, 2)) * grid.cell
    soil = _soil(n, rng)
    ls, gp = 0.02 * rng.normal(size=(n, 4)), np.abs(0.1 * rng.normal(size=n))
    V0 = np.full(n, 0.01)
    Vn = V0 * rng.uniform(0.8, 1.2, n)
    nc = grid.n_cells
    S = imp.StepSystem(grid, x, shape, np.tile(grid.cell / 4, (n, 1)))
    du = 0.01 * rng.normal(size=S.n_free)
    v = rng.normal(size=S.n_free)
    eps = 1e-6

    def f_fin(u):
        dF = np.eye(2) + S.gradient(S.to_nodes(u))
        _, _, tau = stress_update(locking.fbar_increment(dF, Vn, S.host, nc)[0], ls, gp, soil)
        return S.internal_force(V0, tau, np.matmul(S.dN, np.linalg.inv(dF)))

    def f_geo(u):
        H = locking.bbar_gradient(S.gradient(S.to_nodes(u)), Vn, S.host, nc)
        tau = small_strain_update(H, ls, gp, soil)[2]
        return S.internal_force(V0, locking.bbar_force_stress(tau, V0, Vn, S.host, nc), S.dN)

    dF = np.eye(2) + S.gradient(S.to_nodes(du))
    dFb, J, _ = locking.fbar_increment(dF, Vn, S.host, nc)
    tau, A = imp.finite_strain_tangent(dFb, ls, gp, soil)
    g = np.matmul(S.dN, np.linalg.inv(dF))
    K0 = S.tangent(V0, g, A)
    K = K0 + S.fbar_tangent(V0, g, locking.fbar_q(A, tau), locking.fbar_weights(Vn, J, S.host, nc))
    H = locking.bbar_gradient(S.gradient(S.to_nodes(du)), Vn, S.host, nc)
    _, D = imp.small_strain_tangent(H, ls, gp, soil)
    w = Vn / np.bincount(S.host, Vn, minlength=nc)[S.host]
    Kg = S.tangent(V0, S.dN, D) + S.bbar_tangent(V0, S.dN, D, w)
    for KK, f in ((K, f_fin), (Kg, f_geo)):
        fd = (f(du + eps * v) - f(du - eps * v)) / (2 * eps)
        assert np.linalg.norm(KK @ v - fd) < 1e-6 * np.linalg.norm(fd)
    fd = (f_fin(du + eps * v) - f_fin(du - eps * v)) / (2 * eps)
    assert np.linalg.norm(K0 @ v - fd) > 1e-2 * np.linalg.norm(fd)
    # B-bar: the force is the derivative of the work sum_p V0 W(eps_bar_p), so its tangent
    # is symmetric for a symmetric D (von Mises is associated)
    assert abs(Kg - Kg.T).max() < 1e-10 * abs(Kg).max()


def _rough_box(**kw):
    """meshes/column_nu0499.toml narrowed to 2 m, implicit, one large-deformation load step
    of a soft (E = 300 kPa), nearly incompressible (nu = 0.49) elastic soil."""
    scene = with_values(load_scene(MESHES / "column_nu0499.toml"), {
        "grid.size": [2.0, 5.5], "soil.polygon": [[0, 0], [2, 0], [2, 5], [0, 5]],
        "soil.youngs_modulus": 300.0, "soil.poisson_ratio": 0.49, "solver.scheme": "implicit",
        "solver.gravity_phase": "dynamic", "solver.load_steps": 1, **kw})
    grid = make_grid(scene)
    pts = seed_particles(scene, grid)
    return imp.run_implicit(scene, grid, pts)


@pytest.mark.parametrize("shape", ["standard", "gimp"])
def test_newton_converges_quadratically_with_fbar(shape, monkeypatch):
    """Quadratic convergence survives F-bar (the cell coupling is in the tangent): rough box,
    nu = 0.49, gravity in one finite-strain load step; over the last iterations
    r_{k+1} / r_k^2 stays < 10 and the residual reaches 1e-9 in <= 6 iterations.  Control:
    without the F-bar coupling term Newton crawls (linear convergence) and fails."""
    rec = _rough_box(**{"solver.fbar": True, "solver.shape": shape})
    r = np.array(rec.solver["steps"][0]["residuals"])
    assert r[-1] < 1e-9 and len(r) - 1 <= 6, r
    tail = [r[k + 1] / r[k] ** 2 for k in range(len(r) - 1) if r[k] < 0.5 and r[k + 1] > 1e-14]
    assert len(tail) >= 2 and max(tail) < 10.0, tail
    monkeypatch.setattr(imp.StepSystem, "fbar_tangent",
                        lambda self, *a: sp.csr_matrix((self.n_free, self.n_free)))
    with pytest.raises(imp.SimulationError, match="Newton did not converge"):
        _rough_box(**{"solver.fbar": True, "solver.shape": shape, "solver.max_iterations": 12,
                      "solver.max_cuts": 0})


# ------------------------------------------------------------------ locking, measured
def _pressure_error(pts, nu, H=5.0, gamma=20.0):
    """Mean pressure against the column closed form, relative to its
    value at the base: p_a = (1 + 2 K0) / 3 gamma (H - y)."""
    K0 = nu / (1 - nu)
    pa = (1 + 2 * K0) / 3 * gamma * (H - pts.x0[:, 1])
    p = locking.mean_pressure(pts.stress)
    return np.abs(p - pa) / ((1 + 2 * K0) / 3 * gamma * H), p


def test_nu0499_rough_box_no_checkerboard_with_fbar():
    """Closed form of the column, meshes/column_nu0499.toml (nu = 0.499 under self-weight between
    rough walls, where the state tends to the column under self-weight as nu -> 0.5).  With
    F-bar — explicit (the shipped scene, damped to rest) and implicit (one geostatic step)
    — the point pressure deviates from the closed form by < 5 % of its base value anywhere
    and the in-cell oscillation index is ~0.  Without it (standard Q4, 2 x 2 points) the
    pressure oscillates odd-even inside the cells (index > 1 %) and is > 5 % off: locking."""
    scene = load_scene(MESHES / "column_nu0499.toml")
    nu = scene.soils[0].poisson_ratio
    out = {}
    for label, s in (("explicit F-bar", scene),
                     ("implicit F-bar", with_values(scene, {"solver.scheme": "implicit"})),
                     ("implicit standard", with_values(scene, {"solver.scheme": "implicit",
                                                               "solver.fbar": False}))):
        grid = make_grid(s)
        pts = seed_particles(s, grid)
        if s.solver.scheme == "explicit":
            rec = run_explicit(s, grid, pts)
            assert rec.stop_reason == "at rest"
        else:
            imp.run_implicit(s, grid, pts)
        err, p = _pressure_error(pts, nu)
        out[label] = (err.max(), locking.checkerboard_index(grid, pts.x, p, pts.volume))
    print({k: (round(a, 4), round(b, 5)) for k, (a, b) in out.items()})
    for label in ("explicit F-bar", "implicit F-bar"):
        dev, cb = out[label]
        assert dev < 0.05 and cb < 1e-4, (label, dev, cb)
    dev, cb = out["implicit standard"]
    assert dev > 0.05 and cb > 0.01, (dev, cb)


def test_laterally_restrained_column_cannot_lock():
    """Why the locking test needs rough walls: the column under self-weight between
    frictionless walls is one-dimensional and Q4 represents its cell-constant strain for
    any nu, so at nu = 0.499 the standard and the F-bar solutions coincide and both meet
    the closed form to the Q4 cell error (gamma h / (2 sqrt 3) over gamma H = 1.4 %)."""
    scene = with_values(load_scene(MESHES / "column.toml"), {
        "soil.poisson_ratio": 0.499, "solver.scheme": "implicit"})
    res = []
    for fbar in (False, True):
        s = with_values(scene, {"solver.fbar": fbar})
        grid = make_grid(s)
        pts = seed_particles(s, grid)
        imp.run_implicit(s, grid, pts)
        res.append(pts.stress.copy())
        err, _ = _pressure_error(pts, 0.499)
        assert err.max() < 0.015
    assert np.allclose(res[0], res[1], rtol=1e-9, atol=1e-9)


# ---------------------------------------------------------------- cell-constant pressure
def _mc_soil(n, rng):
    """Mohr-Coulomb points (c 5 kPa, phi 30, psi 20 deg: non-associated, dilatant; a third
    softening to c 2 / phi 25 / psi 10 over gamma_p 0.5), G 400, K 900 kPa."""
    from fem_rmpm.materials import MaterialPoints, model_id
    from fem_rmpm.materials import mohr_coulomb as mc
    soft = np.arange(n) % 3 == 0
    params = np.stack([np.full(n, 400.0), np.full(n, 900.0), np.full(n, 5.0),
                       np.where(soft, 2.0, 5.0), np.full(n, 30.0), np.where(soft, 25.0, 30.0),
                       np.full(n, 20.0), np.where(soft, 10.0, 20.0), np.full(n, 0.5),
                       np.zeros(n)], axis=1)
    return MaterialPoints(np.full(n, model_id(mc.NAME)), params)


def _mc_cells(grid, seed):
    """800 Mohr-Coulomb points, 4 in each of 200 random cells of ``grid``, compressed
    (log strain -0.01 +- 0.004), step-start volumes 0.01 x U(0.8, 1.2); the step system,
    a displacement increment (0.002 N(0, 1) per DOF) and a direction.  Returns
    ``(S, soil, ls, gp, V0, Vn, n_cells, du, v)``."""
    rng = np.random.default_rng(seed)
    n = 800
    cells = rng.choice(grid.n_cells, 200, replace=False)
    x = grid.nodes[grid.cells[np.repeat(cells, 4), 0]] + rng.random((n, 2)) * grid.cell
    soil = _mc_soil(n, rng)
    ls = -0.01 + 0.004 * rng.normal(size=(n, 4))
    ls[:, 3] *= 0.5
    V0 = np.full(n, 0.01)
    Vn = V0 * rng.uniform(0.8, 1.2, n)
    S = imp.StepSystem(grid, x, "standard", None)
    du = 0.002 * rng.normal(size=S.n_free)
    return S, soil, ls, np.zeros(n), V0, Vn, grid.n_cells, du, rng.normal(size=S.n_free)


def test_cell_pressure_tangent_is_the_derivative_of_its_force(meshes_dir_fx):
    """``[solver] locking_constraint = "pressure"`` (geostatic): each point's strain is
    ``Bbar u + delta / 2 I`` with ``delta`` solved per cell for one in-plane mean stress
    (:func:`fem_rmpm.schemes.locking.uniform_cell_pressure`); the tangent ``K + K_bbar + K_p``
    (:func:`fem_rmpm.schemes.locking.cell_pressure_tangent_correction`) is the directional
    derivative of the assembled force ``sum V0 Bbar^T tau``: central differences of 800
    dilatant, partly softening Mohr-Coulomb points agree to 1e-6 (achieves 7e-11); without
    ``K_p`` they do not (achieves 2.2e-2; asserts > 5e-3).  The converged points of a cell share one
    ``s`` to 1e-12 of max |tau|, and the cell-mean trace is B-bar's."""
    S, soil, ls, gp, V0, Vn, nc, du, v = _mc_cells(meshes_dir_fx, 5)

    def solve(u):
        Hb = locking.bbar_gradient(S.gradient(S.to_nodes(u)), Vn, S.host, nc)
        return locking.uniform_cell_pressure(
            lambda H: small_strain_update(H, ls, gp, soil), Hb, Vn, S.host, nc, tol=1e-14)

    def force(u):
        tau = solve(u)[2][2]
        return S.internal_force(V0, locking.bbar_force_stress(tau, V0, Vn, S.host, nc), S.dN)

    Hm, delta, (_, q, tau), its = solve(du)
    assert 1 <= its and np.any(q > 0)
    s = 0.5 * (tau[:, 0] + tau[:, 1])
    smean = locking.cell_mean(s, Vn, S.host, nc)
    assert np.abs(s - smean).max() <= 1e-12 * np.abs(tau).max()
    assert np.abs(locking.cell_mean(delta, Vn, S.host, nc)).max() <= 1e-14
    assert np.abs(delta).max() > 1e-4           # the points do take their own volume change
    _, D = imp.small_strain_tangent(Hm, ls, gp, soil)
    w = Vn / np.bincount(S.host, Vn, minlength=nc)[S.host]
    Kb = S.tangent(V0, S.dN, D) + S.bbar_tangent(V0, S.dN, D, w)
    K = Kb + S.cell_pressure_tangent(V0, S.dN, D, w)
    eps = 1e-7
    fd = (force(du + eps * v) - force(du - eps * v)) / (2 * eps)
    err = np.linalg.norm(K @ v - fd) / np.linalg.norm(fd)
    err_b = np.linalg.norm(Kb @ v - fd) / np.linalg.norm(fd)
    print("tangent error", err, "without K_p", err_b)
    assert err < 1e-6
    assert err_b > 5e-3


def test_cell_pressure_is_bbar_for_elastic_points(meshes_dir_fx):
    """For isotropic elastic points (uniform pressure stiffness in a cell) from a
    cell-uniform in-plane mean stress (as every geostatic history from rest leaves it) one
    pressure per cell is one volume change per cell: ``delta`` stays 0 (no iteration) and
    the condensation term of the tangent vanishes (to 1e-12 of the tangent)."""
    grid = meshes_dir_fx
    rng = np.random.default_rng(7)
    n = 400
    cells = rng.choice(grid.n_cells, 100, replace=False)
    x = grid.nodes[grid.cells[np.repeat(cells, 4), 0]] + rng.random((n, 2)) * grid.cell
    soil = _soil(n, rng)
    soil.params[:, 2:] = np.inf                      # von Mises that never yields
    ls, gp = np.repeat(1e-3 * rng.normal(size=(100, 4)), 4, axis=0), np.zeros(n)
    Vn = np.full(n, 0.01)
    S = imp.StepSystem(grid, x, "standard", None)
    Hb = locking.bbar_gradient(S.gradient(S.to_nodes(1e-3 * rng.normal(size=S.n_free))),
                               Vn, S.host, grid.n_cells)
    Hm, delta, _, its = locking.uniform_cell_pressure(
        lambda H: small_strain_update(H, ls, gp, soil), Hb, Vn, S.host, grid.n_cells)
    assert its == 0 and np.all(delta == 0)
    _, D = imp.small_strain_tangent(Hm, ls, gp, soil)
    w = np.full(n, 0.25)
    Kp = S.cell_pressure_tangent(Vn, S.dN, D, w)
    Kb = S.tangent(Vn, S.dN, D)
    assert abs(Kp).max() <= 1e-12 * abs(Kb).max()


def test_fbar_work_conjugate_force_and_its_tangent(meshes_dir_fx):
    """Finite strain: the F-bar force ``sum V0 tau(F_bar) grad_x N`` is not the
    derivative of the F-bar work ``sum_p V0_p W(F_bar_p)`` once the in-plane mean stress
    varies inside a cell (dilatant Mohr-Coulomb flow).  The work-conjugate force
    (:func:`fem_rmpm.schemes.locking.fbar_work_stress`: ``tau + e I``) is: its work increment
    along a path equals the points' stress power ``sum V0 tau : dF_bar F_bar^-1`` to
    1e-6 of it (achieves 1e-9, midpoint rule, 16 substeps), the standard force's misses
    by > 1e-3 (achieves 1e-2).  Its tangent (standard + F-bar coupling + geometric
    term of ``e`` + :func:`fem_rmpm.schemes.locking.fbar_work_tangent_correction`) matches
    central differences of the force to 1e-6 (achieves 2e-10)."""
    from fem_rmpm.schemes.explicit.kernels import stress_update_points
    from fem_rmpm.schemes.implicit.tangent import inv2
    S, soil, ls, gp, V0, Vn, nc, du, v = _mc_cells(meshes_dir_fx, 11)

    def state(u):
        dF = np.eye(2) + S.gradient(S.to_nodes(u))
        dFb, J, _ = locking.fbar_increment(dF, Vn, S.host, nc)
        tau = stress_update_points(dFb, ls, gp, soil)[2]
        return dF, dFb, J, tau, np.matmul(S.dN, inv2(dF)[0])

    def force(u, work=True):
        dF, _, J, tau, g = state(u)
        t = locking.fbar_work_stress(tau, V0, Vn, J, S.host, nc) if work else tau
        return S.internal_force(V0, t, g)

    # work along u(t) = t du (elastic-plastic path is history-free here: one trial step)
    m = 16
    ts = (np.arange(m) + 0.5) / m
    w_work = sum(force(t * du) @ du for t in ts) / m
    w_std = sum(force(t * du, False) @ du for t in ts) / m
    h = 1e-6
    power = 0.0
    for t in ts:
        _, dFb, _, tau, _ = state(t * du)
        _, dFb2, _, _, _ = state((t + h) * du)
        L = (dFb2 - dFb) / h @ inv2(dFb)[0]                 # d F_bar / dt F_bar^-1
        power += np.sum(V0 * (tau[:, 0] * L[:, 0, 0] + tau[:, 1] * L[:, 1, 1]
                              + tau[:, 3] * (L[:, 0, 1] + L[:, 1, 0]))) / m
    print("work", w_work, "std", w_std, "power", power)
    assert abs(w_work - power) < 1e-6 * abs(power)
    assert abs(w_std - power) > 1e-3 * abs(power)
    # the tangent
    dF, dFb, J, tau, g = state(du)
    _, A = imp.finite_strain_tangent(dFb, ls, gp, soil)
    w = locking.fbar_weights(Vn, J, S.host, nc)
    e = locking.fbar_work_stress(tau, V0, Vn, J, S.host, nc)[:, 0] - tau[:, 0]
    Ag = np.zeros_like(A)
    for i in range(2):
        for j in range(2):
            Ag[:, i, j, j, i] = -e
    K = (S.tangent(V0, g, A + Ag) + S.fbar_tangent(V0, g, locking.fbar_q(A, tau), w)
         + S.fbar_work_tangent(V0, g, A, tau, w))
    eps = 1e-7
    fd = (force(du + eps * v) - force(du - eps * v)) / (2 * eps)
    err = np.linalg.norm(K @ v - fd) / np.linalg.norm(fd)
    print("tangent error", err)
    assert err < 1e-6
