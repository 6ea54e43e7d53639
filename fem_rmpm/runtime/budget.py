"""Size and cost of a run, estimated from the scene alone, before anything is allocated.

:func:`estimate_run` returns a :class:`RunEstimate`: material points, grid cells and
nodes, peak memory, time steps and an approximate wall time.  It uses arithmetic on
the scene only (polygon areas, grid size, CFL step), so it takes microseconds even
for a grid of 10^10 cells.  :func:`check_budget` refuses a run whose memory estimate
exceeds the limit (:func:`memory_limit_bytes`) with :class:`BudgetError`, a
:class:`~fem_rmpm.scene.SceneError` (exit 2 on the command line) whose one-line
message carries the estimate.

How the figures are made (all approximate; the run's own ``summary.json`` has the
real ones):

* points = sum over soils of (polygon area inside the grid) / (hx hy) x n^2, with
  n = ``points_per_cell_dir`` (a cell is soil when its centre is inside the polygon,
  so the count is within one cell row of the boundary of this);
* nodes = (nx + 1)(ny + 1), cells = nx ny: the whole rectangle is allocated;
* memory = :data:`BASE_BYTES` (the interpreter with numpy, scipy, numba, scikit-fem)
  + :data:`BYTES_PER_CELL` x cells + :data:`BYTES_PER_POINT` x points (uGIMP:
  + :data:`BYTES_PER_POINT_GIMP`, the factors its basis keeps) + 24 B per
  point per kept snapshot (position and plastic strain, one snapshot per
  ``output_interval`` up to ``t_end``).  The per-item constants are fitted to
  ``tracemalloc`` peaks of seeding plus the explicit workspace;
* explicit steps = ``t_end / dt`` with the CFL step at rest
  ``dt = cfl h_min / c_p``, c_p = sqrt(M / rho) the largest P-wave speed of the
  soils (M the constrained modulus, rho = unit weight / g).  Moving points shorten
  the step and a run that comes to rest stops early; :data:`STEPS_FACTOR` is the
  mean ratio of the steps taken to this count on the reference slope;
* implicit steps = ``load_steps`` (quasi-static) or ``t_end / dt`` (dynamic);
* wall time = steps x :data:`STEPS_FACTOR` (explicit) x points x the cost per
  point-step on one thread / the threads' speed-up (:data:`THREAD_EFFICIENCY` x
  threads, for more than one; the explicit numba step only).  The explicit numba
  cost is the whole-run figure of the reference slope case (i) on one thread, measured
  on the CPU of the run (:data:`EXPLICIT_NS_BY_CPU`, chosen by
  :func:`fem_rmpm.runtime.machine.cpu_signature`); on a CPU not in the table the
  estimate takes the slowest figure and says so.  uGIMP, F-bar and a Mohr-Coulomb soil
  multiply it by their factors in :data:`NS_PER_POINT_STEP`; the numpy kernel and the
  implicit scheme have figures of their own there (the implicit one from a dynamic run
  of the reference slope on a shared core, so it may be high on an idle machine).
  The numba compile of a first run (cached on disk after) is not included.

The figures behind the constants, with the date, commit and machine of each
measurement, are on the benchmarks page of the documentation.
"""
from __future__ import annotations

import math
import os
from dataclasses import asdict, dataclass

from fem_rmpm.discretise.grid import _grid_from_file
from fem_rmpm.runtime.budget3d import estimate_run_3d
from fem_rmpm.runtime.machine import cpu_signature
from fem_rmpm.scene import Scene, SceneError

__all__ = ["RunEstimate", "BudgetError", "estimate_run", "check_budget",
           "memory_limit_bytes", "MEMORY_LIMIT_ENV", "STEPS_FACTOR", "THREAD_EFFICIENCY",
           "explicit_numba", "thread_speed_up", "explicit_cost", "EXPLICIT_NS_BY_CPU"]

#: Environment variable that sets the memory limit in GiB (default: 75 % of the RAM).
MEMORY_LIMIT_ENV = "FEM_RMPM_MEMORY_LIMIT_GB"
BASE_BYTES = 200e6          # interpreter + numpy/scipy/numba/scikit-fem (resident set ~190 MB)
BYTES_PER_CELL = 277.0      # mesh nodes and cells, node flags, seeding temporaries, workspace
#                             (129 B of it: the second half's nodal arrays of the kernels)
BYTES_PER_POINT = 324.0     # point state (Particles) + explicit workspace per point (the
#                             stress pass's scratch is per block, not per point)
BYTES_PER_POINT_SNAPSHOT = 24.0
BYTES_PER_POINT_GIMP = 112.0  # uGIMP: each point's basis factors kept from the map to nodes
#: Whole-run cost per point-step (ns) by (scheme, kernel or shape); see the module docstring.
#: The explicit numba step's own figure depends on the machine: :data:`EXPLICIT_NS_BY_CPU`.
NS_PER_POINT_STEP = {"explicit_gimp_factor": 2.3, "explicit_fbar_factor": 1.4,
                     "explicit_mohr_coulomb_factor": 1.7, "explicit_numpy": 2700.0,
                     "implicit": 35000.0}
#: Whole-run ns per point-step of case (i), explicit numba step, one thread, by the CPU's
#: (vendor_id, cpu family, model) (:func:`fem_rmpm.runtime.machine.cpu_signature`), with the
#: machine it was measured on (a virtual machine may name its CPU only "Intel Xeon" or
#: "AMD EPYC").
EXPLICIT_NS_BY_CPU = {
    ("GenuineIntel", 6, 167): (39.0, "idle 2-core Intel Xeon VM"),
    ("AuthenticAMD", 23, 1): (104.0, "idle 2-core AMD EPYC VM, Zen 1"),
    ("AuthenticAMD", 25, 17): (53.0, "idle 2-core AMD EPYC VM, Zen 4"),
}
#: Steps taken / the CFL count at rest (t_end / dt): the mean over realizations of the
#: reference slope.  Explicit runs only.
STEPS_FACTOR = 1.30
#: Wall-time speed-up of one explicit realization per numba thread, for N > 1 threads (two
#: threads run case (i) of the reference slope about 1.8x as fast as one).
THREAD_EFFICIENCY = 0.9
COST_MACHINE = {"implicit": "shared 2-core AMD EPYC VM",
                "explicit_numpy": "idle 2-core Intel Xeon VM"}


class BudgetError(SceneError):
    """The run is larger than the memory limit (its message carries the estimate)."""


@dataclass(frozen=True)
class RunEstimate:
    """Approximate size and cost of one run (see the module docstring for how)."""
    scheme: str
    points: int
    cells: int
    nodes: int
    memory_bytes: float      # peak, B
    dt: float                # s, explicit CFL step at rest (implicit: the step)
    steps: int               # t_end / dt at rest (implicit: the steps); see steps_factor
    ns_per_point_step: float  # one thread
    wall_time: float         # s, approximate (steps x steps_factor x points x cost / speed-up)
    machine: str = ""        # where the cost per point-step was measured
    threads: int = 1         # numba threads the wall time is for (explicit numba step)
    steps_factor: float = 1.0  # steps taken per step counted at rest (explicit: STEPS_FACTOR)

    def describe(self) -> str:
        """One line for the start of a run."""
        moving = (f" at rest, x{self.steps_factor:.3g} on a failing slope"
                  if self.steps_factor != 1.0 else "")
        on = f" on {self.threads} threads" if self.threads > 1 else ""
        return (f"estimate: {self.points:,} material points, {self.nodes:,} grid nodes, "
                f"{_fmt_bytes(self.memory_bytes)} memory, {self.steps:,} {self.scheme} "
                f"steps of {self.dt:.3g} s{moving}, about {_fmt_time(self.wall_time)} wall"
                f"{on} ({self.ns_per_point_step:.0f} ns per point-step on one thread, "
                f"{self.machine})")

    def to_dict(self) -> dict:
        return asdict(self)


def _fmt_bytes(b: float) -> str:
    for unit, f in (("TiB", 2**40), ("GiB", 2**30), ("MiB", 2**20)):
        if b >= f:
            return f"{b / f:.3g} {unit}"
    return f"{b / 2**10:.3g} KiB"


def _fmt_time(s: float) -> str:
    if s >= 86400:
        return f"{s / 86400:.3g} days"
    if s >= 3600:
        return f"{s / 3600:.3g} h"
    if s >= 60:
        return f"{s / 60:.3g} min"
    return f"{s:.2g} s"


def _polygon_area(poly, lo, hi) -> float:
    """Area (m2) of ``poly`` clipped to the rectangle [lo, hi] (Sutherland-Hodgman)."""
    pts = [tuple(p) for p in poly]
    for axis, bound, keep_below in ((0, lo[0], False), (0, hi[0], True),
                                    (1, lo[1], False), (1, hi[1], True)):
        out = []
        for k, cur in enumerate(pts):
            prev = pts[k - 1]
            cin = (cur[axis] <= bound) if keep_below else (cur[axis] >= bound)
            pin = (prev[axis] <= bound) if keep_below else (prev[axis] >= bound)
            if cin != pin:
                t = (bound - prev[axis]) / (cur[axis] - prev[axis])
                out.append(tuple(prev[i] + t * (cur[i] - prev[i]) for i in range(2)))
            if cin:
                out.append(cur)
        pts = out
        if not pts:
            return 0.0
    return 0.5 * abs(sum(pts[k - 1][0] * p[1] - p[0] * pts[k - 1][1] for k, p in enumerate(pts)))


def _grid_geometry(scene: Scene):
    """(origin, cell, (nx, ny)) without building the mesh."""
    if scene.grid.file is not None:
        origin, cell, shape = _grid_from_file(scene.grid.file, scene.source)
        return tuple(map(float, origin)), tuple(map(float, cell)), tuple(map(int, shape))
    cell = scene.grid.cell
    shape = (int(round(scene.grid.size[0] / cell[0])), int(round(scene.grid.size[1] / cell[1])))
    return scene.grid.origin, cell, shape


def _p_wave_speed(scene: Scene) -> float:
    g = scene.scene.gravity if scene.scene.gravity > 0 else 9.81
    return max(math.sqrt(s.constrained_modulus / (s.unit_weight / g)) for s in scene.soils)


def explicit_cost(cpu: tuple[str, int, int] | None) -> tuple[float, str]:
    """(ns per point-step, machine) of the explicit numba step of case (i) on one thread for
    a CPU ``cpu`` = (vendor_id, cpu family, model): its measured figure, else the slowest
    of :data:`EXPLICIT_NS_BY_CPU`, with the machine saying so."""
    if cpu in EXPLICIT_NS_BY_CPU:
        return EXPLICIT_NS_BY_CPU[cpu]
    ns, machine = max(EXPLICIT_NS_BY_CPU.values())
    return ns, f"the slowest machine measured, an {machine}; this CPU was not measured"


def _cost(scene: Scene, cpu) -> tuple[float, str]:
    sv = scene.solver
    if sv.scheme == "implicit":
        return NS_PER_POINT_STEP["implicit"], COST_MACHINE["implicit"]
    if getattr(sv, "kernel", "numba") == "numpy":
        return NS_PER_POINT_STEP["explicit_numpy"], COST_MACHINE["explicit_numpy"]
    ns, machine = explicit_cost(cpu)
    if sv.shape == "gimp":
        ns *= NS_PER_POINT_STEP["explicit_gimp_factor"]
    if sv.fbar:
        ns *= NS_PER_POINT_STEP["explicit_fbar_factor"]
    if any(s.model.startswith("mohr_coulomb") for s in scene.soils):
        ns *= NS_PER_POINT_STEP["explicit_mohr_coulomb_factor"]
    return ns, machine


def explicit_numba(sv) -> bool:
    """Whether the ``[solver]`` section ``sv`` runs the explicit scheme's numba kernels."""
    return sv.scheme == "explicit" and getattr(sv, "kernel", "numba") == "numba"


def thread_speed_up(threads: int) -> float:
    """Wall-time speed-up of one explicit realization on ``threads`` numba threads."""
    return THREAD_EFFICIENCY * threads if threads > 1 else 1.0


def _threads(scene: Scene) -> int:
    """The numba threads of an explicit numba run, ``[solver] threads`` (1 when 0, auto:
    a run resolves it before estimating; elsewhere 1)."""
    sv = scene.solver
    return max(int(getattr(sv, "threads", 0)), 1) if explicit_numba(sv) else 1


def estimate_run(scene: Scene, cpu: tuple[str, int, int] | None = None) -> RunEstimate:
    """Estimate points, nodes, memory, steps and wall time of one run of ``scene`` on a CPU
    ``cpu`` = (vendor_id, cpu family, model) (default: this machine's,
    :func:`fem_rmpm.runtime.machine.cpu_signature`; it sets the explicit step's cost only).
    A three-dimensional scene: :func:`fem_rmpm.runtime.budget3d.estimate_run_3d`."""
    if scene.grid.dimension == 3:
        return RunEstimate(**estimate_run_3d(scene))
    origin, cell, (nx, ny) = _grid_geometry(scene)
    hi = (origin[0] + cell[0] * nx, origin[1] + cell[1] * ny)
    cell_area = cell[0] * cell[1]
    points = int(round(sum(_polygon_area(s.polygon, origin, hi) / cell_area
                           * s.points_per_cell_dir ** 2 for s in scene.soils)))
    cells, nodes = nx * ny, (nx + 1) * (ny + 1)
    sv = scene.solver
    if sv.scheme == "implicit":
        dt = sv.dt if sv.dynamic else 1.0 / sv.load_steps
        steps = math.ceil(sv.t_end / sv.dt) if sv.dynamic else sv.load_steps
    else:
        dt = sv.cfl * min(cell) / _p_wave_speed(scene)
        steps = math.ceil(sv.t_end / dt)
    snapshots = (math.floor(sv.t_end / sv.output_interval) + 2) if sv.scheme == "explicit" \
        or sv.dynamic else steps + 1
    per_point = BYTES_PER_POINT + (BYTES_PER_POINT_GIMP if sv.shape == "gimp" else 0.0)
    memory = (BASE_BYTES + BYTES_PER_CELL * cells + per_point * points
              + BYTES_PER_POINT_SNAPSHOT * points * snapshots)
    ns, machine = _cost(scene, cpu_signature() if cpu is None else cpu)
    threads, factor = _threads(scene), (STEPS_FACTOR if sv.scheme == "explicit" else 1.0)
    return RunEstimate(scheme=sv.scheme, points=points, cells=cells, nodes=nodes,
                       memory_bytes=float(memory), dt=float(dt), steps=int(steps),
                       ns_per_point_step=ns,
                       wall_time=steps * factor * points * ns * 1e-9 / thread_speed_up(threads),
                       machine=machine, threads=threads, steps_factor=factor)


def memory_limit_bytes() -> float:
    """The memory limit (B): ``$FEM_RMPM_MEMORY_LIMIT_GB`` GiB, else 75 % of the RAM."""
    raw = os.environ.get(MEMORY_LIMIT_ENV)
    if raw:
        try:
            gb = float(raw)
        except ValueError:
            gb = float("nan")
        if not (gb > 0 and math.isfinite(gb)):
            raise SceneError(f"${MEMORY_LIMIT_ENV}: [] {raw!r} is not a memory size; allowed: "
                             "a positive number of GiB, e.g. 8")
        return gb * 2**30
    try:
        ram = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):   # pragma: no cover - non-POSIX
        ram = 8 * 2**30
    return 0.75 * ram


def check_budget(scene: Scene, limit_bytes: float | None = None) -> RunEstimate:
    """The estimate of ``scene``; raises :class:`BudgetError` if its memory exceeds
    ``limit_bytes`` (default :func:`memory_limit_bytes`)."""
    est = estimate_run(scene)
    limit = memory_limit_bytes() if limit_bytes is None else float(limit_bytes)
    if est.memory_bytes > limit:
        raise BudgetError(
            f"{scene.source}: [grid.cell] run too large: {est.describe()}; this exceeds "
            f"the memory limit of {_fmt_bytes(limit)}; allowed: a coarser [grid] cell (now "
            f"{list(scene.grid.cell)} m), a smaller grid, or a higher limit with "
            f"{MEMORY_LIMIT_ENV}=<GiB>")
    return est
