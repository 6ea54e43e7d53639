"""The paragraphs ``fem-rmpm mc`` prints at the end of a campaign: per case for a case
campaign (:func:`summary_text`), the estimate and its levels for a response campaign
(:func:`subset_summary_text`)."""
from __future__ import annotations

from typing import TYPE_CHECKING

from fem_rmpm.campaign.factor_of_safety import fs_text
from fem_rmpm.measures import table as measure_table

if TYPE_CHECKING:
    from fem_rmpm.campaign.case_campaign import CampaignResult
    from fem_rmpm.campaign.subset_runner import SubsetCampaignResult

__all__ = ["summary_text", "subset_summary_text"]

def summary_text(res: CampaignResult) -> str:
    """The final one-paragraph-per-case summary printed by ``fem-rmpm mc``."""
    lines = []
    rph = res.realizations_per_hour
    head = (f"Campaign in {res.out}: {sum(res.realizations.values())} realizations in "
            f"{len(res.cases)} case(s); ")
    if res.computed or res.lost:
        head += (f"this run computed {res.computed} (skipped {res.skipped} already "
                 f"finished) on {res.workers} in {res.wall_time:.1f} s"
                 + (f" ({rph:.0f} realizations/hour)" if rph else "") + ".")
    else:
        head += f"all {res.skipped} had finished before; tables and figures rebuilt."
    lines.append(head)
    for c in res.cases:
        s = res.stats[c.name]
        head = f"  {c.label}: " + ("deterministic (no random field), 1 realization; "
                                   if c.deterministic else f"N = {s['ok']} ok")
        if not c.deterministic:
            head += (f", {s['numerical_failures']} failed numerically" if
                     s["numerical_failures"] else "") + "; "
        if s["ok"] == 0:
            lines.append(head + "no realization finished"
                         + (f" (first error: {s['errors'][0]['error']})" if s["errors"] else ""))
            continue
        if not s.get("mpm_runs"):                      # --fs-only
            lines.append(head + fs_text(s.get("fs")))
            continue
        if c.deterministic:
            lines.append(head + f"failed = {bool(s['slope_failures'])}, " + ", ".join(
                measure_table.value_text(k, s[k]["mean"]) for k in
                measure_table.headline() + measure_table.mechanism() if k in s)
                         + (f"; {fs_text(s['fs'])}" if s.get("fs") else ""))
            continue
        lo, hi = s["wilson95"]
        txt = (f"P(failure) = {s['p_failure']:.3f} +- {s['se']:.3f} (SE sqrt(p(1-p)/N); "
               f"Wilson 95 % [{lo:.2f}, {hi:.2f}])")
        if s.get("measure_runs", s["ok"]) < s["mpm_runs"]:    # [montecarlo] runs_to_rest
            txt += f"; measures over the {s['measure_runs']} run(s) to rest"
        for key in measure_table.headline():
            d = s[key]
            txt += "" if d["mean"] is None else (
                f"; {measure_table.label(key)} mean {d['mean']:.2f} +- {d['se']:.2f} "
                f"{measure_table.unit(key)} "
                f"(5/50/95 %: {d['q05']:.2f}/{d['q50']:.2f}/{d['q95']:.2f})")
        mech = [k for k in measure_table.mechanism() if k in s]
        if mech:
            txt += "; mean " + ", ".join(measure_table.value_text(k, s[k]["mean"])
                                         for k in mech)
        conv = s.get("convergence")
        if conv and s["ok"] >= 4:
            idx = sorted({s["ok"] // 4 - 1, s["ok"] // 2 - 1, s["ok"] - 1})
            txt += ("; with N = " + ", ".join(str(conv["n"][i]) for i in idx)
                    + ": P(failure) " + ", ".join(f"{conv['p_failure'][i]:.2f}" for i in idx)
                    + ("" if len(conv["mean_runout"]) < len(conv["n"]) else ", mean run-out "
                       + ", ".join(f"{conv['mean_runout'][i]:.1f}" for i in idx) + " m"))
        lines.append(head + txt + (f"; {fs_text(s['fs'])}" if s.get("fs") else ""))
        if s["numerical_failures"]:
            e = s["errors"][0]
            lines.append(f"    first failed realization: #{e['index']} (seed {e['seed']}): "
                         f"{e['error']}")
    if res.lost:
        lines.append(f"  {len(res.lost)} realization(s) LOST (their workers died; no record): "
                     + "; ".join(res.lost[:3]) + " -- re-run the same command to compute them")
    figs = ", ".join(p.name for p in res.figures)
    lines.append("Output: results.csv, summary.json, records/"
                 + (", vtk/" if (res.out / "vtk").exists() else "")
                 + (f", {figs}" if figs else "") + f" in {res.out}")
    return "\n".join(lines)


def subset_summary_text(res: SubsetCampaignResult) -> str:
    """The paragraph printed by ``fem-rmpm mc --method subset``."""
    head = (f"Subset simulation in {res.out}: this run computed {res.computed} sample(s) "
            f"(reused {res.reused} records) on {res.workers} in {res.wall_time:.1f} s.")
    if res.result is None:
        return (head + f"\n  {len(res.lost)} sample(s) LOST (their workers died; no record): "
                + "; ".join(res.lost[:3]) + " -- re-run the same command to finish")
    r = res.result
    th = ", ".join(f"{-b if res.response.below else b:.4g}" for b in r.thresholds[:-1])
    lines = [head, f"  P({res.response.describe()}) = {r.probability:.3g}, COV {r.cov:.2f} "
                   f"(Au & Beck, with chain correlation) after {len(r.levels)} level(s), "
                   f"{r.total_runs} runs" + (f", {r.failed_runs} failed numerically"
                                             if r.failed_runs else "")
                   + (f"; intermediate thresholds {th}" if th else "")]
    if r.crude_equivalent_runs:
        lines.append(f"  crude Monte Carlo would need {r.crude_equivalent_runs:.0f} runs for "
                     f"the same COV ({r.crude_equivalent_runs / r.total_runs:.1f}x)")
    lines.extend(f"  WARNING: {note}" for note in r.notes)
    lines.append("Output: summary.json, samples.csv, records/"
                 + "".join(f", {p.name}" for p in res.figures) + f" in {res.out}")
    return "\n".join(lines)
