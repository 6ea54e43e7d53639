"""Kinematics of the stress update (stage 3c, before the material model): velocity
gradient at the points, Hughes-Winget increment, F and volume, and the trial state of
the Hencky update, in passes over the points.

The transcendental functions of the Hencky update (exp, expm1 before, log, arctanh
after :func:`kinematics_pass`) are numpy's SIMD ufuncs over all points, between the
per-point passes: ~4 ns per point against ~35 ns for scalar libm calls inside the loop
(measured).  Formulas as :mod:`fem_rmpm.materials.hencky` (``exp_sym2``, ``log_sym2``,
``hughes_winget_increment``) in the same order.

With F-bar (:mod:`fem_rmpm.locking`) :func:`kinematics_pass` is replaced by two passes:
:func:`fbar_gradient_pass` (increments and per-cell sums of ``V`` and ``V dJ``, in point
order) and :func:`fbar_apply_pass` (the cell mean replaces each point's volume change,
then F, V and b_tr).
"""
from __future__ import annotations

import math

import numpy as np

from .basis import gimp, q4
from numba import get_num_threads, prange

from .common import inline, kernel, kernel_parallel

__all__ = ["exp_args_pass", "trial_pass", "kinematics_pass", "fbar_gradient_pass",
           "fbar_apply_pass", "log_sym2_from", "exp_args_pass_parallel",
           "kinematics_pass_parallel", "fbar_apply_pass_parallel", "exp_args_into"]


@inline
def _exp_args(e0, e1, e3):
    """Arguments of exp(2 E) (material.exp_sym2): 2 m and y = 2 sqrt(r2)."""
    m = 0.5 * (e0 + e1)
    d = 0.5 * (e0 - e1)
    return 2 * m, 2 * math.sqrt(d * d + e3 * e3)


@inline
def _exp_sym2_from(e0, e1, e3, e2m, em, y):
    """exp(2 E) (material.exp_sym2) from ``e2m = exp(2 m)``, ``em = expm1(y)`` and
    ``y = 2 sqrt(r2)``: cosh(y) = (e^y + e^-y) / 2 and sinh(y) / y =
    expm1(y) (expm1(y) + 2) / (2 e^y y), accurate for every y > 0 (no cancellation,
    so no series branch is needed; y = 0 gives 1)."""
    d = 0.5 * (e0 - e1)
    ey = em + 1.0
    iey = 1.0 / ey
    ch = 0.5 * (ey + iey)
    sy = 0.5 * em * (em + 2.0) * iey / y if y > 0 else 1.0
    g = 2 * e2m * sy
    c = e2m * ch
    return c + g * d, c - g * d, g * e3


@inline
def _log_args(axx, ayy, axy):
    """For 1/2 ln(A) (material.log_sym2): (1 / m, d, axy, x) with x = r / m, and the
    ufunc arguments ``m^2 - r^2`` (for log) and ``x`` (for arctanh)."""
    m = 0.5 * (axx + ayy)
    d = 0.5 * (axx - ayy)
    r2 = d * d + axy * axy
    im = 1.0 / m
    x = math.sqrt(r2) * im
    return im, d, axy, x, m * m - r2, x


@inline
def log_sym2_from(im, d, axy, x, log_det, atanh_x):
    """1/2 ln(A) from ``im = 1 / m``, ``log_det = ln(m^2 - r^2)`` and ``atanh_x =
    atanh(x)``, x = r / m (atanh(x) / x is accurate for every x > 0; x = 0 gives 1)."""
    ax = atanh_x / x if x > 0 else 1.0
    lp_lm = 0.25 * log_det
    g = 0.5 * ax * im
    return lp_lm + g * d, lp_lm - g * d, g * axy


@inline
def _trial_b(f00, f01, f10, f11, e0, e1, e3, e2m, em, y):
    """b_tr = dF exp(2 eps) dF^T from ``e2m = exp(2 m)``, ``em = expm1(y)`` of eps;
    returns the arguments of :func:`log_sym2_from` and of the log / arctanh ufuncs."""
    bxx, byy, bxy = _exp_sym2_from(e0, e1, e3, e2m, em, y)
    a00 = f00 * bxx + f01 * bxy                     # (dF B) dF^T, as the numpy matmul chain
    a01 = f00 * bxy + f01 * byy
    a10 = f10 * bxx + f11 * bxy
    a11 = f10 * bxy + f11 * byy
    c00 = a00 * f00 + a01 * f01
    c01 = a00 * f10 + a01 * f11
    c10 = a10 * f00 + a11 * f01
    c11 = a10 * f10 + a11 * f11
    return _log_args(c00, c11, 0.5 * (c01 + c10))


@inline
def _hughes_winget(L00, L01, L10, L11, dt):
    """dF = (I - L dt/2)^-1 (I + L dt/2), as material.hughes_winget_increment."""
    h2 = 0.5 * dt
    a00 = 1.0 + h2 * L00
    a01 = h2 * L01
    a10 = h2 * L10
    a11 = 1.0 + h2 * L11
    b00 = 1.0 - h2 * L00
    b01 = -(h2 * L01)
    b10 = -(h2 * L10)
    b11 = 1.0 - h2 * L11
    idet = 1.0 / (b00 * b11 - b01 * b10)
    i00 = b11 * idet
    i01 = -b01 * idet
    i10 = -b10 * idet
    i11 = b00 * idet
    return (i00 * a00 + i01 * a10, i00 * a01 + i01 * a11,
            i10 * a00 + i11 * a10, i10 * a01 + i11 * a11)


@inline
def _velocity_gradient(sh, vn):
    nodes, _, dx, dy = sh
    L00 = 0.0
    L01 = 0.0
    L10 = 0.0
    L11 = 0.0
    for k in range(len(nodes)):
        a = nodes[k]
        L00 += vn[a, 0] * dx[k]
        L01 += vn[a, 0] * dy[k]
        L10 += vn[a, 1] * dx[k]
        L11 += vn[a, 1] * dy[k]
    return L00, L01, L10, L11


@inline
def _q4_velocity_gradient(ll, s, t, M, vn):
    """:func:`_velocity_gradient` of the Q4 basis of cell ``ll`` at ``s, t``
    (:func:`.basis.q4_at`) with the gradients factored: d/dx = (1/h0) ((1 - t) (v_1 - v_0)
    + t (v_2 - v_3)), d/dy = (1/h1) ((1 - s) (v_3 - v_0) + s (v_2 - v_1)) (nodes
    counter-clockwise from the lower left).  The same sum regrouped (round-off); shorter
    chains than the four-term sums: kinematics pass 18.7-19.2 -> 18.0-18.5 ns per point
    (case (i) at t = 8 and 25 s, 4 interleaved pairs, load 1.2-1.3)."""
    a = np.uint64(ll)
    one = np.uint64(1)
    row = np.uint64(M.nx + 1)
    b, c, d = a + one, a + row + one, a + row
    fs = 1.0 - s
    ft = 1.0 - t
    ih0, ih1 = M.ih0, M.ih1
    L00 = ih0 * (ft * (vn[b, 0] - vn[a, 0]) + t * (vn[c, 0] - vn[d, 0]))
    L10 = ih0 * (ft * (vn[b, 1] - vn[a, 1]) + t * (vn[c, 1] - vn[d, 1]))
    L01 = ih1 * (fs * (vn[d, 0] - vn[a, 0]) + s * (vn[c, 0] - vn[b, 0]))
    L11 = ih1 * (fs * (vn[d, 1] - vn[a, 1]) + s * (vn[c, 1] - vn[b, 1]))
    return L00, L01, L10, L11


@inline
def _small_strain_trial(i, g00, g01, g10, g11, e0, e1, e2, e3, W):
    """Geostatic trial strain of point ``i``: eps + sym(grad du) into ``W``."""
    W[i, 0] = e0 + g00
    W[i, 1] = e1 + g11
    W[i, 2] = e2 + 0.0
    W[i, 3] = e3 + 0.5 * (g01 + g10)


@inline
def _apply_increment(i, f00, f01, f10, f11, e0, e1, e3, P, S):
    """Finite strain at point ``i``: F <- dF F, V <- det(dF) V, trial b_tr into W, ta, tb."""
    F, ta, tb = P.F, S.ta, S.tb
    a00, a01, a10, a11 = F[i, 0, 0], F[i, 0, 1], F[i, 1, 0], F[i, 1, 1]
    F[i, 0, 0] = f00 * a00 + f01 * a10
    F[i, 0, 1] = f00 * a01 + f01 * a11
    F[i, 1, 0] = f10 * a00 + f11 * a10
    F[i, 1, 1] = f10 * a01 + f11 * a11
    P.vol[i] = P.vol[i] * (f00 * f11 - f01 * f10)
    S.W[i, 0], S.W[i, 1], S.W[i, 2], S.W[i, 3], ta[i], tb[i] = _trial_b(
        f00, f01, f10, f11, e0, e1, e3, ta[i], tb[i], S.tc[i])


@inline
def _point_velocity_gradient(i, x, lp, M, vn, gimp_basis):
    """Velocity gradient at point ``i`` at ``x[i]`` from nodal velocities ``vn`` (Q4 or
    uGIMP basis)."""
    if gimp_basis:
        return _velocity_gradient(gimp(x[i, 0], x[i, 1], lp[i, 0], lp[i, 1], M), vn)
    return _velocity_gradient(q4(x[i, 0], x[i, 1], M), vn)


@inline
def exp_args_into(i, ls, S):
    """``S.ta[i]``, ``S.tb[i]`` = 2 m, y of the log strain ``ls[i]`` (for exp, expm1);
    ``S.tc[i]`` = y."""
    a, b = _exp_args(ls[i, 0], ls[i, 1], ls[i, 3])
    S.ta[i] = a
    S.tb[i] = b
    S.tc[i] = b


@inline
def _exp_args_points(P, S, start, stop):
    """Pass 0 over points ``start:stop``: ``ta``, ``tb`` = 2 m, y of the current log
    strains (for exp, expm1); tc = y.  The step computes them in
    :func:`fem_rmpm.kernels.transfer.g2p` instead (the same values for the active points);
    this pass is the stage alone (benchmark, tests)."""
    ls, ta, tb = P.log_strain, S.ta, S.tb
    for i in range(np.uint64(start), np.uint64(stop)):
        if P.active[i]:
            exp_args_into(i, ls, S)
        else:
            ta[i] = 0.0
            tb[i] = 0.0
            S.tc[i] = 0.0


@kernel
def trial_pass(dF, log_strain, active, ta, tb, tc, W):
    """b_tr for given increments ``dF`` (n, 4) (the material-only path of
    :func:`fem_rmpm.kernels.stress.stress_update_points`)."""
    for i in range(dF.shape[0]):
        if not active[i]:
            ta[i] = 1.0
            tb[i] = 0.0
            continue
        W[i, 0], W[i, 1], W[i, 2], W[i, 3], ta[i], tb[i] = _trial_b(
            dF[i, 0], dF[i, 1], dF[i, 2], dF[i, 3], log_strain[i, 0], log_strain[i, 1],
            log_strain[i, 3], ta[i], tb[i], tc[i])


@inline
def _kinematics_points(P, M, N, S, o, start, stop):
    """Pass 1 over points ``start:stop``: velocity gradient at the positions before the
    move.  Geostatic: ``W[i]`` = the small-strain trial strain.  Finite strain:
    Hughes-Winget increment dF, F <- dF F, V <- det(dF) V, and b_tr from ``ta``, ``tb`` =
    exp(2 m), expm1(y) of the current log strain (``W``, ``ta``, ``tb`` then hold the log /
    arctanh arguments)."""
    dt, ls, vn = o.dt, P.log_strain, N.v_remap
    for i in range(np.uint64(start), np.uint64(stop)):
        if not P.active[i]:
            S.ta[i] = 1.0
            S.tb[i] = 0.0
            continue
        if o.gimp:
            L00, L01, L10, L11 = _point_velocity_gradient(i, S.x_old, P.half_width, M, vn, True)
        else:                        # the Q4 cell of the map to nodes (at x_old)
            L00, L01, L10, L11 = _q4_velocity_gradient(S.q4_ll[i], S.q4_st[i, 0],
                                                       S.q4_st[i, 1], M, vn)
        e0, e1, e2, e3 = ls[i, 0], ls[i, 1], ls[i, 2], ls[i, 3]
        if o.geostatic:
            _small_strain_trial(i, L00 * dt, L01 * dt, L10 * dt, L11 * dt, e0, e1, e2, e3, S.W)
            continue
        f00, f01, f10, f11 = _hughes_winget(L00, L01, L10, L11, dt)
        _apply_increment(i, f00, f01, f10, f11, e0, e1, e3, P, S)


@kernel
def fbar_gradient_pass(P, M, N, S, o):
    """F-bar pass 1 (:mod:`fem_rmpm.locking`): per point the host cell at ``x_old`` and the
    increment ``D`` (n, 4) — finite strain: the Hughes-Winget dF; geostatic: grad(du) =
    L dt — and per cell the sums of ``V`` and ``V dJ`` (geostatic: ``V tr grad(du)``),
    in point order as ``np.bincount``.  ``vol`` is read, not changed."""
    x_old, host, D, cv, cvj, vol, dt = S.x_old, S.host, S.D, S.cell_v, S.cell_vdj, P.vol, o.dt
    for i in range(x_old.shape[0]):
        if not P.active[i]:
            continue
        ci = min(max(int(math.floor((x_old[i, 0] - M.o0) * M.ih0)), 0), M.nx - 1)
        cj = min(max(int(math.floor((x_old[i, 1] - M.o1) * M.ih1)), 0), M.ny - 1)
        c = cj * M.nx + ci
        host[i] = c
        cv[c] = 0.0
        cvj[c] = 0.0
    for i in range(x_old.shape[0]):
        if not P.active[i]:
            continue
        L00, L01, L10, L11 = _point_velocity_gradient(i, x_old, P.half_width, M, N.v_remap,
                                                      o.gimp)
        if o.geostatic:
            g00, g01, g10, g11 = L00 * dt, L01 * dt, L10 * dt, L11 * dt
            j = g00 + g11
        else:
            g00, g01, g10, g11 = _hughes_winget(L00, L01, L10, L11, dt)
            j = g00 * g11 - g01 * g10
        D[i, 0] = g00
        D[i, 1] = g01
        D[i, 2] = g10
        D[i, 3] = g11
        c = host[i]
        cv[c] += vol[i]
        cvj[c] += vol[i] * j


@inline
def _fbar_apply_points(P, S, o, start, stop):
    """F-bar pass 2 over points ``start:stop``: the cell mean replaces each point's volume
    change.  Finite strain: dF_bar = (dJ_bar / dJ)^(1/2) dF, then F, V and b_tr as
    :func:`kinematics_pass`; geostatic (B-bar): grad(du) + 1/2 (mean tr - tr) I, the trial
    strain into ``W``."""
    ls, D = P.log_strain, S.D
    for i in range(np.uint64(start), np.uint64(stop)):
        if not P.active[i]:
            S.ta[i] = 1.0
            S.tb[i] = 0.0
            continue
        c = S.host[i]
        mean = S.cell_vdj[c] / S.cell_v[c]
        g00, g01, g10, g11 = D[i, 0], D[i, 1], D[i, 2], D[i, 3]
        e0, e1, e2, e3 = ls[i, 0], ls[i, 1], ls[i, 2], ls[i, 3]
        if o.geostatic:
            corr = 0.5 * (mean - (g00 + g11))
            _small_strain_trial(i, g00 + corr, g01, g10, g11 + corr, e0, e1, e2, e3, S.W)
            continue
        sc = math.sqrt(mean / (g00 * g11 - g01 * g10))
        f00, f01, f10, f11 = sc * g00, sc * g01, sc * g10, sc * g11
        _apply_increment(i, f00, f01, f10, f11, e0, e1, e3, P, S)


# --------------------------------------------------------------------- serial and threaded passes
# Each pass: a serial kernel over all points (the loop starts at the constant 0: LLVM then
# drops the negative-index checks), a compiled chunk ``start:stop`` and a threaded driver
# calling that chunk from a ``prange`` loop (numba's parfor analysis crashed on these loop
# bodies written inline in the ``prange`` loop).  Every point is computed with the same
# arithmetic in all three, so any thread count gives bitwise the serial result.
@kernel
def exp_args_pass(P, S):
    _exp_args_points(P, S, 0, P.log_strain.shape[0])


@kernel
def _exp_args_chunk(P, S, start, stop):
    _exp_args_points(P, S, start, stop)


@kernel_parallel
def exp_args_pass_parallel(P, S):
    n, nch = P.log_strain.shape[0], max(1, min(get_num_threads(), 64))
    for c in prange(nch):
        _exp_args_chunk(P, S, c * n // nch, (c + 1) * n // nch)


@kernel
def kinematics_pass(P, M, N, S, o):
    _kinematics_points(P, M, N, S, o, 0, P.log_strain.shape[0])


@kernel
def _kinematics_chunk(P, M, N, S, o, start, stop):
    _kinematics_points(P, M, N, S, o, start, stop)


@kernel_parallel
def kinematics_pass_parallel(P, M, N, S, o):
    n, nch = P.log_strain.shape[0], max(1, min(o.threads, 64))
    for c in prange(nch):
        _kinematics_chunk(P, M, N, S, o, c * n // nch, (c + 1) * n // nch)


@kernel
def fbar_apply_pass(P, S, o):
    _fbar_apply_points(P, S, o, 0, S.D.shape[0])


@kernel
def _fbar_apply_chunk(P, S, o, start, stop):
    _fbar_apply_points(P, S, o, start, stop)


@kernel_parallel
def fbar_apply_pass_parallel(P, S, o):
    n, nch = S.D.shape[0], max(1, min(o.threads, 64))
    for c in prange(nch):
        _fbar_apply_chunk(P, S, o, c * n // nch, (c + 1) * n // nch)
