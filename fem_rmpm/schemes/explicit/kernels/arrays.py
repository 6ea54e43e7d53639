"""The argument groups of the compiled explicit step (named tuples numba accepts).

Every kernel takes some of five groups instead of a long positional list:

* :class:`Mesh` — the structured grid: lower-left corner, cell size and its inverse,
  cells per direction, the grid rectangle and the fixed node components;
* :class:`PointArrays` — the state of the material points (positions, velocities, mass,
  volume, stress, deformation, the material model id, parameter row and state);
* :class:`NodeArrays` — the nodal arrays of one step (mass, momentum, force, velocities)
  and the list of the nodes the points touch;
* :class:`Scratch` — per-point and per-cell work arrays, and the step's statistics;
* :class:`StepOptions` — the scalars of one step (dt, gravity, damping, FLIP, phase, basis).

Field access of a named tuple is resolved when numba compiles, so grouping costs nothing
per point; building the tuples costs a few microseconds per step.
"""
from __future__ import annotations

from collections import namedtuple
from dataclasses import dataclass, field

import numpy as np
from numba import typeof

from fem_rmpm.materials.dispatch import takes_blocks
from fem_rmpm.materials.protocol import BLOCK_COLUMNS, BLOCK_ROWS
from fem_rmpm.schemes.explicit.kernels.common import BLOCK, QUEUE_STRIDE

CHUNKS = 64          # the most chunks (threads) of the stress pass

__all__ = ["Mesh", "PointArrays", "NodeArrays", "Scratch", "StepOptions", "Workspace",
           "mesh_of", "point_arrays", "scratch_for", "node_arrays", "top_of"]

#: No pore water: the empty segment table and frame of :class:`Mesh` (water: the
#: :class:`fem_rmpm.schemes.pore_pressure.WaterTable`'s arrays).
DRY = (np.zeros((0, 6)), np.zeros(4))
#: No frictional bedrock: the contact fields of :class:`Mesh`.
NO_CONTACT = (False, np.zeros(0, np.uint8), np.zeros(0), np.zeros(0), np.zeros(0), np.zeros(3))

Mesh = namedtuple("Mesh", "o0 o1 h0 h1 ih0 ih1 nx ny lo hi fixed has_contact contact_on "
                         "contact_n contact_mu contact_c contact_work water frame",
                 defaults=NO_CONTACT + DRY)
Mesh.__doc__ = """Structured grid: origin (m), cell size h and 1/h, cells nx x ny, the grid
rectangle ``lo``, ``hi`` (2,) (m) and the fixed node components ``fixed`` (2 nn,) bool,
interleaved as the nodal vectors of :class:`NodeArrays`; frictional bedrock
(:mod:`fem_rmpm.discretise.contact`, :mod:`.contact`): ``has_contact``, and per node the
contact flag (nn,) uint8, outward normal (2 nn,), friction and adhesion force (nn,) (kN/m),
``contact_work`` (3,) the frictional dissipation of each half of the points (kJ/m) and
the step's dt (s) (empty arrays without frictional bedrock); the pore water's ``water``
segments (k, 6) and ``frame`` (4,) (:mod:`fem_rmpm.schemes.pore_pressure`; no rows: dry)."""

PointArrays = namedtuple("PointArrays", "x v mass vol vol0 stress active half_width "
                                        "log_strain state u_geo model params")
PointArrays.__doc__ = """Material points: x, v (n, 2) m, m/s; mass (n,) t; vol, vol0 (n,)
m3/m; Cauchy stress (n, 4) kPa; active (n,) bool; uGIMP half widths (n, 2) m;
elastic log strain (n, 4); model state (n, S); geostatic displacement u_geo (n, 2) m;
model id (n,) and parameter rows (n, P) (:mod:`fem_rmpm.materials`)."""

NodeArrays = namedtuple("NodeArrays",
                        "m p f v_new acc v_remap v_musl flag touched n_touched half",
                        defaults=(None,))
NodeArrays.__doc__ = """The nodal arrays of one half of the points (:mod:`.transfer`): mass
(nn,), momentum, internal force (gravity is added in the solve), end-of-step velocity and
acceleration, the MUSL re-mapped momentum ``v_remap`` and the velocity from it ``v_musl``
(2 nn,): x and y of node ``a`` at ``2 a`` and ``2 a + 1`` (:func:`.common.xy`; the same
memory as C-ordered (nn, 2)); ``flag`` (nn,) uint8 touched by the half this step,
``touched[:n_touched[0]]`` (uint64) those nodes; ``half``: the same arrays of the second
half of the points (in the first half's group; None in the second's).  Flat, not (nn, 2):
numba addresses ``v[a, k]`` of a C-ordered 2-D array as ``(a * shape[1] + k) * 8`` with
``shape[1]`` read at run time, an integer multiply per node and array that ``v[2 a + k]``
does without (seen in the map's machine code; the run bitwise the same)."""

Scratch = namedtuple("Scratch",
                     "x_old W ta tb tc host D cell_v cell_vdj out parts halves q4_ll q4_st queue Z "
                     "gimp_ij gimp_w")
Scratch.__doc__ = """Work arrays: positions before the move (n, 2); the block scratch of the
stress pass, one row per chunk (thread) of :data:`CHUNKS`: W (CHUNKS, 8, :data:`W_COLUMNS`),
per point of a block (its first BLOCK columns) the trial state in rows 0-3 and the
kinematics' work rows 4-7, and the arguments / values of the vectorised Hencky series ta,
tb, tc (CHUNKS, :data:`SERIES_COLUMNS`) (:mod:`.stress`, :mod:`.strain`; laid out in pages
by :func:`scratch_for`); F-bar host cells (n,), increments D
(n, 4) and per-cell sums of V and V dJ (n_cells,); ``out`` (4,) = largest P-wave speed,
largest point speed, non-finite and outside points, ``parts`` (CHUNKS, 2) per chunk of the
stress pass: the largest squared P-wave speed and the points with a non-finite stress;
``halves`` (2, 5) per half of the points from the map back: grid kinetic energy (2x), the
largest squared |v_pic| and |v|, the points with a non-finite x or v and those outside the
grid; ``q4_ll`` (n,) int64 and ``q4_st`` (n, 2): each point's Q4 cell (lower-left node) and
local coordinates, found by the map to nodes and reused by the later passes of the step (the
points have not moved in between); ``queue`` (3 QUEUE_STRIDE,) int64: at 0 and
:data:`.common.QUEUE_STRIDE` the next block of the stress pass's two work queues, one per
half of the points, and :data:`.common.QUEUE_FLAG` after each the flag of that half's
published nodal velocities (:func:`.stress._stress_queue_call`), at
:data:`.common.QUEUE_BARRIER` the two-thread driver's barrier counter (:mod:`.advance`; the
padding puts each on a cache line of its own); ``Z`` (CHUNKS, BLOCK_ROWS, BLOCK_COLUMNS of
:mod:`fem_rmpm.materials.protocol`): per chunk the block scratch of a material's vectorised
update (trial strains in, strains and Kirchhoff stress out; :mod:`.stress`); ``gimp_ij``
(n, 2) int64 and ``gimp_w`` (n, 12): each point's uGIMP basis factors from the map to
nodes (:func:`.basis.gimp_store`; none in a Q4 run: :meth:`Workspace.bind`)."""

StepOptions = namedtuple("StepOptions",
                         "dt gx gy damping flip geostatic gimp fbar threads model block",
                         defaults=(1, -1, False))
StepOptions.__doc__ = """One step: dt (s), gravity (m/s2), local damping (-), FLIP fraction
(-), geostatic (small strain, points fixed), gimp (uGIMP basis), fbar (F-bar remedy),
threads (2 or more: the two halves of the points on two threads, the stress pass in up
to that many chunks), model (the one material model id of all points, -1 if they mix
models: selects the stress pass compiled for that model alone,
:func:`.stress.material_kernels`), block (that model's vectorised ``block_update`` takes
the points: :func:`fem_rmpm.materials.dispatch.takes_blocks`)."""


_TOP = (None, None)


def top_of(N: NodeArrays) -> NodeArrays:
    """``N._replace(half=None)`` (the threaded kernels take no nested group), made once
    per node arrays (~0.9 us each time otherwise, three times per threaded step).  The
    last pair is one tuple, read and replaced whole: steps of two runs interleaving on
    threads of one process at most rebuild it, never mix them."""
    global _TOP
    last = _TOP
    if last[0] is N:
        return last[1]
    top = N._replace(half=None)
    _TOP = (N, top)
    return top


def mesh_of(grid, water=None) -> Mesh:
    """The :class:`Mesh` of a :class:`fem_rmpm.discretise.grid.Grid`; ``water``: a
    :class:`fem_rmpm.schemes.pore_pressure.WaterTable` (None: dry)."""
    (o0, o1), (h0, h1), (nx, ny) = grid.origin, grid.cell, grid.shape
    cn = getattr(grid, "contact", None)
    contact = (True, *cn.dense(grid.n_nodes), cn.work) if cn is not None else NO_CONTACT
    wet = DRY if water is None else (water.segments, water.frame)
    return Mesh(float(o0), float(o1), float(h0), float(h1), 1.0 / h0, 1.0 / h1, int(nx),
                int(ny), np.asarray(grid.origin, float), np.asarray(grid.upper, float),
                np.ascontiguousarray(grid.fixed).reshape(-1), *contact, *wet)


def point_arrays(pts, fallback_half_width: np.ndarray) -> PointArrays:
    """The :class:`PointArrays` view of a :class:`fem_rmpm.discretise.points.Particles` (no copy).
    Raises ValueError unless every array has the column count the kernels assume
    (:func:`.common.fixed_columns`)."""
    lp = pts.half_width if pts.half_width is not None else fallback_half_width
    s = pts.soil
    P = PointArrays(pts.x, pts.velocity, pts.mass, pts.volume, pts.volume0, pts.stress,
                    pts.active, lp, pts.log_strain, pts.state, pts.u_geostatic,
                    s.model, s.params)
    for name, cols in FIXED_COLUMNS.items():
        a = getattr(P, name)
        if a.ndim != 2 or a.shape[1] != cols:
            raise ValueError(f"point array {name} has shape {a.shape}; the compiled step "
                             f"needs (n, {cols})")
    return P


#: Rows of the step driver's energy record (:mod:`.advance`): record steps per call at most.
RECORD_BUFFER = 64


@dataclass
class Workspace:
    """Nodal and scratch arrays of the compiled step, allocated once per (grid, points),
    and the kernels' compiled entry points resolved for them.

    numba resolves the types of a tuple argument in Python, ~0.4 us per array (the
    groups above hold ~60 arrays over the 7 kernel calls of a step).  :meth:`call` does
    that once per kernel and
    then calls the compiled entry point directly (~3x cheaper), as long as :meth:`bind`
    sees the same point arrays (a new array drops the resolved calls).  ``model``: the
    one model id of the bound points (-1: several), found at :meth:`bind` (a point's
    model is set when the points are made and never changes during a run), and
    ``block``: whether its ``block_update`` takes them (:func:`.takes_blocks`, once).  ``clock``,
    ``count``, ``energy``: the step driver's time, step and energy record buffers
    (:mod:`.advance`); ``water``: the pore water (set before the first :meth:`bind`)."""
    nodes: NodeArrays
    scratch: Scratch
    mesh: Mesh | None = None
    points: PointArrays | None = None
    calls: dict = field(default_factory=dict)
    model: int = -1
    block: bool = False
    clock: np.ndarray = field(default_factory=lambda: np.zeros(7))
    count: np.ndarray = field(default_factory=lambda: np.zeros(3, np.int64))
    energy: np.ndarray = field(default_factory=lambda: np.zeros((RECORD_BUFFER, 2)))
    water: object = None             # the pore water's WaterTable (None: dry), in the mesh

    def bind(self, grid, pts, gimp: bool = True) -> tuple[PointArrays, Mesh]:
        """The point and mesh groups of ``pts`` and ``grid`` (kept while the arrays are).
        ``gimp``: the step may use the uGIMP basis, whose factors the scratch keeps per
        point (``gimp_ij``, ``gimp_w``: allocated at the first such call, 112 bytes a
        point; a Q4 run does without them)."""
        if gimp and self.scratch.gimp_w.shape[0] != pts.n:
            self.scratch = self.scratch._replace(gimp_ij=np.zeros((pts.n, 2), np.int64),
                                                 gimp_w=np.zeros((pts.n, 12)))
        P = point_arrays(pts, self.scratch.x_old)
        if self.points is None or any(a is not b for a, b in zip(P, self.points)):
            self.points, self.mesh = P, mesh_of(grid, self.water)
            self.calls.clear()
            m = P.model
            self.model = int(m[0]) if len(m) and bool((m == m[0]).all()) else -1
            self.block = takes_blocks(self.model, P.params)
        return self.points, self.mesh

    def call(self, kernel, *args):
        """``kernel(*args)``; from the second call on through its resolved entry point."""
        entry = self.calls.get(kernel)
        if entry is not None:
            return entry(*args)
        sig = tuple(typeof(a) for a in args)
        result = kernel(*args)
        cres = kernel.overloads.get(sig)
        if cres is not None:
            self.calls[kernel] = cres.entry_point
        return result

    @classmethod
    def for_grid(cls, grid, n_points: int, water=None) -> "Workspace":
        """The workspace of ``n_points`` points on ``grid``; ``water``: the pore water's
        :class:`fem_rmpm.schemes.pore_pressure.WaterTable` (None: dry)."""
        nn, n = grid.n_nodes, n_points
        nodes = node_arrays(nn, node_arrays(nn))
        return cls(nodes, scratch_for(n, grid.n_cells), water=water)


def node_arrays(nn: int, half: NodeArrays | None = None) -> NodeArrays:
    """The :class:`NodeArrays` of one half of the points on ``nn`` nodes (zeros)."""
    return NodeArrays(np.zeros(nn), np.zeros(2 * nn), np.zeros(2 * nn), np.zeros(2 * nn),
                      np.zeros(2 * nn), np.zeros(2 * nn), np.zeros(2 * nn),
                      np.zeros(nn, np.uint8), np.zeros(nn, np.uint64), np.zeros(1, np.int64),
                      half)


# The stress pass's block scratch (W, ta, tb, tc): every chunk's row starts at the same
# offset in its 4 KiB page, W's 8 rows at 8 different offsets (a multiple of 512 bytes
# apart) and ta, tb, tc at three more (256 bytes from W's), so each thread's eleven
# streams sit the same way in the L1 cache and no two of them are 4 KiB apart (a load
# from one then waits on a store to another: "4K aliasing").  As plain arrays, W's rows
# and the series arrays would sit where malloc put them, different for each row and each
# run, and one thread's stress pass could take much longer than the other's.
W_COLUMNS = 192                      # 8 x 192 x 8 bytes = 3 pages per chunk
SERIES_COLUMNS = 512                 # one page per chunk
SERIES_AT = (256, 1792, 3328)        # ta, tb, tc: offsets (bytes) in their pages
assert BLOCK <= min(W_COLUMNS, SERIES_COLUMNS, BLOCK_COLUMNS)     # a block fits in a row


def _page_rows(shape: tuple, offset: int) -> np.ndarray:
    """Zeros of ``shape`` (float64, C order) starting ``offset`` bytes into a 4 KiB page."""
    size = int(np.prod(shape))
    buf = np.zeros(size + 4096 // 8)
    start = (offset - buf.ctypes.data) % 4096 // 8
    return buf[start:start + size].reshape(shape)


#: The column counts of the point arrays that :func:`.common.fixed_columns` promises the
#: compiler (checked by :func:`point_arrays`; the scratch's are made so by
#: :func:`scratch_for`: ``x_old``, ``q4_st``, ``gimp_ij`` (n, 2), ``gimp_w`` (n, 12), ``W``
#: rows of :data:`W_COLUMNS`).
FIXED_COLUMNS = {"x": 2, "v": 2, "half_width": 2, "u_geo": 2, "stress": 4, "log_strain": 4}


def scratch_for(n: int, n_cells: int) -> Scratch:
    """The :class:`Scratch` of ``n`` points on a grid of ``n_cells`` cells (zeros; the uGIMP
    factors with no rows until :meth:`Workspace.bind` needs them)."""
    ta, tb, tc = (_page_rows((CHUNKS, SERIES_COLUMNS), at) for at in SERIES_AT)
    return Scratch(np.zeros((n, 2)), _page_rows((CHUNKS, 8, W_COLUMNS), 0), ta, tb, tc,
                   np.zeros(n, np.int64), np.zeros((n, 4)),
                   np.zeros(n_cells), np.zeros(n_cells), np.zeros(4), np.zeros((CHUNKS, 2)),
                   np.zeros((2, 5)), np.zeros(n, np.int64), np.zeros((n, 2)),
                   np.zeros(3 * QUEUE_STRIDE, np.int64),
                   _page_rows((CHUNKS, BLOCK_ROWS, BLOCK_COLUMNS), 1024),
                   np.zeros((0, 2), np.int64), np.zeros((0, 12)))
