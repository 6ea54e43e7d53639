"""The hexahedral grid of three-dimensional scenes: node order, the trilinear basis against
scikit-fem's own, the six boundary faces and the soil cells of an extruded section with a
plan shape."""
from __future__ import annotations

import numpy as np
import pytest
from skfem import CellBasis, ElementHex1, MeshHex

from fem_rmpm.discretise.basis3d import hex8_at_points, hex8_compiled
from fem_rmpm.discretise.grid3d import HEX_CORNERS, make_grid_3d, soil_cells_3d
from fem_rmpm.scene import scene_from_dict


def _scene(**over):
    data = {"grid": {"origin": [1.0, -2.0, 0.5], "size": [3.0, 2.0, 1.5],
                     "cell": [0.5, 0.25, 0.5]},
            "boundary": {"left": "roller", "right": "fixed", "bottom": "fixed",
                         "top": "free", "front": "roller", "back": "free"},
            "soil": [{"polygon": [[1, -2], [4, -2], [4, -1], [1, -1]], "unit_weight": 20.0,
                      "youngs_modulus": 1e3, "poisson_ratio": 0.3}]}
    for k, v in over.items():
        data[k] = v
    return scene_from_dict(data)


def test_element_node_table_is_not_the_tensor_mesh_order():
    """The trap the grid avoids: ``MeshHex.init_tensor`` lists a cell's corners as (0,0,0),
    (0,1,0), (1,0,0), ... while ``ElementHex1``'s node table starts at (1,1,1); the grid's
    cells follow the element's table, so corner a of a cell is at x_cell + h c_a."""
    m = MeshHex.init_tensor(np.arange(2.0), np.arange(2.0), np.arange(2.0))
    assert not np.array_equal(m.p.T[m.t[:, 0]], HEX_CORNERS)
    grid = make_grid_3d(_scene())
    lower = grid.nodes[grid.cells[:, 0]] - grid.cell       # corner (1,1,1) minus h
    want = lower[:, None, :] + HEX_CORNERS[None] * grid.cell
    assert np.allclose(grid.nodes[grid.cells], want, atol=1e-12)


@pytest.mark.parametrize("compiled", [False, True])
def test_trilinear_basis_equals_scikit_fem_at_points(compiled):
    """Values and physical gradients at 200 random points in the grid (some on cell faces)
    equal scikit-fem's ``ElementHex1`` basis on the grid's ``MeshHex`` evaluated at the same
    reference points of the host cells, to 1e-12 (achieved ~1e-15)."""
    grid = make_grid_3d(_scene())
    rng = np.random.default_rng(3)
    x = grid.origin + rng.random((200, 3)) * (grid.upper - grid.origin)
    x[:20, 0] = grid.origin[0] + grid.cell[0] * rng.integers(0, grid.shape[0], 20)  # faces
    cell, nodes, N, dN, inside = hex8_at_points(grid, x)
    assert inside.all()
    if compiled:
        nodes, N, dN = hex8_compiled(x, grid.origin, grid.cell, np.array(grid.shape))
    mesh = grid.mesh
    for i in range(len(x)):
        xi = (x[i] - mesh.p[:, mesh.t[7, cell[i]]]) / grid.cell   # corner (0,0,0) is node 7
        b = CellBasis(mesh, ElementHex1(), quadrature=(xi[:, None], np.ones(1)),
                      elements=np.array([cell[i]]))
        dofs = b.element_dofs[:, 0]
        assert np.array_equal(dofs, nodes[i])
        for a in range(8):
            phi = b.basis[a][0]
            assert abs(np.asarray(phi)[0, 0] - N[i, a]) < 1e-12
            assert np.abs(phi.grad[:, 0, 0] - dN[i, a]).max() < 1e-12
    assert np.allclose(N.sum(axis=1), 1.0, atol=1e-14)


def test_six_faces_fix_their_components():
    """fixed: all three components; roller: the normal one; free: none (z = back here)."""
    grid = make_grid_3d(_scene())
    p, lo, hi = grid.nodes, grid.origin, grid.upper
    tol = 1e-9
    left, right = p[:, 0] < lo[0] + tol, p[:, 0] > hi[0] - tol
    bottom, top = p[:, 1] < lo[1] + tol, p[:, 1] > hi[1] - tol
    front, back = p[:, 2] < lo[2] + tol, p[:, 2] > hi[2] - tol
    assert grid.fixed[left, 0].all() and grid.fixed[right].all() and grid.fixed[bottom].all()
    assert grid.fixed[front, 2].all()
    inner = ~(left | right | bottom | front)
    assert not grid.fixed[inner].any()
    assert not grid.fixed[back & ~(left | right | bottom), :2].any()
    assert not grid.fixed[top & ~(left | right | front | bottom)].any()


def test_soil_cells_follow_section_strike_and_plan():
    """A cell is soil when its centre is in the x-y section, in the strike range and in the
    plan polygon (x-z)."""
    soil = {"polygon": [[1, -2], [4, -2], [4, -1], [1, -1]], "unit_weight": 20.0,
            "youngs_modulus": 1e3, "poisson_ratio": 0.3, "strike": [0.5, 1.5],
            "plan": [[1, 0.5], [3, 0.5], [3, 2], [1, 2]]}
    scene = _scene(soil=[soil])
    grid = make_grid_3d(scene)
    owner = soil_cells_3d(scene, grid)
    c = grid.cell_centres()
    want = (c[:, 1] < -1) & (c[:, 2] < 1.5) & (c[:, 0] < 3)
    assert np.array_equal(owner >= 0, want) and want.sum() == 4 * 4 * 2
