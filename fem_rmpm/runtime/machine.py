"""Which machine a run's speed figures come from.

A figure in ns per point-step means little without the machine: the same kernels ran the
reference slope at 48 ns per point-step on one 2-core machine and at 70 ns on another (an
Intel Xeon and an AMD EPYC, one thread each).  :func:`describe`
names it in every run's ``summary.json`` (key ``machine``), taken when the run starts:
the CPU model, the cores the process may use, the load average (a run on a loaded machine
is slower and says so), the platform and the versions of Python, numpy and numba.
A campaign's realizations name the host and CPU of the worker that ran them (a record's
``worker``); :func:`tally` counts them per machine for the campaign's ``summary.json``
(``worker_machines``) and ``report.html``.
"""
from __future__ import annotations

import os
import platform
from collections import Counter
from collections.abc import Iterable
from importlib import metadata

__all__ = ["describe", "cpu_model", "cpu_signature", "usable_cores", "tally"]


def _first_values(cpuinfo: str, keys: tuple[str, ...]) -> dict[str, str]:
    """The first non-empty value of each of ``keys`` in ``cpuinfo`` (Linux's
    ``/proc/cpuinfo``: ``key<TAB>: value`` lines, one block per logical CPU); ``{}`` when
    the file cannot be read."""
    found: dict[str, str] = {}
    try:
        with open(cpuinfo, encoding="utf-8", errors="replace") as fh:
            for line in fh:
                key, sep, value = line.partition(":")
                key = key.strip()
                if sep and key in keys and key not in found and value.strip():
                    found[key] = value.strip()
                    if len(found) == len(keys):
                        break
    except OSError:
        pass
    return found


def cpu_model(cpuinfo: str = "/proc/cpuinfo") -> str:
    """The CPU's model name (Linux: the first ``model name`` of ``/proc/cpuinfo``), else
    what :mod:`platform` knows (``processor()``, then ``machine()``)."""
    name = _first_values(cpuinfo, ("model name",)).get("model name")
    return name or platform.processor() or platform.machine() or "unknown"


def cpu_signature(cpuinfo: str = "/proc/cpuinfo") -> tuple[str, int, int] | None:
    """The CPU's ``(vendor_id, cpu family, model)`` from ``/proc/cpuinfo``, e.g.
    ``("AuthenticAMD", 23, 1)`` for an AMD EPYC of the Zen 1 generation; None where the
    file or a field is missing.  A virtual machine may name its CPU just "AMD EPYC" for
    every generation (2 to 3x apart in speed): the family and model tell them apart."""
    v = _first_values(cpuinfo, ("vendor_id", "cpu family", "model"))
    try:
        return v["vendor_id"], int(v["cpu family"]), int(v["model"])
    except (KeyError, ValueError):
        return None


def usable_cores() -> int:
    """Cores this process may run on (its CPU affinity; else all the machine's)."""
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):           # (not on every platform)
        return os.cpu_count() or 1


def threading_layer() -> str | None:
    """numba's threading layer (``"omp"``, ``"tbb"`` or ``"workqueue"``) once a parallel
    loop of this process has run, else None (numba picks it at the first one)."""
    import numba  # lazy: numba (~0.23 s of imports) only once a run has used threads
    try:
        return str(numba.threading_layer())
    except ValueError:
        return None


def slow_threads_warning(layer: str | None, threads: int) -> str | None:
    """The one-line warning for a run on ``threads`` >= 2 threads that numba runs on its
    ``workqueue`` layer (it found neither the OpenMP runtime, ``libgomp.so.1``, nor TBB,
    ``libtbb.so.12``), else None.  That layer wakes its threads for every parallel loop:
    ~80 us per loop against ~1 us with OpenMP (an empty two-thread loop on a 2-core AMD
    EPYC).  Case (i) to t = 10 s on that machine, two threads against one: 1.23x with a
    loop per stage of the step (53 against 65 ns per point-step; F-bar and three or more
    threads still step so), 1.5-1.7x with the two-thread driver's one loop per call (32.0 /
    35.4 against 53.8 ns), where OpenMP gave 1.8-2.1x (25.9 / 29.7)."""
    if threads <= 1 or layer != "workqueue":
        return None
    import numba  # lazy: as in threading_layer
    if numba.config.THREADING_LAYER == "workqueue":
        why, fix = "NUMBA_THREADING_LAYER asks for it", "unset NUMBA_THREADING_LAYER"
    else:
        why = "numba found no OpenMP runtime, libgomp.so.1, and no TBB"
        fix = "install the OpenMP runtime (Debian/Ubuntu: apt install libgomp1)"
    return (f"fem-rmpm: warning: the {threads} threads run on numba's slow 'workqueue' layer "
            f"({why}): each parallel loop costs ~80 us to start, so two threads gain "
            f"1.2-1.7x instead of ~1.8-2x; {fix} or set [solver] threads = 1")


def _version(package: str) -> str | None:
    try:
        return metadata.version(package)
    except metadata.PackageNotFoundError:
        return None


def describe() -> dict:
    """The machine as a JSON-ready dict: ``cpu_model``, ``logical_cores`` (the machine's),
    ``usable_cores`` (this process's affinity), ``load_average`` (1, 5, 15 minutes; None
    where the platform has none), ``platform``, ``node`` (the architecture), ``python``,
    ``numpy``, ``numba``, and ``cpu_signature`` (:func:`cpu_signature`, as a list)."""
    try:
        load = [round(v, 2) for v in os.getloadavg()]
    except (AttributeError, OSError):
        load = None
    return {"cpu_model": cpu_model(), "logical_cores": os.cpu_count(),
            "usable_cores": usable_cores(), "load_average": load,
            "platform": platform.platform(), "node": platform.machine(),
            "python": platform.python_version(), "numpy": _version("numpy"),
            "numba": _version("numba"),
            "cpu_signature": list(sig) if (sig := cpu_signature()) else None}


def tally(workers: Iterable[dict | None]) -> list[dict]:
    """The machines a set of runs ran on, from their workers' descriptions (dicts with
    ``host`` and ``cpu_model``; None and non-dicts are skipped, a missing field is "?"):
    ``[{"host", "cpu_model", "runs"}]``, most runs first, then by host and CPU."""
    counts = Counter((str(w.get("host", "?")), str(w.get("cpu_model", "?")))
                     for w in workers if isinstance(w, dict))
    order = sorted(counts.items(), key=lambda kv: (-kv[1], kv[0]))
    return [{"host": h, "cpu_model": c, "runs": n} for (h, c), n in order]
