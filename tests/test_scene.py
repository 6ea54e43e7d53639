"""Scene files: bad input gets a clear one-line error and loses nothing.

Each case runs the real command line (``fem_rmpm.cli.main``) and checks: exit code 2,
exactly one line on stderr naming the file and the key and what is allowed, no
traceback, and no output directory created.
"""
from __future__ import annotations

import json
import math

import pytest

from fem_rmpm.cli import main
from fem_rmpm.scene import SceneError, load_scene, scene_from_dict, scene_to_dict, with_value


def _run_bad(tmp_path, capsys, text: str | None, expect_key: str, expect_words: tuple[str, ...],
             name: str = "bad.toml", write: bool = True):
    scene = tmp_path / name
    if write:
        scene.write_bytes(text.encode() if isinstance(text, str) else text)
    out = tmp_path / "out"
    code = main(["run", str(scene), "--out", str(out), "--quiet"])
    err = capsys.readouterr().err.strip()
    assert code == 2
    assert len(err.splitlines()) == 1, err
    assert "Traceback" not in err
    assert str(scene) in err
    assert expect_key in err
    for w in expect_words:
        assert w in err, err
    assert not out.exists()
    return err


def test_unknown_key_is_named(tmp_path, capsys, column_text):
    """A typo in a key ('youngs_modulos') names the key and lists the allowed keys."""
    text = column_text.replace("youngs_modulus", "youngs_modulos")
    _run_bad(tmp_path, capsys, text, "soil.youngs_modulos", ("unknown key", "youngs_modulus"))


def test_missing_required_key(tmp_path, capsys, column_text):
    text = "\n".join(l for l in column_text.splitlines() if not l.startswith("unit_weight"))
    _run_bad(tmp_path, capsys, text, "soil.unit_weight", ("missing required key",))


def test_negative_modulus(tmp_path, capsys, column_text):
    text = column_text.replace("youngs_modulus = 1000.0", "youngs_modulus = -1000.0")
    _run_bad(tmp_path, capsys, text, "soil.youngs_modulus", ("out of range", "allowed"))


@pytest.mark.parametrize("nu", ["0.5", "0.7"])
def test_poisson_ratio_at_or_above_half(tmp_path, capsys, column_text, nu):
    text = column_text.replace("poisson_ratio = 0.33", f"poisson_ratio = {nu}")
    _run_bad(tmp_path, capsys, text, "soil.poisson_ratio", ("out of range", "0.5)"))


def test_polygon_outside_grid(tmp_path, capsys, column_text):
    text = column_text.replace("[0.25, 5.0], [0.0, 5.0]]", "[0.25, 9.0], [0.0, 9.0]]")
    _run_bad(tmp_path, capsys, text, "polygon", ("outside the grid",))


def test_not_toml(tmp_path, capsys):
    _run_bad(tmp_path, capsys, "this is = not [valid toml\n", "[]", ("not valid TOML",))


def test_binary_garbage(tmp_path, capsys):
    _run_bad(tmp_path, capsys, b"\xff\xfe\x00garbage", "[]", ("not valid TOML",))


def test_missing_file(tmp_path, capsys):
    _run_bad(tmp_path, capsys, None, "[]", ("file not found",), name="nowhere.toml", write=False)


def test_wrong_type_and_choice(tmp_path, capsys, column_text):
    text = column_text.replace('model = "linear_elastic"', 'model = "mohr_coulomb"')
    _run_bad(tmp_path, capsys, text, "soil.model", ("'linear_elastic'", "'von_mises_softening'"))


def test_residual_above_peak_rejected(tmp_path, capsys, column_text):
    """cohesion_residual > cohesion_peak is physically meaningless for softening."""
    text = column_text.replace('model = "linear_elastic"', 'model = "von_mises_softening"\n'
                               'cohesion_peak = 20.0\ncohesion_residual = 30.0')
    _run_bad(tmp_path, capsys, text, "cohesion_residual", ("exceeds cohesion_peak",))


def test_scene_to_dict_round_trips_through_json_with_infinities(meshes):
    """scene_from_dict(scene_to_dict(s)) == s for every shipped scene, through JSON (as
    summary.json stores it): infinite values (no strength, damping for ever, e.g.
    ``cohesion_peak = inf`` of an elastic soil) are written as "inf" and read back as
    floats; a string "inf" where a string belongs stays a string."""
    scenes = sorted(meshes.glob("*.toml"))
    assert scenes
    n_inf = 0
    for path in scenes:
        s = load_scene(path)
        d = json.loads(json.dumps(scene_to_dict(s), allow_nan=False))
        n_inf += json.dumps(d).count('"inf"')
        assert scene_from_dict(d, s.source) == s, path.name
    assert n_inf > 0                      # the infinities were exercised
    s = with_value(load_scene(meshes / "column.toml"), "scene.name", "inf")
    assert scene_from_dict(scene_to_dict(s), s.source).scene.name == "inf"
    with pytest.raises(SceneError, match="solver.t_end.*finite"):
        with_value(s, "solver.t_end", "inf")


def test_with_value_returns_validated_copy(meshes):
    """Driver scripts change one value; the original scene is untouched (frozen)."""
    s = load_scene(meshes / "column.toml")
    s2 = with_value(s, "soil.youngs_modulus", 2000.0)
    assert s.soils[0].youngs_modulus == 1000.0 and s2.soils[0].youngs_modulus == 2000.0
    assert math.isclose(s2.soils[0].constrained_modulus, 2 * s.soils[0].constrained_modulus)
    with pytest.raises(SceneError, match="solver.cfl"):
        with_value(s, "solver.cfl", -1.0)


def _union_area(polygons, holes, lo, hi, step):
    """Area (m2) of the union of ``polygons`` minus ``holes``, by counting the centres of a
    fine lattice of squares of side ``step`` (error <= perimeter x step / 2)."""
    import numpy as np

    from fem_rmpm.discretise.grid import points_in_polygon
    xs = np.arange(lo[0] + step / 2, hi[0], step)
    ys = np.arange(lo[1] + step / 2, hi[1], step)
    X, Y = np.meshgrid(xs, ys)
    pts = np.stack([X.ravel(), Y.ravel()], axis=1)
    inside = np.zeros(len(pts), dtype=bool)
    for poly in polygons:
        inside |= points_in_polygon(pts, np.array(poly))
    for poly in holes:
        inside &= ~points_in_polygon(pts, np.array(poly))
    return inside.sum() * step * step


def _perimeter(poly):
    import numpy as np
    p = np.array(poly, dtype=float)
    return float(np.linalg.norm(np.roll(p, -1, axis=0) - p, axis=1).sum())


def test_shipped_scenes_load_and_seed_their_soil(meshes):
    """Every scene file in meshes/ parses, validates and seeds the soil it describes: the
    material points inside the grid, their initial volume the soil area (the union of the
    soil polygons less bedrock; a cell belongs to the soil when its centre does, so the
    two differ by at most half a cell along the boundary: perimeter x h / 2, plus the
    h / 8 of the quarter-cell lattice that measures the area; achieves 0 on the
    rectangles and 2.4 % of that bound on the slopes, asserts 10 %), and the
    embedded default is byte-identical to meshes/slope_reference.toml
    (docs/guide/commands.md)."""
    import numpy as np

    from fem_rmpm import api
    from fem_rmpm.cli import default_scene_path
    files = sorted(meshes.glob("*.toml"))
    assert len(files) >= 7
    for f in files:
        scene = load_scene(f)
        if scene.grid.dimension == 3:      # volumes, not areas: tests/test_3d_scene.py
            continue
        grid, pts = api.prepare(scene)
        assert np.all(pts.x0 >= grid.origin) and np.all(pts.x0 <= grid.upper), f.name
        polys = [so.polygon for so in scene.soils]
        h = float(np.max(grid.cell))
        area = _union_area(polys, [b.polygon for b in scene.bedrock], grid.origin, grid.upper,
                           h / 4)
        band = sum(_perimeter(q) for q in polys) * (h / 2 + h / 8)        # + lattice error
        assert abs(pts.volume0.sum() - area) <= 0.1 * band, (f.name, pts.volume0.sum(), area, band)
    assert default_scene_path().read_bytes() == (meshes / "slope_reference.toml").read_bytes()


def test_set_option_changes_scene_and_rejects_bad_values(tmp_path, capsys, meshes):
    """`--set KEY=VALUE` applies a validated change (TOML literal, bare words are strings);
    a bad key or value is a one-line error, exit 2, no output directory."""
    out = tmp_path / "fem"
    code = main(["fem", str(meshes / "column.toml"), "--out", str(out),
                 "--set", "soil.youngs_modulus=2000", "--set", "scene.name=stiff"])
    assert code == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["scene"]["soil"][0]["youngs_modulus"] == 2000.0
    assert summary["scene"]["scene"]["name"] == "stiff"
    # half the compliance: the top settlement halves (closed form u ~ 1/M)
    assert abs(summary["max_displacement"] - 0.16873 / 2) < 1e-4
    for bad, word in (("soil.youngs_modulus=-5", "youngs_modulus"), ("solver.cfll=1", "cfll"),
                      ("novalue", "KEY=VALUE")):
        bad_out = tmp_path / "bad"
        code = main(["fem", str(meshes / "column.toml"), "--out", str(bad_out), "--set", bad])
        err = capsys.readouterr().err.strip()
        assert code == 2 and len(err.splitlines()) == 1 and word in err, err
        assert not bad_out.exists()
