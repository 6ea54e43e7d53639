"""The campaign report: one self-contained HTML page, ``report.html``.

``fem-rmpm report DIR`` (and ``fem-rmpm mc`` at the end of a campaign) reads what a
campaign directory holds — ``summary.json`` (statistics per case), ``campaign.json``
(identity: campaign seed, each case's scene), ``records/`` (one JSON record per
realization), the figures (``*.png``) and the kept VTK (``vtk/...``) — and writes
``DIR/report.html``:

* **Provenance**: scene, fem_rmpm version(s) of the records, campaign seed and seed
  rule, realizations per case, cost (wall and CPU time, core-hours), workers, the
  machine of the last command and the machines (host, CPU) the realizations ran on;
* **Results per case**: N, P(failure) with its standard error and Wilson 95 % interval,
  and mean / standard error / 5-50-95 % quantiles of every measure the summary holds
  (run-out, retrogression, sliding area, ..., factor of safety when computed);
* **Risk study** (when ``validation/risk_study.py`` wrote ``risk_study.json``): per case
  P(failure), P(FS < 1), the failure-mode split and the failure-surface depth;
* **Realizations that failed numerically**, with their messages;
* **Figures**: every PNG of the campaign directory, embedded as ``data:`` URIs;
* **Representative realizations**: per case, among the realizations with kept VTK,
  the ones with the median and the largest run-out, with their plastic-strain figure
  and a relative link to their ``particles.pvd`` (open it in ParaView).

The page needs no network and no other file to render (the VTK links point into
the campaign directory).  A small inline script marks ``<body data-images-loaded>``
with the number of images that decoded, so a headless browser can check the page.
"""
from __future__ import annotations

import datetime as _dt
import json
import math
from pathlib import Path
from typing import Any

from fem_rmpm.campaign.decide import in_measure_sample
from fem_rmpm.campaign.html_parts import CSS, SCRIPT, esc, html_figure, html_table, num
from fem_rmpm.campaign.report3d import report_3d
from fem_rmpm.io.output import _atomic_write_bytes
from fem_rmpm.measures import table
from fem_rmpm.runtime.machine import tally

__all__ = ["write_report", "report_html", "ReportError"]

#: Figures written by the campaign, in the order the report shows them, with captions.
FIGURES = (
    ("exceedance.png", "Exceedance probability P[X > x] of run-out, retrogression and "
                       "sliding area, per case (empirical, over the realizations run to rest)."),
    ("histograms.png", "Histograms of the measures per case."),
    ("convergence.png", "Running P(failure) with its Wilson 95 % band and running mean "
                        "run-out with +- 1.96 standard errors, against N."),
    ("cases.png", "Final plastic shear strain of one kept realization per case."),
    ("cases_mechanism.png", "One kept realization per case at the mechanism time."),
    ("risk_exceedance.png", "Risk study: exceedance curves of sliding area, run-out and "
                            "retrogression, over all realizations (top) and given failure "
                            "(bottom)."),
    ("fragility.png", "Fragility: P(failure | FS) of the MPM per case, binned (Wilson 95 %) "
                      "with the probit curve fitted by maximum likelihood and FS50 with its "
                      "profile-likelihood 95 % interval (shaded)."),
    ("fs_scatter.png", "Factor of safety against sliding area and run-out (filled: failed, "
                       "hollow: stood), realizations run to rest."),
    ("factor_of_safety.png", "Factor of safety per realization: histogram per case, and "
                             "against the MPM's largest displacement."),
    ("risk_modes.png", "Risk study: failure modes per case (rule in the section above) and "
                       "the failure surface's height above the base, given failure."),
)

class ReportError(ValueError):
    """The directory is not a finished campaign (no ``summary.json``), or it is unreadable."""


# ----------------------------------------------------------------------------- reading

def _read_json(path: Path) -> Any:
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise
    except (OSError, ValueError) as exc:
        raise ReportError(f"{path}: cannot be read as JSON ({exc})") from None


def _records(campaign: Path) -> list[dict]:
    root = campaign / "records"
    if not root.is_dir():
        return []
    out = []
    for p in sorted(root.rglob("realization_*.json")):
        try:
            out.append(json.loads(p.read_text(encoding="utf-8")))
        except (OSError, ValueError):
            continue   # a record being replaced right now; the summary still counts it
    return out


# ----------------------------------------------------------------------------- sections

def _provenance(summary: dict, campaign: dict, records: list[dict]) -> str:
    versions = sorted({str(r.get("fem_rmpm")) for r in records if r.get("fem_rmpm")})
    this_run = summary.get("this_run", {})
    cpu = summary.get("realization_cpu_time", {}).get("total")
    wall = summary.get("realization_wall_time", {}).get("total")
    rows = [
        ("scene", esc(summary.get("scene", "?"))),
        ("scene file", esc(summary.get("scene_file") or "embedded default")),
        ("fem_rmpm version of the records", esc(", ".join(versions) or "?")),
        ("campaign seed", esc(summary.get("campaign_seed", campaign.get("campaign_seed")))),
        ("seed of realization i", esc(campaign.get("seed_rule", "?"))),
        ("realizations", esc(", ".join(f"{c.get('label', c.get('name'))}: {c.get('ok', 0)} ok"
                                         f" of {c.get('requested', c.get('realizations', '?'))}"
                                         for c in summary.get("cases", [])))),
        ("failure criterion", _failure_criterion(summary)),
        ("cost (all records)", f"{num(cpu)} s CPU = {num((cpu or 0) / 3600, 3)} core-hours; "
                               f"{num(wall)} s wall summed over realizations"),
        ("last command", f"computed {esc(this_run.get('computed', '?'))} realization(s) on "
                         f"{esc(this_run.get('workers', '?'))} in "
                         f"{num(this_run.get('wall_time'))} s"),
    ]
    if this_run.get("machine"):
        rows.append(("machine of the last command", _machine_text(this_run["machine"])))
    ran_on = tally(r.get("worker") for r in records)
    if ran_on:
        rows.append(("realizations ran on", _workers_text(ran_on)))
    return "<h2>Scene and provenance</h2>" + html_table(("", ""), rows, "kv")


def _machine_text(m: dict) -> str:
    """The campaign process's machine (``summary.json`` ``this_run.machine``, as
    :func:`fem_rmpm.runtime.machine.describe` gave it at the campaign's end), escaped: local
    workers ran on it; cluster workers on their own nodes."""
    load = m.get("load_average")
    text = (f"{m.get('cpu_model', '?')}, {m.get('usable_cores', '?')} of "
            f"{m.get('logical_cores', '?')} cores usable"
            + (f", load average {load[0]} at the end" if isinstance(load, list) and load else "")
            + f"; Python {m.get('python', '?')}, numpy {m.get('numpy', '?')}, "
              f"numba {m.get('numba', '?')} (local workers ran here, cluster workers on "
              "their own nodes)")
    return esc(text)


def _workers_text(machines: list[dict], shown: int = 6) -> str:
    """The machines the records ran on (:func:`fem_rmpm.runtime.machine.tally`), most runs first,
    the first ``shown`` by name, escaped."""
    parts = [f"{m['host']} ({m['cpu_model']}): {m['runs']}" for m in machines[:shown]]
    if len(machines) > shown:
        rest = sum(m["runs"] for m in machines[shown:])
        parts.append(f"{len(machines) - shown} more machines: {rest}")
    return esc("; ".join(parts) + " realization(s)")


def _failure_criterion(summary: dict) -> str:
    """The failure criterion in words (a campaign from before ``failure_area``: any point)."""
    moved = f"moved more than {num(summary.get('failure_displacement'))} m"
    area = summary.get("failure_area")
    if not area:
        return f"a point {moved}"
    return f"at least {num(area)} m2/m of points {moved}"


def _measure_keys(cases: list[dict]) -> list[str]:
    """The headline measures of the table first, then the others in the summary's order."""
    keys = table.headline()
    for c in cases:
        keys += [k for k, v in c.items() if isinstance(v, dict) and "mean" in v and k not in keys]
    return keys


def _label(c: dict) -> str:
    return esc(c.get("label", c.get("name"))) + (" <small>(deterministic)</small>"
                                                    if c.get("deterministic") else "")


def _results(summary: dict) -> str:
    cases = summary.get("cases", [])
    rows = []
    for c in cases:
        w = c.get("wilson95") or [None, None]
        rows.append([_label(c), num(c.get("ok")), num(c.get("numerical_failures")),
                     num(c.get("slope_failures")),
                     f"{num(c.get('p_failure'))} ± {num(c.get('se'))}",
                     f"[{num(w[0])}, {num(w[1])}]",
                     num(c.get("measure_runs", c.get("mpm_runs", c.get("ok"))))])
    head = ("case", "N finished", "numerical failures", "slope failures",
            "P(failure) ± SE", "Wilson 95 %", "run to rest (measures)")
    k_rest = summary.get("runs_to_rest")
    decided = ("" if k_rest is None else
               f" Realizations with index ≥ {num(k_rest)} stopped once their failure was "
               "decided (the failure area of points moved more than the failure displacement); "
               "they count in P(failure) only.")
    mrows = []
    for key in _measure_keys(cases):
        row = [f'<span title="{esc(key)}">{esc(table.label(key))}</span> '
               f"<small>({esc(table.unit(key))})</small>"]
        for c in cases:
            s = c.get(key)
            row.append("–" if not isinstance(s, dict) else
                       f"{num(s.get('mean'))} ± {num(s.get('se'))}<br><small>"
                       f"[{num(s.get('q05'))}, {num(s.get('q50'))}, {num(s.get('q95'))}]"
                       "</small>")
        mrows.append(row)
    return ("<h2>Results per case</h2><p>P(failure): fraction of finished realizations in "
            f"which {esc(_failure_criterion(summary))}; SE = sqrt(p (1 - p) / N); "
            "Wilson 95 % score interval." + esc(decided) + "</p>" + html_table(head, rows, "cases")
            + _decision_check(summary)
            + (_table_of_measures(cases, mrows) if any(
                c.get("measure_runs", c.get("ok")) for c in cases) else
               "<p>No measures of the deposit: they come from the runs to rest with an "
               "index below runs_to_rest, and there are none here (runs that stood went "
               "on to rest, but count in P(failure) only).</p>"))


def _table_of_measures(cases: list[dict], mrows: list) -> str:
    return ("<p>Measures: mean ± standard error of the mean, [5 %, 50 %, 95 %] "
            "quantiles, over the realizations of each case run to rest.</p>"
            + html_table(["measure"] + [_label(c) for c in cases], mrows, "measures"))


def _ci(w: Any) -> str:
    return "–" if not w else f"[{num(w[0])}, {num(w[1])}]"


def _why_failed(summary: dict) -> str:
    """Per case with FS and MPM runs: P(failure) beside P(FS < 1), the split of the
    failures (progressive / strength-limited), FS50 of the fragility fit, and the
    agreement of stand/fail with FS < 1 (all realizations; outside |FS - 1| <= margin)."""
    rows, differ, soft = [], [], set()
    for c in summary.get("cases", []):
        fs = c.get("fs") or {}
        f = fs.get("fragility")
        if not f:
            continue
        soft.add(bool(c.get("softening", True)))
        sp, fit, a = f["split"], f.get("probit"), fs.get("agreement") or {}
        out = a.get("outside_margin") or {}
        fit_txt = "no fit (all failed or none)" if not fit else (
            f"{num(fit['fs50'])} {_ci(fit['fs50_interval95'])}<br><small>s = "
            f"{num(fit['s'])}{', separated' if fit['separated'] else ''}</small>")
        rows.append([_label(c), num(f["n"]),
                     f"{num(f['p_failure'])} {_ci(f['p_failure_wilson95'])}",
                     f"{num(f['p_fs_below_1'])} {_ci(f['p_fs_below_1_wilson95'])}",
                     f"{num(sp['progressive'])} of {num(sp['failures'])}: "
                     f"{num(sp['progressive_fraction'])} {_ci(sp['progressive_wilson95'])}",
                     f"{num(sp['strength_limited'])}: {num(sp['strength_limited_fraction'])}"
                     f" {_ci(sp['strength_limited_wilson95'])}", fit_txt,
                     f"{num(a.get('agree'))} of {num(a.get('n'))}; outside ±"
                     f"{num(out.get('margin'))}: {num(out.get('agree'))} of "
                     f"{num(out.get('n'))}"])
        differ += [[_label(c), num(d["index"]), num(d["seed"]), num(d["factor_of_safety"]),
                    num(d["failed"]), num(d.get("max_displacement"))]
                   for d in a.get("disagree") or []]
    if not rows:
        return ""
    mode = ("Softening was switched off in this campaign (every residual strength set to its "
            "peak: perfectly plastic, as in the strength reduction), so stand/fail should agree "
            "with FS < 1 except near FS = 1: this is the consistency check of the MPM against "
            "strength reduction. " if soft == {False} else
            "A failure with FS ≥ 1 is progressive: the slope stands at peak strength and the "
            "softening after first yield brings it down; one with FS < 1 is strength-limited. "
            "A strength-reduction analysis at peak strength (RFEM) counts only the second kind. ")
    head = [esc(h) for h in (
        "case", "N (FS and MPM)", "P(failure) [Wilson 95 %]", "P(FS < 1) [Wilson 95 %]",
        "progressive failures (FS ≥ 1)", "strength-limited (FS < 1)",
        "FS50 (P = 0.5) [profile 95 %]", "stand/fail agrees with FS < 1")]
    listing = ("" if not differ else "<p>Realizations where stand/fail and FS &lt; 1 differ:</p>"
               + html_table(("case", "index", "seed", "FS", "MPM failed", "max displacement (m)"),
                        differ))
    return ("<h2>Why the realizations failed</h2><p>" + esc(mode) + "FS: strength reduction "
            "at peak strength of the same random field (perfectly plastic). Fragility: probit "
            "P(failure | FS) = Φ((FS50 − FS)/s) fitted by maximum likelihood; the interval of "
            "FS50 is the profile-likelihood 95 % interval (figure fragility.png).</p>"
            + html_table(head, rows, "fragility") + listing)


def _what_n_buys(summary: dict, campaign: Path) -> str:
    """The Wilson 95 % half-width of P(failure) per random case now, the N that would give
    a half-width of 0.05 at the observed P (normal approximation 1.96^2 p (1 - p) / 0.05^2),
    and the command that extends the campaign (``main_job.json`` may name the full study)."""
    rows = []
    for c in summary.get("cases", []):
        n, p, w = c.get("mpm_runs") or c.get("ok"), c.get("p_failure"), c.get("wilson95")
        if c.get("deterministic") or not n or p is None or not w:
            continue
        q = min(max(p, 1.0 / (n + 1)), 1 - 1.0 / (n + 1))   # 0 or 1: one count's worth
        need = math.ceil(1.959963984540054 ** 2 * q * (1 - q) / 0.05 ** 2)
        rows.append([_label(c), num(n), num(p), f"± {num((w[1] - w[0]) / 2)}",
                     f"{num(0.98 / math.sqrt(n))}", num(need)])
    if not rows:
        return ""
    try:
        job = _read_json(campaign / "main_job.json")
    except (FileNotFoundError, ValueError):
        job = {}
    extend = (job.get("full_study") if isinstance(job, dict) else None) or (
        "re-run the same command with a larger -n: the finished realizations are reused")
    return ("<h2>What N buys</h2><p>The Wilson 95 % interval of P(failure) narrows as "
            "1/√N: its half-width is at most about 0.98/√N (at P = 0.5). For the full study: "
            f"<code>{esc(extend)}</code>.</p>"
            + html_table(("case", "N", "P(failure)", "Wilson 95 % half-width now",
                      "worst case 0.98/√N", "N for ± 0.05 at this P"), rows))


def _linked(campaign: Path) -> str:
    """Campaigns in subdirectories of this one (e.g. the main job's seed slope): their
    P(failure) per case and their figures of one realization per case."""
    parts = []
    for sub in sorted(p for p in campaign.iterdir() if p.is_dir()):
        try:
            s = _read_json(sub / "summary.json")
        except (FileNotFoundError, ValueError, OSError):
            continue
        if not isinstance(s, dict) or "cases" not in s:
            continue
        rows = [[_label(c), num(c.get("ok")), num(c.get("slope_failures")),
                 f"{num(c.get('p_failure'))} {_ci(c.get('wilson95'))}",
                 num((c.get("runout_distance") or {}).get("mean")),
                 num((c.get("sliding_area") or {}).get("mean"))] for c in s["cases"]]
        figs = "".join(html_figure(sub / name, f"{s.get('scene', sub.name)}: {cap}", name)
                       for name, cap in (("cases_mechanism.png", "one realization per case at "
                                          "the mechanism time"),
                                         ("cases.png", "one realization per case at rest"))
                       if (sub / name).is_file())
        parts.append(f"<h3>{esc(s.get('scene', sub.name))} "
                     f'(<a href="{esc(sub.name)}/report.html">{esc(sub.name)}/</a>)</h3>'
                     + html_table(("case", "N", "failures", "P(failure) [Wilson 95 %]",
                               "run-out mean (m)", "sliding area mean (m2/m)"), rows) + figs)
    return "" if not parts else "<h2>Linked campaigns</h2>" + "".join(parts)


def _decision_check(summary: dict) -> str:
    """The stopping rule checked on the runs to rest that recorded their decision time."""
    rows = [[esc(name), num(d.get("checked")), num(d.get("agree")),
             esc(", ".join(map(str, d.get("failed_never_decided") or [])) or "none"),
             esc(", ".join(map(str, d.get("decided_but_stood") or [])) or "none")]
            for name, d in (summary.get("decision_check") or {}).items() if d.get("checked")]
    if not rows:
        return ""
    return ("<p>Stopping rule on the runs to rest (decided as failed exactly when failed):</p>"
            + html_table(("case", "runs to rest checked", "agree", "failed, never decided",
                      "decided, stood"), rows))


def _subset(summary: dict) -> str:
    """Subset simulation (``summary["subset"]``): the estimate, its cost, and the levels."""
    sub = summary.get("subset")
    if not isinstance(sub, dict):
        return ""
    rows = [("failure", esc(sub.get("failure", sub.get("response")))),
            ("P(failure)", f"{num(sub.get('probability'), 4)} (coefficient of variation "
                           f"{num(sub.get('cov'))}, Au & Beck 2001, chain correlation included)"),
            ("p0, samples per level", f"{num(sub.get('p0'))}, "
                                      f"{num(sub.get('samples_per_level'))}"),
            ("runs", f"{num(sub.get('total_runs'))} (crude Monte Carlo for the same "
                     f"coefficient of variation: {num(sub.get('crude_equivalent_runs'))}); "
                     f"{num(sub.get('failed_runs'))} failed numerically")]
    rows += [("note", esc(n)) for n in sub.get("notes") or []]
    levels = [[num(lv.get("level")), num(lv.get("threshold_response"), 4),
               num(lv.get("conditional_probability")), num(lv.get("cov")),
               num(lv.get("gamma")), num(lv.get("acceptance")), num(lv.get("runs"))]
              for lv in sub.get("levels") or []]
    return ("<h2>Subset simulation</h2>" + html_table(("", ""), rows, "kv")
            + html_table(("level", "threshold", "P(level | previous)", "COV", "gamma",
                      "acceptance", "runs"), levels))


def _risk_study(campaign: Path) -> str:
    """The risk study (``risk_study.json`` of ``validation/risk_study.py``), when present:
    per case P(failure), P(FS < 1), the failure-mode split and the failure-surface depth."""
    try:
        study = _read_json(campaign / "risk_study.json")
    except (FileNotFoundError, ReportError):
        return ""
    rules = study.get("rules") or {}
    fs = study.get("factor_of_safety") or {}
    rows = []
    for name, c in (study.get("cases") or {}).items():
        w = c.get("wilson95") or [None, None]
        f = fs.get(name) or {}
        a = (c.get("sliding_area") or {}).get("given_failure") or {}
        ro = (c.get("runout_distance") or {}).get("given_failure") or {}
        m = c.get("modes") or {}
        h = c.get("slip_surface_height") or {}
        rows.append([esc(name), num(c.get("n")),
                     f"{num(c.get('n_measure', c.get('n')))} ({num(c.get('failed_measure'))})",
                     f"{num(c.get('p_failure'))} [{num(w[0])}, {num(w[1])}]",
                     f"{num(f.get('p_fs_below_1'))} (N {num(f.get('n'))})" if f else "-",
                     f"{num(a.get('mean'))} ({num(a.get('cov'), 2)})",
                     f"{num(ro.get('mean'))} ({num(ro.get('cov'), 2)})",
                     " / ".join(num(m.get(k)) for k in ("toe slump", "translational",
                                                         "retrogressive")),
                     f"{num(h.get('q50'))} ({num(c.get('above_base'))})"])
    rule = (f"Failure modes: toe slump when the retrogression is at most "
            f"{num(rules.get('toe_slump_retrogression_m'))} m; otherwise translational when at "
            f"least {num(rules.get('translational_early_fraction'))} of the final sliding area "
            "moved by the mechanism time, else retrogressive. Above the base: failure-surface "
            f"height over {num(rules.get('above_base_height_m'))} m.")
    return ("<h2>Risk study</h2><p>" + esc(rule) + "</p>"
            + html_table(("case", "N", "run to rest: n (failed)", "P(failure) [Wilson 95 %]",
                      "P(FS < 1)",
                      f"{table.axis_label('sliding_area')} given failure: mean (COV)",
                      f"{table.axis_label('runout_distance')} given failure: mean (COV)",
                      "toe slump / translational / retrogressive",
                      f"{table.axis_label('slip_surface_height')}: median (n above base)"),
                     rows)
            + _decided_check(study) + _mesh_check(study))


def _decided_check(study: dict) -> str:
    """A decided-only campaign against the runs to rest, pair by pair, when the study has it."""
    rows = [[esc(name), num(d.get("pairs")), num(d.get("agree")),
             esc(", ".join(map(str, d.get("disagree") or [])) or "none"),
             num(d.get("decided_time_max"))]
            for name, d in (study.get("decided_check") or {}).items() if d]
    if not rows:
        return ""
    return ("<h3>Runs stopped once decided against the runs to rest</h3><p>The same "
            "realizations in a campaign with every run stopped once decided ("
            + esc(study.get("decided_campaign") or "") + ").</p>"
            + html_table(("case", "pairs", "same failed", "indices that differ",
                      "latest decision (s)"), rows))


def _mesh_check(study: dict) -> str:
    """The study's mesh check (the same realizations on a finer mesh), when it has one."""
    rows = []
    for name, m in (study.get("mesh_check") or {}).items():
        if not m:
            continue
        ca, fa = ((m.get(k) or {}).get("sliding_area_given_failure") or {}
                  for k in ("coarse", "fine"))
        rows.append([esc(name), num(m.get("n")),
                     f"{num((m.get('coarse') or {}).get('p_failure'))} / "
                     f"{num((m.get('fine') or {}).get('p_failure'))}",
                     num(m.get("agree")), f"{num(ca.get('mean'))} / {num(fa.get('mean'))}",
                     f"{num(m.get('area_abs_difference_mean'))} ({num(m.get('both_failed'))})"])
    if not rows:
        return ""
    area = table.unit("sliding_area")
    return ("<h3>Mesh check</h3><p>The same realizations (same random field) on the scene's "
            "mesh and on a finer one (" + esc(study.get("mesh_campaign") or "") + ").</p>"
            + html_table(("case", "pairs", "P(failure) scene / finer", "agree",
                      f"sliding area given failure ({area}) scene / finer",
                      f"mean |difference| where both failed ({area}) (n)"), rows))


def _failures(records: list[dict]) -> str:
    bad = [r for r in records if r.get("status") != "ok"]
    if not bad:
        return "<h2>Numerical failures</h2><p>None: every realization finished.</p>"
    rows = [[esc(r.get("case")), num(r.get("index")), esc(r.get("seed")),
             esc(r.get("error") or "")] for r in bad]
    return ("<h2>Numerical failures</h2><p>Realizations that stopped with an error are "
            "recorded and left out of the statistics.</p>"
            + html_table(("case", "index", "seed", "message"), rows))


def _figures(campaign: Path) -> str:
    parts, known = [], set()
    for name, caption in FIGURES:
        known.add(name)
        if (campaign / name).is_file():
            parts.append(html_figure(campaign / name, caption, name))
    for p in sorted(campaign.glob("*.png")):
        if p.name not in known:
            parts.append(html_figure(p, p.stem.replace("_", " "), p.name))
    return "<h2>Figures</h2>" + ("".join(parts) or "<p>No figure was written.</p>")


def _measures_text(m: dict) -> str:
    """The headline measures of a record, ``label value unit`` each, escaped."""
    return ", ".join(esc(table.label(k)) + f" {num(m.get(k))} " + esc(table.unit(k))
                     for k in table.headline())


def _representatives(campaign: Path, records: list[dict]) -> str:
    by_case: dict[str, list[dict]] = {}
    for r in records:
        if r.get("status") == "ok":
            by_case.setdefault(str(r.get("case")), []).append(r)
    parts = []
    for case, recs in by_case.items():
        kept = [r for r in recs if r.get("vtk") and (campaign / r["vtk"]).is_dir()
                and (r.get("measures") or {}).get("runout_distance") is not None]
        if not kept:
            parts.append(f"<h3>{esc(case)}</h3><p>No realization of this case kept its VTK "
                         "(use <code>--keep-vtk</code> to keep some).</p>")
            continue
        kept.sort(key=lambda r: (float(r["measures"]["runout_distance"]), r["index"]))
        picks = [("median run-out", kept[(len(kept) - 1) // 2]), ("largest run-out", kept[-1])]
        if picks[0][1] is picks[1][1]:
            picks = [("median and largest run-out", kept[-1])]
        cells = []
        for what, r in picks:
            vtk = campaign / r["vtk"]
            fig = vtk / "plastic_shear_strain.png"
            m = r["measures"]
            text = (f"{esc(what)} among {len(kept)} kept: realization {r['index']} "
                    f"(seed {r['seed']}), {_measures_text(m)}, "
                    f"failed: {num(m.get('failed'))}. "
                    f'<a href="{esc(r["vtk"])}/particles.pvd">particles.pvd</a> · '
                    f'<a href="{esc(r["vtk"])}/grid.vtu">grid.vtu</a>')
            img = html_figure(fig, f"realization {r['index']}", fig.name) if fig.is_file() else ""
            cells.append(f'<div class="rep">{img}<p>{text}</p></div>')
        parts.append(f"<h3>{esc(case)}</h3><div class=\"reps\">{''.join(cells)}</div>")
    return "<h2>Representative realizations</h2>" + "".join(parts)


def _check_campaign_summary(campaign: Path, summary: Any) -> None:
    """Refuse a ``summary.json`` that is not a campaign's: one of ``fem-rmpm run``/``fem``
    (it names a ``scheme``), or one without the per-case results (``cases``/``subset``)."""
    allowed = "allowed: a campaign directory written by `fem-rmpm mc ... --out DIR`"
    if isinstance(summary, dict) and "scheme" in summary and "cases" not in summary:
        raise ReportError(f"{campaign}: a run directory (summary.json of a "
                          f"{summary['scheme']!s:.20} run), not a campaign; {allowed}")
    if not isinstance(summary, dict) or not ("cases" in summary or "subset" in summary):
        raise ReportError(f"{campaign}: summary.json holds no campaign results (no cases); "
                          f"{allowed}")


def report_html(campaign_dir: str | Path) -> str:
    """The report page of a campaign directory, as one HTML string (see the module doc)."""
    campaign = Path(campaign_dir)
    try:
        summary = _read_json(campaign / "summary.json")
    except FileNotFoundError:
        raise ReportError(f"{campaign}: no summary.json here (not a finished campaign "
                          "directory; run `fem-rmpm mc ... --out DIR` first)") from None
    _check_campaign_summary(campaign, summary)
    try:
        identity = _read_json(campaign / "campaign.json")
    except FileNotFoundError:
        identity = {}
    for name, value in (("summary.json", summary), ("campaign.json", identity)):
        if not isinstance(value, dict):
            raise ReportError(f"{campaign / name}: holds a JSON {type(value).__name__}, not "
                              "the object a campaign writes (not a campaign directory?)")
    records = _records(campaign)
    title = f"fem_rmpm campaign report: {summary.get('scene', campaign.name)}"
    made = _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    body = "".join((
        f"<h1>{esc(title)}</h1><p><small>Written {made} from {esc(campaign.resolve())}. "
        'Files: <a href="results.csv">results.csv</a> · <a href="summary.json">summary.json</a>'
        ' · <a href="records/">records/</a></small></p>',
        _provenance(summary, identity, records), _subset(summary), _results(summary),
        _why_failed(summary), _what_n_buys(summary, campaign),
        _risk_study(campaign), _failures(records),
        _figures(campaign),
        report_3d(campaign, [r for r in records
                             if in_measure_sample(r, summary.get("runs_to_rest"))]),
        _linked(campaign), _representatives(campaign, records)))
    return (f'<!DOCTYPE html><html lang="en"><head><meta charset="utf-8">'
            f"<title>{esc(title)}</title><style>{CSS}</style><script>{SCRIPT}</script>"
            f"</head><body>{body}</body></html>\n")


def write_report(campaign_dir: str | Path) -> Path:
    """Write ``report.html`` into the campaign directory (atomically) and return its path."""
    campaign = Path(campaign_dir)
    path = campaign / "report.html"
    page = report_html(campaign).encode("utf-8")
    try:
        _atomic_write_bytes(path, page)
    except OSError as exc:
        raise ReportError(f"{path}: cannot be written ({exc.strerror}); needed: write "
                          f"permission on {campaign}") from None
    return path
