"""Stage 3c of the explicit step: the material update at the points, through the model
registry (:mod:`fem_rmpm.materials`), then Cauchy stress and the step's statistics.

:func:`update_stress` runs the kinematics passes of :mod:`.strain`, the vectorised
exp / log ufuncs between them, and the finish pass: per point the trial log strain, the
point's model update (one dispatch on its model id, generated from the registry by
:mod:`fem_rmpm.materials.dispatch`), Cauchy stress ``tau V0 / V`` and the largest P-wave
speed and point speed (for the next CFL step) and the non-finite and out-of-grid points
(for the guards).  The finish pass is compiled once per registry version
(:func:`material_kernels`) and cached on disk by numba.
"""
from __future__ import annotations

import math

import numpy as np
from numba import prange

from ..materials import registry
from .arrays import top_of
from ..materials.dispatch import point_dispatch
from .common import inline, jit, kernel, kernel_parallel
from .strain import (fbar_apply_pass, fbar_apply_pass_parallel, fbar_gradient_pass,
                     kinematics_pass, kinematics_pass_parallel, log_sym2_from, trial_pass)

__all__ = ["update_stress", "material_kernels", "stress_update_points",
           "small_strain_update_points"]


@inline
def _trial_strain(geostatic, w0, w1, w2, w3, ta, tb, e2):
    """Trial log strain of a point.  Geostatic (small strain): ``w`` holds it.  Finite
    strain: ``w``, ``ta``, ``tb`` hold b_tr (:mod:`.strain`) and its log is taken here."""
    if geostatic:
        return w0, w1, w2, w3
    x0, x1, x3 = log_sym2_from(w0, w1, w2, w3, ta, tb)
    return x0, x1, e2 + 0.0, x3


# The model dispatch is called in the factories' bodies, where ``version`` is a closure
# value and so a compile-time literal (see fem_rmpm.materials.dispatch).
def _make_finish_pass(version, only):
    """``(serial, parallel)`` finish pass compiled for one registry version and model
    restriction ``only`` (-1: any model; else the one model id of all points; see
    :mod:`fem_rmpm.materials.dispatch`): trial strain, the model update, Cauchy stress
    ``tau V0 / V``; ``S.out`` (4,) = max P-wave speed sqrt(M / rho), max |v|, number of
    non-finite points, number outside the grid (for the next CFL step and the guards)."""
    @kernel
    def finish_pass(P, M, S, o):
        # one chunk of all points (the point loops run over uint64 indices: .common)
        _finish_chunk(version, only, P, M, S, o, 0, P.x.shape[0], S.parts[0])
        _combine(S, 1)

    @kernel_parallel
    def finish_pass_parallel(P, M, S, o):
        # the points in ``o.threads`` chunks; maxima and counts combined exactly, so the
        # result is the serial one for any number of chunks
        n = P.x.shape[0]
        parts = S.parts
        nch = max(1, min(o.threads, parts.shape[0]))
        for c in prange(nch):
            _finish_chunk_call(version, only, P, M, S, o, c * n // nch, (c + 1) * n // nch,
                               parts[c])
        _combine(S, nch)
    return finish_pass, finish_pass_parallel


@kernel
def _finish_chunk_call(version, only, P, M, S, o, start, stop, part):
    """:func:`_finish_chunk` as a compiled function of its own (``version`` and ``only``
    literals: one compile and cache entry per pair), called from the threaded loop, not
    inlined into it: numba's parfor passes, run over the inlined model update, changed the
    result (1 vs 2 threads differed in tests/test_threads.py once the dispatch was inlined).
    Module level, not a closure of :func:`_make_finish_pass`: numba's cache key of a closure
    holds its cell values pickled, and a dispatcher pickles with a random uuid, so the
    threaded finish pass closing over a chunk dispatcher missed the cache in every new
    process (1.6 s of compile at every start with threads = 2, measured)."""
    _finish_chunk(version, only, P, M, S, o, start, stop, part)


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
def _finish_chunk(version, only, P, M, S, o, start, stop, part):
    """The finish pass over points ``start:stop``; squared maxima and counts into
    ``part`` (4,) (a row of ``S.parts``)."""
    x, v, ls, stress, params, W, lo, hi = P.x, P.v, P.log_strain, P.stress, P.params, \
        S.W, M.lo, M.hi
    c2max = 0.0
    vmax2 = 0.0
    n_bad = 0
    n_out = 0
    for i in range(np.uint64(start), np.uint64(stop)):
        if not P.active[i]:
            continue
        e0, e1, e2, e3 = _trial_strain(o.geostatic, W[i, 0], W[i, 1], W[i, 2], W[i, 3],
                                       S.ta[i], S.tb[i], ls[i, 2])
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
    part[0] = c2max
    part[1] = vmax2
    part[2] = n_bad
    part[3] = n_out


def _make_material_pass(version):
    """The vectorised material update (tests) for one registry version."""
    @jit
    def material_pass(geostatic, W, ta, tb, log_strain, state, model, params):
        n = W.shape[0]
        eps = np.empty((n, 4))
        st = state.copy()
        tau = np.empty((n, 4))
        for i in range(n):
            e0, e1, e2, e3 = _trial_strain(geostatic, W[i, 0], W[i, 1], W[i, 2], W[i, 3],
                                           ta[i], tb[i], log_strain[i, 2])
            r = point_dispatch(version, -1, model[i], e0, e1, e2, e3, st, params, i)
            eps[i, 0], eps[i, 1], eps[i, 2], eps[i, 3] = r[0], r[1], r[2], r[3]
            tau[i, 0], tau[i, 1], tau[i, 2], tau[i, 3] = r[4], r[5], r[6], r[7]
        return eps, st, tau
    return material_pass


_BY_VERSION: dict = {}


def material_kernels(only: int = -1):
    """``(finish_pass, material_pass, finish_pass_parallel)`` compiled for the current
    model registry; the finish passes for points of model ``only`` alone (-1: any model;
    the material pass always takes any model)."""
    key = (registry.version(), int(only))
    if key not in _BY_VERSION:
        serial, parallel = _make_finish_pass(*key)
        _BY_VERSION[key] = (serial, _make_material_pass(key[0]), parallel)
    return _BY_VERSION[key]


def _direct(kernel, *args):
    return kernel(*args)


def update_stress(P, M, N, S, o, call=_direct) -> None:
    """Stage 3c: velocity gradient from the re-mapped nodal velocities at the positions
    before the move (``S.x_old``), deformation increment (geostatic: small strain, J = 1),
    F, volume, the material update, Cauchy stress; ``S.out`` as the finish pass.
    Finite strain: ``S.ta``, ``S.tb``, ``S.tc`` must hold the exp arguments of the log
    strain (:func:`fem_rmpm.kernels.transfer.g2p` writes them, or ``exp_args_pass``).
    ``o.fbar``: the F-bar remedy (:mod:`fem_rmpm.locking`).  ``call(kernel, *args)``
    runs a kernel (e.g. :meth:`.Workspace.call`)."""
    par = o.threads > 1
    with np.errstate(all="ignore"):     # a non-finite point is reported by the guards
        if not o.geostatic:          # S.ta, S.tb: the exp arguments, written by g2p
            np.exp(S.ta, out=S.ta)
            np.expm1(S.tb, out=S.tb)
        if o.fbar:
            call(fbar_gradient_pass, P, M, N, S, o)
            call(fbar_apply_pass_parallel if par else fbar_apply_pass, P, S, o)
        else:
            call(kinematics_pass_parallel if par else kinematics_pass, P, M,
                 top_of(N) if par else N, S, o)
        if not o.geostatic:
            np.log(S.ta, out=S.ta)
            np.arctanh(S.tb, out=S.tb)
    finish = material_kernels(o.model)
    call(finish[2] if par else finish[0], P, M, S, o)


# --------------------------------------------------------------------- vectorised material (tests)
def stress_update_points(dF, log_strain, state, soil):
    """:func:`fem_rmpm.materials.stress_update` through the kernels' Hencky passes and the
    generated dispatch: ``dF`` (n, 2, 2), ``log_strain`` (n, 4), ``state`` (n, S) or (n,),
    ``soil`` a :class:`~fem_rmpm.materials.MaterialPoints`.  Returns
    ``(log_strain, state, tau)``."""
    n = len(log_strain)
    D = np.ascontiguousarray(dF, dtype=float).reshape(n, 4)
    ls = np.ascontiguousarray(log_strain, dtype=float)
    act = np.ones(n, dtype=bool)
    W, ta, tb, tc = np.empty((n, 4)), np.empty(n), np.empty(n), np.empty(n)
    m, d = 0.5 * (ls[:, 0] + ls[:, 1]), 0.5 * (ls[:, 0] - ls[:, 1])   # as exp_args_pass
    ta[:], tb[:] = 2 * m, 2 * np.sqrt(d * d + ls[:, 3] * ls[:, 3])
    tc[:] = tb
    with np.errstate(all="ignore"):     # non-finite values propagate to the caller's guards
        np.exp(ta, out=ta)
        np.expm1(tb, out=tb)
        trial_pass(D, ls, act, ta, tb, tc, W)
        np.log(ta, out=ta)
        np.arctanh(tb, out=tb)
    return _points_update(False, W, ta, tb, ls, state, soil)


def small_strain_update_points(grad_du, log_strain, state, soil):
    """:func:`fem_rmpm.materials.small_strain_update` through the kernels: returns
    ``(log_strain, state, tau)``."""
    n = len(log_strain)
    L = np.asarray(grad_du, dtype=float)
    e = np.asarray(log_strain, dtype=float)
    W = np.stack([e[:, 0] + L[:, 0, 0], e[:, 1] + L[:, 1, 1], e[:, 2] + 0.0,
                  e[:, 3] + 0.5 * (L[:, 0, 1] + L[:, 1, 0])], axis=1)
    z = np.zeros(n)
    return _points_update(True, W, z, z, e, state, soil)


def _points_update(geostatic, W, ta, tb, log_strain, state, soil):
    flat = np.ndim(state) == 1
    st = np.ascontiguousarray(np.asarray(state, float).reshape(len(W), -1))
    eps, st, tau = material_kernels()[1](geostatic, W, ta, tb, log_strain, st, soil.model,
                                         np.ascontiguousarray(soil.params))
    return eps, (st[:, 0] if flat else st), tau
