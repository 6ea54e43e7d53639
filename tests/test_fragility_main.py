"""The main job (``fem-rmpm mc`` without a scene): its risk slope is the risk slope of
meshes/ with a small [montecarlo], and its dry run writes nothing."""
from __future__ import annotations

import math
from pathlib import Path

from fem_rmpm.campaign.main_job import FULL_STUDY, main_scene_path
from fem_rmpm.cli import main
from fem_rmpm.scene import load_scene, scene_to_dict

ROOT = Path(__file__).resolve().parents[1]


def test_main_scene_is_the_risk_slope_with_a_small_campaign():
    """Every section but [montecarlo] equals meshes/slope_risk.toml's; the main job runs
    the factor of safety, one anisotropic case, runs stopped once decided, the campaign
    seed of the full study (so realization i is the same field in both)."""
    main_job = scene_to_dict(load_scene(main_scene_path()))
    full = scene_to_dict(load_scene(ROOT / "meshes" / "slope_risk.toml"))
    mc, mc_full = main_job.pop("montecarlo"), full.pop("montecarlo")
    assert main_job == full
    assert mc["factor_of_safety"] and mc["runs_to_rest"] == 0 and mc["cases"] == ["xi=12"]
    assert mc["seed"] == mc_full["seed"] and 10 <= mc["realizations"] <= 30
    assert "meshes/slope_risk.toml" in FULL_STUDY and "--fs" in FULL_STUDY


def test_main_job_dry_run_writes_nothing(tmp_path, capsys, monkeypatch):
    """Its realizations are priced with their FS (the FS probe stubbed: 2 s) and as runs
    stopped once decided."""
    from fem_rmpm.campaign import estimate
    monkeypatch.setattr(estimate, "_fs_probe", lambda scene, seed: 2.0)
    out = tmp_path / "mc"
    assert main(["mc", "--out", str(out), "--dry-run"]) == 0
    text = capsys.readouterr().out
    assert "xi = 12: 16 to run" in text and "seed_slope" in text and "homogeneous" in text
    assert "16 MPM run(s) stopped once decided" in text
    assert "16 factor(s) of safety, 2.0 s CPU each" in text
    assert not out.exists()


def test_report_shows_what_n_buys_and_linked_campaigns(tmp_path, dask_scheduler):
    """A campaign with another campaign in a subdirectory (as the main job's seed slope):
    the report gives the Wilson half-width now and the N for +-0.05 (1.96^2 p (1 - p) /
    0.05^2, rounded up), and the linked campaign's table and figures."""
    import json

    from fem_rmpm.campaign.report import write_report
    tiny = str(ROOT / "tests" / "data" / "mc_tiny.toml")
    out = tmp_path / "mc"
    assert main(["mc", tiny, "-n", "4", "--out", str(out), "--scheduler", dask_scheduler,
                 "--quiet"]) == 0
    assert main(["mc", tiny, "-n", "2", "--out", str(out / "seed_slope"), "--scheduler",
                 dask_scheduler, "--quiet"]) == 0
    page = write_report(out).read_text()
    assert "What N buys" in page and "Linked campaigns" in page
    assert 'href="seed_slope/report.html"' in page
    c = json.loads((out / "summary.json").read_text())["cases"][0]
    q = min(max(c["p_failure"], 1 / 5), 4 / 5)
    need = math.ceil(1.959963984540054 ** 2 * q * (1 - q) / 0.05 ** 2)
    assert f"<td>{need}</td>" in page
