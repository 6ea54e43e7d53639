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
``F = 1``, applies gravity in one Newton solve, and where that fails in ``load_steps``
small-strain load steps; it *fails* when Newton does not converge within
``max_iterations`` iterations in some load step even after ``max_cuts`` halvings of that
step, i.e. before full gravity is reached (a converged solve, at once or in steps, is an
equilibrium at full gravity within the reduced strengths: the slope stands).  Every
later trial (``continuation = True``, the default) starts from the converged state of
the largest converged ``F`` at full gravity and reduces the strengths further to the
trial ``F`` in one Newton solve (:func:`.srm_solves.continue_strength`).  Newton's line
search is the energy's (``line_search = "energy"``: the step length where the
directional derivative of the potential energy along the correction has fallen to half,
:func:`~fem_rmpm.schemes.implicit.newton.newton`): below collapse the incremental
energy of the associated perfectly plastic solid has a minimum, which Newton reaches in
5-17 iterations on the risk slope; past collapse it decreases without bound along the
mechanism, the step lengths grow, and the solve fails once its residual exceeds
``diverging`` (10) times the gravity load, within 1-7 iterations.  A solve also fails
when it does not converge within ``max_iterations``.  (``line_search = "residual"``:
backtracking on the residual norm, and a continuation solve rejected once the residual
of an accepted iterate exceeds ``growth_rejection``, 1.5, times the smallest before it.)
A solve failing over a change of ``F`` of at most ``decisive_change`` (1.5 %) fails the
trial; one failing over a larger change does not decide it (Newton can fail over a
large change below FS), the search tries a closer ``F`` instead.  A failure is
accompanied by the jump of the maximum point displacement, which grows without bound as
``F`` approaches ``FS`` from below (the plot ``fs_displacement.png`` shows it, the ratio
of the last converged maximum displacement to that of the smallest trial ``F`` is
``displacement_jump`` in ``fs.json``).  ``FS`` lies in the bracket ``[F_lo, F_hi]`` of
the largest converged and the smallest decisively failed trial.

**Search.**  From ``F = 1`` upwards ``F`` grows by ``march`` (1.25), the step in ``ln F``
doubling after each converged trial, until a solve fails or ``f_max`` (10) converges
("FS > 10"); when ``F = 1`` fails, gravity is applied anew at the gravity fraction ``F = 1``
reached (a lower bound of FS: at ``F = lambda`` every strength is at least that of the
state that stood at ``lambda`` x gravity), or at ``f_min`` (0.1; failing there: "FS <
0.1").  Then bisection in ``ln F`` towards the lowest ``F`` any solve failed at above
``F_lo`` (not a bound of FS unless that failure was decisive, but where to look; a
midpoint within ``decisive_change`` of ``F_lo`` decides by its own failure, and that
lowest failure itself is tried again from ``F_lo`` once within ``tolerance`` of it),
until ``F_hi / F_lo - 1 <= tolerance`` (default 0.005); the reported FS is the
geometric midpoint, so the search error is below ``tolerance / 2`` (0.25 %).  With
``continuation = False`` gravity is applied anew at every trial (``F = 1``, ``f_max`` or
``f_min``, then bisection): the same FS within the bracket, at more cost.

**Cost.**  The solves of one search share what the fixed geometry fixes (the
:class:`~fem_rmpm.schemes.implicit.assembly.StepSystem`: basis, DOF numbering, sparsity
pattern; and the linear solver with its symbolic factorization, :class:`KnownFailures`),
the elastic probe and the gravity solves included;
the tangent is factorized by CHOLMOD (``linear_solver = "cholmod"``, the implicit
scheme's policy: SuperLU for a tangent that is not symmetric positive definite); a
continuation solve known to fail (same start state, same target) is not run again.
Each Newton iteration builds and factorizes the tangent (about three quarters of its
cost) and evaluates the residual 1.5 times on average in its line search.

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

from fem_rmpm.discretise.contact import refuse_frictional
from fem_rmpm.discretise.grid import Grid
from fem_rmpm.discretise.points import Particles
from fem_rmpm.io.rundir import check_run_dir
from fem_rmpm.materials import strength
from fem_rmpm.runtime.errors import InputError
from fem_rmpm.scene import Scene, SceneError, with_values
from fem_rmpm.schemes.common import SimulationError
from fem_rmpm.schemes.implicit.srm_outputs import (
    plot_displacement,
    plot_mechanism,
    write_outputs,
)
from fem_rmpm.schemes.implicit.srm_solves import (
    FSOptions,
    KnownFailures,
    Trial,
    continue_strength,
    gravity_solve,
    reduce_strength,
    srm_scene,
)

__all__ = ["FSOptions", "Trial", "FSResult", "NonPhysicalFailure", "KnownFailures",
           "strength_parameters", "reduce_strength", "factor_of_safety", "stable_at",
           "write_outputs", "plot_displacement", "plot_mechanism", "fs_cli"]

#: Newton failure reasons that are never a mechanism (substrings of the solver's message):
#: a non-finite residual, and a failed linear solve (singular tangent or non-finite
#: solution, :class:`~fem_rmpm.schemes.implicit.linear.LinearSolveError`).
_NON_PHYSICAL = ("non-finite residual", "linear solve failed")


class NonPhysicalFailure(SimulationError):
    """Newton failed for a reason that is not the soil's collapse (``cause`` says which)."""

    def __init__(self, msg: str, cause: str, result: "FSResult | None" = None):
        super().__init__(msg)
        self.cause, self.result = cause, result


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
                    search=SEARCHES[o.line_search].format(div=o.diverging),
                    cont=CONTINUED.format(
                        it=o.max_iterations, decisive=100 * o.decisive_change,
                        early=f" (rejected earlier once its residual grows to "
                              f"{o.growth_rejection:g} times its smallest)"
                        if o.line_search == "residual" and o.growth_rejection > 0 else "")
                    if o.continuation else ""),
                "options": dataclasses.asdict(o),
                "trials": [dataclasses.asdict(t) for t in self.trials]}


CRITERION = ("a trial F fails when gravity does not converge in one Newton solve and, in "
             "{steps} small-strain load steps on the in-situ geometry, Newton does not "
             "converge within {it} iterations in a load step after {cuts} halvings of it, "
             "before full gravity is reached{cont}; Newton's line search: {search}; FS is "
             "the geometric midpoint of the largest converged and the smallest failed F")
CONTINUED = (", or, for a trial continued from the converged state of a smaller F at most "
             "{decisive:g} % below it at full gravity, when the Newton solve reducing the "
             "strengths to F does not converge within {it} iterations{early}")
SEARCHES = {"energy": "on the energy's directional derivative, a solve failing once its "
                      "residual exceeds {div:g} times the gravity load",
            "residual": "backtracking on the residual norm"}


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



def _numerical(reason: str) -> str:
    """A short name of a numerical Newton failure ``reason``."""
    if "linear solve failed" in reason:
        return "linear solve non-finite" if "non-finite" in reason else "linear solve singular"
    return "non-finite residual"


def _probe(scene: Scene, grid: Grid, base: Particles, o: FSOptions,
           known: KnownFailures | None = None) -> None:
    one = dataclasses.replace(o, load_steps=1, max_cuts=0)
    t, _ = gravity_solve(with_values(scene, {"solver.load_steps": 1, "solver.max_cuts": 0}),
                         grid, base, 1.0, one, load=o.probe_load, known=known)
    if not t.converged:
        raise NonPhysicalFailure(
            f"{scene.source}: strength reduction: Newton failed on an elastic probe "
            f"({o.probe_load:g} x gravity in one step at F = 1): {t.reason}. This is not a "
            "slope failure: check the mesh (soil cells without support, points outside the "
            "grid) and [solver] linear_solver", cause=t.reason)


def _prepared(scene: Scene, seed, o: FSOptions, grid, pts, known=None):
    _check_has_strength(scene)
    if grid is None or pts is None:
        raise TypeError("strength reduction needs the prepared realization: grid, pts = "
                        "api.prepare(scene, seed) (or use api.factor_of_safety)")
    srm = srm_scene(scene, o)
    _probe(srm, grid, pts, o, known)
    return srm, grid, pts


def stable_at(scene: Scene, F: float = 1.0, seed: int | None = None,
              options: FSOptions | None = None, grid: Grid | None = None,
              pts: Particles | None = None) -> Trial:
    """One static solve at trial factor ``F`` (after the elastic probe): does the slope
    stand (``.converged``)?  At ``F = 1`` this is the event "FS >= 1" in one solve, all an
    RFEM estimate of P(FS < 1) needs (Griffiths & Fenton 2004).  Raises like
    :func:`factor_of_safety`."""
    o = options or FSOptions()
    known = KnownFailures()
    srm, grid, pts = _prepared(scene, seed, o, grid, pts, known)
    t, _ = gravity_solve(srm, grid, pts, F, o, known=known)
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
    known = KnownFailures()          # and what the search's solves share
    srm, grid, pts = _prepared(scene, seed, o, grid, pts, known)
    trials: list[Trial] = []
    best: dict = {}

    def run(F, continue_from=None):
        state_id = None
        if continue_from is None:
            t, state = gravity_solve(srm, grid, pts, F, o, known=known)
        else:
            t, state, state_id = continue_strength(srm, grid, pts, best["pts"], continue_from,
                                                   F, o, known, best["id"])
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
        above = known.lowest_failed_above(lo)
        F = _next_trial(lo, hi, above, step, o)
        if run(F, continue_from=lo):
            if math.isinf(min(hi, above)):      # marching upwards: the step doubles
                step *= 2
            lo = F
            if F >= o.f_max:
                return _result(trials, ">", (o.f_max, math.inf), o, wall0, seed, best, grid)
        else:                    # decisive (F) or not (inf: the next trial moves closer)
            hi = min(hi, trials[-1].failed_at)
    return _result(trials, "=", (lo, hi), o, wall0, seed, best, grid)


def _next_trial(lo: float, hi: float, failed_above: float, step: float,
                o: FSOptions) -> float:
    """The next trial F of the continued search from the bracket ``[lo, hi]``: upwards by
    ``exp(step)`` while nothing above ``lo`` failed, else the geometric midpoint of ``lo``
    and the lowest failure above it (``failed_above``, any failed solve, or ``hi``), or
    a failed solve below ``hi`` itself once within ``tolerance`` (at most
    ``decisive_change``) of ``lo`` (its solve from ``lo`` then decides it)."""
    soft = failed_above < hi * (1 - 1e-9)       # a failed solve that did not decide
    up = failed_above if soft else hi
    if math.isinf(up):
        return min(lo * math.exp(step), o.f_max)
    if soft and up / lo - 1.0 <= min(o.tolerance, o.decisive_change) * (1 + 1e-9):
        return up
    return math.sqrt(lo * up)


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
