"""The integrator of the fibre-assembly tracer: wavefronts of rays through the periodic cell.

:func:`trace` follows a beam from one incidence through the tiled micro-element
(:mod:`simulate.raytrace.scene`), shading every hit (:mod:`simulate.raytrace.shading`), scoring
next-event estimates towards every detector, escaping-ray bins and the reflected/transmitted
energy, in fixed rounds of chunks until the target relative error
(:func:`simulate.montecarlo.accuracy.relative_error`), the ray budget or the time budget.

Shadow rays
-----------
Every hit scores a next-event estimate towards each detector its shading reaches, each needing a
shadow ray (:meth:`simulate.raytrace.scene.PeriodicScene.visible`): in a felt most of a run's Embree
queries, and most of them carry a small share of what their detector collects. They are played by
Russian roulette on their contribution: a candidate of size ``c`` (its largest spectral value) is
traced with probability ``p = min(1, c / c_ref)`` and, when traced and visible, scores ``1 / p`` times
its contribution -- the same expectation, whatever ``c_ref`` is, as long as ``c_ref`` is fixed before
the draw. ``c_ref`` is :data:`SHADOW_LEVEL` times the chunk's running mean per ray of the candidates'
sizes towards that detector (all bounces so far, this one included): a level relative to what the
detector collects, so it needs no setting per scene, and a candidate at least that large is always
traced. A candidate whose contribution is exactly zero is not traced at all. The draws come from a
stream of the chunk's own (a child of its seed), so a run stays reproducible and independent of the
threads, and the paths are those of a run without roulette. The added variance is in the per-ray
totals, so ``u_beta`` holds it. ``info``: ``shadow_candidates`` (next-event estimates asked for),
``shadow_rays`` (traced), ``shadow_queries`` (their Embree queries, one per cell crossed).

With a fiber material (:data:`SHADOW_BOUND`) the size played is not the contribution's largest spectral
value but a bound of it known before the contribution is formed: the ray's largest spectral weight
times the table cell's largest value times the candidate's scale (the surface term's bound is its
size). The shading then only records where each contribution comes from
(:class:`simulate.raytrace.shading.ShadeOutputs`, ``nee_row`` and ``nee_scale``), and the spectral
products are formed for the candidates traced and visible alone. The roulette stays unbiased (any
``c`` fixed before the draw will do); a candidate is played a little more often (the bound is at
least its size), and the estimator is not the one of the sizes
(``tests/simulate/raytrace/test_shadow_bound.py`` checks the two against each other).

Estimators
----------
*Next-event* (the camera of the virtual measurement): at every event the light that would leave
straight towards each detector direction ``w_o`` of the plan is scored, if a shadow ray towards
``w_o`` escapes (periodic wrap included). With rays of power ``E cos(theta_i) A / N`` on the
micro-element of area ``A``::

    f(w_in, w_o) = 1 / (N cos theta_o) sum_rays sum_events c(w_o),        beta = pi f

where ``c`` is the radiant intensity per unit incident power of the event: ``f_CT cos_o'`` for
the surface, ``T_bin / (c_bar p_cell) cos_o' / Omega_proj,bin`` for a sampled volume exit
(``'`` = local frame). *Direction bins*: escaping rays binned in ``(cos theta, phi)``:
``f_bin = sum w / (N Omega_proj,bin)``. The energy budget (reflected, transmitted, the rest
absorbed) is tallied per wavelength.

Accuracy control: rays are traced in chunks of fixed size with fixed seeds; the run stops at the
target, or at the ray or time budget, and says which. :func:`trace`'s
standard error is that of the ray tracing *given* the BSSRDF table; :func:`fabric_beta` (the
plan-level entry of ``simulate fabric --method mc``) builds the table as two independent halves
(``table_photons`` per row in all, scaling with the target) and adds the table's own noise,
estimated from the difference of the two halves' traces, to ``u_beta``. A felt (a random
realisation of its fibers) is traced at :data:`FELT_ROTATIONS` azimuths per incidence on several
independent realisations, half of them on each table half: their spread is in ``u_beta`` too
(:mod:`.estimate`).
"""

from __future__ import annotations

import logging
import math
import time
import warnings
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any

import numba
import numpy as np

from simulate.montecarlo.accuracy import check_target, relative_error
from simulate.raytrace.materials import (
    K_FIBER,
    K_FIBER_BRDF,
    FiberBRDFAtHit,
    FiberSurface,
    Lambert,
    material_kind,
    surface_albedo,
)
from simulate.raytrace.scene import ESCAPED_DOWN, ESCAPED_UP, LOST, PeriodicScene
from simulate.raytrace.shading import ShadeInputs, ShadeOutputs, shade_groups

__all__ = ["STOP_REASONS", "ROULETTE_SURVIVE", "MCResult", "mean_se", "prepare", "trace", "trace_rotations", "yarn_radius"]

log = logging.getLogger(__name__)

STOP_REASONS = ("target", "max_rays", "max_seconds")
CHUNK = 2048
_ROUND = 4           # chunks per accuracy check (fixed, so results do not depend on the threads)
_MAX_BOUNCES = 200
_ROULETTE_BELOW = 0.01
#: the probability that a ray below the roulette threshold survives (its weight divided by it)
ROULETTE_SURVIVE = 0.1
SHADOW_ROULETTE = True
"""Russian roulette on the shadow rays (module docstring); ``False`` traces every candidate."""
SHADOW_LEVEL = 0.5
"""``c_ref`` as a fraction of the chunk's mean per ray of the candidates' sizes towards a detector (0: all traced)."""
SHADOW_BOUND = True
"""A fiber material's roulette played on each candidate's bound, its contribution formed only when kept (module
docstring); ``False``: every contribution formed by the shading and played on its size."""


@dataclass
class MCResult:
    """Fabric Monte Carlo for one incidence: next-event ``beta`` per detector and wavelength.

    ``beta``, ``u_beta``: ``[D, L]``. ``reflected``, ``transmitted``: energy fractions ``[L]``
    (and their standard errors). ``bins``, ``u_bins``: escaping-ray ``f`` on the uniform
    ``(cos theta, phi)`` grid, ``[n_mu, n_phi, L]``, ``phi`` from -pi. ``stop``: ``"target" | "max_rays" | "max_seconds"``.
    """

    beta: np.ndarray
    u_beta: np.ndarray
    reflected: np.ndarray
    u_reflected: np.ndarray
    transmitted: np.ndarray
    u_transmitted: np.ndarray
    bins: np.ndarray
    u_bins: np.ndarray
    rays: int
    seconds: float
    rel_err: float
    stop: str
    info: dict = field(default_factory=dict)


@dataclass
class _Sums:
    nee: np.ndarray
    nee2: np.ndarray
    refl: np.ndarray
    refl2: np.ndarray
    trans: np.ndarray
    trans2: np.ndarray
    energy2: np.ndarray
    bins: np.ndarray
    bins2: np.ndarray
    rays: int = 0
    lost: int = 0
    killed: int = 0
    embree_rays: int = 0
    hits: int = 0
    albedo_sum: float = 0.0
    albedo_over_one: int = 0
    continued: int = 0
    self_hits: int = 0
    shadow_candidates: int = 0
    shadow_rays: int = 0
    shadow_queries: int = 0
    log: Any = None
    """The chunk's events for a dye's re-weighting (:func:`_chunk` with ``record``), else None."""

    def add(self, o: _Sums) -> None:
        for name in ("nee", "nee2", "refl", "refl2", "trans", "trans2", "energy2", "bins", "bins2"):
            getattr(self, name)[...] += getattr(o, name)
        self.rays += o.rays
        self.lost += o.lost
        self.killed += o.killed
        self.embree_rays += o.embree_rays
        self.hits += o.hits
        self.albedo_sum += o.albedo_sum
        self.albedo_over_one += o.albedo_over_one
        self.continued += o.continued
        self.self_hits += o.self_hits
        self.shadow_candidates += o.shadow_candidates
        self.shadow_rays += o.shadow_rays
        self.shadow_queries += o.shadow_queries


def _new_sums(G: int, D: int, L: int, bins: tuple[int, int]) -> _Sums:
    """Zero sums of ``G`` groups of ``D`` detectors at ``L`` wavelengths (a leading group axis)."""
    b = (G, int(bins[0]), int(bins[1]), L)
    return _Sums(np.zeros((G, D, L)), np.zeros((G, D, L)), np.zeros((G, L)), np.zeros((G, L)), np.zeros((G, L)),
                 np.zeros((G, L)), np.zeros((G, L)), np.zeros(b), np.zeros(b), rays=0)


def yarn_radius(mesh: Any) -> float:
    """The yarn radius of a mesh (um): the first yarn's ``sqrt(a b)``, or the radius the mesh states.

    The semi-axes ``a``, ``b`` come from the first yarn's first ring of vertices; a mesh may state the
    radius as ``yarn_radius_um``, as the felt's does.

    Parameters
    ----------
    mesh : Mesh
        The traced mesh.

    Returns
    -------
    float
        The radius (um).
    """
    if getattr(mesh, "yarn_radius_um", None):
        return float(mesh.yarn_radius_um)
    ring = np.asarray(mesh.vertices)[int(mesh.vertex_base[0]):int(mesh.vertex_base[0]) + int(mesh.sides) + 1]
    axis = 1 if abs(float(np.asarray(mesh.tangents)[int(mesh.vertex_base[0]), 0])) >= 0.5 else 0
    a = 0.5 * float(np.ptp(ring[:, axis]))
    b = 0.5 * float(np.ptp(ring[:, 2]))
    return math.sqrt(max(a * b, 1e-12))


class _Setup:
    """Everything the chunks share (scene, mesh arrays, material arrays)."""

    def __init__(self, mesh: Any, material: Any, n_wl: int, bins: tuple[int, int],
                 twist_deg: tuple[float, float] = (0.0, 0.0), normals: str = "vertex"):
        self.mesh = mesh
        self.scene = PeriodicScene(mesh.vertices, mesh.faces, mesh.Lx, mesh.Ly)
        self.n_wl = n_wl
        self.bins = bins
        f64 = np.float64
        # the axis each yarn runs along (0: x, a warp; 1: y, a weft), from its first tangent
        first = np.asarray(mesh.vertex_base, np.int64)
        tan0 = np.asarray(mesh.tangents)[first]
        self.run_axis = np.where(np.abs(tan0[:, 0]) >= np.abs(tan0[:, 1]), 0, 1).astype(np.int64)
        if getattr(mesh, "open_fibers", False):      # a felt's fibers: s is the arc length, no periodicity
            self.run_axis[:] = 2
        # twist (signed: + Z, - S) per yarn by its system: warp (x) or weft (y); none for a felt's fibers
        angle = np.where(self.run_axis == 0, float(twist_deg[0]), float(twist_deg[1]))
        angle = np.where(self.run_axis == 2, 0.0, angle)
        self.twist_c = np.cos(np.radians(np.abs(angle)))
        self.twist_s = np.sign(angle) * np.sin(np.radians(np.abs(angle)))
        self.kind = material_kind(material)
        if isinstance(material, Lambert):
            self.rho = np.broadcast_to(np.asarray(material.rho, f64), (n_wl,)).copy()
            self.m = 0.0
            self.n_host = 1.0
            self.albedo = np.zeros(2)
            z = np.zeros((1, 1, 1, n_wl))
            self.t_rows, self.t_max = z.reshape(1, n_wl), np.zeros(1)
            self.T, self.cdf, self.cell_sum = z, np.ones((1, 1, 1)), np.zeros((1, 1, n_wl))
            self.c_bar, self.tau, self.nodes = np.ones((1, 1)), np.ones((1, 1)), np.zeros(1)
            self.off_tot, self.off_bar = np.zeros((1, 1, 1, n_wl)), np.zeros((1, 1, 1))
            self.dpsi, self.grid, self.v_edges = 1.0, (1, 1, 1, 1), np.zeros(2)
        else:
            tab = material.table
            self.rho = np.zeros(n_wl)
            self.m = float(material.roughness)
            self.n_host = float(material.n_host)
            self.albedo = surface_albedo(self.m, self.n_host)   # once per run (and cached on disk)
            self.T = np.ascontiguousarray(tab.T)
            # the deferred next-event contributions (SHADOW_BOUND): the table's rows and each one's largest value
            self.t_rows = self.T.reshape(-1, n_wl)
            self.t_max = self.t_rows.max(axis=1)
            tbar = tab.T.mean(axis=3)
            self.cdf = np.ascontiguousarray(np.cumsum(tbar, axis=2))
            self.cell_sum = np.ascontiguousarray(tab.T.sum(axis=2))
            self.c_bar = np.ascontiguousarray(tab.c_bar)
            self.tau = np.ascontiguousarray(tab.tau)
            per_offset = tab.T.reshape(tab.T.shape[0], tab.T.shape[1], tab.n_psi, -1, n_wl).sum(axis=3)
            self.off_tot = np.ascontiguousarray(per_offset)
            self.off_bar = np.ascontiguousarray(per_offset.mean(axis=3))
            self.nodes = np.asarray(tab.w_t_nodes, f64)
            self.dpsi = float(tab.dpsi)
            self.grid = (tab.n_psi, tab.n_v, tab.n_mu, tab.n_phi)
            # v offsets scaled from the fiber to the yarn (similar cylinders, r_yarn = sqrt(a b))
            r_yarn = yarn_radius(mesh)
            v_max = tab.v_max_R * r_yarn
            self.v_edges = np.linspace(-v_max, v_max, tab.n_v + 1)

        me = mesh
        n_psi, n_v, n_mu, n_phi = self.grid
        self.inputs = ShadeInputs(
            me.vertices, me.faces, me.normals, me.tangents, me.vertex_s, me.vertex_phi, me.face_yarn,
            me.vertex_base, me.n_s, me.yarn_length, int(me.sides), self.run_axis,
            self.kind, self.rho, self.m, self.n_host, self.albedo,
            self.T, self.cdf, self.cell_sum, self.c_bar, self.tau, self.nodes, self.dpsi, n_psi, n_v, n_mu, n_phi,
            self.v_edges, self.off_tot, self.off_bar, np.zeros((0, 3)), self.twist_c, self.twist_s,
            yarn_radius(mesh), np.asarray(me.face_base, np.int64), normals == "face",
            float(material.layer_d) if isinstance(material, FiberSurface) else 0.0,
            bool(getattr(material, "axial_shift", False)))


# ---- the per-bounce bookkeeping of a wavefront, compiled (:func:`_chunk`) ---------------------------
# Each kernel does what a few numpy lines did, element by element in the same order and with the same
# arithmetic (the bincount's and np.add.at's sums in input order), so a run is the same bit for bit;
# tests/simulate/raytrace/test_chunk_kernels.py holds those numpy lines as the reference.

@numba.njit(cache=True, nogil=True)
def _tally_escapes(prim, ray, last, dirs, azimuth, weight, n, n_mu, n_phi, refl, trans, bins, bins2,
                   hit_ray, hit_idx):
    """Score the rays of a bounce that escaped and list the ones that hit.

    Score the rays of a bounce that escaped (up: ``refl`` and the exit bins, ``bins2`` their squares;
    down: ``trans``) and list the ones that hit (``hit_ray``: their ray, ``hit_idx``: their row in the
    wavefront), in order. ``azimuth``: ``arctan2(dirs_y, dirs_x)`` (numpy's). Returns
    ``(hits, lost, continued, self_hits)``.
    """
    m = 0
    lost = 0
    continued = 0
    self_hits = 0
    L = weight.shape[1]
    for i in range(prim.shape[0]):
        p = prim[i]
        r = ray[i]
        if last[i] >= 0:
            continued += 1
        if p >= 0:
            if p == last[i]:
                self_hits += 1
            hit_ray[m] = r
            hit_idx[m] = i
            m += 1
        elif p == ESCAPED_UP:
            imu = min(int(dirs[i, 2] * n_mu), n_mu - 1)
            iph = min(int((azimuth[i] + np.pi) / (2 * np.pi) * n_phi), n_phi - 1)
            g = r // n
            for k in range(L):
                x = weight[i, k]
                refl[r, k] += x
                bins[g, imu, iph, k] += x
                bins2[g, imu, iph, k] += x * x
        elif p == ESCAPED_DOWN:
            for k in range(L):
                trans[r, k] += weight[i, k]
        elif p == LOST:
            lost += 1
    return m, lost, continued, self_hits


@numba.njit(cache=True, nogil=True)
def _gather_hits(hit_idx, m, prim, u, v, position, dirs, weight, hp, hu, hv, hpos, hd, hw):
    """The hit rows of a wavefront (``hit_idx[:m]``) gathered into the shading's inputs."""
    L = weight.shape[1]
    for j in range(m):
        i = hit_idx[j]
        hp[j] = prim[i]
        hu[j] = u[i]
        hv[j] = v[i]
        for q in range(3):
            hpos[j, q] = position[i, q]
            hd[j, q] = dirs[i, q]
        for k in range(L):
            hw[j, k] = weight[i, k]


@numba.njit(cache=True, nogil=True)
def _shadow_candidates(need, nee_c, hit_group, D, cand, level_scale, roulette, cidx, size, p, state, binsum):
    """The next-event candidates of a bounce, their roulette probabilities and their states.

    The next-event candidates of a bounce (``need``'s true entries in C order), their sizes (largest
    spectral value), the roulette's probabilities against the running per-detector sums ``cand`` (updated
    with this bounce's sizes first) and their state: 0 not traced (zero), 1 traced, 2 to be drawn with ``p``.
    Returns ``(candidates, to_draw)``.
    """
    M = need.shape[0]
    E = need.shape[1]
    L = nee_c.shape[3]
    c = 0
    for j in range(binsum.shape[0]):
        binsum[j] = 0.0
    for i in range(M):
        for e in range(E):
            for d in range(D):
                if not need[i, e, d]:
                    continue
                s = nee_c[i, e, d, 0]
                for k in range(1, L):
                    x = nee_c[i, e, d, k]
                    if x > s:
                        s = x
                cidx[c, 0] = i
                cidx[c, 1] = e
                cidx[c, 2] = d
                size[c] = s
                if roulette:
                    binsum[hit_group[i] * D + d] += s
                c += 1
    draw = 0
    if roulette:
        for j in range(binsum.shape[0]):
            cand[j] += binsum[j]
    for q in range(c):
        s = size[q]
        p[q] = 1.0
        state[q] = 1 if s > 0.0 else 0
        if roulette:
            level = level_scale * cand[hit_group[cidx[q, 0]] * D + cidx[q, 2]]
            if level > s:
                p[q] = s / level
            if state[q] == 1 and p[q] < 1.0:
                state[q] = 2
                draw += 1
    return c, draw


@numba.njit(cache=True, nogil=True)
def _bounded_candidates(need, nee_row, nee_scale, weight, t_max, hit_group, D, cand, level_scale, cidx, size, p,
                        state, binsum):
    """The next-event candidates of a bounce whose contributions are deferred, by their bounds.

    :func:`_shadow_candidates` of deferred contributions (:data:`SHADOW_BOUND`): each candidate's size is
    the bound ``max_k weight[i, k]`` times ``t_max[nee_row]`` (1 for the surface term, row -1) times
    ``nee_scale``, and the roulette is always played. Returns ``(candidates, to_draw)``.
    """
    M = need.shape[0]
    E = need.shape[1]
    L = weight.shape[1]
    c = 0
    for j in range(binsum.shape[0]):
        binsum[j] = 0.0
    for i in range(M):
        w_top = -1.0
        for e in range(E):
            for d in range(D):
                if not need[i, e, d]:
                    continue
                if w_top < 0.0:
                    w_top = weight[i, 0]
                    for k in range(1, L):
                        if weight[i, k] > w_top:
                            w_top = weight[i, k]
                s = w_top * nee_scale[i, e, d]
                r = nee_row[i, e, d]
                if r >= 0:
                    s *= t_max[r]
                cidx[c, 0] = i
                cidx[c, 1] = e
                cidx[c, 2] = d
                size[c] = s
                binsum[hit_group[i] * D + d] += s
                c += 1
    draw = 0
    for j in range(binsum.shape[0]):
        cand[j] += binsum[j]
    for q in range(c):
        s = size[q]
        p[q] = 1.0
        state[q] = 1 if s > 0.0 else 0
        level = level_scale * cand[hit_group[cidx[q, 0]] * D + cidx[q, 2]]
        if level > s:
            p[q] = s / level
        if state[q] == 1 and p[q] < 1.0:
            state[q] = 2
            draw += 1
    return c, draw


@numba.njit(cache=True, nogil=True)
def _shadow_rays(c, state, p, draws, cidx, nee_o, detectors, hit_group, wrap, lx, ly, traced, origins, towards):
    """Gather the candidates to trace and their shadow rays; returns how many.

    The candidates traced (state 1, or 2 and the next of ``draws`` below ``p``: in order), their
    shadow rays' origins (into the cell for a felt) and directions. Returns how many.
    """
    t = 0
    u = 0
    for q in range(c):
        st = state[q]
        if st == 2:
            st = 1 if draws[u] < p[q] else 0
            u += 1
        if st == 0:
            continue
        i, e, d = cidx[q, 0], cidx[q, 1], cidx[q, 2]
        traced[t] = q
        x, y, z = nee_o[i, e, 0], nee_o[i, e, 1], nee_o[i, e, 2]
        if wrap:
            x = x % lx
            y = y % ly
        origins[t, 0], origins[t, 1], origins[t, 2] = x, y, z
        g = hit_group[i]
        for k in range(3):
            towards[t, k] = detectors[g, d, k]
        t += 1
    return t


@numba.njit(cache=True, nogil=True)
def _score_visible(t, traced, vis, cidx, p, nee_c, hit_ray, acc):
    """Add each visible traced candidate's contribution over its probability to its ray's detector, in order."""
    L = nee_c.shape[3]
    for j in range(t):
        if not vis[j]:
            continue
        q = traced[j]
        i, e, d = cidx[q, 0], cidx[q, 1], cidx[q, 2]
        r = hit_ray[i]
        pq = p[q]
        for k in range(L):
            acc[r, d, k] += nee_c[i, e, d, k] / pq


@numba.njit(cache=True, nogil=True)
def _score_visible_bounded(t, traced, vis, cidx, p, nee_row, nee_scale, weight, t_rows, hit_ray, acc):
    """Score the visible traced candidates of deferred contributions, each over its probability.

    :func:`_score_visible` of deferred contributions: each visible traced candidate's contribution formed
    as the shading forms it (``weight * t_rows[row] * scale``; the surface term, row -1, ``weight * scale``)
    over its probability, added to its ray's detector, in order.
    """
    L = weight.shape[1]
    for j in range(t):
        if not vis[j]:
            continue
        q = traced[j]
        i, e, d = cidx[q, 0], cidx[q, 1], cidx[q, 2]
        r = hit_ray[i]
        pq = p[q]
        sc = nee_scale[i, e, d]
        row = nee_row[i, e, d]
        if row < 0:
            for k in range(L):
                acc[r, d, k] += weight[i, k] * sc / pq
        else:
            for k in range(L):
                acc[r, d, k] += weight[i, k] * t_rows[row, k] * sc / pq


@numba.njit(cache=True, nogil=True)
def _path_roulette(w, below, low):
    """Mark the continuing rays of low weight for the path's Russian roulette; returns how many.

    A ray's weight is low when its largest spectral value is below ``below`` (and above 0).
    """
    c = 0
    L = w.shape[1]
    for i in range(w.shape[0]):
        s = w[i, 0]
        for k in range(1, L):
            if w[i, k] > s:
                s = w[i, k]
        low[i] = s < below and s > 0.0
        if low[i]:
            c += 1
    return c


@numba.njit(cache=True, nogil=True)
def _survivors(o, d, w, left, hit_ray, low, draws, survive, wrap, lx, ly, origins, dirs, weight, ray, last):
    """Play the path's roulette and compact the live rays into the next wavefront; returns how many.

    Play the path's roulette (``draws`` in order over the ``low`` rows: kept with probability
    ``survive``, their weight over it) and compact the live rays (largest weight above 0) into the next
    wavefront's arrays (a felt's origins back into the cell). Returns how many.
    """
    L = w.shape[1]
    u = 0
    a = 0
    for i in range(w.shape[0]):
        if low[i]:
            keep = draws[u] < survive
            u += 1
            for k in range(L):
                w[i, k] = w[i, k] / survive if keep else 0.0
        s = w[i, 0]
        for k in range(1, L):
            if w[i, k] > s:
                s = w[i, k]
        if not s > 0.0:
            continue
        x, y = o[i, 0], o[i, 1]
        if wrap:
            x = x % lx
            y = y % ly
        origins[a, 0], origins[a, 1], origins[a, 2] = x, y, o[i, 2]
        for q in range(3):
            dirs[a, q] = d[i, q]
        for k in range(L):
            weight[a, k] = w[i, k]
        ray[a] = hit_ray[i]
        last[a] = left[i]
        a += 1
    return a


def _group_seeds(rng: np.random.Generator, cuts: np.ndarray, G: int) -> np.ndarray:
    """The shading's random state of each group that has hits (``cuts[g] < cuts[g + 1]``), drawn in the groups' order.

    A group without hits keeps 0 and draws nothing, so the streams of the others do not depend on it.
    """
    seeds = np.zeros(G, np.int64)
    for g in range(G):
        if cuts[g + 1] > cuts[g]:
            seeds[g] = rng.integers(0, 2**62)
    return seeds


def _chunk(setup: _Setup, w_in: np.ndarray, detectors: np.ndarray, n: int, seed: tuple[int, ...],
           events: int = _MAX_BOUNCES, record: bool = False) -> _Sums:
    """Trace ``n`` rays of each beam ``w_in[g]`` through the micro-element in one wavefront.

    One wavefront holds the rays of all ``G`` beams, each followed for at most ``events`` scattering
    events (the rays still going after that count as killed).
    ``record``: the sums' ``log`` holds the events a dye's re-weighting replays
    (:class:`simulate.raytrace.record.EventLog`; a fiber material with deferred contributions only).

    ``w_in`` ``[G, 3]`` and ``detectors`` ``[G, D, 3]``: ray ``r`` belongs to group ``r // n`` and is
    scored towards that group's detectors; the sums carry a leading group axis. The rays of every
    group go through each bounce's Embree queries together; the shading is called once per group
    (the rays stay ordered by group, so each group is a contiguous slice of the hits).
    """
    rng = np.random.default_rng(list(seed))
    L = setup.n_wl
    G, D = detectors.shape[0], detectors.shape[1]
    scene = setup.scene
    stats = {"queries": 0}
    n_mu, n_phi = setup.bins
    sums = _new_sums(G, D, L, (n_mu, n_phi))
    sums.rays = n
    N = G * n
    origins = np.column_stack([rng.uniform(0, setup.mesh.Lx, N), rng.uniform(0, setup.mesh.Ly, N),
                               np.full(N, scene.top)])
    dirs = np.repeat(-np.asarray(w_in, float), n, axis=0)
    weight = np.ones((N, L))
    ray = np.arange(N)
    last = np.full(N, -1, dtype=np.int64)   # the triangle each ray left from (-1: the beam)
    wrap = bool(getattr(setup.mesh, "open_fibers", False))
    lx, ly = float(setup.mesh.Lx), float(setup.mesh.Ly)
    acc = np.zeros((N, D, L))
    refl = np.zeros((N, L))
    trans = np.zeros((N, L))
    roulette = bool(SHADOW_ROULETTE)
    level_scale = SHADOW_LEVEL / n
    # the shadow roulette's draws: a stream of the chunk's own, so the paths stay those of a run without it
    shadow_rng = np.random.default_rng(np.random.SeedSequence(list(seed), spawn_key=(1,)))
    cand = np.zeros(G * D)      # the candidates' sizes so far, per group and detector
    binsum = np.zeros(G * D)
    # the wavefront's arrays, allocated once a chunk (a bounce uses their first rows); the next-event
    # contributions are read only where the shading flags them, so they need no clearing
    hit_ray = np.empty(N, np.int64)
    hit_idx = np.empty(N, np.int64)
    hp, hu, hv = np.empty(N, np.int64), np.empty(N), np.empty(N)
    hpos, hd, hw = np.empty((N, 3)), np.empty((N, 3)), np.empty((N, L))
    work = ShadeOutputs(np.empty((N, 3)), np.empty((N, 3)), np.empty((N, L)), np.empty((N, 2, 3)),
                        np.empty((N, 2, D, L)), np.zeros((N, 2, D), dtype=np.bool_), np.zeros(N),
                        np.empty(N, np.int64), np.empty((N, 2, D), np.int64), np.empty((N, 2, D)),
                        np.empty(N, np.int64), np.empty(N))
    # a fiber's contributions deferred: formed only for the candidates the roulette keeps (SHADOW_BOUND)
    defer = roulette and bool(SHADOW_BOUND) and setup.kind == K_FIBER
    inputs = setup.inputs._replace(defer_nee=True) if defer else setup.inputs
    cidx = np.empty((N * 2 * D, 3), np.int64)
    csize, cp = np.empty(N * 2 * D), np.empty(N * 2 * D)
    cstate = np.empty(N * 2 * D, np.int8)
    traced = np.empty(N * 2 * D, np.int64)
    s_orig, s_dir = np.empty((N * 2 * D, 3)), np.empty((N * 2 * D, 3))
    low = np.empty(N, np.bool_)
    nxt = (np.empty((N, 3)), np.empty((N, 3)), np.empty((N, L)), np.empty(N, np.int64), np.empty(N, np.int64))
    no_draws = np.empty(0)
    log = None
    if record:
        from simulate.raytrace.record import EventLog

        if not defer:
            raise ValueError("trace: a re-weighting record needs a fiber material traced with its next-event "
                             "contributions deferred (SHADOW_ROULETTE and SHADOW_BOUND)")
        log = EventLog(N, n, G, D)
    for _bounce in range(events):
        if ray.size == 0:
            break
        hits = scene.intersect(origins, dirs, stats)
        azimuth = np.arctan2(dirs[:, 1], dirs[:, 0])
        M, lost, continued, self_hits = _tally_escapes(hits.prim, ray, last, dirs, azimuth, weight, n, n_mu, n_phi,
                                                       refl, trans, sums.bins, sums.bins2, hit_ray, hit_idx)
        sums.lost += lost
        sums.continued += continued
        sums.self_hits += self_hits
        if M == 0:
            ray = ray[:0]
            break
        _gather_hits(hit_idx, M, hits.prim, hits.u, hits.v, hits.position, dirs, weight, hp, hu, hv, hpos, hd, hw)
        h_ray = hit_ray[:M]
        hit_group = h_ray // n
        out = ShadeOutputs(*(x[:M] for x in work))
        if setup.kind == K_FIBER_BRDF:
            out.hit_albedo[...] = 0.0
        cuts = np.searchsorted(hit_group, np.arange(G + 1)) if G > 1 else np.array([0, M])
        seeds = _group_seeds(rng, cuts, G)
        shade_groups(seeds, cuts, hp[:M], hu[:M], hv[:M], hpos[:M], hd[:M], hw[:M], inputs, detectors, out)
        o, d, w, nee_o, nee_c, need, alb, left, nee_row, nee_scale, out_row, out_scale = out
        if setup.kind == K_FIBER_BRDF:
            sums.hits += int(alb.size)
            sums.albedo_sum += float(alb.sum())
            sums.albedo_over_one += int(np.count_nonzero(alb > 1.0))
        if defer:
            c, n_draw = _bounded_candidates(need, nee_row, nee_scale, hw[:M], setup.t_max, hit_group, D, cand,
                                            level_scale, cidx, csize, cp, cstate, binsum)
        else:
            c, n_draw = _shadow_candidates(need, nee_c, hit_group, D, cand, level_scale, roulette, cidx, csize, cp,
                                           cstate, binsum)
        if c:
            sums.shadow_candidates += int(c)
            draws = shadow_rng.random(int(n_draw)) if n_draw else no_draws
            t = _shadow_rays(c, cstate, cp, draws, cidx, nee_o, detectors, hit_group, wrap, lx, ly, traced,
                             s_orig, s_dir)
            if t:
                before = stats["queries"]
                vis = scene.visible(s_orig[:t], s_dir[:t], stats)
                sums.shadow_rays += int(t)
                sums.shadow_queries += stats["queries"] - before
                vis = np.ascontiguousarray(vis, dtype=np.bool_)
                if defer:
                    _score_visible_bounded(t, traced, vis, cidx, cp, nee_row, nee_scale, hw[:M], setup.t_rows,
                                           h_ray, acc)
                else:
                    _score_visible(t, traced, vis, cidx, cp, nee_c, h_ray, acc)
                if log is not None:
                    log.scores(traced[:t][vis], cidx, cp, nee_row, nee_scale)
        # Russian roulette on the largest spectral weight, then the live rays compacted
        n_low = _path_roulette(w, _ROULETTE_BELOW, low)
        draws = rng.random(int(n_low)) if n_low else no_draws
        if log is not None:
            log.hits(h_ray, out_row, out_scale, low[:M], draws, ROULETTE_SURVIVE)
        a = _survivors(o, d, w, left, h_ray, low, draws, ROULETTE_SURVIVE, wrap, lx, ly, *nxt)
        # the next wavefront: the compacted rows (written from the shading's outputs, never read from)
        origins, dirs, weight, ray, last = (x[:a] for x in nxt)
    sums.killed += int(ray.size)
    tot = acc.reshape(G, n, D, L)  # per-ray totals
    sums.nee += tot.sum(axis=1)
    sums.nee2 += np.einsum("gndl,gndl->gdl", tot, tot)
    refl = refl.reshape(G, n, L)
    trans = trans.reshape(G, n, L)
    sums.refl += refl.sum(axis=1)
    sums.refl2 += (refl ** 2).sum(axis=1)
    sums.trans += trans.sum(axis=1)
    sums.trans2 += (trans ** 2).sum(axis=1)
    sums.energy2 += ((refl + trans) ** 2).sum(axis=1)
    sums.embree_rays = stats["queries"]
    if log is not None:
        sums.log = log.close()
    return sums


def mean_se(s: np.ndarray, s2: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """The mean of ``n`` per-ray contributions from their sum ``s`` and sum of squares ``s2``, and its standard error.

    Parameters
    ----------
    s, s2 : numpy.ndarray
        The sums of the contributions and of their squares.
    n : int
        The rays.

    Returns
    -------
    mean, u : numpy.ndarray
        The mean per ray and its standard error.
    """
    mean = s / n
    var = np.maximum(s2 / n - mean ** 2, 0.0) / max(n - 1, 1)
    return mean, np.sqrt(var)


def _rel_err(value: np.ndarray, u: np.ndarray) -> float:
    """:func:`simulate.montecarlo.accuracy.relative_error`, with a warning when no light reached any detector."""
    if float(np.abs(value).max(initial=0.0)) == 0.0:
        # nothing reached any detector (e.g. all of them below a black weave's horizon): the
        # estimate 0 has no spread; stopping beats tracing for ever
        log.warning("fabric MC: no light reached any detector direction")
        return 0.0
    return relative_error(value, u)


def trace(mesh: Any, material: Lambert | FiberSurface | FiberBRDFAtHit, w_in: Any, detectors: Any, n_wavelengths: int | None = None,
          *, target_rel_err: float = 0.01, max_rays: int = 0, max_seconds: float = 0.0, seed: int = 0,
          threads: int = 1, progress: bool = False, bins: tuple[int, int] = (9, 12),
          chunk: int = CHUNK, twist_deg: tuple[float, float] = (0.0, 0.0), normals: str = "vertex",
          setups: dict | None = None, max_events: int = 0, record: list | None = None) -> MCResult:
    """Trace the beam from ``w_in`` through the woven micro-element; next-event ``beta`` at ``detectors``.

    Parameters
    ----------
    mesh : simulate.geometry.mesh.FabricMesh
        The micro-element (or :func:`simulate.geometry.validation.flat_mesh`).
    material : Lambert, FiberSurface or FiberBRDFAtHit
        The yarns' material: a Lambertian albedo, or a fiber surface over a yarn table.
    w_in : (3,) array
        Unit direction towards the source, fabric frame (``z > 0``).
    detectors : (D, 3) array
        Unit detector directions (``z > 0``).
    n_wavelengths : int, optional
        Spectral size (default: the material's table, or 1 for a scalar Lambert albedo).
    target_rel_err : float
        Stop when the RMS relative standard error (module docstring) is at most this.
    max_rays, max_seconds : int, float
        Budgets (0 = none); the result's ``stop`` says which ended the run.
    seed : int
        Chunk ``c`` uses the stream ``(seed, c)``: results do not depend on ``threads``.
    threads : int
        Chunks traced concurrently (Embree and the compiled shading release the GIL).
    progress : bool
        Show a progress bar (tqdm) of the rays traced.
    bins : (int, int)
        ``(n_mu, n_phi)`` exit-direction bins of the escaped rays' tally.
    chunk : int
        Rays per chunk (a wavefront); the error is checked after every 4 chunks.
    twist_deg : (float, float)
        Surface twist angle of the warp and the weft yarns, signed: ``+`` Z, ``-`` S (the yarn table
        and the shading use the local fiber direction, :mod:`simulate.raytrace.shading`); ``(0, 0)``:
        the fibers run along the yarn's axis.
    normals : "vertex" or "face"
        Shading normals: the mesh's interpolated vertex normals (with the adjoint shading-normal
        rule of :mod:`simulate.raytrace.shading`), or the triangles' own normals (a faceted tube).
    setups : dict, optional
        Kept across calls by the caller: the scene and the material arrays (a noticeable cost for a felt's
        hundreds of thousands of triangles) are built once per mesh and material and reused (a felt traced at several rotations).
    max_events : int
        Scattering events followed per ray (0: all, up to the tracer's limit of 200). ``1`` scores the
        single scattering only: the next-event estimates of each ray's first hit, shadow rays included
        (the shadow-hiding reference, tests/simulate/raytrace/test_felt_shadow_hiding.py).
    record : list, optional
        The trace's events are appended to it (:class:`simulate.raytrace.record.TraceLog`), from which
        :mod:`simulate.raytrace.reweight` recomputes the result for another dye without tracing again.
    """
    w_in = np.asarray(w_in, float).reshape(1, 3)
    det = np.atleast_2d(np.asarray(detectors, float))[None]
    return _trace(mesh, material, w_in, det, n_wavelengths, target_rel_err=target_rel_err, max_rays=max_rays,
                  max_seconds=max_seconds, seed=seed, threads=threads, progress=progress, bins=bins, chunk=chunk,
                  twist_deg=twist_deg, normals=normals, setups=setups, max_events=max_events, record=record)[0]


def trace_rotations(mesh: Any, material: Lambert | FiberSurface | FiberBRDFAtHit, w_in: Any, detectors: Any,
                    angles: Any, n_wavelengths: int | None = None, *, target_rel_err: float = 0.01,
                    max_rays: int = 0, max_seconds: float = 0.0, seed: int = 0, threads: int = 1,
                    progress: bool = False, bins: tuple[int, int] = (9, 12), chunk: int = CHUNK,
                    twist_deg: tuple[float, float] = (0.0, 0.0), normals: str = "vertex",
                    setups: dict | None = None, max_events: int = 0, record: list | None = None) -> list[MCResult]:
    """:func:`trace` of the incidence and its detectors turned about the normal by each of ``angles`` (radians).

    The rotations are traced together: every chunk holds ``chunk`` rays of each rotation and each
    bounce of all of them is one Embree query (a felt's rotations, :mod:`simulate.raytrace.estimate`).
    Returns one :class:`MCResult` per rotation (``rays``: its own; ``seconds``: an equal share;
    ``info``: the whole trace's). The run stops when the MEAN over the rotations reaches
    ``target_rel_err`` (its standard error ``sqrt(sum u_j^2) / K``); ``max_rays`` is the budget
    of all rotations together, ``max_seconds`` of the whole trace.

    Parameters
    ----------
    mesh, material, w_in, detectors, n_wavelengths
        As :func:`trace`'s.
    angles : array_like
        The rotations about the normal (radians).
    target_rel_err : float
        Target of the mean over the rotations.
    max_rays, max_seconds : int, float
        Budgets of all rotations together (0: none).
    seed, threads, progress, bins, chunk, twist_deg, normals, setups, max_events, record
        As :func:`trace`'s.

    Returns
    -------
    list of MCResult
        One per rotation.
    """
    w = np.asarray(w_in, float).reshape(3)
    det = np.atleast_2d(np.asarray(detectors, float))
    rots = [np.array([[math.cos(a), -math.sin(a), 0.0], [math.sin(a), math.cos(a), 0.0], [0.0, 0.0, 1.0]])
            for a in np.asarray(angles, float).reshape(-1)]
    if not rots:
        raise ValueError("trace_rotations: at least one angle")
    w_all = np.stack([r @ w for r in rots])
    det_all = np.stack([det @ r.T for r in rots])
    return _trace(mesh, material, w_all, det_all, n_wavelengths, target_rel_err=target_rel_err,
                  max_rays=max_rays // len(rots) if max_rays else 0, max_seconds=max_seconds, seed=seed,
                  threads=threads, progress=progress, bins=bins, chunk=chunk, twist_deg=twist_deg,
                  normals=normals, setups=setups, max_events=max_events, fit_last_round=True, record=record)


def _setup_for(mesh: Any, material: Any, n_wavelengths: int | None, bins: tuple[int, int],
               twist_deg: tuple[float, float], normals: str, setups: dict | None) -> _Setup:
    """The :class:`_Setup` of a trace: from ``setups`` when there, else built (and kept there)."""
    if n_wavelengths is None:
        n_wavelengths = (material.table.T.shape[-1] if isinstance(material, (FiberSurface, FiberBRDFAtHit))
                         else int(np.size(material.rho)))
    if normals not in ("vertex", "face"):
        raise ValueError(f"trace: normals must be 'vertex' or 'face', got {normals!r}")
    key = (id(mesh), id(material), int(n_wavelengths), tuple(bins), tuple(twist_deg), normals)
    setup = setups.get(key) if setups is not None else None
    if setup is None:
        setup = _Setup(mesh, material, int(n_wavelengths), bins, twist_deg, normals)
        if setups is not None:
            setups[key] = setup
    return setup


def prepare(mesh: Any, material: Any, setups: dict, *, n_wavelengths: int | None = None,
            bins: tuple[int, int] = (9, 12), twist_deg: tuple[float, float] = (0.0, 0.0),
            normals: str = "vertex") -> None:
    """Build the scene and material arrays of a trace ahead of it into ``setups``.

    They are the arrays :func:`trace` or :func:`trace_rotations` with the same arguments and ``setups``
    would build at its start (e.g. on another thread while an earlier mesh is traced:
    :func:`simulate.raytrace.estimate.fabric_beta`); the traces then start at once.

    Parameters
    ----------
    mesh, material, setups, n_wavelengths, bins, twist_deg, normals
        As :func:`trace`'s.
    """
    _setup_for(mesh, material, n_wavelengths, bins, twist_deg, normals, setups)


def _events_of(max_events: Any) -> int:
    """The scattering events a ray is followed for: ``max_events`` (0: all) capped at the tracer's limit."""
    if isinstance(max_events, bool) or not isinstance(max_events, (int, np.integer)) or max_events < 0:
        raise ValueError(f"trace: max_events must be a whole number >= 0 (0: all events), not {max_events!r}")
    return min(int(max_events), _MAX_BOUNCES) if max_events else _MAX_BOUNCES


def _check_directions(w_in: np.ndarray, det: np.ndarray) -> None:
    """Refuse incidences and detectors at or below the fabric's plane; warn of grazing ones (beyond 85 deg)."""
    # 90 deg exactly (cos 90 deg is 6e-17 in floating point) is an error, not a ray that wraps for ever
    if np.any(w_in[:, 2] <= 1e-12) or np.any(det[..., 2] <= 1e-12):
        raise ValueError("trace: w_in and the detectors must point above the fabric (z > 0)")
    if min(float(w_in[:, 2].min()), float(det[..., 2].min())) < math.cos(math.radians(85.0)):
        from simulate.optics.microfacet import OpticsDomainWarning

        # stacklevel 4: the caller of trace / trace_rotations (this helper, _trace, then theirs)
        warnings.warn("fabric MC: directions more than 85 deg from the normal: the next-event radiance goes "
                      "as 1/cos(theta_o) and few rays reach the fabric at grazing incidence; the relative "
                      "error there is large (it is in u_beta)", OpticsDomainWarning, stacklevel=4)


def _stop_of(rel: float, target_rel_err: float, rays: int, max_rays: int, started: float,
             max_seconds: float) -> str | None:
    """Which stop ends a trace after a round (``target``, ``max_rays``, ``max_seconds``, in that order), or None."""
    if rel <= target_rel_err:
        return "target"
    if max_rays and rays >= max_rays:
        return "max_rays"
    if max_seconds and time.perf_counter() - started >= max_seconds:
        return "max_seconds"
    return None


def _progress_bar() -> Any:
    """The trace's progress bar (tqdm), counting rays; closed when the trace ends."""
    from tqdm import tqdm

    return tqdm(total=None, unit="ray", desc="fabric MC", leave=False)


def _trace(mesh: Any, material: Any, w_in: np.ndarray, det: np.ndarray, n_wavelengths: int | None, *,
           target_rel_err: float, max_rays: int, max_seconds: float, seed: int, threads: int, progress: bool,
           bins: tuple[int, int], chunk: int, twist_deg: tuple[float, float], normals: str,
           setups: dict | None, max_events: int = 0, fit_last_round: bool = False,
           record: list | None = None) -> list[MCResult]:
    """:func:`trace` of ``G`` groups (rotations) at once, stopped on their mean error.

    ``w_in [G, 3]``, ``det [G, D, 3]``; ``max_rays`` per group (:func:`trace_rotations`). ``fit_last_round``: after the first
    round, each round's chunks hold only the rays the target still needs (predicted from the error
    so far, between ``chunk / 8`` and ``chunk`` a group), so a run overshoots its target by less
    than a round of full chunks; the sizes follow from the sums alone (not from the threads). ``record``: a
    :class:`simulate.raytrace.record.TraceLog` of the trace's events is appended to it (a dye's re-weighting).
    """
    target_rel_err = check_target(target_rel_err)
    events = _events_of(max_events)
    det = np.ascontiguousarray(det)
    G = w_in.shape[0]
    _check_directions(w_in, det)
    setup = _setup_for(mesh, material, n_wavelengths, bins, twist_deg, normals, setups)
    L = setup.n_wl
    D = det.shape[1]
    total = _new_sums(G, D, L, bins)
    started = time.perf_counter()
    c = 0
    next_size = int(chunk)
    stop = "target"
    rel = float("inf")
    bar = _progress_bar() if progress else None
    pool = ThreadPoolExecutor(max_workers=max(1, int(threads))) if threads and threads > 1 else None
    logs: list = []
    try:
        while True:
            jobs = [(seed, c + r) for r in range(_ROUND)]
            size = int(chunk) if c == 0 or not fit_last_round else next_size
            if max_rays:   # the last round is cut so the budget is kept exactly
                size = max(1, min(size, (int(max_rays) - total.rays) // _ROUND))
            keep = record is not None
            if pool is None:
                parts = [_chunk(setup, w_in, det, size, s, events, keep) for s in jobs]
            else:
                parts = list(pool.map(lambda s, size=size, keep=keep: _chunk(setup, w_in, det, size, s, events, keep), jobs))
            if keep:
                logs.extend(p.log for p in parts)
            for p in parts:     # in chunk order: the sums do not depend on the threads
                total.add(p)
            c += _ROUND
            if total.lost > 0.5 * G * total.rays:
                raise ValueError(f"trace: {total.lost} of {G * total.rays} rays never reached the fabric (they run "
                                 "parallel to it through the gaps); the incidence is too grazing for this weave")
            mean, u = mean_se(total.nee, total.nee2, total.rays)
            rel = _rel_err(mean.mean(axis=0), np.sqrt((u ** 2).sum(axis=0)) / G)
            if bar is not None:
                bar.update(_ROUND * size * G)
                bar.set_postfix_str(f"rel. err {rel:.3%} (target {target_rel_err:.2%})")
            ended = _stop_of(rel, target_rel_err, total.rays, max_rays, started, max_seconds)
            if ended is not None:
                stop = ended
                break
            if fit_last_round:   # the rays the target still needs (rel ~ 1 / sqrt(rays)); short: one more round
                need = total.rays * ((rel / target_rel_err) ** 2 - 1.0) / _ROUND
                next_size = int(min(chunk, max(chunk // 8, math.ceil(need) if math.isfinite(need) else chunk)))
    finally:
        if pool is not None:
            pool.shutdown()
        if bar is not None:
            bar.close()
    seconds = time.perf_counter() - started
    n = total.rays
    cos_o = det[..., 2][..., None]
    mu_edges = np.linspace(0, 1, bins[0] + 1)
    omega = (0.5 * np.diff(mu_edges ** 2)[:, None] * (2 * np.pi / bins[1]))[:, :, None]
    info: dict[str, Any] = {"lost_rays": total.lost, "killed_at_max_bounces": total.killed, "embree_rays": total.embree_rays,
            "rays_per_second": total.embree_rays / seconds if seconds > 0 else None, "chunk": int(chunk),
            "self_hit_fraction": total.self_hits / max(total.continued, 1),
            "shadow_candidates": total.shadow_candidates, "shadow_rays": total.shadow_rays,
            "shadow_queries": total.shadow_queries}
    if setup.kind == K_FIBER_BRDF:
        info["local_albedo"] = {"hits": total.hits, "mean_max_over_wavelengths": total.albedo_sum / max(total.hits, 1),
                                "fraction_above_one": total.albedo_over_one / max(total.hits, 1)}
    log.info("fabric MC: %d rays, %.1f s, rel. err %.3g (%s)", n * G, seconds, rel, stop)
    if record is not None:
        from simulate.raytrace.record import TraceLog

        record.append(TraceLog(logs, G, D, L, np.array(det), n, tuple(setup.t_rows.shape)))
    out = []
    for g in range(G):
        mean, u = mean_se(total.nee[g], total.nee2[g], n)
        refl, u_refl = mean_se(total.refl[g], total.refl2[g], n)
        trans, u_trans = mean_se(total.trans[g], total.trans2[g], n)
        _, u_energy = mean_se(total.refl[g] + total.trans[g], total.energy2[g], n)
        f_bins, u_bins = mean_se(total.bins[g], total.bins2[g], n)
        out.append(MCResult(np.pi * mean / cos_o[g], np.pi * u / cos_o[g], refl, u_refl, trans, u_trans,
                            f_bins / omega, u_bins / omega, n, seconds / G,
                            rel if G == 1 else _rel_err(mean, u), stop,
                            {"u_reflected_plus_transmitted": u_energy.tolist(), **info}))
    return out
