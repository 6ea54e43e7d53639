"""Full Newton-Raphson on the free DOFs of one implicit step, with a line search
(backtracking on the residual norm, or on the energy's directional derivative) and the
two-part convergence test (relative residual and predicted correction)."""
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


def newton(evaluate, tangent, du0: np.ndarray, solver: LinearSolver, max_iterations: int,
           tol: float, modes=None, line_search: int = 4,
           energy: bool = False, diverging: float = 1e3) -> NewtonResult:
    """Full Newton-Raphson on the free DOFs, with a backtracking line search.

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
    ``energy``: the line search seeks the step length ``alpha`` at which the directional
    derivative of the potential energy along the correction, ``g(alpha) = delta . R(du +
    alpha delta)`` (``R = f_ext - f_int``), has fallen to half its value at ``alpha = 0``
    in magnitude (Matthies & Strang 1979, the line search of the BFGS method; Crisfield
    1991, ch. 9): the full correction, or a multiple of it (x4 per evaluation) while
    ``g`` stays positive, or the Illinois regula falsi between the bracketing lengths,
    ``line_search`` evaluations at most (:func:`_energy_step`).  For a small-strain
    associated plastic solid the energy is convex and bounded below exactly when the
    load can be carried: below collapse the step length is the energy minimum's along
    the correction (which the residual norm, not monotone in a converging iteration of
    a plastic solid, cuts to 1/8-1/16 for many iterations on end); past collapse the
    energy decreases without bound along the mechanism, the step lengths grow and the
    residual with them, so the solve fails as diverging within a few iterations.  A
    tangent that is not positive definite on the correction (``g(0) <= 0``) falls back
    to the residual-norm backtracking for that iteration.  ``diverging``: the relative
    residual (to the larger of the reference norm and the first residual) beyond which
    the solve fails as diverging.
    """
    def _evaluate(u):
        try:
            return evaluate(u)
        except NewtonFailure as exc:
            raise NewtonFailure(exc.reason, res, exc.inverted) from None

    du = du0.copy()
    res: list[float] = []
    t_sol = 0.0
    last_delta = 0.0
    R, ref, state = _evaluate(du)
    ref0 = max(ref, float(np.linalg.norm(R)))
    for it in range(max_iterations + 1):
        rn = float(np.linalg.norm(R))
        r = rn / ref0 if ref0 > 0 else 0.0
        res.append(r)
        if not math.isfinite(r):
            raise NewtonFailure("non-finite residual", res)
        if r > diverging * max(1.0, res[0]):
            raise NewtonFailure(f"diverging (residual grew {diverging:g}-fold)", res)
        # correction the next iteration would make, |delta_k| r_{k+1} / r_k
        predicted = last_delta * r / res[-2] if it > 0 and res[-2] > 0 else 0.0
        if r <= tol and predicted <= math.sqrt(tol) * float(np.linalg.norm(du)):
            return NewtonResult(du, res, it, t_sol, state=state)
        if it == max_iterations:
            break
        K = tangent()
        t1 = time.perf_counter()
        eta = min(1e-3, max(1e-12, 0.1 * r))
        try:
            delta = solver.solve(K, R, modes, rtol=eta)
        except LinearSolveError as exc:
            raise NewtonFailure(f"linear solve failed ({exc})", res) from None
        t_sol += time.perf_counter() - t1
        g0 = float(delta @ R) if energy else 0.0
        if g0 > 0:
            alpha, R, ref, state = _energy_step(_evaluate, du, delta, g0, line_search)
        else:
            alpha, R, ref, state = _backtrack(_evaluate, du, delta, rn, line_search)
        du = du + alpha * delta
        last_delta = alpha * float(np.linalg.norm(delta))
    raise NewtonFailure(f"not converged in {max_iterations} iterations", res)


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
    ``g(alpha) = delta . R(du + alpha delta)`` and ``g0 = g(0) > 0`` (see :func:`newton`):
    ``alpha = 1`` first, times ``ENERGY_GROWTH`` while ``g > 0`` and nothing bracketed,
    else the Illinois regula falsi between the largest length with ``g > 0`` and the
    smallest with ``g < 0`` (kept 1/10 of the bracket inside it); the last length tried
    after ``evaluations + 1`` evaluations.  Returns it with the residual, its reference
    norm and the state there."""
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
