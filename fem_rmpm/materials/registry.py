"""The registry of material models: model ids, parameter columns, the dispatch version.

A model's id is its position in the registry (the order of :func:`register` calls),
which is what a point's ``model`` entry and the kernels' dispatch use.  Registering a
model of a name already there replaces it in place (same id).
"""
from __future__ import annotations

import inspect
import zlib
from types import ModuleType

__all__ = ["register", "unregister", "model", "model_id", "names", "column", "parameter", "version",
           "n_parameters", "n_state"]

_MODELS: list[ModuleType] = []
_VERSION = [0]
_REQUIRED = ("NAME", "PARAMETERS", "STATE", "update", "point_update")


def register(module: ModuleType) -> int:
    """Add a model module (see :mod:`fem_rmpm.materials.protocol`); returns its id."""
    missing = [a for a in _REQUIRED if not hasattr(module, a)]
    if missing:
        raise TypeError(f"material model {module!r} lacks {', '.join(missing)}")
    if module.STATE and module.STATE[0] != "plastic_shear_strain":
        raise TypeError(f"material model {module.NAME!r}: the first state variable must be "
                        "plastic_shear_strain")
    _check_declarations(module)
    for k, m in enumerate(_MODELS):
        if m.NAME == module.NAME:
            _MODELS[k] = module
            break
    else:
        _MODELS.append(module)
        k = len(_MODELS) - 1
    _VERSION[0] = _source_hash()
    return k


def _check_declarations(module: ModuleType) -> None:
    """The names a model's ``STRENGTHS`` and ``REGULARISABLE`` give are its own parameters
    and state variables, and a regularisable model has the hooks the regularisation calls."""
    params = {p.name for p in module.PARAMETERS}
    for s in getattr(module, "STRENGTHS", ()):
        unknown = [n for n in (s.name, s.peak, s.bound) if n is not None and n not in params]
        if unknown:
            raise TypeError(f"material model {module.NAME!r}: STRENGTHS names "
                            f"{', '.join(unknown)}, not among its PARAMETERS")
    reg = getattr(module, "REGULARISABLE", None)
    if reg is None:
        return
    unknown = [n for n in (reg.strain, reg.variable, reg.averaged) if n not in module.STATE]
    unknown += [] if reg.softening_strain in params else [reg.softening_strain]
    if unknown:
        raise TypeError(f"material model {module.NAME!r}: REGULARISABLE names "
                        f"{', '.join(unknown)}, not among its STATE and PARAMETERS")
    missing = [h for h in ("fully_softened", "softening_modulus") if not hasattr(module, h)]
    if missing:
        raise TypeError(f"material model {module.NAME!r}: REGULARISABLE without the hooks "
                        f"{', '.join(missing)}")


def unregister(name: str) -> None:
    """Remove a model (for tests that add one; the ids of later models move down by one)."""
    _MODELS[:] = [m for m in _MODELS if m.NAME != name]
    _VERSION[0] = _source_hash()


def model(key: int | str) -> ModuleType:
    """The model module of an id or a name."""
    return _MODELS[key] if isinstance(key, int) else _MODELS[model_id(key)]


def model_id(name: str) -> int:
    for k, m in enumerate(_MODELS):
        if m.NAME == name:
            return k
    raise KeyError(f"unknown material model {name!r}; registered: {', '.join(names())}")


def models() -> tuple[ModuleType, ...]:
    return tuple(_MODELS)


def names() -> tuple[str, ...]:
    return tuple(m.NAME for m in _MODELS)


def column(key: int | str, name: str) -> int | None:
    """Column of parameter ``name`` in the rows of model ``key`` (None: not its parameter)."""
    if name == "shear_modulus":
        return 0
    if name == "bulk_modulus":
        return 1
    for j, p in enumerate(model(key).PARAMETERS):
        if p.name == name:
            return 2 + j
    return None


def parameter(name: str):
    """The first declaration of a parameter ``name`` among the registered models."""
    for m in _MODELS:
        for p in m.PARAMETERS:
            if p.name == name:
                return p
    return None


def n_parameters(ids=None) -> int:
    """Row length P for the models ``ids`` (default: all registered)."""
    ms = _MODELS if ids is None else [_MODELS[int(k)] for k in ids]
    return 2 + max((len(m.PARAMETERS) for m in ms), default=0)


def n_state(ids=None) -> int:
    """State width S (at least 1: the plastic shear strain column) for the models ``ids``."""
    ms = _MODELS if ids is None else [_MODELS[int(k)] for k in ids]
    return max([1] + [len(m.STATE) for m in ms])


def version() -> int:
    """A number that changes when the registry or a model's source changes: the explicit
    kernels' dispatch is compiled (and cached on disk by numba) once per version."""
    return _VERSION[0]


def _source_hash() -> int:
    h = 0
    for m in _MODELS:
        try:
            src = inspect.getsource(m)
        except (OSError, TypeError):
            src = repr(m)
        h = zlib.crc32(f"{m.NAME}\n{src}".encode(), h)
    return h
