"""The implicit scheme's fast consistent tangent and the CHOLMOD linear solver against their
references.

* The analytic tangent hook of a model (``tangent(eps_tr, state, params)``: von Mises,
  linear elastic) against the complex-step derivative of the same model's ``update``
  (exact to round-off, the reference of the previous implementation), on every branch
  of the return mapping: elastic, the linear softening slope, the residual strength,
  exponential softening.
* The compiled finite-strain tangent (trial Jacobian of the matrix logarithm + model
  stiffness + spin + geometric term) against the complex step of the whole update
  (:func:`finite_strain_tangent_reference`), including repeated eigenvalues (the series
  branch of atanh(x)/x), large rotations, a model without the hook (Mohr-Coulomb: its
  stiffness by complex step) and a mix of models.
* The CHOLMOD solve against SuperLU; a non-symmetric or an indefinite tangent goes to
  SuperLU; the symbolic analysis is reused while the pattern stays.
"""
from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from fem_rmpm.materials import MaterialPoints, model, model_id, return_map
from fem_rmpm.schemes.implicit import LinearSolver
from fem_rmpm.schemes.implicit.tangent import (
    _derivatives,
    finite_strain_tangent,
    finite_strain_tangent_reference,
    small_strain_tangent,
    trial_stiffness,
)

G, K = 375.0, 980.0
VM = [20.0, 4.0, 0.5]            # cohesion_peak, cohesion_residual (kPa), softening_strain


def _soil(name, extra, n):
    return MaterialPoints(np.full(n, model_id(name)), np.tile([G, K] + extra, (n, 1)))


def _complex_step_stiffness(eps, state, soil):
    """d tau / d eps_tr (n, 4, 3) by complex step of the models' update (reference)."""
    n = len(eps)
    e3 = np.tile(eps.astype(complex), (3, 1))
    for j, c in enumerate((0, 1, 3)):
        e3[j * n:(j + 1) * n, c] += 1e-30j
    return np.transpose(_derivatives(e3, state, soil, 1e-30).reshape(3, n, 4), (1, 2, 0))


@pytest.mark.parametrize("law", [0.0, 1.0], ids=["linear", "exponential"])
def test_von_mises_tangent_hook_equals_complex_step_on_every_branch(law):
    """Achieves 4e-16 relative to the largest entry; asserts 4e-15.  The states are
    chosen so that each branch holds at least 50 of the 600 points (checked)."""
    rng = np.random.default_rng(3)
    n = 600
    soil = _soil("von_mises_softening", VM + [law], n)
    eps = 0.03 * rng.normal(size=(n, 4))
    gam = np.concatenate([np.zeros(200), rng.uniform(0.0, 0.45, 200),
                          rng.uniform(0.6, 1.0, 200)])[:, None]
    e_new, g_new, tau = return_map(eps, gam, soil)
    plastic = g_new[:, 0] > gam[:, 0]
    elastic = ~plastic
    if law == 0.0:
        slope, residual = plastic & (g_new[:, 0] <= 0.5), plastic & (g_new[:, 0] > 0.5)
        assert min(elastic.sum(), slope.sum(), residual.sum()) >= 50
    else:
        assert min(elastic.sum(), plastic.sum()) >= 50
    D = model("von_mises_softening").tangent(eps, gam, soil.params)[:, :, [0, 1, 3]]
    ref = _complex_step_stiffness(eps, gam, soil)
    assert np.abs(D - ref).max() <= 4e-15 * np.abs(ref).max()
    assert np.abs(trial_stiffness(eps, gam, soil) - ref).max() <= 4e-15 * np.abs(ref).max()


def test_linear_elastic_tangent_hook_is_hencky():
    """Exact: d tau / d eps of Hencky's law (achieves 0; asserts 1e-15)."""
    soil = _soil("linear_elastic", [], 5)
    eps = np.random.default_rng(0).normal(size=(5, 4)) * 0.01
    D = model("linear_elastic").tangent(eps, np.zeros((5, 1)), soil.params)[:, :, [0, 1, 3]]
    ref = _complex_step_stiffness(eps, np.zeros((5, 1)), soil)
    assert np.abs(D - ref).max() <= 1e-15 * np.abs(ref).max()


def _states(n, rng):
    """Log strains and increments with ordinary, repeated-eigenvalue (isotropic b_tr:
    the series branch) and large-rotation trial states."""
    ls = 0.02 * rng.normal(size=(n, 4))
    dF = np.eye(2) + 0.03 * rng.normal(size=(n, 2, 2))
    k = n // 4
    ls[:k, 3] = 0.0
    ls[:k, 1] = ls[:k, 0]                         # b_e isotropic in-plane ...
    dF[:k] = np.eye(2) * (1 + 0.01 * rng.normal(size=(k, 1, 1)))   # ... and so is b_tr
    ls[k:2 * k, 1] = ls[k:2 * k, 0] + 1e-3 * rng.normal(size=k)    # nearly repeated
    ls[k:2 * k, 3] = 1e-3 * rng.normal(size=k)
    th = rng.uniform(-1.5, 1.5, size=k)           # rotations up to 86 degrees
    R = np.stack([np.stack([np.cos(th), -np.sin(th)], 1), np.stack([np.sin(th), np.cos(th)], 1)], 1)
    dF[2 * k:3 * k] = R @ dF[2 * k:3 * k]
    return ls, dF


@pytest.mark.parametrize("case", ["von_mises", "von_mises_exponential", "linear_elastic",
                                  "mohr_coulomb", "mixed"])
def test_finite_strain_tangent_equals_complex_step_of_the_whole_update(case):
    """The compiled tangent against the complex step of the whole update through the
    models' numpy code (for Mohr-Coulomb the exactly isotropic states are moved off the
    edge of its yield surface, where the update has no derivative).  Achieves 2e-15 (von
    Mises, both laws), 7e-16 (elastic), 2e-15 (Mohr-Coulomb, stiffness by complex step),
    3e-15 (mixed), relative to the largest entry of A; asserts 3e-14.  The stress equals the reference's to 1e-12 of its largest entry."""
    rng = np.random.default_rng(7)
    n = 400
    vm = _soil("von_mises_softening", VM + [0.0], n)
    soils = {"von_mises": vm, "von_mises_exponential": _soil("von_mises_softening",
                                                             VM + [1.0], n),
             "linear_elastic": _soil("linear_elastic", [], n)}
    mc_extra = [5.0, 1.0, 25.0, 20.0, 5.0, 0.0, 0.5, 0.0]
    soils["mohr_coulomb"] = _soil("mohr_coulomb_softening", mc_extra, n)
    if case == "mixed":            # one scene of three models: the parameter rows padded
        P = soils["mohr_coulomb"].params.shape[1]
        rows = np.full((n, P), np.nan)
        ids = rng.integers(0, 3, n)
        rows[:, :2] = [G, K]
        rows[ids == 1, 2:6] = VM + [0.0]
        rows[ids == 2] = soils["mohr_coulomb"].params[ids == 2]
        names = ["linear_elastic", "von_mises_softening", "mohr_coulomb_softening"]
        soil = MaterialPoints(np.array([model_id(names[i]) for i in ids]), rows)
    else:
        soil = soils[case]
    ls, dF = _states(n, rng)
    if case in ("mohr_coulomb", "mixed"):
        ls[:, :3] -= 0.02                         # compression: the main plane and edges
        # an exactly repeated in-plane principal stress lies on an edge of the Mohr-Coulomb
        # surface, where its return mapping has no derivative (directional ones differ)
        ls[:n // 4, 3] += 2e-3
    state = rng.uniform(0.0, 0.8, size=(n, 1))
    tau, A = finite_strain_tangent(dF, ls, state, soil)
    tau_r, A_r = finite_strain_tangent_reference(dF, ls, state, soil)
    assert np.abs(tau - tau_r).max() <= 1e-12 * np.abs(tau_r).max()
    assert np.abs(A - A_r).max() <= 3e-14 * np.abs(A_r).max()
    # the stress of the residual evaluation may be passed in
    _, A2 = finite_strain_tangent(dF, ls, state, soil, tau=tau_r)
    assert np.abs(A2 - A_r).max() <= 3e-14 * np.abs(A_r).max()


def test_small_strain_tangent_equals_complex_step():
    """Geostatic tangent from the hook against the complex step of the model's update
    (achieves 4e-16 relative; asserts 4e-15)."""
    rng = np.random.default_rng(2)
    n = 300
    soil = _soil("von_mises_softening", VM + [0.0], n)
    ls, H = 0.02 * rng.normal(size=(n, 4)), 0.01 * rng.normal(size=(n, 2, 2))
    gam = rng.uniform(0, 0.8, (n, 1))
    _, D = small_strain_tangent(H, ls, gam, soil)
    e = ls.copy()
    e[:, 0] += H[:, 0, 0]
    e[:, 1] += H[:, 1, 1]
    e[:, 3] += 0.5 * (H[:, 0, 1] + H[:, 1, 0])
    ref = _complex_step_stiffness(e, gam, soil)
    scale = np.abs(ref).max()
    for k, (l, m, f) in enumerate(((0, 0, 1.0), (1, 1, 1.0), (0, 1, 0.5))):
        assert np.abs(D[:, 0, 0, l, m] - f * ref[:, 0, k]).max() <= 4e-15 * scale
        assert np.abs(D[:, 1, 1, l, m] - f * ref[:, 1, k]).max() <= 4e-15 * scale
        assert np.abs(D[:, 0, 1, l, m] - f * ref[:, 3, k]).max() <= 4e-15 * scale
    assert np.array_equal(D[..., 0, 1], D[..., 1, 0])


def _spd(n, seed, shift=0.0):
    """A symmetric positive-definite 2-D Laplacian-like matrix (CSR, sorted) + shift I."""
    rng = np.random.default_rng(seed)
    m = int(np.sqrt(n))
    T = sp.diags([-1, 2.2, -1], [-1, 0, 1], shape=(m, m))
    A = sp.kronsum(T, T).tocsr()
    A = A + sp.diags(rng.uniform(0.1, 0.2, A.shape[0]) + shift)
    A = sp.csr_matrix(A)
    A.sort_indices()
    return A


def test_cholmod_solves_like_superlu_and_reuses_the_symbolic_analysis():
    """Two matrices of one pattern: one symbolic analysis, both solved to a relative
    residual of 3e-16 (asserts 3e-15) and equal to SuperLU's solution to 7e-16 (asserts
    7e-15)."""
    pytest.importorskip("cvxopt")
    A1, A2 = _spd(900, 0), _spd(900, 1)
    b = np.random.default_rng(5).normal(size=A1.shape[0])
    s = LinearSolver("cholmod")
    for A in (A1, A2):
        x = s.solve(A, b)
        assert np.linalg.norm(A @ x - b) <= 3e-15 * np.linalg.norm(b)
        xs = LinearSolver("superlu").solve(A, b)
        assert np.abs(x - xs).max() <= 7e-15 * np.abs(xs).max()
    assert s.symbolic_analyses == 1
    assert s.factorizations_by == {"cholmod": 2, "superlu": 0}


def test_cholmod_hands_non_symmetric_and_indefinite_tangents_to_superlu():
    pytest.importorskip("cvxopt")
    A = _spd(400, 0)
    b = np.ones(A.shape[0])
    s = LinearSolver("cholmod")
    N = A.copy()
    N.data[3] *= 1.001                            # F-bar or non-associated flow
    x = s.solve(N, b)
    assert np.linalg.norm(N @ x - b) <= 1e-12 * np.linalg.norm(b)
    indefinite = sp.csr_matrix(A - 3.0 * sp.identity(A.shape[0]))
    indefinite.sort_indices()
    x = s.solve(indefinite, b)
    assert np.linalg.norm(indefinite @ x - b) <= 1e-10 * np.linalg.norm(b)
    unsymmetric_pattern = sp.csr_matrix(A + sp.diags([0.01], [1], shape=A.shape))
    unsymmetric_pattern.sort_indices()
    x = s.solve(unsymmetric_pattern, b)
    assert np.linalg.norm(unsymmetric_pattern @ x - b) <= 1e-12 * np.linalg.norm(b)
    assert s.factorizations_by == {"cholmod": 0, "superlu": 3}
