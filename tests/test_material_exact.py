"""Exact properties of the materials' numpy code, each guarding a line that a mutation of
it would otherwise leave passing (``python validation/mutation.py materials``; the
mutations left as equivalent are listed in validation/mutation_survivors.md).

References, each written out here independently of the code:

* the Taylor series ``atanh(x)/x = sum_k x^(2k) / (2k + 1)`` and ``sinh(y)/y = sum_k
  y^(2k) / (2k + 1)!`` (Abramowitz & Stegun 4.6.33 and 4.5.62), summed in exact rational
  arithmetic to 12 terms, and their term-by-term derivative: the series branch must give
  the value *and* the complex-step derivative (which the consistent tangent uses) to
  round-off;
* the von Mises radial return in closed form (Simo & Hughes 1998, sec. 3.3; the linear
  softening branch ``dgamma = (q_tr - c0) / (G - h)``, ``h = (c_p - c_r) / gamma_s``)
  and the staggered non-local return (perfectly plastic at ``c`` of the softening
  variable, ``dgamma = (q_tr - c0) / G``, the softening variable left to the averaging);
  the yield test's documented band ``q_tr > c0 (1 + 1e-12)``;
* complex-step derivatives against central finite differences, and the mixed-model
  return map against each model's own update on its points;
* the input checks' whole messages and each bound of the per-point checks.
"""
from __future__ import annotations

import math
from fractions import Fraction

import numpy as np
import pytest

from fem_rmpm.materials import (
    MaterialPoints,
    hencky,
    hencky_stress,
    model,
    model_id,
    mohr_coulomb,
    return_map,
    sqrt_j2,
    strength,
    stress_update,
    von_mises,
)

G, K = 375.0, 1000.0
CP, CR, GS = 20.0, 4.0, 0.5
H = (CP - CR) / GS                       # linear softening modulus (kPa)
MC_ROW = [G, K, 10.0, 5.0, 30.0, 25.0, 5.0, 0.0, 0.5, 0.0]


def _vm_row(regularisation=0.0, law=0.0):
    """A von Mises parameter row as a scene makes it (10 columns)."""
    return [G, K, CP, CR, GS, law, regularisation, 0.5, math.nan, 2.0]


# --------------------------------------------------------------- series of the 2x2 functions
def _series(x2: float, coefficient) -> tuple[float, float]:
    """Value and d/d(x2) of sum_k c_k x2^k (12 terms), exact rationals, rounded once."""
    X = Fraction(x2)
    value = sum(coefficient(k) * X ** k for k in range(12))
    slope = sum(k * coefficient(k) * X ** (k - 1) for k in range(1, 12))
    return float(value), float(slope)


@pytest.mark.parametrize("x2", [5e-7, 9.99e-7])
@pytest.mark.parametrize("name, coefficient", [
    ("_atanh_x_over_x", lambda k: Fraction(1, 2 * k + 1)),
    ("_sinh_y_over_y", lambda k: Fraction(1, math.factorial(2 * k + 1))),
])
def test_series_branch_value_and_complex_derivative_are_exact(name, coefficient, x2):
    """On the series side of the switch (|x^2| < 1e-6): the value and the complex-step
    derivative d/d(x^2) equal the exact series to round-off.  Achieves 2.2e-16 relative
    (one ulp); asserts 5e-16."""
    f = getattr(hencky, name)
    value, slope = _series(x2, coefficient)
    z = f(np.array([x2 + 1e-30j]))[0]
    assert abs(z.real - value) <= 5e-16 * value
    assert abs(z.imag / 1e-30 - slope) <= 5e-16 * slope


def test_series_functions_of_an_isotropic_state_raise_no_floating_point_error():
    """x^2 = 0 (an isotropic strain: r^2 = 0) gives exactly 1, real and complex, with
    every floating-point error raised (the masked-out branch must not divide 0 by 0 or
    take atanh outside (-1, 1))."""
    with np.errstate(all="raise"):
        for f in (hencky._atanh_x_over_x, hencky._sinh_y_over_y):
            assert f(np.array([0.0]))[0] == 1.0
            assert f(np.array([0.0 + 0.0j]))[0] == 1.0
            assert f(np.array([4e-7]))[0] > 1.0


def test_zero_increment_of_an_unstrained_point_changes_nothing():
    """dF = I on a point at zero log strain with the scene's three state columns: the
    log strain, the state and the stress come back exactly (the zero that promotes the
    state's dtype must be a zero)."""
    soil = MaterialPoints(np.full(2, model_id(von_mises.NAME)),
                          np.array([_vm_row(), _vm_row(1.0)]))
    state = np.array([[0.1, 0.05, 0.02], [0.0, 0.0, 0.0]])
    with np.errstate(all="raise"):
        eps, st, tau = stress_update(np.tile(np.eye(2), (2, 1, 1)), np.zeros((2, 4)),
                                     state, soil)
    assert np.array_equal(eps, np.zeros((2, 4))) and np.array_equal(st, state)
    assert np.array_equal(tau, np.zeros((2, 4)))


# --------------------------------------------------------------- the von Mises return
def _shear(q, n=1):
    """Trial log strains of plane-strain pure shear with sqrt(J2) = q (kPa)."""
    e = np.zeros((n, 4))
    e[:, 3] = q / (2 * G)
    return e


def test_local_and_nonlocal_returns_in_closed_form():
    """Rows and states as scenes make them (10 parameter, 3 state columns; the state's
    columns all different).  Local point on the linear softening branch: dgamma =
    (q_tr - c(g*)) / (G - h) with g* = column 1; columns 0 and 1 grow by dgamma.
    Non-local point: perfectly plastic at c(g*): dgamma = (q_tr - c(g*)) / G, column 1
    unchanged.  Column 2 is the averaging's and untouched; sqrt(J2) of the returned
    stress is the strength.  Achieves 2.3e-16 relative; asserts 1e-15."""
    rows = np.array([_vm_row(0.0), _vm_row(1.0)])
    state = np.array([[0.30, 0.10, 0.20], [0.30, 0.10, 0.20]])
    q_tr = 30.0
    c0 = CP - H * 0.10                                  # c at g* = 0.1: 16.8 kPa
    eps, st, tau = von_mises.update(_shear(q_tr, 2), state.copy(), rows)
    d_local, d_nonlocal = (q_tr - c0) / (G - H), (q_tr - c0) / G
    assert st[0, 0] == pytest.approx(0.30 + d_local, rel=1e-15, abs=0)
    assert st[0, 1] == pytest.approx(0.10 + d_local, rel=1e-15, abs=0)
    assert st[1, 0] == pytest.approx(0.30 + d_nonlocal, rel=1e-15, abs=0)
    assert st[1, 1] == 0.10 and np.array_equal(st[:, 2], state[:, 2])
    q = sqrt_j2(tau)
    assert q[0] == pytest.approx(c0 - H * d_local, rel=1e-15, abs=0)
    assert q[1] == pytest.approx(c0, rel=1e-15, abs=0)
    assert np.allclose(eps[:, 3], tau[:, 3] / (2 * G), rtol=1e-15, atol=0)


def test_yield_test_band_is_one_part_in_1e12():
    """The documented yield test ``q_tr > c0 (1 + 1e-12)`` (the numba point function's
    too): a trial half a band above the strength, or exactly on the band's edge, is
    elastic (strain and state returned exactly); one 4 bands above is plastic.  G = 512
    kPa makes ``q = 2 G e_xy`` exact in binary, so the edge is met exactly."""
    rows = np.array([_vm_row(0.0)] * 3)
    rows[:, 0] = 512.0
    edge = CP * (1 + 1e-12)
    e = np.zeros((3, 4))
    e[:, 3] = np.array([CP * (1 + 0.5e-12), edge, CP * (1 + 4e-12)]) / 1024.0
    assert sqrt_j2(hencky_stress(e.copy(), rows[:, 0], rows[:, 1]))[1] == edge
    state = np.zeros((3, 3))
    eps, st, _ = von_mises.update(e, state.copy(), rows)
    assert np.array_equal(eps[:2], e[:2]) and np.array_equal(st[:2], state[:2])
    assert st[2, 0] > 0.0 and st[2, 1] == st[2, 0]


def test_tangent_hook_with_scene_rows_equals_the_complex_derivative_of_update():
    """The analytic tangent (n, 4, 4) with 10-column rows and 3-column states (local and
    non-local, elastic and plastic points) equals the complex-step derivative of
    :func:`update` along each trial component.  Achieves 3.0e-16 relative to the largest
    entry; asserts 1.5e-15."""
    rng = np.random.default_rng(21)
    n = 40
    rows = np.array([_vm_row(float(i % 2), float(i % 3 == 2)) for i in range(n)])
    state = np.abs(rng.normal(scale=0.1, size=(n, 3)))
    eps = rng.normal(scale=0.03, size=(n, 4))
    D = von_mises.tangent(eps, state, rows)
    ref = np.empty((n, 4, 4))
    for k in range(4):
        pert = eps.astype(complex)
        pert[:, k] += 1e-30j
        ref[:, :, k] = von_mises.update(pert, state.astype(complex), rows)[2].imag / 1e-30
    assert D.shape == (n, 4, 4)
    assert np.abs(D - ref).max() <= 1.5e-15 * np.abs(ref).max()
    plastic = von_mises.update(eps, state.copy(), rows)[1][:, 0] > state[:, 0]
    assert 5 < plastic.sum() < n - 5


# --------------------------------------------------------------- dtypes of the complex step
def _mixed_soil():
    """Mohr–Coulomb and linear elastic points interleaved (10 columns).  Both models
    take any mix of real and complex input (von Mises needs both complex, as
    stress_update passes them)."""
    names = [mohr_coulomb.NAME, "linear_elastic", mohr_coulomb.NAME] * 3
    rows = [MC_ROW if m == mohr_coulomb.NAME else [G, K] + [math.nan] * 8 for m in names]
    return MaterialPoints(np.array([model_id(m) for m in names]), np.array(rows, float))


@pytest.mark.parametrize("complex_strain, complex_state", [(True, True), (True, False),
                                                           (False, True)])
def test_mixed_return_map_keeps_the_dtype_of_its_inputs(complex_strain, complex_state):
    """return_map over several models returns, for any mix of real and complex trial
    strain and state, exactly what each model's update returns on its own points —
    imaginary parts (the complex-step derivatives) included."""
    soil = _mixed_soil()
    rng = np.random.default_rng(5)
    eps = rng.normal(scale=0.02, size=(9, 4)) + (1e-30j * rng.normal(size=(9, 4))
                                                   if complex_strain else 0)
    state = np.abs(rng.normal(scale=0.1, size=(9, 3))) + (1e-30j if complex_state else 0)
    got = return_map(eps, state, soil)
    assert all(np.iscomplexobj(a) for a in got)
    for k in np.unique(soil.model):
        idx = np.nonzero(soil.model == k)[0]
        want = model(int(k)).update(eps[idx], state[idx], soil.params[idx])
        for a, b in zip(got, want):
            assert np.array_equal(a[idx], b)
    assert np.any(got[2].imag != 0) and np.any(got[1].imag != 0)


def test_mohr_coulomb_complex_derivative_along_the_state_is_the_softening_rate():
    """d tau / d gamma_p of softening Mohr–Coulomb points (real trial strain, complex
    plastic shear strain) equals the central difference (step 1e-5).  Achieves 2.6e-11
    relative to the largest entry (the difference's own error); asserts 2e-10."""
    rows = np.tile(MC_ROW, (6, 1))
    eps = np.random.default_rng(8).normal(scale=0.02, size=(6, 4))
    g0 = np.full((6, 1), 0.2)
    d_cs = mohr_coulomb.update(eps, g0 + 1e-30j, rows)[2].imag / 1e-30
    d = 1e-5
    d_fd = (mohr_coulomb.update(eps, g0 + d, rows)[2]
            - mohr_coulomb.update(eps, g0 - d, rows)[2]) / (2 * d)
    assert np.abs(d_fd).max() > 1.0                     # some points soften
    assert np.abs(d_cs - d_fd).max() <= 2e-10 * np.abs(d_fd).max()


def test_reduce_strength_leaves_the_scene_rows_alone():
    """A strength reduction returns new rows (c / F, atan(tan(phi) / F)); the rows it was
    given are unchanged."""
    rows = np.tile(MC_ROW, (3, 1))
    keep = rows.copy()
    out = strength.reduce_strength(mohr_coulomb.NAME, rows, 1.5, softening=True)
    assert np.array_equal(rows, keep) and out is not rows
    assert out[0, 2] == pytest.approx(10.0 / 1.5, rel=1e-15, abs=0)
    assert out[0, 4] == pytest.approx(math.degrees(math.atan(math.tan(math.radians(30)) / 1.5)),
                                      rel=1e-14, abs=0)


# --------------------------------------------------------------- input checks
def test_regularisation_checks_in_full():
    """The three messages of the regularisation check, whole, with their keys; a key of
    the non-local average without ``regularisation`` given names the default 'local'."""
    chk = von_mises._check_regularisation
    assert chk({"internal_length": 0.5}) == (
        "internal_length", "internal_length belongs to regularisation = 'nonlocal' (now "
        "'local'); allowed: regularisation = 'nonlocal' with internal_length, or no "
        "internal_length")
    assert chk({"regularisation": "nonlocal", "internal_length": 0.5,
                "softening_displacement": 0.1}) == (
        "softening_displacement", "both regularisations at once (internal_length, "
        "softening_displacement); allowed: the keys of one of them")
    assert chk({"regularisation": "displacement", "internal_length": math.nan}) == (
        "softening_displacement", "regularisation = 'displacement' needs "
        "softening_displacement; allowed: a number in (0, inf) (m)")
    assert chk({"regularisation": "displacement", "softening_displacement": 0.1}) is None


def test_displacement_regularisation_is_exempt_from_the_snap_back_check():
    """regularisation = 'displacement' replaces softening_strain by softening_displacement
    / h when the points are made, so a softening_strain that would make h >= G is not an
    error there (it is with the local law)."""
    values = {"cohesion_peak": CP, "cohesion_residual": CR, "softening_strain": 0.01,
              "softening": "linear", "shear_modulus": G}
    assert von_mises.check(values)[0] == "softening_strain"
    assert von_mises.check({**values, "regularisation": "displacement",
                            "softening_displacement": 0.1}) is None


def test_von_mises_invalid_points_bound_and_message():
    """Per point: any cohesion_peak > 0 is a strength (0.5 kPa is valid, 0 is not); the
    reason in full."""
    rows = np.array([[G, K, 0.5, 0.5, GS, 0], [G, K, 0.0, 0.0, GS, 0]], float)
    bad, why = von_mises.invalid_points(rows)
    assert bad.tolist() == [False, True]
    assert why == ("its linear softening modulus is not below the shear modulus (or it is "
                   "not positive)")


def test_mohr_coulomb_check_small_friction_alone_is_a_strength():
    """No cohesion and phi = 0.5 deg is some strength (only c = phi = 0 is refused)."""
    values = {"cohesion_peak": 0.0, "cohesion_residual": 0.0, "friction_angle_peak": 0.5,
              "friction_angle_residual": 0.5, "dilation_angle_peak": 0.0,
              "dilation_angle_residual": 0.0, "softening_strain": 0.5, "softening": "linear",
              "shear_modulus": G}
    assert mohr_coulomb.check(values) is None


def test_mohr_coulomb_invalid_points_each_bound_and_message():
    """Valid rows on each boundary: (c_p - c_r)/g_s = G/2 although (c_p + c_r)/g_s > G;
    c = 0 with phi = 30 or 0.5 deg; c = 0.5 kPa with phi = 0; residual = peak for c and
    phi.  Invalid: c = phi = 0.  The reason in full."""
    rows = np.array([MC_ROW] * 6)
    rows[0, 8] = 10.0 / G                              # h = G / 2, (c_p + c_r) / g_s = 1.5 G
    rows[1, 2:6] = [0.0, 0.0, 30.0, 25.0]
    rows[2, 2:8] = [0.0, 0.0, 0.5, 0.5, 0.0, 0.0]
    rows[3, 2:8] = [0.5, 0.5, 0.0, 0.0, 0.0, 0.0]
    rows[4, 2:6] = [10.0, 10.0, 30.0, 30.0]
    rows[5, 2:8] = 0.0
    bad, why = mohr_coulomb.invalid_points(rows)
    assert bad.tolist() == [False, False, False, False, False, True]
    assert why == ("its strengths are not 0 <= residual <= peak, it has no strength, or its "
                   "cohesion softening modulus is not below the shear modulus")
