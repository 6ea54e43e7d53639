"""Conditioning a 3-D field on measurements, as in 2-D (:mod:`.conditioning`): each value
goes to Gaussian space by the inverse marginal transform, conditions the lattice cell it
lies in (several in one cell: their Gaussian mean), and the conditional realization is
``Z_u + C_.d C_dd^-1 (z_d - Z_u[d])`` (simple kriging of the residual, Journel &
Huijbregts 1978), the convolution by FFT on the 3-D embedding, so the field equals the
data at their cells to round-off.

Measurements: a CSV with header ``x,y,z,value`` (m, m, m, property units; other columns
ignored, ``#`` lines skipped) or arrays ``(xyz (d, 3), value (d,))``.
"""
from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.linalg import cho_factor, cho_solve

from fem_rmpm.random_field.model import property_to_gaussian

__all__ = ["Measurements3D", "read_measurements_3d", "data_cells_3d", "condition_3d"]


@dataclass(frozen=True)
class Measurements3D:
    xyz: np.ndarray            # (d, 3) m
    value: np.ndarray          # (d,) property units
    source: str = "<arrays>"
    rows: np.ndarray | None = None


def read_measurements_3d(path, key: str = "random_field.data") -> Measurements3D:
    """Read ``x,y,z,value`` rows; a missing file or column, an empty table or a value that
    is not a finite number raises ``ValueError`` naming the file, row and column."""
    path = Path(path)
    allowed = "a CSV file with header x,y,z,value (m, m, m, property units)"
    if not path.is_file():
        raise ValueError(f"{path}: [{key}] file not found; allowed: {allowed}")
    try:
        lines = path.read_text(encoding="utf-8-sig").splitlines()
    except (UnicodeDecodeError, OSError) as exc:
        raise ValueError(f"{path}: [{key}] cannot be read as text ({exc}); allowed: "
                         f"{allowed}") from None
    rows = [(n, r) for n, r in enumerate(csv.reader(lines), 1)
            if r and any(c.strip() for c in r) and not r[0].lstrip().startswith("#")]
    if not rows:
        raise ValueError(f"{path}: [{key}] empty file; allowed: {allowed}")
    header = [c.strip().lower() for c in rows[0][1]]
    missing = [c for c in ("x", "y", "z", "value") if c not in header]
    if missing:
        raise ValueError(f"{path}: [{key}] missing column(s) {', '.join(missing)} in header "
                         f"{','.join(header)!r}; allowed: {allowed}")
    cols = [header.index(c) for c in ("x", "y", "z", "value")]
    data, linenos = [], []
    for lineno, r in rows[1:]:
        vals = []
        for name, i in zip(("x", "y", "z", "value"), cols):
            raw = r[i].strip() if i < len(r) else ""
            try:
                v = float(raw)
            except ValueError:
                v = math.nan
            if not math.isfinite(v):
                raise ValueError(f"{path}: [{key}] row {lineno}: column {name} is {raw!r}; "
                                 "allowed: finite numbers")
            vals.append(v)
        data.append(vals)
        linenos.append(lineno)
    if not data:
        raise ValueError(f"{path}: [{key}] no data rows; allowed: {allowed}")
    a = np.array(data)
    return Measurements3D(a[:, :3], a[:, 3], str(path), np.array(linenos))


def data_cells_3d(lattice, meas: Measurements3D, mean, spec,
                  key: str = "random_field.data") -> tuple[np.ndarray, np.ndarray]:
    """Flat lattice cells and Gaussian values of the measurements (``mean``: the property's
    point mean, a number or one per measurement); points outside the lattice, two
    different values at one point and values outside the distribution's range refused."""
    where, inside = lattice.locate(meas.xyz)
    rows = meas.rows if meas.rows is not None else np.arange(1, len(meas.value) + 1)
    if not inside.all():
        r = int(np.nonzero(~inside)[0][0])
        hi = lattice.origin + lattice.cell * np.array(lattice.shape)
        raise ValueError(f"{meas.source}: [{key}] row {rows[r]}: point "
                         f"{tuple(float(v) for v in meas.xyz[r])} m lies outside the field's "
                         f"box {tuple(lattice.origin)} - {tuple(hi)} m; allowed: points inside it")
    _, inv = np.unique(meas.xyz, axis=0, return_inverse=True)
    inv = inv.ravel()
    for g in np.unique(inv):
        vals = meas.value[inv == g]
        if np.any(vals != vals[0]):
            r = np.nonzero(inv == g)[0]
            raise ValueError(f"{meas.source}: [{key}] rows {rows[r[0]]} and {rows[r[1]]}: two "
                             "values at one point; allowed: one value per point (kriging is "
                             "exact at the data points)")
    if spec.distribution == "lognormal" and np.any(meas.value <= 0):
        r = int(np.nonzero(meas.value <= 0)[0][0])
        raise ValueError(f"{meas.source}: [{key}] row {rows[r]}: value {meas.value[r]:g} <= 0 "
                         "with a lognormal field; allowed: values > 0")
    if spec.distribution == "beta" and np.any((meas.value <= spec.low) | (meas.value >= spec.high)):
        r = int(np.nonzero((meas.value <= spec.low) | (meas.value >= spec.high))[0][0])
        raise ValueError(f"{meas.source}: [{key}] row {rows[r]}: value {meas.value[r]:g} "
                         f"outside ({spec.low:g}, {spec.high:g}); allowed: low < value < high")
    if spec.cov == 0:
        raise ValueError(f"{meas.source}: [{key}] conditioning needs cov > 0")
    z = property_to_gaussian(meas.value, np.asarray(mean, float), spec)
    cells, inv = np.unique(where, return_inverse=True)
    return cells, np.bincount(inv.ravel(), weights=z) / np.bincount(inv.ravel())


def condition_3d(emb, z_uncond: np.ndarray, cells: np.ndarray,
                 z_data: np.ndarray) -> np.ndarray:
    """Conditional realization (n1, n2, n3) by simple kriging of the residual."""
    if not hasattr(emb, "convolve"):
        raise ValueError("conditioning a perfectly correlated (single-variable) 3-D field is "
                         "not supported; allowed: a scale of fluctuation below ~50 x the field")
    ci, cj, ck = np.unravel_index(cells, emb.shape)
    Cdd = emb.covariance(ci[:, None] - ci[None, :], cj[:, None] - cj[None, :],
                         ck[:, None] - ck[None, :])
    resid = np.asarray(z_data, float) - z_uncond.ravel()[cells]
    w = cho_solve(cho_factor(Cdd), resid)
    W = np.zeros(emb.shape)
    W.ravel()[cells] = w
    return z_uncond + emb.convolve(W)
