"""The stress pass of the three-dimensional explicit step (stage 4 of
:mod:`.kernels`) on a range of points: the velocity gradient ``L = sum v_I (x) grad N_I``
from the nodal velocities, the stress update (small strain in the geostatic phase; else
the Hughes-Winget increment and the Hencky update with one eigen-decomposition,
:mod:`.elastic`), the plastic return on the principal elastic log strains
(:func:`.plastic.plastic_return_principal_3d`), volume ``V J``, Cauchy ``tau V0 / V`` and
the maxima the time loop needs.  Every point is independent of the others: the two halves
of the points run on two threads with the same arithmetic as on one (:mod:`.step`).
"""
from __future__ import annotations

import math

import numpy as np

from fem_rmpm.runtime.compiled import assume_columns, inline, jit, kernel
from fem_rmpm.schemes.explicit3d.elastic import (
    compose_sym3,
    elastic_tau_3d,
    small_strain_elastic_3d,
    EIG_BLOCK,
    sym_eig3,
    sym_eig3_block,
)
from fem_rmpm.schemes.explicit3d.finite_block import (
    BLOCK_ROWS,
    R_MASS,
    R_TAU,
    R_VOL,
    finite_strain_block,
    gather_material,
)
from fem_rmpm.schemes.explicit3d.plastic import MODEL_ELASTIC, plastic_return_principal_3d
from fem_rmpm.schemes.explicit3d.rows import row_diffs4

__all__ = ["stress_3d", "stress_points_3d", "BLOCK_ROWS"]


@inline
def _gradient_row(v2, k, base, sy, sz, a, b, c, ihx, ihy, ihz):
    """Row ``k - 1`` of the velocity gradient ``sum_I v_I (x) grad N_I`` (1/s) from column
    ``k`` of the nodal rows ``v2`` (velocity component ``k - 1``, m/s), in the factored
    form of the trilinear gradient: along x the differences of the cell's four x-edges
    weighted by the bilinear (y, z) values, and likewise along y and z."""
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
def _hencky_trial(dF, b00, b11, b22, b01, b12, b02):
    """The trial ``b_tr = dF b dF^T`` (six components) from ``dF`` (9-tuple) and the
    point's ``b`` (six components)."""
    f00, f01, f02, f10, f11, f12, f20, f21, f22 = dF
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
def _finite_strain(i, j, blk, be, eps, lam, mu, model, plastic, state, e3):
    """Hencky update and plastic return of point ``i`` from its trial ``b_tr`` (rows
    0-5 of column ``j`` of ``blk``) and that tensor's eigen-decomposition (rows 6-17,
    :func:`.elastic.sym_eig3_block`), :mod:`.elastic`: ``eps[i]`` and ``be[i]`` updated,
    the plastic shear strain increment returned."""
    e3[0] = 0.5 * math.log(blk[6, j])
    e3[1] = 0.5 * math.log(blk[7, j])
    e3[2] = 0.5 * math.log(blk[8, j])
    x0, y0, z0, x1, y1, z1 = blk[9, j], blk[10, j], blk[11, j], blk[12, j], blk[13, j], blk[14, j]
    x2, y2, z2 = blk[15, j], blk[16, j], blk[17, j]
    dg, returned = 0.0, False
    if model[i] != MODEL_ELASTIC:
        l0, l1, l2 = e3[0], e3[1], e3[2]
        dg = plastic_return_principal_3d(model[i], e3, lam[i], mu[i], plastic[i], state[i])
        # a Mohr-Coulomb return to the apex moves e3 with a zero shear increment
        returned = dg > 0.0 or e3[0] != l0 or e3[1] != l1 or e3[2] != l2
    compose_sym3(e3[0], e3[1], e3[2], x0, y0, z0, x1, y1, z1, x2, y2, z2, eps, i)
    if returned:
        compose_sym3(math.exp(2.0 * e3[0]), math.exp(2.0 * e3[1]), math.exp(2.0 * e3[2]),
                     x0, y0, z0, x1, y1, z1, x2, y2, z2, be, i)
    else:
        for k in range(6):
            be[i, k] = blk[k, j]
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


@inline
def _gradient_scalar(node, i, cellbase, cellxi, sy, sz, ihx, ihy, ihz):
    """:func:`_gradient` one component at a time (the reference's)."""
    base, a, b, c = cellbase[i], cellxi[i, 0], cellxi[i, 1], cellxi[i, 2]
    l00, l01, l02 = _gradient_row(node, 1, base, sy, sz, a, b, c, ihx, ihy, ihz)
    l10, l11, l12 = _gradient_row(node, 2, base, sy, sz, a, b, c, ihx, ihy, ihz)
    l20, l21, l22 = _gradient_row(node, 3, base, sy, sz, a, b, c, ihx, ihy, ihz)
    return l00, l01, l02, l10, l11, l12, l20, l21, l22


@inline
def _gradient(node, i, cellbase, cellxi, sy, sz, ihx, ihy, ihz):
    """The velocity gradient at point ``i`` (9 entries, row-major, 1/s): the arithmetic
    of :func:`_gradient_row` on the three velocity components at once, as 8-wide vectors
    over the nodal rows (:func:`.rows.row_diffs4`; component ``k`` in lane ``k + 1``)."""
    base, a, b, c = cellbase[i], cellxi[i, 0], cellxi[i, 1], cellxi[i, 2]
    a0, b0, c0 = 1.0 - a, 1.0 - b, 1.0 - c
    n000, n100, n010, n110 = base, base + 1, base + sy, base + sy + 1
    n001, n101, n011, n111 = base + sz, base + sz + 1, base + sz + sy, base + sz + sy + 1
    gx = row_diffs4(node, (n100, n110, n101, n111), (n000, n010, n001, n011),
                    (b0 * c0, b * c0, b0 * c, b * c))
    gy = row_diffs4(node, (n010, n110, n011, n111), (n000, n100, n001, n101),
                    (a0 * c0, a * c0, a0 * c, a * c))
    gz = row_diffs4(node, (n001, n101, n011, n111), (n000, n100, n010, n110),
                    (a0 * b0, a * b0, a0 * b, a * b))
    return (gx[1] * ihx, gy[1] * ihy, gz[1] * ihz, gx[2] * ihx, gy[2] * ihy, gz[2] * ihz,
            gx[3] * ihx, gy[3] * ihy, gz[3] * ihz)


@inline
def _gather_block(start, hi, node, active, be, cellbase, cellxi, sy, sz, ihx, ihy, ihz,
                  blk, idx, lam, mu, model, plastic, state, vol, vol0, mass):
    """The next block of at most :data:`.elastic.EIG_BLOCK` active points from ``start``:
    their indices in ``idx``, ``b`` (rows 0-5) and velocity gradient (rows 19-27) in the
    columns of ``blk``; returns (points in the block, the point after it)."""
    nb, i = 0, start
    while i < hi and nb < EIG_BLOCK:
        if active[i]:
            L = _gradient(node, i, cellbase, cellxi, sy, sz, ihx, ihy, ihz)
            for k in range(9):
                blk[19 + k, nb] = L[k]
            for k in range(6):
                blk[k, nb] = be[i, k]
            gather_material(i, nb, blk, lam, mu, model, plastic, state, vol, vol0, mass)
            idx[nb] = i
            nb += 1
        i += 1
    return nb, i


@inline
def _trial_block(blk, dt):
    """Per column of ``blk`` (:data:`BLOCK_ROWS`, EIG_BLOCK): the Hughes-Winget ``dF`` of
    the gradient (rows 19-27), ``det dF`` into row 18 and the trial ``dF b dF^T`` over
    ``b`` (rows 0-5); a fixed-length loop with no branch, vectorized like
    :func:`.elastic.sym_eig3_block` (the same bits as point by point)."""
    assume_columns(blk, EIG_BLOCK)
    for j in range(EIG_BLOCK):
        hw = _hughes_winget(blk[19, j], blk[20, j], blk[21, j], blk[22, j], blk[23, j],
                            blk[24, j], blk[25, j], blk[26, j], blk[27, j], dt)
        bt = _hencky_trial(hw[:9], blk[0, j], blk[1, j], blk[2, j], blk[3, j], blk[4, j],
                           blk[5, j])
        blk[0, j], blk[1, j], blk[2, j], blk[3, j], blk[4, j], blk[5, j] = bt
        blk[18, j] = hw[9]


@inline
def _stress_and_checks(i, J, mass, vol, vol0, stress, lam, mu, acc):
    """Volume, Cauchy stress of point ``i`` (from the Kirchhoff stress in ``stress[i]``)
    and its part of the maxima and counts ``acc`` (:func:`_stress_checks`)."""
    vol[i] *= J
    ratio = vol0[i] / vol[i]
    ok = True
    for k in range(6):
        stress[i, k] *= ratio
        ok &= math.isfinite(stress[i, k])
    c2 = (lam[i] + 2.0 * mu[i]) * vol[i] / mass[i]
    return _stress_checks(ok, c2, acc)


@inline
def _stress_checks(ok, c2, acc):
    """A point's part of the pass's largest squared P-wave speed and count of non-finite
    stresses ``acc`` (c2max, nbad): ``ok`` its stress is finite, ``c2`` its squared
    P-wave speed (m2/s2)."""
    return max(acc[0], c2), acc[1] + (0 if ok else 1)


@inline
def _write_and_check(i, j, blk, vol, stress, acc):
    """Point ``i``'s Cauchy stress and volume from column ``j`` of the block and its part
    of the maxima and counts ``acc`` (:func:`_stress_checks`)."""
    ok = True
    for k in range(6):
        stress[i, k] = blk[R_TAU + k, j]
        ok &= math.isfinite(stress[i, k])
    vol[i] = blk[R_VOL, j]
    return _stress_checks(ok, blk[R_MASS, j], acc)


@inline
def _pass_frame(h, shape):
    """Node strides and inverse cell sizes (1/m)."""
    sy, sz = shape[0] + 1, (shape[0] + 1) * (shape[1] + 1)
    return sy, sz, 1.0 / h[0], 1.0 / h[1], 1.0 / h[2]


@inline
def _geostatic_pass(mass, vol, vol0, stress, eps, lam, mu, active, cellbase, cellxi, node,
                    lo, hi, dt, model, plastic, state, e3, frame):
    """The geostatic (small-strain) update of the active points ``lo:hi``, point by
    point; the maxima and counts (:func:`_stress_and_checks`)."""
    sy, sz, ihx, ihy, ihz = frame
    acc = (0.0, 0)
    for i in range(lo, hi):
        if active[i]:
            L = _gradient(node, i, cellbase, cellxi, sy, sz, ihx, ihy, ihz)
            _small_strain(i, L, dt, eps, lam, mu, model, plastic, state, e3)
            elastic_tau_3d(eps, i, lam[i], mu[i], stress, i)
            acc = _stress_and_checks(i, 1.0, mass, vol, vol0, stress, lam, mu, acc)
    return acc


# long function: the stress pass's loops (geostatic, then finite strain in blocks)
@kernel
def stress_3d(mass, vol, vol0, stress, eps, be, lam, mu, active, cellbase, cellxi, h, shape,
              node, lo, hi, dt, geostatic, model, plastic, state, e3, blk, idx, stats):
    """Stage 4 (module docstring) on the active points ``lo:hi``, with the nodal
    velocities in columns 1-3 of ``node`` (nn, 8); scratch ``e3`` (3,), ``blk``
    (:data:`BLOCK_ROWS`, B), ``idx`` (B,); sets ``stats[0]`` to the largest squared P-wave
    speed (m2/s2) and adds the count of points with a non-finite stress to ``stats[2]``
    (the map back checks positions and velocities, :func:`.kernels.map_back_3d`).  The
    finite-strain update runs in blocks of B points: the trial tensors of the block and
    their eigen-decompositions in vectorized loops (:func:`.elastic.sym_eig3_block`), the
    logarithms, von Mises returns, exponentials, new tensors and Cauchy stress of
    :func:`.finite_block.finite_strain_block`, then the points' rows written back and
    checked; :func:`stress_points_3d` within round-off (its logarithms and exponentials
    are the library's, :mod:`.finite_block`)."""
    assume_columns(node, 8)
    assume_columns(blk, EIG_BLOCK)
    frame = _pass_frame(h, shape)
    sy, sz, ihx, ihy, ihz = frame
    if geostatic:
        acc = _geostatic_pass(mass, vol, vol0, stress, eps, lam, mu, active, cellbase,
                              cellxi, node, lo, hi, dt, model, plastic, state, e3, frame)
    else:
        acc = (0.0, 0)
        i = lo
        while i < hi:
            nb, i = _gather_block(i, hi, node, active, be, cellbase, cellxi, sy, sz, ihx,
                                  ihy, ihz, blk, idx, lam, mu, model, plastic, state, vol,
                                  vol0, mass)
            _trial_block(blk, dt)
            sym_eig3_block(blk)
            finite_strain_block(nb, blk, idx, eps, be, lam, mu, model, plastic, state, e3)
            for j in range(nb):
                acc = _write_and_check(idx[j], j, blk, vol, stress, acc)
    stats[0] = acc[0]
    stats[2] += acc[1]


@jit
def stress_points_3d(mass, vol, vol0, stress, eps, be, lam, mu, active, cellbase, cellxi, h,
                     shape, node, lo, hi, dt, geostatic, model, plastic, state, stats):
    """:func:`stress_3d` one point at a time (the same arguments without the scratch):
    gradient, trial stretch, :func:`.elastic.sym_eig3`, logarithms, return
    (:func:`.plastic.plastic_return_principal_3d`), new tensors, volume, Cauchy stress.
    The reference of the blocked pass (``tests/test_3d_stress_block.py``), with the
    library's logarithm and exponential."""
    frame = _pass_frame(h, shape)
    sy, sz, ihx, ihy, ihz = frame
    e3 = np.zeros(3)
    if geostatic:
        acc = _geostatic_pass(mass, vol, vol0, stress, eps, lam, mu, active, cellbase,
                              cellxi, node, lo, hi, dt, model, plastic, state, e3, frame)
    else:
        acc = (0.0, 0)
        one = np.zeros((18, 1))
        for i in range(lo, hi):
            if not active[i]:
                continue
            L = _gradient_scalar(node, i, cellbase, cellxi, sy, sz, ihx, ihy, ihz)
            hw = _hughes_winget(L[0], L[1], L[2], L[3], L[4], L[5], L[6], L[7], L[8], dt)
            bt = _hencky_trial(hw[:9], be[i, 0], be[i, 1], be[i, 2], be[i, 3], be[i, 4],
                               be[i, 5])
            r = sym_eig3(bt[0], bt[1], bt[2], bt[3], bt[4], bt[5])
            for k in range(6):
                one[k, 0] = bt[k]
            for k in range(12):
                one[6 + k, 0] = r[k]
            _finite_strain(i, 0, one, be, eps, lam, mu, model, plastic, state, e3)
            elastic_tau_3d(eps, i, lam[i], mu[i], stress, i)
            acc = _stress_and_checks(i, hw[9], mass, vol, vol0, stress, lam, mu, acc)
    stats[0] = acc[0]
    stats[2] += acc[1]
