"""The size and cost of a campaign before its first core-hour (``fem-rmpm mc ... --dry-run``).

:func:`estimate_campaign` reads the campaign directory (the records already there are
not counted again), writes nothing and starts no worker.  Per case it takes the points
and the CFL step count of one run from :func:`fem_rmpm.runtime.budget.estimate_run`, and

* **steps** = the budget's count (``t_end`` over the CFL step at rest) x a *steps
  factor*: moving points shorten the step and a run that comes to rest stops early.
  From the ok records of this campaign when there are some (their mean ratio of steps
  taken to the budget's count); else :data:`fem_rmpm.runtime.budget.STEPS_FACTOR`, the mean
  ratio measured on the reference slope's literature cases;
* **CPU per realization** = setup + points x steps x the cost per point-step, with the
  cost per point-step and the setup (random field, seeding, measures) *measured on this
  machine*: from the records of this campaign (their CPU time over their point-steps)
  or, without records, by a probe in this process: the first realization to run,
  three times with a short ``t_end`` (warm-up, setup only, setup + about 2 s of steps),
  so the load of the machine at the time of the dry run is in the figure.  In 3-D the
  probe's first steps are elastic (geostatic phase, gravity ramp): the cost per
  point-step is at least the 3-D budget's whole-run figure (return mapping included);
* **the other parts of a realization**: the strength-reduction FS (``--fs``, ``--fs-only``)
  costs the mean FS CPU of this campaign's records, else one FS of the probe's
  realization measured in this process (the loading of its compiled kernels included:
  an upper bound); a run stopped once decided (``runs_to_rest``) costs the mean CPU of
  this campaign's decided runs, else the full run's (an upper bound, said in a note);
* **core-hours** = the sum over the realizations to run, plus one worker start per
  worker (the CPU this process spent on its imports, plus the probe's warm-up beyond a
  warm run: loading or compiling the numba kernels);
* **memory per worker** = the budget's peak memory of one realization (largest case);
* **wall time** = the start of one worker + the realizations spread over the workers
  (``ceil(to_run / workers)`` realizations in a row per worker, each on the local
  workers' ``[solver] threads`` at :data:`fem_rmpm.runtime.budget.THREAD_EFFICIENCY`; queue
  waits of a batch system are not included).

The estimate against a campaign's measured CPU time: the documentation's benchmark pages.
"""
from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Sequence

from fem_rmpm.api import run as run_one
from fem_rmpm.campaign.backends import ClusterSpec, campaign_backend
from fem_rmpm.campaign.case_campaign import pending_work
from fem_rmpm.campaign.cases import CampaignError, Case
from fem_rmpm.campaign.decide import is_decided
from fem_rmpm.runtime.budget import STEPS_FACTOR, RunEstimate, estimate_run, thread_speed_up
from fem_rmpm.scene import Scene, with_value

__all__ = ["STEPS_FACTOR", "CaseEstimate", "CampaignEstimate", "Calibration", "PartCosts",
           "estimate_campaign", "probe_calibration", "records_calibration", "part_costs",
           "estimate_text"]

#: CPU of point-steps the probe aims at (s): long enough to time, short enough for a dry run.
PROBE_SECONDS = 2.0


@dataclass(frozen=True)
class Calibration:
    """Cost figures of this machine: ``ns_per_point_step`` (CPU), ``setup_seconds`` (CPU of
    a realization besides its steps), ``worker_start_seconds`` (CPU of a fresh worker's
    first realization beyond the others), ``steps_factor`` and where they come from."""
    ns_per_point_step: float
    setup_seconds: float
    worker_start_seconds: float
    steps_factor: float
    source: str


@dataclass(frozen=True)
class PartCosts:
    """CPU seconds of the parts of a realization besides its MPM run to the end:
    ``fs_seconds`` (one strength-reduction FS; None: no realization has one),
    ``decided_seconds`` (an MPM run stopped once decided; None: priced as a full run), and
    where each comes from."""
    fs_seconds: float | None
    fs_source: str
    decided_seconds: float | None
    decided_source: str


@dataclass(frozen=True)
class CaseEstimate:
    name: str
    label: str
    to_run: int
    finished: int
    points: int
    budget_steps: int
    steps: int
    cpu_seconds: float          # per realization to run: the mean over its parts
    full_run_seconds: float = 0.0    # an MPM run to its end (setup included)
    decided_run_seconds: float = 0.0  # an MPM run stopped once decided
    full_runs: int = 0               # realizations to run with an MPM run to the end
    decided_runs: int = 0            # ... with an MPM run stopped once decided
    fs_runs: int = 0                 # ... with a factor of safety


@dataclass
class CampaignEstimate:
    """What ``--dry-run`` prints (see the module docstring)."""
    out: Path
    cases: list[CaseEstimate]
    calibration: Calibration
    parts: PartCosts
    workers: int
    plan: dict
    memory_per_worker_bytes: float
    cpu_seconds: float          # realizations to run + worker starts
    wall_seconds: float
    notes: list[str] = field(default_factory=list)

    @property
    def to_run(self) -> int:
        return sum(c.to_run for c in self.cases)

    @property
    def finished(self) -> int:
        return sum(c.finished for c in self.cases)

    @property
    def core_hours(self) -> float:
        return self.cpu_seconds / 3600.0

    def to_dict(self) -> dict:
        d = asdict(self)
        d["out"] = str(self.out)
        d.update(to_run=self.to_run, finished=self.finished, core_hours=self.core_hours)
        return d


# --------------------------------------------------------------------------- calibration

def records_calibration(records: Sequence[dict], budget: dict[str, RunEstimate]
                        ) -> Calibration | None:
    """Calibration from the ok records of this campaign (None without any): cost per
    point-step = their CPU time over their point-steps (setup and worker starts
    included, so both are reported as 0), steps factor = mean steps / budget steps."""
    ok = [r for r in records if r.get("status") == "ok" and r.get("cpu_time") is not None
          and r.get("steps") and r.get("particles") and r.get("case") in budget]
    if not ok:
        return None
    point_steps = sum(r["steps"] * r["particles"] for r in ok)
    ns = 1e9 * sum(r["cpu_time"] - _fs_cpu(r) for r in ok) / point_steps
    factor = sum(r["steps"] / max(budget[r["case"]].steps, 1) for r in ok) / len(ok)
    return Calibration(ns, 0.0, 0.0, factor, f"the {len(ok)} finished record(s) of this "
                       "campaign (CPU time over point-steps; setup and worker starts included)")


def _fs_cpu(rec: dict) -> float:
    """CPU seconds of a record's factor of safety (0 without one)."""
    return float((rec.get("fs") or {}).get("cpu_time") or 0.0)


def part_costs(records: Sequence[dict], fs_probe=None) -> PartCosts:
    """The FS and decided-run costs (:class:`PartCosts`) from the records of this campaign:
    the mean FS CPU of those with a factor of safety, else ``fs_probe()`` if given (CPU
    seconds of one FS measured now), else None; the mean CPU of the decided runs (their
    FS taken out), else None."""
    with_fs = [_fs_cpu(r) for r in records if _fs_cpu(r) > 0.0]
    decided = [r["cpu_time"] - _fs_cpu(r) for r in records
               if is_decided(r) and r.get("cpu_time") is not None]
    if with_fs:
        fs, fs_src = sum(with_fs) / len(with_fs), f"the {len(with_fs)} record(s) with an FS"
    elif fs_probe is not None:
        fs, fs_src = fs_probe(), ("one FS of the probe's realization measured now, the "
                                  "loading of its compiled kernels included")
    else:
        fs, fs_src = None, "no factor of safety"
    if decided:
        return PartCosts(fs, fs_src, sum(decided) / len(decided),
                         f"the {len(decided)} decided run(s) of this campaign")
    return PartCosts(fs, fs_src, None, "priced as full runs: an upper bound until this "
                     "campaign has recorded some")


def _fs_probe(scene: Scene, seed: int) -> float:
    """CPU seconds of the factor of safety of realization ``seed`` of ``scene``, now."""
    from fem_rmpm.campaign.factor_of_safety import fs_measures    # lazy: the implicit scheme
    c0 = time.process_time()
    fs_measures(scene, seed)
    return time.process_time() - c0


def _timed_run(scene: Scene, seed: int, t_end: float) -> tuple[float, int]:
    """(CPU seconds, steps) of one run of ``scene`` cut at ``t_end``, nothing written."""
    short = with_value(scene, "solver.t_end", float(t_end))
    c0 = time.process_time()
    res = run_one(short, out=None, seed=seed, progress=False, vtk=False, figures=False)
    return time.process_time() - c0, int(res.summary["steps"])


def probe_calibration(scene: Scene, seed: int) -> Calibration:
    """Measure the cost per point-step in this process (module docstring): three short
    runs of ``scene`` with ``seed`` (warm-up; a few steps; about :data:`PROBE_SECONDS`
    of steps); nothing is written."""
    est = estimate_run(scene)
    sv = scene.solver
    if sv.scheme == "implicit" and not sv.dynamic:   # load steps: t_end does not cut it
        return Calibration(est.ns_per_point_step, 0.0, 0.0, 1.0,
                           f"the budget's constant ({est.machine}); quasi-static implicit "
                           "runs are not probed")
    imports = time.process_time()     # this process so far: the imports a worker makes too
    step = sv.dt if sv.scheme == "implicit" else est.dt
    n_long = int(min(max(PROBE_SECONDS / (est.points * est.ns_per_point_step * 1e-9), 20),
                     est.steps))
    warm, _ = _timed_run(scene, seed, 2 * step)
    few, n_few = _timed_run(scene, seed, 2 * step)
    many, n_many = _timed_run(scene, seed, n_long * step)
    points = max(est.points, 1)
    ns = 1e9 * max(many - few, 0.0) / max((n_many - n_few) * points, 1)
    if ns <= 0:
        ns = est.ns_per_point_step
    setup = max(few - n_few * points * ns * 1e-9, 0.0)
    return Calibration(ns, setup, imports + max(warm - few, 0.0), STEPS_FACTOR,
                       f"a probe in this process now: {n_many} steps of {points:,} points "
                       f"in {many:.2f} s CPU; imports {imports:.1f} s and warm-up "
                       f"{warm - few:.1f} s per worker")


def _whole_run_floor(cal: Calibration, est: RunEstimate, scene: Scene) -> Calibration:
    """A 3-D probe times the first steps, which are elastic (the geostatic phase or the
    gravity ramp): its cost per point-step is at least the budget's whole-run figure of
    the 3-D step (:mod:`fem_rmpm.runtime.budget3d`, the return mapping included), and says
    which it took.  Plane-strain calibrations are returned unchanged."""
    if scene.grid.dimension != 3 or cal.ns_per_point_step >= est.ns_per_point_step:
        return cal
    return replace(cal, ns_per_point_step=est.ns_per_point_step,
                   source=f"{cal.source}; the probe's {cal.ns_per_point_step:.0f} ns per "
                   "point-step are elastic first steps, below the budget's whole-run "
                   f"figure, which is used ({est.machine})")


# --------------------------------------------------------------------------- the estimate

def estimate_campaign(scene: Scene, out: str | Path, realizations: int | None = None,
                      cases: Sequence[str | Case] | None = None, *,
                      workers: int | None = None, scheduler: str | None = None,
                      force: bool = False, keep_vtk=None,
                      cluster: ClusterSpec | None = None, probe: bool = True,
                      fs_only: bool = False) -> CampaignEstimate:
    """The size and cost of ``run_campaign`` with the same arguments (module docstring);
    raises :class:`fem_rmpm.campaign.CampaignError` for the input errors it would raise
    (bad N, cases, options, another campaign in ``out``, a refused job script).
    ``probe=False`` uses the budget's constant instead of measuring (and prices no FS
    without records of one)."""
    out = Path(out)
    n = scene.montecarlo.realizations if realizations is None else realizations
    if isinstance(n, bool) or not isinstance(n, int) or n <= 0:
        raise CampaignError(f"-n {n}: the number of realizations must be a positive integer")
    pending = pending_work(scene, out, n, cases, keep_vtk=keep_vtk, force=force,
                           fs_only=fs_only)
    case_list, counts = pending.cases, pending.counts
    tasks, finished = pending.tasks, pending.finished
    backend = campaign_backend(cluster, workers, scheduler, case_list)
    plan = backend.plan(max(len(tasks), 1))
    budget = {c.name: estimate_run(c.scene) for c in case_list}
    records = list(finished.values())
    cal = records_calibration(records, budget)
    with_mpm = [t for t in tasks if t["fs"] != "only"]
    if cal is None and with_mpm and probe:
        first = _case_of(with_mpm[0], case_list)
        cal = _whole_run_floor(probe_calibration(first.scene, with_mpm[0]["seed"]),
                               budget[first.name], first.scene)
    if cal is None:
        e = next(iter(budget.values()))
        cal = Calibration(e.ns_per_point_step, 0.0, 0.0, STEPS_FACTOR,
                          f"the budget's constant ({e.machine})")
    with_fs = [t for t in tasks if t["fs"] != "off"]
    fs_probe = None
    if with_fs and probe:
        fs_case = _case_of(with_fs[0], case_list)
        fs_probe = lambda: _fs_probe(fs_case.scene, with_fs[0]["seed"])  # noqa: E731
    parts = part_costs(records, fs_probe)
    per_case = [_case_estimate(c, budget[c.name], cal, parts,
                               [t for t in tasks if t["case"] == c.name],
                               sum(1 for (k, i) in finished if k == c.name
                                   and i < counts[c.name]))
                for c in case_list]
    k = _worker_count(plan, len(tasks))
    work = sum(ce.to_run * ce.cpu_seconds for ce in per_case)
    mean = work / max(len(tasks), 1)
    cpu = work + k * cal.worker_start_seconds if tasks else 0.0
    threads = int(plan.get("cores_per_worker") or 1)
    wall = (cal.worker_start_seconds + math.ceil(len(tasks) / k) * mean
            / thread_speed_up(threads)) if tasks else 0.0
    memory = max(e.memory_bytes for e in budget.values())
    notes = []
    per_worker = plan.get("memory_per_worker_bytes")
    if per_worker is not None and per_worker < memory:
        notes.append(f"the worker memory ({per_worker / 2**20:.0f} MiB) is below the estimated "
                     f"peak of one realization ({memory / 2**20:.0f} MiB): raise --memory")
    return CampaignEstimate(out, per_case, cal, parts, k, plan, memory, cpu, wall, notes)


def _case_of(task: dict, case_list: Sequence[Case]) -> Case:
    """The case a task belongs to."""
    return next(c for c in case_list if c.name == task["case"])


def _case_estimate(case: Case, e: RunEstimate, cal: Calibration, parts: PartCosts,
                   tasks: list[dict], finished: int) -> CaseEstimate:
    """One case's line of the estimate: each task to run costs its parts (the MPM run to
    its end or stopped once decided, the FS) and :attr:`CaseEstimate.cpu_seconds` is
    their mean."""
    steps = int(round(e.steps * cal.steps_factor))
    full = cal.setup_seconds + e.points * steps * cal.ns_per_point_step * 1e-9
    decided = full if parts.decided_seconds is None else parts.decided_seconds
    n_full = sum(t["fs"] != "only" and not t.get("decide") for t in tasks)
    n_decided = sum(t["fs"] != "only" and bool(t.get("decide")) for t in tasks)
    n_fs = sum(t["fs"] != "off" for t in tasks)
    work = n_full * full + n_decided * decided + n_fs * (parts.fs_seconds or 0.0)
    return CaseEstimate(case.name, case.label, len(tasks), finished, e.points, e.steps, steps,
                        work / len(tasks) if tasks else full, full, decided, n_full,
                        n_decided, n_fs)


def _worker_count(plan: dict, n_tasks: int) -> int:
    w = plan.get("workers")
    if isinstance(w, int) and w > 0:
        return w
    if isinstance(w, str) and ".." in w:           # adaptive: at most MAX, at most the tasks
        return max(1, min(int(w.split("..")[1]), n_tasks))
    return max(1, n_tasks)


def _hms(s: float) -> str:
    s = int(round(s))
    return f"{s // 3600:d}:{s % 3600 // 60:02d}:{s % 60:02d}"


def estimate_text(est: CampaignEstimate) -> str:
    """The ``--dry-run`` report (one block of lines)."""
    cal = est.calibration
    lines = [f"Dry run of the campaign in {est.out}: nothing written, no worker started.",
             f"  realizations to run: {est.to_run} ({est.finished} already finished)"]
    parts = est.parts
    for c in est.cases:
        lines.append(f"  {c.label}: {c.to_run} to run, {c.points:,} points, about "
                     f"{c.steps:,} steps each ({c.budget_steps:,} CFL steps at rest x "
                     f"{cal.steps_factor:.2f}), {c.cpu_seconds:.1f} s CPU each"
                     + (":" if c.decided_runs or c.fs_runs else ""))
        if c.decided_runs or c.fs_runs:
            if c.full_runs:
                lines.append(f"    {c.full_runs} MPM run(s) to the end, "
                             f"{c.full_run_seconds:.1f} s CPU each")
            if c.decided_runs:
                lines.append(f"    {c.decided_runs} MPM run(s) stopped once decided, "
                             f"{c.decided_run_seconds:.1f} s CPU each ({parts.decided_source})")
            if c.fs_runs:
                lines.append(f"    {c.fs_runs} factor(s) of safety, {parts.fs_seconds or 0:.1f} s "
                             f"CPU each ({parts.fs_source})")
    lines += [f"  cost per point-step: {cal.ns_per_point_step:.0f} ns CPU, setup "
              f"{cal.setup_seconds:.1f} s, worker start {cal.worker_start_seconds:.1f} s "
              f"(from {cal.source})",
              f"  core-hours: {est.core_hours:.3g} ({est.cpu_seconds:.0f} s CPU)",
              f"  memory per worker: {est.memory_per_worker_bytes / 2**20:.0f} MiB estimated "
              "peak of one realization",
              f"  workers: {est.plan.get('description')}",
              f"  wall time with {est.workers} worker(s): about {_hms(est.wall_seconds)} "
              "(queue waits not included)"]
    if est.plan.get("checked"):
        lines.append(f"  job script accepted by the batch system's test submission: "
                     f"{est.plan['checked']}")
    if est.plan.get("job_script"):
        lines.append("  job script:")
        lines += ["    " + s for s in est.plan["job_script"].strip().splitlines()]
    lines += [f"  note: {s}" for s in est.notes]
    return "\n".join(lines)
