"""The acceptance verdicts printed by ``validation/bench_explicit.py`` (issue 13), on
result documents of the shape its quick and full runs make: the figures are made up, the
thresholds are the issue's (67 ns per point-step, 1.8x on two threads, a 25 % spread of
1e4 / 1e5 / 1e6 points, 3 s to the first step from a warm cache)."""
from __future__ import annotations

from validation_module import load

bench = load("bench_explicit")


def _result(ns1: float, ns2: float | None, big: tuple | None, spread: float | None) -> dict:
    case_i = [{"threads": 1, "ns_per_point_step": ns1}]
    whole = {"case_i": case_i}
    if ns2 is not None:
        case_i.append({"threads": 2, "ns_per_point_step": ns2})
        whole.update({"scaling": {"1e6": [{"threads": 1, "ns_per_point_step": big[0]},
                                          {"threads": 2, "ns_per_point_step": big[1]}]},
                      "scaling_spread": spread})
    return {"whole_run": whole,
            "compile": {"warm_cache": {"imports_and_setup_s": 0.6, "first_step_s": 0.2}}}


def test_quick_run_gives_points_1_and_4():
    lines = bench.issue13_verdicts(_result(40.0, None, None, None))
    assert [line[:2] for line in lines] == ["1.", "4."]
    assert lines[0].endswith(": met") and "0.80 s" in lines[1] and lines[1].endswith(": met")


def test_full_run_gives_points_1_to_4_and_says_not_met():
    """The full run keeps its scaling runs under ``whole_run`` (as ``whole_runs`` returns
    them); a ratio below 1.8 on either size and a spread above 25 % are NOT met."""
    lines = bench.issue13_verdicts(_result(68.0, 36.0, (44.0, 24.7), 0.26))
    assert [line[:2] for line in lines] == ["1.", "2.", "3.", "4."]
    assert lines[0].endswith("NOT met")                       # 68 > 67 ns
    assert "1.89x" in lines[1] and "1.78x" in lines[1] and lines[1].endswith("NOT met")
    assert lines[2].endswith("NOT met")
    ok = bench.issue13_verdicts(_result(39.0, 20.8, (44.0, 23.9), 0.22))
    assert all(line.endswith(": met") for line in ok)
