"""Intact blocks of the sliding mass: connected groups of grid cells holding sliding points
that are still intact (little plastic strain), at least a physical least area."""
from __future__ import annotations

import math

import numpy as np
from scipy import ndimage

__all__ = ["INTACT_BLOCK_AREA", "intact_blocks", "least_cells"]

INTACT_BLOCK_AREA = 1.0    #: m2: least area of an intact block (4 cells of 0.5 m)


def intact_blocks(x: np.ndarray, x0: np.ndarray, gamma_p: np.ndarray, threshold: float,
                  origin: np.ndarray, cell: np.ndarray, shape: tuple[int, int],
                  intact_strain: float = 0.1, min_cells: int | None = None,
                  min_area: float = INTACT_BLOCK_AREA) -> int:
    """Connected groups (4-neighbour grid cells) of sliding, intact points whose area is at
    least ``min_area`` (m2; a group of k cells has the area k x cell area).

    ``x``, ``x0`` (n, 2) current and initial grid-frame positions (m); a point is sliding
    when it moved more than ``threshold`` (m) and intact when ``gamma_p`` (n,) is below
    ``intact_strain`` (-); ``origin``, ``cell`` (2,) m and ``shape`` (nx, ny) are the
    grid's.  ``min_cells``, if given, replaces the area by a least number of cells."""
    if min_cells is None:
        min_cells = least_cells(min_area, cell)
    sel = (np.linalg.norm(x - x0, axis=1) > threshold) & (gamma_p < intact_strain)
    if not sel.any():
        return 0
    ij = np.floor((x[sel] - origin) / cell).astype(np.int64)
    ij[:, 0] = np.clip(ij[:, 0], 0, shape[0] - 1)
    ij[:, 1] = np.clip(ij[:, 1], 0, shape[1] - 1)
    img = np.zeros(shape, dtype=bool)
    img[ij[:, 0], ij[:, 1]] = True
    labels, n = ndimage.label(img)
    sizes = np.bincount(labels.ravel())[1:]
    return int((sizes >= min_cells).sum())


def least_cells(area: float, cell) -> int:
    """Fewest grid cells of size ``cell`` (m, (2,)) whose area reaches ``area`` (m2), >= 1
    (a relative 1e-9 absorbs rounding: 1 m2 is exactly 16 cells of 0.25 m)."""
    cell_area = float(np.prod(np.asarray(cell, dtype=float)))
    return max(1, int(math.ceil(area / cell_area * (1.0 - 1e-9))))
