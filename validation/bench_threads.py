"""Two threads against one, in interleaved pairs of whole runs (target: two threads at
least 1.8x as fast as one).  Plain script:

    nice python validation/bench_threads.py --pairs 10             # case (i), ~4 min
    nice python validation/bench_threads.py --pairs 3 --size 1e6   # ~1e6 points, ~3 min

Why pairs: on a shared machine the cost of the same one-thread run of case (i) varies by
tens of per cent within an hour, so one run on each thread count
(``validation/bench_explicit.py``) can move the ratio by +-10 %.  Each pair here is a
one-thread and a two-thread ``fem-rmpm run`` in fresh processes, one right after the other
(which goes first alternates), so both see about the same host; the ratio of a pair is
one-thread wall / two-thread wall, from each run's own ``summary.json`` (ns per
point-step, the time loop with its VTK output).  Reported: every pair's ratio, their
median, range and how many reach the target, the ratio of the medians and the ratio of
the fastest runs (the least disturbed of each).  The verdict uses the median pair ratio.
Every pair also checks that the two runs agree exactly (steps and measures: a run is the
same on 1 and 2 threads).

Sizes: ``ref`` is case (i) as users run it, 18 260 points to rest; ``1e6`` is case (i)
on 1/30 m cells (~1.03e6 points), the first 0.25 s.  Writes
``validation/out/bench_threads_<size>.json``.
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "validation"))

from bench_explicit import fill_cache, machine, scaling_changes, whole_run  # noqa: E402

OUT = ROOT / "validation" / "out"
TARGET = 1.8                      # two threads >= 1.8x one
SIZES = {"ref": [], "1e6": scaling_changes("1e6")}


def pair(k: int, changes: list[str]) -> dict:
    """Pair ``k``: one- and two-thread whole runs back to back (pair 0 starts with one
    thread, pair 1 with two, ...); their ratio and whether they agree."""
    order = (1, 2) if k % 2 == 0 else (2, 1)
    runs = {th: whole_run(th, changes) for th in order}
    one, two = runs[1], runs[2]
    same = (one["steps"] == two["steps"] and one["measures"] == two["measures"])
    return {"first": order[0], "ns_1": one["ns_per_point_step"],
            "ns_2": two["ns_per_point_step"],
            "ratio": one["ns_per_point_step"] / two["ns_per_point_step"],
            "threads_used_2": two["threads_used"], "points": one["points"],
            "steps": one["steps"], "same_result": same}


def summarize(pairs: list[dict], target: float = TARGET) -> dict:
    """Median, range and count at target of the pair ratios; the ratio of the medians and
    of the fastest runs."""
    ratios = [p["ratio"] for p in pairs]
    ns1, ns2 = [p["ns_1"] for p in pairs], [p["ns_2"] for p in pairs]
    return {"pairs": len(pairs), "median_ratio": statistics.median(ratios),
            "min_ratio": min(ratios), "max_ratio": max(ratios),
            "at_target": sum(r >= target for r in ratios),
            "ratio_of_medians": statistics.median(ns1) / statistics.median(ns2),
            "ratio_of_fastest": min(ns1) / min(ns2),
            "ns_1_range": [min(ns1), max(ns1)], "ns_2_range": [min(ns2), max(ns2)],
            "all_same_result": all(p["same_result"] for p in pairs), "target": target}


def report(size: str, s: dict, m: dict) -> str:
    """The verdict lines of one size."""
    verdict = "met" if s["median_ratio"] >= s["target"] else "NOT met"
    return (f"two threads against one, {size}, {m['cpu_model']}, {m['cores']} cores: median of "
            f"{s['pairs']} pair ratios {s['median_ratio']:.2f}x (range {s['min_ratio']:.2f}-"
            f"{s['max_ratio']:.2f}, {s['at_target']} of {s['pairs']} >= {s['target']}x; "
            f"ratio of the medians {s['ratio_of_medians']:.2f}x, of the fastest runs "
            f"{s['ratio_of_fastest']:.2f}x; one thread {s['ns_1_range'][0]:.1f}-"
            f"{s['ns_1_range'][1]:.1f} ns, two {s['ns_2_range'][0]:.1f}-"
            f"{s['ns_2_range'][1]:.1f} ns per point-step): {verdict}; 1 and 2 threads "
            f"{'agree exactly' if s['all_same_result'] else 'DIFFER'} in every pair")


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--pairs", type=int, default=10, help="interleaved pairs (default 10)")
    ap.add_argument("--size", choices=sorted(SIZES), default="ref",
                    help="ref: case (i), 18 260 points; 1e6: 1/30 m cells, first 0.25 s")
    ap.add_argument("--out", default=None, help="JSON file (default validation/out/...)")
    args = ap.parse_args(argv)
    if args.pairs < 1:
        ap.error("--pairs must be at least 1")
    changes = SIZES[args.size]
    fill_cache()
    m = machine()
    print(f"machine: {m['cpu_model']}, {m['cores']} cores, load average "
          f"{' '.join(f'{v:.2f}' for v in m['load_avg_start'])} at start", flush=True)
    pairs = []
    for k in range(args.pairs):
        p = pair(k, changes)
        pairs.append(p)
        print(f"pair {k + 1}: one thread {p['ns_1']:.1f}, two {p['ns_2']:.1f} ns per "
              f"point-step ({p['points']} points, {p['steps']} steps): {p['ratio']:.2f}x"
              f"{'' if p['same_result'] else '  RESULTS DIFFER'}", flush=True)
    s = summarize(pairs)
    m["load_avg_end"] = os.getloadavg()
    line = report(args.size, s, m)
    print(line)
    out = Path(args.out) if args.out else OUT / f"bench_threads_{args.size}.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    res = {"machine": m, "size": args.size, "changes": changes, "pairs": pairs, "summary": s,
           "verdict": line}
    out.write_text(json.dumps(res, indent=1))
    print(f"wrote {out}")
    return res


if __name__ == "__main__":
    main()
