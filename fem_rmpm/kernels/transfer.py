"""Grid transfers of the explicit step: stage 1 (map to nodes), stage 2 (solve on the
mesh) and the first part of stage 3 (map back, move, MUSL re-map).

Every formula is the one of :func:`fem_rmpm.explicit.explicit_step_numpy`.

**Deterministic two-part scatter.**  The points are split at ``n // 2`` (by index, a
split that does not depend on the number of threads); each half scatters in point
order into its own nodal arrays (``N`` and ``N.half``, each with its own list of touched
nodes).  The node loops that follow (solve on the mesh, the re-mapped nodal velocities)
take the two sums where they read them, ``N + N.half`` at a node both halves touched:
part 0 visits the first half's nodes, part 1 the nodes only the second half touched, so
the two parts run on two threads with no serial merge of the lists in between.  The
halves and parts run on two threads in the ``*_parallel`` compiles and one after the
other in the serial ones, with the same arithmetic: a run gives bitwise the same result
on 1 or 2 threads (``tests/test_threads.py``).  Against the single point-order sum of
``np.bincount`` (the numpy path) this only regroups the sums at nodes both halves touch
(round-off, ~1e-16 relative per step).  More threads than two do not speed the scatter
up (the split is fixed so that results do not depend on them).
"""
from __future__ import annotations

import math

import numpy as np
from numba import prange

from .arrays import NodeArrays
from .basis import gimp, q4_at, q4_cell
from .common import MASS_TOL, inline, kernel, kernel_parallel

__all__ = ["map_to_nodes", "solve_on_mesh", "g2p", "map_to_nodes_parallel", "solve_on_mesh_parallel",
           "g2p_parallel"]


# --------------------------------------------------------------------- 1. map to nodes
@inline
def _clear(N):
    for k in range(N.n_touched[0]):
        a = N.touched[k]
        N.m[a] = 0.0
        N.p[a, 0] = 0.0
        N.p[a, 1] = 0.0
        N.f[a, 0] = 0.0
        N.f[a, 1] = 0.0
        N.flag[a] = 0


@inline
def _scatter(sh, i, P, N, nt):
    nodes, w, dx, dy = sh
    m, p, f, flag, touched = N.m, N.p, N.f, N.flag, N.touched
    mp = P.mass[i]
    mv0 = mp * P.v[i, 0]
    mv1 = mp * P.v[i, 1]
    vol = P.vol[i]
    sx = P.stress[i, 0] * vol
    sy = P.stress[i, 1] * vol
    sxy = P.stress[i, 3] * vol
    for k in range(len(nodes)):
        a = nodes[k]
        if flag[a] == 0:
            flag[a] = 1
            touched[nt] = a
            nt += 1
        wk = w[k]
        m[a] += wk * mp
        p[a, 0] += wk * mv0
        p[a, 1] += wk * mv1
        f[a, 0] -= sx * dx[k] + sxy * dy[k]
        f[a, 1] -= sxy * dx[k] + sy * dy[k]
    return nt


@inline
def _scatter_points(P, M, N, S, o, start, stop):
    """Points ``start:stop`` (active ones) into the arrays of ``N``, from cleared ones;
    Q4: each point's cell and local coordinates into ``S.q4_ll``, ``S.q4_st``."""
    nt = 0
    x, lp, cell, st = P.x, P.half_width, S.q4_ll, S.q4_st
    for i in range(np.uint64(start), np.uint64(stop)):
        if not P.active[i]:
            continue
        if o.gimp:
            sg = gimp(x[i, 0], x[i, 1], lp[i, 0], lp[i, 1], M)
            nt = _scatter(sg, i, P, N, nt)
        else:
            ll, s, t = q4_cell(x[i, 0], x[i, 1], M)
            cell[i] = ll
            st[i, 0] = s
            st[i, 1] = t
            nt = _scatter(q4_at(ll, s, t, M), i, P, N, nt)
    N.n_touched[0] = nt


@inline
def _top(N):
    """``N`` without its ``half`` (the threads' loop takes no nested groups)."""
    return NodeArrays(N.m, N.p, N.f, N.v_new, N.acc, N.v_remap, N.flag, N.touched, N.n_touched,
                      None)


@kernel
def _map_half(P, M, T, H, S, o, c):
    """Half ``c`` (0: points ``:n // 2`` into ``T``; 1: the rest into ``H``, the nodes'
    ``half``), after clearing those arrays at the nodes of the previous step.  The two
    halves touch disjoint arrays, so they can run at the same time (a compiled function,
    called from the threads' loop: numba's parfor analysis crashed on this body inline)."""
    n = P.x.shape[0]
    if c == 0:
        _clear(T)
        _scatter_points(P, M, T, S, o, 0, n // 2)
    else:
        _clear(H)
        _scatter_points(P, M, H, S, o, n // 2, n)


@kernel
def map_to_nodes(P, M, N, S, o):
    """Stage 1: nodal mass, momentum and internal force (stress divergence) from the
    active points (gravity, ``m_I g``, is added on the mesh by :func:`solve_on_mesh`),
    the first half of the points into ``N``, the second into ``N.half``; the nodes each
    half touched are listed in its ``touched[:n_touched[0]]`` (flag 1).  The nodes of the
    previous step are cleared first.  Q4: the points' cells into ``S`` (reused by
    :func:`g2p` and the stress pass, which so skip locating the points again)."""
    T = _top(N)
    _map_half(P, M, T, N.half, S, o, np.int64(0))
    _map_half(P, M, T, N.half, S, o, np.int64(1))


@kernel_parallel
def map_to_nodes_parallel(P, M, T, H, S, o):
    """:func:`map_to_nodes` with the two halves on two threads (bitwise the same):
    ``T`` the nodes' arrays without ``half`` (``N._replace(half=None)``), ``H`` =
    ``N.half`` (numba's threaded loop does not take a nested group)."""
    for c in prange(2):
        _map_half(P, M, T, H, S, o, np.int64(c))


# --------------------------------------------------------------------- 2. solve on the mesh
@inline
def _part_nodes(T, H, c):
    """Part ``c`` of the active nodes: ``(list, count, other flags)``; part 0 the nodes the
    first half touched, part 1 those of the second half, less the ones with ``flag`` set in
    ``other`` (the first half's: they are part 0's)."""
    if c == 0:
        return T.touched, T.n_touched[0], H.flag
    return H.touched, H.n_touched[0], T.flag


@inline
def _solve_nodes(M, T, H, o, c):
    """Stage 2 on part ``c`` of the active nodes (:func:`_part_nodes`), the two halves'
    sums added where both touched a node; ``T.v_new``, ``T.acc``; returns the part's sum of
    m |v|^2."""
    v_new, acc, fixed = T.v_new, T.acc, M.fixed
    dt, damping, gx, gy = o.dt, o.damping, o.gx, o.gy
    nodes, count, other = _part_nodes(T, H, c)
    ke = 0.0
    for k in range(count):
        a = nodes[k]
        if c == 0:
            if other[a]:             # both halves: N + N.half
                m = T.m[a] + H.m[a]
                p0, p1 = T.p[a, 0] + H.p[a, 0], T.p[a, 1] + H.p[a, 1]
                f0, f1 = T.f[a, 0] + H.f[a, 0], T.f[a, 1] + H.f[a, 1]
            else:
                m, p0, p1, f0, f1 = T.m[a], T.p[a, 0], T.p[a, 1], T.f[a, 0], T.f[a, 1]
        elif other[a]:
            continue                 # part 0's node
        else:
            m, p0, p1, f0, f1 = H.m[a], H.p[a, 0], H.p[a, 1], H.f[a, 0], H.f[a, 1]
        has = m > MASS_TOL
        inv_m = 1.0 / m if has else 0.0
        for d in range(2):
            vo = (p0 if d == 0 else p1) * inv_m
            fc = (f0 if d == 0 else f1) + m * (gx if d == 0 else gy)     # + gravity, m_I g
            if damping > 0:
                sg = 1.0 if vo > 0 else (-1.0 if vo < 0 else 0.0)
                fc = fc - damping * abs(fc) * sg
            if fixed[a, d]:
                fc = 0.0
                vo = 0.0
            ac = fc * inv_m
            acc[a, d] = ac
            v_new[a, d] = vo + ac * dt
        ke += m * (v_new[a, 0] * v_new[a, 0] + v_new[a, 1] * v_new[a, 1])
    return ke


@kernel
def _solve_part(M, T, H, o, c, part):
    """Part ``c`` of the active nodes; its sum of m |v|^2 into ``part[2]``."""
    part[2] = _solve_nodes(M, T, H, o, c)


@kernel
def solve_on_mesh(M, N, o):
    """Stage 2 on the active nodes: ``N.v_new`` and ``N.acc`` (lumped mass, force
    ``f = f_int + m_I g`` — gravity on the mesh, exactly the scattered ``sum_p N_Ip m_p g``
    in exact arithmetic: two products per node and point fewer in the map, ~1-3 ns per
    point —, Cundall damping ``f - damping |f| sign(v)``, fixed components zero).
    Returns the grid kinetic energy, summed over the two parts of the active nodes and
    added (as the threaded version)."""
    T = _top(N)
    return 0.5 * (_solve_nodes(M, T, N.half, o, 0) + _solve_nodes(M, T, N.half, o, 1))


@kernel_parallel
def solve_on_mesh_parallel(M, T, H, o, S):
    """:func:`solve_on_mesh` with the two parts of the active nodes on two threads (their
    sums in ``S.parts[:2, 2]``; bitwise the same); ``T``, ``H`` as
    :func:`map_to_nodes_parallel`."""
    parts = S.parts
    for c in prange(2):
        _solve_part(M, T, H, o, np.int64(c), parts[c])
    return 0.5 * (parts[0, 2] + parts[1, 2])


# --------------------------------------------------------------------- 3. update the points
@inline
def _g2p_point(sh, i, P, N, v_remap, S, o):
    nodes, w, _, _ = sh
    v_new, acc, p2, v, x, dt, flip = N.v_new, N.acc, v_remap, P.v, P.x, o.dt, o.flip
    vp0 = 0.0
    vp1 = 0.0
    ap0 = 0.0
    ap1 = 0.0
    for k in range(len(nodes)):
        a = nodes[k]
        vp0 += w[k] * v_new[a, 0]
        vp1 += w[k] * v_new[a, 1]
        ap0 += w[k] * acc[a, 0]
        ap1 += w[k] * acc[a, 1]
    v0 = flip * (v[i, 0] + dt * ap0) + (1.0 - flip) * vp0
    v1 = flip * (v[i, 1] + dt * ap1) + (1.0 - flip) * vp1
    v[i, 0] = v0
    v[i, 1] = v1
    x0 = x[i, 0]
    x1 = x[i, 1]
    S.x_old[i, 0] = x0
    S.x_old[i, 1] = x1
    if o.geostatic:
        P.u_geo[i, 0] += dt * vp0
        P.u_geo[i, 1] += dt * vp1
    else:
        x[i, 0] = x0 + dt * vp0
        x[i, 1] = x1 + dt * vp1
    mp = P.mass[i]
    mv0 = mp * v0
    mv1 = mp * v1
    for k in range(len(nodes)):
        a = nodes[k]
        p2[a, 0] += w[k] * mv0
        p2[a, 1] += w[k] * mv1
    return vp0 * vp0 + vp1 * vp1


@inline
def _g2p_points(P, M, N, v_remap, S, o, start, stop):
    """Points ``start:stop``; their re-mapped momenta into ``v_remap``; max |v_pic|^2."""
    vmax2 = 0.0
    x, lp = P.x, P.half_width
    for i in range(np.uint64(start), np.uint64(stop)):
        if not P.active[i]:
            continue
        if o.gimp:
            sg = gimp(x[i, 0], x[i, 1], lp[i, 0], lp[i, 1], M)
            s2 = _g2p_point(sg, i, P, N, v_remap, S, o)
        else:                        # the cell of the map to nodes (same position)
            sq = q4_at(S.q4_ll[i], S.q4_st[i, 0], S.q4_st[i, 1], M)
            s2 = _g2p_point(sq, i, P, N, v_remap, S, o)
        vmax2 = max(vmax2, s2)
    return vmax2


@inline
def _clear_remap(N):
    for k in range(N.n_touched[0]):
        a = N.touched[k]
        N.v_remap[a, 0] = 0.0
        N.v_remap[a, 1] = 0.0


@kernel
def _g2p_half(P, M, T, H, S, o, c):
    """Half ``c`` of the points (as :func:`_map_half`): the re-mapped momenta into
    ``T.v_remap`` (c = 0) or ``H.v_remap`` (cleared first); max |v_pic|^2 into
    ``S.parts[c, 1]``."""
    n = P.x.shape[0]
    if c == 0:
        _clear_remap(T)
        S.parts[0, 1] = _g2p_points(P, M, T, T.v_remap, S, o, 0, n // 2)
    else:
        _clear_remap(H)
        S.parts[1, 1] = _g2p_points(P, M, T, H.v_remap, S, o, n // 2, n)


@kernel
def _nodal_velocity_part(M, T, H, c):
    _nodal_velocity(M, T, H, c)


@kernel_parallel
def _nodal_velocity_parallel(M, T, H):
    """The nodal velocities, the two parts of the active nodes on two threads."""
    for c in prange(2):
        _nodal_velocity_part(M, T, H, np.int64(c))


@kernel
def g2p(P, M, N, S, o):
    """Stage 3a: FLIP/PIC point velocities, positions (geostatic: ``P.u_geo`` instead),
    and the MUSL re-map of the new point momenta into ``N.v_remap`` (active nodes; the
    two halves of the points summed as in :func:`map_to_nodes`), then (3b) the re-mapped
    nodal velocities ``v_remap / m`` in the same kernel (one pass over the nodes).  The
    positions before the move are kept in ``S.x_old`` for the stress update.  Returns the
    largest |v_pic| (the motion as the grid sees it)."""
    T = _top(N)
    _g2p_half(P, M, T, N.half, S, o, np.int64(0))
    _g2p_half(P, M, T, N.half, S, o, np.int64(1))
    _nodal_velocity(M, T, N.half, np.int64(0))
    _nodal_velocity(M, T, N.half, np.int64(1))
    return math.sqrt(max(S.parts[0, 1], S.parts[1, 1]))


@kernel_parallel
def g2p_parallel(P, M, T, H, S, o):
    """:func:`g2p` with the two halves on two threads (bitwise the same); ``T``, ``H`` as
    :func:`map_to_nodes_parallel`."""
    for c in prange(2):
        _g2p_half(P, M, T, H, S, o, np.int64(c))
    _nodal_velocity_parallel(M, T, H)      # (a prange loop here would be fused: common.py)
    return math.sqrt(max(S.parts[0, 1], S.parts[1, 1]))


@inline
def _nodal_velocity(M, T, H, c):
    """Stage 3b on part ``c`` of the active nodes (:func:`_part_nodes`): the re-mapped
    momenta of the two halves added where both touched a node, then the velocities
    ``v_remap / m`` into ``T.v_remap`` (fixed: 0)."""
    fixed = M.fixed
    nodes, count, other = _part_nodes(T, H, c)
    for k in range(count):
        a = nodes[k]
        if c == 0:
            if other[a]:
                m = T.m[a] + H.m[a]
                q0 = T.v_remap[a, 0] + H.v_remap[a, 0]
                q1 = T.v_remap[a, 1] + H.v_remap[a, 1]
            else:
                m, q0, q1 = T.m[a], T.v_remap[a, 0], T.v_remap[a, 1]
        elif other[a]:
            continue
        else:
            m, q0, q1 = H.m[a], H.v_remap[a, 0], H.v_remap[a, 1]
        ma = m if m > MASS_TOL else 1.0
        T.v_remap[a, 0] = 0.0 if fixed[a, 0] else q0 / ma
        T.v_remap[a, 1] = 0.0 if fixed[a, 1] else q1 / ma
