"""Where a campaign's realizations run: one backend protocol for a local Dask cluster, a
running Dask scheduler, and worker jobs on a batch system (SLURM, PBS, SGE, LSF).

A :class:`Backend` is opened from a :class:`ClusterSpec`
(:mod:`fem_rmpm.campaign.cluster_spec`) by :func:`open_backend` (which checks the options
and starts nothing), then

* ``start(n_tasks)`` returns a ``distributed.Client`` with workers coming (it raises
  :class:`ClusterError`, exit 2, for a refused job submission: the batch system's own
  reason in one line, e.g. ``sbatch: error: invalid partition specified: nosuch``);
* ``check_directory(client, out)`` makes sure the workers see the campaign directory
  ``out`` and can write to it (the workers write the kept VTK there); a worker that
  does not see the client's probe file is a :class:`ClusterError`;
* ``plan(n_tasks)`` describes what ``start`` would start, for ``--dry-run`` (it starts
  nothing and writes nothing in the campaign directory; on SLURM the job script is
  checked by ``sbatch --test-only``);
* ``close()`` closes the client and the cluster (worker jobs are cancelled).

Kinds
-----
``local`` (default): a ``distributed.LocalCluster`` of K worker processes, each with
``[solver] threads`` numba threads (1 for 0, the default; ``--workers K``, default as
many as the usable CPUs hold, at most the realizations to run).
``local`` with ``--scheduler ADDRESS``: the workers of a running Dask cluster.
``slurm`` | ``pbs`` | ``sge`` | ``lsf``: dask-jobqueue's ``SLURMCluster``,
``PBSCluster``, ``SGECluster`` or ``LSFCluster``, one row of :data:`BATCH_SYSTEMS` each
(a :class:`BatchSystem`: a new batch system is one row).  The scheduler runs in the client
(the ``fem-rmpm mc`` process, on the login node or in a job of its own); each batch
job runs ``processes`` single-thread Dask workers on ``cores`` cores with ``memory``.

Configuration of the batch jobs, highest precedence first:

1. command-line options: ``--queue``, ``--account`` (``project`` on SGE and LSF),
   ``--cores`` and ``--memory`` per job, ``--walltime``, ``--job-directive`` (repeatable,
   e.g. ``--job-directive=--constraint=skylake``), ``--interface`` (network interface
   of the scheduler and the workers, e.g. ``ib0``; ``lo`` on a single machine);
2. the Dask configuration: ``jobqueue.<kind>.*`` in ``~/.config/dask/jobqueue.yaml``,
   ``$DASK_CONFIG`` or ``DASK_JOBQUEUE__SLURM__QUEUE=...`` variables, read by
   dask-jobqueue itself (the file users of dask-jobqueue already have);
3. fem_rmpm's defaults where the Dask configuration has none: ``cores = 1``,
   ``processes = cores`` (one single-thread worker per core: a realization is
   single-threaded), ``memory`` = ``processes`` x the larger of 1 GiB and twice the
   estimated peak memory of one realization (:mod:`fem_rmpm.runtime.budget`), the
   dashboard on a free port.

Every job starts with ``OMP_NUM_THREADS``, ``MKL_NUM_THREADS``, ``OPENBLAS_NUM_THREADS``,
``NUMBA_NUM_THREADS`` = 1 and glibc's malloc thresholds raised (unless the job's
environment sets them), then the configured ``job-script-prologue`` lines.

Workers: ``--workers K`` keeps K workers (``ceil(K / processes)`` jobs; default one
job); ``--adapt MIN:MAX`` lets Dask scale between MIN and MAX workers with the work
left.  A job that ends under a campaign (``scancel``, walltime, node failure) loses
nothing: Dask moves its running realization to another worker, and the backend
submits a job in its place.  If the client itself ends, re-running the same command
computes only the realizations without a record.

Shared file system: the campaign directory must be one path that the client and every
worker see (not ``/tmp`` of the login node): the workers write the kept VTK there.
"""
from __future__ import annotations

import asyncio
import math
import os
import re
import shutil
import socket
import subprocess
import tempfile
import time
import uuid
from dataclasses import replace
from pathlib import Path
from typing import Any, Protocol, Sequence

import dask
from dask.utils import parse_timedelta
from distributed import Client
from distributed.core import Status
from tornado.ioloop import PeriodicCallback

from fem_rmpm.campaign.cluster import (
    local_worker_count,
    local_workers_text,
    start_client,
    worker_environment,
)
from fem_rmpm.campaign.cluster_spec import (
    BATCH_SYSTEMS,
    CLUSTER_KINDS,
    BatchSystem,
    ClusterError,
    ClusterSpec,
    _memory_bytes,
    parse_adapt,
    validate,
)
from fem_rmpm.campaign.task import campaign_threads
from fem_rmpm.runtime.budget import estimate_run
from fem_rmpm.runtime.machine import usable_cores

__all__ = ["CLUSTER_KINDS", "BATCH_SYSTEMS", "BatchSystem", "ClusterError", "ClusterSpec",
           "Backend", "open_backend", "campaign_backend", "parse_adapt", "validate",
           "probe_directory", "job_environment_lines"]


_PROBE_PREFIX = ".fem-rmpm-probe-"


# --------------------------------------------------------------------------- protocol

class Backend(Protocol):
    """Where the realizations run (module docstring)."""
    description: str

    def preflight(self, n_tasks: int) -> None: ...         # before anything is written
    def start(self, n_tasks: int, out: Path): ...         # -> distributed.Client
    def check_directory(self, client, out: Path) -> None: ...
    def plan(self, n_tasks: int) -> dict: ...
    def close(self) -> None: ...


def campaign_backend(spec: ClusterSpec | None, workers: int | None, scheduler: str | None,
                     cases: Sequence) -> Backend:
    """The backend of a campaign: ``spec`` (default: local) with ``run_campaign``'s
    ``workers`` and ``scheduler`` arguments and the estimated peak memory of one
    realization of the largest case (:func:`fem_rmpm.runtime.budget.estimate_run`)."""
    spec = spec or ClusterSpec()
    if workers is not None:
        if spec.workers not in (None, workers):
            raise ClusterError(f"--workers {workers} and a cluster of {spec.workers} workers: "
                               "give one of the two")
        spec = replace(spec, workers=workers)
    if scheduler:
        spec = replace(spec, scheduler=scheduler)
    memory = max((estimate_run(c.scene).memory_bytes for c in cases), default=None)
    threads = max((campaign_threads(c.scene) for c in cases), default=1)
    return open_backend(replace(spec, worker_memory_estimate=memory, threads_per_worker=threads))


def open_backend(spec: ClusterSpec) -> Backend:
    """The backend of a (validated) spec; starts nothing."""
    spec = validate(spec)
    if spec.batch:
        return JobqueueBackend(spec)
    if spec.scheduler:
        return SchedulerBackend(spec.scheduler)
    return LocalBackend(spec.workers, spec.threads_per_worker)


class _ClientBackend:
    """Shared closing of a client and, if started here, its cluster."""
    description = ""

    def __init__(self):
        self.client = None
        self.cluster = None

    def preflight(self, n_tasks: int) -> None:
        """Nothing to check before the campaign directory is written."""

    def close(self) -> None:
        if self.client is not None:
            self.client.close(timeout=10)
            self.client = None
        if self.cluster is not None:
            self.cluster.close(timeout=30)
            self.cluster = None


class LocalBackend(_ClientBackend):
    """A LocalCluster of worker processes on this machine, ``threads`` numba threads each."""

    def __init__(self, workers: int | None, threads: int = 1):
        super().__init__()
        self.workers = workers
        self.threads = threads

    def _count(self, n_tasks: int) -> int:
        return local_worker_count(self.workers, n_tasks, self.threads)

    def start(self, n_tasks: int, out: Path):
        self.client, self.cluster, self.description = start_client(self.workers, None,
                                                                   n_tasks, self.threads)
        return self.client

    def check_directory(self, client, out: Path) -> None:
        """Local workers share this machine's file system: nothing to check."""

    def plan(self, n_tasks: int) -> dict:
        k = self._count(n_tasks)
        return {"kind": "local", "workers": k, "cores_per_worker": self.threads,
                "description": f"{local_workers_text(k, self.threads)} "
                               f"({usable_cores()} usable CPUs)"}


class SchedulerBackend(_ClientBackend):
    """The workers of a running Dask cluster (``--scheduler ADDRESS``)."""

    def __init__(self, address: str):
        super().__init__()
        self.address = address

    def preflight(self, n_tasks: int) -> None:
        """Connect now: an unreachable scheduler is an error before anything is written."""
        self.client, _, self.description = start_client(None, self.address, n_tasks)

    def start(self, n_tasks: int, out: Path):
        if self.client is None:
            self.preflight(n_tasks)
        return self.client

    def check_directory(self, client, out: Path) -> None:
        check_shared_directory(client, out, "--scheduler")

    def plan(self, n_tasks: int) -> dict:
        return {"kind": "scheduler", "workers": None,
                "description": f"the workers of the Dask cluster at {self.address} "
                               "(not contacted by --dry-run)"}


# --------------------------------------------------------------------------- batch systems

def job_environment_lines() -> list[str]:
    """Job-script lines that give every worker one thread and raised malloc thresholds,
    unless the job's environment already sets them."""
    return [f'export {k}="${{{k}:-{v}}}"' for k, v in worker_environment().items()]


def _config(kind: str, key: str, default=None):
    return dask.config.get(f"jobqueue.{kind}.{key}", default=default)


def _one_line_refusal(exc: BaseException) -> str:
    """The batch system's reason from dask-jobqueue's 'Command exited with non-zero exit
    code ... stderr: ...' error, as one line."""
    text = str(exc)
    stderr = text.split("stderr:", 1)[1] if "stderr:" in text else text
    lines = [" ".join(s.split()) for s in stderr.splitlines() if s.strip()]
    if not lines:
        return " ".join(text.split())[:300] or type(exc).__name__
    head, rest = lines[0], [re.sub(r"^\S+: error: ", "", s) for s in lines[1:]]
    return "; ".join([head, *rest])[:400]


class JobqueueBackend(_ClientBackend):
    """Dask workers in batch jobs through dask-jobqueue (module docstring)."""

    def __init__(self, spec: ClusterSpec):
        super().__init__()
        self.spec = spec
        self.kind = spec.kind
        self.system = BATCH_SYSTEMS[spec.kind]
        self._keeper = None
        self._seen: dict[str, float | None] = {}   # job -> when its workers left

    # ---- the job options
    def _job_kwargs(self) -> dict[str, Any]:
        s, kind = self.spec, self.kind
        cores = s.cores or _config(kind, "cores") or 1
        processes = _config(kind, "processes") if s.cores is None else None
        processes = int(processes or cores)
        if cores % processes:
            raise ClusterError(f"--cores {cores}: not a multiple of jobqueue.{kind}.processes "
                               f"= {processes} (the Dask configuration)")
        memory = s.memory or _config(kind, "memory")
        if memory is None:
            per = max(2**30, 2.0 * (s.worker_memory_estimate or 0.0))
            memory = f"{math.ceil(processes * per / 2**20)}MiB"
        kw: dict[str, Any] = {"cores": int(cores), "processes": processes, "memory": memory,
                              "job_script_prologue": job_environment_lines()
                              + list(_config(kind, "job-script-prologue", []) or [])}
        for key, value in (("queue", s.queue), (self.system.account_keyword, s.account),
                           ("walltime", s.walltime), ("interface", s.interface)):
            if value is not None:
                kw[key] = value
        if s.job_directives:
            kw["job_extra_directives"] = (list(_config(kind, "job-extra-directives", []) or [])
                                          + list(s.job_directives))
        return kw

    def _worker_count(self, n_tasks: int, processes: int) -> int:
        if self.spec.adapt is not None:
            return max(self.spec.adapt[0], 0)
        return self.spec.workers or max(1, min(processes, n_tasks))

    def _describe(self, kw: dict, workers: int | str) -> str:
        jobs = (f"{math.ceil(workers / kw['processes'])} job(s)" if isinstance(workers, int)
                else "jobs")
        queue = kw.get("queue") or _config(self.kind, "queue") or "the default queue"
        wall = kw.get("walltime") or _config(self.kind, "walltime")
        return (f"{self.system.title} (dask-jobqueue): {workers} worker(s) in {jobs} of "
                f"{kw['cores']} core(s) and {kw['memory']} on {queue}, walltime {wall}")

    def _jobqueue_class(self):
        try:
            import dask_jobqueue  # lazy: optional, only for --cluster slurm|pbs|sge|lsf
        except ImportError:
            raise ClusterError(f"--cluster {self.kind}: needs the dask-jobqueue package "
                               "(pip install dask-jobqueue)") from None
        return getattr(dask_jobqueue, self.system.jobqueue_class)

    def _check_submit_command(self, cls) -> None:
        command = cls.job_cls.submit_command
        if shutil.which(command.split()[0]) is None:
            raise ClusterError(f"--cluster {self.kind}: the batch system's submit command "
                               f"{command.split()[0]!r} is not on PATH (run fem-rmpm mc on a "
                               "login node of the cluster)")

    def _check_node_memory(self, kw: dict) -> None:
        """SLURM: a job asking for more memory than the largest node of its partition has
        is an error naming both (other batch systems refuse it at submission)."""
        if not self.system.node_memory_from_sinfo or shutil.which("sinfo") is None:
            return
        queue = kw.get("queue") or _config(self.kind, "queue")
        cmd = ["sinfo", "-h", "-o", "%m"] + (["-p", str(queue)] if queue else [])
        try:
            res = subprocess.run(cmd, capture_output=True, text=True, timeout=30)
        except (OSError, subprocess.TimeoutExpired):
            return
        sizes = [int(m) for m in re.findall(r"\d+", res.stdout)]
        if res.returncode != 0 or not sizes:
            return                          # no such partition: the submission says so
        asked, largest = _memory_bytes(kw["memory"]), max(sizes) * 2**20
        if asked > largest:
            where = f"partition {queue}" if queue else "the cluster"
            raise ClusterError(f"--memory {kw['memory']} per job is more than any node of "
                               f"{where} has (largest {max(sizes)} MB, from sinfo); ask for "
                               f"at most {max(sizes)}MB or use another --queue")

    def _script(self, cls, kw: dict) -> str:
        """The job script with a placeholder scheduler address (creates nothing)."""
        kw = dict(kw)
        log_dir = kw.get("log_directory") or _config(self.kind, "log-directory")
        if log_dir is not None and not os.path.isdir(log_dir):
            kw["log_directory"] = None        # Job() would create it: write nothing yet
        try:
            return cls.job_cls("tcp://<scheduler>:8786", name="dry-run", **kw).job_script()
        except (ValueError, TypeError) as exc:
            raise ClusterError(f"--cluster {self.kind}: {' '.join(str(exc).split())[:300]}") \
                from None

    def plan(self, n_tasks: int) -> dict:
        """What :meth:`start` would submit (``--dry-run``): starts nothing, writes nothing;
        SLURM checks the job script with ``sbatch --test-only``."""
        cls = self._jobqueue_class()
        kw = self._job_kwargs()
        self._check_node_memory(kw)
        workers = (f"{self.spec.adapt[0]}..{self.spec.adapt[1]}" if self.spec.adapt
                   else self._worker_count(n_tasks, kw["processes"]))
        script = self._script(cls, kw)
        out = {"kind": self.kind, "workers": workers, "processes_per_job": kw["processes"],
               "cores_per_job": kw["cores"], "memory_per_job": kw["memory"],
               "memory_per_worker_bytes": _memory_bytes(kw["memory"]) / kw["processes"],
               "description": self._describe(kw, workers), "job_script": script,
               "checked": None}
        test = self.system.test_submit
        if test and shutil.which(test[0]):
            out["checked"] = _test_submit(list(test), script)
        return out

    def preflight(self, n_tasks: int) -> None:
        """Before anything is written: the submit command is on PATH, the memory fits a
        node (SLURM) and the batch system accepts the job script (SLURM test submission)."""
        cls = self._jobqueue_class()
        self._check_submit_command(cls)
        kw = self._job_kwargs()
        self._check_node_memory(kw)
        test = self.system.test_submit
        if test and shutil.which(test[0]):
            _test_submit(list(test), self._script(cls, kw))

    def start(self, n_tasks: int, out: Path):
        """Start the scheduler here and submit the worker jobs (their logs go to
        ``jobqueue.<kind>.log-directory``, default ``out/worker-logs``)."""
        cls = self._jobqueue_class()
        kw = self._job_kwargs()
        if _config(self.kind, "log-directory") is None:
            kw["log_directory"] = str(Path(out).resolve() / "worker-logs")
        options = dict(_config(self.kind, "scheduler-options", {}) or {})
        options.setdefault("dashboard_address", ":0")
        try:
            self.cluster = cls(scheduler_options=options, **kw)
        except (ValueError, TypeError, OSError) as exc:
            raise ClusterError(f"--cluster {self.kind}: {' '.join(str(exc).split())[:300]}") \
                from None
        try:
            self._submit_first_job()
        except ClusterError:
            self.close()
            raise
        workers = self._worker_count(n_tasks, kw["processes"])
        if self.spec.adapt is not None:
            self.cluster.adapt(minimum=self.spec.adapt[0], maximum=self.spec.adapt[1])
            self.description = self._describe(kw, f"{self.spec.adapt[0]}..{self.spec.adapt[1]}")
        else:
            self.cluster.scale(workers)
            self.description = self._describe(kw, workers)
        self.client = Client(self.cluster, set_as_default=False)
        self._start_keeper()
        return self.client

    def _submit_first_job(self) -> None:
        """Submit one job now and wait for the batch system's answer, so that a refusal
        (no such queue or account, more memory than a node has) is an error before any
        realization runs, with the batch system's reason."""
        cluster = self.cluster
        spec = cluster.new_worker_spec()
        cluster.worker_spec.update(spec)
        try:
            cluster.sync(cluster._correct_state)
        except Exception as exc:  # noqa: BLE001 - dask-jobqueue raises RuntimeError
            for name in spec:      # the failed job never ran: forget it before closing
                cluster.worker_spec.pop(name, None)
                job = cluster.workers.pop(name, None)
                if job is not None:
                    job.status = Status.failed
            raise ClusterError(f"--cluster {self.kind}: the batch system refused the worker "
                               f"job: {_one_line_refusal(exc)}") from None

    # ---- replacing lost jobs
    def _start_keeper(self) -> None:
        self._keeper = PeriodicCallback(self._replace_lost_jobs, 5000)
        self.cluster.loop.add_callback(self._keeper.start)

    def _replace_lost_jobs(self) -> None:
        """On the cluster's event loop, every 5 s: a job whose workers all connected once
        and have all been gone (scancel, walltime, node failure) for longer than
        ``distributed.deploy.lost-worker-timeout`` (after which distributed itself drops a
        single-worker job) is closed, and every job of the plan that is missing is
        submitted anew."""
        cluster = self.cluster
        if cluster is None or cluster.scheduler is None:
            return
        grace = parse_timedelta(dask.config.get("distributed.deploy.lost-worker-timeout")) + 5
        now = time.monotonic()
        live = {ws.name for ws in cluster.scheduler.workers.values()}
        for name in list(cluster.workers):
            group = cluster.worker_spec.get(name, {}).get("group", [""])
            if {f"{name}{g}" for g in group} & live:
                self._seen[name] = None
            elif name in self._seen:
                since = self._seen[name] = self._seen[name] or now
                if now - since > grace:
                    del self._seen[name]
                    asyncio.ensure_future(cluster.workers.pop(name).close())
        if set(cluster.worker_spec) - set(cluster.workers):
            cluster._correct_state()

    def check_directory(self, client, out: Path) -> None:
        check_shared_directory(client, out, f"--cluster {self.kind}")

    def close(self) -> None:
        if self._keeper is not None and self.cluster is not None:
            self.cluster.loop.add_callback(self._keeper.stop)
            self._keeper = None
        super().close()


def _test_submit(command: list[str], script: str) -> str:
    """Check a job script with the batch system's test submission; returns its answer,
    raises ClusterError with its refusal."""
    with tempfile.NamedTemporaryFile("w", suffix=".sh", prefix="fem-rmpm-dry-run-") as fh:
        fh.write(script)
        fh.flush()
        try:
            res = subprocess.run([*command, fh.name], capture_output=True, text=True,
                                 timeout=60)
        except (OSError, subprocess.TimeoutExpired) as exc:
            return f"not checked ({exc})"
    text = (res.stderr + res.stdout).strip()
    if res.returncode != 0:
        lines = [" ".join(s.split()) for s in text.splitlines() if s.strip()]
        raise ClusterError(f"the batch system refused the worker job ({' '.join(command)}): "
                           + "; ".join(lines)[:400])
    return " ".join(text.split())[:300]


# --------------------------------------------------------------------------- shared directory

def probe_directory(out: str, token: str) -> dict:
    """Worker task: does this worker see the client's probe file in ``out``, and can it
    write there?  Returns ``{"ok", "host", "reason"}``; never raises."""
    host = socket.gethostname()
    probe = Path(out) / f"{_PROBE_PREFIX}{token}"
    try:
        seen = probe.read_text().strip() == token
    except OSError as exc:
        return {"ok": False, "host": host,
                "reason": f"it does not see {probe.name} ({exc.strerror or exc})"}
    if not seen:
        return {"ok": False, "host": host, "reason": f"{probe.name} has other contents"}
    answer = probe.with_name(probe.name + ".worker")
    try:
        answer.write_text(host)
    except OSError as exc:
        return {"ok": False, "host": host,
                "reason": f"it cannot write there ({exc.strerror or exc})"}
    return {"ok": True, "host": host, "reason": ""}


def check_shared_directory(client, out: Path, option: str) -> None:
    """Raise ClusterError unless a worker sees the campaign directory ``out`` (a probe
    file written by the client) and can write there.  Waits for the first worker."""
    out = Path(out).resolve()
    token = uuid.uuid4().hex
    probe = out / f"{_PROBE_PREFIX}{token}"
    answer = probe.with_name(probe.name + ".worker")
    try:
        probe.write_text(token)
        res = client.submit(probe_directory, str(out), token, pure=False).result()
        if res["ok"] and not answer.exists():
            res = {"ok": False, "host": res["host"],
                   "reason": "its file did not appear on the client's side"}
    finally:
        for p in (probe, answer):
            try:
                p.unlink()
            except OSError:
                pass
    if not res["ok"]:
        raise ClusterError(
            f"--out {out}: the worker on host {res['host']} cannot use the campaign directory: "
            f"{res['reason']}; with {option} the directory must be on a file system that the "
            "client and every worker share (e.g. /scratch or the home directory)")
