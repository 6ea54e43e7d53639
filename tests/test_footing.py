"""Rigid strip footing on von Mises soil, displacement controlled, implicit.

References: Prandtl 1920 (limit pressure (2 + pi) c of a strip footing on weightless
phi = 0 soil; Hill 1950 for the rough footing, same value); Nagtegaal, Parks & Rice 1974
(locking of isochoric plastic flow); de Souza Neto et al. 1996 (F-bar, the remedy);
Von Mises yield (sqrt(J2) <= c: the plane-strain shear strength is c).
"""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from fem_rmpm import api
from fem_rmpm.discretise.grid import make_grid
from fem_rmpm.scene import SceneError, load_scene, with_values
from fem_rmpm.schemes.implicit import prescribed_nodes

MESHES = Path(__file__).resolve().parents[1] / "meshes"
PRANDTL = 2.0 + math.pi


def _pressures(summary_steps, half_width=1.0, c=10.0):
    """Footing pressure / c per load step from the recorded reactions (half model)."""
    return np.array([-s["reactions"]["footing"][1] / half_width / c for s in summary_steps])


def _footing(tmp_path, **changes):
    scene = with_values(load_scene(MESHES / "footing.toml"), changes) if changes else \
        load_scene(MESHES / "footing.toml")
    res = api.run(scene, out=tmp_path)
    steps = json.loads((tmp_path / "summary.json").read_text())["solver"]["steps"]
    return _pressures(steps), res


def test_strip_footing_reaches_prandtl_with_fbar(tmp_path):
    """Prandtl's limit (meshes/footing.toml: rough rigid footing, B = 2 m, half model,
    c = 10 kPa, E = 3000 kPa, nu = 0.49, F-bar, B/32 cells, 12 small-strain steps to a
    settlement of 3 % of B): the pressure levels off (last two steps within 0.2 %) at a
    limit within 5 % of Prandtl's (2 + pi) c = 5.14 c.  The reactions are in summary.json
    for every step, and every Newton step converged.  The +2.75 % achieved at B/32 is the
    discretisation error (it halves with h, docs/validation/footing.md); that page's 5.28
    is asserted to its rounding (achieves 5.2829), so the table cannot drift."""
    q, res = _footing(tmp_path)
    print(f"q_u / c = {q[-1]:.4f} (Prandtl {PRANDTL:.4f}, {q[-1] / PRANDTL - 1:+.2%})", q)
    assert res.record.stop_reason == "load applied" and len(q) == 12
    assert abs(q[-1] / q[-2] - 1) < 2e-3
    assert abs(q[-1] / PRANDTL - 1) < 0.05
    assert abs(q[-1] - 5.28) < 0.005
    assert np.all(np.diff(q) > -1e-6)                  # monotone load-settlement curve


def test_strip_footing_overshoots_without_fbar(tmp_path):
    """Without the remedy the Q4 mesh locks under isochoric von Mises flow: at the same
    settlement the pressure is more than 15 % above Prandtl's and still rising (no limit
    load), while F-bar has levelled off (previous test).  docs/validation/footing.md: 6.69
    (+30 %) at B/32, asserted to its rounding (achieves 6.6924, last increase +0.91 %)."""
    q, _ = _footing(tmp_path, **{"solver.fbar": False})
    print(f"without F-bar: q / c = {q[-1]:.4f} ({q[-1] / PRANDTL - 1:+.1%}), last increase "
          f"{q[-1] / q[-2] - 1:+.2%}")
    assert q[-1] > 1.15 * PRANDTL and abs(q[-1] - 6.69) < 0.005
    assert q[-1] / q[-2] - 1 > 5e-3


def test_prescribed_regions_are_validated(tmp_path):
    """A [[prescribed]] region needs implicit load steps (explicit or Newmark: a clear
    SceneError naming the key) and must hold grid nodes; its components are "xy" | "x" | "y"."""
    scene = load_scene(MESHES / "footing.toml")
    for change in ({"solver.scheme": "explicit"}, {"solver.dynamic": True}):
        with pytest.raises(SceneError, match=r"\[prescribed\[0\]\].*implicit"):
            with_values(scene, change)
    with pytest.raises(SceneError, match="prescribed.components"):
        with_values(scene, {"prescribed.components": "z"})
    empty = with_values(scene, {"prescribed.polygon": [[0.01, 0.01], [0.02, 0.01], [0.02, 0.02]]})
    with pytest.raises(SceneError, match="holds no grid node"):
        prescribed_nodes(empty, make_grid(empty))
    regions = prescribed_nodes(scene, make_grid(scene))
    assert len(regions) == 1 and len(regions[0]["nodes"]) == 17        # B/2 = 16 cells
    assert regions[0]["mask"][regions[0]["nodes"]].all()
