"""The correlation model of the field (Markov, elliptic or separable, rotated with the
layering), Vanmarcke's 1-D local-average results and the marginal transform between
the standard Gaussian field and the soil property.

Marginals, with the point parameters (``mean`` = the soil's value of the property):

* ``normal``: ``v = mean (1 + cov z)``;
* ``lognormal``: ``v = exp(m_ln + s_ln z)``, ``s_ln^2 = ln(1 + cov^2)``,
  ``m_ln = ln(mean) - s_ln^2 / 2`` (mean ``mean``, COV ``cov``);
* ``beta`` on ``[low, high]`` (bounded, e.g. a friction angle): ``v = low + (high - low)
  B^-1(Phi(z); a, b)``, the shape parameters from the mean and the standard deviation
  ``sigma = cov mean``: ``m = (mean - low) / (high - low)``, ``s = sigma / (high - low)``,
  ``k = m (1 - m) / s^2 - 1``, ``a = m k``, ``b = (1 - m) k`` (needs
  ``sigma^2 < (mean - low)(high - mean)``, checked by the scene).  ``Phi`` and ``B^-1``
  are :func:`scipy.special.ndtr` and ``betaincinv`` (``betainccinv`` of ``Phi(-z)`` for
  ``z > 0``, so the upper tail keeps its precision); every value lies in ``[low, high]``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import special

from fem_rmpm.scene import RandomFieldSpec

__all__ = ["KINDS", "MarkovModel", "model_from_spec", "variance_function",
           "local_average_covariance_1d", "gaussian_to_property", "property_to_gaussian",
           "beta_shape"]

KINDS = ("markov_elliptic", "markov_separable")


@dataclass(frozen=True)
class MarkovModel:
    """Markov correlation with scales ``theta_h`` (along the layering) and ``theta_v`` (m).

    ``angle_deg``: layering angle to the grid x axis (counter-clockwise).
    """
    theta_h: float
    theta_v: float
    angle_deg: float = 0.0
    kind: str = "markov_elliptic"

    def __post_init__(self):
        if not (self.theta_h > 0 and self.theta_v > 0 and math.isfinite(self.theta_h)
                and math.isfinite(self.theta_v)):
            raise ValueError(f"scales of fluctuation must be positive and finite, got "
                             f"theta_h={self.theta_h}, theta_v={self.theta_v}")
        if self.kind not in KINDS:
            raise ValueError(f"kind must be one of {KINDS}, got {self.kind!r}")

    @property
    def rotation(self) -> np.ndarray:
        """(2, 2) matrix mapping grid-frame lags (dx, dy) to layering lags (p, q)."""
        a = math.radians(self.angle_deg)
        c, s = math.cos(a), math.sin(a)
        return np.array([[c, s], [-s, c]])

    def scaled_norm(self, dx, dy) -> np.ndarray:
        """The dimensionless distance ``r`` with ``rho = exp(-2 r)``."""
        R = self.rotation
        p = (R[0, 0] * dx + R[0, 1] * dy) / self.theta_h
        q = (R[1, 0] * dx + R[1, 1] * dy) / self.theta_v
        if self.kind == "markov_elliptic":
            return np.hypot(p, q)
        return np.abs(p) + np.abs(q)

    def correlation(self, dx, dy) -> np.ndarray:
        """Point correlation ``rho(dx, dy)`` for grid-frame lags in m."""
        return np.exp(-2.0 * self.scaled_norm(np.asarray(dx, float), np.asarray(dy, float)))

    def extent(self) -> np.ndarray:
        """(2,) half-widths (m) along x and y of the correlation ellipse r = 1."""
        a = math.radians(self.angle_deg)
        c, s = abs(math.cos(a)), abs(math.sin(a))
        return np.array([math.hypot(self.theta_h * c, self.theta_v * s),
                         math.hypot(self.theta_h * s, self.theta_v * c)])

    def key(self) -> tuple:
        return (float(self.theta_h), float(self.theta_v), float(self.angle_deg), self.kind)


def model_from_spec(spec: RandomFieldSpec) -> MarkovModel:
    return MarkovModel(theta_h=spec.anisotropy * spec.theta_v, theta_v=spec.theta_v,
                       angle_deg=spec.layering_angle_deg, kind=spec.correlation)


def variance_function(T, theta) -> np.ndarray:
    """Vanmarcke's variance function of the 1-D Markov model (Vanmarcke 1983, Random Fields, ch. 5).

    ``g(T) = (theta/T)^2 / 2 (2T/theta + exp(-2T/theta) - 1)``; g(0) = 1.
    """
    T = np.asarray(T, float)
    x = 2.0 * T / theta
    with np.errstate(invalid="ignore", divide="ignore"):
        g = 2.0 * (x + np.expm1(-x)) / x ** 2
    return np.where(x < 1e-6, 1.0 - x / 3.0, g)


def local_average_covariance_1d(k, T, theta) -> np.ndarray:
    """Covariance of 1-D Markov local averages over cells of length T at lag ``k`` cells.

    Vanmarcke (1983): ``C(k) = [D((k-1)T) - 2 D(kT) + D((k+1)T)] / (2 T^2)`` with
    ``D(x) = x^2 g(x)``; for the Markov model ``C(0) = g(T)`` and, for ``|k| >= 1``,
    ``C(k) = (theta/T)^2 exp(-2(|k|-1)T/theta) (1 - exp(-2T/theta))^2 / 4``.
    """
    k = np.abs(np.asarray(k, float))
    a = T / theta
    far = (1.0 / a) ** 2 * np.exp(-2.0 * np.maximum(k - 1.0, 0.0) * a) \
        * (-np.expm1(-2.0 * a)) ** 2 / 4.0
    return np.where(k < 0.5, variance_function(T, theta), far)


def beta_shape(mean, cov: float, low: float, high: float) -> tuple[np.ndarray, np.ndarray]:
    """Shape parameters ``(a, b)`` of the beta distribution on ``[low, high]`` with the
    given mean and coefficient of variation (arrays broadcast like ``mean``)."""
    width = high - low
    m = (np.asarray(mean, float) - low) / width
    s = cov * np.asarray(mean, float) / width
    k = m * (1.0 - m) / (s * s) - 1.0
    return m * k, (1.0 - m) * k


def gaussian_to_property(z, mean, spec) -> np.ndarray:
    """Marginal transform of standard Gaussian values ``z`` with the point parameters
    (``spec``: the property's ``distribution``, ``cov``, ``low``, ``high``; same units as
    ``mean``)."""
    z = np.asarray(z, float)
    if spec.distribution == "normal":
        return mean * (1.0 + spec.cov * z)
    if spec.distribution == "beta":
        if spec.cov == 0:
            return np.broadcast_to(np.asarray(mean, float), z.shape).copy()
        a, b = beta_shape(mean, spec.cov, spec.low, spec.high)
        u = np.where(z <= 0.0, special.betaincinv(a, b, special.ndtr(np.minimum(z, 0.0))),
                     special.betainccinv(a, b, special.ndtr(-np.maximum(z, 0.0))))
        return np.clip(spec.low + (spec.high - spec.low) * u, spec.low, spec.high)
    s2 = math.log1p(spec.cov ** 2)
    return mean * np.exp(math.sqrt(s2) * z - 0.5 * s2)      # = exp(m_ln + s_ln z)


def property_to_gaussian(v, mean, spec) -> np.ndarray:
    """Inverse of :func:`gaussian_to_property` (cov > 0; beta: ``low < v < high``)."""
    v = np.asarray(v, float)
    if spec.distribution == "normal":
        return (v / mean - 1.0) / spec.cov
    if spec.distribution == "beta":
        a, b = beta_shape(mean, spec.cov, spec.low, spec.high)
        x = (v - spec.low) / (spec.high - spec.low)
        lower = special.betainc(a, b, x)
        return np.where(lower <= 0.5, special.ndtri(lower),
                        -special.ndtri(special.betaincc(a, b, x)))
    s2 = math.log1p(spec.cov ** 2)
    return (np.log(v) - (np.log(mean) - 0.5 * s2)) / math.sqrt(s2)
