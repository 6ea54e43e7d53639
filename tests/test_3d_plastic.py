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


def test_principal_return_equals_the_six_component_return_on_a_rotated_strain():
    """The principal-value entry point of the 3-D step gives the same return as the
    six-component von Mises return on the same strain written in a rotated frame (an
    isotropic return is co-axial): principal values of the returned strain and the
    increment to round-off."""
    from fem_rmpm.runtime.compiled import jit
    from fem_rmpm.schemes.explicit3d.plastic import MODEL_VON_MISES, plastic_return_principal_3d

    @jit
    def principal_points(e, lam, mu, prow, state):
        out = np.empty(e.shape[0])
        for i in range(e.shape[0]):
            out[i] = plastic_return_principal_3d(MODEL_VON_MISES, e[i], lam, mu, prow, state[i])
        return out

    rng = np.random.default_rng(5)
    G, lam = 400.0, 1600.0
    e = rng.normal(0.0, 0.05, (40, 3))
    R = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    full = np.einsum("ij,nj,kj->nik", R, e, R)
    eps6 = np.stack([full[:, 0, 0], full[:, 1, 1], full[:, 2, 2],
                     full[:, 0, 1], full[:, 1, 2], full[:, 0, 2]], axis=1)
    gamma0 = rng.uniform(0.0, 0.6, 40)
    dg6 = von_mises_points_3d(eps6, G, 20.0, 4.0, 0.5, False, gamma0.copy())
    state = np.stack([gamma0, gamma0], axis=1)
    dgp = principal_points(e, lam, G, np.array([20.0, 4.0, 0.5, 0.0]), state)
    assert np.abs(dgp - dg6).max() < 1e-12 * max(1.0, np.abs(dg6).max())
    assert (dg6 > 0).sum() > 10
    back = np.empty((40, 3, 3))
    back[:, 0, 0], back[:, 1, 1], back[:, 2, 2] = eps6[:, 0], eps6[:, 1], eps6[:, 2]
    back[:, 0, 1] = back[:, 1, 0] = eps6[:, 3]
    back[:, 1, 2] = back[:, 2, 1] = eps6[:, 4]
    back[:, 0, 2] = back[:, 2, 0] = eps6[:, 5]
    assert np.allclose(np.sort(np.linalg.eigvalsh(back), axis=1), np.sort(e, axis=1), atol=1e-12)
    assert np.allclose(state[:, 0], gamma0 + dgp, atol=1e-14)
