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
    before = signal.signal(signal.SIGTERM, _raise_terminated)
    try:
        from fem_rmpm.cli import main as cli_main
    except KeyboardInterrupt as exc:
        print("fem-rmpm: interrupted while starting; nothing was done", file=sys.stderr)
        return 128 + (signal.SIGTERM if isinstance(exc, _Terminated) else signal.SIGINT)
    finally:
        signal.signal(signal.SIGTERM, before)
    return cli_main()
