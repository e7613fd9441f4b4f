"""Tallies of the Monte Carlo kernel: the estimator contract, bookkeeping and estimators.

The contract (what :func:`simulate.montecarlo.kernel.simulate_batch` guarantees)
---------------------------------------------------------------------------------
* Every history ends in ONE place, after which its per-history scratch tally is flushed:
  for every bin ``k`` the photon touched, ``bins[k, 0] += h_k`` and ``bins[k, 1] += h_k^2``
  with ``h_k`` the photon's TOTAL score in that bin. An estimator may therefore score any
  number of times per photon (next-event estimation scores at every vertex) and the
  standard error ``sqrt((sum h^2 / N - mean^2) / (N - 1))`` stays right, because the
  photons -- not the scores -- are the independent samples.
* Two hooks: :func:`score_exit` when a photon leaves the medium (position, direction after
  refraction, weight, path length, number of scatterings) and :func:`score_vertex` at every
  scattering vertex (position, incoming direction, weight after implicit capture, path
  length so far), before the new direction is drawn.
* Spectral ("white") scoring: a photon walks in ONE medium (the walk medium) and carries a
  weight factor ``A_l`` per wavelength ``l`` that turns its walk into the walk of wavelength
  ``l`` (a likelihood ratio; see :mod:`.kernel`); a score ``s`` into geometric bin ``k`` adds
  ``s A_l`` to bin ``k * n_spec + l``. Runs without spectral re-weighting have
  ``n_spec = 1`` and ``A_0 = 1``.

``scal`` (``float64[N_SCALARS]``)
    Energy bookkeeping and totals of the walk medium; slot indices ``S_*`` below. The exit
    weight of a photon into a face is flushed once per history, so ``S_EXIT*_SQ`` are sums
    of per-photon squares; so is the roulette balance ``S_ROULETTE_NET_SQ`` (per photon:
    gain minus killed), whose mean is zero in expectation. The identity, exact per photon::

        entered + roulette_gain = exited + absorbed + roulette_killed + capped_weight

Exit modes (``tally_mode``, parameters ``tally_params``)
    ``NONE`` -- no bins.
    ``SLAB_DIRECTIONS`` -- ``[n_mu, n_phi]``: face (0 top, 1 bottom) x ``mu = cos theta_out``
    (``n_mu`` uniform bins on (0, 1], relative to the face's outward normal) x azimuth
    ``atan2(w_y, w_x)`` (``n_phi`` bins on [-pi, pi)).
    ``CYLINDER_DIRECTIONS`` -- ``[n_psi, n_mu, n_phi, n_v, v_max]``: surface cell of the
    exit azimuth ``psi = atan2(-y, z)`` (``n_psi`` cells of width ``2 pi / n_psi`` CENTRED on
    ``k 2 pi / n_psi``, cell 0 the top, ``psi = 0``) x axial position ``v = x`` (``n_v`` bins
    on [-v_max, v_max]; the end bins also take everything beyond) x ``mu = w . n(psi)``
    (``n_mu`` bins on (0, 1]) x local azimuth ``phi = atan2(w . b, w . t)`` (``n_phi`` bins
    on [-pi, pi)); local frame ``(n, t, b = n x t)`` of the exit point, see :mod:`.geometry`.
    ``CYLINDER_OUTPUTS`` -- ``[filter, n_out, (psi_lo, psi_hi, mu_lo, mu_hi, phi_lo, phi_hi)
    x n_out]``: an exit scores into every output range containing its ``(psi, mu, phi)``;
    ``filter`` 0 all exits, 1 unscattered exits only, 2 scattered only. The same output
    ranges serve the next-event estimator, so both estimate the same average.

Vertex modes (``vertex_mode``, parameters ``vertex_params``)
    ``V_NONE`` -- nothing.
    ``V_CYLINDER_NEE`` -- ``[n_out, (psi_lo, psi_hi, mu_lo, mu_hi, phi_lo, phi_hi) x n_out]``:
    next-event estimation of the light that leaves the cylinder through the cell
    ``psi_lo <= psi < psi_hi`` in the local direction range (see :func:`score_vertex` for
    the geometry). Its bins follow the exit bins in the same ``bins`` array.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numba
import numpy as np

from simulate.montecarlo.rng import next_u64, to_uniform, to_uniform_open
from simulate.montecarlo.scatter import phase_pdf
from simulate.montecarlo.vecmath import vexp
from simulate.optics.fresnel import fresnel_unpolarized

__all__ = [
    "NONE",
    "SLAB_DIRECTIONS",
    "CYLINDER_DIRECTIONS",
    "CYLINDER_OUTPUTS",
    "V_NONE",
    "V_CYLINDER_NEE",
    "FILTER_ALL",
    "FILTER_UNSCATTERED",
    "FILTER_SCATTERED",
    "N_SCALARS",
    "SCALAR_NAMES",
    "OUTPUT_COLUMNS",
    "bin_count",
    "score_exit",
    "score_vertex",
    "nee_constants",
    "ratio_row",
    "NEE_COLUMNS",
    "N_NEE",
    "touch",
    "flush_history",
    "Scratch",
    "Spectral",
    "VertexInputs",
]

NONE = 0
SLAB_DIRECTIONS = 1
CYLINDER_DIRECTIONS = 2
CYLINDER_OUTPUTS = 3

V_NONE = 0
V_CYLINDER_NEE = 1

FILTER_ALL = 0
FILTER_UNSCATTERED = 1
FILTER_SCATTERED = 2

#: columns of an ``outputs`` row: cell centre (cos, sin of psi_c), cos of the cell's half
#: width, the local direction range (mu_lo, mu_hi, phi_lo, phi_hi), unused
OUTPUT_COLUMNS = ("cos_psi_c", "sin_psi_c", "cos_half_width", "mu_lo", "mu_hi", "phi_lo", "phi_hi", "spare")

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
S_ROULETTE_NET_SQ = 18  # sum over photons of (gain - killed)^2 of that photon
S_LAUNCH_WEIGHT = 19  # sum of launch weights (1 per photon, cos-weighted for the cell source)
N_SCALARS = 20

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
    "roulette_net_sq",
    "launch_weight",
)

_TWO_PI = 2.0 * math.pi


def bin_count(mode: int, params: np.ndarray) -> int:
    """Number of geometric exit bins of a tally mode (before the spectral factor).

    Parameters
    ----------
    mode : int
        Exit tally mode constant.
    params : numpy.ndarray
        The mode's parameters.

    Returns
    -------
    int
        ``n_bins >= 0``.
    """
    if mode == NONE:
        return 0
    if mode == SLAB_DIRECTIONS:
        return 2 * int(params[0]) * int(params[1])
    if mode == CYLINDER_DIRECTIONS:
        return int(params[0]) * int(params[1]) * int(params[2]) * int(params[3])
    if mode == CYLINDER_OUTPUTS:
        return int(params[1])
    raise ValueError(f"unknown tally mode {mode}")


@numba.njit(cache=True, inline="always")
def _uniform_bin(value: float, lo: float, hi: float, count: int) -> int:
    k = int((value - lo) / (hi - lo) * count)
    if k < 0:
        return 0
    if k >= count:
        return count - 1
    return k


class Scratch(NamedTuple):
    """A history's scratch tally, one per batch.

    Its scores ``hist`` (``n_spec`` spectral bins per geometric
    bin) and the geometric bins it touched (``touched[:n_touched[0]]``, flagged in ``marks``).
    """

    hist: np.ndarray
    touched: np.ndarray
    n_touched: np.ndarray
    marks: np.ndarray
    n_spec: int


class Spectral(NamedTuple):
    """A photon's spectral weights and what a score of them reads.

    A photon's spectral weights ``A_l`` (``spec_w``) and what a score of them reads: the targets'
    ``mu_t`` (``spec_mu_t``), whether their phase functions differ from the walk's (``phase_ratio``) and
    the phase ratios ``p^l / p^w`` on the grid of :func:`ratio_row` (``ratio``).
    """

    spec_w: np.ndarray
    spec_mu_t: np.ndarray
    phase_ratio: bool
    ratio: np.ndarray


class VertexInputs(NamedTuple):
    """What :func:`score_vertex` reads of a run, packed once per batch.

    The output ranges, their constants
    (:func:`nee_constants`; a batch's private copy, as ranged outputs overwrite their row) and a work row,
    the first vertex bin (``base``), the cylinder's ``radius`` and index ``n_in``, and the walk's phase
    function (``kind, g, table, pdf, lookup``, as :func:`.scatter.phase_pdf` reads it).
    """

    outputs: np.ndarray
    consts: np.ndarray
    work: np.ndarray
    base: int
    radius: float
    n_in: float
    kind: int
    g: float
    table: np.ndarray
    pdf: np.ndarray
    lookup: np.ndarray


@numba.njit(cache=True, inline="always")
def touch(touched: np.ndarray, n_touched: np.ndarray, marks: np.ndarray, block: int) -> None:
    """Remember that the history scored into geometric bin ``block`` (its ``n_spec`` spectral bins).

    The scratch tally is kept per geometric bin, not per spectral bin: one test per score, and
    the wavelength loops that follow are plain array arithmetic (vectorised by LLVM).

    Parameters
    ----------
    touched : numpy.ndarray
        The geometric bins touched so far (first ``n_touched[0]``).
    n_touched : numpy.ndarray
        ``[1]`` their count.
    marks : numpy.ndarray
        Per geometric bin, whether it is in ``touched``.
    block : int
        The geometric bin scored.
    """
    if not marks[block]:
        marks[block] = True
        touched[n_touched[0]] = block
        n_touched[0] += 1


@numba.njit(cache=True, inline="always")
def flush_history(scratch: Scratch, bins: np.ndarray) -> None:
    """End of a history: move its scratch scores into ``bins`` as (sum, sum of squares).

    Every spectral bin of a touched geometric bin is flushed; a bin that scored nothing adds
    ``0`` to both sums, which leaves them unchanged.

    Parameters
    ----------
    scratch : Scratch
        The history's scores, cleared as they are moved.
    bins : numpy.ndarray
        ``[n_bins, 2]`` the batch's sums and sums of squares.
    """
    hist, touched, n_touched, marks, n_spec = scratch
    for i in range(n_touched[0]):
        block = touched[i]
        marks[block] = False
        for k in range(block * n_spec, (block + 1) * n_spec):
            h = hist[k]
            bins[k, 0] += h
            bins[k, 1] += h * h
            hist[k] = 0.0
    n_touched[0] = 0


@numba.njit(cache=True, inline="always")
def _add_spectral(scratch, block, spec_w, value) -> None:
    hist, touched, n_touched, marks, n_spec = scratch
    touch(touched, n_touched, marks, block)
    h = hist[block * n_spec:(block + 1) * n_spec]
    for l in range(n_spec):
        h[l] += value * spec_w[l]


# _nrt=False: as score_vertex (the inlined _add_spectral binds the scratch tally's arrays)
@numba.njit(cache=True, _nrt=False)
def score_exit(mode: int, params: np.ndarray, outputs: np.ndarray, scratch: Scratch, spec_w: np.ndarray, face: int,
               p: tuple[float, float, float], w: tuple[float, float, float], weight: float, scatterings: int) -> None:
    """Score a photon leaving the medium at ``p`` in direction ``w`` (outside, unit).

    Parameters
    ----------
    mode, params : int, numpy.ndarray
        Exit tally mode and its parameters (module docstring).
    outputs : numpy.ndarray
        ``float64[n_out, 8]`` output ranges (``CYLINDER_OUTPUTS``; columns ``OUTPUT_COLUMNS``).
    scratch : Scratch
        The history's scratch tally.
    spec_w : numpy.ndarray
        ``A_l``, the photon's spectral weight factors.
    face : int
        Slab: 0 top, 1 bottom; cylinder: 0.
    p : (float, float, float)
        Exit point on the surface.
    w : (float, float, float)
        Exit direction after refraction.
    weight : float
        Photon weight leaving (walk medium).
    scatterings : int
        Scattering events of the photon (0: unscattered light).
    """
    x, y, z = p
    wx, wy, wz = w
    if mode == SLAB_DIRECTIONS:
        n_mu = int(params[0])
        n_phi = int(params[1])
        mu = wz if face == 0 else -wz
        k = (face * n_mu + _uniform_bin(mu, 0.0, 1.0, n_mu)) * n_phi
        k += _uniform_bin(math.atan2(wy, wx), -math.pi, math.pi, n_phi)
        _add_spectral(scratch, k, spec_w, weight)
        return
    if mode == NONE:
        return
    r = math.sqrt(y * y + z * z)
    ny = y / r
    nz = z / r
    mu = wy * ny + wz * nz
    # b = n x t = (0, n_z, -n_y): with n = (0, -sin psi, cos psi), b = (0, cos psi, sin psi)
    wb = wy * nz - wz * ny
    phi = math.atan2(wb, wx)
    if mode == CYLINDER_DIRECTIONS:
        n_psi = int(params[0])
        n_mu = int(params[1])
        n_phi = int(params[2])
        n_v = int(params[3])
        psi = math.atan2(-y, z)
        cell = int(math.floor(psi / _TWO_PI * n_psi + 0.5)) % n_psi
        kv = _uniform_bin(x, -params[4], params[4], n_v) if n_v > 1 else 0
        k = ((cell * n_v + kv) * n_mu + _uniform_bin(mu, 0.0, 1.0, n_mu)) * n_phi
        k += _uniform_bin(phi, -math.pi, math.pi, n_phi)
        _add_spectral(scratch, k, spec_w, weight)
        return
    if mode == CYLINDER_OUTPUTS:
        filt = int(params[0])
        if filt == FILTER_UNSCATTERED and scatterings > 0:
            return
        if filt == FILTER_SCATTERED and scatterings == 0:
            return
        for o in range(outputs.shape[0]):
            # n(psi) . n(psi_c) with n = (-sin, cos): -y sin_c + z cos_c over r
            if -ny * outputs[o, 1] + nz * outputs[o, 0] < outputs[o, 2]:
                continue
            if mu < outputs[o, 3] or mu > outputs[o, 4] or phi < outputs[o, 5] or phi > outputs[o, 6]:
                continue
            _add_spectral(scratch, o, spec_w, weight)


#: columns of the per-output constants of the next-event estimator (:func:`nee_constants`)
NEE_COLUMNS = ("u_t", "u_b", "u_n", "rho", "sin_alpha", "cos_alpha", "fresnel", "k_max", "cos_step", "sin_step",
               "chord", "jacobian_factor")
N_NEE = 12
_ORDER_CUTOFF = 1e-6  # internal-reflection orders are followed while F^k exceeds this (bias < 1e-6 relative)
#: internal reflectance up to which :func:`score_vertex` draws the reflections one by one (at most ~19 expected,
#: exits up to ~89.5 deg from the normal); above it the same geometric law is drawn at once (its inverse CDF)
_LOOP_F = 0.95


# fastmath=False explicitly: called from Python (transport.make_inputs) and from the fastmath kernel;
# without its own setting numba would compile it with the flags of whichever caller came first and
# cache that flavour (see rng._exponential_slow)
@numba.njit(cache=True, fastmath=False)
def nee_constants(mu: float, phi: float, n_in: float, radius: float, out: np.ndarray) -> None:
    """Constants of a local exit direction ``(mu = cos theta_out, phi)`` for :func:`score_vertex`.

    Fills ``out[:N_NEE]`` (``NEE_COLUMNS``): the internal direction in the local frame
    (``u_t, u_b, u_n``), ``rho = sqrt(1 - u_t^2)``, ``sin/cos alpha``, the internal Fresnel
    reflectance ``F``, the number of reflection orders with ``F^k > 1e-6``, the rotation of the
    exit point per chord, the 3-D chord length ``2 R cos alpha / rho`` and
    ``R cos alpha / (n^2 u_n)`` (the Jacobian's numerator with the interface factor).
    ``rho = 0`` marks a direction that cannot occur.

    Parameters
    ----------
    mu, phi : float
        The exit direction's cosine from the normal and azimuth.
    n_in : float
        The fiber's refractive index.
    radius : float
        The fiber's radius (um).
    out : numpy.ndarray
        The row written.
    """
    st = math.sqrt(max(1.0 - mu * mu, 0.0))
    u_t = st * math.cos(phi) / n_in
    u_b = st * math.sin(phi) / n_in
    u_n = math.sqrt(max(1.0 - u_t * u_t - u_b * u_b, 0.0))
    rho = math.sqrt(u_n * u_n + u_b * u_b)
    for i in range(N_NEE):
        out[i] = 0.0
    if rho <= 0.0 or u_n <= 0.0:
        return
    sa = u_b / rho
    ca = u_n / rho
    f_out = fresnel_unpolarized(u_n, n_in, 1.0)
    k_max = 1
    fk = f_out
    while fk > _ORDER_CUTOFF and k_max < 64:
        k_max += 1
        fk *= f_out
    alpha = math.atan2(sa, ca)
    step = -(math.pi - 2.0 * alpha) if sa > 0.0 else math.pi + 2.0 * alpha
    out[0] = u_t
    out[1] = u_b
    out[2] = u_n
    out[3] = rho
    out[4] = sa
    out[5] = ca
    out[6] = f_out
    out[7] = k_max
    out[8] = math.cos(step)
    out[9] = math.sin(step)
    out[10] = 2.0 * radius * ca / rho
    out[11] = radius * ca / (n_in * n_in * u_n)


@numba.njit(cache=True, inline="always")
def reflection_order(f_out: float, s0: np.uint64, s1: np.uint64, s2: np.uint64,
                     s3: np.uint64) -> tuple[int, np.uint64, np.uint64, np.uint64, np.uint64]:
    """The number ``k`` of internal reflections before the light leaves, ``P(k) = (1 - F) F^k`` (``F = f_out < 1``).

    Up to ``F =`` :data:`_LOOP_F` one draw per reflection (a reflection while ``U < F``); above it, near grazing
    (``1 / (1 - F)`` reflections expected: 1000 at 89.99 deg), the same law by its inverse CDF in one draw:
    ``k = floor(ln U / ln F)`` with ``U`` in (0, 1], since ``P(k >= m) = P(U <= F^m) = F^m``.

    Parameters
    ----------
    f_out : float
        The internal Fresnel reflectance ``F``.
    s0, s1, s2, s3 : numpy.uint64
        The random state.

    Returns
    -------
    tuple
        ``(k, s0, s1, s2, s3)``: the order and the advanced state.
    """
    k = 0
    if f_out <= _LOOP_F:
        if f_out > 0.0:
            while True:
                rr, s0, s1, s2, s3 = next_u64(s0, s1, s2, s3)
                if to_uniform(rr) >= f_out:
                    break
                k += 1
        return k, s0, s1, s2, s3
    rr, s0, s1, s2, s3 = next_u64(s0, s1, s2, s3)
    k = int(math.floor(math.log(to_uniform_open(rr)) / math.log(f_out)))
    return k, s0, s1, s2, s3


@numba.njit(cache=True, inline="always")
def turned(ny: float, nz: float, c_step: float, s_step: float, k: int, f_out: float) -> tuple[float, float]:
    """The exit normal after ``k`` reflections around the fiber's section.

    Each reflection turns the normal ``n = (-sin psi, cos psi)`` by ``step``: one rotation per
    reflection up to ``F =`` :data:`_LOOP_F` (the orders of :func:`reflection_order`'s loop), one
    rotation by ``k step`` above it.

    Parameters
    ----------
    ny, nz : float
        The normal before.
    c_step, s_step : float
        ``cos step`` and ``sin step``.
    k : int
        Reflections.
    f_out : float
        The internal Fresnel reflectance (which way of turning was drawn).

    Returns
    -------
    tuple of float
        The normal after.
    """
    if f_out <= _LOOP_F:
        for _ in range(k):
            t_y = ny * c_step - nz * s_step
            nz = ny * s_step + nz * c_step
            ny = t_y
        return ny, nz
    turn = k * math.atan2(s_step, c_step)
    c_k = math.cos(turn)
    s_k = math.sin(turn)
    return ny * c_k - nz * s_k, ny * s_k + nz * c_k


@numba.njit(cache=True, inline="always")
def ratio_row(mu: float, n_grid: int) -> tuple[int, float]:
    """Grid node and fraction of ``mu`` on the phase-ratio grid ``t = sqrt((1 - mu) / 2)`` uniform.

    Parameters
    ----------
    mu : float
        Cosine of the scattering angle.
    n_grid : int
        Nodes of the grid.

    Returns
    -------
    tuple
        ``(j, frac)``: the node below and the fraction towards the next.
    """
    t = math.sqrt(max(0.5 * (1.0 - mu), 0.0))
    x = t * (n_grid - 1)
    j = min(int(x), n_grid - 2)
    return j, x - j


@numba.njit(cache=True, error_model="numpy")
def _score_spectral(scratch, block, g0, spectral, path, cos_s) -> None:
    """Add ``g0 A_l (p_l / p_walk)(cos_s) exp(-mu_t,l path)`` to bins ``block * n_spec + l`` (one exit solution).

    The wavelength loop reads contiguous rows (``spec_w``, ``spec_mu_t``, two rows of ``ratio``)
    and writes one contiguous block of ``hist``, with no call and no branch in it
    (:func:`.vecmath.vexp`): LLVM vectorises it. A separate compiled function on purpose: inlined
    into the vertex loop, this loop is no longer vectorised and the whole estimator is slower.
    """
    hist, touched, n_touched, marks, n_spec = scratch
    spec_w, spec_mu_t, phase_ratio, ratio = spectral
    touch(touched, n_touched, marks, block)
    # slices, not hist[first + l]: a slice's index is known non-negative (no wrap-around select),
    # which is what lets LLVM vectorise these loops
    h = hist[block * n_spec:(block + 1) * n_spec]
    if phase_ratio:
        jr, fr = ratio_row(cos_s, ratio.shape[0])
        r0 = ratio[jr]
        r1 = ratio[jr + 1]
        for l in range(n_spec):
            h[l] += g0 * spec_w[l] * (r0[l] + fr * (r1[l] - r0[l])) * vexp(-spec_mu_t[l] * path)
    else:
        for l in range(n_spec):
            h[l] += g0 * spec_w[l] * vexp(-spec_mu_t[l] * path)


# _nrt=False: compiled without reference counting (numba's option for code that allocates nothing): its
# inlined helpers bind the records' arrays to their own variables, which would otherwise be counted up and
# down at every call
@numba.njit(cache=True, _nrt=False)
def score_vertex(vertex: VertexInputs, scratch: Scratch, spectral: Spectral, p: tuple[float, float, float],
                 u: tuple[float, float, float], weight: float,
                 state: tuple[np.uint64, np.uint64, np.uint64, np.uint64]) -> tuple[np.uint64, np.uint64, np.uint64,
                                                                                     np.uint64]:
    r"""Next-event estimate of the light leaving the cylinder at each output, from one vertex.

    The photon (weight ``w`` after implicit capture, arriving along ``u``) scatters at ``p``.
    For an output (cell ``C`` of the surface, local exit direction ``w_out`` -- a point, or
    drawn in the output's range with density ``prop. to cos theta_out``, so that the
    expectation is the projected-solid-angle average over the range), the scored quantity is
    the energy per unit solid angle of ``w_out`` leaving through ``C`` in that LOCAL
    direction (local frame of each exit point; the cylinder's invariance makes them
    equivalent), divided by ``cos theta_out``:

    *Internal direction.* Snell backwards at the exit: ``u_t = w_t / n``, ``u_b = w_b / n``,
    ``u_n = sqrt(1 - u_t^2 - u_b^2)`` (``u_n = cos theta_int``), fixed in the local frame.
    Its projection on the cross-section makes the angle ``alpha`` with the normal:
    ``sin alpha = u_b / rho``, ``cos alpha = u_n / rho``, ``rho = sqrt(1 - u_t^2)``
    (:func:`nee_constants`; a ranged output's direction is drawn by :func:`_output_direction`).
    The exit points, internal reflections and the Jacobian of one output: :func:`_score_output`.

    ``R_vol = (score per photon) x (launch normalisation) / (cell width)`` (see :mod:`simulate.fiber`).

    Parameters
    ----------
    vertex : VertexInputs
        The outputs and their constants (``consts`` holds :func:`nee_constants` of point outputs;
        for ranged outputs the direction is drawn here and its row overwritten), the first vertex
        bin, the cylinder and the walk's phase function.
    scratch : Scratch
        The history's scratch tally.
    spectral : Spectral
        The photon's spectral weights and the targets.
    p, u : (float, float, float)
        The vertex and the photon's direction arriving there.
    weight : float
        The photon's weight after implicit capture.
    state : (uint64, uint64, uint64, uint64)
        The random state.

    Returns
    -------
    (uint64, uint64, uint64, uint64)
        The advanced random state.
    """
    x, y, z = p
    r2 = y * y + z * z
    if r2 <= 0.0:
        r2 = 1e-300
    inv_r2 = 1.0 / r2
    for o in range(vertex.outputs.shape[0]):
        state = _output_direction(vertex, o, state)
        state = _score_output(vertex, o, scratch, spectral, p, u, weight, r2, inv_r2, state)
    return state


@numba.njit(cache=True, inline="always")
def _output_direction(vertex, o, state):
    """Draw a ranged output's exit direction and write its constants; a point output keeps its row.

    A ranged output's exit direction, drawn in its range with density ``prop. to cos theta_out``
    (``mu^2`` uniform, ``phi`` uniform), its constants written to row ``o`` of ``consts``; a point output
    keeps its row. Returns the random state (no draw for a point output).
    """
    outputs, consts, work = vertex.outputs, vertex.consts, vertex.work
    s0, s1, s2, s3 = state
    mu_lo = outputs[o, 3]
    mu_hi = outputs[o, 4]
    phi_lo = outputs[o, 5]
    phi_hi = outputs[o, 6]
    if mu_hi > mu_lo or phi_hi > phi_lo:
        if mu_hi > mu_lo:
            rr, s0, s1, s2, s3 = next_u64(s0, s1, s2, s3)
            mu = math.sqrt(mu_lo * mu_lo + to_uniform(rr) * (mu_hi * mu_hi - mu_lo * mu_lo))
        else:
            mu = mu_lo
        if phi_hi > phi_lo:
            rr, s0, s1, s2, s3 = next_u64(s0, s1, s2, s3)
            phi = phi_lo + to_uniform(rr) * (phi_hi - phi_lo)
        else:
            phi = phi_lo
        nee_constants(mu, phi, vertex.n_in, vertex.radius, work)
        for i in range(N_NEE):
            consts[o, i] = work[i]
    return s0, s1, s2, s3


@numba.njit(cache=True, inline="always")
def _score_output(vertex, o, scratch, spectral, p, u, weight, r2, inv_r2, state):
    r"""The score of output ``o`` from the vertex ``p`` (``r2 = |p'|^2``): up to two exit solutions.

    *Exit points.* A 2-D ray from ``p' = (y, z)`` reaches the circle at angle ``alpha`` to the
    normal after the 2-D distance ``s`` with ``|p'|^2 = R^2 - 2 R s cos alpha + s^2``::

        s_pm = R cos alpha +- sqrt(|p'|^2 - R^2 sin^2 alpha)      (none if |p'| < R |sin alpha|)

    and the exit normal follows from ``p' = (R - s cos alpha) n - s sin alpha b``, i.e. in
    complex form ``n = p' (a_n + i a_b) / |p'|^2`` with ``a_n = R - s cos alpha``,
    ``a_b = -s sin alpha`` (``b`` is ``n`` turned by -90 degrees). The 3-D distance is
    ``s / rho``.

    *Internal reflections.* In a circle a chord keeps its angle to the normal, so after each
    Fresnel reflection the ray meets the surface again with the same local direction, the
    exit point turned by ``-(pi - 2 alpha)`` (``sin alpha > 0``; ``pi + 2 alpha`` otherwise) and
    a further path ``2 R cos alpha / rho``: order ``k`` carries ``F^k (1 - F)``. Rather than
    following every order, each exit solution draws its order ``k`` with probability
    ``(1 - F) F^k`` -- the number of internal reflections the light would really make -- so
    ``F^k (1 - F)`` cancels and only that order is scored (unbiased; one cell test instead of a
    dozen, and the faint orders cost nothing unless drawn): :func:`reflection_order`, :func:`turned`.

    *Jacobian.* With the direction parametrised by ``(u_t, phi)`` (``dOmega = du_t dphi``) and
    the local direction by ``(u_t, alpha)``, ``d alpha / d phi = 1 - s / (R cos alpha)``, since a
    fan ``dphi`` at distance ``s`` covers ``R dpsi = s dphi / cos alpha`` of the surface::

        dOmega_u / dOmega_local = R cos alpha / sqrt(|p'|^2 - R^2 sin^2 alpha)   (= J)

    and across the interface ``dOmega_local = cos theta_out dOmega_out / (n^2 cos theta_int)``.
    The score per wavelength ``l`` and order ``k`` is therefore::

        w A_l p_l(u_in . u) exp(-mu_t,l (s + k c) / rho) F^k (1 - F) J / (n^2 u_n)

    (``c`` here the 2-D chord ``2 R cos alpha``, ``/ rho`` making both lengths 3-D)

    with ``p_l = p_walk x (p_l / p_walk)``, the ratio read from ``ratio`` (see
    :mod:`simulate.montecarlo.kernel`). ``J`` diverges (integrably) on the caustic
    ``|p'| = R |sin alpha|``: the estimator is unbiased but its variance grows logarithmically
    there; cells and direction ranges of finite size average it out. Returns the random state.
    """
    outputs, consts, radius = vertex.outputs, vertex.consts, vertex.radius
    _, y, z = p
    ux, uy, uz = u
    s0, s1, s2, s3 = state
    rho = consts[o, 3]
    if rho <= 0.0:
        return s0, s1, s2, s3
    sa = consts[o, 4]
    ca = consts[o, 5]
    disc = r2 - radius * radius * sa * sa
    if disc <= 0.0:
        return s0, s1, s2, s3
    sq = math.sqrt(disc)
    f_out = consts[o, 6]
    if f_out >= 1.0:
        return s0, s1, s2, s3          # an exactly grazing exit: no light leaves there
    c_step = consts[o, 8]
    s_step = consts[o, 9]
    cos_c = outputs[o, 0]
    sin_c = outputs[o, 1]
    cos_h = outputs[o, 2]
    for sol in range(2):
        s = radius * ca + sq if sol == 0 else radius * ca - sq
        if s <= 0.0:
            continue
        a_n = radius - s * ca
        a_b = -s * sa
        # n = p' (a_n + i a_b) / |p'|^2 in (y + i z) notation: the first exit point's normal
        ny0 = (y * a_n - z * a_b) * inv_r2
        nz0 = (y * a_b + z * a_n) * inv_r2
        # the number of internal reflections before the light leaves, k ~ P(k) = (1 - F) F^k:
        # the physical process itself, so F^k (1 - F) cancels against P(k)
        k, s0, s1, s2, s3 = reflection_order(f_out, s0, s1, s2, s3)
        ny, nz = turned(ny0, nz0, c_step, s_step, k, f_out)
        # cell test: n(psi) . n(psi_c), n(psi_c) = (-sin_c, cos_c)
        if -ny * sin_c + nz * cos_c < cos_h:
            continue
        # the light reaches the cell (most solutions do not: what they need is loaded only now)
        # internal direction at the first exit point: u_t t + u_n n + u_b b, b = (n_z, -n_y)
        u_t = consts[o, 0]
        u_b = consts[o, 1]
        u_n = consts[o, 2]
        cos_s = ux * u_t + uy * (u_n * ny0 + u_b * nz0) + uz * (u_n * nz0 - u_b * ny0)
        p_w = phase_pdf(cos_s, vertex.kind, vertex.g, vertex.table, vertex.pdf, vertex.lookup)
        path = s / rho + k * consts[o, 10]
        common = weight * consts[o, 11] / sq
        _score_spectral(scratch, vertex.base + o, common * p_w, spectral, path, cos_s)
    return s0, s1, s2, s3
