"""Rigid rough strip footing on weightless Mohr-Coulomb soil, associated flow (issue 16,
acceptance 2): meshes/bearing_capacity.toml against Prandtl's N_c.

References: Prandtl 1920, Reissner 1924 (q_u = c N_c, N_c = (N_q - 1) cot(phi),
N_q = exp(pi tan phi) tan^2(45 + phi/2), rough or smooth footing on weightless soil);
Hughes 1980 (B-bar: the internal force is the work conjugate of the B-bar strain).
The table and the extrapolation are validation/bearing_capacity.py.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from fem_rmpm.grid import make_grid
from fem_rmpm.implicit import run_implicit
from fem_rmpm.particles import seed_particles
from fem_rmpm.scene import load_scene, with_values

SCENE = Path(__file__).resolve().parents[1] / "meshes" / "bearing_capacity.toml"


def _nc(phi_deg):
    t = math.tan(math.radians(phi_deg))
    return (math.exp(math.pi * t) * math.tan(math.radians(45 + phi_deg / 2)) ** 2 - 1) / t


def _footing(h=None, **changes):
    """q / c per load step and the Newton iterations per step of the footing scene at cell
    size ``h`` (m; default the scene's B/8)."""
    scene = load_scene(SCENE)
    if h is not None:
        changes.update({"grid.cell": h, "grid.size": [8.0, 4.0 + h]})
    scene = with_values(scene, changes) if changes else scene
    grid = make_grid(scene)
    rec = run_implicit(scene, grid, seed_particles(scene, grid))
    st = rec.solver["steps"]
    return (np.array([-s["reactions"]["footing"][1] / 1.0 / 10.0 for s in st]),
            [s["iterations"] for s in st])


def test_prandtl_formula():
    """N_c at phi = 20 deg is the issue's 14.83 (and 5.14 = 2 + pi as phi -> 0)."""
    assert abs(_nc(20.0) - 14.835) < 1e-3
    assert abs(_nc(1e-6) - (2 + math.pi)) < 1e-4


def test_footing_on_c_phi_soil_converges_at_b8():
    """The shipped scene (B/8, 2048 points, 20 small-strain steps to 2.5 % of B): every
    step converges without a cut in <= 15 Newton iterations (the standard-B force stalled
    at a residual of ~1e-5 from q/c ~ 10 at B/16), and the load-settlement curve rises
    monotonically.  At B/8 q/c is 18.59, +25 % above N_c = 14.83: the coarse mesh is stiff
    (it falls to 17.03 at B/16 and 16.11 at B/32, Richardson 14.78: the slow test).  Pinned
    to 0.05 (achieves 18.592) so a change of the discretisation shows."""
    q, its = _footing()
    print("q/c", np.round(q, 3), "iterations", its)
    assert len(q) == 20 and max(its) <= 15
    assert np.all(np.diff(q) > 0)
    assert abs(q[-1] - 18.59) < 0.05


def test_dilatant_flow_does_not_soften_spuriously():
    """B-bar with the force ``sum V0 Bbar^T tau`` (a variational mean-dilatation element):
    on phi = psi = 5 deg soil at B/8 the perfectly plastic footing's load rises
    monotonically, to q/c = 7.59 (+17 % of N_c(5) = 6.49: coarse mesh).  With the standard-B
    force (the B-bar strain but sum V0 B^T tau) the dilatant flow made the same footing
    peak at q/c ~ 6.2 and lose a third of it within 0.5 % of B before Newton stalled: the
    monotone curve and the lower bound N_c fail on that code."""
    ang = {f"soil.{k}_{s}": 5.0 for k in ("friction_angle", "dilation_angle")
           for s in ("peak", "residual")}
    q, _ = _footing(**ang)
    assert len(q) == 20 and np.all(np.diff(q) > 0)
    assert _nc(5.0) < q[-1] < 1.25 * _nc(5.0)


@pytest.mark.slow
def test_footing_on_c_phi_soil_converges_to_prandtl_under_refinement():
    """Issue 16 acceptance 2: q/c at 2.5 % of B on B/8, B/16, B/32 (2048, 8192, 32 768
    points) decreases monotonically (18.59, 17.03, 16.11) and its Richardson extrapolation
    is within 5 % of Prandtl's N_c = 14.83 (achieves 14.78, -0.35 %; observed order 0.76).
    The finest mesh alone is +8.6 %: it is not within 5 % (see README)."""
    nc = _nc(20.0)
    q = [_footing(2.0 / k)[0][-1] for k in (8, 16, 32)]
    r = (q[1] - q[2]) / (q[0] - q[1])
    q_inf = q[2] - (q[1] - q[2]) * r / (1 - r)
    print("q/c", q, "Richardson", q_inf, f"{q_inf / nc - 1:+.2%}")
    assert q[0] > q[1] > q[2] > nc
    assert abs(q_inf / nc - 1) < 0.05
