"""Compiled (numba) kernels of the explicit MUSL step: the fast path of :mod:`fem_rmpm.explicit`.

The step of :func:`fem_rmpm.explicit.explicit_step_numpy` (the readable numpy reference)
in serial single-thread loops over the points or the active nodes, each a kernel of its
own so that it can be timed alone (``validation/bench_explicit.py``).  The arguments are
grouped (:mod:`.arrays`): the grid ``M``, the points ``P``, the nodes ``N``, scratch ``S``
and the step's options ``o``.  The three stages of the method:

1. **map to nodes** — :func:`map_to_nodes`: per point, the host cell (arithmetic on the
   structured grid), Q4 or uGIMP shape values and gradients (:mod:`.basis`), mass,
   momentum and force scattered to the nodes.  The nodes it touches are listed: every
   later nodal loop visits those *active* nodes only, and the next step clears only
   them (no work on the empty part of the grid).
2. **solve on the mesh** — :func:`solve_on_mesh`: per active node, lumped-mass momentum
   balance, local (Cundall) damping, fixed components, grid kinetic energy.
3. **update the points** — :func:`update_points`: FLIP/PIC velocity, position (or the
   geostatic displacement) and the MUSL re-map of the new point momenta and the nodal
   velocities from them (:func:`g2p`), then the stress update (:func:`update_stress`), one
   pass over the points in blocks: velocity gradient, Hughes-Winget increment, F, volume
   and the trial Hencky state (:mod:`.strain`, with the exp / log of the 2x2 log strain
   as vectorised series, :mod:`.hencky`), the material model of each point through one
   dispatch on its model id, Cauchy stress and the maxima the time loop needs
   (:mod:`.stress`).

Every formula is the one of the numpy path, in the same order where it matters, so the
two agree to round-off (``tests/test_kernels.py``: 1e-12 relative over several steps,
measured ~1e-14).  ``cache=True`` keeps the compiled code on disk (a first run of case (i)
on one thread in a fresh environment compiles: 31.4 s for the whole process, then 2.7 s
for a warm one, 2026-12-02, load 1.1; ``validation/bench_explicit.py`` measures it;
:mod:`fem_rmpm.numba_cache` keys it on every compiled source file).  Threads
(``StepOptions.threads`` > 1): the per-point passes run with ``prange`` and the two
scatters sum two fixed halves of the points (:mod:`.transfer`), so any thread count
gives bitwise the single-thread result; a Monte Carlo campaign runs one thread per
realization.  Each threaded kernel is a function of
its own whose ``prange`` body calls the compiled half or chunk the serial kernel calls
(:mod:`.common` says why); solve on the mesh and the nodal velocities run as two fixed
halves of the active nodes; the stress pass's chunks are whole blocks of points from
point 0 (:func:`.hencky.block_bounds`), the same blocks on any number of threads.
"""
from __future__ import annotations

from .arrays import (Mesh, NodeArrays, PointArrays, Scratch, StepOptions, Workspace, mesh_of,
                     point_arrays, top_of)
from .basis import gimp_shape, q4_shape
from .stress import (_direct, material_kernels, small_strain_update_points, stress_update_points,
                     update_stress)
from .transfer import (g2p, g2p_parallel, map_to_nodes, map_to_nodes_parallel, solve_on_mesh,
                       solve_on_mesh_parallel)

__all__ = ["Mesh", "PointArrays", "NodeArrays", "Scratch", "StepOptions", "Workspace",
           "mesh_of", "point_arrays", "top_of", "map_to_nodes", "map_to_nodes_parallel", "solve_on_mesh",
           "solve_on_mesh_parallel",
           "update_points", "g2p", "g2p_parallel", "update_stress", "material_kernels", "q4_shape",
           "gimp_shape",
           "stress_update_points", "small_strain_update_points"]


def update_points(P: PointArrays, M: Mesh, N: NodeArrays, S: Scratch, o: StepOptions,
                  call=_direct) -> float:
    """Stage 3: move the points, MUSL re-map, then the stress update.  Returns the largest
    |v_pic| (m/s), the motion as the grid sees it.  ``call(kernel, *args)`` runs a kernel
    (e.g. :meth:`.Workspace.call`)."""
    if o.threads > 1:                # + nodal velocity
        vmax = call(g2p_parallel, P, M, top_of(N), N.half, S, o)
    else:
        vmax = call(g2p, P, M, N, S, o)
    update_stress(P, M, N, S, o, call)
    return vmax
