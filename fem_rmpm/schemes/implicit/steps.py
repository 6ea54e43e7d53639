"""The three kinds of implicit step over one shared system.

:class:`ImplicitSystem` holds what every step of a run shares (grid, points, prescribed
regions, linear solver); :meth:`ImplicitSystem.begin` builds the grid-reset
:class:`StepData` of one step (basis at the step-start positions, step-start material
state, external force).  A step kind is a small class with

* ``predictor(st)``: the starting increment of the Newton iteration,
* ``residual(st, du) -> (R, ref, state)``: out-of-balance force on the free DOFs, its
  reference norm and the material state at ``du``,
* ``tangent(st) -> K``: the consistent tangent at the last evaluated ``du``,
* ``commit(st, result) -> info``: applies the converged step to the points,

and :meth:`StepKind.solve` runs the Newton iteration of one step with them.  The kinds:
:class:`Geostatic` (small strain, fixed geometry), :class:`QuasiStatic` (large
deformation load step) and, in :mod:`.dynamic`, :class:`~.dynamic.NewmarkDynamic`
(trapezoidal rule, lumped mass).
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from fem_rmpm.discretise.grid import Grid, points_in_polygon
from fem_rmpm.discretise.points import Particles
from fem_rmpm.materials import MaterialPoints, small_strain_update, stress_update
from fem_rmpm.scene import Scene, SceneError
from fem_rmpm.schemes.common import SimulationError
from fem_rmpm.schemes.explicit import kernels
from fem_rmpm.schemes.implicit import point_kernels as pk
from fem_rmpm.schemes.implicit import step_kernels as sk
from fem_rmpm.schemes.implicit.assembly import StepSystem
from fem_rmpm.schemes.implicit.linear import LinearSolver
from fem_rmpm.schemes.implicit.newton import NewtonFailure, NewtonResult, newton
from fem_rmpm.schemes.pore_pressure import nodal_water_force, water_table
from fem_rmpm.schemes.implicit.tangent import (
    elastic_left_cauchy_green,
    finite_strain_parts,
    finite_strain_tangent,
    inv2,
    small_strain_tangent,
)
from fem_rmpm.schemes.locking import (
    bbar_force_stress,
    bbar_gradient,
    fbar_increment,
    fbar_q,
    fbar_weights,
    fbar_work_stress,
    uniform_cell_pressure,
)

__all__ = ["ImplicitSystem", "StepData", "StepKind", "Geostatic", "QuasiStatic",
           "prescribed_nodes"]

_MASS_TOL = 1e-14
#: BFGS iterations per factorized tangent in a dynamic step (:func:`.newton.newton`)
QUASI_NEWTON = 6
_EYE = np.eye(2)


@dataclass
class StepData:
    """One step's grid-reset system and the step-start state of its active points."""
    S: StepSystem
    act: np.ndarray                 # indices of the active points
    V0: np.ndarray                  # initial volumes (m2 per m)
    Vn: np.ndarray                  # volumes at step start (F-bar weights)
    mass: np.ndarray                # t per m
    ls0: np.ndarray                 # elastic log strain at step start (n, 4)
    state0: np.ndarray                 # state variables of the points' models at step start (n, S)
    soil: MaterialPoints
    f_ext: np.ndarray               # body force on the free DOFs at the step end (kN per m)
    lf_new: float                   # gravity factor at the step end
    lf_old: float                   # gravity factor at the step start
    presc: np.ndarray | None        # prescribed nodal increment (n_nodes, 2), or None
    dt: float = 0.0                 # time step (s), dynamic steps
    cache: dict = field(default_factory=dict)     # the last evaluation, for the tangent
    clock: dict = field(default_factory=lambda: {"material": 0.0, "assembly": 0.0})


@dataclass
class StepOutcome:
    result: NewtonResult
    commit: object                  # callable applying the converged step to the points
    limits: object = None           # callable: the step's kinematic figures (see StepKind)


class ImplicitSystem:
    """What all steps of an implicit run share: scene, grid, points (changed only by a
    step's ``commit``), prescribed regions, the linear solver and the point accelerations."""

    def __init__(self, scene: Scene, grid: Grid, pts: Particles, solver: LinearSolver,
                 pattern_cache: dict | None = None):
        self.scene, self.grid, self.pts, self.solver = scene, grid, pts, solver
        # the last step's StepSystem, reused while the active points have not moved
        # (geostatic steps, strength reduction: the basis, DOF numbering and sparsity
        # pattern are the same); a dict shared by several systems on one geometry
        self.pattern_cache = {} if pattern_cache is None else pattern_cache
        self.sv = scene.solver
        self.fbar = bool(self.sv.fbar)
        self.cell_pressure = self.fbar and getattr(self.sv, "locking_constraint",
                                                   "volume") == "pressure"
        self.g_full = np.array(scene.gravity_vector, dtype=float)
        self.water = water_table(scene)          # pore water (None: dry)
        self.acc = np.zeros((pts.n, 2))          # point accelerations (dynamic)
        self._soil_of = None                     # (pts.soil, act, their C-order soil)
        self.regions = prescribed_nodes(scene, grid)
        mask = np.zeros((grid.n_nodes, 2), dtype=bool)
        target = np.zeros((grid.n_nodes, 2))     # prescribed displacement at load factor 1
        for r in self.regions:
            mask |= r["mask"]
            target[r["mask"]] = np.broadcast_to(r["displacement"], r["mask"].shape)[r["mask"]]
        self.presc_mask, self.presc_target = mask, target
        self.fixed = grid.fixed | mask
        # the residual's stress update: the compiled point update of the explicit kernels
        # (equal to the numpy reference to 1e-12, tests/test_kernels.py) or that reference
        compiled = getattr(self.sv, "kernel", "numba") == "numba"
        self.stress_update = kernels.stress_update_points if compiled else stress_update
        self.small_strain_update = (kernels.small_strain_update_points if compiled
                                    else small_strain_update)
        self._node_work = None

    def node_work(self) -> np.ndarray:
        """A zeroed work array of one value per grid node, kept for the run (the compiled
        step kernels zero what they touch before they return)."""
        if self._node_work is None or len(self._node_work) != self.grid.n_nodes:
            self._node_work = np.zeros(self.grid.n_nodes)
        return self._node_work

    def begin(self, lf_new: float, lf_old: float, dt: float = 0.0,
              dynamic: bool = False) -> StepData:
        """The grid-reset system of a step from gravity factor ``lf_old`` to ``lf_new``;
        prescribed displacements grow by ``(lf_new - lf_old)`` x their value (quasi-static
        and geostatic steps only: a dynamic step cannot carry them)."""
        pts = self.pts
        act = np.nonzero(pts.active)[0]
        if len(act) == 0:
            raise SimulationError("no active material point left (all frozen at the grid "
                                  "edge); enlarge [grid] size")
        S = self._step_system(act, dynamic)
        mass = pts.mass[act]
        presc = None
        if self.presc_mask.any():
            if dynamic:
                raise SimulationError("prescribed displacements need quasi-static load steps")
            presc = np.where(self.presc_mask, (lf_new - lf_old) * self.presc_target, 0.0)
        f_ext = S.body_force(mass, lf_new * self.g_full)
        if self.water is not None:   # pore water: -V grad u at the step's start positions
            f_ext = f_ext + nodal_water_force(self.water, S, pts.x[act], pts.volume[act], lf_new)
        return StepData(S, act, pts.volume0[act], pts.volume[act], mass,
                        sk.rows(pts.log_strain, act), sk.rows(pts.state, act),
                        self._active_soil(act), f_ext, lf_new, lf_old, presc, dt)

    def _active_soil(self, act: np.ndarray) -> MaterialPoints:
        """The active points' materials with their parameters in C order (the compiled
        updates take C arrays), kept while the same points are active and ``pts.soil``
        is the same object (strength reduction replaces it)."""
        c = self._soil_of
        if c is None or c[0] is not self.pts.soil or not np.array_equal(c[1], act):
            soil = self.pts.soil.take(act)       # (MaterialPoints keeps column order)
            soil.params = np.ascontiguousarray(soil.params)
            c = self._soil_of = (self.pts.soil, act.copy(), soil)
        return c[2]

    def _step_system(self, act: np.ndarray, dynamic: bool = False) -> StepSystem:
        """The StepSystem at the active points' positions: the cached one if the same
        points sit at the same positions (same half widths, same prescribed DOFs and
        grid), else a new one (then cached).  Dynamic Q4 steps with CHOLMOD keep the
        cells, DOF numbering and pattern of an earlier step while they hold every host
        cell (:meth:`StepSystem._cell_pattern`: the occupied cells and a halo around
        them), so the symbolic factorization is reused."""
        pts, c = self.pts, self.pattern_cache
        x = sk.rows(pts.x, act)
        hw = pts.half_width[act] if pts.half_width is not None else None
        S = c.get("S")
        if S is not None and c["grid"] is self.grid and c["shape"] == self.sv.shape \
                and np.array_equal(c["act"], act) and np.array_equal(c["x"], x) \
                and (c["fixed"] is self.fixed or np.array_equal(c["fixed"], self.fixed)) \
                and (hw is None) == (c["hw"] is None) \
                and (hw is None or np.array_equal(c["hw"], hw)):
            return S
        halo = dynamic and self.sv.shape == "standard" and self.sv.linear_solver == "cholmod"
        keep = c.get("cells") if halo and c.get("cells_grid") is self.grid else None
        S = StepSystem(self.grid, x, self.sv.shape, hw, fixed=self.fixed, keep=keep,
                       halo=halo)
        if S.halo_cells is not None:
            c.update(cells=S, cells_grid=self.grid)
        c.update(S=S, grid=self.grid, shape=self.sv.shape, act=act.copy(), x=x,
                 fixed=self.fixed, hw=None if hw is None else hw.copy())
        return S

    def reactions(self, st: StepData, du: np.ndarray, tau: np.ndarray,
                  g: np.ndarray) -> dict:
        """Force (kN/m) of each prescribed region on the soil: f_int - f_ext there."""
        if st.presc is None:
            return {}
        S = st.S
        r = S.internal_force(st.V0, tau, g, full=True) - np.bincount(
            S.point_dofs.ravel(), (S.N[:, :, None] * st.mass[:, None, None]
                                   * (st.lf_new * self.g_full)).ravel(),
            minlength=2 * self.grid.n_nodes).reshape(-1, 2)
        return {"reactions": {reg["name"]: [float(v) for v in r[reg["nodes"]].sum(axis=0)]
                              for reg in self.regions}}


class StepKind:
    """A kind of implicit step: ``residual``, ``tangent`` and ``commit`` over the shared
    :class:`ImplicitSystem` (see the module docstring)."""
    name = ""
    dynamic = False
    quasi_newton = 0        # BFGS iterations per factorization (:func:`.newton.newton`)

    def __init__(self, system: ImplicitSystem):
        self.sys = system

    # -- hooks of the subclasses
    def predictor(self, st: StepData) -> np.ndarray:
        return np.zeros(st.S.n_free)

    def material(self, st: StepData, u: np.ndarray):
        """Stress update at the nodal displacement increment ``u`` (n_nodes, 2):
        ``(log_strain, gamma_p, tau, g, dF)`` with ``g`` the spatial gradients."""
        raise NotImplementedError

    def inertia(self, st: StepData, du: np.ndarray, R: np.ndarray) -> np.ndarray:
        return R

    def force_stress(self, st: StepData, tau: np.ndarray) -> np.ndarray:
        """The stress the internal force and the reactions are integrated from (the
        points' stress; geostatic B-bar: see :class:`Geostatic`)."""
        return tau

    def coupling_tangent(self, st: StepData, g, A, Q, w):
        """The locking remedy's term of the tangent (F-bar: rank one per point)."""
        return st.S.fbar_tangent(st.V0, g, Q, w)

    # -- the Newton pieces
    def residual(self, st: StepData, du: np.ndarray):
        """``(R, ref, state)``: ``R = f_ext - f_int`` (minus inertia) on the free DOFs,
        ``ref`` the norm it is measured against, ``state = (ls, q, tau, dF)``."""
        S = st.S
        t0 = time.perf_counter()
        u = S.to_nodes(du, st.presc)
        t_mat = st.clock["material"]
        ls, q, tau, g, dFm = self.material(st, u)
        tf = self.force_stress(st, tau)
        f_int = S.internal_force(st.V0, tf, g)
        R = st.f_ext - f_int
        ref = float(np.linalg.norm(st.f_ext))
        if st.presc is not None:      # the prescribed motion drives the step
            ref = max(ref, float(np.linalg.norm(S.internal_force(st.V0, tf, g, full=True))))
        R = self.inertia(st, du, R)
        st.clock["assembly"] += time.perf_counter() - t0 - (st.clock["material"] - t_mat)
        return R, ref, (ls, q, tau, dFm)

    def point_tangent(self, st: StepData):
        """``(A, Q, w)``: the point tangent (n, 2, 2, 2, 2), and with F-bar the
        coupling factors :func:`fem_rmpm.schemes.locking.fbar_q` and the cell weights."""
        raise NotImplementedError

    def diagonal(self, st: StepData):
        """A free-DOF vector added to the tangent's diagonal (the inertia term), or None."""
        return None

    def stiffness_factor(self, st: StepData) -> float:
        """Weight of the stiffness in the residual (HHT-alpha: ``1 - alpha``)."""
        return 1.0

    def tangent(self, st: StepData):
        t0 = time.perf_counter()
        A, Q, w = self.point_tangent(st)
        t1 = time.perf_counter()
        S, g = st.S, st.cache["g"]
        f = self.stiffness_factor(st)
        if f != 1.0:
            A = f * A
            Q = None if Q is None else f * Q
        K = S.tangent(st.V0, g, A, diagonal=self.diagonal(st))
        if self.sys.fbar:
            K = K + self.coupling_tangent(st, g, A, Q, w)
        st.clock["material"] += t1 - t0
        st.clock["assembly"] += time.perf_counter() - t1
        return K

    def commit(self, st: StepData, res: NewtonResult) -> dict:
        raise NotImplementedError

    # -- one step
    def solve(self, lf_old: float, lf_new: float, dt: float = 0.0) -> StepOutcome:
        """Newton iteration of one step from gravity factor ``lf_old`` to ``lf_new`` (of
        ``dt`` seconds if dynamic); nothing changes until ``outcome.commit()``."""
        sys_, sv = self.sys, self.sys.sv
        t_setup = time.perf_counter()
        st = sys_.begin(lf_new, lf_old, dt, self.dynamic)
        t_pred = time.perf_counter()
        t_setup = t_pred - t_setup
        du0 = self.predictor(st)
        t_pred = time.perf_counter() - t_pred
        sys_.solver.new_step(st.S)
        res = newton(lambda du: self.residual(st, du), lambda: self.tangent(st), du0,
                     sys_.solver, sv.max_iterations, sv.tolerance,
                     modes=st.S.rigid_body_modes, quasi_newton=self.quasi_newton)
        res.t_material, res.t_assembly, res.t_setup = (st.clock["material"],
                                                       st.clock["assembly"], t_setup)
        res.t_predictor = t_pred
        return StepOutcome(res, lambda: self.commit(st, res), lambda: self.limits(st, res))

    def limits(self, st: StepData, res: NewtonResult) -> dict:
        """Kinematic figures of a converged step: the largest point displacement increment
        as a fraction of the (smallest) cell size, and the range of the points' ``det dF``
        (``None`` for steps that do not move the points)."""
        return {}


class Geostatic(StepKind):
    """Gravity on the fixed in-situ geometry, small strain: the points do not move (the
    displacement goes to ``pts.u_geostatic``); B-bar with F-bar on: the points' strain
    takes the cell-mean trace (:func:`fem_rmpm.schemes.locking.bbar_gradient`) and the internal
    force is its work conjugate, ``sum_p V0_p Bbar_p^T tau_p``
    (:func:`fem_rmpm.schemes.locking.bbar_force_stress`), with the symmetric tangent
    ``sum_p V0_p Bbar^T D Bbar`` (:func:`fem_rmpm.schemes.locking.bbar_tangent_correction`)."""
    name = "geostatic"

    def force_stress(self, st, tau):
        if not self.sys.fbar:
            return tau
        return bbar_force_stress(tau, st.V0, st.Vn, st.S.cell, st.S.n_host)

    def tangent(self, st):
        S = st.S
        if not (self.sys.fbar and S.groups_are_cells and not self.sys.cell_pressure):
            return super().tangent(st)
        t0 = time.perf_counter()
        A, _, w = self.point_tangent(st)
        t1 = time.perf_counter()
        K = S.tangent_with_bbar(st.V0, st.cache["g"], A, w, diagonal=self.diagonal(st))
        st.clock["material"] += t1 - t0
        st.clock["assembly"] += time.perf_counter() - t1
        return K

    def coupling_tangent(self, st, g, A, Q, w):
        K = st.S.bbar_tangent(st.V0, g, A, w)
        if self.sys.cell_pressure:
            K = K + st.S.cell_pressure_tangent(st.V0, g, A, w)
        return K

    def material(self, st, u):
        sys_ = self.sys
        H = st.S.gradient(u)
        Hm = bbar_gradient(H, st.Vn, st.S.cell, st.S.n_host) if sys_.fbar else H
        t1 = time.perf_counter()
        if sys_.cell_pressure:       # one in-plane mean stress per cell (locking_constraint)
            try:
                Hm, delta, (ls, q, tau), _ = uniform_cell_pressure(
                    lambda Hx: sys_.small_strain_update(Hx, st.ls0, st.state0, st.soil), Hm,
                    st.Vn, st.S.cell, st.S.n_host, st.cache.get("delta"))
            except ArithmeticError as exc:
                raise NewtonFailure(str(exc), []) from None
            st.cache["delta"] = delta
        else:
            ls, q, tau = sys_.small_strain_update(Hm, st.ls0, st.state0, st.soil)
        st.clock["material"] += time.perf_counter() - t1
        st.cache.update(H=Hm, g=st.S.dN, tau=tau)
        return ls, q, tau, st.S.dN, None

    def point_tangent(self, st):
        _, A = small_strain_tangent(st.cache["H"], st.ls0, st.state0, st.soil, stress=False)
        if not self.sys.fbar:
            return A, None, None
        S, Vn = st.S, st.Vn
        w = Vn / np.bincount(S.cell, Vn, minlength=S.n_host)[S.cell]
        return A, fbar_q(A, None), w

    def commit(self, st, res):
        ls, q, tau, _ = res.state
        info = self.sys.reactions(st, res.du, self.force_stress(st, tau), st.S.dN)
        pts, act = self.sys.pts, st.act
        pts.log_strain[act], pts.state[act] = ls, q
        pts.u_geostatic[act] += st.S.interpolate(st.S.to_nodes(res.du, st.presc))
        pts.stress[act] = tau
        return info


class QuasiStatic(StepKind):
    """A large-deformation load step (updated Lagrangian, Hencky/Kirchhoff): the points
    move by the converged increment, ``F <- dF F``, ``V = det(F) V0``.  With F-bar the
    internal force is the work conjugate of the F-bar deformation
    (:func:`fem_rmpm.schemes.locking.fbar_work_stress`, ``tau + e I``), with its tangent: the
    standard F-bar tangent, the geometric term of ``e`` and
    :func:`fem_rmpm.schemes.locking.fbar_work_tangent_correction`."""
    name = "static"

    def force_stress(self, st, tau):
        if not self.sys.fbar:
            return tau
        return fbar_work_stress(tau, st.V0, st.Vn, st.cache["J"], st.S.cell, st.S.n_host)

    def coupling_tangent(self, st, g, A, Q, w):
        f = self.stiffness_factor(st)
        tau = st.cache["tau"]
        e = f * (self.force_stress(st, tau)[:, 0] - tau[:, 0])
        Ag = np.zeros_like(A)
        for i in range(2):
            for j in range(2):
                Ag[:, i, j, j, i] = -e
        K = st.S.fbar_tangent(st.V0, g, Q, w) + st.S.tangent(st.V0, g, Ag)
        return K + st.S.fbar_work_tangent(st.V0, g, A, f * tau, w)

    def material(self, st, u):
        sys_ = self.sys
        S = st.S
        n = S.n
        dF, det, g = np.empty((n, 2, 2)), np.empty(n), np.empty_like(S.dN)
        if not pk.increment_kinematics(u, S.nodes, S.dN, dF, det, g) > 0:
            i = st.act[np.argmin(det)]
            raise NewtonFailure(f"material point {i} inverted (det dF = {det.min():.3g})", [],
                                inverted=True)
        if sys_.fbar:
            dFm, J, _ = fbar_increment(dF, st.Vn, st.S.cell, st.S.n_host)
            st.cache["w"] = fbar_weights(st.Vn, J, st.S.cell, st.S.n_host)
            st.cache["J"] = J
        else:
            dFm = dF
        t1 = time.perf_counter()
        ls, q, tau = sys_.stress_update(dFm, st.ls0, st.state0, st.soil)
        st.clock["material"] += time.perf_counter() - t1
        st.cache.update(dF=dFm, g=g, tau=tau)
        return ls, q, tau, g, dFm

    def tangent(self, st):
        """Without F-bar and with CHOLMOD: the lower triangle of the tangent in one
        compiled pass from the model stiffness, the trial Jacobian and the stress
        (:meth:`.assembly.StepSystem.finite_strain_tangent`); else, or when a point's
        tangent is not symmetric, the whole matrix (:meth:`StepKind.tangent`)."""
        if self.sys.fbar or self.sys.solver.kind != "cholmod":
            return super().tangent(st)
        t0 = time.perf_counter()
        c = st.cache
        if "b_e" not in c:
            c["b_e"] = elastic_left_cauchy_green(st.ls0)
        D, cols, J = finite_strain_parts(c["dF"], st.ls0, st.state0, st.soil, c["b_e"])
        t1 = time.perf_counter()
        K = st.S.finite_strain_tangent(st.V0, c["g"], D, cols, J, c["tau"],
                                       self.stiffness_factor(st), self.diagonal(st))
        st.clock["material"] += t1 - t0
        st.clock["assembly"] += time.perf_counter() - t1
        return super().tangent(st) if K is None else K

    def point_tangent(self, st):
        c = st.cache
        if "b_e" not in c:
            c["b_e"] = elastic_left_cauchy_green(st.ls0)
        _, A = finite_strain_tangent(c["dF"], st.ls0, st.state0, st.soil, b_e=c["b_e"],
                                     tau=c["tau"])
        return (A, fbar_q(A, c["tau"]), c["w"]) if self.sys.fbar else (A, None, None)

    def commit(self, st, res):
        ls, q, tau, dFm = res.state
        S, pts, act = st.S, self.sys.pts, st.act
        du_nodes = None
        info = {}
        if st.presc is not None:
            du_nodes = S.to_nodes(res.du, st.presc)
            Finv, J = inv2(_EYE + S.gradient(du_nodes))
            st.cache["J"] = J
            info = self.sys.reactions(st, res.du, self.force_stress(st, tau),
                                      np.matmul(S.dN, Finv))
        sk.set_rows(pts.log_strain, act, ls)
        sk.set_rows(pts.state, act, q)
        # x += N du, F <- dF F, V = det(F) V0, sigma = tau / det F (one compiled pass)
        pk.move_points(act, self._point_increment(st, res, du_nodes),
                       np.ascontiguousarray(dFm), st.V0,
                       np.ascontiguousarray(tau), pts.x, pts.F, pts.volume, pts.stress)
        return info

    def _point_increment(self, st, res, du_nodes=None):
        """The converged increment at the points (n, 2), interpolated once per step."""
        c = st.cache.get("u_points")
        if c is None or c[0] is not res.du:
            S = st.S
            if st.presc is None and du_nodes is None:     # no full-grid vector
                u = sk.interpolate_free(res.du, S.fnum, S.nodes, S.N, np.empty((S.n, 2)))
            else:
                u = S.interpolate(S.to_nodes(res.du, st.presc) if du_nodes is None
                                  else du_nodes)
            c = st.cache["u_points"] = (res.du, u)
        return c[1]

    def limits(self, st, res):
        disp, j_min, j_max, i = sk.step_limits(self._point_increment(st, res),
                                               np.ascontiguousarray(res.state[3]))
        return {"displacement": float(disp / np.min(self.sys.grid.cell)),
                "det_min": float(j_min), "det_max": float(j_max),
                "worst_point": int(st.act[i]) if len(st.act) else -1}


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
