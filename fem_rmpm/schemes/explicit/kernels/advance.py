"""Many explicit steps in one compiled call: the time loop's ordinary steps without Python.

Between two steps the time loop of :func:`fem_rmpm.schemes.explicit.loop.run_explicit`
picks the CFL step, the gravity ramp and the damping, then checks guards, output times,
sorting and rest.  Done in Python, that bookkeeping (building the argument groups,
unboxing ~50 arrays for each kernel call) costs tens of microseconds per step, a few
per cent of a run.  :func:`step_drivers` gives compiled drivers that run steps back to
back with the same arithmetic, in the same order, and return to Python at the first
step that needs it (:data:`EVENTS`): a guard fired, an output or sort is due, the run is
at rest or at its end, the geostatic phase may end, or the energy record is full.  The
loop then runs its usual per-step block for that step, so a run is bitwise the one
stepped from Python (``tests/test_advance.py``).  The kinetic energy of every
:data:`RECORD_EVERY`-th step is recorded by the driver into a buffer the loop empties at
each return (``record_limit`` steps' records at most, the last one the loop's own:
:func:`record_limit`), so that a driver returns about once per output, not at every
record step.

Each step is the three stages of the method, as
:func:`fem_rmpm.schemes.explicit.step.explicit_step` calls them: map to nodes
(:func:`.transfer.map_to_nodes`), solve on the mesh and map back
(:func:`.transfer.solve_and_move`), then the stress pass (:mod:`.stress`).  The driver
arithmetic (step size, ramp, damping, the checks) is compiled without any fast-math
flag: every operation is rounded as Python rounds it.

**Two threads, one parallel region per call.**  The threaded driver ``advance_parallel``
opens a parallel region (``prange``) for each of the step's three stages; each region
costs a few microseconds (numba setting it up, the other thread woken, the join).  With
exactly two threads (no F-bar) :func:`step_drivers` also gives ``advance_pair``: one
region per call, in which each of the two threads runs :func:`pair_worker` over the
steps, its half of the points in each stage, with a spin barrier (:func:`.common.arrive`)
where the regions joined, and thread 0 alone books the step (:func:`_tick`).  The same
functions on the same halves in the same order: bitwise the run of either other driver
(``tests/test_advance.py``).  It needs the two threads to run at once (a barrier waits
for the other): the caller uses it only when numba's pool has two threads, and a thread
that gives up waiting (:func:`.common.arrive`, ~30 s) ends the call with the event
``stall`` instead of hanging.  A waiting thread spins, then yields its core, which
matters most where more threads want to run than there are cores.
"""
from __future__ import annotations

from collections import namedtuple

import numpy as np
from numba import njit, prange

from fem_rmpm.materials import registry
from fem_rmpm.runtime.compiled import variant
from fem_rmpm.schemes.explicit.kernels.arrays import RECORD_BUFFER, StepOptions
from fem_rmpm.schemes.explicit.kernels.common import QUEUE_BARRIER, arrive
from fem_rmpm.schemes.explicit.kernels.strain import fbar_gradient_pass, fbar_gradient_pass_parallel
from fem_rmpm.schemes.explicit.kernels.stress import (
    _combine,
    _reset_queues,
    nodal_in_pass,
    serial_stress_pass,
    stress_queue,
    workers,
)
from fem_rmpm.schemes.explicit.kernels.transfer import (
    _grid_stats,
    _map_half,
    _move_half,
    map_to_nodes,
    map_to_nodes_parallel,
    nodal_velocities,
    nodal_velocities_parallel,
    solve_and_move,
    solve_and_move_parallel,
)

__all__ = ["RunControl", "step_drivers", "record_limit", "RECORD_EVERY", "RECORD_BUFFER",
           "EVENTS", "STALL", "pair_worker", "pair_driver_fits"]

#: The step numbers at which the loop records the kinetic energy and reports progress.
RECORD_EVERY = 20

RunControl = namedtuple("RunControl", "cfl h_min t_end ramp_time damping damping_time g0 g1 "
                                      "geostatic_time rest_velocity rest_energy_ratio "
                                      "next_output sort_step record_limit")
RunControl.__doc__ = """The time loop's constants for one driver call: CFL number (-),
smallest cell size (m), end time (s), gravity ramp time (s), damping (-) applied while
t < damping_time (s), full gravity (m/s2), end of the geostatic phase (s), rest speed (m/s)
and kinetic-energy ratio (-), the next output time (s; inf: none), the step at which
the next sort is due (a large number: none) and the record steps per call
(:func:`record_limit`).  All floats."""

#: Point-steps between two returns for the record: ~1-2 s of one thread.
RECORD_POINT_STEPS = 2e7


def record_limit(n_points: int) -> float:
    """Record steps per driver call for ``n_points`` points: as many as fit in
    :data:`RECORD_POINT_STEPS` point-steps (so that the progress bar and Ctrl-C are seen
    every second or two), at least 1 (a return at every record step), at most
    :data:`RECORD_BUFFER`."""
    fit = RECORD_POINT_STEPS // (max(int(n_points), 1) * RECORD_EVERY)
    return float(max(1, min(RECORD_BUFFER, fit)))

#: Why a driver returned (``count[1]``; read by nobody, for debugging).
EVENTS = ("record", "guard", "jump", "output", "sort", "rest", "geostatic", "end", "stall")
STALL = EVENTS.index("stall")

# no fast-math flags: the driver's own arithmetic must round as the Python loop's does
driver = njit(cache=True, fastmath=False, nogil=True, error_model="numpy", _nrt=False)
driver_parallel = njit(cache=True, fastmath=False, nogil=True, error_model="numpy", _nrt=False,
                       parallel=True)
exact_inline = njit(inline="always", error_model="numpy")


@exact_inline
def _options(o, c, t, wave_speed, point_speed):
    """The next step's options, as the Python loop makes them (``loop._python_step``)."""
    dt = min(c.cfl * c.h_min / (wave_speed + point_speed), c.t_end - t)
    ramp = 1.0 if c.ramp_time <= 0 else min(1.0, (t + dt) / c.ramp_time)
    damping = c.damping if (o.geostatic or t < c.damping_time) else 0.0
    return StepOptions(dt, ramp * c.g0, ramp * c.g1, damping, o.flip, o.geostatic, o.gimp,
                       o.fbar, o.threads, o.model, o.block)


@exact_inline
def _event(c, o, S, count, t, step, dt, ke, ke_peak, vmax):
    """The first of :data:`EVENTS` (its index) the step just done raises, or -1 (the
    checks of the Python loop; ``ke_peak`` already holds this step's energy, as the loop's
    rest check sees it — the loop's own ``max`` at the returned step changes nothing;
    ``count[2]``: the records in the buffer)."""
    if S.out[2] != 0 or S.out[3] != 0:
        return 1
    if vmax * dt > 0.5 * c.h_min:
        return 2
    if step % RECORD_EVERY == 0 and count[2] + 1 >= c.record_limit:
        return 0                     # (the last record: the loop's own)
    if t >= c.next_output - 1e-12:
        return 3
    if step >= c.sort_step:
        return 4
    if t >= c.ramp_time and vmax < c.rest_velocity and ke <= c.rest_energy_ratio * ke_peak:
        return 5
    if o.geostatic and t >= c.geostatic_time:
        return 6
    if not t < c.t_end - 1e-12:
        return 7
    return -1


@exact_inline
def _tick(c, op, S, clock, count, energy, ke, vmax):
    """Book the step just done in ``clock`` / ``count`` (time, step number, dt range, peak,
    then its kinetic energy ``ke``, max |v_pic| ``vmax`` and dt) as the Python loop does;
    returns its event (:func:`_event`), also in ``count[1]``.  A record step that raises
    none is recorded in ``energy[count[2]]`` = (t, ke) (the loop records the steps it
    sees itself)."""
    dt = op.dt
    clock[0] = clock[0] + dt
    count[0] = count[0] + 1
    clock[2], clock[3] = min(clock[2], dt), max(clock[3], dt)
    clock[1] = max(clock[1], ke)
    clock[4], clock[5], clock[6] = ke, vmax, dt
    count[1] = _event(c, op, S, count, clock[0], count[0], dt, ke, clock[1], vmax)
    if count[1] < 0 and count[0] % RECORD_EVERY == 0:
        energy[count[2], 0] = clock[0]
        energy[count[2], 1] = ke
        count[2] = count[2] + 1
    return count[1]


def _pair_worker_for(gimp, block):
    """Thread ``w`` (0 or 1) of ``advance_pair`` (module docstring): the steps of
    ``advance_parallel`` with its half ``w`` in each stage and a barrier after each; thread
    0 books each step.  On a stalled barrier: ``count[1]`` = :data:`STALL`, return.
    ``version``, ``only``: literals (:func:`_make_drivers`); compiled for one basis
    (``gimp``) and one model path (``block``), closure constants (numba's cache key holds
    them), so the kernels it calls are compiled for those alone."""
    @driver
    @variant("pair_worker", gimp=gimp, block=block)
    def worker(version, only, P, M, T, H, S, o, c, clock, count, energy, w):
        bar = S.queue[QUEUE_BARRIER:]
        k = 0
        while True:
            op = _options(o, c, clock[0], S.out[0], S.out[1])
            if w == 0:
                _reset_queues(S)          # (the last step's stress pass ended at a barrier)
            _map_half(gimp, P, M, T, H, S, op, w)               # 1. map to nodes
            if not arrive(bar, k + 2):
                break
            _move_half(gimp, P, M, T, H, S, op, w)              # 2. solve, 3a. map back
            if not arrive(bar, k + 4):
                break
            stress_queue(True, gimp, block, version, only, False, P, M, T, H, S, op,
                         w)                                       # 3b, 3c
            if not arrive(bar, k + 6):
                break
            if w == 0:
                _combine(S, 2)
                ke, vmax = _grid_stats(S)
                _tick(c, op, S, clock, count, energy, ke, vmax)
            if not arrive(bar, k + 8):
                break
            if count[1] >= 0:
                return
            k += 8
        count[1] = STALL
    return worker


# The workers of :func:`_pair_worker_for`, module-level names (``advance_pair`` refers to
# them as globals, as :mod:`.stress` its queue kernels), one cache index for the four.
_PAIR_Q4_POINTS = _pair_worker_for(False, False)
_PAIR_Q4_BLOCK = _pair_worker_for(False, True)
_PAIR_GIMP_POINTS = _pair_worker_for(True, False)
_PAIR_GIMP_BLOCK = _pair_worker_for(True, True)
#: A worker of ``advance_pair`` (the four share one cache index: whether it is filled).
pair_worker = _PAIR_Q4_BLOCK


def _make_drivers(version, only, fbar, gimp, block):
    """``(serial, parallel, pair)`` drivers for one registry version, model restriction
    and F-bar or not (the stress pass's, :func:`.stress.material_kernels`; ``fbar`` a
    closure value, so a driver without F-bar compiles none of its passes; ``pair``: exactly
    two threads, no F-bar, module docstring), basis (``gimp``: uGIMP, else Q4) and block
    update or not (``block``, the points' ``o.block``): closure values too, so the kernels
    they call are compiled for that basis and that model path alone
    (:func:`.common.literal_variants`, :func:`.stress.stress_queue`,
    :func:`_pair_worker_for`; a campaign's realizations share all five).  All take the
    step options ``o`` of the previous step (their dt, gravity and damping are replaced),
    a :class:`RunControl`
    ``c``, ``clock`` (float64 (7,): t, peak kinetic energy, smallest and largest dt so far,
    then the last step's kinetic energy, max |v_pic| and dt), ``count`` (int64 (3,): the
    step number; the event that stopped the call; the records in ``energy``) and
    ``energy`` (float64 (:data:`RECORD_BUFFER`, 2): (t, kinetic energy) of the record
    steps run), all updated; ``S.out`` holds the last step's maxima on entry (the CFL
    step) and on return."""
    flags = dict(registry=version, only=only, fbar=fbar, gimp=gimp, block=block)

    @driver
    @variant("advance", **flags)
    def advance(P, M, N, S, o, c, clock, count, energy):
        while True:
            op = _options(o, c, clock[0], S.out[0], S.out[1])
            map_to_nodes(gimp, P, M, N, S, op)                # 1. map to nodes
            ke, vmax = solve_and_move(gimp, P, M, N, S, op)   # 2. solve, 3a. map back
            if fbar:                                          # 3b, 3c. stress update
                nodal_velocities(M, N)
                fbar_gradient_pass(P, M, N, S, op)
            serial_stress_pass(True, gimp, block, version, only, fbar, P, M, N, S, op)
            if _tick(c, op, S, clock, count, energy, ke, vmax) >= 0:
                break

    @driver_parallel
    @variant("advance_parallel", **flags)
    def advance_parallel(P, M, N, T, H, S, o, c, clock, count, energy):
        nch = workers(o, S)
        while True:
            op = _options(o, c, clock[0], S.out[0], S.out[1])
            map_to_nodes_parallel(gimp, P, M, T, H, S, op)
            ke, vmax = solve_and_move_parallel(gimp, P, M, T, H, S, op)
            if not nodal_in_pass(op, S):                      # (else in the stress pass)
                nodal_velocities_parallel(M, T, H)
            if fbar:
                fbar_gradient_pass_parallel(P, M, T, H, S, op)
            _reset_queues(S)
            for ch in prange(nch):
                stress_queue(True, gimp, block, version, only, fbar, P, M, T, H, S, op,
                             np.int64(ch))
            _combine(S, nch)
            if _tick(c, op, S, clock, count, energy, ke, vmax) >= 0:
                break

    @driver_parallel
    @variant("advance_pair", **flags)
    def advance_pair(P, M, N, T, H, S, o, c, clock, count, energy):
        S.queue[QUEUE_BARRIER] = 0
        for w in prange(2):          # (gimp, block: constants, three branches pruned)
            if gimp:
                if block:
                    _PAIR_GIMP_BLOCK(version, only, P, M, T, H, S, o, c, clock, count, energy,
                                     np.int64(w))
                else:
                    _PAIR_GIMP_POINTS(version, only, P, M, T, H, S, o, c, clock, count, energy,
                                      np.int64(w))
            elif block:
                _PAIR_Q4_BLOCK(version, only, P, M, T, H, S, o, c, clock, count, energy,
                               np.int64(w))
            else:
                _PAIR_Q4_POINTS(version, only, P, M, T, H, S, o, c, clock, count, energy,
                                np.int64(w))
    return advance, advance_parallel, advance_pair


def pair_driver_fits(threads: int, fbar: bool) -> bool:
    """Whether a run on ``threads`` threads (with F-bar or not) steps with ``advance_pair``
    (module docstring: exactly two threads, no F-bar), given a numba pool of two threads;
    else with ``advance_parallel`` (``threads`` > 1) or ``advance`` (one)."""
    return threads == 2 and not fbar


_BY_VERSION: dict = {}


def step_drivers(only: int = -1, fbar: bool = False, gimp: bool = False, block: bool = False):
    """``(advance, advance_parallel, advance_pair)`` compiled for the current model registry,
    model restriction ``only`` (the one model id of all points, -1: any; see
    :func:`.stress.material_kernels`), F-bar or not (``fbar``: the ``o.fbar`` of the
    steps they run), the basis (``gimp``: ``o.gimp``) and the block update (``block``:
    ``o.block``)."""
    key = (registry.version(), int(only), bool(fbar), bool(gimp), bool(block))
    if key not in _BY_VERSION:
        _BY_VERSION[key] = _make_drivers(*key)
    return _BY_VERSION[key]
