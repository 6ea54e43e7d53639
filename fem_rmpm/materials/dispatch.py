"""One dispatch on the model id for the explicit kernels, generated from the registry.

``point_dispatch(version, only, model, e0, e1, e2, e3, state, params, i)`` calls the
``point_update`` of model number ``model`` (see :mod:`.protocol`).  ``only`` (a literal,
like ``version``): -1 for any model, or the id of the one model all points of the call
share — then the body is that model's update alone (no chain over the other models:
their code is not compiled into the kernel, and the loop around it optimises as if the
model were written there, about a third faster than through the chain).  It is a numba
``overload`` whose body (an if-chain over the registered models) is written when a
kernel calling it is compiled, so a model registered anywhere — a new module, or a test
— runs in the kernels without any kernel code changing.  The overload is inlined
(``inline="always"``) into the calling kernel: compiled as a function of its own it was
a call per point (the 8-tuple returned through memory, the state and parameter arrays
passed as arguments), and that pass cost about a third more than inlined.

Why the ``version`` argument (:func:`.registry.version`): numba compiles the chain into
the calling kernel and caches that kernel on disk (``cache=True``: no recompilation in
the next process).  A kernel that uses the dispatch is made by a factory closing over
the version number (:func:`fem_rmpm.schemes.explicit.kernels.material_kernels`): numba's cache key
includes a closure's values, and the overload sees ``version`` as a literal, so a new
model or an edited model file gives a new key and one fresh compile (~1 s), never a
stale chain.  An unknown id returns NaN (caught by the run's non-finite guard).

``has_block_update(version, only)`` and ``block_dispatch(version, only, Z, state, params,
active, b, m)``: a kernel restricted to one model (``only`` >= 0) whose module has the
optional vectorised ``block_update`` (:mod:`.protocol`) runs it on whole blocks of points
(:func:`fem_rmpm.schemes.explicit.kernels.stress`'s finish pass); the first is a compile-time
constant, so the other kernels compile no block code.  Whether a run's points take the block path is
decided once per run, in Python, by :func:`takes_blocks` (the kernels' ``StepOptions.block``).
"""
from __future__ import annotations

import numpy as np
from numba import types
from numba.core.errors import TypingError
from numba.extending import overload

from fem_rmpm.materials import registry

__all__ = ["point_dispatch", "block_dispatch", "has_block_update", "takes_blocks"]


def point_dispatch(version, only, model, e0, e1, e2, e3, state, params, i):
    """Placeholder called from numba code only (see the module docstring)."""
    raise NotImplementedError("point_dispatch runs inside numba kernels only")


@overload(point_dispatch, inline="always")
def _point_dispatch(version, only, model, e0, e1, e2, e3, state, params, i):
    models = registry.models()
    only = _literals("point_dispatch", version, only)
    ids = range(len(models)) if only < 0 else [only]
    fns = {f"_f{k}": models[k].point_update for k in ids}
    lines = ["def impl(version, only, model, e0, e1, e2, e3, state, params, i):"]
    for k, name in zip(ids, fns):
        lines.append(f"    {'if' if not lines[1:] else 'elif'} model == {k}:")
        lines.append(f"        r = {name}(e0, e1, e2, e3, state, params, i)")
    lines.append("    else:")
    lines.append("        r = (np.nan, np.nan, np.nan, np.nan, np.nan, np.nan, np.nan, np.nan)")
    lines.append("    return r")
    scope = dict(fns, np=np)
    exec("\n".join(lines), scope)    # generated from the registry above, no user input
    return scope["impl"]


def _literals(name: str, version, only) -> int:
    """The model restriction ``only`` of a dispatch ``name``'s literal arguments."""
    if not (isinstance(version, types.IntegerLiteral) and isinstance(only, types.IntegerLiteral)):
        raise TypingError(f"{name} needs the registry version and the model "
                          "restriction as literals (closure values of the calling kernel)")
    return only.literal_value


def _block_update_of(only: int):
    """The ``block_update`` of model ``only`` (None: any model, or it has none)."""
    return getattr(registry.models()[only], "block_update", None) if only >= 0 else None


def takes_blocks(model: int, params: np.ndarray) -> bool:
    """Whether the points of a run, all of model id ``model`` (-1: several models) with the
    parameter rows ``params`` (n, P), go through that model's ``block_update``: it has one,
    and its optional ``block_eligible(params)`` (default: True) accepts them.  Decided once
    per run: a point's model and parameters never change during a run."""
    if _block_update_of(model) is None:
        return False
    eligible = getattr(registry.models()[model], "block_eligible", None)
    return True if eligible is None else bool(eligible(params))


def has_block_update(version, only):
    """Placeholder called from numba code only: whether the one model of a restricted
    kernel (``only`` >= 0) has a vectorised ``block_update`` (a compile-time constant)."""
    raise NotImplementedError("has_block_update runs inside numba kernels only")


@overload(has_block_update, inline="always")
def _has_block_update(version, only):
    if _block_update_of(_literals("has_block_update", version, only)) is None:
        return lambda version, only: False
    return lambda version, only: True


def block_dispatch(version, only, Z, state, params, active, b, m):
    """Placeholder called from numba code only: the ``block_update`` of the one model of
    a restricted kernel (see :func:`has_block_update`; nothing where there is none)."""
    raise NotImplementedError("block_dispatch runs inside numba kernels only")


@overload(block_dispatch, inline="always")
def _block_dispatch(version, only, Z, state, params, active, b, m):
    fn = _block_update_of(_literals("block_dispatch", version, only))
    if fn is None:
        return lambda version, only, Z, state, params, active, b, m: None

    def impl(version, only, Z, state, params, active, b, m):
        fn(Z, state, params, active, b, m)
    return impl
