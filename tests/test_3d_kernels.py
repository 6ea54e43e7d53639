"""The stage kernels of the 3-D step (:mod:`fem_rmpm.schemes.explicit3d.kernels`) write the
trilinear basis out in factored form; here their map to the nodes and their velocity
gradient are held equal to the same sums taken with the numpy basis
(:func:`fem_rmpm.discretise.basis3d.hex8_at_points`, itself equal to scikit-fem's
``ElementHex1``, ``tests/test_3d_grid.py``) at random points of a grid with unequal cell
sides."""
from __future__ import annotations

import numpy as np

from fem_rmpm.discretise.basis3d import hex8_at_points
from fem_rmpm.discretise.grid3d import make_grid_3d
from fem_rmpm.scene import scene_from_dict
from fem_rmpm.schemes.explicit3d import kernels as K
from fem_rmpm.schemes.explicit3d.elastic import EIG_BLOCK
from fem_rmpm.schemes.explicit3d.stress3d import BLOCK_ROWS, stress_3d


def _setup(n=300):
    scene = scene_from_dict({
        "grid": {"origin": [1.0, -2.0, 0.5], "size": [3.0, 2.0, 1.5], "cell": [0.5, 0.25, 0.5]},
        "boundary": {"left": "roller", "right": "fixed", "bottom": "fixed", "top": "free",
                     "front": "roller", "back": "free"},
        "soil": [{"polygon": [[1, -2], [4, -2], [4, -1], [1, -1]], "unit_weight": 20.0,
                  "youngs_modulus": 1e3, "poisson_ratio": 0.3}]})
    grid = make_grid_3d(scene)
    rng = np.random.default_rng(5)
    x = grid.origin + rng.random((n, 3)) * (grid.upper - grid.origin)
    nn = grid.n_nodes
    arrays = dict(x=x, v=rng.normal(size=(n, 3)), mass=rng.random(n) + 0.5,
                  vol=rng.random(n) + 0.5, stress=rng.normal(size=(n, 6)) * 10.0,
                  active=np.ones(n, dtype=np.bool_), cellbase=np.zeros(n, np.int64),
                  cellxi=np.zeros((n, 3)), buf=np.zeros((nn, K.NODE_COLUMNS)),
                  touched=np.zeros(nn, np.bool_),
                  nodes=np.zeros(nn, np.int64), cell_touched=np.zeros(grid.n_cells, np.bool_),
                  cells=np.zeros(grid.n_cells, np.int64), nact=np.zeros(2, np.int64))
    return grid, arrays


def _map(grid, a):
    K.map_to_nodes_3d(a["x"], a["v"], a["mass"], a["vol"], a["stress"], a["active"],
                      grid.origin, grid.cell, np.array(grid.shape), a["cellbase"], a["cellxi"],
                      0, len(a["mass"]), a["buf"], a["touched"], a["nodes"], a["cell_touched"],
                      a["cells"], a["nact"])


def test_map_to_nodes_equals_the_numpy_basis_sums():
    """Mass, momentum and internal force ``-V sigma grad N`` at the nodes, and the listed
    nodes, equal the numpy sums to 1e-12 relative (achieved ~1e-15)."""
    grid, a = _setup()
    _map(grid, a)
    _, nodes, N, dN, _ = hex8_at_points(grid, a["x"])
    s = a["stress"]
    sig = np.stack([s[:, [0, 3, 5]], s[:, [3, 1, 4]], s[:, [5, 4, 2]]], axis=1)   # (n, 3, 3)
    nn = grid.n_nodes
    m, p, f = np.zeros(nn), np.zeros((nn, 3)), np.zeros((nn, 3))
    np.add.at(m, nodes, N * a["mass"][:, None])
    np.add.at(p, nodes, (N * a["mass"][:, None])[..., None] * a["v"][:, None, :])
    np.add.at(f, nodes, -a["vol"][:, None, None] * np.einsum("nrc,nqc->nqr", sig, dN))
    buf = a["buf"]
    for got, ref in ((buf[:, 0], m), (buf[:, 1:4], p), (buf[:, 4:7], f)):
        assert np.abs(got - ref).max() <= 1e-12 * np.abs(ref).max()
    listed = np.sort(a["nodes"][:a["nact"][0]])
    assert np.array_equal(listed, np.unique(nodes))


def test_velocity_gradient_equals_the_numpy_basis_sum():
    """The stress pass's factored velocity gradient ``sum_I v_I (x) grad N_I`` equals the
    numpy sum to 1e-12 relative: with the points' velocity as a linear field of the nodes,
    the small-strain update of the geostatic phase adds ``sym(L) dt`` to the log strain."""
    grid, a = _setup()
    _map(grid, a)
    rng = np.random.default_rng(6)
    v2 = rng.normal(size=(grid.n_nodes, 3))
    n = len(a["mass"])
    eps, be = np.zeros((n, 6)), np.zeros((n, 6))
    lam, mu = np.full(n, 1e3), np.full(n, 5e2)
    model, plastic, state = np.zeros(n, np.int64), np.zeros((n, 4)), np.zeros((n, 2))
    node = np.zeros((grid.n_nodes, K.NODE_COLUMNS))
    node[:, 1:4] = v2
    stress_3d(a["mass"], a["vol"], a["vol"].copy(), a["stress"], eps, be, lam, mu,
              a["active"], a["cellbase"], a["cellxi"], grid.cell, np.array(grid.shape), node, 0, n, 1.0, True, model, plastic, state, np.zeros(3),
              np.zeros((BLOCK_ROWS, EIG_BLOCK)), np.zeros(EIG_BLOCK, np.int64), np.zeros(4))
    _, nodes, _, dN, _ = hex8_at_points(grid, a["x"])
    L = np.einsum("nqr,nqc->nrc", v2[nodes], dN)
    ref = np.stack([L[:, 0, 0], L[:, 1, 1], L[:, 2, 2], 0.5 * (L[:, 0, 1] + L[:, 1, 0]),
                    0.5 * (L[:, 1, 2] + L[:, 2, 1]), 0.5 * (L[:, 0, 2] + L[:, 2, 0])], axis=1)
    assert np.abs(eps - ref).max() <= 1e-12 * np.abs(ref).max()
