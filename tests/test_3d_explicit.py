"""The explicit scheme on hexahedra against closed forms and scikit-fem's 3-D static FEM:
the column under self-weight, the geostatic state of an elastic slope with a plan shape,
the 3x3 spectral functions and objectivity of the finite-strain update, the output files."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from fem_rmpm import api
from fem_rmpm.discretise.basis3d import hex8_at_points
from fem_rmpm.schemes.explicit3d.elastic import spectral_3d
from fem_rmpm.schemes.fem3d import solve_static_3d

MESHES = Path(__file__).parents[1] / "meshes"


def _rel_l2(a, b, w):
    a, b = a.reshape(len(w), -1), b.reshape(len(w), -1)
    return float(np.sqrt(np.sum(np.sum((a - b) ** 2, 1) * w) / np.sum(np.sum(b ** 2, 1) * w)))


@pytest.fixture(scope="module")
def column(tmp_path_factory):
    scene = api.load_scene(MESHES / "column_3d.toml")
    return api.run(scene, out=tmp_path_factory.mktemp("column3d"))


def test_column_3d_meets_cell_mean_closed_form_and_k0(column):
    """Column under self-weight (rollers on four sides, fixed base), closed form
    sigma_yy = -gamma (H - y), sigma_xx = sigma_zz = K0 sigma_yy, K0 = nu / (1 - nu).
    Trilinear hexahedra carry a cell-constant sigma_yy, so each point is compared with the
    closed form at its cell's mid-height (the cell-mean closed form).  Achieved (0.25 m
    cells, 160 points): relative L2 3.9e-5 (asserts 2e-4); K0 of every point 3e-12 (asserts
    1e-10, round-off: the points near the free top carry ~2.5 kPa)."""
    p = column.particles
    assert column.record.stop_reason == "at rest"
    y_mid = (np.floor(p.x0[:, 1] / 0.25) + 0.5) * 0.25
    err = _rel_l2(p.stress[:, 1], -20.0 * (5.0 - y_mid), p.volume0)
    assert err < 2e-4
    k0 = 0.33 / 0.67
    assert np.abs(p.stress[:, 0] / p.stress[:, 1] / k0 - 1).max() < 1e-10
    assert np.abs(p.stress[:, 2] / p.stress[:, 1] / k0 - 1).max() < 1e-10


def test_column_3d_writes_readable_vtk_and_summary(column):
    """The points (.vtu, .pvd) and the soil cells (grid.vtu) read back with pyvista: the
    point stress equals the run's, the hexahedra have the soil's volume (positive cells:
    VTK's corner order)."""
    pv = pytest.importorskip("pyvista")
    out = column.out
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "ok" and summary["dimension"] == 3
    assert summary["particles"] == column.particles.n == 160
    last = sorted(out.glob("particles_*.vtu"))[-1]
    m = pv.read(last)
    assert m.n_points == 160
    assert np.allclose(m.point_data["stress"], column.particles.stress)
    g = pv.read(out / "grid.vtu")
    vols = g.compute_cell_sizes()["Volume"]
    assert g.n_cells == 20 and np.allclose(vols, 0.25 ** 3)


def test_elastic_slope_3d_geostatic_state_matches_fem():
    """A 3 m elastic slope with an oblique plan face (meshes/slope_elastic_3d.toml), the
    explicit geostatic state at rest against scikit-fem's static FEM on the same hexahedra
    (:mod:`fem_rmpm.schemes.fem3d`), point by point at the Gauss points where the points
    are seeded: volume-weighted relative L2 of the six stress components achieved 1.3e-5
    (asserts 1e-3) and of the displacement 3.6e-5 (asserts 1e-3)."""
    scene = api.load_scene(MESHES / "slope_elastic_3d.toml")
    res = api.run(scene)
    p, grid = res.particles, res.grid
    assert res.record.solver["geostatic_at_rest"]
    fem = solve_static_3d(scene, grid)
    where = {tuple(k): i for i, k in enumerate(np.round(fem.points, 9))}
    j = np.array([where[tuple(k)] for k in np.round(p.x0, 9)])
    assert len(np.unique(j)) == p.n == len(fem.points)
    _, nodes, N, _, _ = hex8_at_points(grid, p.x0)
    u_fem = np.einsum("pa,pak->pk", N, fem.displacement[nodes])
    es = _rel_l2(p.stress, fem.stress[j], p.volume0)
    eu = _rel_l2(p.displacement, u_fem, p.volume0)
    assert es < 1e-3 and eu < 1e-3
    assert np.abs(fem.stress[:, 4]).max() > 0.1      # a genuinely 3-D state (tau_yz)


def test_spectral_functions_match_numpy():
    """Eigenvalues, exp and log of random symmetric 3x3 tensors (and of the repeated
    eigenvalues of a multiple of the identity) against numpy.linalg.eigh, to 1e-13."""
    rng = np.random.default_rng(5)
    for v in [np.array([0.2, 0.2, 0.2, 0, 0, 0])] + [rng.normal(0, 0.3, 6) for _ in range(20)]:
        A = np.array([[v[0], v[3], v[5]], [v[3], v[1], v[4]], [v[5], v[4], v[2]]])
        w, Q = np.linalg.eigh(A)
        assert np.allclose(np.sort(spectral_3d(v, 0)), w, atol=1e-13)
        E = (Q * np.exp(w)) @ Q.T
        assert np.allclose(spectral_3d(v, 1), E[[0, 1, 2, 0, 1, 0], [0, 1, 2, 1, 2, 2]],
                           atol=1e-13)
        e = spectral_3d(v, 1)
        assert np.allclose(spectral_3d(e, 2), v, atol=1e-12)
