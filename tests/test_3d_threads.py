"""The three-dimensional explicit step on two threads (:func:`fem_rmpm.schemes.explicit3d.
step.step_3d_threaded`) against one (:func:`~fem_rmpm.schemes.explicit3d.step.step_3d`):
the two halves of the points scatter into nodal rows of their own, added in the same order
whatever the thread count, so a run must be bitwise the same.  The case: the extruded
reference slope (von Mises softening, 36 448 points) for its first 0.4 s, where the gravity
ramp sets every point moving and the step runs its finite-strain branch."""
from __future__ import annotations

from pathlib import Path

import numba
import numpy as np
import pytest

from fem_rmpm import api
from fem_rmpm.schemes.explicit3d.loop import run_explicit_3d

MESHES = Path(__file__).parents[1] / "meshes"


def _run(threads: int, t_end: float = 0.4):
    scene = api.load_scene(MESHES / "slope_extruded_3d.toml")
    scene = api.with_value(api.with_value(scene, "solver.t_end", t_end), "solver.threads",
                           threads)
    grid, pts = api.prepare(scene)
    rec = run_explicit_3d(scene, grid, pts)
    return rec, pts


@pytest.mark.skipif(numba.config.NUMBA_NUM_THREADS < 2, reason="numba has one thread")
def test_two_threads_give_the_one_thread_run_bitwise():
    """Positions, velocities, stress, log strain, volumes and the plastic state after
    the same steps are identical on one and two threads, and each run reports the
    threads it used."""
    rec1, p1 = _run(1)
    before = numba.get_num_threads()        # (a campaign test may have set one thread)
    numba.set_num_threads(2)
    try:
        rec2, p2 = _run(2)
    finally:
        numba.set_num_threads(before)
    assert rec1.solver["threads"] == 1 and rec2.solver["threads"] == 2
    assert rec1.steps == rec2.steps > 10
    for name in ("x", "velocity", "stress", "log_strain", "volume", "state", "u_geostatic"):
        a, b = getattr(p1, name), getattr(p2, name)
        assert np.array_equal(a, b), name
    assert rec1.energy == rec2.energy
