"""Implicit MPM: updated-Lagrangian Newton-Raphson with the consistent tangent.

Three kinds of step share one Newton solver (:class:`StepSystem` + :func:`newton`):

* **Quasi-static load steps** (``[solver] dynamic = false``): gravity is applied
  in ``load_steps`` equal increments of the load factor.  Each step the grid is
  reset ("updated Lagrangian"): the basis is evaluated at the step-start
  positions ``x_n`` and the unknown is the nodal displacement increment ``du``.
  At a point ``dF = I + grad_n(du)`` (gradient in the step-start configuration),
  the material (:func:`fem_rmpm.materials.stress_update`, Hencky/Kirchhoff) gives
  the Kirchhoff stress ``tau``, and with the spatial gradients
  ``g = dF^-T grad_n N``::

      f_int_ai = sum_p V0_p tau_ij g_aj                      (internal force)
      K_ai,bl  = sum_p V0_p g_aj A_ijlm g_bm                  (consistent tangent)

  ``A`` (:func:`fem_rmpm.materials.spatial_tangent`) holds the material tangent
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
  in-situ geometry, small strain (:func:`fem_rmpm.materials.small_strain_update`),
  points do not move (the displacement goes to ``pts.u_geostatic``).  The
  tangent is ``d tau / d grad(du)`` by complex step (:func:`small_strain_tangent`).
  With linear elastic points at the 2x2 Gauss points one step is exactly the
  scikit-fem Q4 solution (:func:`fem_rmpm.schemes.fem.solve_static`).  The geostatic
  phase is always quasi-static; with ``dynamic = true`` the Newmark phase
  follows from rest under full gravity.

**Assembly.**  The material points are the quadrature points: scikit-fem's
``CellBasis`` with one "element" per point (:func:`fem_rmpm.discretise.basis.skfem_point_basis`)
and the forms :func:`skfem_tangent_form` / :func:`skfem_force_form` assemble
``K`` and ``f_int`` exactly as written above.  The run uses the vectorised
numpy path (:meth:`StepSystem.tangent`) which evaluates the same sums from the
fast Q4 (or uGIMP) basis of :mod:`fem_rmpm.discretise.basis`: per-point 8x8 blocks summed
per node set, then one CSR build of the free DOFs only.  ``tests/test_implicit.py``
checks the two agree to round-off; scikit-fem's ``asm`` is 25-50x slower here
(``validation/bench_implicit.py`` measures both).  The consistent tangent is
:func:`finite_strain_tangent`: the exact derivative of the same update as
:func:`fem_rmpm.materials.spatial_tangent` (tested equal to round-off), from compiled
kinematics and the model's analytic ``tangent`` hook where it has one (else the complex
step of its ``update``), about 10x faster than the complex step of the whole update.

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
:class:`~fem_rmpm.schemes.common.SimulationError` names the step, the residual
history and what to change.  The state of the last converged step is kept (and
written), nothing non-finite is ever accepted.

**Linear solvers** (``[solver] linear_solver``): ``"cholmod"`` (default): sparse
Cholesky (SuiteSparse CHOLMOD, through cvxopt) with the symbolic analysis reused while
the sparsity pattern stays; a tangent that is not symmetric positive definite (F-bar,
non-associated flow, softening under large quasi-static steps) goes to SuperLU for that
solve (``summary.json``: ``solver.factorizations_by``).  ``"superlu"``: sparse LU of the
free-DOF tangent with ``permc_spec = "MMD_AT_PLUS_A"`` (about 2x the default ordering on
these 2-D meshes), the ordering reused while the pattern stays.  ``"pyamg"``: conjugate
gradients preconditioned by pyamg smoothed aggregation whose near-null space is the three
2-D rigid-body modes (the default constant vectors fail to converge on
elasticity) and a sparse-LU coarse solve; the hierarchy is built once per step
and reused by its Newton iterations; GMRES takes over if CG fails (softening
makes the tangent indefinite).  Measured (``validation/bench_implicit.py``, one
BLAS thread): at 9235 DOFs (case (i)) a CHOLMOD factorization costs about 3 ms CPU
against 15-20 ms for SuperLU; pyamg is ~2x faster than SuperLU at 10^5 DOFs.  The inner
tolerance follows the residual (inexact Newton with forcing term
``min(1e-3, max(1e-12, 0.1 r_k))``), which keeps the outer convergence quadratic.

**Volumetric locking** (``[solver] fbar = true``): F-bar with cell averaging
(:mod:`fem_rmpm.schemes.locking`, de Souza Neto et al. 1996): the material sees
``dF_bar = (dJ_bar / dJ)^(1/2) dF``, ``dJ_bar`` the volume-weighted mean over the
points of the host cell (geostatic steps: B-bar, its small-strain linearisation).
The internal force is the work conjugate of the F-bar deformation,
``sum_p V0 (tau + e I) g`` with the true spatial gradients ``g`` and the in-plane mean of
``tau`` replaced by its cell's (:func:`fem_rmpm.schemes.locking.fbar_work_stress`; geostatic:
``sum V0 Bbar^T tau``); the consistent tangent gains the analytic cell-coupling terms
(:meth:`StepSystem.fbar_tangent`, ``fbar_work_tangent``, ``bbar_tangent``), so Newton
stays quadratic (``tests/test_locking.py``).  Points store ``F <- dF_bar F`` and
``V = det(F) V0``.  ``[solver] locking_constraint = "pressure"`` (geostatic steps): one
in-plane mean stress per cell instead of one volume change, for dilatant plastic flow
(:func:`fem_rmpm.schemes.locking.uniform_cell_pressure`).

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

**Package layout.**  :mod:`.tangent` (consistent tangents of the material update),
:mod:`.assembly` (the grid-reset system and its vectorised assembly), :mod:`.skfem_forms`
(the scikit-fem reference forms), :mod:`.linear` (linear solvers), :mod:`.newton` (the
Newton iteration), :mod:`.steps` (the geostatic, quasi-static and Newmark step kinds over
one shared system), :mod:`.driver` (phases, step cutting, output, the run record).
"""
from fem_rmpm.schemes.common import SimulationError
from fem_rmpm.schemes.implicit.assembly import StepSystem, rigid_body_modes
from fem_rmpm.schemes.implicit.driver import run_implicit
from fem_rmpm.schemes.implicit.dynamic import NewmarkDynamic
from fem_rmpm.schemes.implicit.linear import LinearSolveError, LinearSolver
from fem_rmpm.schemes.implicit.newton import NewtonFailure, NewtonResult, newton
from fem_rmpm.schemes.implicit.skfem_forms import (
    skfem_assemble,
    skfem_force_form,
    skfem_tangent_form,
)
from fem_rmpm.schemes.implicit.steps import (
    Geostatic,
    ImplicitSystem,
    QuasiStatic,
    StepKind,
    prescribed_nodes,
)
from fem_rmpm.schemes.implicit.tangent import (
    elastic_left_cauchy_green,
    finite_strain_tangent,
    small_strain_tangent,
)

__all__ = ["small_strain_tangent", "finite_strain_tangent", "elastic_left_cauchy_green",
           "StepSystem", "LinearSolver", "LinearSolveError", "NewtonFailure", "newton",
           "NewtonResult", "run_implicit", "skfem_tangent_form", "skfem_force_form",
           "skfem_assemble", "rigid_body_modes", "prescribed_nodes", "ImplicitSystem",
           "StepKind", "Geostatic", "QuasiStatic", "NewmarkDynamic", "SimulationError"]
