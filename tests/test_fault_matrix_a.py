"""New-user mistakes and numerical failures that once gave a wrong answer, lost data or a
traceback: each is now refused or reported in the code's own error path, as one line on
stderr with the exit code of the command-line contract (2 bad input, 3 the simulation
failed), no traceback, and nothing written, changed or left behind.
"""
from __future__ import annotations

import json
from pathlib import Path

import pytest

from fem_rmpm.cli import main
from fem_rmpm.schemes.common import SimulationError
from fem_rmpm.schemes.explicit.loop import _check_jump
from fem_rmpm.schemes.implicit import strength_reduction
from fem_rmpm.schemes.implicit.linear import LinearSolveError, LinearSolver

ROOT = Path(__file__).resolve().parents[1]
MESHES = ROOT / "meshes"
TINY = ROOT / "tests" / "data" / "mc_tiny.toml"
COLUMN = MESHES / "column.toml"


def _one_line(capsys, *words: str) -> str:
    """The single stderr line of a refused command, holding every one of ``words``."""
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err, err
    for w in words:
        assert w in lines[0], (w, lines[0])
    return lines[0]


def _tree(path: Path) -> dict:
    return {str(p.relative_to(path)): p.read_bytes() for p in sorted(path.rglob("*"))
            if p.is_file()}


# ------------------------------------------------------------------ numerical failure in FS
@pytest.mark.parametrize("failure, named", [
    ("SuperLU: Factor is exactly singular", "linear solve singular at F = 1"),
    ("SuperLU returned a non-finite solution (singular tangent)",
     "linear solve non-finite at F = 1")])
def test_a_singular_or_non_finite_solve_in_a_trial_is_numerical(tmp_path, capsys, monkeypatch,
                                                                 failure, named):
    """A trial whose linear solve fails (a singular tangent, or a non-finite solution) is
    no slope failure: ``fs`` exits 3 naming the numerical cause and the trial F, never
    "FS < 0.1" with exit 0 (the free-ended drained infinite slope did that at every trial
    F: the solver's SuperLU error stood in for a collapse).  The elastic probe is skipped
    here: every solve fails, from the first trial (F = 1) on."""
    monkeypatch.setattr(strength_reduction, "_probe", lambda *a: None)

    def solve(self, K, b, modes=None, rtol=1e-10):
        raise LinearSolveError(failure)
    monkeypatch.setattr(LinearSolver, "solve", solve)
    out = tmp_path / "fs"
    rc = main(["fs", str(MESHES / "infinite_slope.toml"), "--out", str(out), "--quiet",
               "--set", "grid.cell=[2.165064, 0.4330127]"])
    assert rc == 3
    line = _one_line(capsys, named, "not a slope failure", "FS not determined")
    assert "FS <" not in line and not out.exists()


def test_numerical_failure_is_raised_not_taken_as_fs(monkeypatch):
    """The same through the Python API: :class:`NonPhysicalFailure` with the cause."""
    from fem_rmpm import api
    monkeypatch.setattr(strength_reduction, "_probe", lambda *a: None)

    def singular(self, K, b, modes=None, rtol=1e-10):
        raise LinearSolveError("SuperLU: Factor is exactly singular")
    monkeypatch.setattr(LinearSolver, "solve", singular)
    scene = api.with_value(api.load_scene(MESHES / "infinite_slope.toml"), "grid.cell",
                           [2.165064, 0.4330127])
    with pytest.raises(strength_reduction.NonPhysicalFailure) as ei:
        api.factor_of_safety(scene)
    assert "linear solve failed" in ei.value.cause
    assert ei.value.result is not None and ei.value.result.trials[0].F == 1.0


# ------------------------------------------------------------------ --out of fem, fs, field
def _finished_run(path: Path) -> dict:
    """A directory as ``fem-rmpm run`` leaves it (its summary and a VTK file)."""
    path.mkdir()
    (path / "summary.json").write_text(json.dumps({"scheme": "explicit", "status": "ok"}))
    (path / "particles.pvd").write_text("<VTKFile/>")
    return _tree(path)


@pytest.mark.parametrize("argv", [
    ["fem", str(COLUMN)],
    ["fs", str(MESHES / "infinite_slope.toml")],
    ["field", str(TINY), "--seed", "1"]])
def test_fem_fs_field_refuse_a_finished_run_without_force(tmp_path, capsys, argv):
    """Every command writing into ``--out`` follows ``run``'s rule: a directory holding
    another result is refused (exit 2) and left exactly as it was."""
    out = tmp_path / "prev"
    before = _finished_run(out)
    assert main(argv + ["--out", str(out)]) == 2
    _one_line(capsys, "--out", "holds another run", "--force")
    assert _tree(out) == before


def test_fem_with_force_replaces_the_run(tmp_path, capsys):
    """With ``--force`` the run's files go and the FEM result with its own summary
    takes their place (no VTK of the run beside a summary that does not describe it)."""
    out = tmp_path / "prev"
    _finished_run(out)
    assert main(["fem", str(COLUMN), "--out", str(out), "--force"]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["fem.vtu", "summary.json"]
    s = json.loads((out / "summary.json").read_text())
    assert (s["scheme"], s["status"], s["files"]) == ("fem", "ok", ["fem.vtu"])


@pytest.mark.parametrize("argv", [["fem", str(COLUMN), "--out", ""],
                                  ["mc", str(TINY), "--out", "x", "--case", ""]])
def test_empty_out_or_case_is_refused(tmp_path, capsys, monkeypatch, argv):
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 2
    _one_line(capsys, "allowed")
    assert list(tmp_path.iterdir()) == []


# ------------------------------------------------------------------ overlaps and contradictions
_TWO_SOILS = """
[scene]
name = "two"
[grid]
origin = [0.0, 0.0]
size = [4.0, 2.0]
cell = 0.5
[boundary]
left = "roller"
right = "roller"
bottom = "fixed"
top = "free"
[[soil]]
name = "clay"
polygon = [[0.0, 0.0], [2.0, 0.0], [2.0, 1.0], [0.0, 1.0]]
unit_weight = 20.0
youngs_modulus = 1000.0
poisson_ratio = 0.3
[[soil]]
name = "sand"
polygon = POLY
unit_weight = 18.0
youngs_modulus = 2000.0
poisson_ratio = 0.3
"""


def test_overlapping_soils_are_refused(tmp_path, capsys):
    """Two soils sharing area: exit 2 naming both and a point of the overlap (the later
    soil used to take the shared cells silently)."""
    path = tmp_path / "two.toml"
    path.write_text(_TWO_SOILS.replace("POLY", "[[1.5, 0.5], [3.0, 0.5], [3.0, 1.5], "
                                               "[1.5, 1.5]]"))
    out = tmp_path / "out"
    assert main(["fem", str(path), "--out", str(out)]) == 2
    line = _one_line(capsys, "soil[1].polygon", "'clay'", "'sand'", "overlap")
    x, y = (float(v) for v in line.split("e.g. at (")[1].split(")")[0].split(","))
    assert 1.5 < x < 2.0 and 0.5 < y < 1.0                  # inside both
    assert not out.exists()


@pytest.mark.parametrize("poly", ["[[2.0, 0.0], [4.0, 0.0], [4.0, 1.0], [2.0, 1.0]]",  # edge
                                  "[[2.0, 1.0], [4.0, 1.0], [4.0, 2.0], [2.0, 2.0]]",  # corner
                                  "[[0.0, 1.0], [2.0, 1.0], [1.0, 2.0]]"])             # edge
def test_touching_soils_are_accepted(tmp_path, poly):
    from fem_rmpm.scene import load_scene
    path = tmp_path / "two.toml"
    path.write_text(_TWO_SOILS.replace("POLY", poly))
    assert len(load_scene(path).soils) == 2


def test_two_values_at_one_data_point_are_refused(tmp_path, capsys):
    """Kriging is exact at the data points: two different values at one point contradict
    each other and are refused naming the point and both values (they were averaged)."""
    data = tmp_path / "cpt.csv"
    data.write_text("x,y,value\n1.0,1.0,6.0\n2.0,0.5,7.0\n1.0,1.0,9.5\n")
    out = tmp_path / "field"
    assert main(["field", str(TINY), "--seed", "1", "--out", str(out), "--data",
                 str(data)]) == 2
    _one_line(capsys, "rows 2 and 4", "(1, 1) m", "6 and 9.5")
    assert not out.exists()


# ------------------------------------------------------------------ mc --fs, runs stopped once decided
def test_fs_campaign_with_runs_stopped_once_decided_finishes(tmp_path, capsys, dask_scheduler):
    """``mc --fs`` with ``runs_to_rest = 0``: a run stopped once decided has no measures
    to rest (no displacement), and the FS statistics and figure do not need them (it
    ended in a TypeError after writing its records)."""
    out = tmp_path / "mc"
    rc = main(["mc", str(TINY), "-n", "4", "--fs", "--set", "montecarlo.runs_to_rest=0",
               "--out", str(out), "--scheduler", dask_scheduler, "--quiet"])
    err = capsys.readouterr().err
    assert rc == 0 and "Traceback" not in err, err
    records = [json.loads(p.read_text()) for p in (out / "records").rglob("*.json")]
    assert len(records) == 4
    assert any(r["measures"].get("max_displacement") is None for r in records)  # decided
    summary = json.loads((out / "summary.json").read_text())
    assert summary["cases"][0]["fs"]["n"] == 4
    for f in ("factor_of_safety.png", "report.html"):
        assert (out / f).is_file()


# ------------------------------------------------------------------ minor
@pytest.mark.parametrize("setting, words", [
    ("solver.cfl=5", ("solver.cfl", "(0, 3]")),
    ("grid.origin=[nan, 0]", ("grid.origin", "finite")),
    ("grid.origin=[-inf, 0]", ("grid.origin", "finite")),
    ("soil.model=mohr_coulomb_softening", ("soil.cohesion_peak", "missing required key",
                                           "mohr_coulomb_softening"))])
def test_bad_setting_is_refused_naming_its_key(tmp_path, capsys, setting, words):
    out = tmp_path / "out"
    assert main(["fem", str(COLUMN), "--out", str(out), "--set", setting]) == 2
    line = _one_line(capsys, *words)
    assert "got inf" not in line and not out.exists()


def test_the_instability_message_states_the_allowed_cfl():
    """The message of an unstable explicit step and the range of ``solver.cfl`` agree."""
    with pytest.raises(SimulationError, match=r"reduce \[solver\] cfl \(now 2\.5.*"
                                              r"allowed \(0, 3\].*1\.08 to 1\.65"):
        _check_jump(1.0, 0.5, 10, 0.1, 2.5)


@pytest.mark.parametrize("summary, words", [
    ({"scene": {"scene": {"name": "column"}}, "scheme": "explicit", "status": "ok"},
     ("a run directory", "not a campaign")),
    ({}, ("no campaign results",))])
def test_report_refuses_what_is_not_a_campaign(tmp_path, capsys, summary, words):
    (tmp_path / "summary.json").write_text(json.dumps(summary))
    before = _tree(tmp_path)
    assert main(["report", str(tmp_path)]) == 2
    _one_line(capsys, *words)
    assert _tree(tmp_path) == before
