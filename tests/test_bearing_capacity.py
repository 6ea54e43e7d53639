"""Rigid rough strip footing on weightless Mohr-Coulomb soil, associated flow:
meshes/bearing_capacity.toml against Prandtl's N_c.

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

from fem_rmpm.discretise.grid import make_grid
from fem_rmpm.discretise.points import seed_particles
from fem_rmpm.scene import load_scene, with_values
from fem_rmpm.schemes.implicit import run_implicit

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
    """N_c at phi = 20 deg is 14.83 (and 5.14 = 2 + pi as phi -> 0)."""
    assert abs(_nc(20.0) - 14.835) < 1e-3
    assert abs(_nc(1e-6) - (2 + math.pi)) < 1e-4


VOLUME = {"solver.locking_constraint": "volume"}     # B-bar: one volume change per cell


def test_footing_on_c_phi_soil_converges_at_b8():
    """The shipped scene with B-bar (one volume change per cell; B/8, 2048 points, 20
    small-strain steps to 2.5 % of B): every step converges without a cut in <= 15 Newton
    iterations (the standard-B force stalled at a residual of ~1e-5 from q/c ~ 10 at
    B/16), and the load-settlement curve rises monotonically and does not level off
    (dilatancy locking, see the next test).  At B/8 q/c is 18.59, +25 % above N_c =
    14.83 (it falls to 17.03 at B/16 and 16.11 at B/32, Richardson 14.78: the slow test).
    Pinned to 0.05 (achieves 18.592) so a change of the discretisation shows."""
    q, its = _footing(**VOLUME)
    print("q/c", np.round(q, 3), "iterations", its)
    assert len(q) == 20 and max(its) <= 15
    assert np.all(np.diff(q) > 0)
    assert abs(q[-1] - 18.59) < 0.05


def test_one_pressure_per_cell_levels_off_at_b8():
    """The shipped scene (``locking_constraint = "pressure"``: one in-plane mean stress per
    cell, each point its own volume change) at B/8: the load-settlement curve levels off
    (a limit load): q/c 16.179, 16.187, 16.189, 16.189 at the quarters of 2.5 % of B, a
    rise of 0.002 % over the last quarter (asserts < 0.05 %; B-bar on the same mesh: +1.2 %
    and rising, 18.59), and q/c = 16.19 is +9.1 % above N_c, the same mesh error as the
    Tresca soil's +9.8 % on this mesh (5.645 against 2 + pi; B-bar gives the same 5.645
    there: without dilatancy the two constraints agree).  Pinned to 0.03."""
    q, its = _footing()
    print("q/c", np.round(q, 4), "iterations", its)
    assert len(q) == 20 and max(its) <= 15
    assert q[-1] / q[14] - 1 < 5e-4
    assert abs(q[-1] - 16.19) < 0.03


def test_dilatant_flow_does_not_soften_spuriously():
    """B-bar with the force ``sum V0 Bbar^T tau`` (a variational mean-dilatation element):
    on phi = psi = 5 deg soil at B/8 the perfectly plastic footing's load rises
    monotonically, to q/c = 7.59 (+17 % of N_c(5) = 6.49: coarse mesh).  With the standard-B
    force (the B-bar strain but sum V0 B^T tau) the dilatant flow made the same footing
    peak at q/c ~ 6.2 and lose a third of it within 0.5 % of B before Newton stalled: the
    monotone curve and the lower bound N_c fail on that code."""
    ang = {f"soil.{k}_{s}": 5.0 for k in ("friction_angle", "dilation_angle")
           for s in ("peak", "residual")}
    q, _ = _footing(**ang, **VOLUME)
    assert len(q) == 20 and np.all(np.diff(q) > 0)
    assert _nc(5.0) < q[-1] < 1.25 * _nc(5.0)


@pytest.mark.slow
def test_footing_with_bbar_extrapolates_to_prandtl_under_refinement():
    """Prandtl's N_c with B-bar (one volume change per cell): q/c at 2.5 % of B on B/8, B/16,
    B/32 (2048, 8192, 32 768 points) decreases monotonically (18.59, 17.03, 16.11) and its
    Richardson extrapolation is within 5 % of Prandtl's N_c = 14.83 (achieves 14.78, -0.35 %;
    observed order 0.76).
    The finest mesh alone is +8.6 %: it is not within 5 % (docs/validation/footing.md)."""
    nc = _nc(20.0)
    q = [_footing(2.0 / k, **VOLUME)[0][-1] for k in (8, 16, 32)]
    r = (q[1] - q[2]) / (q[0] - q[1])
    q_inf = q[2] - (q[1] - q[2]) * r / (1 - r)
    print("q/c", q, "Richardson", q_inf, f"{q_inf / nc - 1:+.2%}")
    assert q[0] > q[1] > q[2] > nc
    assert abs(q_inf / nc - 1) < 0.05


@pytest.mark.slow
def test_footing_with_one_pressure_per_cell_is_within_5_percent_under_refinement():
    """Prandtl's N_c, the shipped scene (one in-plane mean stress per cell): on B/8,
    B/16, B/32 every load-settlement curve levels off (rise over the last quarter of 2.5 %
    of B achieves 0.002 %, 0.004 %, 0.001 %; asserts < 0.05 %), q/c decreases
    monotonically (16.19, 15.57, 15.23: +9.1 %, +4.95 %, +2.6 % from N_c = 14.83) and is
    within 5 % from B/16 on (asserts B/32 within 3.5 %, B/16 within 5 %).  Richardson:
    14.80 (-0.3 %), observed order 0.85.  About 170 s CPU."""
    nc = _nc(20.0)
    runs = [_footing(2.0 / k)[0] for k in (8, 16, 32)]
    q = [r[-1] for r in runs]
    print("q/c", q, [f"{v / nc - 1:+.2%}" for v in q])
    assert all(r[-1] / r[14] - 1 < 5e-4 for r in runs)
    assert q[0] > q[1] > q[2] > nc
    assert q[1] / nc - 1 < 0.05 and q[2] / nc - 1 < 0.035


def test_large_deformation_fbar_follows_small_strain_at_small_settlement():
    """The large-deformation load step with F-bar (``gravity_phase = "dynamic"``: updated
    Lagrangian, Hencky) on the same footing agrees with the small-strain B-bar step while
    the settlement is small: q/c 15.947 against 15.976 at 0.25 % of B (asserts 1 %), and
    all 20 steps converge (the finite-strain curve then levels at 17.48 against B-bar's
    18.59 and rising).  With the F-bar force ``sum V0 tau(F_bar) grad_x N`` (not the
    derivative of the F-bar work) the dilatant flow softened spuriously, as the standard-B
    force did at small strain: q/c 11.3 and Newton failed at the second step."""
    q_fs, its = _footing(**{"solver.gravity_phase": "dynamic"})
    q_ss, _ = _footing(**VOLUME)
    print("finite strain", np.round(q_fs, 3), "small strain", np.round(q_ss, 3))
    assert len(q_fs) == 20 and max(its) <= 15
    assert abs(q_fs[1] / q_ss[1] - 1) < 0.01
    assert q_fs[-1] > 0.9 * q_ss[-1]
