"""The field of one realization on the material points: the scene's embedding, the
(conditioned) standard Gaussian field of a seed and the property per point."""
from __future__ import annotations

import numpy as np

from ..scene import Scene, SceneError
from .conditioning import Measurements, condition, data_cells, read_measurements, \
    resolve_data_path
from .embedding import Embedding, circulant_embedding
from .layout import FieldLayout, field_layout
from .model import gaussian_to_property, model_from_spec

__all__ = ["embedding_for", "gaussian_field", "field_values", "sample_point_property"]


def embedding_for(scene: Scene, layout: FieldLayout) -> Embedding:
    """The (cached) circulant embedding of the scene's field on ``layout``; a scale the
    embedding cannot take is a scene error."""
    rf = scene.random_field
    try:
        return circulant_embedding(model_from_spec(rf), tuple(layout.cell), layout.shape,
                                   rf.local_averaging)
    except ValueError as exc:
        raise SceneError(f"{scene.source}: [random_field.theta_v] {exc}") from None



def gaussian_field(scene: Scene, grid, seed: int, data=None,
                   layout: FieldLayout | None = None) -> np.ndarray:
    """Standard Gaussian field (n2, n1) of realization ``seed`` (conditioned on data if any).

    ``data``: a CSV path overriding ``[random_field] data`` (or a :class:`Measurements`).
    """
    layout = layout or field_layout(scene, grid)
    emb = embedding_for(scene, layout)
    z = emb.sample(seed)
    meas = data if isinstance(data, Measurements) else None
    if meas is None:
        path = resolve_data_path(scene, data)
        if path is not None:
            meas = read_measurements(path)
    if meas is not None:
        cells, zd = data_cells(scene, grid, layout, meas)
        z = condition(emb, z, cells, zd)
    return z


def _point_field_index(layout: FieldLayout, grid, pts) -> np.ndarray:
    if layout.grid_offset is not None:
        nx = grid.shape[0]
        i0, j0 = layout.grid_offset
        i = pts.cell0 % nx - i0
        j = pts.cell0 // nx - j0
        return j * layout.shape[0] + i
    return layout.locate(pts.x0)[0]


def field_values(scene: Scene, grid, pts, seed: int, data=None) -> tuple[np.ndarray, np.ndarray]:
    """Property value per point for the points of the field's soils (NaN elsewhere) and the mask."""
    layout = field_layout(scene, grid)
    z = gaussian_field(scene, grid, seed, data, layout)
    mask = np.isin(pts.soil_id, layout.soils)
    idx = _point_field_index(layout, grid, pts)
    mean = np.array([s.cohesion_peak for s in scene.soils])[pts.soil_id]
    out = np.full(pts.n, np.nan)
    out[mask] = gaussian_to_property(z.ravel()[idx[mask]], mean[mask], scene.random_field)
    return out, mask


def sample_point_property(scene: Scene, grid, pts, seed: int, data=None) -> np.ndarray:
    """Peak cohesion (kPa) per material point for realization ``seed``.

    Points of soils the field does not apply to, and linear elastic points
    (whose strength is infinite), keep ``pts.soil.cohesion_peak``.
    """
    if scene.random_field is None:
        return pts.soil.cohesion_peak.copy()
    vals, mask = field_values(scene, grid, pts, seed, data)
    base = np.asarray(pts.soil.cohesion_peak, float)
    use = mask & np.isfinite(base)
    return np.where(use, vals, base)

