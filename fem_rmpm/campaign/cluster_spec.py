"""Where a campaign runs, as settings: the cluster kinds of ``--cluster`` (a local or
running Dask cluster, or one :class:`BatchSystem` row of :data:`BATCH_SYSTEMS` per batch
system), the :class:`ClusterSpec` of the command-line options and its checks.  Nothing
here starts or imports Dask; :mod:`fem_rmpm.campaign.backends` opens a backend from a
spec."""
from __future__ import annotations

import re
from dataclasses import dataclass, field

from dask.utils import parse_bytes

from fem_rmpm.campaign.cases import CampaignError

__all__ = ["BATCH_SYSTEMS", "BatchSystem", "CLUSTER_KINDS", "ClusterError", "ClusterSpec",
           "check_scheduler_address", "parse_adapt", "validate"]


@dataclass(frozen=True)
class BatchSystem:
    """A batch system as dask-jobqueue drives it: its ``--cluster`` name, its name in
    messages, dask-jobqueue's cluster class, the job keyword that ``--account`` sets
    (``account`` or ``project``), the command that checks a job script without submitting
    it (None: none is used) and whether ``sinfo`` tells the nodes' memory."""
    kind: str
    title: str
    jobqueue_class: str
    account_keyword: str
    test_submit: tuple[str, ...] | None = None
    node_memory_from_sinfo: bool = False


#: The batch systems of ``--cluster``, one row per kind.
BATCH_SYSTEMS: dict[str, BatchSystem] = {b.kind: b for b in (
    BatchSystem("slurm", "SLURM", "SLURMCluster", "account", ("sbatch", "--test-only"),
                node_memory_from_sinfo=True),
    BatchSystem("pbs", "PBS", "PBSCluster", "account"),
    BatchSystem("sge", "SGE", "SGECluster", "project"),
    BatchSystem("lsf", "LSF", "LSFCluster", "project"),
)}
#: ``--cluster`` values: a local (or already running) Dask cluster, or a batch system.
CLUSTER_KINDS = ("local", *BATCH_SYSTEMS)
_MEMORY = re.compile(r"^\s*([0-9]*\.?[0-9]+)\s*([KMGT]i?B?|B)?\s*$", re.IGNORECASE)


class ClusterError(CampaignError):
    """Bad cluster input or a refused job submission (command line: exit 2, one line)."""


@dataclass(frozen=True)
class ClusterSpec:
    """Where to run (see the module docstring).  ``None`` = not given: the Dask
    configuration, then fem_rmpm's default, decides."""
    kind: str = "local"
    scheduler: str | None = None          # address of a running Dask scheduler (local only)
    workers: int | None = None            # local processes, or workers kept on the batch system
    adapt: tuple[int, int] | None = None  # (minimum, maximum) workers, batch systems only
    queue: str | None = None
    account: str | None = None
    cores: int | None = None              # per job
    memory: str | None = None             # per job, e.g. "8GB"
    walltime: str | None = None           # e.g. "04:00:00"
    interface: str | None = None
    job_directives: tuple[str, ...] = ()
    worker_memory_estimate: float | None = field(default=None, compare=False)  # B
    threads_per_worker: int = field(default=1, compare=False)  # numba threads, local workers

    @property
    def batch(self) -> bool:
        return self.kind in BATCH_SYSTEMS


def parse_adapt(text: str | None) -> tuple[int, int] | None:
    """``"MIN:MAX"`` workers (``"0:20"``) -> (0, 20); None -> None."""
    if text is None:
        return None
    m = re.fullmatch(r"\s*(\d+)\s*:\s*(\d+)\s*", str(text))
    if not m or int(m.group(2)) < max(1, int(m.group(1))):
        raise ClusterError(f"--adapt {text!r}: expected MIN:MAX workers with 0 <= MIN <= MAX "
                           "and MAX >= 1, e.g. --adapt 0:20")
    return int(m.group(1)), int(m.group(2))


def _positive(name: str, value) -> None:
    if value is not None and (isinstance(value, bool) or not isinstance(value, int) or value <= 0):
        raise ClusterError(f"{name} {value}: expected a positive integer")


def _memory_bytes(text: str, option: str = "--memory") -> float:
    """'8GB', '954M', '2 GiB' -> bytes (dask's units: kB = 1000, KiB = 1024)."""
    m = _MEMORY.match(str(text))
    if not m:
        raise ClusterError(f"{option} {text!r}: expected a memory size like 4GB, 1500MB or 2GiB")
    unit = (m.group(2) or "B").upper().replace("IB", "iB")
    unit = unit if unit.endswith("B") else unit + "B"
    return float(parse_bytes(f"{m.group(1)} {unit}"))


#: A Dask scheduler address: ``[scheme://]host:port`` (host a name, an IPv4 address or
#: a bracketed IPv6 address), or an in-process ``inproc://`` address.
_ADDRESS = re.compile(r"(?:[a-z][a-z0-9+.-]*://)?(?:\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9_.-]+)"
                      r":(\d{1,5})/?")


def check_scheduler_address(address: str) -> None:
    """Raise :class:`ClusterError` when ``address`` is not the syntax of a scheduler
    address (checked before connecting: no connect timeout for a typing mistake)."""
    if address.startswith("inproc://"):
        return
    m = _ADDRESS.fullmatch(address.strip())
    if m is None or not 0 < int(m.group(1)) < 65536:
        raise ClusterError(f"--scheduler {address!r}: not a scheduler address; allowed: "
                           "[scheme://]host:port, e.g. tcp://node12:8786")


def validate(spec: ClusterSpec) -> ClusterSpec:
    """Check a spec (raises :class:`ClusterError` naming the option); returns it."""
    if spec.kind not in CLUSTER_KINDS:
        raise ClusterError(f"--cluster {spec.kind!r}: unknown cluster kind; allowed: "
                           + ", ".join(CLUSTER_KINDS))
    _positive("--workers", spec.workers)
    _positive("--cores", spec.cores)
    if spec.memory is not None:
        _memory_bytes(spec.memory)
    if spec.workers is not None and spec.adapt is not None:
        raise ClusterError("--workers keeps a fixed number of workers, --adapt lets Dask "
                           "choose between MIN and MAX: give one of the two")
    if spec.scheduler and spec.kind != "local":
        raise ClusterError(f"--scheduler joins a running Dask cluster; --cluster {spec.kind} "
                           "starts one on the batch system: give one of the two")
    if spec.scheduler:
        check_scheduler_address(spec.scheduler)
    if spec.scheduler and spec.workers is not None:
        raise ClusterError("--workers starts a local cluster; with --scheduler the "
                           "cluster's own workers are used: give one of the two")
    if not spec.batch:
        given = [f"--{k.replace('_', '-')}" for k in ("queue", "account", "cores", "memory",
                                                      "walltime", "interface", "adapt")
                 if getattr(spec, k) is not None] + (["--job-directive"]
                                                     if spec.job_directives else [])
        if given:
            raise ClusterError(f"{', '.join(given)}: options of batch-system workers; "
                               "give --cluster slurm|pbs|sge|lsf as well")
    return spec
