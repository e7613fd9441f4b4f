"""What raises the traced felt's opposition peak: a one-parameter-at-a-time scan from ``green-felt-mc``.

    python docs/scripts/felt_opposition_scan.py                  # every variant; writes docs/data/felt-opposition.json
    python docs/scripts/felt_opposition_scan.py --only preset,scatterers-x10 --out DIR/scan.json
    python docs/scripts/felt_opposition_scan.py --resume --split   # add the single scattering's two parts
    python docs/scripts/felt_opposition_scan.py --resume --lambertian   # add the opaque Lambertian felt
    python docs/scripts/render_figures.py                        # then the note's tables

Each variant is the ``green-felt-mc`` preset with one thing changed (:data:`VARIANTS`): the fibers'
scatterers (the delustrant's volume fraction), the dye's absorption, the surface's reflection slope,
the boundary's roughness for transmitted light, the felt's inclination spread (which sets the
deposited felt's volume fraction), the needle-punched fraction, the fiber amount, the fiber's refractive
index; and three combinations of those changes; then blends of differently dyed fibers, the dye placed in a
ring or a core, and the scatterers placed in a skin or a core (their amount kept, or multiplied; a sheath: a skin
of scatterers over a dyed core). Each is traced by
the felt Monte Carlo (:func:`simulate.raytrace.fabric_beta`, two felt realisations as ``simulate fabric
--method mc`` builds them) at ``--seeds`` seeds (each its own felts, table and rays; the same seeds for every
variant, so variants that keep the preset's felt are traced on the same felts) at the RGL file's incidences 40.03 and
27.76 deg, towards 12 directions on each of the rings 6 and 30 deg from the retro direction
(:func:`compare.ratios.ring_directions`) and towards the normal, at 450, 550 and 650 nm: once
with the single scattering only (``max_events=1``) and once with all orders. The opposition ratio
is :func:`compare.ratios.opposition_ratios` of those points (its standard error takes each
point's error as independent; the table's share of them is common to a ring, so it is indicative); the
seeds' rings are pooled, and the standard error of the mean of the seeds' own ratios, from their
scatter, is kept beside it as a check.
With ``--split`` the single scattering is traced twice more, scoring only the first fiber's surface
reflection or only the light out of its volume (:func:`only_event`; the same felts, tables, seeds and
rays, so the two parts add up to the single scattering, exactly when every shadow ray is traced).
With ``--lambertian`` the preset's felts are traced with opaque Lambertian fibers of the albedos
:data:`ALBEDOS` (single scattering and all orders, every albedo on the same paths: :func:`lambertian_beta`),
and the all-orders curves are read at the file's levels (:func:`albedo_readoff`); alone it traces no variant.
The file's own ratios at the same directions come from the mock sample of the file
(:func:`gonio.mock.samples.make_sample`).

The result is written after every variant (an interrupted scan keeps what it finished; ``--resume``
adds the runs it lacks), wrapped as :func:`render_figures.record` does: the command and the machine.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import math
import os
import resource
import shlex
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from render_figures import DATA, ROOT, machine  # noqa: E402

NAME = "felt-opposition"
CONFIG = "green-felt-mc"
SAMPLE = ROOT / "fixtures" / "real" / "acrylic_felt_green_rgb.bsdf"
INCIDENCES_DEG = (40.03, 27.76)
WAVELENGTHS_NM = (450.0, 550.0, 650.0)
RING_POINTS = 12
#: the preset's exit bins, held for every variant (a turbid fiber would default to coarser ones)
EXIT_BINS = (10, 20)
DEFAULT_TARGET = 0.07
DEFAULT_THREADS = 2
DEFAULT_SEEDS = 3
COMMAND = "python docs/scripts/felt_opposition_scan.py"


def _scatterers(factor: float) -> Callable[[Any], dict]:
    """The change that multiplies the scatterers' volume fraction by ``factor``."""
    def change(cfg: Any) -> dict:
        p = cfg.particles
        return {"particles": dataclasses.replace(p, volume_fraction=p.volume_fraction * factor)}
    return change


def _dye(factor: float) -> Callable[[Any], dict]:
    """The change that multiplies the dye's absorption by ``factor`` (every knot's log10 moved)."""
    def change(cfg: Any) -> dict:
        params = dict(cfg.dye.params)
        params["log10_per_um"] = [v + math.log10(factor) for v in params["log10_per_um"]]
        return {"dye": dataclasses.replace(cfg.dye, params=params)}
    return change


def _dye_red(value: float | None = None, factor: float = 1.0) -> Callable[[Any], dict]:
    """The dye's red knots (above 600 nm) set to ``value`` and multiplied by ``factor``.

    ``value`` is the log10 of the absorption per um (None: each knot's kept): one population of a
    blend whose red differs from the preset's.
    """
    def change(cfg: Any) -> dict:
        params = dict(cfg.dye.params)
        params["log10_per_um"] = [(v if value is None else value) + math.log10(factor) if w > 600.0 else v
                                  for w, v in zip(params["wavelength_nm"], params["log10_per_um"], strict=True)]
        return {"dye": dataclasses.replace(cfg.dye, params=params)}
    return change


def _blend(*parts: tuple[float, Callable[[Any], dict]]) -> Callable[[Any], dict]:
    """A blend of fiber populations (``[[populations]]``): each ``(share, change of the dye)``."""
    def change(cfg: Any) -> dict:
        from simulate.config import Population

        pops = []
        for k, (share, dye_change) in enumerate(parts):
            dye = dye_change(cfg).get("dye", cfg.dye)
            pops.append(Population(name=f"population {k + 1}", share=share, radius_um=cfg.radius_um, n_host=cfg.n_host,
                                   dye=dye, particles=cfg.particles, rms_slope=cfg.rms_slope,
                                   transmission_rms_slope=cfg.transmission_rms_slope,
                                   transmission_rms_slope_around=cfg.transmission_rms_slope_around))
        return {"populations": tuple(pops)}
    return change


def _placed(profile: str, depth_um: float) -> Callable[[Any], dict]:
    """The dye placed in a ``ring`` from the surface to ``depth_um`` or a ``core`` below a clear skin of that depth.

    The fiber's amount of dye is kept: its absorption coefficient is divided by the dyed share of the
    cross-section.
    """
    def change(cfg: Any) -> dict:
        inner = (cfg.radius_um - depth_um) / cfg.radius_um
        share = 1.0 - inner ** 2 if profile == "ring" else inner ** 2
        return {"dye_profile": profile, "dye_depth_um": depth_um, **_dye(1.0 / share)(cfg)}
    return change


def _scatterers_placed(profile: str, depth_um: float, factor: float = 1.0) -> Callable[[Any], dict]:
    """The scatterers placed in a ``skin`` from the surface to ``depth_um`` or a ``core`` below a clear skin of it.

    The fiber's amount of scatterers is kept (times ``factor``): their volume fraction is divided by the share of the
    cross-section they fill.
    """
    def change(cfg: Any) -> dict:
        inner = (cfg.radius_um - depth_um) / cfg.radius_um
        share = 1.0 - inner ** 2 if profile == "skin" else inner ** 2
        return {"scatterer_profile": profile, "scatterer_depth_um": depth_um, **_scatterers(factor / share)(cfg)}
    return change


def _field(**values: Any) -> Callable[[Any], dict]:
    """The change that sets the config's fields ``values``."""
    return lambda cfg: dict(values)


def _structure(**values: Any) -> Callable[[Any], dict]:
    """The change that sets the structure's fields ``values``."""
    return lambda cfg: {"structure": dataclasses.replace(cfg.structure, **values)}


def _both(*changes: Callable[[Any], dict]) -> Callable[[Any], dict]:
    """Several changes of different fields at once."""
    def change(cfg: Any) -> dict:
        out: dict = {}
        for c in changes:
            out.update(c(cfg))
        return out
    return change


#: name -> (what changes, the change of the preset's config), in the order the scan runs them
VARIANTS: dict[str, tuple[str, Callable[[Any], dict]]] = {
    "preset": ("green-felt-mc as shipped", _field()),
    "scatterers-x10": ("scatterers' volume fraction x10", _scatterers(10.0)),
    "scatterers-x30": ("scatterers' volume fraction x30", _scatterers(30.0)),
    "scatterers-x3": ("scatterers' volume fraction x3", _scatterers(3.0)),
    "dye-x3": ("dye absorption x3", _dye(3.0)),
    "dye-x0.3": ("dye absorption x0.3", _dye(0.3)),
    "rms-slope-x2": ("reflection slope x2", lambda c: {"rms_slope": 2.0 * c.rms_slope}),
    "rms-slope-x0.5": ("reflection slope x0.5", lambda c: {"rms_slope": 0.5 * c.rms_slope}),
    "transmission-smooth": ("boundary smooth for transmitted light",
                            _field(transmission_rms_slope=0.0, transmission_rms_slope_around=None)),
    "transmission-x2": ("boundary's transmission slopes x2", lambda c: {
        "transmission_rms_slope": 2.0 * c.transmission_rms_slope,
        "transmission_rms_slope_around": 2.0 * c.transmission_rms_slope_around}),
    "spread-10": ("inclination spread 10 deg", _structure(felt_spread_deg=10.0)),
    "spread-2": ("inclination spread 2 deg", _structure(felt_spread_deg=2.0)),
    "punched-0.2": ("needle-punched fraction 0.2", _structure(felt_normal_fraction=0.2)),
    "layers-5": ("fiber amount halved (5 layers)", _structure(layers=5)),
    "n-1.6": ("fiber's refractive index 1.6", _field(n_host=1.6)),
    "n-1.8": ("fiber's refractive index 1.8 (beyond acrylic)", _field(n_host=1.8)),
    "scatterers-x10+rms-slope-x2": ("scatterers' volume fraction x10 and reflection slope x2",
                                    _both(_scatterers(10.0), lambda c: {"rms_slope": 2.0 * c.rms_slope})),
    "n-1.8+rms-slope-x2": ("fiber's refractive index 1.8 and reflection slope x2",
                           _both(_field(n_host=1.8), lambda c: {"rms_slope": 2.0 * c.rms_slope})),
    "scatterers-x30+dye-x3": ("scatterers' volume fraction x30 and dye absorption x3",
                              _both(_scatterers(30.0), _dye(3.0))),
    "red-clear": ("the dye's red as clear as its green (a yellow-green population)", _dye_red(-2.0)),
    "red-x10": ("the dye's red absorption x10 (a blue-green population)", _dye_red(None, 10.0)),
    "blend-red": ("a blend: half red-clear, half red-x10 fibers", _blend((0.5, _dye_red(-2.0)),
                                                                        (0.5, _dye_red(None, 10.0)))),
    "blend-red-x4": ("a blend: half red-clear, half with the dye's red absorption x4",
                     _blend((0.5, _dye_red(-2.0)), (0.5, _dye_red(None, 4.0)))),
    "blend-red-x2": ("a blend: half red-clear, half with the dye's red absorption x2",
                     _blend((0.5, _dye_red(-2.0)), (0.5, _dye_red(None, 2.0)))),
    "ring-1.5": ("the dye in a ring 1.5 um deep (its amount kept)", _placed("ring", 1.5)),
    "core-4.1": ("the dye in a core below a clear skin 4.1 um deep (its amount kept)", _placed("core", 4.1)),
    "skin-0.5": ("the scatterers in a skin 0.5 um deep (their amount kept)", _scatterers_placed("skin", 0.5)),
    "skin-1.5": ("the scatterers in a skin 1.5 um deep (their amount kept)", _scatterers_placed("skin", 1.5)),
    "skin-3": ("the scatterers in a skin 3 um deep (their amount kept)", _scatterers_placed("skin", 3.0)),
    "scatterers-core-4.1": ("the scatterers in a core below a clear skin 4.1 um deep (their amount kept)",
                            _scatterers_placed("core", 4.1)),
    "sheath-1.5": ("the scatterers in a skin 1.5 um deep over the dye in the core below it (both amounts kept)",
                   _both(_scatterers_placed("skin", 1.5), _placed("core", 1.5))),
    "sheath-1.5-x10": ("sheath-1.5 with ten times the scatterers",
                       _both(_scatterers_placed("skin", 1.5, 10.0), _placed("core", 1.5))),
    "skin-1.5-x10": ("the scatterers x10 in a skin 1.5 um deep", _scatterers_placed("skin", 1.5, 10.0)),
    "skin-0.5-x10": ("the scatterers x10 in a skin 0.5 um deep", _scatterers_placed("skin", 0.5, 10.0)),
    "skin-1.5-x30": ("the scatterers x30 in a skin 1.5 um deep", _scatterers_placed("skin", 1.5, 30.0)),
}


def variant_config(name: str, base: Any) -> tuple[Any, dict]:
    """The config of variant ``name`` and its changed fields, as JSON values.

    Parameters
    ----------
    name : str
        A key of :data:`VARIANTS`.
    base : simulate.config.Config
        The preset's config.

    Returns
    -------
    config : simulate.config.Config
        ``base`` with the variant's change.
    shown : dict
        The changed fields by their dotted names (a structure's: only the fields that differ from the
        preset's), empty for the preset.
    """
    changes = VARIANTS[name][1](base)
    shown = {}
    for key, value in changes.items():
        if key == "particles":
            shown["particles.volume_fraction"] = value.volume_fraction
        elif key == "dye":
            shown["fiber.dye.log10_per_um"] = list(value.params["log10_per_um"])
        elif key == "n_host":
            shown["fiber.n_host"] = value
        elif key == "populations":
            shown["populations"] = [{"share": p.share, "fiber.dye.log10_per_um": list(p.dye.params["log10_per_um"])}
                                    for p in value]
        elif key in ("dye_profile", "dye_depth_um", "scatterer_profile", "scatterer_depth_um"):
            shown[f"fiber.{key}"] = value
        elif key == "structure":
            shown.update({f"structure.{f.name}": getattr(value, f.name) for f in dataclasses.fields(value)
                          if getattr(value, f.name) != getattr(base.structure, f.name)})
        else:
            shown[f"surface.{key}"] = value
    return dataclasses.replace(base, **changes), shown


def detectors(theta_i: float) -> list[tuple[float, float]]:
    """``(theta_o, phi_o)`` of one incidence: the ring at 6 deg, the ring at 30 deg, then the normal.

    Parameters
    ----------
    theta_i : float
        The incidence (deg).

    Returns
    -------
    list of tuple of (float, float)
        :data:`RING_POINTS` directions on each ring, then ``(0, 0)`` (deg).
    """
    from compare.ratios import INNER_DEG, OUTER_DEG, ring_directions

    return [*ring_directions(theta_i, INNER_DEG, RING_POINTS), *ring_directions(theta_i, OUTER_DEG, RING_POINTS),
            (0.0, 0.0)]


def geometries() -> Any:
    """Every (incidence, detector) row: a frame of ``theta_i, phi_i, theta_o, phi_o``.

    Returns
    -------
    pandas.DataFrame
        The :func:`detectors` of each incidence of :data:`INCIDENCES_DEG`, in that order (deg).
    """
    import pandas as pd

    return pd.DataFrame([dict(theta_i=ti, phi_i=0.0, theta_o=t, phi_o=p) for ti in INCIDENCES_DEG
                         for t, p in detectors(ti)])


def summarise(g: Any, beta: np.ndarray, u: np.ndarray, bands: tuple[float, ...] = WAVELENGTHS_NM) -> dict:
    """Per incidence: the two rings' means, the opposition ratio and the view towards the normal, per band.

    Parameters
    ----------
    g : pandas.DataFrame
        The :func:`geometries` rows ``beta`` is traced at.
    beta : numpy.ndarray
        ``[rows, bands]`` values.
    u : numpy.ndarray
        Their standard errors (zeros for the file's noiseless values).
    bands : tuple of float
        The columns of ``beta``: the wavelengths, or the Lambertian felt's albedos.

    Returns
    -------
    dict
        Keyed by the incidence (``"40.03"``): per band the ratio and its standard error, the points of
        each ring, the rings' means and the normal view with their standard errors (JSON lists).

    Raises
    ------
    RuntimeError
        The rows do not hold both rings of an incidence.
    """
    import pandas as pd

    from compare.ratios import Missing, opposition_ratios

    wl = np.asarray(bands, float)
    table = pd.DataFrame({c: np.repeat(g[c].to_numpy(float), wl.size) for c in g.columns})
    table["wavelength_nm"] = np.tile(wl, len(g))
    table["beta"], table["u_beta"] = beta.reshape(-1), u.reshape(-1)
    ratios = opposition_ratios(table)
    if isinstance(ratios, Missing):      # the scan's own detectors hold both rings (tested)
        raise RuntimeError(f"felt_opposition_scan: {ratios.reason}")
    out = {}
    for ti in INCIDENCES_DEG:
        at = np.nonzero(np.isclose(g["theta_i"].to_numpy(float), ti))[0]
        inner, outer, normal = at[:RING_POINTS], at[RING_POINTS:2 * RING_POINTS], at[-1]
        r = ratios[ti]
        out[f"{ti:g}"] = {
            "ratio": [r.value[w] for w in wl], "u_ratio": [r.u[w] for w in wl], "points": list(r.n_points),
            "ring_6": beta[inner].mean(0).tolist(), "u_ring_6": (np.sqrt((u[inner] ** 2).sum(0)) / inner.size).tolist(),
            "ring_30": beta[outer].mean(0).tolist(), "u_ring_30": (np.sqrt((u[outer] ** 2).sum(0)) / outer.size).tolist(),
            "normal_view": beta[normal].tolist(), "u_normal_view": u[normal].tolist()}
    return out


def file_ratios() -> dict:
    """The RGL file's opposition ratios and view towards the normal at the scan's directions (no noise).

    Returns
    -------
    dict
        :func:`summarise` of the mock sample of the file at :func:`geometries` and :data:`WAVELENGTHS_NM`.
    """
    from gonio.mock.samples import make_sample

    g = geometries()
    wl = np.asarray(WAVELENGTHS_NM)
    sample = make_sample(str(SAMPLE))
    rows = g.loc[g.index.repeat(wl.size)]
    beta = sample.beta(rows["theta_i"].to_numpy(float), rows["phi_i"].to_numpy(float), rows["theta_o"].to_numpy(float),
                       rows["phi_o"].to_numpy(float), np.tile(wl, len(g))).reshape(len(g), wl.size)
    return summarise(g, beta, np.zeros_like(beta))


@contextlib.contextmanager
def only_event(event: int) -> Iterator[None]:
    """Within the block the felt tracer scores the next-event estimates of one shading event only.

    Event 0 is the fiber surface's reflection, 1 the light out of the fiber's volume (the events of
    :func:`simulate.raytrace.shading.shade`). The other event's estimates are dropped after each shading
    call (its contributions zeroed, no shadow ray asked for); the rays' paths are not changed. The
    tracer's files are not edited: the wavefront's shading call (``shade_groups`` as
    :mod:`simulate.raytrace.integrator` calls it) is wrapped for the block and restored after it.

    Parameters
    ----------
    event : {0, 1}
        The shading event scored.

    Yields
    ------
    None

    Raises
    ------
    ValueError
        ``event`` is neither 0 nor 1.
    """
    from simulate.raytrace import integrator

    if event not in (0, 1):
        raise ValueError(f"only_event: event must be 0 (surface) or 1 (volume), got {event!r}")
    shade_groups = integrator.shade_groups
    drop = 1 - event

    def shade_groups_one(*args: Any) -> None:
        shade_groups(*args)
        out = args[-1]
        out.nee_c[:, drop] = 0.0
        out.nee_need[:, drop] = False

    integrator.shade_groups = shade_groups_one     # type: ignore[assignment]
    try:
        yield
    finally:
        integrator.shade_groups = shade_groups      # type: ignore[assignment]


#: the orders a run traces: name -> (scattering events followed, the shading event scored: None for both)
ORDERS: dict[str, tuple[int, int | None]] = {"single": (1, None), "all": (0, None)}
#: the single scattering's two parts (``--split``): the first fiber's surface reflection, the light through it
SPLIT_ORDERS: dict[str, tuple[int, int | None]] = {"surface": (1, 0), "volume": (1, 1)}


def _felts_and_geometries(structure: Any, radius_um: float, seed: int, felts: dict, felt: dict | None) -> tuple:
    """The two felts of ``structure`` at ``seed`` (built once into ``felts``), their figures, the plan and its directions.

    ValueError if ``felt`` (the figures a run already holds) differs from the felts built now.
    """
    from simulate.fabric import directions_deg
    from simulate.geometry.felt import felt_mesh
    from simulate.products import FELT_SEED_STRIDE

    key = (structure, seed)
    if key not in felts:
        felts[key] = tuple(felt_mesh(structure, radius_um, seed=seed + FELT_SEED_STRIDE * h) for h in (0, 1))
    meshes = felts[key]
    built = {k: [m.info[k] for m in meshes] for k in ("fibers", "normal_fibers", "thickness_um", "volume_fraction")}
    if felt is not None and built != felt:
        raise ValueError("the felts built now differ from those its runs were traced on")
    g = geometries()
    w_in = directions_deg(g["theta_i"].to_numpy(float), g["phi_i"].to_numpy(float))
    w_out = directions_deg(g["theta_o"].to_numpy(float), g["phi_o"].to_numpy(float))
    return meshes, built, g, w_in, w_out


def run_variant(name: str, base: Any, seed: int, target: float, threads: int, max_rays: int, felts: dict,
                orders: tuple[str, ...] = tuple(ORDERS), felt: dict | None = None) -> dict:
    """Trace variant ``name`` at ``seed`` (its felts' and rays') at each of ``orders``.

    Parameters
    ----------
    name : str
        A key of :data:`VARIANTS`.
    base : simulate.config.Config
        The preset's config.
    seed : int
        The seed of the felts, the table and the rays.
    target : float
        Each trace's target relative error.
    threads : int
        Threads of the traces (they do not change the figures).
    max_rays : int
        Ray budget per incidence and table half (0: none).
    felts : dict
        Meshes by ``(structure, seed)``, filled with the felts built here.
    orders : tuple of str
        Keys of :data:`ORDERS` and :data:`SPLIT_ORDERS`.
    felt : dict, optional
        The felts' figures a run already holds; ValueError before any trace if the felts built now
        differ from them.

    Returns
    -------
    dict
        The run: its seed, the felts' figures, per order its :func:`summarise` and the trace's rays,
        stop, errors, seconds and cache, and the run's wall and CPU seconds.
    """
    from simulate.raytrace import fabric_beta, integrator

    cfg, _ = variant_config(name, base)
    wl = np.asarray(WAVELENGTHS_NM)
    fiber = cfg.fiber(wl)
    started, cpu0 = time.perf_counter(), _cpu()
    meshes, built, g, w_in, w_out = _felts_and_geometries(cfg.structure, fiber.radius_um, seed, felts, felt)
    traced = {}
    tables = None
    if cfg.populations:         # a blend: the populations' tables mixed by share, as simulate fabric traces it
        from simulate.products import RunSettings, felt_population_tables

        tables = felt_population_tables(cfg, fiber, wl, RunSettings(target=target, seed=seed, threads=threads),
                                        EXIT_BINS)
    for label in orders:
        events, event = {**ORDERS, **SPLIT_ORDERS}[label]
        with contextlib.nullcontext() if event is None else only_event(event):
            beta, u, info = fabric_beta(meshes, fiber, w_in, w_out, wl, max_events=events, target_rel_err=target,
                                        tables=tables,
                                        max_rays=max_rays, seed=seed, threads=threads, structure=cfg.structure,
                                        exit_bins=EXIT_BINS, axial_shift=bool(cfg.axial_shift),
                                        w_t_nodes=cfg.w_t_nodes())
        traced[label] = {"incidences": summarise(g, beta, u), "rays": int(info["rays"]), "stop": info["stop"],
                         "rel_err": {f"{math.degrees(math.acos(r['w_in'][2])):.2f}": r["rel_err"]
                                     for r in info["incidences"]},
                         "seconds": float(info["seconds"]), "table_cache": info["table"]["cache"],
                         "shadow_roulette": bool(integrator.SHADOW_ROULETTE), "threads": threads}
    return {"seed": seed, "felt": built, "orders": traced,
            "wall_seconds": time.perf_counter() - started, "cpu_seconds": _cpu() - cpu0}


#: the albedos of the opaque Lambertian fibers (``--lambertian``): one trace scores them all, on the same paths
ALBEDOS = (0.1, 0.2, 0.35, 0.5, 0.65, 0.8, 0.9, 1.0)


def lambertian_beta(meshes: tuple, albedos: tuple[float, ...], w_in: np.ndarray, w_out: np.ndarray, *,
                    target: float, max_rays: int, seed: int, threads: int, max_events: int) -> tuple[np.ndarray, np.ndarray, dict]:
    """``beta [P, A]`` and its standard error of the felts ``meshes`` with opaque Lambertian fibers of each albedo.

    Traced as :func:`simulate.raytrace.fabric_beta` traces a felt (the rotations of each incidence as one
    wavefront, the two felts averaged, the same seeds and chunks) with :class:`simulate.raytrace.Lambert`
    of the albedos as its spectral axis: every albedo on the same paths (the path's weight is the
    product of the albedos it met; Russian roulette acts on the largest, so the estimates stay unbiased
    for each). The standard error is the rays' only (no table).

    Parameters
    ----------
    meshes : tuple
        The two felt realisations.
    albedos : tuple of float
        The fibers' albedos (the spectral axis).
    w_in : numpy.ndarray
        ``[P, 3]`` incident directions (towards the source).
    w_out : numpy.ndarray
        ``[P, 3]`` outgoing directions.
    target : float
        Target relative error per incidence and felt.
    max_rays : int
        Ray budget per incidence and felt (0: none).
    seed : int
        The rays' seed (each incidence its own, derived from it).
    threads : int
        Threads of the traces.
    max_events : int
        Scattering events followed (1: single scattering; 0: all).

    Returns
    -------
    beta : numpy.ndarray
        ``[P, A]`` values.
    u_beta : numpy.ndarray
        Their standard errors.
    info : dict
        The rays traced, the stop (the first that is not ``target``) and the seconds.
    """
    from simulate.raytrace import Lambert
    from simulate.raytrace.estimate import FELT_ROTATIONS, mean_of
    from simulate.raytrace.integrator import CHUNK, trace_rotations

    material = Lambert(np.asarray(albedos, float))
    key = np.round(w_in, 9)
    incidences, inverse = np.unique(key, axis=0, return_inverse=True)
    inverse = np.asarray(inverse).reshape(-1)
    beta = np.zeros((w_in.shape[0], len(albedos)))
    u_beta = np.zeros_like(beta)
    rays, stops, seconds = 0, [], 0.0
    for k, wi in enumerate(incidences):
        rows = np.nonzero(inverse == k)[0]
        det_key, det_inv = np.unique(np.round(w_out[rows], 9), axis=0, return_inverse=True)
        det_inv = np.asarray(det_inv).reshape(-1)
        det = det_key / np.linalg.norm(det_key, axis=1)[:, None]
        halves = []
        for h, m in enumerate(meshes):
            parts = trace_rotations(m, material, wi / np.linalg.norm(wi), det,
                                    [2.0 * math.pi * (j + 0.5 * h) / FELT_ROTATIONS for j in range(FELT_ROTATIONS)],
                                    target_rel_err=target, max_rays=max_rays, seed=seed + 7919 * k, threads=threads,
                                    chunk=max(256, CHUNK // FELT_ROTATIONS), setups={}, max_events=max_events)
            halves.append(mean_of(parts))
        ra, rb = halves
        beta[rows] = (0.5 * (ra.beta + rb.beta))[det_inv]
        u_beta[rows] = np.sqrt(0.25 * (ra.u_beta ** 2 + rb.u_beta ** 2))[det_inv]
        rays += ra.rays + rb.rays
        seconds += ra.seconds + rb.seconds
        stops += [r.stop for r in halves]
    stop = next((s for s in stops if s != "target"), "target")
    return beta, u_beta, {"rays": rays, "stop": stop, "seconds": seconds}


def run_lambertian(base: Any, seed: int, target: float, threads: int, max_rays: int, felts: dict,
                   felt: dict | None = None) -> dict:
    """The preset's felts at ``seed`` with opaque Lambertian fibers of the albedos :data:`ALBEDOS`.

    The felts are built as :func:`run_variant` builds them; single scattering and all orders are
    summarised as a variant's run is (the bands are the albedos).

    Parameters
    ----------
    base : simulate.config.Config
        The preset's config.
    seed : int
        The seed of the felts and the rays.
    target : float
        Each trace's target relative error.
    threads : int
        Threads of the traces.
    max_rays : int
        Ray budget per incidence and felt (0: none).
    felts : dict
        Meshes by ``(structure, seed)``, filled with the felts built here.
    felt : dict, optional
        The felts' figures a run already holds; ValueError if the felts built now differ from them.

    Returns
    -------
    dict
        The run, as :func:`run_variant` returns one.
    """
    fiber = base.fiber(np.asarray(WAVELENGTHS_NM))
    started, cpu0 = time.perf_counter(), _cpu()
    meshes, built, g, w_in, w_out = _felts_and_geometries(base.structure, fiber.radius_um, seed, felts, felt)
    traced = {}
    for label, (events, _) in ORDERS.items():
        beta, u, info = lambertian_beta(meshes, ALBEDOS, w_in, w_out, target=target, max_rays=max_rays, seed=seed,
                                        threads=threads, max_events=events)
        traced[label] = {"incidences": summarise(g, beta, u, ALBEDOS), "rays": int(info["rays"]), "stop": info["stop"],
                         "seconds": float(info["seconds"]), "threads": threads}
    return {"seed": seed, "felt": built, "orders": traced,
            "wall_seconds": time.perf_counter() - started, "cpu_seconds": _cpu() - cpu0}


def _crossing(x: np.ndarray, y: np.ndarray, level: float) -> float | None:
    """The ``x`` at which the increasing ``y(x)`` (linear between the points) reaches ``level``; None outside."""
    if not (y[0] <= level <= y[-1]) or np.any(np.diff(y) <= 0.0):
        return None
    return float(np.interp(level, y, x))


def _at(x: np.ndarray, y: np.ndarray, at: float) -> float:
    """``y`` at ``at``, linear between the points ``(x, y)``."""
    return float(np.interp(at, x, y))


def albedo_readoff(lamb: dict, file: dict, matched: str = "normal_view", pair: tuple[float, float] = (550.0, 650.0)) -> dict:
    """The Lambertian felt's all-orders curves read at the file's levels, per incidence.

    For each wavelength of ``pair``, the albedo at which the felt's ``matched`` beta equals the file's,
    and the felt's opposition ratio there (both linear between the traced albedos), its standard error
    from the ratio's own at the neighbouring albedos and the level's
    (``u_level / (d beta / d a) * (d ratio / d a)``), and the red excess (the second wavelength's ratio
    less the first's; the two errors taken as independent). Then the family the file's beta ratio
    ``650 / 550`` alone allows: for each traced albedo ``a`` taken at 550 nm, the albedo whose beta is
    the file's ratio times ``beta(a)`` and the excess it gives.

    Parameters
    ----------
    lamb : dict
        The pooled Lambertian runs (:func:`pooled`; bands: :data:`ALBEDOS`).
    file : dict
        The file's summary (:func:`file_ratios`).
    matched : {"normal_view", "ring_6", "ring_30"}
        The beta matched to the file's.
    pair : tuple of (float, float)
        The two wavelengths (nm), of :data:`WAVELENGTHS_NM`.

    Returns
    -------
    dict
        Per incidence: the picks at each wavelength, the excess and its standard error, the file's
        excess and level ratio, and the family. ``None`` where a level lies outside the traced albedos.
    """
    a = np.asarray(ALBEDOS, float)
    out: dict = {}
    wl = list(WAVELENGTHS_NM)
    for ti, curve in lamb["all"].items():
        level = np.asarray(curve[matched])
        u_level = np.asarray(curve[f"u_{matched}"])
        ratio, u_ratio = np.asarray(curve["ratio"]), np.asarray(curve["u_ratio"])
        row: dict = {"matched": matched}
        picks: list[dict | None] = []
        for w in pair:
            target = file[ti][matched][wl.index(w)]
            albedo = _crossing(a, level, target)
            if albedo is None:
                picks.append(None)
                continue
            j = int(np.clip(np.searchsorted(a, albedo) - 1, 0, a.size - 2))
            slope_level = (level[j + 1] - level[j]) / (a[j + 1] - a[j])
            slope_ratio = (ratio[j + 1] - ratio[j]) / (a[j + 1] - a[j])
            u_albedo = _at(a, u_level, albedo) / slope_level
            u = math.hypot(_at(a, u_ratio, albedo), u_albedo * slope_ratio)
            picks.append({"wavelength_nm": w, "file_level": target, "albedo": albedo, "u_albedo": u_albedo,
                          "ratio": _at(a, ratio, albedo), "u_ratio": u, "file_ratio": file[ti]["ratio"][wl.index(w)]})
        row["at"] = picks
        if all(p is not None for p in picks):
            row["excess"] = picks[1]["ratio"] - picks[0]["ratio"]
            row["u_excess"] = math.hypot(picks[0]["u_ratio"], picks[1]["u_ratio"])
        else:
            row["excess"] = row["u_excess"] = None
        row["file_excess"] = file[ti]["ratio"][wl.index(pair[1])] - file[ti]["ratio"][wl.index(pair[0])]
        scale = file[ti][matched][wl.index(pair[1])] / file[ti][matched][wl.index(pair[0])]
        row["file_level_ratio"] = scale
        family = []
        for k, a_first in enumerate(a):
            a_second = _crossing(a, level, scale * level[k])
            family.append({"albedo_first": float(a_first), "albedo_second": a_second,
                           "level_first": float(level[k]),
                           "excess": None if a_second is None else _at(a, ratio, a_second) - float(ratio[k])})
        row["family"] = family
        out[ti] = row
    return out


def multiple_share(lamb: dict) -> dict:
    """Per incidence and albedo: the share of each ring's and the normal view's all-orders beta that is multiple scattering.

    That is ``1 - single / all``, of the pooled runs of :func:`pooled`.

    Parameters
    ----------
    lamb : dict
        The pooled Lambertian runs, with both orders.

    Returns
    -------
    dict
        ``{incidence: {"ring_6" | "ring_30" | "normal_view": [share per albedo]}}``.
    """
    return {ti: {k: (1.0 - np.asarray(lamb["single"][ti][k]) / np.asarray(lamb["all"][ti][k])).tolist()
                 for k in ("ring_6", "ring_30", "normal_view")} for ti in lamb["all"]}


def pooled(runs: list[dict]) -> dict:
    """The runs (seeds) of one variant pooled, per order (those every run holds) and incidence.

    The rings' and the normal view's means over the seeds, the ratio of the pooled rings with its
    standard error from the points' errors (independent), and the standard error of the mean of the
    seeds' own ratios from their scatter.

    Parameters
    ----------
    runs : list of dict
        The variant's runs (:func:`run_variant` or :func:`run_lambertian`).

    Returns
    -------
    dict
        ``{order: {incidence: figures}}``, the figures as JSON lists (the seeds' standard error None
        from one seed).
    """
    out: dict = {}
    n = len(runs)
    for order in [o for o in (*ORDERS, *SPLIT_ORDERS) if all(o in r["orders"] for r in runs)]:
        out[order] = {}
        for ti in runs[0]["orders"][order]["incidences"]:
            per = [r["orders"][order]["incidences"][ti] for r in runs]
            m = {k: np.mean([p[k] for p in per], axis=0) for k in ("ring_6", "ring_30", "normal_view")}
            u = {k: np.sqrt(np.sum([np.square(p[f"u_{k}"]) for p in per], axis=0)) / n
                 for k in ("ring_6", "ring_30", "normal_view")}
            ratio = m["ring_6"] / m["ring_30"]
            u_ratio = ratio * np.hypot(u["ring_6"] / m["ring_6"], u["ring_30"] / m["ring_30"])
            seeds = np.array([p["ratio"] for p in per])
            spread = seeds.std(axis=0, ddof=1) / math.sqrt(n) if n > 1 else np.full(seeds.shape[1], np.nan)
            out[order][ti] = {"ratio": ratio.tolist(), "u_ratio": u_ratio.tolist(),
                              "u_ratio_seeds": [None if math.isnan(x) else float(x) for x in spread],
                              **{k: v.tolist() for k, v in m.items()}, **{f"u_{k}": v.tolist() for k, v in u.items()}}
    return out


def _cpu() -> float:
    """The process's CPU seconds so far (user and system)."""
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def _fail(message: str) -> SystemExit:
    """Print ``message`` as one error line and return the SystemExit (2) to raise."""
    print(f"felt_opposition_scan: {message}", file=sys.stderr)
    return SystemExit(2)


def _write(path: Path, record: dict) -> None:
    """Write ``record`` to ``path`` as JSON, through a temporary file moved into place."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".partial")
    tmp.write_text(json.dumps(record, indent=1) + "\n", encoding="utf-8")
    os.replace(tmp, path)


def _arguments(argv: list[str] | None) -> tuple[argparse.Namespace, list[str]]:
    """The parsed command line and the variants to trace; SystemExit (2) naming a bad option."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", help=f"comma-separated variants (default: all, in order: {', '.join(VARIANTS)})")
    ap.add_argument("--target-rel-err", type=float, default=DEFAULT_TARGET,
                    help=f"each trace's target relative error (default {DEFAULT_TARGET})")
    ap.add_argument("--threads", type=int, default=DEFAULT_THREADS, help=f"threads (default {DEFAULT_THREADS})")
    ap.add_argument("--max-rays", type=int, default=0, help="ray budget per incidence and table half (0: none)")
    ap.add_argument("--seeds", type=int, default=DEFAULT_SEEDS,
                    help=f"runs per variant, each with its own felts, table and rays (default {DEFAULT_SEEDS})")
    ap.add_argument("--out", type=Path, default=DATA / f"{NAME}.json",
                    help="the JSON to write (default docs/data/felt-opposition.json)")
    ap.add_argument("--split", action="store_true",
                    help="also trace the single scattering's two parts, the first fiber's surface reflection and "
                         "the light through it (with --resume: added to the runs that lack them)")
    ap.add_argument("--lambertian", action="store_true",
                    help="also trace the preset's felts with opaque Lambertian fibers of the albedos "
                         f"{', '.join(f'{a:g}' for a in ALBEDOS)} (with --resume: the seeds it lacks)")
    group = ap.add_mutually_exclusive_group()
    group.add_argument("--force", action="store_true", help="replace an existing --out")
    group.add_argument("--resume", action="store_true",
                       help="keep the runs an existing --out holds (same settings) and add the others")
    args = ap.parse_args(argv)
    # --lambertian alone traces the Lambertian felt only; --only names the variants traced with it
    names = ([n.strip() for n in args.only.split(",") if n.strip()] if args.only is not None
             else [] if args.lambertian else list(VARIANTS))
    unknown = [n for n in names if n not in VARIANTS]
    if unknown or (not names and not args.lambertian):
        raise _fail(f"--only: unknown variant(s) {', '.join(unknown) or '(none given)'}; "
                    f"known: {', '.join(VARIANTS)}")
    if not 0.0 < args.target_rel_err < 1.0:
        raise _fail(f"--target-rel-err must lie in (0, 1), got {args.target_rel_err:g}")
    if args.threads < 1 or args.max_rays < 0 or args.seeds < 1:
        raise _fail("--threads and --seeds must be >= 1 and --max-rays >= 0")
    return args, names


def _earlier(args: argparse.Namespace, settings: dict) -> tuple[list[dict], list[str], dict, int]:
    """What ``--out`` already holds: its variants, invocations, Lambertian felt and threads (nothing without it)."""
    done: list[dict] = []
    invocations: list[str] = []
    lamb: dict = {"albedos": list(ALBEDOS), "runs": []}
    # the threads do not change a run's figures (each chunk has its own stream); each run keeps its own count
    threads = args.threads
    if args.out.exists():
        if not (args.force or args.resume):
            raise _fail(f"{args.out} exists; pass --force to replace it or --resume to add the runs it lacks")
        if args.resume:
            try:
                old = json.loads(args.out.read_text(encoding="utf-8"))["data"]
            except (OSError, ValueError, KeyError) as exc:
                raise _fail(f"--resume: {args.out} is not a scan this script wrote ({exc})") from None
            differs = [k for k, v in settings.items() if old.get("settings", {}).get(k) != v]
            if differs:
                raise _fail(f"--resume: {args.out} was run with other settings ({', '.join(differs)}); "
                            "give the same options or --force")
            done, invocations = old["variants"], old.get("invocations", [])
            lamb = old.get("lambertian", lamb)
            if lamb["albedos"] != list(ALBEDOS):
                raise _fail(f"--resume: {args.out} holds a Lambertian felt of other albedos; --force to replace it")
            threads = old["settings"].get("threads", args.threads)
    return done, invocations, lamb, threads


def _canonical(args: argparse.Namespace) -> list[str]:
    """The command that gives this scan's settings, its defaults left out (the record's ``command``)."""
    canonical = [COMMAND]
    if args.target_rel_err != DEFAULT_TARGET:
        canonical.append(f"--target-rel-err {args.target_rel_err:g}")
    if args.max_rays:
        canonical.append(f"--max-rays {args.max_rays}")
    if args.seeds != DEFAULT_SEEDS:
        canonical.append(f"--seeds {args.seeds}")
    if args.out.resolve() != (DATA / f"{NAME}.json").resolve():
        canonical.append(f"--out {shlex.quote(str(args.out))}")
    return canonical


def _save(path: Path, canonical: list[str], data: dict) -> None:
    """Write the scan's record (its command, the machine and ``data``) to ``path``."""
    _write(path, {"name": NAME, "command": " ".join(canonical), "machine": machine(), "data": data})


def _complete(done: list[dict], seeds: int) -> bool:
    """Whether every variant of :data:`VARIANTS` has its ``seeds`` runs."""
    return all(any(v["name"] == n and len(v["runs"]) == seeds for v in done) for n in VARIANTS)


def _trace_variants(seed: int, names: list[str], wanted: tuple[str, ...], felts: dict, base: Any,
                    args: argparse.Namespace, data: dict, canonical: list[str]) -> dict:
    """Trace the orders ``wanted`` that each variant's run at ``seed`` lacks, saving after each; the felts kept."""
    done = data["variants"]
    for name in names:
        variant = next(v for v in done if v["name"] == name)
        run = next((r for r in variant["runs"] if r["seed"] == seed), None)
        missing = tuple(o for o in wanted if run is None or o not in run["orders"])
        if not missing:
            continue
        print(f"felt_opposition_scan: {name} ({VARIANTS[name][0]}), seed {seed}: {', '.join(missing)}", flush=True)
        try:
            new = run_variant(name, base, seed, args.target_rel_err, args.threads, args.max_rays, felts, missing,
                              None if run is None else run["felt"])
        except ValueError as exc:
            raise _fail(f"{name}, seed {seed}: {exc} ({args.out}); trace the variant anew into another --out") from None
        if run is None:
            variant["runs"].append(new)
            variant["runs"].sort(key=lambda r: r["seed"])
        else:
            run["orders"].update(new["orders"])
            run["cpu_seconds"] += new["cpu_seconds"]
            run["wall_seconds"] += new["wall_seconds"]
        variant["pooled"] = pooled(variant["runs"])
        variant["cpu_seconds"] = sum(r["cpu_seconds"] for r in variant["runs"])
        data["complete"] = _complete(done, args.seeds)
        _save(args.out, canonical, data)
        felts = {k: m for k, m in felts.items() if k[0] == base.structure}   # the preset's felts are reused
    return felts


def _trace_lambertian(seed: int, lamb: dict, felts: dict, base: Any, args: argparse.Namespace, data: dict,
                      canonical: list[str]) -> None:
    """Trace the Lambertian felt at ``seed`` when ``lamb`` has no run of it, then pool, read off and save."""
    run = next((r for r in lamb["runs"] if r["seed"] == seed), None)
    if args.lambertian and run is None:
        print(f"felt_opposition_scan: opaque Lambertian fibers, seed {seed}", flush=True)
        lamb["runs"].append(run_lambertian(base, seed, args.target_rel_err, args.threads, args.max_rays, felts))
        lamb["runs"].sort(key=lambda r: r["seed"])
        lamb["pooled"] = pooled(lamb["runs"])
        lamb["cpu_seconds"] = sum(r["cpu_seconds"] for r in lamb["runs"])
        lamb["readoff"] = {m: albedo_readoff(lamb["pooled"], data["file"]["incidences"], m)
                           for m in ("normal_view", "ring_6", "ring_30")}
        lamb["multiple_share"] = multiple_share(lamb["pooled"])
        _save(args.out, canonical, data)


def main(argv: list[str] | None = None) -> int:
    """Trace the variants (and the Lambertian felt) seed by seed, writing the record after every run.

    Parameters
    ----------
    argv : list of str, optional
        Command-line arguments (``--only``, ``--target-rel-err``, ``--threads``, ``--max-rays``,
        ``--seeds``, ``--out``, ``--split``, ``--lambertian``, ``--force`` or ``--resume``);
        ``sys.argv[1:]`` when None.

    Returns
    -------
    int
        0; a bad option, an existing ``--out`` without ``--force`` or ``--resume``, or a resumed run
        whose felts differ exits 2 with one line.
    """
    args, names = _arguments(argv)
    settings = {"config": CONFIG, "target_rel_err": args.target_rel_err, "max_rays": args.max_rays, "seeds": args.seeds,
                "incidences_deg": list(INCIDENCES_DEG), "wavelengths_nm": list(WAVELENGTHS_NM),
                "ring_points": RING_POINTS, "exit_bins": list(EXIT_BINS)}
    done, invocations, lamb, threads = _earlier(args, settings)
    from simulate.config import load_config

    base = load_config(CONFIG)
    invocations.append(shlex.join([*COMMAND.split(), *(sys.argv[1:] if argv is None else argv)]))
    canonical = _canonical(args)
    data: dict[str, Any] = {"settings": {**settings, "threads": threads, "first_seed": base.seed},
            "file": {"sample": str(SAMPLE.relative_to(ROOT)), "incidences": file_ratios()},
            "variants": done, "invocations": invocations}
    if lamb["runs"] or args.lambertian:
        data["lambertian"] = lamb
    order = list(VARIANTS)
    for name in names:
        if not any(v["name"] == name for v in done):
            done.append({"name": name, "label": VARIANTS[name][0], "changes": variant_config(name, base)[1], "runs": []})
    done.sort(key=lambda v: order.index(v["name"]))
    wanted = (*ORDERS, *(SPLIT_ORDERS if args.split else ()))
    for seed in range(base.seed, base.seed + args.seeds):     # every variant at one seed before the next seed
        felts = _trace_variants(seed, names, wanted, {}, base, args, data, canonical)
        _trace_lambertian(seed, lamb, felts, base, args, data, canonical)
    data["complete"] = _complete(done, args.seeds)
    _save(args.out, canonical, data)
    print(f"felt_opposition_scan: {len(done)} variant(s) in {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
