"""Monte Carlo RMPM on Dask: many realizations of a scene, resumable and lossless.

Modules: :mod:`.cases` (cases and seeds), :mod:`.task` (the realization task run by the
workers), :mod:`.store` (campaign directory, identity, lock, records, ``results.csv``),
:mod:`.statistics`, :mod:`.keep_vtk`, :mod:`.backends` and :mod:`.cluster` (where the
realizations run); :mod:`.methods` (the campaign-method protocol and its table
:data:`~fem_rmpm.campaign.methods.METHODS`: crude Monte Carlo, subset simulation);
:mod:`.runner` (the one campaign runner: any method, records, lock, Dask);
:mod:`.case_campaign` (campaigns of cases, :func:`run_campaign`), :mod:`.subset_runner`
(response campaigns of a scene, ``fem-rmpm mc --method subset``), :mod:`.subset_plots`
and :mod:`.summary_text` (the paragraphs ``fem-rmpm mc`` prints); :mod:`.factor_of_safety`
and :mod:`.fragility` (the FS of every realization, why each failed: progressive or
strength-limited, the fragility curve, softening switched off), :mod:`.convergence` and
:mod:`.convergence_report` (``fem-rmpm converge``: the same realizations on two or three
meshes), :mod:`.main_job` (``fem-rmpm mc`` without a scene).

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
  simulated, wall and CPU time, the scalar measures (:mod:`fem_rmpm.measures.deposit`) and the
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
  its ``fem_rmpm`` version); use ``--force`` or a new directory to recompute.  A lock
  file stops two commands from working on one directory at the same time (released by
  the kernel even if the client is killed).
* **Failures.** A realization that fails (:class:`fem_rmpm.schemes.common.SimulationError`:
  unstable, a random-field value the material cannot take, ...; or any other
  exception in the realization) is recorded with ``status = failed`` and its
  message and the campaign goes on.  Statistics use the ``ok`` realizations; the
  summary counts the failed ones.  A realization whose *worker* died is retried
  by Dask on another worker (up to ``distributed.scheduler.allowed-failures``
  times); if it is still lost, it has no record and the next run computes it.
* **Runs stopped once decided** (:mod:`.decide`): with ``[montecarlo] runs_to_rest = K``
  realization ``i >= K`` stops at the first output at which ``failure_area`` (1 m2/m) of
  points has moved more than ``failure_displacement`` (its record: ``stop_reason =
  "failure decided"``, only ``failed``, ``decided_time``, ``decided_area``); a run never
  decided so runs to rest.
  P(failure) is over all realizations, the measures over the runs to rest with ``i < K``
  (``measure_runs`` in the statistics).  ``runs_to_rest`` is not part of the identity:
  a larger K reruns the decided records below it to rest.
* **VTK** is written only for kept realizations (``--keep-vtk K``: the first K
  of each case; ``--keep-vtk 0,5,9``: those indices; default ``[montecarlo]
  keep_vtk``), to ``vtk/<case>/realization_00003/`` (``particles.pvd``,
  ``grid.vtu``, ``summary.json``, ``plastic_shear_strain.png``), by the worker:
  with a remote cluster, the campaign directory must be on a file system the
  workers share (as usual on HPC clusters).

Statistics (``summary.json`` and the printed summary), per case over the ``ok``
realizations: P(failure) = fraction with ``failed`` (at least ``[montecarlo]
failure_area`` of points moved more than ``failure_displacement``), its standard error
``sqrt(p (1 - p) / N)`` (binomial; e.g. Fenton & Griffiths 2008, Risk Assessment in Geotechnical
Engineering, sec. 6.2) and the Wilson 95 % score interval (Wilson 1927; Brown, Cai &
DasGupta 2001), which stays meaningful at p = 0 or 1; mean, standard deviation,
standard error of the mean and the 5/50/95 % quantiles of run-out, retrogression
and sliding area; and their running values in index order (convergence with N).

Figures (:mod:`fem_rmpm.campaign.plots`): ``exceedance.png`` (P[run-out > x],
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
``MKL_NUM_THREADS``, ``OPENBLAS_NUM_THREADS`` = 1 and ``NUMBA_NUM_THREADS`` = the
scene's ``[solver] threads`` (1 for 0, the default: one thread per process, the
parallelism comes from the processes; with ``threads = 2`` a 2-core machine gets one
worker of two threads, unless ``--workers`` says otherwise) and
``MALLOC_TRIM_THRESHOLD_`` = 1 GiB with ``MALLOC_MMAP_THRESHOLD_`` = 32 MiB.
Dask sets ``MALLOC_TRIM_THRESHOLD_=65536``; setting *any* trim threshold also
freezes glibc's mmap threshold at 128 KiB, so every array above 128 KiB is a
fresh ``mmap`` that page-faults on first touch and is unmapped when freed: with
array-heavy kernels (the numpy kernel) that is several times the wall time in system
time; raising both thresholds (or setting neither) removes it, raising the trim
threshold alone does not (the figures: the documentation's benchmark pages).  Workers
of an existing cluster keep the environment they were started with, so each
realization task also raises both thresholds with ``mallopt`` (glibc; a no-op
elsewhere), to the same effect as the environment variables.

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

import importlib

from fem_rmpm.campaign.cases import (
    LITERATURE_CASES,
    CampaignError,
    Case,
    campaign_cases,
    default_scene_path,
    literature_cases,
    parse_case,
    realization_seed,
    without_random_field,
)

# The rest is imported when first used (PEP 562): the cluster, runner and task modules
# import dask and distributed (~0.65 s), which a plain ``fem-rmpm run`` never needs.
_LAZY = {"start_local_cluster": ".cluster", "worker_environment": ".cluster",
         "parse_keep_vtk": ".keep_vtk", "CampaignResult": ".case_campaign",
         "run_campaign": ".case_campaign",
         "case_statistics": ".statistics", "wilson_interval": ".statistics",
         "RECORD_COLUMNS": ".store", "read_results": ".store", "result_columns": ".store",
         "write_results": ".store", "run_realization": ".task", "CampaignMethod": ".methods",
         "CrudeMonteCarlo": ".methods", "SubsetSimulation": ".methods", "METHODS": ".methods",
         "subset_simulation": ".methods", "run_subset_campaign": ".subset_runner",
         # for the CLI's mc command
         "ClusterSpec": ".backends", "parse_adapt": ".backends",
         "estimate_campaign": ".estimate", "estimate_text": ".estimate",
         "fs_text": ".factor_of_safety", "subset_summary_text": ".summary_text",
         "summary_text": ".summary_text", "perfectly_plastic": ".fragility",
         "fragility_statistics": ".fragility", "run_convergence": ".convergence",
         "convergence_statistics": ".convergence"}


def __getattr__(name: str):
    if name in _LAZY:
        value = getattr(importlib.import_module(_LAZY[name], __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = ["CampaignError", "Case", "LITERATURE_CASES", "parse_case", "literature_cases",
           "campaign_cases", "default_scene_path",
           "realization_seed", "without_random_field", "run_realization", "run_campaign",
           "CampaignResult", "case_statistics", "wilson_interval", "read_results",
           "write_results", "result_columns", "parse_keep_vtk", "worker_environment",
           "start_local_cluster", "RECORD_COLUMNS", "CampaignMethod", "CrudeMonteCarlo", "METHODS",
           "SubsetSimulation", "subset_simulation", "run_subset_campaign", "summary_text",
           "subset_summary_text", "perfectly_plastic", "fragility_statistics",
           "run_convergence", "convergence_statistics"]
