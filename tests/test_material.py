"""Soil at a material point: von Mises with cohesion softening.

References: radial return for J2 plasticity (Simo & Hughes 1998, ch. 3; de Souza Neto
et al. 2008, ch. 7) in Hencky log-strain space (Simo 1992); the softening laws are the
formulas of the module docstring, evaluated independently here.
"""
from __future__ import annotations

import numpy as np
import pytest
from soil_points import vm_points

from fem_rmpm.discretise.basis import q4_at_points
from fem_rmpm.discretise.grid import make_grid
from fem_rmpm.discretise.points import seed_particles
from fem_rmpm.materials import (
    exp_sym2,
    kirchhoff_stress,
    log_sym2,
    spatial_tangent,
    sqrt_j2,
    stress_update,
)
from fem_rmpm.scene import load_scene, with_values
from fem_rmpm.schemes.explicit.reference import map_to_nodes

E, NU = 1000.0, 0.33
G, K = E / (2 * (1 + NU)), E / (3 * (1 - 2 * NU))
CP, CR, GS = 20.0, 4.0, 0.5


def _soil(n=1, exponential=False, gs=GS):
    return vm_points(np.full(n, G), np.full(n, K), np.full(n, CP), np.full(n, CR),
                      np.full(n, gs), np.full(n, exponential))


def _law(gamma, exponential, gs=GS):
    """The softening law written out independently of the code."""
    if exponential:
        return CR + (CP - CR) * np.exp(-gamma / gs)
    return np.maximum(CR, CP - (CP - CR) * gamma / gs)


def _drive(F_path, soil):
    eps, gam = np.zeros((1, 4)), np.zeros(1)
    F_old = np.eye(2)
    q, g = [], []
    for F in F_path:
        dF = (F @ np.linalg.inv(F_old))[None]
        eps, gam, tau = stress_update(dF, eps, gam, soil)
        q.append(sqrt_j2(tau)[0])
        g.append(gam[0])
        F_old = F
    return np.array(q), np.array(g)


@pytest.mark.parametrize("exponential", [False, True])
def test_simple_shear_reaches_peak_then_softens_to_residual(exponential):
    """Simple shear F = [[1, g], [0, 1]] at a constant rate: elastic until sqrt(J2) = c_peak
    (at g ~ c/G), then sqrt(J2) = c(gamma_p) on the softening law at every step, down to
    c_res, all within 1e-6 relative."""
    soil = _soil(exponential=exponential)
    g_path = np.linspace(0, 4.0, 2001)[1:]
    q, gam = _drive([np.array([[1.0, g], [0.0, 1.0]]) for g in g_path], soil)
    plastic = gam > 0
    first = np.argmax(plastic)
    assert abs(g_path[first] - CP / G) < 0.01 * CP / G + (g_path[1] - g_path[0])
    assert np.all(q[~plastic] <= CP * (1 + 1e-9))
    assert np.allclose(q[plastic], _law(gam[plastic], exponential), rtol=1e-6)
    if exponential:   # approaches c_res asymptotically: past 5 e-folding strains
        assert gam[-1] > 5 * GS and q[-1] - CR < 0.01 * (CP - CR)
    else:
        assert abs(q[-1] / CR - 1) < 1e-6
    assert np.all(np.diff(gam) >= -1e-15)


def test_plane_strain_compression_softens_likewise():
    """Uniaxial plane-strain compression F = diag(1, 1 - e): same law, 1e-6 relative."""
    soil = _soil()
    path = [np.diag([1.0, 1.0 - e]) for e in np.linspace(0, 0.6, 1501)[1:]]
    q, gam = _drive(path, soil)
    plastic = gam > 0
    assert plastic.any() and gam[-1] > GS
    assert np.allclose(q[plastic], _law(gam[plastic], False), rtol=1e-6)
    assert abs(q[-1] / CR - 1) < 1e-6


@pytest.mark.parametrize("gamma0,exponential", [(0.0, False), (0.1, False), (0.6, False),
                                                (0.2, True), (0.0, True)])
def test_consistent_tangent_matches_finite_differences(gamma0, exponential):
    """The complex-step tangent equals a central finite-difference tangent of the same
    update to 1e-6 relative, on the elastic, softening and residual branches."""
    rng = np.random.default_rng(7)
    n = 6
    soil = _soil(n, exponential)
    eps = rng.normal(0, 0.01, (n, 4))
    gam = np.full(n, gamma0)
    dF = np.eye(2) + rng.normal(0, 0.03, (n, 2, 2))
    tau, A = spatial_tangent(dF, eps, gam, soil)
    assert np.any(stress_update(dF, eps, gam, soil)[1] > gam) or gamma0 == 0.0

    def T(t):
        return np.array([[t[:, 0], t[:, 3]], [t[:, 3], t[:, 1]]]).transpose(2, 0, 1)
    h = 1e-6
    for l in range(2):
        for m in range(2):
            E_lm = np.zeros((2, 2))
            E_lm[l, m] = 1.0
            tp = stress_update(dF + h * (E_lm @ dF), eps, gam, soil)[2]
            tm = stress_update(dF - h * (E_lm @ dF), eps, gam, soil)[2]
            fd = (T(tp) - T(tm)) / (2 * h)
            fd[:, :, l] -= T(tau)[:, :, m]
            assert np.max(np.abs(fd - A[:, :, :, l, m])) <= 1e-6 * np.max(np.abs(A))


def test_log_exp_roundtrip_and_repeated_eigenvalues():
    """1/2 ln(exp(2 E)) = E, including E = 0 and isotropic E (repeated eigenvalues)."""
    rng = np.random.default_rng(3)
    e = np.vstack([rng.normal(0, 0.2, (50, 3)), np.zeros((1, 3)), [[0.1, 0.1, 0.0]]])
    back = np.stack(log_sym2(*exp_sym2(e[:, 0], e[:, 1], e[:, 2])), axis=1)
    assert np.allclose(back, e, atol=1e-13)


def test_block_in_simple_shear_yields_at_predicted_load(meshes):
    """A plane-strain block (bottom fixed, top moved sideways) in simple shear; the shear
    load on its top, F = sum of nodal internal forces, grows as G g L and first yield
    occurs when F = c_peak L (von Mises, sqrt(J2) = tau_xy = c): within 1 %."""
    scene = load_scene(meshes / "column.toml")
    L, H = 2.0, 1.0
    scene = with_values(scene, {"grid.size": [L, H], "grid.cell": [0.25, 0.25],
                                "soil.polygon": [[0, 0], [L, 0], [L, H], [0, H]],
                                "soil.model": "von_mises_softening", "soil.cohesion_peak": CP,
                                "soil.cohesion_residual": CR})
    grid = make_grid(scene)
    pts = seed_particles(scene, grid)
    _, nodes, N, dN, _ = q4_at_points(grid, pts.x)
    top = np.isclose(grid.nodes[:, 1], H)
    rate, dt = 1.0, 2e-4                                   # shear strain rate 1/s
    eps, gam = np.zeros((pts.n, 4)), np.zeros(pts.n)
    v_nodes = np.stack([rate * grid.nodes[:, 1], 0 * grid.nodes[:, 1]], axis=1)
    L_grad = np.einsum("pak,pal->pkl", v_nodes[nodes], dN)
    load_at_yield = None
    for step in range(1, 600):
        dF = np.eye(2) + L_grad * dt                          # exact simple-shear increment
        eps, gam, tau = stress_update(dF, eps, gam, pts.soil)
        _, _, f = map_to_nodes(nodes, N, dN, pts.mass, pts.velocity, tau, pts.volume,
                               np.zeros(2), grid.n_nodes)
        load = -f[top, 0].sum()
        if gam.max() > 0:
            load_at_yield = prev_load
            break
        prev_load = load
    assert load_at_yield is not None
    assert abs(load_at_yield / (CP * L) - 1) < 0.01


def test_models_share_the_defaults_of_the_soil_fields():
    """A model's parameter that is also a field of SoilSpec (the keys softening models
    share) is read from that field, so the field's default is the model's: a model either
    requires the key (default None; validation then needs a value, or the model's own check
    refuses the field's infinite strength) or declares the field's default."""
    import dataclasses

    from fem_rmpm import materials
    from fem_rmpm.scene import SoilSpec
    fields = {f.name: f.default for f in dataclasses.fields(SoilSpec)}
    shared = 0
    for m in materials.models():
        for p in m.PARAMETERS:
            if p.name in fields:
                shared += 1
                assert p.default is None or p.default == fields[p.name], (m.NAME, p.name)
    assert shared >= 4          # von Mises' and Mohr-Coulomb's cohesions, law and strain
