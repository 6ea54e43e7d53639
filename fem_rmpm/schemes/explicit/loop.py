"""Explicit MPM: lumped mass, MUSL, CFL time step, gravity ramp, local damping.

One step has the three stages of the method (Wang et al. 2016, Fig. 1):

1. **map to nodes** — mass, momentum and internal (stress divergence) force from
   the points to the grid nodes, plus the external force of gravity on the mesh,
   ``m_I g`` (the nodal mass times g: the scattered ``sum_p N_Ip m_p g`` in exact
   arithmetic);
2. **solve on the mesh** — lumped-mass momentum balance ``m a = f`` with local
   (Cundall) damping ``f - alpha |f| sign(v)`` and the boundary conditions;
3. **update the points** — velocities (FLIP/PIC blend) and positions from the
   nodal solution, then, as in MUSL (modified update stress last), the nodal
   velocities are recomputed from the *updated* point momenta and used for the
   velocity gradient, the Hughes-Winget deformation increment and the stress
   update.  MUSL rather than USL: USL computes stresses from the nodal
   velocities of the old momenta, which for nodes with tiny mass (a point near a
   cell edge) are noisy; the MUSL re-map damps that noise and conserves momentum.

The mesh is "reset" by construction: the grid is fixed and only the points move.

Volumetric locking (``[solver] fbar = true``, :mod:`.locking`): F-bar with cell
averaging — each point's deformation increment takes the volume-weighted mean volume
change of its host cell, ``dF_bar = (dJ_bar / dJ)^(1/2) dF`` (geostatic steps: the
small-strain B-bar); about 5 % more time per step (Q4, measured on the reference slope).
The stable step (CFL) is mapped in :mod:`.stability` and ``validation/stability_map.py``.

Two implementations of the same step, equal to round-off (``tests/test_kernels.py``):
``kernel="numba"`` (default) runs the compiled loops of :mod:`.kernels`
(~10x faster, only the nodes the points touch take part);
``kernel="numpy"`` runs :func:`explicit_step_numpy`, the readable vectorised
reference.
"""
from __future__ import annotations

import functools
import gc
import os
import sys
import time
from contextlib import contextmanager
from dataclasses import dataclass

import numba
import numpy as np
from numba.np.ufunc import parallel as numba_parallel

from fem_rmpm.discretise.basis import shape_at_points
from fem_rmpm.discretise.grid import Grid
from fem_rmpm.discretise.point_order import SORT_EVERY, PointOrder
from fem_rmpm.discretise.points import Particles
from fem_rmpm.materials import hughes_winget_increment, small_strain_update, stress_update
from fem_rmpm.runtime.machine import slow_threads_warning, threading_layer
from fem_rmpm.runtime.machine import usable_cores as _cores
from fem_rmpm.scene import Scene
from fem_rmpm.schemes.common import RunRecord, SimulationError, at_rest, check_points
from fem_rmpm.schemes.explicit import kernels as K
from fem_rmpm.schemes.explicit.kernels import Workspace
from fem_rmpm.schemes.explicit.kernels.advance import (
    RECORD_EVERY,
    STALL,
    RunControl,
    pair_driver_fits,
    record_limit,
    step_drivers,
)
from fem_rmpm.schemes.locking import bbar_gradient, fbar_increment, host_cells
from fem_rmpm.schemes.regularisation import average_softening, has_nonlocal

__all__ = ["StepStats", "Workspace", "explicit_step", "explicit_step_numpy", "threads_from_auto",
           "stable_time_step", "run_explicit", "KERNELS", "DEFAULT_KERNEL", "auto_threads",
           "busy_threads_warning"]

_MASS_TOL = 1e-14
KERNELS = ("numba", "numpy")
DEFAULT_KERNEL = "numba"


def auto_threads() -> int:
    """Threads of ``[solver] threads = 0`` (auto): numba's thread count — all cores for a
    single run (or ``NUMBA_NUM_THREADS``), 1 in a campaign worker (the task sets it) —
    less the cores busy right now (the other runnable threads, :func:`_runnable_others`;
    where ``/proc/loadavg`` is missing, the rounded 1-minute load average), at least 1.
    The count "right now", not the 1-minute average: the average still counts one's own
    run of a moment ago (it decays over a minute), so an idle machine got one thread.  Any
    count gives bitwise the same run; on busy cores a second thread only waits (on the
    shared 2-core machine at load 16: 3.5x the wall time of one thread, measured)."""
    # numba's pool size without starting the pool (get_num_threads would start it)
    started = getattr(numba_parallel, "_is_initialized", True)
    n = numba.get_num_threads() if started else int(numba.config.NUMBA_NUM_THREADS)
    if n <= 1:
        return 1
    return max(1, min(n, int(n - _busy_cores() + 0.5)))


@dataclass
class StepStats:
    kinetic_energy: float   # of the grid, 1/2 sum m_I |v_I|^2 (kJ per m of out-of-plane length)
    max_speed: float        # max |v| of the points as moved by the grid (m/s)
    # numba kernel only (None from the numpy path): for the next CFL step and the guards
    wave_speed: float | None = None   # max P-wave speed sqrt(M / rho) of the active points (m/s)
    point_speed: float | None = None  # max |v| of the active points (m/s)
    n_bad: int = 0                    # non-finite findings (x or v; stress) of active points
    n_outside: int = 0                # active points outside the grid rectangle


def _cfl_speeds(pts: Particles) -> tuple[float, float]:
    """(largest P-wave speed c_p = sqrt(M / rho), largest |v|) of the active points (m/s)."""
    act = pts.active
    rho = pts.mass[act] / pts.volume[act]
    M = pts.soil.bulk_modulus[act] + 4.0 / 3.0 * pts.soil.shear_modulus[act]
    wave_speed = float(np.max(np.sqrt(M / rho)))
    vmax = float(np.max(np.linalg.norm(pts.velocity[act], axis=1))) if act.any() else 0.0
    return wave_speed, vmax


def stable_time_step(pts: Particles, cell: np.ndarray, cfl: float) -> float:
    """CFL step dt = cfl * h / (c_p + |v|max), c_p = sqrt(M / rho) the P-wave speed (s)."""
    wave_speed, vmax = _cfl_speeds(pts)
    return cfl * float(np.min(cell)) / (wave_speed + vmax)


def _scatter(nodes: np.ndarray, weights: np.ndarray, n_nodes: int,
             second: np.ndarray | None = None) -> np.ndarray:
    if second is None:
        return np.bincount(nodes.ravel(), weights.ravel(), minlength=n_nodes)
    first = ~second         # each half summed in point order, then added (as the kernels)
    return (np.bincount(nodes[first].ravel(), weights[first].ravel(), minlength=n_nodes)
            + np.bincount(nodes[second].ravel(), weights[second].ravel(), minlength=n_nodes))


def map_to_nodes(nodes, N, dN, mass, velocity, stress, volume, gravity, n_nodes, second=None):
    """Stage 1: nodal mass (nn,), momentum (nn, 2) and force (nn, 2) from the points.
    The force is the internal one (stress divergence) scattered, plus gravity on the mesh,
    ``m_I g`` (= the scattered ``sum_p N_Ip m_p g`` in exact arithmetic; the compiled step
    adds it in its solve on the mesh, which saves two products per node and point).
    ``second`` (bool per point): the points summed apart and added last, as the compiled
    two-part scatter (:mod:`fem_rmpm.schemes.explicit.kernels.transfer`); None: one sum in point
    order."""
    m = _scatter(nodes, N * mass[:, None], n_nodes, second)
    p = np.stack([_scatter(nodes, N * (mass * velocity[:, k])[:, None], n_nodes, second)
                  for k in range(2)], axis=1)
    sx, sy, sxy = (stress[:, i][:, None] * volume[:, None] for i in (0, 1, 3))
    fx = -(sx * dN[..., 0] + sxy * dN[..., 1])
    fy = -(sxy * dN[..., 0] + sy * dN[..., 1])
    f = np.stack([_scatter(nodes, fx, n_nodes, second), _scatter(nodes, fy, n_nodes, second)],
                 axis=1)
    return m, p, f + m[:, None] * np.asarray(gravity, float)


def solve_on_mesh(m, p, f, fixed, dt, damping):
    """Stage 2: nodal velocities before/after the step and accelerations (lumped mass)."""
    has = m > _MASS_TOL
    inv_m = np.where(has, 1.0 / np.where(has, m, 1.0), 0.0)[:, None]
    v_old = p * inv_m
    if damping > 0:
        f = f - damping * np.abs(f) * np.sign(v_old)
    f = np.where(fixed, 0.0, f)
    v_old = np.where(fixed, 0.0, v_old)
    a = f * inv_m
    return v_old, v_old + a * dt, a


def explicit_step(grid: Grid, pts: Particles, dt: float, gravity: np.ndarray,
                  damping: float, flip: float = 1.0, shape: str = "standard",
                  geostatic: bool = False, kernel: str | None = None,
                  work: Workspace | None = None, fbar: bool = False,
                  threads: int = 1) -> StepStats:
    """Advance the active points by one explicit MUSL step of ``dt`` seconds (in place).

    ``geostatic``: points stay where they are and strains are small (the in-situ
    gravity phase); the displacement is accumulated in ``pts.u_geostatic``.
    ``kernel``: ``"numba"`` (default, compiled) or ``"numpy"`` (reference);
    ``work``: nodal arrays reused between steps (numba; made here if not given).
    ``fbar``: the F-bar locking remedy (:mod:`fem_rmpm.schemes.locking`): each point's volume
    change is replaced by the volume-weighted mean of its host cell (geostatic: B-bar).
    ``threads`` (numba): 2 or more runs the two halves of the points on two threads (the
    stress update on up to ``threads``); the result is bitwise the single-thread one.
    ``pts.F`` is not updated (the step needs det(dF) only; :func:`run_explicit` sets it NaN).
    """
    kernel = kernel or DEFAULT_KERNEL
    if kernel == "numpy":
        return explicit_step_numpy(grid, pts, dt, gravity, damping, flip, shape, geostatic,
                                   fbar)
    if kernel != "numba":
        raise ValueError(f"kernel {kernel!r} not allowed; allowed: {' | '.join(KERNELS)}")
    w = work if work is not None else Workspace.for_grid(grid, pts.n)
    (P, M), N, S, call = w.bind(grid, pts, shape == "gimp"), w.nodes, w.scratch, w.call
    o = K.StepOptions(float(dt), float(gravity[0]), float(gravity[1]), float(damping),
                      float(flip), bool(geostatic), shape == "gimp", bool(fbar), int(threads),
                      w.model, w.block)
    # each stage per half of the points, the halves on two threads (kernels.transfer)
    if threads > 1:     # (the threaded loops take the nodes' half apart: kernels.arrays.top_of)
        T = K.top_of(N)
        # 1. map to nodes: mass, momentum and force (locate + shape + scatter, one pass)
        call(K.map_to_nodes_parallel, P, M, T, N.half, S, o)
        # 2. solve on the mesh, 3a. map back: move the points, (MUSL) re-map momentum
        ke, vmax = call(K.solve_and_move_parallel, P, M, T, N.half, S, o)
    else:
        call(K.map_to_nodes, P, M, N, S, o)
        ke, vmax = call(K.solve_and_move, P, M, N, S, o)
    # 3b, 3c. nodal velocities from the re-mapped momenta, then the stress update
    K.update_stress(P, M, N, S, o, call)
    out = S.out
    return StepStats(ke, vmax, float(out[0]), float(out[1]), int(out[2]), int(out[3]))


def explicit_step_numpy(grid: Grid, pts: Particles, dt: float, gravity: np.ndarray,
                        damping: float, flip: float = 1.0, shape: str = "standard",
                        geostatic: bool = False, fbar: bool = False) -> StepStats:
    """Reference numpy implementation of :func:`explicit_step` (same arguments).

    ``geostatic``: points stay where they are and strains are small (the in-situ
    gravity phase); the displacement is accumulated in ``pts.u_geostatic``.
    """
    act = np.nonzero(pts.active)[0] if not pts.active.all() else slice(None)
    x, v, mass, vol = pts.x[act], pts.velocity[act], pts.mass[act], pts.volume[act]
    nn = grid.n_nodes
    second = np.arange(pts.n)[act] >= K.half_split(pts.n)   # the kernels' second half
    # 1. map point state to the nodes
    _, nodes, N, dN, _ = shape_at_points(grid, x, shape, pts.half_width[act])
    m, p, f = map_to_nodes(nodes, N, dN, mass, v, pts.stress[act], vol, gravity, nn, second)
    # 2. solve momentum balance on the mesh
    v_old, v_new, a = solve_on_mesh(m, p, f, grid.fixed, dt, damping)
    # 3. map back, move the points, then (MUSL) re-map momentum and update stress
    v_pic = np.einsum("pa,pak->pk", N, v_new[nodes])
    v = flip * (v + dt * np.einsum("pa,pak->pk", N, a[nodes])) + (1.0 - flip) * v_pic
    if geostatic:
        pts.u_geostatic[act] += dt * v_pic
    else:
        x = x + dt * v_pic
    _, p2, _ = map_to_nodes(nodes, N, dN, mass, v, pts.stress[act] * 0, vol, gravity * 0, nn,
                            second)
    v_nodes = np.where(grid.fixed, 0.0, p2 / np.where(m > _MASS_TOL, m, 1.0)[:, None])
    L = np.einsum("pak,pal->pkl", v_nodes[nodes], dN)          # velocity gradient
    state = (pts.log_strain[act], pts.state[act], pts.soil.take(act))
    host = host_cells(grid, pts.x[act]) if fbar else None      # cells before the move
    if geostatic:
        H = bbar_gradient(L * dt, vol, host, grid.n_cells) if fbar else L * dt
        log_strain, mstate, tau = small_strain_update(H, *state)
        dF, J = np.eye(2), 1.0
    else:
        dF = hughes_winget_increment(L, dt)
        if fbar:
            dF = fbar_increment(dF, vol, host, grid.n_cells)[0]
        log_strain, mstate, tau = stress_update(dF, *state)
        J = np.linalg.det(dF)
    pts.x[act], pts.velocity[act], pts.volume[act] = x, v, vol * J
    pts.log_strain[act], pts.state[act] = log_strain, mstate
    pts.stress[act] = tau * (pts.volume0[act] / pts.volume[act])[:, None]
    # motion as the grid sees it (FLIP keeps particle velocity modes the grid cannot see)
    speed2 = np.einsum("pk,pk->p", v_pic, v_pic)
    ke = 0.5 * float(m @ np.einsum("ik,ik->i", v_new, v_new))
    return StepStats(ke, float(np.sqrt(speed2.max(initial=0.0))))


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
            f"cfl (now {cfl:g}; the CFL limit is 1, default 0.5)")


def _without_gc(run):
    """``run`` with Python's automatic garbage collection paused, and restored as it was
    (on, or off if the caller had turned it off) however ``run`` ends.  The time loop makes
    hardly any reference cycles, but numba loading the step driver from its on-disk cache
    in the first step makes enough objects to trigger a full collection, which walks every
    object of the imported libraries: 56 ms of case (i)'s 5.9 s two-thread run (and ~9 ms
    of young collections after), measured with ``gc.callbacks``.  Left for the caller's
    next collection."""
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
    ``sort_every`` steps (0: never; :mod:`fem_rmpm.discretise.point_order`), in their original order
    whenever ``on_output``, a guard or the caller sees them; the ordinary steps between two steps
    the loop must see run in one compiled call (:func:`_advance`, bitwise the same).  ``threads``:
    :func:`_run_threads`.  ``pts.F``: NaN (not tracked)."""
    sv = scene.solver
    kernel = kernel or getattr(sv, "kernel", None) or DEFAULT_KERNEL
    if kernel not in KERNELS:
        raise ValueError(f"kernel {kernel!r} not allowed; allowed: {' | '.join(KERNELS)}")
    work = Workspace.for_grid(grid, pts.n) if kernel == "numba" else None
    threads = _run_threads(int(getattr(sv, "threads", 0)), kernel)
    pts.F[...] = np.nan              # the step needs det(dF) only (volume), not the total F
    h_min, g_full = float(np.min(grid.cell)), np.array(scene.gravity_vector)
    rec = RunRecord(scheme="explicit", solver={"threads": threads})
    t, step, ke_peak, next_out, stats = 0.0, 0, 0.0, sv.output_interval, None
    geostatic = sv.gravity_phase == "geostatic"
    wall0 = time.perf_counter()
    if on_output:
        on_output(t, pts)
    order = PointOrder(sort_every if kernel == "numba" else 0)
    driven = kernel == "numba" and not has_nonlocal(pts.soil)    # non-local: Python steps
    try:
        while t < sv.t_end - 1e-12:
            if driven:
                ctl = _run_control(sv, h_min, g_full, next_out if on_output else np.inf,
                                   order.due_step(), pts.n)
                stats, dt, t, step, ke_peak = _advance(grid, pts, work, sv, geostatic, threads,
                                                       ctl, (t, step, ke_peak), rec, stats)
            else:
                stats, dt, t, step, ke_peak = _python_step(
                    grid, pts, sv, kernel, work, threads, geostatic, g_full,
                    _cfl_step(stats, pts, grid, sv.cfl, h_min), (t, step, ke_peak), rec)
            if step == 1:                    # the t = 0 output and the kernels' first calls
                _first_step_done(rec, time.perf_counter() - wall0, threads)
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
                order.restore(pts)
                on_output(t, pts)
                next_out += sv.output_interval
            order.sort_if_due(grid, pts, step)
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
    finally:
        order.restore(pts)
    rec.steps, rec.time, rec.wall_time = step, t, time.perf_counter() - wall0
    if on_output and next_out - sv.output_interval < t - 1e-12:
        on_output(t, pts)
    return rec


def _first_step_done(rec: RunRecord, seconds: float, threads: int) -> None:
    """Book the first step's wall time (s) and, on two or more threads, numba's threading
    layer in ``rec.solver``; warn (once per process) when that layer is the slow one
    (:func:`fem_rmpm.runtime.machine.slow_threads_warning`)."""
    rec.solver["first_step_time"] = seconds
    if threads > 1:
        layer = rec.solver["threading_layer"] = threading_layer()
        _print_once("layer", slow_threads_warning(layer, threads))


def _run_control(sv, h_min: float, g_full: np.ndarray, next_output: float,
                 sort_step: float, n_points: int) -> RunControl:
    """The :class:`~.kernels.advance.RunControl` of ``[solver]`` ``sv`` for ``n_points``
    points (all floats)."""
    return RunControl(float(sv.cfl), float(h_min), float(sv.t_end), float(sv.gravity_ramp_time),
                      float(sv.damping), float(sv.damping_time), float(g_full[0]),
                      float(g_full[1]), float(sv.geostatic_time), float(sv.rest_velocity),
                      float(sv.rest_energy_ratio), float(next_output), float(sort_step),
                      record_limit(n_points))


def _guards(grid: Grid, pts: Particles, stats: StepStats, order: PointOrder, step: int,
            t: float, policy: str, rec: RunRecord) -> bool:
    """The run's guards after a step with a finding (or from the numpy path):
    :func:`fem_rmpm.schemes.common.check_points` on the points in their original order (the guards
    name points by their original index); frozen points make the next CFL step come from
    :func:`stable_time_step`.  False when no active point is left."""
    order.restore(pts)
    check_points(grid, pts, step, t, policy, rec)
    if stats.n_outside:
        stats.wave_speed = None
    return bool(pts.active.any())


def _python_step(grid: Grid, pts: Particles, sv, kernel: str, work: Workspace | None,
                 threads: int, geostatic: bool, g_full: np.ndarray, cfl_dt: float,
                 clock0: tuple, rec: RunRecord) -> tuple[StepStats, float, float, int, float]:
    """One step of the time loop from Python, from ``clock0`` = (t, step, peak kinetic
    energy): the CFL step ``cfl_dt`` (s) cut at ``t_end``, the gravity ramp and the damping
    of ``[solver]`` ``sv``, then the non-local averaging; ``rec.dt_min`` / ``dt_max``
    updated.  Returns as :func:`_advance` (the peak is left to the loop)."""
    t, step, ke_peak = clock0
    dt = min(cfl_dt, sv.t_end - t)
    ramp = 1.0 if sv.gravity_ramp_time <= 0 else min(1.0, (t + dt) / sv.gravity_ramp_time)
    damping = sv.damping if (geostatic or t < sv.damping_time) else 0.0
    stats = explicit_step(grid, pts, dt, ramp * g_full, damping, sv.flip, sv.shape,
                          geostatic, kernel, work, bool(sv.fbar), threads)
    average_softening(grid, pts)     # non-local softening (no-op for local soils)
    rec.dt_min, rec.dt_max = min(rec.dt_min, dt), max(rec.dt_max, dt)
    return stats, dt, t + dt, step + 1, ke_peak


def _advance(grid: Grid, pts: Particles, work: Workspace, sv, geostatic: bool, threads: int,
             ctl: RunControl, clock0: tuple, rec: RunRecord,
             stats: StepStats | None) -> tuple[StepStats, float, float, int, float]:
    """Ordinary steps of the time loop in one compiled call (:mod:`.kernels.advance`), from
    ``clock0`` = (t, step, peak kinetic energy) and the previous step's maxima in the
    scratch (``stats`` None or without them, at the first step and after a guard: those of
    the points, :func:`_cfl_speeds`, so :func:`stable_time_step`'s dt), to the first step
    the loop must see; ``rec.dt_min`` / ``dt_max`` and ``rec.energy`` updated.  Returns
    that step's :class:`StepStats`, its dt, and the new t, step and peak.  (The first step
    runs through the driver too, so a run with local soils needs no other compiled kernel;
    loading the driver from the numba cache takes about what the Python step's six
    kernels took: a first step of 0.21-0.32 s against 0.20-0.25 s, case (i), measured.)"""
    (P, M), N, S, call = (work.bind(grid, pts, sv.shape == "gimp"), work.nodes, work.scratch,
                          work.call)
    if stats is None or stats.wave_speed is None:
        S.out[:2] = _cfl_speeds(pts)
    clock, count = work.clock, work.count
    o = K.StepOptions(0.0, 0.0, 0.0, 0.0, float(sv.flip), bool(geostatic), sv.shape == "gimp",
                      bool(sv.fbar), int(threads), work.model, work.block)
    clock[:4] = clock0[0], clock0[2], rec.dt_min, rec.dt_max
    count[0], count[2] = clock0[1], 0
    serial, parallel, pair = step_drivers(o.model)
    if threads > 1:
        both = pair_driver_fits(threads, bool(sv.fbar)) and numba.get_num_threads() >= 2
        call(pair if both else parallel, P, M, N, K.top_of(N), N.half, S, o, ctl, clock,
             count, work.energy)
        if count[1] == STALL:
            raise SimulationError(
                f"step {int(count[0]) + 1} (t = {float(clock[0]):.6g} s): one of the two "
                "threads of the step waited for the other for half a minute (numba's thread "
                "pool did not run both); set [solver] threads = 1")
    else:
        call(serial, P, M, N, S, o, ctl, clock, count, work.energy)
    out = S.out
    rec.energy.extend(map(tuple, work.energy[:count[2]].tolist()))   # the steps run inside
    rec.dt_min, rec.dt_max = float(clock[2]), float(clock[3])
    stats = StepStats(float(clock[4]), float(clock[5]), float(out[0]), float(out[1]),
                      int(out[2]), int(out[3]))
    return stats, float(clock[6]), float(clock[0]), int(count[0]), float(clock[1])


def _run_threads(threads: int, kernel: str) -> int:
    """The run's thread count: ``[solver] threads``, or with 0 :func:`auto_threads`; an
    explicit count of 2 or more on busy cores is warned about (:func:`_warn_busy_threads`)."""
    if threads > 1 and kernel == "numba":
        _warn_busy_threads(threads)
    return threads or auto_threads()


def _runnable_others(samples: int = 3, pause: float = 0.001) -> int | None:
    """Other threads running or waiting for a core right now: the kernel's count of runnable
    threads (4th field of ``/proc/loadavg``) less this one, the least of a few samples a
    millisecond apart; None where there is no ``/proc/loadavg``."""
    counts = []
    try:
        for i in range(samples):
            with open("/proc/loadavg") as fh:
                counts.append(int(fh.read().split()[3].split("/")[0]) - 1)
            if i + 1 < samples:
                time.sleep(pause)
    except (OSError, ValueError, IndexError):
        return None
    return max(0, min(counts))


def _busy_cores() -> float:
    """Cores busy right now: :func:`_runnable_others`; where ``/proc/loadavg`` is missing,
    the 1-minute load average; 0 without either."""
    others = _runnable_others()
    if others is not None:
        return float(others)
    try:
        return os.getloadavg()[0]
    except OSError:
        return 0.0


def busy_threads_warning(threads: int) -> str | None:
    """The one-line warning for an explicit ``[solver] threads`` of 2 or more when that many
    cores are not free (cores less the other processes running right now), else None.  On
    busy cores every parallel loop waits for its slowest thread: on the 2-core machine one
    other busy process made a ``threads = 2`` run of case (i) take 184.6 s instead of ~14 s
    (measured).  ``threads = 0`` (auto) leaves busy cores out by itself."""
    if threads <= 1:
        return None
    cores = _cores()
    others = int(_busy_cores() + 0.5)
    try:
        load = f"{os.getloadavg()[0]:.2f}"
    except OSError:
        load = "unknown"
    free = max(cores - others, 0)
    if threads <= free:
        return None
    return (f"fem-rmpm: warning: [solver] threads = {threads}, but {others} other "
            f"process(es) are running on this machine's {cores} core(s) (1-minute load average "
            f"{load}): every parallel loop waits for a thread on a busy core, which can make the "
            f"run many times slower; set [solver] threads = {max(free, 1)} or 0 (auto: the idle "
            "cores)")


_THREADS_WARNED: set = set()      # the thread counts (and "layer") already warned about
_FROM_AUTO = [False]              # True while a run uses a count resolved from threads = 0


@contextmanager
def threads_from_auto(resolved: bool):
    """While ``resolved`` (the run's ``[solver] threads`` was 0 and the caller replaced it by
    :func:`auto_threads`, as :func:`fem_rmpm.api.run` does): no busy-cores warning.  The
    warning is for a count the user set; auto left the busy cores out a moment before the
    run, and a process that started since (e.g. another test worker) is not the user's
    setting to change."""
    before, _FROM_AUTO[0] = _FROM_AUTO[0], bool(resolved)
    try:
        yield
    finally:
        _FROM_AUTO[0] = before


def _warn_busy_threads(threads: int) -> None:
    """Print :func:`busy_threads_warning` to stderr, once per process and thread count."""
    if not (_FROM_AUTO[0] or threads in _THREADS_WARNED):
        _print_once(threads, busy_threads_warning(threads))


def _print_once(key, text: str | None) -> None:
    """Print the warning ``text`` (None: nothing to say) to stderr unless this process
    already printed the one filed under ``key`` (a thread count, or ``"layer"``)."""
    if text and key not in _THREADS_WARNED:
        _THREADS_WARNED.add(key)
        print(text, file=sys.stderr, flush=True)
