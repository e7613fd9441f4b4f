"""Mie scattering by homogeneous spheres in a host medium (thin wrapper of miepython).

A sphere of radius ``r`` and complex index ``m_p = n_p - i k_p`` sits in a non-absorbing host
of real index ``n_h`` and is lit at vacuum wavelength ``lambda`` (docs/physics.md section 2). Mie
theory depends only on the relative index and the size parameter in the HOST::

    m = m_p / n_h                    x = 2 pi n_h r / lambda

and yields the efficiencies ``Q_ext, Q_sca, Q_back``, ``Q_abs = Q_ext - Q_sca``, the
asymmetry parameter ``g = <cos theta>`` and the amplitude functions ``S1(mu), S2(mu)``. The
unpolarised phase function, normalised over the sphere, is (Bohren & Huffman 1983,
eqs. 3.12, 4.74)::

    p(mu) = (|S1|^2 + |S2|^2) / (2 pi x^2 Q_sca)   [1/sr],      2 pi int p dmu = 1

which is miepython's ``i_unpolarized(m, x, mu, norm="one")``. Cross sections are
``sigma = Q pi r^2``.

Sign convention (miepython, Bohren & Huffman): ``m = n - i k`` with ``k >= 0`` absorbing.
Functions here accept the absorption index either way: a complex index with a positive
imaginary part is read as ``n + i k`` and conjugated, i.e. the absorption index is always
``|Im m|`` (gain media are not modelled). :func:`particle_index` builds ``n - i k`` from a
positive ``k``.

Limits handled explicitly:

* no index contrast (``m = 1``): ``Q_ext = Q_sca = 0``; :func:`phase_function` returns the
  ``m -> 1`` limit (Rayleigh-Gans-Debye, Bohren & Huffman sec. 6.1) and warns;
* tiny spheres (``Q_sca`` underflows to 0): the Rayleigh phase function
  ``3 (1 + mu^2) / (16 pi)``;
* large spheres: miepython sums ``x + 4 x^(1/3) + 2`` terms (Wiscombe 1980); the angular grid
  of :func:`phase_grid` grows with ``x`` (about 0.4/x rad steps) and is capped at
  ``MAX_PHASE_GRID`` nodes, with a warning beyond ``x = MAX_SIZE_PARAMETER_PHASE``.

Log-normal size distributions (:class:`LogNormalSize`) are integrated with the trapezoidal
rule in ``z = ln(r / r_g) / ln(sigma_g)`` on ``[-z_max, z_max]`` (exponentially convergent
for smooth integrands under a Gaussian weight); the same sum on every other node gives a
second estimate, and their relative difference is returned as ``quadrature_error``, an
upper bound in practice of the error of the fine sum. Defaults: 257 nodes on ``[-8, 8]``
(truncated mass 1e-15, wide enough for the ``r^6``-weighted Rayleigh regime up to
``sigma_g = 1.5``). Non-absorbing resonant spheres converge slowly: raise ``n_nodes`` there
(the estimates per regime: docs/notes/implementation.md, "Mie").

The JIT backend of miepython is switched on (``MIEPYTHON_USE_JIT=1``, unless already set)
before it is imported (much faster, the same values to rounding). miepython is imported on first
use, not with this module: its JIT backend compiles one kernel at every import (``_cn_dn_nb`` has
no ``cache=True``), which a run whose tables come from the cache never needs.

References
----------
Bohren, C. F. & Huffman, D. R. (1983). *Absorption and Scattering of Light by Small Particles*,
ch. 4 and App. A. Wiley.
Wiscombe, W. J. (1980). Improved Mie scattering algorithms. *Applied Optics* 19, 1505-1509.
Prahl, S. miepython 3.3, https://miepython.readthedocs.io
"""

from __future__ import annotations

import os

os.environ.setdefault("MIEPYTHON_USE_JIT", "1")

import warnings  # noqa: E402
from dataclasses import dataclass  # noqa: E402
from typing import Any  # noqa: E402

import numpy as np  # noqa: E402
import numpy.typing as npt  # noqa: E402

from simulate.optics.fresnel import OpticsDomainWarning  # noqa: E402


def _miepython():
    """miepython, imported on first use, with its JIT kernels cached on disk (module docstring).

    miepython's ``mie_jit`` compiles ``_cn_dn_nb`` eagerly (it has a signature) and without
    ``cache=True`` -- the only one of its kernels without it -- so every process that imports it
    would spend seconds compiling a function this package never calls. During the import, ``numba.njit`` is
    wrapped to default ``cache=True`` for miepython's own modules only (numba's cache is keyed by the
    function's source and signature, so this is the same compiled code; it is kept with the
    project's kernels in the user's kernel cache, :mod:`simulate.kernelcache`). Numba's caching
    notes: https://numba.readthedocs.io/en/stable/developer/caching.html
    """
    import sys

    if "miepython" in sys.modules:
        return sys.modules["miepython"]
    import numba

    real = numba.njit

    def njit_cached(*args: Any, **kwargs: Any) -> Any:
        if str(sys._getframe(1).f_globals.get("__name__", "")).startswith("miepython"):
            kwargs.setdefault("cache", True)
        return real(*args, **kwargs)

    numba.njit = njit_cached
    try:
        import miepython
    finally:
        numba.njit = real
    return miepython

__all__ = [
    "particle_index",
    "relative_index",
    "size_parameter",
    "MieEfficiencies",
    "efficiencies",
    "sphere_efficiencies",
    "phase_function",
    "phase_grid",
    "LogNormalSize",
    "MieCrossSections",
    "cross_sections",
    "ensemble_phase_function",
    "MAX_PHASE_GRID",
    "MAX_SIZE_PARAMETER_PHASE",
]

#: Largest number of angular nodes :func:`phase_grid` produces.
MAX_PHASE_GRID = 24_000
#: Beyond this size parameter the capped phase grid no longer resolves the ripple (warning).
MAX_SIZE_PARAMETER_PHASE = 3_000.0
_PHASE_NODE_CUTOFF = 1e-7


# --------------------------------------------------------------------------------------
# indices and size parameter
# --------------------------------------------------------------------------------------


def particle_index(n: npt.ArrayLike, k: npt.ArrayLike = 0.0) -> np.ndarray | complex:
    """Complex index ``n - i k`` (miepython convention) from real ``n > 0`` and ``k >= 0``.

    Parameters
    ----------
    n : array_like
        Real part (refractive index).
    k : array_like
        Absorption index, given as a non-negative number.

    Returns
    -------
    complex or numpy.ndarray
        ``n - 1j * k``.

    Examples
    --------
    >>> particle_index(1.5, 0.01)
    (1.5-0.01j)
    """
    n_arr = np.asarray(n, dtype=float)
    k_arr = np.asarray(k, dtype=float)
    if np.any(~(n_arr > 0)):
        raise ValueError("particle index: the real part n must be finite and > 0")
    if np.any(~(k_arr >= 0)):
        raise ValueError("particle index: the absorption index k must be finite and >= 0")
    out = n_arr - 1j * k_arr
    return complex(out) if out.ndim == 0 else out


def _absorbing_convention(m: npt.ArrayLike) -> np.ndarray:
    """``Re m - i |Im m|`` as a complex array."""
    m_arr = np.asarray(m, dtype=complex)
    return m_arr.real - 1j * np.abs(m_arr.imag)


def relative_index(m_particle: npt.ArrayLike, n_host: npt.ArrayLike) -> np.ndarray | complex:
    """Relative index ``m = m_p / n_h`` in the ``n - i k`` convention.

    Parameters
    ----------
    m_particle : array_like
        Particle complex index (absorption index read as ``|Im|``).
    n_host : array_like
        Real host index ``> 0``.

    Returns
    -------
    complex or numpy.ndarray
    """
    n_h = np.asarray(n_host)
    if np.iscomplexobj(n_h) or np.any(~(n_h.astype(float) > 0)):
        raise ValueError("Mie: the host index n_host must be real and > 0 (absorbing hosts: "
                         "give their absorption as mu_a_host instead)")
    out = _absorbing_convention(m_particle) / n_h.astype(float)
    return complex(out) if out.ndim == 0 else out


def size_parameter(
    radius_um: npt.ArrayLike, wavelength_nm: npt.ArrayLike, n_host: npt.ArrayLike
) -> np.ndarray | float:
    """Size parameter in the host, ``x = 2 pi n_h r / lambda``.

    Parameters
    ----------
    radius_um : array_like
        Sphere radius in micrometres.
    wavelength_nm : array_like
        Vacuum wavelength in nanometres.
    n_host : array_like
        Real host index.

    Returns
    -------
    float or numpy.ndarray

    Examples
    --------
    >>> round(size_parameter(0.5, 500.0, 1.0), 12) == round(2 * np.pi, 12)
    True
    """
    out = 2.0 * np.pi * np.asarray(n_host, float) * np.asarray(radius_um, float) * 1000.0 / (
        np.asarray(wavelength_nm, float)
    )
    return float(out) if np.ndim(out) == 0 else out


# --------------------------------------------------------------------------------------
# efficiencies
# --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class MieEfficiencies:
    """Mie efficiencies of a sphere (dimensionless; floats or arrays of one shape).

    Attributes
    ----------
    qext, qsca, qabs, qback : float or numpy.ndarray
        Extinction, scattering, absorption (``qext - qsca``) and backscattering efficiencies.
    g : float or numpy.ndarray
        Asymmetry parameter (mean scattering cosine); 0 where nothing scatters.
    """

    qext: float | np.ndarray
    qsca: float | np.ndarray
    qabs: float | np.ndarray
    qback: float | np.ndarray
    g: float | np.ndarray


def efficiencies(m: npt.ArrayLike, x: npt.ArrayLike) -> MieEfficiencies:
    """Mie efficiencies for relative index ``m`` and size parameter ``x`` (broadcast).

    Parameters
    ----------
    m : array_like
        Relative complex index ``m_p / n_h`` (``n - ik``; ``|Im m|`` is the absorption index).
    x : array_like
        Size parameter(s) ``2 pi n_h r / lambda``, ``> 0``.

    Returns
    -------
    MieEfficiencies
        Floats for scalar inputs, arrays of the broadcast shape otherwise.

    Examples
    --------
    >>> e = efficiencies(1.55, 5.21282)        # Bohren & Huffman App. A
    >>> round(float(e.qsca), 5), round(float(e.qback), 5), round(float(e.g), 5)
    (3.10542, 2.92534, 0.63314)
    """
    m_arr = _absorbing_convention(m)
    x_arr = np.asarray(x, dtype=float)
    if np.any(~(x_arr > 0)) or np.any(~np.isfinite(x_arr)):
        raise ValueError("Mie: size parameter x must be finite and > 0")
    if np.any(~(m_arr.real > 0)) or np.any(~np.isfinite(m_arr)):
        raise ValueError("Mie: relative index must be finite with a positive real part")
    m_b, x_b = np.broadcast_arrays(m_arr, x_arr)
    shape = m_b.shape
    m_flat = np.ascontiguousarray(m_b.ravel())
    x_flat = np.ascontiguousarray(x_b.ravel())
    qext = np.empty(x_flat.size)
    qsca = np.empty(x_flat.size)
    qback = np.empty(x_flat.size)
    g = np.empty(x_flat.size)
    for i in range(x_flat.size):
        qext[i], qsca[i], qback[i], g[i] = _miepython().efficiencies_mx(complex(m_flat[i]), float(x_flat[i]))
    # a sphere without contrast scatters nothing: report exact zeros, not round-off
    none = m_flat == 1.0
    for arr in (qext, qsca, qback, g):
        arr[none] = 0.0
    # a non-absorbing sphere absorbs exactly nothing (no round-off albedo below 1)
    qabs = np.where(m_flat.imag == 0.0, 0.0, np.clip(qext - qsca, 0.0, None))
    vals = [qext, qsca, qabs, qback, g]
    if len(shape) == 0:
        return MieEfficiencies(*(float(v[0]) for v in vals))
    return MieEfficiencies(*(v.reshape(shape) for v in vals))


def sphere_efficiencies(
    m_particle: npt.ArrayLike,
    n_host: float,
    radius_um: npt.ArrayLike,
    wavelength_nm: npt.ArrayLike,
) -> MieEfficiencies:
    """Efficiencies of a sphere of index ``m_p`` and radius ``r`` in a host ``n_h`` at ``lambda``.

    Uses ``m = m_p / n_h`` and ``x = 2 pi n_h r / lambda`` (host index for both).

    Parameters
    ----------
    m_particle : array_like
        Particle complex index.
    n_host : float
        Host index.
    radius_um : array_like
        Radius in micrometres.
    wavelength_nm : array_like
        Vacuum wavelength in nanometres.

    Returns
    -------
    MieEfficiencies
    """
    return efficiencies(relative_index(m_particle, n_host), size_parameter(radius_um, wavelength_nm, n_host))


# --------------------------------------------------------------------------------------
# phase function
# --------------------------------------------------------------------------------------


def phase_grid(x: float, n_theta: int | None = None) -> np.ndarray:
    """Cosine grid on [-1, 1] fine enough to integrate the Mie phase function of size ``x``.

    Uniform in ``theta`` with two densities: 2000 intervals over the forward peak
    ``[0, min(pi, 40/x)]`` (about 50 nodes per diffraction lobe of width ``~pi/x``) and
    ``max(2000, 16x)`` intervals (about 16 per ripple period ``pi/x``) over the rest, at most
    ``MAX_PHASE_GRID`` nodes in all (reached near ``x = 1400``; at ``x = 3000`` still 7 nodes
    per ripple period). With the trapezoidal rule this integrates ``p`` to about 2e-5
    (``PhaseTable.quadrature_norm - 1``) for ``1e-3 <= x <= 1e3``.

    Parameters
    ----------
    x : float
        Size parameter.
    n_theta : int, optional
        Use a plain uniform-in-theta grid with this many intervals instead.

    Returns
    -------
    numpy.ndarray
        Cosines, descending from 1 to -1 (both included).
    """
    if n_theta is not None:
        if int(n_theta) < 2:
            raise ValueError("phase_grid: n_theta must be >= 2")
        theta = np.linspace(0.0, np.pi, int(n_theta) + 1)
    else:
        x = float(x)
        if x > MAX_SIZE_PARAMETER_PHASE:
            warnings.warn(
                f"Mie phase function at size parameter x = {x:g} > {MAX_SIZE_PARAMETER_PHASE:g}: "
                f"the angular grid is capped at {MAX_PHASE_GRID} nodes and no longer resolves "
                "the ripple structure (the forward peak is still resolved)",
                OpticsDomainWarning,
                stacklevel=2,
            )
        theta_f = min(np.pi, 40.0 / max(x, 1e-300))
        forward = np.linspace(0.0, theta_f, 2001)
        if theta_f >= np.pi:
            theta = forward
        else:
            n_back = int(min(max(2000, np.ceil(16.0 * x * (np.pi - theta_f) / np.pi)), MAX_PHASE_GRID - 2001))
            theta = np.concatenate((forward, np.linspace(theta_f, np.pi, n_back + 1)[1:]))
    mu = np.cos(theta)
    mu[0], mu[-1] = 1.0, -1.0
    return mu


def _rgd_shape(x: float, mu: np.ndarray) -> np.ndarray:
    """Unnormalised Rayleigh-Gans-Debye phase function of a sphere (the ``m -> 1`` limit)."""
    u = x * np.sqrt(np.clip(2.0 * (1.0 - mu), 0.0, None))  # = 2 x sin(theta/2)
    small = u < 1e-3
    us = np.where(small, 1.0, u)
    form = np.where(small, 1.0 - u * u / 10.0, 3.0 * (np.sin(us) - us * np.cos(us)) / us**3)
    return 0.5 * (1.0 + mu * mu) * form * form


def phase_function(m: complex, x: float, mu: npt.ArrayLike) -> np.ndarray:
    """Unpolarised Mie phase function ``p(mu)`` in 1/sr, ``2 pi int_{-1}^{1} p dmu = 1``.

    Parameters
    ----------
    m : complex
        Relative index ``m_p / n_h`` (``n - ik``).
    x : float
        Size parameter ``> 0``.
    mu : array_like
        Cosines of the scattering angle.

    Returns
    -------
    numpy.ndarray
        ``p(mu)``, same shape as ``mu``. For ``m = 1`` exactly (nothing scatters) the
        ``m -> 1`` limit (Rayleigh-Gans-Debye) with an :class:`OpticsDomainWarning`; where
        ``Q_sca`` underflows to 0 the Rayleigh limit ``3 (1 + mu^2) / (16 pi)``.
    """
    m_c = complex(_absorbing_convention(m))
    x = float(x)
    if not (x > 0 and np.isfinite(x)):
        raise ValueError("Mie: size parameter x must be finite and > 0")
    mu_arr = np.asarray(mu, dtype=float)
    if np.any(~((mu_arr >= -1.0) & (mu_arr <= 1.0))):
        raise ValueError("Mie phase function: mu must lie in [-1, 1]")
    if m_c == 1.0:
        warnings.warn(
            "Mie: particle index equals the host index (m = 1): the particles scatter nothing; "
            "the phase function returned is the m -> 1 (Rayleigh-Gans-Debye) limit",
            OpticsDomainWarning,
            stacklevel=2,
        )
        grid = phase_grid(x)
        norm = 2.0 * np.pi * -np.trapezoid(_rgd_shape(x, grid), grid)
        return _rgd_shape(x, mu_arr) / norm
    qsca = efficiencies(m_c, x).qsca
    if not qsca > 0:
        return 3.0 * (1.0 + mu_arr * mu_arr) / (16.0 * np.pi)
    flat = np.ascontiguousarray(mu_arr.ravel())
    p = _miepython().i_unpolarized(m_c, x, flat, norm="one")
    return np.asarray(p, dtype=float).reshape(mu_arr.shape)


# --------------------------------------------------------------------------------------
# size distributions
# --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class LogNormalSize:
    """Log-normal number distribution of sphere radii.

    ``ln r ~ Normal(ln r_g, ln sigma_g)``: ``r_g`` is the median (geometric mean) radius,
    ``sigma_g >= 1`` the geometric standard deviation (``sigma_g = 1`` is monodisperse).

    Attributes
    ----------
    median_radius_um : float
        ``r_g`` in micrometres.
    sigma_g : float
        Geometric standard deviation (dimensionless, ``>= 1``).
    n_nodes : int
        Odd number of trapezoid nodes in ``z`` on ``[-z_max, z_max]``.
    z_max : float
        Truncation in standard deviations (mass beyond it: ``erfc(z_max / sqrt 2)``).
    """

    median_radius_um: float
    sigma_g: float
    n_nodes: int = 257
    z_max: float = 8.0

    def __post_init__(self) -> None:
        if not (self.median_radius_um > 0 and np.isfinite(self.median_radius_um)):
            raise ValueError("LogNormalSize: median_radius_um must be finite and > 0")
        if not (self.sigma_g >= 1.0 and np.isfinite(self.sigma_g)):
            raise ValueError("LogNormalSize: sigma_g (geometric standard deviation) must be >= 1")
        if self.n_nodes < 3 or self.n_nodes % 2 == 0:
            raise ValueError("LogNormalSize: n_nodes must be odd and >= 3")
        if not self.z_max > 0:
            raise ValueError("LogNormalSize: z_max must be > 0")

    @property
    def log_sigma(self) -> float:
        """``s = ln sigma_g``."""
        return float(np.log(self.sigma_g))

    def moment(self, k: float) -> float:
        """Exact raw moment ``<r^k> = r_g^k exp(k^2 s^2 / 2)`` in um^k."""
        s = self.log_sigma
        return float(self.median_radius_um**k * np.exp(0.5 * k * k * s * s))

    def nodes(self, coarse: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """Radii (um) and weights (summing to 1) of the trapezoid rule.

        Parameters
        ----------
        coarse : bool
            Every other node (twice the step), for the error estimate.

        Returns
        -------
        radii_um, weights : numpy.ndarray
        """
        if self.sigma_g == 1.0:
            return np.array([self.median_radius_um]), np.array([1.0])
        z = np.linspace(-self.z_max, self.z_max, self.n_nodes)
        if coarse:
            z = z[::2]
        w = np.exp(-0.5 * z * z)
        w /= w.sum()
        return self.median_radius_um * np.exp(self.log_sigma * z), w


@dataclass(frozen=True)
class MieCrossSections:
    """Mean cross sections per particle (um^2) and mean asymmetry of a sphere ensemble.

    Attributes
    ----------
    sigma_ext, sigma_sca, sigma_abs, sigma_back : float
        ``<Q pi r^2>`` over the size distribution, in um^2.
    g : float
        ``<g sigma_sca> / <sigma_sca>`` (0 when nothing scatters).
    x : float
        Size parameter of the median (or only) radius.
    m : complex
        Relative index ``m_p / n_h``.
    quadrature_error : float
        Relative difference between the fine and coarse size quadratures (0 for one size).
    """

    sigma_ext: float
    sigma_sca: float
    sigma_abs: float
    sigma_back: float
    g: float
    x: float
    m: complex
    quadrature_error: float = 0.0


def _ensemble(
    m_particle: complex,
    n_host: float,
    wavelength_nm: float,
    radius_um: float | None,
    distribution: LogNormalSize | None,
) -> tuple[complex, np.ndarray, np.ndarray, np.ndarray, MieEfficiencies]:
    if (radius_um is None) == (distribution is None):
        raise ValueError("Mie: give exactly one of radius_um and distribution")
    m = complex(relative_index(m_particle, n_host))
    if distribution is None:
        if not (radius_um is not None and radius_um > 0 and np.isfinite(radius_um)):
            raise ValueError("Mie: radius_um must be finite and > 0")
        radii, weights = np.array([float(radius_um)]), np.array([1.0])
    else:
        radii, weights = distribution.nodes()
    x = np.asarray(size_parameter(radii, wavelength_nm, n_host), dtype=float).ravel()
    eff = efficiencies(np.full(x.shape, m), x)
    return m, radii, weights, x, eff


#: results of :func:`cross_sections` and :func:`ensemble_phase_function` by their exact inputs, in
#: this process: a run asks for the same wavelengths more than once (``simulate fabric``'s cost
#: estimate, then the run's medium: seconds each time for a log-normal distribution). Cleared
#: when it reaches :data:`_MEMO_MAX` entries. Results are immutable (the arrays are copied out).
_MEMO: dict[tuple, Any] = {}
_MEMO_MAX = 4096


def _memo_key(kind: str, m_particle: complex, n_host: float, wavelength_nm: float, radius_um: float | None,
              distribution: LogNormalSize | None, mu: npt.ArrayLike | None = None) -> tuple:
    mu_key = None if mu is None else np.ascontiguousarray(mu, dtype=float).tobytes()
    return (kind, complex(m_particle), float(n_host), float(wavelength_nm),
            None if radius_um is None else float(radius_um), distribution, mu_key)


def _remember(key: tuple, value: Any) -> Any:
    if len(_MEMO) >= _MEMO_MAX:
        _MEMO.clear()
    _MEMO[key] = value
    return value


def cross_sections(
    m_particle: complex,
    n_host: float,
    wavelength_nm: float,
    radius_um: float | None = None,
    distribution: LogNormalSize | None = None,
) -> MieCrossSections:
    """Mean cross sections of one sphere size or of a log-normal ensemble.

    Parameters
    ----------
    m_particle : complex
        Particle complex index (``n - ik``; ``|Im|`` is the absorption index).
    n_host : float
        Real host index.
    wavelength_nm : float
        Vacuum wavelength in nm.
    radius_um : float, optional
        Radius of monodisperse spheres (um).
    distribution : LogNormalSize, optional
        Log-normal number distribution instead.

    Returns
    -------
    MieCrossSections
    """
    key = _memo_key("cs", m_particle, n_host, wavelength_nm, radius_um, distribution)
    if key in _MEMO:
        return _MEMO[key]
    m, radii, w, x, eff = _ensemble(m_particle, n_host, wavelength_nm, radius_um, distribution)
    area = np.pi * radii**2
    # the ensemble's efficiencies are arrays over its size nodes (np.asarray takes them as they are)
    qext, qsca, qback, qabs, g = (np.asarray(q) for q in (eff.qext, eff.qsca, eff.qback, eff.qabs, eff.g))

    def integrate(weights: np.ndarray, sl: slice) -> tuple[float, float, float, float, float]:
        a = area[sl]
        s_ext = float(np.sum(weights * qext[sl] * a))
        s_sca = float(np.sum(weights * qsca[sl] * a))
        s_back = float(np.sum(weights * qback[sl] * a))
        s_abs = float(np.sum(weights * qabs[sl] * a))
        gw = float(np.sum(weights * g[sl] * qsca[sl] * a))
        return s_ext, s_sca, s_abs, s_back, (gw / s_sca if s_sca > 0 else 0.0)

    fine = integrate(w, slice(None))
    err = 0.0
    if distribution is not None and distribution.sigma_g > 1.0:
        _, wc = distribution.nodes(coarse=True)
        coarse = integrate(wc, slice(None, None, 2))
        # sigma_back is left out: resonance spikes make it converge slowly, and no
        # coefficient of the medium depends on it
        pairs = [(fine[i], coarse[i]) for i in (0, 1, 2, 4)]
        rel = [abs(a - b) / abs(a) for a, b in pairs if a != 0]
        err = max(rel) if rel else 0.0
    # one size: its radius, the only node (_ensemble has checked it)
    x_med = float(size_parameter(radii[0] if distribution is None else distribution.median_radius_um,
                                 wavelength_nm, n_host))
    return _remember(key, MieCrossSections(*fine, x=x_med, m=m, quadrature_error=err))


def ensemble_phase_function(
    m_particle: complex,
    n_host: float,
    wavelength_nm: float,
    radius_um: float | None = None,
    distribution: LogNormalSize | None = None,
    mu: npt.ArrayLike | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Phase function of one size or of a log-normal ensemble, weighted by ``sigma_sca``.

    ``p(mu) = sum_i w_i sigma_sca,i p_i(mu) / sum_i w_i sigma_sca,i`` over the size nodes
    (nodes contributing less than ``_PHASE_NODE_CUTOFF`` = 1e-7 of the scattering each are
    skipped; they change ``p`` by less than about 1e-6 in all). The cost grows with the number
    of nodes times the grid size (``~16 x_max``) times the number of Mie terms (``~x``).

    Parameters
    ----------
    m_particle, n_host, wavelength_nm, radius_um, distribution
        As in :func:`cross_sections`.
    mu : array_like, optional
        Cosines; default :func:`phase_grid` of the largest contributing size parameter.

    Returns
    -------
    mu, p : numpy.ndarray
        The cosines used and ``p(mu)`` in 1/sr (normalised to 1 over the sphere).
    """
    key = _memo_key("phase", m_particle, n_host, wavelength_nm, radius_um, distribution, mu)
    if key not in _MEMO:
        _remember(key, _ensemble_phase(m_particle, n_host, wavelength_nm, radius_um, distribution, mu))
    mu_arr, p = _MEMO[key]
    return mu_arr.copy(), p.copy()


def _ensemble_phase(m_particle: complex, n_host: float, wavelength_nm: float, radius_um: float | None,
                    distribution: LogNormalSize | None, mu: npt.ArrayLike | None) -> tuple[np.ndarray, np.ndarray]:
    """:func:`ensemble_phase_function` without the memo."""
    m, radii, w, x, eff = _ensemble(m_particle, n_host, wavelength_nm, radius_um, distribution)
    ws = w * eff.qsca * np.pi * radii**2
    total = ws.sum()
    if not total > 0:
        x_ref = float(np.max(x))
        mu_arr = phase_grid(x_ref) if mu is None else np.asarray(mu, float)
        return mu_arr, phase_function(m, x_ref, mu_arr)
    keep = ws > _PHASE_NODE_CUTOFF * total
    mu_arr = phase_grid(float(np.max(x[keep]))) if mu is None else np.asarray(mu, dtype=float)
    p = np.zeros(mu_arr.shape)
    for xi, wi in zip(x[keep], ws[keep], strict=True):
        p += wi * phase_function(m, float(xi), mu_arr)
    return mu_arr, p / ws[keep].sum()
