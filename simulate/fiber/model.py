"""The fiber, its outputs (direction rows of the tallies) and its surface term (package docstring).

Frames and the meaning of a cell's BRDF: :mod:`simulate.fiber`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from simulate.media.medium import HGMedium, MieMedium
from simulate.montecarlo.transport import ParameterError
from simulate.optics import microfacet

__all__ = ["METHODS", "DYE_PROFILES", "SCATTERER_PROFILES", "Fiber", "BRDFEstimate", "point_outputs", "range_outputs", "as_directions", "as_wavelengths",
           "surface_brdf"]

METHODS = ("nee", "beam", "bssrdf")
#: Where a fiber's dye sits (:attr:`Fiber.dye_profile`)
DYE_PROFILES = ("uniform", "ring", "core")
#: Where a fiber's scatterers sit (:attr:`Fiber.scatterer_profile`)
SCATTERER_PROFILES = ("uniform", "skin", "core")


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
    transmission_roughness : float
        Beckmann RMS slope of the boundary for the light the volume walk sends through it (entry,
        internal reflections, exit; :mod:`simulate.montecarlo.rough`); 0 (the default) is the smooth
        interface. With ``transmission_roughness_around`` (None: the same) the surface is anisotropic:
        ``transmission_roughness`` is then the slope of facets tilted along the axis (they move the exits'
        axial angle, the cone's opening) and ``..._around`` of those tilted about it (they spread the light
        around the cone). Only the exit-tally routes take it (the woven/felt yarn tables): the next-event
        routes of the fiber BRDF assume the smooth boundary and refuse it.
    cell_width_deg : float
        Angular width of the surface cell B about the top of the fiber (the cell whose BRDF
        the fabric summation uses); 360 / cell_width_deg should be an integer for the
        ``bssrdf`` route.
    dye_profile : str
        Where the host's absorption (the dye) sits across the fiber: ``"uniform"`` (everywhere, the default),
        ``"ring"`` (from the surface to the depth ``dye_depth_um``: a ring-dyed fiber) or ``"core"`` (below a
        clear skin of that depth). Walked by the exit-tally routes (the yarn and exit tables:
        :mod:`simulate.montecarlo.kernel`, "Dye profile"); the next-event routes refuse it.
    dye_depth_um : float
        The profile's depth below the surface (um), in ``(0, radius_um)``; 0 for the uniform profile.
    scatterer_profile : str
        Where the medium's scatterers (its particles) sit across the fiber: ``"uniform"`` (everywhere, the
        default), ``"skin"`` (from the surface to the depth ``scatterer_depth_um``, a clear core) or ``"core"``
        (below a clear skin of that depth). The clear part has the host's index and absorption (the dye, placed
        by ``dye_profile`` independently); the particles must not absorb (``k = 0``). Walked by the exit-tally
        routes with null collisions (:mod:`simulate.montecarlo.kernel`, "Scatterer profile").
    scatterer_depth_um : float
        The scatterer profile's depth below the surface (um), in ``(0, radius_um)``; 0 for the uniform profile.
    """

    radius_um: float
    n_host: float
    medium: MieMedium | HGMedium
    roughness: float
    cell_width_deg: float = 10.0
    transmission_roughness: float = 0.0
    transmission_roughness_around: float | None = None
    dye_profile: str = "uniform"
    dye_depth_um: float = 0.0
    scatterer_profile: str = "uniform"
    scatterer_depth_um: float = 0.0

    def __post_init__(self) -> None:
        t = self.transmission_roughness
        if isinstance(t, bool) or not isinstance(t, (int, float)) or not math.isfinite(t) or not 0.0 <= t <= 1.0:
            raise ParameterError(f"Fiber: transmission_roughness must be a number in [0, 1], got {t!r}")
        b = self.transmission_roughness_around
        if b is not None and (isinstance(b, bool) or not isinstance(b, (int, float)) or not math.isfinite(b)
                              or not 0.0 <= b <= 1.0):
            raise ParameterError(f"Fiber: transmission_roughness_around must be None or a number in [0, 1], got {b!r}")
        for name in ("radius_um", "n_host", "roughness", "cell_width_deg"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0:
                raise ParameterError(f"Fiber: {name} must be a finite number > 0, got {v!r}")
        if not self.cell_width_deg <= 180.0:
            raise ParameterError(f"Fiber: cell_width_deg must be <= 180, got {self.cell_width_deg!r}")
        if self.dye_profile not in DYE_PROFILES:
            raise ParameterError(f"Fiber: dye_profile must be one of {', '.join(DYE_PROFILES)}, got {self.dye_profile!r}")
        d = self.dye_depth_um
        if self.dye_profile != "uniform" and (isinstance(d, bool) or not isinstance(d, (int, float))
                                              or not 0.0 < d < self.radius_um):
            raise ParameterError(f"Fiber: dye_depth_um must be a number in (0, radius_um = {self.radius_um:g}) for the "
                                 f"{self.dye_profile} profile, got {d!r}")
        if self.scatterer_profile not in SCATTERER_PROFILES:
            raise ParameterError(f"Fiber: scatterer_profile must be one of {', '.join(SCATTERER_PROFILES)}, "
                                 f"got {self.scatterer_profile!r}")
        d = self.scatterer_depth_um
        if self.scatterer_profile != "uniform" and (isinstance(d, bool) or not isinstance(d, (int, float))
                                                    or not 0.0 < d < self.radius_um):
            raise ParameterError(f"Fiber: scatterer_depth_um must be a number in (0, radius_um = {self.radius_um:g}) "
                                 f"for the {self.scatterer_profile} profile, got {d!r}")

    @property
    def dye_radius_um(self) -> float:
        """The dye profile's inner boundary, ``radius_um - dye_depth_um``.

        The radius where the ring or the clear skin begins.
        """
        return float(self.radius_um) - float(self.dye_depth_um)

    @property
    def scatterer_radius_um(self) -> float:
        """The scatterer profile's inner boundary, ``radius_um - scatterer_depth_um``.

        The radius where the skin of scatterers or the clear skin begins.
        """
        return float(self.radius_um) - float(self.scatterer_depth_um)

    @property
    def half_width(self) -> float:
        """Half the cell width in radians."""
        return math.radians(self.cell_width_deg) / 2.0

    def cell_count(self, what: str = "bssrdf route") -> int:
        """Cells around the fiber, ``360 / cell_width_deg``; an error naming ``what`` unless it is an integer."""
        n_psi = int(round(360.0 / self.cell_width_deg))
        if abs(n_psi * self.cell_width_deg - 360.0) > 1e-9:
            raise ParameterError(f"{what}: 360 / cell_width_deg must be an integer, got {self.cell_width_deg}")
        return n_psi


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
        Method, seed, groups, ``rel_err`` (:func:`simulate.montecarlo.accuracy.relative_error`), energy balance, ...
    """

    R: np.ndarray
    u_R: np.ndarray
    photons: int
    seconds: float
    info: dict[str, Any] = field(default_factory=dict)


def point_outputs(w_out: np.ndarray, half_width: float, psi_c: float = 0.0) -> np.ndarray:
    """Output rows (``tallies.OUTPUT_COLUMNS``) for point directions ``w_out[P, 3]`` at the cell ``psi_c``.

    The local frame of the top cell is the fiber frame: ``mu = w_z``, ``phi = atan2(w_y, w_x)``.
    """
    w = np.atleast_2d(np.asarray(w_out, dtype=float))
    mu = w[:, 2]
    phi = np.arctan2(w[:, 1], w[:, 0])
    return range_outputs(mu, mu, phi, phi, half_width, psi_c)


def range_outputs(mu_lo, mu_hi, phi_lo, phi_hi, half_width: float, psi_c: float = 0.0) -> np.ndarray:
    """Output rows for direction ranges (arrays of equal length) at the cell centred on ``psi_c``."""
    mu_lo, mu_hi, phi_lo, phi_hi = (np.atleast_1d(np.asarray(v, dtype=float)) for v in (mu_lo, mu_hi, phi_lo, phi_hi))
    out = np.zeros((mu_lo.size, 8))
    centres = np.broadcast_to(np.asarray(psi_c, dtype=float), mu_lo.shape)
    out[:, 0] = np.cos(centres)
    out[:, 1] = np.sin(centres)
    out[:, 2] = math.cos(half_width)
    out[:, 3] = mu_lo
    out[:, 4] = mu_hi
    out[:, 5] = phi_lo
    out[:, 6] = phi_hi
    return out

def as_directions(name: str, w: Any) -> np.ndarray:
    """``w`` as unit rows ``[P, 3]``; a ParameterError naming ``name`` otherwise."""
    a = np.atleast_2d(np.asarray(w, dtype=float))
    if a.ndim != 2 or a.shape[1] != 3 or not np.all(np.isfinite(a)):
        raise ParameterError(f"{name} must be an array of finite 3-vectors, shape [P, 3]")
    norm = np.linalg.norm(a, axis=1)
    if np.any(norm == 0):
        raise ParameterError(f"{name} contains a zero vector")
    return a / norm[:, None]


def as_wavelengths(wavelengths_nm: Any) -> np.ndarray:
    """``wavelengths_nm`` as a non-empty 1-D array of finite positive values, else a ParameterError."""
    wl = np.atleast_1d(np.asarray(wavelengths_nm, dtype=float))
    if wl.ndim != 1 or wl.size == 0 or not np.all(np.isfinite(wl)) or np.any(wl <= 0):
        raise ParameterError("wavelengths_nm must be a non-empty 1-D array of finite wavelengths > 0")
    return wl


def surface_brdf(fiber: Fiber, w_in: np.ndarray, w_out: np.ndarray) -> np.ndarray:
    """Surface term at B, ``R_surf = f_CT(w_in, w_out) cos(theta_in)`` (0 below B's tangent plane), ``[P]``.

    Cook-Torrance with the host index and the fiber's Beckmann RMS slope (docs/physics.md section 5);
    wavelength-independent because the host index is real and constant.
    """
    w_in = as_directions("w_in", w_in)
    w_out = as_directions("w_out", w_out)
    f = microfacet.cook_torrance(w_in, w_out, fiber.roughness, fiber.n_host)
    return np.where((w_in[:, 2] > 0) & (w_out[:, 2] > 0), f * w_in[:, 2], 0.0)

