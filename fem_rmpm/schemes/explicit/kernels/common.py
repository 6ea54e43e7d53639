"""Constants and small compiled helpers shared by the kernel modules (the numba
decorators: :mod:`fem_rmpm.runtime.compiled`)."""
from __future__ import annotations

import functools
import inspect
import sys

import numpy as np
from llvmlite import ir
from numba import njit, types
from numba.core import cgutils
from numba.extending import intrinsic, overload

from fem_rmpm.runtime.compiled import assume_columns, inline

MASS_TOL = 1e-14     # as reference.MASS_TOL: nodes lighter than this carry no velocity
# Indices: numba reads a negative signed index ``i`` as ``i + n`` (a compare and a select at
# every array access), which LLVM can drop only where it proves ``i >= 0`` (a loop from the
# constant 0).  So node numbers are uint64 (:mod:`.basis`, ``NodeArrays.touched``) and
# every point loop runs over ``range(np.uint64(start), np.uint64(stop))``; a uint64 index
# must not meet an int64 in arithmetic (numba makes that float64).

# Points are processed in blocks of BLOCK (the stress pass: .stress, .hencky) and in two
# halves split at a block boundary (the scatters: .transfer); whole blocks from point 0,
# so that blocks, halves and every point's code do not depend on the thread count.
BLOCK = 128
# The stress pass's two work queues (one per half of the points): counters at elements 0
# and QUEUE_STRIDE of an int64 array, so that each sits on a cache line of its own, each
# with its half's nodal-velocity flag QUEUE_FLAG elements after it.
QUEUE_STRIDE = 8
QUEUE_FLAG = 1
# The two-thread step driver's barrier counter, on a third cache line of the same array
# (:func:`arrive`, :mod:`.advance`).
QUEUE_BARRIER = 2 * QUEUE_STRIDE
# A thread waiting at :func:`arrive` spins SPINS_BEFORE_YIELD times, then gives its core
# away (:func:`yield_core`) between reads, and gives up after YIELD_LIMIT yields that came
# straight back (of the order of half a minute: the other worker never runs).
SPINS_BEFORE_YIELD = 200_000
YIELD_LIMIT = 30_000_000


@inline
def xy(a):
    """Indices of the x and y components of node ``a`` (uint64) in a nodal vector array,
    stored interleaved as (2 nn,) (:class:`.arrays.NodeArrays`): ``2 a``, ``2 a + 1``."""
    i = a + a
    return i, i + np.uint64(1)


@inline
def block_bounds(n, chunks, c):
    """Points ``start:stop`` of chunk ``c`` of ``chunks``: whole blocks of :data:`BLOCK`
    (the last one may be short), so that the blocks do not depend on the thread count."""
    nb = (n + BLOCK - 1) // BLOCK
    return min(n, c * nb // chunks * BLOCK), min(n, (c + 1) * nb // chunks * BLOCK)


@inline
def half_split(n):
    """First point of the second half of ``n`` points: the block boundary nearest below
    the middle's (:func:`block_bounds` of two chunks)."""
    return block_bounds(n, 2, 1)[0]


@inline
def half_range(n, c):
    """Points ``start:stop`` of half ``c`` (0 or 1) of ``n`` points."""
    s = half_split(n)
    return (0, s) if c == 0 else (s, n)


@intrinsic
def take_ticket(typingctx, counter):
    """``counter[0] += 1`` as one atomic operation (any thread), returning the value before:
    the next ticket of a shared work queue (``counter``: an int64 array).  numba has no
    atomics on the CPU; this is LLVM's ``atomicrmw add`` on the array's first element."""
    if not (isinstance(counter, types.Array) and counter.dtype == types.int64):
        return None
    sig = types.int64(counter)

    def codegen(context, builder, signature, args):
        ary = context.make_array(signature.args[0])(context, builder, args[0])
        one = context.get_constant(types.int64, 1)
        return builder.atomic_rmw("add", ary.data, one, "seq_cst")
    return sig, codegen


@intrinsic
def read_flag(typingctx, counter):
    """``counter[0]`` read as one atomic (sequentially consistent) load: a flag another
    thread set with :func:`take_ticket`, and everything that thread wrote before it."""
    if not (isinstance(counter, types.Array) and counter.dtype == types.int64):
        return None
    sig = types.int64(counter)

    def codegen(context, builder, signature, args):
        ary = context.make_array(signature.args[0])(context, builder, args[0])
        return builder.load_atomic(ary.data, "seq_cst", 8)
    return sig, codegen



_YIELD = "SwitchToThread" if sys.platform == "win32" else "sched_yield"


@intrinsic
def yield_core(typingctx):
    """Give this thread's core to another runnable thread, if any (POSIX ``sched_yield``,
    Windows ``SwitchToThread``; both in every process, resolved by name when the compiled
    code is loaded)."""
    sig = types.int32()

    def codegen(context, builder, signature, args):
        fnty = ir.FunctionType(ir.IntType(32), [])
        return builder.call(cgutils.get_or_insert_function(builder.module, fnty, _YIELD), [])
    return sig, codegen


@njit(inline="always")
def arrive(counter, target):
    """Arrive at a barrier of two threads: ``counter[0] += 1`` (:func:`take_ticket`), then
    wait until it reaches ``target`` (2 k at the k-th barrier since the counter was 0: both
    threads arrived), reading it with :func:`read_flag`, so everything the other thread
    wrote before it arrived is seen after.  A thread can run at most one barrier ahead (the
    next needs the other's arrival), so the counter never needs resetting within a call.
    The wait spins, then yields its core between reads (:data:`SPINS_BEFORE_YIELD`): on a
    machine with more runnable threads than cores the other thread may be waiting for this
    very core.  False after :data:`YIELD_LIMIT` yields (the other thread never came)."""
    take_ticket(counter)
    spins = 0
    while read_flag(counter) < target:
        spins += 1
        if spins > SPINS_BEFORE_YIELD:
            yield_core()
            if spins > SPINS_BEFORE_YIELD + YIELD_LIMIT:
                return False
    return True


@njit(inline="always")
def fixed_columns(P, S):
    """The column counts every kernel may assume (:func:`assume_columns`; checked when the
    arrays are bound, :func:`.arrays.point_arrays`): positions, velocities, half widths,
    geostatic displacements, the positions before the move, the Q4 local coordinates and
    the uGIMP factors' node column and row (2); stress and log strain (4); the uGIMP
    weights and derivatives (12)."""
    assume_columns(P.x, 2)
    assume_columns(P.v, 2)
    assume_columns(P.half_width, 2)
    assume_columns(P.u_geo, 2)
    assume_columns(S.x_old, 2)
    assume_columns(S.q4_st, 2)
    assume_columns(S.gimp_ij, 2)
    assume_columns(S.gimp_w, 12)
    assume_columns(P.stress, 4)
    assume_columns(P.log_strain, 4)



# Compile-time choices.  numba types both arms of ``if flag:`` where ``flag`` is an
# argument of the kernel being compiled, even a literal one: its dead-branch pruning keeps
# a branch on an argument.  Typing and lowering the arm a run never takes is most of what
# that arm costs at the first step (the uGIMP basis in a Q4 run, the per-point model
# update in a run of block updates).  A constant is pruned, also when an inlined helper
# receives it as an argument; so a kernel made for one value of the flag (a closure
# constant) compiles one arm, and :func:`literal_variants` calls that kernel where the
# caller's flag is a literal (a closure value of a step driver).
_VARIANTS = """
def typer({args}):
    flags = ({flags},)
    if not all(isinstance(f, types.BooleanLiteral) for f in flags):
        return either
    kernel = made(*(f.literal_value for f in flags))

    def pick({args}):
        return kernel({rest})
    return pick
"""


def literal_variants(placeholder, make, either=None):
    """Make ``placeholder(*flags, *args)`` (a Python function called from numba code only)
    call ``make(*flags)(*args)``, the compiled kernel ``make`` gives for those boolean
    values (made once per value), where every flag is a literal; else ``either`` (a
    function with the placeholder's arguments, compiled by numba; default, one flag: both
    kernels behind ``if flag``).  ``make``'s arguments name the flags (the placeholder's
    first ones).  The kernel of each value is the same code as the run-time branch
    compiled for that value: the results are bitwise the same.  ``make`` must give each
    value's kernel a name of its own (:func:`fem_rmpm.runtime.compiled.variant`: kernels of
    one name could run each other's code).  Returns ``make`` as it is used (the kernel of
    each value made once)."""
    names = list(inspect.signature(placeholder).parameters)
    k = len(inspect.signature(make).parameters)
    made = functools.lru_cache(maxsize=None)(make)
    if either is None:
        if k != 1:
            raise ValueError("literal_variants: more than one flag needs its own 'either'")
        yes, no = made(True), made(False)

        src = (f"def either({', '.join(names)}):\n    if {names[0]}:\n"
               f"        return yes({', '.join(names[1:])})\n"
               f"    return no({', '.join(names[1:])})\n")
        scope = {"yes": yes, "no": no}
        exec(src, scope)             # (argument names of the placeholder, no user input)
        either = scope["either"]
    scope = {"types": types, "made": made, "either": either}
    exec(_VARIANTS.format(args=", ".join(names), flags=", ".join(names[:k]),
                          rest=", ".join(names[k:])), scope)
    overload(placeholder, inline="always", prefer_literal=True)(scope["typer"])
    return made
