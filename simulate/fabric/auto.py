"""Model no more than the scene needs: which fabric method is good enough at which geometry.

``simulate fabric --method auto`` evaluates, per geometry, the cheapest of classic, summation and
the woven Monte Carlo whose error against the Monte Carlo reference is within the requested
accuracy. The errors come from the bench's "where methods fail" study (:mod:`fabric_optics.bench.method_errors`,
run by ``simulate bench``): for every geometry of the red-cotton plan, the RMS over wavelengths of
``(model - MC) / max_lambda(MC)`` -- the same spectral-peak convention as the accuracy target.
The shipped table (``simulate/configs/method-errors.json``, its provenance inside) is for the
red-cotton fabric; a geometry farther than ``MATCH_DEG`` from every studied one, or another
incidence, gets the Monte Carlo (an unknown error is not a small one).

Decision: the study is per fabric; a sample far from red cotton should regenerate it with
``simulate bench`` and pass it through ``choose(..., errors=...)``.
"""

from __future__ import annotations

import json
import math
from importlib import resources
from typing import Any

import numpy as np

from simulate.optics.microfacet import directions_deg

__all__ = ["CHEAPEST_FIRST", "MATCH_DEG", "load_errors", "choose"]

#: cheapest first (the order ``auto`` tries them)
CHEAPEST_FIRST = ("classic", "summation", "mc")
#: a geometry must lie within this angle (observation direction, same incidence) of a studied one
MATCH_DEG = 6.0


def load_errors(path: Any = None) -> dict:
    """The shipped study (or one written by :func:`fabric_optics.bench.method_errors.errors_from_report`)."""
    if path is None:
        text = resources.files("simulate.configs").joinpath("method-errors.json").read_text()
    else:
        with open(path) as fh:
            text = fh.read()
    return json.loads(text)


def choose(theta_i: Any, phi_i: Any, theta_o: Any, phi_o: Any, target: float,
           errors: dict | None = None) -> tuple[np.ndarray, dict]:
    """Per geometry the cheapest method within ``target``; returns the names and the study's provenance."""
    errors = load_errors() if errors is None else errors
    ti = np.asarray(theta_i, float)
    rel = np.asarray(phi_o, float) - np.asarray(phi_i, float)
    w = directions_deg(np.asarray(theta_o, float), rel)
    rows = errors["geometries"]
    s_ti = np.array([r["theta_i"] for r in rows])
    s_w = directions_deg(np.array([r["theta_o"] for r in rows]), np.array([r["rel_phi_o"] for r in rows]))
    out = np.full(ti.size, "mc", dtype=object)
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
