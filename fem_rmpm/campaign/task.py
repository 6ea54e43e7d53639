"""The Dask task of a campaign: one realization of one case, returned as a JSON-ready record."""
from __future__ import annotations

import asyncio
import ctypes
import os
import signal
import socket
import sys
import threading
import time
from importlib.metadata import PackageNotFoundError, version
from typing import Any

import numba
import numpy as np

from fem_rmpm import api
from fem_rmpm.campaign.decide import DECIDED, FailureWatch, failure_threshold
from fem_rmpm.campaign.factor_of_safety import fs_measures
from fem_rmpm.campaign.store import FORMAT
from fem_rmpm.io.rundir import mark_interrupted
from fem_rmpm.runtime.machine import cpu_model
from fem_rmpm.schemes.common import SimulationError

__all__ = ["run_realization", "campaign_threads", "MALLOC_THRESHOLDS"]

#: glibc malloc thresholds of campaign workers (see :mod:`fem_rmpm.campaign`, "Dask").
MALLOC_THRESHOLDS = {"MALLOC_TRIM_THRESHOLD_": 2**30, "MALLOC_MMAP_THRESHOLD_": 2**25}


def _raise_malloc_thresholds() -> None:
    """glibc: raise the mmap and trim thresholds in this process (see
    :mod:`fem_rmpm.campaign`, "Dask")."""
    if not sys.platform.startswith("linux"):
        return
    try:
        libc = ctypes.CDLL("libc.so.6")
        libc.mallopt(-3, MALLOC_THRESHOLDS["MALLOC_MMAP_THRESHOLD_"])   # M_MMAP_THRESHOLD
        libc.mallopt(-1, MALLOC_THRESHOLDS["MALLOC_TRIM_THRESHOLD_"])   # M_TRIM_THRESHOLD
    except (OSError, AttributeError):  # pragma: no cover - not glibc
        pass


def _version() -> str:
    try:
        return version("fem_rmpm")
    except PackageNotFoundError:  # not installed (run from a source tree)
        return "unknown"


def _plain(v: Any) -> Any:
    """numpy scalars -> Python scalars (repr of np.float64 is not a number in numpy 2)."""
    if isinstance(v, (bool, np.bool_)):
        return bool(v)
    if isinstance(v, (int, np.integer)):
        return int(v)
    if isinstance(v, (float, np.floating)):
        return float(v)
    return v


def _scalar_measures(m: dict) -> dict:
    """The scalar measures (numbers, booleans, None) of a realization, Python types."""
    return {k: _plain(v) for k, v in m.items()
            if v is None or isinstance(v, (bool, int, float, np.bool_, np.integer, np.floating))}


#: The kept-VTK run directories of the realizations running in this worker process.
_RUNNING_DIRS: set[str] = set()
#: Set once this worker process marks those directories on SIGTERM or its closing
#: (:func:`_watch_sigterm`).
_WATCHING = threading.Event()


def _mark_running(reason: str) -> None:
    """The kept-VTK runs this worker process is computing say ``"interrupted"``."""
    for path in list(_RUNNING_DIRS):
        mark_interrupted(path, reason)


def _on_worker_sigterm() -> None:
    """SIGTERM to a worker process (a batch system's wall-time limit, ``kill``): the runs
    it keeps VTK of say ``"interrupted"`` in their ``summary.json`` (not ``"running"``),
    then the process ends by SIGTERM as before."""
    _mark_running("interrupted (SIGTERM to the Dask worker process)")
    asyncio.get_running_loop().remove_signal_handler(signal.SIGTERM)   # back to the default
    os.kill(os.getpid(), signal.SIGTERM)


def _install_handlers(worker) -> None:
    """In the worker's event loop (the main thread): mark the running kept-VTK runs
    interrupted on SIGTERM, and when the worker closes with a run still going (a
    campaign stopped by Ctrl-C: the nanny kills a busy worker with SIGKILL, which no
    handler sees; a run that still finishes rewrites its summary as usual)."""
    try:
        if signal.getsignal(signal.SIGTERM) == signal.SIG_DFL:   # nobody else handles it
            asyncio.get_running_loop().add_signal_handler(signal.SIGTERM, _on_worker_sigterm)
        from distributed.diagnostics.plugin import WorkerPlugin  # lazy: in a worker only

        class MarkOnClose(WorkerPlugin):
            def teardown(self, worker) -> None:
                _mark_running("interrupted (the Dask worker closed)")
        asyncio.ensure_future(worker.plugin_add(MarkOnClose(), name="fem-rmpm-interrupted"))
    except (RuntimeError, ValueError, NotImplementedError, ImportError):   # no loop, ...
        pass
    finally:
        _WATCHING.set()


def _watch_sigterm(wait: float = 2.0) -> None:
    """In a Dask worker process, have SIGTERM or the worker's closing mark the running
    kept-VTK runs interrupted (:func:`_install_handlers`); waits up to ``wait`` s for the
    handlers to be in place.  Nothing outside a worker (a realization run here)."""
    if _WATCHING.is_set():
        return
    try:
        from distributed import get_worker  # lazy: distributed loads on first use (campaign)
        worker = get_worker()
    except (ImportError, ValueError, AttributeError):
        return
    worker.loop.add_callback(_install_handlers, worker)
    _WATCHING.wait(wait)


def campaign_threads(scene) -> int:
    """Numba threads per realization in a campaign: the scene's ``[solver] threads``, 1
    for 0 (auto: the campaign's parallelism is its worker processes)."""
    return max(1, int(getattr(scene.solver, "threads", 0) or 1))


def run_realization(task: dict) -> dict:
    """The Dask task: run realization ``task["index"]`` of ``task["case"]`` and return
    its record (a JSON-ready dict).  Never raises for a failing realization: the
    error is in the record (``status = "failed"``).

    ``task``: ``case``, ``index``, ``seed``, ``scene`` (a :class:`Scene`), ``vtk_dir``
    (str or None: write VTK, ``summary.json`` and the plastic strain PNG there); optional
    ``decide`` (True: stop once decided, :mod:`fem_rmpm.campaign.decide`; every run records
    ``decided_time``, the first output at which that rule holds, None if never) and
    ``noise``: the random field's standard-normal noise array, in place of the seed
    (``seed`` None; subset simulation)."""
    _raise_malloc_thresholds()
    # one thread per realization (the campaign runs them in parallel), unless the scene asks
    # for more ([solver] threads; any count gives bitwise the same realization), at most the
    # worker's pool (NUMBA_NUM_THREADS)
    numba.set_num_threads(min(campaign_threads(task["scene"]), numba.config.NUMBA_NUM_THREADS))
    rec: dict[str, Any] = {
        "format": FORMAT, "case": task["case"], "index": int(task["index"]),
        "seed": None if task["seed"] is None else int(task["seed"]),
        "scheme": task["scene"].solver.scheme, "status": "ok",
        "error": None, "vtk": task.get("vtk_rel"),
        "worker": {"host": socket.gethostname(), "cpu_model": cpu_model(), "pid": os.getpid(),
                   "threads": numba.get_num_threads()},
        "fem_rmpm": _version(),
    }
    t0, c0 = time.perf_counter(), time.process_time()
    mode = rec["fs_mode"] = task.get("fs", "off")
    fs_m: dict = {}
    if mode != "off":           # strength-reduction FS on the in-situ geometry first
        fs_m, rec["fs"] = fs_measures(task["scene"], rec["seed"])
    if mode == "only":
        ok = rec["fs"]["status"] == "ok"
        rec.update(status="ok" if ok else "failed", error=None if ok else rec["fs"]["error"],
                   measures=fs_m if ok else None, steps=0, stop_reason="factor of safety only")
        rec["wall_time"] = time.perf_counter() - t0
        rec["cpu_time"] = time.process_time() - c0
        return rec
    mc = task["scene"].montecarlo
    watch = FailureWatch(mc.failure_displacement, failure_threshold(task["scene"]),
                         stop=bool(task.get("decide")))
    vtk_dir = task.get("vtk_dir")
    if vtk_dir is not None:
        _watch_sigterm()
        _RUNNING_DIRS.add(vtk_dir)
    try:
        res = api.run(task["scene"], out=vtk_dir, seed=rec["seed"], progress=False,
                      vtk=vtk_dir is not None, figures=vtk_dir is not None, force=True,
                      noise=task.get("noise"), stop_when=watch,
                      label=f"case {task['case']}, realization {task['index']} "
                            f"(seed {rec['seed']})")
    except Exception as exc:       # noqa: BLE001 - every failure is data, recorded
        msg = str(exc) if isinstance(exc, SimulationError) else f"{type(exc).__name__}: {exc}"
        rec.update(status="failed", error=" ".join(msg.split()) or type(exc).__name__,
                   measures=None, final_profile=None)
    else:
        s, m = res.summary, res.measures
        rec.update(steps=s["steps"], simulated_time=s["simulated_time"],
                   stop_reason=s["stop_reason"], particles=s["particles"],
                   frozen_points=s["frozen_points"]["count"],
                   measures={**_scalar_measures(m), **fs_m, "decided_time": watch.time},
                   final_profile=m.get("final_profile"))
        if "slides" in m:                  # 3-D: each slide's strike range and volume
            rec.update(dimension=3, slides=[list(map(float, v)) for v in m["slides"]])
        if s["stop_reason"] == DECIDED:    # stopped once decided: the outcome only
            rec.update(steps=None, final_profile=None, slides=None, measures={
                "failed": True, "decided_time": watch.time, "decided_area": watch.moved_area,
                "failure_displacement": m["failure_displacement"], **fs_m})
    finally:
        _RUNNING_DIRS.discard(vtk_dir)
    rec["wall_time"] = time.perf_counter() - t0
    rec["cpu_time"] = time.process_time() - c0     # of the worker process (s)
    return rec
