r"""``simulate fit``: fit named config parameters of a fabric model to a measurement (the inverse problem).

``simulate fit CONFIG MEASURED_DIR --free NAME[=LOW:HIGH],... --out DIR [--method summation|classic]``

Parameters
----------
A free parameter is a numeric field of the config, named by its dotted TOML path with list
indices (``particles.volume_fraction``, ``particles.size.median_radius_um``,
``surface.rms_slope``, ``fiber.dye.bands[0].peak_per_um``, ``fiber.dye.edge_nm``, ...), or an
alias: ``volume_fraction``, ``radius`` (the particle radius or median radius), ``rms_slope``,
``dye`` (every coefficient of the config's smooth dye curve: baseline, band centres, widths and
peaks, or the logistic edge's four), ``dye-peaks`` (only the dye's amplitudes: baseline and peaks,
or short/long). Bounds default per kind (:func:`default_bounds`); explicit ``=LOW:HIGH`` wins.
The dye must be a named smooth curve (``gaussian-bands``/``logistic-edge``): a few coefficients
describe a smooth spectrum, a free table would be an ill-posed fit of 30 values.

Objective (weights)
-------------------
Exactly the figures ``compare`` reports: per evaluation the model is written as a dataset at the
measured geometries (only those: the normal/normal value of both is estimated alike) and
:func:`compare.comparison.compare_datasets` normalises it at the normal direction and computes the
overall curve error and the colour match (no re-implementation). The residual vector is::

    r = [ (k C_j - beta_meas,j) / (mean(beta_meas) sqrt(N)) ]_j  ++  sqrt(w_c) [dh, ds]

so ``F = |r|^2 = NRMSE^2 + w_c (dh^2 + ds^2)``: the overall NRMSE squared plus the hue
difference (turns, on the circle) and saturation difference squared at compare's colour
geometry, with ``w_c = 1`` by default (``--colour-weight``). With ``w_c = 1`` a hue error of
0.01 turn (3.6 deg) costs as much as 1 % NRMSE: both are just noticeable. V is left out: it is
set by the luminance scale ``k_Y`` (and undefined for relative measurements); a photometric
measurement has no colour terms.

Monte Carlo noise
-----------------
Only the particles / fiber geometry need photons to be walked. Every walk uses the same seeds
per (incident direction, wavelength group) and, after the first (accuracy-controlled) one, the
same photon counts: common random numbers, so the objective is a smooth function of the
parameters up to rare discrete events, not a fresh noise sample per evaluation. The dye is
re-weighted, never walked: every walk stores the volume term at 16 host absorptions per
wavelength (:mod:`simulate.fiber.absorption`) and any dye spectrum is read from that table, so a
dye-only fit walks photons once; the surface RMS slope enters through the analytic
Cook-Torrance term only. Finite-difference Jacobians: central, step 10^-3 of the bound range, for
dye and surface parameters (the table is C1); forward, step 10 % of the value, for walked
parameters. Common random numbers reduce but do not remove the Monte Carlo noise of a re-walked
objective (a change of mu_s moves every photon path): measured on red cotton's volume fraction at
5 % photon error, a 3 % step gave a slope of the wrong sign (the noise), 10 % the trend, and the
walked-parameter recovery test converges with it.

Optimiser
---------
``scipy.optimize.least_squares`` (trust-region reflective, bounded) in coordinates scaled to
``[0, 1]`` by the bounds: the objective is a sum of squares with a cheap exact structure and
few parameters, where Gauss-Newton converges in a handful of Jacobians -- decisive when a
Jacobian costs a walk per scattering parameter. Band centres and edges can make it multimodal
(a band can slide to either side of a spectral feature): ``--starts N`` adds N-1 Latin-hypercube
starts (``scipy.stats.qmc``) inside the bounds and keeps the best -- cheap for dye-only fits,
where no photon is walked; a global evolutionary method would spend thousands of evaluations,
which a walked parameter cannot afford.

Uncertainties
-------------
Linear propagation at the solution with the Jacobian ``J`` (``dp = -J^+ dr``): the measurement's
``u_beta`` by sampling 64 noise draws of the measured dataset, each run through the whole
objective (normalisation and colour included, so their correlations are exact to first order),
and the model's Monte Carlo standard error the same way (table values perturbed by their
standard errors, per output and wavelength). ``u`` = square root of the diagonal of the summed
covariance; correlations from it. A parameter is flagged not identifiable when the scaled
Jacobian has a flat direction (singular value below 10^-3 of the largest: the direction is
named) or its uncertainty exceeds half its bound range.

Interrupt and resume
--------------------
The last accepted point (the best objective so far: trust-region steps are accepted only when
they lower it) is written atomically to ``DIR/fit-state.json`` after every improvement, with the
photon counts; ``--resume`` starts from it (refused when the config, measurement, method or
free parameters differ). Ctrl-C leaves that state behind (exit 130).

Outputs in DIR: ``fitted.toml`` (the fitted config, ready for ``simulate fabric``),
``initial/`` and ``fitted/`` (datasets of the model at the start and the fitted parameters, at
the measured geometries), ``report/`` (``compare report`` of measurement vs initial vs fitted),
``fit.json`` (parameters, uncertainties, correlations, objective, warnings, evaluations, walks,
times) and ``fit-state.json``.
"""

from __future__ import annotations

import json
import logging
import math
import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np

from gonio.data.dataset import make_dataset

from studies.fit_problem import GENERATOR, FitError, FitProblem, FreeParameter, default_bounds, parse_free
from studies.fit_start import inverted_start
from studies.paths import toml_dumps

__all__ = [
    "FitError",
    "FreeParameter",
    "FitProblem",
    "FitResult",
    "GENERATOR",
    "STATE_NAME",
    "default_bounds",
    "parse_free",
    "run_fit",
    "toml_dumps",
    "write_outputs",
]

log = logging.getLogger(__name__)

STATE_NAME = "fit-state.json"
STATE_SCHEMA = "simulate-fit-state/1"
_NOISE_DRAWS = 64
_FLAT = 1e-3
_WALK_STEP = 0.10
_CHEAP_STEP = 1e-3


# ------------------------------------------------------------------------------------------
# the fit


@dataclass
class FitResult:
    """A finished fit (see :func:`run_fit`)."""

    x: np.ndarray
    start: np.ndarray
    objective: float
    objective_start: float
    u: np.ndarray
    u_data: np.ndarray
    u_mc: np.ndarray
    correlation: np.ndarray
    warnings: list[str]
    info: dict


def _write_json_atomic(path: Path, doc: dict) -> None:
    tmp = path.with_name(f".{path.name}.tmp")
    with open(tmp, "w", encoding="utf-8") as fh:
        json.dump(doc, fh, indent=1)
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, path)


def load_state(out: Path, problem: FitProblem) -> dict | None:
    """The saved state of an interrupted fit of the same problem, or raise FitError."""
    path = out / STATE_NAME
    try:
        state = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        return None
    except (OSError, ValueError) as exc:
        raise FitError(f"--resume: cannot read {path} ({exc})") from None
    if state.get("schema") != STATE_SCHEMA or state.get("identity") != problem.identity():
        raise FitError(f"--resume: {path} belongs to a different fit (config, measurement, method, seed or "
                       "free parameters differ); use a new --out or drop --resume")
    return state


def _jacobian(problem: FitProblem, x: np.ndarray, r0: np.ndarray, fun: Callable) -> np.ndarray:
    """d r / d x (physical units) by finite differences (steps in the module docstring)."""
    J = np.zeros((r0.size, x.size))
    for j, p in enumerate(problem.free):
        span = p.high - p.low
        if p.kind == "walk":
            h = max(_WALK_STEP * abs(x[j]), 1e-3 * span)
            if x[j] + h > p.high:
                h = -h
            J[:, j] = (fun(_with(x, j, x[j] + h)) - r0) / h
        else:
            h = _CHEAP_STEP * span
            lo, hi = max(x[j] - h, p.low), min(x[j] + h, p.high)
            J[:, j] = (fun(_with(x, j, hi)) - fun(_with(x, j, lo))) / (hi - lo)
    return J


def _with(x: np.ndarray, j: int, v: float) -> np.ndarray:
    y = x.copy()
    y[j] = v
    return y


def run_fit(problem: FitProblem, *, out: Path | None = None, resume: bool = False, max_evaluations: int = 60,
            starts: int = 1, progress: bool = False, noise_draws: int = _NOISE_DRAWS,
            invert_start: bool = True) -> FitResult:
    """Fit ``problem`` with ``scipy.optimize.least_squares`` (module docstring); state in ``out``."""
    from scipy.optimize import least_squares
    from tqdm import tqdm

    t0 = time.perf_counter()
    span = problem.high - problem.low
    x0 = problem.start.copy()
    state = load_state(out, problem) if (resume and out is not None) else None
    start_note = ""
    if state is not None:
        x0 = np.clip(np.array(state["x"], float), problem.low, problem.high)
        problem.photons = state.get("photons")
        log.info("resuming from the last accepted point (objective %.6g)", state["objective"])
    elif invert_start:
        x0, start_note = inverted_start(problem, x0)
    best: dict[str, Any] = {"F": math.inf, "x": x0.copy()}
    bar = tqdm(total=None, desc="fit", unit="eval", disable=not progress, leave=False)

    def phys(u: np.ndarray) -> np.ndarray:
        return problem.low + np.clip(u, 0.0, 1.0) * span

    def fun_x(x: np.ndarray) -> np.ndarray:
        return problem.residuals(x)

    def accept(x: np.ndarray, r: np.ndarray) -> None:
        F = float(r @ r)
        bar.update(1)
        if F < best["F"]:
            best.update(F=F, x=x.copy())
            bar.set_postfix(objective=f"{F:.5g}", walks=problem.walks)
            if out is not None:
                _write_json_atomic(out / STATE_NAME, {
                    "schema": STATE_SCHEMA, "identity": problem.identity(), "x": x.tolist(),
                    "names": [p.name for p in problem.free], "objective": F, "photons": problem.photons,
                    "evaluations": problem.evaluations})

    def fun_u(u: np.ndarray) -> np.ndarray:
        x = phys(u)
        r = fun_x(x)
        accept(x, r)
        return r

    def jac_u(u: np.ndarray) -> np.ndarray:
        x = phys(u)
        J = _jacobian(problem, x, fun_x(x), fun_x)
        bar.update(1)
        return J * span[None, :]

    r_start = fun_x(problem.start)
    F_start = float(r_start @ r_start)
    starts_u = [(x0 - problem.low) / span]
    if starts > 1 and state is None:
        from scipy.stats import qmc

        starts_u += list(qmc.LatinHypercube(d=x0.size, seed=int(problem.seed or 0)).random(starts - 1))
    results = []
    try:
        for su in starts_u:
            results.append(least_squares(fun_u, np.clip(su, 0.0, 1.0), jac=jac_u, bounds=(0.0, 1.0), method="trf",
                                         x_scale=1.0, max_nfev=max_evaluations, ftol=1e-8, xtol=1e-8, gtol=1e-10))
    finally:
        bar.close()
    x_best = best["x"]
    r_best = fun_x(x_best)
    J = _jacobian(problem, x_best, r_best, fun_x)
    pinv = np.linalg.pinv(J)

    # uncertainty: data noise and Monte Carlo noise propagated through the whole objective
    rng = np.random.default_rng(20260101 + int(problem.seed or 0))
    meas = problem.measured
    dp_data = []
    for _ in range(noise_draws):
        table = meas.table.copy()
        table["beta"] = table["beta"] + rng.standard_normal(len(table)) * table["u_beta"]
        noisy = make_dataset(table, meas.meta)
        dp_data.append(-pinv @ (problem.residuals(x_best, measured=noisy) - r_best))
    beta_shape = problem.table(problem.config_at(x_best)).R.shape[:2]
    dp_mc = [-pinv @ (problem.residuals(x_best, mc_noise=rng.standard_normal(beta_shape)) - r_best)
             for _ in range(noise_draws)]
    cov_data = np.atleast_2d(np.cov(np.array(dp_data).T, bias=True))
    cov_mc = np.atleast_2d(np.cov(np.array(dp_mc).T, bias=True))
    cov = cov_data + cov_mc
    u = np.sqrt(np.maximum(np.diag(cov), 0.0))
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov / np.outer(u, u)
    corr[~np.isfinite(corr)] = 0.0
    notes = _identifiability(problem, J, u)
    for note in notes:
        log.warning("%s", note)
    info = {
        "optimiser": "scipy.optimize.least_squares (trf, bounds scaled to [0, 1])",
        "starts": len(starts_u), "status": [int(r.status) for r in results],
        "message": results[-1].message if results else "", "evaluations": problem.evaluations,
        "walks": problem.walks, "walk_seconds": problem.walk_seconds, "seconds": time.perf_counter() - t0,
        "photons": problem.photons, "resumed": state is not None, "start_note": start_note,
        "singular_values": np.linalg.svd(J * span[None, :], compute_uv=False).tolist(),
    }
    if out is not None:
        _write_json_atomic(out / STATE_NAME, {
            "schema": STATE_SCHEMA, "identity": problem.identity(), "x": x_best.tolist(),
            "names": [p.name for p in problem.free], "objective": float(r_best @ r_best),
            "photons": problem.photons, "evaluations": problem.evaluations, "done": True})
    return FitResult(x=x_best, start=problem.start.copy(), objective=float(r_best @ r_best), objective_start=F_start,
                     u=u, u_data=np.sqrt(np.maximum(np.diag(cov_data), 0.0)),
                     u_mc=np.sqrt(np.maximum(np.diag(cov_mc), 0.0)), correlation=corr, warnings=notes, info=info)


def _identifiability(problem: FitProblem, J: np.ndarray, u: np.ndarray) -> list[str]:
    span = problem.high - problem.low
    notes = []
    _, s, vt = np.linalg.svd(J * span[None, :], full_matrices=False)
    names = [p.name for p in problem.free]
    flagged: set[str] = set()
    for k in range(s.size):
        if s[0] == 0 or s[k] < _FLAT * s[0]:
            v = vt[k] / np.max(np.abs(vt[k]))
            terms = " ".join(f"{c:+.2f}*{n}" for c, n in zip(v, names) if abs(c) > 0.2)
            notes.append(f"not identifiable: the objective is flat along {terms} (scaled singular value "
                         f"{s[k] / s[0] if s[0] else 0:.1e} of the largest)")
            flagged.update(n for c, n in zip(v, names) if abs(c) > 0.2)
    for name, uu, sp in zip(names, u, span):
        if name not in flagged and not uu <= 0.5 * sp:
            notes.append(f"not identifiable: {name} has an uncertainty ({uu:.3g}) above half its bound range "
                         f"({sp:.3g})")
    return notes


# ------------------------------------------------------------------------------------------
# outputs


def _summary(comparison) -> dict:
    name = next(iter(comparison.frames))
    out = {"nrmse": float(comparison.overall[name].nrmse)}
    if comparison.colour is not None:
        c = comparison.colour.simulated[name]
        out.update(dh=float(c.dh), ds=float(c.ds), h=float(c.colour.h), s=float(c.colour.s))
    return out


def write_outputs(problem: FitProblem, result: FitResult, out: Path) -> dict:
    """fitted.toml, initial/ and fitted/ datasets, report/ and fit.json in ``out``; returns fit.json."""
    from compare.comparison import compare_datasets
    from compare.report import write_report
    from gonio.data.dataset import write_dataset
    from simulate.montecarlo.accuracy import REL_ERR_DEFINITION, relative_error
    from simulate.provenance import jsonable, software_versions

    prov = {"command": GENERATOR, "config": problem.config.provenance(), "seed": problem.seed,
            "versions": software_versions()}
    b0, u0 = problem.model(result.start)
    b1, u1 = problem.model(result.x)
    rel_err = {"start": relative_error(b0, u0), "fitted": relative_error(b1, u1), "definition": REL_ERR_DEFINITION}
    initial = problem.dataset(b0, u0, "initial", {**prov, "rel_err": rel_err["start"],
                                                  "rel_err_definition": REL_ERR_DEFINITION})
    fitted = problem.dataset(b1, u1, "fitted", {**prov, "rel_err": rel_err["fitted"],
                                                "rel_err_definition": REL_ERR_DEFINITION,
                                                "fitted": {p.name: float(v) for p, v in zip(problem.free, result.x)}})
    write_dataset(initial, out / "initial")
    write_dataset(fitted, out / "fitted")
    lines = [f"{problem.config.name} fitted by `simulate fit` ({problem.method} model) to {problem.measured.source}",
             "free parameters (value +- standard uncertainty):"]
    lines += [f"  {p.name} = {v:.6g} +- {uu:.2g}" for p, v, uu in zip(problem.free, result.x, result.u)]
    (out / "fitted.toml").write_text(problem.fitted_toml(result.x, "\n".join(lines)), encoding="utf-8")
    comparison = compare_datasets(problem.measured, [initial, fitted])
    write_report(comparison, out / "report", force=True)
    c0 = _summary(problem.compare(initial))
    c1 = _summary(problem.compare(fitted))
    doc = {
        "generator": GENERATOR, "method": problem.method, "config": problem.config.name,
        "measured": str(problem.measured.source),
        "objective": {"definition": "NRMSE^2 + w_c (dh^2 + ds^2)", "colour_weight": problem.colour_weight,
                      "start": result.objective_start, "fitted": result.objective},
        "start": c0, "fitted": c1, "rel_err": rel_err,
        "parameters": [{"name": p.name, "kind": p.kind, "low": p.low, "high": p.high, "start": p.start,
                        "value": float(v), "u": float(uu), "u_data": float(ud), "u_mc": float(um)}
                       for p, v, uu, ud, um in zip(problem.free, result.x, result.u, result.u_data, result.u_mc)],
        "correlation": result.correlation.tolist(), "warnings": result.warnings, "info": result.info,
    }
    doc = jsonable(doc)
    _write_json_atomic(out / "fit.json", doc)
    return doc
