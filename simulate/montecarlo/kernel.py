"""The compiled photon-transport kernel (docs/physics.md section 3).

One photon history, in the units of the caller (any consistent length unit), event by event::

    entry      refraction by Snell at the entry point; weight w = 1 - F(theta_i) (the specular
               part F is the surface term: counted, not followed)                    _enter
    step       l = E / mu_t, E ~ Exp(1); a collision when p + l u is strictly inside the
               (convex) shape, else a move of the distance s_b to the boundary         free_path
    collision  implicit capture (absorbed += w mu_a / mu_t, w *= mu_s / mu_t), the vertex
               estimator's score, a new direction from the phase function (:mod:`.scatter`)
                                                                implicit_capture, _at_vertex
    roulette   if w < w_th: survive with probability p and w /= p, else the photon ends
                                                                              roulette_below
    boundary   Fresnel reflection with total internal reflection (or a rough facet, :mod:`.rough`),
               or refraction out and the exit's score             _cross_boundary, _score_exit
    cap        a photon reaching ``max_events`` steps is stopped and counted (a guard only)
    end        the history's tallies flushed, in one place for every history           end_history

The direction update is MCML's (Wang, Jacques & Zheng 1995, eq. 3.23). Each event is a helper of
:mod:`.events` (shared with the slab's two-lane loop, :mod:`.slab_lanes`) or of this module (the
events only this loop has). The helpers are inlined by numba, so the hot state of a history stays in
registers as in a loop written in one piece (docs/notes/implementation.md, "The photon kernel").

Spectral re-weighting ("white" Monte Carlo, wavelength groups): photons walk in the walk medium
``(mu_a^w, mu_s^w, p^w)`` and carry, for each target wavelength ``l``, the likelihood ratio ``A_l`` of
their path: ``(mu_s^l / mu_s^w) exp(-(mu_t^l - mu_t^w) l) p^l(mu) / p^w(mu)`` per collision after a free
path ``l``, ``exp(-(mu_t^l - mu_t^w) s)`` for the last path ``s`` to the boundary. With ``mu_a^w = 0`` and
``p^l = p^w`` this is white Monte Carlo, ``A_l = exp(-mu_a^l L)``; other scattering spectra re-weight
exactly at a variance that grows with the mismatch (callers group wavelengths, :mod:`simulate.fiber`).
The phase ratio is read from a table of cell-averaged ratios, uniform in ``t = sqrt((1 - mu) / 2)``;
the free-path factors are deferred (:data:`REWEIGHT_EVERY`); roulette acts on ``w max_l A_l``.
A dye profile (``medium[M_DYE_PROFILE]``, cylinders) absorbs the dye's part ``mu_d^l`` of ``mu_a^l`` only
along the length of a path in the dyed region (:func:`.geometry.core_length`); it is walked by a flavour
of its own, compiled only when a run places its dye.
A scatterer profile (``medium[M_SCAT_PROFILE]``, cylinders: the scatterers in a skin beyond the radius
``a`` or in a core within it, the rest of the fiber clear) is walked by the same flavour with null
collisions (delta tracking, Woodcock et al. 1965): free paths are drawn at the walk's uniform
``mu_t^w = mu_a^w + mu_s^w``; a collision at a point of the clear region takes the implicit capture of
``mu_a^w`` and goes on in the same direction (a null collision: no scattering, no vertex, no spectral
factor), one in the scattering region scatters. This is exact for piecewise-constant scattering
(analog: absorption ``mu_a / mu_t``, scattering ``mu_s(r) / mu_t``, a null event the rest). The targets
take null collisions at the walk's rate, so along the clear part ``l_c`` of a path their free-path
factor is ``exp(-(mu_a^l - mu_a^w) l_c)`` (:func:`.events.catch_up_placed`).

Public objects: :class:`KernelInputs` (a run's inputs packed once); :func:`simulate_batch` (one batch
of photons on its own random stream ``(seed, batch)``, :mod:`.rng`); :func:`run_batches` (consecutive
batches in parallel, one row each, reduced in batch order by the caller: a fixed seed gives the same
result on any number of threads); :func:`run_rows` (the batches of many runs that differ only in
source row and seed, :mod:`.rows`). Geometry, phase function, tallies and estimators are run-time
switches of one compiled signature, cached on disk under keys that are the same in every process.

References
----------
Wang, L., Jacques, S. L. & Zheng, L. (1995). MCML -- Monte Carlo modeling of light transport
in multi-layered tissues. *Comput. Methods Programs Biomed.* 47, 131-146.
Henyey, L. G. & Greenstein, J. L. (1941). Diffuse radiation in the Galaxy. *Astrophys. J.* 93, 70-83.
Woodcock, E. R., Murphy, T., Hemmings, P. J. & Longworth, T. C. (1965). Techniques used in the GEM code
for Monte Carlo neutronics calculations in reactors and other systems of complex geometry. ANL-7050, 557-579.
"""

from __future__ import annotations

import hashlib
import math
import os
from pathlib import Path
from typing import NamedTuple

import numba
import numpy as np

from simulate.montecarlo import rough as R
from simulate.montecarlo import tallies as T
from simulate.montecarlo.events import (
    C_MAX_EVENTS,
    C_SURVIVAL,
    C_WEIGHT_THRESHOLD,
    M_DYE_PROFILE,
    M_DYE_RADIUS,
    M_G,
    M_MU_A,
    M_MU_S,
    M_N,
    M_PHASE,
    M_ROUGH,
    M_ROUGH_B,
    M_SCAT_PROFILE,
    M_SCAT_RADIUS,
    N_CONTROL,
    N_MEDIUM,
    Walk,
    add_totals,
    catch_up,
    catch_up_dyed,
    catch_up_placed,
    end_history,
    free_path,
    fresnel_reflects,
    implicit_capture,
    largest,
    mirror,
    refract_in,
    refract_out,
    roulette_below,
    walk_constants,
)
from simulate.montecarlo.geometry import (
    CELL,
    SLAB,
    core_length,
    distance_to_boundary,
    entry_point,
    inside,
    outward_normal,
    snap_to_surface,
)
from simulate.montecarlo.rng import next_u64, seed_state, to_uniform
from simulate.montecarlo.scatter import PHASE_HG, PHASE_TABLE, sample_direction
from simulate.montecarlo.slab_lanes import simulate_batch_slab_lanes

__all__ = [
    "PHASE_HG",
    "PHASE_TABLE",
    "M_MU_A",
    "M_MU_S",
    "M_G",
    "M_N",
    "M_PHASE",
    "M_ROUGH",
    "M_ROUGH_B",
    "M_DYE_PROFILE",
    "M_DYE_RADIUS",
    "DYE_UNIFORM",
    "DYE_RING",
    "DYE_CORE",
    "M_SCAT_PROFILE",
    "M_SCAT_RADIUS",
    "SCAT_UNIFORM",
    "SCAT_SKIN",
    "SCAT_CORE",
    "N_MEDIUM",
    "C_WEIGHT_THRESHOLD",
    "C_SURVIVAL",
    "C_MAX_EVENTS",
    "N_CONTROL",
    "KernelInputs",
    "simulate_batch",
    "run_batches",
    "simulate_batch_plain",
    "run_batches_plain",
    "run_batches_for",
    "run_rows",
    "run_rows_for",
    "has_profile",
    "has_scatterer_profile",
]

# numba's 'omp' threading layer (GNU libgomp) spin-waits at the end of every parallel region by
# default. On a machine whose other cores are busy the spinning thread and the one it waits for share
# a core: every kernel call then costs milliseconds of CPU whatever its size, which dominates many
# small calls (docs/notes/implementation.md, "The photon kernel"). Passive threads sleep at the
# barrier; long runs are unaffected. libgomp reads the variable when numba first starts its
# threads, after this import; a value the user set is kept.
# https://gcc.gnu.org/onlinedocs/libgomp/OMP_005fWAIT_005fPOLICY.html
os.environ.setdefault("OMP_WAIT_POLICY", "passive")

# the walk-medium (M_*) and control (C_*) slots are defined with the events that read them (.events)

# dye profiles (M_DYE_PROFILE; module docstring)
DYE_UNIFORM = 0
DYE_RING = 1
DYE_CORE = 2

# scatterer profiles (M_SCAT_PROFILE; module docstring)
SCAT_UNIFORM = 0
SCAT_SKIN = 1
SCAT_CORE = 2

# No 'nnan'/'ninf': infinite free paths (mu_t = 0) and distances are legitimate values.
# (Fast-math 'nsz'/'reassoc' allow no rewrite that turns 0 * _LOG_ZERO into a NaN: it is finite.)
_LOG_ZERO = -1e300

#: Collisions between updates of the spectral weights (and roulette decisions) when no vertex
#: estimator reads them. The medium is homogeneous, so the free-path factors of ``n`` collisions
#: and of the path ``L`` walked since the last update are one factor,
#: ``(mu_s^l / mu_s^w)^n exp(-(mu_t^l - mu_t^w) L) = exp(n ln(mu_s^l / mu_s^w) - (mu_t^l - mu_t^w) L)``:
#: the weights are brought up to date every :data:`REWEIGHT_EVERY` collisions, at every exit, and
#: at every vertex when a vertex estimator reads them; the phase ratios are applied at each
#: collision. Roulette is decided at the updates only -- a roulette rule may depend on anything
#: in the history so far without biasing the estimate, so deciding it every few collisions changes
#: the variance by a hair and nothing else, and saves the exponentials of every collision.
REWEIGHT_EVERY = 8
_FASTMATH = {"nsz", "arcp", "contract", "afn", "reassoc"}

# what _cross_boundary did with a photon besides letting it out by a face (0, 1)
_LOST = -1  # its weight is spent (a rough crossing's factor 0); also "no exit" at the end of a history
_REFLECTED = -2  # it is reflected back inside


class KernelInputs(NamedTuple):
    """Everything a run hands to the compiled kernel, packed once.

    ``spec_*`` describe the ``n_spec >= 1`` target wavelengths (see the module docstring);
    ``reweight`` is False when the targets equal the walk medium (then ``A_l = 1``).
    """

    geometry: int  # geometry.SLAB or geometry.CYLINDER
    geom: np.ndarray  # [d] or [R]
    source: np.ndarray  # [mode, w_x, w_y, w_z, cell half width]
    medium: np.ndarray  # walk medium [mu_a, mu_s, g, n, phase kind]
    table: np.ndarray  # walk phase inverse CDF
    pdf: np.ndarray  # walk phase density per table interval
    lookup: np.ndarray  # walk phase interval index
    control: np.ndarray  # [w_threshold, survival, max_events]
    tally_mode: int
    tally_params: np.ndarray
    vertex_mode: int
    outputs: np.ndarray  # float64[n_out, 8] output ranges (CYLINDER_OUTPUTS and NEE)
    n_exit_bins: int  # geometric exit bins (vertex bins follow them)
    reweight: bool
    spec_mu: np.ndarray  # float64[n_spec, 2]: (mu_a, mu_s) per target wavelength
    phase_ratio: bool  # some target's phase function differs from the walk's
    spec_ratio: np.ndarray  # float64[n_grid, n_spec]: p^l / p^w on the grid t = sqrt((1 - mu)/2) uniform
    nee_consts: np.ndarray  # float64[n_out, tallies.N_NEE]: next-event constants of point outputs


class _Reweighting(NamedTuple):
    """A batch's spectral state (module docstring).

    A batch's spectral state (module docstring): the photon's weights ``spec_w`` (``A_l``) and what
    updates them -- ``log_s = ln(mu_s^l / mu_s^w)``, ``d_mu_t = mu_t^l - mu_t^w``, with a dye profile the
    dye's ``spec_dye = mu_d^l`` and the rest ``d_mu_u = d_mu_t - mu_d^l``, the phase ratios ``ratio`` on
    ``n_grid`` nodes -- and what the tallies read (``spec_mu_t``: the targets' ``mu_t``).

    With a dye profile a free path of length ``l`` of which ``l_d`` lies in the dyed region takes
    ``exp(-(mu_t^l - mu_d^l - mu_t^w) l - mu_d^l l_d)`` instead of ``exp(-(mu_t^l - mu_t^w) l)``: the walk
    itself is unchanged, the dye's absorption is carried by the weights. With a scatterer profile the
    clear part ``l_c`` of the path takes back ``d_mu_s = mu_s^l - mu_s^w`` (:func:`.events.catch_up_placed`).
    """

    reweight: bool
    spec_w: np.ndarray
    log_s: np.ndarray
    d_mu_t: np.ndarray
    d_mu_u: np.ndarray
    spec_dye: np.ndarray
    d_mu_s: np.ndarray
    spec_mu_t: np.ndarray
    phase_ratio: bool
    ratio: np.ndarray
    n_grid: int


@numba.njit(cache=True, inline="always", fastmath=_FASTMATH)
def _reweighting(inp, mu_s, mu_t):
    """The :class:`_Reweighting` of a run for the walk medium's ``mu_s`` and ``mu_t`` (``A_l = 1``)."""
    n_spec = inp.spec_mu.shape[0]
    d_mu_t = np.zeros(n_spec)
    log_s = np.zeros(n_spec)  # a large negative number for mu_s^l = 0
    spec_mu_t = np.zeros(n_spec)
    spec_dye = np.zeros(n_spec)  # the dye's column: profiled runs only (make_inputs checks it)
    d_mu_s = np.zeros(n_spec)
    for l in range(n_spec):
        spec_mu_t[l] = inp.spec_mu[l, 0] + inp.spec_mu[l, 1]
        d_mu_t[l] = spec_mu_t[l] - mu_t
        d_mu_s[l] = inp.spec_mu[l, 1] - mu_s
        s_ratio = inp.spec_mu[l, 1] / mu_s if mu_s > 0.0 else 1.0
        log_s[l] = math.log(s_ratio) if s_ratio > 0.0 else _LOG_ZERO
        if inp.spec_mu.shape[1] > 2:
            spec_dye[l] = inp.spec_mu[l, 2]
    if not inp.reweight:
        spec_mu_t[:] = mu_t
    return _Reweighting(inp.reweight, np.ones(n_spec), log_s, d_mu_t, d_mu_t - spec_dye, spec_dye, d_mu_s, spec_mu_t,
                        inp.phase_ratio, inp.spec_ratio, inp.spec_ratio.shape[0])


@numba.njit(cache=True, inline="always")
def _tally_records(inp, bins, walk, rw):
    """The records the tallies read, packed once a batch.

    The records the tallies read, packed once a batch: the history's scratch tally (:class:`.tallies.Scratch`,
    ``n_spec`` spectral bins per geometric bin of ``bins``), the spectral weights (:class:`.tallies.Spectral`)
    and the vertex estimator's inputs (:class:`.tallies.VertexInputs`, with a private copy of the next-event
    constants: ranged outputs overwrite their row per vertex).
    """
    n_spec = rw.spec_w.shape[0]
    n_blocks = max(bins.shape[0] // n_spec, 1)  # geometric bins
    scratch = T.Scratch(np.zeros(bins.shape[0]), np.zeros(n_blocks, dtype=np.int64), np.zeros(1, dtype=np.int64),
                        np.zeros(n_blocks, dtype=np.bool_), n_spec)
    spectral = T.Spectral(rw.spec_w, rw.spec_mu_t, rw.phase_ratio, rw.ratio)
    vertex = T.VertexInputs(inp.outputs, inp.nee_consts.copy(), np.zeros(T.N_NEE), inp.n_exit_bins, inp.geom[0],
                            walk.n_in, walk.phase, walk.g, inp.table, inp.pdf, inp.lookup)
    return scratch, spectral, vertex


@numba.njit(cache=True, inline="always")
def _beam(geometry, source):
    """A source row unpacked once a batch.

    A source row unpacked once a batch: ``(mode, d_x, d_y, d_z, half width, cell)``, ``d = -w`` the photons'
    direction, ``cell`` for a cell source (launch weight ``cos theta_i``).
    """
    src_mode = int(source[0])
    return src_mode, -source[1], -source[2], -source[3], source[4], geometry != SLAB and src_mode == CELL


# The rough surface's two events are compiled once as functions of their own and called, not inlined:
# numba's inlining of their sizeable code made up about a fifth of the photon loop's compile time, while
# a call (scalars in and out) costs nothing measurable at the rate rough runs make it.
@numba.njit(cache=True, error_model="numpy", fastmath=_FASTMATH)
def _rough_entry(dx, dy, dz, nx, ny, nz, n_in, m_a, m_b, xi1, xi2):
    """:func:`.rough.rough_entry`, called (not inlined)."""
    return R.rough_entry(dx, dy, dz, nx, ny, nz, n_in, m_a, m_b, xi1, xi2)


@numba.njit(cache=True, error_model="numpy", fastmath=_FASTMATH)
def _rough_cross(ux, uy, uz, nx, ny, nz, n1, n2, m_a, m_b, xi1, xi2, xi3):
    """:func:`.rough.rough_cross`, called (not inlined)."""
    return R.rough_cross(ux, uy, uz, nx, ny, nz, n1, n2, m_a, m_b, xi1, xi2, xi3)


@numba.njit(cache=True, inline="always", fastmath=_FASTMATH)
def _enter(geometry, size, beam, walk, acc, absorbed, s0, s1, s2, s3):
    """A photon enters the medium from the source.

    A photon enters from the source ``beam`` (:func:`_beam`): its entry point and direction inside, its
    weight (launch weight x (1 - F), or a rough facet's transmitted part), the launch, specular and entered
    weights booked in ``acc``, a rough entry's balance (its masking loss, signed: one facet's draw may give
    more or less than its mean) in ``absorbed``. ``(x, y, z, ux, uy, uz, w, absorbed, s0, s1, s2, s3)``.
    """
    src_mode, dx, dy, dz, src_h, cell_source = beam
    r, s0, s1, s2, s3 = next_u64(s0, s1, s2, s3)
    x, y, z, nx, ny, nz = entry_point(geometry, size, src_mode, -dx, -dy, -dz, src_h, to_uniform(r))
    cos_i = -(dx * nx + dy * ny + dz * nz)
    w0 = 1.0
    if cell_source:
        w0 = max(cos_i, 0.0)  # irradiance on the surface element, per unit beam irradiance
    t_in = -1.0  # the rough entry's transmitted weight (per unit arriving); < 0: 1 - f_in
    if walk.rough and w0 > 0.0:
        r, s0, s1, s2, s3 = next_u64(s0, s1, s2, s3)
        r2, s0, s1, s2, s3 = next_u64(s0, s1, s2, s3)
        ux, uy, uz, t_in, f_in = _rough_entry(dx, dy, dz, nx, ny, nz, walk.n_in, walk.m_rough, walk.m_rough_b,
                                             to_uniform(r), to_uniform(r2))
    elif walk.contrast and w0 > 0.0:
        ux, uy, uz, f_in = refract_in(dx, dy, dz, nx, ny, nz, cos_i, walk.n_in, walk.eta_in)
    else:
        f_in = 0.0
        ux = dx
        uy = dy
        uz = dz
    acc[T.S_LAUNCH_WEIGHT] += w0
    w = w0 * (1.0 - f_in) if t_in < 0.0 else w0 * t_in
    acc[T.S_SPECULAR] += w0 * f_in  # rough: f_in is the facet's reflected part, masking included
    if t_in >= 0.0:
        absorbed += w0 * (1.0 - t_in - f_in)
    acc[T.S_ENTERED] += w
    return x, y, z, ux, uy, uz, w, absorbed, s0, s1, s2, s3


@numba.njit(cache=True, inline="always", fastmath=_FASTMATH)
def _dyed_length(y, z, uy, uz, s, radius, mode):
    """The part of a path that lies where a dye profile's dye sits.

    The part of a path of length ``s`` from ``(y, z)`` along ``u`` that lies where a dye profile's dye
    sits: within ``radius`` of the axis (``DYE_CORE``) or beyond it (``DYE_RING``).
    """
    inner = core_length(y, z, uy, uz, s, radius)
    return inner if mode == DYE_CORE else s - inner


@numba.njit(cache=True, inline="always", fastmath=_FASTMATH)
def _clear_length(y, z, uy, uz, s, radius, mode):
    """The part of a path that lies where a scatterer profile has no scatterers.

    The part of a path of length ``s`` from ``(y, z)`` along ``u`` that lies in the clear region of a
    scatterer profile: within ``radius`` of the axis (``SCAT_SKIN``) or beyond it (``SCAT_CORE``).
    """
    inner = core_length(y, z, uy, uz, s, radius)
    return inner if mode == SCAT_SKIN else s - inner


@numba.njit(cache=True, inline="always")
def _placement(medium):
    """A profiled run's ``(dye_mode, dye_radius, scat_mode, scat_radius)`` from its medium row."""
    return (int(medium[M_DYE_PROFILE]), medium[M_DYE_RADIUS], int(medium[M_SCAT_PROFILE]),
            medium[M_SCAT_RADIUS])


@numba.njit(cache=True, inline="always", fastmath=_FASTMATH)
def _placed_lengths(place, y, z, uy, uz, s, pend_d, pend_c):
    """The pending dyed and clear lengths after a path of length ``s`` from ``(y, z)`` along ``u``.

    ``place``: the run's ``(dye_mode, dye_radius, scat_mode, scat_radius)``; each profile's length is taken
    only when the run has that profile. ``(pend_d, pend_c)``.
    """
    dye_mode, dye_radius, scat_mode, scat_radius = place
    if dye_mode != DYE_UNIFORM:
        pend_d += _dyed_length(y, z, uy, uz, s, dye_radius, dye_mode)
    if scat_mode != SCAT_UNIFORM:
        pend_c += _clear_length(y, z, uy, uz, s, scat_radius, scat_mode)
    return pend_d, pend_c


@numba.njit(cache=True, inline="always")
def _null_at(place, y, z):
    """Whether a collision at ``(y, z)`` is a null collision.

    The run places its scatterers and the point lies in the clear region (``place`` as in :func:`_placed_lengths`).
    """
    _, _, mode, radius = place
    if mode == SCAT_UNIFORM:
        return False
    r2 = y * y + z * z
    a2 = radius * radius
    return r2 <= a2 if mode == SCAT_SKIN else r2 >= a2


@numba.njit(cache=True, inline="always", fastmath=_FASTMATH)
def _settle(rw, n, length, dyed, clear, profiled):
    """The spectral weights brought up to date (the pending free-path factors).

    The spectral weights brought up to date with the ``n`` collisions and the path ``length`` (``dyed`` of
    it in a dye profile's dyed region, ``clear`` of it in a scatterer profile's clear region) walked since
    their last update (:data:`REWEIGHT_EVERY`).
    """
    if profiled:
        if clear != 0.0:
            catch_up_placed(rw.spec_w, rw.log_s, rw.d_mu_u, rw.spec_dye, rw.d_mu_s, n, length, dyed, clear)
        else:
            catch_up_dyed(rw.spec_w, rw.log_s, rw.d_mu_u, rw.spec_dye, n, length, dyed)
    else:
        catch_up(rw.spec_w, rw.log_s, rw.d_mu_t, n, length)


@numba.njit(cache=True, inline="always", fastmath=_FASTMATH)
def _at_vertex(recs, vertex_mode, p, u, w, step, pend_n, pend_l, state):
    """A collision's vertex, before the new direction: pending factors and the vertex score.

    A collision at ``p`` after a free path ``step``, before the new direction: the free path joins the
    pending spectral factors (``pend_n`` collisions, ``pend_l`` length); a vertex estimator brings the
    weights up to date and scores the vertex (:func:`.tallies.score_vertex`). ``recs``: the batch's
    :class:`_Records`; ``state``: the random stream's four words. ``(pend_n, pend_l, state)``.
    """
    rw = recs.rw
    if rw.reweight:
        pend_n += 1
        pend_l += step
        if vertex_mode == T.V_CYLINDER_NEE:  # the vertex estimator reads spec_w
            catch_up(rw.spec_w, rw.log_s, rw.d_mu_t, pend_n, pend_l)
            pend_n = 0
            pend_l = 0.0
    if vertex_mode == T.V_CYLINDER_NEE:
        state = T.score_vertex(recs.vertex, recs.scratch, recs.spectral, p, u, w, state)
    return pend_n, pend_l, state


@numba.njit(cache=True, inline="always", fastmath=_FASTMATH)
def _after_scattering(rw, ct, pend_n, pend_l, pend_d, pend_c, profiled):
    """The spectral weights after a scattering, and whether roulette is decided now.

    The spectral weights after a scattering by ``ct`` (the cosine of the angle): the phase ratios applied,
    the pending free-path factors settled every :data:`REWEIGHT_EVERY` collisions. Roulette is decided at
    those updates only (any rule is unbiased), on ``w max_l A_l``.
    ``(decide, w_max, pend_n, pend_l, pend_d, pend_c)``.
    """
    if not rw.reweight:
        return True, 1.0, pend_n, pend_l, pend_d, pend_c
    if rw.phase_ratio:
        jr, fr = T.ratio_row(ct, rw.n_grid)
        r0 = rw.ratio[jr]
        r1 = rw.ratio[jr + 1]
        for l in range(rw.spec_w.shape[0]):
            rw.spec_w[l] *= r0[l] + fr * (r1[l] - r0[l])
    if pend_n == 0 or pend_n >= REWEIGHT_EVERY:
        if pend_n > 0:
            _settle(rw, pend_n, pend_l, pend_d, pend_c, profiled)
            pend_n = 0
            pend_l = 0.0
            pend_d = 0.0
            pend_c = 0.0
        return True, largest(rw.spec_w), pend_n, pend_l, pend_d, pend_c
    return False, 1.0, pend_n, pend_l, pend_d, pend_c


@numba.njit(cache=True, inline="always", fastmath=_FASTMATH)
def _cross_boundary(geometry, size, walk, p, u, w, absorbed, state):
    """A photon at the boundary: reflected, let out, or spent.

    A photon at the boundary point ``p`` (snapped onto it) travelling along ``u``: reflected (Fresnel with
    total internal reflection, or a rough facet's choice) or let out (refracted). ``(outcome, x, y, z, ox, oy,
    oz, w, absorbed, s0, s1, s2, s3)``: ``outcome`` is the face it leaves by (0, 1; ``o`` its direction
    outside), :data:`_REFLECTED` (``o`` its new direction inside) or :data:`_LOST`. A rough crossing's weight
    factor is 1 on average less the facets' masking loss; its difference from 1 is booked in ``absorbed``
    (signed), so every photon's balance stays exact. ``state``: the random stream's four words.
    """
    s0, s1, s2, s3 = state
    ux, uy, uz = u
    x, y, z = snap_to_surface(geometry, size, p[0], p[1], p[2], uz)
    nx, ny, nz = outward_normal(geometry, size, x, y, z, uz)
    cos_i = ux * nx + uy * ny + uz * nz
    face = 1 if geometry == SLAB and nz < 0.0 else 0
    if walk.rough:
        r, s0, s1, s2, s3 = next_u64(s0, s1, s2, s3)
        r2, s0, s1, s2, s3 = next_u64(s0, s1, s2, s3)
        r3, s0, s1, s2, s3 = next_u64(s0, s1, s2, s3)
        ox, oy, oz, factor, crossed = _rough_cross(ux, uy, uz, nx, ny, nz, walk.n_in, 1.0, walk.m_rough,
                                                  walk.m_rough_b, to_uniform(r), to_uniform(r2), to_uniform(r3))
        absorbed += w * (1.0 - factor)
        if factor <= 0.0:
            return _LOST, x, y, z, ux, uy, uz, w, absorbed, s0, s1, s2, s3
        w *= factor
        return (face if crossed else _REFLECTED), x, y, z, ox, oy, oz, w, absorbed, s0, s1, s2, s3
    if walk.contrast:
        reflect, s0, s1, s2, s3 = fresnel_reflects(cos_i, walk.n_in, s0, s1, s2, s3)
        if reflect:
            ox, oy, oz = mirror(ux, uy, uz, nx, ny, nz, cos_i, geometry == SLAB)
            return _REFLECTED, x, y, z, ox, oy, oz, w, absorbed, s0, s1, s2, s3
        ox, oy, oz = refract_out(ux, uy, uz, nx, ny, nz, cos_i, walk.n_in)
        return face, x, y, z, ox, oy, oz, w, absorbed, s0, s1, s2, s3
    return face, x, y, z, ux, uy, uz, w, absorbed, s0, s1, s2, s3


@numba.njit(cache=True, inline="always", fastmath=_FASTMATH)
def _score_exit(inp, recs, face, p, o, w, scatterings, pending, profiled):
    """The exit of a photon, scored.

    A photon leaving by ``face`` at ``p`` along ``o`` (outside) with weight ``w``: its spectral weights
    brought up to date (``pending``: the collisions, length, dyed length and clear length walked since their
    last update) and its exit scored (:func:`.tallies.score_exit`).
    """
    rw = recs.rw
    pend_n, pend_l, pend_d, pend_c = pending
    if rw.reweight and (pend_n > 0 or pend_l > 0.0):
        _settle(rw, pend_n, pend_l, pend_d, pend_c, profiled)
    T.score_exit(inp.tally_mode, inp.tally_params, inp.outputs, recs.scratch, rw.spec_w, face, p, o, w, scatterings)


class _Records(NamedTuple):
    """What a batch's photon loop reads besides the run's inputs, packed once a batch.

    The walk's constants (:class:`.events.Walk`), the source (:func:`_beam`), the spectral state
    (:class:`_Reweighting`) and the tallies' records (:func:`_tally_records`).
    """

    walk: Walk
    beam: tuple[int, float, float, float, float, bool]
    rw: _Reweighting
    scratch: T.Scratch
    spectral: T.Spectral
    vertex: T.VertexInputs


@numba.njit(cache=True, inline="always", fastmath=_FASTMATH)
def _transport(scoring, profiled, inp, recs, photons, seed, batch, bins, acc):
    """The photon loop of a batch, one event helper a line (module docstring).

    The histories of ``photons`` photons of stream ``(seed, batch)``, their sums booked in ``acc`` and their
    scores in ``bins``; returns the two sums kept in registers, ``(absorbed, reflections)``. ``scoring`` and
    ``profiled`` are the flavour's constants (:func:`_make_walk`): their branches are pruned from the
    flavours without them.
    """
    walk, beam, rw, scratch = recs.walk, recs.beam, recs.rw, recs.scratch
    geometry = inp.geometry
    size = inp.geom[0]
    place = _placement(inp.medium) if profiled else (DYE_UNIFORM, 0.0, SCAT_UNIFORM, 0.0)
    absorbed = 0.0  # (added to at every collision)
    reflections = 0
    s0, s1, s2, s3 = seed_state(seed, batch)
    for _ in range(photons):
        x, y, z, ux, uy, uz, w, absorbed, s0, s1, s2, s3 = _enter(geometry, size, beam, walk, acc, absorbed,
                                                                  s0, s1, s2, s3)
        h_gain = h_killed = path = pend_l = pend_d = pend_c = 0.0
        # int64, not the literal 0: the counters are arguments of compiled (not inlined) helpers, which
        # type inference would otherwise also compile once for the literal
        events = scatterings = pend_n = np.int64(0)
        face = _LOST
        capped = False
        if scoring and rw.reweight:
            rw.spec_w[:] = 1.0
        alive = w > 0.0
        while alive:
            if events >= walk.max_events:
                capped = True
                break
            events += 1
            step, s0, s1, s2, s3 = free_path(walk.inv_mu_t, s0, s1, s2, s3)
            xn = x + step * ux
            yn = y + step * uy
            zn = z + step * uz
            if inside(geometry, size, xn, yn, zn):  # a collision (the end point is inside: convex shape)
                if profiled:
                    pend_d, pend_c = _placed_lengths(place, y, z, uy, uz, step, pend_d, pend_c)
                x = xn
                y = yn
                z = zn
                path += step
                w, absorbed = implicit_capture(w, absorbed, walk.albedo, walk.absorb)
                if profiled and _null_at(place, y, z):
                    # a null collision (module docstring): straight on, its path pending, no spectral factor
                    pend_l += step if rw.reweight else 0.0
                    alive = w > 0.0
                    continue
                scatterings += 1
                if scoring:
                    pend_n, pend_l, state = _at_vertex(recs, inp.vertex_mode, (x, y, z), (ux, uy, uz), w, step,
                                                       pend_n, pend_l, (s0, s1, s2, s3))
                    s0, s1, s2, s3 = state
                ux, uy, uz, ct, s0, s1, s2, s3 = sample_direction(ux, uy, uz, walk.phase, walk.g, inp.table, walk.hg,
                                                                  s0, s1, s2, s3)
                decide = True
                w_max = 1.0
                if scoring:
                    decide, w_max, pend_n, pend_l, pend_d, pend_c = _after_scattering(rw, ct, pend_n, pend_l, pend_d,
                                                                                     pend_c, profiled)
                if decide:
                    alive, w, h_gain, h_killed, s0, s1, s2, s3 = roulette_below(w, w_max, walk, h_gain, h_killed,
                                                                                s0, s1, s2, s3)
            else:  # the boundary
                s_b = distance_to_boundary(geometry, size, x, y, z, ux, uy, uz)
                if profiled:
                    pend_d, pend_c = _placed_lengths(place, y, z, uy, uz, s_b, pend_d, pend_c)
                x += s_b * ux
                y += s_b * uy
                z += s_b * uz
                path += s_b
                pend_l += s_b
                outcome, x, y, z, ox, oy, oz, w, absorbed, s0, s1, s2, s3 = _cross_boundary(
                    geometry, size, walk, (x, y, z), (ux, uy, uz), w, absorbed, (s0, s1, s2, s3))
                if outcome == _REFLECTED:
                    ux = ox
                    uy = oy
                    uz = oz
                    reflections += 1
                    continue
                face = outcome
                if scoring and face != _LOST:
                    _score_exit(inp, recs, face, (x, y, z), (ox, oy, oz), w, scatterings,
                                (pend_n, pend_l, pend_d, pend_c), profiled)
                break
        end_history(acc, face, w, scatterings, path, h_gain, h_killed, events, capped)
        if scoring:
            T.flush_history(scratch, bins)
    return absorbed, reflections


def _source_stamp() -> int:
    """A hash of every source the compiled kernel is built from (this package and fresnel.py).

    numba's cache checks only the modification time of the file that defines a function, yet
    the cached kernel contains the code of every function it inlines or calls: after a change
    to, say, ``geometry.py`` alone, a worked-in checkout would keep running the old code. The
    stamp is a closure constant of the kernel, and numba keys cached closures by their
    constants, so any change to these sources compiles the kernel afresh.
    """
    digest = hashlib.sha256()
    here = Path(__file__).resolve().parent
    for path in sorted(here.glob("*.py")) + [here.parent / "optics" / "fresnel.py"]:
        digest.update(path.name.encode())
        digest.update(path.read_bytes())
    return int.from_bytes(digest.digest()[:7], "little")


_SOURCE_STAMP = _source_stamp()


def _make_walk(scoring: bool, profiled: bool = False):
    """Compile the photon loop of one flavour (:func:`_transport`; flavours as in :func:`_make_kernel`).

    The loop allocates nothing, so it is compiled without numba's reference counting (``_nrt=False``):
    its event helpers take records that hold arrays, and every such record handed to an inlined helper
    would otherwise cost atomic reference-count updates of each of its arrays, at every event.
    :func:`simulate_batch` allocates and packs the records, then calls the loop once a batch through a
    module global (the cache-key rule of :func:`_make_runner`).
    """
    SCORING = scoring
    PROFILED = profiled and scoring
    STAMP = _SOURCE_STAMP

    @numba.njit(cache=True, error_model="numpy", fastmath=_FASTMATH, _nrt=False)
    def walk_photons(inp, recs, photons, seed, batch, bins, acc):
        if STAMP < 0:  # never: the stamp only keys the cache (see _source_stamp)
            return 0.0, 0
        return _transport(SCORING, PROFILED, inp, recs, photons, seed, batch, bins, acc)

    return walk_photons


_walk_plain = _make_walk(False)
_walk_scoring = _make_walk(True)
_walk_profiled = _make_walk(True, profiled=True)


def _make_kernel(scoring: bool, profiled: bool = False):
    """Compile the kernel for one flavour.

    ``scoring`` False is the plain transport loop (totals and bookkeeping only), True adds the tallies,
    the vertex hook and spectral re-weighting; ``profiled`` (with ``scoring``) adds a dye profile (module
    docstring). Each flavour's photon loop is compiled apart with the others' code pruned
    (:func:`_make_walk`): its mere presence in the loop slows the plain case
    (docs/notes/implementation.md, "The photon kernel"), and a run without a profile runs the loop without
    it, bit for bit. (The plain slab runs in a loop of its own with two photons in flight,
    :mod:`.slab_lanes`; :func:`run_batches_plain` picks it for slab runs.) ``STAMP``
    (:func:`_source_stamp`) keys the cache to the sources the kernel is built from.
    """
    SCORING = scoring
    PROFILED = profiled and scoring
    STAMP = _SOURCE_STAMP

    @numba.njit(cache=True, error_model="numpy", fastmath=_FASTMATH)
    def simulate_batch(inp: KernelInputs, source: np.ndarray, photons: int, seed: int, batch: int,
                       scal: np.ndarray, bins: np.ndarray) -> None:
        """Transport ``photons`` photons of stream ``(seed, batch)``, adding to ``scal`` and ``bins``.

        Parameters
        ----------
        inp : KernelInputs
            The packed run inputs (its ``source`` is not read: ``source`` is).
        source : numpy.ndarray
            ``float64[5]`` source row (``inp.source`` for one run; one row of many for
            :func:`run_rows`, whose rows differ only in their source and seed).
        photons : int
            Photons in this batch.
        seed, batch : int
            Random stream identifiers.
        scal : numpy.ndarray
            ``float64[tallies.N_SCALARS]`` accumulators.
        bins : numpy.ndarray
            ``float64[n_bins_total, 2]`` accumulators (sum, sum of per-photon squares).
        """
        if STAMP < 0:  # never: the stamp only keys the cache (see _source_stamp)
            return
        walk = walk_constants(inp.medium, inp.control)
        rw = _reweighting(inp, inp.medium[M_MU_S], walk.mu_t)
        scratch, spectral, vertex = _tally_records(inp, bins, walk, rw)
        recs = _Records(walk, _beam(inp.geometry, source), rw, scratch, spectral, vertex)
        acc = np.zeros(T.N_SCALARS)  # the batch's sums
        if PROFILED:
            absorbed, reflections = _walk_profiled(inp, recs, photons, seed, batch, bins, acc)
        elif SCORING:
            absorbed, reflections = _walk_scoring(inp, recs, photons, seed, batch, bins, acc)
        else:
            absorbed, reflections = _walk_plain(inp, recs, photons, seed, batch, bins, acc)
        acc[T.S_LAUNCHED] = photons
        acc[T.S_ABSORBED] = absorbed
        acc[T.S_INTERNAL_REFLECTIONS] = reflections
        add_totals(scal, acc)

    return simulate_batch


simulate_batch_plain = _make_kernel(False)
simulate_batch = _make_kernel(True)
simulate_batch_profiled = _make_kernel(True, profiled=True)


def has_profile(inp: KernelInputs) -> bool:
    """The run places its dye or its scatterers (``medium[M_DYE_PROFILE]``, ``medium[M_SCAT_PROFILE]``).

    The profiled flavour walks them.
    """
    return (inp.medium.shape[0] > M_DYE_PROFILE and inp.medium[M_DYE_PROFILE] != DYE_UNIFORM) \
        or has_scatterer_profile(inp)


def has_scatterer_profile(inp: KernelInputs) -> bool:
    """The run places its scatterers (``medium[M_SCAT_PROFILE]``).

    Walked by the profiled flavour even without tallies (the plain loop scatters everywhere).
    """
    return inp.medium.shape[0] > M_SCAT_PROFILE and inp.medium[M_SCAT_PROFILE] != SCAT_UNIFORM


def _make_runner(scoring: bool, profiled: bool = False):
    """The parallel driver of one flavour, calling its :func:`simulate_batch` through a module global.

    Why a global and not the closure of :func:`_make_kernel`: numba keys a cached closure on a
    pickle of its closure cells, and a dispatcher pickles with an id unique to the process, so
    a driver closing over the batch dispatcher would get a new cache key in every process and
    recompile each time (seconds), leaving one more data file in the cache directory per run.
    The closure cells here are plain constants (``SCORING``,
    ``STAMP``), whose pickles are the same in every process; ``SCORING`` selects the global at
    compile time (numba prunes the constant branch). ``tests/simulate/mc/test_kernel_cache.py``
    guards this: a second process must load every kernel from the cache and add no file.
    numba's caching notes: https://numba.readthedocs.io/en/stable/developer/caching.html
    """
    SCORING = scoring
    PROFILED = profiled and scoring
    STAMP = _SOURCE_STAMP

    @numba.njit(cache=True, parallel=True)
    def run_batches(inp: KernelInputs, total_photons: int, batch_size: int, first_batch: int, n_batches: int,
                    seed: int, scal: np.ndarray, bins: np.ndarray) -> None:
        """Run batches ``first_batch .. first_batch + n_batches - 1`` in parallel.

        Batch ``b`` holds photons ``[b * batch_size, min((b + 1) * batch_size, total_photons))``
        and writes row ``b - first_batch`` of ``scal`` (``float64[n_batches, N_SCALARS]``) and of
        ``bins`` (``float64[n_batches, n_bins, 2]``), which are zeroed first.
        """
        if STAMP < 0:  # never: the stamp only keys the cache (see _source_stamp)
            return
        for i in numba.prange(n_batches):
            b = first_batch + i
            start = b * batch_size
            count = min(batch_size, total_photons - start)
            scal[i, :] = 0.0
            bins[i, :, :] = 0.0
            if count > 0:
                if PROFILED:
                    simulate_batch_profiled(inp, inp.source, count, seed, b, scal[i], bins[i])
                elif SCORING:
                    simulate_batch(inp, inp.source, count, seed, b, scal[i], bins[i])
                else:
                    if inp.geometry == SLAB and inp.medium[M_ROUGH] <= 0.0 and inp.medium[M_ROUGH_B] <= 0.0:
                        simulate_batch_slab_lanes(inp, inp.source, count, seed, b, scal[i], bins[i])
                    else:
                        simulate_batch_plain(inp, inp.source, count, seed, b, scal[i], bins[i])

    return run_batches


run_batches_plain = _make_runner(False)
run_batches = _make_runner(True)
#: the dye profile's runner: compiled only when a run places its dye (the others never reference its kernel)
run_batches_profiled = _make_runner(True, profiled=True)


def _make_rows_runner(profiled: bool = False):
    """The parallel driver of many runs that differ only in their source row and seed (:func:`run_rows`).

    Scoring flavour only (its callers, the BSSRDF rows, tally exits). Same cache-key rule as
    :func:`_make_runner`: the closure holds only constants (the stamp, ``PROFILED``).
    """
    PROFILED = profiled
    STAMP = _SOURCE_STAMP

    @numba.njit(cache=True, parallel=True, nogil=True)
    def run_rows(inp: KernelInputs, sources: np.ndarray, seeds: np.ndarray, job_row: np.ndarray,
                 job_batch: np.ndarray, total_photons: int, batch_size: int, scal: np.ndarray,
                 bins: np.ndarray) -> None:
        """Run many runs' batches, one job a row, in parallel.

        Run jobs ``i`` = batch ``job_batch[i]`` of run ``job_row[i]`` (source ``sources[row]``, seed
        ``seeds[row]``, ``total_photons`` photons per run) in parallel, job ``i`` into row ``i`` of
        ``scal`` / ``bins`` (zeroed first). Each job is exactly the batch that :func:`run_batches`
        runs for that run alone: the same stream ``(seed, batch)`` and photons.
        """
        if STAMP < 0:  # never: the stamp only keys the cache (see _source_stamp)
            return
        for i in numba.prange(job_row.shape[0]):
            row = job_row[i]
            b = job_batch[i]
            start = b * batch_size
            count = min(batch_size, total_photons - start)
            scal[i, :] = 0.0
            bins[i, :, :] = 0.0
            if count > 0:
                if PROFILED:
                    simulate_batch_profiled(inp, sources[row], count, seeds[row], b, scal[i], bins[i])
                else:
                    simulate_batch(inp, sources[row], count, seeds[row], b, scal[i], bins[i])

    return run_rows


run_rows = _make_rows_runner()
run_rows_profiled = _make_rows_runner(profiled=True)


def run_rows_for(inp: KernelInputs):
    """The compiled :func:`run_rows` flavour a run needs (the dye profile's when it places its dye)."""
    return run_rows_profiled if has_profile(inp) else run_rows


def run_batches_for(inp: KernelInputs):
    """The compiled :func:`run_batches` flavour a run needs.

    Plain when nothing is tallied and the scatterers are everywhere.
    """
    if has_scatterer_profile(inp):
        return run_batches_profiled
    if inp.tally_mode == T.NONE and inp.vertex_mode == T.V_NONE:
        return run_batches_plain
    return run_batches_profiled if has_profile(inp) else run_batches
