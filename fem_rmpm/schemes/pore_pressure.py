"""Pore pressure u and its gradient at the material points (numpy and compiled).

**Sign convention.**  Stresses are positive in tension; u is a pressure (>= 0).  With
``[water]`` the stored point stress is the effective stress sigma' and the total stress
is sigma = sigma' - u I.

**The field.**  The phreatic surface is a polyline (:mod:`fem_rmpm.scene.water`); at a
point a true-vertical depth d below it (true frame: the grid tilted by
``frame_angle_deg``), u = gamma_w d (``"hydrostatic"``) or gamma_w d cos^2(beta)
(``"parallel_seepage"``, beta the local true inclination of the segment above the point);
u = 0 above the surface.  Beyond the polyline's ends its end segments continue.  Where
the surface lies above the ground the same formula is the free water's pressure.  On
each segment grad u is constant below the surface (:func:`water_table` keeps it in the
grid frame).

**How the water enters the momentum balance.**  The free water's load on the moving soil
surface, -int_dOmega N u n dS, equals -int_Omega (u grad N + N grad u) dV (divergence
theorem, u continuous and zero above the surface).  Added to the internal force of the
total stress, -int grad N : (sigma' - u I) dV, the u grad N terms cancel: the water is the
internal force of sigma' (as without water), a per-point body force -V_p grad u(x_p)
(buoyancy and seepage force, :func:`water_force`, ramped with gravity) and the saturated
unit weight below the surface (:func:`saturate_points`: the point mass, fixed at the
initial state).  u is evaluated at the points' current positions every step (a steady
phreatic surface; after failure a point carries the saturated mass it started with and
the pore pressure of wherever it is).
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from fem_rmpm.scene import Scene
from fem_rmpm.scene.water import true_polyline
from fem_rmpm.schemes.explicit.kernels.water import water_force, water_ramp  # noqa: F401

__all__ = ["WaterTable", "water_table", "pore_pressure", "water_force", "water_forces",
           "water_ramp", "nodal_water_force", "saturate_points", "total_stress", "vtk_fields",
           "scaled_water"]

#: Columns of a segment row of :attr:`WaterTable.segments`.
X0, Y0, SLOPE, COEF, G0, G1 = range(6)


@dataclass(frozen=True)
class WaterTable:
    """The phreatic surface as the kernels read it.  ``segments`` (k, 6): per segment its
    start in the true frame X0, Y0 (m), slope dY/dX (-), coef = gamma_w (x cos^2 beta for
    parallel seepage) (kN/m3), and grad u below the surface in the grid frame G0, G1
    (kPa/m); ``frame`` (4,): cos and sin of the frame angle and full gravity (grid frame,
    m/s2; the ramp of the water force is that of gravity)."""
    segments: np.ndarray
    frame: np.ndarray


def water_table(scene: Scene) -> WaterTable | None:
    """The :class:`WaterTable` of ``scene`` (None without ``[water]``)."""
    w = scene.water
    if w is None:
        return None
    a = math.radians(scene.scene.frame_angle_deg)
    c, s = math.cos(a), math.sin(a)
    q = true_polyline(w, scene.scene.frame_angle_deg)
    slope = np.diff(q[:, 1]) / np.diff(q[:, 0])
    coef = np.full(len(slope), w.unit_weight)
    if w.pore_pressure == "parallel_seepage":
        coef = coef / (1.0 + slope ** 2)                   # cos^2 beta
    seg = np.column_stack([q[:-1, 0], q[:-1, 1], slope, coef,
                           coef * (slope * c + s), coef * (slope * s - c)])
    g = scene.gravity_vector
    return WaterTable(np.ascontiguousarray(seg), np.array([c, s, g[0], g[1]]))


def pore_pressure(wt: WaterTable, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """u (n,) kPa and grad u (n, 2) kPa/m (grid frame) at grid-frame points ``x`` (n, 2)."""
    seg, (c, s) = wt.segments, wt.frame[:2]
    X = x[:, 0] * c + x[:, 1] * s
    Y = -x[:, 0] * s + x[:, 1] * c
    k = np.clip(np.searchsorted(seg[:, X0], X, side="right") - 1, 0, len(seg) - 1)
    r = seg[k]
    depth = r[:, Y0] + r[:, SLOPE] * (X - r[:, X0]) - Y
    wet = depth > 0
    u = np.where(wet, r[:, COEF] * depth, 0.0)
    grad = np.where(wet[:, None], r[:, [G0, G1]], 0.0)
    return u, grad


def water_forces(wt: WaterTable, x: np.ndarray, volume: np.ndarray) -> np.ndarray:
    """The per-point water force -V_p grad u(x_p) (n, 2), kN per m, at full gravity."""
    return -volume[:, None] * pore_pressure(wt, x)[1]


def nodal_water_force(wt: WaterTable | None, S, x: np.ndarray, volume: np.ndarray,
                      factor: float) -> np.ndarray | float:
    """The implicit step's external water force on the free DOFs of the step system ``S``
    (:class:`fem_rmpm.schemes.implicit.assembly.StepSystem`): ``factor`` (the gravity
    factor) x sum_p N_a(x_p) (-V_p grad u(x_p)), kN per m; 0.0 when dry."""
    if wt is None:
        return 0.0
    fw = factor * water_forces(wt, x, volume)
    full = np.bincount(S.point_dofs.ravel(), (S.N[:, :, None] * fw[:, None, :]).ravel(),
                       minlength=2 * S.grid.n_nodes)
    return full[S.free_dofs]


def saturate_points(scene: Scene, pts) -> None:
    """Give the points below the phreatic surface (at their initial position) the mass of
    their soil's ``unit_weight_saturated`` (undrained soils without it: ``unit_weight``,
    their total unit weight), in place.  No-op without ``[water]``."""
    if scene.water is None:
        return
    u, _ = pore_pressure(water_table(scene), pts.x0)
    g = scene.scene.gravity if scene.scene.gravity > 0 else 9.81
    gamma = np.array([(so.unit_weight_saturated if so.unit_weight_saturated is not None
                       else so.unit_weight) for so in scene.soils])[pts.soil_id]
    wet = u > 0
    pts.mass[wet] = gamma[wet] / g * pts.volume0[wet]


def total_stress(scene: Scene, pts) -> tuple[np.ndarray, np.ndarray] | None:
    """(u (n,) kPa, total stress (n, 4) kPa) at the points' current positions, or None
    without ``[water]``: sigma = stored - u I (xx, yy, zz) for every soil.  A drained
    soil's stored stress is the effective stress; an undrained (total-stress,
    pressure-independent) soil's stored stress is sigma + u I, which its model yields on
    alike (:func:`fem_rmpm.scene.water.drainage_of`)."""
    wt = water_table(scene)
    if wt is None:
        return None
    u, _ = pore_pressure(wt, pts.x)
    sig = pts.stress.copy()
    sig[:, :3] -= u[:, None]
    return u, sig


def vtk_fields(scene: Scene):
    """None without ``[water]``; else pts -> {"pore_pressure": u (n,) kPa, "total_stress":
    (n, 6) kPa (xx yy zz xy, yz = xz = 0)}: the points' extra VTK fields
    (:class:`fem_rmpm.io.output.PvdSeries`).  The stored ``stress`` is then sigma'."""
    if scene.water is None:
        return None

    def fields(pts) -> dict:
        u, sig = total_stress(scene, pts)
        six = np.zeros((len(u), 6))
        six[:, :4] = sig
        return {"pore_pressure": u, "total_stress": six}
    return fields


def scaled_water(scene: Scene, factor: float) -> Scene:
    """``scene`` with the pore water's unit weight times ``factor`` (a strength-reduction
    probe applies ``factor`` x gravity by scaling the point masses: the water force
    follows)."""
    if scene.water is None or factor == 1.0:
        return scene
    return dataclasses.replace(scene, water=dataclasses.replace(
        scene.water, unit_weight=scene.water.unit_weight * factor))
