"""The main job (``fem-rmpm mc`` without a scene): its risk slope is the risk slope of
meshes/ with a small [montecarlo], and its dry run writes nothing."""
from __future__ import annotations

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


def test_main_job_dry_run_writes_nothing(tmp_path, capsys):
    out = tmp_path / "mc"
    assert main(["mc", "--out", str(out), "--dry-run"]) == 0
    text = capsys.readouterr().out
    assert "xi = 12: 16 to run" in text and "seed_slope" in text and "homogeneous" in text
    assert not out.exists()
