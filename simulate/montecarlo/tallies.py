"""Tallies of the Monte Carlo kernel: scalar bookkeeping and exit-binned estimators.

Every batch writes into two preallocated arrays owned by that batch:

``scal`` (``float64[N_SCALARS]``)
    Energy bookkeeping and totals; the slot indices are the ``S_*`` constants below. Each
    photon exits at most once, so its score into a face is its weight ``w`` or 0 and the
    per-photon second moment is ``sum w^2``: the standard error of a mean score ``R`` over
    ``N`` photons is ``sqrt((sum w^2 / N - R^2) / (N - 1))``.
    The bookkeeping identity, exact per photon (PHYSICS.md section 3)::

        entered + roulette_gain = exited + absorbed + roulette_killed + capped_weight

    with ``entered = sum (1 - F(theta_i))``, ``roulette_gain = sum w (1/p - 1)`` over
    survivors and ``roulette_killed = sum w`` over the killed; ``gain - killed`` is zero in
    expectation (unbiased roulette).

``bins`` (``float64[n_bins, 2]``)
    Column 0: ``sum w`` of the photons exiting into a bin; column 1: ``sum w^2``. The binning
    is chosen by the tally mode and its parameters ``tally_params``:

    ``NONE`` -- no bins (``n_bins = 1``, unused).
    ``SLAB_DIRECTIONS`` -- ``params = [n_mu, n_phi]``: face (0 top / reflected, 1 bottom /
    transmitted) x ``mu = cos(theta_out)`` relative to the face's outward normal, ``n_mu``
    uniform bins on (0, 1] (equal solid angle ``2 pi / n_mu / n_phi`` each) x azimuth
    ``phi_out = atan2(w_y, w_x)`` in ``n_phi`` uniform bins on [-pi, pi).
    ``CYLINDER_DIRECTIONS`` -- ``params = [n_psi, n_mu, n_phi]``: exit azimuth ``psi`` around
    the axis (``n_psi`` uniform bins on [-pi, pi)) x ``mu = w . n(psi)`` (``n_mu`` bins on
    (0, 1]) x local azimuth ``phi = atan2(w . b, w . t)`` about ``n(psi)`` from the axis
    ``t`` (``n_phi`` bins on [-pi, pi)); local frame as in :mod:`.geometry`.

Extending: a new estimator is a new mode constant, its branch in :func:`score_exit` and its
``n_bins`` in :func:`bin_count`. A next-event estimator (a contribution towards each fixed
internal direction at every scattering vertex, weighted by the phase function, the
attenuation to the boundary, the Fresnel transmission and ``n^2``) adds a vertex scorer
called at the marked scattering site of :func:`simulate.montecarlo.kernel.simulate_batch`,
where position, incoming direction, weight and path length are at hand. The exit scorer
receives the path length ``path_length`` travelled inside the medium, so "white" Monte
Carlo can apply ``exp(-mu_a L)`` afterwards.
"""

from __future__ import annotations

import math

import numba
import numpy as np

__all__ = [
    "NONE",
    "SLAB_DIRECTIONS",
    "CYLINDER_DIRECTIONS",
    "N_SCALARS",
    "SCALAR_NAMES",
    "bin_count",
    "score_exit",
]

NONE = 0
SLAB_DIRECTIONS = 1
CYLINDER_DIRECTIONS = 2

# scalar slots
S_LAUNCHED = 0  # photons launched (weight 1 each)
S_SPECULAR = 1  # sum F(theta_i) at entry (surface term, not part of the volume result)
S_ENTERED = 2  # sum (1 - F(theta_i))
S_EXIT0 = 3  # weight exiting through face 0 (slab top = Rd; cylinder: all exits)
S_EXIT0_SQ = 4
S_EXIT1 = 5  # weight exiting through face 1 (slab bottom = Tt)
S_EXIT1_SQ = 6
S_UNSCATTERED0 = 7  # part of S_EXIT0 that never scattered
S_UNSCATTERED1 = 8  # part of S_EXIT1 that never scattered (slab: collimated transmittance)
S_ABSORBED = 9
S_ROULETTE_GAIN = 10
S_ROULETTE_KILLED = 11
S_CAPPED = 12  # photons stopped by the event cap
S_CAPPED_WEIGHT = 13
S_EVENTS = 14  # free-path steps (each ends in an interaction or at the boundary)
S_SCATTERINGS = 15
S_INTERNAL_REFLECTIONS = 16
S_PATH_LENGTH = 17  # sum of w_exit * L over exits (mean path length of exiting light)
N_SCALARS = 18

SCALAR_NAMES = (
    "launched",
    "specular",
    "entered",
    "exit0",
    "exit0_sq",
    "exit1",
    "exit1_sq",
    "unscattered0",
    "unscattered1",
    "absorbed",
    "roulette_gain",
    "roulette_killed",
    "capped",
    "capped_weight",
    "events",
    "scatterings",
    "internal_reflections",
    "path_length",
)

_TWO_PI = 2.0 * math.pi


def bin_count(mode: int, params: np.ndarray) -> int:
    """Number of bins a tally mode needs (rows of the ``bins`` array).

    Parameters
    ----------
    mode : int
        Tally mode constant.
    params : numpy.ndarray
        The mode's parameters.

    Returns
    -------
    int
        ``n_bins >= 1``.
    """
    if mode == NONE:
        return 1
    if mode == SLAB_DIRECTIONS:
        return 2 * int(params[0]) * int(params[1])
    if mode == CYLINDER_DIRECTIONS:
        return int(params[0]) * int(params[1]) * int(params[2])
    raise ValueError(f"unknown tally mode {mode}")


@numba.njit(cache=True, inline="always")
def _uniform_bin(value: float, lo: float, hi: float, count: int) -> int:
    k = int((value - lo) / (hi - lo) * count)
    if k < 0:
        return 0
    if k >= count:
        return count - 1
    return k


@numba.njit(cache=True)
def score_exit(
    mode: int,
    params: np.ndarray,
    bins: np.ndarray,
    face: int,
    x: float,
    y: float,
    z: float,
    wx: float,
    wy: float,
    wz: float,
    weight: float,
    path_length: float,
) -> None:
    """Score a photon leaving the medium at ``(x, y, z)`` in direction ``w`` (outside, unit).

    Parameters
    ----------
    mode : int
        Tally mode.
    params : numpy.ndarray
        Mode parameters (see the module docstring).
    bins : numpy.ndarray
        ``float64[n_bins, 2]`` accumulators (``sum w``, ``sum w^2``).
    face : int
        Slab: 0 top, 1 bottom; cylinder: 0.
    x, y, z : float
        Exit point on the surface.
    wx, wy, wz : float
        Exit direction after refraction.
    weight : float
        Photon weight leaving.
    path_length : float
        Geometric path length travelled inside the medium.
    """
    if mode == SLAB_DIRECTIONS:
        n_mu = int(params[0])
        n_phi = int(params[1])
        mu = wz if face == 0 else -wz
        k = (face * n_mu + _uniform_bin(mu, 0.0, 1.0, n_mu)) * n_phi
        k += _uniform_bin(math.atan2(wy, wx), -math.pi, math.pi, n_phi)
        bins[k, 0] += weight
        bins[k, 1] += weight * weight
    elif mode == CYLINDER_DIRECTIONS:
        n_psi = int(params[0])
        n_mu = int(params[1])
        n_phi = int(params[2])
        psi = math.atan2(-y, z)
        r = math.sqrt(y * y + z * z)
        ny = y / r
        nz = z / r
        mu = wy * ny + wz * nz
        # b = n x t = (0, n_z, -n_y): with n = (0, -sin psi, cos psi), b = (0, cos psi, sin psi)
        wb = wy * nz - wz * ny
        phi = math.atan2(wb, wx)
        k = (_uniform_bin(psi, -math.pi, math.pi, n_psi) * n_mu + _uniform_bin(mu, 0.0, 1.0, n_mu)) * n_phi
        k += _uniform_bin(phi, -math.pi, math.pi, n_phi)
        bins[k, 0] += weight
        bins[k, 1] += weight * weight

