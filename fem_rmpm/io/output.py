"""Output: VTK for ParaView, a ``.pvd`` time series, JSON summaries and PNG figures.

Point data of ``particles_NNNN.vtu``: ``displacement`` and
``velocity`` (3 components, m and m/s), ``stress`` (6 components, VTK order
xx yy zz xy yz xz, kPa, tension positive), ``plastic_shear_strain`` (-),
``cohesion`` (kPa), ``volume`` (m2 per m), ``mass`` (t per m), ``active`` (0/1).
Coordinates are in the grid frame.  Every file is written to a temporary name
and renamed, and no array holding NaN or Inf is ever written.

The points' files are VTK XML ``UnstructuredGrid`` with raw appended data (``<AppendedData
encoding="raw">``, ``header_type="UInt64"``, vertex cells), written by :func:`write_points_vtu`
straight from the arrays: no base64, no XML per value.  meshio, pyvista (VTK's own reader)
and ParaView read them (``tests/test_output_vtu.py``: every field bitwise, both readers).
``grid.vtu`` is written by VTK's own XML writer (:func:`write_grid`, zlib at level 1).
"""
from __future__ import annotations

import json
import math
import os
import tempfile
from pathlib import Path
from typing import Callable, NamedTuple

import numpy as np

from fem_rmpm.discretise.points import Particles
from fem_rmpm.materials import cohesion

__all__ = ["write_json", "write_particles", "write_points_vtu", "write_grid", "PvdSeries",
           "read_pvd", "to_true_frame", "OutputError"]


class OutputError(RuntimeError):
    """Refused to write a non-finite field."""


def _read_umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


_UMASK = _read_umask()   # read once at import: os.umask is process-wide and not thread-safe


def _atomic_write_bytes(path: Path, data: bytes, durable: bool = True) -> None:
    """``data`` to ``path`` through a temporary file and a rename (a reader never sees a
    part-written file); ``durable``: flushed to disk before the rename (``fsync``, ~1 ms)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
            fh.flush()
            if durable:
                os.fsync(fh.fileno())
        os.chmod(tmp, 0o644 & ~_UMASK)          # mkstemp makes 0600; records are shared
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def _jsonable(obj):
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _jsonable(obj.tolist())
    if isinstance(obj, (np.floating, float)):
        v = float(obj)
        return v if math.isfinite(v) else str(v)
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, np.bool_):
        return bool(obj)
    return obj


def write_json(path: str | Path, obj) -> None:
    """Write JSON atomically (non-finite floats become the strings 'inf'/'nan')."""
    _atomic_write_bytes(Path(path), json.dumps(_jsonable(obj), indent=2).encode())


def _check_finite(name: str, arr: np.ndarray, where: str) -> None:
    if not np.all(np.isfinite(arr)):
        raise OutputError(f"refusing to write non-finite '{name}' to {where}")


def _padded(a: np.ndarray, width: int) -> np.ndarray:
    """``a`` (n, k) with zero columns appended to ``width`` (one allocation)."""
    out = np.zeros((len(a), width))
    out[:, :a.shape[1]] = a
    return out


def particle_fields(pts: Particles) -> dict[str, np.ndarray]:
    coh = pts.cohesion
    peak = pts.soil.cohesion_peak
    return {
        "displacement": _padded(pts.displacement, 3),
        "velocity": _padded(pts.velocity, 3),
        "stress": _padded(pts.stress, 6),            # xx yy zz xy, then yz = xz = 0
        "plastic_shear_strain": pts.plastic_shear_strain.copy(),
        "cohesion": np.where(np.isfinite(coh), coh, -1.0),   # -1: elastic point (no strength)
        "cohesion_peak": np.where(np.isfinite(peak), peak, -1.0),
        "volume": pts.volume.copy(),
        "mass": pts.mass.copy(),
        "active": pts.active.astype(np.int8),
        "soil": pts.soil_id.astype(np.int32),
    }


#: Compression of the points' ``.vtu``: None.  The float64 fields of a running slope (noisy
#: mantissas) shrink only to 0.95 of their size with zlib, for 22-50 ms of CPU per snapshot
#: of the reference slope's 18 260 points against 5 ms uncompressed (measured with meshio),
#: i.e. up to ~2 s of a 40-snapshot run for 5 % of disk.  (The raw writer has no compressor.)
POINTS_COMPRESSION = None

_VTK_VERTEX = 1
_VTU_TYPES = {np.dtype(np.float64): "Float64", np.dtype(np.float32): "Float32",
              np.dtype(np.int64): "Int64", np.dtype(np.int32): "Int32",
              np.dtype(np.int8): "Int8", np.dtype(np.uint8): "UInt8"}
_vertex_cells: dict = {}       # n -> (connectivity, offsets, types): the same every snapshot


def _vertex_cells_of(n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    cells = _vertex_cells.get(n)
    if cells is None:
        idx = np.arange(n, dtype=np.int64)
        cells = (idx, idx + 1, np.full(n, _VTK_VERTEX, dtype=np.uint8))
        _vertex_cells.clear()               # one point count per run: keep one
        _vertex_cells[n] = cells
    return cells


#: Points per block when a field is computed and written a block at a time: the blocks'
#: temporaries stay in cache and are reused, where whole-array temporaries of 1e6 points
#: fault in fresh (huge) pages every frame.  A multiple of 64, so a numpy SIMD loop splits
#: a block as it splits the whole array.
_BLOCK = 1 << 15


class _Blocks(NamedTuple):
    """A point-data array given block by block: ``block(lo, hi)`` -> rows lo:hi (C order)."""
    dtype: np.dtype
    components: int
    block: Callable[[int, int], np.ndarray]


def _blocks_of(a: np.ndarray) -> _Blocks:
    a = np.ascontiguousarray(a)
    if a.dtype.byteorder == ">":
        a = a.astype(a.dtype.newbyteorder("<"))
    return _Blocks(a.dtype, 1 if a.ndim == 1 else int(np.prod(a.shape[1:])),
                   lambda lo, hi: a[lo:hi])


def write_points_vtu(path: str | Path, points, point_data: dict, check=None,
                     n: int | None = None) -> None:
    """Points (n, 3) as vertex cells with ``point_data`` (name -> (n,) or (n, k) array, or
    :class:`_Blocks`) to a VTK XML ``UnstructuredGrid`` file with raw appended data (little
    endian, UInt64 block headers), written to a temporary name and renamed.  The arrays
    are written as they are (their dtype; float64, int8, int32, ...), each preceded by its
    byte count; in the appended data the point data come first and the points last.
    ``check(name, rows)``: called on every block before it is written (it may raise);
    ``n``: the point count when ``points`` is given as :class:`_Blocks`."""
    path = Path(path)
    pts = points if isinstance(points, _Blocks) else _blocks_of(points)
    n = int(n) if isinstance(points, _Blocks) else len(points)
    conn, offs, types = _vertex_cells_of(n)
    entries = [("PointData", name, a if isinstance(a, _Blocks) else _blocks_of(a))
               for name, a in point_data.items()]
    entries += [("Cells", "connectivity", _blocks_of(conn)), ("Cells", "offsets", _blocks_of(offs)),
                ("Cells", "types", _blocks_of(types)), ("Points", "Points", pts)]
    for name, a in point_data.items():
        if not isinstance(a, _Blocks) and len(a) != n:
            raise ValueError(f"point data {name!r} has {len(a)} rows, not {n}")
    sections, offset = {}, 0
    for section, name, a in entries:
        nc = (f' NumberOfComponents="{a.components}"'
              if a.components > 1 or section == "Points" else "")
        sections.setdefault(section, []).append(
            f'<DataArray type="{_VTU_TYPES[a.dtype.newbyteorder("=")]}" Name="{name}"{nc} '
            f'format="appended" offset="{offset}"/>')
        offset += 8 + n * a.components * a.dtype.itemsize
    xml = ['<?xml version="1.0"?>\n<VTKFile type="UnstructuredGrid" version="1.0" '
           'byte_order="LittleEndian" header_type="UInt64">\n'
           '<!--fem_rmpm: raw appended data, UInt64 block headers-->\n<UnstructuredGrid>\n'
           f'<Piece NumberOfPoints="{n}" NumberOfCells="{n}">\n']
    for section in ("Points", "Cells", "PointData"):
        xml.append(f"<{section}>\n" + "\n".join(sections.get(section, [])) + f"\n</{section}>\n")
    xml.append('</Piece>\n</UnstructuredGrid>\n<AppendedData encoding="raw">\n_')
    tmp = path.with_name(f".{path.name}.tmp.vtu")
    try:
        with open(tmp, "wb") as fh:
            fh.write("".join(xml).encode())
            for _, name, a in entries:
                fh.write(np.uint64(n * a.components * a.dtype.itemsize).tobytes())
                for lo in range(0, n, _BLOCK):
                    rows = a.block(lo, min(lo + _BLOCK, n))
                    if check is not None:
                        check(name, rows)
                    fh.write(memoryview(np.ascontiguousarray(rows, a.dtype).reshape(-1)).cast("B"))
            fh.write(b"\n</AppendedData>\n</VTKFile>\n")
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def _particle_blocks(pts: Particles) -> dict[str, _Blocks]:
    """:func:`particle_fields` a block of points at a time (the same elementwise arithmetic
    on the same values: bitwise the same arrays, ``tests/test_output_vtu.py``)."""
    f8, soil, disp = np.dtype(np.float64), pts.soil, pts.displacement

    def coh(lo, hi):
        c = cohesion(pts.state[lo:hi], soil.take(slice(lo, hi)))
        return np.where(np.isfinite(c), c, -1.0)

    def peak(lo, hi):
        c = soil.take(slice(lo, hi)).cohesion_peak
        return np.where(np.isfinite(c), c, -1.0)

    return {
        "displacement": _Blocks(f8, 3, lambda lo, hi: _padded(disp[lo:hi], 3)),
        "velocity": _Blocks(f8, 3, lambda lo, hi: _padded(pts.velocity[lo:hi], 3)),
        "stress": _Blocks(f8, 6, lambda lo, hi: _padded(pts.stress[lo:hi], 6)),
        "plastic_shear_strain": _Blocks(f8, 1, lambda lo, hi: pts.plastic_shear_strain[lo:hi]),
        "cohesion": _Blocks(f8, 1, coh),
        "cohesion_peak": _Blocks(f8, 1, peak),
        "volume": _Blocks(f8, 1, lambda lo, hi: pts.volume[lo:hi]),
        "mass": _Blocks(f8, 1, lambda lo, hi: pts.mass[lo:hi]),
        "active": _Blocks(np.dtype(np.int8), 1, lambda lo, hi: pts.active[lo:hi].astype(np.int8)),
        "soil": _Blocks(np.dtype(np.int32), 1, lambda lo, hi: pts.soil_id[lo:hi].astype(np.int32)),
    }


def write_particles(path: str | Path, pts: Particles, extra=None) -> None:
    """One ``.vtu`` of the material points (vertex cells) with the fields above, raw
    binary appended data (:func:`write_points_vtu`), uncompressed, computed and written a
    block of points at a time; a non-finite value in any field (checked in the order
    above, the positions last) stops the write and leaves no file.  ``extra``: more
    fields {name: (n,) or (n, k) float array}, after these (e.g. the pore water's
    ``pore_pressure`` and ``total_stress``)."""
    path = Path(path)
    where = str(path)

    def check(name, rows):
        if rows.dtype.kind == "f":
            _check_finite("points" if name == "Points" else name, rows, where)

    write_points_vtu(path, _Blocks(np.dtype(np.float64), 3,
                                   lambda lo, hi: _padded(pts.x[lo:hi], 3)),
                     {**_particle_blocks(pts), **_extra_blocks(extra)}, check, n=pts.n)


def _extra_blocks(extra) -> dict[str, _Blocks]:
    """The :class:`_Blocks` of :func:`write_particles`' ``extra`` fields."""
    out = {}
    for name, a in (extra or {}).items():
        a = np.asarray(a, dtype=np.float64)
        out[name] = _Blocks(np.dtype(np.float64), 1 if a.ndim == 1 else a.shape[1],
                            lambda lo, hi, a=a: a[lo:hi])
    return out


def write_grid(path: str | Path, grid, active_cells: np.ndarray | None = None) -> None:
    """The background grid as ``.vtu`` with cell data ``soil_cell`` and point data ``fixed``
    (VTK's own XML writer: raw appended data, zlib at level 1; written to a temporary name
    and renamed).  Level 1 compresses the grid's regular coordinates and connectivity as
    well as meshio's level 6 in a fifth of the time: the 1/30 m grid of the reference slope
    (4.97 M cells) 1.5 s and 51 MB against 7.0 s and 62 MB, the 0.25 m grid 0.03 s and
    0.8 MB against 0.11 s and 1.0 MB (measured)."""
    # lazy: VTK (~0.2 s of imports) only where a grid is written
    from vtkmodules.util.numpy_support import numpy_to_vtk  # lazy: VTK
    from vtkmodules.vtkCommonCore import vtkPoints  # lazy: VTK
    from vtkmodules.vtkCommonDataModel import (  # lazy: VTK
        VTK_QUAD,
        vtkCellArray,
        vtkUnstructuredGrid,
    )
    from vtkmodules.vtkIOXML import vtkXMLUnstructuredGridWriter  # lazy: VTK
    path = Path(path)
    ug = vtkUnstructuredGrid()
    xyz = np.zeros((grid.n_nodes, 3))
    xyz[:, :2] = grid.nodes
    points = vtkPoints()
    points.SetData(numpy_to_vtk(xyz, deep=True))
    ug.SetPoints(points)
    cells = vtkCellArray()
    cells.SetData(numpy_to_vtk(np.arange(0, 4 * grid.n_cells + 1, 4, dtype=np.int64), deep=True),
                  numpy_to_vtk(np.ascontiguousarray(grid.cells, np.int64).ravel(), deep=True))
    ug.SetCells(VTK_QUAD, cells)
    arrays = [(ug.GetPointData(), "fixed", grid.fixed.astype(np.int8))]
    if active_cells is not None:
        flag = np.zeros(grid.n_cells, dtype=np.int8)
        flag[active_cells] = 1
        arrays.append((ug.GetCellData(), "soil_cell", flag))
    for data, name, values in arrays:
        array = numpy_to_vtk(values, deep=True)
        array.SetName(name)
        data.AddArray(array)
    tmp = path.with_name(f".{path.name}.tmp.vtu")
    writer = vtkXMLUnstructuredGridWriter()
    writer.SetFileName(str(tmp))
    writer.SetInputData(ug)
    writer.SetDataModeToAppended()
    writer.EncodeAppendedDataOff()
    writer.SetCompressorTypeToZLib()
    writer.SetCompressionLevel(1)
    if writer.Write() != 1:
        if tmp.exists():
            tmp.unlink()
        raise OSError(f"could not write the grid to {path} (VTK's XML writer failed)")
    os.replace(tmp, path)


class PvdSeries:
    """``particles.pvd`` time series, rewritten after each snapshot (valid if a run dies:
    renamed into place; not flushed to disk, ``fsync``, as its frames are not either: ~1 ms
    a frame, 1 % of a two-thread run of the reference slope, measured)."""

    def __init__(self, directory: str | Path, stem: str = "particles", extra=None):
        self.dir = Path(directory)
        self.stem = stem
        self.entries: list[tuple[float, str]] = []
        self.extra = extra           # pts -> {name: array} of more point fields, or None

    def add(self, t: float, pts: Particles) -> Path:
        name = f"{self.stem}_{len(self.entries):04d}.vtu"
        write_particles(self.dir / name, pts, self.extra(pts) if self.extra else None)
        self.entries.append((t, name))
        rows = "\n".join(f'    <DataSet timestep="{tt:.9g}" group="" part="0" file="{f}"/>'
                         for tt, f in self.entries)
        xml = ('<?xml version="1.0"?>\n<VTKFile type="Collection" version="0.1" '
               f'byte_order="LittleEndian">\n  <Collection>\n{rows}\n  </Collection>\n</VTKFile>\n')
        _atomic_write_bytes(self.dir / f"{self.stem}.pvd", xml.encode(), durable=False)
        return self.dir / name


def read_pvd(path: str | Path) -> list[tuple[float, Path]]:
    """The snapshots a ``.pvd`` series file (:class:`PvdSeries`) lists, in its order:
    ``(time s, path of the .vtu)``; [] when the file is missing or not valid XML."""
    import xml.etree.ElementTree as ET  # lazy: reading a series back only
    path = Path(path)
    try:
        entries = ET.parse(path).getroot().findall(".//DataSet")
    except (OSError, ET.ParseError):
        return []
    return [(float(d.get("timestep")), path.parent / d.get("file")) for d in entries]


def to_true_frame(x: np.ndarray, frame_angle_deg: float) -> np.ndarray:
    """Rotate grid-frame coordinates (n, 2) to the true horizontal/vertical (m)."""
    a = math.radians(frame_angle_deg)
    c, s = math.cos(a), math.sin(a)
    return np.stack([c * x[:, 0] + s * x[:, 1], -s * x[:, 0] + c * x[:, 1]], axis=1)
