"""Phase function of the kernel: one compiled sampler and one compiled evaluator.

A phase function is handed to the kernel as a :class:`PhaseArrays` triple (see
:func:`phase_arrays`): ``kind`` with ``g`` for Henyey-Greenstein, or the inverse-CDF
``table`` of a :class:`simulate.optics.phase.PhaseTable` with its density ``pdf`` and an index
``lookup`` that finds a cosine's interval in O(1). The sampler and the evaluator describe
the SAME distribution, so an estimator that weights by ``p(mu)`` (next-event estimation,
likelihood ratios between wavelengths) is exact with respect to what the walk samples:

Henyey-Greenstein (``kind = PHASE_HG``)::

    p(mu) = (1 - g^2) / (4 pi (1 + g^2 - 2 g mu)^(3/2))
    mu(xi) = (1 + g^2 - ((1 - g^2) / (1 - g + 2 g xi))^2) / (2 g)      (g != 0; 2 xi - 1 if g = 0)

Table (``kind = PHASE_TABLE``): ``cos_table`` holds ``K + 1`` nodes ``mu_k = F^-1(k/K)``;
sampling picks interval ``j = floor(xi K)`` and is uniform in ``mu`` inside it, so the
density it samples is piecewise constant::

    p(mu) = 1 / (2 pi K (mu_{k+1} - mu_k))      for mu_k <= mu < mu_{k+1}

``pdf[k]`` stores that value (0 for an empty interval). ``lookup[j]`` (``M + 1`` entries,
``M = 4 K``) is the interval containing ``-1 + 2 j / M``; the evaluator starts there and steps
forward (at most a few steps: the lookup grid is finer than the table on average).

The new direction (``mu`` = cosine to the old direction, azimuth uniform) uses the direction
update of MCML (Wang, Jacques & Zheng 1995, eq. 3.23). One 64-bit draw gives both angles: its
top 40 bits the uniform of ``mu`` (grid 2^-40), its low 24 bits the azimuth
``phi = 2 pi k / 2^24`` (grid 3.7e-7 rad), whose cosine and sine come from a 256-node table and
the angle-addition formulas with short Taylor polynomials (:func:`azimuth`, within 2e-15; no
trigonometric call, no branch): one draw, where a point drawn uniformly in the unit disc by
rejection takes more, a division and an unpredictable branch (docs/notes/implementation.md).

References
----------
Henyey, L. G. & Greenstein, J. L. (1941). Diffuse radiation in the Galaxy. *Astrophys. J.* 93, 70-83.
Wang, L., Jacques, S. L. & Zheng, L. (1995). MCML. *Comput. Methods Programs Biomed.* 47, 131-146.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numba
import numpy as np

from simulate.montecarlo.rng import next_u64, seed_state

__all__ = [
    "PHASE_HG",
    "PHASE_TABLE",
    "PhaseArrays",
    "phase_arrays",
    "hg_constants",
    "sample_cosine",
    "sample_direction",
    "phase_pdf",
    "sample_directions",
    "evaluate_pdf",
]

PHASE_HG = 0
PHASE_TABLE = 1

_INV_4PI = 1.0 / (4.0 * math.pi)
_INV_2PI = 1.0 / (2.0 * math.pi)


class PhaseArrays(NamedTuple):
    """A phase function as the kernel reads it (one wavelength)."""

    kind: int
    g: float
    table: np.ndarray  # float64[K + 1] inverse CDF (unused, length 2, for HG)
    pdf: np.ndarray  # float64[K] density per interval, 1/sr
    lookup: np.ndarray  # int64[M + 1] interval index of the grid -1 + 2 j / M


def phase_arrays(g: float | None = None, cos_table: np.ndarray | None = None) -> PhaseArrays:
    """Kernel arrays of a Henyey-Greenstein phase function (``g``) or of an inverse-CDF table.

    Parameters
    ----------
    g : float, optional
        HG asymmetry in (-1, 1).
    cos_table : numpy.ndarray, optional
        Inverse-CDF nodes (``PhaseTable.cos_table``): non-decreasing from -1 to 1.

    Returns
    -------
    PhaseArrays

    Examples
    --------
    >>> pa = phase_arrays(cos_table=np.array([-1.0, 0.0, 1.0]))
    >>> [round(float(phase_pdf(mu, pa.kind, pa.g, pa.table, pa.pdf, pa.lookup)) * 4 * math.pi, 12)
    ...  for mu in (-0.5, 0.5)]
    [1.0, 1.0]
    """
    if cos_table is None:
        return PhaseArrays(PHASE_HG, float(g or 0.0), np.zeros(2), np.zeros(1), np.zeros(2, dtype=np.int64))
    table = np.array(cos_table, dtype=np.float64, order="C", copy=True)
    K = table.size - 1
    width = np.diff(table)
    with np.errstate(divide="ignore"):
        pdf = np.where(width > 0, 1.0 / (2.0 * math.pi * K * np.where(width > 0, width, 1.0)), 0.0)
    M = 4 * K
    grid = -1.0 + 2.0 * np.arange(M + 1) / M
    lookup = np.clip(np.searchsorted(table, grid, side="right") - 1, 0, K - 1).astype(np.int64)
    return PhaseArrays(PHASE_TABLE, 0.0, table, pdf, lookup)


@numba.njit(cache=True, inline="always")
def hg_constants(g: float) -> tuple[float, float, float, float, float]:
    """``(1 + g^2, 1 - g^2, 1 - g, 2 g, 1 / (2 g))``: the HG inverse CDF's constants, computed once per run."""
    return 1.0 + g * g, 1.0 - g * g, 1.0 - g, 2.0 * g, (0.5 / g if g != 0.0 else 0.0)


@numba.njit(cache=True, inline="always")
def sample_cosine(kind: int, g: float, table: np.ndarray, xi: float,
                  hg: tuple[float, float, float, float, float]) -> float:
    """Scattering cosine for a uniform ``xi`` in [0, 1) (HG inverse CDF or table rule).

    ``hg`` is :func:`hg_constants` of ``g`` (hoisted out of the photon loop by the caller).
    """
    if kind == PHASE_TABLE:
        n = table.shape[0] - 1
        t = xi * n
        j = min(int(t), n - 1)
        f = t - j
        return table[j] + f * (table[j + 1] - table[j])
    if g != 0.0:
        tmp = hg[1] / (hg[2] + hg[3] * xi)
        return max(-1.0, min(1.0, (hg[0] - tmp * tmp) * hg[4]))
    return 2.0 * xi - 1.0


# One 64-bit draw split in two: the top 40 bits for the scattering cosine, the low 24 for the azimuth
# (shared with the slab loop in simulate.montecarlo.slab_lanes).
U40_SHIFT = np.uint64(24)
INV40 = 1.0 / 1099511627776.0  # 2^-40
LOW24 = np.uint64(0xFFFFFF)
_LOW16 = np.uint64(0xFFFF)
_U16 = np.uint64(16)
_N_AZ = 256
_AZ_STEP = 2.0 * math.pi / _N_AZ
_AZ_FRAC = _AZ_STEP / 65536.0
_AZ_COS = np.cos(_AZ_STEP * np.arange(_N_AZ))
_AZ_SIN = np.sin(_AZ_STEP * np.arange(_N_AZ))


@numba.njit(cache=True, inline="always")
def azimuth(r24: np.uint64) -> tuple[float, float]:
    """``(cos phi, sin phi)`` of the azimuth ``phi = 2 pi r24 / 2^24`` (``r24 < 2^24``), branch-free.

    The top 8 bits of ``r24`` pick a node ``phi_i = 2 pi i / 256`` of a table, the low 16 bits the
    offset ``d < 2 pi / 256`` from it; the angle-addition formulas with Taylor polynomials of
    ``cos d`` and ``sin d`` (truncation below 1.2e-15) give the pair.
    """
    i = int(r24 >> _U16)
    d = float(r24 & _LOW16) * _AZ_FRAC
    d2 = d * d
    sd = d * (1.0 - d2 * (1.0 / 6.0) * (1.0 - d2 * (1.0 / 20.0)))
    cd = 1.0 - d2 * 0.5 * (1.0 - d2 * (1.0 / 12.0) * (1.0 - d2 * (1.0 / 30.0)))
    c0 = _AZ_COS[i]
    s0 = _AZ_SIN[i]
    return c0 * cd - s0 * sd, s0 * cd + c0 * sd


@numba.njit(cache=True, inline="always")
def sample_direction(
    ux: float, uy: float, uz: float, kind: int, g: float, table: np.ndarray,
    hg: tuple[float, float, float, float, float],
    s0: np.uint64, s1: np.uint64, s2: np.uint64, s3: np.uint64,
) -> tuple[float, float, float, float, np.uint64, np.uint64, np.uint64, np.uint64]:
    """New direction after a scattering event: ``(ux, uy, uz, mu, s0, s1, s2, s3)``.

    ``mu`` is the cosine between the old and the new direction, drawn from the phase
    function; the azimuth is uniform. Both from one 64-bit draw (module docstring).
    ``hg = hg_constants(g)``.
    """
    r, s0, s1, s2, s3 = next_u64(s0, s1, s2, s3)
    ct = sample_cosine(kind, g, table, float(r >> U40_SHIFT) * INV40, hg)
    st = math.sqrt(max(1.0 - ct * ct, 0.0))
    cp, sp = azimuth(r & LOW24)
    scp = st * cp  # sin(theta) cos(phi)
    ssp = st * sp  # sin(theta) sin(phi)
    if abs(uz) > 0.99999:
        nx = scp
        ny = ssp
        nz = ct if uz > 0.0 else -ct
    else:
        tmp = math.sqrt(1.0 - uz * uz)
        inv_tmp = 1.0 / tmp
        nx = (ux * uz * scp - uy * ssp) * inv_tmp + ux * ct
        ny = (uy * uz * scp + ux * ssp) * inv_tmp + uy * ct
        nz = -scp * tmp + uz * ct
    return nx, ny, nz, ct, s0, s1, s2, s3


@numba.njit(cache=True, inline="always")
def phase_pdf(mu: float, kind: int, g: float, table: np.ndarray, pdf: np.ndarray, lookup: np.ndarray) -> float:
    """Phase function ``p(mu)`` in 1/sr, exactly the density :func:`sample_cosine` samples."""
    if kind == PHASE_TABLE:
        m = lookup.shape[0] - 1
        n = table.shape[0] - 1
        j = int((mu + 1.0) * 0.5 * m)
        if j < 0:
            j = 0
        elif j > m:
            j = m
        k = lookup[j]
        while k < n - 1 and table[k + 1] <= mu:
            k += 1
        return pdf[k]
    if g == 0.0:
        return _INV_4PI
    d = 1.0 + g * g - 2.0 * g * mu
    return (1.0 - g * g) * _INV_4PI / (d * math.sqrt(d))


@numba.njit(cache=True)
def sample_directions(
    u: np.ndarray, count: int, seed: int, kind: int, g: float, table: np.ndarray
) -> np.ndarray:
    """``count`` directions scattered from the unit vector ``u`` by :func:`sample_direction` (tests)."""
    s0, s1, s2, s3 = seed_state(seed, 0)
    hg = hg_constants(g)
    out = np.empty((count, 3))
    for n in range(count):
        x, y, z, _, s0, s1, s2, s3 = sample_direction(u[0], u[1], u[2], kind, g, table, hg, s0, s1, s2, s3)
        out[n, 0] = x
        out[n, 1] = y
        out[n, 2] = z
    return out


@numba.njit(cache=True)
def evaluate_pdf(mu: np.ndarray, kind: int, g: float, table: np.ndarray, pdf: np.ndarray,
                 lookup: np.ndarray) -> np.ndarray:
    """:func:`phase_pdf` over an array of cosines (tests, Python callers)."""
    out = np.empty(mu.shape[0])
    for i in range(mu.shape[0]):
        out[i] = phase_pdf(mu[i], kind, g, table, pdf, lookup)
    return out
