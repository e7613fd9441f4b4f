"""The compiled photon-transport kernel (docs/physics.md section 3).

One photon history, in the units of the caller (any consistent length unit)::

    entry      refraction by Snell at the entry point; weight w = 1 - F(theta_i)
               (the specular part F is the surface term and is only counted, not followed)
    step       l = E / mu_t with E ~ Exp(1) (ziggurat, :func:`.rng.exponential`); the step is
               a collision when its end point p + l u is strictly inside the (convex) shape,
               otherwise the photon moves the analytic distance s_b to the boundary
    collision  (l < s_b) implicit capture: absorbed += w mu_a / mu_t, w *= mu_s / mu_t;
               new direction from the phase function (:mod:`.scatter`: Henyey-Greenstein or
               an inverse-CDF table; azimuth from a table, no trigonometric call)
    roulette   if w < w_th: survive with probability p and w /= p, else the photon ends
    boundary   (l >= s_b) unpolarised Fresnel reflectance F(theta) with total internal
               reflection; reflect with probability F, otherwise refract out and tally
    cap        a photon reaching ``max_events`` steps is stopped and counted (a guard only)

The direction update is MCML's (Wang, Jacques & Zheng 1995, eq. 3.23). The loop reads as the list
above: each event is a helper of :mod:`.events` (entry, Fresnel decision, reflection, exit, roulette,
the deferred spectral weights), shared with the slab's two-lane loop (:mod:`.slab_lanes`). The helpers
take and return scalars and are inlined into the loop by numba, so the hot state of a history stays in
registers as in a loop written in one piece (a loop split into called functions is slower:
docs/notes/implementation.md, "The photon kernel").

Public objects: :class:`KernelInputs` (a run's inputs packed once: geometry, source, walk medium
and phase arrays, control, tallies, spectral targets); :func:`simulate_batch` (one batch of photons
on its own random stream ``(seed, batch)``, :mod:`.rng`); :func:`run_batches` (consecutive batches
in parallel, one row each, reduced in batch order by the caller: a fixed seed gives the same
result on any number of threads); :func:`run_rows` (the batches of many runs that differ only in
source row and seed, :mod:`.rows`). Geometry, phase function, tallies and estimators are run-time
switches of one compiled signature, cached on disk under keys that are the same in every process
(:func:`_make_runner`). Every history ends in one place that flushes its tallies (the estimator
contract of :mod:`.tallies`).

Spectral re-weighting ("white" Monte Carlo and wavelength groups): photons walk in the walk
medium ``(mu_a^w, mu_s^w, p^w)``; for each target wavelength ``l`` with ``(mu_a^l, mu_s^l, p^l)``
a photon carries the likelihood ratio ``A_l`` of its path::

    collision after a free path l, scattering by mu:  A_l *= (mu_s^l / mu_s^w) exp(-(mu_t^l - mu_t^w) l)
                                                      A_l *= p^l(mu) / p^w(mu)   (new direction)
    boundary reached after s:                         A_l *= exp(-(mu_t^l - mu_t^w) s)

(implicit capture makes the walk's weight-density of a collision segment ``mu_s^w exp(-mu_t^w l)``).
The phase ratio ``p^l / p^w`` is read from a table of cell-averaged ratios on a grid uniform in
``t = sqrt((1 - mu) / 2)`` (dense in the forward peak; 1025 nodes, linear interpolation, every
wavelength's value on one cache line), so a collision costs one look-up for all wavelengths
instead of one table search per wavelength; it re-weights towards the cell-averaged target
density, which differs from the target's own sampling table only by that table's
discretisation.
With ``mu_a^w = 0`` and ``p^l = p^w`` this is exactly white Monte Carlo, ``A_l = exp(-mu_a^l L)``
(absorption applied afterwards along the path length ``L``); different scattering spectra
re-weight exactly too, at a variance that grows with the mismatch (callers group
wavelengths, :mod:`simulate.fiber`). Roulette acts on ``w max_l A_l``.

Dye profile (``medium[M_DYE_PROFILE]``, cylinders, re-weighted runs only): the targets' dye absorption
``mu_d^l`` (``spec_mu[l, 2]``, a part of ``mu_a^l``) absorbs only where the dye sits -- beyond the radius
``a = medium[M_DYE_RADIUS]`` (a ring dye) or within it (a dyed core) -- so a free path of length ``l`` of
which ``l_d`` lies in the dyed region takes ``exp(-(mu_t^l - mu_d^l - mu_t^w) l - mu_d^l l_d)`` instead of
``exp(-(mu_t^l - mu_t^w) l)``; ``l_d`` is the exact chord of the straight path with the inner circle
(:func:`.geometry.core_length`). The walk itself is unchanged: absorption is carried by the weights. A profile
is walked by a flavour of its own (:func:`_make_kernel`, with its own runners, compiled only when a run places
its dye), so a run without one runs the loop without it.

The free-path factors are deferred: they are brought up to date every :data:`REWEIGHT_EVERY`
collisions (see there), at every exit and at every vertex a vertex estimator reads.

References
----------
Wang, L., Jacques, S. L. & Zheng, L. (1995). MCML -- Monte Carlo modeling of light transport
in multi-layered tissues. *Comput. Methods Programs Biomed.* 47, 131-146.
Henyey, L. G. & Greenstein, J. L. (1941). Diffuse radiation in the Galaxy. *Astrophys. J.* 93, 70-83.
"""

from __future__ import annotations

import hashlib
import math
import os
from pathlib import Path
from typing import NamedTuple

import numba
import numpy as np

from simulate.montecarlo import tallies as T
from simulate.montecarlo.events import (catch_up, catch_up_dyed, fresnel_reflects, implicit_capture, largest, mirror,
                                        refract_in, refract_out, roulette)
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
from simulate.montecarlo.rng import exponential, next_u64, seed_state, to_uniform
from simulate.montecarlo.rough import rough_cross, rough_entry
from simulate.montecarlo.scatter import PHASE_HG, PHASE_TABLE, hg_constants, sample_direction
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
]

# numba's 'omp' threading layer (GNU libgomp) spin-waits at the end of every parallel region by
# default. On a machine whose other cores are busy the spinning thread and the one it waits for share
# a core: every kernel call then costs milliseconds of CPU whatever its size, which dominates many
# small calls (docs/notes/implementation.md, "The photon kernel"). Passive threads sleep at the
# barrier; long runs are unaffected. libgomp reads the variable when numba first starts its
# threads, after this import; a value the user set is kept.
# https://gcc.gnu.org/onlinedocs/libgomp/OMP_005fWAIT_005fPOLICY.html
os.environ.setdefault("OMP_WAIT_POLICY", "passive")

# walk-medium array slots
M_MU_A = 0
M_MU_S = 1
M_G = 2
M_N = 3
M_PHASE = 4
M_ROUGH = 5  # Beckmann RMS slope of the boundary for light crossing it, along the axis (0 with M_ROUGH_B: smooth; .rough)
M_ROUGH_B = 6  # ... and about the axis (the same value: isotropic)
M_DYE_PROFILE = 7  # where the targets' dye absorbs across a cylinder: DYE_UNIFORM (0), DYE_RING, DYE_CORE
M_DYE_RADIUS = 8  # the profile's inner boundary: the dye at r > it (ring) or at r < it (core)
N_MEDIUM = 9

# dye profiles (M_DYE_PROFILE; module docstring, "Dye profile")
DYE_UNIFORM = 0
DYE_RING = 1
DYE_CORE = 2

# control array slots
C_WEIGHT_THRESHOLD = 0
C_SURVIVAL = 1
C_MAX_EVENTS = 2
N_CONTROL = 3

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


def _make_kernel(scoring: bool, profiled: bool = False):
    """Compile the kernel for one flavour: ``scoring`` False is the plain transport loop (totals
    and bookkeeping only), True adds the tallies, the vertex hook and spectral re-weighting.

    ``SCORING`` is a closure constant, so numba prunes the scoring code from the plain
    flavour: its mere presence (calls and array stores in the photon loop) costs the plain
    slab case about 30 % of its speed. (The plain slab runs in a loop of its own with two photons
    in flight, :mod:`.slab_lanes`; :func:`run_batches_plain` picks it for slab runs.)
    ``STAMP`` (:func:`_source_stamp`) keys the cache to the sources the kernel is built from.
    ``profiled`` (with ``scoring``) is the flavour of a dye profile (module docstring, "Dye profile"); its code
    is pruned from the others as the scoring code is from the plain one, so a run without a profile is the
    loop without it, bit for bit.
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
        geometry = inp.geometry
        geom = inp.geom
        medium = inp.medium
        table = inp.table
        mu_a = medium[M_MU_A]
        mu_s = medium[M_MU_S]
        g = medium[M_G]
        n_in = medium[M_N]
        phase = int(medium[M_PHASE])
        mu_t = mu_a + mu_s
        inv_mu_t = 1.0 / mu_t if mu_t > 0.0 else math.inf
        albedo = mu_s / mu_t if mu_t > 0.0 else 0.0
        absorb = 1.0 - albedo
        w_threshold = inp.control[C_WEIGHT_THRESHOLD]
        survival = inp.control[C_SURVIVAL]
        inv_survival = 1.0 / survival
        max_events = int(inp.control[C_MAX_EVENTS])
        contrast = n_in != 1.0
        eta_in = 1.0 / n_in
        m_rough = medium[M_ROUGH]
        m_rough_b = medium[M_ROUGH_B]
        rough = contrast and (m_rough > 0.0 or m_rough_b > 0.0)  # a rough boundary (.rough); else the smooth code
        if PROFILED:
            dye_mode = int(medium[M_DYE_PROFILE])
            dye_radius = medium[M_DYE_RADIUS]
        dx = -source[1]
        dy = -source[2]
        dz = -source[3]
        size = geom[0]
        src_mode = int(source[0])
        src_h = source[4]
        cell_source = geometry != SLAB and src_mode == CELL
        hg = hg_constants(g)

        tally_mode = inp.tally_mode
        vertex_mode = inp.vertex_mode
        reweight = inp.reweight
        n_spec = inp.spec_mu.shape[0]
        vertex_base = inp.n_exit_bins
        n_bins_total = bins.shape[0]
        hist = np.zeros(n_bins_total)
        n_blocks = max(n_bins_total // n_spec, 1)  # geometric bins, each of n_spec spectral bins
        touched = np.zeros(n_blocks, dtype=np.int64)
        n_touched = np.zeros(1, dtype=np.int64)
        marks = np.zeros(n_blocks, dtype=np.bool_)
        spec_w = np.ones(n_spec)
        nee_work = np.zeros(T.N_NEE)
        nee_consts = inp.nee_consts.copy()  # private: ranged outputs overwrite their row per vertex
        phase_ratio = inp.phase_ratio
        ratio = inp.spec_ratio
        n_grid = ratio.shape[0]
        d_mu_t = np.zeros(n_spec)
        log_s = np.zeros(n_spec)  # ln(mu_s^l / mu_s^w), a large negative number for mu_s^l = 0
        spec_mu_t = np.zeros(n_spec)
        for l in range(n_spec):
            spec_mu_t[l] = inp.spec_mu[l, 0] + inp.spec_mu[l, 1]
            d_mu_t[l] = spec_mu_t[l] - mu_t
            s_ratio = inp.spec_mu[l, 1] / mu_s if mu_s > 0.0 else 1.0
            log_s[l] = math.log(s_ratio) if s_ratio > 0.0 else _LOG_ZERO
        # deferred re-weighting: the factors (mu_s^l / mu_s^w) exp(-(mu_t^l - mu_t^w) l) of the free
        # paths since the last update are one exp of (n ln s_l - d_l L) per wavelength (module docstring)
        pend_n = 0
        pend_l = 0.0
        if not reweight:
            for l in range(n_spec):
                spec_mu_t[l] = mu_t
        if PROFILED:
            # a dye profile: the dye's part of d_mu_t is taken along the dyed length pend_d instead of pend_l
            # (its runs are re-weighted, with the dye's column: make_inputs checks it)
            d_mu_u = d_mu_t.copy()
            spec_dye = np.zeros(n_spec)
            for l in range(n_spec):
                spec_dye[l] = inp.spec_mu[l, 2]
                d_mu_u[l] = d_mu_t[l] - spec_dye[l]
            pend_d = 0.0
        # the records the tallies read, packed once (tuples: no allocation, passed as their fields)
        scratch = T.Scratch(hist, touched, n_touched, marks, n_spec)
        spectral = T.Spectral(spec_w, spec_mu_t, phase_ratio, ratio)
        vertex = T.VertexInputs(inp.outputs, nee_consts, nee_work, vertex_base, size, n_in, phase, g, table, inp.pdf,
                                inp.lookup)

        s0, s1, s2, s3 = seed_state(seed, batch)

        specular = 0.0
        entered = 0.0
        launch_weight = 0.0
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

        for _ in range(photons):
            # --- entry: Snell refraction, weight (launch weight) x (1 - F) -----------------
            r, s0, s1, s2, s3 = next_u64(s0, s1, s2, s3)
            x, y, z, nx, ny, nz = entry_point(geometry, size, src_mode, -dx, -dy, -dz, src_h, to_uniform(r))
            cos_i = -(dx * nx + dy * ny + dz * nz)
            w0 = 1.0
            if cell_source:
                w0 = max(cos_i, 0.0)  # irradiance on the surface element, per unit beam irradiance
            t_in = -1.0  # the rough entry's transmitted weight (per unit arriving); < 0: 1 - f_in
            if rough and w0 > 0.0:
                r, s0, s1, s2, s3 = next_u64(s0, s1, s2, s3)
                r2, s0, s1, s2, s3 = next_u64(s0, s1, s2, s3)
                ux, uy, uz, t_in, f_in = rough_entry(dx, dy, dz, nx, ny, nz, n_in, m_rough, m_rough_b,
                                                     to_uniform(r), to_uniform(r2))
            elif contrast and w0 > 0.0:
                ux, uy, uz, f_in = refract_in(dx, dy, dz, nx, ny, nz, cos_i, n_in, eta_in)
            else:
                f_in = 0.0
                ux = dx
                uy = dy
                uz = dz
            launch_weight += w0
            w = w0 * (1.0 - f_in) if t_in < 0.0 else w0 * t_in
            specular += w0 * f_in  # rough: f_in is the facet's reflected part, masking included
            if t_in >= 0.0:
                # the rough entry's balance: its mean is the facets' masking loss (.rough), booked as
                # absorbed; one facet's draw may give more or less than its mean, so this may be < 0
                absorbed += w0 * (1.0 - t_in - f_in)
            entered += w
            h_exit0 = 0.0
            h_exit1 = 0.0
            h_gain = 0.0
            h_killed = 0.0
            events = 0
            scatterings = 0
            path = 0.0
            if SCORING:
                if reweight:
                    for l in range(n_spec):
                        spec_w[l] = 1.0
                    pend_n = 0
                    pend_l = 0.0
                    if PROFILED:
                        pend_d = 0.0
            alive = w > 0.0
            while alive:
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
                if inside(geometry, size, xn, yn, zn):
                    # --- collision (the end point is inside: convex shape) ------------------
                    if PROFILED:
                        inner = core_length(y, z, uy, uz, step, dye_radius)
                        pend_d += inner if dye_mode == DYE_CORE else step - inner
                    x = xn
                    y = yn
                    z = zn
                    path += step
                    w, absorbed = implicit_capture(w, absorbed, albedo, absorb)
                    scatterings += 1
                    w_max = 1.0
                    decide = True  # roulette decided at this collision
                    if SCORING:
                        if reweight:
                            pend_n += 1
                            pend_l += step
                            if vertex_mode == T.V_CYLINDER_NEE:  # the vertex estimator reads spec_w
                                catch_up(spec_w, log_s, d_mu_t, pend_n, pend_l)
                                pend_n = 0
                                pend_l = 0.0
                        if vertex_mode == T.V_CYLINDER_NEE:
                            s0, s1, s2, s3 = T.score_vertex(vertex, scratch, spectral, (x, y, z), (ux, uy, uz), w,
                                                            (s0, s1, s2, s3))
                    ux, uy, uz, ct, s0, s1, s2, s3 = sample_direction(ux, uy, uz, phase, g, table, hg, s0, s1, s2, s3)
                    if SCORING:
                        if reweight:
                            if phase_ratio:
                                jr, fr = T.ratio_row(ct, n_grid)
                                r0 = ratio[jr]
                                r1 = ratio[jr + 1]
                                for l in range(n_spec):
                                    spec_w[l] *= r0[l] + fr * (r1[l] - r0[l])
                            if pend_n == 0 or pend_n >= REWEIGHT_EVERY:
                                if pend_n > 0:
                                    if PROFILED:
                                        catch_up_dyed(spec_w, log_s, d_mu_u, spec_dye, pend_n, pend_l, pend_d)
                                        pend_d = 0.0
                                    else:
                                        catch_up(spec_w, log_s, d_mu_t, pend_n, pend_l)
                                    pend_n = 0
                                    pend_l = 0.0
                                w_max = largest(spec_w)
                            else:
                                decide = False  # decided at the next update (any rule is unbiased)
                    if decide and w * w_max < w_threshold:
                        if w <= 0.0 or w_max <= 0.0:
                            break
                        alive, w, h_gain, h_killed, s0, s1, s2, s3 = roulette(w, h_gain, h_killed, survival,
                                                                              inv_survival, s0, s1, s2, s3)
                        if not alive:
                            break
                else:
                    # --- boundary --------------------------------------------------------
                    s_b = distance_to_boundary(geometry, size, x, y, z, ux, uy, uz)
                    if PROFILED:
                        inner = core_length(y, z, uy, uz, s_b, dye_radius)
                        pend_d += inner if dye_mode == DYE_CORE else s_b - inner
                    x += s_b * ux
                    y += s_b * uy
                    z += s_b * uz
                    path += s_b
                    if SCORING:
                        if reweight:
                            pend_l += s_b
                    x, y, z = snap_to_surface(geometry, size, x, y, z, uz)
                    nx, ny, nz = outward_normal(geometry, size, x, y, z, uz)
                    cos_i = ux * nx + uy * ny + uz * nz
                    if rough:
                        r, s0, s1, s2, s3 = next_u64(s0, s1, s2, s3)
                        r2, s0, s1, s2, s3 = next_u64(s0, s1, s2, s3)
                        r3, s0, s1, s2, s3 = next_u64(s0, s1, s2, s3)
                        ox, oy, oz, factor, crossed = rough_cross(ux, uy, uz, nx, ny, nz, n_in, 1.0, m_rough,
                                                                  m_rough_b, to_uniform(r), to_uniform(r2),
                                                                  to_uniform(r3))
                        # the crossing's weight factor is 1 on average less the facets' masking loss
                        # (.rough); its difference from 1 is booked as absorbed (signed: one facet's
                        # draw may weigh more than 1), so every photon's balance stays exact
                        absorbed += w * (1.0 - factor)
                        if factor <= 0.0:
                            break
                        w *= factor
                        if not crossed:
                            ux = ox
                            uy = oy
                            uz = oz
                            reflections_total += 1
                            continue
                        wx = ox
                        wy = oy
                        wz = oz
                    elif contrast:
                        reflect, s0, s1, s2, s3 = fresnel_reflects(cos_i, n_in, s0, s1, s2, s3)
                        if reflect:
                            ux, uy, uz = mirror(ux, uy, uz, nx, ny, nz, cos_i, geometry == SLAB)
                            reflections_total += 1
                            continue
                        wx, wy, wz = refract_out(ux, uy, uz, nx, ny, nz, cos_i, n_in)
                    else:
                        wx = ux
                        wy = uy
                        wz = uz
                    face = 0
                    if geometry == SLAB and nz < 0.0:
                        face = 1
                    if face == 0:
                        h_exit0 = w
                        if scatterings == 0:
                            unscattered0 += w
                    else:
                        h_exit1 = w
                        if scatterings == 0:
                            unscattered1 += w
                    path_total += w * path
                    if SCORING:
                        if reweight and (pend_n > 0 or pend_l > 0.0):
                            if PROFILED:
                                catch_up_dyed(spec_w, log_s, d_mu_u, spec_dye, pend_n, pend_l, pend_d)
                            else:
                                catch_up(spec_w, log_s, d_mu_t, pend_n, pend_l)
                        T.score_exit(tally_mode, inp.tally_params, inp.outputs, scratch, spec_w, face, (x, y, z),
                                     (wx, wy, wz), w, scatterings)
                    break
            # --- the one end of every history: flush per-photon tallies -------------------
            exit0 += h_exit0
            exit0_sq += h_exit0 * h_exit0
            exit1 += h_exit1
            exit1_sq += h_exit1 * h_exit1
            gain += h_gain
            killed += h_killed
            net_sq += (h_gain - h_killed) * (h_gain - h_killed)
            if SCORING:
                T.flush_history(scratch, bins)
            events_total += events
            scatterings_total += scatterings

        scal[T.S_LAUNCHED] += photons
        scal[T.S_LAUNCH_WEIGHT] += launch_weight
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
        scal[T.S_ROULETTE_NET_SQ] += net_sq
        scal[T.S_CAPPED] += capped
        scal[T.S_CAPPED_WEIGHT] += capped_weight
        scal[T.S_EVENTS] += events_total
        scal[T.S_SCATTERINGS] += scatterings_total
        scal[T.S_INTERNAL_REFLECTIONS] += reflections_total
        scal[T.S_PATH_LENGTH] += path_total

    return simulate_batch


simulate_batch_plain = _make_kernel(False)
simulate_batch = _make_kernel(True)
simulate_batch_profiled = _make_kernel(True, profiled=True)


def has_profile(inp: KernelInputs) -> bool:
    """The run places its dye (``medium[M_DYE_PROFILE]``): the profiled flavour walks it."""
    return inp.medium.shape[0] > M_DYE_PROFILE and inp.medium[M_DYE_PROFILE] != DYE_UNIFORM


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
        """Run jobs ``i`` = batch ``job_batch[i]`` of run ``job_row[i]`` (source ``sources[row]``, seed
        ``seeds[row]``, ``total_photons`` photons per run) in parallel, job ``i`` into row ``i`` of
        ``scal`` / ``bins`` (zeroed first). Each job is exactly the batch that :func:`run_batches`
        runs for that run alone: the same stream ``(seed, batch)`` and photons."""
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
    """The compiled :func:`run_batches` flavour a run needs (plain when nothing is tallied)."""
    if inp.tally_mode == T.NONE and inp.vertex_mode == T.V_NONE:
        return run_batches_plain
    return run_batches_profiled if has_profile(inp) else run_batches
