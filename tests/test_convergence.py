"""Mesh convergence as a campaign feature (fem_rmpm.campaign.convergence, ``fem-rmpm
converge``): the exact McNemar test, the paired statistics from the meshes' results.csv,
the command on the tiny slope, and its refusal of bad input."""
from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest
from scipy import stats

from fem_rmpm.campaign.convergence import (
    convergence_statistics,
    mcnemar_exact,
    mesh_directory,
    parse_cells,
)
from fem_rmpm.campaign.convergence_report import convergence_text
from fem_rmpm.cli import main

ROOT = Path(__file__).resolve().parents[1]
TINY = ROOT / "tests" / "data" / "mc_tiny.toml"


@pytest.mark.parametrize("b, c", [(0, 0), (3, 0), (7, 2), (5, 5), (1, 12), (30, 18)])
def test_mcnemar_exact_is_the_two_sided_binomial_test(b, c):
    """Against scipy.stats.binomtest(b, b + c, 1/2), two-sided (an independent code)."""
    ref = 1.0 if b + c == 0 else stats.binomtest(b, b + c, 0.5).pvalue
    assert mcnemar_exact(b, c) == pytest.approx(ref, rel=1e-9)


def _write(d: Path, rows: list[tuple]) -> None:
    d.mkdir(parents=True)
    with open(d / "results.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["case", "index", "seed", "status", "stop_reason", "failed", "sliding_area",
                    "runout_distance", "retrogression_distance"])
        for case, i, failed, area in rows:
            w.writerow([case, i, 100 + i, "ok", "at rest", int(failed), area, area / 10,
                        area / 20])
    (d / "summary.json").write_text(json.dumps({"runs_to_rest": None}))


def test_paired_statistics_count_by_hand(tmp_path):
    """Two meshes, one case, 6 realizations: fail on coarse only {1, 2}, on fine only {5};
    P(failure) 3/6 and 2/6; paired difference (2 - 1)/6 with SE sqrt(3 - 1/6)/6; given-
    failure mean sliding area over the failures of each mesh."""
    coarse = [("xi12", i, f, a) for i, f, a in
              [(0, 1, 10.0), (1, 1, 20.0), (2, 1, 30.0), (3, 0, 0.0), (4, 0, 0.0), (5, 0, 0.0)]]
    fine = [("xi12", i, f, a) for i, f, a in
            [(0, 1, 12.0), (1, 0, 0.0), (2, 0, 0.0), (3, 0, 0.0), (4, 0, 0.0), (5, 1, 40.0)]]
    _write(mesh_directory(tmp_path, 0.5), coarse)
    _write(mesh_directory(tmp_path, 0.25), fine)
    st = convergence_statistics(tmp_path, [0.5, 0.25])
    c = st["cases"][0]
    assert [m["failures"] for m in c["meshes"]] == [3, 2]
    assert c["meshes"][0]["given_failure"]["sliding_area"]["mean"] == pytest.approx(20.0)
    assert c["meshes"][1]["given_failure"]["sliding_area"]["mean"] == pytest.approx(26.0)
    p = c["pairs"][0]
    assert (p["n_paired"], p["fail_first_only"], p["fail_second_only"]) == (6, 2, 1)
    assert p["discordant_indices"] == {"fail_first_only": [1, 2], "fail_second_only": [5]}
    assert p["paired_difference"] == pytest.approx(1 / 6)
    assert p["paired_se"] == pytest.approx((3 - 1 / 6) ** 0.5 / 6)
    assert p["mcnemar_p"] == pytest.approx(1.0)
    assert "3 discordant of 6 (2/1)" in convergence_text(st)


@pytest.mark.parametrize("text", ["0.5", "0.5,0.5", "0.5,-1", "a,b", "1,0.5,0.25,0.125"])
def test_bad_cells_are_refused_in_one_line(tmp_path, capsys, text):
    out = tmp_path / "cv"
    assert main(["converge", str(TINY), "--cells", text, "-n", "2", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--cells" in err[0] and "Traceback" not in err[0]
    assert not out.exists()
    with pytest.raises(Exception):
        parse_cells(text)


def test_converge_command_on_the_tiny_slope(tmp_path, capsys, dask_scheduler):
    """Two meshes (1.0 and 0.5 m) of the tiny slope with the field's box, N = 4: one
    campaign per mesh, the same seeds on both, convergence.json/.png/.html; a second run
    computes nothing (resumable)."""
    out = tmp_path / "cv"
    args = ["converge", str(TINY), "--cells", "1.0,0.5", "-n", "4", "--out", str(out),
            "--set", "random_field.box=[0.0, 0.0, 6.0, 2.0]",
            "--set", "random_field.cell_size=0.5", "--scheduler", dask_scheduler, "--quiet"]
    assert main(args) == 0
    st = json.loads((out / "convergence.json").read_text())
    assert st["paired_fields"] and st["cells"] == [1.0, 0.5]
    assert [m["n"] for m in st["cases"][0]["meshes"]] == [4, 4]
    assert st["cases"][0]["pairs"][0]["n_paired"] == 4
    seeds = [{r["seed"] for r in csv.DictReader(open(mesh_directory(out, h) / "results.csv"))}
             for h in (1.0, 0.5)]
    assert seeds[0] == seeds[1] and len(seeds[0]) == 4
    for f in ("convergence.png", "convergence.html", "cell_1/report.html",
              "cell_0.5/report.html"):
        assert (out / f).is_file(), f
    assert "McNemar" in (out / "convergence.html").read_text()
    capsys.readouterr()
    assert main(args) == 0
    assert "P(failure)" in capsys.readouterr().out
