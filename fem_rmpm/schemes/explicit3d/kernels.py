"""Compiled explicit MUSL step on the hexahedral grid: the three-dimensional counterpart of
:mod:`fem_rmpm.schemes.explicit.kernels`, with the same stages and formulas as the
plane-strain reference step (:mod:`fem_rmpm.schemes.explicit.reference`).  The points are
taken in two halves (``0:split`` and ``split:n``, :func:`half_split`), each with nodal rows
of its own, so that the two halves can run on two threads with the arithmetic of one
(:mod:`.step`); each stage is a kernel of its own so that it can be timed alone
(``validation/bench_explicit_3d.py``):

1. :func:`map_to_nodes_3d` (per half): per point, the host cell and local coordinates
   (kept for the later stages: the basis is that of the point's position at the start of
   the step), mass, momentum and internal force ``-V sigma grad N`` (kN) to the half's
   nodal rows; the cells and nodes it touches are listed, and the half's next clearing
   visits those only;
2. :func:`solve_nodes_3d` (serial, on the nodes either half touched): the two halves'
   sums added (half 0's + half 1's), gravity ``m g``, local (Cundall) damping
   ``-alpha |f| sign(v)``, fixed components at rest, ``v_new = v + dt f / m``;
3. :func:`map_back_3d` (per half): FLIP/PIC point velocity, the point moved with the grid
   velocity (geostatic: its displacement accumulated, the point kept in place), the MUSL
   re-map of the updated momenta into the half's rows; :func:`nodal_velocity_3d` (serial)
   adds the halves and divides by the mass;
4. :func:`.stress3d.stress_3d` (per half): velocity gradient, stress update, the maxima.

Nodal rows are eight numbers, one 64-byte cache line: the halves' ``buf`` (2, nn, 8)
``[m, p_x, p_y, p_z, f_x, f_y, f_z, -]`` (t, t m/s, kN; the map back's re-mapped momenta
in columns 1-3), and the totals ``node`` (nn, 8) ``[m, v_x, v_y, v_z, a_x, a_y, a_z, -]``
(t, m/s, m/s2; the re-mapped velocities in columns 1-3 after the map back).  Within a
half the scatter runs in point order, so a run is bitwise the same on one and two
threads.  The kernels allocate nothing (compiled without reference counting,
:data:`fem_rmpm.runtime.compiled.kernel`): the step's scratch comes with the workspace
(:class:`.loop.Workspace3D`).
"""
from __future__ import annotations

import math

from fem_rmpm.runtime.compiled import assume_columns, inline, kernel
from fem_rmpm.schemes.explicit3d.rows import row_add4, row_sum8

__all__ = ["map_to_nodes_3d", "solve_nodes_3d", "map_back_3d", "nodal_velocity_3d",
           "half_split", "MASS_TOL", "N_STATS", "NODE_COLUMNS"]

#: Nodes lighter than this (t) carry no velocity (as in the plane-strain step).
MASS_TOL = 1e-14
#: Entries of the stats array a step returns: kinetic energy (kJ), max |v_pic|, max P-wave
#: speed, max |v| (m/s), non-finite points, points outside the grid.
N_STATS = 6
#: Numbers per nodal row (module docstring).
NODE_COLUMNS = 8


@inline
def half_split(n):
    """First point of the second half of ``n`` points."""
    return n // 2


@inline
def _scatter(buf, node, N, gx, gy, gz, mi, w0, w1, w2, sxx, syy, szz, sxy, syz, sxz):
    """One corner's share of a point: mass ``N mi``, momentum ``N mi v`` (``w``) and
    force ``-V sigma grad N`` (the stress premultiplied by the volume).  (Scalar: as one
    8-wide vector addition, :mod:`.rows`, the map took 1.2x the time.)"""
    buf[node, 0] += N * mi
    buf[node, 1] += N * w0
    buf[node, 2] += N * w1
    buf[node, 3] += N * w2
    buf[node, 4] -= sxx * gx + sxy * gy + sxz * gz
    buf[node, 5] -= sxy * gx + syy * gy + syz * gz
    buf[node, 6] -= sxz * gx + syz * gy + szz * gz


@inline
def _clear_listed(buf, touched, nodes, nact, cell_touched, cells):
    """Zero the rows of the nodes listed last step and unflag them and their cells."""
    for t in range(nact[0]):
        a = nodes[t]
        touched[a] = False
        for k in range(NODE_COLUMNS):
            buf[a, k] = 0.0
    for t in range(nact[1]):
        cell_touched[cells[t]] = False


@inline
def _list_nodes(cells, ncell, touched, nodes, nx, ny, sy, sz):
    """List (in ``nodes``) and flag the nodes of the first ``ncell`` listed cells; their
    count."""
    count = 0
    for t in range(ncell):
        cell = cells[t]
        base = cell % nx + sy * ((cell // nx) % ny) + sz * (cell // (nx * ny))
        for q in range(8):
            node = base + (q & 1) + sy * ((q >> 1) & 1) + sz * (q >> 2)
            if not touched[node]:
                touched[node] = True
                nodes[count] = node
                count += 1
    return count


# long function: the per-point scatter written out on scalars
@kernel
def map_to_nodes_3d(x, v, mass, vol, stress, active, origin, h, shape, cellbase, cellxi,
                    lo, hi, buf, touched, nodes, cell_touched, cells, nact):
    """Stage 1 (module docstring) for the points ``lo:hi``: clears the half's rows ``buf``
    (nn, 8) at the nodes it listed last step, then scatters mass (t), momentum (t m/s) and
    internal force (kN) of its active points, listing their cells in ``cells[:nact[1]]``
    and those cells' nodes in ``nodes[:nact[0]]``; keeps each point's cell's first node
    in ``cellbase`` and its local coordinates in ``cellxi`` (n, 3)."""
    assume_columns(buf, 8)
    _clear_listed(buf, touched, nodes, nact, cell_touched, cells)
    ncell = 0
    nx, ny, nz = shape[0], shape[1], shape[2]
    sy, sz = nx + 1, (nx + 1) * (ny + 1)
    ihx, ihy, ihz = 1.0 / h[0], 1.0 / h[1], 1.0 / h[2]
    for i in range(lo, hi):
        if not active[i]:
            continue
        s0 = (x[i, 0] - origin[0]) * ihx
        s1 = (x[i, 1] - origin[1]) * ihy
        s2 = (x[i, 2] - origin[2]) * ihz
        ic = min(max(int(math.floor(s0)), 0), nx - 1)
        jc = min(max(int(math.floor(s1)), 0), ny - 1)
        kc = min(max(int(math.floor(s2)), 0), nz - 1)
        a, b, c = s0 - ic, s1 - jc, s2 - kc
        cell = ic + nx * (jc + ny * kc)
        if not cell_touched[cell]:
            cell_touched[cell] = True
            cells[ncell] = cell
            ncell += 1
        base = ic + sy * jc + sz * kc
        cellbase[i] = base
        cellxi[i, 0], cellxi[i, 1], cellxi[i, 2] = a, b, c
        mi, Vi = mass[i], vol[i]
        sxx, syy, szz = Vi * stress[i, 0], Vi * stress[i, 1], Vi * stress[i, 2]
        sxy, syz, sxz = Vi * stress[i, 3], Vi * stress[i, 4], Vi * stress[i, 5]
        w0, w1, w2 = mi * v[i, 0], mi * v[i, 1], mi * v[i, 2]
        # the eight corners written out (x fastest): values and gradients in factored form
        a0, b0, c0 = 1.0 - a, 1.0 - b, 1.0 - c
        bc00, bc10, bc01, bc11 = b0 * c0, b * c0, b0 * c, b * c
        ac00, ac10, ac01, ac11 = a0 * c0, a * c0, a0 * c, a * c
        ab00, ab10, ab01, ab11 = a0 * b0, a * b0, a0 * b, a * b
        _scatter(buf, base, a0 * bc00, -ihx * bc00, -ihy * ac00, -ihz * ab00,
                 mi, w0, w1, w2, sxx, syy, szz, sxy, syz, sxz)
        _scatter(buf, base + 1, a * bc00, ihx * bc00, -ihy * ac10, -ihz * ab10,
                 mi, w0, w1, w2, sxx, syy, szz, sxy, syz, sxz)
        _scatter(buf, base + sy, a0 * bc10, -ihx * bc10, ihy * ac00, -ihz * ab01,
                 mi, w0, w1, w2, sxx, syy, szz, sxy, syz, sxz)
        _scatter(buf, base + sy + 1, a * bc10, ihx * bc10, ihy * ac10, -ihz * ab11,
                 mi, w0, w1, w2, sxx, syy, szz, sxy, syz, sxz)
        _scatter(buf, base + sz, a0 * bc01, -ihx * bc01, -ihy * ac01, ihz * ab00,
                 mi, w0, w1, w2, sxx, syy, szz, sxy, syz, sxz)
        _scatter(buf, base + sz + 1, a * bc01, ihx * bc01, -ihy * ac11, ihz * ab10,
                 mi, w0, w1, w2, sxx, syy, szz, sxy, syz, sxz)
        _scatter(buf, base + sz + sy, a0 * bc11, -ihx * bc11, ihy * ac01, ihz * ab01,
                 mi, w0, w1, w2, sxx, syy, szz, sxy, syz, sxz)
        _scatter(buf, base + sz + sy + 1, a * bc11, ihx * bc11, ihy * ac11, ihz * ab11,
                 mi, w0, w1, w2, sxx, syy, szz, sxy, syz, sxz)
    nact[0] = _list_nodes(cells, ncell, touched, nodes, nx, ny, sy, sz)
    nact[1] = ncell


@kernel
def solve_nodes_3d(buf, touched, nodes, nact, node, unodes, fixed, g, dt, damping):
    """Stage 2 (module docstring): lists the nodes either half touched in
    ``unodes[:nact[2, 0]]`` (half 0's, then half 1's others) and there sets the total
    mass, the new velocity ``v + dt f / m`` and the acceleration in ``node`` (nn, 8) from
    the halves' rows ``buf`` (2, nn, 8) (their lists ``nodes`` (2, nn), flags ``touched``
    (2, nn) and counts ``nact`` (3, 2)); returns the grid's kinetic energy (kJ)."""
    assume_columns(node, 8)
    count = 0
    for t in range(nact[0, 0]):
        unodes[count] = nodes[0, t]
        count += 1
    for t in range(nact[1, 0]):
        a = nodes[1, t]
        if not touched[0, a]:
            unodes[count] = a
            count += 1
    nact[2, 0] = count
    ke = 0.0
    for t in range(count):
        a = unodes[t]
        ma = buf[0, a, 0] + buf[1, a, 0]
        node[a, 0] = ma
        if ma <= MASS_TOL:
            for k in range(1, 7):
                node[a, k] = 0.0
            continue
        inv = 1.0 / ma
        for k in range(3):
            vo = (buf[0, a, 1 + k] + buf[1, a, 1 + k]) * inv
            fk = (buf[0, a, 4 + k] + buf[1, a, 4 + k]) + ma * g[k]
            if damping > 0.0 and vo != 0.0:
                fk -= damping * abs(fk) * (1.0 if vo > 0.0 else -1.0)
            if fixed[a, k]:
                vo, fk = 0.0, 0.0
            vn = vo + dt * fk * inv               # new nodal velocity
            node[a, 1 + k] = vn
            node[a, 4 + k] = fk * inv             # acceleration
            ke += 0.5 * ma * vn * vn
    return ke


@inline
def _point_checks(i, x, v, origin, upper, pmax2):
    """Point ``i``'s squared speed into the maximum ``pmax2`` (m2/s2); 1 when its
    position or velocity is not finite, else 0; 1 when it lies outside the box
    ``origin`` to ``upper`` (m), else 0."""
    ok, out = True, False
    for k in range(3):
        ok &= math.isfinite(x[i, k]) and math.isfinite(v[i, k])
        out |= x[i, k] < origin[k] or x[i, k] > upper[k]
    pmax2 = max(pmax2, v[i, 0] * v[i, 0] + v[i, 1] * v[i, 1] + v[i, 2] * v[i, 2])
    return pmax2, 0 if ok else 1, 1 if out else 0


@inline
def _add_momentum(buf, node, N, w0, w1, w2):
    """``buf[node, 1:4] += N w`` (column 0, the mass, gets ``+ N 0``: unchanged)."""
    row_add4(buf, node, N, (0.0, w0, w1, w2))


# long function: the gather, move and re-map of a point written out on scalars
@kernel
def map_back_3d(x, v, mass, active, u_geo, cellbase, cellxi, origin, h, shape, lo, hi, node,
                buf, nodes, nact, dt, flip, geostatic, stats):
    """Stage 3 for the points ``lo:hi``: point velocity (FLIP fraction ``flip``), position
    (or, ``geostatic``, the displacement ``u_geo``) from the nodal velocities and
    accelerations of ``node``, and the updated point momenta re-mapped into columns 1-3 of
    the half's rows ``buf`` (cleared first at its listed ``nodes[:nact[0]]``).  Sets
    ``stats[1:5]`` (:data:`.step.StepScratch` ``stats``): the largest squared point speed
    (m2/s2), the count of points with a non-finite position or velocity, the count of
    points outside the grid box (``origin`` to ``origin + h shape``, m) and the largest
    squared grid (PIC) velocity of a point (m2/s2)."""
    assume_columns(node, 8)
    assume_columns(buf, 8)
    for t in range(nact[0]):
        a = nodes[t]
        buf[a, 1], buf[a, 2], buf[a, 3] = 0.0, 0.0, 0.0
    sy, sz = shape[0] + 1, (shape[0] + 1) * (shape[1] + 1)
    upper = (origin[0] + h[0] * shape[0], origin[1] + h[1] * shape[1],
             origin[2] + h[2] * shape[2])
    vmax2, pmax2, nbad, nout = 0.0, 0.0, 0, 0
    for i in range(lo, hi):
        if not active[i]:
            continue
        base, a, b, c = cellbase[i], cellxi[i, 0], cellxi[i, 1], cellxi[i, 2]
        a0, b0, c0 = 1.0 - a, 1.0 - b, 1.0 - c
        bc00, bc10, bc01, bc11 = b0 * c0, b * c0, b0 * c, b * c
        n0, n1, n2, n3 = base, base + 1, base + sy, base + sy + 1
        n4, n5, n6, n7 = base + sz, base + sz + 1, base + sz + sy, base + sz + sy + 1
        N0, N1, N2, N3 = a0 * bc00, a * bc00, a0 * bc10, a * bc10
        N4, N5, N6, N7 = a0 * bc01, a * bc01, a0 * bc11, a * bc11
        # sum_I N_I node[I] of the whole rows: velocities in 1-3, accelerations in 4-6
        r = row_sum8(node, (n0, n1, n2, n3, n4, n5, n6, n7), (N0, N1, N2, N3, N4, N5, N6, N7))
        vp0, vp1, vp2, ap0, ap1, ap2 = r[1], r[2], r[3], r[4], r[5], r[6]
        v[i, 0] = flip * (v[i, 0] + dt * ap0) + (1.0 - flip) * vp0
        v[i, 1] = flip * (v[i, 1] + dt * ap1) + (1.0 - flip) * vp1
        v[i, 2] = flip * (v[i, 2] + dt * ap2) + (1.0 - flip) * vp2
        if geostatic:
            u_geo[i, 0] += dt * vp0
            u_geo[i, 1] += dt * vp1
            u_geo[i, 2] += dt * vp2
        else:
            x[i, 0] += dt * vp0
            x[i, 1] += dt * vp1
            x[i, 2] += dt * vp2
        vmax2 = max(vmax2, vp0 * vp0 + vp1 * vp1 + vp2 * vp2)
        pmax2, bad, out = _point_checks(i, x, v, origin, upper, pmax2)
        nbad += bad
        nout += out
        mi = mass[i]
        w0, w1, w2 = mi * v[i, 0], mi * v[i, 1], mi * v[i, 2]
        _add_momentum(buf, n0, N0, w0, w1, w2)
        _add_momentum(buf, n1, N1, w0, w1, w2)
        _add_momentum(buf, n2, N2, w0, w1, w2)
        _add_momentum(buf, n3, N3, w0, w1, w2)
        _add_momentum(buf, n4, N4, w0, w1, w2)
        _add_momentum(buf, n5, N5, w0, w1, w2)
        _add_momentum(buf, n6, N6, w0, w1, w2)
        _add_momentum(buf, n7, N7, w0, w1, w2)
    stats[1], stats[2], stats[3], stats[4] = pmax2, nbad, nout, vmax2


@kernel
def nodal_velocity_3d(node, buf, fixed, unodes, nact):
    """Stage 3, on the nodes either half touched (``unodes[:nact[2, 0]]``): the halves'
    re-mapped momenta (columns 1-3 of ``buf`` (2, nn, 8)) added and divided by the mass
    become the velocities in columns 1-3 of ``node`` (m/s), zero on fixed components and
    massless nodes."""
    assume_columns(node, 8)
    for t in range(nact[2, 0]):
        a = unodes[t]
        ma = node[a, 0]
        inv = 1.0 / ma if ma > MASS_TOL else 0.0
        for k in range(3):
            node[a, 1 + k] = 0.0 if fixed[a, k] else (buf[0, a, 1 + k] + buf[1, a, 1 + k]) * inv
