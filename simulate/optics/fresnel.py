"""Fresnel reflection and Snell refraction at a smooth dielectric interface.

Light travelling in a medium of (real) index ``n1`` meets a medium of index ``n2``
at incidence angle ``theta_i`` (measured from the normal, ``cos_i = cos(theta_i)``).
Snell's law gives the transmitted angle ``theta_t``::

    n1 sin(theta_i) = n2 sin(theta_t)
    cos_t = sqrt(1 - (n1/n2)^2 (1 - cos_i^2))          (no solution: total internal reflection)

and the Fresnel amplitude reflection coefficients (Born & Wolf 1999, eq. 1.5.21;
Bohren & Huffman 1983, sec. 2.7) give the reflectances::

    r_s = (n1 cos_i - n2 cos_t) / (n1 cos_i + n2 cos_t)      R_s = r_s^2
    r_p = (n2 cos_i - n1 cos_t) / (n2 cos_i + n1 cos_t)      R_p = r_p^2
    F   = R = (R_s + R_p) / 2      (unpolarised; docs/physics.md sections 3 and 5)
    T   = 1 - R

``R = 1`` beyond the critical angle ``asin(n2/n1)`` (``n1 > n2``), ``R_p = 0`` at
Brewster's angle ``atan(n2/n1)``, and ``R = 0`` when ``n1 == n2`` (no interface).

Two layers:

* compiled scalar kernels for the Monte Carlo code, :func:`fresnel_unpolarized` and
  :func:`refracted_cos` (``numba.njit(cache=True, fastmath=False)``, taking cosines: their own
  flags, not those of a fastmath caller);
* vectorised numpy functions for everything else, taking angles in radians
  (:func:`reflectance`, :func:`reflectance_s`, :func:`reflectance_p`,
  :func:`transmittance`, :func:`snell`) or cosines (:func:`reflectance_from_cos`).

References
----------
Born, M. & Wolf, E. (1999). *Principles of Optics*, 7th ed., sec. 1.5. Cambridge University Press.
Bohren, C. F. & Huffman, D. R. (1983). *Absorption and Scattering of Light by Small Particles*,
sec. 2.7. Wiley.
"""

from __future__ import annotations

from typing import Literal

import numba
import numpy as np
import numpy.typing as npt

__all__ = [
    "fresnel_unpolarized",
    "refracted_cos",
    "reflectance",
    "reflectance_s",
    "reflectance_p",
    "reflectance_from_cos",
    "transmittance",
    "snell",
    "critical_angle",
    "brewster_angle",
    "OpticsDomainWarning",
]

ArrayLike = npt.ArrayLike


class OpticsDomainWarning(UserWarning):
    """An optics-layer input lies outside the domain where the model is trustworthy.

    Shared by :mod:`simulate.optics.fresnel`, :mod:`simulate.optics.mie`, :mod:`simulate.media.medium` and
    :mod:`simulate.optics.microfacet`: the result is still finite and bounded, but the physics it
    stands for is doubtful (grazing limit of a microfacet model, no index contrast,
    extrapolated spectra, dependent scattering, ...). Turn it into an error with
    ``warnings.simplefilter("error", OpticsDomainWarning)``.
    """


# --------------------------------------------------------------------------------------
# Compiled scalar kernels (used inside the Monte Carlo kernel)
# --------------------------------------------------------------------------------------


# fastmath=False explicitly: these are called from Python and from fastmath kernels (Monte Carlo,
# woven shading); without their own setting numba compiles a callee with the flags of its first
# caller and caches that flavour (see simulate/montecarlo/rng._exponential_slow), so their
# numerics would depend on which caller ran first
@numba.njit(cache=True, fastmath=False)
def fresnel_unpolarized(cos_i: float, n1: float, n2: float) -> float:
    """Unpolarised Fresnel reflectance ``F = (R_s + R_p) / 2`` (compiled scalar kernel).

    Parameters
    ----------
    cos_i : float
        Cosine of the incidence angle, in [0, 1]. Its absolute value is used and values
        above 1 (rounding) are clipped to 1.
    n1, n2 : float
        Real refractive indices of the incident and the transmitting medium.

    Returns
    -------
    float
        Reflectance in [0, 1]; exactly 1.0 on total internal reflection (including the
        critical angle itself), exactly 0.0 when ``n1 == n2``; 1.0 at grazing incidence
        ``cos_i = 0`` when ``n1 != n2``.
    """
    if n1 == n2:
        return 0.0
    c = abs(cos_i)
    if c > 1.0:
        c = 1.0
    eta = n1 / n2
    sin2_t = eta * eta * (1.0 - c * c)
    if sin2_t >= 1.0:
        return 1.0
    cos_t = np.sqrt(1.0 - sin2_t)
    rs = (n1 * c - n2 * cos_t) / (n1 * c + n2 * cos_t)
    rp = (n2 * c - n1 * cos_t) / (n2 * c + n1 * cos_t)
    return 0.5 * (rs * rs + rp * rp)


@numba.njit(cache=True, fastmath=False)
def refracted_cos(cos_i: float, n1: float, n2: float) -> float:
    """Cosine of the transmitted angle by Snell's law (compiled scalar kernel).

    Parameters
    ----------
    cos_i : float
        Cosine of the incidence angle, in [0, 1] (absolute value used, clipped to 1).
    n1, n2 : float
        Real refractive indices of the incident and the transmitting medium.

    Returns
    -------
    float
        ``cos_t = sqrt(1 - (n1/n2)^2 (1 - cos_i^2)) >= 0``, or -1.0 on total internal
        reflection (``(n1/n2)^2 (1 - cos_i^2) >= 1``). Equals ``cos_i`` when ``n1 == n2``.
    """
    c = abs(cos_i)
    if c > 1.0:
        c = 1.0
    if n1 == n2:
        return c
    eta = n1 / n2
    sin2_t = eta * eta * (1.0 - c * c)
    if sin2_t >= 1.0:
        return -1.0
    return np.sqrt(1.0 - sin2_t)


# --------------------------------------------------------------------------------------
# Vectorised numpy functions
# --------------------------------------------------------------------------------------


def _check_indices(n1: np.ndarray, n2: np.ndarray) -> None:
    if np.iscomplexobj(n1) or np.iscomplexobj(n2):
        raise ValueError("Fresnel: n1 and n2 must be real (dielectric) refractive indices")
    if np.any(~(n1 > 0)) or np.any(~(n2 > 0)):
        raise ValueError("Fresnel: refractive indices n1 and n2 must be finite and > 0")


def _cos_sin_from_theta(theta_i: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    theta = np.asarray(theta_i, dtype=float)
    tol = 1e-12
    if np.any(~((theta >= -tol) & (theta <= 0.5 * np.pi + tol))):
        raise ValueError(
            "Fresnel: incidence angles theta_i must be in [0, pi/2] radians "
            "(measured from the normal); convert degrees with np.radians"
        )
    theta = np.clip(theta, 0.0, 0.5 * np.pi)
    cos_i = np.cos(theta)
    # cos(pi/2) is 6e-17 in floating point; make grazing incidence exact
    cos_i = np.where(theta == 0.5 * np.pi, 0.0, cos_i)
    return cos_i, np.sin(theta)


def _amplitudes(
    cos_i: np.ndarray, sin_i: np.ndarray, n1: ArrayLike, n2: ArrayLike
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Return ``(R_s, R_p, cos_t, tir)`` broadcast over all inputs."""
    n1a = np.asarray(n1)
    n2a = np.asarray(n2)
    _check_indices(n1a, n2a)
    n1a = n1a.astype(float)
    n2a = n2a.astype(float)
    cos_i, sin_i, n1a, n2a = np.broadcast_arrays(cos_i, sin_i, n1a, n2a)
    eta = n1a / n2a
    sin2_t = (eta * sin_i) ** 2
    tir = (sin2_t >= 1.0) & (n1a != n2a)
    cos_t = np.sqrt(np.clip(1.0 - sin2_t, 0.0, None))
    same = n1a == n2a
    cos_t = np.where(same, cos_i, cos_t)
    with np.errstate(invalid="ignore", divide="ignore"):
        rs = (n1a * cos_i - n2a * cos_t) / (n1a * cos_i + n2a * cos_t)
        rp = (n2a * cos_i - n1a * cos_t) / (n2a * cos_i + n1a * cos_t)
    r_s = np.where(tir, 1.0, np.where(same, 0.0, rs * rs))
    r_p = np.where(tir, 1.0, np.where(same, 0.0, rp * rp))
    return r_s, r_p, cos_t, tir


def reflectance_s(theta_i: ArrayLike, n1: ArrayLike, n2: ArrayLike) -> np.ndarray:
    """s-polarised (TE) Fresnel reflectance ``R_s = r_s^2``.

    Parameters
    ----------
    theta_i : array_like
        Incidence angle(s) in radians, in [0, pi/2].
    n1, n2 : array_like
        Real indices of the incident and transmitting media (broadcast with ``theta_i``).

    Returns
    -------
    numpy.ndarray
        ``R_s`` in [0, 1]; 1 on total internal reflection.

    Examples
    --------
    >>> round(float(reflectance_s(0.0, 1.0, 1.5)), 12)
    0.04
    """
    cos_i, sin_i = _cos_sin_from_theta(theta_i)
    return _amplitudes(cos_i, sin_i, n1, n2)[0]


def reflectance_p(theta_i: ArrayLike, n1: ArrayLike, n2: ArrayLike) -> np.ndarray:
    """p-polarised (TM) Fresnel reflectance ``R_p = r_p^2``; zero at Brewster's angle.

    Parameters
    ----------
    theta_i : array_like
        Incidence angle(s) in radians, in [0, pi/2].
    n1, n2 : array_like
        Real indices of the incident and transmitting media.

    Returns
    -------
    numpy.ndarray
        ``R_p`` in [0, 1]; 1 on total internal reflection.

    Examples
    --------
    >>> float(reflectance_p(brewster_angle(1.0, 1.5), 1.0, 1.5)) < 1e-30
    True
    """
    cos_i, sin_i = _cos_sin_from_theta(theta_i)
    return _amplitudes(cos_i, sin_i, n1, n2)[1]


def reflectance(theta_i: ArrayLike, n1: ArrayLike, n2: ArrayLike) -> np.ndarray:
    """Unpolarised Fresnel reflectance ``F = (R_s + R_p) / 2``.

    Parameters
    ----------
    theta_i : array_like
        Incidence angle(s) in radians, in [0, pi/2].
    n1, n2 : array_like
        Real indices of the incident and transmitting media.

    Returns
    -------
    numpy.ndarray
        Reflectance in [0, 1]; 1 beyond the critical angle, 0 when ``n1 == n2``.

    Examples
    --------
    >>> round(float(reflectance(0.0, 1.0, 1.5)), 12)
    0.04
    """
    cos_i, sin_i = _cos_sin_from_theta(theta_i)
    r_s, r_p, _, _ = _amplitudes(cos_i, sin_i, n1, n2)
    return 0.5 * (r_s + r_p)


def reflectance_from_cos(cos_i: ArrayLike, n1: ArrayLike, n2: ArrayLike) -> np.ndarray:
    """Unpolarised Fresnel reflectance from incidence cosines (vectorised :func:`fresnel_unpolarized`).

    Parameters
    ----------
    cos_i : array_like
        Incidence cosines; the absolute value is used and clipped to 1.
    n1, n2 : array_like
        Real indices of the incident and transmitting media.

    Returns
    -------
    numpy.ndarray
        Reflectance in [0, 1].
    """
    c = np.clip(np.abs(np.asarray(cos_i, dtype=float)), 0.0, 1.0)
    s = np.sqrt(np.clip(1.0 - c * c, 0.0, None))
    r_s, r_p, _, _ = _amplitudes(c, s, n1, n2)
    return 0.5 * (r_s + r_p)


def transmittance(theta_i: ArrayLike, n1: ArrayLike, n2: ArrayLike) -> np.ndarray:
    """Unpolarised Fresnel (energy) transmittance ``T = 1 - R``.

    Parameters
    ----------
    theta_i : array_like
        Incidence angle(s) in radians, in [0, pi/2].
    n1, n2 : array_like
        Real indices of the incident and transmitting media.

    Returns
    -------
    numpy.ndarray
        Transmittance in [0, 1]; 0 on total internal reflection.
    """
    return 1.0 - reflectance(theta_i, n1, n2)


def snell(
    theta_i: ArrayLike,
    n1: ArrayLike,
    n2: ArrayLike,
    on_tir: Literal["raise", "nan"] = "raise",
) -> np.ndarray:
    """Transmitted angle ``theta_t`` from Snell's law ``n1 sin(theta_i) = n2 sin(theta_t)``.

    Parameters
    ----------
    theta_i : array_like
        Incidence angle(s) in radians, in [0, pi/2].
    n1, n2 : array_like
        Real indices of the incident and transmitting media.
    on_tir : {"raise", "nan"}
        What to do where total internal reflection leaves no transmitted ray:
        ``"raise"`` (default) raises :class:`ValueError`; ``"nan"`` returns NaN at exactly
        those elements (the caller asked for it and masks them, e.g. with
        ``np.isnan``). No other input produces NaN.

    Returns
    -------
    numpy.ndarray
        Transmitted angle(s) in radians, in [0, pi/2].

    Raises
    ------
    ValueError
        On total internal reflection with ``on_tir="raise"``, or on invalid inputs.

    Examples
    --------
    >>> round(float(np.degrees(snell(np.radians(30.0), 1.0, 1.5))), 6)
    19.471221
    """
    if on_tir not in ("raise", "nan"):
        raise ValueError(f"snell: on_tir must be 'raise' or 'nan', got {on_tir!r}")
    cos_i, sin_i = _cos_sin_from_theta(theta_i)
    _, _, cos_t, tir = _amplitudes(cos_i, sin_i, n1, n2)
    if np.any(tir):
        if on_tir == "raise":
            raise ValueError(
                f"snell: total internal reflection for {int(np.count_nonzero(tir))} incidence "
                "angle(s) beyond the critical angle asin(n2/n1); no transmitted ray exists "
                "(pass on_tir='nan' to get NaN there instead)"
            )
    theta_t = np.arccos(np.clip(cos_t, 0.0, 1.0))
    return np.where(tir, np.nan, theta_t)


def critical_angle(n1: ArrayLike, n2: ArrayLike) -> np.ndarray:
    """Critical angle ``asin(n2 / n1)`` in radians; NaN-free: ``pi/2`` where ``n1 <= n2`` (no TIR).

    Parameters
    ----------
    n1, n2 : array_like
        Real indices of the incident and transmitting media.

    Returns
    -------
    numpy.ndarray
        Critical angle in radians (``pi/2`` when total internal reflection cannot occur).
    """
    n1a = np.asarray(n1)
    n2a = np.asarray(n2)
    _check_indices(n1a, n2a)
    n1a, n2a = n1a.astype(float), n2a.astype(float)
    return np.arcsin(np.clip(n2a / n1a, 0.0, 1.0))


def brewster_angle(n1: ArrayLike, n2: ArrayLike) -> np.ndarray:
    """Brewster's angle ``atan(n2 / n1)`` in radians, where ``R_p = 0``.

    Parameters
    ----------
    n1, n2 : array_like
        Real indices of the incident and transmitting media.

    Returns
    -------
    numpy.ndarray
        Brewster's angle in radians.
    """
    n1a = np.asarray(n1)
    n2a = np.asarray(n2)
    _check_indices(n1a, n2a)
    n1a, n2a = n1a.astype(float), n2a.astype(float)
    return np.arctan(n2a / n1a)
