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
from simulate.montecarlo import kernel as K
from simulate.montecarlo.scatter import PhaseArrays, phase_arrays
from simulate.montecarlo.transport import SpectralTargets

__all__ = ["GROUP_LOG_MU_S", "GROUP_G", "SpectralOptics", "spectral_optics", "wavelength_groups", "group_walk",
           "run_seed", "direction_keys"]

GROUP_LOG_MU_S = 0.25
GROUP_G = 0.03


@dataclass(frozen=True)
class SpectralOptics:
    """The medium's ``mu_s``, ``mu_a``, ``g`` and phase arrays per wavelength (phase arrays shared when equal)."""

    mu_s: np.ndarray
    mu_a: np.ndarray
    g: np.ndarray
    phases: list[PhaseArrays]



def spectral_optics(fiber: Fiber, wavelengths_nm: np.ndarray) -> SpectralOptics:
    """The medium's optical properties at each wavelength."""
    mu_s, mu_a, g, phases = [], [], [], []
    cache: dict[Any, PhaseArrays] = {}
    for wl in wavelengths_nm:
        op = fiber.medium.optical_properties(float(wl))
        mu_s.append(op.mu_s)
        mu_a.append(op.mu_a)
        g.append(op.g)
        key = op.phase.cos_table.tobytes()
        if key not in cache:
            cache[key] = phase_arrays(cos_table=op.phase.cos_table)
        phases.append(cache[key])
    return SpectralOptics(np.array(mu_s), np.array(mu_a), np.array(g), phases)


def wavelength_groups(optics: SpectralOptics) -> list[np.ndarray]:
    """Consecutive wavelengths whose scattering is close enough to share one walk."""
    n = optics.mu_s.size
    groups: list[list[int]] = []
    current: list[int] = []
    for i in range(n):
        trial = current + [i]
        ref = trial[len(trial) // 2]
        ok = all(
            (optics.mu_s[j] == optics.mu_s[ref] or (optics.mu_s[j] > 0 and optics.mu_s[ref] > 0
             and abs(math.log(optics.mu_s[j] / optics.mu_s[ref])) <= GROUP_LOG_MU_S))
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
    return [np.array(gr) for gr in groups]


def group_walk(fiber: Fiber, optics: SpectralOptics, group: np.ndarray, white: bool):
    """Walk medium, walk phase and spectral targets of one wavelength group (its middle wavelength walks)."""
    ref = int(group[len(group) // 2])
    walk_phase = optics.phases[ref]
    medium = np.zeros(K.N_MEDIUM)
    medium[K.M_MU_A] = 0.0 if white else optics.mu_a[ref]
    medium[K.M_MU_S] = optics.mu_s[ref]
    medium[K.M_G] = walk_phase.g
    medium[K.M_N] = fiber.n_host
    medium[K.M_PHASE] = walk_phase.kind
    targets = SpectralTargets(
        mu_a=optics.mu_a[group].astype(float),
        mu_s=optics.mu_s[group].astype(float),
        phases=[optics.phases[int(j)] for j in group],
        same_phase=np.array([optics.phases[int(j)] is walk_phase for j in group]),
    )
    return medium, walk_phase, targets



def run_seed(seed: int, direction: int, group: int) -> int:
    """The seed of the run of incident direction ``direction`` and wavelength group ``group``.

    >>> run_seed(3, 2, 1)
    3002028
    """
    return int(seed) * 1_000_003 + int(direction) * 1009 + int(group)


def direction_keys(w_in: np.ndarray) -> dict[tuple[float, ...], list[int]]:
    """Rows of ``w_in`` grouped by direction (rounded to 1e-12), in first-seen order: one run per key."""
    keys: dict[tuple[float, ...], list[int]] = {}
    for p in range(w_in.shape[0]):
        keys.setdefault(tuple(np.round(w_in[p], 12)), []).append(p)
    return keys
