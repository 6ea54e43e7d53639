"""Compiled (numba) kernels of the explicit MUSL step: the fast path of
:func:`fem_rmpm.schemes.explicit.step.explicit_step` and of the time loop.

The step of :func:`fem_rmpm.schemes.explicit.reference.explicit_step_numpy` (the readable
numpy reference) in compiled loops over the points or the active nodes, each stage a kernel
of its own so that it can be timed alone (``validation/bench_explicit.py``). The arguments
are grouped (:mod:`.arrays`): the grid ``M``, the points ``P``, the nodes ``N``, scratch
``S`` and the step's options ``o``. The points are taken in two halves, each with its own
nodal arrays (:mod:`.transfer`). The three stages of the method:

1. **map to nodes** — :func:`map_to_nodes`: per point, the host cell (arithmetic on the
   structured grid), Q4 or uGIMP shape values and gradients (:mod:`.basis`), mass,
   momentum and force (with the pore water's force on the point, :mod:`.water`)
   scattered to the nodes.  The nodes it touches are listed: every
   later nodal loop visits those *active* nodes only, and the next step clears only
   them (no work on the empty part of the grid).
2. **solve on the mesh** — in :func:`solve_and_move`: per active node, lumped-mass
   momentum balance, local (Cundall) damping, fixed components, the contact with
   frictional bedrock (:mod:`.contact`), grid kinetic energy.
3. **update the points** — :func:`solve_and_move`: FLIP/PIC velocity, position (or the
   geostatic displacement) and the MUSL re-map of the new point momenta; then
   :func:`update_stress`: the nodal velocities from them and one pass over the points in
   blocks: velocity gradient, Hughes-Winget increment, F, volume and the trial Hencky
   state (:mod:`.strain`, with the exp / log of the 2x2 log strain as vectorised series,
   :mod:`.hencky`), the material model of each point through one dispatch on its model
   id, Cauchy stress and the maxima the time loop needs (:mod:`.stress`).

The time loop runs its ordinary steps back to back in one compiled call
(:mod:`.advance`: the same three stages, then the CFL step, gravity ramp, damping and the
loop's checks, returning at the first step the loop must see), bitwise the steps made one
by one from Python.

Every formula is the one of the numpy path, in the same order where it matters, so the two
agree to round-off (``tests/test_kernels.py``: 1e-12 relative over several steps).
``cache=True`` keeps the compiled code on disk (``validation/bench_explicit.py`` measures
the first compile and the load; :mod:`fem_rmpm.runtime.numba_cache` keys it on every
compiled source file). Threads (``StepOptions.threads`` > 1): the two halves run on two
threads — each stage's nodal loop over the nodes its half touched, so a step has three
parallel regions (map; move; nodal velocities and stress) and no serial merge
(:mod:`.transfer`), or, with exactly two threads and no F-bar, the driver's steps all run in
one region whose joins are spin barriers (:mod:`.advance`); the stress pass hands its blocks
of points out from two work queues, one per half, to all threads (a plastic point costs more
than an elastic one). Any thread count gives bitwise the single-thread result; a Monte Carlo
campaign runs one thread per realization. Each threaded kernel is a function of its own
whose ``prange`` body calls the compiled half or worker function the serial kernel calls
(:mod:`.common` says why); blocks and halves are whole blocks of points from point 0
(:func:`.common.block_bounds`), the same on any number of threads."""
from __future__ import annotations

from fem_rmpm.schemes.explicit.kernels.arrays import (
    Mesh,
    NodeArrays,
    PointArrays,
    Scratch,
    StepOptions,
    Workspace,
    mesh_of,
    node_arrays,
    point_arrays,
    top_of,
)
from fem_rmpm.schemes.explicit.kernels.basis import gimp_shape, q4_shape
from fem_rmpm.schemes.explicit.kernels.common import BLOCK, block_bounds, half_split
from fem_rmpm.schemes.explicit.kernels.stress import (
    _direct,
    material_kernels,
    small_strain_update_points,
    stress_update_points,
    update_stress,
)
from fem_rmpm.schemes.explicit.kernels.transfer import (
    map_to_nodes,
    map_to_nodes_parallel,
    nodal_velocities,
    nodal_velocities_parallel,
    solve_and_move,
    solve_and_move_parallel,
)

__all__ = ["Mesh", "PointArrays", "NodeArrays", "Scratch", "StepOptions", "Workspace",
           "mesh_of", "node_arrays", "point_arrays", "top_of", "map_to_nodes",
           "map_to_nodes_parallel", "solve_and_move", "solve_and_move_parallel",
           "nodal_velocities", "nodal_velocities_parallel", "update_stress", "material_kernels",
           "q4_shape", "gimp_shape", "stress_update_points", "small_strain_update_points",
           "BLOCK", "block_bounds", "half_split"]
