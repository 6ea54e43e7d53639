"""The finite-strain update of a block of points in the stress pass
(:func:`.stress3d.stress_3d`): after the block's trial stretches and eigen-decompositions,
the principal log strains, the plastic return, the new log strain, stretch and
Kirchhoff stress of every point of the block, in five loops over its columns:

1. the three logarithms of every point, vectorized (:func:`.logexp.log_near_one`; the
   library's outside its range), then, point by point, the return of a point whose
   model has no vectorized form (Mohr-Coulomb, von Mises with the exponential law:
   :func:`.plastic.plastic_return_principal_3d`);
2. (vectorized) the radial return of every von Mises point with the linear softening law,
   without a branch: each case is computed and the results selected;
3. (vectorized) the exponentials of the principal log strains (:func:`.logexp.exp_small`;
   the library's outside its range), used where the return moved the point;
4. (vectorized) the new log strain and stretch ``sum_k f_k n_k n_k^T``, the Kirchhoff
   stress ``lam tr(eps) I + 2 mu eps``
   with volume ``V J``, Cauchy stress ``tau V0 / V`` and squared P-wave speed;
5. (point by point) the point rows written back and the checks.

Loops 1-4 run over all :data:`.elastic.EIG_BLOCK` columns with no branch, so LLVM
vectorizes them (8 points per AVX-512 instruction).  Every point goes through the IEEE
operations of the one-point update (:func:`.stress3d.stress_points_3d`, the reference of
``tests/test_3d_stress_block.py``) in the same order, square root and division correctly
rounded in both, nothing fused, except the logarithms and exponentials: the series of
:mod:`.logexp` are within one unit in the last place of the correctly rounded values, as
the library calls of the reference, so the two agree within round-off (3e-15 of each
array's largest value after three passes; 7e-16 reached).
"""
from __future__ import annotations

import math

from fem_rmpm.runtime.compiled import assume_columns, inline
from fem_rmpm.schemes.explicit3d.elastic import EIG_BLOCK
from fem_rmpm.schemes.explicit3d.logexp import exp_in_range, exp_small, log_in_range, log_near_one
from fem_rmpm.schemes.explicit3d.plastic import (
    MODEL_ELASTIC,
    MODEL_VON_MISES,
    plastic_return_principal_3d,
)

__all__ = ["BLOCK_ROWS", "gather_material", "finite_strain_block", "R_J", "R_TAU", "R_VOL",
           "R_MASS"]

# Rows of the block (one column per point), :func:`.stress3d.stress_3d`:
#: b, then the trial b_tr, then the new b (0-5)
R_B = 0
#: eigenvalues of b_tr, then the principal log strains, then the returned ones (6-8);
#: the eigenvectors (9-17)
R_EIG = 6
#: det dF
R_J = 18
#: the velocity gradient (19-27), then the new log strain (19-24)
R_L = 19
R_EPS = 19
#: Lame's constants (kPa); von Mises c_p, c_r (kPa), softening strain, plastic shear strain
R_LAM, R_MU, R_CP, R_CR, R_GS, R_GAMMA = 28, 29, 30, 31, 32, 33
#: the point's return: 0 none (elastic), 1 the vectorized von Mises return (3 after it
#: yielded), 2 a return point by point (loop 1)
R_KIND = 34
#: 1 when the return moved the point's log strain (its b is recomposed), else 0
R_RET = 35
#: exp(2 e_k) of a returned point (36-38)
R_EXP = 36
#: the Kirchhoff stress, then the Cauchy stress (39-44, kPa)
R_TAU = 39
#: the point's volume (m3), then the new one; its initial volume (m3); its mass (t), then
#: its squared P-wave speed (m2/s2)
R_VOL, R_VOL0, R_MASS = 45, 46, 47
#: Rows of the stress pass's block.
BLOCK_ROWS = 48

KIND_NONE, KIND_VECTOR, KIND_POINT, KIND_YIELDED = 0.0, 1.0, 2.0, 3.0


@inline
def gather_material(i, j, blk, lam, mu, model, plastic, state, vol, vol0, mass):
    """Column ``j`` of ``blk``: point ``i``'s Lame constants, von Mises parameters,
    plastic shear strain, the kind of its return, volumes and mass (the row comments
    above)."""
    m = model[i]
    blk[R_LAM, j] = lam[i]
    blk[R_MU, j] = mu[i]
    blk[R_VOL, j] = vol[i]
    blk[R_VOL0, j] = vol0[i]
    blk[R_MASS, j] = mass[i]
    if m == MODEL_VON_MISES and plastic[i, 3] == 0.0:
        blk[R_CP, j] = plastic[i, 0]
        blk[R_CR, j] = plastic[i, 1]
        blk[R_GS, j] = plastic[i, 2]
        blk[R_GAMMA, j] = state[i, 0]
        blk[R_KIND, j] = KIND_VECTOR
    else:
        blk[R_KIND, j] = KIND_NONE if m == MODEL_ELASTIC else KIND_POINT
    blk[R_RET, j] = 0.0


@inline
def _logs_block(blk):
    """Loop 1a: ``e_k = ln(lambda_k) / 2`` of every column in rows 6-8 (the eigenvalues
    kept in rows 36-38 for loop 1b) by :func:`.logexp.log_near_one`, vectorized; returns
    the count of eigenvalues outside its range."""
    assume_columns(blk, EIG_BLOCK)
    nout = 0
    for j in range(EIG_BLOCK):
        for k in range(3):
            x = blk[R_EIG + k, j]
            blk[R_EXP + k, j] = x
            blk[R_EIG + k, j] = 0.5 * log_near_one(x)
            nout += 0 if log_in_range(x) else 1
    return nout


@inline
def _logs_and_point_returns(nb, blk, idx, lam, mu, model, plastic, state, e3, nout):
    """Loop 1b: the library logarithm of the ``nout`` eigenvalues outside the range of
    :func:`.logexp.log_near_one`; the point-by-point returns."""
    if nout:
        for j in range(nb):
            for k in range(3):
                x = blk[R_EXP + k, j]
                if not log_in_range(x):
                    blk[R_EIG + k, j] = 0.5 * math.log(x)
    for j in range(nb):
        if blk[R_KIND, j] == KIND_POINT:
            e0, e1, e2 = blk[R_EIG, j], blk[R_EIG + 1, j], blk[R_EIG + 2, j]
            i = idx[j]
            e3[0], e3[1], e3[2] = e0, e1, e2
            dg = plastic_return_principal_3d(model[i], e3, lam[i], mu[i], plastic[i], state[i])
            # a Mohr-Coulomb return to the apex moves e3 with a zero shear increment
            ret = dg > 0.0 or e3[0] != e0 or e3[1] != e1 or e3[2] != e2
            blk[R_RET, j] = 1.0 if ret else 0.0
            blk[R_EIG, j], blk[R_EIG + 1, j], blk[R_EIG + 2, j] = e3[0], e3[1], e3[2]


@inline
def _von_mises_block(blk):
    """Loop 2: the radial return of :func:`.plastic.plastic_return_principal_3d` (von
    Mises, linear softening law) on every column of kind 1, branch-free: the cohesion on
    the slope or at the residual, the closed-form increment and its correction when the
    residual is reached within the step, the scaled deviator; the kind becomes 3 where
    the point yielded, its new plastic shear strain in row 33."""
    assume_columns(blk, EIG_BLOCK)
    for j in range(EIG_BLOCK):
        e0, e1, e2 = blk[R_EIG, j], blk[R_EIG + 1, j], blk[R_EIG + 2, j]
        mu, cp, cr = blk[R_MU, j], blk[R_CP, j], blk[R_CR, j]
        gs, gamma = blk[R_GS, j], blk[R_GAMMA, j]
        mean = (e0 + e1 + e2) / 3.0
        d0, d1, d2 = e0 - mean, e1 - mean, e2 - mean
        q = math.sqrt(2.0) * mu * math.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
        slope = gamma < gs
        c_slope, dc_slope = cp - (cp - cr) * gamma / gs, -(cp - cr) / gs
        c = c_slope if slope else cr
        dc = dc_slope if slope else 0.0
        dg = (q - c) / (mu + dc)
        dg_res = (q - cr) / mu
        dg = dg_res if (gamma < gs) & (gs < gamma + dg) else dg
        scale = (q - mu * dg) / q
        n0, n1, n2 = mean + d0 * scale, mean + d1 * scale, mean + d2 * scale
        yld = (blk[R_KIND, j] == KIND_VECTOR) & ~(q <= c)
        moved = (dg > 0.0) | (n0 != e0) | (n1 != e1) | (n2 != e2)
        blk[R_EIG, j] = n0 if yld else e0
        blk[R_EIG + 1, j] = n1 if yld else e1
        blk[R_EIG + 2, j] = n2 if yld else e2
        blk[R_RET, j] = 1.0 if (yld & moved) else blk[R_RET, j]
        blk[R_GAMMA, j] = gamma + dg if yld else gamma
        blk[R_KIND, j] = KIND_YIELDED if yld else blk[R_KIND, j]


@inline
def _exponentials(nb, blk):
    """Loop 3: ``exp(2 e_k)`` into rows 36-38 of every column by
    :func:`.logexp.exp_small`, vectorized (used where the return moved the point), then
    the library exponential of a returned point's value outside its range."""
    assume_columns(blk, EIG_BLOCK)
    nout = 0
    for j in range(EIG_BLOCK):
        for k in range(3):
            y = 2.0 * blk[R_EIG + k, j]
            blk[R_EXP + k, j] = exp_small(y)
            nout += 0 if exp_in_range(y) else 1
    if nout:
        for j in range(nb):
            for k in range(3):
                y = 2.0 * blk[R_EIG + k, j]
                if blk[R_RET, j] != 0.0 and not exp_in_range(y):
                    blk[R_EXP + k, j] = math.exp(y)


@inline
def _compose(f0, f1, f2, x0, y0, z0, x1, y1, z1, x2, y2, z2):
    """``sum_k f_k n_k n_k^T`` (six components), the arithmetic of
    :func:`.elastic.compose_sym3`."""
    return (f0 * x0 * x0 + f1 * x1 * x1 + f2 * x2 * x2,
            f0 * y0 * y0 + f1 * y1 * y1 + f2 * y2 * y2,
            f0 * z0 * z0 + f1 * z1 * z1 + f2 * z2 * z2,
            f0 * x0 * y0 + f1 * x1 * y1 + f2 * x2 * y2,
            f0 * y0 * z0 + f1 * y1 * z1 + f2 * y2 * z2,
            f0 * x0 * z0 + f1 * x1 * z1 + f2 * x2 * z2)


@inline
def _compose_block(blk):
    """Loop 4: the new log strain (rows 19-24), stretch (rows 0-5: recomposed where the
    return moved the point, else b_tr as it is), volume ``V J`` (row 45), Cauchy stress
    ``tau V0 / V`` (rows 39-44, kPa) and squared P-wave speed ``(lam + 2 mu) V / m``
    (row 47, m2/s2)."""
    assume_columns(blk, EIG_BLOCK)
    for j in range(EIG_BLOCK):
        x0, y0, z0 = blk[R_EIG + 3, j], blk[R_EIG + 4, j], blk[R_EIG + 5, j]
        x1, y1, z1 = blk[R_EIG + 6, j], blk[R_EIG + 7, j], blk[R_EIG + 8, j]
        x2, y2, z2 = blk[R_EIG + 9, j], blk[R_EIG + 10, j], blk[R_EIG + 11, j]
        eps = _compose(blk[R_EIG, j], blk[R_EIG + 1, j], blk[R_EIG + 2, j],
                       x0, y0, z0, x1, y1, z1, x2, y2, z2)
        b = _compose(blk[R_EXP, j], blk[R_EXP + 1, j], blk[R_EXP + 2, j],
                     x0, y0, z0, x1, y1, z1, x2, y2, z2)
        ret = blk[R_RET, j] != 0.0
        two_mu, lam = 2.0 * blk[R_MU, j], blk[R_LAM, j]
        tr = eps[0] + eps[1] + eps[2]
        vol = blk[R_VOL, j] * blk[R_J, j]
        ratio = blk[R_VOL0, j] / vol
        for k in range(6):
            blk[R_EPS + k, j] = eps[k]
            blk[R_B + k, j] = b[k] if ret else blk[R_B + k, j]
            blk[R_TAU + k, j] = (two_mu * eps[k] + (lam * tr if k < 3 else 0.0)) * ratio
        blk[R_VOL, j] = vol
        blk[R_MASS, j] = (lam + 2.0 * blk[R_MU, j]) * vol / blk[R_MASS, j]


@inline
def finite_strain_block(nb, blk, idx, eps, be, lam, mu, model, plastic, state, e3):
    """Loops 1-4 (module docstring) on the first ``nb`` columns of ``blk`` (points
    ``idx[:nb]``), whose trial stretches (rows 0-5), eigen-decompositions (6-17) and
    material (28-35, :func:`gather_material`) are set; writes each point's ``eps``,
    ``be`` and plastic state.  The Cauchy stress, volume and squared P-wave speed are
    left in rows 39-47 for the caller (loop 5)."""
    nout = _logs_block(blk)
    _logs_and_point_returns(nb, blk, idx, lam, mu, model, plastic, state, e3, nout)
    _von_mises_block(blk)
    _exponentials(nb, blk)
    _compose_block(blk)
    for j in range(nb):
        i = idx[j]
        for k in range(6):
            eps[i, k] = blk[R_EPS + k, j]
            be[i, k] = blk[R_B + k, j]
        if blk[R_KIND, j] == KIND_YIELDED:
            state[i, 0] = blk[R_GAMMA, j]
            state[i, 1] = state[i, 0]
