"""Static FEM reference: plane-strain linear elasticity under gravity on scikit-fem.

The mesh is the scene's background grid restricted to the soil cells (the same
cells the material points are seeded in), Q4 elements (``ElementQuad1``),
full 2x2 Gauss integration, the grid's fixed DOFs.  This is the independent
reference every MPM scheme is checked against before a large-deformation run.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse.linalg import splu
from skfem import Basis, BilinearForm, ElementQuad1, ElementVector, LinearForm, asm
from skfem.helpers import ddot, sym_grad, trace

from fem_rmpm.discretise.grid import Grid, make_grid
from fem_rmpm.discretise.points import density, soil_cells
from fem_rmpm.scene import Scene

__all__ = ["FemResult", "solve_static", "elastic_stiffness", "gravity_load"]


@dataclass
class FemResult:
    """Nodal displacement (n_nodes, 2) in m and Gauss-point fields of the soil cells."""
    grid: Grid
    cells: np.ndarray          # (n_soil_cells,) grid cell indices
    displacement: np.ndarray   # (n_nodes, 2)
    points: np.ndarray         # (n_gp, 2) Gauss-point coordinates
    stress: np.ndarray         # (n_gp, 4) Cauchy stress [xx, yy, zz, xy], kPa
    volume: np.ndarray         # (n_gp,) Gauss weight x detJ, m2
    K: object = None           # assembled stiffness (full grid numbering)
    f: np.ndarray | None = None


@BilinearForm
def _elasticity(u, v, w):
    lam, mu = w["lam"], w["mu"]
    eu, ev = sym_grad(u), sym_grad(v)
    return 2.0 * mu * ddot(eu, ev) + lam * trace(eu) * trace(ev)


@LinearForm
def _body_force(v, w):
    return w["rho"] * (w["gx"] * v[0] + w["gy"] * v[1])


def _lame(scene: Scene, owner_cells: np.ndarray):
    """Per-element Lame constants (kPa) and density (t/m3), shape (n_elems, 1)."""
    E = np.array([s.youngs_modulus for s in scene.soils])[owner_cells]
    nu = np.array([s.poisson_ratio for s in scene.soils])[owner_cells]
    rho = np.array([density(s.unit_weight, scene.scene.gravity) for s in scene.soils])[owner_cells]
    lam = E * nu / ((1 + nu) * (1 - 2 * nu))
    mu = E / (2 * (1 + nu))
    return lam[:, None], mu[:, None], rho[:, None]


def elastic_stiffness(basis: Basis, lam: np.ndarray, mu: np.ndarray):
    """Plane-strain elastic stiffness (kN/m per m) with per-quadrature-point Lame constants."""
    return asm(_elasticity, basis, lam=lam, mu=mu)


def gravity_load(basis: Basis, rho: np.ndarray, gravity) -> np.ndarray:
    """Nodal gravity load (kN per m): integral of rho g . v."""
    return asm(_body_force, basis, rho=rho, gx=gravity[0], gy=gravity[1])


def solve_static(scene: Scene, grid: Grid | None = None) -> FemResult:
    """Solve K u = f for the soil cells of ``scene`` under full gravity (small strain)."""
    grid = grid or make_grid(scene)
    owner = soil_cells(scene, grid)
    cells = np.nonzero(owner >= 0)[0]
    basis = Basis(grid.mesh, ElementVector(ElementQuad1()), intorder=2, elements=cells)
    lam, mu, rho = _lame(scene, owner[cells])
    K = elastic_stiffness(basis, lam, mu)
    f = gravity_load(basis, rho, scene.gravity_vector)
    used = np.zeros(grid.n_nodes, dtype=bool)
    used[grid.cells[cells].ravel()] = True
    free = (~grid.fixed & used[:, None]).ravel()           # dof = 2 node + component
    u = np.zeros(2 * grid.n_nodes)
    Kff = K[free][:, free].tocsc()
    u[free] = splu(Kff, permc_spec="MMD_AT_PLUS_A").solve(f[free])
    # Gauss-point stresses (plane strain: sigma_zz = lam tr(eps))
    ub = basis.interpolate(u)
    G = ub.grad                                            # (2, 2, n_elems, n_qp)
    exx, eyy, exy = G[0, 0], G[1, 1], 0.5 * (G[0, 1] + G[1, 0])
    tr = exx + eyy
    stress = np.stack([lam * tr + 2 * mu * exx, lam * tr + 2 * mu * eyy, lam * tr,
                       2 * mu * exy], axis=-1).reshape(-1, 4)
    points = np.moveaxis(np.asarray(basis.global_coordinates()), 0, -1).reshape(-1, 2)
    volume = (basis.dx).reshape(-1)
    return FemResult(grid=grid, cells=cells, displacement=u.reshape(-1, 2), points=points,
                     stress=stress, volume=volume, K=K, f=f)
