"""Linear elastic soil: Hencky elasticity only, no strength (``model = "linear_elastic"``).

Parameter row ``[shear_modulus, bulk_modulus]`` (kPa); no state variable.
"""
from __future__ import annotations

import numpy as np
from numba import njit

from fem_rmpm.materials.hencky import hencky_stress

NAME = "linear_elastic"
PARAMETERS = ()
STATE = ()


def update(eps_tr: np.ndarray, state: np.ndarray, params: np.ndarray):
    """The trial log strain is the elastic one; Kirchhoff stress from Hencky's law."""
    return eps_tr, state, hencky_stress(eps_tr, params[:, 0], params[:, 1])


@njit(inline="always", fastmath=False, error_model="numpy")
def point_update(e0, e1, e2, e3, state, params, i):
    G = params[i, 0]
    lam = params[i, 1] - 2 / 3 * G
    vol = e0 + e1 + e2
    return (e0, e1, e2, e3, 2 * G * e0 + lam * vol, 2 * G * e1 + lam * vol,
            2 * G * e2 + lam * vol, 2 * G * e3)


def tangent(eps_tr: np.ndarray, state: np.ndarray, params: np.ndarray) -> np.ndarray:
    """``d tau / d eps_tr`` (n, 4, 4) of Hencky's law, ``K 1 1^T + 2 G I_dev`` (kPa);
    columns ``[xx, yy, zz, xy]`` (``xy`` a symmetric, tensor perturbation)."""
    G, K = params[:, 0], params[:, 1]
    one = np.array([1.0, 1.0, 1.0, 0.0])
    dev = np.eye(4) - np.outer(one, one) / 3
    return (K[:, None, None] * np.outer(one, one) + 2 * G[:, None, None] * dev)
