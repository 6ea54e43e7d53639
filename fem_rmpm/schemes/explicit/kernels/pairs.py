"""Pairs: the (x, y) components of a point's or a node's vector as one 2-wide vector.

numba compiles scalar code: ``p[2a] += w mv_x; p[2a + 1] += w mv_y`` is two loads, two
fused multiply-adds and two stores.  LLVM's SLP vectorizer would pack such twins into
one vector operation, but numba turns it off (it miscompiled), and where it ran it
packed and fused the map's kernels differently in each caller, so that a run loaded from
numba's cache differed from the same run compiled in its process
(``validation/load_order.py --slp`` before these intrinsics; it agrees since).  These
intrinsics write the packing out.  Each takes and returns pairs as ``(x, y)`` tuples of
float64 and does its arithmetic as one ``<2 x double>`` operation: a product that is
added is an explicit ``llvm.fma`` (one rounding per component, as IEEE 754's
fusedMultiplyAdd), and no operation carries a fast-math flag, so LLVM cannot fuse, split
or regroup them differently in different callers: every caller computes the same bits,
on one thread or two, compiled or cached.  LLVM folds the tuples away (the pairs stay in
vector registers between intrinsics).  A nodal vector array (interleaved x, y:
:func:`.common.xy`) is read and written at ``a[i], a[i + 1]`` as one pair; ``i`` is not
bounds-checked (the kernels' node numbers are valid, as for every kernel access).

Used by the map to nodes and the map back (:mod:`.transfer`): case (i), one thread,
0.92-0.95x the time of the scalar code (9 interleaved pairs).
"""
from __future__ import annotations

from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic

__all__ = ["load2", "mul2", "fma2", "fma2_to", "sub2_from"]

_F = types.float64
_PAIR = types.UniTuple(_F, 2)
_V2 = ir.VectorType(ir.DoubleType(), 2)


def _is_pair(t) -> bool:
    return isinstance(t, types.UniTuple) and t.count == 2 and t.dtype == _F


def _is_vector_array(a) -> bool:
    """A contiguous (nn,) float64 array: its elements ``i``, ``i + 1`` are adjacent."""
    return (isinstance(a, types.Array) and a.ndim == 1 and a.dtype == _F
            and a.layout == "C")


def _vec(builder, x0, x1):
    v = builder.insert_element(ir.Constant(_V2, ir.Undefined), x0, ir.IntType(32)(0))
    return builder.insert_element(v, x1, ir.IntType(32)(1))


def _from_pair(builder, t):
    return _vec(builder, builder.extract_value(t, 0), builder.extract_value(t, 1))


def _to_pair(context, builder, v):
    parts = [builder.extract_element(v, ir.IntType(32)(k)) for k in (0, 1)]
    return context.make_tuple(builder, _PAIR, parts)


def _splat(builder, w):
    return _vec(builder, w, w)


def _fma(builder, a, b, c):
    fn = cgutils.get_or_insert_function(builder.module, ir.FunctionType(_V2, [_V2] * 3),
                                        "llvm.fma.v2f64")
    return builder.call(fn, [a, b, c])


def _pair_ptr(context, builder, aty, ary, i):
    a = context.make_array(aty)(context, builder, ary)
    return builder.bitcast(builder.gep(a.data, [i]), _V2.as_pointer())


@intrinsic
def load2(typingctx, a, i):
    """``(a[i], a[i + 1])`` as one load."""
    if not (_is_vector_array(a) and isinstance(i, types.Integer)):
        return None

    def codegen(context, builder, signature, args):
        p = _pair_ptr(context, builder, signature.args[0], *args)
        return _to_pair(context, builder, builder.load(p, align=8))
    return _PAIR(a, i), codegen


@intrinsic
def mul2(typingctx, w, x):
    """``w x`` for a scalar ``w`` and a pair ``x``."""
    if not (isinstance(w, types.Float) and _is_pair(x)):
        return None

    def codegen(context, builder, signature, args):
        w, x = args
        return _to_pair(context, builder, builder.fmul(_splat(builder, w),
                                                       _from_pair(builder, x)))
    return _PAIR(_F, x), codegen


@intrinsic
def fma2(typingctx, w, x, y):
    """``w x + y`` for a scalar ``w`` and pairs ``x``, ``y``, one rounding per component."""
    if not (isinstance(w, types.Float) and _is_pair(x) and _is_pair(y)):
        return None

    def codegen(context, builder, signature, args):
        w, x, y = args
        r = _fma(builder, _splat(builder, w), _from_pair(builder, x), _from_pair(builder, y))
        return _to_pair(context, builder, r)
    return _PAIR(_F, x, y), codegen


@intrinsic
def fma2_to(typingctx, a, i, w, x):
    """``a[i], a[i + 1] += w x`` (``w`` scalar, ``x`` a pair), one rounding per component."""
    if not (_is_vector_array(a) and isinstance(i, types.Integer) and isinstance(w, types.Float)
            and _is_pair(x)):
        return None

    def codegen(context, builder, signature, args):
        a, i, w, x = args
        p = _pair_ptr(context, builder, signature.args[0], a, i)
        old = builder.load(p, align=8)
        builder.store(_fma(builder, _splat(builder, w), _from_pair(builder, x), old), p,
                      align=8)
        return context.get_dummy_value()
    return types.none(a, i, _F, x), codegen


@intrinsic
def sub2_from(typingctx, a, i, x):
    """``a[i], a[i + 1] -= x`` (a pair)."""
    if not (_is_vector_array(a) and isinstance(i, types.Integer) and _is_pair(x)):
        return None

    def codegen(context, builder, signature, args):
        a, i, x = args
        p = _pair_ptr(context, builder, signature.args[0], a, i)
        builder.store(builder.fsub(builder.load(p, align=8), _from_pair(builder, x)), p,
                      align=8)
        return context.get_dummy_value()
    return types.none(a, i, x), codegen

