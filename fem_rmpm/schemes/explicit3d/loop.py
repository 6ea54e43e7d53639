"""The explicit scheme's time loop in three dimensions: the plane-strain loop's rules
(:mod:`fem_rmpm.schemes.explicit.loop`) around the compiled hexahedral step
(:func:`.kernels.step_3d`): the CFL step ``dt = cfl h_min / (c_p + |v|max)``, the gravity
ramp, local damping while ``t < damping_time`` (always in the geostatic phase), the
geostatic phase on the fixed geometry until at rest or ``geostatic_time``, the guards
(non-finite state: an error naming the point; a point leaving the grid: frozen or the
run stopped, ``edge_policy``; a point moving more than half a cell in a step: an error),
the output callback, progress every 20 steps and the at-rest test
(:func:`fem_rmpm.schemes.common.at_rest`).  ``[solver] threads`` of 2 or more (or 0, auto,
:func:`fem_rmpm.schemes.explicit.threads.run_threads`, giving 2 or more) runs the step's
two halves of the points on two threads (:mod:`.step`, bitwise the one-thread run); the
run's record says the threads used.
"""
from __future__ import annotations

import time

import numba
import numpy as np

from fem_rmpm.discretise.grid3d import Grid3D
from fem_rmpm.discretise.points3d import Particles3D
from fem_rmpm.scene import Scene
from fem_rmpm.schemes.common import RunRecord, SimulationError, at_rest
from fem_rmpm.schemes.explicit3d.elastic import EIG_BLOCK, stretch_from_log_strain
from fem_rmpm.schemes.explicit.threads import first_step_done, run_threads
from fem_rmpm.schemes.explicit3d.kernels import N_STATS, NODE_COLUMNS
from fem_rmpm.schemes.explicit3d.step import (
    StepGrid,
    StepPoints,
    StepScratch,
    step_3d,
    step_3d_threaded,
)
from fem_rmpm.discretise.point_order import PointOrder
from fem_rmpm.schemes.explicit3d.order import SORT_EVERY, point_order_3d
from fem_rmpm.schemes.explicit3d.stress3d import BLOCK_ROWS

__all__ = ["run_explicit_3d", "wave_speed_3d", "Workspace3D", "RECORD_EVERY"]

#: Steps between two kinetic-energy records and progress calls (as in plane strain).
RECORD_EVERY = 20


def wave_speed_3d(pts: Particles3D) -> float:
    """Largest P-wave speed sqrt((lambda + 2 mu) / rho) of the active points (m/s)."""
    act = pts.active
    rho = pts.mass[act] / pts.volume[act]
    return float(np.max(np.sqrt((pts.lame[act, 0] + 2 * pts.lame[act, 1]) / rho)))


class Workspace3D:
    """What the step keeps besides the points, made once per run: the elastic left
    Cauchy-Green tensor of each point (``b = exp(2 eps)``, (n, 6), :mod:`.elastic`), the
    Lame constants as contiguous columns, the points' cells and local coordinates, the
    nodal rows of each half of the points and their totals with the lists of touched
    nodes and cells (:data:`.step.StepScratch`), and the stats of the last step."""

    def __init__(self, grid: Grid3D, pts: Particles3D):
        nn, n, nc = grid.n_nodes, pts.n, grid.n_cells
        self.shape = np.array(grid.shape, dtype=np.int64)
        self.lam = np.ascontiguousarray(pts.lame[:, 0])
        self.mu = np.ascontiguousarray(pts.lame[:, 1])
        self.be = np.empty((n, 6))
        self.out = np.zeros(N_STATS)
        self.scratch = StepScratch(
            cellbase=np.zeros(n, dtype=np.int64), cellxi=np.zeros((n, 3)),
            buf=np.zeros((2, nn, NODE_COLUMNS)), touched=np.zeros((2, nn), dtype=np.bool_),
            nodes=np.zeros((2, nn), dtype=np.int64),
            cell_touched=np.zeros((2, nc), dtype=np.bool_),
            cells=np.zeros((2, nc), dtype=np.int64), nact=np.zeros((3, 2), dtype=np.int64),
            node=np.zeros((nn, NODE_COLUMNS)), unodes=np.zeros(nn, dtype=np.int64),
            stats=np.zeros((2, 5)), e3=np.zeros((2, 3)), blk=np.zeros((2, BLOCK_ROWS, EIG_BLOCK)),
            idx=np.zeros((2, EIG_BLOCK), np.int64))
        self.grid = StepGrid(grid.origin, grid.cell, self.shape, grid.fixed)
        self.points = StepPoints(pts.x, pts.velocity, pts.mass, pts.volume, pts.volume0,
                                 pts.stress, pts.log_strain, self.be, self.lam, self.mu,
                                 pts.active, pts.u_geostatic, pts.model, pts.plastic,
                                 pts.state)
        self.stretch_from_strain(pts)

    def stretch_from_strain(self, pts: Particles3D) -> None:
        """``b = exp(2 eps)`` of every point from its log strain (at the start and after
        the geostatic phase, which updates the log strain alone)."""
        stretch_from_log_strain(pts.log_strain, self.be)


def _step(work: Workspace3D, dt, g, damping, flip, geostatic, threads: int) -> np.ndarray:
    step = step_3d if threads <= 1 else step_3d_threaded
    step(work.points, work.grid, work.scratch, dt, g, damping, flip, geostatic, work.out)
    return work.out


def run_explicit_3d(scene: Scene, grid: Grid3D, pts: Particles3D, on_output=None,
                    progress=None) -> RunRecord:
    """Advance ``pts`` to rest or ``t_end`` (the module docstring); ``on_output(t, pts)`` at
    t = 0, every ``output_interval`` and the end; ``progress(t, step)`` every 20 steps.
    The points are kept sorted by cell while the loop runs (:mod:`.order`); ``on_output``
    and the caller see them in their seeded order (also after an error)."""
    work = Workspace3D(grid, pts)
    order = point_order_3d(pts, work, SORT_EVERY)
    try:
        return _time_loop(scene, grid, pts, work, order, on_output, progress)
    finally:
        order.restore()


# long function: the time loop's rules written out in order
def _time_loop(scene: Scene, grid: Grid3D, pts: Particles3D, work: Workspace3D,
               order: PointOrder, on_output, progress) -> RunRecord:
    sv = scene.solver
    h_min = float(np.min(grid.cell))
    g_full = np.array([*scene.gravity_vector, 0.0])
    threads = _threads_used(run_threads(int(getattr(sv, "threads", 0)), "numba"))
    rec = RunRecord(scheme="explicit", solver={"threads": threads, "dimension": 3})
    t, step, ke_peak, next_out = 0.0, 0, 0.0, sv.output_interval
    geostatic = sv.gravity_phase == "geostatic"
    speeds = (wave_speed_3d(pts), 0.0)
    wall0 = time.perf_counter()
    if on_output:
        on_output(t, pts)
    while t < sv.t_end - 1e-12:
        dt = min(sv.cfl * h_min / (speeds[0] + speeds[1]), sv.t_end - t)
        ramp = 1.0 if sv.gravity_ramp_time <= 0 else min(1.0, (t + dt) / sv.gravity_ramp_time)
        damping = sv.damping if (geostatic or t < sv.damping_time) else 0.0
        stats = _step(work, dt, ramp * g_full, damping, sv.flip, geostatic, threads)
        t, step = t + dt, step + 1
        if step == 1:
            first_step_done(rec, time.perf_counter() - wall0, threads)
        rec.dt_min, rec.dt_max = min(rec.dt_min, dt), max(rec.dt_max, dt)
        ke, max_speed, wave, point_speed, n_bad, n_out = stats
        if n_bad:
            _non_finite(pts, order.ids, step, t, sv.cfl)
        if n_out and not _freeze(grid, pts, order.ids, step, t, sv.edge_policy, rec):
            rec.stop_reason = "all points left the grid"
            break
        if max_speed * dt > 0.5 * h_min:
            raise SimulationError(
                f"step {step} (t = {t:.4g} s): a material point moved {max_speed * dt:.3g} m "
                f"in one step (> half a cell); the explicit scheme is unstable — reduce "
                f"[solver] cfl (now {sv.cfl:g}, default 0.5, allowed (0, 3])")
        speeds = (wave_speed_3d(pts), point_speed) if n_out else (wave, point_speed)
        ke_peak = max(ke_peak, ke)
        if step % RECORD_EVERY == 0:
            rec.energy.append((t, ke))
            if progress:
                progress(t, step)
        if on_output and t >= next_out - 1e-12:
            order.restore()
            on_output(t, pts)
            next_out += sv.output_interval
        if not geostatic:
            order.sort_if_due(step)                   # by the cells of this step's map
        rest = at_rest(t, sv.gravity_ramp_time, max_speed, ke, ke_peak, sv.rest_velocity,
                       sv.rest_energy_ratio)
        if geostatic and (rest or t >= sv.geostatic_time):
            geostatic = False
            rec.solver["geostatic_end_time"] = t
            rec.solver["geostatic_at_rest"] = bool(rest)
            work.stretch_from_strain(pts)
            continue
        if rest:
            rec.stop_reason = "at rest"
            break
    else:
        rec.stop_reason = "t_end reached"
    rec.steps, rec.time, rec.wall_time = step, t, time.perf_counter() - wall0
    rec.solver["point_sorts"] = order.sorts
    if on_output and next_out - sv.output_interval < t - 1e-12:
        order.restore()
        on_output(t, pts)
    return rec


def _threads_used(asked: int) -> int:
    """1, or 2 when two or more threads are asked for and numba's pool has two."""
    if asked <= 1:
        return 1
    return 2 if numba.get_num_threads() >= 2 else 1


def _non_finite(pts: Particles3D, ids: np.ndarray, step: int, t: float, cfl: float) -> None:
    """The error naming the first point (by its id ``ids[i]``) with a non-finite state."""
    act = np.nonzero(pts.active)[0]
    bad = ~(np.isfinite(pts.x[act]).all(1) & np.isfinite(pts.velocity[act]).all(1)
            & np.isfinite(pts.stress[act]).all(1))
    i = act[np.argmax(bad)]
    x0 = pts.x0[i]
    raise SimulationError(
        f"step {step} (t = {t:.4g} s): non-finite state at material point {ids[i]} (started at "
        f"x = {x0[0]:.3f}, y = {x0[1]:.3f}, z = {x0[2]:.3f} m); the explicit scheme went "
        f"unstable — reduce [solver] cfl (now {cfl:g}, default 0.5) or check the material "
        "constants")


def _freeze(grid: Grid3D, pts: Particles3D, ids: np.ndarray, step: int, t: float,
            policy: str, rec: RunRecord) -> bool:
    """Points outside the grid box: frozen (inactive, listed by id ``ids[i]``) or, with
    ``policy`` "stop", an error naming the first; False when no active point is left."""
    act = np.nonzero(pts.active)[0]
    out = ((pts.x[act] < grid.origin) | (pts.x[act] > grid.upper)).any(axis=1)
    idx = act[out]
    if len(idx) and policy == "stop":
        i = idx[0]
        raise SimulationError(
            f"step {step} (t = {t:.4g} s): {len(idx)} material point(s) left the grid, first "
            f"point {ids[i]} at x = {pts.x[i, 0]:.3f}, y = {pts.x[i, 1]:.3f}, "
            f"z = {pts.x[i, 2]:.3f} m; enlarge [grid] size or set [solver] "
            "edge_policy = \"freeze\"")
    pts.active[idx] = False
    pts.velocity[idx] = 0.0
    rec.frozen_points.extend(int(ids[i]) for i in idx)
    return bool(pts.active.any())
