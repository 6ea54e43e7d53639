"""The pair intrinsics of ``fem_rmpm.schemes.explicit.kernels.pairs`` against exact arithmetic.

Reference: IEEE 754-2008 (section 5.4.1) defines fusedMultiplyAdd(x, y, z) as x y + z
computed exactly and rounded once; an ordinary multiply and add round twice.  The exact
value is computed here with ``fractions.Fraction`` and rounded once by ``float()``
(correctly rounded, to nearest even), so the fused and the unfused results differ on the
chosen operands and the tests can tell them apart.
"""
from __future__ import annotations

from fractions import Fraction

import numpy as np
import pytest
from numba import njit
from numba.core.errors import TypingError

from fem_rmpm.schemes.explicit.kernels.pairs import fma2, fma2_to, load2, mul2, sub2_from

EPS = 2.0 ** -30
# w x + y with w = x = 1 + 2^-30, y = -(1 + 2^-29): exactly 2^-60, but w x rounds to
# 1 + 2^-29 first, so an unfused multiply-add gives 0
W, X, Y = 1.0 + EPS, 1.0 + EPS, -(1.0 + 2 * EPS)


def fused(w: float, x: float, y: float) -> float:
    """w x + y rounded once (the IEEE fusedMultiplyAdd)."""
    return float(Fraction(w) * Fraction(x) + Fraction(y))


@njit
def _fma2(w, x0, x1, y0, y1):
    return fma2(w, (x0, x1), (y0, y1))


@njit
def _mul2(w, x0, x1):
    return mul2(w, (x0, x1))


@njit
def _load2(a, i):
    return load2(a, np.uint64(i))


@njit
def _fma2_to(a, i, w, x0, x1):
    fma2_to(a, np.uint64(i), w, (x0, x1))


@njit
def _sub2_from(a, i, x0, x1):
    sub2_from(a, np.uint64(i), (x0, x1))


def test_fma2_rounds_once_per_component():
    assert fused(W, X, Y) == 2.0 ** -60 and W * X + Y == 0.0      # the operands tell
    got = _fma2(W, X, 3.0 * X, Y, 0.5)
    assert got == (fused(W, X, Y), fused(W, 3.0 * X, 0.5))


def test_fma2_to_updates_exactly_the_pair():
    a = np.arange(8.0)
    a[3], a[4] = Y, -7.25
    _fma2_to(a, 3, W, X, 2.0)
    expected = np.arange(8.0)
    expected[3], expected[4] = fused(W, X, Y), fused(W, 2.0, -7.25)
    assert np.array_equal(a, expected)


def test_sub2_from_load2_and_mul2():
    a = np.arange(6.0) + 0.5
    _sub2_from(a, 2, 0.25, -1.0)
    assert np.array_equal(a, [0.5, 1.5, 2.25, 4.5, 4.5, 5.5])
    assert _load2(a, 4) == (4.5, 5.5)
    assert _mul2(3.0, 0.1, -2.5) == (3.0 * 0.1, -7.5)


def test_pairs_refuse_a_strided_array():
    """A strided view's elements ``i``, ``i + 1`` are not adjacent: no pair to load."""
    with pytest.raises(TypingError):
        _load2(np.arange(8.0)[::2], 0)
