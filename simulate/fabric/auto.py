"""Model no more than the scene needs: which fabric method is good enough at which geometry.

``simulate fabric --method auto`` evaluates, per geometry, the cheapest of classic, summation and
the woven Monte Carlo whose error against the Monte Carlo reference is within the requested
accuracy. The errors come from the bench's "where methods fail" study (:mod:`fabric_optics.bench.method_errors`,
run by ``simulate bench``): for every geometry of the red-cotton plan, the RMS over wavelengths of
``(model - MC) / max_lambda(MC)`` -- the same spectral-peak convention as the accuracy target.

The rule: the table is chosen by the config's structure kind (:data:`TABLES`). A woven fabric
(``[structure] kind = "woven"``) reads ``simulate/configs/method-errors.json`` (red cotton against the
woven Monte Carlo); a felt (``kind = "nonwoven"``) reads ``simulate/configs/method-errors-felt.json``
(the green felt against the felt Monte Carlo). A config of no studied kind (no ``[structure]`` table)
gets the Monte Carlo at every geometry, with one logged line saying why: an unknown error is not a
small one.

A blend (``[[populations]]`` of two or more) is judged by its kind's blend study (:data:`BLEND_TABLES`: a
felt's ``simulate/configs/method-errors-felt-blend.json``, the green felt as two populations of different
dyes against the felt Monte Carlo of the blend; a weave's ``simulate/configs/method-errors-woven-blend.json``,
red cotton as two populations of one dye at two strengths against the woven Monte Carlo of the blend). It
holds when the blend lies within the studied range: its populations differ in their dye only (and its
placement), and their :func:`dye_spread` is at most the studied blend's (``provenance.dye_spread`` of the
study). The cheaper models mix the populations' results by share (two fabrics side by side) where the Monte
Carlo draws each fiber (a felt) or each yarn (a weave) a path meets from the populations, so their error may
grow with how differently the populations absorb. A felt blend within its study reads the study's own
departures, which are larger than the one-population felt's. A woven blend within its study reads the
one-population woven table (:data:`BLEND_DEPARTURES`): the study found the summation's departures the one
population's within their errors, and the one-population table's Monte Carlo is the more precise. A blend
beyond the studied spread or of populations that differ in more than their dye gets the Monte Carlo at every
geometry, with one logged line saying why.

Within a table, a geometry farther than ``MATCH_DEG`` from every studied one, or at another incidence,
gets the Monte Carlo too. Each table is one fabric's: a sample far from it
should regenerate its own (``python -m fabric_optics.bench.method_errors``) and pass it through
``choose(..., errors=...)``. The chosen table's provenance goes into the dataset's meta.
"""

from __future__ import annotations

import json
import logging
import math
from importlib import resources
from typing import Any

import numpy as np

from simulate.optics.microfacet import directions_deg

__all__ = ["CHEAPEST_FIRST", "MATCH_DEG", "TABLES", "BLEND_TABLES", "BLEND_DEPARTURES", "table_for", "errors_for",
           "load_errors", "choose", "dye_spread", "blend_outside"]

log = logging.getLogger(__name__)

#: cheapest first (the order ``auto`` tries them)
CHEAPEST_FIRST = ("classic", "summation", "mc")
#: a geometry must lie within this angle (observation direction, same incidence) of a studied one
MATCH_DEG = 6.0
#: the method-errors table (under simulate/configs) of each studied structure kind
TABLES = {"woven": "method-errors.json", "nonwoven": "method-errors-felt.json"}
#: the method-errors study of a blend (``[[populations]]`` of two or more) of each studied structure kind: its
#: ``provenance.dye_spread`` bounds the blends it holds for (:func:`blend_outside`)
BLEND_TABLES = {"nonwoven": "method-errors-felt-blend.json", "woven": "method-errors-woven-blend.json"}
#: the kinds whose blend study found the cheaper models' departures their one-population table's (within the
#: errors of the two Monte Carlo references): a blend within the study reads this table's departures
BLEND_DEPARTURES = {"woven": "method-errors.json"}
#: the wavelengths (nm) :func:`dye_spread` reads the populations' dyes at
SPREAD_WAVELENGTHS = tuple(float(w) for w in np.arange(390.0, 711.0, 10.0))
#: what a blend's populations may differ in for a blend table to hold (:func:`blend_outside`)
_SAME = (("radius_um", "fiber.radius_um"), ("n_host", "fiber.n_host"), ("particles", "particles"),
         ("rms_slope", "surface.rms_slope"), ("transmission_rms_slope", "surface.transmission_rms_slope"),
         ("transmission_rms_slope_around", "surface.transmission_rms_slope_around"))


def _is_blend(config: Any) -> bool:
    return len(getattr(config, "populations", None) or ()) > 1


def table_for(config: Any) -> str | None:
    """The shipped method-errors table's file name for ``config``, by its ``[structure] kind``.

    A blend's is its kind's blend study (:data:`BLEND_TABLES`). Whether a blend lies within the study is
    :func:`blend_outside`'s; which departures a blend within it reads, :func:`errors_for`'s.

    Parameters
    ----------
    config : SimulationConfig
        The fabric's config.

    Returns
    -------
    str or None
        The table's file name, None for a config without ``[structure]`` or of no studied kind.
    """
    kind = getattr(getattr(config, "structure", None), "kind", None)
    tables = BLEND_TABLES if _is_blend(config) else TABLES
    return None if kind is None else tables.get(kind)


def no_study(config: Any, why: str | None = None) -> dict:
    """The empty table of a config of no studied kind, or of a blend outside its study.

    With it every geometry gets the Monte Carlo; the reason is logged on one line.

    Parameters
    ----------
    config : SimulationConfig
        The fabric's config.
    why : str, optional
        Why the blend lies outside its study (:func:`blend_outside`); None: the config's kind has no study.

    Returns
    -------
    dict
        A table with no geometries, its ``provenance`` holding the logged reason.
    """
    if why is None:
        structure = getattr(config, "structure", None)
        kind = "no [structure] table" if structure is None else f'[structure] kind = "{structure.kind}"'
        tables = BLEND_TABLES if _is_blend(config) else TABLES
        what = "a blend ([[populations]]) of " if _is_blend(config) else ""
        why = (f"no method-errors study for {what}{kind} (studied: "
               + ", ".join(f'kind = "{k}"' for k in tables) + ")")
    reason = f"--method auto: {why}; the Monte Carlo at every geometry"
    log.warning(reason)
    return {"provenance": {"table": None, "reason": reason}, "geometries": []}


def dye_spread(config: Any, wavelengths_nm: Any = SPREAD_WAVELENGTHS) -> float:
    """How differently a blend's populations absorb, from 0 (alike) to 0.5.

    The largest, over ``wavelengths_nm``, of the share-weighted standard deviation of the populations'
    transmittance along a fiber's mean dyed chord.

    Each population's transmittance is ``exp(-mu_dye(lambda) A_dyed / (2 r))``: its dye's absorption over
    the mean length a straight line across the fiber spends in the dyed region (the dyed area of the
    section over the fiber's width: ``pi r / 2`` for a dye through the fiber, the ring's or core's area
    over ``2 r`` for a placed one). 0 for one population or populations of one dye; 0.5 at most.

    Parameters
    ----------
    config : SimulationConfig
        The blend's config (its ``population_configs()``).
    wavelengths_nm : array_like
        The wavelengths (nm) the spread is taken over.

    Returns
    -------
    float
        The dye spread.
    """
    wl = np.asarray(wavelengths_nm, float)
    shares, trans = [], []
    for share, c in config.population_configs():
        r = float(c.radius_um)
        if c.dye_profile == "uniform" or c.dye is None:
            area = math.pi * r * r
        else:
            inner = r - float(c.dye_depth_um)
            area = math.pi * (r * r - inner * inner) if c.dye_profile == "ring" else math.pi * inner * inner
        mu = np.zeros(wl.size) if c.dye is None else np.asarray(c.dye(wl), float)
        shares.append(float(share))
        trans.append(np.exp(-mu * area / (2.0 * r)))
    s = np.asarray(shares)[:, None] / sum(shares)
    t = np.asarray(trans)
    mean = (s * t).sum(axis=0)
    return float(np.sqrt((s * (t - mean) ** 2).sum(axis=0)).max())


def blend_outside(config: Any, errors: dict) -> str | None:
    """Why a blend lies outside a blend study, or None within it.

    A blend lies outside when its populations differ in more than their dye, or when their
    :func:`dye_spread` exceeds the study's ``provenance.dye_spread``.

    Parameters
    ----------
    config : SimulationConfig
        The blend's config (its ``populations``).
    errors : dict
        The blend study (:func:`load_errors`).

    Returns
    -------
    str or None
        The reason, one line, or None when the study holds for the blend.
    """
    pops = config.populations
    for attr, label in _SAME:
        # by their text: a particle spectrum holds arrays
        other = next((p for p in pops[1:] if repr(getattr(p, attr)) != repr(getattr(pops[0], attr))), None)
        if other is not None:
            return (f"the blend's populations differ in {label} ({pops[0].name!r} and {other.name!r}), the studied "
                    "blends in their dye only")
    studied = float(errors.get("provenance", {}).get("dye_spread", 0.0))
    spread = dye_spread(config)
    if spread > studied + 1e-9:
        return (f"the blend's populations absorb more differently (dye spread {spread:.3f}) than the studied "
                f"blend's ({studied:.3f}, {errors.get('provenance', {}).get('table')}), where the cheaper models' "
                "mix of the populations departs most from the Monte Carlo")
    return None


def load_errors(path: Any = None, name: str = "method-errors.json") -> dict:
    """A method-errors study: a shipped one by file name, or one written to a path.

    Parameters
    ----------
    path : str or os.PathLike, optional
        A study written by :func:`fabric_optics.bench.method_errors.errors_from_report`; None: the shipped
        study ``name``.
    name : str
        The shipped study's file name in ``simulate.configs`` (red cotton's by default).

    Returns
    -------
    dict
        The study: ``provenance`` (a shipped one's with its ``table`` name) and ``geometries``.
    """
    if path is None:
        text = resources.files("simulate.configs").joinpath(name).read_text()
        out = json.loads(text)
        out.setdefault("provenance", {})["table"] = name
        return out
    with open(path) as fh:
        return json.loads(fh.read())


def errors_for(config: Any) -> dict:
    """The table ``--method auto`` reads for ``config`` (:func:`table_for`; the rule in the module's text).

    A blend within its study reads the study (or, for a kind of :data:`BLEND_DEPARTURES`, that table, its
    provenance's ``blend_study`` naming the study); its ``provenance.config_dye_spread`` is the blend's spread.
    """
    name = table_for(config)
    if name is None:
        return no_study(config)
    errors = load_errors(name=name)
    if _is_blend(config):
        why = blend_outside(config, errors)
        if why is not None:
            return no_study(config, why)
        kind = config.structure.kind
        if kind in BLEND_DEPARTURES:
            # the blend study holds for this blend and found its departures the one population's
            study = errors["provenance"]
            errors = load_errors(name=BLEND_DEPARTURES[kind])
            errors["provenance"]["blend_study"] = {k: study.get(k) for k in ("table", "study", "blend", "dye_spread")}
        errors["provenance"]["config_dye_spread"] = dye_spread(config)
    return errors


def choose(theta_i: Any, phi_i: Any, theta_o: Any, phi_o: Any, target: float,
           errors: dict | None = None) -> tuple[np.ndarray, dict]:
    """Per geometry the cheapest method within ``target``; returns the names and the study's provenance."""
    errors = load_errors() if errors is None else errors
    ti = np.asarray(theta_i, float)
    rel = np.asarray(phi_o, float) - np.asarray(phi_i, float)
    w = directions_deg(np.asarray(theta_o, float), rel)
    rows = errors["geometries"]
    out = np.full(ti.size, "mc", dtype=object)
    if not rows:
        return out.astype(str), errors.get("provenance", {})
    s_ti = np.array([r["theta_i"] for r in rows])
    s_w = directions_deg(np.array([r["theta_o"] for r in rows]), np.array([r["rel_phi_o"] for r in rows]))
    cos_match = math.cos(math.radians(MATCH_DEG))
    for g in range(ti.size):
        cand = np.nonzero(np.abs(s_ti - ti[g]) < 0.5)[0]
        if cand.size == 0:
            continue
        dots = s_w[cand] @ w[g]
        best = cand[int(np.argmax(dots))]
        if dots.max() < cos_match:
            continue
        for m in CHEAPEST_FIRST[:-1]:
            if rows[best][m] <= target:
                out[g] = m
                break
    return out.astype(str), errors.get("provenance", {})
