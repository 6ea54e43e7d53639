"""Statistics of 3-D random fields over many realizations against their targets.

References (formulas): for point values of a lognormal field with mean ``mu`` and COV
``v`` (``s^2 = ln(1 + v^2)``) the values have mean ``mu``, variance ``(v mu)^2`` and, at a
lag where the Gaussian correlation is ``rho``, the correlation
``(exp(s^2 rho) - 1) / (exp(s^2) - 1)`` (Fenton & Griffiths 2008, ch. 1); along each axis
the Markov correlation at half the scale of fluctuation is ``rho = exp(-1)``.  Local
averages of the separable Markov model over cells ``T1 x T2 x T3`` have the variance
``g(T1) g(T2) g(T3)`` (Vanmarcke 1983, ch. 5).

Each statistic is estimated per realization (over the cells or cell pairs of the field,
with the known mean) and averaged over N independent realizations; its standard error SE
is the standard deviation of the per-realization estimates over sqrt(N), and the tests
require the average within 5 SE of the target.
"""
from __future__ import annotations

import math

import numpy as np

from fem_rmpm.random_field.field3d import (
    embeddings_3d,
    field_lattice_3d,
    gaussian_fields_3d,
    sample_cell_field_3d,
)
from fem_rmpm.random_field.model import local_average_covariance_1d, variance_function
from fem_rmpm.scene import RandomFieldSpec

N = 240
MU, COV = 20.0, 0.3
THETA = (4.0, 1.0, 2.0)                     # theta_h (x), theta_v (y), theta_z (z), m
CELL = (0.5, 0.25, 0.5)                     # theta / 2 = 4, 2, 2 cells along x, y, z
BOX = (0.0, 0.0, 0.0, 8.0, 2.0, 6.0)        # 16 x 8 x 12 cells


def _within(values, target, what):
    est = float(np.mean(values))
    se = float(np.std(values, ddof=1) / math.sqrt(len(values)))
    assert abs(est - target) <= 5 * se, (
        f"{what}: {est:.5f} over N = {len(values)} realizations, target {target:.5f}, "
        f"SE {se:.5f}: off by {abs(est - target) / se:.1f} SE (allowed 5); check the 3-D "
        "embedding's covariance table (quadrature3d) and the lattice axes")
    return est, se


def test_lognormal_point_field_mean_cov_and_correlation_at_half_theta_on_each_axis():
    """Point values (no averaging) of an elliptic Markov lognormal field, 16 x 8 x 12 cells,
    theta = (4, 1, 2) m along x, y, z, N = 240 realizations.  Targets: mean 20, COV 0.3
    (variance 36), correlation at theta/2 on each axis 0.346.  Measured (seeds 0..239):
    SE of the mean ~0.12 kPa, of the variance ~1.1 kPa^2, of each correlation ~0.01."""
    spec = RandomFieldSpec(cov=COV, theta_v=THETA[1], anisotropy=THETA[0] / THETA[1],
                           local_averaging=False, cell_size=None)
    lattice = field_lattice_3d(None, None, cell_size=CELL, box=BOX)
    assert lattice.shape == (16, 8, 12)
    centres = lattice.centres()
    sizes = np.broadcast_to(lattice.cell, centres.shape)
    s2 = math.log1p(COV ** 2)
    rho_ln = math.expm1(s2 * math.exp(-1.0)) / math.expm1(s2)
    means, variances, corr = [], [], {0: [], 1: [], 2: []}
    for seed in range(N):
        c = sample_cell_field_3d(spec, centres, sizes, seed, means=MU, theta_z=THETA[2],
                                 box=BOX, cell_size=CELL)["cohesion_peak"]
        d = (c.reshape(lattice.shape) - MU) / (COV * MU)
        means.append(c.mean())
        variances.append(np.mean((c - MU) ** 2))
        for axis, lag in ((0, 4), (1, 2), (2, 2)):
            n = lattice.shape[axis]
            a = np.take(d, range(n - lag), axis=axis)
            b = np.take(d, range(lag, n), axis=axis)
            corr[axis].append(np.mean(a * b))
    _within(means, MU, "mean (kPa)")
    _within(variances, (COV * MU) ** 2, "variance (kPa^2)")
    for axis, name in enumerate("xyz"):
        _within(corr[axis], rho_ln, f"correlation at theta/2 along {name}")


def test_local_average_variance_and_axis_covariance_of_the_separable_field():
    """Cell averages of the separable model (closed-form covariance): the Gaussian cell
    variance is g(0.5; 4) g(0.25; 1) g(0.5; 2) = 0.748 and the covariance at theta/2 on
    each axis the product of Vanmarcke's 1-D terms; N = 240 realizations of 16 x 8 x 12
    cells (SE of the variance ~0.02)."""
    spec = RandomFieldSpec(cov=COV, theta_v=THETA[1], anisotropy=THETA[0] / THETA[1],
                           correlation="markov_separable")
    lattice = field_lattice_3d(None, None, cell_size=CELL, box=BOX)
    g = [float(variance_function(h, t)) for h, t in zip(CELL, THETA)]
    target_var = g[0] * g[1] * g[2]
    variances, cov = [], {0: [], 1: [], 2: []}
    embs = embeddings_3d(spec, lattice, THETA[2])
    assert abs(embs[0].variance - target_var) < 1e-12
    for seed in range(N):
        z = gaussian_fields_3d(spec, lattice, seed, theta_z=THETA[2])[0]
        variances.append(np.mean(z * z))
        for axis, lag in ((0, 4), (1, 2), (2, 2)):
            n = lattice.shape[axis]
            cov[axis].append(np.mean(np.take(z, range(n - lag), axis=axis)
                                     * np.take(z, range(lag, n), axis=axis)))
    _within(variances, target_var, "variance of cell averages")
    for axis, lag in ((0, 4), (1, 2), (2, 2)):
        terms = [float(local_average_covariance_1d(lag if a == axis else 0, CELL[a], THETA[a]))
                 for a in range(3)]
        _within(cov[axis], math.prod(terms), f"covariance at theta/2 along {'xyz'[axis]}")
