"""Adaptive step size of the implicit scheme.

After every converged step :meth:`StepController.judge` proposes the next step from

* the **Newton iteration count** ``k``, the factorized tangents of the step (the BFGS
  iterations between them, :func:`fem_rmpm.schemes.implicit.newton.newton`, cost a
  fifth of one and are not counted): ``k <= EASY_FACTORIZATIONS`` grows the step by
  ``GROW``, ``k >= HARD_ITERATIONS`` (or more than half of ``max_iterations``) shrinks it
  by ``SHRINK`` (quasi-static load steps: the user's load step is the largest step and a
  converged step is never shrunk; a step halved by a cut grows back by ``GROW`` after
  each sub-step converged in fewer than ``HARD_ITERATIONS``);
* (dynamic steps) the **kinematic limits**: the largest point displacement increment
  ``|du_p|`` as a fraction of the cell size against ``[solver] max_displacement_fraction``,
  and the points' volume ratio ``det dF`` against ``DET_BOUNDS``.  A step beyond a limit
  by more than ``REJECT_RATIO`` is rejected and redone smaller (it would have moved a
  point through most of a cell in one Newton solve, where the grid-reset basis no longer
  describes it); within that it is accepted and the next step is scaled to meet the limit.

and bounds it to ``[dt_min, dt_max]``.  A step Newton cannot converge is still halved
(``max_cuts`` times) by the driver; ``det dF <= 0`` is never accepted (the Newton line
search shortens a correction that inverts a point, the step is cut if none helps).
With ``[solver] adaptive = false`` the step stays at ``dt`` (dynamic) or at the load step
(quasi-static) except for cuts.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["StepController", "Verdict", "DET_BOUNDS"]

EASY_ITERATIONS = 3        # the least HARD_ITERATIONS - 1 (few allowed iterations)
#: a dynamic step that converged with this many factorized tangents or fewer grows (the
#: larger steps it allows cost fewer factorizations per simulated second: case (i) to
#: rest takes 4881 in 1818 steps instead of 5381 in 1926 with 3, 7052 in 2355 with 2)
EASY_FACTORIZATIONS = 4
HARD_ITERATIONS = 7        # a step that needed this many or more shrinks
GROW, SHRINK = 1.5, 0.6
DET_BOUNDS = (0.8, 1.25)   # allowed det dF of a point in one step (volume ratio)
REJECT_RATIO = 2.0         # a limit exceeded by this factor rejects the step
#: aim below a limit when scaling a step to meet it: the next step is the last one scaled
#: by SAFETY / (its displacement or det dF against the limit).  The largest displacement
#: changes little from one step to the next in a flow, so a step sized so lands within
#: 2 % of its aim for 90 % of the steps (case (i)); 0.9 takes 10 % fewer steps than 0.8
#: and keeps all but 3 of them within the limit (case (i) to rest: 1633 steps, 4578
#: factorizations, against 1818 and 4881 with 0.8; 0.95: 1647 and 5145, 12 steps over)
SAFETY = 0.9


@dataclass
class Verdict:
    accept: bool
    size: float            # the next step (accepted) or the retry (rejected)
    limited_by: str        # "iterations", "displacement", "det dF", "dt_max", "" (none)


class StepController:
    """Proposes step sizes; ``dynamic`` steps are also held to the kinematic limits."""

    def __init__(self, sv, dynamic: bool, size: float, size_max: float,
                 size_min: float = 0.0):
        self.sv, self.dynamic = sv, dynamic
        self.adaptive = bool(sv.adaptive)
        self.size, self.size_max, self.size_min = size, size_max, size_min
        self.hard = min(HARD_ITERATIONS, max(EASY_ITERATIONS + 1, sv.max_iterations // 2 + 1))

    def kinematic_ratio(self, limits: dict) -> tuple[float, str]:
        """How far the step went relative to its kinematic limits (1 = at the limit)."""
        if not limits:
            return 0.0, ""
        r_u = limits["displacement"] / self.sv.max_displacement_fraction
        lo, hi = DET_BOUNDS
        r_j = max(math.log(limits["det_max"]) / math.log(hi),
                  math.log(max(limits["det_min"], 1e-300)) / math.log(lo))
        return (r_u, "displacement") if r_u >= r_j else (r_j, "det dF")

    def judge(self, h: float, iterations: int, limits: dict, clipped: bool) -> Verdict:
        """Verdict on a converged step of size ``h`` that took ``iterations`` full Newton
        iterations (factorized tangents); ``clipped``: the step was shortened to meet an
        output time or the end of an interval (no growth is read from it)."""
        if not self.adaptive:
            return Verdict(True, self.size, "")
        r, why = self.kinematic_ratio(limits) if self.dynamic else (0.0, "")
        if r > REJECT_RATIO and h > self.size_min * (1 + 1e-9):
            self.size = max(self.size_min, h * SAFETY / r)
            return Verdict(False, self.size, why)
        base = self.size if clipped else h
        new, reason = base, ""
        if iterations >= self.hard and self.dynamic:
            new, reason = base * SHRINK, "iterations"
        elif not clipped and iterations <= (EASY_FACTORIZATIONS if self.dynamic
                                            else self.hard):
            new = base * GROW
        if r > 0 and h * SAFETY / r < new:
            new, reason = h * SAFETY / r, why
        if new >= self.size_max:
            new, reason = self.size_max, reason or "dt_max"
        self.size = max(self.size_min, new)
        return Verdict(True, self.size, reason)
