"""Three-dimensional random fields for the hexahedral engine: the field lattice (the
``box`` rule), the standard Gaussian fields of a seed or a noise array (one or several
cross-correlated properties), their values on hexahedral cells and on points.

The public entry points take arrays only (no scene, no grid), so the 3-D engine calls
them with its cells:

* :func:`sample_cell_field_3d` ``(spec, centres (n, 3), sizes (n, 3), seed, means=...)``
  -> ``{property: value per cell}``;
* :func:`sample_point_field_3d` ``(spec, points (n, 3), seed, lattice, means=...)`` ->
  ``{property: value per point}`` (the value of the lattice cell holding the point);
* :func:`field_lattice_3d`, :func:`gaussian_fields_3d`, :func:`noise_shape_3d`,
  :func:`field_noise_3d` underneath.

The lattice.  With ``box = (x0, y0, z0, x1, y1, z1)`` and ``cell_size`` (one value or three,
m) the field lives on a fixed lattice over the box: realization ``i`` is the same field
on every mesh.  Without a box the lattice covers the bounding box of the given cells with
the cell size ``cell_size`` or, by default, the smallest cell size per axis; when the
cells are a regular grid that lattice *is* the grid.

Cells average the lattice.  The Gaussian value of a hexahedral cell is the average of the
lattice values weighted by the volume each lattice cell shares with it (the weights are
products of 1-D overlaps).  Lattice values are local averages (``local_averaging``), so
a cell that is a union of lattice cells gets exactly the local average of the point field
over it; a cell cutting lattice cells gets the average over the lattice cells it touches,
weighted by overlap (slightly smoother than the exact local average; a cell inside one
lattice cell takes that cell's value).  The marginal transform uses the point parameters,
as in 2-D (:func:`~.model.gaussian_to_property`).  Points outside the lattice take the
value of the nearest edge cell.

Several properties (``spec.properties``): noise ``(p, m1, m2, m3)`` mixed by the Cholesky
factor of ``cross_correlation`` (:mod:`.cross`), each property's own embedding on the common
lattice.  One property: noise ``(m1, m2, m3)``, ``default_rng(seed).standard_normal``.

Conditioning on measurements (``data=``, CSV ``x,y,z,value``): :mod:`.conditioning3d`.

Subset simulation moves in this noise space, which in 3-D is the whole embedding lattice
(8 B per lattice point per sample, tens of MB for a slope): :func:`subset_noise_3d`
refuses with the reason and the size (no reduced noise representation yet).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from fem_rmpm.random_field.conditioning3d import (
    Measurements3D,
    condition_3d,
    data_cells_3d,
    read_measurements_3d,
)
from fem_rmpm.random_field.cross import cholesky_factor
from fem_rmpm.random_field.embedding3d import circulant_embedding_3d
from fem_rmpm.random_field.model import gaussian_to_property
from fem_rmpm.random_field.model3d import model_from_spec_3d
from fem_rmpm.scene import RandomFieldSpec

__all__ = ["Lattice3D", "field_lattice_3d", "embeddings_3d", "noise_shape_3d",
           "field_noise_3d", "gaussian_fields_3d", "cell_weights_3d", "cell_gaussian_3d",
           "sample_cell_field_3d", "sample_point_field_3d", "subset_noise_3d"]


@dataclass(frozen=True)
class Lattice3D:
    """Field cells: ``shape = (n1, n2, n3)`` cells of size ``cell`` (m) from ``origin``."""
    origin: np.ndarray
    cell: np.ndarray
    shape: tuple[int, int, int]

    @property
    def n_cells(self) -> int:
        return math.prod(self.shape)

    def centres(self) -> np.ndarray:
        """(n, 3) centres in the order of ``array.ravel()`` of an (n1, n2, n3) field."""
        idx = np.stack(np.meshgrid(*(np.arange(n) for n in self.shape), indexing="ij"), -1)
        return self.origin + (idx.reshape(-1, 3) + 0.5) * self.cell

    def locate(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(flat index, inside) of points ``x`` (n, 3); outside points: nearest edge cell."""
        s = (np.asarray(x, float) - self.origin) / self.cell
        n = np.array(self.shape)
        tol = 1e-9
        inside = np.all((s >= -tol) & (s <= n + tol), axis=1)
        ijk = np.clip(np.floor(s).astype(np.int64), 0, n - 1)
        return np.ravel_multi_index(ijk.T, self.shape), inside


def _three(v, name: str) -> np.ndarray:
    a = np.broadcast_to(np.asarray(v, float), (3,)).copy()
    if not np.all(np.isfinite(a) & (a > 0)):
        raise ValueError(f"{name} must be positive and finite (m), got {v}")
    return a


def _check_cells(centres, sizes) -> tuple[np.ndarray, np.ndarray]:
    c = np.asarray(centres, float)
    if c.ndim != 2 or c.shape[1] != 3:
        raise ValueError(f"centres: expected an (n, 3) array of cell centres (m) for a 3-D "
                         f"field, got shape {c.shape}; a 2-D scene uses the 2-D field")
    s = np.broadcast_to(np.asarray(sizes, float), c.shape)
    if not (np.all(np.isfinite(c)) and np.all(np.isfinite(s)) and np.all(s > 0)):
        raise ValueError("centres and sizes: expected finite values and positive sizes (m)")
    return c, s


def field_lattice_3d(centres, sizes, cell_size=None, box=None) -> Lattice3D:
    """The field lattice of cells (centres and sizes (n, 3), m): over ``box`` (x0, y0, z0,
    x1, y1, z1) with ``cell_size`` (the same lattice for every mesh), else over the cells'
    bounding box with ``cell_size`` or the smallest cell size per axis."""
    if box is not None:
        b = np.asarray(box, float)
        if b.shape != (6,) or not np.all(np.isfinite(b)) or np.any(b[3:] <= b[:3]):
            raise ValueError(f"box: expected [x0, y0, z0, x1, y1, z1] with x1 > x0, y1 > y0, "
                             f"z1 > z0 (m) for a 3-D field, got {list(np.ravel(box))}")
        if cell_size is None:
            raise ValueError("box: a fixed 3-D field box needs cell_size (m)")
        lo, size = b[:3], b[3:] - b[:3]
        h = _three(cell_size, "cell_size")
    else:
        c, s = _check_cells(centres, sizes)
        lo = (c - 0.5 * s).min(axis=0)
        size = (c + 0.5 * s).max(axis=0) - lo
        h = _three(s.min(axis=0) if cell_size is None else cell_size, "cell_size")
    n = np.maximum(np.ceil(size / h - 1e-9).astype(int), 1)
    return Lattice3D(origin=lo, cell=h, shape=tuple(int(v) for v in n))


def embeddings_3d(spec: RandomFieldSpec, lattice: Lattice3D, theta_z=None,
                  limit_bytes=None, report=None) -> tuple:
    """One embedding per property on a common periodic lattice (the largest any needs).
    ``theta_z``: strike scale(s) of fluctuation (m), one value or one per property."""
    fields = spec.fields()
    tz = list(theta_z) if isinstance(theta_z, (list, tuple)) else [theta_z] * len(fields)
    models = [model_from_spec_3d(f, t) for f, t in zip(fields, tz)]

    def make(mp):
        return [circulant_embedding_3d(m, tuple(lattice.cell), lattice.shape, f.local_averaging,
                                       min_padded=mp, limit_bytes=limit_bytes, report=report)
                for m, f in zip(models, fields)]
    embs = make((0, 0, 0))
    for _ in range(4):
        common = tuple(max(e.padded[a] for e in embs) for a in range(3))
        if all(tuple(e.padded) == common for e in embs):
            return tuple(embs)
        embs = make(common)
    raise ValueError("the properties' 3-D circulant embeddings do not settle on one lattice; "
                     "allowed: closer scales of fluctuation between the properties")


def noise_shape_3d(embs) -> tuple[int, ...]:
    """``(m1, m2, m3)`` for one property, ``(p, m1, m2, m3)`` for ``p``."""
    m = tuple(embs[0].padded)
    return m if len(embs) == 1 else (len(embs),) + m


def field_noise_3d(embs, seed: int) -> np.ndarray:
    """The noise of realization ``seed``: ``default_rng(seed).standard_normal(shape)``."""
    return np.random.default_rng(seed).standard_normal(noise_shape_3d(embs))


def gaussian_fields_3d(spec: RandomFieldSpec, lattice: Lattice3D, seed: int | None,
                       noise=None, theta_z=None, limit_bytes=None, report=None,
                       data=None, data_mean=None, data_index: int = 0) -> np.ndarray:
    """Standard Gaussian fields (p, n1, n2, n3) on the lattice from ``seed`` or ``noise``;
    property ``data_index`` conditioned on ``data`` (a CSV path, ``(xyz, value)`` arrays or
    :class:`~.conditioning3d.Measurements3D`; ``data_mean`` the property's point mean at
    the data, a number or one per measurement) when given (:mod:`.conditioning3d`)."""
    z = _unconditioned(spec, lattice, seed, noise, theta_z, limit_bytes, report)
    if data is None:
        return z
    embs = embeddings_3d(spec, lattice, theta_z, limit_bytes, report)
    meas = data if isinstance(data, Measurements3D) else (
        Measurements3D(np.asarray(data[0], float).reshape(-1, 3), np.asarray(data[1], float))
        if isinstance(data, (tuple, list)) else read_measurements_3d(data))
    if data_mean is None:
        raise ValueError("data_mean: the property's point mean at the data is needed to "
                         "condition on measurements (a number or one per measurement)")
    f = spec.fields()[data_index]
    cells, zd = data_cells_3d(lattice, meas, data_mean, f)
    z = z.copy()
    z[data_index] = condition_3d(embs[data_index], z[data_index], cells, zd)
    return z


def _unconditioned(spec, lattice, seed, noise, theta_z, limit_bytes, report) -> np.ndarray:
    embs = embeddings_3d(spec, lattice, theta_z, limit_bytes, report)
    shape = noise_shape_3d(embs)
    if noise is None:
        eps = field_noise_3d(embs, seed)
    else:
        eps = np.asarray(noise, float)
        if eps.size != math.prod(shape) or not np.all(np.isfinite(eps)):
            raise ValueError(f"noise: expected {math.prod(shape)} finite standard-normal "
                             f"values (shape {shape}), got {eps.size}")
        eps = eps.reshape(shape)
    if len(embs) == 1:
        return embs[0].from_noise(eps)[None]
    L = cholesky_factor(spec.cross_correlation)
    out = []
    for k, e in enumerate(embs):
        eta = eps[k] if L.size == 0 else np.tensordot(L[k], eps, axes=1)
        out.append(e.from_noise(eta))
    return np.stack(out)


def _axis_overlaps(lo, hi, origin, h, n) -> tuple[np.ndarray, np.ndarray]:
    """Lattice indices (c, q) and overlap fractions of intervals [lo, hi] along one axis."""
    a = np.clip((lo - origin) / h, 0.0, n)
    b = np.clip((hi - origin) / h, 0.0, n)
    i0 = np.clip(np.floor(a).astype(np.int64), 0, n - 1)
    i1 = np.clip(np.ceil(b).astype(np.int64) - 1, 0, n - 1)
    q = int(np.max(i1 - i0)) + 1
    idx = i0[:, None] + np.arange(q)
    left = np.maximum(idx, a[:, None])
    right = np.minimum(idx + 1, b[:, None])
    w = np.clip(right - left, 0.0, None)
    w = np.where(idx <= i1[:, None], w, 0.0)
    tot = w.sum(axis=1, keepdims=True)
    outside = tot[:, 0] <= 0                  # interval outside the lattice: nearest cell
    w[outside] = 0.0
    w[outside, 0] = 1.0
    idx = np.minimum(idx, n - 1)
    return idx, w / np.where(tot > 0, tot, 1.0)


def cell_weights_3d(lattice: Lattice3D, centres, sizes) -> tuple[np.ndarray, np.ndarray]:
    """Flat lattice indices (c, q) and weights (c, q) (rows sum to 1) of the overlap of
    each hexahedral cell with the lattice cells."""
    c, s = _check_cells(centres, sizes)
    parts = [_axis_overlaps(c[:, a] - 0.5 * s[:, a], c[:, a] + 0.5 * s[:, a],
                            lattice.origin[a], lattice.cell[a], lattice.shape[a])
             for a in range(3)]
    (ix, wx), (iy, wy), (iz, wz) = parts
    n = len(c)
    I = np.broadcast_to(ix[:, :, None, None], (n, ix.shape[1], iy.shape[1], iz.shape[1]))
    J = np.broadcast_to(iy[:, None, :, None], I.shape)
    K = np.broadcast_to(iz[:, None, None, :], I.shape)
    W = wx[:, :, None, None] * wy[:, None, :, None] * wz[:, None, None, :]
    flat = np.ravel_multi_index((I.reshape(n, -1).T, J.reshape(n, -1).T, K.reshape(n, -1).T),
                                lattice.shape).T
    return flat, W.reshape(n, -1)


def cell_gaussian_3d(z: np.ndarray, lattice: Lattice3D, centres, sizes) -> np.ndarray:
    """Gaussian values (p, c) of hexahedral cells from lattice fields ``z`` (p, n1, n2, n3)."""
    idx, w = cell_weights_3d(lattice, centres, sizes)
    zf = z.reshape(z.shape[0], -1)
    return np.einsum("pcq,cq->pc", zf[:, idx], w)


def _values(spec: RandomFieldSpec, zc: np.ndarray, means) -> dict[str, np.ndarray]:
    out = {}
    for k, f in enumerate(spec.fields()):
        mean = means[f.property] if isinstance(means, dict) else means
        out[f.property] = gaussian_to_property(zc[k], np.asarray(mean, float), f)
    return out


def sample_cell_field_3d(spec: RandomFieldSpec, centres, sizes, seed: int | None, *,
                         means=1.0, noise=None, theta_z=None, box=None, cell_size=None,
                         limit_bytes=None, report=None, data=None,
                         data_mean=None) -> dict[str, np.ndarray]:
    """``{property: value per cell}`` of realization ``seed`` (or ``noise``) on hexahedral
    cells (centres and sizes (n, 3), m).

    ``means``: the point mean of each property (a number, an (n,) array, or a dict by
    property), in the property's unit; ``theta_z``: the strike scale (m; default
    :func:`~.model3d.model_from_spec_3d`); ``box`` and ``cell_size``: the fixed lattice
    (default ``spec.cell_size`` and, for a 6-value ``spec.box``, that box).  Raises
    :class:`~.embedding3d.FieldTooLarge` (a scene error and a ``MemoryError``, with the
    estimate) for a field over the memory limit, ``ValueError``
    for bad input.  ``data``, ``data_mean``: measurements of the first property to
    condition on (:func:`gaussian_fields_3d`; ``data_mean`` defaults to a scalar ``means``)."""
    lattice = _lattice_for(spec, centres, sizes, box, cell_size)
    z = gaussian_fields_3d(spec, lattice, seed, noise, theta_z, limit_bytes, report,
                           data, _data_mean(spec, means, data_mean))
    return _values(spec, cell_gaussian_3d(z, lattice, centres, sizes), means)


def sample_point_field_3d(spec: RandomFieldSpec, points, seed: int | None,
                          lattice: Lattice3D, *, means=1.0, noise=None, theta_z=None,
                          limit_bytes=None, report=None, data=None,
                          data_mean=None) -> dict[str, np.ndarray]:
    """``{property: value per point}``: each point (n, 3) takes the value of the lattice
    cell holding it (outside: the nearest edge cell)."""
    p = np.asarray(points, float)
    if p.ndim != 2 or p.shape[1] != 3:
        raise ValueError(f"points: expected an (n, 3) array (m) for a 3-D field, got {p.shape}")
    z = gaussian_fields_3d(spec, lattice, seed, noise, theta_z, limit_bytes, report,
                           data, _data_mean(spec, means, data_mean))
    idx, _ = lattice.locate(p)
    return _values(spec, z.reshape(z.shape[0], -1)[:, idx], means)


def _data_mean(spec, means, data_mean):
    if data_mean is not None:
        return data_mean
    m = means[spec.fields()[0].property] if isinstance(means, dict) else means
    return m if np.ndim(m) == 0 else None


def _lattice_for(spec, centres, sizes, box, cell_size) -> Lattice3D:
    if box is None and spec.box is not None:
        if len(spec.box) != 6:
            raise ValueError(f"[random_field.box] {list(spec.box)} is a 2-D rectangle; allowed "
                             "for a 3-D field: [x0, y0, z0, x1, y1, z1] (m)")
        box = spec.box
    return field_lattice_3d(centres, sizes, cell_size if cell_size is not None
                            else spec.cell_size, box)


def subset_noise_3d(embs) -> None:
    """Refuse subset simulation on a 3-D field: its noise is the whole embedding lattice."""
    shape = noise_shape_3d(embs)
    mb = 8.0 * math.prod(shape) / 2**20
    raise ValueError(f"subset simulation is not available for 3-D random fields: its Markov "
                     f"chains move in the noise of the whole circulant-embedding lattice "
                     f"({math.prod(shape):,} standard normals, {mb:.3g} MB per sample, every "
                     "sample of a level kept) and no reduced noise representation exists yet; "
                     "allowed: crude Monte Carlo for 3-D scenes")
