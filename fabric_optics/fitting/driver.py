r"""``simulate fit``: fit named config parameters of a fabric model to a measurement (the inverse problem).

``simulate fit CONFIG MEASURED_DIR --free NAME[=LOW:HIGH],... --out DIR [--method summation|classic|mc]
[--dye knots] [--max-evaluations N] [--resume]``

``--method mc`` (the woven/felt Monte Carlo, fitted by output space mapping through the structured
summation) is :mod:`fabric_optics.fitting.mc`; :func:`fabric_optics.fitting.methods.method_runner` chooses between them.

Parameters
----------
A free parameter is a numeric field of the config, named by its dotted TOML path with list
indices (``particles.volume_fraction``, ``particles.size.median_radius_um``,
``surface.rms_slope``, ``fiber.dye.bands[0].peak_per_um``, ``fiber.dye.edge_nm``, ...), or an
alias: ``volume_fraction``, ``radius`` (the particle radius or median radius), ``rms_slope``,
``dye`` (every coefficient of the config's smooth dye curve: baseline, band centres, widths and
peaks, or the logistic edge's four), ``dye-peaks`` (only the dye's amplitudes: baseline and peaks,
or short/long; for a ``knots`` dye both name its knot values ``fiber.dye.log10_per_um[k]``). Bounds
default per kind (:func:`default_bounds`); explicit ``=LOW:HIGH`` wins. The dye must be a named
curve (``knots``/``gaussian-bands``/``logistic-edge``): a few coefficients describe a smooth
spectrum, a free table would be an ill-posed fit of 30 values.

A dye of any colour: ``--dye knots`` replaces the config's dye by 8 knots of log10 absorption
spanning the model wavelengths (:func:`fabric_optics.fitting.start.knots_config`); whenever knots are free
the search starts from the knots inverted from the measured colour through the model's own
absorption table (:func:`fabric_optics.fitting.start.inverted_start`: the start has the measured hue and
saturation at the colour geometry), not from the config's. Two Gaussian bands started from red
cotton could not turn green (the felt: hue -0.044 turn, ds -0.16 left after the fit).

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

The colour hold: ``w_c (dh^2 + ds^2)`` alone trades the colour against the curve error, and where the
model's curves and colour pull apart the curves win (the green felt's measured plan, 138 geometries:
the classic fit ended at ds -0.207 at ``w_c`` 1, -0.074 at ``w_c`` 10). So the classic and summation
fits append ``sqrt(W) max(0, |dh|/0.02 - 0.7)`` and ``sqrt(W) max(0, |ds|/0.03 - 0.7)``, ``W`` 1
(:func:`fabric_optics.fitting.problem.colour_hold`): nothing inside 0.7 of :data:`COLOUR_TOLERANCE`, and
beyond it a cost that outweighs the curve error, so the search ends within the tolerance whenever the
model reaches the colour, and as near as the model comes otherwise (then the verdict says a larger
weight does not help). ``--no-colour-hold`` leaves the weighted terms alone; the Monte Carlo fit's
surrogate (:mod:`fabric_optics.fitting.mc`) does not hold the colour.

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

Scattering parameters re-weighted, not re-walked: the fit walks only at the points of a
geometric lattice of the walked parameters (``start * exp(0.1 k)``, :meth:`FitProblem.lattice`)
and evaluates any other particle volume fraction or size (``mu_s`` and the phase function per
wavelength) by scoring the paths of the walk at its lattice point -- same seeds, same photons,
same groups -- for the new optics with the kernel's likelihood ratio (``absorption_table(...,
reference=...)``), as the walk already does across wavelengths. The lattice makes the objective a
deterministic function of the parameters (a first version re-weighted from the *last* walk: the
same point then took different values depending on the search's history, and a resumed fit
found its accepted point 8 % worse). The paths do not move, so the objective is smooth in these
parameters (exact common random numbers; the re-weighted estimate equals a fresh walk within its
standard errors, tested). The variance bound :func:`simulate.fiber.spectral.reweight_exponent`
(``ln E[w^2] ~= N [(r - 1)^2 + ln(1 + chi^2)]``, ``N`` the mean scatterings per photon, counted by
the kernel) decides: a point whose bound exceeds the lattice walk's own (its wavelength groups'
spread) by more than ``ln 4`` (:data:`fabric_optics.fitting.problem.REWEIGHT_LIMIT`) is walked itself. On red
cotton (``N`` ~ 40-55) the bound allows about +-10 % in volume fraction or particle radius (the
lattice needs +-5 %); the measured standard error grew by 4-13 % there, far below the bound (scores
come mostly from short paths). A re-weighted pass costs about what a walk costs (the kernel walks
the same paths to score them): the gain is the smooth objective, not the pass. ``fit.json`` counts
``walks`` and ``reweighted`` passes apart. The structured summation (``[structure]``,
:mod:`fabric_optics.fitting.structure`) does not re-weight: its walks at the points of a 20 % lattice are
blended, multilinear in ``log v`` (:meth:`FitProblem.lattice_corners`), so only lattice points are
walked, and each walk is kept in the disk table cache (``fit.json`` ``walks_from_cache``).

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

Warnings (each once, in ``fit.json`` and on stderr): a parameter within 10^-3 of its bound range
from a bound ("at its lower/upper bound": the optimum may lie beyond), a flat direction or a
too-large uncertainty (above), a fitted colour further than ``|dh| > 0.02`` turn or ``|ds| > 0.03``
from the measured one (:data:`COLOUR_TOLERANCE`: twice the just-noticeable 0.01 turn; with the colour
held, the model cannot reach the colour with these free parameters), and a search stopped by its budget.

Evaluation budget
-----------------
``--max-evaluations N`` (default 800: on the demo's acquisition the classic fit converges in 205 evaluations and
the summation fit, the colour held, in about 570) bounds the objective evaluations of the *search in all*:
the start's figure, every trust-region step and every Jacobian column, over all ``--starts``. The
search stops before a Jacobian it cannot complete and keeps the best point evaluated (with a
warning). The uncertainty propagation afterwards (one Jacobian and 2 x 64 noise draws, all table
reads: no walk) is counted apart (``fit.json`` ``info.evaluations_uncertainty``).

Grazing incidence
-----------------
Rows at ``theta_i >= 89`` deg (:data:`gonio.data.formats.GRAZING_DEG`, the rule of ``gonio
import``, which drops them unless ``--keep-grazing``) are left out of the fit with a note
(``fit.json`` ``info.notes``); a measurement with nothing else is refused.

Interrupt and resume
--------------------
Progress: a walk bar counts photons from the first batch round of the first run (and the runs
done, ``run i/N``), the fit bar counts evaluations against the budget. Every finished Monte Carlo
run is checkpointed in ``DIR/walks/`` (:mod:`fabric_optics.fitting.state`), and the last accepted point (the
best objective so far: trust-region steps are accepted only when they lower it; the start is the
first) is written atomically to ``DIR/fit-state.json`` after every improvement, with the photon
counts. ``--resume`` continues from the state file, or -- stopped during the first walk, before
any point -- from the runs on disk (not walked again); it is refused, saying why, when the state
belongs to another fit (config, measurement, method, seed or free parameters differ) or when there
is nothing to resume. Ctrl-C says which of the two was left behind (exit 130).

Outputs in DIR: ``fitted.toml`` (the fitted config, ready for ``simulate fabric``),
``initial/`` and ``fitted/`` (datasets of the model at the start and the fitted parameters, at
the measured geometries), ``report/`` (``compare report`` of measurement vs initial vs fitted),
``fit.json`` (parameters, uncertainties, correlations, objective, warnings, evaluations, walks,
times) and ``fit-state.json``.

The outputs are written together (:func:`write_outputs`): first all of them into a hidden folder
``DIR/.outputs-XXXXXXXX.tmp/``, then moved into place, ``fit.json`` first, with Ctrl-C held back
during the moves (milliseconds). An interrupt or a full disk while they are written leaves the
previous outputs (none, or those of an earlier run) as they were and the state ``--resume``
continues from; ``fitted.toml`` is never there without its ``fit.json``.
"""

from __future__ import annotations

import contextlib
import json
import logging
import math
import os
import re
import shutil
import signal
import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np

from gonio.data.dataset import make_dataset

from fabric_optics.fitting.problem import (COLOUR_HOLD_FROM, COLOUR_HOLD_WEIGHT, COLOUR_TOLERANCE, GENERATOR,
                                           FitError, FitProblem, FreeParameter, default_bounds, parse_free)
from fabric_optics.fitting.start import inverted_start
from fabric_optics.fitting.state import WALKS_DIR, WalkCheckpoint, write_json_atomic
from fabric_optics.paths import toml_dumps

__all__ = [
    "FitError",
    "FreeParameter",
    "FitProblem",
    "FitResult",
    "GENERATOR",
    "STATE_NAME",
    "DEFAULT_MAX_EVALUATIONS",
    "COLOUR_TOLERANCE",
    "EXIT_COLOUR_OFF",
    "colour_left_off",
    "residual_covariance",
    "uncertainty_text",
    "default_bounds",
    "jacobian",
    "at_bounds",
    "identifiability",
    "parse_free",
    "run_fit",
    "search_fit",
    "finish_fit",
    "FitSearch",
    "toml_dumps",
    "write_outputs",
]

log = logging.getLogger(__name__)

STATE_NAME = "fit-state.json"
STATE_SCHEMA = "simulate-fit-state/1"
_NOISE_DRAWS = 64
#: ``--max-evaluations`` default: objective evaluations of the search in all (module docstring)
DEFAULT_MAX_EVALUATIONS = 800
#: exit status of ``simulate fit`` whose fitted colour is left off: its outputs are written, fit.json's
#: ``verdict`` says ``passed: false`` (2 stays bad input, 130 an interrupt)
EXIT_COLOUR_OFF = 3
_AT_BOUND = 1e-3
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


def load_state(out: Path, problem: FitProblem) -> dict | None:
    """The saved state of an interrupted fit of the same problem, checked field by field
    (:mod:`fabric_optics.fitting.state`), or raise FitError naming the file and the field."""
    from fabric_optics.fitting.state import check_number, check_photons, check_point, read_state_json

    path = out / STATE_NAME
    state = read_state_json(path)
    if state is None:
        return None
    if state.get("schema") != STATE_SCHEMA or state.get("identity") != problem.identity():
        raise FitError(f"--resume: {path} belongs to a different fit (config, measurement, method, seed or "
                       "free parameters differ); use a new --out or drop --resume")
    names = [p.name for p in problem.free]
    if "names" in state and state["names"] != names:
        raise FitError(f"--resume: {path}: field 'names' does not list this fit's free parameters ({', '.join(names)}); "
                       "delete the file or run without --resume to start afresh")
    for name in ("x", "objective"):
        if name not in state:
            raise FitError(f"--resume: {path}: field {name!r} is missing; delete the file or run without --resume "
                           "to start afresh")
    return {**state,
            "x": check_point(path, "x", state["x"], names, problem.low, problem.high),
            "objective": check_number(path, "objective", state["objective"], low=0.0),
            "photons": check_photons(path, "photons", state.get("photons")),
            "evaluations": int(check_number(path, "evaluations", state.get("evaluations", 0), low=0, integer=True))}


def jacobian(problem: FitProblem, x: np.ndarray, r0: np.ndarray, fun: Callable) -> np.ndarray:
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


class _Budget(Exception):
    """The evaluation budget of the search is spent."""


@dataclass
class FitSearch:
    """The search of a fit (:func:`search_fit`), before its uncertainty (:func:`finish_fit`)."""

    x: np.ndarray
    objective_start: float
    results: list
    stopped: str
    start_note: str
    evaluations: int
    max_evaluations: int
    resume: bool
    out: Path | None
    t0: float


def run_fit(problem: FitProblem, *, out: Path | None = None, resume: bool = False,
            max_evaluations: int = DEFAULT_MAX_EVALUATIONS, starts: int = 1, progress: bool = False,
            noise_draws: int = _NOISE_DRAWS, invert_start: bool = True) -> FitResult:
    """Fit ``problem`` with ``scipy.optimize.least_squares`` (module docstring); state in ``out``.

    ``max_evaluations``: the objective evaluations of the search in all (the start's, every step's
    and every Jacobian column's, over all starts); the uncertainty propagation afterwards is
    counted apart (``info["evaluations_uncertainty"]``). The search (:func:`search_fit`) and the
    uncertainty at its best point (:func:`finish_fit`) in one.
    """
    search = search_fit(problem, out=out, resume=resume, max_evaluations=max_evaluations, starts=starts,
                        progress=progress, invert_start=invert_start)
    return finish_fit(problem, search, noise_draws=noise_draws)


def search_fit(problem: FitProblem, *, out: Path | None = None, resume: bool = False,
               max_evaluations: int = DEFAULT_MAX_EVALUATIONS, starts: int = 1, progress: bool = False,
               invert_start: bool = True) -> FitSearch:
    """The search of :func:`run_fit` alone: its best point, no uncertainty. A caller that fits the same problem
    several times and keeps one (:func:`fabric_optics.fitting.mc`'s colour weights) finishes only the kept one."""
    from scipy.optimize import least_squares
    from tqdm import tqdm

    from compare.errors import CompareError

    t0 = time.perf_counter()
    problem.out = out
    span = problem.high - problem.low
    x0 = problem.start.copy()
    state = None
    start_note = ""
    if resume:
        if out is None:
            raise FitError("--resume needs the output directory of the interrupted fit (--out)")
        state = load_state(out, problem)
        if state is None:
            runs = WalkCheckpoint(out, "", (), np.zeros(1), None).count()
            if not runs:
                raise FitError(f"--resume: nothing to resume in {out}: no {STATE_NAME} and no finished Monte Carlo "
                               "run (the fit was stopped before its first run finished); run without --resume")
            start_note = (f"resumed: no point had been accepted; the finished Monte Carlo runs in "
                          f"{out / WALKS_DIR} are read, not walked again")
    if state is not None:
        x0 = np.array(state["x"], float)   # inside the bounds: load_state refuses a point outside
        problem.photons = state.get("photons")
        start_note = (f"resumed from the last accepted point of {out / STATE_NAME} (objective "
                      f"{state['objective']:.6g})")
        log.info("%s", start_note)
    best: dict[str, Any] = {"F": math.inf, "x": x0.copy()}
    walk_bar = tqdm(total=None, desc="walk 1", unit="photon", unit_scale=True, disable=not progress, leave=False)
    bar = tqdm(total=max_evaluations, desc="fit", unit="eval", disable=not progress, leave=False)

    def walk_progress(photons: int, run: int, runs: int) -> None:
        if photons == 0 and run == 0:
            walk_bar.reset()
            walk_bar.set_description(f"walk {problem.walks + 1}")
        walk_bar.n = photons
        walk_bar.set_postfix_str(f"run {run}/{runs}", refresh=False)
        walk_bar.refresh()

    problem.walk_progress = walk_progress if progress else None
    ev0 = problem.evaluations
    memo: dict[str, Any] = {"x": None, "r": None}

    def used() -> int:
        return problem.evaluations - ev0

    def fun_x(x: np.ndarray) -> np.ndarray:
        if memo["x"] is not None and np.array_equal(memo["x"], x):
            return memo["r"]
        if used() >= max_evaluations:
            raise _Budget
        try:
            r = problem.residuals(x)
        except CompareError as exc:
            # a trial point whose model compare cannot normalise (e.g. its normal/normal estimate from the
            # neighbours is not positive): rejected by a residual far above any other, not a traceback
            if memo["r"] is None:
                raise FitError(f"the model at the start cannot be compared with the measurement: {exc}") from None
            problem.evaluations += 1
            r = np.full(memo["r"].size, 1e3 / math.sqrt(memo["r"].size))
            log.info("trial point rejected: %s", exc)
        bar.update(1)
        memo.update(x=x.copy(), r=r)
        return r

    def accept(x: np.ndarray, r: np.ndarray) -> None:
        F = float(r @ r)
        if F < best["F"]:
            best.update(F=F, x=x.copy())
            bar.set_postfix(objective=f"{F:.5g}", walks=problem.walks)
            if out is not None:
                write_json_atomic(out / STATE_NAME, {
                    "schema": STATE_SCHEMA, "identity": problem.identity(), "x": x.tolist(),
                    "names": [p.name for p in problem.free], "objective": F, "photons": problem.photons,
                    "evaluations": problem.evaluations})

    def phys(u: np.ndarray) -> np.ndarray:
        return problem.low + np.clip(u, 0.0, 1.0) * span

    def fun_u(u: np.ndarray) -> np.ndarray:
        x = phys(u)
        r = fun_x(x)
        accept(x, r)
        return r

    def jac_u(u: np.ndarray) -> np.ndarray:
        x = phys(u)
        cost = sum(1 if p.kind == "walk" else 2 for p in problem.free)
        if used() + cost > max_evaluations:
            raise _Budget
        return jacobian(problem, x, fun_x(x), fun_x) * span[None, :]

    stopped = ""
    results = []
    try:
        if state is None and invert_start:
            x0, note = inverted_start(problem, x0)
            start_note = f"{start_note}; {note}" if start_note else note
        r_start = fun_x(problem.start)
        F_start = float(r_start @ r_start)
        accept(problem.start, r_start)
        if state is None and invert_start and not np.array_equal(x0, problem.start):
            # a config whose dye was fitted already (a preset's knots): its own start may beat the inversion,
            # which matches the colour only. The colour comes first (a fit left off in colour fails): the start
            # nearer the measured colour (in tolerances) starts the search, the lower objective when both are
            # within the tolerance; from a start of another colour the search stays in that colour's basin
            r_inv = fun_x(x0)
            off_own, off_inv = colour_distance(problem, problem.start), colour_distance(problem, x0)
            if off_own <= 1.0 and off_inv <= 1.0:
                use_own = float(r_inv @ r_inv) > F_start
            elif off_own <= 1.0 or off_inv <= 1.0:
                use_own = off_own <= 1.0
            else:
                use_own = off_own < off_inv
            if use_own:
                x0 = problem.start.copy()
                start_note += ("; the config's own values are nearer the measured colour or score better than the "
                               "inverted start and start the search")
            else:
                start_note += "; the inverted start is nearer the measured colour and starts the search"
        starts_u = [(x0 - problem.low) / span]
        if starts > 1 and state is None:
            from scipy.stats import qmc

            starts_u += list(qmc.LatinHypercube(d=x0.size, seed=int(problem.seed or 0)).random(starts - 1))
        for su in starts_u:
            results.append(least_squares(fun_u, np.clip(su, 0.0, 1.0), jac=jac_u, bounds=(0.0, 1.0), method="trf",
                                         x_scale=1.0, max_nfev=max_evaluations, ftol=1e-8, xtol=1e-8, gtol=1e-10))
    except _Budget:
        stopped = (f"the search stopped at its evaluation budget (--max-evaluations {max_evaluations}) before "
                   "converging: the result is the best point evaluated")
        if not math.isfinite(best["F"]):
            raise FitError(f"--max-evaluations {max_evaluations}: no evaluation was possible") from None
    finally:
        bar.close()
        walk_bar.close()
    return FitSearch(x=best["x"], objective_start=F_start, results=results, stopped=stopped, start_note=start_note,
                     evaluations=used(), max_evaluations=max_evaluations, resume=resume, out=out, t0=t0)


def finish_fit(problem: FitProblem, search: FitSearch, *, noise_draws: int = _NOISE_DRAWS) -> FitResult:
    """The result of ``search`` (:func:`search_fit`): the uncertainty at its best point (module docstring), the
    warnings and fit.json's ``info``; the final state in the search's ``out``. ``problem`` as the search left it
    (its colour weight and start)."""
    from compare.errors import CompareError

    ev0 = problem.evaluations
    x_best, results, stopped, start_note = search.x, search.results, search.stopped, search.start_note
    search_evaluations, max_evaluations, resume, out = search.evaluations, search.max_evaluations, search.resume, search.out
    span = problem.high - problem.low
    r_best = problem.residuals(x_best)
    J = jacobian(problem, x_best, r_best, problem.residuals)
    pinv = np.linalg.pinv(J)

    # uncertainty: data noise and Monte Carlo noise propagated through the whole objective
    rng = np.random.default_rng(20260101 + int(problem.seed or 0))
    meas = problem.measured
    dp_data, dp_mc, refused = [], [], 0
    without_u = not measurement_has_u(meas)
    u_rule: dict = {"data": "u_beta", "rule": "the measurement's u_beta propagated by noise draws"}
    if without_u:   # the same draws as a stated u_beta would get, scaled by the residual's noise
        cov_resid, u_rule = residual_scaled_draws(problem, x_best, r_best, J, rng, noise_draws)
    for _ in range(0 if without_u else noise_draws):
        table = meas.table.copy()
        table["beta"] = table["beta"] + rng.standard_normal(len(table)) * table["u_beta"]
        noisy = make_dataset(table, meas.meta)
        try:
            dp_data.append(-pinv @ (problem.residuals(x_best, measured=noisy) - r_best))
        except CompareError:
            # a draw whose normal/normal value is not positive (a value within ~1 u of zero, e.g. a
            # simulated measurement's 400 nm in a strongly absorbed band) cannot be normalised: left out
            refused += 1
    beta_shape = problem.table(problem.config_at(x_best)).R.shape[:2]
    for _ in range(noise_draws):
        try:
            dp_mc.append(-pinv @ (problem.residuals(x_best, mc_noise=rng.standard_normal(beta_shape)) - r_best))
        except CompareError:
            refused += 1
    if refused:
        log.warning("%d of %d noise draws left out of the uncertainty: their normal/normal value was not positive",
                    refused, 2 * noise_draws)
    # a part drawn with no draw accepted could not be estimated (NaN); a part not drawn (noise_draws 0) is 0
    n = len(problem.free)
    missing = np.full((n, n), np.nan) if noise_draws > 0 else np.zeros((n, n))
    cov_data = np.atleast_2d(np.cov(np.array(dp_data).T, bias=True)) if dp_data else missing
    if without_u:
        cov_data = cov_resid
    cov_mc = np.atleast_2d(np.cov(np.array(dp_mc).T, bias=True)) if dp_mc else missing
    cov, u, u_data, u_mc, u_notes = uncertainty_parts(cov_data, cov_mc)
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov / np.outer(u, u)
    corr[~np.isfinite(corr)] = 0.0
    bound_notes, ident_notes = at_bounds(problem, x_best), identifiability(problem, J, u)
    notes = ([stopped] if stopped else []) + bound_notes + ident_notes
    notes += _colour_left_off(problem, x_best) + u_notes + ([u_rule["note"]] if "note" in u_rule else [])
    for note in notes:  # printed once, by the caller (the CLI prints fit.json's warnings)
        log.debug("%s", note)
    info = {
        "optimiser": "scipy.optimize.least_squares (trf, bounds scaled to [0, 1])",
        "starts": len(results) if results else 1, "status": [int(r.status) for r in results],
        "message": results[-1].message if results else stopped,
        "evaluations": search_evaluations, "max_evaluations": max_evaluations,
        "evaluations_uncertainty": problem.evaluations - ev0,
        "walks": problem.walks, "walk_seconds": problem.walk_seconds, "reweighted": problem.reweights,
        "walks_from_cache": problem.cached_walks,
        "reweighted_seconds": problem.reweight_seconds, "seconds": time.perf_counter() - search.t0,
        "photons": problem.photons, "resumed": resume, "start_note": start_note, "notes": list(problem.notes),
        "singular_values": np.linalg.svd(J * span[None, :], compute_uv=False).tolist(),
        "uncertainty": u_rule, "u_status": u_status(problem, bound_notes, ident_notes),
    }
    if out is not None:
        write_json_atomic(out / STATE_NAME, {
            "schema": STATE_SCHEMA, "identity": problem.identity(), "x": x_best.tolist(),
            "names": [p.name for p in problem.free], "objective": float(r_best @ r_best),
            "photons": problem.photons, "evaluations": problem.evaluations, "done": True})
    return FitResult(x=x_best, start=problem.start.copy(), objective=float(r_best @ r_best),
                     objective_start=search.objective_start,
                     u=u, u_data=u_data, u_mc=u_mc, correlation=corr, warnings=notes, info=info)


def measurement_has_u(measured) -> bool:
    """Whether the measurement states an uncertainty (some ``u_beta`` > 0; an RGL file's import has none)."""
    u = measured.table["u_beta"].to_numpy(float)
    return bool(np.any(np.isfinite(u) & (u > 0)))


#: the rule of the data part of ``u`` for a measurement without ``u_beta`` (fit.json ``info.uncertainty``)
RESIDUAL_RULE = ("no measurement uncertainty (u_beta is 0): the data part of u is the least-squares covariance "
                 "scaled by the residual, s^2 (J^T J)^-1 with s^2 = SSR/(n - p) -- the residual taken as the "
                 "measurement's noise, so model error counts as noise")


def residual_covariance(J: np.ndarray, r: np.ndarray, unweighted: int = 0) -> tuple[np.ndarray, dict]:
    """``(cov, rule)``: the parameters' covariance ``s^2 (J^T J)^+`` with ``s^2 = SSR/(n - p)`` from the
    residual ``r`` at the solution (the usual least-squares rule for data without stated uncertainty).

    ``n`` counts the residuals that carry weight (``unweighted``: the colour terms at ``--colour-weight 0``), ``p``
    the free parameters. No degree of freedom left (``n <= p``): the covariance is NaN (no number is printed).
    """
    p = J.shape[1]
    n = int(r.size) - int(unweighted)
    dof = n - p
    ssr = float(r @ r)
    rule: dict[str, Any] = {"data": "residual", "n": n, "p": p, "dof": dof, "ssr": ssr, "rule": RESIDUAL_RULE}
    if dof <= 0:
        rule["s2"] = None
        rule["note"] = (f"uncertainty: no measurement uncertainty and no degree of freedom left (n = {n} residuals, "
                        f"p = {p} parameters): no u is given")
        return np.full((p, p), np.nan), rule
    s2 = ssr / dof
    rule["s2"] = s2
    rule["note"] = (f"uncertainty: the measurement states none (u_beta 0), so u is scaled by the residual: "
                    f"s^2 = SSR/(n - p) = {ssr:.4g}/{dof} = {s2:.3g} (s = {math.sqrt(s2):.3g} in the objective's units)")
    return s2 * np.linalg.pinv(J.T @ J), rule


#: the rule of the data part of ``u`` for a measurement without ``u_beta``, by noise draws (fit.json ``uncertainty``)
RESIDUAL_DRAWS_RULE = ("no measurement uncertainty (u_beta is 0): one noise level sigma for every beta is estimated "
                       "from the residual, sigma^2 = SSR / E[SSR per unit noise variance] (the expectation from noise "
                       "draws through the whole objective, the normalisation at the normal included, after the re-fit), "
                       "and propagated like a stated u_beta -- the residual taken as the measurement's noise, so "
                       "model error counts as noise")


def residual_scaled_draws(problem: FitProblem, x: np.ndarray, r0: np.ndarray, J: np.ndarray, rng: np.random.Generator,
                          draws: int, residuals: Callable | None = None) -> tuple[np.ndarray, dict]:
    """``(cov, rule)``: the data part of the parameters' covariance for a measurement without ``u_beta``
    (:data:`RESIDUAL_DRAWS_RULE`). Noise draws of 1 % of the mean ``|beta|`` on every value go through the whole
    objective (``residuals``, default the problem's): their parameter shifts ``-J^+ dr`` and the part of ``dr`` the
    re-fit cannot absorb, ``(I - J J^+) dr``, whose mean square calibrates ``SSR`` into ``sigma^2``. The plain rule
    ``s^2 (J^T J)^-1`` (:func:`residual_covariance`) treats the residuals as independent; the per-wavelength
    normalisation at the normal makes them correlated, and on synthetic data with known noise it gave a third to a
    half of the true u (tests/fabric_optics/fitting/test_fit.py)."""
    from compare.errors import CompareError

    fn = residuals or problem.residuals
    meas = problem.measured
    p = J.shape[1]
    pinv = np.linalg.pinv(J)
    u0 = 0.01 * float(np.mean(np.abs(meas.table["beta"].to_numpy(float))))
    shifts, unit_ssr = [], []
    for _ in range(draws):
        table = meas.table.copy()
        table["beta"] = table["beta"] + rng.standard_normal(len(table)) * u0
        try:
            d = fn(x, measured=make_dataset(table, meas.meta)) - r0
        except CompareError:
            continue
        shifts.append(-pinv @ d / u0)
        rest = d - J @ (pinv @ d)
        unit_ssr.append(float(rest @ rest) / u0 ** 2)
    ssr = float(r0 @ r0)
    rule: dict[str, Any] = {"data": "residual", "p": p, "draws": len(shifts), "ssr": ssr,
                            "rule": RESIDUAL_DRAWS_RULE}
    if len(shifts) < 2 or not np.mean(unit_ssr) > 0:
        rule["sigma_beta"] = None
        rule["note"] = "uncertainty: no measurement uncertainty and no noise draw could be evaluated: no u is given"
        return np.full((p, p), np.nan), rule
    c = float(np.mean(unit_ssr))
    sigma2 = ssr / c
    rule.update(sigma_beta=math.sqrt(sigma2), ssr_per_unit_variance=c)
    rule["note"] = (f"uncertainty: the measurement states none (u_beta 0), so u is scaled by the residual: noise "
                    f"sigma = {math.sqrt(sigma2):.3g} on beta (SSR {ssr:.4g} over {c:.4g} per unit variance, from "
                    f"{len(shifts)} noise draws)")
    return sigma2 * np.atleast_2d(np.cov(np.array(shifts).T, bias=True)), rule


def unweighted_rows(problem: FitProblem) -> int:
    """The residual entries that carry no weight: the two colour terms at ``--colour-weight 0``."""
    return 2 if problem.colour_weight <= 0 and problem.residual_model().has_colour else 0


def u_status(problem: FitProblem, bound_notes: list[str], ident_notes: list[str]) -> list[str]:
    """Per free parameter: ``""`` (its ``u`` is a number), ``"at its lower bound"``/``"at its upper bound"`` or
    ``"not identifiable"`` -- reported as such, not with a number (``u`` null in fit.json)."""
    out = []
    for p in problem.free:
        status = ""
        for note in bound_notes:
            if f": {p.name} = " in note:
                status = note.split(":", 1)[0]
        for note in ident_notes:
            if re.search(rf"(\*|^not identifiable: ){re.escape(p.name)}( |$)", note):
                status = "not identifiable"
        out.append(status)
    return out


def uncertainty_parts(cov_data: np.ndarray, cov_mc: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray,
                                                                           np.ndarray, list[str]]:
    """``(cov, u, u_data, u_mc, notes)`` from the two parts' covariances of the parameters.

    A part whose noise draws were all refused (none could be normalised) is all-NaN: it could not be
    estimated. Its ``u_*`` is then NaN (``null`` in fit.json, "-" in the report), ``u`` holds the other
    part alone -- a lower bound -- and a note says so (printed with the fit's warnings).
    """
    notes, parts = [], []
    for name, c in (("data", cov_data), ("Monte Carlo", cov_mc)):
        if c.size and np.all(np.isnan(c)):
            notes.append(f"uncertainty: the {name} part could not be estimated (every noise draw was refused: "
                         "its normal/normal value was not positive); u is the other part alone, a lower bound")
        parts.append(np.nan_to_num(c, nan=0.0))
    cov = parts[0] + parts[1]
    u = np.sqrt(np.maximum(np.diag(cov), 0.0))
    u_data, u_mc = (np.sqrt(np.maximum(np.diag(c), 0.0)) for c in (cov_data, cov_mc))   # NaN stays NaN
    return cov, u, u_data, u_mc, notes


def at_bounds(problem: FitProblem, x: np.ndarray) -> list[str]:
    """A parameter within 10^-3 of its bound range from a bound: the optimum may lie beyond."""
    notes = []
    for p, v in zip(problem.free, x):
        tol = _AT_BOUND * (p.high - p.low)
        side = "lower" if v - p.low <= tol else "upper" if p.high - v <= tol else ""
        if side:
            notes.append(f"at its {side} bound: {p.name} = {v:.6g} (bounds [{p.low:g}, {p.high:g}]); the best value "
                         f"may lie beyond: widen with --free {p.name}=LOW:HIGH")
    return notes


def colour_distance(problem: FitProblem, x: np.ndarray) -> float:
    """``max(|dh|/tol_h, |ds|/tol_s)`` of the model at ``x`` (:data:`COLOUR_TOLERANCE`): <= 1 within the
    tolerance; 0 for a measurement without colour."""
    fig = problem.residual_model().evaluate(problem.model(x)[0])
    if not fig.has_colour:
        return 0.0
    dh_max, ds_max = COLOUR_TOLERANCE
    return max(abs(float(fig.dh)) / dh_max, abs(float(fig.ds)) / ds_max)


def colour_left_off(problem: FitProblem, dh: float, ds: float, method: str | None = None) -> str:
    """One line when the colour ``(dh, ds)`` is further from the measured than :data:`COLOUR_TOLERANCE`
    (``""`` within it, or without a colour), with what helps for this fit's free parameters and method."""
    if not (math.isfinite(dh) and math.isfinite(ds)):
        return ""
    dh_max, ds_max = COLOUR_TOLERANCE
    if abs(dh) <= dh_max and abs(ds) <= ds_max:
        return ""
    method = method or problem.method
    dye = problem.config.dye
    if not any(p.kind == "dye" for p in problem.free):
        helps = "the dye is fixed: free it (--free dye; with --dye knots it can take any colour)"
    elif problem.colour_weight <= 0:
        helps = "--colour-weight 0 leaves the colour out of the objective: give it a weight (the default 1)"
    elif method != "mc" and not problem.holds_colour():
        helps = ("the colour hold is off (--no-colour-hold): without it the curve error outweighs the colour; "
                 "drop the option")
    elif dye is None or dye.curve != "knots":
        helps = (f"the {dye.curve if dye is not None else 'absent'} dye cannot take every colour: --dye knots "
                 "(8 knots started from the measured colour)")
    elif method == "mc":
        helps = ("more Monte Carlo runs (--resume --max-runs N: each run corrects the surrogate's colour "
                 "again), or start from the summation's fit of the same data (its fitted.toml as CONFIG)")
    else:
        helps = (f"the objective held the colour to the tolerance and this is as near as the {method} model comes "
                 "with these free parameters: a larger --colour-weight does not help; "
                 + (_SUMMATION_LIMIT if method == "summation" else _CLASSIC_LIMIT))
    return (f"colour left off: the fitted model's hue differs by {dh:+.3f} turn and its saturation by {ds:+.3f} "
            f"from the measurement (tolerance |dh| <= {dh_max} turn, |ds| <= {ds_max}); {helps}")


#: what helps a classic or summation fit whose held colour stays off (measured: docs/notes/fit-trust.md, "The fits on
#: the measured plan")
_CLASSIC_LIMIT = ("the classic model is a carpet of fibers with one surface term: free more of its parameters, or fit "
                  "the summation (--method summation)")
_SUMMATION_LIMIT = ("free more parameters (volume_fraction), or fit the Monte Carlo (--method mc), which carries the "
                    "forward transport through clear fibers the summation's layers lack (they stay desaturated)")


def _colour_left_off(problem: FitProblem, x: np.ndarray) -> list[str]:
    """The fitted colour further from the measured than :data:`COLOUR_TOLERANCE` (:func:`colour_left_off`)."""
    fig = problem.residual_model().evaluate(problem.model(x)[0])
    if not fig.has_colour:
        return []
    note = colour_left_off(problem, float(fig.dh), float(fig.ds))
    return [note] if note else []


def identifiability(problem: FitProblem, J: np.ndarray, u: np.ndarray) -> list[str]:
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
        if name not in flagged and math.isfinite(uu) and uu > 0.5 * sp:
            notes.append(f"not identifiable: {name} has an uncertainty ({uu:.3g}) above half its bound range "
                         f"({sp:.3g})")
    return notes


# ------------------------------------------------------------------------------------------
# outputs


def _summary(comparison) -> dict:
    name = next(iter(comparison.frames))
    level = comparison.level(name)
    out = {"nrmse": float(comparison.overall[name].nrmse), "level_k": level.k, "level_ratio": level.ratio,
           "k_spread": level.spread}
    if comparison.colour is not None:
        c = comparison.colour.simulated[name]
        out.update(dh=float(c.dh), ds=float(c.ds), h=float(c.colour.h), s=float(c.colour.s))
    return out


def uncertainty_text(u: float, status: str = "") -> str:
    """``+- u`` for a parameter whose uncertainty is a number; its status (at a bound, not identifiable) or
    ``(no uncertainty)`` otherwise -- never a number for those."""
    if status:
        return f"({status}: no uncertainty)"
    if not math.isfinite(float(u)):
        return "(no uncertainty)"
    return f"+- {float(u):.2g}"


def _u_fields(u: float, u_data: float, u_mc: float, status: str) -> dict:
    """fit.json's uncertainty fields of one parameter: null with ``u_status`` when it has no number."""
    if status:
        return {"u": None, "u_data": None, "u_mc": None, "u_status": status}
    return {"u": float(u), "u_data": float(u_data), "u_mc": float(u_mc), "u_status": ""}


#: the outputs of a fit in DIR, in the order they are put in place (module docstring: fit.json first)
OUTPUT_NAMES = ("fit.json", "fitted.toml", "initial", "fitted", "report")
_STAGE_PREFIX = ".outputs-"


@contextlib.contextmanager
def _interrupt_held() -> Any:
    """Hold SIGINT back (main thread only) while the block runs; an interrupt that arrived is logged."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    got: list[int] = []
    previous = signal.signal(signal.SIGINT, lambda signum, frame: got.append(signum))
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
    if got:
        log.warning("an interrupt arrived while the outputs were being moved into place: they were completed first")


def _put_in_place(stage: Path, out: Path) -> None:
    """Move the staged outputs into ``out`` (module docstring); a replaced folder is moved into ``stage``."""
    aside = stage / ".replaced"
    aside.mkdir()
    with _interrupt_held():
        for name in OUTPUT_NAMES:
            new, dest = stage / name, out / name
            if new.is_dir() and (dest.is_dir() and not dest.is_symlink()):
                os.replace(dest, aside / name)
            os.replace(new, dest)


def write_outputs(problem: FitProblem, result: FitResult, out: Path) -> dict:
    """fitted.toml, initial/ and fitted/ datasets, report/ and fit.json in ``out``; returns fit.json.

    All are written into a hidden folder of ``out`` first and then moved into place together (module
    docstring): an exception or an interrupt while writing leaves ``out``'s previous outputs unchanged."""
    from compare.comparison import compare_datasets
    from compare.errors import CompareError
    from compare.report import write_report
    from gonio.data.dataset import atomic_write, write_dataset
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
    for stale in out.glob(f"{_STAGE_PREFIX}*.tmp"):   # a killed earlier write's folder
        shutil.rmtree(stale, ignore_errors=True)
    try:
        stage = Path(tempfile.mkdtemp(prefix=_STAGE_PREFIX, suffix=".tmp", dir=out))
    except OSError as exc:
        raise OSError(exc.errno, exc.strerror, str(out)) from None
    try:
        for ds, name in ((initial, "initial"), (fitted, "fitted")):
            write_dataset(ds, stage / name)
            ds.path = out / name          # where it will be: the report names it
        lines = [f"{problem.config.name} fitted by `simulate fit` ({problem.method} model) to {problem.measured.source}"]
        fig1 = problem.residual_model().evaluate(b1, u1)
        off = colour_left_off(problem, float(getattr(fig1, "dh", math.nan)), float(getattr(fig1, "ds", math.nan)))
        if off:
            lines.append(f"FAILED: {off}")
        status = result.info.get("u_status") or [""] * len(problem.free)
        lines.append("free parameters (value +- standard uncertainty):")
        lines += [f"  {p.name} = {v:.6g} {uncertainty_text(uu, st)}"
                  for p, v, uu, st in zip(problem.free, result.x, result.u, status)]
        rule = result.info.get("uncertainty") or {}
        if rule.get("data") == "residual":
            lines.append(f"  (no measurement uncertainty: u scaled by the residual, s^2 = SSR/(n - p) = "
                         f"{rule['s2']:.3g})" if rule.get("s2") is not None else "  (no measurement uncertainty and "
                         "no degree of freedom: no u)")
        atomic_write(stage / "fitted.toml", problem.fitted_toml(result.x, "\n".join(lines)).encode("utf-8"))
        comparison = compare_datasets(problem.measured, [initial, fitted])
        try:
            write_report(comparison, stage / "report", force=True)
        except CompareError as exc:   # the report's own one-line failure (a full disk): its cause
            if isinstance(exc.__cause__, OSError):
                raise exc.__cause__ from None
            raise
        c0 = _summary(problem.compare(initial))
        c1 = _summary(problem.compare(fitted))
        left_off = colour_left_off(problem, c1.get("dh", math.nan), c1.get("ds", math.nan))
        dh_max, ds_max = COLOUR_TOLERANCE
        verdict = {"passed": not left_off,
                   "colour": "left off" if left_off else ("ok" if "dh" in c1 else "no colour"),
                   "tolerance": {"dh_turn": dh_max, "ds": ds_max}, "exit_status": EXIT_COLOUR_OFF if left_off else 0}
        if left_off:
            verdict["why"] = left_off
        doc = {
            "generator": GENERATOR, "method": problem.method, "config": problem.config.name,
            "measured": str(problem.measured.source),
            "objective": {"definition": "NRMSE^2 + w_c (dh^2 + ds^2)"
                                        + (" + hold(dh, ds)" if problem.holds_colour() else "")
                                        + (" + w_l (ln k_Y)^2" if problem.level_weight else ""),
                          "colour_weight": problem.colour_weight, "level_weight": problem.level_weight,
                          "colour_hold": ({"from": COLOUR_HOLD_FROM, "weight": COLOUR_HOLD_WEIGHT,
                                           "rule": "hold(dh, ds) = W [max(0, |dh|/0.02 - f)^2 + max(0, |ds|/0.03 - f)^2]"}
                                          if problem.holds_colour() else None),
                          "start": result.objective_start, "fitted": result.objective},
            "verdict": verdict, "start": c0, "fitted": c1, "rel_err": rel_err,
            "parameters": [{"name": p.name, "kind": p.kind, "low": p.low, "high": p.high, "start": p.start,
                            "value": float(v), **_u_fields(uu, ud, um, st)}
                           for p, v, uu, ud, um, st in zip(problem.free, result.x, result.u, result.u_data,
                                                           result.u_mc, status)],
            "uncertainty": rule,
            "correlation": result.correlation.tolist(), "warnings": result.warnings, "info": result.info,
        }
        doc = jsonable(doc)
        atomic_write(stage / "fit.json", (json.dumps(doc, indent=1) + "\n").encode("utf-8"))
        _put_in_place(stage, out)
    except OSError as exc:   # one line naming DIR (the hidden folder is gone with what it held)
        raise OSError(exc.errno, f"{exc.strerror or exc}; the previous outputs are unchanged", str(out)) from None
    finally:
        shutil.rmtree(stage, ignore_errors=True)
    return doc
