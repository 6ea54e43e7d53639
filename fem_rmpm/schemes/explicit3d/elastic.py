"""Compiled three-dimensional elastic kinematics: a closed-form symmetric 3x3
eigen-decomposition, the small-strain update (the geostatic phase) and the finite-strain
Hencky update with one eigen-decomposition per point-step.

Tensors are six components ``[xx, yy, zz, xy, yz, xz]`` (the VTK order of the point
files); strains hold tensor (not engineering) shear components.

**Finite strain** (Simo 1992, the 3-D form of :mod:`fem_rmpm.materials.hencky`): the
point keeps its elastic left Cauchy-Green tensor ``b = exp(2 eps)`` beside the elastic log
strain ``eps``.  A step takes the trial ``b_tr = dF b dF^T``, its eigen-decomposition
``b_tr = sum_k lambda_k n_k n_k^T`` and the principal log strains ``e_k = ln(lambda_k) / 2``;
the plastic return works on ``e`` (an isotropic return keeps the ``n_k``); then
``eps = sum_k e_k n_k n_k^T``, ``b = sum_k exp(2 e_k) n_k n_k^T`` (``b_tr`` itself when the
step is elastic) and the Kirchhoff stress ``tau = lam tr(eps) I + 2 mu eps`` (kPa).

**Eigen-decomposition** (:func:`sym_eig3`).  With ``q = tr(A) / 3`` and
``p = sqrt(|A - q I|^2 / 6)``, ``C = (A - q I) / p`` has eigenvalues
``beta = 2 cos(phi + 2 pi k / 3)``, ``cos(3 phi) = det(C) / 2`` (the trigonometric solution
of the characteristic cubic ``beta^3 - 3 beta = det(C)``, Smith 1961, Commun. ACM 4(4)
168).  Near a repeated eigenvalue that cubic fixes the two close roots only to the square
root of the round-off, so only the root farthest from the other two is taken from it
(the largest when ``det(C) >= 0``, else the smallest: at least sqrt(3) from the others,
a simple root), evaluated without acos / cos: a degree-5 polynomial fit of
``2 cos(acos(h) / 3)`` on ``h = |det(C)| / 2`` in [0, 1], then one Halley step on the
cubic, to round-off; its eigenvector is the largest cross product of two rows of
``C - beta I``.  The other two eigenpairs are those of the 2x2 matrix of ``C`` on an
orthonormal basis ``U, V`` of the plane normal to it, in closed form (exact for 2x2, no
cancellation): the split of the eigenvector computation of Eberly (2014, "A robust
eigensolver for 3x3 symmetric matrices", Geometric Tools), with the pair solved as a 2x2
problem so that equal and nearly equal eigenvalues keep full accuracy.  The eigenvectors
are orthonormal to round-off whatever the multiplicity.  ``tests/test_3d_elastic.py``
checks eigenvalues and the reconstructed tensor against ``numpy.linalg.eigh`` on random,
near-degenerate and exactly degenerate matrices.
"""
from __future__ import annotations

import math

import numpy as np

from fem_rmpm.runtime.compiled import assume_columns, inline, jit

__all__ = ["sym_eig3", "sym_eig3_block", "eig_blocks", "EIG_BLOCK", "compose_sym3",
           "small_strain_elastic_3d", "elastic_tau_3d",
           "spectral_3d", "stretch_from_log_strain"]

#: 2 cos(acos(h) / 3), the largest root of beta^3 - 3 beta = 2 h, for h in [0, 1]: the
#: degree-5 Chebyshev fit as a polynomial in 2 h - 1 (error < 2.6e-6, then one Halley
#: step: < 3e-16).
_R0, _R1, _R2 = 1.8793845685812673, 0.13164429558895394, -0.012848881368903284
_R3, _R4, _R5 = 0.002207275400202328, -0.0005080406809108717, 0.00012269865821269124
_THIRD, _SIXTH = 1.0 / 3.0, 1.0 / 6.0       # (multiplications: a division is ~13 cycles)


@inline
def _pair(m00, m01, m11):
    """Eigenvalues ``mu0 >= mu1`` and the unit eigenvector ``(c, s)`` of ``mu0`` of the
    symmetric 2x2 [[m00, m01], [m01, m11]] (that of ``mu1`` is ``(-s, c)``): with
    ``d = (m00 - m11) / 2`` and ``r = sqrt(d^2 + m01^2)``, the eigenvector is
    ``(d + r, m01)`` for ``d >= 0``, else ``(m01, r - d)``, both free of cancellation;
    ``(1, 0)`` when ``r = 0``.  Branch-free (each case computed, then selected), so that a
    loop over points of it vectorizes (:func:`sym_eig3`)."""
    d = 0.5 * (m00 - m11)
    mean = 0.5 * (m00 + m11)
    r = math.sqrt(d * d + m01 * m01)
    zero = r == 0.0
    pos = d >= 0.0
    dr, rd = d + r, r - d
    x = dr if pos else m01
    y = m01 if pos else rd
    nrm = x * x + y * y
    inv = 1.0 / math.sqrt(1.0 if zero else nrm)
    cx, sy = x * inv, y * inv
    return mean + r, mean - r, 1.0 if zero else cx, 0.0 if zero else sy


# long function: the closed form written out on scalars (no arrays, nothing allocated)
@inline
def sym_eig3(a00, a11, a22, a01, a12, a02):
    """Eigenvalues ``l0, l1, l2`` and unit eigenvectors ``(x0, y0, z0)``, ``(x1, ...)``,
    ``(x2, ...)`` of the symmetric 3x3 with entries ``a..`` (module docstring), as a tuple
    of 12 floats ``(l0, l1, l2, x0, y0, z0, x1, y1, z1, x2, y2, z2)``; unordered.  A
    multiple of the identity (or NaN) gives ``q, q, q`` and the unit axes.  Branch-free:
    every case is computed and the results selected, so that a loop of it over points
    vectorizes (:func:`sym_eig3_block`)."""
    q = (a00 + a11 + a22) * _THIRD
    b00, b11, b22 = a00 - q, a11 - q, a22 - q
    p2 = (b00 * b00 + b11 * b11 + b22 * b22
          + 2.0 * (a01 * a01 + a12 * a12 + a02 * a02)) * _SIXTH
    iso = not p2 > 1e-300                    # a multiple of the identity (or NaN)
    p = math.sqrt(1.0 if iso else p2)
    inv = 1.0 / p
    c00, c11, c22 = b00 * inv, b11 * inv, b22 * inv
    c01, c12, c02 = a01 * inv, a12 * inv, a02 * inv
    half_det = 0.5 * (c00 * (c11 * c22 - c12 * c12) - c01 * (c01 * c22 - c12 * c02)
                      + c02 * (c01 * c12 - c11 * c02))
    h = min(abs(half_det), 1.0)
    x = 2.0 * h - 1.0
    beta = _R0 + x * (_R1 + x * (_R2 + x * (_R3 + x * (_R4 + x * _R5))))
    f = beta * beta * beta - 3.0 * beta - 2.0 * h           # one Halley step
    fp = 3.0 * beta * beta - 3.0
    beta -= 2.0 * f * fp / (2.0 * fp * fp - 6.0 * f * beta)
    beta = -beta if half_det < 0.0 else beta
    # the isolated root's eigenvector n: the largest cross product of rows of C - beta I
    r00, r11, r22 = c00 - beta, c11 - beta, c22 - beta
    ux, uy, uz = c01 * c12 - c02 * r11, c02 * c01 - r00 * c12, r00 * r11 - c01 * c01
    vx, vy, vz = c01 * r22 - c02 * c12, c02 * c02 - r00 * r22, r00 * c12 - c01 * c02
    wx, wy, wz = r11 * r22 - c12 * c12, c12 * c02 - c01 * r22, c01 * c12 - r11 * c02
    du = ux * ux + uy * uy + uz * uz
    dv = vx * vx + vy * vy + vz * vz
    dw = wx * wx + wy * wy + wz * wz
    take_v = (dv > du) & (dv >= dw)
    take_w = (dw > du) & ~take_v
    ux = vx if take_v else (wx if take_w else ux)
    uy = vy if take_v else (wy if take_w else uy)
    uz = vz if take_v else (wz if take_w else uz)
    du = dv if take_v else (dw if take_w else du)
    # a unit U normal to n (from n's unnormalised components), V = n x U
    along_x = abs(ux) > abs(uy)
    t = ux if along_x else uy
    s = 1.0 / math.sqrt(t * t + uz * uz)
    mzs, xs, zs, mys = -uz * s, ux * s, uz * s, -uy * s
    ex = mzs if along_x else 0.0
    ey = 0.0 if along_x else zs
    ez = xs if along_x else mys
    s = 1.0 / math.sqrt(du)
    nx, ny, nz = ux * s, uy * s, uz * s
    fx, fy, fz = ny * ez - nz * ey, nz * ex - nx * ez, nx * ey - ny * ex
    # the 2x2 matrix of C on (U, V) and its eigenpairs
    cux = c00 * ex + c01 * ey + c02 * ez
    cuy = c01 * ex + c11 * ey + c12 * ez
    cuz = c02 * ex + c12 * ey + c22 * ez
    cvx = c00 * fx + c01 * fy + c02 * fz
    cvy = c01 * fx + c11 * fy + c12 * fz
    cvz = c02 * fx + c12 * fy + c22 * fz
    m00 = ex * cux + ey * cuy + ez * cuz
    m01 = fx * cux + fy * cuy + fz * cuz
    m11 = fx * cvx + fy * cvy + fz * cvz
    mu0, mu1, c, s = _pair(m00, m01, m11)
    if iso:
        return q, q, q, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0
    return (q + p * beta, q + p * mu0, q + p * mu1, nx, ny, nz,
            c * ex + s * fx, c * ey + s * fy, c * ez + s * fz,
            c * fx - s * ex, c * fy - s * ey, c * fz - s * ez)


#: Points per block of :func:`sym_eig3_block` (a whole number of 8-wide vectors).
EIG_BLOCK = 64


@inline
def sym_eig3_block(blk):
    """:func:`sym_eig3` of the :data:`EIG_BLOCK` tensors in the columns of rows 0-5 of
    ``blk`` (rows >= 18, EIG_BLOCK) (``xx, yy, zz, xy, yz, xz``) into rows 6-17 (the tuple of
    :func:`sym_eig3`).  A loop of fixed length with no branch over one array whose rows
    have a fixed length, so LLVM proves its loads and stores independent and vectorizes
    it over the points (8 points per AVX-512 instruction): the same IEEE operations on
    each point as one at a time (square root and division are correctly rounded in both),
    so the same results bit for bit (``tests/test_3d_elastic.py``), at a fifth of the
    cost.  Columns holding no point may hold anything (a NaN stays in its column)."""
    assume_columns(blk, EIG_BLOCK)
    for j in range(EIG_BLOCK):
        r = sym_eig3(blk[0, j], blk[1, j], blk[2, j], blk[3, j], blk[4, j], blk[5, j])
        blk[6, j], blk[7, j], blk[8, j], blk[9, j] = r[0], r[1], r[2], r[3]
        blk[10, j], blk[11, j], blk[12, j], blk[13, j] = r[4], r[5], r[6], r[7]
        blk[14, j], blk[15, j], blk[16, j], blk[17, j] = r[8], r[9], r[10], r[11]


@jit
def eig_blocks(a6: np.ndarray) -> np.ndarray:
    """Test hook: :func:`sym_eig3_block` on the rows of ``a6`` (n, 6), in blocks; the
    results (n, 12) in the order of :func:`sym_eig3`."""
    n = a6.shape[0]
    out = np.empty((n, 12))
    blk = np.zeros((20, EIG_BLOCK))
    for s in range(0, n, EIG_BLOCK):
        m = min(EIG_BLOCK, n - s)
        for j in range(m):
            for k in range(6):
                blk[k, j] = a6[s + j, k]
        sym_eig3_block(blk)
        for j in range(m):
            for k in range(12):
                out[s + j, k] = blk[6 + k, j]
    return out


@inline
def compose_sym3(f0, f1, f2, x0, y0, z0, x1, y1, z1, x2, y2, z2, out, i):
    """``out[i]`` (six components) = sum_k f_k n_k n_k^T with ``n_k = (x_k, y_k, z_k)``."""
    out[i, 0] = f0 * x0 * x0 + f1 * x1 * x1 + f2 * x2 * x2
    out[i, 1] = f0 * y0 * y0 + f1 * y1 * y1 + f2 * y2 * y2
    out[i, 2] = f0 * z0 * z0 + f1 * z1 * z1 + f2 * z2 * z2
    out[i, 3] = f0 * x0 * y0 + f1 * x1 * y1 + f2 * x2 * y2
    out[i, 4] = f0 * y0 * z0 + f1 * y1 * z1 + f2 * y2 * z2
    out[i, 5] = f0 * x0 * z0 + f1 * x1 * z1 + f2 * x2 * z2


@inline
def elastic_tau_3d(eps, i, lam, mu, tau, j):
    """``tau[j]`` (6,) kPa = lam tr(eps[i]) I + 2 mu eps[i] (Hencky, Kirchhoff)."""
    tr = eps[i, 0] + eps[i, 1] + eps[i, 2]
    for m in range(6):
        tau[j, m] = 2.0 * mu * eps[i, m] + (lam * tr if m < 3 else 0.0)


@inline
def small_strain_elastic_3d(l00, l01, l02, l10, l11, l12, l20, l21, l22, dt, eps, i):
    """Geostatic step: ``eps[i] += sym(L) dt`` (L in 1/s, row-major entries ``l..``)."""
    eps[i, 0] += l00 * dt
    eps[i, 1] += l11 * dt
    eps[i, 2] += l22 * dt
    eps[i, 3] += 0.5 * (l01 + l10) * dt
    eps[i, 4] += 0.5 * (l12 + l21) * dt
    eps[i, 5] += 0.5 * (l02 + l20) * dt


@jit
def stretch_from_log_strain(eps: np.ndarray, b: np.ndarray) -> None:
    """``b[i] = exp(2 eps[i])`` (six components) for every row of ``eps`` (n, 6): the
    elastic left Cauchy-Green tensor the finite-strain step keeps, at the start of a run
    and after the geostatic phase (which updates ``eps`` alone)."""
    for i in range(eps.shape[0]):
        r = sym_eig3(eps[i, 0], eps[i, 1], eps[i, 2], eps[i, 3], eps[i, 4], eps[i, 5])
        compose_sym3(math.exp(2.0 * r[0]), math.exp(2.0 * r[1]), math.exp(2.0 * r[2]),
                     r[3], r[4], r[5], r[6], r[7], r[8], r[9], r[10], r[11], b, i)


@jit
def spectral_3d(v6: np.ndarray, kind: int) -> np.ndarray:
    """Test hook: eigenvalues (kind 0), the six components of exp (1) / log (2) of the
    symmetric tensor ``v6`` (6,), or (kind 3) the eigenvectors as the rows of a (3, 3)
    array, flattened."""
    r = sym_eig3(v6[0], v6[1], v6[2], v6[3], v6[4], v6[5])
    if kind == 0:
        return np.array([r[0], r[1], r[2]])
    if kind == 3:
        return np.array([r[3], r[4], r[5], r[6], r[7], r[8], r[9], r[10], r[11]])
    out = np.empty((1, 6))
    if kind == 1:
        compose_sym3(math.exp(r[0]), math.exp(r[1]), math.exp(r[2]), r[3], r[4], r[5], r[6],
                     r[7], r[8], r[9], r[10], r[11], out, 0)
    else:
        compose_sym3(math.log(r[0]), math.log(r[1]), math.log(r[2]), r[3], r[4], r[5], r[6],
                     r[7], r[8], r[9], r[10], r[11], out, 0)
    return out[0]
