"""Test helpers: material points of the two built-in models from per-point arrays, and
the check that the implicit tangent equals the complex step of a model's update.

``vm_points(G, K, cohesion_peak, cohesion_residual, softening_strain, exponential)``
(kPa, kPa, kPa, kPa, -, 0/1): points with an infinite ``cohesion_peak`` are linear elastic,
the others ``von_mises_softening``.  Scenes build their points with
:func:`fem_rmpm.materials.material_points`; the unit tests of the update want arrays.
"""
from __future__ import annotations

import math

import numpy as np

from fem_rmpm import materials
from fem_rmpm.materials import MaterialPoints, model_id, von_mises
from fem_rmpm.schemes.implicit import finite_strain_tangent


def vm_points(shear_modulus, bulk_modulus, cohesion_peak, cohesion_residual,
                     softening_strain, exponential) -> MaterialPoints:
    """:class:`MaterialPoints` (elastic where ``cohesion_peak`` is infinite)."""
    cp = np.asarray(cohesion_peak, float)
    model = np.where(np.isfinite(cp), model_id(von_mises.NAME), model_id("linear_elastic"))
    params = np.stack([np.asarray(a, float) for a in (shear_modulus, bulk_modulus, cp,
                       cohesion_residual, softening_strain, exponential)], axis=1)
    params[~np.isfinite(cp), 2:] = math.nan
    return MaterialPoints(model, params)


def tangents_agree(soil: MaterialPoints, rng, eps_scale: float):
    """Random states of ``soil`` (dF = I + 0.01 N(0, 1), elastic log strain eps_scale
    N(0, 1), zero state): the implicit scheme's tangent
    (:func:`fem_rmpm.schemes.implicit.finite_strain_tangent`) equals the independent complex step
    of the whole update (:func:`fem_rmpm.materials.spatial_tangent`): tau to 1e-12 and A
    to 1e-10 relative.  Returns ``(dF, eps, state, tau)`` for the caller's branch checks."""
    n = len(soil)
    dF = np.eye(2) + 0.01 * rng.normal(size=(n, 2, 2))
    eps = eps_scale * rng.normal(size=(n, 4))
    state = np.zeros((n, 1))
    tau_a, A_a = materials.spatial_tangent(dF, eps, state, soil)
    tau_b, A_b = finite_strain_tangent(dF, eps, state, soil)
    assert np.abs(tau_a - tau_b).max() <= 1e-12 * np.abs(tau_a).max()
    assert np.abs(A_a - A_b).max() <= 1e-10 * np.abs(A_a).max()
    return dF, eps, state, tau_a
