"""The three-dimensional von Mises return against the plane-strain model's own update
(:mod:`fem_rmpm.materials.von_mises` through :func:`fem_rmpm.materials.hencky.return_map`):
on plane-strain trial strains the two must agree, and on general 3-D strains the returned
state must lie on the softened yield surface."""
from __future__ import annotations

import numpy as np
import pytest

from fem_rmpm.materials import material_points, new_state
from fem_rmpm.materials.hencky import return_map
from fem_rmpm.scene import scene_from_dict
from fem_rmpm.schemes.explicit3d.plastic import von_mises_points_3d

E, NU = 1000.0, 0.33
G = E / (2 * (1 + NU))


def _soil(softening):
    scene = scene_from_dict({"soil": [{
        "polygon": [[0, 0], [1, 0], [1, 1], [0, 1]], "unit_weight": 20.0,
        "youngs_modulus": E, "poisson_ratio": NU, "model": "von_mises_softening",
        "cohesion_peak": 20.0, "cohesion_residual": 4.0, "softening": softening,
        "softening_strain": 0.5}]})
    return scene.soils


@pytest.mark.parametrize("softening", ["linear", "exponential"])
def test_plane_strain_trials_return_as_the_2d_model(softening):
    """200 random plane-strain trial log strains (xx, yy, zz, xy; yz = xz = 0) and prior
    plastic strains (across the end of the linear slope): the 3-D return equals the 2-D
    model's strain and plastic shear strain to 1e-12."""
    rng = np.random.default_rng(11)
    n = 200
    eps4 = rng.normal(0, 0.03, (n, 4))
    gamma0 = rng.uniform(0, 0.7, n)
    soils = _soil(softening)
    soil = material_points(soils, np.zeros(n, dtype=np.int64))
    state = new_state(soil)
    state[:, 0] = gamma0
    state[:, 1] = gamma0
    eps2, st2, _ = return_map(eps4.copy(), state.copy(), soil)
    eps6 = np.zeros((n, 6))
    eps6[:, :4] = eps4
    dg = von_mises_points_3d(eps6, G, 20.0, 4.0, 0.5, softening == "exponential", gamma0)
    assert (dg > 0).sum() > 50
    assert np.abs(eps6[:, :4] - eps2).max() < 1e-12
    assert np.abs(gamma0 + dg - st2[:, 0]).max() < 1e-12


def test_general_trials_end_on_the_softened_yield_surface():
    """On general 3-D trial strains, sqrt(J2(tau)) after the return equals c(gamma_p) of
    the new plastic strain (linear law), the volume strain is kept, and elastic trials
    are untouched."""
    rng = np.random.default_rng(12)
    eps = rng.normal(0, 0.012, (300, 6))
    before = eps.copy()
    gamma0 = rng.uniform(0, 0.7, 300)
    dg = von_mises_points_3d(eps, G, 20.0, 4.0, 0.5, False, gamma0)
    gamma = gamma0 + dg
    c = np.where(gamma < 0.5, 20.0 - 32.0 * gamma, 4.0)
    mean = eps[:, :3].sum(1) / 3
    dev = eps.copy()
    dev[:, :3] -= mean[:, None]
    q = np.sqrt(2.0) * G * np.sqrt((dev[:, :3] ** 2).sum(1) + 2 * (dev[:, 3:] ** 2).sum(1))
    plastic = dg > 0
    assert plastic.sum() > 100 and (~plastic).sum() > 10
    assert np.abs(q[plastic] - c[plastic]).max() < 1e-9
    assert np.all(q[~plastic] <= c[~plastic] + 1e-12)
    assert np.allclose(eps[:, :3].sum(1), before[:, :3].sum(1), atol=1e-15)
    assert np.array_equal(eps[~plastic], before[~plastic])
