"""The static solves of a strength reduction (:mod:`~fem_rmpm.schemes.implicit.strength_reduction`).

Two kinds, both small-strain geostatic Newton solves on the fixed in-situ geometry:

* :func:`gravity_solve`: gravity applied from zero at a trial factor ``F`` in
  ``load_steps`` load steps (the implicit scheme's static run);
* :func:`continue_strength`: from the converged state of a smaller ``F0`` at full gravity,
  the strengths reduced further to ``F`` in one Newton solve (strength continuation),
  which decides the trial when it fails over a small change of ``F``.

A continuation solve is rejected as soon as its residual grows to ``growth_rejection``
(1.5) times the smallest residual of its earlier iterations (:func:`_solve`).
The line search keeps a step that lowers the residual whenever one of its halvings does,
so a converging solve hardly ever lets it grow: in the strength-reduction searches of
realizations 0-11 of the risk slope (xi = 12, the search that halved every failed
continuation twice) the 44 converged continuation solves grew it by 1.013 times at most,
while the 107 failing ones, rejected so, would have taken 27 % fewer Newton iterations in
all, every decision unchanged.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from fem_rmpm.discretise.grid import Grid
from fem_rmpm.discretise.points import Particles
from fem_rmpm.materials import MaterialPoints, strength
from fem_rmpm.scene import Scene, with_values
from fem_rmpm.schemes.common import SimulationError
from fem_rmpm.schemes.implicit.linear import LinearSolver
from fem_rmpm.schemes.implicit.newton import NewtonFailure, newton
from fem_rmpm.schemes.implicit.steps import Geostatic, ImplicitSystem, StepOutcome
from fem_rmpm.schemes.pore_pressure import scaled_water
from fem_rmpm.schemes.regularisation import average_softening

__all__ = ["FSOptions", "Trial", "KnownFailures", "reduce_strength", "gravity_solve",
           "continue_strength", "srm_scene"]


@dataclass(frozen=True)
class FSOptions:
    """Settings of the strength reduction (not of the scene's MPM run)."""
    tolerance: float = 0.005      # relative bracket width F_hi / F_lo - 1 at which to stop
    f_min: float = 0.1            # below: "FS < f_min"
    f_max: float = 10.0           # above: "FS > f_max"
    softening: bool = False       # False: peak strength, perfectly plastic (RFEM practice)
    load_steps: int = 4           # equal gravity increments per trial
    max_iterations: int = 20      # Newton iterations per (sub)step: the failure criterion
    max_cuts: int = 1             # halvings of a load step before the trial fails
    newton_tolerance: float = 1e-8  # relative residual
    fbar: bool = True             # B-bar against volumetric locking
    probe_load: float = 1e-3      # gravity fraction of the elastic probe at F = 1
    linear_solver: str = "cholmod"  # the implicit scheme's policy (SuperLU where not SPD)
    continuation: bool = True     # a trial starts from the largest converged F's state
    march: float = 1.25           # first upward ratio of F from a converged state (doubles in ln F)
    decisive_change: float = 0.015  # a continuation solve failing over a change of F of at
    #                                 most this (relative) fails the trial; over more: not
    line_search: str = "energy"   # Newton's line search: "energy" (the energy's directional
    #                               derivative) or "residual" (backtracking on the residual norm)
    diverging: float = 10.0       # a solve fails as diverging once its residual exceeds
    #                               this times the gravity load's norm (the energy line
    #                               search past collapse; the implicit scheme: 1000)
    growth_rejection: float = 1.5   # "residual" line search: reject a continuation solve whose
    #                                 residual grows to this times its smallest earlier one
    #                                 (0: never)


@dataclass
class Trial:
    """One static solve at a trial factor ``F``."""
    F: float
    converged: bool
    max_displacement: float       # m, last converged state (at load_factor)
    load_factor: float            # gravity fraction reached (1 when converged)
    iterations: int
    cuts: int
    wall_time: float              # s
    reason: str = ""              # why Newton failed ("" when converged)
    start: float = 0.0            # F of the converged state it continued from (0: gravity
    #                               from zero)
    reached: float = 0.0          # continuation: F of its last converged solve (= F if converged)
    failed_at: float = math.inf   # F when the trial failed decisively (an upper bound of
    #                               FS), else inf


def reduce_strength(pts: Particles, scene: Scene, F: float, softening: bool = False) -> None:
    """Reduce the strengths of ``pts`` (in place) by the trial factor ``F``, each point as
    its material model declares (:func:`fem_rmpm.materials.strength.reduce_strength`:
    e.g. ``c / F`` and ``atan(tan(phi) / F)``).  Without ``softening`` the residual
    strengths are set to the reduced peak (perfectly plastic).  Elastic points keep
    c = inf.  ``scene`` is not read (kept for the callers' signature)."""
    s = pts.soil
    params = s.params.copy()
    for k in np.unique(s.model):
        mask = s.model == k
        params[mask] = strength.reduce_strength(int(k), params[mask], F, softening)
    pts.soil = MaterialPoints(s.model, params)


def srm_scene(scene: Scene, o: FSOptions) -> Scene:
    """The scene with the solver settings of the search's static solves."""
    return with_values(scene, {
        "solver.scheme": "implicit", "solver.dynamic": False,
        "solver.gravity_phase": "geostatic", "solver.load_steps": o.load_steps,
        "solver.max_iterations": o.max_iterations, "solver.max_cuts": o.max_cuts,
        "solver.tolerance": o.newton_tolerance, "solver.fbar": o.fbar,
        "solver.linear_solver": o.linear_solver,
        "solver.adaptive": False})         # fixed load steps: the criterion stays as stated


def _max_displacement(pts: Particles) -> float:
    """Largest point displacement magnitude (m) of the geostatic state."""
    return float(np.sqrt(np.max(np.sum(pts.u_geostatic ** 2, axis=1), initial=0.0)))


def gravity_solve(scene: Scene, grid: Grid, base: Particles, F: float, o: FSOptions,
                  load: float = 1.0, known: "KnownFailures | None" = None
                  ) -> tuple[Trial, Particles]:
    """Apply ``load`` x gravity at trial factor ``F`` on a copy of ``base`` (``scene``:
    :func:`srm_scene`): in one geostatic Newton solve first, and where that fails in
    ``[solver] load_steps`` geostatic load steps, each halved up to ``[solver] max_cuts``
    times while Newton fails (the implicit scheme's geostatic phase,
    :func:`~fem_rmpm.schemes.implicit.driver.run_implicit`, with ``adaptive = false``).
    Either converged solve is an equilibrium at full gravity within the reduced
    strengths, so the slope stands at ``F``; the load steps decide a failure and the
    gravity fraction it reached.  On the system and linear solver the search shares
    (``known``).  ``Trial.iterations`` counts the Newton iterations of both."""
    known = KnownFailures() if known is None else known
    pts = base.copy()
    reduce_strength(pts, scene, F, o.softening)
    if load != 1.0:
        pts.mass = pts.mass * load
        scene = scaled_water(scene, load)        # pore water: its force follows the load
    t0 = time.perf_counter()
    system = ImplicitSystem(scene, grid, pts, known.solver(scene.solver.linear_solver),
                            pattern_cache=known.patterns)
    energy, sv = o.line_search == "energy", scene.solver
    its0 = 0
    if sv.load_steps > 1:                 # full gravity at once: the one solve's cost
        reason, _, its0, _ = _load_steps(Geostatic(system), 1, 0, energy, o.diverging)
        if not reason:
            return Trial(F, True, _max_displacement(pts), 1.0, its0, 0,
                         time.perf_counter() - t0), pts
    reason, pos, its, cuts = _load_steps(Geostatic(system), sv.load_steps, sv.max_cuts,
                                         energy, o.diverging)
    its += its0
    return Trial(F, not reason, _max_displacement(pts), 1.0 if not reason else pos, its, cuts,
                 time.perf_counter() - t0, reason), pts


def _load_steps(kind: Geostatic, n: int, max_cuts: int, energy: bool,
                diverging: float) -> tuple[str, float, int, int]:
    """Gravity from 0 to 1 in ``n`` equal steps; a step Newton cannot converge is halved
    (the rest of its load step goes on at the halved size), at most ``max_cuts`` times.
    Returns Newton's reason of the failure ("" when full gravity is reached), the
    gravity fraction reached, the Newton iterations (of the failed attempts too) and
    the cuts.  A failed attempt changes nothing: a step is committed once converged."""
    its = cuts_total = 0
    for k in range(n):
        pos, end = k / n, (k + 1) / n
        h = 1.0 / n
        while pos < end - 1e-12:
            h = end - pos if end - pos < 1.05 * h else h     # no sliver before the end
            cuts = 0
            while True:
                try:
                    out = _solve(kind, pos, pos + h, 0.0, energy, diverging)
                    break
                except NewtonFailure as f:
                    reason = f.reason
                    its += max(len(f.residuals) - 1, 0)
                except SimulationError as exc:
                    reason = str(exc)
                if cuts >= max_cuts:
                    return reason, pos, its, cuts_total
                cuts += 1
                cuts_total += 1
                h *= 0.5
            out.commit()
            average_softening(kind.sys.grid, kind.sys.pts)   # staggered non-local softening
            its += out.result.iterations
            pos += h
    return "", 1.0, its, cuts_total


def _solve(kind: Geostatic, lf_old: float, lf_new: float, growth: float,
           energy: bool, diverging: float = 1e3) -> StepOutcome:
    """One geostatic Newton solve from gravity factor ``lf_old`` to ``lf_new`` (as
    :meth:`Geostatic.solve`; ``energy``: the energy line search of
    :func:`~fem_rmpm.schemes.implicit.newton.newton`), rejected with a
    :class:`NewtonFailure` once the residual of an accepted iterate exceeds ``growth``
    times the smallest residual of the iterates before it (``growth <= 0``: never).  The
    check runs where Newton asks for the tangent, i.e. on the accepted iterate only (the
    line search's last evaluation), before the tangent is built.  ``diverging``: the
    relative residual at which Newton gives up as diverging."""
    sys_ = kind.sys
    sv = sys_.sv
    st = sys_.begin(lf_new, lf_old)
    du0 = kind.predictor(st)
    sys_.solver.new_step()
    norms: list[float] = []
    last = {}

    def evaluate(du):
        R, ref, state = kind.residual(st, du)
        last["r"], last["ref"] = float(np.linalg.norm(R)), ref
        return R, ref, state

    def tangent():
        r = last["r"]
        if growth > 0 and norms and r > growth * min(norms):
            ref0 = max(last["ref"], norms[0]) or 1.0
            raise NewtonFailure(f"residual grew {r / min(norms):.3g}-fold above its "
                                f"smallest (rejected at {growth:g})",
                                [x / ref0 for x in norms + [r]])
        norms.append(r)
        return kind.tangent(st)

    res = newton(evaluate, tangent, du0, sys_.solver, sv.max_iterations, sv.tolerance,
                 modes=st.S.rigid_body_modes, energy=energy, diverging=diverging)
    return StepOutcome(res, lambda: kind.commit(st, res))


def continue_strength(scene: Scene, grid: Grid, base: Particles, start: Particles, F0: float,
                      F: float, o: FSOptions, known: "KnownFailures | None" = None,
                      start_id: int = 0) -> tuple[Trial, Particles, int]:
    """Strength continuation: from ``start``, the converged state at full gravity and
    trial factor ``F0``, the strengths of ``base`` are reduced to ``F`` at full gravity in
    one small-strain geostatic Newton solve.

    A solve that fails over a change of at most ``decisive_change`` (1.5 %) fails the
    trial at ``F`` (``Trial.failed_at = F``); one that fails over a larger change does not
    decide it (``failed_at = inf``): over a large change Newton fails below FS at times
    (the undrained infinite slope z = 2.5 m, beta = 20 deg: FS -5.3 % when any failed
    solve bounded FS), and the search then moves closer
    (:func:`~fem_rmpm.schemes.implicit.strength_reduction.factor_of_safety`).  The
    collapse factor of a perfectly plastic soil does not depend on the path (associated
    flow: the limit theorems), so this finds the same FS as applying gravity anew at
    every trial, at a fraction of the cost.

    ``known`` (:class:`KnownFailures`): the solves that failed, by the identity of their
    start state (``start_id`` for ``start``) and their target; such a solve is not run
    again.  Returns the trial, its state (``start``'s when it failed) and that state's
    identity."""
    known = KnownFailures() if known is None else known
    t0 = time.perf_counter()
    its, target = 0, math.log(F)
    reason = known.get(start_id, target)
    pts, state_id = start, start_id
    if reason is None:
        pts = start.copy()
        system = ImplicitSystem(scene, grid, pts, known.solver(o.linear_solver),
                                pattern_cache=known.patterns)
        pts.soil = base.soil
        reduce_strength(pts, scene, F, o.softening)
        try:
            energy = o.line_search == "energy"
            out = _solve(Geostatic(system), 1.0, 1.0, 0.0 if energy else o.growth_rejection,
                         energy, o.diverging)
        except NewtonFailure as exc:
            its, reason = max(len(exc.residuals) - 1, 0), known.add(start_id, target,
                                                                   exc.reason)
            pts = start
        else:
            out.commit()
            its, reason, state_id = out.result.iterations, "", known.new_state()
    decisive = F / F0 - 1.0 <= o.decisive_change * (1 + 1e-9)
    failed_at = math.inf if not reason or not decisive else F
    return Trial(F, not reason, _max_displacement(pts), 1.0, its, 0,
                 time.perf_counter() - t0, reason, F0, F if not reason else F0,
                 failed_at), pts, state_id


class KnownFailures:
    """The continuation solves of one search that failed: ``(start state, target ln F)``
    -> Newton's reason; the start states are numbered (:meth:`new_state`) as the search
    converges them, so a solve is known only from the very state it started from.  Also
    holds what the search's solves share on the fixed geometry: the StepSystem (basis,
    DOF numbering, sparsity pattern) and the linear solver (its symbolic factorization)."""

    def __init__(self):
        self._failed: dict = {}
        self._states = 0
        self.patterns: dict = {}
        self._solvers: dict = {}

    def solver(self, kind: str) -> LinearSolver:
        if kind not in self._solvers:
            self._solvers[kind] = LinearSolver(kind)
        return self._solvers[kind]

    def new_state(self) -> int:
        self._states += 1
        return self._states

    @staticmethod
    def _key(state_id: int, target: float):
        return state_id, round(target, 12)

    def get(self, state_id: int, target: float) -> str | None:
        return self._failed.get(self._key(state_id, target))

    def add(self, state_id: int, target: float, reason: str) -> str:
        self._failed[self._key(state_id, target)] = reason
        return reason

    def lowest_failed_above(self, F: float) -> float:
        """The smallest target F of a failed solve above ``F`` (from any start state;
        ``inf`` if none): where the search looks next, not a bound of FS (a solve over a
        large change can fail below FS)."""
        above = [t for _, t in self._failed if t > math.log(F) + 1e-12]
        return math.exp(min(above)) if above else math.inf
