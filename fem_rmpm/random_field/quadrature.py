"""Covariance of the field between field cells at integer lags: point correlation, or
the covariance of local averages (closed form for the separable unrotated model, else
tensor Gauss where smooth and signed fans from the kink of the correlation elsewhere)."""
from __future__ import annotations

import math

import numpy as np

from fem_rmpm.random_field.model import MarkovModel, local_average_covariance_1d

__all__ = ["lattice_covariance"]


_GL = {n: (0.5 * (np.polynomial.legendre.leggauss(n)[0] + 1.0),
           0.5 * np.polynomial.legendre.leggauss(n)[1]) for n in (4, 8, 14)}


def _cell_norm(model: MarkovModel, cell) -> tuple[np.ndarray, float, float, bool]:
    """Matrix P mapping cell-unit lags to layering lags (m), and the scales."""
    P = model.rotation @ np.diag(np.asarray(cell, float))
    return P, model.theta_h, model.theta_v, model.kind == "markov_elliptic"


def _norm_cells(P, th, tv, ell, vs, vt):
    p = (P[0, 0] * vs + P[0, 1] * vt) / th
    q = (P[1, 0] * vs + P[1, 1] * vt) / tv
    return np.hypot(p, q) if ell else np.abs(p) + np.abs(q)


def _tensor_average(P, th, tv, ell, K, L, n) -> np.ndarray:
    """Tent-weighted Gauss rule (n points per quadrant and direction) at lags K, L."""
    x, w = _GL[n]
    s = np.concatenate([x - 1.0, x])
    ws = np.concatenate([w, w]) * (1.0 - np.abs(s))
    out = np.empty(len(K))
    chunk = max(1, 2_000_000 // (4 * n * n))
    for a in range(0, len(K), chunk):
        S = K[a:a + chunk, None, None] + s[None, :, None]
        T = L[a:a + chunk, None, None] + s[None, None, :]
        r = np.exp(-2.0 * _norm_cells(P, th, tv, ell, S, T))
        out[a:a + chunk] = np.einsum("nij,i,j->n", r, ws, ws)
    return out


def _J123(beta: np.ndarray) -> np.ndarray:
    """``J_m(b) = int_0^1 lam^m exp(-b lam) dlam`` for m = 1, 2, 3 (b >= 0), shape (3, ...)."""
    beta = np.asarray(beta, float)
    out = np.empty((3,) + beta.shape)
    small = beta <= 1.0
    bs, bl = beta[small], beta[~small]
    e = np.exp(-bl)
    for i, m in enumerate((1, 2, 3)):
        acc = np.zeros_like(bs)
        term = np.ones_like(bs)
        for j in range(18):                       # series: sum (-b)^j / (j! (m + j + 1))
            acc += term / (m + j + 1)
            term = term * (-bs) / (j + 1)
        out[i][small] = acc
        partial = np.zeros_like(bl)
        t = np.ones_like(bl)
        for j in range(m + 1):                    # m!/b^(m+1) (1 - e^-b sum_j b^j/j!)
            partial += t
            t = t * bl / (j + 1)
        out[i][~small] = math.factorial(m) / bl ** (m + 1) * (1.0 - e * partial)
    return out


def _fan_average(P, th, tv, ell, K, L, sigma=0.3, jmax=40) -> np.ndarray:
    """Exact-to-quadrature covariance of local averages by signed fans from the kink.

    Each quadrant of the tent support is a rectangle on which the weight is the
    bilinear ``(a0 + a1 s)(b0 + b1 t)``; its integral is the sum over its edges
    (A, B) of the signed triangle (0, A, B), parametrised ``x = lam (A + mu (B-A))``
    with Jacobian ``lam (A x B)``.  Along ``lam`` the integrand is a polynomial times
    ``exp(-2 lam N(V))`` (N homogeneous of degree 1): closed form.  Across (``mu``)
    the edge is split at the kinks of N (separable) or its closest approach
    (elliptic) and each piece is integrated by Gauss on panels graded toward the
    end nearest to the kink, whose complex singularity lies at distance
    ``N_min / N(B - A)`` in ``mu``.
    """
    K = np.asarray(K, float)
    L = np.asarray(L, float)
    nl = len(K)
    G = P.T @ np.diag([1.0 / th ** 2, 1.0 / tv ** 2]) @ P
    total = np.zeros(nl)
    for ss in (-1.0, 1.0):
        for st in (-1.0, 1.0):
            s0, s1 = np.minimum(K, K + ss), np.maximum(K, K + ss)
            t0, t1 = np.minimum(L, L + st), np.maximum(L, L + st)
            a0, a1 = 1.0 + ss * K, -ss
            b0, b1 = 1.0 + st * L, -st
            corners = [(s0, t0), (s1, t0), (s1, t1), (s0, t1)]
            for e in range(4):
                As, At = corners[e]
                Bs, Bt = corners[(e + 1) % 4]
                c = _edge_fan(P, th, tv, ell, G, As, At, Bs, Bt, a0, a1, b0, b1, nl, sigma, jmax)
                if c is not None:
                    total += c
    return total


def _split_points(P, G, ell, As, At, Ds, Dt) -> tuple[np.ndarray, np.ndarray]:
    """Where the edge ``A + mu (B - A)`` is split in ``mu`` (0..1): at its closest
    approach to the kink (elliptic) or where it crosses the layering axes (separable)."""
    if ell:
        DGD = G[0, 0] * Ds * Ds + 2 * G[0, 1] * Ds * Dt + G[1, 1] * Dt * Dt
        AGD = G[0, 0] * As * Ds + G[0, 1] * (As * Dt + At * Ds) + G[1, 1] * At * Dt
        c1 = np.clip(-AGD / DGD, 0.0, 1.0)
        c2 = np.ones_like(c1)
    else:
        cs = []
        for row in (0, 1):
            pa = P[row, 0] * As + P[row, 1] * At
            pd = P[row, 0] * Ds + P[row, 1] * Dt
            with np.errstate(divide="ignore", invalid="ignore"):
                m = np.where(np.abs(pd) > 1e-300, -pa / pd, 0.0)
            cs.append(np.clip(m, 0.0, 1.0))
        c1, c2 = np.minimum(cs[0], cs[1]), np.maximum(cs[0], cs[1])
    return c1, c2


def _edge_fan(P, th, tv, ell, G, As, At, Bs, Bt, a0, a1, b0, b1, nl, sigma, jmax):
    """Contribution (per lag, length ``nl``) of the signed triangle (0, A, B) of one
    edge of one quadrant to :func:`_fan_average`; None if every such triangle is
    degenerate (the edge lies on a line through the kink)."""
    x, w = _GL[14]

    def nrm(vs, vt):
        return _norm_cells(P, th, tv, ell, vs, vt)

    cross = As * Bt - At * Bs
    keep = np.abs(cross) > 1e-13
    if not keep.any():
        return None
    idx = np.nonzero(keep)[0]
    As, At, Bs, Bt, cr = As[idx], At[idx], Bs[idx], Bt[idx], cross[idx]
    Ds, Dt = Bs - As, Bt - At
    c1, c2 = _split_points(P, G, ell, As, At, Ds, Dt)
    bk = np.stack([np.zeros_like(c1), c1, c2, np.ones_like(c1)], axis=1)
    ma = bk[:, :3].ravel()
    mb = bk[:, 1:].ravel()
    item = np.repeat(np.arange(len(idx)), 3)
    good = mb - ma > 1e-15
    ma, mb, item = ma[good], mb[good], item[good]
    Na = nrm(As[item] + ma * Ds[item], At[item] + ma * Dt[item])
    Nb = nrm(As[item] + mb * Ds[item], At[item] + mb * Dt[item])
    kap = nrm(Ds[item], Dt[item])
    lo_end = Na <= Nb
    end = np.where(lo_end, ma, mb)
    sgn = np.where(lo_end, 1.0, -1.0)
    Lm = mb - ma
    eps = np.minimum(Na, Nb) / np.maximum(kap, 1e-300)
    with np.errstate(divide="ignore"):
        J = np.where(eps >= Lm, 0,
                     np.ceil(np.log(np.maximum(eps, 1e-300) / Lm) / math.log(sigma)))
    J = np.clip(J, 0, jmax).astype(np.int64)
    # panels: j < J: [Lm s^(j+1), Lm s^j]; j = J: [0, Lm s^J]
    cnt = J + 1
    pitem = np.repeat(np.arange(len(ma)), cnt)
    first = np.repeat(np.cumsum(cnt) - cnt, cnt)
    j = np.arange(len(pitem)) - first
    Jp = J[pitem]
    hi = Lm[pitem] * sigma ** j
    lo = np.where(j < Jp, hi * sigma, 0.0)
    mu = end[pitem, None] + sgn[pitem, None] * (lo[:, None] + (hi - lo)[:, None] * x)
    wm = (hi - lo)[:, None] * w
    it = item[pitem]
    Vs = As[it, None] + mu * Ds[it, None]
    Vt = At[it, None] + mu * Dt[it, None]
    J1, J2, J3 = _J123(2.0 * nrm(Vs, Vt))
    lag = idx[it]
    A0, A1 = a0[lag, None], a1
    B0, B1 = b0[lag, None], b1
    f = (A0 * B0) * J1 + (A0 * B1 * Vt + A1 * B0 * Vs) * J2 + (A1 * B1) * Vs * Vt * J3
    contrib = cr[it] * np.sum(wm * f, axis=1)
    return np.bincount(lag, weights=contrib, minlength=nl)


def lattice_covariance(model: MarkovModel, cell, K, L, averaging: bool = True,
                       method: str = "auto") -> np.ndarray:
    """Covariance of the standard Gaussian field between field cells at integer lags.

    ``cell`` = (h1, h2) in m; ``K``, ``L`` integer lags along x and y (any shape).
    Without averaging: the point correlation at the lag.  With averaging: the
    covariance of local averages over the cells (:mod:`fem_rmpm.random_field`).
    ``method``: "auto", "quadrature" (force the numerical path) or "closed"
    (separable, not rotated only).
    """
    K = np.asarray(K, float)
    L = np.asarray(L, float)
    shape = np.broadcast(K, L).shape
    K, L = np.broadcast_to(K, shape).ravel(), np.broadcast_to(L, shape).ravel()
    h1, h2 = (float(c) for c in cell)
    if not averaging:
        return model.correlation(K * h1, L * h2).reshape(shape)
    closed_ok = model.kind == "markov_separable" and model.angle_deg == 0.0
    if method == "closed" or (method == "auto" and closed_ok):
        if not closed_ok:
            raise ValueError("closed form only for the separable, unrotated model")
        return (local_average_covariance_1d(K, h1, model.theta_h)
                * local_average_covariance_1d(L, h2, model.theta_v)).reshape(shape)
    P, th, tv, ell = _cell_norm(model, (h1, h2))
    # |C| <= max of rho over the support [K-1, K+1] x [L-1, L+1]; N >= hypot of the minima
    # of |p|/theta_h and |q|/theta_v over the support (valid for both kinds)
    mins = []
    for row, th_ in ((0, th), (1, tv)):
        c = P[row, 0] * K + P[row, 1] * L
        r = abs(P[row, 0]) + abs(P[row, 1])
        mins.append(np.maximum(np.abs(c) - r, 0.0) / th_)
    bound = np.exp(-2.0 * np.hypot(mins[0], mins[1]))
    out = model.correlation(K * h1, L * h2)                      # |error| < 1e-17 where unused
    sig = np.nonzero(bound > 1e-17)[0]
    if len(sig):
        t8 = _tensor_average(P, th, tv, ell, K[sig], L[sig], 8)
        t4 = _tensor_average(P, th, tv, ell, K[sig], L[sig], 4)
        out[sig] = t8
        bad = sig[np.abs(t8 - t4) > 1e-11]
        for a in range(0, len(bad), 2000):
            b = bad[a:a + 2000]
            out[b] = _fan_average(P, th, tv, ell, K[b], L[b])
    return out.reshape(shape)

