"""Strength reduction of the parameter rows, from each model's ``STRENGTHS`` table.

A model declares its strength parameters and how a strength reduction by the trial factor
``F`` scales them (:class:`fem_rmpm.materials.protocol.Strength`); the factor-of-safety
search (:mod:`fem_rmpm.schemes.implicit.strength_reduction`) reads only this module.  The
reduction of a model's rows, in order:

1. every parameter with the rule ``"c/F"`` is divided by ``F`` (kPa; infinite stays
   infinite) and every one with ``"atan(tan(phi)/F)"`` becomes ``atan(tan(phi) / F)``
   (deg; Griffiths & Lane 1999, Dawson, Roth & Drescher 1999);
2. without softening, a residual value (a row with ``peak``) takes the reduced peak value:
   the soil is perfectly plastic at its reduced peak strength (RFEM practice);
3. a parameter with the rule ``"at most"`` is capped at the reduced value of its ``bound``
   (a dilation angle may not exceed the reduced friction angle); where it equals its
   bound before the reduction (associated flow, psi = phi), it takes the bound's reduced
   value at every trial, so that a soil declared associated stays associated also at
   trials F < 1, where phi grows (a capped psi would make it non-associated there, and a
   non-associated soil collapses at a lower load: Davis 1968).
"""
from __future__ import annotations

import math

import numpy as np

from fem_rmpm.materials import registry

__all__ = ["strengths", "strength_parameters", "reduce_strength", "has_strength",
           "models_with_strength"]


def strengths(key: int | str) -> tuple:
    """The ``STRENGTHS`` table of model ``key`` (id or name; empty: no strength)."""
    return tuple(getattr(registry.model(key), "STRENGTHS", ()))


def strength_parameters(key: int | str) -> tuple[str, ...]:
    """The names of the parameters of model ``key`` that a strength reduction scales by
    ``F`` (the "at most" ones excluded: they are capped, not scaled)."""
    return tuple(s.name for s in strengths(key) if s.rule != "at most")


def _tan_reduced(deg: np.ndarray, F: float) -> np.ndarray:
    """``atan(tan(phi) / F)`` of angles ``deg`` (deg)."""
    return np.degrees(np.arctan(np.tan(np.radians(deg)) / F))


def reduce_strength(key: int | str, params: np.ndarray, F: float,
                    softening: bool) -> np.ndarray:
    """New parameter rows (n, P) of model ``key`` with its strengths reduced by the trial
    factor ``F`` (> 0) as its ``STRENGTHS`` table says (see the module docstring);
    ``softening=False`` makes the residuals the reduced peaks.  ``params`` is not changed."""
    p = np.array(params, dtype=float, copy=True)
    table = strengths(key)
    col = {s.name: registry.column(key, s.name) for s in table}
    associated = _associated(key, p, table, col, softening)
    for s in table:
        if s.rule == "c/F":
            p[:, col[s.name]] = p[:, col[s.name]] / F
        elif s.rule == "atan(tan(phi)/F)":
            p[:, col[s.name]] = _tan_reduced(p[:, col[s.name]], F)
    if not softening:
        for s in table:
            if s.peak is not None:
                p[:, col[s.name]] = p[:, registry.column(key, s.peak)]
    for s in table:
        if s.rule == "at most":
            c, b = col[s.name], registry.column(key, s.bound)
            p[:, c] = np.where(associated[s.name], p[:, b], np.minimum(p[:, c], p[:, b]))
    return p


def _associated(key, p: np.ndarray, table: tuple, col: dict, softening: bool) -> dict:
    """Per "at most" row of ``table``: which points (bool (n,)) have the parameter equal to
    its bound in the unreduced rows ``p`` (after step 2 of the module docstring)."""
    q = p.copy()
    if not softening:
        for s in table:
            if s.peak is not None:
                q[:, col[s.name]] = q[:, registry.column(key, s.peak)]
    return {s.name: q[:, col[s.name]] == q[:, registry.column(key, s.bound)]
            for s in table if s.rule == "at most"}


def has_strength(spec) -> bool:
    """Does one ``[[soil]]`` (a :class:`fem_rmpm.scene.SoilSpec`) have a strength to
    reduce: some scaled strength parameter of its model with a finite value?"""
    return any(math.isfinite(float(spec.value(n, math.inf)))
               for n in strength_parameters(spec.model))


def models_with_strength() -> tuple[str, ...]:
    """Names of the registered models that declare a strength to reduce."""
    return tuple(m.NAME for m in registry.models() if strength_parameters(m.NAME))
