"""The results of a slab or cylinder run and the reductions of the kernel's sums into them.

:class:`SlabResult` and :class:`CylinderResult` (with their optional direction bins,
:class:`SlabAngular` and :class:`CylinderAngular`) carry values, standard errors, timing and the
:class:`EnergyBalance`; :func:`stderr`, :func:`bins_stderr` and :func:`energy_balance` turn the
per-photon sums that :func:`simulate.montecarlo.transport.execute` returns into them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from simulate.montecarlo import tallies as T

__all__ = ["EnergyBalance", "SlabAngular", "SlabResult", "CylinderAngular", "CylinderResult", "stderr",
           "bins_stderr", "energy_balance"]


@dataclass(frozen=True)
class EnergyBalance:
    """Energy bookkeeping of a run, as fractions of the launched photons (weight 1 each).

    ``entered + roulette_gain = exited + absorbed + roulette_killed + capped_weight`` holds
    exactly (``residual`` is its rounding error); ``roulette_gain - roulette_killed`` is zero
    in expectation. ``specular + entered = 1``.
    """

    launched: int
    specular: float
    entered: float
    exited: float
    exited_by_face: tuple[float, ...]
    absorbed: float
    roulette_gain: float
    roulette_killed: float
    capped_weight: float
    u_roulette_balance: float = math.nan

    @property
    def roulette_balance(self) -> float:
        """Net weight added by Russian roulette (``gain - killed``, zero in expectation)."""
        return self.roulette_gain - self.roulette_killed

    @property
    def residual(self) -> float:
        """``entered + gain - exited - absorbed - killed - capped`` (rounding only)."""
        return (
            self.entered + self.roulette_gain - self.exited - self.absorbed
            - self.roulette_killed - self.capped_weight
        )

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready dictionary."""
        return {
            "launched": self.launched,
            "specular": self.specular,
            "entered": self.entered,
            "exited": self.exited,
            "exited_by_face": list(self.exited_by_face),
            "absorbed": self.absorbed,
            "roulette_gain": self.roulette_gain,
            "roulette_killed": self.roulette_killed,
            "roulette_balance": self.roulette_balance,
            "u_roulette_balance": self.u_roulette_balance,
            "capped_weight": self.capped_weight,
            "residual": self.residual,
        }


@dataclass(frozen=True)
class SlabAngular:
    """Exit weight of a slab run per direction bin (fractions of the launched photons).

    ``reflected[i, j]`` / ``transmitted[i, j]``: weight leaving the top / bottom face with
    ``mu = cos(theta_out)`` in ``[mu_edges[i], mu_edges[i+1])`` (relative to that face's
    outward normal) and azimuth ``atan2(w_y, w_x)`` in ``[phi_edges[j], phi_edges[j+1])``;
    ``u_*`` their standard errors. Each bin spans the solid angle
    ``d_omega = (mu_edges[i+1] - mu_edges[i]) * (phi_edges[j+1] - phi_edges[j])``.
    """

    mu_edges: np.ndarray
    phi_edges: np.ndarray
    reflected: np.ndarray
    u_reflected: np.ndarray
    transmitted: np.ndarray
    u_transmitted: np.ndarray


@dataclass(frozen=True)
class SlabResult:
    """Result of :func:`run_slab` (all fractions of the launched photons)."""

    Rd: float
    Tt: float
    u_Rd: float
    u_Tt: float
    Tu: float
    Rsp: float
    absorbed: float
    photons: int
    seconds: float
    events_per_photon: float
    scatterings_per_photon: float
    capped: int
    energy: EnergyBalance
    theta_i_deg: float
    seed: int
    angular: SlabAngular | None = field(default=None, repr=False)

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready dictionary (the ``simulate slab --json`` object)."""
        return {
            "Rd": self.Rd,
            "Tt": self.Tt,
            "u_Rd": self.u_Rd,
            "u_Tt": self.u_Tt,
            "Tu": self.Tu,
            "Rsp": self.Rsp,
            "absorbed": self.absorbed,
            "photons": self.photons,
            "seconds": self.seconds,
            "events_per_photon": self.events_per_photon,
            "scatterings_per_photon": self.scatterings_per_photon,
            "capped": self.capped,
            "theta_i_deg": self.theta_i_deg,
            "seed": self.seed,
            "energy": self.energy.as_dict(),
        }


@dataclass(frozen=True)
class CylinderAngular:
    """Exit weight of a cylinder run per (psi, local direction) bin, fractions of launched photons.

    ``exits[k, i, j]``: weight leaving through the surface cell ``k`` (azimuth ``psi`` within
    half a cell width ``2 pi / n_psi`` of ``psi_centers[k] = 2 pi k / n_psi``; cell 0 is the
    top) with ``mu = w . n(psi)`` in ``[mu_edges[i], mu_edges[i+1])`` and local azimuth
    ``phi = atan2(w . b, w . t)`` in ``[phi_edges[j], phi_edges[j+1])`` (frame
    ``(n(psi), t = x, b = n x t)``, see :mod:`.geometry`); ``u_exits`` its standard error.
    """

    psi_centers: np.ndarray
    mu_edges: np.ndarray
    phi_edges: np.ndarray
    exits: np.ndarray
    u_exits: np.ndarray


@dataclass(frozen=True)
class CylinderResult:
    """Result of :func:`run_cylinder` (fractions of the launched photons).

    In ``"beam"`` mode the launched photons are the power of a parallel beam intercepted by
    the projected width of the cylinder; in ``"point"`` mode the power arriving at the cell
    A (``psi = 0``). ``exited`` excludes the specular surface reflection ``specular``.
    """

    exited: float
    u_exited: float
    unscattered: float
    specular: float
    absorbed: float
    photons: int
    seconds: float
    events_per_photon: float
    scatterings_per_photon: float
    capped: int
    energy: EnergyBalance
    direction: tuple[float, float, float]
    source: str
    seed: int
    angular: CylinderAngular | None = field(default=None, repr=False)

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready dictionary of the scalar results."""
        return {
            "exited": self.exited,
            "u_exited": self.u_exited,
            "unscattered": self.unscattered,
            "specular": self.specular,
            "absorbed": self.absorbed,
            "photons": self.photons,
            "seconds": self.seconds,
            "events_per_photon": self.events_per_photon,
            "scatterings_per_photon": self.scatterings_per_photon,
            "capped": self.capped,
            "direction": list(self.direction),
            "source": self.source,
            "seed": self.seed,
            "energy": self.energy.as_dict(),
        }


def stderr(total: float, total_sq: float, n: int) -> float:
    """Standard error of the mean of ``n`` per-photon scores from their sum and sum of squares (nan below 2)."""
    if n < 2:
        return math.nan
    mean = total / n
    return math.sqrt(max(total_sq / n - mean * mean, 0.0) / (n - 1))


def bins_stderr(sums: np.ndarray, sums_sq: np.ndarray, n: int) -> np.ndarray:
    """Per-bin :func:`stderr` of arrays of sums and sums of squares."""
    if n < 2:
        return np.full_like(sums, np.nan)
    mean = sums / n
    return np.sqrt(np.maximum(sums_sq / n - mean * mean, 0.0) / (n - 1))


def energy_balance(scal: np.ndarray, faces: int) -> EnergyBalance:
    """The :class:`EnergyBalance` of a run's scalar sums (``faces``: 2 for a slab, 1 for a cylinder)."""
    n = scal[T.S_LAUNCHED]
    by_face = (scal[T.S_EXIT0] / n, scal[T.S_EXIT1] / n)[:faces]
    return EnergyBalance(
        launched=int(n),
        specular=scal[T.S_SPECULAR] / n,
        entered=scal[T.S_ENTERED] / n,
        exited=(scal[T.S_EXIT0] + scal[T.S_EXIT1]) / n,
        exited_by_face=tuple(float(v) for v in by_face),
        absorbed=scal[T.S_ABSORBED] / n,
        roulette_gain=scal[T.S_ROULETTE_GAIN] / n,
        roulette_killed=scal[T.S_ROULETTE_KILLED] / n,
        capped_weight=scal[T.S_CAPPED_WEIGHT] / n,
        u_roulette_balance=stderr(scal[T.S_ROULETTE_GAIN] - scal[T.S_ROULETTE_KILLED], scal[T.S_ROULETTE_NET_SQ], int(n)),
    )
