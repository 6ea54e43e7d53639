"""Grid transfers of the explicit step: stage 1 (map to nodes), stage 2 (solve on the
mesh) and stage 3a (map back, move, MUSL re-map), and the MUSL nodal velocities (3b).

Every formula is the one of :func:`fem_rmpm.schemes.explicit.reference.explicit_step_numpy`.

**Two halves, each with its own nodes.**  The points are split in two halves at a block
boundary near the middle (:func:`.common.half_split`, which does not depend on the number
of threads).  Each half scatters in point order into its own nodal arrays (``N`` and
``N.half``) and lists the nodes it touched.  Then each half, on its own:

* solves the momentum balance on the nodes *it* touched (:func:`solve_and_move`), taking
  at a node both halves touched the sum first half + second half (the numpy path's
  ``second`` split), into its own ``v_new`` and ``acc``; maps back to its points, moves
  them and re-maps their momenta into its own ``v_remap``;
* computes the nodal velocities ``v_remap / m`` of its nodes (both halves' re-mapped
  momenta) into its own ``v_musl`` (:func:`nodal_velocity`), for its points' stress
  update (:mod:`.stress`).

A node both halves touched is solved by both, with the same sums in the same order, so
with the same result.  So the two halves run as two independent tasks between the two
synchronisations of the method (after the scatter, after the re-map), each on the data it
wrote itself: on two threads a step has three parallel regions (map; solve and move;
nodal velocities and stress), or one region per call of the two-thread step driver with a
spin barrier for each join (:mod:`.advance`), and no serial merge of the nodal lists; on
one thread the halves run one after the other with the same arithmetic, so 1 and 2
threads give bitwise the same run (``tests/test_threads.py``).  Against the single
point-order sum of ``np.bincount`` (the numpy path) this only regroups the sums at nodes
both halves touch (round-off, ~1e-16 relative per step).  The grid kinetic energy is
summed over the first half's nodes, then the second half's that the first did not touch.

**Pairs.**  A point's or a node's x and y components (velocity, momentum, force,
acceleration) are read, combined and written as one 2-wide vector (:mod:`.pairs`:
explicit vector operations and fused multiply-adds, so every caller rounds alike).
"""
from __future__ import annotations

import math

import numpy as np
from numba import prange

from fem_rmpm.runtime.compiled import inline, kernel, kernel_parallel, variant
from fem_rmpm.schemes.explicit.kernels.arrays import NodeArrays
from fem_rmpm.schemes.explicit.kernels.basis import gimp_kept, gimp_store, q4_at, q4_cell
from fem_rmpm.schemes.explicit.kernels.common import (
    MASS_TOL,
    fixed_columns,
    half_range,
    literal_variants,
    xy,
)
from fem_rmpm.schemes.explicit.kernels.contact import contact_velocity
from fem_rmpm.schemes.explicit.kernels.pairs import fma2, fma2_to, load2, mul2, sub2_from
from fem_rmpm.schemes.explicit.kernels.water import water_force, water_ramp

__all__ = ["map_to_nodes", "map_to_nodes_parallel", "solve_and_move", "solve_and_move_parallel",
           "nodal_velocity", "nodal_velocities", "nodal_velocities_parallel"]


@inline
def _top(N):
    """``N`` without its ``half`` (the threads' loop takes no nested groups)."""
    return NodeArrays(N.m, N.p, N.f, N.v_new, N.acc, N.v_remap, N.v_musl, N.flag, N.touched,
                      N.n_touched, None)


@inline
def _own(T, H, c):
    """The nodal arrays of half ``c``."""
    return T if c == 0 else H


# --------------------------------------------------------------------- 1. map to nodes
@inline
def _clear(N):
    for k in range(N.n_touched[0]):
        a = N.touched[k]
        N.m[a] = 0.0
        ax, ay = xy(a)
        N.p[ax] = 0.0
        N.p[ay] = 0.0
        N.f[ax] = 0.0
        N.f[ay] = 0.0
        N.flag[a] = 0


@inline
def _scatter(sh, i, P, N, nt):
    nodes, w, dx, dy = sh
    m, p, f, flag, touched = N.m, N.p, N.f, N.flag, N.touched
    mp = P.mass[i]
    mv = mul2(mp, (P.v[i, 0], P.v[i, 1]))
    vol = P.vol[i]
    sx = P.stress[i, 0] * vol
    sy = P.stress[i, 1] * vol
    sxy = P.stress[i, 3] * vol
    s_x = (sx, sxy)                  # the stress's rows (times volume): the force at a
    s_y = (sxy, sy)                  # node with gradient (dx, dy) is dx s_x + dy s_y
    for k in range(len(nodes)):
        a = nodes[k]
        if flag[a] == 0:
            flag[a] = 1
            touched[nt] = a
            nt += 1
        wk = w[k]
        m[a] += wk * mp
        ax, ay = xy(a)
        fma2_to(p, ax, wk, mv)
        sub2_from(f, ax, fma2(dx[k], s_x, mul2(dy[k], s_y)))
    return nt


@inline
def _scatter_force(sh, f, fp):
    """A point force ``fp`` (kN per m) to the nodal forces ``f`` of its basis ``sh``."""
    nodes, w, _, _ = sh
    for k in range(len(nodes)):
        ax, _ = xy(nodes[k])
        fma2_to(f, ax, w[k], fp)


@inline
def _scatter_points(gimp, P, M, N, S, o, start, stop):
    """Points ``start:stop`` (active ones) into the arrays of ``N``, from cleared ones;
    Q4: each point's cell and local coordinates into ``S.q4_ll``, ``S.q4_st``; uGIMP
    (``gimp``, a constant: the other basis is not compiled): its basis factors into
    ``S.gimp_ij``, ``S.gimp_w`` (:func:`.basis.gimp_store`)."""
    nt = 0
    x, lp, cell, st = P.x, P.half_width, S.q4_ll, S.q4_st
    wet, ramp = water_ramp(M, o)     # pore water (fem_rmpm.schemes.pore_pressure)
    for i in range(np.uint64(start), np.uint64(stop)):
        if not P.active[i]:
            continue
        if gimp:
            sg = gimp_store(i, x[i, 0], x[i, 1], lp[i, 0], lp[i, 1], M, S.gimp_ij, S.gimp_w)
            nt = _scatter(sg, i, P, N, nt)
            if wet:                  # the water's force -V grad u at the point (ramped)
                _scatter_force(sg, N.f, water_force(x[i, 0], x[i, 1], P.vol[i], M.water,
                                                    M.frame, ramp))
        else:
            ll, s, t = q4_cell(x[i, 0], x[i, 1], M)
            cell[i] = ll
            st[i, 0] = s
            st[i, 1] = t
            sq = q4_at(ll, s, t, M)
            nt = _scatter(sq, i, P, N, nt)
            if wet:
                _scatter_force(sq, N.f, water_force(x[i, 0], x[i, 1], P.vol[i], M.water,
                                                    M.frame, ramp))
    N.n_touched[0] = nt


def _map_half_for(gimp):
    """:func:`_map_half` compiled for one basis (``gimp``: uGIMP, else Q4)."""
    @kernel
    @variant("map_half", gimp=gimp)
    def map_half(P, M, T, H, S, o, c):
        fixed_columns(P, S)
        A = _own(T, H, c)
        start, stop = half_range(P.x.shape[0], c)
        _clear(A)
        _scatter_points(gimp, P, M, A, S, o, start, stop)
    return map_half


def _map_half(gimp, P, M, T, H, S, o, c):
    """Half ``c`` of the points into its nodal arrays (``T``: the first, ``H`` = the nodes'
    ``half``: the second), after clearing them at the nodes of its previous step, in the
    basis ``gimp`` (``o.gimp``; a literal: the kernel of that basis alone,
    :func:`.common.literal_variants`).  The two halves touch disjoint arrays, so they can
    run at the same time (a compiled function, called from the threads' loop: numba's
    parfor analysis crashed on this body inline).  Called from numba code only."""
    raise NotImplementedError("_map_half runs inside numba kernels only")


map_half_of = literal_variants(_map_half, _map_half_for)


@kernel
def map_to_nodes(gimp, P, M, N, S, o):
    """Stage 1: nodal mass, momentum and internal force (stress divergence) from the
    active points (gravity, ``m_I g``, is added on the mesh by :func:`solve_and_move`),
    the first half of the points into ``N``, the second into ``N.half``; the nodes each
    half touched are listed in its ``touched[:n_touched[0]]`` (flag 1).  The nodes of the
    previous step are cleared first.  Q4: the points' cells into ``S`` (reused by the map
    back and the stress pass, which so skip locating the points again).  ``gimp``: the
    basis, ``o.gimp`` (or a literal of it: that basis alone is compiled)."""
    T = _top(N)
    _map_half(gimp, P, M, T, N.half, S, o, np.int64(0))
    _map_half(gimp, P, M, T, N.half, S, o, np.int64(1))


@kernel_parallel
def map_to_nodes_parallel(gimp, P, M, T, H, S, o):
    """:func:`map_to_nodes` with the two halves on two threads (bitwise the same):
    ``T`` the nodes' arrays without ``half`` (:func:`.arrays.top_of`), ``H`` = ``N.half``
    (numba's threaded loop does not take a nested group)."""
    for c in prange(2):
        _map_half(gimp, P, M, T, H, S, o, np.int64(c))


# --------------------------------------------------------------------- 2. solve on the mesh
@inline
def _solve_nodes(M, T, H, o, c):
    """Stage 2 on the nodes half ``c`` touched: lumped-mass momentum balance with the sums
    of both halves (first + second where both touched a node), force ``f = f_int + m_I g``
    (gravity on the mesh: exactly the scattered ``sum_p N_Ip m_p g`` in exact arithmetic,
    two products per node and point fewer in the map), Cundall damping ``f - damping |f|
    sign(v)``, fixed components zero, into the half's ``v_new`` and ``acc``.  Returns the
    sum of m |v|^2 over these nodes (half 1: less those half 0 touched)."""
    A = _own(T, H, c)
    other = H.flag if c == 0 else T.flag
    v_new, acc, fixed = A.v_new, A.acc, M.fixed
    dt, damping, gx, gy = o.dt, o.damping, o.gx, o.gy
    ke = 0.0
    for k in range(A.n_touched[0]):
        a = A.touched[k]
        ax, ay = xy(a)
        shared = other[a] != 0
        if shared:                   # both halves: first + second
            m = T.m[a] + H.m[a]
            p0, p1 = T.p[ax] + H.p[ax], T.p[ay] + H.p[ay]
            f0, f1 = T.f[ax] + H.f[ax], T.f[ay] + H.f[ay]
        else:
            m, p0, p1, f0, f1 = A.m[a], A.p[ax], A.p[ay], A.f[ax], A.f[ay]
        has = m > MASS_TOL
        inv_m = 1.0 / m if has else 0.0
        for d in range(2):
            ad = ax if d == 0 else ay
            vo = (p0 if d == 0 else p1) * inv_m
            fc = (f0 if d == 0 else f1) + m * (gx if d == 0 else gy)     # + gravity, m_I g
            if damping > 0:
                sg = 1.0 if vo > 0 else (-1.0 if vo < 0 else 0.0)
                fc = fc - damping * abs(fc) * sg
            if fixed[ad]:
                fc = 0.0
                vo = 0.0
            ac = fc * inv_m
            acc[ad] = ac
            v_new[ad] = vo + ac * dt
        if M.has_contact and has and M.contact_on[a]:        # frictional bedrock
            w = _contact_solve(M, a, m, v_new, acc, ax, ay, dt, p0 * inv_m, p1 * inv_m)
            if c == 0 or not shared:
                M.contact_work[c] += w
        if c == 0 or not shared:
            ke += m * (v_new[ax] * v_new[ax] + v_new[ay] * v_new[ay])
    return ke


@inline
def _contact_solve(M, a, m, v_new, acc, ax, ay, dt, vo0, vo1):
    """Contact node ``a`` (velocity ``vo0``, ``vo1`` at the start of the step): its new
    velocity corrected (:func:`.contact.contact_velocity`), the acceleration with it (the
    points' FLIP update sees the contact force); returns the work the friction took
    (kJ/m)."""
    M.contact_work[2] = dt
    u0, u1 = v_new[ax], v_new[ay]
    w0, w1, w = contact_velocity(M, a, m, u0, u1, dt, vo0, vo1)
    acc[ax] += (w0 - u0) / dt
    acc[ay] += (w1 - u1) / dt
    v_new[ax] = w0
    v_new[ay] = w1
    return w


# --------------------------------------------------------------------- 3. update the points
@inline
def _g2p_point(sh, i, P, N, v_remap, S, o):
    nodes, w, _, _ = sh
    v_new, acc, p2, v, x, dt, flip = N.v_new, N.acc, v_remap, P.v, P.x, o.dt, o.flip
    vp = (0.0, 0.0)
    ap = (0.0, 0.0)
    for k in range(len(nodes)):
        ax, _ = xy(nodes[k])
        vp = fma2(w[k], load2(v_new, ax), vp)
        ap = fma2(w[k], load2(acc, ax), ap)
    vp0, vp1 = vp
    # FLIP / PIC blend: v <- flip (v + dt a_pic) + (1 - flip) v_pic
    v0, v1 = fma2(flip, fma2(dt, ap, (v[i, 0], v[i, 1])), mul2(1.0 - flip, vp))
    v[i, 0] = v0
    v[i, 1] = v1
    x0 = x[i, 0]
    x1 = x[i, 1]
    if o.fbar:                       # (F-bar's host cells; the basis is the map's)
        S.x_old[i, 0] = x0
        S.x_old[i, 1] = x1
    if o.geostatic:
        P.u_geo[i, 0] += dt * vp0
        P.u_geo[i, 1] += dt * vp1
    else:
        x[i, 0], x[i, 1] = fma2(dt, vp, (x0, x1))
    mv = mul2(P.mass[i], (v0, v1))
    for k in range(len(nodes)):
        ax, _ = xy(nodes[k])
        fma2_to(p2, ax, w[k], mv)
    return vp0 * vp0 + vp1 * vp1


@inline
def _g2p_points(gimp, P, M, A, S, o, start, stop, row):
    """Points ``start:stop`` with the nodal solution of their half ``A``; their re-mapped
    momenta into ``A.v_remap``.  Into ``row`` (a row of ``S.halves``): max |v_pic|^2
    (the motion as the grid sees it), max |v|^2 (for the next CFL step), the points with a
    non-finite position or velocity and those outside the grid rectangle (for the guards);
    here, where the new x and v are in registers, not in the stress pass (which would load
    them again)."""
    vpic2 = 0.0
    v2max = 0.0
    n_bad = 0
    n_out = 0
    x, v, lo, hi = P.x, P.v, M.lo, M.hi
    for i in range(np.uint64(start), np.uint64(stop)):
        if not P.active[i]:
            continue
        if gimp:                     # the basis of the map to nodes (same position)
            s2 = _g2p_point(gimp_kept(i, S.gimp_ij, S.gimp_w, M), i, P, A, A.v_remap, S, o)
        else:                        # the cell of the map to nodes (same position)
            sq = q4_at(S.q4_ll[i], S.q4_st[i, 0], S.q4_st[i, 1], M)
            s2 = _g2p_point(sq, i, P, A, A.v_remap, S, o)
        vpic2 = max(vpic2, s2)
        v0 = v[i, 0]
        v1 = v[i, 1]
        sv = v0 * v0 + v1 * v1
        v2max = max(v2max, sv)
        y0 = x[i, 0]
        y1 = x[i, 1]
        if not math.isfinite(y0 + y1 + sv):
            n_bad += 1
        elif y0 < lo[0] or y1 < lo[1] or y0 > hi[0] or y1 > hi[1]:
            n_out += 1
    row[1] = vpic2
    row[2] = v2max
    row[3] = n_bad
    row[4] = n_out


@inline
def _clear_remap(N):
    for k in range(N.n_touched[0]):
        ax, ay = xy(N.touched[k])
        N.v_remap[ax] = 0.0
        N.v_remap[ay] = 0.0


@inline
def _move_points(gimp, P, M, T, H, S, o, c):
    """Stage 3a for the points of half ``c`` (the re-mapped momenta into its ``v_remap``,
    cleared first) in the basis ``gimp`` (a constant); their statistics into
    ``S.halves[c]`` (:func:`_g2p_points`)."""
    A = _own(T, H, c)
    start, stop = half_range(P.x.shape[0], c)
    _clear_remap(A)
    _g2p_points(gimp, P, M, A, S, o, start, stop, S.halves[c])


@kernel
def _solve_half(M, T, H, S, o, c):
    """Stage 2 on the nodes of half ``c``; their sum of m |v|^2 into ``S.halves[c, 0]``."""
    S.halves[c, 0] = _solve_nodes(M, T, H, o, c)


def _move_points_half_for(gimp):
    """:func:`_move_points_half` compiled for one basis (``gimp``: uGIMP, else Q4)."""
    @kernel
    @variant("move_points_half", gimp=gimp)
    def move_points_half(P, M, T, H, S, o, c):
        fixed_columns(P, S)
        _move_points(gimp, P, M, T, H, S, o, c)
    return move_points_half


def _move_points_half(gimp, P, M, T, H, S, o, c):
    """Stage 3a for the points of half ``c`` in the basis ``gimp`` (``o.gimp``; a literal:
    the kernel of that basis alone, :func:`.common.literal_variants`).  Called from numba
    code only."""
    raise NotImplementedError("_move_points_half runs inside numba kernels only")


_move_points_half_of = literal_variants(_move_points_half, _move_points_half_for)


@kernel
def _move_half(gimp, P, M, T, H, S, o, c):
    """Half ``c``: stage 2 on its nodes, then stage 3a for its points (the threaded
    kernel's task; the serial kernel calls the same two functions, both halves' nodes
    first).  LLVM inlines the solve into both callers; with FMA contraction allowed it
    could fuse the kinetic-energy sum differently in each (1 ulp), so no kernel contracts
    (:data:`fem_rmpm.runtime.compiled.FASTMATH`)."""
    _solve_half(M, T, H, S, o, c)
    _move_points_half(gimp, P, M, T, H, S, o, c)


@inline
def _grid_stats(S):
    """(grid kinetic energy, max |v_pic|) from the halves' rows of ``S.halves``."""
    return 0.5 * (S.halves[0, 0] + S.halves[1, 0]), math.sqrt(max(S.halves[0, 1],
                                                                   S.halves[1, 1]))


@kernel
def solve_and_move(gimp, P, M, N, S, o):
    """Stage 2, solve on the mesh (the nodes' ``v_new``, ``acc``), and 3a: FLIP/PIC point
    velocities, positions (geostatic: ``P.u_geo`` instead) and the MUSL re-map of the new
    point momenta into ``v_remap``, per half (module docstring).  The positions before the
    move are kept in ``S.x_old`` for F-bar's host cells (the stress pass takes the basis
    the map to nodes kept: Q4 cells and local coordinates, uGIMP factors).  Returns the
    grid kinetic energy 1/2 sum m_I |v_I|^2 and the largest |v_pic| (the motion as the
    grid sees it)."""
    T = _top(N)                      # (both halves' nodes, then both halves' points)
    _solve_half(M, T, N.half, S, o, np.int64(0))
    _solve_half(M, T, N.half, S, o, np.int64(1))
    _move_points_half(gimp, P, M, T, N.half, S, o, np.int64(0))
    _move_points_half(gimp, P, M, T, N.half, S, o, np.int64(1))
    return _grid_stats(S)


@kernel_parallel
def solve_and_move_parallel(gimp, P, M, T, H, S, o):
    """:func:`solve_and_move` with the two halves on two threads (bitwise the same); ``T``,
    ``H`` as :func:`map_to_nodes_parallel`."""
    for c in prange(2):
        _move_half(gimp, P, M, T, H, S, o, np.int64(c))
    return _grid_stats(S)


@inline
def nodal_velocity(M, T, H, c):
    """Stage 3b on the nodes half ``c`` touched: the velocities from the re-mapped momenta
    of both halves (first + second where both touched a node), ``v_remap / m`` (fixed: 0),
    into the half's ``v_musl``."""
    A = _own(T, H, c)
    other = H.flag if c == 0 else T.flag
    fixed, out = M.fixed, A.v_musl
    for k in range(A.n_touched[0]):
        a = A.touched[k]
        ax, ay = xy(a)
        if other[a]:
            m = T.m[a] + H.m[a]
            q0 = T.v_remap[ax] + H.v_remap[ax]
            q1 = T.v_remap[ay] + H.v_remap[ay]
        else:
            m, q0, q1 = A.m[a], A.v_remap[ax], A.v_remap[ay]
        ma = m if m > MASS_TOL else 1.0
        out[ax] = 0.0 if fixed[ax] else q0 / ma
        out[ay] = 0.0 if fixed[ay] else q1 / ma
        if M.has_contact and m > MASS_TOL and M.contact_on[a]:   # frictional bedrock
            if A.v_new[ax] == 0.0 and A.v_new[ay] == 0.0:          # stuck in the solve
                out[ax] = 0.0
                out[ay] = 0.0
            else:
                out[ax], out[ay], _ = contact_velocity(M, a, m, out[ax], out[ay],
                                                       M.contact_work[2], 0.0, 0.0)


@kernel
def nodal_velocity_half(M, T, H, c):
    """:func:`nodal_velocity` compiled on its own (serial and threaded callers share it)."""
    nodal_velocity(M, T, H, c)


@kernel
def nodal_velocities(M, N):
    """Stage 3b for both halves (before F-bar's gradient pass, which reads every point)."""
    T = _top(N)
    nodal_velocity_half(M, T, N.half, np.int64(0))
    nodal_velocity_half(M, T, N.half, np.int64(1))


@kernel_parallel
def nodal_velocities_parallel(M, T, H):
    """:func:`nodal_velocities` with the two halves on two threads."""
    for c in prange(2):
        nodal_velocity_half(M, T, H, np.int64(c))
