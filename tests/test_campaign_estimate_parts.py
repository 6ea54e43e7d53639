"""The dry run prices every part of a realization: the factor of safety (``--fs``,
``--fs-only``) and the MPM runs stopped once decided (``runs_to_rest``), from the
campaign's records when it has some, else from a probe (the FS) or as full runs (an upper
bound, said).  References: the arithmetic of the records given here."""
from __future__ import annotations

from pathlib import Path

import pytest

from fem_rmpm import cli
from fem_rmpm.campaign import estimate as E
from fem_rmpm.campaign.cases import Case
from fem_rmpm.campaign.decide import DECIDED
from fem_rmpm.runtime.budget import estimate_run
from fem_rmpm.scene import load_scene, with_values

TINY = Path(__file__).parent / "data" / "mc_tiny.toml"


def _rec(cpu: float, fs: float | None = None, steps: int | None = 1000,
         decided: bool = False) -> dict:
    r = {"case": "scene", "status": "ok", "cpu_time": cpu, "steps": steps, "particles": 100,
         "stop_reason": DECIDED if decided else "t_end"}
    if fs is not None:
        r["fs"] = {"status": "ok", "cpu_time": fs}
    return r


def test_record_costs_take_the_factor_of_safety_out_of_the_mpm_run():
    """Full runs of 3 s and 5 s CPU with FS of 1 s and 3 s: 2 s per 1e5 point-steps ->
    20 000 ns; FS mean 2 s; decided runs of 4 s and 2 s with FS of 1 s: 2 s mean."""
    scene = load_scene(TINY)
    e = estimate_run(scene)
    budget = {"scene": type(e)(**{**e.to_dict(), "steps": 1000})}
    recs = [_rec(3.0, fs=1.0), _rec(5.0, fs=3.0),
            _rec(4.0, fs=1.0, steps=None, decided=True),
            _rec(2.0, fs=None, steps=None, decided=True)]
    assert E.records_calibration(recs, budget).ns_per_point_step == pytest.approx(2e4)
    parts = E.part_costs(recs, fs_probe=lambda: pytest.fail("probed despite records"))
    assert parts.fs_seconds == pytest.approx((1 + 3 + 1) / 3)
    assert parts.decided_seconds == pytest.approx((3.0 + 2.0) / 2)
    none = E.part_costs([_rec(3.0)])
    assert none.fs_seconds is None and none.decided_seconds is None
    assert "upper bound" in none.decided_source
    assert E.part_costs([], fs_probe=lambda: 7.5).fs_seconds == 7.5


def test_a_case_costs_the_sum_of_its_tasks_parts():
    """Tasks: one full run + FS, two decided runs + FS, one FS only: (full + 2 x 4 + 4 x 2)
    / 4 s per realization, a full run priced at setup + points x steps x ns."""
    scene = load_scene(TINY)
    e = estimate_run(scene)
    cal = E.Calibration(1e3, 0.5, 0.0, 1.0, "given")
    full = 0.5 + e.points * e.steps * 1e3 * 1e-9
    parts = E.PartCosts(2.0, "given", 4.0, "given")
    tasks = [{"fs": "before", "decide": False}, {"fs": "before", "decide": True},
             {"fs": "before", "decide": True}, {"fs": "only", "decide": False}]
    c = E._case_estimate(Case("scene", "scene", scene), e, cal, parts, tasks, 0)
    assert (c.full_runs, c.decided_runs, c.fs_runs) == (1, 2, 4)
    assert c.full_run_seconds == pytest.approx(full)
    assert c.cpu_seconds == pytest.approx((full + 2 * 4.0 + 4 * 2.0) / 4)
    unknown = E._case_estimate(Case("scene", "scene", scene), e, cal,
                               E.PartCosts(2.0, "given", None, "full"), tasks, 0)
    assert unknown.cpu_seconds == pytest.approx((3 * full + 4 * 2.0) / 4)


def test_fs_only_dry_run_prices_the_factor_of_safety_and_no_mpm_run(tmp_path, capsys,
                                                                    monkeypatch):
    """``mc --fs-only --dry-run``: no MPM probe, each realization one FS (its probe made to
    cost 1.25 s here), nothing written."""
    monkeypatch.setattr(E, "probe_calibration",
                        lambda *a, **k: pytest.fail("an MPM probe for FS-only realizations"))
    monkeypatch.setattr(E, "_fs_probe", lambda scene, seed: 1.25)
    out = tmp_path / "c"
    est = E.estimate_campaign(load_scene(TINY), out, realizations=3, workers=1, fs_only=True)
    c = est.cases[0]
    assert (c.full_runs, c.decided_runs, c.fs_runs) == (0, 0, 3)
    assert c.cpu_seconds == pytest.approx(1.25)
    assert est.cpu_seconds == pytest.approx(3 * 1.25 + est.calibration.worker_start_seconds)
    assert cli.main(["mc", str(TINY), "-n", "3", "--out", str(out), "--fs-only",
                     "--dry-run"]) == 0
    text = capsys.readouterr().out
    assert "3 factor(s) of safety, 1.2 s CPU each" in text and "MPM run" not in text
    assert not out.exists()


def test_fs_and_decided_runs_dry_run_lines(tmp_path, capsys, monkeypatch):
    """``--fs`` with ``runs_to_rest = 1`` on 3 realizations: 1 run to the end, 2 stopped
    once decided (priced as full runs, said), 3 FS; the probe's figures stubbed."""
    monkeypatch.setattr(E, "probe_calibration",
                        lambda scene, seed: E.Calibration(1e3, 0.0, 0.0, 1.0, "stub"))
    monkeypatch.setattr(E, "_fs_probe", lambda scene, seed: 0.5)
    scene = with_values(load_scene(TINY), {"montecarlo.factor_of_safety": True,
                                           "montecarlo.runs_to_rest": 1})
    est = E.estimate_campaign(scene, tmp_path / "c", realizations=3, workers=1)
    c = est.cases[0]
    assert (c.full_runs, c.decided_runs, c.fs_runs) == (1, 2, 3)
    assert c.cpu_seconds == pytest.approx(c.full_run_seconds + 0.5)
    text = E.estimate_text(est)
    assert "2 MPM run(s) stopped once decided" in text and "upper bound" in text
    assert "3 factor(s) of safety, 0.5 s CPU each" in text
