"""A run does not depend on which compiled copy of a shared kernel its process loaded
first (``validation/load_order.py``: compiled in the process or loaded from numba's cache,
on 1 and on 2 threads).  The comparisons are slow: each compiles the kernels cold (~20 s)
in a cache directory of its own, then runs three more times."""
from __future__ import annotations

import pytest
from validation_module import load


@pytest.mark.slow
@pytest.mark.parametrize("args", [
    ["--t-end", "4"],                                                   # case (i): Q4
    ["--t-end", "1", "--set", "solver.shape=gimp", "--set", "solver.fbar=true"],
    ["--t-end", "2", "--scene", "meshes/slope_drained.toml"],          # Mohr-Coulomb
    ["--t-end", "2", "--cpu", "znver1"],                      # case (i), AVX2 code
])
def test_compiled_and_cached_kernels_give_the_same_run(args):
    """The four runs' step counts and state hashes are equal (exit status 0).  The check
    fails when a callee's compiled copies may round differently: with numba's SLP
    vectorizer on and the map's x, y twins not written as vector operations (``--slp``), or
    with FMA contraction allowed in code for an AVX2 CPU (``--cpu znver1``)."""
    assert load("load_order").main(args) == 0


def test_bad_setting_is_refused_in_one_line(capsys):
    """A ``--set`` that is not KEY=VALUE: exit status 2, one line on stderr, no run (not
    slow: refused before any child process starts)."""
    assert load("load_order").main(["--set", "solver.shape"]) == 2
    assert len(capsys.readouterr().err.strip().splitlines()) == 1
