"""Cook-Torrance validation (docs/quality.md section A): normalisation, reciprocity, albedo, mirror limit."""

import warnings
from itertools import pairwise

import numpy as np
import pytest
from scipy import integrate

from simulate.optics import microfacet as mf
from simulate.optics.fresnel import OpticsDomainWarning

N_HOST = 1.557


@pytest.mark.parametrize("m", [0.01, 0.05, 0.2, 0.5, 1.0])
def test_projected_beckmann_area_integrates_to_one(m):
    def integrand(theta):
        return 2 * np.pi * float(mf.beckmann_d(np.cos(theta), m)) * np.cos(theta) * np.sin(theta)

    peak = min(np.pi / 2, 10 * m)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", OpticsDomainWarning)  # m = 1.0 is flagged (tested elsewhere)
        total = integrate.quad(integrand, 0, peak, limit=200)[0] + integrate.quad(integrand, peak, np.pi / 2, limit=200)[0]
    assert total == pytest.approx(1.0, abs=1e-8)


def test_brdf_matches_the_formula_written_out():
    """One configuration computed by hand from docs/physics.md section 5 with scalar math."""
    m, n = 0.3, 1.557
    ti, pi_, to, po = np.radians(30.0), 0.0, np.radians(50.0), np.radians(160.0)
    wi = np.array([np.sin(ti) * np.cos(pi_), np.sin(ti) * np.sin(pi_), np.cos(ti)])
    wo = np.array([np.sin(to) * np.cos(po), np.sin(to) * np.sin(po), np.cos(to)])
    h = (wi + wo) / np.linalg.norm(wi + wo)
    ch, oh = h[2], wo @ h
    d = np.exp(-(1 - ch**2) / ch**2 / m**2) / (np.pi * m**2 * ch**4)
    g = min(1.0, 2 * ch * wo[2] / oh, 2 * ch * wi[2] / oh)
    ct = np.sqrt(1 - (np.sin(np.arccos(oh)) / n) ** 2)
    rs = (oh - n * ct) / (oh + n * ct)
    rp = (n * oh - ct) / (n * oh + ct)
    f = 0.5 * (rs**2 + rp**2)
    expected = d * g * f / (4 * wi[2] * wo[2])
    assert float(mf.cook_torrance(wi, wo, m, n)) == pytest.approx(expected, rel=1e-12)
    assert float(mf.cook_torrance_angles(ti, pi_, to, po, m, n)) == pytest.approx(expected, rel=1e-12)


def test_reciprocity():
    rng = np.random.default_rng(5)
    # directions up to 84 deg (inside the model's domain) in random azimuths
    t = np.arccos(rng.uniform(np.cos(np.radians(84)), 1, size=(2, 2000)))
    p = rng.uniform(0, 2 * np.pi, size=(2, 2000))
    wi, wo = mf.direction(t[0], p[0]), mf.direction(t[1], p[1])
    for m in (0.05, 0.3):
        a = mf.cook_torrance(wi, wo, m, N_HOST)
        b = mf.cook_torrance(wo, wi, m, N_HOST)
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=0)
        assert np.all(a >= 0) and np.any(a > 0)


def test_lower_hemisphere_is_zero():
    wi = mf.direction(np.radians(30.0), 0.0)
    wo = mf.direction(np.radians([100.0, 150.0, 180.0]), np.pi)
    np.testing.assert_array_equal(mf.cook_torrance(wi, wo, 0.3, N_HOST), 0.0)
    np.testing.assert_array_equal(mf.cook_torrance(wo, wi, 0.3, N_HOST), 0.0)


@pytest.mark.parametrize("with_fresnel", [True, False])
def test_directional_albedo_at_most_one(with_fresnel):
    theta = np.radians([0, 15, 30, 45, 60, 70, 80, 85, 88, 89, 89.9])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", OpticsDomainWarning)  # grazing / rough cells are flagged
        for m in (0.001, 0.01, 0.05, 0.1, 0.2, 0.3, 0.5, 0.7, 1.0):
            a, err = mf.directional_albedo(theta, m, N_HOST, n_grid=128, with_fresnel=with_fresnel,
                                           return_error=True)
            assert np.all(np.isfinite(a)) and np.all(a >= 0)
            assert np.all(a <= 1.0 + err + 1e-12), (m, a, err)


def test_directional_albedo_by_an_independent_quadrature():
    """Brute-force integration over outgoing directions at normal and 40 deg incidence."""
    m = 0.3
    theta_o = np.linspace(0, np.pi / 2, 601)[1:-1]
    phi_o = np.linspace(0, 2 * np.pi, 361)[:-1]
    T, P = np.meshgrid(theta_o, phi_o, indexing="ij")
    wo = mf.direction(T, P)
    for ti in (0.0, np.radians(40.0)):
        with pytest.warns(OpticsDomainWarning, match="from the normal"):  # the grid reaches 89.9 deg
            f = mf.cook_torrance(mf.direction(ti, 0.0), wo, m, N_HOST)
        brute = integrate.simpson(np.sum(f * np.cos(T) * np.sin(T), axis=1) * (phi_o[1] - phi_o[0]), x=theta_o)
        assert float(mf.directional_albedo(ti, m, N_HOST)) == pytest.approx(brute, abs=2e-4)


def test_smooth_limit_approaches_mirror_fresnel():
    from simulate.optics.fresnel import reflectance

    theta = np.radians([0.0, 20.0, 45.0, 60.0, 75.0, 80.0])
    mirror = reflectance(theta, 1.0, N_HOST)
    gaps = [np.max(np.abs(mf.directional_albedo(theta, m, N_HOST) - mirror)) for m in (0.1, 0.03, 0.01, 0.001)]
    assert all(a > b for a, b in pairwise(gaps))  # converges monotonically
    assert gaps[-1] < 1e-4


def test_sampled_normals_follow_beckmann():
    m = 0.25
    rng = np.random.default_rng(11)
    n = 200_000
    h, pdf = mf.sample_microfacet_normal(rng.random(n), rng.random(n), m)
    np.testing.assert_allclose(np.linalg.norm(h, axis=-1), 1.0, atol=1e-14)
    np.testing.assert_allclose(pdf, mf.beckmann_d(h[:, 2], m) * h[:, 2], rtol=1e-12)
    # P(tan^2 theta_h <= T) = 1 - exp(-T / m^2) for the projected Beckmann measure
    tan2 = (1 - h[:, 2] ** 2) / h[:, 2] ** 2
    for T in (0.01, 0.05, 0.1, 0.3):
        p_ref = 1 - np.exp(-T / m**2)
        frac = np.mean(tan2 <= T)
        assert abs(frac - p_ref) < 4 * np.sqrt(p_ref * (1 - p_ref) / n)
    # azimuth uniform: mean of cos and sin of phi vanish within 4 SE (SE = sqrt(1/2n))
    phi = np.arctan2(h[:, 1], h[:, 0])
    assert abs(np.cos(phi).mean()) < 4 * np.sqrt(0.5 / n)
    assert abs(np.sin(phi).mean()) < 4 * np.sqrt(0.5 / n)


def test_importance_sampled_albedo_agrees_with_quadrature():
    rng = np.random.default_rng(3)
    n = 400_000
    for ti in (0.0, np.radians(60.0)):
        wi = mf.direction(ti, 0.0)
        wo, w = mf.sample_reflection(wi, rng.random(n), rng.random(n), 0.3, N_HOST)
        assert np.all(wo[w > 0, 2] > 0)
        se = w.std(ddof=1) / np.sqrt(n)
        assert abs(w.mean() - float(mf.directional_albedo(ti, 0.3, N_HOST))) < 4 * se


def test_the_compiled_cook_torrance_is_the_numpy_one():
    """One Cook-Torrance: the tracers' compiled scalar form equals the models' numpy form times cos_o."""
    rng = np.random.default_rng(5)
    w_in = mf.direction(rng.uniform(0, 1.45, 200), rng.uniform(-np.pi, np.pi, 200))
    w_out = mf.direction(rng.uniform(0, 1.45, 200), rng.uniform(-np.pi, np.pi, 200))
    for m, n_host in ((0.1, 1.5), (0.35, 1.557), (0.5, 1.33)):
        expected = mf.cook_torrance(w_in, w_out, m, n_host) * w_out[:, 2]
        got = np.array([mf.cook_torrance_cos_local(*a, *b, m, n_host) for a, b in zip(w_in, w_out, strict=True)])
        np.testing.assert_allclose(got, expected, rtol=1e-12, atol=1e-300)
    assert mf.cook_torrance_cos_local(0.0, 0.0, -1.0, 0.0, 0.0, 1.0, 0.3, 1.5) == 0.0  # light from below
