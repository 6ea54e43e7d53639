"""Compiled explicit MUSL step on the hexahedral grid: the three-dimensional counterpart of
:mod:`fem_rmpm.schemes.explicit.kernels`, with the same stages and formulas as the
plane-strain reference step (:mod:`fem_rmpm.schemes.explicit.reference`):

1. map to the nodes: mass, momentum and internal force ``-V sigma grad N`` (kN);
2. on the mesh: gravity ``m g``, local (Cundall) damping ``-alpha |f| sign(v)``, fixed
   components at rest, ``v_new = v + dt f / m``;
3. map back: FLIP/PIC point velocity, the point moved with the grid velocity (geostatic:
   its displacement accumulated, the point kept in place), the MUSL re-map of the
   updated momenta, the velocity gradient ``L = sum v_I (x) grad N_I`` and the linear
   elastic stress update (:mod:`.elastic`: small strain in the geostatic phase, else the
   Hughes-Winget increment and the Hencky update), volume ``V J``, Cauchy ``tau V0 / V``.

One serial pass per stage (the scatter in point order, so a run is bitwise the same
whatever the thread setting).  The nodal arrays are cleared at the start of each step.
"""
from __future__ import annotations

import math

import numpy as np

from fem_rmpm.discretise.basis3d import hex8_point
from fem_rmpm.runtime.compiled import jit
from fem_rmpm.schemes.explicit3d.elastic import (
    _compose,
    _elastic_tau,
    _full,
    hencky_elastic_3d,
    small_strain_elastic_3d,
    sym_eig3,
)
from fem_rmpm.schemes.explicit3d.plastic import (
    MODEL_MOHR_COULOMB,
    MODEL_VON_MISES,
    plastic_return_principal_3d,
    von_mises_return_3d,
)

__all__ = ["step_3d", "MASS_TOL", "N_STATS"]

#: Nodes lighter than this (t) carry no velocity (as in the plane-strain step).
MASS_TOL = 1e-14
#: Entries of the stats array a step returns: kinetic energy (kJ), max |v_pic|, max P-wave
#: speed, max |v| (m/s), non-finite points, points outside the grid.
N_STATS = 6


# long function: the stages of one step share the per-point scratch arrays
@jit
def step_3d(x, v, mass, vol, vol0, stress, eps, lam, mu, active, u_geo, cellxi,
            origin, h, shape, fixed, m, p, f, v2, dt, g, damping, flip, geostatic,
            model, plastic, state):
    """One explicit step of ``dt`` s in place on the points (``x``, ``v`` (n, 3) m, m/s;
    ``mass`` t; ``vol``, ``vol0`` m3; ``stress`` Cauchy (n, 6) kPa; ``eps`` elastic log
    strain (n, 6); Lame ``lam``, ``mu`` (n,) kPa; ``active`` (n,); ``u_geo`` (n, 3) m;
    ``cellxi`` (n, 3) scratch; ``model`` (n,) 0 elastic, 1 von Mises, 2 Mohr-Coulomb,
    with the parameter rows ``plastic`` (n, >= 4) and ``state`` rows of
    :mod:`.plastic`) on the grid
    (``origin``, ``h`` (3,) m, ``shape`` (3,) cells, ``fixed`` (nn, 3)) with nodal
    scratch ``m`` (nn,), ``p``, ``f``, ``v2`` (nn, 3), gravity ``g`` (3,) m/s2, damping
    ratio, FLIP fraction; returns :data:`N_STATS` stats."""
    n, nn = x.shape[0], m.shape[0]
    nx, ny, nz = shape[0], shape[1], shape[2]
    hx, hy, hz = h[0], h[1], h[2]
    nodes = np.empty(8, np.int64)
    N = np.empty(8)
    dN = np.empty((8, 3))
    L = np.empty((3, 3))
    dF = np.empty((3, 3))
    A, B, Q = np.empty((3, 3)), np.empty((3, 3)), np.empty((3, 3))
    w, fw, tau = np.empty(3), np.empty(3), np.empty(6)
    m[:] = 0.0
    p[:] = 0.0
    f[:] = 0.0
    # 1. map to the nodes
    for i in range(n):
        if not active[i]:
            continue
        for k in range(3):
            cellxi[i, k] = (x[i, k] - origin[k]) / h[k]
        hex8_point(cellxi[i, 0], cellxi[i, 1], cellxi[i, 2], hx, hy, hz, nx, ny, nz,
                   nodes, N, dN)
        mi, Vi = mass[i], vol[i]
        sxx, syy, szz = stress[i, 0], stress[i, 1], stress[i, 2]
        sxy, syz, sxz = stress[i, 3], stress[i, 4], stress[i, 5]
        for q in range(8):
            a = nodes[q]
            wm = N[q] * mi
            m[a] += wm
            for k in range(3):
                p[a, k] += wm * v[i, k]
            f[a, 0] -= Vi * (sxx * dN[q, 0] + sxy * dN[q, 1] + sxz * dN[q, 2])
            f[a, 1] -= Vi * (sxy * dN[q, 0] + syy * dN[q, 1] + syz * dN[q, 2])
            f[a, 2] -= Vi * (sxz * dN[q, 0] + syz * dN[q, 1] + szz * dN[q, 2])
    # 2. momentum balance on the mesh (f becomes the acceleration, p the old velocity)
    ke = 0.0
    for a in range(nn):
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
    # 3. map back, move, re-map the updated momenta (MUSL) into v2
    vmax2, nbad, nout = 0.0, 0, 0
    for i in range(n):
        if not active[i]:
            continue
        hex8_point(cellxi[i, 0], cellxi[i, 1], cellxi[i, 2], hx, hy, hz, nx, ny, nz,
                   nodes, N, dN)
        for k in range(3):
            vp, ap = 0.0, 0.0
            for q in range(8):
                vp += N[q] * p[nodes[q], k]
                ap += N[q] * f[nodes[q], k]
            v[i, k] = flip * (v[i, k] + dt * ap) + (1.0 - flip) * vp
            if geostatic:
                u_geo[i, k] += dt * vp
            else:
                x[i, k] += dt * vp
            w[k] = vp
        vmax2 = max(vmax2, w[0] * w[0] + w[1] * w[1] + w[2] * w[2])
        for q in range(8):
            wm = N[q] * mass[i]
            for k in range(3):
                v2[nodes[q], k] += wm * v[i, k]
    for a in range(nn):
        inv = 1.0 / m[a] if m[a] > MASS_TOL else 0.0
        for k in range(3):
            v2[a, k] = 0.0 if fixed[a, k] else v2[a, k] * inv
    # velocity gradient and stress
    cmax, pmax2 = 0.0, 0.0
    for i in range(n):
        if not active[i]:
            continue
        hex8_point(cellxi[i, 0], cellxi[i, 1], cellxi[i, 2], hx, hy, hz, nx, ny, nz,
                   nodes, N, dN)
        for r in range(3):
            for c in range(3):
                s = 0.0
                for q in range(8):
                    s += v2[nodes[q], r] * dN[q, c]
                L[r, c] = s
        for k in range(6):
            tau[k] = 0.0
        if geostatic:
            small_strain_elastic_3d(L, dt, eps[i], lam[i], mu[i], tau)
            J = 1.0
        else:
            # Hughes-Winget: dF = (I - L dt / 2)^-1 (I + L dt / 2)
            for r in range(3):
                for c in range(3):
                    A[r, c] = (1.0 if r == c else 0.0) - 0.5 * dt * L[r, c]
                    B[r, c] = (1.0 if r == c else 0.0) + 0.5 * dt * L[r, c]
            _solve3(A, B, dF)
            J = (dF[0, 0] * (dF[1, 1] * dF[2, 2] - dF[1, 2] * dF[2, 1])
                 - dF[0, 1] * (dF[1, 0] * dF[2, 2] - dF[1, 2] * dF[2, 0])
                 + dF[0, 2] * (dF[1, 0] * dF[2, 1] - dF[1, 1] * dF[2, 0]))
            hencky_elastic_3d(dF, eps[i], lam[i], mu[i], tau, A, B, Q, w, fw)
        if model[i] == MODEL_VON_MISES:
            dg = von_mises_return_3d(eps[i], mu[i], plastic[i, 0], plastic[i, 1],
                                     plastic[i, 2], plastic[i, 3] != 0.0, state[i, 0])
            if dg > 0.0:
                state[i, 0] += dg
                state[i, 1] = state[i, 0]
                _elastic_tau(eps[i], lam[i], mu[i], tau)
        elif model[i] == MODEL_MOHR_COULOMB:     # on the principal values, co-axial
            _full(eps[i], A)
            sym_eig3(A, w, Q)
            fw[0], fw[1], fw[2] = w[0], w[1], w[2]
            plastic_return_principal_3d(MODEL_MOHR_COULOMB, w, lam[i], mu[i], plastic[i],
                                        state[i])
            if w[0] != fw[0] or w[1] != fw[1] or w[2] != fw[2]:
                _compose(Q, w, eps[i])
                _elastic_tau(eps[i], lam[i], mu[i], tau)
        vol[i] *= J
        ratio = vol0[i] / vol[i]
        ok = True
        for k in range(6):
            stress[i, k] = tau[k] * ratio
            ok &= math.isfinite(stress[i, k])
        for k in range(3):
            ok &= math.isfinite(x[i, k]) and math.isfinite(v[i, k])
            s = (x[i, k] - origin[k]) / h[k]
            if s < 0.0 or s > shape[k]:
                nout += 1
                break
        if not ok:
            nbad += 1
        rho = mass[i] / vol[i]
        cmax = max(cmax, math.sqrt((lam[i] + 2.0 * mu[i]) / rho))
        pmax2 = max(pmax2, v[i, 0] * v[i, 0] + v[i, 1] * v[i, 1] + v[i, 2] * v[i, 2])
    out = np.empty(N_STATS)
    out[0], out[1], out[2] = ke, math.sqrt(vmax2), cmax
    out[3], out[4], out[5] = math.sqrt(pmax2), nbad, nout
    return out


@jit
def _solve3(A, B, X):
    """X = A^-1 B for 3x3 matrices (Cramer's rule, A close to the identity)."""
    det = (A[0, 0] * (A[1, 1] * A[2, 2] - A[1, 2] * A[2, 1])
           - A[0, 1] * (A[1, 0] * A[2, 2] - A[1, 2] * A[2, 0])
           + A[0, 2] * (A[1, 0] * A[2, 1] - A[1, 1] * A[2, 0]))
    inv = 1.0 / det
    C00 = (A[1, 1] * A[2, 2] - A[1, 2] * A[2, 1]) * inv
    C01 = (A[0, 2] * A[2, 1] - A[0, 1] * A[2, 2]) * inv
    C02 = (A[0, 1] * A[1, 2] - A[0, 2] * A[1, 1]) * inv
    C10 = (A[1, 2] * A[2, 0] - A[1, 0] * A[2, 2]) * inv
    C11 = (A[0, 0] * A[2, 2] - A[0, 2] * A[2, 0]) * inv
    C12 = (A[0, 2] * A[1, 0] - A[0, 0] * A[1, 2]) * inv
    C20 = (A[1, 0] * A[2, 1] - A[1, 1] * A[2, 0]) * inv
    C21 = (A[0, 1] * A[2, 0] - A[0, 0] * A[2, 1]) * inv
    C22 = (A[0, 0] * A[1, 1] - A[0, 1] * A[1, 0]) * inv
    for c in range(3):
        b0, b1, b2 = B[0, c], B[1, c], B[2, c]
        X[0, c] = C00 * b0 + C01 * b1 + C02 * b2
        X[1, c] = C10 * b0 + C11 * b1 + C12 * b2
        X[2, c] = C20 * b0 + C21 * b1 + C22 * b2
