"""Compiled (numba) kernels of the explicit MUSL step: the fast path of :mod:`.explicit`.

The step of :func:`fem_rmpm.explicit.explicit_step_numpy` (the readable numpy
reference) in five serial single-thread loops, each a kernel of its own so that
it can be timed alone (``validation/bench_explicit.py``):

1. :func:`p2g` — per point: locate the host cell (arithmetic on the structured
   grid), Q4 or uGIMP shape values and gradients, scatter mass, momentum and
   force to the nodes.  The nodes it touches are listed: every later nodal loop
   visits those *active* nodes only, and the next step clears only them (no
   work on the empty part of the grid).
2. :func:`nodal_solve` — per active node: lumped-mass momentum balance, local
   (Cundall) damping, fixed components, grid kinetic energy.
3. :func:`g2p` — per point: FLIP/PIC velocity, position (or the geostatic
   displacement), and the MUSL re-map of the new point momenta to the nodes;
   :func:`nodal_velocity` — per active node: the re-mapped velocities;
   :func:`update_stress` — per point, in passes: velocity gradient,
   Hughes-Winget increment, F, volume and the trial left Cauchy-Green tensor
   (:func:`_kinematics_pass`), then the Hencky/von Mises return mapping (linear
   or exponential softening), Cauchy stress and the quantities the time loop
   needs next (largest P-wave speed and point speed for the CFL step,
   non-finite and out-of-grid points) (:func:`_finish_pass`).  The
   transcendental functions of the Hencky update (exp, expm1 before, log,
   arctanh after the kinematics pass) are numpy's SIMD ufuncs over all points:
   ~4 ns per point against ~35 ns for scalar libm calls inside the loop.

With F-bar (``update_stress(..., fbar=True)``) the kinematics pass is replaced by two:
:func:`_fbar_gradient_pass` (increments and per-cell sums of ``V`` and ``V dJ``, in
point order) and :func:`_fbar_apply_pass` (the cell mean replaces each point's volume
change, then F, V and b_tr).

Every formula is the one of the numpy path, in the same order where it matters
(the scatter sums points in the same order as ``np.bincount``), so the two
agree to round-off (``tests/test_kernels.py``: 1e-12 relative over several
steps, measured ~1e-14).  ``cache=True`` keeps the compiled code on disk (the
first call in a fresh environment compiles for 11-25 s on the shared 2-core
machine, then 0.4-0.7 s to load; ``validation/bench_explicit.py`` measures it);
no threads: a Monte Carlo campaign parallelises over realizations.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from .materials import registry
from .materials.dispatch import point_dispatch

__all__ = ["p2g", "nodal_solve", "g2p", "nodal_velocity", "update_stress",
           "q4_shape", "gimp_shape", "stress_update_points", "small_strain_update_points"]

_MASS_TOL = 1e-14     # as explicit._MASS_TOL
_SMALL = 1e-6         # as material._SMALL: series below this |x^2|
_jit = njit(cache=True, fastmath=False, nogil=True, error_model="numpy")
# The step kernels allocate nothing, so they run without numba's reference counting
# (NRT): with it, every array handed to an inlined per-point helper is incref'd and
# decref'd (atomic operations) once per point, which made G2P ~4x slower (56 vs 13
# ns per point, measured).  A kernel that allocated would fail to compile, not misbehave.
_kernel = njit(cache=True, fastmath=False, nogil=True, error_model="numpy", _nrt=False)
_inline = njit(inline="always", fastmath=False, error_model="numpy")


# --------------------------------------------------------------------- shape functions
@_inline
def _q4(x0, x1, o0, o1, h0, h1, ih0, ih1, nx, ny):
    """Bilinear Q4 basis at one point as tuples (nodes, N, dN/dx, dN/dy), 4 each.

    Same arithmetic as :func:`fem_rmpm.grid.locate` + :func:`fem_rmpm.shape.q4_values`
    (local coordinates in [0, 1], cell clipped into the grid, nodes counter-clockwise
    from the lower left), except that ``ih = 1 / h`` is multiplied, not divided by
    (a point within one rounding of a cell edge may so be placed in the neighbour
    cell: Q4 is continuous there, only its gradient jumps)."""
    s0 = (x0 - o0) * ih0
    s1 = (x1 - o1) * ih1
    i = min(max(int(math.floor(s0)), 0), nx - 1)
    j = min(max(int(math.floor(s1)), 0), ny - 1)
    s = s0 - i
    t = s1 - j
    ll = j * (nx + 1) + i
    fs = 1.0 - s
    ft = 1.0 - t
    return ((ll, ll + 1, ll + nx + 2, ll + nx + 1),
            (fs * ft, s * ft, s * t, fs * t),
            (-ft * ih0, ft * ih0, t * ih0, -t * ih0),
            (-fs * ih1, -s * ih1, s * ih1, fs * ih1))


@_inline
def _gimp_1d(d, h, lp):
    """uGIMP weight and derivative (Bardenhagen & Kober 2004), as shape._gimp_1d."""
    a = abs(d)
    sg = 1.0 if d > 0 else (-1.0 if d < 0 else 0.0)
    if a < lp:
        return 1.0 - (d * d + lp * lp) / (2 * h * lp), -d / (h * lp)
    if a <= h - lp:
        return 1.0 - a / h, -sg / h
    if a < h + lp:
        r = h + lp - a
        return r * r / (4 * h * lp), -sg * r / (2 * h * lp)
    return 0.0, 0.0


@_inline
def _gimp(x0, x1, lp0, lp1, o0, o1, h0, h1, ih0, ih1, nx, ny):
    """uGIMP basis at one point: the 3 x 3 nodes around it as tuples of 9, as
    :func:`fem_rmpm.shape.gimp_at_points` (y-major, nodes beyond the edge clipped onto it)."""
    s0 = (x0 - o0) * ih0
    s1 = (x1 - o1) * ih1
    i = min(max(int(math.floor(s0)), 0), nx - 1)
    j = min(max(int(math.floor(s1)), 0), ny - 1)
    fi = i - 1 if s0 - i < 0.5 else i
    fj = j - 1 if s1 - j < 0.5 else j
    X0 = _gimp_1d(x0 - (o0 + fi * h0), h0, lp0)
    X1 = _gimp_1d(x0 - (o0 + (fi + 1) * h0), h0, lp0)
    X2 = _gimp_1d(x0 - (o0 + (fi + 2) * h0), h0, lp0)
    Y0 = _gimp_1d(x1 - (o1 + fj * h1), h1, lp1)
    Y1 = _gimp_1d(x1 - (o1 + (fj + 1) * h1), h1, lp1)
    Y2 = _gimp_1d(x1 - (o1 + (fj + 2) * h1), h1, lp1)
    c0 = min(max(fi, 0), nx)
    c1 = min(max(fi + 1, 0), nx)
    c2 = min(max(fi + 2, 0), nx)
    r0 = min(max(fj, 0), ny) * (nx + 1)
    r1 = min(max(fj + 1, 0), ny) * (nx + 1)
    r2 = min(max(fj + 2, 0), ny) * (nx + 1)
    nodes = (r0 + c0, r0 + c1, r0 + c2, r1 + c0, r1 + c1, r1 + c2, r2 + c0, r2 + c1, r2 + c2)
    N = (X0[0] * Y0[0], X1[0] * Y0[0], X2[0] * Y0[0], X0[0] * Y1[0], X1[0] * Y1[0],
         X2[0] * Y1[0], X0[0] * Y2[0], X1[0] * Y2[0], X2[0] * Y2[0])
    dx = (X0[1] * Y0[0], X1[1] * Y0[0], X2[1] * Y0[0], X0[1] * Y1[0], X1[1] * Y1[0],
          X2[1] * Y1[0], X0[1] * Y2[0], X1[1] * Y2[0], X2[1] * Y2[0])
    dy = (X0[0] * Y0[1], X1[0] * Y0[1], X2[0] * Y0[1], X0[0] * Y1[1], X1[0] * Y1[1],
          X2[0] * Y1[1], X0[0] * Y2[1], X1[0] * Y2[1], X2[0] * Y2[1])
    return nodes, N, dx, dy


@_jit
def q4_shape(x, org, h, nx, ny):
    """Q4 basis at points ``x`` (n, 2): nodes (n, 4), values (n, 4), gradients (n, 4, 2)."""
    o0, o1, h0, h1 = org[0], org[1], h[0], h[1]
    ih0, ih1 = 1.0 / h0, 1.0 / h1
    n = x.shape[0]
    nodes = np.empty((n, 4), np.int64)
    N = np.empty((n, 4))
    dN = np.empty((n, 4, 2))
    for i in range(n):
        a, b, c, d = _q4(x[i, 0], x[i, 1], o0, o1, h0, h1, ih0, ih1, nx, ny)
        for k in range(4):
            nodes[i, k], N[i, k], dN[i, k, 0], dN[i, k, 1] = a[k], b[k], c[k], d[k]
    return nodes, N, dN


@_jit
def gimp_shape(x, lp, org, h, nx, ny):
    """uGIMP basis at points ``x`` (n, 2): nodes (n, 9), values (n, 9), gradients (n, 9, 2)."""
    o0, o1, h0, h1 = org[0], org[1], h[0], h[1]
    ih0, ih1 = 1.0 / h0, 1.0 / h1
    n = x.shape[0]
    nodes = np.empty((n, 9), np.int64)
    N = np.empty((n, 9))
    dN = np.empty((n, 9, 2))
    for i in range(n):
        a, b, c, d = _gimp(x[i, 0], x[i, 1], lp[i, 0], lp[i, 1], o0, o1, h0, h1, ih0, ih1,
                           nx, ny)
        for k in range(9):
            nodes[i, k], N[i, k], dN[i, k, 0], dN[i, k, 1] = a[k], b[k], c[k], d[k]
    return nodes, N, dN


# --------------------------------------------------------------------- 1. map to nodes
@_inline
def _clear(touched, nt, m, p, f, flag):
    for k in range(nt):
        a = touched[k]
        m[a] = 0.0
        p[a, 0] = 0.0
        p[a, 1] = 0.0
        f[a, 0] = 0.0
        f[a, 1] = 0.0
        flag[a] = 0


@_inline
def _scatter(sh, i, x, v, mass, vol, stress, gx, gy, m, p, f, flag, touched, nt):
    nodes, N, dx, dy = sh
    mp = mass[i]
    mv0 = mp * v[i, 0]
    mv1 = mp * v[i, 1]
    sx = stress[i, 0] * vol[i]
    sy = stress[i, 1] * vol[i]
    sxy = stress[i, 3] * vol[i]
    mg0 = mp * gx
    mg1 = mp * gy
    for k in range(len(nodes)):
        a = nodes[k]
        if flag[a] == 0:
            flag[a] = 1
            touched[nt] = a
            nt += 1
        w = N[k]
        m[a] += w * mp
        p[a, 0] += w * mv0
        p[a, 1] += w * mv1
        f[a, 0] += -(sx * dx[k] + sxy * dy[k]) + w * mg0
        f[a, 1] += -(sxy * dx[k] + sy * dy[k]) + w * mg1
    return nt


@_kernel
def p2g(x, v, mass, vol, stress, active, gx, gy, gimp, lp, org, h, nx, ny,
        m, p, f, flag, touched, n_touched):
    """Stage 1: nodal mass ``m``, momentum ``p`` and force ``f`` (gravity + stress
    divergence) from the active points; the touched nodes are listed in
    ``touched[:n_touched[0]]`` (flag 1).  The nodes of the previous step are cleared first."""
    o0, o1, h0, h1 = org[0], org[1], h[0], h[1]
    ih0, ih1 = 1.0 / h0, 1.0 / h1
    _clear(touched, n_touched[0], m, p, f, flag)
    nt = 0
    for i in range(x.shape[0]):
        if not active[i]:
            continue
        if gimp:
            sg = _gimp(x[i, 0], x[i, 1], lp[i, 0], lp[i, 1], o0, o1, h0, h1, ih0, ih1, nx, ny)
            nt = _scatter(sg, i, x, v, mass, vol, stress, gx, gy, m, p, f, flag, touched, nt)
        else:
            sq = _q4(x[i, 0], x[i, 1], o0, o1, h0, h1, ih0, ih1, nx, ny)
            nt = _scatter(sq, i, x, v, mass, vol, stress, gx, gy, m, p, f, flag, touched, nt)
    n_touched[0] = nt


# --------------------------------------------------------------------- 2. solve on the mesh
@_kernel
def nodal_solve(m, p, f, fixed, dt, damping, touched, n_touched, v_new, acc):
    """Stage 2 on the active nodes: ``v_new`` and ``acc`` (lumped mass, Cundall damping
    ``f - damping |f| sign(v)``, fixed components zero).  Returns the grid kinetic energy."""
    ke = 0.0
    for k in range(n_touched[0]):
        a = touched[k]
        has = m[a] > _MASS_TOL
        inv_m = 1.0 / m[a] if has else 0.0
        for c in range(2):
            vo = p[a, c] * inv_m
            fc = f[a, c]
            if damping > 0:
                sg = 1.0 if vo > 0 else (-1.0 if vo < 0 else 0.0)
                fc = fc - damping * abs(fc) * sg
            if fixed[a, c]:
                fc = 0.0
                vo = 0.0
            ac = fc * inv_m
            acc[a, c] = ac
            v_new[a, c] = vo + ac * dt
        ke += m[a] * (v_new[a, 0] * v_new[a, 0] + v_new[a, 1] * v_new[a, 1])
    return 0.5 * ke


# --------------------------------------------------------------------- 3. update the points
@_inline
def _g2p_point(sh, i, x, v, mass, dt, flip, geostatic, u_geo, v_new, acc, p2, x_old):
    nodes, N, _, _ = sh
    vp0 = 0.0
    vp1 = 0.0
    ap0 = 0.0
    ap1 = 0.0
    for k in range(len(nodes)):
        a = nodes[k]
        vp0 += N[k] * v_new[a, 0]
        vp1 += N[k] * v_new[a, 1]
        ap0 += N[k] * acc[a, 0]
        ap1 += N[k] * acc[a, 1]
    v0 = flip * (v[i, 0] + dt * ap0) + (1.0 - flip) * vp0
    v1 = flip * (v[i, 1] + dt * ap1) + (1.0 - flip) * vp1
    v[i, 0] = v0
    v[i, 1] = v1
    x0 = x[i, 0]
    x1 = x[i, 1]
    x_old[i, 0] = x0
    x_old[i, 1] = x1
    if geostatic:
        u_geo[i, 0] += dt * vp0
        u_geo[i, 1] += dt * vp1
    else:
        x[i, 0] = x0 + dt * vp0
        x[i, 1] = x1 + dt * vp1
    mp = mass[i]
    mv0 = mp * v0
    mv1 = mp * v1
    for k in range(len(nodes)):
        a = nodes[k]
        p2[a, 0] += N[k] * mv0
        p2[a, 1] += N[k] * mv1
    return vp0 * vp0 + vp1 * vp1


@_kernel
def g2p(x, v, mass, active, dt, flip, geostatic, u_geo, gimp, lp, org, h, nx, ny,
        v_new, acc, touched, n_touched, p2, x_old):
    """Stage 3a: FLIP/PIC point velocities, positions (geostatic: ``u_geo`` instead),
    and the MUSL re-map of the new point momenta into ``p2`` (active nodes).  The
    positions before the move are kept in ``x_old`` for the stress update.
    Returns the largest |v_pic| (the motion as the grid sees it)."""
    o0, o1, h0, h1 = org[0], org[1], h[0], h[1]
    ih0, ih1 = 1.0 / h0, 1.0 / h1
    for k in range(n_touched[0]):
        a = touched[k]
        p2[a, 0] = 0.0
        p2[a, 1] = 0.0
    vmax2 = 0.0
    for i in range(x.shape[0]):
        if not active[i]:
            continue
        if gimp:
            sg = _gimp(x[i, 0], x[i, 1], lp[i, 0], lp[i, 1], o0, o1, h0, h1, ih0, ih1, nx, ny)
            s2 = _g2p_point(sg, i, x, v, mass, dt, flip, geostatic, u_geo, v_new, acc, p2, x_old)
        else:
            sq = _q4(x[i, 0], x[i, 1], o0, o1, h0, h1, ih0, ih1, nx, ny)
            s2 = _g2p_point(sq, i, x, v, mass, dt, flip, geostatic, u_geo, v_new, acc, p2, x_old)
        vmax2 = max(vmax2, s2)
    return math.sqrt(vmax2)


@_kernel
def nodal_velocity(m, p2, fixed, touched, n_touched):
    """Stage 3b on the active nodes: re-mapped velocities ``p2 / m`` in place (fixed: 0)."""
    for k in range(n_touched[0]):
        a = touched[k]
        ma = m[a] if m[a] > _MASS_TOL else 1.0
        for c in range(2):
            p2[a, c] = 0.0 if fixed[a, c] else p2[a, c] / ma


# --------------------------------------------------------------------- material (per point)
# Hencky update in passes: the transcendental functions (exp, expm1, log, arctanh) of
# all points are evaluated by numpy's SIMD ufuncs between per-point passes; scalar
# libm calls in the per-point loop cost ~35 ns per point, the ufuncs ~4 ns (measured).
@_inline
def _exp_args(e0, e1, e3):
    """Arguments of exp(2 E) (material.exp_sym2): 2 m and y = 2 sqrt(r2)."""
    m = 0.5 * (e0 + e1)
    d = 0.5 * (e0 - e1)
    return 2 * m, 2 * math.sqrt(d * d + e3 * e3)


@_inline
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


@_inline
def _log_args(axx, ayy, axy):
    """For 1/2 ln(A) (material.log_sym2): (1 / m, d, axy, x) with x = r / m, and the
    ufunc arguments ``m^2 - r^2`` (for log) and ``x`` (for arctanh)."""
    m = 0.5 * (axx + ayy)
    d = 0.5 * (axx - ayy)
    r2 = d * d + axy * axy
    im = 1.0 / m
    x = math.sqrt(r2) * im
    return im, d, axy, x, m * m - r2, x


@_inline
def _log_sym2_from(im, d, axy, x, log_det, atanh_x):
    """1/2 ln(A) from ``im = 1 / m``, ``log_det = ln(m^2 - r^2)`` and ``atanh_x =
    atanh(x)``, x = r / m (atanh(x) / x is accurate for every x > 0; x = 0 gives 1)."""
    ax = atanh_x / x if x > 0 else 1.0
    lp_lm = 0.25 * log_det
    g = 0.5 * ax * im
    return lp_lm + g * d, lp_lm - g * d, g * axy


@_inline
def _trial_b(f00, f01, f10, f11, e0, e1, e3, e2m, em, y):
    """b_tr = dF exp(2 eps) dF^T from ``e2m = exp(2 m)``, ``em = expm1(y)`` of eps;
    returns the arguments of :func:`_log_sym2_from` and of the log / arctanh ufuncs."""
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


@_kernel
def _exp_args_pass(log_strain, active, ta, tb, tc):
    """Pass 0: ``ta``, ``tb`` = 2 m, y of the current log strains (for exp, expm1); tc = y."""
    for i in range(log_strain.shape[0]):
        if active[i]:
            ta[i], tb[i] = _exp_args(log_strain[i, 0], log_strain[i, 1], log_strain[i, 3])
        else:
            ta[i] = 0.0
            tb[i] = 0.0
        tc[i] = tb[i]


@_kernel
def _trial_pass(dF, log_strain, active, ta, tb, tc, W):
    """b_tr for given increments ``dF`` (n, 4) (the material-only path of
    :func:`stress_update_points`)."""
    for i in range(dF.shape[0]):
        if not active[i]:
            ta[i] = 1.0
            tb[i] = 0.0
            continue
        W[i, 0], W[i, 1], W[i, 2], W[i, 3], ta[i], tb[i] = _trial_b(
            dF[i, 0], dF[i, 1], dF[i, 2], dF[i, 3], log_strain[i, 0], log_strain[i, 1],
            log_strain[i, 3], ta[i], tb[i], tc[i])


@_inline
def _material_point(version, geostatic, model, w0, w1, w2, w3, ta, tb, e2, state, params, i):
    """Trial log strain, then the point's model update (one dispatch on its model id).

    Geostatic (small strain): ``w`` holds the trial strain.  Finite strain: ``w``,
    ``ta``, ``tb`` hold b_tr (see :func:`_trial_b`).  Writes ``state[i]``; returns
    ``(e0, e1, e2, e3, t0, t1, t2, t3)``."""
    if geostatic:
        return point_dispatch(version, model, w0, w1, w2, w3, state, params, i)
    x0, x1, x3 = _log_sym2_from(w0, w1, w2, w3, ta, tb)
    return point_dispatch(version, model, x0, x1, e2 + 0.0, x3, state, params, i)


@_inline
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


@_inline
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


@_inline
def _small_strain_trial(i, g00, g01, g10, g11, e0, e1, e2, e3, W):
    """Geostatic trial strain of point ``i``: eps + sym(grad du) into ``W``."""
    W[i, 0] = e0 + g00
    W[i, 1] = e1 + g11
    W[i, 2] = e2 + 0.0
    W[i, 3] = e3 + 0.5 * (g01 + g10)


@_inline
def _apply_increment(i, f00, f01, f10, f11, e0, e1, e3, F, vol, W, ta, tb, tc):
    """Finite strain at point ``i``: F <- dF F, V <- det(dF) V, trial b_tr into W, ta, tb."""
    a00, a01, a10, a11 = F[i, 0, 0], F[i, 0, 1], F[i, 1, 0], F[i, 1, 1]
    F[i, 0, 0] = f00 * a00 + f01 * a10
    F[i, 0, 1] = f00 * a01 + f01 * a11
    F[i, 1, 0] = f10 * a00 + f11 * a10
    F[i, 1, 1] = f10 * a01 + f11 * a11
    vol[i] = vol[i] * (f00 * f11 - f01 * f10)
    W[i, 0], W[i, 1], W[i, 2], W[i, 3], ta[i], tb[i] = _trial_b(
        f00, f01, f10, f11, e0, e1, e3, ta[i], tb[i], tc[i])


@_inline
def _point_velocity_gradient(i, x, lp, gimp, o0, o1, h0, h1, ih0, ih1, nx, ny, vn):
    """Velocity gradient at point ``i`` from nodal velocities ``vn`` (Q4 or uGIMP basis)."""
    if gimp:
        return _velocity_gradient(_gimp(x[i, 0], x[i, 1], lp[i, 0], lp[i, 1], o0, o1, h0, h1,
                                        ih0, ih1, nx, ny), vn)
    return _velocity_gradient(_q4(x[i, 0], x[i, 1], o0, o1, h0, h1, ih0, ih1, nx, ny), vn)


@_kernel
def _kinematics_pass(x_old, active, log_strain, F, vol, dt, geostatic, gimp, lp, org, h, nx, ny,
                     vn, W, ta, tb, tc):
    """Pass 1: velocity gradient at the positions before the move.  Geostatic: ``W[i]`` =
    the small-strain trial strain.  Finite strain: Hughes-Winget increment dF, F <- dF F,
    V <- det(dF) V, and b_tr from ``ta``, ``tb`` = exp(2 m), expm1(y) of the current
    log strain (``W``, ``ta``, ``tb`` then hold the log / arctanh arguments)."""
    o0, o1, h0, h1 = org[0], org[1], h[0], h[1]
    ih0, ih1 = 1.0 / h0, 1.0 / h1
    for i in range(x_old.shape[0]):
        if not active[i]:
            ta[i] = 1.0
            tb[i] = 0.0
            continue
        L00, L01, L10, L11 = _point_velocity_gradient(i, x_old, lp, gimp, o0, o1, h0, h1,
                                                      ih0, ih1, nx, ny, vn)
        e0, e1, e2, e3 = log_strain[i, 0], log_strain[i, 1], log_strain[i, 2], log_strain[i, 3]
        if geostatic:
            _small_strain_trial(i, L00 * dt, L01 * dt, L10 * dt, L11 * dt, e0, e1, e2, e3, W)
            continue
        f00, f01, f10, f11 = _hughes_winget(L00, L01, L10, L11, dt)
        _apply_increment(i, f00, f01, f10, f11, e0, e1, e3, F, vol, W, ta, tb, tc)


def _make_finish_pass(version):
    """The finish pass compiled for one registry version (see :mod:`fem_rmpm.materials.dispatch`)."""
    @_kernel
    def _finish_pass(x, v, mass, vol, vol0, log_strain, state, stress, active,
                     model, params, geostatic, W, ta, tb, lo, hi, out):
        """Pass 2: trial strain, the model update, Cauchy stress ``tau V0 / V``; ``out`` (4,) =
        max P-wave speed sqrt(M / rho), max |v|, number of non-finite points, number
        outside [lo, hi] (for the next CFL step and the guards)."""
        c2max = 0.0
        vmax2 = 0.0
        n_bad = 0
        n_out = 0
        for i in range(x.shape[0]):
            if not active[i]:
                continue
            r = _material_point(version, geostatic, model[i], W[i, 0], W[i, 1], W[i, 2],
                                W[i, 3], ta[i], tb[i], log_strain[i, 2], state, params, i)
            log_strain[i, 0] = r[0]
            log_strain[i, 1] = r[1]
            log_strain[i, 2] = r[2]
            log_strain[i, 3] = r[3]
            V = vol[i]
            ratio = vol0[i] / V
            s0 = r[4] * ratio
            s1 = r[5] * ratio
            s2 = r[6] * ratio
            s3 = r[7] * ratio
            stress[i, 0] = s0
            stress[i, 1] = s1
            stress[i, 2] = s2
            stress[i, 3] = s3
            # for the next CFL step (max of sqrt = sqrt of max) and the guards
            c2max = max(c2max, (params[i, 1] + 4.0 / 3.0 * params[i, 0]) * V / mass[i])
            v0 = v[i, 0]
            v1 = v[i, 1]
            s2v = v0 * v0 + v1 * v1
            vmax2 = max(vmax2, s2v)
            y0 = x[i, 0]
            y1 = x[i, 1]
            if not math.isfinite(y0 + y1 + s2v + s0 + s1 + s2 + s3):
                n_bad += 1
            elif y0 < lo[0] or y1 < lo[1] or y0 > hi[0] or y1 > hi[1]:
                n_out += 1
        out[0] = math.sqrt(c2max)
        out[1] = math.sqrt(vmax2)
        out[2] = n_bad
        out[3] = n_out
    return _finish_pass


def _make_material_pass(version):
    """The vectorised material update (tests) for one registry version."""
    @_jit
    def _material_pass(geostatic, W, ta, tb, log_strain, state, model, params):
        n = W.shape[0]
        eps = np.empty((n, 4))
        st = state.copy()
        tau = np.empty((n, 4))
        for i in range(n):
            r = _material_point(version, geostatic, model[i], W[i, 0], W[i, 1], W[i, 2],
                                W[i, 3], ta[i], tb[i], log_strain[i, 2], st, params, i)
            eps[i, 0], eps[i, 1], eps[i, 2], eps[i, 3] = r[0], r[1], r[2], r[3]
            tau[i, 0], tau[i, 1], tau[i, 2], tau[i, 3] = r[4], r[5], r[6], r[7]
        return eps, st, tau
    return _material_pass


_BY_VERSION: dict = {}


def material_kernels():
    """``(finish_pass, material_pass)`` compiled for the current model registry."""
    v = registry.version()
    if v not in _BY_VERSION:
        _BY_VERSION[v] = (_make_finish_pass(v), _make_material_pass(v))
    return _BY_VERSION[v]


@_kernel
def _fbar_gradient_pass(x_old, active, vol, dt, geostatic, gimp, lp, org, h, nx, ny, vn,
                        host, D, cv, cvj):
    """F-bar pass 1 (:mod:`fem_rmpm.locking`): per point the host cell at ``x_old`` and the
    increment ``D`` (n, 4) — finite strain: the Hughes-Winget dF; geostatic: grad(du) =
    L dt — and per cell the sums of ``V`` and ``V dJ`` (geostatic: ``V tr grad(du)``),
    in point order as ``np.bincount``.  ``vol`` is read, not changed."""
    o0, o1, h0, h1 = org[0], org[1], h[0], h[1]
    ih0, ih1 = 1.0 / h0, 1.0 / h1
    for i in range(x_old.shape[0]):
        if not active[i]:
            continue
        ci = min(max(int(math.floor((x_old[i, 0] - o0) * ih0)), 0), nx - 1)
        cj = min(max(int(math.floor((x_old[i, 1] - o1) * ih1)), 0), ny - 1)
        c = cj * nx + ci
        host[i] = c
        cv[c] = 0.0
        cvj[c] = 0.0
    for i in range(x_old.shape[0]):
        if not active[i]:
            continue
        L00, L01, L10, L11 = _point_velocity_gradient(i, x_old, lp, gimp, o0, o1, h0, h1,
                                                      ih0, ih1, nx, ny, vn)
        if geostatic:
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


@_kernel
def _fbar_apply_pass(active, log_strain, F, vol, geostatic, host, D, cv, cvj, W, ta, tb, tc):
    """F-bar pass 2: the cell mean replaces each point's volume change.  Finite strain:
    dF_bar = (dJ_bar / dJ)^(1/2) dF, then F, V and b_tr as :func:`_kinematics_pass`;
    geostatic (B-bar): grad(du) + 1/2 (mean tr - tr) I, the trial strain into ``W``."""
    for i in range(D.shape[0]):
        if not active[i]:
            ta[i] = 1.0
            tb[i] = 0.0
            continue
        c = host[i]
        mean = cvj[c] / cv[c]
        g00, g01, g10, g11 = D[i, 0], D[i, 1], D[i, 2], D[i, 3]
        e0, e1, e2, e3 = log_strain[i, 0], log_strain[i, 1], log_strain[i, 2], log_strain[i, 3]
        if geostatic:
            corr = 0.5 * (mean - (g00 + g11))
            _small_strain_trial(i, g00 + corr, g01, g10, g11 + corr, e0, e1, e2, e3, W)
            continue
        sc = math.sqrt(mean / (g00 * g11 - g01 * g10))
        f00, f01, f10, f11 = sc * g00, sc * g01, sc * g10, sc * g11
        _apply_increment(i, f00, f01, f10, f11, e0, e1, e3, F, vol, W, ta, tb, tc)


def update_stress(x, x_old, v, mass, vol, vol0, F, log_strain, state, stress, active,
                  model, params, dt, geostatic, gimp, lp, org, h, nx, ny, vn,
                  lo, hi, out, W, ta, tb, tc, fbar=False, host=None, D=None, cv=None,
                  cvj=None):
    """Stage 3c: velocity gradient from the re-mapped nodal velocities ``vn`` at the
    positions before the move (``x_old``), deformation increment (geostatic: small
    strain, J = 1), F, volume, Hencky/von Mises stress update, Cauchy stress; see
    :func:`_finish_pass` for ``out``.  ``W`` (n, 4), ``ta``, ``tb``, ``tc`` (n,) are scratch.
    ``fbar``: the F-bar remedy (:mod:`fem_rmpm.locking`) with the scratch arrays ``host``
    (n,) int64, ``D`` (n, 4) and the per-cell sums ``cv``, ``cvj`` (n_cells,)."""
    with np.errstate(all="ignore"):     # a non-finite point is reported by the guards
        if not geostatic:
            _exp_args_pass(log_strain, active, ta, tb, tc)
            np.exp(ta, out=ta)
            np.expm1(tb, out=tb)
        if fbar:
            _fbar_gradient_pass(x_old, active, vol, dt, geostatic, gimp, lp, org, h, nx, ny, vn,
                                host, D, cv, cvj)
            _fbar_apply_pass(active, log_strain, F, vol, geostatic, host, D, cv, cvj, W, ta, tb,
                             tc)
        else:
            _kinematics_pass(x_old, active, log_strain, F, vol, dt, geostatic, gimp, lp, org, h,
                             nx, ny, vn, W, ta, tb, tc)
        if not geostatic:
            np.log(ta, out=ta)
            np.arctanh(tb, out=tb)
    material_kernels()[0](x, v, mass, vol, vol0, log_strain, state, stress, active,
                          model, params, geostatic, W, ta, tb, lo, hi, out)


# --------------------------------------------------------------------- vectorised material (tests)
def stress_update_points(dF, log_strain, gamma_p, soil):
    """material.stress_update through the kernels' Hencky passes: ``dF`` (n, 2, 2),
    ``log_strain`` (n, 4), ``gamma_p`` (n,), ``soil`` a SoilPoints.  Returns
    ``(log_strain, gamma_p, tau)``."""
    n = len(gamma_p)
    D = np.ascontiguousarray(dF, dtype=float).reshape(n, 4)
    ls = np.ascontiguousarray(log_strain, dtype=float)
    act = np.ones(n, dtype=bool)
    W, ta, tb, tc = np.empty((n, 4)), np.empty(n), np.empty(n), np.empty(n)
    _exp_args_pass(ls, act, ta, tb, tc)
    with np.errstate(all="ignore"):     # non-finite values propagate to the caller's guards
        np.exp(ta, out=ta)
        np.expm1(tb, out=tb)
        _trial_pass(D, ls, act, ta, tb, tc, W)
        np.log(ta, out=ta)
        np.arctanh(tb, out=tb)
    return _points_update(False, W, ta, tb, ls, gamma_p, soil)


def small_strain_update_points(grad_du, log_strain, gamma_p, soil):
    """material.small_strain_update through the kernels: returns (log_strain, gamma_p, tau)."""
    n = len(gamma_p)
    L = np.asarray(grad_du, dtype=float)
    e = np.asarray(log_strain, dtype=float)
    W = np.stack([e[:, 0] + L[:, 0, 0], e[:, 1] + L[:, 1, 1], e[:, 2] + 0.0,
                  e[:, 3] + 0.5 * (L[:, 0, 1] + L[:, 1, 0])], axis=1)
    z = np.zeros(n)
    return _points_update(True, W, z, z, e, gamma_p, soil)


def _points_update(geostatic, W, ta, tb, log_strain, state, soil):
    flat = np.ndim(state) == 1
    st = np.ascontiguousarray(np.asarray(state, float).reshape(len(W), -1))
    eps, st, tau = material_kernels()[1](geostatic, W, ta, tb, log_strain, st, soil.model,
                                         np.ascontiguousarray(soil.params))
    return eps, (st[:, 0] if flat else st), tau
