"""Size and cost of a three-dimensional run from the scene alone (the 3-D branch of
:func:`fem_rmpm.runtime.budget.estimate_run`): arithmetic on the scene, no allocation, so a
scene of 10^12 cells is refused at once.

* points = sum over soils of (section area inside the grid) x (strike length inside the
  grid) / (hx hy hz) x n^3 (n = ``points_per_cell_dir``); a ``plan`` shape is not
  subtracted, so with one this is an upper bound;
* nodes = (nx + 1)(ny + 1)(nz + 1), cells = nx ny nz (the whole box is allocated);
* memory = :data:`BASE_BYTES` + :data:`BYTES_PER_NODE_3D` x nodes +
  :data:`BYTES_PER_POINT_3D` x points (no positions kept per snapshot in 3-D);
* steps = ``t_end / dt`` with ``dt = cfl h_min / c_p``, wall time = steps x points x
  :data:`NS_PER_POINT_STEP_3D` (one thread).
"""
from __future__ import annotations

import math

import numpy as np

from fem_rmpm.scene import Scene
from fem_rmpm.scene.dimension import strike_range

__all__ = ["estimate_run_3d", "BYTES_PER_POINT_3D", "BYTES_PER_NODE_3D",
           "NS_PER_POINT_STEP_3D", "BASE_BYTES"]

#: The interpreter with numpy, scipy, numba, scikit-fem (as the plane-strain estimate).
BASE_BYTES = 200e6

#: Point state of :class:`fem_rmpm.discretise.points3d.Particles3D` (positions, velocity,
#: strain, stress, Lame constants, material rows), the step's per-point arrays (the elastic
#: stretch b, the cell and local coordinates, the Lame columns), the seeding, the measures'
#: temporaries and the compiled step's code: set so that the estimate meets the peak
#: resident set of a one-thread run of the extruded slab (279 MiB with its 36 448 points
#: and 112 065 nodes, ``fem-rmpm run`` to 2 s, measured 2026-12-07 at commit 6e3a6e4).
BYTES_PER_POINT_3D = 1540.0
#: Per node: fixed flags, the step's nodal rows (two halves of 8 numbers and their totals,
#: 24 numbers; node flags and lists), coordinates and cell tables built for the output and
#: the FEM reference.
BYTES_PER_NODE_3D = 330.0
#: Whole-run cost per point-step of the 3-D explicit step, one thread (ns of CPU): the
#: extruded reference slope with von Mises softening (``meshes/slope_extruded_3d.toml``,
#: 36 448 points: first 12 s 152-160 ns over five runs, to rest (13 172 steps) 152 ns, the
#: kernels' load from numba's cache included), measured 2026-12-07 at commit 598df98 on a
#: quiet 2-core AMD EPYC VM (Zen 4, load average 1.2-1.8); 163-172 ns on the same VM
#: loaded (load average 2.5-3.5) (``validation/bench_explicit_3d.py`` re-measures it).
NS_PER_POINT_STEP_3D = 170.0
#: The same for a scene whose soils are all linear elastic (no return mapping, no
#: eigen-decomposition in the geostatic phase): ``meshes/slope_elastic_3d.toml``, 6656
#: points, 528 steps to rest, 156-178 ns per point-step on the same machine and commit.
NS_PER_POINT_STEP_3D_ELASTIC = 170.0


def _cost_3d(scene: Scene) -> tuple[float, str]:
    """(ns per point-step on one thread, what it was measured on) of a 3-D scene: the
    elastic figure when every soil is linear elastic, else the von Mises one."""
    where = "loaded 2-core AMD EPYC VM, Zen 4"
    if all(s.model == "linear_elastic" for s in scene.soils):
        return NS_PER_POINT_STEP_3D_ELASTIC, f"3-D step, linear elastic slope, {where}"
    return NS_PER_POINT_STEP_3D, f"3-D step, von Mises slab, {where}"


def _clipped_area(poly, lo, hi) -> float:
    """Area (m2) of ``poly`` (x, y) inside the rectangle [lo, hi] (clipped one side at a
    time, Sutherland-Hodgman)."""
    pts = np.asarray(poly, dtype=float)
    for axis, bound, sign in ((0, lo[0], 1), (0, hi[0], -1), (1, lo[1], 1), (1, hi[1], -1)):
        if len(pts) == 0:
            return 0.0
        d = sign * (pts[:, axis] - bound)              # >= 0: kept
        prev, dprev = np.roll(pts, 1, axis=0), np.roll(d, 1)
        out = []
        for p, q, dp, dq in zip(prev, pts, dprev, d):
            if (dp >= 0) != (dq >= 0):
                out.append(p + (q - p) * (dp / (dp - dq)))
            if dq >= 0:
                out.append(q)
        pts = np.array(out).reshape(-1, 2)
    x, y = pts[:, 0], pts[:, 1]
    return 0.5 * abs(float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))))


def estimate_run_3d(scene: Scene) -> dict:
    """The fields of the :class:`fem_rmpm.runtime.budget.RunEstimate` of a
    three-dimensional explicit run (module docstring)."""
    g = scene.grid
    shape = [int(round(g.size[k] / g.cell[k])) for k in range(3)]
    lo = g.origin
    hi = [lo[k] + g.cell[k] * shape[k] for k in range(3)]
    cell_volume = g.cell[0] * g.cell[1] * g.cell[2]
    points = 0.0
    for s in scene.soils:
        z0, z1 = strike_range(scene, s)
        length = max(min(z1, hi[2]) - max(z0, lo[2]), 0.0)
        area = _clipped_area(s.polygon, lo[:2], hi[:2])
        points += area * length / cell_volume * s.points_per_cell_dir ** 3
    points = int(round(points))
    cells = shape[0] * shape[1] * shape[2]
    nodes = (shape[0] + 1) * (shape[1] + 1) * (shape[2] + 1)
    sv = scene.solver
    gravity = scene.scene.gravity if scene.scene.gravity > 0 else 9.81
    c_p = max(math.sqrt(s.constrained_modulus / (s.unit_weight / gravity)) for s in scene.soils)
    dt = sv.cfl * min(g.cell) / c_p
    steps = math.ceil(sv.t_end / dt)
    memory = BASE_BYTES + BYTES_PER_NODE_3D * nodes + BYTES_PER_POINT_3D * points
    ns, machine = _cost_3d(scene)
    return dict(scheme="explicit", points=points, cells=cells, nodes=nodes,
                memory_bytes=float(memory), dt=float(dt), steps=int(steps),
                ns_per_point_step=ns, wall_time=steps * points * ns * 1e-9,
                machine=machine, threads=1)
