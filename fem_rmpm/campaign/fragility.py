"""Why each realization failed: the MPM's stand/fail against the strength-reduction factor
of safety (FS) of the same random field, per case of an ``mc --fs`` campaign.

* **Split of the failures**: a failure with FS >= 1 is *progressive* (the slope stands at
  peak strength; softening after first yield brings it down), one with FS < 1 is
  *strength-limited* (the peak strength alone does not carry the slope).  Fractions of the
  failures, each with its Wilson 95 % interval.
* **Fragility curve** P(failure | FS): binned (equal-count FS bins, each with its Wilson
  interval) and a probit curve ``P = Phi((FS50 - FS) / s)`` fitted by maximum likelihood
  over the realizations (Bernoulli likelihood).  FS50, the FS at which P = 0.5, has a
  95 % *profile-likelihood* interval: the FS50 values whose profile log-likelihood (s
  maximised) lies within chi2(1, 0.95) / 2 = 1.92 of the maximum.  When the failures and
  the standing realizations are separated by FS (no overlap), the MLE of ``s`` is zero;
  ``s`` is then held at its floor (:data:`S_MIN`) and the interval is the gap between the
  largest failing and the smallest standing FS (``separated``: true).
* **Consistency check** (:func:`agreement_outside`): with softening switched off
  (:func:`perfectly_plastic`, ``mc --no-softening``) the MPM and strength reduction
  describe the same soil, and stand/fail should agree with "FS < 1" wherever FS is not
  within a margin of 1 (the FS search tolerance plus the MPM's failure criterion).
"""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from fem_rmpm.campaign.statistics import wilson_interval
from fem_rmpm.materials.strength import strengths
from fem_rmpm.scene import Scene, with_values

__all__ = ["S_MIN", "CHI2_HALF", "failure_split", "binned_fragility", "fit_probit",
           "probit_curve", "fragility_statistics", "agreement_outside", "perfectly_plastic",
           "has_softening"]

#: Floor of the probit scale s (FS units): below it the fit is "separated".
S_MIN = 1e-3
#: Half the 95 % quantile of chi2 with one degree of freedom (profile-likelihood interval).
CHI2_HALF = 0.5 * 3.841458820694124


def _interval(k: int, n: int) -> list[float] | None:
    return list(wilson_interval(k, n)) if n else None


def failure_split(fs: np.ndarray, below: np.ndarray, failed: np.ndarray) -> dict:
    """Counts and fractions (Wilson 95 %) of the failures that are progressive (FS >= 1)
    and strength-limited (FS < 1), and of the realizations with FS < 1 that stood.
    ``below``: the exact "FS < 1" flags of the search (its first trial is F = 1)."""
    failed, below = np.asarray(failed, bool), np.asarray(below, bool)
    k = int(failed.sum())
    prog = int((failed & ~below).sum())
    lim = int((failed & below).sum())
    return {"failures": k, "progressive": prog, "strength_limited": lim,
            "progressive_fraction": prog / k if k else None,
            "progressive_wilson95": _interval(prog, k),
            "strength_limited_fraction": lim / k if k else None,
            "strength_limited_wilson95": _interval(lim, k),
            "stood_with_fs_below_1": int((~failed & below).sum())}


def binned_fragility(fs: np.ndarray, failed: np.ndarray, bins: int | None = None) -> list[dict]:
    """P(failure) in equal-count FS bins (``bins``: default N // 10, 2 to 8): per bin the
    FS range and mean, n, failures, p and its Wilson 95 % interval."""
    fs, failed = np.asarray(fs, float), np.asarray(failed, bool)
    n = len(fs)
    if n == 0:
        return []
    nb = bins if bins is not None else int(min(8, max(2, n // 10)))
    nb = max(1, min(nb, n))
    order = np.argsort(fs, kind="stable")
    out = []
    for part in np.array_split(order, nb):
        if len(part) == 0:
            continue
        k = int(failed[part].sum())
        out.append({"fs_min": float(fs[part].min()), "fs_max": float(fs[part].max()),
                    "fs_mean": float(fs[part].mean()), "n": len(part), "failures": k,
                    "p": k / len(part), "wilson95": list(wilson_interval(k, len(part)))})
    return out


def _loglik(fs50: float, s: float, fs: np.ndarray, failed: np.ndarray) -> float:
    from scipy import stats  # lazy: scipy.stats costs 0.3 s at the command line's start
    z = (fs50 - fs) / s
    return float(np.sum(np.where(failed, stats.norm.logcdf(z), stats.norm.logcdf(-z))))


def _profile(fs50: float, fs: np.ndarray, failed: np.ndarray, s_max: float) -> tuple[float, float]:
    """(max over s of the log-likelihood at ``fs50``, that s)."""
    from scipy import optimize  # lazy: with scipy.stats (_loglik)
    res = optimize.minimize_scalar(lambda ls: -_loglik(fs50, math.exp(ls), fs, failed),
                                   bounds=(math.log(S_MIN), math.log(s_max)), method="bounded",
                                   options={"xatol": 1e-6})
    return -float(res.fun), math.exp(float(res.x))


def fit_probit(fs: np.ndarray, failed: np.ndarray) -> dict | None:
    """Maximum-likelihood probit fragility ``P(failure | FS) = Phi((FS50 - FS) / s)`` with
    the 95 % profile-likelihood interval of FS50 (module docstring); None when every
    realization failed or none did (no curve to fit).  An interval bound that the profile
    does not reach within the data range +- 1 is None (open)."""
    from scipy import optimize  # lazy: with scipy.stats (_loglik)
    fs, failed = np.asarray(fs, float), np.asarray(failed, bool)
    if len(fs) < 2 or failed.all() or not failed.any():
        return None
    span = float(np.ptp(fs)) or 1.0
    s_max = 10.0 * span + 1.0
    grid = np.linspace(fs.min() - 0.1 * span, fs.max() + 0.1 * span, 201)
    prof = [(_profile(g, fs, failed, s_max)[0], g) for g in grid]
    best = max(prof)[1]
    step = grid[1] - grid[0]
    res = optimize.minimize_scalar(lambda x: -_profile(x, fs, failed, s_max)[0],
                                   bounds=(best - step, best + step), method="bounded",
                                   options={"xatol": 1e-7})
    fs50 = float(res.x)
    ll_max, s = _profile(fs50, fs, failed, s_max)
    separated = bool(fs[failed].max() < fs[~failed].min())

    def gap(x: float) -> float:
        return ll_max - _profile(x, fs, failed, s_max)[0] - CHI2_HALF

    def bound(direction: int) -> float | None:
        lo, far = fs50, fs50 + direction * (span + 1.0)
        if gap(far) < 0:
            return None
        return float(optimize.brentq(gap, *sorted((lo, far)), xtol=1e-6))
    return {"model": "probit: P = Phi((FS50 - FS) / s)", "fs50": fs50, "s": s,
            "fs50_interval95": [bound(-1), bound(+1)],
            "interval_method": "profile likelihood (chi2(1) 95 %)",
            "log_likelihood": ll_max, "n": len(fs), "separated": separated,
            "fs_failed_max": float(fs[failed].max()),
            "fs_stood_min": float(fs[~failed].min())}


def probit_curve(fit: dict, fs: np.ndarray) -> np.ndarray:
    """P(failure | FS) of a :func:`fit_probit` result at ``fs``."""
    from scipy import stats  # lazy: with _loglik
    return stats.norm.cdf((fit["fs50"] - np.asarray(fs, float)) / fit["s"])


def fragility_statistics(fs: Sequence[float], below: Sequence[bool],
                         failed: Sequence[bool]) -> dict:
    """The failure split, P(FS < 1) beside P(failure) (both Wilson 95 %), the binned
    fragility and the probit fit of one case's realizations with an FS and an MPM run."""
    fs, below, failed = (np.asarray(fs, float), np.asarray(below, bool),
                         np.asarray(failed, bool))
    n, k, kb = len(fs), int(failed.sum()), int(below.sum())
    return {"n": n, "p_failure": k / n if n else None, "p_failure_wilson95": _interval(k, n),
            "p_fs_below_1": kb / n if n else None, "p_fs_below_1_wilson95": _interval(kb, n),
            "split": failure_split(fs, below, failed),
            "binned": binned_fragility(fs, failed), "probit": fit_probit(fs, failed)}


def agreement_outside(fs: Sequence[float], below: Sequence[bool], failed: Sequence[bool],
                      margin: float = 0.03) -> dict:
    """Agreement of the MPM's stand/fail with "FS < 1" over the realizations with
    ``|FS - 1| > margin`` (and the count within the margin, left out)."""
    fs, below, failed = (np.asarray(fs, float), np.asarray(below, bool),
                         np.asarray(failed, bool))
    out = np.abs(fs - 1.0) > margin
    agree = int((below[out] == failed[out]).sum())
    n = int(out.sum())
    return {"margin": margin, "n": n, "agree": agree, "within_margin": int((~out).sum()),
            "fraction": agree / n if n else None}


def _softening_pairs(scene: Scene) -> list[tuple[int, str, str]]:
    """(soil index, residual name, peak name) of every residual a soil's model declares
    (``STRENGTHS`` rows with a ``peak``)."""
    return [(i, s.name, s.peak) for i, soil in enumerate(scene.soils)
            for s in strengths(soil.model) if s.peak is not None]


def has_softening(scene: Scene) -> bool:
    """Does any soil of ``scene`` have a residual below its peak?"""
    return any(float(scene.soils[i].value(r, math.inf)) < float(scene.soils[i].value(p, math.inf))
               for i, r, p in _softening_pairs(scene))


def perfectly_plastic(scene: Scene) -> Scene:
    """``scene`` with softening switched off: every residual that a soil's model declares
    (a ``STRENGTHS`` row with a ``peak``, :mod:`fem_rmpm.materials.strength`) set to its
    peak, so each soil is perfectly plastic at peak strength, as in the strength reduction.
    A random field of the peak scales the residual in proportion, so the residual of
    every point equals its peak.  Unchanged when no soil declares a residual."""
    changes = {f"soil[{i}].{r}": scene.soils[i].value(p) for i, r, p in _softening_pairs(scene)
               if scene.soils[i].value(p) is not None}
    return with_values(scene, changes) if changes else scene
