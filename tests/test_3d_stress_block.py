"""The blocked stress pass of the 3-D explicit step (:func:`fem_rmpm.schemes.explicit3d.
stress3d.stress_3d`: trial stretches, eigen-decompositions, von Mises returns and new
tensors vectorized over blocks of points) against the same update one point at a time
(:func:`~fem_rmpm.schemes.explicit3d.stress3d.stress_points_3d`): the same IEEE
operations on every point but the logarithms and exponentials (vectorized series,
:mod:`fem_rmpm.schemes.explicit3d.logexp`, against the library's in the reference), so
the same results within round-off, whatever the mix of models in a block (linear
elastic, von Mises with the linear and the exponential law, Mohr-Coulomb), inactive
points, stretches outside the series' ranges and a partial last block."""
from __future__ import annotations

import numpy as np

from fem_rmpm.schemes.explicit3d.elastic import EIG_BLOCK, stretch_from_log_strain
from fem_rmpm.schemes.explicit3d.finite_block import BLOCK_ROWS
from fem_rmpm.schemes.explicit3d.plastic import (
    MODEL_ELASTIC,
    MODEL_MOHR_COULOMB,
    MODEL_VON_MISES,
)
from fem_rmpm.schemes.explicit3d.stress3d import stress_3d, stress_points_3d

SHAPE = np.array([4, 4, 4])
H = np.array([0.5, 0.5, 0.5])
ORIGIN = np.zeros(3)


def _points(n: int, rng: np.random.Generator) -> dict:
    """``n`` points in random cells of a 4 x 4 x 4 grid with random elastic strains
    (within a few times the yield strain), plastic shear strains across the end of the
    softening slope (0.5) and a mix of models; one in nine inactive."""
    sy, sz = SHAPE[0] + 1, (SHAPE[0] + 1) * (SHAPE[1] + 1)
    ijk = rng.integers(0, 4, (n, 3))
    xi = rng.uniform(0, 1, (n, 3))
    x = ORIGIN + H * (ijk + xi)
    eps = rng.normal(0, 0.02, (n, 6))
    be = np.empty((n, 6))
    stretch_from_log_strain(eps, be)
    model = rng.choice([MODEL_ELASTIC, MODEL_VON_MISES, MODEL_VON_MISES, MODEL_VON_MISES,
                        MODEL_MOHR_COULOMB], n)
    plastic = np.tile([20.0, 4.0, 0.5, 0.0, np.nan, np.nan, np.nan, np.nan, np.nan], (n, 1))
    plastic[rng.uniform(size=n) < 0.2, 3] = 1.0                   # the exponential law
    mc = model == MODEL_MOHR_COULOMB
    plastic[mc] = [20.0, 4.0, 30.0, 20.0, 5.0, 0.0, 0.5, 0.0, np.inf]
    gamma = rng.uniform(0, 0.7, n)
    mu = np.full(n, 1000.0 / 2.66)
    lam = np.full(n, 1000.0 * 0.33 / (1.33 * 0.34))
    vol0 = np.full(n, 0.125 / 8)
    return dict(
        x=x, v=rng.normal(0, 1.0, (n, 3)), mass=2.0 * vol0, vol=vol0 * rng.uniform(0.9, 1.1, n),
        vol0=vol0, stress=np.zeros((n, 6)), eps=eps, be=be, lam=lam, mu=mu,
        active=rng.uniform(size=n) > 1 / 9, cellbase=ijk[:, 0] + sy * ijk[:, 1] + sz * ijk[:, 2],
        cellxi=xi, model=model, plastic=np.ascontiguousarray(plastic),
        state=np.stack([gamma, gamma], axis=1))


def _pass(p: dict, node: np.ndarray, blocked: bool) -> np.ndarray:
    stats = np.zeros(4)
    args = (p["mass"], p["vol"], p["vol0"], p["stress"], p["eps"], p["be"], p["lam"],
            p["mu"], p["active"], p["cellbase"], p["cellxi"], H, SHAPE, node, 0, len(p["x"]), 0.01, False, p["model"], p["plastic"], p["state"])
    if blocked:
        stress_3d(*args, np.zeros(3), np.zeros((BLOCK_ROWS, EIG_BLOCK)),
                  np.zeros(EIG_BLOCK, np.int64), stats)
    else:
        stress_points_3d(*args, stats)
    return stats


#: Largest difference allowed between the blocked and the point-by-point pass, relative
#: to the largest magnitude of each array: 7e-16 is reached (the plastic state after
#: three passes; stress and log strain 2.8e-16, volumes and maxima equal).
ROUND_OFF = 3e-15


def _close(a: np.ndarray, b: np.ndarray) -> bool:
    return bool(np.abs(a - b).max() <= ROUND_OFF * np.abs(b).max())


def test_blocked_stress_pass_equals_the_point_by_point_update_within_round_off():
    """1000 points (15 full blocks and a partial one), three passes in a row: stress, log
    strain, stretch, volume, plastic state and the pass's maxima are those of one point
    at a time within round-off (:data:`ROUND_OFF`); the case yields on the slope, crosses
    to the residual and returns Mohr-Coulomb points, and eleven points are stretched
    beyond the series' ranges (log strains 1.3-1.6: the library's logarithm and
    exponential), so each branch is compared."""
    rng = np.random.default_rng(7)
    p = _points(1000, rng)
    big = np.arange(0, 1000, 97)
    p["eps"][big] = [1.6, 1.3, 1.4, 0.05, 0.0, 0.02]
    stretch_from_log_strain(p["eps"], p["be"])
    q = {k: v.copy() for k, v in p.items()}
    gamma0 = p["state"][:, 0].copy()
    for _ in range(3):
        node = np.zeros((int(np.prod(SHAPE + 1)), 8))
        node[:, 1:4] = rng.normal(0, 1.0, (len(node), 3))
        s_block = _pass(p, node, True)
        s_point = _pass(q, node, False)
        assert _close(s_block, s_point)
        for k in ("stress", "eps", "be", "vol", "state"):
            assert _close(p[k], q[k]), k
    assert ((p["eps"][big, 0] > 1.2) & (p["state"][big, 0] > gamma0[big])).sum() >= 3
    dg = p["state"][:, 0] - gamma0
    vm = (p["model"] == MODEL_VON_MISES) & p["active"]
    linear = vm & (p["plastic"][:, 3] == 0.0)
    assert (dg[linear] > 0).sum() > 100
    assert ((gamma0 < 0.5) & (p["state"][:, 0] > 0.5) & linear).sum() > 5
    assert (dg[vm & ~linear] > 0).sum() > 20
    assert (dg[p["model"] == MODEL_MOHR_COULOMB] > 0).sum() > 20
    assert np.array_equal(p["stress"][~p["active"]], np.zeros((int((~p["active"]).sum()), 6)))


def test_nodal_row_vectors_equal_the_scalar_sums_bitwise():
    """The map back's interpolation of whole nodal rows and its re-mapped momentum
    (:mod:`fem_rmpm.schemes.explicit3d.rows`, 8- and 4-wide vector operations) against
    the scalar sums written out in the same order, on random rows and weights."""
    from numba import njit

    from fem_rmpm.schemes.explicit3d.rows import row_add4, row_diffs4, row_sum8

    @njit
    def both(g, n, w, buf):
        r = row_sum8(g, (n[0], n[1], n[2], n[3], n[4], n[5], n[6], n[7]),
                     (w[0], w[1], w[2], w[3], w[4], w[5], w[6], w[7]))
        d = row_diffs4(g, (n[0], n[1], n[2], n[3]), (n[4], n[5], n[6], n[7]),
                       (w[0], w[1], w[2], w[3]))
        out = np.empty((4, 8))
        for k in range(8):
            out[0, k] = r[k]
            out[1, k] = (w[0] * g[n[0], k] + w[1] * g[n[1], k] + w[2] * g[n[2], k]
                         + w[3] * g[n[3], k] + w[4] * g[n[4], k] + w[5] * g[n[5], k]
                         + w[6] * g[n[6], k] + w[7] * g[n[7], k])
            out[2, k] = d[k]
            out[3, k] = (w[0] * (g[n[0], k] - g[n[4], k]) + w[1] * (g[n[1], k] - g[n[5], k])
                         + w[2] * (g[n[2], k] - g[n[6], k]) + w[3] * (g[n[3], k] - g[n[7], k]))
        ref = buf.copy()
        row_add4(buf, n[0], w[0], (0.0, w[1], w[2], w[3]))
        for k in range(1, 4):
            ref[n[0], k] += w[0] * w[k]
        return out, buf, ref

    rng = np.random.default_rng(3)
    for _ in range(200):
        g = rng.normal(size=(50, 8)) * 10.0 ** rng.integers(-3, 3, (50, 1))
        n = rng.choice(50, 8, replace=False)
        w = rng.uniform(0, 1, 8)
        out, buf, ref = both(g, n, w, rng.normal(size=(50, 8)))
        assert np.array_equal(out[0], out[1]) and np.array_equal(out[2], out[3])
        assert np.array_equal(buf, ref)
