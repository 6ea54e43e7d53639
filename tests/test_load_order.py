"""A run does not depend on which compiled copy of a shared kernel its process loaded
first (``validation/load_order.py``: compiled in the process or loaded from numba's cache,
on 1 and on 2 threads).  Slow: one cold compile of the kernels (~20 s) in a cache
directory of its own, then three more runs to t = 1 s."""
from __future__ import annotations

import pytest

from validation_module import load


@pytest.mark.slow
def test_compiled_and_cached_kernels_give_the_same_run():
    """The four runs' step counts and state hashes are equal (exit status 0).  The check
    fails with numba's SLP vectorizer on (``--slp``: measured, module docstring)."""
    assert load("load_order").main(["--t-end", "1"]) == 0
