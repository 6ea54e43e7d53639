"""The vectorised von Mises update of a block of points (``von_mises.block_update``, the
material protocol's optional ``block_update``) against the per-point update the kernels
used before (``von_mises.point_update``).

References: ``point_update`` (itself checked against the numpy reference and the closed
form radial return in ``tests/test_material_exact.py``) — the block update must give
bitwise its strains, Kirchhoff stresses and state on every branch (elastic, the linear
softening branch, the residual branch, a step that crosses from one to the other), so a
run is bitwise the one before; and the numpy ``update`` (Simo & Hughes 1998, sec. 3.3)
within 2e-15 of the largest stress and strain (measured: 2.9e-16 and 4.0e-16, round-off).
Points the block update does not compute (exponential softening, non-local) must keep a
run on the per-point path: ``block_eligible`` and ``takes_blocks``, asked once per run.
"""
from __future__ import annotations

import numpy as np
import pytest

from fem_rmpm.materials import model_id, mohr_coulomb, von_mises
from fem_rmpm.materials.dispatch import takes_blocks
from fem_rmpm.materials.protocol import BLOCK_COLUMNS, BLOCK_ROWS
from fem_rmpm.runtime.compiled import jit
from fem_rmpm.schemes.explicit.kernels.common import BLOCK

G, K, GS = 375.0, 1000.0, 0.5
_EXP, _REG = 5, 6                        # the law's and the regularisation's columns


@jit
def _point_path(E, state, params):
    """``point_update`` point by point (the kernels' per-point path, same flags)."""
    n = E.shape[0]
    out = np.empty((n, 8))
    for i in range(n):
        r = von_mises.point_update(E[i, 0], E[i, 1], E[i, 2], E[i, 3], state, params, i)
        for k in range(8):
            out[i, k] = r[k]
    return out


def _points(n: int, rng, state_columns: int):
    """Trial strains, parameter rows (column-major, as the run holds them) and states of
    ``n`` points spread over the update's branches."""
    cp = rng.uniform(10.0, 30.0, n)
    params = np.zeros((n, 10), order="F")
    params[:, 0], params[:, 1], params[:, 2], params[:, 3], params[:, 4] = G, K, cp, cp / 5, GS
    params[:, 7], params[:, 8], params[:, 9] = 0.5, np.nan, 2.0
    gam = rng.choice([0.0, 0.2, GS - 1e-3, 0.8], n) + rng.uniform(0.0, 1e-3, n)
    state = np.zeros((n, state_columns), order="F")
    state[:, 0] = gam
    state[:, -1] = gam
    dev = rng.normal(0.0, 1.0, (n, 4)) * rng.choice([0.003, 0.02, 0.08], n)[:, None]
    E = dev + rng.normal(0.0, 0.01, n)[:, None] * np.array([1.0, 1.0, 1.0, 0.0])
    return E, params, state


def _block_path(E, state, params, active):
    Z = np.full((BLOCK_ROWS, BLOCK_COLUMNS), np.nan)
    out = np.empty((len(E), 8))
    for b in range(0, len(E), BLOCK):
        m = min(BLOCK, len(E) - b)
        Z[:4, :m] = E[b:b + m].T
        von_mises.block_update(Z, state, params, active, np.uint64(b), np.uint64(m))
        out[b:b + m] = Z[4:12, :m].T
    return out


@pytest.mark.parametrize("state_columns", [3, 1])
def test_block_update_is_bitwise_the_point_update(state_columns):
    """1 000 points in 8 blocks (the last one partial), each branch taken: the same bits
    as ``point_update`` for the returned strains, the stresses and the state."""
    rng = np.random.default_rng(7)
    E, params, state = _points(1000, rng, state_columns)
    ref_state = state.copy(order="F")
    ref = _point_path(E, ref_state, params)
    got_state = state.copy(order="F")
    got = _block_path(E, got_state, params, np.ones(len(E), dtype=bool))
    assert np.array_equal(got, ref)
    assert np.array_equal(got_state, ref_state)
    dg = ref_state[:, 0] - state[:, 0]
    gam = state[:, -1]
    elastic, plastic = dg == 0, dg > 0
    crossed = plastic & (gam < GS) & (gam + dg > GS)
    assert elastic.sum() > 100 and (plastic & (gam + dg <= GS)).sum() > 50
    assert (plastic & (gam >= GS)).sum() > 100 and crossed.sum() > 20
    eps, _, tau = von_mises.update(E, state.copy(), params)
    assert np.abs(got[:, 4:] - tau).max() < 2e-15 * np.abs(tau).max()
    assert np.abs(got[:, :4] - eps).max() < 2e-15 * np.abs(eps).max()


def test_inactive_points_keep_their_state():
    rng = np.random.default_rng(8)
    E, params, state = _points(300, rng, 3)
    active = rng.random(300) < 0.5
    before = state.copy(order="F")
    _block_path(E, state, params, active)
    assert np.array_equal(state[~active], before[~active])
    assert (state[active, 0] > before[active, 0]).sum() > 50


@pytest.mark.parametrize("column, value", [(_EXP, 1.0), (_REG, 1.0)])
def test_one_point_needing_the_point_update_keeps_the_run_off_the_block_path(column, value):
    """Exponential softening (a Newton iteration) and non-local softening (a frozen
    strength) are left to ``point_update``: one such point among 1 000 and the run's
    points are not eligible; linear, local or displacement-regularised points are."""
    rng = np.random.default_rng(9)
    _, params, _ = _points(1000, rng, 3)
    vm = model_id("von_mises_softening")
    assert von_mises.block_eligible(params) and takes_blocks(vm, params)
    params[:, _REG] = 2.0                          # "displacement": a local softening strain
    assert von_mises.block_eligible(params) and takes_blocks(vm, params)
    params[:, _REG] = 0.0
    params[637, column] = value
    assert not von_mises.block_eligible(params) and not takes_blocks(vm, params)


def test_only_a_one_model_run_of_a_model_with_a_block_update_takes_blocks():
    """Mixed models (-1) and a model without ``block_update`` (Mohr-Coulomb) run point
    by point."""
    rng = np.random.default_rng(10)
    _, params, _ = _points(10, rng, 3)
    assert not takes_blocks(-1, params)
    assert not hasattr(mohr_coulomb, "block_update")
    assert not takes_blocks(model_id(mohr_coulomb.NAME), params)
