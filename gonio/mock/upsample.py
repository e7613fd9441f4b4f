r"""Spectra for RGB samples: what the mock's spectral photometer reads from an RGB file.

The mock's photometer is spectral; the real measurement we hold (the RGL green felt,
``fixtures/real/``) is RGB: linear sRGB channels ``(R, G, B)`` at every geometry. The mock answers
a wavelength ``lambda`` with a spectrum whose colour is that RGB, by the **spectral primary
decomposition of Mallett & Yuksel (2019)**::

    beta(lambda) = R b_R(lambda) + G b_G(lambda) + B b_B(lambda)

with their three basis spectra (colour-science's
:data:`colour.recovery.MSDS_BASIS_FUNCTIONS_sRGB_MALLETT2019`, 380..780 nm at 5 nm, interpolated
linearly; the end values outside), read from a copy beside this module (``mallett2019_srgb_basis.csv``:
the photometer answers without importing colour-science, whose import would stall the first reading). The basis spectra are non-negative, sum to 1 at every
wavelength (white stays flat) and are the sRGB primaries' own spectra: the colour of ``beta``
(CIE 1931 2-degree observer, illuminant D65, ``Y = 1`` for the ideal white diffuser, the colour
match's pipeline, :func:`gonio.data.colour.spectrum_to_rgb`) is the file's RGB, to 1.5e-4 (absolute,
for channels up to 1.5) on a 5 nm grid (``tests/gonio/mock/test_upsample.py``) and 0.3-0.5 % on the
demo's 10 nm grid (``tests/gonio/acquisition/test_closed_loop_felt.py`` allows 1 %).

Why a linear decomposition and not three-band steps (whose colour is not the file's) or a smooth
sigmoid upsampling (non-linear, so the tail wavelengths follow the sigmoid rather than the fabric):
docs/instrument.md, "An RGB sample's spectrum". The decomposition is linear in the RGB, so every
wavelength's angular curve is a fixed mixture of the file's channel curves.

An RGB file carries three numbers per geometry: any spectrum read from it is an assumption, and
this one is stated here and in the demo's report. Negative channels (fitting noise at dark
geometries) are clipped to 0.

Reference: I. Mallett, C. Yuksel, "Spectral Primary Decomposition for Rendering with sRGB
Reflectance", Eurographics Symposium on Rendering (DL-only track), 2019.
"""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path

import numpy as np

__all__ = ["rgb_spectrum", "basis", "BASIS_FILE"]

BASIS_FILE = Path(__file__).with_name("mallett2019_srgb_basis.csv")
"""The basis spectra: wavelength (nm) and ``b_R, b_G, b_B``, copied from colour-science."""


@lru_cache(maxsize=1)
def _basis_table() -> tuple[np.ndarray, np.ndarray]:
    table = np.loadtxt(BASIS_FILE, delimiter=",", comments="#", skiprows=5)
    return table[:, 0], table[:, 1:]   # wavelengths, R, G, B


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
