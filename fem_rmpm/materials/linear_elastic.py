"""Linear elastic soil: Hencky elasticity only, no strength (``model = "linear_elastic"``).

Parameter row ``[shear_modulus, bulk_modulus]`` (kPa); no state variable.
"""
from __future__ import annotations

import numpy as np
from numba import njit

from .hencky import hencky_stress

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
