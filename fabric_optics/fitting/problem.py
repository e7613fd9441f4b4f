"""The model evaluator of ``simulate fit``: the model at the measured geometries and the objective's residuals.

:class:`FitProblem` evaluates a :class:`~fabric_optics.fitting.spec.FitSpec`: the classic model, the top cell's
summation or the structured summation (:mod:`simulate.structwalk`), for any value of the free parameters, and the
residual vector of the objective (``NRMSE^2 + w_c (dh^2 + ds^2)`` and the colour hold, computed by
:class:`compare.residual.ModelResidual`). It owns the caches that make an evaluation cheap: the dye is read from an
absorption table, scattering parameters are walked at the points of a geometric lattice and re-weighted (top cell)
or blended (structured) between them, the surface term is analytic. :class:`Counters` count its work apart.

Why these choices and what they cost: docs/notes/fit-trust.md ("How the objective is evaluated").
"""

from __future__ import annotations

import copy
import dataclasses
import hashlib
import json
import logging
import math
import tomllib
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from compare import ModelResidual
from compare.comparison import compare_datasets
from compare.errors import CompareError
from fabric_optics import paths
from fabric_optics.fitting.errors import FitError
from fabric_optics.fitting.spec import (
    COLOUR_HOLD_FROM,
    COLOUR_HOLD_WEIGHT,
    DEPTH_FIELDS,
    GENERATOR,
    FitSpec,
    FreeParameter,
    colour_hold,
    dye_ceiling,
    make_spec,
    model_geometries,
    shares_at,
)
from fabric_optics.fitting.state import WalkCheckpoint
from fabric_optics.paths import toml_dumps
from gonio.data.dataset import COLUMNS, Dataset, make_dataset, new_meta
from simulate import fabric as fab
from simulate import fiber as fib
from simulate.config import SimulationConfig, parse_config
from simulate.config_dye import dye_from_table
from simulate.config_table import Table
from simulate.fabric.surfacesum import SurfaceSum
from simulate.fiber.absorption import AbsorptionTable, absorption_nodes, absorption_table
from simulate.fiber.spectral import reweight_exponent, spectral_optics
from simulate.media.medium import HGMedium
from simulate.products import smooth_boundary_unless_mc
from simulate.structwalk import walk as structwalk

__all__ = ["FitProblem", "Counters", "mixed_model", "REWEIGHT_LIMIT", "LATTICE_STEP", "STRUCTURED_LATTICE_STEP",
           "SURFACE_LATTICE_STEP"]

log = logging.getLogger(__name__)

#: How much larger ``ln E[w^2]`` (:func:`simulate.fiber.spectral.reweight_exponent`) of a re-weighted evaluation may
#: be than the reference walk's own: ``ln 4``, the standard error at most doubled by the bound.
REWEIGHT_LIMIT = math.log(4.0)
#: Step of the geometric lattice of reference walks (:meth:`FitProblem.lattice`): a point is at most 5 % from its
#: reference.
LATTICE_STEP = 0.10
#: Step of the structured summation's lattice of walks (:meth:`FitProblem.lattice_corners`): its walks are blended
#: (linear in ``log v``), not re-weighted, so the step is not bounded by the re-weighting's variance.
STRUCTURED_LATTICE_STEP = 0.20
#: Step of the structured summation's lattice of surface terms in ``log rms_slope`` (:meth:`FitProblem.surface_term`):
#: the exact term at the lattice points, blended linearly between them.
SURFACE_LATTICE_STEP = 0.02
#: Surface terms :meth:`FitProblem.surface_term` keeps, by RMS slope (lattice points; ``[N]`` each): a search's
#: steps and Jacobian columns return to the points around its slope, and a fit reaches a few dozen of them.
SURFACE_MEMO = 256
#: Parsed configs :meth:`FitProblem.config_at` keeps, by the values of the free parameters other than the dye: the
#: centre and a Jacobian's columns of the others (a dye-only point reads its config from them).
PARSED_CONFIGS = 8


@dataclass
class Counters:
    """What the evaluator did, counted apart from what it evaluates (fit.json ``info``)."""

    evaluations: int = 0
    walks: int = 0
    walk_seconds: float = 0.0
    reweights: int = 0
    reweight_seconds: float = 0.0
    #: structured walks and re-weighted passes read whole from the disk cache (also in ``walks``/``reweights``)
    cached_walks: int = 0


class FitProblem:
    """The model evaluator of a :class:`~fabric_optics.fitting.spec.FitSpec`.

    The model at the measured geometries for any value of the free parameters, the objective's residuals, and the
    caches that make both cheap.

    Built from the spec's arguments (:func:`~fabric_optics.fitting.spec.make_spec`); the spec's fields are read-only
    attributes. It owns its caches (walks, re-weighted tables, parsed configs, facets, surface terms), the photons
    of its first walk, its walk checkpoint and its :class:`Counters`; a runner changes them only through
    :meth:`use_checkpoint`, :meth:`use_photons`, :meth:`use_walk_progress` and :meth:`share_walks`.
    """

    def __init__(self, config: SimulationConfig, measured: Dataset, free: list[FreeParameter],
                 **settings: Any) -> None:
        #: what is fitted (:func:`~fabric_optics.fitting.spec.make_spec` of these arguments; ``settings``: its
        #: keyword arguments ``method``, ``colour_weight``, ``hold_colour``, ``level_weight``, ``target_rel_err``,
        #: ``seed``, ``threads``, ``wavelengths_nm``, ``nodes``, ``reweight``, ``fine_capable``)
        self.spec: FitSpec = make_spec(config, measured, free, **settings)
        self.counters = Counters()
        self._photons: dict | None = None
        self._out: Path | None = None
        self._walk_progress: Callable[[int, int, int], None] | None = None
        #: ``(bound of the last re-weighting considered, the reference walk's own)`` (diagnostics)
        self.last_exponent: tuple = (0.0, 0.0)
        self._references: dict = {}
        self._tables: dict = {}
        self._parsed: dict = {}
        self._doc = tomllib.loads(self.spec.config.text)
        self._facets: dict = {}
        self._surfaces: dict = {}
        self._surface_sums: dict = {}
        # the structured walk's interior closure: its surface share at the starting RMS slope (simulate.structwalk)
        self._roughness = float(self.spec.config.rms_slope)
        self.geometries = model_geometries(self.spec.measured)
        self._residual: Any = None  # compare.residual.ModelResidual, built on first use
        g = self.geometries
        self.w_i = fab.directions_deg(g["theta_i"].to_numpy(), g["phi_i"].to_numpy())
        self.w_o = fab.directions_deg(g["theta_o"].to_numpy(), g["phi_o"].to_numpy())
        if self.spec.method == "summation":
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                self.pairs = fab.FiberPairs.from_angles(g["theta_i"], g["phi_i"], g["theta_o"], g["phi_o"])
        self.nu_max = dye_ceiling(self.spec.config, list(self.spec.free), self.spec.wavelengths_nm)
        self._low = _frozen([p.low for p in self.spec.free])
        self._high = _frozen([p.high for p in self.spec.free])
        self._start = _frozen([p.start for p in self.spec.free])

    # -- the spec, read-only ---------------------------------------------------------------

    config = property(lambda self: self.spec.config)
    measured = property(lambda self: self.spec.measured)
    free = property(lambda self: list(self.spec.free))
    method = property(lambda self: self.spec.method)
    colour_weight = property(lambda self: self.spec.colour_weight)
    hold_colour = property(lambda self: self.spec.hold_colour)
    level_weight = property(lambda self: self.spec.level_weight)
    target_rel_err = property(lambda self: self.spec.target_rel_err)
    seed = property(lambda self: self.spec.seed)
    threads = property(lambda self: self.spec.threads)
    wavelengths_nm = property(lambda self: self.spec.wavelengths_nm)
    nodes = property(lambda self: self.spec.nodes)
    reweight = property(lambda self: self.spec.reweight)
    fine_capable = property(lambda self: self.spec.fine_capable)
    notes = property(lambda self: list(self.spec.notes))
    structured = property(lambda self: self.spec.structured)
    low = property(lambda self: self._low)
    high = property(lambda self: self._high)
    start = property(lambda self: self._start)

    @property
    def photons(self) -> dict | None:
        """The photons per run of the first walk (later walks reuse them: common random numbers)."""
        return self._photons

    # -- what a runner sets --------------------------------------------------------------------

    def use_checkpoint(self, out: Path | None) -> None:
        """Checkpoint every finished Monte Carlo run in ``out/walks/`` (None: none).

        Parameters
        ----------
        out : Path or None
            The fit's ``--out`` folder, or None for no checkpoint.
        """
        self._out = None if out is None else Path(out)

    def use_photons(self, photons: dict | None) -> None:
        """The photons of a resumed fit's first walk (its state file), so its walks are the interrupted one's.

        Parameters
        ----------
        photons : dict or None
            Run key -> photons (the state file's ``photons``), or None for a fresh fit.
        """
        self._photons = None if photons is None else dict(photons)

    def use_walk_progress(self, progress: Callable[[int, int, int], None] | None) -> None:
        """``progress(photons, run, runs)`` during walks (None: silent).

        Parameters
        ----------
        progress : callable or None
            Called with the photons walked so far, the run's number and the number of runs.
        """
        self._walk_progress = progress

    def share_walks(self, other: FitProblem) -> None:
        """Read the walks ``other`` made (same config and walked parameters) instead of walking them again.

        Parameters
        ----------
        other : FitProblem
            The problem whose walks (tables, reference points and photons) are shared.
        """
        self._tables, self._references, self._photons = other._tables, other._references, other._photons

    # -- parameters and configs ------------------------------------------------------------

    def config_at(self, x: np.ndarray) -> SimulationConfig:
        """The config with the free fields set to ``x`` (validated by the config parser).

        The whole config is parsed once per value of the parameters other than the dye (the last
        :data:`PARSED_CONFIGS`); a point that differs from one of those in the dye alone gets that config with
        its dye table parsed (:func:`simulate.config_dye.dye_from_table`, the parser's own) and the text and
        SHA-256 of the whole: field by field the config a full parse gives (a dye-only search step or Jacobian
        column re-parsed the whole config, a quarter of an evaluation).

        Parameters
        ----------
        x : numpy.ndarray
            One value per free parameter, in its physical units.

        Returns
        -------
        SimulationConfig
            The config at ``x``.
        """
        doc = self._doc_at(x)
        text = toml_dumps(doc)
        file = f"{self.config.name}.toml"
        key = tuple(float(v) for p, v in zip(self.free, x, strict=True) if p.kind not in ("dye", "share"))
        base = self._parsed.get(key)
        if base is None:
            config = parse_config(text, file, source=f"fit of {self.config.source}")
            if len(self._parsed) >= PARSED_CONFIGS:
                self._parsed.pop(next(iter(self._parsed)))
            self._parsed[key] = config
            return config
        raw = text.encode("utf-8", errors="surrogatepass")   # as parse_config reads a text
        dye_t = doc["fiber"].get("dye")
        dye = None if dye_t is None else dye_from_table(Table(dye_t, "fiber.dye", file))
        populations = base.populations
        if populations:      # each population's own dye (or the config's) and its share, as the parser sets them
            populations = tuple(
                dataclasses.replace(
                    pop, share=float(item["share"]),
                    dye=(dye if pop.dye is base.dye else
                         dye_from_table(Table(item["fiber"]["dye"], f"populations[{k}].fiber.dye", file))))
                for k, (pop, item) in enumerate(zip(populations, doc["populations"], strict=True)))
        return dataclasses.replace(base, text=raw.decode("utf-8"), sha256=hashlib.sha256(raw).hexdigest(),
                                   dye=dye, populations=populations)

    def _doc_at(self, x: np.ndarray) -> dict:
        """The config document with the free fields set to ``x``.

        A blend's shares that are not free take the remainder (:func:`~fabric_optics.fitting.spec.shares_at`).
        """
        doc = copy.deepcopy(self._doc)
        for p, v in zip(self.free, x, strict=True):
            paths.set_value(doc, p.name, float(v))
        for k, share in shares_at(self.config, self.spec.free, x).items():
            doc["populations"][k]["share"] = share
        return doc

    def fitted_toml(self, x: np.ndarray, note: str) -> str:
        """TOML text of the fitted config (comments of the original are not kept).

        Parameters
        ----------
        x : numpy.ndarray
            One value per free parameter, in its physical units.
        note : str
            Text written as comment lines at the top.

        Returns
        -------
        str
            The TOML text, its ``name`` the start config's with ``-fitted``.
        """
        doc = self._doc_at(x)
        doc["name"] = f"{self.config.name}-fitted"
        return toml_dumps(doc, header="\n".join("# " + line for line in note.splitlines()))

    # -- the model ----------------------------------------------------------------------------

    def table(self, config: SimulationConfig) -> AbsorptionTable:
        """The absorption table of ``config``'s scattering.

        Walked, or re-weighted from the walk at its lattice point (:meth:`lattice`), whichever the module
        docstring's rule says; memoised.

        Parameters
        ----------
        config : SimulationConfig
            The config (its scattering parameters select the walk).

        Returns
        -------
        AbsorptionTable
            The table: the volume term at any host absorption.
        """
        if self.structured:
            return self._structured_table(config)
        return self._walk_table(config)

    def _structured_table(self, config: SimulationConfig) -> AbsorptionTable:
        """The structured summation's table of ``config``.

        Its walk's, or -- a walked parameter between two lattice points -- the interpolation of the walks at the
        lattice points around it (:meth:`lattice_corners`).
        """
        key = structwalk.structure_key(config)
        facets = self._facets_of(config)
        corners = self.lattice_corners(self._walk_values(config))
        if len(corners) == 1 and corners[0][0] == self._walk_values(config):
            return self._walk_table(config).table(key, facets, self.w_i, self.w_o, self.wavelengths_nm)
        parts = [(w, self._lattice_walk(config, point).table(key, facets, self.w_i, self.w_o, self.wavelengths_nm))
                 for point, w in corners]
        first = parts[0][1]
        R = sum(w * t.R for w, t in parts)
        u = sum(w * t.u_R for w, t in parts)        # the correlated bound (the walks share their streams)
        return AbsorptionTable(R=R, u_R=u, nodes=first.nodes, wavelengths_nm=first.wavelengths_nm,
                               photons=first.photons, seconds=first.seconds, scatterings=first.scatterings,
                               groups=first.groups, optics=None)

    def lattice_corners(self, walk: tuple) -> list[tuple[tuple, float]]:
        """The lattice points around the walked values ``walk`` and their multilinear weights in ``log v``.

        The lattice is ``start * exp(STRUCTURED_LATTICE_STEP k)`` per walked parameter; the result is
        ``[(point, weight)]`` (one point, weight 1, on the lattice; 2^d around it). Values that are not
        positive, or whose start is not, are kept as they are.

        The structured summation's walked parameters are read this way instead of re-weighting the walk at the
        nearest lattice point (:meth:`lattice`): a re-weighted pass walks the same paths again to score them
        and costs about what a walk costs (docs/notes/fit-trust.md, "Monte Carlo noise"), so the walks at
        the lattice points are all that is walked (each in the disk cache: a refit walks nothing). The
        objective is then continuous across lattice cells (the jumps between the walks at 10 % target,
        docs/physics.md 6.5, become a linear blend).

        Parameters
        ----------
        walk : tuple
            The walked parameters' values, in the order of the free parameters.

        Returns
        -------
        list of (tuple, float)
            Each lattice point around ``walk`` and its weight (the weights sum to 1).
        """
        starts = [p.start for p in self.free if p.kind == "walk"]
        axes: list[list[tuple[float, float]]] = []
        step = STRUCTURED_LATTICE_STEP
        for s, v in zip(starts, walk, strict=True):
            if s > 0 and v > 0:
                x = math.log(v / s) / step
                k = math.floor(x + 1e-9)
                f = x - k
                lo = round(s * math.exp(step * k), 12)
                if f < 1e-9:
                    axes.append([(lo, 1.0)])
                else:
                    axes.append([(lo, 1.0 - f), (round(s * math.exp(step * (k + 1)), 12), f)])
            else:
                axes.append([(v, 1.0)])
        corners: list[tuple[tuple, float]] = [((), 1.0)]
        for axis in axes:
            corners = [(point + (v,), w * wv) for point, w in corners for v, wv in axis]
        return corners

    def _lattice_walk(self, config: SimulationConfig, point: tuple) -> Any:
        """The structured walk at the lattice point ``point`` of the walked parameters (walked once, memoised)."""
        if point in self._tables:
            return self._tables[point]
        doc = self._doc_of(config)
        for p, v in zip([p for p in self.free if p.kind == "walk"], point, strict=True):
            paths.set_value(doc, p.name, v)
        at = parse_config(toml_dumps(doc), "lattice.toml")
        nodye = at.undyed().fiber(self.wavelengths_nm)
        walk = self._run(nodye, point, None, at)
        self._references[point] = (nodye, walk)
        if len(self._tables) >= 6:  # the 2^d corners of a step and of a Jacobian's columns
            self._tables.pop(next(iter(self._tables)))
        self._tables[point] = walk
        return walk

    def _facets_of(self, config: SimulationConfig) -> Any:
        key = structwalk.structure_key(config)
        if key not in self._facets:
            if len(self._facets) >= 8:
                self._facets.pop(next(iter(self._facets)))
            self._facets[key] = structwalk.facets_of(config)
        return self._facets[key]

    def _walk_table(self, config: SimulationConfig) -> Any:
        """The walk of ``config``'s scattering (an absorption table, or the structured layer tables)."""
        walk = self._walk_values(config)
        if walk in self._tables:
            return self._tables[walk]
        wl = self.wavelengths_nm
        nodye = config.undyed().fiber(wl)
        lattice = self.lattice(walk)
        table = None
        if self.reweight and lattice != walk:
            ref = self._references.get(lattice)
            if ref is None:
                doc = self._doc_of(config)
                for p, v in zip([p for p in self.free if p.kind == "walk"], lattice, strict=True):
                    paths.set_value(doc, p.name, v)
                ref_fiber = parse_config(toml_dumps(doc), "lattice.toml").undyed().fiber(wl)
                ref = (ref_fiber, self._run(ref_fiber, lattice, None, config))
                self._references[lattice] = ref
            if self._within_bound(ref[1], nodye, wl):
                table = self._run(nodye, walk + ("reweighted from",) + lattice, ref, config)
        if table is None:
            table = self._run(nodye, walk, None, config)
            self._references[walk] = (nodye, table)
        if len(self._tables) >= 4:  # the centre and a Jacobian's columns
            self._tables.pop(next(iter(self._tables)))
        self._tables[walk] = table
        return table

    def _walk_values(self, config: SimulationConfig) -> tuple:
        return tuple(round(float(paths.get(self._doc_of(config), p.name)), 12) for p in self.free if p.kind == "walk")

    def lattice(self, walk: tuple) -> tuple:
        """The reference point of walked values ``walk``.

        Each positive value rounded to the geometric lattice ``start * exp(LATTICE_STEP * k)`` (others kept).
        Evaluating every point from the walk at its lattice point makes the objective a deterministic function
        of the parameters (not of the order in which the search visited them: a resumed fit sees the same
        values). A depth (a dye's or the scatterers') is kept: a walk is re-weighted to other scattering, not to
        another dyed region or another placement of its scatterers (:mod:`simulate.fiber.absorption`).

        Parameters
        ----------
        walk : tuple
            The walked parameters' values, in the order of the free parameters.

        Returns
        -------
        tuple
            The lattice point.
        """
        walked = [p for p in self.free if p.kind == "walk"]
        out: list[float] = []
        for s, v in zip([p.start for p in walked], walk, strict=True):
            if s > 0 and v > 0 and not walked[len(out)].name.endswith(DEPTH_FIELDS):
                k = round(math.log(v / s) / LATTICE_STEP)
                out.append(round(s * math.exp(LATTICE_STEP * k), 12))
            else:
                out.append(v)
        return tuple(out)

    def _run(self, nodye: Any, key: tuple, ref: tuple | None, config: SimulationConfig | None = None) -> Any:
        """A fresh walk of ``nodye`` (``ref`` None) or the re-weighting of ``ref = (fiber, table)``."""
        # the summation's and classic model's routes walk the smooth boundary (simulate.products)
        nodye = smooth_boundary_unless_mc(self.method, nodye, quiet=self.fine_capable)
        if ref is not None:
            ref = (smooth_boundary_unless_mc(self.method, ref[0], quiet=self.fine_capable), ref[1])
        wl = self.wavelengths_nm
        if self.structured:
            return self._run_structured(nodye, ref, config or self.config)
        if self.method == "classic":
            w_in = np.array([[0.0, 0.0, 1.0]])
            outputs = fib.range_outputs([0.0], [1.0], [-math.pi], [math.pi], nodye.half_width)
            route = "beam"
        else:
            w_in = self.pairs.w_in
            outputs = fib.point_outputs(self.pairs.w_out, nodye.half_width)
            route = self.config.route
        nodes = absorption_nodes(self.nu_max, self.nodes)
        cache = None
        if self._out is not None:
            cache = WalkCheckpoint(self._out, self.identity(), key, nodes, self._photons)
        table = absorption_table(nodye, w_in, outputs, wl, nodes, method=route, target_rel_err=self.target_rel_err,
                                 photons=self._photons if ref is None else ref[1].photons, seed=int(self.seed or 0),
                                 threads=self.threads, progress=self._walk_progress, cache=cache,
                                 reference=None if ref is None else ref[0])
        if cache is not None and cache.found:
            log.info("%d Monte Carlo runs read from the checkpoint %s", cache.found, cache.dir)
        if ref is not None:
            self.counters.reweights += 1
            self.counters.reweight_seconds += table.seconds
            return table
        if self._photons is None:
            self._photons = dict(table.photons)
        self.counters.walks += 1
        self.counters.walk_seconds += table.seconds
        if len(self._references) >= 8:
            self._references.pop(next(iter(self._references)))
        return table

    def _run_structured(self, nodye: Any, ref: tuple | None, config: SimulationConfig) -> Any:
        """The structured walk (:func:`simulate.structwalk.walk.walk_structure`); not checkpointed per run."""
        rough = dataclasses.replace(nodye, roughness=self._roughness)
        reference = None if ref is None else dataclasses.replace(ref[0], roughness=self._roughness)
        walk = structwalk.walk_structure(rough, config, structwalk.walk_wavelengths(self.wavelengths_nm),
                              absorption_nodes(self.nu_max, self.nodes),
                              target_rel_err=self.target_rel_err, seed=int(self.seed or 0), threads=self.threads,
                              reference=reference, progress=self._walk_progress)
        if walk.cache == "hit":
            self.counters.cached_walks += 1
        if ref is not None:
            self.counters.reweights += 1
            self.counters.reweight_seconds += walk.seconds
            return walk
        if self._photons is None:
            self._photons = dict(walk.photons)
        self.counters.walks += 1
        self.counters.walk_seconds += walk.seconds
        if len(self._references) >= 8:
            self._references.pop(next(iter(self._references)))
        return walk

    def _within_bound(self, ref_table: Any, nodye: Any, wl: np.ndarray) -> bool:
        """Whether ``ref_table``'s paths can be re-weighted to ``nodye``'s scattering.

        They can when the bound of :func:`simulate.fiber.spectral.reweight_exponent` grows by at most
        :data:`REWEIGHT_LIMIT` over the walk's own wavelength groups.
        """
        n = ref_table.group_scatterings()
        own = reweight_exponent(ref_table.optics, ref_table.optics, ref_table.groups, n)
        # the walk's wavelengths (a structured walk may have fewer than the model: fit_structure.walk_wavelengths)
        target = reweight_exponent(ref_table.optics, spectral_optics(nodye, ref_table.wavelengths_nm), ref_table.groups,
                                   n)
        self.last_exponent = (target, own)
        if target - own > REWEIGHT_LIMIT:
            log.info("scattering too far from the lattice walk (bound %.3g > %.3g + %.3g): walked itself",
                     target, own, REWEIGHT_LIMIT)
            return False
        return True

    def _doc_of(self, config: SimulationConfig) -> dict:
        return tomllib.loads(config.text)

    def model(self, x: np.ndarray, mc_noise: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """``beta, u_beta`` ``[G, L]`` of the model at the model geometries for parameters ``x``.

        ``mc_noise`` (``[P, L]`` standard normal draws) shifts the volume term by that many
        standard errors (the uncertainty propagation of the Monte Carlo error).

        Parameters
        ----------
        x : numpy.ndarray
            One value per free parameter, in its physical units.
        mc_noise : numpy.ndarray, optional
            Standard normal draws, one per value of the absorption table; None: no shift.

        Returns
        -------
        beta, u_beta : numpy.ndarray
            The radiance coefficients and their standard uncertainties (geometries x wavelengths).
        """
        return mixed_model(self.config_at(x), self.wavelengths_nm, self.model_at_host, mc_noise)

    def model_at_host(self, config: SimulationConfig, mu_host: np.ndarray,
                      mc_noise: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """``beta, u_beta`` ``[G, L]`` of ``config``'s fiber with the host absorption ``mu_host[L]`` (1/um).

        The host absorption stands in place of the dye; the values are read from the absorption table
        (no walk once the table exists).

        Parameters
        ----------
        config : SimulationConfig
            The config of one fiber (one population).
        mu_host : numpy.ndarray
            The host absorption coefficient at each wavelength (1/um).
        mc_noise : numpy.ndarray, optional
            Standard normal draws, one per value of the absorption table; None: no shift.

        Returns
        -------
        beta, u_beta : numpy.ndarray
            The radiance coefficients and their standard uncertainties (geometries x wavelengths).
        """
        table = self.table(config)
        R, u = table(mu_host)
        if mc_noise is not None:
            R = R + u * mc_noise
        with warnings.catch_warnings():
            # the domain warnings (RMS slope > 0.5, grazing) are the config's business, not once per evaluation
            warnings.simplefilter("ignore")
            return self._surface(config, R, u)

    def _surface(self, config: SimulationConfig, R: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        if self.structured:
            return R + self.surface_term(config)[:, None], u
        if self.method == "classic":
            rho = R[0] * math.pi
            beta = fab.classic_beta(rho, self.w_i, self.w_o, config.rms_slope, config.n_host)
            u_beta = np.broadcast_to(u[0] * math.pi, beta.shape).copy()
        else:
            surface_fiber = fib.Fiber(config.radius_um, config.n_host, HGMedium(mu_s=0.0, mu_a=0.0, g=0.0),
                                      config.rms_slope, config.cell_width_deg)
            r_surf = np.asarray(fib.surface_brdf(surface_fiber, self.pairs.w_in, self.pairs.w_out), float)
            beta, u_beta = fab.summation_from_table(self.pairs, R + r_surf[:, None], u)
        return beta, u_beta

    def surface_term(self, config: SimulationConfig) -> np.ndarray:
        """The structured summation's surface ``beta [N]`` at ``config``'s RMS slope.

        The exact term (:func:`simulate.structwalk.walk.surface_beta`) at the points of the lattice ``r0
        exp(SURFACE_LATTICE_STEP k)`` (``r0`` the start config's RMS slope), blended linearly in ``log
        rms_slope`` between the two around it (:data:`SURFACE_LATTICE_STEP`); each lattice point computed once
        per structure (memoised). A positive RMS slope on the lattice (the start's, a fit that does not free it)
        is the exact term.

        Parameters
        ----------
        config : SimulationConfig
            The config (its ``rms_slope``).

        Returns
        -------
        numpy.ndarray
            The surface term's radiance coefficient at each of the ``N`` model geometries.
        """
        r, r0 = float(config.rms_slope), float(self.config.rms_slope)
        if r <= 0.0 or r0 <= 0.0:
            return self._surface_at(config, r)
        x = math.log(r / r0) / SURFACE_LATTICE_STEP
        k = math.floor(x + 1e-9)
        f = x - k
        lo = self._surface_at(config, round(r0 * math.exp(SURFACE_LATTICE_STEP * k), 12))
        if f < 1e-9:
            return lo
        hi = self._surface_at(config, round(r0 * math.exp(SURFACE_LATTICE_STEP * (k + 1)), 12))
        return (1.0 - f) * lo + f * hi

    def _surface_at(self, config: SimulationConfig, rms_slope: float) -> np.ndarray:
        """The exact surface ``beta [N]`` of ``config``'s structure at ``rms_slope`` (the last :data:`SURFACE_MEMO` kept).

        :func:`simulate.structwalk.walk.surface_beta`'s value, bit for bit, from the structure's
        :class:`simulate.fabric.surfacesum.SurfaceSum` (what does not depend on the slope, formed once per
        structure and host index: :meth:`_surface_sum_of`).
        """
        key = (structwalk.structure_key(config), rms_slope, float(config.n_host))
        if key not in self._surfaces:
            if len(self._surfaces) >= SURFACE_MEMO:
                self._surfaces.pop(next(iter(self._surfaces)))
            self._surfaces[key] = self._surface_sum_of(config).beta(rms_slope)
        return self._surfaces[key]

    def _surface_sum_of(self, config: SimulationConfig) -> SurfaceSum:
        """The :class:`~simulate.fabric.surfacesum.SurfaceSum` of ``config``'s structure and host index.

        At the model geometries; the last 4 are kept (a free structure field's centre and Jacobian columns).
        """
        key = (structwalk.structure_key(config), float(config.n_host))
        if key not in self._surface_sums:
            if len(self._surface_sums) >= 4:
                self._surface_sums.pop(next(iter(self._surface_sums)))
            self._surface_sums[key] = SurfaceSum(self._facets_of(config), self.w_i, self.w_o, float(config.n_host),
                                                 config.structure.spacing_ratio)
        return self._surface_sums[key]

    def dataset(self, beta: np.ndarray, u_beta: np.ndarray, label: str, extra: dict | None = None,
                method: str | None = None) -> Dataset:
        """The model values as a ``"simulated"`` dataset at the model geometries.

        The dataset is labelled ``method``: the spec's model unless given.

        Parameters
        ----------
        beta, u_beta : numpy.ndarray
            The model's radiance coefficients and their standard uncertainties (geometries x wavelengths).
        label : str
            What the values are (e.g. "fitted"), in the sample's and model's names.
        extra : dict, optional
            Further meta.json fields.
        method : str, optional
            The model's method (default: the spec's).

        Returns
        -------
        Dataset
            The dataset, in memory (not written).
        """
        method = method or self.method
        g = self.geometries
        wl = self.wavelengths_nm
        rep = g.loc[g.index.repeat(wl.size)].reset_index(drop=True)
        table = pd.DataFrame({"theta_i": rep["theta_i"], "phi_i": rep["phi_i"], "theta_o": rep["theta_o"],
                              "phi_o": rep["phi_o"], "wavelength_nm": np.tile(wl, len(g)),
                              "beta": np.asarray(beta).ravel(), "u_beta": np.asarray(u_beta).ravel(),
                              "n": np.ones(beta.size, dtype=np.int64)}, columns=list(COLUMNS))
        sample = dict(self.measured.meta.get("sample") or {})
        sample["name"] = f"{method} model ({label})"
        model = {"generator": GENERATOR, "name": f"fabric {method} ({label})", "method": method,
                 "config": self.config.name}
        return make_dataset(table, new_meta("simulated", sample, model, extra or {}))

    # -- the objective ----------------------------------------------------------------------

    def compare(self, sim: Dataset, measured: Dataset | None = None):
        """:func:`compare.comparison.compare_datasets` of the measurement and ``sim``.

        Parameters
        ----------
        sim : Dataset
            The model's dataset (:meth:`dataset`).
        measured : Dataset, optional
            The measurement (default: the fit's).

        Returns
        -------
        Comparison
            The comparison.
        """
        logging.getLogger("compare").setLevel(logging.ERROR)  # per-evaluation chatter
        return compare_datasets(self.measured if measured is None else measured, [sim])

    def residuals_of(self, comparison) -> np.ndarray:
        """The residual vector of the module docstring from a comparison of one simulation.

        Parameters
        ----------
        comparison : Comparison
            A comparison of one simulation (:meth:`compare`).

        Returns
        -------
        numpy.ndarray
            The curve residuals over ``mean(beta_meas) sqrt(n)``, then the weighted hue and saturation
            differences when the measurement has a colour.
        """
        name = next(iter(comparison.frames))
        frame = comparison.frames[name]
        meas = frame["beta_meas"].to_numpy(float)
        d = frame["beta_sim"].to_numpy(float) - meas
        parts = [d / (float(np.mean(meas)) * math.sqrt(d.size))]
        if comparison.colour is not None:
            c = comparison.colour.simulated[name]
            parts.append(math.sqrt(self.colour_weight) * np.array([c.dh, c.ds]))
        return np.concatenate(parts)

    def residual_model(self, measured: Dataset | None = None):
        """The :class:`compare.residual.ModelResidual` of the measurement, prepared once.

        Of the measurement or of a noise draw of it with the same rows; per evaluation only the model
        side is computed.

        Parameters
        ----------
        measured : Dataset, optional
            A noise draw of the measurement with its rows (default: the measurement itself).

        Returns
        -------
        ModelResidual
            The prepared residual.

        Raises
        ------
        CompareError
            When ``measured`` has other rows than the measurement.
        """
        if self._residual is None:
            self._residual = ModelResidual(self.measured, self.geometries, self.wavelengths_nm,
                                           name=f"{self.method} model")
        if measured is None or measured is self.measured:
            return self._residual
        return self._residual.with_measured(measured)

    def residuals(self, x: np.ndarray, measured: Dataset | None = None,
                  mc_noise: np.ndarray | None = None) -> np.ndarray:
        """Residuals at parameters ``x`` (physical units).

        ``compare``'s figures through :meth:`residual_model` (equal to :meth:`residuals_of` of :meth:`compare`
        to 1e-12, tested in compare).

        Parameters
        ----------
        x : numpy.ndarray
            One value per free parameter, in its physical units.
        measured : Dataset, optional
            A noise draw of the measurement with its rows (default: the measurement itself).
        mc_noise : numpy.ndarray, optional
            Standard normal draws, one per value of the absorption table; None: no shift.

        Returns
        -------
        numpy.ndarray
            The residual vector (:meth:`residuals_of_model`).
        """
        beta, u = self.model(x, mc_noise)
        return self.residuals_of_model(beta, u, measured)

    def residuals_of_model(self, beta: np.ndarray, u: np.ndarray, measured: Dataset | None = None,
                           colour_weight: float | None = None) -> np.ndarray:
        """The residual vector of model values ``beta, u`` ``[G, L]`` (one evaluation counted).

        ``colour_weight`` in place of the spec's (a surrogate fit that raises it,
        :mod:`fabric_optics.fitting.spacemapping`).

        Parameters
        ----------
        beta, u : numpy.ndarray
            The model's radiance coefficients and their standard uncertainties (geometries x wavelengths).
        measured : Dataset, optional
            A noise draw of the measurement with its rows (default: the measurement itself).
        colour_weight : float, optional
            The weight of the colour terms (default: the spec's).

        Returns
        -------
        numpy.ndarray
            :meth:`compare.residual.ResidualFigures.vector`, then the colour hold's terms when the
            objective holds the colour.
        """
        w = self.colour_weight if colour_weight is None else colour_weight
        self.counters.evaluations += 1
        fig = self.residual_model(measured).evaluate(beta, u)
        r = fig.vector(w, self.level_weight)
        if self.holds_colour(w):
            r = np.concatenate([r, colour_hold(float(fig.dh), float(fig.ds))])
        return r

    def holds_colour(self, colour_weight: float | None = None) -> bool:
        """Whether the objective holds the colour within the tolerance (:func:`colour_hold`).

        Asked for, the measurement has a colour and the colour terms carry weight.

        Parameters
        ----------
        colour_weight : float, optional
            The weight of the colour terms (default: the spec's).

        Returns
        -------
        bool
            Whether the colour hold's terms are in the residual vector.
        """
        w = self.colour_weight if colour_weight is None else colour_weight
        return self.hold_colour and w > 0 and bool(self.residual_model().has_colour)

    def precheck(self) -> None:
        """Everything the objective needs from the measurement, before any photon (FitError)."""
        flat = np.full((len(self.geometries), self.wavelengths_nm.size), 0.5)
        try:
            self.compare(self.dataset(flat, 0.0 * flat, "check"))
        except CompareError as exc:
            raise FitError(f"the measurement cannot be fitted: {exc}") from None

    def identity(self) -> str:
        """Hash of what a resumed fit must share with the interrupted one."""
        doc = {"config": self.config.sha256, "measured": self.measured.meta.get("files", {}),
               "rows": len(self.measured), "method": self.method,
               "free": [[p.name, p.low, p.high] for p in self.free], "seed": self.seed,
               "wavelengths": self.wavelengths_nm.tolist(), "colour_weight": self.colour_weight}
        if self.holds_colour():
            doc["colour_hold"] = [COLOUR_HOLD_FROM, COLOUR_HOLD_WEIGHT]
        if self.level_weight:
            doc["level_weight"] = self.level_weight
        return hashlib.sha256(json.dumps(doc, sort_keys=True, default=str).encode()).hexdigest()


def mixed_model(config: SimulationConfig, wavelengths_nm: np.ndarray, at_host: Callable[..., tuple],
                mc_noise: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """``beta, u_beta`` of ``config``.

    ``at_host(fiber_config, mu_host, mc_noise)`` of its fiber with its dye; of a blend, the populations' models
    mixed by share (as :func:`simulate.products.evaluate` mixes the summation's and the classic model's), ``u_beta``
    added linearly (their tables are one walk's). One population: its model alone.

    The populations of a fitted blend share the fiber's scattering (:func:`~fabric_optics.fitting.spec.make_spec`),
    so each reads its dye from the same absorption table and one ``mc_noise`` draw shifts them all alike.

    Parameters
    ----------
    config : SimulationConfig
        The config (one fiber, or a blend of populations).
    wavelengths_nm : numpy.ndarray
        The wavelengths (nm).
    at_host : callable
        The model of one population at a host absorption (:meth:`FitProblem.model_at_host`).
    mc_noise : numpy.ndarray, optional
        Standard normal draws passed to ``at_host``.

    Returns
    -------
    beta, u_beta : numpy.ndarray
        The radiance coefficients and their standard uncertainties (geometries x wavelengths).
    """
    wl = np.asarray(wavelengths_nm, float)
    parts = config.population_configs()
    if len(parts) == 1:
        c = parts[0][1]
        return at_host(c, c.dye(wl) if c.dye is not None else np.zeros(wl.size), mc_noise)
    beta: Any = 0.0
    u: Any = 0.0
    for share, c in parts:
        b, ub = at_host(c, c.dye(wl) if c.dye is not None else np.zeros(wl.size), mc_noise)
        beta = beta + share * b
        u = u + share * ub
    return np.asarray(beta, float), np.asarray(u, float)


def _frozen(values: list[float]) -> np.ndarray:
    a = np.array(values, float)
    a.setflags(write=False)
    return a
