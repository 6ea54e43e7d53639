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


#: Modules that ``fem-rmpm run`` of an explicit plane-strain scene without a random field
#: does not need: the campaign's cluster (dask), the figures (matplotlib; written after
#: the run), the implicit scheme, the random fields, the three-dimensional scheme and the
#: static FEM reference.
_NOT_NEEDED = ("dask", "distributed", "matplotlib", "fem_rmpm.campaign.cluster",
               "fem_rmpm.schemes.implicit", "fem_rmpm.random_field", "fem_rmpm.schemes.explicit3d",
               "fem_rmpm.schemes.fem")

_RUN = r"""
import json, sys
from fem_rmpm.schemes.explicit import loop
first = {}
done = loop.first_step_done
def first_step_done(*args, **kw):
    first["modules"] = sorted(sys.modules)
    return done(*args, **kw)
loop.first_step_done = first_step_done
from fem_rmpm import cli
parser = sys.modules.copy()
cli.build_parser()
code = cli.main(sys.argv[1:])
print(json.dumps({"code": code, "cli": sorted(parser), "first": first["modules"],
                  "end": sorted(sys.modules)}))
"""


def test_an_explicit_run_imports_no_module_it_does_not_use(tmp_path):
    """``import fem_rmpm.cli`` and its parser, a run of the embedded reference slope up to
    its first step, and the whole run without figures (``output.png = false``) import none
    of :data:`_NOT_NEEDED`; the measures (scipy.ndimage's labelling) come after the first
    step.  With figures the run imports matplotlib, and a scene with a random field the
    random fields (the check can fail)."""
    import json

    out = subprocess.run(
        [sys.executable, "-c", _RUN, "run", "--set", 'solver.kernel="numpy"', "--set",
         "solver.t_end=0.004", "--set", "output.png=false", "--out", str(tmp_path / "run")],
        env=_ENV, capture_output=True, text=True, check=True, cwd=tmp_path).stdout
    got = json.loads(out.splitlines()[-1])
    assert got["code"] == 0
    for stage in ("cli", "first", "end"):
        assert not [m for m in _NOT_NEEDED if m in got[stage]], stage
    assert "fem_rmpm.measures.deposit" not in got["first"]
    assert "fem_rmpm.measures.deposit" in got["end"]
    out = subprocess.run(
        [sys.executable, "-c", _RUN, "run", str(PACKAGE.parent / "tests" / "data" / "mc_tiny.toml"),
         "--set", 'solver.kernel="numpy"', "--set", "solver.t_end=0.004", "--set",
         "output.png=true", "--out", str(tmp_path / "tiny")],
        env=_ENV, capture_output=True, text=True, check=True, cwd=tmp_path).stdout
    got = json.loads(out.splitlines()[-1])
    assert "fem_rmpm.random_field" in got["first"] and "matplotlib" in got["end"]
