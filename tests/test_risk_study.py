"""The risk scene (meshes/slope_risk.toml) and the study's rules (validation/risk_study.py)."""
from __future__ import annotations

import math
from pathlib import Path

import pytest
from validation_module import load

ROOT = Path(__file__).resolve().parents[1]


def _study():
    return load("risk_study")


def _row(index, failed, area=0.0, early=0.0, retro=0.0, runout=0.0, h=0.0):
    return {"case": "xi12", "index": index, "status": "ok", "failed": failed,
            "sliding_area": area, "sliding_area_early": early, "retrogression_distance": retro,
            "runout_distance": runout, "slip_surface_height": h, "intact_blocks": 2,
            "time_to_rest": 40.0, "excluded_frozen_points": 0, "excluded_stray_points": 0}


def test_failure_mode_rule():
    """The documented rule: toe slump when the failure stays within 2 H = 10 m of the
    crest; else translational when at least half the final sliding area moved by the
    mechanism time; else retrogressive; None when the slope stood."""
    s = _study()
    assert s.failure_mode(_row(0, False)) is None
    assert s.failure_mode(_row(0, True, area=30, early=30, retro=10.0)) == "toe slump"
    assert s.failure_mode(_row(0, True, area=200, early=100, retro=10.01)) == "translational"
    assert s.failure_mode(_row(0, True, area=200, early=99.9, retro=40)) == "retrogressive"


def test_case_summary_counts_and_interval():
    """P(failure) = k / N with SE sqrt(p(1-p)/N) and the Wilson interval; measures given
    failure only over the failed rows; modes and 'above the base' counted by the rule."""
    s = _study()
    rows = [_row(0, False), _row(1, True, 200, 150, 40, 30, 0.2),
            _row(2, True, 100, 10, 30, 10, 1.0), _row(3, True, 20, 20, 5, 2, 0.0)]
    out = s.case_summary(rows)
    assert out["n"] == 4 and out["failed"] == 3
    assert out["p_failure"] == 0.75
    assert math.isclose(out["se"], math.sqrt(0.75 * 0.25 / 4))
    lo, hi = out["wilson95"]
    assert lo < 0.75 < hi
    assert out["sliding_area"]["given_failure"]["mean"] == pytest.approx(320 / 3)
    assert out["sliding_area"]["unconditional"]["mean"] == pytest.approx(80.0)
    assert out["modes"] == {"toe slump": 1, "translational": 1, "retrogressive": 1}
    assert out["above_base"] == 1                       # 1.0 m > H / 6 = 0.83 m
    assert s._label("xi12") == "xi = 12" and s._label("homogeneous") == "homogeneous"


def test_homogeneous_risk_slope_stands():
    """meshes/slope_risk.toml without its random field stands (its file says so): the
    geostatic phase comes to rest before geostatic_time, no point moves the failure
    displacement, no point is frozen; the mechanism time is counted from the end of the
    geostatic phase (3 s after it).  About 1 s of CPU."""
    from fem_rmpm import api
    from fem_rmpm.campaign import without_random_field
    from fem_rmpm.scene import load_scene
    scene = without_random_field(load_scene(ROOT / "meshes" / "slope_risk.toml"))
    res = api.run(scene, vtk=False, figures=False)
    geo = res.record.solver
    assert geo["geostatic_at_rest"] and geo["geostatic_end_time"] < scene.solver.geostatic_time
    assert res.record.stop_reason == "at rest"
    assert not res.measures["failed"] and res.measures["max_displacement"] < 0.05
    assert res.measures["excluded_frozen_points"] == 0
    assert res.measures["mechanism_time"] == pytest.approx(3.0 + geo["geostatic_end_time"])


def test_report_shows_the_risk_study(tmp_path):
    """report.html gains a 'Risk study' section from risk_study.json (the study's output:
    P(failure) with its Wilson interval and the mode split per case); none without it; a
    'Mesh check' table when the study has one."""
    from fem_rmpm.campaign.report import report_html
    s = _study()
    rows = [_row(0, False), _row(1, True, 200, 150, 40, 30, 0.2)]
    (tmp_path / "summary.json").write_text('{"scene": "slope_risk", "cases": []}')
    assert "Risk study" not in report_html(tmp_path)
    summary = {"xi12": s.case_summary(rows)}
    import json
    (tmp_path / "risk_study.json").write_text(json.dumps(
        {"rules": {"toe_slump_retrogression_m": 10.0}, "cases": summary,
         "factor_of_safety": {"xi12": None}}))
    page = report_html(tmp_path)
    assert "<h2>Risk study</h2>" in page and "xi12" in page
    assert "0.5 [" in page and "0 / 1 / 0" in page
    assert "Mesh check" not in page
    (tmp_path / "risk_study.json").write_text(json.dumps(
        {"rules": {}, "cases": summary, "mesh_campaign": "runs/fine",
         "mesh_check": {"xi12": s.mesh_summary(rows, [_row(1, True, 150)])}}))
    page = report_html(tmp_path)
    assert "<h3>Mesh check</h3>" in page and "runs/fine" in page
    assert "200 / 150" in page and "50 (1)" in page


def test_mesh_summary_pairs_by_index():
    """The mesh check pairs realizations by index (same random field on both meshes):
    P(failure) on each side over the pairs only, agreement on failed / stood, the mean
    sliding area given failure per side and the mean |difference| where both failed."""
    s = _study()
    coarse = [_row(0, False), _row(1, True, 200), _row(2, True, 100), _row(3, True, 50)]
    fine = [_row(1, True, 180), _row(2, False), _row(3, True, 80), _row(7, True, 999)]
    m = s.mesh_summary(coarse, fine)
    assert m["n"] == 3 and m["agree"] == 2            # indices 1, 2, 3; 2 disagrees
    assert m["coarse"]["p_failure"] == 1.0 and m["fine"]["p_failure"] == pytest.approx(2 / 3)
    assert m["coarse"]["sliding_area_given_failure"]["mean"] == pytest.approx(350 / 3)
    assert m["fine"]["sliding_area_given_failure"]["mean"] == pytest.approx(130.0)
    assert m["both_failed"] == 2 and m["area_abs_difference_mean"] == pytest.approx(25.0)
    assert s.mesh_summary(coarse, []) is None


def test_case_summary_with_runs_stopped_once_decided():
    """With runs_to_rest = K: P(failure) over all N rows (decided ones count as failed),
    the measures over the runs to rest with index < K only (a run to rest above K, e.g. a
    stander of a decided campaign, is left out, so the sample stays iid); n stated; a
    decided-only campaign is compared with the runs to rest pair by pair."""
    s = _study()
    decided = {"case": "xi12", "index": 3, "status": "ok", "failed": True,
               "stop_reason": "failure decided", "decided_time": 9.0, "sliding_area": None,
               "runout_distance": None, "retrogression_distance": None}
    rows = [_row(0, False), _row(1, True, 200, 150, 40, 30, 0.2),
            _row(2, True, 100, 10, 30, 10, 1.0), decided, _row(4, False)]
    out = s.case_summary(rows, runs_to_rest=3)
    assert out["n"] == 5 and out["failed"] == 3 and out["p_failure"] == pytest.approx(0.6)
    assert out["decided"] == 1 and out["n_measure"] == 3 and out["failed_measure"] == 2
    assert out["sliding_area"]["given_failure"]["mean"] == pytest.approx(150.0)
    assert out["sliding_area"]["unconditional"]["n"] == 3
    assert sum(out["modes"].values()) == 2
    table = s.markdown_table({"xi12": out}, {})
    assert "| 3 (2) |" in table
    check = s.decided_check(rows, [{**decided, "index": 1}, {**decided, "index": 0},
                                   {**_row(2, True), "stop_reason": "at rest"}])
    assert check["pairs"] == 3 and check["agree"] == 2 and check["disagree"] == [0]
    assert check["decided"] == 2


def test_report_shows_the_decided_check(tmp_path):
    """report.html's risk study shows the decided-only campaign against the runs to rest."""
    import json

    from fem_rmpm.campaign.report import report_html
    (tmp_path / "summary.json").write_text('{"scene": "slope_risk", "cases": []}')
    (tmp_path / "risk_study.json").write_text(json.dumps(
        {"rules": {}, "cases": {}, "decided_campaign": "runs/decided",
         "decided_check": {"xi12": {"pairs": 60, "agree": 59, "disagree": [7],
                                    "decided_time_max": 18.0}}}))
    page = report_html(tmp_path)
    assert "Runs stopped once decided against the runs to rest" in page
    assert "runs/decided" in page and "<td>59</td><td>7</td><td>18</td>" in page
