r"""The structured summation in ``simulate fit``: one walk per lattice point, any dye, any structure.

``simulate fabric --method summation`` on a config with ``[structure]`` evaluates
:func:`simulate.fabric.structure.structured_beta`: two independent exit tables of the fiber
(:func:`simulate.fiber.farfield.exit_table`), their layer tables with the interior closure
(:mod:`simulate.fabric.fiberlayer`, :mod:`simulate.fabric.interior`) and the facet sum over the
fabric's visible fiber orientations (:mod:`simulate.fabric.structure`). The fit evaluates the SAME
model, split by what each free parameter changes:

* **dye** (host absorption): every exit-table walk is white (absorption applied per path), so the
  exit table is scored at the ``K`` host-absorption nodes of :mod:`simulate.fiber.absorption` at
  once (each wavelength becomes ``K`` channels: ``mu_a = mu_a,particles + nu_k``). Every later
  step -- the symmetrisation, the interior closure (Stokes' adding, nonlinear in the table), the
  layer table and the facet sum -- acts on each channel alone, so the fabric's ``beta`` is known
  at every node exactly as ``simulate fabric`` would compute it with a dye of that absorption,
  and a dye spectrum is read between the nodes by the absorption table's monotone cubic in
  ``log beta`` over ``log(nu + 1e-4)`` (:class:`simulate.fiber.absorption.AbsorptionTable`, the
  same interpolation as the top-cell fit: ~1e-3 relative). The fabric's ``beta`` falls
  monotonically with the absorption (the closure included), which the cubic keeps.
* **structure** (``structure.felt_spread_deg``, ``structure.warp_twist_deg``,
  ``structure.weft_twist_deg``): only the facets change; the layer tables at the nodes are kept,
  the facet sum (compiled, :func:`simulate.fabric.structtable.facet_sum`) is re-run -- no photon.
* **surface** (``surface.rms_slope``): the layer's surface term is its own table
  (:func:`simulate.fabric.fiberlayer.surface_table`, analytic) summed over the same facets. The
  interior closure's share of the surface's Fresnel energy is computed at the config's starting
  RMS slope (the table is not rebuilt per evaluation; the returned light is diffuse and its surface
  part a few per cent of it): stated limit.
* **scattering** (volume fraction, particle size, fiber radius): walked at the lattice points of
  :meth:`studies.fit_problem.FitProblem.lattice` and re-weighted between them by the likelihood
  ratio within the variance bound, as the top-cell fit does (the same rule, the same seeds).

Memory. A chunk of at most 7 wavelengths (the exit table's own chunks, so the streams are the
ones ``simulate fabric`` walks) times ``K = 16`` nodes is 112 channels: its exit table (~0.6 GB)
is reduced to its layer table (~26 MB) before the next chunk is walked.

Deterministic: the photons per row come from ``target_rel_err`` by :func:`photons_per_row` (no
accuracy loop) and the seeds from the config's seed: the streams of the FIRST round of
:func:`simulate.fiber.farfield.controlled_halves` (seeds ``2 seed + half``). ``simulate fabric
--method summation`` grows its tables in rounds until beta's error meets the target; the fit's model
is that summation in its fixed-photons mode, ``structured_beta(..., photons_per_row=photons_per_row(target))``
(one round, the same streams), which is what the equality test compares with.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any, Callable

import numba
import numpy as np

from simulate.fiber.absorption import AbsorptionTable, absorption_targets
from simulate.montecarlo.tallies import S_LAUNCHED, S_SCATTERINGS

__all__ = ["STRUCTURE_FIELDS", "StructWalk", "walk_structure", "facets_of", "surface_beta", "structure_key"]

#: The ``[structure]`` fields a fit may free, with their valid ranges (simulate.fabric.structure's schema).
STRUCTURE_FIELDS = {"structure.felt_spread_deg": (0.0, 60.0), "structure.warp_twist_deg": (0.0, 60.0),
                    "structure.weft_twist_deg": (0.0, 60.0)}


def structure_key(config: Any) -> tuple:
    """What the facets depend on: the structure spec and the weave."""
    spec = config.structure
    return (spec, repr(getattr(config, "weave", None)) if spec.kind == "woven" else None)


def facets_of(config: Any) -> Any:
    """The facets of ``config``'s structure (:func:`simulate.fabric.structure.facets_for`)."""
    from simulate.config import weave_from_config
    from simulate.fabric.structure import facets_for

    spec = config.structure
    weave = weave_from_config(config) if spec.kind == "woven" else None
    return facets_for(spec, weave)


def surface_beta(config: Any, facets: Any, w_i: np.ndarray, w_o: np.ndarray) -> np.ndarray:
    """``beta [N]`` of the layers' surface term (Cook-Torrance with masking) summed over ``facets``."""
    from simulate.fabric.fiberlayer import LayerTable, layer_grid, surface_table
    from simulate.fabric.structtable import facet_sum

    spec = config.structure
    th, ph_i, ph_o, _ = layer_grid(7.5, 15.0)
    G = surface_table(float(config.rms_slope), float(config.n_host), bool(spec.masking), float(spec.spacing_ratio),
                      7.5, 15.0)[..., None]
    lt = LayerTable(th, ph_i, th, ph_o, np.ascontiguousarray(G), spec.masking, spec.spacing_ratio)
    return math.pi * facet_sum(lt, facets, w_i, w_o)[:, 0] / (w_i[:, 2] * w_o[:, 2])


@dataclass
class StructWalk:
    """Layer tables (volume and interior return, no surface) at every (wavelength, node) channel, two halves.

    ``G[h]`` is ``[Ti, Pi, To, Po, L * K]`` (channel ``l K + k``); ``optics``, ``groups`` and
    ``scatterings`` are what :meth:`studies.fit_problem.FitProblem._within_bound` reads.
    """

    G: list
    grid: tuple
    masking: bool
    spacing_ratio: float
    nodes: np.ndarray
    wavelengths_nm: np.ndarray
    photons: dict = field(default_factory=dict)
    seconds: float = 0.0
    scatterings: dict = field(default_factory=dict)
    groups: list = field(default_factory=list)
    optics: Any = None
    layers: int = 0
    _tables: dict = field(default_factory=dict)

    def group_scatterings(self) -> np.ndarray:
        return np.array([self.scatterings.get(f"0:{gi}", 0.0) for gi in range(len(self.groups))])

    @property
    def nu_max(self) -> float:
        return float(self.nodes[-1])

    def table(self, key: tuple, facets: Any, w_i: np.ndarray, w_o: np.ndarray) -> AbsorptionTable:
        """The fabric's volume ``beta`` (and interior return) at the geometries, ``R [N, L, K]``, for ``facets``
        (memoised by ``key``): mean of the halves, ``u`` half their difference (as ``structured_beta``)."""
        if key in self._tables:
            return self._tables[key]
        from simulate.fabric.fiberlayer import LayerTable
        from simulate.fabric.structtable import facet_sum

        th, ph_i, th_o, ph_o = self.grid
        scale = math.pi / (w_i[:, 2] * w_o[:, 2])[:, None]
        betas = [scale * facet_sum(LayerTable(th, ph_i, th_o, ph_o, G, self.masking, self.spacing_ratio), facets,
                                   w_i, w_o) for G in self.G]
        N, L, K = w_i.shape[0], self.wavelengths_nm.size, self.nodes.size
        b = [x.reshape(N, L, K) for x in betas]
        table = AbsorptionTable(R=0.5 * (b[0] + b[1]), u_R=0.5 * np.abs(b[0] - b[1]), nodes=self.nodes,
                                wavelengths_nm=self.wavelengths_nm, photons=self.photons, seconds=self.seconds,
                                scatterings=self.scatterings, groups=self.groups, optics=self.optics)
        if len(self._tables) >= 8:
            self._tables.pop(next(iter(self._tables)))
        self._tables[key] = table
        return table


def photons_per_row(target_rel_err: float) -> int:
    """Photons per exit-table row of each half of the fit's walk: ``PHOTONS_PER_ROW_AT_1PCT (0.01 / target)^2 / 2``
    rounded UP to a multiple of ``FIT_ROW_QUANTUM`` (so at least 2000).

    The fit has no accuracy loop (its dye changes at every evaluation, so the rounds that
    :func:`simulate.fiber.farfield.controlled_halves` would add at one dye mean nothing at another)
    and its objective weighs residuals by the model's two-halves error, which is unreliable at a few
    hundred photons per row (the spectral re-weighting's rare heavy weights; see
    ``PHOTONS_PER_ROW_AT_1PCT``): hence the floor. ``simulate fabric --method summation`` evaluates the
    same model in its fixed-photons mode, :func:`simulate.fabric.structure.structured_beta` with
    ``photons_per_row=`` this number (one round, the first round's streams).
    """
    from simulate.fabric.structure import PHOTONS_PER_ROW_AT_1PCT

    raw = PHOTONS_PER_ROW_AT_1PCT * (0.01 / target_rel_err) ** 2 / 2.0
    return int(math.ceil(raw / FIT_ROW_QUANTUM)) * FIT_ROW_QUANTUM


#: the fit's photons per row are a multiple of this (and at least this): see :func:`photons_per_row`
FIT_ROW_QUANTUM = 2000


def walk_structure(nodye: Any, config: Any, wavelengths_nm: np.ndarray, nodes: np.ndarray, *,
                   target_rel_err: float, seed: int, threads: int | None = None, reference: Any = None,
                   progress: Callable[[int, int, int], None] | None = None, max_group: int = 7) -> StructWalk:
    """Walk the two exit tables of ``nodye`` (the fiber without dye; its roughness is the interior closure's)
    scored at every host-absorption node, and reduce them chunk by chunk to layer tables (module docstring).

    Streams, chunks and photons are those of :func:`simulate.fiber.farfield.exit_table` called by
    :func:`simulate.fabric.structure.structured_beta` in its fixed-photons mode with ``photons_per_row(target_rel_err)``
    (the first round of the controlled halves, seeds ``2 seed + half``). ``reference``: walk
    the photons in that fiber's scattering and score them for ``nodye``'s by the likelihood ratio.
    """
    from simulate.config import weave_from_config
    from simulate.fabric.fiberlayer import layer_grid, layer_table
    from simulate.fabric.interior import interior
    from simulate.fiber import farfield as FF
    from simulate.fiber.bssrdf import bssrdf_rows, lit_rows
    from simulate.fiber.spectral import group_walk, spectral_optics, wavelength_groups
    from simulate.montecarlo.transport import make_control

    t0 = time.perf_counter()
    spec = config.structure
    wl = np.asarray(wavelengths_nm, float)
    fiber = FF.cached(nodye)
    walk_fiber = fiber if reference is None else FF.cached(reference)
    weave = weave_from_config(config) if spec.kind == "woven" else None
    n_layers = spec.layers or (10 if spec.kind == "nonwoven" or weave is None
                               else max(1, round(weave.height_um / fiber.radius_um)))
    per_row = photons_per_row(target_rel_err)
    K = nodes.size
    w_t = np.asarray(FF.DEFAULT_WT_NODES, float)
    n_psi = fiber.cell_count("bssrdf route")
    dpsi = 2.0 * math.pi / n_psi
    k_max = lit_rows(dpsi)
    ks = list(range(-k_max, k_max + 1))
    n_mu, n_phi = 9, 18
    grid = (n_psi, 1, 10.0 * fiber.radius_um, n_mu, n_phi)
    control = make_control()
    chunks = np.array_split(np.arange(wl.size), int(math.ceil(wl.size / max(1, int(max_group)))))
    optics_all = spectral_optics(fiber, wl)
    walk_all = optics_all if reference is None else spectral_optics(walk_fiber, wl)
    groups_global: list[np.ndarray] = []
    scatterings: dict[str, float] = {}
    th, ph_i, ph_o, _ = layer_grid(7.5, 15.0)
    halves: list[np.ndarray] = []
    photons = 0
    runs, run = 2 * len(chunks) * w_t.size, 0
    if progress is not None:
        progress(0, 0, runs)
    for half in range(2):
        G = np.zeros((th.size, ph_i.size, th.size, ph_o.size, wl.size * K))
        for c, chunk in enumerate(chunks):
            optics = spectral_optics(fiber, wl[chunk])
            walk_optics = optics if reference is None else spectral_optics(walk_fiber, wl[chunk])
            groups = wavelength_groups(walk_optics)
            if half == 0:
                first = len(groups_global)
                groups_global += [chunk[g] for g in groups]
            T = np.zeros((w_t.size, len(ks), n_psi, n_mu, n_phi, chunk.size * K))
            for i, wt in enumerate(w_t):
                for gi, group in enumerate(groups):
                    medium, walk_phase, _ = group_walk(walk_fiber, walk_optics, group, white=True)
                    targets = absorption_targets(optics, group, nodes, walk_phase)
                    scal: list = []
                    t, _, p, _ = bssrdf_rows(fiber, float(wt), ks, grid, medium, walk_phase, targets, control, per_row,
                                             int(seed_of(seed, half, i, c)), threads, scal)
                    T[i, ..., int(group[0]) * K:(int(group[-1]) + 1) * K] = t[:, :, 0]   # groups: consecutive
                    photons += int(p)
                    n = max(float(s[S_SCATTERINGS]) / max(float(s[S_LAUNCHED]), 1.0) for s in scal)
                    key = f"0:{first + gi}" if half == 0 else None
                    if key is not None:
                        scatterings[key] = max(scatterings.get(key, 0.0), n)
                run += 1
                if progress is not None:
                    progress(photons, run, runs)
            _symmetrise(T)
            table = FF.ExitTable(w_t=w_t, T=T, u_T=np.zeros(1), k=np.array(ks), radius_um=fiber.radius_um,
                                 wavelengths_nm=np.repeat(wl[chunk], K), n_host=float(fiber.n_host))
            inner = None
            if spec.interior and spec.masking:
                inner = interior(table, fiber, n_layers, spacing_ratio=spec.spacing_ratio,
                                 directional=spec.interior_return == "directional")
            lt = layer_table(table, fiber, masking=spec.masking, spacing_ratio=spec.spacing_ratio, interior=inner,
                             surface=False)
            G[..., chunk[0] * K:(chunk[-1] + 1) * K] = lt.G
            del table, T
        halves.append(G)
    del walk_all
    return StructWalk(G=halves, grid=(th, ph_i, th, ph_o), masking=spec.masking, spacing_ratio=spec.spacing_ratio,
                      nodes=nodes, wavelengths_nm=wl, photons={"exit_tables": photons, "per_row": per_row},
                      seconds=time.perf_counter() - t0, scatterings=scatterings, groups=groups_global,
                      optics=optics_all, layers=n_layers)


@numba.njit(cache=True, parallel=True)
def _symmetrise(T):
    """In place, :func:`simulate.fiber.farfield._symmetrised` (each row averaged with the mirror image of its
    opposite: row ``r -> R-1-r``, exit cell ``o -> -o``, exit azimuth bin ``p -> P-1-p``) in one pass
    without the three ``[W, K, n_psi, n_mu, n_phi, L]`` temporaries (16 s of a 133 s walk on the felt)."""
    W, R, O, M, P, C = T.shape
    for w in numba.prange(W):
        for r in range(R):
            for o in range(O):
                for p in range(P):
                    r2, o2, p2 = R - 1 - r, (O - o) % O, P - 1 - p
                    if (r2, o2, p2) < (r, o, p):
                        continue          # the pair was done from its other member
                    for m in range(M):
                        for c in range(C):
                            v = 0.5 * (T[w, r, o, m, p, c] + T[w, r2, o2, m, p2, c])
                            T[w, r, o, m, p, c] = v
                            T[w, r2, o2, m, p2, c] = v


def seed_of(seed: int, half: int, node: int, chunk: int) -> int:
    """The stream of exit-table node ``node``, chunk ``chunk`` of half ``half``: :func:`simulate.fiber.farfield.exit_table`'s
    rule with ``structured_beta``'s seed ``2 seed + half``."""
    return (2 * int(seed) + half) * 1_000_003 + 104_729 * node + 1_009 * chunk
