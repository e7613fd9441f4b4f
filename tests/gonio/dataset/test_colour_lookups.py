"""The colour functions look each illuminant and colour space up once: same numbers, same refusals.

The reference here is colour-science's chain written out with a fresh look-up of every name on every
call (the computation :func:`gonio.data.colour.spectrum_colour` documents); the published numbers are
checked in test_colour.py.
"""

from __future__ import annotations

import re
import warnings

import colour
import numpy as np
import pytest

from gonio.data import colour as gc

OBSERVER = "CIE 1931 2 Degree Standard Observer"
WL = np.arange(390.0, 711.0, 10.0)
SPECTRA = [np.linspace(0.1, 0.6, WL.size),                                   # rising
           0.05 + 0.7 * np.exp(-0.5 * ((WL - 640.0) / 30.0) ** 2),           # red band
           np.full(WL.size, 0.5),                                            # grey
           0.3 + 0.2 * np.sin(WL / 37.0)]                                    # wavy
UNKNOWN = "unknown illuminant 'nope'; use a key of colour.SDS_ILLUMINANTS such as 'D65'"


def _looked_up_every_time(wl, beta, illuminant, space="sRGB"):
    """XYZ, linear RGB in ``space`` and HSV of sRGB, every name looked up in colour-science's mappings."""
    sd = colour.SpectralDistribution(dict(zip(wl.tolist(), beta.tolist(), strict=True)), name="beta")
    with warnings.catch_warnings(), np.errstate(over="ignore", invalid="ignore"):
        warnings.simplefilter("ignore", colour.utilities.ColourRuntimeWarning)
        xyz = colour.sd_to_XYZ(sd, colour.MSDS_CMFS[OBSERVER], colour.SDS_ILLUMINANTS[illuminant]) / 100.0
        white = colour.CCS_ILLUMINANTS[OBSERVER][illuminant]
        srgb = colour.XYZ_to_RGB(xyz, "sRGB", illuminant=white)
        rgb = colour.XYZ_to_RGB(xyz, colour.RGB_COLOURSPACES[space], illuminant=white,
                                chromatic_adaptation_transform="Bradford")
        hsv = colour.RGB_to_HSV(srgb)
    return xyz, srgb, rgb, hsv


@pytest.mark.parametrize("illuminant", ["D65", "A", "D50", "d65"])
def test_results_are_those_of_a_fresh_lookup_bit_for_bit(illuminant):
    for beta in SPECTRA:
        for _ in range(2):  # the first call fills the cache, the second reads it
            xyz, srgb, rgb, hsv = _looked_up_every_time(WL, beta, illuminant, "Adobe RGB (1998)")
            c = gc.spectrum_colour(WL, beta, illuminant=illuminant)
            assert c.xyz == tuple(float(v) for v in xyz)
            assert c.rgb == tuple(float(v) for v in srgb)
            assert (c.h, c.s, c.v) == tuple(float(v) for v in hsv)
            assert c.illuminant == illuminant
            got = gc.spectrum_to_rgb(WL, beta, "linear Adobe RGB (1998)", illuminant=illuminant)
            assert got.tolist() == np.asarray(rgb, dtype=float).tolist()


def test_each_name_is_looked_up_once():
    gc._illuminant_entry.cache_clear()
    for beta in SPECTRA:
        gc.spectrum_colour(WL, beta, illuminant="D50")
    info = gc._illuminant_entry.cache_info()
    assert (info.misses, info.hits) == (1, len(SPECTRA) - 1)


def test_a_bad_name_is_refused_every_time_with_the_same_message():
    beta = SPECTRA[0]
    for _ in range(3):
        with pytest.raises(ValueError, match=f"^{re.escape(UNKNOWN)}$"):
            gc.spectrum_colour(WL, beta, illuminant="nope")
        gc.spectrum_colour(WL, beta)  # a good name in between changes nothing
    with pytest.raises(ValueError, match=f"^{re.escape(UNKNOWN)}$"):
        gc.spectrum_to_rgb(WL, beta, illuminant="nope")
    for bad in (None, ["D65"]):
        with pytest.raises(ValueError, match="unknown illuminant"):
            gc.spectrum_colour(WL, beta, illuminant=bad)
    for _ in range(2):
        with pytest.raises(ValueError, match=r"^unknown colour space 'linear nope'; use \"linear sRGB\""):
            gc.spectrum_to_rgb(WL, beta, "linear nope")
    with pytest.raises(ValueError, match="unknown colour space"):
        gc.colourspace(["sRGB"])
