"""The explicit scheme's time loop: CFL step, gravity ramp, damping, guards, output, rest.

Each step is :func:`fem_rmpm.schemes.explicit.step.explicit_step` (the method's three
stages, read in numpy in :mod:`fem_rmpm.schemes.explicit.reference`); the loop around it
chooses the step size (CFL, :func:`.reference.stable_time_step`), ramps gravity on, damps
the motion while ``t < damping_time``, checks the points (:func:`_guards`, a point moving
more than half a cell: :func:`_check_jump`), calls the output, sorts the points by cell
(:mod:`fem_rmpm.discretise.point_order`) and stops at rest or at ``t_end``.  With the
compiled kernels and local soils the ordinary steps between two the loop must see run in
one compiled call (:func:`.step.advance`), bitwise the same as stepping from Python
(:func:`_python_step`, also the path of the numpy kernel and of non-local soils).

Volumetric locking (``[solver] fbar = true``, :mod:`fem_rmpm.schemes.locking`): F-bar with
cell averaging.  The stable step (CFL) is mapped in :mod:`.stability` and
``validation/stability_map.py``; threads are chosen in :mod:`.threads`.
"""
from __future__ import annotations

import contextlib
import functools
import gc
import time

import numpy as np

from fem_rmpm.discretise.grid import Grid
from fem_rmpm.discretise.point_order import SORT_EVERY, PointOrder, plane_point_order
from fem_rmpm.discretise.points import Particles
from fem_rmpm.scene import Scene
from fem_rmpm.schemes.common import RunRecord, SimulationError, at_rest, check_points
from fem_rmpm.schemes.explicit.cold_start import stop_helpers
from fem_rmpm.schemes.explicit.kernels import Workspace
from fem_rmpm.schemes.explicit.kernels.advance import RECORD_EVERY
from fem_rmpm.schemes.explicit.reference import StepStats, stable_time_step
from fem_rmpm.schemes.explicit.step import (
    DEFAULT_KERNEL,
    KERNELS,
    advance,
    explicit_step,
    record_friction,
    run_control,
)
from fem_rmpm.schemes.explicit.threads import first_step_done, run_threads
from fem_rmpm.schemes.pore_pressure import water_table
from fem_rmpm.schemes.regularisation import average_softening, has_nonlocal

__all__ = ["run_explicit", "explicit_step", "stable_time_step", "Workspace", "StepStats",
           "KERNELS", "DEFAULT_KERNEL"]


def _without_gc(run):
    """``run`` with Python's automatic garbage collection paused, and restored as it was
    (on, or off if the caller had turned it off) however ``run`` ends.  The time loop makes
    hardly any reference cycles, but numba loading the step driver from its on-disk cache
    in the first step makes enough objects to trigger a full collection, which walks every
    object of the imported libraries (tens of milliseconds).  Left for the caller's next
    collection."""
    @functools.wraps(run)
    def paused(*args, **kwargs):
        was_enabled = gc.isenabled()
        gc.disable()
        try:
            return run(*args, **kwargs)
        finally:
            if was_enabled:
                gc.enable()
    return paused


@contextlib.contextmanager
def _stopping(order: PointOrder):
    """Around the time loop: the points back in their seeded order however it ends; an
    interrupt or error also stops the compile helpers at once (no wait for a compile at
    exit, :func:`.cold_start.stop_helpers`)."""
    try:
        yield
    except BaseException:
        stop_helpers()
        raise
    finally:
        order.restore()


@_without_gc
def run_explicit(scene: Scene, grid: Grid, pts: Particles, on_output=None,
                 progress=None, kernel: str | None = None,
                 sort_every: int = SORT_EVERY) -> RunRecord:
    """Time loop of the explicit scheme.

    Phases: with ``gravity_phase = "geostatic"`` gravity is first ramped onto the fixed
    in-situ geometry (small strain, damped) until at rest or for at most ``geostatic_time``;
    then (or from t = 0 with ``"dynamic"``) the large deformation phase runs, damped until
    ``damping_time``, until ``t_end`` or rest (:func:`fem_rmpm.schemes.common.at_rest`, once gravity
    is fully on).  ``on_output(t, pts)`` is called at t = 0, every ``output_interval`` and at the
    end; ``progress(t, step)`` at the driver's returns (from Python: every 20th step).  ``kernel``:
    ``"numba"`` | ``"numpy"`` (default: ``[solver] kernel``, else :data:`DEFAULT_KERNEL`).  With
    numba the CFL step and the guards use the maxima the stress kernel returns (no pass over the
    points in Python), and the points are sorted by host cell after every output and every
    ``sort_every`` steps (0: never; :mod:`fem_rmpm.discretise.point_order`), in their original
    order whenever ``on_output``, a guard or the caller sees them; the ordinary steps between
    two steps the loop must see run in one compiled call (:func:`.step.advance`, bitwise the
    same).  ``threads``: :func:`.threads.run_threads`.  ``pts.F``: NaN (not tracked)."""
    sv, water = scene.solver, water_table(scene)      # water: the pore water (None: dry)
    kernel = kernel or getattr(sv, "kernel", None) or DEFAULT_KERNEL
    if kernel not in KERNELS:
        raise ValueError(f"kernel {kernel!r} not allowed; allowed: {' | '.join(KERNELS)}")
    work = Workspace.for_grid(grid, pts.n, water) if kernel == "numba" else None
    threads = run_threads(int(getattr(sv, "threads", 0)), kernel)
    pts.F[...] = np.nan              # the step needs det(dF) only (volume), not the total F
    h_min, g_full = float(np.min(grid.cell)), np.array(scene.gravity_vector)
    rec = RunRecord(scheme="explicit", solver={"threads": threads})
    t, step, ke_peak, next_out, stats = 0.0, 0, 0.0, sv.output_interval, None
    geostatic = sv.gravity_phase == "geostatic"
    wall0 = time.perf_counter()
    if on_output:
        on_output(t, pts)
    order = plane_point_order(grid, pts, sort_every if kernel == "numba" else 0)
    driven = kernel == "numba" and not has_nonlocal(pts.soil)    # non-local: Python steps
    with _stopping(order):
        while t < sv.t_end - 1e-12:
            if driven:
                ctl = run_control(sv, h_min, g_full, next_out if on_output else np.inf,
                                  order.due_step(), pts.n)
                stats, dt, t, step, ke_peak = advance(grid, pts, work, sv, geostatic, threads,
                                                      ctl, (t, step, ke_peak), rec, stats)
            else:
                stats, dt, t, step, ke_peak = _python_step(
                    grid, pts, sv, kernel, work, threads, geostatic, g_full,
                    _cfl_step(stats, pts, grid, sv.cfl, h_min), (t, step, ke_peak), rec, water)
            if step == 1:                    # the t = 0 output and the kernels' first calls
                first_step_done(rec, time.perf_counter() - wall0, threads)
            if (stats.wave_speed is None or stats.n_bad or stats.n_outside) and \
                    not _guards(grid, pts, stats, order, step, t, sv.edge_policy, rec):
                rec.stop_reason = "all points left the grid"
                break
            _check_jump(stats.max_speed * dt, h_min, step, t, sv.cfl)
            ke_peak = max(ke_peak, stats.kinetic_energy)
            if step % RECORD_EVERY == 0:
                rec.energy.append((t, stats.kinetic_energy))
            if progress and (driven or step % RECORD_EVERY == 0):
                progress(t, step)
            if on_output and t >= next_out - 1e-12:
                order.restore()
                on_output(t, pts)
                next_out += sv.output_interval
            order.sort_if_due(step)
            rest = at_rest(t, sv.gravity_ramp_time, stats.max_speed, stats.kinetic_energy, ke_peak,
                           sv.rest_velocity, sv.rest_energy_ratio)
            if geostatic and (rest or t >= sv.geostatic_time):
                geostatic = False
                rec.solver["geostatic_end_time"] = t
                rec.solver["geostatic_at_rest"] = bool(rest)
                continue
            if rest:
                rec.stop_reason = "at rest"
                break
        else:
            rec.stop_reason = "t_end reached"
    rec.steps, rec.time, rec.wall_time = step, t, time.perf_counter() - wall0
    if on_output and next_out - sv.output_interval < t - 1e-12:
        on_output(t, pts)
    return rec


def _guards(grid: Grid, pts: Particles, stats: StepStats, order: PointOrder, step: int,
            t: float, policy: str, rec: RunRecord) -> bool:
    """The run's guards after a step with a finding (or from the numpy path):
    :func:`fem_rmpm.schemes.common.check_points` on the points in their original order (the
    guards name points by their original index); frozen points make the next CFL step come
    from :func:`.reference.stable_time_step`.  False when no active point is left."""
    order.restore()
    check_points(grid, pts, step, t, policy, rec)
    if stats.n_outside:
        stats.wave_speed = None
    return bool(pts.active.any())


def _python_step(grid: Grid, pts: Particles, sv, kernel: str, work: Workspace | None,
                 threads: int, geostatic: bool, g_full: np.ndarray, cfl_dt: float,
                 clock0: tuple, rec: RunRecord,
                 water=None) -> tuple[StepStats, float, float, int, float]:
    """One step of the time loop from Python, from ``clock0`` = (t, step, peak kinetic
    energy): the CFL step ``cfl_dt`` (s) cut at ``t_end``, the gravity ramp and the damping
    of ``[solver]`` ``sv``, then the non-local averaging; ``rec.dt_min`` / ``dt_max``
    updated.  Returns as :func:`.step.advance` (the peak is left to the loop)."""
    t, step, ke_peak = clock0
    dt = min(cfl_dt, sv.t_end - t)
    ramp = 1.0 if sv.gravity_ramp_time <= 0 else min(1.0, (t + dt) / sv.gravity_ramp_time)
    damping = sv.damping if (geostatic or t < sv.damping_time) else 0.0
    record_friction(grid, rec, step, None)      # (from zero at the first step)
    stats = explicit_step(grid, pts, dt, ramp * g_full, damping, sv.flip, sv.shape,
                          geostatic, kernel, work, bool(sv.fbar), threads, water)
    average_softening(grid, pts)     # non-local softening (no-op for local soils)
    rec.dt_min, rec.dt_max = min(rec.dt_min, dt), max(rec.dt_max, dt)
    record_friction(grid, rec, -1, t + dt)
    return stats, dt, t + dt, step + 1, ke_peak


def _cfl_step(stats: StepStats | None, pts: Particles, grid: Grid, cfl: float,
              h_min: float) -> float:
    """CFL step (s): from the maxima the numba step returned, else :func:`stable_time_step`."""
    if stats is not None and stats.wave_speed is not None:
        return cfl * h_min / (stats.wave_speed + stats.point_speed)
    return stable_time_step(pts, grid.cell, cfl)


def _check_jump(jump: float, h_min: float, step: int, t: float, cfl: float) -> None:
    """Stop when a point moved more than half a cell in one step (``jump``, m)."""
    if jump > 0.5 * h_min:
        raise SimulationError(
            f"step {step} (t = {t:.4g} s): a material point moved {jump:.3g} m "
            f"in one step (> half a cell); the explicit scheme is unstable — reduce [solver] "
            f"cfl (now {cfl:g}, default 0.5, allowed (0, 3]; the estimate dt = h / (c_p + "
            "|v|) is cfl 1, the measured limits are 1.08 to 1.65)")
