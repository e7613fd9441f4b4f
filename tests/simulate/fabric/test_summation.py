"""Summation over warp and weft, sample rotation, symmetry reduction, and the classic model.

A fake fiber BRDF with a known analytic form (conftest) makes every frame mapping checkable
exactly: the expected values are written out by hand from docs/physics.md section 6.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from simulate import fabric as fab
from simulate.optics import microfacet
from simulate.optics.fresnel import OpticsDomainWarning

from .conftest import fake_R, fake_rho

WL = np.array([450.0, 550.0, 650.0])


def _R(w_in, w_out):
    return fake_R(w_in, w_out, WL)


def _random_geometries(rng, g, theta_max=85.0):
    theta_i = rng.uniform(0, theta_max, g)
    theta_o = rng.uniform(0, theta_max, g)
    return (theta_i, rng.uniform(0, 360, g), theta_o, rng.uniform(0, 360, g))


def test_weft_matrix_takes_fabric_y_to_the_fiber_axis():
    np.testing.assert_array_equal(fab.M_WEFT @ [0.0, 1.0, 0.0], [1.0, 0.0, 0.0])
    np.testing.assert_array_equal(fab.M_WEFT @ [0.0, 0.0, 1.0], [0.0, 0.0, 1.0])
    np.testing.assert_allclose(fab.M_WEFT @ fab.M_WEFT.T, np.eye(3))
    assert np.linalg.det(fab.M_WEFT) == pytest.approx(1.0)  # a rotation, not a mirror
    np.testing.assert_allclose(fab.rotation_z(-90.0), fab.M_WEFT, atol=1e-15)


def test_summation_equals_the_hand_written_warp_and_weft_sum():
    rng = np.random.default_rng(1)
    ti, pi_, to, po = _random_geometries(rng, 200)
    w_i, w_o = fab.directions_deg(ti, pi_), fab.directions_deg(to, po)
    # weft fiber frame by hand: (x_f, y_f, z_f) = (y, -x, z)
    weft = lambda w: np.stack([w[:, 1], -w[:, 0], w[:, 2]], axis=1)  # noqa: E731
    expected = np.pi / w_i[:, 2:3] * 0.5 * (_R(w_i, w_o) + _R(weft(w_i), weft(w_o)))
    np.testing.assert_allclose(fab.summation_beta(_R, w_i, w_o), expected, rtol=1e-13)


def test_in_plane_incidence_along_the_warp_is_across_the_weft():
    # R_B depending only on the incident component along the fiber axis: w_i in the fabric x-z
    # plane has w_x = sin(theta) along the warp and 0 along the weft fiber.
    def along_axis(w_in, w_out):
        return (w_in[:, 0] ** 2)[:, None] * np.ones((1, 1))

    theta = np.radians([10.0, 30.0, 60.0])
    w_i = np.stack([np.sin(theta), 0 * theta, np.cos(theta)], axis=1)
    w_o = np.tile([0.0, 0.0, 1.0], (3, 1))
    beta = fab.summation_beta(along_axis, w_i, w_o)[:, 0]
    np.testing.assert_allclose(beta, np.pi * 0.5 * np.sin(theta) ** 2 / np.cos(theta), rtol=1e-13)
    # the same incidence in the fabric y-z plane is along the weft fiber: same sum, swapped roles
    w_i_y = np.stack([0 * theta, np.sin(theta), np.cos(theta)], axis=1)
    np.testing.assert_allclose(fab.summation_beta(along_axis, w_i_y, w_o)[:, 0], beta, rtol=1e-13)


def test_sample_rotation_rotates_the_fiber_frames_about_z():
    rng = np.random.default_rng(2)
    ti, pi_, to, po = _random_geometries(rng, 100)
    w_i, w_o = fab.directions_deg(ti, pi_), fab.directions_deg(to, po)
    for rho in (17.0, 90.0, 200.0):
        r = fab.rotation_z(-rho)
        np.testing.assert_allclose(fab.summation_beta(_R, w_i, w_o, rotation_deg=rho),
                                   fab.summation_beta(_R, w_i @ r.T, w_o @ r.T), rtol=1e-12)
    # by 90 deg the warp fiber takes the weft's place; the weft's place is the warp turned by 180
    # deg about z, which the fiber's two mirror symmetries (x and y flipped) leave unchanged
    np.testing.assert_allclose(fab.summation_beta(_R, w_i, w_o, rotation_deg=90.0),
                               fab.summation_beta(_R, w_i, w_o), rtol=1e-12)
    # a BRDF without the mirror symmetry does see the difference
    skew = lambda a, b: (1.0 + 0.5 * a[:, 0] + 0.2 * b[:, 1])[:, None]  # noqa: E731
    assert not np.allclose(fab.summation_beta(skew, w_i, w_o, rotation_deg=90.0),
                           fab.summation_beta(skew, w_i, w_o))
    a_in, a_out, b_in, b_out = fab.fiber_frame_pairs(w_i, w_o, rotation_deg=90.0)
    np.testing.assert_allclose(a_in, w_i @ fab.M_WEFT.T, atol=1e-15)
    np.testing.assert_allclose(b_in, -w_i * [1, 1, -1], atol=1e-15)


def test_canonical_pairs_keep_values_and_land_in_the_quarter():
    rng = np.random.default_rng(3)
    w_in = rng.normal(size=(500, 3))
    w_in /= np.linalg.norm(w_in, axis=1, keepdims=True)
    w_out = rng.normal(size=(500, 3))
    w_out[:, 2] = np.abs(w_out[:, 2])
    w_out /= np.linalg.norm(w_out, axis=1, keepdims=True)
    c_in, c_out = fab.canonical_pairs(w_in, w_out)
    assert np.all(c_in[:, 0] >= 0) and np.all(c_in[:, 1] >= 0)
    np.testing.assert_array_equal(c_in[:, 2], w_in[:, 2])
    np.testing.assert_allclose(np.einsum("ij,ij->i", c_in, c_out), np.einsum("ij,ij->i", w_in, w_out))
    np.testing.assert_allclose(_R(c_in, c_out), _R(w_in, w_out), rtol=1e-13)


def test_table_route_dedupes_and_equals_the_direct_sum():
    from gonio.acquisition.plan import load_plan

    plan = load_plan("red-cotton")
    g = plan.geometries()
    pairs = fab.FiberPairs.from_angles(g["theta_i"], g["phi_i"], g["theta_o"], g["phi_o"])
    assert pairs.n_unique < 2 * len(g)
    assert np.all(pairs.w_in[:, 0] >= 0) and np.all(pairs.w_in[:, 1] >= 0)
    key = np.round(np.hstack([pairs.w_in, pairs.w_out]), 9)
    assert len(np.unique(key, axis=0)) == pairs.n_unique
    R = _R(pairs.w_in, pairs.w_out)
    beta, u = fab.summation_from_table(pairs, R, 0.02 * R)
    w_i = fab.directions_deg(g["theta_i"], g["phi_i"])
    w_o = fab.directions_deg(g["theta_o"], g["phi_o"])
    direct = fab.summation_beta(_R, w_i, w_o)
    np.testing.assert_allclose(beta, direct, rtol=1e-12)
    np.testing.assert_allclose(u, 0.02 * direct, rtol=1e-12)  # correlated bound of equal rel. errors
    # random out-of-plane geometries with a sample rotation too
    rng = np.random.default_rng(4)
    ti, pi_, to, po = _random_geometries(rng, 300)
    with pytest.warns(OpticsDomainWarning, match="incidence beyond 70 deg"):  # some theta_i > 70
        pairs = fab.FiberPairs.from_angles(ti, pi_, to, po, rotation_deg=33.0)
    beta, _ = fab.summation_from_table(pairs, _R(pairs.w_in, pairs.w_out))
    np.testing.assert_allclose(beta, fab.summation_beta(_R, fab.directions_deg(ti, pi_),
                                                        fab.directions_deg(to, po), 33.0), rtol=1e-12)


def test_uncertainty_when_warp_and_weft_share_a_pair():
    # normal incidence, normal observation: both fibers see (z, z), one pair
    pairs = fab.FiberPairs.from_angles([0.0], [0.0], [0.0], [180.0])
    assert pairs.n_unique == 1
    beta, u = fab.summation_from_table(pairs, np.array([[0.2]]), np.array([[0.01]]))
    assert beta[0, 0] == pytest.approx(np.pi * 0.2) and u[0, 0] == pytest.approx(np.pi * 0.01)


def test_grazing_incidence_is_refused():
    with pytest.raises(fab.FabricError, match="theta_i = 90"):
        fab.FiberPairs.from_angles([90.0], [0.0], [10.0], [0.0])


@pytest.mark.parametrize("theta_i", [0.0, 30.0, 60.0, 80.0])
def test_lambertian_fiber_gives_its_albedo(theta_i):
    lam = lambda a, b: np.clip(a[:, 2], 0, None)[:, None] * fake_rho(WL)[None, :] / np.pi  # noqa: E731
    albedo = fab.summation_hemispherical_albedo(lam, theta_i)
    np.testing.assert_allclose(albedo, fake_rho(WL), rtol=1e-12)
    # and beta = rho everywhere
    rng = np.random.default_rng(5)
    _, pi_, to, po = _random_geometries(rng, 50)
    beta = fab.summation_beta(lam, fab.directions_deg(np.full(50, theta_i), pi_), fab.directions_deg(to, po))
    np.testing.assert_allclose(beta, np.broadcast_to(fake_rho(WL), beta.shape), rtol=1e-12)


def test_classic_at_normal_is_rho_plus_the_analytic_specular_peak():
    m, n = 0.35, 1.557
    rho = fake_rho(WL)
    beta = fab.classic_beta(rho, [[0.0, 0.0, 1.0]], [[0.0, 0.0, 1.0]], m, n)
    f0 = ((n - 1) / (n + 1)) ** 2
    # D(0) = 1 / (pi m^2), G = 1, F = F0: pi f_CT = pi D F / 4 = F0 / (4 m^2)
    np.testing.assert_allclose(beta[0], rho + f0 / (4 * m * m), rtol=1e-12)


def test_classic_is_rho_plus_pi_cook_torrance_anywhere():
    rng = np.random.default_rng(6)
    ti, pi_, to, po = _random_geometries(rng, 100, theta_max=80.0)
    w_i, w_o = fab.directions_deg(ti, pi_), fab.directions_deg(to, po)
    rho = fake_rho(WL)
    beta = fab.classic_beta(rho, w_i, w_o, 0.35, 1.557)
    spec = beta - rho[None, :]
    # spectrally flat, reciprocal, non-negative, and the Cook-Torrance of simulate.optics.microfacet
    np.testing.assert_allclose(spec, spec[:, :1] * np.ones((1, WL.size)), rtol=1e-12, atol=1e-15)
    assert np.all(spec >= 0)
    np.testing.assert_allclose(fab.classic_beta(rho, w_o, w_i, 0.35, 1.557), beta, rtol=1e-12)
    np.testing.assert_allclose(spec[:, 0], np.pi * microfacet.cook_torrance(w_i, w_o, 0.35, 1.557),
                               rtol=1e-12, atol=1e-15)


@pytest.mark.parametrize("theta_i", [0.0, 45.0, 75.0, 85.0])
def test_classic_hemispherical_albedo_is_rho_plus_ct_albedo_and_at_most_one(theta_i):
    # Lambert and Cook-Torrance are not energy-coupled: the classic albedo rho_d + A_CT(theta_i)
    # stays <= 1 only while rho_d <= 1 - A_CT (0.70 at 85 deg for m = 0.35); a red fiber's
    # albedo (here up to 0.55) is well inside
    m, n = 0.35, 1.557
    rho = fake_rho(np.array([450.0, 600.0, 710.0]))
    # quadrature of beta/pi cos_o over the hemisphere (u = sin^2 theta_o, midpoints)
    k, nphi = 400, 360
    u = (np.arange(k) + 0.5) / k
    phi = 2 * np.pi * (np.arange(nphi) + 0.5) / nphi
    uu, pp = np.meshgrid(u, phi, indexing="ij")
    st, ct = np.sqrt(uu.ravel()), np.sqrt(1 - uu.ravel())
    w_o = np.stack([st * np.cos(pp.ravel()), st * np.sin(pp.ravel()), ct], axis=1)
    w_i = np.broadcast_to(fab.directions_deg(theta_i, 0.0), w_o.shape)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # grazing outgoing directions near the horizon
        beta = fab.classic_beta(rho, w_i, w_o, m, n)
    albedo = beta.sum(axis=0) / np.pi * (np.pi / (k * nphi))
    a_ct = float(microfacet.directional_albedo(np.radians(theta_i), m, n))
    np.testing.assert_allclose(albedo, rho + a_ct, atol=2e-3)
    assert np.all(rho + a_ct <= 1.0)


@pytest.mark.parametrize("theta_i", [0.0, 45.0, 80.0])
def test_summation_albedo_of_lambert_plus_ct_fiber(fake_fiber, theta_i):
    from simulate.config import load_config

    fiber = load_config("red-cotton").fiber(WL)
    # anisotropic fake: the volume albedo is no longer rho, but the quadrature of the volume
    # term must agree with summation_hemispherical_albedo on a much finer grid
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        albedo, u, info = fab.summation_albedo(fiber, theta_i, WL, n_theta=64, n_phi=128)
    fine = fab.summation_hemispherical_albedo(_R, theta_i, n_theta=256, n_phi=512)
    np.testing.assert_allclose(info["volume"], fine, rtol=2e-3)
    a_ct = float(microfacet.directional_albedo(np.radians(theta_i), 0.35, 1.557))
    assert info["surface"] == pytest.approx(a_ct, abs=2e-3)
    np.testing.assert_allclose(albedo, info["volume"] + info["surface"])
    np.testing.assert_allclose(u, 0.02 * info["volume"], rtol=1e-10)
    assert len(fake_fiber.volume_calls) == 1


@pytest.mark.parametrize("theta", [80.0, 89.0, 89.99])
def test_grazing_geometries_are_finite_and_bounded_below(theta):
    # 1/cos(theta_i) grows near the horizon; R_B ~ cos(theta_in) keeps beta finite
    with pytest.warns(OpticsDomainWarning, match="summation overestimates there"):
        pairs = fab.FiberPairs.from_angles([theta, 10.0], [0.0, 0.0], [30.0, theta], [180.0, 90.0])
    beta, u = fab.summation_from_table(pairs, _R(pairs.w_in, pairs.w_out), 0.01 * _R(pairs.w_in, pairs.w_out))
    assert np.all(np.isfinite(beta)) and np.all(beta >= 0) and np.all(np.isfinite(u))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # Cook-Torrance's grazing-angle domain warning
        classic = fab.classic_beta(fake_rho(WL), fab.directions_deg([theta], [0.0]),
                                   fab.directions_deg([30.0], [180.0]), 0.35, 1.557)
    assert np.all(np.isfinite(classic)) and np.all(classic >= fake_rho(WL))
