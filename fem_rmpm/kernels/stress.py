"""Stage 3c of the explicit step: the stress update in one pass over the points —
kinematics, the Hencky trial state, the material model through the model registry
(:mod:`fem_rmpm.materials`), Cauchy stress and the step's statistics.

:func:`update_stress` runs the stress pass (after :func:`.strain.fbar_gradient_pass` with
F-bar).  The pass walks the points in blocks of :data:`.hencky.BLOCK`; per block:

1. the exp parts of the log strains (:func:`.hencky.exp_block`, vectorised series);
2. per point the velocity gradient, Hughes-Winget increment, F, volume and b_tr
   (:func:`.strain.kinematics_points`, or :func:`.strain.fbar_apply_points`);
3. the log parts of b_tr (:func:`.hencky.log_block`, vectorised series);
4. per point the trial log strain, the point's model update (one dispatch on its model
   id, generated from the registry by :mod:`fem_rmpm.materials.dispatch`), Cauchy stress
   ``tau V0 / V``, the largest P-wave speed and point speed (for the next CFL step) and
   the non-finite and out-of-grid points (for the guards).

Geostatic steps (small strain) skip 1 and 3.  A block's scratch stays in L1 between the
four loops; before, 1 and 3 were numpy ufunc passes over all points between three
kernels (the ufuncs alone ~5 ns per point-step on one thread, and serial).  The pass is
compiled once per registry version and model restriction (:func:`material_kernels`) and
cached on disk by numba.
"""
from __future__ import annotations

import math

import numpy as np
from numba import prange

from ..materials import registry
from ..materials.dispatch import point_dispatch
from .arrays import top_of
from .common import inline, jit, kernel, kernel_parallel
from .hencky import BLOCK, block_bounds, exp_block, log_block
from .strain import (fbar_apply_points, fbar_gradient_pass, hencky_trial_pass, kinematics_points,
                     log_sym2_from)

__all__ = ["update_stress", "material_kernels", "stress_update_points",
           "small_strain_update_points"]


@inline
def _trial_strain(geostatic, i, W, ta, tb, ls):
    """Trial log strain of point ``i`` (its log strain ``ls[i]`` not yet updated).
    Geostatic (small strain): ``W[i]`` holds it.  Finite strain: ``W[i, :3]``, ``ta[i]`` =
    ln(J) and ``tb[i]`` = atanh(x)/x hold the log parts of B_tr (:mod:`.hencky`)."""
    if geostatic:
        return W[i, 0], W[i, 1], W[i, 2], W[i, 3]
    iso = 0.5 * (ls[i, 0] + ls[i, 1]) + 0.5 * ta[i]
    x0, x1, x3 = log_sym2_from(W[i, 0], W[i, 1], W[i, 2], iso, tb[i])
    return x0, x1, ls[i, 2] + 0.0, x3


# The model dispatch is called in the factories' bodies, where ``version`` is a closure
# value and so a compile-time literal (see fem_rmpm.materials.dispatch).
def _make_stress_pass(version, only):
    """``(serial, parallel)`` stress pass compiled for one registry version and model
    restriction ``only`` (-1: any model; else the one model id of all points; see
    :mod:`fem_rmpm.materials.dispatch`); ``S.out`` (4,) = max P-wave speed
    sqrt(M / rho), max |v|, number of non-finite points, number outside the grid."""
    @kernel
    def stress_pass(P, M, N, S, o):
        # one chunk of all points (the point loops run over uint64 indices: .common)
        _stress_points(version, only, P, M, N, S, o, 0, P.x.shape[0], S.parts[0])
        _combine(S, 1)

    @kernel_parallel
    def stress_pass_parallel(P, M, N, S, o):
        # the points in ``o.threads`` chunks of whole blocks; maxima and counts combined
        # exactly, so the result is the serial one for any number of chunks
        n = P.x.shape[0]
        parts = S.parts
        nch = max(1, min(o.threads, parts.shape[0]))
        for c in prange(nch):
            start, stop = block_bounds(n, nch, c)
            _stress_chunk_call(version, only, P, M, N, S, o, start, stop, parts[c])
        _combine(S, nch)
    return stress_pass, stress_pass_parallel


@kernel
def _stress_chunk_call(version, only, P, M, N, S, o, start, stop, part):
    """:func:`_stress_points` as a compiled function of its own (``version`` and ``only``
    literals: one compile and cache entry per pair), called from the threaded loop, not
    inlined into it: numba's parfor passes, run over the inlined model update, changed the
    result (1 vs 2 threads differed in tests/test_threads.py once the dispatch was inlined).
    Module level, not a closure of :func:`_make_stress_pass`: numba's cache key of a closure
    holds its cell values pickled, and a dispatcher pickles with a random uuid, so the
    threaded pass closing over a chunk dispatcher missed the cache in every new process
    (1.6 s of compile at every start with threads = 2, measured)."""
    _stress_points(version, only, P, M, N, S, o, start, stop, part)


@inline
def _combine(S, nch):
    """``S.out`` from the squared maxima and counts of the chunks in ``S.parts``."""
    S.out[0] = 0.0
    S.out[1] = 0.0
    S.out[2] = 0.0
    S.out[3] = 0.0
    for c in range(nch):
        S.out[0] = max(S.out[0], S.parts[c, 0])
        S.out[1] = max(S.out[1], S.parts[c, 1])
        S.out[2] += S.parts[c, 2]
        S.out[3] += S.parts[c, 3]
    S.out[0] = math.sqrt(S.out[0])
    S.out[1] = math.sqrt(S.out[1])


@inline
def _stress_points(version, only, P, M, N, S, o, start, stop, part):
    """The stress pass over points ``start:stop`` (whole blocks from a multiple of
    :data:`BLOCK`); squared maxima and counts into ``part`` (4,) (a row of ``S.parts``)."""
    c2max = 0.0
    vmax2 = 0.0
    n_bad = 0
    n_out = 0
    stop_ = np.uint64(stop)
    for b in range(np.uint64(start), stop_, np.uint64(BLOCK)):
        e = min(b + np.uint64(BLOCK), stop_)
        if not o.geostatic:
            exp_block(P.log_strain, S.tb, S.tc, b, e)
        if o.fbar:
            fbar_apply_points(P, S, o, b, e)
        else:
            kinematics_points(P, M, N, S, o, b, e)
        if not o.geostatic:
            log_block(S.W, S.ta, S.tb, S.tc, b, e)
        c2, v2, nb, no = _finish_points(version, only, P, M, S, o, b, e)
        c2max = max(c2max, c2)
        vmax2 = max(vmax2, v2)
        n_bad += nb
        n_out += no
    part[0] = c2max
    part[1] = vmax2
    part[2] = n_bad
    part[3] = n_out


@inline
def _finish_points(version, only, P, M, S, o, b, e):
    """Points ``b:e``: the model update of the trial strain, Cauchy stress; returns the
    squared maxima (P-wave speed, |v|) and the non-finite and outside counts."""
    x, v, ls, stress, params, W, lo, hi = P.x, P.v, P.log_strain, P.stress, P.params, \
        S.W, M.lo, M.hi
    c2max = 0.0
    vmax2 = 0.0
    n_bad = 0
    n_out = 0
    for i in range(b, e):
        if not P.active[i]:
            continue
        e0, e1, e2, e3 = _trial_strain(o.geostatic, i, W, S.ta, S.tb, ls)
        r = point_dispatch(version, only, P.model[i], e0, e1, e2, e3, P.state, params, i)
        ls[i, 0] = r[0]
        ls[i, 1] = r[1]
        ls[i, 2] = r[2]
        ls[i, 3] = r[3]
        V = P.vol[i]
        ratio = P.vol0[i] / V
        s0 = r[4] * ratio
        s1 = r[5] * ratio
        s2 = r[6] * ratio
        s3 = r[7] * ratio
        stress[i, 0] = s0
        stress[i, 1] = s1
        stress[i, 2] = s2
        stress[i, 3] = s3
        # for the next CFL step (max of sqrt = sqrt of max) and the guards
        c2max = max(c2max, (params[i, 1] + 4.0 / 3.0 * params[i, 0]) * V / P.mass[i])
        v0 = v[i, 0]
        v1 = v[i, 1]
        s2v = v0 * v0 + v1 * v1
        vmax2 = max(vmax2, s2v)
        y0 = x[i, 0]
        y1 = x[i, 1]
        if not math.isfinite(y0 + y1 + s2v + s0 + s1 + s2 + s3):
            n_bad += 1
        elif y0 < lo[0] or y1 < lo[1] or y0 > hi[0] or y1 > hi[1]:
            n_out += 1
    return c2max, vmax2, n_bad, n_out


def _make_material_pass(version):
    """The vectorised material update (tests, implicit scheme) for one registry version:
    the model update of trial log strains ``eps_tr`` (n, 4)."""
    @jit
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


def material_kernels(only: int = -1):
    """``(stress_pass, material_pass, stress_pass_parallel)`` compiled for the current
    model registry; the stress passes for points of model ``only`` alone (-1: any model;
    the material pass always takes any model)."""
    key = (registry.version(), int(only))
    if key not in _BY_VERSION:
        serial, parallel = _make_stress_pass(*key)
        _BY_VERSION[key] = (serial, _make_material_pass(key[0]), parallel)
    return _BY_VERSION[key]


def _direct(kernel, *args):
    return kernel(*args)


def update_stress(P, M, N, S, o, call=_direct) -> None:
    """Stage 3c: velocity gradient from the re-mapped nodal velocities at the positions
    before the move (``S.x_old``), deformation increment (geostatic: small strain, J = 1),
    F, volume, the material update, Cauchy stress, and ``S.out`` (4,) = the largest P-wave
    speed and point speed, the non-finite and the outside points — one stress pass (on
    ``o.threads`` threads), after :func:`.strain.fbar_gradient_pass` with ``o.fbar`` (the
    F-bar remedy, :mod:`fem_rmpm.locking`).  ``call(kernel, *args)`` runs a kernel (e.g.
    :meth:`.Workspace.call`)."""
    if o.fbar:
        call(fbar_gradient_pass, P, M, N, S, o)
    passes = material_kernels(o.model)
    if o.threads > 1:                # (the threaded loop takes no nested group: top_of)
        call(passes[2], P, M, top_of(N), S, o)
    else:
        call(passes[0], P, M, N, S, o)


# --------------------------------------------------------------------- vectorised material (tests)
def stress_update_points(dF, log_strain, state, soil):
    """:func:`fem_rmpm.materials.stress_update` through the kernels' Hencky functions
    (:mod:`.hencky`) and the generated dispatch: ``dF`` (n, 2, 2), ``log_strain`` (n, 4),
    ``state`` (n, S) or (n,), ``soil`` a :class:`~fem_rmpm.materials.MaterialPoints`.
    Returns ``(log_strain, state, tau)``."""
    n = len(log_strain)
    D = np.ascontiguousarray(dF, dtype=float).reshape(n, 4)
    ls = np.ascontiguousarray(log_strain, dtype=float)
    W, eps_tr = np.empty((n, 4)), np.empty((n, 4))
    ta, tb, tc = np.empty(n), np.empty(n), np.empty(n)
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
