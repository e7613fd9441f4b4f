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
- ``mc``: the woven micro-element's Monte Carlo (:mod:`simulate.woven`).
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from simulate import fabric as fab
from simulate.config import SimulationConfig, weave_from_config
from simulate.provenance import jsonable

__all__ = ["FabricEstimate", "Geometries", "RunSettings", "MODELS", "all_threads", "register", "evaluate"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Geometries:
    """``G`` geometries of the fabric frame: incidence and observation angles in degrees."""

    theta_i: np.ndarray
    phi_i: np.ndarray
    theta_o: np.ndarray
    phi_o: np.ndarray


def all_threads(threads: Any) -> int:
    """``threads`` with 0 or None meaning "all that numba allows" (``numba.config.NUMBA_NUM_THREADS``,
    which ``NUMBA_NUM_THREADS`` in the environment lowers), the one meaning of 0 in configs and flags."""
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
    fiber = smooth_boundary_unless_mc(method, fiber)
    return _REGISTRY[method](config, fiber, geometries, np.asarray(wavelengths, float), settings)


def smooth_boundary_unless_mc(method: str, fiber: Any, *, quiet: bool = False) -> Any:
    """The fiber a model walks: the Monte Carlo takes a rough boundary for transmitted light
    (``[surface] transmission_rms_slope``, :mod:`simulate.montecarlo.rough`); the summation's and the
    classic model's fiber routes estimate exits by next events through the smooth boundary, so they walk
    the fiber with it smooth, and say so once per process (``quiet``: not at all -- the Monte Carlo fit's
    surrogate, whose docstring says how the boundary's slopes are fitted without it)."""
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
    """The summation over the fabric's visible fibers in all their orientations
    (:func:`simulate.fabric.structure.structured_beta`), for a config with a ``[structure]`` section."""
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
    from simulate import woven
    from simulate.fabric.mesh import mesh as weave_mesh

    w_i = fab.directions_deg(g.theta_i, g.phi_i)
    w_o = fab.directions_deg(g.theta_o, g.phi_o)
    spec = getattr(config, "structure", None)       # twist, or a felt (simulate.nonwoven.felt)
    if spec is not None and spec.kind == "nonwoven":
        from simulate.nonwoven.felt import cached_felt_mesh

        # two realisations of the felt, one per table half: their difference puts the spread of the
        # fibers' placement into u_beta (simulate.woven.estimate, "A felt"); from the table cache, so
        # the runs of a fit that keeps the structure build them once
        felts = tuple(cached_felt_mesh(spec, float(fiber.radius_um), seed=s.seed + FELT_SEED_STRIDE * h)[0]
                      for h in (0, 1))
        mesh: Any = felts
        geometry: dict = {"felt": felts[0].info, "felt_second_realisation": felts[1].info}
    else:
        wv = weave_from_config(config)
        mesh = weave_mesh(wv)
        geometry = {"weave": {"matrix": wv.matrix.tolist(), "spacing_um": wv.spacing_um, "width_um": wv.width_um,
                              "height_um": wv.height_um, "crimp": wv.crimp, "sides": wv.sides,
                              "points_per_span": wv.points_per_span}}
    # a felt walks the fiber's own table (a weave's yarns walk the pile, simulate.woven.pile, whose exits
    # are the yarn's): where the fiber's clearness decides whether the exit bins resolve it
    felt = spec is not None and spec.kind == "nonwoven"
    bins = config.exit_bins
    if bins is None:
        bins = woven.estimate.default_exit_bins(fiber, wavelengths, felt)
    note = woven.estimate.clear_fiber_note(fiber, wavelengths, bins) if felt else None
    if note:
        log.warning("simulate fabric --method mc: %s", note)
    beta, u_beta, mc_info = woven.fabric_beta(
        mesh, fiber, w_i, w_o, wavelengths, target_rel_err=s.target, max_rays=s.max_photons or 0,
        seed=s.seed, threads=all_threads(s.threads), progress=s.progress, max_seconds=s.max_seconds,
        structure=spec, exit_bins=bins, axial_shift=bool(getattr(config, "axial_shift", False)),
        w_t_nodes=config.w_t_nodes() if hasattr(config, "w_t_nodes") else (0.0, 0.25, 0.5, 0.75, 0.95))
    n = np.full(beta.shape, max(int(mc_info["rays"]), 1))
    meshes = mesh if isinstance(mesh, tuple) else (mesh,)
    extra = {**geometry, "triangles": int(meshes[0].faces.shape[0]), "ray_engine": "embree (embreex)",
             "estimator": "next-event towards each detector direction"}
    return FabricEstimate(beta, u_beta, n, int(mc_info["table"]["photons"]), jsonable(mc_info),
                          float(mc_info["table"]["seconds"]), extra)


#: The seed of a felt's second realisation is the run's seed plus this (the first's is the run's seed).
FELT_SEED_STRIDE = 1_000_003

#: The registered fabric models, in registration order.
MODELS: tuple[str, ...] = tuple(_REGISTRY)
