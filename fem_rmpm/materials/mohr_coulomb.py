"""Mohr–Coulomb soil with strength softening (``model = "mohr_coulomb_softening"``).

* **Yield** on the principal Kirchhoff stresses ``tau_1 >= tau_2 >= tau_3`` (tension
  positive, the out-of-plane ``tau_zz`` included: plane strain)::

      f = (tau_1 - tau_3) + (tau_1 + tau_3) sin(phi) - 2 c cos(phi) <= 0

  with cohesion ``c`` (kPa) and friction angle ``phi``.  ``phi = 0`` is Tresca
  (``(tau_1 - tau_3) / 2 <= c``), which equals von Mises ``sqrt(J2) <= c`` in plane-strain
  pure shear.
* **Flow**: non-associated, plastic potential ``g = (tau_1 - tau_3) + (tau_1 + tau_3)
  sin(psi)`` with the dilation angle ``psi <= phi``: a plastic step on the main plane has
  volumetric / shear plastic strain ``d_eps_v / (d_eps_1 - d_eps_3) = sin(psi)``.
* **Softening**: ``c``, ``phi`` and ``psi`` each fall from peak to residual with the
  plastic shear strain invariant ``gamma_p``, linearly (reaching the residual at
  ``gamma_p = softening_strain``) or exponentially (e-folding strain
  ``softening_strain``), as the von Mises model.  ``gamma_p`` sums ``sqrt(2 de_p : de_p)``
  over the steps, ``de_p`` the *deviatoric* plastic log-strain increment (the engineering
  plastic shear strain in simple shear; dilation does not count).
* **Return mapping** in principal log-strain space, exact for each branch (main plane,
  edge, apex; then the tension cut-off): :mod:`.mohr_coulomb_return`.
* **psi <= phi at every point**: a scene's ``[[soil]]`` must have psi <= phi (peak and
  residual, :func:`check`), but a random field may draw a friction angle below the soil's
  dilation angle; there the flow uses ``psi = phi`` (the dilation angle is capped at the
  current friction angle, as the strength reduction caps it at the reduced one), so such
  a point is valid and associated.
* **Tangent**: the implicit scheme differentiates :func:`update` by the complex step;
  the return is one numba function for real and complex numbers, so the numpy reference
  and the explicit kernels run the same arithmetic.
* **Tension cut-off** ``tension_cutoff`` (kPa, default none: the apex is the tensile
  limit): no principal stress above it (Rankine planes, returned with Mohr-Coulomb's).

Parameter row ``[G, K, cohesion_peak, cohesion_residual, friction_angle_peak,
friction_angle_residual, dilation_angle_peak, dilation_angle_residual, softening_strain,
softening]`` (kPa, kPa, kPa, kPa, deg, deg, deg, deg, -, 0 linear / 1 exponential);
state ``[plastic_shear_strain]``.  Strength reduction (:data:`STRENGTHS`): ``c / F``,
``atan(tan(phi) / F)``, ``psi`` at most the reduced ``phi``, peak and residual alike.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from fem_rmpm.materials.mohr_coulomb_return import (
    _CP,
    _CR,
    _EXP,
    _GS,
    _PHP,
    _PHR,
    update_all,
    update_point,
)
from fem_rmpm.materials.protocol import Parameter, Strength

NAME = "mohr_coulomb_softening"
PARAMETERS = (
    Parameter("cohesion_peak", "kPa", 0.0, math.inf, True, False, None, absent=math.inf,
              description="cohesion c at peak"),
    Parameter("cohesion_residual", "kPa", 0.0, math.inf, True, False, None, absent=math.inf,
              description="cohesion after softening"),
    Parameter("friction_angle_peak", "deg", 0.0, 60.0, True, False, None, absent=math.nan,
              description="friction angle phi at peak"),
    Parameter("friction_angle_residual", "deg", 0.0, 60.0, True, False, None,
              absent=math.nan, description="friction angle after softening"),
    Parameter("dilation_angle_peak", "deg", 0.0, 60.0, True, False, 0.0, absent=math.nan,
              description="dilation angle psi at peak (<= friction_angle_peak)"),
    Parameter("dilation_angle_residual", "deg", 0.0, 60.0, True, False, 0.0,
              absent=math.nan, description="dilation angle after softening"),
    Parameter("softening_strain", "-", 0.0, math.inf, False, False, 0.5,
              description="plastic shear strain at which the strengths reach the residual "
                          "(linear) or the e-folding strain (exponential)"),
    Parameter("softening", "-", default="linear", choices=("linear", "exponential"),
              description="softening law"),
    Parameter("tension_cutoff", "kPa", 0.0, math.inf, True, True, math.inf, allow_inf=True,
              absent=math.nan,
              description="tension cut-off t_c: no principal stress above it (Rankine "
                          "planes); inf: none, the apex c cot(phi) is the tensile limit"),
)
STATE = ("plastic_shear_strain",)
STRENGTHS = (
    Strength("cohesion_peak", "c/F"),
    Strength("cohesion_residual", "c/F", peak="cohesion_peak"),
    Strength("friction_angle_peak", "atan(tan(phi)/F)"),
    Strength("friction_angle_residual", "atan(tan(phi)/F)", peak="friction_angle_peak"),
    Strength("dilation_angle_peak", "at most", bound="friction_angle_peak"),
    Strength("dilation_angle_residual", "at most", peak="dilation_angle_peak",
             bound="friction_angle_residual"),
)


def check(values: dict):
    """Scene check across parameters: residual <= peak for c, phi and psi; psi <= phi;
    some strength; a cohesion softening modulus below G (else the return snaps back)."""
    for what in ("cohesion", "friction_angle", "dilation_angle"):
        pk, rs = values[f"{what}_peak"], values[f"{what}_residual"]
        if rs > pk:
            return f"{what}_residual", (f"{rs:g} exceeds {what}_peak {pk:g}; allowed: "
                                        f"0 <= {what}_residual <= {what}_peak")
    for stage in ("peak", "residual"):
        psi, phi = values[f"dilation_angle_{stage}"], values[f"friction_angle_{stage}"]
        if psi > phi:
            return f"dilation_angle_{stage}", (f"{psi:g} deg exceeds friction_angle_{stage} "
                                               f"{phi:g} deg; allowed: 0 <= psi <= phi")
    if values["cohesion_peak"] <= 0 and values["friction_angle_peak"] <= 0:
        return "cohesion_peak", ("mohr_coulomb_softening needs cohesion_peak > 0 or "
                                 "friction_angle_peak > 0 (no strength at all)")
    drop = values["cohesion_peak"] - values["cohesion_residual"]
    G = values["shear_modulus"]
    h = drop / values["softening_strain"]
    if values["softening"] == "linear" and h >= G:
        return "softening_strain", (f"cohesion softening modulus {h:g} kPa >= shear modulus "
                                    f"{G:g} kPa makes the local return mapping snap back; "
                                    f"allowed: softening_strain > {drop / G:g}")
    return None


def _snaps_back(params: np.ndarray) -> np.ndarray:
    """Points of linear softening whose cohesion softening modulus is not below G."""
    cp, cr, gs, G = params[:, _CP], params[:, _CR], params[:, _GS], params[:, 0]
    return (params[:, _EXP] == 0) & ((cp - cr) / gs >= G)


def invalid_points(params: np.ndarray):
    """Per-point :func:`check` for values drawn by a random field: mask and reason."""
    cp, cr = params[:, _CP], params[:, _CR]
    bad = _snaps_back(params)
    bad |= ~(cp >= 0) | ~(cr <= cp) | ~(params[:, _PHR] <= params[:, _PHP])
    bad |= (cp <= 0) & (params[:, _PHP] <= 0)
    return bad, ("its strengths are not 0 <= residual <= peak, it has no strength, or its "
                 "cohesion softening modulus is not below the shear modulus")


def point_problem(row: np.ndarray) -> str:
    """What is wrong with one parameter row that :func:`invalid_points` rejects, naming
    the values it has and what to change."""
    cp, cr, php, phr = row[_CP], row[_CR], row[_PHP], row[_PHR]
    if not cp >= 0 or not cr <= cp:
        return (f"draws cohesion_peak = {cp:.4g} kPa and cohesion_residual = {cr:.4g} kPa; "
                "allowed: 0 <= cohesion_residual <= cohesion_peak (lower [random_field] cov "
                "or draw the residual in proportion to the peak)")
    if not phr <= php:
        return (f"draws friction_angle_peak = {php:.4g} deg below friction_angle_residual = "
                f"{phr:.4g} deg; allowed: friction_angle_residual <= friction_angle_peak "
                "(lower [random_field] cov of the friction angle or the residual angle)")
    if cp <= 0 and php <= 0:
        return ("draws no strength (cohesion_peak = 0 kPa and friction_angle_peak = 0 deg); "
                "allowed: cohesion_peak > 0 or friction_angle_peak > 0")
    return (f"draws cohesion_peak = {cp:.4g} kPa, whose linear cohesion softening modulus "
            f"{(cp - cr) / row[_GS]:.4g} kPa is not below the shear modulus {row[0]:.4g} kPa "
            "(the return mapping would snap back); increase [[soil]] softening_strain or "
            "lower [random_field] cov")


def cohesion(gamma_p, params: np.ndarray):
    """Current cohesion c(gamma_p) (kPa) and dc/dgamma_p per point (for outputs)."""
    w, dw = _weight_np(gamma_p, params)
    drop = params[:, _CP] - params[:, _CR]
    return params[:, _CR] + drop * w, drop * dw


def friction_angle(gamma_p, params: np.ndarray):
    """Current friction angle phi(gamma_p) (deg) per point."""
    w, _ = _weight_np(gamma_p, params)
    return params[:, _PHR] + (params[:, _PHP] - params[:, _PHR]) * w


def _weight_np(gamma_p, params):
    gs, expo = params[:, _GS], params[:, _EXP] == 1
    decay = np.exp(-gamma_p / gs)
    on = np.real(gamma_p) < gs
    w = np.where(expo, decay, np.where(on, 1 - gamma_p / gs, 0.0))
    dw = np.where(expo, -decay / gs, np.where(on, -1 / gs, 0.0))
    return w, dw


def update(eps_tr: np.ndarray, state: np.ndarray, params: np.ndarray):
    """Mohr–Coulomb return of trial log strains (n, 4) ``[xx, yy, zz, xy]``; returns
    ``(eps_e, state, tau)``.  Real or complex (complex step) input."""
    dtype = np.result_type(eps_tr, state, float)
    eps_tr = np.ascontiguousarray(eps_tr, dtype=dtype)
    state_in = np.ascontiguousarray(state, dtype=dtype)
    eps, tau, st = np.empty_like(eps_tr), np.empty_like(eps_tr), state_in.copy()
    update_all(eps_tr, state_in, np.ascontiguousarray(params, dtype=float), eps, st, tau)
    return eps, st, tau


@njit(inline="always")
def point_update(e0, e1, e2, e3, state, params, i):
    """:func:`update` for point ``i`` of the explicit kernels (writes ``state[i, 0]``)."""
    e0, e1, e2, e3, gam = update_point(e0, e1, e2, e3, state[i, 0], params[i])
    G, K = params[i, 0], params[i, 1]
    lam = K - 2.0 / 3.0 * G
    vol = e0 + e1 + e2
    state[i, 0] = gam
    return (e0, e1, e2, e3, lam * vol + 2 * G * e0, lam * vol + 2 * G * e1,
            lam * vol + 2 * G * e2, 2 * G * e3)
