"""Campaigns of cases: realizations ``0 .. N-1`` of one or more cases of a scene, run by
any case method of :data:`fem_rmpm.campaign.methods.METHODS` (crude Monte Carlo by
default) through the campaign runner (:mod:`fem_rmpm.campaign.runner`); records per case
and index, ``results.csv``, ``summary.json`` and the figures rebuilt from them
(:mod:`fem_rmpm.campaign`'s docstring)."""
from __future__ import annotations

import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import numpy as np

from fem_rmpm.campaign.backends import ClusterSpec, campaign_backend
from fem_rmpm.campaign.cases import CampaignError, Case, parse_case
from fem_rmpm.campaign.decide import decision_check, in_measure_sample, is_decided
from fem_rmpm.campaign.factor_of_safety import (
    fs_statistics,
    plot_factor_of_safety,
    plot_fragility,
    plot_fs_scatter,
)
from fem_rmpm.campaign.fragility import has_softening
from fem_rmpm.campaign.keep_vtk import kept, parse_keep_vtk
from fem_rmpm.campaign.methods import METHODS, MethodOptions, PerCase, Sample
from fem_rmpm.campaign.plots import campaign_figures
from fem_rmpm.campaign.report import write_report
from fem_rmpm.campaign.report3d import figures_3d
from fem_rmpm.campaign.runner import Execution, RunTally, run_method_campaign
from fem_rmpm.campaign.statistics import case_statistics
from fem_rmpm.campaign.store import (
    Layout,
    campaign_doc,
    check_directory,
    clean_temporaries,
    read_record,
    write_results,
)
from fem_rmpm.campaign.task import campaign_threads, run_realization
from fem_rmpm.campaign.three_d import check_campaign_3d
from fem_rmpm.io.output import write_json
from fem_rmpm.runtime.machine import describe as describe_machine
from fem_rmpm.runtime.budget import estimate_run
from fem_rmpm.runtime.machine import tally
from fem_rmpm.scene import Scene

__all__ = ["run_campaign", "CampaignResult", "CasePlan", "pending_work", "case_methods",
           "thread_shortfall"]


@dataclass
class CampaignResult:
    """What :func:`run_campaign` did: ``stats`` per case (:func:`case_statistics`),
    ``computed``/``skipped``/``lost`` realizations of this command, its wall time
    and the number of workers."""
    out: Path
    cases: list[Case]
    realizations: dict[str, int]
    stats: dict[str, dict]
    computed: int
    skipped: int
    lost: list[str]
    wall_time: float
    compute_time: float
    workers: str
    figures: list[Path] = field(default_factory=list)

    @property
    def realizations_per_hour(self) -> float | None:
        return 3600.0 * self.computed / self.compute_time if self.compute_time > 0 else None


def _case_realizations(case: Case, n: int) -> int:
    return 1 if case.deterministic else n


#: At most this many realizations in one campaign: a task (a few hundred bytes) is built
#: for each before the campaign starts, so a larger N is refused at once, with its cost.
MAX_REALIZATIONS = 1_000_000


def check_campaign_size(case_list: list[Case], counts: dict[str, int]) -> None:
    """Raise :class:`CampaignError` (with the estimated core-hours, from the budget of one
    realization per case) when the campaign has more than :data:`MAX_REALIZATIONS`
    realizations; constant time in N (nothing is built per realization)."""
    total = sum(counts.values())
    if total <= MAX_REALIZATIONS:
        return
    seconds = 0.0
    for c in case_list:       # one thread per realization, as the campaign's workers run
        e = estimate_run(c.scene)
        seconds += counts[c.name] * e.points * e.steps * e.steps_factor * e.ns_per_point_step
    hours = seconds * 1e-9 / 3600.0
    raise CampaignError(f"-n {max(counts.values())}: {total} realizations in all "
                        f"({len(case_list)} case(s)), about {hours:.3g} core-hours by the "
                        f"budget's estimate; allowed: at most {MAX_REALIZATIONS} realizations "
                        "in one campaign")


def run_campaign(scene: Scene, out: str | Path, realizations: int | None = None,
                 cases: Sequence[str | Case] | None = None, *, workers: int | None = None,
                 scheduler: str | None = None, force: bool = False, keep_vtk=None,
                 progress: bool = True, figures: bool = True, client=None,
                 cluster: ClusterSpec | None = None, fs_only: bool = False,
                 method: str = "crude") -> CampaignResult:
    """Run (or finish) a campaign in ``out``; see :mod:`fem_rmpm.campaign`.

    ``realizations``: N per case (default ``[montecarlo] realizations``);
    ``cases``: case texts for :func:`parse_case` or :class:`Case` objects
    (default: the scene itself); ``workers``: local worker processes;
    ``scheduler``: address of a running Dask scheduler instead; ``client``: an
    existing ``distributed.Client`` to use (left open); ``cluster``: where to run
    (:class:`fem_rmpm.campaign.backends.ClusterSpec`, e.g. SLURM workers); ``keep_vtk``:
    see :func:`parse_keep_vtk`; ``fs_only``: the strength-reduction factor of safety of
    every realization instead of its MPM run (``[montecarlo] factor_of_safety``: before
    it); ``method``: a case method of :data:`fem_rmpm.campaign.methods.METHODS` (one
    instance per case).  Raises :class:`CampaignError` (bad input, other campaign in
    ``out``, unreachable scheduler, a refused worker job, a campaign directory the
    workers do not share) before any realization runs."""
    t_start = time.perf_counter()
    out = Path(out)
    n = scene.montecarlo.realizations if realizations is None else realizations
    _check_arguments(n, workers, scheduler, client)
    check_campaign_3d(scene, fs_only=fs_only, method=method)
    if client is not None and cluster is not None:
        raise CampaignError("give a client or a cluster, not both")
    plan = pending_work(scene, out, n, cases, keep_vtk=keep_vtk, force=force,
                        fs_only=fs_only, method=method)
    backend = (campaign_backend(cluster, workers, scheduler, plan.cases)
               if client is None else None)
    run = Execution(backend, client, preflight=len(plan.tasks) or None,
                    progress=f"{scene.scene.name} mc" if progress else None,
                    notice=lambda k, desc: (
                        f"fem-rmpm mc: {k} realization(s) to run ({len(plan.finished)} "
                        f"already finished) on {desc}; records in {out}") if progress else None)

    def finish(tally: RunTally) -> CampaignResult:
        result = _finish(out, scene, plan, tally, t_start, figures)
        if (short := thread_shortfall(plan.cases, plan.finished.values())) is not None:
            print(short, file=sys.stderr, flush=True)
        return result

    return run_method_campaign(plan.method, _CaseEvaluation(plan), out, plan.doc, run, finish)


@dataclass
class CasePlan:
    """A case campaign before it runs (read-only): the :class:`Case` list, realizations per
    case, the identity document, the :class:`Layout`, the VTK choice, the factor-of-safety
    mode, ``force``, the method (:class:`~fem_rmpm.campaign.methods.PerCase`), the tasks
    of its first batch and the finished records ``{(case, index): record}``."""
    scene: Scene
    cases: list[Case]
    counts: dict[str, int]
    doc: dict
    layout: Layout
    keep: object
    fs_mode: str
    force: bool
    method: PerCase
    tasks: list[dict] = field(default_factory=list)
    finished: dict = field(default_factory=dict)


def case_methods(name: str, counts: dict[str, int], seed: int) -> PerCase:
    """One method ``name`` of :data:`METHODS` per case (``counts[case]`` samples each), the
    response of a realization being its failure indicator (threshold 0.5)."""
    entry = METHODS.get(name)
    if entry is None or entry.response:
        allowed = ", ".join(k for k, e in METHODS.items() if not e.response)
        raise CampaignError(f"--method {name!r}: not a method of case campaigns; "
                            f"allowed: {allowed}")
    return PerCase({c: entry.make(MethodOptions(n=k, seed=seed, threshold=0.5))
                    for c, k in counts.items()})


def pending_work(scene: Scene, out: Path, n: int, cases: Sequence[str | Case] | None, *,
                 keep_vtk=None, force: bool = False, fs_only: bool = False,
                 method: str = "crude") -> CasePlan:
    """What a campaign in ``out`` has left to do in its first batch (read-only; raises
    CampaignError for bad cases or another campaign in ``out``)."""
    keep = parse_keep_vtk(keep_vtk, scene.montecarlo.keep_vtk)
    case_list = [c if isinstance(c, Case) else parse_case(c, scene)
                 for c in (cases or ["scene"])]
    names = [c.name for c in case_list]
    if len(set(names)) != len(names):
        raise CampaignError(f"case names must be unique, got {names}")
    counts = {c.name: _case_realizations(c, n) for c in case_list}
    check_campaign_size(case_list, counts)
    doc = campaign_doc(case_list, scene.montecarlo.seed)
    check_directory(out, doc)
    fs_mode = "only" if fs_only else ("before" if scene.montecarlo.factor_of_safety else "off")
    plan = CasePlan(scene, case_list, counts, doc, Layout(out, case_list), keep, fs_mode,
                    force, case_methods(method, counts, scene.montecarlo.seed))
    plan.tasks = _CaseEvaluation(plan).plan(plan.method.next_batch() or [])
    return plan


def _check_arguments(n, workers, scheduler, client) -> None:
    """Raise CampaignError for a bad N, worker count or cluster choice."""
    if isinstance(n, bool) or not isinstance(n, int) or n <= 0:
        raise CampaignError(f"-n {n}: the number of realizations must be a positive integer")
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int)
                                or workers <= 0):
        raise CampaignError(f"--workers {workers}: expected a positive integer")
    if client is not None and (workers is not None or scheduler):
        raise CampaignError("give a client, or workers, or a scheduler address")
    if workers is not None and scheduler:
        raise CampaignError("--workers starts a local cluster; with --scheduler the "
                            "cluster's own workers are used: give one of the two")


class _CaseEvaluation:
    """The runner's view of a case campaign (:class:`fem_rmpm.campaign.runner.Evaluation`):
    a sample is realization ``chain`` of case ``case``; its record is reused if its seed,
    case and factor-of-safety mode match (a decided record serves only ``i >=
    runs_to_rest``; none with ``force``); its response is the failure indicator."""
    task_function = staticmethod(run_realization)

    def __init__(self, plan: CasePlan):
        self.p = plan

    def check_directory(self, out: Path) -> None:
        check_directory(out, self.p.doc)

    def clean_temporaries(self, out: Path) -> None:
        clean_temporaries(out)

    def task_key(self, task: dict) -> str:
        return f"{task['case']}-{task['index']:05d}"

    def task_name(self, task: dict) -> str:
        return f"{task['case']} #{task['index']}"

    def plan(self, batch: list[Sample]) -> list[dict]:
        p, lay = self.p, self.p.layout
        k_rest = p.scene.montecarlo.runs_to_rest
        by_name = {c.name: c for c in p.cases}
        tasks = []
        for s in batch:
            c, i, seed = by_name[s.case], s.chain, s.seed
            decide = k_rest is not None and i >= k_rest and p.fs_mode != "only"
            rec = None if p.force else read_record(lay.record(c.name, i))
            if (rec is not None and rec.get("seed") == seed and rec.get("case") == c.name
                    and rec.get("fs_mode", "off") == p.fs_mode
                    and (decide or not is_decided(rec))):
                p.finished[(c.name, i)] = rec      # a decided record serves i >= runs_to_rest
                continue
            vtk = lay.vtk(c.name, i) if kept(p.keep, i) and not decide else None
            tasks.append({"case": c.name, "index": i, "seed": seed, "scene": c.scene,
                          "fs": p.fs_mode, "decide": decide,
                          "vtk_dir": str(vtk.resolve()) if vtk is not None else None,
                          "vtk_rel": str(vtk.relative_to(lay.out)) if vtk is not None else None})
        return tasks

    def arrived(self, rec: dict) -> None:
        lay = self.p.layout
        profile = rec.pop("final_profile", None)
        if profile is not None:
            write_json(lay.profile(rec["case"], rec["index"]),
                       {"case": rec["case"], "index": rec["index"], "seed": rec["seed"],
                        "final_profile": profile})
        write_json(lay.record(rec["case"], rec["index"]), rec)
        self.p.finished[(rec["case"], rec["index"])] = rec

    def responses(self, batch: list[Sample]) -> list[float]:
        out = []
        for s in batch:
            rec = self.p.finished[(s.case, s.chain)]
            failed = (rec.get("measures") or {}).get("failed")
            out.append(float(bool(failed)) if rec["status"] == "ok" and failed is not None
                       else float("nan"))
        return out


def thread_shortfall(cases: Sequence[Case], records) -> str | None:
    """A one-line warning when realizations ran on fewer numba threads than their case's
    ``[solver] threads`` asks for (records that name their threads), else None.  The
    workers' ``NUMBA_NUM_THREADS`` caps the count: workers of a running Dask cluster or of
    batch jobs start with one thread.  The results are the same on any thread count; only
    the wall time is longer."""
    asked = {c.name: campaign_threads(c.scene) for c in cases}
    short = [(r["worker"]["threads"], asked[r["case"]]) for r in records
             if r.get("case") in asked and isinstance(r.get("worker"), dict)
             and r["worker"].get("threads", asked[r["case"]]) < asked[r["case"]]]
    if not short:
        return None
    used, want = min(short)
    return (f"fem-rmpm: warning: {len(short)} realization(s) ran on {used} numba thread(s), "
            f"fewer than [solver] threads = {want}: the workers' NUMBA_NUM_THREADS caps it "
            "(set it in the workers' environment; the results are the same, only slower)")


def _finish(out: Path, scene: Scene, plan: CasePlan, done: RunTally, t_start: float,
            figures: bool) -> CampaignResult:
    """Rebuild ``results.csv``, ``summary.json`` and the figures from the records."""
    cases, counts, lay, finished = plan.cases, plan.counts, plan.layout, plan.finished
    computed, skipped, lost = done.computed, done.reused, done.lost
    desc, compute_time = done.workers, done.compute_time
    order = [c.name for c in cases]
    records = [r for (c, i), r in finished.items() if i < counts[c]]
    write_results(out / "results.csv", records, order)
    k_rest = scene.montecarlo.runs_to_rest
    stats = {c.name: case_statistics([r for r in records if r["case"] == c.name],
                                     counts[c.name], k_rest) for c in cases}
    for c in cases:
        fs = fs_statistics([r for r in records if r["case"] == c.name])
        if fs is not None:
            stats[c.name]["fs"] = fs
    walls = [r["wall_time"] for r in records if r.get("wall_time") is not None]
    cpus = [r["cpu_time"] for r in records if r.get("cpu_time") is not None]
    res = CampaignResult(out, cases, counts, stats, computed, skipped, lost,
                         time.perf_counter() - t_start, compute_time, desc)
    extra = sum(1 for (c, i) in finished if i >= counts[c])
    summary = {
        "scene": scene.scene.name, "scene_file": scene.source,
        "campaign_seed": scene.montecarlo.seed,
        "failure_displacement": scene.montecarlo.failure_displacement,
        "failure_area": scene.montecarlo.failure_area,
        "cases": [{"name": c.name, "spec": c.spec, "label": c.label,
                   "deterministic": c.deterministic, "realizations": counts[c.name],
                   "softening": has_softening(c.scene), **stats[c.name]} for c in cases],
        "this_run": {"computed": computed, "skipped_finished": skipped, "lost": lost,
                     "workers": desc, "compute_wall_time": compute_time,
                     "wall_time": res.wall_time,
                     "realizations_per_hour": res.realizations_per_hour,
                     "machine": describe_machine()},     # (the campaign process's)
        "worker_machines": tally(r.get("worker") for r in records),   # (the records')
        "realization_wall_time": {"mean": float(np.mean(walls)) if walls else None,
                                  "total": float(np.sum(walls)) if walls else None},
        "realization_cpu_time": {"mean": float(np.mean(cpus)) if cpus else None,
                                 "total": float(np.sum(cpus)) if cpus else None},
        "records_beyond_n": extra,
        "runs_to_rest": k_rest,
        "decision_check": {c.name: decision_check(r for r in records if r["case"] == c.name)
                           for c in cases},
    }
    write_json(out / "summary.json", summary)
    mpm = [r for r in records if r.get("fs_mode", "off") != "only"   # with an MPM run,
           and in_measure_sample(r, k_rest)]                           # run to rest
    if figures and records:
        res.figures = campaign_figures(out, cases, stats, mpm, lay, scene) if mpm else []
        res.figures += figures_3d(out, mpm, scene.montecarlo.failure_displacement)
        if any("fs" in stats[c.name] for c in cases):
            res.figures.append(plot_factor_of_safety(out / "factor_of_safety.png", cases,
                                                     stats, records))
            for fig in (plot_fragility(out / "fragility.png", cases, stats),
                        plot_fs_scatter(out / "fs_scatter.png", cases, mpm)):
                if fig is not None:
                    res.figures.append(fig)
        res.figures.append(write_report(out))
    return res
