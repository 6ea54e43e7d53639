"""The explicit MPM step in numpy: the method as it reads, and the reference of the kernels.

One step of ``dt`` seconds moves the material points through the three stages of the
method (Wang et al. 2016, Fig. 1), then resets the mesh:

1. **map point state to the nodes** (:func:`map_to_nodes`) — with the grid's shape
   functions ``N_Ip`` (Q4 or uGIMP, :func:`fem_rmpm.discretise.basis.shape_at_points`),
   nodal mass ``m_I = sum_p N_Ip m_p`` (t per m out of plane), momentum
   ``p_I = sum_p N_Ip m_p v_p`` and force ``f_I = -sum_p V_p sigma_p grad N_Ip + m_I g``
   (kN per m: the internal force, the stress divergence, plus gravity on the mesh);
2. **solve momentum balance on the mesh** (:func:`solve_on_mesh`) — lumped mass,
   ``m_I a_I = f_I - alpha |f_I| sign(v_I)`` with local (Cundall) damping ``alpha``,
   fixed components held at rest; new nodal velocities ``v_I + a_I dt`` (m/s);
3. **map back and move the points** (:func:`point_velocities`,
   :func:`velocity_gradient`, :func:`update_stress`) — FLIP/PIC blend of the point
   velocities, positions moved with the grid velocity ``v_pic``; then, as MUSL (modified
   update stress last), nodal velocities from the *updated* point momenta, the velocity
   gradient ``L_p = sum_I v_I (x) grad N_Ip`` (1/s), the Hughes-Winget deformation
   increment and the material's stress update (:mod:`fem_rmpm.materials`).  MUSL rather
   than USL: USL computes stresses from the nodal velocities of the old momenta, which
   for nodes with tiny mass (a point near a cell edge) are noisy; the re-map damps that
   noise and conserves momentum;
4. **reset** — the grid is fixed and only the points move: the nodal arrays of a step
   are made anew from the points (here every step allocates them; the compiled kernels
   clear the nodes they touched).

Geostatic steps (the in-situ gravity phase) keep the points where they are, accumulate
their displacement in ``pts.u_geostatic`` and update the stress with small strains.
With F-bar (:mod:`fem_rmpm.schemes.locking`) each point's volume change is replaced by
the volume-weighted mean of its host cell (geostatic: the small-strain B-bar).

The compiled step (:mod:`fem_rmpm.schemes.explicit.kernels`) computes the same formulas in
loops; ``tests/test_kernels.py`` holds the two equal to round-off.  Nodal sums are taken
over the two halves of the points apart and then added, as the kernels take them
(:func:`fem_rmpm.schemes.explicit.kernels.common.half_split`).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fem_rmpm.discretise.basis import shape_at_points
from fem_rmpm.discretise.grid import Grid
from fem_rmpm.discretise.points import Particles
from fem_rmpm.materials import hughes_winget_increment, small_strain_update, stress_update
from fem_rmpm.schemes.contact import contact_velocities
from fem_rmpm.schemes.explicit.kernels.common import half_split
from fem_rmpm.schemes.locking import bbar_gradient, fbar_increment, host_cells
from fem_rmpm.schemes.pore_pressure import water_forces

__all__ = ["MASS_TOL", "StepStats", "cfl_speeds", "stable_time_step", "map_to_nodes",
           "solve_on_mesh", "point_velocities", "velocity_gradient", "update_stress",
           "explicit_step_numpy"]

#: Nodes lighter than this (t per m) carry no velocity.
MASS_TOL = 1e-14


@dataclass
class StepStats:
    """What the time loop needs from one step."""
    kinetic_energy: float   # of the grid, 1/2 sum m_I |v_I|^2 (kJ per m of out-of-plane length)
    max_speed: float        # max |v| of the points as moved by the grid (m/s)
    # compiled step only (None from the numpy step): for the next CFL step and the guards
    wave_speed: float | None = None   # max P-wave speed sqrt(M / rho) of the active points (m/s)
    point_speed: float | None = None  # max |v| of the active points (m/s)
    n_bad: int = 0                    # non-finite findings (x or v; stress) of active points
    n_outside: int = 0                # active points outside the grid rectangle


def cfl_speeds(pts: Particles) -> tuple[float, float]:
    """(largest P-wave speed c_p = sqrt(M / rho), largest |v|) of the active points (m/s);
    M = K + 4/3 G the constrained modulus (kPa), rho = m / V (t/m3)."""
    act = pts.active
    rho = pts.mass[act] / pts.volume[act]
    M = pts.soil.bulk_modulus[act] + 4.0 / 3.0 * pts.soil.shear_modulus[act]
    wave_speed = float(np.max(np.sqrt(M / rho)))
    vmax = float(np.max(np.linalg.norm(pts.velocity[act], axis=1))) if act.any() else 0.0
    return wave_speed, vmax


def stable_time_step(pts: Particles, cell: np.ndarray, cfl: float) -> float:
    """CFL step dt = cfl * h / (c_p + |v|max) (s), h the smallest cell size (m),
    c_p = sqrt(M / rho) the P-wave speed (:func:`cfl_speeds`)."""
    wave_speed, vmax = cfl_speeds(pts)
    return cfl * float(np.min(cell)) / (wave_speed + vmax)


def _scatter(nodes: np.ndarray, weights: np.ndarray, n_nodes: int,
             second: np.ndarray | None = None) -> np.ndarray:
    """Sum ``weights`` (n, k) into the nodes ``nodes`` (n, k): (n_nodes,).  ``second`` (bool
    per point): those points summed apart and added last; None: one sum in point order."""
    if second is None:
        return np.bincount(nodes.ravel(), weights.ravel(), minlength=n_nodes)
    first = ~second         # each half summed in point order, then added (as the kernels)
    return (np.bincount(nodes[first].ravel(), weights[first].ravel(), minlength=n_nodes)
            + np.bincount(nodes[second].ravel(), weights[second].ravel(), minlength=n_nodes))


def map_to_nodes(nodes, N, dN, mass, velocity, stress, volume, gravity, n_nodes, second=None):
    """Stage 1: nodal mass (nn,) t, momentum (nn, 2) t m/s and force (nn, 2) kN, all per m
    out of plane, from the points' ``nodes`` (n, k), shape values ``N`` (n, k) and
    gradients ``dN`` (n, k, 2) 1/m, mass (n,) t, velocity (n, 2) m/s, Cauchy ``stress``
    (n, 4) kPa (xx, yy, zz, xy), ``volume`` (n,) m3/m and ``gravity`` (2,) m/s2.
    The force is the internal one (stress divergence) scattered, plus gravity on the mesh,
    ``m_I g`` (= the scattered ``sum_p N_Ip m_p g`` in exact arithmetic; the compiled step
    adds it in its solve on the mesh, which saves two products per node and point).
    ``second`` (bool per point): the points summed apart and added last, as the compiled
    two-part scatter (:mod:`fem_rmpm.schemes.explicit.kernels.transfer`); None: one sum in
    point order."""
    m = _scatter(nodes, N * mass[:, None], n_nodes, second)
    p = np.stack([_scatter(nodes, N * (mass * velocity[:, k])[:, None], n_nodes, second)
                  for k in range(2)], axis=1)
    sx, sy, sxy = (stress[:, i][:, None] * volume[:, None] for i in (0, 1, 3))
    fx = -(sx * dN[..., 0] + sxy * dN[..., 1])
    fy = -(sxy * dN[..., 0] + sy * dN[..., 1])
    f = np.stack([_scatter(nodes, fx, n_nodes, second), _scatter(nodes, fy, n_nodes, second)],
                 axis=1)
    return m, p, f + m[:, None] * np.asarray(gravity, float)


def water_nodal_force(water, gravity, nodes, N, x, volume, n_nodes, second=None):
    """The nodal force (nn, 2) kN per m of the pore water's point forces -V_p grad u(x_p)
    (:mod:`fem_rmpm.schemes.pore_pressure`) at the points ``x`` (n, 2) of ``volume`` (n,),
    times the gravity ramp (``gravity`` over full gravity)."""
    full = water.frame[2:]
    ramp = float(np.dot(gravity, full) / np.dot(full, full)) if np.dot(full, full) else 1.0
    fw = ramp * water_forces(water, x, volume)
    return np.stack([_scatter(nodes, N * fw[:, k:k + 1], n_nodes, second) for k in range(2)],
                    axis=1)


def solve_on_mesh(m, p, f, fixed, dt, damping):
    """Stage 2: lumped-mass momentum balance on the nodes: from mass ``m`` (nn,), momentum
    ``p`` and force ``f`` (nn, 2), the fixed components ``fixed`` (nn, 2) bool, the step
    ``dt`` (s) and the local damping ratio ``damping`` (-), the nodal velocities before and
    after the step (m/s) and the accelerations (m/s2), each (nn, 2); zero on nodes
    without mass and on fixed components."""
    has = m > MASS_TOL
    inv_m = np.where(has, 1.0 / np.where(has, m, 1.0), 0.0)[:, None]
    v_old = p * inv_m
    if damping > 0:
        f = f - damping * np.abs(f) * np.sign(v_old)
    f = np.where(fixed, 0.0, f)
    v_old = np.where(fixed, 0.0, v_old)
    a = f * inv_m
    return v_old, v_old + a * dt, a


def point_velocities(N, nodes, v, v_new, a, dt, flip):
    """Stage 3, map back: (``v_pic``, new point velocity), each (n, 2) m/s, from the points'
    shape values ``N`` (n, k) at ``nodes`` (n, k), their velocity ``v``, the nodal
    velocity ``v_new`` after the step and acceleration ``a`` (nn, 2).  ``v_pic`` is the
    grid's velocity at the point (it moves the point); the new velocity blends FLIP
    (``v + dt a`` interpolated, fraction ``flip``) with PIC (``v_pic``)."""
    v_pic = np.einsum("pa,pak->pk", N, v_new[nodes])
    return v_pic, flip * (v + dt * np.einsum("pa,pak->pk", N, a[nodes])) + (1.0 - flip) * v_pic


def velocity_gradient(nodes, N, dN, mass, v, m, fixed, n_nodes, second=None, correct=None):
    """Stage 3, MUSL re-map: the velocity gradient L (n, 2, 2) 1/s of each point from the
    nodal velocities of the *updated* point momenta ``mass v`` (fixed components at rest),
    divided by the nodal mass ``m`` of stage 1 (arguments as :func:`map_to_nodes`);
    ``correct``: None, or a function of the nodal velocities (nn, 2) giving them corrected
    (the contact with frictional bedrock, :mod:`fem_rmpm.schemes.contact`)."""
    p = np.stack([_scatter(nodes, N * (mass * v[:, k])[:, None], n_nodes, second)
                  for k in range(2)], axis=1)
    v_nodes = np.where(fixed, 0.0, p / np.where(m > MASS_TOL, m, 1.0)[:, None])
    if correct is not None:
        v_nodes = correct(v_nodes)
    return np.einsum("pak,pal->pkl", v_nodes[nodes], dN)


def update_stress(L, dt, state, geostatic, fbar_cells=None):
    """Stage 3, stress update: from the velocity gradient ``L`` (n, 2, 2) 1/s over ``dt``
    (s) and the points' ``state`` = (elastic log strain (n, 4), model state, material
    rows), the new (log strain, model state, Kirchhoff stress tau (n, 4) kPa, volume ratio
    J (n,) or 1.0).  Large deformation: Hughes-Winget increment dF and the material's
    Hencky update; ``geostatic``: small strain ``L dt``, J = 1.  ``fbar_cells``: None, or
    (volumes (n,) m3/m, host cells (n,), number of cells) for F-bar (geostatic: B-bar)."""
    if geostatic:
        H = bbar_gradient(L * dt, *fbar_cells) if fbar_cells else L * dt
        log_strain, mstate, tau = small_strain_update(H, *state)
        return log_strain, mstate, tau, 1.0
    dF = hughes_winget_increment(L, dt)
    if fbar_cells:
        dF = fbar_increment(dF, *fbar_cells)[0]
    log_strain, mstate, tau = stress_update(dF, *state)
    return log_strain, mstate, tau, np.linalg.det(dF)


def explicit_step_numpy(grid: Grid, pts: Particles, dt: float, gravity: np.ndarray,
                        damping: float, flip: float = 1.0, shape: str = "standard",
                        geostatic: bool = False, fbar: bool = False,
                        water=None) -> StepStats:
    """Advance the active points of ``pts`` by one explicit MUSL step of ``dt`` seconds (in
    place) under ``gravity`` (2,) m/s2, with local ``damping`` (-), FLIP fraction ``flip``
    (-), basis ``shape`` (``"standard"`` Q4 or ``"gimp"``), in the geostatic phase or not,
    with F-bar or not; ``water``: the pore water's
    :class:`fem_rmpm.schemes.pore_pressure.WaterTable` (None: dry).  ``pts.F`` is not
    updated (the step needs det(dF) only)."""
    act = np.nonzero(pts.active)[0] if not pts.active.all() else slice(None)
    x, v, mass, vol = pts.x[act], pts.velocity[act], pts.mass[act], pts.volume[act]
    nn = grid.n_nodes
    second = np.arange(pts.n)[act] >= half_split(pts.n)   # the kernels' second half
    _, nodes, N, dN, _ = shape_at_points(grid, x, shape, pts.half_width[act])
    # 1. map point state to the nodes
    m, p, f = map_to_nodes(nodes, N, dN, mass, v, pts.stress[act], vol, gravity, nn, second)
    if water is not None:            # the pore water's force -V grad u, ramped with gravity
        f += water_nodal_force(water, gravity, nodes, N, x, vol, nn, second)
    # 2. solve momentum balance on the mesh
    v_old, v_new, a = solve_on_mesh(m, p, f, grid.fixed, dt, damping)
    contact, correct = grid.contact, None
    if contact is not None:          # frictional bedrock: the nodal contact rule
        v_c, dissipated = contact_velocities(contact, m, v_new, dt, v_old)
        a, v_new = a + (v_c - v_new) / dt, v_c
        contact.work[0] += dissipated
        contact.work[2] = dt

        def correct(v_nodes):        # (a node that stuck in the solve stays at rest)
            out = contact_velocities(contact, m, v_nodes, dt)[0]
            k = contact.node
            out[k[(m[k] > MASS_TOL) & (v_new[k] == 0.0).all(axis=1)]] = 0.0
            return out
    # 3. map back and move the points, then (MUSL) re-map momentum and update stress
    v_pic, v = point_velocities(N, nodes, v, v_new, a, dt, flip)
    if geostatic:
        pts.u_geostatic[act] += dt * v_pic
    else:
        x = x + dt * v_pic
    L = velocity_gradient(nodes, N, dN, mass, v, m, grid.fixed, nn, second, correct)
    cells = (vol, host_cells(grid, pts.x[act]), grid.n_cells) if fbar else None  # before the move
    state = (pts.log_strain[act], pts.state[act], pts.soil.take(act))
    log_strain, mstate, tau, J = update_stress(L, dt, state, geostatic, cells)
    pts.x[act], pts.velocity[act], pts.volume[act] = x, v, vol * J
    pts.log_strain[act], pts.state[act] = log_strain, mstate
    pts.stress[act] = tau * (pts.volume0[act] / pts.volume[act])[:, None]
    # 4. reset: nothing kept on the mesh (the nodal arrays above are the step's own)
    # motion as the grid sees it (FLIP keeps particle velocity modes the grid cannot see)
    speed2 = np.einsum("pk,pk->p", v_pic, v_pic)
    ke = 0.5 * float(m @ np.einsum("ik,ik->i", v_new, v_new))
    return StepStats(ke, float(np.sqrt(speed2.max(initial=0.0))))
