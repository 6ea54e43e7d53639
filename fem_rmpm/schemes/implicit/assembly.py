"""The grid-reset system of one implicit step: basis at the step-start positions, DOF
numbering, and the vectorised assembly of internal force, tangent and lumped mass with the
material points as quadrature points."""
from __future__ import annotations

from functools import cached_property

import numpy as np
import scipy.sparse as sp

from fem_rmpm.discretise.basis import shape_at_points
from fem_rmpm.discretise.grid import Grid
from fem_rmpm.schemes.implicit import point_kernels as pk
from fem_rmpm.schemes.implicit import step_kernels as sk
from fem_rmpm.schemes.implicit import tangent_kernels as tk
from fem_rmpm.schemes.implicit.linear import LowerTangent
from fem_rmpm.schemes.locking import (
    bbar_tangent_correction,
    cell_pressure_tangent_correction,
    fbar_tangent_correction,
    fbar_work_tangent_correction,
    host_cells,
)

__all__ = ["StepSystem", "rigid_body_modes"]


class StepSystem:
    """The grid-reset system of one step: basis at the step-start positions, DOF numbering,
    and the vectorised assembly of internal force, tangent and lumped mass.

    ``free`` numbers the DOFs that are touched by a point's basis and not
    prescribed by a boundary (``grid.fixed``); only they enter the solve.  The
    sparsity pattern is built once per step (the CSR structure of the free DOFs and, per
    node set -- a host cell for Q4 -- the position of each block entry in its data
    array; ``halo``: of the occupied cells and the empty cells around them, kept from
    ``keep`` while it holds every point, see :meth:`_cell_pattern`); every Newton
    iteration then adds the per-point blocks straight into the data array
    (:func:`fem_rmpm.schemes.implicit.point_kernels.assemble_tangent`, one compiled loop
    over the points), with no sparse products, sorting or index building.
    """

    def __init__(self, grid: Grid, x: np.ndarray, shape: str = "standard", half_width=None,
                 fixed: np.ndarray | None = None, keep: "StepSystem | None" = None,
                 halo: bool = False):
        self.grid = grid
        fixed = grid.fixed if fixed is None else fixed      # (n_nodes, 2) prescribed DOFs
        nn = grid.n_nodes
        if shape == "gimp":
            self.host = host_cells(grid, x)                 # F-bar cells
            _, nodes, N, dN, _ = shape_at_points(grid, x, shape, half_width)
            used = np.zeros(nn, dtype=bool)
            touch = (N != 0) | (dN[:, :, 0] != 0) | (dN[:, :, 1] != 0)  # uGIMP: zero weights
            used[nodes[touch]] = True
        else:                       # Q4: host cells, basis and used nodes in one pass
            n = len(x)
            self.host = np.empty(n, dtype=np.int64)
            t = grid.mesh.t                                 # (4, n_cells) cell nodes
            nodes, N, dN = np.empty((n, 4), dtype=t.dtype), np.empty((n, 4)), \
                np.empty((n, 4, 2))
            used = np.zeros(nn, dtype=bool)
            sk.q4_step_basis(np.ascontiguousarray(x, dtype=float), grid.origin, grid.cell,
                             1.0 / grid.cell, grid.shape[0], grid.shape[1], t,
                             self.host, nodes, N, dN, used)
        # the host cells numbered 0..n_host-1: the cell sums over the points (bincount in
        # point order, the same sums as over grid cells) on arrays of the used cells only
        self.cell = np.empty(len(self.host), dtype=np.int64)
        self.n_host = sk.dense_rank(self.host, grid.n_cells, self.cell)
        self.nodes, self.N, self.dN = nodes, N, dN
        n, k = nodes.shape
        self.n, self.k = n, k
        self.used = used
        self.halo_cells = None
        if k == 4 and halo:                  # the DOFs of the cells and their halo
            self._cell_pattern(grid, fixed, keep)
            return
        free_mask = (used[:, None] & ~fixed).ravel()           # dof = 2 node + comp
        self.free_dofs = np.nonzero(free_mask)[0]
        self.n_free = nf = len(self.free_dofs)
        fnum = np.full(2 * nn, -1, dtype=np.int64)
        fnum[self.free_dofs] = np.arange(nf)
        self.fnum = fnum
        # group the points by their node set (Q4: the host cell, identified by node 0)
        if k == 4:
            inv = np.empty(n, dtype=np.int64)
            sk.dense_rank(nodes[:, 0], nn, inv)
        else:
            _, inv = np.unique(nodes, axis=0, return_inverse=True)
            inv = inv.ravel()
        ng = int(inv.max()) + 1 if n else 0
        self.n_groups = ng
        first = np.zeros(ng, dtype=np.int64)
        first[inv] = np.arange(n)                                  # a representative point
        gd = fnum[self.point_dofs[first]]                          # (ng, 2k) free or -1
        # the CSR pattern of the free DOFs (rows, then sorted columns) and the position of
        # each block entry [a, i, l, b] (row dof (a, i), column dof (b, l)) in its data
        # array, -1 for entries of prescribed DOFs (:func:`point_kernels.block_pattern`)
        (self._indptr, self._indices, self._positions, self._diag,
         self.transpose) = pk.block_pattern(np.ascontiguousarray(gd), nf)
        self.nnz = len(self._indices)
        self._lower: dict = {}          # lower_positions, made on first use
        self._group = inv.astype(np.int64)
        # Q4: the node sets are the host cells, so the B-bar terms are blocks of the
        # pattern (compiled path of :meth:`bbar_tangent_into`)
        self.groups_are_cells = k == 4 and bool(
            np.all(self.host == self.host[first][self._group]))

    @cached_property
    def used_nodes(self) -> np.ndarray:
        """The nodes of :attr:`used` (ascending)."""
        return np.nonzero(self.used)[0]

    @cached_property
    def point_dofs(self) -> np.ndarray:
        """The global DOFs of each point's nodes (n, 2k), ``2 node + component``."""
        return (2 * self.nodes[:, :, None] + np.arange(2)).reshape(self.n, 2 * self.k)

    def _cell_pattern(self, grid: Grid, fixed: np.ndarray, keep) -> None:
        """Q4 dynamic steps: the DOF numbering and sparsity pattern of a set of cells that
        holds every point's host cell, with a halo: the cells next to an occupied one,
        empty now, whose nodes are free DOFs with only the diagonal (the Newmark mass
        floor) and no load, so their increment stays zero and the solution is that of
        the occupied cells alone.  ``keep``: a previous system's cells, numbering and
        pattern, taken as they are if they hold every host cell (same prescribed DOFs):
        the linear solver then keeps its symbolic factorization; else the occupied cells
        and their halo anew."""
        nodes = self.nodes
        fits = keep is not None and keep.halo_cells is not None \
            and (keep._fixed is fixed or np.array_equal(keep._fixed, fixed))
        self._group = np.empty(self.n, dtype=np.int64)
        if fits and sk.kept_groups(keep._group_of, nodes, self._group):
            for name in ("free_dofs", "n_free", "fnum", "n_groups", "_indptr", "_indices",
                         "_positions", "_diag", "transpose", "nnz", "_lower", "halo_cells",
                         "_group_of", "_fixed"):
                setattr(self, name, getattr(keep, name))
        else:
            self._halo_pattern(grid, fixed)
            self._group = self._group_of[nodes[:, 0]]
        self.groups_are_cells = False          # B-bar (geostatic steps) needs the exact sets

    def _halo_pattern(self, grid: Grid, fixed: np.ndarray) -> None:
        """The occupied cells and the 8 around each: their free DOFs and pattern."""
        nn = grid.n_nodes
        nx, ny = grid.shape
        occupied = np.zeros((ny, nx), dtype=bool)
        occupied.ravel()[self.host] = True
        near = occupied.copy()
        near[1:, :] |= occupied[:-1, :]
        near[:-1, :] |= occupied[1:, :]
        rows = near.copy()
        near[:, 1:] |= rows[:, :-1]
        near[:, :-1] |= rows[:, 1:]
        cells = np.nonzero(near.ravel())[0]
        cn = grid.cells[cells]                           # (nc, 4) nodes, as the basis's
        order = np.argsort(cn[:, 0], kind="stable")      # node sets ranked by node 0
        cells, cn = cells[order], cn[order]
        pattern_nodes = np.zeros(nn, dtype=bool)
        pattern_nodes[cn.ravel()] = True
        self.free_dofs = np.nonzero((pattern_nodes[:, None] & ~fixed).ravel())[0]
        self.n_free = nf = len(self.free_dofs)
        fnum = np.full(2 * nn, -1, dtype=np.int64)
        fnum[self.free_dofs] = np.arange(nf)
        self.fnum = fnum
        gd = fnum[(2 * cn[:, :, None] + np.arange(2)).reshape(len(cells), 8)]
        (self._indptr, self._indices, self._positions, self._diag,
         self.transpose) = pk.block_pattern(np.ascontiguousarray(gd), nf)
        self.nnz = len(self._indices)
        self._lower: dict = {}          # lower_positions, made on first use
        self.n_groups = len(cells)
        self.halo_cells = cells
        self._group_of = np.full(nn, -1, dtype=np.int64)
        self._group_of[cn[:, 0]] = np.arange(len(cells))
        self._fixed = fixed.copy()

    # --- kinematics
    def gradient(self, du: np.ndarray) -> np.ndarray:
        """grad_n(du) at the points (n, 2, 2), ``H_ij = d du_i / d x_j``; du (n_nodes, 2)."""
        return pk.displacement_gradient(np.ascontiguousarray(du, dtype=float), self.nodes,
                                       self.dN, np.empty((self.n, 2, 2)))

    def interpolate(self, nodal: np.ndarray) -> np.ndarray:
        """Nodal vector (n_nodes, 2) at the points (n, 2)."""
        return pk.interpolate(np.ascontiguousarray(nodal, dtype=float), self.nodes, self.N,
                              np.empty((self.n, 2)))

    def to_nodes(self, free_vec: np.ndarray, prescribed: np.ndarray | None = None) -> np.ndarray:
        """Free-DOF vector -> nodal (n_nodes, 2); the other DOFs are zero, or take the
        values of ``prescribed`` (n_nodes, 2) if given."""
        full = np.zeros(2 * self.grid.n_nodes) if prescribed is None else \
            np.array(prescribed, dtype=float).ravel()
        full[self.free_dofs] = free_vec
        return full.reshape(-1, 2)

    # --- vectors
    def internal_force(self, V0: np.ndarray, tau4: np.ndarray, g: np.ndarray,
                       full: bool = False) -> np.ndarray:
        """``f_ai = sum_p V0_p tau_ij g_aj`` on the free DOFs (kN per m); ``full``: on all
        DOFs, as (n_nodes, 2) (for the reactions at prescribed DOFs)."""
        f = pk.internal_force(np.ascontiguousarray(tau4), V0, g, self.nodes,
                             np.zeros((self.grid.n_nodes, 2)))
        return f if full else f.ravel()[self.free_dofs]

    def fbar_tangent(self, V0: np.ndarray, g: np.ndarray, Q: np.ndarray,
                     w: np.ndarray) -> sp.csr_matrix:
        """The F-bar coupling term of the tangent on the free DOFs
        (:func:`fem_rmpm.schemes.locking.fbar_tangent_correction`)."""
        return fbar_tangent_correction(self.fnum[self.point_dofs], V0, g, Q, w, self.host,
                                       self.n_free)

    def bbar_tangent(self, V0: np.ndarray, g: np.ndarray, D: np.ndarray,
                     w: np.ndarray) -> sp.csr_matrix:
        """The B-bar terms of the small-strain tangent on the free DOFs
        (:func:`fem_rmpm.schemes.locking.bbar_tangent_correction`)."""
        return bbar_tangent_correction(self.fnum[self.point_dofs], V0, g, D, w, self.host,
                                       self.n_free)

    def tangent_with_bbar(self, V0: np.ndarray, g: np.ndarray, D: np.ndarray,
                          w: np.ndarray, diagonal: np.ndarray | None = None) -> sp.csr_matrix:
        """The small-strain B-bar tangent ``sum_p V0_p Bbar^T D Bbar`` (+ ``diag(diagonal)``)
        on the free DOFs in one pass into the pattern: the standard blocks and the B-bar
        terms (:func:`fem_rmpm.schemes.implicit.point_kernels.assemble_bbar_tangent`; the
        same sum as :meth:`tangent` + :meth:`bbar_tangent`, which a Q4 grid does not
        need).  Only where ``groups_are_cells``."""
        if not self.groups_are_cells:
            raise ValueError("tangent_with_bbar needs node sets equal to host cells (Q4)")
        data = np.zeros(self.nnz)
        pk.assemble_tangent(g, D, V0, self._group, self._positions, data)
        if diagonal is not None:
            data[self._diag] += diagonal
        t1, t2, t3 = np.zeros(self.nnz), np.zeros(self.nnz), np.zeros(self.nnz)
        pk.assemble_bbar_tangent(g, D, V0, w, self._group, self.n_groups, self._positions,
                                 t1, t2, t3)
        t1 += t2
        t1 += t3
        data += t1
        return sp.csr_matrix((data, self._indices, self._indptr),
                             shape=(self.n_free, self.n_free))

    def fbar_work_tangent(self, V0: np.ndarray, g: np.ndarray, A: np.ndarray,
                          tau4: np.ndarray, w: np.ndarray) -> sp.csr_matrix:
        """The work-conjugate F-bar force's extra tangent term on the free DOFs
        (:func:`fem_rmpm.schemes.locking.fbar_work_tangent_correction`)."""
        return fbar_work_tangent_correction(self.fnum[self.point_dofs], V0, g, A, tau4, w,
                                            self.host, self.n_free)

    def cell_pressure_tangent(self, V0: np.ndarray, g: np.ndarray, D: np.ndarray,
                              w: np.ndarray) -> sp.csr_matrix:
        """The cell-pressure condensation term of the small-strain tangent
        (:func:`fem_rmpm.schemes.locking.cell_pressure_tangent_correction`)."""
        return cell_pressure_tangent_correction(self.fnum[self.point_dofs], V0, g, D, w,
                                                self.host, self.n_free)

    def body_force(self, mass: np.ndarray, gravity) -> np.ndarray:
        """``f_ai = sum_p m_p g_i N_a`` on the free DOFs (kN per m)."""
        gx, gy = (float(v) for v in np.asarray(gravity, dtype=float))
        return sk.free_body_force(self.nodes, self.N, np.ascontiguousarray(mass, dtype=float),
                                  gx, gy, self.fnum, np.zeros(self.n_free))

    def mass_and_momenta(self, mass: np.ndarray, v: np.ndarray, a: np.ndarray):
        """The nodal lumped mass ``m_a = sum_p m_p N_a`` (n_nodes,), t per m, and the nodal
        sums ``sum_p m_p v_p N_a`` and ``sum_p m_p a_p N_a`` (n_nodes, 2), in one pass."""
        nn = self.grid.n_nodes
        m, mv, ma = np.zeros(nn), np.zeros((nn, 2)), np.zeros((nn, 2))
        pk.nodal_mass_momentum(self.nodes, self.N, mass, np.ascontiguousarray(v),
                               np.ascontiguousarray(a), m, mv, ma)
        return m, mv, ma

    # --- matrix
    def tangent(self, V0: np.ndarray, g: np.ndarray, A: np.ndarray,
                diagonal: np.ndarray | None = None) -> sp.csr_matrix:
        """``K_ai,bl = sum_p V0_p g_aj A_ijlm g_bm`` (+ ``diag(diagonal)``) on the free DOFs.

        ``g`` (n, k, 2) spatial gradients, ``A`` (n, 2, 2, 2, 2); ``diagonal``
        is a free-DOF vector (e.g. the Newmark mass term 4 m / dt^2).
        """
        data = np.zeros(self.nnz)
        pk.assemble_tangent(g, A, V0, self._group, self._positions, data)
        if diagonal is not None:
            data[self._diag] += diagonal
        return sp.csr_matrix((data, self._indices, self._indptr),
                             shape=(self.n_free, self.n_free))

    def lower_positions(self) -> tuple[np.ndarray, np.ndarray, int]:
        """``(positions, diag, n)`` into the data of the pattern's lower triangle in
        CHOLMOD's order (the entries ``(r, c)``, ``c >= r``, of the CSR rows in turn): the
        position of each block entry (layout of the full pattern's; -1 for the upper
        triangle and prescribed DOFs), of each diagonal entry, and the length ``n`` of
        that data.  Made once per pattern and kept with it (``_lower``, shared by the
        steps that keep the pattern, :meth:`_cell_pattern`)."""
        c = self._lower
        if not c:
            row = np.repeat(np.arange(self.n_free, dtype=np.int64), np.diff(self._indptr))
            lower = np.nonzero(self._indices >= row)[0]
            index = np.full(self.nnz + 1, -1, dtype=np.int64)      # [-1]: a prescribed DOF
            index[lower] = np.arange(len(lower))
            c.update(positions=index[self._positions], diag=index[self._diag], n=len(lower))
        return c["positions"], c["diag"], c["n"]

    def finite_strain_tangent(self, V0: np.ndarray, g: np.ndarray, D: np.ndarray,
                              cols: np.ndarray, J: np.ndarray, tau: np.ndarray, factor: float,
                              diagonal: np.ndarray | None = None,
                              rtol: float = 1e-12) -> LowerTangent | None:
        """The tangent of a finite-strain step, ``factor sum_p V0_p g_aj A_ijlm g_bm``
        (+ ``diag(diagonal)``), as its lower triangle in one compiled pass from the model
        stiffness ``D`` (columns ``cols``), the trial Jacobian ``J`` and the stress ``tau``
        (:func:`.tangent_kernels.assemble_spatial_lower`; the same entries as
        :func:`.tangent_kernels.spatial_tangent` and :meth:`tangent` to the last bit).
        None when a point's ``A`` lacks the major symmetry ``A_ijlm = A_lmij`` to ``rtol``
        of the largest entry (the caller then assembles the whole matrix)."""
        positions, diag, n_lower = self.lower_positions()
        data = np.zeros(n_lower)
        asym, amax = tk.assemble_spatial_lower(
            D, cols, J, np.ascontiguousarray(tau, dtype=float), float(factor), g, V0,
            self._group, positions, data)
        if not asym <= rtol * amax:
            return None
        if diagonal is not None:
            data[diag] += diagonal

        def full():
            A = tk.spatial_tangent(D if cols[2] == 2 else D[:, :, cols], J,
                                   np.ascontiguousarray(tau, dtype=float),
                                   np.empty((self.n, 2, 2, 2, 2)))
            return self.tangent(V0, g, A if factor == 1.0 else factor * A, diagonal)
        return LowerTangent(data, self._indptr, self._indices, full)

    def rigid_body_modes(self) -> np.ndarray:
        return rigid_body_modes(self.grid.nodes, self.free_dofs)


def rigid_body_modes(node_xy: np.ndarray, free_dofs: np.ndarray) -> np.ndarray:
    """The three 2-D rigid-body modes (x, y translation, rotation) on the free DOFs (nf, 3)."""
    node, comp = free_dofs // 2, free_dofs % 2
    xy = node_xy[node] - node_xy[node].mean(axis=0)
    B = np.zeros((len(free_dofs), 3))
    B[comp == 0, 0] = 1.0
    B[comp == 1, 1] = 1.0
    B[:, 2] = np.where(comp == 0, -xy[:, 1], xy[:, 0])
    return B

