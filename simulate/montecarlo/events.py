"""The photon kernel's events, one compiled helper each, shared by both photon loops.

Each helper is what happens to one photon at one event of its history (docs/physics.md section 3;
the order of events in :mod:`.kernel`'s module docstring), written once and called by both loops:
:func:`.kernel.simulate_batch` (every geometry, tallies and spectral targets) and
:func:`.slab_lanes.simulate_batch_slab_lanes` (the plain slab, two photons in flight).

* :class:`Walk` and :func:`walk_constants`: the walk medium's and the control's constants of a run;
* :func:`free_path`: the length of the next free path;
* :func:`refract_in`: a smooth entry (Snell), the entering direction and the reflected fraction;
* :func:`implicit_capture`: the absorbed part of a photon's weight at a collision;
* :func:`fresnel_reflects`: whether a photon meeting the smooth boundary from inside is reflected
  (Fresnel, total internal reflection included), drawing only when the answer is not certain;
* :func:`mirror` and :func:`refract_out`: its new direction, reflected or leaving;
* :func:`roulette_below` and :func:`roulette`: Russian roulette of a photon whose weight fell below
  the threshold;
* :func:`catch_up` and :func:`catch_up_dyed`: the spectral weights brought up to date with the
  free paths walked since their last update (:data:`.kernel.REWEIGHT_EVERY`), without and with a
  dye profile; :func:`largest`: the largest of them, which roulette reads;
* :func:`end_history` and :func:`add_totals`: a history's end booked in the batch's sums, and those
  sums added to the caller's accumulators (:mod:`.tallies` ``S_*``).

The helpers take and return scalars (the random stream's four words included) or small records of
scalars, so that inlined (``inline="always"``: numba inlines them in its own IR before LLVM sees the
loop) they leave the hot state of a history in registers, as a loop written out in one piece does;
the compiled loops and their results at a fixed seed are those of that piece, bit for bit.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numba

from simulate.montecarlo import tallies as T
from simulate.montecarlo.rng import exponential, next_u64, to_uniform
from simulate.montecarlo.scatter import hg_constants
from simulate.montecarlo.vecmath import vexp
from simulate.optics.fresnel import fresnel_unpolarized, refracted_cos

__all__ = ["M_MU_A", "M_MU_S", "M_G", "M_N", "M_PHASE", "M_ROUGH", "M_ROUGH_B", "M_DYE_PROFILE", "M_DYE_RADIUS",
           "M_SCAT_PROFILE", "M_SCAT_RADIUS", "N_MEDIUM", "C_WEIGHT_THRESHOLD", "C_SURVIVAL", "C_MAX_EVENTS", "N_CONTROL", "Walk", "walk_constants",
           "free_path", "refract_in", "implicit_capture", "fresnel_reflects", "mirror", "refract_out", "roulette_below",
           "roulette", "catch_up", "catch_up_dyed", "catch_up_placed", "largest", "end_history", "add_totals"]

_FASTMATH = {"nsz", "arcp", "contract", "afn", "reassoc"}  # as kernel._FASTMATH

# walk-medium array slots (kernel.KernelInputs.medium; re-exported by kernel)
M_MU_A = 0
M_MU_S = 1
M_G = 2
M_N = 3
M_PHASE = 4
M_ROUGH = 5  # Beckmann RMS slope of the boundary for light crossing it, along the axis (0 with M_ROUGH_B: smooth; .rough)
M_ROUGH_B = 6  # ... and about the axis (the same value: isotropic)
M_DYE_PROFILE = 7  # where the targets' dye absorbs across a cylinder: kernel.DYE_UNIFORM (0), DYE_RING, DYE_CORE
M_DYE_RADIUS = 8  # the profile's inner boundary: the dye at r > it (ring) or at r < it (core)
M_SCAT_PROFILE = 9  # where the scatterers sit across a cylinder: kernel.SCAT_UNIFORM (0), SCAT_SKIN, SCAT_CORE
M_SCAT_RADIUS = 10  # the scatterer profile's inner boundary: scatterers at r > it (skin) or at r < it (core)
N_MEDIUM = 11

# control array slots (kernel.KernelInputs.control; re-exported by kernel)
C_WEIGHT_THRESHOLD = 0
C_SURVIVAL = 1
C_MAX_EVENTS = 2
N_CONTROL = 3


class Walk(NamedTuple):
    """The constants of a run's walk, derived once per batch from its medium and control rows.

    ``inv_mu_t`` is the mean free path (``inf`` in vacuum), ``albedo`` and ``absorb`` the scattered and
    absorbed parts of a collision; ``contrast``: the boundary refracts (``n_in != 1``), ``eta_in = 1 / n_in``;
    ``rough``: it is rough (:mod:`.rough`, slopes ``m_rough`` along and ``m_rough_b`` about the axis);
    ``phase, g, hg``: the phase function (:func:`.scatter.sample_direction`); roulette below ``w_threshold``
    with survival probability ``survival``; at most ``max_events`` steps a photon.
    """

    mu_t: float
    inv_mu_t: float
    albedo: float
    absorb: float
    n_in: float
    eta_in: float
    contrast: bool
    rough: bool
    m_rough: float
    m_rough_b: float
    phase: int
    g: float
    hg: tuple[float, float, float, float, float]
    w_threshold: float
    survival: float
    inv_survival: float
    max_events: int


@numba.njit(cache=True, inline="always", fastmath=_FASTMATH)
def walk_constants(medium, control):
    """The :class:`Walk` of a medium row (``M_*`` slots) and a control row (``C_*`` slots)."""
    mu_a = medium[M_MU_A]
    mu_s = medium[M_MU_S]
    g = medium[M_G]
    n_in = medium[M_N]
    mu_t = mu_a + mu_s
    albedo = mu_s / mu_t if mu_t > 0.0 else 0.0
    contrast = n_in != 1.0
    m_rough = medium[M_ROUGH]
    m_rough_b = medium[M_ROUGH_B]
    survival = control[C_SURVIVAL]
    return Walk(mu_t, 1.0 / mu_t if mu_t > 0.0 else math.inf, albedo, 1.0 - albedo, n_in, 1.0 / n_in, contrast,
                contrast and (m_rough > 0.0 or m_rough_b > 0.0), m_rough, m_rough_b, int(medium[M_PHASE]), g,
                hg_constants(g), control[C_WEIGHT_THRESHOLD], survival, 1.0 / survival, int(control[C_MAX_EVENTS]))


@numba.njit(cache=True, inline="always", fastmath=_FASTMATH)
def free_path(inv_mu_t, s0, s1, s2, s3):
    """The length of the next free path, ``E / mu_t`` with ``E ~ Exp(1)`` (ziggurat, :func:`.rng.exponential`).

    ``(step, s0, s1, s2, s3)``.
    """
    e, s0, s1, s2, s3 = exponential(s0, s1, s2, s3)
    return e * inv_mu_t, s0, s1, s2, s3


@numba.njit(cache=True, inline="always", fastmath=_FASTMATH)
def refract_in(dx, dy, dz, nx, ny, nz, cos_i, n_in, eta_in):
    """A smooth entry (Snell): the direction inside and the reflected fraction.

    A smooth entry from outside (index 1) into index ``n_in`` (``eta_in = 1 / n_in``) along ``d``, at a
    surface of outward normal ``n`` with ``cos_i = -d . n``: ``(ux, uy, uz, f_in)``, the unit refracted
    direction and the Fresnel reflectance (unpolarised) that the entering weight loses.
    """
    f_in = fresnel_unpolarized(cos_i, 1.0, n_in)
    cos_t = refracted_cos(cos_i, 1.0, n_in)
    k = eta_in * cos_i - cos_t
    ux = eta_in * dx + k * nx
    uy = eta_in * dy + k * ny
    uz = eta_in * dz + k * nz
    norm = 1.0 / math.sqrt(ux * ux + uy * uy + uz * uz)
    return ux * norm, uy * norm, uz * norm, f_in


@numba.njit(cache=True, inline="always", fastmath=_FASTMATH)
def implicit_capture(w, absorbed, albedo, absorb):
    """Implicit capture at a collision: ``(w, absorbed)``.

    Implicit capture at a collision: the absorbed part ``w mu_a / mu_t`` (``absorb``) of the weight ``w``
    booked, the photon going on with ``w mu_s / mu_t`` (``albedo``). ``(w, absorbed)``.
    """
    return w * albedo, absorbed + w * absorb


@numba.njit(cache=True, inline="always", fastmath=_FASTMATH)
def fresnel_reflects(cos_i, n_in, s0, s1, s2, s3):
    """Whether a photon meeting the smooth boundary from inside is reflected.

    Whether a photon inside (index ``n_in``) meeting the smooth boundary at ``cos_i`` is reflected:
    ``(reflect, s0, s1, s2, s3)``. Reflected with the Fresnel probability; certain beyond the critical
    angle and impossible when the reflectance is 0, and then no random number is drawn.
    """
    f_out = fresnel_unpolarized(cos_i, n_in, 1.0)
    reflect = False
    if f_out > 0.0:
        if f_out >= 1.0:
            reflect = True
        else:
            r, s0, s1, s2, s3 = next_u64(s0, s1, s2, s3)
            reflect = to_uniform(r) < f_out
    return reflect, s0, s1, s2, s3


@numba.njit(cache=True, inline="always", fastmath=_FASTMATH)
def mirror(ux, uy, uz, nx, ny, nz, cos_i, flat):
    """The mirror image of a direction at the boundary.

    The direction ``u`` reflected at a surface of normal ``n`` (``cos_i = u . n``); ``flat``: a face
    ``z = const``, whose mirror image is exact (``u_z`` negated).
    """
    if flat:
        return ux, uy, -uz
    ux -= 2.0 * cos_i * nx
    uy -= 2.0 * cos_i * ny
    uz -= 2.0 * cos_i * nz
    norm = 1.0 / math.sqrt(ux * ux + uy * uy + uz * uz)
    return ux * norm, uy * norm, uz * norm


@numba.njit(cache=True, inline="always", fastmath=_FASTMATH)
def refract_out(ux, uy, uz, nx, ny, nz, cos_i, n_in):
    """The direction of a photon refracted out of the medium.

    The unit direction of a photon leaving index ``n_in`` for index 1 along ``u`` through a surface of
    outward normal ``n`` (``cos_i = u . n``, below the critical angle).
    """
    cos_t = refracted_cos(cos_i, n_in, 1.0)
    k = cos_t - n_in * cos_i
    wx = n_in * ux + k * nx
    wy = n_in * uy + k * ny
    wz = n_in * uz + k * nz
    norm = 1.0 / math.sqrt(wx * wx + wy * wy + wz * wz)
    return wx * norm, wy * norm, wz * norm


@numba.njit(cache=True, inline="always", fastmath=_FASTMATH)
def roulette_below(w, w_max, walk, h_gain, h_killed, s0, s1, s2, s3):
    """Russian roulette of a photon whose weight fell below the threshold.

    Russian roulette when the weight that counts, ``w w_max`` (``w_max``: the largest spectral weight, 1
    without targets), fell below the threshold; a photon with nothing left to carry ends without a draw.

    ``(alive, w, h_gain, h_killed, s0, s1, s2, s3)``, as :func:`roulette`.
    """
    if w * w_max < walk.w_threshold:
        if w <= 0.0 or w_max <= 0.0:
            return False, w, h_gain, h_killed, s0, s1, s2, s3
        return roulette(w, h_gain, h_killed, walk.survival, walk.inv_survival, s0, s1, s2, s3)
    return True, w, h_gain, h_killed, s0, s1, s2, s3


@numba.njit(cache=True, inline="always", fastmath=_FASTMATH)
def roulette(w, h_gain, h_killed, survival, inv_survival, s0, s1, s2, s3):
    """Russian roulette: the photon survives, heavier, or ends.

    Russian roulette of a photon of weight ``w > 0`` below the threshold: it survives with probability
    ``survival`` and its weight is divided by it. ``(alive, w, h_gain, h_killed, s0, s1, s2, s3)``: the
    history's roulette gain and killed weight (its balance) updated.
    """
    r, s0, s1, s2, s3 = next_u64(s0, s1, s2, s3)
    if to_uniform(r) < survival:
        return True, w * inv_survival, h_gain + w * (inv_survival - 1.0), h_killed, s0, s1, s2, s3
    return False, w, h_gain, h_killed + w, s0, s1, s2, s3


@numba.njit(cache=True, inline="always", fastmath=_FASTMATH)
def catch_up(spec_w, log_s, d_mu_t, n, length):
    """The spectral weights brought up to date with the free paths since their last update.

    The spectral weights times the free-path factors of ``n`` collisions over the path ``length`` walked
    since their last update: ``A_l *= exp(n ln(mu_s^l / mu_s^w) - (mu_t^l - mu_t^w) length)`` (one
    vectorised exponential per wavelength, :func:`.vecmath.vexp`).
    """
    for l in range(spec_w.shape[0]):
        spec_w[l] *= vexp(n * log_s[l] - d_mu_t[l] * length)


@numba.njit(cache=True, inline="always", fastmath=_FASTMATH)
def catch_up_dyed(spec_w, log_s, d_mu_u, spec_dye, n, length, dyed):
    """:func:`catch_up` with a dye profile.

    :func:`catch_up` with a dye profile: the dye's absorption ``spec_dye`` taken along the part ``dyed``
    of the path in the dyed region, the rest of the difference ``d_mu_u`` along the whole ``length``.
    """
    for l in range(spec_w.shape[0]):
        spec_w[l] *= vexp(n * log_s[l] - d_mu_u[l] * length - spec_dye[l] * dyed)


@numba.njit(cache=True, inline="always", fastmath=_FASTMATH)
def catch_up_placed(spec_w, log_s, d_mu_u, spec_dye, d_mu_s, n, length, dyed, clear):
    """:func:`catch_up_dyed` with a scatterer profile too.

    :func:`catch_up_dyed` where the scatterers sit in part of the fiber: the walk takes null collisions
    (no scattering, no spectral factor) in the clear region, at the walk's own ``mu_s^w``, and so does
    the target (its null rate is the walk's). There the target's extinction differs from the walk's by
    ``mu_a^l - mu_a^w = (mu_t^l - mu_t^w) - d_mu_s``: the part ``clear`` of the path takes back
    ``d_mu_s = mu_s^l - mu_s^w``; ``n`` counts the real scatterings only.
    """
    for l in range(spec_w.shape[0]):
        spec_w[l] *= vexp(n * log_s[l] - d_mu_u[l] * length - spec_dye[l] * dyed + d_mu_s[l] * clear)


@numba.njit(cache=True, inline="always", fastmath=_FASTMATH)
def largest(spec_w):
    """The largest spectral weight (roulette acts on ``w max_l A_l``)."""
    w_max = 0.0
    for l in range(spec_w.shape[0]):
        w_max = max(w_max, spec_w[l])
    return w_max


@numba.njit(cache=True, inline="always", fastmath=_FASTMATH)
def end_history(acc, face, w, scatterings, path, h_gain, h_killed, events, capped):
    """The one end of every history, booked in the batch's sums ``acc`` (``float64[tallies.N_SCALARS]``).

    ``face``: the face the photon left by (slab: 0 top, 1 bottom; cylinder: 0) with weight ``w`` after
    ``scatterings`` scatterings and a path ``path``, or -1 (absorbed, killed by roulette, stopped by the
    event cap: ``capped``); ``h_gain, h_killed``: its roulette balance; ``events``: its steps.
    """
    if capped:
        acc[T.S_CAPPED] += 1.0
        acc[T.S_CAPPED_WEIGHT] += w
    if face == 0:
        acc[T.S_EXIT0] += w
        acc[T.S_EXIT0_SQ] += w * w
        if scatterings == 0:
            acc[T.S_UNSCATTERED0] += w
        acc[T.S_PATH_LENGTH] += w * path
    elif face == 1:
        acc[T.S_EXIT1] += w
        acc[T.S_EXIT1_SQ] += w * w
        if scatterings == 0:
            acc[T.S_UNSCATTERED1] += w
        acc[T.S_PATH_LENGTH] += w * path
    acc[T.S_ROULETTE_GAIN] += h_gain
    acc[T.S_ROULETTE_KILLED] += h_killed
    acc[T.S_ROULETTE_NET_SQ] += (h_gain - h_killed) * (h_gain - h_killed)
    acc[T.S_EVENTS] += events
    acc[T.S_SCATTERINGS] += scatterings


@numba.njit(cache=True, inline="always")
def add_totals(scal, acc):
    """Add a batch's sums ``acc`` to the caller's accumulators ``scal`` (both ``float64[tallies.N_SCALARS]``)."""
    for k in range(T.N_SCALARS):
        scal[k] += acc[k]
