"""Three-dimensional background grid: a structured hexahedral mesh (scikit-fem ``MeshHex``,
``ElementHex1``), its six boundary faces, the soil cells and point location.

Nodes are numbered x fastest, then y, then z: ``node = i + (nx+1) (j + (ny+1) k)``; cells
likewise, ``cell = ic + nx (jc + ny kc)``.  The eight nodes of a cell are listed in the
order of ``ElementHex1``'s own node table (:data:`HEX_CORNERS`, the reference corners
``(1,1,1), (1,1,0), ...``), **not** in the order of ``MeshHex.init_tensor``'s cells
(``(0,0,0), (0,1,0), (1,0,0), ...``): scikit-fem maps an element's reference cube through
that table, so only with it do a point's cell-local coordinates ``(x - x_cell) / h`` equal
its reference coordinates, and the compiled trilinear basis
(:mod:`fem_rmpm.discretise.basis3d`) equals scikit-fem's (``tests/test_3d_grid.py``).
Vector DOFs follow ``ElementVector``: ``dof = 3 node + component``.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
from skfem import ElementHex1, MeshHex

from fem_rmpm.discretise.grid import _on_or_in_polygon, points_in_polygon
from fem_rmpm.scene import Scene
from fem_rmpm.scene.dimension import strike_range

__all__ = ["Grid3D", "HEX_CORNERS", "make_grid_3d", "locate_3d", "soil_cells_3d",
           "fixed_dofs_3d"]

#: The reference corners of ``ElementHex1``'s nodes, in its order (8, 3) of 0 / 1.
HEX_CORNERS = np.asarray(ElementHex1().doflocs, dtype=np.int64)


@dataclass(frozen=True)
class Grid3D:
    """Structured hexahedral background grid (all lengths in m)."""
    origin: np.ndarray            # (3,) lowest corner
    cell: np.ndarray              # (3,) cell size hx, hy, hz
    shape: tuple[int, int, int]   # (nx, ny, nz) cells
    fixed: np.ndarray             # (n_nodes, 3) bool: displacement component prescribed zero

    dimension = 3

    @property
    def n_nodes(self) -> int:
        nx, ny, nz = self.shape
        return (nx + 1) * (ny + 1) * (nz + 1)

    @property
    def n_cells(self) -> int:
        return self.shape[0] * self.shape[1] * self.shape[2]

    @property
    def upper(self) -> np.ndarray:
        return self.origin + self.cell * np.array(self.shape)

    @property
    def nodes(self) -> np.ndarray:
        """(n_nodes, 3) node coordinates, m."""
        return node_coordinates(self.origin, self.cell, self.shape)

    @cached_property
    def cells(self) -> np.ndarray:
        """(n_cells, 8) node indices of each cell, in ``ElementHex1``'s node order."""
        return cell_nodes(self.shape, np.arange(self.n_cells))

    @property
    def mesh(self) -> MeshHex:
        """The scikit-fem mesh of all cells (built on demand: the FEM reference, VTK)."""
        return MeshHex(self.nodes.T.copy(), self.cells.T.copy(), validate=False)

    def cell_centres(self, cells: np.ndarray | None = None) -> np.ndarray:
        """(n, 3) centres of ``cells`` (all if None), m."""
        idx = np.arange(self.n_cells) if cells is None else np.asarray(cells)
        return self.origin + self.cell * (cell_index(self.shape, idx) + 0.5)


def node_coordinates(origin, cell, shape) -> np.ndarray:
    nx, ny, nz = shape
    k, j, i = np.meshgrid(np.arange(nz + 1), np.arange(ny + 1), np.arange(nx + 1),
                          indexing="ij")
    ijk = np.stack([i.ravel(), j.ravel(), k.ravel()], axis=1)
    return np.asarray(origin, float) + np.asarray(cell, float) * ijk


def cell_index(shape, cells: np.ndarray) -> np.ndarray:
    """(n, 3) integer (ic, jc, kc) of cell numbers ``cells``."""
    nx, ny, _ = shape
    return np.stack([cells % nx, (cells // nx) % ny, cells // (nx * ny)], axis=1)


def cell_nodes(shape, cells: np.ndarray) -> np.ndarray:
    """(n, 8) nodes of ``cells`` in ``ElementHex1``'s order (:data:`HEX_CORNERS`)."""
    nx, ny, _ = shape
    ijk = cell_index(shape, cells)[:, None, :] + HEX_CORNERS[None]
    return ijk[..., 0] + (nx + 1) * (ijk[..., 1] + (ny + 1) * ijk[..., 2])


def soil_cells_3d(scene: Scene, grid: Grid3D) -> np.ndarray:
    """(n_cells,) soil index of each cell (-1: empty): its centre inside the soil's section
    (x, y), strike range (z) and plan shape (x, z); later soils overwrite earlier ones, and
    a centre inside a ``[[bedrock]]`` section leaves the cell empty."""
    owner = np.full(grid.n_cells, -1)
    c = grid.cell_centres()
    for k, soil in enumerate(scene.soils):
        z0, z1 = strike_range(scene, soil)
        inside = points_in_polygon(c[:, :2], np.array(soil.polygon))
        inside &= (c[:, 2] > z0) & (c[:, 2] < z1)
        if soil.plan is not None:
            inside &= points_in_polygon(c[:, [0, 2]], np.array(soil.plan))
        owner[inside] = k
    for rock in scene.bedrock:
        owner[points_in_polygon(c[:, :2], np.array(rock.polygon))] = -1
    return owner


def fixed_dofs_3d(scene: Scene, nodes: np.ndarray, origin, upper, cell) -> np.ndarray:
    """(n_nodes, 3) mask of prescribed (zero) components: on each of the six faces
    ``fixed`` holds all three, ``roller`` the normal one, ``free`` none (``front`` /
    ``back``: default roller); every node inside or on a ``[[bedrock]]`` section (all z)
    is fixed."""
    tol = 1e-9 * float(np.max(upper - origin))
    fixed = np.zeros((len(nodes), 3), dtype=bool)
    b = scene.boundary
    faces = (("left", b.left, 0, False), ("right", b.right, 0, True),
             ("bottom", b.bottom, 1, False), ("top", b.top, 1, True),
             ("front", b.front or "roller", 2, False), ("back", b.back or "roller", 2, True))
    for _, kind, axis, high in faces:
        on = (nodes[:, axis] >= upper[axis] - tol) if high else \
            (nodes[:, axis] <= origin[axis] + tol)
        if kind == "fixed":
            fixed[on] = True
        elif kind == "roller":
            fixed[on, axis] = True
    for rock in scene.bedrock:
        fixed[_on_or_in_polygon(nodes[:, :2], np.array(rock.polygon),
                                1e-6 * float(np.min(cell)))] = True
    return fixed


def make_grid_3d(scene: Scene) -> Grid3D:
    """The hexahedral background grid of a three-dimensional scene."""
    origin = np.array(scene.grid.origin, dtype=float)
    cell = np.array(scene.grid.cell, dtype=float)
    shape = tuple(int(round(scene.grid.size[k] / cell[k])) for k in range(3))
    upper = origin + cell * np.array(shape)
    fixed = fixed_dofs_3d(scene, node_coordinates(origin, cell, shape), origin, upper, cell)
    return Grid3D(origin=origin, cell=cell, shape=shape, fixed=fixed)


def locate_3d(grid: Grid3D, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Host cell (n,), local coordinates (n, 3) in [0, 1] (the reference cube of
    ``ElementHex1`` through :attr:`Grid3D.cells`) and ``inside`` (n,) of points ``x``."""
    s = (x - grid.origin) / grid.cell
    n = np.array(grid.shape)
    inside = ((s >= 0) & (s <= n)).all(axis=1)
    ijk = np.clip(np.floor(s).astype(np.int64), 0, n - 1)
    nx, ny, _ = grid.shape
    return ijk[:, 0] + nx * (ijk[:, 1] + ny * ijk[:, 2]), s - ijk, inside
