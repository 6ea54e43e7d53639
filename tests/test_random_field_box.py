"""``[random_field] box``: a fixed field rectangle, so that realization i has the same
random field on every mesh (a paired mesh check).  Without it the field's
rectangle is the bounding box of the soil cells, which moves with the grid cell (242 /
243 field columns at 0.5 / 0.25 m on meshes/slope_risk.toml), so the circulant embedding
and the whole field of a seed change with the mesh."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from fem_rmpm import api
from fem_rmpm.campaign.cases import parse_case, realization_seed
from fem_rmpm.random_field.layout import field_layout
from fem_rmpm.scene import SceneError, with_values

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "meshes" / "slope_risk.toml"


def _cells(scene, cell: float, seed: int) -> dict[int, float]:
    """{field cell: c_peak} of the points of realization ``seed`` on cells of ``cell`` m
    (each field cell holds one value; asserted)."""
    s = api.with_value(scene, "grid.cell", cell)
    grid, pts = api.prepare(s, seed)
    idx, _ = field_layout(s, grid).locate(pts.x0)
    c = np.asarray(pts.soil.cohesion_peak)
    out: dict[int, float] = {}
    for i, v in zip(idx.tolist(), c.tolist()):
        assert out.setdefault(i, v) == v
    return out


def test_same_field_on_every_mesh():
    """With the scene's box, every field cell holds the same c_peak at 0.5 and 0.25 m
    cells (xi = 48, realization 8: 3850 common cells, all equal)."""
    scene = parse_case("xi=48", api.load_scene(SCENE)).scene
    seed = realization_seed(scene.montecarlo.seed, 8)
    coarse, fine = _cells(scene, 0.5, seed), _cells(scene, 0.25, seed)
    common = set(coarse) & set(fine)
    assert len(common) > 0.95 * len(coarse)
    assert all(coarse[k] == fine[k] for k in common)


def test_box_keeps_the_coarse_field_and_without_it_the_mesh_changes_it():
    """The box is the 0.5 m mesh's own rectangle: the 0.5 m field is the one drawn without
    it (the campaign's records stay valid).  Without the box the 0.25 m mesh draws another
    field from the same seed: most common cells differ."""
    boxed = parse_case("xi=48", api.load_scene(SCENE)).scene
    plain = api.with_value(boxed, "random_field.box", None)
    seed = realization_seed(boxed.montecarlo.seed, 8)
    assert _cells(boxed, 0.5, seed) == _cells(plain, 0.5, seed)
    coarse, fine = _cells(plain, 0.5, seed), _cells(plain, 0.25, seed)
    common = set(coarse) & set(fine)
    assert sum(coarse[k] != fine[k] for k in common) > 0.9 * len(common)


@pytest.mark.parametrize("box, cell_size, needle", [
    ([0.0, 0.0, 60.5], 0.25, "four numbers"),
    ([0.0, 0.0, 60.5, 0.0], 0.25, "y1 > y0"),
    ([0.0, 0.0, 60.5, 5.0], None, "needs random_field.cell_size"),
])
def test_bad_box_is_refused(box, cell_size, needle):
    scene = api.load_scene(SCENE)
    with pytest.raises(SceneError, match="random_field.box") as err:
        with_values(scene, {"random_field.cell_size": cell_size, "random_field.box": box})
    assert needle in str(err.value)
