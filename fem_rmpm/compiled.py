"""numba decorators and the LLVM shape promise of the package's compiled code.

Shared by the explicit kernels (:mod:`fem_rmpm.kernels`) and the material models' point
and block functions (:mod:`fem_rmpm.materials`), which the kernels inline or call: both
import this module and it imports neither, so a material model does not depend on the
kernels package.
"""
from __future__ import annotations

from llvmlite import ir
from numba import njit, types
from numba.extending import intrinsic

# LLVM floating-point flags of every kernel (and of the material point functions inlined
# into them): "contract" lets a * b + c become one fused multiply-add (one rounding instead
# of two), "arcp" a division by a constant or a reused divisor a multiplication by its
# reciprocal, "nsz" ignores the sign of zero.  Each changes round-off only (the numba =
# numpy tests hold at their 1e-12); never "nnan" / "ninf" / "fast": the run's guards must
# still see NaN and inf, and never "reassoc": sums would be regrouped differently in the
# serial and the threaded compiles.  Measured on case (i) (per-kernel probes at t = 8 and
# 25 s, 1 thread): kinematics 22.1 -> 19.3 ns per point, finish pass 24.6 -> 21.5 ns with
# 74 % of the points plastic.
FASTMATH = {"contract", "arcp", "nsz"}
jit = njit(cache=True, fastmath=FASTMATH, nogil=True, error_model="numpy")
# Each caller's compiled code holds a copy of every compiled (not inlined) callee, optimized
# again there; which copy a call runs depends on what the process loaded first (compiled in
# the process: the callee's own; from the cache: the caller's).  The copies must compute
# the same: ``validation/load_order.py`` checks that they do (with LLVM's SLP vectorizer
# on, numba's default off, the map's copies did not until its x, y twins were written as
# explicit vector operations, :mod:`fem_rmpm.kernels.pairs`).
# The step kernels allocate nothing, so they run without numba's reference counting
# (NRT): with it, every array handed to an inlined per-point helper is incref'd and
# decref'd (atomic operations) once per point, which made G2P ~4x slower (56 vs 13
# ns per point, measured).  A kernel that allocated would fail to compile, not misbehave.
kernel = njit(cache=True, fastmath=FASTMATH, nogil=True, error_model="numpy", _nrt=False)
inline = njit(inline="always", fastmath=FASTMATH, error_model="numpy")
# The solve on the mesh without "contract": its compiled half is called by the serial kernel
# (with the half's number a constant) and by the threaded one (a variable); LLVM inlines it
# into both and, with contraction allowed, fused the kinetic-energy sum differently where
# the constant folded its branch away (1 ulp between 1 and 2 threads, measured).  Without
# it every product and sum is rounded on its own, whatever the caller.  A node loop: the
# FMA it loses costs nothing measurable.
kernel_exact = njit(cache=True, fastmath={"arcp", "nsz"}, nogil=True, error_model="numpy",
                    _nrt=False)
# The threaded drivers: a ``prange`` loop over chunks of the points whose body calls a
# compiled (``kernel``) chunk function, the same one the serial kernel runs, so every point
# is computed with the same arithmetic and the result is bitwise the serial one.  The loop
# body is a call, not the per-point code itself: numba 0.68's parfor array analysis
# crashed on those bodies inline (IndexError in array_analysis._gen_shape_call), and the
# threaded loop takes no nested named tuple (pass ``N._replace(half=None)`` and ``N.half``).
# A threaded driver must be a Python function of its own: numba names its cache files
# after the function's qualified name and its cache key does not contain the ``parallel``
# flag, so a serial and a parallel compile of ONE function share one cache entry and
# whichever compiled first is loaded by both (the threaded kernels had run serial that way).
# One ``prange`` loop per threaded function: numba fuses two ``prange`` loops of the same
# length into one when it sees no dependency between them, and it cannot see into the
# chunk calls (g2p's nodal velocities ran before the other half's re-map had finished
# that way).  ``parallel={"fusion": False}`` does not stop it: numba 0.68 pops the key
# from the options dict that all dispatchers of this decorator share, at the first compile.
kernel_parallel = njit(cache=True, fastmath=FASTMATH, nogil=True, error_model="numpy", _nrt=False,
                       parallel=True)


# Column counts: numba indexes a C-contiguous 2-D array ``a[i, j]`` as ``i a.shape[1] + j``
# with the run-time shape, so every point's row costs an integer multiply per array, and
# the shapes (and row pointers) compete for registers with the arithmetic (the stress
# pass spilled most of them to the stack).  The point arrays' column counts never change
# (2 for positions and velocities, 4 for stress and log strain, W_COLUMNS for the block
# scratch), so the kernels state them (:func:`assume_columns`) and LLVM indexes with
# constants: case (i), one thread, 7 interleaved pairs against the same code without
# them: 0.90-0.93x the time, bitwise the same run (run-out 63.72968029438788 m, 11 724
# steps); the stress pass's integer multiplies 15 -> 10, the map's 12 -> 4.


@intrinsic
def assume_columns(typingctx, a, k):
    """Tell LLVM that the 2-D C-contiguous array ``a`` has ``k`` columns (``k`` a literal),
    so ``a[i, j]`` indexes ``k i + j`` without loading the shape and multiplying by it.
    ``llvm.assume``: a false promise is undefined behaviour (a run with the block scratch's
    width promised wrong took another path, measured), so only shapes the callers check or
    make are promised (:data:`fem_rmpm.kernels.arrays.FIXED_COLUMNS`); a strided view promises nothing."""
    if not (isinstance(a, types.Array) and a.ndim == 2 and isinstance(k, types.IntegerLiteral)):
        return None
    sig = types.none(a, k)

    def codegen(context, builder, signature, args):
        if signature.args[0].layout != "C":      # (a strided view: nothing to promise)
            return context.get_dummy_value()
        ary = context.make_array(signature.args[0])(context, builder, args[0])
        cols = builder.extract_value(ary.shape, 1)
        ok = builder.icmp_signed("==", cols, cols.type(signature.args[1].literal_value))
        fn = builder.module.declare_intrinsic("llvm.assume", fnty=ir.FunctionType(
            ir.VoidType(), [ir.IntType(1)]))
        builder.call(fn, [ok])
        return context.get_dummy_value()
    return sig, codegen
