"""The long 3-D slope against its plane-strain section: the length effect and the modes.

Reads two finished campaigns -- the 3-D long slope (``meshes/slope_long_3d.toml``, cases
``theta_strike`` = 3 m and 80 m) and its plane-strain section
(``meshes/slope_long_section.toml``, the same section, material, field and solver on the
same 1 m cells) -- and prints, per case:

* P(failure) = k/N with its Wilson 95 % interval (Wilson 1927);
* given failure, over the failed runs to rest (realizations ``i < runs_to_rest``): sliding
  volume (m3) and sliding area per metre of strike (m2/m; the 2-D section's sliding area),
  run-out and retrogression (largest slice, m), the number of separate slides along the
  strike and the strike length of each slide (m);
* the length effect: P(3-D) - P(section) with Newcombe's hybrid score interval for a
  difference of two independent proportions (Newcombe 1998, Statistics in Medicine 17,
  873-890, method 10), and the ratio P(3-D) / P(section).

It writes a figure (P(failure) with intervals; slides per failed realization; each slide's
strike length against its volume) with ``--figure``.  Usage::

    fem-rmpm mc meshes/slope_long_3d.toml -n 30 --set montecarlo.runs_to_rest=10 --out runs/long3d
    fem-rmpm mc meshes/slope_long_section.toml -n 30 --out runs/long_section
    python validation/long_slope_3d.py runs/long_section runs/long3d [more 3-D campaigns]
        [--section-large DIR] [--figure docs/validation/figures/long_slope_3d.png]

Nothing is recomputed: the script reads ``records/`` (JSON) of each campaign.
"""
from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

from fem_rmpm.campaign.decide import is_decided
from fem_rmpm.campaign.statistics import wilson_interval
from fem_rmpm.campaign.store import read_record
from fem_rmpm.io.output import read_pvd

STRIKE_LENGTH = 40.0   # m, meshes/slope_long_3d.toml [grid] size[2]


def read_cases(out: Path) -> dict[str, list[dict]]:
    """The finished ``ok`` records of a campaign directory, by case, in index order."""
    cases: dict[str, list[dict]] = {}
    for f in sorted(Path(out, "records").rglob("realization_*.json")):
        rec = read_record(f)
        if rec and rec.get("status") == "ok" and (rec.get("measures") or {}).get("failed") \
                is not None:
            cases.setdefault(rec["case"], []).append(rec)
    for recs in cases.values():
        recs.sort(key=lambda r: r["index"])
    return cases


def newcombe_difference(k1: int, n1: int, k2: int, n2: int) -> tuple[float, float, float]:
    """p1 - p2 and its 95 % interval by Newcombe's hybrid score method (method 10) from the
    two Wilson intervals."""
    p1, p2 = k1 / n1, k2 / n2
    l1, u1 = wilson_interval(k1, n1)
    l2, u2 = wilson_interval(k2, n2)
    d = p1 - p2
    return (d, d - math.sqrt((p1 - l1) ** 2 + (u2 - p2) ** 2),
            d + math.sqrt((u1 - p1) ** 2 + (p2 - l2) ** 2))


def _mean_se(x: list[float]) -> str:
    if not x:
        return "-"
    a = np.asarray(x, dtype=float)
    se = a.std(ddof=1) / math.sqrt(len(a)) if len(a) > 1 else float("nan")
    return f"{a.mean():.1f} +- {se:.1f}"


def case_row(name: str, recs: list[dict], three_d: bool) -> dict:
    """P(failure), its interval and the given-failure measures of one case: those over the
    failed runs to rest (every run not stopped once decided; with ``runs_to_rest = K`` the
    failures among realizations 0..K-1, a random subsample of all failures)."""
    n = len(recs)
    k = sum(bool(r["measures"]["failed"]) for r in recs)
    rest = [r for r in recs if r["measures"]["failed"] and not is_decided(r)]
    m = [r["measures"] for r in rest]
    row = {"case": name, "n": n, "k": k, "p": k / n if n else float("nan"),
           "wilson": wilson_interval(k, n), "rest_failed": len(rest),
           "area": [x["sliding_area"] for x in m],
           "runout": [x["runout_distance"] for x in m],
           "retro": [x["retrogression_distance"] for x in m],
           "decided": [r["measures"].get("decided_time") for r in recs
                       if r["measures"]["failed"]],
           "cpu": [r.get("cpu_time") or 0.0 for r in recs]}
    if three_d:
        row["volume"] = [x["sliding_volume"] for x in m]
        row["count"] = [x["slide_count"] for x in m]
        row["slides"] = [(s[1] - s[0], s[2]) for r in rest for s in r.get("slides", [])]
    return row


def print_table(rows: list[dict]) -> None:
    print("| case | N | failed | P(failure) [Wilson 95 %] | failed runs to rest | "
          "sliding area m2/m | sliding volume m3 | slides per failure | slide length m | "
          "run-out m | retrogression m | CPU s per realization (median) |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        lo, hi = r["wilson"]
        counts = (", ".join(str(c) for c in r["count"]) if r.get("count") else "-")
        lengths = (", ".join(f"{a:.0f}" for a, _ in r["slides"]) if r.get("slides") else "-")
        print(f"| {r['case']} | {r['n']} | {r['k']} | {r['p']:.3f} [{lo:.3f}, {hi:.3f}] | "
              f"{r['rest_failed']} | {_mean_se(r['area'])} | "
              f"{_mean_se(r.get('volume', []))} | {counts} | {lengths} | "
              f"{_mean_se(r['runout'])} | {_mean_se(r['retro'])} | "
              f"{np.median(r['cpu']):.0f} |")


def print_length_effect(rows3d: list[dict], section: dict) -> None:
    print(f"\nLength effect against the section ({section['case']}, "
          f"{section['k']}/{section['n']}):")
    for r in rows3d:
        d, lo, hi = newcombe_difference(r["k"], r["n"], section["k"], section["n"])
        ratio = r["p"] / section["p"] if section["p"] > 0 else float("inf")
        print(f"  {r['case']}: P(3-D) - P(section) = {d:+.3f} [{lo:+.3f}, {hi:+.3f}] "
              f"(Newcombe 95 %); ratio {ratio:.2f}")


def figure(rows: list[dict], path: Path) -> None:
    """P(failure) per case with its interval; slides per failed run to rest; each slide's
    strike length against its volume."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(1, 3, figsize=(15, 4.6), width_ratios=(1.2, 1, 1))
    y = np.arange(len(rows))
    p = np.array([r["p"] for r in rows])
    lo = np.array([r["wilson"][0] for r in rows])
    hi = np.array([r["wilson"][1] for r in rows])
    ax[0].errorbar(p, y, xerr=[p - lo, hi - p], fmt="o", capsize=4, color="k")
    ax[0].set_yticks(y, [f"{r['case']}, N = {r['n']}" for r in rows], fontsize=8)
    ax[0].set_xlabel("P(failure), Wilson 95 % interval")
    ax[0].set_xlim(0, 1)
    ax[0].invert_yaxis()
    ax[0].grid(alpha=0.3)
    three = [r for r in rows if "count" in r]
    width = 0.8 / max(len(three), 1)
    for j, r in enumerate(three):
        c = np.bincount(np.asarray(r["count"], dtype=int), minlength=6)[1:6]
        ax[1].bar(np.arange(1, 6) + (j - (len(three) - 1) / 2) * width, c, width,
                  label=r["case"])
        if r["slides"]:
            a = np.array(r["slides"])
            ax[2].scatter(a[:, 0], a[:, 1], label=r["case"], alpha=0.8)
    ax[1].set_xlabel("separate slides along the strike, per failed run to t_end")
    ax[1].set_ylabel("failed runs to t_end")
    ax[1].yaxis.get_major_locator().set_params(integer=True)
    ax[1].set_xticks(range(1, 6))
    ax[2].axvline(STRIKE_LENGTH, color="0.5", ls="--", lw=1)
    ax[2].text(STRIKE_LENGTH, 0.02, "whole strike ", color="0.4", va="bottom", ha="right",
               rotation=90, transform=ax[2].get_xaxis_transform())
    ax[2].set_xlim(0, STRIKE_LENGTH + 2)
    ax[2].set_ylim(bottom=0)
    ax[2].set_xlabel("slide length along the strike (m)")
    ax[2].set_ylabel("slide volume (m3)")
    for a in ax[1:]:
        a.grid(alpha=0.3)
        if a.get_legend_handles_labels()[0]:
            a.legend(fontsize=8)
    fig.suptitle("Long 3-D slope (40 m strike) and its plane-strain section, 1 m cells")
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def spread(vtk_dir: Path, geostatic_time: float, threshold: float = 0.5,
           least: float = 1.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """How a kept realization's failure spreads along the strike: for every output of its
    VTK series (``particles.pvd``) after the geostatic phase, the sliding volume (m3) of
    each 1 m strike slice -- points moved more than ``threshold`` m since the output at
    ``geostatic_time`` s (the campaign's rule).  Returns (times s, slice z m, volume
    array (times, slices)); a slice holds a slide when its volume >= ``least`` m3."""
    import meshio
    series = read_pvd(Path(vtk_dir, "particles.pvd"))
    t0, f0 = min(((t, f) for t, f in series if t >= geostatic_time - 0.5),
                 key=lambda tf: abs(tf[0] - geostatic_time))
    x0 = meshio.read(f0).points
    k = np.floor(x0[:, 2]).astype(int)
    times, rows = [], []
    for t, f in series:
        if t < t0:
            continue
        m = meshio.read(f)
        moved = np.linalg.norm(m.points - x0, axis=1) > threshold
        rows.append(np.bincount(k, weights=m.point_data["volume"] * moved, minlength=k.max() + 1))
        times.append(t)
    return np.array(times), np.arange(k.max() + 1) + 0.5, np.array(rows)


def spread_figure(runs: list[tuple[str, Path]], geostatic_time: float, path: Path) -> None:
    """Sliding volume per strike slice against time for kept failed realizations."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(1, len(runs), figsize=(5.5 * len(runs), 4), squeeze=False)
    for a, (label, d) in zip(ax[0], runs):
        t, z, v = spread(d, geostatic_time)
        im = a.pcolormesh(z, t, v, shading="nearest", cmap="magma_r")
        fig.colorbar(im, ax=a, label="sliding volume per 1 m slice (m3)")
        a.set_xlabel("strike z (m)")
        a.set_ylabel("time (s)")
        a.set_ylim(t[0], min(t[-1], t[0] + 14))
        a.set_title(label, fontsize=10)
        first = [tt for tt, row in zip(t, v) if (row >= 1.0).any()]
        if first:
            row = v[list(t).index(first[0])]
            print(f"  {label}: first slide at {first[0]:.0f} s over "
                  f"{int((row >= 1.0).sum())} m of strike; whole strike "
                  + next((f"at {tt:.0f} s" for tt, r in zip(t, v) if (r >= 1.0).all()),
                         "never"))
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("section", type=Path, help="campaign directory of slope_long_section.toml "
                    "at the same N")
    ap.add_argument("three_d", type=Path, nargs="+", help="campaign directories of "
                    "slope_long_3d.toml (their cases in order)")
    ap.add_argument("--section-large", type=Path, help="the section at a larger N (optional)")
    ap.add_argument("--figure", type=Path, help="write the figure (PNG) here")
    ap.add_argument("--spread", nargs=2, action="append", metavar=("LABEL", "VTK_DIR"),
                    default=[], help="a kept failed realization's VTK directory: how its "
                    "slide spreads along the strike (repeatable)")
    ap.add_argument("--spread-figure", type=Path, help="write the spread figure (PNG) here")
    a = ap.parse_args(argv)
    for d in (*a.three_d, a.section, a.section_large):
        if d is not None and not Path(d, "campaign.json").is_file():
            print(f"long_slope_3d: {d} is not a campaign directory (no campaign.json)",
                  file=sys.stderr)
            return 2
    rows3d = [case_row(c.replace("random_field.", ""), recs, True)
              for d in a.three_d for c, recs in read_cases(d).items()]
    rows3d.sort(key=lambda r: float(r["case"].split("=")[-1]))
    sec = [case_row("section (2-D)", recs, False)
           for recs in read_cases(a.section).values()]
    if a.section_large is not None:
        sec += [case_row("section (2-D), large N", recs, False)
                for recs in read_cases(a.section_large).values()]
    rows = sec + rows3d
    print_table(rows)
    print_length_effect(rows3d, sec[0])
    if len(sec) > 1:
        print_length_effect(rows3d, sec[1])
    for r in rows:
        dec = [t for t in r["decided"] if t is not None]
        if dec:
            print(f"  {r['case']}: failures decided at {min(dec):.0f}-{max(dec):.0f} s "
                  f"(median {np.median(dec):.0f} s)")
    if a.figure:
        figure(rows, a.figure)
        print(f"figure: {a.figure}")
    if a.spread:
        print("\nHow the kept failures spread along the strike:")
        spread_figure([(lab, Path(d)) for lab, d in a.spread], 6.0,
                      a.spread_figure or Path("long_slope_spread.png"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
