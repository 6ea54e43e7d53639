"""Kinematics of the stress update (stage 3c, before the material model): velocity
gradient at the points, Hughes-Winget increment and volume, and the trial state of
the Hencky update, per point, for the blocks of the stress pass (:mod:`.stress`).

Finite strain: :func:`kinematics_points` reads the exp parts of each point's log strain
(``cosh(y)``, ``sinh(y)/y``, vectorised before it by :func:`.hencky.exp_block`), forms
``B_tr = dF B dF^T`` (``B = exp(2 eps) / e^{2m}``) and writes the arguments of its log
(``mu``, ``d``, ``axy``, ``s^2``, ``J = det dF``), whose transcendental parts (and the
division by ``mu``) :func:`.hencky.log_block` computes after it, vectorised;
:func:`log_sym2_from` then gives the trial log strain.  The same quantity as
:mod:`fem_rmpm.materials.hencky` (``exp_sym2``, ``log_sym2``), factored as
:mod:`.hencky` says (equal to round-off); ``hughes_winget_increment`` in the same order.

With F-bar (:mod:`fem_rmpm.schemes.locking`) the increments come from two passes:
:func:`fbar_gradient_pass` (increments and per-cell sums of ``V`` and ``V dJ``, in point
order, over all points) and :func:`fbar_apply_points` (the cell mean replaces each point's
volume change, then V and b_tr), which takes the place of :func:`kinematics_points`.
"""
from __future__ import annotations

import math

import numpy as np
from numba import prange

from fem_rmpm.runtime.compiled import (
    assume_columns,
    inline,
    kernel,
    kernel_parallel,
    variant,
)
from fem_rmpm.schemes.explicit.kernels.arrays import W_COLUMNS
from fem_rmpm.schemes.explicit.kernels.basis import cell_index, gimp_kept, q4_at
from fem_rmpm.schemes.explicit.kernels.common import (
    BLOCK,
    fixed_columns,
    half_range,
    literal_variants,
    xy,
)
from fem_rmpm.schemes.explicit.kernels.hencky import exp_block, log_block

__all__ = ["kinematics_points", "fbar_gradient_pass", "fbar_gradient_pass_parallel",
           "fbar_increments", "fbar_apply_points", "log_args",
           "log_sym2_from", "hencky_trial_pass", "inactive_row"]


@inline
def log_args(axx, ayy, axy):
    """For 1/2 ln(A) of ``A = mu I + E`` (material.log_sym2): ``(mu, d, axy, s^2)`` with
    ``d`` = (axx - ayy) / 2 and ``s^2 = d^2 + axy^2`` (``x^2 = s^2 / mu^2``, :mod:`.hencky`)."""
    m = 0.5 * (axx + ayy)
    d = 0.5 * (axx - ayy)
    return m, d, axy, d * d + axy * axy


@inline
def log_sym2_from(g, d, axy, iso):
    """The trial log strain (xx, yy, xy): ``iso I + g E`` from :func:`log_args` of B_tr,
    its isotropic part ``iso = m + ln(J) / 2`` and ``g = atanh(x) / (2 x mu)``
    (:func:`.hencky.log_block`)."""
    return iso + g * d, iso - g * d, g * axy


@inline
def _trial_b(f00, f01, f10, f11, e0, e1, e3, ch, sh):
    """B_tr = dF B dF^T, ``B = exp(2 eps) / e^{2m}`` from ``ch, sh = cosh(y), sinh(y) / y``
    of eps (:func:`.hencky.exp_parts`); returns :func:`log_args` of B_tr."""
    d = 0.5 * (e0 - e1)                             # B = cosh(y) I + 2 sinh(y)/y D
    g = 2.0 * sh
    bxx = ch + g * d
    byy = ch - g * d
    bxy = g * e3
    a00 = f00 * bxx + f01 * bxy                     # (dF B) dF^T, as the numpy matmul chain
    a01 = f00 * bxy + f01 * byy
    a10 = f10 * bxx + f11 * bxy
    a11 = f10 * bxy + f11 * byy
    c00 = a00 * f00 + a01 * f01
    c01 = a00 * f10 + a01 * f11
    c10 = a10 * f00 + a11 * f01
    c11 = a10 * f10 + a11 * f11
    return log_args(c00, c11, 0.5 * (c01 + c10))


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
        ax, ay = xy(nodes[k])
        L00 += vn[ax] * dx[k]
        L01 += vn[ax] * dy[k]
        L10 += vn[ay] * dx[k]
        L11 += vn[ay] * dy[k]
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
    a0, a1 = xy(a)
    b0, b1 = xy(b)
    c0, c1 = xy(c)
    d0, d1 = xy(d)
    L00 = ih0 * (ft * (vn[b0] - vn[a0]) + t * (vn[c0] - vn[d0]))
    L10 = ih0 * (ft * (vn[b1] - vn[a1]) + t * (vn[c1] - vn[d1]))
    L01 = ih1 * (fs * (vn[d0] - vn[a0]) + s * (vn[c0] - vn[b0]))
    L11 = ih1 * (fs * (vn[d1] - vn[a1]) + s * (vn[c1] - vn[b1]))
    return L00, L01, L10, L11


@inline
def _small_strain_trial(i, g00, g01, g10, g11, e0, e1, e2, e3, W):
    """Geostatic trial strain: eps + sym(grad du) into column ``i`` of ``W``."""
    W[0, i] = e0 + g00
    W[1, i] = e1 + g11
    W[2, i] = e2 + 0.0
    W[3, i] = e3 + 0.5 * (g01 + g10)


@inline
def _apply_increment(i, j, f00, f01, f10, f11, e0, e1, e3, P, W, ta, tb, tc):
    """Finite strain at point ``i`` (column ``j`` of the block scratch W, ta, tb, tc): V <- J V
    (J = det dF), and B_tr from the exp parts ``tb, tc`` of its log strain: :func:`log_args`
    of B_tr into ``W[:4, j]`` (mu, d, axy, J) and, for :func:`.hencky.log_block`, ``ta[j],
    tb[j], tc[j]`` = J, mu, s^2.  The total F is not carried: nothing in the explicit step
    reads it (updating it would cost a few per cent of the stress pass)."""
    J = f00 * f11 - f01 * f10
    P.vol[i] = P.vol[i] * J
    W[3, j] = J
    ta[j] = J
    m, d, axy, s2 = _trial_b(f00, f01, f10, f11, e0, e1, e3, tb[j], tc[j])
    W[0, j] = m
    W[1, j] = d
    W[2, j] = axy
    tb[j] = m
    tc[j] = s2


@inline
def _kept_velocity_gradient(i, S, M, vn, gimp_basis):
    """Velocity gradient at point ``i`` from nodal velocities ``vn`` in the basis the map
    to nodes computed at the same position (uGIMP: its factors, Q4: its cell and local
    coordinates; :mod:`.basis`)."""
    if gimp_basis:
        return _velocity_gradient(gimp_kept(i, S.gimp_ij, S.gimp_w, M), vn)
    return _velocity_gradient(q4_at(S.q4_ll[i], S.q4_st[i, 0], S.q4_st[i, 1], M), vn)


@inline
def inactive_row(j, W, ta, tb, tc):
    """Neutral log arguments (J = mu = 1, s = 0) in column ``j`` of the block scratch for
    an inactive point."""
    W[0, j] = 1.0
    W[3, j] = 1.0
    ta[j] = 1.0
    tb[j] = 1.0
    tc[j] = 0.0


def _kinematics_points_for(gimp):
    """:func:`kinematics_points` compiled for one basis (``gimp``: uGIMP, else Q4)."""
    @kernel
    @variant("kinematics_points", gimp=gimp)
    def kinematics(P, M, vn, S, o, W, ta, tb, tc, b, e):
        fixed_columns(P, S)
        assume_columns(W, W_COLUMNS)
        _gather_points(gimp, P, M, vn, S, o, tb, tc, W, b, e)
        n = e - b
        if o.geostatic:
            _small_strain_rows(W, P.log_strain, o.dt, b, n)
            return
        _increment_rows(W, ta, tb, tc, o.dt, n)
        vol, V = P.vol, W[7]
        for j in range(n):
            vol[b + j] = V[j]
    return kinematics


def kinematics_points(gimp, P, M, vn, S, o, W, ta, tb, tc, b, e):
    """Points ``b:e`` (uint64; column ``i - b`` of the block scratch ``W`` (8, >= BLOCK)
    and of ``ta, tb, tc``): velocity gradient from the nodal velocities ``vn`` (2 nn,) at
    the positions before the move, per point (:func:`_gather_points`: the gathers from the
    nodes, with the point's strain and volume, into the rows of ``W``); then, over those
    contiguous rows without a branch (LLVM vectorises the loops, AVX2: four points at a
    time), geostatic: the small-strain trial strain into ``W[:4]``
    (:func:`_small_strain_rows`); finite strain: Hughes-Winget increment dF, V <- det(dF) V
    and the log arguments of B_tr (:func:`_increment_rows`, from the exp parts in ``tb,
    tc``).  One loop over the points ran the arithmetic one point at a time: the rows took
    the kinematics from 23.6-24.6 to 13.6-15.4 ns per point (case (i) at t = 8 s, one thread,
    micro-benchmark, 8 interleaved rounds).  The velocity gradient has one call site: with
    a second one for the geostatic path the stress pass's first compile took 15-35 s
    longer.  ``gimp``: the basis, ``o.gimp`` (a literal: the kernel of that basis alone,
    :func:`.common.literal_variants`).  Called from numba code only."""
    raise NotImplementedError("kinematics_points runs inside numba kernels only")


_kinematics_of = literal_variants(kinematics_points, _kinematics_points_for)


@inline
def _small_strain_rows(W, ls, dt, b, n):
    """Geostatic (small strain), the first ``n`` columns of ``W``
    (:func:`_gather_points`): the trial strain ``eps + sym(L dt)`` (xx, yy, zz, xy) into
    rows 0-3 (the volume is not changed)."""
    for j in range(n):
        _small_strain_trial(j, W[0, j] * dt, W[1, j] * dt, W[2, j] * dt, W[3, j] * dt,
                            W[4, j], W[5, j], ls[b + j, 2], W[6, j], W)


@inline
def _gather_points(gimp, P, M, vn, S, o, tb, tc, W, b, e):
    """Per point of ``b:e``, into column ``i - b`` of the rows of ``W``: the velocity
    gradient (L00, L01, L10, L11; rows 0-3), the in-plane log strain (xx, yy, xy; rows
    4-6) and the volume (row 7).
    An inactive point gets zero gradient and strain and ``tb = tc = 1`` (cosh 0, sinh(0)/0),
    so that :func:`_increment_rows` leaves it neutral: dF = I, J = mu = 1, s = 0, V kept."""
    ls, vol = P.log_strain, P.vol
    for i in range(b, e):
        j = i - b
        if P.active[i]:
            # velocity gradient before the move: in the basis of the map to nodes (uGIMP
            # its factors, Q4 its cell and local coordinates).  Written out here, not
            # through two levels of inlined helpers, which would double the time numba's
            # inliner takes in each stress-pass compile (``gimp``: a constant)
            if gimp:
                L00, L01, L10, L11 = _velocity_gradient(gimp_kept(i, S.gimp_ij, S.gimp_w, M),
                                                        vn)
            else:
                L00, L01, L10, L11 = _q4_velocity_gradient(S.q4_ll[i], S.q4_st[i, 0],
                                                           S.q4_st[i, 1], M, vn)
            e0, e1, e3 = ls[i, 0], ls[i, 1], ls[i, 3]
        else:
            L00, L01, L10, L11 = 0.0, 0.0, 0.0, 0.0
            e0, e1, e3 = 0.0, 0.0, 0.0
            tb[j] = 1.0
            tc[j] = 1.0
        W[0, j] = L00
        W[1, j] = L01
        W[2, j] = L10
        W[3, j] = L11
        W[4, j] = e0
        W[5, j] = e1
        W[6, j] = e3
        W[7, j] = vol[i]


@inline
def _increment_rows(W, ta, tb, tc, dt, n):
    """The first ``n`` columns of the rows of ``W`` (:func:`_gather_points`): Hughes-Winget
    dF, J = det dF, V <- J V (into row 7), and :func:`log_args` of B_tr (:func:`_trial_b`,
    exp parts ``tb, tc``) into rows 0-3 (mu, d, axy, J), ``ta = J``, ``tb = mu``,
    ``tc = s^2``.  Contiguous rows and no branch: LLVM vectorises this loop."""
    g0, g1, g2, g3, g4, g5, g6, g7 = W[0], W[1], W[2], W[3], W[4], W[5], W[6], W[7]
    for j in range(n):
        f00, f01, f10, f11 = _hughes_winget(g0[j], g1[j], g2[j], g3[j], dt)
        J = f00 * f11 - f01 * f10
        g7[j] = g7[j] * J
        ta[j] = J
        m, d, axy, s2 = _trial_b(f00, f01, f10, f11, g4[j], g5[j], g6[j], tb[j], tc[j])
        g0[j] = m
        g1[j] = d
        g2[j] = axy
        g3[j] = J
        tb[j] = m
        tc[j] = s2


@kernel
def fbar_increments(P, M, vn, S, o, start, stop):
    """F-bar pass 1, per point of ``start:stop`` (one half of the points, ``vn`` its nodal
    velocities): the host cell at ``x_old`` into ``S.host`` and the increment into ``S.D``
    (n, 4) — finite strain: the Hughes-Winget dF; geostatic: grad(du) = L dt — from the
    basis the map to nodes kept (:func:`_kept_velocity_gradient`; ``x_old`` is where the
    map found it).  Each point on its own: the halves can run at the same time."""
    fixed_columns(P, S)
    x_old, host, D, dt = S.x_old, S.host, S.D, o.dt
    for i in range(np.uint64(start), np.uint64(stop)):      # (unsigned: no negative-index fix-up)
        if not P.active[i]:
            continue
        ci = cell_index((x_old[i, 0] - M.o0) * M.ih0, M.nx)
        cj = cell_index((x_old[i, 1] - M.o1) * M.ih1, M.ny)
        host[i] = cj * M.nx + ci
        L00, L01, L10, L11 = _kept_velocity_gradient(i, S, M, vn, o.gimp)
        if o.geostatic:
            g00, g01, g10, g11 = L00 * dt, L01 * dt, L10 * dt, L11 * dt
        else:
            g00, g01, g10, g11 = _hughes_winget(L00, L01, L10, L11, dt)
        D[i, 0] = g00
        D[i, 1] = g01
        D[i, 2] = g10
        D[i, 3] = g11


@inline
def _fbar_cell_sums(P, S, o):
    """F-bar pass 1, per cell: the sums of ``V`` and ``V dJ`` (geostatic: ``V tr
    grad(du)``) of its points, in point order as ``np.bincount`` (one thread: the order
    of the sums is the run's on any thread count).  ``vol`` is read, not changed."""
    host, D, cv, cvj, vol = S.host, S.D, S.cell_v, S.cell_vdj, P.vol
    for i in range(host.shape[0]):
        if P.active[i]:
            c = host[i]
            cv[c] = 0.0
            cvj[c] = 0.0
    for i in range(host.shape[0]):
        if not P.active[i]:
            continue
        if o.geostatic:
            j = D[i, 0] + D[i, 3]
        else:
            j = D[i, 0] * D[i, 3] - D[i, 1] * D[i, 2]
        c = host[i]
        cv[c] += vol[i]
        cvj[c] += vol[i] * j


@kernel
def fbar_gradient_pass(P, M, N, S, o):
    """F-bar pass 1 (:mod:`fem_rmpm.schemes.locking`): :func:`fbar_increments` of each half of the
    points with its nodal velocities (``N.v_musl``, ``N.half.v_musl``), then the per-cell
    sums (:func:`_fbar_cell_sums`)."""
    for c in range(2):               # (one call site: the drivers inline this kernel)
        start, stop = half_range(S.host.shape[0], c)
        fbar_increments(P, M, N.v_musl if c == 0 else N.half.v_musl, S, o, start, stop)
    _fbar_cell_sums(P, S, o)


@kernel_parallel
def fbar_gradient_pass_parallel(P, M, T, H, S, o):
    """:func:`fbar_gradient_pass` with the halves' increments on two threads (bitwise the
    same): ``T`` the nodes' arrays without ``half``, ``H`` = ``N.half``."""
    for c in prange(2):
        start, stop = half_range(S.host.shape[0], c)
        fbar_increments(P, M, T.v_musl if c == 0 else H.v_musl, S, o, start, stop)
    _fbar_cell_sums(P, S, o)


@kernel
def fbar_apply_points(P, S, o, W, ta, tb, tc, b, e):
    """F-bar pass 2 over points ``b:e`` (uint64; block scratch rows as
    :func:`kinematics_points`): the cell mean replaces each point's volume change.  Finite
    strain: dF_bar = (dJ_bar / dJ)^(1/2) dF, then V and the log arguments of B_tr as
    :func:`kinematics_points`; geostatic (B-bar): grad(du) + 1/2 (mean tr - tr) I, the
    trial strain into ``W``."""
    ls, D = P.log_strain, S.D
    for i in range(b, e):
        j = i - b
        if not P.active[i]:
            inactive_row(j, W, ta, tb, tc)
            continue
        c = S.host[i]
        mean = S.cell_vdj[c] / S.cell_v[c]
        g00, g01, g10, g11 = D[i, 0], D[i, 1], D[i, 2], D[i, 3]
        e0, e1, e2, e3 = ls[i, 0], ls[i, 1], ls[i, 2], ls[i, 3]
        if o.geostatic:
            corr = 0.5 * (mean - (g00 + g11))
            _small_strain_trial(j, g00 + corr, g01, g10, g11 + corr, e0, e1, e2, e3, W)
            continue
        sc = math.sqrt(mean / (g00 * g11 - g01 * g10))
        f00, f01, f10, f11 = sc * g00, sc * g01, sc * g10, sc * g11
        _apply_increment(i, j, f00, f01, f10, f11, e0, e1, e3, P, W, ta, tb, tc)


@kernel
def hencky_trial_pass(dF, log_strain, active, ta, tb, tc, W, eps_tr):
    """Trial log strains ``eps_tr`` (n, 4) of given increments ``dF`` (n, 4) (the
    material-only path of :func:`fem_rmpm.schemes.explicit.kernels.stress.stress_update_points`), in
    the blocks of the stress pass; ``ta, tb, tc`` (BLOCK,), ``W`` (4, BLOCK) block scratch."""
    n = np.uint64(dF.shape[0])
    ls = log_strain
    for b in range(np.uint64(0), n, np.uint64(BLOCK)):
        e = min(b + np.uint64(BLOCK), n)
        exp_block(ls, tb, tc, b, e)
        for i in range(b, e):
            j = i - b
            if not active[i]:
                inactive_row(j, W, ta, tb, tc)
                continue
            f00, f01, f10, f11 = dF[i, 0], dF[i, 1], dF[i, 2], dF[i, 3]
            J = f00 * f11 - f01 * f10
            m, d, axy, s2 = _trial_b(f00, f01, f10, f11, ls[i, 0], ls[i, 1], ls[i, 3], tb[j],
                                     tc[j])
            W[0, j], W[1, j], W[2, j], W[3, j] = m, d, axy, J
            ta[j], tb[j], tc[j] = J, m, s2
        log_block(W, ta, tb, tc, e - b)
        for i in range(b, e):
            j = i - b
            iso = 0.5 * (ls[i, 0] + ls[i, 1]) + 0.5 * ta[j]
            eps_tr[i, 0], eps_tr[i, 1], eps_tr[i, 3] = log_sym2_from(tb[j], W[1, j], W[2, j],
                                                                     iso)
            eps_tr[i, 2] = ls[i, 2] + 0.0
