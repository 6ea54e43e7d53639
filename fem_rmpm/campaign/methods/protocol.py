"""The campaign-method protocol: ask for samples, tell their responses, get the estimate.

A *campaign method* turns evaluations of a scalar response ``Y(z)`` of a standard-normal
noise vector ``z`` (dimension ``d``) into ``P(Y > threshold)``.  It is independent of
the MPM: a realization of a scene is a pure function of its noise vector, so the same
methods drive analytic limit states (the tests) and slope campaigns.  Every method
follows one ask/tell protocol, :class:`CampaignMethod`: ``next_batch()`` returns the
samples to evaluate next (each with its position and its noise or the seed the noise
is drawn from), ``tell(responses)`` hands back their responses in order, and
``result()`` gives the estimate when ``next_batch()`` returns ``None``.  A method is
deterministic given the responses, so a driver that stores each response (a record per
sample) resumes a killed campaign by replaying the stored responses, and 1 or N workers
give identical results.

The methods are listed in :data:`fem_rmpm.campaign.methods.METHODS`; :func:`run_method`
evaluates a method with a Python function (analytic limit states), the campaign runner
(:mod:`fem_rmpm.campaign.runner`) evaluates it with realizations of a scene on Dask.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Callable, Iterator, Protocol, Sequence

import numpy as np

from fem_rmpm.runtime.errors import InputError

__all__ = ["SubsetError", "SubsetWarning", "Sample", "CampaignMethod", "MethodResult",
           "LevelResult", "BatchMethod", "check_common", "run_method", "standard_noise"]


class SubsetError(InputError):
    """Bad input of a campaign method (p0, N, threshold, responses): one line that
    names the option, the value and what is allowed."""


class SubsetWarning(UserWarning):
    """The campaign ran, but its estimate needs a caveat (e.g. the threshold is not rare)."""


def standard_noise(dim: int) -> Callable[[int], np.ndarray]:
    """``seed -> default_rng(seed).standard_normal(dim)``: the noise of a seeded sample."""
    return lambda seed: np.random.default_rng(seed).standard_normal(dim)


@dataclass(frozen=True, eq=False)
class Sample:
    """One evaluation a method asks for.  ``level`` (0 for crude samples), ``chain`` (the
    realization index at level 0), ``step`` (0 at level 0; ``1 ..`` along a chain);
    ``seed``: the noise is ``noise_from_seed(seed)`` (level 0) or else ``noise``
    (the candidate, a float64 vector); ``start``: key of the chain state the candidate
    was proposed from; ``level_threshold``: the candidate is accepted if its response
    is at least this (chains only); ``case``: the campaign case it belongs to (set by
    :class:`fem_rmpm.campaign.methods.PerCase`, None otherwise)."""
    level: int
    chain: int
    step: int
    seed: int | None = None
    noise: np.ndarray | None = None
    start: str | None = None
    level_threshold: float | None = None
    case: str | None = None

    @property
    def key(self) -> str:
        return f"L{self.level:02d}_C{self.chain:05d}_S{self.step:03d}"


@dataclass
class MethodResult:
    """``probability`` = P(Y > threshold), its coefficient of variation ``cov``, the
    ``total_runs`` it took and the crude Monte Carlo runs that would give the same COV."""
    method: str
    threshold: float
    probability: float
    cov: float
    total_runs: int
    failed_runs: int = 0
    notes: list[str] = field(default_factory=list)
    levels: list["LevelResult"] = field(default_factory=list)

    @property
    def crude_equivalent_runs(self) -> float | None:
        p, d = self.probability, self.cov
        if not p or not d or not math.isfinite(d):
            return None
        return (1.0 - p) / (p * d * d)

    @property
    def thresholds(self) -> list[float]:
        return [lv.threshold for lv in self.levels]

    def as_dict(self) -> dict[str, Any]:
        return {"method": self.method, "threshold": self.threshold,
                "probability": self.probability, "cov": self.cov,
                "total_runs": self.total_runs, "failed_runs": self.failed_runs,
                "crude_equivalent_runs": self.crude_equivalent_runs, "notes": list(self.notes),
                "levels": [lv.as_dict() for lv in self.levels]}


@dataclass
class LevelResult:
    """One level: its samples' ``responses`` (state order: chain-major), the threshold
    ``threshold`` = b_{j+1} the level defines (the final threshold at the last level),
    ``conditional_probability`` P(Y > threshold | level), ``cov`` delta_j,
    ``gamma`` (chain correlation factor), ``acceptance`` (mean, chains only) and
    ``runs`` (new evaluations)."""
    level: int
    threshold: float
    conditional_probability: float
    cov: float
    gamma: float
    responses: np.ndarray
    chain: np.ndarray
    step: np.ndarray
    runs: int
    seeds: int
    acceptance: float | None = None
    lambdas: list[float] = field(default_factory=list)

    def as_dict(self) -> dict[str, Any]:
        return {"level": self.level, "threshold": self.threshold,
                "conditional_probability": self.conditional_probability,
                "cov": self.cov, "gamma": self.gamma, "runs": self.runs,
                "seeds": self.seeds, "acceptance": self.acceptance,
                "lambdas": list(self.lambdas), "responses": self.responses.tolist()}


class CampaignMethod(Protocol):
    """Ask/tell protocol of a campaign method (module docstring)."""
    name: str

    def next_batch(self) -> list[Sample] | None:
        """The samples to evaluate next (independent of each other), or None when done."""

    def tell(self, responses: Sequence[float]) -> None:
        """The responses of the last batch, in its order (NaN: the evaluation failed)."""

    def result(self) -> MethodResult:
        """The estimate (after ``next_batch()`` returned None)."""


class BatchMethod:
    """next_batch/tell on top of a generator (``_process``) that yields batches and receives
    their responses; the base class of the methods of :data:`fem_rmpm.campaign.methods.METHODS`."""
    name = "?"

    def _process(self) -> Iterator[list[Sample]]:  # pragma: no cover - abstract
        raise NotImplementedError

    def _start(self) -> None:
        self._gen = self._process()
        self._batch: list[Sample] | None = None
        self._result: MethodResult | None = None
        self.failed_runs = 0

    def next_batch(self) -> list[Sample] | None:
        if self._batch is not None:
            return self._batch
        if self._result is not None:
            return None
        try:
            self._batch = next(self._gen)
        except StopIteration as stop:
            self._result = stop.value
            return None
        return self._batch

    def tell(self, responses: Sequence[float]) -> None:
        if self._batch is None:
            raise RuntimeError("tell() without a pending batch")
        y = np.asarray(responses, dtype=float).reshape(-1)
        if len(y) != len(self._batch):
            raise SubsetError(f"{len(y)} responses for a batch of {len(self._batch)} samples")
        bad = ~np.isfinite(y)
        if bad.any():
            if self.on_failure == "raise":
                k = int(np.argmax(bad))
                raise SubsetError(f"response of sample {self._batch[k].key} is {y[k]}: "
                                  "responses must be finite numbers (or on_failure='reject')")
            self.failed_runs += int(bad.sum())
            y = np.where(bad, -np.inf, y)     # a failed run exceeds no threshold
        self._batch = None
        try:
            self._batch = self._gen.send(y)
        except StopIteration as stop:
            self._result = stop.value

    def result(self) -> MethodResult:
        if self._result is None:
            raise RuntimeError("the method has not finished: evaluate its batches first")
        return self._result


def check_common(threshold: float, n: int, on_failure: str) -> None:
    if not isinstance(threshold, (int, float)) or not math.isfinite(threshold):
        raise SubsetError(f"threshold {threshold!r}: expected a finite number")
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
        raise SubsetError(f"-n {n!r}: the samples per level must be a positive integer")
    if on_failure not in ("raise", "reject"):
        raise SubsetError(f"on_failure {on_failure!r}: allowed 'raise', 'reject'")


def run_method(method: CampaignMethod, response: Callable[[np.ndarray], Any],
               vectorised: bool = True) -> MethodResult:
    """Evaluate ``method`` with ``response``: a function of an (k, d) array of noise
    vectors returning k responses (``vectorised``), or of one vector returning a number."""
    while (batch := method.next_batch()) is not None:
        z = np.stack([s.noise if s.noise is not None else method.noise_from_seed(s.seed)
                      for s in batch])
        y = response(z) if vectorised else [response(row) for row in z]
        method.tell(np.asarray(y, dtype=float))
    return method.result()
