"""A material model added in one file, run through both schemes and the factor of safety.

This test module *is* the model: Tresca, perfectly plastic (undrained shear strength
``su``, yield ``(tau_1 - tau_3) / 2 <= su`` on the principal Kirchhoff stresses
including ``tau_zz``), written to the protocol of :mod:`fem_rmpm.materials.protocol`
(``NAME``, ``PARAMETERS``, ``STATE``, a numpy ``update``, a numba ``point_update``, and
its strength table ``STRENGTHS`` and its own message for a rejected point) and
registered by a fixture.  No kernel, scheme, strength-reduction or scene code knows it:
the scene validation reads its parameter, the explicit kernels reach it through the
generated dispatch, the numpy reference step and the implicit scheme through its
``update``, the strength reduction through ``STRENGTHS``.  It declares no regularisable
state (it does not soften), so the regularisation of softening leaves its points alone.

Return mapping in principal log-strain space (isotropic, so the principal directions do
not change): the main plane, or the right / left corner when the main-plane return would
break the order of the principal stresses (de Souza Neto, Peric & Owen 2008,
"Computational Methods for Plasticity", Boxes 8.1-8.2, perfect plasticity).
"""
from __future__ import annotations

import dataclasses
import math
import sys
from pathlib import Path

import numpy as np
import pytest
from numba import njit
from soil_points import tangents_agree

from fem_rmpm import materials
from fem_rmpm.discretise.grid import make_grid
from fem_rmpm.discretise.points import seed_particles
from fem_rmpm.materials import MaterialPoints, Parameter, Strength
from fem_rmpm.scene import SceneError, load_scene, scene_from_dict, scene_to_dict
from fem_rmpm.schemes.explicit import kernels as K
from fem_rmpm.schemes.explicit.loop import run_explicit

NAME = "tresca_test"
PARAMETERS = (Parameter("undrained_shear_strength", "kPa", 0.0, math.inf,
                        description="half the largest principal stress difference at yield"),)
STATE = ("plastic_shear_strain",)
STRENGTHS = (Strength("undrained_shear_strength", "c/F"),)     # su / F
TINY = Path(__file__).parent / "data" / "mc_tiny.toml"


def invalid_points(params):
    """Points without strength (su not positive, or not a number): mask and reason."""
    return ~(params[:, 2] > 0), "it has no undrained shear strength"


def point_problem(row):
    """The model's own words for a rejected point."""
    return (f"draws undrained_shear_strength = {row[2]:.4g} kPa; allowed: a positive "
            "strength (lower [random_field] cov)")


# ------------------------------------------------------------------ the model (numpy)
def update(eps_tr, state, params):
    """Tresca return of trial log strains (n, 4) [xx, yy, zz, xy]; complex-safe."""
    G, Kb, su = params[:, 0], params[:, 1], params[:, 2]
    m, d, exy = 0.5 * (eps_tr[:, 0] + eps_tr[:, 1]), 0.5 * (eps_tr[:, 0] - eps_tr[:, 1]), eps_tr[:, 3]
    r = np.sqrt(d * d + exy * exy)
    e = np.stack([m + r, m - r, eps_tr[:, 2]], axis=1)             # principal: a, b, zz
    lam = (Kb - 2 / 3 * G)[:, None]
    t = lam * e.sum(1, keepdims=True) + 2 * G[:, None] * e
    order = np.argsort(-t.real, axis=1)                           # t1 >= t2 >= t3
    ts = np.take_along_axis(t, order, 1)
    A = ts[:, 0] - ts[:, 2] - 2 * su
    B = ts[:, 1] - ts[:, 2] - 2 * su
    C = ts[:, 0] - ts[:, 1] - 2 * su
    dg = A / (4 * G)                                              # main plane
    de = np.stack([dg, 0 * dg, -dg], 1)
    right = (ts[:, 1] > ts[:, 0] - 2 * G * dg).real
    left = (ts[:, 1] < ts[:, 2] + 2 * G * dg).real
    a, b = (2 * A - B) / (6 * G), (2 * B - A) / (6 * G)
    de = np.where(right[:, None], np.stack([a, b, -(a + b)], 1), de)
    a, c = (2 * A - C) / (6 * G), (2 * C - A) / (6 * G)
    de = np.where(left[:, None], np.stack([a + c, -c, -a], 1), de)
    de = np.where((A.real > 0)[:, None], de, 0 * de)              # elastic: no return
    inv = np.argsort(order, axis=1)
    de = np.take_along_axis(de, inv, 1)                           # back to a, b, zz
    ea, eb = e[:, 0] - de[:, 0], e[:, 1] - de[:, 1]
    rn = 0.5 * (ea - eb)
    q = np.where(r.real > 0, rn / np.where(r.real > 0, r, 1.0), 0.0)
    mn = 0.5 * (ea + eb)
    eps = np.stack([mn + q * d, mn - q * d, e[:, 2] - de[:, 2], q * exy], 1)
    # an elastic point keeps its trial strain as given: the rotation back is then exact,
    # and so is the complex-step tangent at an isotropic in-plane strain (r = 0, e.g. the
    # unstrained state where a static solve starts)
    eps = np.where((A.real > 0)[:, None], eps, eps_tr)
    st = state + 0 * de[:, :1]                                   # a copy (complex if de is)
    st[:, 0] = state[:, 0] + np.sqrt(2 * (de * de).sum(1))
    vol = eps[:, 0] + eps[:, 1] + eps[:, 2]
    tau = 2 * G[:, None] * eps
    tau[:, :3] += ((Kb - 2 / 3 * G) * vol)[:, None]
    return eps, st, tau


# ------------------------------------------------------------------ the model (numba)
@njit(inline="always")
def _sorted3(t0, t1, t2):
    """Indices (i, j, k) with t_i >= t_j >= t_k."""
    i, j, k = 0, 1, 2
    a, b, c = t0, t1, t2
    if a < b:
        a, b, i, j = b, a, j, i
    if b < c:
        b, c, j, k = c, b, k, j
    if a < b:
        a, b, i, j = b, a, j, i
    return i, j, k


@njit(inline="always")
def point_update(e0, e1, e2, e3, state, params, i):
    """:func:`update` for point ``i`` (writes ``state[i, 0]``)."""
    G, Kb, su = params[i, 0], params[i, 1], params[i, 2]
    lam = Kb - 2 / 3 * G
    m, d = 0.5 * (e0 + e1), 0.5 * (e0 - e1)
    r = math.sqrt(d * d + e3 * e3)
    e = (m + r, m - r, e2)
    v = e[0] + e[1] + e[2]
    t = (lam * v + 2 * G * e[0], lam * v + 2 * G * e[1], lam * v + 2 * G * e[2])
    o1, o2, o3 = _sorted3(t[0], t[1], t[2])
    A = t[o1] - t[o3] - 2 * su
    if not A > 0:
        return e0, e1, e2, e3, lam * v + 2 * G * e0, lam * v + 2 * G * e1, t[2], 2 * G * e3
    B = t[o2] - t[o3] - 2 * su
    C = t[o1] - t[o2] - 2 * su
    dg = A / (4 * G)
    s1, s2, s3 = dg, 0.0, -dg
    if t[o2] > t[o1] - 2 * G * dg:                                 # right corner
        a, b = (2 * A - B) / (6 * G), (2 * B - A) / (6 * G)
        s1, s2, s3 = a, b, -(a + b)
    elif t[o2] < t[o3] + 2 * G * dg:                               # left corner
        a, c = (2 * A - C) / (6 * G), (2 * C - A) / (6 * G)
        s1, s2, s3 = a + c, -c, -a
    da = s1 if o1 == 0 else (s2 if o2 == 0 else s3)              # back to a, b, zz
    db = s1 if o1 == 1 else (s2 if o2 == 1 else s3)
    dz = s1 if o1 == 2 else (s2 if o2 == 2 else s3)
    ea, eb = e[0] - da, e[1] - db
    q = 0.5 * (ea - eb) / r if r > 0 else 0.0
    mn = 0.5 * (ea + eb)
    x0, x1, x2, x3 = mn + q * d, mn - q * d, e2 - dz, q * e3
    state[i, 0] += math.sqrt(2 * (s1 * s1 + s2 * s2 + s3 * s3))
    vol = x0 + x1 + x2
    return (x0, x1, x2, x3, 2 * G * x0 + lam * vol, 2 * G * x1 + lam * vol,
            2 * G * x2 + lam * vol, 2 * G * x3)


# ------------------------------------------------------------------ tests
@pytest.fixture
def tresca():
    materials.register(sys.modules[__name__])
    yield materials.model_id(NAME)
    materials.registry.unregister(NAME)


def _scene(su=4.0, **extra):
    data = scene_to_dict(load_scene(TINY))
    data.pop("random_field")
    soil = data["soil"][0]
    for k in ("cohesion_peak", "cohesion_residual", "softening", "softening_strain"):
        soil.pop(k)
    soil.update(model=NAME, undrained_shear_strength=su, **extra)
    data["solver"]["t_end"] = 1.0
    return scene_from_dict(data, "tresca.toml")


def _principal_gap(tau):
    """(tau_1 - tau_3) / 2 of Kirchhoff stresses (n, 4)."""
    m, d = 0.5 * (tau[:, 0] + tau[:, 1]), 0.5 * (tau[:, 0] - tau[:, 1])
    r = np.sqrt(d * d + tau[:, 3] ** 2)
    t = np.stack([m + r, m - r, tau[:, 2]], 1)
    return 0.5 * (t.max(1) - t.min(1))


def test_scene_reads_the_new_models_parameters(tresca):
    """The [[soil]] validation takes the parameter's name and range from the module."""
    assert _scene().soils[0].value("undrained_shear_strength") == 4.0
    with pytest.raises(SceneError, match=r"\[soil.undrained_shear_strength\] value -1.0 out "
                                         r"of range; allowed: a number in \(0, inf\) \(kPa\)"):
        _scene(su=-1.0)
    with pytest.raises(SceneError, match=r"\[soil.cohesion_pea\] unknown key for model"):
        _scene(cohesion_pea=3.0)


def test_point_update_kernel_equals_numpy_and_stays_on_the_yield_surface(tresca):
    """The numba point function through the generated dispatch equals the numpy update
    (achieves ~1e-16; asserts 1e-12) on trial states of every return kind (elastic, main
    plane, both corners), and every returned stress satisfies (tau_1 - tau_3)/2 <= su,
    with equality at the plastic points (relative 1e-12)."""
    rng = np.random.default_rng(5)
    n = 4000
    su = rng.uniform(1.0, 12.0, n)
    params = np.stack([np.full(n, 400.0), np.full(n, 900.0), su], 1)
    soil = MaterialPoints(np.full(n, tresca), params)
    dF = np.eye(2) + 0.005 * rng.normal(size=(n, 2, 2))
    eps = 0.003 * rng.normal(size=(n, 4))
    eps[::3, 2] = 0.01 * rng.normal(size=len(eps[::3]))       # zz major or minor: corners
    gam = np.zeros(n)
    e_ref, g_ref, t_ref = materials.stress_update(dF, eps, gam, soil)
    e, g, t = K.stress_update_points(dF, eps, gam, soil)
    for a, b in ((e, e_ref), (g, g_ref), (t, t_ref)):
        assert np.abs(a - b).max() <= 1e-12 * np.abs(b).max()
    gap = _principal_gap(t_ref)
    plastic = g_ref > 0
    assert 0.2 * n < plastic.sum() < 0.8 * n
    assert (gap <= su * (1 + 1e-12)).all()
    np.testing.assert_allclose(gap[plastic], su[plastic], rtol=1e-12)
    # every return kind occurred: corners have the intermediate stress on the surface too
    m, d = 0.5 * (t_ref[:, 0] + t_ref[:, 1]), 0.5 * (t_ref[:, 0] - t_ref[:, 1])
    r = np.sqrt(d * d + t_ref[:, 3] ** 2)
    ts = np.sort(np.stack([m + r, m - r, t_ref[:, 2]], 1), axis=1)
    corner = (np.abs(ts[:, 1] - ts[:, 0]) < 1e-9 * su) | (np.abs(ts[:, 2] - ts[:, 1]) < 1e-9 * su)
    assert 0.1 * n < (plastic & corner).sum() < (plastic & ~corner).sum()


def test_simple_shear_matches_von_mises_where_zz_is_intermediate(tresca):
    """Closed form: isochoric in-plane simple shear from rest keeps tau_zz = the mean
    stress, where (tau_1 - tau_3) / 2 = sqrt(J2); so Tresca(su) and perfectly plastic
    von Mises (c = su) give the same path (achieves 1e-15; asserts 1e-12): tau_xy rises
    with G gamma (small strain) and (tau_1 - tau_3) / 2 stops at su."""
    g = np.linspace(0, 0.05, 51)
    n = len(g)
    dF = np.tile(np.eye(2), (n, 1, 1))
    dF[:, 0, 1] = g
    tres = MaterialPoints(np.full(n, tresca), np.stack([np.full(n, 400.0),
                                                        np.full(n, 900.0), np.full(n, 3.0)], 1))
    vm = MaterialPoints(
        np.full(n, materials.model_id("von_mises_softening")),
        np.stack([np.full(n, 400.0), np.full(n, 900.0), np.full(n, 3.0), np.full(n, 3.0),
                  np.full(n, 0.5), np.zeros(n)], 1))
    z, zs = np.zeros((n, 4)), np.zeros(n)
    _, _, t_tr = K.stress_update_points(dF, z, zs, tres)
    _, _, t_vm = K.stress_update_points(dF, z, zs, vm)
    assert np.abs(t_tr - t_vm).max() <= 1e-12 * np.abs(t_vm).max()
    assert abs(_principal_gap(t_tr[-1:])[0] - 3.0) < 1e-12 * 3.0
    assert abs(t_tr[1, 3] - 400.0 * g[1]) < 1e-3 * 400 * g[1]


def test_explicit_run_numba_equals_numpy(tresca):
    """The tiny slope (152 points) in Tresca clay, 1 s of gravity-driven dynamics (111
    steps), run by the compiled kernels and by the numpy reference step: the same run up
    to round-off grown by the failing slope (achieves 3.6e-7 relative on the velocities,
    2.3e-7 on the stresses with the kernels compiled without FMA contraction; 3.4e-7
    and 1.9e-7 with it: the two steps round differently in every point at every step, and
    the failing slope grows those differences by ~1e8 over the run; asserts 2e-6, an error
    in either implementation shows as 1e-3 or more), and
    the slope yields (Taylor's stability number
    of a 45 degree cut, su / (gamma H) = 4 / 40 = 0.10 < 0.18) with every point on or
    inside the yield surface."""
    scene = _scene()
    grid = make_grid(scene)
    a, b = seed_particles(scene, grid), seed_particles(scene, grid)
    assert set(a.soil.model) == {tresca}
    ra = run_explicit(scene, grid, a, kernel="numpy")
    rb = run_explicit(scene, grid, b, kernel="numba")
    assert ra.steps == rb.steps > 50
    for f in ("x", "velocity", "stress", "log_strain", "state"):
        x, y = getattr(b, f), getattr(a, f)
        assert np.abs(x - y).max() <= 2e-6 * np.abs(y).max(), f
    assert (a.plastic_shear_strain > 0.01).sum() > 20
    tau = a.stress * (a.volume / a.volume0)[:, None]
    assert _principal_gap(tau).max() <= 4.0 * (1 + 1e-9)


def test_implicit_tangent_and_run_use_the_models_update(tresca):
    """The same model through the implicit scheme, with no implicit code knowing it.
    (a) The scheme's consistent tangent (fem_rmpm.schemes.implicit.finite_strain_tangent: complex
    step of the model's update, spin part analytic) equals materials.spatial_tangent (an
    independent complex step of the whole update in four directions) on elastic, main-plane
    and corner states: achieves ~1e-13 relative; asserts 1e-10.  (b) The tiny Tresca slope,
    1 s of implicit (Newmark) dynamics: the run completes, every step converged to the
    tolerance, the slope yields and every point is on or inside the yield surface
    (relative 1e-9)."""
    from fem_rmpm.schemes.implicit import run_implicit
    rng = np.random.default_rng(8)
    n = 600
    params = np.stack([np.full(n, 400.0), np.full(n, 900.0), rng.uniform(2.0, 16.0, n)], 1)
    soil = MaterialPoints(np.full(n, tresca), params)
    dF, eps, state, _ = tangents_agree(soil, rng, 0.004)
    _, g, _ = materials.stress_update(dF, eps, state, soil)
    assert 0.1 * n < (g[:, 0] > 0).sum() < 0.9 * n              # elastic and plastic points
    scene = _scene()
    scene = dataclasses.replace(scene, solver=dataclasses.replace(
        scene.solver, scheme="implicit", dynamic=True, dt=0.05))
    grid = make_grid(scene)
    pts = seed_particles(scene, grid)
    rec = run_implicit(scene, grid, pts)
    assert rec.stop_reason in ("t_end reached", "at rest") and rec.time == pytest.approx(1.0)
    steps = rec.solver["steps"]
    assert all(s["residuals"][-1] <= scene.solver.tolerance for s in steps)
    assert (pts.plastic_shear_strain > 0.01).sum() > 20
    tau = pts.stress * (pts.volume / pts.volume0)[:, None]
    assert _principal_gap(tau).max() <= 4.0 * (1 + 1e-9)


# ------------------------------------------------------------------ strength reduction
def _infinite_slope(meshes, z=5.0, beta=20.0, rows=20, hx=0.5, length=12.0, su=20.0):
    """meshes/infinite_slope.toml in Tresca clay: vertical depth z (m), angle beta (deg),
    ``rows`` cells over the normal thickness t = z cos(beta), cells ``hx`` t long, a layer
    ``length`` t long on the fixed bedrock, both ends free."""
    data = scene_to_dict(load_scene(meshes / "infinite_slope.toml"))
    t = z * math.cos(math.radians(beta))
    L = length * t
    soil = data["soil"][0]
    for k in ("cohesion_peak", "cohesion_residual", "softening", "softening_strain"):
        soil.pop(k, None)
    soil.update(model=NAME, undrained_shear_strength=su,
                polygon=[[0, 0], [L, 0], [L, t], [0, t]])
    data["scene"]["frame_angle_deg"] = beta
    data["grid"].update(size=[L, t], cell=[hx * t, t / rows])
    return scene_from_dict(data, "tresca_infinite_slope.toml")


def test_strength_reduction_scales_the_declared_strength(tresca):
    """The strength reduction reads the model's STRENGTHS: su / F, nothing else."""
    from fem_rmpm.materials import strength
    from fem_rmpm.schemes.implicit.strength_reduction import strength_parameters
    assert strength_parameters(NAME) == ("undrained_shear_strength",)
    rows = np.array([[400.0, 900.0, 12.0], [400.0, 900.0, 3.0]])
    out = strength.reduce_strength(NAME, rows, 1.5, softening=False)
    assert np.array_equal(out[:, :2], rows[:, :2]) and np.array_equal(out[:, 2], rows[:, 2] / 1.5)
    assert NAME in strength.models_with_strength()


def test_factor_of_safety_of_the_undrained_infinite_slope(tresca, meshes):
    """Closed form: the undrained infinite slope FS = su / (gamma z sin(beta) cos(beta))
    (limit equilibrium of a slice; Duncan & Wright 2005, ch. 6), here 20 / (20 x 5 x
    sin 20 cos 20) = 0.622.  Plane-strain simple shear along the slope keeps tau_zz
    intermediate, where Tresca's (tau_1 - tau_3) / 2 is von Mises' sqrt(J2).  On the mesh
    of the von Mises layer of tests/test_strength_reduction.py (20 rows over the
    thickness, 1920 points) it achieves FS 0.625 (+0.5 %) in 6 static solves; asserts
    that test's 2 %."""
    from fem_rmpm import api
    from fem_rmpm.schemes.implicit.strength_reduction import factor_of_safety
    scene = _infinite_slope(meshes)
    grid, pts = api.prepare(scene)
    res = factor_of_safety(scene, grid=grid, pts=pts)
    b = math.radians(20.0)
    exact = 20.0 / (20.0 * 5.0 * math.sin(b) * math.cos(b))
    assert res.bound == "=" and res.bracket[1] / res.bracket[0] - 1 <= 0.01
    assert abs(res.fs / exact - 1) < 0.02, (res.fs, exact)


def test_a_rejected_point_is_told_in_the_models_words(tresca):
    """A point whose model rejects its values (here a strength of 0) is reported with the
    model's own message, after the point's position."""
    soil = MaterialPoints(np.full(3, tresca), np.array([[400.0, 900.0, 4.0],
                                                        [400.0, 900.0, 0.0],
                                                        [400.0, 900.0, 4.0]]))
    x0 = np.array([[0.0, 0.0], [1.25, 0.5], [2.0, 0.0]])
    assert materials.point_problem(soil, x0) == (
        "material point 1 at x = 1.25, y = 0.50 m draws undrained_shear_strength = 0 kPa; "
        "allowed: a positive strength (lower [random_field] cov)")
    assert materials.point_problem(soil.take([0, 2]), x0[[0, 2]]) is None
