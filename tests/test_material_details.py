"""Exact checks of the materials' numpy parts, one property at a time (each guards lines a
mutation would otherwise leave passing: ``python validation/mutation.py materials``).

Each test compares with a formula written out here, independently of the code:

* Hughes & Winget (1980): ``dF = (I - L dt/2)^-1 (I + L dt/2)`` — a Cayley transform,
  exactly orthogonal for a spin and second-order accurate against ``expm(L dt)``;
* Hencky elasticity ``tau = K tr(eps) I + 2 G dev(eps)`` and ``sqrt(J2)``;
* the series of ``atanh(x)/x`` and ``sinh(y)/y`` used below ``|x^2| < 1e-6`` against the
  library functions (both accurate to round-off there);
* the von Mises and Mohr–Coulomb parameter checks (each message and each boundary) and
  their softening laws (linear: ``c = c_p - (c_p - c_r) gamma_p / gamma_s`` until the
  residual; exponential ``c = c_r + (c_p - c_r) exp(-gamma_p / gamma_s)``).
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.linalg import expm
from soil_points import vm_points

from fem_rmpm.materials import (
    MaterialPoints,
    exp_sym2,
    hencky,
    hencky_stress,
    hughes_winget_increment,
    kirchhoff_stress,
    log_sym2,
    model_id,
    mohr_coulomb,
    return_map,
    small_strain_update,
    sqrt_j2,
    stress_update,
    von_mises,
)

G, K = 375.0, 1000.0
CP, CR, GS = 20.0, 4.0, 0.5


# --------------------------------------------------------------- kinematics
def test_hughes_winget_is_the_cayley_transform_and_orthogonal_for_a_spin():
    """A spin of rate w over dt: dF is the rotation by 2 atan(w dt / 2) (orthogonal,
    det 1, to 1e-15); a general L: dF equals solve(I - L dt/2, I + L dt/2) to 1e-14 and
    differs from expm(L dt) by O(dt^3) (ratio of the errors at dt and dt/2 ~ 8)."""
    w, dt = 0.7, 0.3
    L = np.array([[[0.0, -w], [w, 0.0]]])
    dF = hughes_winget_increment(L, dt)[0]
    a = 2 * math.atan(w * dt / 2)
    assert np.allclose(dF, [[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]],
                       rtol=0, atol=1e-15)
    assert np.allclose(dF.T @ dF, np.eye(2), rtol=0, atol=1e-15)
    rng = np.random.default_rng(4)
    Ls = rng.normal(size=(5, 2, 2))
    got = hughes_winget_increment(Ls, dt)
    for Li, Fi in zip(Ls, got):
        ref = np.linalg.solve(np.eye(2) - 0.5 * dt * Li, np.eye(2) + 0.5 * dt * Li)
        assert np.allclose(Fi, ref, rtol=0, atol=1e-14)
    err = [np.abs(hughes_winget_increment(Ls[:1], h)[0] - expm(Ls[0] * h)).max()
           for h in (0.01, 0.005)]
    assert 6.0 < err[0] / err[1] < 10.0


def test_log_and_exp_of_symmetric_2x2_match_scipy_on_both_branches():
    """1/2 ln(A) and exp(2E) against scipy.linalg.logm/expm: on matrices with nearly equal
    eigenvalues (the series branch, |x^2| < 1e-6) and distinct ones, to 1e-14."""
    from scipy.linalg import logm
    for axx, ayy, axy in ((1.3, 0.8, 0.25), (1.0 + 1e-5, 1.0, 2e-5), (2.0, 2.0, 0.0),
                          (0.9, 1.1 + 4e-4, 0.0)):
        A = np.array([[axx, axy], [axy, ayy]])
        ref = 0.5 * logm(A).real
        exx, eyy, exy = (float(v[0]) for v in log_sym2(np.array([axx]), np.array([ayy]),
                                                       np.array([axy])))
        assert np.allclose([exx, eyy, exy], [ref[0, 0], ref[1, 1], ref[0, 1]], rtol=0,
                           atol=1e-14)
        E = np.array([[exx, exy], [exy, eyy]])
        back = expm(2 * E)
        bxx, byy, bxy = (float(v[0]) for v in exp_sym2(np.array([exx]), np.array([eyy]),
                                                       np.array([exy])))
        assert np.allclose([bxx, byy, bxy], [back[0, 0], back[1, 1], back[0, 1]], rtol=0,
                           atol=1e-14)


@pytest.mark.parametrize("x2", [1e-9, 3e-7, 9.9e-7, 1.01e-6, 1e-3, 0.3])
def test_series_branches_equal_the_functions(x2):
    """atanh(x)/x and sinh(y)/y (as functions of x^2, y^2) on both sides of the switch
    at 1e-6: equal to numpy's arctanh/sinh to 1e-15 relative (the series' truncation is
    below 1e-25 there), also for a negative y^2 (sinh(iy)/(iy) = sin(y)/y).  ``abs=0``:
    pytest.approx's default abs of 1e-12 would otherwise be the bound on these O(1)
    values."""
    x = math.sqrt(x2)
    assert hencky._atanh_x_over_x(np.array([x2]))[0] == pytest.approx(math.atanh(x) / x,
                                                                      rel=1e-15, abs=0)
    assert hencky._sinh_y_over_y(np.array([x2]))[0] == pytest.approx(math.sinh(x) / x,
                                                                     rel=1e-15, abs=0)
    neg = hencky._sinh_y_over_y(np.array([-x2], dtype=complex))[0]
    assert neg.real == pytest.approx(math.sin(x) / x, rel=1e-15, abs=0)
    assert abs(neg.imag) < 1e-16


def test_hencky_stress_and_sqrt_j2_closed_form():
    """tau_ii = 2 G e_ii + (K - 2G/3) tr e, tau_xy = 2 G e_xy; sqrt(J2) of a pure shear
    is |tau_xy| and of a uniaxial stress s is |s|/sqrt(3); kirchhoff_stress reads G, K
    from the parameter rows."""
    e = np.array([[1e-3, -2e-3, 5e-4, 7e-4]])
    tr = e[0, :3].sum()
    ref = [2 * G * e[0, 0] + (K - 2 * G / 3) * tr, 2 * G * e[0, 1] + (K - 2 * G / 3) * tr,
           2 * G * e[0, 2] + (K - 2 * G / 3) * tr, 2 * G * e[0, 3]]
    assert np.allclose(hencky_stress(e.copy(), np.array([G]), np.array([K])), ref,
                       rtol=1e-15, atol=0)
    soil = vm_points([G], [K], [CP], [CR], [GS], [0])
    assert np.allclose(kirchhoff_stress(e.copy(), soil), ref, rtol=1e-15, atol=0)
    t = np.array([[0.0, 0.0, 0.0, 3.0], [6.0, 0.0, 0.0, 0.0], [-1.0, 2.0, 5.0, 0.5]])
    p = (-1 + 2 + 5) / 3
    j2 = 0.5 * ((-1 - p) ** 2 + (2 - p) ** 2 + (5 - p) ** 2) + 0.25
    assert np.allclose(sqrt_j2(t), [3.0, 6.0 / math.sqrt(3), math.sqrt(j2)], rtol=1e-15)


# --------------------------------------------------------------- the update's plumbing
def _trial(n=6, scale=0.02, seed=1):
    return np.random.default_rng(seed).normal(scale=scale, size=(n, 4))


def test_update_keeps_the_state_shape_and_does_not_touch_its_inputs():
    """A state given as (n,) comes back as (n,), as (n, 1) as (n, 1), with the same values
    (yielding and elastic points mixed); the inputs are not modified."""
    soil = vm_points(np.full(6, G), np.full(6, K), [CP, CP, CP, math.inf, CP, CP],
                     np.full(6, CR), np.full(6, GS), [0, 1, 0, 0, 1, 0])
    dF = np.eye(2) + _trial(6, 0.05).reshape(6, 2, 2)
    eps0, g0 = _trial(6, 0.01, seed=2), np.array([0.0, 0.1, 0.6, 0.0, 0.0, 0.2])
    keep = (dF.copy(), eps0.copy(), g0.copy())
    e1, s1, t1 = stress_update(dF, eps0, g0, soil)
    e2, s2, t2 = stress_update(dF, eps0, g0[:, None], soil)
    assert s1.shape == (6,) and s2.shape == (6, 1)
    assert np.array_equal(s1, s2[:, 0]) and np.array_equal(e1, e2) and np.array_equal(t1, t2)
    assert s1[3] == 0.0 and np.any(s1 > g0)            # the elastic point; some yielded
    for a, b in zip(keep, (dF, eps0, g0)):
        assert np.array_equal(a, b)
    grad = _trial(6, 0.02, seed=3).reshape(6, 2, 2)
    f1 = small_strain_update(grad, eps0, g0, soil)
    f2 = small_strain_update(grad, eps0, g0[:, None], soil)
    assert f1[1].shape == (6,) and f2[1].shape == (6, 1)
    assert np.array_equal(f1[1], f2[1][:, 0]) and np.array_equal(f1[2], f2[2])


def test_small_strain_update_adds_the_symmetric_gradient():
    """Elastic points: eps = eps0 + sym(grad du) (xx, yy, xy; zz unchanged), tau from it."""
    soil = vm_points(np.full(3, G), np.full(3, K), np.full(3, math.inf), np.full(3, CR),
                     np.full(3, GS), np.zeros(3))
    grad = np.array([[[1e-3, 4e-4], [-2e-4, -5e-4]]] * 3)
    eps0 = np.array([[1e-4, 2e-4, 3e-4, 4e-4]] * 3)
    eps, st, tau = small_strain_update(grad, eps0, np.zeros(3), soil)
    ref = eps0 + [1e-3, -5e-4, 0.0, 1e-4]
    assert np.allclose(eps, ref, rtol=1e-14, atol=0) and np.array_equal(st, np.zeros(3))
    assert np.allclose(tau, hencky_stress(ref.copy(), np.full(3, G), np.full(3, K)),
                       rtol=1e-14, atol=0)


def test_stress_update_of_a_stretch_is_its_log_strain():
    """Elastic point, eps0 = 0, dF = diag(l1, l2): eps = (ln l1, ln l2, 0, 0) to 1e-15; a
    rotation of a stressed state keeps sqrt(J2) and rotates tau (objectivity)."""
    soil = vm_points([G], [K], [math.inf], [CR], [GS], [0])
    l1, l2 = 1.1, 0.93
    eps, _, _ = stress_update(np.array([[[l1, 0.0], [0.0, l2]]]), np.zeros((1, 4)),
                              np.zeros(1), soil)
    assert np.allclose(eps[0], [math.log(l1), math.log(l2), 0.0, 0.0], rtol=0, atol=1e-15)
    a = 0.4
    R = np.array([[[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]]])
    e0 = np.array([[0.01, -0.004, 0.002, 0.003]])
    _, _, tau = stress_update(R, e0, np.zeros(1), soil)
    t0 = hencky_stress(e0.copy(), np.array([G]), np.array([K]))
    T0 = np.array([[t0[0, 0], t0[0, 3]], [t0[0, 3], t0[0, 1]]])
    T = R[0] @ T0 @ R[0].T
    assert np.allclose(tau[0], [T[0, 0], T[1, 1], t0[0, 2], T[0, 1]], rtol=0, atol=1e-12)


def test_mixed_models_update_each_point_with_its_own_model():
    """return_map on points of von Mises, Mohr–Coulomb and linear elastic interleaved
    equals each model's update on its own points, bitwise; states of 1 column."""
    vm = vm_points(np.full(4, G), np.full(4, K), np.full(4, CP), np.full(4, CR),
                   np.full(4, GS), [0, 1, 0, 1])
    mc = np.tile([G, K, 10.0, 5.0, 30.0, 25.0, 5.0, 0.0, 0.4, 0.0], (3, 1))
    n_vm, n_mc = vm.params.shape[1], mc.shape[1]
    width = max(n_vm, n_mc)
    params = np.full((8, width), math.nan)
    order = [0, "m", 1, "e", 2, "m", 3, "m"]
    model = np.empty(8, dtype=np.int64)
    iv = im = 0
    for k, o in enumerate(order):
        if o == "m":
            model[k], params[k, :n_mc] = model_id(mohr_coulomb.NAME), mc[im]
            im += 1
        elif o == "e":
            model[k], params[k, :2] = model_id("linear_elastic"), [G, K]
        else:
            model[k], params[k, :n_vm] = model_id(von_mises.NAME), vm.params[iv]
            iv += 1
    soil = MaterialPoints(model, params)
    eps_tr = _trial(8, 0.02, seed=5)
    state = np.abs(_trial(8, 0.1, seed=6)[:, :1])
    eps, st, tau = return_map(eps_tr, state, soil)
    for name in (von_mises.NAME, mohr_coulomb.NAME, "linear_elastic"):
        idx = np.nonzero(model == model_id(name))[0]
        from fem_rmpm.materials import model as model_module
        e2, s2, t2 = model_module(name).update(eps_tr[idx], state[idx], params[idx])
        assert np.array_equal(eps[idx], e2) and np.array_equal(tau[idx], t2)
        assert np.array_equal(st[idx], s2)
    assert np.any(st[model == model_id(von_mises.NAME)] > state[model == model_id(von_mises.NAME)])


# --------------------------------------------------------------- von Mises parameters
def _vm_values(**kw):
    v = {"cohesion_peak": CP, "cohesion_residual": CR, "softening_strain": GS,
         "softening": "linear", "shear_modulus": G}
    v.update(kw)
    return v


@pytest.mark.parametrize("kw, key, words", [
    ({"cohesion_peak": math.inf}, "cohesion_peak", "needs finite cohesion_peak"),
    ({"cohesion_residual": math.inf}, "cohesion_peak", "needs finite cohesion_peak"),
    ({"cohesion_residual": 20.5}, "cohesion_residual",
     "20.5 kPa exceeds cohesion_peak 20 kPa; allowed: 0 < cohesion_residual <= cohesion_peak"),
    ({"softening_strain": 16.0 / G}, "softening_strain",
     f"softening modulus {G:g} kPa >= shear modulus {G:g} kPa"),
    ({"softening_strain": 0.01}, "softening_strain",
     f"allowed: softening_strain > {16.0 / G:g}"),
])
def test_von_mises_check_names_the_key_and_the_bound(kw, key, words):
    got = von_mises.check(_vm_values(**kw))
    assert got is not None and got[0] == key and words in got[1], got


@pytest.mark.parametrize("kw", [{}, {"cohesion_residual": CP},
                                {"softening_strain": 0.01, "softening": "exponential"},
                                {"softening_strain": 16.0 / G * 1.0001}])
def test_von_mises_check_accepts_the_boundaries(kw):
    """residual = peak; an exponential law with a steep start; a linear modulus just
    below G."""
    assert von_mises.check(_vm_values(**kw)) is None


def test_von_mises_invalid_points_mask():
    """Per point: a linear modulus (c_p - c_r)/gamma_s >= G, or c_p <= 0 (or NaN) is
    invalid; the same modulus with the exponential law is not."""
    h_eq = 16.0 / G
    rows = np.array([[G, K, CP, CR, GS, 0], [G, K, CP, CR, h_eq, 0], [G, K, CP, CR, h_eq, 1],
                     [G, K, 0.0, 0.0, GS, 0], [G, K, math.nan, CR, GS, 0],
                     [G, K, CP, CR, h_eq * 1.001, 0]])
    bad, why = von_mises.invalid_points(rows)
    assert bad.tolist() == [False, True, False, True, True, False]
    assert "softening modulus is not below the shear modulus" in why


def test_a_rejected_von_mises_point_is_reported_with_its_position_and_values():
    """materials.point_problem: the first rejected point, where it is and, in the von
    Mises model's words, the peak cohesion it drew and the shear modulus it must stay
    below (the message a random-field realization stops with)."""
    from fem_rmpm.materials import MaterialPoints, point_problem
    h_eq = 16.0 / G
    rows = np.array([[G, K, CP, CR, GS, 0], [G, K, CP, CR, h_eq, 0]])
    soil = MaterialPoints(np.full(2, model_id(von_mises.NAME)), rows)
    x0 = np.array([[1.0, 2.0], [3.5, 0.25]])
    assert point_problem(soil, x0) == (
        f"material point 1 at x = 3.50, y = 0.25 m draws cohesion_peak = {CP:.4g} kPa, "
        f"whose linear softening modulus is not below the shear modulus {G:.4g} kPa (or is "
        "not positive); increase [[soil]] softening_strain or lower [random_field] cov")
    assert point_problem(soil.take([0]), x0[:1]) is None


def test_von_mises_cohesion_laws_and_derivatives():
    """Linear: c_p - (c_p - c_r) g / g_s and slope -(c_p - c_r)/g_s before g_s, c_r and 0
    after; exponential: c_r + (c_p - c_r) e^{-g/g_s}, slope -(c_p - c_r)/g_s e^{-g/g_s};
    an elastic row (c_p = inf) has no drop."""
    g = np.array([0.0, 0.2, 0.499, 0.5, 0.8, 3.0])
    lin = np.tile([G, K, CP, CR, GS, 0.0], (len(g), 1))
    c, dc = von_mises.cohesion(g, lin)
    assert np.allclose(c, np.where(g < GS, CP - (CP - CR) * g / GS, CR), rtol=1e-15)
    assert np.allclose(dc, np.where(g < GS, -(CP - CR) / GS, 0.0), rtol=1e-15)
    ex = lin.copy()
    ex[:, 5] = 1.0
    c, dc = von_mises.cohesion(g, ex)
    assert np.allclose(c, CR + (CP - CR) * np.exp(-g / GS), rtol=1e-15)
    assert np.allclose(dc, -(CP - CR) / GS * np.exp(-g / GS), rtol=1e-15)
    el = np.array([[G, K, math.inf, CR, GS, 0.0]])
    c, dc = von_mises.cohesion(np.array([0.3]), el)
    assert np.isinf(c[0]) and dc[0] == 0.0


def test_von_mises_return_lands_on_the_softened_surface():
    """A trial state far outside: sqrt(J2) of the returned stress = c(gamma_p + dgamma) to
    1e-12 (linear on the softening and on the residual branch, and exponential), the
    plastic multiplier dgamma = (q_tr - q) / G, the volume unchanged."""
    e = np.array([[0.08, -0.08, 0.0, 0.04]] * 4)
    rows = np.array([[G, K, CP, CR, GS, 0], [G, K, CP, CR, 0.02, 0], [G, K, CP, CR, GS, 1],
                     [G, K, CP, CR, 2.0, 0]])
    g0 = np.array([0.0, 0.1, 0.3, 0.0])
    eps, st, tau = von_mises.update(e.copy(), g0[:, None].copy(), rows)
    q_tr = sqrt_j2(hencky_stress(e.copy(), rows[:, 0], rows[:, 1]))
    q = sqrt_j2(tau)
    c, _ = von_mises.cohesion(st[:, 0], rows)
    assert np.allclose(q, c, rtol=1e-12) and np.all(st[:, 0] > g0)
    assert np.allclose(st[:, 0] - g0, (q_tr - q) / G, rtol=1e-12)
    assert np.allclose(eps[:, :3].sum(1), e[:, :3].sum(1), rtol=1e-14)
    assert st[1, 0] > 0.02                               # reached the residual branch


# --------------------------------------------------------------- Mohr–Coulomb parameters
def _mc_values(**kw):
    v = {"cohesion_peak": 10.0, "cohesion_residual": 5.0, "friction_angle_peak": 30.0,
         "friction_angle_residual": 25.0, "dilation_angle_peak": 5.0,
         "dilation_angle_residual": 0.0, "softening_strain": 0.5, "softening": "linear",
         "shear_modulus": G}
    v.update(kw)
    return v


@pytest.mark.parametrize("kw, key, words", [
    ({"cohesion_residual": 11.0}, "cohesion_residual", "11 exceeds cohesion_peak 10"),
    ({"friction_angle_residual": 31.0}, "friction_angle_residual",
     "31 exceeds friction_angle_peak 30; allowed: 0 <= friction_angle_residual"),
    ({"dilation_angle_residual": 6.0}, "dilation_angle_residual", "6 exceeds"),
    ({"dilation_angle_peak": 31.0, "dilation_angle_residual": 0.0}, "dilation_angle_peak",
     "31 deg exceeds friction_angle_peak 30 deg; allowed: 0 <= psi <= phi"),
    ({"dilation_angle_peak": 26.0, "dilation_angle_residual": 26.0},
     "dilation_angle_residual", "26 deg exceeds friction_angle_residual 25 deg"),
    ({"cohesion_peak": 0.0, "cohesion_residual": 0.0, "friction_angle_peak": 0.0,
      "friction_angle_residual": 0.0, "dilation_angle_peak": 0.0}, "cohesion_peak",
     "no strength at all"),
    ({"softening_strain": 5.0 / G}, "softening_strain",
     f"allowed: softening_strain > {5.0 / G:g}"),
])
def test_mohr_coulomb_check_names_the_key_and_the_bound(kw, key, words):
    got = mohr_coulomb.check(_mc_values(**kw))
    assert got is not None and got[0] == key and words in got[1], got


@pytest.mark.parametrize("kw", [{}, {"cohesion_peak": 0.0, "cohesion_residual": 0.0},
                                {"friction_angle_peak": 0.0, "friction_angle_residual": 0.0,
                                 "dilation_angle_peak": 0.0},
                                {"softening_strain": 0.001, "softening": "exponential"},
                                {"dilation_angle_peak": 30.0, "dilation_angle_residual": 25.0},
                                {"cohesion_peak": 0.5, "cohesion_residual": 0.5,
                                 "friction_angle_peak": 0.0, "friction_angle_residual": 0.0,
                                 "dilation_angle_peak": 0.0},
                                {"softening_strain": 10.0 / G}])
def test_mohr_coulomb_check_accepts_the_boundaries(kw):
    """Purely frictional; purely cohesive; a steep exponential start; psi = phi; a small
    cohesion alone; a linear softening modulus (c_p - c_r)/g_s = G/2."""
    assert mohr_coulomb.check(_mc_values(**kw)) is None


def test_mohr_coulomb_invalid_points_mask():
    """Rows [G, K, c_p, c_r, phi_p, phi_r, psi_p, psi_r, g_s, exp]: good; residual c above
    peak; residual phi above peak; no strength; a linear modulus >= G; the same modulus
    exponential (valid); negative c_p."""
    base = [G, K, 10.0, 5.0, 30.0, 25.0, 5.0, 0.0, 0.5, 0.0]
    rows = np.array([base] * 7)
    rows[1, 3] = 11.0
    rows[2, 5] = 31.0
    rows[3, 2:6] = 0.0
    rows[4, 8] = 5.0 / G
    rows[5, 8], rows[5, 9] = 5.0 / G, 1.0
    rows[6, 2] = -1.0
    bad, why = mohr_coulomb.invalid_points(rows)
    assert bad.tolist() == [False, True, True, True, True, False, True]
    assert "no strength" in why


def test_mohr_coulomb_names_the_bound_a_rejected_point_breaks():
    """Each rejected row of the mask test above gets its own words: the cohesions out of
    order, the friction angles out of order, no strength, the snap-back modulus."""
    base = [G, K, 10.0, 5.0, 30.0, 25.0, 5.0, 0.0, 0.5, 0.0]
    rows = np.array([base] * 4)
    rows[0, 3] = 11.0
    rows[1, 5] = 31.0
    rows[2, 2:6] = 0.0
    rows[3, 8] = 5.0 / G
    said = [mohr_coulomb.point_problem(r) for r in rows]
    assert said[0].startswith("draws cohesion_peak = 10 kPa and cohesion_residual = 11 kPa")
    assert said[1].startswith("draws friction_angle_peak = 30 deg below "
                              "friction_angle_residual = 31 deg")
    assert said[2].startswith("draws no strength")
    assert said[3].startswith(f"draws cohesion_peak = 10 kPa, whose linear cohesion softening "
                              f"modulus {G:.4g} kPa is not below the shear modulus {G:.4g} kPa")
    assert all(mohr_coulomb.invalid_points(rows)[0])


def test_no_model_is_named_where_the_package_reads_the_protocol():
    """The strength reduction, the regularisation of softening and the Python API know
    the models only through the protocol: no model's name appears in them."""
    from pathlib import Path

    import fem_rmpm
    from fem_rmpm.materials import names
    root = Path(fem_rmpm.__file__).parent
    for rel in ("schemes/implicit/strength_reduction.py", "schemes/regularisation.py",
                "api.py"):
        text = (root / rel).read_text()
        assert not [n for n in names() if n in text], rel


def test_mohr_coulomb_softened_strengths():
    """cohesion and friction angle follow the same weight w(g): linear 1 - g/g_s down to
    0 at g_s, exponential e^{-g/g_s}; dc/dg = (c_p - c_r) dw/dg."""
    g = np.array([0.0, 0.25, 0.5, 1.0])
    rows = np.tile([G, K, 10.0, 4.0, 30.0, 20.0, 5.0, 0.0, 0.5, 0.0], (4, 1))
    w = np.clip(1 - g / 0.5, 0.0, None)
    c, dc = mohr_coulomb.cohesion(g, rows)
    assert np.allclose(c, 4.0 + 6.0 * w, rtol=1e-15)
    assert np.allclose(dc, np.where(g < 0.5, -6.0 / 0.5, 0.0), rtol=1e-15)
    assert np.allclose(mohr_coulomb.friction_angle(g, rows), 20.0 + 10.0 * w, rtol=1e-15)
    rows[:, 9] = 1.0
    w = np.exp(-g / 0.5)
    c, dc = mohr_coulomb.cohesion(g, rows)
    assert np.allclose(c, 4.0 + 6.0 * w, rtol=1e-15)
    assert np.allclose(dc, -6.0 / 0.5 * w, rtol=1e-15)
    assert np.allclose(mohr_coulomb.friction_angle(g, rows), 20.0 + 10.0 * w, rtol=1e-15)


def test_mohr_coulomb_update_keeps_inputs_and_dtype():
    """update returns new arrays (inputs untouched), real for real input and complex for
    complex input with the real part equal to the real update."""
    rows = np.tile([G, K, 10.0, 5.0, 30.0, 25.0, 5.0, 0.0, 0.5, 0.0], (5, 1))
    e = _trial(5, 0.02, seed=8)
    s = np.zeros((5, 1))
    keep = (e.copy(), s.copy())
    eps, st, tau = mohr_coulomb.update(e, s, rows)
    assert np.array_equal(e, keep[0]) and np.array_equal(s, keep[1])
    assert eps.dtype == tau.dtype == st.dtype == np.float64 and np.any(st > 0)
    epsc, stc, tauc = mohr_coulomb.update(e + 1e-30j, s.astype(complex), rows)
    assert tauc.dtype == complex and np.allclose(tauc.real, tau, rtol=1e-14, atol=0)
    assert np.allclose(stc.real, st, rtol=1e-14, atol=0)


def test_stress_update_takes_complex_log_strain():
    """Complex-step derivative of tau with respect to the starting log strain (elastic
    point, dF a stretch): equals the central finite difference to 1e-7 relative — the
    update keeps the imaginary part through exp, the push-forward and log."""
    soil = vm_points([G], [K], [math.inf], [CR], [GS], [0])
    dF = np.array([[[1.05, 0.02], [-0.01, 0.97]]])
    e0 = np.array([[0.01, -0.004, 0.002, 0.003]])
    h = 1e-30
    for k in (0, 1, 3):
        pert = e0.astype(complex)
        pert[0, k] += 1j * h
        d_cs = stress_update(dF, pert, np.zeros(1), soil)[2].imag / h
        d = 1e-6
        plus, minus = e0.copy(), e0.copy()
        plus[0, k] += d
        minus[0, k] -= d
        d_fd = (stress_update(dF, plus, np.zeros(1), soil)[2]
                - stress_update(dF, minus, np.zeros(1), soil)[2]) / (2 * d)
        assert np.allclose(d_cs, d_fd, rtol=1e-7, atol=1e-7 * np.abs(d_fd).max())


def test_mixed_models_complex_derivative_equals_each_models_tangent():
    """spatial_tangent (complex step through return_map) on a mix of von Mises and
    elastic points equals the tangent of each group alone, to 1e-12 relative (the mixed
    branch keeps the imaginary parts)."""
    soil = vm_points(np.full(6, G), np.full(6, K), [CP, math.inf, CP, math.inf, CP, CP],
                     np.full(6, CR), np.full(6, GS), [0, 0, 1, 0, 0, 1])
    rng = np.random.default_rng(11)
    dF = np.eye(2) + 0.03 * rng.normal(size=(6, 2, 2))
    eps = 0.02 * rng.normal(size=(6, 4))
    g0 = np.zeros(6)
    from fem_rmpm.materials import spatial_tangent
    tau, A = spatial_tangent(dF, eps, g0, soil)
    for idx in (np.array([0, 2, 4, 5]), np.array([1, 3])):
        t1, A1 = spatial_tangent(dF[idx], eps[idx], g0[idx], soil.take(idx))
        assert np.allclose(A[idx], A1, rtol=1e-12, atol=1e-12 * np.abs(A1).max())
        assert np.allclose(tau[idx], t1, rtol=1e-14, atol=0)
    assert np.abs(A[[0, 2, 4, 5]] - A[[1, 1, 3, 3]]).max() > 1.0       # plastic differs


def test_exponential_return_converges_with_a_steep_softening_start():
    """Exponential law with (c_p - c_r)/g_s = 0.95 G and a trial just above yield: the
    plastic multiplier solves q_tr - G dg = c(g + dg) to 1e-12 (Newton's slope G + dc/dg;
    with a wrong slope the 40 iterations would not converge here)."""
    gs = 16.0 / (0.95 * G)
    rows = np.array([[G, K, CP, CR, gs, 1.0]])
    e = np.array([[0.0305, -0.0305, 0.0, 0.0]])            # q_tr = 2 G 0.0305 = 22.9 kPa
    eps, st, tau = von_mises.update(e.copy(), np.zeros((1, 1)), rows)
    q_tr = sqrt_j2(hencky_stress(e.copy(), rows[:, 0], rows[:, 1]))[0]
    c, _ = von_mises.cohesion(st[:, 0], rows)
    assert q_tr > CP and st[0, 0] > 0
    assert abs(q_tr - G * st[0, 0] - c[0]) <= 1e-12 * CP
    assert sqrt_j2(tau)[0] == pytest.approx(c[0], rel=1e-12)


def test_check_messages_in_full():
    """The whole message of the checks a user sees most (one line, units, the bound)."""
    assert von_mises.check(_vm_values(cohesion_peak=math.inf)) == (
        "cohesion_peak", "von_mises_softening needs finite cohesion_peak and "
        "cohesion_residual (kPa)")
    assert von_mises.check(_vm_values(softening_strain=0.01)) == (
        "softening_strain", f"softening modulus {1600.0:g} kPa >= shear modulus {G:g} kPa "
        "makes the local return mapping snap back; allowed: softening_strain > "
        f"{16.0 / G:g}")
    assert mohr_coulomb.check(_mc_values(cohesion_peak=0.0, cohesion_residual=0.0,
                                         friction_angle_peak=0.0, friction_angle_residual=0.0,
                                         dilation_angle_peak=0.0)) == (
        "cohesion_peak", "mohr_coulomb_softening needs cohesion_peak > 0 or "
        "friction_angle_peak > 0 (no strength at all)")


def test_small_strain_update_of_a_zero_gradient_changes_nothing():
    """The first geostatic step of points at rest: grad du = 0 leaves the log strain, the
    state and the stress of elastic and yielding soil exactly as they were."""
    soil = vm_points(np.full(2, G), np.full(2, K), [CP, math.inf], np.full(2, CR),
                     np.full(2, GS), np.zeros(2))
    eps0 = np.array([[1e-4, 2e-4, 3e-4, 4e-4]] * 2)
    for g0 in (np.array([0.1, 0.0]), np.array([[0.1], [0.0]])):
        eps, st, tau = small_strain_update(np.zeros((2, 2, 2)), eps0, g0, soil)
        assert np.array_equal(eps, eps0) and np.array_equal(st, g0)
        assert np.all(np.isfinite(tau))
        assert np.array_equal(tau, hencky_stress(eps0.copy(), np.full(2, G), np.full(2, K)))


def test_register_refuses_declarations_that_name_what_the_model_lacks():
    """A STRENGTHS row or a REGULARISABLE name that is not the model's own parameter or
    state variable is refused when the model is registered."""
    import types

    from fem_rmpm.materials import Parameter, Regularisable, Strength, registry
    m = types.SimpleNamespace(NAME="declared_test", PARAMETERS=(Parameter("su", "kPa"),),
                              STATE=("plastic_shear_strain",), update=None, point_update=None,
                              STRENGTHS=(Strength("cohesion", "c/F"),))
    with pytest.raises(TypeError, match="STRENGTHS names cohesion"):
        registry.register(m)
    m.STRENGTHS = (Strength("su", "c/F"),)
    m.REGULARISABLE = Regularisable()
    with pytest.raises(TypeError, match="REGULARISABLE names softening_variable"):
        registry.register(m)
    assert "declared_test" not in registry.names()
