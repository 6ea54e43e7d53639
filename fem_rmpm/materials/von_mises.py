"""Von Mises soil with cohesion softening (``model = "von_mises_softening"``).

* **Yield** ``sqrt(J2(tau)) <= c`` (undrained shear strength ``c``).  The return is
  radial in the deviatoric plane of log-strain space (exact for isotropic Hencky
  elasticity; eigenvectors never needed).
* **Softening.**  ``c`` falls from ``cohesion_peak`` to ``cohesion_residual`` with
  the plastic shear strain invariant ``gamma_p``, linearly (default) reaching the
  residual at ``gamma_p = softening_strain``, or exponentially
  ``c = c_r + (c_p - c_r) exp(-gamma_p / softening_strain)``.
* **Plastic shear strain invariant** ``gamma_p = sum over steps of
  sqrt(2 d_eps_p : d_eps_p)`` (d_eps_p the plastic log-strain increment).  It is the
  work conjugate of ``sqrt(J2)`` (``tau : d_eps_p = c d_gamma_p``) and equals the
  engineering plastic shear strain in simple shear.

* **Regularisation** (``regularisation``, :mod:`fem_rmpm.schemes.regularisation`): ``c`` softens
  with the *softening variable* (state column 1).  ``"local"`` (default): it is the
  point's own ``gamma_p``; ``"nonlocal"``: its increments are ``m`` times the
  Galavi-weighted mean of the neighbours' over ``internal_length`` (m) plus ``1 - m``
  times its own (``m = nonlocal_factor``, default 2: over-non-local), kept >= 0;
  ``"displacement"``: ``softening_strain``
  is replaced by ``softening_displacement / h`` (h the cell, m) when the points are made.

Parameter row ``[G, K, cohesion_peak, cohesion_residual, softening_strain, softening,
regularisation, internal_length, softening_displacement, nonlocal_factor]`` (kPa, kPa,
kPa, kPa, -, 0 linear / 1 exponential, 0 local / 1 nonlocal / 2 displacement, m, m, -);
state
``[plastic_shear_strain, softening_variable, plastic_shear_strain_averaged]`` (the last
is the local value at the last non-local averaging).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from fem_rmpm.materials.hencky import hencky_stress, sqrt_j2
from fem_rmpm.materials.protocol import BLOCK_COLUMNS, Parameter, Regularisable, Strength
from fem_rmpm.runtime.compiled import assume_columns, jit

NAME = "von_mises_softening"
PARAMETERS = (
    Parameter("cohesion_peak", "kPa", 0.0, math.inf, False, True, None, allow_inf=True,
              absent=math.inf, description="undrained shear strength sqrt(J2) at yield, peak"),
    Parameter("cohesion_residual", "kPa", 0.0, math.inf, False, True, None, allow_inf=True,
              absent=math.inf, description="strength after softening"),
    Parameter("softening_strain", "-", 0.0, math.inf, False, False, 0.5,
              description="plastic shear strain at which c reaches the residual (linear) "
                          "or the e-folding strain (exponential)"),
    Parameter("softening", "-", default="linear", choices=("linear", "exponential"),
              description="softening law"),
    Parameter("regularisation", "-", default="local", choices=("local", "nonlocal", "displacement"),
              description="what the strength softens with: the point's own plastic shear "
                          "strain (local), its non-local mean over internal_length "
                          "(nonlocal), or a softening strain softening_displacement / cell "
                          "(displacement)"),
    Parameter("internal_length", "m", 0.0, math.inf, False, False, math.nan,
              description="internal length l of the non-local average (regularisation = "
                          "'nonlocal'; default 0.5 m)"),
    Parameter("softening_displacement", "m", 0.0, math.inf, False, False, math.nan,
              description="displacement across the band at which c reaches the residual "
                          "(regularisation = 'displacement': softening_strain = "
                          "softening_displacement / cell)"),
    Parameter("nonlocal_factor", "-", 1.0, 4.0, True, True, math.nan,
              description="m of the non-local softening increment m x (non-local mean) + "
                          "(1 - m) x (own increment), kept >= 0 (regularisation = 'nonlocal'; "
                          "1: plain mean, default 2: over-non-local)"),
)
STATE = ("plastic_shear_strain", "softening_variable", "plastic_shear_strain_averaged")
STRENGTHS = (Strength("cohesion_peak", "c/F"),
             Strength("cohesion_residual", "c/F", peak="cohesion_peak"))
REGULARISABLE = Regularisable(strain="plastic_shear_strain", variable="softening_variable",
                              averaged="plastic_shear_strain_averaged",
                              softening_strain="softening_strain")
_CP, _CR, _GS, _EXP, _REG = 2, 3, 4, 5, 6     # columns of the parameter row
_NONLOCAL = 1.0                               # regularisation index of "nonlocal"
_KEYS = {"internal_length": "nonlocal", "nonlocal_factor": "nonlocal",
         "softening_displacement": "displacement"}
_EXP_FULL = 14.0                              # exponential law: c - c_r < 1e-6 (c_p - c_r)
#                                               past 14 e-folds


def _check_regularisation(values: dict):
    """One regularisation at a time, and its keys only with it."""
    mode = values.get("regularisation", "local")
    given = [k for k in _KEYS if math.isfinite(values.get(k, math.nan))]
    if len({_KEYS[k] for k in given}) == 2:
        return "softening_displacement", (f"both regularisations at once ({', '.join(given)}); "
                                          "allowed: the keys of one of them")
    for key in given:
        m = _KEYS[key]
        if mode != m:
            return key, (f"{key} belongs to regularisation = {m!r} (now {mode!r}); allowed: "
                         f"regularisation = {m!r} with {key}, or no {key}")
    if mode == "displacement" and not given:
        return "softening_displacement", ("regularisation = 'displacement' needs "
                                          "softening_displacement; allowed: a number in (0, "
                                          "inf) (m)")
    return None


def check(values: dict):
    """Scene check across parameters: finite strengths, residual <= peak, a linear
    softening modulus below G (else the local return mapping snaps back), one
    regularisation at a time."""
    bad = _check_regularisation(values)
    if bad:
        return bad
    cp, cr, gs = values["cohesion_peak"], values["cohesion_residual"], values["softening_strain"]
    G = values["shear_modulus"]
    if not math.isfinite(cp) or not math.isfinite(cr):
        return "cohesion_peak", ("von_mises_softening needs finite cohesion_peak and "
                                 "cohesion_residual (kPa)")
    if cr > cp:
        return "cohesion_residual", (f"{cr:g} kPa exceeds cohesion_peak {cp:g} kPa; allowed: "
                                     "0 < cohesion_residual <= cohesion_peak")
    h = (cp - cr) / gs
    if values["softening"] == "linear" and h >= G and \
            values.get("regularisation", "local") != "displacement":
        return "softening_strain", (f"softening modulus {h:g} kPa >= shear modulus {G:g} kPa "
                                    "makes the local return mapping snap back; allowed: "
                                    f"softening_strain > {(cp - cr) / G:g}")
    return None


def invalid_points(params: np.ndarray):
    """Per-point version of :func:`check` for values drawn per point (a random field
    scales peak and residual together): mask of the points and the reason."""
    cp, cr, gs, G = params[:, _CP], params[:, _CR], params[:, _GS], params[:, 0]
    bad = (params[:, _EXP] == 0) & ((cp - cr) / gs >= G)
    bad |= ~(cp > 0)
    return bad, ("its linear softening modulus is not below the shear modulus "
                 "(or it is not positive)")


def point_problem(row: np.ndarray) -> str:
    """What is wrong with one parameter row that :func:`invalid_points` rejects, naming
    its peak cohesion and shear modulus and what to change."""
    return (f"draws cohesion_peak = {row[_CP]:.4g} kPa, whose linear softening modulus is "
            f"not below the shear modulus {row[0]:.4g} kPa (or is not positive); increase "
            "[[soil]] softening_strain or lower [random_field] cov")


def fully_softened(params: np.ndarray) -> np.ndarray:
    """The softening variable (n,) past which the cohesion no longer falls: the softening
    strain (linear law), 14 e-folds of it (exponential: within 1e-6 of the drop)."""
    return np.where(params[:, _EXP] == 1.0, _EXP_FULL, 1.0) * params[:, _GS]


def softening_modulus(values: dict) -> float:
    """Drop of the cohesion per unit softening variable (kPa) of one ``[[soil]]``'s values
    (``values`` as for :func:`check`): ``(c_p - c_r) / softening_strain`` for the linear
    law; 0 for the exponential one (its modulus falls with the strain; the return's
    Newton iteration needs no bound)."""
    if values["softening"] != "linear":
        return 0.0
    return (values["cohesion_peak"] - values["cohesion_residual"]) / values["softening_strain"]


def cohesion(gamma_p, params: np.ndarray):
    """Cohesion c(gamma_p) (kPa) and its slope dc/dgamma_p (kPa) per point."""
    cp, cr, gs = params[:, _CP], params[:, _CR], params[:, _GS]
    drop = np.subtract(cp, cr, out=np.zeros(np.shape(cp)), where=np.isfinite(cp))
    decay = np.exp(-gamma_p / gs)
    c_exp, dc_exp = cr + drop * decay, -drop / gs * decay
    on_slope = gamma_p.real < gs
    c_lin = np.where(on_slope, cp - drop * gamma_p / gs, cr)
    dc_lin = np.where(on_slope, -drop / gs, 0.0)
    expo = params[:, _EXP] == 1
    return np.where(expo, c_exp, c_lin), np.where(expo, dc_exp, dc_lin)


def _plastic_multiplier(q_tr, gamma_p, params):
    """Solve sqrt(J2_tr) - G dgamma = c(gamma_p + dgamma) for dgamma >= 0 (plastic points)."""
    G = params[:, 0]
    cp, cr, gs = params[:, _CP], params[:, _CR], params[:, _GS]
    expo = params[:, _EXP] == 1
    # linear law: closed form on the softening branch, then on the residual branch
    h = (cp - cr) / gs
    c0, _ = cohesion(gamma_p, params)
    d1 = (q_tr - c0) / (G - h)
    on_slope = (gamma_p.real < gs) & ((gamma_p + d1).real <= gs)
    d_lin = np.where(on_slope, d1, (q_tr - cr) / G)
    # exponential law: Newton from the elastic-perfectly-plastic guess (monotone from the right)
    d_exp = (q_tr - c0) / G
    if np.any(expo):
        for _ in range(40):
            c, dc = cohesion(gamma_p + d_exp, params)
            r = q_tr - G * d_exp - c
            d_exp = d_exp + r / (G + dc)
    return np.where(expo, d_exp, d_lin)


def _frozen(params: np.ndarray) -> np.ndarray:
    """Points whose softening variable only the non-local pass changes (their return
    mapping is perfectly plastic at the strength of the step's start)."""
    if params.shape[1] <= _REG:
        return np.zeros(len(params), dtype=bool)
    return params[:, _REG] == _NONLOCAL


def update(eps_tr: np.ndarray, state: np.ndarray, params: np.ndarray):
    """Radial return of trial log strains (n, 4); returns (eps_e, state, tau)."""
    G, K = params[:, 0], params[:, 1]
    gamma_p = state[:, 1] if state.shape[1] > 1 else state[:, 0]    # softening variable
    tau_tr = hencky_stress(eps_tr, G, K)
    q_tr = sqrt_j2(tau_tr)
    c0, _ = cohesion(gamma_p, params)
    plastic = q_tr.real > c0.real * (1 + 1e-12)
    if not np.any(plastic):
        return eps_tr, state, tau_tr
    idx = np.nonzero(plastic)[0]
    sp = params[idx]
    dgam = _plastic_multiplier(q_tr[idx], gamma_p[idx], sp)
    frozen = _frozen(sp)                 # non-local: perfectly plastic within the step
    if np.any(frozen):
        dgam = np.where(frozen, (q_tr[idx] - c0[idx]) / sp[:, 0], dgam)
    scale = 1 - sp[:, 0] * dgam / q_tr[idx]                 # s = s_tr * scale
    e = eps_tr[idx]
    vol3 = (e[:, 0] + e[:, 1] + e[:, 2]) / 3
    dev = e.copy()
    dev[:, :3] -= vol3[:, None]
    e_new = dev * scale[:, None]
    e_new[:, :3] += vol3[:, None]
    eps = eps_tr.copy()
    eps[idx] = e_new
    st = state.copy()
    st[idx, 0] = state[idx, 0] + dgam
    if state.shape[1] > 1:
        st[idx, 1] = np.where(frozen, gamma_p[idx], gamma_p[idx] + dgam)
    tau = tau_tr.copy()
    tau[idx] = hencky_stress(e_new, sp[:, 0], sp[:, 1])
    return eps, st, tau


# --------------------------------------------------------------- numba point function
@njit(inline="always", fastmath=False, error_model="numpy")
def _cohesion(gam, cp, cr, gs, expo):
    """c(gamma_p) and dc/dgamma_p (as :func:`cohesion`) of one point."""
    drop = cp - cr
    if expo:
        decay = math.exp(-gam / gs)
        return cr + drop * decay, -drop / gs * decay
    if gam < gs:
        return cp - drop * gam / gs, -drop / gs
    return cr, 0.0


@njit(inline="always", fastmath=False, error_model="numpy")
def _trial(e0, e1, e2, e3, G, K):
    """Lame's lambda, the Kirchhoff stress of the log strain and its ``sqrt(J2)`` (kPa)."""
    lam = K - 2 / 3 * G
    vol = e0 + e1 + e2
    t0 = 2 * G * e0 + lam * vol
    t1 = 2 * G * e1 + lam * vol
    t2 = 2 * G * e2 + lam * vol
    t3 = 2 * G * e3
    pm = (t0 + t1 + t2) / 3
    s0 = t0 - pm
    s1 = t1 - pm
    s2 = t2 - pm
    return lam, t0, t1, t2, t3, math.sqrt(0.5 * (s0 * s0 + s1 * s1 + s2 * s2) + t3 * t3)


@njit(inline="always", fastmath=False, error_model="numpy")
def _returned(e0, e1, e2, e3, scale, G, lam):
    """The log strain with its deviator scaled by ``scale``, and its Kirchhoff stress."""
    vol3 = (e0 + e1 + e2) / 3
    n0 = (e0 - vol3) * scale + vol3
    n1 = (e1 - vol3) * scale + vol3
    n2 = (e2 - vol3) * scale + vol3
    n3 = e3 * scale
    vn = n0 + n1 + n2
    return n0, n1, n2, n3, 2 * G * n0 + lam * vn, 2 * G * n1 + lam * vn, \
        2 * G * n2 + lam * vn, 2 * G * n3


@njit(inline="always", fastmath=False, error_model="numpy")
def _softening_branch(q, c0, G, cp, cr, gs):
    """(dgamma, deviator scale) of the return onto the linear softening branch: one
    division gives both (one division fewer per yielding point than dgamma first, then
    scale = 1 - G dgamma / q)."""
    hs = (cp - cr) / gs
    num = q - c0
    r = 1.0 / ((G - hs) * q)
    return num * q * r, 1 - G * num * r


@njit(inline="always", fastmath=False, error_model="numpy")
def _residual_branch(q, cr, G):
    """(dgamma, deviator scale) of the return onto the residual strength."""
    return (q - cr) / G, cr / q


@njit(inline="always", fastmath=False, error_model="numpy")
def point_update(e0, e1, e2, e3, state, params, i):
    """:func:`update` for point ``i`` (writes ``state[i, 0]``)."""
    G, K = params[i, 0], params[i, 1]
    cp, cr, gs, expo = params[i, _CP], params[i, _CR], params[i, _GS], params[i, _EXP] == 1.0
    soft = 1 if state.shape[1] > 1 else 0          # the softening variable's column
    gam = state[i, soft]
    lam, t0, t1, t2, t3, q = _trial(e0, e1, e2, e3, G, K)
    c0, _ = _cohesion(gam, cp, cr, gs, expo)
    if not q > c0 * (1 + 1e-12):
        return e0, e1, e2, e3, t0, t1, t2, t3
    frozen = params.shape[1] > _REG and params[i, _REG] == _NONLOCAL
    if frozen:                                      # non-local: strength of the step's start
        dg = (q - c0) / G
        scale = c0 / q
    elif expo:                                      # Newton from the perfectly plastic guess
        dg = (q - c0) / G
        for _ in range(40):
            c, dc = _cohesion(gam + dg, cp, cr, gs, expo)
            step = (q - G * dg - c) / (G + dc)
            if step == 0.0:                         # fixed point: further passes change nothing
                break
            dg = dg + step
        scale = 1 - G * dg / q
    else:                                           # closed form, softening or residual branch
        # (a point on the residual branch skips the softening branch's division)
        dg = 0.0                                    # (always set below: numba's inliner
        scale = 1.0                                 # rejects names bound in one branch only)
        soft_branch = gam < gs
        if soft_branch:
            dg, scale = _softening_branch(q, c0, G, cp, cr, gs)
            soft_branch = gam + dg <= gs
        if not soft_branch:
            dg, scale = _residual_branch(q, cr, G)
    state[i, 0] += dg
    if not frozen:
        state[i, soft] = gam + dg
    return _returned(e0, e1, e2, e3, scale, G, lam)


def block_eligible(params: np.ndarray) -> bool:
    """Whether :func:`block_update` computes points with the parameter rows ``params``
    (n, P): all soften linearly and none non-locally (the exponential law's Newton
    iteration and the non-local frozen strength are :func:`point_update`'s alone)."""
    return not bool(_frozen(params).any() or (params[:, _EXP] != 0.0).any())


@jit
def block_update(Z, state, params, active, b, m):
    """:func:`point_update` of points ``b .. b + m - 1`` at once (the protocol's optional
    ``block_update``): the trial strains of point ``b + j`` in ``Z[0:4, j]``, its returned
    strains into ``Z[4:8, j]`` and Kirchhoff stress into ``Z[8:12, j]``; the state of the
    active points updated.  Each point's result is bitwise :func:`point_update`'s: the same
    operations, with both branches computed and one selected, so that LLVM's loop
    vectorizer takes four or eight points per instruction (the branches on "yields" and
    on the softening branch went either way from point to point).  Two passes: the elastic
    trial of every point (:func:`_elastic_trial`), then, only if a point of the block
    yields, the return (:func:`_radial_return`).  Only for points that
    :func:`block_eligible` accepts (linear, local softening): the kernels ask it once per
    run."""
    soft = 1 if state.shape[1] > 1 else 0          # the softening variable's column
    if _elastic_trial(Z, state, params, soft, b, m) == 0:
        return
    _radial_return(Z, state, params, soft, b, m)
    for j in range(m):                              # the state, point by point
        i = b + j
        if active[i] and Z[13, j] != 0.0:
            gam = state[i, soft]
            state[i, 0] += Z[12, j]
            state[i, soft] = gam + Z[12, j]


@jit
def _elastic_trial(Z, state, params, soft, b, m):
    """Pass 1 of :func:`block_update` (vectorised): the elastic result into ``Z[4:12]``,
    ``q = sqrt(J2)`` of the trial stress into ``Z[12]`` and the cohesion into ``Z[13]``;
    returns the number of yielding points.  The cohesion is :func:`_cohesion`'s, both
    branches computed and one selected: with the branch, LLVM loaded ``cp`` under a mask
    (``vmaskmovpd``), slow on AMD Zen 1."""
    assume_columns(Z, BLOCK_COLUMNS)
    n_plastic = 0
    for j in range(m):
        i = b + j
        e0, e1, e2, e3 = Z[0, j], Z[1, j], Z[2, j], Z[3, j]
        G, K = params[i, 0], params[i, 1]
        cp, cr, gs = params[i, _CP], params[i, _CR], params[i, _GS]
        gam = state[i, soft]
        _, t0, t1, t2, t3, q = _trial(e0, e1, e2, e3, G, K)
        c_slope = cp - (cp - cr) * gam / gs
        c0 = c_slope if gam < gs else cr
        Z[4, j], Z[5, j], Z[6, j], Z[7, j] = e0, e1, e2, e3
        Z[8, j], Z[9, j], Z[10, j], Z[11, j] = t0, t1, t2, t3
        Z[12, j] = q
        Z[13, j] = c0
        n_plastic += q > c0 * (1 + 1e-12)
    return n_plastic


@jit
def _radial_return(Z, state, params, soft, b, m):
    """Pass 2 of :func:`block_update` (vectorised): the yielding points' return into
    ``Z[4:12]`` (the others keep pass 1's), their plastic multiplier into ``Z[12]`` (else
    0) and 1 into ``Z[13]`` (else 0).  Every point's eight values are stored: an elastic
    point's are its trial strains and :func:`_trial`'s stress again (the same operations,
    so the same bits as pass 1's), not pass 1's reloaded.  Reloading a value to store it
    back where it was made LLVM write ``Z`` with masked stores (``vmaskmovpd``: 18 in this
    loop), which AMD's Zen 1 runs in microcode (slower there; bitwise the same run)."""
    assume_columns(Z, BLOCK_COLUMNS)
    for j in range(m):
        i = b + j
        e0, e1, e2, e3 = Z[0, j], Z[1, j], Z[2, j], Z[3, j]
        q, c0 = Z[12, j], Z[13, j]
        plastic = q > c0 * (1 + 1e-12)
        G, K = params[i, 0], params[i, 1]
        cp, cr, gs = params[i, _CP], params[i, _CR], params[i, _GS]
        gam = state[i, soft]
        lam = K - 2 / 3 * G
        dg_soft, scale_soft = _softening_branch(q, c0, G, cp, cr, gs)
        dg_res, scale_res = _residual_branch(q, cr, G)
        on_slope = (gam < gs) & (gam + dg_soft <= gs)
        dg = dg_soft if on_slope else dg_res
        scale = scale_soft if on_slope else scale_res
        r = _returned(e0, e1, e2, e3, scale, G, lam)
        _, t0, t1, t2, t3, _ = _trial(e0, e1, e2, e3, G, K)
        kept = (e0, e1, e2, e3, t0, t1, t2, t3)
        for k in range(8):
            Z[4 + k, j] = r[k] if plastic else kept[k]
        Z[12, j] = dg if plastic else 0.0
        Z[13, j] = 1.0 if plastic else 0.0


# --------------------------------------------------------------- consistent tangent (implicit)
def tangent(eps_tr: np.ndarray, state: np.ndarray, params: np.ndarray) -> np.ndarray:
    """Consistent (algorithmic) tangent ``D = d tau / d eps_tr`` (n, 4, 4) of
    :func:`update` at the trial log strains (n, 4), kPa; column ``k`` is the derivative
    along the trial strain component ``k`` of ``[xx, yy, zz, xy]`` (``xy`` a symmetric,
    tensor perturbation).  Elastic: ``K 1 1^T + 2 G I_dev``; plastic (radial return,
    ``s = s_tr (1 - G dgamma / q_tr)``, ``q = sqrt(J2)``)::

        D = K 1 1^T + 2 G (1 - G dgamma / q) I_dev
            - 2 G^2 (d dgamma/d q - dgamma / q) / q  s_tr (x) w,   w = d q / d s_tr

    with ``d dgamma / d q = 1 / (G + c'(gamma_p + dgamma))`` on the branch the update
    takes (softening slope, residual, exponential).  Optional protocol hook: the implicit
    scheme uses it instead of the complex step of :func:`update`; the two agree to
    round-off (``tests/test_implicit_tangent.py``)."""
    eps = np.ascontiguousarray(np.real(eps_tr), dtype=float)
    st = np.ascontiguousarray(np.real(state), dtype=float).reshape(len(eps), -1)
    return _tangent_points(eps, st, np.ascontiguousarray(params, dtype=float),
                           np.empty((len(eps), 4, 4)))


@njit(cache=True, fastmath=False, error_model="numpy")
def _tangent_points(eps, state, params, D):
    for i in range(eps.shape[0]):
        G, K = params[i, 0], params[i, 1]
        cp, cr, gs, expo = params[i, _CP], params[i, _CR], params[i, _GS], params[i, _EXP] == 1.0
        gam = state[i, 1] if state.shape[1] > 1 else state[i, 0]   # softening variable
        frozen = params.shape[1] > _REG and params[i, _REG] == _NONLOCAL
        e0, e1, e2, e3 = eps[i, 0], eps[i, 1], eps[i, 2], eps[i, 3]
        v3 = (e0 + e1 + e2) / 3
        s = (2 * G * (e0 - v3), 2 * G * (e1 - v3), 2 * G * (e2 - v3), 2 * G * e3)
        q = math.sqrt(0.5 * (s[0] * s[0] + s[1] * s[1] + s[2] * s[2]) + s[3] * s[3])
        c0, _ = _cohesion(gam, cp, cr, gs, expo)
        scale, beta = 1.0, 0.0
        if q > c0 * (1 + 1e-12):                     # plastic: the branch of point_update
            if frozen:                               # non-local: perfectly plastic step
                dg, dc = (q - c0) / G, 0.0
            elif expo:
                dg = (q - c0) / G
                for _ in range(40):
                    c, dc = _cohesion(gam + dg, cp, cr, gs, expo)
                    step = (q - G * dg - c) / (G + dc)
                    if step == 0.0:
                        break
                    dg = dg + step
                _, dc = _cohesion(gam + dg, cp, cr, gs, expo)
            else:
                hs = (cp - cr) / gs
                d1 = (q - c0) / (G - hs)
                if gam < gs and gam + d1 <= gs:
                    dg, dc = d1, -hs
                else:
                    dg, dc = (q - cr) / G, 0.0
            scale = 1 - G * dg / q
            beta = 2 * G * G * (1 / (G + dc) - dg / q) / (q * q)
        w = (0.5 * s[0], 0.5 * s[1], 0.5 * s[2], s[3])     # q d q / d s_tr
        for a in range(4):
            for b in range(4):
                dev = (1.0 if a == b else 0.0) - (1 / 3 if (a < 3 and b < 3) else 0.0)
                vol = K if (a < 3 and b < 3) else 0.0
                D[i, a, b] = vol + 2 * G * scale * dev - beta * s[a] * w[b]
    return D
