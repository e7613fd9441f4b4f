r"""Colour of a radiance-coefficient spectrum: CIE XYZ, linear sRGB, HSV and channel ratios.

docs/physics.md section 7: spectral ``beta`` at one geometry -> CIE XYZ (CIE 1931 2-degree standard
observer, illuminant D65 unless set) -> linear sRGB, so that an ideal white diffuser (``beta = 1``)
is RGB (1, 1, 1) -> HSV and the ratios BLUE/RED and GREEN/RED, all on the LINEAR values (the
published reference table is only self-consistent that way: S = 0.99 goes with GREEN/RED = 0.011).
Gamma-encoded sRGB is for display only (:func:`display_srgb`).

An RGB dataset (channels R, G, B in a named LINEAR colour space) is read directly
(:func:`rgb_colour`): its channels are converted to linear sRGB through CIE XYZ when the space is
not sRGB, then to HSV. A spectrum compared with an RGB measurement is first converted to the
measurement's colour space (:func:`spectrum_to_rgb`: spectrum -> XYZ as above -> the space's RGB,
with the chromatic adaptation of colour-science from the illuminant's white to the space's white).

The computation is colour-science's:

.. math::

    X = k \sum_\lambda \beta(\lambda) S(\lambda) \bar x(\lambda) \Delta\lambda, \quad
    k = 1 / \sum_\lambda S(\lambda) \bar y(\lambda) \Delta\lambda

(``colour.sd_to_XYZ``, ASTM E308 method, divided by 100 so that ``Y = 1`` for ``beta = 1``), then
``colour.XYZ_to_RGB(XYZ, "sRGB", illuminant=D65 white point)`` and ``colour.RGB_to_HSV``. With
illuminant D65 the ideal white diffuser gives RGB (1, 1, 1) to within 2e-4 (the rounding of the
published sRGB matrix). A spectrum measured on 390..710 nm is integrated over its own range (the
observer and the illuminant are trimmed to it by colour-science, and ``k`` is computed over the same
range), so white stays white; colour-science's warning about that trimming is silenced here.

References
----------
CIE 015:2018 Colorimetry, 4th ed.; IEC 61966-2-1:1999 (sRGB); ASTM E308-22; Mansencal et al.,
Colour 0.4.7 (colour-science).
"""

from __future__ import annotations

import functools
import warnings
from dataclasses import dataclass

import numpy as np

__all__ = ["ColourSummary", "check_illuminant", "colourspace", "display_srgb", "hue_difference", "rgb_colour",
           "spectra_srgb", "spectrum_colour", "spectrum_to_rgb"]

OBSERVER = "CIE 1931 2 Degree Standard Observer"


@dataclass(frozen=True)
class ColourSummary:
    """Colour of one spectrum. ``h``, ``s``, ``v`` in [0, 1] from LINEAR sRGB ``rgb``."""

    h: float
    s: float
    v: float
    blue_red: float
    green_red: float
    rgb: tuple[float, float, float]
    xyz: tuple[float, float, float]
    illuminant: str = "D65"

    def as_dict(self) -> dict:
        """The contract's keys (``h``, ``s``, ``v``, ``blue_red``, ``green_red``) plus ``rgb``."""
        return {"h": self.h, "s": self.s, "v": self.v, "blue_red": self.blue_red,
                "green_red": self.green_red, "rgb": list(self.rgb)}


def _ratio(a: float, b: float) -> float:
    return float(a / b) if b > 0 else float("nan")


def spectrum_colour(wavelength_nm, beta, illuminant: str = "D65") -> ColourSummary:
    """Colour summary of the spectrum ``beta(wavelength_nm)`` seen under ``illuminant``.

    Parameters
    ----------
    wavelength_nm : array_like
        Strictly increasing, evenly spaced wavelengths in nm (1, 5, 10 or 20 nm steps for the
        ASTM E308 method; others are interpolated by colour-science).
    beta : array_like
        Radiance coefficient at those wavelengths.
    illuminant : str
        A key of ``colour.SDS_ILLUMINANTS`` (e.g. ``"D65"``, ``"A"``, ``"D50"``).

    Returns
    -------
    ColourSummary
        ``rgb`` is linear sRGB; the ratios are NaN when red is not positive.

    Raises
    ------
    ValueError
        Mismatched or too short inputs, unsorted wavelengths, NaN or infinite values, an
        unknown illuminant, or values so large that XYZ overflows.

    Examples
    --------
    >>> import numpy as np
    >>> c = spectrum_colour(np.arange(390, 711, 10), np.full(33, 0.5))
    >>> round(c.v, 3), round(c.s, 3)
    (0.5, 0.0)
    """
    import colour

    wl = np.asarray(wavelength_nm, dtype=float).ravel()
    values = np.asarray(beta, dtype=float).ravel()
    if wl.size != values.size:
        raise ValueError(f"{wl.size} wavelengths but {values.size} values")
    if wl.size < 2:
        raise ValueError("a colour needs a spectrum of at least two wavelengths")
    if not np.all(np.diff(wl) > 0):
        raise ValueError("wavelengths must be strictly increasing")
    if not np.all(np.isfinite(values)):
        raise ValueError("the spectrum contains NaN or infinite values")
    cmfs, sd_illuminant, white_xy = _illuminant_data(illuminant)
    sd = colour.SpectralDistribution(dict(zip(wl.tolist(), values.tolist(), strict=True)), name="beta")
    with warnings.catch_warnings(), np.errstate(over="ignore", invalid="ignore"):
        warnings.simplefilter("ignore", colour.utilities.ColourRuntimeWarning)
        xyz = colour.sd_to_XYZ(sd, cmfs, sd_illuminant) / 100.0
        rgb = colour.XYZ_to_RGB(xyz, _colourspace("sRGB"), illuminant=white_xy)
        hsv = colour.RGB_to_HSV(rgb)
    if not (np.all(np.isfinite(xyz)) and np.all(np.isfinite(rgb))):
        # finite values whose weighted sum overflows (|beta| ~ 1e308): say so rather than
        # returning NaN
        raise ValueError(f"the colour of this spectrum overflows (largest |beta| "
                         f"{float(np.max(np.abs(values))):.3g}): its CIE XYZ is not finite; "
                         "a radiance coefficient is of order 1")
    r, g, b = (float(x) for x in rgb)
    return ColourSummary(h=float(hsv[0]), s=float(hsv[1]), v=float(hsv[2]),
                         blue_red=_ratio(b, r), green_red=_ratio(g, r), rgb=(r, g, b),
                         xyz=(float(xyz[0]), float(xyz[1]), float(xyz[2])), illuminant=illuminant)


def spectra_srgb(wavelength_nm, betas, illuminant: str = "D65") -> tuple[np.ndarray, np.ndarray]:
    """Linear sRGB and HSV of many spectra on one wavelength grid: :func:`spectrum_colour` row by row.

    The spectrum-to-XYZ step of colour-science (ASTM E308) is linear in the spectrum, so it is the
    matrix whose column ``j`` is the CIE XYZ of the unit spectrum at wavelength ``j`` (computed
    once per grid and illuminant by :func:`spectrum_colour` itself); XYZ -> linear sRGB -> HSV are
    then colour-science's own calls on all rows at once. The result equals converting each row
    with :func:`spectrum_colour` to the rounding of the sum (about 1e-16 relative).

    Parameters
    ----------
    wavelength_nm : array_like
        The grid (as :func:`spectrum_colour`).
    betas : array_like
        Radiance coefficients, one spectrum per row (shape ``(m, n)`` for ``n`` wavelengths).
    illuminant : str
        A key of ``colour.SDS_ILLUMINANTS``.

    Returns
    -------
    rgb, hsv : ndarray
        Shape ``(m, 3)`` each. A row whose spectrum holds NaN or infinite values, or whose colour
        overflows (where :func:`spectrum_colour` raises), is NaN.

    Raises
    ------
    ValueError
        A grid :func:`spectrum_colour` refuses, rows of another length than the grid, or an unknown
        illuminant.

    Examples
    --------
    >>> import numpy as np
    >>> wl = np.arange(390, 711, 10)
    >>> rgb, hsv = spectra_srgb(wl, [np.full(33, 0.5), np.linspace(0.1, 0.9, 33)])
    >>> c = spectrum_colour(wl, np.linspace(0.1, 0.9, 33))
    >>> bool(np.allclose(rgb[1], c.rgb, rtol=1e-12)), bool(np.isclose(hsv[1, 0], c.h, rtol=1e-12))
    (True, True)
    """
    import colour

    wl = np.asarray(wavelength_nm, dtype=float).ravel()
    values = np.asarray(betas, dtype=float)
    if values.ndim != 2 or values.shape[1] != wl.size:
        raise ValueError(f"{wl.size} wavelengths but spectra of shape {values.shape}")
    weights = _xyz_weights(tuple(wl.tolist()), illuminant)
    _, _, white_xy = _illuminant_data(illuminant)
    finite = np.all(np.isfinite(values), axis=1)
    with warnings.catch_warnings(), np.errstate(over="ignore", invalid="ignore"):
        warnings.simplefilter("ignore", colour.utilities.ColourRuntimeWarning)
        xyz = np.where(finite[:, None], values, 0.0) @ weights.T
        rgb = np.asarray(colour.XYZ_to_RGB(xyz, _colourspace("sRGB"), illuminant=white_xy), dtype=float)
        rgb = rgb.reshape(-1, 3)
        bad = ~(finite & np.all(np.isfinite(xyz), axis=1) & np.all(np.isfinite(rgb), axis=1))
        rgb[bad] = np.nan
        hsv = np.asarray(colour.RGB_to_HSV(np.where(bad[:, None], 0.0, rgb)), dtype=float).reshape(-1, 3)
    hsv[bad] = np.nan
    return rgb, hsv


@functools.lru_cache(maxsize=32)
def _xyz_weights(wavelengths: tuple[float, ...], illuminant: str) -> np.ndarray:
    """``W`` (3 x n): ``W @ beta`` is :func:`spectrum_colour`'s ``xyz`` of ``beta`` on ``wavelengths``."""
    wl = np.asarray(wavelengths)
    out = np.empty((3, wl.size))
    for j in range(wl.size):
        unit = np.zeros(wl.size)
        unit[j] = 1.0
        out[:, j] = spectrum_colour(wl, unit, illuminant=illuminant).xyz
    out.setflags(write=False)
    return out


def colourspace(name: str):
    """The colour-science RGB colour space of ``"linear NAME"`` (e.g. ``"linear sRGB"``)."""
    if not isinstance(name, str):
        raise ValueError(f"unknown colour space {name!r}; use \"linear sRGB\" or \"linear NAME\" "
                         "with NAME a key of colour.RGB_COLOURSPACES")
    return _colourspace(name)


@functools.lru_cache(maxsize=64)
def _colourspace(name: str):
    """:func:`colourspace`, each accepted name looked up once (as :func:`_illuminant_entry`)."""
    import colour

    key = name[len("linear "):] if name.startswith("linear ") else name
    if key not in colour.RGB_COLOURSPACES:
        raise ValueError(f"unknown colour space {name!r}; use \"linear sRGB\" or \"linear NAME\" "
                         "with NAME a key of colour.RGB_COLOURSPACES")
    return colour.RGB_COLOURSPACES[key]


def _summary(rgb_srgb, xyz, illuminant: str) -> ColourSummary:
    import colour

    hsv = colour.RGB_to_HSV(np.asarray(rgb_srgb, dtype=float))
    r, g, b = (float(x) for x in rgb_srgb)
    return ColourSummary(h=float(hsv[0]), s=float(hsv[1]), v=float(hsv[2]),
                         blue_red=_ratio(b, r), green_red=_ratio(g, r), rgb=(r, g, b),
                         xyz=(float(xyz[0]), float(xyz[1]), float(xyz[2])), illuminant=illuminant)


def rgb_colour(channels, colour_space: str = "linear sRGB") -> ColourSummary:
    """Colour summary of linear RGB channel values (a mapping with keys R, G, B).

    The channels are converted to linear sRGB (through CIE XYZ, colour-science, when the space is
    not sRGB) and then to HSV and the channel ratios, as for a spectrum. A photometric (Y-only)
    dataset has no colour: :class:`ValueError`.

    Examples
    --------
    >>> c = rgb_colour({"R": 0.8, "G": 0.0088, "B": 0.064})
    >>> round(c.s, 3), round(c.v, 2), round(c.green_red, 3)
    (0.989, 0.8, 0.011)
    """
    import colour

    missing = [c for c in "RGB" if c not in channels]
    if missing:
        raise ValueError(f"a colour needs the channels R, G and B (missing {', '.join(missing)})")
    rgb = np.array([float(channels[c]) for c in "RGB"])
    if not np.all(np.isfinite(rgb)):
        raise ValueError("the channel values contain NaN or infinite values")
    space = colourspace(colour_space)
    xyz = colour.RGB_to_XYZ(rgb, space, apply_cctf_decoding=False)
    if space.name == "sRGB":
        srgb = rgb
    else:
        srgb = colour.XYZ_to_RGB(xyz, _colourspace("sRGB"), illuminant=space.whitepoint,
                                 chromatic_adaptation_transform="Bradford")
    return _summary(srgb, xyz, illuminant=f"{space.whitepoint_name} ({space.name} white)")


def spectrum_to_rgb(wavelength_nm, beta, colour_space: str = "linear sRGB",
                    illuminant: str = "D65") -> np.ndarray:
    """Linear RGB of the spectrum ``beta(wavelength_nm)`` in ``colour_space`` (a 3-vector).

    Spectrum -> CIE XYZ under ``illuminant`` (as :func:`spectrum_colour`, Y = 1 for the ideal
    white) -> the space's linear RGB, adapting the illuminant's white to the space's (Bradford).
    For linear sRGB under D65 this is exactly :func:`spectrum_colour`'s ``rgb``.
    """
    import colour

    summary = spectrum_colour(wavelength_nm, beta, illuminant=illuminant)
    space = colourspace(colour_space)
    white_xy = _illuminant_xy(illuminant)
    return np.asarray(colour.XYZ_to_RGB(np.asarray(summary.xyz), space, illuminant=white_xy,
                                        chromatic_adaptation_transform="Bradford"), dtype=float)


def _illuminant_data(illuminant: str):
    """``(cmfs, illuminant spectrum, white xy)`` of the illuminant named ``illuminant``.

    The name is a key of ``colour.SDS_ILLUMINANTS``; any other name is a ValueError.

    colour-science's mappings compare a name with every key in several spellings (slow for a
    look-up in a loop), so the data of each accepted name are looked up once (:func:`_illuminant_entry`);
    an unknown name is not remembered and is refused again on every call.
    """
    if not isinstance(illuminant, str):
        raise ValueError(f"unknown illuminant {illuminant!r}; use a key of "
                         "colour.SDS_ILLUMINANTS such as 'D65'")
    return _illuminant_entry(illuminant)


def check_illuminant(illuminant: str) -> str:
    """Return ``illuminant`` when it names an illuminant of the colour match.

    Raises
    ------
    ValueError
        Any name that is not a key of ``colour.SDS_ILLUMINANTS``.
    """
    _illuminant_data(illuminant)
    return illuminant


@functools.lru_cache(maxsize=64)
def _illuminant_entry(illuminant: str):
    import colour

    if illuminant not in colour.SDS_ILLUMINANTS:
        raise ValueError(f"unknown illuminant {illuminant!r}; use a key of "
                         "colour.SDS_ILLUMINANTS such as 'D65'")
    cmfs = colour.MSDS_CMFS[OBSERVER]
    sd_illuminant = colour.SDS_ILLUMINANTS[illuminant]
    if illuminant in colour.CCS_ILLUMINANTS[OBSERVER]:
        white_xy = colour.CCS_ILLUMINANTS[OBSERVER][illuminant]
    else:
        with warnings.catch_warnings(), np.errstate(over="ignore", invalid="ignore"):
            warnings.simplefilter("ignore", colour.utilities.ColourRuntimeWarning)
            white_xy = colour.XYZ_to_xy(colour.sd_to_XYZ(colour.sd_ones(), cmfs, sd_illuminant))
        white_xy.setflags(write=False)
    return cmfs, sd_illuminant, white_xy


def _illuminant_xy(illuminant: str):
    return _illuminant_data(illuminant)[2]


def hue_difference(h1, h2):
    """Signed hue difference ``h2 - h1`` on the hue circle, in [-0.5, 0.5).

    Examples
    --------
    >>> round(float(hue_difference(0.98, 0.02)), 6)
    0.04
    """
    d = np.mod(np.asarray(h2, dtype=float) - np.asarray(h1, dtype=float) + 0.5, 1.0) - 0.5
    return d[()] if np.ndim(d) == 0 else d


def display_srgb(rgb_linear):
    """Gamma-encoded sRGB in [0, 1] for display (swatches); never used for the metrics."""
    import colour

    rgb = np.clip(np.asarray(rgb_linear, dtype=float), 0.0, None)
    encoded = colour.cctf_encoding(rgb, function="sRGB")
    return np.clip(encoded, 0.0, 1.0)
