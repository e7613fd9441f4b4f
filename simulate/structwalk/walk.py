r"""The structured summation in ``simulate fit``: one walk per lattice point, any dye, any structure.

``simulate fabric --method summation`` on a config with ``[structure]`` evaluates
:func:`simulate.fabric.structure.structured_beta`: two independent exit tables of the fiber
(:func:`simulate.fiber.farfield.exit_table`), their layer tables with the interior closure
(:mod:`simulate.fabric.fiberlayer`, :mod:`simulate.fabric.interior`) and the facet sum over the
fabric's visible fiber orientations (:mod:`simulate.fabric.structure`). The fit evaluates the SAME
model from the same steps -- :func:`~simulate.fabric.structure.layer_table_of` (layer table with the
closure), :func:`~simulate.fabric.structure.surface_layer_table`, :func:`simulate.fabric.structtable.facet_sum`
(the facet sum of :func:`~simulate.fabric.structure.fabric_beta_from_G`), :func:`~simulate.fabric.structure.mean_of_halves` and
:func:`~simulate.fabric.structure.interior_layers` -- split by what each free parameter changes:

* **dye** (host absorption): every exit-table walk is white (absorption applied per path), so the
  exit table is scored at the ``K`` host-absorption nodes of :mod:`simulate.fiber.absorption` at
  once (each wavelength becomes ``K`` channels: ``mu_a = mu_a,particles + nu_k``). Every later
  step -- the symmetrisation, the interior closure (Stokes' adding, nonlinear in the table), the
  layer table and the facet sum -- acts on each channel alone, so the fabric's ``beta`` is known
  at every node exactly as ``simulate fabric`` would compute it with a dye of that absorption,
  and a dye spectrum is read between the nodes by the absorption table's monotone cubic in
  ``log beta`` over ``log(nu + 1e-4)`` (:class:`simulate.fiber.absorption.AbsorptionTable`, the
  same interpolation as the top-cell fit). Its error, measured on the same photons against a node
  placed at the dye (the felt of ``tests/fabric_optics/fitting/test_fit_structure.py``, 450-650 nm, 23
  geometries): at 0.058 /um -0.3 to -0.5 % of the volume term on average (at most 0.65 %), at
  0.32 /um +0.1 to +0.3 % (at most 1.5 %), at 0.01 and 2 /um below 0.2 %. The fabric's ``beta`` falls
  monotonically with the absorption (the closure included), which the cubic keeps.
* **structure** (``structure.felt_spread_deg``, ``structure.warp_twist_deg``,
  ``structure.weft_twist_deg``): only the facets change; the layer tables at the nodes are kept,
  the facet sum (compiled, :func:`simulate.fabric.structtable.facet_sum`) is re-run -- no photon.
* **surface** (``surface.rms_slope``): the layer's surface term is its own table
  (:func:`simulate.fabric.fiberlayer.surface_table`, analytic) summed over the same facets. The
  interior closure's share of the surface's Fresnel energy is computed at the config's starting
  RMS slope (the table is not rebuilt per evaluation; the returned light is diffuse and its surface
  part a few per cent of it): stated limit.
* **scattering** (volume fraction, particle size, fiber radius): walked at the lattice points
  ``start * exp(0.2 k)`` and read between them multilinearly in ``log v``
  (:meth:`fabric_optics.fitting.problem.FitProblem.lattice_corners`). The top-cell fit re-weights the walk at
  the nearest lattice point instead; here a re-weighted pass walks the same paths again (as long as a
  walk), so only the lattice points are walked.
* **wavelengths**: a spectral measurement finer than 20 nm is walked at every 20 nm
  (:func:`walk_wavelengths`) and read linearly in the wavelength at each absorption node; the dye is
  applied at every model wavelength.

Disk cache. Each (half, chunk) layer table is stored in :mod:`simulate.fiber.tablecache` (its
atomic writes, checksums and size bound) under :func:`walk_key`: the content hash of the fiber
WITHOUT dye, the walk's part of ``[structure]``, wavelengths, nodes, photons per row, seed and the
code (:data:`WALK_MODULES`). The walk is white, so the dye is not in the key: another colour of the
same felt (a dye-only refit after the structure was fitted: the "structure transfer"),
``--resume``, the Monte Carlo fit's surrogate (:mod:`fabric_optics.fitting.spacemapping`) and any re-run read it. The
felt's walk is 17 wavelengths x 16 nodes x ~55 000 grid values x 8 bytes x 2 halves = 240 MB (the
default bound, 2 GiB, holds 8 of them).

Memory. A chunk of at most 7 wavelengths (the exit table's largest wavelength group) times ``K = 16``
nodes is 112 channels: its exit table (~0.6 GB) is reduced to its layer table (~26 MB) before the next
chunk is walked.

Deterministic: the photons per row come from ``target_rel_err`` by :func:`photons_per_row` (no
accuracy loop) and the seeds from the config's seed: the streams of the FIRST round of
:func:`simulate.fiber.farfield.controlled_halves` (seeds ``2 seed + half``; wavelength group ``k`` on the
exit table's stream of group ``k``, :func:`seed_of`). ``simulate fabric
--method summation`` grows its tables in rounds until beta's error meets the target; the fit's model
is that summation in its fixed-photons mode, ``structured_beta(..., photons_per_row=photons_per_row(target))``
(one round, the same streams where the wavelength groups are the same), which is what the equality test
compares with. The groups are formed per chunk and not blended across their boundary: on a 17-wavelength
felt they differ from the exit table's (the same expectation, other Monte Carlo errors).

Length (~520 lines): the walk, its chunk and its cache key stay together -- this module's source is part of
every walk's key (:data:`WALK_MODULES`); the threads' scheduling is apart (:mod:`simulate.structwalk.threads`).
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numba
import numpy as np

from simulate.fabric.structure import FELT_ONLY_KEYS
from simulate.fiber.absorption import AbsorptionTable, absorption_targets
from simulate.fiber.farfield import EXIT_TABLE_MODULES, plain_fiber
from simulate.montecarlo.tallies import S_LAUNCHED, S_SCATTERINGS
from simulate.structwalk.threads import Progress, plan, run_entries

log = logging.getLogger(__name__)

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
    """The layers' surface term (Cook-Torrance with masking) summed over ``facets``.

    The surface term is analytic (:func:`simulate.fabric.structure.surface_layer_table`), so the fit sums it
    over the facets apart from the walked volume term, through
    :func:`~simulate.fabric.structure.fabric_beta_from_G`.

    Parameters
    ----------
    config : Config
        The fabric's config: its ``structure``, ``rms_slope`` and ``n_host``.
    facets : Facets
        The visible fiber orientations (:func:`facets_of`).
    w_i, w_o : numpy.ndarray
        Incident and exit directions, ``[N, 3]`` unit vectors.

    Returns
    -------
    numpy.ndarray
        ``beta [N]`` of the surface term at the ``N`` geometries.
    """
    from simulate.fabric.structure import fabric_beta_from_G, surface_layer_table

    lt = surface_layer_table(config.structure, config.rms_slope, config.n_host)
    return fabric_beta_from_G(lt, facets, w_i, w_o)[:, 0]


@dataclass
class StructWalk:
    """Layer tables (volume and interior return, no surface) at every (wavelength, node) channel, two halves.

    ``G[h]`` is ``[Ti, Pi, To, Po, L * K]`` (channel ``l K + k``); ``optics``, ``groups`` and
    ``scatterings`` are what :meth:`fabric_optics.fitting.problem.FitProblem._within_bound` reads.
    """

    G: list
    grid: tuple
    spacing_ratio: float
    nodes: np.ndarray
    wavelengths_nm: np.ndarray
    photons: dict = field(default_factory=dict)
    seconds: float = 0.0
    scatterings: dict = field(default_factory=dict)
    groups: list = field(default_factory=list)
    layers: int = 0
    #: ``() -> SpectralOptics`` of the walked fiber (Mie), called on first use of :attr:`optics` only: a dye-only
    #: fit read from the cache never needs it
    optics_fn: Any = None
    #: where the layer tables came from: "miss" (walked and stored), "hit" (read from the disk cache),
    #: "partial" (some chunks read), "off" (no cache)
    cache: str = "off"
    _optics: Any = None
    _tables: dict = field(default_factory=dict)

    @property
    def optics(self) -> Any:
        """The walked fiber's :func:`simulate.fiber.spectral.spectral_optics` (the re-weighting bound reads it)."""
        if self._optics is None and self.optics_fn is not None:
            self._optics = self.optics_fn()
        return self._optics

    def group_scatterings(self) -> np.ndarray:
        """The mean scatterings per photon of each wavelength group of half 0, in group order.

        Returns
        -------
        numpy.ndarray
            One value per entry of :attr:`groups` (0 where a group has no count).
        """
        return np.array([self.scatterings.get(f"0:{gi}", 0.0) for gi in range(len(self.groups))])

    @property
    def nu_max(self) -> float:
        """The largest host-absorption node walked (1/um): the dye's absorption the table reaches."""
        return float(self.nodes[-1])

    def table(self, key: tuple, facets: Any, w_i: np.ndarray, w_o: np.ndarray,
              wavelengths_nm: np.ndarray | None = None) -> AbsorptionTable:
        """The fabric's volume ``beta`` (and interior return) at the geometries, at every absorption node.

        ``R [N, L, K]`` is the mean of the two halves' facet sums and ``u`` half their difference, as in
        :func:`simulate.fabric.structure.structured_beta`. The last eight tables are memoised by ``key``.

        Parameters
        ----------
        key : tuple
            What the facets depend on (:func:`structure_key`) and the geometries: the memo's key.
        facets : Facets
            The visible fiber orientations (:func:`facets_of`).
        w_i, w_o : numpy.ndarray
            Incident and exit directions, ``[N, 3]`` unit vectors.
        wavelengths_nm : numpy.ndarray, optional
            The model's wavelengths, when the walk was walked at fewer (:func:`walk_wavelengths`): ``R``
            and ``u`` are read linearly in the wavelength at every absorption node (the dye is applied
            afterwards at each model wavelength, exactly). None: the walked wavelengths.

        Returns
        -------
        AbsorptionTable
            ``R`` and ``u_R`` over the geometries, wavelengths and nodes, with the walk's counts.

        Raises
        ------
        ValueError
            If ``wavelengths_nm`` reaches outside the walked wavelengths.
        """
        if key in self._tables:
            return self._tables[key]
        from simulate.fabric.fiberlayer import LayerTable
        from simulate.fabric.structtable import facet_sum
        from simulate.fabric.structure import mean_of_halves

        # the compiled facet sum of simulate.fabric.structure.fabric_beta_from_G, times pi / (cos_i cos_o)
        th, ph_i, th_o, ph_o = self.grid
        scale = math.pi / (w_i[:, 2] * w_o[:, 2])[:, None]
        N, L, K = w_i.shape[0], self.wavelengths_nm.size, self.nodes.size
        b = [(scale * facet_sum(LayerTable(th, ph_i, th_o, ph_o, G, True, self.spacing_ratio), facets, w_i, w_o))
             .reshape(N, L, K) for G in self.G]
        R, u = mean_of_halves(b[0], b[1])
        wl = self.wavelengths_nm
        if wavelengths_nm is not None and not np.array_equal(np.asarray(wavelengths_nm, float), wl):
            target = np.asarray(wavelengths_nm, float)
            if target[0] < wl[0] - 1e-9 or target[-1] > wl[-1] + 1e-9:
                raise ValueError("StructWalk.table: model wavelengths outside the walked ones")
            j = np.clip(np.searchsorted(wl, target, side="right") - 1, 0, wl.size - 2)
            f = ((target - wl[j]) / (wl[j + 1] - wl[j]))[None, :, None]
            R = (1.0 - f) * R[:, j] + f * R[:, j + 1]
            u = (1.0 - f) * u[:, j] + f * u[:, j + 1]
            wl = target
        table = AbsorptionTable(R=R, u_R=u, nodes=self.nodes, wavelengths_nm=wl, photons=self.photons,
                                seconds=self.seconds, scatterings=self.scatterings, groups=self.groups,
                                optics=self._optics)
        if len(self._tables) >= 8:
            self._tables.pop(next(iter(self._tables)))
        self._tables[key] = table
        return table


#: the structured walk's wavelength step (nm) for a finer measurement: see :func:`walk_wavelengths`
WALK_STEP_NM = 20.0


def walk_wavelengths(wavelengths_nm: Any) -> np.ndarray:
    """The wavelengths the fit's structured walk is walked at: a uniform grid thinned to at most a 20 nm step.

    Every ``s``-th model wavelength of a uniform grid is kept, ``s`` the largest stride with a step of at
    most :data:`WALK_STEP_NM` that keeps both ends (else all of them).

    A spectral measurement at 10 nm (33 wavelengths, 390-710) is walked at 20 nm (17): the walk's cost is
    proportional to its channels (wavelengths x absorption nodes), and between two walked wavelengths
    only the medium's scattering (Mie of sub-micron particles: smooth, ~lambda^-3) changes -- the dye is
    applied at every model wavelength exactly, through the absorption nodes. :meth:`StructWalk.table`
    reads ``R`` linearly in the wavelength at each node. Measured on the felt (docs/physics.md 6.5):
    the fit's NRMSE, hue and saturation unchanged within the Monte Carlo error. ASTM E308's 20 nm
    table is the coarsest the colour terms use, so 20 nm is the step (an RGB measurement's model
    wavelengths, the config's 20 nm, are walked as they are).

    Parameters
    ----------
    wavelengths_nm : array_like
        The model's wavelengths (nm), ascending.

    Returns
    -------
    numpy.ndarray
        The wavelengths to walk, a subset of ``wavelengths_nm`` with both ends.
    """
    wl = np.asarray(wavelengths_nm, float)
    if wl.size < 3:
        return wl
    d = np.diff(wl)
    if not np.allclose(d, d[0], rtol=1e-9, atol=1e-9):
        return wl
    for stride in range(int(WALK_STEP_NM / d[0] + 1e-9), 1, -1):
        if (wl.size - 1) % stride == 0:
            return wl[::stride]
    return wl


def photons_per_row(target_rel_err: float) -> int:
    """Photons per exit-table row of each half of the fit's walk for a target relative error.

    ``PHOTONS_PER_ROW_AT_1PCT (0.01 / target)^2 / 2`` rounded UP to a multiple of ``FIT_ROW_QUANTUM`` (so at
    least 2000).

    The fit has no accuracy loop (its dye changes at every evaluation, so the rounds that
    :func:`simulate.fiber.farfield.controlled_halves` would add at one dye mean nothing at another)
    and its objective weighs residuals by the model's two-halves error, which is unreliable at a few
    hundred photons per row (the spectral re-weighting's rare heavy weights; see
    ``PHOTONS_PER_ROW_AT_1PCT``): hence the floor. ``simulate fabric --method summation`` evaluates the
    same model in its fixed-photons mode, :func:`simulate.fabric.structure.structured_beta` with
    ``photons_per_row=`` this number (one round, the first round's streams).

    Parameters
    ----------
    target_rel_err : float
        The fit's target relative error of ``beta`` (0.01: 1 %).

    Returns
    -------
    int
        Photons per row of each half.
    """
    from simulate.fabric.structure import PHOTONS_PER_ROW_AT_1PCT

    raw = PHOTONS_PER_ROW_AT_1PCT * (0.01 / target_rel_err) ** 2 / 2.0
    return int(math.ceil(raw / FIT_ROW_QUANTUM)) * FIT_ROW_QUANTUM


#: the fit's photons per row are a multiple of this (and at least this): see :func:`photons_per_row`
FIT_ROW_QUANTUM = 2000


def walk_structure(nodye: Any, config: Any, wavelengths_nm: np.ndarray, nodes: np.ndarray, *,
                   target_rel_err: float, seed: int, threads: int | None = None, reference: Any = None,
                   progress: Callable[[int, int, int], None] | None = None, max_group: int = 7,
                   cache: bool = True) -> StructWalk:
    """Walk the two exit tables of a fiber without dye at every absorption node and reduce them to layer tables.

    The exit tables of ``nodye`` (the fiber without dye; its roughness is the interior closure's) are scored
    at every host-absorption node and reduced chunk by chunk to layer tables (module docstring).

    Streams and photons are those of :func:`simulate.fiber.farfield.exit_table` called by
    :func:`simulate.fabric.structure.structured_beta` in its fixed-photons mode with ``photons_per_row(target_rel_err)``
    (the first round of the controlled halves, seeds ``2 seed + half``, group ``k`` on group ``k``'s stream:
    :func:`seed_of`); the wavelength groups are formed per chunk. ``reference``: walk
    the photons in that fiber's scattering and score them for ``nodye``'s by the likelihood ratio.

    ``cache``: each (half, chunk) layer table is looked up in / stored to the disk cache
    (:mod:`simulate.fiber.tablecache`) under :func:`walk_key` -- the walk is white, so the key holds the
    fiber without dye, the scattering, the walk's part of ``[structure]``, wavelengths, nodes, photons
    and seed, never the dye or the facets: another colour of the same felt, ``--resume``, the Monte
    Carlo fit's surrogate and a second run read it instead of walking (a hit is bit-identical).

    Threads (details in :mod:`simulate.structwalk.threads`). The entries not in the cache
    run two at a time on threads, ``threads // 2`` kernel threads each (``threads=None``: the cores, and a
    second worker only when a core is idle: with the other core busy two threads cost more CPU and
    are slower); ``threads=1`` is the serial walk. Why threads: most of a cold walk is one core's work
    per entry (exit radiance, layer table, closure), and processes would pickle ~10^8-byte tables and
    re-load numba. Why ``nogil=True`` (row runner, ``_accumulate_beam``, :func:`_symmetrise`, the rows'
    reduction): a numba call holds the GIL unless compiled without it, and those are most of an entry.
    The numbers do not depend on the thread: bit-identical to the serial walk (hits read first, entries
    assembled by index; ``tests/fabric_optics/fitting/test_walk_threads.py``). Progress: one lock-guarded monotone
    sum. Ctrl-C: re-raised at once, the workers stop at their next tick, finished entries are stored.

    Parameters
    ----------
    nodye : Fiber
        The fiber without dye, whose scattering is scored.
    config : Config
        The fabric's config with ``[structure]`` (the layer count and the walk's part of the structure).
    wavelengths_nm : numpy.ndarray
        The wavelengths to walk (nm; :func:`walk_wavelengths`).
    nodes : numpy.ndarray
        The host-absorption nodes (1/um) the exit tables are scored at.
    target_rel_err : float
        The target relative error that sets the photons per row (:func:`photons_per_row`).
    seed : int
        The config's seed; the streams follow from it (:func:`seed_of`).
    threads : int, optional
        The thread budget (None: the cores; 1: the serial walk).
    reference : Fiber, optional
        A fiber whose scattering the photons are walked in, scored for ``nodye``'s by the likelihood ratio.
    progress : callable, optional
        ``progress(photons, runs done, runs)``, called with sums that never decrease.
    max_group : int
        The most wavelengths in one chunk (and so in one exit table held in memory).
    cache : bool
        Read and store the (half, chunk) layer tables in the disk cache.

    Returns
    -------
    StructWalk
        The two halves' layer tables at every (wavelength, node) channel, with the walk's counts and
        where its tables came from (``cache``: "miss", "hit", "partial" or "off").
    """
    from simulate.fabric.fiberlayer import layer_grid
    from simulate.fiber import farfield as FF
    from simulate.fiber import tablecache
    from simulate.fiber.spectral import spectral_optics, wavelength_groups

    t0 = time.perf_counter()
    spec = config.structure
    wl = np.asarray(wavelengths_nm, float)
    nodes = np.asarray(nodes, float)
    fiber = FF.cached(nodye)
    walk_fiber = fiber if reference is None else FF.cached(reference)
    n_layers = walk_layers(config, fiber)
    per_row = photons_per_row(target_rel_err)
    K = nodes.size
    chunks = np.array_split(np.arange(wl.size), int(math.ceil(wl.size / max(1, int(max_group)))))
    groups_global: list[np.ndarray] = []
    scatterings: dict[str, float] = {}
    th, ph_i, ph_o, _ = layer_grid(7.5, 15.0)
    hits = 0
    n_wt = len(FF.DEFAULT_WT_NODES)
    runs = 2 * len(chunks) * n_wt
    use = cache and tablecache.enabled()
    base = None
    if use:
        try:
            base = walk_inputs(nodye, reference, config, wl, nodes, per_row, seed, max_group)
        except TypeError as exc:      # a medium without a canonical form: no key, no cache
            log.warning("structured walk: not cached (%s)", exc)
    entries = [(half, c) for half in range(2) for c in range(len(chunks))]
    halves = [np.zeros((th.size, ph_i.size, th.size, ph_o.size, wl.size * K)) for _ in range(2)]
    keys = {e: None if base is None else tablecache.content_key("structwalk", (base, *e), WALK_MODULES) for e in entries}
    small: dict[tuple[int, int], dict] = {}      # each entry's arrays but G (G goes into its half at once)
    shared = Progress(progress, runs)
    if progress is not None:
        progress(0, 0, runs)

    def place(e: tuple[int, int], got: dict) -> None:
        chunk = chunks[e[1]]
        halves[e[0]][..., chunk[0] * K:(chunk[-1] + 1) * K] = got["G"]
        small[e] = {k: v for k, v in got.items() if k != "G"}
        shared.finish(e, int(got["photons"]), n_wt)

    for e in entries:                            # the hits first: read, never walked
        key = keys[e]
        got = None if key is None else _entry(tablecache.load(key), halves[0].shape[:4] + (chunks[e[1]].size * K,))
        if got is not None:
            hits += 1
            place(e, got)
            del got

    own = threading.local()                      # each thread's spare exit-table memory (_walk_chunk), this walk only

    def work(e: tuple[int, int], kernel_threads: int | None) -> dict:
        half, c = e
        if not hasattr(own, "spare"):
            own.spare = []
        got = _walk_chunk(fiber, walk_fiber, spec, n_layers, wl[chunks[c]], nodes, per_row, seed, half, first[c],
                          kernel_threads, shared.report(e), shared.tick, own.spare)
        key = keys[e]
        if key is not None:
            tablecache.store(key, got)          # stored when done: an interrupt keeps the finished entries
        return got

    missing = [e for e in entries if e not in small]
    workers, kernel_threads = plan(threads, len(missing))
    if missing:
        # in this thread, before any worker: the Mie optics of every wavelength into the fibers' caches
        # (FF.cached) and the lazy imports (miepython's import wraps numba.njit: not thread-safe)
        spectral_optics(fiber, wl)
        spectral_optics(walk_fiber, wl)
        import simulate.fabric.fiberlayer  # noqa: F401
        import simulate.fabric.interior  # noqa: F401
        import simulate.fiber.bssrdf  # noqa: F401
    # the index in the walk of each chunk's first wavelength group (group k walks on the exit table's stream of
    # group k, seed_of); the hits need none
    counts = [len(wavelength_groups(spectral_optics(walk_fiber, wl[ch]))) if missing else 0 for ch in chunks]
    first = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(int)
    run_entries(missing, work, place, workers=workers, kernel_threads=kernel_threads, progress=shared)
    for c, chunk in enumerate(chunks):           # half 0's groups, in chunk order
        got = small[(0, c)]
        sizes = np.asarray(got["group_sizes"], int)
        local = np.split(np.asarray(got["group_index"], int), np.cumsum(sizes)[:-1])
        for g, n in zip(local, np.asarray(got["scatterings"], float), strict=True):
            scatterings[f"0:{len(groups_global)}"] = float(n)
            groups_global.append(chunk[g])
    photons = sum(int(v["photons"]) for v in small.values())
    walk = StructWalk(G=halves, grid=(th, ph_i, th, ph_o), spacing_ratio=spec.spacing_ratio,
                      nodes=nodes, wavelengths_nm=wl, photons={"exit_tables": photons, "per_row": per_row},
                      seconds=time.perf_counter() - t0, scatterings=scatterings, groups=groups_global,
                      layers=n_layers, optics_fn=lambda: spectral_optics(fiber, wl))
    walk.cache = "off" if base is None else ("hit" if hits == 2 * len(chunks) else ("miss" if hits == 0 else "partial"))
    return walk


def walk_layers(config: Any, fiber: Any) -> int:
    """The interior closure's number of layers (``[structure] layers``, else 10 for a felt, else the weave's height)."""
    from simulate.config import weave_from_config
    from simulate.fabric.structure import interior_layers

    spec = config.structure
    return interior_layers(spec, weave_from_config(config) if spec.kind == "woven" else None, fiber.radius_um)


#: ``[structure]`` fields that change only the facets (the facet sum of :meth:`StructWalk.table`), not the walk:
#: left out of :func:`walk_inputs`. Every other field is in the key, so a field added later is a miss, never stale.
FACET_ONLY_FIELDS = ("felt_spread_deg", "warp_twist_deg", "weft_twist_deg", "warp_twist", "weft_twist", "samples")

#: ``[structure]`` fields of the felt's Monte Carlo only (:data:`simulate.fabric.structure.FELT_ONLY_KEYS`: the
#: needle-punched population and the crimp), which the summation does not read: left out of :func:`walk_inputs`,
#: so configs differing only in them share the walk
MC_ONLY_FIELDS = FELT_ONLY_KEYS

#: the modules whose source is part of every walk's key: the kernel, the exit-table and layer-table builders,
#: the closure and this module (an edit to any of them is a miss, never a stale walk)
WALK_MODULES = EXIT_TABLE_MODULES + (
    "simulate.fiber.absorption", "simulate.optics.microfacet", "simulate.fabric.fiberlayer",
    "simulate.fabric.interior", "simulate.fabric.structure", "simulate.structwalk.walk",
)


def walk_inputs(nodye: Any, reference: Any, config: Any, wavelengths_nm: Any, nodes: Any, per_row: int, seed: int,
                max_group: int = 7) -> dict:
    """Everything a structured walk depends on (the content of its cache key; :func:`walk_structure`).

    The fiber WITHOUT dye (radius, index, roughness, cell width, medium: particles, volume fraction, size),
    the walked reference (re-weighted passes), the walk's part of ``[structure]`` (not
    :data:`FACET_ONLY_FIELDS` nor :data:`MC_ONLY_FIELDS`) and its layer count, wavelengths, absorption nodes, photons per row,
    seed and chunking. The threads are not in it: the rows do not depend on them.
    """
    from simulate.fiber.farfield import DEFAULT_WT_NODES

    def plain(f: Any) -> Any:
        return None if f is None else plain_fiber(f)

    spec = config.structure
    fiber = plain(nodye)
    return {"fiber": fiber, "reference": plain(reference),
            "structure": {k: getattr(spec, k) for k in spec.__dataclass_fields__ if k not in FACET_ONLY_FIELDS + MC_ONLY_FIELDS},
            "layers": walk_layers(config, fiber), "wavelengths_nm": np.asarray(wavelengths_nm, float),
            "nodes": np.asarray(nodes, float), "photons_per_row": int(per_row), "seed": int(seed),
            "max_group": int(max_group), "w_t": np.asarray(DEFAULT_WT_NODES, float), "bins": (9, 18)}


def walk_key(nodye: Any, config: Any, wavelengths_nm: Any, nodes: Any, *, target_rel_err: float, seed: int,
             reference: Any = None, half: int = 0, chunk: int = 0, max_group: int = 7) -> str:
    """The cache key of one (half, chunk) entry of :func:`walk_structure` with these arguments."""
    from simulate.fiber import tablecache

    base = walk_inputs(nodye, reference, config, wavelengths_nm, nodes, photons_per_row(target_rel_err), seed,
                       max_group)
    return tablecache.content_key("structwalk", (base, int(half), int(chunk)), WALK_MODULES)


def _entry(arrays: dict | None, shape: tuple) -> dict | None:
    """A loaded entry if it has every array in the expected shape (else None: recomputed and rewritten)."""
    if arrays is None:
        return None
    need = ("G", "photons", "scatterings", "group_sizes", "group_index")
    if any(k not in arrays for k in need) or tuple(arrays["G"].shape) != tuple(shape) or \
            arrays["scatterings"].shape != arrays["group_sizes"].shape:
        log.warning("structured walk: a cache entry has unexpected arrays; it is walked again")
        return None
    return arrays


def _walk_chunk(fiber: Any, walk_fiber: Any, spec: Any, n_layers: int, wl: np.ndarray, nodes: np.ndarray,
                per_row: int, seed: int, half: int, group0: int, threads: int | None,
                report: Callable[[int, int], None], tick: Callable[[], None] | None = None,
                spare: list | None = None) -> dict:
    """One (half, chunk) of :func:`walk_structure`: its exit table walked, symmetrised and reduced to a layer table.

    The exit table is walked at every node and reduced to the layer table with the interior closure.
    Returns the cache entry's arrays.

    ``group0``: the index, in the whole walk, of the chunk's first wavelength group; the chunk's group ``g``
    walks on the stream of group ``group0 + g`` (:func:`seed_of`).

    ``spare``: a list of flat float64 buffers to take the exit table's memory from and give it back to (the
    table, ~0.6 GB on the felt, is written whole by the rows -- every node, row and wavelength group -- so
    a used buffer needs no zeroing, and a fresh one per entry would cost its page faults).
    """
    from simulate.fabric.structure import layer_table_of
    from simulate.fiber import farfield as FF
    from simulate.fiber.bssrdf import bssrdf_rows, lit_rows
    from simulate.fiber.spectral import group_walk, spectral_optics, wavelength_groups
    from simulate.montecarlo.transport import make_control

    K = nodes.size
    w_t = np.asarray(FF.DEFAULT_WT_NODES, float)
    n_psi = fiber.cell_count("bssrdf route")
    k_max = lit_rows(2.0 * math.pi / n_psi)
    ks = list(range(-k_max, k_max + 1))
    n_mu, n_phi = 9, 18
    grid = (n_psi, 1, 10.0 * fiber.radius_um, n_mu, n_phi)
    control = make_control()
    optics = spectral_optics(fiber, wl)
    walk_optics = optics if walk_fiber is fiber else spectral_optics(walk_fiber, wl)
    groups = wavelength_groups(walk_optics)
    scatterings = np.zeros(len(groups))
    photons = 0
    shape = (w_t.size, len(ks), n_psi, n_mu, n_phi, wl.size * K)
    size = int(np.prod(shape))
    buffers: list = [] if spare is None else spare
    flat = next((b for b in buffers if b.size >= size), None)
    if flat is None:
        flat = np.zeros(size)
    else:
        buffers.remove(flat)
    T = flat[:size].reshape(shape)
    for i, wt in enumerate(w_t):
        for gi, group in enumerate(groups):
            if tick is not None:
                tick()
            medium, walk_phase, _ = group_walk(walk_fiber, walk_optics, group, white=True)
            targets = absorption_targets(optics, group, nodes, walk_phase)
            scal: list = []
            # the means straight into the table (groups are consecutive): no per-call copies of ~10^8 bytes
            view = T[i, :, :, None, :, :, int(group[0]) * K:(int(group[-1]) + 1) * K]
            _, _, p, _ = bssrdf_rows(fiber, float(wt), ks, grid, medium, walk_phase, targets, control, per_row,
                                     int(seed_of(seed, half, i, group0 + gi)), threads, scal, into=view)
            photons += int(p)
            n = max(float(s[S_SCATTERINGS]) / max(float(s[S_LAUNCHED]), 1.0) for s in scal)
            scatterings[gi] = max(scatterings[gi], n)
        report(photons, i + 1)
    _symmetrise(T)
    table = FF.ExitTable(w_t=w_t, T=T, u_T=np.zeros(1), k=np.array(ks), radius_um=fiber.radius_um,
                         wavelengths_nm=np.repeat(wl, K), n_host=float(fiber.n_host))
    lt = layer_table_of(spec, table, fiber, n_layers, surface=False, tick=tick)
    del table, T
    if spare is not None:
        spare.append(flat)
    return {"G": lt.G, "photons": np.int64(photons), "scatterings": scatterings,
            "group_sizes": np.array([len(g) for g in groups], np.int64),
            "group_index": np.concatenate([np.asarray(g, np.int64) for g in groups])}


@numba.njit(cache=True, parallel=True, nogil=True)
def _symmetrise(T):
    """In place, :func:`simulate.fiber.farfield._symmetrised` in one pass without temporaries.

    Each row is averaged with the mirror image of its opposite: row ``r -> R-1-r``, exit cell ``o -> -o``,
    exit azimuth bin ``p -> P-1-p``. One pass avoids the three ``[W, K, n_psi, n_mu, n_phi, L]``
    temporaries (on the felt, tables of ~0.6 GB each).
    """
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


def seed_of(seed: int, half: int, node: int, group: int) -> int:
    """The random stream of one exit-table node and wavelength group of one half of the walk.

    :func:`simulate.fiber.farfield.exit_table`'s rule (node ``104729 i``, and
    :func:`simulate.fiber.bssrdf.bssrdf_table`'s group ``GROUP_SEED_STEP k``) with ``structured_beta``'s seed
    ``2 seed + half``. Every group has its own stream: the groups' errors are independent, as in ``simulate
    fabric``. Where the walk's groups are the exit table's and none is blended with its neighbour (the
    exit table blends two groups of 2 or more wavelengths across their boundary, the walk does not), the
    streams are the same and the two differ by the roulette only
    (``tests/fabric_optics/fitting/test_fit_structure.py``, three wavelengths in two groups).

    Parameters
    ----------
    seed : int
        The config's seed.
    half : int
        The half of the controlled halves, 0 or 1.
    node : int
        The index of the exit table's incidence node.
    group : int
        The wavelength group, counted over the whole walk.

    Returns
    -------
    int
        The stream's seed.
    """
    from simulate.fiber.bssrdf import GROUP_SEED_STEP

    return (2 * int(seed) + half) * 1_000_003 + 104_729 * node + GROUP_SEED_STEP * group
