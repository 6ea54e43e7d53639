"""The vectorizable logarithm and exponential of the 3-D stress pass
(:mod:`fem_rmpm.schemes.explicit3d.logexp`) against the correctly rounded values, taken
from ``numpy.longdouble`` (x87 extended precision, 64-bit significand): within one unit
in the last place (ulp) over their ranges, as the library's ``math.log`` and
``math.exp`` (0.5 ulp), and exact where the value is (``ln 1 = 0``, ``e^0 = 1``)."""
from __future__ import annotations

import math

import numpy as np
import pytest
from numba import njit

from fem_rmpm.schemes.explicit3d.logexp import (
    EXP_BOUND,
    LOG_HI,
    LOG_LO,
    exp_in_range,
    exp_small,
    log_in_range,
    log_near_one,
)

#: Largest error allowed in units in the last place: 0.93 (log) and 0.91 (exp) measured.
ULP = 1.0


@njit
def _apply(f, x):
    out = np.empty_like(x)
    for i in range(x.size):
        out[i] = f(x[i])
    return out


@njit
def _log(x):
    return log_near_one(x)


@njit
def _exp(x):
    return exp_small(x)


def _ulps(y: np.ndarray, exact: np.ndarray) -> np.ndarray:
    return np.abs(y.astype(np.longdouble) - exact) / np.spacing(np.abs(exact.astype(float)))


pytestmark = pytest.mark.skipif(np.finfo(np.longdouble).nmant < 63,
                                reason="needs an extended-precision longdouble as reference")


def test_log_within_one_ulp_over_its_range():
    rng = np.random.default_rng(5)
    x = np.concatenate([np.exp(rng.uniform(math.log(LOG_LO), math.log(LOG_HI), 200_000)),
                        1.0 + rng.uniform(-1e-3, 1e-3, 20_000),
                        [LOG_LO, LOG_HI, math.sqrt(2.0), math.sqrt(0.5), 0.5, 2.0, 8.0,
                         np.nextafter(1.0, 0.0), np.nextafter(1.0, 2.0)]])
    y = _apply(_log, x)
    assert _ulps(y, np.log(x.astype(np.longdouble))).max() <= ULP
    assert _apply(_log, np.array([1.0]))[0] == 0.0


def test_exp_within_one_ulp_over_its_range():
    rng = np.random.default_rng(6)
    y = np.concatenate([rng.uniform(-EXP_BOUND, EXP_BOUND, 200_000),
                        rng.uniform(-1e-3, 1e-3, 20_000),
                        [EXP_BOUND, -EXP_BOUND, math.log(2.0) / 2, -math.log(2.0) / 2, 1e-300]])
    e = _apply(_exp, y)
    assert _ulps(e, np.exp(y.astype(np.longdouble))).max() <= ULP
    assert _apply(_exp, np.array([0.0]))[0] == 1.0


def test_ranges_are_those_the_callers_check():
    """The range tests select the series exactly on [LOG_LO, LOG_HI] and [-B, B]."""
    @njit
    def both(x, y):
        return log_in_range(x), exp_in_range(y)
    assert both(LOG_LO, EXP_BOUND) == (True, True)
    assert both(LOG_HI, -EXP_BOUND) == (True, True)
    assert both(np.nextafter(LOG_LO, 0.0), np.nextafter(EXP_BOUND, 3.0)) == (False, False)
    assert both(np.nextafter(LOG_HI, 20.0), np.nextafter(-EXP_BOUND, -3.0)) == (False, False)
    assert both(np.nan, np.nan) == (False, False)
