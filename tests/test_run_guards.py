"""The run guards' exact thresholds and messages in :mod:`fem_rmpm.schemes.common` and
:mod:`fem_rmpm.schemes.explicit.loop` (exact, so that mutation testing finds them checked).
The expected values follow from the documented rules: at rest when the kinetic energy is at
most ``rest_energy_ratio`` x its peak (a peak other than 1 tells a product from a
quotient); a point moving more than half a cell in a step stops the run; a non-finite point
or a point outside the grid is named with its step, time, position and the option to
change."""
from __future__ import annotations

import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

import fem_rmpm.schemes.explicit.loop as ex
import fem_rmpm.schemes.explicit.threads as threads_mod
from fem_rmpm.discretise.grid import make_grid
from fem_rmpm.discretise.points import seed_particles
from fem_rmpm.scene import load_scene, with_values
from fem_rmpm.schemes.common import RunRecord, SimulationError, at_rest, check_points
from fem_rmpm.schemes.explicit.loop import _check_jump, run_explicit
from tests.test_measures_details import _points


def test_at_rest_energy_ratio_scales_with_the_peak():
    """Peak 100 kJ/m, ratio 1e-4: rest below 1e-2 kJ/m (5e-3 rests, 2e-2 does not)."""
    assert at_rest(2.0, 0.5, 1e-6, 5e-3, 100.0, 1e-5, 1e-4)
    assert not at_rest(2.0, 0.5, 1e-6, 2e-2, 100.0, 1e-5, 1e-4)


def test_half_cell_motion_guard_threshold_and_message():
    """h_min 0.25 m: a jump of 0.125 m passes (not > half a cell), 0.13 m and 0.3 m stop
    with the step, the time, the jump and the cfl to reduce."""
    _check_jump(0.125, 0.25, 7, 1.5, 0.5)
    for jump in (0.13, 0.3):
        with pytest.raises(SimulationError) as e:
            _check_jump(jump, 0.25, 7, 1.5, 0.8)
        msg = str(e.value)
        assert msg.startswith("step 7 (t = 1.5 s): a material point moved ")
        assert f"moved {jump:.3g} m" in msg and "reduce [solver] cfl (now 0.8," in msg


def _grid():
    return SimpleNamespace(origin=np.array([0.0, 0.0]), upper=np.array([10.0, 5.0]))


def test_non_finite_point_message_names_the_point_and_the_fix():
    """The first active non-finite point (index 2, started at (3, 1)) is named, with the
    step, the time and the cure, word for word."""
    pts = _points([[1.0, 1.0], [2.0, 1.0], [3.0, 1.0]])
    pts.velocity[2, 1] = np.nan
    with pytest.raises(SimulationError) as e:
        check_points(_grid(), pts, 12, 0.25, "freeze", RunRecord("explicit"))
    assert str(e.value) == (
        "step 12 (t = 0.25 s): non-finite state at material point 2 (started at "
        "x = 3.000, y = 1.000 m); the explicit scheme went unstable — reduce [solver] cfl "
        "(default 0.5) or check the material constants")


def test_points_leaving_the_grid_stop_or_freeze():
    """Point 1 at (10.5, 2.25) is beyond x = 10: ``stop`` names it (x and y of its current
    position); ``freeze`` makes it inactive, still, and listed; a point on the edge stays."""
    x0 = [[1.0, 1.0], [9.0, 2.0], [5.0, 4.0]]
    pts = _points(x0, [[1.0, 1.0], [10.5, 2.25], [5.0, 5.0]])
    pts.velocity[:] = 1.0
    with pytest.raises(SimulationError) as e:
        check_points(_grid(), pts, 3, 2.0, "stop", RunRecord("explicit"))
    assert str(e.value) == (
        "step 3 (t = 2 s): 1 material point(s) left the grid, first point 1 at x = 10.500, "
        "y = 2.250 m; enlarge [grid] size or set [solver] edge_policy = \"freeze\"")
    rec = RunRecord("explicit")
    check_points(_grid(), pts, 3, 2.0, "freeze", rec)
    assert pts.active.tolist() == [True, False, True] and pts.active.dtype == bool
    assert rec.frozen_points == [1]
    assert np.array_equal(pts.velocity, [[1.0, 1.0], [0.0, 0.0], [1.0, 1.0]])


def test_check_points_nan_position_and_lower_edge():
    """A NaN position at point 2 names point 2; a point exactly on the lower-left corner
    of the grid (x = 0, y = 0) is inside, not frozen."""
    grid = _grid()
    pts = _points([[1.0, 1.0], [2.0, 1.0], [3.0, 1.0]])
    pts.x[2, 0] = np.nan
    with pytest.raises(SimulationError, match="non-finite state at material point 2 "):
        check_points(grid, pts, 4, 0.1, "freeze", RunRecord("explicit"))
    pts = _points([[0.0, 0.0], [2.0, 1.0]])
    rec = RunRecord("explicit")
    check_points(grid, pts, 4, 0.1, "stop", rec)
    assert pts.active.all() and rec.frozen_points == []


@pytest.mark.parametrize("pool, load, expected", [
    (4, 0.4, 4),      # 4 - 0.4 + 0.5 = 4.1 -> 4
    (4, 1.4, 3),      # 3.1 -> 3
    (4, 1.6, 2),      # 2.9 -> 2 (rounded, not ceiled)
    (4, 9.0, 1),      # busier than the pool: at least 1
    (4, None, 4),     # no load average (OSError): the whole pool
    (1, 0.0, 1),      # a one-thread pool
    (2, 0.0, 2),      # the 2-core machine, idle: both threads
])
def test_auto_threads_is_the_pool_less_the_busy_cores(monkeypatch, pool, load, expected):
    """``[solver] threads = 0``: numba's pool size (read from the config while the pool
    has not started, from numba once it has) less the rounded 1-minute load average where
    the runnable count of ``/proc/loadavg`` is not available."""
    monkeypatch.setattr(threads_mod, "_runnable_others", lambda *a, **k: None)
    def loadavg():
        if load is None:
            raise OSError("no load average")
        return (load, 99.0, 99.0)
    monkeypatch.setattr(threads_mod.os, "getloadavg", loadavg)
    monkeypatch.setattr(threads_mod.numba_parallel, "_is_initialized", False, raising=False)
    monkeypatch.setattr(threads_mod.numba.config, "NUMBA_NUM_THREADS", pool)
    monkeypatch.setattr(threads_mod.numba, "get_num_threads", lambda: 99)
    assert threads_mod.auto_threads() == expected
    monkeypatch.setattr(threads_mod.numba_parallel, "_is_initialized", True, raising=False)
    monkeypatch.setattr(threads_mod.numba, "get_num_threads", lambda: pool)
    monkeypatch.setattr(threads_mod.numba.config, "NUMBA_NUM_THREADS", 99)
    assert threads_mod.auto_threads() == expected


@pytest.mark.parametrize("pool, others, expected", [
    (2, 0, 2),        # idle now, whatever the 1-minute average still says
    (2, 1, 1),        # one other process running now
    (4, 1, 3),
    (4, 7, 1),        # at least 1
])
def test_auto_threads_counts_the_processes_running_now(monkeypatch, pool, others, expected):
    """With ``/proc/loadavg``'s runnable count, auto takes the pool less the other threads
    running now, not the 1-minute load average (here 9.0: it would give 1 thread)."""
    monkeypatch.setattr(threads_mod, "_runnable_others", lambda *a, **k: others)
    monkeypatch.setattr(threads_mod.os, "getloadavg", lambda: (9.0, 9.0, 9.0))
    monkeypatch.setattr(threads_mod.numba_parallel, "_is_initialized", True, raising=False)
    monkeypatch.setattr(threads_mod.numba, "get_num_threads", lambda: pool)
    assert threads_mod.auto_threads() == expected


def test_run_record_threads_and_times():
    """A short column run (t_end 0.01 s) with ``threads = 1``: the record holds the thread
    count and a wall time between 0 and the time the call took."""
    scene = load_scene(Path(__file__).resolve().parents[1] / "meshes" / "column.toml")
    sc = with_values(scene, {"solver.t_end": 0.01, "solver.threads": 1})
    grid = make_grid(sc)
    pts = seed_particles(sc, grid)
    t0 = time.perf_counter()
    rec = run_explicit(sc, grid, pts)
    took = time.perf_counter() - t0
    assert rec.solver["threads"] == 1
    assert 0.0 < rec.wall_time <= took


@pytest.mark.parametrize("threads, cores, others, warned", [
    (2, 2, 1, True),      # the 2-core machine with one other busy process
    (2, 2, 0, False),     # idle: no warning
    (4, 2, 0, True),      # more threads than cores
    (2, 8, 5, False),     # 3 free cores
    (3, 8, 6, True),
    (1, 2, 5, False),     # one thread never waits for another
    (2, 2, None, True),   # no /proc/loadavg: the rounded load average (1.6 -> 2) instead
])
def test_explicit_threads_on_busy_cores_warn(monkeypatch, threads, cores, others, warned):
    """``[solver] threads >= 2`` where fewer cores are free: one line naming the thread
    count, the busy processes, the cores, the load average and what to set instead."""
    monkeypatch.setattr(threads_mod, "_cores", lambda: cores)
    monkeypatch.setattr(threads_mod, "_runnable_others", lambda: others)
    monkeypatch.setattr(threads_mod.os, "getloadavg", lambda: (1.6, 1.0, 1.0))
    text = threads_mod.busy_threads_warning(threads)
    assert (text is not None) == warned
    if warned:
        busy = others if others is not None else 2
        free = max(cores - busy, 0)
        assert "\n" not in text and text.startswith("fem-rmpm: warning: ")
        assert f"threads = {threads}," in text and f"{busy} other process(es)" in text
        assert f"{cores} core(s)" in text and "load average 1.60" in text
        assert f"set [solver] threads = {max(free, 1)} or 0 (auto" in text


def test_runnable_others_reads_proc_loadavg(monkeypatch):
    """The 4th field of /proc/loadavg ("running/total") less this process, least sample."""
    import builtins
    import io
    lines = iter(["1.00 0.50 0.20 3/120 999", "1.00 0.50 0.20 2/120 999",
                  "1.00 0.50 0.20 4/120 999"])
    real_open = builtins.open
    monkeypatch.setattr(builtins, "open", lambda f, *a, **k: io.StringIO(next(lines))
                        if f == "/proc/loadavg" else real_open(f, *a, **k))
    assert threads_mod._runnable_others(pause=0.0) == 1
    monkeypatch.setattr(builtins, "open", lambda *a, **k: (_ for _ in ()).throw(OSError()))
    assert threads_mod._runnable_others(pause=0.0) is None


class FirstStep(Exception):
    """Raised in place of a run's first step (the busy-cores tests stop there)."""


def _busy_two_cores(monkeypatch, others: int) -> None:
    """A 2-core machine with ``others`` busy processes; the run stops at its first step
    (:class:`FirstStep`), and no thread count has been warned about yet."""
    def first_step(*a, **k):
        raise FirstStep

    monkeypatch.setattr(ex, "explicit_step", first_step)
    monkeypatch.setattr(ex, "advance", first_step)
    monkeypatch.setattr(threads_mod, "_runnable_others", lambda: others)
    monkeypatch.setattr(threads_mod, "_cores", lambda: 2)
    monkeypatch.setattr(threads_mod, "_THREADS_WARNED", set())


def test_run_warns_once_at_the_start_on_busy_cores(monkeypatch, capsys):
    """run_explicit with ``threads = 2`` on busy cores prints the warning before the first
    step (not a refusal), once per process; ``threads = 0`` (auto) and 1 print nothing."""
    scene = load_scene(Path(__file__).resolve().parents[1] / "meshes" / "column.toml")
    grid = make_grid(scene)
    _busy_two_cores(monkeypatch, others=1)
    for threads, lines in ((0, 0), (1, 0), (2, 1), (2, 0)):
        sc = with_values(scene, {"solver.t_end": 0.01, "solver.threads": threads})
        with pytest.raises(FirstStep):
            run_explicit(sc, grid, seed_particles(sc, grid))
        err = capsys.readouterr().err
        assert len(err.splitlines()) == lines, (threads, err)
        assert lines == 0 or "[solver] threads = 2," in err


def test_threads_resolved_from_auto_by_run_do_not_warn(monkeypatch, capsys):
    """``fem_rmpm.api.run`` replaces ``threads = 0`` by :func:`auto_threads` once, before
    the run; if the cores turn busy in between (another process starts), the run does not
    warn as if the user had set that count (such a warning would say "threads = 2" for a
    scene without a ``threads`` key, and add a line to a one-line stderr).  An explicit
    ``threads = 2`` on the same busy cores still warns, once."""
    import fem_rmpm.api as api
    scene = load_scene(Path(__file__).resolve().parents[1] / "meshes" / "column.toml")
    monkeypatch.setattr(api, "auto_threads", lambda: 2)        # two idle cores when resolved
    _busy_two_cores(monkeypatch, others=2)                     # both busy at the run's start
    for threads, lines in ((0, 0), (2, 1)):
        sc = with_values(scene, {"solver.t_end": 0.01, "solver.threads": threads})
        with pytest.raises(FirstStep):
            api.run(sc)
        err = capsys.readouterr().err
        assert len(err.splitlines()) == lines, (threads, err)
    assert not threads_mod._FROM_AUTO[0]
