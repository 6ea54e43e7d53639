"""One process running scenes of both bases, with and without F-bar, and of both thread
counts: each run gets its own compiled kernels (a kernel specialised for one basis and handed to a run of the other
gave non-finite states at the first step, or another deposit).  Reference: the same run
earlier in the same process, a run in a fresh process, and (slow) runs from a cache another
process filled against runs of an empty cache (:func:`fem_rmpm.runtime.compiled.variant`
says why variants need names of their own)."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from fem_rmpm import api
from fem_rmpm.scene import load_scene, with_values

ROOT = Path(__file__).resolve().parents[1]
TINY = ROOT / "tests" / "data" / "mc_tiny.toml"


def _max_displacement(shape: str, threads: int, fbar: bool = False) -> float:
    scene = with_values(load_scene(TINY), {"solver.shape": shape, "solver.threads": threads,
                                           "solver.fbar": fbar})
    return api.run(scene, seed=7, progress=False, vtk=False, figures=False
                   ).measures["max_displacement"]


def test_runs_of_both_bases_in_one_process_equal_their_own_fresh_runs():
    """uGIMP, Q4, uGIMP, Q4 on 1 then 2 threads in this process: each run equals bitwise
    its first occurrence and the uGIMP run of a fresh process."""
    got = {}
    for threads in (1, 2):
        for shape in ("gimp", "standard", "gimp", "standard"):
            d = _max_displacement(shape, threads)
            got.setdefault(shape, d)
            assert d == got[shape], (shape, threads, d, got[shape])
    code = ("from tests.test_kernel_variants_in_one_process import _max_displacement;"
            "print(repr(_max_displacement('gimp', 1)))")
    fresh = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True,
                           text=True, timeout=600, check=True)
    assert float(fresh.stdout.strip().splitlines()[-1]) == got["gimp"]
    assert got["gimp"] != got["standard"]


def test_runs_with_and_without_fbar_in_one_process_equal_their_first_runs():
    """F-bar on, off, on, off on 1 then 2 threads in this process (the kinematics chosen
    as a compile-time literal): each run equals bitwise its first occurrence, and the two
    settings differ."""
    got = {}
    for threads in (1, 2):
        for fbar in (True, False, True, False):
            d = _max_displacement("standard", threads, fbar)
            got.setdefault(fbar, d)
            assert d == got[fbar], (fbar, threads, d, got[fbar])
    assert got[True] != got[False]


_RUNS = ("from tests.test_kernel_variants_in_one_process import _max_displacement;"
         "print(' '.join(repr(_max_displacement(s, t)) for s, t in {runs}))")


def _fresh_process(runs, cache: Path) -> list[float]:
    """``_max_displacement`` of each (shape, threads) of ``runs`` in a new process whose
    numba cache is ``cache``."""
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache))
    out = subprocess.run([sys.executable, "-c", _RUNS.format(runs=list(runs))], cwd=ROOT,
                         env=env, capture_output=True, text=True, timeout=1200, check=True)
    return [float(x) for x in out.stdout.strip().splitlines()[-1].split()]


@pytest.mark.slow
def test_variants_from_a_cache_another_process_filled_equal_cold_runs(tmp_path):
    """A process fills an empty cache with the uGIMP kernels (2 then 1 threads); a second
    process runs Q4 (2, 1 threads) and then uGIMP from that cache: its Q4 runs equal those
    of a process with an empty cache of its own, its uGIMP run the first process's (a
    variant loaded from the cache beside another one compiled here, in both orders)."""
    filled = tmp_path / "filled"
    gimp = _fresh_process([("gimp", 2), ("gimp", 1)], filled)
    mixed = _fresh_process([("standard", 2), ("standard", 1), ("gimp", 2)], filled)
    cold = _fresh_process([("standard", 2), ("standard", 1)], tmp_path / "empty")
    assert gimp[0] == gimp[1] and cold[0] == cold[1], (gimp, cold)
    assert mixed[:2] == cold, (mixed, cold)
    assert mixed[2] == gimp[0], (mixed, gimp)
    assert gimp[0] != cold[0]
