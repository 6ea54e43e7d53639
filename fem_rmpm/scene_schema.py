"""Scene files: parse a TOML scene, check every value and build the dataclasses of
:mod:`fem_rmpm.scene_spec`.

Unknown keys, missing keys and out-of-range values raise :class:`SceneError`, whose
one-line message names the file, the key and what is allowed.  Nothing is evaluated:
TOML is parsed by :mod:`tomllib` and every value is type checked.  The keys of a
``[[soil]]`` table are checked against its material model's declared parameters.
:func:`scene_to_dict` is the inverse of :func:`scene_from_dict` (infinities are written
as the strings ``"inf"``/``"-inf"`` so that the dict is plain JSON, and read back).
"""
from __future__ import annotations

import dataclasses
import math
import tomllib
from pathlib import Path
from typing import Any

import numpy as np

from . import materials
from .errors import InputError
from .materials.points import soil_values
from .scene_spec import (_SOIL_FIELDS, BOUNDARY_KINDS, EDGE_POLICIES, SCHEMES, SHAPES,
                         BedrockSpec, BoundarySpec, GridSpec, MonteCarloSpec, OutputSpec,
                         PrescribedSpec, RandomFieldSpec, Scene, SceneError, SceneInfo,
                         SoilSpec, SolverSpec)

__all__ = ["load_scene", "scene_from_dict", "scene_to_dict", "check_seed", "polygon_problem"]

# --------------------------------------------------------------------------- validation

_SECTIONS = {"scene": SceneInfo, "grid": GridSpec, "boundary": BoundarySpec, "soil": SoilSpec,
             "bedrock": BedrockSpec, "prescribed": PrescribedSpec, "random_field": RandomFieldSpec, "solver": SolverSpec,
             "montecarlo": MonteCarloSpec, "output": OutputSpec}

# (low, high, low_inclusive, high_inclusive) for numeric keys
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
    "solver.cfl": (0, 10, False, True),
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
    "montecarlo.realizations": (1, 1e9, True, True),
    "montecarlo.seed": (0, 2**63 - 1, True, True),
    "montecarlo.failure_displacement": (0, math.inf, False, False),
    "montecarlo.keep_vtk": (0, 1e9, True, True),
}
_CHOICES: dict[str, tuple[str, ...]] = {
    "boundary.left": BOUNDARY_KINDS, "boundary.right": BOUNDARY_KINDS,
    "boundary.bottom": BOUNDARY_KINDS, "boundary.top": BOUNDARY_KINDS,
    "random_field.distribution": ("normal", "lognormal"),
    "random_field.correlation": ("markov_elliptic", "markov_separable"),
    "random_field.property": ("cohesion_peak",),
    "solver.scheme": SCHEMES, "solver.shape": SHAPES, "solver.edge_policy": EDGE_POLICIES,
    "solver.linear_solver": ("cholmod", "superlu", "pyamg"),
    "solver.gravity_phase": ("dynamic", "geostatic"),
    "solver.kernel": ("numba", "numpy"),
    "prescribed.components": ("xy", "x", "y"),
}


_LISTS = ("soil", "bedrock", "prescribed")     # sections that are arrays of tables


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


def _coerce(source: str, key: str, value: Any, default: Any, annotation: str) -> Any:
    """Check the TOML value against the dataclass field type and convert it."""
    ann = annotation.replace(" ", "")
    if ann in ("float", "float|None"):
        if value is None and "None" in ann:
            return None
        value = _infinity(value)
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise _fail(source, key, f"expected a number, got {value!r}")
        value = float(value)
        if not math.isfinite(value) and key not in ("solver.damping_time", "soil.cohesion_peak",
                                                     "soil.cohesion_residual"):
            raise _fail(source, key, f"expected a finite number, got {value!r}")
        return value
    if ann == "int":
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
        if isinstance(value, (int, float)) and not isinstance(value, bool) and key == "grid.cell":
            value = [value, value]
        if (not isinstance(value, list) or len(value) != 2
                or not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value)):
            raise _fail(source, key, f"expected two numbers [x, y], got {value!r}")
        return (float(value[0]), float(value[1]))
    if ann == "tuple[tuple[float,float],...]":
        ok = isinstance(value, list) and len(value) >= 3 and all(
            isinstance(p, list) and len(p) == 2 and all(
                isinstance(v, (int, float)) and not isinstance(v, bool) for v in p) for p in value)
        if not ok:
            raise _fail(source, key, "expected a list of at least 3 points [[x, y], ...] in m")
        return tuple((float(p[0]), float(p[1])) for p in value)
    raise AssertionError(f"unhandled annotation {annotation}")  # pragma: no cover


def _build(source: str, section: str, cls: type, data: Any) -> Any:
    if not isinstance(data, dict):
        raise _fail(source, section, f"expected a table, got {type(data).__name__}")
    fields = {f.name: f for f in dataclasses.fields(cls)}
    unknown = sorted(set(data) - set(fields))
    if unknown:
        raise _fail(source, f"{section}.{unknown[0]}",
                    f"unknown key; allowed keys: {', '.join(sorted(fields))}")
    kwargs = {}
    for name, f in fields.items():
        key = f"{section}.{name}"
        if name not in data:
            if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
                raise _fail(source, key, "missing required key")
            continue
        value = _coerce(source, key, data[name], f.default, str(f.type))
        if key in _RANGES and value is not None:
            lo, hi, lo_in, hi_in = _RANGES[key]
            bad = (value < lo or (value == lo and not lo_in) or value > hi
                   or (value == hi and not hi_in))
            if bad:
                raise _fail(source, key, f"value {value!r} out of range; allowed: "
                            + _fmt_range(lo, hi, lo_in, hi_in))
        if key in _CHOICES and value not in _CHOICES[key]:
            raise _fail(source, key, f"value {value!r} not allowed; allowed: "
                        + " | ".join(repr(c) for c in _CHOICES[key]))
        kwargs[name] = value
    return cls(**kwargs)


def _build_soil(source: str, data: Any) -> SoilSpec:
    """A ``[[soil]]`` table: the common keys as any section, the keys of its material
    model against the model's declared parameters (unit, range or choices)."""
    if not isinstance(data, dict):
        raise _fail(source, "soil", f"expected a table, got {type(data).__name__}")
    name = data.get("model", "linear_elastic")
    if name not in materials.names():
        raise _fail(source, "soil.model", f"value {name!r} not allowed; allowed: "
                    + " | ".join(repr(n) for n in materials.names()))
    declared = {p.name: p for p in materials.model(name).PARAMETERS}
    unknown = sorted(set(data) - set(_SOIL_FIELDS) - set(declared))
    if unknown:
        allowed = sorted(set(_SOIL_FIELDS[:7]) | set(declared))
        raise _fail(source, f"soil.{unknown[0]}", f"unknown key for model {name!r}; allowed "
                    f"keys: {', '.join(allowed)}")
    data = {k: (_infinity(v) if k in declared and not declared[k].choices else v)
            for k, v in data.items()}
    for key, p in declared.items():
        if key in data:
            err = p.check(data[key])
            if err:
                raise _fail(source, f"soil.{key}", f"{err}; allowed: {p.allowed()}")
        elif p.default is None and key not in _SOIL_FIELDS:
            raise _fail(source, f"soil.{key}", f"missing required key of model {name!r}; "
                        f"allowed: {p.allowed()}")
    extra = tuple(sorted((k, v) for k, v in data.items() if k not in _SOIL_FIELDS))
    spec = _build(source, "soil", SoilSpec, {k: v for k, v in data.items() if k in _SOIL_FIELDS})
    return dataclasses.replace(spec, parameters=extra)


def check_seed(seed, option: str = "--seed") -> int | None:
    """A random-field seed: None (the scene's) or an integer in [0, 2**63 - 1]."""
    if seed is None:
        return None
    if isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed < 2**63:
        raise InputError(f"{option} {seed}: [seed] not allowed; allowed: an integer in "
                         "[0, 2^63 - 1] (numpy SeedSequence entropy)")
    return seed


def polygon_problem(poly) -> str | None:
    """What is wrong with a polygon [(x, y), ...] (m), or None: a repeated point, zero
    area (collinear points), or two edges that cross or touch (a bow-tie).  A last
    point equal to the first (an explicitly closed ring) is allowed."""
    p = np.asarray(poly, dtype=float)
    if len(p) > 3 and np.array_equal(p[0], p[-1]):
        p = p[:-1]
    scale = max(float(np.ptp(p, axis=0).max()), 1e-300)
    q = np.roll(p, -1, axis=0)
    short = np.linalg.norm(q - p, axis=1) <= 1e-12 * scale
    if short.any():
        i = int(np.argmax(short))
        return f"point {(i + 1) % len(p) + 1} ({p[(i + 1) % len(p)][0]:g}, {p[(i + 1) % len(p)][1]:g}) " \
               "repeats the point before it"
    a, b = p[:, None, :], q[:, None, :]            # edge i: a -> b;  edge j: c -> d
    c, d = p[None, :, :], q[None, :, :]

    def orient(u, v, w):
        return np.sign((v[..., 0] - u[..., 0]) * (w[..., 1] - u[..., 1])
                       - (v[..., 1] - u[..., 1]) * (w[..., 0] - u[..., 0]))
    cross = (orient(a, b, c) * orient(a, b, d) <= 0) & (orient(c, d, a) * orient(c, d, b) <= 0)
    for k in (0, 1):                               # bounding boxes overlap
        cross &= (np.minimum(a[..., k], b[..., k]) <= np.maximum(c[..., k], d[..., k])) & \
                 (np.minimum(c[..., k], d[..., k]) <= np.maximum(a[..., k], b[..., k]))
    n = len(p)
    i, j = np.triu_indices(n, k=2)
    keep = ~((i == 0) & (j == n - 1))              # adjacent through the closing edge
    hit = cross[i[keep], j[keep]]
    if hit.any():
        e1, e2 = int(i[keep][hit][0]), int(j[keep][hit][0])
        return (f"is self-intersecting: edge {e1 + 1} (from point {e1 + 1}) crosses or touches "
                f"edge {e2 + 1} (from point {e2 + 1}); a bow-tie cannot be filled")
    area = 0.5 * float(np.sum(p[:, 0] * q[:, 1] - q[:, 0] * p[:, 1]))
    if abs(area) <= 1e-12 * scale * scale:
        return "has zero area (its points are collinear)"
    return None


def _check_polygons(s: Scene) -> None:
    for base, items in (("soil", s.soils), ("bedrock", s.bedrock), ("prescribed", s.prescribed)):
        for k, item in enumerate(items):
            what = polygon_problem(item.polygon)
            if what:
                raise _fail(s.source, f"{base}[{k}].polygon", f"the polygon {what}; allowed: "
                            "a simple polygon (edges meet only at their shared points), "
                            "at least 3 distinct points, non-zero area (m)")


def _check_scene(s: Scene) -> None:
    src = s.source
    _check_polygons(s)
    gx, gy = s.grid.size
    if s.grid.file is None:
        if gx <= 0 or gy <= 0:
            raise _fail(src, "grid.size", "grid size must be positive (m)")
        hx, hy = s.grid.cell
        if hx <= 0 or hy <= 0:
            raise _fail(src, "grid.cell", "cell size must be positive (m)")
        for n, h, L in (("x", hx, gx), ("y", hy, gy)):
            k = L / h
            if abs(k - round(k)) > 1e-6 * max(1.0, k):
                raise _fail(src, "grid.cell", f"grid size {L:g} m is not a whole number of "
                            f"cells of {h:g} m along {n}")
    if not s.soils:
        raise _fail(src, "soil", "at least one [[soil]] table is required")
    names = [so.name for so in s.soils]
    if len(set(names)) != len(names):
        raise _fail(src, "soil.name", f"soil names must be unique, got {names}")
    for i, so in enumerate(s.soils):
        key = f"soil[{i}]"
        check = getattr(materials.model(so.model), "check", None)
        bad = check(soil_values(so)) if check else None
        if bad:
            raise _fail(src, f"{key}.{bad[0]}", bad[1])
        if s.grid.file is None:
            x0, y0 = s.grid.origin
            for (px, py) in so.polygon:
                tol = 1e-9 * max(gx, gy)
                if not (x0 - tol <= px <= x0 + gx + tol and y0 - tol <= py <= y0 + gy + tol):
                    raise _fail(src, f"{key}.polygon", f"point ({px:g}, {py:g}) m lies outside "
                                f"the grid [{x0:g}, {x0 + gx:g}] x [{y0:g}, {y0 + gy:g}] m")
    for i, pr in enumerate(s.prescribed):
        if s.solver.scheme != "implicit" or s.solver.dynamic:
            raise _fail(src, f"prescribed[{i}]", "prescribed displacements need load steps; "
                        "allowed: [solver] scheme = \"implicit\" with dynamic = false")
    if s.random_field is not None:
        rf = s.random_field
        if rf.soil is not None and rf.soil not in names:
            raise _fail(src, "random_field.soil", f"{rf.soil!r} is not a soil; allowed: {names}")
        if rf.distribution == "normal" and rf.cov > 0.5:
            raise _fail(src, "random_field.cov", f"{rf.cov:g} with a normal distribution gives "
                        "negative strengths too often; allowed: cov <= 0.5 or 'lognormal'")


def scene_from_dict(data: dict, source: str = "<dict>") -> Scene:
    """Build and validate a :class:`Scene` from parsed TOML (``source`` names the file)."""
    if not isinstance(data, dict):
        raise SceneError(f"{source}: [] expected a TOML table at the top level")
    unknown = sorted(set(data) - set(_SECTIONS))
    if unknown:
        raise _fail(source, unknown[0], "unknown section; allowed: "
                    + ", ".join(f"[{k}]" for k in _SECTIONS if k not in _LISTS)
                    + ", [[soil]], [[bedrock]], [[prescribed]]")
    if "soil" not in data:
        raise _fail(source, "soil", "missing required section [[soil]]")
    soils_raw = data["soil"] if isinstance(data["soil"], list) else [data["soil"]]
    soils = tuple(_build_soil(source, d) for d in soils_raw)
    rock_raw = data.get("bedrock", [])
    rock_raw = rock_raw if isinstance(rock_raw, list) else [rock_raw]
    presc_raw = data.get("prescribed", [])
    presc_raw = presc_raw if isinstance(presc_raw, list) else [presc_raw]
    scene = Scene(
        scene=_build(source, "scene", SceneInfo, data.get("scene", {})),
        grid=_build(source, "grid", GridSpec, data.get("grid", {})),
        boundary=_build(source, "boundary", BoundarySpec, data.get("boundary", {})),
        soils=soils,
        bedrock=tuple(_build(source, "bedrock", BedrockSpec, d) for d in rock_raw),
        prescribed=tuple(_build(source, "prescribed", PrescribedSpec, d) for d in presc_raw),
        random_field=(_build(source, "random_field", RandomFieldSpec, data["random_field"])
                      if "random_field" in data else None),
        solver=_build(source, "solver", SolverSpec, data.get("solver", {})),
        montecarlo=_build(source, "montecarlo", MonteCarloSpec, data.get("montecarlo", {})),
        output=_build(source, "output", OutputSpec, data.get("output", {})),
        source=source,
    )
    if scene.grid.file is not None and source not in ("<dict>",):
        p = Path(scene.grid.file)
        if not p.is_absolute():
            p = Path(source).parent / p
        scene = dataclasses.replace(scene, grid=dataclasses.replace(scene.grid, file=str(p)))
    _check_scene(scene)
    return scene


def load_scene(path: str | Path) -> Scene:
    """Read and validate a scene file (TOML). Raises :class:`SceneError` on any problem."""
    path = Path(path)
    source = str(path)
    if not path.exists():
        raise SceneError(f"{source}: [] file not found; allowed: a path to a TOML scene file")
    if path.is_dir():
        raise SceneError(f"{source}: [] is a directory; allowed: a path to a TOML scene file")
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8-sig"))   # a UTF-8 BOM is accepted
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise SceneError(f"{source}: [] not valid TOML ({exc}); allowed: a TOML scene file "
                         "(see meshes/*.toml)") from None
    return scene_from_dict(data, source)


def scene_to_dict(scene: Scene) -> dict:
    """Plain-data view of a scene (for ``summary.json``); inverse of :func:`scene_from_dict`."""
    out: dict[str, Any] = {}
    for name in ("scene", "grid", "boundary", "solver", "montecarlo", "output"):
        out[name] = dataclasses.asdict(getattr(scene, name))
    out["soil"] = [{**{k: v for k, v in dataclasses.asdict(s).items() if k != "parameters"},
                    **dict(s.parameters)} for s in scene.soils]
    if scene.bedrock:
        out["bedrock"] = [dataclasses.asdict(b) for b in scene.bedrock]
    if scene.prescribed:
        out["prescribed"] = [dataclasses.asdict(b) for b in scene.prescribed]
    if scene.random_field is not None:
        out["random_field"] = dataclasses.asdict(scene.random_field)

    def clean(v: Any) -> Any:
        if isinstance(v, dict):
            return {k: clean(x) for k, x in v.items() if x is not None}
        if isinstance(v, (list, tuple)):
            return [clean(x) for x in v]
        if isinstance(v, float) and not math.isfinite(v):
            return str(v)
        return v
    return clean(out)
