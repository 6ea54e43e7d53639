"""One graceful path for SIGINT (Ctrl-C) and SIGTERM (``timeout``, a batch system's
wall-time limit): both become a :class:`KeyboardInterrupt` in the main thread, so the
same ``finally`` blocks and handlers run (finished output kept, a run's ``summary.json``
marked ``"interrupted"``, the campaign lock released, the workers closed); the command
line then exits 128 + the signal number (130, 143), as a shell reports a process killed
by that signal.
"""
from __future__ import annotations

import contextlib
import logging
import signal
import threading

__all__ = ["Terminated", "interrupt_exit_code", "interrupt_name", "graceful_interrupts",
           "raise_if_interrupted", "sigint_ignored_by_children"]

#: Signals received under :func:`graceful_interrupts` whose exception has not reached the
#: command line yet (an exception raised inside a ctypes callback, e.g. while numba loads
#: a kernel, is printed and dropped by Python: :func:`raise_if_interrupted` raises it again).
_pending: list[int] = []


class Terminated(KeyboardInterrupt):
    """SIGTERM received: handled like Ctrl-C (:class:`KeyboardInterrupt`)."""


def _exception(signum: int) -> KeyboardInterrupt:
    return Terminated() if signum == signal.SIGTERM else KeyboardInterrupt()


#: Seconds between two tries to raise an interrupt that arrived inside a native callback.
RETRY_SECONDS = 0.05


def _in_native_callback(frame) -> bool:
    """True when ``frame`` runs inside llvmlite's callbacks from native code (numba
    loading or storing a compiled kernel): an exception raised there is printed with
    its traceback and dropped by ctypes."""
    depth = 0
    while frame is not None and depth < 200:
        if "llvmlite" in frame.f_code.co_filename:
            return True
        frame, depth = frame.f_back, depth + 1
    return False


def _raise_or_retry(signum: int, frame) -> None:
    if _in_native_callback(frame):         # try again once the callback has returned
        signal.signal(signal.SIGALRM, _retry)
        signal.setitimer(signal.ITIMER_REAL, RETRY_SECONDS)
        return
    raise _exception(signum)


def _retry(signum, frame) -> None:
    if _pending:
        _raise_or_retry(_pending[0], frame)


def _on_signal(signum, frame) -> None:
    """The first SIGINT or SIGTERM: ignore both from now on (a second Ctrl-C must not
    break the clean-up it starts: closing the workers, the lock), then raise."""
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, signal.SIG_IGN)
    # a SIGTERM sent to the whole job stops the local Dask workers too: their scheduler's
    # complaints about them during the clean-up are not the user's news
    logging.getLogger("distributed").setLevel(logging.CRITICAL + 1)
    _pending.append(signum)
    _raise_or_retry(signum, frame)


def interrupt_exit_code(exc: BaseException) -> int:
    """128 + the signal number: 143 for SIGTERM (:class:`Terminated`), else 130 (SIGINT)."""
    return 128 + (signal.SIGTERM if isinstance(exc, Terminated) else signal.SIGINT)


def interrupt_name(exc: BaseException) -> str:
    """``"SIGTERM"`` or ``"Ctrl-C"``: what stopped the command, for its message."""
    return "SIGTERM" if isinstance(exc, Terminated) else "Ctrl-C"


def raise_if_interrupted() -> None:
    """Raise the interrupt of a signal received but not yet handled (its exception was
    dropped on the way): a cheap check for the periodic callbacks of a run."""
    if _pending:
        raise _exception(_pending[0])


@contextlib.contextmanager
def graceful_interrupts():
    """Within the block, SIGINT raises :class:`KeyboardInterrupt` and SIGTERM
    :class:`Terminated` in the main thread, once: after the first, both are ignored
    while the command cleans up and exits.  Without a signal the earlier handlers are
    restored after the block; nothing changes off the main thread."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    before = {sig: signal.signal(sig, _on_signal) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        if not _pending:
            for sig, handler in before.items():
                signal.signal(sig, handler)
        _pending.clear()


@contextlib.contextmanager
def sigint_ignored_by_children():
    """Ignore SIGINT within the block (main thread only), so that the processes started
    in it (a local Dask cluster's workers) inherit the ignored disposition (kept across
    ``exec``) and never see a terminal's Ctrl-C, which goes to the whole process group:
    the command alone handles it and closes them, without their tracebacks.  A Ctrl-C
    during the block (the workers' start, a second or two) is lost: press it again."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    before = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        if not _pending:             # a SIGTERM in the block leaves both ignored
            signal.signal(signal.SIGINT, before)
