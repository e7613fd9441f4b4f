"""Putting a simulation on the measured dataset's geometries and wavelengths.

The comparison is made on what the datasets share:

- **wavelengths**: the measured wavelengths that lie inside the wavelength range of *every*
  simulated dataset (one grid for the whole comparison, so the measured colour and all curves
  use the same wavelengths). A simulation whose grid does not contain them is linearly
  interpolated in wavelength (``Dataset.interpolate``). Grids that share fewer than
  :data:`MIN_SHARED_WAVELENGTHS` wavelengths, or less than :data:`MIN_SHARED_FRACTION` of the
  measured ones, cannot be reconciled and are refused with a :class:`~compare.errors.CompareError`.
- **geometries**: every measured geometry where the simulation has the same geometry (to 1e-6
  deg), or else where ``Dataset.interpolate`` can interpolate it (piecewise linear inside the
  simulation's geometries; never extrapolated). Measured geometries outside the simulation are
  left out of the comparison (logged); none in common is refused.

The result is one table per simulation with the measured and raw simulated values side by side.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence

import numpy as np
import pandas as pd

from gonio.data import GEOMETRY, Dataset, DatasetError, signed_angle

from .errors import CompareError

__all__ = ["MIN_SHARED_FRACTION", "MIN_SHARED_WAVELENGTHS", "align", "shared_wavelengths"]

log = logging.getLogger(__name__)

#: At least this many wavelengths must be shared by the measured and every simulated dataset.
MIN_SHARED_WAVELENGTHS = 3
#: ... and at least this fraction of the measured wavelengths.
MIN_SHARED_FRACTION = 0.5
_KEY_DECIMALS = 6


def _range(wl: np.ndarray) -> str:
    step = np.unique(np.round(np.diff(wl), 6))
    step_text = f" step {step[0]:g}" if step.size == 1 else ""
    return f"{wl[0]:g}..{wl[-1]:g} nm{step_text} ({wl.size} wavelengths)"


def shared_wavelengths(measured: Dataset, simulated: Sequence[Dataset]) -> np.ndarray:
    """Measured wavelengths inside every simulation's wavelength range.

    Parameters
    ----------
    measured : Dataset
        The measurement; its wavelengths (nm) are the candidates.
    simulated : sequence of Dataset
        The simulations; each must cover the kept wavelengths.

    Returns
    -------
    numpy.ndarray
        The measured wavelengths (nm, ascending) inside every simulation's range.

    Raises
    ------
    CompareError
        When fewer than ``MIN_SHARED_WAVELENGTHS`` (or ``MIN_SHARED_FRACTION`` of the measured
        wavelengths) remain; the message names the dataset and both grids.
    """
    grid = measured.wavelengths_nm
    if grid.size < MIN_SHARED_WAVELENGTHS:
        raise CompareError(
            f"measured dataset '{measured.name}' ({measured.source}) has {grid.size} "
            f"wavelength(s); a comparison needs a spectrum of at least {MIN_SHARED_WAVELENGTHS} "
            "(per-wavelength normalisation and colour); measure the plan's wavelength range")
    keep = np.ones(grid.size, dtype=bool)
    for sim in simulated:
        wl = sim.wavelengths_nm
        inside = (grid >= wl[0] - 1e-6) & (grid <= wl[-1] + 1e-6)
        if inside.sum() < max(MIN_SHARED_WAVELENGTHS, MIN_SHARED_FRACTION * grid.size):
            raise CompareError(
                f"wavelength grids cannot be reconciled: simulated dataset '{sim.name}' "
                f"({sim.source}) covers {_range(wl)}, measured dataset '{measured.name}' "
                f"({measured.source}) covers {_range(grid)}; only {int(inside.sum())} measured "
                f"wavelengths fall inside the simulation (need at least "
                f"{max(MIN_SHARED_WAVELENGTHS, int(np.ceil(MIN_SHARED_FRACTION * grid.size)))}); "
                "simulate the measured wavelengths")
        keep &= inside
    if keep.sum() < MIN_SHARED_WAVELENGTHS:
        raise CompareError(
            f"the simulated datasets share only {int(keep.sum())} of the measured wavelengths of "
            f"'{measured.name}' ({measured.source}); simulate them on a common wavelength range")
    if not keep.all():
        log.warning("comparing on %s: measured wavelengths outside a simulation's range are "
                    "left out", _range(grid[keep]))
    return grid[keep]


def _keys(frame: pd.DataFrame) -> pd.DataFrame:
    return frame[list(GEOMETRY) + ["wavelength_nm"]].round(_KEY_DECIMALS)


def align(measured: Dataset, simulated: Dataset, wavelength_nm) -> pd.DataFrame:
    """Measured and raw simulated values at the measured geometries, on ``wavelength_nm``.

    Parameters
    ----------
    measured, simulated : gonio.data.Dataset
        The measurement and one simulation (as compared: :func:`compare.bands.prepare`).
    wavelength_nm : array_like
        Comparison grid (a subset of the measured wavelengths, inside the simulation's range).

    Returns
    -------
    pandas.DataFrame
        Columns ``theta_i, phi_i, theta_o, phi_o, s, wavelength_nm, beta_meas, u_meas,
        beta_sim_raw, u_sim_raw, interpolated`` (``s`` NaN out of the plane of incidence), sorted
        by geometry and wavelength.

    Raises
    ------
    CompareError
        When no measured geometry can be matched or interpolated in the simulation.
    """
    grid = np.asarray(wavelength_nm, dtype=float)
    meas = measured.table
    meas = meas[np.isin(np.round(meas["wavelength_nm"].to_numpy(), _KEY_DECIMALS),
                        np.round(grid, _KEY_DECIMALS))]
    frame = meas[list(GEOMETRY) + ["wavelength_nm", "beta", "u_beta"]].rename(
        columns={"beta": "beta_meas", "u_beta": "u_meas"}).reset_index(drop=True)
    sim = simulated.table[list(GEOMETRY) + ["wavelength_nm", "beta", "u_beta"]]
    sim_keyed = pd.concat([_keys(sim), sim[["beta", "u_beta"]].rename(
        columns={"beta": "beta_sim_raw", "u_beta": "u_sim_raw"})], axis=1)
    keyed = pd.concat([_keys(frame).add_suffix("_key"), frame], axis=1)
    merged = keyed.merge(sim_keyed, how="left",
                         left_on=[c + "_key" for c in list(GEOMETRY) + ["wavelength_nm"]],
                         right_on=list(GEOMETRY) + ["wavelength_nm"], suffixes=("", "_s"))
    merged = merged[list(frame.columns) + ["beta_sim_raw", "u_sim_raw"]].copy()
    missing = merged["beta_sim_raw"].isna().to_numpy()
    merged["interpolated"] = missing
    if missing.any():
        cols = [merged.loc[missing, c].to_numpy() for c in list(GEOMETRY) + ["wavelength_nm"]]
        try:
            b, u = simulated.interpolate(*cols)
            merged.loc[missing, "beta_sim_raw"] = b
            merged.loc[missing, "u_sim_raw"] = u
        except DatasetError:
            # some geometries lie outside the simulation: interpolate geometry by geometry
            sub = merged[missing]
            for _, rows in sub.groupby(list(GEOMETRY), sort=False):
                try:
                    b, u = simulated.interpolate(*(rows[c].to_numpy() for c in
                                                   list(GEOMETRY) + ["wavelength_nm"]))
                except DatasetError:
                    continue
                merged.loc[rows.index, "beta_sim_raw"] = b
                merged.loc[rows.index, "u_sim_raw"] = u
    dropped = merged["beta_sim_raw"].isna().to_numpy()
    if dropped.all():
        raise CompareError(
            f"simulated dataset '{simulated.name}' ({simulated.source}) shares no geometry with "
            f"measured dataset '{measured.name}' ({measured.source}), not even by interpolation; "
            "simulate at the measured geometries (e.g. simulate fabric --plan PLAN.toml)")
    if dropped.any():
        n_geo = merged.loc[dropped, list(GEOMETRY)].drop_duplicates().shape[0]
        log.warning("%d measured geometries lie outside simulated dataset '%s' and are left out",
                    n_geo, simulated.name)
    merged = merged[~dropped].reset_index(drop=True)
    n_interp = merged.loc[merged["interpolated"], list(GEOMETRY)].drop_duplicates().shape[0]
    if n_interp:
        log.info("'%s': %d geometries interpolated to the measured ones", simulated.name, n_interp)
    merged.insert(4, "s", signed_angle(merged["theta_i"], merged["phi_i"], merged["theta_o"],
                                       merged["phi_o"]))
    return merged.sort_values(list(GEOMETRY) + ["wavelength_nm"], kind="mergesort"
                              ).reset_index(drop=True)
