"""Static FEM reference in three dimensions: linear elasticity under gravity on scikit-fem.

The mesh is the scene's hexahedral grid restricted to the soil cells (the cells the
material points are seeded in), trilinear hexahedra (``ElementHex1`` through
``ElementVector``), 2 x 2 x 2 Gauss integration, the grid's fixed DOFs of the six faces and
the bedrock.  Its Gauss points are where the material points are seeded, so the explicit
geostatic state is compared with it point by point (``tests/test_3d_explicit.py``).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse.linalg import splu
from skfem import Basis, BilinearForm, ElementHex1, ElementVector, LinearForm, asm
from skfem.helpers import ddot, sym_grad, trace

from fem_rmpm.discretise.grid3d import Grid3D, make_grid_3d, soil_cells_3d
from fem_rmpm.discretise.points import density
from fem_rmpm.scene import Scene

__all__ = ["Fem3DResult", "solve_static_3d"]


@dataclass
class Fem3DResult:
    """Nodal displacement (n_nodes, 3) m and Gauss-point fields of the soil cells."""
    grid: Grid3D
    cells: np.ndarray          # (n_soil_cells,) grid cell indices
    displacement: np.ndarray   # (n_nodes, 3) m
    points: np.ndarray         # (n_gp, 3) Gauss-point coordinates, m
    stress: np.ndarray         # (n_gp, 6) Cauchy stress [xx, yy, zz, xy, yz, xz], kPa
    volume: np.ndarray         # (n_gp,) Gauss weight x detJ, m3


@BilinearForm
def _elasticity(u, v, w):
    eu, ev = sym_grad(u), sym_grad(v)
    return 2.0 * w["mu"] * ddot(eu, ev) + w["lam"] * trace(eu) * trace(ev)


@LinearForm
def _body_force(v, w):
    return w["rho"] * (w["gx"] * v[0] + w["gy"] * v[1] + w["gz"] * v[2])


def solve_static_3d(scene: Scene, grid: Grid3D | None = None) -> Fem3DResult:
    """Solve K u = f on the soil cells of a three-dimensional ``scene`` under full
    gravity (small strain); Gauss-point stresses."""
    grid = grid or make_grid_3d(scene)
    owner = soil_cells_3d(scene, grid)
    cells = np.nonzero(owner >= 0)[0]
    basis = Basis(grid.mesh, ElementVector(ElementHex1()), intorder=2, elements=cells)
    soils = scene.soils
    E = np.array([s.youngs_modulus for s in soils])[owner[cells]]
    nu = np.array([s.poisson_ratio for s in soils])[owner[cells]]
    rho = np.array([density(s.unit_weight, scene.scene.gravity) for s in soils])[owner[cells]]
    lam = (E * nu / ((1 + nu) * (1 - 2 * nu)))[:, None]
    mu = (E / (2 * (1 + nu)))[:, None]
    K = asm(_elasticity, basis, lam=lam, mu=mu)
    gx, gy = scene.gravity_vector
    f = asm(_body_force, basis, rho=rho[:, None], gx=gx, gy=gy, gz=0.0)
    used = np.zeros(grid.n_nodes, dtype=bool)
    used[grid.cells[cells].ravel()] = True
    free = (~grid.fixed & used[:, None]).ravel()           # dof = 3 node + component
    u = np.zeros(3 * grid.n_nodes)
    u[free] = splu(K[free][:, free].tocsc(), permc_spec="MMD_AT_PLUS_A").solve(f[free])
    G = basis.interpolate(u).grad                          # (3, 3, n_elems, n_qp)
    e = 0.5 * (G + np.swapaxes(G, 0, 1))
    tr = e[0, 0] + e[1, 1] + e[2, 2]
    stress = np.stack([lam * tr + 2 * mu * e[0, 0], lam * tr + 2 * mu * e[1, 1],
                       lam * tr + 2 * mu * e[2, 2], 2 * mu * e[0, 1], 2 * mu * e[1, 2],
                       2 * mu * e[0, 2]], axis=-1).reshape(-1, 6)
    points = np.moveaxis(np.asarray(basis.global_coordinates()), 0, -1).reshape(-1, 3)
    return Fem3DResult(grid=grid, cells=cells, displacement=u.reshape(-1, 3), points=points,
                       stress=stress, volume=basis.dx.reshape(-1))
