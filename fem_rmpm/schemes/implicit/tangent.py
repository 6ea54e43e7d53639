"""Consistent tangents of the material update at the points (complex step).

The implicit scheme needs, per point, the stress of the trial state and its derivative
with respect to the displacement-increment gradient:

* :func:`small_strain_tangent` for the geostatic (small-strain) step, ``D = d tau / d grad(du)``;
* :func:`finite_strain_tangent` for the large-deformation steps, the spatial tangent
  ``A_ijlm = d tau_ij / d(grad_x du)_lm - delta_jl tau_im`` (material and geometric part).

Both are exact derivatives of the very same update the residual uses, return mapping and
softening branch included, for any registered model; the scheme holds no material
constants.  The model's part, ``D = d tau / d eps_tr`` at the trial log strain
(:func:`trial_stiffness`), comes from the model's optional ``tangent`` hook (an analytic
consistent tangent, e.g. von Mises) or else from the complex step of its numpy ``update``
(which works on complex input).  The kinematics of the finite-strain step (the trial log
strain of ``b_tr = dF b_e dF^T`` and its derivative) and the joining of the pieces are
compiled loops (:mod:`.tangent_kernels`).  :func:`finite_strain_tangent_reference` is the
complex step of the whole update through the model's numpy code, the reference both are
tested against.  ``state`` is the points' state array (n, S) of their models (or the
plastic shear strain (n,)).
"""
from __future__ import annotations

import numpy as np

from fem_rmpm.materials import (
    MaterialPoints,
    exp_sym2,
    log_sym2,
    registry,
    return_map,
    small_strain_update,
)
from fem_rmpm.schemes.implicit import tangent_kernels as tk

__all__ = ["small_strain_tangent", "finite_strain_tangent", "finite_strain_tangent_reference",
           "finite_strain_parts", "trial_stiffness", "elastic_left_cauchy_green", "tensor", "inv2"]

_IN_PLANE = [0, 1, 3]     # trial strain components a plane-strain perturbation moves


def small_strain_tangent(grad_du: np.ndarray, log_strain: np.ndarray, state: np.ndarray,
                         soil: MaterialPoints, step: float = 1e-30, stress: bool = True):
    """Consistent tangent of the small-strain (geostatic) update.

    Returns ``(tau, D)``: ``tau`` (n, 4) [xx, yy, zz, xy] from
    :func:`~fem_rmpm.materials.small_strain_update` and ``D`` (n, 2, 2, 2, 2) with
    ``D_ijlm = d tau_ij / d grad(du)_lm`` (kPa), exact to round-off including the
    return mapping (:func:`trial_stiffness` at the trial strain ``eps + sym(grad du)``).
    ``K_ai,bl = sum_p V_p dN_aj D_ijlm dN_bm``: the same contraction as the
    finite-strain tangent with ``g = dN``.  The update depends on ``sym(grad du)``
    only, so ``D_ij01 = D_ij10``.  ``stress=False``: ``tau`` is None (the caller has
    it from the residual; the update is not run again).
    """
    n = grad_du.shape[0]
    tau = small_strain_update(grad_du, log_strain, state, soil)[2] if stress else None
    e = np.array(log_strain, dtype=float)
    e[:, 0] += grad_du[:, 0, 0]
    e[:, 1] += grad_du[:, 1, 1]
    e[:, 3] += 0.5 * (grad_du[:, 0, 1] + grad_du[:, 1, 0])
    d = trial_stiffness(e, state, soil, step)              # (n, 4, 3)
    D = np.empty((n, 2, 2, 2, 2))
    for k, (l, m, f) in enumerate(((0, 0, 1.0), (1, 1, 1.0), (0, 1, 0.5))):
        D[:, 0, 0, l, m], D[:, 1, 1, l, m] = f * d[:, 0, k], f * d[:, 1, k]
        D[:, 0, 1, l, m] = D[:, 1, 0, l, m] = f * d[:, 3, k]
    D[..., 1, 0] = D[..., 0, 1]
    return tau, D


def trial_stiffness(eps_tr: np.ndarray, state: np.ndarray, soil: MaterialPoints,
                    step: float = 1e-30) -> np.ndarray:
    """``d tau / d eps_tr`` (n, 4, 3) of each point's model update at the trial log
    strain (n, 4) (kPa): rows ``tau [xx, yy, zz, xy]``, columns the in-plane trial
    components ``xx, yy, xy`` (``xy`` a symmetric, tensor perturbation).  A model with
    the ``tangent`` hook gives it analytically; for the others the complex step of their
    ``update`` (:func:`fem_rmpm.materials.return_map`, one call on 3n trial states)."""
    n = len(eps_tr)
    st = state[:, None] if state.ndim == 1 else state
    out = np.empty((n, 4, 3))
    models = soil.model
    ids = models[:1] if n and models.min() == models.max() else np.unique(models)
    for k in ids:
        idx = slice(None) if len(ids) == 1 else np.nonzero(soil.model == k)[0]
        hook = getattr(registry.model(int(k)), "tangent", None)
        if hook is not None:
            if len(ids) == 1:        # one model: its columns straight in (no gathers)
                D = hook(eps_tr, st, soil.params)
                out[:, :, :2] = D[:, :, :2]
                out[:, :, 2] = D[:, :, 3]
            else:
                out[idx] = hook(eps_tr[idx], st[idx], soil.params[idx])[:, :, _IN_PLANE]
            continue
        e, m = eps_tr[idx], len(eps_tr[idx])
        e3 = np.tile(e.astype(complex), (3, 1))
        for j, c in enumerate(_IN_PLANE):
            e3[j * m:(j + 1) * m, c] += 1j * step
        d = _derivatives(e3, st[idx], soil.take(np.arange(n)[idx]), step).reshape(3, m, 4)
        out[idx] = np.transpose(d, (1, 2, 0))
    return out


def model_stiffness(eps_tr: np.ndarray, state: np.ndarray,
                    soil: MaterialPoints) -> tuple[np.ndarray, np.ndarray]:
    """``(D, cols)``: the models' ``d tau / d eps_tr`` at the trial log strain (n, 4) and
    the columns of ``D`` that are the in-plane trial components ``xx, yy, xy``: the
    ``tangent`` hook's (n, 4, 4) as it returns it, ``cols = (0, 1, 3)``, when every point
    has one model with that hook (no column gathers); else :func:`trial_stiffness`,
    ``cols = (0, 1, 2)``."""
    models = soil.model
    if len(eps_tr) and models.min() == models.max():
        hook = getattr(registry.model(int(models[0])), "tangent", None)
        if hook is not None:
            st = state[:, None] if state.ndim == 1 else state
            return hook(eps_tr, st, soil.params), _COLS_HOOK
    return trial_stiffness(eps_tr, state, soil), _COLS_PLANE


_COLS_HOOK, _COLS_PLANE = np.array([0, 1, 3]), np.array([0, 1, 2])


def finite_strain_parts(dF: np.ndarray, log_strain: np.ndarray, state: np.ndarray,
                        soil: MaterialPoints, b_e: np.ndarray):
    """The pieces of :func:`finite_strain_tangent` before they are joined: ``(D, cols,
    J)``, the model stiffness at the trial log strain (:func:`model_stiffness`) and the
    trial Jacobian (n, 3, 3) (:func:`.tangent_kernels.trial_jacobian`); joined with the
    stress by :func:`.tangent_kernels.spatial_tangent` (or straight into the matrix by
    :func:`.tangent_kernels.assemble_spatial_lower`)."""
    n = dF.shape[0]
    eps_tr = np.empty((n, 4))
    eps_tr[:, 2] = log_strain[:, 2]
    eps_tr, J = tk.trial_jacobian(np.ascontiguousarray(dF, dtype=float),
                                  np.ascontiguousarray(b_e, dtype=float), eps_tr,
                                  np.empty((n, 3, 3)))
    D, cols = model_stiffness(eps_tr, state, soil)
    return D, cols, J


def _derivatives(eps_c: np.ndarray, state: np.ndarray, soil: MaterialPoints,
                 step: float) -> np.ndarray:
    """``Im tau(eps_c) / step`` for 3 stacked complex-step perturbations (3n, 4) of the
    trial log strain of n points: the directional derivatives of the Kirchhoff stress,
    through each point's own model update (:func:`fem_rmpm.materials.return_map`, one
    call on the 3n trial states)."""
    n = len(eps_c) // 3
    idx = np.tile(np.arange(n), 3)
    return return_map(eps_c, state[idx] + 0j, soil.take(idx))[2].imag / step


def elastic_left_cauchy_green(log_strain: np.ndarray) -> np.ndarray:
    """``b_e = exp(2 eps_e)`` (n, 2, 2) in-plane, from the stored log strain (n, 4)."""
    bxx, byy, bxy = exp_sym2(log_strain[:, 0], log_strain[:, 1], log_strain[:, 3])
    B = np.empty((len(log_strain), 2, 2))
    B[:, 0, 0], B[:, 1, 1], B[:, 0, 1], B[:, 1, 0] = bxx, byy, bxy, bxy
    return B


def finite_strain_tangent(dF: np.ndarray, log_strain: np.ndarray, state: np.ndarray,
                          soil: MaterialPoints, step: float = 1e-30, b_e: np.ndarray | None = None,
                          tau: np.ndarray | None = None):
    """``(tau, A)`` of the finite-strain update: ``tau`` (n, 4) and the spatial tangent
    ``A_ijlm = d tau_ij / d(grad_x du)_lm - delta_jl tau_im`` (n, 2, 2, 2, 2), kPa.

    A perturbation ``dF -> (I + E) dF`` splits into its symmetric part, which moves the
    trial log strain by ``J E`` (:func:`.tangent_kernels.trial_jacobian`) and the stress
    by ``D J E`` (:func:`trial_stiffness`), and its spin ``W``, whose effect is exact and
    analytic for an isotropic law: ``d tau = W tau - tau W``.  Equal to
    :func:`finite_strain_tangent_reference` (complex step of the whole update) to
    round-off (tested).  Within a Newton step ``b_e`` (:func:`elastic_left_cauchy_green`
    of the step-start strain) and ``tau`` (from the residual evaluation at the same
    ``dF``) may be passed in to save their evaluation.
    """
    n = dF.shape[0]
    B = elastic_left_cauchy_green(log_strain) if b_e is None else b_e
    eps_tr = np.empty((n, 4))
    eps_tr[:, 2] = log_strain[:, 2]
    eps_tr, J = tk.trial_jacobian(np.ascontiguousarray(dF, dtype=float),
                                  np.ascontiguousarray(B, dtype=float), eps_tr,
                                  np.empty((n, 3, 3)))
    if tau is None:
        tau = return_map(eps_tr, state, soil)[2]
    D = trial_stiffness(eps_tr, state, soil, step)
    A = tk.spatial_tangent(D, J, np.ascontiguousarray(tau, dtype=float),
                           np.empty((n, 2, 2, 2, 2)))
    return tau, A


def finite_strain_tangent_reference(dF: np.ndarray, log_strain: np.ndarray, state: np.ndarray,
                          soil: MaterialPoints, step: float = 1e-30, b_e: np.ndarray | None = None,
                          tau: np.ndarray | None = None):
    """Same ``(tau, A)`` as :func:`fem_rmpm.materials.spatial_tangent`, about 3x faster:
    the complex step of the whole update through the models' numpy code (the reference of
    :func:`finite_strain_tangent`).

    ``A_ijlm = d tau_ij / d(grad_x du)_lm - delta_jl tau_im`` where a perturbation
    ``dF -> (I + E) dF`` is split into its symmetric part (three complex-step
    evaluations of the very same trial state and return mapping of
    :mod:`fem_rmpm.materials`, done as one call on 3n points, with the trial
    ``b = (I + i h S) b_tr (I + i h S)`` formed directly) and its spin ``W``,
    whose effect is exact and analytic for this isotropic law:
    ``tau((I + W) dF) = (I + W) tau (I + W)^T``, i.e. ``d tau = W tau - tau W``.
    Equality with ``spatial_tangent`` is tested.  Within a Newton step ``b_e``
    (:func:`elastic_left_cauchy_green` of the step-start strain) and ``tau`` (from the
    residual evaluation at the same ``dF``) may be passed in to save their evaluation.
    """
    n = dF.shape[0]
    B = elastic_left_cauchy_green(log_strain) if b_e is None else b_e
    btr = dF @ B @ np.swapaxes(dF, 1, 2)
    btr = 0.5 * (btr + np.swapaxes(btr, 1, 2))
    if tau is None:
        exx, eyy, exy = log_sym2(btr[:, 0, 0], btr[:, 1, 1], btr[:, 0, 1])
        eps_tr = np.stack([exx, eyy, log_strain[:, 2], exy], axis=1)
        tau = return_map(eps_tr, state, soil)[2]
    b00, b11, b01 = btr[:, 0, 0], btr[:, 1, 1], btr[:, 0, 1]
    # symmetric directions S_00, S_11, (E_01 + E_10)/2: b = b_tr + i h (S b_tr + b_tr S)
    h = 1j * step
    axx, ayy, axy = (np.empty(3 * n, dtype=complex) for _ in range(3))
    axx[:n], ayy[:n], axy[:n] = b00 + 2 * h * b00, b11, b01 + h * b01
    axx[n:2 * n], ayy[n:2 * n], axy[n:2 * n] = b00, b11 + 2 * h * b11, b01 + h * b01
    axx[2 * n:], ayy[2 * n:] = b00 + h * b01, b11 + h * b01
    axy[2 * n:] = b01 + h * 0.5 * (b00 + b11)
    exx, eyy, exy = log_sym2(axx, ayy, axy)
    eps_c = np.empty((3 * n, 4), dtype=complex)
    eps_c[:, 0], eps_c[:, 1], eps_c[:, 3] = exx, eyy, exy
    eps_c[:, 2] = np.tile(log_strain[:, 2], 3)
    d = tensor(_derivatives(eps_c, state, soil, step)).reshape(3, n, 2, 2)
    T = tensor(tau)
    # spin W = (E_01 - E_10)/2: d tau = W tau - tau W = [[t01, (t11-t00)/2], [.., -t01]]
    dW = np.empty((n, 2, 2))
    dW[:, 0, 0], dW[:, 1, 1] = T[:, 0, 1], -T[:, 0, 1]
    dW[:, 0, 1] = dW[:, 1, 0] = 0.5 * (T[:, 1, 1] - T[:, 0, 0])
    A = np.empty((n, 2, 2, 2, 2))
    A[..., 0, 0], A[..., 1, 1] = d[0], d[1]
    A[..., 0, 1], A[..., 1, 0] = d[2] + dW, d[2] - dW
    A[:, :, 0, 0, :] -= T                                     # - delta_jl tau_im
    A[:, :, 1, 1, :] -= T
    return tau, A


def tensor(t4: np.ndarray) -> np.ndarray:
    """(n, 4) [xx, yy, zz, xy] -> (n, 2, 2) in-plane tensor."""
    T = np.empty((len(t4), 2, 2))
    T[:, 0, 0], T[:, 1, 1], T[:, 0, 1], T[:, 1, 0] = t4[:, 0], t4[:, 1], t4[:, 3], t4[:, 3]
    return T


def inv2(M: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Inverse and determinant of (n, 2, 2) matrices."""
    det = M[:, 0, 0] * M[:, 1, 1] - M[:, 0, 1] * M[:, 1, 0]
    inv = np.empty_like(M)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv[:, 0, 0], inv[:, 1, 1] = M[:, 1, 1] / det, M[:, 0, 0] / det
        inv[:, 0, 1], inv[:, 1, 0] = -M[:, 0, 1] / det, -M[:, 1, 0] / det
    return inv, det

