"""The factor of safety in a campaign (``[montecarlo] factor_of_safety = true``, ``--fs``,
``--fs-only``): per realization, the strength-reduction FS of its random field
(:mod:`fem_rmpm.schemes.implicit.strength_reduction`) before the MPM run, or instead of it.

Per realization the record gains ``fs`` (text, bracket, static solves, wall time, status)
and the measures (hence ``results.csv``): ``factor_of_safety`` (the bound itself when
censored, "FS > 10" -> 10), ``fs_bound`` (-1: below ``f_min``, 0: found, 1: above
``f_max``), ``fs_below_1`` (exact: the first trial of the search is ``F = 1``),
``fs_static_solves`` (its wall time is in the record only, like the run's, so the table
is the same on any number of workers).  Per case (:func:`fs_statistics`):
P(FS < 1) with its binomial standard error and Wilson interval, the reliability index and
the agreement between "FS < 1" and the MPM's ``failed``, with the realizations where they
disagree listed with both values, and with MPM runs the failure split and fragility curve
of :mod:`fem_rmpm.campaign.fragility` (``fragility``).
"""
from __future__ import annotations

import math
import time
from pathlib import Path
from typing import Sequence

import numpy as np

from fem_rmpm import api
from fem_rmpm.campaign.fragility import agreement_outside, fragility_statistics, probit_curve
from fem_rmpm.campaign.statistics import wilson_interval
from fem_rmpm.io.plots import _plt
from fem_rmpm.measures import table
from fem_rmpm.scene import Scene
from fem_rmpm.schemes.implicit.strength_reduction import NonPhysicalFailure, factor_of_safety

__all__ = ["MODES", "fs_measures", "fs_statistics", "fs_text", "plot_factor_of_safety",
           "plot_fragility", "plot_fs_scatter"]

#: "off": no FS; "before": FS, then the MPM run; "only": FS instead of the MPM run.
MODES = ("off", "before", "only")
_BOUND = {"<": -1, "=": 0, ">": 1}


def fs_measures(scene: Scene, seed: int) -> tuple[dict, dict]:
    """(measures, info) of the FS of realization ``seed``; a non-physical Newton failure
    is recorded (``info["status"] = "failed"``, measures empty), never raised."""
    t0, c0 = time.perf_counter(), time.process_time()
    try:
        grid, pts = api.prepare(scene, seed)
        res = factor_of_safety(scene, seed=seed, grid=grid, pts=pts)
    except NonPhysicalFailure as exc:
        return {}, {"status": "failed", "error": " ".join(str(exc).split()),
                    "cause": exc.cause, "wall_time": time.perf_counter() - t0,
                    "cpu_time": time.process_time() - c0}
    below = not res.trials[0].converged          # the search starts at F = 1
    m = {"factor_of_safety": float(res.fs), "fs_bound": _BOUND[res.bound],
         "fs_below_1": bool(below), "fs_static_solves": res.static_solves}
    info = {"status": "ok", "text": res.text, "bracket": list(res.bracket),
            "static_solves": res.static_solves, "wall_time": res.wall_time,
            "cpu_time": time.process_time() - c0, "displacement_jump": res.displacement_jump}
    return m, info


def _get(r: dict, key: str):
    if "measures" in r:
        return (r.get("measures") or {}).get(key)
    return r.get(key)


def fs_statistics(rows: Sequence[dict]) -> dict | None:
    """FS statistics of the ``ok`` rows (records or ``results.csv`` rows) that have an FS;
    None if none has one.  ``reliability_index`` = mean / std of ln FS (FS lognormal,
    Griffiths & Fenton 2004) and ``reliability_index_normal`` = (mean FS - 1) / std FS;
    censored values enter at their bound."""
    fs_rows = [r for r in rows if _get(r, "factor_of_safety") is not None]
    if not fs_rows:
        return None
    fs = np.array([float(_get(r, "factor_of_safety")) for r in fs_rows])
    below = np.array([bool(_get(r, "fs_below_1")) for r in fs_rows])
    n, k = len(fs), int(below.sum())
    p = k / n
    ln = np.log(fs)
    s_ln = float(np.std(ln, ddof=1)) if n > 1 else 0.0
    s = float(np.std(fs, ddof=1)) if n > 1 else 0.0
    out = {"n": n, "fs_below_1": k, "p_fs_below_1": p, "se": math.sqrt(p * (1 - p) / n),
           "wilson95": list(wilson_interval(k, n)),
           "fs_mean": float(fs.mean()), "fs_std": s, "ln_fs_mean": float(ln.mean()),
           "ln_fs_std": s_ln,
           "reliability_index": float(ln.mean()) / s_ln if s_ln > 0 else None,
           "reliability_index_normal": (float(fs.mean()) - 1) / s if s > 0 else None,
           "censored": int(sum(_get(r, "fs_bound") not in (0, None) for r in fs_rows)),
           "static_solves_mean": float(np.mean([float(_get(r, "fs_static_solves") or 0)
                                                for r in fs_rows])),
           "wall_time_mean": float(np.mean([float((r.get("fs") or {}).get("wall_time") or 0)
                                            for r in fs_rows]))}
    both = [r for r in fs_rows if _get(r, "failed") is not None]
    if both:
        differ = [r for r in both if bool(_get(r, "failed")) != bool(_get(r, "fs_below_1"))]
        out["agreement"] = {
            "n": len(both), "agree": len(both) - len(differ),
            "fraction": (len(both) - len(differ)) / len(both),
            "disagree": [{"index": r["index"], "seed": r["seed"],
                          "factor_of_safety": float(_get(r, "factor_of_safety")),
                          "failed": bool(_get(r, "failed")),
                          "max_displacement": _get(r, "max_displacement")} for r in differ]}
        fs_b = [float(_get(r, "factor_of_safety")) for r in both]
        below_b = [bool(_get(r, "fs_below_1")) for r in both]
        failed_b = [bool(_get(r, "failed")) for r in both]
        out["agreement"]["outside_margin"] = agreement_outside(fs_b, below_b, failed_b)
        out["fragility"] = fragility_statistics(fs_b, below_b, failed_b)
    return out


def fs_text(s: dict | None) -> str:
    """One sentence of FS statistics for the campaign summary ("" without FS)."""
    if not s:
        return ""
    lo, hi = s["wilson95"]
    beta = s["reliability_index"]
    txt = (f"FS mean {s['fs_mean']:.3f} (std {s['fs_std']:.3f}); P(FS < 1) = "
           f"{s['p_fs_below_1']:.3f} +- {s['se']:.3f} (Wilson 95 % [{lo:.2f}, {hi:.2f}]), "
           f"reliability index {'n/a' if beta is None else f'{beta:.2f}'}")
    if s["censored"]:
        txt += f", {s['censored']} censored (FS > 10 or < 0.1)"
    f = s.get("fragility")
    if f and f["split"]["failures"]:
        sp, fit = f["split"], f.get("probit")
        txt += (f"; of the {sp['failures']} failures {sp['progressive']} progressive (FS >= 1) "
                f"and {sp['strength_limited']} strength-limited (FS < 1)")
        if fit:
            lo, hi = (("-" if v is None else f"{v:.3f}") for v in fit["fs50_interval95"])
            txt += f"; fragility: P(failure) = 0.5 at FS {fit['fs50']:.3f} [{lo}, {hi}]"
    a = s.get("agreement")
    if a:
        txt += (f"; 'FS < 1' and MPM 'failed' agree in {a['agree']} of {a['n']} "
                f"({100 * a['fraction']:.0f} %)")
        if a["disagree"]:
            txt += ": differ " + ", ".join(
                f"#{d['index']} (FS {d['factor_of_safety']:.3f}, failed {d['failed']})"
                for d in a["disagree"][:10])
    return txt


def plot_factor_of_safety(path: Path, cases, stats: dict, records: Sequence[dict]) -> Path:
    """Histogram of FS per case (FS = 1 marked; legend with P(FS < 1) and its interval);
    with MPM runs, FS against the MPM's maximum displacement, failed realizations red."""
    plt = _plt()
    # a run stopped once decided has ``failed`` but no measures to rest (no displacement)
    have_mpm = any(_get(r, "max_displacement") is not None
                   and _get(r, "factor_of_safety") is not None for r in records)
    fig, axes = plt.subplots(1, 2 if have_mpm else 1, figsize=(12 if have_mpm else 7, 4.2),
                             squeeze=False)
    ax = axes[0, 0]
    for c in cases:
        fs = [float(_get(r, "factor_of_safety")) for r in records if r["case"] == c.name
              and r["status"] == "ok" and _get(r, "factor_of_safety") is not None]
        s = (stats.get(c.name) or {}).get("fs")
        if not fs or not s:
            continue
        lo, hi = s["wilson95"]
        ax.hist(fs, bins=max(5, min(40, len(fs) // 5)), histtype="step", lw=1.5,
                label=f"{c.label}: P(FS<1) = {s['p_fs_below_1']:.2f} [{lo:.2f}, {hi:.2f}], "
                      f"N = {s['n']}")
    ax.axvline(1.0, color="k", ls="--", lw=1)
    ax.set_xlabel("factor of safety (strength reduction)")
    ax.set_ylabel("realizations")
    ax.legend(fontsize=7)
    if have_mpm:
        ax = axes[0, 1]
        for failed, col, lab in ((False, "tab:blue", "MPM: not failed"),
                                 (True, "tab:red", "MPM: failed")):
            pts = [(float(_get(r, "factor_of_safety")), float(_get(r, "max_displacement")))
                   for r in records if r["status"] == "ok"
                   and _get(r, "max_displacement") is not None
                   and _get(r, "factor_of_safety") is not None
                   and bool(_get(r, "failed")) == failed]
            if pts:
                a = np.array(pts)
                ax.plot(a[:, 0], a[:, 1], "o", ms=4, color=col, label=lab)
        ax.axvline(1.0, color="k", ls="--", lw=1)
        ax.set_yscale("log")
        ax.set_xlabel("factor of safety")
        ax.set_ylabel("MPM max displacement (m)")
        ax.legend(fontsize=8)
    fig.suptitle("Factor of safety per realization", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_fragility(path: Path, cases, stats: dict) -> Path | None:
    """Fragility curve P(failure | FS) per case: the binned fractions with their Wilson
    95 % intervals (points at the bin's mean FS, horizontal bar its FS range), the fitted
    probit curve, FS50 with its profile-likelihood interval (shaded); FS = 1 dashed.
    None when no case has an FS and an MPM run."""
    frag = [(k, c, (stats.get(c.name) or {}).get("fs", {}).get("fragility"))
            for k, c in enumerate(cases)]
    frag = [(k, c, f) for k, c, f in frag if f and f["n"]]
    if not frag:
        return None
    plt = _plt()
    fig, ax = plt.subplots(figsize=(8, 4.6))
    lo_all = min(b["fs_min"] for _, _, f in frag for b in f["binned"])
    hi_all = max(b["fs_max"] for _, _, f in frag for b in f["binned"])
    x = np.linspace(lo_all - 0.05, hi_all + 0.05, 300)
    for k, c, f in frag:
        col = f"C{k}"
        b = f["binned"]
        xm = np.array([v["fs_mean"] for v in b])
        p = np.array([v["p"] for v in b])
        lo = np.array([v["wilson95"][0] for v in b])
        hi = np.array([v["wilson95"][1] for v in b])
        xerr = np.array([[v["fs_mean"] - v["fs_min"] for v in b],
                         [v["fs_max"] - v["fs_mean"] for v in b]])
        fit = f.get("probit")
        lab = f"{c.label} (N = {f['n']})"
        if fit:
            a, z = fit["fs50_interval95"]
            lab += (f": FS50 = {fit['fs50']:.3f} [{'-' if a is None else f'{a:.3f}'}, "
                    f"{'-' if z is None else f'{z:.3f}'}]")
            ax.plot(x, probit_curve(fit, x), color=col, lw=1.5)
            ax.axvspan(x[0] if a is None else a, x[-1] if z is None else z, color=col,
                       alpha=0.12)
        ax.errorbar(xm, p, yerr=[p - lo, hi - p], xerr=xerr, fmt="o", ms=5, color=col,
                    capsize=3, lw=1, label=lab)
    ax.axvline(1.0, color="k", ls="--", lw=1)
    ax.set_xlabel("factor of safety (strength reduction at peak strength)")
    ax.set_ylabel("P(failure | FS) (MPM)")
    ax.set_ylim(-0.03, 1.03)
    ax.legend(fontsize=8, title="binned (Wilson 95 %), probit fit; FS50 [profile 95 %]",
              title_fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_fs_scatter(path: Path, cases, records: Sequence[dict]) -> Path | None:
    """FS against sliding area and against run-out per realization run to rest (marker per
    case; failed filled, stood hollow); FS = 1 dashed.  None without such realizations."""
    keys = ("sliding_area", "runout_distance")
    rows = [r for r in records if r["status"] == "ok" and _get(r, "factor_of_safety") is not None
            and all(_get(r, k) is not None for k in keys)]
    if not rows:
        return None
    plt = _plt()
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.2))
    for ax, key in zip(axes, keys):
        for k, c in enumerate(cases):
            for failed in (True, False):
                pts = np.array([(float(_get(r, "factor_of_safety")), float(_get(r, key)))
                                for r in rows if r["case"] == c.name
                                and bool(_get(r, "failed")) == failed]).reshape(-1, 2)
                if len(pts):
                    ax.plot(pts[:, 0], pts[:, 1], "o", ms=5, color=f"C{k}",
                            mfc=f"C{k}" if failed else "none",
                            label=f"{c.label}: {'failed' if failed else 'stood'}")
        ax.axvline(1.0, color="k", ls="--", lw=1)
        ax.set_xlabel("factor of safety")
        ax.set_ylabel(table.axis_label(key))
        ax.legend(fontsize=7)
    fig.suptitle("Factor of safety against the MPM's sliding area and run-out "
                 "(realizations run to rest)", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
