"""``api.run`` keeps at most :data:`fem_rmpm.api.SNAPSHOT_MEMORY_BYTES` of output
snapshots in memory (positions and plastic strains of every output would be ~5 GB for
5 million points); the snapshots beyond are disk-backed and give bitwise the same
measures.  A three-dimensional run keeps no positions at all."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from fem_rmpm import api
from fem_rmpm.scene import with_values

MESHES = Path(__file__).parents[1] / "meshes"


def test_disk_backed_snapshots_give_the_same_measures(monkeypatch):
    """The 2-D column with every snapshot after the first on disk: the measures and the
    snapshots equal those of the run held in memory, bitwise."""
    scene = with_values(api.load_scene(MESHES / "column.toml"), {"solver.t_end": 3.0})
    ref = api.run(scene)
    monkeypatch.setattr(api, "SNAPSHOT_MEMORY_BYTES", 1)
    res = api.run(scene)
    assert len(res.snapshots) == len(ref.snapshots) >= 3
    assert all(isinstance(x, np.memmap) for _, x, _ in res.snapshots)
    for (t1, x1, g1), (t2, x2, g2) in zip(res.snapshots, ref.snapshots):
        assert t1 == t2 and np.array_equal(x1, x2) and np.array_equal(g1, g2)
    assert res.measures == ref.measures


def test_3d_run_keeps_output_times_only():
    scene = with_values(api.load_scene(MESHES / "column_3d.toml"), {"solver.t_end": 2.0})
    res = api.run(scene)
    assert res.snapshots and all(len(s) == 1 for s in res.snapshots)


def test_intact_blocks_are_3d_connected_components():
    """Two separated 2x2x2-cell lumps of sliding intact points and one single cell: two
    blocks of at least a 1 m2-faced cube (cells of 0.5 m: 8 cells), one too small."""
    from types import SimpleNamespace

    from fem_rmpm.discretise.grid3d import Grid3D
    from fem_rmpm.measures.deposit3d import intact_blocks_3d
    grid = Grid3D(origin=np.zeros(3), cell=np.full(3, 0.5), shape=(10, 4, 6),
                  fixed=np.zeros((11 * 5 * 7, 3), bool))
    centres = []
    for lo in ((0, 0, 0), (3, 0, 3)):
        for d in np.ndindex(2, 2, 2):
            centres.append((np.array(lo) + d + 0.5) * 0.5)
    centres.append(np.array([9.5, 3.5, 5.5]) * 0.5)
    x = np.array(centres)
    pts = SimpleNamespace(x=x, x0=x - [1.0, 0, 0], active=np.ones(len(x), bool),
                          plastic_shear_strain=np.zeros(len(x)))
    assert intact_blocks_3d(pts, grid, 0.5, 1.0) == 2
    pts.plastic_shear_strain[:8] = 0.5            # one lump no longer intact
    assert intact_blocks_3d(pts, grid, 0.5, 1.0) == 1
