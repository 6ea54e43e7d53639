"""Where the explicit step is stable: the CFL limit measured, and predicted.

The textbook bound is ``dt <= C h / (c_p + |v|max)`` with C = 1:
the critical step of central differences with a lumped mass on linear elements,
``omega_max = 2 c_p / h`` in 1-D.  The explicit scheme takes
``dt = cfl h / (c_p + |v|max)`` (:func:`fem_rmpm.schemes.explicit.reference.stable_time_step`).
Two ways to find the real limit of *this* scheme (MUSL, FLIP/PIC, local damping, guards):

* :func:`cfl_limit` — by bisection on ``cfl``: a run is unstable when the guards of
  :func:`fem_rmpm.schemes.explicit.loop.run_explicit` stop it (:class:`SimulationError`:
  non-finite state, a point moving more than half a cell in a step) or when its stresses leave
  any physical bound (``|sigma| > 10 gamma H``);
* :func:`spectral_cfl_limit` — the linear stability theory of the same code: the
  Jacobian of one undamped geostatic (small-strain, fixed-point) step with respect to
  the point velocities and strains, built column by column from
  :func:`fem_rmpm.schemes.explicit.reference.explicit_step_numpy` (the step is linear
  there, so the columns are exact), and the ``cfl`` at which its spectral radius exceeds 1.

Why MUSL is stable beyond C = 1 in the linear (geostatic) regime: the stress update
uses nodal velocities re-mapped from the point momenta; the highest nodal mode of a
Q4 row is attenuated by the map to the 2x2 Gauss points and back (by 1/3), so the
stiffest mode of the step is softer than ``2 c_p / h``.  Once points move (large
deformation), nodes of cells that lose points keep little mass and the limit falls
back towards C = 1 (``validation/stability_map.py`` measures both).
"""
from __future__ import annotations

import numpy as np

from fem_rmpm.discretise.grid import make_grid
from fem_rmpm.discretise.points import seed_particles
from fem_rmpm.materials import kirchhoff_stress
from fem_rmpm.scene import Scene, with_values
from fem_rmpm.schemes.common import SimulationError
from fem_rmpm.schemes.explicit.loop import run_explicit
from fem_rmpm.schemes.explicit.reference import explicit_step_numpy, stable_time_step

__all__ = ["is_stable", "cfl_limit", "step_jacobian", "spectral_cfl_limit"]


def is_stable(scene: Scene, cfl: float, t_end: float, stress_bound: float) -> tuple[bool, str]:
    """Run ``scene`` (explicit) with ``cfl`` to ``t_end`` (s, never stopping at rest);
    stable unless the run stops with :class:`SimulationError` or ends with a non-finite
    stress or ``max |sigma| > stress_bound`` (kPa).  Returns ``(stable, why)``."""
    s = with_values(scene, {"solver.cfl": cfl, "solver.t_end": t_end,
                            "solver.rest_velocity": 0.0,
                            "solver.geostatic_time": max(scene.solver.geostatic_time, t_end)})
    grid = make_grid(s)
    pts = seed_particles(s, grid)
    try:
        rec = run_explicit(s, grid, pts)
    except SimulationError as exc:
        return False, str(exc).split(";")[0]
    smax = float(np.max(np.abs(pts.stress)))
    if not np.isfinite(smax) or smax > stress_bound:
        return False, f"max |sigma| = {smax:.3g} kPa after {rec.steps} steps"
    return True, f"{rec.steps} steps"


def cfl_limit(scene: Scene, t_end: float, stress_bound: float, lo: float = 0.25,
              hi: float = 4.0, tol: float = 0.005) -> tuple[float, float, list]:
    """Largest stable ``cfl`` of an explicit scene by bisection: ``(lo, hi, trials)`` with
    ``lo`` stable, ``hi`` unstable, ``hi - lo <= tol``; ``trials`` lists
    ``(cfl, stable, why)``.  ``lo`` must be stable and ``hi`` unstable (checked)."""
    trials = []
    for c, expect in ((lo, True), (hi, False)):
        ok, why = is_stable(scene, c, t_end, stress_bound)
        trials.append((c, ok, why))
        if ok != expect:
            raise ValueError(f"cfl = {c:g} is {'stable' if ok else 'unstable'} ({why}): "
                             "widen the bracket")
    while hi - lo > tol:
        mid = 0.5 * (lo + hi)
        ok, why = is_stable(scene, mid, t_end, stress_bound)
        trials.append((mid, ok, why))
        lo, hi = (mid, hi) if ok else (lo, mid)
    return lo, hi, trials


def step_jacobian(scene: Scene, cfl: float, flip: float | None = None) -> np.ndarray:
    """Jacobian (6n x 6n) of one undamped, gravity-free geostatic explicit step (numpy
    reference step) with respect to the state ``(velocity (n, 2), log strain (n, 4))`` of
    linear elastic points at their seeded positions, ``dt = cfl h / c_p``.  The step is
    linear in that state, so each column is the step of a unit state."""
    grid = make_grid(scene)
    base = seed_particles(scene, grid)
    n = base.n
    dt = stable_time_step(base, grid.cell, cfl)
    flip = scene.solver.flip if flip is None else flip
    J = np.empty((6 * n, 6 * n))
    for k in range(6 * n):
        p = base.copy()
        e = np.zeros(6 * n)
        e[k] = 1.0
        p.velocity[:] = e[:2 * n].reshape(n, 2)
        p.log_strain[:] = e[2 * n:].reshape(n, 4)
        p.stress[:] = kirchhoff_stress(p.log_strain, p.soil)
        explicit_step_numpy(grid, p, dt, np.zeros(2), 0.0, flip, scene.solver.shape, True,
                            bool(scene.solver.fbar))
        J[:, k] = np.concatenate([p.velocity.ravel(), p.log_strain.ravel()])
    return J


def spectral_cfl_limit(scene: Scene, lo: float = 0.5, hi: float = 4.0, tol: float = 0.005,
                       flip: float | None = None) -> tuple[float, float]:
    """``cfl`` at which the spectral radius of :func:`step_jacobian` first exceeds 1
    (+1e-9), by bisection: ``(lo, hi)``.  For small scenes (6n columns, n points)."""
    def radius(c):
        return float(np.max(np.abs(np.linalg.eigvals(step_jacobian(scene, c, flip)))))
    if radius(lo) > 1 + 1e-9 or radius(hi) <= 1 + 1e-9:
        raise ValueError("the bracket does not contain the spectral limit")
    while hi - lo > tol:
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if radius(mid) <= 1 + 1e-9 else (lo, mid)
    return lo, hi
