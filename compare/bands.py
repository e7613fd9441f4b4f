r"""What a comparison is made on: wavelengths, or the colour channels of an RGB measurement.

A spectral measurement is compared wavelength by wavelength (:mod:`compare.align`). An RGB
measurement (a ``channel`` column R, G, B, or Y for a photometric one, and a LINEAR colour space
in its meta.json; :mod:`gonio.data.dataset`) is compared channel by channel, and every simulation
is first put into the measurement's channels:

- a **spectral** simulation is converted, at each of its geometries, to the measurement's colour
  space: spectrum -> CIE XYZ (CIE 1931 2-degree observer, the comparison's illuminant, D65 by
  default, ``Y = 1`` for the ideal white diffuser) -> the space's linear RGB, adapting the
  illuminant's white to the space's (Bradford); ``Y`` is the CIE ``Y`` itself. This is
  :func:`gonio.data.colour.spectrum_to_rgb`, the pipeline of the colour match (docs/physics.md
  section 7). The conversion is linear in the spectrum, so it is a matrix ``M`` (channels x
  wavelengths) built once per wavelength grid from the unit spectra, ``RGB = M beta`` and
  ``u_RGB = sqrt(M^2 u_beta^2)`` (wavelengths independent). Only geometries whose spectrum is
  complete on the simulation's grid are converted. Its wavelength range must carry at least
  :data:`MIN_CHANNEL_COVERAGE` (99 %) of each channel's weight (:func:`channel_coverage`; about
  410..690 nm for sRGB under D65), otherwise the conversion would miss part of a channel and it
  is refused.
- an **RGB** simulation in another linear colour space is converted through CIE XYZ
  (``colour.matrix_RGB_to_RGB``, Bradford); a ``Y`` wanted from R, G, B is the space's
  luminance row (``0.2126 R + 0.7152 G + 0.0722 B`` for sRGB).

The comparison is then made on the channels the measurement and every simulation share; none in
common is refused (:class:`~compare.errors.CompareError`). A spectral measurement cannot be
compared with an RGB simulation (a spectrum is not recoverable from three channels): refused too.

Internally a channel travels through the wavelength-keyed machinery (:mod:`compare.align`,
:mod:`compare.normalise`, :mod:`compare.metrics`) as a *band code* (:data:`CODES`, R = 1, G = 2,
B = 3, Y = 4) in the ``wavelength_nm`` column of in-memory views of the datasets; these views are
never written, and every label shown to a person goes through :meth:`Bands.label`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np
import pandas as pd

from gonio.data import GEOMETRY, Dataset
from gonio.data.colour import spectra_srgb, spectrum_colour, spectrum_to_rgb

from .errors import CompareError

__all__ = ["ASTM_STEPS_NM", "CODES", "COLOUR_STEP_NM", "MIN_CHANNEL_COVERAGE", "Bands",
           "channel_coverage", "colour_at", "colour_resampling", "conversion_matrix", "prepare", "spectra_colours"]

#: Band code of each channel inside the comparison (not a wavelength).
CODES = {"R": 1.0, "G": 2.0, "B": 3.0, "Y": 4.0}
_CHANNEL_OF = {v: k for k, v in CODES.items()}
_TOL = 1e-6
#: The observer's range (nm) on which the channels' weights are judged.
FULL_RANGE_NM = np.arange(360.0, 831.0, 5.0)
#: Least fraction of each channel's weight a converted spectrum's range must carry.
MIN_CHANNEL_COVERAGE = 0.99


@dataclass(frozen=True)
class Bands:
    """The bands of one comparison.

    Attributes
    ----------
    channels : tuple of str or None
        The channels compared (canonical order), or None for a spectral comparison.
    colour_space : str or None
        The measurement's linear colour space (RGB comparisons).
    conversions : dict
        Simulation name -> one sentence saying how it was put into the measurement's channels
        (empty for a simulation used as it is).
    """

    channels: tuple[str, ...] | None = None
    colour_space: str | None = None
    conversions: dict[str, str] = field(default_factory=dict)

    @property
    def is_rgb(self) -> bool:
        """Whether the comparison is made on colour channels (an RGB measurement) rather than wavelengths."""
        return self.channels is not None

    @property
    def has_colour(self) -> bool:
        """False for a photometric (Y-only) comparison: there is no colour to state."""
        return not self.is_rgb or set("RGB") <= set(self.channels or ())

    @property
    def noun(self) -> str:
        """What one band is called in messages: ``channel`` or ``wavelength``."""
        return "channel" if self.is_rgb else "wavelength"

    def label(self, band: float) -> str:
        """``"R"`` for an RGB band code, ``"550 nm"`` for a wavelength.

        Parameters
        ----------
        band : float
            A band code (:data:`CODES`) in an RGB comparison, else a wavelength (nm).

        Returns
        -------
        str
            The channel's letter, or the wavelength with its unit.
        """
        if self.is_rgb:
            return _CHANNEL_OF.get(round(float(band), 6), f"{band:g}")
        return f"{float(band):g} nm"

    def key(self, band: float) -> str:
        """JSON key of a band: ``"R"`` or ``"550"``.

        Parameters
        ----------
        band : float
            A band code (:data:`CODES`) in an RGB comparison, else a wavelength (nm).

        Returns
        -------
        str
            The channel's letter, or the wavelength in nm without its unit.
        """
        return self.label(band) if self.is_rgb else f"{float(band):g}"

    def codes(self) -> np.ndarray:
        """The band codes of the channels (:data:`CODES`), in the order of ``channels``; empty for wavelengths."""
        return np.array([CODES[c] for c in self.channels or ()], dtype=float)


def _view(table: pd.DataFrame, source: Dataset) -> Dataset:
    """An in-memory dataset keyed by band codes (never validated nor written)."""
    table = table.sort_values(list(GEOMETRY) + ["wavelength_nm"], kind="mergesort")
    meta = dict(source.meta)
    meta["wavelengths_nm"] = sorted({float(x) for x in table["wavelength_nm"]})
    return Dataset(table.reset_index(drop=True), meta, source.path)


def _rgb_view(ds: Dataset, values: pd.DataFrame) -> Dataset:
    """``values``: geometry columns plus one column per channel (beta) and ``u_<channel>``."""
    rows = []
    for c in CODES:
        if c in values.columns:
            part = values[list(GEOMETRY)].copy()
            part["wavelength_nm"] = CODES[c]
            part["beta"] = values[c].to_numpy(dtype=float)
            part["u_beta"] = values["u_" + c].to_numpy(dtype=float)
            part["n"] = values["n"].to_numpy()
            rows.append(part)
    return _view(pd.concat(rows, ignore_index=True), ds)


def _wide(ds: Dataset) -> pd.DataFrame:
    """One row per geometry of an RGB dataset: columns R, G, B, Y present and u_R, ..."""
    t = ds.table
    beta = t.pivot_table(index=list(GEOMETRY), columns="channel", values="beta", aggfunc="first")
    u = t.pivot_table(index=list(GEOMETRY), columns="channel", values="u_beta", aggfunc="first")
    n = t.groupby(list(GEOMETRY))["n"].min()
    out = beta.join(u.add_prefix("u_")).join(n)
    return out.reset_index()


#: Wavelength steps colour-science's ASTM E308 integration accepts (evenly spaced grids only).
ASTM_STEPS_NM = (1.0, 5.0, 10.0, 20.0)
#: Step (nm) a spectrum on any other grid is linearly interpolated to before its colour is taken.
COLOUR_STEP_NM = 5.0


def colour_resampling(wavelength_nm) -> tuple[np.ndarray, np.ndarray | None]:
    """The grid a spectrum's colour is integrated on, and the interpolation to it.

    Returns ``(grid, L)``: the wavelengths, and the linear interpolation matrix (``grid`` x given)
    to them, or None when the given grid is used as it is.

    ASTM E308 (colour-science's ``sd_to_XYZ``) integrates evenly spaced spectra at 1, 5, 10 or 20
    nm and raises on others (a 50 nm simulation, an irregular grid); such a spectrum is linearly
    interpolated to :data:`COLOUR_STEP_NM` inside its own range first (never extrapolated), which
    the comparison notes say.

    Parameters
    ----------
    wavelength_nm : array_like
        The spectrum's wavelengths (nm, ascending).

    Returns
    -------
    grid : numpy.ndarray
        The wavelengths (nm) the colour is integrated on.
    L : numpy.ndarray or None
        The interpolation matrix (``grid.size`` x ``wavelength_nm.size``), or None when ``grid`` is
        ``wavelength_nm`` itself.

    Examples
    --------
    >>> grid, L = colour_resampling(np.arange(400.0, 701.0, 50.0))
    >>> float(grid[0]), float(grid[-1]), grid.size, L.shape
    (400.0, 700.0, 61, (61, 7))
    >>> colour_resampling(np.arange(400.0, 701.0, 10.0))[1] is None
    True
    """
    wl = np.asarray(wavelength_nm, dtype=float).ravel()
    steps = np.diff(wl)
    if wl.size >= 2 and np.allclose(steps, steps[0], rtol=0, atol=1e-6) and any(
            abs(steps[0] - s) < 1e-6 for s in ASTM_STEPS_NM):
        return wl, None
    start = math.ceil(wl[0] / COLOUR_STEP_NM - 1e-9) * COLOUR_STEP_NM
    grid = np.arange(start, wl[-1] + 1e-6, COLOUR_STEP_NM)
    eye = np.eye(wl.size)
    interp = np.column_stack([np.interp(grid, wl, eye[:, j]) for j in range(wl.size)])
    return grid, interp


def colour_at(ds: Dataset, theta_i: float, phi_i: float, theta_o: float, phi_o: float,
              illuminant: str = "D65"):
    """The colour of a dataset at one geometry, on any wavelength grid.

    As :meth:`gonio.data.Dataset.colour_at`, a spectrum on a grid ASTM E308 does not integrate
    first interpolated linearly (:func:`colour_resampling`); ValueError when there is none.

    Parameters
    ----------
    ds : Dataset
        The dataset (spectral or RGB).
    theta_i, phi_i : float
        Incidence direction (degrees): polar angle from the normal and azimuth.
    theta_o, phi_o : float
        Observation direction (degrees): polar angle from the normal and azimuth.
    illuminant : str, default "D65"
        The illuminant the colour is seen under.

    Returns
    -------
    ColourSummary
        The colour (linear sRGB, and HSV in [0, 1]) at that geometry.

    Raises
    ------
    ValueError
        When the dataset holds no spectrum at that geometry, or its grid cannot be integrated.
    """
    if ds.is_rgb:
        return ds.colour_at(theta_i, phi_i, theta_o, phi_o, illuminant=illuminant)
    rows = ds.spectrum(theta_i, phi_i, theta_o, phi_o)
    wl = rows["wavelength_nm"].to_numpy(float)
    beta = rows["beta"].to_numpy(float)
    grid, interp = colour_resampling(wl)
    if interp is not None:
        beta = interp @ beta
    return spectrum_colour(grid, beta, illuminant=illuminant)


def spectra_colours(wavelength_nm, betas, illuminant: str = "D65") -> tuple[np.ndarray, np.ndarray]:
    """Linear sRGB and hue (turns) of many spectra on one grid, each as :func:`colour_at` gives it.

    One spectrum per row of ``betas``, resampled as :func:`colour_at` does and converted at once
    (:func:`gonio.data.colour.spectra_srgb`); a row whose colour :func:`colour_at` would refuse
    (NaN or infinite values, an overflow) is NaN. ValueError for a grid it refuses.

    Parameters
    ----------
    wavelength_nm : array_like
        The common wavelength grid (nm, ascending).
    betas : array_like
        The spectra's radiance coefficients, one spectrum per row (``n`` x ``wavelength_nm.size``).
    illuminant : str, default "D65"
        The illuminant the colours are seen under.

    Returns
    -------
    rgb : numpy.ndarray
        Linear sRGB of each spectrum (``n`` x 3).
    hue : numpy.ndarray
        Hue of each spectrum (turns, in [0, 1)).

    Raises
    ------
    ValueError
        When colour-science refuses the grid.
    """
    wl = np.asarray(wavelength_nm, dtype=float).ravel()
    values = np.asarray(betas, dtype=float).reshape(-1, wl.size)
    grid, interp = colour_resampling(wl)
    if interp is not None:
        values = values @ interp.T
    rgb, hsv = spectra_srgb(grid, values, illuminant=illuminant)
    return rgb, hsv[:, 0]


@lru_cache(maxsize=32)
def _matrix(wavelengths: tuple[float, ...], channels: tuple[str, ...], colour_space: str,
            illuminant: str) -> np.ndarray:
    grid, interp = colour_resampling(wavelengths)
    if interp is not None:
        return _matrix(tuple(float(x) for x in grid), channels, colour_space, illuminant) @ interp
    wl = np.asarray(wavelengths)
    out = np.empty((len(channels), wl.size))
    for j in range(wl.size):
        unit = np.zeros(wl.size)
        unit[j] = 1.0
        rgb = dict(zip("RGB", spectrum_to_rgb(wl, unit, colour_space, illuminant), strict=True))
        if "Y" in channels:
            rgb["Y"] = spectrum_colour(wl, unit, illuminant=illuminant).xyz[1]
        out[:, j] = [rgb[c] for c in channels]
    return out


def conversion_matrix(wavelength_nm, channels: Sequence[str], colour_space: str = "linear sRGB",
                      illuminant: str = "D65") -> np.ndarray:
    """``M`` (channels x wavelengths) with ``M @ beta`` the linear ``channels`` of a spectrum.

    Column ``j`` is :func:`gonio.data.colour.spectrum_to_rgb` of the unit spectrum at wavelength
    ``j`` (``Y``: its CIE ``Y``); the conversion is linear, so ``M @ beta`` equals converting
    ``beta`` itself.

    Parameters
    ----------
    wavelength_nm : array_like
        The spectrum's wavelengths (nm, ascending).
    channels : sequence of str
        The channels wanted, each of ``"R"``, ``"G"``, ``"B"`` and ``"Y"``.
    colour_space : str, default "linear sRGB"
        The linear colour space of R, G and B.
    illuminant : str, default "D65"
        The illuminant the spectrum is seen under.

    Returns
    -------
    numpy.ndarray
        ``M`` (``len(channels)`` x ``wavelength_nm.size``), a copy the caller may change.

    Examples
    --------
    >>> import numpy as np
    >>> m = conversion_matrix(np.arange(390.0, 711.0, 10.0), ("R", "G", "B", "Y"))
    >>> [round(float(x), 3) for x in m.sum(axis=1)]   # the ideal white diffuser
    [1.0, 1.0, 1.0, 1.0]
    """
    wl = tuple(float(x) for x in np.asarray(wavelength_nm, dtype=float).ravel())
    return _matrix(wl, tuple(channels), colour_space, illuminant).copy()


def channel_coverage(lo_nm: float, hi_nm: float, channels: Sequence[str],
                     colour_space: str = "linear sRGB", illuminant: str = "D65") -> np.ndarray:
    """How much of each colour channel a spectrum on ``[lo_nm, hi_nm]`` sees.

    The fraction of each channel's weight (``sum |M|`` over the observer's 360..830 nm at 5 nm)
    that lies inside the range.

    Parameters
    ----------
    lo_nm, hi_nm : float
        The spectrum's wavelength range (nm).
    channels : sequence of str
        The channels judged, each of ``"R"``, ``"G"``, ``"B"`` and ``"Y"``.
    colour_space : str, default "linear sRGB"
        The linear colour space of R, G and B.
    illuminant : str, default "D65"
        The illuminant the spectrum is seen under.

    Returns
    -------
    numpy.ndarray
        The fraction (0 to 1) of each channel's weight inside the range, in the order of ``channels``.

    Examples
    --------
    >>> [round(float(x), 3) for x in channel_coverage(410.0, 690.0, ("R", "G", "B"))]
    [0.997, 0.998, 0.992]
    """
    full = np.abs(conversion_matrix(FULL_RANGE_NM, channels, colour_space, illuminant))
    inside = (FULL_RANGE_NM >= lo_nm - _TOL) & (FULL_RANGE_NM <= hi_nm + _TOL)
    return full[:, inside].sum(axis=1) / full.sum(axis=1)


def _convert_spectral(sim: Dataset, channels: tuple[str, ...], colour_space: str,
                      illuminant: str) -> Dataset:
    wl = sim.wavelengths_nm
    if wl.size < 2:
        raise CompareError(
            f"simulated dataset '{sim.name}' ({sim.source}) has {wl.size} wavelength(s): a "
            "spectrum of at least two is needed to convert it to the measurement's channels")
    coverage = channel_coverage(wl[0], wl[-1], channels, colour_space, illuminant)
    if np.any(coverage < MIN_CHANNEL_COVERAGE):
        k = int(np.argmin(coverage))
        raise CompareError(
            f"simulated dataset '{sim.name}' ({sim.source}) covers {wl[0]:g}..{wl[-1]:g} nm, "
            f"which carries only {100 * coverage[k]:.1f}% of the weight of the measurement's "
            f"{channels[k]} channel ({colour_space}, illuminant {illuminant}); converting a "
            f"spectrum to the channels needs >= {100 * MIN_CHANNEL_COVERAGE:g}% of each (about "
            "410..690 nm); simulate the visible range")
    t = sim.table
    beta = t.pivot_table(index=list(GEOMETRY), columns="wavelength_nm", values="beta",
                         aggfunc="first").reindex(columns=wl)
    u = t.pivot_table(index=list(GEOMETRY), columns="wavelength_nm", values="u_beta",
                      aggfunc="first").reindex(columns=wl)
    n = t.groupby(list(GEOMETRY))["n"].min()
    complete = beta.notna().all(axis=1).to_numpy()
    if not complete.any():
        raise CompareError(f"simulated dataset '{sim.name}' ({sim.source}) has no geometry with "
                           "a complete spectrum to convert to the measurement's channels")
    m = conversion_matrix(wl, channels, colour_space, illuminant)
    b = beta.to_numpy()[complete]
    uu = u.to_numpy()[complete]
    values = beta.index.to_frame(index=False)[complete].reset_index(drop=True)
    conv = b @ m.T
    u_conv = np.sqrt((uu ** 2) @ (m ** 2).T)
    for k, c in enumerate(channels):
        values[c] = conv[:, k]
        values["u_" + c] = u_conv[:, k]
    values["n"] = n.to_numpy()[complete]
    return _rgb_view(sim, values)


def _convert_rgb(sim: Dataset, channels: tuple[str, ...], colour_space: str) -> Dataset:
    """``sim`` (RGB) in ``colour_space``, restricted to ``channels`` it has or can give."""
    import colour

    from gonio.data.colour import colourspace

    wide = _wide(sim)
    have = set(sim.channels)
    src = colourspace(sim.colour_space or "linear sRGB")
    dst = colourspace(colour_space)
    rgb_wanted = [c for c in channels if c in "RGB"]
    if src.name != dst.name and rgb_wanted:
        if not set("RGB") <= have:
            raise CompareError(
                f"simulated dataset '{sim.name}' ({sim.source}) is in {sim.colour_space} with "
                f"channels {', '.join(sim.channels)}: all of R, G, B are needed to convert it to "
                f"the measurement's {colour_space}")
        m = colour.matrix_RGB_to_RGB(src, dst, chromatic_adaptation_transform="Bradford")
        b = wide[["R", "G", "B"]].to_numpy() @ m.T
        u = np.sqrt((wide[["u_R", "u_G", "u_B"]].to_numpy() ** 2) @ (m ** 2).T)
        for k, c in enumerate("RGB"):
            wide[c], wide["u_" + c] = b[:, k], u[:, k]
    if "Y" in channels and "Y" not in have and set("RGB") <= have:
        w = np.asarray(src.matrix_RGB_to_XYZ, dtype=float)[1]
        wide_src = _wide(sim)
        wide["Y"] = wide_src[["R", "G", "B"]].to_numpy() @ w
        wide["u_Y"] = np.sqrt((wide_src[["u_R", "u_G", "u_B"]].to_numpy() ** 2) @ (w ** 2))
    keep = [c for c in channels if c in wide.columns]
    wide = wide.dropna(subset=keep)
    drop = [c for c in CODES if c in wide.columns and c not in keep]
    return _rgb_view(sim, wide.drop(columns=drop + ["u_" + c for c in drop]))


def _describe_grid(ds: Dataset) -> str:
    if ds.is_rgb:
        return f"channels {', '.join(ds.channels)} ({ds.colour_space})"
    wl = ds.wavelengths_nm
    return f"wavelengths {wl[0]:g}..{wl[-1]:g} nm"


def prepare(measured: Dataset, simulated: Sequence[Dataset], names: Sequence[str],
            illuminant: str = "D65") -> tuple[Dataset, list[Dataset], Bands]:
    """The measured dataset and the simulations as compared, and the :class:`Bands`.

    Spectral measurement: every dataset as it is (an RGB simulation is refused). RGB
    measurement: every simulation converted to the measurement's channels and colour space (see
    the module docstring), all restricted to the channels they share.

    Parameters
    ----------
    measured : gonio.data.Dataset
        The measurement.
    simulated : sequence of gonio.data.Dataset
        The simulations.
    names : sequence of str
        The simulations' names (messages and conversion notes).
    illuminant : str
        Illuminant of an RGB conversion.

    Returns
    -------
    (gonio.data.Dataset, list of gonio.data.Dataset, Bands)
        The measurement and the simulations as compared, and what they are compared on.

    Raises
    ------
    CompareError
        A spectral measurement with an RGB simulation, or no channel in common.
    """
    if not measured.is_rgb:
        for sim in simulated:
            if sim.is_rgb:
                raise CompareError(
                    f"simulated dataset '{sim.name}' ({sim.source}) has {_describe_grid(sim)} "
                    f"but measured dataset '{measured.name}' ({measured.source}) is spectral: a "
                    "spectrum cannot be recovered from colour channels; compare a spectral "
                    "simulation, or an RGB measurement")
        return measured, list(simulated), Bands()
    space = measured.colour_space or "linear sRGB"
    channels = measured.channels
    views: list[Dataset] = []
    conversions: dict[str, str] = {}
    shared = set(channels)
    for name, sim in zip(names, simulated, strict=True):
        if sim.is_rgb:
            gives = set(sim.channels) | ({"Y"} if set("RGB") <= set(sim.channels) else set())
            common = tuple(c for c in channels if c in gives)
            if not common:
                raise CompareError(
                    f"simulated dataset '{sim.name}' ({sim.source}) has "
                    f"{_describe_grid(sim)} and measured dataset '{measured.name}' "
                    f"({measured.source}) has {_describe_grid(measured)}: no channel in common; "
                    "simulate the measured channels (or a spectrum)")
            view = _convert_rgb(sim, common, space)
            if (sim.colour_space or "linear sRGB") != space or any(
                    c not in sim.channels for c in common):
                conversions[name] = (
                    f"'{name}' converted from {sim.colour_space} channels "
                    f"{', '.join(sim.channels)} to {space} {', '.join(common)} through CIE XYZ "
                    "(colour-science, Bradford adaptation; Y = the space's luminance row)")
        else:
            common = tuple(channels)
            view = _convert_spectral(sim, common, space, illuminant)
            wl = sim.wavelengths_nm
            rgb_part = [c for c in common if c in "RGB"]
            target = (f"{space} channels {', '.join(rgb_part)}" if rgb_part else "")
            if "Y" in common:
                target += (" and " if target else "") + "photometric channel Y (its CIE Y)"
            how = ("spectrum -> CIE XYZ (CIE 1931 2-degree observer, illuminant "
                   f"{illuminant}, Y = 1 for the ideal white diffuser)")
            if rgb_part:
                how += (f" -> {space} (the illuminant's white adapted to the space's, "
                        "Bradford)")
            if colour_resampling(wl)[1] is not None:
                how = (f"linear interpolation in wavelength to {COLOUR_STEP_NM:g} nm steps "
                       "(ASTM E308 integrates 1, 5, 10 or 20 nm) -> " + how)
            conversions[name] = (
                f"'{name}' is spectral ({wl[0]:g}..{wl[-1]:g} nm, {wl.size} wavelengths) and was "
                f"converted to the measurement's {target} before comparing: {how}; "
                "uncertainties propagated through the same linear map "
                "(gonio.data.colour.spectrum_to_rgb, colour-science)")
        shared &= set(common)
        views.append(view)
    kept = tuple(c for c in channels if c in shared)
    if not kept:
        raise CompareError(
            f"the simulated datasets share no channel with each other and with measured dataset "
            f"'{measured.name}' ({measured.source}, channels {', '.join(channels)})")
    codes = [CODES[c] for c in kept]

    def restrict(ds: Dataset) -> Dataset:
        t = ds.table
        return _view(t[np.isin(t["wavelength_nm"].to_numpy(), codes)], ds)

    wide = _wide(measured)
    unused = [c for x in CODES if x not in kept for c in (x, "u_" + x) if c in wide.columns]
    meas_view = _rgb_view(measured, wide.drop(columns=unused).dropna(subset=list(kept)))
    return (meas_view, [restrict(v) for v in views],
            Bands(channels=kept, colour_space=space, conversions=conversions))
