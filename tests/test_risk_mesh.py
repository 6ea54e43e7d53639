"""The critical strength factor search of validation/risk_mesh.py: bracketing
from lambda = 1 and bisection, on a stand/fail rule given in closed form."""
from __future__ import annotations

import pytest
from validation_module import load


def _mesh():
    return load("risk_mesh")


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


def test_paired_decisions_counts_discordant_pairs(tmp_path):
    """Four realizations on two meshes at lambda = 1: one fails on both, one on the fine
    mesh only, two stand on both; a run at another lambda or with a scene change and a
    realization on one mesh only are not pairs."""
    import json
    m = _mesh()
    rows = [(0, 0.5, True), (0, 0.25, True), (1, 0.5, False), (1, 0.25, True),
            (2, 0.5, False), (2, 0.25, False), (3, 0.5, False), (3, 0.25, False), (4, 0.5, True)]
    lines = [{"case": "xi=48", "index": i, "cell": c, "sets": "", "lambda": 1.0, "failed": f}
             for i, c, f in rows]
    lines += [{"case": "xi=48", "index": 2, "cell": 0.25, "sets": "", "lambda": 0.9, "failed": True},
              {"case": "xi=48", "index": 3, "cell": 0.25, "sets": "x=1", "lambda": 1.0, "failed": True}]
    (tmp_path / "runs.jsonl").write_text("".join(json.dumps(r) + "\n" for r in lines))
    res = m.paired_decisions(tmp_path, "xi=48", 0.5, 0.25)
    assert res["pairs"] == 4
    assert (res["fail_coarse"]["k"], res["fail_fine"]["k"]) == (1, 2)
    assert (res["fine_only"]["k"], res["coarse_only"]["k"]) == (1, 0)
    lo, hi = res["fine_only"]["wilson95"]
    assert lo < 0.25 < hi
