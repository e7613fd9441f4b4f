"""Mie wrapper validation (docs/quality.md section A): published values, Rayleigh limit, host index."""

import os
import warnings

import numpy as np
import pytest

from simulate.optics import mie
from simulate.optics.fresnel import OpticsDomainWarning

os.environ.setdefault("MIEPYTHON_USE_JIT", "1")
import miepython  # noqa: E402


def _rayleigh_k(m):
    return (m * m - 1) / (m * m + 2)


def test_bohren_huffman_appendix_a():
    # Bohren & Huffman (1983), App. A (BHMIE output): m = 1.55, x = 5.21282
    e = mie.efficiencies(1.55, 5.21282)
    assert e.qext == pytest.approx(3.10543, abs=1e-5)
    assert e.qsca == pytest.approx(3.10543, abs=1e-5)
    assert e.qback == pytest.approx(2.92534, abs=1e-5)
    assert e.g == pytest.approx(0.63314, abs=1e-5)
    assert e.qabs == 0.0


def test_host_index_sets_relative_index_and_size_parameter():
    """The same B&H sphere expressed as particle index 1.55 n_h in a host n_h."""
    n_h = 1.557
    wavelength_nm = 550.0
    radius_um = 5.21282 * wavelength_nm / 1000.0 / (2 * np.pi * n_h)
    e = mie.sphere_efficiencies(1.55 * n_h, n_h, radius_um, wavelength_nm)
    assert e.qsca == pytest.approx(3.10543, abs=1e-5)
    assert e.qback == pytest.approx(2.92534, abs=1e-5)
    assert e.g == pytest.approx(0.63314, abs=1e-5)


@pytest.mark.parametrize("n_env", [1.0, 1.33])
def test_same_particle_in_water_and_air_matches_miepython(n_env):
    m_p = 1.5 - 0.01j
    d_um, lam_um = 1.0, 0.55
    ref = miepython.efficiencies(m_p, d_um, lam_um, n_env=n_env)
    ours = mie.sphere_efficiencies(m_p, n_env, d_um / 2, lam_um * 1000.0)
    np.testing.assert_allclose([ours.qext, ours.qsca, ours.qback, ours.g], ref, rtol=1e-12)
    # and the positive-k spelling gives the same answer
    ours_pos = mie.sphere_efficiencies(1.5 + 0.01j, n_env, d_um / 2, lam_um * 1000.0)
    assert ours_pos.qext == pytest.approx(ours.qext, rel=1e-14)


def test_water_and_air_differ():
    a = mie.sphere_efficiencies(1.5, 1.0, 0.5, 550.0)
    w = mie.sphere_efficiencies(1.5, 1.33, 0.5, 550.0)
    assert abs(a.qsca - w.qsca) > 0.1


def test_sign_convention_and_particle_index():
    assert mie.particle_index(1.5, 0.02) == 1.5 - 0.02j
    assert mie.relative_index(1.5 + 0.02j, 1.5) == pytest.approx(1.0 - 0.02j / 1.5)
    with pytest.raises(ValueError):
        mie.particle_index(1.5, -0.1)


@pytest.mark.parametrize("m", [1.33, 1.5, 2.0])
@pytest.mark.parametrize("x", [1e-3, 1e-2])
def test_rayleigh_limit_scattering(m, x):
    # Q_sca = 8/3 x^4 |K|^2 (1 + (6/5) x^2 Re[(m^2-2)/(m^2+2)] + ...) (Penndorf 1962 expansion);
    # the correction is below x^2 in magnitude for these m -> rtol 2 x^2
    e = mie.efficiencies(m, x)
    ref = 8.0 / 3.0 * x**4 * abs(_rayleigh_k(m)) ** 2
    assert e.qsca == pytest.approx(ref, rel=2 * x * x)
    assert abs(e.g) < x * x  # g = O(x^2): Rayleigh scattering is symmetric about 90 deg


@pytest.mark.parametrize("m", [1.33, 1.5, 2.0])
@pytest.mark.parametrize("x", [1e-2, 3e-2])
def test_rayleigh_second_order_term(m, x):
    # with Penndorf's x^2 term included, what is left is O(x^4): a tolerance of x^4 (relative)
    # fails if the size parameter or the index were off by even 1e-4
    K = (m * m - 1) / (m * m + 2)
    ref = 8.0 / 3.0 * x**4 * K * K * (1 + 1.2 * x * x * (m * m - 2) / (m * m + 2))
    assert mie.efficiencies(m, x).qsca == pytest.approx(ref, rel=x**4)


def test_rayleigh_limit_absorption():
    m, x = 1.5 - 0.1j, 1e-3
    e = mie.efficiencies(m, x)
    # Q_abs = 4 x Im[(m^2-1)/(m^2+2)] with m = n + ik (here -Im because m = n - ik);
    # relative corrections are O(x^2)
    assert e.qabs == pytest.approx(-4 * x * _rayleigh_k(m).imag, rel=1e-4)


def test_rayleigh_phase_function():
    mu = np.linspace(-1, 1, 41)
    p = mie.phase_function(1.5, 1e-3, mu)
    np.testing.assert_allclose(p, 3 * (1 + mu**2) / (16 * np.pi), rtol=1e-5)


@pytest.mark.parametrize("m,x", [(1.55, 5.21282), (1.2, 60.0), (1.33 - 0.001j, 100.0)])
def test_phase_function_normalised_and_mean_cosine(m, x):
    # independent fine quadrature: Simpson on 60001 equally spaced theta (~190 nodes per
    # ripple period pi/x at x = 100)
    theta = np.linspace(0, np.pi, 60001)
    mu = np.cos(theta)
    p = mie.phase_function(m, x, mu)
    w = np.ones_like(theta)
    w[1:-1:2], w[2:-1:2] = 4, 2
    h = theta[1] - theta[0]
    integ = lambda f: 2 * np.pi * np.sum(w * f * np.sin(theta)) * h / 3  # noqa: E731
    assert integ(p) == pytest.approx(1.0, abs=2e-6)
    assert integ(mu * p) == pytest.approx(mie.efficiencies(m, x).g, abs=2e-6)


def test_no_contrast_scatters_nothing():
    e = mie.efficiencies(1.0, 5.0)
    assert (e.qext, e.qsca, e.qabs, e.qback, e.g) == (0.0, 0.0, 0.0, 0.0, 0.0)
    mu = np.linspace(-1, 1, 2001)
    with pytest.warns(OpticsDomainWarning, match="scatter nothing"):
        p = mie.phase_function(1.0, 5.0, mu)
    assert np.all(np.isfinite(p)) and np.all(p >= 0)
    assert 2 * np.pi * np.trapezoid(p, mu) == pytest.approx(1.0, abs=1e-5)


def test_large_size_parameter_extinction_paradox():
    # Q_ext -> 2 for x >> 1 (van de Hulst 1957, sec. 8.22); ripple ~ few % at x = 1e3
    for m in (1.1, 1.33, 1.55 - 0.01j):
        e = mie.efficiencies(m, 1e3)
        assert e.qext == pytest.approx(2.0, abs=0.1)
        assert np.isfinite([e.qsca, e.qback, e.g]).all() and 0 < e.g < 1


def test_lognormal_monodisperse_limit():
    single = mie.cross_sections(1.59, 1.33, 633.0, radius_um=0.4)
    dist = mie.cross_sections(1.59, 1.33, 633.0, distribution=mie.LogNormalSize(0.4, 1.0))
    assert dist.sigma_sca == pytest.approx(single.sigma_sca, rel=1e-14)
    assert single.sigma_sca == pytest.approx(mie.sphere_efficiencies(1.59, 1.33, 0.4, 633.0).qsca * np.pi * 0.16)


def test_lognormal_quadrature_against_rayleigh_moment():
    """Rayleigh spheres: <sigma_sca> = C <r^6> with the exact moment r_g^6 exp(18 s^2)."""
    r_g, sigma_g, m_p, n_h, lam = 0.001, 1.5, 1.5, 1.0, 550.0
    cs = mie.cross_sections(m_p, n_h, lam, distribution=mie.LogNormalSize(r_g, sigma_g))
    k = 2 * np.pi * n_h / (lam / 1000.0)
    s = np.log(sigma_g)
    mean_r6 = r_g**6 * np.exp(18 * s * s)
    ref = 8.0 / 3.0 * k**4 * abs(_rayleigh_k(m_p)) ** 2 * np.pi * mean_r6
    # x at the r^6-weighted mean radius is ~0.03: Rayleigh corrections ~ 2 x^2 = 2e-3
    assert cs.sigma_sca == pytest.approx(ref, rel=3e-3)
    assert cs.quadrature_error < 1e-6


def test_lognormal_ensemble_phase_function_normalised():
    d = mie.LogNormalSize(0.2, 1.3)
    cs = mie.cross_sections(2.7, 1.557, 550.0, distribution=d)
    mu, p = mie.ensemble_phase_function(2.7, 1.557, 550.0, distribution=d)
    assert 2 * np.pi * -np.trapezoid(p, mu) == pytest.approx(1.0, abs=1e-4)
    assert 2 * np.pi * -np.trapezoid(mu * p, mu) == pytest.approx(cs.g, abs=1e-4)


def test_input_errors():
    with pytest.raises(ValueError, match="size parameter"):
        mie.efficiencies(1.5, 0.0)
    with pytest.raises(ValueError, match="exactly one"):
        mie.cross_sections(1.5, 1.0, 500.0)
    with pytest.raises(ValueError, match="host index"):
        mie.relative_index(1.5, 1.0 - 0.1j)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        mie.phase_grid(1000.0)
    with pytest.warns(OpticsDomainWarning, match="capped"):
        mie.phase_grid(5000.0)


def test_memoised_results_are_exact_and_private():
    # the memo (a second run of the same wavelength, e.g. the cost estimate then the run) returns what
    # a computation returns, and a caller that modifies its arrays does not change the next answer
    dist = mie.LogNormalSize(0.1, 1.4)
    args = (complex(2.7, 0.0), 1.557, 550.0)
    mie._MEMO.clear()
    mu1, p1 = mie.ensemble_phase_function(*args, distribution=dist)
    cs1 = mie.cross_sections(*args, distribution=dist)
    p1_copy = p1.copy()
    p1 *= 0.0
    mu2, p2 = mie.ensemble_phase_function(*args, distribution=dist)
    np.testing.assert_array_equal(p2, p1_copy)
    assert mie.cross_sections(*args, distribution=dist) == cs1
    fresh_mu, fresh_p = mie._ensemble_phase(*args, None, dist, None)
    np.testing.assert_array_equal(mu2, fresh_mu)
    np.testing.assert_array_equal(p2, fresh_p)
    # a different input is a different entry
    _, p3 = mie.ensemble_phase_function(complex(2.6, 0.0), 1.557, 550.0, distribution=dist)
    assert not np.array_equal(p3, p2)
