"""Soil at a material point: Hencky elasticity with von Mises cohesion softening.

One finite-strain law serves both the explicit and the implicit scheme:

* **Elasticity (Hencky).**  The state is the elastic logarithmic strain
  ``eps_e = 1/2 ln(b_e)`` (left Cauchy-Green ``b_e``), stored per point as
  ``[xx, yy, zz, xy]`` (tensor, not engineering, shear).  Kirchhoff stress
  ``tau = K tr(eps_e) I + 2 G dev(eps_e)``; Cauchy stress ``sigma = tau / J``.
  Given an increment of deformation gradient ``dF`` (2x2, plane strain so
  ``dF_zz = 1``) the trial state is ``b_tr = dF b_e dF^T`` — a pure rotation
  ``dF = R`` leaves ``tau`` rotated and unchanged in magnitude (objective for any
  rotation size).  For uniaxial compaction with nu = 0 this law gives
  ``tau = E ln(lambda)`` and the closed form of DESIGN section 7.
* **Plasticity (von Mises, undrained shear strength c).**  Yield ``sqrt(J2(tau))
  <= c``.  The return is radial in the deviatoric plane of log-strain space
  (exact for isotropic Hencky elasticity; eigenvectors never needed).
* **Softening.**  ``c`` falls from ``cohesion_peak`` to ``cohesion_residual`` with
  the plastic shear strain invariant ``gamma_p``, linearly (default) reaching the
  residual at ``gamma_p = softening_strain``, or exponentially
  ``c = c_r + (c_p - c_r) exp(-gamma_p / softening_strain)``.

**Plastic shear strain invariant** ``gamma_p = sum over steps of
sqrt(2 d_eps_p : d_eps_p)`` (d_eps_p the plastic log-strain increment).  It is the
work conjugate of ``sqrt(J2)`` (``tau : d_eps_p = c d_gamma_p``) and equals the
engineering plastic shear strain in simple shear.

**Consistent tangent** by complex-step differentiation of the very same update
(:func:`spatial_tangent`): the derivative is exact to round-off (no step-size
error, unlike finite differences), including the return mapping and the branch
of the softening law, so Newton converges quadratically.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["SoilPoints", "kirchhoff_stress", "sqrt_j2", "cohesion", "stress_update",
           "small_strain_update", "return_map",
           "spatial_tangent", "hughes_winget_increment", "exp_sym2", "log_sym2"]

_SMALL = 1e-6   # switch to series below this |x^2|


@dataclass(frozen=True)
class SoilPoints:
    """Material constants per point (arrays of shape (n,)); units kPa and -."""
    shear_modulus: np.ndarray
    bulk_modulus: np.ndarray
    cohesion_peak: np.ndarray           # inf for linear elastic points
    cohesion_residual: np.ndarray
    softening_strain: np.ndarray
    exponential: np.ndarray             # bool: exponential softening law

    def take(self, idx) -> "SoilPoints":
        return SoilPoints(*(getattr(self, f)[idx] for f in self.__dataclass_fields__))


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


# --------------------------------------------------------------- stress and strength
def kirchhoff_stress(eps: np.ndarray, soil: SoilPoints) -> np.ndarray:
    """Kirchhoff stress (n, 4) [xx, yy, zz, xy] (kPa) from elastic log strain (n, 4)."""
    vol = eps[:, 0] + eps[:, 1] + eps[:, 2]
    tau = 2 * soil.shear_modulus[:, None] * eps
    tau[:, :3] += ((soil.bulk_modulus - 2 / 3 * soil.shear_modulus) * vol)[:, None]
    return tau


def sqrt_j2(t: np.ndarray) -> np.ndarray:
    """sqrt(J2) of stresses (n, 4) [xx, yy, zz, xy] (same units as t)."""
    p = (t[:, 0] + t[:, 1] + t[:, 2]) / 3
    sx, sy, sz = t[:, 0] - p, t[:, 1] - p, t[:, 2] - p
    return np.sqrt(0.5 * (sx * sx + sy * sy + sz * sz) + t[:, 3] * t[:, 3])


def cohesion(gamma_p, soil: SoilPoints):
    """Cohesion c(gamma_p) (kPa) and its slope dc/dgamma_p (kPa) per point."""
    cp, cr, gs = soil.cohesion_peak, soil.cohesion_residual, soil.softening_strain
    drop = np.subtract(cp, cr, out=np.zeros(np.shape(cp)), where=np.isfinite(cp))  # elastic: no drop
    decay = np.exp(-gamma_p / gs)
    c_exp, dc_exp = cr + drop * decay, -drop / gs * decay
    on_slope = gamma_p.real < gs
    c_lin = np.where(on_slope, cp - drop * gamma_p / gs, cr)
    dc_lin = np.where(on_slope, -drop / gs, 0.0)
    return (np.where(soil.exponential, c_exp, c_lin), np.where(soil.exponential, dc_exp, dc_lin))


def _plastic_multiplier(q_tr, gamma_p, soil: SoilPoints):
    """Solve sqrt(J2_tr) - G dgamma = c(gamma_p + dgamma) for dgamma >= 0 (plastic points)."""
    G = soil.shear_modulus
    cp, cr, gs = soil.cohesion_peak, soil.cohesion_residual, soil.softening_strain
    # linear law: closed form on the softening branch, then on the residual branch
    h = (cp - cr) / gs
    c0, _ = cohesion(gamma_p, soil)
    d1 = (q_tr - c0) / (G - h)
    on_slope = (gamma_p.real < gs) & ((gamma_p + d1).real <= gs)
    d_lin = np.where(on_slope, d1, (q_tr - cr) / G)
    # exponential law: Newton from the elastic-perfectly-plastic guess (monotone from the right)
    d_exp = (q_tr - c0) / G
    if np.any(soil.exponential):
        for _ in range(40):
            c, dc = cohesion(gamma_p + d_exp, soil)
            r = q_tr - G * d_exp - c
            d_exp = d_exp + r / (G + dc)
    return np.where(soil.exponential, d_exp, d_lin)


def return_map(eps_tr: np.ndarray, gamma_p: np.ndarray, soil: SoilPoints):
    """Radial return of trial log strains (n, 4); returns (eps_e, gamma_p, tau)."""
    tau_tr = kirchhoff_stress(eps_tr, soil)
    q_tr = sqrt_j2(tau_tr)
    c0, _ = cohesion(gamma_p, soil)
    plastic = q_tr.real > c0.real * (1 + 1e-12)
    if not np.any(plastic):
        return eps_tr, gamma_p, tau_tr
    idx = np.nonzero(plastic)[0]
    sp = soil.take(idx)
    dgam = _plastic_multiplier(q_tr[idx], gamma_p[idx], sp)
    scale = 1 - sp.shear_modulus * dgam / q_tr[idx]         # s = s_tr * scale
    e = eps_tr[idx]
    vol3 = (e[:, 0] + e[:, 1] + e[:, 2]) / 3
    dev = e.copy()
    dev[:, :3] -= vol3[:, None]
    e_new = dev * scale[:, None]
    e_new[:, :3] += vol3[:, None]
    eps = eps_tr.copy()
    eps[idx] = e_new
    gam = gamma_p.copy()
    gam[idx] = gamma_p[idx] + dgam
    tau = tau_tr.copy()
    tau[idx] = kirchhoff_stress(e_new, sp)
    return eps, gam, tau


def stress_update(dF: np.ndarray, log_strain: np.ndarray, gamma_p: np.ndarray, soil: SoilPoints):
    """Advance the material state by a deformation-gradient increment.

    Parameters: ``dF`` (n, 2, 2) increment (plane strain), ``log_strain`` (n, 4)
    elastic log strain at the start, ``gamma_p`` (n,) plastic shear strain.
    Returns ``(log_strain, gamma_p, tau)`` with ``tau`` the Kirchhoff stress
    (n, 4) [xx, yy, zz, xy] in kPa.  Works on complex input (complex step).
    """
    bxx, byy, bxy = exp_sym2(log_strain[:, 0], log_strain[:, 1], log_strain[:, 3])
    B = np.empty(dF.shape, dtype=np.result_type(dF, log_strain))
    B[:, 0, 0], B[:, 1, 1], B[:, 0, 1], B[:, 1, 0] = bxx, byy, bxy, bxy
    btr = dF @ B @ np.swapaxes(dF, 1, 2)
    exx, eyy, exy = log_sym2(btr[:, 0, 0], btr[:, 1, 1], 0.5 * (btr[:, 0, 1] + btr[:, 1, 0]))
    eps_tr = np.stack([exx, eyy, log_strain[:, 2] + 0 * exx, exy], axis=1)
    return return_map(eps_tr, gamma_p + 0 * exx, soil)


def small_strain_update(grad_du: np.ndarray, log_strain: np.ndarray, gamma_p: np.ndarray,
                        soil: SoilPoints):
    """Geostatic (small-strain) update: ``eps += sym(grad du)`` on the fixed geometry.

    Same state, same return mapping as :func:`stress_update`; used while gravity
    is applied to the in-situ geometry (points do not move, J = 1).  Returns
    ``(log_strain, gamma_p, tau)``.
    """
    deps = 0.5 * (grad_du + np.swapaxes(grad_du, 1, 2))
    eps_tr = log_strain + np.stack([deps[:, 0, 0], deps[:, 1, 1], 0 * deps[:, 0, 0],
                                    deps[:, 0, 1]], axis=1)
    return return_map(eps_tr, gamma_p + 0 * deps[:, 0, 0], soil)


def spatial_tangent(dF: np.ndarray, log_strain: np.ndarray, gamma_p: np.ndarray,
                    soil: SoilPoints, step: float = 1e-30) -> tuple[np.ndarray, np.ndarray]:
    """Consistent spatial tangent of the Kirchhoff stress, by complex step.

    Returns ``(tau, A)``: ``tau`` (n, 4) and ``A`` (n, 2, 2, 2, 2) with
    ``A_ijlm = d tau_ij / d F_ln F_mn - delta_jl tau_im``, so that the linearised
    internal force of a node pair is ``K_ai,bl = V0 g_a_j A_ijlm g_b_m`` with ``g``
    the spatial shape-function gradients (units kPa).
    """
    n = dF.shape[0]
    _, _, tau = stress_update(dF, log_strain, gamma_p, soil)
    T = np.empty((n, 2, 2))
    T[:, 0, 0], T[:, 1, 1], T[:, 0, 1], T[:, 1, 0] = tau[:, 0], tau[:, 1], tau[:, 3], tau[:, 3]
    A = np.empty((n, 2, 2, 2, 2))
    for l in range(2):
        for m in range(2):
            pert = dF.astype(complex)
            pert[:, l, :] += 1j * step * dF[:, m, :]           # dF + i h E_lm dF
            _, _, tc = stress_update(pert, log_strain, gamma_p, soil)
            d = tc.imag / step
            A[:, 0, 0, l, m], A[:, 1, 1, l, m] = d[:, 0], d[:, 1]
            A[:, 0, 1, l, m] = A[:, 1, 0, l, m] = d[:, 3]
    A -= np.einsum("jl,nim->nijlm", np.eye(2), T)
    return tau, A


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
