"""The Dask client of a campaign: a local cluster of worker processes (one Dask thread
each, numba threads as the scene asks) with the worker environment set before they
start, or a connection to a running scheduler; and the one compile of the kernels for
all workers (:func:`warm_workers`)."""
from __future__ import annotations

import logging
import os
import sys
import time
import weakref

import dask
import numba
from distributed import Client, LocalCluster
from distributed.core import Status

from fem_rmpm import api
from fem_rmpm.campaign.cases import CampaignError
from fem_rmpm.campaign.task import MALLOC_THRESHOLDS, campaign_threads
from fem_rmpm.runtime import signals
from fem_rmpm.runtime.machine import usable_cores as _usable_cpus
from fem_rmpm.runtime.numba_cache import compile_stats
from fem_rmpm.runtime.signals import sigint_ignored_by_children
from fem_rmpm.scene import with_values

__all__ = ["worker_environment", "local_worker_count", "local_workers_text",
           "start_local_cluster", "start_client", "warm_kernels", "load_kernels", "warm_workers",
           "kernels_cold_here", "WorkerDeathNotice"]

_THREADS = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS", "NUMBA_NUM_THREADS")


def worker_environment(threads: int = 1) -> dict[str, str]:
    """Environment of local worker processes (:mod:`fem_rmpm.campaign`, "Dask"): one
    thread for BLAS and OpenMP, ``threads`` for numba's pool (the scene's ``[solver]
    threads``; 1 by default), malloc thresholds."""
    env = {k: "1" for k in _THREADS}
    env["NUMBA_NUM_THREADS"] = str(max(1, int(threads)))
    env.update({k: str(v) for k, v in MALLOC_THRESHOLDS.items()})
    return env


def local_worker_count(workers: int | None, n_tasks: int, threads: int = 1) -> int:
    """Local worker processes: ``workers`` if given, else as many as the usable CPUs hold
    at ``threads`` each (at least 1, at most ``n_tasks``)."""
    return workers or max(1, min(_usable_cpus() // max(1, threads), n_tasks))


def start_client(workers: int | None, scheduler: str | None, n_tasks: int, threads: int = 1):
    """``(client, cluster or None, description)``: connect to ``scheduler`` if given, else
    start a local cluster of ``workers`` processes with ``threads`` numba threads each
    (default :func:`local_worker_count`)."""
    if scheduler:
        timeout = dask.config.get("distributed.comm.timeouts.connect")
        try:
            client = Client(scheduler, timeout=timeout, set_as_default=False)
        except (OSError, TimeoutError, ValueError, TypeError) as exc:
            msg = " ".join(str(exc).split()) or type(exc).__name__
            raise CampaignError(f"cannot reach the Dask scheduler at {scheduler!r} within "
                                f"{timeout}: {msg[:200]}") from None
        n = len(client.scheduler_info(n_workers=-1).get("workers", {}))
        return client, None, f"the Dask cluster at {scheduler} ({n} workers now)"
    k = local_worker_count(workers, n_tasks, threads)
    client, cluster = start_local_cluster(k, threads)
    return client, cluster, local_workers_text(k, threads)


def local_workers_text(workers: int, threads: int) -> str:
    """"2 local worker processes", "1 local worker process of 2 threads": for the campaign's
    messages and ``summary.json``."""
    each = f" of {threads} threads" if threads > 1 else ""
    return f"{workers} local worker process{'es' if workers > 1 else ''}{each}"


class WorkerDeathNotice(logging.Handler):
    """One line on stderr when a local worker process dies (out of memory, killed): the
    nanny's own log of it (``"Worker process 123 was killed by signal 9"``) is silenced
    with the rest of Dask's logs, but a user must see it.  Not while the cluster closes
    (it kills a busy worker itself).  After Ctrl-C or SIGTERM the
    ``distributed`` loggers are raised above CRITICAL (:mod:`fem_rmpm.runtime.signals`),
    so the workers closed by the command's own clean-up are not reported."""

    def __init__(self):
        super().__init__(level=logging.INFO)
        self.clusters: weakref.WeakSet = weakref.WeakSet()

    def emit(self, record: logging.LogRecord) -> None:
        try:
            msg = record.getMessage()
        except (TypeError, ValueError):
            return
        if any(c.status in (Status.closing, Status.closed) for c in list(self.clusters)):
            return                  # a worker killed by the cluster's own closing
        died = (" was killed by " in msg or " exited with status " in msg)
        if msg.startswith("Worker process ") and died and not msg.endswith(" status 0"):
            if _interrupted_with_the_command(msg):
                return
            print(f"fem-rmpm: warning: a Dask worker process died ({msg}; out of memory is "
                  "the usual cause): its realization runs again on a worker, and is lost "
                  "if the worker dies again and again", file=sys.stderr, flush=True)


def _interrupted_with_the_command(msg: str, wait: float = 0.5) -> bool:
    """True when a worker killed by SIGINT or SIGTERM went down with this command: the
    signal of a terminal's Ctrl-C or a job's SIGTERM reaches the whole process group at
    once, and the nanny may log the worker's death (in its thread) before the command's
    handler has run in the main thread; so wait up to ``wait`` s for that handler
    (:mod:`fem_rmpm.runtime.signals`) before calling the death news."""
    if not msg.endswith((" signal 15", " signal 2")):
        return False
    deadline = time.monotonic() + wait
    while not signals._pending and time.monotonic() < deadline:
        time.sleep(0.02)
    return bool(signals._pending)


def _notice_worker_deaths(cluster) -> None:
    """Attach :class:`WorkerDeathNotice` to the nanny's logger (once per process), for
    the workers of ``cluster``."""
    logger = logging.getLogger("distributed.nanny")
    notice = next((h for h in logger.handlers if isinstance(h, WorkerDeathNotice)), None)
    if notice is None:
        notice = WorkerDeathNotice()
        logger.addHandler(notice)
    notice.clusters.add(cluster)


def start_local_cluster(workers: int, threads: int = 1):
    """``(client, cluster)``: a LocalCluster of ``workers`` processes (one Dask thread each,
    ``threads`` numba threads) with :func:`worker_environment` set before they start
    (close both when done)."""
    wenv = worker_environment(threads)
    env = {f"distributed.nanny.pre-spawn-environ.{key}": val for key, val in wenv.items()}
    # the nannies set these in *this* process's environment before spawning; put ours
    # back after (else a later numba compile here reads NUMBA_NUM_THREADS=1 and refuses
    # to run once numba's thread pool has started with more threads)
    saved = {key: os.environ.get(key) for key in wenv}
    with dask.config.set(env):
        # ":0": the scheduler's HTTP server (and the dashboard, if bokeh is installed) on a
        # free port; None would still bind 8787 and warn when another cluster holds it
        # silence_logs: a lost realization is the campaign's own news (its line, "lost"),
        # a worker's death is one warning line (WorkerDeathNotice); Dask's other logs
        # (event-loop and GC timings under load, a cluster closed under busy workers on
        # Ctrl-C) are not the user's
        with sigint_ignored_by_children():      # Ctrl-C stops the command, not its workers
            cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                                   dashboard_address=":0", silence_logs=logging.CRITICAL)
        _notice_worker_deaths(cluster)
    for key, val in saved.items():
        if val is None:
            os.environ.pop(key, None)
        else:
            os.environ[key] = val
    return Client(cluster, set_as_default=False), cluster



#: Simulated time (s) of the warm-up run: shorter than any stable step, so the run is one
#: step (every kernel of an ordinary step compiled, nothing written).
WARM_UP_TIME = 1e-9


def warm_kernels(task: dict, always: bool = False) -> dict:
    """Dask task: fill numba's on-disk cache with the explicit kernels realization ``task``
    (a :func:`fem_rmpm.campaign.task.run_realization` task) runs, by running its scene
    for one step (:data:`WARM_UP_TIME`, no output), on the threads the campaign gives it.
    Returns ``{"compiled": whether numba compiled anything, "functions": how many it
    compiled (:func:`fem_rmpm.runtime.numba_cache.compile_stats`; 0: every kernel came
    from the cache), "seconds": wall time (s), "cpu_seconds": this process's CPU time
    (s)}``; nothing run (``compiled`` False, no ``functions``) when the kernels were
    cached and not ``always``, or the scene is not an explicit numba run."""
    t0, c0 = time.perf_counter(), time.process_time()
    scene = task["scene"]
    threads = campaign_threads(scene)
    if not (api.explicit_numba(scene.solver) and (always or api.kernels_cold(
            threads, bool(getattr(scene.solver, "fbar", False))))):
        return {"compiled": False, "seconds": 0.0, "cpu_seconds": 0.0}
    numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))
    short = with_values(scene, {"solver.threads": threads, "solver.t_end": WARM_UP_TIME})
    before = compile_stats()[0]
    api.run(short, out=None, seed=task.get("seed"), noise=task.get("noise"), progress=False)
    functions = compile_stats()[0] - before
    return {"compiled": functions > 0, "functions": functions,
            "seconds": time.perf_counter() - t0, "cpu_seconds": time.process_time() - c0}


def load_kernels(task: dict) -> dict:
    """Dask task: :func:`warm_kernels` run also when the kernels are cached — a worker
    loading what the first one compiled says how long that took and what it compiled."""
    return warm_kernels(task, always=True)


def kernels_cold_here(task: dict) -> bool:
    """Whether this process sees the kernels of ``task``'s explicit realization uncompiled
    in numba's cache (the cache local workers share; False if not explicit numba)."""
    sv = task["scene"].solver
    return bool(api.explicit_numba(sv) and api.kernels_cold(
        campaign_threads(task["scene"]), bool(getattr(sv, "fbar", False))))


def warm_workers(client, tasks: list[dict], run=warm_kernels, say=None,
                 cold=kernels_cold_here, load=load_kernels) -> str | None:
    """Compile the kernels of ``tasks`` once, on one worker, before the others start: the
    workers of a machine share numba's on-disk cache, so they then load the kernels
    instead of each compiling them (20-30 s of CPU each on a fresh install).  Runs
    ``run(tasks[0])`` (:func:`warm_kernels`) on one worker and waits for it; when it
    compiled, ``load(tasks[0])`` (:func:`load_kernels`) on each other worker (plane-strain
    scenes), so that the line says what they compiled and how long their load took.
    Returns the line to print (None: one worker, no explicit realization, or the kernels
    were cached).  ``say(line)`` is told before the wait when ``cold(task)`` (this
    process's view of the cache) finds the kernels uncompiled.  A warm-up that fails is
    left to the realizations to report (None; a failed load on another worker is left out
    of the line)."""
    task = tasks[0] if tasks else None
    if task is None or "scene" not in task or task.get("fs") == "only":
        return None
    try:
        workers = list(client.nthreads())
        if len(workers) < 2:
            return None
        if say is not None and cold(task):
            say("compiling the kernels once, on one worker, for all workers (first "
                "campaign after an install or an upgrade) ...")
        res = client.submit(run, task, pure=False, key=f"rmpm-warm-up-{os.getpid()}",
                            workers=workers[:1], allow_other_workers=True,
                            retries=0).result()
    except Exception:  # noqa: BLE001 - the realizations report their own errors
        return None
    if not res.get("compiled"):
        return None
    line = (f"compiled the kernels once for all workers: {res['seconds']:.1f} s "
            f"({res['cpu_seconds']:.1f} s CPU"
            + (f", {res['functions']} functions" if "functions" in res else "")
            + ") on one worker")
    if getattr(getattr(task["scene"], "grid", None), "dimension", 2) == 3:
        # (a one-step 3-D run per worker would set up the whole 3-D scene again)
        return line + "; the others load them from numba's on-disk cache"
    return line + _loads_text(client, task, workers[1:], load)


def _loads_text(client, task: dict, others: list, load) -> str:
    """``load(task)`` on each worker of ``others`` (addresses), awaited; the end of
    :func:`warm_workers`' line: how many loaded the kernels from the cache (no compile),
    in how many seconds, and any that compiled."""
    futures = [client.submit(load, task, pure=False, key=f"rmpm-load-{os.getpid()}-{k}",
                             workers=[addr], allow_other_workers=False, retries=0)
               for k, addr in enumerate(others)]
    results = []
    for fut in futures:
        try:
            results.append(fut.result())
        except Exception:  # noqa: BLE001 - a worker lost here is the realizations' news
            continue
    loaded = [r for r in results if r.get("functions") == 0]
    compiled = [r for r in results if r.get("functions")]
    if not loaded and not compiled:
        return "; the others load them from numba's on-disk cache"
    text = ""
    if loaded:
        secs = sorted(r["seconds"] for r in loaded)
        span = f"{secs[0]:.1f} s" if len(secs) == 1 else f"{secs[0]:.1f}-{secs[-1]:.1f} s"
        text += (f"; {len(loaded)} other worker(s) loaded them from numba's on-disk cache, "
                 f"no function compiled ({span} for a one-step run each)")
    if compiled:
        text += (f"; {len(compiled)} other worker(s) compiled again "
                 f"({max(r['functions'] for r in compiled)} functions, up to "
                 f"{max(r['seconds'] for r in compiled):.1f} s): they do not share the "
                 "first worker's cache (another NUMBA_CACHE_DIR, machine or package copy)")
    return text
