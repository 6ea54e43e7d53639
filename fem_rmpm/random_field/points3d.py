"""The ``[random_field]`` of a three-dimensional scene on its material points: the field
lattice of the scene, the realization of a seed on the points, and the points' material
with the drawn values.

The lattice (:func:`scene_lattice_3d`) follows the 2-D rule in three dimensions.  With
``box = [x0, y0, z0, x1, y1, z1]`` and ``cell_size`` (m) the field lives on a fixed
lattice over that box, so realization ``i`` is the same field on every mesh (the box rule).
Without a box it covers the bounding box of the soil cells of the field's soils with
cells of ``cell_size`` (default: the grid cell, so that the lattice *is* the grid over
that box).  Each material point takes the value of the lattice cell holding its initial
position (with the default lattice: its own grid cell), as in 2-D.  The strike scale of
fluctuation is ``theta_strike`` (m, default ``theta_h = anisotropy x theta_v``: a
horizontally isotropic field, Hicks & Spencer 2010).

A realization is a pure function of (scene, seed): the noise is
``default_rng(seed).standard_normal`` on the periodic embedding lattice
(:func:`~.field3d.field_noise_3d`), the FFTs are pocketfft.  The random property is the
peak cohesion of von Mises softening (:data:`PROPERTIES_3D`), its residual in proportion
(:func:`~.points.apply_to_points`).
"""
from __future__ import annotations

import numpy as np

from fem_rmpm.random_field.embedding3d import FieldTooLarge
from fem_rmpm.random_field.field3d import (
    Lattice3D,
    embeddings_3d,
    field_lattice_3d,
    sample_point_field_3d,
)
from fem_rmpm.random_field.points import apply_to_points
from fem_rmpm.scene import Scene, SceneError

__all__ = ["PROPERTIES_3D", "field_soils_3d", "scene_lattice_3d", "prepare_field_3d",
           "sample_point_properties_3d", "apply_to_points_3d"]

#: Parameters a 3-D random field may draw: the ones the 3-D point arrays read from the
#: soil (:class:`~fem_rmpm.discretise.points3d.Particles3D` ``plastic`` columns 0 and 1).
PROPERTIES_3D = ("cohesion_peak",)


def field_soils_3d(scene: Scene) -> list[int]:
    """Indices of the soils the field applies to (``[random_field] soil``, else every soil
    whose model is not linear elastic)."""
    rf = scene.random_field
    return [k for k, so in enumerate(scene.soils)
            if (so.name == rf.soil if rf.soil is not None else so.model != "linear_elastic")]


def scene_lattice_3d(scene: Scene, grid, owner: np.ndarray) -> Lattice3D:
    """The field lattice of a 3-D scene (module docstring); ``owner`` (n_cells,) the soil
    index of every grid cell, -1 for none
    (:func:`~fem_rmpm.discretise.grid3d.soil_cells_3d`)."""
    rf = scene.random_field
    if rf.box is not None:
        return field_lattice_3d(None, None, rf.cell_size, rf.box)
    cells = np.nonzero(np.isin(owner, field_soils_3d(scene)))[0]
    return field_lattice_3d(grid.cell_centres(cells), np.asarray(grid.cell, float),
                            rf.cell_size)


def prepare_field_3d(scene: Scene, grid, owner: np.ndarray) -> Lattice3D:
    """The lattice and the (cached) circulant embeddings of the scene's field: raises
    :class:`~.embedding3d.FieldTooLarge` (a scene error) from the memory estimate, before
    anything large is allocated, when the field would exceed the memory limit."""
    lattice = scene_lattice_3d(scene, grid, owner)
    try:
        embeddings_3d(scene.random_field, lattice)
    except FieldTooLarge as exc:                      # the file in front, as a scene error
        raise FieldTooLarge(f"{scene.source}: {exc}") from None
    except ValueError as exc:                         # scales the embedding cannot take
        raise SceneError(f"{scene.source}: [random_field.theta_strike] {exc}") from None
    return lattice


def sample_point_properties_3d(scene: Scene, pts, seed: int, lattice: Lattice3D
                               ) -> dict[str, np.ndarray]:
    """``{property: value per point}`` of realization ``seed``: the drawn value on the
    points of the field's soils, the soil's value elsewhere (property units)."""
    rf = scene.random_field
    mask = np.isin(pts.soil_id, field_soils_3d(scene))
    out = {}
    for f in rf.fields():
        base = np.array([np.nan if (v := so.value(f.property)) is None else float(v)
                         for so in scene.soils])[pts.soil_id]
        drawn = sample_point_field_3d(rf, pts.x0[mask], seed, lattice,
                                      means={f.property: base[mask]})
        v = base.copy()
        v[mask] = drawn[f.property]
        out[f.property] = v
    return out


def apply_to_points_3d(pts, values: dict[str, np.ndarray]) -> None:
    """Give the points ``pts`` (:class:`~fem_rmpm.discretise.points3d.Particles3D`) the
    drawn ``values``: their material rows (residual in proportion to peak) and the peak
    and residual cohesion (kPa) the 3-D von Mises update reads."""
    pts.soil = apply_to_points(pts.soil, values)
    vm = pts.model == 1
    pts.plastic[vm, 0] = pts.soil.cohesion_peak[vm]
    pts.plastic[vm, 1] = pts.soil.cohesion_residual[vm]
