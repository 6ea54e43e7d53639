"""The three-dimensional explicit step on one thread (:func:`step_3d`, one compiled call)
and on two (:func:`step_3d_threaded`): the stages of :mod:`.kernels` and
:func:`.stress3d.stress_3d`, each per-half stage run for half 0 and half 1 of the points,
one after the other or on two threads (a ``prange`` over the two halves whose body calls
the same compiled stage kernel, :data:`fem_rmpm.runtime.compiled.kernel_parallel` says
why), with the serial nodal stages between them.  Each half scatters into nodal rows of
its own and the halves are added in the same order on one and two threads, so the two
steps are bitwise equal (``tests/test_3d_threads.py``).
"""
from __future__ import annotations

import math
from collections import namedtuple

from numba import prange

from fem_rmpm.runtime.compiled import kernel, kernel_parallel
from fem_rmpm.schemes.explicit3d.kernels import (
    half_split,
    map_back_3d,
    map_to_nodes_3d,
    nodal_velocity_3d,
    solve_nodes_3d,
)
from fem_rmpm.schemes.explicit3d.stress3d import stress_3d

__all__ = ["step_3d", "step_3d_threaded", "StepPoints", "StepGrid", "StepScratch"]


#: The point arrays of the step: positions ``x``, velocities ``v`` (n, 3) m, m/s;
#: ``mass`` t; ``vol``, ``vol0`` m3; Cauchy ``stress`` (n, 6) kPa; elastic log strain
#: ``eps`` (n, 6) and its ``be = exp(2 eps)``; Lame ``lam``, ``mu`` (n,) kPa; ``active``
#: (n,) bool; geostatic displacement ``u_geo`` (n, 3) m; ``model`` (n,) with its parameter
#: rows ``plastic`` (n, 4) and state rows ``state`` (n, >= 2)
#: (:func:`.plastic.plastic_return_principal_3d`).
StepPoints = namedtuple("StepPoints", "x v mass vol vol0 stress eps be lam mu active u_geo "
                                      "model plastic state")
#: The grid: ``origin``, cell sizes ``h`` (3,) m, ``shape`` (3,) cells, ``fixed`` (nn, 3).
StepGrid = namedtuple("StepGrid", "origin h shape fixed")
#: The step's scratch (:class:`.loop.Workspace3D`): each point's first cell node
#: ``cellbase`` and local coordinates ``cellxi`` (n, 3); per half (first axis 2) the
#: nodal rows ``buf`` (2, nn, 8), node flags ``touched`` and list ``nodes`` (2, nn), cell
#: flags ``cell_touched`` and list ``cells`` (2, n_cells); the counts ``nact`` (3, 2)
#: (per half: nodes, cells; then the nodes of both); the totals ``node`` (nn, 8) and the
#: nodes of both halves ``unodes`` (nn,); ``stats`` (2, 5) per half (squared P-wave
#: speed (the stress pass), squared point speed, non-finite points (map back: positions
#: and velocities; the stress pass adds stresses), points outside, squared grid velocity
#: (map back));
#: ``e3`` (2, 3), the stress pass's blocks ``blk`` (2, BLOCK_ROWS, B) and ``idx`` (2, B) per half
#: (:func:`.stress3d.stress_3d`).
StepScratch = namedtuple("StepScratch", "cellbase cellxi buf touched nodes cell_touched cells "
                                        "nact node unodes stats e3 blk idx")


@kernel
def _bounds(n, w):
    """Points ``lo, hi`` of half ``w`` (0 or 1) of ``n`` points."""
    s = half_split(n)
    return (0, s) if w == 0 else (s, n)


@kernel
def _map_half(P, G, W, w):
    lo, hi = _bounds(P.x.shape[0], w)
    map_to_nodes_3d(P.x, P.v, P.mass, P.vol, P.stress, P.active, G.origin, G.h, G.shape,
                    W.cellbase, W.cellxi, lo, hi, W.buf[w], W.touched[w], W.nodes[w],
                    W.cell_touched[w], W.cells[w], W.nact[w])


@kernel
def _back_half(P, G, W, w, dt, flip, geostatic):
    lo, hi = _bounds(P.x.shape[0], w)
    map_back_3d(P.x, P.v, P.mass, P.active, P.u_geo, W.cellbase, W.cellxi, G.origin, G.h,
                G.shape, lo, hi, W.node, W.buf[w], W.nodes[w], W.nact[w], dt, flip, geostatic,
                W.stats[w])


@kernel
def _stress_half(P, G, W, w, dt, geostatic):
    lo, hi = _bounds(P.x.shape[0], w)
    stress_3d(P.mass, P.vol, P.vol0, P.stress, P.eps, P.be, P.lam, P.mu, P.active,
              W.cellbase, W.cellxi, G.h, G.shape, W.node, lo, hi, dt,
              geostatic, P.model, P.plastic, P.state, W.e3[w], W.blk[w], W.idx[w],
              W.stats[w])


@kernel
def _nodal(G, W, g, dt, damping):
    """The serial stage 2; returns the kinetic energy."""
    return solve_nodes_3d(W.buf, W.touched, W.nodes, W.nact, W.node, W.unodes, G.fixed, g,
                          dt, damping)


@kernel
def _nodal_velocity(G, W):
    nodal_velocity_3d(W.node, W.buf, G.fixed, W.unodes, W.nact)


@kernel
def _finish(W, ke, out):
    """The step's stats ``out`` (:data:`.kernels.N_STATS`) from the halves' ``stats``."""
    s = W.stats
    out[0] = ke
    out[1] = math.sqrt(max(s[0, 4], s[1, 4]))
    out[2] = math.sqrt(max(s[0, 0], s[1, 0]))
    out[3] = math.sqrt(max(s[0, 1], s[1, 1]))
    out[4] = s[0, 2] + s[1, 2]
    out[5] = s[0, 3] + s[1, 3]


@kernel
def step_3d(P, G, W, dt, g, damping, flip, geostatic, out):
    """One explicit step of ``dt`` s on one thread, in place on the points ``P``
    (:data:`StepPoints`) on the grid ``G`` (:data:`StepGrid`) with the scratch ``W``
    (:data:`StepScratch`), gravity ``g`` (3,) m/s2,
    damping ratio, FLIP fraction; fills ``out`` (:data:`.kernels.N_STATS`)."""
    for w in range(2):
        _map_half(P, G, W, w)
    ke = _nodal(G, W, g, dt, damping)
    for w in range(2):
        _back_half(P, G, W, w, dt, flip, geostatic)
    _nodal_velocity(G, W)
    for w in range(2):
        _stress_half(P, G, W, w, dt, geostatic)
    _finish(W, ke, out)


@kernel_parallel
def _map_pair(P, G, W):
    for w in prange(2):
        _map_half(P, G, W, w)


@kernel_parallel
def _back_pair(P, G, W, dt, flip, geostatic):
    for w in prange(2):
        _back_half(P, G, W, w, dt, flip, geostatic)


@kernel_parallel
def _stress_pair(P, G, W, dt, geostatic):
    for w in prange(2):
        _stress_half(P, G, W, w, dt, geostatic)


def step_3d_threaded(P, G, W, dt, g, damping, flip, geostatic, out) -> None:
    """:func:`step_3d` with each half of the points on a thread of its own in the map,
    the map back and the stress pass (three parallel regions a step); bitwise the same."""
    _map_pair(P, G, W)
    ke = _nodal(G, W, g, dt, damping)
    _back_pair(P, G, W, dt, flip, geostatic)
    _nodal_velocity(G, W)
    _stress_pair(P, G, W, dt, geostatic)
    _finish(W, ke, out)
