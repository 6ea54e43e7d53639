"""Newton-Raphson on the free DOFs of one implicit step, with a line search
(backtracking on the residual norm, or on the energy's directional derivative) and the
two-part convergence test (relative residual and predicted correction); optionally
BFGS updates of the step's last factorized tangent between full Newton iterations.

BFGS iterations (:func:`newton` with ``quasi_newton = m > 0``): once the relative
residual is below ``QN_START``, or once a full Newton iteration left more than
``QN_STALL`` of the residual (Newton stalling, as at a kink of a softening law: the
tangent of one side of the kink overshoots, the secant pairs see both sides), up to
``m`` iterations after a full Newton one take the direction of the step's last
factorized tangent ``K0`` updated by the secant pairs ``(s, y)`` of the iterations since
(``s`` the increment, ``y`` the fall of the residual: ``y = K s`` for a linear problem),
in the inverse form of Matthies & Strang (1979) by the two-loop recursion (Nocedal &
Wright 2006, alg. 7.4) with ``H0 = K0^-1`` (one forward and back substitution, no
tangent, no factorization): a full step, kept when it lowers the residual (one that
leaves more than ``QN_RATE`` of it -- after a stalled Newton iteration, more than the
share that iteration left if that is larger -- and the ``m``-th make the next iteration
a full Newton one; one that does not lower it is dropped for a full Newton iteration
from the same state).  Convergence is superlinear; the converged state passes the same
test.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from fem_rmpm.schemes.implicit.linear import LinearSolveError, LinearSolver

__all__ = ["NewtonFailure", "NewtonResult", "newton"]


class NewtonFailure(RuntimeError):
    """A Newton iteration that cannot go on; ``inverted``: a trial state inverted a point
    (``det dF <= 0``), which the line search answers by a shorter correction."""

    def __init__(self, reason: str, residuals: list[float], inverted: bool = False):
        super().__init__(reason)
        self.reason, self.residuals, self.inverted = reason, residuals, inverted


@dataclass
class NewtonResult:
    du: np.ndarray              # free-DOF increment
    residuals: list[float]      # relative residual before each solve and at the end
    iterations: int             # linear solves
    t_solve: float = 0.0        # s (factorisation and solve)
    t_material: float = 0.0     # s (stress update and consistent tangent at the points)
    t_assembly: float = 0.0     # s (kinematics, internal force, tangent matrix)
    t_setup: float = 0.0        # s (basis at the points, DOF numbering, sparsity pattern)
    state: tuple = ()           # what the last evaluation returned (material state)
    factorizations: int = 0     # full Newton iterations among them (a tangent factorized)


#: BFGS iterations (``quasi_newton > 0``) start once the relative residual is below
#: QN_START; one that leaves more than QN_RATE of the residual is followed by a full
#: Newton iteration (a new tangent factorized)
QN_START, QN_RATE = 1e-3, 0.1
#: ... or, at any residual, once a Newton iteration left more than QN_STALL of the
#: residual (Newton stalling at a kink of the softening law); a BFGS iteration is then
#: slow when it leaves more than the larger of QN_RATE and that Newton iteration's share
QN_STALL = 0.3


def newton(evaluate, tangent, du0: np.ndarray, solver: LinearSolver, max_iterations: int,
           tol: float, modes=None, line_search: int = 4,
           energy: bool = False, diverging: float = 1e3,
           quasi_newton: int = 0) -> NewtonResult:
    """Newton-Raphson on the free DOFs, with a backtracking line search.

    ``evaluate(du) -> (R, ref, state)``: residual (free DOFs), its reference
    norm and whatever the caller needs at convergence; may raise
    :class:`NewtonFailure`.  ``tangent() -> K`` the consistent tangent at the
    last evaluated ``du``.  Converged when ``|R| <= tol ref0`` and the correction
    the next iteration would make, estimated as ``|delta_k| r_{k+1} / r_k``, is
    ``<= sqrt(tol) |du|`` (see the module docstring).

    Line search: a full correction that does not lower the residual, or that inverts a
    point, is halved up to ``line_search`` times (the last, smallest one is kept if none
    lowers the residual; a state with an inverted point is never kept).  Near
    the solution full steps always lower the residual, so quadratic convergence is
    untouched; far from it, or where the softening law has a kink (the linear law
    reaching the residual cohesion), it stops the 2-cycles Newton otherwise falls into.
    ``energy``: the line search on the energy's directional derivative along the
    correction instead (:func:`_energy_step`).  ``diverging``: the relative
    residual (to the larger of the reference norm and the first residual) beyond which
    the solve fails as diverging.

    ``quasi_newton = m > 0``: BFGS iterations between full Newton ones (see the module
    docstring); ``max_iterations`` then bounds the factorizations, and the iterations at
    ``(m + 1) max_iterations``.
    """
    def _evaluate(u):
        try:
            return evaluate(u)
        except NewtonFailure as exc:
            raise NewtonFailure(exc.reason, res, exc.inverted) from None

    du = du0.copy()
    res: list[float] = []
    t_sol = last_delta = 0.0    # s of linear solves; |the last increment|
    n_fact = n_quasi = 0        # factorizations; BFGS iterations since the last one
    stall = 0.0                 # the share of the residual the last Newton iteration left
    pairs: list = []            # the BFGS memory: (s, y, 1 / y.s) since the last factorization
    R, ref, state = _evaluate(du)
    ref0 = max(ref, float(np.linalg.norm(R)))
    while True:
        rn = float(np.linalg.norm(R))
        r = rn / ref0 if ref0 > 0 else 0.0
        res.append(r)
        it = len(res) - 1
        _refuse_growth(r, res, diverging)
        # correction the next iteration would make, |delta_k| r_{k+1} / r_k
        predicted = last_delta * r / res[-2] if it > 0 and res[-2] > 0 else 0.0
        if r <= tol and predicted <= math.sqrt(tol) * float(np.linalg.norm(du)):
            return NewtonResult(du, res, it, t_sol, state=state, factorizations=n_fact)
        quasi = (0 < n_fact and (r < QN_START or stall > QN_STALL)
                 and n_quasi < quasi_newton and solver.can_resolve())
        if (n_fact == max_iterations and not quasi) \
                or it == (quasi_newton + 1) * max_iterations:
            break
        if quasi:
            n_quasi += 1
            dt, kept, moved = _bfgs_iteration(_evaluate, du, R, rn, pairs, solver,
                                              max(QN_RATE, stall))
            t_sol += dt
            if kept is not None:                     # a lower residual
                du, R, ref, state, last_delta, slow = kept
                n_quasi = quasi_newton if slow else n_quasi   # slow: the next factorizes
                continue
            res.append(r)                            # the rejected trial was a solve
            if moved:                                # the tangent is taken at du
                R, ref, state = _evaluate(du)
        alpha, delta, R_new, ref, state, dt = _newton_iteration(
            _evaluate, tangent, solver, du, R, rn, r, modes, energy, line_search, res)
        t_sol += dt
        n_fact, n_quasi = n_fact + 1, 0
        du, last_delta = du + alpha * delta, alpha * float(np.linalg.norm(delta))
        pairs.clear()
        if quasi_newton > 0:
            _remember(pairs, alpha * delta, R - R_new)
            stall = float(np.linalg.norm(R_new)) / rn if rn > 0 else 0.0
        R = R_new
    raise NewtonFailure(f"not converged in {len(res) - 1} iterations", res)


def _refuse_growth(r: float, res: list[float], diverging: float) -> None:
    """:class:`NewtonFailure` when the relative residual ``r`` is not finite or beyond
    ``diverging`` times the larger of 1 and the first one (``res`` the history)."""
    if not math.isfinite(r):
        raise NewtonFailure("non-finite residual", res)
    if r > diverging * max(1.0, res[0]):
        raise NewtonFailure(f"diverging (residual grew {diverging:g}-fold)", res)


def _newton_iteration(evaluate, tangent, solver: LinearSolver, du: np.ndarray,
                      R: np.ndarray, rn: float, r: float, modes, energy: bool,
                      line_search: int, res: list):
    """One full Newton iteration of :func:`newton` from ``du`` (residual ``R``, its norm
    ``rn``, relative ``r``): the tangent, its solve and the line search.  Returns the
    step length, the correction, the residual, its reference norm and the state there,
    and the seconds of the linear solve."""
    K = tangent()
    t1 = time.perf_counter()
    eta = min(1e-3, max(1e-12, 0.1 * r))
    try:
        delta = solver.solve(K, R, modes, rtol=eta)
    except LinearSolveError as exc:
        raise NewtonFailure(f"linear solve failed ({exc})", res) from None
    dt = time.perf_counter() - t1
    g0 = float(delta @ R) if energy else 0.0
    if g0 > 0:
        alpha, R_new, ref, state = _energy_step(evaluate, du, delta, g0, line_search)
    else:
        alpha, R_new, ref, state = _backtrack(evaluate, du, delta, rn, line_search)
    return alpha, delta, R_new, ref, state, dt


def _bfgs_iteration(evaluate, du: np.ndarray, R: np.ndarray, rn: float, pairs: list,
                    solver: LinearSolver, rate: float = QN_RATE):
    """One BFGS iteration of :func:`newton` (see the module docstring) from ``du``
    (residual ``R`` of norm ``rn``).  Returns the seconds of the substitution, ``(du, R,
    ref, state, |increment|, slow)`` if the full step lowered the residual (``slow``: to
    more than ``rate`` of it; the secant pair is then added to ``pairs``) else None,
    and whether the last evaluation left ``du`` (then the caller evaluates it again)."""
    t1 = time.perf_counter()
    delta = _bfgs_direction(R, pairs, solver)
    dt = time.perf_counter() - t1
    out = _quasi_trial(evaluate, du, delta)
    if out is None or not out[0] < rn:
        return dt, None, out is not None
    rn_new, R_new, ref, state = out
    _remember(pairs, delta, R - R_new)
    return dt, (du + delta, R_new, ref, state, float(np.linalg.norm(delta)),
                rn_new > rate * rn), False


def _remember(pairs: list, s: np.ndarray, y: np.ndarray) -> None:
    """Adds the secant pair ``(s, y)`` to the BFGS memory if its curvature ``y.s`` is
    positive (else it is skipped, so the update stays positive definite)."""
    ys = float(y @ s)
    if ys > 1e-12 * float(np.linalg.norm(y) * np.linalg.norm(s)):
        pairs.append((s, y, 1.0 / ys))


def _bfgs_direction(R: np.ndarray, pairs: list, solver: LinearSolver) -> np.ndarray | None:
    """``H R`` by the BFGS two-loop recursion over ``pairs`` with ``H0 = K0^-1``, the
    step's last factorization (see :func:`newton`); None if that solve fails."""
    q = R.copy()
    a = []
    for s, y, rho in reversed(pairs):
        ai = rho * float(s @ q)
        q -= ai * y
        a.append(ai)
    try:
        d = solver.resolve(q)
    except LinearSolveError:
        return None
    for (s, y, rho), ai in zip(pairs, reversed(a)):
        d += s * (ai - rho * float(y @ d))
    return d


def _quasi_trial(evaluate, du: np.ndarray, delta: np.ndarray | None):
    """The full BFGS step: ``(|R|, R, ref, state)`` at ``du + delta``, or None when there
    is no direction or the step inverts a point (the state then stays at ``du``)."""
    if delta is None:
        return None
    try:
        R, ref, state = evaluate(du + delta)
    except NewtonFailure as exc:
        if exc.inverted:
            return None
        raise
    return float(np.linalg.norm(R)), R, ref, state


def _backtrack(evaluate, du: np.ndarray, delta: np.ndarray, rn: float,
               halvings: int) -> tuple[float, np.ndarray, float, tuple]:
    """The residual-norm line search of :func:`newton`: the full correction, halved up to
    ``halvings`` times until the residual norm falls below ``rn`` or a point is no longer
    inverted (the last, smallest length is kept if none lowers it; a state with an
    inverted point never is).  Returns the length, the residual, its reference norm and
    the state there."""
    alpha = 1.0
    for _ in range(halvings + 1):
        last = alpha < 0.5 ** (halvings - 0.5)
        try:
            R, ref, state = evaluate(du + alpha * delta)
        except NewtonFailure as exc:      # an inverted point: try a shorter correction
            if not exc.inverted or last:
                raise
            alpha *= 0.5
            continue
        if float(np.linalg.norm(R)) < rn or last:
            break
        alpha *= 0.5
    return alpha, R, ref, state


#: the energy line search: |g(alpha)| <= ENERGY_ETA g(0) ends it; while g stays positive
#: the step length grows by ENERGY_GROWTH per evaluation
ENERGY_ETA, ENERGY_GROWTH = 0.5, 4.0


def _energy_step(evaluate, du: np.ndarray, delta: np.ndarray, g0: float,
                 evaluations: int) -> tuple[float, np.ndarray, float, tuple]:
    """The step length along ``delta`` from ``du`` where ``|g(alpha)| <= ENERGY_ETA g0``,
    ``g(alpha) = delta . R(du + alpha delta)`` and ``g0 = g(0) > 0`` (see below):
    ``alpha = 1`` first, times ``ENERGY_GROWTH`` while ``g > 0`` and nothing bracketed,
    else the Illinois regula falsi between the largest length with ``g > 0`` and the
    smallest with ``g < 0`` (kept 1/10 of the bracket inside it); the last length tried
    after ``evaluations + 1`` evaluations.  Returns it with the residual, its reference
    norm and the state there.

    The line search of :func:`newton` with ``energy``: it seeks the step length
    ``alpha`` at which the directional derivative of the potential energy along the
    correction, ``g(alpha) = delta . R(du + alpha delta)`` (``R = f_ext - f_int``), has
    fallen to half its value at ``alpha = 0`` in magnitude (Matthies & Strang 1979, the
    line search of the BFGS method; Crisfield 1991, ch. 9): the full correction, or a
    multiple of it (x4 per evaluation) while ``g`` stays positive, or the Illinois regula
    falsi between the bracketing lengths, ``line_search`` evaluations at most.  For a
    small-strain
    associated plastic solid the energy is convex and bounded below exactly when the
    load can be carried: below collapse the step length is the energy minimum's along
    the correction (which the residual norm, not monotone in a converging iteration of
    a plastic solid, cuts to 1/8-1/16 for many iterations on end); past collapse the
    energy decreases without bound along the mechanism, the step lengths grow and the
    residual with them, so the solve fails as diverging within a few iterations.  A
    tangent that is not positive definite on the correction (``g(0) <= 0``) falls back
    to the residual-norm backtracking for that iteration."""
    alpha, lo, g_lo, hi, g_hi = 1.0, 0.0, g0, math.inf, 0.0
    side = 0                         # Illinois: the end kept twice in a row is halved
    for k in range(evaluations + 1):
        R, ref, state = evaluate(du + alpha * delta)
        g = float(delta @ R)
        if abs(g) <= ENERGY_ETA * g0 or k == evaluations:
            break
        if g > 0:
            lo, g_lo = alpha, g
            if math.isinf(hi):
                alpha *= ENERGY_GROWTH
                continue
            if side > 0:
                g_hi *= 0.5
            side = 1
        else:
            hi, g_hi = alpha, g
            if side < 0:
                g_lo *= 0.5
            side = -1
        a = lo + (hi - lo) * g_lo / (g_lo - g_hi)
        alpha = min(max(a, lo + 0.1 * (hi - lo)), hi - 0.1 * (hi - lo))
    return alpha, R, ref, state
