r"""Spectra for RGB samples: what the mock's spectral photometer reads from an RGB file.

The mock's photometer is spectral; the real measurement we hold (the RGL green felt,
``fixtures/real/``) is RGB: linear sRGB channels ``(R, G, B)`` at every geometry. The mock answers
a wavelength ``lambda`` with a spectrum whose colour is that RGB, by the **spectral primary
decomposition of Mallett & Yuksel (2019)**::

    beta(lambda) = R b_R(lambda) + G b_G(lambda) + B b_B(lambda)

with their three basis spectra (colour-science's
:data:`colour.recovery.MSDS_BASIS_FUNCTIONS_sRGB_MALLETT2019`, 380..780 nm at 5 nm, interpolated
linearly; the end values outside). The basis spectra are non-negative, sum to 1 at every
wavelength (white stays flat) and are the sRGB primaries' own spectra: the colour of ``beta``
(CIE 1931 2-degree observer, illuminant D65, ``Y = 1`` for the ideal white diffuser, the colour
match's pipeline, :func:`gonio.data.colour.spectrum_to_rgb`) is the file's RGB, to 1.5e-4 (absolute,
for channels up to 1.5) on a 5 nm grid (``tests/gonio/mock/test_upsample.py``) and 0.3-0.5 % on the
demo's 10 nm grid (``tests/gonio/acquisition/test_closed_loop_felt.py`` allows 1 %).

**Why this and not a three-band view** (B below 490 nm, G 490..590
nm, R above): the steps do not have the file's colour. At the felt's normal direction the steps'
sRGB is (0.160, 0.319, 0.041) where the file says (0.182, 0.305, 0.048): hue +0.016 turn and
saturation +0.03 off the felt, more than the colour targets the fits are judged by (the Monte
Carlo fitted to the steps was 0.022 turn off the file's own hue). The decomposition keeps the
steps' virtue: it is linear in the RGB, so every wavelength's angular curve is a fixed mixture of
the file's channel curves (at 450 nm 0.95 B, 0.04 G; at 550 nm 0.97 G; at 650 nm 0.91 R).

**Why not a smooth upsampling** (Jakob & Hanika 2019, the sigmoid spectra of Mitsuba 3's
``rgb2spec``, :func:`colour.recovery.XYZ_to_sd_Jakob2019`): it is non-linear, so each geometry's
spectrum is shaped on its own and the curves of the tail wavelengths follow the sigmoid's tails
rather than the fabric (the green felt's forward sheen at 60 / +70 deg over its 0 / 10 deg value:
12.6 at 700 nm in the sigmoid view, where the decomposition gives 5.7 and the G channel 4.8).
Measured on the felt: the Monte Carlo fitted to the three-band acquisition scores NRMSE 0.114 against the decomposition's view and 0.161 against the sigmoid
view; a dye refit on the sigmoid view reached only 0.125 with the hue 0.019 turn off.

An RGB file carries three numbers per geometry: any spectrum read from it is an assumption, and
this one is stated here and in the demo's report. Negative channels (fitting noise at dark
geometries) are clipped to 0.

Reference: I. Mallett, C. Yuksel, "Spectral Primary Decomposition for Rendering with sRGB
Reflectance", Eurographics Symposium on Rendering (DL-only track), 2019.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

__all__ = ["rgb_spectrum", "basis"]


@lru_cache(maxsize=1)
def _basis_table() -> tuple[np.ndarray, np.ndarray]:
    from colour.recovery import MSDS_BASIS_FUNCTIONS_sRGB_MALLETT2019 as table

    return np.asarray(table.wavelengths, dtype=float), np.asarray(table.values, dtype=float)   # R, G, B


def basis(wavelength_nm) -> np.ndarray:
    """The basis spectra ``b_R, b_G, b_B`` at ``wavelength_nm``: array ``(..., 3)``."""
    grid, values = _basis_table()
    wl = np.asarray(wavelength_nm, dtype=float)
    return np.stack([np.interp(wl, grid, values[:, k]) for k in range(3)], axis=-1)


def rgb_spectrum(rgb, wavelength_nm) -> np.ndarray:
    """``beta`` at ``wavelength_nm`` of the spectra whose colours are the linear sRGB ``rgb``.

    ``rgb``: array ``(..., 3)`` in the order R, G, B; ``wavelength_nm`` broadcasts against
    ``rgb[..., 0]``. Returns the broadcast shape.

    Examples
    --------
    >>> from gonio.data.colour import spectrum_to_rgb
    >>> wl = np.arange(380.0, 781.0, 5.0)
    >>> beta = rgb_spectrum(np.array([0.18, 0.30, 0.05]), wl)
    >>> np.round(spectrum_to_rgb(wl, beta), 3).tolist()
    [0.18, 0.3, 0.05]
    """
    rgb = np.clip(np.asarray(rgb, dtype=float), 0.0, None)
    return np.einsum("...k,...k->...", rgb, basis(wavelength_nm))
