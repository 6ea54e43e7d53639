"""BFGS iterations of the implicit Newton solve (:func:`fem_rmpm.schemes.implicit.newton.newton`,
``quasi_newton``) and the reuse of a factorization they rest on.

Reference: a discrete nonlinear spring chain whose solution is chosen first and the load
made from it, ``f = K u* + k3 u*^3`` (so the root ``u*`` is known exactly), with a
stiffening cubic term strong enough that full Newton needs several iterations; the BFGS
update is that of Matthies & Strang (1979) in the two-loop form (Nocedal & Wright 2006,
alg. 7.4).
"""
from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from fem_rmpm.schemes.implicit.linear import LinearSolver
from fem_rmpm.schemes.implicit.newton import newton


def _chain(n: int = 60):
    """Tridiagonal spring chain (SPD) with a cubic stiffening on every DOF; returns the
    exact root, the residual function, the tangent and the last evaluated state."""
    main = np.full(n, 2.0)
    K = sp.diags([-np.ones(n - 1), main, -np.ones(n - 1)], [-1, 0, 1], format="csr") * 50.0
    K = K + sp.identity(n, format="csr") * 10.0
    K = K.tocsr()
    K.sort_indices()
    k3 = 400.0
    u_star = 0.3 * np.sin(np.linspace(0.0, 3.0, n)) + 0.1
    f = K @ u_star + k3 * u_star ** 3
    last = {}

    def evaluate(u):
        last["u"] = u.copy()
        return f - (K @ u + k3 * u ** 3), float(np.linalg.norm(f)), (u.copy(),)

    def tangent():
        T = (K + sp.diags(3.0 * k3 * last["u"] ** 2)).tocsr()
        T.sort_indices()
        return T
    return u_star, evaluate, tangent


@pytest.mark.parametrize("kind", ["cholmod", "superlu"])
def test_bfgs_iterations_reach_the_root_with_fewer_factorizations(kind):
    """Full Newton and Newton with BFGS iterations reach the exact root to the tolerance's
    accuracy; the BFGS run factorizes fewer tangents and counts them apart from its
    iterations (full Newton: one factorization per iteration)."""
    u_star, evaluate, tangent = _chain()
    full = newton(evaluate, tangent, np.zeros_like(u_star), LinearSolver(kind), 15, 1e-12)
    u_star, evaluate, tangent = _chain()
    quasi = newton(evaluate, tangent, np.zeros_like(u_star), LinearSolver(kind), 15, 1e-12,
                   quasi_newton=6)
    scale = np.abs(u_star).max()
    assert np.abs(full.du - u_star).max() <= 1e-9 * scale
    assert np.abs(quasi.du - u_star).max() <= 1e-9 * scale
    assert full.factorizations == full.iterations >= 4
    assert quasi.iterations > quasi.factorizations
    assert quasi.factorizations < full.factorizations
    assert quasi.residuals[-1] <= 1e-12


def test_resolve_uses_the_last_factorization_of_the_step():
    """``resolve`` solves with the last factorized matrix (to round-off), is refused
    before any factorization and after a new step."""
    u_star, evaluate, tangent = _chain(40)
    evaluate(u_star)
    K = tangent()
    b = np.linspace(1.0, 2.0, K.shape[0])
    for kind in ("cholmod", "superlu"):
        s = LinearSolver(kind)
        s.new_step()
        assert not s.can_resolve()
        x = s.solve(K, b)
        assert s.can_resolve()
        y = s.resolve(b + 1.0)
        assert np.abs(K @ x - b).max() <= 1e-10 * np.abs(b).max()
        assert np.abs(K @ y - (b + 1.0)).max() <= 1e-10 * np.abs(b + 1.0).max()
        s.new_step()
        assert not s.can_resolve()


def _stalling_chain(n: int = 60):
    """A soft spring chain with a quintic term about the chosen root ``u*``:
    ``R(u) = K u* - K u - k5 (u - u*)^5``; far from ``u*`` the tangent is nearly singular
    there, so full Newton converges only linearly, each iteration leaving about
    ``(4/5)^5 = 0.33`` of the residual (the stall the BFGS iterations answer)."""
    main = np.full(n, 2.0)
    K = (sp.diags([-np.ones(n - 1), main, -np.ones(n - 1)], [-1, 0, 1], format="csr") * 0.5
         + sp.identity(n, format="csr") * 0.1).tocsr()
    K.sort_indices()
    k5 = 400.0
    u_star = 0.3 * np.sin(np.linspace(0.0, 3.0, n)) + 0.1
    f = K @ u_star
    last = {}

    def evaluate(u):
        last["u"] = u.copy()
        return f - (K @ u + k5 * (u - u_star) ** 5), float(np.linalg.norm(f)), (u.copy(),)

    def tangent():
        T = (K + sp.diags(5.0 * k5 * (last["u"] - u_star) ** 4)).tocsr()
        T.sort_indices()
        return T
    return u_star, evaluate, tangent


def test_bfgs_iterations_take_over_where_newton_stalls(monkeypatch):
    """Where a Newton iteration leaves more than ``QN_STALL`` of the residual, BFGS
    iterations follow at any residual: the root (to 1e-9 of its size; achieves 6e-13) with
    5 factorizations instead of the 8 of BFGS only below ``QN_START`` (asserted: at least
    2 fewer)."""
    import sys
    nw = sys.modules["fem_rmpm.schemes.implicit.newton"]
    runs = {}
    for stall in (np.inf, nw.QN_STALL):
        monkeypatch.setattr(nw, "QN_STALL", stall)
        u_star, evaluate, tangent = _stalling_chain()
        runs[stall] = newton(evaluate, tangent, np.zeros_like(u_star),
                             LinearSolver("cholmod"), 30, 1e-12, quasi_newton=6)
        assert np.abs(runs[stall].du - u_star).max() <= 1e-9 * np.abs(u_star).max()
        assert runs[stall].residuals[-1] <= 1e-12
    plain, stalled = runs[np.inf], runs[nw.QN_STALL]
    assert plain.residuals[1] / plain.residuals[0] > nw.QN_STALL    # Newton stalls here
    assert stalled.factorizations <= plain.factorizations - 2
