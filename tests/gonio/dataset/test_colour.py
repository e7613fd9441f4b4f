"""Colour of spectra: checked against colour-science called directly, step by step."""

from __future__ import annotations

import colour
import numpy as np
import pytest

from gonio.colour import hue_difference, spectrum_colour

WL = np.arange(390.0, 711.0, 10.0)
OBS = "CIE 1931 2 Degree Standard Observer"


def reference(beta, illuminant="D65"):
    sd = colour.SpectralDistribution(dict(zip(WL, beta)))
    xyz = colour.sd_to_XYZ(sd, colour.MSDS_CMFS[OBS], colour.SDS_ILLUMINANTS[illuminant]) / 100
    rgb = colour.XYZ_to_RGB(xyz, colour.RGB_COLOURSPACES["sRGB"],
                            illuminant=colour.CCS_ILLUMINANTS[OBS][illuminant])
    return rgb, colour.RGB_to_HSV(rgb)


def test_ideal_white_is_rgb_one():
    c = spectrum_colour(WL, np.ones_like(WL))
    np.testing.assert_allclose(c.rgb, 1.0, atol=2e-4)
    assert c.v == pytest.approx(1.0, abs=2e-4) and c.s < 3e-4


@pytest.mark.parametrize("level", [0.05, 0.5, 0.9])
def test_flat_grey(level):
    c = spectrum_colour(WL, np.full_like(WL, level))
    rgb, hsv = reference(np.full_like(WL, level))
    np.testing.assert_allclose(c.rgb, rgb, rtol=1e-12)
    assert c.v == pytest.approx(level, rel=3e-4)
    assert c.s == pytest.approx(hsv[1], abs=1e-12) and c.s < 3e-4
    assert c.blue_red == pytest.approx(1.0, abs=3e-4) and c.green_red == pytest.approx(1.0, abs=3e-4)


def test_red_step_spectrum():
    beta = np.where(WL >= 600.0, 0.8, 0.02)
    c = spectrum_colour(WL, beta)
    rgb, hsv = reference(beta)
    assert (c.h, c.s, c.v) == pytest.approx(tuple(hsv), abs=1e-12)
    assert c.blue_red == pytest.approx(rgb[2] / rgb[0], rel=1e-12)
    assert c.green_red == pytest.approx(rgb[1] / rgb[0], rel=1e-12)
    # a red: hue near 0 (or 1), strongly saturated, blue and green far below red
    assert min(c.h, 1 - c.h) < 0.05 and c.s > 0.9 and c.green_red < 0.1


def test_other_illuminant_and_bad_input():
    beta = np.linspace(0.1, 0.6, WL.size)
    c = spectrum_colour(WL, beta, illuminant="A")
    rgb, _ = reference(beta, "A") if "A" in colour.CCS_ILLUMINANTS[OBS] else (None, None)
    np.testing.assert_allclose(c.rgb, rgb, rtol=1e-12)
    with pytest.raises(ValueError, match="unknown illuminant"):
        spectrum_colour(WL, beta, illuminant="nope")
    with pytest.raises(ValueError, match="NaN"):
        spectrum_colour(WL, np.full_like(WL, np.nan))


def test_hue_difference_wraps():
    assert hue_difference(0.98, 0.02) == pytest.approx(0.04)
    assert hue_difference(0.02, 0.98) == pytest.approx(-0.04)
    assert hue_difference(0.25, 0.5) == pytest.approx(0.25)
    np.testing.assert_allclose(hue_difference([0.1, 0.9], [0.9, 0.1]), [-0.2, 0.2])


def test_overflowing_spectrum_is_a_clear_error_not_nan():
    with pytest.raises(ValueError, match="colour of this spectrum overflows .*1e\\+308"):
        spectrum_colour(WL, np.full_like(WL, 1e308))
