"""Statistics, cost and memory of the 3-D random fields (fem_rmpm.random_field.field3d).

Usage::

    python validation/random_field_stats_3d.py [--n 1000] [--memory]

Per case (16 x 8 x 12 cells of 0.5 x 0.25 x 0.5 m, theta = 4, 1, 2 m along x, y, z), over N
realizations: the mean and COV of a lognormal property (mean 20, COV 0.3; point values)
or the variance of the Gaussian cell averages, and the correlation at theta/2 along each
axis, each with its standard error (SE, spread of the per-realization estimates over
sqrt(N)) and its distance to the target in SE.  Then the CPU time of the set-up and per
realization, and (``--memory``) the memory estimate against the tracemalloc peak and the
growth of the resident set for fields of 0.9 M and 7.5 M lattice points, and the estimate
of a 200 x 40 x 20 m slope at 0.5 m cells.
"""
from __future__ import annotations

import argparse
import math
import resource
import time
import tracemalloc

import numpy as np

from fem_rmpm.random_field.embedding3d import circulant_embedding_3d, estimate_embedding_3d
from fem_rmpm.random_field.field3d import embeddings_3d, field_lattice_3d
from fem_rmpm.random_field.model import local_average_covariance_1d
from fem_rmpm.random_field.model3d import MarkovModel3D
from fem_rmpm.random_field.quadrature3d import lattice_covariance_3d
from fem_rmpm.scene import RandomFieldSpec

THETA = (4.0, 1.0, 2.0)
CELL = (0.5, 0.25, 0.5)
BOX = (0.0, 0.0, 0.0, 8.0, 2.0, 6.0)
LAGS = (4, 2, 2)
MU, COV = 20.0, 0.3


def _stat(values, target):
    v = np.asarray(values)
    est, se = v.mean(), v.std(ddof=1) / math.sqrt(len(v))
    return f"{est:9.5f} {target:9.5f} {se:8.5f} {(est - target) / se:+6.2f}"


def case(kind: str, averaging: bool, n: int) -> None:
    spec = RandomFieldSpec(cov=COV, theta_v=THETA[1], anisotropy=THETA[0] / THETA[1],
                           correlation=kind, local_averaging=averaging)
    lat = field_lattice_3d(None, None, CELL, BOX)
    t0 = time.process_time()
    emb = embeddings_3d(spec, lat, THETA[2])[0]
    setup = time.process_time() - t0
    s2 = math.log1p(COV ** 2)
    rows = {"mean": [], "var": [], 0: [], 1: [], 2: []}
    t0 = time.process_time()
    zs = [emb.sample(seed) for seed in range(n)]
    per = (time.process_time() - t0) / n
    for z in zs:
        if averaging:                      # Gaussian cell averages: variance and covariance
            rows["var"].append(np.mean(z * z))
            d = z
        else:                              # lognormal point values
            c = MU * np.exp(math.sqrt(s2) * z - s2 / 2)
            rows["mean"].append(c.mean())
            rows["var"].append(np.mean((c - MU) ** 2))
            d = (c - MU) / (COV * MU)
        for a, lag in enumerate(LAGS):
            m = lat.shape[a]
            rows[a].append(np.mean(np.take(d, range(m - lag), a) * np.take(d, range(lag, m), a)))
    print(f"\n{kind}, {'cell averages (Gaussian)' if averaging else 'point values (lognormal)'}"
          f", N = {n}, lattice {emb.padded}, set-up {setup:.2f} s CPU, {1e3 * per:.2f} ms CPU "
          "per realization")
    print(f"{'statistic':28s} {'estimate':>9s} {'target':>9s} {'SE':>8s} {'z':>6s}")
    if averaging:
        print(f"{'variance':28s} {_stat(rows['var'], emb.variance)}")
        for a, lag in enumerate(LAGS):
            tgt = float(lattice_covariance_3d(emb.model, CELL, *[lag if b == a else 0
                                                                  for b in range(3)]))
            if kind == "markov_separable":
                closed = math.prod(float(local_average_covariance_1d(
                    lag if b == a else 0, CELL[b], THETA[b])) for b in range(3))
                assert abs(closed - tgt) < 1e-12
            print(f"{'covariance at theta/2, ' + 'xyz'[a]:28s} {_stat(rows[a], tgt)}")
    else:
        rho = math.expm1(s2 * math.exp(-1)) / math.expm1(s2)
        print(f"{'mean (kPa)':28s} {_stat(rows['mean'], MU)}")
        print(f"{'variance (kPa^2)':28s} {_stat(rows['var'], (COV * MU) ** 2)}")
        for a in range(3):
            print(f"{'correlation at theta/2, ' + 'xyz'[a]:28s} {_stat(rows[a], rho)}")


def _rss_mib() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def memory() -> None:
    m = MarkovModel3D(4.0, 1.0, 4.0)
    lattice_covariance_3d(m, CELL, [0], [0], [0])
    print("\nmemory: estimate against tracemalloc peak and growth of the peak resident set")
    for shape in ((60, 30, 40), (120, 60, 80)):
        est = estimate_embedding_3d(m, CELL, shape)
        rss0 = _rss_mib()
        tracemalloc.start()
        t0 = time.process_time()
        e = circulant_embedding_3d(m, CELL, shape, report=print)
        setup_t = time.process_time() - t0
        setup = tracemalloc.get_traced_memory()[1]
        tracemalloc.reset_peak()
        t0 = time.process_time()
        e.sample(1)
        sample_t = time.process_time() - t0
        sample = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        peak = max(setup, sample)
        print(f"  {shape} cells, lattice {e.padded} ({math.prod(e.padded):,} points): "
              f"estimate {est.peak_bytes / 2**20:.1f} MiB, tracemalloc peak "
              f"{peak / 2**20:.1f} MiB (ratio {est.peak_bytes / peak:.2f}), peak RSS growth "
              f"{_rss_mib() - rss0:.0f} MiB; set-up {setup_t:.1f} s CPU, one sample "
              f"{sample_t:.2f} s CPU")
    for th in (10.0, 40.0):
        big = MarkovModel3D(th, 1.0, th)
        est = estimate_embedding_3d(big, (0.5, 0.5, 0.5), (400, 80, 40))
        print(f"  200 x 40 x 20 m at 0.5 m, theta_h = {th:g} m: {est.describe()}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=1000)
    ap.add_argument("--memory", action="store_true")
    args = ap.parse_args()
    for kind in ("markov_elliptic", "markov_separable"):
        for averaging in (False, True):
            case(kind, averaging, args.n)
    if args.memory:
        memory()


if __name__ == "__main__":
    main()
