"""The ``fem-rmpm`` console command: a light entry that loads the package (numba, scikit-fem,
Dask: about a second) inside its own interrupt handling, so that Ctrl-C or SIGTERM while
it loads ends the command quietly (exit 130 or 143) instead of with a traceback; then
:func:`fem_rmpm.cli.main` runs the command.  It imports nothing heavy itself."""
from __future__ import annotations

import signal
import sys

__all__ = ["main"]


class _Terminated(KeyboardInterrupt):
    """SIGTERM while the package loads."""


def _raise_terminated(signum, frame) -> None:
    raise _Terminated()


def main() -> int:
    """Load the command line and run it; an interrupt while loading exits 130 (Ctrl-C) or
    143 (SIGTERM) with one line on stderr."""
    before_term = signal.signal(signal.SIGTERM, _raise_terminated)
    # Ctrl-C raises KeyboardInterrupt while loading, whatever handler the process was
    # started with (a test runner's worker installs its own); an ignored SIGINT (a
    # background job) stays ignored
    before_int = signal.getsignal(signal.SIGINT)
    if before_int is not signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        from fem_rmpm.cli import main as cli_main
    except KeyboardInterrupt as exc:
        print("fem-rmpm: interrupted while starting; nothing was done", file=sys.stderr)
        return 128 + (signal.SIGTERM if isinstance(exc, _Terminated) else signal.SIGINT)
    finally:
        signal.signal(signal.SIGTERM, before_term)
        if before_int is not signal.SIG_IGN and before_int is not None:
            signal.signal(signal.SIGINT, before_int)
    return cli_main()
