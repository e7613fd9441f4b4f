"""The normal/normal estimate and the normalisation factor (compare.normalise)."""

from __future__ import annotations

import numpy as np
import pytest

from compare.errors import CompareError
from compare.normalise import estimate_normal_value

WL = np.array([450.0, 550.0, 650.0])


def smooth_beta(theta_i, s, wl):
    """An asymmetric smooth curve whose normal value is exactly 0.3 + 0.5 * (wl / 550)."""
    amp = 0.5 * (np.asarray(wl) / 550.0)
    return 0.3 + amp * np.exp(-(np.asarray(s) / 35.0) ** 2) + 0.002 * np.asarray(s)


def test_estimate_recovers_analytic_value_within_stated_error(h):
    ds = h.dataset(h.in_plane_table(smooth_beta, incidence=(0.0,), wavelengths=WL))
    nv = estimate_normal_value(ds)
    truth = 0.3 + 0.5 * WL / 550.0
    assert nv.how == "estimated"
    assert nv.s_used == (-20.0, -10.0, 10.0, 20.0)
    err = np.abs(nv.value - truth)
    assert np.all(err <= nv.u)
    # the estimate is informative: much better than the nearest point and than its own bound
    assert np.all(err < 0.3 * nv.u_model)
    assert np.all(np.abs(smooth_beta(0, 10.0, WL) - truth) > 2 * err)


def test_estimate_with_noise_within_three_standard_uncertainties(h):
    rng = np.random.default_rng(20261122)
    u = 0.004
    table = h.in_plane_table(smooth_beta, incidence=(0.0,), wavelengths=np.arange(400.0, 701.0, 10),
                           u_fn=lambda b: u + 0 * b)
    table["beta"] = table["beta"] + rng.normal(0.0, u, len(table))
    nv = estimate_normal_value(h.dataset(table))
    truth = 0.3 + 0.5 * nv.wavelength_nm / 550.0
    z = (nv.value - truth) / nv.u
    assert np.all(np.abs(z) < 3.0)
    # u_data is the propagation of u through the quadratic intercept weights: for s = +-10, +-20
    # (unweighted LSQ) the weights are (-1/6, 2/3, 2/3, -1/6) -> u * sqrt(1/36*2 + 4/9*2)
    np.testing.assert_allclose(nv.u_data, u * np.sqrt(2 / 36 + 8 / 9), rtol=1e-12)


def test_exactly_quadratic_curve_is_exact_and_model_term_is_linear_error(h):
    ds = h.dataset(h.in_plane_table(lambda ti, s, wl: 0.7 - 2e-4 * s**2 + 1e-3 * s,
                                incidence=(0.0,), wavelengths=WL))
    nv = estimate_normal_value(ds)
    np.testing.assert_allclose(nv.value, 0.7, rtol=0, atol=1e-12)
    # linear interpolation between s = -10 and 10 gives 0.7 - 2e-4 * 100
    np.testing.assert_allclose(nv.u_model, 0.02, rtol=1e-9)


def test_measured_normal_point_is_used_as_is(h):
    table = h.in_plane_table(smooth_beta, incidence=(0.0,), wavelengths=WL, extra_s=(0.0,))
    table.loc[table["theta_o"] == 0.0, "beta"] = 0.123
    table.loc[table["theta_o"] == 0.0, "u_beta"] = 0.004
    nv = estimate_normal_value(h.dataset(table))
    assert nv.how == "measured"
    np.testing.assert_array_equal(nv.value, 0.123)
    np.testing.assert_array_equal(nv.u, 0.004)


@pytest.mark.parametrize("s_grid, side", [
    (np.array([10.0, 20.0, 30.0, 40.0, -30.0, -40.0]), "source side s < 0: []"),
    (np.array([-20.0, -10.0, 30.0, 40.0]), "mirror side s > 0: []"),
    (np.array([-10.0, 10.0, 40.0]), "3 in all"),
])
def test_refuses_without_neighbours_on_both_sides(h, s_grid, side):
    ds = h.dataset(h.in_plane_table(smooth_beta, incidence=(0.0,), s_grid=s_grid, wavelengths=WL),
                 name="lopsided")
    with pytest.raises(CompareError) as info:
        estimate_normal_value(ds)
    message = str(info.value)
    assert "'lopsided'" in message and "beta(0, 0)" in message and "BOTH sides" in message
    assert side in message


def test_refuses_without_normal_incidence(h):
    ds = h.dataset(h.in_plane_table(smooth_beta, incidence=(30.0,), wavelengths=WL), name="oblique")
    with pytest.raises(CompareError, match="'oblique'.*no in-plane points at normal incidence"):
        estimate_normal_value(ds)


@pytest.mark.parametrize("level", [0.0, -0.01])
def test_refuses_zero_or_negative_normal_value(h, level):
    ds = h.dataset(h.in_plane_table(lambda ti, s, wl: level + 0 * s, incidence=(0.0,),
                                wavelengths=WL), name="dark")
    with pytest.raises(CompareError, match=r"'dark'.*estimated normal/normal value .* is "
                                           r"-?0\.?0?1?; it must be a positive"):
        estimate_normal_value(ds)


def test_refuses_zero_measured_normal_point(h):
    table = h.in_plane_table(smooth_beta, incidence=(0.0,), wavelengths=WL, extra_s=(0.0,))
    table.loc[table["theta_o"] == 0.0, "beta"] = 0.0
    with pytest.raises(CompareError, match="measured normal/normal value .* is 0"):
        estimate_normal_value(h.dataset(table, kind="simulated", name="zero"))


def test_window_is_respected(h):
    # with a 10-degree window only s = +-10 remain: fewer than three points -> refused
    ds = h.dataset(h.in_plane_table(smooth_beta, incidence=(0.0,), wavelengths=WL))
    with pytest.raises(CompareError, match=r"\|s\| <= 10 deg"):
        estimate_normal_value(ds, window_deg=10.0)
    assert estimate_normal_value(ds, window_deg=30.0).s_used == (-30.0, -20.0, -10.0, 10.0,
                                                                   20.0, 30.0)
