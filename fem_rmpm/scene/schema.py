"""Scene files: parse a TOML scene, check every value and build the dataclasses of
:mod:`fem_rmpm.scene.spec`.

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

from fem_rmpm import materials
from fem_rmpm.materials.points import soil_values
from fem_rmpm.runtime.errors import InputError
from fem_rmpm.scene.dimension import check_dimension, with_grid_dimension
from fem_rmpm.scene.fields import build_random_field, check_random_field, random_field_to_dict
from fem_rmpm.scene.overlap import overlap_point
from fem_rmpm.scene.spec import (
    _SOIL_FIELDS,
    BedrockSpec,
    BoundarySpec,
    GridSpec,
    MonteCarloSpec,
    OutputSpec,
    PrescribedSpec,
    RandomFieldSpec,
    Scene,
    SceneError,
    SceneInfo,
    SoilSpec,
    SolverSpec,
    WaterSpec,
)
from fem_rmpm.scene.values import _build, _fail, _infinity
from fem_rmpm.scene.water import build_water, check_water, water_to_dict

__all__ = ["load_scene", "scene_from_dict", "scene_to_dict", "check_seed", "polygon_problem"]

# --------------------------------------------------------------------------- validation

_SECTIONS = {"scene": SceneInfo, "grid": GridSpec, "boundary": BoundarySpec, "soil": SoilSpec,
             "bedrock": BedrockSpec, "prescribed": PrescribedSpec,
             "random_field": RandomFieldSpec, "solver": SolverSpec,
             "montecarlo": MonteCarloSpec, "output": OutputSpec, "water": WaterSpec}

_LISTS = ("soil", "bedrock", "prescribed")     # sections that are arrays of tables
_SOIL_DEFAULT = {f.name: f.default for f in dataclasses.fields(SoilSpec)}


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
        elif p.default is None and (key not in _SOIL_FIELDS or p.check(_SOIL_DEFAULT[key])):
            # a shared field's default (c = inf: no strength) stands in only where allowed
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


def _candidate_pairs(p: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pairs ``i < j`` of non-adjacent edges (edge k: ``p[k] -> q[k]``) that share a
    bucket of a uniform grid: every pair that can cross (a pair may repeat).  Each edge is
    cut into pieces no longer than a bucket and lies in the buckets of its pieces'
    bounding boxes (slightly widened against rounding), so a long edge covers a line of
    buckets, not its bounding box.  The buckets are about the size of the median edge,
    doubled until there are at most ~4 pieces per edge: near-linear in the number of
    edges for a polygon's edges."""
    n = len(p)
    extent = np.abs(q - p).max(axis=1)
    side = max(float(np.median(extent)), 1e-300)
    while True:
        pieces = np.maximum(np.ceil(extent / side).astype(np.int64), 1)
        if pieces.sum() <= 4 * n + 64:
            break
        side *= 2.0
    owner = np.repeat(np.arange(n), pieces)
    t = (np.arange(len(owner)) - np.repeat(np.cumsum(pieces) - pieces, pieces))[:, None]
    m = pieces[owner][:, None]
    u = p[owner] + (q[owner] - p[owner]) * (t / m)
    v = p[owner] + (q[owner] - p[owner]) * ((t + 1) / m)
    pad = 1e-9 * side
    origin = np.minimum(p, q).min(axis=0) - 2 * pad
    k0 = np.floor((np.minimum(u, v) - pad - origin) / side).astype(np.int64)
    k1 = np.floor((np.maximum(u, v) + pad - origin) / side).astype(np.int64)
    span = k1 - k0 + 1
    cells = span[:, 0] * span[:, 1]
    piece = np.repeat(np.arange(len(owner)), cells)  # one entry per (piece, bucket)
    offset = np.arange(len(piece)) - np.repeat(np.cumsum(cells) - cells, cells)
    bx = k0[piece, 0] + offset % span[piece, 0]
    by = k0[piece, 1] + offset // span[piece, 0]
    bucket = by * (int(k1[:, 0].max()) + 1) + bx
    edge = owner[piece]
    order = np.lexsort((edge, bucket))
    bucket, edge = bucket[order], edge[order]
    first = np.ones(len(edge), dtype=bool)            # an edge once per bucket
    first[1:] = (bucket[1:] != bucket[:-1]) | (edge[1:] != edge[:-1])
    bucket, edge = bucket[first], edge[first]
    pairs_i, pairs_j = [], []
    for step in range(1, len(edge)):                 # entries ``step`` apart in one bucket
        same = bucket[step:] == bucket[:-step]
        if not same.any():
            break
        pairs_i.append(edge[:-step][same])
        pairs_j.append(edge[step:][same])
    if not pairs_i:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    i, j = np.concatenate(pairs_i), np.concatenate(pairs_j)
    keep = (j - i >= 2) & ~((i == 0) & (j == n - 1))  # adjacent edges share a point
    return i[keep], j[keep]


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
        k = (int(np.argmax(short)) + 1) % len(p)       # the repeated point (0-based)
        return f"point {k + 1} ({p[k][0]:g}, {p[k][1]:g}) repeats the point before it"
    i, j = _candidate_pairs(p, q)
    a, b, c, d = p[i], q[i], p[j], q[j]            # edge i: a -> b;  edge j: c -> d

    def orient(u, v, w):
        return np.sign((v[..., 0] - u[..., 0]) * (w[..., 1] - u[..., 1])
                       - (v[..., 1] - u[..., 1]) * (w[..., 0] - u[..., 0]))
    hit = (orient(a, b, c) * orient(a, b, d) <= 0) & (orient(c, d, a) * orient(c, d, b) <= 0)
    for k in (0, 1):                               # bounding boxes overlap
        hit &= (np.minimum(a[..., k], b[..., k]) <= np.maximum(c[..., k], d[..., k])) & \
               (np.minimum(c[..., k], d[..., k]) <= np.maximum(a[..., k], b[..., k]))
    if hit.any():
        first = np.lexsort((j[hit], i[hit]))[0]     # the first pair in (i, j) order
        e1, e2 = int(i[hit][first]), int(j[hit][first])
        return (f"is self-intersecting: edge {e1 + 1} (from point {e1 + 1}) crosses or touches "
                f"edge {e2 + 1} (from point {e2 + 1}); a bow-tie cannot be filled")
    area = 0.5 * float(np.sum(p[:, 0] * q[:, 1] - q[:, 0] * p[:, 1]))
    if abs(area) <= 1e-12 * scale * scale:
        return "has zero area (its points are collinear)"
    return None


#: The most points of one polygon: seeding tests every cell centre near the polygon once
#: per edge (:func:`fem_rmpm.discretise.grid.points_in_polygon`), so a finer outline costs
#: time in every run and adds nothing at the grid's resolution.
MAX_POLYGON_POINTS = 100_000
#: The largest scene file read (bytes), checked before parsing: a scene is a few tables
#: (large data are CSV files named in it); a bigger file is refused at once.
MAX_SCENE_BYTES = 16 * 2**20


def _check_polygons(s: Scene) -> None:
    for base, items in (("soil", s.soils), ("bedrock", s.bedrock), ("prescribed", s.prescribed)):
        for k, item in enumerate(items):
            if len(item.polygon) > MAX_POLYGON_POINTS:
                raise _fail(s.source, f"{base}[{k}].polygon", f"the polygon has "
                            f"{len(item.polygon)} points; allowed: at most "
                            f"{MAX_POLYGON_POINTS} points (finer than the grid adds nothing)")
            what = polygon_problem(item.polygon)
            if what:
                raise _fail(s.source, f"{base}[{k}].polygon", f"the polygon {what}; allowed: "
                            "a simple polygon (edges meet only at their shared points), "
                            "at least 3 distinct points, non-zero area (m)")
    for k, so in enumerate(s.soils):                   # 3-D: the plan shape [[x, z], ...]
        what = polygon_problem(so.plan) if so.plan is not None else None
        if what:
            raise _fail(s.source, f"soil[{k}].plan", f"the polygon {what}; allowed: a simple "
                        "polygon [[x, z], ...] of non-zero area (m)")


def _check_soil_overlap(s: Scene) -> None:
    """Refuse two soils that share area (which soil a shared cell takes would be the
    file's order, not the user's choice); touching edges are fine."""
    for j, b in enumerate(s.soils):
        for i, a in enumerate(s.soils[:j]):
            at = overlap_point(a.polygon, b.polygon)
            if at is not None:
                raise _fail(s.source, f"soil[{j}].polygon", f"soils {a.name!r} (soil[{i}]) "
                            f"and {b.name!r} (soil[{j}]) overlap, e.g. at ({at[0]:.6g}, "
                            f"{at[1]:.6g}) m; allowed: soils that share no area (touching "
                            "edges are fine)")


def _check_soils(s: Scene) -> None:
    """At least one soil, unique names, no shared area, each model's own check."""
    src = s.source
    if not s.soils:
        raise _fail(src, "soil", "at least one [[soil]] table is required")
    names = [so.name for so in s.soils]
    if len(set(names)) != len(names):
        raise _fail(src, "soil.name", f"soil names must be unique, got {names}")
    if s.grid.dimension == 2:         # 3-D soils may share a section over other strikes
        _check_soil_overlap(s)
    for i, so in enumerate(s.soils):
        check = getattr(materials.model(so.model), "check", None)
        bad = check(soil_values(so)) if check else None
        if bad:
            raise _fail(src, f"soil[{i}].{bad[0]}", bad[1])


def _check_interfaces(s: Scene) -> None:
    """A rough bedrock takes no interface keys; a frictional one needs ``friction`` and
    the explicit scheme (the implicit scheme has no contact: refused, not ignored)."""
    for k, rock in enumerate(s.bedrock):
        key = f"bedrock[{k}]"
        if rock.interface == "rough":
            given = [n for n in ("friction", "adhesion") if getattr(rock, n) is not None]
            if given:
                raise _fail(s.source, f"{key}.{given[0]}", "a rough bedrock (no slip) takes "
                            "no friction or adhesion; allowed: interface = \"frictional\" "
                            "with friction (and adhesion), or neither key")
            continue
        if rock.friction is None:
            raise _fail(s.source, f"{key}.friction", "missing for interface = \"frictional\"; "
                        "allowed: a Coulomb coefficient in [0, 10] (-)")
        if s.solver.scheme != "explicit":
            raise _fail(s.source, f"{key}.interface", "a frictional interface is supported "
                        "by the explicit scheme only; allowed: interface = \"rough\" with "
                        "[solver] scheme = \"implicit\"")


def _check_scene(s: Scene) -> None:
    src = s.source
    _check_polygons(s)
    check_dimension(s)                  # keys of the other dimension; 3-D: its own checks
    if s.grid.dimension == 3:
        _check_soils(s)
        for k, rock in enumerate(s.bedrock):     # 3-D bedrock is rough (its nodes fixed)
            if rock.interface != "rough":
                raise _fail(src, f"bedrock[{k}].interface", "a frictional interface is "
                            "supported in two dimensions only; allowed in 3-D: \"rough\"")
        return
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
    _check_soils(s)
    for i, so in enumerate(s.soils):
        key = f"soil[{i}]"
        if s.grid.file is None:
            x0, y0 = s.grid.origin
            for (px, py) in so.polygon:
                tol = 1e-9 * max(gx, gy)
                if not (x0 - tol <= px <= x0 + gx + tol and y0 - tol <= py <= y0 + gy + tol):
                    raise _fail(src, f"{key}.polygon", f"point ({px:g}, {py:g}) m lies outside "
                                f"the grid [{x0:g}, {x0 + gx:g}] x [{y0:g}, {y0 + gy:g}] m")
    _check_interfaces(s)
    for i, pr in enumerate(s.prescribed):
        if s.solver.scheme != "implicit" or s.solver.dynamic:
            raise _fail(src, f"prescribed[{i}]", "prescribed displacements need load steps; "
                        "allowed: [solver] scheme = \"implicit\" with dynamic = false")
    if s.random_field is not None:
        check_random_field(s)
    check_water(s)                   # [water] and the soils' drainage (scene.water)


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
        grid=with_grid_dimension(source, _build(source, "grid", GridSpec, data.get("grid", {})),
                                 data.get("grid", {})),
        boundary=_build(source, "boundary", BoundarySpec, data.get("boundary", {})),
        soils=soils,
        bedrock=tuple(_build(source, "bedrock", BedrockSpec, d) for d in rock_raw),
        prescribed=tuple(_build(source, "prescribed", PrescribedSpec, d) for d in presc_raw),
        random_field=(build_random_field(source, data["random_field"])
                      if "random_field" in data else None),
        solver=_build(source, "solver", SolverSpec, data.get("solver", {})),
        montecarlo=_build(source, "montecarlo", MonteCarloSpec, data.get("montecarlo", {})),
        output=_build(source, "output", OutputSpec, data.get("output", {})),
        source=source,
        water=build_water(source, data["water"]) if "water" in data else None,
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
        size = path.stat().st_size
        if size > MAX_SCENE_BYTES:
            raise SceneError(f"{source}: [] a file of {size / 2**20:.0f} MiB; allowed: a scene "
                             f"file of at most {MAX_SCENE_BYTES // 2**20} MiB (give large data "
                             "as CSV files named in it)")
        text = path.read_text(encoding="utf-8-sig")    # a UTF-8 BOM is accepted
    except UnicodeDecodeError as exc:
        raise SceneError(f"{source}: [] not valid TOML ({exc}); allowed: a TOML scene file "
                         "(see meshes/*.toml)") from None
    except OSError as exc:
        raise SceneError(f"{source}: [] cannot be read ({exc.strerror}); needed: read "
                         "permission on the scene file") from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise SceneError(f"{source}: [] not valid TOML ({exc}); allowed: a TOML scene file "
                         "(see meshes/*.toml)") from None
    except RecursionError:
        raise SceneError(f"{source}: [] arrays or tables nested too deeply to read; allowed: "
                         "a TOML scene file (see meshes/*.toml)") from None
    return scene_from_dict(data, source)


def scene_to_dict(scene: Scene) -> dict:
    """Plain-data view of a scene (for ``summary.json``); inverse of :func:`scene_from_dict`."""
    out: dict[str, Any] = {}
    for name in ("scene", "grid", "boundary", "solver", "montecarlo", "output"):
        out[name] = dataclasses.asdict(getattr(scene, name))
    out["soil"] = [{**{k: v for k, v in dataclasses.asdict(s).items() if k != "parameters"},
                    **dict(s.parameters)} for s in scene.soils]
    if scene.bedrock:
        out["bedrock"] = [{k: v for k, v in dataclasses.asdict(b).items()    # rough: as before
                           if not (k == "interface" and v == "rough")} for b in scene.bedrock]
    if scene.prescribed:
        out["prescribed"] = [dataclasses.asdict(b) for b in scene.prescribed]
    if scene.random_field is not None:
        out["random_field"] = random_field_to_dict(scene.random_field)
    if scene.water is not None:
        out["water"] = water_to_dict(scene.water)

    def clean(v: Any) -> Any:
        if isinstance(v, dict):
            return {k: clean(x) for k, x in v.items() if x is not None}
        if isinstance(v, (list, tuple)):
            return [clean(x) for x in v]
        if isinstance(v, float) and not math.isfinite(v):
            return str(v)
        return v
    return clean(out)
