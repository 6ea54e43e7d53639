"""Compiled three-dimensional von Mises return with cohesion softening, on the elastic
log strain of the Hencky update (:mod:`.elastic`): the model ``von_mises_softening`` of
:mod:`fem_rmpm.materials.von_mises` (yield ``sqrt(J2(tau)) <= c``, a radial return in the
deviatoric plane of log-strain space, ``gamma_p`` the sum of ``sqrt(2 d_eps_p : d_eps_p)``),
local softening, linear or exponential law.

With ``e`` the deviatoric elastic log strain (six components, tensor shear), the trial
``q = sqrt(J2) = sqrt(2) G |e|``; plastic flow along ``e / |e|`` lowers ``q`` by ``G dgamma``,
so the return solves ``q - G dgamma = c(gamma + dgamma)``: in closed form for the linear
law (on the slope, else at the residual), by Newton for the exponential law.
"""
from __future__ import annotations

import math

import numpy as np

from fem_rmpm.runtime.compiled import inline, jit

__all__ = ["von_mises_return_3d", "von_mises_points_3d", "plastic_return_principal_3d",
           "MODEL_ELASTIC", "MODEL_VON_MISES"]

MODEL_ELASTIC = 0
MODEL_VON_MISES = 1


@inline
def _cohesion(gamma, cp, cr, gs, expo):
    """c(gamma) (kPa) and dc/dgamma (kPa)."""
    if expo:
        decay = math.exp(-gamma / gs)
        return cr + (cp - cr) * decay, -(cp - cr) / gs * decay
    if gamma < gs:
        return cp - (cp - cr) * gamma / gs, -(cp - cr) / gs
    return cr, 0.0


@inline
def von_mises_return_3d(eps, G, cp, cr, gs, expo, gamma):
    """Return the trial elastic log strain ``eps`` (6,) in place onto the yield surface;
    returns the plastic shear strain increment (0 when elastic).  ``gamma`` the plastic
    shear strain so far, ``cp``, ``cr`` peak and residual cohesion (kPa), ``gs`` the
    softening strain, ``expo`` the exponential law."""
    mean = (eps[0] + eps[1] + eps[2]) / 3.0
    d0, d1, d2 = eps[0] - mean, eps[1] - mean, eps[2] - mean
    norm = math.sqrt(d0 * d0 + d1 * d1 + d2 * d2
                     + 2.0 * (eps[3] * eps[3] + eps[4] * eps[4] + eps[5] * eps[5]))
    q = math.sqrt(2.0) * G * norm
    c, dc = _cohesion(gamma, cp, cr, gs, expo)
    if q <= c:
        return 0.0
    if not expo:
        dg = (q - c) / (G + dc)                    # dc = -h on the slope
        if gamma < gs < gamma + dg:                # the residual is reached in this step
            dg = (q - cr) / G
    else:
        dg = 0.0
        for _ in range(50):
            c, dc = _cohesion(gamma + dg, cp, cr, gs, expo)
            r = q - G * dg - c
            step = r / (G + dc)
            dg += step
            if abs(step) <= 1e-14 * (1.0 + dg):
                break
    scale = (q - G * dg) / q
    eps[0] = mean + d0 * scale
    eps[1] = mean + d1 * scale
    eps[2] = mean + d2 * scale
    for m in range(3, 6):
        eps[m] *= scale
    return dg


@jit
def von_mises_points_3d(eps, G, cp, cr, gs, expo, gamma):
    """:func:`von_mises_return_3d` on every row of ``eps`` (n, 6) in place (scalars the
    same for all; ``gamma`` (n,)); returns the increments (n,).  For the tests."""
    out = np.empty(eps.shape[0])
    for i in range(eps.shape[0]):
        out[i] = von_mises_return_3d(eps[i], G, cp, cr, gs, expo, gamma[i])
    return out


@inline
def plastic_return_principal_3d(model, e, lam, mu, prow, srow):
    """The plastic return of one point on its three principal elastic log strains ``e``
    (3,), in place and in the order given (an isotropic return keeps the principal
    directions), for the point's ``model`` (:data:`MODEL_ELASTIC`: nothing;
    :data:`MODEL_VON_MISES`: :func:`von_mises_return_3d`), Lame ``lam``, ``mu`` (kPa), its
    parameter row ``prow`` (peak and residual cohesion kPa, softening strain, exponential
    law) and state row ``srow`` (plastic shear strain, softening variable; updated).
    Returns the plastic shear strain increment (0 when elastic).  The one entry point of
    the 3-D step into the materials: a new model is one branch here."""
    if model != MODEL_VON_MISES:
        return 0.0
    mean = (e[0] + e[1] + e[2]) / 3.0
    d0, d1, d2 = e[0] - mean, e[1] - mean, e[2] - mean
    q = math.sqrt(2.0) * mu * math.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
    cp, cr, gs, expo = prow[0], prow[1], prow[2], prow[3] != 0.0
    gamma = srow[0]
    c, dc = _cohesion(gamma, cp, cr, gs, expo)
    if q <= c:
        return 0.0
    if not expo:
        dg = (q - c) / (mu + dc)
        if gamma < gs < gamma + dg:
            dg = (q - cr) / mu
    else:
        dg = 0.0
        for _ in range(50):
            c, dc = _cohesion(gamma + dg, cp, cr, gs, expo)
            step = (q - mu * dg - c) / (mu + dc)
            dg += step
            if abs(step) <= 1e-14 * (1.0 + dg):
                break
    scale = (q - mu * dg) / q
    e[0] = mean + d0 * scale
    e[1] = mean + d1 * scale
    e[2] = mean + d2 * scale
    srow[0] = gamma + dg
    srow[1] = srow[0]
    return dg
