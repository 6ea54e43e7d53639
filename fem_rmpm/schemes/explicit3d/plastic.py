"""Compiled three-dimensional plastic returns on the elastic log strain of the Hencky
update (:mod:`.elastic`), one branch per material model, reached through
:func:`plastic_return_principal_3d`:

* ``von_mises_softening`` (:mod:`fem_rmpm.materials.von_mises`): yield
  ``sqrt(J2(tau)) <= c``, a radial return in the deviatoric plane of log-strain space,
  ``gamma_p`` the sum of ``sqrt(2 d_eps_p : d_eps_p)``, local softening, linear or
  exponential law.  With ``e`` the deviatoric elastic log strain (six components, tensor
  shear), the trial ``q = sqrt(J2) = sqrt(2) G |e|``; plastic flow along ``e / |e|``
  lowers ``q`` by ``G dgamma``, so the return solves ``q - G dgamma = c(gamma + dgamma)``:
  in closed form for the linear law (on the slope, else at the residual), by Newton for
  the exponential law.
* ``mohr_coulomb_softening`` (:mod:`fem_rmpm.materials.mohr_coulomb`): the plane-strain
  model's own return on three ordered principal log strains
  (:mod:`fem_rmpm.materials.mohr_coulomb_return`, main plane, edges, apex, tension
  cut-off; c, phi and psi softening with ``gamma_p``), called here on the three principal
  values of the 3-D elastic log strain (in plane strain one of them is the out-of-plane
  ``zz``; here any), so both dimensions run the same arithmetic.

A point's parameter row is its 2-D parameter row (:class:`fem_rmpm.materials.MaterialPoints`)
without the two elastic moduli (the step passes Lame's constants): von Mises ``[c_p, c_r,
softening_strain, exponential]`` (kPa, kPa, -, 0 / 1), Mohr-Coulomb ``[c_p, c_r, phi_p,
phi_r, psi_p, psi_r, softening_strain, exponential, tension_cutoff]`` (kPa, kPa, deg,
deg, deg, deg, -, 0 / 1, kPa; inf: no cut-off).
"""
from __future__ import annotations

import math

import numpy as np

from fem_rmpm.materials.mohr_coulomb_return import _principal_return
from fem_rmpm.runtime.compiled import inline, jit

__all__ = ["von_mises_return_3d", "von_mises_points_3d", "plastic_return_principal_3d",
           "plastic_return_points_3d", "MODEL_ELASTIC", "MODEL_VON_MISES",
           "MODEL_MOHR_COULOMB"]

MODEL_ELASTIC = 0
MODEL_VON_MISES = 1
MODEL_MOHR_COULOMB = 2


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
def _mohr_coulomb_principal(e, lam, mu, prow, srow):
    """The Mohr-Coulomb branch of :func:`plastic_return_principal_3d`: ``e`` (3,) sorted
    into ``e1 >= e2 >= e3``, returned by the plane-strain model's principal return
    (bulk modulus ``lam + 2 mu / 3``) and written back into the slots they came from."""
    a, b, c = 0, 1, 2                      # slot of the largest, middle, smallest value
    if e[a] < e[b]:
        a, b = b, a
    if e[b] < e[c]:
        b, c = c, b
    if e[a] < e[b]:
        a, b = b, a
    gn = srow[0]
    n1, n2, n3, gam = _principal_return(
        e[a], e[b], e[c], gn, mu, lam + 2.0 / 3.0 * mu, prow[0], prow[1], prow[2], prow[3],
        prow[4], prow[5], prow[6], prow[7] == 1.0, prow[8])
    e[a], e[b], e[c] = n1, n2, n3
    srow[0] = gam
    return gam - gn


@inline
def plastic_return_principal_3d(model, e, lam, mu, prow, srow):
    """The plastic return of one point on its three principal elastic log strains ``e``
    (3,), in place and in the order given (an isotropic return keeps the principal
    directions), for the point's ``model`` (:data:`MODEL_ELASTIC`: nothing;
    :data:`MODEL_VON_MISES`: the radial return of :func:`von_mises_return_3d`;
    :data:`MODEL_MOHR_COULOMB`: the plane-strain model's principal return), Lame ``lam``,
    ``mu`` (kPa), its parameter row ``prow`` (module docstring) and state row ``srow``
    (von Mises: plastic shear strain and softening variable; Mohr-Coulomb: plastic shear
    strain; updated).  Returns the plastic shear strain increment (0 when elastic).  A
    Mohr-Coulomb return to the apex from an isotropic trial changes ``e`` with a zero
    increment (no deviatoric flow): the caller writes ``e`` back whatever the value.  The
    one entry point of the 3-D step into the materials: a new model is one branch here."""
    if model == MODEL_MOHR_COULOMB:
        return _mohr_coulomb_principal(e, lam, mu, prow, srow)
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


@jit
def plastic_return_points_3d(model, e, lam, mu, prow, state):
    """:func:`plastic_return_principal_3d` on every row of ``e`` (n, 3) in place, with
    the points' ``prow`` (n, P) and ``state`` (n, S) rows (``model``, ``lam``, ``mu`` the
    same for all); returns the increments (n,).  For the tests."""
    out = np.empty(e.shape[0])
    for i in range(e.shape[0]):
        out[i] = plastic_return_principal_3d(model, e[i], lam, mu, prow[i], state[i])
    return out
