"""Crude Monte Carlo: realizations ``0 .. n-1`` in one batch; P = k/n.

Sample ``i`` draws its noise from ``realization_seed(campaign_seed, i)``
(:func:`fem_rmpm.campaign.cases.realization_seed`), so a crude campaign of ``n`` and one of
``n + m`` share their first ``n`` realizations.  Its coefficient of variation is the
binomial ``sqrt((1 - P) / (n P))`` (e.g. Fenton & Griffiths 2008, Risk Assessment in
Geotechnical Engineering, sec. 6.2).
"""
from __future__ import annotations

import math
from typing import Callable

import numpy as np

from fem_rmpm.campaign.cases import realization_seed
from fem_rmpm.campaign.methods.protocol import (
    BatchMethod,
    LevelResult,
    MethodResult,
    Sample,
    check_common,
    standard_noise,
)

__all__ = ["CrudeMonteCarlo"]


class CrudeMonteCarlo(BatchMethod):
    """Crude Monte Carlo: ``n`` samples in one batch, P = k/n, COV = sqrt((1-P)/(n P))."""
    name = "crude"

    def __init__(self, threshold: float, n: int, seed: int = 0,
                 noise_from_seed: Callable[[int], np.ndarray] | None = None,
                 dim: int | None = None, on_failure: str = "raise"):
        check_common(threshold, n, on_failure)
        self.threshold, self.n, self.seed = float(threshold), int(n), int(seed)
        self.noise_from_seed = noise_from_seed or standard_noise(int(dim or 1))
        self.on_failure = on_failure
        self._start()

    def _process(self):
        samples = [Sample(0, i, 0, seed=realization_seed(self.seed, i)) for i in range(self.n)]
        y = yield samples
        k = int(np.count_nonzero(y > self.threshold))
        p = k / self.n
        cov = math.sqrt((1 - p) / (self.n * p)) if k else math.inf
        lv = LevelResult(0, self.threshold, p, cov, 0.0, y, np.arange(self.n),
                         np.zeros(self.n, int), self.n, 0)
        return MethodResult("crude", self.threshold, p, cov, self.n, self.failed_runs,
                            levels=[lv])
