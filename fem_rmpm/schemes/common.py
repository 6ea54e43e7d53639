"""The run vocabulary both schemes share: the error, the run record, the point guard
and the at-rest test.

Kept apart from the schemes so that the implicit scheme, the API and the campaign can
report a failure or read a run record without importing the explicit scheme.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from fem_rmpm.discretise.grid import Grid
from fem_rmpm.discretise.points import Particles

__all__ = ["SimulationError", "RunRecord", "check_points", "at_rest"]


class SimulationError(RuntimeError):
    """A run cannot go on; the message says what, where, at which step and what to change."""


@dataclass
class RunRecord:
    """What happened in a run (filled by the scheme, written to summary.json)."""
    scheme: str
    steps: int = 0
    time: float = 0.0
    wall_time: float = 0.0
    cpu_time: float = 0.0        # s of CPU of this process (all its threads) during the run
    stop_reason: str = ""
    dt_min: float = math.inf
    dt_max: float = 0.0
    energy: list = field(default_factory=list)       # [(t, kinetic energy kJ/m)]
    friction: list = field(default_factory=list)     # [(t, frictional dissipation so far kJ/m)]
    frozen_points: list = field(default_factory=list)  # indices of points frozen at the edge
    error: str | None = None
    solver: dict = field(default_factory=dict)


def at_rest(t: float, ramp_time: float, max_speed: float, kinetic_energy: float,
            kinetic_energy_peak: float, rest_velocity: float, rest_energy_ratio: float) -> bool:
    """True when a run has come to rest: gravity fully on (``t >= ramp_time``, s), the
    largest point speed below ``rest_velocity`` (m/s) and the grid kinetic energy at most
    ``rest_energy_ratio`` x its peak so far (kJ per m of out-of-plane length)."""
    return (t >= ramp_time and max_speed < rest_velocity
            and kinetic_energy <= rest_energy_ratio * kinetic_energy_peak)


def check_points(grid: Grid, pts: Particles, step: int, t: float, policy: str,
                 record: RunRecord) -> None:
    """Guard after each step: a non-finite state stops the run with a clear error.

    Points can only leave the grid through a ``free`` edge (fixed and roller
    edges stop them).  Policy ``freeze``: such a point is kept where it is,
    inactive (no mass, no force, no motion) and listed in ``summary.json``;
    ``stop``: the run ends with an error naming the point."""
    act = np.nonzero(pts.active)[0]
    bad = ~(np.isfinite(pts.x[act]).all(1) & np.isfinite(pts.velocity[act]).all(1)
            & np.isfinite(pts.stress[act]).all(1))
    if bad.any():
        i = act[np.argmax(bad)]
        raise SimulationError(
            f"step {step} (t = {t:.4g} s): non-finite state at material point {i} (started at "
            f"x = {pts.x0[i, 0]:.3f}, y = {pts.x0[i, 1]:.3f} m); the explicit scheme went "
            "unstable — reduce [solver] cfl (default 0.5) or check the material constants")
    lo, hi = grid.origin, grid.upper
    out = ((pts.x[act] < lo) | (pts.x[act] > hi)).any(axis=1)
    if out.any():
        idx = act[out]
        if policy == "stop":
            i = idx[0]
            raise SimulationError(
                f"step {step} (t = {t:.4g} s): {len(idx)} material point(s) left the grid, "
                f"first point {i} at x = {pts.x[i, 0]:.3f}, y = {pts.x[i, 1]:.3f} m; enlarge "
                "[grid] size or set [solver] edge_policy = \"freeze\"")
        pts.active[idx] = False
        pts.velocity[idx] = 0.0
        record.frozen_points.extend(int(i) for i in idx)
