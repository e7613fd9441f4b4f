"""What a run will cost, estimated before it starts: refuse the hopeless, warn about the long.

A config can be valid field by field and still never finish: particles of 1 mm (``median_radius_um
= 1e3``: the Mie phase function sums ~10^4 terms on a 24 000-node grid at 257 sizes per
wavelength), ``number_density_per_um3 = 1e14`` (every photon scatters until the event cap of a
million), ``target_rel_err = 1e-9`` (1e20 photons). :func:`estimate_cost` gives the order of
magnitude from the config alone, and :func:`check_cost` turns it into a decision that the commands
(``simulate fabric``, ``fiber``, ``fit``, ``sweep``) apply before any work:

- estimated above :data:`MAX_SECONDS` (one day): refused, one line with the figures and what to
  change (exit 2); a photon budget (``--max-photons``, ``method.max_photons``) smaller than the
  target needs is what the estimate then counts;
- above :data:`WARN_SECONDS` (ten minutes): a warning line with the figure, then the run.

The model (an order of magnitude, not a promise; its constants are calibrated on one run of red
cotton, docs/notes/implementation.md, "The cost model"):

- photons ``N = max(N_FLOOR, C / target^2)`` with ``C`` = 215 (the standard
  error falls as ``1/sqrt(N)``) and ``N_FLOOR`` = 1e6 (the routes' first rounds), or the photon
  budget when that is smaller;
- events per photon in the fiber (a cylinder of diameter ``D``), from the optical thicknesses
  ``tau_s = mu_s D`` and ``tau' = mu_s (1 - g) D`` and the albedo ``w``: a diffusing photon needs
  ``~tau'^2`` transport steps of ``1/(1 - g)`` scatterings to cross the fiber, and implicit capture
  with roulette ends it after ``~10 / (1 - w)`` events, so ``E = 1 + min(tau_s (1 + tau'),
  10 / (1 - w), DEFAULT_MAX_EVENTS)``, averaged over the wavelengths (red cotton: 73);
- :data:`EVENT_RATE` = 2e6 photon events a second (NEE route, all threads);
- the Mie phase functions: per wavelength ``0.082 s (x / 534)^2`` for one radius and
  ``2.2 s (x / 53)^2`` for a log-normal distribution (257 sizes), ``x = 2 pi n_host r / lambda``
  at the shortest wavelength and the (median) radius (miepython with JIT).

Particles at least as large as the fiber are refused outright (they cannot sit inside it), and so is
a number density whose particles would fill more than the whole volume.

The events per photon of a ``[particles]`` config need the medium's Mie cross sections (``mu_s``,
``mu_a``, ``g`` at every wavelength; importing miepython and loading its compiled kernels alone
takes about a second), although a run whose tables are in the table cache needs no Mie result otherwise.
They are therefore kept in the table cache (:mod:`simulate.fiber.tablecache`, kind ``coeffs``, a
file of ~1.5 kB; :func:`medium_coefficients`) under the hash of the medium (particles, host index, dye sampled at the
wavelengths), the wavelengths and the source of the Mie and medium modules: a later check of the
same medium reads the stored coefficients, the same float64 values a computation gives, so the
estimate and the decision are the same to the bit. With the cache disabled
(``FABRIC_OPTICS_NO_CACHE``, ``--no-cache``) they are computed each time, as is an entry that
cannot be read.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from simulate.config import ConfigError, SimulationConfig
from simulate.fiber import tablecache

__all__ = ["BudgetError", "CostEstimate", "EVENT_RATE", "MAX_SECONDS", "WARN_SECONDS", "check_cost",
           "estimate_cost", "medium_coefficients"]

#: Estimated seconds beyond which a run without a photon budget is refused (one day).
MAX_SECONDS = 86_400.0
#: Estimated seconds beyond which a run is announced with its estimate (ten minutes).
WARN_SECONDS = 600.0
#: Photon events a second of the fiber Monte Carlo (see the module docstring).
EVENT_RATE = 2e6
#: ``N = C / target^2``: photons for a target relative error (module docstring).
PHOTONS_AT_UNIT_ERROR = 215.0
#: The routes' smallest run.
N_FLOOR = 1e6
#: Per-photon event cap of the transport (``simulate.montecarlo.DEFAULT_MAX_EVENTS``).
EVENT_CAP = 1e6


class BudgetError(ConfigError):
    """A run whose estimated cost is beyond :data:`MAX_SECONDS` (one line with the figures)."""


@dataclass(frozen=True)
class CostEstimate:
    """The estimate of one run (module docstring): photons, events per photon, seconds."""

    photons: float
    events_per_photon: float
    mie_seconds: float
    seconds: float
    budgeted: bool

    def describe(self) -> str:
        """``about 3.2 h (2.2e+06 photons x 73 events, Mie 1.5 s)``."""
        return (f"about {_duration(self.seconds)} ({self.photons:.2g} photons x {self.events_per_photon:.3g} "
                f"events each, Mie {_duration(self.mie_seconds)})")


def _duration(seconds: float) -> str:
    if seconds < 10:
        return f"{seconds:.2g} s"
    if seconds < 120:
        return f"{seconds:.0f} s"
    if seconds < 7200:
        return f"{seconds / 60:.0f} min"
    if seconds < 3 * 86400:
        return f"{seconds / 3600:.1f} h"
    if seconds < 365 * 86400:
        return f"{seconds / 86400:.0f} days"
    return f"{seconds / (365.25 * 86400):.2g} years"


def _mie_seconds(config: SimulationConfig, wavelengths: np.ndarray) -> float:
    p = config.particles
    if p is None:
        return 0.0
    lam_um = float(np.min(wavelengths)) / 1000.0
    if p.size is not None:
        x = 2 * math.pi * config.n_host * p.size.median_radius_um / lam_um
        per = 2.2 * (x / 53.0) ** 2
    else:
        x = 2 * math.pi * config.n_host * float(p.radius_um or 0.0) / lam_um
        per = 0.082 * (x / 534.0) ** 2
    return per * len(wavelengths)


#: the code the stored coefficients of :func:`medium_coefficients` depend on (part of their key)
MIE_MODULES = ("simulate.optics.mie", "simulate.media.medium", "simulate.optics.fresnel")


def medium_coefficients(medium: Any, wavelengths: Any) -> dict[str, np.ndarray]:
    """``mu_s``, ``mu_a``, ``g`` (1/um, 1/um, -) of a Mie ``medium`` at ``wavelengths``, through the table cache.

    Kept under the hash of the medium, the wavelengths and :data:`MIE_MODULES` (module docstring):
    a hit returns the float64 values :meth:`~simulate.media.medium.MieMedium.optical_properties`
    gives (``with_phase=False``), without importing miepython. Shared by the cost check and the felt
    tracer's exit-bin choice (:func:`simulate.raytrace.estimate.fiber_scatterings`).

    Parameters
    ----------
    medium : MieMedium
        The particles in their host.
    wavelengths : array_like
        Wavelengths (nm).

    Returns
    -------
    dict of str -> numpy.ndarray
        ``"mu_s"``, ``"mu_a"`` and ``"g"``, one value per wavelength.
    """
    wl = np.atleast_1d(np.asarray(wavelengths, float))

    def compute() -> dict[str, np.ndarray]:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            ops = [medium.optical_properties(float(w), with_phase=False) for w in wl]
        return {a: np.array([float(getattr(op, a)) for op in ops], float) for a in ("mu_s", "mu_a", "g")}

    key = tablecache.content_key("coeffs", (medium, wl), MIE_MODULES)
    return tablecache.cached(key, compute)[0]


def _events_per_photon(config: SimulationConfig, wavelengths: np.ndarray) -> float:
    diameter = 2.0 * config.radius_um
    if config.hg is not None:
        mu_s, mu_a, g = config.hg
        props = [(mu_s, mu_a, g)] * len(wavelengths)
    else:
        coeffs = medium_coefficients(config.medium(wavelengths), wavelengths)
        props = [(float(s), float(a), float(g)) for s, a, g in zip(coeffs["mu_s"], coeffs["mu_a"], coeffs["g"], strict=True)]
    events = []
    for mu_s, mu_a, g in props:
        tau_s = mu_s * diameter
        tau_t = mu_s * (1.0 - g) * diameter
        mu_t = mu_s + mu_a
        absorbed = 10.0 / (mu_a / mu_t) if mu_t > 0 and mu_a > 0 else math.inf
        events.append(1.0 + min(tau_s * (1.0 + tau_t), absorbed, EVENT_CAP))
    return float(np.mean(events))


def estimate_cost(config: SimulationConfig, wavelengths: Any, target_rel_err: float,
                  max_photons: int | None = None) -> CostEstimate:
    """The estimated cost of a run of ``config`` at ``wavelengths`` (module docstring).

    The Mie part is estimated from the size parameter alone; the events per photon need the
    medium's coefficients (no phase function), computed only when the Mie part is affordable.

    Parameters
    ----------
    config : SimulationConfig
        The run's fiber, medium and particles.
    wavelengths : array_like
        Wavelengths of the run (nm).
    target_rel_err : float
        The run's target relative error, which sets the photons.
    max_photons : int, optional
        A photon budget; the estimate is bounded by it when it is smaller than the target needs.

    Returns
    -------
    CostEstimate
        Photons, events per photon (NaN when the Mie part alone is beyond :data:`MAX_SECONDS`), the
        Mie part's seconds and the total seconds.
    """
    wl = np.atleast_1d(np.asarray(wavelengths, float))
    mie = _mie_seconds(config, wl)
    photons = max(N_FLOOR, PHOTONS_AT_UNIT_ERROR / float(target_rel_err) ** 2)
    budgeted = False
    if max_photons and float(max_photons) < photons:
        budgeted = True
        photons = float(max_photons)
    if mie > MAX_SECONDS:
        return CostEstimate(photons, math.nan, mie, mie, budgeted)
    events = _events_per_photon(config, wl)
    return CostEstimate(photons, events, mie, mie + photons * events / EVENT_RATE, budgeted)


def check_cost(config: SimulationConfig, wavelengths: Any, target_rel_err: float,
               max_photons: int | None = None, *, runs: int = 1) -> str | None:
    """Refuse (:class:`BudgetError`) or announce (the returned warning line) a costly run.

    Parameters
    ----------
    config : SimulationConfig
        The run's config; its ``source`` names the file in the messages.
    wavelengths : array_like
        Wavelengths of the run (nm).
    target_rel_err : float
        The run's target relative error.
    max_photons : int, optional
        The run's photon budget (``--max-photons``, ``method.max_photons``).
    runs : int
        Independent runs of this cost (the points of a sweep).

    Returns
    -------
    str or None
        A one-line warning for a run estimated beyond :data:`WARN_SECONDS`, else None.

    Raises
    ------
    BudgetError
        Particles at least as large as the fiber; or an estimate beyond :data:`MAX_SECONDS`
        (Mie alone, or the Monte Carlo without a photon budget).
    """
    source = config.source
    file = f"{source[len('preset '):]}.toml" if source.startswith("preset ") else Path(source).name
    p = config.particles
    if p is not None:
        r = p.size.median_radius_um if p.size is not None else float(p.radius_um or 0.0)
        field = "particles.size.median_radius_um" if p.size is not None else "particles.radius_um"
        if r >= config.radius_um:
            raise BudgetError(f"{file}: {field} = {r:g} um is not smaller than fiber.radius_um = "
                              f"{config.radius_um:g} um: the particles sit inside the fiber")
        if p.number_density_per_um3 is not None:
            with warnings.catch_warnings():       # the "dependent scattering" warning: refused below anyway
                warnings.simplefilter("ignore")
                medium: Any = config.medium(np.atleast_1d(np.asarray(wavelengths, float)))
            fv = float(medium.volume_fraction_value)   # a [particles] config gives a MieMedium
            if fv >= 1.0:
                raise BudgetError(f"{file}: particles.number_density_per_um3 = {p.number_density_per_um3:g} gives "
                                  f"a volume fraction of {fv:.3g}: the particles cannot fit (it must be < 1)")
    est = estimate_cost(config, wavelengths, target_rel_err, max_photons)
    total = est.seconds * runs
    what = f"{runs} runs, " if runs > 1 else ""
    if est.mie_seconds * runs > MAX_SECONDS:
        raise BudgetError(f"{file}: the Mie phase functions of these particles would take about "
                          f"{_duration(est.mie_seconds * runs)} ({what}size parameter too large); at most "
                          f"{_duration(MAX_SECONDS)}: use smaller particles")
    if total > MAX_SECONDS:
        raise BudgetError(f"{file}: estimated cost {what}{est.describe()} (target_rel_err {target_rel_err:g}); "
                          f"at most {_duration(MAX_SECONDS)} without a photon budget: raise the target "
                          f"error, set --max-photons (method.max_photons), or make the medium less dense")
    if total > WARN_SECONDS:
        return (f"estimated cost {what}{est.describe()}"
                + ("; bounded by the photon budget" if est.budgeted else ""))
    return None
