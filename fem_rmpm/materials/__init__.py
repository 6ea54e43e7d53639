"""Soil models at a material point: one protocol, one module per model, a registry.

To add a model: write a module following :mod:`.protocol` (parameters with units and
ranges, state variables, a numpy ``update`` and a numba ``point_update``; optionally its
checks and their messages, its strengths and how a strength reduction scales them, its
regularisable state) and register it — one line below, or ``register(module)`` from
anywhere (e.g. a test).  The scene validation of ``[[soil]]``, the explicit kernels
(through :mod:`.dispatch`), the implicit scheme's complex-step tangent, the strength
reduction (:mod:`.strength`) and the regularisation of softening then use it; no kernel,
scheme or scene code changes.
"""
from __future__ import annotations

from fem_rmpm.materials import linear_elastic, mohr_coulomb, von_mises
from fem_rmpm.materials.hencky import (
    exp_sym2,
    hencky_stress,
    hughes_winget_increment,
    kirchhoff_stress,
    log_sym2,
    return_map,
    small_strain_update,
    spatial_tangent,
    sqrt_j2,
    stress_update,
)
from fem_rmpm.materials.points import (
    cohesion,
    invalid_points,
    material_points,
    new_state,
    point_problem,
    soil_values,
)
from fem_rmpm.materials.protocol import (
    ELASTIC_COLUMNS,
    MaterialPoints,
    Parameter,
    Regularisable,
    Strength,
)
from fem_rmpm.materials.registry import model, model_id, models, names, register, version

__all__ = ["MaterialPoints", "Parameter", "Strength", "Regularisable", "ELASTIC_COLUMNS",
           "register", "model", "model_id", "models", "names", "version", "material_points",
           "new_state", "soil_values", "cohesion", "invalid_points", "point_problem",
           "exp_sym2", "log_sym2", "hughes_winget_increment", "hencky_stress",
           "kirchhoff_stress", "sqrt_j2", "return_map", "stress_update", "small_strain_update",
           "spatial_tangent"]

# the registry: one line per model (the order gives the model ids)
register(linear_elastic)
register(von_mises)
register(mohr_coulomb)
