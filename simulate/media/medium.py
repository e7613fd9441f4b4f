"""Scattering media: optical coefficients of a host filled with Mie spheres (docs/physics.md section 2).

A host of real index ``n_h`` (optionally absorbing, ``mu_a_host(lambda)``) contains spheres of
complex index ``m_p(lambda) = n_p - i k_p`` and radius ``r`` (or a log-normal distribution of
radii), at number density ``N`` or volume fraction ``f_v = N 4/3 pi <r^3>``. With the Mie
efficiencies for ``m = m_p / n_h`` and ``x = 2 pi n_h r / lambda`` (:mod:`simulate.optics.mie`)::

    sigma_sca = Q_sca pi r^2              mu_s = N sigma_sca
    sigma_abs = (Q_ext - Q_sca) pi r^2    mu_a = N sigma_abs + mu_a_host
    mu_t = mu_s + mu_a                    albedo = mu_s / mu_t   (0 when mu_t = 0)

(cross sections averaged over the size distribution; ``g`` averaged with weight
``sigma_sca``), and the phase function ``p(mu)`` as an inverse-CDF :class:`~simulate.optics.phase.PhaseTable`.

Units: lengths in micrometres (``radius_um``), wavelengths in nanometres (vacuum),
number densities in 1/um^3, cross sections in um^2, coefficients ``mu_s, mu_a, mu_t`` in 1/um
(1/um = 10^4 /cm).

Independent scattering is assumed (far-field Mie per particle, intensities add); it fails
for dense packings. A common rule of thumb (Tien & Drolen 1987) puts the limit near
``f_v = 0.1``; above it an :class:`OpticsDomainWarning` is issued. Spectra are interpolated
linearly and held constant outside their range, with a warning.

References
----------
Bohren, C. F. & Huffman, D. R. (1983). *Absorption and Scattering of Light by Small Particles*,
ch. 3-4. Wiley.
Tien, C. L. & Drolen, B. L. (1987). Thermal radiation in particulate media with dependent and
independent scattering. *Annual Review of Numerical Fluid Mechanics and Heat Transfer* 1, 1-32.
Henyey, L. G. & Greenstein, J. L. (1941). *Astrophysical Journal* 93, 70-83 (:class:`HGMedium`).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from simulate.optics import mie
from simulate.optics.fresnel import OpticsDomainWarning
from simulate.optics.mie import LogNormalSize
from simulate.optics.phase import DEFAULT_TABLE_SIZE, PhaseTable

__all__ = [
    "OpticsDomainWarning",
    "Spectrum",
    "OpticalProperties",
    "MieMedium",
    "HGMedium",
    "LogNormalSize",
    "DEPENDENT_SCATTERING_VOLUME_FRACTION",
]

#: Volume fraction above which independent scattering is doubtful (warning).
DEPENDENT_SCATTERING_VOLUME_FRACTION = 0.1
#: what :class:`MieMedium` requires of its size and of its amount of particles: one of each pair
_ONE_SIZE = "MieMedium: give exactly one of radius_um and size_distribution"
_ONE_AMOUNT = "MieMedium: give exactly one of number_density_per_um3 and volume_fraction"


@dataclass(frozen=True, eq=False)
class Spectrum:
    """A tabulated real spectrum, interpolated linearly in wavelength.

    Attributes
    ----------
    wavelength_nm : numpy.ndarray
        Strictly increasing vacuum wavelengths (nm).
    values : numpy.ndarray
        Values at those wavelengths (same length).
    name : str
        What the spectrum is (used in messages), e.g. ``"particle k"``.
    """

    wavelength_nm: np.ndarray
    values: np.ndarray
    name: str = "spectrum"

    def __post_init__(self) -> None:
        wl = np.asarray(self.wavelength_nm, dtype=float).ravel()
        v = np.asarray(self.values, dtype=float).ravel()
        if wl.size < 1 or wl.shape != v.shape:
            raise ValueError(f"{self.name}: wavelength_nm and values must be non-empty and of equal length")
        if not (np.all(np.isfinite(wl)) and np.all(np.isfinite(v))):
            raise ValueError(f"{self.name}: wavelengths and values must be finite")
        if np.any(np.diff(wl) <= 0):
            raise ValueError(f"{self.name}: wavelength_nm must be strictly increasing")
        object.__setattr__(self, "wavelength_nm", wl)
        object.__setattr__(self, "values", v)

    def __call__(self, wavelength_nm: npt.ArrayLike) -> np.ndarray:
        """Values at ``wavelength_nm`` (held constant outside the table, with a warning)."""
        w = np.asarray(wavelength_nm, dtype=float)
        lo, hi = self.wavelength_nm[0], self.wavelength_nm[-1]
        if np.any(w < lo) or np.any(w > hi):
            warnings.warn(
                f"{self.name}: wavelength outside the tabulated range {lo:g}-{hi:g} nm; "
                "the end value is used",
                OpticsDomainWarning,
                stacklevel=2,
            )
        return np.interp(w, self.wavelength_nm, self.values)

    def min(self) -> float:
        """Smallest tabulated value."""
        return float(self.values.min())


def _evaluate(value: float | Spectrum, wavelength_nm: float) -> float:
    if isinstance(value, Spectrum):
        return float(value(wavelength_nm))
    return float(value)


@dataclass(frozen=True, eq=False)
class OpticalProperties:
    """Optical coefficients of a medium at one wavelength (lengths in um, coefficients in 1/um).

    Attributes
    ----------
    wavelength_nm : float
        Vacuum wavelength (NaN for wavelength-independent media).
    mu_s, mu_a, mu_t : float
        Scattering, absorption and extinction coefficients (1/um).
    g : float
        Asymmetry parameter of the phase function (0 when nothing scatters).
    albedo : float
        ``mu_s / mu_t`` (0 when ``mu_t = 0``).
    phase : PhaseTable
        Inverse-CDF table of the phase function (isotropic when nothing scatters).
    m : complex
        Relative index ``m_p / n_h`` (NaN for HG media).
    x : float
        Size parameter of the (median) radius (NaN for HG media).
    quadrature_error : float
        Relative error estimate of the size-distribution quadrature (0 for one size).
    """

    wavelength_nm: float
    mu_s: float
    mu_a: float
    mu_t: float
    g: float
    albedo: float
    phase: PhaseTable
    m: complex = complex("nan")
    x: float = float("nan")
    quadrature_error: float = 0.0


def _albedo(mu_s: float, mu_t: float) -> float:
    return mu_s / mu_t if mu_t > 0 else 0.0


@dataclass(frozen=True, eq=False)
class MieMedium:
    """Host medium with Mie spheres (docs/physics.md section 2).

    Attributes
    ----------
    n_host : float
        Real host index (cotton: 1.557).
    particle_n : float or Spectrum
        Real part of the particle index.
    particle_k : float or Spectrum
        Particle absorption index ``k >= 0`` (index ``n - i k``).
    radius_um : float, optional
        Sphere radius (um); give exactly one of ``radius_um`` and ``size_distribution``.
    size_distribution : LogNormalSize, optional
        Log-normal number distribution of radii.
    number_density_per_um3 : float, optional
        Particles per um^3; give exactly one of this and ``volume_fraction``.
    volume_fraction : float, optional
        ``f_v = N 4/3 pi <r^3>`` in [0, 1).
    mu_a_host_per_um : float or Spectrum
        Host absorption coefficient (1/um), default 0.
    phase_table_size : int
        ``K`` of the phase tables.

    Examples
    --------
    >>> med = MieMedium(n_host=1.0, particle_n=1.55, radius_um=0.5, number_density_per_um3=0.01)
    >>> op = med.optical_properties(500.0)
    >>> round(op.albedo, 12), op.phase.K
    (1.0, 4096)
    """

    n_host: float
    particle_n: float | Spectrum
    particle_k: float | Spectrum = 0.0
    radius_um: float | None = None
    size_distribution: LogNormalSize | None = None
    number_density_per_um3: float | None = None
    volume_fraction: float | None = None
    mu_a_host_per_um: float | Spectrum = 0.0
    phase_table_size: int = DEFAULT_TABLE_SIZE

    def __post_init__(self) -> None:
        if not (float(self.n_host) > 0 and np.isfinite(self.n_host)):
            raise ValueError("MieMedium: n_host must be a finite real index > 0")
        if (self.radius_um is None) == (self.size_distribution is None):
            raise ValueError(_ONE_SIZE)
        if self.radius_um is not None and not (self.radius_um > 0 and np.isfinite(self.radius_um)):
            raise ValueError("MieMedium: radius_um must be finite and > 0")
        if (self.number_density_per_um3 is None) == (self.volume_fraction is None):
            raise ValueError(_ONE_AMOUNT)
        if self.number_density_per_um3 is not None and not (
            self.number_density_per_um3 >= 0 and np.isfinite(self.number_density_per_um3)
        ):
            raise ValueError("MieMedium: number_density_per_um3 must be finite and >= 0")
        if self.volume_fraction is not None and not (0.0 <= self.volume_fraction < 1.0):
            raise ValueError("MieMedium: volume_fraction must be in [0, 1)")
        for name in ("particle_n", "particle_k", "mu_a_host_per_um"):
            v = getattr(self, name)
            low = v.min() if isinstance(v, Spectrum) else float(v)
            limit_ok = low > 0 if name == "particle_n" else low >= 0
            if not (limit_ok and np.isfinite(low)):
                bound = "> 0" if name == "particle_n" else ">= 0"
                raise ValueError(f"MieMedium: {name} must be finite and {bound}")
        if int(self.phase_table_size) < 2:
            raise ValueError("MieMedium: phase_table_size must be >= 2")
        if self.volume_fraction_value > DEPENDENT_SCATTERING_VOLUME_FRACTION:
            warnings.warn(
                f"MieMedium: volume fraction {self.volume_fraction_value:.3g} > "
                f"{DEPENDENT_SCATTERING_VOLUME_FRACTION}: independent (Mie) scattering is doubtful "
                "in such dense packings",
                OpticsDomainWarning,
                stacklevel=3,
            )

    # ------------------------------------------------------------------ derived quantities
    @property
    def mean_particle_volume_um3(self) -> float:
        """``<4/3 pi r^3>`` in um^3 (exact log-normal moment for a distribution)."""
        if self.size_distribution is not None:
            return 4.0 / 3.0 * np.pi * self.size_distribution.moment(3.0)
        if self.radius_um is None:      # not reached: __post_init__ requires one of the two
            raise ValueError(_ONE_SIZE)
        return 4.0 / 3.0 * np.pi * float(self.radius_um) ** 3

    @property
    def number_density(self) -> float:
        """``N`` in 1/um^3 (from ``f_v`` if that was given)."""
        if self.number_density_per_um3 is not None:
            return float(self.number_density_per_um3)
        if self.volume_fraction is None:    # not reached: __post_init__ requires one of the two
            raise ValueError(_ONE_AMOUNT)
        return float(self.volume_fraction) / self.mean_particle_volume_um3

    @property
    def volume_fraction_value(self) -> float:
        """``f_v = N <4/3 pi r^3>``."""
        if self.volume_fraction is not None:
            return float(self.volume_fraction)
        if self.number_density_per_um3 is None:     # not reached: __post_init__ requires one of the two
            raise ValueError(_ONE_AMOUNT)
        return float(self.number_density_per_um3) * self.mean_particle_volume_um3

    def particle_index(self, wavelength_nm: float) -> complex:
        """Particle complex index ``n_p - i k_p`` at ``wavelength_nm``."""
        return complex(mie.particle_index(_evaluate(self.particle_n, wavelength_nm),
                                          _evaluate(self.particle_k, wavelength_nm)))

    # ------------------------------------------------------------------ main entry point
    def optical_properties(self, wavelength_nm: float, with_phase: bool = True) -> OpticalProperties:
        """Coefficients and phase table at one vacuum wavelength.

        Parameters
        ----------
        wavelength_nm : float
            Vacuum wavelength in nm.
        with_phase : bool
            Build the phase table (set False for cheap coefficient spectra; ``phase`` is
            then the HG table of ``g``, documented as such).

        Returns
        -------
        OpticalProperties
        """
        wavelength_nm = float(wavelength_nm)
        if not (wavelength_nm > 0 and np.isfinite(wavelength_nm)):
            raise ValueError("MieMedium: wavelength_nm must be finite and > 0")
        m_p = self.particle_index(wavelength_nm)
        cs = mie.cross_sections(m_p, self.n_host, wavelength_nm, radius_um=self.radius_um,
                                distribution=self.size_distribution)
        N = self.number_density
        mu_s = N * cs.sigma_sca
        mu_a = N * cs.sigma_abs + _evaluate(self.mu_a_host_per_um, wavelength_nm)
        mu_t = mu_s + mu_a
        K = int(self.phase_table_size)
        no_contrast = cs.m == 1.0
        if no_contrast:
            warnings.warn(
                f"MieMedium: particle index equals the host index ({self.n_host:g}) at "
                f"{wavelength_nm:g} nm: the particles scatter nothing (mu_s = 0); the phase table "
                "is isotropic and irrelevant",
                OpticsDomainWarning,
                stacklevel=2,
            )
        if no_contrast or not cs.sigma_sca > 0:
            phase = PhaseTable.from_hg(0.0, K)
        elif not with_phase:
            phase = PhaseTable.from_hg(cs.g, K)
        else:
            mu, p = mie.ensemble_phase_function(m_p, self.n_host, wavelength_nm, radius_um=self.radius_um,
                                                distribution=self.size_distribution)
            phase = PhaseTable.from_tabulated(mu, p, K=K, g_reference=cs.g)
        return OpticalProperties(
            wavelength_nm=wavelength_nm,
            mu_s=mu_s,
            mu_a=mu_a,
            mu_t=mu_t,
            g=cs.g,
            albedo=_albedo(mu_s, mu_t),
            phase=phase,
            m=cs.m,
            x=cs.x,
            quadrature_error=cs.quadrature_error,
        )

    def coefficients(self, wavelength_nm: npt.ArrayLike) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(mu_s, mu_a, g)`` spectra (1/um, 1/um, -) without phase tables.

        Parameters
        ----------
        wavelength_nm : array_like
            Vacuum wavelengths in nm.

        Returns
        -------
        mu_s, mu_a, g : numpy.ndarray
            Same shape as ``wavelength_nm``.
        """
        wl = np.asarray(wavelength_nm, dtype=float)
        props = [self.optical_properties(w, with_phase=False) for w in wl.ravel()]
        out = [np.array([getattr(p, a) for p in props]).reshape(wl.shape) for a in ("mu_s", "mu_a", "g")]
        return out[0], out[1], out[2]


@dataclass(frozen=True, eq=False)
class HGMedium:
    """Wavelength-independent medium with a Henyey-Greenstein phase function (validation cases).

    Attributes
    ----------
    mu_s, mu_a : float
        Scattering and absorption coefficients (1/um, or any consistent length unit).
    g : float
        Asymmetry parameter, ``-1 < g < 1``.
    phase_table_size : int
        ``K`` of the phase table.

    Examples
    --------
    >>> op = HGMedium(mu_s=9.0e-3, mu_a=1.0e-3, g=0.75).optical_properties()
    >>> round(op.albedo, 12), round(op.mu_t, 12)
    (0.9, 0.01)
    """

    mu_s: float
    mu_a: float
    g: float
    phase_table_size: int = DEFAULT_TABLE_SIZE

    def __post_init__(self) -> None:
        if not (self.mu_s >= 0 and np.isfinite(self.mu_s)):
            raise ValueError("HGMedium: mu_s must be finite and >= 0")
        if not (self.mu_a >= 0 and np.isfinite(self.mu_a)):
            raise ValueError("HGMedium: mu_a must be finite and >= 0")
        if not -1.0 < self.g < 1.0:
            raise ValueError("HGMedium: g must satisfy -1 < g < 1")

    def optical_properties(self, wavelength_nm: float = float("nan")) -> OpticalProperties:
        """Coefficients and HG phase table (the same at every wavelength).

        Parameters
        ----------
        wavelength_nm : float, optional
            Recorded only.

        Returns
        -------
        OpticalProperties
        """
        mu_t = float(self.mu_s) + float(self.mu_a)
        return OpticalProperties(
            wavelength_nm=float(wavelength_nm),
            mu_s=float(self.mu_s),
            mu_a=float(self.mu_a),
            mu_t=mu_t,
            g=float(self.g),
            albedo=_albedo(float(self.mu_s), mu_t),
            phase=PhaseTable.from_hg(self.g, int(self.phase_table_size)),
        )
