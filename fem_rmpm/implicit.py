"""Implicit MPM: updated-Lagrangian Newton-Raphson with the consistent tangent.

Three kinds of step share one Newton solver (:class:`StepSystem` + :func:`newton`):

* **Quasi-static load steps** (``[solver] dynamic = false``): gravity is applied
  in ``load_steps`` equal increments of the load factor.  Each step the grid is
  reset ("updated Lagrangian"): the basis is evaluated at the step-start
  positions ``x_n`` and the unknown is the nodal displacement increment ``du``.
  At a point ``dF = I + grad_n(du)`` (gradient in the step-start configuration),
  the material (:func:`fem_rmpm.material.stress_update`, Hencky/Kirchhoff) gives
  the Kirchhoff stress ``tau``, and with the spatial gradients
  ``g = dF^-T grad_n N``::

      f_int_ai = sum_p V0_p tau_ij g_aj                      (internal force)
      K_ai,bl  = sum_p V0_p g_aj A_ijlm g_bm                  (consistent tangent)

  ``A`` (:func:`fem_rmpm.material.spatial_tangent`) holds the material tangent
  *and* the geometric (initial-stress) term, so Newton converges quadratically.
  At convergence the points move by the interpolated increment,
  ``F <- dF F``, ``V = det(F) V0`` and the stored stress is Cauchy
  ``sigma = tau V0 / V``.
* **Dynamic steps** (``dynamic = true``): Newmark trapezoidal rule
  (``beta = 1/4, gamma = 1/2``, unconditionally stable, no numerical damping) on
  the same grid-reset increments, with the *lumped* nodal mass ``m_a = sum_p
  m_p N_a``: ``a_{n+1} = 4/dt^2 (du - dt v_n) - a_n``, residual ``f_ext - f_int -
  m a_{n+1}``, tangent ``K + 4 m / dt^2``.  Why lumped rather than consistent:
  the nodal velocity and acceleration of step start are projections of the
  point values; with a consistent mass they need a solve with a matrix that is
  rank-deficient wherever a cell holds fewer points than it has nodes (the
  usual MPM situation near a free surface), with the lumped mass they are
  plain divisions, as in the explicit scheme (the two schemes then map alike);
  the positive diagonal also keeps the tangent regular at nodes with little
  stiffness support.  Points: ``x += N du``, ``a_p = N a_{n+1}``, and the
  velocity is updated FLIP-like, ``v_p += N (v_{n+1} - v_n)`` blended with PIC
  by ``[solver] flip``.  The scheme has no numerical dissipation and
  ``[solver] damping`` (the explicit scheme's local damping) is not used: a
  dynamic run comes to rest only through plastic dissipation.
* **Geostatic steps** (``gravity_phase = "geostatic"``): gravity on the fixed
  in-situ geometry, small strain (:func:`fem_rmpm.material.small_strain_update`),
  points do not move (the displacement goes to ``pts.u_geostatic``).  The
  tangent is ``d tau / d grad(du)`` by complex step (:func:`small_strain_tangent`).
  With linear elastic points at the 2x2 Gauss points one step is exactly the
  scikit-fem Q4 solution (:func:`fem_rmpm.fem.solve_static`).  The geostatic
  phase is always quasi-static; with ``dynamic = true`` the Newmark phase
  follows from rest under full gravity.

**Assembly.**  The material points are the quadrature points: scikit-fem's
``CellBasis`` with one "element" per point (:func:`fem_rmpm.shape.skfem_point_basis`)
and the forms :func:`skfem_tangent_form` / :func:`skfem_force_form` assemble
``K`` and ``f_int`` exactly as written above.  The run uses the vectorised
numpy path (:meth:`StepSystem.tangent`) which evaluates the same sums from the
fast Q4 (or uGIMP) basis of :mod:`fem_rmpm.shape`: per-point 8x8 blocks summed
per node set, then one CSR build of the free DOFs only.  ``tests/test_implicit.py``
checks the two agree to round-off; scikit-fem's ``asm`` is 25-50x slower here
(``validation/bench_implicit.py`` measures both).  The consistent tangent is
:func:`finite_strain_tangent`: the same complex-step derivative of the same
update as :func:`fem_rmpm.material.spatial_tangent` (tested equal), about 3x
faster.

**Convergence** (defaults from the scene): a step has converged when the
relative residual ``r = |R_free| / max(|f_ext_free|, |R_0|) <= tolerance``
(``[solver] tolerance``, default 1e-9) *and* the displacement correction still
to come, estimated from the last one as ``|delta_k| r_{k+1} / r_k``, is at most
``sqrt(tolerance)`` of the step's displacement increment (it catches a small
residual over a still-drifting soft mode; with quadratic convergence a relative
correction eps leaves a residual ~eps^2, hence the square root).  A linear step
converges after one iteration.  A step that fails (``max_iterations``
reached, a non-finite residual, an inverted point ``det dF <= 0`` or a failed
linear solve) is cut in half and retried, at most ``max_cuts`` times; then
:class:`~fem_rmpm.run.SimulationError` names the step, the residual
history and what to change.  The state of the last converged step is kept (and
written), nothing non-finite is ever accepted.

**Linear solvers** (``[solver] linear_solver``): ``"superlu"`` (default): sparse
LU of the free-DOF tangent with ``permc_spec = "MMD_AT_PLUS_A"`` (about 2x the
default ordering on these 2-D meshes); ``"pyamg"``: conjugate gradients
preconditioned by pyamg smoothed aggregation whose near-null space is the three
2-D rigid-body modes (the default constant vectors fail to converge on
elasticity) and a sparse-LU coarse solve; the hierarchy is built once per step
and reused by its Newton iterations; GMRES takes over if CG fails (softening
makes the tangent indefinite).  Measured (``validation/bench_implicit.py``, one
BLAS thread): the two are comparable at 10^4 DOFs, pyamg is ~2x faster at 10^5.  The inner tolerance follows the
residual (inexact Newton with forcing term ``min(1e-3, max(1e-12, 0.1 r_k))``),
which keeps the outer convergence quadratic.

**Volumetric locking** (``[solver] fbar = true``): F-bar with cell averaging
(:mod:`fem_rmpm.locking`, de Souza Neto et al. 1996): the material sees
``dF_bar = (dJ_bar / dJ)^(1/2) dF``, ``dJ_bar`` the volume-weighted mean over the
points of the host cell (geostatic steps: B-bar, its small-strain linearisation).
The internal force keeps ``sum_p V0 tau(dF_bar) g`` with the true spatial gradients
``g``; the consistent tangent gains the analytic cell-coupling term
:meth:`StepSystem.fbar_tangent` (rank one per point), so Newton stays quadratic
(``tests/test_locking.py``).  Points store ``F <- dF_bar F`` and ``V = det(F) V0``.

**Prescribed displacements** (``[[prescribed]]`` regions, quasi-static or geostatic
load steps only): the grid nodes in a region's polygon are removed from the free
DOFs and move by the load-factor increment times the region's displacement; the
reaction ``f_int - f_ext`` summed over each region (kN per m, the force the region
exerts on the soil) is recorded per step in ``record.solver["steps"][k]["reactions"]``.
A displacement-controlled footing is a region on the surface (``meshes/footing.toml``).
The nodes stay where they are (the grid is reset every step): the footing keeps
contact while the soil under it has moved less than about 0.7 of a cell.

**Basis** (``[solver] shape``): with the standard Q4 basis the points sit on
the Gauss points only in the first step; once they move, cell crossing makes
the point-quadrature error O(1) (a cell holds 3 or 5 points instead of 4) and
it accumulates over load steps: the soft column (meshes/soft_column.toml)
settles 7 % too much in 10 Q4 load steps and the compaction error stalls near
4 % under refinement, while uGIMP (``shape = "gimp"``) converges
(``validation/compaction.py``).  Use uGIMP for large deformation.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import splu

from .run import RunRecord, SimulationError, at_rest, check_points
from .grid import Grid, points_in_polygon
from .locking import (bbar_gradient, fbar_increment, fbar_q, fbar_tangent_correction,
                      fbar_weights, host_cells)
from .material import (SoilPoints, return_map, exp_sym2, kirchhoff_stress, log_sym2,
                       small_strain_update, stress_update)
from .particles import Particles
from .scene import Scene, SceneError
from .shape import shape_at_points

__all__ = ["small_strain_tangent", "finite_strain_tangent", "elastic_left_cauchy_green",
           "StepSystem", "LinearSolver", "NewtonFailure", "newton", "NewtonResult", "run_implicit", "skfem_tangent_form", "skfem_force_form",
           "skfem_assemble", "rigid_body_modes"]

_MASS_TOL = 1e-14
_EYE = np.eye(2)


# ----------------------------------------------------------------------------- material
def small_strain_tangent(grad_du: np.ndarray, log_strain: np.ndarray, gamma_p: np.ndarray,
                         soil: SoilPoints, step: float = 1e-30):
    """Consistent tangent of the small-strain (geostatic) update, by complex step.

    Returns ``(tau, D)``: ``tau`` (n, 4) [xx, yy, zz, xy] from
    :func:`~fem_rmpm.material.small_strain_update` and ``D`` (n, 2, 2, 2, 2) with
    ``D_ijlm = d tau_ij / d grad(du)_lm`` (kPa), exact to round-off including the
    return mapping.  ``K_ai,bl = sum_p V_p dN_aj D_ijlm dN_bm``: the same
    contraction as the finite-strain tangent with ``g = dN``.  The update depends
    on ``sym(grad du)`` only, so ``D_ij01 = D_ij10`` and three complex
    evaluations suffice (done as one call on 3n points).
    """
    n = grad_du.shape[0]
    _, _, tau = small_strain_update(grad_du, log_strain, gamma_p, soil)
    # trial strain of small_strain_update, eps + sym(grad du), perturbed in 3 directions
    e3 = np.tile(log_strain.astype(complex), (3, 1))
    e3[:, 0] += np.tile(grad_du[:, 0, 0], 3)
    e3[:, 1] += np.tile(grad_du[:, 1, 1], 3)
    e3[:, 3] += np.tile(0.5 * (grad_du[:, 0, 1] + grad_du[:, 1, 0]), 3)
    e3[:n, 0] += 1j * step
    e3[n:2 * n, 1] += 1j * step
    e3[2 * n:, 3] += 0.5j * step
    d = _stress_derivative(e3, gamma_p, soil, step).reshape(3, n, 4)
    D = np.empty((n, 2, 2, 2, 2))
    for k, (l, m) in enumerate(((0, 0), (1, 1), (0, 1))):
        D[:, 0, 0, l, m], D[:, 1, 1, l, m] = d[k, :, 0], d[k, :, 1]
        D[:, 0, 1, l, m] = D[:, 1, 0, l, m] = d[k, :, 3]
    D[..., 1, 0] = D[..., 0, 1]
    return tau, D


def _stress_of(eps: np.ndarray, gamma_p: np.ndarray, soil: SoilPoints) -> np.ndarray:
    """Kirchhoff stress after the return mapping of :mod:`fem_rmpm.material`; points
    without a strength (linear elastic: peak and residual cohesion inf) skip the (never active)
    yield check, which is most of the cost of a complex evaluation."""
    elastic = ~np.isfinite(soil.cohesion_peak) & ~np.isfinite(soil.cohesion_residual)
    if elastic.all():
        return kirchhoff_stress(eps, soil)
    if not elastic.any():
        return return_map(eps, gamma_p, soil)[2]
    tau = kirchhoff_stress(eps, soil)
    idx = np.nonzero(~elastic)[0]
    tau[idx] = return_map(eps[idx], gamma_p[idx], soil.take(idx))[2]
    return tau


def _stress_derivative(eps_c: np.ndarray, gamma_p: np.ndarray, soil: SoilPoints,
                       step: float) -> np.ndarray:
    """``Im tau(eps_c) / step`` for 3 stacked complex-step perturbations (3n, 4) of n
    points: the directional derivatives of the Kirchhoff stress.  Linear elastic points
    (no strength) are linear in the strain, so their derivative is
    ``kirchhoff_stress(Im eps_c) / step`` in real arithmetic; the others go through the
    complex return mapping of :mod:`fem_rmpm.material`."""
    n = len(gamma_p)
    elastic = ~np.isfinite(soil.cohesion_peak) & ~np.isfinite(soil.cohesion_residual)
    d = np.empty((3 * n, 4))
    for k in range(3):
        d[k * n:(k + 1) * n] = kirchhoff_stress(eps_c[k * n:(k + 1) * n].imag, soil) / step
    if not elastic.all():
        idx = np.nonzero(~elastic)[0]
        sp_ = soil.take(idx)
        for k in range(3):
            e = eps_c[k * n + idx]
            d[k * n + idx] = return_map(e, gamma_p[idx] + 0 * e[:, 0], sp_)[2].imag / step
    return d


def elastic_left_cauchy_green(log_strain: np.ndarray) -> np.ndarray:
    """``b_e = exp(2 eps_e)`` (n, 2, 2) in-plane, from the stored log strain (n, 4)."""
    bxx, byy, bxy = exp_sym2(log_strain[:, 0], log_strain[:, 1], log_strain[:, 3])
    B = np.empty((len(log_strain), 2, 2))
    B[:, 0, 0], B[:, 1, 1], B[:, 0, 1], B[:, 1, 0] = bxx, byy, bxy, bxy
    return B


def finite_strain_tangent(dF: np.ndarray, log_strain: np.ndarray, gamma_p: np.ndarray,
                          soil: SoilPoints, step: float = 1e-30, b_e: np.ndarray | None = None,
                          tau: np.ndarray | None = None):
    """Same ``(tau, A)`` as :func:`fem_rmpm.material.spatial_tangent`, about 3x faster.

    ``A_ijlm = d tau_ij / d(grad_x du)_lm - delta_jl tau_im`` where a perturbation
    ``dF -> (I + E) dF`` is split into its symmetric part (three complex-step
    evaluations of the very same trial state and return mapping of
    :mod:`fem_rmpm.material`, done as one call on 3n points, with the trial
    ``b = (I + i h S) b_tr (I + i h S)`` formed directly) and its spin ``W``,
    whose effect is exact and analytic for this isotropic law:
    ``tau((I + W) dF) = (I + W) tau (I + W)^T``, i.e. ``d tau = W tau - tau W``.
    Equality with ``spatial_tangent`` is tested.  Within a Newton step ``b_e``
    (:func:`elastic_left_cauchy_green` of the step-start strain) and ``tau`` (from the
    residual evaluation at the same ``dF``) may be passed in to save their evaluation.
    """
    n = dF.shape[0]
    B = elastic_left_cauchy_green(log_strain) if b_e is None else b_e
    btr = dF @ B @ np.swapaxes(dF, 1, 2)
    btr = 0.5 * (btr + np.swapaxes(btr, 1, 2))
    if tau is None:
        exx, eyy, exy = log_sym2(btr[:, 0, 0], btr[:, 1, 1], btr[:, 0, 1])
        eps_tr = np.stack([exx, eyy, log_strain[:, 2], exy], axis=1)
        tau = _stress_of(eps_tr, gamma_p, soil)
    b00, b11, b01 = btr[:, 0, 0], btr[:, 1, 1], btr[:, 0, 1]
    # symmetric directions S_00, S_11, (E_01 + E_10)/2: b = b_tr + i h (S b_tr + b_tr S)
    h = 1j * step
    axx, ayy, axy = (np.empty(3 * n, dtype=complex) for _ in range(3))
    axx[:n], ayy[:n], axy[:n] = b00 + 2 * h * b00, b11, b01 + h * b01
    axx[n:2 * n], ayy[n:2 * n], axy[n:2 * n] = b00, b11 + 2 * h * b11, b01 + h * b01
    axx[2 * n:], ayy[2 * n:] = b00 + h * b01, b11 + h * b01
    axy[2 * n:] = b01 + h * 0.5 * (b00 + b11)
    exx, eyy, exy = log_sym2(axx, ayy, axy)
    eps_c = np.empty((3 * n, 4), dtype=complex)
    eps_c[:, 0], eps_c[:, 1], eps_c[:, 3] = exx, eyy, exy
    eps_c[:, 2] = np.tile(log_strain[:, 2], 3)
    d = _tensor(_stress_derivative(eps_c, gamma_p, soil, step)).reshape(3, n, 2, 2)
    T = _tensor(tau)
    # spin W = (E_01 - E_10)/2: d tau = W tau - tau W = [[t01, (t11-t00)/2], [.., -t01]]
    dW = np.empty((n, 2, 2))
    dW[:, 0, 0], dW[:, 1, 1] = T[:, 0, 1], -T[:, 0, 1]
    dW[:, 0, 1] = dW[:, 1, 0] = 0.5 * (T[:, 1, 1] - T[:, 0, 0])
    A = np.empty((n, 2, 2, 2, 2))
    A[..., 0, 0], A[..., 1, 1] = d[0], d[1]
    A[..., 0, 1], A[..., 1, 0] = d[2] + dW, d[2] - dW
    A[:, :, 0, 0, :] -= T                                     # - delta_jl tau_im
    A[:, :, 1, 1, :] -= T
    return tau, A


def _tensor(t4: np.ndarray) -> np.ndarray:
    """(n, 4) [xx, yy, zz, xy] -> (n, 2, 2) in-plane tensor."""
    T = np.empty((len(t4), 2, 2))
    T[:, 0, 0], T[:, 1, 1], T[:, 0, 1], T[:, 1, 0] = t4[:, 0], t4[:, 1], t4[:, 3], t4[:, 3]
    return T


def _inv2(M: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Inverse and determinant of (n, 2, 2) matrices."""
    det = M[:, 0, 0] * M[:, 1, 1] - M[:, 0, 1] * M[:, 1, 0]
    inv = np.empty_like(M)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv[:, 0, 0], inv[:, 1, 1] = M[:, 1, 1] / det, M[:, 0, 0] / det
        inv[:, 0, 1], inv[:, 1, 0] = -M[:, 0, 1] / det, -M[:, 1, 0] / det
    return inv, det


# ----------------------------------------------------------------------------- assembly
class StepSystem:
    """The grid-reset system of one step: basis at the step-start positions, DOF numbering,
    and the vectorised assembly of internal force, tangent and lumped mass.

    ``free`` numbers the DOFs that are touched by a point's basis and not
    prescribed by a boundary (``grid.fixed``); only they enter the solve.  The
    sparsity pattern is built once per step: per-point blocks are summed over
    the points sharing a node set (a host cell for Q4) by a sparse 0/1 matrix,
    and the sums go straight into the CSR data array at precomputed positions.
    """

    def __init__(self, grid: Grid, x: np.ndarray, shape: str = "standard", half_width=None,
                 fixed: np.ndarray | None = None):
        self.grid = grid
        fixed = grid.fixed if fixed is None else fixed      # (n_nodes, 2) prescribed DOFs
        self.host = host_cells(grid, x)                     # F-bar cells
        _, nodes, N, dN, _ = shape_at_points(grid, x, shape, half_width)
        self.nodes, self.N, self.dN = nodes, N, dN
        n, k = nodes.shape
        self.n, self.k = n, k
        nn = grid.n_nodes
        used = np.zeros(nn, dtype=bool)
        touch = (N != 0) | (dN != 0).any(axis=2)     # uGIMP lists nodes with zero weight
        used[nodes[touch]] = True
        self.used = used
        free_mask = (used[:, None] & ~fixed).ravel()           # dof = 2 node + comp
        self.free_dofs = np.nonzero(free_mask)[0]
        self.n_free = nf = len(self.free_dofs)
        fnum = np.full(2 * nn, -1, dtype=np.int64)
        fnum[self.free_dofs] = np.arange(nf)
        self.fnum = fnum
        self.point_dofs = (2 * nodes[:, :, None] + np.arange(2)).reshape(n, 2 * k)  # global
        # group the points by their node set (Q4: the host cell, identified by node 0)
        if k == 4:
            _, inv = np.unique(nodes[:, 0], return_inverse=True)
        else:
            _, inv = np.unique(nodes, axis=0, return_inverse=True)
        inv = inv.ravel()
        ng = int(inv.max()) + 1 if n else 0
        self.n_groups = ng
        self.group_sum = sp.csr_matrix((np.ones(n), (inv, np.arange(n))), shape=(ng, n))
        first = np.zeros(ng, dtype=np.int64)
        first[inv] = np.arange(n)                                  # a representative point
        gd = fnum[self.point_dofs[first]].reshape(ng, k, 2)        # free index or -1
        # block entries are laid out [a, i, l, b]: row dof (a, i), column dof (b, l)
        rows = np.broadcast_to(gd[:, :, :, None, None], (ng, k, 2, 2, k)).ravel()
        cols = np.broadcast_to(np.swapaxes(gd, 1, 2)[:, None, None, :, :],
                               (ng, k, 2, 2, k)).ravel()
        keep = (rows >= 0) & (cols >= 0)
        self._keep = keep
        key = rows[keep] * nf + cols[keep]
        ukey, self._pos = np.unique(key, return_inverse=True)     # CSR order: row, then column
        self._pos = self._pos.ravel()
        self._indices = (ukey % nf).astype(np.int32) if nf else ukey.astype(np.int32)
        self._indptr = np.searchsorted(ukey, np.arange(nf + 1) * nf).astype(np.int32)
        self.nnz = len(ukey)

    # --- kinematics
    def gradient(self, du: np.ndarray) -> np.ndarray:
        """grad_n(du) at the points (n, 2, 2), ``H_ij = d du_i / d x_j``; du (n_nodes, 2)."""
        return np.matmul(np.swapaxes(du[self.nodes], 1, 2), self.dN)

    def interpolate(self, nodal: np.ndarray) -> np.ndarray:
        """Nodal vector (n_nodes, 2) at the points (n, 2)."""
        return np.einsum("pa,pai->pi", self.N, nodal[self.nodes])

    def to_nodes(self, free_vec: np.ndarray, prescribed: np.ndarray | None = None) -> np.ndarray:
        """Free-DOF vector -> nodal (n_nodes, 2); the other DOFs are zero, or take the
        values of ``prescribed`` (n_nodes, 2) if given."""
        full = np.zeros(2 * self.grid.n_nodes) if prescribed is None else \
            np.array(prescribed, dtype=float).ravel()
        full[self.free_dofs] = free_vec
        return full.reshape(-1, 2)

    # --- vectors
    def _scatter(self, per_point: np.ndarray) -> np.ndarray:
        """(n, k, 2) per-point nodal contributions -> free-DOF vector."""
        full = np.bincount(self.point_dofs.ravel(), per_point.ravel(),
                           minlength=2 * self.grid.n_nodes)
        return full[self.free_dofs]

    def internal_force(self, V0: np.ndarray, tau4: np.ndarray, g: np.ndarray,
                       full: bool = False) -> np.ndarray:
        """``f_ai = sum_p V0_p tau_ij g_aj`` on the free DOFs (kN per m); ``full``: on all
        DOFs, as (n_nodes, 2) (for the reactions at prescribed DOFs)."""
        T = _tensor(tau4) * V0[:, None, None]
        per_point = np.matmul(g, T)                     # (g T)_ai = g_aj T_ji, T symmetric
        if full:
            return np.bincount(self.point_dofs.ravel(), per_point.ravel(),
                               minlength=2 * self.grid.n_nodes).reshape(-1, 2)
        return self._scatter(per_point)

    def fbar_tangent(self, V0: np.ndarray, g: np.ndarray, Q: np.ndarray,
                     w: np.ndarray) -> sp.csr_matrix:
        """The F-bar coupling term of the tangent on the free DOFs
        (:func:`fem_rmpm.locking.fbar_tangent_correction`)."""
        return fbar_tangent_correction(self.fnum[self.point_dofs], V0, g, Q, w, self.host,
                                       self.n_free)

    def body_force(self, mass: np.ndarray, gravity) -> np.ndarray:
        """``f_ai = sum_p m_p g_i N_a`` on the free DOFs (kN per m)."""
        return self._scatter(self.N[:, :, None] * mass[:, None, None]
                             * np.asarray(gravity, dtype=float))

    def lumped_mass(self, mass: np.ndarray) -> np.ndarray:
        """Nodal lumped mass ``m_a = sum_p m_p N_a`` (n_nodes,), t per m."""
        return np.bincount(self.nodes.ravel(), (self.N * mass[:, None]).ravel(),
                           minlength=self.grid.n_nodes)

    def momentum(self, mass: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Nodal ``sum_p m_p v_p N_a`` (n_nodes, 2)."""
        w = self.N * mass[:, None]
        return np.stack([np.bincount(self.nodes.ravel(), (w * v[:, k:k + 1]).ravel(),
                                     minlength=self.grid.n_nodes) for k in range(2)], axis=1)

    # --- matrix
    def tangent(self, V0: np.ndarray, g: np.ndarray, A: np.ndarray,
                diagonal: np.ndarray | None = None) -> sp.csr_matrix:
        """``K_ai,bl = sum_p V0_p g_aj A_ijlm g_bm`` (+ ``diag(diagonal)``) on the free DOFs.

        ``g`` (n, k, 2) spatial gradients, ``A`` (n, 2, 2, 2, 2); ``diagonal``
        is a free-DOF vector (e.g. the Newmark mass term 4 m / dt^2).
        """
        n, k = self.n, self.k
        # Ke[p, a, i, l, b] = V0_p g_aj A_ijlm g_bm, two batched matmuls:
        # (g A)[p, a, (i, l, m)] = g[p, a, j] A[p, j, (i, l, m)], then contract m with g_bm
        Aj = np.ascontiguousarray(A.transpose(0, 2, 1, 3, 4)).reshape(n, 2, 8)
        gA = np.matmul(g * V0[:, None, None], Aj).reshape(n, 4 * k, 2)
        Ke = np.matmul(gA, np.swapaxes(g, 1, 2)).reshape(n, 4 * k * k)
        Kg = self.group_sum @ Ke                                          # per node set
        data = np.bincount(self._pos, Kg.ravel()[self._keep], minlength=self.nnz)
        K = sp.csr_matrix((data, self._indices, self._indptr), shape=(self.n_free, self.n_free))
        if diagonal is not None:
            K = K + sp.diags(diagonal, format="csr")
        return K

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


# --------------------------------------------------------- scikit-fem forms (reference path)
def _skfem_forms():
    from skfem import BilinearForm, LinearForm

    @BilinearForm
    def tangent(u, v, w):
        """``V0/dx g(v)_ij A_ijlm g(u)_lm`` with ``g = grad . dF^-1``: K_ai,bl."""
        Finv, A = np.asarray(w["Finv"]), np.asarray(w["A"])
        gu = np.einsum("lk...,km...->lm...", u.grad, Finv)
        gv = np.einsum("ik...,kj...->ij...", v.grad, Finv)
        return np.einsum("ij...,ijlm...,lm...->...", gv, A, gu) * np.asarray(w["scale"])

    @LinearForm
    def force(v, w):
        """``V0/dx tau_ij g(v)_ij`` (internal force) and ``m/dx g_i v_i`` (body force)."""
        Finv, T = np.asarray(w["Finv"]), np.asarray(w["tau"])
        gv = np.einsum("ik...,kj...->ij...", v.grad, Finv)
        return (np.einsum("ij...,ij...->...", T, gv) * np.asarray(w["scale"]))

    return tangent, force


def skfem_tangent_form():
    """The scikit-fem BilinearForm of the consistent tangent (material points as quadrature)."""
    return _skfem_forms()[0]


def skfem_force_form():
    """The scikit-fem LinearForm of the internal force (material points as quadrature)."""
    return _skfem_forms()[1]


def skfem_assemble(grid: Grid, x: np.ndarray, V0: np.ndarray, dF: np.ndarray,
                   tau4: np.ndarray, A: np.ndarray):
    """Tangent (full DOF numbering, csr) and internal force assembled by ``skfem.asm``.

    The points ``x`` are the quadrature points (one element per point, weight 1,
    so ``dx`` is the host cell's Jacobian and the forms are scaled by ``V0 / dx``).
    Used to verify :meth:`StepSystem.tangent` / :meth:`StepSystem.internal_force`
    and in ``validation/bench_implicit.py``.
    """
    from skfem import asm

    from .shape import skfem_point_basis

    tangent, force = _skfem_forms()
    basis = skfem_point_basis(grid, x)
    scale = V0[:, None] / basis.dx
    Finv, _ = _inv2(dF)
    FinvT = np.moveaxis(Finv, 0, -1)[..., None]               # (2, 2, n, 1)
    AT = np.moveaxis(A, 0, -1)[..., None]                      # (2, 2, 2, 2, n, 1)
    TT = np.moveaxis(_tensor(tau4), 0, -1)[..., None]
    K = asm(tangent, basis, Finv=FinvT, A=AT, scale=scale)
    f = asm(force, basis, Finv=FinvT, tau=TT, scale=scale)
    return K.tocsr(), f


# ----------------------------------------------------------------------------- linear solve
class LinearSolveError(RuntimeError):
    pass


class LinearSolver:
    """``"superlu"``: LU with MMD_AT_PLUS_A ordering; ``"pyamg"``: CG (GMRES fallback)
    preconditioned by smoothed aggregation with rigid-body modes, hierarchy kept per step."""

    def __init__(self, kind: str = "superlu"):
        self.kind = kind
        self._ml = None

    def new_step(self) -> None:
        self._ml = None

    def solve(self, K: sp.csr_matrix, b: np.ndarray, modes=None, rtol: float = 1e-10) -> np.ndarray:
        if self.kind == "superlu":
            try:
                lu = splu(K.tocsc(), permc_spec="MMD_AT_PLUS_A")
            except RuntimeError as exc:           # "Factor is exactly singular"
                raise LinearSolveError(f"SuperLU: {exc}") from None
            x = lu.solve(b)
            if not np.all(np.isfinite(x)):
                raise LinearSolveError("SuperLU returned a non-finite solution (singular tangent)")
            return x
        import pyamg
        from scipy.sparse.linalg import cg, gmres
        if self._ml is None:
            B = modes() if callable(modes) else modes
            self._ml = pyamg.smoothed_aggregation_solver(K, B=B, max_coarse=500,
                                                         coarse_solver="splu")
        M = self._ml.aspreconditioner(cycle="V")
        x, info = cg(K, b, rtol=rtol, atol=0.0, maxiter=500, M=M)
        if info != 0 or not np.all(np.isfinite(x)):
            x, info = gmres(K, b, rtol=rtol, atol=0.0, restart=60, maxiter=20, M=M)
            if info != 0 or not np.all(np.isfinite(x)):
                raise LinearSolveError(f"pyamg-preconditioned CG and GMRES did not reach "
                                       f"rtol {rtol:.1e} (info {info})")
        return x


# ----------------------------------------------------------------------------- Newton
class NewtonFailure(RuntimeError):
    def __init__(self, reason: str, residuals: list[float]):
        super().__init__(reason)
        self.reason, self.residuals = reason, residuals


@dataclass
class NewtonResult:
    du: np.ndarray              # free-DOF increment
    residuals: list[float]      # relative residual before each solve and at the end
    iterations: int             # linear solves
    t_solve: float = 0.0        # s (factorisation and solve)
    t_material: float = 0.0     # s (stress update and consistent tangent at the points)
    t_assembly: float = 0.0     # s (kinematics, internal force, tangent matrix)
    t_setup: float = 0.0        # s (basis at the points, DOF numbering, sparsity pattern)
    state: tuple = ()           # what the last evaluation returned (material state)


def newton(evaluate, tangent, du0: np.ndarray, solver: LinearSolver, max_iterations: int,
           tol: float, modes=None, line_search: int = 4) -> NewtonResult:
    """Full Newton-Raphson on the free DOFs, with a backtracking line search.

    ``evaluate(du) -> (R, ref, state)``: residual (free DOFs), its reference
    norm and whatever the caller needs at convergence; may raise
    :class:`NewtonFailure`.  ``tangent() -> K`` the consistent tangent at the
    last evaluated ``du``.  Converged when ``|R| <= tol ref0`` and the correction
    the next iteration would make, estimated as ``|delta_k| r_{k+1} / r_k``, is
    ``<= sqrt(tol) |du|`` (see the module docstring).

    Line search: a full correction that does not lower the residual is halved up
    to ``line_search`` times (the last, smallest one is kept if none helps).  Near
    the solution full steps always lower the residual, so quadratic convergence is
    untouched; far from it, or where the softening law has a kink (the linear law
    reaching the residual cohesion), it stops the 2-cycles Newton otherwise falls into.
    """
    def _evaluate(u):
        try:
            return evaluate(u)
        except NewtonFailure as exc:
            raise NewtonFailure(exc.reason, res) from None

    du = du0.copy()
    res: list[float] = []
    t_sol = 0.0
    last_delta = 0.0
    R, ref, state = _evaluate(du)
    ref0 = max(ref, float(np.linalg.norm(R)))
    for it in range(max_iterations + 1):
        rn = float(np.linalg.norm(R))
        r = rn / ref0 if ref0 > 0 else 0.0
        res.append(r)
        if not math.isfinite(r):
            raise NewtonFailure("non-finite residual", res)
        if r > 1e3 * max(1.0, res[0]):
            raise NewtonFailure("diverging (residual grew 1000-fold)", res)
        # correction the next iteration would make, |delta_k| r_{k+1} / r_k
        predicted = last_delta * r / res[-2] if it > 0 and res[-2] > 0 else 0.0
        if r <= tol and predicted <= math.sqrt(tol) * float(np.linalg.norm(du)):
            return NewtonResult(du, res, it, t_sol, state=state)
        if it == max_iterations:
            break
        K = tangent()
        t1 = time.perf_counter()
        eta = min(1e-3, max(1e-12, 0.1 * r))
        try:
            delta = solver.solve(K, R, modes, rtol=eta)
        except LinearSolveError as exc:
            raise NewtonFailure(f"linear solve failed ({exc})", res) from None
        t_sol += time.perf_counter() - t1
        alpha = 1.0
        for _ in range(line_search + 1):
            R, ref, state = _evaluate(du + alpha * delta)
            if float(np.linalg.norm(R)) < rn or alpha < 0.5 ** (line_search - 0.5):
                break
            alpha *= 0.5
        du = du + alpha * delta
        last_delta = alpha * float(np.linalg.norm(delta))
    raise NewtonFailure(f"not converged in {max_iterations} iterations", res)


# ----------------------------------------------------------------------------- steps
@dataclass
class _StepOutcome:
    result: NewtonResult
    commit: object                # callable applying the converged step to the points


class _Stepper:
    """Builds and solves one step of a given kind for the active points (no side effects
    until ``commit()`` is called)."""

    def __init__(self, scene: Scene, grid: Grid, pts: Particles, solver: LinearSolver):
        self.scene, self.grid, self.pts, self.solver = scene, grid, pts, solver
        self.sv = scene.solver
        self.fbar = bool(self.sv.fbar)
        self.g_full = np.array(scene.gravity_vector, dtype=float)
        self.acc = np.zeros((pts.n, 2))          # point accelerations (dynamic)
        self.regions = prescribed_nodes(scene, grid)
        mask = np.zeros((grid.n_nodes, 2), dtype=bool)
        target = np.zeros((grid.n_nodes, 2))     # prescribed displacement at load factor 1
        for r in self.regions:
            mask |= r["mask"]
            target[r["mask"]] = np.broadcast_to(r["displacement"], r["mask"].shape)[r["mask"]]
        self.presc_mask, self.presc_target = mask, target
        self.fixed = grid.fixed | mask

    def _setup(self):
        pts = self.pts
        act = np.nonzero(pts.active)[0]
        if len(act) == 0:
            raise SimulationError("no active material point left (all frozen at the grid "
                                  "edge); enlarge [grid] size")
        sys_ = StepSystem(self.grid, pts.x[act], self.sv.shape,
                          pts.half_width[act] if pts.half_width is not None else None,
                          fixed=self.fixed)
        return act, sys_

    # -- geostatic (small strain, fixed geometry) and quasi-static / dynamic large deformation
    def step(self, kind: str, lf_new: float, dt: float = 0.0,
             lf_old: float | None = None) -> _StepOutcome:
        """``kind``: "geostatic" | "static" | "dynamic"; ``lf_new`` the gravity factor at
        the end of the step; ``dt`` the time step (dynamic); ``lf_old`` the load factor at
        its start (prescribed displacements grow by ``(lf_new - lf_old)`` x their value)."""
        pts = self.pts
        clock = {"material": 0.0, "assembly": 0.0}
        t_setup = time.perf_counter()
        act, S = self._setup()
        t_setup = time.perf_counter() - t_setup
        V0, mass = pts.volume0[act], pts.mass[act]
        Vn = pts.volume[act]                          # F-bar weights: volumes at step start
        ls0, gp0, soil = pts.log_strain[act], pts.plastic_shear_strain[act], pts.soil.take(act)
        f_ext = S.body_force(mass, lf_new * self.g_full)
        dyn = kind == "dynamic"
        presc = None
        if self.presc_mask.any():
            if dyn or lf_old is None:
                raise SimulationError("prescribed displacements need quasi-static load steps")
            presc = np.where(self.presc_mask, (lf_new - lf_old) * self.presc_target, 0.0)
        if dyn:
            m_nodes = S.lumped_mass(mass)
            has = m_nodes > _MASS_TOL
            inv_m = np.where(has, 1.0 / np.where(has, m_nodes, 1.0), 0.0)[:, None]
            v_n = (S.momentum(mass, pts.velocity[act]) * inv_m).ravel()[S.free_dofs]
            a_n = (S.momentum(mass, self.acc[act]) * inv_m).ravel()[S.free_dofs]
            m_free = np.repeat(m_nodes, 2)[S.free_dofs]
            c = 4.0 / (dt * dt)
            du0 = dt * v_n + 0.5 * dt * dt * a_n
        else:
            du0 = np.zeros(S.n_free)
        cache = {}
        nc = self.grid.n_cells

        def evaluate(du_free):
            t0 = time.perf_counter()
            H = S.gradient(S.to_nodes(du_free, presc))
            if kind == "geostatic":
                Hm = bbar_gradient(H, Vn, S.host, nc) if self.fbar else H
                t1 = time.perf_counter()
                ls, gp, tau = small_strain_update(Hm, ls0, gp0, soil)
                t2 = time.perf_counter()
                g = S.dN
                cache.update(H=Hm, g=g, tau=tau)
                dFm = None
            else:
                dF = _EYE + H
                Finv, det = _inv2(dF)
                if not np.all(det > 0):
                    i = act[np.argmin(det)]
                    raise NewtonFailure(f"material point {i} inverted (det dF = "
                                        f"{det.min():.3g})", [])
                if self.fbar:
                    dFm, J, _ = fbar_increment(dF, Vn, S.host, nc)
                    cache["w"] = fbar_weights(Vn, J, S.host, nc)
                else:
                    dFm = dF
                t1 = time.perf_counter()
                ls, gp, tau = stress_update(dFm, ls0, gp0, soil)
                t2 = time.perf_counter()
                g = np.matmul(S.dN, Finv)
                cache.update(H=H, dF=dFm, g=g, tau=tau)
            f_int = S.internal_force(V0, tau, g)
            clock["material"] += t2 - t1
            clock["assembly"] += time.perf_counter() - t0 - (t2 - t1)
            R = f_ext - f_int
            ref = float(np.linalg.norm(f_ext))
            if presc is not None:      # the prescribed motion drives the step
                ref = max(ref, float(np.linalg.norm(S.internal_force(V0, tau, g, full=True))))
            if dyn:
                a_new = c * (du_free - dt * v_n) - a_n
                R = R - m_free * a_new
            return R, ref, (ls, gp, tau, dFm)

        def tangent():
            t0 = time.perf_counter()
            if kind == "geostatic":
                _, A = small_strain_tangent(cache["H"], ls0, gp0, soil)
            else:
                if "b_e" not in cache:
                    cache["b_e"] = elastic_left_cauchy_green(ls0)
                _, A = finite_strain_tangent(cache["dF"], ls0, gp0, soil, b_e=cache["b_e"],
                                             tau=cache["tau"])
            t1 = time.perf_counter()
            K = S.tangent(V0, cache["g"], A, diagonal=(c * m_free) if dyn else None)
            if self.fbar:
                geo = kind == "geostatic"
                w = Vn / np.bincount(S.host, Vn, minlength=nc)[S.host] if geo else cache["w"]
                K = K + S.fbar_tangent(V0, cache["g"], fbar_q(A, None if geo else cache["tau"]),
                                       w)
            clock["material"] += t1 - t0
            clock["assembly"] += time.perf_counter() - t1
            return K

        self.solver.new_step()
        res = newton(evaluate, tangent, du0, self.solver, self.sv.max_iterations,
                     self.sv.tolerance, modes=S.rigid_body_modes)
        res.t_material, res.t_assembly, res.t_setup = (clock["material"], clock["assembly"],
                                                       t_setup)

        def reactions():
            """Force (kN/m) of each prescribed region on the soil: f_int - f_ext there."""
            if presc is None:
                return {}
            _, _, tau, _ = res.state
            g = S.dN if kind == "geostatic" else np.matmul(
                S.dN, _inv2(_EYE + S.gradient(S.to_nodes(res.du, presc)))[0])
            r = S.internal_force(V0, tau, g, full=True) - np.bincount(
                S.point_dofs.ravel(), (S.N[:, :, None] * mass[:, None, None]
                                       * (lf_new * self.g_full)).ravel(),
                minlength=2 * self.grid.n_nodes).reshape(-1, 2)
            return {"reactions": {reg["name"]: [float(v) for v in r[reg["nodes"]].sum(axis=0)]
                                  for reg in self.regions}}

        def commit():
            ls, gp, tau, dFm = res.state
            info = reactions()
            du_nodes = S.to_nodes(res.du, presc)
            u_p = S.interpolate(du_nodes)
            pts.log_strain[act], pts.plastic_shear_strain[act] = ls, gp
            if kind == "geostatic":
                pts.u_geostatic[act] += u_p
                pts.stress[act] = tau
                return info
            pts.x[act] = pts.x[act] + u_p
            pts.F[act] = dFm @ pts.F[act]
            F = pts.F[act]
            J = F[:, 0, 0] * F[:, 1, 1] - F[:, 0, 1] * F[:, 1, 0]
            pts.volume[act] = J * V0
            pts.stress[act] = tau / J[:, None]
            if not dyn:
                return info
            a_new = c * (res.du - dt * v_n) - a_n
            v_new = v_n + 0.5 * dt * (a_n + a_new)
            a_nodes, v_nodes = S.to_nodes(a_new), S.to_nodes(v_new)
            dv_nodes = S.to_nodes(v_new - v_n)
            v_pic = S.interpolate(v_nodes)
            flip = self.sv.flip
            pts.velocity[act] = flip * (pts.velocity[act] + S.interpolate(dv_nodes)) \
                + (1 - flip) * v_pic
            self.acc[act] = S.interpolate(a_nodes)
            ke = 0.5 * float(np.sum(m_free * v_new * v_new))
            return {"kinetic_energy": ke,
                    "max_speed": float(np.sqrt(np.max(np.sum(v_pic * v_pic, 1), initial=0.0)))}

        return _StepOutcome(res, commit)


def prescribed_nodes(scene: Scene, grid: Grid) -> list[dict]:
    """The ``[[prescribed]]`` regions of a scene on its grid: per region its ``name``, the
    ``nodes`` in or on its polygon, the (n_nodes, 2) ``mask`` of prescribed components
    and the ``displacement`` (2,) at load factor 1.  A region that holds no grid node is
    a :class:`SceneError`."""
    out = []
    p = grid.nodes
    tol = 1e-6 * float(np.min(grid.cell))
    for i, pr in enumerate(getattr(scene, "prescribed", ())):
        poly = np.asarray(pr.polygon, dtype=float)
        on = points_in_polygon(p, poly)
        for a, b in zip(poly, np.roll(poly, -1, axis=0)):
            ab = b - a
            t = np.clip(((p - a) @ ab) / max(float(ab @ ab), 1e-300), 0.0, 1.0)
            on |= np.linalg.norm(p - (a + t[:, None] * ab), axis=1) <= tol
        nodes = np.nonzero(on)[0]
        if len(nodes) == 0:
            raise SceneError(f"{scene.source}: [prescribed[{i}].polygon] holds no grid node; "
                             "allowed: a polygon containing or touching grid nodes (m)")
        mask = np.zeros((grid.n_nodes, 2), dtype=bool)
        comps = [k for k, c in enumerate("xy") if c in pr.components]
        mask[np.ix_(nodes, comps)] = True
        out.append({"name": pr.name if pr.name != "prescribed" or len(scene.prescribed) == 1
                    else f"{pr.name}{i}", "nodes": nodes, "mask": mask,
                    "displacement": np.array(pr.displacement, dtype=float)})
    return out


# ----------------------------------------------------------------------------- driver
def _advice(kind: str, sv) -> str:
    if kind == "dynamic":
        return (f"reduce [solver] dt (now {sv.dt:g} s), increase max_iterations (now "
                f"{sv.max_iterations}) or max_cuts (now {sv.max_cuts}), or loosen tolerance "
                f"(now {sv.tolerance:g}); a residual that stalls at a level points to a kink "
                "in the material response (softening reaching the residual cohesion): "
                "softening = \"exponential\" is smooth")
    return (f"increase [solver] load_steps (now {sv.load_steps}), max_iterations (now "
            f"{sv.max_iterations}) or max_cuts (now {sv.max_cuts}), or loosen tolerance (now "
            f"{sv.tolerance:g}); a residual that stalls instead of falling quadratically means "
            "the soil cannot carry the load (limit load reached): run it with dynamic = true")


def run_implicit(scene: Scene, grid: Grid, pts: Particles, on_output=None,
                 progress=None) -> RunRecord:
    """Run the implicit scheme on ``pts`` (in place) and return its :class:`RunRecord`.

    Phases (see the module docstring): ``gravity_phase = "geostatic"`` first
    applies gravity in ``load_steps`` small-strain steps on the fixed geometry;
    then with ``dynamic = true`` Newmark steps of ``dt`` run under gravity
    (ramped over ``gravity_ramp_time`` unless the geostatic phase applied it)
    until ``t_end`` or at rest (max point speed < ``rest_velocity`` and grid
    kinetic energy <= ``rest_energy_ratio`` x its peak, gravity fully on).
    With ``dynamic = false`` and ``gravity_phase = "dynamic"`` gravity is
    applied in ``load_steps`` quasi-static large-deformation steps.

    ``on_output(t, pts)``: quasi-static, at the start and after every converged
    load step with ``t`` = the load factor (0..1); dynamic, at t = 0 (after the
    geostatic phase, if any), every ``output_interval`` and at the end.
    ``progress(t, step)``: ``t`` is the simulated time, or for quasi-static
    steps the load factor times ``t_end`` (so a bar over t_end fills up).
    ``record.solver["steps"]`` lists every converged step with its residual
    history.  Raises :class:`SimulationError` (with ``solver_stats``) when a step
    cannot be converged; the points then hold the last converged state, which
    has been passed to ``on_output``.
    """
    sv = scene.solver
    rec = RunRecord(scheme="implicit")
    solver = LinearSolver(sv.linear_solver)
    stepper = _Stepper(scene, grid, pts, solver)
    stats = {"formulation": "updated Lagrangian, Hencky/Kirchhoff, full Newton-Raphson",
             "time_integration": "Newmark trapezoidal (beta 1/4, gamma 1/2), lumped mass"
             if sv.dynamic else "quasi-static load stepping",
             "linear_solver": sv.linear_solver, "tolerance": sv.tolerance,
             "displacement_tolerance": math.sqrt(sv.tolerance),
             "max_iterations": sv.max_iterations, "max_cuts": sv.max_cuts,
             "iterations_total": 0, "cuts_total": 0, "setup_time": 0.0, "material_time": 0.0,
             "assembly_time": 0.0, "solve_time": 0.0,
             "steps": []}
    rec.solver = stats
    wall0 = time.perf_counter()
    state = {"t": 0.0, "step": 0, "written_t": None}

    def output(t):
        if on_output is not None:
            on_output(t, pts)
        state["written_t"] = t

    def fail(kind, label, failure: NewtonFailure, n_cuts, size):
        # the points hold the last converged state: write it if not written yet
        if state["written_t"] is None or state["written_t"] != state["t"]:
            output(state["t"])
        hist = ", ".join(f"{r:.2e}" for r in failure.residuals) or "none"
        msg = (f"{label}: Newton did not converge after {n_cuts} cut(s) down to a step of "
               f"{size:.4g} ({failure.reason}); relative residuals of the last attempt: "
               f"[{hist}] (tolerance {sv.tolerance:g}). Output holds the last converged "
               f"state (step {state['step']}). To go on: {_advice(kind, sv)}")
        stats.update(last_converged_step=state["step"], last_converged_time=state["t"],
                     failed_step=label, failed_residuals=failure.residuals)
        rec.steps, rec.time = state["step"], state["t"]
        rec.error, rec.stop_reason = msg, "error"
        rec.wall_time = time.perf_counter() - wall0
        exc = SimulationError(msg)
        exc.solver_stats = stats          # merged into summary.json by api.run
        exc.record = rec                  # the record up to the last converged step
        raise exc

    def advance(kind, a0, a1, label, time_of, gravity_of):
        """Cover [a0, a1] (load factor or time) with converged substeps; cut on failure."""
        pos, size, cuts, last = a0, a1 - a0, 0, None
        while pos < a1 - 1e-12 * max(1.0, abs(a1)):
            h = min(size, a1 - pos)
            try:
                out = stepper.step(kind, gravity_of(pos + h), h if kind == "dynamic" else 0.0,
                                   None if kind == "dynamic" else gravity_of(pos))
            except NewtonFailure as f:
                last = f
                if cuts >= sv.max_cuts:
                    fail(kind, label, last, cuts, h)
                cuts += 1
                stats["cuts_total"] += 1
                size = 0.5 * h
                continue
            info = out.commit() or {}
            pos += h
            res = out.result
            state["step"] += 1
            state["t"] = time_of(pos)
            stats["iterations_total"] += res.iterations
            stats["assembly_time"] += res.t_assembly
            stats["material_time"] += res.t_material
            stats["setup_time"] += res.t_setup
            stats["solve_time"] += res.t_solve
            stats["steps"].append({"step": state["step"], "phase": kind,
                                   ("time" if kind == "dynamic" else "load_factor"): pos,
                                   "size": h, "iterations": res.iterations, "cuts": cuts,
                                   "residuals": res.residuals})
            if "reactions" in info:
                stats["steps"][-1]["reactions"] = info.pop("reactions")
            check_points(grid, pts, state["step"], state["t"], sv.edge_policy, rec)
            yield info

    if not (sv.dynamic and sv.gravity_phase == "geostatic"):
        output(0.0)
    n_ls = sv.load_steps
    quasi = not sv.dynamic
    if sv.gravity_phase == "geostatic" or quasi:
        kind = "geostatic" if sv.gravity_phase == "geostatic" else "static"
        for k in range(n_ls):
            a0, a1 = k / n_ls, (k + 1) / n_ls
            label = (f"{'geostatic' if kind == 'geostatic' else 'load'} step {k + 1} of {n_ls} "
                     f"(load factor {a0:.4g} -> {a1:.4g})")
            for _ in advance(kind, a0, a1, label, (lambda p: p if quasi else 0.0),
                             lambda p: p):
                if quasi:
                    output(state["t"])
                    if progress:
                        progress(state["t"] * sv.t_end, state["step"])
        if kind == "geostatic":
            stats["geostatic_steps"] = state["step"]
        rec.time = 1.0 if quasi else 0.0
        rec.stop_reason = "load applied" if quasi else ""
    if sv.dynamic:
        if sv.gravity_phase == "geostatic":
            state["t"] = 0.0
            output(0.0)
        ramp = 0.0 if sv.gravity_phase == "geostatic" else sv.gravity_ramp_time

        def gravity_of(t):
            return 1.0 if ramp <= 0 else min(1.0, t / ramp)

        t, next_out, ke_peak = 0.0, sv.output_interval, 0.0
        n_dyn = 0
        rec.stop_reason = "t_end reached"
        while t < sv.t_end - 1e-12:
            t1 = min(t + sv.dt, sv.t_end)
            label = f"time step {n_dyn + 1} (t = {t:.4g} -> {t1:.4g} s)"
            rest = False
            for info in advance("dynamic", t, t1, label, lambda p: p, gravity_of):
                tt = state["t"]
                h = stats["steps"][-1]["size"]
                rec.dt_min, rec.dt_max = min(rec.dt_min, h), max(rec.dt_max, h)
                ke = info.get("kinetic_energy", 0.0)
                ke_peak = max(ke_peak, ke)
                rec.energy.append((tt, ke))
                rest = at_rest(tt, ramp, info.get("max_speed", 0.0), ke, ke_peak,
                               sv.rest_velocity, sv.rest_energy_ratio)
            t = t1
            n_dyn += 1
            if progress:
                progress(t, state["step"])
            if on_output and t >= next_out - 1e-12:
                output(t)
                next_out += sv.output_interval
            if rest:
                rec.stop_reason = "at rest"
                break
        rec.time = t
        if state["written_t"] != t:
            output(t)
    its = stats["iterations_total"]
    stats["ms_per_iteration"] = {
        k: 1e3 * stats[f"{k}_time"] / max(its, 1)
        for k in ("setup", "material", "assembly", "solve")}
    stats["max_iterations_in_a_step"] = max((s["iterations"] for s in stats["steps"]),
                                            default=0)
    rec.steps = state["step"]
    rec.wall_time = time.perf_counter() - wall0
    return rec
