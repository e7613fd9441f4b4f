"""The inverse problem of ``simulate fit``: free parameters, the model at the measured geometries, the objective.

Decisions (objective, weights, Monte Carlo noise, common random numbers): :mod:`fabric_optics.fitting.driver`'s
docstring. This module states the problem; :mod:`fabric_optics.fitting.driver` solves it and writes the outputs.
"""

from __future__ import annotations

import copy
import dataclasses
import hashlib
import json
import logging
import math
import warnings
from pathlib import Path
from typing import Any, Callable
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from fabric_optics.fitting.errors import FitError
from gonio.data.dataset import COLUMNS, Dataset, make_dataset, new_meta
from gonio.data.schema import WAVELENGTH_RANGE_NM
from simulate import fabric as fab
from simulate import fiber as fib
from simulate.config import SimulationConfig, parse_config
from simulate.config_dye import dye_from_table
from simulate.config_table import Table
from simulate.fiber.absorption import DEFAULT_NODES, AbsorptionTable, absorption_nodes, absorption_table
from fabric_optics import paths
from fabric_optics.fitting.structure import STRUCTURE_FIELDS
from fabric_optics.paths import toml_dumps

__all__ = ["GENERATOR", "COLOUR_TOLERANCE", "COLOUR_HOLD_FROM", "COLOUR_HOLD_WEIGHT", "FitError", "FreeParameter",
           "colour_hold", "default_bounds", "parse_free", "FitProblem"]

log = logging.getLogger(__name__)

GENERATOR = "simulate fit"
#: How much larger ``ln E[w^2]`` (:func:`simulate.fiber.spectral.reweight_exponent`) of a re-weighted
#: evaluation may be than that of the reference walk's own wavelength groups: ``ln 4``, the standard
#: error at most doubled by the bound (measured on red cotton: x1.1 for a 10 % volume fraction change).
REWEIGHT_LIMIT = math.log(4.0)
#: Step of the geometric lattice of reference walks (:meth:`FitProblem.lattice`): 10 %, so a point is
#: at most 5 % from its reference (bound ~0.1-0.5 on red cotton, well inside the limit).
LATTICE_STEP = 0.10
#: Step of the structured summation's lattice of walks (:meth:`FitProblem.lattice_corners`): 20 %. Its walks are
#: not re-weighted but blended (linear in ``log v``), so the step is not bounded by the re-weighting's variance;
#: a cell of 20 % instead of 10 % halves the walks a search across the volume fraction needs (the felt's went
#: 0.005 -> 0.0035: 6 walks at 10 %), and ``beta``'s curvature in ``log v`` over it stays far below the walks'
#: Monte Carlo error (the blend's deviation from a walk at the value itself: tests/fabric_optics/fitting/test_lattice_walks.py).
STRUCTURED_LATTICE_STEP = 0.20
#: Step of the structured summation's lattice of surface terms in the RMS slope (:meth:`FitProblem.surface_term`):
#: 2 % in ``log rms_slope``. The surface term's table (:func:`simulate.fabric.fiberlayer.surface_table`, ~0.17 CPU s
#: on the 7.5 deg layer grid, compiled; ~1.9 s in numpy) is computed at the lattice points only and blended linearly
#: in ``log rms_slope`` between them; computed in numpy at every value the search visits (each step and each
#: Jacobian's two columns) it was about two thirds of the felt's summation fit. The blend's deviation from the exact term at a cell's middle:
#: 4e-5 of the mean ``beta`` (RMS over the demo's geometries at RMS slope 0.15), far below the walk's Monte Carlo
#: error (tests/fabric_optics/fitting/test_surface_lattice.py).
SURFACE_LATTICE_STEP = 0.02
#: Parsed configs :meth:`FitProblem.config_at` keeps, by the values of the free parameters other than the dye: the
#: centre and a Jacobian's columns of the others (a dye-only point reads its config from them).
PARSED_CONFIGS = 8
#: Default bounds of a dye knot (log10 of 1/um): see :func:`default_bounds`.
KNOT_LOW, KNOT_HIGH = -4.0, 0.5
#: Fields only the Monte Carlo sees (kind ``"fine"``), with their valid range: the rough boundary for transmitted
#: light (docs/physics.md 3). The summation and classic model walk the smooth boundary
#: (:func:`simulate.products.smooth_boundary_unless_mc`), so a fit of theirs refuses them; the Monte Carlo fit
#: takes their trend from Monte Carlo runs themselves (:mod:`fabric_optics.fitting.mc`, "Parameters only the Monte Carlo sees").
FINE_FIELDS = {"surface.transmission_rms_slope": (0.0, 1.0), "surface.transmission_rms_slope_around": (0.0, 1.0)}
#: ``(|dh| turn, |ds|)`` above which a fitted colour is left off: the fit fails (:mod:`fabric_optics.fitting.driver`)
COLOUR_TOLERANCE = (0.02, 0.03)
#: The colour hold (:func:`colour_hold`): from this fraction of :data:`COLOUR_TOLERANCE` on, each colour difference
#: pays ``COLOUR_HOLD_WEIGHT (|d|/tol - COLOUR_HOLD_FROM)^2`` in the objective. ``w_c (dh^2 + ds^2)`` alone loses to
#: the curve error: on the green felt's measured plan (138 geometries) the classic fit ended at ds -0.207 at ``w_c``
#: 1, at -0.036 at ``w_c`` 30 (docs/notes/fit-trust.md). The hold is zero inside 0.7 of the tolerance, so it does not
#: move a fit that ends there anyway; one tolerance out it costs 0.09, two out 1.7, above the NRMSE^2 of the fits
#: (0.1 to 0.5), so the search ends within the tolerance whenever the model reaches the colour: past 0.7 it stops
#: where the curve error's slope g (in NRMSE^2 per tolerance) equals the hold's, ``0.7 + g / (2 W)``; the felt's fits
#: met g of 0.05 to 0.1 (they ended at 0.7 to 0.8 of the tolerance). A weight of 10 held as well but slowed the
#: summation's search (ill-conditioned: 600 evaluations reached NRMSE 0.735, 1000 0.70; weight 1: see the note).
COLOUR_HOLD_FROM = 0.7
COLOUR_HOLD_WEIGHT = 1.0


def colour_hold(dh: float, ds: float) -> np.ndarray:
    """``sqrt(COLOUR_HOLD_WEIGHT) [max(0, |dh|/tol_h - f), max(0, |ds|/tol_s - f)]`` (``f`` :data:`COLOUR_HOLD_FROM`,
    ``tol`` :data:`COLOUR_TOLERANCE`): the residual entries of the colour hold, zero well inside the tolerance."""
    tol_h, tol_s = COLOUR_TOLERANCE
    excess = np.maximum(0.0, np.abs(np.array([dh / tol_h, ds / tol_s], float)) - COLOUR_HOLD_FROM)
    return math.sqrt(COLOUR_HOLD_WEIGHT) * excess



# ------------------------------------------------------------------------------------------
# free parameters


@dataclass(frozen=True)
class FreeParameter:
    """One free config field: its dotted path, kind and bounds.

    ``kind``: ``"dye"`` (re-weighted from the absorption table), ``"surface"`` (analytic
    Cook-Torrance term), ``"structure"`` (the structured summation's geometry), ``"walk"`` (changes the
    scattering: photons are walked again) or ``"fine"`` (:data:`FINE_FIELDS`: seen by the Monte Carlo only).
    """

    name: str
    start: float
    low: float
    high: float
    kind: str


def _kind(path: str) -> str:
    if path.startswith("fiber.dye"):
        return "dye"
    if path == "surface.rms_slope":
        return "surface"
    if path in STRUCTURE_FIELDS:
        return "structure"
    if path in FINE_FIELDS:
        return "fine"
    return "walk"


def default_bounds(path: str, start: float) -> tuple[float, float]:
    """Default bounds of a free parameter from its field and start value.

    Volume fraction ``[start/5, min(5 start, 0.5)]``; radii and widths ``[start/4, 4 start]``;
    RMS slope ``[0.02, 0.5]``; dye amplitudes (``*_per_um``) ``[0, max(4 start, 0.01)]``; dye
    knots (``log10_per_um[k]``) ``[-4, 0.5]`` (1e-4 to 3.2 /um: transparent to opaque over a
    fiber's radius; widened to hold the start); band
    centres and edges ``start -+ 60 nm``; log-normal ``sigma_g`` ``[1, 3]``; anything else
    ``[start/4, 4 start]`` (give ``=LOW:HIGH`` for a field that is 0). Structure fields
    (:data:`fabric_optics.fitting.structure.STRUCTURE_FIELDS`): their whole valid range, 0-60 deg. The boundary's
    slopes for transmitted light (:data:`FINE_FIELDS`): ``[0, 1]``, their valid range (0 is the smooth boundary).
    """
    if path in STRUCTURE_FIELDS:
        return STRUCTURE_FIELDS[path]
    if path in FINE_FIELDS:
        return FINE_FIELDS[path]
    leaf = path.rsplit(".", 1)[-1]
    if leaf == "volume_fraction":
        return start / 5.0, min(5.0 * start, 0.5)
    if path == "surface.rms_slope":
        return 0.02, 0.5  # Cook-Torrance's single-scattering domain (simulate.optics.microfacet warns above)
    if leaf.endswith("_per_um") and path.startswith("fiber.dye"):
        return 0.0, max(4.0 * start, 0.01)
    if leaf in ("center_nm", "edge_nm"):
        return start - 60.0, start + 60.0
    if leaf == "sigma_g":
        return 1.0, 3.0
    if leaf.startswith("log10_per_um[") and path.startswith("fiber.dye"):
        return min(KNOT_LOW, start), max(KNOT_HIGH, start)
    return start / 4.0, 4.0 * start


def parse_free(specs: list[str], config: SimulationConfig) -> list[FreeParameter]:
    """Free parameters from ``NAME[=LOW:HIGH]`` items (comma-separated in each string).

    Raises
    ------
    FitError
        An unknown name (the config has no such numeric field), malformed or empty bounds, bounds
        that exclude the start value, or a parameter named twice.
    """
    import tomllib

    data = tomllib.loads(config.text)
    out: list[FreeParameter] = []
    for spec in ",".join(specs).split(","):
        spec = spec.strip()
        if not spec:
            continue
        name, _, bounds = spec.partition("=")
        try:
            names = paths.expand(name.strip(), data)
            for path in names:
                paths.split(path)
        except paths.PathError as exc:
            raise FitError(f"--free {exc}" if name.strip() in paths.ALIASES else f"--free: {exc}") from None
        for path in names:
            # before the look-up: a run setting at its default is not written in the config
            if path.startswith(("method.", "wavelengths.", "weave.")) or path == "seed":
                raise FitError(f"--free: {path!r} is a run setting, not an optical parameter")
            if path.startswith("structure."):
                _check_structure_field(path, config)
            try:
                start = paths.get(data, path)
            except KeyError:
                if path in STRUCTURE_FIELDS:   # a defaulted [structure] field: its default starts the fit
                    start = getattr(config.structure, path.split(".", 1)[1])
                    data["structure"][path.split(".", 1)[1]] = start
                else:
                    start = None
            if start is None:
                candidates = ", ".join(sorted(set(paths.numeric_leaves(data, "")) - {"seed"})[:12])
                raise FitError(f"--free: unknown parameter {path!r}: the config {config.name} has no such "
                               f"numeric field (fields: {candidates}, ...; aliases: volume_fraction, radius, "
                               "rms_slope, dye, dye-peaks)") from None
            if isinstance(start, bool) or not isinstance(start, (int, float)):
                raise FitError(f"--free: {path!r} is not a number in the config (a table or text); "
                               "free one numeric field")
            start = float(start)
            if bounds:
                lo_text, sep, hi_text = bounds.partition(":")
                try:
                    low, high = float(lo_text), float(hi_text)
                except ValueError:
                    low = high = math.nan
                if not sep or not (math.isfinite(low) and math.isfinite(high)) or not low < high:
                    raise FitError(f"--free: {spec!r}: bounds must be LOW:HIGH with LOW < HIGH, got {bounds!r}")
            else:
                low, high = default_bounds(path, start)
            if path in STRUCTURE_FIELDS or path in FINE_FIELDS:
                lo_ok, hi_ok = STRUCTURE_FIELDS.get(path) or FINE_FIELDS[path]
                if low < lo_ok or high > hi_ok:
                    raise FitError(f"--free: {path} bounds [{low:g}, {high:g}] leave the field's valid range "
                                   f"[{lo_ok:g}, {hi_ok:g}]; give bounds inside it")
            if not low <= start <= high:
                raise FitError(f"--free: {path} = {start:g} in the config lies outside its bounds "
                               f"[{low:g}, {high:g}]; widen the bounds or change the config")
            if any(p.name == path for p in out):
                raise FitError(f"--free: {path} is named twice")
            out.append(FreeParameter(path, start, float(low), float(high), _kind(path)))
    if not out:
        raise FitError("--free: no parameter to fit")
    return out


def _check_structure_field(path: str, config: SimulationConfig) -> None:
    """A ``structure.*`` parameter: the config has ``[structure]``, the field is one a fit frees, of its kind."""
    spec = getattr(config, "structure", None)
    if spec is None:
        raise FitError(f"--free: {path!r}: the config {config.name} has no [structure] section (add one: "
                       "kind = \"woven\" or \"nonwoven\")")
    if path not in STRUCTURE_FIELDS:
        raise FitError(f"--free: {path!r} is not a structure parameter a fit frees (free one of "
                       f"{', '.join(sorted(STRUCTURE_FIELDS))})")
    felt = path == "structure.felt_spread_deg"
    if felt != (spec.kind == "nonwoven"):
        raise FitError(f"--free: {path!r} does nothing for the config's structure kind {spec.kind!r} "
                       f"({'felt_spread_deg' if spec.kind == 'nonwoven' else 'warp_twist_deg, weft_twist_deg'} do)")


# ------------------------------------------------------------------------------------------
# the problem: model evaluation and objective


def _model_geometries(measured: Dataset) -> pd.DataFrame:
    # exactly the measured geometries: compare then estimates the model's normal/normal value from
    # the same neighbours as the measurement's, so the estimate's own bias cancels in k(lambda)
    # (the model's exact normal value against an estimated measured one biased the fit)
    g = measured.table[["theta_i", "phi_i", "theta_o", "phi_o"]].drop_duplicates()
    return g.reset_index(drop=True)


def _dye_ceiling(config: SimulationConfig, free: list[FreeParameter], wl: np.ndarray) -> float:
    """Largest host absorption (1/um) any dye within the bounds can reach (the table's nu_max)."""
    if config.dye is None:
        return 1e-3
    p = copy.deepcopy(config.dye.params)
    doc = {"fiber": {"dye": p}}
    for f in free:
        if f.kind == "dye":
            paths.set_value(doc, f.name, f.high if "_per_um" in f.name else paths.get(doc, f.name))
    if config.dye.curve == "gaussian-bands":
        top = p["baseline_per_um"] + sum(b["peak_per_um"] for b in p["bands"])
    elif config.dye.curve == "knots":  # PCHIP does not overshoot: the largest knot is the maximum
        top = 10.0 ** max(p["log10_per_um"])
    elif config.dye.curve == "logistic-edge":
        top = max(p["short_per_um"], p["long_per_um"])
    else:
        top = float(np.max(config.dye(wl)))
    return max(1.05 * top, 1e-3)


def _checked_wavelengths(value: object) -> np.ndarray:
    """The model wavelengths (``--wavelengths``) as a float array: finite, in the dataset range, increasing."""
    try:
        wl = np.asarray(value, float).reshape(-1)
    except (TypeError, ValueError):
        raise FitError(f"--wavelengths: expected numbers in nm, got {value!r}") from None
    lo, hi = WAVELENGTH_RANGE_NM
    if wl.size == 0:
        raise FitError("--wavelengths: no wavelength given")
    bad = [w for w in wl if not (np.isfinite(w) and lo <= w <= hi)]
    if bad:
        raise FitError(f"--wavelengths: {bad[0]:g} is not a wavelength in [{lo:g}, {hi:g}] nm")
    if np.any(np.diff(wl) <= 0):
        raise FitError("--wavelengths: must be strictly increasing, without repeats (e.g. 400,410,...,700)")
    return wl


@dataclass
class FitProblem:
    """Everything an evaluation needs: measurement, config, model, free parameters, settings."""

    config: SimulationConfig
    measured: Dataset
    free: list[FreeParameter]
    method: str = "classic"
    colour_weight: float = 1.0
    #: the colour hold (:func:`colour_hold`) in the objective, when the measurement has a colour and ``colour_weight``
    #: is positive (the classic and summation fits; ``--colour-hold off``: the weighted colour terms only)
    hold_colour: bool = False
    #: weight of ``(ln k_Y)^2``, the absolute level, in the objective (``--absolute``: 1; 0: shapes and colour only)
    level_weight: float = 0.0
    target_rel_err: float = 0.03
    seed: int | None = None
    threads: int | None = None
    wavelengths_nm: np.ndarray | None = None
    nodes: int = DEFAULT_NODES
    walks: int = 0
    walk_seconds: float = 0.0
    evaluations: int = 0
    photons: dict | None = None
    #: the fit's output directory: walks are checkpointed in it (fabric_optics.fitting.state)
    out: Path | None = None
    #: ``progress(photons, run, runs)`` during walks (simulate.fiber.absorption.absorption_table)
    walk_progress: Callable[[int, int, int], None] | None = None
    #: re-weight the reference walk to other scattering parameters within the bound (module docstring)
    reweight: bool = True
    reweights: int = 0
    reweight_seconds: float = 0.0
    #: structured walks and re-weighted passes read whole from the disk cache (fabric_optics.fitting.structure.walk_structure);
    #: they are also counted in ``walks`` / ``reweights``
    cached_walks: int = 0
    #: ``(bound of the last re-weighting considered, the reference walk's own)`` (diagnostics)
    last_exponent: tuple = (0.0, 0.0)
    #: whether :data:`FINE_FIELDS` may be free (the Monte Carlo fit: their trend comes from Monte Carlo runs)
    fine_capable: bool = False
    _references: dict = field(default_factory=dict)
    _tables: dict = field(default_factory=dict)
    _doc: dict = field(default_factory=dict)
    #: the parsed configs by the values of the free parameters other than the dye (:meth:`config_at`)
    _parsed: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        import tomllib

        if self.method not in ("classic", "summation"):
            raise FitError(f"--method must be classic or summation, got {self.method!r}")
        if self.level_weight and self.measured.relative:
            raise FitError("--absolute: the measurement is relative (\"relative\": true, raw units): it has no absolute "
                           "level to fit; drop --absolute")
        if self.method == "summation" and self.config.route == "bssrdf":
            raise FitError("the summation fit needs the nee or beam fiber route (fiber.route in the config)")
        self._doc = tomllib.loads(self.config.text)
        if self.seed is None:
            self.seed = self.config.seed
        if self.wavelengths_nm is None:
            spectral = "channel" not in self.measured.table.columns
            self.wavelengths_nm = (np.asarray(self.measured.wavelengths_nm, float) if spectral
                                   else np.asarray(self.config.wavelengths_nm, float))
        self.wavelengths_nm = _checked_wavelengths(self.wavelengths_nm)
        self.notes: list[str] = []
        spec = getattr(self.config, "structure", None)
        #: the structured summation of simulate fabric (fabric_optics.fitting.structure) instead of the top-cell carpet
        self.structured = self.method == "summation" and spec is not None
        fine = [p.name for p in self.free if p.kind == "fine"]
        if fine and not self.fine_capable:
            raise FitError(f"--free {fine[0]}: only the Monte Carlo sees the rough boundary for transmitted light "
                           f"(the {self.method} model walks the smooth one, docs/physics.md 3); fit it with --method mc")
        if any(p.kind == "structure" for p in self.free) and not self.structured:
            raise FitError("--free structure.*: structure parameters need --method summation and a config with "
                           "a [structure] section")
        if self.structured:
            # the interior closure's surface share is computed at the starting RMS slope (fabric_optics.fitting.structure)
            self._roughness = float(self.config.rms_slope)
            self._facets: dict = {}
            self._surfaces: dict = {}
        self._drop_grazing()
        incidences = (self.measured.meta.get("sample") or {}).get("incidences") or {}
        if incidences.get("interpolated_deg"):
            self.notes.append(f"the measurement's incidences {', '.join(f'{t:g}' for t in incidences['interpolated_deg'])} "
                              f"deg are {incidences.get('source', 'the file')}'s interpolation between its measured "
                              "tables, not measured (a plan of its measured incidences: --plan measured)")
        self.geometries = _model_geometries(self.measured)
        self._residual: Any = None  # compare.residual.ModelResidual, built on first use
        g = self.geometries
        self.w_i = fab.directions_deg(g["theta_i"].to_numpy(), g["phi_i"].to_numpy())
        self.w_o = fab.directions_deg(g["theta_o"].to_numpy(), g["phi_o"].to_numpy())
        if self.method == "summation":
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                self.pairs = fab.FiberPairs.from_angles(g["theta_i"], g["phi_i"], g["theta_o"], g["phi_o"])
        self.nu_max = _dye_ceiling(self.config, self.free, self.wavelengths_nm)
        self.low = np.array([p.low for p in self.free])
        self.high = np.array([p.high for p in self.free])
        self.start = np.array([p.start for p in self.free])

    def _drop_grazing(self) -> None:
        """The grazing rule of ``gonio import`` (:data:`gonio.data.formats.GRAZING_DEG`): rows at
        ``theta_i >= 89`` deg are left out of the fit with a note (a file imported with
        ``--keep-grazing`` keeps them; no fabric model is meant for them: the projected area
        vanishes, Cook-Torrance leaves its domain); a measurement with nothing else is refused."""
        from gonio.data.dataset import Dataset
        from gonio.data.formats import GRAZING_DEG

        t = self.measured.table
        grazing = t["theta_i"].to_numpy(float) >= GRAZING_DEG
        if not grazing.any():
            return
        if grazing.all():
            raise FitError(f"every incidence of the measurement is >= {GRAZING_DEG:g} deg (near grazing), where "
                           "no fabric model is meant to be fitted")
        angles = ", ".join(f"{a:.10g}" for a in np.unique(t["theta_i"].to_numpy(float)[grazing]))
        self.notes.append(f"{int(grazing.sum())} rows of the measurement at incidence >= {GRAZING_DEG:g} deg "
                          f"(theta_i {angles}) are left out of the fit (near grazing: the rule of gonio import)")
        log.warning("%s", self.notes[-1])
        self.measured = Dataset(t[~grazing].reset_index(drop=True), self.measured.meta, self.measured.path)

    # -- parameters and configs ------------------------------------------------------------

    def config_at(self, x: np.ndarray) -> SimulationConfig:
        """The config with the free fields set to ``x`` (validated by the config parser).

        The whole config is parsed once per value of the parameters other than the dye (the last
        :data:`PARSED_CONFIGS`); a point that differs from one of those in the dye alone gets that config with
        its dye table parsed (:func:`simulate.config_dye.dye_from_table`, the parser's own) and the text and
        SHA-256 of the whole: field by field the config a full parse gives (a dye-only search step or Jacobian
        column re-parsed the whole config, a quarter of an evaluation)."""
        doc = copy.deepcopy(self._doc)
        for p, v in zip(self.free, x):
            paths.set_value(doc, p.name, float(v))
        text = toml_dumps(doc)
        file = f"{self.config.name}.toml"
        key = tuple(float(v) for p, v in zip(self.free, x) if p.kind != "dye")
        base = self._parsed.get(key)
        if base is None:
            config = parse_config(text, file, source=f"fit of {self.config.source}")
            if len(self._parsed) >= PARSED_CONFIGS:
                self._parsed.pop(next(iter(self._parsed)))
            self._parsed[key] = config
            return config
        raw = text.encode("utf-8", errors="surrogatepass")   # as parse_config reads a text
        dye = doc["fiber"].get("dye")
        return dataclasses.replace(base, text=raw.decode("utf-8"), sha256=hashlib.sha256(raw).hexdigest(),
                                   dye=None if dye is None else dye_from_table(Table(dye, "fiber.dye", file)))

    def fitted_toml(self, x: np.ndarray, note: str) -> str:
        """TOML text of the fitted config (comments of the original are not kept)."""
        doc = copy.deepcopy(self._doc)
        for p, v in zip(self.free, x):
            paths.set_value(doc, p.name, float(v))
        doc["name"] = f"{self.config.name}-fitted"
        return toml_dumps(doc, header="\n".join("# " + line for line in note.splitlines()))

    # -- the model ----------------------------------------------------------------------------

    def table(self, config: SimulationConfig) -> AbsorptionTable:
        """The absorption table of ``config``'s scattering: walked, or re-weighted from the walk at its
        lattice point (:meth:`lattice`), whichever the module docstring's rule says; memoised."""
        if self.structured:
            return self._structured_table(config)
        return self._walk_table(config)

    def _structured_table(self, config: SimulationConfig) -> AbsorptionTable:
        """The structured summation's table of ``config``: its walk's, or -- a walked parameter between two
        lattice points -- the interpolation of the walks at the lattice points around it (:meth:`lattice_corners`)."""
        from fabric_optics.fitting.structure import structure_key

        key = structure_key(config)
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
        """The lattice points (``start * exp(STRUCTURED_LATTICE_STEP k)`` per walked parameter) around the walked values
        ``walk`` and their multilinear weights in ``log v``: ``[(point, weight)]`` (one point, weight 1, on the
        lattice; 2^d around it). Values that are not positive, or whose start is not, are kept as they are.

        The structured summation's walked parameters are read this way instead of re-weighting the walk at the
        nearest lattice point (:meth:`lattice`): a re-weighted pass walks the same paths again to score them
        (as long as a walk: 9 passes of 51 evaluations were 3/4 of a 347 s fit of the felt), so the walks at
        the lattice points are all that is walked (each in the disk cache: a refit walks nothing). The
        objective is then continuous across lattice cells (the jumps between the walks at 10 % target,
        docs/physics.md 6.5, become a linear blend)."""
        starts = [p.start for p in self.free if p.kind == "walk"]
        axes: list[list[tuple[float, float]]] = []
        step = STRUCTURED_LATTICE_STEP
        for s, v in zip(starts, walk):
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
        for p, v in zip([p for p in self.free if p.kind == "walk"], point):
            paths.set_value(doc, p.name, v)
        at = parse_config(toml_dumps(doc), "lattice.toml")
        nodye = dataclasses.replace(at, dye=None).fiber(self.wavelengths_nm)
        walk = self._run(nodye, point, None, at)
        self._references[point] = (nodye, walk)
        if len(self._tables) >= 6:  # the 2^d corners of a step and of a Jacobian's columns
            self._tables.pop(next(iter(self._tables)))
        self._tables[point] = walk
        return walk

    def _facets_of(self, config: SimulationConfig) -> Any:
        from fabric_optics.fitting.structure import facets_of, structure_key

        key = structure_key(config)
        if key not in self._facets:
            if len(self._facets) >= 8:
                self._facets.pop(next(iter(self._facets)))
            self._facets[key] = facets_of(config)
        return self._facets[key]

    def _walk_table(self, config: SimulationConfig) -> Any:
        """The walk of ``config``'s scattering (an absorption table, or the structured layer tables)."""
        walk = self._walk_values(config)
        if walk in self._tables:
            return self._tables[walk]
        wl = self.wavelengths_nm
        nodye = dataclasses.replace(config, dye=None).fiber(wl)
        lattice = self.lattice(walk)
        table = None
        if self.reweight and lattice != walk:
            ref = self._references.get(lattice)
            if ref is None:
                doc = self._doc_of(config)
                for p, v in zip([p for p in self.free if p.kind == "walk"], lattice):
                    paths.set_value(doc, p.name, v)
                ref_fiber = dataclasses.replace(parse_config(toml_dumps(doc), "lattice.toml"), dye=None).fiber(wl)
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
        """The reference point of walked values ``walk``: each positive value rounded to the geometric
        lattice ``start * exp(LATTICE_STEP * k)`` (others kept). Evaluating every point from the walk
        at its lattice point makes the objective a deterministic function of the parameters (not of
        the order in which the search visited them: a resumed fit sees the same values)."""
        starts = [p.start for p in self.free if p.kind == "walk"]
        out = []
        for s, v in zip(starts, walk):
            if s > 0 and v > 0:
                k = round(math.log(v / s) / LATTICE_STEP)
                out.append(round(s * math.exp(LATTICE_STEP * k), 12))
            else:
                out.append(v)
        return tuple(out)

    def _run(self, nodye: Any, key: tuple, ref: tuple | None, config: SimulationConfig | None = None) -> Any:
        """A fresh walk of ``nodye`` (``ref`` None) or the re-weighting of ``ref = (fiber, table)``."""
        from simulate.products import smooth_boundary_unless_mc

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
        if self.out is not None:
            from fabric_optics.fitting.state import WalkCheckpoint

            cache = WalkCheckpoint(self.out, self.identity(), key, nodes, self.photons)
        table = absorption_table(nodye, w_in, outputs, wl, nodes, method=route, target_rel_err=self.target_rel_err,
                                 photons=self.photons if ref is None else ref[1].photons, seed=int(self.seed or 0),
                                 threads=self.threads, progress=self.walk_progress, cache=cache,
                                 reference=None if ref is None else ref[0])
        if cache is not None and cache.found:
            log.info("%d Monte Carlo runs read from the checkpoint %s", cache.found, cache.dir)
        if ref is not None:
            self.reweights += 1
            self.reweight_seconds += table.seconds
            return table
        if self.photons is None:
            self.photons = dict(table.photons)
        self.walks += 1
        self.walk_seconds += table.seconds
        if len(self._references) >= 8:
            self._references.pop(next(iter(self._references)))
        return table

    def _run_structured(self, nodye: Any, ref: tuple | None, config: SimulationConfig) -> Any:
        """The structured walk (:func:`fabric_optics.fitting.structure.walk_structure`); not checkpointed per run."""
        from fabric_optics.fitting.structure import walk_structure, walk_wavelengths

        rough = dataclasses.replace(nodye, roughness=self._roughness)
        reference = None if ref is None else dataclasses.replace(ref[0], roughness=self._roughness)
        walk = walk_structure(rough, config, walk_wavelengths(self.wavelengths_nm),
                              absorption_nodes(self.nu_max, self.nodes),
                              target_rel_err=self.target_rel_err, seed=int(self.seed or 0), threads=self.threads,
                              reference=reference, progress=self.walk_progress)
        if walk.cache == "hit":
            self.cached_walks += 1
        if ref is not None:
            self.reweights += 1
            self.reweight_seconds += walk.seconds
            return walk
        if self.photons is None:
            self.photons = dict(walk.photons)
        self.walks += 1
        self.walk_seconds += walk.seconds
        if len(self._references) >= 8:
            self._references.pop(next(iter(self._references)))
        return walk

    def _within_bound(self, ref_table: Any, nodye: Any, wl: np.ndarray) -> bool:
        """Whether ``ref_table``'s paths can be re-weighted to ``nodye``'s scattering
        (:func:`simulate.fiber.spectral.reweight_exponent`: the bound grows by at most
        :data:`REWEIGHT_LIMIT` over the walk's own wavelength groups)."""
        from simulate.fiber.spectral import reweight_exponent, spectral_optics

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
        import tomllib

        return tomllib.loads(config.text)

    def model(self, x: np.ndarray, mc_noise: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """``beta, u_beta`` ``[G, L]`` of the model at the model geometries for parameters ``x``.

        ``mc_noise`` (``[P, L]`` standard normal draws) shifts the volume term by that many
        standard errors (the uncertainty propagation of the Monte Carlo error).
        """
        config = self.config_at(x)
        wl = self.wavelengths_nm
        mu_host = config.dye(wl) if config.dye is not None else np.zeros(wl.size)
        return self.model_at_host(config, mu_host, mc_noise)

    def model_at_host(self, config: SimulationConfig, mu_host: np.ndarray,
                      mc_noise: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """``beta, u_beta`` ``[G, L]`` of ``config``'s fiber with the host absorption ``mu_host[L]`` (1/um)
        in place of its dye (read from the absorption table, no walk once the table exists)."""
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
            from simulate.media.medium import HGMedium

            surface_fiber = fib.Fiber(config.radius_um, config.n_host, HGMedium(mu_s=0.0, mu_a=0.0, g=0.0),
                                      config.rms_slope, config.cell_width_deg)
            r_surf = np.asarray(fib.surface_brdf(surface_fiber, self.pairs.w_in, self.pairs.w_out), float)
            beta, u_beta = fab.summation_from_table(self.pairs, R + r_surf[:, None], u)
        return beta, u_beta

    def surface_term(self, config: SimulationConfig) -> np.ndarray:
        """The structured summation's surface ``beta [N]`` at ``config``'s RMS slope: the exact term
        (:func:`fabric_optics.fitting.structure.surface_beta`) at the points of the lattice ``r0 exp(SURFACE_LATTICE_STEP k)``
        (``r0`` the start config's RMS slope), blended linearly in ``log rms_slope`` between the two around it
        (:data:`SURFACE_LATTICE_STEP`); each lattice point computed once per structure (memoised). A positive RMS
        slope on the lattice (the start's, a fit that does not free it) is the exact term."""
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
        """The exact surface ``beta [N]`` of ``config``'s structure at ``rms_slope`` (memoised, the last 16)."""
        from fabric_optics.fitting.structure import structure_key, surface_beta

        key = (structure_key(config), rms_slope, float(config.n_host))
        if key not in self._surfaces:
            if len(self._surfaces) >= 16:
                self._surfaces.pop(next(iter(self._surfaces)))
            at = config if rms_slope == float(config.rms_slope) else dataclasses.replace(config, rms_slope=rms_slope)
            self._surfaces[key] = surface_beta(at, self._facets_of(config), self.w_i, self.w_o)
        return self._surfaces[key]

    def dataset(self, beta: np.ndarray, u_beta: np.ndarray, label: str, extra: dict | None = None) -> Dataset:
        """The model values as a ``"simulated"`` dataset at the model geometries."""
        g = self.geometries
        wl = self.wavelengths_nm
        rep = g.loc[g.index.repeat(wl.size)].reset_index(drop=True)
        table = pd.DataFrame({"theta_i": rep["theta_i"], "phi_i": rep["phi_i"], "theta_o": rep["theta_o"],
                              "phi_o": rep["phi_o"], "wavelength_nm": np.tile(wl, len(g)),
                              "beta": np.asarray(beta).ravel(), "u_beta": np.asarray(u_beta).ravel(),
                              "n": np.ones(beta.size, dtype=np.int64)}, columns=list(COLUMNS))
        sample = dict(self.measured.meta.get("sample") or {})
        sample["name"] = f"{self.method} model ({label})"
        model = {"generator": GENERATOR, "name": f"fabric {self.method} ({label})", "method": self.method,
                 "config": self.config.name}
        return make_dataset(table, new_meta("simulated", sample, model, extra or {}))

    # -- the objective ----------------------------------------------------------------------

    def compare(self, sim: Dataset, measured: Dataset | None = None):
        """:func:`compare.comparison.compare_datasets` of the measurement and ``sim``."""
        from compare.comparison import compare_datasets

        logging.getLogger("compare").setLevel(logging.ERROR)  # per-evaluation chatter
        return compare_datasets(self.measured if measured is None else measured, [sim])

    def residuals_of(self, comparison) -> np.ndarray:
        """The residual vector of the module docstring from a comparison of one simulation."""
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
        """:class:`compare.residual.ModelResidual` of the measurement (or of a noise draw of it with
        the same rows), prepared once: per evaluation only the model side is computed."""
        from compare import ModelResidual

        if self._residual is None:
            self._residual = ModelResidual(self.measured, self.geometries, self.wavelengths_nm,
                                           name=f"{self.method} model")
        if measured is None or measured is self.measured:
            return self._residual
        return self._residual.with_measured(measured)

    def residuals(self, x: np.ndarray, measured: Dataset | None = None,
                  mc_noise: np.ndarray | None = None) -> np.ndarray:
        """Residuals at parameters ``x`` (physical units): ``compare``'s figures through
        :meth:`residual_model` (equal to :meth:`residuals_of` of :meth:`compare` to 1e-12, tested
        in compare)."""
        beta, u = self.model(x, mc_noise)
        self.evaluations += 1
        fig = self.residual_model(measured).evaluate(beta, u)
        r = fig.vector(self.colour_weight, self.level_weight)
        if self.holds_colour():
            r = np.concatenate([r, colour_hold(float(fig.dh), float(fig.ds))])
        return r

    def holds_colour(self) -> bool:
        """Whether the objective holds the colour within the tolerance (:func:`colour_hold`): asked for, the
        measurement has a colour and the colour terms carry weight."""
        return self.hold_colour and self.colour_weight > 0 and bool(self.residual_model().has_colour)

    def precheck(self) -> None:
        """Everything the objective needs from the measurement, before any photon (FitError)."""
        from compare.errors import CompareError

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
