"""The photon kernel's events, one compiled helper each: entry, boundary, roulette and the deferred weights.

Each helper is what happens to one photon at one event of its history (docs/physics.md section 3;
the order of events in :mod:`.kernel`'s module docstring), written once and called by both photon loops:
:func:`.kernel.simulate_batch` (every geometry, tallies and spectral targets) and
:func:`.slab_lanes.simulate_batch_slab_lanes` (the plain slab, two photons in flight).

* :func:`refract_in`: a smooth entry (Snell), the entering direction and the reflected fraction;
* :func:`implicit_capture`: the absorbed part of a photon's weight at a collision;
* :func:`fresnel_reflects`: whether a photon meeting the smooth boundary from inside is reflected
  (Fresnel, total internal reflection included), drawing only when the answer is not certain;
* :func:`mirror` and :func:`refract_out`: its new direction, reflected or leaving;
* :func:`roulette`: Russian roulette of a photon whose weight fell below the threshold;
* :func:`catch_up` and :func:`catch_up_dyed`: the spectral weights brought up to date with the
  free paths walked since their last update (:data:`.kernel.REWEIGHT_EVERY`), without and with a
  dye profile; :func:`largest`: the largest of them, which roulette reads.

The helpers take and return scalars (the random stream's four words included), so that inlined
(``inline="always"``: numba inlines them in its own IR before LLVM sees the loop) they leave the hot
state of a history in registers, as the loop written out in one piece did; the compiled loops and
their results at a fixed seed are those of that piece, bit for bit.
"""

from __future__ import annotations

import math

import numba

from simulate.montecarlo.rng import next_u64, to_uniform
from simulate.montecarlo.vecmath import vexp
from simulate.optics.fresnel import fresnel_unpolarized, refracted_cos

__all__ = ["refract_in", "implicit_capture", "fresnel_reflects", "mirror", "refract_out", "roulette", "catch_up", "catch_up_dyed",
           "largest"]

_FASTMATH = {"nsz", "arcp", "contract", "afn", "reassoc"}  # as kernel._FASTMATH


@numba.njit(cache=True, inline="always", fastmath=_FASTMATH)
def refract_in(dx, dy, dz, nx, ny, nz, cos_i, n_in, eta_in):
    """A smooth entry from outside (index 1) into index ``n_in`` (``eta_in = 1 / n_in``) along ``d``, at a
    surface of outward normal ``n`` with ``cos_i = -d . n``: ``(ux, uy, uz, f_in)``, the unit refracted
    direction and the Fresnel reflectance (unpolarised) that the entering weight loses."""
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
    """Implicit capture at a collision: the absorbed part ``w mu_a / mu_t`` (``absorb``) of the weight ``w``
    booked, the photon going on with ``w mu_s / mu_t`` (``albedo``). ``(w, absorbed)``."""
    return w * albedo, absorbed + w * absorb


@numba.njit(cache=True, inline="always", fastmath=_FASTMATH)
def fresnel_reflects(cos_i, n_in, s0, s1, s2, s3):
    """Whether a photon inside (index ``n_in``) meeting the smooth boundary at ``cos_i`` is reflected:
    ``(reflect, s0, s1, s2, s3)``. Reflected with the Fresnel probability; certain beyond the critical
    angle and impossible when the reflectance is 0, and then no random number is drawn."""
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
    """The direction ``u`` reflected at a surface of normal ``n`` (``cos_i = u . n``); ``flat``: a face
    ``z = const``, whose mirror image is exact (``u_z`` negated)."""
    if flat:
        return ux, uy, -uz
    ux -= 2.0 * cos_i * nx
    uy -= 2.0 * cos_i * ny
    uz -= 2.0 * cos_i * nz
    norm = 1.0 / math.sqrt(ux * ux + uy * uy + uz * uz)
    return ux * norm, uy * norm, uz * norm


@numba.njit(cache=True, inline="always", fastmath=_FASTMATH)
def refract_out(ux, uy, uz, nx, ny, nz, cos_i, n_in):
    """The unit direction of a photon leaving index ``n_in`` for index 1 along ``u`` through a surface of
    outward normal ``n`` (``cos_i = u . n``, below the critical angle)."""
    cos_t = refracted_cos(cos_i, n_in, 1.0)
    k = cos_t - n_in * cos_i
    wx = n_in * ux + k * nx
    wy = n_in * uy + k * ny
    wz = n_in * uz + k * nz
    norm = 1.0 / math.sqrt(wx * wx + wy * wy + wz * wz)
    return wx * norm, wy * norm, wz * norm


@numba.njit(cache=True, inline="always", fastmath=_FASTMATH)
def roulette(w, h_gain, h_killed, survival, inv_survival, s0, s1, s2, s3):
    """Russian roulette of a photon of weight ``w > 0`` below the threshold: it survives with probability
    ``survival`` and its weight is divided by it. ``(alive, w, h_gain, h_killed, s0, s1, s2, s3)``: the
    history's roulette gain and killed weight (its balance) updated."""
    r, s0, s1, s2, s3 = next_u64(s0, s1, s2, s3)
    if to_uniform(r) < survival:
        return True, w * inv_survival, h_gain + w * (inv_survival - 1.0), h_killed, s0, s1, s2, s3
    return False, w, h_gain, h_killed + w, s0, s1, s2, s3


@numba.njit(cache=True, inline="always", fastmath=_FASTMATH)
def catch_up(spec_w, log_s, d_mu_t, n, length):
    """The spectral weights times the free-path factors of ``n`` collisions over the path ``length`` walked
    since their last update: ``A_l *= exp(n ln(mu_s^l / mu_s^w) - (mu_t^l - mu_t^w) length)`` (one
    vectorised exponential per wavelength, :func:`.vecmath.vexp`)."""
    for l in range(spec_w.shape[0]):
        spec_w[l] *= vexp(n * log_s[l] - d_mu_t[l] * length)


@numba.njit(cache=True, inline="always", fastmath=_FASTMATH)
def catch_up_dyed(spec_w, log_s, d_mu_u, spec_dye, n, length, dyed):
    """:func:`catch_up` with a dye profile: the dye's absorption ``spec_dye`` taken along the part ``dyed``
    of the path in the dyed region, the rest of the difference ``d_mu_u`` along the whole ``length``."""
    for l in range(spec_w.shape[0]):
        spec_w[l] *= vexp(n * log_s[l] - d_mu_u[l] * length - spec_dye[l] * dyed)


@numba.njit(cache=True, inline="always", fastmath=_FASTMATH)
def largest(spec_w):
    """The largest spectral weight (roulette acts on ``w max_l A_l``)."""
    w_max = 0.0
    for l in range(spec_w.shape[0]):
        w_max = max(w_max, spec_w[l])
    return w_max
