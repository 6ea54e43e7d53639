"""VTK output of a three-dimensional run: the hexahedral grid's soil cells (``grid.vtu``).

The points use the plane-strain writer as they are (:func:`fem_rmpm.io.output.write_particles`:
three coordinates and six stress components ``[xx, yy, zz, xy, yz, xz]``).  VTK numbers a
hexahedron's corners ``(0,0,0), (1,0,0), (1,1,0), (0,1,0), (0,0,1), (1,0,1), (1,1,1),
(0,1,1)``, not in ``ElementHex1``'s order (:data:`fem_rmpm.discretise.grid3d.HEX_CORNERS`):
the cells are reordered here (``tests/test_3d_output.py`` reads them back with pyvista and
checks positive cell volumes).
"""
from __future__ import annotations

from pathlib import Path

import meshio
import numpy as np

from fem_rmpm.discretise.grid3d import HEX_CORNERS, Grid3D

__all__ = ["write_grid_3d", "VTK_HEX_ORDER"]

_VTK_CORNERS = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0],
                         [0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]])
#: VTK_HEX_ORDER[v] = the ElementHex1 local node at VTK corner v.
VTK_HEX_ORDER = np.array([int(np.nonzero((HEX_CORNERS == c).all(axis=1))[0][0])
                          for c in _VTK_CORNERS])


def write_grid_3d(path: str | Path, grid: Grid3D, cells: np.ndarray) -> None:
    """The hexahedra ``cells`` of ``grid`` (their used nodes only) to ``path`` (.vtu)."""
    conn = grid.cells[cells][:, VTK_HEX_ORDER]
    used = np.unique(conn)
    remap = np.full(grid.n_nodes, -1, dtype=np.int64)
    remap[used] = np.arange(len(used))
    nodes = grid.nodes[used]
    fixed = grid.fixed[used].astype(np.int8)
    mesh = meshio.Mesh(nodes, [("hexahedron", remap[conn])],
                       point_data={"fixed": fixed},
                       cell_data={"cell": [np.asarray(cells, dtype=np.int64)]})
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp.vtu")
    mesh.write(tmp, binary=True)
    tmp.replace(path)
