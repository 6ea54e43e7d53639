"""One method per case of a campaign, asked and told together (index-major order)."""
from __future__ import annotations

from dataclasses import replace
from typing import Sequence

import numpy as np

from fem_rmpm.campaign.methods.protocol import CampaignMethod, MethodResult, Sample

__all__ = ["PerCase"]


class PerCase:
    """The ask/tell protocol over ``methods`` (case name -> method, in case order): a batch
    holds the pending samples of every case's method, each tagged with its ``case``, in
    index-major order (sample position, then case); ``tell`` hands each method its own
    responses; ``result`` is ``{case: MethodResult}``."""
    name = "per case"

    def __init__(self, methods: dict[str, CampaignMethod]):
        self.methods = dict(methods)
        self._order = {c: k for k, c in enumerate(self.methods)}
        self._batch: list[Sample] | None = None

    def next_batch(self) -> list[Sample] | None:
        if self._batch is not None:
            return self._batch
        batch = [replace(s, case=c) for c, m in self.methods.items()
                 if (b := m.next_batch()) is not None for s in b]
        if not batch:
            return None
        batch.sort(key=lambda s: (s.level, s.step, s.chain, self._order[s.case]))
        self._batch = batch
        return batch

    def tell(self, responses: Sequence[float]) -> None:
        if self._batch is None:
            raise RuntimeError("tell() without a pending batch")
        y = np.asarray(responses, dtype=float).reshape(-1)
        for c, m in self.methods.items():
            own = m.next_batch()
            if own is None:
                continue
            pos = {(s.level, s.chain, s.step): k for k, s in enumerate(self._batch)
                   if s.case == c}
            m.tell([y[pos[(s.level, s.chain, s.step)]] for s in own])
        self._batch = None

    def result(self) -> dict[str, MethodResult]:
        return {c: m.result() for c, m in self.methods.items()}
