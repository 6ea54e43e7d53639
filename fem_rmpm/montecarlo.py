"""Monte Carlo RMPM on Dask: many realizations of a scene, resumable and lossless.

``fem-rmpm mc SCENE -n N --out DIR [--workers K | --scheduler ADDRESS]`` (or
:func:`run_campaign` from Python) runs realizations ``0 .. N-1`` of one or more
*cases* of a scene on a Dask cluster and turns them into probabilities.

What a campaign is
------------------
* **Cases.** A campaign runs one scene, or several variants of it side by side
  (:func:`parse_case`): ``"homogeneous"`` (the scene without its random field),
  ``"xi=12"`` (``random_field.anisotropy = 12``) or any ``"<section.key>=<value>"``
  accepted by :func:`fem_rmpm.scene.with_value`.  The embedded default scene (the
  reference slope, ``fem-rmpm mc`` without SCENE) runs the four literature cases
  :data:`LITERATURE_CASES` — homogeneous, xi = 1, 12, 48 (Wang, Vardon & Hicks
  2017).  A case without a ``[random_field]`` is deterministic (a realization is a
  pure function of the scene and the seed, and the seed only drives the field),
  so it runs exactly one realization, whatever N is.
* **Seeds.** Realization ``i`` of every case uses the seed
  :func:`realization_seed` ``(campaign_seed, i)`` = the first 63 bits of
  ``numpy.random.SeedSequence([campaign_seed, i]).generate_state(1, uint64)``,
  with ``campaign_seed`` = ``[montecarlo] seed``.  It depends on nothing else
  (not on N, the worker, the order, the case): the same realization index gets
  the same seed in every case (common random numbers, so the cases differ only
  by what the case changes), and growing N only appends realizations.
* **Records.** When a realization finishes, the client writes its record
  atomically (temporary file + rename) as ``records/realization_00012.json``
  (``records/<case>/...`` with several cases): case, index, seed, status ``ok`` |
  ``failed``, the error message of a failed realization, scheme, steps,
  simulated, wall and CPU time, the scalar measures (:mod:`fem_rmpm.measures`) and the
  worker; its final surface profile goes to ``profiles/`` the same way.
  ``results.csv`` is rebuilt from the records (one row per realization, sorted by
  case and index, floats written with ``repr`` so they round-trip bitwise; wall
  times are in the records and ``summary.json``, not in the table, so the table
  of a campaign is the same on 1 or 64 workers and after an interruption).
* **Identity and resuming.** ``campaign.json`` holds the campaign seed and each
  case's scene (as :func:`fem_rmpm.scene.scene_to_dict`, without the keys that do
  not change a realization: ``montecarlo.realizations``, ``montecarlo.keep_vtk``,
  ``scene.description``, ``[output]``).  Re-running the same command computes only the realizations
  without a record; a larger N appends; ``--force`` recomputes (each record is
  replaced only when its new one is complete).  Another scene in the same
  directory is an error that names the first differing key; nothing is
  overwritten.  A key that fem_rmpm gained after the campaign started is no
  difference while it holds its default.  The identity is the scene, not the code:
  a campaign resumed after upgrading fem_rmpm mixes versions (each record names
  its ``fem_rmpm`` version); use ``--force`` or a new directory to recompute.  A lock file stops two commands from working on one directory at
  the same time (released by the kernel even if the client is killed).
* **Failures.** A realization that fails (:class:`fem_rmpm.run.SimulationError`:
  unstable, a random-field value the material cannot take, ...; or any other
  exception in the realization) is recorded with ``status = failed`` and its
  message and the campaign goes on.  Statistics use the ``ok`` realizations; the
  summary counts the failed ones.  A realization whose *worker* died is retried
  by Dask on another worker (up to ``distributed.scheduler.allowed-failures``
  times); if it is still lost, it has no record and the next run computes it.
* **VTK** is written only for kept realizations (``--keep-vtk K``: the first K
  of each case; ``--keep-vtk 0,5,9``: those indices; default ``[montecarlo]
  keep_vtk``), to ``vtk/<case>/realization_00003/`` (``particles.pvd``,
  ``grid.vtu``, ``summary.json``, ``plastic_shear_strain.png``), by the worker:
  with a remote cluster, the campaign directory must be on a file system the
  workers share (as usual on HPC clusters).

Statistics (``summary.json`` and the printed summary), per case over the ``ok``
realizations: P(failure) = fraction with ``failed`` (a point moved more than
``[montecarlo] failure_displacement``), its standard error ``sqrt(p (1 - p) / N)``
(binomial; e.g. Fenton & Griffiths 2008, Risk Assessment in Geotechnical
Engineering, sec. 6.2) and the Wilson 95 % score interval (Wilson 1927; Brown, Cai &
DasGupta 2001), which stays meaningful at p = 0 or 1; mean, standard deviation,
standard error of the mean and the 5/50/95 % quantiles of run-out, retrogression
and sliding area; and their running values in index order (convergence with N).

Figures (:mod:`fem_rmpm.campaign_plots`): ``exceedance.png`` (P[run-out > x],
P[retrogression > r], P[sliding area > a]), ``histograms.png``,
``convergence.png`` (P(failure) and mean run-out against N with 95 % bands) and,
with kept VTK, ``cases.png`` (final plastic shear strain of one realization per
case, side by side).

Dask
----
Default: a ``distributed.LocalCluster`` of K worker processes (K = ``--workers``,
default the usable CPUs, at most the number of realizations to run), one thread
each.  Before the cluster starts, the worker environment is set through
``distributed.nanny.pre-spawn-environ`` (the only place where it takes effect;
variables already set in the user's environment win): ``OMP_NUM_THREADS``,
``MKL_NUM_THREADS``, ``OPENBLAS_NUM_THREADS``, ``NUMBA_NUM_THREADS`` = 1 (one
thread per process; parallelism comes from the processes) and
``MALLOC_TRIM_THRESHOLD_`` = 1 GiB with ``MALLOC_MMAP_THRESHOLD_`` = 32 MiB.
Dask sets ``MALLOC_TRIM_THRESHOLD_=65536``; setting *any* trim threshold also
freezes glibc's mmap threshold at 128 KiB, so every array above 128 KiB is a
fresh ``mmap`` that page-faults on first touch and is unmapped when freed.
Measured here (two workers, reference slope, 1 s of dynamics, numpy kernel):
65536 -> 10 s system time and 4.5 million page faults per task, 3-4x the wall
time; trim raised alone (1 GiB) -> still 7 s and 3.4 million; trim and mmap
thresholds raised (or neither set) -> 0.06 s and ~300.  With the default numba
kernel (few temporaries) the difference is within noise (24 500 vs 370 page
faults, user time equal).  Workers of an existing cluster keep the environment
they were started with, so each realization task also raises both thresholds
with ``mallopt`` (glibc; a no-op elsewhere), which measured the same as the
environment variables.

An existing cluster: ``--scheduler tcp://host:8786`` (or ``run_campaign(...,
scheduler=address)``) connects a ``distributed.Client`` to it (timeout
``distributed.comm.timeouts.connect``); its workers need fem_rmpm installed and,
for kept VTK, the campaign directory.  Start them with one thread each::

    dask scheduler --host 10.0.0.1                      # prints tcp://10.0.0.1:8786
    OMP_NUM_THREADS=1 dask worker tcp://10.0.0.1:8786 --nworkers 32 --nthreads 1

On SLURM/PBS, dask-jobqueue starts the workers as batch jobs; the client runs
on the login node (or in a job) and the campaign directory is on the shared
file system::

    from dask_jobqueue import SLURMCluster        # PBSCluster for PBS/Torque
    cluster = SLURMCluster(cores=32, processes=32, memory="64GB", walltime="04:00:00",
                           job_script_prologue=["export OMP_NUM_THREADS=1"])
    cluster.scale(jobs=4)                          # 4 nodes x 32 single-thread workers
    print(cluster.scheduler_address)               # pass to --scheduler, or:
    run_campaign(scene, "runs/mc", 1000, scheduler=cluster.scheduler_address)

Scripts that start a local cluster need the usual guard, because worker
processes are spawned and re-import the main module::

    if __name__ == "__main__":
        run_campaign(load_scene("meshes/slope_reference.toml"), "runs/mc", 200)

The realization task :func:`run_realization` is a top-level function of plain,
picklable arguments; records are JSON: nothing a user gives is ever unpickled.
"""
from __future__ import annotations

import csv
import dataclasses
import fcntl
import io
import json
import math
import os
import re
import socket
import sys
import time
import tomllib
import uuid
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable, Sequence

import numpy as np

from .cli import InputError
from .output import write_json
from .scene import Scene, SceneError, scene_from_dict, scene_to_dict, with_value

__all__ = ["CampaignError", "Case", "LITERATURE_CASES", "parse_case", "literature_cases",
           "realization_seed", "run_realization", "run_campaign", "run_campaign_cli",
           "CampaignResult", "case_statistics", "read_results", "parse_keep_vtk",
           "worker_environment", "start_local_cluster", "summary_text", "RESULT_COLUMNS"]

FORMAT = "fem_rmpm campaign 1"
#: The literature cases of the reference slope (Wang, Vardon & Hicks 2017).
LITERATURE_CASES = ("homogeneous", "xi=1", "xi=12", "xi=48")
#: The first measure columns of ``results.csv``; every other scalar measure of
#: :func:`fem_rmpm.measures.compute_measures` (slip-surface height, intact blocks, ...)
#: follows in alphabetical order.  Profiles (lists) go to ``profiles/``.
MEASURE_KEYS = ("failed", "sliding_area", "runout_distance", "retrogression_distance",
                "max_displacement", "time_to_rest")
#: Columns of ``results.csv`` (extra measure columns are inserted before ``stop_reason``).
RESULT_COLUMNS = ("case", "index", "seed", "status", *MEASURE_KEYS, "stop_reason", "steps",
                  "simulated_time", "particles", "frozen_points", "scheme", "error")
#: Measures that are settings, not results (left out of the statistics).
_NOT_STATISTICS = ("failed", "failure_displacement", "mechanism_time", "time_to_rest")
#: Keys that do not change a realization (left out of the campaign identity).
_NOT_IDENTITY = {"montecarlo": ("realizations", "keep_vtk", "cases"), "output": None,
                 "scene": ("description",)}
_MALLOC = {"MALLOC_TRIM_THRESHOLD_": 2**30, "MALLOC_MMAP_THRESHOLD_": 2**25}
_THREADS = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS", "NUMBA_NUM_THREADS")


class CampaignError(InputError):
    """Bad campaign input: N, workers, scheduler address, output directory (CLI exit 2)."""


# --------------------------------------------------------------------------- cases and seeds

@dataclass(frozen=True)
class Case:
    """One variant of the campaign's scene: ``name`` (used in file names), ``spec``
    (how it was given) and the scene it runs."""
    name: str
    spec: str
    scene: Scene

    @property
    def deterministic(self) -> bool:
        return self.scene.random_field is None

    @property
    def label(self) -> str:
        if self.spec.startswith("xi="):
            return "xi = " + self.spec[3:]
        return self.spec


def _plain_scene_dict(scene: Scene) -> dict:
    """scene_to_dict with the 'inf' strings turned back into floats (rebuildable)."""
    data = scene_to_dict(scene)
    for sec in data.values():
        for d in (sec if isinstance(sec, list) else [sec]):
            for k, v in list(d.items()):
                if v in ("inf", "-inf"):
                    d[k] = float(v)
    return data


def without_random_field(scene: Scene) -> Scene:
    """The scene with its ``[random_field]`` removed (homogeneous soil)."""
    data = _plain_scene_dict(scene)
    data.pop("random_field", None)
    return scene_from_dict(data, scene.source)


def parse_case(spec: str, scene: Scene) -> Case:
    """A case from its text: ``"homogeneous"`` (no random field), ``"xi=12"``
    (``random_field.anisotropy``; a scene without a field gets the defaults of
    :class:`fem_rmpm.scene.RandomFieldSpec`: lognormal, COV 0.25, theta_v 0.5 m) or
    ``"<section.key>=<TOML value>"``, several joined by ``;``
    (``"solver.cfl=0.3;soil.softening_strain=0.8"``)."""
    spec = spec.strip()
    if spec in ("", "scene", "base"):
        return Case("scene", "scene", scene)
    if spec == "homogeneous":
        return Case("homogeneous", spec, without_random_field(scene))
    out = scene
    for part in spec.split(";"):
        key, eq, text = part.partition("=")
        key, text = key.strip(), text.strip()
        if not eq or not key or not text:
            raise CampaignError(f"case {spec!r}: expected 'homogeneous', 'xi=<number>' or "
                                "'<section.key>=<value>'")
        if key == "xi":
            key = "random_field.anisotropy"
        try:
            value = tomllib.loads(f"v = {text}")["v"]
        except tomllib.TOMLDecodeError:
            value = text                      # a bare word: a string value
        out = with_value(out, key, value)
    name = re.sub(r"[^A-Za-z0-9.=+-]+", "_", spec.replace("xi=", "xi")).strip("_")
    return Case(name, spec, out)


def literature_cases(scene: Scene) -> list[Case]:
    """The four cases of the reference slope: homogeneous and xi = theta_h/theta_v = 1, 12, 48."""
    return [parse_case(s, scene) for s in LITERATURE_CASES]


def realization_seed(campaign_seed: int, index: int) -> int:
    """Seed of realization ``index``: the first 63 bits of
    ``SeedSequence([campaign_seed, index]).generate_state(1, numpy.uint64)``.

    SeedSequence hashes its entropy, so neighbouring indices (and campaign seeds)
    give statistically independent streams (numpy's recommended way to key
    streams); the result fits ``[montecarlo] seed`` and ``fem-rmpm run --seed``,
    so ``fem-rmpm run SCENE --seed S`` reproduces a realization alone."""
    if campaign_seed < 0 or index < 0:
        raise ValueError("campaign seed and index must be >= 0")
    state = np.random.SeedSequence([int(campaign_seed), int(index)]).generate_state(1, np.uint64)
    return int(state[0] >> np.uint64(1))


# --------------------------------------------------------------------------- the task

def _raise_malloc_thresholds() -> None:
    """glibc: raise the mmap and trim thresholds in this process (see module docstring)."""
    if not sys.platform.startswith("linux"):
        return
    try:
        import ctypes
        libc = ctypes.CDLL("libc.so.6")
        libc.mallopt(-3, _MALLOC["MALLOC_MMAP_THRESHOLD_"])   # M_MMAP_THRESHOLD
        libc.mallopt(-1, _MALLOC["MALLOC_TRIM_THRESHOLD_"])   # M_TRIM_THRESHOLD
    except (OSError, AttributeError):  # pragma: no cover - not glibc
        pass


def _version() -> str:
    try:
        from importlib.metadata import version
        return version("fem_rmpm")
    except Exception:  # noqa: BLE001 - informative only
        return "unknown"


def _plain(v: Any) -> Any:
    """numpy scalars -> Python scalars (repr of np.float64 is not a number in numpy 2)."""
    if isinstance(v, (bool, np.bool_)):
        return bool(v)
    if isinstance(v, (int, np.integer)):
        return int(v)
    if isinstance(v, (float, np.floating)):
        return float(v)
    return v


def _scalar_measures(m: dict) -> dict:
    """The scalar measures (numbers, booleans, None) of a realization, Python types."""
    return {k: _plain(v) for k, v in m.items()
            if v is None or isinstance(v, (bool, int, float, np.bool_, np.integer, np.floating))}


def run_realization(task: dict) -> dict:
    """The Dask task: run realization ``task["index"]`` of ``task["case"]`` and return
    its record (a JSON-ready dict).  Never raises for a failing realization: the
    error is in the record (``status = "failed"``).

    ``task``: ``case``, ``index``, ``seed``, ``scene`` (a :class:`Scene`), ``vtk_dir``
    (str or None: write VTK, ``summary.json`` and the plastic strain PNG there)."""
    from . import api
    _raise_malloc_thresholds()
    rec: dict[str, Any] = {
        "format": FORMAT, "case": task["case"], "index": int(task["index"]),
        "seed": int(task["seed"]), "scheme": task["scene"].solver.scheme, "status": "ok",
        "error": None, "vtk": task.get("vtk_rel"),
        "worker": {"host": socket.gethostname(), "pid": os.getpid()},
        "fem_rmpm": _version(),
    }
    t0, c0 = time.perf_counter(), time.process_time()
    try:
        vtk_dir = task.get("vtk_dir")
        res = api.run(task["scene"], out=vtk_dir, seed=rec["seed"], progress=False,
                      vtk=vtk_dir is not None, figures=vtk_dir is not None)
    except Exception as exc:       # noqa: BLE001 - every failure is data, recorded
        from .run import SimulationError
        msg = str(exc) if isinstance(exc, SimulationError) else f"{type(exc).__name__}: {exc}"
        rec.update(status="failed", error=" ".join(msg.split()) or type(exc).__name__,
                   measures=None, final_profile=None)
    else:
        s, m = res.summary, res.measures
        rec.update(steps=s["steps"], simulated_time=s["simulated_time"],
                   stop_reason=s["stop_reason"], particles=s["particles"],
                   frozen_points=s["frozen_points"]["count"],
                   measures=_scalar_measures(m),
                   final_profile=m.get("final_profile"))
    rec["wall_time"] = time.perf_counter() - t0
    rec["cpu_time"] = time.process_time() - c0     # of the worker process (s)
    return rec


# --------------------------------------------------------------------------- campaign directory

def _identity_dict(scene: Scene) -> dict:
    return _strip_identity(json.loads(json.dumps(scene_to_dict(scene))))


def _strip_identity(d: dict) -> dict:
    """Drop the keys that do not change a realization (also from stored campaign files)."""
    d = json.loads(json.dumps(d))
    for sec, keys in _NOT_IDENTITY.items():
        if keys is None:
            d.pop(sec, None)
        elif sec in d:
            for k in keys:
                d[sec].pop(k, None)
    return d


def _json_form(v: Any) -> Any:
    """A default value as scene_to_dict writes it (tuples -> lists, inf -> 'inf')."""
    if isinstance(v, (list, tuple)):
        return [_json_form(x) for x in v]
    if isinstance(v, float) and not math.isfinite(v):
        return str(v)
    return v


def _field_default(path: str) -> tuple[bool, Any]:
    """(True, default as written by scene_to_dict) of a scene key like ``solver.kernel``
    or ``soil[0].model``; (False, None) if the key is unknown or has no default."""
    from . import scene as S
    classes = {"scene": S.SceneInfo, "grid": S.GridSpec, "boundary": S.BoundarySpec,
               "soil": S.SoilSpec, "bedrock": S.BedrockSpec,
               "random_field": S.RandomFieldSpec, "solver": S.SolverSpec,
               "montecarlo": S.MonteCarloSpec, "output": S.OutputSpec}
    section, _, name = path.partition(".")
    cls = classes.get(section.split("[")[0])
    if cls is None or "." in name:
        return False, None
    for f in dataclasses.fields(cls):
        if f.name == name and f.default is not dataclasses.MISSING:
            return True, _json_form(f.default)
    return False, None


def _first_difference(a: Any, b: Any, path: str = "") -> str | None:
    """First difference of scene dicts ``a`` (this scene) and ``b`` (the campaign's).
    A key only in ``a`` that holds its default value is no difference: it is a key added
    to fem_rmpm after the campaign started, whose default keeps the old behaviour."""
    if isinstance(a, dict) and isinstance(b, dict):
        for k in sorted(set(a) | set(b)):
            if k not in a or k not in b:
                key = f"{path}.{k}".strip(".")
                if k in a:
                    has, default = _field_default(key)
                    if has and a[k] == default:
                        continue
                return key + (" (only in this scene)" if k in a
                              else " (only in the campaign's scene)")
            d = _first_difference(a[k], b[k], f"{path}.{k}")
            if d:
                return d
        return None
    if isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            return f"{path.strip('.')} ({len(a)} vs {len(b)} entries)"
        for i, (x, y) in enumerate(zip(a, b)):
            d = _first_difference(x, y, f"{path}[{i}]")
            if d:
                return d
        return None
    return None if a == b else f"{path.strip('.')} = {a!r} here, {b!r} in the campaign"


def _case_dir(root: Path, case: str, single: bool) -> Path:
    return root if single else root / case


def _record_name(index: int) -> str:
    return f"realization_{index:05d}.json"


@dataclass
class _Layout:
    out: Path
    cases: list[Case]

    @property
    def single(self) -> bool:
        return len(self.cases) == 1

    def record(self, case: str, index: int) -> Path:
        return _case_dir(self.out / "records", case, self.single) / _record_name(index)

    def profile(self, case: str, index: int) -> Path:
        return _case_dir(self.out / "profiles", case, self.single) / _record_name(index)

    def vtk(self, case: str, index: int) -> Path:
        return _case_dir(self.out / "vtk", case, self.single) / f"realization_{index:05d}"


def _campaign_doc(cases: list[Case], campaign_seed: int) -> dict:
    return {"format": FORMAT, "campaign_seed": int(campaign_seed),
            "seed_rule": "seed_i = SeedSequence([campaign_seed, i]).generate_state(1, "
                         "uint64)[0] >> 1 (fem_rmpm.montecarlo.realization_seed)",
            "cases": [{"name": c.name, "spec": c.spec, "scene": _identity_dict(c.scene)}
                      for c in cases]}


def _check_directory(out: Path, doc: dict) -> bool:
    """Raise CampaignError unless ``out`` is free or holds this campaign; True if it exists."""
    meta = out / "campaign.json"
    if out.exists() and not out.is_dir():
        raise CampaignError(f"{out}: --out is a file, not a directory")
    if not meta.exists():
        if out.exists() and any(p.name != ".campaign.lock" for p in out.iterdir()):
            raise CampaignError(f"{out}: directory is not empty and holds no campaign.json "
                                "(not a campaign directory); choose another --out")
        return False
    try:
        old = json.loads(meta.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise CampaignError(f"{meta}: unreadable campaign file ({exc}); choose another "
                            "--out") from None
    if old.get("format") != FORMAT:
        raise CampaignError(f"{meta}: not a {FORMAT!r} campaign; choose another --out")
    if old.get("campaign_seed") != doc["campaign_seed"]:
        raise CampaignError(f"{out}: holds a campaign with seed {old.get('campaign_seed')}, "
                            f"this scene has [montecarlo] seed = {doc['campaign_seed']}; "
                            "nothing was changed; choose another --out")
    old_names = [c["name"] for c in old.get("cases", [])]
    new_names = [c["name"] for c in doc["cases"]]
    if old_names != new_names:
        raise CampaignError(f"{out}: holds a campaign of the cases {old_names}, not "
                            f"{new_names}; nothing was changed; choose another --out")
    for o, n in zip(old["cases"], doc["cases"]):
        diff = _first_difference(n["scene"], _strip_identity(o.get("scene", {})))
        if diff:
            where = f"case {n['name']}: " if len(new_names) > 1 else ""
            raise CampaignError(f"{out}: holds the campaign of a different scene ({where}"
                                f"[{diff}]); nothing was changed; choose another --out")
    return True


class _Lock:
    """Exclusive, non-blocking flock on ``out/.campaign.lock`` (freed when the process dies)."""

    def __init__(self, out: Path):
        self.path = out / ".campaign.lock"
        self.fh = None

    def __enter__(self):
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self.fh = open(self.path, "a+")
        except OSError as exc:
            raise CampaignError(f"{self.path.parent}: cannot write the campaign directory "
                                f"({exc.strerror or exc}); choose another --out") from None
        try:
            fcntl.flock(self.fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            self.fh.seek(0)
            who = self.fh.read().strip() or "another process"
            self.fh.close()
            raise CampaignError(f"{self.path.parent}: the campaign is being run by {who}; "
                                "wait for it or choose another --out") from None
        self.fh.seek(0)
        self.fh.truncate()
        self.fh.write(f"pid {os.getpid()} on {socket.gethostname()}\n")
        self.fh.flush()
        return self

    def __exit__(self, *exc):
        fcntl.flock(self.fh, fcntl.LOCK_UN)
        self.fh.close()


def _read_record(path: Path) -> dict | None:
    try:
        rec = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError):
        return None
    return rec if isinstance(rec, dict) and rec.get("format") == FORMAT else None


def _clean_temporaries(out: Path) -> None:
    """Remove temporary files left by a client killed while writing (never a record)."""
    for sub in ("records", "profiles"):
        for p in (out / sub).rglob(".realization_*.tmp"):
            try:
                p.unlink()
            except OSError:
                pass


# --------------------------------------------------------------------------- table and statistics

def _fmt(v: Any) -> str:
    if v is None:
        return ""
    if isinstance(v, bool):
        return "1" if v else "0"
    if isinstance(v, float):
        return repr(v)
    return str(v)


def result_columns(records: Iterable[dict]) -> list[str]:
    """RESULT_COLUMNS with the extra scalar measures of ``records`` (sorted) inserted."""
    extra = sorted({k for r in records for k in (r.get("measures") or {})} - set(MEASURE_KEYS))
    i = RESULT_COLUMNS.index("stop_reason")
    return [*RESULT_COLUMNS[:i], *extra, *RESULT_COLUMNS[i:]]


def _row(rec: dict, columns: Sequence[str]) -> dict:
    m = rec.get("measures") or {}
    return {k: _fmt(m.get(k) if k in m or k not in rec else rec.get(k)) for k in columns}


def write_results(path: Path, records: Iterable[dict], order: Sequence[str]) -> None:
    """``results.csv`` from records, sorted by case (campaign order) and index (atomic)."""
    rank = {c: i for i, c in enumerate(order)}
    rows = sorted(records, key=lambda r: (rank.get(r["case"], len(rank)), r["index"]))
    columns = result_columns(rows)
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=columns, lineterminator="\n")
    w.writeheader()
    for r in rows:
        w.writerow(_row(r, columns))
    from .output import _atomic_write_bytes
    _atomic_write_bytes(path, buf.getvalue().encode())


def read_results(path: str | Path) -> list[dict]:
    """Rows of a ``results.csv`` with numbers parsed (empty cells -> None)."""
    rows = []
    with open(path, newline="") as fh:
        for r in csv.DictReader(fh):
            out: dict[str, Any] = {}
            for k, v in r.items():
                if v == "":
                    out[k] = None
                elif k in ("index", "seed", "steps", "particles", "frozen_points"):
                    out[k] = int(v)
                elif k == "failed":
                    out[k] = v == "1"
                elif k in ("case", "status", "stop_reason", "scheme", "error"):
                    out[k] = v
                elif re.fullmatch(r"-?[0-9]+", v):
                    out[k] = int(v)          # integer measures (floats are written as repr)
                else:
                    out[k] = float(v)
            rows.append(out)
    return rows


def wilson_interval(k: int, n: int, z: float = 1.959963984540054) -> tuple[float, float]:
    """Wilson score interval of a binomial proportion k/n (Wilson 1927)."""
    if n == 0:
        return (0.0, 1.0)
    p = k / n
    den = 1 + z * z / n
    mid = (p + z * z / (2 * n)) / den
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / den
    return (max(0.0, mid - half), min(1.0, mid + half))


def _describe(x: np.ndarray) -> dict:
    if len(x) == 0:
        return {"mean": None, "std": None, "se": None, "q05": None, "q50": None, "q95": None}
    q = np.quantile(x, [0.05, 0.5, 0.95])
    std = float(np.std(x, ddof=1)) if len(x) > 1 else 0.0
    return {"mean": float(np.mean(x)), "std": std, "se": std / math.sqrt(len(x)),
            "q05": float(q[0]), "q50": float(q[1]), "q95": float(q[2])}


def case_statistics(rows: Sequence[dict], requested: int | None = None) -> dict:
    """Statistics of one case from its rows (``read_results`` or records), in index order.

    ``p_failure`` = k/N over the ``ok`` rows, ``se`` = sqrt(p (1 - p) / N) (binomial
    standard error), ``wilson95`` its Wilson score interval; for each of
    ``runout_distance``, ``retrogression_distance``, ``sliding_area``: mean, std
    (ddof 1), se = std/sqrt(N), quantiles 5/50/95 %; ``convergence``: running
    N, P(failure), its se and the running mean run-out, in index order."""
    rows = sorted(rows, key=lambda r: r["index"])
    ok = [r for r in rows if r["status"] == "ok"]
    n = len(ok)
    fails = np.array([bool(_measure(r, "failed")) for r in ok], dtype=float)
    k = int(fails.sum())
    p = k / n if n else None
    out: dict[str, Any] = {
        "requested": requested, "finished": len(rows), "ok": n,
        "numerical_failures": len(rows) - n,
        "errors": [{"index": r["index"], "seed": r["seed"], "error": r.get("error")}
                   for r in rows if r["status"] != "ok"],
        "slope_failures": k, "p_failure": p,
        "se": math.sqrt(p * (1 - p) / n) if n else None,
        "wilson95": list(wilson_interval(k, n)) if n else None,
    }
    for key in _statistic_names(ok):
        out[key] = _describe(np.array([float(_measure(r, key)) for r in ok]))
    if n:
        nn = np.arange(1, n + 1)
        pr = np.cumsum(fails) / nn
        ro = np.array([float(_measure(r, "runout_distance")) for r in ok])
        out["convergence"] = {"n": nn.tolist(), "p_failure": pr.tolist(),
                              "se": np.sqrt(pr * (1 - pr) / nn).tolist(),
                              "mean_runout": (np.cumsum(ro) / nn).tolist()}
    return out


def _statistic_names(ok: Sequence[dict]) -> list[str]:
    """Numeric result measures present in every row (records or results.csv rows)."""
    core = ["runout_distance", "retrogression_distance", "sliding_area", "max_displacement"]
    if not ok:
        return core
    other = set(RESULT_COLUMNS) - set(MEASURE_KEYS)
    names = [set((r.get("measures") or {}) if "measures" in r else set(r) - other) for r in ok]
    extra = sorted(set.intersection(*names) - set(core) - set(_NOT_STATISTICS))
    extra = [k for k in extra if all(isinstance(_measure(r, k), (int, float))
                                     and not isinstance(_measure(r, k), bool) for r in ok)]
    return core + extra


def _measure(r: dict, key: str):
    if "measures" in r:
        return (r.get("measures") or {}).get(key)
    return r.get(key)


# --------------------------------------------------------------------------- keep-VTK selection

def parse_keep_vtk(text: str | int | Sequence[int] | None, default: int = 0):
    """``None`` -> first ``default``; ``"3"``/3 -> the first 3 of each case;
    ``"0,5,9"`` or a list -> those indices; ``"0"``/``"none"`` -> none.
    Returns an int (first k) or a frozenset of indices."""
    if text is None:
        return int(default)
    if isinstance(text, int) and not isinstance(text, bool):
        if text < 0:
            raise CampaignError(f"--keep-vtk {text}: expected K >= 0 or a list of indices")
        return text
    if isinstance(text, (list, tuple, set, frozenset)):
        idx = [int(i) for i in text]
    else:
        t = str(text).strip().lower()
        if t in ("", "none"):
            return 0
        if "," not in t:
            try:
                k = int(t)
            except ValueError:
                raise CampaignError(f"--keep-vtk {text!r}: expected K (the first K "
                                    "realizations) or indices like 0,5,9") from None
            return parse_keep_vtk(k)
        try:
            idx = [int(s) for s in t.split(",") if s.strip()]
        except ValueError:
            raise CampaignError(f"--keep-vtk {text!r}: expected K (the first K realizations) "
                                "or indices like 0,5,9") from None
    if any(i < 0 for i in idx):
        raise CampaignError(f"--keep-vtk {text!r}: indices must be >= 0")
    return frozenset(idx)


def _kept(keep, index: int) -> bool:
    return index < keep if isinstance(keep, int) else index in keep


# --------------------------------------------------------------------------- Dask

def worker_environment() -> dict[str, str]:
    """Environment of local worker processes (module docstring): one thread, malloc thresholds."""
    env = {k: "1" for k in _THREADS}
    env.update({k: str(v) for k, v in _MALLOC.items()})
    return env


def _usable_cpus() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover
        return os.cpu_count() or 1


def _start_client(workers: int | None, scheduler: str | None, n_tasks: int):
    """(client, cluster or None, description)."""
    import dask
    from distributed import Client
    if scheduler:
        timeout = dask.config.get("distributed.comm.timeouts.connect")
        try:
            client = Client(scheduler, timeout=timeout, set_as_default=False)
        except (OSError, TimeoutError, ValueError, TypeError) as exc:
            msg = " ".join(str(exc).split()) or type(exc).__name__
            raise CampaignError(f"cannot reach the Dask scheduler at {scheduler!r} within "
                                f"{timeout}: {msg[:200]}") from None
        n = len(client.scheduler_info(n_workers=-1).get("workers", {}))
        return client, None, f"the Dask cluster at {scheduler} ({n} workers now)"
    k = workers or max(1, min(_usable_cpus(), n_tasks))
    client, cluster = start_local_cluster(k)
    return client, cluster, f"{k} local worker process{'es' if k > 1 else ''}"


def start_local_cluster(workers: int):
    """``(client, cluster)``: a LocalCluster of ``workers`` single-thread processes with
    :func:`worker_environment` set before they start (close both when done)."""
    import logging

    import dask
    from distributed import Client, LocalCluster
    env = {f"distributed.nanny.pre-spawn-environ.{key}": val
           for key, val in worker_environment().items()}
    with dask.config.set(env):
        # ":0": the scheduler's HTTP server (and the dashboard, if bokeh is installed) on a
        # free port; None would still bind 8787 and warn when another cluster holds it
        cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                               dashboard_address=":0", silence_logs=logging.ERROR)
    return Client(cluster, set_as_default=False), cluster


class _Progress:
    def __init__(self, total: int, enabled: bool, desc: str):
        self.bar = None
        self.ok = self.failed = self.lost = self.running = 0
        if enabled and total:
            from tqdm import tqdm
            self.bar = tqdm(total=total, desc=desc, unit="real", dynamic_ncols=True,
                            postfix=self._text(),
                            bar_format="{l_bar}{bar}| {n}/{total} [{elapsed}<{remaining}, "
                                       "{rate_fmt}{postfix}]")

    def _text(self) -> str:
        return (f"ok {self.ok}, failed {self.failed}, running {self.running}"
                + (f", lost {self.lost}" if self.lost else ""))

    def _post(self):
        if self.bar is not None:
            self.bar.set_postfix_str(self._text(), refresh=True)

    def done(self, status: str):
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

    def set_running(self, n: int):
        if n != self.running:
            self.running = n
            self._post()

    def close(self):
        if self.bar is not None:
            self.bar.close()


# --------------------------------------------------------------------------- the campaign

@dataclass
class CampaignResult:
    """What :func:`run_campaign` did: ``stats`` per case (:func:`case_statistics`),
    ``computed``/``skipped``/``lost`` realizations of this command, its wall time
    and the number of workers."""
    out: Path
    cases: list[Case]
    realizations: dict[str, int]
    stats: dict[str, dict]
    computed: int
    skipped: int
    lost: list[str]
    wall_time: float
    compute_time: float
    workers: str
    figures: list[Path] = field(default_factory=list)

    @property
    def realizations_per_hour(self) -> float | None:
        return 3600.0 * self.computed / self.compute_time if self.compute_time > 0 else None


def _case_realizations(case: Case, n: int) -> int:
    return 1 if case.deterministic else n


def run_campaign(scene: Scene, out: str | Path, realizations: int | None = None,
                 cases: Sequence[str | Case] | None = None, workers: int | None = None,
                 scheduler: str | None = None, force: bool = False, keep_vtk=None,
                 progress: bool = True, figures: bool = True, client=None) -> CampaignResult:
    """Run (or finish) a campaign in ``out``; see the module docstring.

    ``realizations``: N per case (default ``[montecarlo] realizations``);
    ``cases``: case texts for :func:`parse_case` or :class:`Case` objects
    (default: the scene itself); ``workers``: local worker processes;
    ``scheduler``: address of a running Dask scheduler instead; ``client``: an
    existing ``distributed.Client`` to use (left open); ``keep_vtk``: see
    :func:`parse_keep_vtk`.  Raises :class:`CampaignError` (bad input, other
    campaign in ``out``, unreachable scheduler) before anything is written."""
    t_start = time.perf_counter()
    out = Path(out)
    n = scene.montecarlo.realizations if realizations is None else realizations
    if isinstance(n, bool) or not isinstance(n, int) or n <= 0:
        raise CampaignError(f"-n {n}: the number of realizations must be a positive integer")
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int)
                                or workers <= 0):
        raise CampaignError(f"--workers {workers}: expected a positive integer")
    if client is not None and (workers is not None or scheduler):
        raise CampaignError("give a client, or workers, or a scheduler address")
    if workers is not None and scheduler:
        raise CampaignError("--workers starts a local cluster; with --scheduler the "
                            "cluster's own workers are used: give one of the two")
    keep = parse_keep_vtk(keep_vtk, scene.montecarlo.keep_vtk)
    case_list = [c if isinstance(c, Case) else parse_case(c, scene)
                 for c in (cases or ["scene"])]
    names = [c.name for c in case_list]
    if len(set(names)) != len(names):
        raise CampaignError(f"case names must be unique, got {names}")
    counts = {c.name: _case_realizations(c, n) for c in case_list}
    doc = _campaign_doc(case_list, scene.montecarlo.seed)
    _check_directory(out, doc)
    lay = _Layout(out, case_list)
    # what is left to do (read-only)
    tasks, finished = [], {}
    for i in range(max(counts.values())):
        for c in case_list:
            if i >= counts[c.name]:
                continue
            seed = realization_seed(scene.montecarlo.seed, i)
            rec = None if force else _read_record(lay.record(c.name, i))
            if rec is not None and rec.get("seed") == seed and rec.get("case") == c.name:
                finished[(c.name, i)] = rec
                continue
            vtk = lay.vtk(c.name, i) if _kept(keep, i) else None
            tasks.append({"case": c.name, "index": i, "seed": seed, "scene": c.scene,
                          "vtk_dir": str(vtk.resolve()) if vtk is not None else None,
                          "vtk_rel": str(vtk.relative_to(out)) if vtk is not None else None})
    skipped = len(finished)
    own = client is None
    cluster = None
    desc, lost = "no workers needed", []
    if not own:
        desc = f"the given Dask client ({len(client.nthreads())} workers)"
    compute_time = 0.0
    if own and tasks and scheduler:  # before anything is written: unreachable -> error
        client, cluster, desc = _start_client(None, scheduler, len(tasks))
    try:
        with _Lock(out):
            _check_directory(out, doc)   # again, now that no one else can write here
            if not (out / "campaign.json").exists():
                write_json(out / "campaign.json", doc)
            _clean_temporaries(out)
            if tasks:
                if client is None:
                    client, cluster, desc = _start_client(workers, None, len(tasks))
                if progress:
                    print(f"fem-rmpm mc: {len(tasks)} realization(s) to run ({skipped} "
                          f"already finished) on {desc}; records in {out}", file=sys.stderr)
                t0 = time.perf_counter()
                lost = _compute(client, tasks, lay, finished, progress, scene.scene.name)
                compute_time = time.perf_counter() - t0
            result = _finish(out, scene, case_list, counts, lay, finished,
                             len(tasks) - len(lost), skipped, lost, desc, t_start,
                             compute_time, figures)
    finally:
        if own and client is not None:
            client.close(timeout=10)
        if cluster is not None:
            cluster.close(timeout=10)
    return result


def _compute(client, tasks: list[dict], lay: _Layout, finished: dict, progress: bool,
             name: str) -> list[str]:
    """Submit the tasks, write each record as it arrives; return the lost ones."""
    from distributed import as_completed
    token = uuid.uuid4().hex[:8]
    keys = [f"rmpm-{token}-{t['case']}-{t['index']:05d}" for t in tasks]
    futures = client.map(run_realization, tasks, key=keys, pure=False, retries=0)
    by_key = dict(zip(keys, tasks))
    bar = _Progress(len(tasks), progress, f"{name} mc")
    lost: list[str] = []
    ours = set(keys)
    ac = as_completed(futures, with_results=False, loop=client.loop)
    last_poll = 0.0
    try:
        while not ac.is_empty():
            batch = ac.next_batch(block=False)
            if not batch:
                now = time.monotonic()
                if bar.bar is not None and now - last_poll > 1.0:
                    last_poll = now
                    try:   # executing = assigned to a worker, at most its thread count
                        proc, threads = client.processing(), client.nthreads()
                        bar.set_running(sum(min(sum(1 for k in ks if k in ours),
                                                threads.get(w, 1)) for w, ks in proc.items()))
                    except Exception:  # noqa: BLE001 - the bar is cosmetic
                        pass
                time.sleep(0.05)
                continue
            for fut in batch:
                task = by_key[fut.key]
                try:
                    rec = fut.result()
                except Exception as exc:  # noqa: BLE001 - infrastructure, not the realization
                    msg = " ".join(str(exc).split())[:300]
                    lost.append(f"{task['case']} #{task['index']}: {type(exc).__name__}: {msg}")
                    bar.done("lost")
                    fut.release()
                    continue
                profile = rec.pop("final_profile", None)
                if profile is not None:
                    write_json(lay.profile(rec["case"], rec["index"]),
                               {"case": rec["case"], "index": rec["index"], "seed": rec["seed"],
                                "final_profile": profile})
                write_json(lay.record(rec["case"], rec["index"]), rec)
                finished[(rec["case"], rec["index"])] = rec
                bar.done(rec["status"])
                fut.release()
    finally:
        bar.close()
    return lost


def _finish(out, scene, cases, counts, lay, finished, computed, skipped, lost, desc,
            t_start, compute_time, figures) -> CampaignResult:
    order = [c.name for c in cases]
    records = [r for (c, i), r in finished.items() if i < counts[c]]
    write_results(out / "results.csv", records, order)
    stats = {c.name: case_statistics([r for r in records if r["case"] == c.name],
                                     counts[c.name]) for c in cases}
    walls = [r["wall_time"] for r in records if r.get("wall_time") is not None]
    cpus = [r["cpu_time"] for r in records if r.get("cpu_time") is not None]
    res = CampaignResult(out, cases, counts, stats, computed, skipped, lost,
                         time.perf_counter() - t_start, compute_time, desc)
    extra = sum(1 for (c, i) in finished if i >= counts[c])
    summary = {
        "scene": scene.scene.name, "scene_file": scene.source,
        "campaign_seed": scene.montecarlo.seed,
        "failure_displacement": scene.montecarlo.failure_displacement,
        "cases": [{"name": c.name, "spec": c.spec, "label": c.label,
                   "deterministic": c.deterministic, "realizations": counts[c.name],
                   **stats[c.name]} for c in cases],
        "this_run": {"computed": computed, "skipped_finished": skipped, "lost": lost,
                     "workers": desc, "compute_wall_time": compute_time,
                     "wall_time": res.wall_time,
                     "realizations_per_hour": res.realizations_per_hour},
        "realization_wall_time": {"mean": float(np.mean(walls)) if walls else None,
                                  "total": float(np.sum(walls)) if walls else None},
        "realization_cpu_time": {"mean": float(np.mean(cpus)) if cpus else None,
                                 "total": float(np.sum(cpus)) if cpus else None},
        "records_beyond_n": extra,
    }
    write_json(out / "summary.json", summary)
    if figures and records:
        from .campaign_plots import campaign_figures
        res.figures = campaign_figures(out, cases, stats, records, lay, scene)
    return res


# --------------------------------------------------------------------------- CLI

def _is_default_scene(path: str | Path) -> bool:
    from .cli import default_scene_path
    try:
        return Path(path).resolve() == default_scene_path().resolve()
    except OSError:  # pragma: no cover
        return False


def campaign_cases(scene: Scene, scene_path: str | Path | None = None) -> list[str]:
    """Cases of a campaign run from the command line: ``[montecarlo] cases`` if the scene
    has that key, the four :data:`LITERATURE_CASES` for the embedded default scene,
    else the scene itself."""
    listed = tuple(getattr(scene.montecarlo, "cases", ()) or ())
    if listed:
        return list(listed)
    if scene_path is not None and _is_default_scene(scene_path):
        return list(LITERATURE_CASES)
    return ["scene"]


_MECHANISM_TEXT = (("slip_surface_height", "slip-surface height", " m"),
                   ("intact_blocks", "intact blocks", ""),
                   ("sliding_area_early", "early sliding area", " m2"))


def summary_text(res: CampaignResult) -> str:
    """The final one-paragraph-per-case summary printed by ``fem-rmpm mc``."""
    lines = []
    rph = res.realizations_per_hour
    head = (f"Campaign in {res.out}: {sum(res.realizations.values())} realizations in "
            f"{len(res.cases)} case(s); ")
    if res.computed or res.lost:
        head += (f"this run computed {res.computed} (skipped {res.skipped} already "
                 f"finished) on {res.workers} in {res.wall_time:.1f} s"
                 + (f" ({rph:.0f} realizations/hour)" if rph else "") + ".")
    else:
        head += f"all {res.skipped} had finished before; tables and figures rebuilt."
    lines.append(head)
    for c in res.cases:
        s = res.stats[c.name]
        head = f"  {c.label}: " + ("deterministic (no random field), 1 realization; "
                                   if c.deterministic else f"N = {s['ok']} ok")
        if not c.deterministic:
            head += (f", {s['numerical_failures']} failed numerically" if
                     s["numerical_failures"] else "") + "; "
        if s["ok"] == 0:
            lines.append(head + "no realization finished"
                         + (f" (first error: {s['errors'][0]['error']})" if s["errors"] else ""))
            continue
        if c.deterministic:
            r, t, a = (s[k]["mean"] for k in ("runout_distance", "retrogression_distance",
                                              "sliding_area"))
            mech = "".join(f", {lab} {s[k]['mean']:.2f}{unit}"
                           for k, lab, unit in _MECHANISM_TEXT if k in s)
            lines.append(head + f"failed = {bool(s['slope_failures'])}, run-out {r:.2f} m, "
                         f"retrogression {t:.2f} m, sliding area {a:.1f} m2{mech}")
            continue
        lo, hi = s["wilson95"]
        txt = (f"P(failure) = {s['p_failure']:.3f} +- {s['se']:.3f} (SE sqrt(p(1-p)/N); "
               f"Wilson 95 % [{lo:.2f}, {hi:.2f}])")
        for key, lab, unit in (("runout_distance", "run-out", "m"),
                               ("retrogression_distance", "retrogression", "m"),
                               ("sliding_area", "sliding area", "m2")):
            d = s[key]
            txt += (f"; {lab} mean {d['mean']:.2f} +- {d['se']:.2f} {unit} "
                    f"(5/50/95 %: {d['q05']:.2f}/{d['q50']:.2f}/{d['q95']:.2f})")
        mech = [(k, lab, unit) for k, lab, unit in _MECHANISM_TEXT if k in s]
        if mech:
            txt += "; mean " + ", ".join(f"{lab} {s[k]['mean']:.2f}{unit}"
                                         for k, lab, unit in mech)
        conv = s.get("convergence")
        if conv and s["ok"] >= 4:
            idx = sorted({s["ok"] // 4 - 1, s["ok"] // 2 - 1, s["ok"] - 1})
            txt += ("; with N = " + ", ".join(str(conv["n"][i]) for i in idx)
                    + ": P(failure) " + ", ".join(f"{conv['p_failure'][i]:.2f}" for i in idx)
                    + ", mean run-out " + ", ".join(f"{conv['mean_runout'][i]:.1f}" for i in idx)
                    + " m")
        lines.append(head + txt)
        if s["numerical_failures"]:
            e = s["errors"][0]
            lines.append(f"    first failed realization: #{e['index']} (seed {e['seed']}): "
                         f"{e['error']}")
    if res.lost:
        lines.append(f"  {len(res.lost)} realization(s) LOST (their workers died; no record): "
                     + "; ".join(res.lost[:3]) + " -- re-run the same command to compute them")
    figs = ", ".join(p.name for p in res.figures)
    lines.append(f"Output: results.csv, summary.json, records/"
                 + (", vtk/" if (res.out / "vtk").exists() else "")
                 + (f", {figs}" if figs else "") + f" in {res.out}")
    return "\n".join(lines)


def run_campaign_cli(args) -> int:
    """``fem-rmpm mc``: returns 0, or 3 if realizations were lost (re-run to finish)."""
    from .scene import load_scene
    scene = load_scene(args.scene)
    cases = campaign_cases(scene, args.scene)
    res = run_campaign(scene, args.out, realizations=args.realizations, cases=cases,
                       workers=args.workers, scheduler=args.scheduler, force=args.force,
                       keep_vtk=args.keep_vtk, progress=not args.quiet)
    print(summary_text(res))
    return 3 if res.lost else 0
