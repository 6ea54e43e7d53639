"""Temporary shim: the former single-material module, now :mod:`fem_rmpm.materials`.

Kept so that modules not yet switched to the materials package import as before;
new code imports from :mod:`fem_rmpm.materials`.  ``gamma_p`` arguments (n,) are the
plastic shear strain, the first state variable.
"""
from __future__ import annotations

import math

import numpy as np

from .materials import (MaterialPoints, exp_sym2, hughes_winget_increment, kirchhoff_stress,
                        log_sym2, model_id, return_map, small_strain_update, spatial_tangent,
                        sqrt_j2, stress_update, von_mises)

__all__ = ["SoilPoints", "kirchhoff_stress", "sqrt_j2", "cohesion", "stress_update",
           "small_strain_update", "return_map", "spatial_tangent", "hughes_winget_increment",
           "exp_sym2", "log_sym2"]


def SoilPoints(shear_modulus, bulk_modulus, cohesion_peak, cohesion_residual,  # noqa: N802
               softening_strain, exponential) -> MaterialPoints:
    """Material points of the two built-in models from per-point arrays (kPa, -): points
    with an infinite ``cohesion_peak`` are linear elastic, the others von Mises."""
    cp = np.asarray(cohesion_peak, float)
    model = np.where(np.isfinite(cp), model_id(von_mises.NAME), model_id("linear_elastic"))
    params = np.stack([np.asarray(a, float) for a in (shear_modulus, bulk_modulus, cp,
                       cohesion_residual, softening_strain, exponential)], axis=1)
    params[~np.isfinite(cp), 2:] = math.nan
    return MaterialPoints(model, params)


def cohesion(gamma_p, soil: MaterialPoints):
    """Von Mises cohesion c(gamma_p) (kPa) and its slope dc/dgamma_p (kPa) per point."""
    return von_mises.cohesion(gamma_p, soil.params)
