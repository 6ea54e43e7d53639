"""Volumetric locking of the Q4 background and its remedy: F-bar with cell averaging.

**The problem.**  With the bilinear Q4 basis and 2 x 2 (or more) points per cell
every point imposes its own volume change.  When the material is nearly
incompressible — undrained clay (nu -> 0.5) or, whatever nu, isochoric von Mises
plastic flow — there are far more volume constraints than a Q4 displacement field
can satisfy, so the mesh locks: the limit load of a footing overshoots and the
pressure at the points shows a checkerboard (Nagtegaal, Parks & Rice 1974).

**The remedy** (de Souza Neto, Peric, Dutko & Owen 1996, "Design of simple low
order finite elements for large strain analysis of nearly incompressible solids",
Int. J. Solids Struct. 33; in MPM with cell averaging: Coombs, Charlton, Cortis &
Augarde 2018, CMAME 333).  Each point's deformation increment keeps its
isochoric part and takes the volume change of its cell::

    dF_bar_p = (dJ_bar_c / dJ_p)^(1/2) dF_p,     dJ_bar_c = sum_q V_q dJ_q / sum_q V_q

(plane strain: the in-plane 2x2 part, exponent 1/2; ``V_q`` the volumes at the start
of the step of the points ``q`` of the same host cell ``c``, ``dJ = det dF``).  A
cell then carries one volume constraint, as the mean-dilatation (Q1/P0) element.
The point's F, volume and Cauchy stress follow the F-bar increment
(``F <- dF_bar F``, ``V = det(F) V0``, ``sigma = tau(F_bar) / det F``): the cell
volume is unchanged (volume-weighted average).  The explicit scheme's internal force is
``sum_p V sigma_p grad_x N``; the implicit scheme's is the work conjugate of the F-bar
deformation (:func:`fbar_work_stress`, geostatic :func:`bbar_force_stress`): the two
differ where the in-plane mean stress varies inside a cell (dilatant plastic flow), and
there the former is not the derivative of any stored work.

**One pressure per cell** (:func:`uniform_cell_pressure`, implicit geostatic steps,
``[solver] locking_constraint = "pressure"``): B-bar's one volume change per cell
still locks under dilatant flow, which ties each point's volume change to its own
plastic shear; the mixed alternative gives each cell one in-plane mean stress instead.

**Why F-bar and not B-bar.**  B-bar (Hughes 1980) replaces the volumetric part of
the *linear* strain-displacement operator; it is exact for small strain only, and
carried to finite strain by rates it is not objective and does not preserve the
volume of a cell.  Our material law is finite strain (Hencky, multiplicative
``b_tr = dF b_e dF^T``), and the large-deformation phase moves points through
cells: F-bar modifies the deformation gradient itself, multiplicatively, so the
law, its rotation invariance and the stored ``F`` stay as they are.  In the
geostatic (small-strain) phase the linearisation of F-bar *is* B-bar: the
volumetric part ``tr(grad du) / 2 I`` of each point's displacement gradient is
replaced by the volume-weighted cell average (:func:`bbar_gradient`).

**Consistent tangent** (implicit).  With ``G_p = grad_x(delta u)`` at point p and
``w_q = V_q dJ_q / sum_r V_r dJ_r``, the F-bar perturbation of the deformation is
``delta F_bar F_bar^-1 = G_p + 1/2 (sum_q w_q tr G_q - tr G_p) I``.  The
standard tangent (``K_ai,bl = sum_p V0 g_aj A_ijlm g_bm``, ``A`` evaluated at the
F-bar state, ``g`` the spatial gradients of the true configuration) gains the
rank-one-per-point term (:func:`fbar_tangent_correction`)::

    K'_ai,bl = sum_p V0_p (g_aj Q_ij)_p (gbar_c(p) - g_p)_bl,
    Q_ij = 1/2 (A_ij00 + A_ij11 + tau_ij),     gbar_c = sum_{q in c} w_q g_q

which couples every point of a cell to every node its cell's points see (for Q4 the
cell's 4 nodes; for uGIMP up to 16).  It is assembled with sparse products over
the point-cell membership, for any basis, and is checked against finite differences
of the assembled F-bar internal force (``tests/test_locking.py``); Newton keeps
converging quadratically.  Geostatic (B-bar): ``Q_ij = 1/2 (D_ij00 + D_ij11)`` and
``w_q = V_q / sum_r V_r``.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

__all__ = ["host_cells", "cell_mean", "fbar_increment", "bbar_gradient", "fbar_weights",
           "fbar_q", "fbar_tangent_correction", "bbar_force_stress", "bbar_tangent_correction",
           "cell_pressure_tangent_correction", "uniform_cell_pressure",
           "fbar_work_stress", "fbar_work_tangent_correction",
           "mean_pressure", "checkerboard_index"]


def host_cells(grid, x: np.ndarray) -> np.ndarray:
    """Host cell of each point (n,), with the arithmetic of the compiled kernels
    (``floor((x - origin) * (1 / h))`` clipped into the grid), so the numpy and the
    numba F-bar average over the same points."""
    ih = 1.0 / grid.cell
    nx, ny = grid.shape
    i = np.clip(np.floor((x[:, 0] - grid.origin[0]) * ih[0]).astype(np.int64), 0, nx - 1)
    j = np.clip(np.floor((x[:, 1] - grid.origin[1]) * ih[1]).astype(np.int64), 0, ny - 1)
    return j * nx + i


def cell_mean(values: np.ndarray, weights: np.ndarray, host: np.ndarray,
              n_cells: int) -> np.ndarray:
    """Weighted mean of ``values`` over the points of each host cell, returned per point."""
    num = np.bincount(host, weights * values, minlength=n_cells)
    den = np.bincount(host, weights, minlength=n_cells)
    return (num / np.where(den > 0, den, 1.0))[host]


def fbar_increment(dF: np.ndarray, volume: np.ndarray, host: np.ndarray, n_cells: int):
    """F-bar increments ``(dJ_bar / dJ)^(1/2) dF`` (n, 2, 2); also returns ``dJ`` and
    ``dJ_bar`` per point.  ``volume``: the point volumes at the start of the step."""
    J = dF[:, 0, 0] * dF[:, 1, 1] - dF[:, 0, 1] * dF[:, 1, 0]
    Jbar = cell_mean(J, volume, host, n_cells)
    return np.sqrt(Jbar / J)[:, None, None] * dF, J, Jbar


def bbar_gradient(H: np.ndarray, volume: np.ndarray, host: np.ndarray, n_cells: int):
    """Small strain (geostatic) B-bar: displacement gradients (n, 2, 2) whose trace is the
    volume-weighted cell mean of the trace, ``H + 1/2 (mean tr H - tr H) I``."""
    tr = H[:, 0, 0] + H[:, 1, 1]
    c = 0.5 * (cell_mean(tr, volume, host, n_cells) - tr)
    out = H.copy()
    out[:, 0, 0] += c
    out[:, 1, 1] += c
    return out


def fbar_weights(volume: np.ndarray, J: np.ndarray, host: np.ndarray, n_cells: int):
    """``w_q = V_q J_q / sum_{r in c} V_r J_r`` (the derivative of log dJ_bar)."""
    vj = volume * J
    den = np.bincount(host, vj, minlength=n_cells)
    return vj / den[host]


def fbar_q(A: np.ndarray, tau4: np.ndarray | None) -> np.ndarray:
    """``Q_ij = 1/2 (A_ij00 + A_ij11 + tau_ij)`` (n, 2, 2); geostatic: ``tau4 = None``,
    ``Q_ij = 1/2 (D_ij00 + D_ij11)``."""
    Q = 0.5 * (A[:, :, :, 0, 0] + A[:, :, :, 1, 1])
    if tau4 is not None:
        Q[:, 0, 0] += 0.5 * tau4[:, 0]
        Q[:, 1, 1] += 0.5 * tau4[:, 1]
        Q[:, 0, 1] += 0.5 * tau4[:, 3]
        Q[:, 1, 0] += 0.5 * tau4[:, 3]
    return Q


def fbar_tangent_correction(point_rows: np.ndarray, V0: np.ndarray, g: np.ndarray,
                            Q: np.ndarray, w: np.ndarray, host: np.ndarray,
                            n_free: int) -> sp.csr_matrix:
    """The F-bar term of the tangent on the free DOFs (see the module docstring).

    ``point_rows`` (n, 2k): free-DOF index of each point's DOF (node a, component i
    at ``2 a + i``; -1 for a prescribed DOF), ``g`` (n, k, 2) spatial gradients,
    ``Q`` (n, 2, 2), ``w`` (n,) weights, ``host`` (n,) cells.  Returns
    ``sum_p V0_p u_p (gbar_c(p) - g_p)^T`` with ``u_p = (g Q^T)_p`` as a CSR matrix.
    """
    n, k = g.shape[:2]
    u = np.matmul(g, np.swapaxes(Q, 1, 2)) * V0[:, None, None]     # u[p, a, i] = g_aj Q_ij V0
    rows = point_rows.ravel()
    keep = rows >= 0
    cols = np.repeat(np.arange(n), 2 * k)[keep]
    U = sp.csr_matrix((u.reshape(-1)[keep], (rows[keep], cols)), shape=(n_free, n))
    Gm = sp.csr_matrix((g.reshape(-1)[keep], (rows[keep], cols)), shape=(n_free, n))
    _, cell = np.unique(host, return_inverse=True)
    P = sp.csr_matrix((np.ones(n), (np.arange(n), cell.ravel())), shape=(n, int(cell.max()) + 1))
    Pw = sp.csr_matrix((w, (np.arange(n), cell.ravel())), shape=P.shape)
    return ((U @ P) @ (Gm @ Pw).T - U @ Gm.T).tocsr()



def bbar_force_stress(tau4: np.ndarray, V0: np.ndarray, volume: np.ndarray, host: np.ndarray,
                      n_cells: int) -> np.ndarray:
    """The stress whose standard internal force ``sum_p V0_p tau~_p g_p`` is the B-bar force
    ``sum_p V0_p Bbar_p^T tau_p`` (small strain): the in-plane mean
    ``s_p = (tau_xx + tau_yy) / 2`` of each point is replaced by ``w_p S_c / V0_p`` with
    ``S_c = sum_{q in c} V0_q s_q`` and ``w_p = V_p / sum_{q in c} V_q`` (the weights of
    :func:`bbar_gradient`); equal volumes: the cell's volume-weighted mean of ``s``.
    Without it the force is not the derivative of the B-bar work, which is harmless
    while ``s`` is uniform in a cell (elastic or isochoric von Mises flow) but makes
    dilatant plastic flow (Mohr-Coulomb with psi > 0) soften spuriously: a rough footing
    on phi = psi = 5 deg soil peaks and then loses half its load (B/8 cells)."""
    s = 0.5 * (tau4[:, 0] + tau4[:, 1])
    S = np.bincount(host, V0 * s, minlength=n_cells)
    den = np.bincount(host, volume, minlength=n_cells)
    d = volume / den[host] * S[host] / V0 - s
    out = np.array(tau4, dtype=float, copy=True)
    out[:, 0] += d
    out[:, 1] += d
    return out


def _cell_operators(point_rows, g, w, host, n_free):
    """Sparse pieces shared by the B-bar and cell-pressure tangents: ``per_point(vals)``
    (vals (n, k, 2) -> free DOFs x points), the trace rows ``Gm`` (column p: ``b_p``),
    ``Dm`` (column p: ``bbar_c(p) - b_p``, ``bbar_c = sum_{q in c} w_q b_q``) and the
    point-cell incidence ``P``."""
    n, k = g.shape[:2]
    rows = point_rows.ravel()
    keep = rows >= 0
    cols = np.repeat(np.arange(n), 2 * k)[keep]

    def per_point(vals):
        return sp.csr_matrix((vals.reshape(-1)[keep], (rows[keep], cols)), shape=(n_free, n))
    Gm = per_point(g)
    _, cell = np.unique(host, return_inverse=True)
    cell = cell.ravel()
    P = sp.csr_matrix((np.ones(n), (np.arange(n), cell)), shape=(n, int(cell.max()) + 1))
    Pw = sp.csr_matrix((w, (np.arange(n), cell)), shape=P.shape)
    Dm = ((Gm @ Pw) @ P.T - Gm).tocsr()
    return per_point, Gm, Dm, P, cell


def _volumetric_rows(D):
    """``Q_ij = 1/2 (D_ij00 + D_ij11)``, ``P_lm = 1/2 (D_00lm + D_11lm)`` and
    ``kappa = 1/2 (P_00 + P_11)`` (the in-plane mean stress per unit in-plane trace)."""
    Q = 0.5 * (D[:, :, :, 0, 0] + D[:, :, :, 1, 1])
    Pm = 0.5 * (D[:, 0, 0] + D[:, 1, 1])
    return Q, Pm, 0.5 * (Pm[:, 0, 0] + Pm[:, 1, 1])


def bbar_tangent_correction(point_rows: np.ndarray, V0: np.ndarray, g: np.ndarray,
                            D: np.ndarray, w: np.ndarray, host: np.ndarray,
                            n_free: int) -> sp.csr_matrix:
    """The B-bar terms of the small-strain tangent ``sum_p V0_p Bbar^T D Bbar`` beyond the
    standard one, with ``Bbar_p = B_p + 1/2 I (bbar_c - b_p)`` (``b_p`` the trace row of
    point p, ``bbar_c = sum_{q in c} w_q b_q``)::

        sum_p V0_p [u_p d_p^T + d_p v_p^T + kappa_p d_p d_p^T],   d_p = bbar_c(p) - b_p

    with ``u = g Q^T``, ``Q_ij = 1/2 (D_ij00 + D_ij11)``, ``v = g P^T``,
    ``P_lm = 1/2 (D_00lm + D_11lm)``, ``kappa = 1/2 (P_00 + P_11)``; D (n, 2, 2, 2, 2).
    The first term is :func:`fbar_tangent_correction`; the whole is symmetric when D
    is.  Arguments as there."""
    Q, Pm, kappa = _volumetric_rows(D)
    per_point, _, Dm, _, _ = _cell_operators(point_rows, g, w, host, n_free)
    U = per_point(np.matmul(g, np.swapaxes(Q, 1, 2)) * V0[:, None, None])
    Vv = per_point(np.matmul(g, np.swapaxes(Pm, 1, 2)) * V0[:, None, None])
    return (U @ Dm.T + Dm @ Vv.T + (Dm @ sp.diags(V0 * kappa)) @ Dm.T).tocsr()


def fbar_work_tangent_correction(point_rows: np.ndarray, V0: np.ndarray, g: np.ndarray,
                                 A: np.ndarray, tau4: np.ndarray, w: np.ndarray,
                                 host: np.ndarray, n_free: int) -> sp.csr_matrix:
    """Finite strain: the tangent of the work-conjugate F-bar force beyond the standard
    F-bar tangent and the geometric term of ``e`` (see :func:`fbar_work_stress`).

    The force ``sum_p V0_p (tau_p + e_p I) : g_p`` with ``e_p = w_p S_c / V0_p - s_p``,
    ``s = (tau_xx + tau_yy) / 2``, ``S_c = sum_{q in c} V0_q s_q``, ``w`` the F-bar
    weights (:func:`fbar_weights`).  Linearised, ``ds_p = y_p . du`` with
    ``y_p = (g P^T)_p + kappa_p d_p``, ``P_lm = 1/2 (A_00lm + A_11lm + tau_lm)``,
    ``kappa = 1/2 (P_00 + P_11)``, ``d_p = bbar_c - b_p``; ``dw_p = -w_p d_p . du``; so
    ``V0_p de_p = [-w_p S_c d_p + w_p sum_{q in c} V0_q y_q - V0_p y_p] . du`` and the
    term is ``sum_p b_p (...)^T`` (``b_p`` the trace row of point p).  Arguments as
    :func:`fbar_tangent_correction`; ``A`` (n, 2, 2, 2, 2) the spatial tangent."""
    T = np.empty((len(tau4), 2, 2))
    T[:, 0, 0], T[:, 1, 1], T[:, 0, 1], T[:, 1, 0] = tau4[:, 0], tau4[:, 1], tau4[:, 3], tau4[:, 3]
    Pm = 0.5 * (A[:, 0, 0] + A[:, 1, 1] + T)
    kappa = 0.5 * (Pm[:, 0, 0] + Pm[:, 1, 1])
    per_point, Gm, Dm, P, cell = _cell_operators(point_rows, g, w, host, n_free)
    Y = per_point(np.matmul(g, np.swapaxes(Pm, 1, 2))) + Dm @ sp.diags(kappa)
    s = 0.5 * (tau4[:, 0] + tau4[:, 1])
    S = np.bincount(cell, V0 * s)[cell]
    Yc = ((Y @ sp.diags(V0)) @ P) @ P.T
    R = Yc @ sp.diags(w) - Dm @ sp.diags(w * S) - Y @ sp.diags(V0)
    return (Gm @ R.T).tocsr()


def fbar_work_stress(tau4: np.ndarray, V0: np.ndarray, volume: np.ndarray, J: np.ndarray,
                     host: np.ndarray, n_cells: int) -> np.ndarray:
    """Finite strain: the stress whose standard force ``sum_p V0_p tau~_p grad_x N`` is the
    derivative of the F-bar work ``sum_p V0_p W(F_bar_p)``: ``delta F_bar F_bar^-1 = G_p +
    1/2 (sum_q w_q tr G_q - tr G_p) I`` gives ``tau~_p = tau_p + e_p I``,
    ``e_p = w_p S_c / V0_p - s_p`` (:func:`bbar_force_stress` with the weights
    ``w_q = V_q dJ_q / sum_r V_r dJ_r``).  ``volume`` the step-start volumes, ``J`` the
    points' ``det dF``.  With ``sum_p V0_p tau_p grad_x N`` (de Souza Neto et al.'s F-bar
    force) the two differ as soon as ``s`` varies inside a cell, which dilatant plastic
    flow does, and the force softens spuriously, as the small-strain B-bar force does."""
    return bbar_force_stress(tau4, V0, volume * J, host, n_cells)


# ------------------------------------------------------- cell-constant pressure
def cell_pressure_tangent_correction(point_rows: np.ndarray, V0: np.ndarray, g: np.ndarray,
                                     D: np.ndarray, w: np.ndarray, host: np.ndarray,
                                     n_free: int, kappa_floor: float = 1e-9) -> sp.csr_matrix:
    """The term the cell-pressure condensation adds to the B-bar tangent
    (:func:`uniform_cell_pressure`).  Each point's strain is ``Bbar_p u + delta_p / 2 I``
    with ``delta_p`` set so that the in-plane mean stress ``s`` is one value per cell and
    ``sum_{q in c} w_q delta_q = 0``; linearised, ``s_p = P_p : dH_p``, ``kappa_p =
    ds_p / d delta_p``::

        d delta_p = (vbar_c - v_p)^T du / kappa_p,   v_p = Bbar_p^T P_p,
        vbar_c = sum_{q in c} a_q v_q,   a_q = (w_q / kappa_q) / sum_{r in c} (w_r / kappa_r)

    and the force ``sum_p V0_p Bbar_p^T tau_p`` gains ``sum_p V0_p / kappa_p u_p
    (vbar_c - v_p)^T`` with ``u_p = Bbar_p^T Q_p`` (symmetric when D is and V0 is
    proportional to w in a cell).  ``kappa`` is floored at ``kappa_floor`` x its
    largest value (a point at the apex of a cohesive-frictional surface has none).
    Arguments as :func:`bbar_tangent_correction`."""
    Q, Pm, kappa = _volumetric_rows(D)
    kappa = np.maximum(kappa, kappa_floor * max(float(np.max(np.abs(kappa))), 1e-300))
    per_point, _, Dm, P, cell = _cell_operators(point_rows, g, w, host, n_free)
    Ub = per_point(np.matmul(g, np.swapaxes(Q, 1, 2))) + Dm @ sp.diags(kappa)
    Vb = per_point(np.matmul(g, np.swapaxes(Pm, 1, 2))) + Dm @ sp.diags(kappa)
    a = w / kappa
    a = a / np.bincount(cell, a)[cell]
    Aw = sp.csr_matrix((a, (np.arange(len(a)), cell)), shape=P.shape)
    Vdiff = (Vb @ Aw) @ P.T - Vb
    return ((Ub @ sp.diags(V0 / kappa)) @ Vdiff.T).tocsr()


def uniform_cell_pressure(update, Hm: np.ndarray, volume: np.ndarray, host: np.ndarray,
                          n_cells: int, delta: np.ndarray | None = None, tol: float = 1e-12,
                          max_iter: int = 40, step: float = 1e-8):
    """Cell-constant in-plane mean stress (small strain): the points of a cell share one
    ``s = (tau_xx + tau_yy) / 2`` and each takes its own volume change, the cell's
    volume-weighted mean trace staying the B-bar one.

    Why: B-bar gives every point of a cell the same volume change.  Dilatant plastic
    flow (Mohr-Coulomb, psi > 0) ties the volume change of a point to its own plastic
    shear, ``d eps_v = sin(psi) d gamma`` at the limit state, so with one volume change
    per cell all points of a cell must shear at the same rate: constraints the Q4 field
    cannot meet, and the load of a footing keeps rising (locking).  With one pressure
    per cell (the mixed u-p element Q1/P0 with the constitutive volume change) the cell
    carries one volume constraint, the mean of ``d eps_v - sin(psi) d gamma``.  For a
    point law whose pressure stiffness is uniform in a cell (elastic, isotropic) it is
    B-bar exactly.

    ``update(H)`` -> ``(log_strain, state, tau)`` is the points' small-strain update at
    displacement-increment gradients ``H`` (n, 2, 2); ``Hm`` the B-bar gradients;
    ``volume`` the weights of the cell mean.  Solves, per cell, ``s_p(delta_p) = s_c``,
    ``sum_p V_p delta_p = 0`` by Newton (``kappa_p = ds_p / d delta_p`` by a forward
    difference of ``step``), from ``delta`` (warm start) to ``|s_p - s_c| <= tol x
    max |tau|``.  Returns ``(H, delta, (log_strain, state, tau), iterations)``; raises
    ``ArithmeticError`` if the iteration does not converge."""
    n = len(Hm)
    d = np.zeros(n) if delta is None else np.array(delta, dtype=float)

    def at(dv):
        H = np.array(Hm, dtype=float, copy=True)
        H[:, 0, 0] += 0.5 * dv
        H[:, 1, 1] += 0.5 * dv
        return H, update(H)
    den = np.bincount(host, volume, minlength=n_cells)
    den = np.where(den > 0, den, 1.0)
    H, out = at(d)
    for it in range(max_iter + 1):
        tau = out[2]
        s = 0.5 * (tau[:, 0] + tau[:, 1])
        r = s - (np.bincount(host, volume * s, minlength=n_cells) / den)[host]
        scale = max(float(np.max(np.abs(tau))), 1e-300)
        if float(np.max(np.abs(r), initial=0.0)) <= tol * scale:
            return H, d, out, it
        if it == max_iter:
            break
        tau_h = at(d + step)[1][2]
        kappa = (0.5 * (tau_h[:, 0] + tau_h[:, 1]) - s) / step
        kappa = np.maximum(kappa, 1e-9 * max(float(np.max(np.abs(kappa))), 1e-300))
        a = volume / kappa
        lam = (np.bincount(host, a * s, minlength=n_cells)[host]
               / np.bincount(host, a, minlength=n_cells)[host])
        d = d + (lam - s) / kappa
        d -= (np.bincount(host, volume * d, minlength=n_cells) / den)[host]   # round-off
        H, out = at(d)
    raise ArithmeticError(f"cell-constant pressure: no convergence in {max_iter} iterations "
                          f"(largest |s_p - s_c| {np.max(np.abs(r)):.3g} kPa)")

# ----------------------------------------------------------------------- measures
def mean_pressure(stress: np.ndarray) -> np.ndarray:
    """Mean pressure ``p = -(s_xx + s_yy + s_zz) / 3`` (kPa, compression positive)."""
    return -(stress[:, 0] + stress[:, 1] + stress[:, 2]) / 3.0


def checkerboard_index(grid, x: np.ndarray, p: np.ndarray, volume: np.ndarray) -> float:
    """Pressure oscillation inside the cells, relative to the field: the root mean square
    (volume-weighted) of ``p_p - pbar_c`` over the points, ``pbar_c`` the volume-weighted
    mean of the point's host cell, divided by ``max |p|``.

    Why inside the cells: with 2 x 2 points per Q4 cell a locked mesh satisfies the
    volume constraints on average over a cell and puts the spurious pressure into an
    odd-even pattern *between the points of a cell* (the cell means stay smooth, so a
    cell-averaged plot hides it).  With F-bar the volume change, hence the pressure of
    an elastic or von Mises point (``p = -K tr eps_e``), is constant over a cell and the
    index is ~0; a Q4 field that does not lock varies linearly across a cell, which gives
    ``|grad p| h / (2 sqrt 3) / max |p|`` (1.4 % for a column of 20 cells, at the base).
    """
    host = host_cells(grid, x)
    num = np.bincount(host, p * volume, minlength=grid.n_cells)
    den = np.bincount(host, volume, minlength=grid.n_cells)
    pbar = (num / np.where(den > 0, den, 1.0))[host]
    scale = float(np.max(np.abs(p))) if len(p) else 0.0
    if scale == 0:
        return 0.0
    return float(np.sqrt(np.sum(volume * (p - pbar) ** 2) / np.sum(volume)) / scale)
