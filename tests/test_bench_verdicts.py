"""The performance-target verdicts printed by ``validation/bench_explicit.py`` and
``validation/bench_threads.py``, on result documents of the shape their runs make: the
figures are made up, the thresholds are the benchmarks' targets (67 ns per point-step,
1.8x on two threads, a 25 % spread of 1e4 / 1e5 / 1e6 points, 3 s to the first step from
a warm cache)."""
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


def _labels(lines: list[str]) -> list[str]:
    return [line.split(":")[0] for line in lines]


def test_quick_run_gives_one_thread_and_warm_start():
    lines = bench.target_verdicts(_result(40.0, None, None, None))
    assert _labels(lines) == ["one thread", "warm start"]
    assert lines[0].endswith(": met") and "0.80 s" in lines[1] and lines[1].endswith(": met")


def test_full_run_gives_every_target_and_says_not_met():
    """The full run keeps its scaling runs under ``whole_run`` (as ``whole_runs`` returns
    them); a ratio below 1.8 on either size and a spread above 25 % are NOT met."""
    lines = bench.target_verdicts(_result(68.0, 36.0, (44.0, 24.7), 0.26))
    assert _labels(lines) == ["one thread", "two threads", "scaling", "warm start"]
    assert lines[0].endswith("NOT met")                       # 68 > 67 ns
    assert "1.89x" in lines[1] and "1.78x" in lines[1] and lines[1].endswith("NOT met")
    assert lines[2].endswith("NOT met")
    ok = bench.target_verdicts(_result(39.0, 20.8, (44.0, 23.9), 0.22))
    assert all(line.endswith(": met") for line in ok)


threads = load("bench_threads")


def _pairs(ns: list[tuple[float, float]], same: bool = True) -> list[dict]:
    return [{"ns_1": a, "ns_2": b, "ratio": a / b, "same_result": same} for a, b in ns]


def test_thread_pairs_verdict_is_the_median_pair_ratio():
    """``validation/bench_threads.py``: three made-up pairs, ratios 2.0, 1.75 and 1.9 (median
    1.9: met, 2 of 3 at 1.8x); the fastest runs 44 and 23 ns; one thread's median 46 over
    two's median 44 / 1.9 = 23.16 ns."""
    s = threads.summarize(_pairs([(46.0, 23.0), (49.0, 28.0), (44.0, 44.0 / 1.9)]))
    assert abs(s["median_ratio"] - 1.9) < 1e-12 and s["at_target"] == 2
    assert abs(s["ratio_of_fastest"] - 44.0 / 23.0) < 1e-12
    assert abs(s["ratio_of_medians"] - 46.0 / (44.0 / 1.9)) < 1e-12
    m = {"cpu_model": "CPU", "cores": 2}
    line = threads.report("ref", s, m)
    assert "median of 3 pair ratios 1.90x" in line and ": met;" in line
    assert "agree exactly" in line


def test_thread_pairs_below_target_or_differing_are_said():
    """A median pair ratio of 1.75 is NOT met; a pair whose two runs differ is named."""
    s = threads.summarize(_pairs([(35.0, 20.0), (36.0, 20.0)], same=False) +
                          _pairs([(34.0, 20.0)]))
    line = threads.report("1e6", s, {"cpu_model": "CPU", "cores": 2})
    assert "1.75x" in line and "NOT met" in line and "DIFFER" in line
