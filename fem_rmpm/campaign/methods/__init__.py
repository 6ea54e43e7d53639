"""Campaign methods: one ask/tell protocol (:mod:`.protocol`), one file per method, and
:data:`METHODS`, the table the campaign runner and ``fem-rmpm mc --method NAME`` read.

A new method is a :class:`~fem_rmpm.campaign.methods.protocol.BatchMethod` subclass in a
file of its own plus one :class:`MethodEntry` row in :data:`METHODS`; the runner
(:func:`fem_rmpm.campaign.runner.run_method_campaign`) evaluates any of them.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from fem_rmpm.campaign.methods.crude import CrudeMonteCarlo
from fem_rmpm.campaign.methods.per_case import PerCase
from fem_rmpm.campaign.methods.protocol import (
    BatchMethod,
    CampaignMethod,
    LevelResult,
    MethodResult,
    Sample,
    SubsetError,
    SubsetWarning,
    run_method,
    standard_noise,
)
from fem_rmpm.campaign.methods.subset import (
    SubsetSimulation,
    chain_correlation_factor,
    subset_simulation,
)

__all__ = ["METHODS", "MethodEntry", "MethodOptions", "CampaignMethod", "BatchMethod",
           "Sample", "MethodResult", "LevelResult", "SubsetError", "SubsetWarning",
           "CrudeMonteCarlo", "SubsetSimulation", "PerCase", "run_method", "subset_simulation",
           "chain_correlation_factor", "standard_noise"]


@dataclass(frozen=True)
class MethodOptions:
    """What a campaign gives a method: ``n`` samples (per level), the campaign ``seed``,
    the failure ``threshold`` on the response Y (failure: Y > threshold), the level
    probability ``p0``, ``noise_from_seed`` (the noise vector of a seeded sample), how a
    failed run counts (``on_failure``), the failure event in messages (``label``) and the
    most levels of a multi-level method (``max_levels``)."""
    n: int
    seed: int
    threshold: float
    p0: float = 0.1
    noise_from_seed: Callable[[int], np.ndarray] | None = None
    on_failure: str = "reject"
    label: str | None = None
    max_levels: int = 20


@dataclass(frozen=True)
class MethodEntry:
    """A row of :data:`METHODS`.  ``make`` builds the method from :class:`MethodOptions`;
    ``response``: True for a method that estimates P(response beyond threshold) of one
    scene (``--response``, ``--threshold``, ``--p0``; its samples may be chain states,
    recorded by key), False for one whose samples are realizations ``i`` of every case
    (records per case and index, statistics per case); ``help``: one line for ``--help``."""
    make: Callable[[MethodOptions], CampaignMethod]
    response: bool
    help: str


def _crude(o: MethodOptions) -> CrudeMonteCarlo:
    return CrudeMonteCarlo(o.threshold, o.n, seed=o.seed, noise_from_seed=o.noise_from_seed,
                           on_failure=o.on_failure)


def _subset(o: MethodOptions) -> SubsetSimulation:
    return SubsetSimulation(o.threshold, n=o.n, p0=o.p0, seed=o.seed,
                            noise_from_seed=o.noise_from_seed, on_failure=o.on_failure,
                            max_levels=o.max_levels, label=o.label)


#: ``--method`` name -> :class:`MethodEntry`.
METHODS: dict[str, MethodEntry] = {
    "crude": MethodEntry(_crude, response=False,
                         help="crude Monte Carlo: realizations 0 .. N-1 of every case"),
    "subset": MethodEntry(_subset, response=True,
                          help="subset simulation: P(--response beyond --threshold)"),
}
