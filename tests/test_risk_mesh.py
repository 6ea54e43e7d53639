"""The critical strength factor search of validation/risk_mesh.py (issue 17): bracketing
from lambda = 1 and bisection, on a stand/fail rule given in closed form."""
from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _mesh():
    spec = importlib.util.spec_from_file_location("risk_mesh", ROOT / "validation" / "risk_mesh.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.mark.parametrize("crit", [0.6234, 0.937, 1.0, 1.2871])
def test_bracket_contains_the_critical_factor(crit):
    """A slope that fails below ``crit`` and stands at or above it: the bracket [lo, hi]
    has lo failing, hi standing, lo < crit <= hi and width <= the tolerance 0.01."""
    m = _mesh()
    calls = []

    def do_run(lam):
        calls.append(lam)
        return lam < crit
    lo, hi = m.critical_factor({}, do_run, step=0.1, tol=0.01)
    assert lo < crit <= hi
    assert hi - lo <= 0.01 + 1e-9
    assert len(calls) == len(set(calls))          # no lambda run twice
    assert len(calls) <= 12


def test_cached_runs_are_reused():
    """Runs already in the cache (a resumed search) are not run again; the bracket is the same."""
    m = _mesh()
    crit = 0.937
    cache: dict = {}
    first = m.critical_factor(cache, lambda lam: lam < crit, 0.1, 0.01)
    again = m.critical_factor(dict(cache), lambda lam: pytest.fail(f"ran {lam} again"), 0.1, 0.01)
    assert first == again


def test_block_mean():
    """Points in the same block get the block's mean; other blocks are untouched."""
    import numpy as np
    m = _mesh()
    x0 = np.array([[0.1, 0.1], [0.4, 0.3], [0.6, 0.1], [0.2, 0.7]])
    v = np.array([10.0, 20.0, 30.0, 40.0])
    np.testing.assert_allclose(m.block_mean(x0, v, 0.5), [15.0, 15.0, 30.0, 40.0])
