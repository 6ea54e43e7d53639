"""The ``[water]`` section: reading and checking a phreatic surface, and which soils are
drained.

A scene with ``[water]`` is an effective-stress analysis: the stored point stress is the
effective stress sigma' (tension positive) and the pore pressure u (a pressure, >= 0) is
a function of the position (:mod:`fem_rmpm.schemes.pore_pressure`).  The phreatic surface
is a polyline in the grid frame; its geometry in the true frame (x horizontal, y up; the
grid is tilted by ``[scene] frame_angle_deg``) is :func:`true_polyline`, which both the
checks here and the pore pressure use.

Checks (each a one-line :class:`SceneError`): the polyline spans the grid's width, its x
(grid frame) and its true-horizontal coordinate both increase strictly (it does not fold
back), ``unit_weight_saturated >= unit_weight``, a drained soil that reaches below the
surface gives ``unit_weight_saturated``, and the drainage suits the model
(:func:`drainage_of`).
"""
from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np

from fem_rmpm.scene.spec import DRAINAGE, PORE_PRESSURES, Scene, WaterSpec
from fem_rmpm.scene.values import _build, _fail

__all__ = ["build_water", "check_water", "water_to_dict", "drainage_of", "true_polyline",
           "to_true_frame", "MODEL_DRAINAGE"]

#: The drainage each material model allows (the first: its default).  Mohr-Coulomb is an
#: effective-stress (drained, c', phi') model; von Mises a total-stress (undrained, s_u)
#: one, pressure-independent, so its stored stress is read as sigma + u I; linear elastic
#: is either.
MODEL_DRAINAGE = {"mohr_coulomb_softening": ("drained",), "von_mises_softening": ("undrained",),
                  "linear_elastic": ("drained", "undrained")}


def drainage_of(soil) -> str:
    """``"drained"`` or ``"undrained"``: the soil's ``drainage`` or its model's default."""
    if soil.drainage is not None:
        return soil.drainage
    return MODEL_DRAINAGE.get(soil.model, ("drained",))[0]


def to_true_frame(xy: np.ndarray, frame_angle_deg: float) -> np.ndarray:
    """Grid-frame points (n, 2) m in the true frame (x horizontal, y up): the grid x axis
    lies ``frame_angle_deg`` below the true horizontal."""
    a = math.radians(frame_angle_deg)
    c, s = math.cos(a), math.sin(a)
    xy = np.asarray(xy, dtype=float)
    return np.stack([xy[..., 0] * c + xy[..., 1] * s, -xy[..., 0] * s + xy[..., 1] * c], -1)


def true_polyline(water: WaterSpec, frame_angle_deg: float) -> np.ndarray:
    """The phreatic surface's points (k, 2) in the true frame (m)."""
    return to_true_frame(np.array(water.phreatic_surface, dtype=float), frame_angle_deg)


def build_water(source: str, data: Any) -> WaterSpec:
    """The :class:`WaterSpec` of a ``[water]`` table (types and choices; the geometry is
    checked against the grid by :func:`check_water`)."""
    if not isinstance(data, dict):
        raise _fail(source, "water", f"expected a table, got {type(data).__name__}")
    rest = {k: v for k, v in data.items() if k != "phreatic_surface"}
    if "phreatic_surface" not in data:
        raise _fail(source, "water.phreatic_surface", "missing required key; allowed: a "
                    "polyline [[x, y], ...] (m) spanning the grid's width")
    line = data["phreatic_surface"]
    ok = isinstance(line, list) and len(line) >= 2 and all(
        isinstance(p, list) and len(p) == 2 and all(
            isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
            for v in p) for p in line)
    if not ok:
        raise _fail(source, "water.phreatic_surface", "expected a list of at least 2 points "
                    "[[x, y], ...] of finite numbers (m)")
    spec = _build(source, "water", _WaterRest, rest)
    if not 0 < spec.unit_weight <= 1e3:
        raise _fail(source, "water.unit_weight", f"value {spec.unit_weight!r} out of range; "
                    "allowed: a number in (0, 1000] (kN/m3)")
    if spec.pore_pressure not in PORE_PRESSURES:
        raise _fail(source, "water.pore_pressure", f"value {spec.pore_pressure!r} not "
                    "allowed; allowed: " + " | ".join(repr(c) for c in PORE_PRESSURES))
    return WaterSpec(tuple((float(p[0]), float(p[1])) for p in line), spec.unit_weight,
                     spec.pore_pressure)


@dataclasses.dataclass(frozen=True)
class _WaterRest:
    """The ``[water]`` keys other than the polyline (typed by :func:`_build`)."""
    unit_weight: float = 9.81
    pore_pressure: str = "hydrostatic"


def water_to_dict(water: WaterSpec) -> dict:
    """Plain-data view of ``[water]`` (inverse of :func:`build_water`)."""
    return {"phreatic_surface": [list(p) for p in water.phreatic_surface],
            "unit_weight": water.unit_weight, "pore_pressure": water.pore_pressure}


def _check_line(s: Scene) -> None:
    src, w = s.source, s.water
    p = np.array(w.phreatic_surface, dtype=float)
    key = "water.phreatic_surface"
    step = np.diff(p[:, 0])
    if (step <= 0).any():
        k = int(np.argmax(step <= 0))
        raise _fail(src, key, f"point {k + 2} ({p[k + 1, 0]:g}, {p[k + 1, 1]:g}) does not lie "
                    f"right of point {k + 1}: the surface folds back; allowed: x increasing "
                    "strictly along the polyline (m, grid frame)")
    q = true_polyline(w, s.scene.frame_angle_deg)
    step = np.diff(q[:, 0])
    if (step <= 0).any():
        k = int(np.argmax(step <= 0))
        raise _fail(src, key, f"segment {k + 1} is steeper than the true vertical in the "
                    f"frame tilted by {s.scene.frame_angle_deg:g} deg: the surface folds "
                    "back; allowed: true-horizontal coordinate increasing along the polyline")
    if s.grid.file is None:
        x0, gx = s.grid.origin[0], s.grid.size[0]
        tol = 1e-9 * max(gx, 1.0)
        if p[0, 0] > x0 + tol or p[-1, 0] < x0 + gx - tol:
            raise _fail(src, key, f"the polyline spans x = [{p[0, 0]:g}, {p[-1, 0]:g}] m, not "
                        f"the grid's width [{x0:g}, {x0 + gx:g}] m; allowed: first x <= "
                        f"{x0:g}, last x >= {x0 + gx:g} (m)")


def _below(poly: np.ndarray, line: np.ndarray, frame_angle_deg: float) -> bool:
    """Whether any corner of a soil polygon (grid frame) lies below the surface ``line``
    (true frame)."""
    t = to_true_frame(poly, frame_angle_deg)
    ys = np.interp(t[:, 0], line[:, 0], line[:, 1])
    return bool((t[:, 1] < ys).any())


def check_water(s: Scene) -> None:
    """Check ``[water]`` against the grid and the soils (one-line SceneError)."""
    src = s.source
    for i, so in enumerate(s.soils):
        allowed = MODEL_DRAINAGE.get(so.model, DRAINAGE)
        if so.drainage is not None and so.drainage not in DRAINAGE:
            raise _fail(src, f"soil[{i}].drainage", f"value {so.drainage!r} not allowed; "
                        "allowed: " + " | ".join(repr(c) for c in DRAINAGE))
        if so.drainage is not None and so.drainage not in allowed:
            raise _fail(src, f"soil[{i}].drainage", f"{so.drainage!r} does not suit model "
                        f"{so.model!r} (an {'effective' if allowed == ('drained',) else 'total'}"
                        f"-stress model); allowed: " + " | ".join(repr(c) for c in allowed))
        sat = so.unit_weight_saturated
        if sat is not None and not (so.unit_weight <= sat <= 1e3):
            raise _fail(src, f"soil[{i}].unit_weight_saturated", f"value {sat!r} below "
                        f"unit_weight {so.unit_weight:g} or above 1000; allowed: a number in "
                        f"[{so.unit_weight:g}, 1000] (kN/m3)")
    if s.water is None:
        return
    _check_line(s)
    line = true_polyline(s.water, s.scene.frame_angle_deg)
    for i, so in enumerate(s.soils):
        if (so.unit_weight_saturated is None and drainage_of(so) == "drained"
                and _below(np.array(so.polygon), line, s.scene.frame_angle_deg)):
            raise _fail(src, f"soil[{i}].unit_weight_saturated", f"soil {so.name!r} is "
                        "drained and reaches below the phreatic surface: missing required "
                        "key; allowed: a number in [unit_weight, 1000] (kN/m3)")
