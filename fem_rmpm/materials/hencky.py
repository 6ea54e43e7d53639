"""Finite-strain kinematics every model shares, and the per-model numpy update.

* **Elasticity (Hencky).**  The state is the elastic logarithmic strain
  ``eps_e = 1/2 ln(b_e)`` (left Cauchy-Green ``b_e``), stored per point as
  ``[xx, yy, zz, xy]`` (tensor, not engineering, shear).  Kirchhoff stress
  ``tau = K tr(eps_e) I + 2 G dev(eps_e)``; Cauchy stress ``sigma = tau / J``.
  Given an increment of deformation gradient ``dF`` (2x2, plane strain so
  ``dF_zz = 1``) the trial state is ``b_tr = dF b_e dF^T`` — a pure rotation
  ``dF = R`` leaves ``tau`` rotated and unchanged in magnitude (objective for any
  rotation size).  For uniaxial compaction with nu = 0 this law gives
  ``tau = E ln(lambda)``.
* **Return mapping** in log-strain space: each model's ``update`` (see
  :mod:`.protocol`) maps the trial log strain to the returned one; for an isotropic
  model the principal directions do not change, so eigenvectors are never needed.
* **Consistent tangent** by complex-step differentiation of the very same update
  (:func:`spatial_tangent`): exact to round-off (no step-size error, unlike finite
  differences), including the return mapping and the branch of a softening law.

``state`` may be given as (n, S) or, for the plastic shear strain alone, as (n,); it
comes back in the same shape.
"""
from __future__ import annotations

import numpy as np

from fem_rmpm.materials import registry
from fem_rmpm.materials.protocol import MaterialPoints

__all__ = ["exp_sym2", "log_sym2", "hughes_winget_increment", "hencky_stress",
           "kirchhoff_stress", "sqrt_j2", "return_map", "stress_update", "small_strain_update",
           "spatial_tangent"]

_SMALL = 1e-6   # switch to series below this |x^2|


# --------------------------------------------------------------- 2x2 matrix functions
def _atanh_x_over_x(x2):
    """atanh(x)/x as a function of x^2 (analytic, also for complex x^2)."""
    small = np.abs(x2) < _SMALL
    x = np.sqrt(np.where(small, 0.25, x2))
    full = np.arctanh(x) / x
    series = 1 + x2 / 3 + x2 ** 2 / 5 + x2 ** 3 / 7
    return np.where(small, series, full)


def _sinh_y_over_y(y2):
    """sinh(y)/y as a function of y^2."""
    small = np.abs(y2) < _SMALL
    y = np.sqrt(np.where(small, 0.25, y2))
    full = np.sinh(y) / y
    series = 1 + y2 / 6 + y2 ** 2 / 120 + y2 ** 3 / 5040
    return np.where(small, series, full)


def log_sym2(axx, ayy, axy):
    """``1/2 ln(A)`` of symmetric positive-definite 2x2 matrices, componentwise arrays.

    Uses ``A = m I + D`` (m the mean eigenvalue, D traceless): no eigenvectors,
    smooth through repeated eigenvalues, valid for complex perturbations.
    """
    m = 0.5 * (axx + ayy)
    d = 0.5 * (axx - ayy)
    r2 = d * d + axy * axy
    lp_lm = 0.25 * np.log(m * m - r2)                       # 1/2 * mean of ln(m +- r)
    g = 0.5 * _atanh_x_over_x(r2 / (m * m)) / m            # 1/2 (ln(m+r) - ln(m-r)) / (2r)
    return lp_lm + g * d, lp_lm - g * d, g * axy


def exp_sym2(exx, eyy, exy):
    """``exp(2 E)`` of symmetric 2x2 matrices, componentwise arrays."""
    m = 0.5 * (exx + eyy)
    d = 0.5 * (exx - eyy)
    r2 = d * d + exy * exy
    e2m = np.exp(2 * m)
    ch = np.cosh(2 * np.sqrt(r2))
    g = 2 * e2m * _sinh_y_over_y(4 * r2)                    # (e^{2(m+r)} - e^{2(m-r)}) / (2r)
    c = e2m * ch
    return c + g * d, c - g * d, g * exy


def hughes_winget_increment(L: np.ndarray, dt: float) -> np.ndarray:
    """Incremental deformation gradient from a velocity gradient (n, 2, 2) over ``dt``.

    ``dF = (I - L dt/2)^-1 (I + L dt/2)``: second-order accurate and exactly
    orthogonal for a pure spin, so rigid rotations of any size create no stress.
    """
    eye = np.eye(2)
    a = eye + 0.5 * dt * L
    b = eye - 0.5 * dt * L
    det = b[:, 0, 0] * b[:, 1, 1] - b[:, 0, 1] * b[:, 1, 0]
    binv = np.empty_like(b)
    binv[:, 0, 0], binv[:, 1, 1] = b[:, 1, 1] / det, b[:, 0, 0] / det
    binv[:, 0, 1], binv[:, 1, 0] = -b[:, 0, 1] / det, -b[:, 1, 0] / det
    return binv @ a


# --------------------------------------------------------------- stress
def hencky_stress(eps: np.ndarray, G, K) -> np.ndarray:
    """Kirchhoff stress (n, 4) [xx, yy, zz, xy] (kPa) from elastic log strain (n, 4),
    shear and bulk modulus ``G``, ``K`` (n,) in kPa."""
    vol = eps[:, 0] + eps[:, 1] + eps[:, 2]
    tau = 2 * G[:, None] * eps
    tau[:, :3] += ((K - 2 / 3 * G) * vol)[:, None]
    return tau


def kirchhoff_stress(eps: np.ndarray, soil: MaterialPoints) -> np.ndarray:
    """The elastic (Hencky) Kirchhoff stress (n, 4) of ``soil`` at log strain ``eps``."""
    return hencky_stress(eps, soil.params[:, 0], soil.params[:, 1])


def sqrt_j2(t: np.ndarray) -> np.ndarray:
    """sqrt(J2) of stresses (n, 4) [xx, yy, zz, xy] (same units as t)."""
    p = (t[:, 0] + t[:, 1] + t[:, 2]) / 3
    sx, sy, sz = t[:, 0] - p, t[:, 1] - p, t[:, 2] - p
    return np.sqrt(0.5 * (sx * sx + sy * sy + sz * sz) + t[:, 3] * t[:, 3])


# --------------------------------------------------------------- update through the models
def return_map(eps_tr: np.ndarray, state: np.ndarray, soil: MaterialPoints):
    """Each point's model update (its ``update``) of trial log strains (n, 4);
    returns ``(eps_e, state, tau)``.  Works on complex input (complex step)."""
    flat = state.ndim == 1
    st = state[:, None] if flat else state
    ids = np.unique(soil.model)
    if len(ids) == 1:
        eps, st, tau = registry.model(int(ids[0])).update(eps_tr, st, soil.params)
    else:
        dtype = np.result_type(eps_tr, st)
        eps, tau = np.empty(eps_tr.shape, dtype), np.empty(eps_tr.shape, dtype)
        st_new = np.empty(st.shape, dtype)
        for k in ids:
            idx = np.nonzero(soil.model == k)[0]
            eps[idx], st_new[idx], tau[idx] = registry.model(int(k)).update(
                eps_tr[idx], st[idx], soil.params[idx])
        st = st_new
    return eps, (st[:, 0] if flat else st), tau


def stress_update(dF: np.ndarray, log_strain: np.ndarray, state: np.ndarray,
                  soil: MaterialPoints):
    """Advance the material state by a deformation-gradient increment.

    Parameters: ``dF`` (n, 2, 2) increment (plane strain), ``log_strain`` (n, 4)
    elastic log strain at the start, ``state`` (n, S) or the plastic shear strain (n,).
    Returns ``(log_strain, state, tau)`` with ``tau`` the Kirchhoff stress
    (n, 4) [xx, yy, zz, xy] in kPa.  Works on complex input (complex step).
    """
    bxx, byy, bxy = exp_sym2(log_strain[:, 0], log_strain[:, 1], log_strain[:, 3])
    B = np.empty(dF.shape, dtype=np.result_type(dF, log_strain))
    B[:, 0, 0], B[:, 1, 1], B[:, 0, 1], B[:, 1, 0] = bxx, byy, bxy, bxy
    btr = dF @ B @ np.swapaxes(dF, 1, 2)
    exx, eyy, exy = log_sym2(btr[:, 0, 0], btr[:, 1, 1], 0.5 * (btr[:, 0, 1] + btr[:, 1, 0]))
    eps_tr = np.stack([exx, eyy, log_strain[:, 2] + 0 * exx, exy], axis=1)
    zero = 0 * exx if state.ndim == 1 else 0 * exx[:, None]
    return return_map(eps_tr, state + zero, soil)


def small_strain_update(grad_du: np.ndarray, log_strain: np.ndarray, state: np.ndarray,
                        soil: MaterialPoints):
    """Geostatic (small-strain) update: ``eps += sym(grad du)`` on the fixed geometry.

    Same state, same return mapping as :func:`stress_update`; used while gravity
    is applied to the in-situ geometry (points do not move, J = 1).  Returns
    ``(log_strain, state, tau)``.
    """
    deps = 0.5 * (grad_du + np.swapaxes(grad_du, 1, 2))
    eps_tr = log_strain + np.stack([deps[:, 0, 0], deps[:, 1, 1], 0 * deps[:, 0, 0],
                                    deps[:, 0, 1]], axis=1)
    zero = 0 * deps[:, 0, 0] if state.ndim == 1 else 0 * deps[:, 0, 0][:, None]
    return return_map(eps_tr, state + zero, soil)


def spatial_tangent(dF: np.ndarray, log_strain: np.ndarray, state: np.ndarray,
                    soil: MaterialPoints, step: float = 1e-30) -> tuple[np.ndarray, np.ndarray]:
    """Consistent spatial tangent of the Kirchhoff stress, by complex step.

    Returns ``(tau, A)``: ``tau`` (n, 4) and ``A`` (n, 2, 2, 2, 2) with
    ``A_ijlm = d tau_ij / d F_ln F_mn - delta_jl tau_im``, so that the linearised
    internal force of a node pair is ``K_ai,bl = V0 g_a_j A_ijlm g_b_m`` with ``g``
    the spatial shape-function gradients (units kPa).
    """
    n = dF.shape[0]
    _, _, tau = stress_update(dF, log_strain, state, soil)
    T = np.empty((n, 2, 2))
    T[:, 0, 0], T[:, 1, 1], T[:, 0, 1], T[:, 1, 0] = tau[:, 0], tau[:, 1], tau[:, 3], tau[:, 3]
    A = np.empty((n, 2, 2, 2, 2))
    for l in range(2):
        for m in range(2):
            pert = dF.astype(complex)
            pert[:, l, :] += 1j * step * dF[:, m, :]           # dF + i h E_lm dF
            _, _, tc = stress_update(pert, log_strain, state, soil)
            d = tc.imag / step
            A[:, 0, 0, l, m], A[:, 1, 1, l, m] = d[:, 0], d[:, 1]
            A[:, 0, 1, l, m] = A[:, 1, 0, l, m] = d[:, 3]
    A -= np.einsum("jl,nim->nijlm", np.eye(2), T)
    return tau, A
