"""Frictional contact with bedrock (:mod:`fem_rmpm.discretise.contact`,
:mod:`fem_rmpm.schemes.contact`): the sliding block, the dropped block, the geometry of the
contact nodes, the compiled rule against the numpy reference, and bad input.

Reference for the sliding block: Newton's second law for a rigid block on a plane at angle
beta with Coulomb friction mu (e.g. Bardenhagen et al. 2001, the inclined-plane benchmark of
MPM contact): a = g (sin beta - mu cos beta) while mu < tan beta, no motion otherwise.  The
scenes ramp gravity on over t_r = 0.25 s (meshes/sliding_block.toml says why), so
d(t) = a (t_r^2 / 6 + t_r (t - t_r) / 2 + (t - t_r)^2 / 2), which is 1/2 a t^2 for t_r -> 0;
the test takes d at the end of 1 s of sliding after the ramp.  Measured errors: aligned grid
mu 0 / 0.2 / 0.4: +0.11 / +0.09 / -0.36 %; plane at 30 deg to the grid: +0.11 / +0.14 /
+0.13 %; mu = 0.6 >= tan 30: 0.43 mm (aligned) and 0.82 mm (inclined) in 2 s.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from fem_rmpm import api
from fem_rmpm.cli import main
from fem_rmpm.discretise.contact import outward_edges
from fem_rmpm.scene import SceneError, with_values

ROOT = Path(__file__).resolve().parents[1]
MESHES = ROOT / "meshes"
BETA = math.radians(30.0)
G = 9.81
RAMP = 0.25


def _block(name: str, mu: float, **solver):
    scene = api.load_scene(str(MESHES / name))
    changes = {"bedrock[0].friction": mu, "solver.threads": 1}
    changes.update({f"solver.{k}": v for k, v in solver.items()})
    return with_values(scene, changes)


def _down_plane(scene) -> np.ndarray:
    """Unit vector down the plane in the grid frame."""
    if scene.scene.frame_angle_deg == 0.0:
        return np.array([math.cos(BETA), -math.sin(BETA)])
    return np.array([1.0, 0.0])


def _closed_form(mu: float, t: float) -> float:
    a = G * max(0.0, math.sin(BETA) - mu * math.cos(BETA))
    return a * (RAMP ** 2 / 6 + RAMP * (t - RAMP) / 2 + (t - RAMP) ** 2 / 2)


def _slide(name: str, mu: float, **solver) -> tuple[float, float, object]:
    res = api.run(_block(name, mu, **solver))
    d = float(((res.particles.x - res.particles.x0) @ _down_plane(res.scene)).mean())
    return d, res.record.time, res


PLANES = ["sliding_block.toml", "sliding_block_inclined_grid.toml"]


@pytest.mark.parametrize("name", PLANES)
@pytest.mark.parametrize("mu, tol", [(0.0, 0.01), (0.2, 0.02), (0.4, 0.02)])
def test_sliding_block_follows_coulomb(name, mu, tol):
    """Displacement down the plane after 1 s of sliding within 2 % (mu 0.2, 0.4) and 1 %
    (mu = 0) of the closed form, for the plane along the grid and at 30 deg to it."""
    d, t, res = _slide(name, mu)
    ref = _closed_form(mu, t)
    assert t == pytest.approx(RAMP + 1.0)
    assert abs(d - ref) <= tol * ref, (
        f"{name}, mu = {mu}: block slid {d:.4f} m in {t:.3f} s, closed form {ref:.4f} m "
        f"({100 * (d / ref - 1):+.2f} %, allowed {100 * tol:g} %)")


@pytest.mark.parametrize("name", PLANES)
def test_sliding_block_sticks_at_or_above_tan_beta(name):
    """mu = 0.6 >= tan 30 = 0.577: the block moves less than 1 mm in 2 s."""
    d, t, res = _slide(name, 0.6, t_end=2.0)
    assert t == pytest.approx(2.0)
    assert abs(d) < 1e-3, f"{name}: a block at mu = 0.6 moved {1000 * d:.2f} mm in 2 s"


def test_frictional_dissipation_is_coulomb_work():
    """The recorded dissipation of the aligned block at mu = 0.2 is the work of the Coulomb
    force mu N over the slip: mu m g cos(beta) (d(t) - a t_r^2 / 24) with the ramp
    (N grows with it), within 2 % (measured 0.2 %)."""
    d, t, res = _slide("sliding_block.toml", 0.2)
    mass = float(res.particles.mass.sum())
    a = G * (math.sin(BETA) - 0.2 * math.cos(BETA))
    ref = 0.2 * mass * G * math.cos(BETA) * (_closed_form(0.2, t) - a * RAMP ** 2 / 24)
    got = res.record.friction[-1][1]
    assert res.summary["friction_dissipation"][-1][1] == got
    assert abs(got - ref) <= 0.02 * ref, f"dissipation {got:.4f} kJ/m, Coulomb work {ref:.4f}"


def test_dropped_block_bounces_and_does_not_penetrate():
    """A block falling 0.5 m onto a frictional floor lifts off again after the impact (the
    contact carries no tension: its lowest points rise more than half a cell above where
    they turned) and its lower edge (lowest point less a quarter cell, 2 points per cell)
    never sinks more than a tenth of a cell below the floor.  Measured: the block turns
    with its lower edge 0.065 m above the floor (the nodal contact acts once the points
    enter the cells on the surface) and rises 0.29 m."""
    scene = with_values(api.load_scene(str(MESHES / "dropped_block.toml")),
                        {"solver.threads": 1})
    res = api.run(scene)
    h, floor = 0.1, 0.3
    low = np.array([x[:, 1].min() - h / 4 for _, x, _ in res.snapshots])   # lower edge
    times = np.array([t for t, _, _ in res.snapshots])
    turn = int(np.argmin(low))
    assert low[0] - low[turn] > 0.3, "the block did not fall onto the floor"
    assert low[turn] >= floor - 0.1 * h, (
        f"the block sank {1000 * (floor - low[turn]):.1f} mm into the floor at "
        f"t = {times[turn]:.3f} s (allowed a tenth of a cell, 10 mm)")
    rise = low[turn:].max() - low[turn]
    assert rise > 0.5 * h, (
        f"the block did not lift off after the impact at t = {times[turn]:.3f} s: its "
        f"lowest points rose {1000 * rise:.1f} mm (needed more than half a cell)")


def test_normals_come_from_the_polygon():
    """Inclined plane: every contact node's normal is the plane's (sin 30, cos 30), not a
    staircase direction; the rock's edges on the grid's sides are not contact surfaces."""
    grid = api.prepare(_block("sliding_block_inclined_grid.toml", 0.2))[0]
    n = grid.contact.normal
    np.testing.assert_allclose(n, np.tile([0.5, math.sqrt(3) / 2], (len(n), 1)), atol=1e-12)
    a, b, nn = outward_edges(np.array([[0, 0], [5, 0], [0, 2.886751]]), np.zeros(2),
                             np.array([5.0, 3.8]), 1e-9)
    assert len(a) == 1 and nn[0] @ [0.5, math.sqrt(3) / 2] == pytest.approx(1.0)
    assert not grid.fixed[grid.contact.node].any()


def test_compiled_rule_agrees_with_numpy_reference():
    """Thirty steps of the inclined block (contact nodes stick and slip) with the compiled
    kernels and with the numpy reference step: positions within 1e-10 m, dissipation within
    1e-9 relative."""
    out = {}
    for kernel in ("numba", "numpy"):
        scene = _block("sliding_block_inclined_grid.toml", 0.4, kernel=kernel, t_end=0.3,
                       gravity_ramp_time=0.0)
        res = api.run(scene)
        out[kernel] = (res.particles.x.copy(), res.record.friction[-1][1], res.record.steps)
    assert out["numba"][2] == out["numpy"][2]
    np.testing.assert_allclose(out["numba"][0], out["numpy"][0], rtol=0, atol=1e-10)
    assert out["numba"][1] == pytest.approx(out["numpy"][1], rel=1e-9)


#: The block as a von Mises soil too strong to yield: it slides as the elastic block does,
#: on the step kernels of the von Mises runs (``tests/test_advance.py``), so that the
#: two-thread check below compiles no kernel of its own.
STRONG_VON_MISES = {"soil.model": "von_mises_softening", "soil.cohesion_peak": 1.0e4,
                    "soil.cohesion_residual": 1.0e4, "soil.softening_strain": 0.5}


def test_two_threads_bitwise_one():
    """The contact path keeps the 1 = 2 threads rule (bitwise); the block never yields."""
    xs = []
    for threads in (1, 2):
        scene = with_values(_block("sliding_block.toml", 0.4),
                            {"solver.threads": threads, "solver.t_end": 0.3,
                             **STRONG_VON_MISES})
        res = api.run(scene)
        assert not (res.particles.plastic_shear_strain > 0).any()
        xs.append((res.particles.x.copy(), res.record.friction[-1][1]))
    assert np.array_equal(xs[0][0], xs[1][0]) and xs[0][1] == xs[1][1]


@pytest.mark.parametrize("extra, key", [
    ({"bedrock[0].friction": -0.1}, "bedrock[0].friction"),
    ({"bedrock[0].interface": "rough"}, "bedrock[0].friction"),
    ({"bedrock[0].friction": None}, "bedrock[0].friction"),
    ({"bedrock[0].interface": "sticky"}, "bedrock[0].interface"),
    ({"solver.scheme": "implicit"}, "bedrock[0].interface"),
])
def test_bad_interface_input_is_one_line(extra, key):
    scene = api.load_scene(str(MESHES / "sliding_block.toml"))
    with pytest.raises(SceneError) as exc:
        with_values(scene, extra)
    msg = str(exc.value)
    field = key.split(".")[-1]
    assert ("[bedrock" in msg and f".{field}]" in msg and "\n" not in msg
            and "allowed" in msg), msg


def test_adhesion_on_a_rough_bedrock_is_refused():
    scene = api.load_scene(str(MESHES / "slope_reference.toml"))
    with pytest.raises(SceneError, match=r"\[bedrock\[0\]\.adhesion\] a rough bedrock"):
        with_values(scene, {"bedrock[0].adhesion": 5.0})


def test_cli_bad_friction_exit_2_one_line(tmp_path, capsys):
    """Through the command line (its ``main``, in this process): exit 2, one line, nothing
    written."""
    out = tmp_path / "run"
    code = main(["run", str(MESHES / "sliding_block.toml"), "--set",
                 "bedrock[0].friction=-0.2", "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 2
    assert len(err.strip().splitlines()) == 1 and "friction" in err
    assert "Traceback" not in err
    assert not out.exists()


def test_strength_reduction_refuses_frictional_bedrock():
    scene = api.load_scene(str(MESHES / "sliding_block.toml"))
    with pytest.raises(SceneError, match="strength reduction"):
        api.factor_of_safety(scene)


def test_frictional_bedrock_in_a_3d_scene_exits_2(capsys, tmp_path):
    """The 3-D scheme fixes its bedrock nodes (rough): a frictional interface there is
    refused, not ignored."""
    from fem_rmpm.cli import main
    text = (Path(__file__).parents[1] / "meshes" / "slope_extruded_3d.toml").read_text()
    assert "[[bedrock]]" in text
    text = text.replace("[[bedrock]]", '[[bedrock]]\ninterface = "frictional"\nfriction = 0.4', 1)
    (tmp_path / "s.toml").write_text(text)
    out = tmp_path / "out"
    code = main(["run", str(tmp_path / "s.toml"), "--out", str(out), "--quiet"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and "Traceback" not in err, err
    assert "bedrock[0].interface" in err and not out.exists()
