"""Colour of spectra, checked against published numbers (not against colour-science's own chain).

References for the constants below:

- CIE 015:2018 Colorimetry, Table 5 (white points, CIE 1931 2 deg): D65 XYZ = (95.047, 100,
  108.883); A XYZ = (109.850, 100, 35.585).
- CIE 1931 2 deg spectral locus (CIE 015:2018 Table 1 / CIE 018): chromaticity (x, y) of
  monochromatic light, e.g. 550 nm -> (0.30160, 0.69231).
- IEC 61966-2-1:1999 (sRGB): the XYZ -> linear RGB matrix with 4 decimals and the transfer
  function; D65 white -> RGB (1, 1, 1).
- HSV: A. R. Smith, "Color gamut transform pairs", SIGGRAPH 1978 (V = max, S = (max - min) / max,
  H in turns); Python's ``colorsys`` implements it independently of colour-science.
- The red-cotton table (docs/physics.md section 8): H 0.98, S 0.99, V 0.8, BLUE/RED 0.08,
  GREEN/RED 0.011 on LINEAR sRGB.
"""

from __future__ import annotations

import colorsys

import numpy as np
import pytest

from gonio.data.colour import display_srgb, hue_difference, spectra_srgb, spectrum_colour

WL = np.arange(390.0, 711.0, 10.0)
WL_1NM = np.arange(360.0, 831.0, 1.0)

#: IEC 61966-2-1 XYZ (D65, Y = 1 white) -> linear sRGB.
SRGB_MATRIX = np.array([[3.2406, -1.5372, -0.4986],
                        [-0.9689, 1.8758, 0.0415],
                        [0.0557, -0.2040, 1.0570]])


@pytest.mark.parametrize("illuminant, published", [("D65", (95.047, 100.0, 108.883)),
                                                   ("A", (109.850, 100.0, 35.585))])
def test_perfect_white_has_the_published_white_point(illuminant, published):
    c = spectrum_colour(WL_1NM, np.ones_like(WL_1NM), illuminant=illuminant)
    # the CIE rounds to 3 decimals; colour-science's 1-nm tables reproduce them to <0.01
    np.testing.assert_allclose(100 * np.array(c.xyz), published, atol=0.01)


@pytest.mark.parametrize("wavelength_nm, published_xy", [
    (450.0, (0.15664, 0.01771)), (550.0, (0.30160, 0.69231)),
    (600.0, (0.62704, 0.37249)), (650.0, (0.72599, 0.27401))])
def test_monochromatic_light_lies_on_the_published_spectral_locus(wavelength_nm, published_xy):
    wl = np.arange(wavelength_nm - 10, wavelength_nm + 10.5, 1.0)
    x, y, z = spectrum_colour(wl, (np.abs(wl - wavelength_nm) < 0.5).astype(float)).xyz
    np.testing.assert_allclose((x / (x + y + z), y / (x + y + z)), published_xy, atol=5e-5)


def test_perfect_white_is_rgb_one_and_grey_scales_linearly():
    c = spectrum_colour(WL, np.ones_like(WL))
    # IEC 61966-2-1: D65 white is (1, 1, 1); the 4-decimal matrix rounds at ~2e-4
    np.testing.assert_allclose(c.rgb, 1.0, atol=2e-4)
    assert c.v == pytest.approx(1.0, abs=2e-4) and c.s < 3e-4
    for level in (0.05, 0.5, 0.9):
        g = spectrum_colour(WL, np.full_like(WL, level))
        np.testing.assert_allclose(g.rgb, level * np.asarray(c.rgb), rtol=1e-9)
        assert g.blue_red == pytest.approx(1.0, abs=3e-4)
        assert g.green_red == pytest.approx(1.0, abs=3e-4)


@pytest.mark.parametrize("spectrum", [
    np.where(WL >= 600.0, 0.8, 0.02),                       # a red step
    0.25 + 0.3 * np.exp(-0.5 * ((WL - 530.0) / 30.0) ** 2), # a green band
    np.linspace(0.6, 0.1, WL.size),                          # a bluish slope
])
def test_rgb_is_the_published_srgb_matrix_and_hsv_is_smiths(spectrum):
    c = spectrum_colour(WL, spectrum)
    np.testing.assert_allclose(c.rgb, SRGB_MATRIX @ np.asarray(c.xyz), atol=5e-4)
    r, g, b = c.rgb
    h, s, v = colorsys.rgb_to_hsv(r, g, b)
    assert (c.h, c.s, c.v) == pytest.approx((h, s, v), abs=1e-9)
    assert (c.blue_red, c.green_red) == pytest.approx((b / r, g / r), rel=1e-12)


def test_the_published_red_cotton_table_is_consistent_in_linear_srgb_only():
    """H 0.98, S 0.99, V 0.8 with BLUE/RED 0.08 and GREEN/RED 0.011 describe ONE linear colour."""
    rgb_linear = 0.8 * np.array([1.0, 0.011, 0.08])
    h, s, v = colorsys.rgb_to_hsv(*rgb_linear)
    assert v == pytest.approx(0.8) and s == pytest.approx(0.99, abs=0.0015)
    assert 0.975 <= h < 0.995                      # 0.988: 0.98 in the table
    # had the table been gamma-encoded sRGB, those ratios would give S 0.90, not 0.99
    encoded = display_srgb(rgb_linear)
    assert colorsys.rgb_to_hsv(*encoded)[1] == pytest.approx(0.90, abs=0.01)
    # and gonio.data.colour reports the linear figures: a red-dye spectrum of that colour (the mock
    # red cotton's at theta_i = 0, theta_o = 10 deg: 0.913 = Oren-Nayar A x retro factor there,
    # + 0.0093 of neutral gloss) gets them back, where display values would give S ~ 0.90
    wl = np.arange(390.0, 711.0, 10.0)
    red = 0.01 + 0.088 * np.exp(-0.5 * ((wl - 420) / 40) ** 2) + 0.91 / (1 + np.exp(-(wl - 594.7)
                                                                                / 7.1))
    c = spectrum_colour(wl, 0.913 * red + 0.0093)
    assert c.s == pytest.approx(0.99, abs=0.005) and c.green_red == pytest.approx(0.011,
                                                                                  abs=5e-4)
    assert c.blue_red == pytest.approx(0.08, abs=0.005)


def test_display_encoding_is_the_iec_transfer_function():
    x = np.array([0.0, 0.002, 0.0031308, 0.2, 0.5, 1.0])
    expected = np.where(x <= 0.0031308, 12.92 * x, 1.055 * x ** (1 / 2.4) - 0.055)
    np.testing.assert_allclose(display_srgb(x), expected, atol=1e-6)
    assert display_srgb([-0.1, 2.0]).tolist() == [0.0, 1.0]


def test_bad_input_is_refused():
    beta = np.linspace(0.1, 0.6, WL.size)
    with pytest.raises(ValueError, match="unknown illuminant"):
        spectrum_colour(WL, beta, illuminant="nope")
    with pytest.raises(ValueError, match="NaN"):
        spectrum_colour(WL, np.full_like(WL, np.nan))
    with pytest.raises(ValueError, match="strictly increasing"):
        spectrum_colour(WL[::-1], beta)


def test_overflowing_spectrum_is_a_clear_error_not_nan():
    with pytest.raises(ValueError, match="colour of this spectrum overflows .*1e\\+308"):
        spectrum_colour(WL, np.full_like(WL, 1e308))


def test_hue_difference_wraps():
    assert hue_difference(0.98, 0.02) == pytest.approx(0.04)
    assert hue_difference(0.02, 0.98) == pytest.approx(-0.04)
    assert hue_difference(0.25, 0.5) == pytest.approx(0.25)
    np.testing.assert_allclose(hue_difference([0.1, 0.9], [0.9, 0.1]), [-0.2, 0.2])


@pytest.mark.parametrize("wl, illuminant", [(WL, "D65"), (WL, "A"), (np.arange(400.0, 701.0, 20.0), "D65"),
                                            (np.arange(380.0, 781.0, 5.0), "D50")])
def test_many_spectra_at_once_are_each_spectrum_colour(wl, illuminant):
    """spectra_srgb (one matrix per grid) against spectrum_colour called row by row (colour-science's chain)."""
    rng = np.random.default_rng(7)
    betas = np.vstack([rng.uniform(0.0, 1.0, (5, wl.size)), np.full(wl.size, 1e308), np.full(wl.size, np.nan)])
    betas[5, 0] = 0.5                       # not all equal: an overflow whatever the weights
    rgb, hsv = spectra_srgb(wl, betas, illuminant=illuminant)
    assert rgb.shape == hsv.shape == (7, 3)
    for row, beta in enumerate(betas[:5]):
        c = spectrum_colour(wl, beta, illuminant=illuminant)
        np.testing.assert_allclose(rgb[row], c.rgb, rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(hsv[row], (c.h, c.s, c.v), rtol=1e-12, atol=1e-15)
    # where spectrum_colour refuses (an overflow, a NaN), the row is NaN
    for row in (5, 6):
        with pytest.raises(ValueError):
            spectrum_colour(wl, betas[row], illuminant=illuminant)
        assert np.all(np.isnan(rgb[row])) and np.all(np.isnan(hsv[row]))
    with pytest.raises(ValueError, match="spectra of shape"):
        spectra_srgb(wl, betas[:, 1:])
    with pytest.raises(ValueError, match="strictly increasing"):
        spectra_srgb(wl[::-1], betas)
