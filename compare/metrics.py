r"""Curve errors between a measured dataset and a normalised simulation.

For the residuals :math:`d_j = k\,C_j - \beta_{\mathrm{meas},j}` over a set of points ``j``
(geometry x wavelength, all shared wavelengths pooled):

.. math::

    \mathrm{RMSE} = \sqrt{\tfrac{1}{N}\sum_j d_j^2}, \qquad
    \mathrm{NRMSE} = \mathrm{RMSE} / \overline{\beta_\mathrm{meas}}, \qquad
    \max_j |d_j| \text{ and the geometry and wavelength where it occurs.}

They are computed per incidence angle ``theta_i`` (all shared geometries of that incidence:
the in-plane curve, plus any out-of-plane points; sample rotations pooled) and overall (every
shared point). The units are those of ``beta`` (radiance coefficient), not ``beta / pi``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pandas as pd

__all__ = ["DEFAULT_MAX_HUE_DIFF", "DEFAULT_MAX_LEVEL_RATIO", "DEFAULT_MAX_NRMSE", "DEFAULT_MAX_SAT_DIFF", "CurveError",
           "angle_key", "curve_error", "curve_errors"]

#: What "a match" means (``compare check``'s default thresholds, stated in every report; chosen
#: from the reference results of docs/physics.md section 8: the published model hues lie within
#: 0.01 of the measured one, saturations within 0.01): overall NRMSE of the normalised curves,
#: ``|dh|`` (turns of the hue circle) and ``|ds|``.
DEFAULT_MAX_NRMSE = 0.10
DEFAULT_MAX_HUE_DIFF = 0.02
DEFAULT_MAX_SAT_DIFF = 0.05
#: ``compare check --max-level-ratio``: largest ratio between the model's absolute level and the measured one,
#: ``max(k_Y, 1/k_Y)`` (:class:`compare.comparison.Level`). 1.5: a model at the measured level within its
#: Monte Carlo error and the reference's calibration (a few %) passes with a wide margin, one scaled by 2 (or
#: 1/2) fails; a model fitted in shape only, several times too dark, fails as it should (docs/notes/fit-trust.md,
#: "The level").
DEFAULT_MAX_LEVEL_RATIO = 1.5


@dataclass(frozen=True)
class CurveError:
    """Error figures of one set of points.

    Attributes
    ----------
    rmse, nrmse, max_abs : float
        See the module docstring (``nrmse`` is NaN when the measured mean is not positive).
    max_abs_at : dict
        ``theta_i, phi_i, theta_o, phi_o, s`` (None out of plane), ``wavelength_nm``,
        ``measured``, ``simulated`` at the largest absolute deviation.
    n_points : int
        Number of (geometry, wavelength) points.
    """

    rmse: float
    nrmse: float
    max_abs: float
    max_abs_at: dict
    n_points: int


def angle_key(angle_deg: float) -> str:
    """JSON key of an angle: ``30.0 -> "30"``, ``22.5 -> "22.5"``.

    Parameters
    ----------
    angle_deg : float
        The angle (degrees).

    Returns
    -------
    str
        The angle in its shortest form.
    """
    return f"{float(angle_deg):g}"


def _finite_or_none(x: float):
    return float(x) if math.isfinite(x) else None


def curve_error(frame: pd.DataFrame) -> CurveError:
    """Error figures of ``frame`` (columns of :func:`compare.align.align` plus ``beta_sim``).

    Parameters
    ----------
    frame : pandas.DataFrame
        The aligned points: the geometry columns (degrees), ``s`` (degrees), ``wavelength_nm``,
        ``beta_meas`` and ``beta_sim`` (radiance coefficients).

    Returns
    -------
    CurveError
        RMSE, NRMSE (RMSE over the mean measured ``beta``; NaN when that mean is not positive), the
        largest |difference| and where it is, and the number of points.

    Examples
    --------
    >>> import pandas as pd
    >>> f = pd.DataFrame(dict(theta_i=[0, 0], phi_i=[0, 0], theta_o=[10, 20], phi_o=[0, 0],
    ...                       s=[-10, -20], wavelength_nm=[550, 550], beta_meas=[1.0, 1.0],
    ...                       beta_sim=[1.0, 1.2]))
    >>> e = curve_error(f)
    >>> round(e.rmse, 6), round(e.nrmse, 6), round(e.max_abs, 6), e.max_abs_at["theta_o"]
    (0.141421, 0.141421, 0.2, 20.0)
    """
    meas = frame["beta_meas"].to_numpy(dtype=float)
    sim = frame["beta_sim"].to_numpy(dtype=float)
    d = sim - meas
    rmse = float(np.sqrt(np.mean(d * d)))
    mean = float(np.mean(meas))
    nrmse = rmse / mean if mean > 0 else float("nan")
    j = int(np.argmax(np.abs(d)))
    row = frame.iloc[j]
    at = {c: float(row[c]) for c in ("theta_i", "phi_i", "theta_o", "phi_o")}
    at["s"] = _finite_or_none(float(row["s"]))
    at["wavelength_nm"] = float(row["wavelength_nm"])
    at["measured"] = float(meas[j])
    at["simulated"] = float(sim[j])
    return CurveError(rmse=rmse, nrmse=nrmse, max_abs=float(abs(d[j])), max_abs_at=at,
                      n_points=int(d.size))


def curve_errors(frame: pd.DataFrame) -> tuple[dict[str, CurveError], CurveError]:
    """Per-incidence errors (keyed by :func:`angle_key`, ascending) and the overall error.

    Parameters
    ----------
    frame : pandas.DataFrame
        An aligned, normalised table (:func:`compare.align.align` with ``beta_sim``): one row per
        geometry and wavelength, columns ``theta_i``, ``beta_meas``, ``beta_sim``.

    Returns
    -------
    (dict of str -> CurveError, CurveError)
        The error of each incidence's curve and of all of them together.
    """
    per_angle = {angle_key(theta_i): curve_error(rows)
                 for theta_i, rows in frame.groupby("theta_i", sort=True)}
    return per_angle, curve_error(frame)
