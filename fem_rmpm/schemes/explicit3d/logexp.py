"""Logarithm and exponential over the elastic stretches of soil, as straight-line
arithmetic that LLVM vectorizes: the stress pass's principal log strains
``ln(lambda) / 2`` of the trial stretch's eigenvalues ``lambda`` and the returned
stretches ``exp(2 e)`` (:mod:`.finite_block`, loops 1 and 3), eight points per AVX-512
instruction instead of one library call per value.  Both follow fdlibm's ``log`` and
``exp`` (the reduction by ``ln 2`` in two parts, the series on the reduced argument) with
the reduction written as selections instead of exponent bit fields, and Taylor
coefficients:

* :func:`log_near_one`: ``ln x`` for ``x`` in [:data:`LOG_LO`, :data:`LOG_HI`]
  (principal log strains of -1.2 to 1.2): ``x = 2^k m`` with ``m`` in [1/sqrt 2, sqrt 2]
  (three halvings or doublings at most), ``f = m - 1`` (exact), ``s = f / (2 + f)``,
  ``ln m = 2 atanh s = f - s (f - R)`` with ``R = sum_k 2 s^2k / (2k + 1)`` (k = 1 to 11,
  remainder below 1e-18 of ``ln m``), ``ln x = k ln2_hi + (ln m + k ln2_lo)``;
* :func:`exp_small`: ``e^y`` for ``|y| <=`` :data:`EXP_BOUND`: ``k = round(y / ln 2)``,
  ``r = (y - k ln2_hi) - k ln2_lo`` (``|r| <= 0.35``), ``e^r = 1 + (r + r^2 P(r))``, ``P``
  the Taylor polynomial of ``(e^r - 1 - r) / r^2`` to ``r^12`` (remainder below 5e-18),
  times ``2^k`` (exact).

Each result is within about one unit in the last place of the correctly rounded value,
as the library's (measured against ``numpy.longdouble``, ``tests/test_3d_logexp.py``), but
not always the same bits.  Outside the ranges the callers take the library ``math.log`` /
``math.exp``.
"""
from __future__ import annotations

from fem_rmpm.runtime.compiled import inline

__all__ = ["log_near_one", "exp_small", "log_in_range", "exp_in_range", "LOG_LO", "LOG_HI",
           "EXP_BOUND"]

#: The range of :func:`log_near_one` (``2^-3 / sqrt 2`` to ``2^3 sqrt 2``, rounded inwards).
LOG_LO, LOG_HI = 0.09, 11.0
#: The range of :func:`exp_small`: ``|y| <= 2.5``.
EXP_BOUND = 2.5

_SQRT2, _SQRT1_2 = 1.4142135623730951, 0.7071067811865476
# ln 2 in two parts (fdlibm): the first with 32 trailing zero bits, so k ln2_hi is exact
_LN2_HI, _LN2_LO = 6.93147180369123816490e-01, 1.90821492927058770002e-10
_INV_LN2 = 1.44269504088896338700e+00
_ROUND = 6755399441055744.0          # 1.5 * 2^52: x + _ROUND - _ROUND rounds x to an integer
# 2 / (2k + 1), k = 1..11
_L1, _L2, _L3, _L4, _L5 = 2.0 / 3.0, 2.0 / 5.0, 2.0 / 7.0, 2.0 / 9.0, 2.0 / 11.0
_L6, _L7, _L8, _L9, _L10 = 2.0 / 13.0, 2.0 / 15.0, 2.0 / 17.0, 2.0 / 19.0, 2.0 / 21.0
_L11 = 2.0 / 23.0
# 1 / k!, k = 2..14
_E2, _E3, _E4, _E5 = 1.0 / 2.0, 1.0 / 6.0, 1.0 / 24.0, 1.0 / 120.0
_E6, _E7, _E8, _E9 = 1.0 / 720.0, 1.0 / 5040.0, 1.0 / 40320.0, 1.0 / 362880.0
_E10, _E11, _E12 = 1.0 / 3628800.0, 1.0 / 39916800.0, 1.0 / 479001600.0
_E13, _E14 = 1.0 / 6227020800.0, 1.0 / 87178291200.0


@inline
def _halve_or_double(m, k):
    """One step of the reduction of ``m`` towards [1/sqrt 2, sqrt 2]: ``(m', k')`` with
    ``m 2^k = m' 2^k'`` (exact)."""
    up = m > _SQRT2
    m, k = (m * 0.5, k + 1.0) if up else (m, k)
    down = m < _SQRT1_2
    return (m * 2.0, k - 1.0) if down else (m, k)


@inline
def log_near_one(x):
    """``ln x`` (module docstring) for ``x`` in [LOG_LO, LOG_HI]; a number of no
    meaning outside (the caller selects the library value there)."""
    m, k = _halve_or_double(x, 0.0)
    m, k = _halve_or_double(m, k)
    m, k = _halve_or_double(m, k)
    f = m - 1.0
    s = f / (2.0 + f)
    z = s * s
    r = z * (_L1 + z * (_L2 + z * (_L3 + z * (_L4 + z * (_L5 + z * (
        _L6 + z * (_L7 + z * (_L8 + z * (_L9 + z * (_L10 + z * _L11))))))))))
    return k * _LN2_HI + (f - (s * (f - r) - k * _LN2_LO))


@inline
def _pow2(k):
    """``2^k`` for the integers ``k`` of -4 to 4 (a float), by selection."""
    p = 16.0 if k == 4.0 else 8.0
    p = 4.0 if k == 2.0 else p
    p = 2.0 if k == 1.0 else p
    p = 1.0 if k == 0.0 else p
    p = 0.5 if k == -1.0 else p
    p = 0.25 if k == -2.0 else p
    p = 0.125 if k == -3.0 else p
    return 0.0625 if k == -4.0 else p


@inline
def exp_small(y):
    """``e^y`` (module docstring) for ``|y| <= EXP_BOUND``; a number of no meaning
    outside (the caller selects the library value there)."""
    k = (y * _INV_LN2 + _ROUND) - _ROUND
    r = (y - k * _LN2_HI) - k * _LN2_LO
    p = _E2 + r * (_E3 + r * (_E4 + r * (_E5 + r * (_E6 + r * (_E7 + r * (
        _E8 + r * (_E9 + r * (_E10 + r * (_E11 + r * (_E12 + r * (_E13 + r * _E14)))))))))))
    return (1.0 + (r + (r * r) * p)) * _pow2(k)


@inline
def log_in_range(x):
    """True where :func:`log_near_one` holds."""
    return (x >= LOG_LO) & (x <= LOG_HI)


@inline
def exp_in_range(y):
    """True where :func:`exp_small` holds."""
    return (y >= -EXP_BOUND) & (y <= EXP_BOUND)
