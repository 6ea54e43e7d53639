"""The start of ``fem-rmpm run``: what a command imports before it needs it, and the clock
of the user's wait (from the start of the process to the first step)."""
from __future__ import annotations

import os
import subprocess
import sys
import time

from fem_rmpm.runtime.numba_cache import PACKAGE, process_seconds

_ENV = dict(os.environ, PYTHONPATH=str(PACKAGE.parent))


def test_process_seconds_count_from_the_start_of_the_process():
    """:func:`.numba_cache.process_seconds` in a child that sleeps 0.5 s before asking: at
    least the 0.5 s (and the interpreter's start before), at most the child's wall time as
    its parent sees it (plus the kernel's 10 ms clock tick); in this process, after the
    imports, more than zero."""
    code = ("import time; time.sleep(0.5); "
            "from fem_rmpm.runtime.numba_cache import process_seconds; print(process_seconds())")
    t0 = time.monotonic()
    out = subprocess.run([sys.executable, "-c", code], env=_ENV, capture_output=True,
                         text=True, check=True, cwd=PACKAGE.parent).stdout
    wall = time.monotonic() - t0
    seconds = float(out)
    assert 0.5 <= seconds <= wall + 0.02, (seconds, wall)
    assert process_seconds() > 0.0
