"""The risk study of ``meshes/slope_risk.toml``: from a crude Monte Carlo campaign
of the four cases (homogeneous, xi = 1, 12, 48), the figures and the table a risk analyst
reads.

Run the campaign (resumable: re-run the same command after a kill and it goes on where
it stopped), then this script on its directory::

    fem-rmpm mc meshes/slope_risk.toml -n 280 --out runs/risk
    python validation/risk_study.py runs/risk [--fs runs/risk_fs] [--decided DIR]

The scene sets ``[montecarlo] runs_to_rest = 60``: realizations 0..59 of each case run to
rest, the others stop once their failure is decided (``fem_rmpm.campaign.decide``).
P(failure) is over all N; every measure (sliding area, run-out, retrogression, modes,
failure-surface height, blocks) is over the runs to rest with index < 60, whose failures
are a random subsample of all failures (the realizations are iid); the unconditional
exceedance is P(failure) x the exceedance given failure.  Each n is stated.

``--run N`` runs (or resumes) the campaign first with ``N`` realizations per random case.
``--import-from SRC`` first copies the records of another campaign directory of the same
scene (checked case by case as for resuming; e.g. runs made with ``--set grid.cell=0.25``,
the file's own cell, or a decided-only campaign) into the campaign directory,
so that ``fem-rmpm mc`` then computes only the rest.
``--decided DIR``: a campaign of the same scene with ``--set montecarlo.runs_to_rest=0``
(every run stopped once decided): its ``failed`` against this campaign's runs to rest,
realization by realization (the check that stopping once decided changes no outcome).
``--mesh DIR``: the mesh check, a campaign of the first realizations of a case on a finer
mesh (``fem-rmpm mc meshes/slope_risk.toml -n 20 --case xi=48 --set grid.cell=0.25 --out
DIR``); realization i has the same random field on both meshes because the scene fixes
the field's rectangle (``[random_field] box``; without it the rectangle follows the soil
cells of each mesh and a seed draws an unrelated field): P(failure) and sliding area on
each, pair by pair.  ``validation/risk_mesh.py`` measures the mesh dependence as a number,
the shift of each realization's critical strength factor.
``--fs DIR``: a factor-of-safety campaign of the same scene and seed
(``fem-rmpm mc meshes/slope_risk.toml --fs-only -n M --out DIR``; realization i has the same
random field in both, the seeds being ``SeedSequence([campaign_seed, i])``): P(FS < 1) per
case and its agreement with the MPM outcome, realization by realization.

Written into the campaign directory (so ``report.html``, rewritten at the end, shows them):
``risk_study.json`` (every number below), ``risk_study.md`` (the table of the risk-study page),
``risk_exceedance.png`` (exceedance curves of sliding area, run-out and retrogression,
unconditional and given failure), ``risk_modes.png`` (failure modes and depth of the
failure surface per case).

Per case: P(failure) with its standard error sqrt(p (1 - p) / N) and Wilson 95 % interval;
mean, coefficient of variation and 5/50/95 % quantiles of sliding area, run-out and
retrogression given failure; the failure-mode split; the failure-surface height above the
base given failure; the intact-block count at the mechanism time.

**Failure mode** of a failed realization (``failed``: a counted point moved more than
``failure_displacement``), a documented rule on its recorded measures, with ``H`` = 5 m
the layer's normal thickness:

* ``toe slump``: ``retrogression_distance <= 2 H`` -- the failure stays within two layer
  thicknesses behind the crest of the toe cut;
* ``translational``: otherwise, if ``sliding_area_early >= 0.5 sliding_area`` -- at the
  mechanism time (3 s into the large-deformation phase) at least half of the final
  sliding mass was already moving: one slab slid on its base;
* ``retrogressive``: otherwise -- the failure grew back up the slope by successive
  slides after the first one.

**Failure above the base**: ``slip_surface_height`` (the mean height above the bedrock of
the lowest stayed point under the sliding mass, over the columns that slid) above ``H / 6``
(0.83 m, half way to the paper's "about a third of the depth" for xi = 48).
"""
from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np

from fem_rmpm.campaign import read_results, wilson_interval
from fem_rmpm.campaign.decide import in_measure_sample, is_decided

LAYER_THICKNESS = 5.0                   # m, normal to the bedrock
TOE_SLUMP_RETROGRESSION = 2 * LAYER_THICKNESS   # m
TRANSLATIONAL_EARLY_FRACTION = 0.5
ABOVE_BASE_HEIGHT = LAYER_THICKNESS / 6        # m
MODES = ("toe slump", "translational", "retrogressive")
SHORT = {"sliding_area": "area", "runout_distance": "run-out",
         "retrogression_distance": "retrogression"}
MEASURES = (("sliding_area", "sliding area (m2 per m)"),
            ("runout_distance", "run-out distance (m)"),
            ("retrogression_distance", "retrogression distance (m)"))


def failure_mode(row: dict) -> str | None:
    """The failure mode of a row of ``results.csv`` (None when it did not fail)."""
    if not row.get("failed"):
        return None
    if (row.get("retrogression_distance") or 0.0) <= TOE_SLUMP_RETROGRESSION:
        return "toe slump"
    early = row.get("sliding_area_early") or 0.0
    if early >= TRANSLATIONAL_EARLY_FRACTION * row["sliding_area"]:
        return "translational"
    return "retrogressive"


def _describe(x: np.ndarray) -> dict:
    if len(x) == 0:
        return {"n": 0}
    mean = float(x.mean())
    sd = float(x.std(ddof=1)) if len(x) > 1 else 0.0
    q = np.quantile(x, [0.05, 0.5, 0.95])
    return {"n": int(len(x)), "mean": mean, "se": sd / math.sqrt(len(x)),
            "cov": sd / mean if mean > 0 else None, "min": float(x.min()), "max": float(x.max()),
            "q05": float(q[0]), "q50": float(q[1]), "q95": float(q[2])}


def case_summary(rows: list[dict], runs_to_rest: int | None = None) -> dict:
    """Everything the study states about one case, from its ``ok`` rows: P(failure) over
    all of them (runs stopped once decided included), the measures over the *measure
    sample*, the runs to rest with index < ``runs_to_rest`` (None: all;
    ``fem_rmpm.campaign.decide``): ``n_measure`` runs, ``failed_measure`` failures."""
    ok = [r for r in rows if r.get("status") == "ok" and r.get("failed") is not None]
    n, k = len(ok), sum(1 for r in ok if r["failed"])
    sample = [r for r in ok if in_measure_sample(r, runs_to_rest)]
    failed = [r for r in sample if r["failed"]]
    p = k / n if n else float("nan")
    out = {"n": n, "numerical_failures": len(rows) - n, "failed": k, "p_failure": p,
           "se": math.sqrt(p * (1 - p) / n) if n else None,
           "wilson95": list(wilson_interval(k, n)) if n else None,
           "decided": sum(1 for r in ok if is_decided(r)), "runs_to_rest": runs_to_rest,
           "n_measure": len(sample), "failed_measure": len(failed),
           "frozen_points": int(sum(r.get("frozen_points") or 0 for r in ok)),
           "stray_points_max": int(max((r.get("excluded_stray_points") or 0 for r in sample),
                                       default=0))}
    for key, _ in MEASURES:
        out[key] = {"unconditional": _describe(np.array([r[key] for r in sample], float)),
                    "given_failure": _describe(np.array([r[key] for r in failed], float))}
    modes = [failure_mode(r) for r in failed]
    out["modes"] = {m: modes.count(m) for m in MODES}
    h = np.array([r["slip_surface_height"] for r in failed], float)
    out["slip_surface_height"] = _describe(h)
    out["above_base"] = int((h > ABOVE_BASE_HEIGHT).sum())
    out["intact_blocks"] = _describe(np.array([r.get("intact_blocks") or 0 for r in failed], float))
    rest = [r.get("time_to_rest") for r in sample]
    out["not_at_rest"] = sum(1 for t in rest if t is None)
    out["time_to_rest_max"] = max((t for t in rest if t is not None), default=None)
    return out


def decided_check(rows: list[dict], decided_rows: list[dict]) -> dict | None:
    """A campaign of runs stopped once decided (``runs_to_rest = 0``) against the runs to
    rest ``rows`` of this one (its measure sample), realization by realization (same index
    = same field): how many pairs, how many agree on ``failed``, and the indices that do
    not."""
    dec = {r["index"]: r for r in decided_rows
           if r.get("status") == "ok" and r.get("failed") is not None}
    pairs = [(r, dec[r["index"]]) for r in rows if r["index"] in dec and not is_decided(r)
             and r.get("status") == "ok" and r.get("failed") is not None]
    if not pairs:
        return None
    bad = [a["index"] for a, b in pairs if bool(a["failed"]) != bool(b["failed"])]
    times = [b["decided_time"] for a, b in pairs if is_decided(b)]
    return {"pairs": len(pairs), "agree": len(pairs) - len(bad), "disagree": bad,
            "decided": len(times), "decided_time_max": max(times, default=None)}


def fs_summary(mpm_rows: list[dict], fs_rows: list[dict]) -> dict | None:
    """P(FS < 1) and its agreement with the MPM outcome over the realizations in both."""
    fs = {r["index"]: r for r in fs_rows if r.get("status") == "ok"
          and r.get("factor_of_safety") is not None}
    if not fs:
        return None
    n = len(fs)
    below = [bool(r.get("fs_below_1")) for r in fs.values()]
    k = sum(below)
    p = k / n
    both = [(bool(fs[r["index"]].get("fs_below_1")), bool(r["failed"])) for r in mpm_rows
            if r["index"] in fs and r.get("failed") is not None]
    f = np.array([r["factor_of_safety"] for r in fs.values()], float)
    return {"n": n, "fs_below_1": k, "p_fs_below_1": p, "se": math.sqrt(p * (1 - p) / n),
            "wilson95": list(wilson_interval(k, n)), "fs": _describe(f),
            "paired": len(both),
            "agree": sum(1 for a, b in both if a == b),
            "fs_below_1_mpm_stands": sum(1 for a, b in both if a and not b),
            "fs_above_1_mpm_fails": sum(1 for a, b in both if b and not a)}


def mesh_summary(coarse_rows: list[dict], fine_rows: list[dict]) -> dict | None:
    """The same realizations (same index, hence the same random field when the scene fixes
    ``[random_field] box``) on the scene's mesh and on a finer one: P(failure) on
    each over the pairs, how many agree on failed / stood, and the sliding area given
    failure (mean on each; mean absolute difference where both failed)."""
    fine = {r["index"]: r for r in fine_rows
            if r.get("status") == "ok" and r.get("failed") is not None}
    pairs = [(r, fine[r["index"]]) for r in coarse_rows
             if r["index"] in fine and r.get("status") == "ok" and r.get("failed") is not None]
    if not pairs:
        return None
    n = len(pairs)
    out: dict = {"n": n, "agree": sum(1 for a, b in pairs if bool(a["failed"]) == bool(b["failed"]))}
    for side, i in (("coarse", 0), ("fine", 1)):
        k = sum(1 for p in pairs if p[i]["failed"])
        area = np.array([p[i]["sliding_area"] for p in pairs if p[i]["failed"]], float)
        out[side] = {"failed": k, "p_failure": k / n, "wilson95": list(wilson_interval(k, n)),
                     "sliding_area_given_failure": _describe(area)}
    both = [(a["sliding_area"], b["sliding_area"]) for a, b in pairs if a["failed"] and b["failed"]]
    out["both_failed"] = len(both)
    out["area_abs_difference_mean"] = (float(np.mean([abs(a - b) for a, b in both]))
                                       if both else None)
    return out


def _by_case(rows: list[dict]) -> dict[str, list[dict]]:
    out: dict[str, list[dict]] = {}
    for r in rows:
        out.setdefault(r["case"], []).append(r)
    return out


def _label(case: str) -> str:
    """"xi12" (the case's directory name) or "xi=12" -> "xi = 12"."""
    return "xi = " + case[2:].lstrip("=") if case.startswith("xi") else case


def _exceedance(x: np.ndarray, scale: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Step curve (x, P(X > x)) of a sample, scaled by ``scale`` (from x = 0)."""
    x = np.sort(x)
    p = 1.0 - np.arange(1, len(x) + 1) / len(x)
    return np.r_[0.0, x], scale * np.r_[1.0, p]


def plot_exceedance(path: Path, sample: dict[str, list[dict]], summary: dict[str, dict]) -> Path:
    """P(X > x) of the three measures, given failure (bottom: over the failures of the
    measure sample ``sample``, the runs to rest per case) and over all realizations (top:
    P(failure) of the case's summary, from all N, x the curve given failure; exact for x
    above every standing realization's value)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(2, 3, figsize=(14, 8), constrained_layout=True)
    styles = ["-", "--", "-.", ":"]
    for j, (key, unit) in enumerate(MEASURES):
        for ci, (case, rows) in enumerate(sample.items()):
            s = summary[case]
            failed = np.array([r[key] for r in rows if r.get("status") == "ok"
                               and r.get("failed")], float)
            if len(failed) == 0:
                continue
            kw = dict(where="post", ls=styles[ci % 4], lw=1.6, color=f"C{ci}")
            axes[0, j].step(*_exceedance(failed, s["p_failure"]), **kw,
                            label=f"{_label(case)} (P = {s['p_failure']:.3f}, N = {s['n']})")
            axes[1, j].step(*_exceedance(failed), **kw,
                            label=f"{_label(case)} (n = {len(failed)} failures run to rest)")
        for i, cond in enumerate(("all realizations", "given failure")):
            ax = axes[i, j]
            ax.set_xlabel(unit)
            ax.set_ylabel(f"P({SHORT[key]} > x), {cond}")
            ax.set_ylim(-0.02, 1.02)
            ax.grid(alpha=0.3)
            ax.legend(fontsize=8)
    fig.suptitle("slope_risk: exceedance curves per case (top: P(failure) x bottom)")
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_modes(path: Path, summary: dict[str, dict], cases: dict[str, list[dict]]) -> Path:
    """Failure modes per case (stacked fractions of the measure sample ``cases``, the runs
    to rest) and the failure-surface height above the base given failure."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(13, 4.8), constrained_layout=True)
    names = list(summary)
    bottom = np.zeros(len(names))
    for m, colour in zip(MODES, ("tab:orange", "tab:blue", "tab:red")):
        frac = np.array([summary[c]["modes"][m] / max(1, summary[c]["n_measure"]) for c in names])
        a1.bar([_label(c) for c in names], frac, bottom=bottom, color=colour, label=m)
        bottom += frac
    a1.set_ylabel("fraction of the realizations run to rest")
    a1.set_ylim(0, 1)
    a1.set_title("failure mode (rule in validation/risk_study.py); white: stands")
    a1.legend(fontsize=8)
    data = [[r["slip_surface_height"] for r in cases[c] if r.get("failed")] for c in names]
    keep = [i for i, d in enumerate(data) if d]
    if keep:
        a2.boxplot([data[i] for i in keep])
        a2.set_xticks(range(1, len(keep) + 1), [_label(names[i]) for i in keep])
    a2.axhline(ABOVE_BASE_HEIGHT, color="grey", ls="--", lw=1,
               label=f"H / 6 = {ABOVE_BASE_HEIGHT:.2f} m")
    a2.axhline(LAYER_THICKNESS / 3, color="grey", ls=":", lw=1, label="H / 3 (paper, xi = 48)")
    a2.set_ylabel("failure-surface height above the base (m)")
    a2.set_title("depth of the failure surface, given failure")
    a2.legend(fontsize=8)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _pct(x: dict | None, key: str = "mean", fmt: str = "{:.1f}") -> str:
    return fmt.format(x[key]) if x and x.get(key) is not None else "-"


def markdown_table(summary: dict[str, dict], fs: dict[str, dict | None]) -> str:
    """The per-case table of the risk-study page: P(failure) over all N realizations; the measures over
    the n realizations run to rest (the failures among them: the sample given failure)."""
    head = ("| case | N | P(failure) | SE | Wilson 95 % | P(FS < 1) (N) | run to rest: n "
            "(failed) | sliding area given failure: mean (COV) | run-out given failure: mean "
            "(COV) | retrogression given failure: mean | toe slump / translational / "
            "retrogressive | failure surface above base: median m (n > H/6) | intact blocks |")
    lines = [head, "|" + "---|" * 13]
    for c, s in summary.items():
        a, ro, re_ = (s[k]["given_failure"] for k, _ in MEASURES)
        f = fs.get(c)
        pfs = (f"{f['p_fs_below_1']:.3f} ({f['n']})" if f else "-")
        w = s["wilson95"] or [float("nan")] * 2
        lines.append(
            f"| {_label(c)} | {s['n']} | {s['p_failure']:.3f} | {s['se']:.3f} | "
            f"[{w[0]:.3f}, {w[1]:.3f}] | {pfs} | {s['n_measure']} ({s['failed_measure']}) | "
            f"{_pct(a)} m2 ({_pct(a, 'cov', '{:.2f}')}) | "
            f"{_pct(ro)} m ({_pct(ro, 'cov', '{:.2f}')}) | {_pct(re_)} m | "
            f"{' / '.join(str(s['modes'][m]) for m in MODES)} | "
            f"{_pct(s['slip_surface_height'], 'q50', '{:.2f}')} ({s['above_base']}) | "
            f"{_pct(s['intact_blocks'], 'mean', '{:.1f}')} |")
    return "\n".join(lines) + "\n"


def cpu_by_run(campaign: Path) -> dict:
    """CPU seconds of the records, split into runs to rest and runs stopped once decided,
    with their counts (from ``records/``: ``results.csv`` holds no times)."""
    out = {"to_rest": {"runs": 0, "cpu_s": 0.0}, "decided": {"runs": 0, "cpu_s": 0.0}}
    for p in (campaign / "records").rglob("realization_*.json"):
        r = json.loads(p.read_text())
        d = out["decided" if is_decided(r) else "to_rest"]
        d["runs"] += 1
        d["cpu_s"] += float(r.get("cpu_time") or 0.0)
    return out


def study(campaign: Path, fs_dir: Path | None = None, report: bool = True,
          mesh_dir: Path | None = None, decided_dir: Path | None = None) -> dict:
    """Read the campaign (and the FS, finer-mesh and decided-only campaigns), write the
    study's files, return its dict."""
    rows = read_results(campaign / "results.csv")
    camp = json.loads((campaign / "summary.json").read_text())
    k_rest = camp.get("runs_to_rest")
    cases = _by_case(rows)
    sample = {c: [r for r in rs if in_measure_sample(r, k_rest)] for c, rs in cases.items()}
    summary = {c: case_summary(r, k_rest) for c, r in cases.items()}
    fs_cases = _by_case(read_results(fs_dir / "results.csv")) if fs_dir else {}
    fs = {c: fs_summary(cases[c], fs_cases.get(c, [])) for c in cases}
    mesh_cases = _by_case(read_results(mesh_dir / "results.csv")) if mesh_dir else {}
    mesh = {c: mesh_summary(sample[c], r) for c, r in mesh_cases.items() if c in cases}
    dec_cases = _by_case(read_results(decided_dir / "results.csv")) if decided_dir else {}
    out = {"campaign": str(campaign), "fs_campaign": str(fs_dir) if fs_dir else None,
           "mesh_campaign": str(mesh_dir) if mesh_dir else None, "mesh_check": mesh,
           "decided_campaign": str(decided_dir) if decided_dir else None,
           "decided_check": {c: decided_check(sample[c], r) for c, r in dec_cases.items()
                             if c in cases},
           "decision_check": camp.get("decision_check"), "runs_to_rest": k_rest,
           "rules": {"toe_slump_retrogression_m": TOE_SLUMP_RETROGRESSION,
                     "translational_early_fraction": TRANSLATIONAL_EARLY_FRACTION,
                     "above_base_height_m": ABOVE_BASE_HEIGHT},
           "cpu_time_total_s": (camp.get("realization_cpu_time") or {}).get("total"),
           "cpu_by_run": cpu_by_run(campaign),
           "cases": summary, "factor_of_safety": fs}
    (campaign / "risk_study.json").write_text(json.dumps(out, indent=1))
    (campaign / "risk_study.md").write_text(markdown_table(summary, fs))
    plot_exceedance(campaign / "risk_exceedance.png", sample, summary)
    plot_modes(campaign / "risk_modes.png", summary, sample)
    if report:
        from fem_rmpm.campaign.report import write_report
        write_report(campaign)
    return out


def import_from(src: Path, campaign: Path, scene_path: str) -> dict[str, int]:
    """Copy the records of campaign ``src`` into ``campaign``, the directory of
    ``fem-rmpm mc SCENE --out campaign`` (its cases from the scene's ``[montecarlo]
    cases``), for the cases both have: ``fem_rmpm.campaign.store.import_records`` checks
    that each has the same scene (the identity of resuming) and campaign seed and each
    record the seed of its index.  Then the ``mc`` command computes only the rest."""
    from fem_rmpm.campaign import parse_case
    from fem_rmpm.campaign.store import campaign_doc, import_records
    from fem_rmpm.cli import campaign_cases
    from fem_rmpm.scene import load_scene
    scene = load_scene(scene_path)
    cases = [parse_case(c, scene) for c in campaign_cases(scene, scene_path)]
    return import_records(src, campaign, campaign_doc(cases, scene.montecarlo.seed), cases)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("campaign", type=Path, help="campaign directory (fem-rmpm mc --out)")
    ap.add_argument("--fs", type=Path, default=None, help="FS campaign directory (--fs-only)")
    ap.add_argument("--mesh", type=Path, default=None,
                    help="the same realizations on a finer mesh (fem-rmpm mc ... -n 20 --case "
                         "xi=48 --set grid.cell=0.25 --out DIR): the mesh check")
    ap.add_argument("--run", type=int, default=None, metavar="N",
                    help="run or resume the campaign first with N realizations per case")
    ap.add_argument("--decided", type=Path, default=None,
                    help="a campaign of the same scene with runs_to_rest = 0 (every run "
                         "stopped once decided): its failed against this one's runs to rest")
    ap.add_argument("--import-from", type=Path, default=None, metavar="SRC",
                    help="first copy the records of campaign SRC (same scene per case, "
                         "checked) into the campaign directory (see import_from)")
    ap.add_argument("--scene", default="meshes/slope_risk.toml")
    a = ap.parse_args(argv)
    if a.import_from is not None:
        print(f"imported from {a.import_from}: {import_from(a.import_from, a.campaign, a.scene)}")
        if a.run is None:
            return 0
    if a.run is not None:
        subprocess.run([sys.executable, "-m", "fem_rmpm.cli", "mc", a.scene, "-n", str(a.run),
                        "--out", str(a.campaign)], check=True)
    out = study(a.campaign, a.fs, mesh_dir=a.mesh, decided_dir=a.decided)
    print((a.campaign / "risk_study.md").read_text())
    print(f"measures from the runs to rest with index < {out['runs_to_rest']}; "
          f"decision rule on the runs to rest: {out['decision_check']}")
    for c, d in out["decided_check"].items():
        print(f"decided-only campaign {c}: {d}")
    print(f"CPU by run: {out['cpu_by_run']}")
    for c, m in (out["mesh_check"] or {}).items():
        if m:
            ca, fa = (m[k]["sliding_area_given_failure"] for k in ("coarse", "fine"))
            print(f"mesh check {c}: N = {m['n']} pairs; P(failure) {m['coarse']['p_failure']:.2f}"
                  f" vs {m['fine']['p_failure']:.2f} (agree {m['agree']}); area given failure"
                  f" {_pct(ca)} vs {_pct(fa)} m2; |difference| where both failed"
                  f" {m['area_abs_difference_mean'] or float('nan'):.1f} m2 ({m['both_failed']})")
    cpu = out["cpu_time_total_s"]
    if cpu:
        print(f"CPU of the MPM realizations: {cpu:.0f} s = {cpu / 3600:.2f} core-hours")
    return 0


if __name__ == "__main__":
    sys.exit(main())
