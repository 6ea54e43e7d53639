"""Basis functions of the background grid evaluated at material points.

Two ways, checked against each other in ``tests/test_shape.py``:

* :func:`q4_at_points` — the fast path used in every step: bilinear Q4 values and
  physical gradients from the local coordinates of the structured grid, fully
  vectorised (no mapping objects).
* :func:`skfem_point_basis` — scikit-fem's own ``ElementQuad1`` / ``ElementVector``
  basis with the material points as quadrature points (one "element" per point,
  repeated host cells allowed), used to assemble the implicit tangent and for
  verification.  Weights are 1 and volumes are passed to the forms, because a
  scikit-fem quadrature weight cannot differ between elements.
"""
from __future__ import annotations

import numpy as np
from skfem import CellBasis, ElementQuad1, ElementVector
from skfem.mapping import MappingIsoparametric

from fem_rmpm.discretise.grid import Grid, locate

__all__ = ["q4_values", "q4_at_points", "gimp_at_points", "shape_at_points", "skfem_point_basis"]

# local node coordinates in scikit-fem's reference square, counter-clockwise
_CORNERS = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])


def q4_values(xi: np.ndarray, cell_size: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Bilinear shape values (n, 4) and physical gradients (n, 4, 2) at local coords ``xi``."""
    s, t = xi[:, 0:1], xi[:, 1:2]
    cs = 2 * _CORNERS - 1                                   # +-1 sign pattern
    fs = (1 - _CORNERS[:, 0]) + cs[:, 0] * s                 # (n, 4): 1-s or s
    ft = (1 - _CORNERS[:, 1]) + cs[:, 1] * t
    N = fs * ft
    dN = np.empty(N.shape + (2,))
    dN[..., 0] = cs[:, 0] * ft / cell_size[0]
    dN[..., 1] = fs * cs[:, 1] / cell_size[1]
    return N, dN


def q4_at_points(grid: Grid, x: np.ndarray):
    """Host cells, node indices (n, 4), values (n, 4), gradients (n, 4, 2) and inside mask."""
    cell, xi, inside = locate(grid, x)
    N, dN = q4_values(xi, grid.cell)
    return cell, grid.cells[cell], N, dN, inside


def _gimp_1d(d: np.ndarray, h: float, lp: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """uGIMP weight and its derivative for node distance ``d = x - x_I`` (Bardenhagen &
    Kober 2004), particle half-width ``lp <= h/2``."""
    a = np.abs(d)
    sg = np.sign(d)
    inner = a < lp
    mid = (a >= lp) & (a <= h - lp)
    outer = (a > h - lp) & (a < h + lp)
    S = np.where(inner, 1 - (d * d + lp * lp) / (2 * h * lp),
                 np.where(mid, 1 - a / h, np.where(outer, (h + lp - a) ** 2 / (4 * h * lp), 0.0)))
    dS = np.where(inner, -d / (h * lp),
                  np.where(mid, -sg / h, np.where(outer, -sg * (h + lp - a) / (2 * h * lp), 0.0)))
    return S, dS


def gimp_at_points(grid: Grid, x: np.ndarray, half_width: np.ndarray):
    """uGIMP basis: host cells, nodes (n, 9), values (n, 9), gradients (n, 9, 2), inside mask.

    ``half_width`` (n, 2) is the particle half-size lp (m), fixed at its initial
    value (h / (2 ppc)).  Each point sees the 3 x 3 nodes around it.  At the grid
    edge the weight of a node beyond the edge is added to the edge node, which
    keeps the partition of unity and sum of gradients = 0 (so a roller edge stays
    frictionless).  Where a particle lies wholly inside one cell, uGIMP equals Q4
    with the weights averaged over the particle domain.
    """
    cell, xi, inside = locate(grid, x)
    nx, ny = grid.shape
    ic, jc = cell % nx, cell // nx
    vals, ders, idx = [], [], []
    for k, (c, h, n_nodes) in enumerate(((ic, grid.cell[0], nx + 1), (jc, grid.cell[1], ny + 1))):
        first = c + np.where(xi[:, k] < 0.5, -1, 0)            # first of 3 nodes
        nodes = first[:, None] + np.arange(3)                   # (n, 3) unclipped
        d = x[:, k:k + 1] - (grid.origin[k] + nodes * h)
        S, dS = _gimp_1d(d, h, half_width[:, k:k + 1])
        vals.append(S)
        ders.append(dS)
        idx.append(np.clip(nodes, 0, n_nodes - 1))
    Sx, Sy = vals
    dSx, dSy = ders
    N = (Sx[:, None, :] * Sy[:, :, None]).reshape(len(x), 9)    # node (a, b): y-major
    dN = np.empty((len(x), 9, 2))
    dN[..., 0] = (dSx[:, None, :] * Sy[:, :, None]).reshape(len(x), 9)
    dN[..., 1] = (Sx[:, None, :] * dSy[:, :, None]).reshape(len(x), 9)
    nodes = (idx[1][:, :, None] * (nx + 1) + idx[0][:, None, :]).reshape(len(x), 9)
    return cell, nodes, N, dN, inside


def shape_at_points(grid: Grid, x: np.ndarray, kind: str = "standard", half_width=None):
    """Dispatch: ``standard`` Q4 (4 nodes per point) or ``gimp`` (9 nodes per point)."""
    if kind == "gimp":
        return gimp_at_points(grid, x, half_width)
    return q4_at_points(grid, x)


def skfem_point_basis(grid: Grid, x: np.ndarray, vector: bool = True) -> CellBasis:
    """scikit-fem basis whose quadrature points are the material points ``x`` (n, 2).

    A fresh :class:`MappingIsoparametric` is built on each call (reusing the
    mesh's cached mapping leaks memory when called every step).  ``dx`` of the
    returned basis is the cell Jacobian, not the point volume: multiply by
    ``volume / dx`` in the form.
    """
    cell, xi, _ = locate(grid, x)
    elem = ElementVector(ElementQuad1()) if vector else ElementQuad1()
    mapping = MappingIsoparametric(grid.mesh, ElementQuad1())
    X = xi.T[:, :, None]                                    # (2, n_points, 1)
    return CellBasis(grid.mesh, elem, mapping=mapping, elements=cell,
                     quadrature=(X, np.ones(1)))
