"""The report's data: in-plane rows, luminance and single-wavelength curves, curve breaks.

The in-plane rows of the measurement and of each normalised simulation, their luminance and
single-wavelength curves, and where a drawn curve must be broken.

Simulated curves are drawn at the simulation's own in-plane geometries when its wavelength grid
contains the comparison grid (so points the instrument cannot measure, like the normal/normal one,
are shown), otherwise at the measured geometries (interpolated).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from ..comparison import Comparison

__all__ = ["BEAM_BLOCK_DEG", "GRAZING_DEG", "REPORT_WAVELENGTHS_NM", "angle_text", "beam_blocked",
           "gapped", "luminance_curve",
           "measured_inplane", "sim_inplane", "single_wavelength"]

#: Single wavelengths plotted (nearest shared ones).
REPORT_WAVELENGTHS_NM = (450.0, 550.0, 650.0)
#: Half-width (deg) of the cone around the source direction the detector cannot enter.
BEAM_BLOCK_DEG = 5.0
#: Incidences at or beyond this (deg) are grazing: drawn in panels with their own value axis (a
#: 90 deg curve reaching 5 would flatten every 0-60 deg curve on a shared axis).
GRAZING_DEG = 85.0


def angle_text(theta_deg: float) -> str:
    """``"θi = 27.8°"``: an incidence to one decimal (no trailing ``.0``).

    Parameters
    ----------
    theta_deg : float
        The incidence polar angle (degrees).

    Returns
    -------
    str
        The label.
    """
    return f"θi = {round(float(theta_deg), 1):g}°"


def beam_blocked(rows: pd.DataFrame, dataset=None) -> set[float]:
    """Incidences (rounded to 1e-6) at which the measured curve has a beam-block gap.

    A gap is no point within :data:`BEAM_BLOCK_DEG` of the retro-direction ``s = -theta_i`` but
    points on both sides of it. A beam block is the instrument's: a dataset imported from another instrument's
    file (meta.json ``instrument.format``: rgl-bsdf, merl, pgii, ...) has none, even where its
    geometries (a plan's) skip the retro-direction, nor does a simulation (kind other than
    ``measured``): empty.

    Parameters
    ----------
    rows : pandas.DataFrame
        The measurement's in-plane rows, with ``theta_i`` and ``s`` (degrees).
    dataset : Dataset, optional
        The dataset the rows are from, to tell an instrument's measurement from others.

    Returns
    -------
    set of float
        The incidence polar angles (degrees) with a gap.
    """
    if dataset is not None:
        instrument = dataset.meta.get("instrument")
        if dataset.kind != "measured" or (isinstance(instrument, dict) and instrument.get("format")):
            return set()
    out = set()
    for theta_i, r in rows.groupby(rows["theta_i"].round(6)):
        s = r["s"].to_numpy(float) + float(theta_i)
        if not np.any(np.abs(s) < BEAM_BLOCK_DEG) and np.any(s < 0) and np.any(s > 0):
            out.add(float(theta_i))
    return out


def sim_inplane(comparison: Comparison, name: str) -> pd.DataFrame:
    """Normalised in-plane simulated rows (``theta_i, s, wavelength_nm, beta, u_beta``).

    Parameters
    ----------
    comparison : Comparison
        The comparison.
    name : str
        The simulation's name.

    Returns
    -------
    pandas.DataFrame
        Columns ``theta_i``, ``s``, ``phi_i`` (degrees), ``wavelength_nm`` and ``beta``, ``u_beta``
        times ``k(lambda)``; the simulation's own rows where it holds the comparison grid, else the
        rows aligned to the measurement.
    """
    grid = comparison.wavelength_nm
    sim = comparison.view(name)
    norm = comparison.normalisations[name]
    sim_wl = sim.wavelengths_nm
    on_grid = np.all(np.min(np.abs(sim_wl[None, :] - grid[:, None]), axis=1) < 1e-6)
    if on_grid:
        rows = sim.in_plane()
        rows = rows[np.min(np.abs(rows["wavelength_nm"].to_numpy()[:, None] - grid[None, :]),
                           axis=1) < 1e-6].copy()
        rows["wavelength_nm"] = grid[np.argmin(np.abs(rows["wavelength_nm"].to_numpy()[:, None]
                                                      - grid[None, :]), axis=1)]
        k = norm.factor_at(rows["wavelength_nm"].to_numpy())
        return pd.DataFrame({"theta_i": rows["theta_i"].to_numpy(), "s": rows["s"].to_numpy(),
                             "phi_i": rows["phi_i"].to_numpy(),
                             "wavelength_nm": rows["wavelength_nm"].to_numpy(),
                             "beta": k * rows["beta"].to_numpy(),
                             "u_beta": k * rows["u_beta"].to_numpy()})
    frame = comparison.frames[name]
    frame = frame[np.isfinite(frame["s"].to_numpy())]
    return pd.DataFrame({"theta_i": frame["theta_i"].to_numpy(), "s": frame["s"].to_numpy(),
                         "phi_i": frame["phi_i"].to_numpy(),
                         "wavelength_nm": frame["wavelength_nm"].to_numpy(),
                         "beta": frame["beta_sim"].to_numpy(),
                         "u_beta": frame["u_sim"].to_numpy()})


def measured_inplane(comparison: Comparison) -> pd.DataFrame:
    """The measurement's in-plane rows on the comparison grid: geometry, wavelength, ``beta`` and ``u_beta``.

    Parameters
    ----------
    comparison : Comparison
        The comparison.

    Returns
    -------
    pandas.DataFrame
        Columns ``theta_i``, ``s``, ``phi_i`` (degrees), ``wavelength_nm``, ``beta`` and ``u_beta``.
    """
    rows = comparison.measured_compared.in_plane()
    grid = comparison.wavelength_nm
    keep = np.min(np.abs(rows["wavelength_nm"].to_numpy()[:, None] - grid[None, :]), axis=1) < 1e-6
    rows = rows[keep]
    return pd.DataFrame({"theta_i": rows["theta_i"].to_numpy(), "s": rows["s"].to_numpy(),
                         "phi_i": rows["phi_i"].to_numpy(),
                         "wavelength_nm": rows["wavelength_nm"].to_numpy(),
                         "beta": rows["beta"].to_numpy(), "u_beta": rows["u_beta"].to_numpy()})


def luminance_curve(rows: pd.DataFrame, grid: np.ndarray, weights: np.ndarray,
                     correlated: bool = False) -> pd.DataFrame:
    """``Y`` and ``u_Y`` per in-plane geometry (complete spectra on ``grid`` only).

    ``u_Y`` combines the ``u_beta`` of the wavelengths in quadrature (independent errors: the
    instrument reads each wavelength separately) or, when ``correlated``, linearly,
    ``u_Y = sum |w| u_beta``: the simulations are "white" Monte Carlo, one set of photons
    re-weighted for every wavelength, so their errors move together across the spectrum and the
    quadrature sum would understate the band by up to ``sqrt(n_wavelengths)``.

    Parameters
    ----------
    rows : pandas.DataFrame
        In-plane rows with ``theta_i``, ``phi_i``, ``s``, ``wavelength_nm``, ``beta`` and ``u_beta``.
    grid : numpy.ndarray
        The comparison grid (wavelengths in nm, or band codes).
    weights : numpy.ndarray
        Weights with ``Y = weights @ beta`` on ``grid``
        (:func:`compare.colourmatch.band_luminance_weights`).
    correlated : bool, default False
        Add the uncertainties linearly instead of in quadrature.

    Returns
    -------
    pandas.DataFrame
        Columns ``theta_i``, ``s`` (degrees), ``value`` (``Y``) and ``u`` (``u_Y``).
    """
    if rows.empty:
        return pd.DataFrame(columns=["theta_i", "s", "value", "u"])
    idx = np.argmin(np.abs(rows["wavelength_nm"].to_numpy()[:, None] - grid[None, :]), axis=1)
    key = ["theta_i", "phi_i", "s"]
    rows = rows.assign(j=idx)
    b = rows.pivot_table(index=key, columns="j", values="beta", aggfunc="mean")
    u = rows.pivot_table(index=key, columns="j", values="u_beta", aggfunc="mean")
    b = b.reindex(columns=range(grid.size))
    u = u.reindex(columns=range(grid.size))
    complete = b.notna().all(axis=1).to_numpy()
    values = b.to_numpy()[complete] @ weights
    if correlated:
        u_values = u.to_numpy()[complete] @ np.abs(weights)
    else:
        u_values = np.sqrt((u.to_numpy()[complete] ** 2) @ (weights ** 2))
    index = b.index.to_frame(index=False)[complete]
    return pd.DataFrame({"theta_i": index["theta_i"].to_numpy(), "s": index["s"].to_numpy(),
                         "value": values, "u": u_values})


def single_wavelength(rows: pd.DataFrame, wavelength_nm: float) -> pd.DataFrame:
    """The in-plane curve of ``rows`` at one wavelength: ``theta_i``, ``s``, ``value`` and ``u``.

    Parameters
    ----------
    rows : pandas.DataFrame
        In-plane rows with ``theta_i``, ``s``, ``wavelength_nm``, ``beta`` and ``u_beta``.
    wavelength_nm : float
        The wavelength (nm) or band code.

    Returns
    -------
    pandas.DataFrame
        The rows at that wavelength.
    """
    sel = rows[np.abs(rows["wavelength_nm"].to_numpy() - wavelength_nm) < 1e-6]
    return pd.DataFrame({"theta_i": sel["theta_i"].to_numpy(), "s": sel["s"].to_numpy(),
                         "value": sel["beta"].to_numpy(), "u": sel["u_beta"].to_numpy()})


def gapped(s: np.ndarray, y: np.ndarray, theta_i: float) -> tuple[np.ndarray, np.ndarray]:
    """``s, y`` with NaN inserted where a line must not be drawn.

    That is across the beam-blocked retro-direction when the curve has no point there, and across
    holes wider than 1.5 times the usual spacing (missing points are not interpolated by eye).

    Parameters
    ----------
    s : numpy.ndarray
        Signed observation angles (degrees, ascending).
    y : numpy.ndarray
        The values at ``s``.
    theta_i : float
        The incidence polar angle (degrees); the retro-direction is ``s = -theta_i``.

    Returns
    -------
    s, y : numpy.ndarray
        The arrays with NaN at each cut (the inputs themselves when there is none).
    """
    if s.size < 2:
        return s, y
    gaps = np.diff(s)
    usual = float(np.median(gaps))
    retro = -theta_i
    has_retro = bool(np.any(np.abs(s - retro) < BEAM_BLOCK_DEG))
    cut = gaps > 1.5 * usual + 1e-9
    if not has_retro:
        cut |= (s[:-1] < retro) & (s[1:] > retro)
    if not cut.any():
        return s, y
    where = np.flatnonzero(cut) + 1
    return (np.insert(s.astype(float), where, np.nan), np.insert(y.astype(float), where, np.nan))
