"""Stage 3c of the explicit step: the stress update in one pass over the points —
kinematics, the Hencky trial state, the material model through the model registry
(:mod:`fem_rmpm.materials`), Cauchy stress and the step's statistics.

:func:`update_stress` runs the stress pass (after :func:`.strain.fbar_gradient_pass` with
F-bar).  The pass walks the points in blocks of :data:`.hencky.BLOCK`; per block:

1. the exp parts of the log strains (:func:`.hencky.exp_block`, vectorised series);
2. per point the velocity gradient, Hughes-Winget increment, volume and b_tr
   (:func:`.strain.kinematics_points`, or :func:`.strain.fbar_apply_points`);
3. the log parts of b_tr (:func:`.hencky.log_block`, vectorised series);
4. per point the trial log strain, the point's model update (one dispatch on its model
   id, generated from the registry by :mod:`fem_rmpm.materials.dispatch`), Cauchy stress
   ``tau V0 / V``, the largest P-wave speed and point speed (for the next CFL step) and
   the non-finite and out-of-grid points (for the guards).  Where all points have one
   model and it has a vectorised ``block_update`` (von Mises), the block's trial strains
   go to the scratch ``S.Z`` and the model updates the block at once
   (:func:`_finish_block`; bitwise the same as point by point, and faster).

Geostatic steps (small strain) skip 1 and 3.  A block's scratch stays in L1 between the
four loops, and every thread runs all four (numpy ufunc passes over all points between
kernels would be serial and walk the points three times).  The pass is
compiled once per registry version and model restriction (:func:`material_kernels`) and
cached on disk by numba; only step 4 differs between those compiles.  Steps 1-3 are
kernels of their own, called once per block and compiled once for all of them: numba's
inliner (``inline="always"``) runs the callee's untyped pipeline again and deep-copies
its IR at every inline site, at a cost of about blocks x variables, so inlined they
would make every model restriction's first compile several times longer.  They exchange
data with step 4 through the block scratch only, so a run is bitwise the one with them
inlined, and as fast.
"""
from __future__ import annotations

import math

import numpy as np
from numba import prange, types
from numba.core.errors import TypingError
from numba.extending import overload

from fem_rmpm.materials import registry
from fem_rmpm.materials.dispatch import block_dispatch, point_dispatch
from fem_rmpm.materials.protocol import BLOCK_COLUMNS
from fem_rmpm.runtime.compiled import (
    assume_columns,
    inline,
    jit,
    kernel,
    kernel_parallel,
    variant,
)
from fem_rmpm.schemes.explicit.kernels.arrays import W_COLUMNS, top_of
from fem_rmpm.schemes.explicit.kernels.common import (
    BLOCK,
    QUEUE_FLAG,
    QUEUE_STRIDE,
    fixed_columns,
    half_split,
    read_flag,
    take_ticket,
)
from fem_rmpm.schemes.explicit.kernels.hencky import exp_block, log_block
from fem_rmpm.schemes.explicit.kernels.strain import (
    fbar_apply_points,
    fbar_gradient_pass,
    fbar_gradient_pass_parallel,
    hencky_trial_pass,
    kinematics_points,
    log_sym2_from,
)
from fem_rmpm.schemes.explicit.kernels.transfer import _top as top
from fem_rmpm.schemes.explicit.kernels.transfer import (
    nodal_velocities,
    nodal_velocities_parallel,
    nodal_velocity_half,
)

__all__ = ["update_stress", "material_kernels", "stress_update_points",
           "small_strain_update_points"]


@inline
def _trial_strain(geostatic, i, j, W, ta, tb, ls):
    """Trial log strain of point ``i`` (its log strain ``ls[i]`` not yet updated) from
    column ``j`` of the block scratch.  Geostatic (small strain): ``W[:4, j]`` holds it.  Finite
    strain: ``W[1:3, j]`` (d, axy), ``ta[j]`` = ln(J) and ``tb[j]`` = atanh(x)/(2 x mu)
    hold the log parts of B_tr (:mod:`.hencky`)."""
    if geostatic:
        return W[0, j], W[1, j], W[2, j], W[3, j]
    iso = 0.5 * (ls[i, 0] + ls[i, 1]) + 0.5 * ta[j]
    x0, x1, x3 = log_sym2_from(tb[j], W[1, j], W[2, j], iso)
    return x0, x1, ls[i, 2] + 0.0, x3


def point_kinematics(fbar, gimp, P, M, vn, S, o, W, ta, tb, tc, b, e):
    """Step 2 of the pass on points ``b:e``: :func:`.strain.fbar_apply_points` where
    ``fbar`` (a literal), else :func:`.strain.kinematics_points` in the basis ``gimp``
    (``o.gimp``, or a literal of it).  Placeholder called from numba code only: chosen
    when the calling kernel is compiled, so a pass without F-bar compiles no F-bar code
    (and one with F-bar no plain kinematics)."""
    raise NotImplementedError("point_kinematics runs inside numba kernels only")


@overload(point_kinematics, inline="always", prefer_literal=True)
def _point_kinematics(fbar, gimp, P, M, vn, S, o, W, ta, tb, tc, b, e):
    if not isinstance(fbar, types.BooleanLiteral):
        raise TypingError("point_kinematics needs F-bar as a literal (a closure value of "
                          "the calling kernel)")
    if fbar.literal_value:
        def impl(fbar, gimp, P, M, vn, S, o, W, ta, tb, tc, b, e):
            fbar_apply_points(P, S, o, W, ta, tb, tc, b, e)
    else:
        def impl(fbar, gimp, P, M, vn, S, o, W, ta, tb, tc, b, e):
            kinematics_points(gimp, P, M, vn, S, o, W, ta, tb, tc, b, e)
    return impl


# The model dispatch is called in the factories' bodies, where ``version`` is a closure
# value and so a compile-time literal (see fem_rmpm.materials.dispatch); so is ``fbar``.
def _make_stress_pass(version, only, fbar):
    """``(serial, parallel)`` stress pass compiled for one registry version, model
    restriction ``only`` (-1: any model; else the one model id of all points; see
    :mod:`fem_rmpm.materials.dispatch`) and F-bar or not (``fbar``, the steps' ``o.fbar``:
    only that kinematics is compiled, :func:`point_kinematics`); ``S.out`` (4,) = max P-wave speed
    sqrt(M / rho), max |v|, number of non-finite points, number outside the grid.
    ``serial``: the nodal velocities of both halves (:func:`.transfer.nodal_velocity`;
    with F-bar they are computed before, for the gradient pass), then every block of
    points in order; ``parallel``: ``o.threads`` workers taking the blocks from the two
    halves' queues (:func:`_stress_queue_call`), the nodal velocities computed before
    (two workers without F-bar: by the workers, :func:`nodal_in_pass`).
    Maxima and counts are combined exactly: the same result in both."""
    @kernel
    @variant("stress_pass", registry=version, only=only, fbar=fbar)
    def stress_pass(P, M, N, S, o):
        serial_stress_pass(False, False, False, version, only, fbar, P, M, N, S, o)

    @kernel_parallel
    @variant("stress_pass_parallel", registry=version, only=only, fbar=fbar)
    def stress_pass_parallel(P, M, T, H, S, o):
        nch = workers(o, S)
        _reset_queues(S)
        for c in prange(nch):
            _stress_queue_call(version, only, fbar, P, M, T, H, S, o, np.int64(c))
        _combine(S, nch)
    return stress_pass, stress_pass_parallel


@inline
def serial_stress_pass(fixed, gimp, block, version, only, fbar, P, M, N, S, o):
    """The serial stress pass (the body of :func:`_make_stress_pass`'s ``serial``, also run
    by the step driver, :mod:`.advance`): the nodal velocities of both halves (with F-bar
    the caller computed them before its gradient pass), then every block of points in
    order, one worker; ``version``, ``only``, ``fbar``: literals, as there; ``gimp``,
    ``block``: the basis and the block update, ``fixed``: whether they are constants, as
    :func:`stress_queue`."""
    T = top(N)
    if not fbar:
        nodal_velocity_half(M, T, N.half, np.int64(0))
        nodal_velocity_half(M, T, N.half, np.int64(1))
    _reset_queues(S)
    stress_queue(fixed, gimp, block, version, only, fbar, P, M, T, N.half, S, o, np.int64(0))
    _combine(S, 1)


@inline
def workers(o, S):
    """The stress pass's workers: ``o.threads``, at most one per row of ``S.parts``."""
    return max(1, min(o.threads, S.parts.shape[0]))


@inline
def nodal_in_pass(o, S):
    """Whether the threaded stress pass computes the nodal velocities itself: each of
    exactly two workers those of its own half, publishes them (a flag, read by the other
    worker before it takes any block of that half), then its half's blocks; so the threaded
    loop needs no region of its own for them (F-bar's gradient pass needs all of them
    before the pass)."""
    return workers(o, S) == 2 and not o.fbar


@inline
def _reset_queues(S):
    """Both work queues of the stress pass back to their first block, both halves' nodal
    velocities unpublished (:func:`nodal_in_pass`)."""
    for h in range(2):
        S.queue[QUEUE_STRIDE * h] = 0
        S.queue[QUEUE_STRIDE * h + QUEUE_FLAG] = 0


@kernel
def _stress_queue_call(version, only, fbar, P, M, T, H, S, o, c):
    """Worker ``c`` of the stress pass: takes the next block of :data:`.common.BLOCK`
    points from the queue of its own half of the points (half ``c % 2``, the half its
    thread mapped and moved: those points are in its core's cache), then from the other
    half's queue until none is left (``S.queue[0]`` and ``[QUEUE_STRIDE]``,
    :func:`.common.take_ticket`), each block with the nodal velocities of its half, the
    scratch row ``c``; its statistics into ``S.parts[c]``.  Where :func:`nodal_in_pass`
    (two workers), first the nodal velocities of its own half, then their flag
    (``S.queue[QUEUE_STRIDE c + QUEUE_FLAG]``, an atomic add); it takes blocks of the other half
    only once that half's flag is set (:func:`.common.read_flag`), else it stops (it never
    waits: a numba pool of one thread runs the workers one after the other).
    Why its own half first: a block the other thread took crosses between the cores twice
    per step (its stress and volume to the other core, then back for the next map), and a
    core-to-core round trip can cost hundreds of nanoseconds on a virtual machine.  Why
    the other half after: the halves' stress passes differ in cost (plastic points cost
    more), and a worker done first would otherwise wait.  Which worker takes a block
    changes nothing in it: every block is computed by this one compiled function, maxima
    and counts combine exactly, so any thread count and any interleaving give bitwise the
    same result (``tests/test_threads.py``, with a half switched off so that one worker
    takes most of the other's blocks).  ``version``, ``only`` and ``fbar`` (``o.fbar``) are
    literals (one compile and cache entry per triple); not inlined into the threaded loop:
    numba's parfor passes, run over the inlined model update, can change the result (1 and
    2 threads would differ).  Module level, not a closure of :func:`_make_stress_pass`:
    numba's cache key of a closure holds its cell values pickled, and a dispatcher pickles
    with a random uuid, so a threaded pass closing over this dispatcher would miss the
    cache in every new process."""
    _stress_queue(version, only, fbar, o.gimp, o.block, P, M, T, H, S, o, c)


@inline
def _stress_queue(version, only, fbar, gimp, block, P, M, T, H, S, o, c):
    """The body of :func:`_stress_queue_call`, with the basis ``gimp`` and the block
    update ``block`` (``o.gimp``, ``o.block``; or constants, :func:`stress_queue`)."""
    n = P.x.shape[0]
    fixed_columns(P, S)
    bounds = (0, half_split(n) // BLOCK, (n + BLOCK - 1) // BLOCK)   # blocks of the halves
    c2max = 0.0
    n_bad = 0
    in_pass = nodal_in_pass(o, S)
    if in_pass:
        nodal_velocity_half(M, T, H, c)
        take_ticket(S.queue[QUEUE_STRIDE * c + QUEUE_FLAG:])
    for r in range(2):                       # its own half (c % 2), then the other's
        h = (c + r) % 2
        if r == 1 and in_pass and read_flag(S.queue[QUEUE_STRIDE * h + QUEUE_FLAG:]) == 0:
            break
        vn = T.v_musl if h == 0 else H.v_musl
        while True:                  # (one call site: one inlined copy of the model update)
            k = bounds[h] + take_ticket(S.queue[QUEUE_STRIDE * h:])
            if k >= bounds[h + 1]:
                break
            b = k * BLOCK
            c2, nb = _stress_points(version, only, fbar, gimp, block, P, M, vn, S, o, b,
                                    min(b + BLOCK, n), c)
            c2max = max(c2max, c2)
            n_bad += nb
    S.parts[c, 0] = c2max
    S.parts[c, 1] = n_bad


def _stress_queue_for(gimp, block):
    """:func:`_stress_queue_call` compiled for one basis (``gimp``) and one model path
    (``block``: the model's block update, else its point update): the constants are pruned,
    so neither the other basis nor the other path is compiled.  A closure of two booleans
    (numba's cache key holds them)."""
    @kernel
    @variant("stress_queue", gimp=gimp, block=block)
    def queue(version, only, fbar, P, M, T, H, S, o, c):
        _stress_queue(version, only, fbar, gimp, block, P, M, T, H, S, o, c)
    return queue


# The kernels of :func:`_stress_queue_for`, module-level names (a step driver refers to
# them as globals: numba's cache key of a closure holds its cell values, and a dispatcher
# there would pickle with a random uuid), all in one cache index (one qualified name).
_QUEUE_Q4_POINTS = _stress_queue_for(False, False)
_QUEUE_Q4_BLOCK = _stress_queue_for(False, True)
_QUEUE_GIMP_POINTS = _stress_queue_for(True, False)
_QUEUE_GIMP_BLOCK = _stress_queue_for(True, True)


@inline
def stress_queue(fixed, gimp, block, version, only, fbar, P, M, T, H, S, o, c):
    """Worker ``c`` of the stress pass (:func:`_stress_queue_call`).  ``fixed`` (a
    constant): ``gimp`` and ``block`` are constants too (closure values of a step driver,
    :mod:`.advance`), and the kernel of :func:`_stress_queue_for` for them runs (the other
    three are not compiled); else :func:`_stress_queue_call` with ``o.gimp`` and
    ``o.block``."""
    if not fixed:
        _stress_queue_call(version, only, fbar, P, M, T, H, S, o, c)
    elif gimp:
        if block:
            _QUEUE_GIMP_BLOCK(version, only, fbar, P, M, T, H, S, o, c)
        else:
            _QUEUE_GIMP_POINTS(version, only, fbar, P, M, T, H, S, o, c)
    elif block:
        _QUEUE_Q4_BLOCK(version, only, fbar, P, M, T, H, S, o, c)
    else:
        _QUEUE_Q4_POINTS(version, only, fbar, P, M, T, H, S, o, c)


@inline
def _combine(S, nch):
    """``S.out`` = (largest P-wave speed, largest point speed, non-finite points, points
    outside the grid) from the stress pass's ``nch`` chunks (``S.parts``) and the map
    back's two halves (``S.halves``), exactly (maxima and counts)."""
    c2 = 0.0
    n_bad = S.halves[0, 3] + S.halves[1, 3]
    for c in range(nch):
        c2 = max(c2, S.parts[c, 0])
        n_bad += S.parts[c, 1]
    S.out[0] = math.sqrt(c2)
    S.out[1] = math.sqrt(max(S.halves[0, 2], S.halves[1, 2]))
    S.out[2] = n_bad
    S.out[3] = S.halves[0, 4] + S.halves[1, 4]


@inline
def _stress_points(version, only, fbar, gimp, block, P, M, vn, S, o, start, stop, row):
    """The stress pass over points ``start:stop`` (whole blocks from a multiple of
    :data:`.common.BLOCK`) with the nodal velocities ``vn`` (2 nn,) and the block scratch
    ``row`` of ``S`` (one per thread: the same BLOCK rows for every block, so they stay in
    L1 and are never written back); returns the largest squared P-wave speed and the
    number of points with a non-finite stress.  (The four scratch arrays are passed one by
    one: numba 0.68 can lose writes to the arrays of a tuple made in two branches of an
    ``if`` by inlined functions.)"""
    W, ta, tb, tc, Z = S.W[row], S.ta[row], S.tb[row], S.tc[row], S.Z[row]
    assume_columns(W, W_COLUMNS)
    assume_columns(Z, BLOCK_COLUMNS)
    c2max = 0.0
    n_bad = 0
    stop_ = np.uint64(stop)
    for b in range(np.uint64(start), stop_, np.uint64(BLOCK)):
        e = min(b + np.uint64(BLOCK), stop_)
        if not o.geostatic:
            exp_block(P.log_strain, tb, tc, b, e)
        point_kinematics(fbar, gimp, P, M, vn, S, o, W, ta, tb, tc, b, e)
        if not o.geostatic:
            log_block(W, ta, tb, tc, e - b)
        c2, nb = _finish(version, only, block, P, o, W, ta, tb, Z, b, e)
        c2max = max(c2max, c2)
        n_bad += nb
    return c2max, n_bad


@inline
def _finish(version, only, block, P, o, W, ta, tb, Z, b, e):
    """Points ``b:e`` after the log series: the model update and the Cauchy stress,
    through the model's block update where the run's points take it (``block``:
    ``o.block``, true only where the one model of the pass has a block update,
    :func:`fem_rmpm.materials.dispatch.takes_blocks`; a constant compiles one path), else
    point by point; returns (largest squared P-wave speed, non-finite points)."""
    if block:
        return _finish_block(version, only, P, o, W, ta, tb, Z, b, e)
    # (one call site: one inlined copy of the model update)
    return _finish_points(version, only, P, o, W, ta, tb, b, e)


@inline
def _finish_points(version, only, P, o, W, ta, tb, b, e):
    """Points ``b:e``: the model update of the trial strain, Cauchy stress; returns the
    largest squared P-wave speed sqrt((K + 4/3 G) V / m) (for the next CFL step) and the
    number of points with a non-finite stress (for the guards; their positions and
    velocities are checked by the map back)."""
    ls, params = P.log_strain, P.params
    c2max = 0.0
    n_bad = 0
    for i in range(b, e):
        if not P.active[i]:
            continue
        e0, e1, e2, e3 = _trial_strain(o.geostatic, i, i - b, W, ta, tb, ls)
        r = point_dispatch(version, only, P.model[i], e0, e1, e2, e3, P.state, params, i)
        c2, bad = _store(P, i, r[0], r[1], r[2], r[3], r[4], r[5], r[6], r[7])
        c2max = max(c2max, c2)
        n_bad += bad
    return c2max, n_bad


@inline
def _store(P, i, e0, e1, e2, e3, t0, t1, t2, t3):
    """Point ``i``'s returned log strain and its Cauchy stress ``tau V0 / V``; returns its
    squared P-wave speed (K + 4/3 G) V / m (for the next CFL step: max of sqrt = sqrt of
    max) and 1 if its stress is not finite (for the guards), else 0."""
    ls, stress, params = P.log_strain, P.stress, P.params
    ls[i, 0] = e0
    ls[i, 1] = e1
    ls[i, 2] = e2
    ls[i, 3] = e3
    V = P.vol[i]
    ratio = P.vol0[i] / V
    s0 = t0 * ratio
    s1 = t1 * ratio
    s2 = t2 * ratio
    s3 = t3 * ratio
    stress[i, 0] = s0
    stress[i, 1] = s1
    stress[i, 2] = s2
    stress[i, 3] = s3
    bad = 0 if math.isfinite(s0 + s1 + s2 + s3) else 1
    return (params[i, 1] + 4.0 / 3.0 * params[i, 0]) * V / P.mass[i], bad


@inline
def _finish_block(version, only, P, o, W, ta, tb, Z, b, e):
    """:func:`_finish_points` through the model's vectorised ``block_update`` (the trial
    strains into ``Z[0:4]``, the model's strains and Kirchhoff stress from ``Z[4:12]``;
    the same results), for a run whose points it takes (``o.block``,
    :func:`fem_rmpm.materials.dispatch.takes_blocks`)."""
    for i in range(b, e):
        j = i - b
        Z[0, j], Z[1, j], Z[2, j], Z[3, j] = _trial_strain(o.geostatic, i, j, W, ta, tb,
                                                           P.log_strain)
    block_dispatch(version, only, Z, P.state, P.params, P.active, b, e - b)
    c2max = 0.0
    n_bad = 0
    for i in range(b, e):
        if not P.active[i]:
            continue
        j = i - b
        c2, bad = _store(P, i, Z[4, j], Z[5, j], Z[6, j], Z[7, j], Z[8, j], Z[9, j], Z[10, j],
                         Z[11, j])
        c2max = max(c2max, c2)
        n_bad += bad
    return c2max, n_bad


def _make_material_pass(version):
    """The vectorised material update (tests, implicit scheme) for one registry version:
    the model update of trial log strains ``eps_tr`` (n, 4)."""
    @jit
    @variant("material_pass", registry=version)
    def material_pass(eps_tr, state, model, params):
        n = eps_tr.shape[0]
        eps = np.empty((n, 4))
        st = state.copy()
        tau = np.empty((n, 4))
        for i in range(n):
            r = point_dispatch(version, -1, model[i], eps_tr[i, 0], eps_tr[i, 1], eps_tr[i, 2],
                               eps_tr[i, 3], st, params, i)
            eps[i, 0], eps[i, 1], eps[i, 2], eps[i, 3] = r[0], r[1], r[2], r[3]
            tau[i, 0], tau[i, 1], tau[i, 2], tau[i, 3] = r[4], r[5], r[6], r[7]
        return eps, st, tau
    return material_pass


_BY_VERSION: dict = {}
_MATERIAL_PASS: dict = {}


def material_kernels(only: int = -1, fbar: bool = False):
    """``(stress_pass, material_pass, stress_pass_parallel)`` compiled
    for the current model registry; the stress passes for points of model ``only`` alone
    (-1: any model; the material pass always takes any model) and for steps with F-bar
    (``fbar``, the steps' ``o.fbar``) or without."""
    key = (registry.version(), int(only), bool(fbar))
    if key not in _BY_VERSION:
        if key[0] not in _MATERIAL_PASS:
            _MATERIAL_PASS[key[0]] = _make_material_pass(key[0])
        serial, parallel = _make_stress_pass(*key)
        _BY_VERSION[key] = (serial, _MATERIAL_PASS[key[0]], parallel)
    return _BY_VERSION[key]


def _direct(kernel, *args):
    return kernel(*args)


def update_stress(P, M, N, S, o, call=_direct) -> None:
    """Stage 3b and 3c: the MUSL nodal velocities from the re-mapped momenta, then per
    point the velocity gradient at the positions before the move (in the basis the map
    to nodes kept there), deformation increment (geostatic: small strain, J = 1),
    volume, the material update, Cauchy stress, and ``S.out`` (4,) = the largest P-wave
    speed and point speed, the non-finite and the outside points — one stress pass per
    half of the points, on ``o.threads`` threads.  ``o.fbar`` (the F-bar remedy,
    :mod:`fem_rmpm.schemes.locking`): the nodal velocities and
    :func:`.strain.fbar_gradient_pass` first.  ``call(kernel, *args)`` runs a kernel
    (e.g. :meth:`.Workspace.call`)."""
    serial, _, parallel = material_kernels(o.model, o.fbar)
    if o.threads <= 1:
        if o.fbar:
            call(nodal_velocities, M, N)
            call(fbar_gradient_pass, P, M, N, S, o)
        call(serial, P, M, N, S, o)
        return
    T = top_of(N)                    # (the threaded loop takes no nested group)
    if o.fbar or min(o.threads, S.parts.shape[0]) != 2:      # (else: nodal_in_pass)
        call(nodal_velocities_parallel, M, T, N.half)
    if o.fbar:
        call(fbar_gradient_pass_parallel, P, M, T, N.half, S, o)
    call(parallel, P, M, T, N.half, S, o)


# --------------------------------------------------------------------- vectorised material (tests)
def stress_update_points(dF, log_strain, state, soil):
    """:func:`fem_rmpm.materials.stress_update` through the kernels' Hencky functions
    (:mod:`.hencky`) and the generated dispatch: ``dF`` (n, 2, 2), ``log_strain`` (n, 4),
    ``state`` (n, S) or (n,), ``soil`` a :class:`~fem_rmpm.materials.MaterialPoints`.
    Returns ``(log_strain, state, tau)``."""
    n = len(log_strain)
    D = np.ascontiguousarray(dF, dtype=float).reshape(n, 4)
    ls = np.ascontiguousarray(log_strain, dtype=float)
    eps_tr = np.empty((n, 4))
    W, ta, tb, tc = np.empty((4, BLOCK)), np.empty(BLOCK), np.empty(BLOCK), np.empty(BLOCK)
    hencky_trial_pass(D, ls, np.ones(n, dtype=bool), ta, tb, tc, W, eps_tr)
    return _points_update(eps_tr, state, soil)


def small_strain_update_points(grad_du, log_strain, state, soil):
    """:func:`fem_rmpm.materials.small_strain_update` through the kernels: returns
    ``(log_strain, state, tau)``."""
    L = np.asarray(grad_du, dtype=float)
    e = np.asarray(log_strain, dtype=float)
    eps_tr = np.stack([e[:, 0] + L[:, 0, 0], e[:, 1] + L[:, 1, 1], e[:, 2] + 0.0,
                       e[:, 3] + 0.5 * (L[:, 0, 1] + L[:, 1, 0])], axis=1)
    return _points_update(eps_tr, state, soil)


def _points_update(eps_tr, state, soil):
    flat = np.ndim(state) == 1
    st = np.ascontiguousarray(np.asarray(state, float).reshape(len(eps_tr), -1))
    eps, st, tau = material_kernels()[1](eps_tr, st, soil.model,
                                         np.ascontiguousarray(soil.params))
    return eps, (st[:, 0] if flat else st), tau
