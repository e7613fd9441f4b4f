"""The plain slab loop with two photons in flight: the slab's own batch kernel (for speed).

The photon loop of :mod:`.kernel` is bound by latency: each step of a photon waits for the one
before (the direction update feeds the next free path, whose end point decides the branch), so a
core runs one photon's chain at a time and leaves most of its execution units idle. Here a batch's
photons are split between two independent *lanes*, and every turn of the loop advances each lane
by one event; the two chains interleave, the core overlaps them (the gain, measured:
docs/notes/implementation.md, "The photon kernel").

The physics is that of the kernel's plain slab path, event for event (module docstring of
:mod:`.kernel`), and its events are the kernel's own helpers, inlined (:mod:`.events`: the walk's
constants, the smooth entry, implicit capture, the Fresnel decision, the mirror image, roulette;
:func:`.scatter.sample_direction`). The loop itself is written in one piece, its sums in registers: the
free path, the roulette threshold and the end of a history written as the kernel's helpers cost this loop
a few per cent (docs/notes/implementation.md, "The photon kernel"). Only ``u_z`` is carried: nothing of a
plain slab run reads ``u_x, u_y``, and the code that would compute them is dead and left out by the compiler.

What differs is which random numbers a photon gets: lane 0 of batch ``b`` draws from stream
``(seed, b)``, lane 1 from stream ``(seed, b + LANE_OFFSET)`` (:mod:`.rng`), each lane takes every
photon it can until its share (``ceil(n/2)``, ``floor(n/2)``) is done, and the slab entry needs no
draw (every photon enters at the origin). So a seed gives other photons than the scoring kernel
would (statistically the same; identical for any thread count), and the plain slab spends no
draw per photon on an entry point it does not use.

Only the plain slab (no tallies, no vertex estimator, no spectral targets) runs here; every
other run keeps :func:`.kernel.simulate_batch`.
"""

from __future__ import annotations

import numba
import numpy as np

from simulate.montecarlo import tallies as T
from simulate.montecarlo.events import fresnel_reflects, implicit_capture, mirror, refract_in, roulette, walk_constants
from simulate.montecarlo.rng import exponential, seed_state
from simulate.montecarlo.scatter import sample_direction

__all__ = ["LANE_OFFSET", "simulate_batch_slab_lanes"]

#: lane 1 of batch ``b`` uses stream ``(seed, b + LANE_OFFSET)`` (batches stay far below it)
LANE_OFFSET = 1 << 62

_FASTMATH = {"nsz", "arcp", "contract", "afn", "reassoc"}  # as kernel._FASTMATH


@numba.njit(cache=True, inline="always", fastmath=_FASTMATH)
def _slab_entry(walk, source):
    """The entry of every photon of a plain slab run.

    At the origin of the top face (normal +z), along ``-w`` (``w = source[1:4]``): ``(u_z, f_in)``, the
    direction's ``z`` component inside and the reflected fraction.
    """
    dx = -source[1]
    dy = -source[2]
    dz = -source[3]
    if walk.contrast:
        _, _, uz0, f_in = refract_in(dx, dy, dz, 0.0, 0.0, 1.0, -dz, walk.n_in, walk.eta_in)
        return uz0, f_in
    return dz, 0.0


@numba.njit(cache=True, error_model="numpy", fastmath=_FASTMATH)
def simulate_batch_slab_lanes(inp, source: np.ndarray, photons: int, seed: int, batch: int,  # noqa: C901 (one loop)
                              scal: np.ndarray, bins: np.ndarray) -> None:
    """Transport ``photons`` photons of batch ``batch`` through the plain slab, adding to ``scal``.

    The signature of :func:`.kernel.simulate_batch` (``inp`` a :class:`.kernel.KernelInputs` of a
    slab with no tallies; ``bins`` is not written).
    """
    walk = walk_constants(inp.medium, inp.control)
    # the walk's constants as locals: the loop below is written in one piece (module docstring)
    inv_mu_t, albedo, absorb, n_in, contrast = walk.inv_mu_t, walk.albedo, walk.absorb, walk.n_in, walk.contrast
    phase, g, hg, table, size = walk.phase, walk.g, walk.hg, inp.table, inp.geom[0]
    w_threshold, survival, inv_survival, max_events = walk.w_threshold, walk.survival, walk.inv_survival, walk.max_events
    uz0, f_in = _slab_entry(walk, source)  # the same for every photon
    w_in = 1.0 - f_in
    if not w_in > 0.0:  # no light enters (never for an incidence below 90 degrees)
        scal[T.S_LAUNCHED] += photons
        scal[T.S_LAUNCH_WEIGHT] += photons
        scal[T.S_SPECULAR] += photons * f_in
        return

    launched = 0.0
    exit0 = 0.0
    exit0_sq = 0.0
    exit1 = 0.0
    exit1_sq = 0.0
    unscattered0 = 0.0
    unscattered1 = 0.0
    absorbed = 0.0
    gain = 0.0
    killed = 0.0
    net_sq = 0.0
    capped = 0.0
    capped_weight = 0.0
    events_total = 0
    scatterings_total = 0
    reflections_total = 0
    path_total = 0.0

    # the current lane (z, uz, w, ..., s0..s3) and the other one (zo, uzo, wo, ..., t0..t3): every turn
    # runs one event of the current lane's photon, then the two swap (module docstring)
    s0, s1, s2, s3 = seed_state(seed, batch)
    t0, t1, t2, t3 = seed_state(seed, batch + LANE_OFFSET)
    left = (photons + 1) // 2
    lefto = photons // 2
    z, uz, w, events, scat, path, h_gain, h_killed = 0.0, uz0, w_in, 0, 0, 0.0, 0.0, 0.0
    zo, uzo, wo, evo, sco, po, go, ko = 0.0, uz0, w_in, 0, 0, 0.0, 0.0, 0.0
    active = left > 0
    activeo = lefto > 0
    if active:  # each active lane holds a photon that has entered (counted when it starts)
        left -= 1
        launched += 1.0
    if activeo:
        lefto -= 1
        launched += 1.0
    while active:
        end = False
        exit_face = -1
        if events >= max_events:
            capped += 1.0
            capped_weight += w
            end = True
        else:
            events += 1
            e, s0, s1, s2, s3 = exponential(s0, s1, s2, s3)
            step = e * inv_mu_t
            zn = z + step * uz
            if zn < 0.0 and zn > -size:
                # --- collision: implicit capture, new direction (MCML update, u_z only), roulette ----
                z = zn
                path += step
                w, absorbed = implicit_capture(w, absorbed, albedo, absorb)
                scat += 1
                # u_z of the new direction depends on u_z alone: the lanes carry no u_x, u_y (0 here)
                _, _, uz, _, s0, s1, s2, s3 = sample_direction(0.0, 0.0, uz, phase, g, table, hg, s0, s1, s2, s3)
                if w < w_threshold:
                    if w <= 0.0:
                        end = True
                    else:
                        alive, w, h_gain, h_killed, s0, s1, s2, s3 = roulette(w, h_gain, h_killed, survival,
                                                                              inv_survival, s0, s1, s2, s3)
                        end = not alive
            else:
                # --- boundary: the face u_z points to; Fresnel reflection or exit -----------------
                if uz > 0.0:
                    s_b = max(-z, 0.0) / uz
                    z = 0.0
                    cos_i = uz
                    face = 0
                else:  # u_z < 0 (a step along u_z = 0 stays inside)
                    s_b = min(-size - z, 0.0) / uz
                    z = -size
                    cos_i = -uz
                    face = 1
                path += s_b
                reflect = False
                if contrast:
                    reflect, s0, s1, s2, s3 = fresnel_reflects(cos_i, n_in, s0, s1, s2, s3)
                if reflect:
                    _, _, uz = mirror(0.0, 0.0, uz, 0.0, 0.0, 1.0, cos_i, True)  # a face z = const: u_z negated
                    reflections_total += 1
                else:
                    exit_face = face
                    end = True
        if end:
            # --- the one end of every history: flush, then the lane's next photon enters --------
            if exit_face == 0:
                exit0 += w
                exit0_sq += w * w
                if scat == 0:
                    unscattered0 += w
                path_total += w * path
            elif exit_face == 1:
                exit1 += w
                exit1_sq += w * w
                if scat == 0:
                    unscattered1 += w
                path_total += w * path
            gain += h_gain
            killed += h_killed
            net_sq += (h_gain - h_killed) * (h_gain - h_killed)
            events_total += events
            scatterings_total += scat
            if left > 0:
                left -= 1
                launched += 1.0
                z, uz, w, events, scat, path, h_gain, h_killed = 0.0, uz0, w_in, 0, 0, 0.0, 0.0, 0.0
            else:
                active = False
        if activeo:  # the other lane's turn
            z, zo = zo, z
            uz, uzo = uzo, uz
            w, wo = wo, w
            events, evo = evo, events
            scat, sco = sco, scat
            path, po = po, path
            h_gain, go = go, h_gain
            h_killed, ko = ko, h_killed
            left, lefto = lefto, left
            active, activeo = activeo, active
            s0, t0 = t0, s0
            s1, t1 = t1, s1
            s2, t2 = t2, s2
            s3, t3 = t3, s3

    scal[T.S_LAUNCHED] += launched
    scal[T.S_LAUNCH_WEIGHT] += launched
    scal[T.S_SPECULAR] += launched * f_in
    scal[T.S_ENTERED] += launched * w_in
    scal[T.S_EXIT0] += exit0
    scal[T.S_EXIT0_SQ] += exit0_sq
    scal[T.S_EXIT1] += exit1
    scal[T.S_EXIT1_SQ] += exit1_sq
    scal[T.S_UNSCATTERED0] += unscattered0
    scal[T.S_UNSCATTERED1] += unscattered1
    scal[T.S_ABSORBED] += absorbed
    scal[T.S_ROULETTE_GAIN] += gain
    scal[T.S_ROULETTE_KILLED] += killed
    scal[T.S_ROULETTE_NET_SQ] += net_sq
    scal[T.S_CAPPED] += capped
    scal[T.S_CAPPED_WEIGHT] += capped_weight
    scal[T.S_EVENTS] += events_total
    scal[T.S_SCATTERINGS] += scatterings_total
    scal[T.S_INTERNAL_REFLECTIONS] += reflections_total
    scal[T.S_PATH_LENGTH] += path_total
