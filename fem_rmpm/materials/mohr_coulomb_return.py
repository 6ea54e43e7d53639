"""Mohr–Coulomb return mapping in principal log-strain space, one point at a time.

The compiled (numba) half of :mod:`fem_rmpm.materials.mohr_coulomb`, which declares the
model (parameters, state, checks, strength reduction) and calls :func:`update_point` /
:func:`update_all` from its ``update`` and ``point_update``.

* **Principal stresses.**  Isotropic Hencky elasticity keeps the principal directions of
  the trial state, so a return works on the ordered principal trial log strains
  ``e1 >= e2 >= e3`` (the out-of-plane ``zz`` one included: plane strain) and rotates
  back with the in-plane eigenvectors of the trial strain (:func:`update_point`).
* **Mohr–Coulomb branches** (de Souza Neto, Peric & Owen 2008, *Computational Methods for
  Plasticity*, sec. 8.2, Boxes 8.4-8.5), each exact: the main plane (:func:`_main_plane`);
  the edge ``tau_1 = tau_2`` (planes 1-3 and 2-3) or ``tau_2 = tau_3`` (planes 1-3 and
  1-2) when the main-plane return breaks the order of the principal stresses
  (:func:`_edge`); the apex ``tau_1 = tau_2 = tau_3 = c cot(phi)`` when the edge return is
  not admissible either (``phi > 0``).  With softening each branch is a Newton iteration
  on its plastic multipliers with ``c, phi`` at the new ``gamma_p`` and the flow direction
  of ``psi`` at the start of the step; past the residual of linear softening each is the
  perfectly plastic closed form.
* **Tension cut-off** (:func:`_cutoff_return`): when the Mohr–Coulomb return leaves the
  major principal stress above ``tension_cutoff``, the first admissible active set of
  tension (Rankine) and Mohr–Coulomb planes (:data:`_SETS`).
* **Real and complex.**  Every function runs on real or complex numbers (branch tests on
  real parts): the implicit scheme's tangent is the complex-step derivative of the same
  arithmetic the explicit kernels run.

Units: strains dimensionless (log strain), stresses and moduli kPa, angles in degrees in
the parameter row (radians inside).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from fem_rmpm.runtime.compiled import FASTMATH

__all__ = ["update_point", "update_all"]

# Columns of the parameter row (the order of mohr_coulomb.PARAMETERS, after G and K).
_CP = 2               # cohesion_peak (kPa)
_CR = 3               # cohesion_residual (kPa)
_PHP = 4              # friction_angle_peak (deg)
_PHR = 5              # friction_angle_residual (deg)
_PSP = 6              # dilation_angle_peak (deg)
_PSR = 7              # dilation_angle_residual (deg)
_GS = 8               # softening_strain (-)
_EXP = 9              # softening: 0 linear, 1 exponential
_TC = 10              # tension_cutoff (kPa; inf: none)
_DEG = math.pi / 180.0
_REL = 1e-12          # relative tolerance of the yield test and of the branch checks
_NEWTON = 1e-13       # a return's Newton stops after the step taken at |f| <= this x |stress|


# --------------------------------------------------------------- strengths (one point)
# The helpers are compiled once per type and called, not inlined (inlined, the first
# compile took 4.6 / 7.1 s real / complex, not 3.0 / 4.3).  They set the kernels' fastmath
# and error model: numba gives a function without them the flags of the caller compiling
# it first (the kernels then contracted multiply-adds), so the drained slope's state at t = 3 s
# depended on whether a kernel or a numpy-level call came first, and the cache kept it.
_compiled = njit(cache=True, fastmath=FASTMATH, error_model="numpy")


@_compiled
def _strengths(gam, cp, cr, php, phr, gs, expo):
    """c, sin(phi), c cos(phi) at gamma_p and their derivatives d/dgamma_p."""
    if expo:
        w = np.exp(-gam / gs)
        dw = -w / gs
    elif gam.real < gs:
        w = 1.0 - gam / gs
        dw = -1.0 / gs + 0.0 * gam
    else:
        w = 0.0 * gam
        dw = 0.0 * gam
    c = cr + (cp - cr) * w
    phi = (phr + (php - phr) * w) * _DEG
    dphi = (php - phr) * _DEG * dw
    sphi, cphi = np.sin(phi), np.cos(phi)
    dc = (cp - cr) * dw
    return c, sphi, c * cphi, dc, cphi * dphi, dc * cphi - c * sphi * dphi


@_compiled
def _constant_strength(gn, cp, cr, php, phr, gs, expo):
    """Whether c, phi stay constant from ``gn`` on: no softening, or linear past gs."""
    return (cp == cr and php == phr) or (not expo and gn.real >= gs)


@_compiled
def _strengths_after(gam, gn, at_gn, cp, cr, php, phr, gs, expo):
    """:func:`_strengths` at ``gam >= gn`` given ``at_gn`` (its value at ``gn``), which
    it is past the residual of linear softening (a sine and cosine per step, not iteration)."""
    if not expo and gn.real >= gs and gam.real >= gs:
        return at_gn
    return _strengths(gam, cp, cr, php, phr, gs, expo)


@_compiled
def _sin_angle(gam, pk, rs, gs, expo):
    """sin of an angle (deg) softening from pk to rs with gamma_p, as in _strengths."""
    if pk == rs:
        return np.sin(pk * _DEG) + 0.0 * gam
    if expo:
        w = np.exp(-gam / gs)
    elif gam.real < gs:
        w = 1.0 - gam / gs
    else:
        w = 0.0 * gam
    return np.sin((rs + (pk - rs) * w) * _DEG)


@_compiled
def _dev_norm(a, b, c):
    """sqrt(2 dev(x) : dev(x)) of a diagonal (principal) increment x = (a, b, c)."""
    m = (a + b + c) / 3.0
    return (2.0 * ((a - m) ** 2 + (b - m) ** 2 + (c - m) ** 2)) ** 0.5


# --------------------------------------------------------------- the three returns
@_compiled
def _main_plane(t1, t3, gn, sps, at_gn, lam, G, cp, cr, php, phr, gs, expo):
    """Multiplier of the main-plane return (plane 1-3), Newton on f(dg) = 0; ``at_gn``:
    :func:`_strengths` at the start of the step."""
    sph, ccp = at_gn[1], at_gn[2]
    dn1 = lam * 2 * sps + 2 * G * (1 + sps)
    dn3 = lam * 2 * sps - 2 * G * (1 - sps)
    k = 2.0 * (1.0 + sps * sps / 3.0) ** 0.5          # d gamma_p / d dg on this plane
    dg = (t1 - t3 + (t1 + t3) * sph - 2 * ccp) / (4 * G + 4 * sps * sph * (lam + G))
    if _constant_strength(gn, cp, cr, php, phr, gs, expo):   # f is linear in dg: exact
        return dg, gn + k * dg
    for it in range(60):
        c, sph, ccp, dc, dsph, dccp = _strengths_after(gn + k * dg, gn, at_gn, cp, cr, php,
                                                       phr, gs, expo)
        s1, s3 = t1 - dg * dn1, t3 - dg * dn3
        f = s1 - s3 + (s1 + s3) * sph - 2 * ccp
        df = -(dn1 - dn3) - (dn1 + dn3) * sph + ((s1 + s3) * dsph - 2 * dccp) * k
        step = f / df
        dg = dg - step
        # converged: the residual was at round-off before this (last, complex-exact) step
        if abs(f.real) <= _NEWTON * (abs(s1.real) + abs(s3.real) + abs(ccp.real)) or (
                it > 0 and abs(step.real) <= 1e-15 * abs(dg.real)):
            break
    return dg, gn + k * dg


@_compiled
def _edge(t1, t2, t3, upper, gn, sps, at_gn, lam, G, cp, cr, php, phr, gs, expo):
    """Multipliers of an edge return: planes 1-3 and 2-3 on the edge tau_1 = tau_2
    (``upper``), planes 1-3 and 1-2 on the edge tau_2 = tau_3; ``at_gn``: c, phi at gn."""
    z = 0.0 * sps                                   # a zero of the type of sps
    na = (1 + sps, z, -(1 - sps))
    nb = (z, 1 + sps, -(1 - sps)) if upper else (1 + sps, -(1 - sps), z)
    tr = 2 * sps
    da = (lam * tr + 2 * G * na[0], lam * tr + 2 * G * na[1], lam * tr + 2 * G * na[2])
    db = (lam * tr + 2 * G * nb[0], lam * tr + 2 * G * nb[1], lam * tr + 2 * G * nb[2])
    # plane b: f_b = s_i - s_j + (s_i + s_j) sin(phi) - 2 c cos(phi) with (i, j)
    i, j = (1, 2) if upper else (0, 1)
    ga, gb = 0.0 * t1, 0.0 * t1
    for it in range(60):
        s = (t1 - ga * da[0] - gb * db[0], t2 - ga * da[1] - gb * db[1],
             t3 - ga * da[2] - gb * db[2])
        x = (ga * na[0] + gb * nb[0], ga * na[1] + gb * nb[1], ga * na[2] + gb * nb[2])
        inv = _dev_norm(x[0], x[1], x[2])
        c, sph, ccp, dc, dsph, dccp = _strengths_after(gn + inv, gn, at_gn, cp, cr, php, phr,
                                                       gs, expo)
        fa = s[0] - s[2] + (s[0] + s[2]) * sph - 2 * ccp
        fb = s[i] - s[j] + (s[i] + s[j]) * sph - 2 * ccp
        # d gamma_p / d ga, d gb (zero at the first, perfectly plastic, iteration)
        m = (x[0] + x[1] + x[2]) / 3
        if inv.real > 0:
            ma, mb = (na[0] + na[1] + na[2]) / 3, (nb[0] + nb[1] + nb[2]) / 3
            ka = 2 * ((x[0] - m) * (na[0] - ma) + (x[1] - m) * (na[1] - ma)
                      + (x[2] - m) * (na[2] - ma)) / inv
            kb = 2 * ((x[0] - m) * (nb[0] - mb) + (x[1] - m) * (nb[1] - mb)
                      + (x[2] - m) * (nb[2] - mb)) / inv
        else:
            ka, kb = 0.0 * inv, 0.0 * inv
        ha = (s[0] + s[2]) * dsph - 2 * dccp
        hb = (s[i] + s[j]) * dsph - 2 * dccp
        a11 = -(da[0] - da[2]) - (da[0] + da[2]) * sph + ha * ka
        a12 = -(db[0] - db[2]) - (db[0] + db[2]) * sph + ha * kb
        a21 = -(da[i] - da[j]) - (da[i] + da[j]) * sph + hb * ka
        a22 = -(db[i] - db[j]) - (db[i] + db[j]) * sph + hb * kb
        det = a11 * a22 - a12 * a21
        sa = (fa * a22 - fb * a12) / det
        sb = (a11 * fb - a21 * fa) / det
        ga, gb = ga - sa, gb - sb
        if _constant_strength(gn, cp, cr, php, phr, gs, expo):   # linear, exact at once
            break
        sc = abs(s[0].real) + abs(s[1].real) + abs(s[2].real) + abs(ccp.real)
        if abs(fa.real) + abs(fb.real) <= _NEWTON * sc or (
                it > 0 and abs(sa.real) + abs(sb.real) <= 1e-15 * (abs(ga.real) + abs(gb.real))):
            break
    x = (ga * na[0] + gb * nb[0], ga * na[1] + gb * nb[1], ga * na[2] + gb * nb[2])
    return ga, gb, x, gn + _dev_norm(x[0], x[1], x[2])


@_compiled
def _surely_elastic(t1, t3, gam, cp, cr, php, phr, gs):
    """True only where the yield test of :func:`_mc_return` finds the trial stresses
    ``t1 >= t3`` (kPa) elastic, decided without a sine or cosine (linear softening): the
    cohesion c and friction angle x (rad) at ``gam`` as :func:`_strengths` computes them,
    and bounds that hold for 0 <= x <= pi / 2: x - x^3 / 6 <= sin x <= x and
    cos x >= 1 - x^2 / 2.  So ``f_up`` >= f = t1 - t3 + (t1 + t3) sin x - 2 c cos x, and
    f_up < 0 (less a margin for its own round-off) means f < 0, where the yield test
    (f > 1e-12 of the stresses) finds the point elastic.  False also where it cannot
    tell (close to yield, NaN): the exact test decides."""
    w = 1.0 - gam / gs if gam < gs else 0.0
    c = cr + (cp - cr) * w
    x = (phr + (php - phr) * w) * _DEG
    if not (0.0 <= x <= 1.5 and c >= 0.0):
        return False
    s = t1 + t3
    x2 = x * x
    sin_bound = x - x * x2 / 6.0 if s <= 0.0 else x
    f_up = (t1 - t3) + s * sin_bound - 2.0 * c * (1.0 - 0.5 * x2)
    return f_up < -1e-9 * (abs(t1) + abs(t3) + c)


@_compiled
def _mc_return(e1, e2, e3, gn, G, K, cp, cr, php, phr, psp, psr, gs, expo):
    """Mohr-Coulomb return of ordered principal trial log strains e1 >= e2 >= e3 (no
    tension cut-off): new principal elastic log strains and gamma_p.  Elastic: the inputs
    unchanged."""
    lam = K - 2.0 / 3.0 * G
    vol = e1 + e2 + e3
    t1, t2, t3 = lam * vol + 2 * G * e1, lam * vol + 2 * G * e2, lam * vol + 2 * G * e3
    if not expo and _surely_elastic(t1.real, t3.real, gn.real, cp, cr, php, phr, gs):
        return e1, e2, e3, gn
    at_gn = _strengths(gn, cp, cr, php, phr, gs, expo)
    c, sph, ccp, _, _, _ = at_gn
    f_tr = t1 - t3 + (t1 + t3) * sph - 2 * ccp
    scale = abs(t1.real) + abs(t3.real) + abs(ccp.real) + 1e-300
    if not f_tr.real > _REL * scale:
        return e1, e2, e3, gn
    sps = _sin_angle(gn, psp, psr, gs, expo)       # sin(psi) at the start of the step
    if sps.real > sph.real:                         # psi capped at phi (a drawn phi < psi)
        sps = sph
    dg, gam = _main_plane(t1, t3, gn, sps, at_gn, lam, G, cp, cr, php, phr, gs, expo)
    p1, p2, p3 = dg * (1 + sps), 0.0 * dg, -dg * (1 - sps)
    s1 = t1 - lam * 2 * sps * dg - 2 * G * p1
    s2 = t2 - lam * 2 * sps * dg
    s3 = t3 - lam * 2 * sps * dg - 2 * G * p3
    tol = _REL * scale
    if s1.real + tol >= s2.real and s2.real + tol >= s3.real:
        return e1 - p1, e2 - p2, e3 - p3, gam
    upper = s2.real > s1.real                       # the edge tau_1 = tau_2, else tau_2 = tau_3
    ga, gb, x, gam = _edge(t1, t2, t3, upper, gn, sps, at_gn, lam, G, cp, cr, php, phr, gs,
                           expo)
    n1, n2, n3 = e1 - x[0], e2 - x[1], e3 - x[2]
    v = n1 + n2 + n3
    u1, u2, u3 = lam * v + 2 * G * n1, lam * v + 2 * G * n2, lam * v + 2 * G * n3
    admissible = (ga.real >= -tol / G and gb.real >= -tol / G and u1.real + tol >= u2.real
                  and u2.real + tol >= u3.real)
    if admissible or not php > 0:
        return n1, n2, n3, gam
    # apex: the trial deviator becomes plastic, the pressure goes to c cot(phi)
    gam = gn + _dev_norm(e1, e2, e3)
    c, sph, ccp, _, _, _ = _strengths_after(gam, gn, at_gn, cp, cr, php, phr, gs, expo)
    ev = 3.0 * (c * (1 - sph * sph) ** 0.5 / sph) / (3.0 * K)     # e_vol = p / K
    return ev / 3.0, ev / 3.0, ev / 3.0, gam


# --------------------------------------------------------------- tension cut-off
# Planes of the cut-off returns, by code: 0, 1, 2 the tension planes tau_i = t_c; 3, 4, 5
# the Mohr-Coulomb planes (i, j) = (1, 3), (1, 2), (2, 3) of the ordered principal stresses.
# The active sets tried, in order (codes, -1 unused; last: how many are active).
_SETS = ((0, -1, -1, 1), (0, 3, -1, 2), (0, 1, -1, 2), (0, 3, 4, 3), (0, 1, 3, 3),
         (0, 1, 5, 3), (0, 3, 5, 3), (0, 1, 2, 3))


@_compiled
def _ij(code):
    if code == 3:
        return 0, 2
    if code == 4:
        return 0, 1
    if code == 5:
        return 1, 2
    return code, code


@_compiled
def _plane_vec(code, sa, z):
    """Gradient (sa = sin phi) or flow direction (sa = sin psi) of plane ``code``; zero
    for an unused code (-1).  ``z``: a zero of the working type."""
    if code < 0:
        return z, z, z
    i, j = _ij(code)
    if code < 3:
        return (z + (1.0 if i == 0 else 0.0), z + (1.0 if i == 1 else 0.0),
                z + (1.0 if i == 2 else 0.0))
    a, b = 1.0 + sa, -(1.0 - sa)
    return ((a if i == 0 else z) + (b if j == 0 else z), (a if i == 1 else z)
            + (b if j == 1 else z), (a if i == 2 else z) + (b if j == 2 else z))


@_compiled
def _plane_f(code, s, sph, ccp, dsph, dccp, tc):
    """Value of plane ``code`` at the principal stresses s and its derivative with
    respect to gamma_p (zero for the tension planes and an unused code)."""
    z = 0.0 * s[0]
    if code < 0:
        return z, z
    i, j = _ij(code)
    if code < 3:
        return s[i] - tc, z
    return s[i] - s[j] + (s[i] + s[j]) * sph - 2 * ccp, (s[i] + s[j]) * dsph - 2 * dccp


@_compiled
def _dot3(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


@_compiled
def _c_times(n, lam, G):
    """Elastic stiffness times a principal strain (lam tr(n) + 2 G n_i)."""
    tr = lam * (n[0] + n[1] + n[2])
    return tr + 2 * G * n[0], tr + 2 * G * n[1], tr + 2 * G * n[2]


@_compiled
def _dgam(p, n, dg):
    """d dev_norm(p) / d multiplier of flow n (0 at p = 0)."""
    if not dg.real > 0:
        return 0.0 * dg
    mp, mn = (p[0] + p[1] + p[2]) / 3, (n[0] + n[1] + n[2]) / 3
    return 2 * ((p[0] - mp) * (n[0] - mn) + (p[1] - mp) * (n[1] - mn)
                + (p[2] - mp) * (n[2] - mn)) / dg


@_compiled
def _corner(t, codes, gn, sps, lam, G, tc, cp, cr, php, phr, gs, expo):
    """Return onto the active planes ``codes`` (up to three, see ``_SETS``) of the
    ordered principal trial stresses t: Newton on the multipliers with c, phi at the new
    gamma_p.  Returns the multipliers, the plastic strain p, the stresses and gamma_p."""
    z = 0.0 * t[0]
    k0, k1, k2 = codes[0], codes[1], codes[2]
    n0, n1, n2 = _plane_vec(k0, sps, z), _plane_vec(k1, sps, z), _plane_vec(k2, sps, z)
    c0, c1, c2 = _c_times(n0, lam, G), _c_times(n1, lam, G), _c_times(n2, lam, G)
    l0, l1, l2 = z, z, z
    for it in range(60):
        p = (l0 * n0[0] + l1 * n1[0] + l2 * n2[0], l0 * n0[1] + l1 * n1[1] + l2 * n2[1],
             l0 * n0[2] + l1 * n1[2] + l2 * n2[2])
        cp_ = _c_times(p, lam, G)
        s = (t[0] - cp_[0], t[1] - cp_[1], t[2] - cp_[2])
        dg = _dev_norm(p[0], p[1], p[2])
        c, sph, ccp, dc, dsph, dccp = _strengths(gn + dg, cp, cr, php, phr, gs, expo)
        f0, h0 = _plane_f(k0, s, sph, ccp, dsph, dccp, tc)
        f1, h1 = _plane_f(k1, s, sph, ccp, dsph, dccp, tc)
        f2, h2 = _plane_f(k2, s, sph, ccp, dsph, dccp, tc)
        a0, a1, a2 = _plane_vec(k0, sph, z), _plane_vec(k1, sph, z), _plane_vec(k2, sph, z)
        q0, q1, q2 = _dgam(p, n0, dg), _dgam(p, n1, dg), _dgam(p, n2, dg)
        # J_kl = d f_k / d l_l; rows of unused codes: the identity (their l stays 0)
        j00 = h0 * q0 - _dot3(a0, c0)
        j01 = h0 * q1 - _dot3(a0, c1)
        j02 = h0 * q2 - _dot3(a0, c2)
        j10 = h1 * q0 - _dot3(a1, c0)
        j11 = h1 * q1 - _dot3(a1, c1)
        j12 = h1 * q2 - _dot3(a1, c2)
        j20 = h2 * q0 - _dot3(a2, c0)
        j21 = h2 * q1 - _dot3(a2, c1)
        j22 = h2 * q2 - _dot3(a2, c2)
        if k1 < 0:
            j10, j11, j12, j01, j21 = z, z + 1.0, z, z, z
        if k2 < 0:
            j20, j21, j22, j02, j12 = z, z, z + 1.0, z, z
        det = j00 * (j11 * j22 - j12 * j21) - j01 * (j10 * j22 - j12 * j20) \
            + j02 * (j10 * j21 - j11 * j20)
        d0 = (f0 * (j11 * j22 - j12 * j21) - j01 * (f1 * j22 - j12 * f2)
              + j02 * (f1 * j21 - j11 * f2)) / det
        d1 = (j00 * (f1 * j22 - j12 * f2) - f0 * (j10 * j22 - j12 * j20)
              + j02 * (j10 * f2 - f1 * j20)) / det
        d2 = (j00 * (j11 * f2 - f1 * j21) - j01 * (j10 * f2 - f1 * j20)
              + f0 * (j10 * j21 - j11 * j20)) / det
        l0, l1, l2 = l0 - d0, l1 - d1, l2 - d2
        sc = abs(s[0].real) + abs(s[1].real) + abs(s[2].real) + abs(ccp.real) + abs(tc)
        if abs(f0.real) + abs(f1.real) + abs(f2.real) <= _NEWTON * sc or (
                it > 0 and abs(d0.real) + abs(d1.real) + abs(d2.real) <= 1e-15 * (
                abs(l0.real) + abs(l1.real) + abs(l2.real))):
            break
    p = (l0 * n0[0] + l1 * n1[0] + l2 * n2[0], l0 * n0[1] + l1 * n1[1] + l2 * n2[1],
         l0 * n0[2] + l1 * n1[2] + l2 * n2[2])
    cp_ = _c_times(p, lam, G)
    s = (t[0] - cp_[0], t[1] - cp_[1], t[2] - cp_[2])
    return (l0, l1, l2), p, s, gn + _dev_norm(p[0], p[1], p[2])


@_compiled
def _cutoff_return(e1, e2, e3, gn, G, K, cp, cr, php, phr, psp, psr, gs, expo, tc):
    """Return with the tension cut-off active (the Mohr-Coulomb return left tau_1 > t_c):
    the first active set of ``_SETS`` whose multipliers are >= 0 and whose stress
    satisfies every plane (all three tension planes and Mohr-Coulomb at the new
    gamma_p)."""
    lam = K - 2.0 / 3.0 * G
    vol = e1 + e2 + e3
    t = (lam * vol + 2 * G * e1, lam * vol + 2 * G * e2, lam * vol + 2 * G * e3)
    c, sph, ccp, _, _, _ = _strengths(gn, cp, cr, php, phr, gs, expo)
    sps = _sin_angle(gn, psp, psr, gs, expo)
    if sps.real > sph.real:
        sps = sph
    tol = _REL * (abs(t[0].real) + abs(t[2].real) + abs(ccp.real) + abs(tc) + 1e-300)
    for k in range(len(_SETS)):
        codes = _SETS[k]
        lm, p, s, gam = _corner(t, codes, gn, sps, lam, G, tc, cp, cr, php, phr, gs, expo)
        ok = lm[0].real >= -tol / G and lm[1].real >= -tol / G and lm[2].real >= -tol / G
        hi = max(s[0].real, s[1].real, s[2].real)
        lo = min(s[0].real, s[1].real, s[2].real)
        c, sph, ccp, _, _, _ = _strengths(gam, cp, cr, php, phr, gs, expo)
        ok = ok and hi <= tc + tol and hi - lo + (hi + lo) * sph.real - 2 * ccp.real <= tol
        if ok:
            break
    return e1 - p[0], e2 - p[1], e3 - p[2], gam


@_compiled
def _principal_return(e1, e2, e3, gn, G, K, cp, cr, php, phr, psp, psr, gs, expo, tc):
    """Return of ordered principal trial log strains e1 >= e2 >= e3: new principal
    elastic log strains and gamma_p (elastic: the inputs unchanged).  The Mohr-Coulomb
    return; if it leaves the major principal stress above the tension cut-off ``tc``
    (kPa; inf: none), the return onto the cut-off and Mohr-Coulomb planes."""
    n1, n2, n3, gam = _mc_return(e1, e2, e3, gn, G, K, cp, cr, php, phr, psp, psr, gs, expo)
    if not tc < math.inf:
        return n1, n2, n3, gam
    lam = K - 2.0 / 3.0 * G
    v = n1 + n2 + n3
    u1 = max((lam * v + 2 * G * n1).real, (lam * v + 2 * G * n2).real,
             (lam * v + 2 * G * n3).real)
    if u1 <= tc + _REL * (abs(u1) + abs(tc) + 1e-300):
        return n1, n2, n3, gam
    return _cutoff_return(e1, e2, e3, gn, G, K, cp, cr, php, phr, psp, psr, gs, expo, tc)


@_compiled
def update_point(e0, e1, e2, e3, gn, prm):
    """One point: trial log strain ``[xx, yy, zz, xy]``, plastic shear strain ``gn`` at the
    step's start and parameter row ``prm`` -> (returned elastic log strain, gamma_p)."""
    G, K = prm[0], prm[1]
    m, d = 0.5 * (e0 + e1), 0.5 * (e0 - e1)
    r = (d * d + e3 * e3) ** 0.5
    ea, eb = m + r, m - r                        # in-plane principal, ea >= eb; zz is e2
    expo = prm[_EXP] == 1.0
    tc = prm[_TC] if prm.shape[0] > _TC else math.inf     # a row without the column: none
    args = (G, K, prm[_CP], prm[_CR], prm[_PHP], prm[_PHR], prm[_PSP], prm[_PSR], prm[_GS],
            expo, tc)
    if e2.real >= ea.real:
        nz, na, nb, gam = _principal_return(e2, ea, eb, gn, *args)
    elif e2.real >= eb.real:
        na, nz, nb, gam = _principal_return(ea, e2, eb, gn, *args)
    else:
        na, nb, nz, gam = _principal_return(ea, eb, e2, gn, *args)
    mn, rn = 0.5 * (na + nb), 0.5 * (na - nb)
    if r.real > 0:
        q = rn / r
        return mn + q * d, mn - q * d, nz, q * e3, gam
    return na, nb, nz, 0.0 * e3, gam           # isotropic in-plane trial: any axes are principal


@_compiled
def update_all(eps_tr, state, params, eps, st, tau):
    """:func:`update_point` of every point: trial log strains ``eps_tr`` (n, 4), state
    (n, 1) and parameter rows (n, P) into the returned strains ``eps``, the state ``st``
    and the Kirchhoff stress ``tau`` (kPa), all given."""
    for i in range(eps_tr.shape[0]):
        e0, e1, e2, e3, gam = update_point(eps_tr[i, 0], eps_tr[i, 1], eps_tr[i, 2],
                                            eps_tr[i, 3], state[i, 0], params[i])
        G, K = params[i, 0], params[i, 1]
        lam = K - 2.0 / 3.0 * G
        vol = e0 + e1 + e2
        eps[i, 0], eps[i, 1], eps[i, 2], eps[i, 3] = e0, e1, e2, e3
        tau[i, 0], tau[i, 1] = lam * vol + 2 * G * e0, lam * vol + 2 * G * e1
        tau[i, 2], tau[i, 3] = lam * vol + 2 * G * e2, 2 * G * e3
        st[i, 0] = gam

