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
    failed with numba's SLP vectorizer on before the map's pair intrinsics (``--slp`` on
    c8efb93: two hashes at t = 2 s, measured; the script's module docstring), and compiled
    for an AVX2 CPU while the kernels allowed FMA contraction (``--cpu znver1`` on 739f015,
    478 steps: the run compiled in its process against the three others, measured on a
    Zen 4 host; a Zen 1 host differed the same way without ``--cpu``)."""
    assert load("load_order").main(args) == 0


def test_bad_setting_is_refused_in_one_line(capsys):
    """A ``--set`` that is not KEY=VALUE: exit status 2, one line on stderr, no run (not
    slow: refused before any child process starts)."""
    assert load("load_order").main(["--set", "solver.shape"]) == 2
    assert len(capsys.readouterr().err.strip().splitlines()) == 1
