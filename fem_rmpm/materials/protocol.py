"""The material protocol: what a soil model module declares, and the per-point arrays.

A model is one module with these attributes (see :mod:`.von_mises` for a full one):

``NAME`` (str)
    the ``[[soil]] model`` value of the scene file, e.g. ``"von_mises_softening"``.
``PARAMETERS`` (tuple of :class:`Parameter`)
    the model's own constants, read from the ``[[soil]]`` table by name and checked
    against the declared unit, range or choices by the scene validation.  Every model
    also has the Hencky elasticity of the soil (``youngs_modulus``, ``poisson_ratio`` in the
    scene, stored as shear and bulk modulus), so a point's parameter row is
    ``[shear_modulus, bulk_modulus, *PARAMETERS]`` (kPa, then the declared units; a
    choice is stored as its index).
``STATE`` (tuple of str)
    the names of the internal variables per point; a plastic model's first one is the
    ``plastic_shear_strain`` invariant (outputs and measures read column 0).
``update(eps_tr, state, params) -> (eps, state, tau)``
    vectorised numpy reference: trial elastic log strain (n, 4) ``[xx, yy, zz, xy]``,
    state (n, S) and parameter rows (n, P) to the elastic log strain, the new state and
    the Kirchhoff stress (n, 4) in kPa.  It must work on complex input: the implicit
    scheme's consistent tangent is its complex-step derivative.
``point_update(e0, e1, e2, e3, state, params, i) -> (e0, e1, e2, e3, t0, t1, t2, t3)``
    the same update for point ``i`` as a numba function (``njit(inline="always")``),
    writing ``state[i, :]``; the explicit kernels call it through one dispatch on the
    point's model id (:mod:`.dispatch`).  It must allocate nothing.

Optional, what the rest of the package asks a model (none of it names a model):

``check(values) -> (key, message) | None``
    scene check of one ``[[soil]]`` across parameters; ``values`` maps the parameter
    names, ``shear_modulus`` and ``bulk_modulus`` to numbers.
``invalid_points(params) -> (mask, reason)``
    the same for per-point values (n, P), e.g. drawn by a random field.
``point_problem(row) -> str``
    what is wrong with one rejected parameter row, in the model's own words, naming its
    values and what to change (:func:`fem_rmpm.materials.points.point_problem` puts it
    after the point's position); default: the ``reason`` of ``invalid_points``.
``cohesion(state, params)``
    the current strength per point in kPa for outputs (default: infinite).
``STRENGTHS`` (tuple of :class:`Strength`)
    the strength parameters and how a strength reduction by the trial factor ``F``
    scales each (:data:`REDUCTIONS`: ``c / F``, ``atan(tan(phi) / F)``, at most another
    reduced parameter), and which residual takes its peak's reduced value when the soil
    is reduced perfectly plastic (:func:`fem_rmpm.materials.strength.reduce_strength`);
    default: none, the model has no strength to reduce.
``REGULARISABLE`` (:class:`Regularisable`)
    the state columns and parameter a mesh regularisation of softening acts on, by name
    (:mod:`fem_rmpm.schemes.regularisation`); such a model also declares the
    regularisation's keys as parameters (``regularisation``, ``internal_length``,
    ``nonlocal_factor``, ``softening_displacement``) and the hooks
    ``fully_softened(params)`` (the softening variable (n,) past which the strength no
    longer falls) and ``softening_modulus(values)`` (kPa, the drop of strength per unit
    softening variable of one ``[[soil]]``'s values, for the check of a displacement-scaled
    softening strain).
``tangent(eps_tr, state, params) -> D``
    the consistent tangent ``d tau / d eps_tr`` (n, 4, 4) of ``update`` at the trial log
    strains, columns ``[xx, yy, zz, xy]``; the implicit scheme uses it instead of the
    complex step of ``update``, which is ~10x slower; a test must show the two agree.
``block_update(Z, state, params, active, b, m)``
    ``point_update`` of the points ``b .. b + m - 1`` at once, written without branches so
    that LLVM vectorises it: the trial strains of point ``b + j`` in ``Z[0:4, j]``, its
    strains into ``Z[4:8, j]`` and Kirchhoff stress into ``Z[8:12, j]`` (rows 12-15 are its
    own), the state of the ``active`` points updated; ``Z`` is the kernels' block scratch,
    :data:`BLOCK_ROWS` x :data:`BLOCK_COLUMNS`, compiled with
    :data:`fem_rmpm.runtime.compiled.jit`; the results must be bitwise ``point_update``'s:
    the kernels use it where all points have the model, else ``point_update``.  With it
    ``block_eligible(params) -> bool``: whether ``block_update`` computes points with these
    parameter rows (n, P), e.g. not a law it leaves to ``point_update`` (asked once per
    run, for all its points; default: True).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from fem_rmpm.materials import registry

__all__ = ["Parameter", "Strength", "Regularisable", "MaterialPoints", "ELASTIC_COLUMNS",
           "BLOCK_ROWS", "BLOCK_COLUMNS", "REDUCTIONS"]

# The block scratch ``Z`` a model's ``block_update`` gets (per chunk, i.e. per thread, of
# the kernels): BLOCK_ROWS rows of BLOCK_COLUMNS float64, at least the kernels' block of
# points (128).  The update may promise the width to LLVM
# (:func:`fem_rmpm.runtime.compiled.assume_columns`), so that it can tell the rows apart and
# vectorise a loop that reads some and writes others.
BLOCK_ROWS = 16
BLOCK_COLUMNS = 192

ELASTIC_COLUMNS = ("shear_modulus", "bulk_modulus")   # columns 0 and 1 of every row


@dataclass(frozen=True)
class Parameter:
    """One constant of a model: ``[[soil]]`` key, unit, allowed range or choices."""
    name: str
    unit: str
    low: float = -math.inf
    high: float = math.inf
    low_inclusive: bool = False
    high_inclusive: bool = False
    default: Any = None                  # None: required when the model is chosen
    choices: tuple[str, ...] = ()        # a string parameter; stored as its index
    allow_inf: bool = False              # inf is a value (e.g. no strength)
    absent: float = math.nan             # its value at points of models without it
    description: str = ""

    def allowed(self) -> str:
        """What a scene file may give, for an error message."""
        if self.choices:
            return " | ".join(repr(c) for c in self.choices)
        lo = "[" if self.low_inclusive else "("
        hi = "]" if self.high_inclusive else ")"
        return f"a number in {lo}{self.low:g}, {self.high:g}{hi} ({self.unit})"

    def check(self, value: Any) -> str | None:
        """None if ``value`` is allowed, else what is wrong (for the scene error)."""
        if self.choices:
            return None if value in self.choices else f"value {value!r} not allowed"
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            return f"expected a number, got {value!r}"
        v = float(value)
        if math.isnan(v) or (math.isinf(v) and not self.allow_inf):
            return f"expected a finite number, got {value!r}"
        bad = (v < self.low or (v == self.low and not self.low_inclusive) or v > self.high
               or (v == self.high and not self.high_inclusive))
        return f"value {value!r} out of range" if bad else None

    def encode(self, value: Any) -> float:
        """The number stored in a parameter row."""
        return float(self.choices.index(value)) if self.choices else float(value)


#: How a strength reduction scales a parameter (:class:`Strength` ``rule``), F the trial
#: factor: a cohesion or strength in kPa is divided by F; a friction angle in degrees
#: becomes ``atan(tan(phi) / F)``; "at most" keeps a value (e.g. a dilation angle, deg)
#: but not above the reduced value of the parameter ``bound``.
REDUCTIONS = ("c/F", "atan(tan(phi)/F)", "at most")


@dataclass(frozen=True)
class Strength:
    """One row of a model's ``STRENGTHS``: parameter ``name``, how a strength reduction
    scales it (``rule``, one of :data:`REDUCTIONS`), the parameter it may not exceed
    (``bound``, rule "at most"), and for a residual value the peak parameter whose reduced
    value it takes when the soil is reduced perfectly plastic (``peak``)."""
    name: str
    rule: str
    peak: str | None = None
    bound: str | None = None

    def __post_init__(self):
        if self.rule not in REDUCTIONS:
            raise ValueError(f"strength {self.name!r}: rule {self.rule!r} not one of "
                             f"{', '.join(REDUCTIONS)}")
        if (self.rule == "at most") != (self.bound is not None):
            raise ValueError(f"strength {self.name!r}: a bound goes with the rule 'at most'")


@dataclass(frozen=True)
class Regularisable:
    """A softening model's state a mesh regularisation acts on, by the names of its
    ``STATE`` columns and ``PARAMETERS`` (:mod:`fem_rmpm.schemes.regularisation`):

    ``strain``: the local plastic shear strain whose increments the non-local average
    takes; ``variable``: the softening variable the strength falls with (the non-local
    pass adds to it); ``averaged``: the ``strain`` at the last averaging (the increments
    are counted from it); ``softening_strain``: the parameter the displacement-scaled
    softening replaces by ``softening_displacement / h``."""
    strain: str = "plastic_shear_strain"
    variable: str = "softening_variable"
    averaged: str = "plastic_shear_strain_averaged"
    softening_strain: str = "softening_strain"


@dataclass(init=False, eq=False)
class MaterialPoints:
    """Material of n points: model id (n,) int64, parameter rows (n, P) float64 (stored
    column-major).

    Named read access, ``soil.cohesion_peak``: the column of that parameter for the
    points whose model declares it, the parameter's ``absent`` value elsewhere.  Named
    keywords to the constructor set those columns (on a copy of ``params``), so
    ``dataclasses.replace(soil, cohesion_peak=...)`` or ``soil.replace(...)`` give a
    copy with new values.
    """
    model: np.ndarray
    params: np.ndarray

    def __init__(self, model: np.ndarray, params: np.ndarray, **named: np.ndarray):
        self.model = np.asarray(model, dtype=np.int64)
        # column-major (a copy), as the state (points.new_state): a model update reads a
        # few columns of every point's row, and the explicit stress pass streams just those
        # (faster than row-major rows, which it read whole; bitwise the same run)
        self.params = np.array(params, dtype=float, ndmin=2, order="F")
        for name, values in named.items():
            self._set(name, values)

    # -- named access
    def _columns(self, name: str):
        """[(mask of the points, column)] of the models that declare ``name``."""
        if name in ELASTIC_COLUMNS:
            return [(slice(None), ELASTIC_COLUMNS.index(name))]
        m = self.model
        if len(m) and bool((m == m[0]).all()):                # one model: every point
            col = registry.column(int(m[0]), name)
            return [] if col is None else [(slice(None), col)]
        out = []
        for k in np.unique(m):
            col = registry.column(int(k), name)
            if col is not None:
                out.append((m == k, col))
        return out

    def __getattr__(self, name: str) -> np.ndarray:
        if name.startswith("_"):
            raise AttributeError(name)
        p = registry.parameter(name)
        if p is None and name not in ELASTIC_COLUMNS:
            raise AttributeError(f"no material parameter {name!r}")
        out = np.full(len(self.model), math.nan if p is None else p.absent)
        for mask, col in self._columns(name):
            out[mask] = self.params[mask, col]
        return out

    def _set(self, name: str, values) -> None:
        values = np.broadcast_to(np.asarray(values, dtype=float), self.model.shape)
        for mask, col in self._columns(name):
            self.params[mask, col] = values[mask]

    def replace(self, **named) -> "MaterialPoints":
        """A copy with the named parameters set to the given per-point values."""
        return MaterialPoints(self.model.copy(), self.params.copy(), **named)

    def take(self, idx) -> "MaterialPoints":
        return MaterialPoints(self.model[idx], self.params[idx])

    def __len__(self) -> int:
        return len(self.model)

    def __repr__(self) -> str:
        names = [registry.model(int(k)).NAME for k in np.unique(self.model)]
        return f"MaterialPoints(n={len(self.model)}, models={names})"
