"""Fresnel/Snell validation against closed-form references (docs/quality.md section A)."""

import numpy as np
import pytest

from simulate.optics import fresnel
from simulate.optics.fresnel import fresnel_unpolarized, refracted_cos

INDEX_PAIRS = [(1.0, 1.33), (1.0, 1.5), (1.0, 1.557), (1.0, 2.7), (1.557, 1.0), (1.33, 1.0), (2.7, 1.557)]


@pytest.mark.parametrize("n1,n2", INDEX_PAIRS)
def test_normal_incidence(n1, n2):
    expected = ((n2 - n1) / (n2 + n1)) ** 2
    assert fresnel.reflectance(0.0, n1, n2) == pytest.approx(expected, rel=1e-13)
    assert fresnel_unpolarized(1.0, n1, n2) == pytest.approx(expected, rel=1e-13)


def test_published_value_glass_45_degrees():
    # worked by hand for n = 1.5 at 45 deg: cos_t = sqrt(1 - 0.5 / 2.25) = 0.881917,
    # r_s = (0.707107 - 1.322876) / (0.707107 + 1.322876) = -0.303337,
    # r_p = (1.060660 - 0.881917) / (1.060660 + 0.881917) = 0.092010
    th = np.radians(45.0)
    assert float(fresnel.reflectance_s(th, 1.0, 1.5)) == pytest.approx(0.09202, abs=5e-5)
    assert float(fresnel.reflectance_p(th, 1.0, 1.5)) == pytest.approx(0.00847, abs=5e-5)


@pytest.mark.parametrize("n1,n2", INDEX_PAIRS)
def test_p_reflectance_vanishes_at_brewster(n1, n2):
    theta_b = np.arctan(n2 / n1)
    assert float(fresnel.reflectance_p(theta_b, n1, n2)) < 1e-28
    # and is positive on either side
    assert float(fresnel.reflectance_p(theta_b * 0.9, n1, n2)) > 1e-6
    assert float(fresnel.reflectance_p(min(theta_b * 1.05, np.pi / 2), n1, n2)) > 1e-6


@pytest.mark.parametrize("n1,n2", [(1.557, 1.0), (1.33, 1.0), (2.7, 1.557)])
def test_total_internal_reflection(n1, n2):
    theta_c = np.arcsin(n2 / n1)
    beyond = np.linspace(theta_c + 1e-9, np.pi / 2, 50)
    np.testing.assert_array_equal(fresnel.reflectance(beyond, n1, n2), 1.0)
    np.testing.assert_array_equal(fresnel.transmittance(beyond, n1, n2), 0.0)
    for th in beyond:
        assert fresnel_unpolarized(np.cos(th), n1, n2) == 1.0
        assert refracted_cos(np.cos(th), n1, n2) == -1.0
    below = theta_c - 1e-3
    assert float(fresnel.reflectance(below, n1, n2)) < 1.0


@pytest.mark.parametrize("n1,n2", INDEX_PAIRS)
def test_energy_conservation_from_transmission_amplitudes(n1, n2):
    """R + T = 1 with T built independently from the Fresnel transmission amplitudes."""
    theta_c = np.arcsin(min(1.0, n2 / n1))
    th = np.linspace(0.0, theta_c * (1 - 1e-6), 200)
    ci = np.cos(th)
    ct = np.sqrt(1 - (n1 / n2 * np.sin(th)) ** 2)
    ratio = n2 * ct / (n1 * ci)
    t_s = 2 * n1 * ci / (n1 * ci + n2 * ct)
    t_p = 2 * n1 * ci / (n2 * ci + n1 * ct)
    np.testing.assert_allclose(fresnel.reflectance_s(th, n1, n2) + ratio * t_s**2, 1.0, atol=1e-13)
    np.testing.assert_allclose(fresnel.reflectance_p(th, n1, n2) + ratio * t_p**2, 1.0, atol=1e-13)
    np.testing.assert_allclose(fresnel.transmittance(th, n1, n2), 0.5 * ratio * (t_s**2 + t_p**2), atol=1e-13)
    np.testing.assert_allclose(fresnel.reflectance(th, n1, n2) + fresnel.transmittance(th, n1, n2), 1.0, atol=1e-15)


@pytest.mark.parametrize("n1,n2", INDEX_PAIRS + [(1.5, 1.5)])
def test_njit_scalar_equals_vectorised(n1, n2):
    cosines = np.concatenate(([0.0, 1.0, 1e-12, 1 - 1e-12], np.linspace(0, 1, 101)))
    vec = fresnel.reflectance_from_cos(cosines, n1, n2)
    via_angles = fresnel.reflectance(np.arccos(cosines), n1, n2)
    for c, v, a in zip(cosines, vec, via_angles, strict=True):
        s = fresnel_unpolarized(c, n1, n2)
        assert s == pytest.approx(v, abs=1e-14)
        assert s == pytest.approx(a, abs=1e-12)


@pytest.mark.parametrize("n1,n2", [(1.0, 1.557), (1.557, 1.0), (1.0, 2.7)])
def test_snell_law(n1, n2):
    theta_c = np.arcsin(min(1.0, n2 / n1))
    th = np.linspace(0.0, theta_c * (1 - 1e-9), 100)
    tt = fresnel.snell(th, n1, n2)
    np.testing.assert_allclose(n1 * np.sin(th), n2 * np.sin(tt), atol=1e-12)
    for a, b in zip(th, tt, strict=True):
        assert refracted_cos(np.cos(a), n1, n2) == pytest.approx(np.cos(b), abs=1e-10)


def test_snell_tir_is_an_error_or_an_explicit_nan():
    th = np.radians([10.0, 60.0])
    with pytest.raises(ValueError, match="total internal reflection"):
        fresnel.snell(th, 1.557, 1.0)
    out = fresnel.snell(th, 1.557, 1.0, on_tir="nan")
    assert np.isfinite(out[0]) and np.isnan(out[1])


def test_no_interface_and_grazing():
    th = np.radians([0.0, 30.0, 89.99, 90.0])
    np.testing.assert_array_equal(fresnel.reflectance(th, 1.5, 1.5), 0.0)
    np.testing.assert_allclose(fresnel.snell(th, 1.5, 1.5), th, atol=1e-15)
    assert fresnel_unpolarized(0.0, 1.5, 1.5) == 0.0
    assert refracted_cos(0.0, 1.5, 1.5) == 0.0
    # grazing incidence on a denser medium reflects everything
    assert float(fresnel.reflectance(np.pi / 2, 1.0, 1.557)) == 1.0
    assert fresnel_unpolarized(0.0, 1.0, 1.557) == 1.0
    assert refracted_cos(0.0, 1.0, 1.557) == pytest.approx(np.sqrt(1 - 1 / 1.557**2), rel=1e-14)


def test_vectorised_shapes_and_input_errors():
    th = np.zeros((3, 4))
    n2 = np.linspace(1.1, 2.0, 4)
    assert fresnel.reflectance(th, 1.0, n2).shape == (3, 4)
    with pytest.raises(ValueError, match=r"\[0, pi/2\]"):
        fresnel.reflectance(np.radians(95.0), 1.0, 1.5)
    with pytest.raises(ValueError, match="> 0"):
        fresnel.reflectance(0.1, 1.0, -1.5)
    with pytest.raises(ValueError, match="real"):
        fresnel.reflectance(0.1, 1.0, 1.5 - 0.1j)


def test_compiled_kernels_set_their_own_fastmath_flags():
    # numba compiles a callee that has no flags of its own with the flags of its first caller (the
    # fastmath Monte Carlo kernel or a Python call) and caches that flavour: the scalar kernels
    # shared by both kinds of caller must pin theirs, or their rounding depends on the call order
    for fn in (fresnel_unpolarized, refracted_cos):
        assert fn.targetoptions.get("fastmath") is False, fn.__name__
