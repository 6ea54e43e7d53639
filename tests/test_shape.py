"""Basis functions at material points: the fast path against scikit-fem, and uGIMP."""
from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from fem_rmpm.discretise.basis import gimp_at_points, q4_at_points, skfem_point_basis
from fem_rmpm.discretise.grid import make_grid
from fem_rmpm.scene import load_scene


def _grid(meshes):
    return make_grid(load_scene(meshes / "slope_elastic.toml"))


def test_fast_q4_equals_scikit_fem_basis(meshes):
    """The vectorised Q4 values/gradients equal scikit-fem's ElementQuad1 basis evaluated
    at the same points through MappingIsoparametric (scikit-fem is the reference)."""
    grid = _grid(meshes)
    rng = np.random.default_rng(1)
    x = grid.origin + rng.random((500, 2)) * (grid.upper - grid.origin)
    cell, nodes, N, dN, inside = q4_at_points(grid, x)
    assert inside.all()
    basis = skfem_point_basis(grid, x, vector=False)
    # basis.basis[i][0].value has shape (n_points, 1): local dof i of each point's cell
    for a in range(4):
        val = np.asarray(basis.basis[a][0])[:, 0]
        grad = basis.basis[a][0].grad[:, :, 0].T
        assert np.allclose(val, N[:, a], atol=1e-13)
        assert np.allclose(grad, dN[:, a, :], atol=1e-11)
    assert np.array_equal(basis.element_dofs.T, nodes)


@settings(max_examples=40, deadline=None)
@given(st.floats(0.0, 1.0), st.floats(0.0, 1.0), st.floats(0.02, 0.98), st.floats(0.02, 0.98),
       st.floats(-3.0, 3.0), st.floats(-3.0, 3.0), st.floats(-3.0, 3.0))
def test_gimp_partition_of_unity_and_linear_completeness(meshes_dir_fx, ci, cj, sx, sy, a, b, c):
    """uGIMP (Bardenhagen & Kober 2004): sum N = 1, sum dN = 0, and a linear field
    a + b x + c y is reproduced with its exact gradient, anywhere in the grid interior:
    hypothesis draws the cell (every cell whose particle domain, a quarter cell, stays off
    the grid edge: columns 1 .. nx-2, rows 1 .. ny-2) and the position inside it."""
    grid = meshes_dir_fx
    nx, ny = grid.shape
    i, j = 1 + round(ci * (nx - 3)), 1 + round(cj * (ny - 3))
    x = grid.origin + grid.cell * (np.array([[i, j]]) + np.array([[sx, sy]]))
    _, nodes, N, dN, _ = gimp_at_points(grid, x, np.tile(grid.cell / 4, (1, 1)))
    assert abs(N.sum() - 1) < 1e-12
    assert np.allclose(dN.sum(axis=1), 0, atol=1e-10)
    xn = grid.nodes[nodes[0]]
    f = a + b * xn[:, 0] + c * xn[:, 1]
    assert abs(N[0] @ f - (a + b * x[0, 0] + c * x[0, 1])) < 1e-10
    assert np.allclose(dN[0].T @ f, [b, c], atol=1e-9)


def test_gimp_equals_q4_cell_average_when_inside_one_cell(meshes):
    """Where a particle domain lies inside one cell, uGIMP weights are the Q4 functions
    averaged over the domain: for a bilinear basis that is Q4 at the particle centre."""
    grid = _grid(meshes)
    x = grid.origin + grid.cell * np.array([[30.25, 3.75], [12.6, 2.4]])
    lp = np.tile(grid.cell / 5, (2, 1))                        # domain well inside the cell
    _, nq, Nq, _, _ = q4_at_points(grid, x)
    _, ng, Ng, _, _ = gimp_at_points(grid, x, lp)
    for p in range(2):
        w = dict.fromkeys(ng[p], 0.0)
        for node, val in zip(ng[p], Ng[p]):
            w[node] += val
        for node, val in zip(nq[p], Nq[p]):
            assert abs(w[node] - val) < 1e-12


def test_gimp_edge_folding_keeps_partition_of_unity(meshes):
    """Points whose domain crosses the grid edge: the outside node's weight is folded onto
    the edge node, so sum N = 1 and sum dN = 0 still hold (a roller edge stays frictionless)."""
    grid = _grid(meshes)
    x = grid.origin + grid.cell * np.array([[0.1, 0.1], [0.05, 3.5]])
    _, nodes, N, dN, _ = gimp_at_points(grid, x, np.tile(grid.cell / 4, (2, 1)))
    assert np.allclose(N.sum(1), 1, atol=1e-12)
    assert np.allclose(dN.sum(1), 0, atol=1e-10)
    assert nodes.min() >= 0
