"""Measurements of the property (CSV ``x,y,value``) and the conditional realization
(simple kriging of the residual, the convolution done by FFT on the embedding)."""
from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.linalg import cho_factor, cho_solve

from fem_rmpm.discretise.grid import locate
from fem_rmpm.discretise.points import soil_cells
from fem_rmpm.random_field.embedding import Embedding
from fem_rmpm.random_field.layout import FieldLayout
from fem_rmpm.random_field.model import property_to_gaussian
from fem_rmpm.scene import RandomFieldSpec, Scene, SceneError

__all__ = ["Measurements", "read_measurements", "resolve_data_path", "data_cells", "condition"]


@dataclass(frozen=True)
class Measurements:
    x: np.ndarray
    y: np.ndarray
    value: np.ndarray
    source: str
    rows: np.ndarray          # CSV line numbers (for messages)
    group: np.ndarray | None = None   # optional column "group" (site labels, for fit_scales)


def read_measurements(path, key: str = "random_field.data") -> Measurements:
    """Read a CSV with a header naming columns ``x``, ``y``, ``value`` (others ignored,
    except an optional ``group`` of site labels used by the variogram fit).

    Raises :class:`SceneError` (one line naming the file, row and column) on a
    missing file or column, an empty table or a value that is not a finite number.
    """
    path = Path(path)
    src = str(path)
    allowed = "a CSV file with header x,y,value (m, m, property units)"
    if not path.is_file():
        raise SceneError(f"{src}: [{key}] file not found; allowed: {allowed}")
    try:
        text = path.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError:
        raise SceneError(f"{src}: [{key}] not a text file; allowed: {allowed}") from None
    except OSError as exc:
        raise SceneError(f"{src}: [{key}] cannot be read ({exc.strerror}); needed: read "
                         "permission on the file") from None
    lines = [ln for ln in text.splitlines()]
    reader = csv.reader(lines)
    header, start = None, 0
    for start, row in enumerate(reader, 1):
        if row and any(c.strip() for c in row) and not row[0].lstrip().startswith("#"):
            header = [c.strip().lower() for c in row]
            break
    if header is None:
        raise SceneError(f"{src}: [{key}] empty file; allowed: {allowed}")
    missing = [c for c in ("x", "y", "value") if c not in header]
    if missing:
        raise SceneError(f"{src}: [{key}] missing column(s) {', '.join(missing)} in header "
                         f"{','.join(header)!r}; allowed: {allowed}")
    col = {c: header.index(c) for c in ("x", "y", "value")}
    vals = {c: [] for c in col}
    gcol = header.index("group") if "group" in header else None
    groups = []
    rows = []
    for lineno, row in enumerate(csv.reader(lines[start:]), start + 1):
        if not row or not any(c.strip() for c in row) or row[0].lstrip().startswith("#"):
            continue
        for c, i in col.items():
            raw = row[i].strip() if i < len(row) else ""
            try:
                v = float(raw)
            except ValueError:
                raise SceneError(f"{src}: [{key}] row {lineno}: column {c} is not a number "
                                 f"({raw!r}); allowed: finite numbers") from None
            if not math.isfinite(v):
                raise SceneError(f"{src}: [{key}] row {lineno}: column {c} is {raw!r}; "
                                 "allowed: finite numbers")
            vals[c].append(v)
        if gcol is not None:
            groups.append(row[gcol].strip() if gcol < len(row) else "")
        rows.append(lineno)
    if not rows:
        raise SceneError(f"{src}: [{key}] no data rows; allowed: {allowed}")
    return Measurements(x=np.array(vals["x"]), y=np.array(vals["y"]),
                        value=np.array(vals["value"]), source=src, rows=np.array(rows),
                        group=np.array(groups) if gcol is not None else None)


def resolve_data_path(scene: Scene, data, spec: RandomFieldSpec | None = None) -> Path | None:
    """The CSV to condition on: ``data`` if given, else the ``data`` of ``spec`` (one
    property's spec, default the scene's ``[random_field]``), relative to the scene file."""
    if data is None:
        data = (spec or scene.random_field).data
        if data is None:
            return None
        p = Path(data)
        if not p.is_absolute() and scene.source not in ("<dict>",):
            p = Path(scene.source).parent / p
        return p
    return Path(data)


def _check_one_value_per_point(meas: Measurements, key: str) -> None:
    """Refuse two different values at one point (same x and y): kriging is exact at the
    data points, so they contradict each other (averaging them would hide it)."""
    xy = np.stack([meas.x, meas.y], axis=1)
    _, inv = np.unique(xy, axis=0, return_inverse=True)
    inv = inv.ravel()
    lo = np.full(inv.max() + 1, np.inf)
    hi = np.full(inv.max() + 1, -np.inf)
    np.minimum.at(lo, inv, meas.value)
    np.maximum.at(hi, inv, meas.value)
    bad = np.nonzero(lo != hi)[0]
    if len(bad):
        rows = np.nonzero(inv == bad[0])[0]
        r1 = rows[0]
        r2 = rows[np.nonzero(meas.value[rows] != meas.value[r1])[0][0]]
        raise SceneError(
            f"{meas.source}: [{key}] rows {meas.rows[r1]} and {meas.rows[r2]}: two values at "
            f"the point ({meas.x[r1]:g}, {meas.y[r1]:g}) m, {meas.value[r1]:g} and "
            f"{meas.value[r2]:g}; allowed: one value per point (kriging is exact at the data "
            "points)")


def data_cells(scene: Scene, grid, layout: FieldLayout, meas: Measurements,
               key: str = "random_field.data",
               spec: RandomFieldSpec | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Field cells and Gaussian values of the measurements of the property of ``spec``
    (default the scene's ``[random_field]``), checked to lie in the field's soil and in
    the range of the property's distribution."""
    rf = spec or scene.random_field
    _check_one_value_per_point(meas, key)
    pts = np.stack([meas.x, meas.y], axis=1)
    fidx, inside = layout.locate(pts)
    gcell, _, ginside = locate(grid, pts)
    owner = soil_cells(scene, grid)
    ok_soil = np.isin(owner[gcell], layout.soils) & ginside
    lo = layout.origin
    hi = layout.origin + layout.cell * np.array(layout.shape)
    bad = np.nonzero(~(inside & ok_soil))[0]
    if len(bad):
        r = bad[0]
        names = ", ".join(scene.soils[k].name for k in layout.soils)
        raise SceneError(
            f"{meas.source}: [{key}] row {meas.rows[r]}: point ({pts[r, 0]:g}, {pts[r, 1]:g}) m "
            f"lies outside the domain of the random field (soil {names} within "
            f"[{lo[0]:g}, {hi[0]:g}] x [{lo[1]:g}, {hi[1]:g}] m, grid frame); allowed: "
            "points inside the field's soil cells")
    mean = np.array([np.nan if (v := s.value(rf.property)) is None else float(v)
                     for s in scene.soils])[owner[gcell]]
    if rf.distribution == "lognormal":
        bad = np.nonzero(meas.value <= 0)[0]
        if len(bad):
            r = bad[0]
            raise SceneError(f"{meas.source}: [{key}] row {meas.rows[r]}: value "
                             f"{meas.value[r]:g} <= 0 with a lognormal field; allowed: values > 0")
    if rf.distribution == "beta":
        bad = np.nonzero(~((meas.value > rf.low) & (meas.value < rf.high)))[0]
        if len(bad):
            r = bad[0]
            raise SceneError(f"{meas.source}: [{key}] row {meas.rows[r]}: value "
                             f"{meas.value[r]:g} outside the beta field's ({rf.low:g}, "
                             f"{rf.high:g}); allowed: low < value < high")
    if rf.cov == 0:
        cov_key = key.rsplit(".", 1)[0] + ".cov"
        raise SceneError(f"{scene.source}: [{cov_key}] conditioning needs cov > 0; "
                         "allowed: cov > 0 with a data file")
    z = property_to_gaussian(meas.value, mean, rf)
    cells, inv = np.unique(fidx, return_inverse=True)
    zc = np.bincount(inv, weights=z) / np.bincount(inv)
    return cells, zc


def condition(emb: Embedding, z_uncond: np.ndarray, cells: np.ndarray,
              z_data: np.ndarray) -> np.ndarray:
    """Conditional realization: ``Z_u + C_.d C_dd^-1 (z_d - Z_u[d])`` (simple kriging).

    ``z_uncond`` (n2, n1), ``cells`` flat field indices (distinct), ``z_data`` Gaussian values.
    """
    n1, _ = emb.shape
    ci, cj = cells % n1, cells // n1
    Cdd = emb.covariance(ci[:, None] - ci[None, :], cj[:, None] - cj[None, :])
    resid = np.asarray(z_data, float) - z_uncond.ravel()[cells]
    w = cho_solve(cho_factor(Cdd), resid)
    W = np.zeros(emb.shape[::-1])
    W.ravel()[cells] = w
    return z_uncond + emb.convolve(W)
