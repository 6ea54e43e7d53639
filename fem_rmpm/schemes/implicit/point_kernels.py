"""Compiled loops of the implicit assembly (numba): the per-point sums of
:class:`fem_rmpm.schemes.implicit.assembly.StepSystem`, written straight into a fixed pattern.

Each replaces a chain of numpy passes (batched 2x2 matmuls, a sparse group sum, a
bincount) by one loop over the points; they compute the same sums (equal to the
scikit-fem assembly to round-off, ``tests/test_implicit.py``).  Compiled on first use
and cached on disk (``cache=True``).
"""
from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["assemble_tangent", "assemble_bbar_tangent", "displacement_gradient", "block_pattern",
           "interpolate", "spatial_gradients", "increment_kinematics", "nodal_mass_momentum",
           "move_points", "internal_force"]


@njit(cache=True, error_model="numpy")
def assemble_tangent(g, A, V0, group, positions, data):
    """``data[positions[group[p], e]] += Ke_p[e]`` for every point ``p``, with the point
    block ``Ke[a, i, l, b] = V0_p g_aj A_ijlm g_bm`` (flattened in that order, ``e``;
    position -1: a prescribed DOF, skipped).  ``g`` (n, k, 2), ``A`` (n, 2, 2, 2, 2)."""
    n, k = g.shape[0], g.shape[1]
    gA = np.empty((k, 2, 2, 2))
    for p in range(n):
        v = V0[p]
        for a in range(k):
            g0, g1 = v * g[p, a, 0], v * g[p, a, 1]
            for i in range(2):
                for l in range(2):
                    for m in range(2):
                        gA[a, i, l, m] = g0 * A[p, i, 0, l, m] + g1 * A[p, i, 1, l, m]
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


@njit(cache=True, error_model="numpy")
def assemble_bbar_tangent(g, D, V0, w, group, n_groups, positions, t1, t2, t3):
    """The three B-bar terms of the small-strain tangent beyond the standard one
    (:func:`fem_rmpm.schemes.locking.bbar_tangent_correction`), each summed over the
    points in ``t1``, ``t2``, ``t3`` (data arrays of the pattern, zeroed by the caller):
    for every point ``p`` of node set ``c`` (a Q4 host cell: its points share the cell's
    nodes, so every term is a block of that cell)::

        t1[a, i, l, b] += u_ai d_bl,   t2 += d_ai v_bl,   t3 += (d_ai V0_p kappa_p) d_bl

    with ``d = bbar_c - g_p``, ``bbar_c = sum_{q in c} w_q g_q``, ``u = V0 g Q^T``,
    ``Q_ij = 1/2 (D_ij00 + D_ij11)``, ``v = V0 g P^T``, ``P_lm = 1/2 (D_00lm + D_11lm)``,
    ``kappa = 1/2 (P_00 + P_11)``.  Every product and every sum is taken in the order of
    the sparse products of the reference (points in ascending order), so ``(t1 + t2) + t3``
    is that correction to the last bit (a tangent near a mechanism is then singular, or
    not, in both alike).  ``g`` (n, k, 2), ``D`` (n, 2, 2, 2, 2), ``w`` (n,) the cell
    weights; layout of ``positions`` as :func:`assemble_tangent`."""
    n, k = g.shape[0], g.shape[1]
    bbar = np.zeros((n_groups, k, 2))
    for p in range(n):
        c = group[p]
        for a in range(k):
            bbar[c, a, 0] += g[p, a, 0] * w[p]
            bbar[c, a, 1] += g[p, a, 1] * w[p]
    u = np.empty((k, 2))
    v = np.empty((k, 2))
    d = np.empty((k, 2))
    for p in range(n):
        c = group[p]
        vol = V0[p]
        q00 = 0.5 * (D[p, 0, 0, 0, 0] + D[p, 0, 0, 1, 1])
        q01 = 0.5 * (D[p, 0, 1, 0, 0] + D[p, 0, 1, 1, 1])
        q10 = 0.5 * (D[p, 1, 0, 0, 0] + D[p, 1, 0, 1, 1])
        q11 = 0.5 * (D[p, 1, 1, 0, 0] + D[p, 1, 1, 1, 1])
        p00 = 0.5 * (D[p, 0, 0, 0, 0] + D[p, 1, 1, 0, 0])
        p01 = 0.5 * (D[p, 0, 0, 0, 1] + D[p, 1, 1, 0, 1])
        p10 = 0.5 * (D[p, 0, 0, 1, 0] + D[p, 1, 1, 1, 0])
        p11 = 0.5 * (D[p, 0, 0, 1, 1] + D[p, 1, 1, 1, 1])
        kv = vol * (0.5 * (p00 + p11))
        for a in range(k):
            g0, g1 = g[p, a, 0], g[p, a, 1]
            u[a, 0] = (g0 * q00 + g1 * q01) * vol
            u[a, 1] = (g0 * q10 + g1 * q11) * vol
            v[a, 0] = (g0 * p00 + g1 * p01) * vol
            v[a, 1] = (g0 * p10 + g1 * p11) * vol
            d[a, 0] = bbar[c, a, 0] - g0
            d[a, 1] = bbar[c, a, 1] - g1
        row = positions[c]
        e = 0
        for a in range(k):
            for i in range(2):
                for l in range(2):
                    for b in range(k):
                        q = row[e]
                        e += 1
                        if q >= 0:
                            t1[q] += u[a, i] * d[b, l]
                            t2[q] += d[a, i] * v[b, l]
                            t3[q] += (d[a, i] * kv) * d[b, l]


@njit(cache=True, error_model="numpy")
def displacement_gradient(du, nodes, dN, out):
    """``out[p, i, j] = sum_a du[nodes[p, a], i] dN[p, a, j]`` (n, 2, 2)."""
    n, k = nodes.shape
    for p in range(n):
        h00 = h01 = h10 = h11 = 0.0
        for a in range(k):
            q = nodes[p, a]
            u0, u1 = du[q, 0], du[q, 1]
            d0, d1 = dN[p, a, 0], dN[p, a, 1]
            h00 += u0 * d0
            h01 += u0 * d1
            h10 += u1 * d0
            h11 += u1 * d1
        out[p, 0, 0], out[p, 0, 1], out[p, 1, 0], out[p, 1, 1] = h00, h01, h10, h11
    return out


@njit(cache=True, error_model="numpy")
def internal_force(tau4, V0, g, nodes, out):
    """``out[nodes[p, a], i] += V0_p tau_ij g_aj`` (``out`` (n_nodes, 2), zeroed by the
    caller); ``tau4`` (n, 4) [xx, yy, zz, xy]."""
    n, k = nodes.shape
    for p in range(n):
        v = V0[p]
        txx, tyy, txy = v * tau4[p, 0], v * tau4[p, 1], v * tau4[p, 3]
        for a in range(k):
            g0, g1 = g[p, a, 0], g[p, a, 1]
            q = nodes[p, a]
            out[q, 0] += txx * g0 + txy * g1
            out[q, 1] += txy * g0 + tyy * g1
    return out


@njit(cache=True)
def block_pattern(gd, nf):
    """The CSR pattern of a matrix assembled from dense blocks, one per node set.

    ``gd`` (ng, m): the free DOF index of each of the ``m = 2k`` DOFs of node set ``g``
    (order ``[a, i]``: node ``a``, component ``i``), -1 for a prescribed DOF; ``nf`` the
    number of free DOFs.  Returns ``(indptr, indices, positions, diag, transpose)``:
    the CSR row pointer and sorted column indices (int32) of every pair of free DOFs
    that share a node set; ``positions`` (ng, m*m) the data position of the block
    entry ``[a, i, l, b]`` (row DOF ``(a, i)``, column DOF ``(b, l)``; -1 where either
    is prescribed); ``diag`` (nf,) the position of each diagonal entry; ``transpose``
    (nnz,) the position of entry ``(c, r)`` for the entry ``(r, c)`` (the pattern is
    symmetric).  The same arrays as the sorted unique keys ``row * nf + col`` of all
    block entries, in one pass over the rows (no sort of the ``ng m^2`` keys)."""
    ng, m = gd.shape
    k = m // 2
    # the node sets of each row, with the row's local index in the set
    cnt = np.zeros(nf + 1, dtype=np.int64)
    for g in range(ng):
        for e in range(m):
            r = gd[g, e]
            if r >= 0:
                cnt[r + 1] += 1
    rptr = np.cumsum(cnt)
    rgrp = np.empty(rptr[nf], dtype=np.int64)
    rloc = np.empty(rptr[nf], dtype=np.int64)
    fill = rptr[:nf].copy()
    for g in range(ng):
        for e in range(m):
            r = gd[g, e]
            if r >= 0:
                rgrp[fill[r]] = g
                rloc[fill[r]] = e
                fill[r] += 1
    mark = np.full(nf, -1, dtype=np.int64)
    colpos = np.empty(nf, dtype=np.int64)
    buf = np.empty(rptr[nf] * m, dtype=np.int32)
    indptr = np.zeros(nf + 1, dtype=np.int32)
    positions = np.full((ng, m * m), -1, dtype=np.int64)
    diag = np.empty(nf, dtype=np.int64)
    nnz = 0
    for r in range(nf):
        # the columns of row r: the free DOFs of its node sets, once each, sorted
        start = nnz
        for q in range(rptr[r], rptr[r + 1]):
            g = rgrp[q]
            for e in range(m):
                c = gd[g, e]
                if c >= 0 and mark[c] != r:
                    mark[c] = r
                    j = nnz                     # insertion sort (at most a few dozen)
                    while j > start and buf[j - 1] > c:
                        buf[j] = buf[j - 1]
                        j -= 1
                    buf[j] = c
                    nnz += 1
        indptr[r + 1] = nnz
        for q in range(start, nnz):
            colpos[buf[q]] = q
        diag[r] = colpos[r]
        # the positions of row r's entries in each of its blocks
        for q in range(rptr[r], rptr[r + 1]):
            g, ri = rgrp[q], rloc[q]
            for l in range(2):
                for b in range(k):
                    c = gd[g, 2 * b + l]
                    if c >= 0:
                        positions[g, ri * m + l * k + b] = colpos[c]
    indices = buf[:nnz].copy()
    # symmetric pattern: the entries (r, c) in CSR order fill each row c in ascending r
    transpose = np.empty(nnz, dtype=np.int64)
    nxt = indptr[:nf].astype(np.int64)
    for r in range(nf):
        for q in range(indptr[r], indptr[r + 1]):
            c = indices[q]
            transpose[q] = nxt[c]
            nxt[c] += 1
    return indptr, indices, positions, diag, transpose


@njit(cache=True, error_model="numpy")
def interpolate(nodal, nodes, N, out):
    """``out[p, i] = sum_a N[p, a] nodal[nodes[p, a], i]`` (n, 2): a nodal vector
    (n_nodes, 2) at the points."""
    n, k = nodes.shape
    for p in range(n):
        s0 = s1 = 0.0
        for a in range(k):
            q = nodes[p, a]
            s0 += N[p, a] * nodal[q, 0]
            s1 += N[p, a] * nodal[q, 1]
        out[p, 0], out[p, 1] = s0, s1
    return out


@njit(cache=True, error_model="numpy")
def _spatial_at(p, f00, f01, f10, f11, dN, dF, det, g):
    """Point ``p``'s ``dF`` (its four entries given), ``det dF`` and, where ``det > 0``,
    its spatial basis gradients ``g[p, a, j] = sum_l dN[p, a, l] (dF^-1)_lj``; returns
    ``det dF``."""
    dF[p, 0, 0], dF[p, 0, 1], dF[p, 1, 0], dF[p, 1, 1] = f00, f01, f10, f11
    d = f00 * f11 - f01 * f10
    det[p] = d
    if not d > 0.0:
        return d
    i00, i11, i01, i10 = f11 / d, f00 / d, -f01 / d, -f10 / d
    for a in range(dN.shape[1]):
        d0, d1 = dN[p, a, 0], dN[p, a, 1]
        g[p, a, 0] = d0 * i00 + d1 * i10
        g[p, a, 1] = d0 * i01 + d1 * i11
    return d


@njit(cache=True, error_model="numpy")
def spatial_gradients(H, dN, dF, det, g):
    """Per point: ``dF = I + H``, ``det = det dF`` and the spatial basis gradients
    ``g[p, a, j] = sum_l dN[p, a, l] (dF^-1)_lj`` (n, k, 2); returns the smallest
    ``det`` (``g`` is left unset at a point with ``det <= 0``)."""
    dmin = np.inf
    for p in range(dN.shape[0]):
        d = _spatial_at(p, 1.0 + H[p, 0, 0], H[p, 0, 1], H[p, 1, 0], 1.0 + H[p, 1, 1], dN,
                        dF, det, g)
        if d < dmin:
            dmin = d
    return dmin


@njit(cache=True, error_model="numpy")
def increment_kinematics(du, nodes, dN, dF, det, g):
    """:func:`displacement_gradient` of the nodal increment ``du`` (n_nodes, 2) and
    :func:`spatial_gradients` of it in one pass over the points (the same arithmetic, so
    the same bits, without the gradient array): ``dF = I + grad du``, ``det`` and ``g``;
    returns the smallest ``det``."""
    n, k = nodes.shape
    dmin = np.inf
    for p in range(n):
        h00 = h01 = h10 = h11 = 0.0
        for a in range(k):
            q = nodes[p, a]
            u0, u1 = du[q, 0], du[q, 1]
            d0, d1 = dN[p, a, 0], dN[p, a, 1]
            h00 += u0 * d0
            h01 += u0 * d1
            h10 += u1 * d0
            h11 += u1 * d1
        d = _spatial_at(p, 1.0 + h00, h01, h10, 1.0 + h11, dN, dF, det, g)
        if d < dmin:
            dmin = d
    return dmin


@njit(cache=True, error_model="numpy")
def nodal_mass_momentum(nodes, N, mass, v, a, m, mv, ma):
    """Lumped nodal mass ``m_b = sum_p m_p N_b`` and the nodal sums ``sum_p m_p N_b v_p``
    and ``sum_p m_p N_b a_p`` (``m`` (n_nodes,), ``mv``, ``ma`` (n_nodes, 2), zeroed by
    the caller)."""
    n, k = nodes.shape
    for p in range(n):
        for b in range(k):
            q = nodes[p, b]
            w = N[p, b] * mass[p]
            m[q] += w
            mv[q, 0] += w * v[p, 0]
            mv[q, 1] += w * v[p, 1]
            ma[q, 0] += w * a[p, 0]
            ma[q, 1] += w * a[p, 1]


@njit(cache=True, error_model="numpy")
def move_points(act, dx, dF, V0, tau4, x, F, volume, stress):
    """The converged step at the active points ``act``: ``x += dx``, ``F <- dF F``,
    ``V = det(F) V0`` and the Cauchy stress ``tau / det F`` (``x``, ``F``, ``volume``,
    ``stress``: the arrays of all points, in place; ``dx``, ``dF``, ``V0``, ``tau4``: per
    active point)."""
    for j in range(len(act)):
        p = act[j]
        x[p, 0] = x[p, 0] + dx[j, 0]
        x[p, 1] = x[p, 1] + dx[j, 1]
        a00, a01, a10, a11 = dF[j, 0, 0], dF[j, 0, 1], dF[j, 1, 0], dF[j, 1, 1]
        b00, b01, b10, b11 = F[p, 0, 0], F[p, 0, 1], F[p, 1, 0], F[p, 1, 1]
        f00 = a00 * b00 + a01 * b10
        f01 = a00 * b01 + a01 * b11
        f10 = a10 * b00 + a11 * b10
        f11 = a10 * b01 + a11 * b11
        F[p, 0, 0], F[p, 0, 1], F[p, 1, 0], F[p, 1, 1] = f00, f01, f10, f11
        J = f00 * f11 - f01 * f10
        volume[p] = J * V0[j]
        for c in range(stress.shape[1]):
            stress[p, c] = tau4[j, c] / J
