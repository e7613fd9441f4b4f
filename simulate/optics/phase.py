"""Scattering phase functions and their inverse-CDF tables for Monte Carlo sampling.

The phase function ``p(mu)``, ``mu = cos(theta)`` the cosine of the scattering angle, is
normalised over the sphere (docs/physics.md section 2)::

    int_{4 pi} p dOmega = 2 pi int_{-1}^{1} p(mu) dmu = 1,     g = 2 pi int mu p(mu) dmu

Henyey-Greenstein (Henyey & Greenstein 1941)::

    p_HG(mu; g) = (1 - g^2) / (4 pi (1 + g^2 - 2 g mu)^(3/2))
    mu(u) = (1 + g^2 - ((1 - g^2) / (1 - g + 2 g u))^2) / (2 g)      (inverse CDF, g != 0)

:class:`PhaseTable` is the sampling contract with the Monte Carlo kernel: ``cos_table`` is
a float64 array of length ``K + 1`` holding ``mu_k = F^{-1}(k / K)``, where
``F(mu) = 2 pi int_{-1}^{mu} p dmu``, monotone non-decreasing from -1 to 1. The kernel
draws ``u`` in [0, 1), sets ``j = floor(u K)``, ``f = u K - j`` and returns
``(1 - f) cos_table[j] + f cos_table[j + 1]``: each of the ``K`` intervals carries
probability ``1/K`` and is uniform in ``mu``. The table's own mean cosine is therefore
``sum_k (mu_k + mu_{k+1}) / (2 K)`` (:meth:`PhaseTable.mean_cosine`).

Tables built from a tabulated ``p(mu)`` (e.g. Mie, strongly forward peaked for large
size parameters) integrate ``p`` on the caller's grid, which should be fine where
``p`` varies fast (see :func:`simulate.optics.mie.phase_grid`), taking ``p`` piecewise linear in
``mu`` between grid nodes; the CDF is then piecewise quadratic and is inverted exactly
cell by cell, so the only error left in the table is the piecewise-uniform rule between
its ``K + 1`` nodes (a bias of the mean cosine below ``1/K`` in the worst case, usually far
smaller; the exact figure for a table is ``table.mean_cosine() - g``).

References
----------
Henyey, L. G. & Greenstein, J. L. (1941). Diffuse radiation in the galaxy.
*Astrophysical Journal* 93, 70-83.
Bohren, C. F. & Huffman, D. R. (1983). *Absorption and Scattering of Light by Small Particles*,
sec. 4.5 (phase function, asymmetry parameter). Wiley.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

__all__ = [
    "henyey_greenstein",
    "hg_inverse_cdf",
    "PhaseTable",
    "DEFAULT_TABLE_SIZE",
]

#: Default number of CDF intervals K of a :class:`PhaseTable` (32 KiB of float64).
DEFAULT_TABLE_SIZE = 4096

_TWO_PI = 2.0 * np.pi


def _check_hg_g(g: float) -> float:
    g = float(g)
    if not -1.0 < g < 1.0:
        raise ValueError(
            f"Henyey-Greenstein asymmetry g must satisfy -1 < g < 1, got {g} "
            "(|g| = 1 is a delta function; use g = 0.999 for an extremely forward-peaked case)"
        )
    return g


def henyey_greenstein(mu: npt.ArrayLike, g: float) -> np.ndarray:
    """Henyey-Greenstein phase function ``p_HG(mu; g)`` in 1/sr, normalised over the sphere.

    Parameters
    ----------
    mu : array_like
        Cosine(s) of the scattering angle, in [-1, 1].
    g : float
        Asymmetry parameter (mean cosine), ``-1 < g < 1``.

    Returns
    -------
    numpy.ndarray
        ``(1 - g^2) / (4 pi (1 + g^2 - 2 g mu)^(3/2))``.

    Examples
    --------
    >>> round(float(henyey_greenstein(0.3, 0.0)) * 4 * np.pi, 12)
    1.0
    """
    g = _check_hg_g(g)
    mu = np.asarray(mu, dtype=float)
    return (1.0 - g * g) / (4.0 * np.pi * (1.0 + g * g - 2.0 * g * mu) ** 1.5)


def hg_inverse_cdf(u: npt.ArrayLike, g: float) -> np.ndarray:
    """Inverse CDF of Henyey-Greenstein: ``mu`` such that ``F(mu) = u``.

    Parameters
    ----------
    u : array_like
        Probabilities in [0, 1].
    g : float
        Asymmetry parameter, ``-1 < g < 1``.

    Returns
    -------
    numpy.ndarray
        ``mu(u)`` in [-1, 1], non-decreasing in ``u`` (``2u - 1`` when ``|g| < 1e-9``,
        where the exact formula loses precision and the isotropic limit is exact to 1e-9).
    """
    g = _check_hg_g(g)
    u = np.asarray(u, dtype=float)
    if abs(g) < 1e-9:
        return np.clip(2.0 * u - 1.0, -1.0, 1.0)
    s = (1.0 - g * g) / (1.0 - g + 2.0 * g * u)
    return np.clip((1.0 + g * g - s * s) / (2.0 * g), -1.0, 1.0)


@dataclass(frozen=True)
class PhaseTable:
    """Inverse-CDF table of a phase function (the sampling contract with the MC kernel).

    Attributes
    ----------
    cos_table : numpy.ndarray
        float64, length ``K + 1``: ``cos_table[k] = F^{-1}(k / K)``, non-decreasing,
        ``cos_table[0] = -1``, ``cos_table[K] = 1``.
    g_reference : float
        Mean cosine of the phase function the table was built from (HG ``g``, Mie ``g``),
        NaN when unknown; compare with :meth:`mean_cosine`.
    quadrature_norm : float
        ``2 pi int p dmu`` on the source grid before renormalisation (1 for analytic
        tables); its distance from 1 measures the quadrature error of the source grid.
    """

    cos_table: np.ndarray
    g_reference: float = float("nan")
    quadrature_norm: float = 1.0

    def __post_init__(self) -> None:
        table = np.ascontiguousarray(self.cos_table, dtype=np.float64)
        if table.ndim != 1 or table.size < 2:
            raise ValueError("PhaseTable: cos_table must be 1-D with at least 2 entries")
        if not np.all(np.isfinite(table)):
            raise ValueError("PhaseTable: cos_table contains non-finite values")
        if np.any(np.diff(table) < 0) or table[0] != -1.0 or table[-1] != 1.0:
            raise ValueError("PhaseTable: cos_table must be non-decreasing from -1 to 1")
        table.setflags(write=False)
        object.__setattr__(self, "cos_table", table)

    # ------------------------------------------------------------------ constructors
    @classmethod
    def from_hg(cls, g: float, K: int = DEFAULT_TABLE_SIZE) -> PhaseTable:
        """Table of the Henyey-Greenstein phase function from its exact inverse CDF.

        Parameters
        ----------
        g : float
            Asymmetry parameter, ``-1 < g < 1``.
        K : int
            Number of equiprobable intervals.

        Returns
        -------
        PhaseTable
        """
        K = _check_K(K)
        u = np.arange(K + 1, dtype=float) / K
        table = hg_inverse_cdf(u, g)
        table[0], table[-1] = -1.0, 1.0
        return cls(table, g_reference=float(g))

    @classmethod
    def from_tabulated(
        cls,
        mu: npt.ArrayLike,
        p: npt.ArrayLike,
        K: int = DEFAULT_TABLE_SIZE,
        g_reference: float = float("nan"),
    ) -> PhaseTable:
        """Table from samples of ``p(mu)`` on a grid (taken piecewise linear in ``mu``).

        Parameters
        ----------
        mu : array_like
            Grid of scattering-angle cosines covering [-1, 1] (any order; endpoints
            -1 and 1 must be included). Make it dense where ``p`` varies fast, e.g.
            uniform in ``theta`` and finer still in the forward peak.
        p : array_like
            Phase function values ``>= 0`` at ``mu`` (any normalisation: the table is
            renormalised; the raw ``2 pi int p dmu`` is kept as ``quadrature_norm``).
        K : int
            Number of equiprobable intervals.
        g_reference : float, optional
            Known mean cosine of ``p`` (e.g. Mie ``g``) kept for comparison.

        Returns
        -------
        PhaseTable
        """
        K = _check_K(K)
        mu = np.asarray(mu, dtype=float).ravel()
        p = np.asarray(p, dtype=float).ravel()
        if mu.shape != p.shape:
            raise ValueError("PhaseTable.from_tabulated: mu and p must have the same length")
        if not (np.all(np.isfinite(mu)) and np.all(np.isfinite(p))):
            raise ValueError("PhaseTable.from_tabulated: mu and p must be finite")
        if np.any(p < 0):
            raise ValueError("PhaseTable.from_tabulated: phase function values must be >= 0")
        order = np.argsort(mu, kind="stable")
        mu, p = mu[order], p[order]
        keep = np.concatenate(([True], np.diff(mu) > 0))
        mu, p = mu[keep], p[keep]
        if mu[0] != -1.0 or mu[-1] != 1.0:
            raise ValueError("PhaseTable.from_tabulated: the mu grid must include -1 and 1")
        h = np.diff(mu)
        cell = 0.5 * (p[:-1] + p[1:]) * h
        cdf = np.concatenate(([0.0], np.cumsum(cell)))
        total = cdf[-1]
        if not total > 0:
            raise ValueError("PhaseTable.from_tabulated: phase function integrates to zero")
        u = np.arange(K + 1, dtype=float) / K
        target = u * total
        j = np.clip(np.searchsorted(cdf, target, side="right") - 1, 0, mu.size - 2)
        # exact inverse of the piecewise-quadratic CDF inside cell j:
        # p_a t + s t^2 / 2 = r,  s = (p_b - p_a) / h  ->  t = 2 r / (p_a + sqrt(p_a^2 + 2 s r))
        p_a, p_b, hj = p[j], p[j + 1], h[j]
        r = np.clip(target - cdf[j], 0.0, None)
        s = (p_b - p_a) / hj
        disc = np.sqrt(np.clip(p_a * p_a + 2.0 * s * r, 0.0, None))
        denom = p_a + disc
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.where(denom > 0, 2.0 * r / denom, 0.0)
        table = mu[j] + np.clip(t, 0.0, hj)
        table = np.maximum.accumulate(np.clip(table, -1.0, 1.0))
        table[0], table[-1] = -1.0, 1.0
        return cls(table, g_reference=float(g_reference), quadrature_norm=float(_TWO_PI * total))

    @classmethod
    def from_mie(
        cls,
        m: complex,
        x: float,
        K: int = DEFAULT_TABLE_SIZE,
        n_theta: int | None = None,
    ) -> PhaseTable:
        """Table of the Mie phase function of one sphere (see :func:`simulate.optics.mie.phase_function`).

        Parameters
        ----------
        m : complex
            Relative refractive index ``m_p / n_h`` (``n - ik``; the sign of ``k`` is ignored).
        x : float
            Size parameter ``2 pi n_h r / lambda``.
        K : int
            Number of equiprobable intervals.
        n_theta : int, optional
            Override the number of angular grid nodes (default from :func:`simulate.optics.mie.phase_grid`).

        Returns
        -------
        PhaseTable
        """
        from simulate.optics import mie  # local import: mie pulls in miepython (slow first import)

        mu_grid = mie.phase_grid(x, n_theta=n_theta)
        p = mie.phase_function(m, x, mu_grid)
        g = float(mie.efficiencies(m, x).g)
        return cls.from_tabulated(mu_grid, p, K=K, g_reference=g)

    # ------------------------------------------------------------------ queries
    @property
    def K(self) -> int:
        """Number of equiprobable intervals (``len(cos_table) - 1``)."""
        return int(self.cos_table.size - 1)

    def sample(self, u: npt.ArrayLike) -> np.ndarray:
        """Scattering cosines for uniform deviates ``u`` in [0, 1) by the kernel's rule.

        ``j = floor(u K)``, ``f = u K - j``, ``mu = (1 - f) cos_table[j] + f cos_table[j+1]``
        (``u = 1`` is mapped to the last node).

        Parameters
        ----------
        u : array_like
            Uniform deviates in [0, 1].

        Returns
        -------
        numpy.ndarray
            Cosines in [-1, 1], same shape as ``u``.
        """
        u = np.asarray(u, dtype=float)
        if np.any(~((u >= 0.0) & (u <= 1.0))):
            raise ValueError("PhaseTable.sample: u must lie in [0, 1]")
        K = self.K
        su = u * K
        j = np.minimum(np.floor(su).astype(np.int64), K - 1)
        f = su - j
        c = self.cos_table
        return (1.0 - f) * c[j] + f * c[j + 1]

    def mean_cosine(self) -> float:
        """Mean cosine of the table's implied distribution, ``sum_k (mu_k + mu_{k+1}) / (2K)``."""
        c = self.cos_table
        return float(np.mean(0.5 * (c[:-1] + c[1:])))

    def second_moment(self) -> float:
        """``E[mu^2]`` of the table's distribution (uniform in each interval)."""
        a, b = self.cos_table[:-1], self.cos_table[1:]
        return float(np.mean((a * a + a * b + b * b) / 3.0))


def _check_K(K: int) -> int:
    if int(K) != K or K < 2:
        raise ValueError(f"PhaseTable: K must be an integer >= 2, got {K!r}")
    return int(K)
