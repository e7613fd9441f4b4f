"""Spectral ("white") Monte Carlo of a fiber: optics per wavelength, wavelength groups, a group's walk.

Package docstring of :mod:`simulate.fiber` ("Spectral Monte Carlo"): wavelengths whose scattering
is close enough (``|ln(mu_s / mu_s^ref)| <= 0.25``, ``|g - g^ref| <= 0.03``) share one walk and
re-weight its paths. :func:`run_seed` is the ONE rule that gives each (incident direction, group)
run its streams: the volume term (:func:`simulate.fiber.volume_brdf`) and the absorption table
(:mod:`simulate.fiber.absorption`) both use it, which is what lets the fit re-walk the same
photons (common random numbers).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from simulate.fiber.model import Fiber
from simulate.media.medium import MieMedium
from simulate.montecarlo import kernel as K
from simulate.montecarlo.scatter import PhaseArrays, phase_arrays
from simulate.montecarlo.transport import ParameterError, SpectralTargets

__all__ = ["GROUP_LOG_MU_S", "GROUP_G", "REWEIGHT_LIMIT", "BLEND", "SpectralOptics", "spectral_optics",
           "wavelength_groups", "blended_groups", "group_walk", "run_seed", "direction_keys", "phase_chi2",
           "reweight_exponent"]

GROUP_LOG_MU_S = 0.25
GROUP_G = 0.03
#: Largest ``N (r - 1)^2 + N chi^2`` of :func:`reweight_exponent` at which a walk is re-weighted to
#: other scattering (``ln 2``: the likelihood ratio at most doubles the variance).
REWEIGHT_LIMIT = math.log(2.0)
#: Wavelengths on each side of a group boundary that both neighbouring walks score and
#: :func:`blended_groups` blends linearly (docs/notes/spectral-groups.md).
BLEND = 2


@dataclass(frozen=True)
class SpectralOptics:
    """The medium's ``mu_s``, ``mu_a``, ``g`` and phase arrays per wavelength (phase arrays shared when equal)."""

    mu_s: np.ndarray
    mu_a: np.ndarray
    g: np.ndarray
    phases: list[PhaseArrays]
    #: the host's absorption (the dye) within ``mu_a``, for a fiber whose dye has a profile; None: uniform
    mu_a_dye: np.ndarray | None = None



def spectral_optics(fiber: Fiber, wavelengths_nm: np.ndarray, phase_at: Any = None) -> SpectralOptics:
    """The medium's optical properties at each wavelength.

    Parameters
    ----------
    fiber : Fiber
        The fiber whose medium (and placed dye) is read.
    wavelengths_nm : numpy.ndarray
        Vacuum wavelengths (nm).
    phase_at : array_like of int, optional
        Only these wavelengths (indices into ``wavelengths_nm``) get their own phase table (Mie: the
        expensive part); the others get the Henyey-Greenstein table of their ``g``
        (``optical_properties(..., with_phase=False)``), for callers that walk and score with the phase
        functions of a few wavelengths only (the held-scattering tables of :mod:`simulate.raytrace.yarn`).
        ``mu_s``, ``mu_a`` and ``g`` are the same either way. None: every wavelength's own table.

    Returns
    -------
    SpectralOptics
        ``mu_s``, ``mu_a``, ``g``, the phase tables and a placed dye's ``mu_a_dye`` per wavelength.
    """
    mu_s, mu_a, g, phases = [], [], [], []
    cache: dict[Any, PhaseArrays] = {}
    wanted = None if phase_at is None else {int(i) for i in phase_at}
    for i, wl in enumerate(wavelengths_nm):
        if wanted is not None and i not in wanted and isinstance(fiber.medium, MieMedium):
            op = fiber.medium.optical_properties(float(wl), with_phase=False)
        else:       # an HG medium has one table for all
            op = fiber.medium.optical_properties(float(wl))
        mu_s.append(op.mu_s)
        mu_a.append(op.mu_a)
        g.append(op.g)
        key = op.phase.cos_table.tobytes()
        if key not in cache:
            cache[key] = phase_arrays(cos_table=op.phase.cos_table)
        phases.append(cache[key])
    dye = None
    if getattr(fiber, "dye_profile", "uniform") != "uniform":
        dye = np.array([host_absorption(fiber.medium, float(wl)) for wl in wavelengths_nm])
    if getattr(fiber, "scatterer_profile", "uniform") != "uniform":
        _check_clear_particles(fiber, wavelengths_nm, np.array(mu_a))
    return SpectralOptics(np.array(mu_s), np.array(mu_a), np.array(g), phases, dye)


def _check_clear_particles(fiber: Fiber, wavelengths_nm: np.ndarray, mu_a: np.ndarray) -> None:
    """Refuse absorbing particles under a scatterer profile (ParameterError).

    A scatterer profile places the particles' scattering only: the walk absorbs ``mu_a`` everywhere, so the
    particles themselves must not absorb (their absorption would sit where they are).
    """
    host = np.array([host_absorption(fiber.medium, float(wl)) for wl in wavelengths_nm])
    particles = mu_a - host
    if np.any(particles > 1e-9 * np.maximum(mu_a, 1e-300)):
        i = int(np.argmax(particles))
        raise ParameterError(f"Fiber: scatterer_profile {fiber.scatterer_profile!r} takes particles that do not "
                             f"absorb (k = 0); these absorb {particles[i]:.3g} /um at {float(wavelengths_nm[i]):g} nm")


def host_absorption(medium: Any, wavelength_nm: float) -> float:
    """The host's own absorption (1/um) within the medium's ``mu_a``.

    It is the dye a profile places (:attr:`simulate.fiber.Fiber.dye_profile`): a Mie medium's
    ``mu_a_host_per_um``; a Henyey-Greenstein medium's whole ``mu_a`` (it has no other absorber).

    Parameters
    ----------
    medium : MieMedium or HGMedium
        The fiber's medium (a cached medium is unwrapped).
    wavelength_nm : float
        Vacuum wavelength (nm).

    Returns
    -------
    float
        The host's absorption coefficient (1/um).
    """
    inner = getattr(medium, "medium", None)     # a cached medium (simulate.fiber.farfield.CachedMedium)
    if inner is not None and not isinstance(medium, MieMedium):
        return host_absorption(inner, wavelength_nm)
    if isinstance(medium, MieMedium):
        host = medium.mu_a_host_per_um
        return float(host(np.array([wavelength_nm]))[0]) if callable(host) else float(host)
    return float(medium.optical_properties(wavelength_nm).mu_a)


def wavelength_groups(optics: SpectralOptics, max_log_mu_s: float = GROUP_LOG_MU_S,
                      max_size: int | None = None) -> list[np.ndarray]:
    """Consecutive wavelengths whose scattering is close enough to share one walk.

    A group's ``mu_s`` lie within ``max_log_mu_s`` (in ``log``; equal values always) and its ``g``
    within ``GROUP_G`` of the group's middle one.

    Parameters
    ----------
    optics : SpectralOptics
        The medium's optics per wavelength.
    max_log_mu_s : float
        Largest ``log`` distance of ``mu_s`` within a group. The default is the re-weighted walks'; a
        held-scattering table passes its own (:func:`simulate.raytrace.yarn.held_groups`).
    max_size : int, optional
        A group of more wavelengths is split into ``ceil(size / max_size)`` consecutive groups of
        near-equal size.

    Returns
    -------
    list of numpy.ndarray
        The wavelength indices of each group, in order.
    """
    n = optics.mu_s.size
    groups: list[list[int]] = []
    current: list[int] = []
    for i in range(n):
        trial = current + [i]
        ref = trial[len(trial) // 2]
        ok = all(
            (optics.mu_s[j] == optics.mu_s[ref] or (optics.mu_s[j] > 0 and optics.mu_s[ref] > 0
             and abs(math.log(optics.mu_s[j] / optics.mu_s[ref])) <= max_log_mu_s))
            and abs(optics.g[j] - optics.g[ref]) <= GROUP_G
            for j in trial
        )
        if ok:
            current = trial
        else:
            groups.append(current)
            current = [i]
    if current:
        groups.append(current)
    if max_size is not None:
        groups = [list(part) for gr in groups
                  for part in np.array_split(np.array(gr), int(math.ceil(len(gr) / max(1, int(max_size)))))]
    return [np.array(gr) for gr in groups]


def blended_groups(groups: list[np.ndarray], blend: int = BLEND) -> list[tuple[np.ndarray, np.ndarray]]:
    """What each group's walk scores, and with which weight: ``(scored, weight)`` per group.

    A boundary between groups ``A`` and ``B`` gets a transition zone of the last ``h`` wavelengths of
    ``A`` and the first ``h`` of ``B`` (``h = min(blend, |A| // 2, |B| // 2)``; zones never overlap).
    Both walks score the zone; its ``j``-th wavelength (``j = 0 .. 2h - 1``) takes ``t = (j + 1) /
    (2h + 1)`` of ``B``'s walk and ``1 - t`` of ``A``'s. Every wavelength's weights add up to 1,
    so the blend of unbiased estimates is unbiased; the difference between two walks (their Monte
    Carlo noise) is spread over ``2h + 1`` steps instead of one step at the boundary.

    Parameters
    ----------
    groups : list of numpy.ndarray
        Consecutive wavelength groups (:func:`wavelength_groups`).
    blend : int
        Largest half-width ``h`` of a transition zone (0: no blending).

    Returns
    -------
    list of (numpy.ndarray, numpy.ndarray)
        Per group, the wavelengths its walk scores and their weights.

    Examples
    --------
    >>> [(s.tolist(), w.round(2).tolist()) for s, w in blended_groups([np.arange(4), np.arange(4, 8)], 2)]
    [([0, 1, 2, 3, 4, 5], [1.0, 1.0, 0.8, 0.6, 0.4, 0.2]), ([2, 3, 4, 5, 6, 7], [0.2, 0.4, 0.6, 0.8, 1.0, 1.0])]
    """
    n = sum(len(g) for g in groups)
    first = int(groups[0][0]) if groups else 0
    W = np.zeros((len(groups), n))
    for k, g in enumerate(groups):
        W[k, np.asarray(g) - first] = 1.0
    for k in range(len(groups) - 1):
        a, b = np.asarray(groups[k]), np.asarray(groups[k + 1])
        h = min(int(blend), a.size // 2, b.size // 2)
        if h <= 0:
            continue
        zone = np.concatenate([a[-h:], b[:h]]) - first
        t = np.arange(1, 2 * h + 1) / (2 * h + 1)
        W[k, zone] = 1.0 - t
        W[k + 1, zone] = t
    out = []
    for k in range(len(groups)):
        idx = np.flatnonzero(W[k] > 0.0)
        out.append((idx + first, W[k, idx]))
    return out


def group_walk(fiber: Fiber, optics: SpectralOptics, group: np.ndarray, white: bool, scored: Any = None):
    """Walk medium, walk phase and spectral targets of one wavelength group (its middle wavelength walks).

    Parameters
    ----------
    fiber : Fiber
        The fiber (index, roughness, dye and scatterer placement).
    optics : SpectralOptics
        Its optics per wavelength (:func:`spectral_optics`).
    group : numpy.ndarray
        The group's wavelength indices.
    white : bool
        Walk without absorption (scored by re-weighting) rather than with the middle wavelength's.
    scored : array_like of int, optional
        The wavelengths the walk scores, if not the group's own (a blended walk also scores its
        neighbours' transition zones: :func:`blended_groups`).

    Returns
    -------
    medium : numpy.ndarray
        The kernel's medium row (:mod:`simulate.montecarlo.kernel`).
    walk_phase : PhaseArrays
        The phase function walked.
    targets : SpectralTargets
        The scored wavelengths' optics.
    """
    ref = int(group[len(group) // 2])
    group = np.asarray(group if scored is None else scored)
    walk_phase = optics.phases[ref]
    medium = np.zeros(K.N_MEDIUM)
    medium[K.M_MU_A] = 0.0 if white else optics.mu_a[ref]
    medium[K.M_MU_S] = optics.mu_s[ref]
    medium[K.M_G] = walk_phase.g
    medium[K.M_N] = fiber.n_host
    medium[K.M_PHASE] = walk_phase.kind
    medium[K.M_ROUGH] = float(getattr(fiber, "transmission_roughness", 0.0))
    around = getattr(fiber, "transmission_roughness_around", None)
    medium[K.M_ROUGH_B] = medium[K.M_ROUGH] if around is None else float(around)
    dye = None
    if optics.mu_a_dye is not None:     # the dye where it sits (kernel docstring, "Dye profile")
        medium[K.M_DYE_PROFILE] = K.DYE_RING if fiber.dye_profile == "ring" else K.DYE_CORE
        medium[K.M_DYE_RADIUS] = fiber.dye_radius_um
        dye = optics.mu_a_dye[group].astype(float)
    if getattr(fiber, "scatterer_profile", "uniform") != "uniform":    # the scatterers where they sit (null collisions)
        medium[K.M_SCAT_PROFILE] = K.SCAT_SKIN if fiber.scatterer_profile == "skin" else K.SCAT_CORE
        medium[K.M_SCAT_RADIUS] = fiber.scatterer_radius_um
    targets = SpectralTargets(
        mu_a=optics.mu_a[group].astype(float),
        mu_s=optics.mu_s[group].astype(float),
        phases=[optics.phases[int(j)] for j in group],
        same_phase=np.array([optics.phases[int(j)] is walk_phase for j in group]),
        mu_a_dye=dye,
    )
    return medium, walk_phase, targets



def run_seed(seed: int, direction: int, group: int) -> int:
    """The seed of the run of incident direction ``direction`` and wavelength group ``group``.

    Parameters
    ----------
    seed : int
        The table's seed.
    direction : int
        Index of the incident direction.
    group : int
        Index of the wavelength group.

    Returns
    -------
    int
        A seed distinct for every direction and group of a table.

    Examples
    --------
    >>> run_seed(3, 2, 1)
    3002028
    """
    return int(seed) * 1_000_003 + int(direction) * 1009 + int(group)


def direction_keys(w_in: np.ndarray) -> dict[tuple[float, ...], list[int]]:
    """Rows of ``w_in`` grouped by direction (rounded to 1e-12), in first-seen order: one run per key.

    Parameters
    ----------
    w_in : numpy.ndarray
        ``[P, 3]`` incident directions.

    Returns
    -------
    dict of tuple to list of int
        The rows of each distinct direction.
    """
    keys: dict[tuple[float, ...], list[int]] = {}
    for p in range(w_in.shape[0]):
        keys.setdefault(tuple(np.round(w_in[p], 12)), []).append(p)
    return keys


def phase_chi2(walk: PhaseArrays, target: PhaseArrays, cells: int = 512) -> float:
    """Chi-square divergence ``int p^2 / p0 dmu - 1`` of the target phase function from the walk's.

    Binned on ``cells`` cells of equal probability under the walk's function (a lower bound that
    converges with ``cells``): ``chi2 = K sum_i q_i^2 - 1`` with ``q_i`` the target's probability
    of cell ``i``.

    Parameters
    ----------
    walk : PhaseArrays
        The walk's phase function as kernel arrays (an inverse-CDF table, or Henyey-Greenstein).
    target : PhaseArrays
        The target's, the same way.
    cells : int
        Cells of equal probability under the walk's function.

    Returns
    -------
    float
        The divergence, ``>= 0``.
    """
    from simulate.optics.phase import hg_inverse_cdf

    def inverse_cdf(pa: PhaseArrays, u: np.ndarray) -> np.ndarray:
        if pa.table.size > 2:
            return np.interp(u, np.linspace(0.0, 1.0, pa.table.size), pa.table)
        return np.asarray(hg_inverse_cdf(u, pa.g), float)

    u = np.linspace(0.0, 1.0, cells + 1)
    edges = np.clip(inverse_cdf(walk, u), -1.0, 1.0)
    fine = np.linspace(0.0, 1.0, 8 * cells + 1)
    t_mu = np.clip(inverse_cdf(target, fine), -1.0, 1.0)
    # the target's CDF at the walk's cell edges (its inverse CDF is monotone: interpolate back)
    t_mu, idx = np.unique(t_mu, return_index=True)
    cdf = np.interp(edges, t_mu, fine[idx])
    q = np.diff(cdf)
    return max(float(cells * np.sum(q * q) - 1.0), 0.0)


def reweight_exponent(walk: SpectralOptics, target: SpectralOptics, groups: list[np.ndarray],
                      scatterings: np.ndarray) -> float:
    r"""The largest ``ln E[w^2]`` over the wavelength groups of the likelihood ratio ``w`` of a re-weighted walk.

    The walk runs in ``walk``'s optics and is scored for ``target``'s.

    Derivation. A path of ``n`` scatterings and length ``L`` (white: absorption is a separate
    ``exp(-mu_a L)`` factor) walked with ``mu_s0, p0`` and scored for ``mu_s = r mu_s0, p`` has
    ``w = r^n exp(-(r - 1) mu_s0 L) prod_i p(mu_i) / p0(mu_i)``. Given ``L``, ``n`` is Poisson with
    mean ``mu_s0 L`` (the free flights), so ``E[r^{2n}] = exp(mu_s0 L (r^2 - 1))`` and the first two
    factors give ``E[w^2 | L] = exp(mu_s0 L (r - 1)^2)``; each scattering multiplies by
    ``E_p0[(p/p0)^2] = 1 + chi^2`` (:func:`phase_chi2`), independently. With ``N`` the mean number
    of scatterings of a walked photon (the kernel counts them)::

        ln E[w^2] ~= N [(r - 1)^2 + ln(1 + chi^2)]

    and ``E[w] = 1`` (unbiased), so the variance of a re-weighted score is ``E[w^2]`` times that of
    the walk's (for scores uncorrelated with ``w``; Jensen makes ``N`` a lower estimate when the
    path lengths vary). Re-weighting is accepted while this is at most :data:`REWEIGHT_LIMIT`
    (``ln 2``); for red cotton (``N`` ~ 10-30 in the fiber) that allows ``|r - 1|`` ~ 0.15-0.25, the
    range of :data:`GROUP_LOG_MU_S`. Same reasoning: Hammersley & Handscomb (1964), *Monte Carlo
    Methods*, ch. 5 (importance sampling); Sassaroli et al. (2012), perturbation Monte Carlo,
    JOSA A 29, 2110 (the ``r^n exp(-(r-1) mu_s L)`` weight).

    Parameters
    ----------
    walk : SpectralOptics
        The optics the photons are walked in.
    target : SpectralOptics
        The optics they are scored for.
    groups : list of numpy.ndarray
        The wavelength indices of each walk (its reference wavelength the middle one).
    scatterings : numpy.ndarray
        ``scatterings[gi]``: the mean scatterings per photon of group ``gi``'s walk (worst direction).

    Returns
    -------
    float
        ``max ln E[w^2]``, compared with :data:`REWEIGHT_LIMIT`.
    """
    worst = 0.0
    for gi, group in enumerate(groups):
        ref = int(group[len(group) // 2])
        walk_phase = walk.phases[ref]
        mu_s0 = walk.mu_s[ref]
        for j in group:
            j = int(j)
            r = target.mu_s[j] / mu_s0 if mu_s0 > 0 else (1.0 if target.mu_s[j] == 0 else math.inf)
            chi2 = 0.0 if target.phases[j] is walk_phase else phase_chi2(walk_phase, target.phases[j])
            worst = max(worst, float(scatterings[gi]) * ((r - 1.0) ** 2 + math.log1p(chi2)))
    return worst
