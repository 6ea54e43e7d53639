"""Implicit Newton MPM: from the Gauss points to large compaction.

References: closed forms (column, compaction, explicit time step); Charlton,
Coombs & Augarde 2017 (AMPLE / iGIMP, Computers & Structures 190: the
compaction benchmark and the updated-Lagrangian implicit MPM), the closed forms
quoted in each docstring.
"""
from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import meshio
import numpy as np
import pytest
from scipy.integrate import quad
from scipy.special import lambertw
from soil_points import vm_points

from fem_rmpm import api
from fem_rmpm.cli import main
from fem_rmpm.discretise.basis import q4_at_points
from fem_rmpm.discretise.grid import make_grid
from fem_rmpm.discretise.points import seed_particles
from fem_rmpm.materials import small_strain_update, spatial_tangent, stress_update
from fem_rmpm.scene import load_scene
from fem_rmpm.schemes import implicit as imp
from fem_rmpm.schemes.common import SimulationError
from fem_rmpm.schemes.fem import solve_static

MESHES = Path(__file__).resolve().parents[1] / "meshes"


def _solver(scene, **kw):
    return dataclasses.replace(scene, solver=dataclasses.replace(scene.solver, **kw))


def _run(scene, **kw):
    scene = _solver(scene, **kw)
    grid = make_grid(scene)
    pts = seed_particles(scene, grid)
    rec = imp.run_implicit(scene, grid, pts)
    return grid, pts, rec


def _rel_l2(a, b, w):
    a, b = a.reshape(len(w), -1), b.reshape(len(w), -1)
    return float(np.sqrt(np.sum(np.sum((a - b) ** 2, 1) * w) / np.sum(np.sum(b ** 2, 1) * w)))


def _hencky_settlement(Y, gamma, M, H):
    """Closed form (oedometric Hencky/Kirchhoff): Cauchy
    M ln(lambda)/lambda = -gamma (H - Y) gives lambda = exp(-W0(s)), s = gamma (H - Y)/M,
    and u(Y) = integral_0^Y (lambda - 1) dY."""
    lam = lambda y: float(np.exp(-lambertw(gamma * (H - y) / M).real))  # noqa: E731
    return quad(lambda y: lam(y) - 1.0, 0.0, Y, limit=200)[0]


def _random_state(n, seed=1):
    rng = np.random.default_rng(seed)
    idx = np.arange(n)
    plastic = idx % 3 != 2
    soil = vm_points(shear_modulus=np.full(n, 400.0), bulk_modulus=np.full(n, 900.0),
                      cohesion_peak=np.where(plastic, 5.0, np.inf),
                      cohesion_residual=np.where(plastic, 2.0, np.inf),
                      softening_strain=np.full(n, 0.5), exponential=idx % 3 == 1)
    dF = np.eye(2) + 0.05 * rng.normal(size=(n, 2, 2))
    ls = 0.02 * rng.normal(size=(n, 4))
    gp = np.abs(0.1 * rng.normal(size=n))
    return soil, dF, ls, gp


# ------------------------------------------------------------------ 1. Gauss points = FEM
@pytest.mark.parametrize("name", ["column.toml", "slope_elastic.toml"])
def test_one_static_step_at_gauss_points_equals_fem(name):
    """The column under self-weight and the elastic reference slope: with the points at
    the 2x2 Gauss points (volume area/4), one geostatic (small-strain) implicit step is the
    scikit-fem Q4 solution of fem.solve_static: displacement and stress to relative 1e-10,
    in one Newton iteration (the problem is linear)."""
    scene = _solver(load_scene(MESHES / name), scheme="implicit", gravity_phase="geostatic",
                    dynamic=False, load_steps=1)
    grid = make_grid(scene)
    pts = seed_particles(scene, grid)
    rec = imp.run_implicit(scene, grid, pts)
    fem = solve_static(scene, grid)
    from scipy.spatial import cKDTree
    d, i = cKDTree(fem.points).query(pts.x0)
    assert d.max() < 1e-9
    _, nodes, N, _, _ = q4_at_points(grid, pts.x0)
    u_fem = np.einsum("pa,pak->pk", N, fem.displacement[nodes])
    du = np.linalg.norm(pts.displacement - u_fem) / np.linalg.norm(u_fem)
    ds = np.linalg.norm(pts.stress - fem.stress[i]) / np.linalg.norm(fem.stress[i])
    assert du < 1e-10 and ds < 1e-10, (du, ds)
    assert rec.solver["steps"][0]["iterations"] == 1
    assert np.array_equal(pts.x, pts.x0)             # geostatic: the points do not move


# ------------------------------------------------------------------ tangent and assembly
def test_fast_tangent_equals_material_spatial_tangent():
    """The batched complex-step tangent (symmetric part by complex step, spin part
    analytic for the isotropic law) equals material.spatial_tangent to round-off, for
    elastic, linearly and exponentially softening points."""
    soil, dF, ls, gp = _random_state(300)
    tau1, A1 = spatial_tangent(dF, ls, gp, soil)
    tau2, A2 = imp.finite_strain_tangent(dF, ls, gp, soil)
    _, _, t_plastic = stress_update(dF, ls, gp, soil)
    assert np.allclose(tau1, tau2, rtol=0, atol=1e-12 * np.abs(tau1).max())
    assert np.abs(A1 - A2).max() < 1e-12 * np.abs(A1).max()
    assert np.allclose(tau1, t_plastic)


def test_small_strain_tangent_is_the_derivative_of_small_strain_update():
    """Geostatic tangent D_ijlm = d tau_ij / d grad(du)_lm: against a complex step taken
    through material.small_strain_update itself (all four components of grad du)."""
    soil, dF, ls, gp = _random_state(200, seed=3)
    H = dF - np.eye(2)
    tau, D = imp.small_strain_tangent(H, ls, gp, soil)
    h = 1e-30
    for l in range(2):
        for m in range(2):
            Hc = H.astype(complex)
            Hc[:, l, m] += 1j * h
            _, _, tc = small_strain_update(Hc, ls, gp, soil)
            d = tc.imag / h
            assert np.abs(D[:, 0, 0, l, m] - d[:, 0]).max() < 1e-10 * np.abs(D).max()
            assert np.abs(D[:, 1, 1, l, m] - d[:, 1]).max() < 1e-10 * np.abs(D).max()
            assert np.abs(D[:, 0, 1, l, m] - d[:, 3]).max() < 1e-10 * np.abs(D).max()


def test_vectorised_assembly_equals_scikit_fem_asm(meshes_dir_fx):
    """The tangent and internal force with the material points as
    quadrature, assembled by skfem.asm (forms in implicit.py, skfem_point_basis) and by
    the vectorised numpy path used in the run, agree to round-off (a deformed,
    partly plastic state with points off the Gauss points)."""
    grid = meshes_dir_fx
    rng = np.random.default_rng(5)
    cells = rng.choice(grid.n_cells, 300, replace=False)
    lower = grid.nodes[grid.cells[np.repeat(cells, 3), 0]]
    x = lower + rng.random((900, 2)) * grid.cell
    soil, dF, ls, gp = _random_state(900, seed=7)
    V0 = np.full(900, 0.01)
    S = imp.StepSystem(grid, x)
    tau, A = imp.finite_strain_tangent(dF, ls, gp, soil)
    Finv = np.linalg.inv(dF)
    g = np.matmul(S.dN, Finv)
    K_fast = S.tangent(V0, g, A)
    f_fast = S.internal_force(V0, tau, g)
    K_sk, f_sk = imp.skfem_assemble(grid, x, V0, dF, tau, A)
    K_sk = K_sk[S.free_dofs][:, S.free_dofs]
    assert abs(K_fast - K_sk).max() < 1e-12 * abs(K_sk).max()
    assert np.abs(f_fast - f_sk[S.free_dofs]).max() < 1e-12 * np.abs(f_sk).max()


@pytest.mark.parametrize("shape", ["standard", "gimp"])
def test_tangent_is_the_derivative_of_the_internal_force(meshes_dir_fx, shape):
    """The assembled K (material + geometric stiffness) is the directional derivative of
    the assembled internal force f(du) = sum_p V0 tau(dF) dF^-T grad N: central
    differences along a random direction agree to 1e-6 (truncation-limited), for the
    Q4 basis and for uGIMP (9 nodes per point, which scikit-fem's asm cannot check)."""
    grid = meshes_dir_fx
    rng = np.random.default_rng(2)
    cells = rng.choice(grid.n_cells, 200, replace=False)
    x = grid.nodes[grid.cells[np.repeat(cells, 4), 0]] + rng.random((800, 2)) * grid.cell
    soil, _, ls, gp = _random_state(800, seed=4)
    V0 = np.full(800, 0.01)
    S = imp.StepSystem(grid, x, shape, np.tile(grid.cell / 4, (800, 1)))

    def f_int(du):
        dF = np.eye(2) + S.gradient(S.to_nodes(du))
        _, _, tau = stress_update(dF, ls, gp, soil)
        return S.internal_force(V0, tau, np.matmul(S.dN, np.linalg.inv(dF)))

    du = 0.01 * rng.normal(size=S.n_free)
    dF = np.eye(2) + S.gradient(S.to_nodes(du))
    _, A = imp.finite_strain_tangent(dF, ls, gp, soil)
    K = S.tangent(V0, np.matmul(S.dN, np.linalg.inv(dF)), A)
    v = rng.normal(size=S.n_free)
    eps = 1e-6
    fd = (f_int(du + eps * v) - f_int(du - eps * v)) / (2 * eps)
    assert np.linalg.norm(K @ v - fd) < 1e-6 * np.linalg.norm(fd)


# ------------------------------------------------------------------ 2. compaction
def test_column_compaction_top_displacement_hencky():
    """Charlton et al. 2017 (AMPLE): l0 = 50 m, E = 10 kPa, nu = 0,
    rho0 = 0.08 t/m3, g = 10, one cell wide, uGIMP, 32 cells, 50 load steps.  The top
    settles -25.940 m (Hencky/Kirchhoff: lambda = exp(-W0(s))); the top material point
    must be within 1 % of the closed form at its initial height, and the stress error
    norm sum_p |sigma_p - sigma_a| V_p / (rho0 g l0 V0) below 1 %.  These are discretisation
    errors (32 cells), so the benchmark's 1 % is kept and a regression guard near the
    achieved figures is added: top 0.726 % (asserts 0.85 %), stress norm 0.609 % (asserts
    0.7 %); at most 4 Newton iterations per step (asserts 6)."""
    scene = load_scene(MESHES / "compaction.toml")
    grid, pts, rec = _run(scene)
    top = np.argmax(pts.x0[:, 1])
    ua = _hencky_settlement(pts.x0[top, 1], 0.8, 10.0, 50.0)
    assert abs(_hencky_settlement(50.0, 0.8, 10.0, 50.0) - (-25.940)) < 5e-4
    assert abs(pts.displacement[top, 1] / ua - 1) < 0.0085, (pts.displacement[top, 1], ua)
    sigma_a = -0.8 * (50.0 - pts.x0[:, 1])
    err = np.sum(np.abs(pts.stress[:, 1] - sigma_a) * pts.volume) / (0.8 * 50.0 * pts.volume0.sum())
    assert err < 0.007, err
    assert max(s["iterations"] for s in rec.solver["steps"]) <= 6


# ------------------------------------------------------------------ 3. quadratic convergence
def _soft_column_residuals(monkeypatch=None):
    scene = _solver(load_scene(MESHES / "soft_column.toml"), load_steps=1, max_iterations=30)
    _, pts, rec = _run(scene)
    return rec.solver["steps"][0]["residuals"]


def test_newton_converges_quadratically(monkeypatch):
    """Full Newton with the consistent tangent: over the last iterations of a loaded step
    (soft column, gravity in one step) r_{k+1} / r_k^2 stays bounded (< 10) while the
    residual falls from 1 to round-off.  Control: dropping the geometric (initial-stress)
    term -delta_jl tau_im from the tangent makes convergence linear (the same ratio
    explodes and more iterations are needed), so the test can tell."""
    r = np.array(_soft_column_residuals())
    assert r[-1] < 1e-9 and len(r) - 1 <= 6
    tail = [(r[k + 1] / r[k] ** 2) for k in range(len(r) - 1) if r[k] < 0.5 and r[k + 1] > 1e-14]
    assert len(tail) >= 2
    assert max(tail) < 10.0, tail

    full = imp.finite_strain_tangent

    def no_geometric(dF, ls, gp, soil, **kw):
        tau, A = full(dF, ls, gp, soil, **kw)
        return tau, A + np.einsum("jl,nim->nijlm", np.eye(2), imp.tangent.tensor(tau))

    monkeypatch.setattr(imp.steps, "finite_strain_tangent", no_geometric)
    r2 = np.array(_soft_column_residuals())
    ratios = [r2[k + 1] / r2[k] ** 2 for k in range(len(r2) - 1) if r2[k + 1] > 1e-14]
    assert len(r2) > len(r) + 2 and max(ratios) > 100 * max(tail)


# ------------------------------------------------------------------ 4. soft column
@pytest.mark.parametrize("steps", [1, 10])
def test_soft_column_large_deformation(steps):
    """Closed form of a soft column (the case a peer code never converges on): E = 1000 kPa,
    nu = 0.3, unit weight 20, H = 10 m, 0.25 m cells (uGIMP), gravity in 1 and in 10
    load steps: <= 10 Newton iterations per step, settlement within 1 % of the closed
    form (oedometric Hencky, Cauchy M ln(lambda)/lambda = -gamma (H - Y)).
    Achieved: 1 step -1.1e-4 in 4 iterations (asserts 5e-4); 10 steps +2.0e-3 in 3
    iterations each (asserts 4e-3: the updated-Lagrangian uGIMP domains move between
    steps, a load-path discretisation the single step does not have)."""
    scene = load_scene(MESHES / "soft_column.toml")
    _, pts, rec = _run(scene, load_steps=steps)
    its = [s["iterations"] for s in rec.solver["steps"]]
    assert len(its) == steps and max(its) <= 10, its
    M = scene.soils[0].constrained_modulus
    top = np.argmax(pts.x0[:, 1])
    ua = _hencky_settlement(pts.x0[top, 1], 20.0, M, 10.0)
    assert ua < -0.6                                       # large: 12 % strain at the base
    assert abs(pts.displacement[top, 1] / ua - 1) < (5e-4 if steps == 1 else 4e-3), \
        (pts.displacement[top, 1], ua)
    assert rec.stop_reason == "load applied"


# ------------------------------------------------------------------ 5. explicit vs implicit
def test_explicit_and_implicit_agree_on_elastic_slope():
    """Independent solver, elastic reference slope: the explicit run
    of meshes/slope_elastic.toml (geostatic phase, damped to rest) and the implicit
    scheme on the same scene agree in stress (volume-weighted relative L2) for the implicit
    geostatic step (small strain, the same problem: achieves 6.9e-5, asserts 3e-4) and for
    one large-deformation load step (finite strain against the explicit small-strain
    geostatic state: the 1.6e-2 achieved is the geometric non-linearity; asserts 2.5e-2)."""
    scene = load_scene(MESHES / "slope_elastic.toml")
    res = api.run(scene)
    assert res.record.stop_reason == "at rest"
    s_exp, w = res.particles.stress, res.particles.volume0
    for kw in (dict(gravity_phase="geostatic"), dict(gravity_phase="dynamic", load_steps=1)):
        _, pts, rec = _run(scene, scheme="implicit", dynamic=False, **kw)
        err = _rel_l2(pts.stress, s_exp, w)
        assert err < (3e-4 if kw["gravity_phase"] == "geostatic" else 2.5e-2), (kw, err)


# ------------------------------------------------------------------ 6. loud failure
def _plastic_column_file(tmp_path, max_iterations, max_cuts):
    """meshes/column.toml with von Mises soil (c = 21 kPa, no softening) under implicit
    geostatic load steps of 0.1.  Elastic plane strain: sigma_xx = K0 sigma_yy with
    K0 = nu/(1 - nu) and sigma_zz = nu (sigma_xx + sigma_yy) = K0 sigma_yy, so
    sqrt(J2) = (1 - K0) |sigma_yy| / sqrt(3).  The Q4 stress is cell-constant, the value at
    the cell centre, so the base cells (y_c = h/2 = 0.125 m) yield first, at the load factor
    lambda_y = sqrt(3) c / ((1 - K0) gamma (H - h/2)) = 21 / 28.566 = 0.7351.  Steps 1-7
    (lambda <= 0.7, 4.8 % below) are elastic (linear: one Newton iteration); step 8 is the
    first plastic one (two iterations), and so is its half (0.7 -> 0.75, 2 % above yield).
    (With c = 20 kPa the first yield is at 0.7001, 0.02 % above step 7: too thin a margin.)"""
    text = (MESHES / "column.toml").read_text()
    text = text.replace('model = "linear_elastic"', 'model = "von_mises_softening"\n'
                        'cohesion_peak = 21.0\ncohesion_residual = 21.0')
    text = text.replace('scheme = "explicit"', 'scheme = "implicit"\nload_steps = 10\n'
                        f'max_iterations = {max_iterations}\nmax_cuts = {max_cuts}')
    p = tmp_path / f"plastic_column_{max_iterations}.toml"
    p.write_text(text + "\n[output]\npng = false\n")
    return p


def test_forced_nonconvergence_fails_loudly_and_keeps_output(tmp_path, capsys):
    """A run that cannot converge (plastic column, max_iterations = 1:
    the elastic steps are linear and converge, the first plastic step needs two iterations,
    halving it once does not help) stops with exit code 3 and a one-line error naming the
    step, the residual history and what to change; summary.json holds the error and every
    converged step's residuals; the VTK series holds the initial state and each converged
    step, all finite."""
    scene_file = _plastic_column_file(tmp_path, max_iterations=1, max_cuts=1)
    out = tmp_path / "run"
    code = main(["run", str(scene_file), "--out", str(out), "--quiet"])
    err = capsys.readouterr().err
    assert code == 3
    assert "Newton did not converge after 1 cut(s)" in err and "geostatic step 8 of 10" in err
    assert "relative residuals of the last attempt" in err and "max_iterations (now 1)" in err
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "failed" and "Newton did not converge" in summary["error"]
    solver = summary["solver"]
    assert solver["last_converged_step"] == 7 and len(solver["steps"]) == 7
    assert all(s["residuals"][-1] <= 1e-9 and s["iterations"] == 1 for s in solver["steps"])
    assert len(solver["failed_residuals"]) == 2 and solver["failed_residuals"][-1] > 1e-9
    assert solver["cuts_total"] == 1
    vtus = sorted(out.glob("particles_*.vtu"))
    assert len(vtus) == 8
    last = meshio.read(vtus[-1])
    for v in last.point_data.values():
        assert np.all(np.isfinite(v))
    # the last snapshot is the (elastic, Q4) state at load factor 0.7: the cell-constant
    # sigma_yy of Q4 is exact at the cell centre, -0.7 gamma (H - y_c)
    y_c = (np.floor(last.points[:, 1] / 0.25) + 0.5) * 0.25
    assert np.allclose(last.point_data["stress"][:, 1], -0.7 * 20.0 * (5.0 - y_c), rtol=1e-9)
    # with two iterations allowed the same run completes
    assert main(["run", str(_plastic_column_file(tmp_path, 2, 0)), "--out",
                 str(tmp_path / "ok"), "--quiet"]) == 0


def test_step_cutting_recovers_and_is_recorded():
    """A step that needs 4 iterations with max_iterations = 3 is halved until it converges
    (soft column, one load step): the run succeeds, the cuts are recorded per step, and
    the settlement still meets the closed form: achieves 1.8e-3 in 3 cuts (asserts 4e-3)."""
    scene = load_scene(MESHES / "soft_column.toml")
    _, pts, rec = _run(scene, load_steps=1, max_iterations=3)
    steps = rec.solver["steps"]
    assert rec.solver["cuts_total"] >= 1 and len(steps) > 1
    assert abs(sum(s["size"] for s in steps) - 1.0) < 1e-12
    top = np.argmax(pts.x0[:, 1])
    ua = _hencky_settlement(pts.x0[top, 1], 20.0, scene.soils[0].constrained_modulus, 10.0)
    assert abs(pts.displacement[top, 1] / ua - 1) < 4e-3


def test_summary_json_holds_residual_history(tmp_path):
    """summary.json has the solver statistics: every step with
    its residual history, iterations and the time split per Newton iteration."""
    scene = _solver(load_scene(MESHES / "soft_column.toml"), load_steps=2)
    api.run(scene, out=tmp_path, figures=False)
    s = json.loads((tmp_path / "summary.json").read_text())["solver"]
    assert len(s["steps"]) == 2
    assert all(st["residuals"][0] > st["residuals"][-1] for st in s["steps"])
    assert set(s["ms_per_iteration"]) == {"setup", "material", "assembly", "solve"}
    assert s["iterations_total"] == sum(st["iterations"] for st in s["steps"])
    assert len(list(tmp_path.glob("particles_*.vtu"))) == 3


# ------------------------------------------------------------------ linear solvers, dynamics
def test_pyamg_solver_matches_superlu():
    """The pyamg option (smoothed aggregation with rigid-body modes, as a CG
    preconditioner) gives the SuperLU solution of the elastic slope's geostatic step:
    achieves 7.0e-14 relative (asserts 1e-12), final residual 2.5e-14 (asserts 1e-9, the
    Newton tolerance)."""
    scene = load_scene(MESHES / "slope_elastic.toml")
    kw = dict(scheme="implicit", gravity_phase="geostatic", dynamic=False)
    _, p1, _ = _run(scene, linear_solver="superlu", **kw)
    _, p2, rec = _run(scene, linear_solver="pyamg", **kw)
    d = np.linalg.norm(p1.u_geostatic - p2.u_geostatic) / np.linalg.norm(p1.u_geostatic)
    assert d < 1e-12 and rec.solver["steps"][0]["residuals"][-1] < 1e-9


def test_newmark_sudden_gravity_on_stiff_column():
    """Newmark trapezoidal (beta 1/4, gamma 1/2) on a stiff elastic column (E = 1e5 kPa,
    small strain) under suddenly applied gravity: the undamped response swings to twice
    the static settlement (1-D wave solution: u_max = 2 u_static) with the period of the
    first mode T = 4 H / c_p (c_p = sqrt(M / rho)).  Sampled every T/40:
    the amplitude achieves -2.1e-3 (asserts 6e-3); the time of the first minimum is one
    sample (T/40 = 5 % of T/2) from T/2 (asserts 7.5 %: within 1.5 samples)."""
    scene = load_scene(MESHES / "column.toml")
    scene = dataclasses.replace(scene, soils=(dataclasses.replace(scene.soils[0],
                                                                  youngs_modulus=1e5),))
    M = scene.soils[0].constrained_modulus
    T = 4 * 5.0 / np.sqrt(M / (20.0 / 9.81))
    scene = _solver(scene, scheme="implicit", dynamic=True, gravity_phase="dynamic",
                    gravity_ramp_time=0.0, dt=T / 40, t_end=1.5 * T, output_interval=T / 40)
    grid = make_grid(scene)
    pts = seed_particles(scene, grid)
    top = np.argmax(pts.x0[:, 1])
    hist = []
    imp.run_implicit(scene, grid, pts, on_output=lambda t, p: hist.append(
        (t, p.displacement[top, 1])))
    t, u = np.array(hist).T
    Y = pts.x0[top, 1]
    u_static = -(20.0 / M) * (5.0 * Y - Y * Y / 2)
    assert abs(u.min() / (2 * u_static) - 1) < 6e-3
    t_min = t[np.argmin(u[t < T])]
    assert abs(t_min / (T / 2) - 1) < 0.075
    assert np.all(np.isfinite(pts.stress))


def test_geostatic_then_newmark_starts_in_equilibrium():
    """gravity_phase = "geostatic" with dynamic = true: the small-strain geostatic step is
    the FEM state (the column under self-weight), the Newmark phase then starts in equilibrium
    (no Newton iteration needed, no motion) and stops at rest; one snapshot at t = 0."""
    scene = _solver(load_scene(MESHES / "column.toml"), scheme="implicit", dynamic=True,
                    gravity_phase="geostatic", dt=0.05, t_end=1.0)
    grid = make_grid(scene)
    pts = seed_particles(scene, grid)
    times = []
    rec = imp.run_implicit(scene, grid, pts, on_output=lambda t, p: times.append(t))
    phases = [(s["phase"], s["iterations"]) for s in rec.solver["steps"]]
    assert phases[0] == ("geostatic", 1) and phases[1] == ("dynamic", 0)
    assert rec.stop_reason == "at rest" and times[0] == 0.0 and times.count(0.0) == 1
    fem = solve_static(scene, grid)
    _, nodes, N, _, _ = q4_at_points(grid, pts.x0)
    u_fem = np.einsum("pa,pak->pk", N, fem.displacement[nodes])
    assert np.linalg.norm(pts.displacement - u_fem) < 1e-10 * np.linalg.norm(u_fem)
    assert np.array_equal(pts.x, pts.x0) and np.abs(pts.velocity).max() == 0.0
