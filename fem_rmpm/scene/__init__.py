"""Scenes: the public face of the scene layer, and changing values of a scene.

:func:`with_value` / :func:`with_values` return a validated, modified copy of a scene
(for driver scripts, ``--set`` and campaign cases).  The spec dataclasses live in
:mod:`fem_rmpm.scene.spec`, reading and validating TOML in :mod:`fem_rmpm.scene.schema`
(typed values :mod:`fem_rmpm.scene.values`, the random field :mod:`fem_rmpm.scene.fields`,
the dimension of a scene :mod:`fem_rmpm.scene.dimension`, the pore water
:mod:`fem_rmpm.scene.water`);
every public name of both is re-exported here, so ``from fem_rmpm.scene import
load_scene, Scene, SceneError`` keeps working.
"""
from __future__ import annotations

import re
from typing import Any

from fem_rmpm.scene.schema import (
    _LISTS,
    check_seed,
    load_scene,
    polygon_problem,
    scene_from_dict,
    scene_to_dict,
)
from fem_rmpm.scene.spec import (
    BedrockSpec,
    BoundarySpec,
    GridSpec,
    MonteCarloSpec,
    OutputSpec,
    PrescribedSpec,
    PropertyFieldSpec,
    RandomFieldSpec,
    Scene,
    SceneError,
    SceneInfo,
    SoilSpec,
    SolverSpec,
)
from fem_rmpm.scene.values import _fail

__all__ = [
    "SceneError", "Scene", "SceneInfo", "GridSpec", "BoundarySpec", "SoilSpec",
    "BedrockSpec", "PrescribedSpec", "RandomFieldSpec", "PropertyFieldSpec", "SolverSpec",
    "MonteCarloSpec", "OutputSpec", "load_scene", "scene_from_dict", "with_value", "with_values",
    "scene_to_dict",
    "check_seed", "polygon_problem",
]


def _list_index(source: str, key: str, section: str, data: dict) -> tuple[str, int | None]:
    """``soil`` -> ("soil", None); ``soil[1]`` -> ("soil", 1), checked against the scene."""
    m = re.fullmatch(r"([a-z_]+)(?:\[([^\]]*)\])?", section)
    base = m.group(1) if m else section.split("[")[0]
    n = len(data.get(base, []))
    allowed = (f"{base}.KEY (every table) or {base}[i].KEY with i = 0" +
               (f"..{n - 1}" if n > 1 else "") if n else f"none: the scene has no [[{base}]]")
    if base not in data:
        raise _fail(source, key, f"the scene has no [[{base}]] table; allowed: {allowed}")
    if m is None or m.group(2) is None:
        if m is None or "[" in section:
            raise _fail(source, key, f"malformed table index; allowed: {allowed}")
        return base, None
    if not m.group(2).isdigit() or int(m.group(2)) >= n:
        raise _fail(source, key, f"no [[{base}]] table number {m.group(2)!r} (the scene has "
                    f"{n}); allowed: {allowed}")
    return base, int(m.group(2))


def with_value(scene: Scene, key: str, value: Any) -> Scene:
    """Return a validated copy of ``scene`` with one value changed.

    ``key`` is dotted: ``"solver.cfl"``, ``"soil.youngs_modulus"`` (all soils) or
    ``"soil[1].cohesion_peak"``, ``"random_field.anisotropy"`` (creates the
    section if the scene has none).  See :func:`with_values` for several at once.
    """
    return with_values(scene, {key: value})


def with_values(scene: Scene, changes: dict[str, Any]) -> Scene:
    """Return a validated copy of ``scene`` with several values changed together
    (validated once, after all changes: e.g. a new grid size and a new polygon)."""
    data = scene_to_dict(scene)      # infinities as "inf": read back by scene_from_dict
    for key, value in changes.items():
        section, _, name = key.partition(".")
        if not name:
            raise SceneError(f"{scene.source}: [{key}] expected a dotted key like 'solver.cfl'")
        if section.split("[")[0] in _LISTS:
            base, idx = _list_index(scene.source, key, section, data)
            targets = data[base] if idx is None else [data[base][idx]]
            for t in targets:
                t[name] = value
                if name == "model":      # a default "no strength" is not a value for the new
                    for k in ("cohesion_peak", "cohesion_residual"):   # model to check
                        if t.get(k) == "inf":
                            del t[k]
        elif section == "random_field" and "random_field" not in data:
            data["random_field"] = {name: value}
        else:
            if section not in data:
                raise _fail(scene.source, key, "unknown section")
            data[section][name] = value
    return scene_from_dict(data, scene.source)
