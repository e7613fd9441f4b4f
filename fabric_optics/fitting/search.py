"""The least-squares search of the classic and summation fits, and their run (search, then uncertainty).

``scipy.optimize.least_squares`` (trust-region reflective, bounded) in coordinates scaled to ``[0, 1]`` by the
bounds: the objective is a sum of squares with few parameters, where Gauss-Newton converges in a handful of
Jacobians -- decisive when a Jacobian costs a walk per scattering parameter. ``--starts N`` adds N-1
Latin-hypercube starts (:class:`scipy.stats.qmc.LatinHypercube`) and keeps the best. The evaluation budget
(``--max-evaluations``) counts the search's evaluations in all (the start's, every step's and every Jacobian
column's); the search stops before a Jacobian it cannot complete and keeps the best point evaluated. Every
improvement is written to ``DIR/fit-state.json`` (:mod:`fabric_optics.fitting.state`); ``--resume`` continues from it.

Public objects: :func:`run_fit` (:func:`search_fit` then :func:`finish_fit`), :class:`FitSearch`,
:data:`DEFAULT_MAX_EVALUATIONS`. Why these choices: docs/notes/fit-trust.md ("The search").
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from scipy.optimize import least_squares
from scipy.stats import qmc
from tqdm import tqdm

from compare.errors import CompareError
from fabric_optics.fitting.errors import FitError
from fabric_optics.fitting.outputs import FitResult
from fabric_optics.fitting.start import inverted_start
from fabric_optics.fitting.state import STATE_NAME, WALKS_DIR, WalkCheckpoint, load_state, save_state
from fabric_optics.fitting.uncertainty import (
    NOISE_DRAWS,
    at_bounds,
    identifiability,
    jacobian,
    propagate,
    u_status,
    uncertainty_parts,
)
from fabric_optics.fitting.verdict import colour_distance, colour_left_off_at

__all__ = ["DEFAULT_MAX_EVALUATIONS", "FitSearch", "run_fit", "search_fit", "finish_fit"]

log = logging.getLogger(__name__)

#: ``--max-evaluations`` default: objective evaluations of the search in all (the demo's fits converge within it:
#: docs/notes/fit-trust.md)
DEFAULT_MAX_EVALUATIONS = 800


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
    #: the search's start and bounds
    start: np.ndarray
    low: np.ndarray
    high: np.ndarray


def run_fit(problem: Any, *, out: Path | None = None, resume: bool = False,
            max_evaluations: int = DEFAULT_MAX_EVALUATIONS, starts: int = 1, progress: bool = False,
            noise_draws: int = NOISE_DRAWS, invert_start: bool = True) -> FitResult:
    """Fit ``problem`` (a :class:`~fabric_optics.fitting.problem.FitProblem`) by least squares; state in ``out``.

    ``max_evaluations``: the objective evaluations of the search in all (the start's, every step's
    and every Jacobian column's, over all starts); the uncertainty propagation afterwards is
    counted apart (``info["evaluations_uncertainty"]``).

    Parameters
    ----------
    problem : FitProblem
        The fit.
    out : Path, optional
        The ``--out`` folder the state is kept in (None: none kept).
    resume : bool, default False
        Continue the interrupted fit in ``out``.
    max_evaluations : int, default DEFAULT_MAX_EVALUATIONS
        The search's budget of objective evaluations.
    starts : int, default 1
        Starts of the search: the start point, then Latin-hypercube points.
    progress : bool, default False
        Show progress bars.
    noise_draws : int, default NOISE_DRAWS
        Noise draws of each part of the uncertainty.
    invert_start : bool, default True
        Start free dye knots from the measured colour inverted (:func:`fabric_optics.fitting.start.inverted_start`).

    Returns
    -------
    FitResult
        The fit, with the model at the start and at the result.

    Raises
    ------
    FitError
        For a state that cannot be resumed.
    """
    search = search_fit(problem, out=out, resume=resume, max_evaluations=max_evaluations, starts=starts,
                        progress=progress, invert_start=invert_start)
    return finish_fit(problem, search, noise_draws=noise_draws, with_model=True)


def search_fit(problem: Any, *, start: np.ndarray | None = None, bounds: tuple[np.ndarray, np.ndarray] | None = None,
               out: Path | None = None, resume: bool = False, max_evaluations: int = DEFAULT_MAX_EVALUATIONS,
               starts: int = 1, progress: bool = False, invert_start: bool = True) -> FitSearch:
    """The search of :func:`run_fit` alone: its best point, no uncertainty.

    A caller that fits the same problem several times and keeps one (:mod:`fabric_optics.fitting.spacemapping`'s
    colour weights) finishes only the kept one. ``start`` (default the config's values) and ``bounds`` (default the
    free parameters') are this search's.

    Parameters
    ----------
    problem : FitProblem or Surrogate
        The objective.
    start : numpy.ndarray, optional
        The start point, one value per free parameter.
    bounds : tuple of numpy.ndarray, optional
        ``(low, high)`` of the search.
    out : Path, optional
        The ``--out`` folder the state is kept in (None: none kept).
    resume : bool, default False
        Continue the interrupted fit in ``out``.
    max_evaluations : int, default DEFAULT_MAX_EVALUATIONS
        The search's budget of objective evaluations.
    starts : int, default 1
        Starts of the search: the start point, then Latin-hypercube points.
    progress : bool, default False
        Show progress bars.
    invert_start : bool, default True
        Start free dye knots from the measured colour inverted.

    Returns
    -------
    FitSearch
        The best point, the searches' results and why the search stopped.

    Raises
    ------
    FitError
        For a state that cannot be resumed.
    """
    t0 = time.perf_counter()
    problem.use_checkpoint(out)
    start = np.array(problem.start if start is None else start, float)
    low, high = _search_bounds(problem, bounds)
    span = high - low
    state, start_note = _resumed(problem, out) if resume else (None, "")
    x0 = start.copy() if state is None else np.array(state["x"], float)  # load_state refuses a point outside
    best: dict[str, Any] = {"F": math.inf, "x": x0.copy()}
    walk_bar, bar = _bars(problem, max_evaluations, progress)
    ev0 = problem.counters.evaluations
    memo: dict[str, Any] = {"x": None, "r": None}

    def used() -> int:
        return problem.counters.evaluations - ev0

    def fun_x(x: np.ndarray) -> np.ndarray:
        if memo["x"] is not None and np.array_equal(memo["x"], x):
            return memo["r"]
        if used() >= max_evaluations:
            raise _Budget
        try:
            r = problem.residuals(x)
        except CompareError as exc:
            r = _rejected(problem, memo["r"], exc)
        bar.update(1)
        memo.update(x=x.copy(), r=r)
        return r

    def accept(x: np.ndarray, r: np.ndarray) -> None:
        F = float(r @ r)
        if F < best["F"]:
            best.update(F=F, x=x.copy())
            bar.set_postfix(objective=f"{F:.5g}", walks=problem.counters.walks)
            if out is not None:
                save_state(out, problem, x, F)

    def phys(u: np.ndarray) -> np.ndarray:
        return low + np.clip(u, 0.0, 1.0) * span

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
    F_start = math.nan
    invert = state is None and invert_start
    try:
        x0, start_note = _inverted(problem, x0, start_note, invert)
        r_start = fun_x(start)
        F_start = float(r_start @ r_start)    # the start's objective stands even when the budget ends next
        accept(start, r_start)
        x0, start_note = _search_start(problem, start, x0, F_start, fun_x, start_note, invert=invert)
        for su in _start_points(problem, x0, low, span, starts if state is None else 1):
            results.append(least_squares(fun_u, np.clip(su, 0.0, 1.0), jac=jac_u, bounds=(0.0, 1.0), method="trf",
                                         x_scale=1.0, max_nfev=max_evaluations, ftol=1e-8, xtol=1e-8, gtol=1e-10))
    except _Budget:
        stopped = _budget_spent(max_evaluations, best["F"])
    finally:
        bar.close()
        walk_bar.close()
    return FitSearch(x=best["x"], objective_start=F_start, results=results, stopped=stopped, start_note=start_note,
                     evaluations=used(), max_evaluations=max_evaluations, resume=resume, out=out, t0=t0,
                     start=start, low=low, high=high)


def _rejected(problem: Any, last: np.ndarray | None, exc: CompareError) -> np.ndarray:
    """The residual of a trial point whose model ``compare`` cannot normalise: far above any other, not a traceback.

    Such a point (e.g. its normal/normal estimate from the neighbours is not positive) is rejected by the search
    and counted as an evaluation; at the start (no ``last`` residual) the fit cannot begin.
    """
    if last is None:
        raise FitError(f"the model at the start cannot be compared with the measurement: {exc}") from None
    problem.counters.evaluations += 1
    log.info("trial point rejected: %s", exc)
    return np.full(last.size, 1e3 / math.sqrt(last.size))


def _budget_spent(max_evaluations: int, best_objective: float) -> str:
    """The stop note of a search that spent its budget; a FitError when no evaluation was possible at all."""
    if not math.isfinite(best_objective):
        raise FitError(f"--max-evaluations {max_evaluations}: no evaluation was possible") from None
    return (f"the search stopped at its evaluation budget (--max-evaluations {max_evaluations}) before "
            "converging: the result is the best point evaluated")


def _search_bounds(problem: Any, bounds: tuple[np.ndarray, np.ndarray] | None) -> tuple[np.ndarray, np.ndarray]:
    """``(low, high)`` of a search: ``bounds`` as given, or the free parameters' own."""
    if bounds is None:
        return problem.low, problem.high
    return np.asarray(bounds[0], float), np.asarray(bounds[1], float)


def _start_points(problem: Any, x0: np.ndarray, low: np.ndarray, span: np.ndarray, starts: int) -> list[np.ndarray]:
    """The searches' start points in the unit cube: ``x0``, then ``starts - 1`` Latin-hypercube points (seeded)."""
    points = [(x0 - low) / span]
    if starts > 1:
        points += list(qmc.LatinHypercube(d=x0.size, seed=int(problem.seed or 0)).random(starts - 1))
    return points


def _inverted(problem: Any, x0: np.ndarray, start_note: str, invert: bool) -> tuple[np.ndarray, str]:
    """``(x0, note)``: with ``invert``, the start inverted from the measured colour and its note (no evaluation)."""
    if not invert:
        return x0, start_note
    x0, note = inverted_start(problem, x0)
    return x0, f"{start_note}; {note}" if start_note else note


def _search_start(problem: Any, start: np.ndarray, x0: np.ndarray, F_start: float, fun_x: Any, start_note: str, *,
                  invert: bool) -> tuple[np.ndarray, str]:
    """``(x0, note)``: the point the search starts from and the start's note.

    With ``invert``, the start inverted from the measured colour (``x0``,
    :func:`~fabric_optics.fitting.start.inverted_start`) is evaluated and starts the search unless the config's
    own values (``start``, objective ``F_start``) are nearer the measured colour or score better
    (:func:`_own_start_first`).
    """
    if invert and not np.array_equal(x0, start):
        r_inv = fun_x(x0)
        if _own_start_first(problem, start, x0, F_start, float(r_inv @ r_inv)):
            x0 = start.copy()
            start_note += ("; the config's own values are nearer the measured colour or score better than the "
                           "inverted start and start the search")
        else:
            start_note += "; the inverted start is nearer the measured colour and starts the search"
    return x0, start_note


def _bars(problem: Any, max_evaluations: int, progress: bool) -> tuple[Any, Any]:
    """The walk's and the search's progress bars (disabled without ``progress``); the walk's fed by the problem."""
    walk_bar = tqdm(total=None, desc="walk 1", unit="photon", unit_scale=True, disable=not progress, leave=False)
    bar = tqdm(total=max_evaluations, desc="fit", unit="eval", disable=not progress, leave=False)

    def walk_progress(photons: int, run: int, runs: int) -> None:
        if photons == 0 and run == 0:
            walk_bar.reset()
            walk_bar.set_description(f"walk {problem.counters.walks + 1}")
        walk_bar.n = photons
        walk_bar.set_postfix_str(f"run {run}/{runs}", refresh=False)
        walk_bar.refresh()

    problem.use_walk_progress(walk_progress if progress else None)
    return walk_bar, bar


def _resumed(problem: Any, out: Path | None) -> tuple[dict | None, str]:
    """``(state, note)`` of ``--resume``.

    The last accepted point of ``out/fit-state.json`` (its photons given to the problem: the walks are the
    interrupted fit's), or None when only finished Monte Carlo runs are on disk.
    """
    if out is None:
        raise FitError("--resume needs the output directory of the interrupted fit (--out)")
    state = load_state(out, problem)
    if state is None:
        if not WalkCheckpoint(out, "", (), np.zeros(1), None).count():
            raise FitError(f"--resume: nothing to resume in {out}: no {STATE_NAME} and no finished Monte Carlo "
                           "run (the fit was stopped before its first run finished); run without --resume")
        return None, (f"resumed: no point had been accepted; the finished Monte Carlo runs in {out / WALKS_DIR} "
                      "are read, not walked again")
    problem.use_photons(state.get("photons"))
    note = f"resumed from the last accepted point of {out / STATE_NAME} (objective {state['objective']:.6g})"
    log.info("%s", note)
    return state, note


def _own_start_first(problem: Any, start: np.ndarray, x0: np.ndarray, F_start: float, F_inv: float) -> bool:
    """Whether the config's own values start the search rather than the inverted start ``x0``.

    A config whose dye was fitted already (a preset's knots) may beat the inversion, which matches the colour only.
    The colour comes first (a fit left off in colour fails): the start nearer the measured colour (in tolerances),
    the lower objective when both are within the tolerance; from a start of another colour the search stays in that
    colour's basin.
    """
    off_own, off_inv = colour_distance(problem, start), colour_distance(problem, x0)
    if off_own <= 1.0 and off_inv <= 1.0:
        return F_inv > F_start
    if off_own <= 1.0 or off_inv <= 1.0:
        return off_own <= 1.0
    return off_own < off_inv


def finish_fit(problem: Any, search: FitSearch, *, noise_draws: int = NOISE_DRAWS, method: str | None = None,
               with_model: bool = False) -> FitResult:
    """The result of ``search`` (:func:`search_fit`).

    The uncertainty at its best point (:func:`~fabric_optics.fitting.uncertainty.propagate`), the warnings and
    fit.json's ``info``; the final state in the search's ``out``. ``with_model``: the model at the start and at the
    result too (the outputs' datasets).

    Parameters
    ----------
    problem : FitProblem or Surrogate
        The objective searched.
    search : FitSearch
        The search.
    noise_draws : int, default NOISE_DRAWS
        Noise draws of each part of the uncertainty.
    method : str, optional
        The method the result names (default: the problem's).
    with_model : bool, default False
        Also evaluate the model at the start and at the result.

    Returns
    -------
    FitResult
        The fit.
    """
    ev0 = problem.counters.evaluations
    x_best, results, stopped, start_note = search.x, search.results, search.stopped, search.start_note
    span = search.high - search.low
    r_best = problem.residuals(x_best)
    J = jacobian(problem, x_best, r_best, problem.residuals)
    beta_shape = problem.table(problem.config_at(x_best)).R.shape[:2]
    cov_data, cov_mc, u_rule = propagate(
        problem, x_best, r_best, J, problem.residuals,
        lambda rng: problem.residuals(x_best, mc_noise=rng.standard_normal(beta_shape)), noise_draws)
    cov, u, u_data, u_mc, u_notes = uncertainty_parts(cov_data, cov_mc)
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov / np.outer(u, u)
    corr[~np.isfinite(corr)] = 0.0
    bound_notes, ident_notes = at_bounds(problem, x_best), identifiability(problem, J, u, span)
    notes = ([stopped] if stopped else []) + bound_notes + ident_notes
    notes += colour_left_off_at(problem, x_best) + u_notes + ([u_rule["note"]] if "note" in u_rule else [])
    counts = problem.counters
    info = {
        "optimiser": "scipy.optimize.least_squares (trf, bounds scaled to [0, 1])",
        "starts": len(results) if results else 1, "status": [int(r.status) for r in results],
        "message": results[-1].message if results else stopped,
        "evaluations": search.evaluations, "max_evaluations": search.max_evaluations,
        "evaluations_uncertainty": counts.evaluations - ev0,
        "walks": counts.walks, "walk_seconds": counts.walk_seconds, "reweighted": counts.reweights,
        "walks_from_cache": counts.cached_walks,
        "reweighted_seconds": counts.reweight_seconds, "seconds": time.perf_counter() - search.t0,
        "photons": problem.photons, "resumed": search.resume, "start_note": start_note, "notes": list(problem.notes),
        "singular_values": np.linalg.svd(J * span[None, :], compute_uv=False).tolist(),
        "uncertainty": u_rule, "u_status": u_status(problem, bound_notes, ident_notes),
    }
    if search.out is not None:
        save_state(search.out, problem, x_best, float(r_best @ r_best), done=True)
    models = (problem.model(search.start), problem.model(x_best)) if with_model else (None, None)
    return FitResult(method=method or problem.method, names=tuple(p.name for p in problem.free), x=x_best,
                     start=search.start.copy(), objective=float(r_best @ r_best),
                     objective_start=search.objective_start, u=u, u_data=u_data, u_mc=u_mc, correlation=corr,
                     warnings=notes, info=info, stop=stopped, model_start=models[0], model_fit=models[1])
