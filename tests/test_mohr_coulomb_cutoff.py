"""The tension cut-off of the Mohr–Coulomb model (``tension_cutoff``, kPa): no principal
stress above t_c (Rankine planes), returned exactly together with the Mohr–Coulomb planes.

References: the closest-point projection in the energy norm (Simo & Hughes 1998,
*Computational Inelasticity*, sec. 3.6: for associated perfect plasticity the return is
the stress of the admissible set nearest to the trial in the compliance metric), here
computed independently by scipy's SLSQP over the nine planes (three tension, six
Mohr–Coulomb orderings); the multi-surface corner returns of de Souza Neto, Peric & Owen
2008, sec. 8.2.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.optimize import minimize
from test_mohr_coulomb import _scene, kernel_equals_numpy

from fem_rmpm.materials import mohr_coulomb as mc
from fem_rmpm.scene import SceneError

E, NU = 1e4, 0.3
G, KB = E / (2 * (1 + NU)), E / (3 * (1 - 2 * NU))
LAM = KB - 2 * G / 3
C3 = np.full((3, 3), LAM) + 2 * G * np.eye(3)


def _row(c=10.0, phi=30.0, psi=None, tc=5.0, c_r=None, phi_r=None, gs=0.5, expo=0):
    psi = phi if psi is None else psi
    return np.array([[G, KB, c, c if c_r is None else c_r, phi, phi if phi_r is None else phi_r,
                      psi, psi, gs, expo, tc]], dtype=float)


def _principal(tau):
    m, d = 0.5 * (tau[:, 0] + tau[:, 1]), 0.5 * (tau[:, 0] - tau[:, 1])
    r = np.sqrt(d * d + tau[:, 3] ** 2)
    return -np.sort(-np.stack([m + r, m - r, tau[:, 2]], 1), axis=1)


def _constraints(c, phi, tc):
    s, cc = math.sin(math.radians(phi)), c * math.cos(math.radians(phi))

    def g(S):                                       # >= 0 inside
        out = [tc - S[i] for i in range(3)]
        out += [-(S[i] - S[j] + (S[i] + S[j]) * s - 2 * cc)
                for i in range(3) for j in range(3) if i != j]
        return np.array(out)
    return g


def _closest_point(St, c, phi, tc, starts):
    """The admissible principal stress nearest to St in the compliance norm (SLSQP)."""
    Ci = np.linalg.inv(C3)
    g = _constraints(c, phi, tc)
    best = None
    for x0 in starts:
        r = minimize(lambda S: 0.5 * (S - St) @ Ci @ (S - St), x0, jac=lambda S: Ci @ (S - St),
                     constraints=[{"type": "ineq", "fun": g}], method="SLSQP",
                     options={"ftol": 1e-15, "maxiter": 1000})
        if g(r.x).min() > -1e-7 and (best is None or r.fun < best.fun):
            best = r
    return best.x


def _branch(s, c, phi, tc, tol=1e-9):
    """Active planes of a returned principal stress s (decreasing): 'T' for each
    principal at t_c, 'M' if Mohr–Coulomb is active."""
    sp, cc = math.sin(math.radians(phi)), c * math.cos(math.radians(phi))
    n_t = int(np.sum(np.abs(s - tc) <= tol * (abs(tc) + c)))
    f = s[0] - s[2] + (s[0] + s[2]) * sp - 2 * cc
    return "T" * n_t + ("M" if abs(f) <= tol * (np.abs(s).max() + c) else "")


def test_cutoff_return_is_the_closest_point():
    """Associated (psi = phi = 30 deg), perfectly plastic, c = 10, t_c = 5 kPa: on 300
    random principal trial states the return equals the SLSQP closest point over the nine
    planes (achieves 3e-9 relative, the optimiser's precision; asserts 1e-6), and the
    states cover every cut-off corner: T, TM, TT, TTM, TTT and the Mohr–Coulomb returns."""
    rng = np.random.default_rng(3)
    seen = set()
    worst = 0.0
    for _ in range(300):
        e = rng.standard_normal(3) * 2e-3 + rng.standard_normal() * 1e-3
        _, _, tau = mc.update(np.array([[e[0], e[1], e[2], 0.0]]), np.zeros((1, 1)), _row())
        St, S = C3 @ e, tau[0, :3]
        ref = _closest_point(St, 10.0, 30.0, 5.0, (S, np.full(3, -1.0), np.minimum(St, 4.0)))
        worst = max(worst, np.abs(ref - S).max() / (np.abs(St).max() + 10.0))
        seen.add(_branch(np.sort(S)[::-1], 10.0, 30.0, 5.0))
    print("worst", worst, sorted(seen))
    assert worst < 1e-6
    assert {"T", "TM", "TT", "TTM", "TTT", "M", ""} <= seen


def test_tension_levels_off_at_the_cutoff():
    """Plane-strain extension of one point (xx stretched in steps, yy and zz held): the
    major principal stress rises elastically and then stays at t_c exactly (achieves
    1e-15 relative; asserts 1e-12), never above it; the plastic shear strain grows (the
    tension flow has a deviatoric part)."""
    row = _row(c=20.0, phi=25.0, tc=8.0)
    eps, st = np.zeros((1, 4)), np.zeros((1, 1))
    s1 = []
    for _ in range(40):
        eps, st, tau = mc.update(eps + np.array([[1e-4, 0, 0, 0]]), st, row)
        s1.append(_principal(tau)[0, 0])
    s1 = np.array(s1)
    assert np.all(s1 <= 8.0 * (1 + 1e-12)) and abs(s1[-1] - 8.0) <= 1e-12 * 8.0
    assert s1[0] < 8.0 and st[0, 0] > 0


def test_cutoff_above_the_apex_changes_nothing():
    """t_c >= c cot(phi) cannot be reached (the apex is the tensile limit): the update
    equals the one without the cut-off (inf), bitwise, on random states."""
    rng = np.random.default_rng(5)
    e = 0.003 * rng.normal(size=(400, 4)) + 0.002
    st = np.zeros((400, 1))
    a = mc.update(e, st, np.repeat(_row(tc=math.inf), 400, axis=0))
    b = mc.update(e, st, np.repeat(_row(tc=10.0 / math.tan(math.radians(30.0)) + 1.0), 400, 0))
    for x, y in zip(a, b):
        assert np.array_equal(x, y)


CUTOFF_CASES = {  # name: (trial [xx, yy, zz, xy], row, branch of the returned stress)
    "T": ([0.002, -0.001, 0.0, 0.0003], _row(), "T"),
    "TT": ([0.004, 0.003, 0.0, 0.0002], _row(), "TT"),
    "TTT": ([0.01, 0.01, 0.011, 0.0001], _row(), "TTT"),
    "TM": ([0.0004, 0.0017, -0.0022, 0.0003], _row(), "TM"),
    "TTM": ([0.004, 0.0035, -0.0035, 0.0003], _row(), "TTM"),
    "TM non-associated": ([-0.0023, 0.0008, 0.0019, 0.0003], _row(psi=5.0), "TM"),
    "TTM non-associated": ([0.0014, -0.0024, 0.0029, 0.0003], _row(psi=5.0), "TTM"),
    "TM softening": ([-0.0026, -0.0016, 0.004, 0.0003],
                     _row(c=10.0, phi=30.0, psi=10.0, c_r=4.0, phi_r=25.0, gs=0.05), "TM"),
    "TTM softening": ([0.0036, 0.0035, -0.0034, 0.0003],
                      _row(c=10.0, phi=30.0, psi=10.0, c_r=4.0, phi_r=25.0, gs=0.05), "TTM"),
    "TT softening": ([0.0018, 0.0028, -0.0005, 0.0003],
                     _row(c=10.0, phi=30.0, psi=10.0, c_r=4.0, phi_r=25.0, gs=0.05), "TT"),
    "T exponential": ([0.002, -0.001, 0.0, 0.0003],
                      _row(c=10.0, phi=30.0, psi=10.0, c_r=4.0, phi_r=25.0, gs=0.05, expo=1),
                      "T"),
}


@pytest.mark.parametrize("name", list(CUTOFF_CASES))
def test_cutoff_tangent_matches_finite_differences(name):
    """d tau / d eps_trial by the complex step (the implicit scheme's tangent) equals a
    central finite difference (h = 1e-8) on every cut-off branch, associated or not,
    perfectly plastic or softening (achieves ~1e-8; asserts 1e-6 relative to the largest
    entry, or to G on the corner TTT where the stress is t_c whatever the strain and
    D = 0: there the difference is 3e-10 G of round-off); each case returns to the corner
    it names."""
    trial, row, branch = CUTOFF_CASES[name]
    e0 = np.array([trial], dtype=float)
    st = np.zeros((1, 1))
    D_cs, D_fd = np.empty((4, 4)), np.empty((4, 4))
    for j in range(4):
        h = np.zeros((1, 4))
        h[0, j] = 1.0
        D_cs[:, j] = mc.update(e0 + 1e-30j * h, st, row)[2][0].imag / 1e-30
        D_fd[:, j] = (mc.update(e0 + 1e-8 * h, st, row)[2][0]
                      - mc.update(e0 - 1e-8 * h, st, row)[2][0]) / 2e-8
    scale = max(np.abs(D_cs).max(), G)        # TTT: the stress is t_c whatever, D = 0
    assert np.abs(D_cs - D_fd).max() <= 1e-6 * scale, (D_cs, D_fd)
    _, gam, tau = mc.update(e0, st, row)
    c, phi = mc.cohesion(gam[:, 0], row)[0][0], mc.friction_angle(gam[:, 0], row)[0]
    assert _branch(_principal(tau)[0], c, phi, row[0, 10]) == branch


def test_explicit_kernel_equals_numpy_update_with_cutoff():
    """The kernels' point function equals the numpy update with the cut-off on (random
    states, softening, every branch; achieves ~1e-16 relative; asserts 1e-12)."""
    rng = np.random.default_rng(4)
    n = 2000
    t_ref, _, _ = kernel_equals_numpy(np.repeat(_row(10.0, 30.0, 10.0, 3.0, 2.0, 20.0, gs=0.3),
                                                n, axis=0), rng)
    assert (_principal(t_ref)[:, 0] >= 3.0 - 1e-9).sum() > 0.05 * n


def test_scene_reads_and_refuses_the_cutoff():
    """``tension_cutoff`` in a [[soil]] table: a number >= 0 kPa or inf (the default);
    a negative value is one SceneError naming the key (exit 2 through the CLI)."""
    assert _scene(tension_cutoff=2.0).soils[0].value("tension_cutoff") == 2.0
    assert _scene().soils[0].value("tension_cutoff", math.inf) == math.inf
    with pytest.raises(SceneError, match=r"\[soil(\[0\])?\.tension_cutoff\].*out of range"):
        _scene(tension_cutoff=-1.0)

