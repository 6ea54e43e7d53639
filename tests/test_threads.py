"""Two threads for one realization give bitwise the single-thread result.

The points are taken in two fixed halves, each scattering into its own nodal arrays and
solving, moving and re-mapping on its own nodes, with both halves' sums added in a fixed
order where both touched a node (:mod:`fem_rmpm.schemes.explicit.kernels.transfer`); the halves run on two
threads or one after the other.  The stress pass hands out blocks of points from two work
queues (one per half) to however many threads there are, in whatever order they come; each block is
computed by the one compiled function the serial pass also runs, and the step's maxima
and counts are combined exactly.  So the state after any number of steps
is equal bit for bit on 1 and 2 threads (asserted: 0 difference).  numba's pool is set
to 2 threads for the test (the campaign tests pin it to 1 in this process).
"""
from __future__ import annotations

import numba
import numpy as np
import pytest

from fem_rmpm.discretise.grid import make_grid
from fem_rmpm.discretise.point_order import permute_points
from fem_rmpm.discretise.points import seed_particles
from fem_rmpm.scene import load_scene, with_values
from fem_rmpm.schemes.explicit.kernels import half_split
from fem_rmpm.schemes.explicit.loop import Workspace, explicit_step, stable_time_step

FIELDS = ("x", "velocity", "stress", "log_strain", "state", "volume", "u_geostatic")


def _softening_layer(meshes, shape="standard"):
    """The elastic slope's layer on 0.5 m cells, von Mises softening from 3 to 1 kPa."""
    return with_values(load_scene(meshes / "slope_elastic.toml"), {
        "grid.cell": [0.5, 0.5], "solver.shape": shape, "soil.model": "von_mises_softening",
        "soil.cohesion_peak": 3.0, "soil.cohesion_residual": 1.0, "soil.softening_strain": 0.05})


def _assert_steps_equal(scene, grid, a, shape, fbar, threads):
    """12 steps (3 geostatic, gravity x 20) of ``a`` on one thread and of a copy of it on
    ``threads``, numba's pool at 2: the steps' maxima and every field bitwise equal."""
    b = a.copy()
    wa, wb = Workspace.for_grid(grid, a.n), Workspace.for_grid(grid, b.n)
    before = numba.get_num_threads()
    numba.set_num_threads(min(2, numba.config.NUMBA_NUM_THREADS))
    try:
        g = np.array(scene.gravity_vector) * 20.0
        for k in range(12):
            dt = stable_time_step(a, grid.cell, 0.5)
            sa = explicit_step(grid, a, dt, g, 0.7, 1.0, shape, k < 3, "numba", wa, fbar,
                               threads=1)
            sb = explicit_step(grid, b, dt, g, 0.7, 1.0, shape, k < 3, "numba", wb, fbar,
                               threads=threads)
            assert (sa.kinetic_energy, sa.max_speed, sa.wave_speed, sa.point_speed) == \
                (sb.kinetic_energy, sb.max_speed, sb.wave_speed, sb.point_speed)
    finally:
        numba.set_num_threads(before)
    for f in FIELDS:
        assert np.array_equal(getattr(a, f), getattr(b, f)), f


@pytest.mark.parametrize("shape,fbar,threads", [("standard", False, 2), ("gimp", True, 2),
                                               ("standard", False, 4), ("gimp", True, 3)])
def test_two_threads_bitwise_equal_one_thread(meshes, shape, fbar, threads):
    """``threads`` 3 and 4: the stress pass's queues taken by that many workers on numba's
    two threads (the nodal velocities in a region of their own before it)."""
    scene = _softening_layer(meshes, shape)
    grid = make_grid(scene)
    a = seed_particles(scene, grid)
    _assert_steps_equal(scene, grid, a, shape, fbar, threads)
    assert (a.plastic_shear_strain > 0).sum() > 100


def test_stolen_stress_blocks_bitwise_equal_one_thread(meshes):
    """The threaded stress pass with two workers: a worker done with its own half takes
    blocks from the other half's queue once that half's nodal velocities are published
    (:func:`fem_rmpm.schemes.explicit.kernels.stress._stress_queue_call`).  Here the first half of the points
    is switched off, so the first worker has next to nothing to do and takes blocks of the
    second half on nearly every step; a stolen block computed with the wrong nodal
    velocities, or before they were complete, would show as a difference.  The points are
    put in reverse order first, so that the switched-off half is the top of the layer and the
    rest stands on the fixed base and yields (with two numba threads, the first worker took
    57 of the second half's 18 x 12 blocks, counted once with a probe in the pass)."""
    scene = _softening_layer(meshes)
    grid = make_grid(scene)
    a = seed_particles(scene, grid)
    permute_points(a, np.arange(a.n)[::-1].copy())
    a.active[:half_split(a.n)] = False
    _assert_steps_equal(scene, grid, a, "standard", False, 2)
    assert (a.plastic_shear_strain > 0).sum() > 1000
