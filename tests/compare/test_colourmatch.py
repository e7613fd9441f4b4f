"""Colour match against colour-science computed directly here (not through gonio.data.colour)."""

from __future__ import annotations

import colour
import numpy as np
import pytest

from compare.colourmatch import luminance_weights
from compare.comparison import compare_datasets
from gonio.data.colour import hue_difference, spectrum_colour

CMFS = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"]
D65 = colour.SDS_ILLUMINANTS["D65"]


def independent(wl, beta):
    """(h, s, v, blue/red, green/red, Y) straight from colour-science, linear sRGB."""
    sd = colour.SpectralDistribution(dict(zip(np.asarray(wl, float), np.asarray(beta, float), strict=True)))
    with colour.utilities.suppress_warnings(colour_runtime_warnings=True):
        xyz = colour.sd_to_XYZ(sd, CMFS, D65) / 100.0
    rgb = colour.XYZ_to_RGB(xyz, colour.RGB_COLOURSPACES["sRGB"])
    h, s, v = colour.RGB_to_HSV(rgb)
    return dict(h=h, s=s, v=v, blue_red=rgb[2] / rgb[0], green_red=rgb[1] / rgb[0], Y=xyz[1])


def flat_grey(wl):
    return 0.5 + 0.0 * wl


def red_step(wl):
    return np.where(wl >= 600.0, 0.7, 0.05)


def _angle_independent(h, spectrum, **kw):
    """A dataset whose spectrum is the same at every geometry (so at the colour geometry too)."""
    return h.in_plane_table(lambda ti, s, wl: spectrum(wl), **kw)


@pytest.mark.parametrize("meas_fn, sim_fn", [(red_step, flat_grey), (flat_grey, red_step)])
def test_hsv_and_ratios_match_colour_science(h, meas_fn, sim_fn):
    wl = h.WAVELENGTHS
    measured = h.dataset(_angle_independent(h, meas_fn))
    sim = h.dataset(_angle_independent(h, lambda w: 3.0 * sim_fn(w)), kind="simulated",
                    name="sim")
    c = compare_datasets(measured, [sim]).metrics()["colour"]
    exp_m = independent(wl, meas_fn(wl))
    for key in ("h", "s", "v", "blue_red", "green_red"):
        assert c["measured"][key] == pytest.approx(exp_m[key], rel=1e-9, abs=1e-12), key
    # the simulation is scaled by k_Y = Y[measured normal] / Y[simulated normal]
    exp_s = independent(wl, sim_fn(wl))
    k_y = exp_m["Y"] / (3.0 * exp_s["Y"])
    assert c["sim"]["v"] == pytest.approx(exp_s["v"] * 3.0 * k_y, rel=1e-9)
    for key in ("h", "s", "blue_red", "green_red"):
        assert c["sim"][key] == pytest.approx(exp_s[key], rel=1e-9, abs=1e-12), key
    assert c["sim"]["ds"] == pytest.approx(exp_s["s"] - exp_m["s"], abs=1e-12)
    assert c["sim"]["dv"] == pytest.approx(exp_s["v"] * 3.0 * k_y - exp_m["v"], abs=1e-12)


def test_known_values_of_grey_and_red_step(h):
    """Plain facts, independent of any implementation: grey has S ~ 0 and ratios ~ 1 (D65 white
    is RGB (1, 1, 1) to the rounding of the sRGB matrix); the red step is red (H ~ 0)."""
    wl = h.WAVELENGTHS
    grey = spectrum_colour(wl, flat_grey(wl))
    assert grey.s < 1e-3 and grey.v == pytest.approx(0.5, abs=1e-3)
    assert grey.blue_red == pytest.approx(1.0, abs=1e-3)
    assert grey.green_red == pytest.approx(1.0, abs=1e-3)
    red = independent(wl, red_step(wl))
    assert min(red["h"], 1 - red["h"]) < 0.03 and red["s"] > 0.8


def test_hue_difference_wraps_around_the_circle():
    assert float(hue_difference(0.98, 0.02)) == pytest.approx(0.04, abs=1e-12)
    assert float(hue_difference(0.02, 0.98)) == pytest.approx(-0.04, abs=1e-12)


def test_colour_match_hue_difference_wraps(h):
    """Measured hue just below 1, simulated just above 0: dh is small, not ~ -0.97."""
    wl = h.WAVELENGTHS

    def purple_red(w):
        return 0.04 + 0.6 * (w >= 610) + 0.05 * (w <= 470)

    def orange_red(w):
        return 0.04 + 0.6 * (w >= 600) + 0.03 * ((w >= 540) & (w < 600))

    hm, hs = independent(wl, purple_red(wl))["h"], independent(wl, orange_red(wl))["h"]
    assert hm > 0.9 and hs < 0.1  # the premise of the test
    measured = h.dataset(_angle_independent(h, purple_red))
    sim = h.dataset(_angle_independent(h, orange_red), kind="simulated", name="sim")
    dh = compare_datasets(measured, [sim]).metrics()["colour"]["sim"]["dh"]
    expected = hs + 1.0 - hm
    assert 0 < expected < 0.2
    assert dh == pytest.approx(expected, abs=1e-9)


@pytest.mark.parametrize("wl", [np.arange(390.0, 711.0, 10.0), np.arange(400.0, 701.0, 10.0),
                                np.arange(380.0, 781.0, 5.0)])
def test_luminance_weights_reproduce_spectrum_colour(wl):
    rng = np.random.default_rng(11)
    beta = rng.uniform(0.0, 1.0, wl.size)
    assert luminance_weights(wl) @ beta == pytest.approx(independent(wl, beta)["Y"], rel=1e-9)
    assert luminance_weights(wl).sum() == pytest.approx(1.0, abs=1e-3)


def test_colour_geometry_is_the_shared_one_closest_to_normal(h):
    measured = h.dataset(h.in_plane_table(h.red_lobe))
    full = h.dataset(h.in_plane_table(h.red_lobe), kind="simulated", name="full")
    coarse = h.dataset(h.in_plane_table(h.red_lobe, s_grid=np.array([-40, -20, -15, 20, 40, 60.0])),
                       kind="simulated", name="coarse")
    g1 = compare_datasets(measured, [full]).colour.geometry
    assert (g1["theta_i"], g1["theta_o"], g1["phi_o"], g1["s"]) == (0.0, 10.0, 0.0, -10.0)
    g2 = compare_datasets(measured, [full, coarse]).colour.geometry
    assert (g2["theta_i"], g2["theta_o"], g2["phi_o"], g2["s"]) == (0.0, 20.0, 0.0, -20.0)


def test_a_colour_that_cannot_be_computed_is_a_compare_error_naming_the_dataset():
    import numpy as np

    from compare.colourmatch import colour_of
    from compare.errors import CompareError

    wl = np.arange(390.0, 711.0, 10.0)
    with pytest.raises(CompareError, match="no colour for simulated dataset 'x': the colour of "
                                           "this spectrum overflows"):
        colour_of(wl, np.full(wl.size, 1e308), "D65", "simulated dataset 'x'")
