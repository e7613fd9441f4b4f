r"""Normalisation of a simulation at the normal direction (docs/physics.md section 8).

Simulated values :math:`C` are proportional to the radiance coefficient. They are scaled, per
wavelength (per channel when the measurement is RGB: :mod:`compare.bands`; a relative measurement
is normalised the same way, only shapes are needed), by

.. math::

    k(\lambda) = \frac{\beta_\mathrm{meas}(0, 0; \lambda)}{C(0, 0; \lambda)},
    \qquad u_k = k \sqrt{(u_{\beta}/\beta_\mathrm{meas})^2 + (u_C / C)^2},

where ``(0, 0)`` is normal incidence and normal observation. :math:`k` multiplies every simulated
``beta`` and its ``u_beta`` (the factor's own uncertainty is reported separately, not folded into
the curves: it is one scale error shared by all points of a wavelength; the report shows the
overall NRMSE at ``k - u_k`` and ``k + u_k``,
:meth:`compare.comparison.Comparison.nrmse_with_factor_shifted`).

The normal/normal value
-----------------------
The instrument refuses to observe within 5 degrees of the source, so the measured normal/normal
point is normally absent. It is then *estimated* per wavelength from the normal-incidence
(``theta_i = 0``) in-plane points, as a function of the signed observation angle ``s``:

1. take the points with ``0 < |s| <= window`` (default 20 deg); at least one on each side of the
   normal (``s < 0`` source side, ``s > 0`` mirror side) and three in all are required, otherwise
   the estimate is refused with a :class:`~compare.errors.CompareError` naming the dataset and
   the angles found;
2. the estimate is the intercept of an unweighted least-squares quadratic
   :math:`\beta(s) \approx a + b s + c s^2` through those points. The intercept is a linear
   combination :math:`a = \sum_j L_j \beta_j` of the data, so its data uncertainty is
   :math:`u_\mathrm{data} = \sqrt{\sum_j L_j^2 u_{\beta,j}^2}` (independent points);
3. a model-error term :math:`u_\mathrm{model} = |a - \beta_\mathrm{lin}|`, the difference from
   the linear interpolation at ``s = 0`` between the nearest point on each side. For a curve
   :math:`a + c s^2 + O(s^4)` sampled at ``+-10, +-20`` deg the linear estimate is off by
   :math:`c \cdot 100\,\mathrm{deg}^2` while the quadratic is exact up to the quartic term,
   so this term bounds the quadratic's error generously;
4. :math:`u = \sqrt{u_\mathrm{data}^2 + u_\mathrm{model}^2}`.

Points from several sample rotations (``phi_i`` planes) at normal incidence are pooled: they all
tend to the same normal/normal value. If the dataset holds the normal/normal geometry itself
(``theta_i = theta_o = 0``), that value is used as it is (averaged over rotations; ``u`` from its
``u_beta``). A normal value that is zero, negative or not finite is refused: a factor cannot be
built on it (docs/quality.md B).
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from gonio.data import Dataset

from .errors import CompareError

__all__ = [
    "DEFAULT_WINDOW_DEG",
    "Normalisation",
    "NormalValue",
    "check_normal_values",
    "estimate_normal_value",
    "intercept_weights",
    "normal_selection",
    "normalisation_factor",
]

log = logging.getLogger(__name__)

#: Half-width (degrees of signed observation angle) of the window used for the estimate.
DEFAULT_WINDOW_DEG = 20.0
#: Points required on each side of the normal, and in all, inside the window.
MIN_PER_SIDE = 1
MIN_POINTS = 3
_S_TOL = 1e-6

METHOD_TEXT = (
    "k(lambda) = beta_meas(0,0) / C(0,0) per wavelength, applied to every simulated beta and "
    "u_beta. A normal/normal value present in a dataset is used as is; otherwise it is estimated "
    "at normal incidence as the intercept of an unweighted least-squares quadratic in the signed "
    "observation angle s through the points with 0 < |s| <= {window:g} deg (>= 1 on each side, "
    ">= 3 in all), with u = sqrt(u_data^2 + u_model^2): u_data propagated from u_beta, u_model = "
    "|quadratic - linear interpolation between the nearest point on each side|."
)


@dataclass(frozen=True)
class NormalValue:
    """The normal/normal radiance coefficient of one dataset, per wavelength.

    Attributes
    ----------
    wavelength_nm : numpy.ndarray
        The dataset's wavelengths.
    value : numpy.ndarray
        ``beta(0, 0)`` (or ``C(0, 0)``) at each wavelength.
    u : numpy.ndarray
        Total standard uncertainty, ``sqrt(u_data**2 + u_model**2)``.
    u_data : numpy.ndarray
        Part propagated from the points' ``u_beta``.
    u_model : numpy.ndarray
        ``|quadratic - linear|`` estimate difference (0 where the point was measured).
    how : str
        ``"measured"`` (the point exists), ``"estimated"`` or ``"mixed"``.
    s_used : tuple of float
        Signed observation angles used (at the first wavelength), for the report.
    """

    wavelength_nm: np.ndarray
    value: np.ndarray
    u: np.ndarray
    u_data: np.ndarray
    u_model: np.ndarray
    how: str
    s_used: tuple[float, ...]

    def at(self, wavelength_nm) -> tuple[np.ndarray, np.ndarray]:
        """``(value, u)`` linearly interpolated to ``wavelength_nm`` (inside the dataset's range).

        Parameters
        ----------
        wavelength_nm : array_like
            The wavelengths (nm).

        Returns
        -------
        value : numpy.ndarray
            ``beta(0, 0)`` at each wavelength.
        u : numpy.ndarray
            Its standard uncertainty.
        """
        wl = np.asarray(wavelength_nm, dtype=float)
        return (np.interp(wl, self.wavelength_nm, self.value),
                np.interp(wl, self.wavelength_nm, self.u))


def _nm(wavelength: float) -> str:
    return f"{wavelength:g} nm"


def _describe(dataset: Dataset) -> str:
    return f"dataset '{dataset.name}' ({dataset.source})"


def intercept_weights(s: np.ndarray) -> np.ndarray:
    """Weights ``w`` with ``w @ beta`` the intercept of a least-squares quadratic in ``s``.

    The quadratic is unweighted, through ``(s, beta)``: the estimate is linear in the values.

    Parameters
    ----------
    s : numpy.ndarray
        The signed observation angles (degrees) of the points.

    Returns
    -------
    numpy.ndarray
        One weight per point.
    """
    scale = max(float(np.max(np.abs(s))), 1.0)  # conditioning: fit in s / max|s|
    x = s / scale
    design = np.column_stack([np.ones_like(x), x, x * x])
    return np.linalg.pinv(design)[0]


def normal_selection(dataset: Dataset, s: np.ndarray, wavelength: float, window_deg: float,
                     band_label: Callable[[float], str] = _nm, use_exact: bool = True) -> tuple[bool, np.ndarray]:
    """Which normal-incidence points of one wavelength give ``beta(0, 0)``.

    ``s`` are the signed observation angles of the dataset's in-plane normal-incidence rows at
    ``wavelength``. Returns ``(True, mask)`` when the normal/normal point itself is there (its
    mean is the value), else ``(False, mask)`` of the points of the quadratic fit. Raises
    :class:`CompareError` when the window holds too few points (shared by
    :func:`estimate_normal_value` and :mod:`compare.residual`). ``use_exact=False``: estimate even
    where the normal/normal point exists, from the same neighbours as a measurement without it.

    Parameters
    ----------
    dataset : Dataset
        The dataset, named in the message.
    s : numpy.ndarray
        The signed observation angles (degrees) of its normal-incidence in-plane rows at ``wavelength``.
    wavelength : float
        The wavelength (nm) or band code.
    window_deg : float
        Largest |s| (degrees) of the points of the fit.
    band_label : callable, optional
        Label of a band in the message (default: the wavelength in nm).
    use_exact : bool, default True
        Use the normal/normal point itself where it is there.

    Returns
    -------
    exact : bool
        Whether the mask selects the normal/normal point itself.
    mask : numpy.ndarray
        Boolean mask over ``s``.

    Raises
    ------
    CompareError
        When the window holds too few points on either side of the normal.
    """
    exact = np.abs(s) < _S_TOL
    if exact.any() and use_exact:
        return True, exact
    near = (np.abs(s) <= window_deg + _S_TOL) & ~exact
    left, right = near & (s < 0), near & (s > 0)
    too_few = left.sum() < MIN_PER_SIDE or right.sum() < MIN_PER_SIDE or near.sum() < MIN_POINTS
    if too_few and exact.any():
        return True, exact        # like for like is impossible: the dataset's own normal point
    if too_few:
        def fmt(mask):
            return "[" + ", ".join(f"{x:g}" for x in np.unique(s[mask])) + "]"
        raise CompareError(
            f"{_describe(dataset)}: cannot estimate the normal/normal value beta(0, 0) at "
            f"{band_label(wavelength)}: it needs normal-incidence points within |s| <= "
            f"{window_deg:g} deg on BOTH sides of the normal (at least {MIN_PER_SIDE} on each "
            f"side, {MIN_POINTS} in all); found source side s < 0: {fmt(left)}, mirror side "
            f"s > 0: {fmt(right)} "
            "(measure e.g. s = -20, -10, 10, 20 at theta_i = 0, or widen --normal-window)")
    return False, near


def check_normal_values(dataset: Dataset, wavelengths: np.ndarray, value: np.ndarray,
                        measured: np.ndarray, band_label: Callable[[float], str] = _nm) -> None:
    """Refuse a normal value that is zero, negative or not finite (:class:`CompareError`).

    Parameters
    ----------
    dataset : Dataset
        The dataset, named in the message.
    wavelengths : numpy.ndarray
        The wavelengths (nm) or band codes.
    value : numpy.ndarray
        The normal/normal value ``beta(0, 0)`` at each.
    measured : numpy.ndarray
        Whether each value was measured (True) or estimated (False).
    band_label : callable, optional
        Label of a band in the message (default: the wavelength in nm).

    Raises
    ------
    CompareError
        When a value is zero, negative or not finite.
    """
    bad = ~np.isfinite(value) | (value <= 0)
    if bad.any():
        k = int(np.flatnonzero(bad)[0])
        what = "measured" if measured[k] else "estimated"
        raise CompareError(
            f"{_describe(dataset)}: the {what} normal/normal value beta(0, 0) at "
            f"{band_label(wavelengths[k])} is {value[k]:g}; it must be a positive finite number "
            "to normalise at the normal direction (check the normal-incidence data)")


def _fit_intercept(s: np.ndarray, beta: np.ndarray, u_beta: np.ndarray
                   ) -> tuple[float, float, float]:
    """Quadratic intercept, its propagated uncertainty and the linear-vs-quadratic difference."""
    weights = intercept_weights(s)               # intercept = weights @ beta
    quadratic = float(weights @ beta)
    u_data = float(np.sqrt(np.sum((weights * u_beta) ** 2)))
    left_s = np.max(s[s < 0])
    right_s = np.min(s[s > 0])
    b_left = float(np.mean(beta[np.abs(s - left_s) < _S_TOL]))
    b_right = float(np.mean(beta[np.abs(s - right_s) < _S_TOL]))
    linear = (b_left * right_s - b_right * left_s) / (right_s - left_s)
    return quadratic, u_data, abs(quadratic - linear)


def estimate_normal_value(dataset: Dataset, window_deg: float = DEFAULT_WINDOW_DEG,
                          band_label: Callable[[float], str] = _nm, use_exact: bool = True) -> NormalValue:
    """``beta(0, 0)`` of ``dataset`` per wavelength: the measured point, or the estimate above.

    Parameters
    ----------
    dataset : gonio.data.Dataset
        Measured or simulated radiance-coefficient dataset.
    window_deg : float
        Largest ``|s|`` (degrees) of the normal-incidence points used for the estimate.
    band_label : callable
        How a band is named in messages (``"550 nm"``; ``"channel R"`` in an RGB comparison,
        :mod:`compare.bands`).
    use_exact : bool
        ``False``: ignore a normal/normal point and estimate from the neighbours. A simulation is
        normalised like for like: when the measurement has no normal/normal point (the instrument
        cannot observe there), the simulation's value is estimated from the same neighbouring
        angles, not read at its own normal point -- a narrow backscatter peak the measurement
        cannot see would otherwise set the whole scale (the felt Monte Carlo's retro-reflection:
        docs/physics.md section 8).

    Returns
    -------
    NormalValue

    Raises
    ------
    CompareError
        No normal-incidence data, not enough points on both sides of the normal inside the
        window, or a normal value that is zero, negative or not finite.

    Examples
    --------
    >>> import numpy as np
    >>> from gonio.data import make_dataset, new_meta, in_plane_geometry
    >>> s = np.array([-20.0, -10.0, 10.0, 20.0])
    >>> theta_o, phi_o = in_plane_geometry(0.0, s)
    >>> table = dict(theta_i=0.0 * s, phi_i=0.0 * s, theta_o=theta_o, phi_o=phi_o,
    ...              wavelength_nm=550.0 + 0 * s, beta=0.5 - 1e-4 * s**2, u_beta=0.001 + 0 * s,
    ...              n=1 + 0 * s)
    >>> ds = make_dataset(table, new_meta("measured", {"name": "demo"}))
    >>> round(float(estimate_normal_value(ds).value[0]), 6)
    0.5
    """
    if not window_deg > 0:
        raise CompareError(f"the normal-estimate window must be positive, got {window_deg:g} deg")
    rows = dataset.in_plane(theta_i=0.0)
    if rows.empty:
        raise CompareError(
            f"{_describe(dataset)} has no in-plane points at normal incidence (theta_i = 0): the "
            "normal/normal value beta(0, 0) needed for the normalisation cannot be obtained; "
            "include normal incidence with observation angles on both sides of the normal")
    wavelengths = dataset.wavelengths_nm
    n_wl = wavelengths.size
    value = np.empty(n_wl)
    u_data = np.empty(n_wl)
    u_model = np.zeros(n_wl)
    measured = np.zeros(n_wl, dtype=bool)
    s_used: tuple[float, ...] = ()
    wl_rows = rows["wavelength_nm"].to_numpy()
    s_all = rows["s"].to_numpy()
    beta_all = rows["beta"].to_numpy()
    u_all = rows["u_beta"].to_numpy()
    for k, wl in enumerate(wavelengths):
        sel = np.abs(wl_rows - wl) < 1e-9
        s, beta, u_beta = s_all[sel], beta_all[sel], u_all[sel]
        is_exact, sel_k = normal_selection(dataset, s, wl, window_deg, band_label, use_exact)
        if is_exact:
            exact = sel_k
            value[k] = float(np.mean(beta[exact]))
            u_data[k] = float(np.sqrt(np.sum(u_beta[exact] ** 2))) / exact.sum()
            measured[k] = True
            if not s_used:
                s_used = (0.0,)
            continue
        near = sel_k
        value[k], u_data[k], u_model[k] = _fit_intercept(s[near], beta[near], u_beta[near])
        if not s_used:
            s_used = tuple(float(x) for x in np.unique(s[near]))
    check_normal_values(dataset, wavelengths, value, measured, band_label)
    how = "measured" if measured.all() else ("estimated" if not measured.any() else "mixed")
    log.debug("%s: normal value %s (%s)", dataset.name, how, s_used)
    return NormalValue(wavelength_nm=wavelengths, value=value,
                       u=np.hypot(u_data, u_model), u_data=u_data, u_model=u_model, how=how,
                       s_used=s_used)


@dataclass(frozen=True)
class Normalisation:
    """Per-wavelength factor ``k`` putting one simulation on the measured scale.

    Attributes
    ----------
    wavelength_nm : numpy.ndarray
        The comparison grid.
    factor, u_factor : numpy.ndarray
        ``k`` and its standard uncertainty on that grid.
    measured, simulated : NormalValue
        The normal values of the two datasets (on their own grids).
    measured_value, simulated_value : numpy.ndarray
        ``beta_meas(0, 0)`` and ``C(0, 0)`` on the comparison grid.
    """

    wavelength_nm: np.ndarray
    factor: np.ndarray
    u_factor: np.ndarray
    measured: NormalValue
    simulated: NormalValue
    measured_value: np.ndarray
    simulated_value: np.ndarray

    def _index(self, wavelength_nm) -> np.ndarray:
        wl = np.asarray(wavelength_nm, dtype=float)
        idx = np.searchsorted(self.wavelength_nm, wl - 1e-9)
        idx = np.clip(idx, 0, self.wavelength_nm.size - 1)
        if not np.allclose(self.wavelength_nm[idx], wl, atol=1e-6, rtol=0):
            raise ValueError("factor_at: wavelength not on the comparison grid")
        return idx

    def factor_at(self, wavelength_nm) -> np.ndarray:
        """``k`` at each of ``wavelength_nm`` (values of the comparison grid).

        Parameters
        ----------
        wavelength_nm : array_like
            Wavelengths (nm) or band codes of the comparison grid.

        Returns
        -------
        numpy.ndarray
            The factor ``k`` at each.

        Raises
        ------
        ValueError
            When a value is not on the comparison grid.
        """
        return self.factor[self._index(wavelength_nm)]

    def u_factor_at(self, wavelength_nm) -> np.ndarray:
        """``u_k`` at each of ``wavelength_nm`` (values of the comparison grid).

        Parameters
        ----------
        wavelength_nm : array_like
            Wavelengths (nm) or band codes of the comparison grid.

        Returns
        -------
        numpy.ndarray
            The standard uncertainty ``u_k`` at each.

        Raises
        ------
        ValueError
            When a value is not on the comparison grid.
        """
        return self.u_factor[self._index(wavelength_nm)]


def normalisation_factor(measured: NormalValue, simulated: NormalValue,
                         wavelength_nm) -> Normalisation:
    """``k = beta_meas(0,0) / C(0,0)`` on ``wavelength_nm`` (inside both datasets' ranges).

    Both normal values are linearly interpolated in wavelength where the grid is not theirs (the
    comparison grid is a subset of the measured wavelengths, so only the simulation may be).

    Parameters
    ----------
    measured, simulated : NormalValue
        The normal/normal values of the measurement and of the simulation
        (:func:`estimate_normal_value`).
    wavelength_nm : array_like
        The comparison grid.

    Returns
    -------
    Normalisation
        The factor ``k`` and its standard uncertainty on the grid, with both normal values.
    """
    wl = np.asarray(wavelength_nm, dtype=float)
    m, u_m = measured.at(wl)
    c, u_c = simulated.at(wl)
    k = m / c
    u_k = k * np.hypot(u_m / m, u_c / c)
    return Normalisation(wavelength_nm=wl, factor=k, u_factor=u_k, measured=measured,
                         simulated=simulated, measured_value=m, simulated_value=c)
