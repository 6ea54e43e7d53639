"""The explicit step as the time loop runs it: one step, or many in one compiled call.

:func:`explicit_step` is one step of the method (:mod:`.reference` explains it) in either
implementation: ``kernel="numba"`` (default) the compiled loops of :mod:`.kernels` (only the
nodes the points touch take part), ``kernel="numpy"`` the readable
:func:`.reference.explicit_step_numpy`; the two agree to round-off
(``tests/test_kernels.py``).  :func:`advance` runs the ordinary steps of the time loop
back to back in one compiled call (:mod:`.kernels.advance`), bitwise the steps made one by
one.
"""
from __future__ import annotations

import numba
import numpy as np

from fem_rmpm.discretise.grid import Grid
from fem_rmpm.discretise.points import Particles
from fem_rmpm.schemes.common import RunRecord, SimulationError
from fem_rmpm.schemes.explicit import kernels as K
from fem_rmpm.schemes.explicit.cold_start import serial_driver_ready, threaded_driver_ready
from fem_rmpm.schemes.explicit.kernels import Workspace
from fem_rmpm.schemes.explicit.kernels.advance import (
    STALL,
    RunControl,
    pair_driver_fits,
    record_limit,
    step_drivers,
)
from fem_rmpm.schemes.explicit.reference import StepStats, cfl_speeds, explicit_step_numpy

__all__ = ["KERNELS", "DEFAULT_KERNEL", "explicit_step", "run_control", "advance",
           "record_friction"]

KERNELS = ("numba", "numpy")
DEFAULT_KERNEL = "numba"


def explicit_step(grid: Grid, pts: Particles, dt: float, gravity: np.ndarray,
                  damping: float, flip: float = 1.0, shape: str = "standard",
                  geostatic: bool = False, kernel: str | None = None,
                  work: Workspace | None = None, fbar: bool = False,
                  threads: int = 1, water=None) -> StepStats:
    """Advance the active points by one explicit MUSL step of ``dt`` seconds (in place).

    ``gravity`` (2,) m/s2; ``damping``: local damping ratio (-); ``flip``: FLIP fraction
    (-); ``shape``: ``"standard"`` (Q4) or ``"gimp"`` (uGIMP).  ``geostatic``: points stay
    where they are and strains are small (the in-situ gravity phase); the displacement is
    accumulated in ``pts.u_geostatic``.  ``kernel``: ``"numba"`` (default, compiled) or
    ``"numpy"`` (reference); ``work``: nodal arrays reused between steps (numba; made here
    if not given).  ``fbar``: the F-bar locking remedy (:mod:`fem_rmpm.schemes.locking`).
    ``threads`` (numba): 2 or more runs the two halves of the points on two threads (the
    stress update on up to ``threads``); the result is bitwise the single-thread one.
    ``water``: the pore water (:class:`fem_rmpm.schemes.pore_pressure.WaterTable`; numba:
    that of ``work`` when given).
    ``pts.F`` is not updated (the step needs det(dF) only; the time loop sets it NaN).
    """
    kernel = kernel or DEFAULT_KERNEL
    if kernel == "numpy":
        return explicit_step_numpy(grid, pts, dt, gravity, damping, flip, shape, geostatic,
                                   fbar, water)
    if kernel != "numba":
        raise ValueError(f"kernel {kernel!r} not allowed; allowed: {' | '.join(KERNELS)}")
    w = work if work is not None else Workspace.for_grid(grid, pts.n, water)
    (P, M), N, S, call = w.bind(grid, pts, shape == "gimp"), w.nodes, w.scratch, w.call
    o = K.StepOptions(float(dt), float(gravity[0]), float(gravity[1]), float(damping),
                      float(flip), bool(geostatic), shape == "gimp", bool(fbar), int(threads),
                      w.model, w.block)
    # each stage per half of the points, the halves on two threads (kernels.transfer)
    if threads > 1:     # (the threaded loops take the nodes' half apart: kernels.arrays.top_of)
        T = K.top_of(N)
        # 1. map to nodes: mass, momentum and force (locate + shape + scatter, one pass)
        call(K.map_to_nodes_parallel, o.gimp, P, M, T, N.half, S, o)
        # 2. solve on the mesh, 3a. map back: move the points, (MUSL) re-map momentum
        ke, vmax = call(K.solve_and_move_parallel, o.gimp, P, M, T, N.half, S, o)
    else:
        call(K.map_to_nodes, o.gimp, P, M, N, S, o)
        ke, vmax = call(K.solve_and_move, o.gimp, P, M, N, S, o)
    # 3b, 3c. nodal velocities from the re-mapped momenta, then the stress update
    K.update_stress(P, M, N, S, o, call)
    # 4. reset: the next step's map clears the nodes this one touched
    out = S.out
    return StepStats(ke, vmax, float(out[0]), float(out[1]), int(out[2]), int(out[3]))


def record_friction(grid: Grid, rec: RunRecord, step: int, t: float | None) -> None:
    """Frictional bedrock (:mod:`fem_rmpm.discretise.contact`): its dissipation set to zero
    before ``step`` 0, and recorded as (``t``, kJ/m so far) in ``rec.friction`` when ``t``
    is given (after every step from Python, at every return of the step driver)."""
    contact = grid.contact
    if contact is None:
        return
    if step == 0:
        contact.work[:] = 0.0
    if t is not None:
        rec.friction.append((t, float(contact.work[0] + contact.work[1])))


def run_control(sv, h_min: float, g_full: np.ndarray, next_output: float,
                sort_step: float, n_points: int) -> RunControl:
    """The :class:`~.kernels.advance.RunControl` of ``[solver]`` ``sv`` for ``n_points``
    points: smallest cell ``h_min`` (m), full gravity ``g_full`` (m/s2), the next output
    time (s) and the step of the next sort (all floats)."""
    return RunControl(float(sv.cfl), float(h_min), float(sv.t_end), float(sv.gravity_ramp_time),
                      float(sv.damping), float(sv.damping_time), float(g_full[0]),
                      float(g_full[1]), float(sv.geostatic_time), float(sv.rest_velocity),
                      float(sv.rest_energy_ratio), float(next_output), float(sort_step),
                      record_limit(n_points))


def advance(grid: Grid, pts: Particles, work: Workspace, sv, geostatic: bool, threads: int,
            ctl: RunControl, clock0: tuple, rec: RunRecord,
            stats: StepStats | None) -> tuple[StepStats, float, float, int, float]:
    """Ordinary steps of the time loop in one compiled call (:mod:`.kernels.advance`), from
    ``clock0`` = (t, step, peak kinetic energy) and the previous step's maxima in the
    scratch (``stats`` None or without them, at the first step and after a guard: those of
    the points, :func:`.reference.cfl_speeds`, so :func:`.reference.stable_time_step`'s
    dt), to the first step the loop must see; ``rec.dt_min`` / ``dt_max`` and
    ``rec.energy`` updated.  Returns that step's :class:`StepStats`, its dt, and the new t,
    step and peak.  (The first step runs through the driver too, so a run with local soils
    needs no other compiled kernel.)"""
    (P, M), N, S, call = (work.bind(grid, pts, sv.shape == "gimp"), work.nodes, work.scratch,
                          work.call)
    record_friction(grid, rec, clock0[1], None)          # (from zero at the first step)
    if stats is None or stats.wave_speed is None:
        S.out[:2] = cfl_speeds(pts)
    clock, count = work.clock, work.count
    o = K.StepOptions(0.0, 0.0, 0.0, 0.0, float(sv.flip), bool(geostatic), sv.shape == "gimp",
                      bool(sv.fbar), int(threads), work.model, work.block)
    clock[:4] = clock0[0], clock0[2], rec.dt_min, rec.dt_max
    count[0], count[2] = clock0[1], 0
    key = (o.model, o.fbar, o.gimp, o.block)
    serial, parallel, pair = step_drivers(*key)
    serial_args = (P, M, N, S, o._replace(threads=1), ctl, clock, count, work.energy)
    if threads > 1:
        both = pair_driver_fits(threads, bool(sv.fbar)) and numba.get_num_threads() >= 2
        drv = pair if both else parallel
        args = (P, M, N, K.top_of(N), N.half, S, o, ctl, clock, count, work.energy)
        if threaded_driver_ready("pair" if both else "parallel", drv, args, key, serial,
                                 serial_args):
            call(drv, *args)
        else:                        # (compiled aside meanwhile; bitwise the same steps)
            call(serial, *serial_args)
        if count[1] == STALL:
            raise SimulationError(
                f"step {int(count[0]) + 1} (t = {float(clock[0]):.6g} s): one of the two "
                "threads of the step waited for the other for half a minute (numba's thread "
                "pool did not run both); set [solver] threads = 1")
    else:
        serial_driver_ready(serial, serial_args)
        call(serial, *serial_args)
    out = S.out
    rec.energy.extend(map(tuple, work.energy[:count[2]].tolist()))   # the steps run inside
    rec.dt_min, rec.dt_max = float(clock[2]), float(clock[3])
    record_friction(grid, rec, -1, float(clock[0]))
    stats = StepStats(float(clock[4]), float(clock[5]), float(out[0]), float(out[1]),
                      int(out[2]), int(out[3]))
    return stats, float(clock[6]), float(clock[0]), int(count[0]), float(clock[1])
