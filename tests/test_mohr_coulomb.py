"""Mohr–Coulomb with softening (``fem_rmpm.materials.mohr_coulomb``), at material points.

References: the Mohr–Coulomb limit ``sigma_1 = sigma_3 N_phi + 2 c sqrt(N_phi)``,
``N_phi = (1 + sin phi) / (1 - sin phi)`` (compression positive; e.g. Chen & Saleeb
1982, *Constitutive Equations for Engineering Materials*, sec. 5.4); the dilatancy of a
plastic step on the main plane ``d_eps_v / (d_eps_1 - d_eps_3) = sin(psi)`` and the apex
``p = c cot(phi)`` (de Souza Neto, Peric & Owen 2008, sec. 8.2); Tresca = von Mises in
plane-strain pure shear (both yield at a shear stress c).
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from soil_points import tangents_agree

from fem_rmpm import api, materials
from fem_rmpm.materials import MaterialPoints
from fem_rmpm.materials import mohr_coulomb as mc
from fem_rmpm.materials import mohr_coulomb_return as mcr
from fem_rmpm.materials import von_mises as vm
from fem_rmpm.scene import SceneError, load_scene, scene_from_dict, scene_to_dict
from fem_rmpm.schemes.explicit import kernels as K
from fem_rmpm.schemes.explicit.loop import run_explicit

E, NU = 1e4, 0.3
G, KB = E / (2 * (1 + NU)), E / (3 * (1 - 2 * NU))
TINY = Path(__file__).parent / "data" / "mc_tiny.toml"


def _params(c=10.0, phi=30.0, psi=0.0, c_r=None, phi_r=None, psi_r=None, gs=0.5, expo=0):
    return np.array([[G, KB, c, c if c_r is None else c_r, phi, phi if phi_r is None else phi_r,
                      psi, psi if psi_r is None else psi_r, gs, expo]], dtype=float)


def _principal(tau):
    """Principal stresses (n, 3) in decreasing order (tension positive)."""
    m, d = 0.5 * (tau[:, 0] + tau[:, 1]), 0.5 * (tau[:, 0] - tau[:, 1])
    r = np.sqrt(d * d + tau[:, 3] ** 2)
    return -np.sort(-np.stack([m + r, m - r, tau[:, 2]], 1), axis=1)


def _yield(tau, c, phi):
    s = _principal(tau)
    sp = math.sin(math.radians(phi))
    return s[:, 0] - s[:, 2] + (s[:, 0] + s[:, 2]) * sp - 2 * c * math.cos(math.radians(phi))


def _compression(confining, prm, steps=60, d_axial=-1e-3):
    """Plane-strain compression of one point: axial (yy) log strain decreased in steps,
    eps_zz fixed, lateral (xx) strain found at each step so that tau_xx = -confining.
    Returns the axial stress history and the strain and state history."""
    eps = np.full((1, 4), -confining / (3 * KB))
    eps[0, 3] = 0.0
    state = np.zeros((1, 1))
    axial, path = [], []
    for _ in range(steps):
        de = np.array([[0.0, d_axial, 0.0, 0.0]])
        x = 0.0
        for _ in range(30):                       # Newton on the lateral strain (complex step)
            trial = eps + de + np.array([[x + 1e-30j, 0, 0, 0]])
            e1, s1, t1 = mc.update(trial, state, prm)
            r, dr = t1[0, 0].real + confining, t1[0, 0].imag / 1e-30
            x -= r / dr
            if abs(r) < 1e-11 * confining:
                break
        e1, s1, t1 = mc.update(eps + de + np.array([[x, 0, 0, 0]]), state, prm)
        path.append((de[0] + np.array([x, 0, 0, 0]), e1[0] - eps[0], s1[0, 0]))
        eps, state = e1, s1
        axial.append(t1[0, 1])
    return np.array(axial), path


@pytest.mark.parametrize("confining", [50.0, 100.0, 200.0])
def test_plane_strain_compression_reaches_mohr_coulomb(confining):
    """c = 10 kPa, phi = 30 deg, psi = 0, perfectly plastic: the axial stress levels off at
    sigma_3 N_phi + 2 c sqrt(N_phi) (achieves 1e-13 relative; asserts 0.5 % and
    1e-9)."""
    c, phi = 10.0, 30.0
    axial, _ = _compression(confining, _params(c, phi))
    nphi = (1 + math.sin(math.radians(phi))) / (1 - math.sin(math.radians(phi)))
    limit = confining * nphi + 2 * c * math.sqrt(nphi)
    assert abs(-axial[-1] - limit) <= 5e-3 * limit
    assert abs(-axial[-1] - limit) <= 1e-9 * limit
    assert np.all(-axial <= limit * (1 + 1e-12))            # never above the limit


def test_dilation_rate_is_set_by_psi():
    """Non-associated flow (phi = 30, psi = 10 deg): in the plastic steps the volumetric
    plastic strain over the principal plastic strain difference is sin(psi) (achieves
    1e-12; asserts 1e-9); psi = 0 gives no plastic volume change."""
    for psi in (10.0, 0.0):
        prm = _params(10.0, 30.0, psi)
        axial, path = _compression(100.0, prm, steps=60)
        plastic = [(d, de) for d, de, g in path[-10:]]
        for total, elastic in plastic:
            p = total - elastic                     # plastic increment (principal axes = xyz)
            ratio = (p[0] + p[1] + p[2]) / (p[0] - p[1])   # 1 = lateral (xx), 3 = axial (yy)
            assert abs(ratio - math.sin(math.radians(psi))) <= 1e-9


def test_apex_return_is_exact():
    """A trial state far in tension returns to tau_1 = tau_2 = tau_3 = c cot(phi) exactly
    (achieves 1e-15 relative; asserts 1e-12), with no deviator left."""
    c, phi = 10.0, 30.0
    eps, st, tau = mc.update(np.array([[0.05, 0.04, 0.045, 0.004]]), np.zeros((1, 1)),
                             _params(c, phi))
    p = c / math.tan(math.radians(phi))
    np.testing.assert_allclose(tau[0, :3], p, rtol=1e-12)
    assert abs(tau[0, 3]) <= 1e-12 * p
    assert st[0, 0] > 0


def test_edge_return_lies_on_both_planes():
    """A trial state with eps_zz = eps_xx (two equal major principal stresses) returns to
    the right edge tau_1 = tau_2 on the yield surface (both planes active)."""
    c, phi = 10.0, 30.0
    eps, st, tau = mc.update(np.array([[0.005, -0.03, 0.005, 0.0]]), np.zeros((1, 1)),
                             _params(c, phi, psi=10.0))
    s = _principal(tau)[0]
    assert _branch(tau, st[0, 0]) == "right"
    assert abs(s[0] - s[1]) <= 1e-10 * abs(s).max()
    assert abs(_yield(tau, c, phi)[0]) <= 1e-10 * abs(s).max()


def test_dilation_angle_is_capped_at_the_friction_angle_of_a_point():
    """A point whose (drawn) friction angle is below the soil's dilation angle flows with
    psi = phi: the update with psi = 25 > phi = 15 deg (peak and residual, softening on)
    equals the associated one to round-off (achieves 0; asserts 1e-12 relative) on the main
    plane and an edge, and such a point is valid (invalid_points); psi <= phi is left
    as it was (psi = 5 differs from psi = 15)."""
    for trial in ([0.01, -0.03, -0.005, 0.002], [0.005, -0.03, 0.005, 0.0]):
        e = np.array([trial])
        assoc = mc.update(e, np.zeros((1, 1)), _params(20.0, 15.0, 15.0, 4.0, 10.0, 10.0))
        capped = mc.update(e, np.zeros((1, 1)), _params(20.0, 15.0, 25.0, 4.0, 10.0, 25.0))
        lower = mc.update(e, np.zeros((1, 1)), _params(20.0, 15.0, 5.0, 4.0, 10.0, 5.0))
        for a, b in zip(assoc, capped):
            np.testing.assert_allclose(b, a, rtol=1e-12, atol=1e-12 * np.abs(a).max())
        assert np.abs(lower[2] - assoc[2]).max() > 1e-3 * np.abs(assoc[2]).max()
    assert not mc.invalid_points(_params(20.0, 15.0, 25.0, 4.0, 10.0, 25.0))[0].any()


CASES = {  # name: (trial log strain [xx, yy, zz, xy], parameter row, branch)
    "elastic": ([-0.001, -0.0012, -0.001, 0.0001], _params(), "elastic"),
    "main plane": ([0.01, -0.03, -0.005, 0.002], _params(psi=10.0), "main"),
    "right edge": ([0.005, -0.03, 0.005, 0.0], _params(psi=10.0), "right"),
    "left edge": ([0.015, -0.02, -0.02, 0.0], _params(psi=10.0), "left"),
    "apex": ([0.05, 0.04, 0.045, 0.004], _params(), "apex"),
    "linear softening": ([0.04, -0.08, -0.02, 0.01],
                         _params(20.0, 35.0, 5.0, 4.0, 25.0, 0.0, gs=0.2), "main"),
    "exponential softening": ([0.04, -0.08, -0.02, 0.01],
                              _params(20.0, 35.0, 5.0, 4.0, 25.0, 0.0, gs=0.2, expo=1), "main"),
    "edge softening": ([0.02, -0.08, 0.02, 0.0],
                       _params(20.0, 35.0, 5.0, 4.0, 25.0, 0.0, gs=0.2), "right"),
    "tresca softening": ([0.0, 0.0, 0.0, 0.05], _params(20.0, 0.0, 0.0, 4.0, 0.0, 0.0, gs=0.5),
                         "main"),
}


def _branch(tau, gamma, tol=1e-9):
    """Which return a stress state came from: elastic, main, right (the edge tau_1 =
    tau_2), left (tau_2 = tau_3) or apex."""
    if gamma == 0:
        return "elastic"
    s = _principal(tau)[0]
    eq12, eq23 = abs(s[0] - s[1]) <= tol * abs(s).max(), abs(s[1] - s[2]) <= tol * abs(s).max()
    return {(False, False): "main", (True, False): "right", (False, True): "left",
            (True, True): "apex"}[(eq12, eq23)]


@pytest.mark.parametrize("name", list(CASES))
def test_complex_step_tangent_matches_finite_differences(name):
    """d tau / d eps_trial by the complex step (what the implicit scheme uses) equals a
    central finite difference (h = 1e-7) on every branch (achieves ~1e-9; asserts 1e-6
    relative to the largest entry)."""
    trial, prm, branch = CASES[name]
    e0 = np.array([trial], dtype=float)
    st = np.zeros((1, 1))
    D_cs = np.empty((4, 4))
    D_fd = np.empty((4, 4))
    for j in range(4):
        h = np.zeros((1, 4))
        h[0, j] = 1.0
        D_cs[:, j] = mc.update(e0 + 1e-30j * h, st, prm)[2][0].imag / 1e-30
        tp = mc.update(e0 + 1e-7 * h, st, prm)[2][0]
        tm = mc.update(e0 - 1e-7 * h, st, prm)[2][0]
        D_fd[:, j] = (tp - tm) / 2e-7
    assert np.abs(D_cs - D_fd).max() <= 1e-6 * np.abs(D_cs).max(), (D_cs, D_fd)
    _, gamma, tau = mc.update(e0, st, prm)
    assert _branch(tau, gamma[0, 0]) == branch           # the case tests the branch it names


def test_tresca_equals_von_mises_in_plane_strain_pure_shear():
    """phi = psi = 0 with cohesion softening 20 -> 4 kPa (linear, gamma_r = 0.5): along an
    isochoric pure-shear path eps_xy = 0 .. 0.4 (steps 0.002) the shear stress and the
    plastic shear strain equal those of von Mises with the same strengths (achieves
    ~1e-15; asserts 1e-10)."""
    mc_prm = _params(20.0, 0.0, 0.0, 4.0, 0.0, 0.0, gs=0.5)
    vm_prm = np.array([[G, KB, 20.0, 4.0, 0.5, 0.0]])
    eps_m, eps_v = np.zeros((1, 4)), np.zeros((1, 4))
    st_m, st_v = np.zeros((1, 1)), np.zeros((1, 1))
    d = np.array([[0.0, 0.0, 0.0, 0.002]])
    for _ in range(200):
        eps_m, st_m, tm = mc.update(eps_m + d, st_m, mc_prm)
        eps_v, st_v, tv = vm.update(eps_v + d, st_v, vm_prm)
        assert abs(tm[0, 3] - tv[0, 3]) <= 1e-10 * 20.0
        assert abs(st_m[0, 0] - st_v[0, 0]) <= 1e-10 * (1 + st_v[0, 0])
    assert st_v[0, 0] > 0.5 and abs(tv[0, 3] - 4.0) < 1e-9    # reached the residual


def kernel_equals_numpy(prm, rng):
    """The kernels' stress update of random states equals the numpy update (asserts 1e-12
    relative); returns the numpy stress, plastic shear strain and its start value."""
    n = len(prm)
    soil = MaterialPoints(np.full(n, materials.model_id(mc.NAME)), prm)
    dF = np.eye(2) + 0.01 * rng.normal(size=(n, 2, 2))
    eps = 0.004 * rng.normal(size=(n, 4))
    gam = rng.uniform(0, 0.4, n)
    e_ref, g_ref, t_ref = materials.stress_update(dF, eps, gam, soil)
    e, g, t = K.stress_update_points(dF, eps, gam, soil)
    for a, b in ((e, e_ref), (g, g_ref), (t, t_ref)):
        assert np.abs(a - b).max() <= 1e-12 * np.abs(b).max()
    return t_ref, g_ref, gam


def test_explicit_kernel_equals_numpy_update():
    """The numba point function through the kernels' dispatch equals the numpy update on
    random trial states of every branch (achieves ~1e-16 relative; asserts 1e-12)."""
    rng = np.random.default_rng(3)
    n = 3000
    prm = np.repeat(_params(10.0, 30.0, 10.0, 2.0, 20.0, 0.0, gs=0.3), n, axis=0)
    prm[:, 2] *= rng.uniform(0.5, 2.0, n)
    _, g_ref, gam = kernel_equals_numpy(prm, rng)
    assert 0.1 * n < (g_ref > gam).sum() < 0.9 * n


def _tiny(solver: dict | None = None, **soil) -> dict:
    """The tiny cut (tests/data/mc_tiny.toml) as a scene dict without its random field and
    its von Mises keys; ``soil`` updates the soil, ``solver`` the solver section."""
    data = scene_to_dict(load_scene(TINY))
    data.pop("random_field")
    s = data["soil"][0]
    for k in ("cohesion_peak", "cohesion_residual", "softening", "softening_strain"):
        s.pop(k)
    s.update(soil)
    data["solver"].update(solver or {})
    return data


def _scene(**soil):
    mc_soil = dict(model="mohr_coulomb_softening", cohesion_peak=5.0, cohesion_residual=2.0,
                   friction_angle_peak=30.0, friction_angle_residual=25.0)
    return scene_from_dict(_tiny(**{**mc_soil, **soil}), "mc.toml")


@pytest.mark.parametrize("soil, key, what", [
    ({"friction_angle_peak": 60.0}, "friction_angle_peak", "out of range"),
    ({"friction_angle_peak": -1.0}, "friction_angle_peak", "out of range"),
    ({"dilation_angle_peak": 31.0}, "dilation_angle_peak", "exceeds friction_angle_peak"),
    ({"cohesion_residual": 6.0}, "cohesion_residual", "exceeds cohesion_peak"),
    ({"friction_angle_residual": 31.0}, "friction_angle_residual", "exceeds friction_angle_peak"),
    ({"cohesion_peak": 0.0, "cohesion_residual": 0.0, "friction_angle_peak": 0.0,
      "friction_angle_residual": 0.0}, "cohesion_peak", "no strength"),
])
def test_bad_parameters_are_one_clear_error(soil, key, what):
    """Bad Mohr–Coulomb input names the key and what is allowed (SceneError: exit 2)."""
    with pytest.raises(SceneError, match=rf"\[soil(\[0\])?\.{key}\].*{what}"):
        _scene(**soil)


def test_scene_accepts_mohr_coulomb():
    s = _scene(dilation_angle_peak=5.0)
    assert s.soils[0].value("friction_angle_peak") == 30.0
    assert s.soils[0].value("dilation_angle_peak") == 5.0


def test_explicit_scheme_runs_mohr_coulomb_like_elastic_below_yield():
    """Through the explicit scheme (kernels' dispatch), a Mohr–Coulomb soil too strong to
    yield gives the linear elastic run (positions achieve 6e-11 and stresses 1.2e-8
    relative: the round-off of another operation order grown over ~100 dynamic steps;
    asserts 1e-9 and 1e-7), and
    the same soil at its real strength yields (plastic strain > 0)."""
    runs = {}
    for name, extra in (("elastic", {"model": "linear_elastic"}),
                        ("strong", {"model": "mohr_coulomb_softening", "cohesion_peak": 1e6,
                                    "cohesion_residual": 1e6, "friction_angle_peak": 30.0,
                                    "friction_angle_residual": 30.0}),
                        ("weak", {"model": "mohr_coulomb_softening", "cohesion_peak": 2.0,
                                  "cohesion_residual": 1.0, "friction_angle_peak": 10.0,
                                  "friction_angle_residual": 5.0})):
        scene = scene_from_dict(_tiny({"t_end": 0.3}, **extra), "mc.toml")
        grid, pts = api.prepare(scene)
        run_explicit(scene, grid, pts, progress=False)
        runs[name] = pts
    e, s = runs["elastic"], runs["strong"]
    assert np.abs(s.x - e.x).max() <= 1e-9 * np.abs(e.x).max()
    assert np.abs(s.stress - e.stress).max() <= 1e-7 * np.abs(e.stress).max()
    assert runs["weak"].plastic_shear_strain.max() > 0


def _infinite_slope(fs: float, beta=30.0, z=5.0, phi=20.0, gamma=20.0):
    """A drained infinite slope (uniform layer of vertical depth z on rigid bedrock at
    beta, free ends, 6 normal thicknesses long) whose cohesion gives the limit-equilibrium
    factor of safety FS = c / (gamma z sin b cos b) + tan(phi) / tan(b)."""
    b = math.radians(beta)
    c = (fs - math.tan(math.radians(phi)) / math.tan(b)) * gamma * z * math.sin(b) * math.cos(b)
    t = z * math.cos(b)                           # normal thickness
    length = 6 * t
    data = {
        "scene": {"name": f"infinite_slope_drained_fs{fs}", "gravity": 9.81,
                  "frame_angle_deg": beta},
        "grid": {"origin": [0.0, 0.0], "size": [length, t], "cell": [t / 8, t / 8]},
        "boundary": {"left": "free", "right": "free", "bottom": "fixed", "top": "free"},
        "soil": [{"name": "sand", "polygon": [[0, 0], [length, 0], [length, t], [0, t]],
                  "unit_weight": gamma, "youngs_modulus": 1e4, "poisson_ratio": 0.3,
                  "model": "mohr_coulomb_softening", "cohesion_peak": c,
                  "cohesion_residual": c, "friction_angle_peak": phi,
                  "friction_angle_residual": phi, "dilation_angle_peak": phi,
                  "dilation_angle_residual": phi}],
        "solver": {"scheme": "explicit", "gravity_phase": "dynamic", "gravity_ramp_time": 1.0,
                   "damping": 0.7, "damping_time": 1.0, "t_end": 3.0, "output_interval": 3.0},
        "output": {"vtk": False, "png": False},
    }
    return scene_from_dict(data, "infinite_slope_drained.toml"), c


@pytest.mark.parametrize("fs, slides", [(1.1, False), (0.9, True)])
def test_drained_infinite_slope_stands_at_1_1_and_slides_at_0_9(fs, slides):
    """Explicit MPM, associated flow (psi = phi = 20 deg; then the continuum limit of the
    infinite slope is the limit-equilibrium one), beta = 30 deg, z = 5 m: at FS = 1.1 the
    middle third of the layer stays put after gravity is ramped on (mean down-slope
    displacement at 3 s achieves 0.04 m, elastic shear and the yielding free ends; asserts
    < 0.1 m), at FS = 0.9 it slides (achieves 1.03 m; asserts > 0.3 m).  At FS = 1.0 it
    creeps 0.23 m: the limit is where the closed form puts it."""
    scene, c = _infinite_slope(fs)
    grid, pts = api.prepare(scene)
    x0 = pts.x.copy()
    run_explicit(scene, grid, pts, progress=False)
    length = scene.grid.size[0]
    mid = (x0[:, 0] > length / 3) & (x0[:, 0] < 2 * length / 3)
    down = np.mean(pts.x[mid, 0] - x0[mid, 0])
    if slides:
        assert down > 0.3, down
    else:
        assert abs(down) < 0.1, down


def test_implicit_scheme_runs_mohr_coulomb():
    """Through the implicit scheme: (a) its consistent tangent (complex step of the model's
    update, spin part analytic) equals the independent complex step of the whole update
    (materials.spatial_tangent) on elastic, main-plane, edge and apex states (achieves
    ~1e-13 relative; asserts 1e-10); (b) the tiny cut in a weak Mohr–Coulomb soil, 1 s of
    implicit (Newmark) dynamics: every step converges to the tolerance, the cut yields and
    every point is on or inside the yield surface (relative 1e-9)."""
    from fem_rmpm.schemes.implicit import run_implicit
    rng = np.random.default_rng(9)
    n = 600
    prm = np.repeat(_params(10.0, 30.0, 10.0), n, axis=0)
    soil = MaterialPoints(np.full(n, materials.model_id(mc.NAME)), prm)
    dF, eps, state, tau_a = tangents_agree(soil, rng, 0.01)
    branches = {_branch(t[None], g) for t, g in zip(tau_a, materials.stress_update(
        dF, eps, state, soil)[1][:, 0])}
    assert {"elastic", "main", "right", "left", "apex"} <= branches
    scene = scene_from_dict(_tiny({"scheme": "implicit", "dynamic": True, "dt": 0.05,
                                   "t_end": 1.0}, model="mohr_coulomb_softening",
                                  cohesion_peak=3.0, cohesion_residual=3.0,
                                  friction_angle_peak=15.0, friction_angle_residual=15.0),
                            "mc_implicit.toml")
    grid, pts = api.prepare(scene)
    rec = run_implicit(scene, grid, pts)
    assert rec.stop_reason in ("t_end reached", "at rest") and rec.time == pytest.approx(1.0)
    assert len(rec.solver["steps"]) >= 10
    assert all(s["residuals"][-1] <= scene.solver.tolerance for s in rec.solver["steps"])
    assert (pts.plastic_shear_strain > 0.01).sum() > 20
    tau = pts.stress * (pts.volume / pts.volume0)[:, None]
    f = _yield(tau, 3.0, 15.0)
    assert f.max() <= 1e-9 * np.abs(tau).max()


def test_the_elastic_precheck_never_passes_a_yielding_trial_stress():
    """``_surely_elastic`` (the yield test without sine and cosine, from x - x^3 / 6 <=
    sin x <= x and cos x >= 1 - x^2 / 2) may say True only where the exact test of
    ``_mc_return`` finds the point elastic (f <= 1e-12 of the stresses): 200 000 trial
    stresses drawn within +-5 % of the yield surface (f / (|t1| + |t3| + c cos phi) in
    [-0.05, 0.05]), friction angles 0-45 deg, on and off the softening slope; and it must
    catch the clearly elastic ones (f below -1 % of the stresses) all but 1 % of the time
    (measured: 99.8 % caught; the largest f it passed, -3.2e-7 of the stresses), or it
    would save nothing."""
    rng = np.random.default_rng(11)
    n = 200_000
    cp, php = rng.uniform(0.0, 30.0, n), rng.uniform(0.0, 45.0, n)
    cr, phr = cp * rng.uniform(0.2, 1.0, n), php * rng.uniform(0.5, 1.0, n)
    gs = rng.uniform(0.05, 0.5, n)
    gam = gs * rng.choice([0.0, 0.3, 0.9, 1.0, 2.0], n)
    t3 = -rng.uniform(0.0, 300.0, n)
    ratio = rng.uniform(-0.05, 0.05, n)
    sure, f_rel = np.zeros(n, bool), np.zeros(n)
    for i in range(n):
        c, sph, ccp, *_ = mcr._strengths(gam[i], cp[i], cr[i], php[i], phr[i], gs[i], False)
        # t1 from t3 and a chosen f: f = t1 (1 + sph) - t3 (1 - sph) - 2 ccp
        scale = abs(t3[i]) + ccp + 1e-300
        t1 = max(t3[i], (ratio[i] * scale + t3[i] * (1 - sph) + 2 * ccp) / (1 + sph))
        f = t1 - t3[i] + (t1 + t3[i]) * sph - 2 * ccp
        f_rel[i] = f / (abs(t1) + abs(t3[i]) + abs(ccp) + 1e-300)
        sure[i] = mcr._surely_elastic(t1, t3[i], gam[i], cp[i], cr[i], php[i], phr[i], gs[i])
    assert not (sure & (f_rel > 1e-12)).any()
    clear = f_rel < -0.01
    assert clear.sum() > 50_000 and sure[clear].mean() > 0.99


def test_softened_points_return_onto_the_surface_at_their_new_strength():
    """Linear softening (c 10 -> 2 kPa, phi 30 -> 20 deg, psi 5 -> 0 deg, residual at
    gamma_p = 0.5): 4 000 random trial states (main plane, edges, apex) of points before
    and past the residual (gamma_p in [0, 1.5]).  Every plastic point ends on the yield
    surface of c and phi at its *new* gamma_p, evaluated here in numpy (|f| <= 1e-13 of
    the stresses; achieves 1.8e-14, 2.8e-14 before the model took the kernels' flags),
    gamma_p never falls, and a point past the residual (whose return the update solves in
    closed form, without Newton) gives the update of the perfectly plastic soil with the
    residual strength (c 2 kPa, phi 20, psi 0 deg) to 1e-14 (achieves 0: the same
    arithmetic): the closed form of the plateau is that soil's return, not the peak's."""
    rng = np.random.default_rng(5)
    n = 4000
    trial = rng.normal(0.0, 0.01, (n, 4)) + np.array([-0.002, -0.006, -0.004, 0.0])
    apex = rng.random(n) < 0.1                    # far in tension: the apex return
    trial[apex, :3] = 0.02 + rng.normal(0.0, 0.002, (apex.sum(), 3))
    gamma = rng.uniform(0.0, 1.5, (n, 1))
    prm = np.repeat(_params(10.0, 30.0, 5.0, 2.0, 20.0, 0.0, gs=0.5), n, axis=0)
    eps, st, tau = mc.update(trial, gamma, prm)
    plastic = st[:, 0] > gamma[:, 0]
    assert (st[:, 0] >= gamma[:, 0]).all() and 0.2 * n < plastic.sum() < 0.9 * n
    w = np.clip(1.0 - st[:, 0] / 0.5, 0.0, None)
    c, phi = 2.0 + 8.0 * w, 20.0 + 10.0 * w
    s = _principal(tau)
    f = s[:, 0] - s[:, 2] + (s[:, 0] + s[:, 2]) * np.sin(np.radians(phi)) \
        - 2 * c * np.cos(np.radians(phi))
    assert (np.abs(f[plastic]) <= 1e-13 * np.abs(s[plastic]).max(axis=1)).all()
    past = gamma[:, 0] >= 0.5
    residual = np.repeat(_params(2.0, 20.0, 0.0), n, axis=0)
    eps_r, st_r, tau_r = mc.update(trial[past], gamma[past], residual[past])
    np.testing.assert_allclose(tau[past], tau_r, rtol=0, atol=1e-14 * np.abs(tau_r).max())
    np.testing.assert_allclose(st[past], st_r, rtol=1e-14)
