"""Compiled per-point loops of the finite-strain consistent tangent (numba).

The tangent of the Hencky update splits into the kinematics every model shares (the
trial log strain ``eps_tr = 1/2 ln(b_tr)``, ``b_tr = dF b_e dF^T``, and its derivative
along the three symmetric directions of a perturbation ``dF -> (I + E) dF``) and the
model's stiffness ``D = d tau / d eps_tr`` (its ``tangent`` hook, or the complex step of
its ``update``).  :func:`trial_jacobian` does the first part for all points in one loop
(the analytic derivative of the 2x2 matrix logarithm, smooth through repeated
eigenvalues);
:func:`spatial_tangent` joins ``D``, the Jacobian, the spin and the geometric term into
``A_ijlm`` (see :func:`fem_rmpm.schemes.implicit.tangent.finite_strain_tangent`).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["trial_jacobian", "spatial_tangent", "assemble_spatial_lower"]

_SERIES = 1e-3     # atanh(x)/x and its derivative by their series below this x^2


@njit(inline="always")
def _phi(y):
    """``atanh(sqrt(y)) / sqrt(y)`` and its derivative in ``y`` (0 <= y < 1)."""
    if y < _SERIES:
        f, df, yk = 1.0, 0.0, 1.0
        for k in range(1, 7):              # sum y^k / (2k + 1); truncation < 1e-19
            df += k * yk / (2 * k + 1)
            yk *= y
            f += yk / (2 * k + 1)
        return f, df
    x = math.sqrt(y)
    f = math.atanh(x) / x
    return f, (1 / (1 - y) - f) / (2 * y)


@njit(cache=True, error_model="numpy")
def trial_jacobian(dF, B, eps, J):
    """Per point: ``eps[p]`` (4,) the trial log strain ``[xx, yy, zz, xy]`` (``zz`` left
    as given: plane strain) and ``J[p, c, k] = d eps_c / d E_k`` (3, 3) for ``c`` in
    ``(xx, yy, xy)`` and the directions ``E_0 = e_x e_x``, ``E_1 = e_y e_y``,
    ``E_2 = (e_x e_y + e_y e_x) / 2`` of ``dF -> (I + E) dF``, which perturb
    ``b_tr -> b_tr + E b_tr + b_tr E``.  ``dF``, ``B`` (n, 2, 2); ``eps`` (n, 4) holds
    ``eps_zz`` on entry.

    ``1/2 ln(b) = lp I + g D`` with ``b = m I + D`` (``D`` traceless, ``r^2 = -det D``),
    ``lp = ln(m^2 - r^2) / 4`` and ``g = phi(r^2 / m^2) / (2 m)``,
    ``phi(y) = atanh(sqrt y) / sqrt y`` (as :func:`fem_rmpm.materials.log_sym2`, smooth
    through repeated eigenvalues); the derivative is that of these scalar functions."""
    for p in range(dF.shape[0]):
        f00, f01, f10, f11 = dF[p, 0, 0], dF[p, 0, 1], dF[p, 1, 0], dF[p, 1, 1]
        b00, b01, b11 = B[p, 0, 0], 0.5 * (B[p, 0, 1] + B[p, 1, 0]), B[p, 1, 1]
        # b_tr = dF B dF^T (symmetric)
        c00, c01 = f00 * b00 + f01 * b01, f00 * b01 + f01 * b11
        c10, c11 = f10 * b00 + f11 * b01, f10 * b01 + f11 * b11
        t00 = c00 * f00 + c01 * f01
        t11 = c10 * f10 + c11 * f11
        t01 = 0.5 * (c00 * f10 + c01 * f11 + c10 * f00 + c11 * f01)
        m, d = 0.5 * (t00 + t11), 0.5 * (t00 - t11)
        r2 = d * d + t01 * t01
        det = m * m - r2
        y = r2 / (m * m)
        ph, dph = _phi(y)
        lp, g = 0.25 * math.log(det), 0.5 * ph / m
        eps[p, 0], eps[p, 1], eps[p, 3] = lp + g * d, lp - g * d, g * t01
        for k in range(3):
            if k == 0:                      # perturbation of (b00, b11, b01)
                x00, x11, x01 = 2 * t00, 0.0, t01
            elif k == 1:
                x00, x11, x01 = 0.0, 2 * t11, t01
            else:
                x00, x11, x01 = t01, t01, 0.5 * (t00 + t11)
            dm, dd = 0.5 * (x00 + x11), 0.5 * (x00 - x11)
            dr2 = 2 * (d * dd + t01 * x01)
            dlp = 0.25 * (2 * m * dm - dr2) / det
            dy = dr2 / (m * m) - 2 * r2 * dm / (m * m * m)
            dg = 0.5 * (dph * dy / m - ph * dm / (m * m))
            J[p, 0, k] = dlp + dg * d + g * dd
            J[p, 1, k] = dlp - dg * d - g * dd
            J[p, 2, k] = dg * t01 + g * x01
    return eps, J


@njit(inline="always")
def _point_tangent(D, c0, c1, c2, J, tau, p, d, A):
    """``A (2, 2, 2, 2)`` of point ``p`` as :func:`spatial_tangent` describes it, from
    the columns ``c0, c1, c2`` (trial ``xx, yy, xy``) of ``D[p]``; ``d`` (3, 3) scratch."""
    t00, t11, t01 = tau[p, 0], tau[p, 1], tau[p, 3]
    for k in range(3):
        for r, c in ((0, 0), (1, 1), (2, 3)):
            d[k, r] = (D[p, c, c0] * J[p, 0, k] + D[p, c, c1] * J[p, 1, k]
                       + D[p, c, c2] * J[p, 2, k])
    w00, w11, w01 = t01, -t01, 0.5 * (t11 - t00)     # W tau - tau W
    for lm in range(4):
        l, m = lm // 2, lm % 2
        if lm == 0:
            a00, a11, a01, a10 = d[0, 0], d[0, 1], d[0, 2], d[0, 2]
        elif lm == 3:
            a00, a11, a01, a10 = d[1, 0], d[1, 1], d[1, 2], d[1, 2]
        elif lm == 1:
            a00, a11, a01, a10 = d[2, 0] + w00, d[2, 1] + w11, d[2, 2] + w01, d[2, 2] + w01
        else:
            a00, a11, a01, a10 = d[2, 0] - w00, d[2, 1] - w11, d[2, 2] - w01, d[2, 2] - w01
        A[0, 0, l, m], A[1, 1, l, m] = a00, a11
        A[0, 1, l, m], A[1, 0, l, m] = a01, a10
    # geometric term: - delta_jl tau_im
    for i in range(2):
        for m in range(2):
            tim = (t00 if m == 0 else t01) if i == 0 else (t01 if m == 0 else t11)
            A[i, 0, 0, m] -= tim
            A[i, 1, 1, m] -= tim


@njit(cache=True, error_model="numpy")
def spatial_tangent(D, J, tau, A):
    """``A[p] (2, 2, 2, 2)``: ``A_ijlm = d tau_ij / d(grad_x du)_lm - delta_jl tau_im``
    from the model stiffness ``D[p] = d tau / d eps_tr`` (4, 3; columns ``xx, yy, xy``),
    the trial Jacobian ``J[p]`` (3, 3) of :func:`trial_jacobian` and the Kirchhoff stress
    ``tau[p]`` (4,).  A symmetric direction ``E_k`` gives ``d tau = D J_k``; the spin
    ``W = (e_x e_y - e_y e_x) / 2`` rotates the stress of this isotropic law,
    ``d tau = W tau - tau W``."""
    d = np.empty((3, 3))                # d[k] = (d tau_xx, d tau_yy, d tau_xy) along E_k
    for p in range(D.shape[0]):
        _point_tangent(D, 0, 1, 2, J, tau, p, d, A[p])
    return A


@njit(cache=True, error_model="numpy")
def assemble_spatial_lower(D, cols, J, tau, f, g, V0, group, positions, data):
    """The tangent of the finite-strain step in one pass over the points, straight into
    the data of its lower triangle: per point ``A`` as :func:`spatial_tangent` (from the
    model stiffness ``D[p]`` (4, nc), whose columns ``cols`` are the trial components
    ``xx, yy, xy``, the trial Jacobian ``J[p]`` and the Kirchhoff stress ``tau[p]``) times
    the stiffness factor ``f``, then the block ``Ke[a, i, l, b] = V0_p g_aj A_ijlm g_bm``
    added at ``data[positions[group[p], e]]`` for the entries with a position (``-1``:
    an entry of the upper triangle or of a prescribed DOF, skipped, not computed).  The
    same arithmetic, in the same order, as :func:`spatial_tangent` followed by
    :func:`fem_rmpm.schemes.implicit.point_kernels.assemble_tangent`, so the entries
    equal that matrix's to the last bit.

    Returns ``(asym, amax)``: the largest ``|A_ijlm - A_lmij|`` over the points and the
    largest ``|A_ijlm|`` (kPa).  ``K_ai,bl = g_aj A_ijlm g_bm`` summed over points is
    symmetric when every ``A`` has that major symmetry, so ``asym <= rtol amax`` says the
    lower triangle is the whole matrix to ``rtol`` (the check of
    :meth:`fem_rmpm.schemes.implicit.linear.LinearSolver.solve`)."""
    n, k = g.shape[0], g.shape[1]
    A = np.empty((2, 2, 2, 2))
    d = np.empty((3, 3))
    gA = np.empty((k, 2, 2, 2))
    c0_, c1_, c2_ = cols[0], cols[1], cols[2]
    asym = 0.0
    amax = 0.0
    for p in range(n):
        _point_tangent(D, c0_, c1_, c2_, J, tau, p, d, A)
        if f != 1.0:
            for i in range(2):
                for j in range(2):
                    for l in range(2):
                        for m in range(2):
                            A[i, j, l, m] = f * A[i, j, l, m]
        for i in range(2):
            for j in range(2):
                for l in range(2):
                    for m in range(2):
                        a = abs(A[i, j, l, m])
                        if a > amax:
                            amax = a
                        a = abs(A[i, j, l, m] - A[l, m, i, j])
                        if a > asym:
                            asym = a
        v = V0[p]
        for a in range(k):
            g0, g1 = v * g[p, a, 0], v * g[p, a, 1]
            for i in range(2):
                for l in range(2):
                    for m in range(2):
                        gA[a, i, l, m] = g0 * A[i, 0, l, m] + g1 * A[i, 1, l, m]
        row = positions[group[p]]
        e = 0
        for a in range(k):
            for i in range(2):
                for l in range(2):
                    c0, c1 = gA[a, i, l, 0], gA[a, i, l, 1]
                    for b in range(k):
                        q = row[e]
                        e += 1
                        if q >= 0:
                            data[q] += c0 * g[p, b, 0] + c1 * g[p, b, 1]
    return asym, amax
