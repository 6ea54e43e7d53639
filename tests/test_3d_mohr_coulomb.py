"""Mohr–Coulomb with softening in the three-dimensional explicit scheme.

The 3-D return (:func:`fem_rmpm.schemes.explicit3d.plastic.plastic_return_principal_3d`)
calls the plane-strain model's principal-space return
(:mod:`fem_rmpm.materials.mohr_coulomb_return`) on the three principal elastic log strains,
so it must give the plane-strain model's update on plane-strain trial strains; on general
3-D trials the returned stress must lie on the softened Mohr–Coulomb surface (closed form,
de Souza Neto, Peric & Owen 2008, *Computational Methods for Plasticity*, sec. 8.2) with
the plastic flow of the dilation angle; and a slab one cell thick with rollers on both
strike faces must move as the plane-strain run of its section.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from fem_rmpm import api
from fem_rmpm.cli import main
from fem_rmpm.discretise.points3d import MODEL_NUMBERS_3D
from fem_rmpm.materials import material_points, mohr_coulomb, new_state
from fem_rmpm.scene import scene_from_dict
from fem_rmpm.schemes.explicit.loop import run_explicit
from fem_rmpm.schemes.explicit3d import plastic
from fem_rmpm.schemes.explicit3d.loop import run_explicit_3d
from fem_rmpm.schemes.explicit3d.plastic import MODEL_MOHR_COULOMB, plastic_return_points_3d

SOIL = {"polygon": [[0, 0], [1, 0], [1, 1], [0, 1]], "unit_weight": 20.0,
        "youngs_modulus": 1000.0, "poisson_ratio": 0.33, "model": "mohr_coulomb_softening",
        "cohesion_peak": 10.0, "cohesion_residual": 2.0, "friction_angle_peak": 30.0,
        "friction_angle_residual": 20.0, "dilation_angle_peak": 10.0,
        "dilation_angle_residual": 0.0, "softening_strain": 0.5}
G = 1000.0 / (2 * 1.33)
K = 1000.0 / (3 * (1 - 2 * 0.33))
LAM = K - 2.0 / 3.0 * G


def _points(n, **values):
    soils = scene_from_dict({"soil": [{**SOIL, **values}]}).soils
    return material_points(soils, np.zeros(n, dtype=np.int64))


def _principal_stress(e):
    """Kirchhoff principal stresses (kPa) of principal log strains (n, 3), sorted
    descending."""
    tau = LAM * e.sum(1, keepdims=True) + 2 * G * e
    return -np.sort(-tau, axis=1)


def _strengths(gamma, values):
    """c (kPa), phi, psi (rad) of linear softening at plastic shear strain gamma."""
    w = np.clip(1 - gamma / values["softening_strain"], 0.0, 1.0)
    c = values["cohesion_residual"] + (values["cohesion_peak"] - values["cohesion_residual"]) * w
    phi = values["friction_angle_residual"] + (
        values["friction_angle_peak"] - values["friction_angle_residual"]) * w
    psi = values["dilation_angle_residual"] + (
        values["dilation_angle_peak"] - values["dilation_angle_residual"]) * w
    return c, np.radians(phi), np.radians(psi)


@pytest.mark.parametrize("values", [{}, {"softening": "exponential"}, {"tension_cutoff": 3.0}],
                         ids=["linear", "exponential", "tension_cutoff"])
def test_plane_strain_trials_return_as_the_2d_model(values):
    """2000 random plane-strain trial log strains ``[xx, yy, zz, xy]`` (yz = xz = 0) and
    prior plastic strains across the end of the linear slope: the 3-D return on their
    principal values, turned back with the trial's eigenvectors, equals the 2-D model's
    update (:func:`fem_rmpm.materials.mohr_coulomb.update`) to 2e-16 in the strains (the
    yz, xz components stay 0) and 5e-16 in the plastic shear strain (achieved 2.8e-17
    and 1.1e-16); the trials reach the main plane, both edges, the apex and (with
    ``tension_cutoff``) the cut-off."""
    n = 2000
    rng = np.random.default_rng(3)
    eps4 = rng.normal(0.0, 0.02, (n, 4))
    eps4[:, :3] += rng.normal(0.0, 0.01, (n, 1))
    soil = _points(n, **values)
    state = new_state(soil)
    state[:, 0] = rng.uniform(0.0, 0.7, n)
    eps2, st2, _ = mohr_coulomb.update(eps4.copy(), state.copy(), soil.params)
    full = np.zeros((n, 3, 3))
    full[:, 0, 0], full[:, 1, 1], full[:, 2, 2] = eps4[:, 0], eps4[:, 1], eps4[:, 2]
    full[:, 0, 1] = full[:, 1, 0] = eps4[:, 3]
    w, Q = np.linalg.eigh(full)
    st3 = state.copy()
    dg = plastic_return_points_3d(MODEL_MOHR_COULOMB, w, LAM, G,
                                  np.ascontiguousarray(soil.params[:, 2:]), st3)
    back = np.einsum("nik,nk,njk->nij", Q, w, Q)
    eps3 = np.stack([back[:, 0, 0], back[:, 1, 1], back[:, 2, 2], back[:, 0, 1]], axis=1)
    assert np.abs(eps3 - eps2).max() < 2e-16
    assert np.abs(back[:, 1, 2]).max() < 2e-16 and np.abs(back[:, 0, 2]).max() < 2e-16
    assert np.abs(st3[:, 0] - st2[:, 0]).max() < 5e-16
    assert np.allclose(dg, st3[:, 0] - state[:, 0], rtol=0, atol=1e-15)
    s = _principal_stress(w)
    tol = 1e-9 * np.abs(s).max(1)
    yielded = st2[:, 0] > state[:, 0]
    upper = yielded & (s[:, 0] - s[:, 1] < tol) & (s[:, 1] - s[:, 2] > tol)
    lower = yielded & (s[:, 1] - s[:, 2] < tol) & (s[:, 0] - s[:, 1] > tol)
    apex = yielded & (s[:, 0] - s[:, 2] < tol)
    main_plane = yielded & (s[:, 0] - s[:, 1] > tol) & (s[:, 1] - s[:, 2] > tol)
    assert min(upper.sum(), lower.sum(), main_plane.sum()) > 20 and apex.sum() > 0
    if "tension_cutoff" in values:
        assert (np.abs(s[:, 0] - 3.0) < 1e-9).sum() > 20


def test_general_trials_end_on_the_surface_and_flow_with_the_dilation_angle():
    """3000 random 3-D principal trial log strains (not plane strain; 530 return to the
    apex, 362 to an edge, 403 to the main plane) and prior plastic strains, linear
    softening: a plastic point's returned principal stresses satisfy
    ``tau_1 - tau_3 + (tau_1 + tau_3) sin(phi) = 2 c cos(phi)`` at c, phi of its new
    plastic shear strain (closed form of the law) to 1e-12 of the stresses; its plastic
    strain increment ``dp`` (trial minus returned, per principal direction) has
    ``tr(dp) = sin(psi) sum |dp_k|`` (each Mohr–Coulomb plane's flow ``(1 + sin psi, 0,
    -(1 - sin psi))`` up to order: dilatancy of psi at the step's start, capped at phi) and
    ``gamma_p`` grows by ``sqrt(2 dev(dp) : dev(dp))``, both to 1e-12; apex returns end
    at the isotropic ``c cot(phi)``; elastic trials are unchanged and inside the surface."""
    n = 3000
    rng = np.random.default_rng(7)
    e = rng.normal(0.0, 0.02, (n, 3)) + rng.normal(-0.01, 0.01, (n, 1))
    trial = e.copy()
    soil = _points(n)
    state = new_state(soil)
    gamma0 = rng.uniform(0.0, 0.7, n)
    state[:, 0] = gamma0
    plastic_return_points_3d(MODEL_MOHR_COULOMB, e, LAM, G,
                             np.ascontiguousarray(soil.params[:, 2:]), state)
    gamma = state[:, 0]
    yielded = gamma > gamma0
    assert yielded.sum() > 1000 and (~yielded).sum() > 1000
    assert np.array_equal(e[~yielded], trial[~yielded])
    s = _principal_stress(e)
    c, phi, _ = _strengths(gamma, SOIL)
    f = s[:, 0] - s[:, 2] + (s[:, 0] + s[:, 2]) * np.sin(phi) - 2 * c * np.cos(phi)
    scale = np.abs(s).max(1) + c
    assert np.all(np.abs(f[yielded]) < 1e-12 * scale[yielded])
    assert np.all(f[~yielded] <= 1e-12 * scale[~yielded])
    apex = yielded & (s[:, 0] - s[:, 2] < 1e-9 * scale)
    planes = yielded & ~apex
    edge = planes & ((s[:, 0] - s[:, 1] < 1e-9 * scale) | (s[:, 1] - s[:, 2] < 1e-9 * scale))
    assert apex.sum() > 100 and planes.sum() > 500 and edge.sum() > 200
    cot = c[apex] * np.cos(phi[apex]) / np.sin(phi[apex])
    assert np.abs(s[apex] - cot[:, None]).max() < 1e-12 * np.abs(cot).max()
    dp = (trial - e)[planes]
    _, phi0, psi0 = _strengths(gamma0[planes], SOIL)
    sin_psi = np.sin(np.minimum(psi0, phi0))
    assert np.abs(dp.sum(1) - sin_psi * np.abs(dp).sum(1)).max() < 1e-12
    dev = dp - dp.mean(1, keepdims=True)
    dgamma = np.sqrt(2 * (dev ** 2).sum(1))
    assert np.abs(gamma[planes] - gamma0[planes] - dgamma).max() < 1e-12


def test_the_return_keeps_the_slots_of_the_principal_values():
    """The principal values come in any order and go back into the slots they came
    from: every permutation of the same trial returns the same permutation of one
    result."""
    soil = _points(6)
    rows = np.ascontiguousarray(soil.params[:, 2:])
    base = np.array([0.04, -0.01, -0.05])
    perms = [(0, 1, 2), (0, 2, 1), (1, 0, 2), (1, 2, 0), (2, 0, 1), (2, 1, 0)]
    e = np.array([base[list(p)] for p in perms])
    state = new_state(soil)
    dg = plastic_return_points_3d(MODEL_MOHR_COULOMB, e, LAM, G, rows, state)
    assert np.all(dg > 0) and np.all(dg == dg[0])
    for k, p in enumerate(perms):
        assert np.array_equal(e[k], e[0][list(p)])


def test_the_points_carry_the_2d_parameter_rows_and_the_step_numbers_of_plastic_py():
    """A Mohr–Coulomb soil's 3-D points carry its 2-D parameter row without G and K
    (``[c_p, c_r, phi_p, phi_r, psi_p, psi_r, softening_strain, law, tension_cutoff]``)
    and the model numbers of the 3-D step are :mod:`.plastic`'s."""
    assert MODEL_NUMBERS_3D == {"linear_elastic": plastic.MODEL_ELASTIC,
                                "von_mises_softening": plastic.MODEL_VON_MISES,
                                "mohr_coulomb_softening": plastic.MODEL_MOHR_COULOMB}
    sc = _slab_scene(3, t_end=0.1)
    _, pts = api.prepare(sc)
    assert np.all(pts.model == plastic.MODEL_MOHR_COULOMB)
    assert np.array_equal(pts.plastic[0], [2.0, 0.5, 30.0, 25.0, 5.0, 0.0, 0.2, 0.0, math.inf])
    assert pts.state.shape[1] == 1


# --------------------------------------------------------------- the slab against 2-D
def _slab_scene(dim, t_end=1.0):
    """A 1.5 m x 1.5 m block of frictional soil (c' 2 -> 0.5 kPa, phi' 30 -> 25 deg, psi
    5 -> 0 deg, softening strain 0.2) on a fixed base, free on its right, 0.25 m cells; in
    3-D one cell thick along the strike with rollers on both strike faces.  Its critical
    height as a vertical cut, 4 c / gamma tan(45 + phi / 2) = 0.69 m, is below 1.5 m: it
    collapses to the right when gravity is ramped on over 0.2 s."""
    soil = {**SOIL, "polygon": [[0, 0], [1.5, 0], [1.5, 1.5], [0, 1.5]],
            "youngs_modulus": 2000.0, "poisson_ratio": 0.3, "cohesion_peak": 2.0,
            "cohesion_residual": 0.5, "friction_angle_peak": 30.0,
            "friction_angle_residual": 25.0, "dilation_angle_peak": 5.0,
            "dilation_angle_residual": 0.0, "softening_strain": 0.2}
    grid = {"origin": [0.0, 0.0], "size": [4.0, 2.0], "cell": 0.25}
    boundary = {"left": "roller", "right": "roller", "bottom": "fixed", "top": "free"}
    if dim == 3:
        grid = {"origin": [0.0, 0.0, 0.0], "size": [4.0, 2.0, 0.25], "cell": 0.25}
        boundary.update(front="roller", back="roller")
    solver = {"scheme": "explicit", "gravity_phase": "dynamic", "gravity_ramp_time": 0.2,
              "damping": 0.0, "cfl": 0.5, "t_end": t_end, "output_interval": t_end,
              "rest_velocity": 1e-9, "rest_energy_ratio": 1e-12}
    return scene_from_dict({"scene": {"name": f"block_{dim}d"}, "grid": grid,
                            "boundary": boundary, "soil": [soil], "solver": solver})


def test_slab_with_rollers_on_the_strike_faces_moves_as_the_plane_strain_run():
    """The collapsing block (:func:`_slab_scene`) to t = 1 s (326 steps): the 3-D slab's
    points (two per 2-D point along the strike) end where the plane-strain run's do to
    5e-13 m after up to 0.84 m of displacement (achieved 4.5e-14 m), with the same plastic
    shear strain to 2.5e-12 (achieved 2.5e-13; up to 3.0, past the residual), no motion
    along the strike, and the same toe position."""
    runs = {}
    for dim in (2, 3):
        sc = _slab_scene(dim)
        grid, pts = api.prepare(sc)
        rec = (run_explicit if dim == 2 else run_explicit_3d)(sc, grid, pts)
        assert rec.stop_reason == "t_end reached" and rec.steps > 300
        runs[dim] = pts
    p2, p3 = runs[2], runs[3]
    where = {tuple(np.round(x, 9)): i for i, x in enumerate(p2.x0)}
    idx = np.array([where[tuple(np.round(x, 9))] for x in p3.x0[:, :2]])
    assert len(idx) == 2 * p2.n
    moved = np.linalg.norm(p2.x - p2.x0, axis=1)
    assert moved.max() > 0.5 and p2.state[:, 0].max() > 0.2       # collapsed, softened
    assert np.abs(p3.x[:, :2] - p2.x[idx]).max() < 5e-13
    assert np.array_equal(p3.x[:, 2], p3.x0[:, 2])
    assert np.abs(p3.state[:, 0] - p2.state[idx, 0]).max() < 2.5e-12
    assert abs(p3.x[:, 0].max() - p2.x[:, 0].max()) < 5e-13


# --------------------------------------------------------------- the scene
MESHES = Path(__file__).parents[1] / "meshes"


def test_a_3d_mohr_coulomb_scene_is_accepted_and_pore_water_is_refused(capsys, tmp_path):
    """``mohr_coulomb_softening`` reads in a 3-D scene; ``[water]`` in 3-D (the pore
    pressure is plane strain only) exits 2 with one line naming ``[water]``, nothing
    written."""
    assert _slab_scene(3).soils[0].model == "mohr_coulomb_softening"
    text = (MESHES / "column_3d.toml").read_text() + (
        "\n[water]\nphreatic_surface = [[0.0, 3.0], [0.25, 3.0]]\n")
    path = tmp_path / "wet.toml"
    path.write_text(text)
    out = tmp_path / "out"
    code = main(["run", str(path), "--out", str(out), "--quiet"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and "[water]" in err, err
    assert "Traceback" not in err and not out.exists()
