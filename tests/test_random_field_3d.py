"""3-D random fields: the covariance of local averages over hexahedral cells, the exact
circulant embedding, the box rule, cross-correlated properties, the memory estimate and
the refusals.

References: the closed form of the separable Markov model (product of Vanmarcke's 1-D
local-average covariances, Vanmarcke 1983 ch. 5); the 2-D local-average covariance of
:mod:`fem_rmpm.random_field.quadrature` (checked against ``scipy.integrate.nquad`` in
``tests/test_random_field.py``) as the limit ``theta_z -> infinity`` of the 3-D elliptic
model (the two models differ by at most ``2 h_z / theta_z`` = 1e-9 there); the dense
definition of the circulant's covariance (inverse FFT of its spectrum).
"""
from __future__ import annotations

import math
import tracemalloc

import numpy as np
import pytest
import scipy.fft as sfft

from fem_rmpm.random_field.embedding3d import (
    SingleVariable3D,
    circulant_embedding_3d,
    estimate_embedding_3d,
)
from fem_rmpm.random_field.field3d import (
    cell_weights_3d,
    embeddings_3d,
    field_lattice_3d,
    gaussian_fields_3d,
    sample_cell_field_3d,
    sample_point_field_3d,
    subset_noise_3d,
)
from fem_rmpm.random_field.memory import ByteBoundedCache
from fem_rmpm.random_field.model import MarkovModel, local_average_covariance_1d
from fem_rmpm.random_field.model3d import MarkovModel3D, model_from_spec_3d
from fem_rmpm.random_field.quadrature import lattice_covariance
from fem_rmpm.random_field.quadrature3d import lattice_covariance_3d, quadrature_error_3d
from fem_rmpm.scene import RandomFieldSpec, SceneError
from fem_rmpm.scene.spec import PropertyFieldSpec

LAGS = np.meshgrid(np.arange(-3, 4), np.arange(-3, 4), np.arange(-3, 4), indexing="ij")


@pytest.mark.parametrize("theta,cell", [((1.0, 1.0, 1.0), (0.5, 0.5, 0.5)),
                                        ((12.0, 0.5, 12.0), (0.25, 0.25, 1.0)),
                                        ((0.3, 0.3, 0.3), (0.5, 0.5, 0.5))])
def test_quadrature_reproduces_the_closed_form_of_the_separable_model(theta, cell):
    """The tensor quadrature (forced) against the product of the 1-D closed forms on the
    343 lags |K| <= 3: agreement to 1e-9 (measured 3.3e-10 at most, for theta = 0.6 cells)."""
    m = MarkovModel3D(*theta, kind="markov_separable")
    quad = lattice_covariance_3d(m, cell, *LAGS, method="quadrature")
    closed = lattice_covariance_3d(m, cell, *LAGS, method="closed")
    assert np.abs(quad - closed).max() < 1e-9


@pytest.mark.parametrize("th,tv,angle,cell,tol", [
    (1.0, 1.0, 0.0, (0.5, 0.5, 0.5), 1e-6), (12.0, 0.5, 0.0, (0.25, 0.25, 1.0), 1e-6),
    (48.0, 0.5, 0.0, (0.25, 0.25, 0.5), 1e-6), (6.0, 0.5, 20.0, (0.25, 0.25, 0.5), 1e-4)])
def test_elliptic_quadrature_tends_to_the_2d_result_for_a_long_strike_scale(th, tv, angle,
                                                                             cell, tol):
    """theta_z = 1e9 m: the 3-D cell averages at M = 0 equal the 2-D ones of the section
    within 1e-6 (measured 6e-9, 1.9e-7 and 4e-8: the near-kink of strong anisotropy); a
    layering turned 20 deg against xi = 12 within 1e-4 (measured 2.0e-5: the graded axes do
    not follow the turned near-kink plane)."""
    m3 = MarkovModel3D(th, tv, 1e9, angle_deg=angle)
    K, L = LAGS[0][..., 0], LAGS[1][..., 0]
    c3 = lattice_covariance_3d(m3, cell, K, L, 0 * K)
    c2 = lattice_covariance(MarkovModel(th, tv, angle), cell[:2], K, L)
    assert np.abs(c3 - c2).max() < tol


def test_separable_model_with_turned_layering_is_the_section_times_the_strike_term():
    """The strike factor of the separable model separates: C3(K, L, M) = C2(K, L) C1(M)
    with the 2-D fan quadrature and Vanmarcke's 1-D term (to round-off); the tensor rule
    (forced) agrees to 1e-3 only (measured 4e-4: kink planes cut the cells obliquely)."""
    m = MarkovModel3D(6.0, 0.5, 3.0, angle_deg=20.0, kind="markov_separable")
    cell = (0.25, 0.25, 0.5)
    K, L, M = LAGS
    c3 = lattice_covariance_3d(m, cell, K, L, M)
    ref = lattice_covariance(m.section, cell[:2], K, L) * local_average_covariance_1d(M, 0.5, 3.0)
    assert np.abs(c3 - ref).max() < 1e-15
    quad = lattice_covariance_3d(m, cell, K, L, M, method="quadrature")
    assert np.abs(quad - ref).max() < 1e-3


def test_error_estimate_against_a_finer_rule():
    """:func:`quadrature_error_3d` (difference to the graded rule with twice the levels and
    7 points per panel) at the kink lags of an isotropic field: below 1e-8 (measured
    2.9e-10)."""
    err = quadrature_error_3d(MarkovModel3D(1.0, 1.0, 1.0), (0.5, 0.5, 0.5),
                              [0, 1, 0, 3], [0, 0, 1, 1], [0, 1, 1, 0])
    assert err.max() < 1e-8


def test_point_covariance_and_symmetry():
    """Without averaging the table is the point correlation; with a layering turned about
    the strike axis C(K, L, M) = C(-K, -L, M) = C(K, L, -M)."""
    m = MarkovModel3D(6.0, 0.5, 3.0, angle_deg=15.0)
    K, L, M = LAGS
    pt = lattice_covariance_3d(m, (0.5, 0.25, 0.5), K, L, M, averaging=False)
    assert np.allclose(pt, np.exp(-2 * m.scaled_norm(0.5 * K, 0.25 * L, 0.5 * M)), rtol=0,
                       atol=1e-15)
    c = lattice_covariance_3d(m, (0.5, 0.25, 0.5), K, L, M)
    assert np.abs(c - c[::-1, ::-1, :]).max() < 1e-12
    assert np.abs(c - c[:, :, ::-1]).max() < 1e-12


@pytest.mark.parametrize("model,averaging", [
    (MarkovModel3D(4.0, 1.0, 2.0), True), (MarkovModel3D(4.0, 1.0, 2.0), False),
    (MarkovModel3D(4.0, 1.0, 2.0, kind="markov_separable"), True),
    (MarkovModel3D(3.0, 0.5, 2.0, angle_deg=15.0), True)])
def test_embedding_is_exact_on_every_lag_inside_the_field(model, averaging):
    """The covariance the circulant generates (inverse FFT of lambda) equals the table at
    every lag of a 16 x 8 x 12 field to 1e-12 (measured 8e-15): no clipping, no wrap."""
    e = circulant_embedding_3d(model, (0.5, 0.25, 0.5), (16, 8, 12), averaging)
    assert e.clipped == 0.0 and e.lambda_min >= -1e-10 * e.lambda_max
    implied = sfft.irfftn(e.sqrt_eig ** 2, s=e.padded)
    K, L, M = np.meshgrid(np.arange(-15, 16), np.arange(-7, 8), np.arange(-11, 12),
                          indexing="ij")
    ref = lattice_covariance_3d(model, (0.5, 0.25, 0.5), K, L, M, averaging)
    got = implied[K % e.padded[0], L % e.padded[1], M % e.padded[2]]
    assert np.abs(got - ref).max() < 1e-12


def test_a_field_far_more_correlated_than_its_extent_is_one_variable():
    e = circulant_embedding_3d(MarkovModel3D(1e5, 1e5, 1e5), (1.0, 1.0, 1.0), (4, 3, 2))
    assert isinstance(e, SingleVariable3D)
    z = e.sample(3)
    assert z.shape == (4, 3, 2) and np.all(z == z.flat[0])


def test_model_from_spec_defaults_to_a_horizontally_isotropic_field():
    spec = RandomFieldSpec(theta_v=0.5, anisotropy=8.0, layering_angle_deg=10.0)
    m = model_from_spec_3d(spec)
    assert (m.theta_h, m.theta_v, m.theta_z, m.angle_deg) == (4.0, 0.5, 4.0, 10.0)
    assert model_from_spec_3d(spec, 20.0).theta_z == 20.0
    assert np.allclose(m.section.correlation(1.0, 0.3), m.correlation(1.0, 0.3, 0.0))


def test_box_rule_same_field_on_every_mesh_and_cells_average_the_lattice():
    """With a box and cell_size the lattice, hence the field of a seed, is the same for a
    fine mesh (0.5 m cells, = the lattice) and a coarse one (1 m): each coarse cell is the
    mean of the 8 fine cells it holds, and the point path gives the fine cells' values."""
    spec = RandomFieldSpec(cov=0.3, theta_v=1.0, anisotropy=3.0, local_averaging=True)
    box = (0.0, 0.0, 0.0, 4.0, 2.0, 3.0)
    fine = field_lattice_3d(None, None, 0.5, box)
    cf = fine.centres()
    zf = sample_cell_field_3d(spec, cf, 0.5, 7, means=0.0 + 1.0, box=box, cell_size=0.5)
    coarse = field_lattice_3d(None, None, 1.0, box)
    cc = coarse.centres()
    z_lat = gaussian_fields_3d(spec, fine, 7)[0]
    idx, w = cell_weights_3d(fine, cc, 1.0)
    assert np.allclose(w, 1 / 8) and idx.shape == (len(cc), 8)
    gc = sample_cell_field_3d(spec, cc, 1.0, 7, means=1.0, box=box, cell_size=0.5)
    blocks = z_lat.reshape(4, 2, 2, 2, 3, 2).mean(axis=(1, 3, 5)).ravel()
    s2 = math.log1p(0.3 ** 2)
    assert np.allclose(np.log(gc["cohesion_peak"]), math.sqrt(s2) * blocks - s2 / 2, atol=1e-12)
    pts = sample_point_field_3d(spec, cf, 7, fine, means=1.0)
    assert np.array_equal(pts["cohesion_peak"], zf["cohesion_peak"])


def test_cell_weights_cut_lattice_cells_by_overlap():
    """A cell from 0.25 to 1.25 m on x (lattice cells of 0.5 m) takes 1/4, 1/2, 1/4 of
    three lattice cells; a cell outside the lattice takes the nearest edge cell."""
    lat = field_lattice_3d(None, None, 0.5, (0.0, 0.0, 0.0, 2.0, 0.5, 0.5))
    idx, w = cell_weights_3d(lat, [[0.75, 0.25, 0.25], [9.0, 0.25, 0.25]], [1.0, 0.5, 0.5])
    assert np.allclose(w[0][w[0] > 0], [0.25, 0.5, 0.25])
    assert np.allclose(w.sum(axis=1), 1.0)
    assert idx[1][w[1] > 0].tolist() == [3]


def test_one_property_noise_path_equals_the_seed_path_and_cross_correlation_mixes():
    """One property: ``noise = default_rng(seed).standard_normal(m)`` gives bitwise the
    seed's field.  Two properties with the same structure and R = 0.6: the second field is
    exactly 0.6 G1 + 0.8 G2 of the two noises' fields (to 1e-12)."""
    lat = field_lattice_3d(None, None, 0.5, (0.0, 0.0, 0.0, 3.0, 2.0, 2.5))
    spec = RandomFieldSpec(theta_v=1.0, anisotropy=2.0)
    emb = embeddings_3d(spec, lat)[0]
    z = gaussian_fields_3d(spec, lat, 5)
    eps = np.random.default_rng(5).standard_normal(emb.padded)
    assert np.array_equal(z, gaussian_fields_3d(spec, lat, None, noise=eps))
    two = RandomFieldSpec(theta_v=1.0, anisotropy=2.0, properties=(
        _prop("cohesion_peak"), _prop("friction_angle_peak")),
        cross_correlation=((1.0, 0.6), (0.6, 1.0)))
    eps2 = np.random.default_rng(9).standard_normal((2,) + emb.padded)
    zz = gaussian_fields_3d(two, lat, None, noise=eps2)
    g1, g2 = emb.from_noise(eps2[0]), emb.from_noise(eps2[1])
    assert np.abs(zz[0] - g1).max() < 1e-12
    assert np.abs(zz[1] - (0.6 * g1 + 0.8 * g2)).max() < 1e-12


def _prop(name):
    return PropertyFieldSpec(property=name)


def test_memory_estimate_within_1_5x_of_the_measured_peak():
    """A 60 x 30 x 40-cell field (lattice 135 x 72 x 96, 0.93 M points): the estimate
    against the tracemalloc peak of the set-up and of one sample with the kept spectrum
    (measured 25.7 MiB estimated, 25.3 MiB peak)."""
    m = MarkovModel3D(4.0, 1.0, 4.0)
    shape, cell = (60, 30, 40), (0.5, 0.25, 0.5)
    est = estimate_embedding_3d(m, cell, shape)
    lattice_covariance_3d(m, cell, [0], [0], [0])          # compile outside the measurement
    tracemalloc.start()
    try:
        e = circulant_embedding_3d(m, cell, shape, report=lambda s: None)
        setup = tracemalloc.get_traced_memory()[1]
        tracemalloc.reset_peak()
        e.sample(1)
        sample = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert e.padded == est.padded
    peak = max(setup, sample)
    assert peak / 1.5 <= est.peak_bytes <= 1.5 * peak, (est.describe(), setup, sample)


def test_a_field_over_the_memory_limit_is_refused_at_once_with_its_estimate():
    """A 400 x 80 x 200 m slope at 0.1 m cells (6.4e9 lattice points) is refused from
    arithmetic before anything is allocated (peak of traced memory below 16 MiB against
    the estimate's hundreds of GiB), the message carrying the lattice and the estimate;
    one line."""
    spec = RandomFieldSpec(theta_v=0.5, anisotropy=40.0)
    tracemalloc.start()
    try:
        with pytest.raises(MemoryError) as exc:
            sample_cell_field_3d(spec, np.array([[200.0, 40.0, 100.0]]),
                                 [[400.0, 80.0, 200.0]], 1, cell_size=0.1,
                                 limit_bytes=8 * 2**30)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 16 * 2**20, peak
    msg = str(exc.value)
    assert "\n" not in msg and "lattice" in msg and "exceeds the memory limit of 8 GiB" in msg
    assert isinstance(exc.value, SceneError)          # exit 2 on the command line


def test_large_fields_print_their_estimate_first():
    seen = []
    m = MarkovModel3D(1.0, 1.0, 1.0)
    circulant_embedding_3d(m, (0.5, 0.5, 0.5), (8, 8, 8), limit_bytes=1e12,
                           report=seen.append)
    assert seen == []                              # small: silent
    with pytest.raises(MemoryError):
        circulant_embedding_3d(m, (0.5, 0.5, 0.5), (8, 8, 8), limit_bytes=1e3)


def test_the_embedding_cache_is_bounded_by_bytes():
    """Entries of 800 B in a 2000 B cache: the least recently used goes out at the third;
    an entry larger than the bound is returned and not kept."""
    class Entry:
        def __init__(self, n):
            self.a = np.zeros(n)
    cache = ByteBoundedCache(limit=lambda: 2000)
    a = cache.get_or_make("a", lambda: Entry(100))
    cache.get_or_make("b", lambda: Entry(100))
    assert cache.get_or_make("a", lambda: None) is a          # hit; "a" most recent
    cache.get_or_make("c", lambda: Entry(100))
    assert len(cache) == 2 and cache.nbytes == 1600
    assert cache.get_or_make("b", lambda: "remade") == "remade"
    big = cache.get_or_make("big", lambda: Entry(1000))
    assert isinstance(big, Entry) and "big" not in cache._data


def test_bad_input_is_refused_with_a_one_line_reason():
    spec = RandomFieldSpec()
    with pytest.raises(ValueError, match=r"\(n, 3\) array of cell centres"):
        sample_cell_field_3d(spec, np.zeros((4, 2)), 0.5, 1)
    box2d = RandomFieldSpec(box=(0.0, 0.0, 4.0, 2.0), cell_size=0.5)
    with pytest.raises(ValueError, match="is a 2-D rectangle"):
        sample_cell_field_3d(box2d, np.zeros((1, 3)), 0.5, 1)
    with pytest.raises(ValueError, match="needs cell_size"):
        field_lattice_3d(None, None, None, (0, 0, 0, 1, 1, 1))


def test_subset_simulation_refuses_a_3d_field_with_the_reason():
    lat = field_lattice_3d(None, None, 0.5, (0.0, 0.0, 0.0, 3.0, 2.0, 2.5))
    embs = embeddings_3d(RandomFieldSpec(theta_v=1.0), lat)
    with pytest.raises(ValueError, match="subset simulation is not available for 3-D") as exc:
        subset_noise_3d(embs)
    assert "MB per sample" in str(exc.value) and "crude Monte Carlo" in str(exc.value)


def test_conditioning_honours_the_data_and_gives_the_kriging_mean(tmp_path):
    """Two measurements (CSV x,y,z,value) of a lognormal field (mean 20 kPa, COV 0.3): every
    conditional realization holds their Gaussian values at their cells to 1e-10; over
    N = 200 realizations the mean at the cell next to a lone datum along x is the simple
    kriging mean C(1,0,0)/C(0) z_d up to the second datum's (small) weight, within 5 SE
    (the reference is the dense kriging solution on the two data cells)."""
    spec = RandomFieldSpec(cov=0.3, theta_v=1.0, anisotropy=2.0)
    lat = field_lattice_3d(None, None, 0.5, (0.0, 0.0, 0.0, 4.0, 2.0, 3.0))
    csv = tmp_path / "cpt.csv"
    csv.write_text("x,y,z,value\n1.1,0.6,1.2,31.0\n3.3,1.4,2.6,15.0\n")
    s2 = math.log1p(0.09)
    zd = (np.log([31.0, 15.0]) - (math.log(20.0) - s2 / 2)) / math.sqrt(s2)
    cells = np.ravel_multi_index(([2, 6], [1, 2], [2, 5]), lat.shape)
    emb = embeddings_3d(spec, lat)[0]
    ijk = np.array([[2, 1, 2], [6, 2, 5]])
    C = emb.covariance(*(ijk[:, None, :] - ijk[None, :, :]).transpose(2, 0, 1))
    target_cell = np.ravel_multi_index((3, 1, 2), lat.shape)
    c_t = emb.covariance(*(np.array([3, 1, 2]) - ijk).T)
    kriging_mean = float(c_t @ np.linalg.solve(C, zd))
    vals = []
    for seed in range(200):
        z = gaussian_fields_3d(spec, lat, seed, data=csv, data_mean=20.0)[0].ravel()
        assert np.abs(z[cells] - zd).max() < 1e-10
        vals.append(z[target_cell])
    est, se = np.mean(vals), np.std(vals, ddof=1) / math.sqrt(len(vals))
    assert abs(est - kriging_mean) < 5 * se, (est, kriging_mean, se)
    with pytest.raises(ValueError, match="lies outside the field's box"):
        gaussian_fields_3d(spec, lat, 1, data=([9.0, 1.0, 1.0], [20.0]), data_mean=20.0)
    bad = tmp_path / "bad.csv"
    bad.write_text("x,y,value\n1,1,20\n")
    with pytest.raises(ValueError, match="missing column"):
        gaussian_fields_3d(spec, lat, 1, data=bad, data_mean=20.0)
