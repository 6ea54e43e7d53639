"""The correlation model of a three-dimensional field: Markov, elliptic or separable, with
three scales of fluctuation and the layering turned about the strike axis.

Axes (the frame of the 3-D engine): ``x`` along the slope (down-dip direction of the
section), ``y`` vertical, ``z`` along the strike.  The layering is turned in the ``x-y``
section by ``angle_deg`` (counter-clockwise from x, as in 2-D), so it stays parallel to the
strike.  With the lags ``(p, q)`` along and across the layering in the section (the 2-D
rotation of ``(dx, dy)``) and ``dz`` along the strike:

* ``markov_elliptic``: ``rho = exp(-2 sqrt((p/theta_h)^2 + (q/theta_v)^2 + (dz/theta_z)^2))``;
* ``markov_separable``: ``rho = exp(-2 (|p|/theta_h + |q|/theta_v + |dz|/theta_z))``.

On the plane ``dz = 0`` both are the 2-D models of :class:`~.model.MarkovModel` with the same
``theta_h``, ``theta_v`` and angle.  ``theta_z = theta_h`` (the default of
:func:`model_from_spec_3d`) is the horizontally isotropic field of Hicks & Spencer (2010).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from fem_rmpm.random_field.model import KINDS, MarkovModel
from fem_rmpm.scene import RandomFieldSpec

__all__ = ["MarkovModel3D", "model_from_spec_3d"]


@dataclass(frozen=True)
class MarkovModel3D:
    """Markov correlation with scales ``theta_h`` (along the layering in the section),
    ``theta_v`` (across it) and ``theta_z`` (along the strike), all in m; ``angle_deg`` the
    layering angle to the x axis in the x-y section (counter-clockwise)."""
    theta_h: float
    theta_v: float
    theta_z: float
    angle_deg: float = 0.0
    kind: str = "markov_elliptic"

    def __post_init__(self):
        for name in ("theta_h", "theta_v", "theta_z"):
            v = getattr(self, name)
            if not (v > 0 and math.isfinite(v)):
                raise ValueError(f"scales of fluctuation must be positive and finite, got "
                                 f"{name}={v}")
        if self.kind not in KINDS:
            raise ValueError(f"kind must be one of {KINDS}, got {self.kind!r}")

    @property
    def section(self) -> MarkovModel:
        """The 2-D model of the x-y section (``dz = 0``)."""
        return MarkovModel(self.theta_h, self.theta_v, self.angle_deg, self.kind)

    @property
    def rotation(self) -> np.ndarray:
        """(3, 3) matrix mapping grid lags (dx, dy, dz) to layering lags (p, q, dz)."""
        R = np.eye(3)
        R[:2, :2] = self.section.rotation
        return R

    @property
    def scales(self) -> np.ndarray:
        return np.array([self.theta_h, self.theta_v, self.theta_z])

    def scaled_norm(self, dx, dy, dz) -> np.ndarray:
        """The dimensionless distance ``r`` with ``rho = exp(-2 r)``."""
        R = self.rotation
        p = (R[0, 0] * dx + R[0, 1] * dy) / self.theta_h
        q = (R[1, 0] * dx + R[1, 1] * dy) / self.theta_v
        s = np.asarray(dz, float) / self.theta_z
        if self.kind == "markov_elliptic":
            return np.sqrt(p * p + q * q + s * s)
        return np.abs(p) + np.abs(q) + np.abs(s)

    def correlation(self, dx, dy, dz) -> np.ndarray:
        """Point correlation ``rho(dx, dy, dz)`` for grid-frame lags in m."""
        return np.exp(-2.0 * self.scaled_norm(np.asarray(dx, float), np.asarray(dy, float),
                                              np.asarray(dz, float)))

    def extent(self) -> np.ndarray:
        """(3,) half-widths (m) along x, y, z of the correlation ellipsoid r = 1."""
        return np.append(self.section.extent(), self.theta_z)

    def key(self) -> tuple:
        return (float(self.theta_h), float(self.theta_v), float(self.theta_z),
                float(self.angle_deg), self.kind)


def model_from_spec_3d(spec: RandomFieldSpec, theta_z: float | None = None) -> MarkovModel3D:
    """The 3-D model of a ``[random_field]`` spec: ``theta_v``, ``theta_h = anisotropy
    theta_v`` and the layering as in 2-D; the strike scale ``theta_z`` (m) from the
    argument, else from a ``theta_strike`` attribute of the spec when it has one, else
    ``theta_h`` (horizontally isotropic)."""
    theta_h = spec.anisotropy * spec.theta_v
    if theta_z is None:
        theta_z = getattr(spec, "theta_strike", None)
    if theta_z is None:
        theta_z = theta_h
    return MarkovModel3D(theta_h=theta_h, theta_v=spec.theta_v, theta_z=float(theta_z),
                         angle_deg=spec.layering_angle_deg, kind=spec.correlation)
