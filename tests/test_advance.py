"""The compiled step driver (:mod:`fem_rmpm.schemes.explicit.kernels.advance`) runs the
explicit time loop bitwise as the Python loop steps it.

The driver runs the ordinary steps of :func:`fem_rmpm.schemes.explicit.loop.run_explicit`
back to back in one compiled call and returns at the first step the loop must see (records, outputs,
sorts, guards, rest, the end of the geostatic phase, the end).  The reference is the same
loop with the driver switched off (every step from Python):
every point field, the step count, the smallest and largest dt, the energy record, the
output times and the stop reason must be equal bit for bit (asserted: 0 difference), on
one and two threads, Q4 and uGIMP with F-bar, through a geostatic phase, a failure with
softening, and a run that stops at rest.
"""
from __future__ import annotations

import numba
import numpy as np
import pytest

from fem_rmpm.discretise.grid import make_grid
from fem_rmpm.discretise.points import seed_particles
from fem_rmpm.scene import load_scene, with_values
from fem_rmpm.schemes.explicit import loop as explicit
from fem_rmpm.schemes.explicit.loop import run_explicit

FIELDS = ("x", "velocity", "stress", "log_strain", "state", "volume", "u_geostatic", "active")

FAILING = {"grid.cell": [1.0, 1.0], "soil.model": "von_mises_softening",
           "soil.cohesion_peak": 3.0, "soil.cohesion_residual": 1.0,
           "soil.softening_strain": 0.05, "solver.gravity_phase": "geostatic",
           "solver.geostatic_time": 0.4, "solver.t_end": 2.5, "solver.output_interval": 0.3}
# strong enough to stay elastic (the same model as FAILING: no other kernel to compile)
RESTING = {"grid.cell": [1.0, 1.0], "soil.model": "von_mises_softening",
           "soil.cohesion_peak": 200.0, "soil.cohesion_residual": 100.0,
           "soil.softening_strain": 0.5, "solver.gravity_phase": "dynamic",
           "solver.damping_time": 100.0, "solver.t_end": 60.0, "solver.output_interval": 5.0}


def _run(meshes, values, threads, driven, monkeypatch):
    scene = with_values(load_scene(meshes / "slope_elastic.toml"),
                        dict(values, **{"solver.threads": threads}))
    grid = make_grid(scene)
    pts = seed_particles(scene, grid)
    outputs = []
    calls = {"step": 0}
    step = explicit.explicit_step

    def counted(*a, **k):
        calls["step"] += 1
        return step(*a, **k)
    with monkeypatch.context() as m:
        m.setattr(explicit, "explicit_step", counted)
        if not driven:                   # every step from Python (the driver off)
            m.setattr(explicit, "has_nonlocal", lambda soil: True)
        rec = run_explicit(scene, grid, pts, on_output=lambda t, p: outputs.append(t),
                           sort_every=7)
    return pts, rec, outputs, calls["step"]


@pytest.mark.parametrize("values,threads,extra", [
    (FAILING, 1, {}), (FAILING, 2, {}), (FAILING, 3, {}),
    (FAILING, 1, {"solver.shape": "gimp", "solver.fbar": True}),
    (FAILING, 2, {"solver.shape": "gimp", "solver.fbar": True}),
    (RESTING, 1, {}), (RESTING, 2, {})])
def test_driver_is_the_python_loop_bitwise(meshes, monkeypatch, values, threads, extra):
    """Two threads without F-bar: the one-region driver (``advance_pair``); with F-bar or
    three threads: the driver with a region per stage (``advance_parallel``)."""
    before = numba.get_num_threads()
    numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))
    try:
        a, ra, oa, steps_a = _run(meshes, dict(values, **extra), threads, True, monkeypatch)
        b, rb, ob, steps_b = _run(meshes, dict(values, **extra), threads, False, monkeypatch)
    finally:
        numba.set_num_threads(before)
    assert steps_b == rb.steps                     # the reference stepped every step itself
    assert steps_a == 0                            # the driver did all of them
    assert (ra.steps, ra.time, ra.dt_min, ra.dt_max, ra.stop_reason) == \
        (rb.steps, rb.time, rb.dt_min, rb.dt_max, rb.stop_reason)
    assert ra.energy == rb.energy and oa == ob
    for f in FIELDS:
        assert np.array_equal(getattr(a, f), getattr(b, f)), f
    if values is FAILING:
        assert (a.plastic_shear_strain > 0.05).sum() > 20        # it failed and softened
        assert ra.solver.get("geostatic_end_time") is not None
    else:
        assert ra.stop_reason == "at rest" and not (a.plastic_shear_strain > 0).any()


def test_nonlocal_soil_steps_from_python(meshes, monkeypatch):
    """Non-local softening needs a Python pass (:func:`~fem_rmpm.schemes.regularisation.average_softening`)
    after every step, so a run with a non-local soil takes every step from Python (the
    driver would skip the averaging)."""
    values = dict(FAILING, **{"soil.regularisation": "nonlocal", "soil.internal_length": 2.0,
                              "solver.t_end": 0.3})
    calls = []
    real = explicit.average_softening
    monkeypatch.setattr(explicit, "average_softening",
                        lambda grid, pts: calls.append(1) or real(grid, pts))
    pts, rec, _, steps = _run(meshes, values, 1, True, monkeypatch)
    assert steps == rec.steps == len(calls) > 10


def test_two_threads_on_a_pool_of_one_take_the_driver_that_never_waits(meshes, monkeypatch):
    """``threads = 2`` while numba's pool has one thread (e.g. a campaign worker's):
    ``advance_pair`` would wait at its first barrier for a thread that runs only after it,
    so the loop takes ``advance_parallel``, whose workers never wait; the run is bitwise
    the one-thread run.  (With the pair driver this test fails after a ~30 s stall.)"""
    before = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        a, ra, _, _ = _run(meshes, RESTING, 2, True, monkeypatch)
    finally:
        numba.set_num_threads(before)
    b, rb, _, _ = _run(meshes, RESTING, 1, True, monkeypatch)
    assert (ra.steps, ra.time, ra.stop_reason) == (rb.steps, rb.time, rb.stop_reason)
    for f in FIELDS:
        assert np.array_equal(getattr(a, f), getattr(b, f)), f


def test_a_stalled_two_thread_step_stops_the_run_with_what_to_change(meshes, monkeypatch):
    """A driver call that returns the event ``stall`` (a thread gave up waiting at a
    barrier) stops the run with its step and time and the setting that avoids it."""
    from fem_rmpm.schemes.common import SimulationError
    from fem_rmpm.schemes.explicit import cold_start
    from fem_rmpm.schemes.explicit.kernels.advance import STALL
    from fem_rmpm.schemes.explicit.kernels.arrays import Workspace

    if numba.config.NUMBA_NUM_THREADS < 2:
        pytest.skip("one core: the one-region driver needs a pool of two threads")
    call = Workspace.call

    def stalled(self, kernel, *args):
        if getattr(kernel, "__name__", "").startswith("advance_pair"):
            args[9][1] = STALL                   # count: the event of the call
            return None
        return call(self, kernel, *args)
    before = numba.get_num_threads()
    numba.set_num_threads(min(2, numba.config.NUMBA_NUM_THREADS))
    try:
        monkeypatch.setattr(Workspace, "call", stalled)
        monkeypatch.setattr(cold_start, "usable_cores", lambda: 1)   # (no serial first steps)
        with pytest.raises(SimulationError, match=r"^step 1 \(t = 0 s\): one of the two "
                           r"threads .* set \[solver\] threads = 1$"):
            _run(meshes, RESTING, 2, True, monkeypatch)
    finally:
        numba.set_num_threads(before)
