"""Factor of safety by strength reduction (Griffiths & Lane 1999), on the in-situ geometry.

**Method.**  The strengths of every soil are divided by a trial factor ``F`` and gravity is
applied with the implicit solver's small-strain static load steps on the fixed in-situ
geometry (``gravity_phase = "geostatic"``, quasi-static, exactly what an RFEM analysis
does).  The factor of safety ``FS`` is the smallest ``F`` at which full gravity can no
longer be brought to equilibrium.  How a soil's strengths reduce is declared by its
material model (``STRENGTHS``, :mod:`fem_rmpm.materials.strength`): e.g. ``c / F`` for a
cohesion, ``tan(phi_F) = tan(phi) / F`` for a friction angle, a dilation angle at most
the reduced friction angle.  Peak strength by default (RFEM practice: every residual
strength is set to the reduced peak, a perfectly plastic soil); ``softening=True`` keeps
the softening law with peak and residual reduced alike.

**Failure criterion** (documented in ``fs.json`` as ``criterion``).  The first trial,
``F = 1``, applies gravity in ``load_steps`` small-strain load steps; it *fails* when
Newton does not converge within ``max_iterations`` iterations in some load step even after
``max_cuts`` halvings of that step, i.e. before full gravity is reached.  Every later
trial (``continuation = True``, the default) starts from the converged state of the
largest converged ``F`` at full gravity and reduces the strengths further to the trial
``F`` in Newton solves (:func:`_continue`); it fails when a solve does not converge
within ``max_iterations`` even after ``continuation_cuts`` (2) halvings of the change.
Either failure is accompanied by the jump of the maximum point displacement, which grows
without bound as ``F`` approaches ``FS`` from below (the plot ``fs_displacement.png``
shows it, the ratio of the last converged maximum displacement to that of the smallest
trial ``F`` is ``displacement_jump`` in ``fs.json``).  ``FS`` lies in the bracket
``[F_lo, F_hi]`` of the largest converged and the smallest failed trial.

**Search.**  From ``F = 1`` upwards ``F`` grows by ``march`` (1.25), the step in ``ln F``
doubling after each converged trial, until a trial fails or ``f_max`` (10) converges
("FS > 10"); when ``F = 1`` fails, gravity is applied anew at the gravity fraction ``F = 1``
reached (a lower bound of FS: at ``F = lambda`` every strength is at least that of the
state that stood at ``lambda`` x gravity), or at ``f_min`` (0.1; failing there: "FS <
0.1").  Then bisection in ``ln F`` until ``F_hi / F_lo - 1 <= tolerance`` (default 0.01);
the reported FS is the geometric midpoint, so the search error is below ``tolerance / 2``.
With ``continuation = False`` gravity is applied anew at every trial (``F = 1``,
``f_max`` or ``f_min``, then bisection): the same FS within the bracket, at more cost (a
failed continued trial costs up to three solves, its halvings, but every converged one
only a few Newton iterations).

**Cost.**  The solves of one search share what the fixed geometry fixes (the
:class:`~fem_rmpm.schemes.implicit.assembly.StepSystem`: basis, DOF numbering, sparsity
pattern; and the linear solver with its symbolic factorization, :class:`KnownFailures`);
the tangent is factorized by CHOLMOD (``linear_solver = "cholmod"``, the implicit
scheme's policy: SuperLU for a tangent that is not symmetric positive definite); a
continuation solve known to fail (same start state, same target) is not run again.
None of these changes a decision of the search.

**Non-physical Newton failures** are told apart and raised as :class:`NonPhysicalFailure`
(never taken as an FS): before the search a *probe* applies ``probe_load`` (1e-3) x gravity
in one step at ``F = 1``, an elastic response which must converge in one step (a failed
linear solve there is a singular elastic tangent: a mesh or boundary problem; a diverging
first iteration is a broken material or solver); and a trial that ends in a non-finite
residual or in a failed linear solve (a singular tangent, or a non-finite solution) is not
a mechanism either: a collapse shows as Newton not converging (the residual stalls or
grows), while a singular tangent means the solver could not resolve the state at all
(e.g. a drained layer whose free end faces fail first, at trial strengths far above the
soil's).  Such a trial stops the search with the numerical cause and no FS.

**Discretisation.**  A displacement-based mesh overestimates the collapse load: a shear
band cannot be thinner than one element row, so a sliding surface along the bedrock sits
about half a cell above it (infinite slope: ``FS_h / FS = z / (z - h/2)`` for a layer of
normal thickness ``z`` and cells of height ``h``).  Volumetric locking of Q4 under
isochoric plastic flow is removed with B-bar (``fbar = True``, the default here).
"""
from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from fem_rmpm.discretise.contact import refuse_frictional
from fem_rmpm.discretise.grid import Grid
from fem_rmpm.discretise.points import Particles
from fem_rmpm.io.output import to_true_frame, write_json, write_particles
from fem_rmpm.io.plots import _plt, plot_field
from fem_rmpm.io.rundir import check_run_dir
from fem_rmpm.materials import MaterialPoints, strength
from fem_rmpm.runtime.errors import InputError
from fem_rmpm.scene import Scene, SceneError, with_values
from fem_rmpm.schemes.common import SimulationError
from fem_rmpm.schemes.pore_pressure import scaled_water
from fem_rmpm.schemes.implicit import (
    Geostatic,
    ImplicitSystem,
    LinearSolver,
    NewtonFailure,
    run_implicit,
)

__all__ = ["FSOptions", "Trial", "FSResult", "NonPhysicalFailure", "strength_parameters",
           "reduce_strength", "factor_of_safety", "stable_at", "write_outputs"]

#: Newton failure reasons that are never a mechanism (substrings of the solver's message):
#: a non-finite residual, and a failed linear solve (singular tangent or non-finite
#: solution, :class:`~fem_rmpm.schemes.implicit.linear.LinearSolveError`).
_NON_PHYSICAL = ("non-finite residual", "linear solve failed")


class NonPhysicalFailure(SimulationError):
    """Newton failed for a reason that is not the soil's collapse (``cause`` says which)."""

    def __init__(self, msg: str, cause: str, result: "FSResult | None" = None):
        super().__init__(msg)
        self.cause, self.result = cause, result


@dataclass(frozen=True)
class FSOptions:
    """Settings of the strength reduction (not of the scene's MPM run)."""
    tolerance: float = 0.01       # relative bracket width F_hi / F_lo - 1 at which to stop
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
    continuation_cuts: int = 2    # halvings of a continuation solve before the trial fails


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


@dataclass
class FSResult:
    """Outcome of :func:`factor_of_safety`.

    ``fs`` is the factor of safety (the geometric midpoint of the bracket); for a censored
    result (``bound`` ">" or "<") it is the bound itself (``f_max`` or ``f_min``).  ``text``
    is what to print ("FS = 1.47", "FS > 10", "FS < 0.1")."""
    fs: float
    bound: str                    # "=" | ">" | "<"
    bracket: tuple[float, float]  # (largest converged F, smallest failed F); inf / 0 if none
    trials: list[Trial]
    options: FSOptions
    wall_time: float
    seed: int | None = None
    displacement_jump: float = float("nan")
    mechanism: Particles | None = field(default=None, repr=False)  # state at the bracket's F_lo
    grid: Grid | None = field(default=None, repr=False)

    @property
    def text(self) -> str:
        if self.bound == ">":
            return f"FS > {self.fs:g}"
        if self.bound == "<":
            return f"FS < {self.fs:g}"
        return f"FS = {self.fs:.3f}"

    @property
    def static_solves(self) -> int:
        return len(self.trials)

    def to_dict(self) -> dict:
        o = self.options
        return {"fs": self.fs, "bound": self.bound, "text": self.text,
                "bracket": list(self.bracket), "tolerance": o.tolerance, "seed": self.seed,
                "static_solves": self.static_solves, "wall_time": self.wall_time,
                "displacement_jump": self.displacement_jump,
                "strength": "softening" if o.softening else "peak",
                "criterion": CRITERION.format(
                    it=o.max_iterations, cuts=o.max_cuts, steps=o.load_steps,
                    cont=CONTINUED.format(it=o.max_iterations, cuts=o.continuation_cuts)
                    if o.continuation else ""),
                "options": dataclasses.asdict(o),
                "trials": [dataclasses.asdict(t) for t in self.trials]}


CRITERION = ("a trial F fails when Newton does not converge within {it} iterations in a "
             "load step after {cuts} halvings of it, before full gravity is reached "
             "({steps} small-strain load steps on the in-situ geometry){cont}; FS is the "
             "geometric midpoint of the largest converged and the smallest failed F")
CONTINUED = (", or, for a trial continued from the converged state of a smaller F at full "
             "gravity, when the Newton solve reducing the strengths towards F does not "
             "converge within {it} iterations after {cuts} halvings of the change")


# ----------------------------------------------------------------------------- strengths
def strength_parameters(model: str) -> tuple[str, ...]:
    """The per-point parameters of material ``model`` that a strength reduction scales by
    ``F``, as the model declares them (:func:`fem_rmpm.materials.strength.strength_parameters`)."""
    return strength.strength_parameters(model)


def _check_has_strength(scene: Scene) -> None:
    if not any(strength.has_strength(s) for s in scene.soils):
        models = ", ".join(sorted({s.model for s in scene.soils}))
        declared = " | ".join(f'"{m}"' for m in strength.models_with_strength())
        raise SceneError(f"{scene.source}: [soil.model] no soil has a strength to reduce "
                         f"(models: {models}); allowed for a factor of safety: a soil whose "
                         f"model declares a strength ({declared}) with a finite value of it")


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


# ----------------------------------------------------------------------------- trials
def _srm_scene(scene: Scene, o: FSOptions) -> Scene:
    return with_values(scene, {
        "solver.scheme": "implicit", "solver.dynamic": False,
        "solver.gravity_phase": "geostatic", "solver.load_steps": o.load_steps,
        "solver.max_iterations": o.max_iterations, "solver.max_cuts": o.max_cuts,
        "solver.tolerance": o.newton_tolerance, "solver.fbar": o.fbar,
        "solver.linear_solver": o.linear_solver,
        "solver.adaptive": False})         # fixed load steps: the criterion stays as stated


def _failure_reason(msg: str) -> str:
    """The Newton reason inside the solver's message ("... down to a step of h (REASON);")."""
    head = msg.split("; relative residuals")[0]
    i = head.find("(", head.find("down to a step of"))
    return head[i + 1:-1] if i >= 0 and head.endswith(")") else head


def _solve(scene: Scene, grid: Grid, base: Particles, F: float, o: FSOptions,
           load: float = 1.0) -> tuple[Trial, Particles]:
    """Apply ``load`` x gravity at trial factor ``F`` on a copy of ``base``."""
    pts = base.copy()
    reduce_strength(pts, scene, F, o.softening)
    if load != 1.0:
        pts.mass = pts.mass * load
        scene = scaled_water(scene, load)        # pore water: its force follows the load
    t0 = time.perf_counter()
    reason, lf = "", 1.0
    try:
        rec = run_implicit(scene, grid, pts)
        stats = rec.solver
    except SimulationError as exc:
        stats = getattr(exc, "solver_stats", {})
        reason = _failure_reason(str(exc))
        lf = float(stats.get("last_converged_time", 0.0))
    umax = float(np.sqrt(np.max(np.sum(pts.u_geostatic ** 2, axis=1), initial=0.0)))
    return Trial(F, not reason, umax, lf, int(stats.get("iterations_total", 0)),
                 int(stats.get("cuts_total", 0)), time.perf_counter() - t0, reason), pts


def _continue(scene: Scene, grid: Grid, base: Particles, start: Particles, F0: float,
              F: float, o: FSOptions, known: "KnownFailures | None" = None,
              start_id: int = 0) -> tuple[Trial, Particles, int]:
    """Strength continuation: from ``start``, the converged state at full gravity and
    trial factor ``F0``, the strengths of ``base`` are reduced to ``F`` at full gravity in
    small-strain geostatic Newton solves (one solve for the whole change; a solve that
    fails is halved in ``ln F`` at most ``continuation_cuts`` times, default 2; a failed
    trial keeps the state of its last converged solve, ``Trial.reached``, which becomes
    the bracket's lower end).  Without cuts a thin layer near collapse fails falsely: the
    undrained infinite slope z = 2.5 m, beta = 20 deg gave FS -5.3 % (no cut), -1.3 % (2
    cuts), -1.1 % (4 cuts); gravity anew at every trial -2.5 %.  The
    collapse factor of a perfectly plastic soil does not depend on the path
    (associated flow: the limit theorems), so this finds the same FS as applying gravity
    anew at every trial, at a fraction of the cost: far from collapse one or two Newton
    iterations, and the bisection's last trials change F by under 1 %.

    ``known`` (:class:`KnownFailures`): the solves that failed in earlier trials, by the
    identity of their start state (``start_id`` for ``start``) and their target; such a
    solve is not repeated (the search's next trial often begins with the very solve its
    predecessor ended on: same state, same target, the same Newton iterations to the same
    failure).  Returns the trial, its last converged state and that state's identity."""
    pts = start.copy()
    known = KnownFailures() if known is None else known
    state_id = start_id
    system = ImplicitSystem(scene, grid, pts, known.solver(o.linear_solver),
                            pattern_cache=known.patterns)
    kind = Geostatic(system)
    t0 = time.perf_counter()
    at, h, cuts, its, reason = math.log(F0), math.log(F / F0), 0, 0, ""
    end = math.log(F)
    while abs(end - at) > 1e-12 and not reason:
        h = end - at if abs(end - at) < 1.05 * abs(h) else h
        failed = known.get(state_id, at + h)
        if failed is None:
            pts.soil = base.soil
            reduce_strength(pts, scene, math.exp(at + h), o.softening)
            try:
                out = kind.solve(1.0, 1.0)
            except NewtonFailure as exc:
                its += len(exc.residuals) - 1
                failed = known.add(state_id, at + h, exc.reason)
            else:
                out.commit()
                its += out.result.iterations
                at += h
                state_id = known.new_state()
                continue
        if cuts >= o.continuation_cuts:
            reason = failed
        else:
            cuts, h = cuts + 1, 0.5 * h
    reached = F if not reason else math.exp(at)
    pts.soil = base.soil
    reduce_strength(pts, scene, reached, o.softening)
    umax = float(np.sqrt(np.max(np.sum(pts.u_geostatic ** 2, axis=1), initial=0.0)))
    return Trial(F, not reason, umax, 1.0, its, cuts, time.perf_counter() - t0, reason,
                 F0, reached), pts, state_id


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


def _numerical(reason: str) -> str:
    """A short name of a numerical Newton failure ``reason``."""
    if "linear solve failed" in reason:
        return "linear solve non-finite" if "non-finite" in reason else "linear solve singular"
    return "non-finite residual"


def _probe(scene: Scene, grid: Grid, base: Particles, o: FSOptions) -> None:
    one = dataclasses.replace(o, load_steps=1, max_cuts=0)
    t, _ = _solve(with_values(scene, {"solver.load_steps": 1, "solver.max_cuts": 0}), grid,
                  base, 1.0, one, load=o.probe_load)
    if not t.converged:
        raise NonPhysicalFailure(
            f"{scene.source}: strength reduction: Newton failed on an elastic probe "
            f"({o.probe_load:g} x gravity in one step at F = 1): {t.reason}. This is not a "
            "slope failure: check the mesh (soil cells without support, points outside the "
            "grid) and [solver] linear_solver", cause=t.reason)


def _prepared(scene: Scene, seed, o: FSOptions, grid, pts):
    _check_has_strength(scene)
    if grid is None or pts is None:
        raise TypeError("strength reduction needs the prepared realization: grid, pts = "
                        "api.prepare(scene, seed) (or use api.factor_of_safety)")
    srm = _srm_scene(scene, o)
    _probe(srm, grid, pts, o)
    return srm, grid, pts


def stable_at(scene: Scene, F: float = 1.0, seed: int | None = None,
              options: FSOptions | None = None, grid: Grid | None = None,
              pts: Particles | None = None) -> Trial:
    """One static solve at trial factor ``F`` (after the elastic probe): does the slope
    stand (``.converged``)?  At ``F = 1`` this is the event "FS >= 1" in one solve, all an
    RFEM estimate of P(FS < 1) needs (Griffiths & Fenton 2004).  Raises like
    :func:`factor_of_safety`."""
    o = options or FSOptions()
    srm, grid, pts = _prepared(scene, seed, o, grid, pts)
    t, _ = _solve(srm, grid, pts, F, o)
    if not t.converged and any(k in t.reason for k in _NON_PHYSICAL):
        raise NonPhysicalFailure(f"{scene.source}: strength reduction at F = {F:.4g}: "
                                 f"Newton failed for a reason that is not a mechanism "
                                 f"({t.reason})", cause=t.reason)
    return t


# ----------------------------------------------------------------------------- search
def factor_of_safety(scene: Scene, seed: int | None = None, options: FSOptions | None = None,
                     grid: Grid | None = None, pts: Particles | None = None,
                     progress=None) -> FSResult:
    """Factor of safety of ``scene`` (realization ``seed`` of its random field, if any).

    ``grid``/``pts``: the prepared realization ``seed`` (``api.prepare(scene, seed)``;
    :func:`fem_rmpm.api.factor_of_safety` does both).  ``progress(trial)`` is called after
    each static solve.  Raises :class:`SceneError` when no soil has a strength and
    :class:`NonPhysicalFailure` when Newton fails for a reason other than collapse.
    """
    refuse_frictional(scene, "strength reduction")   # no contact in the implicit scheme
    o = options or FSOptions()
    wall0 = time.perf_counter()
    srm, grid, pts = _prepared(scene, seed, o, grid, pts)
    trials: list[Trial] = []
    best: dict = {}
    known = KnownFailures()

    def run(F, continue_from=None):
        state_id = None
        if continue_from is None:
            t, state = _solve(srm, grid, pts, F, o)
        else:
            t, state, state_id = _continue(srm, grid, pts, best["pts"], continue_from, F, o,
                                           known, best["id"])
        trials.append(t)
        if progress:
            progress(t)
        if not t.converged and any(k in t.reason for k in _NON_PHYSICAL):
            res = _result(trials, "=", (math.nan, math.nan), o, wall0, seed, best, grid)
            raise NonPhysicalFailure(
                f"{scene.source}: strength reduction: {_numerical(t.reason)} at F = {F:.4g}"
                f" (load factor {t.load_factor:.3g}): the mechanism is not resolved, this is "
                f"not a slope failure; FS not determined ({t.reason}). Check the geometry "
                "(free faces that fail first), a finer mesh or [solver] linear_solver",
                cause=t.reason, result=res)
        done = F if t.converged else t.reached       # a failed continuation's last solve
        if done > 0 and done >= best.get("F", -1.0) and (t.converged or done > t.start):
            best.update(F=done, pts=state,
                        id=known.new_state() if state_id is None else state_id)
        return t.converged

    if not o.continuation:
        return _bisect_anew(run, o, lambda b, br: _result(trials, b, br, o, wall0, seed,
                                                            best, grid))
    lo, hi = 0.0, math.inf
    if run(1.0):
        lo = 1.0
    else:                          # FS < 1: gravity anew at a lower F, then upwards
        hi = 1.0
        guess = trials[-1].load_factor       # gravity fraction reached at F = 1 (<= FS)
        F0 = guess if o.f_min < guess < 0.95 else o.f_min
        if not run(F0):
            if F0 <= o.f_min or not run(o.f_min):
                return _result(trials, "<", (0.0, o.f_min), o, wall0, seed, best, grid)
            hi = F0
        lo = best["F"]
    step = math.log(o.march)
    while math.isinf(hi) or hi / lo - 1.0 > o.tolerance:
        F = min(lo * math.exp(step), o.f_max) if math.isinf(hi) else math.sqrt(lo * hi)
        if run(F, continue_from=lo):
            lo, step = F, 2 * step
            if F >= o.f_max:
                return _result(trials, ">", (o.f_max, math.inf), o, wall0, seed, best, grid)
        else:
            lo, hi = best["F"], F
    return _result(trials, "=", (lo, hi), o, wall0, seed, best, grid)


def _bisect_anew(run, o: FSOptions, result) -> FSResult:
    """The classic search (``continuation = False``): gravity applied anew at every
    trial; F = 1, then ``f_max`` or ``f_min``, then bisection in ``ln F``."""
    lo, hi = 0.0, math.inf
    if run(1.0):
        lo = 1.0
        if run(o.f_max):
            return result(">", (o.f_max, math.inf))
        hi = o.f_max
    else:
        hi = 1.0
        if not run(o.f_min):
            return result("<", (0.0, o.f_min))
        lo = o.f_min
    while hi / lo - 1.0 > o.tolerance:
        mid = math.sqrt(lo * hi)
        if run(mid):
            lo = mid
        else:
            hi = mid
    return result("=", (lo, hi))


def _result(trials, bound, bracket, o, wall0, seed, best, grid) -> FSResult:
    fs = {">": o.f_max, "<": o.f_min}.get(bound, math.sqrt(bracket[0] * bracket[1])
                                          if bracket[0] > 0 else math.nan)
    # converged states: the converged trials and a failed continued trial's last solve
    ok = sorted((t.F if t.converged else t.reached, t.max_displacement) for t in trials
                if t.converged or t.reached > t.start)
    jump = ok[-1][1] / ok[0][1] if len(ok) > 1 and ok[0][1] > 0 else math.nan
    return FSResult(fs, bound, (float(bracket[0]), float(bracket[1])), list(trials), o,
                    time.perf_counter() - wall0, seed, jump, best.get("pts"), grid)


# ----------------------------------------------------------------------------- outputs
def write_outputs(res: FSResult, scene: Scene, out: str | Path) -> None:
    """``fs.json``, ``fs_displacement.png`` (max displacement against F), and the
    mechanism: ``mechanism.vtu`` (points at the largest converged F) with
    ``mechanism.png``."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    d = res.to_dict()
    d["scene"] = scene.scene.name
    if res.mechanism is not None:
        d["mechanism_F"] = res.bracket[0] if res.bound != ">" else res.options.f_max
        write_particles(out / "mechanism.vtu", res.mechanism)
        plot_mechanism(out / "mechanism.png", res, scene)
    write_json(out / "fs.json", d)
    plot_displacement(out / "fs_displacement.png", res, scene.scene.name)


def plot_displacement(path: Path, res: FSResult, name: str = "") -> None:
    """Maximum displacement (log scale) against the trial F; failed trials hollow, at the
    displacement of their last converged load step, labelled with the gravity fraction
    reached."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(7, 4.2))
    ok = sorted((t for t in res.trials if t.converged), key=lambda t: t.F)
    bad = [t for t in res.trials if not t.converged]
    if ok:
        ax.plot([t.F for t in ok], [t.max_displacement for t in ok], "o-", color="tab:blue",
                label="converged at full gravity")
    if bad:
        ax.plot([t.F for t in bad], [max(t.max_displacement, 1e-12) for t in bad], "o",
                mfc="none", color="tab:red", label="failed (at the last converged load step)")
        for t in bad:
            ax.annotate(f"{t.load_factor:.2g} g", (t.F, max(t.max_displacement, 1e-12)),
                        textcoords="offset points", xytext=(5, -10), fontsize=7,
                        color="tab:red")
    if res.bound == "=":
        ax.axvline(res.fs, color="k", ls="--", lw=1, label=res.text)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("trial factor F (strengths divided by F)")
    ax.set_ylabel("max displacement (m)")
    ax.set_title(f"{name}: strength reduction, {res.text} ({res.static_solves} static solves)",
                 fontsize=10)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_mechanism(path: Path, res: FSResult, scene: Scene) -> None:
    """Displacement magnitude of the last converged state just below FS (true frame)."""
    plt = _plt()
    p = res.mechanism
    X = to_true_frame(p.x0, scene.scene.frame_angle_deg)
    u = np.sqrt(np.sum(p.u_geostatic ** 2, axis=1))
    span = np.ptp(X, axis=0)
    fig, ax = plt.subplots(figsize=(10, 1.5 + 8 * span[1] / max(span[0], 1e-9)))
    sc = plot_field(ax, X, u, float(np.max(res.grid.cell)) / 2, 0.0, float(u.max()),
                    cmap="turbo")
    ax.set_aspect("equal")
    ax.set_xlabel("X, true horizontal (m)")
    ax.set_ylabel("Y (m)")
    ax.set_title(f"{scene.scene.name}: mechanism, |u| at F = {res.bracket[0]:.4g} "
                 f"(just below {res.text})", fontsize=10)
    fig.colorbar(sc, ax=ax, label="displacement (m)", shrink=0.8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


# ----------------------------------------------------------------------------- command line
def fs_cli(a, scene: Scene, grid: Grid, pts: Particles) -> int:
    """``fem-rmpm fs``: print one line per static solve and a summary; write the outputs."""
    if not 0 < a.tolerance < 1:
        raise InputError(f"--tolerance {a.tolerance:g}: allowed 0 < tolerance < 1 "
                         "(relative bracket width)")
    o = FSOptions(tolerance=a.tolerance, softening=a.softening)
    check_run_dir(a.out, force=getattr(a, "force", False))   # before any computing

    def show(t: Trial) -> None:
        if not a.quiet:
            state = "converged" if t.converged else f"failed at load factor {t.load_factor:.3g} " \
                f"({t.reason})"
            print(f"  F = {t.F:.4f}: {state}; max displacement {t.max_displacement:.4g} m, "
                  f"{t.iterations} Newton iterations, {t.wall_time:.1f} s", flush=True)
    res = factor_of_safety(scene, seed=a.seed, options=o, grid=grid, pts=pts, progress=show)
    write_outputs(res, scene, a.out)
    lo, hi = res.bracket
    print(f"{scene.scene.name}: {res.text} ({'peak' if not o.softening else 'softening'} "
          f"strength; bracket [{lo:.4g}, {hi:.4g}], tolerance {o.tolerance:g}) from "
          f"{res.static_solves} static solves in {res.wall_time:.1f} s wall. Output: {a.out}")
    return 0
