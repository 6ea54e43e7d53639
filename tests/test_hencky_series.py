"""The vectorised series of the Hencky update (:mod:`fem_rmpm.schemes.explicit.kernels.hencky`).

References: the functions themselves in 50-digit decimal arithmetic (``decimal``'s
``exp`` and ``ln``: cosh(y) = (e^y + e^-y)/2, sinh(y)/y, atanh(x)/x = ln((1+x)/(1-x))/(2x),
ln J), and the numpy reference of the trial log strain, ``1/2 ln(dF exp(2 eps) dF^T)``
through :func:`fem_rmpm.materials.hencky.exp_sym2` / ``log_sym2`` (numpy's exp, cosh,
sinh, log, arctanh of the matrix's own invariants).
"""
from __future__ import annotations

import math
from decimal import Decimal, getcontext

import numpy as np
import pytest

from fem_rmpm.materials.hencky import exp_sym2, log_sym2
from fem_rmpm.schemes.explicit.kernels import hencky as H
from fem_rmpm.schemes.explicit.kernels.common import BLOCK
from fem_rmpm.schemes.explicit.kernels.strain import hencky_trial_pass

getcontext().prec = 50
ULP = 2.0 ** -52


def _cosh(y2: float) -> Decimal:
    y = Decimal(y2).sqrt()
    return (y.exp() + (-y).exp()) / 2


def _sinhc(y2: float) -> Decimal:
    y = Decimal(y2).sqrt()
    return (y.exp() - (-y).exp()) / (2 * y) if y2 > 0 else Decimal(1)


def _atanhc(z: float) -> Decimal:
    x = Decimal(z).sqrt()
    return ((1 + x) / (1 - x)).ln() / (2 * x) if z > 0 else Decimal(1)


def _rel(value: float, exact: Decimal) -> float:
    return float(abs(Decimal(value) - exact) / abs(exact))


@pytest.mark.parametrize("name,series,exact,top", [
    ("cosh", H.cosh_series, _cosh, H.Y2_MAX), ("sinh(y)/y", H.sinhc_series, _sinhc, H.Y2_MAX),
    ("atanh(x)/x", H.atanhc_series, _atanhc, H.Z_MAX)])
def test_series_within_two_ulp_of_50_digit_values_over_their_range(name, series, exact, top):
    """201 arguments from 0 to the range's end (where the truncation error is largest):
    each series is within 2 ulp of the 50-digit value (the table in the module: omitted
    terms < 1e-18, the rest is Horner's rounding; measured 0.50 ulp at most)."""
    worst = max(_rel(series(a), exact(a)) for a in np.linspace(0.0, top, 201))
    assert worst <= 2 * ULP, f"{name}: {worst / ULP:.2f} ulp"


def test_log_of_the_step_volume_ratio_within_two_ulp():
    """ln(J) = 2 u atanh(u)/u, u = (J - 1)/(J + 1), over 0.6 <= J <= 5/3 (u^2 <= 1/16):
    301 values within 2 ulp of 50 digits (measured 1.2 ulp at most)."""
    worst = 0.0
    for J in np.linspace(0.6, 5.0 / 3.0, 301):
        if J == 1.0:
            continue
        lj, _ = H.log_parts(J, 0.0)
        worst = max(worst, _rel(lj, Decimal(J).ln()))
    assert worst <= 2 * ULP, f"{worst / ULP:.2f} ulp"


def test_parts_outside_the_series_ranges_use_the_math_functions():
    """Beyond the ranges the parts are the ``math`` forms: within 2 ulp of 50 digits
    (measured: 0.76 ulp at most over these 8 arguments)."""
    for y2 in (0.07, 1.0, 25.0):
        ch, sh = H.exp_parts(math.sqrt(y2) / 2, -math.sqrt(y2) / 2, 0.0)   # y^2 = 4 r^2
        assert _rel(ch, _cosh(y2)) <= 2 * ULP and _rel(sh, _sinhc(y2)) <= 2 * ULP
    for z in (0.07, 0.5, 0.9):
        assert _rel(H.log_parts(1.0, z)[1], _atanhc(z)) <= 2 * ULP
    for J in (0.1, 3.0):
        assert _rel(H.log_parts(J, 0.0)[0], Decimal(J).ln()) <= 2 * ULP


def _trial_numpy(dF, ls):
    """1/2 ln(dF exp(2 eps) dF^T) through the numpy reference of the materials."""
    bxx, byy, bxy = exp_sym2(ls[:, 0], ls[:, 1], ls[:, 3])
    B = np.empty((len(ls), 2, 2))
    B[:, 0, 0], B[:, 1, 1], B[:, 0, 1], B[:, 1, 0] = bxx, byy, bxy, bxy
    F = dF.reshape(-1, 2, 2)
    bt = F @ B @ np.swapaxes(F, 1, 2)
    return np.stack(log_sym2(bt[:, 0, 0], bt[:, 1, 1], 0.5 * (bt[:, 0, 1] + bt[:, 1, 0])), 1)


def _trial_kernel(dF, ls, active=None):
    n = len(ls)
    eps = np.zeros((n, 4))
    active = np.ones(n, bool) if active is None else active
    hencky_trial_pass(np.ascontiguousarray(dF), np.ascontiguousarray(ls), active, np.zeros(n),
                      np.zeros(n), np.zeros(n), np.zeros((4, n)), eps)
    return eps


@pytest.mark.parametrize("strain", [0.003, 0.03, 0.3])
def test_trial_log_strain_equals_numpy_reference(strain):
    """1000 random points (log strains ~ N(0, strain), increments I + N(0, 0.02)): the
    kernel's trial log strain equals the numpy reference within 1e-14 of the largest
    component (measured <= 5.3e-15); at strain 0.3 about half of the points take the
    ``math`` forms (outside the series ranges)."""
    rng = np.random.default_rng(7)
    ls = rng.normal(0.0, strain, (1000, 4))
    dF = np.eye(2).ravel() + rng.normal(0.0, 0.02, (1000, 4))
    got = _trial_kernel(dF, ls)
    ref = _trial_numpy(dF, ls)
    err = np.abs(got[:, [0, 1, 3]] - ref).max() / np.abs(ref).max()
    assert err < 1e-14, err
    assert np.array_equal(got[:, 2], ls[:, 2])


def test_a_point_outside_the_ranges_leaves_its_block_bitwise_unchanged():
    """One point of a block with a large shear strain (outside the series) is recomputed
    alone: the block's other points are bitwise those of the block without it."""
    rng = np.random.default_rng(3)
    ls = rng.normal(0.0, 0.02, (2 * BLOCK, 4))
    dF = np.eye(2).ravel() + rng.normal(0.0, 0.01, (2 * BLOCK, 4))
    base = _trial_kernel(dF, ls)
    ls2 = ls.copy()
    ls2[5, 3] = 0.4                   # y^2 = 0.64 > Y2_MAX
    dF2 = dF.copy()
    dF2[9] = [1.5, 0.0, 0.0, 1.5]     # J = 2.25: u^2 > Z_MAX
    out = _trial_kernel(dF2, ls2)
    keep = np.ones(len(ls), bool)
    keep[[5, 9]] = False
    assert np.array_equal(out[keep], base[keep])
    ref = _trial_numpy(dF2[[5, 9]], ls2[[5, 9]])
    assert np.allclose(out[[5, 9]][:, [0, 1, 3]], ref, rtol=0, atol=1e-14)


def test_non_finite_input_gives_non_finite_trial_strain():
    """NaN in a log strain or in an increment reaches the trial strain (the run's guard
    then stops the run); the other points are finite."""
    ls = np.zeros((4, 4))
    dF = np.tile(np.eye(2).ravel(), (4, 1))
    ls[1, 0] = np.nan
    dF[2, 1] = np.inf
    out = _trial_kernel(dF, ls)
    assert not np.isfinite(out[1]).all() and not np.isfinite(out[2]).all()
    assert np.isfinite(out[[0, 3]]).all()
