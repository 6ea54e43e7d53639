"""The field of one realization on the material points: the scene's embedding, the
(conditioned) standard Gaussian field of a seed or of a noise array, and the property per
point.

A realization's field is a pure function of (scene, noise): the noise is the
standard-normal array ``eps`` of shape :func:`noise_shape` (``(m2, m1)``, the periodic
embedding lattice) that the circulant embedding maps to the field.  The seed path draws
it as ``default_rng(seed).standard_normal((m2, m1))`` (:func:`field_noise`), so
``noise=field_noise(scene, grid, seed)`` gives bitwise the field of ``seed``.  Subset
simulation moves in this noise space."""
from __future__ import annotations

import numpy as np

from ..scene import Scene, SceneError
from .conditioning import Measurements, condition, data_cells, read_measurements, \
    resolve_data_path
from .embedding import Embedding, circulant_embedding
from .layout import FieldLayout, field_layout
from .model import gaussian_to_property, model_from_spec

__all__ = ["embedding_for", "noise_shape", "field_noise", "gaussian_field", "field_values",
           "sample_point_property"]


def embedding_for(scene: Scene, layout: FieldLayout) -> Embedding:
    """The (cached) circulant embedding of the scene's field on ``layout``; a scale the
    embedding cannot take is a scene error."""
    rf = scene.random_field
    try:
        return circulant_embedding(model_from_spec(rf), tuple(layout.cell), layout.shape,
                                   rf.local_averaging)
    except ValueError as exc:
        raise SceneError(f"{scene.source}: [random_field.theta_v] {exc}") from None



def noise_shape(scene: Scene, grid) -> tuple[int, int]:
    """Shape ``(m2, m1)`` of the standard-normal noise array of the scene's field."""
    m1, m2 = embedding_for(scene, field_layout(scene, grid)).padded
    return (m2, m1)


def field_noise(scene: Scene, grid, seed: int) -> np.ndarray:
    """The noise array of realization ``seed``: ``default_rng(seed).standard_normal((m2, m1))``."""
    return embedding_for(scene, field_layout(scene, grid)).white_noise(seed)


def _checked_noise(emb: Embedding, noise) -> np.ndarray:
    m1, m2 = emb.padded
    eps = np.asarray(noise, dtype=float)
    if eps.size != m1 * m2 or not np.all(np.isfinite(eps)):
        raise ValueError(f"noise: expected {m2 * m1} finite standard-normal values (shape "
                         f"({m2}, {m1})), got {eps.size}" + ("" if eps.size != m1 * m2
                                                              else " with non-finite ones"))
    return eps.reshape(m2, m1)


def gaussian_field(scene: Scene, grid, seed: int | None, data=None,
                   layout: FieldLayout | None = None, noise=None) -> np.ndarray:
    """Standard Gaussian field (n2, n1) of realization ``seed``, or of the standard-normal
    ``noise`` array (:func:`noise_shape`, any layout of that many values; it overrides
    ``seed``), conditioned on data if any.

    ``data``: a CSV path overriding ``[random_field] data`` (or a :class:`Measurements`).
    """
    layout = layout or field_layout(scene, grid)
    emb = embedding_for(scene, layout)
    z = emb.sample(seed) if noise is None else emb.from_noise(_checked_noise(emb, noise))
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


def field_values(scene: Scene, grid, pts, seed: int | None, data=None,
                 noise=None) -> tuple[np.ndarray, np.ndarray]:
    """Property value per point for the points of the field's soils (NaN elsewhere) and the
    mask; from ``seed`` or from the ``noise`` array (see :func:`gaussian_field`)."""
    layout = field_layout(scene, grid)
    z = gaussian_field(scene, grid, seed, data, layout, noise)
    mask = np.isin(pts.soil_id, layout.soils)
    idx = _point_field_index(layout, grid, pts)
    mean = np.array([s.cohesion_peak for s in scene.soils])[pts.soil_id]
    out = np.full(pts.n, np.nan)
    out[mask] = gaussian_to_property(z.ravel()[idx[mask]], mean[mask], scene.random_field)
    return out, mask


def sample_point_property(scene: Scene, grid, pts, seed: int | None, data=None,
                          noise=None) -> np.ndarray:
    """Peak cohesion (kPa) per material point for realization ``seed`` (or ``noise``).

    Points of soils the field does not apply to, and linear elastic points
    (whose strength is infinite), keep ``pts.soil.cohesion_peak``.
    """
    if scene.random_field is None:
        return pts.soil.cohesion_peak.copy()
    vals, mask = field_values(scene, grid, pts, seed, data, noise)
    base = np.asarray(pts.soil.cohesion_peak, float)
    use = mask & np.isfinite(base)
    return np.where(use, vals, base)

