"""Nodal rows as vectors: the eight numbers of a node's row (one 64-byte cache line,
:data:`.kernels.NODE_COLUMNS`) read and combined as one ``<8 x double>`` value in the map
back's interpolation (:func:`.kernels.map_back_3d`) and the stress pass's velocity
gradient (:func:`.stress3d._gradient`), the re-mapped momentum added to the first four
as one ``<4 x double>``.  (The map's scatter stays scalar: as one 8-wide addition per
corner it took 1.2 times as long.)

numba compiles scalar code and keeps LLVM's SLP vectorizer off, so the map back's
interpolation of six columns over the eight corners is 48 loads and as many products,
each corner's re-mapped momentum three loads, additions and stores, and the gradient 24
loads.  These intrinsics
write the vector operations out: each lane gets the IEEE operations of the scalar code in
the same order (``sum_I N_I g_I`` left to right, a product then a sum, never fused: no
fast-math flag), so the results are the same bits as the scalar code, in every caller,
compiled or loaded from numba's cache (as :mod:`fem_rmpm.schemes.explicit.kernels.pairs`
does for the plane-strain pairs).  The rows are read and written unaligned (``align 8``);
the node numbers are not bounds-checked (the kernels' are valid, as for every kernel
access).
"""
from __future__ import annotations

from llvmlite import ir
from numba import types
from numba.extending import intrinsic

__all__ = ["row_sum8", "row_add4", "row_diffs4"]

_F = types.float64
_ROW8 = types.UniTuple(_F, 8)
_ROW4 = types.UniTuple(_F, 4)
_V8 = ir.VectorType(ir.DoubleType(), 8)
_V4 = ir.VectorType(ir.DoubleType(), 4)


def _is_rows(a) -> bool:
    """A C-contiguous 2-D float64 array (its rows are eight numbers: the callers promise)."""
    return (isinstance(a, types.Array) and a.ndim == 2 and a.dtype == _F
            and a.layout == "C")


def _row_ptr(context, builder, aty, ary, i, vty):
    """Pointer to row ``i`` of the (nn, 8) array ``ary`` as a ``vty`` vector."""
    a = context.make_array(aty)(context, builder, ary)
    off = builder.mul(i, i.type(8))
    return builder.bitcast(builder.gep(a.data, [off]), vty.as_pointer())


def _splat(builder, w, vty):
    v = ir.Constant(vty, ir.Undefined)
    for k in range(vty.count):
        v = builder.insert_element(v, w, ir.IntType(32)(k))
    return v


def _from_tuple(builder, t, vty):
    v = ir.Constant(vty, ir.Undefined)
    for k in range(vty.count):
        v = builder.insert_element(v, builder.extract_value(t, k), ir.IntType(32)(k))
    return v


def _to_tuple(context, builder, v, tty):
    parts = [builder.extract_element(v, ir.IntType(32)(k)) for k in range(tty.count)]
    return context.make_tuple(builder, tty, parts)


@intrinsic
def row_sum8(typingctx, g, n, w):
    """``sum_I w_I g[n_I, 0:8]`` over the eight node numbers ``n`` and weights ``w``
    (tuples), summed left to right (``((w0 g0 + w1 g1) + w2 g2) + ...``), each product
    rounded, then each sum; an 8-tuple."""
    if not (_is_rows(g) and isinstance(n, types.UniTuple) and n.count == 8
            and isinstance(n.dtype, types.Integer) and isinstance(w, types.UniTuple)
            and w.count == 8 and w.dtype == _F):
        return None

    def codegen(context, builder, signature, args):
        gty = signature.args[0]
        g, n, w = args
        acc = None
        for k in range(8):
            p = _row_ptr(context, builder, gty, g, builder.extract_value(n, k), _V8)
            term = builder.fmul(_splat(builder, builder.extract_value(w, k), _V8),
                                builder.load(p, align=8))
            acc = term if acc is None else builder.fadd(acc, term)
        return _to_tuple(context, builder, acc, _ROW8)
    return _ROW8(g, n, w), codegen


@intrinsic
def row_add4(typingctx, buf, i, w, x):
    """``buf[i, 0:4] += w x`` (``w`` a scalar, ``x`` a 4-tuple), the product rounded,
    then the sum, per lane."""
    if not (_is_rows(buf) and isinstance(i, types.Integer) and isinstance(w, types.Float)
            and x == _ROW4):
        return None

    def codegen(context, builder, signature, args):
        buf, i, w, x = args
        p = _row_ptr(context, builder, signature.args[0], buf, i, _V4)
        prod = builder.fmul(_splat(builder, w, _V4), _from_tuple(builder, x, _V4))
        builder.store(builder.fadd(builder.load(p, align=8), prod), p, align=8)
        return context.get_dummy_value()
    return types.none(buf, i, _F, x), codegen


@intrinsic
def row_diffs4(typingctx, g, p, q, w):
    """``sum_k w_k (g[p_k, 0:8] - g[q_k, 0:8])`` over four node pairs ``p``, ``q`` and
    weights ``w`` (tuples), summed left to right, each difference, product and sum
    rounded; an 8-tuple (the stress pass's velocity gradient along one axis, for each
    velocity component at once, :func:`.stress3d._gradient`)."""
    if not (_is_rows(g) and all(isinstance(t, types.UniTuple) and t.count == 4
                                for t in (p, q, w))
            and isinstance(p.dtype, types.Integer) and isinstance(q.dtype, types.Integer)
            and w.dtype == _F):
        return None

    def codegen(context, builder, signature, args):
        gty = signature.args[0]
        g, p, q, w = args
        acc = None
        for k in range(4):
            rp = builder.load(_row_ptr(context, builder, gty, g, builder.extract_value(p, k),
                                       _V8), align=8)
            rq = builder.load(_row_ptr(context, builder, gty, g, builder.extract_value(q, k),
                                       _V8), align=8)
            term = builder.fmul(_splat(builder, builder.extract_value(w, k), _V8),
                                builder.fsub(rp, rq))
            acc = term if acc is None else builder.fadd(acc, term)
        return _to_tuple(context, builder, acc, _ROW8)
    return _ROW8(g, p, q, w), codegen
