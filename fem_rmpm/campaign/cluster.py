"""The Dask client of a campaign: a local cluster of single-thread worker processes with
the worker environment set before they start, or a connection to a running scheduler."""
from __future__ import annotations

import logging
import os

import dask
from distributed import Client, LocalCluster

from .cases import CampaignError
from .task import MALLOC_THRESHOLDS

__all__ = ["worker_environment", "start_local_cluster", "start_client"]

_THREADS = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS", "NUMBA_NUM_THREADS")


def worker_environment() -> dict[str, str]:
    """Environment of local worker processes (:mod:`fem_rmpm.campaign`, "Dask"): one thread, malloc thresholds."""
    env = {k: "1" for k in _THREADS}
    env.update({k: str(v) for k, v in MALLOC_THRESHOLDS.items()})
    return env


def _usable_cpus() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover
        return os.cpu_count() or 1


def start_client(workers: int | None, scheduler: str | None, n_tasks: int):
    """``(client, cluster or None, description)``: connect to ``scheduler`` if given, else
    start a local cluster of ``workers`` (default: usable CPUs, at most ``n_tasks``)."""
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
    k = workers or max(1, min(_usable_cpus(), n_tasks))
    client, cluster = start_local_cluster(k)
    return client, cluster, f"{k} local worker process{'es' if k > 1 else ''}"


def start_local_cluster(workers: int):
    """``(client, cluster)``: a LocalCluster of ``workers`` single-thread processes with
    :func:`worker_environment` set before they start (close both when done)."""
    env = {f"distributed.nanny.pre-spawn-environ.{key}": val
           for key, val in worker_environment().items()}
    # the nannies set these in *this* process's environment before spawning; put ours
    # back after (else a later numba compile here reads NUMBA_NUM_THREADS=1 and refuses
    # to run once numba's thread pool has started with more threads)
    saved = {key: os.environ.get(key) for key in worker_environment()}
    with dask.config.set(env):
        # ":0": the scheduler's HTTP server (and the dashboard, if bokeh is installed) on a
        # free port; None would still bind 8787 and warn when another cluster holds it
        cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                               dashboard_address=":0", silence_logs=logging.ERROR)
    for key, val in saved.items():
        if val is None:
            os.environ.pop(key, None)
        else:
            os.environ[key] = val
    return Client(cluster, set_as_default=False), cluster

