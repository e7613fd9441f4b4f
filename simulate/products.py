"""The fabric models as a registry: name -> a function of (config, fiber, geometries, wavelengths, settings).

Every model returns the same typed result, :class:`FabricEstimate` (``beta``, ``u_beta``, ``n``
as ``[G, L]``, photons, the run's ``info``, seconds and the fields it adds to the dataset's
``model`` metadata), so the virtual goniophotometer (:func:`simulate.virtual.fabric_dataset`)
assembles a dataset from any of them, and ``auto`` mixes them per geometry. A new model is one
function decorated with :func:`register`; ``simulate fabric --method`` offers every registered
name (:data:`MODELS`) plus ``auto``.

- ``summation``: the fiber BRDF summed over warp and weft (:mod:`simulate.fabric.summation`) at
  the unique fiber-frame pairs of the geometries (one :func:`simulate.fiber.volume_brdf` call);
- ``classic``: Cook-Torrance over the fiber's normal-incidence albedo (:mod:`simulate.fabric.classic`);
- ``mc``: the woven micro-element's (or the felt's) Monte Carlo (:mod:`simulate.raytrace`).

A blend (``[[populations]]``) is the share-weighted mix of its populations' estimates in the summation and the
classic model (:func:`_blend`) and of their exit tables in the Monte Carlo (:func:`population_walks`).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from simulate import fabric as fab
from simulate.config import DEFAULT_FELT_REALISATIONS, SimulationConfig, weave_from_config
from simulate.provenance import jsonable

__all__ = ["FabricEstimate", "Geometries", "RunSettings", "MODELS", "all_threads", "register", "evaluate",
           "reweighted_estimate"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Geometries:
    """``G`` geometries of the fabric frame: incidence and observation angles in degrees."""

    theta_i: np.ndarray
    phi_i: np.ndarray
    theta_o: np.ndarray
    phi_o: np.ndarray


def all_threads(threads: Any) -> int:
    """``threads`` with 0 or None meaning "all that numba allows".

    That is ``numba.config.NUMBA_NUM_THREADS``, which ``NUMBA_NUM_THREADS`` in the environment lowers: the
    one meaning of 0 in configs and flags.
    """
    import numba

    return int(threads) if threads else int(numba.config.NUMBA_NUM_THREADS)


@dataclass(frozen=True)
class RunSettings:
    """Accuracy and resources of a run (``target``: :func:`simulate.montecarlo.accuracy.relative_error`)."""

    target: float
    seed: int
    threads: Any = None
    max_photons: Any = None
    progress: bool = False
    max_seconds: float = 0.0
    record: dict | None = field(default=None, compare=False)
    """``--method mc``: a dict the run's ray events are recorded into, from which
    :func:`reweighted_estimate` gives another dye's result without tracing again."""


@dataclass(frozen=True)
class FabricEstimate:
    """A fabric model at ``G`` geometries and ``L`` wavelengths."""

    beta: np.ndarray
    u_beta: np.ndarray
    n: np.ndarray
    photons: int | None
    info: dict = field(default_factory=dict)
    seconds: float = 0.0
    model: dict = field(default_factory=dict)


Model = Callable[[SimulationConfig, Any, Geometries, np.ndarray, RunSettings], FabricEstimate]
_REGISTRY: dict[str, Model] = {}


def register(name: str) -> Callable[[Model], Model]:
    """Register a fabric model under ``name`` (a ``simulate fabric --method`` value)."""
    def add(fn: Model) -> Model:
        _REGISTRY[name] = fn
        return fn
    return add


def evaluate(method: str, config: SimulationConfig, fiber: Any, geometries: Geometries, wavelengths: np.ndarray,
             settings: RunSettings) -> FabricEstimate:
    """The registered model ``method`` at ``geometries``."""
    if method not in _REGISTRY:
        raise ValueError(f"fabric model must be one of {', '.join(_REGISTRY)}, got {method!r}")
    if getattr(config, "populations", None) and method != "mc":
        return _blend(method, config, geometries, np.asarray(wavelengths, float), settings)
    fiber = smooth_boundary_unless_mc(method, fiber)
    return _REGISTRY[method](config, fiber, geometries, np.asarray(wavelengths, float), settings)


def _blend(method: str, config: SimulationConfig, g: Geometries, wavelengths: np.ndarray,
           s: RunSettings) -> FabricEstimate:
    """A blend of fiber populations (``[[populations]]``) by a model linear in its fiber's tables.

    Such models are the summation and the classic model: each population's estimate at the run's seed,
    mixed by share. The
    summation's layer tables enter ``beta`` linearly, so this is the share-weighted mix of the populations'
    layer tables (exact for the top layer). ``u_beta`` adds the populations' errors linearly (they share the
    seed's streams, so they are correlated).
    """
    parts = [(share, evaluate(method, c, c.fiber(wavelengths), g, wavelengths, s))
             for share, c in config.population_configs()]
    beta = sum(share * e.beta for share, e in parts)
    u_beta = sum(share * e.u_beta for share, e in parts)
    n = np.min([e.n for _, e in parts], axis=0)
    photons = None if any(e.photons is None for _, e in parts) else int(sum(int(e.photons or 0) for _, e in parts))
    model = dict(parts[0][1].model)
    model["populations"] = _population_record(config, [e.model for _, e in parts])
    info = {"populations": [jsonable(e.info) for _, e in parts]}
    return FabricEstimate(np.asarray(beta, float), np.asarray(u_beta, float), n, photons, info,
                          float(sum(e.seconds for _, e in parts)), model)


def _population_record(config: SimulationConfig, models: list[dict] | None = None) -> list[dict]:
    """The dataset's record of a blend's populations: name and share (and each one's model fields)."""
    pops = config.populations or ()
    out = []
    for k, p in enumerate(pops):
        row: dict[str, Any] = {"name": p.name, "share": p.share}
        if models is not None:
            row["model"] = jsonable({key: v for key, v in models[k].items() if key != "populations"})
        out.append(row)
    return out


def check_blend(config: SimulationConfig, method: str) -> None:
    """Refuse, before any work, a blend (``[[populations]]``) that ``method`` cannot trace.

    The Monte Carlo (``mc``, and ``auto``, which may choose it) traces a blend whose populations share the fiber's
    radius, host index and reflection slope (:func:`population_walks`); :class:`ConfigError`, one line naming
    the field, otherwise.
    """
    if not getattr(config, "populations", None) or method not in ("mc", "auto"):
        return
    _same_fiber(config)


def _same_fiber(config: SimulationConfig) -> None:
    from simulate.config import ConfigError

    spec = getattr(config, "structure", None)
    what = "felt" if spec is not None and spec.kind == "nonwoven" else "woven"
    parts = config.population_configs()
    first = parts[0][1]
    for _, c in parts[1:]:
        for field_name, a, b in (("fiber.radius_um", c.radius_um, first.radius_um),
                                 ("fiber.n_host", c.n_host, first.n_host),
                                 ("surface.rms_slope", c.rms_slope, first.rms_slope)):
            if a != b:
                raise ConfigError(f"{_file_of(config)}: populations: the {what} Monte Carlo traces one {field_name} "
                                  f"for every population, got {b:g} and {a:g}; give the populations the same "
                                  f"{field_name} (or use --method summation)")


def population_walks(config: SimulationConfig, wavelengths: np.ndarray) -> list[tuple[float, Any]]:
    """``(share, fiber)`` of each of a blend's populations, as the Monte Carlo traces them (:func:`_woven_mc`).

    The tracer mixes the populations' exit tables by share (:func:`simulate.raytrace.yarn.blend_halves`): light
    that enters a fiber of a felt, or a yarn of a weave, scatters in expectation as one of a population drawn by
    share. In a felt that is each fiber a ray meets drawn from the populations (exact for light that meets a fiber
    once; a fiber met again draws afresh). In a weave it is each yarn a ray enters: its volume, the pile of its
    fibers (:mod:`simulate.raytrace.pile`), walked as the pile of one population, drawn by share -- a mélange
    (heather) yarn whose populations mix within the yarn, taken in the limit where the light that enters the yarn
    meets fibers of the population it entered through (the mix of the populations' yarns' reflectances; a pile
    whose light crosses fibers of every population would darken more: docs/physics.md 6, "Fiber populations").
    A share is by number of fibers, which with one radius is the share of the yarn's (or the felt's) fiber volume
    and, for equal densities, of its mass. The populations must share the fiber's radius, host index and
    reflection slope (one fiber geometry for the felt's tubes and the shares; one surface term):
    :class:`ConfigError` naming the field otherwise.
    """
    _same_fiber(config)
    return [(share, c.fiber(wavelengths)) for share, c in config.population_configs()]


def felt_population_tables(config: SimulationConfig, fiber: Any, wavelengths: np.ndarray, s: RunSettings,
                           bins: tuple[int, int]) -> tuple[Any, Any]:
    """The felt Monte Carlo's two table halves of a blend: those :func:`_woven_mc` traces a felt blend with.

    Each population's halves (the run's seed and photons, as :func:`simulate.raytrace.fabric_beta` builds
    one fiber's) with their exit weights mixed by share (:func:`population_walks`: what that means and what the
    populations must share). ``fiber``: the first population's (unused: each population's own is walked).
    """
    from simulate.raytrace.estimate import table_photons
    from simulate.raytrace.yarn import blend_halves

    nodes = tuple(float(x) for x in config.w_t_nodes())
    threads = all_threads(s.threads)
    return blend_halves(population_walks(config, wavelengths), wavelengths, table_photons(s.target) // 2, s.seed,
                        threads if threads else None, n_mu=int(bins[0]), n_phi=int(bins[1]), w_t_nodes=nodes)


def _file_of(config: SimulationConfig) -> str:
    from pathlib import Path

    source = config.source
    return f"{source[len('preset '):]}.toml" if source.startswith("preset ") else Path(source).name


def smooth_boundary_unless_mc(method: str, fiber: Any, *, quiet: bool = False) -> Any:
    """The fiber a model walks: with its transmitting boundary smooth unless the model is the Monte Carlo.

    The Monte Carlo takes a rough boundary for transmitted light
    (``[surface] transmission_rms_slope``, :mod:`simulate.montecarlo.rough`); the summation's and the
    classic model's fiber routes estimate exits by next events through the smooth boundary, so they walk
    the fiber with it smooth, and say so once per process (``quiet``: not at all -- the Monte Carlo fit's
    surrogate, whose docstring says how the boundary's slopes are fitted without it).
    """
    import dataclasses

    rough = max(float(getattr(fiber, "transmission_roughness", 0.0) or 0.0),
                float(getattr(fiber, "transmission_roughness_around", 0.0) or 0.0))
    if method == "mc" or not rough > 0.0:
        return fiber
    if not _SMOOTH_NOTED and not quiet:
        _SMOOTH_NOTED.append(True)
        log.warning("--method %s walks the fiber with a smooth boundary: [surface] transmission_rms_slope "
                    "(%.3g) is taken by --method mc only (docs/physics.md 3, \"Rough boundary\")",
                    method, float(fiber.transmission_roughness))
    return dataclasses.replace(fiber, transmission_roughness=0.0, transmission_roughness_around=None)


_SMOOTH_NOTED: list[bool] = []


@register("summation")
def _summation(config: SimulationConfig, fiber: Any, g: Geometries, wavelengths: np.ndarray,
               s: RunSettings) -> FabricEstimate:
    from simulate import fiber as fiber_mod

    if getattr(config, "structure", None) is not None:  # the fabric's visible fibers
        return _structured(config, fiber, g, wavelengths, s)
    pairs = fab.FiberPairs.from_angles(g.theta_i, g.phi_i, g.theta_o, g.phi_o)
    log.info("summation: %d geometries -> %d unique fiber-frame pairs x %d wavelengths",
             g.theta_i.size, pairs.n_unique, wavelengths.size)
    est = fiber_mod.volume_brdf(fiber, pairs.w_in, pairs.w_out, wavelengths, method=config.route,
                                target_rel_err=s.target, max_photons=s.max_photons, seed=s.seed,
                                threads=s.threads, progress=s.progress)
    r_surf = np.asarray(fiber_mod.surface_brdf(fiber, pairs.w_in, pairs.w_out), float)
    R_B = np.asarray(est.R, float) + r_surf[:, None]
    beta, u_beta = fab.summation_from_table(pairs, R_B, est.u_R)
    n = np.full(beta.shape, max(int(est.photons), 1))
    return FabricEstimate(beta, u_beta, n, int(est.photons), jsonable(dict(est.info)), float(est.seconds),
                          {"unique_fiber_pairs": pairs.n_unique, "symmetry_reduced": True})


def _structured(config: SimulationConfig, fiber: Any, g: Geometries, wavelengths: np.ndarray,
                s: RunSettings) -> FabricEstimate:
    """The summation over the fabric's visible fibers in all their orientations.

    :func:`simulate.fabric.structure.structured_beta`, for a config with a ``[structure]`` section.
    """
    from simulate.fabric import structure as st

    spec = config.structure
    fab.FiberPairs.from_angles(g.theta_i, g.phi_i, g.theta_o, g.phi_o)  # the summation's checks and warnings
    weave = weave_from_config(config) if spec.kind == "woven" else None
    beta, u_beta, info = st.structured_beta(spec, fiber, weave, fab.directions_deg(g.theta_i, g.phi_i),
                                            fab.directions_deg(g.theta_o, g.phi_o), wavelengths,
                                            target_rel_err=s.target, seed=s.seed, threads=s.threads)
    n = np.full(beta.shape, max(int(info["photons"]), 1))
    return FabricEstimate(beta, u_beta, n, int(info["photons"]), jsonable(info), float(info["seconds"]),
                          {"structure": jsonable(info["structure"]), "facets": jsonable(info["facets"])})


@register("classic")
def _classic(config: SimulationConfig, fiber: Any, g: Geometries, wavelengths: np.ndarray,
             s: RunSettings) -> FabricEstimate:
    from simulate import fiber as fiber_mod

    started = time.perf_counter()
    w_i = fab.directions_deg(g.theta_i, g.phi_i)
    w_o = fab.directions_deg(g.theta_o, g.phi_o)
    rho, u_rho = fiber_mod.normal_albedo(fiber, wavelengths, target_rel_err=s.target, seed=s.seed, threads=s.threads)
    rho = np.asarray(rho, float)
    beta = fab.classic_beta(rho, w_i, w_o, config.rms_slope, config.n_host)
    u_beta = np.broadcast_to(np.asarray(u_rho, float)[None, :], beta.shape).copy()
    n = np.ones(beta.shape, dtype=np.int64)
    return FabricEstimate(beta, u_beta, n, None, {}, time.perf_counter() - started,
                          {"rho_d": rho.tolist(), "u_rho_d": np.asarray(u_rho, float).tolist()})


@register("mc")
def _woven_mc(config: SimulationConfig, fiber: Any, g: Geometries, wavelengths: np.ndarray,
              s: RunSettings) -> FabricEstimate:
    """The Monte Carlo of the config's weave (a felt with a ``nonwoven`` ``[structure]``).

    A blend's populations are mixed by share in the exit tables its yarns (the felt's fibers) walk
    (:func:`population_walks`).
    """
    from simulate import raytrace
    from simulate.geometry.mesh import mesh as weave_mesh

    w_i = fab.directions_deg(g.theta_i, g.phi_i)
    w_o = fab.directions_deg(g.theta_o, g.phi_o)
    spec = getattr(config, "structure", None)       # twist, or a felt (simulate.geometry.felt)
    blend = getattr(config, "populations", None)
    populations = population_walks(config, wavelengths) if blend else None
    if populations:
        fiber = populations[0][1]       # the surface term's (radius, index and slope: the populations')
    if spec is not None and spec.kind == "nonwoven":
        from simulate.geometry.felt import cached_felt_mesh

        # the felt's independent realisations, alternately on the two table halves: their spread puts the
        # fibers' placement into u_beta (simulate.raytrace.estimate, "A felt"); from the table cache, so
        # the runs of a fit that keeps the structure build them once
        n_real = int(getattr(config, "felt_realisations", DEFAULT_FELT_REALISATIONS))
        felts = tuple(cached_felt_mesh(spec, float(fiber.radius_um), seed=s.seed + FELT_SEED_STRIDE * h)[0]
                      for h in range(n_real))
        mesh: Any = felts
        geometry: dict = {"felt": felts[0].info, "felt_second_realisation": felts[1].info}
    else:
        wv = weave_from_config(config)
        mesh = weave_mesh(wv)
        geometry = {"weave": {"matrix": wv.matrix.tolist(), "spacing_um": wv.spacing_um, "width_um": wv.width_um,
                              "height_um": wv.height_um, "crimp": wv.crimp, "sides": wv.sides,
                              "points_per_span": wv.points_per_span}}
    # a felt walks the fiber's own table (a weave's yarns walk the pile, simulate.raytrace.pile, whose exits
    # are the yarn's): where the fiber's clearness decides whether the exit bins resolve it
    felt = spec is not None and spec.kind == "nonwoven"
    bins = config.exit_bins
    fibers = [f for _, f in populations] if populations else [fiber]
    if bins is None:     # a blend: the finest any of its fibers asks
        bins = max((raytrace.estimate.default_exit_bins(f, wavelengths, felt) for f in fibers), key=lambda b: b[0] * b[1])
    for f in fibers:
        note = raytrace.estimate.clear_fiber_note(f, wavelengths, bins) if felt else None
        if note:
            log.warning("simulate fabric --method mc: %s", note)
            break
    if blend:
        geometry["populations"] = _population_record(config)
    beta, u_beta, mc_info = raytrace.fabric_beta(
        mesh, fiber, w_i, w_o, wavelengths, target_rel_err=s.target, max_rays=s.max_photons or 0,
        populations=populations,
        seed=s.seed, threads=all_threads(s.threads), progress=s.progress, max_seconds=s.max_seconds,
        structure=spec, exit_bins=bins, axial_shift=bool(getattr(config, "axial_shift", False)),
        w_t_nodes=config.w_t_nodes() if hasattr(config, "w_t_nodes") else (0.0, 0.25, 0.5, 0.75, 0.95),
        record=s.record)
    if s.record is not None:      # what a dye's re-weighting builds its tables from (simulate.raytrace.reweight)
        s.record.update(fiber=fiber, blend=bool(blend), bins=tuple(bins), target=s.target)
    n = np.full(beta.shape, max(int(mc_info["rays"]), 1))
    meshes = mesh if isinstance(mesh, tuple) else (mesh,)
    extra = {**geometry, "triangles": int(meshes[0].faces.shape[0]), "ray_engine": "embree (embreex)",
             "estimator": "next-event towards each detector direction"}
    return FabricEstimate(beta, u_beta, n, int(mc_info["table"]["photons"]), jsonable(mc_info),
                          float(mc_info["table"]["seconds"]), extra)


#: The seed of a felt's realisation ``j`` is the run's seed plus this times ``j`` (the first's is the run's seed).
FELT_SEED_STRIDE = 1_000_003

#: The registered fabric models, in registration order.
MODELS: tuple[str, ...] = tuple(_REGISTRY)


def reweighted_estimate(record: dict, config: Any, wavelengths_nm: Any) -> tuple[np.ndarray, np.ndarray, dict]:
    """:func:`simulate.raytrace.reweight.reweighted_beta` of a recorded ``--method mc`` run.

    The run was recorded through :class:`RunSettings` ``record``; the estimate is for ``config`` (the
    traced config with another dye, or
    other shares or dyes of its populations). The tables are those a trace of ``config`` would walk (the same
    photons and seeds). :class:`ValueError` when ``config``'s fiber differs from the traced one in more than its
    dye. For a blend only the first population's fiber is compared: the caller changes no more than the
    populations' dyes and shares (the fit re-weights ``fiber.dye`` parameters only).
    """
    from simulate.raytrace.reweight import new_tables, reweighted_beta, same_but_dye

    wl = np.asarray(wavelengths_nm, float)
    if not np.array_equal(wl, record["wavelengths_nm"]):
        raise ValueError("reweight: other wavelengths than the traced run's")
    blend = bool(record.get("blend"))
    populations = population_walks(config, wl) if blend else None
    fiber = populations[0][1] if populations else config.fiber(wl)
    if not same_but_dye(record["fiber"], fiber):
        raise ValueError("reweight: the fiber differs from the traced one in more than its dye: trace again")
    return reweighted_beta(record, new_tables(record, fiber, populations=populations))
