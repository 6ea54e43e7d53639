"""Why each realization failed (fem_rmpm.campaign.fragility): the failure split, the probit
fragility fit and its profile-likelihood interval, softening switched off by the materials'
declarations, and the ``mc --fs`` / ``mc --fs --no-softening`` campaign outputs."""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from fem_rmpm.campaign.fragility import (
    CHI2_HALF,
    agreement_outside,
    binned_fragility,
    failure_split,
    fit_probit,
    has_softening,
    perfectly_plastic,
)
from fem_rmpm.cli import main
from fem_rmpm.materials.strength import strengths
from fem_rmpm.scene import load_scene, with_values

ROOT = Path(__file__).resolve().parents[1]
TINY = ROOT / "tests" / "data" / "mc_tiny.toml"


def test_saturated_probit_is_exact():
    """Two FS levels with failure fractions p1, p2 (0 < p < 1): the two-parameter probit is
    saturated, so the MLE passes through both fractions exactly:
    (FS50 - x_i) / s = Phi^-1(p_i)  =>  s = (x2 - x1) / (z1 - z2), FS50 = x1 + s z1."""
    x1, x2, k1, k2, n = 0.9, 1.2, 16, 5, 20
    fs = np.r_[np.full(n, x1), np.full(n, x2)]
    failed = np.r_[np.arange(n) < k1, np.arange(n) < k2]
    z1, z2 = stats.norm.ppf(k1 / n), stats.norm.ppf(k2 / n)
    s = (x2 - x1) / (z1 - z2)
    fit = fit_probit(fs, failed)
    assert fit["s"] == pytest.approx(s, rel=1e-4)
    assert fit["fs50"] == pytest.approx(x1 + s * z1, abs=1e-5)
    assert not fit["separated"]


def test_profile_interval_matches_a_brute_force_grid():
    """The 95 % profile-likelihood interval of FS50 against an independent evaluation of
    the Bernoulli log-likelihood on a 2-D (FS50, s) grid (N = 60 drawn from a probit with
    FS50 1.1, s 0.08): bounds within the grid step 0.002."""
    rng = np.random.default_rng(7)
    fs = rng.uniform(0.9, 1.3, 60)
    failed = rng.random(60) < stats.norm.cdf((1.1 - fs) / 0.08)
    fit = fit_probit(fs, failed)
    g50 = np.arange(0.95, 1.3, 0.002)
    gs = np.exp(np.linspace(np.log(0.005), np.log(1.0), 400))
    z = (g50[:, None, None] - fs[None, None, :]) / gs[None, :, None]
    ll = np.where(failed, stats.norm.logcdf(z), stats.norm.logcdf(-z)).sum(-1)
    prof = ll.max(1)
    inside = g50[prof >= prof.max() - CHI2_HALF]
    lo, hi = fit["fs50_interval95"]
    assert lo == pytest.approx(inside.min(), abs=0.003)
    assert hi == pytest.approx(inside.max(), abs=0.003)
    assert lo < fit["fs50"] < hi
    assert g50[prof.argmax()] == pytest.approx(fit["fs50"], abs=0.003)


def test_separated_data_and_no_fit():
    """Failures all below the standing FS: s at its floor, FS50 in the gap, the interval
    holding the gap; every realization failed (or none): no fit."""
    fs = np.array([0.8, 0.9, 0.95, 1.05, 1.1, 1.3])
    failed = fs < 1.0
    fit = fit_probit(fs, failed)
    assert fit["separated"] and fit["s"] < 0.01
    assert 0.95 <= fit["fs50"] <= 1.05
    lo, hi = fit["fs50_interval95"]
    assert lo <= 0.95 and hi >= 1.05
    assert fit_probit(fs, np.ones(6, bool)) is None
    assert fit_probit(fs, np.zeros(6, bool)) is None


def test_split_bins_and_agreement_count_by_hand():
    """Failures with FS >= 1 are progressive, with FS < 1 strength-limited; equal-count
    bins; agreement outside |FS - 1| <= 0.03 leaves the near-1 realization out."""
    fs = np.array([0.8, 0.9, 0.99, 1.1, 1.2, 1.3])
    below = fs < 1
    failed = np.array([True, False, True, True, False, False])
    sp = failure_split(fs, below, failed)
    assert (sp["failures"], sp["progressive"], sp["strength_limited"],
            sp["stood_with_fs_below_1"]) == (3, 1, 2, 1)
    assert sp["progressive_fraction"] == pytest.approx(1 / 3)
    b = binned_fragility(fs, failed, bins=3)
    assert [v["n"] for v in b] == [2, 2, 2] and [v["failures"] for v in b] == [1, 2, 0]
    a = agreement_outside(fs, below, failed)
    assert (a["n"], a["within_margin"], a["agree"]) == (5, 1, 3)


def test_perfectly_plastic_sets_every_declared_residual_to_its_peak():
    """By the models' STRENGTHS declarations (a row with ``peak``), for any softening model:
    von Mises (cohesion) and Mohr-Coulomb (cohesion and friction)."""
    scene = load_scene(TINY)
    assert has_softening(scene)
    pp = perfectly_plastic(scene)
    assert not has_softening(pp)
    assert pp.soils[0].value("cohesion_residual") == scene.soils[0].value("cohesion_peak")
    mc = with_values(scene, {"soil.model": "mohr_coulomb_softening", "soil.cohesion_peak": 5.0,
                             "soil.cohesion_residual": 1.0, "soil.friction_angle_peak": 30.0,
                             "soil.friction_angle_residual": 20.0})
    declared = [s for s in strengths("mohr_coulomb_softening") if s.peak is not None]
    assert len(declared) >= 2
    pmc = perfectly_plastic(mc)
    for s in declared:
        assert pmc.soils[0].value(s.name) == pmc.soils[0].value(s.peak)
    assert perfectly_plastic(pp) == pp


def _campaign(tmp_path, name, scheduler, *extra):
    out = tmp_path / name
    rc = main(["mc", str(TINY), "-n", "10", "--fs", "--set", "montecarlo.seed=404",
               "--set", "solver.fbar=true", "--out", str(out), "--scheduler", scheduler,
               "--quiet", *extra])
    assert rc == 0
    return out, json.loads((out / "summary.json").read_text())["cases"][0]


def test_fs_campaign_explains_its_failures(tmp_path, dask_scheduler):
    """``mc --fs`` on the tiny slope (campaign seed 404, N = 10): summary.json and the
    report give P(FS < 1) beside P(failure), the progressive / strength-limited split and
    the fragility fit; every realization with FS < 0.97 fails (a slope below its peak
    strength cannot stand in the MPM either).  With ``--no-softening`` (the same fields,
    perfectly plastic at peak) stand/fail agrees with FS < 1 wherever |FS - 1| > 0.03."""
    out, case = _campaign(tmp_path, "soft", dask_scheduler)
    f = case["fs"]["fragility"]
    assert f["n"] >= 6 and f["split"]["failures"] == (f["split"]["progressive"]
                                                      + f["split"]["strength_limited"])
    assert f["p_fs_below_1_wilson95"][0] <= f["p_fs_below_1"] <= f["p_fs_below_1_wilson95"][1]
    rows = [json.loads(p.read_text()) for p in (out / "records").rglob("*.json")]
    with_fs = [r["measures"] for r in rows if r["measures"].get("factor_of_safety") is not None]
    low = [m for m in with_fs if m["factor_of_safety"] < 0.97]
    assert low and all(m["failed"] for m in low)
    page = (out / "report.html").read_text()
    for words in ("Why the realizations failed", "progressive", "FS50", "P(FS &lt; 1)"):
        assert words in page, words
    assert (out / "fragility.png").is_file() and (out / "fs_scatter.png").is_file()

    out2, case2 = _campaign(tmp_path, "plastic", dask_scheduler, "--no-softening")
    assert case2["softening"] is False
    a = case2["fs"]["agreement"]["outside_margin"]
    assert a["n"] >= 6 and a["agree"] == a["n"], case2["fs"]["agreement"]
    assert "Softening was switched off" in (out2 / "report.html").read_text()
    assert math.isclose(case2["fs"]["fs_mean"], case["fs"]["fs_mean"], rel_tol=1e-12)
