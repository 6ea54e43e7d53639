"""The dimension of a scene: two (plane strain) or three (hexahedra), read from the number
of ``[grid] size`` values, and the checks that every key agrees with it.

A three-dimensional scene is a grid ``origin = [x0, y0, z0]``, ``size = [Lx, Ly, Lz]``,
``cell = [hx, hy, hz]`` (or one number), y up (gravity in the x-y plane) and z the strike.
A soil is its ``polygon``, an x-y section, extruded along z over ``strike = [z0, z1]``
(default: the whole grid) and cut in plan by ``plan = [[x, z], ...]`` (optional); a
``[[bedrock]]`` polygon is extruded over the whole grid.  The boundary has six faces:
``left``/``right`` (x), ``bottom``/``top`` (y), ``front``/``back`` (z = z0 / z0 + Lz,
default roller).  What the three-dimensional scheme does not have yet is refused here,
with the key that asks for it: prescribed displacements, the implicit scheme, uGIMP,
F-bar, the numpy kernel, a mesh file, pore water, material models other than linear
elastic, von Mises softening and Mohr-Coulomb softening, and regularised softening.

A ``[random_field]`` in 3-D (:mod:`fem_rmpm.random_field.points3d`) draws the peak cohesion
(``property = "cohesion_peak"``) with the strike scale ``theta_strike`` (m) and, for the
box rule, ``box = [x0, y0, z0, x1, y1, z1]``; conditioning on data (``data``) is
refused.  In 2-D, ``theta_strike`` and a six-number box are refused.
"""
from __future__ import annotations

import dataclasses


from fem_rmpm.scene.fields import check_random_field
from fem_rmpm.scene.spec import GridSpec, Scene
from fem_rmpm.scene.values import _fail

__all__ = ["with_grid_dimension", "check_dimension", "strike_range", "refuse_three_d",
           "MODELS_3D"]

#: Material models the three-dimensional explicit scheme updates.
MODELS_3D = ("linear_elastic", "von_mises_softening", "mohr_coulomb_softening")
#: Properties a 3-D random field draws (:data:`fem_rmpm.random_field.points3d.PROPERTIES_3D`,
#: repeated here: the scene layer does not import the random-field layer).
FIELD_PROPERTIES_3D = ("cohesion_peak",)


def with_grid_dimension(source: str, grid: GridSpec, raw: dict) -> GridSpec:
    """``grid`` with a one-number ``cell`` repeated per size and a default ``origin`` or
    ``cell`` of the grid's dimension; one-line error when the three keys disagree."""
    dim = grid.dimension
    if dim not in (2, 3):
        raise _fail(source, "grid.size", f"{dim} sizes; allowed: [Lx, Ly] (plane strain) or "
                    "[Lx, Ly, Lz] (three-dimensional), m")
    cell, origin = grid.cell, grid.origin
    if len(cell) == 1 or "cell" not in raw:
        cell = (cell[0],) * dim
    if "origin" not in raw:
        origin = (0.0,) * dim
    for key, value in (("origin", origin), ("cell", cell)):
        if len(value) != dim:
            raise _fail(source, f"grid.{key}", f"{len(value)} numbers for a grid of {dim} "
                        f"sizes; allowed: {dim} numbers, as many as [grid] size (2: plane "
                        "strain, 3: three-dimensional)")
    return dataclasses.replace(grid, origin=tuple(origin), cell=tuple(cell))


def check_dimension(s: Scene) -> None:
    """Refuse keys of the other dimension: in 2-D the strike keys, in 3-D what the
    three-dimensional scheme does not do yet (module docstring)."""
    if s.grid.dimension == 2:
        _refuse_3d_keys(s)
    else:
        _check_3d(s)


def _refuse_3d_keys(s: Scene) -> None:
    why = ("allowed: only in a three-dimensional scene ([grid] size = [Lx, Ly, Lz])")
    for face in ("front", "back"):
        if getattr(s.boundary, face) is not None:
            raise _fail(s.source, f"boundary.{face}", f"a face of a 2-D grid; {why}")
    for i, so in enumerate(s.soils):
        for key in ("strike", "plan"):
            if getattr(so, key) is not None:
                raise _fail(s.source, f"soil[{i}].{key}", f"set in a 2-D grid; {why}")
    rf = s.random_field
    if rf is not None and rf.theta_strike is not None:
        raise _fail(s.source, "random_field.theta_strike", f"a strike scale of fluctuation "
                    f"in a 2-D scene; {why}")
    if rf is not None and rf.box is not None and len(rf.box) != 4:
        raise _fail(s.source, "random_field.box", f"{len(rf.box)} numbers in a 2-D scene; "
                    "allowed: four, [x0, y0, x1, y1] (m)")


def _check_field_3d(s: Scene) -> None:
    """The ``[random_field]`` of a 3-D scene: its property, box and data (module
    docstring), then the checks of every field against the soils."""
    rf = s.random_field
    if rf.box is not None and len(rf.box) != 6:
        raise _fail(s.source, "random_field.box", f"{len(rf.box)} numbers in a "
                    "three-dimensional scene; allowed: six, [x0, y0, z0, x1, y1, z1] (m)")
    for k, f in enumerate(rf.fields()):
        key = f"random_field.properties[{k}]" if rf.properties else "random_field"
        if f.property not in FIELD_PROPERTIES_3D:
            raise _fail(s.source, f"{key}.property", f"{f.property!r} in a three-dimensional "
                        "scene; allowed: " + " | ".join(repr(p) for p in FIELD_PROPERTIES_3D)
                        + " (the strength of von Mises softening)")
        if f.data is not None:
            raise _fail(s.source, f"{key}.data", "conditioning on data in a "
                        "three-dimensional scene; allowed: no data (3-D conditioning is in "
                        "the Python API, fem_rmpm.random_field.field3d)")
    check_random_field(s)


def _check_3d(s: Scene) -> None:
    src, g = s.source, s.grid
    unsupported = (
        (g.file is not None, "grid.file", "a mesh file", "a structured grid (origin, size, "
         "cell)"),
        (bool(s.prescribed), "prescribed", "prescribed displacements", "none in 3-D"),
        (s.solver.scheme != "explicit", "solver.scheme", f"scheme {s.solver.scheme!r}",
         "'explicit' (the implicit scheme is plane strain only)"),
        (s.solver.shape != "standard", "solver.shape", f"shape {s.solver.shape!r}",
         "'standard' (trilinear hexahedra; uGIMP is plane strain only)"),
        (s.solver.fbar, "solver.fbar", "F-bar", "false (plane strain only)"),
        (s.solver.kernel != "numba", "solver.kernel", f"kernel {s.solver.kernel!r}",
         "'numba' (the numpy reference step is plane strain only)"),
    )
    for bad, key, what, allowed in unsupported:
        if bad:
            raise _fail(src, key, f"{what} in a three-dimensional scene; allowed: {allowed}")
    if s.water is not None:
        raise _fail(src, "water", "pore water in a three-dimensional scene; allowed: a dry 3-D "
                    "scene (no [water]; the pore pressure is plane strain only)")
    lo, size, cell = g.origin, g.size, g.cell
    for k, axis in enumerate("xyz"):
        if size[k] <= 0:
            raise _fail(src, "grid.size", f"grid size along {axis} must be positive (m)")
        if cell[k] <= 0:
            raise _fail(src, "grid.cell", "cell size must be positive (m)")
        n = size[k] / cell[k]
        if abs(n - round(n)) > 1e-6 * max(1.0, n):
            raise _fail(src, "grid.cell", f"grid size {size[k]:g} m is not a whole number of "
                        f"cells of {cell[k]:g} m along {axis}")
    hi = [lo[k] + size[k] for k in range(3)]
    tol = 1e-9 * max(size)
    for i, so in enumerate(s.soils):
        if so.model not in MODELS_3D:
            raise _fail(src, f"soil[{i}].model", f"model {so.model!r} in a three-dimensional "
                        f"scene; allowed: {' | '.join(repr(m) for m in MODELS_3D)}")
        if so.model == "von_mises_softening" and \
                so.value("regularisation", "local") != "local":
            raise _fail(src, f"soil[{i}].regularisation", f"{so.value('regularisation')!r} "
                        "in a three-dimensional scene; allowed: 'local'")
        _inside(src, f"soil[{i}].polygon", so.polygon, (0, 1), lo, hi, tol)
        if so.strike is not None:
            z0, z1 = so.strike
            if not (lo[2] - tol <= z0 < z1 <= hi[2] + tol):
                raise _fail(src, f"soil[{i}].strike", f"[{z0:g}, {z1:g}] m; allowed: z0 < z1 "
                            f"within the grid's [{lo[2]:g}, {hi[2]:g}] m")
        if so.plan is not None:      # (a simple polygon: checked with the sections)
            _inside(src, f"soil[{i}].plan", so.plan, (0, 2), lo, hi, tol)
    if s.random_field is not None:
        _check_field_3d(s)


def _inside(src: str, key: str, poly, axes: tuple[int, int], lo, hi, tol: float) -> None:
    a, b = axes
    names = "xyz"
    for p in poly:
        if not (lo[a] - tol <= p[0] <= hi[a] + tol and lo[b] - tol <= p[1] <= hi[b] + tol):
            raise _fail(src, key, f"point ({p[0]:g}, {p[1]:g}) m lies outside the grid "
                        f"[{lo[a]:g}, {hi[a]:g}] x [{lo[b]:g}, {hi[b]:g}] m ({names[a]}, "
                        f"{names[b]})")


def refuse_three_d(s: Scene, command: str) -> None:
    """Raise a one-line :class:`SceneError` when ``s`` is three-dimensional and
    ``fem-rmpm COMMAND`` works on plane-strain scenes only (``fs``, ``field``,
    ``converge``)."""
    if s.grid.dimension == 3:
        raise _fail(s.source, "grid.size", f"a three-dimensional scene: 'fem-rmpm {command}' "
                    "does not support 3-D scenes yet; allowed: a plane-strain grid "
                    "([grid] size = [Lx, Ly]); 3-D scenes run with 'fem-rmpm run' and "
                    "'fem-rmpm fem'")


def strike_range(s: Scene, soil) -> tuple[float, float]:
    """The z range (m) a soil is extruded over: its ``strike``, else the whole grid."""
    if soil.strike is not None:
        return soil.strike
    return (s.grid.origin[2], s.grid.origin[2] + s.grid.size[2])



