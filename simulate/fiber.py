"""Fiber BRDF: volume term by Monte Carlo (three routes) plus the Cook-Torrance surface term.

INTERFACE SKELETON (work in progress): the signatures and conventions below are the
contract used by :mod:`simulate.fabric`; the Monte Carlo routes replace the placeholder
bodies (which raise ``NotImplementedError``).

Frames (PHYSICS.md sections 1, 4, 5): the fiber frame has x = the fiber axis ``t``,
z = the outward normal of the cell B at the top of the fiber (``psi = 0``), y = z x x... so a
fiber lying in the fabric plane along the warp has its frame equal to the fabric frame.
Directions point away from the surface (``w_in`` towards the light, ``w_out`` towards the
detector).

``R`` returned here is ``L_o / E_perp`` (radiance leaving B per unit irradiance on a plane
normal to the beam), defined for ``w_in`` on the whole sphere; for ``w_in`` above B's
tangent plane the ordinary BRDF is ``R / cos(theta_in)``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from simulate.medium import HGMedium, MieMedium

__all__ = ["Fiber", "BRDFEstimate", "volume_brdf", "surface_brdf", "normal_albedo"]


@dataclass(frozen=True)
class Fiber:
    """One fiber: a smooth dielectric cylinder filled with a scattering medium.

    Attributes
    ----------
    radius_um : float
        Fiber radius R (um).
    n_host : float
        Real refractive index of the host (cotton: 1.557).
    medium : MieMedium or HGMedium
        The scattering medium inside (coefficients in 1/um).
    roughness : float
        Beckmann RMS slope ``m`` of the fiber surface (Cook-Torrance term).
    cell_width_deg : float
        Angular width of the surface cell B about the top of the fiber (the cell whose BRDF
        the fabric summation uses).
    """

    radius_um: float
    n_host: float
    medium: MieMedium | HGMedium
    roughness: float
    cell_width_deg: float = 10.0


@dataclass(frozen=True)
class BRDFEstimate:
    """Monte Carlo estimate of ``R`` for P direction pairs and L wavelengths.

    Attributes
    ----------
    R, u_R : numpy.ndarray
        ``[P, L]`` estimate and its standard error.
    photons : int
        Photons used in total.
    seconds : float
        Wall time.
    info : dict
        Method, seeds, batches, achieved relative error, energy balance, peak memory, ...
    """

    R: np.ndarray
    u_R: np.ndarray
    photons: int
    seconds: float
    info: dict[str, Any] = field(default_factory=dict)


def volume_brdf(
    fiber: Fiber,
    w_in: np.ndarray,
    w_out: np.ndarray,
    wavelengths_nm: np.ndarray,
    *,
    method: str = "nee",
    target_rel_err: float = 0.01,
    max_photons: int | None = None,
    seed: int = 0,
    threads: int | None = None,
    progress: bool = False,
) -> BRDFEstimate:
    """Volume term ``R_vol,B(w_in, w_out)`` of the top cell B, per wavelength.

    Parameters
    ----------
    fiber : Fiber
    w_in, w_out : numpy.ndarray
        ``[P, 3]`` unit vectors in the fiber frame (pairs); ``w_out[:, 2] > 0``; ``w_in``
        anywhere on the sphere except along the axis.
    wavelengths_nm : numpy.ndarray
        ``[L]`` vacuum wavelengths.
    method : {"nee", "beam", "bssrdf"}
    target_rel_err : float
        Target relative standard error (photons follow from it, batch by batch).

    Returns
    -------
    BRDFEstimate
    """
    raise NotImplementedError("volume_brdf: Monte Carlo routes land with the fiber issue")


def surface_brdf(fiber: Fiber, w_in: np.ndarray, w_out: np.ndarray) -> np.ndarray:
    """Surface term ``R_surf = f_CT cos(theta_in)`` (0 for ``w_in`` below B's tangent plane), ``[P]``."""
    raise NotImplementedError


def normal_albedo(
    fiber: Fiber, wavelengths_nm: np.ndarray, *, target_rel_err: float = 0.01, seed: int = 0,
    threads: int | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Volume albedo of cell B under normal incidence ``rho(lambda)`` and its standard error.

    ``rho = int R_vol,B(z, w_o) cos(theta_o) dOmega_o``: the fraction of the irradiance on B
    that leaves B through its volume (the classic model's Lambertian albedo).
    """
    raise NotImplementedError
