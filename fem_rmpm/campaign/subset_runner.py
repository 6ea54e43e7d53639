"""Subset-simulation campaigns of a scene on Dask: small probabilities at a fraction of the runs.

``fem-rmpm mc SCENE --method subset --response NAME --threshold X [--p0 0.1] [-n N]``
(or :func:`run_subset_campaign`) estimates ``P(response > X)`` (``P(FS < X)`` for the
factor of safety) by subset simulation (:mod:`fem_rmpm.campaign.methods.subset`; any
response method of :data:`fem_rmpm.campaign.methods.METHODS`) in the noise space of the
scene's random field: a realization is a pure function of (scene, noise),
:func:`fem_rmpm.random_field.noise_shape` standard normals.  The samples run through the
campaign runner (:mod:`fem_rmpm.campaign.runner`).

* **Responses**: the measures the table marks as responses
  (:func:`fem_rmpm.measures.table.responses`): ``runout_distance``,
  ``retrogression_distance``, ``sliding_area``, ``max_displacement`` (failure: above the
  threshold) or ``factor_of_safety`` (strength reduction; failure: FS below the threshold,
  1 by default).  Aliases: ``runout``, ``run-out``, ``retrogression``, ``fs``.
* **Batches.** Level 0 is one batch of ``N`` realizations, which are the crude Monte
  Carlo realizations ``0 .. N-1`` (same seeds, same fields); every step of the Markov
  chains is one batch of ``N p0`` independent realizations.  Batches run on the same
  Dask clusters as crude Monte Carlo (``--workers``, ``--scheduler``).
* **Records.** Each finished sample is written atomically (temporary file + rename) as
  ``records/L01_C00042_S003.json`` (level, chain, step): the crude record of the
  realization (status, measures, steps, times, worker) plus ``key``, ``level``,
  ``chain``, ``step``, ``seed`` (level 0: the realization seed; chains: null),
  ``start`` (key of the chain state the candidate was proposed from),
  ``noise_digest`` (SHA-256 of the candidate's float64 noise; the noise itself is
  replayed from the records: :func:`sample_noise`), ``value`` (the response),
  ``level_threshold`` and ``accepted``.
* **Resuming and identity.** The method is deterministic given the responses, so a
  re-run replays the campaign from its records and computes only the samples without
  one: a campaign killed during a level resumes at the sample where it stopped and ends
  with the same estimate and records as an uninterrupted one, on 1 or N workers.  A
  record is reused only if its key, seed and noise digest match the replayed sample.
  ``campaign.json`` holds the scene, the campaign seed, the response, ``p0`` and ``N``;
  another scene, response, ``p0`` or ``N`` in the same directory is an error.  The
  threshold is not part of the identity: the levels do not depend on it until the last
  one, so a re-run with a rarer threshold reuses every record and adds levels.
* **Failed realizations** (a :class:`fem_rmpm.schemes.common.SimulationError`) are recorded and
  count as runs that exceed no threshold (a rejected candidate); the summary counts them.
* **Output.** ``summary.json`` (``"subset"``: P, its COV with the chain correlation
  (Au & Beck 2001), the thresholds, per-level conditional probability, COV, chain
  correlation factor, acceptance rate; total runs and the crude Monte Carlo runs the same
  COV would need), ``samples.csv`` (one row per record), ``subset_levels.png`` (the
  responses of each level's samples with the thresholds) and ``report.html``.
"""
from __future__ import annotations

import csv
import hashlib
import io
import json
import math
import os
import socket
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterator

import numpy as np

from fem_rmpm import api
from fem_rmpm.campaign.backends import ClusterSpec, campaign_backend
from fem_rmpm.campaign.cases import CampaignError, parse_case
from fem_rmpm.campaign.methods import (
    METHODS,
    MethodOptions,
    MethodResult,
    Sample,
    SubsetSimulation,
    SubsetWarning,
)
from fem_rmpm.campaign.report import write_report
from fem_rmpm.campaign.runner import Execution, RunTally, run_method_campaign
from fem_rmpm.campaign.store import FORMAT, campaign_doc, check_directory, read_record
from fem_rmpm.campaign.subset_plots import plot_levels
from fem_rmpm.campaign.task import run_realization
from fem_rmpm.discretise.grid import make_grid
from fem_rmpm.io.output import _atomic_write_bytes, write_json
from fem_rmpm.measures import table as measure_table
from fem_rmpm.random_field import field_noise
from fem_rmpm.runtime.machine import describe as describe_machine
from fem_rmpm.runtime.machine import tally
from fem_rmpm.scene import Scene
from fem_rmpm.schemes.common import SimulationError
from fem_rmpm.schemes.implicit.strength_reduction import FSOptions, factor_of_safety

__all__ = ["SUBSET_FORMAT", "Response", "parse_response", "run_subset_sample",
           "run_subset_campaign", "SubsetCampaignResult",
           "sample_noise", "sample_noises"]

SUBSET_FORMAT = "fem_rmpm subset campaign 1"
FS_RESPONSE = "factor_of_safety"


@dataclass(frozen=True)
class Response:
    """A response of a realization and its failure threshold (``value > threshold``, or
    ``value < threshold`` for a response failing below, the factor of safety)."""
    name: str
    threshold: float

    @property
    def below(self) -> bool:
        return getattr(measure_table.MEASURES.get(self.name), "response", None) == "below"

    def exceedance(self, value: float | None) -> float:
        """The subset variable Y (failure: Y > y_threshold); NaN for a missing value."""
        if value is None or not math.isfinite(value):
            return math.nan
        return -float(value) if self.below else float(value)

    @property
    def y_threshold(self) -> float:
        return -self.threshold if self.below else self.threshold

    def describe(self) -> str:
        unit = measure_table.unit(self.name)
        return f"{self.name} {'<' if self.below else '>'} {self.threshold:g}" + (
            f" {unit}" if unit != "-" else "")


def parse_response(name: str | None, threshold: float | None) -> Response:
    """The response named on the command line (a response of the measure table or an
    alias)."""
    allowed = (", ".join(measure_table.responses()) + " (aliases: "
               + ", ".join(measure_table.response_aliases()) + ")")
    if not name:
        raise CampaignError(f"--method subset needs --response NAME; allowed: {allowed}")
    key = measure_table.resolve_response(name)
    if key is None:
        raise CampaignError(f"--response {name!r}: not a response of a realization; "
                            f"allowed: {allowed}")
    if threshold is None:
        if key != FS_RESPONSE:
            raise CampaignError(f"--response {key} needs --threshold X (failure: "
                                f"{key} > X, in {measure_table.unit(key)})")
        threshold = 1.0
    if isinstance(threshold, bool) or not isinstance(threshold, (int, float)) \
            or not math.isfinite(threshold):
        raise CampaignError(f"--threshold {threshold!r}: expected a finite number")
    return Response(key, float(threshold))


def noise_digest(noise: np.ndarray) -> str:
    """SHA-256 of the noise as C-ordered float64 bytes (the record's noise reference)."""
    return hashlib.sha256(np.ascontiguousarray(noise, dtype=np.float64).tobytes()).hexdigest()


# --------------------------------------------------------------------------- the task

def _factor_of_safety_record(task: dict) -> dict:
    """The record of a strength-reduction run of the sample
    (:mod:`fem_rmpm.schemes.implicit.strength_reduction`): status, error, ``value`` = FS (the bound
    for "FS > f_max" / "FS < f_min"), its bound, bracket and number of static solves, worker, wall
    and CPU time."""
    rec: dict[str, Any] = {"format": FORMAT, "case": task["case"], "index": int(task["index"]),
                           "seed": task["seed"], "scheme": "strength_reduction",
                           "status": "ok", "error": None, "vtk": None, "value": None,
                           "worker": {"host": socket.gethostname(), "pid": os.getpid()}}
    t0, c0 = time.perf_counter(), time.process_time()
    try:
        grid, pts = api.prepare(task["scene"], task["seed"], task.get("noise"))
        res = factor_of_safety(task["scene"], task["seed"], FSOptions(**task["fs_options"]),
                               grid=grid, pts=pts)
    except (SimulationError, ValueError) as exc:
        rec.update(status="failed", error=" ".join(str(exc).split()) or type(exc).__name__,
                   measures=None)
    else:
        rec["value"] = float(res.fs)
        rec["measures"] = {FS_RESPONSE: float(res.fs), "fs_bound": res.bound,
                           "fs_bracket_low": float(res.bracket[0]),
                           "fs_bracket_high": float(res.bracket[1]),
                           "static_solves": res.static_solves}
    rec["wall_time"] = time.perf_counter() - t0
    rec["cpu_time"] = time.process_time() - c0
    return rec


def run_subset_sample(task: dict) -> dict:
    """The Dask task of one subset sample: the crude realization record
    (:func:`fem_rmpm.campaign.task.run_realization`, with the ``noise`` array in place of
    the seed for chain samples) plus the sample's position and its response ``value``."""
    if task["response"] == FS_RESPONSE:
        rec = _factor_of_safety_record(task)
    else:
        rec = run_realization(task)
        rec.pop("final_profile", None)
        m = rec.get("measures") or {}
        rec["value"] = m.get(task["response"]) if rec["status"] == "ok" else None
    rec.update({k: task[k] for k in ("key", "level", "chain", "step", "start",
                                     "noise_digest", "response", "level_threshold")})
    return rec


# --------------------------------------------------------------------------- the client

@dataclass
class SubsetCampaignResult:
    """What :func:`run_subset_campaign` did: the estimate (``result``, a
    :class:`fem_rmpm.campaign.methods.MethodResult`; None if samples were lost) and the
    samples this command computed, reused from records and lost."""
    out: Path
    response: Response
    result: MethodResult | None
    computed: int
    reused: int
    lost: list[str]
    wall_time: float
    compute_time: float
    workers: str
    figures: list[Path] = field(default_factory=list)


def _record_path(out: Path, key: str) -> Path:
    return out / "records" / f"{key}.json"


class _SubsetEvaluation:
    """The runner's view of a response campaign (:class:`fem_rmpm.campaign.runner.Evaluation`):
    a sample's record (``records/<key>.json``) is reused if its key, seed, noise digest and
    response match (none with ``force``); its response is the subset variable Y."""
    task_function = staticmethod(run_subset_sample)

    def __init__(self, scene: Scene, response: Response, doc: dict, force: bool,
                 fs_options: dict):
        self.scene, self.response, self.doc = scene, response, doc
        self.force, self.fs_options = force, fs_options
        self.records: dict[str, dict] = {}
        self.out = Path()

    def check_directory(self, out: Path) -> None:
        self.out = out
        _check_subset_directory(out, self.doc)

    def clean_temporaries(self, out: Path) -> None:
        _clean_temporaries(out)

    def task_key(self, task: dict) -> str:
        return task["key"]

    def task_name(self, task: dict) -> str:
        return task["key"]

    def plan(self, batch: list[Sample]) -> list[dict]:
        tasks = []
        for s in batch:
            digest = noise_digest(s.noise) if s.noise is not None else None
            rec = None if self.force else read_record(_record_path(self.out, s.key))
            if (rec is not None and rec.get("key") == s.key and rec.get("seed") == s.seed
                    and rec.get("noise_digest") == digest
                    and rec.get("response") == self.response.name):
                self.records[s.key] = rec
            else:
                tasks.append(self._task(s, digest))
        return tasks

    def _task(self, s: Sample, digest: str | None) -> dict:
        return {"case": "scene", "index": s.chain, "seed": s.seed, "noise": s.noise,
                "scene": self.scene, "vtk_dir": None, "vtk_rel": None, "key": s.key,
                "level": s.level, "chain": s.chain, "step": s.step, "start": s.start,
                "noise_digest": digest, "response": self.response.name,
                "level_threshold": s.level_threshold, "fs_options": self.fs_options}

    def arrived(self, rec: dict) -> None:
        rec["accepted"] = (None if rec["level_threshold"] is None else
                           bool(self.response.exceedance(rec["value"])
                                >= rec["level_threshold"]))
        write_json(_record_path(self.out, rec["key"]), rec)
        self.records[rec["key"]] = rec

    def responses(self, batch: list[Sample]) -> list[float]:
        return [self.response.exceedance(self.records[s.key].get("value"))
                if self.records[s.key]["status"] == "ok" else math.nan for s in batch]


def _identity(scene: Scene, response: Response, p0: float, n: int, fs_options: dict,
              method: str = "subset") -> dict:
    doc = campaign_doc([parse_case("scene", scene)], scene.montecarlo.seed)
    doc["format"] = SUBSET_FORMAT
    doc["method"] = {"name": method, "response": response.name, "p0": p0,
                     "samples_per_level": n}
    if response.name == FS_RESPONSE:
        doc["method"]["fs_options"] = fs_options
    return doc


def _check_subset_directory(out: Path, doc: dict) -> None:
    """Raise CampaignError unless ``out`` is free or holds this subset campaign."""
    check_directory(out, doc, fmt=SUBSET_FORMAT)
    meta = out / "campaign.json"
    if meta.exists():
        old = json.loads(meta.read_text()).get("method")
        if old != doc["method"]:
            diff = [f"{k} = {old.get(k)!r} there, {v!r} here" for k, v in doc["method"].items()
                    if (old or {}).get(k) != v] if isinstance(old, dict) else ["no method"]
            raise CampaignError(f"{out}: holds a subset campaign with {'; '.join(diff)}; "
                                "nothing was changed; choose another --out")


def _clean_temporaries(out: Path) -> None:
    for p in (out / "records").glob(".L*.tmp"):
        try:
            p.unlink()
        except OSError:
            pass


def _check_fs_options(options: dict) -> None:
    try:
        FSOptions(**options)
    except TypeError as exc:
        raise CampaignError(f"fs_options {options!r}: {exc}") from None


def run_subset_campaign(scene: Scene, out: str | Path, response: str | Response,
                        threshold: float | None = None, *, p0: float = 0.1,
                        n: int | None = None,
                        workers: int | None = None, scheduler: str | None = None,
                        client=None, force: bool = False, progress: bool = True,
                        figures: bool = True, fs_options: dict | None = None,
                        cluster: ClusterSpec | None = None,
                        method: str = "subset") -> SubsetCampaignResult:
    """Run (or finish, or extend) a subset-simulation campaign in ``out`` (module docstring).

    ``response``: a response's name or alias (or a :class:`Response`);
    ``threshold``: failure above it (below it for the FS, default 1); ``p0``: level
    probability in (0, 0.5]; ``n``: samples per level (default 1000; ``n p0 >= 10``);
    ``workers`` / ``scheduler`` / ``client`` / ``cluster``: as for crude Monte Carlo
    (:func:`fem_rmpm.campaign.run_campaign`; ``cluster`` a
    :class:`~fem_rmpm.campaign.backends.ClusterSpec`, e.g. SLURM workers); ``fs_options``:
    :class:`fem_rmpm.schemes.implicit.strength_reduction.FSOptions` fields for the factor of safety
    (part of the campaign identity); ``method``: a response method of
    :data:`fem_rmpm.campaign.methods.METHODS`.  Raises
    :class:`CampaignError` or :class:`SubsetError` (both input errors) before anything
    is written."""
    t_start = time.perf_counter()
    out = Path(out)
    resp = response if isinstance(response, Response) else parse_response(response, threshold)
    n = 1000 if n is None else n
    if scene.random_field is None:
        raise CampaignError(f"{scene.source}: subset simulation needs a [random_field]; "
                            "without one every realization is the same")
    if resp.name == FS_RESPONSE:
        _check_fs_options(fs_options or {})
    grid = make_grid(scene)
    entry = METHODS.get(method)
    if entry is None or not entry.response:
        allowed = ", ".join(k for k, e in METHODS.items() if e.response)
        raise CampaignError(f"--method {method!r}: not a method of response campaigns; "
                            f"allowed: {allowed}")
    sampler = entry.make(MethodOptions(
        n=n, seed=scene.montecarlo.seed, threshold=resp.y_threshold, p0=p0,
        noise_from_seed=lambda seed: field_noise(scene, grid, seed).ravel(),
        on_failure="reject", label=resp.describe()))
    doc = _identity(scene, resp, float(p0), int(n), dict(fs_options or {}), method)
    _check_subset_directory(out, doc)
    if client is not None and cluster is not None:
        raise CampaignError("give a client or a cluster, not both")
    kind = _SubsetEvaluation(scene, resp, doc, force, dict(fs_options or {}))
    backend = (campaign_backend(cluster, workers, scheduler, [parse_case("scene", scene)])
               if client is None else None)
    # a local cluster sized for a level, not for its (possibly small) first batch
    run = Execution(backend, client, preflight=n, start_size=lambda k: max(k, 1000),
                    progress=f"{scene.scene.name} subset" if progress else None)

    def finish(tally: RunTally) -> SubsetCampaignResult:
        result = sampler.result() if tally.finished else None
        res = SubsetCampaignResult(out, resp, result, tally.computed, tally.reused,
                                   tally.lost, time.perf_counter() - t_start,
                                   tally.compute_time, tally.workers)
        if result is not None:
            _finish(res, scene, sampler, kind.records, figures)
        return res

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SubsetWarning)
        res = run_method_campaign(sampler, kind, out, doc, run, finish)
    res.wall_time = time.perf_counter() - t_start
    return res


# --------------------------------------------------------------------------- outputs

_CSV_FIRST = ("key", "level", "chain", "step", "seed", "start", "status", "value",
              "level_threshold", "accepted")


def _fmt(v: Any) -> str:
    if v is None:
        return ""
    if isinstance(v, bool):
        return "1" if v else "0"
    return repr(v) if isinstance(v, float) else str(v)


def write_samples_csv(path: Path, records: list[dict]) -> None:
    """``samples.csv``: one row per record in (level, chain, step) order, then the measures."""
    rows = sorted(records, key=lambda r: (r["level"], r["chain"], r["step"]))
    extra = sorted({k for r in rows for k in (r.get("measures") or {})})
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow([*_CSV_FIRST, *extra, "error"])
    for r in rows:
        m = r.get("measures") or {}
        w.writerow([_fmt(r.get(k)) for k in _CSV_FIRST] + [_fmt(m.get(k)) for k in extra]
                   + [_fmt(r.get("error"))])
    _atomic_write_bytes(path, buf.getvalue().encode())


def _level_dict(lv, response: Response) -> dict:
    d = lv.as_dict()
    d.pop("responses")
    d["threshold_response"] = -lv.threshold if response.below else lv.threshold
    return d


def _finish(res: SubsetCampaignResult, scene: Scene, method: SubsetSimulation,
            records: dict[str, dict], figures: bool) -> None:
    r, resp = res.result, res.response
    recs = list(records.values())
    write_samples_csv(res.out / "samples.csv", recs)
    walls = [x["wall_time"] for x in recs if x.get("wall_time") is not None]
    cpus = [x["cpu_time"] for x in recs if x.get("cpu_time") is not None]
    failed = sum(1 for x in recs if x["status"] != "ok")
    summary = {
        "method": "subset", "scene": scene.scene.name, "scene_file": scene.source,
        "campaign_seed": scene.montecarlo.seed,
        "failure_displacement": scene.montecarlo.failure_displacement,
        "failure_area": scene.montecarlo.failure_area,
        "subset": {"response": resp.name, "failure": resp.describe(),
                   "threshold": resp.threshold, "p0": method.p0,
                   "samples_per_level": method.n, "probability": r.probability,
                   "cov": r.cov, "total_runs": r.total_runs,
                   "crude_equivalent_runs": r.crude_equivalent_runs,
                   "failed_runs": failed, "notes": r.notes,
                   "thresholds": [x["threshold_response"] for x in
                                  (_level_dict(lv, resp) for lv in r.levels)],
                   "levels": [_level_dict(lv, resp) for lv in r.levels]},
        "this_run": {"computed": res.computed, "reused_records": res.reused,
                     "workers": res.workers, "compute_wall_time": res.compute_time,
                     "wall_time": res.wall_time, "machine": describe_machine()},
        "worker_machines": tally(x.get("worker") for x in recs),
        "realization_wall_time": {"mean": float(np.mean(walls)) if walls else None,
                                  "total": float(np.sum(walls)) if walls else None},
        "realization_cpu_time": {"mean": float(np.mean(cpus)) if cpus else None,
                                 "total": float(np.sum(cpus)) if cpus else None},
    }
    write_json(res.out / "summary.json", summary)
    if figures:
        res.figures = [plot_levels(res.out / "subset_levels.png", r, resp, scene.scene.name,
                                   measure_table.unit(resp.name)),
                       write_report(res.out)]


def sample_noises(scene: Scene, out: str | Path) -> Iterator[tuple[str, np.ndarray]]:
    """``(key, noise)`` of every sample of the campaign in ``out`` in the order the method
    asked for them, replayed from its records; stops before the first batch one of whose
    samples has no record (the noise of that batch's samples is still yielded)."""
    doc = json.loads((Path(out) / "campaign.json").read_text())["method"]
    grid = make_grid(scene)

    def noise_from_seed(seed: int) -> np.ndarray:
        return field_noise(scene, grid, seed).ravel()

    method = METHODS[doc["name"]].make(MethodOptions(
        n=doc["samples_per_level"], seed=scene.montecarlo.seed, threshold=1e300, p0=doc["p0"],
        noise_from_seed=noise_from_seed, on_failure="reject", max_levels=99))
    resp = Response(doc["response"], 1.0)
    while (batch := method.next_batch()) is not None:
        ys = []
        for s in batch:
            yield s.key, (s.noise if s.noise is not None else noise_from_seed(s.seed))
        for s in batch:
            rec = read_record(_record_path(Path(out), s.key))
            if rec is None:
                return
            ys.append(resp.exceedance(rec.get("value")) if rec["status"] == "ok" else math.nan)
        method.tell(ys)


def sample_noise(scene: Scene, out: str | Path, key: str) -> np.ndarray:
    """The noise vector of sample ``key`` of the campaign in ``out``, replayed from its
    records (``api.run(scene, noise=sample_noise(scene, out, key))`` re-runs it)."""
    for k, noise in sample_noises(scene, out):
        if k == key:
            return noise
    raise CampaignError(f"{out}: the campaign has no sample {key}, or a sample before it "
                        "has no record")
