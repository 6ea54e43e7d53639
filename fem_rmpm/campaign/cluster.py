"""The Dask client of a campaign: a local cluster of worker processes (one Dask thread
each, numba threads as the scene asks) with the worker environment set before they
start, or a connection to a running scheduler."""
from __future__ import annotations

import logging
import os
import sys
import weakref

import dask
from distributed import Client, LocalCluster
from distributed.core import Status

from fem_rmpm.campaign.cases import CampaignError
from fem_rmpm.campaign.task import MALLOC_THRESHOLDS
from fem_rmpm.runtime.machine import usable_cores as _usable_cpus
from fem_rmpm.runtime.signals import sigint_ignored_by_children

__all__ = ["worker_environment", "local_worker_count", "local_workers_text",
           "start_local_cluster", "start_client", "WorkerDeathNotice"]

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
            print(f"fem-rmpm: warning: a Dask worker process died ({msg}; out of memory is "
                  "the usual cause): its realization runs again on a worker, and is lost "
                  "if the worker dies again and again", file=sys.stderr, flush=True)


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

