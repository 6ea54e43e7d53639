"""How many threads an explicit run uses, and the warnings about them.

Any thread count gives bitwise the same run (:mod:`.kernels`); threads change only the
wall time.  ``[solver] threads = 0`` (auto) takes the cores idle right now
(:func:`auto_threads`); a count the user set that is more than the idle cores is warned
about once per process (:func:`busy_threads_warning`): on busy cores every parallel loop
waits for its slowest thread, and a two-thread run can take many times as long as on
one.  A threaded run books numba's threading layer and warns about the slow one
(:func:`first_step_done`).
"""
from __future__ import annotations

import os
import sys
import time
from contextlib import contextmanager

import numba
from numba.np.ufunc import parallel as numba_parallel

from fem_rmpm.runtime.machine import slow_threads_warning, threading_layer
from fem_rmpm.runtime.machine import usable_cores as _cores
from fem_rmpm.runtime.numba_cache import compile_stats, process_seconds
from fem_rmpm.schemes.common import RunRecord

__all__ = ["auto_threads", "run_threads", "busy_threads_warning", "threads_from_auto",
           "first_step_done"]


def auto_threads() -> int:
    """Threads of ``[solver] threads = 0`` (auto): numba's thread count — all cores for a
    single run (or ``NUMBA_NUM_THREADS``), 1 in a campaign worker (the task sets it) —
    less the cores busy right now (the other runnable threads, :func:`_runnable_others`;
    where ``/proc/loadavg`` is missing, the rounded 1-minute load average), at least 1.
    The count "right now", not the 1-minute average: the average still counts one's own
    run of a moment ago (it decays over a minute), so an idle machine would get one
    thread."""
    # numba's pool size without starting the pool (get_num_threads would start it)
    started = getattr(numba_parallel, "_is_initialized", True)
    n = numba.get_num_threads() if started else int(numba.config.NUMBA_NUM_THREADS)
    if n <= 1:
        return 1
    return max(1, min(n, int(n - _busy_cores() + 0.5)))


def run_threads(threads: int, kernel: str) -> int:
    """The run's thread count: ``[solver] threads``, or with 0 :func:`auto_threads`.  An
    explicit count of 2 or more on busy cores is warned about on stderr, once per process
    and count (:func:`busy_threads_warning`), unless the count was resolved from auto
    (:func:`threads_from_auto`)."""
    if threads > 1 and kernel == "numba" and not _FROM_AUTO[0] and threads not in _THREADS_WARNED:
        _print_once(threads, busy_threads_warning(threads))
    return threads or auto_threads()


def _runnable_others(samples: int = 3, pause: float = 0.001) -> int | None:
    """Other threads running or waiting for a core right now: the kernel's count of runnable
    threads (4th field of ``/proc/loadavg``) less this one, the least of a few samples a
    millisecond apart; None where there is no ``/proc/loadavg``."""
    counts = []
    try:
        for i in range(samples):
            with open("/proc/loadavg") as fh:
                counts.append(int(fh.read().split()[3].split("/")[0]) - 1)
            if i + 1 < samples:
                time.sleep(pause)
    except (OSError, ValueError, IndexError):
        return None
    return max(0, min(counts))


def _busy_cores() -> float:
    """Cores busy right now: :func:`_runnable_others`; where ``/proc/loadavg`` is missing,
    the 1-minute load average; 0 without either."""
    others = _runnable_others()
    if others is not None:
        return float(others)
    try:
        return os.getloadavg()[0]
    except OSError:
        return 0.0


def busy_threads_warning(threads: int) -> str | None:
    """The one-line warning for an explicit ``[solver] threads`` of 2 or more when that many
    cores are not free (cores less the other processes running right now), else None.  On
    busy cores every parallel loop waits for its slowest thread, which can make a run many
    times slower than on one thread.  ``threads = 0`` (auto) leaves busy cores out by
    itself."""
    if threads <= 1:
        return None
    cores = _cores()
    others = int(_busy_cores() + 0.5)
    try:
        load = f"{os.getloadavg()[0]:.2f}"
    except OSError:
        load = "unknown"
    free = max(cores - others, 0)
    if threads <= free:
        return None
    return (f"fem-rmpm: warning: [solver] threads = {threads}, but {others} other "
            f"process(es) are running on this machine's {cores} core(s) (1-minute load average "
            f"{load}): every parallel loop waits for a thread on a busy core, which can make the "
            f"run many times slower; set [solver] threads = {max(free, 1)} or 0 (auto: the idle "
            "cores)")


_THREADS_WARNED: set = set()      # the thread counts (and "layer") already warned about
_FROM_AUTO = [False]      # True while a run uses a count resolved from threads = 0


@contextmanager
def threads_from_auto(resolved: bool):
    """While ``resolved`` (the run's ``[solver] threads`` was 0 and the caller replaced it by
    :func:`auto_threads`, as :func:`fem_rmpm.api.run` does): no busy-cores warning.  The
    warning is for a count the user set; auto left the busy cores out a moment before the
    run, and a process that started since (e.g. another test worker) is not the user's
    setting to change."""
    before, _FROM_AUTO[0] = _FROM_AUTO[0], bool(resolved)
    try:
        yield
    finally:
        _FROM_AUTO[0] = before


def first_step_done(rec: RunRecord, seconds: float, threads: int) -> None:
    """Book the first step's wall time (s) from the time loop's set-up
    (``first_step_time``) and from the start of the process (``first_step_after_start``:
    the interpreter, the imports and the scene's set-up included;
    :func:`fem_rmpm.runtime.numba_cache.process_seconds`, absent where the process's start
    time cannot be read), the functions numba compiled in this process
    up to it and the wall seconds that took (``numba_compiles``,
    :func:`fem_rmpm.runtime.numba_cache.compile_stats`: 0 when every kernel came from the
    on-disk cache) and, on two or more threads, numba's threading layer in ``rec.solver``;
    warn (once per process) when that layer is the slow one
    (:func:`fem_rmpm.runtime.machine.slow_threads_warning`)."""
    rec.solver["first_step_time"] = seconds
    since_start = process_seconds()
    if since_start is not None:
        rec.solver["first_step_after_start"] = since_start
    functions, compile_seconds = compile_stats()
    rec.solver["numba_compiles"] = {"functions": functions, "seconds": compile_seconds}
    if threads > 1:
        layer = rec.solver["threading_layer"] = threading_layer()
        _print_once("layer", slow_threads_warning(layer, threads))


def _print_once(key, text: str | None) -> None:
    """Print the warning ``text`` (None: nothing to say) to stderr unless this process
    already printed the one filed under ``key`` (a thread count, or ``"layer"``)."""
    if text and key not in _THREADS_WARNED:
        _THREADS_WARNED.add(key)
        print(text, file=sys.stderr, flush=True)
