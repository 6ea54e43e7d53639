"""Test helper: material points of the two built-in models from per-point arrays.

``vm_points(G, K, cohesion_peak, cohesion_residual, softening_strain, exponential)``
(kPa, kPa, kPa, kPa, -, 0/1): points with an infinite ``cohesion_peak`` are linear elastic,
the others ``von_mises_softening``.  Scenes build their points with
:func:`fem_rmpm.materials.material_points`; the unit tests of the update want arrays.
"""
from __future__ import annotations

import math

import numpy as np

from fem_rmpm.materials import MaterialPoints, model_id, von_mises


def vm_points(shear_modulus, bulk_modulus, cohesion_peak, cohesion_residual,
                     softening_strain, exponential) -> MaterialPoints:
    """:class:`MaterialPoints` (elastic where ``cohesion_peak`` is infinite)."""
    cp = np.asarray(cohesion_peak, float)
    model = np.where(np.isfinite(cp), model_id(von_mises.NAME), model_id("linear_elastic"))
    params = np.stack([np.asarray(a, float) for a in (shear_modulus, bulk_modulus, cp,
                       cohesion_residual, softening_strain, exponential)], axis=1)
    params[~np.isfinite(cp), 2:] = math.nan
    return MaterialPoints(model, params)
