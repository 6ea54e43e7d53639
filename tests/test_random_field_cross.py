"""Random fields of several cross-correlated properties: sample cross-correlation and
marginals against their targets, the one-property seed path against golden values, and
one-line errors for bad cross-correlated fields.

The generator (``fem_rmpm.random_field.cross``): one standard-normal noise array per
property on a common circulant-embedding lattice, mixed by the Cholesky factor ``L`` of
the cross-correlation matrix ``R``, each mixed noise turned into its property's Gaussian
field by that property's embedding; with a shared correlation structure this is exactly
``Z = L G`` for independent standard Gaussian fields ``G``.  The statistical tests use
point values (``local_averaging = false``), so each cell's Gaussian value is standard
normal and the marginal transforms are exact.
"""
from __future__ import annotations

import hashlib
import json
import math

import numpy as np
import pytest

from fem_rmpm import api
from fem_rmpm import campaign as mc
from fem_rmpm import random_field as rf
from fem_rmpm.cli import main as cli_main
from fem_rmpm.discretise.grid import make_grid
from fem_rmpm.discretise.points import seed_particles
from fem_rmpm.scene import SceneError, load_scene, scene_from_dict, scene_to_dict, with_value

TINY = "tests/data/mc_tiny.toml"
DRAINED = "meshes/slope_drained_random.toml"
C_MEAN, C_COV, PHI_MEAN, PHI_COV, PHI_LOW, PHI_HIGH = 5.0, 0.3, 22.0, 0.1, 10.0, 35.0


def two_property_scene(rho: float = 0.0, averaging: bool = False, own: dict | None = None,
                       size: float = 8.0, extra: dict | None = None):
    """An 8 m x 8 m block of Mohr-Coulomb soil (0.25 m cells: 32 x 32 field cells) with
    a lognormal cohesion field (mean 5 kPa, COV 0.3) and a beta friction-angle field on
    [10, 35] deg (mean 22 deg, COV 0.1), theta_v = 0.5 m, xi = 1, cross-correlation rho;
    ``own``: the friction angle's own correlation keys."""
    phi = {"property": "friction_angle_peak", "distribution": "beta", "cov": PHI_COV,
           "low": PHI_LOW, "high": PHI_HIGH, **(own or {})}
    field = {"theta_v": 0.5, "anisotropy": 1.0, "local_averaging": averaging,
             "cross_correlation": [[1.0, rho], [rho, 1.0]],
             "properties": [{"property": "cohesion_peak", "distribution": "lognormal",
                             "cov": C_COV}, phi], **(extra or {})}
    return scene_from_dict({
        "scene": {"name": "cross"}, "grid": {"origin": [0.0, 0.0], "size": [size, size],
                                             "cell": 0.25},
        "soil": [{"name": "soil", "polygon": [[0, 0], [size, 0], [size, size], [0, size]],
                  "unit_weight": 20.0, "youngs_modulus": 1000.0, "poisson_ratio": 0.3,
                  "model": "mohr_coulomb_softening", "cohesion_peak": C_MEAN,
                  "cohesion_residual": 1.0, "friction_angle_peak": PHI_MEAN,
                  "friction_angle_residual": 18.0}],
        "random_field": field})


def realizations(scene, n: int) -> np.ndarray:
    """Gaussian fields (n, p, n2, n1) of seeds 0..n-1."""
    grid = make_grid(scene)
    layout = rf.field_layout(scene, grid)
    return np.stack([rf.gaussian_fields(scene, grid, s, layout=layout) for s in range(n)])


def _sha(a: np.ndarray) -> str:
    return hashlib.sha256(np.ascontiguousarray(a).tobytes()).hexdigest()


# ---------------------------------------------------------------- correlation and marginals
N_STAT = 500


@pytest.mark.parametrize("rho,averaging", [(-0.5, False), (0.0, False), (0.5, False),
                                           (0.5, True)])
def test_sample_cross_correlation_of_the_gaussian_fields(rho, averaging):
    """Reference: Z = L G (the Cholesky factor L of R mixes independent standard Gaussian
    fields G).  The sample (Pearson) correlation of the two Gaussian fields, pooled
    over N = 500 realizations of 32 x 32 cells, is within 4.5 standard errors of rho, and
    4.5 SE is below the required 0.03.  The SE is the spread of the per-realization
    correlations / sqrt(N): 0.0014-0.0019 (4.5 SE <= 0.0087); achieved |r - rho| <= 0.0013.
    With local averaging (cell variance gamma < 1) the correlation of the cell values is
    still rho (shared structure: Z = L G)."""
    Z = realizations(two_property_scene(rho, averaging), N_STAT)
    a, b = Z[:, 0].reshape(N_STAT, -1), Z[:, 1].reshape(N_STAT, -1)
    r = np.corrcoef(a.ravel(), b.ravel())[0, 1]
    r_i = np.array([np.corrcoef(x, y)[0, 1] for x, y in zip(a, b)])
    se = r_i.std(ddof=1) / math.sqrt(N_STAT)
    bound = 4.5 * se
    assert bound <= 0.03, f"the test cannot show 0.03: 4.5 SE = {bound:.4f}"
    assert abs(r - rho) <= bound, f"r = {r:.4f}, rho = {rho}, SE {se:.4f}"


def _mean_cov_se(v: np.ndarray, batches: int = 20):
    """Pooled mean and COV of v (N, cells) and their standard errors: from the spread of
    the per-realization means, and of the COVs of ``batches`` batches of realizations."""
    n = len(v)
    m_i, q_i = v.mean(axis=1), (v * v).mean(axis=1)
    mean = m_i.mean()
    cov = math.sqrt(q_i.mean() - mean ** 2) / mean
    mb, qb = m_i.reshape(batches, -1).mean(axis=1), q_i.reshape(batches, -1).mean(axis=1)
    covb = np.sqrt(qb - mb ** 2) / mb
    return mean, cov, m_i.std(ddof=1) / math.sqrt(n), covb.std(ddof=1) / math.sqrt(batches)


@pytest.mark.parametrize("rho", [-0.5, 0.5])
def test_marginal_means_covs_and_phi_bounds(rho):
    """Over N = 500 realizations (32 x 32 point values each) the mean and COV
    of cohesion (lognormal, 5 kPa, 0.3) and friction angle (beta on [10, 35] deg, 22 deg,
    0.1) are within 4.5 SE of the targets (relative), 4.5 SE below the required 2 %;
    phi never leaves [10, 35] deg.  SE (relative): c mean 0.10 %, c COV 0.16 %, phi mean
    0.034 %, phi COV 0.13 %; achieved: c within 0.02 %, phi mean 0.03 %, phi COV 0.16 %."""
    scene = two_property_scene(rho)
    grid, pts = api.prepare(scene, 0)
    Z = realizations(scene, N_STAT)
    f_c, f_phi = scene.random_field.fields()
    for f, k, mu, cv in ((f_c, 0, C_MEAN, C_COV), (f_phi, 1, PHI_MEAN, PHI_COV)):
        v = rf.gaussian_to_property(Z[:, k].reshape(N_STAT, -1), mu, f)
        mean, cov, se_m, se_c = _mean_cov_se(v)
        for what, got, target, se in (("mean", mean, mu, se_m / mu), ("COV", cov, cv, se_c / cv)):
            assert 4.5 * se <= 0.02, f"{f.property} {what}: 4.5 SE = {4.5 * se:.4f}"
            assert abs(got / target - 1) <= 4.5 * se, f"{f.property} {what} {got:.5g}"
        if k == 1:
            assert v.min() >= PHI_LOW and v.max() <= PHI_HIGH
            assert v.min() < 14 and v.max() > 30        # the tails are drawn
    phi = pts.soil.friction_angle_peak
    assert PHI_LOW <= phi.min() and phi.max() <= PHI_HIGH


def test_beta_transform_stays_inside_its_bounds_in_the_far_tails():
    """phi = low + (high - low) B^-1(Phi(z)) for z up to +-40 (Phi underflows to 0 at -38):
    never outside [10, 35] deg, monotone, and property_to_gaussian inverts it to 1e-9 where
    the tails are representable (|z| <= 8)."""
    f = two_property_scene().random_field.fields()[1]
    z = np.concatenate([[-1e3, -40.0], np.linspace(-8, 8, 161), [40.0, 1e3]])
    v = rf.gaussian_to_property(z, PHI_MEAN, f)
    assert v.min() >= PHI_LOW and v.max() <= PHI_HIGH and np.all(np.diff(v) >= 0)
    inner = slice(2, -2)
    assert np.allclose(rf.property_to_gaussian(v[inner], PHI_MEAN, f), z[inner], atol=1e-9)
    a, b = rf.beta_shape(PHI_MEAN, PHI_COV, PHI_LOW, PHI_HIGH)
    m, s = (PHI_MEAN - PHI_LOW) / 25, PHI_COV * PHI_MEAN / 25      # beta moments
    assert a / (a + b) == pytest.approx(m, rel=1e-14, abs=0)
    assert math.sqrt(a * b / ((a + b) ** 2 * (a + b + 1))) == pytest.approx(s, rel=1e-12)


def test_shared_structure_is_exactly_the_cholesky_mix_of_independent_fields():
    """Z = L G: the fields of a seed equal the Cholesky factor of R applied to the two
    independent fields of the same noise (linearity of the embedding; 2e-16 achieved,
    asserts 1e-13)."""
    scene = two_property_scene(-0.5)
    grid = make_grid(scene)
    layout = rf.field_layout(scene, grid)
    embs = rf.embeddings_for(scene, layout)
    eps = rf.field_noise(scene, grid, 7)
    G = np.stack([embs[0].from_noise(eps[0]), embs[1].from_noise(eps[1])])
    L = np.linalg.cholesky(np.array(scene.random_field.cross_correlation))
    Z = rf.gaussian_fields(scene, grid, 7, layout=layout)
    assert np.allclose(Z, np.einsum("kj,jab->kab", L, G), rtol=0, atol=1e-13)


def test_own_structures_keep_their_covariance_and_scale_the_cross_correlation():
    """Own structure (phi: theta_v = 1 m, xi = 3): each field keeps exactly its own
    covariance (lag-1 correlations along x of both fields within 4.5 SE of their own
    model's, N = 300), and the point cross-correlation is rho times the coherence
    sum sqrt(lambda_c lambda_phi) / sqrt(sum lambda_c sum lambda_phi) < 1 (within 4.5 SE)."""
    n, rho = 300, 0.6
    scene = two_property_scene(rho, own={"theta_v": 1.0, "anisotropy": 3.0})
    grid = make_grid(scene)
    embs = rf.embeddings_for(scene, rf.field_layout(scene, grid))
    assert embs[0].padded == embs[1].padded
    Z = realizations(scene, n)
    for k in (0, 1):
        lag = (Z[:, k, :, :-1] * Z[:, k, :, 1:]).reshape(n, -1).mean(axis=1)
        target = float(embs[k].covariance(1, 0))
        assert abs(lag.mean() - target) <= 4.5 * lag.std(ddof=1) / math.sqrt(n), (k, target)
    coh = rf.coherence(embs[0], embs[1])
    assert 0.5 < coh < 0.99
    r_i = (Z[:, 0] * Z[:, 1]).reshape(n, -1).mean(axis=1)
    assert abs(r_i.mean() - rho * coh) <= 4.5 * r_i.std(ddof=1) / math.sqrt(n)
    assert abs(r_i.mean() - rho) > 4.5 * r_i.std(ddof=1) / math.sqrt(n)   # not rho itself


# ------------------------------------------------------------------------- golden seed path
# Golden values of the one-property seed path, recorded from the single-property generator:
# (sum, sum of squares, first, middle and last finite entry).  The seed path is bitwise the
# same on one machine, but not across CPUs: numpy's FFT takes other SIMD paths (AVX2 /
# AVX-512), 1.55e-12 relative apart at most (on the reference slope's larger field,
# tests/test_noise_field.py).  So the values are asserted to 1e-11 relative, far below what
# any change of the seed path (other draws: O(1)) would give.
GOLDEN = {
    ("gaussian_field", 0): (6.63414266656928, 14.842020682566268, -0.20350799336526723,
                            0.16299079249154977, -0.1982762871305678),
    ("gaussian_field", 11): (11.326176889446764, 7.2963021493447915, 0.2415059004281545,
                             0.46519414962610284, -0.3428707975541456),
    ("sample_point_property", 0): (1019.2265211019885, 7182.049357439747, 5.280903219420509,
                                   8.377930026764012, 4.223394111267531),
    ("sample_point_property", 11): (1018.8349395194613, 6972.023005573011, 6.516341729779928,
                                    6.333302323261649, 6.2167988554877445),
    ("prepare", 11): (207570.78759921214, 167587601.96573818, 375.9398496240601,
                      375.9398496240601, 0.0),
}


def _summary(a: np.ndarray) -> tuple:
    """(sum, sum of squares, first, middle, last) of the finite entries of ``a``."""
    v = np.asarray(a, float).ravel()
    v = v[np.isfinite(v)]
    return (float(v.sum()), float((v * v).sum()), float(v[0]), float(v[len(v) // 2]),
            float(v[-1]))


def _as_before(a: np.ndarray, key) -> bool:
    return _summary(a) == pytest.approx(GOLDEN[key], rel=1e-11, abs=1e-300)


def test_single_property_seed_path_is_as_before():
    """The one-property scene (mc_tiny) gives the fields, point cohesions and parameter
    rows of the single-property generator (:data:`GOLDEN`, 1e-11 relative:
    bitwise on one machine, FFT round-off between machines); the same field written as a
    one-entry [[random_field.properties]] list gives bitwise the same parameter rows."""
    scene = load_scene(TINY)
    grid = make_grid(scene)
    pts = seed_particles(scene, grid)
    for seed in (0, 11):
        assert _as_before(rf.gaussian_field(scene, grid, seed), ("gaussian_field", seed))
        assert _as_before(rf.sample_point_property(scene, grid, pts, seed),
                          ("sample_point_property", seed))
    # the parameter rows' first 6 columns (moduli + the von Mises parameters); the
    # regularisation columns are not part of the golden values
    params = api.prepare(scene, 11)[1].soil.params
    assert _as_before(params[:, :6], ("prepare", 11))
    d = scene_to_dict(scene)
    f = d["random_field"]
    d["random_field"] = {"theta_v": f.pop("theta_v"), "anisotropy": f.pop("anisotropy"),
                         "properties": [{k: f[k] for k in ("property", "distribution", "cov")}]}
    listed = scene_from_dict(d, scene.source)
    assert listed.random_field.properties and rf.noise_shape(listed, grid) == \
        rf.noise_shape(scene, grid)
    listed_params = api.prepare(listed, 11)[1].soil.params
    assert _sha(np.ascontiguousarray(listed_params[:, :6])) == \
        _sha(np.ascontiguousarray(params[:, :6]))
    assert np.array_equal(listed_params, params, equal_nan=True)


def test_the_golden_check_sees_another_seed():
    """The check can fail: seed 1's field is not seed 0's."""
    scene = load_scene(TINY)
    grid = make_grid(scene)
    assert not _as_before(rf.gaussian_field(scene, grid, 1), ("gaussian_field", 0))


def test_noise_path_equals_seed_path_and_first_property_is_the_single_field():
    """Several properties: the noise (p, m2, m1) of field_noise(seed) gives bitwise the
    fields of the seed; with independent properties (R = I) and a shared structure the
    first property's field is bitwise the one-property field of the same seed (its noise
    is the first block of the same stream)."""
    scene = two_property_scene(0.5)
    grid = make_grid(scene)
    eps = rf.field_noise(scene, grid, 5)
    assert eps.shape == rf.noise_shape(scene, grid) and eps.shape[0] == 2
    assert np.array_equal(rf.gaussian_fields(scene, grid, None, noise=eps.ravel()),
                          rf.gaussian_fields(scene, grid, 5))
    g1, p1 = api.prepare(scene, 5)
    g2, p2 = api.prepare(scene, None, noise=eps)
    assert np.array_equal(p1.soil.params, p2.soil.params)
    indep = two_property_scene(0.0)
    single = scene_from_dict({**scene_to_dict(indep), "random_field": {
        "theta_v": 0.5, "anisotropy": 1.0, "local_averaging": False,
        "property": "cohesion_peak", "distribution": "lognormal", "cov": C_COV}})
    assert single.random_field.properties == ()
    z2 = rf.gaussian_fields(indep, grid, 5)
    assert np.array_equal(z2[0], rf.gaussian_field(single, grid, 5))
    with pytest.raises(ValueError, match=r"shape \(2, "):
        rf.gaussian_fields(scene, grid, None, noise=np.zeros(3))


def test_residuals_follow_each_drawn_peak_in_proportion():
    """api.prepare: every point's residual cohesion is 1/5 of its drawn peak and its
    residual friction angle 18/22 of its drawn peak (the soil's ratios; 1e-15)."""
    scene = two_property_scene(-0.5)
    _, pts = api.prepare(scene, 3)
    s = pts.soil
    assert np.ptp(s.cohesion_peak) > 1 and np.ptp(s.friction_angle_peak) > 1
    assert np.allclose(s.cohesion_residual / s.cohesion_peak, 0.2, rtol=1e-15, atol=0)
    assert np.allclose(s.friction_angle_residual / s.friction_angle_peak, 18 / 22,
                       rtol=1e-15, atol=0)


def test_conditioning_is_per_property(tmp_path):
    """Kriging per property: friction-angle data condition the friction-angle field (it
    takes the data value at the data cell, 1e-9) and leave the cohesion field as the
    unconditioned one (bitwise)."""
    csv = tmp_path / "phi.csv"
    csv.write_text("x,y,value\n2.1,2.1,30.0\n6.1,5.1,14.0\n")
    plain = two_property_scene(0.5)
    d = scene_to_dict(plain)
    d["random_field"]["properties"][1]["data"] = str(csv)
    cond = scene_from_dict(d)
    grid = make_grid(cond)
    pts = seed_particles(cond, grid)
    v_plain, _ = rf.point_fields(plain, grid, pts, 4)
    v_cond, _ = rf.point_fields(cond, grid, pts, 4)
    assert np.array_equal(v_plain["cohesion_peak"], v_cond["cohesion_peak"])
    for (x, y), value in (((2.1, 2.1), 30.0), ((6.1, 5.1), 14.0)):
        cell = int(y // 0.25) * 32 + int(x // 0.25)
        at = pts.cell0 == cell
        assert np.allclose(v_cond["friction_angle_peak"][at], value, atol=1e-9)
        assert not np.allclose(v_plain["friction_angle_peak"][at], value, atol=0.1)


def test_field_command_shows_and_fits_one_property(tmp_path, capsys):
    """fem-rmpm field --property friction_angle_peak: the friction-angle field (deg, within
    its bounds), its cross-correlation named; --fit uses the property's marginal (a beta
    property is fitted on its values, a lognormal one on their logarithm)."""
    rng = np.random.default_rng(0)
    x, y = np.meshgrid(np.arange(0.1, 50, 0.5), np.arange(0.1, 4.9, 0.25))
    csv = tmp_path / "fit.csv"
    csv.write_text("x,y,value\n" + "".join(f"{a:.3f},{b:.3f},{20 + rng.normal():.4f}\n"
                                           for a, b in zip(x.ravel(), y.ravel())))
    for prop, log in (("friction_angle_peak", False), ("cohesion_peak", True)):
        out = tmp_path / prop
        assert cli_main(["field", DRAINED, "--seed", "2", "--property", prop, "--out", str(out),
                         "--fit", str(csv)]) == 0
        text = capsys.readouterr().out
        assert f"random field of {prop}" in text and "cross-correlated with" in text
        fit = json.loads((out / "fit.json").read_text())
        assert fit["log_transformed"] is log
        field = json.loads((out / "field.json").read_text())
        assert field["property"] == prop
        if prop == "friction_angle_peak":
            assert PHI_LOW <= field["min"] and field["max"] <= PHI_HIGH
    assert cli_main(["field", DRAINED, "--property", "friction", "--out",
                     str(tmp_path / "bad")]) == 2
    assert "allowed: cohesion_peak | friction_angle_peak" in capsys.readouterr().err
    assert not (tmp_path / "bad").exists()


def test_drained_random_scene_round_trips_and_draws_both_fields():
    """The shipped scene: reads back from scene_to_dict through JSON, and realization 1
    gives every soil point a cohesion and a friction angle from the fields (phi in its
    bounds, the two negatively correlated: Pearson of ln c and phi about -0.5)."""
    scene = load_scene(DRAINED)
    assert scene_from_dict(json.loads(json.dumps(scene_to_dict(scene))), scene.source) == scene
    _, pts = api.prepare(scene, 1)
    c, phi = pts.soil.cohesion_peak, pts.soil.friction_angle_peak
    assert PHI_LOW <= phi.min() and phi.max() <= PHI_HIGH and c.min() > 0
    assert -0.65 < np.corrcoef(np.log(c), phi)[0, 1] < -0.35


# ------------------------------------------------------------------------------- bad fields
def _drained_text(field: str, props: str | None = None) -> str:
    """The shipped drained random scene with its [random_field] section (and properties)
    replaced."""
    text = open(DRAINED).read()
    head, rest = text.split("[random_field]", 1)
    solver = rest[rest.index("[solver]"):]
    default_props = rest[rest.index("[[random_field.properties]]"):rest.index("[solver]")]
    return (head + "[random_field]\n" + field + "\n"
            + (default_props if props is None else props) + "\n" + solver)


PHI = ("[[random_field.properties]]\nproperty = \"cohesion_peak\"\ncov = 0.3\n"
       "[[random_field.properties]]\nproperty = \"friction_angle_peak\"\n"
       "distribution = \"beta\"\ncov = 0.1\n")
THREE = PHI + "low = 10.0\nhigh = 35.0\n[[random_field.properties]]\nproperty = \"softening_strain\"\n"


@pytest.mark.parametrize("field,props,key,words", [
    ("cross_correlation = [[1.0, 0.9, 0.9], [0.9, 1.0, -0.9], [0.9, -0.9, 1.0]]", THREE,
     "random_field.cross_correlation", ("not positive definite", "smallest eigenvalue")),
    ("cross_correlation = [[1.0, 1.0], [1.0, 1.0]]", None, "random_field.cross_correlation",
     ("|rho| = 1 >= 1", "-1 < rho < 1")),
    ("cross_correlation = [[1.0, -1.2], [-1.2, 1.0]]", None, "random_field.cross_correlation",
     ("|rho| = 1.2 >= 1",)),
    ("cross_correlation = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]", None,
     "random_field.cross_correlation", ("shape 3 x 3 for 2 properties", "2 x 2")),
    ("cross_correlation = [[1.0, 0.2], [0.2]]", None, "random_field.cross_correlation",
     ("shape 2 x 1/2 for 2 properties",)),
    ("cross_correlation = [[1.0, 0.2], [0.3, 1.0]]", None, "random_field.cross_correlation",
     ("not symmetric",)),
    ("cross_correlation = [[2.0, 0.2], [0.2, 1.0]]", None, "random_field.cross_correlation",
     ("is not all 1",)),
    ("", PHI.replace("friction_angle_peak", "friction_angle") + "low = 10.0\nhigh = 35.0\n",
     "random_field.properties[1].property",
     ("'friction_angle' is not a parameter of model 'mohr_coulomb_softening'",
      "allowed: cohesion_peak, friction_angle_peak")),
    ("", PHI + "low = -5.0\nhigh = 35.0\n", "random_field.properties[1].low",
     ("bounds [-5, 35]", "[0, 60)")),
    ("", PHI + "low = 10.0\nhigh = 95.0\n", "random_field.properties[1].high",
     ("bounds [10, 95]", "[0, 60)")),
    ("", PHI + "low = 10.0\nhigh = 60.0\n", "random_field.properties[1].high",
     ("bounds [10, 60]",)),
    ("", PHI + "low = 10.0\n", "random_field.properties[1].high", ("missing",)),
    ("", PHI.replace("distribution = \"beta\"\n", ""), "random_field.properties[1].distribution",
     ("'lognormal' for 'friction_angle_peak'", "'beta'")),
    ("", PHI.replace("cov = 0.1", "cov = 0.6") + "low = 10.0\nhigh = 35.0\n",
     "random_field.properties[1].cov", ("too large for a beta distribution", "cov < 0.5")),
    ("", PHI + "low = 25.0\nhigh = 35.0\n", "random_field.properties[1].low",
     ("= 22 (the field's mean) is not inside (low, high)",)),
    ("cov = 0.3", None, "random_field.cov", ("beside [[random_field.properties]]",)),
    ("", PHI.replace("friction_angle_peak", "cohesion_peak"),
     "random_field.properties[1].property", ("repeats random_field.properties[0]",)),
    ("", PHI.replace("friction_angle_peak", "cohesion_residual"),
     "random_field.properties[1].property", ("cannot be random",)),
])
def test_bad_cross_correlated_fields_are_one_line_errors(tmp_path, capsys, field, props, key,
                                                         words):
    """A cross-correlation matrix not positive definite, with
    |rho| >= 1, of the wrong shape (or not symmetric, or without a unit diagonal); a
    property the model does not have; friction-angle bounds outside the model's declared
    [0, 60) deg (narrower than the physical [0, 90)) or an unbounded marginal for it; a beta COV
    out of reach; a per-property key beside the list: exit 2, one line on stderr naming
    the file, the key and what is allowed, no traceback, nothing written."""
    scene = tmp_path / "bad.toml"
    scene.write_text(_drained_text(field, props))
    out = tmp_path / "out"
    code = cli_main(["run", str(scene), "--out", str(out), "--quiet"])
    err = capsys.readouterr().err.strip()
    assert code == 2, err
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    assert str(scene) in err and f"[{key}]" in err, err
    for w in words:
        assert w in err, err
    assert "allowed" in err
    assert not out.exists()


def test_a_property_of_another_model_is_refused():
    """cohesion field + friction_angle_peak on a von Mises soil (it has no friction
    angle): SceneError naming the model, the soil and the allowed properties."""
    d = scene_to_dict(load_scene(TINY))
    d["random_field"] = {"properties": [
        {"property": "cohesion_peak"},
        {"property": "friction_angle_peak", "distribution": "beta", "low": 5.0, "high": 30.0}]}
    with pytest.raises(SceneError, match=r"properties\[1\]\.property\] 'friction_angle_peak' is "
                       r"not a parameter of model 'von_mises_softening' \(soil 'clay'\); allowed: "
                       r"cohesion_peak, softening_strain"):
        scene_from_dict(d, "mc_tiny.toml")


# ----------------------------------------------------------------------------- a campaign
def test_two_realization_campaign_of_a_cut_in_c_phi_soil(tmp_path, dask_client):
    """The mc_tiny cut (2 m high, 45 deg) in Mohr-Coulomb soil (c' 4 -> 1 kPa lognormal
    COV 0.3, phi' 25 -> 20 deg beta on [15, 35] COV 0.1, rho = -0.5): a 2-realization
    campaign (the test run's 2-worker Dask cluster) finishes both realizations, they
    differ, each record's run is the realization's seed run in this process (pure function
    of scene and seed), and a rerun
    of the same campaign finds nothing to do (the campaign identity reads the new keys)."""
    d = scene_to_dict(load_scene(TINY))
    soil = {k: v for k, v in d["soil"][0].items() if k not in ("cohesion_peak",
                                                               "cohesion_residual")}
    d["soil"] = [{**soil, "model": "mohr_coulomb_softening", "cohesion_peak": 4.0,
                  "cohesion_residual": 1.0, "friction_angle_peak": 25.0,
                  "friction_angle_residual": 20.0}]
    d["random_field"] = {"theta_v": 0.5, "anisotropy": 4.0,
                         "cross_correlation": [[1.0, -0.5], [-0.5, 1.0]], "properties": [
                             {"property": "cohesion_peak", "distribution": "lognormal",
                              "cov": 0.3},
                             {"property": "friction_angle_peak", "distribution": "beta",
                              "cov": 0.1, "low": 15.0, "high": 35.0}]}
    scene = scene_from_dict(d, TINY)
    out = tmp_path / "cphi"
    res = mc.run_campaign(scene, out, 2, client=dask_client, progress=False, figures=False)
    assert res.computed == 2 and not res.lost
    rows = mc.read_results(out / "results.csv")
    assert [r["status"] for r in rows] == ["ok", "ok"]
    assert rows[0]["max_displacement"] != rows[1]["max_displacement"]
    alone = api.run(scene, seed=mc.realization_seed(scene.montecarlo.seed, 1), progress=False)
    assert alone.measures["max_displacement"] == rows[1]["max_displacement"]
    again = mc.run_campaign(scene, out, 2, client=dask_client, progress=False, figures=False)
    assert again.computed == 0 and again.skipped == 2
