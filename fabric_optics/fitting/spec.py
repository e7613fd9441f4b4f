"""The fit specification: what ``simulate fit`` fits, frozen before the search starts.

A :class:`FitSpec` holds the start config, the measurement (its near-grazing rows left out), the
free parameters with their bounds (:class:`FreeParameter`, :func:`parse_free`), the model, the
objective's weights, the seed, the model wavelengths and the Monte Carlo target. No runner writes
into it: what a runner varies (a start, bounds, a colour weight, an output correction) is passed to
it as an argument (:mod:`fabric_optics.fitting.search`, :mod:`fabric_optics.fitting.spacemapping`).

Public objects: :class:`FitSpec` and :func:`make_spec`, :class:`FreeParameter`, :func:`parse_free`,
:func:`default_bounds`, :func:`colour_hold` and the objective's constants (:data:`COLOUR_TOLERANCE`,
:data:`COLOUR_HOLD_FROM`, :data:`COLOUR_HOLD_WEIGHT`). Why each value: docs/notes/fit-trust.md.
"""

from __future__ import annotations

import copy
import logging
import math
import re
import tomllib
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from fabric_optics import paths
from fabric_optics.fitting.errors import FitError
from gonio.data.dataset import Dataset
from gonio.data.formats import GRAZING_DEG
from gonio.data.schema import WAVELENGTH_RANGE_NM
from simulate.config import SimulationConfig
from simulate.fiber.absorption import DEFAULT_NODES
from simulate.structwalk.walk import STRUCTURE_FIELDS

__all__ = ["GENERATOR", "SHARE_MIN", "DEPTH_FIELDS", "shares_at", "COLOUR_TOLERANCE", "COLOUR_HOLD_FROM", "COLOUR_HOLD_WEIGHT",
           "FINE_FIELDS", "FreeParameter", "FitSpec", "make_spec", "colour_hold", "default_bounds", "parse_free", "model_geometries", "dye_ceiling",
           "checked_wavelengths"]

log = logging.getLogger(__name__)

GENERATOR = "simulate fit"
#: Default bounds of a dye knot (log10 of 1/um): see :func:`default_bounds`.
KNOT_LOW, KNOT_HIGH = -4.0, 0.5
#: Fields only the Monte Carlo sees (kind ``"fine"``), with their valid range: the rough boundary for transmitted
#: light (docs/physics.md 3). The summation and classic model walk the smooth boundary
#: (:func:`simulate.products.smooth_boundary_unless_mc`), so a fit of theirs refuses them; the Monte Carlo fit
#: takes their trend from Monte Carlo runs themselves (:mod:`fabric_optics.fitting.spacemapping`, "Parameters only the Monte Carlo sees").
FINE_FIELDS = {"surface.transmission_rms_slope": (0.0, 1.0), "surface.transmission_rms_slope_around": (0.0, 1.0)}
#: ``(|dh| turn, |ds|)`` above which a fitted colour is left off: the fit fails (:mod:`fabric_optics.fitting.search`)
COLOUR_TOLERANCE = (0.02, 0.03)
#: The colour hold (:func:`colour_hold`): from this fraction of :data:`COLOUR_TOLERANCE` on, each colour difference
#: pays ``COLOUR_HOLD_WEIGHT (|d|/tol - COLOUR_HOLD_FROM)^2`` in the objective (why these values:
#: docs/notes/fit-trust.md, "The fit's constants").
COLOUR_HOLD_FROM = 0.7
COLOUR_HOLD_WEIGHT = 1.0


def colour_hold(dh: float, ds: float) -> np.ndarray:
    """The residual entries of the colour hold, zero well inside the tolerance.

    ``sqrt(COLOUR_HOLD_WEIGHT) [max(0, |dh|/tol_h - f), max(0, |ds|/tol_s - f)]`` (``f``
    :data:`COLOUR_HOLD_FROM`, ``tol`` :data:`COLOUR_TOLERANCE`).

    Parameters
    ----------
    dh, ds : float
        Hue (turns) and saturation differences, simulated minus measured.

    Returns
    -------
    numpy.ndarray
        The two entries.
    """
    tol_h, tol_s = COLOUR_TOLERANCE
    excess = np.maximum(0.0, np.abs(np.array([dh / tol_h, ds / tol_s], float)) - COLOUR_HOLD_FROM)
    return math.sqrt(COLOUR_HOLD_WEIGHT) * excess



# ------------------------------------------------------------------------------------------
# free parameters


@dataclass(frozen=True)
class FreeParameter:
    """One free config field: its dotted path, kind and bounds.

    ``kind``: ``"dye"`` (re-weighted from the absorption table; a population's dye too), ``"share"`` (a blend's
    population share: its populations' models mixed by share, :func:`shares_at`), ``"surface"`` (analytic
    Cook-Torrance term), ``"structure"`` (the structured summation's geometry), ``"walk"`` (changes the
    scattering: photons are walked again; a ring or core dye's depth too, whose dyed region the walk scores:
    :mod:`simulate.fiber.absorption`) or ``"fine"`` (:data:`FINE_FIELDS`: seen by the Monte Carlo only).
    """

    name: str
    start: float
    low: float
    high: float
    kind: str


_POP_DYE = re.compile(r"^populations\[\d+\]\.fiber\.dye\.")
_POP_SHARE = re.compile(r"^populations\[(\d+)\]\.share$")
_POP_PATH = re.compile(r"^populations\[(\d+)\]\.")
#: A free share's smallest value (a population's share must stay above 0: config.py's rule)
SHARE_MIN = 1e-3


#: The free depths of a placement (a ring or core dye, a skin or core of scatterers): walked, inside the fiber
DEPTH_FIELDS = ("dye_depth_um", "scatterer_depth_um")


def _kind(path: str) -> str:
    if path.endswith(DEPTH_FIELDS):
        return "walk"
    if path.startswith("fiber.dye") or _POP_DYE.match(path):
        return "dye"
    if _POP_SHARE.match(path):
        return "share"
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
    ``[start/4, 4 start]`` (give ``=LOW:HIGH`` for a field that is 0). A population's share: ``[0.001, 0.999]``,
    narrowed by :func:`parse_free` so that the free shares cannot add up beyond 1. Structure fields
    (:data:`simulate.structwalk.walk.STRUCTURE_FIELDS`): their whole valid range, 0-60 deg. The boundary's
    slopes for transmitted light (:data:`FINE_FIELDS`): ``[0, 1]``, their valid range (0 is the smooth boundary).

    Parameters
    ----------
    path : str
        The free parameter's field (e.g. ``fiber.radius_um``).
    start : float
        Its value in the config.

    Returns
    -------
    tuple of float
        ``(low, high)``, in the field's units.
    """
    if path in STRUCTURE_FIELDS:
        return STRUCTURE_FIELDS[path]
    if path in FINE_FIELDS:
        return FINE_FIELDS[path]
    if _POP_SHARE.match(path):      # parse_free narrows the upper bound by the other free shares
        return SHARE_MIN, 1.0 - SHARE_MIN
    leaf = path.rsplit(".", 1)[-1]
    if leaf == "volume_fraction":
        return start / 5.0, min(5.0 * start, 0.5)
    if path == "surface.rms_slope":
        return 0.02, 0.5  # Cook-Torrance's single-scattering domain (simulate.optics.microfacet warns above)
    if leaf.endswith("_per_um") and _kind(path) == "dye" and not leaf.startswith("log10_per_um["):
        return 0.0, max(4.0 * start, 0.01)
    if leaf in ("center_nm", "edge_nm"):
        return start - 60.0, start + 60.0
    if leaf == "sigma_g":
        return 1.0, 3.0
    if leaf.startswith("log10_per_um[") and _kind(path) == "dye":
        return min(KNOT_LOW, start), max(KNOT_HIGH, start)
    return start / 4.0, 4.0 * start


def parse_free(specs: list[str], config: SimulationConfig) -> list[FreeParameter]:
    """Free parameters from ``NAME[=LOW:HIGH]`` items (comma-separated in each string).

    Parameters
    ----------
    specs : list of str
        The ``--free`` items.
    config : SimulationConfig
        The start config.

    Returns
    -------
    list of FreeParameter
        The free parameters, in the order named.

    Raises
    ------
    FitError
        An unknown name (the config has no such numeric field), malformed or empty bounds, bounds
        that exclude the start value, or a parameter named twice.
    """
    data = tomllib.loads(config.text)
    out: list[FreeParameter] = []
    for spec in ",".join(specs).split(","):
        spec = spec.strip()
        if not spec:
            continue
        name, _, bounds = spec.partition("=")
        for path in _free_paths(name.strip(), data):
            start = _free_start(name.strip(), path, config, data)
            low, high = _free_bounds(spec, path, bounds, start)
            if path.endswith(DEPTH_FIELDS):
                low, high = _depth_bounds(path, spec, bool(bounds), low, high, config)
                if not low <= start <= high:
                    raise FitError(f"--free: {path} = {start:g} in the config lies outside its bounds "
                                   f"[{low:g}, {high:g}]; widen the bounds or change the config")
            if any(p.name == path for p in out):
                raise FitError(f"--free: {path} is named twice")
            out.append(FreeParameter(path, start, float(low), float(high), _kind(path)))
    if not out:
        raise FitError("--free: no parameter to fit")
    return _narrowed_shares(out, config)


def _free_paths(name: str, data: dict) -> list[str]:
    """The config paths that the ``--free`` name ``name`` stands for (an alias expanded), each checked."""
    try:
        names = paths.expand(name, data)
        for path in names:
            paths.split(path)
    except paths.PathError as exc:
        raise FitError(f"--free {exc}" if name in paths.ALIASES else f"--free: {exc}") from None
    return names


def _free_start(name: str, path: str, config: SimulationConfig, data: dict) -> float:
    """The start value of the free ``path``: the config's number there (a defaulted structure field: its default)."""
    # before the look-up: a run setting at its default is not written in the config
    if path.startswith(("method.", "wavelengths.", "weave.")) or path == "seed":
        raise FitError(f"--free: {path!r} is a run setting, not an optical parameter")
    if path.startswith("structure."):
        _check_structure_field(path, config)
    if config.populations or path.startswith("populations"):
        _check_population_field(name, path, config, data)
    try:
        start = paths.get(data, path)
    except KeyError:
        if path in STRUCTURE_FIELDS:   # a defaulted [structure] field: its default starts the fit
            start = getattr(config.structure, path.split(".", 1)[1])
            data["structure"][path.split(".", 1)[1]] = start
        else:
            start = None
    if start is None and path == "fiber.scatterer_depth_um":
        raise FitError(_no_scatterer_depth(name, config))
    if start is None:
        candidates = ", ".join(sorted(set(paths.numeric_leaves(data, "")) - {"seed"})[:12])
        raise FitError(f"--free: unknown parameter {path!r}: the config {config.name} has no such "
                       f"numeric field (fields: {candidates}, ...; aliases: volume_fraction, radius, "
                       "rms_slope, dye, dye-peaks)") from None
    if isinstance(start, bool) or not isinstance(start, (int, float)):
        raise FitError(f"--free: {path!r} is not a number in the config (a table or text); "
                       "free one numeric field")
    return float(start)


def _free_bounds(spec: str, path: str, bounds: str, start: float) -> tuple[float, float]:
    """``(low, high)`` of the free ``path``: ``LOW:HIGH`` as given (or the defaults), inside the field's range."""
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
    return low, high


#: a free depth's default bounds (a dye's or the scatterers'): from this fraction of the fiber's radius to the
#: radius less it
DEPTH_MARGIN = 0.02


def _depth_bounds(path: str, spec: str, given: bool, low: float, high: float,
                  config: SimulationConfig) -> tuple[float, float]:
    """A free depth's bounds inside ``(0, radius)`` (a placement needs both of its regions).

    A ring or core dye, a skin or core of scatterers. The defaults are clipped to :data:`DEPTH_MARGIN` of the
    radius from either end; given bounds outside ``(0, radius)`` are refused in one line.
    """
    m = _POP_PATH.match(path)
    radius = float(config.populations[int(m.group(1))].radius_um if m and config.populations else config.radius_um)
    if given:
        if not (0.0 < low and high < radius):
            what = "a scatterer depth" if path.endswith("scatterer_depth_um") else "a dye depth"
            raise FitError(f"--free: {spec!r}: {what} lies in (0, {radius:g}) um (the fiber's radius), got "
                           f"[{low:g}, {high:g}]; give bounds inside it")
        return low, high
    return max(low, DEPTH_MARGIN * radius), min(high, (1.0 - DEPTH_MARGIN) * radius)


def _check_population_field(name: str, path: str, config: SimulationConfig, data: dict) -> None:
    """A free path of a blend.

    A population's dye, share or dye depth (nothing else of a population is freed: its scattering is the config's);
    the config's own dye only while some population takes it.
    """
    pops = config.populations or ()
    kind = _kind(path)
    if kind == "dye" and path.startswith("fiber.dye"):
        if all(p.dye is not config.dye for p in pops):
            named = ", ".join(f"populations.{p.name}.dye" for p in pops)
            raise FitError(f"--free {name}: every population of the blend has a dye of its own, so [fiber.dye] "
                           f"colours none of them; free the populations' dyes ({named})")
        return
    m = _POP_PATH.match(path)
    if not m:
        # a field of the config's fiber that a population overrides would move the others only
        table, _, field = path.partition(".")
        for item, p in zip(data.get("populations") or [], pops, strict=True):
            own = item.get(table) if isinstance(item, dict) else None
            if isinstance(own, dict) and (table == "particles" or field.split(".")[0] in own):
                raise FitError(f"--free {name}: population {p.name!r} sets its own {table}"
                               f"{'' if table == 'particles' else '.' + field.split('.')[0]}, which this field of the "
                               "config would not move; give the populations the config's (delete the override)")
        return
    k = int(m.group(1))
    if k >= len(pops):
        raise FitError(f"--free {name}: the config has {len(pops)} population(s) (populations[0] to "
                       f"populations[{len(pops) - 1}])")
    pop = pops[k]
    if kind not in ("dye", "share") and not path.endswith("dye_depth_um"):
        raise FitError(f"--free {name}: a fit frees a population's dye, share and dye_depth_um "
                       f"(populations.NAME.dye, .share, .dye_depth_um); its fiber's scattering is the config's")
    if kind == "share" and len(pops) < 2:
        raise FitError(f"--free {name}: the config has one population, whose share is 1; a share is fitted in a "
                       "blend of two or more populations")
    if path.endswith("dye_depth_um"):
        if pop.dye_profile == "uniform":
            raise FitError(f"--free {name}: population {pop.name!r} has a uniform dye, which has no depth; give it "
                           "dye_profile = \"ring\" or \"core\" and a dye_depth_um in [populations.fiber]")
        own = (data["populations"][k].get("fiber") or {})
        if "dye_depth_um" not in own:
            raise FitError(f"--free {name}: population {pop.name!r} takes fiber.dye_depth_um of the config; give it "
                           "its own dye_profile and dye_depth_um in [populations.fiber] to free them")


def _narrowed_shares(free: list[FreeParameter], config: SimulationConfig) -> list[FreeParameter]:
    """The free shares checked and their default upper bounds narrowed (:func:`shares_at`).

    At least one population's share stays out of ``--free`` (it takes the remainder), and the free shares' upper
    bounds add up to below 1.
    """
    shares = [p for p in free if p.kind == "share"]
    if not shares:
        return free
    pops = config.populations or ()
    if len(shares) >= len(pops):
        raise FitError("--free: the shares of all the populations add up to 1, so one of them follows from the "
                       "others: leave one population's share out of --free (it takes the remainder)")
    rest = 1.0 - sum(p.start for p in shares)            # the shares of the populations whose share is not free
    fixed = len(pops) - len(shares)
    out = []
    for p in free:
        if p.kind == "share" and p.high == 1.0 - SHARE_MIN and p.low == SHARE_MIN:   # default bounds: narrowed
            high = p.start + (rest - SHARE_MIN * fixed) / len(shares)
            p = FreeParameter(p.name, p.start, p.low, max(high, p.start), p.kind)
        out.append(p)
    top = sum(p.high for p in out if p.kind == "share")
    if top > 1.0 - SHARE_MIN * fixed + 1e-12:
        raise FitError(f"--free: the free shares' upper bounds add up to {top:.6g}, leaving no share for the other "
                       f"population(s); give bounds that add up to at most {1.0 - SHARE_MIN * fixed:.6g}")
    low = [p for p in out if p.kind == "share" and p.low <= 0.0]
    if low:
        raise FitError(f"--free: {low[0].name}: a share's lower bound must be above 0 (a population of share 0 is "
                       f"no population), got {low[0].low:g}")
    return out


def shares_at(config: SimulationConfig, free: list[FreeParameter] | tuple[FreeParameter, ...],
              x: np.ndarray) -> dict[int, float]:
    """The shares of a blend's populations ``{index: share}`` at the free values ``x``.

    A free share is its value; the populations whose share is not free take the remainder ``1 - sum(free shares)``
    in proportion to their shares in the config (with two populations, the one free share moves both). Empty when no
    share is free.

    Parameters
    ----------
    config : SimulationConfig
        The config, a blend of populations.
    free : list or tuple of FreeParameter
        The free parameters.
    x : numpy.ndarray
        One value per free parameter.

    Returns
    -------
    dict of int to float
        Population index -> share.
    """
    pops = config.populations or ()
    free_k = {int(m.group(1)): float(v) for p, v in zip(free, x, strict=True) if (m := _POP_SHARE.match(p.name))}
    if not free_k:
        return {}
    rest = 1.0 - sum(free_k.values())
    fixed = {k: pops[k].share for k in range(len(pops)) if k not in free_k}
    total = sum(fixed.values())
    out = dict(free_k)
    for k, s in fixed.items():
        out[k] = rest * s / total
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


def model_geometries(measured: Dataset) -> pd.DataFrame:
    """The geometries the model is evaluated at: exactly the measured ones.

    Parameters
    ----------
    measured : Dataset
        The measurement.

    Returns
    -------
    pandas.DataFrame
        Columns ``theta_i``, ``phi_i``, ``theta_o``, ``phi_o`` (degrees), one row per geometry.
    """
    # exactly the measured geometries: compare then estimates the model's normal/normal value from
    # the same neighbours as the measurement's, so the estimate's own bias cancels in k(lambda)
    # (the model's exact normal value against an estimated measured one biased the fit)
    g = measured.table[["theta_i", "phi_i", "theta_o", "phi_o"]].drop_duplicates()
    return g.reset_index(drop=True)


def dye_ceiling(config: SimulationConfig, free: list[FreeParameter], wl: np.ndarray) -> float:
    """Largest host absorption (1/um) any dye within the bounds can reach (the table's nu_max).

    Parameters
    ----------
    config : SimulationConfig
        The start config.
    free : list of FreeParameter
        The free parameters (a free dye coefficient is taken at its bound).
    wl : numpy.ndarray
        The model wavelengths (nm).

    Returns
    -------
    float
        The largest host absorption (1/um).
    """
    if not config.populations:
        return _dye_top(config.dye, "fiber.dye", free, wl)
    # a blend: the largest over the config's dye and each population's own (their free coefficients at the bounds)
    tops = [_dye_top(config.dye, "fiber.dye", free, wl)]
    tops += [_dye_top(p.dye, f"populations[{k}].fiber.dye", free, wl)
             for k, p in enumerate(config.populations) if p.dye is not config.dye]
    return max(tops)


def _dye_top(dye, prefix: str, free: list[FreeParameter], wl: np.ndarray) -> float:
    """The largest host absorption of the dye at ``prefix`` with its free coefficients at their upper bounds."""
    if dye is None:
        return 1e-3
    p = copy.deepcopy(dye.params)
    root = {"dye": p}
    for f in free:
        if f.kind == "dye" and f.name.startswith(prefix + "."):
            rel = "dye." + f.name[len(prefix) + 1:]
            paths.set_value(root, rel, f.high if "_per_um" in f.name else paths.get(root, rel))
    if dye.curve == "gaussian-bands":
        top = p["baseline_per_um"] + sum(b["peak_per_um"] for b in p["bands"])
    elif dye.curve == "knots":  # PCHIP does not overshoot: the largest knot is the maximum
        top = 10.0 ** max(p["log10_per_um"])
    elif dye.curve == "logistic-edge":
        top = max(p["short_per_um"], p["long_per_um"])
    else:
        top = float(np.max(dye(wl)))
    return max(1.05 * top, 1e-3)


def checked_wavelengths(value: object) -> np.ndarray:
    """The model wavelengths (``--wavelengths``) as a float array: finite, in the dataset range, increasing.

    Parameters
    ----------
    value : object
        The wavelengths as given (nm).

    Returns
    -------
    numpy.ndarray
        The wavelengths (nm).

    Raises
    ------
    FitError
        For no wavelength, one that is not a number in the dataset range, or values not increasing.
    """
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


#: the models a :class:`FitSpec` evaluates (the Monte Carlo fit's coarse model is the summation)
SPEC_MODELS = ("classic", "summation")


@dataclass(frozen=True, eq=False)
class FitSpec:
    """What a fit fits, checked and frozen (:func:`make_spec`): no runner writes into it.

    ``measured`` is the measurement without its near-grazing rows (``notes`` say so); ``wavelengths_nm``
    the model wavelengths (the measurement's, or the config's for an RGB measurement); ``method`` the model
    evaluated (``classic`` or ``summation``; the Monte Carlo fit's coarse model is the summation, with
    ``fine_capable``: the fields only the Monte Carlo sees may be free).
    """

    config: SimulationConfig
    measured: Dataset
    free: tuple[FreeParameter, ...]
    method: str
    colour_weight: float
    #: the colour hold (:func:`colour_hold`) in the objective, when the measurement has a colour
    hold_colour: bool
    #: weight of ``(ln k_Y)^2``, the absolute level (``--absolute``: 1; 0: shapes and colour only)
    level_weight: float
    target_rel_err: float
    seed: int
    threads: int | None
    wavelengths_nm: np.ndarray
    nodes: int
    #: re-weight the lattice walk to other scattering parameters within the variance bound
    reweight: bool
    fine_capable: bool
    #: what the spec changed in the measurement (the near-grazing rows left out, interpolated incidences)
    notes: tuple[str, ...]

    @property
    def structured(self) -> bool:
        """The structured summation (:mod:`simulate.structwalk`) instead of the top cell's carpet."""
        return self.method == "summation" and getattr(self.config, "structure", None) is not None

    @property
    def names(self) -> list[str]:
        """The free parameters' names, in order."""
        return [p.name for p in self.free]


def make_spec(config: SimulationConfig, measured: Dataset, free: list[FreeParameter] | tuple[FreeParameter, ...], *,
              method: str = "classic", colour_weight: float = 1.0, hold_colour: bool = False,
              level_weight: float = 0.0, target_rel_err: float = 0.03, seed: int | None = None,
              threads: int | None = None, wavelengths_nm: object = None, nodes: int = DEFAULT_NODES,
              reweight: bool = True, fine_capable: bool = False) -> FitSpec:
    """The checked :class:`FitSpec` (:class:`~fabric_optics.fitting.errors.FitError`, one line, on bad input).

    ``seed`` defaults to the config's; ``wavelengths_nm`` to the measurement's (spectral) or the config's (RGB).
    Rows at ``theta_i >= 89`` deg are left out with a note (the rule of ``gonio import``).

    Parameters
    ----------
    config : SimulationConfig
        The start config.
    measured : Dataset
        The measurement.
    free : list or tuple of FreeParameter
        The free parameters (:func:`parse_free`).
    method : str, default "classic"
        The model: ``"classic"`` or ``"summation"``.
    colour_weight : float, default 1
        Weight ``w_c`` of the colour terms of the objective.
    hold_colour : bool, default False
        Hold the colour within its tolerance (:func:`colour_hold`).
    level_weight : float, default 0
        Weight of the absolute level (``--absolute``); 0 leaves it out.
    target_rel_err : float, default 0.03
        Relative standard error the Monte Carlo walks aim at.
    seed : int, optional
        Seed of the walks.
    threads : int, optional
        Threads of the walks (None: the default).
    wavelengths_nm : object, optional
        The model wavelengths (nm).
    nodes : int, default DEFAULT_NODES
        Host-absorption nodes of the absorption tables.
    reweight : bool, default True
        Re-weight walks between lattice points rather than walk them.
    fine_capable : bool, default False
        Whether the method sees the fine parameters (the Monte Carlo's).

    Returns
    -------
    FitSpec
        The spec, its measurement without the grazing rows.

    Raises
    ------
    FitError
        For a method, blend, placement, free parameter, wavelength or ``level_weight`` the fit cannot
        take.
    """
    _check_blend(config)
    _check_dye_placement(config, free, method)
    _check_scatterer_placement(config, free, method)
    if method not in SPEC_MODELS:
        raise FitError(f"--method must be classic or summation, got {method!r}")
    if level_weight and measured.relative:
        raise FitError("--absolute: the measurement is relative (\"relative\": true, raw units): it has no absolute "
                       "level to fit; drop --absolute")
    if method == "summation" and config.route == "bssrdf":
        raise FitError("the summation fit needs the nee or beam fiber route (fiber.route in the config)")
    if wavelengths_nm is None:
        spectral = "channel" not in measured.table.columns
        wavelengths_nm = (np.asarray(measured.wavelengths_nm, float) if spectral
                          else np.asarray(config.wavelengths_nm, float))
    wl = checked_wavelengths(wavelengths_nm)
    wl.setflags(write=False)
    structured = method == "summation" and getattr(config, "structure", None) is not None
    fine = [p.name for p in free if p.kind == "fine"]
    if fine and not fine_capable:
        raise FitError(f"--free {fine[0]}: only the Monte Carlo sees the rough boundary for transmitted light "
                       f"(the {method} model walks the smooth one, docs/physics.md 3); fit it with --method mc")
    if any(p.kind == "structure" for p in free) and not structured:
        raise FitError("--free structure.*: structure parameters need --method summation and a config with "
                       "a [structure] section")
    notes: list[str] = []
    measured = _without_grazing(measured, notes)
    incidences = (measured.meta.get("sample") or {}).get("incidences") or {}
    if incidences.get("interpolated_deg"):
        notes.append(f"the measurement's incidences {', '.join(f'{t:g}' for t in incidences['interpolated_deg'])} "
                     f"deg are {incidences.get('source', 'the file')}'s interpolation between its measured "
                     "tables, not measured (a plan of its measured incidences: --plan measured)")
    return FitSpec(config=config, measured=measured, free=tuple(free), method=method,
                   colour_weight=float(colour_weight), hold_colour=bool(hold_colour), level_weight=float(level_weight),
                   target_rel_err=float(target_rel_err), seed=int(config.seed if seed is None else seed),
                   threads=threads, wavelengths_nm=wl, nodes=int(nodes), reweight=bool(reweight),
                   fine_capable=bool(fine_capable), notes=tuple(notes))


#: the fields a fitted blend's populations share (the fit walks one fiber's scattering for all of them)
SHARED_FIELDS = (("fiber.radius_um", "radius_um"), ("fiber.n_host", "n_host"), ("particles", "particles"),
                 ("surface.rms_slope", "rms_slope"), ("surface.transmission_rms_slope", "transmission_rms_slope"),
                 ("surface.transmission_rms_slope_around", "transmission_rms_slope_around"))


def _check_blend(config: SimulationConfig) -> None:
    """A blend is fitted when its populations differ in dye and share only.

    One walk of the fiber's scattering serves them all (each population's dye read from the same absorption table).
    Otherwise one line naming the field.
    """
    pops = config.populations or ()
    for p in pops[1:]:
        for label, attr in SHARED_FIELDS:
            if getattr(p, attr) != getattr(pops[0], attr):
                raise FitError(f"{_file(config)}: populations: simulate fit takes a blend whose populations differ in "
                               f"dye and share only; {pops[0].name!r} and {p.name!r} differ in {label}: give them the "
                               "same, or fit each population's fiber alone")


def _file(config: SimulationConfig) -> str:
    """The config's file name as its messages name it (a preset: ``NAME.toml``)."""
    source = config.source
    return f"{source[len('preset '):]}.toml" if source.startswith("preset ") else Path(source).name


def _check_dye_placement(config: SimulationConfig, free: list[FreeParameter] | tuple[FreeParameter, ...],
                         method: str) -> None:
    """Check a ring or core dye (``dye_profile``) and its depth against what the fit can score.

    The fit's absorption tables score the dye in its region (:mod:`simulate.fiber.absorption`) through exit
    tallies, which the classic model's albedo and the structured summation walk; the top cell's next-event
    summation (a config without ``[structure]``) cannot. One walk serves every population of a blend, so their
    dyes must sit alike (the config's profile and depth). One line each.
    """
    depth = [p.name for p in free if p.name.endswith("dye_depth_um")]
    parts = [c for _, c in config.population_configs()]
    placed = [c for c in parts if c.dye_profile != "uniform"]
    if not depth and not placed:
        return
    if method == "summation" and getattr(config, "structure", None) is None:
        what = f"--free {depth[0]}" if depth else f"{_file(config)}: fiber.dye_profile = {placed[0].dye_profile!r}"
        raise FitError(f"{what}: the summation of a config without [structure] reads the top cell by next events, "
                       "which assume a dye through the fiber; fit a ring or core dye with --method classic or a "
                       "config with a [structure] section (the structured summation)")
    pops = config.populations or ()
    for p in pops:
        if (p.dye_profile, p.dye_depth_um) != (config.dye_profile, config.dye_depth_um):
            raise FitError(f"{_file(config)}: populations: population {p.name!r} places its dye otherwise than "
                           f"[fiber] (dye_profile {p.dye_profile!r}, dye_depth_um {p.dye_depth_um:g}); the fit walks one "
                           "fiber's paths for every population, so give them the config's dye_profile and "
                           "dye_depth_um")
    for name in depth:
        if name.startswith("populations"):
            raise FitError(f"--free {name}: the fit walks one fiber's paths for every population, whose dyes sit "
                           "alike; free the depth they share, fiber.dye_depth_um")
        if config.dye_profile == "uniform":
            raise FitError(f"--free {name}: {_file(config)} has a uniform dye (fiber.dye_profile), which has no "
                           "depth; give it dye_profile = \"ring\" or \"core\" and a dye_depth_um")


def _no_scatterer_depth(name: str, config: SimulationConfig) -> str:
    """The one line refusing a free scatterer depth of a config whose scatterers fill the fiber."""
    return (f"--free {name}: {_file(config)} has its scatterers through the fiber (fiber.scatterer_profile "
            "\"uniform\"), which have no depth; give it scatterer_profile = \"skin\" or \"core\" and a "
            "scatterer_depth_um")


def _check_scatterer_placement(config: SimulationConfig, free: list[FreeParameter] | tuple[FreeParameter, ...],
                               method: str) -> None:
    """Check a skin or core of scatterers (``scatterer_profile``) and its free depth against what the fit can score.

    Like a placed dye's (:func:`_check_dye_placement`): the exit tallies of the classic model's albedo and of the
    structured summation walk it, the top cell's next-event summation (a config without ``[structure]``) cannot.
    Every population shares the config's placement, so only ``fiber.scatterer_depth_um`` is freed. One line each.
    """
    depth = [p.name for p in free if p.name.endswith("scatterer_depth_um")]
    profile = getattr(config, "scatterer_profile", "uniform")
    for name in depth:
        if name != "fiber.scatterer_depth_um":
            raise FitError(f"--free {name}: every population shares the config's scatterer placement; free "
                           "fiber.scatterer_depth_um")
        if profile == "uniform":
            raise FitError(_no_scatterer_depth(name, config))
    if (depth or profile != "uniform") and method == "summation" and getattr(config, "structure", None) is None:
        what = f"--free {depth[0]}" if depth else f"{_file(config)}: fiber.scatterer_profile = {profile!r}"
        raise FitError(f"{what}: the summation of a config without [structure] reads the top cell by next events, "
                       "which assume scatterers through the fiber; fit a skin or core of scatterers with --method "
                       "classic or a config with a [structure] section (the structured summation)")


def _without_grazing(measured: Dataset, notes: list[str]) -> Dataset:
    """The grazing rule of ``gonio import`` (:data:`gonio.data.formats.GRAZING_DEG`).

    Rows at ``theta_i >= 89`` deg are left out of the fit with a note (a file imported with ``--keep-grazing`` keeps
    them; no fabric model is meant for them: the projected area vanishes, Cook-Torrance leaves its domain); a
    measurement with nothing else is refused.
    """
    t = measured.table
    grazing = t["theta_i"].to_numpy(float) >= GRAZING_DEG
    if not grazing.any():
        return measured
    if grazing.all():
        raise FitError(f"every incidence of the measurement is >= {GRAZING_DEG:g} deg (near grazing), where "
                       "no fabric model is meant to be fitted")
    angles = ", ".join(f"{a:.10g}" for a in np.unique(t["theta_i"].to_numpy(float)[grazing]))
    notes.append(f"{int(grazing.sum())} rows of the measurement at incidence >= {GRAZING_DEG:g} deg "
                 f"(theta_i {angles}) are left out of the fit (near grazing: the rule of gonio import)")
    log.warning("%s", notes[-1])
    return Dataset(t[~grazing].reset_index(drop=True), measured.meta, measured.path)
