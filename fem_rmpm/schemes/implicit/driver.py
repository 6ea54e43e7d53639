"""The implicit run: phases, step cutting, output, at-rest test and the run record.

One driver serves every step kind (:mod:`fem_rmpm.schemes.implicit.steps`): :meth:`_Run.advance`
covers an interval of load factor or time with converged steps, halving a step that
fails up to ``max_cuts`` times, and records each step.  The at-rest test and the
:class:`~fem_rmpm.schemes.common.RunRecord` are the explicit scheme's
(:mod:`fem_rmpm.schemes.common`).
"""
from __future__ import annotations

import math
import time

from fem_rmpm.discretise.grid import Grid
from fem_rmpm.discretise.points import Particles
from fem_rmpm.scene import Scene
from fem_rmpm.schemes.common import RunRecord, SimulationError, at_rest, check_points
from fem_rmpm.schemes.implicit.control import DET_BOUNDS, StepController, Verdict
from fem_rmpm.schemes.implicit.linear import LinearSolver
from fem_rmpm.schemes.implicit import step_kernels as sk
from fem_rmpm.schemes.implicit.newton import NewtonFailure
from fem_rmpm.schemes.implicit.dynamic import NewmarkDynamic
from fem_rmpm.schemes.implicit.steps import (
    Geostatic,
    ImplicitSystem,
    QuasiStatic,
    StepKind,
)
from fem_rmpm.schemes.regularisation import average_softening

__all__ = ["run_implicit"]

MAX_REJECTIONS = 6          # a step rejected this often by the kinematic limits is taken


def _advice(kind: StepKind, sv) -> str:
    if kind.dynamic:
        return (f"reduce [solver] dt (now {sv.dt:g} s) or max_displacement_fraction (now "
                f"{sv.max_displacement_fraction:g}), add hht_alpha damping (now "
                f"{sv.hht_alpha:g}), increase max_iterations (now "
                f"{sv.max_iterations}) or max_cuts (now {sv.max_cuts}), or loosen tolerance "
                f"(now {sv.tolerance:g}); a residual that stalls at a level points to a kink "
                "in the material response (softening reaching the residual cohesion): "
                "softening = \"exponential\" is smooth")
    return (f"increase [solver] load_steps (now {sv.load_steps}), max_iterations (now "
            f"{sv.max_iterations}) or max_cuts (now {sv.max_cuts}), or loosen tolerance (now "
            f"{sv.tolerance:g}); a residual that stalls instead of falling quadratically means "
            "the soil cannot carry the load (limit load reached): run it with dynamic = true; "
            "with a softening soil it can also be a snap-back (a one-cell local softening band "
            "dissipates less than the specimen's elastic energy releases, worse on finer "
            "cells): regularisation = \"nonlocal\" widens the band")


def _solver_stats(sv) -> dict:
    return {"formulation": "updated Lagrangian, Hencky/Kirchhoff, full Newton-Raphson",
            "time_integration": (f"Newmark HHT-alpha (alpha {sv.hht_alpha:g}), lumped mass"
                                 if sv.hht_alpha > 0 else
                                 "Newmark trapezoidal (beta 1/4, gamma 1/2), lumped mass")
            if sv.dynamic else "quasi-static load stepping",
            "linear_solver": sv.linear_solver, "tolerance": sv.tolerance,
            "displacement_tolerance": math.sqrt(sv.tolerance),
            "max_iterations": sv.max_iterations, "max_cuts": sv.max_cuts,
            "iterations_total": 0, "factorizations_total": 0, "cuts_total": 0,
            "setup_time": 0.0, "material_time": 0.0,
            "assembly_time": 0.0, "solve_time": 0.0, "predictor_time": 0.0,
            "commit_time": 0.0, "rejected_total": 0, "limited_by": {},
            "adaptive": bool(sv.adaptive), "limits": {
                "max_displacement_fraction": sv.max_displacement_fraction,
                "det_dF_bounds": list(DET_BOUNDS), "dt": sv.dt, "dt_max": sv.dt_max,
                "dt_min": sv.dt * 0.5 ** sv.max_cuts},
            "hht_alpha": sv.hht_alpha, "min_mass_fraction": sv.min_mass_fraction,
            "steps": []}


class _Run:
    """State of one implicit run: record, statistics, output bookkeeping."""

    def __init__(self, scene: Scene, grid: Grid, pts: Particles, on_output, progress):
        self.sv, self.grid, self.pts = scene.solver, grid, pts
        self.on_output, self.progress = on_output, progress
        self.rec = RunRecord(scheme="implicit")
        self.stats = self.rec.solver = _solver_stats(self.sv)
        self.system = ImplicitSystem(scene, grid, pts, LinearSolver(self.sv.linear_solver))
        self.wall0 = time.perf_counter()
        self.t, self.step, self.written_t = 0.0, 0, None

    def output(self, t: float) -> None:
        if self.on_output is not None:
            self.on_output(t, self.pts)
        self.written_t = t

    def fail(self, kind: StepKind, label: str, failure: NewtonFailure, n_cuts: int,
             size: float):
        """Stop loudly; the points hold the last converged state: write it if not yet."""
        sv, stats, rec = self.sv, self.stats, self.rec
        if self.written_t is None or self.written_t != self.t:
            self.output(self.t)
        hist = ", ".join(f"{r:.2e}" for r in failure.residuals) or "none"
        msg = (f"{label}: Newton did not converge after {n_cuts} cut(s) down to a step of "
               f"{size:.4g} ({failure.reason}); relative residuals of the last attempt: "
               f"[{hist}] (tolerance {sv.tolerance:g}). Output holds the last converged "
               f"state (step {self.step}). To go on: {_advice(kind, sv)}")
        stats.update(last_converged_step=self.step, last_converged_time=self.t,
                     failed_step=label, failed_residuals=failure.residuals)
        rec.steps, rec.time = self.step, self.t
        rec.error, rec.stop_reason = msg, "error"
        rec.wall_time = time.perf_counter() - self.wall0
        exc = SimulationError(msg)
        exc.solver_stats = stats          # merged into summary.json by api.run
        exc.record = rec                  # the record up to the last converged step
        raise exc

    def record_step(self, kind: StepKind, res, pos: float, h: float, cuts: int,
                    info: dict, verdict: Verdict, limits: dict) -> None:
        stats = self.stats
        self.step += 1
        stats["iterations_total"] += res.iterations
        stats["factorizations_total"] += res.factorizations
        for k in ("assembly", "material", "setup", "solve", "predictor"):
            stats[f"{k}_time"] += getattr(res, f"t_{k}", 0.0)
        entry = {"step": self.step, "phase": kind.name,
                 ("time" if kind.dynamic else "load_factor"): pos,
                 "size": h, "iterations": res.iterations,
                 "factorizations": res.factorizations, "cuts": cuts,
                 "residuals": res.residuals}
        if limits:
            entry.update(displacement=limits["displacement"], det_min=limits["det_min"],
                         det_max=limits["det_max"])
        if verdict.limited_by:
            entry["limited_by"] = verdict.limited_by
            lb = stats["limited_by"]
            lb[verdict.limited_by] = lb.get(verdict.limited_by, 0) + 1
        if info.get("floor_mass_nodes"):
            entry["floor_mass_nodes"] = info["floor_mass_nodes"]
        if "reactions" in info:
            entry["reactions"] = info.pop("reactions")
        stats["steps"].append(entry)

    def attempt(self, kind: StepKind, pos: float, h: float, label: str, gravity_of,
                ctl: StepController, clipped: bool):
        """One step from ``pos``: halved while Newton fails (``max_cuts`` times, then the
        run stops), redone smaller while the controller rejects it.  Returns the outcome,
        the size taken, the cuts, the verdict and the kinematic figures."""
        cuts = rejections = 0
        while True:
            try:
                out = kind.solve(gravity_of(pos), gravity_of(pos + h),
                                 h if kind.dynamic else 0.0)
            except NewtonFailure as f:
                if cuts >= self.sv.max_cuts:
                    self.fail(kind, label(pos, h), f, cuts, h)
                cuts += 1
                self.stats["cuts_total"] += 1
                h, clipped = 0.5 * h, False
                continue
            t0 = time.perf_counter()
            limits = out.limits() if kind.dynamic else {}
            self.stats["commit_time"] += time.perf_counter() - t0
            verdict = ctl.judge(h, out.result.factorizations, limits, clipped)
            if verdict.accept or rejections >= MAX_REJECTIONS:
                return out, h, cuts, verdict, limits
            rejections += 1
            self.stats["rejected_total"] += 1
            h, clipped = min(verdict.size, h), False

    def advance(self, kind: StepKind, a0: float, a1: float, label, time_of, gravity_of,
                ctl: StepController):
        """Cover [a0, a1] (load factor or time) with converged steps of the controller's
        size; yields the ``info`` of each converged step.  ``label(pos, h)`` names a step
        in an error message."""
        pos, size = a0, ctl.size
        while pos < a1 - 1e-12 * max(1.0, abs(a1)):
            h = min(size, a1 - pos)
            if a1 - pos < 1.05 * size:         # no sliver of a step before a1
                h = a1 - pos
            out, h, cuts, verdict, limits = self.attempt(kind, pos, h, label, gravity_of,
                                                         ctl, h < 0.999 * size)
            t0 = time.perf_counter()
            info = out.commit() or {}
            average_softening(self.grid, self.pts)    # staggered non-local softening
            pos += h
            size = verdict.size if ctl.adaptive else (h if cuts else size)
            self.t = time_of(pos)
            self.record_step(kind, out.result, pos, h, cuts, info, verdict, limits)
            self.check_points()
            self.stats["commit_time"] += time.perf_counter() - t0
            yield info

    def check_points(self) -> None:
        """The point check after a step (:func:`fem_rmpm.schemes.common.check_points`: a
        non-finite state stops the run, a point off the grid is frozen or stops it), run
        only when one compiled pass over the points finds something to report."""
        pts, lo, hi = self.pts, self.grid.origin, self.grid.upper
        if not sk.points_fine(pts.active, pts.x, pts.velocity, pts.stress, float(lo[0]),
                              float(lo[1]), float(hi[0]), float(hi[1])):
            check_points(self.grid, pts, self.step, self.t, self.sv.edge_policy, self.rec)

    # -- phases
    def load_phase(self) -> None:
        """Gravity in ``load_steps`` geostatic or quasi-static steps; quasi-static output
        after the load steps that reach the next ``output_interval`` (in units of
        ``t_end`` x load factor) and after the last."""
        sv, n_ls = self.sv, self.sv.load_steps
        quasi = not sv.dynamic
        geo = sv.gravity_phase == "geostatic"
        kind = Geostatic(self.system) if geo else QuasiStatic(self.system)
        ctl = StepController(sv, False, 1.0 / n_ls, 1.0 / n_ls, 0.5 ** sv.max_cuts / n_ls)
        next_out = sv.output_interval / sv.t_end
        for k in range(n_ls):
            a0, a1 = k / n_ls, (k + 1) / n_ls
            text = (f"{'geostatic' if geo else 'load'} step {k + 1} of {n_ls} "
                    f"(load factor {a0:.4g} -> {a1:.4g})")
            for _ in self.advance(kind, a0, a1, lambda p, h: text,
                                  (lambda p: p if quasi else 0.0), lambda p: p, ctl):
                if quasi and self.progress:
                    self.progress(self.t * sv.t_end, self.step)
            if quasi and (a1 >= next_out - 1e-12 or k == n_ls - 1):
                self.output(self.t)
                while next_out <= a1 + 1e-12:
                    next_out += sv.output_interval / sv.t_end
        if geo:
            self.stats["geostatic_steps"] = self.step
        self.rec.time = 1.0 if quasi else 0.0
        self.rec.stop_reason = "load applied" if quasi else ""

    def dynamic_phase(self) -> None:
        """Newmark (HHT-alpha) steps of adaptive size until ``t_end`` or at rest; output
        every ``output_interval`` (the steps are shortened to meet the output times)."""
        sv, rec = self.sv, self.rec
        if sv.gravity_phase == "geostatic":
            self.t = 0.0
            self.output(0.0)
        ramp = 0.0 if sv.gravity_phase == "geostatic" else sv.gravity_ramp_time

        def gravity_of(t):
            return 1.0 if ramp <= 0 else min(1.0, t / ramp)

        def label(pos, h):
            n = self.step - self.stats.get("geostatic_steps", 0)
            return f"time step {n + 1} (t = {pos:.4g} -> {pos + h:.4g} s)"

        kind = NewmarkDynamic(self.system)
        ctl = StepController(sv, True, sv.dt, max(sv.dt_max, sv.dt) if sv.adaptive else sv.dt,
                             sv.dt * 0.5 ** sv.max_cuts)
        t, next_out, ke_peak, rest = 0.0, sv.output_interval, 0.0, False
        rec.stop_reason = "t_end reached"
        while t < sv.t_end - 1e-12 and not rest:
            for info in self.advance(kind, t, min(next_out, sv.t_end), label, lambda p: p,
                                     gravity_of, ctl):
                h = self.stats["steps"][-1]["size"]
                rec.dt_min, rec.dt_max = min(rec.dt_min, h), max(rec.dt_max, h)
                ke = info.get("kinetic_energy", 0.0)
                ke_peak = max(ke_peak, ke)
                rec.energy.append((self.t, ke))
                if self.progress:
                    self.progress(self.t, self.step)
                rest = at_rest(self.t, ramp, info.get("max_speed", 0.0), ke, ke_peak,
                               sv.rest_velocity, sv.rest_energy_ratio)
                if rest:
                    break
            t = self.t
            if t >= next_out - 1e-12:
                self.output(t)
                next_out += sv.output_interval
        if rest:
            rec.stop_reason = "at rest"
        rec.time = t
        if self.written_t != t:
            self.output(t)

    def finish(self) -> RunRecord:
        stats = self.stats
        its = stats["iterations_total"]
        stats["ms_per_iteration"] = {k: 1e3 * stats[f"{k}_time"] / max(its, 1)
                                     for k in ("setup", "material", "assembly", "solve")}
        steps = stats["steps"]
        stats["ms_per_step"] = {k: 1e3 * stats[f"{k}_time"] / max(len(steps), 1)
                                for k in ("setup", "predictor", "material", "assembly",
                                          "solve", "commit")}
        stats["factorizations_per_step"] = stats["factorizations_total"] / max(len(steps), 1)
        stats["max_iterations_in_a_step"] = max((s["iterations"] for s in steps), default=0)
        stats["n_steps"] = len(steps)
        stats["iterations_per_step"] = its / max(len(steps), 1)
        stats["dt_history"] = [[s["time"], s["size"]] for s in steps if "time" in s]
        solver = self.system.solver
        stats["factorizations_by"] = dict(solver.factorizations_by)
        stats["symbolic_analyses"] = solver.symbolic_analyses
        self.rec.steps = self.step
        self.rec.wall_time = time.perf_counter() - self.wall0
        return self.rec


def run_implicit(scene: Scene, grid: Grid, pts: Particles, on_output=None,
                 progress=None) -> RunRecord:
    """Run the implicit scheme on ``pts`` (in place) and return its :class:`RunRecord`.

    Phases: ``gravity_phase = "geostatic"`` first applies gravity in ``load_steps``
    small-strain steps on the fixed geometry; then with ``dynamic = true`` Newmark steps
    of ``dt`` run under gravity (ramped over ``gravity_ramp_time`` unless the geostatic
    phase applied it) until ``t_end`` or at rest (:func:`fem_rmpm.schemes.common.at_rest`: max point
    speed < ``rest_velocity`` and grid kinetic energy <= ``rest_energy_ratio`` x its peak,
    gravity fully on).  With ``dynamic = false`` and ``gravity_phase = "dynamic"``
    gravity is applied in ``load_steps`` quasi-static large-deformation steps.

    ``on_output(t, pts)``: quasi-static, at the start and after every converged load step
    with ``t`` = the load factor (0..1); dynamic, at t = 0 (after the geostatic phase, if
    any), every ``output_interval`` and at the end.  ``progress(t, step)``: ``t`` is the
    simulated time, or for quasi-static steps the load factor times ``t_end``.
    ``record.solver["steps"]`` lists every converged step with its residual history.
    Raises :class:`~fem_rmpm.schemes.common.SimulationError` (with ``solver_stats``) when a step
    cannot be converged; the points then hold the last converged state, which has been
    passed to ``on_output``.
    """
    sv = scene.solver
    run = _Run(scene, grid, pts, on_output, progress)
    if not (sv.dynamic and sv.gravity_phase == "geostatic"):
        run.output(0.0)
    if sv.gravity_phase == "geostatic" or not sv.dynamic:
        run.load_phase()
    if sv.dynamic:
        run.dynamic_phase()
    return run.finish()
