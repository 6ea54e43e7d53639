"""Typed values of a scene section: the ranges and choices of the numeric and string
keys, the conversion of a TOML value to its dataclass field's type, and the one-line
:class:`SceneError` naming the file, the key and what is allowed."""
from __future__ import annotations

import dataclasses
import math
from typing import Any

from fem_rmpm.scene.spec import (
    BOUNDARY_KINDS,
    CORRELATIONS,
    DISTRIBUTIONS,
    EDGE_POLICIES,
    SCHEMES,
    SHAPES,
    SceneError,
)

__all__: list[str] = []      # internal to the scene layer (schema, fields, reference)

_RANGES: dict[str, tuple[float, float, bool, bool]] = {
    "scene.gravity": (0, 1e3, True, True),
    "scene.frame_angle_deg": (-90, 90, False, False),
    "soil.unit_weight": (0, 1e3, False, True),
    "soil.youngs_modulus": (0, 1e12, False, True),
    "soil.poisson_ratio": (0, 0.5, True, False),   # auxetic (nu < 0) soils are refused
    "soil.points_per_cell_dir": (1, 8, True, True),
    "random_field.cov": (0, 10, True, True),
    "random_field.theta_v": (0, math.inf, False, False),
    "random_field.anisotropy": (0, math.inf, False, False),
    "random_field.layering_angle_deg": (-90, 90, True, True),
    "random_field.cell_size": (0, math.inf, False, False),
    "random_field.theta_strike": (0, math.inf, False, False),
    "random_field.low": (-math.inf, math.inf, False, False),
    "random_field.high": (-math.inf, math.inf, False, False),
    "random_field.properties.cov": (0, 10, True, True),
    "random_field.properties.theta_v": (0, math.inf, False, False),
    "random_field.properties.anisotropy": (0, math.inf, False, False),
    "random_field.properties.layering_angle_deg": (-90, 90, True, True),
    "solver.cfl": (0, 3, False, True),     # measured limits 1.08 to 1.65 (docs: choosing)
    "solver.damping": (0, 1, True, False),
    "solver.damping_time": (0, math.inf, True, True),
    "solver.gravity_ramp_time": (0, math.inf, True, False),
    "solver.geostatic_time": (0, math.inf, False, False),
    "solver.t_end": (0, math.inf, False, False),
    "solver.rest_velocity": (0, math.inf, True, False),
    "solver.rest_energy_ratio": (0, 1, True, True),
    "solver.output_interval": (0, math.inf, False, True),
    "solver.flip": (0, 1, True, True),
    "solver.threads": (0, 64, True, True),
    "solver.load_steps": (1, 1e6, True, True),
    "solver.dt": (0, math.inf, False, False),
    "solver.max_iterations": (1, 1000, True, True),
    "solver.tolerance": (0, 1, False, False),
    "solver.max_cuts": (0, 30, True, True),
    "solver.dt_max": (0, math.inf, False, False),
    "solver.max_displacement_fraction": (0, 1, False, True),
    "solver.hht_alpha": (0, 1 / 3, True, True),
    "solver.min_mass_fraction": (0, 1, True, False),
    "bedrock.friction": (0, 10, True, True),
    "bedrock.adhesion": (0, 1e6, True, True),
    "montecarlo.realizations": (1, 1e9, True, True),
    "montecarlo.seed": (0, 2**63 - 1, True, True),
    "montecarlo.failure_displacement": (0, math.inf, False, False),
    "montecarlo.intact_block_area": (0, math.inf, False, False),
    "montecarlo.failure_area": (0, math.inf, True, False),
    "montecarlo.keep_vtk": (0, 1e9, True, True),
    "montecarlo.runs_to_rest": (0, 1e9, True, True),
}
_CHOICES: dict[str, tuple[str, ...]] = {
    "boundary.left": BOUNDARY_KINDS, "boundary.right": BOUNDARY_KINDS,
    "boundary.bottom": BOUNDARY_KINDS, "boundary.top": BOUNDARY_KINDS,
    "random_field.distribution": DISTRIBUTIONS,
    "random_field.correlation": CORRELATIONS,
    "random_field.properties.distribution": DISTRIBUTIONS,
    "random_field.properties.correlation": CORRELATIONS,
    "solver.scheme": SCHEMES, "solver.shape": SHAPES, "solver.edge_policy": EDGE_POLICIES,
    "boundary.front": BOUNDARY_KINDS, "boundary.back": BOUNDARY_KINDS,
    "solver.linear_solver": ("cholmod", "superlu", "pyamg"),
    "solver.gravity_phase": ("dynamic", "geostatic"),
    "solver.kernel": ("numba", "numpy"),
    "solver.locking_constraint": ("volume", "pressure"),
    "prescribed.components": ("xy", "x", "y"),
    "bedrock.interface": ("rough", "frictional"),
}

#: float keys whose value may be infinite (no strength, damping for ever)
_INFINITE_OK = ("solver.damping_time", "soil.cohesion_peak", "soil.cohesion_residual")


def _fail(source: str, key: str, msg: str) -> SceneError:
    return SceneError(f"{source}: [{key}] {msg}")


def _fmt_range(lo: float, hi: float, lo_in: bool, hi_in: bool) -> str:
    left = "[" if lo_in else "("
    right = "]" if hi_in else ")"
    return f"a number in {left}{lo:g}, {hi:g}{right}"


def _infinity(value: Any) -> Any:
    """``"inf"`` / ``"-inf"`` (how :func:`scene_to_dict` writes an infinity) as a float;
    any other value unchanged (TOML's own ``inf`` is already a float)."""
    return float(value) if isinstance(value, str) and value in ("inf", "-inf") else value


def _coerce(source: str, key: str, value: Any, default: Any, annotation: str,
            shown: str | None = None) -> Any:
    """Check the TOML value of ``key`` against the dataclass field type and convert it
    (messages name the key ``shown``, default ``key``)."""
    ann = annotation.replace(" ", "")
    lookup, key = key, shown or key
    if ann in ("float", "float|None"):
        if value is None and "None" in ann:
            return None
        value = _infinity(value)
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise _fail(source, key, f"expected a number, got {value!r}")
        value = float(value)
        if not math.isfinite(value) and lookup not in _INFINITE_OK:
            raise _fail(source, key, f"expected a finite number, got {value!r}")
        return value
    if ann in ("int", "int|None"):
        if value is None and "None" in ann:
            return None
        if isinstance(value, bool) or not isinstance(value, int):
            raise _fail(source, key, f"expected an integer, got {value!r}")
        return value
    if ann == "bool":
        if not isinstance(value, bool):
            raise _fail(source, key, f"expected true or false, got {value!r}")
        return value
    if ann in ("str", "str|None"):
        if not isinstance(value, str):
            raise _fail(source, key, f"expected a string, got {value!r}")
        return value
    if ann == "tuple[str,...]":
        if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
            raise _fail(source, key, f"expected a list of strings, got {value!r}")
        return tuple(value)
    if ann == "tuple[float,float]":
        if (isinstance(value, (int, float)) and not isinstance(value, bool)
                and lookup == "grid.cell"):
            value = [value, value]
        if (not isinstance(value, list) or len(value) != 2
                or not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value)):
            raise _fail(source, key, f"expected two numbers [x, y], got {value!r}")
        if not all(math.isfinite(v) for v in value):
            raise _fail(source, key, f"expected two finite numbers [x, y], got {value!r}")
        return (float(value[0]), float(value[1]))
    if ann in _COERCE_3D:
        return _COERCE_3D[ann](source, lookup, key, value)
    if ann == "tuple[float,...]|None":        # [random_field] box: a rectangle or a box
        if value is None:
            return None
        if (not isinstance(value, list) or len(value) not in (4, 6)
                or not all(isinstance(v, (int, float)) and not isinstance(v, bool)
                           and math.isfinite(v) for v in value)):
            raise _fail(source, key, f"expected four numbers [x0, y0, x1, y1] in m (six, "
                        f"[x0, y0, z0, x1, y1, z1], in a 3-D scene), got {value!r}")
        return tuple(float(v) for v in value)
    if ann == "tuple[tuple[float,float],...]":
        ok = isinstance(value, list) and len(value) >= 3 and all(
            isinstance(p, list) and len(p) == 2 and all(
                isinstance(v, (int, float)) and not isinstance(v, bool) for v in p) for p in value)
        if not ok:
            raise _fail(source, key, "expected a list of at least 3 points [[x, y], ...] in m")
        return tuple((float(p[0]), float(p[1])) for p in value)
    raise AssertionError(f"unhandled annotation {annotation}")  # pragma: no cover


def _grid_numbers(source: str, lookup: str, key: str, value: Any) -> tuple[float, ...]:
    """``[grid]`` origin, size, cell: two numbers (plane strain) or three (3-D); a cell
    may be one number (the same in every direction)."""
    if isinstance(value, (int, float)) and not isinstance(value, bool) and lookup == "grid.cell":
        value = [value]
    if (not isinstance(value, list) or not 1 <= len(value) <= 3
            or not all(isinstance(v, (int, float)) and not isinstance(v, bool)
                       and math.isfinite(v) for v in value)
            or (len(value) == 1 and lookup != "grid.cell")):
        raise _fail(source, key, f"expected two finite numbers [x, y] or three [x, y, z] "
                    f"(m), got {value!r}")
    return tuple(float(v) for v in value)


def _strike_range(source: str, lookup: str, key: str, value: Any):
    if (not isinstance(value, list) or len(value) != 2
            or not all(isinstance(v, (int, float)) and not isinstance(v, bool)
                       and math.isfinite(v) for v in value)):
        raise _fail(source, key, f"expected two finite numbers [z0, z1] (m), got {value!r}")
    return (float(value[0]), float(value[1]))


def _plan_polygon(source: str, lookup: str, key: str, value: Any):
    return _coerce(source, lookup, value, None, "tuple[tuple[float,float],...]", key)


#: The annotations of the three-dimensional keys (``[grid]``, ``[[soil]] strike / plan``).
_COERCE_3D = {"tuple[float,...]": _grid_numbers, "tuple[float,float]|None": _strike_range,
              "tuple[tuple[float,float],...]|None": _plan_polygon}


def _build(source: str, section: str, cls: type, data: Any, label: str | None = None) -> Any:
    """The dataclass ``cls`` of a TOML table: every key known, typed, in range or one of
    its choices (``_RANGES`` / ``_CHOICES`` under ``section.key``); messages name the key
    as ``label.key`` (default ``section.key``; e.g. a table of an array)."""
    label = label or section
    if not isinstance(data, dict):
        raise _fail(source, label, f"expected a table, got {type(data).__name__}")
    fields = {f.name: f for f in dataclasses.fields(cls)}
    unknown = sorted(set(data) - set(fields))
    if unknown:
        raise _fail(source, f"{label}.{unknown[0]}",
                    f"unknown key; allowed keys: {', '.join(sorted(fields))}")
    kwargs = {}
    for name, f in fields.items():
        key, shown = f"{section}.{name}", f"{label}.{name}"
        if name not in data:
            if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
                raise _fail(source, shown, "missing required key")
            continue
        value = _coerce(source, key, data[name], f.default, str(f.type), shown)
        if key in _RANGES and value is not None:
            lo, hi, lo_in, hi_in = _RANGES[key]
            bad = (value < lo or (value == lo and not lo_in) or value > hi
                   or (value == hi and not hi_in))
            if bad:
                raise _fail(source, shown, f"value {value!r} out of range; allowed: "
                            + _fmt_range(lo, hi, lo_in, hi_in))
        if key in _CHOICES and value not in _CHOICES[key]:
            raise _fail(source, shown, f"value {value!r} not allowed; allowed: "
                        + " | ".join(repr(c) for c in _CHOICES[key]))
        kwargs[name] = value
    return cls(**kwargs)


