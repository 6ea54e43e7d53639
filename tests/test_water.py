"""Pore water: the pore-pressure field, the column with a water table in both schemes,
the explicit kernels against the numpy reference step, and bad ``[water]`` input.

References: closed forms (hydrostatic pore pressure below a phreatic line; the
oedometric column with a water table, effective stress sigma' = sigma + u, tension
positive; Terzaghi's principle as in e.g. Craig's Soil Mechanics, ch. 3).
"""
from __future__ import annotations

import math
import re

import numpy as np
import pytest

from fem_rmpm import api
from fem_rmpm.cli import main
from fem_rmpm.discretise.grid import make_grid
from fem_rmpm.scene import load_scene, with_values
from fem_rmpm.schemes.explicit import kernels as K
from fem_rmpm.schemes.explicit.step import explicit_step
from fem_rmpm.schemes.pore_pressure import (
    pore_pressure,
    total_stress,
    water_force,
    water_table,
)
from fem_rmpm.runtime.compiled import jit

GW, G, GSAT, H, YW = 9.81, 18.0, 20.0, 5.0, 2.5


# ------------------------------------------------------------------ the field
@pytest.mark.parametrize("mode", ["hydrostatic", "parallel_seepage"])
@pytest.mark.parametrize("angle", [0.0, 25.0])
def test_pore_pressure_closed_form(meshes, mode, angle):
    """A straight phreatic line of true inclination beta in a frame tilted by ``angle``:
    u = gamma_w d (x cos^2 beta for parallel seepage), d the true-vertical depth below
    it, 0 above; grad u by finite differences of u.  Exact to round-off (1e-12)."""
    s = load_scene(meshes / "column_water.toml")
    beta = math.radians(10.0)
    a = math.radians(angle)
    # the line through the true point (0, 3) at inclination beta, given in the grid frame
    P = np.array([[-20.0, 3.0 - 20.0 * math.tan(beta)], [20.0, 3.0 + 20.0 * math.tan(beta)]])
    c, sn = math.cos(a), math.sin(a)
    grid_xy = np.column_stack([P[:, 0] * c - P[:, 1] * sn, P[:, 0] * sn + P[:, 1] * c])
    s = with_values(s, {"scene.frame_angle_deg": angle, "water.pore_pressure": mode,
                        "water.phreatic_surface": grid_xy.tolist(),
                        "grid.size": [0.25, 5.5]})
    wt = water_table(s)
    rng = np.random.default_rng(1)
    true = np.column_stack([rng.uniform(-5, 5, 200), rng.uniform(-4, 8, 200)])
    x = np.column_stack([true[:, 0] * c - true[:, 1] * sn, true[:, 0] * sn + true[:, 1] * c])
    u, grad = pore_pressure(wt, x)
    d = 3.0 + true[:, 0] * math.tan(beta) - true[:, 1]
    f = math.cos(beta) ** 2 if mode == "parallel_seepage" else 1.0
    assert np.abs(u - GW * f * np.maximum(d, 0)).max() < 1e-12
    e = 1e-6
    for k in range(2):
        dx = np.zeros(2)
        dx[k] = e
        fd = (pore_pressure(wt, x + dx)[0] - pore_pressure(wt, x - dx)[0]) / (2 * e)
        wet = d > 1e-3
        assert np.abs(fd[wet] - grad[wet, k]).max() < 1e-6
    assert np.all(grad[d < 0] == 0)


def test_compiled_water_force_equals_numpy(meshes):
    """The kernels' per-point force equals -V grad u of the numpy field (bitwise here)."""
    s = with_values(load_scene(meshes / "column_water.toml"),
                    {"water.phreatic_surface": [[0, 2.0], [0.1, 2.6], [0.25, 2.4]]})
    wt = water_table(s)
    rng = np.random.default_rng(2)
    x = np.column_stack([rng.uniform(-0.5, 0.8, 300), rng.uniform(0, 5, 300)])
    vol = rng.uniform(0.01, 0.02, 300)

    @jit
    def forces(x, vol, seg, frame):
        out = np.zeros_like(x)
        for i in range(x.shape[0]):
            out[i, 0], out[i, 1] = water_force(x[i, 0], x[i, 1], vol[i], seg, frame, 1.0)
        return out
    got = forces(x, vol, wt.segments, wt.frame)
    want = -vol[:, None] * pore_pressure(wt, x)[1]
    assert np.abs(got - want).max() <= 1e-12 * np.abs(want).max()


# ------------------------------------------------------------------ the column
def _cell_means(pts, values):
    cell = np.floor(pts.x0[:, 1] / 0.25).astype(int)
    w = pts.volume0
    return np.bincount(cell, values * w) / np.bincount(cell, w)


def _closed_form(y):
    s_eff = np.where(y >= YW, -G * (H - y), -G * (H - YW) - (GSAT - GW) * (YW - y))
    return s_eff, GW * np.maximum(YW - y, 0.0)


@pytest.mark.parametrize("scheme", ["explicit", "implicit"])
def test_column_with_water_table(meshes, scheme):
    """Column, water table at mid-height (meshes/column_water.toml): the cell means of
    the effective and total vertical stress and of u against the closed form at the cell
    centres (the stresses are linear within each cell, the water table on a cell edge),
    relative L2 over the cells.  Achieved: explicit (damped to rest) sigma' 6.9e-5,
    sigma 5.8e-5, u 5.1e-8 (the points' rest displacement); implicit (one geostatic step)
    2e-14.  Asserts 2e-4 for all.  K0 = nu / (1 - nu) on the effective stress (1e-9)."""
    s = load_scene(meshes / "column_water.toml")
    if scheme == "implicit":
        s = with_values(s, {"solver.scheme": "implicit", "solver.load_steps": 1})
    res = api.run(s)
    pts = res.particles
    u, sig = total_stress(s, pts)
    yc = (np.arange(20) + 0.5) * 0.25
    s_eff, u_ref = _closed_form(yc)
    for got, ref in ((_cell_means(pts, pts.stress[:, 1]), s_eff),
                     (_cell_means(pts, sig[:, 1]), s_eff - u_ref),
                     (_cell_means(pts, u), u_ref)):
        assert np.sqrt(np.sum((got - ref) ** 2) / np.sum(ref ** 2)) < 2e-4
    k0 = _cell_means(pts, pts.stress[:, 0]) / _cell_means(pts, pts.stress[:, 1])
    assert np.abs(k0 / (0.33 / 0.67) - 1).max() < 1e-9
    # the saturated mass below the water table, the dry one above
    below = pts.x0[:, 1] < YW
    rho = pts.mass / pts.volume0
    assert np.allclose(rho[below], GSAT / 9.81) and np.allclose(rho[~below], G / 9.81)


@pytest.mark.parametrize("shape", ["standard", "gimp"])
def test_kernel_step_with_water_equals_numpy_reference(meshes, shape):
    """Ten explicit steps with water (a sloping surface, tilted frame, points moving):
    compiled kernels against the numpy reference step, positions to 1e-12 and stresses to
    1e-11 of their largest (round-off of the regrouped sums: 9.5e-13 seen with uGIMP)."""
    s = with_values(load_scene(meshes / "column_water.toml"),
                    {"scene.frame_angle_deg": 20.0, "solver.shape": shape,
                     "water.phreatic_surface": [[0.0, 2.0], [0.25, 3.0]]})
    grid = make_grid(s)
    wt = water_table(s)
    runs = []
    for kernel in ("numpy", "numba"):
        _, pts = api.prepare(s)
        work = K.Workspace.for_grid(grid, pts.n, wt) if kernel == "numba" else None
        g = np.array(s.gravity_vector)
        for k in range(10):
            explicit_step(grid, pts, 1e-3, 0.5 * g, 0.0, 1.0, shape, False, kernel, work,
                          water=wt)
        runs.append(pts)
    a, b = runs
    assert np.abs(a.x - b.x).max() <= 1e-12 * np.abs(a.x).max()
    assert np.abs(a.stress - b.stress).max() <= 1e-11 * np.abs(a.stress).max()
    assert np.abs(a.stress).max() > 0.1


# ------------------------------------------------------------------ bad input
def _bad_scene(tmp_path, meshes, capsys, edit, *words):
    text = (meshes / "column_water.toml").read_text()
    text = edit(text)
    path = tmp_path / "bad.toml"
    path.write_text(text)
    out = tmp_path / "out"
    code = main(["run", str(path), "--out", str(out), "--quiet"])
    err = capsys.readouterr().err.strip()
    assert code == 2, err
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    for w in words:
        assert w in err, err
    assert not out.exists()


def _sub(pattern, repl):
    return lambda text: re.sub(pattern, repl, text, count=1, flags=re.M)


@pytest.mark.parametrize("edit, words", [
    (_sub(r"^phreatic_surface = .*$", "phreatic_surface = [[0.05, 2.5], [0.25, 2.5]]"),
     ("water.phreatic_surface", "grid's width")),
    (_sub(r"^phreatic_surface = .*$",
          "phreatic_surface = [[0.0, 2.5], [0.2, 2.5], [0.1, 2.6], [0.25, 2.5]]"),
     ("water.phreatic_surface", "folds back")),
    (_sub(r"^phreatic_surface = .*$", "phreatic_surface = [[0.0, 2.5]]"),
     ("water.phreatic_surface", "at least 2 points")),
    (_sub(r"^unit_weight_saturated = .*$", "unit_weight_saturated = 17.0"),
     ("soil[0].unit_weight_saturated", "below unit_weight")),
    (_sub(r"^unit_weight_saturated = .*$", ""),
     ("soil[0].unit_weight_saturated", "drained", "missing")),
    (_sub(r"^pore_pressure = .*$", 'pore_pressure = "artesian"'),
     ("water.pore_pressure", "parallel_seepage")),
    (_sub(r"^model = .*$", 'model = "von_mises_softening"\ndrainage = "drained"\n'
          'cohesion_peak = 10.0\ncohesion_residual = 10.0'),
     ("soil[0].drainage", "undrained")),
    (_sub(r"^unit_weight = 9.81 .*$", "unit_weight = -1.0"), ("water.unit_weight",)),
])
def test_bad_water_input(tmp_path, meshes, capsys, edit, words):
    """Bad [water] input: exit 2, one line naming the key and what is allowed, nothing
    written."""
    _bad_scene(tmp_path, meshes, capsys, edit, *words)


def test_mohr_coulomb_undrained_refused(meshes):
    """Mohr-Coulomb is an effective-stress model: declaring it undrained is an error."""
    from fem_rmpm.scene import SceneError
    s = load_scene(meshes / "infinite_slope_water.toml")
    with pytest.raises(SceneError, match=r"soil\[0\]\.drainage.*'drained'"):
        with_values(s, {"soil[0].drainage": "undrained"})


def test_scene_round_trip_keeps_water(meshes):
    """with_values (through scene_to_dict) keeps [water] and the soil keys."""
    s = load_scene(meshes / "column_water.toml")
    t = with_values(s, {"water.unit_weight": 10.0})
    assert t.water.unit_weight == 10.0
    assert t.water.phreatic_surface == s.water.phreatic_surface
    assert t.soils[0].unit_weight_saturated == 20.0


# ------------------------------------------------------------------ explicit infinite slope
def _wet_infinite_slope(fs: float, case: str, beta=30.0, z=5.0, phi=20.0):
    """The drained infinite slope of tests/test_mohr_coulomb.py (free ends, 6 normal
    thicknesses t long, associated flow) with water: ``"submerged"`` below a horizontal
    free water level 1 m above its highest point, or ``"seepage"`` with a water table
    parallel to the slope at m = 0.5 (parallel seepage).  Its cohesion gives the closed-form
    FS ``fs``: c' / (gamma' z sin b cos b) + tan(phi') / tan(b) submerged, and
    (c' + (W - gamma_w m z) cos^2 b tan phi') / (W sin b cos b) with seepage."""
    b, t = math.radians(beta), z * math.cos(math.radians(beta))
    tphi, sc = math.tan(math.radians(phi)), math.sin(b) * math.cos(b)
    if case == "submerged":
        c = (fs - tphi / math.tan(b)) * (GSAT - GW) * z * sc
        Y = t * math.cos(b) + 1.0
        line = [[0.0, Y / math.cos(b)], [6 * t, (Y + 6 * t * math.sin(b)) / math.cos(b)]]
    else:
        W = 0.5 * (G + GSAT) * z
        c = fs * W * sc - (W - GW * 0.5 * z) * math.cos(b) ** 2 * tphi
        line = [[0.0, 0.5 * t], [6 * t, 0.5 * t]]
    length = 6 * t
    data = {
        "scene": {"name": f"infinite_slope_{case}_fs{fs}", "gravity": 9.81,
                  "frame_angle_deg": beta},
        "grid": {"origin": [0.0, 0.0], "size": [length, t], "cell": [t / 8, t / 8]},
        "boundary": {"left": "free", "right": "free", "bottom": "fixed", "top": "free"},
        "soil": [{"name": "sand", "polygon": [[0, 0], [length, 0], [length, t], [0, t]],
                  "unit_weight": G, "unit_weight_saturated": GSAT, "youngs_modulus": 1e4,
                  "poisson_ratio": 0.3, "model": "mohr_coulomb_softening",
                  "cohesion_peak": c, "cohesion_residual": c, "friction_angle_peak": phi,
                  "friction_angle_residual": phi, "dilation_angle_peak": phi,
                  "dilation_angle_residual": phi}],
        "water": {"phreatic_surface": line, "pore_pressure": "parallel_seepage"},
        "solver": {"scheme": "explicit", "gravity_phase": "dynamic", "gravity_ramp_time": 1.0,
                   "damping": 0.7, "damping_time": 1.0, "t_end": 3.0, "output_interval": 3.0},
        "output": {"vtk": False, "png": False},
    }
    from fem_rmpm.scene import scene_from_dict
    return scene_from_dict(data, f"infinite_slope_{case}.toml")


@pytest.mark.parametrize("case", ["submerged", "seepage"])
@pytest.mark.parametrize("fs, slides", [(1.1, False), (0.9, True)])
def test_wet_infinite_slope_stands_at_1_1_and_slides_at_0_9(case, fs, slides):
    """Explicit MPM with water, as the dry test of tests/test_mohr_coulomb.py: the mean
    down-slope displacement of the middle third of the layer 3 s after gravity (and the
    water force) is ramped on.  Achieved: submerged 0.020 m at 1.1 and 0.487 m at 0.9;
    seepage 0.024 m and 0.923 m (asserts < 0.1 m standing, > 0.3 m sliding)."""
    from fem_rmpm.schemes.explicit.loop import run_explicit
    scene = _wet_infinite_slope(fs, case)
    grid, pts = api.prepare(scene)
    x0 = pts.x.copy()
    run_explicit(scene, grid, pts, progress=False)
    length = scene.grid.size[0]
    mid = (x0[:, 0] > length / 3) & (x0[:, 0] < 2 * length / 3)
    down = float(np.mean(pts.x[mid, 0] - x0[mid, 0]))
    if slides:
        assert down > 0.3, down
    else:
        assert abs(down) < 0.1, down


# ------------------------------------------------------------------ infinite slope with water
def _validation_module():
    import importlib.util
    from pathlib import Path
    path = Path(__file__).parents[1] / "validation" / "water_infinite_slope.py"
    spec = importlib.util.spec_from_file_location("water_infinite_slope", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.mark.parametrize("mode", ["hydrostatic", "parallel_seepage"])
@pytest.mark.parametrize("m", [0.5, 1.0])
def test_infinite_slope_pore_pressure_is_the_closed_forms(mode, m):
    """The u field of validation/water_infinite_slope.py's scenes is the one its closed
    forms assume: u depends on the distance from the bedrock only (grad u normal to the
    slope in the grid frame, so the water's side forces on a slice cancel), zero at the
    water table y = m t, and on the slip plane gamma_w m H (hydrostatic: true-vertical
    depth m H) or gamma_w m H cos^2 b (parallel seepage).  Hydrostatic below a line
    parallel to the slope is horizontal seepage (pressure head = vertical depth), for
    which Duncan, Wright & Brandon (2014, Soil Strength and Slope Stability, 2nd ed.,
    infinite slope with seepage at angle theta: r_u = (gamma_w / gamma) / (1 + tan b tan
    theta), theta = 0) give the same slip-plane u.  Exact to round-off (1e-9 kPa)."""
    w = _validation_module()
    s = w.case_scene(m, mode)
    b = math.radians(w.B)
    t = w.H * math.cos(b)
    L = s.grid.size[0]
    rng = np.random.default_rng(3)
    x = np.column_stack([rng.uniform(0, L, 300), rng.uniform(0, t, 300)])
    u, grad = pore_pressure(water_table(s), x)
    f = 1.0 if mode == "hydrostatic" else math.cos(b) ** 2
    depth = (m * t - x[:, 1]) / math.cos(b)            # true-vertical depth below the table
    assert np.abs(u - GW * f * np.maximum(depth, 0.0)).max() < 1e-9
    wet = depth > 0
    assert np.abs(grad[wet, 0]).max() < 1e-9           # normal to the slope
    assert np.allclose(grad[wet, 1], -GW * f / math.cos(b), rtol=0, atol=1e-9)
    base, _ = pore_pressure(water_table(s), np.array([[L / 2, 0.0]]))
    assert abs(base[0] - GW * f * m * w.H) < 1e-9


def test_davis_estimate_equals_closed_form_for_associated_trials():
    """validation/water_infinite_slope.py's Davis (1968) estimate: the closed form where
    every trial is associated (FS >= 1 with psi = phi: dry, submerged) to 1e-9, and below
    it where FS < 1 keeps psi under the raised phi_F (the hydrostatic table at the ground
    surface: 0.4184 against 0.4770)."""
    w = _validation_module()
    for m, mode in [(0.0, "hydrostatic"), (None, "hydrostatic")]:
        assert abs(w.davis_fs(m, mode) / w.closed_form(m, mode) - 1) < 1e-9
    assert w.davis_fs(1.0, "hydrostatic") == pytest.approx(0.4184, abs=1e-4)
    assert w.closed_form(1.0, "hydrostatic") == pytest.approx(0.4770, abs=1e-4)


@pytest.mark.slow
def test_infinite_slope_water_table_at_surface_fs_strong_soil():
    """Strength reduction of the drained infinite slope with a hydrostatic water table at
    the ground surface (m = 1) and a soil (c' = 30 kPa, phi' = psi = 35 deg) whose FS is
    above 1, so that every trial is associated flow (the closed form's limit load).
    Reference: (c' + (W cos^2 b - gamma_w H_s) tan phi') / (W sin b cos b), W = gamma_sat
    H_s, on the plane where the mesh puts the shear band, half a cell row above the
    bedrock (H_s = H - (h / 2) / cos b: 1.1302 with 20 rows; on the bedrock 1.1124).
    Achieved 1.1295 (-0.06 %; +1.5 % against the bedrock plane); asserts 1 %."""
    w = _validation_module()
    r = w.run_case("h1-strong")
    assert abs(r["band_error"]) < 0.01, r
