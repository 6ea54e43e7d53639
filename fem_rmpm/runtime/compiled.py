"""numba decorators and the LLVM shape promise of the package's compiled code.

Shared by the explicit kernels (:mod:`fem_rmpm.schemes.explicit.kernels`) and the material models'
point and block functions (:mod:`fem_rmpm.materials`), which the kernels inline or call: both import
this module and it imports neither, so a material model does not depend on the
kernels package.
"""
from __future__ import annotations

from llvmlite import ir
from numba import njit, types
from numba.extending import intrinsic

# LLVM floating-point flags of every kernel (and of the material point functions inlined
# into them): "nsz" only (the sign of a zero may be ignored), no flag that changes a
# value.  Each caller's compiled code holds a copy of every compiled callee, optimized a
# second time there (below), and a flag that lets LLVM choose the arithmetic lets the
# copies choose differently.  With "contract" (a * b + c as one fused multiply-add where
# the backend sees fit) the copies of one function may fuse differently, so a run
# compiled in its process and the same run loaded from the on-disk cache can differ by
# one ulp (``validation/load_order.py`` compares the two, also for another target CPU
# with ``--cpu``).  Likewise "arcp" (a division by a reused divisor becomes a
# multiplication by its reciprocal where the backend counts enough of them in one block).
# Without them every copy rounds every operation as written.  The fused multiply-adds
# the map and the move need are written out
# (:mod:`fem_rmpm.schemes.explicit.kernels.pairs`).  The solve on the mesh is inlined
# into the serial and the threaded step: with "contract" the kinetic-energy sum could be
# fused differently in the two, and 1 and 2 threads would differ by one ulp.
# Never "nnan" / "ninf" / "fast": the run's guards must see NaN and inf; never "reassoc":
# sums would be regrouped differently in the serial and the threaded compiles.
FASTMATH = {"nsz"}
jit = njit(cache=True, fastmath=FASTMATH, nogil=True, error_model="numpy")
# Each caller's compiled code holds a copy of every compiled (not inlined) callee, optimized
# again there; which copy a call runs depends on what the process loaded first (compiled in
# the process: the callee's own; from the cache: the caller's).  The copies must compute
# the same: ``validation/load_order.py`` checks that they do (with LLVM's SLP vectorizer
# on, numba's default off, the map's x, y twins are written as explicit vector operations
# so that its copies agree, :mod:`fem_rmpm.schemes.explicit.kernels.pairs`).
# The step kernels allocate nothing, so they run without numba's reference counting
# (NRT): with it, every array handed to an inlined per-point helper is incref'd and
# decref'd (atomic operations) once per point, several times the cost of the map back
# itself.  A kernel that allocated would fail to compile, not misbehave.
kernel = njit(cache=True, fastmath=FASTMATH, nogil=True, error_model="numpy", _nrt=False)
inline = njit(inline="always", fastmath=FASTMATH, error_model="numpy")
# The threaded drivers: a ``prange`` loop over chunks of the points whose body calls a
# compiled (``kernel``) chunk function, the same one the serial kernel runs, so every point
# is computed with the same arithmetic and the result is bitwise the serial one.  The loop
# body is a call, not the per-point code itself: numba 0.68's parfor array analysis
# crashes on those bodies inline (IndexError in array_analysis._gen_shape_call), and the
# threaded loop takes no nested named tuple (pass ``N._replace(half=None)`` and ``N.half``).
# A threaded driver must be a Python function of its own: numba names its cache files
# after the function's qualified name and its cache key does not contain the ``parallel``
# flag, so a serial and a parallel compile of ONE function would share one cache entry and
# whichever compiled first would be loaded by both.
# One ``prange`` loop per threaded function: numba fuses two ``prange`` loops of the same
# length into one when it sees no dependency between them, and it cannot see into the
# chunk calls (the nodal velocities of the map back could then run before the other
# half's re-map has finished).  ``parallel={"fusion": False}`` does not stop it: numba
# 0.68 pops the key from the options dict that all dispatchers of this decorator share,
# at the first compile.
kernel_parallel = njit(cache=True, fastmath=FASTMATH, nogil=True, error_model="numpy", _nrt=False,
                       parallel=True)



# Variants of one function.  A factory that compiles one Python function per value of a
# flag (a closure constant: numba prunes the other branch) must give each variant a name of
# its own (:func:`variant`).  numba names a compiled function's machine code after its
# qualified name, a counter of the process that compiled it and its argument types, and
# the process's JIT links calls by that name, one definition per name (numba marks the code
# of a callee linked into its caller ``linkonce_odr``: "the same name is the same code").
# Closures of one factory share a qualified name and, when the flag is not an argument,
# their argument types; their counters differ within one process but not between
# processes (each counts its compiles from 1 in the same order).  So a variant compiled in
# one process and another variant of the same function loaded from the on-disk cache, or
# two variants loaded from it, can carry one name, and a process that loads both runs
# whichever was linked first for both: a uGIMP run after a Q4 run of the same scene ran
# the Q4 map and moved 5.64 m instead of 0.91 m.  A distinct qualified name gives each
# variant distinct machine-code names and a cache file of its own, whatever the order of
# compiles and loads; an argument whose numba type differs per variant (a literal, as the
# registry version and model restriction of the stress pass) does the same through the
# argument types.  ``tests/test_kernel_variants_in_one_process.py`` runs the variants in
# both orders in one process and from a cache another process filled.


def variant_name(base: str, **flags) -> str:
    """The name of the variant of ``base`` for ``flags`` (bools and ints): ``base`` and
    each flag's name and value, e.g. ``map_half__gimp1``; an identifier."""
    tags = [f"{k}{'m' if int(v) < 0 else ''}{abs(int(v))}" for k, v in flags.items()]
    return "__".join([base, "_".join(tags)]) if tags else base


def variant(base: str, **flags):
    """Decorator for a function a factory makes per value of its ``flags``: renames it
    :func:`variant_name` ``(base, **flags)`` (``__name__`` and ``__qualname__``) , under the
    numba decorator (written below it), so that numba sees the new name (comment above)."""
    name = variant_name(base, **flags)

    def rename(f):
        f.__name__ = f.__qualname__ = name
        return f
    return rename

# Column counts: numba indexes a C-contiguous 2-D array ``a[i, j]`` as ``i a.shape[1] + j``
# with the run-time shape, so every point's row costs an integer multiply per array, and
# the shapes (and row pointers) compete for registers with the arithmetic (the stress
# pass spilled most of them to the stack).  The point arrays' column counts never change
# (2 for positions and velocities, 4 for stress and log strain, W_COLUMNS for the block
# scratch), so the kernels state them (:func:`assume_columns`) and LLVM indexes with
# constants: fewer integer multiplies per point (the stress pass's 15 -> 10, the map's
# 12 -> 4), the same arithmetic on the values (bitwise the same run).


@intrinsic
def assume_columns(typingctx, a, k):
    """Tell LLVM that the 2-D C-contiguous array ``a`` has ``k`` columns (``k`` a literal),
    so ``a[i, j]`` indexes ``k i + j`` without loading the shape and multiplying by it.
    ``llvm.assume``: a false promise is undefined behaviour (the compiled code may take
    another path), so only shapes the callers check or make are promised
    (:data:`fem_rmpm.schemes.explicit.kernels.arrays.FIXED_COLUMNS`); a strided
    view promises nothing."""
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
