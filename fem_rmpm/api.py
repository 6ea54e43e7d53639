"""Public Python API for research driver scripts.

>>> from fem_rmpm import api
>>> scene = api.load_scene("meshes/column.toml")
>>> scene = api.with_value(scene, "soil.youngs_modulus", 2000.0)
>>> result = api.run(scene, out="runs/stiff")          # or out=None: nothing written
>>> result.measures["max_displacement"], result.particles.stress[:, 1].min()

A realization is a pure function of ``(scene, seed)``: the seed only drives the
random field (if the scene has one); nothing else is random.  ``prepare`` and ``run``
also take ``noise=``, the random field's standard-normal noise array, which replaces
the seed: a realization is a pure function of ``(scene, noise)``.
``noise_shape(scene, grid)`` is that array's shape and ``field_noise(scene, grid, seed)``
the seed's own noise (``grid = prepare(scene)[0]``), so that

>>> grid, _ = api.prepare(scene)
>>> eps = api.field_noise(scene, grid, 3)        # == api.run(scene, seed=3)'s field
>>> result = api.run(scene, noise=0.5 * eps)    # another point of the noise space
"""
from __future__ import annotations

import dataclasses
import importlib
import os
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from tqdm import tqdm

from fem_rmpm.discretise.contact import refuse_frictional
from fem_rmpm.discretise.grid import Grid, make_grid
from fem_rmpm.discretise.points import Particles, seed_particles, soil_cells
from fem_rmpm.io.output import PvdSeries, write_grid, write_json
from fem_rmpm.io.rundir import (
    RunDirError,
    check_run_dir,
    mark_interrupted,
    run_files,
    start_run_dir,
)
from fem_rmpm.materials import point_problem
from fem_rmpm.runtime.budget import check_budget, explicit_numba
from fem_rmpm.runtime.machine import describe as describe_machine
from fem_rmpm.runtime.signals import interrupt_name, raise_if_interrupted
from fem_rmpm.scene import Scene, SceneError, check_seed, load_scene, scene_to_dict, with_value
from fem_rmpm.schemes.common import RunRecord, SimulationError
from fem_rmpm.schemes.explicit import kernels
from fem_rmpm.schemes.explicit.kernels.advance import pair_driver_fits, pair_worker
from fem_rmpm.schemes.explicit.loop import run_explicit
from fem_rmpm.schemes.explicit.threads import auto_threads, threads_from_auto
from fem_rmpm.schemes.pore_pressure import saturate_points, vtk_fields

if TYPE_CHECKING:
    from fem_rmpm.schemes.fem import FemResult
    from fem_rmpm.schemes.fem3d import Fem3DResult

# Imported where first used, so that an explicit two-dimensional run loads neither the
# implicit scheme, the static FEM reference, the random fields (unless its scene has one),
# the three-dimensional scheme, the measures (after the time loop) nor matplotlib (the
# figures at the end) before its first step (``tests/test_start_up.py``).
# ``noise_shape`` and ``field_noise`` are the random field's (:mod:`fem_rmpm.random_field`),
# loaded on first access (PEP 562).
_LAZY = {"noise_shape": "fem_rmpm.random_field", "field_noise": "fem_rmpm.random_field"}


def __getattr__(name: str):
    if name in _LAZY:
        value = getattr(importlib.import_module(_LAZY[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = ["load_scene", "with_value", "prepare", "run", "fem", "factor_of_safety", "RunResult",
           "noise_shape", "field_noise", "with_run_threads", "SceneError", "SimulationError",
           "RunDirError"]


@dataclass
class RunResult:
    scene: Scene
    seed: int | None
    grid: Grid
    particles: Particles
    record: RunRecord
    measures: dict
    summary: dict
    out: Path | None
    snapshots: list = dataclasses.field(default_factory=list)  # [(t, x (n, 2), gamma_p (n,))]


def prepare(scene: Scene, seed: int | None = None, noise=None) -> tuple[Grid, Particles]:
    """Grid and seeded material points; with a random field, the realization ``seed`` or the
    field of the standard-normal ``noise`` array (which replaces the seed)."""
    check_seed(seed)
    check_budget(scene)                        # refuse before allocating (BudgetError)
    if scene.grid.dimension == 3:
        return _prepare_3d(scene, seed, noise)
    grid = make_grid(scene)
    pts = seed_particles(scene, grid)
    saturate_points(scene, pts)                # [water]: saturated mass below the surface
    if scene.random_field is not None:
        # lazy: a scene with a random field only
        from fem_rmpm.random_field import apply_to_points, sample_point_properties
        seed = scene.montecarlo.seed if seed is None else seed
        values = sample_point_properties(scene, grid, pts, seed, noise=noise)
        pts.soil = apply_to_points(pts.soil, values)   # residuals in proportion to peak
        _check_point_strength(scene, pts, seed if noise is None else "(given noise)")
    return grid, pts


def _prepare_3d(scene: Scene, seed: int | None, noise) -> tuple:
    """:func:`prepare` of a three-dimensional scene: the field's memory is checked (and its
    embedding set up) before the points are seeded
    (:mod:`fem_rmpm.random_field.points3d`)."""
    from fem_rmpm.discretise.grid3d import make_grid_3d, soil_cells_3d  # lazy: 3-D only
    from fem_rmpm.discretise.points3d import seed_particles_3d  # lazy: 3-D only
    # lazy: 3-D only
    from fem_rmpm.random_field.points3d import (
        apply_to_points_3d,
        prepare_field_3d,
        sample_point_properties_3d,
    )
    grid = make_grid_3d(scene)
    if scene.random_field is None:
        return grid, seed_particles_3d(scene, grid)
    if noise is not None:
        raise SceneError(f"{scene.source}: [random_field] a noise array for a "
                         "three-dimensional field; allowed: a seed (3-D realizations are "
                         "drawn from their seed only)")
    lattice = prepare_field_3d(scene, grid, soil_cells_3d(scene, grid))
    pts = seed_particles_3d(scene, grid)
    seed = scene.montecarlo.seed if seed is None else seed
    apply_to_points_3d(pts, sample_point_properties_3d(scene, pts, seed, lattice))
    _check_point_strength(scene, pts, seed)
    return grid, pts


def _check_point_strength(scene: Scene, pts: Particles, seed) -> None:
    """Stop with the model's own message when a random field drew values at a point that
    its material model rejects (:func:`fem_rmpm.materials.point_problem`)."""
    problem = point_problem(pts.soil, pts.x0)
    if problem:
        raise SimulationError(f"realization seed {seed}: {problem}")


def _run_scheme(scene, grid, pts, on_output, progress, out=None):
    """The scheme's run; Ctrl-C or SIGTERM marks the summary in ``out`` interrupted."""
    try:
        if scene.solver.scheme == "implicit":
            from fem_rmpm.schemes.implicit import run_implicit  # lazy: implicit runs only
            return run_implicit(scene, grid, pts, on_output=on_output, progress=progress)
        return run_explicit(scene, grid, pts, on_output=on_output, progress=progress)
    except KeyboardInterrupt as exc:
        if out is not None:
            mark_interrupted(out, f"interrupted ({interrupt_name(exc)})")
        raise


#: Bytes of snapshot positions and plastic strains :func:`run` keeps in memory; the
#: snapshots beyond are memory maps of unlinked temporary files (pages on disk, not in
#: RAM; the same values bitwise): 5 million points x 40 outputs would otherwise hold
#: ~5 GB of positions for the measures and figures that read a few of them.
SNAPSHOT_MEMORY_BYTES = 256 * 2**20


class SnapshotStore(list):
    """``[(t, x, gamma_p)]`` of a run's outputs: copies in memory up to ``limit`` bytes
    (default :data:`SNAPSHOT_MEMORY_BYTES`), then disk-backed (:func:`_on_disk`)."""

    def __init__(self, limit: float | None = None):
        super().__init__()
        self.limit = SNAPSHOT_MEMORY_BYTES if limit is None else limit
        self.bytes = 0

    def add(self, t: float, x: np.ndarray, gamma: np.ndarray) -> None:
        size = x.nbytes + gamma.nbytes
        if self.bytes + size > self.limit:
            self.append((t, _on_disk(x), _on_disk(gamma)))
        else:
            self.bytes += size
            self.append((t, x.copy(), gamma.copy()))


def _on_disk(a: np.ndarray) -> np.ndarray:
    """A copy of ``a`` as a memory map of a temporary ``.npy`` file, unlinked at once (the
    mapping keeps it until the array is freed)."""
    fd, name = tempfile.mkstemp(prefix="fem_rmpm_snapshot_", suffix=".npy")
    os.close(fd)
    try:
        m = np.lib.format.open_memmap(name, mode="w+", dtype=a.dtype, shape=a.shape)
        m[...] = a
        m.flush()
    finally:
        os.unlink(name)
    return m


class _Stopped(Exception):
    """Raised from the output callback of :func:`run` when ``stop_when`` gives a reason."""

    def __init__(self, t: float, reason: str):
        super().__init__(reason)
        self.t, self.reason = t, reason


def run(scene: Scene, out: str | Path | None = None, seed: int | None = None, *,
        progress: bool = False, vtk: bool | None = None, figures: bool | None = None,
        force: bool = False, noise=None, label: str | None = None,
        stop_when=None) -> RunResult:  # long function: the run's steps in order, 3-D first
    """Run one realization; write VTK, PNG and ``summary.json`` to ``out`` if given.
    ``noise``: the random field's standard-normal noise array instead of ``seed``.
    ``stop_when(t, pts) -> str | None``: called at every output (t = 0, every
    ``output_interval`` s, the end); a non-empty string stops the run there, becomes its
    ``stop_reason`` and the measures are those of the state at that time (``steps`` 0:
    not counted; e.g. a campaign's runs stopped once decided, :mod:`fem_rmpm.campaign`).

    ``out`` must be a new or empty directory, or ``force=True`` replaces the run in it
    (:mod:`fem_rmpm.io.rundir`: ``summary.json`` says ``"running"`` until the run's
    output is complete).  ``label`` names the run in figure titles (e.g. case and
    realization; default: the scene name, and the seed of a random field).  Raises
    :class:`RunDirError` or :class:`BudgetError` (bad input, nothing written) and
    :class:`SimulationError` when the run cannot go on (after writing what it has to ``out``).
    """
    if scene.grid.dimension == 3:
        return _run_3d(scene, out, seed, progress=progress, vtk=vtk, force=force,
                       noise=noise, stop_when=stop_when)
    out = check_run_dir(out, force) if out is not None else None
    check_seed(seed)
    solved = with_run_threads(scene)     # the notice, estimate and run use one thread count
    estimate = check_budget(solved)
    if progress:
        print(f"{scene.scene.name}: {estimate.describe()}", file=sys.stderr, flush=True)
        notice = compile_notice(solved)
        if notice:
            print(notice, file=sys.stderr, flush=True)
    grid, pts = prepare(scene, seed, noise)
    vtk = scene.output.vtk if vtk is None else vtk
    figures = scene.output.png if figures is None else figures
    series = PvdSeries(out, extra=vtk_fields(scene)) if (out is not None and vtk) else None
    snapshots = SnapshotStore()

    def on_output(t, p):
        raise_if_interrupted()          # a signal whose exception a native callback dropped
        snapshots.add(t, p.x, p.plastic_shear_strain)
        if series is not None:
            series.add(t, p)
        reason = stop_when(t, p) if stop_when is not None else None
        if reason:
            raise _Stopped(t, reason)

    if out is not None:
        start_run_dir(out, {"scene": scene_to_dict(scene), "scene_file": scene.source,
                            "seed": seed, "estimate": estimate.to_dict()})
        if vtk:
            write_grid(out / "grid.vtu", grid, np.nonzero(soil_cells(scene, grid) >= 0)[0])
    bar = _Bar(scene) if progress else None
    machine, wall0, cpu0 = describe_machine(), time.perf_counter(), time.process_time()
    error = None
    try:
        with threads_from_auto(solved is not scene):      # auto: no busy-cores warning
            rec = _run_scheme(solved, grid, pts, on_output, bar.update_to if bar else None, out)
    except _Stopped as stop:
        rec = RunRecord(scheme=scene.solver.scheme, time=stop.t, stop_reason=stop.reason,
                        frozen_points=np.nonzero(~pts.active)[0].tolist())
    except SimulationError as exc:
        error = exc
        rec = getattr(exc, "record", None) or RunRecord(scheme=scene.solver.scheme)
        rec.error, rec.stop_reason = str(exc), "error"
    finally:
        if bar:
            bar.close()
    rec.wall_time, rec.cpu_time = time.perf_counter() - wall0, time.process_time() - cpu0
    from fem_rmpm.measures.deposit import compute_measures  # lazy: after the time loop
    mc, t0 = scene.montecarlo, rec.solver.get("geostatic_end_time", 0.0)   # t0: motion starts
    measures = compute_measures(pts, scene.scene.frame_angle_deg, mc.failure_displacement,
                                grid.cell, rec.time if rec.stop_reason == "at rest" else None,
                                snapshots=snapshots, grid=grid,
                                mechanism_time=MECHANISM_TIME + t0,
                                intact_block_area=mc.intact_block_area,
                                failure_area=mc.failure_area)
    summary = _summary(scene, seed, pts, rec, measures, machine, estimate)
    if out is not None:
        if figures and snapshots and error is None:
            who = label or (f"{scene.scene.name}, seed {seed}" if seed is not None
                            and scene.random_field is not None else scene.scene.name)
            _figures(out, scene, grid, snapshots, measures, who, rec)
        write_json(out / "summary.json", {**summary, "files": run_files(out)})   # last
    if error is not None:
        raise error
    return RunResult(scene, seed, grid, pts, rec, measures, summary, out, snapshots)


def _run_3d(scene: Scene, out, seed, *, progress: bool, vtk: bool | None,
            force: bool, noise=None, stop_when=None) -> RunResult:
    """:func:`run` of a three-dimensional scene (:mod:`fem_rmpm.schemes.explicit3d`): VTK
    of the points at every output and of the soil cells, ``summary.json`` with the
    strike-wise measures (:mod:`fem_rmpm.measures.deposit3d`).  No snapshot of the
    positions is kept in memory (``snapshots`` holds the output times only);
    ``stop_when`` as in :func:`run`."""
    from fem_rmpm.discretise.grid3d import soil_cells_3d  # lazy: 3-D only
    from fem_rmpm.io.output3d import write_grid_3d  # lazy: 3-D only
    from fem_rmpm.measures.deposit3d import compute_measures_3d  # lazy: 3-D only
    from fem_rmpm.schemes.explicit3d import run_explicit_3d  # lazy: 3-D only
    out = check_run_dir(out, force) if out is not None else None
    check_seed(seed)
    estimate = check_budget(scene)
    if progress:
        print(f"{scene.scene.name}: {estimate.describe()}", file=sys.stderr, flush=True)
    grid, pts = prepare(scene, seed, noise)
    vtk = scene.output.vtk if vtk is None else vtk
    series = PvdSeries(out) if (out is not None and vtk) else None
    times: list = []

    def on_output(t, p):
        raise_if_interrupted()
        times.append((t,))
        if series is not None:
            series.add(t, p)
        reason = stop_when(t, p) if stop_when is not None else None
        if reason:
            raise _Stopped(t, reason)

    if out is not None:
        start_run_dir(out, {"scene": scene_to_dict(scene), "scene_file": scene.source,
                            "seed": seed, "estimate": estimate.to_dict()})
        if vtk:
            write_grid_3d(out / "grid.vtu", grid, np.nonzero(soil_cells_3d(scene, grid) >= 0)[0])
    bar = _Bar(scene) if progress else None
    machine, wall0, cpu0 = describe_machine(), time.perf_counter(), time.process_time()
    error = None
    try:
        rec = run_explicit_3d(scene, grid, pts, on_output=on_output,
                              progress=bar.update_to if bar else None)
    except _Stopped as stop:
        rec = RunRecord(scheme="explicit", time=stop.t, stop_reason=stop.reason,
                        frozen_points=np.nonzero(~pts.active)[0].tolist())
    except SimulationError as exc:
        error = exc
        rec = RunRecord(scheme="explicit", error=str(exc), stop_reason="error")
    except KeyboardInterrupt as exc:
        if out is not None:
            mark_interrupted(out, f"interrupted ({interrupt_name(exc)})")
        raise
    finally:
        if bar:
            bar.close()
    rec.wall_time, rec.cpu_time = time.perf_counter() - wall0, time.process_time() - cpu0
    measures = compute_measures_3d(pts, grid, scene.scene.frame_angle_deg,
                                   scene.montecarlo.failure_displacement,
                                   rec.time if rec.stop_reason == "at rest" else None,
                                   scene.montecarlo.intact_block_area,
                                   scene.montecarlo.failure_area)
    summary = _summary(scene, seed, pts, rec, measures, machine, estimate)
    summary["excluded_points"] = {why: {k: measures[f"excluded_{why}_{k}"]
                                        for k in ("points", "volume")}
                                  for why in ("frozen", "stray")}
    summary["dimension"] = 3
    if out is not None:
        write_json(out / "summary.json", {**summary, "files": run_files(out)})   # last
    if error is not None:
        raise error
    return RunResult(scene, seed, grid, pts, rec, measures, summary, out, times)


#: Mechanism time (s) after the start of the large-deformation phase (t = 0, or the end of a
#: geostatic phase, in which the points do not move): when the mass breaks up in the
#: literature's figure 5 (Wang et al. 2017).
MECHANISM_TIME = 3.0


#: Announced compile time (s) of the first explicit run on one thread, and the extra of the
#: threaded kernels (``threads`` >= 2, the default of a single run on an idle multi-core
#: machine), as (fastest, slowest) over the machines measured, from a fresh install or an
#: empty numba cache to the first step done (the measured figures: the documentation's
#: benchmark pages).  A warm start (cache filled) takes a few seconds; more on a loaded
#: machine.  On two cores the threaded driver compiles aside while the first steps run on
#: the serial one (:mod:`.schemes.explicit.cold_start`): little extra, more on one core.
COMPILE_SECONDS = (10.0, 40.0)
COMPILE_SECONDS_THREADED = (0.0, 10.0)
#: ... and of the serial (index 0) or threaded (1) drivers alone, when the other drivers ran
#: before (the per-half functions they share are cached).
COMPILE_SECONDS_DRIVERS = ((5.0, 10.0), (10.0, 30.0))


#: Explicit kernels every numba run calls on one thread, on two (the one-region driver's
#: worker, :mod:`.kernels.advance`) and on more (others, e.g. uGIMP or F-bar passes, only
#: some; the stress pass is made per model registry version, :func:`.kernels.material_kernels`).
_ALWAYS_COMPILED = (kernels.map_to_nodes, kernels.solve_and_move)
_ALWAYS_COMPILED_PAIR = (pair_worker,)
_ALWAYS_COMPILED_THREADED = (kernels.map_to_nodes_parallel, kernels.solve_and_move_parallel)


def _always_compiled(threads: int, fbar: bool) -> tuple:
    """The dispatchers whose cache says whether an explicit run on ``threads`` threads
    (with F-bar or not) compiles: two threads without F-bar run the one-region driver
    (:func:`.schemes.explicit.step.advance`), F-bar and more threads the driver with a
    region per stage."""
    if threads <= 1:
        return _ALWAYS_COMPILED
    return _ALWAYS_COMPILED_PAIR if pair_driver_fits(threads, fbar) else _ALWAYS_COMPILED_THREADED


def kernels_cold(threads: int = 1, fbar: bool = False) -> bool:
    """True when numba's on-disk cache holds no valid compiled version of a kernel every
    explicit run on ``threads`` threads calls (first run, or the kernels' sources changed):
    that run compiles first.  The serial and the threaded drivers are cached apart (a
    two-thread run never compiles the serial ones).  Reads numba's cache index only (no
    compilation); False if that cannot be determined."""
    try:
        for dispatcher in _always_compiled(threads, fbar):
            cache = getattr(dispatcher, "_cache", None)
            if hasattr(cache, "_cache_file") and not cache._cache_file._load_index():
                return True
    except Exception:      # noqa: BLE001 - numba internals moved: no notice, never an error
        return False
    return False


def with_run_threads(scene: Scene) -> Scene:
    """``scene`` with ``[solver] threads = 0`` (auto) replaced by the count
    :func:`.schemes.explicit.threads.auto_threads` gives now, for an explicit numba run
    (else ``scene``): resolved once, so that the compile notice and the run agree (each
    asking on its own, the count of free cores could change in between: 2 in the notice,
    1 in the run)."""
    sv = scene.solver
    if not explicit_numba(sv) or int(getattr(sv, "threads", 0)) > 0:
        return scene
    return with_value(scene, "solver.threads", auto_threads())


def compile_notice(scene: Scene) -> str | None:
    """The line announcing the one-time compile of an explicit numba run of ``scene`` on
    the threads it will use (``[solver] threads``, 0:
    :func:`.schemes.explicit.threads.auto_threads`), or None when those kernels are cached
    (or the run is not an explicit numba run)."""
    sv = scene.solver
    if not explicit_numba(sv):
        return None
    threads = int(getattr(sv, "threads", 0)) or auto_threads()
    if not kernels_cold(threads, fbar=bool(getattr(sv, "fbar", False))):
        return None
    if not kernels_cold(2 if threads <= 1 else 1):   # the other drivers' shared parts are cached
        lo, hi = COMPILE_SECONDS_DRIVERS[threads > 1]
    else:
        extra = COMPILE_SECONDS_THREADED if threads > 1 else (0.0, 0.0)
        lo, hi = COMPILE_SECONDS[0] + extra[0], COMPILE_SECONDS[1] + extra[1]
    where = "" if threads <= 1 else f" for {threads} threads"
    return (f"compiling kernels{where} (first run only, {lo:.0f}-{hi:.0f} s by the machine; "
            "cached on disk after)")


def _summary(scene, seed, pts, rec, measures, machine: dict, estimate) -> dict:
    from fem_rmpm.measures.deposit import excluded_summary  # lazy: after the time loop
    return {
        "scene": scene_to_dict(scene), "scene_file": scene.source, "seed": seed,
        "scheme": rec.scheme, "status": "failed" if rec.error else "ok", "error": rec.error,
        "stop_reason": rec.stop_reason, "steps": rec.steps, "simulated_time": rec.time,
        "wall_time": rec.wall_time, "particles": pts.n,
        "ns_per_particle_step": (1e9 * rec.wall_time / max(rec.steps * pts.n, 1)),
        # CPU time (all threads of the process) over the same span: the cost on a loaded machine
        "cpu_time": rec.cpu_time,
        "ns_per_particle_step_cpu": (1e9 * rec.cpu_time / max(rec.steps * pts.n, 1)),
        "dt_min": rec.dt_min, "dt_max": rec.dt_max,
        "frozen_points": {"count": len(rec.frozen_points), "indices": rec.frozen_points,
                          "policy": scene.solver.edge_policy},
        "measures": measures,
        "excluded_points": excluded_summary(measures) if "excluded_stray_points" in measures
        else None,
        "solver": rec.solver,
        "kinetic_energy": rec.energy[:: max(1, len(rec.energy) // 400)],
        # frictional bedrock: the energy the friction took so far (kJ/m), to the end
        **({"friction_dissipation": rec.friction[-1::-max(1, len(rec.friction) // 400)][::-1]}
           if rec.friction else {}),
        "machine": machine,         # (fem_rmpm.runtime.machine.describe at the run's start)
        "estimate": estimate.to_dict(),
    }


def _figures(out, scene, grid, snapshots, measures, label: str | None = None, rec=None):
    # lazy: matplotlib, for figures
    from fem_rmpm.io.plots import plot_energy, plot_profile, plot_snapshots
    from fem_rmpm.measures import table as measure_table  # lazy: figures only
    times = np.array([t for t, *_ in snapshots])
    mech = measures.get("mechanism_time")
    targets = list(times[-1] * np.array([0.0, 0.1, 0.25, 0.5, 1.0]))   # early failure in detail
    if mech is not None and mech <= times[-1]:
        targets.append(mech)
    pick = sorted({int(np.argmin(np.abs(times - tt))) for tt in targets})
    spacing = float(np.min(grid.cell)) / 2
    who = label or scene.scene.name
    plot_snapshots(out / "plastic_shear_strain.png", [snapshots[i] for i in pick],
                   scene.scene.frame_angle_deg, spacing, scene=scene, mechanism_time=mech,
                   title=f"{who}: plastic shear strain (" + ", ".join(
                       measure_table.value_text(k, measures[k], ".1f")
                       for k in ("runout_distance", "sliding_area")) + ")")
    plot_profile(out / "profile.png", measures["initial_profile"], measures["final_profile"],
                 title=f"{who}: surface before and after", scene=scene)
    if rec is not None and rec.friction:          # frictional bedrock
        plot_energy(out / "energy.png", rec.energy, rec.friction,
                    title=f"{who}: kinetic energy and frictional dissipation")


def fem(scene: Scene, out: str | Path | None = None, *, force: bool = False) -> FemResult:
    """Static small-strain FEM reference (scikit-fem); writes ``fem.vtu`` and a summary.

    ``out`` follows :func:`run`'s rule: a new or empty directory, or ``force=True``
    replaces the run in it (:mod:`fem_rmpm.io.rundir`)."""
    t0 = time.perf_counter()
    refuse_frictional(scene, "the static FEM reference")     # (no contact there)
    if out is not None:
        check_run_dir(out, force)
    check_budget(scene)
    if scene.grid.dimension == 3:
        return _fem_3d(scene, out, t0)
    import meshio  # lazy: fem only

    from fem_rmpm.schemes.fem import solve_static  # lazy: fem only
    res = solve_static(scene)
    if out is not None:
        out = start_run_dir(out, {"scene": scene_to_dict(scene), "scene_file": scene.source,
                                  "scheme": "fem"})
        used = np.unique(res.grid.cells[res.cells])
        remap = -np.ones(res.grid.n_nodes, dtype=np.int64)
        remap[used] = np.arange(len(used))
        s = res.stress.reshape(len(res.cells), -1, 4).mean(axis=1)
        stress6 = np.column_stack([s[:, 0], s[:, 1], s[:, 2], s[:, 3], 0 * s[:, 0], 0 * s[:, 0]])
        u = np.column_stack([res.displacement[used], np.zeros(len(used))])
        mesh = meshio.Mesh(np.column_stack([res.grid.nodes[used], np.zeros(len(used))]),
                           [("quad", remap[res.grid.cells[res.cells]])],
                           point_data={"displacement": u}, cell_data={"stress": [stress6]})
        mesh.write(out / "fem.vtu", binary=True)
        write_json(out / "summary.json", {
            "scene": scene_to_dict(scene), "scene_file": scene.source, "scheme": "fem",
            "elements": int(len(res.cells)), "dofs": int(2 * len(used)),
            "max_displacement": float(np.abs(res.displacement).max()),
            "min_sigma_yy": float(res.stress[:, 1].min()), "wall_time": time.perf_counter() - t0,
            "status": "ok", "files": run_files(out)})
    return res


def _fem_3d(scene: Scene, out, t0: float) -> Fem3DResult:
    """:func:`fem` of a three-dimensional scene (:mod:`fem_rmpm.schemes.fem3d`): the
    soil hexahedra with their displacement and mean Gauss-point stress in ``fem.vtu``."""
    import meshio  # lazy: fem only

    from fem_rmpm.io.output3d import VTK_HEX_ORDER  # lazy: 3-D fem only
    from fem_rmpm.schemes.fem3d import solve_static_3d  # lazy: 3-D fem only
    res = solve_static_3d(scene)
    if out is None:
        return res
    out = start_run_dir(out, {"scene": scene_to_dict(scene), "scene_file": scene.source,
                              "scheme": "fem"})
    conn = res.grid.cells[res.cells][:, VTK_HEX_ORDER]
    used = np.unique(conn)
    remap = -np.ones(res.grid.n_nodes, dtype=np.int64)
    remap[used] = np.arange(len(used))
    stress = res.stress.reshape(len(res.cells), -1, 6).mean(axis=1)
    meshio.Mesh(res.grid.nodes[used], [("hexahedron", remap[conn])],
                point_data={"displacement": res.displacement[used]},
                cell_data={"stress": [stress]}).write(out / "fem.vtu", binary=True)
    write_json(out / "summary.json", {
        "scene": scene_to_dict(scene), "scene_file": scene.source, "scheme": "fem",
        "dimension": 3, "elements": int(len(res.cells)), "dofs": int(3 * len(used)),
        "max_displacement": float(np.abs(res.displacement).max()),
        "min_sigma_yy": float(res.stress[:, 1].min()), "wall_time": time.perf_counter() - t0,
        "status": "ok", "files": run_files(out)})
    return res


def factor_of_safety(scene: Scene, seed: int | None = None, out: str | Path | None = None,
                     **options):
    """Factor of safety by strength reduction (:mod:`fem_rmpm.schemes.implicit.strength_reduction`)
    of the realization ``seed``; ``options`` are
    :class:`~fem_rmpm.schemes.implicit.strength_reduction.FSOptions` fields (``tolerance=0.005``,
    ``softening=False``, ...).  Writes ``fs.json``,
    ``fs_displacement.png`` and the mechanism (``mechanism.vtu``/``.png``) to ``out`` if
    given.  Returns an :class:`~fem_rmpm.schemes.implicit.strength_reduction.FSResult` (``.fs``,
    ``.text``)."""
    if scene.grid.dimension == 3:
        raise SceneError(f"{scene.source}: [grid.size] a three-dimensional scene; allowed: "
                         "a plane-strain scene for the factor of safety (the implicit "
                         "strength reduction is plane strain only)")
    from fem_rmpm.schemes.implicit import strength_reduction  # lazy: fs only
    grid, pts = prepare(scene, seed)
    res = strength_reduction.factor_of_safety(
        scene, seed=seed, options=strength_reduction.FSOptions(**options), grid=grid, pts=pts)
    if out is not None:
        strength_reduction.write_outputs(res, scene, out)
    return res


class _Bar:
    REFRESH = 0.1        # s between two draws of the bar (tqdm's own mininterval)

    def __init__(self, scene: Scene):
        self.drawn = -float("inf")
        self.t_end = scene.solver.t_end
        self.bar = tqdm(total=round(self.t_end, 6), unit="s sim", desc=scene.scene.name,
                        bar_format="{l_bar}{bar}| {n:.2f}/{total:.2f} s "
                                   "[{elapsed}<{remaining}] {postfix}")

    def update_to(self, t: float, step: int) -> None:
        """Show time ``t`` (s) and ``step``; drawn at most every ``REFRESH`` s of wall time
        (a draw costs ~0.3 ms: at every 20th step, 0.2 s of a 9 s run, measured)."""
        self.bar.n = round(min(t, self.t_end), 6)
        self.bar.set_postfix_str(f"step {step}", refresh=False)
        now = time.perf_counter()
        if now - self.drawn >= self.REFRESH:
            self.drawn = now
            self.bar.refresh()

    def close(self):
        self.bar.close()

