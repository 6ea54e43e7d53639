"""The dynamic step of the implicit scheme: Newmark (HHT-alpha) time integration with the
lumped nodal mass on the quasi-static step's finite-strain residual and tangent
(:class:`NewmarkDynamic`, :class:`fem_rmpm.schemes.implicit.steps.QuasiStatic`)."""
from __future__ import annotations

import numpy as np

from fem_rmpm.schemes.implicit import step_kernels as sk
from fem_rmpm.schemes.implicit.steps import _MASS_TOL, QUASI_NEWTON, QuasiStatic
from fem_rmpm.schemes.locking import fbar_work_stress
from fem_rmpm.schemes.pore_pressure import nodal_water_force

__all__ = ["NewmarkDynamic"]


class NewmarkDynamic(QuasiStatic):
    """Newmark dynamics with the lumped nodal mass, optionally with HHT-alpha numerical
    damping (Hilber, Hughes & Taylor 1977, in the force-averaged form of Kuhl & Crisfield
    1999 for nonlinear problems), ``alpha = [solver] hht_alpha`` in [0, 1/3]::

        (1 - alpha) (f_ext,n+1 - f_int(du)) + alpha (f_ext,n - f_int,n) - m a_n+1 = 0
        a_n+1 = (du - dt v_n - dt^2 (1/2 - beta) a_n) / (beta dt^2)
        v_n+1 = v_n + dt ((1 - gamma) a_n + gamma a_n+1)

    with ``gamma = 1/2 + alpha``, ``beta = (1 + alpha)^2 / 4``; ``alpha = 0`` is the
    trapezoidal rule (``beta = 1/4, gamma = 1/2``: no numerical dissipation), ``alpha > 0``
    damps the high frequencies (grid noise) and, with large steps, the slow modes too,
    so a run comes to rest.  Tangent ``(1 - alpha) K + m / (beta dt^2)``.  ``f_int,n`` is
    the step-start stress on the step-start grid.  The point velocities are updated
    FLIP-like, blended with PIC by ``[solver] flip``.

    Nearly empty nodes: a node whose lumped mass is below ``[solver] min_mass_fraction``
    of a full cell's (``rho A_cell``, ``rho`` the mean density of the points) carries that
    floor mass instead, in the residual and the tangent alike (a small stabilising mass):
    a lone point entering an empty cell row no longer leaves its new nodes held by almost
    nothing, which made Newton throw them (and the point) far away.
    """
    name = "dynamic"
    dynamic = True
    quasi_newton = QUASI_NEWTON

    def _coefficients(self):
        alpha = float(self.sys.sv.hht_alpha)
        return alpha, 0.5 + alpha, 0.25 * (1.0 + alpha) ** 2

    def predictor(self, st):
        S, pts, act, mass, dt = st.S, self.sys.pts, st.act, st.mass, st.dt
        frac = float(self.sys.sv.min_mass_fraction)
        m_min = frac * float(mass.sum() / st.Vn.sum()) * float(np.prod(self.sys.grid.cell))
        nf = S.n_free
        v_n, a_n, m_free = np.empty(nf), np.empty(nf), np.empty(nf)
        # the nodal mass, velocity and acceleration on the free DOFs only, in one pass
        n_floor = sk.newmark_start(S.nodes, S.N, mass, sk.rows(pts.velocity, act),
                                   sk.rows(self.sys.acc, act), S.fnum, S.free_dofs,
                                   S.used_nodes, m_min, _MASS_TOL, self.sys.node_work(),
                                   np.zeros(nf), np.zeros(nf), v_n, a_n, m_free)
        alpha, gamma, beta = self._coefficients()
        st.cache.update(v_n=v_n, a_n=a_n, m_free=m_free, c=1.0 / (beta * dt * dt),
                        n_floor=int(n_floor))
        if alpha > 0:
            tau_n = pts.stress[act] * (st.Vn / st.V0)[:, None]
            if self.sys.fbar:        # the work-conjugate F-bar force at dF = I
                tau_n = fbar_work_stress(tau_n, st.V0, st.Vn, np.ones(len(act)), S.cell,
                                         S.n_host)
            st.cache["f_n"] = (S.body_force(mass, st.lf_old * self.sys.g_full)
                               + nodal_water_force(self.sys.water, S, pts.x[act], st.Vn,
                                                   st.lf_old)    # pore water (0 if dry)
                               - S.internal_force(st.V0, tau_n, S.dN))
        return dt * v_n + 0.5 * dt * dt * a_n

    def _acceleration(self, st, du):
        c = st.cache
        if "f_n" not in c:           # trapezoidal rule: a = 4/dt^2 (du - dt v_n) - a_n
            return c["c"] * (du - st.dt * c["v_n"]) - c["a_n"]
        beta = self._coefficients()[2]
        return c["c"] * (du - st.dt * c["v_n"] - st.dt * st.dt * (0.5 - beta) * c["a_n"])

    def inertia(self, st, du, R):
        c = st.cache
        if "f_n" in c:
            alpha = self._coefficients()[0]
            R = (1.0 - alpha) * R + alpha * c["f_n"]
        return R - c["m_free"] * self._acceleration(st, du)

    def stiffness_factor(self, st):
        return 1.0 - self._coefficients()[0]

    def diagonal(self, st):
        return st.cache["c"] * st.cache["m_free"]

    def commit(self, st, res):
        super().commit(st, res)
        S, pts, act, c = st.S, self.sys.pts, st.act, st.cache
        v_n, a_n = c["v_n"], c["a_n"]
        a_new = self._acceleration(st, res.du)
        gamma = self._coefficients()[1]
        v_new = v_n + st.dt * ((1.0 - gamma) * a_n + gamma * a_new)
        # FLIP/PIC point velocities and the point accelerations in one pass
        v_max = sk.newmark_commit(act, v_new, v_new - v_n, a_new, S.fnum, S.nodes, S.N,
                                  float(self.sys.sv.flip), pts.velocity, self.sys.acc)
        ke = 0.5 * float(np.sum(c["m_free"] * v_new * v_new))
        return {"kinetic_energy": ke, "floor_mass_nodes": c["n_floor"],
                "max_speed": float(v_max)}
