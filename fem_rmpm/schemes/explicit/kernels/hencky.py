"""The transcendental functions of the Hencky update, vectorised over blocks of points.

The elastic state is the log strain ``eps = 1/2 ln(b_e)`` (:mod:`fem_rmpm.materials.hencky`);
a finite-strain step needs ``eps_tr = 1/2 ln(dF exp(2 eps) dF^T)``.  Write the in-plane
``eps = m I + D`` (``m`` the mean, ``D`` traceless, ``|D| = r``, ``y = 2 r``).  Then
``exp(2 eps) = e^{2m} B`` with ``B = cosh(y) I + 2 sinh(y)/y D`` (det B = 1), and since
``ln(c A) = ln(c) I + ln(A)``::

    eps_tr = m I + 1/2 ln(B_tr),   B_tr = dF B dF^T,   det B_tr = J^2,  J = det dF.

With ``B_tr = mu I + E`` (``|E| = s``, ``x = s / mu``), ``1/2 ln(B_tr) = 1/2 ln(J) I +
atanh(x)/(2 x mu) E``.  So a step needs, per point, no exponential of the volumetric strain
and no eigenvectors, only

* ``cosh(y)`` and ``sinh(y) / y`` as functions of ``y^2 = 4 r^2`` (before the increment);
* ``ln(J) = 2 u atanh(u)/u``, ``u = (J - 1)/(J + 1)``, and ``atanh(x) / x`` as a function
  of ``x^2 = s^2 / mu^2`` (after it).

``J`` is the volume ratio of one step (|J - 1| ~ 1e-3) and ``y``, ``x`` are set by the elastic
shear strain (y ~ 2 |dev eps|: a few hundredths in a soil, bounded by its strength): each
function is its Taylor series (exact rational coefficients), evaluated by Horner's rule,
on a range that holds these many times over:

====================  =====================  =====  =================================
function              range                  terms  first omitted term (relative)
====================  =====================  =====  =================================
``cosh(y)``           ``y^2 <= 1/16``        7      (1/16)^7 / 14! = 4e-20
``sinh(y) / y``       ``y^2 <= 1/16``        7      (1/16)^7 / 15! = 3e-21
``atanh(x) / x``      ``x^2 <= 1/16``        14     (1/16)^14 / 29 = 5e-19
``ln(J)``             ``u^2 <= 1/16``        14     (0.6 <= J <= 5/3)
====================  =====================  =====  =================================

Against 50-digit values the series are within 0.5 ulp and ln(J) within 1.2 ulp; the trial
log strain agrees with the numpy reference (numpy's ``exp``, ``cosh``, ``log``, ``arctanh``
of ``b_tr``'s own invariants) to 5.3e-15 of its largest component
(``tests/test_hencky_series.py``).  A point outside the ranges is
computed with the scalar ``math`` functions (any input; NaN and inf pass through to the
run's guards).

**Why series in blocks.**  numba calls scalar libm for ``math.exp`` and friends (a few ns
each per point); numpy's SIMD ufuncs over all points would run between kernels, on one
thread, and split the stress update into three passes.
A branch-free polynomial loop over uint64 indices is vectorised by LLVM (AVX2 /
AVX-512): :func:`exp_block` and :func:`log_block` run over a block of :data:`.common.BLOCK`
points inside the one stress pass (:mod:`.stress`), on every thread, with the block's
scratch in L1.  The range check is a boolean OR over the block (vectorised too); a block
with a point outside the ranges recomputes that point with the ``math`` functions.

Blocks are aligned to multiples of :data:`.common.BLOCK` (128 points) from point 0 whatever
the thread count (:func:`.common.block_bounds`), so every point goes through the same code
on 1 or N threads and the result is bitwise the same.
"""
from __future__ import annotations

import math
from fractions import Fraction

from fem_rmpm.runtime.compiled import assume_columns, inline, kernel

__all__ = ["Y2_MAX", "Z_MAX", "exp_block", "log_block", "exp_parts", "log_parts",
           "cosh_series", "sinhc_series", "atanhc_series"]
Y2_MAX = 0.0625      # y^2 of cosh(y), sinh(y)/y by their series
Z_MAX = 0.0625       # x^2 of atanh(x)/x, and u^2 of ln(J), by the series


def _taylor(term, n: int) -> tuple:
    """The first ``n`` coefficients ``term(k)`` (exact fractions) rounded to float64."""
    return tuple(float(term(k)) for k in range(n))


_C = _taylor(lambda k: Fraction(1, math.factorial(2 * k)), 7)         # cosh(y) in y^2
_S = _taylor(lambda k: Fraction(1, math.factorial(2 * k + 1)), 7)     # sinh(y)/y in y^2
_A = _taylor(lambda k: Fraction(1, 2 * k + 1), 14)                    # atanh(x)/x in x^2


@inline
def cosh_series(y2):
    """cosh(y) from y^2 <= :data:`Y2_MAX` (7 Taylor terms)."""
    c = _C
    return c[0] + y2 * (c[1] + y2 * (c[2] + y2 * (c[3] + y2 * (c[4] + y2 * (
        c[5] + y2 * c[6])))))


@inline
def sinhc_series(y2):
    """sinh(y) / y from y^2 <= :data:`Y2_MAX` (7 Taylor terms)."""
    c = _S
    return c[0] + y2 * (c[1] + y2 * (c[2] + y2 * (c[3] + y2 * (c[4] + y2 * (
        c[5] + y2 * c[6])))))


@inline
def atanhc_series(z):
    """atanh(x) / x from z = x^2 <= :data:`Z_MAX` (14 Taylor terms)."""
    c = _A
    return c[0] + z * (c[1] + z * (c[2] + z * (c[3] + z * (c[4] + z * (c[5] + z * (
        c[6] + z * (c[7] + z * (c[8] + z * (c[9] + z * (c[10] + z * (c[11] + z * (
            c[12] + z * c[13]))))))))))))


@inline
def _y2(e0, e1, e3):
    """``y^2 = 4 r^2`` of the in-plane log strain (xx, yy, xy)."""
    d = 0.5 * (e0 - e1)
    return 4.0 * (d * d + e3 * e3)


@inline
def exp_parts(e0, e1, e3):
    """``(cosh(y), sinh(y) / y)`` of one log strain, any range (the series inside
    :data:`Y2_MAX`, else ``math.expm1``; NaN and inf propagate)."""
    y2 = _y2(e0, e1, e3)
    if y2 <= Y2_MAX:
        return cosh_series(y2), sinhc_series(y2)
    y = math.sqrt(y2)                 # > 1/4 (or NaN): no cancellation in the expm1 form
    em = math.expm1(y)
    ey = em + 1.0
    return 0.5 * (ey + 1.0 / ey), 0.5 * em * (em + 2.0) / (ey * y)


@inline
def log_parts(J, z):
    """``(ln(J), atanh(x) / x)`` with ``z = x^2``, any range (as :func:`exp_parts`)."""
    u = (J - 1.0) / (J + 1.0)
    u2 = u * u
    lj = 2.0 * u * atanhc_series(u2) if u2 <= Z_MAX else math.log(J)
    if z <= Z_MAX:
        return lj, atanhc_series(z)
    x = math.sqrt(z)
    return lj, math.atanh(x) / x


@kernel
def exp_block(ls, tb, tc, b, e):
    """Points ``b:e`` (uint64) into the block scratch (entry ``i - b``): ``tb, tc = cosh(y),
    sinh(y)/y`` of the log strains ``ls`` (n, 4).  Two vectorised loops (``y^2`` from the
    strided rows, then the series on the contiguous ``y^2``: about half the time of one
    loop); if a point of the block is outside :data:`Y2_MAX` (or
    not finite), the points outside are recomputed by :func:`exp_parts`."""
    assume_columns(ls, 4)
    n = e - b
    for j in range(n):
        i = b + j
        tc[j] = _y2(ls[i, 0], ls[i, 1], ls[i, 3])
    out = False
    for j in range(n):
        y2 = tc[j]
        tb[j] = cosh_series(y2)
        tc[j] = sinhc_series(y2)
        out |= not (y2 <= Y2_MAX)
    if out:
        for j in range(n):
            i = b + j
            if not (_y2(ls[i, 0], ls[i, 1], ls[i, 3]) <= Y2_MAX):
                tb[j], tc[j] = exp_parts(ls[i, 0], ls[i, 1], ls[i, 3])


@kernel
def log_block(W, ta, tb, tc, n):
    """The first ``n`` columns of the block scratch: from ``ta, tb, tc`` = J, mu, s^2 of B_tr
    (contiguous: one vectorised loop, its division by ``mu`` too) ``ta = ln(J)`` and
    ``tb = atanh(x) / (2 x mu)``, ``x^2 = s^2 / mu^2``.  The columns outside the series ranges
    are then recomputed by :func:`log_parts` from ``W[3]`` = J, ``W[0]`` = mu and
    ``tc`` (inactive points carry J = mu = 1, s = 0)."""
    out = False
    for j in range(n):
        J = ta[j]
        u = (J - 1.0) / (J + 1.0)
        u2 = u * u
        im = 1.0 / tb[j]
        z = tc[j] * im * im
        ta[j] = 2.0 * u * atanhc_series(u2)
        tb[j] = 0.5 * atanhc_series(z) * im
        out |= not ((u2 <= Z_MAX) & (z <= Z_MAX))
    if out:
        for j in range(n):
            J = W[3, j]
            u = (J - 1.0) / (J + 1.0)
            im = 1.0 / W[0, j]
            z = tc[j] * im * im
            if not ((u * u <= Z_MAX) & (z <= Z_MAX)):
                lj, at = log_parts(J, z)
                ta[j] = lj
                tb[j] = 0.5 * at * im
