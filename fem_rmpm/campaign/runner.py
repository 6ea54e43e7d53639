"""The one campaign runner: any campaign method (:data:`fem_rmpm.campaign.methods.METHODS`)
evaluated with realizations of a scene on Dask.

:func:`run_method_campaign` asks the method for a batch, reuses the samples that already
have a usable record, computes the rest on the backend's workers (records written as they
arrive), tells the method the responses and asks again, until the method is done or a
sample is lost (its worker died: no record, the next run computes it).  Around that loop:
the backend is checked before anything is written (``preflight``), the campaign directory
is locked (:class:`fem_rmpm.campaign.store.Lock`), checked again under the lock, its
identity (``campaign.json``) written once and temporaries of a killed run removed; the
cluster starts at the first batch that needs it and the workers' view of the directory
is checked.  What a sample's task is, which record serves it and what its response is
belong to the *campaign kind*, an :class:`Evaluation`: realizations of cases
(:mod:`fem_rmpm.campaign.case_campaign`, crude Monte Carlo) or responses of one scene
(:mod:`fem_rmpm.campaign.subset_runner`, subset simulation).
"""
from __future__ import annotations

import sys
import time
import uuid
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Protocol, TypeVar

from distributed import as_completed
from tqdm import tqdm

from fem_rmpm.campaign.cluster import warm_workers
from fem_rmpm.campaign.methods import CampaignMethod, Sample
from fem_rmpm.campaign.store import Lock
from fem_rmpm.io.output import write_json

__all__ = ["Evaluation", "Execution", "RunTally", "run_method_campaign"]

T = TypeVar("T")


class Evaluation(Protocol):
    """A campaign kind: how the runner evaluates samples (module docstring)."""
    task_function: Callable[[dict], dict]   # the Dask task: task dict -> record

    def check_directory(self, out: Path) -> None:
        """Raise CampaignError unless ``out`` is free or holds this campaign."""

    def clean_temporaries(self, out: Path) -> None:
        """Remove the temporary files a killed run left."""

    def plan(self, batch: list[Sample]) -> list[dict]:
        """The tasks of the samples without a usable record (the others are reused)."""

    def task_key(self, task: dict) -> str:
        """A short, unique name of a task (the Dask key's tail)."""

    def task_name(self, task: dict) -> str:
        """The task as named in the line of a lost sample."""

    def arrived(self, rec: dict) -> None:
        """Write a record that arrived from a worker."""

    def responses(self, batch: list[Sample]) -> list[float]:
        """The responses of a batch whose samples all have a record."""


@dataclass
class Execution:
    """Where a campaign runs: ``backend`` (opened here, closed by the runner) or an
    existing ``client`` (left open); ``preflight``: tasks to check the backend for before
    anything is written (None: no check); ``start_size``: the tasks to size a started
    cluster for, from the first batch's; ``notice``: the line printed when the first tasks
    start (tasks, workers' description), or None; ``progress``: the bar's label or None."""
    backend: object | None
    client: object | None = None
    preflight: int | None = None
    start_size: Callable[[int], int] = lambda n: n
    notice: Callable[[int, str], str | None] = lambda n, desc: None
    progress: str | None = None
    description: str = "no workers needed"
    warm_up: Callable | None = warm_workers

    def __post_init__(self):
        if self.client is not None:
            self.description = f"the given Dask client ({len(self.client.nthreads())} workers)"


@dataclass
class RunTally:
    """What :func:`run_method_campaign` did: samples computed and reused, the lost ones
    (one line each), the compute wall time (s), the workers and whether the method
    finished (False when samples were lost)."""
    computed: int = 0
    reused: int = 0
    lost: list[str] = field(default_factory=list)
    compute_time: float = 0.0
    workers: str = ""
    finished: bool = False


def run_method_campaign(method: CampaignMethod, kind: Evaluation, out: Path, doc: dict,
                        run: Execution, finish: Callable[[RunTally], T]) -> T:
    """Evaluate ``method`` in the campaign directory ``out`` (identity ``doc``) on
    ``run``'s workers (module docstring); returns ``finish(tally)``, called while the
    directory is still locked (it writes the tables and figures).  Raises CampaignError
    (a refused or unreachable cluster, another campaign in ``out``, a directory the
    workers do not share) before any sample runs."""
    tally = RunTally(workers=run.description)
    own = run.client is None
    try:
        if own and run.preflight is not None:   # refused, unreachable -> error, nothing written
            run.backend.preflight(run.preflight)
        with Lock(out):
            kind.check_directory(out)           # again, now that no one else can write here
            if not (out / "campaign.json").exists():
                write_json(out / "campaign.json", doc)
            kind.clean_temporaries(out)
            _evaluate(method, kind, out, run, tally, own)
            return finish(tally)
    finally:
        if own and run.backend is not None:
            run.backend.close()


def _evaluate(method: CampaignMethod, kind: Evaluation, out: Path, run: Execution,
              tally: RunTally, own: bool) -> None:
    """The ask/tell loop: reuse, compute, tell, until done or a sample is lost."""
    bar = _Progress(run.progress)
    client = run.client
    try:
        while (batch := method.next_batch()) is not None:
            tasks = kind.plan(batch)
            tally.reused += len(batch) - len(tasks)
            bar.add(len(batch), len(batch) - len(tasks))
            if tasks:
                if client is None:
                    client = run.backend.start(run.start_size(len(tasks)), out)
                    tally.workers = run.backend.description
                    if (line := run.notice(len(tasks), tally.workers)) is not None:
                        print(line, file=sys.stderr)
                    run.backend.check_directory(client, out)   # the workers share it
                    if run.warm_up is not None and (line := run.warm_up(client, tasks,
                                                                        say=_say)):
                        _say(line)
                t0 = time.perf_counter()
                lost = _submit(client, kind, tasks, bar)
                tally.compute_time += time.perf_counter() - t0
                tally.computed += len(tasks) - len(lost)
                if lost:
                    tally.lost = lost
                    return
            method.tell(kind.responses(batch))
        tally.finished = True
    finally:
        bar.close()


def _say(line: str) -> None:
    print(f"fem-rmpm mc: {line}", file=sys.stderr, flush=True)


def _submit(client, kind: Evaluation, tasks: list[dict], bar: "_Progress") -> list[str]:
    """Submit the tasks, hand each record to the kind as it arrives; return the lost ones."""
    token = uuid.uuid4().hex[:8]
    keys = [f"rmpm-{token}-{kind.task_key(t)}" for t in tasks]
    futures = client.map(kind.task_function, tasks, key=keys, pure=False, retries=0)
    by_key = dict(zip(keys, tasks))
    lost: list[str] = []
    ours = set(keys)
    ac = as_completed(futures, with_results=False, loop=client.loop)
    last_poll = 0.0
    while not ac.is_empty():
        batch = ac.next_batch(block=False)
        if not batch:
            if bar.bar is not None and time.monotonic() - last_poll > 1.0:
                last_poll = time.monotonic()
                bar.poll(client, ours)
            time.sleep(0.05)
            continue
        for fut in batch:
            task = by_key[fut.key]
            try:
                rec = fut.result()
            except Exception as exc:  # noqa: BLE001 - infrastructure, not the realization
                msg = " ".join(str(exc).split())[:300]
                lost.append(f"{kind.task_name(task)}: {type(exc).__name__}: {msg}")
                bar.done("lost")
                fut.release()
                continue
            kind.arrived(rec)
            bar.done(rec["status"])
            fut.release()
    return lost


class _Progress:
    """The progress bar of a campaign (tqdm on stderr): done, ok, failed, running, lost;
    its total grows with the batches."""

    def __init__(self, desc: str | None):
        self.bar = None
        self.ok = self.failed = self.lost = self.running = 0
        if desc is not None:
            self.bar = tqdm(total=0, desc=desc, unit="real", dynamic_ncols=True,
                            postfix=self._text(),
                            bar_format="{l_bar}{bar}| {n}/{total} [{elapsed}<{remaining}, "
                                       "{rate_fmt}{postfix}]")

    def _text(self) -> str:
        return (f"ok {self.ok}, failed {self.failed}, running {self.running}"
                + (f", lost {self.lost}" if self.lost else ""))

    def add(self, total: int, done: int) -> None:
        """A batch of ``total`` samples, ``done`` of them served by records."""
        if self.bar is not None:
            self.bar.total += total
            self.bar.update(done)

    def done(self, status: str) -> None:
        if status == "ok":
            self.ok += 1
        elif status == "failed":
            self.failed += 1
        else:
            self.lost += 1
        self.running = max(0, self.running - 1)     # until the next poll of the scheduler
        if self.bar is not None:
            self.bar.set_postfix_str(self._text(), refresh=False)
            self.bar.update(1)

    def poll(self, client, ours: set) -> None:
        """Running = assigned to a worker, at most its thread count."""
        try:
            proc, threads = client.processing(), client.nthreads()
            n = sum(min(sum(1 for k in ks if k in ours), threads.get(w, 1))
                    for w, ks in proc.items())
        except Exception:  # noqa: BLE001 - the bar is cosmetic
            return
        if n != self.running:
            self.running = n
            self.bar.set_postfix_str(self._text(), refresh=True)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()
