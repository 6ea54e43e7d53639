"""The search of the strength reduction (fem_rmpm.schemes.implicit.strength_reduction) and
its continuation solves (fem_rmpm.schemes.implicit.srm_solves): the energy line search,
the rejection of a Newton solve whose residual grows, the decisive small change, the next
trial F.

Reference: the undrained infinite slope FS = c / (gamma z sin(beta) cos(beta)) (limit
equilibrium of a slice; Duncan & Wright 2005, ch. 6); on a mesh of n rows across the
layer the shear band sits half a row above the bedrock, FS_h / FS = n / (n - 1/2).
"""
import dataclasses
import math

import pytest

from fem_rmpm import api
from fem_rmpm.schemes.implicit.srm_solves import (
    FSOptions,
    continue_strength,
    gravity_solve,
    srm_scene,
)
from fem_rmpm.schemes.implicit.strength_reduction import _next_trial, factor_of_safety
from tests.test_strength_reduction import closed_form, infinite_slope

GAMMA = 20.0     # kN/m3, meshes/infinite_slope.toml


def _standing_slope(meshes, o: FSOptions):
    """The infinite slope of these tests (8 rows, c = 60 kPa; this mesh: FS 1.475) at
    gravity with F = 1 under ``o``'s search: ``(scene, srm scene, grid, points, the
    converged state)``."""
    sc = infinite_slope(meshes, rows=8, hx=1.0, c=60.0)
    grid, pts = api.prepare(sc)
    srm = srm_scene(sc, o)
    t1, start = gravity_solve(srm, grid, pts, 1.0, o)
    assert t1.converged
    return sc, srm, grid, pts, start


def test_next_trial_marches_bisects_and_never_repeats_the_bracket_end():
    o = FSOptions()
    step = math.log(o.march)
    # nothing failed: upwards by the march, capped at f_max
    assert _next_trial(1.0, math.inf, math.inf, step, o) == pytest.approx(1.25)
    assert _next_trial(9.0, math.inf, math.inf, 2 * step, o) == o.f_max
    # a failed solve below hi guides the bisection ...
    assert _next_trial(1.0, 1.25, 1.10, step, o) == pytest.approx(math.sqrt(1.10))
    # ... also within decisive_change of lo (the midpoint's failure decides too) ...
    assert _next_trial(1.0, 1.25, 1.01, step, o) == pytest.approx(math.sqrt(1.01))
    # ... and is itself the next trial once within the tolerance of lo
    assert _next_trial(1.0, 1.25, 1.004, step, o) == pytest.approx(1.004)
    # hi is never tried again (its failure is known): the midpoint, however close
    assert _next_trial(1.0, 1.01, math.inf, step, o) == pytest.approx(math.sqrt(1.01))
    assert _next_trial(1.0, 1.01, 1.01, step, o) == pytest.approx(math.sqrt(1.01))


def test_rejection_keeps_converging_solves_and_shortens_failing_ones(meshes):
    """Infinite slope, 8 rows, c = 60 kPa (closed form 1.386; this mesh: FS 1.475).  From
    the converged state at F = 1, continuations to 1.3-1.45 (up to 2 % below collapse)
    converge alike with and without the rejection of a growing residual (same
    iterations, same maximum displacement); past collapse (1.7) both fail, the rejecting
    solve in fewer iterations (seen: 8 against 12)."""
    never = FSOptions(line_search="residual", growth_rejection=0.0)
    rejecting = dataclasses.replace(never, growth_rejection=1.5)
    _, srm, grid, pts, start = _standing_slope(meshes, never)
    for F in (1.3, 1.45, 1.7):
        a, _, _ = continue_strength(srm, grid, pts, start, 1.0, F, never)
        b, _, _ = continue_strength(srm, grid, pts, start, 1.0, F, rejecting)
        assert a.converged == b.converged == (F < 1.475)
        if a.converged:
            assert a.iterations == b.iterations
            assert b.max_displacement == pytest.approx(a.max_displacement, rel=1e-12)
        else:
            assert b.iterations < a.iterations
            assert "above its smallest" in b.reason and "smallest" not in a.reason


def test_energy_line_search_converges_the_same_states_and_diverges_past_collapse(meshes):
    """Same slope (this mesh: FS 1.475).  From the converged state at F = 1 the
    continuations to 1.3, 1.45 and 1.47 converge with the energy line search and with
    the residual-norm backtracking to the same state (maximum displacement within 1e-6:
    the incremental problem of an associated elastic-plastic solid has one minimum), the
    energy line search in as many iterations or fewer (seen: 5, 7, 10 against 5, 7, 12);
    past collapse (1.7) the energy decreases without bound along the mechanism and the
    solve fails as diverging, sooner than the residual norm's growth rejects it (seen:
    4 against 8 iterations)."""
    energy = FSOptions()
    residual = FSOptions(line_search="residual")
    _, srm, grid, pts, start = _standing_slope(meshes, energy)
    for F in (1.3, 1.45, 1.47):
        a, _, _ = continue_strength(srm, grid, pts, start, 1.0, F, energy)
        b, _, _ = continue_strength(srm, grid, pts, start, 1.0, F, residual)
        assert a.converged and b.converged
        assert a.iterations <= b.iterations - (F == 1.47), (F, a.iterations, b.iterations)
        assert a.max_displacement == pytest.approx(b.max_displacement, rel=1e-6)
    past, _, _ = continue_strength(srm, grid, pts, start, 1.0, 1.7, energy)
    rejected, _, _ = continue_strength(srm, grid, pts, start, 1.0, 1.7, residual)
    assert not past.converged and "diverging" in past.reason
    assert not rejected.converged and past.iterations < rejected.iterations


def test_failure_over_a_small_change_is_decisive_a_large_one_is_not(meshes):
    """Same slope (FS 1.475), from the converged state at F = 1.46: a solve to 1.6 (9.6 %,
    above decisive_change 1.5 %) fails without deciding the trial (no upper bound of FS);
    a solve to 1.48 (1.4 %) that fails fails the trial there; a converged solve below
    FS (1.47) moves the state on.  Then the search: no decisive failure lies below its
    bracket's lower end."""
    o = FSOptions()
    sc, srm, grid, pts, start = _standing_slope(meshes, o)
    t1, state, _ = continue_strength(srm, grid, pts, start, 1.0, 1.46, o)
    assert t1.converged
    big, _, _ = continue_strength(srm, grid, pts, state, 1.46, 1.6, o)
    assert not big.converged and math.isinf(big.failed_at) and big.reached == 1.46
    small, _, _ = continue_strength(srm, grid, pts, state, 1.46, 1.48, o)
    assert not small.converged and (small.failed_at, small.reached) == (1.48, 1.46)
    near, _, _ = continue_strength(srm, grid, pts, state, 1.46, 1.47, o)
    assert near.converged and near.reached == 1.47 and math.isinf(near.failed_at)
    res = factor_of_safety(sc, options=o, grid=grid, pts=pts)
    assert res.bound == "=" and 1.46 < res.fs < 1.49
    lo, hi = res.bracket
    assert hi == min(t.failed_at for t in res.trials)
    assert lo == max(t.F for t in res.trials if t.converged)


def test_search_matches_closed_form_and_the_gravity_anew_search(meshes):
    """Infinite slope z = 5 m, beta = 30 deg, c = 60 kPa, 20 rows (closed form 1.386,
    with the half-row shear band 1.421): the continued search (decisive small changes,
    the energy line search, bisection towards the lowest failure) and the plain
    search (gravity applied anew at every trial, no continuation) bracket FS within their
    tolerance (0.5 %).  Achieves 1.4196 (10 static solves, 46 Newton iterations) and
    1.4170 (11 solves, 409 iterations, the failed one-solve gravity attempts included):
    0.19 % apart (asserts 0.6 %), -0.11 % from the half-row closed form (asserts 1.5 %)."""
    sc = infinite_slope(meshes, rows=20, hx=0.5, c=60.0)
    exact = closed_form(60.0, GAMMA, 5.0, 30.0) * 20 / 19.5
    grid, pts = api.prepare(sc)
    fast = factor_of_safety(sc, options=FSOptions(), grid=grid, pts=pts)
    grid, pts = api.prepare(sc)
    plain = factor_of_safety(sc, options=FSOptions(continuation=False), grid=grid, pts=pts)
    for res in (fast, plain):
        assert res.bound == "="
        assert res.bracket[1] / res.bracket[0] - 1 <= 0.005 + 1e-12
    assert abs(fast.fs / plain.fs - 1) < 0.006, (fast.fs, plain.fs)
    assert abs(fast.fs / exact - 1) < 0.015, (fast.fs, exact)
