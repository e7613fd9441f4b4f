r"""Colour match of measured and simulated spectra at one geometry (docs/physics.md sections 7-8).

Colour is computed by :func:`gonio.data.colour.spectrum_colour` (CIE 1931 2-degree observer,
illuminant D65 unless set, LINEAR sRGB, HSV and the ratios BLUE/RED and GREEN/RED), at the
geometry closest to normal incidence and normal observation that the measured dataset and every
simulation share (exactly, not by interpolation, when there is such a geometry): the smallest ``theta_i + theta_o``, ties broken by smaller ``theta_i``, then
``phi_i``, then ``phi_o``. Differences are simulated minus measured: ``dh`` on the hue circle
(:func:`gonio.data.colour.hue_difference`, in [-0.5, 0.5)), ``ds``, ``dv``.

Which simulated values are compared
-----------------------------------
Not the per-wavelength normalised ones: :math:`k(\lambda)` makes the simulated spectrum equal the
measured one at the normal direction by construction, so near the normal the colours would agree
trivially. The simulation's own spectrum is used, scaled by ONE wavelength-independent factor, the
ratio of the luminances of the two normal/normal spectra:

.. math::

    k_Y = \frac{Y[\beta_\mathrm{meas}(0,0)]}{Y[C(0,0)]}
        = \frac{\sum_\lambda k(\lambda)\, C(0,0;\lambda)\, w_Y(\lambda)}
               {\sum_\lambda C(0,0;\lambda)\, w_Y(\lambda)},

the luminance-weighted mean of :math:`k(\lambda)` (:math:`w_Y` are the CIE ``Y`` weights, see
:func:`luminance_weights`). Hue, saturation and the channel ratios do not depend on any scale
factor, so they are the simulation's own; ``v`` is on the measured scale. Every figure is
unchanged when the simulation is multiplied by a positive constant.

RGB measurements
----------------
In an RGB comparison (:mod:`compare.bands`) the channels are read directly
(:func:`gonio.data.colour.rgb_colour`, from the measurement's linear colour space to linear sRGB
and HSV); the simulations are already in that space, and :math:`k_Y` uses the space's luminance
row (``0.2126 R + 0.7152 G + 0.0722 B`` for sRGB) in place of the CIE ``Y`` weights.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
import pandas as pd

from gonio.data import GEOMETRY
from gonio.data.colour import ColourSummary, colourspace, hue_difference, rgb_colour, spectrum_colour

from .errors import CompareError

__all__ = ["ColourMatch", "SimulatedColour", "MAX_COLOUR_STEP_NM", "band_luminance_weights", "colour_geometry",
           "colour_match", "colour_of", "colour_refusal", "luminance_weights"]

OBSERVER = "CIE 1931 2 Degree Standard Observer"
#: the widest step between the compared wavelengths of a spectrum whose colour is stated (the spectrum is
#: linearly interpolated to 5 nm between them: :func:`compare.bands.colour_resampling`)
MAX_COLOUR_STEP_NM = 50.0


def colour_refusal(wavelength_nm, illuminant: str = "D65") -> str | None:
    """Why no colour (H, S, V) is stated for spectra on ``wavelength_nm``, or None when it is.

    The rule: a spectrum on an evenly spaced 1, 5, 10 or 20 nm grid is integrated as it is (ASTM E308,
    colour-science); a spectrum on any other grid is first interpolated linearly to 5 nm
    (:func:`compare.bands.colour_resampling`), which is stated only when its wavelengths are at most
    :data:`MAX_COLOUR_STEP_NM` apart. Sparser samples (e.g. 450, 550 and 650 nm) do not determine a
    colour: a band between two of them, where a dye absorbs, would be a straight line. Their curves are
    compared all the same. ``illuminant`` is accepted for symmetry with the colour functions.

    Parameters
    ----------
    wavelength_nm : array_like
        The compared wavelengths (nm).
    illuminant : str, default "D65"
        The comparison's illuminant (not used by the rule).

    Returns
    -------
    str or None
        One sentence saying why no colour is stated, or None when a colour is stated.
    """
    from .bands import colour_resampling

    wl = np.sort(np.asarray(wavelength_nm, dtype=float).ravel())
    if wl.size < 2:
        return f"a colour needs a spectrum of at least two wavelengths; the comparison has {wl.size}"
    if colour_resampling(wl)[1] is None:
        return None
    step = float(np.max(np.diff(wl)))
    if step > MAX_COLOUR_STEP_NM + 1e-9:
        shown = ", ".join(f"{w:g}" for w in wl[:8]) + (" ..." if wl.size > 8 else "")
        return (f"the compared wavelengths ({shown} nm) are up to {step:g} nm apart; a colour is computed from "
                f"spectra on an even 1, 5, 10 or 20 nm grid, or sampled at least every {MAX_COLOUR_STEP_NM:g} nm "
                "(then interpolated linearly to 5 nm)")
    return None


@lru_cache(maxsize=16)
def _weights(wavelengths: tuple[float, ...], illuminant: str) -> np.ndarray:
    import colour

    from .bands import colour_resampling

    grid, interp = colour_resampling(wavelengths)
    if interp is not None:
        # a grid ASTM E308 does not integrate (not 1, 5, 10 or 20 nm, or uneven): the weights of the spectrum
        # interpolated linearly to 5 nm (compare.bands.colour_resampling), a linear map of the given values
        return interp.T @ _weights(tuple(float(x) for x in grid), illuminant)
    wl = np.asarray(wavelengths)
    basis = colour.MultiSpectralDistributions(np.eye(wl.size), wl)
    # colour-science warns while it trims/extends each basis spectrum to the observer's range,
    # exactly as it does (silently, once) for a single spectrum in gonio.data.colour
    with colour.utilities.suppress_warnings(colour_runtime_warnings=True):
        xyz = colour.msds_to_XYZ(basis, colour.MSDS_CMFS[OBSERVER],
                                 colour.SDS_ILLUMINANTS[illuminant], method="ASTM E308")
    return np.asarray(xyz, dtype=float) / 100.0


def luminance_weights(wavelength_nm, illuminant: str = "D65") -> np.ndarray:
    """Weights ``w`` with ``Y = w @ beta``, the CIE ``Y`` of a spectrum on ``wavelength_nm``.

    colour-science's integration (ASTM E308, as in :func:`gonio.data.colour.spectrum_colour`) is linear
    in the spectrum, so ``w`` is the ``Y`` of each unit basis spectrum; ``Y = 1`` for ``beta = 1``.

    Parameters
    ----------
    wavelength_nm : array_like
        The spectrum's wavelengths (nm, ascending).
    illuminant : str, default "D65"
        The illuminant the spectrum is seen under.

    Returns
    -------
    numpy.ndarray
        One weight per wavelength.

    Examples
    --------
    >>> import numpy as np
    >>> w = luminance_weights(np.arange(390.0, 711.0, 10.0))
    >>> round(float(w.sum()), 4)
    1.0
    """
    wl = tuple(float(x) for x in np.asarray(wavelength_nm, dtype=float).ravel())
    return _weights(wl, illuminant)[:, 1].copy()


def band_luminance_weights(bands, grid, illuminant: str = "D65") -> np.ndarray:
    """Weights ``w`` with ``Y = w @ values`` on the comparison grid.

    The CIE ``Y`` weights of the wavelengths, or for channels the ``Y`` channel itself when
    present, else the colour space's luminance row over R, G, B.

    Parameters
    ----------
    bands : Bands or None
        The comparison's bands; None (or a spectral comparison) for wavelengths.
    grid : array_like
        The comparison grid: wavelengths (nm), or band codes of ``bands``.
    illuminant : str, default "D65"
        The illuminant of the ``Y`` of wavelengths.

    Returns
    -------
    numpy.ndarray
        One weight per value of ``grid``.
    """
    if bands is None or not bands.is_rgb:
        return luminance_weights(grid, illuminant)
    labels = [bands.label(b) for b in np.asarray(grid, dtype=float)]
    if "Y" in labels:
        return np.array([1.0 if c == "Y" else 0.0 for c in labels])
    row = np.asarray(colourspace(bands.colour_space).matrix_RGB_to_XYZ, dtype=float)[1]
    return np.array([row["RGB".index(c)] for c in labels])


def colour_geometry(frames: Mapping[str, pd.DataFrame]) -> dict:
    """The geometry (dict of the four angles and ``s``) closest to normal/normal in every frame.

    Geometries a simulation actually holds are preferred; interpolated ones are used only when
    the datasets share no geometry exactly.

    Parameters
    ----------
    frames : mapping of str to pandas.DataFrame
        The aligned frames (:func:`compare.align.align`) by name, with the geometry columns, ``s``
        and ``interpolated``.

    Returns
    -------
    dict
        ``theta_i``, ``phi_i``, ``theta_o``, ``phi_o`` (degrees) and ``s`` (degrees, None when the
        geometry is out of the plane).

    Raises
    ------
    CompareError
        When the frames share no geometry.
    """
    def shared(exact_only: bool):
        common = None
        for frame in frames.values():
            rows = frame[~frame["interpolated"].to_numpy()] if exact_only else frame
            keys = rows[list(GEOMETRY)].round(6).drop_duplicates()
            common = keys if common is None else common.merge(keys, how="inner")
        return common

    common = shared(exact_only=True)
    if common is None or common.empty:
        common = shared(exact_only=False)
    if common is None or common.empty:
        raise CompareError("the simulated datasets share no geometry with each other and the "
                           "measured dataset, so no colour can be compared at one geometry")
    order = common.assign(total=common["theta_i"] + common["theta_o"]).sort_values(
        ["total", "theta_i", "phi_i", "phi_o", "theta_o"], kind="mergesort")
    row = order.iloc[0]
    first = next(iter(frames.values()))
    s = first.loc[(first[list(GEOMETRY)].round(6) == row[list(GEOMETRY)]).all(axis=1), "s"]
    geometry: dict[str, float | None] = {c: float(row[c]) for c in GEOMETRY}
    s_value = float(s.iloc[0]) if len(s) else float("nan")
    geometry["s"] = s_value if np.isfinite(s_value) else None
    return geometry


def _rows_at(frame: pd.DataFrame, geometry: dict) -> pd.DataFrame:
    mask = np.ones(len(frame), dtype=bool)
    for c in GEOMETRY:
        mask &= np.abs(frame[c].to_numpy() - geometry[c]) < 1e-6
    return frame[mask].sort_values("wavelength_nm")


@dataclass(frozen=True)
class SimulatedColour:
    """Colour of one simulation, its scale ``k_Y`` and its differences from the measurement."""

    colour: ColourSummary
    scale: float
    dh: float
    ds: float
    dv: float
    wavelength_nm: np.ndarray
    beta: np.ndarray


@dataclass(frozen=True)
class ColourMatch:
    """Measured colour and each simulation's at :attr:`geometry`."""

    geometry: dict
    measured: ColourSummary
    measured_wavelength_nm: np.ndarray
    measured_beta: np.ndarray
    simulated: dict[str, SimulatedColour]


def colour_of(wl, beta, illuminant: str, what: str, bands=None) -> ColourSummary:
    """The colour of values on the comparison grid (a spectrum, or the channels of ``bands``).

    Raises CompareError naming ``what`` when there is none.

    Parameters
    ----------
    wl : array_like
        The comparison grid: wavelengths (nm), or band codes of ``bands``.
    beta : array_like
        The radiance coefficients at ``wl``.
    illuminant : str
        The illuminant of a spectrum's colour.
    what : str
        What the values are (e.g. "the measured dataset"), for the message.
    bands : Bands, optional
        The comparison's bands; None or a spectral comparison for a spectrum.

    Returns
    -------
    ColourSummary
        The colour (linear sRGB, and HSV in [0, 1]).

    Raises
    ------
    CompareError
        When the values have no colour.
    """
    try:
        if bands is not None and bands.is_rgb:
            return rgb_colour({bands.label(b): v for b, v in zip(wl, beta, strict=True)},
                              colour_space=bands.colour_space)
        from .bands import colour_resampling

        grid, interp = colour_resampling(wl)
        values = np.asarray(beta, dtype=float)
        return spectrum_colour(grid, values if interp is None else interp @ values, illuminant=illuminant)
    except ValueError as exc:
        raise CompareError(f"no colour for {what}: {exc}") from None


def colour_match(frames: Mapping[str, pd.DataFrame], normal_values: Mapping[str, tuple],
                 illuminant: str = "D65", bands=None) -> ColourMatch:
    """Colour match of every simulation against the measurement.

    Parameters
    ----------
    frames : mapping of name -> DataFrame
        Aligned tables (:func:`compare.align.align`), all on the same wavelength grid.
    normal_values : mapping of name -> (beta_meas(0,0), C(0,0))
        Normal/normal spectra on the same grid (:class:`compare.normalise.Normalisation`'s
        ``measured_value`` and ``simulated_value``), for the luminance scale ``k_Y``.
    illuminant : str
        Illuminant of the colour computation.
    bands : compare.bands.Bands, optional
        The comparison's bands; for channels (R, G, B present) the colour is read from them.
    """
    geometry = colour_geometry(frames)
    measured: ColourSummary | None = None
    simulated: dict[str, SimulatedColour] = {}
    for name, frame in frames.items():
        rows = _rows_at(frame, geometry)
        wl = rows["wavelength_nm"].to_numpy()
        if measured is None:
            meas_beta = rows["beta_meas"].to_numpy()
            meas_wl = wl
            measured = colour_of(wl, meas_beta, illuminant, "the measured dataset", bands)
        w = band_luminance_weights(bands, wl, illuminant)
        normal_meas, normal_sim = normal_values[name]
        scale = float(w @ normal_meas) / float(w @ normal_sim)
        beta = rows["beta_sim_raw"].to_numpy() * scale
        c = colour_of(wl, beta, illuminant,
                    f"simulated dataset '{name}' (scaled by k_Y {scale:.3g})", bands)
        simulated[name] = SimulatedColour(
            colour=c, scale=scale, dh=float(hue_difference(measured.h, c.h)),
            ds=c.s - measured.s, dv=c.v - measured.v, wavelength_nm=wl, beta=beta)
    if measured is None:
        raise CompareError("no dataset to match the colour of")
    return ColourMatch(geometry=geometry, measured=measured, measured_wavelength_nm=meas_wl,
                       measured_beta=meas_beta, simulated=simulated)
