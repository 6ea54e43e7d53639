"""The random-field model written out term by term, so that each term is checked (mutation
testing: `validation/mutation.py random_field`).  References: the Markov correlation
rho = exp(-2 r) with the elliptic r = sqrt((p/theta_h)^2 + (q/theta_v)^2) or separable
r = |p|/theta_h + |q|/theta_v of the lag rotated into the layering (Fenton & Griffiths 2008,
ch. 3); Vanmarcke's (1983) variance function g(T) = 2 (x + e^-x - 1) / x^2, x = 2T/theta,
whose series is 1 - x/3 + x^2/12; the normal and lognormal marginal transforms.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from fem_rmpm import random_field as rf
from fem_rmpm.random_field.model import MarkovModel, property_to_gaussian, variance_function
from fem_rmpm.scene import scene_from_dict


def _spec(**field):
    data = {"scene": {"name": "m"}, "grid": {"origin": [0.0, 0.0], "size": [4.0, 2.0],
                                             "cell": [0.25, 0.25]},
            "soil": [{"name": "clay", "polygon": [[0, 0], [4, 0], [4, 2], [0, 2]],
                      "unit_weight": 20.0, "youngs_modulus": 1000.0, "poisson_ratio": 0.3,
                      "model": "von_mises_softening", "cohesion_peak": 20.0,
                      "cohesion_residual": 4.0, "softening_strain": 0.5}],
            "random_field": {"cov": 0.3, "theta_v": 0.5, **field}}
    return scene_from_dict(data, "<dict>")


@pytest.mark.parametrize("kind", ["markov_elliptic", "markov_separable"])
def test_correlation_of_a_rotated_anisotropic_lag(kind):
    """rho(dx, dy) at a lag rotated by 30 degrees into the layering, against the formula."""
    m = MarkovModel(3.0, 0.5, 30.0, kind)
    dx, dy = np.array([0.7, -1.2, 0.0]), np.array([0.2, 0.4, -0.3])
    a = math.radians(30.0)
    p = (math.cos(a) * dx + math.sin(a) * dy) / 3.0
    q = (-math.sin(a) * dx + math.cos(a) * dy) / 0.5
    r = np.hypot(p, q) if kind == "markov_elliptic" else np.abs(p) + np.abs(q)
    np.testing.assert_allclose(m.correlation(dx, dy), np.exp(-2.0 * r), rtol=1e-14)
    np.testing.assert_allclose(m.correlation([1, 0], [0, 1]),          # integer lags
                               m.correlation([1.0, 0.0], [0.0, 1.0]), rtol=0)


def test_extent_is_the_half_width_of_the_rotated_ellipse():
    """extent(): the x and y half-widths of the ellipse (p/theta_h)^2 + (q/theta_v)^2 = 1."""
    m = MarkovModel(3.0, 0.5, 30.0)
    t = np.linspace(0, 2 * np.pi, 200_001)
    a = math.radians(30.0)
    p, q = 3.0 * np.cos(t), 0.5 * np.sin(t)
    x, y = math.cos(a) * p - math.sin(a) * q, math.sin(a) * p + math.cos(a) * q
    np.testing.assert_allclose(m.extent(), [x.max(), y.max()], rtol=1e-9)


@pytest.mark.parametrize("bad", [dict(theta_h=0.0), dict(theta_v=0.0), dict(theta_h=-1.0),
                                 dict(theta_v=math.inf), dict(theta_h=math.inf),
                                 dict(kind="gaussian")])
def test_model_rejects_bad_parameters_with_a_message(bad):
    kw = {"theta_h": 2.0, "theta_v": 0.5, **bad}
    with pytest.raises(ValueError, match="theta_h=|kind must be one of"):
        MarkovModel(**kw)


def test_variance_function_near_zero_and_model_from_spec():
    """g(T) follows its series 1 - x/3 + x^2/12 for tiny T (the branch that avoids 0/0) and
    the closed form elsewhere; the scene's correlation kind and angle reach the model."""
    for T in (1e-12, 1e-8, 1e-7):
        x = 2 * T / 0.5
        assert abs(float(variance_function(T, 0.5)) - (1 - x / 3 + x * x / 12)) < 1e-13
    T = 0.3
    x = 2 * T / 0.5
    assert float(variance_function(T, 0.5)) == pytest.approx(2 * (x + math.exp(-x) - 1) / x ** 2,
                                                             rel=1e-14)
    m = rf.model_from_spec(_spec(correlation="markov_separable", anisotropy=6.0,
                                 layering_angle_deg=15.0).random_field)
    assert (m.kind, m.theta_h, m.theta_v, m.angle_deg) == ("markov_separable", 3.0, 0.5, 15.0)


@pytest.mark.parametrize("dist", ["normal", "lognormal"])
def test_marginal_transform_and_its_inverse(dist):
    """normal: mean (1 + cov z); lognormal: mean exp(s z - s^2/2), s^2 = ln(1 + cov^2); the
    inverse undoes it (to 1e-13)."""
    spec = _spec(distribution=dist).random_field
    z = np.array([-2.0, -0.3, 0.0, 0.7, 1.9])
    v = rf.gaussian_to_property(z, 20.0, spec)
    s2 = math.log(1 + 0.3 ** 2)
    expect = 20.0 * (1 + 0.3 * z) if dist == "normal" else 20.0 * np.exp(math.sqrt(s2) * z - s2 / 2)
    np.testing.assert_allclose(v, expect, rtol=1e-14)
    np.testing.assert_allclose(property_to_gaussian(v, 20.0, spec), z, atol=1e-13)


def test_embedding_rejects_empty_fields_and_takes_one_cell_wide_ones():
    """A field needs >= 1 cell of positive size; a one-cell-wide field is a 1-D field whose
    variance is the local-average variance (averaging on by default)."""
    m = MarkovModel(1.0, 0.5)
    for shape, cell in (((0, 5), (0.25, 0.25)), ((5, 0), (0.25, 0.25)),
                        ((5, 5), (0.0, 0.25)), ((5, 5), (0.25, -0.1))):
        with pytest.raises(ValueError, match="needs >= 1 cell of positive size"):
            rf.circulant_embedding(m, cell, shape)
    emb = rf.circulant_embedding(m, (0.25, 0.25), (1, 8))
    dense = rf.dense_covariance(m, (0.25, 0.25), (1, 8))
    point = rf.dense_covariance(m, (0.25, 0.25), (1, 8), False)
    assert emb.variance == pytest.approx(dense[0, 0], rel=1e-12) and dense[0, 0] < 0.95
    assert point[0, 0] == pytest.approx(1.0, rel=1e-14, abs=0)
