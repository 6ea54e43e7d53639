"""Per-point material arrays from the scene's soils, and the per-point model hooks."""
from __future__ import annotations

import math

import numpy as np

from fem_rmpm.materials import registry
from fem_rmpm.materials.protocol import MaterialPoints

__all__ = ["material_points", "soil_values", "cohesion", "invalid_points", "point_problem",
           "new_state"]


def soil_values(spec) -> dict:
    """``{name: value}`` of a ``[[soil]]`` table's model parameters, plus ``shear_modulus``
    and ``bulk_modulus`` (kPa) (``spec`` a :class:`fem_rmpm.scene.SoilSpec`)."""
    m = registry.model(spec.model)
    out = {"shear_modulus": spec.shear_modulus, "bulk_modulus": spec.bulk_modulus}
    for p in m.PARAMETERS:
        out[p.name] = spec.value(p.name, p.default)
    return out


def material_points(soils, soil_id: np.ndarray) -> MaterialPoints:
    """:class:`MaterialPoints` of points whose soil (index into ``soils``) is ``soil_id``."""
    ids = [registry.model_id(s.model) for s in soils]
    rows = np.full((len(soils), registry.n_parameters(ids)), math.nan)
    for k, s in enumerate(soils):
        m = registry.model(ids[k])
        vals = soil_values(s)
        rows[k, 0], rows[k, 1] = vals["shear_modulus"], vals["bulk_modulus"]
        for j, p in enumerate(m.PARAMETERS):
            rows[k, 2 + j] = p.encode(vals[p.name])
    return MaterialPoints(np.array(ids, dtype=np.int64)[soil_id], rows[soil_id])


def new_state(soil: MaterialPoints) -> np.ndarray:
    """Zero state (n, S) for the models of ``soil`` (S >= 1: plastic shear strain first),
    column-major as the parameter rows (:class:`MaterialPoints`): a model update reads one
    or two columns of it per point."""
    return np.zeros((len(soil), registry.n_state(np.unique(soil.model))), order="F")


def cohesion(state: np.ndarray, soil: MaterialPoints) -> np.ndarray:
    """Current strength per point (kPa) from the models' ``cohesion`` hook (of the
    softening variable where the model declares one (``REGULARISABLE``), else of the
    plastic shear strain); inf where a model has none (linear elastic).  With one model
    the hook gets the soil's own parameter rows, in their own memory order (no copy: the
    rows are column-major, and a row-major copy took half of this function's time): hooks
    read them, never write."""
    state = state[:, None] if state.ndim == 1 else state
    out = np.full(len(soil), math.inf)
    models = soil.model
    one = len(models) > 0 and bool((models == models[0]).all())   # one model: no masks
    for k in (models[:1] if one else np.unique(models)):
        m = registry.model(int(k))
        if hasattr(m, "cohesion"):
            reg = getattr(m, "REGULARISABLE", None)
            col = m.STATE.index(reg.variable) if (
                reg is not None and state.shape[1] > 1) else 0
            if one:      # the same values as the masked copies, without copying
                out[:] = m.cohesion(np.ascontiguousarray(state[:, col]), soil.params)[0]
            else:
                idx = models == k
                out[idx] = m.cohesion(state[idx, col], soil.params[idx])[0]
    return out


def invalid_points(soil: MaterialPoints) -> tuple[np.ndarray, str]:
    """Points whose parameter values their model rejects (its ``invalid_points`` hook):
    a mask (n,) and the first such model's reason ("" if none)."""
    bad = np.zeros(len(soil), dtype=bool)
    reason = ""
    for k in np.unique(soil.model):
        m = registry.model(int(k))
        if hasattr(m, "invalid_points"):
            idx = np.nonzero(soil.model == k)[0]
            b, why = m.invalid_points(soil.params[idx])
            bad[idx] = b
            reason = reason or (why if b.any() else "")
    return bad, reason


def point_problem(soil: MaterialPoints, x0: np.ndarray) -> str | None:
    """What is wrong with the first point whose model rejects its parameter values
    (:func:`invalid_points`), e.g. values drawn by a random field: ``"material point i at
    x = .., y = .. m "`` and the model's own words (its ``point_problem`` hook, else its
    ``invalid_points`` reason); None if every point is valid.  ``x0`` (n, 2): the points'
    initial positions (m)."""
    bad, reason = invalid_points(soil)
    if not bad.any():
        return None
    i = int(np.argmax(bad))
    m = registry.model(int(soil.model[i]))
    hook = getattr(m, "point_problem", None)
    what = hook(soil.params[i]) if hook is not None else reason
    return f"material point {i} at x = {x0[i, 0]:.2f}, y = {x0[i, 1]:.2f} m {what}"
