"""The field of one realization on the material points: the scene's embeddings, the
(conditioned) standard Gaussian fields of a seed or of a noise array, and the property
values per point.

A realization's field is a pure function of (scene, noise): the noise is the
standard-normal array ``eps`` of shape :func:`noise_shape` -- ``(m2, m1)``, the periodic
embedding lattice, for one property; ``(p, m2, m1)`` for ``p`` cross-correlated
properties (:mod:`.cross`) -- that the circulant embeddings map to the fields.  The seed
path draws it as ``default_rng(seed).standard_normal(noise_shape)`` (:func:`field_noise`),
so ``noise=field_noise(scene, grid, seed)`` gives bitwise the fields of ``seed``.  Subset
simulation moves in this noise space."""
from __future__ import annotations

import math

import numpy as np

from fem_rmpm.materials import MaterialPoints, registry
from fem_rmpm.random_field.conditioning import (
    Measurements,
    condition,
    data_cells,
    read_measurements,
    resolve_data_path,
)
from fem_rmpm.random_field.cross import cholesky_factor, mix_noise
from fem_rmpm.random_field.embedding import Embedding, circulant_embedding
from fem_rmpm.random_field.layout import FieldLayout, field_layout
from fem_rmpm.random_field.model import gaussian_to_property, model_from_spec
from fem_rmpm.scene import RandomFieldSpec, Scene, SceneError

__all__ = ["embedding_for", "embeddings_for", "noise_shape", "field_noise", "gaussian_field",
           "gaussian_fields", "field_values", "sample_point_property",
           "sample_point_properties", "apply_to_points"]


def _embedding(scene: Scene, f: RandomFieldSpec, layout: FieldLayout, key: str,
               min_padded=(0, 0)) -> Embedding:
    try:
        return circulant_embedding(model_from_spec(f), tuple(layout.cell), layout.shape,
                                   f.local_averaging, min_padded=min_padded)
    except ValueError as exc:
        raise SceneError(f"{scene.source}: [{key}.theta_v] {exc}") from None


def embedding_for(scene: Scene, layout: FieldLayout) -> Embedding:
    """The (cached) circulant embedding of the scene's (first) field on ``layout``; a scale
    the embedding cannot take is a scene error."""
    return embeddings_for(scene, layout)[0]


def embeddings_for(scene: Scene, layout: FieldLayout) -> tuple[Embedding, ...]:
    """One embedding per property (:meth:`RandomFieldSpec.fields`), all on one periodic
    lattice (the largest any of them needs) so that their noises can be mixed."""
    rf = scene.random_field
    fields = rf.fields()
    keys = [f"random_field.properties[{k}]" if rf.properties else "random_field"
            for k in range(len(fields))]
    embs = [_embedding(scene, f, layout, k) for f, k in zip(fields, keys)]
    for _ in range(4):
        common = tuple(max(e.padded[a] for e in embs) for a in (0, 1))
        if all(e.padded == common for e in embs):
            return tuple(embs)
        embs = [_embedding(scene, f, layout, k, common) for f, k in zip(fields, keys)]
    raise SceneError(f"{scene.source}: [random_field.theta_v] the properties' circulant "
                     "embeddings do not settle on one lattice; allowed: closer scales of "
                     "fluctuation between the properties")  # pragma: no cover


def noise_shape(scene: Scene, grid) -> tuple[int, ...]:
    """Shape of the standard-normal noise array of the scene's field: ``(m2, m1)`` for one
    property, ``(p, m2, m1)`` for ``p`` properties."""
    embs = embeddings_for(scene, field_layout(scene, grid))
    m1, m2 = embs[0].padded
    return (m2, m1) if len(embs) == 1 else (len(embs), m2, m1)


def field_noise(scene: Scene, grid, seed: int) -> np.ndarray:
    """The noise array of realization ``seed``: ``default_rng(seed).standard_normal(shape)``
    with the shape of :func:`noise_shape` (its first ``(m2, m1)`` block is the noise of a
    single-property field of the same seed)."""
    embs = embeddings_for(scene, field_layout(scene, grid))
    if len(embs) == 1:
        return embs[0].white_noise(seed)
    return np.random.default_rng(seed).standard_normal(noise_shape(scene, grid))


def _checked_noise(shape: tuple[int, ...], noise) -> np.ndarray:
    eps = np.asarray(noise, dtype=float)
    size = math.prod(shape)
    if eps.size != size or not np.all(np.isfinite(eps)):
        raise ValueError(f"noise: expected {size} finite standard-normal values (shape "
                         f"{shape}), got {eps.size}" + ("" if eps.size != size
                                                        else " with non-finite ones"))
    return eps.reshape(shape)


def _conditioned(scene, grid, layout, f, emb, z, data, key) -> np.ndarray:
    meas = data if isinstance(data, Measurements) else None
    if meas is None:
        path = resolve_data_path(scene, data, f)
        if path is not None:
            meas = read_measurements(path, key=f"{key}.data")
    if meas is None:
        return z
    cells, zd = data_cells(scene, grid, layout, meas, key=f"{key}.data", spec=f)
    return condition(emb, z, cells, zd)


def gaussian_fields(scene: Scene, grid, seed: int | None, data=None,
                    layout: FieldLayout | None = None, noise=None,
                    data_index: int = 0) -> np.ndarray:
    """Standard Gaussian fields (p, n2, n1) of the p properties of realization ``seed``, or
    of the standard-normal ``noise`` (:func:`noise_shape`; any layout of that many values;
    it overrides ``seed``), each conditioned on its own data if any.  ``data`` (a CSV path
    or :class:`Measurements`) overrides the data of property ``data_index``."""
    layout = layout or field_layout(scene, grid)
    embs = embeddings_for(scene, layout)
    rf = scene.random_field
    fields = rf.fields()
    if len(embs) == 1:                      # the single-property generator, unchanged
        emb = embs[0]
        z = emb.sample(seed) if noise is None else emb.from_noise(
            _checked_noise((emb.padded[1], emb.padded[0]), noise))
        zs = [z]
    else:
        shape = (len(embs), embs[0].padded[1], embs[0].padded[0])
        eps = (np.random.default_rng(seed).standard_normal(shape) if noise is None
               else _checked_noise(shape, noise))
        eta = mix_noise(cholesky_factor(rf.cross_correlation), eps)
        zs = [e.from_noise(eta[k]) for k, e in enumerate(embs)]
    keys = [f"random_field.properties[{k}]" if rf.properties else "random_field"
            for k in range(len(fields))]
    return np.stack([_conditioned(scene, grid, layout, f, e, z,
                                  data if k == data_index else None, key)
                     for k, (f, e, z, key) in enumerate(zip(fields, embs, zs, keys))])


def gaussian_field(scene: Scene, grid, seed: int | None, data=None,
                   layout: FieldLayout | None = None, noise=None) -> np.ndarray:
    """Standard Gaussian field (n2, n1) of the (first) property (see
    :func:`gaussian_fields`)."""
    return gaussian_fields(scene, grid, seed, data, layout, noise)[0]


def _point_field_index(layout: FieldLayout, grid, pts) -> np.ndarray:
    if layout.grid_offset is not None:
        nx = grid.shape[0]
        i0, j0 = layout.grid_offset
        i = pts.cell0 % nx - i0
        j = pts.cell0 // nx - j0
        return j * layout.shape[0] + i
    return layout.locate(pts.x0)[0]


def _soil_means(scene: Scene, name: str) -> np.ndarray:
    return np.array([np.nan if (v := s.value(name)) is None else float(v) for s in scene.soils])


def point_fields(scene: Scene, grid, pts, seed: int | None, data=None, noise=None,
                 data_index: int = 0) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """``{property: value per point}`` on the points of the field's soils (NaN elsewhere)
    and the mask, from ``seed`` or the ``noise`` array (see :func:`gaussian_fields`)."""
    layout = field_layout(scene, grid)
    z = gaussian_fields(scene, grid, seed, data, layout, noise, data_index)
    mask = np.isin(pts.soil_id, layout.soils)
    idx = _point_field_index(layout, grid, pts)
    out = {}
    for k, f in enumerate(scene.random_field.fields()):
        mean = _soil_means(scene, f.property)[pts.soil_id]
        v = np.full(pts.n, np.nan)
        v[mask] = gaussian_to_property(z[k].ravel()[idx[mask]], mean[mask], f)
        out[f.property] = v
    return out, mask


def field_values(scene: Scene, grid, pts, seed: int | None, data=None,
                 noise=None) -> tuple[np.ndarray, np.ndarray]:
    """Value per point of the (first) property for the points of the field's soils (NaN
    elsewhere) and the mask; from ``seed`` or from the ``noise`` array."""
    vals, mask = point_fields(scene, grid, pts, seed, data, noise)
    return vals[scene.random_field.fields()[0].property], mask


def sample_point_properties(scene: Scene, grid, pts, seed: int | None, data=None,
                            noise=None) -> dict[str, np.ndarray]:
    """``{property: value per material point}`` of realization ``seed`` (or ``noise``).
    Points of soils the field does not apply to, and points whose value is infinite
    (linear elastic: no strength), keep their soil's value."""
    if scene.random_field is None:
        return {}
    vals, mask = point_fields(scene, grid, pts, seed, data, noise)
    out = {}
    for name, v in vals.items():
        base = np.asarray(getattr(pts.soil, name), float)
        out[name] = np.where(mask & np.isfinite(base), v, base)
    return out


def sample_point_property(scene: Scene, grid, pts, seed: int | None, data=None,
                          noise=None) -> np.ndarray:
    """Peak cohesion (kPa) -- the (first) property of the field -- per material point for
    realization ``seed`` (or ``noise``); see :func:`sample_point_properties`."""
    if scene.random_field is None:
        return pts.soil.cohesion_peak.copy()
    return sample_point_properties(scene, grid, pts, seed, data, noise)[
        scene.random_field.fields()[0].property]


def apply_to_points(soil: MaterialPoints, values: dict[str, np.ndarray]) -> MaterialPoints:
    """Material of the points with the drawn values: each property set where its value is
    finite, and its residual (``<name>_residual`` of a ``<name>_peak``) in proportion,
    ``residual = value * residual_0 / peak_0``, so the realization keeps the soil's
    residual-to-peak ratio."""
    named = {}
    for name, v in values.items():
        old = np.asarray(getattr(soil, name), float)
        finite = np.isfinite(old)
        named[name] = np.where(finite, v, old)
        res = name[:-len("_peak")] + "_residual" if name.endswith("_peak") else None
        if res is not None and registry.parameter(res) is not None:
            old_r = np.asarray(getattr(soil, res), float)
            ratio = np.divide(old_r, old, out=np.ones_like(old), where=finite & (old != 0))
            named[res] = np.where(finite, v * ratio, old_r)
    return soil.replace(**named)
