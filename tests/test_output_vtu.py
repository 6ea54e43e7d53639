"""The points' VTU (raw appended data, :func:`fem_rmpm.io.output.write_points_vtu`): every field
and the positions read back bitwise by meshio and by pyvista (VTK's own XML reader, the one
ParaView uses), vertex cells, the ``.pvd`` series, and the atomic write."""
from __future__ import annotations

import os
from pathlib import Path

import meshio
import numpy as np
import pytest

from fem_rmpm import api
from fem_rmpm.io import output
from fem_rmpm.io.output import PvdSeries, particle_fields, write_particles, write_points_vtu

MESHES = Path(__file__).resolve().parents[1] / "meshes"


def _points():
    """The column's points with awkward values in every field: noisy mantissas, -0.0,
    subnormals, huge and tiny magnitudes, a frozen point and a second soil index."""
    _, pts = api.prepare(api.load_scene(MESHES / "column.toml"))
    rng = np.random.default_rng(7)
    pts.x[:] += rng.normal(size=pts.x.shape) * 1e-3
    pts.velocity[:] = rng.normal(size=pts.velocity.shape)
    pts.stress[:] = rng.normal(size=pts.stress.shape) * 1e3
    pts.stress[0] = [-0.0, 5e-324, 1.7e308, -2.2e-308]
    pts.state[:, 0] = np.abs(rng.normal(size=pts.n)) * 1e-2
    pts.volume[:] *= 1 + rng.normal(size=pts.n) * 1e-6
    pts.active[1] = False
    pts.soil_id[2] = 1
    return pts


def _same(a, b) -> bool:
    """Bitwise equality, dtype and shape included (NaN-free data; -0.0 != 0.0 here)."""
    a, b = np.asarray(a), np.asarray(b)
    return a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()


def test_every_field_round_trips_bitwise_in_meshio(tmp_path):
    pts = _points()
    write_particles(tmp_path / "p.vtu", pts)
    m = meshio.read(tmp_path / "p.vtu")
    expected = particle_fields(pts)
    assert _same(m.points, np.hstack([pts.x, np.zeros((pts.n, 1))]))
    assert [c.type for c in m.cells] == ["vertex"]
    assert np.array_equal(m.cells[0].data.ravel(), np.arange(pts.n))
    assert list(m.point_data) == list(expected)
    for name, value in expected.items():
        assert _same(m.point_data[name], value), name
    assert m.point_data["stress"][0, 0] == 0.0 and np.signbit(m.point_data["stress"][0, 0])
    # the documented layout (docs/guide/outputs.md): 2D vectors with a zero z, the stress's
    # yz and xz zero
    for name, value, k in (("displacement", pts.displacement, 2), ("velocity", pts.velocity, 2),
                           ("stress", pts.stress, 4)):
        assert _same(m.point_data[name][:, :k], value) and not m.point_data[name][:, k:].any()
        assert not np.signbit(m.point_data[name][:, k:]).any()
    # the same content as meshio's own writer gives (the writer before the raw one)
    meshio.Mesh(m.points, [("vertex", np.arange(pts.n)[:, None])], point_data=expected).write(
        tmp_path / "meshio.vtu", binary=True, compression=None)
    ref = meshio.read(tmp_path / "meshio.vtu")
    assert _same(ref.points, m.points)
    for name in expected:
        assert _same(ref.point_data[name], m.point_data[name]), name
    assert os.path.getsize(tmp_path / "p.vtu") < os.path.getsize(tmp_path / "meshio.vtu")


def test_every_field_round_trips_bitwise_in_pyvista(tmp_path):
    """pyvista reads with VTK's vtkXMLUnstructuredGridReader, ParaView's reader."""
    pv = pytest.importorskip("pyvista")
    pts = _points()
    write_particles(tmp_path / "p.vtu", pts)
    g = pv.read(tmp_path / "p.vtu")
    assert g.n_points == pts.n and g.n_cells == pts.n
    assert set(np.asarray(g.celltypes).tolist()) == {1}            # VTK_VERTEX
    assert _same(g.points, np.hstack([pts.x, np.zeros((pts.n, 1))]))
    expected = particle_fields(pts)
    assert sorted(g.point_data.keys()) == sorted(expected)
    for name, value in expected.items():
        assert _same(np.asarray(g.point_data[name]), value), name


def test_the_pvd_series_opens_in_pyvista(tmp_path):
    pv = pytest.importorskip("pyvista")
    pts = _points()
    series = PvdSeries(tmp_path)
    series.add(0.0, pts)
    pts.x[:, 1] -= 0.25
    series.add(1.5, pts)
    reader = pv.get_reader(tmp_path / "particles.pvd")
    assert list(reader.time_values) == [0.0, 1.5]
    reader.set_active_time_value(1.5)
    block = reader.read()[0]
    assert _same(block.points[:, :2], pts.x)
    assert _same(np.asarray(block.point_data["velocity"]), particle_fields(pts)["velocity"])


def test_any_dtype_and_shape_the_writer_accepts_round_trips(tmp_path):
    n = 5
    data = {"f32": np.arange(n, dtype=np.float32) / 3, "i64": -np.arange(n, dtype=np.int64),
            "u8": np.arange(n, dtype=np.uint8), "m": np.arange(2 * n, dtype=float).reshape(n, 2),
            "fortran": np.asfortranarray(np.arange(3 * n, dtype=float).reshape(n, 3))}
    x = np.arange(3 * n, dtype=float).reshape(n, 3)
    write_points_vtu(tmp_path / "d.vtu", x, data)
    m = meshio.read(tmp_path / "d.vtu")
    for name, value in data.items():
        assert _same(m.point_data[name], np.ascontiguousarray(value)), name
    write_points_vtu(tmp_path / "none.vtu", x, {})                 # no point data at all
    assert len(meshio.read(tmp_path / "none.vtu").points) == n
    with pytest.raises(ValueError, match="rows"):
        write_points_vtu(tmp_path / "e.vtu", x, {"short": np.zeros(n - 1)})
    assert not (tmp_path / "e.vtu").exists()


def test_a_failed_write_leaves_no_file_and_no_temporary(tmp_path, monkeypatch):
    pts = _points()
    write_particles(tmp_path / "p.vtu", pts)
    before = (tmp_path / "p.vtu").read_bytes()

    def boom(*_):
        raise OSError("disk full")

    monkeypatch.setattr(output.os, "replace", boom)
    pts.x[:] += 1.0
    with pytest.raises(OSError, match="disk full"):
        write_particles(tmp_path / "p.vtu", pts)
    with pytest.raises(OSError, match="disk full"):
        write_particles(tmp_path / "q.vtu", pts)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["p.vtu"]
    assert (tmp_path / "p.vtu").read_bytes() == before           # the old snapshot is intact


def test_block_by_block_is_bitwise_the_whole_array_fields(tmp_path, monkeypatch):
    """write_particles computes the fields a block of points at a time: with blocks of 64
    (286 blocks of the reference slope, a last short one) and two models mixed block by
    block, every field read back is bitwise :func:`particle_fields` of the whole arrays."""
    from fem_rmpm.materials.protocol import MaterialPoints
    _, pts = api.prepare(api.load_scene(MESHES / "slope_reference.toml"))
    rng = np.random.default_rng(11)
    pts.state[:, 0] = rng.random(pts.n) * 0.3                 # softened, some residual
    pts.stress[:] = rng.normal(size=pts.stress.shape) * 50
    model = pts.soil.model.copy()
    model[5000:5100] = 0                                      # linear elastic: no cohesion
    model[rng.random(pts.n) < 0.01] = 0
    pts.soil = MaterialPoints(model, pts.soil.params)
    monkeypatch.setattr(output, "_BLOCK", 64)
    write_particles(tmp_path / "b.vtu", pts)
    m = meshio.read(tmp_path / "b.vtu")
    assert _same(m.points, np.hstack([pts.x, np.zeros((pts.n, 1))]))
    for name, value in particle_fields(pts).items():
        assert _same(m.point_data[name], value), name
    assert (m.point_data["cohesion"][model == 0] == -1.0).all()
    # a non-finite value stops the write, naming the first bad field in the documented order
    # (the positions last), whatever block it is in; nothing is left behind
    pts.stress[-1, 3] = np.nan
    pts.velocity[9000, 1] = np.inf
    with pytest.raises(output.OutputError, match="'velocity'"):
        write_particles(tmp_path / "c.vtu", pts)
    pts.velocity[9000, 1] = 0.0
    with pytest.raises(output.OutputError, match="'stress'"):
        write_particles(tmp_path / "c.vtu", pts)
    pts.stress[-1, 3] = 0.0
    pts.x[-1, 0] = np.nan                                     # a position: its displacement
    with pytest.raises(output.OutputError, match="'displacement'"):
        write_particles(tmp_path / "c.vtu", pts)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["b.vtu"]


def test_the_grid_round_trips_in_meshio_and_pyvista(tmp_path):
    """``grid.vtu`` (:func:`fem_rmpm.io.output.write_grid`, VTK's XML writer, zlib level 1):
    the node coordinates bitwise, the quads' node numbers, ``soil_cell`` (1 on the given
    cells) and ``fixed`` read back by meshio and by pyvista, no temporary left behind."""
    import pyvista as pv
    grid, _ = api.prepare(api.load_scene(MESHES / "slope_reference.toml"))
    active = np.arange(0, grid.n_cells, 3)
    flag = np.zeros(grid.n_cells, np.int8)
    flag[active] = 1
    path = tmp_path / "grid.vtu"
    output.write_grid(path, grid, active)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["grid.vtu"]
    m = meshio.read(path)
    assert _same(m.points[:, :2], grid.nodes) and not m.points[:, 2].any()
    assert np.array_equal(m.cells_dict["quad"], grid.cells)
    assert np.array_equal(m.cell_data["soil_cell"][0], flag)
    assert np.array_equal(m.point_data["fixed"], grid.fixed.astype(np.int8))
    v = pv.read(path)
    assert v.n_cells == grid.n_cells and _same(np.asarray(v.points)[:, :2], grid.nodes)
    assert np.array_equal(v.cell_data["soil_cell"], flag)
    assert np.array_equal(v.point_data["fixed"], grid.fixed.astype(np.int8))
