"""Interpolation of a radiance-coefficient dataset at geometries and wavelengths inside its data.

Linear in wavelength between the bracketing measured wavelengths (an RGB dataset's channels are
looked up, never mixed); piecewise linear over the data's geometries at a sample rotation
``phi_i`` present in the data: over the signed in-plane angle ``s`` (and ``theta_i``) for
in-plane data, otherwise over a Delaunay triangulation of (``theta_i``,
``sin theta_o cos dphi``, ``sin theta_o sin dphi``), ``dphi = phi_o - phi_i``. A request outside
the data is refused with :class:`~gonio.data.schema.DatasetError`, never extrapolated.

References
----------
scipy.interpolate.LinearNDInterpolator (barycentric interpolation on a Qhull triangulation).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Protocol

import numpy as np
import pandas as pd

from gonio.data.geometry import signed_angle
from gonio.data.schema import ANGLE_TOL_DEG, GEOMETRY, DatasetError


class Dataset(Protocol):
    """What interpolation needs of a dataset.

    :class:`gonio.data.dataset.Dataset` has it; that module imports this one for
    :meth:`~gonio.data.dataset.Dataset.interpolate`, so the type is structural here rather than
    imported.
    """

    table: pd.DataFrame

    @property
    def source(self) -> Any: ...

    @property
    def is_rgb(self) -> bool: ...

    @property
    def bands(self) -> Any: ...

    @property
    def band_column(self) -> str: ...

    def derived(self, key: Any, build: Callable[[], Any]) -> Any: ...

__all__ = ["interpolate"]


def interpolate(dataset: Dataset, theta_i, phi_i, theta_o, phi_o, band):
    """``(beta, u_beta)`` of ``dataset`` at arbitrary geometries and bands inside the data.

    Parameters
    ----------
    dataset : gonio.data.Dataset
        The dataset whose values are interpolated.
    theta_i, phi_i, theta_o, phi_o : array_like
        Fabric-frame angles in degrees (broadcast together with ``band``).
    band : array_like
        Wavelengths in nm for a spectral dataset; channel names (``"R"``, ...) for an RGB one.

    Returns
    -------
    beta, u_beta : numpy.ndarray
        The broadcast shape of the inputs.

    Raises
    ------
    DatasetError
        Any request outside the data (a wavelength outside the range, an unknown channel, a
        sample rotation not in the data, an out-of-plane request on in-plane data, a geometry
        outside the convex hull of the data).
    """
    angles = [np.asarray(a, dtype=float) for a in (theta_i, phi_i, theta_o, phi_o)]
    band_arr = np.asarray(band, dtype=object if dataset.is_rgb else float)
    shape = np.broadcast_shapes(*(a.shape for a in angles), band_arr.shape)
    ti, pi_, to, po = (np.broadcast_to(a, shape).ravel() for a in angles)
    bands_req = np.broadcast_to(band_arr, shape).ravel()
    pi_ = np.mod(pi_, 360.0)
    bands = dataset.bands
    if dataset.is_rgb:
        index = {c: k for k, c in enumerate(bands)}
        unknown = [str(c) for c in bands_req if str(c) not in index]
        if unknown:
            raise DatasetError(f"channel {unknown[0]!r} is not in the data "
                               f"(channels {', '.join(bands)})", file=dataset.source)
        j_exact = np.array([index[str(c)] for c in bands_req], dtype=int)
    else:
        wl = bands_req.astype(float)
        outside = (wl < bands[0] - 1e-9) | (wl > bands[-1] + 1e-9)
        if outside.any():
            raise DatasetError(
                f"wavelength {wl[outside][0]:g} nm is outside the data "
                f"({bands[0]:g}..{bands[-1]:g} nm)", file=dataset.source,
                hint="interpolation never extrapolates")
    beta = np.empty(ti.size)
    u_beta = np.empty(ti.size)
    rotations = np.unique(dataset.table["phi_i"].to_numpy())
    for rotation in np.unique(pi_):
        sel = np.flatnonzero(np.abs(pi_ - rotation) < ANGLE_TOL_DEG)
        match = rotations[np.abs(rotations - rotation) < ANGLE_TOL_DEG]
        if match.size == 0:
            raise DatasetError(f"no data at sample rotation phi_i={rotation:g}",
                               file=dataset.source,
                               hint=f"the data have phi_i in {sorted(set(rotations.tolist()))}")
        interp = _geometry_interpolator(dataset, float(match[0]))
        spectra_b, spectra_u = interp(ti[sel], to[sel], po[sel] - rotation)
        rows = np.arange(sel.size)
        if dataset.is_rgb:
            b, u = spectra_b[rows, j_exact[sel]], spectra_u[rows, j_exact[sel]]
        elif len(bands) > 1:
            # linear interpolation in wavelength, row by row
            w = wl[sel]
            j = np.clip(np.searchsorted(bands, w) - 1, 0, len(bands) - 2)
            w0, w1 = bands[j], bands[j + 1]
            f = np.clip((w - w0) / (w1 - w0), 0.0, 1.0)
            b = (1 - f) * spectra_b[rows, j] + f * spectra_b[rows, j + 1]
            u = (1 - f) * spectra_u[rows, j] + f * spectra_u[rows, j + 1]
        else:
            b, u = spectra_b[:, 0], spectra_u[:, 0]
        if not np.all(np.isfinite(b)):
            k = int(np.flatnonzero(~np.isfinite(b))[0])
            where = (f"channel {bands_req[sel][k]}" if dataset.is_rgb
                     else f"{float(bands_req[sel][k]):g} nm")
            raise DatasetError(
                f"geometry theta_i={ti[sel][k]:g}, phi_i={rotation:g}, theta_o={to[sel][k]:g}, "
                f"phi_o={po[sel][k]:g} at {where} is outside the measured data",
                file=dataset.source, hint="interpolation never extrapolates")
        beta[sel] = b
        u_beta[sel] = u
    return beta.reshape(shape), u_beta.reshape(shape)


def _geometry_interpolator(dataset: Dataset, rotation: float) -> Callable:
    """A function (theta_i, theta_o, dphi) -> (beta per band, u_beta per band) for one phi_i.

    Built once per dataset and rotation (:meth:`Dataset.derived`).
    """
    return dataset.derived(("geometry interpolator", rotation),
                           lambda: _build_geometry_interpolator(dataset, rotation))


def _build_geometry_interpolator(dataset: Dataset, rotation: float) -> Callable:
    from scipy.interpolate import LinearNDInterpolator

    table = dataset.table
    t = table[np.abs(table["phi_i"].to_numpy() - rotation) < ANGLE_TOL_DEG]
    band_col = dataset.band_column
    bands = list(dataset.bands)
    pivot_b = t.pivot_table(index=list(GEOMETRY), columns=band_col, values="beta",
                            aggfunc="first").reindex(columns=bands)
    pivot_u = t.pivot_table(index=list(GEOMETRY), columns=band_col, values="u_beta",
                            aggfunc="first").reindex(columns=bands)
    index = pivot_b.index.to_frame(index=False)
    values_b = pivot_b.to_numpy(dtype=float)
    values_u = pivot_u.to_numpy(dtype=float)
    theta_i = index["theta_i"].to_numpy()
    theta_o = index["theta_o"].to_numpy()
    dphi = np.mod(index["phi_o"].to_numpy() - rotation, 360.0)
    s = signed_angle(theta_i, 0.0, theta_o, dphi)
    in_plane = bool(np.all(np.isfinite(s)))
    source = dataset.source
    n_theta_i = np.unique(theta_i).size

    def coords(ti, to, dp, *, plane: bool):
        if plane:
            return signed_angle(ti, 0.0, to, np.mod(dp, 360.0))
        rad_o = np.radians(to)
        rad_d = np.radians(dp)
        return np.sin(rad_o) * np.cos(rad_d), np.sin(rad_o) * np.sin(rad_d)

    data_xy = [s] if in_plane else list(coords(theta_i, theta_o, dphi, plane=False))
    if n_theta_i > 1:
        data_xy = [theta_i] + data_xy
    points = np.column_stack(data_xy)
    stacked = np.concatenate([values_b, values_u], axis=1)
    n_band = values_b.shape[1]
    reason = ""
    if points.shape[1] == 1:
        order = np.argsort(points[:, 0])
        xs = points[order, 0]
        ys = stacked[order]

        def interp_points(q):
            q = q[:, 0]
            out = np.full((q.size, ys.shape[1]), np.nan)
            for k in range(ys.shape[1]):
                out[:, k] = np.interp(q, xs, ys[:, k], left=np.nan, right=np.nan)
            return out
    else:
        try:
            lin = LinearNDInterpolator(points, stacked)
        except Exception as exc:  # Qhull: degenerate geometry sets (e.g. collinear points)
            lin = None
            reason = str(exc).splitlines()[0]

        def interp_points(q):
            if lin is None:
                raise DatasetError(f"cannot interpolate over these geometries ({reason})",
                                   file=source)
            return lin(q)

    single_theta_i = float(theta_i[0]) if n_theta_i == 1 else None

    def interpolate_rotation(ti, to, dp):
        ti = np.asarray(ti, dtype=float)
        if in_plane:
            q_s = coords(ti, to, dp, plane=True)
            if not np.all(np.isfinite(q_s)):
                raise DatasetError("the data are in the plane of incidence only; an "
                                   "out-of-plane geometry cannot be interpolated", file=source)
            cols = [q_s]
        else:
            cols = list(coords(ti, to, dp, plane=False))
        if single_theta_i is not None:
            off = np.abs(ti - single_theta_i) > ANGLE_TOL_DEG
            if off.any():
                raise DatasetError(f"incidence theta_i={ti[off][0]:g} is outside the data "
                                   f"(only theta_i={single_theta_i:g})", file=source)
        else:
            cols = [ti] + cols
        q = np.column_stack(cols)
        out = interp_points(q)
        return out[:, :n_band], out[:, n_band:]

    return interpolate_rotation
