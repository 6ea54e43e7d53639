"""Q4 and uGIMP basis functions at one point, on the structured grid (:class:`.Mesh`)."""
from __future__ import annotations

import numpy as np

from fem_rmpm.runtime.compiled import inline, jit, kernel
from fem_rmpm.schemes.explicit.kernels.arrays import Mesh

__all__ = ["q4", "q4_cell", "q4_at", "gimp", "gimp_factors", "gimp_at", "gimp_store",
           "gimp_kept", "q4_shape", "gimp_shape"]


@inline
def cell_index(s, n):
    """The cell ``0 <= i < n`` of grid coordinate ``s`` (in cells from the origin), clamped
    to the grid: ``min(max(floor(s), 0), n - 1)``, computed as ``int(s)`` (truncation)
    clamped, which is the same number for every ``s``: truncation and floor differ only
    for a negative ``s`` off the integers, where both clamp to 0 (and NaN or a value out of
    int64's range converts to int64's minimum, which clamps to 0 as well).  It saves a
    rounding on the way from a point's position to its nodes: ``x -> s -> floor ->
    integer -> node`` is the chain every point of the map to nodes waits on."""
    return min(max(int(s), 0), n - 1)


@inline
def q4_cell(x0, x1, M):
    """Host cell of a point for the Q4 basis: ``(ll, s, t)`` = the cell's lower-left node
    and the local coordinates in [0, 1] (see :func:`q4`)."""
    nx, ny = M.nx, M.ny
    s0 = (x0 - M.o0) * M.ih0
    s1 = (x1 - M.o1) * M.ih1
    i = cell_index(s0, nx)
    j = cell_index(s1, ny)
    return j * (nx + 1) + i, s0 - i, s1 - j


@inline
def q4_at(ll, s, t, M):
    """Q4 basis (nodes, N, dN/dx, dN/dy) of the cell ``ll`` at local coordinates ``s, t``
    (:func:`q4_cell`): the step computes the cell once per point and reuses it.  The node
    numbers are uint64 (as those of :func:`gimp`): numba then omits its negative-index
    fix-up on every nodal array access (a signed index ``a`` is read as ``a + n`` if
    negative); with it, the map to nodes cost ~3.5 ns per point more (case (i), t = 25 s,
    13.7-14.0 against 17.3 ns, micro-benchmark)."""
    ih0, ih1 = M.ih0, M.ih1
    a = np.uint64(ll)
    one = np.uint64(1)
    row = np.uint64(M.nx + 1)
    fs = 1.0 - s
    ft = 1.0 - t
    return ((a, a + one, a + row + one, a + row),
            (fs * ft, s * ft, s * t, fs * t),
            (-ft * ih0, ft * ih0, t * ih0, -t * ih0),
            (-fs * ih1, -s * ih1, s * ih1, fs * ih1))


@inline
def q4(x0, x1, M):
    """Bilinear Q4 basis at one point as tuples (nodes, N, dN/dx, dN/dy), 4 each.

    Same arithmetic as :func:`fem_rmpm.discretise.grid.locate` +
    :func:`fem_rmpm.discretise.basis.q4_values` (local coordinates in [0, 1], cell clipped into the
    grid, nodes counter-clockwise from the lower left), except that ``ih = 1 / h`` is multiplied,
    not divided by
    (a point within one rounding of a cell edge may so be placed in the neighbour
    cell: Q4 is continuous there, only its gradient jumps)."""
    ll, s, t = q4_cell(x0, x1, M)
    return q4_at(ll, s, t, M)


# Compiled once and called, not inlined: :func:`gimp` calls it six times and is inlined
# into the map to nodes, the map back, the kinematics and F-bar's gradient pass; numba's
# inliner repeats its pipeline and copies the IR at every inline site, which took ~9 s
# of the first run's compile (cold, numba 0.68: the serial driver 28.3 -> 19.6 s).  It
# computes from its arguments alone, so the results are bitwise those inlined (LLVM
# still inlines it: uGIMP on case (i), 5 interleaved one-thread pairs, 0.96-1.02x).
@kernel
def _gimp_1d(d, h, lp):
    """uGIMP weight and derivative (Bardenhagen & Kober 2004), as shape._gimp_1d."""
    a = abs(d)
    sg = 1.0 if d > 0 else (-1.0 if d < 0 else 0.0)
    if a < lp:
        return 1.0 - (d * d + lp * lp) / (2 * h * lp), -d / (h * lp)
    if a <= h - lp:
        return 1.0 - a / h, -sg / h
    if a < h + lp:
        r = h + lp - a
        return r * r / (4 * h * lp), -sg * r / (2 * h * lp)
    return 0.0, 0.0


@inline
def gimp_factors(x0, x1, lp0, lp1, M):
    """The factors of the uGIMP basis at one point: the column ``fi`` and the row ``fj`` of
    the lower left of its 3 x 3 nodes (-1 left of or below the grid: clipped by
    :func:`gimp_at`) and the 1-D weights and derivatives ``(w, dw/dx)`` (-, 1/m) of the
    three node columns ``X0, X1, X2`` and rows ``Y0, Y1, Y2``."""
    o0, o1, h0, h1 = M.o0, M.o1, M.h0, M.h1
    s0 = (x0 - o0) * M.ih0
    s1 = (x1 - o1) * M.ih1
    i = cell_index(s0, M.nx)
    j = cell_index(s1, M.ny)
    fi = i - 1 if s0 - i < 0.5 else i
    fj = j - 1 if s1 - j < 0.5 else j
    X0 = _gimp_1d(x0 - (o0 + fi * h0), h0, lp0)
    X1 = _gimp_1d(x0 - (o0 + (fi + 1) * h0), h0, lp0)
    X2 = _gimp_1d(x0 - (o0 + (fi + 2) * h0), h0, lp0)
    Y0 = _gimp_1d(x1 - (o1 + fj * h1), h1, lp1)
    Y1 = _gimp_1d(x1 - (o1 + (fj + 1) * h1), h1, lp1)
    Y2 = _gimp_1d(x1 - (o1 + (fj + 2) * h1), h1, lp1)
    return fi, fj, X0, X1, X2, Y0, Y1, Y2


@inline
def gimp_at(fi, fj, X0, X1, X2, Y0, Y1, Y2, M):
    """uGIMP basis (nodes, N, dN/dx, dN/dy; tuples of 9, y-major, nodes beyond the edge
    clipped onto it) from the factors of :func:`gimp_factors`."""
    nx, ny = M.nx, M.ny
    c0 = min(max(fi, 0), nx)
    c1 = min(max(fi + 1, 0), nx)
    c2 = min(max(fi + 2, 0), nx)
    r0 = min(max(fj, 0), ny) * (nx + 1)
    r1 = min(max(fj + 1, 0), ny) * (nx + 1)
    r2 = min(max(fj + 2, 0), ny) * (nx + 1)
    u = np.uint64
    nodes = (u(r0 + c0), u(r0 + c1), u(r0 + c2), u(r1 + c0), u(r1 + c1), u(r1 + c2),
             u(r2 + c0), u(r2 + c1), u(r2 + c2))
    N = (X0[0] * Y0[0], X1[0] * Y0[0], X2[0] * Y0[0], X0[0] * Y1[0], X1[0] * Y1[0],
         X2[0] * Y1[0], X0[0] * Y2[0], X1[0] * Y2[0], X2[0] * Y2[0])
    dx = (X0[1] * Y0[0], X1[1] * Y0[0], X2[1] * Y0[0], X0[1] * Y1[0], X1[1] * Y1[0],
          X2[1] * Y1[0], X0[1] * Y2[0], X1[1] * Y2[0], X2[1] * Y2[0])
    dy = (X0[0] * Y0[1], X1[0] * Y0[1], X2[0] * Y0[1], X0[0] * Y1[1], X1[0] * Y1[1],
          X2[0] * Y1[1], X0[0] * Y2[1], X1[0] * Y2[1], X2[0] * Y2[1])
    return nodes, N, dx, dy


@inline
def gimp(x0, x1, lp0, lp1, M):
    """uGIMP basis at one point: the 3 x 3 nodes around it as tuples of 9, as
    :func:`fem_rmpm.discretise.basis.gimp_at_points` (y-major, nodes beyond the edge clipped onto
    it)."""
    fi, fj, X0, X1, X2, Y0, Y1, Y2 = gimp_factors(x0, x1, lp0, lp1, M)
    return gimp_at(fi, fj, X0, X1, X2, Y0, Y1, Y2, M)


# The step evaluates a point's basis three times at one position: in the map to nodes,
# the map back and the kinematics (at the position before the move).  Q4 keeps the cell
# and local coordinates of the first (``q4_ll``, ``q4_st``); uGIMP keeps its factors
# (``gimp_ij`` (n, 2), ``gimp_w`` (n, 12) of :class:`.Scratch`), and the later passes
# rebuild the basis from them with the same products: bitwise the basis they recomputed.
@inline
def gimp_store(i, x0, x1, lp0, lp1, M, ij, wd):
    """:func:`gimp` of point ``i``, its factors kept in row ``i`` of ``ij`` and ``wd``."""
    fi, fj, X0, X1, X2, Y0, Y1, Y2 = gimp_factors(x0, x1, lp0, lp1, M)
    ij[i, 0] = fi
    ij[i, 1] = fj
    wd[i, 0], wd[i, 1], wd[i, 2], wd[i, 3], wd[i, 4], wd[i, 5] = X0[0], X0[1], X1[0], X1[1], \
        X2[0], X2[1]
    wd[i, 6], wd[i, 7], wd[i, 8], wd[i, 9], wd[i, 10], wd[i, 11] = Y0[0], Y0[1], Y1[0], \
        Y1[1], Y2[0], Y2[1]
    return gimp_at(fi, fj, X0, X1, X2, Y0, Y1, Y2, M)


@inline
def gimp_kept(i, ij, wd, M):
    """The uGIMP basis of point ``i`` from the factors :func:`gimp_store` kept."""
    return gimp_at(ij[i, 0], ij[i, 1], (wd[i, 0], wd[i, 1]), (wd[i, 2], wd[i, 3]),
                   (wd[i, 4], wd[i, 5]), (wd[i, 6], wd[i, 7]), (wd[i, 8], wd[i, 9]),
                   (wd[i, 10], wd[i, 11]), M)


def _mesh(org, h, nx, ny) -> Mesh:
    return Mesh(float(org[0]), float(org[1]), float(h[0]), float(h[1]), 1.0 / h[0], 1.0 / h[1],
                int(nx), int(ny), np.zeros(2), np.zeros(2), np.zeros(2, np.bool_))


@jit
def _q4_all(x, M):
    n = x.shape[0]
    nodes = np.empty((n, 4), np.int64)
    N = np.empty((n, 4))
    dN = np.empty((n, 4, 2))
    for i in range(n):
        a, b, c, d = q4(x[i, 0], x[i, 1], M)
        for k in range(4):
            nodes[i, k], N[i, k], dN[i, k, 0], dN[i, k, 1] = a[k], b[k], c[k], d[k]
    return nodes, N, dN


@jit
def _gimp_all(x, lp, M):
    n = x.shape[0]
    nodes = np.empty((n, 9), np.int64)
    N = np.empty((n, 9))
    dN = np.empty((n, 9, 2))
    for i in range(n):
        a, b, c, d = gimp(x[i, 0], x[i, 1], lp[i, 0], lp[i, 1], M)
        for k in range(9):
            nodes[i, k], N[i, k], dN[i, k, 0], dN[i, k, 1] = a[k], b[k], c[k], d[k]
    return nodes, N, dN


def q4_shape(x, org, h, nx, ny):
    """Q4 basis at points ``x`` (n, 2): nodes (n, 4), values (n, 4), gradients (n, 4, 2)."""
    return _q4_all(x, _mesh(org, h, nx, ny))


def gimp_shape(x, lp, org, h, nx, ny):
    """uGIMP basis at points ``x`` (n, 2): nodes (n, 9), values (n, 9), gradients (n, 9, 2)."""
    return _gimp_all(x, lp, _mesh(org, h, nx, ny))
