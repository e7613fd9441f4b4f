"""The fiber's BSSRDF as a yarn table: the exits the ray tracer samples.

Built with the fiber's public Monte Carlo (:mod:`simulate.fiber.bssrdf`, :mod:`simulate.fiber.spectral`):
white walks per wavelength group, rows for a grid of axial incidences, ``v`` offsets kept.

Tables are cached on disk (:mod:`simulate.fiber.tablecache`) under the content hash of all they
depend on: the fiber's radius, host index, cell width and medium (and, when not uniform, the dye's and the
scatterers' placement across it), the wavelengths, the grid
(nodes, ``n_v``, ``v_max_R``, ``n_mu``, ``n_phi``), the photons per row, the seed and the
source of the kernel and of the modules that build the table (:data:`TABLE_MODULES`). The
threads are not in the key: the rows do not depend on them (batches of fixed seeds). A hit is
bit-identical to the miss that stored it; :func:`table_halves` builds the medium's optics
(Mie: the expensive part outside the kernel) once for both halves and only when one misses.

The fiber table on a yarn (the decisions, docs/physics.md section 6)
--------------------------------------------------------------------
* The table is the fiber's (radius ``R``); the yarn uses it as a similar cylinder: angular
  offsets are kept (``d_psi`` rotates the exit point about the yarn's axis through the same
  angle, as the cross-section's parametric angle), axial offsets ``v`` are scaled by
  ``r_yarn / R`` with ``r_yarn = sqrt(a b)`` (the cross-section's semi-axes).
* Local incidence ``(w_t, a)`` (``w_t = w_in . t``, ``a`` its azimuth about ``t`` from the
  normal) selects the table row by *stochastic* linear interpolation between the nodes of the
  ``w_t`` grid and the cell-multiple azimuths (unbiased for the linear interpolant). Mirror
  symmetries halve the table: ``w_t -> -w_t`` flips ``v`` and the exit direction's ``t``
  component, ``a -> -a`` flips the cell offset and the ``b`` component.
* Interpenetrating yarns: a ray that starts inside another yarn hits that yarn's surface from
  inside first (a back face); it is moved to that point and processed as entering it (the
  light is in its volume already: no surface reflection), its incidence mirrored about the
  tangent plane.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any

import numpy as np

from simulate.fiber import tablecache
from simulate.fiber.bssrdf import lit_rows, row_sources, rows_inputs
from simulate.fiber.model import as_wavelengths
from simulate.fiber.spectral import SpectralOptics, group_walk, spectral_optics, wavelength_groups
from simulate.montecarlo.accuracy import BATCH
from simulate.montecarlo.kernel import M_MU_S
from simulate.montecarlo.rows import execute_rows
from simulate.montecarlo.transport import SpectralTargets, make_control
from simulate.optics.fresnel import reflectance_from_cos

__all__ = ["TABLE_MODULES", "YarnTable", "yarn_table", "table_halves", "table_key", "held_groups", "HALF_SEED_STEP",
           "mix_tables", "blend_halves"]

#: The modules whose source is part of every yarn table's cache key (the kernel and the table's builders).
TABLE_MODULES = (
    "simulate.montecarlo.kernel", "simulate.montecarlo.tallies", "simulate.montecarlo.geometry",
    "simulate.montecarlo.scatter", "simulate.montecarlo.rng", "simulate.montecarlo.vecmath",
    "simulate.montecarlo.transport", "simulate.montecarlo.accuracy", "simulate.montecarlo.rows",
    "simulate.fiber.bssrdf",
    "simulate.fiber.spectral", "simulate.fiber.model", "simulate.media.medium", "simulate.optics.mie",
    "simulate.optics.phase", "simulate.optics.fresnel", "simulate.raytrace.yarn",
)
#: Seed offset of the second of :func:`table_halves`.
HALF_SEED_STEP = 1_000_003

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class YarnTable:
    """The fiber BSSRDF by offset for a grid of axial incidences (rows ``[w_t node, k >= 0]``).

    ``T[j, k, cell, lambda]``: mean exit weight per photon entering cell A with launch weight
    ``max(w . n, 0)`` (:func:`simulate.fiber.bssrdf_table`), ``cell`` the flat index of
    ``(psi offset, v bin, mu bin, phi bin)``; ``c_bar[j, k]`` the mean launch weight, so that
    ``T / c_bar`` is per unit power arriving at a point of A; ``tau[j, k]`` the mean smooth-
    interface transmission ``1 - F`` of that light (taken out again for light that is inside a
    yarn already: the interpenetration rule). No per-cell standard error is kept: the tracer reads
    ``T`` only, and the table's noise is measured from two independent halves
    (:func:`table_halves`), which halves the table's memory.
    """

    T: np.ndarray
    c_bar: np.ndarray
    tau: np.ndarray
    w_t_nodes: np.ndarray
    dpsi: float
    n_psi: int
    n_v: int
    n_mu: int
    n_phi: int
    v_max_R: float
    radius_um: float
    wavelengths_nm: np.ndarray
    photons: int
    seconds: float
    cache: str = "off"
    """``"hit"`` (loaded; ``seconds`` is the load time), ``"miss"`` (computed and stored) or ``"off"``."""

    @property
    def exit_fraction(self) -> np.ndarray:
        """``e[j, k, lambda] = sum_cells T / c_bar`` (the energy that comes out again)."""
        return self.T.sum(axis=2) / self.c_bar[:, :, None]


def _grid(fiber: Any, w_t_nodes: Any) -> tuple[np.ndarray, int, float, list[int]]:
    n_psi = fiber.cell_count("yarn table")
    dpsi = 2.0 * math.pi / n_psi
    nodes = np.asarray(w_t_nodes, float)
    if nodes.ndim != 1 or nodes[0] != 0.0 or np.any(np.diff(nodes) <= 0) or nodes[-1] >= 1.0:
        raise ValueError("yarn table: w_t_nodes must increase from 0 and stay below 1")
    return nodes, n_psi, dpsi, list(range(0, lit_rows(dpsi) + 1))


def table_key(fiber: Any, wavelengths_nm: Any, *, w_t_nodes: Any = (0.0, 0.25, 0.5, 0.75, 0.95), n_v: int = 3,
              v_max_R: float = 2.0, n_mu: int = 5, n_phi: int = 10, photons_per_row: int = 20_000,
              seed: int = 0, held_log_mu_s: float = 0.0) -> str:
    """The cache key of :func:`yarn_table` with these arguments (module docstring: what it covers)."""
    inputs: dict[str, Any] = {"radius_um": float(fiber.radius_um), "n_host": float(fiber.n_host),
              "cell_width_deg": float(fiber.cell_width_deg), "medium": fiber.medium,
              "wavelengths_nm": as_wavelengths(wavelengths_nm), "w_t_nodes": np.asarray(w_t_nodes, float),
              "grid": (int(n_v), float(v_max_R), int(n_mu), int(n_phi)), "photons_per_row": int(photons_per_row),
              "seed": int(seed)}
    if held_log_mu_s > 0.0:      # only then: the keys of the re-weighted tables are unchanged
        inputs["held_log_mu_s"] = float(held_log_mu_s)
    rough = float(getattr(fiber, "transmission_roughness", 0.0) or 0.0)
    around = getattr(fiber, "transmission_roughness_around", None)
    if rough > 0.0 or around is not None:   # the rough boundary (simulate.montecarlo.rough); smooth keys unchanged
        inputs["transmission_roughness"] = rough
        if around is not None:
            inputs["transmission_roughness_around"] = float(around)
    profile = getattr(fiber, "dye_profile", "uniform")
    if profile != "uniform":                # the dye where it sits; uniform keys unchanged
        inputs["dye_profile"] = (str(profile), float(fiber.dye_depth_um))
    placed = getattr(fiber, "scatterer_profile", "uniform")
    if placed != "uniform":                 # the scatterers where they sit; uniform keys unchanged
        inputs["scatterer_profile"] = (str(placed), float(fiber.scatterer_depth_um))
    return tablecache.content_key("yarn", inputs, TABLE_MODULES)


def yarn_table(fiber: Any, wavelengths_nm: Any, *, w_t_nodes: Any = (0.0, 0.25, 0.5, 0.75, 0.95),
               n_v: int = 3, v_max_R: float = 2.0, n_mu: int = 5, n_phi: int = 10,
               photons_per_row: int = 20_000, seed: int = 0, threads: int | None = None,
               optics: SpectralOptics | Callable[[], SpectralOptics] | None = None, cache: bool = True,
               held_log_mu_s: float = 0.0) -> YarnTable:
    """Build the BSSRDF rows the ray tracer samples exits from (white Monte Carlo).

    Only ``w_t >= 0`` and azimuths ``k dpsi >= 0`` are walked (the mirror symmetries of the
    module docstring give the rest). Each row costs ``photons_per_row`` photons per
    wavelength group of the medium. ``optics``: the medium's :func:`spectral_optics` at these
    wavelengths when the caller has it already (or a function computing it, called only on a miss). ``cache``: look the table up on disk / store it
    (module docstring; also off with ``FABRIC_OPTICS_NO_CACHE=1``).

    ``held_log_mu_s > 0``: the wavelengths walked together are those whose scattering coefficients
    differ by at most that in ``log mu_s`` (and ``g`` by ``GROUP_G``), and their scattering is HELD at
    the walk's (only the absorption is applied per wavelength, exactly): a bias of at most that
    relative error in ``mu_s`` instead of the re-weighting's variance, which in an optically thick
    cylinder (hundreds of events per path: the yarn's pile, :mod:`simulate.raytrace.pile`) has heavy
    tails (docs/physics.md 6, "Yarn made of fibers").
    """
    return _tables(fiber, wavelengths_nm, [seed], threads, optics, cache, w_t_nodes=w_t_nodes, n_v=n_v,
                   v_max_R=v_max_R, n_mu=n_mu, n_phi=n_phi, photons_per_row=photons_per_row,
                   held_log_mu_s=held_log_mu_s)[0]


def table_halves(fiber: Any, wavelengths_nm: Any, photons_per_row: int, seed: int, threads: int | None = None,
                 cache: bool = True, **grid: Any) -> tuple[YarnTable, YarnTable]:
    """The two independent halves of :func:`simulate.raytrace.fabric_beta` (seeds ``seed``, ``seed + HALF_SEED_STEP``).

    The medium's optics (Mie phase functions) are computed at most once, and only if a half is
    not in the cache. The halves that miss are walked together (one kernel call per wavelength
    group for all their rows: :func:`_compute`), each bit-identical to its own :func:`yarn_table`.
    """
    a, b = _tables(fiber, wavelengths_nm, [seed, seed + HALF_SEED_STEP], threads, None, cache,
                   photons_per_row=photons_per_row, **grid)
    return a, b


def mix_tables(tables: Sequence[YarnTable], shares: Sequence[float]) -> YarnTable:
    """A blend's table: the tables of its fiber populations (one grid) with ``T``, ``c_bar`` and ``tau`` mixed by share.

    A ray that enters a yarn (or a felt's fiber) then scatters, in expectation, as one drawn from the
    populations by share: the table is linear in what the tracer reads of it. ``photons`` and ``seconds`` are the
    tables' sums. One table of share 1 is that table, bit for bit. :class:`ValueError` for tables of two grids.
    """
    first = tables[0]
    for t in tables[1:]:
        if t.T.shape != first.T.shape or t.radius_um != first.radius_um or not np.array_equal(t.w_t_nodes,
                                                                                               first.w_t_nodes):
            raise ValueError("mix_tables: the populations' tables are on different grids (radius, nodes or bins)")
    T = shares[0] * first.T
    c_bar = shares[0] * first.c_bar
    tau = shares[0] * first.tau
    for share, t in zip(shares[1:], tables[1:], strict=True):
        T = T + share * t.T
        c_bar = c_bar + share * t.c_bar
        tau = tau + share * t.tau
    return dataclasses.replace(first, T=T, c_bar=c_bar, tau=tau, photons=int(sum(t.photons for t in tables)),
                               seconds=float(sum(t.seconds for t in tables)))


def blend_halves(populations: Sequence[tuple[float, Any]], wavelengths_nm: Any, photons_per_row: int, seed: int,
                 threads: int | None = None, cache: bool = True, **grid: Any) -> tuple[YarnTable, YarnTable]:
    """:func:`table_halves` of each of a blend's ``populations`` (``(share, fiber)``), mixed by share.

    Half by half (:func:`mix_tables`); each population's halves are walked as one fiber's are (the same photons,
    seeds and grid).
    """
    halves = [table_halves(f, wavelengths_nm, photons_per_row, seed, threads, cache, **grid) for _, f in populations]
    shares = [float(share) for share, _ in populations]
    a, b = (mix_tables([pair[h] for pair in halves], shares) for h in range(2))
    return a, b


def _tables(fiber: Any, wavelengths_nm: Any, seeds: list[int], threads: int | None, optics: Any, cache: bool,
            *, w_t_nodes: Any = (0.0, 0.25, 0.5, 0.75, 0.95), n_v: int = 3, v_max_R: float = 2.0, n_mu: int = 5,
            n_phi: int = 10, photons_per_row: int = 20_000, held_log_mu_s: float = 0.0) -> list[YarnTable]:
    """:func:`yarn_table` for each of ``seeds``: the cached ones loaded, the others computed together."""
    wl = as_wavelengths(wavelengths_nm)
    nodes, n_psi, dpsi, ks = _grid(fiber, w_t_nodes)
    use = cache and tablecache.enabled()
    keys: list[str] = [""] * len(seeds)
    found: list[Any] = [None] * len(seeds)
    for i, seed in enumerate(seeds):
        if not use:
            break
        try:
            keys[i] = table_key(fiber, wl, w_t_nodes=nodes, n_v=n_v, v_max_R=v_max_R, n_mu=n_mu, n_phi=n_phi,
                                photons_per_row=photons_per_row, seed=seed, held_log_mu_s=held_log_mu_s)
        except TypeError as exc:  # a medium without a canonical form: no key, no cache
            use = False
            log.warning("yarn table: not cached (%s)", exc)

    def load(key: str) -> tuple[Any, float]:
        started = time.perf_counter()
        return tablecache.load(key), time.perf_counter() - started

    if use:
        # the halves read side by side (the file reads and their CRC-32s release the GIL), unless one thread
        if threads == 1 or len(seeds) == 1:
            loaded = [load(k) for k in keys]
        else:
            with ThreadPoolExecutor(max_workers=len(seeds)) as pool:
                loaded = list(pool.map(load, keys))
        for i, (arrays, seconds) in enumerate(loaded):
            if arrays is not None:
                found[i] = _from_arrays(arrays, dpsi, n_psi, n_v, n_mu, n_phi, v_max_R, fiber, wl, seconds, "hit")
    missing = [i for i in range(len(seeds)) if found[i] is None]
    if missing:
        if optics is None:
            optics = _walk_optics(fiber, wl, held_log_mu_s)
        computed = _compute(fiber, wl, nodes, n_psi, dpsi, ks, n_v, v_max_R, n_mu, n_phi, photons_per_row,
                            [seeds[i] for i in missing], threads, optics, held_log_mu_s)
        for i, arrays in zip(missing, computed, strict=True):
            if use:
                tablecache.store(keys[i], arrays)
            found[i] = _from_arrays(arrays, dpsi, n_psi, n_v, n_mu, n_phi, v_max_R, fiber, wl,
                                    float(arrays["seconds"]), "miss" if use else "off")
    return found


def _walk_optics(fiber: Any, wl: np.ndarray, held_log_mu_s: float) -> SpectralOptics:
    """The optics a table walks with.

    Every phase function, or for a held-scattering table only those of the groups' middle wavelengths
    (the walks'; the others are never read, so they are not computed). The groups depend on ``mu_s`` and
    ``g`` only.
    """
    if held_log_mu_s <= 0.0:
        return spectral_optics(fiber, wl)
    coefficients = spectral_optics(fiber, wl, phase_at=())
    refs = [int(g[len(g) // 2]) for g in held_groups(coefficients, held_log_mu_s)]
    return spectral_optics(fiber, wl, phase_at=refs)


def held_groups(optics: SpectralOptics, max_log_mu_s: float) -> list[np.ndarray]:
    """The groups of a held-scattering table: runs of consecutive wavelengths.

    In a group every ``mu_s`` lies within ``max_log_mu_s`` (in ``log``) and every ``g`` within ``GROUP_G``
    of the group's middle one (which walks): :func:`simulate.fiber.spectral.wavelength_groups` with this
    bound.
    """
    return wavelength_groups(optics, max_log_mu_s)


def _compute(fiber: Any, wl: np.ndarray, nodes: np.ndarray, n_psi: int, dpsi: float, ks: list[int], n_v: int,
             v_max_R: float, n_mu: int, n_phi: int, photons_per_row: int, seeds: list[int], threads: int | None,
             optics: Any, held_log_mu_s: float = 0.0) -> list[dict[str, Any]]:
    """The arrays of the tables of ``seeds`` (white Monte Carlo), as stored in the cache.

    Row ``k`` of node ``j`` of the table of seed ``s`` is the run of seed ``s + 104729 j + 7919 r``
    (``r`` its index in ``ks``), as :func:`simulate.fiber.bssrdf.bssrdf_rows` of node ``j`` would
    run it; all rows of all nodes and tables of one wavelength group go to ONE parallel kernel call
    (:func:`simulate.montecarlo.rows.execute_rows`): the sums are bit-identical to one call per
    row, without the idle thread of a one-batch call (700 calls for red cotton's two
    pile-table halves, one or two batches each).
    """
    if not isinstance(optics, SpectralOptics):
        optics = optics()
    v_max = v_max_R * fiber.radius_um
    grid = (n_psi, n_v, v_max, n_mu, n_phi)
    control = make_control()
    n_cells = n_psi * n_v * n_mu * n_phi
    n_k = len(ks)
    sources = np.concatenate([row_sources(float(w_t), ks, dpsi) for w_t in nodes] * len(seeds))
    run_seeds = np.array([s + 104729 * j + 7919 * r for s in seeds for j in range(nodes.size) for r in range(n_k)],
                         dtype=np.int64)
    groups = wavelength_groups(optics) if held_log_mu_s <= 0.0 else held_groups(optics, held_log_mu_s)
    # the groups are consecutive runs of wavelengths: each group's means go straight into its slice of T
    assert np.array_equal(np.concatenate(groups), np.arange(wl.size))
    T = np.empty((len(seeds), nodes.size, n_k, n_cells, wl.size))
    rows6 = T.reshape(len(seeds) * nodes.size * n_k, n_psi, n_v, n_mu, n_phi, wl.size)
    seconds = 0.0
    for group in groups:
        medium, walk_phase, targets = group_walk(fiber, optics, group, white=True)
        if held_log_mu_s > 0.0:      # the walk's scattering for every wavelength, each its own absorption
            targets = SpectralTargets(mu_a=targets.mu_a, mu_s=np.full(group.size, float(medium[M_MU_S])),
                                      phases=[walk_phase] * group.size, same_phase=np.ones(group.size, bool),
                                      mu_a_dye=targets.mu_a_dye)
        inp = rows_inputs(fiber, grid, medium, walk_phase, targets, control)
        # the means written into T (bit-identical to accuracy.mean_and_error's): no [rows, bins, 2] sums array and no
        # standard errors -- the tracer reads T only; the table's noise is measured from the two halves
        _, _, sec = execute_rows(inp, sources, run_seeds, photons_per_row, threads, BATCH,
                                 means=rows6[..., int(group[0]):int(group[-1]) + 1])
        seconds += sec
    photons = photons_per_row * nodes.size * n_k * len(groups)
    # mean launch weight max(w . n, 0) over a cell at azimuth k dpsi: rho <cos(a + x)>_x
    x = np.linspace(-dpsi / 2, dpsi / 2, 4001)
    rho = np.sqrt(1.0 - nodes ** 2)
    cos = np.maximum(rho[:, None, None] * np.cos(np.array(ks)[None, :, None] * dpsi + x[None, None, :]), 0.0)
    c_bar = np.trapezoid(cos, x, axis=2) / dpsi
    # the mean smooth-interface transmission of light entering the row's cell (weighted by w . n)
    transmitted = np.trapezoid(cos * (1.0 - reflectance_from_cos(cos, 1.0, fiber.n_host)), x, axis=2) / dpsi
    tau = np.where(c_bar > 0, transmitted / np.where(c_bar > 0, c_bar, 1.0), 1.0)
    # the seconds of the joint calls, shared equally by the tables
    return [{"T": T[i], "c_bar": c_bar, "tau": tau, "w_t_nodes": nodes, "photons": np.int64(photons),
             "seconds": np.float64(seconds / len(seeds))} for i in range(len(seeds))]


def _from_arrays(a: dict[str, np.ndarray], dpsi: float, n_psi: int, n_v: int, n_mu: int, n_phi: int, v_max_R: float,
                 fiber: Any, wl: np.ndarray, seconds: float, cache: str) -> YarnTable:
    return YarnTable(a["T"], a["c_bar"], a["tau"], a["w_t_nodes"], dpsi, n_psi, n_v, n_mu, n_phi,
                     float(v_max_R), float(fiber.radius_um), wl, int(a["photons"]), float(seconds), cache)
