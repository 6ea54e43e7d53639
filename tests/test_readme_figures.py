"""The documented figures, recomputed: each slow test runs the validation script or run that
produced a number of the documentation (docs/guide, docs/validation), into a temporary
directory (never validation/out, whose files may be stale), reads the number from the page
itself and asserts the fresh result rounds to it.  So the documentation cannot drift from
the code: change one and the test fails until the other follows.  All are marked slow
(minutes each; `python -m pytest -m slow tests/test_readme_figures.py`); each has its own
pytest timeout (the default 600 s of pyproject.toml is for default tests).
"""
from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
CHOOSING = "guide/choosing.md"
FOOTING = "validation/footing.md"
REFERENCE_SLOPE = "validation/reference_slope.md"


def doc_numbers(page: str, pattern: str) -> list[str]:
    """The groups of the first line of ``docs/<page>`` matching ``pattern`` (a regex), as
    written."""
    m = re.search(pattern, (DOCS / page).read_text(encoding="utf-8"), re.MULTILINE)
    assert m, f"docs/{page} no longer has a line matching {pattern!r}"
    return list(m.groups())


def rounds_to(value: float, written: str) -> bool:
    """``value`` rounds to the page's ``written`` (its decimals; +-half a unit)."""
    decimals = len(written.split(".")[1]) if "." in written else 0
    return abs(value - float(written)) <= 0.5 * 10.0 ** -decimals + 1e-12


def _script(name: str, *args: str, timeout: float) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    r = subprocess.run([sys.executable, str(ROOT / "validation" / name), *args], cwd=ROOT,
                       env=env, capture_output=True, text=True, timeout=timeout)
    assert r.returncode == 0, r.stderr[-3000:]
    return r



@pytest.mark.slow
@pytest.mark.timeout(4 * 3600)     # the suite's 600 s is for default tests
def test_footing_table_and_richardson_match_docs(tmp_path):
    """docs/validation/footing.md against Prandtl's 2 + pi: q/c at 3 % of B for h = B/8 ..
    B/64 with and without F-bar, and "Richardson extrapolation of the F-bar values gives
    5.137" (validation/footing.py, full: about 10 minutes on a shared core)."""
    _script("footing.py", "--out", str(tmp_path), timeout=4 * 3600)
    res = json.loads((tmp_path / "footing.json").read_text())
    assert (tmp_path / "footing.png").stat().st_size > 10_000
    (rich,) = doc_numbers(FOOTING, r"Richardson extrapolation of the F-bar values gives ([\d.]+)")
    assert rounds_to(res["richardson"]["q_over_c"], rich), (res["richardson"], rich)
    num = r"([\d.]+)[^|]*"
    with_fbar = doc_numbers(FOOTING, rf"^\s*\| with F-bar \| {num}\| {num}\| {num}\| {num}\|")
    without = doc_numbers(FOOTING, rf"^\s*\| without \(locking\) \| {num}\| {num}\| {num}\| {num}\|")
    for fbar, written in ((True, with_fbar), (False, without)):
        runs = sorted((r for r in res["runs"] if r["fbar"] == fbar and r["kind"] == "geostatic"
                       and r["components"] == "xy" and r["domain"] == [3.0, 2.0]),
                      key=lambda r: -r["h_over_B"])
        assert len(runs) == 4
        for r, w in zip(runs, written):
            assert rounds_to(r["q_end"], w), (fbar, r["h_over_B"], r["q_end"], w)


@pytest.mark.slow
@pytest.mark.timeout(3 * 3600)     # the suite's 600 s is for default tests
def test_cfl_limits_match_docs(tmp_path):
    """docs/guide/choosing.md, explicit stability: the bisected cfl limits of the column
    (large deformation undamped 1.08, damped 1.35; linear MUSL 1.65) and the spectral radius
    of the linearised step predicting the linear limit within 1 %
    (validation/stability_map.py --only cfl)."""
    _script("stability_map.py", "--only", "cfl", "--out", str(tmp_path), timeout=3 * 3600)
    res = json.loads((tmp_path / "stability_map.json").read_text())["cfl"]
    assert (tmp_path / "stability_cfl.png").stat().st_size > 10_000
    limit = {c["case"]: c["limit"] for c in res["cases"]}
    (undamped,) = doc_numbers(CHOOSING, r"column, large deformation, undamped \| ([\d.]+)")
    (damped,) = doc_numbers(CHOOSING, r"column, large deformation, damped \| ([\d.]+)")
    (linear,) = doc_numbers(CHOOSING, r"column, linear MUSL \| ([\d.]+)")
    tol = 0.005 + 0.005                     # the bisection's tolerance + the page's rounding
    assert abs(limit["column, large deformation, undamped"] - float(undamped)) <= tol
    assert abs(limit["column, large deformation, damping 0.7"] - float(damped)) <= tol
    lin = limit["column, linear (geostatic), undamped"]
    assert abs(lin - float(linear)) <= tol
    assert abs(res["spectral"]["FLIP"] / lin - 1) < 0.01


@pytest.mark.slow
@pytest.mark.timeout(6 * 3600)     # the suite's 600 s is for default tests
def test_four_literature_cases_match_docs(tmp_path):
    """docs/validation/reference_slope.md, "The four literature cases" (Wang, Vardon &
    Hicks 2017; validation/montecarlo_cases.py with its documented N, into a temporary
    directory): P(failure) = 1 in every case and the intact blocks at 3 s per case (mean,
    and SE where the page gives one) as the page's table writes them."""
    out = tmp_path / "cases"
    _script("montecarlo_cases.py", "--out", str(out), "--quiet", timeout=6 * 3600)
    summary = json.loads((out / "summary.json").read_text())
    cases = {c["name"]: c for c in summary["cases"]}
    assert list(cases) == ["homogeneous", "xi1", "xi12", "xi48"]
    for c in cases.values():
        assert c["finished"] == c["realizations"] and c["p_failure"] == 1.0
    (homog,) = doc_numbers(REFERENCE_SLOPE, r"^\| homogeneous \| ([\d.]+) \|")
    assert rounds_to(cases["homogeneous"]["intact_blocks"]["mean"], homog)
    for name, label in (("xi1", "1"), ("xi12", "12"), ("xi48", "48")):
        mean, se = doc_numbers(REFERENCE_SLOPE, rf"^\| xi = {label} \| ([\d.]+) ± ([\d.]+) \|")
        s = cases[name]["intact_blocks"]
        assert rounds_to(s["mean"], mean) and rounds_to(s["se"], se), (name, s, mean, se)


# the homogeneous rows (case (i)) of the implicit-against-explicit table of
# docs/validation/reference_slope.md
_SCHEME_ROWS = {"runout_distance": r"^\| homogeneous \| run-out \(m\) \| ([\d.]+) \| ([\d.]+) \|",
                "retrogression_distance":
                    r"^\| homogeneous \| retrogression \(m\) \| ([\d.]+) \| ([\d.]+) \|",
                "sliding_area":
                    r"^\| homogeneous \| sliding area \(m2\) \| ([\d.]+) \| ([\d.]+) \|"}


def _reference_slope_measures(out: Path, **settings) -> dict:
    from fem_rmpm import api
    from fem_rmpm.scene import load_scene, with_values
    scene = load_scene(ROOT / "meshes" / "slope_reference.toml")
    return api.run(with_values(scene, settings), out=out).measures


@pytest.mark.slow
@pytest.mark.timeout(3600)     # the suite's 600 s is for default tests
def test_reference_slope_explicit_matches_docs(tmp_path):
    """docs/validation/reference_slope.md: the explicit column of the
    implicit-against-explicit table's homogeneous rows (run-out, retrogression, sliding
    area; the reference is the implicit scheme's column) from a fresh run of
    meshes/slope_reference.toml (about 20 s idle, several minutes under load)."""
    exp = _reference_slope_measures(tmp_path / "exp")
    for key, pattern in _SCHEME_ROWS.items():
        e, _ = doc_numbers(REFERENCE_SLOPE, pattern)
        assert rounds_to(exp[key], e), (key, exp[key], e)


@pytest.mark.slow
@pytest.mark.timeout(4 * 3600)     # the suite's 600 s is for default tests
def test_reference_slope_implicit_matches_docs(tmp_path):
    """docs/validation/reference_slope.md: the implicit column of those rows, from the run
    the page describes (the default adaptive steps, ``--set solver.scheme=implicit --set
    solver.dynamic=true``; about 3 minutes idle)."""
    imp = _reference_slope_measures(tmp_path / "imp", **{"solver.scheme": "implicit",
                                                         "solver.dynamic": True})
    for key, pattern in _SCHEME_ROWS.items():
        _, i = doc_numbers(REFERENCE_SLOPE, pattern)
        assert rounds_to(imp[key], i), (key, imp[key], i)
