"""The real fiber model through the fabric layer: red-cotton colour, shared colour, albedo <= 1.

These tests need the fiber Monte Carlo (:func:`simulate.fiber.volume_brdf`); they skip, saying
why, on a build where it raises ``NotImplementedError``. Monte Carlo comparisons use fixed seeds
and tolerances of a few computed standard errors (colour uncertainties are propagated from the
spectra's standard errors through the colour transform by its Jacobian).
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from gonio.colour import hue_difference, spectrum_colour
from simulate import fabric as fab
from simulate import fiber as fiber_mod
from simulate import microfacet
from simulate.config import load_config

WL = np.arange(390.0, 710.0 + 1e-9, 10.0)


@pytest.fixture(scope="module")
def red_cotton():
    cfg = load_config("red-cotton")
    fiber = cfg.fiber(WL)
    try:
        fiber_mod.volume_brdf(fiber, np.array([[0.0, 0.0, 1.0]]), np.array([[0.0, 0.0, 1.0]]),
                              np.array([600.0]), target_rel_err=0.5, max_photons=2000)
    except NotImplementedError:
        pytest.skip("the fiber Monte Carlo (simulate.fiber.volume_brdf) is not in this build")
    return cfg, fiber


@pytest.fixture(scope="module")
def rho_d(red_cotton):
    _, fiber = red_cotton
    return fiber_mod.normal_albedo(fiber, WL, target_rel_err=0.01, seed=11)


def _colour_figures(spectrum):
    c = spectrum_colour(WL, spectrum)
    return np.array([c.h, c.s, c.blue_red, c.green_red])


def _colour_uncertainty(spectrum, u_spectrum):
    """Standard errors of (H, S, B/R, G/R) by first-order propagation (central differences)."""
    base = np.asarray(spectrum, float)
    jac = np.empty((4, base.size))
    for j in range(base.size):
        h = max(1e-4 * abs(base[j]), 1e-7)
        up, dn = base.copy(), base.copy()
        up[j] += h
        dn[j] -= h
        d = _colour_figures(up) - _colour_figures(dn)
        d[0] = hue_difference(_colour_figures(dn)[0], _colour_figures(up)[0])
        jac[:, j] = d / (2 * h)
    return np.sqrt((jac ** 2) @ (np.asarray(u_spectrum, float) ** 2))


def test_red_cotton_colour_at_normal_incidence_is_in_the_published_range(rho_d):
    rho, u_rho = rho_d
    assert np.all(u_rho <= 0.02 * rho + 1e-6)  # the achieved error is what was asked (1%, slack 2x)
    h, s, b_r, g_r = _colour_figures(rho)
    # published (PHYSICS.md section 8): H 0.97-0.99, S ~ 0.99, BLUE/RED 0.05-0.25, GREEN/RED 0.01-0.017
    assert 0.97 <= h <= 0.99, h
    assert 0.98 <= s <= 1.0, s
    assert 0.05 <= b_r <= 0.25, b_r
    assert 0.01 <= g_r <= 0.017, g_r


def test_classic_and_summation_share_the_normal_incidence_colour(red_cotton, rho_d):
    _, fiber = red_cotton
    rho, u_rho = rho_d
    albedo, u_albedo, _ = fab.summation_albedo(fiber, 0.0, WL, n_theta=10, n_phi=20, surface=False,
                                               target_rel_err=0.01, seed=12)
    a = _colour_figures(rho)
    b = _colour_figures(albedo)
    u = np.hypot(_colour_uncertainty(rho, u_rho), _colour_uncertainty(albedo, u_albedo))
    diff = b - a
    diff[0] = hue_difference(a[0], b[0])
    # hue and saturation agree within 4 combined standard errors
    assert abs(diff[0]) <= 4 * u[0], (diff, u)
    assert abs(diff[1]) <= 4 * u[1], (diff, u)


@pytest.mark.parametrize("theta_i", [0.0, 30.0, 60.0, 85.0])
def test_fabric_albedo_at_most_one(red_cotton, rho_d, theta_i):
    _, fiber = red_cotton
    wl = WL[::4]  # 390 .. 710 every 40 nm: includes the bright red end
    albedo, u, info = fab.summation_albedo(fiber, theta_i, wl, n_theta=6, n_phi=12,
                                           target_rel_err=0.03, seed=13)
    assert np.all(np.isfinite(albedo)) and np.all(albedo > 0)
    assert np.all(albedo <= 1.0), albedo
    rho, _ = rho_d
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # grazing-angle domain warning of Cook-Torrance
        a_ct = float(microfacet.directional_albedo(np.radians(theta_i), fiber.roughness, fiber.n_host))
    assert np.all(rho + a_ct <= 1.0)


def test_classic_albedo_at_most_one_up_to_grazing(red_cotton, rho_d):
    _, fiber = red_cotton
    rho, _ = rho_d
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        a_ct = microfacet.directional_albedo(np.radians(np.arange(0.0, 90.0, 1.0)), fiber.roughness,
                                             fiber.n_host)
    assert float(rho.max() + a_ct.max()) <= 1.0


def test_real_summation_dataset_small_plan(red_cotton, tmp_path):
    from gonio.dataset import read_dataset, write_dataset
    from gonio.plan import parse_plan
    from simulate.virtual import fabric_dataset

    cfg, _ = red_cotton
    plan = parse_plan('[sample]\nname = "x"\n[wavelengths]\nlist_nm = [450, 550, 650]\n'
                      '[geometry]\nincidence_deg = [0, 45]\nin_plane_deg = [-30, 0, 30]\n', "tiny.toml")
    ds = fabric_dataset(cfg, plan, "summation", target_rel_err=0.05, seed=3)
    write_dataset(ds, tmp_path / "d")
    t = read_dataset(tmp_path / "d").table
    assert len(t) == len(plan.geometries()) * 3
    assert np.all(t["beta"] > 0) and np.all(np.isfinite(t["u_beta"]))
    assert ds.meta["provenance"]["photons"] > 0
    # red is brighter than green at every geometry (the dye)
    red = t[t["wavelength_nm"] == 650]["beta"].to_numpy()
    green = t[t["wavelength_nm"] == 550]["beta"].to_numpy()
    assert np.all(red > green)
