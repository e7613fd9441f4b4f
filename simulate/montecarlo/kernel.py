"""The compiled photon-transport kernel (PHYSICS.md section 3).

One photon history, in the units of the caller (any consistent length unit)::

    entry      refraction by Snell at the entry point; weight w = 1 - F(theta_i)
               (the specular part F is the surface term and is only counted, not followed)
    step       l = E / mu_t with E ~ Exp(1) (ziggurat, :func:`.rng.exponential`); the step is
               a collision when its end point p + l u is strictly inside the (convex) shape,
               otherwise the photon moves the analytic distance s_b to the boundary
    collision  (l < s_b) implicit capture: absorbed += w mu_a / mu_t, w *= mu_s / mu_t;
               new direction from the phase function (Henyey-Greenstein or an inverse-CDF table)
    roulette   if w < w_th: survive with probability p and w /= p, else the photon ends
    boundary   (l >= s_b) unpolarised Fresnel reflectance F(theta) with total internal
               reflection; reflect with probability F, otherwise refract out and tally
    cap        a photon reaching ``max_events`` steps is stopped and counted (a guard only)

Henyey-Greenstein sampling (g != 0), with the constants hoisted out of the loop::

    cos theta = (1 + g^2 - ((1 - g^2) / (1 - g + 2 g xi))^2) / (2 g)

Table sampling: ``j = floor(xi K)``, linear interpolation between ``cos_table[j]`` and
``cos_table[j + 1]`` (``cos_table`` = cos theta at CDF values ``k / K``). The azimuth is
uniform; its cosine and sine come from a point (a, b) uniform in the unit disc (rejection
from the square, both coordinates from one 64-bit draw; no trigonometric calls)::

    cos phi = (a^2 - b^2) / r^2,  sin phi = 2 a b / r^2,  r^2 = a^2 + b^2

(the reciprocal ``1 / r^2`` is computed while ``sin theta`` waits for the HG division and
square root, keeping the dependency chain short). The direction update is the standard one
of MCML (Wang, Jacques & Zheng 1995, eq. 3.23).

Speed (van de Hulst case, one thread): the random state lives in registers (four ``uint64``
locals), the free path needs no logarithm in 98.9 % of the draws (ziggurat), and the
collision test needs no division; with ~3 collisions and one exit per photon the remaining
cost is the square root and division of the MCML update, the HG division and the
mispredicted branches (collision/exit, disc rejection).

Layout: :func:`simulate_batch` runs one batch of photons on its own random stream
``(seed, batch)`` (see :mod:`.rng`) into that batch's accumulators; :func:`run_batches`
runs consecutive batches in parallel (``prange``), each writing its own row, so the
caller can reduce the rows in batch order: results for a fixed seed do not depend on the
number of threads. Both functions have exactly one compiled signature (geometry, phase
function and tally mode are run-time switches), so a fresh clone compiles them once.

References
----------
Wang, L., Jacques, S. L. & Zheng, L. (1995). MCML -- Monte Carlo modeling of light transport
in multi-layered tissues. *Comput. Methods Programs Biomed.* 47, 131-146.
Henyey, L. G. & Greenstein, J. L. (1941). Diffuse radiation in the Galaxy. *Astrophys. J.* 93, 70-83.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from simulate.fresnel import fresnel_unpolarized, refracted_cos
from simulate.montecarlo import tallies as T
from simulate.montecarlo.geometry import (
    SLAB,
    distance_to_boundary,
    entry_point,
    inside,
    outward_normal,
    snap_to_surface,
)
from simulate.montecarlo.rng import exponential, next_u64, seed_state, to_signed_pair, to_uniform

__all__ = [
    "PHASE_HG",
    "PHASE_TABLE",
    "M_MU_A",
    "M_MU_S",
    "M_G",
    "M_N",
    "M_PHASE",
    "N_MEDIUM",
    "C_WEIGHT_THRESHOLD",
    "C_SURVIVAL",
    "C_MAX_EVENTS",
    "N_CONTROL",
    "simulate_batch",
    "run_batches",
]

PHASE_HG = 0
PHASE_TABLE = 1

# medium array slots
M_MU_A = 0
M_MU_S = 1
M_G = 2
M_N = 3
M_PHASE = 4
N_MEDIUM = 5

# control array slots
C_WEIGHT_THRESHOLD = 0
C_SURVIVAL = 1
C_MAX_EVENTS = 2
N_CONTROL = 3

# No 'nnan'/'ninf': infinite free paths (mu_t = 0) and distances are legitimate values.
_FASTMATH = {"nsz", "arcp", "contract", "afn", "reassoc"}


@numba.njit(cache=True, error_model="numpy", fastmath=_FASTMATH)
def simulate_batch(
    photons: int,
    seed: int,
    batch: int,
    geometry: int,
    geom: np.ndarray,
    medium: np.ndarray,
    table: np.ndarray,
    source: np.ndarray,
    control: np.ndarray,
    tally_mode: int,
    tally_params: np.ndarray,
    scal: np.ndarray,
    bins: np.ndarray,
) -> None:
    """Transport ``photons`` photons of stream ``(seed, batch)``, adding to ``scal`` and ``bins``.

    Parameters
    ----------
    photons : int
        Photons in this batch.
    seed, batch : int
        Random stream identifiers.
    geometry : int
        ``geometry.SLAB`` or ``geometry.CYLINDER``.
    geom : numpy.ndarray
        Shape parameters (``[d]`` or ``[R]``).
    medium : numpy.ndarray
        ``[mu_a, mu_s, g, n, phase]`` (slots ``M_*``; ``phase`` is ``PHASE_HG`` or ``PHASE_TABLE``).
    table : numpy.ndarray
        Inverse-CDF table of cos theta (length K + 1 >= 2; ignored for Henyey-Greenstein).
    source : numpy.ndarray
        ``[mode, w_x, w_y, w_z]`` (see :mod:`.geometry`).
    control : numpy.ndarray
        ``[w_threshold, survival_probability, max_events]`` (slots ``C_*``).
    tally_mode : int
        Exit tally mode (see :mod:`.tallies`).
    tally_params : numpy.ndarray
        Its parameters.
    scal : numpy.ndarray
        ``float64[tallies.N_SCALARS]`` accumulators.
    bins : numpy.ndarray
        ``float64[n_bins, 2]`` accumulators.
    """
    mu_a = medium[M_MU_A]
    mu_s = medium[M_MU_S]
    g = medium[M_G]
    n_in = medium[M_N]
    phase = int(medium[M_PHASE])
    mu_t = mu_a + mu_s
    inv_mu_t = 1.0 / mu_t if mu_t > 0.0 else math.inf
    albedo = mu_s / mu_t if mu_t > 0.0 else 0.0
    w_threshold = control[C_WEIGHT_THRESHOLD]
    survival = control[C_SURVIVAL]
    inv_survival = 1.0 / survival
    max_events = int(control[C_MAX_EVENTS])
    contrast = n_in != 1.0
    eta_in = 1.0 / n_in
    dx = -source[1]
    dy = -source[2]
    dz = -source[3]

    hg = phase == PHASE_HG and g != 0.0
    hg_a = 1.0 + g * g
    hg_b = 1.0 - g * g
    hg_c = 1.0 - g
    hg_d = 2.0 * g
    hg_e = 0.5 / g if g != 0.0 else 0.0
    n_table = table.shape[0] - 1
    absorb = 1.0 - albedo

    s0, s1, s2, s3 = seed_state(seed, batch)

    specular = 0.0
    entered = 0.0
    exit0 = 0.0
    exit0_sq = 0.0
    exit1 = 0.0
    exit1_sq = 0.0
    unscattered0 = 0.0
    unscattered1 = 0.0
    absorbed = 0.0
    gain = 0.0
    killed = 0.0
    capped = 0.0
    capped_weight = 0.0
    events_total = 0
    scatterings_total = 0
    reflections_total = 0
    path_total = 0.0

    for _ in range(photons):
        # --- entry: Snell refraction, weight 1 - F ---------------------------------------
        r, s0, s1, s2, s3 = next_u64(s0, s1, s2, s3)
        x, y, z, nx, ny, nz = entry_point(geometry, geom, source, to_uniform(r))
        cos_i = -(dx * nx + dy * ny + dz * nz)
        if contrast:
            f_in = fresnel_unpolarized(cos_i, 1.0, n_in)
            cos_t = refracted_cos(cos_i, 1.0, n_in)
            k = eta_in * cos_i - cos_t
            ux = eta_in * dx + k * nx
            uy = eta_in * dy + k * ny
            uz = eta_in * dz + k * nz
            norm = 1.0 / math.sqrt(ux * ux + uy * uy + uz * uz)
            ux *= norm
            uy *= norm
            uz *= norm
        else:
            f_in = 0.0
            ux = dx
            uy = dy
            uz = dz
        w = 1.0 - f_in
        specular += f_in
        entered += w
        if w <= 0.0:
            continue

        events = 0
        scatterings = 0
        path = 0.0
        while True:
            if events >= max_events:
                capped += 1.0
                capped_weight += w
                break
            events += 1
            e, s0, s1, s2, s3 = exponential(s0, s1, s2, s3)
            step = e * inv_mu_t
            xn = x + step * ux
            yn = y + step * uy
            zn = z + step * uz
            if inside(geometry, geom, xn, yn, zn):
                # --- collision (the end point is inside: convex shape) ------------------
                x = xn
                y = yn
                z = zn
                path += step
                # (a next-event vertex scorer goes here: position, incoming u, w, path)
                absorbed += w * absorb
                w *= albedo
                scatterings += 1
                r, s0, s1, s2, s3 = next_u64(s0, s1, s2, s3)
                xi = to_uniform(r)
                if hg:
                    tmp = hg_b / (hg_c + hg_d * xi)
                    ct = max(-1.0, min(1.0, (hg_a - tmp * tmp) * hg_e))
                elif phase == PHASE_TABLE:
                    t = xi * n_table
                    j = min(int(t), n_table - 1)
                    f = t - j
                    ct = table[j] + f * (table[j + 1] - table[j])
                else:
                    ct = 2.0 * xi - 1.0
                st = math.sqrt(max(1.0 - ct * ct, 0.0))
                while True:
                    r, s0, s1, s2, s3 = next_u64(s0, s1, s2, s3)
                    a, b = to_signed_pair(r)
                    r2 = a * a + b * b
                    if r2 <= 1.0 and r2 > 0.0:
                        break
                inv_r2 = 1.0 / r2  # in parallel with the square root, off the HG chain
                scp = st * ((a * a - b * b) * inv_r2)  # sin(theta) cos(phi)
                ssp = st * (2.0 * a * b * inv_r2)  # sin(theta) sin(phi)
                if abs(uz) > 0.99999:
                    ux = scp
                    uy = ssp
                    uz = ct if uz > 0.0 else -ct
                else:
                    tmp = math.sqrt(1.0 - uz * uz)
                    inv_tmp = 1.0 / tmp
                    nux = (ux * uz * scp - uy * ssp) * inv_tmp + ux * ct
                    nuy = (uy * uz * scp + ux * ssp) * inv_tmp + uy * ct
                    uz = -scp * tmp + uz * ct
                    ux = nux
                    uy = nuy
                if w < w_threshold:
                    if w <= 0.0:
                        break
                    r, s0, s1, s2, s3 = next_u64(s0, s1, s2, s3)
                    if to_uniform(r) < survival:
                        gain += w * (inv_survival - 1.0)
                        w *= inv_survival
                    else:
                        killed += w
                        break
            else:
                # --- boundary --------------------------------------------------------
                s_b = distance_to_boundary(geometry, geom, x, y, z, ux, uy, uz)
                x += s_b * ux
                y += s_b * uy
                z += s_b * uz
                path += s_b
                x, y, z = snap_to_surface(geometry, geom, x, y, z, uz)
                nx, ny, nz = outward_normal(geometry, geom, x, y, z, uz)
                cos_i = ux * nx + uy * ny + uz * nz
                if contrast:
                    f_out = fresnel_unpolarized(cos_i, n_in, 1.0)
                    if f_out > 0.0:
                        if f_out >= 1.0:
                            reflect = True
                        else:
                            r, s0, s1, s2, s3 = next_u64(s0, s1, s2, s3)
                            reflect = to_uniform(r) < f_out
                        if reflect:
                            ux -= 2.0 * cos_i * nx
                            uy -= 2.0 * cos_i * ny
                            uz -= 2.0 * cos_i * nz
                            norm = 1.0 / math.sqrt(ux * ux + uy * uy + uz * uz)
                            ux *= norm
                            uy *= norm
                            uz *= norm
                            reflections_total += 1
                            continue
                    cos_t = refracted_cos(cos_i, n_in, 1.0)
                    k = cos_t - n_in * cos_i
                    wx = n_in * ux + k * nx
                    wy = n_in * uy + k * ny
                    wz = n_in * uz + k * nz
                    norm = 1.0 / math.sqrt(wx * wx + wy * wy + wz * wz)
                    wx *= norm
                    wy *= norm
                    wz *= norm
                else:
                    wx = ux
                    wy = uy
                    wz = uz
                face = 0
                if geometry == SLAB and nz < 0.0:
                    face = 1
                if face == 0:
                    exit0 += w
                    exit0_sq += w * w
                    if scatterings == 0:
                        unscattered0 += w
                else:
                    exit1 += w
                    exit1_sq += w * w
                    if scatterings == 0:
                        unscattered1 += w
                path_total += w * path
                if tally_mode != T.NONE:
                    T.score_exit(tally_mode, tally_params, bins, face, x, y, z, wx, wy, wz, w, path)
                break
        events_total += events
        scatterings_total += scatterings

    scal[T.S_LAUNCHED] += photons
    scal[T.S_SPECULAR] += specular
    scal[T.S_ENTERED] += entered
    scal[T.S_EXIT0] += exit0
    scal[T.S_EXIT0_SQ] += exit0_sq
    scal[T.S_EXIT1] += exit1
    scal[T.S_EXIT1_SQ] += exit1_sq
    scal[T.S_UNSCATTERED0] += unscattered0
    scal[T.S_UNSCATTERED1] += unscattered1
    scal[T.S_ABSORBED] += absorbed
    scal[T.S_ROULETTE_GAIN] += gain
    scal[T.S_ROULETTE_KILLED] += killed
    scal[T.S_CAPPED] += capped
    scal[T.S_CAPPED_WEIGHT] += capped_weight
    scal[T.S_EVENTS] += events_total
    scal[T.S_SCATTERINGS] += scatterings_total
    scal[T.S_INTERNAL_REFLECTIONS] += reflections_total
    scal[T.S_PATH_LENGTH] += path_total


@numba.njit(cache=True, parallel=True)
def run_batches(
    total_photons: int,
    batch_size: int,
    first_batch: int,
    n_batches: int,
    seed: int,
    geometry: int,
    geom: np.ndarray,
    medium: np.ndarray,
    table: np.ndarray,
    source: np.ndarray,
    control: np.ndarray,
    tally_mode: int,
    tally_params: np.ndarray,
    scal: np.ndarray,
    bins: np.ndarray,
) -> None:
    """Run batches ``first_batch .. first_batch + n_batches - 1`` in parallel.

    Batch ``b`` holds photons ``[b * batch_size, min((b + 1) * batch_size, total_photons))``
    and writes row ``b - first_batch`` of ``scal`` (``float64[n_batches, N_SCALARS]``) and of
    ``bins`` (``float64[n_batches, n_bins, 2]``), which are zeroed first.
    """
    for i in numba.prange(n_batches):
        b = first_batch + i
        start = b * batch_size
        count = min(batch_size, total_photons - start)
        scal[i, :] = 0.0
        bins[i, :, :] = 0.0
        if count > 0:
            simulate_batch(
                count, seed, b, geometry, geom, medium, table, source, control,
                tally_mode, tally_params, scal[i], bins[i],
            )
