"""The fitted parameters' uncertainties: noise draws through the whole objective, and what they say.

Linear propagation at the solution with the Jacobian ``J`` (``dp = -J^+ dr``): the measurement's ``u_beta`` by noise
draws of the measured dataset, each run through the whole objective (the normalisation at the normal and the colour
included, so their correlations are exact to first order), and the model's Monte Carlo standard error the same way
(:func:`propagate`: ONE routine for every method; the model's part is a callable of the method). ``u`` is the square
root of the summed covariance's diagonal. A measurement without ``u_beta`` gets the data part scaled by the residual
(:func:`residual_scaled_draws`). A parameter at a bound (:func:`at_bounds`) or in a flat direction
(:func:`identifiability`) is reported with its status, not a number (:func:`u_status`).

Public objects: :func:`propagate`, :func:`uncertainty_parts`, :func:`at_bounds`, :func:`identifiability`,
:func:`u_status`, :func:`residual_covariance`, :func:`residual_scaled_draws`, :func:`measurement_has_u`,
:func:`jacobian`.
"""

from __future__ import annotations

import logging
import math
import re
from collections.abc import Callable
from typing import Any

import numpy as np

from compare.errors import CompareError
from gonio.data.dataset import Dataset, make_dataset

__all__ = ["NOISE_DRAWS", "propagate", "uncertainty_parts", "at_bounds", "identifiability", "u_status",
           "residual_covariance", "residual_scaled_draws", "measurement_has_u", "unweighted_rows", "jacobian",
           "RESIDUAL_RULE", "RESIDUAL_DRAWS_RULE", "DATA_RULE"]

log = logging.getLogger(__name__)

#: noise draws of each part (the measurement's, the Monte Carlo's)
NOISE_DRAWS = 64
#: the seed of the draws: this plus the fit's seed
DRAW_SEED = 20260101
_AT_BOUND = 1e-3
_FLAT = 1e-3
#: finite-difference steps of :func:`jacobian`: a walked parameter's (forward, this share of its value) and a
#: table-read parameter's (central, this share of its bound range)
WALK_STEP = 0.10
CHEAP_STEP = 1e-3
#: the rule of the data part of ``u`` for a measurement with ``u_beta`` (fit.json ``uncertainty``)
DATA_RULE = {"data": "u_beta", "rule": "the measurement's u_beta propagated by noise draws"}


def jacobian(problem: Any, x: np.ndarray, r0: np.ndarray, fun: Callable) -> np.ndarray:
    """D r / d x (physical units) by finite differences.

    Forward, :data:`WALK_STEP` of the value, for walked parameters (common random numbers reduce but do not remove
    their noise); central, :data:`CHEAP_STEP` of the bound range, for the dye and surface parameters (table reads:
    smooth).

    Parameters
    ----------
    problem : FitProblem or Surrogate
        The fit (its free parameters and bounds).
    x : numpy.ndarray
        The point, one value per free parameter.
    r0 : numpy.ndarray
        The residual vector at ``x``.
    fun : callable
        The residual vector at a point.

    Returns
    -------
    numpy.ndarray
        The Jacobian (residuals x parameters).
    """
    J = np.zeros((r0.size, x.size))
    for j, p in enumerate(problem.free):
        span = p.high - p.low
        if p.kind == "walk":
            h = max(WALK_STEP * abs(x[j]), 1e-3 * span)
            if x[j] + h > p.high:
                h = -h
            J[:, j] = (fun(_with(x, j, x[j] + h)) - r0) / h
        else:
            h = CHEAP_STEP * span
            lo, hi = max(x[j] - h, p.low), min(x[j] + h, p.high)
            J[:, j] = (fun(_with(x, j, hi)) - fun(_with(x, j, lo))) / (hi - lo)
    return J


def _with(x: np.ndarray, j: int, v: float) -> np.ndarray:
    y = x.copy()
    y[j] = v
    return y


def propagate(problem: Any, x: np.ndarray, r0: np.ndarray, J: np.ndarray, residuals: Callable[..., np.ndarray],
              mc_residuals: Callable[[np.random.Generator], np.ndarray], draws: int, *,
              data: bool = True) -> tuple[np.ndarray, np.ndarray, dict]:
    """``(cov_data, cov_mc, rule)``: the parameters' covariance from the measurement's noise and from the model's.

    ``residuals(x, measured=noisy)`` is the objective at ``x`` against a noise draw of the measurement;
    ``mc_residuals(rng)`` the objective at ``x`` with the model perturbed by one draw of its Monte Carlo error (the
    method's own: the absorption table's standard errors, or the Monte Carlo run's behind a space-mapping
    correction). ``data=False``: the model's part only (``cov_data`` zero). A part whose draws were all refused
    (their normal/normal value not positive: compare cannot normalise them) is all-NaN; a part not drawn is zero.

    Parameters
    ----------
    problem : FitProblem or Surrogate
        The fit (its measurement and seed).
    x : numpy.ndarray
        The solution, one value per free parameter.
    r0 : numpy.ndarray
        The residual vector at ``x``.
    J : numpy.ndarray
        The Jacobian at ``x`` (:func:`jacobian`).
    residuals : callable
        The objective against a noise draw of the measurement.
    mc_residuals : callable
        The objective with the model perturbed by one draw of its Monte Carlo error.
    draws : int
        Noise draws of each part.
    data : bool, default True
        Draw the measurement's part.

    Returns
    -------
    cov_data, cov_mc : numpy.ndarray
        The two parts of the covariance (parameters x parameters).
    rule : dict
        How the data part was estimated.
    """
    pinv = np.linalg.pinv(J)
    rng = np.random.default_rng(DRAW_SEED + int(problem.seed or 0))
    meas = problem.measured
    n = x.size
    with_u = measurement_has_u(meas)
    rule: dict = dict(DATA_RULE)
    cov_data = np.zeros((n, n))
    refused = 0
    if data and not with_u:     # the same draws as a stated u_beta would get, scaled by the residual's noise
        cov_data, rule = residual_scaled_draws(problem, x, r0, J, rng, draws, residuals)
    elif data:
        dp_data = []
        for _ in range(draws):
            table = meas.table.copy()
            table["beta"] = table["beta"] + rng.standard_normal(len(table)) * table["u_beta"]
            try:
                dp_data.append(-pinv @ (residuals(x, measured=make_dataset(table, meas.meta)) - r0))
            except CompareError:
                # a draw whose normal/normal value is not positive (a value within ~1 u of zero) cannot be
                # normalised: left out
                refused += 1
        cov_data = _cov(dp_data, draws, n)
    dp_mc = []
    for _ in range(draws):
        try:
            dp_mc.append(-pinv @ (mc_residuals(rng) - r0))
        except CompareError:
            refused += 1
    if refused:
        log.warning("%d of %d noise draws left out of the uncertainty: their normal/normal value was not positive",
                    refused, (2 if data else 1) * draws)
    return cov_data, _cov(dp_mc, draws, n), rule


def _cov(shifts: list[np.ndarray], draws: int, n: int) -> np.ndarray:
    """The covariance of parameter shifts; all-NaN when every draw was refused, zero when none was drawn."""
    if shifts:
        return np.atleast_2d(np.cov(np.array(shifts).T, bias=True))
    return np.full((n, n), np.nan) if draws > 0 else np.zeros((n, n))


def uncertainty_parts(cov_data: np.ndarray, cov_mc: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray,
                                                                           np.ndarray, list[str]]:
    """``(cov, u, u_data, u_mc, notes)`` from the two parts' covariances of the parameters.

    A part whose noise draws were all refused (none could be normalised) is all-NaN: it could not be
    estimated. Its ``u_*`` is then NaN (``null`` in fit.json, "-" in the report), ``u`` holds the other
    part alone -- a lower bound -- and a note says so (printed with the fit's warnings).

    Parameters
    ----------
    cov_data, cov_mc : numpy.ndarray
        The parameters' covariance from the measurement's noise and from the model's.

    Returns
    -------
    cov : numpy.ndarray
        The covariance, the two parts added (a part not estimated counted as zero).
    u, u_data, u_mc : numpy.ndarray
        The standard uncertainties of the parameters in all and from each part.
    notes : list of str
        One note per part that could not be estimated.
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


def at_bounds(problem: Any, x: np.ndarray) -> list[str]:
    """A parameter within 10^-3 of its bound range from a bound: the optimum may lie beyond.

    Parameters
    ----------
    problem : FitProblem or Surrogate
        The fit (its free parameters and bounds).
    x : numpy.ndarray
        The solution, one value per free parameter.

    Returns
    -------
    list of str
        One note per parameter at a bound.
    """
    notes = []
    for p, v in zip(problem.free, x, strict=True):
        tol = _AT_BOUND * (p.high - p.low)
        side = "lower" if v - p.low <= tol else "upper" if p.high - v <= tol else ""
        if side:
            notes.append(f"at its {side} bound: {p.name} = {v:.6g} (bounds [{p.low:g}, {p.high:g}]); the best value "
                         f"may lie beyond: widen with --free {p.name}=LOW:HIGH")
    return notes


def identifiability(problem: Any, J: np.ndarray, u: np.ndarray, span: np.ndarray | None = None) -> list[str]:
    """A flat direction of the scaled Jacobian, or an uncertainty above half the bound range ``span``.

    A direction is flat when its singular value is below 10^-3 of the largest (the direction is named);
    ``span`` is by default the free parameters' bounds.

    Parameters
    ----------
    problem : FitProblem or Surrogate
        The fit (its free parameters and bounds).
    J : numpy.ndarray
        The Jacobian at the solution (residuals x parameters).
    u : numpy.ndarray
        The parameters' standard uncertainties.
    span : numpy.ndarray, optional
        The parameters' bound ranges.

    Returns
    -------
    list of str
        One note per flat direction or parameter too uncertain.
    """
    if span is None:
        span = problem.high - problem.low
    notes = []
    _, s, vt = np.linalg.svd(J * span[None, :], full_matrices=False)
    names = [p.name for p in problem.free]
    flagged: set[str] = set()
    for k in range(s.size):
        if s[0] == 0 or s[k] < _FLAT * s[0]:
            v = vt[k] / np.max(np.abs(vt[k]))
            terms = " ".join(f"{c:+.2f}*{n}" for c, n in zip(v, names, strict=True) if abs(c) > 0.2)
            notes.append(f"not identifiable: the objective is flat along {terms} (scaled singular value "
                         f"{s[k] / s[0] if s[0] else 0:.1e} of the largest)")
            flagged.update(n for c, n in zip(v, names, strict=True) if abs(c) > 0.2)
    for name, uu, sp in zip(names, u, span, strict=True):
        if name not in flagged and math.isfinite(uu) and uu > 0.5 * sp:
            notes.append(f"not identifiable: {name} has an uncertainty ({uu:.3g}) above half its bound range "
                         f"({sp:.3g})")
    return notes


def measurement_has_u(measured: Dataset) -> bool:
    """Whether the measurement states an uncertainty (some ``u_beta`` > 0; an RGL file's import has none).

    Parameters
    ----------
    measured : Dataset
        The measurement.

    Returns
    -------
    bool
        Whether any ``u_beta`` is positive.
    """
    u = measured.table["u_beta"].to_numpy(float)
    return bool(np.any(np.isfinite(u) & (u > 0)))


#: the rule of the data part of ``u`` for a measurement without ``u_beta`` (fit.json ``info.uncertainty``)
RESIDUAL_RULE = ("no measurement uncertainty (u_beta is 0): the data part of u is the least-squares covariance "
                 "scaled by the residual, s^2 (J^T J)^-1 with s^2 = SSR/(n - p) -- the residual taken as the "
                 "measurement's noise, so model error counts as noise")


def residual_covariance(J: np.ndarray, r: np.ndarray, unweighted: int = 0) -> tuple[np.ndarray, dict]:
    """``(cov, rule)``: the parameters' covariance ``s^2 (J^T J)^+``, with ``s^2 = SSR/(n - p)``.

    ``SSR`` is from the residual ``r`` at the solution: the usual least-squares rule for data without
    stated uncertainty.

    ``n`` counts the residuals that carry weight (``unweighted``: the colour terms at ``--colour-weight 0``), ``p``
    the free parameters. No degree of freedom left (``n <= p``): the covariance is NaN (no number is printed).

    Parameters
    ----------
    J : numpy.ndarray
        The Jacobian at the solution (residuals x parameters).
    r : numpy.ndarray
        The residual vector at the solution.
    unweighted : int, default 0
        Residual entries that carry no weight.

    Returns
    -------
    cov : numpy.ndarray
        The covariance (parameters x parameters), NaN without a degree of freedom.
    rule : dict
        How it was estimated: ``n``, ``p``, ``dof``, ``ssr``, ``s2`` and a note.
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


def residual_scaled_draws(problem: Any, x: np.ndarray, r0: np.ndarray, J: np.ndarray, rng: np.random.Generator,
                          draws: int, residuals: Callable | None = None) -> tuple[np.ndarray, dict]:
    """``(cov, rule)``: the data part of the parameters' covariance for a measurement without ``u_beta``.

    The rule is :data:`RESIDUAL_DRAWS_RULE`. Noise draws of 1 % of the mean ``|beta|`` on every value go through the whole
    objective (``residuals``, default the problem's): their parameter shifts ``-J^+ dr`` and the part of ``dr`` the
    re-fit cannot absorb, ``(I - J J^+) dr``, whose mean square calibrates ``SSR`` into ``sigma^2``. The plain rule
    ``s^2 (J^T J)^-1`` (:func:`residual_covariance`) treats the residuals as independent; the per-wavelength
    normalisation at the normal makes them correlated, and on synthetic data with known noise it underestimates u
    (docs/notes/fit-trust.md, "Honest uncertainties"; tests/fabric_optics/fitting/test_fit.py).

    Parameters
    ----------
    problem : FitProblem or Surrogate
        The fit (its measurement).
    x : numpy.ndarray
        The solution, one value per free parameter.
    r0 : numpy.ndarray
        The residual vector at ``x``.
    J : numpy.ndarray
        The Jacobian at ``x``.
    rng : numpy.random.Generator
        The noise draws' generator.
    draws : int
        Noise draws.
    residuals : callable, optional
        The objective against a noise draw of the measurement.

    Returns
    -------
    cov : numpy.ndarray
        The covariance (parameters x parameters), NaN when fewer than two draws could be evaluated.
    rule : dict
        How it was estimated: the noise ``sigma_beta``, ``ssr``, the draws and a note.
    """
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


def unweighted_rows(problem: Any) -> int:
    """The residual entries that carry no weight: the two colour terms at ``--colour-weight 0``.

    Parameters
    ----------
    problem : FitProblem or Surrogate
        The fit.

    Returns
    -------
    int
        2 or 0.
    """
    return 2 if problem.colour_weight <= 0 and problem.residual_model().has_colour else 0


def u_status(problem: Any, bound_notes: list[str], ident_notes: list[str]) -> list[str]:
    """Per free parameter.

    ``""`` (its ``u`` is a number), ``"at its lower bound"``/``"at its upper bound"`` or ``"not identifiable"`` --
    reported as such, not with a number (``u`` null in fit.json).

    Parameters
    ----------
    problem : FitProblem or Surrogate
        The fit (its free parameters).
    bound_notes : list of str
        The notes of :func:`at_bounds`.
    ident_notes : list of str
        The notes of :func:`identifiability`.

    Returns
    -------
    list of str
        One status per free parameter.
    """
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
