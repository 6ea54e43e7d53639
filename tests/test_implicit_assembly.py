"""The finite-strain tangent assembled in one compiled pass into the lower triangle
(:meth:`StepSystem.finite_strain_tangent`) against the pieces it joins: the spatial
tangent of :func:`.tangent_kernels.spatial_tangent` assembled into the whole matrix by
:meth:`StepSystem.tangent` (the path it replaces, itself tested against scikit-fem's
assembly in ``tests/test_implicit.py``), on the reference slope's points with von Mises
softening states on every branch (elastic, softening slope, residual)."""
from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse.linalg as spla

from fem_rmpm import api
from tests.conftest import MESHES
from fem_rmpm.materials import return_map
from fem_rmpm.schemes.implicit import LinearSolver
from fem_rmpm.schemes.implicit import tangent_kernels as tk
from fem_rmpm.schemes.implicit.assembly import StepSystem
from fem_rmpm.schemes.implicit.linear import LowerTangent
from fem_rmpm.schemes.implicit.tangent import elastic_left_cauchy_green, finite_strain_parts


@pytest.fixture(scope="module")
def slope_step():
    """A dynamic step's system (occupied cells and halo) on the reference slope's points
    and a trial state at each point: ``dF`` near the identity, plastic on about half."""
    sc = api.load_scene(MESHES / "slope_reference.toml")
    grid, pts = api.prepare(sc)
    S = StepSystem(grid, pts.x, halo=True)
    rng = np.random.default_rng(11)
    n = S.n
    soil = pts.soil.take(np.arange(n))
    soil.params = np.ascontiguousarray(soil.params)
    ls0 = 0.01 * rng.normal(size=(n, 4))
    state = np.ascontiguousarray(pts.state.copy())
    state[:, -1] = rng.uniform(0.0, 1.0, n)           # softening variable: every branch
    dF = np.eye(2) + 0.02 * rng.normal(size=(n, 2, 2))
    B = elastic_left_cauchy_green(ls0)
    D, cols, J = finite_strain_parts(dF, ls0, state, soil, B)
    eps_tr = np.empty((n, 4))
    eps_tr[:, 2] = ls0[:, 2]
    tk.trial_jacobian(dF, B, eps_tr, np.empty((n, 3, 3)))
    _, g_new, tau = return_map(eps_tr, state, soil)
    g = np.einsum("pal,plj->paj", S.dN, np.linalg.inv(dF))
    return S, pts.volume0, g, D, cols, J, tau, np.abs(g_new - state).max(axis=1) > 0


@pytest.mark.parametrize("factor", [1.0, 0.9], ids=["trapezoidal", "hht"])
def test_lower_triangle_equals_the_whole_matrix_bitwise(slope_step, factor):
    """Every entry of the lower triangle equals the whole matrix's (spatial tangent, then
    the block assembly; measured: 0 difference), the points' tangents pass the symmetry
    check, and CHOLMOD on the triangle solves as SuperLU on the whole matrix (achieves
    7e-16 relative; asserts 1e-12)."""
    S, V0, g, D, cols, J, tau, plastic = slope_step
    assert 0.2 < plastic.mean() < 0.9
    diagonal = np.full(S.n_free, 1.0e3)
    K = S.finite_strain_tangent(V0, g, D, cols, J, tau, factor, diagonal)
    assert isinstance(K, LowerTangent)
    A = tk.spatial_tangent(D[:, :, cols], J, tau, np.empty((S.n, 2, 2, 2, 2)))
    full = S.tangent(V0, g, A if factor == 1.0 else factor * A, diagonal)
    row = np.repeat(np.arange(S.n_free), np.diff(full.indptr))
    assert np.array_equal(K.lower_data, full.data[full.indices >= row])
    assert np.array_equal(K.full().data, full.data)
    b = np.random.default_rng(2).normal(size=S.n_free)
    solver = LinearSolver("cholmod")
    solver.new_step(S)
    x = solver.solve(K, b)
    ref = spla.spsolve(full.tocsc(), b)
    assert solver.factorizations_by == {"cholmod": 1, "superlu": 0}
    assert np.abs(x - ref).max() <= 1e-12 * np.abs(ref).max()


def test_a_tangent_without_major_symmetry_is_left_to_the_whole_matrix(slope_step):
    """A model stiffness that breaks ``A_ijlm = A_lmij`` at one point (as non-associated
    flow does) makes the one-pass assembly decline (None): the caller assembles the whole
    matrix, which the linear solver checks and hands to SuperLU."""
    S, V0, g, D, cols, J, tau, _ = slope_step
    bad = D.copy()
    bad[7, 3, cols[0]] += 50.0                       # d tau_xy / d eps_xx only
    assert S.finite_strain_tangent(V0, g, bad, cols, J, tau, 1.0) is None
    assert isinstance(S.finite_strain_tangent(V0, g, D, cols, J, tau, 1.0), LowerTangent)
