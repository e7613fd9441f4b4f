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
small one. Within a table, a geometry farther than ``MATCH_DEG`` from every studied one, or at
another incidence, gets the Monte Carlo too. Each table is one fabric's: a sample far from it
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

__all__ = ["CHEAPEST_FIRST", "MATCH_DEG", "TABLES", "table_for", "errors_for", "load_errors", "choose"]

log = logging.getLogger(__name__)

#: cheapest first (the order ``auto`` tries them)
CHEAPEST_FIRST = ("classic", "summation", "mc")
#: a geometry must lie within this angle (observation direction, same incidence) of a studied one
MATCH_DEG = 6.0
#: the method-errors table (under simulate/configs) of each studied structure kind
TABLES = {"woven": "method-errors.json", "nonwoven": "method-errors-felt.json"}


def table_for(config: Any) -> str | None:
    """The shipped table's file name for ``config`` (by its ``[structure] kind``), None for no studied kind."""
    structure = getattr(config, "structure", None)
    return None if structure is None else TABLES.get(getattr(structure, "kind", None))


def no_study(config: Any) -> dict:
    """The empty table of a config of no studied kind (every geometry gets the Monte Carlo), logged once."""
    structure = getattr(config, "structure", None)
    kind = "no [structure] table" if structure is None else f'[structure] kind = "{structure.kind}"'
    reason = (f"--method auto: no method-errors study for {kind} (studied: "
              + ", ".join(f'kind = "{k}"' for k in TABLES) + "); the Monte Carlo at every geometry")
    log.warning(reason)
    return {"provenance": {"table": None, "reason": reason}, "geometries": []}


def load_errors(path: Any = None, name: str = "method-errors.json") -> dict:
    """A shipped study by file ``name`` (red cotton's by default), or the one at ``path`` (written by
    :func:`fabric_optics.bench.method_errors.errors_from_report`)."""
    if path is None:
        text = resources.files("simulate.configs").joinpath(name).read_text()
        out = json.loads(text)
        out.setdefault("provenance", {})["table"] = name
        return out
    with open(path) as fh:
        return json.loads(fh.read())


def errors_for(config: Any) -> dict:
    """The table ``--method auto`` reads for ``config`` (:func:`table_for`; the rule in the module's text)."""
    name = table_for(config)
    return no_study(config) if name is None else load_errors(name=name)


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
