"""Accuracy control of the Monte Carlo estimators: the one relative error and the photon rounds.

The relative error (one definition for the whole toolkit: ``simulate fabric`` of every method,
``simulate fiber``, ``sweep``, ``fit`` and the ``auto`` method's choice) is the RMS, over outputs
(detector directions) and wavelengths, of the standard error relative to the PEAK of that
output's spectrum::

    rel_err = sqrt(mean_{o, l} (u[o, l] / max_l |value[o, l]|)^2)      outputs with a peak > 1e-3 max

A 1 % target means 1 % of the brightest wavelength of each curve: what a colour or a normalised
curve is sensitive to; the dark, dye-absorbed wavelengths of a red fabric would otherwise decide
the cost alone. Outputs whose peak is below 1e-3 of the largest are ignored (they carry nothing
a normalised curve shows). :func:`run_controlled` adds photons in rounds, each sized from the
error reached (``u ~ 1/sqrt(N)``, :func:`next_round`), until just past the target or the photon
budget.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from simulate.montecarlo import kernel as K
from simulate.montecarlo import tallies as T
from simulate.montecarlo.transport import ParameterError, execute

__all__ = ["BATCH", "FIRST_ROUND", "REL_ERR_DEFINITION", "Run", "relative_error", "check_target", "default_max_photons", "check_budget",
           "SAFETY", "MIN_GROWTH", "MAX_GROWTH", "next_round", "run_controlled", "mean_and_error"]

BATCH = 2_000
"""Photons per batch of every accuracy-controlled run (batches are the unit of the RNG streams)."""
FIRST_ROUND = 50_000
"""Photons of the first round before the error is first measured."""
REL_ERR_DEFINITION = ("RMS over directions and wavelengths of u / the peak of that direction's spectrum "
                      "(directions whose peak is below 1e-3 of the brightest ignored)")
"""What ``rel_err`` means in every output that reports it (datasets, fiber tables, sweep, fit)."""


def relative_error(value: Any, u: Any) -> float:
    """RMS of ``u`` relative to the peak of each output's spectrum (rows: outputs, columns: wavelengths).

    The one definition of "relative error" (module docstring). ``value`` and ``u`` of shape
    ``[outputs, wavelengths]`` (a 1-D array is one output).

    >>> relative_error([[1.0, 0.5], [2.0, 4.0]], [[0.01, 0.01], [0.04, 0.04]])
    0.01
    """
    v = np.abs(np.atleast_2d(np.asarray(value, dtype=float)))
    uu = np.atleast_2d(np.asarray(u, dtype=float))
    peak = v.max(axis=1) if v.size else np.zeros(0)
    if peak.size == 0 or not np.any(peak > 0):
        return 0.0
    keep = peak > 1e-3 * peak.max()
    return float(np.sqrt(np.mean((uu[keep] / peak[keep, None]) ** 2)))


def check_target(target_rel_err: Any, name: str = "target_rel_err") -> float:
    """``target_rel_err`` as a float in (0, 1), else :class:`ParameterError` (no zero reaches a division)."""
    ok = isinstance(target_rel_err, (int, float, np.floating)) and not isinstance(target_rel_err, bool)
    if not ok or not math.isfinite(float(target_rel_err)) or not 0 < float(target_rel_err) < 1:
        raise ParameterError(f"{name} must be a number in (0, 1), got {target_rel_err!r}")
    return float(target_rel_err)


def default_max_photons(target_rel_err: float) -> int:
    """The photon budget per run when none is given: ``100 / target^2``, at least 10^6."""
    return max(int(100.0 / check_target(target_rel_err) ** 2), 1_000_000)


def check_budget(target_rel_err: Any, max_photons: int | None) -> tuple[float, int]:
    """The checked target and the photon budget (:func:`default_max_photons` when None)."""
    target = check_target(target_rel_err)
    return target, default_max_photons(target) if max_photons is None else max_photons


@dataclass
class Run:
    """Sums of an accuracy-controlled run: scalars, bins, photons used, kernel seconds."""

    scal: np.ndarray
    bins: np.ndarray
    photons: int
    seconds: float


SAFETY = 1.03
"""Photons beyond the extrapolated need in each round (the error estimate is itself noisy)."""
MIN_GROWTH = 0.02
"""The smallest round after the first, as a fraction of the photons done (at least one batch)."""
MAX_GROWTH = 8.0
"""The largest round, as a multiple of the photons done (one noisy early estimate cannot run away)."""


def next_round(history: list[tuple[int, float]], target: float, max_photons: int) -> int:
    """Photons of the next round, from the error decay observed so far, to just past the target.

    ``history``: ``(photons, rel)`` after each round. The decay ``rel ~ N^-a`` is measured
    between the last two rounds (``a`` clipped to [1/2, 1]: 1/2 is the law of large numbers,
    steeper is the early estimate settling; with one round ``a = 1/2``), the need extrapolated
    to ``N_need = N (rel / target)^(1/a)``. A first extrapolation further than twice the photons
    done goes only to the geometric mean of the two (the error measured there gives the
    decay); otherwise to ``SAFETY N_need``. Rounds are at least ``max(BATCH, MIN_GROWTH N)``,
    at most ``MAX_GROWTH N`` and the budget, whole batches. The decay is measured rather than taken
    as ``1/sqrt(N)`` because the early error falls faster than that (docs/notes/implementation.md,
    "The accuracy control").

    >>> next_round([(50_000, 0.0110)], 0.01, 10**7)   # 1.03 * 1.21 * 50 000 = 62 315 -> 12 315 more -> batches
    14000
    >>> next_round([(50_000, 0.0100)], 0.01, 10**7)   # at the target: the floor, one batch
    2000
    >>> next_round([(50_000, 0.0200)], 0.01, 10**7)   # 4x: first to the geometric mean, 100 000
    50000
    >>> next_round([(50_000, 0.0200), (100_000, 0.0125)], 0.01, 10**7)  # measured a = 0.68: 139 000 x 1.03
    44000
    """
    photons, rel = history[-1]
    a = 0.5
    if len(history) >= 2 and 0 < rel < history[-2][1] and photons > history[-2][0]:
        n0, r0 = history[-2]
        a = min(max(math.log(r0 / rel) / math.log(photons / n0), 0.5), 1.0)
    need = photons * (rel / target) ** (1.0 / a)
    if len(history) == 1 and need > 2.0 * photons:
        total = math.sqrt(photons * need)
    else:
        total = need * SAFETY
    want = max(total - photons, MIN_GROWTH * photons, BATCH)
    want = min(want, MAX_GROWTH * photons, max_photons - photons)
    return int(math.ceil(want / BATCH) * BATCH) if want > 0 else 0


def run_controlled(inp: K.KernelInputs, estimate: Callable[[np.ndarray, int], tuple[np.ndarray, np.ndarray]],
                   target_rel_err: float, max_photons: int, seed: int, threads: int | None,
                   min_photons: int = FIRST_ROUND, progress: Any = None) -> Run:
    """Run batches until ``estimate(bins, photons)`` -> (value, u) reaches the target :func:`relative_error`.

    The first round is ``min_photons``; each later one is :func:`next_round` of the error just
    measured, so a run stops a few per cent past the photons the target needs. Batch ``b`` of
    the run always has the stream ``(seed, b)`` whatever the rounds and threads: a fixed seed
    gives the same photons and result on any machine (the rounds only decide where it stops).
    ``target_rel_err`` must be > 0 (a target of 1e-12 with ``max_photons`` = N walks exactly the
    batches of N photons: how a run is repeated with common random numbers).
    """
    if not target_rel_err > 0:
        raise ParameterError(f"target_rel_err must be > 0, got {target_rel_err!r}")
    scal = np.zeros(T.N_SCALARS)
    bins = None
    photons = 0
    seconds = 0.0
    want = min(min_photons, max_photons)
    want = int(math.ceil(want / BATCH) * BATCH)
    history: list[tuple[int, float]] = []
    while want > 0:
        s, b, sec = execute(inp, want, seed, threads, BATCH, first_batch=photons // BATCH)
        scal += s
        bins = b if bins is None else bins + b
        photons += want
        seconds += sec
        value, u = estimate(bins, photons)
        rel = relative_error(value, u)
        if progress is not None:
            progress(photons, rel)
        if rel <= target_rel_err or photons >= max_photons:
            break
        history.append((photons, rel))
        want = next_round(history, target_rel_err, max_photons)
    if bins is None:
        raise ParameterError(f"no photons to run: min_photons {min_photons!r} and max_photons {max_photons!r} "
                             "must both be >= 1")
    return Run(scal, bins, photons, seconds)


def mean_and_error(bins: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Mean per photon and its standard error from ``(sum, sum of squares)`` rows."""
    mean = bins[:, 0] / n
    u = np.sqrt(np.maximum(bins[:, 1] / n - mean * mean, 0.0) / max(n - 1, 1))
    return mean, u
