"""The plain slab loop with two photons in flight: the slab's own batch kernel (for speed).

The photon loop of :mod:`.kernel` is bound by latency: each step of a photon waits for the one
before (the direction update feeds the next free path, whose end point decides the branch), so a
core runs one photon's chain at a time and leaves most of its execution units idle. Here a batch's
photons are split between two independent *lanes*, and every turn of the loop advances each lane
by one event; the two chains interleave, the core overlaps them (the gain, measured:
docs/notes/implementation.md, "The photon kernel").

The physics is that of the kernel's plain slab path, event for event (module docstring of
:mod:`.kernel`), and its events are the kernel's own helpers, inlined (:mod:`.events`: the walk's
constants, the free path, the smooth entry, implicit capture, the Fresnel decision, the mirror image,
roulette, the end of a history and the batch's sums; :func:`.scatter.sample_direction`). Only the way to
the boundary is the slab's own (:func:`_slab_face`), and only ``u_z`` is carried: nothing of a plain slab
run reads ``u_x, u_y``, and the code that would compute them is dead and left out by the compiler.

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
from simulate.montecarlo.events import (
    add_totals,
    end_history,
    free_path,
    fresnel_reflects,
    implicit_capture,
    mirror,
    refract_in,
    roulette_below,
    walk_constants,
)
from simulate.montecarlo.rng import seed_state
from simulate.montecarlo.scatter import sample_direction

__all__ = ["LANE_OFFSET", "simulate_batch_slab_lanes"]

#: lane 1 of batch ``b`` uses stream ``(seed, b + LANE_OFFSET)`` (batches stay far below it)
LANE_OFFSET = 1 << 62

_FASTMATH = {"nsz", "arcp", "contract", "afn", "reassoc"}  # as kernel._FASTMATH


@numba.njit(cache=True, inline="always", fastmath=_FASTMATH)
def _slab_face(z, uz, size):
    """The way of a slab photon to the face it points to.

    A photon at depth ``z`` travelling along ``u_z != 0`` to the face it points to: ``(s_b, z, cos_i,
    face)``, the distance, the face's depth, the cosine with its outward normal and the face (0 top,
    1 bottom); the slab's case of :func:`.geometry.distance_to_boundary` and :func:`.geometry.snap_to_surface`.
    """
    if uz > 0.0:
        return max(-z, 0.0) / uz, 0.0, uz, 0
    return min(-size - z, 0.0) / uz, -size, -uz, 1


@numba.njit(cache=True, error_model="numpy", fastmath=_FASTMATH)
def simulate_batch_slab_lanes(inp, source: np.ndarray, photons: int, seed: int, batch: int,
                              scal: np.ndarray, bins: np.ndarray) -> None:
    """Transport ``photons`` photons of batch ``batch`` through the plain slab, adding to ``scal``.

    The signature of :func:`.kernel.simulate_batch` (``inp`` a :class:`.kernel.KernelInputs` of a
    slab with no tallies; ``bins`` is not written).
    """
    walk = walk_constants(inp.medium, inp.control)
    size = inp.geom[0]
    # the entry is the same for every photon: at the origin of the top face (normal +z), along -w
    dx = -source[1]
    dy = -source[2]
    dz = -source[3]
    cos_i = -dz
    if walk.contrast:
        _, _, uz0, f_in = refract_in(dx, dy, dz, 0.0, 0.0, 1.0, cos_i, walk.n_in, walk.eta_in)
    else:
        f_in = 0.0
        uz0 = dz
    w_in = 1.0 - f_in
    if not w_in > 0.0:  # no light enters (never for an incidence below 90 degrees)
        scal[T.S_LAUNCHED] += photons
        scal[T.S_LAUNCH_WEIGHT] += photons
        scal[T.S_SPECULAR] += photons * f_in
        return

    acc = np.zeros(T.N_SCALARS)  # the batch's sums (events.end_history)
    absorbed = 0.0
    reflections = 0
    launched = 0.0
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
        capped = False
        exit_face = -1
        if events >= walk.max_events:
            capped = True
            end = True
        else:
            events += 1
            step, s0, s1, s2, s3 = free_path(walk.inv_mu_t, s0, s1, s2, s3)
            zn = z + step * uz
            if zn < 0.0 and zn > -size:
                # --- collision: implicit capture, new direction (MCML update, u_z only), roulette ----
                z = zn
                path += step
                w, absorbed = implicit_capture(w, absorbed, walk.albedo, walk.absorb)
                scat += 1
                # u_z of the new direction depends on u_z alone: the lanes carry no u_x, u_y (0 here)
                _, _, uz, _, s0, s1, s2, s3 = sample_direction(0.0, 0.0, uz, walk.phase, walk.g, inp.table, walk.hg,
                                                               s0, s1, s2, s3)
                alive, w, h_gain, h_killed, s0, s1, s2, s3 = roulette_below(w, 1.0, walk, h_gain, h_killed,
                                                                            s0, s1, s2, s3)
                end = not alive
            else:
                # --- boundary: the face u_z points to (a step along u_z = 0 stays inside); Fresnel or exit
                s_b, z, cos_i, face = _slab_face(z, uz, size)
                path += s_b
                reflect = False
                if walk.contrast:
                    reflect, s0, s1, s2, s3 = fresnel_reflects(cos_i, walk.n_in, s0, s1, s2, s3)
                if reflect:
                    _, _, uz = mirror(0.0, 0.0, uz, 0.0, 0.0, 1.0, cos_i, True)  # a face z = const: u_z negated
                    reflections += 1
                else:
                    exit_face = face
                    end = True
        if end:
            # --- the one end of every history, then the lane's next photon enters -------------------
            end_history(acc, exit_face, w, scat, path, h_gain, h_killed, events, capped)
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

    acc[T.S_LAUNCHED] = launched
    acc[T.S_LAUNCH_WEIGHT] = launched
    acc[T.S_SPECULAR] = launched * f_in
    acc[T.S_ENTERED] = launched * w_in
    acc[T.S_ABSORBED] = absorbed
    acc[T.S_INTERNAL_REFLECTIONS] = reflections
    add_totals(scal, acc)
