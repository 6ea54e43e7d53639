"""The campaign loop: plan what is left to do, compute it on Dask, write each record as it
arrives, rebuild ``results.csv``, ``summary.json`` and the figures."""
from __future__ import annotations

import sys
import time
import uuid
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import numpy as np
from distributed import as_completed
from tqdm import tqdm

from fem_rmpm.campaign.backends import ClusterSpec, campaign_backend
from fem_rmpm.campaign.cases import CampaignError, Case, parse_case, realization_seed
from fem_rmpm.campaign.decide import decision_check, in_measure_sample, is_decided
from fem_rmpm.campaign.factor_of_safety import fs_statistics, plot_factor_of_safety
from fem_rmpm.campaign.keep_vtk import kept, parse_keep_vtk
from fem_rmpm.campaign.plots import campaign_figures
from fem_rmpm.campaign.report import write_report
from fem_rmpm.campaign.statistics import case_statistics
from fem_rmpm.campaign.store import (
    Layout,
    Lock,
    campaign_doc,
    check_directory,
    clean_temporaries,
    read_record,
    write_results,
)
from fem_rmpm.campaign.task import campaign_threads, run_realization
from fem_rmpm.io.output import write_json
from fem_rmpm.runtime.machine import describe as describe_machine
from fem_rmpm.runtime.machine import tally
from fem_rmpm.scene import Scene

__all__ = ["run_campaign", "CampaignResult", "pending_work", "thread_shortfall"]


class _Progress:
    """The progress bar of a campaign (tqdm on stderr): done, ok, failed, running, lost."""

    def __init__(self, total: int, enabled: bool, desc: str):
        self.bar = None
        self.ok = self.failed = self.lost = self.running = 0
        if enabled and total:
            self.bar = tqdm(total=total, desc=desc, unit="real", dynamic_ncols=True,
                            postfix=self._text(),
                            bar_format="{l_bar}{bar}| {n}/{total} [{elapsed}<{remaining}, "
                                       "{rate_fmt}{postfix}]")

    def _text(self) -> str:
        return (f"ok {self.ok}, failed {self.failed}, running {self.running}"
                + (f", lost {self.lost}" if self.lost else ""))

    def _post(self):
        if self.bar is not None:
            self.bar.set_postfix_str(self._text(), refresh=True)

    def done(self, status: str):
        if status == "ok":
            self.ok += 1
        elif status == "failed":
            self.failed += 1
        else:
            self.lost += 1
        self.running = max(0, self.running - 1)     # until the next poll of the scheduler
        if self.bar is not None:
            self.bar.set_postfix_str(self._text(), refresh=False)
            self.bar.update(1)

    def set_running(self, n: int):
        if n != self.running:
            self.running = n
            self._post()

    def close(self):
        if self.bar is not None:
            self.bar.close()



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


def run_campaign(scene: Scene, out: str | Path, realizations: int | None = None,
                 cases: Sequence[str | Case] | None = None, workers: int | None = None,
                 scheduler: str | None = None, force: bool = False, keep_vtk=None,
                 progress: bool = True, figures: bool = True, client=None,
                 cluster: ClusterSpec | None = None, fs_only: bool = False) -> CampaignResult:
    """Run (or finish) a campaign in ``out``; see the module docstring.

    ``realizations``: N per case (default ``[montecarlo] realizations``);
    ``cases``: case texts for :func:`parse_case` or :class:`Case` objects
    (default: the scene itself); ``workers``: local worker processes;
    ``scheduler``: address of a running Dask scheduler instead; ``client``: an
    existing ``distributed.Client`` to use (left open); ``cluster``: where to run
    (:class:`fem_rmpm.campaign.backends.ClusterSpec`, e.g. SLURM workers); ``keep_vtk``:
    see :func:`parse_keep_vtk`; ``fs_only``: the strength-reduction factor of safety of
    every realization instead of its MPM run (``[montecarlo] factor_of_safety``: before
    it).  Raises :class:`CampaignError` (bad input, other
    campaign in ``out``, unreachable scheduler, a refused worker job, a campaign
    directory the workers do not share) before any realization runs."""
    t_start = time.perf_counter()
    out = Path(out)
    n = scene.montecarlo.realizations if realizations is None else realizations
    _check_arguments(n, workers, scheduler, client)
    if client is not None and cluster is not None:
        raise CampaignError("give a client or a cluster, not both")
    case_list, counts, doc, lay, tasks, finished = pending_work(scene, out, n, cases,
                                                               keep_vtk, force, fs_only)
    skipped = len(finished)
    own = client is None
    backend = campaign_backend(cluster, workers, scheduler, case_list) if own else None
    desc, lost = "no workers needed", []
    if not own:
        desc = f"the given Dask client ({len(client.nthreads())} workers)"
    compute_time = 0.0
    try:
        if own and tasks:      # before anything is written: refused, unreachable -> error
            backend.preflight(len(tasks))
        with Lock(out):
            check_directory(out, doc)   # again, now that no one else can write here
            if not (out / "campaign.json").exists():
                write_json(out / "campaign.json", doc)
            clean_temporaries(out)
            if tasks:
                if client is None:
                    client, desc = backend.start(len(tasks), out), backend.description
                if progress:
                    print(f"fem-rmpm mc: {len(tasks)} realization(s) to run ({skipped} "
                          f"already finished) on {desc}; records in {out}", file=sys.stderr)
                if own:
                    backend.check_directory(client, out)   # the workers share it
                t0 = time.perf_counter()
                lost = _compute(client, tasks, lay, finished, progress, scene.scene.name)
                compute_time = time.perf_counter() - t0
            result = _finish(out, scene, case_list, counts, lay, finished,
                             len(tasks) - len(lost), skipped, lost, desc, t_start,
                             compute_time, figures)
            if (short := thread_shortfall(case_list, finished.values())) is not None:
                print(short, file=sys.stderr, flush=True)
    finally:
        if backend is not None:
            backend.close()
    return result


def pending_work(scene: Scene, out: Path, n: int, cases: Sequence[str | Case] | None,
                 keep_vtk, force: bool, fs_only: bool = False):
    """What a campaign in ``out`` has left to do (read-only; raises CampaignError for bad
    cases or another campaign in ``out``): ``(cases, counts, doc, layout, tasks,
    finished)`` with the :class:`Case` list, realizations per case, the identity
    document, the :class:`Layout`, the tasks to run and the finished records."""
    keep = parse_keep_vtk(keep_vtk, scene.montecarlo.keep_vtk)
    case_list = [c if isinstance(c, Case) else parse_case(c, scene)
                 for c in (cases or ["scene"])]
    names = [c.name for c in case_list]
    if len(set(names)) != len(names):
        raise CampaignError(f"case names must be unique, got {names}")
    counts = {c.name: _case_realizations(c, n) for c in case_list}
    doc = campaign_doc(case_list, scene.montecarlo.seed)
    check_directory(out, doc)
    lay = Layout(out, case_list)
    fs_mode = "only" if fs_only else ("before" if scene.montecarlo.factor_of_safety else "off")
    tasks, finished = _plan(scene, lay, counts, keep, force, fs_mode)
    return case_list, counts, doc, lay, tasks, finished


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


def _plan(scene: Scene, lay: Layout, counts: dict[str, int], keep, force: bool,
          fs_mode: str = "off") -> tuple[list[dict], dict]:
    """What is left to do (read-only): the tasks to run, in index-major order, and the
    finished records ``{(case, index): record}`` (none with ``force``; a record made with
    another factor-of-safety mode is recomputed)."""
    out = lay.out
    tasks, finished = [], {}
    k_rest = scene.montecarlo.runs_to_rest
    for i in range(max(counts.values())):
        decide = k_rest is not None and i >= k_rest and fs_mode != "only"
        for c in lay.cases:
            if i >= counts[c.name]:
                continue
            seed = realization_seed(scene.montecarlo.seed, i)
            rec = None if force else read_record(lay.record(c.name, i))
            if (rec is not None and rec.get("seed") == seed and rec.get("case") == c.name
                    and rec.get("fs_mode", "off") == fs_mode and (decide or not is_decided(rec))):
                finished[(c.name, i)] = rec      # a decided record serves i >= runs_to_rest
                continue
            vtk = lay.vtk(c.name, i) if kept(keep, i) and not decide else None
            tasks.append({"case": c.name, "index": i, "seed": seed, "scene": c.scene,
                          "fs": fs_mode, "decide": decide,
                          "vtk_dir": str(vtk.resolve()) if vtk is not None else None,
                          "vtk_rel": str(vtk.relative_to(out)) if vtk is not None else None})
    return tasks, finished


def _compute(client, tasks: list[dict], lay: Layout, finished: dict, progress: bool,
             name: str) -> list[str]:
    """Submit the tasks, write each record as it arrives; return the lost ones."""
    token = uuid.uuid4().hex[:8]
    keys = [f"rmpm-{token}-{t['case']}-{t['index']:05d}" for t in tasks]
    futures = client.map(run_realization, tasks, key=keys, pure=False, retries=0)
    by_key = dict(zip(keys, tasks))
    bar = _Progress(len(tasks), progress, f"{name} mc")
    lost: list[str] = []
    ours = set(keys)
    ac = as_completed(futures, with_results=False, loop=client.loop)
    last_poll = 0.0
    try:
        while not ac.is_empty():
            batch = ac.next_batch(block=False)
            if not batch:
                now = time.monotonic()
                if bar.bar is not None and now - last_poll > 1.0:
                    last_poll = now
                    try:   # executing = assigned to a worker, at most its thread count
                        proc, threads = client.processing(), client.nthreads()
                        bar.set_running(sum(min(sum(1 for k in ks if k in ours),
                                                threads.get(w, 1)) for w, ks in proc.items()))
                    except Exception:  # noqa: BLE001 - the bar is cosmetic
                        pass
                time.sleep(0.05)
                continue
            for fut in batch:
                task = by_key[fut.key]
                try:
                    rec = fut.result()
                except Exception as exc:  # noqa: BLE001 - infrastructure, not the realization
                    msg = " ".join(str(exc).split())[:300]
                    lost.append(f"{task['case']} #{task['index']}: {type(exc).__name__}: {msg}")
                    bar.done("lost")
                    fut.release()
                    continue
                profile = rec.pop("final_profile", None)
                if profile is not None:
                    write_json(lay.profile(rec["case"], rec["index"]),
                               {"case": rec["case"], "index": rec["index"], "seed": rec["seed"],
                                "final_profile": profile})
                write_json(lay.record(rec["case"], rec["index"]), rec)
                finished[(rec["case"], rec["index"])] = rec
                bar.done(rec["status"])
                fut.release()
    finally:
        bar.close()
    return lost


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


def _finish(out, scene, cases, counts, lay, finished, computed, skipped, lost, desc,
            t_start, compute_time, figures) -> CampaignResult:
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
        "cases": [{"name": c.name, "spec": c.spec, "label": c.label,
                   "deterministic": c.deterministic, "realizations": counts[c.name],
                   **stats[c.name]} for c in cases],
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
        if any("fs" in stats[c.name] for c in cases):
            res.figures.append(plot_factor_of_safety(out / "factor_of_safety.png", cases,
                                                     stats, records))
        res.figures.append(write_report(out))
    return res
