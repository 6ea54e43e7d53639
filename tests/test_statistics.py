"""Campaign statistics of a case (fem_rmpm.campaign.statistics), key by key.

References: the binomial standard error sqrt(p (1 - p) / N) and the Wilson (1927) score
interval (scipy.stats.binomtest is the independent implementation); sample moments and
quantiles from numpy.  Written to kill the mutants `validation/mutation.py statistics`
found alive: every key of the result, records and results.csv rows alike, the empty and
the one- and two-realization cases.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.stats import binomtest

from fem_rmpm.campaign.statistics import case_statistics, wilson_interval

MEASURES = ("runout_distance", "retrogression_distance", "sliding_area", "max_displacement")


def _records(n_ok: int, seed: int = 5, nested: bool = True) -> list[dict]:
    """n_ok finished realizations (records with a "measures" dict, or flat results.csv rows)
    plus one numerical failure, in shuffled index order."""
    rng = np.random.default_rng(seed)
    rows = []
    for i in range(n_ok):
        m = {"failed": bool(rng.random() < 0.4), "runout_distance": float(rng.gamma(2, 3)),
             "retrogression_distance": float(rng.gamma(2, 2)),
             "sliding_area": float(rng.gamma(3, 50)), "max_displacement": float(rng.gamma(2, 1)),
             "slip_surface_height": float(rng.random()), "intact_blocks": int(rng.integers(9)),
             "time_to_rest": 30.0, "failure_displacement": 0.5, "mechanism_time": 3.0,
             "at_rest": True}
        head = {"index": i, "seed": 100 + i, "status": "ok"}
        rows.append({**head, "measures": m} if nested else {**head, **m})
    rows.append({"index": n_ok, "seed": 100 + n_ok, "status": "failed", "error": "boom"})
    return [rows[i] for i in np.random.default_rng(seed + 1).permutation(len(rows))]


def _value(row, key):
    return row["measures"][key] if "measures" in row else row[key]


@pytest.mark.parametrize("nested", [True, False])
def test_case_statistics_every_key(nested):
    """For 7 realizations and one failure: counts, the error list, P(failure) = k/N with its
    SE and Wilson interval (scipy), mean / std (ddof 1) / se / 5-50-95 % quantiles (numpy) of
    each numeric measure (settings such as failure_displacement and flags such as at_rest
    are not statistics), and the running convergence in index order."""
    rows = _records(7, nested=nested)
    s = case_statistics(rows, requested=9)
    ok = sorted((r for r in rows if r["status"] == "ok"), key=lambda r: r["index"])
    fails = np.array([_value(r, "failed") for r in ok], dtype=float)
    k, n = int(fails.sum()), len(ok)
    p = k / n
    assert (s["requested"], s["finished"], s["ok"], s["numerical_failures"]) == (9, 8, 7, 1)
    assert s["errors"] == [{"index": 7, "seed": 107, "error": "boom"}]
    assert s["slope_failures"] == k and 0 < k < n and s["p_failure"] == p
    assert s["se"] == pytest.approx(math.sqrt(p * (1 - p) / n), rel=1e-14, abs=0)
    ci = binomtest(k, n).proportion_ci(0.95, method="wilson")
    assert s["wilson95"] == pytest.approx([ci.low, ci.high], rel=1e-12)
    for key in (*MEASURES, "slip_surface_height", "intact_blocks"):
        x = np.array([float(_value(r, key)) for r in ok])
        q = np.quantile(x, [0.05, 0.5, 0.95])
        assert s[key] == pytest.approx({"mean": x.mean(), "std": x.std(ddof=1),
                                        "se": x.std(ddof=1) / math.sqrt(n), "q05": q[0],
                                        "q50": q[1], "q95": q[2]}, rel=1e-14), key
    for key in ("failed", "time_to_rest", "failure_displacement", "mechanism_time", "at_rest"):
        assert key not in s, key
    conv = s["convergence"]
    nn = np.arange(1, n + 1)
    pr = np.cumsum(fails) / nn
    runout = np.array([_value(r, "runout_distance") for r in ok])
    assert conv["n"] == nn.tolist()
    np.testing.assert_allclose(conv["p_failure"], pr, rtol=1e-15)
    np.testing.assert_allclose(conv["se"], np.sqrt(pr * (1 - pr) / nn), rtol=1e-15)
    np.testing.assert_allclose(conv["mean_runout"], np.cumsum(runout) / nn, rtol=1e-14)


def test_a_measure_missing_from_one_row_is_left_out():
    """Only measures present (and numeric, not boolean) in every row are summarised."""
    rows = _records(4)
    for r in rows:
        if r["status"] == "ok" and r["index"] == 2:
            del r["measures"]["slip_surface_height"]
            r["measures"]["intact_blocks"] = True
    s = case_statistics(rows)
    assert "slip_surface_height" not in s and "intact_blocks" not in s
    assert all(key in s for key in MEASURES)


def test_no_finished_realization_gives_empty_statistics():
    """Every realization failed numerically: P(failure), SE and the interval are None, every
    measure's statistics are None, there is no convergence table."""
    rows = [{"index": 0, "seed": 1, "status": "failed", "error": "a"},
            {"index": 1, "seed": 2, "status": "failed", "error": "b"}]
    s = case_statistics(rows, requested=2)
    assert (s["ok"], s["numerical_failures"], s["slope_failures"]) == (0, 2, 0)
    assert s["p_failure"] is None and s["se"] is None and s["wilson95"] is None
    assert [e["error"] for e in s["errors"]] == ["a", "b"]
    for key in MEASURES:
        assert s[key] == {"mean": None, "std": None, "se": None, "q05": None, "q50": None,
                          "q95": None}
    assert "convergence" not in s


@pytest.mark.parametrize("n", [1, 2])
def test_one_and_two_realizations(n):
    """N = 1: the spread is 0 (not NaN); N = 2: the sample std with ddof 1."""
    rows = [r for r in _records(n) if r["status"] == "ok"]
    s = case_statistics(rows)
    x = np.array([r["measures"]["runout_distance"] for r in sorted(rows, key=lambda r: r["index"])])
    expect = 0.0 if n == 1 else abs(x[1] - x[0]) / math.sqrt(2)
    assert s["runout_distance"]["std"] == pytest.approx(expect, rel=1e-14, abs=0)
    assert s["runout_distance"]["se"] == pytest.approx(expect / math.sqrt(n), rel=1e-14, abs=0)
    assert s["runout_distance"]["mean"] == pytest.approx(x.mean(), rel=1e-15, abs=0)


def test_wilson_interval_edges():
    """Wilson (1927) against scipy at k = 0, k = N and in between; N = 0 is the whole [0, 1]."""
    assert wilson_interval(0, 0) == (0.0, 1.0)
    for k, n in ((0, 1), (1, 1), (0, 10), (10, 10), (3, 10), (1, 2)):
        ci = binomtest(k, n).proportion_ci(0.95, method="wilson")
        lo, hi = wilson_interval(k, n)
        assert (lo, hi) == pytest.approx((ci.low, ci.high), rel=1e-12, abs=1e-15)
        assert 0.0 <= lo <= hi <= 1.0
