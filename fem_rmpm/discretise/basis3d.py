"""Trilinear (``ElementHex1``) basis of the hexahedral grid at material points: compiled
per-point values (:func:`hex8_point`) and a vectorised numpy form.  The three-dimensional
step's kernels write the same basis out in factored form per stage
(:mod:`fem_rmpm.schemes.explicit3d.kernels`; ``tests/test_3d_kernels.py`` holds their
nodal sums and velocity gradient equal to those of the numpy form).

A point's local coordinates ``xi = (x - x_cell) / h`` in [0, 1]^3 are its reference
coordinates on scikit-fem's cube because :attr:`fem_rmpm.discretise.grid3d.Grid3D.cells`
lists each cell's nodes in ``ElementHex1``'s own node order (:data:`HEX_CORNERS`).  Node
``a`` with reference corner ``c_a`` has ``N_a = prod_k (c_ak xi_k + (1 - c_ak)(1 - xi_k))``
and ``dN_a / dx_k = (2 c_ak - 1) / h_k prod_{l != k} (...)`` (1/m).
``tests/test_3d_grid.py`` holds both equal to scikit-fem's basis at random points.
"""
from __future__ import annotations

import numpy as np

from fem_rmpm.discretise.grid3d import HEX_CORNERS, Grid3D, locate_3d
from fem_rmpm.runtime.compiled import inline, jit

__all__ = ["hex8_values", "hex8_at_points", "hex8_point", "hex8_compiled"]

_C = HEX_CORNERS.astype(np.float64)


def hex8_values(xi: np.ndarray, h: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Trilinear values (n, 8) and physical gradients (n, 8, 3) (1/m) at local coordinates
    ``xi`` (n, 3) of cells of size ``h`` (3,) m, in ``ElementHex1``'s node order."""
    f = _C[None] * xi[:, None, :] + (1 - _C[None]) * (1 - xi[:, None, :])   # (n, 8, 3)
    s = (2 * _C - 1) / np.asarray(h, float)                                 # (8, 3)
    N = f[..., 0] * f[..., 1] * f[..., 2]
    dN = np.empty(N.shape + (3,))
    dN[..., 0] = s[:, 0] * f[..., 1] * f[..., 2]
    dN[..., 1] = f[..., 0] * s[:, 1] * f[..., 2]
    dN[..., 2] = f[..., 0] * f[..., 1] * s[:, 2]
    return N, dN


def hex8_at_points(grid: Grid3D, x: np.ndarray):
    """Host cells (n,), node indices (n, 8), values (n, 8), gradients (n, 8, 3) and the
    inside mask (n,) of points ``x`` (n, 3), m."""
    cell, xi, inside = locate_3d(grid, x)
    N, dN = hex8_values(xi, grid.cell)
    nx, ny, _ = grid.shape
    ic, jc, kc = cell % nx, (cell // nx) % ny, cell // (nx * ny)
    ijk = np.stack([ic, jc, kc], axis=1)[:, None, :] + HEX_CORNERS[None]
    nodes = ijk[..., 0] + (nx + 1) * (ijk[..., 1] + (ny + 1) * ijk[..., 2])
    return cell, nodes, N, dN, inside


@inline
def hex8_point(s0, s1, s2, hx, hy, hz, nx, ny, nz, nodes, N, dN):
    """One point's basis from its grid coordinates ``s = (x - origin) / h`` (cells): fills
    ``nodes`` (8,) int, ``N`` (8,) and ``dN`` (8, 3) 1/m in ``ElementHex1``'s order (the
    corners of :data:`HEX_CORNERS`, written out below)."""
    i = min(max(int(np.floor(s0)), 0), nx - 1)
    j = min(max(int(np.floor(s1)), 0), ny - 1)
    k = min(max(int(np.floor(s2)), 0), nz - 1)
    a, b, c = s0 - i, s1 - j, s2 - k
    base = i + (nx + 1) * (j + (ny + 1) * k)
    sx, sy = 1, nx + 1
    sz = (nx + 1) * (ny + 1)
    # ElementHex1 corners: (1,1,1) (1,1,0) (1,0,1) (0,1,1) (1,0,0) (0,1,0) (0,0,1) (0,0,0)
    cx = (1, 1, 1, 0, 1, 0, 0, 0)
    cy = (1, 1, 0, 1, 0, 1, 0, 0)
    cz = (1, 0, 1, 1, 0, 0, 1, 0)
    for q in range(8):
        fx = a if cx[q] == 1 else 1.0 - a
        fy = b if cy[q] == 1 else 1.0 - b
        fz = c if cz[q] == 1 else 1.0 - c
        gx = (1.0 if cx[q] == 1 else -1.0) / hx
        gy = (1.0 if cy[q] == 1 else -1.0) / hy
        gz = (1.0 if cz[q] == 1 else -1.0) / hz
        nodes[q] = base + cx[q] * sx + cy[q] * sy + cz[q] * sz
        N[q] = fx * fy * fz
        dN[q, 0] = gx * fy * fz
        dN[q, 1] = fx * gy * fz
        dN[q, 2] = fx * fy * gz


@jit
def hex8_compiled(x, origin, h, shape):
    """The compiled per-point basis (:func:`hex8_point`, as the kernels call it) at points
    ``x`` (n, 3): nodes (n, 8), values (n, 8), gradients (n, 8, 3); for the tests."""
    n = x.shape[0]
    nodes, N, dN = np.empty((n, 8), np.int64), np.empty((n, 8)), np.empty((n, 8, 3))
    for i in range(n):
        hex8_point((x[i, 0] - origin[0]) / h[0], (x[i, 1] - origin[1]) / h[1],
                   (x[i, 2] - origin[2]) / h[2], h[0], h[1], h[2], shape[0], shape[1],
                   shape[2], nodes[i], N[i], dN[i])
    return nodes, N, dN
