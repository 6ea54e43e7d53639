"""Compiled explicit MUSL step on the hexahedral grid: the three-dimensional counterpart of
:mod:`fem_rmpm.schemes.explicit.kernels`, with the same stages and formulas as the
plane-strain reference step (:mod:`fem_rmpm.schemes.explicit.reference`), each stage a
kernel of its own so that it can be timed alone (``validation/bench_explicit_3d.py``):

1. :func:`map_to_nodes_3d`: per point, the host cell and local coordinates (kept for the
   later stages: the basis is that of the point's position at the start of the step),
   mass, momentum and internal force ``-V sigma grad N`` (kN) to the nodes; the nodes it
   touches are listed, and the nodal loops and the next step's clearing visit those only;
2. :func:`solve_nodes_3d`: gravity ``m g``, local (Cundall) damping ``-alpha |f| sign(v)``,
   fixed components at rest, ``v_new = v + dt f / m``;
3. :func:`map_back_3d`: FLIP/PIC point velocity, the point moved with the grid velocity
   (geostatic: its displacement accumulated, the point kept in place), the MUSL re-map of
   the updated momenta; :func:`nodal_velocity_3d` divides them by the mass;
4. :func:`stress_3d`: the velocity gradient ``L = sum v_I (x) grad N_I``, the stress update
   (small strain in the geostatic phase; else the Hughes-Winget increment and the Hencky
   update with one eigen-decomposition, :mod:`.elastic`), the plastic return on the
   principal elastic log strains (:func:`.plastic.plastic_return_principal_3d`), volume
   ``V J``, Cauchy ``tau V0 / V`` and the maxima the time loop needs.

One serial pass per stage, the scatter in point order, so a run is bitwise the same
whatever the thread setting.  The kernels allocate nothing (compiled without reference
counting, :data:`fem_rmpm.runtime.compiled.kernel`): the step's scratch comes with the
workspace (:class:`.loop.Workspace3D`).
"""
from __future__ import annotations

import math

from fem_rmpm.runtime.compiled import inline, kernel
from fem_rmpm.schemes.explicit3d.elastic import (
    compose_sym3,
    elastic_tau_3d,
    small_strain_elastic_3d,
    sym_eig3,
)
from fem_rmpm.schemes.explicit3d.plastic import MODEL_ELASTIC, plastic_return_principal_3d

__all__ = ["step_3d", "map_to_nodes_3d", "solve_nodes_3d", "map_back_3d",
           "nodal_velocity_3d", "stress_3d", "MASS_TOL", "N_STATS"]

#: Nodes lighter than this (t) carry no velocity (as in the plane-strain step).
MASS_TOL = 1e-14
#: Entries of the stats array a step returns: kinetic energy (kJ), max |v_pic|, max P-wave
#: speed, max |v| (m/s), non-finite points, points outside the grid.
N_STATS = 6


@inline
def _scatter(m, p, f, node, N, gx, gy, gz, mi, w0, w1, w2, sxx, syy, szz, sxy, syz, sxz):
    """One corner's share of a point: mass ``N mi``, momentum ``N mi v`` (``w``) and
    force ``-V sigma grad N`` (the stress premultiplied by the volume)."""
    m[node] += N * mi
    p[node, 0] += N * w0
    p[node, 1] += N * w1
    p[node, 2] += N * w2
    f[node, 0] -= sxx * gx + sxy * gy + sxz * gz
    f[node, 1] -= sxy * gx + syy * gy + syz * gz
    f[node, 2] -= sxz * gx + syz * gy + szz * gz


# long function: the per-point scatter written out on scalars
@kernel
def map_to_nodes_3d(x, v, mass, vol, stress, active, origin, h, shape, cellbase, cellxi,
                    m, p, f, touched, nodes, cell_touched, cells, nact):
    """Stage 1 (module docstring): clears the nodes and cells listed last step, then
    scatters mass ``m`` (t), momentum ``p`` (t m/s) and internal force ``f`` (kN) of the
    active points, listing their cells in ``cells[:nact[1]]`` and those cells' nodes in
    ``nodes[:nact[0]]``; keeps each point's cell's first node in ``cellbase`` and its
    local coordinates in ``cellxi`` (n, 3)."""
    for t in range(nact[0]):
        a = nodes[t]
        m[a] = 0.0
        touched[a] = False
        for k in range(3):
            p[a, k] = 0.0
            f[a, k] = 0.0
    for t in range(nact[1]):
        cell_touched[cells[t]] = False
    ncell = 0
    nx, ny, nz = shape[0], shape[1], shape[2]
    sy, sz = nx + 1, (nx + 1) * (ny + 1)
    ihx, ihy, ihz = 1.0 / h[0], 1.0 / h[1], 1.0 / h[2]
    for i in range(x.shape[0]):
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
        _scatter(m, p, f, base, a0 * bc00, -ihx * bc00, -ihy * ac00, -ihz * ab00,
                 mi, w0, w1, w2, sxx, syy, szz, sxy, syz, sxz)
        _scatter(m, p, f, base + 1, a * bc00, ihx * bc00, -ihy * ac10, -ihz * ab10,
                 mi, w0, w1, w2, sxx, syy, szz, sxy, syz, sxz)
        _scatter(m, p, f, base + sy, a0 * bc10, -ihx * bc10, ihy * ac00, -ihz * ab01,
                 mi, w0, w1, w2, sxx, syy, szz, sxy, syz, sxz)
        _scatter(m, p, f, base + sy + 1, a * bc10, ihx * bc10, ihy * ac10, -ihz * ab11,
                 mi, w0, w1, w2, sxx, syy, szz, sxy, syz, sxz)
        _scatter(m, p, f, base + sz, a0 * bc01, -ihx * bc01, -ihy * ac01, ihz * ab00,
                 mi, w0, w1, w2, sxx, syy, szz, sxy, syz, sxz)
        _scatter(m, p, f, base + sz + 1, a * bc01, ihx * bc01, -ihy * ac11, ihz * ab10,
                 mi, w0, w1, w2, sxx, syy, szz, sxy, syz, sxz)
        _scatter(m, p, f, base + sz + sy, a0 * bc11, -ihx * bc11, ihy * ac01, ihz * ab01,
                 mi, w0, w1, w2, sxx, syy, szz, sxy, syz, sxz)
        _scatter(m, p, f, base + sz + sy + 1, a * bc11, ihx * bc11, ihy * ac11, ihz * ab11,
                 mi, w0, w1, w2, sxx, syy, szz, sxy, syz, sxz)
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
    nact[0], nact[1] = count, ncell


@kernel
def solve_nodes_3d(m, p, f, v2, fixed, g, dt, damping, nodes, nact):
    """Stage 2 on the listed nodes: ``p`` becomes the new nodal velocity, ``f`` the
    acceleration (m/s2), ``v2`` cleared for the re-map; returns the grid's kinetic energy
    (kJ)."""
    ke = 0.0
    for t in range(nact[0]):
        a = nodes[t]
        if m[a] <= MASS_TOL:
            for k in range(3):
                p[a, k] = 0.0
                f[a, k] = 0.0
                v2[a, k] = 0.0
            continue
        inv = 1.0 / m[a]
        for k in range(3):
            vo = p[a, k] * inv
            fk = f[a, k] + m[a] * g[k]
            if damping > 0.0 and vo != 0.0:
                fk -= damping * abs(fk) * (1.0 if vo > 0.0 else -1.0)
            if fixed[a, k]:
                vo, fk = 0.0, 0.0
            p[a, k] = vo + dt * fk * inv          # new nodal velocity
            f[a, k] = fk * inv                    # acceleration
            ke += 0.5 * m[a] * p[a, k] * p[a, k]
            v2[a, k] = 0.0
    return ke


@inline
def _interpolate(g, k, n0, n1, n2, n3, n4, n5, n6, n7, N0, N1, N2, N3, N4, N5, N6, N7):
    """Component ``k`` of the nodal field ``g`` at a point: ``sum_I N_I g[I, k]``."""
    return (N0 * g[n0, k] + N1 * g[n1, k] + N2 * g[n2, k] + N3 * g[n3, k]
            + N4 * g[n4, k] + N5 * g[n5, k] + N6 * g[n6, k] + N7 * g[n7, k])


@inline
def _add_momentum(v2, node, N, w0, w1, w2):
    v2[node, 0] += N * w0
    v2[node, 1] += N * w1
    v2[node, 2] += N * w2


# long function: the gather, move and re-map of a point written out on scalars
@kernel
def map_back_3d(x, v, mass, active, u_geo, cellbase, cellxi, h, shape, p, f, v2, dt, flip,
                geostatic):
    """Stage 3: point velocity (FLIP fraction ``flip``), position (or, ``geostatic``, the
    displacement ``u_geo``), and the updated point momenta re-mapped into ``v2``; returns
    the largest squared grid (PIC) velocity of a point (m2/s2)."""
    sy, sz = shape[0] + 1, (shape[0] + 1) * (shape[1] + 1)
    vmax2 = 0.0
    for i in range(x.shape[0]):
        if not active[i]:
            continue
        base, a, b, c = cellbase[i], cellxi[i, 0], cellxi[i, 1], cellxi[i, 2]
        a0, b0, c0 = 1.0 - a, 1.0 - b, 1.0 - c
        bc00, bc10, bc01, bc11 = b0 * c0, b * c0, b0 * c, b * c
        n0, n1, n2, n3 = base, base + 1, base + sy, base + sy + 1
        n4, n5, n6, n7 = base + sz, base + sz + 1, base + sz + sy, base + sz + sy + 1
        N0, N1, N2, N3 = a0 * bc00, a * bc00, a0 * bc10, a * bc10
        N4, N5, N6, N7 = a0 * bc01, a * bc01, a0 * bc11, a * bc11
        vp0 = _interpolate(p, 0, n0, n1, n2, n3, n4, n5, n6, n7, N0, N1, N2, N3, N4, N5, N6, N7)
        vp1 = _interpolate(p, 1, n0, n1, n2, n3, n4, n5, n6, n7, N0, N1, N2, N3, N4, N5, N6, N7)
        vp2 = _interpolate(p, 2, n0, n1, n2, n3, n4, n5, n6, n7, N0, N1, N2, N3, N4, N5, N6, N7)
        ap0 = _interpolate(f, 0, n0, n1, n2, n3, n4, n5, n6, n7, N0, N1, N2, N3, N4, N5, N6, N7)
        ap1 = _interpolate(f, 1, n0, n1, n2, n3, n4, n5, n6, n7, N0, N1, N2, N3, N4, N5, N6, N7)
        ap2 = _interpolate(f, 2, n0, n1, n2, n3, n4, n5, n6, n7, N0, N1, N2, N3, N4, N5, N6, N7)
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
        mi = mass[i]
        w0, w1, w2 = mi * v[i, 0], mi * v[i, 1], mi * v[i, 2]
        _add_momentum(v2, n0, N0, w0, w1, w2)
        _add_momentum(v2, n1, N1, w0, w1, w2)
        _add_momentum(v2, n2, N2, w0, w1, w2)
        _add_momentum(v2, n3, N3, w0, w1, w2)
        _add_momentum(v2, n4, N4, w0, w1, w2)
        _add_momentum(v2, n5, N5, w0, w1, w2)
        _add_momentum(v2, n6, N6, w0, w1, w2)
        _add_momentum(v2, n7, N7, w0, w1, w2)
    return vmax2


@kernel
def nodal_velocity_3d(m, v2, fixed, nodes, nact):
    """Stage 3, on the listed nodes: the re-mapped momenta ``v2`` become velocities (m/s),
    zero on fixed components and massless nodes."""
    for t in range(nact[0]):
        a = nodes[t]
        inv = 1.0 / m[a] if m[a] > MASS_TOL else 0.0
        for k in range(3):
            v2[a, k] = 0.0 if fixed[a, k] else v2[a, k] * inv


@inline
def _gradient_row(v2, k, base, sy, sz, a, b, c, ihx, ihy, ihz):
    """Row ``k`` of the velocity gradient, ``sum_I v2[I, k] grad N_I`` (1/s), in the
    factored form of the trilinear gradient: along x the differences of the cell's four
    x-edges weighted by the bilinear (y, z) values, and likewise along y and z."""
    u000, u100 = v2[base, k], v2[base + 1, k]
    u010, u110 = v2[base + sy, k], v2[base + sy + 1, k]
    u001, u101 = v2[base + sz, k], v2[base + sz + 1, k]
    u011, u111 = v2[base + sz + sy, k], v2[base + sz + sy + 1, k]
    a0, b0, c0 = 1.0 - a, 1.0 - b, 1.0 - c
    gx = (b0 * c0 * (u100 - u000) + b * c0 * (u110 - u010) + b0 * c * (u101 - u001)
          + b * c * (u111 - u011))
    gy = (a0 * c0 * (u010 - u000) + a * c0 * (u110 - u100) + a0 * c * (u011 - u001)
          + a * c * (u111 - u101))
    gz = (a0 * b0 * (u001 - u000) + a * b0 * (u101 - u100) + a0 * b * (u011 - u010)
          + a * b * (u111 - u110))
    return gx * ihx, gy * ihy, gz * ihz


@inline
def _hughes_winget(l00, l01, l02, l10, l11, l12, l20, l21, l22, dt):
    """``dF = (I - L dt / 2)^-1 (I + L dt / 2)`` (row-major 9 entries) and det dF."""
    hd = 0.5 * dt
    a00, a01, a02 = 1.0 - hd * l00, -hd * l01, -hd * l02
    a10, a11, a12 = -hd * l10, 1.0 - hd * l11, -hd * l12
    a20, a21, a22 = -hd * l20, -hd * l21, 1.0 - hd * l22
    c00 = a11 * a22 - a12 * a21
    c01 = a02 * a21 - a01 * a22
    c02 = a01 * a12 - a02 * a11
    c10 = a12 * a20 - a10 * a22
    c11 = a00 * a22 - a02 * a20
    c12 = a02 * a10 - a00 * a12
    c20 = a10 * a21 - a11 * a20
    c21 = a01 * a20 - a00 * a21
    c22 = a00 * a11 - a01 * a10
    inv = 1.0 / (a00 * c00 + a01 * c10 + a02 * c20)
    # B = I + L dt / 2 = 2 I - A, so A^-1 B = 2 A^-1 - I
    two = 2.0 * inv
    f00, f01, f02 = two * c00 - 1.0, two * c01, two * c02
    f10, f11, f12 = two * c10, two * c11 - 1.0, two * c12
    f20, f21, f22 = two * c20, two * c21, two * c22 - 1.0
    J = (f00 * (f11 * f22 - f12 * f21) - f01 * (f10 * f22 - f12 * f20)
         + f02 * (f10 * f21 - f11 * f20))
    return f00, f01, f02, f10, f11, f12, f20, f21, f22, J


# long function: the Hencky update written out on scalars (nothing allocated)
@inline
def _hencky_trial(dF, be, i):
    """The trial ``b_tr = dF b dF^T`` (six components) from ``dF`` (9-tuple) and the
    point's ``b`` (row ``i`` of ``be``)."""
    f00, f01, f02, f10, f11, f12, f20, f21, f22 = dF
    b00, b11, b22, b01, b12, b02 = be[i, 0], be[i, 1], be[i, 2], be[i, 3], be[i, 4], be[i, 5]
    # G = dF b (rows)
    g00 = f00 * b00 + f01 * b01 + f02 * b02
    g01 = f00 * b01 + f01 * b11 + f02 * b12
    g02 = f00 * b02 + f01 * b12 + f02 * b22
    g10 = f10 * b00 + f11 * b01 + f12 * b02
    g11 = f10 * b01 + f11 * b11 + f12 * b12
    g12 = f10 * b02 + f11 * b12 + f12 * b22
    g20 = f20 * b00 + f21 * b01 + f22 * b02
    g21 = f20 * b01 + f21 * b11 + f22 * b12
    g22 = f20 * b02 + f21 * b12 + f22 * b22
    return (g00 * f00 + g01 * f01 + g02 * f02,
            g10 * f10 + g11 * f11 + g12 * f12,
            g20 * f20 + g21 * f21 + g22 * f22,
            g00 * f10 + g01 * f11 + g02 * f12,
            g10 * f20 + g11 * f21 + g12 * f22,
            g00 * f20 + g01 * f21 + g02 * f22)


@inline
def _finite_strain(i, dF, be, eps, lam, mu, model, plastic, state, e3):
    """Hencky update and plastic return of point ``i`` (:mod:`.elastic`): ``eps[i]`` and
    ``be[i]`` updated, the plastic shear strain increment returned."""
    bt = _hencky_trial(dF, be, i)
    r = sym_eig3(bt[0], bt[1], bt[2], bt[3], bt[4], bt[5])
    e3[0] = 0.5 * math.log(r[0])
    e3[1] = 0.5 * math.log(r[1])
    e3[2] = 0.5 * math.log(r[2])
    dg, returned = 0.0, False
    if model[i] != MODEL_ELASTIC:
        l0, l1, l2 = e3[0], e3[1], e3[2]
        dg = plastic_return_principal_3d(model[i], e3, lam[i], mu[i], plastic[i], state[i])
        # a Mohr-Coulomb return to the apex moves e3 with a zero shear increment
        returned = dg > 0.0 or e3[0] != l0 or e3[1] != l1 or e3[2] != l2
    compose_sym3(e3[0], e3[1], e3[2], r[3], r[4], r[5], r[6], r[7], r[8], r[9], r[10],
                 r[11], eps, i)
    if returned:
        compose_sym3(math.exp(2.0 * e3[0]), math.exp(2.0 * e3[1]), math.exp(2.0 * e3[2]),
                     r[3], r[4], r[5], r[6], r[7], r[8], r[9], r[10], r[11], be, i)
    else:
        for k in range(6):
            be[i, k] = bt[k]
    return dg


@inline
def _small_strain(i, L, dt, eps, lam, mu, model, plastic, state, e3):
    """Geostatic update of point ``i``: ``eps[i] += sym(L) dt``, then the plastic return
    on its principal values (an elastic point needs no eigen-decomposition)."""
    small_strain_elastic_3d(L[0], L[1], L[2], L[3], L[4], L[5], L[6], L[7], L[8], dt, eps, i)
    if model[i] == MODEL_ELASTIC:
        return 0.0
    r = sym_eig3(eps[i, 0], eps[i, 1], eps[i, 2], eps[i, 3], eps[i, 4], eps[i, 5])
    e3[0], e3[1], e3[2] = r[0], r[1], r[2]
    dg = plastic_return_principal_3d(model[i], e3, lam[i], mu[i], plastic[i], state[i])
    if dg > 0.0 or e3[0] != r[0] or e3[1] != r[1] or e3[2] != r[2]:   # apex: dg = 0
        compose_sym3(e3[0], e3[1], e3[2], r[3], r[4], r[5], r[6], r[7], r[8], r[9], r[10],
                     r[11], eps, i)
    return dg


# long function: the per-point gather, update and checks of the stress pass
@kernel
def stress_3d(x, v, mass, vol, vol0, stress, eps, be, lam, mu, active, cellbase, cellxi,
              origin, h, shape, v2, dt, geostatic, model, plastic, state, e3, out):
    """Stage 4 (module docstring) on every active point; fills ``out[2:]`` with the
    largest P-wave speed, largest point speed (m/s), non-finite points and points outside
    the grid box (``origin`` to ``origin + h shape``)."""
    sy, sz = shape[0] + 1, (shape[0] + 1) * (shape[1] + 1)
    ihx, ihy, ihz = 1.0 / h[0], 1.0 / h[1], 1.0 / h[2]
    upper = (origin[0] + h[0] * shape[0], origin[1] + h[1] * shape[1],
             origin[2] + h[2] * shape[2])
    nbad, nout, c2max, pmax2 = 0, 0, 0.0, 0.0
    for i in range(x.shape[0]):
        if not active[i]:
            continue
        base, a, b, c = cellbase[i], cellxi[i, 0], cellxi[i, 1], cellxi[i, 2]
        l00, l01, l02 = _gradient_row(v2, 0, base, sy, sz, a, b, c, ihx, ihy, ihz)
        l10, l11, l12 = _gradient_row(v2, 1, base, sy, sz, a, b, c, ihx, ihy, ihz)
        l20, l21, l22 = _gradient_row(v2, 2, base, sy, sz, a, b, c, ihx, ihy, ihz)
        L = (l00, l01, l02, l10, l11, l12, l20, l21, l22)
        if geostatic:
            _small_strain(i, L, dt, eps, lam, mu, model, plastic, state, e3)
            J = 1.0
        else:
            hw = _hughes_winget(l00, l01, l02, l10, l11, l12, l20, l21, l22, dt)
            J = hw[9]
            _finite_strain(i, hw[:9], be, eps, lam, mu, model, plastic, state, e3)
        vol[i] *= J
        ratio = vol0[i] / vol[i]
        elastic_tau_3d(eps, i, lam[i], mu[i], stress, i)
        ok = True
        for k in range(6):
            stress[i, k] *= ratio
            ok &= math.isfinite(stress[i, k])
        for k in range(3):
            ok &= math.isfinite(x[i, k]) and math.isfinite(v[i, k])
            if x[i, k] < origin[k] or x[i, k] > upper[k]:
                nout += 1
                break
        if not ok:
            nbad += 1
        c2max = max(c2max, (lam[i] + 2.0 * mu[i]) * vol[i] / mass[i])
        pmax2 = max(pmax2, v[i, 0] * v[i, 0] + v[i, 1] * v[i, 1] + v[i, 2] * v[i, 2])
    out[2], out[3], out[4], out[5] = math.sqrt(c2max), math.sqrt(pmax2), nbad, nout


@kernel
def step_3d(x, v, mass, vol, vol0, stress, eps, be, lam, mu, active, u_geo, cellbase,
            cellxi, origin, h, shape, fixed, m, p, f, v2, touched, nodes, cell_touched, cells,
            nact, dt, g, damping, flip, geostatic, model, plastic, state, e3, out):
    """One explicit step of ``dt`` s in place on the points (``x``, ``v`` (n, 3) m, m/s;
    ``mass`` t; ``vol``, ``vol0`` m3; ``stress`` Cauchy (n, 6) kPa; ``eps`` elastic log
    strain (n, 6); ``be`` its ``exp(2 eps)`` (n, 6); Lame ``lam``, ``mu`` (n,) kPa;
    ``active`` (n,); ``u_geo`` (n, 3) m; ``model`` (n,) with its parameter rows
    ``plastic`` (n, 4) and state rows ``state`` (n, >= 2), see
    :func:`.plastic.plastic_return_principal_3d`) on the grid (``origin``, ``h`` (3,) m,
    ``shape`` (3,) cells, ``fixed`` (nn, 3)) with the workspace's scratch (``cellbase``,
    ``cellxi``; nodal ``m``, ``p``, ``f``, ``v2``, ``touched``, the listed ``nodes``, the
    cells' ``cell_touched`` and listed ``cells``, their counts ``nact`` (2,); ``e3``
    (3,)), gravity ``g`` (3,) m/s2, damping ratio, FLIP
    fraction; fills ``out`` (:data:`N_STATS`)."""
    map_to_nodes_3d(x, v, mass, vol, stress, active, origin, h, shape, cellbase, cellxi,
                    m, p, f, touched, nodes, cell_touched, cells, nact)
    out[0] = solve_nodes_3d(m, p, f, v2, fixed, g, dt, damping, nodes, nact)
    out[1] = math.sqrt(map_back_3d(x, v, mass, active, u_geo, cellbase, cellxi, h, shape,
                                   p, f, v2, dt, flip, geostatic))
    nodal_velocity_3d(m, v2, fixed, nodes, nact)
    stress_3d(x, v, mass, vol, vol0, stress, eps, be, lam, mu, active, cellbase, cellxi,
              origin, h, shape, v2, dt, geostatic, model, plastic, state, e3, out)
