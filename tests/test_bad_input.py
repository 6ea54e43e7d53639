"""Bad input everywhere: one test per bad input.

Each case runs the real command line (``fem_rmpm.cli.main``) and checks exit code 2,
exactly one line on stderr naming the option or file and what is allowed, no
traceback, and that the output path was neither created nor changed.
"""
from __future__ import annotations

import os

import pytest

from fem_rmpm.cli import main
from fem_rmpm.scene import load_scene, polygon_problem

SLOPE_POLY = "[[0.0, 0.0], [61.0, 0.0], [56.0, 5.0], [6.0, 5.0], [0.0, 2.81614]]"


def _snapshot(path):
    if not path.exists():
        return None
    if path.is_file():
        return ("file", path.read_bytes())
    return {p.name: p.stat().st_mtime_ns for p in path.iterdir()}


def _bad(capsys, argv, out, *words):
    before = _snapshot(out)
    code = main(argv)
    err = capsys.readouterr().err.strip()
    assert code == 2, err
    assert len(err.splitlines()) == 1, err
    assert "Traceback" not in err
    for w in words:
        assert w in err, err
    assert _snapshot(out) == before
    return err


@pytest.fixture
def out(tmp_path):
    return tmp_path / "out"


def _column(meshes, out, *extra):
    return ["run", str(meshes / "column.toml"), "--out", str(out), "--quiet", *extra]


def test_soil_index_out_of_range(capsys, meshes, out):
    err = _bad(capsys, _column(meshes, out, "--set", "soil[5].cohesion_peak=1"), out,
               "soil[5].cohesion_peak", "has 1", "soil[i].KEY with i = 0")
    assert "column.toml" in err


def test_soil_index_not_a_number(capsys, meshes, out):
    _bad(capsys, _column(meshes, out, "--set", "soil[x].cohesion_peak=1"), out,
         "soil[x].cohesion_peak", "'x'", "allowed")


def test_soil_index_negative(capsys, meshes, out):
    _bad(capsys, _column(meshes, out, "--set", "soil[-1].youngs_modulus=5"), out,
         "soil[-1]", "allowed")


def test_soil_index_malformed(capsys, meshes, out):
    _bad(capsys, _column(meshes, out, "--set", "soil[0.youngs_modulus=5"), out,
         "soil[0", "allowed")


def test_table_the_scene_has_not(capsys, meshes, out):
    _bad(capsys, _column(meshes, out, "--set", "bedrock[0].polygon=[[0,0],[1,0],[1,1]]"), out,
         "bedrock[0]", "no [[bedrock]]")


def test_negative_seed(capsys, meshes, out):
    _bad(capsys, _column(meshes, out, "--seed", "-1"), out, "--seed -1", "[0, 2^63 - 1]")


@pytest.mark.parametrize("command", ["run", "fem"])
def test_out_is_a_file(capsys, meshes, out, command):
    out.write_text("not a directory")
    _bad(capsys, [command, str(meshes / "column.toml"), "--out", str(out)]
         + (["--quiet"] if command == "run" else []), out, "is a file", str(out))


def test_bow_tie_soil_polygon(capsys, meshes, out):
    bow = "[[0.0, 0.0], [61.0, 5.0], [61.0, 0.0], [0.0, 5.0]]"
    _bad(capsys, ["run", "--out", str(out), "--quiet", "--set", f"soil.polygon={bow}"], out,
         "soil[0].polygon", "self-intersecting", "bow-tie", "allowed: a simple polygon")


def test_degenerate_collinear_polygon(capsys, meshes, out):
    line = "[[0.0, 0.0], [10.0, 1.0], [20.0, 2.0]]"
    _bad(capsys, ["run", "--out", str(out), "--quiet", "--set", f"soil.polygon={line}"], out,
         "soil[0].polygon", "zero area")


def test_repeated_point_polygon(capsys, meshes, out):
    rep = "[[0.0, 0.0], [61.0, 0.0], [61.0, 0.0], [6.0, 5.0]]"
    _bad(capsys, ["run", "--out", str(out), "--quiet", "--set", f"soil.polygon={rep}"], out,
         "soil[0].polygon", "repeats the point before it")


def test_bow_tie_bedrock_polygon(tmp_path, capsys, meshes, out):
    text = (meshes / "slope_reference.toml").read_text().replace(
        "[[61.0, 0.0], [120.0, 0.0], [120.0, 42.8683], [107.9846, 17.1010]]",
        "[[61.0, 0.0], [120.0, 0.0], [61.0, 10.0], [120.0, 42.8683]]")
    scene = tmp_path / "bow_rock.toml"
    scene.write_text(text)
    _bad(capsys, ["run", str(scene), "--out", str(out), "--quiet", "--set", "solver.t_end=0.01"],
         out, str(scene), "bedrock[0].polygon", "self-intersecting")


def test_negative_poisson_ratio_refused(tmp_path, capsys, column_text, out):
    scene = tmp_path / "auxetic.toml"
    scene.write_text(column_text.replace("poisson_ratio = 0.33", "poisson_ratio = -0.9"))
    _bad(capsys, ["run", str(scene), "--out", str(out), "--quiet"], out,
         str(scene), "soil.poisson_ratio", "-0.9", "[0, 0.5)")


def test_run_into_a_directory_holding_a_run(capsys, meshes, out):
    out.mkdir()
    (out / "particles.pvd").write_text("<VTKFile/>")
    _bad(capsys, _column(meshes, out), out, "holds another run", "--force")


def test_run_into_a_non_empty_directory(capsys, meshes, out):
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    _bad(capsys, _column(meshes, out), out, "is not empty", "notes.txt")


def test_utf8_bom_is_accepted(tmp_path, column_text):
    """A scene saved with a UTF-8 byte-order mark (Windows editors) loads like without."""
    plain, bom = tmp_path / "plain.toml", tmp_path / "bom.toml"
    plain.write_text(column_text, encoding="utf-8")
    bom.write_bytes(b"\xef\xbb\xbf" + column_text.encode("utf-8"))
    a, b = load_scene(plain), load_scene(bom)
    assert a.soils == b.soils and a.grid == b.grid and a.solver == b.solver


@pytest.mark.parametrize("poly, problem", [
    ([(0, 0), (1, 0), (1, 1), (0, 1)], None),
    ([(0, 0), (1, 0), (1, 1), (0, 1), (0, 0)], None),              # explicitly closed
    ([(0, 0), (2, 0), (2, 2), (1, 0.0), (0, 2)], "self-intersecting"),   # touches an edge
    ([(0, 0), (1, 1), (1, 0), (0, 1)], "self-intersecting"),
    ([(0, 0), (1, 0), (2, 0)], "zero area"),
])
def test_polygon_problem(poly, problem):
    got = polygon_problem(poly)
    assert (got is None) if problem is None else (problem in got)


@pytest.mark.parametrize("csv, words", [
    (None, ("not found",)),                                    # missing file
    ("a,b,c\n1,2,3\n", ("x",)),                                # missing columns
    ("x,y,value\n1.0,2.0,abc\n", ("abc",)),                    # not a number
    ("x,y,value\n", ("no data rows",)),                        # no rows
])
def test_field_data_errors_leave_no_directory(tmp_path, capsys, out, csv, words):
    data = tmp_path / "cpt.csv"
    if csv is not None:
        data.write_text(csv)
    err = _bad(capsys, ["field", "--seed", "1", "--out", str(out), "--data", str(data)], out,
               str(data), *words)
    assert not out.exists(), err


def test_field_fit_error_leaves_no_directory(tmp_path, capsys, out):
    data = tmp_path / "fit.csv"
    data.write_text("x,y\n1,2\n")
    _bad(capsys, ["field", "--out", str(out), "--fit", str(data)], out, str(data))


def test_field_negative_seed(capsys, out):
    _bad(capsys, ["field", "--seed", "-3", "--out", str(out)], out, "--seed -3", "allowed")


def test_field_out_is_a_file(capsys, out):
    out.write_text("x")
    _bad(capsys, ["field", "--out", str(out)], out, "is a file")
