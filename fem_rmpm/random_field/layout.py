"""Where the field lives: the field cells over the soils it applies to (the grid cells,
or square cells of ``cell_size``)."""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from fem_rmpm.discretise.points import soil_cells
from fem_rmpm.scene import Scene, SceneError

__all__ = ["FieldLayout", "field_layout"]


@dataclass(frozen=True)
class FieldLayout:
    """Field cells: ``shape = (n1, n2)`` cells of size ``cell`` from ``origin`` (m)."""
    origin: np.ndarray
    cell: np.ndarray
    shape: tuple[int, int]
    soils: tuple[int, ...]               # indices of the soils the field applies to
    grid_offset: tuple[int, int] | None  # (i0, j0) when field cells are the grid cells

    @property
    def n_cells(self) -> int:
        return self.shape[0] * self.shape[1]

    def centres(self) -> np.ndarray:
        n1, n2 = self.shape
        i, j = np.meshgrid(np.arange(n1), np.arange(n2))
        return self.origin + (np.stack([i.ravel(), j.ravel()], 1) + 0.5) * self.cell

    def locate(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(flat index j * n1 + i, inside) of points x (n, 2)."""
        s = (np.asarray(x, float) - self.origin) / self.cell
        n1, n2 = self.shape
        tol = 1e-9
        inside = ((s[:, 0] >= -tol) & (s[:, 0] <= n1 + tol)
                  & (s[:, 1] >= -tol) & (s[:, 1] <= n2 + tol))
        i = np.clip(np.floor(s[:, 0]).astype(np.int64), 0, n1 - 1)
        j = np.clip(np.floor(s[:, 1]).astype(np.int64), 0, n2 - 1)
        return j * n1 + i, inside


def _field_soils(scene: Scene) -> tuple[int, ...]:
    """The soils the field applies to: the named one, or every soil whose value of each
    random property is finite (a linear elastic soil has infinite strength: no field)."""
    rf = scene.random_field
    names = [s.name for s in scene.soils]
    props = [f.property for f in rf.fields()]
    cand = range(len(scene.soils)) if rf.soil is None else [names.index(rf.soil)]

    def finite(s) -> bool:
        return all(isinstance(v := s.value(p), (int, float)) and math.isfinite(v) for p in props)
    soils = tuple(k for k in cand if finite(scene.soils[k]))
    if not soils:
        which = "the soils" if rf.soil is None else f"soil {rf.soil!r}"
        raise SceneError(f"{scene.source}: [random_field.soil] {which} of the random field "
                         f"have no finite {' / '.join(props)} (the field's mean); allowed: a "
                         "soil with finite values, e.g. cohesion_peak > 0 kPa")
    return soils


def field_layout(scene: Scene, grid) -> FieldLayout:
    """Field cells over the bounding box of the cells of the soils the field applies to,
    or, with ``[random_field] box`` (and ``cell_size``), over that fixed rectangle: the
    layout, hence the circulant embedding and the field of a seed, then do not depend on
    the grid cell (points outside the box take the nearest edge cell's value)."""
    soils = _field_soils(scene)
    owner = soil_cells(scene, grid)
    cells = np.nonzero(np.isin(owner, soils))[0]
    if len(cells) == 0:
        raise SceneError(f"{scene.source}: [random_field.soil] the field's soils cover no grid "
                         "cell; allowed: a soil polygon enclosing cell centres")
    nx = grid.shape[0]
    ic, jc = cells % nx, cells // nx
    i0, i1, j0, j1 = ic.min(), ic.max() + 1, jc.min(), jc.max() + 1
    rf = scene.random_field
    if rf.cell_size is None:
        return FieldLayout(origin=grid.origin + grid.cell * np.array([i0, j0]),
                           cell=np.array(grid.cell, float), shape=(int(i1 - i0), int(j1 - j0)),
                           soils=soils, grid_offset=(int(i0), int(j0)))
    lo = grid.origin + grid.cell * np.array([i0, j0])
    size = grid.cell * np.array([i1 - i0, j1 - j0])
    if rf.box is not None:           # a fixed rectangle: the same field on every grid
        lo, size = np.array(rf.box[:2]), np.array(rf.box[2:]) - np.array(rf.box[:2])
    h = float(rf.cell_size)
    n = np.maximum(np.ceil(size / h - 1e-9).astype(int), 1)
    return FieldLayout(origin=lo, cell=np.array([h, h]), shape=(int(n[0]), int(n[1])),
                       soils=soils, grid_offset=None)

