"""The strength-reduction rule for the dilation angle (``fem_rmpm.materials.strength``).

A soil declared associated (psi = phi) stays associated at every trial F, also below 1
where the reduced friction angle grows; a non-associated soil's psi is capped at the
reduced friction angle.  Reference: the rule in the module docstring; a capped psi below
F = 1 makes an associated soil non-associated, which collapses at a lower load (Davis
1968), so the FS of an associated layer with FS < 1 would fall below its closed form."""
from __future__ import annotations

import numpy as np
import pytest

from fem_rmpm.materials import registry, strength

KEY = "mohr_coulomb_softening"


def _rows(psi: float, phi: float = 26.0) -> np.ndarray:
    cols = {s.name: registry.column(KEY, s.name) for s in strength.strengths(KEY)}
    p = np.zeros((1, max(cols.values()) + 1))
    for name, v in (("cohesion_peak", 8.0), ("cohesion_residual", 8.0),
                    ("friction_angle_peak", phi), ("friction_angle_residual", phi),
                    ("dilation_angle_peak", psi), ("dilation_angle_residual", psi)):
        p[0, cols[name]] = v
    return p


def _angle(p: np.ndarray, name: str) -> float:
    return float(p[0, registry.column(KEY, name)])


@pytest.mark.parametrize("F", [0.4, 0.8, 1.0, 1.5, 3.0])
@pytest.mark.parametrize("softening", [True, False])
def test_associated_soil_stays_associated_at_every_trial(F, softening):
    p = strength.reduce_strength(KEY, _rows(psi=26.0), F, softening)
    phi_F = np.degrees(np.arctan(np.tan(np.radians(26.0)) / F))
    for stage in ("peak", "residual"):
        assert _angle(p, f"friction_angle_{stage}") == pytest.approx(phi_F, abs=1e-12)
        assert _angle(p, f"dilation_angle_{stage}") == _angle(p, f"friction_angle_{stage}")


@pytest.mark.parametrize("F, expected", [(0.5, 10.0), (1.0, 10.0), (4.0, None)])
def test_non_associated_dilation_is_capped_not_scaled(F, expected):
    p = strength.reduce_strength(KEY, _rows(psi=10.0), F, softening=False)
    phi_F = _angle(p, "friction_angle_peak")
    want = expected if expected is not None else phi_F       # F = 4: phi_F 6.9 deg < 10
    assert phi_F < 10.0 or expected == 10.0
    assert _angle(p, "dilation_angle_peak") == pytest.approx(want, abs=1e-12)
