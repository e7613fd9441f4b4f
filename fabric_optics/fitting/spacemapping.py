"""The Monte Carlo fit (``simulate fit --method mc``): output space mapping through the structured summation.

The woven/felt Monte Carlo costs tens of seconds per evaluation and is noisy, so it cannot be the objective of a
least-squares search. It is fitted through a cheap model that shares its parameters (output space mapping): the
**coarse model** is the structured summation of the same config (:class:`MCFitProblem`), the **fine model** the
Monte Carlo at fixed seeds (:func:`run_monte_carlo`). Iterate: run the Monte Carlo at ``x_k``; form the output
correction there (:func:`correction`: ``MC = S c + d``, multiplicative where the summation is not near zero,
additive elsewhere), so the surrogate (:class:`Surrogate`) equals the Monte Carlo at ``x_k`` and follows the
summation's trend around it; fit the surrogate by least squares (:func:`fabric_optics.fitting.search.search_fit`)
-> ``x_{k+1}``; run the Monte Carlo there. The result is the Monte-Carlo-evaluated point of lowest Monte Carlo
objective; with free dye knots the colour comes first (a run within the colour tolerance beats one outside it;
the surrogate fit raises its colour weight until its colour is within :data:`COLOUR_MARGIN` of the tolerance).
Parameters the summation cannot see (:data:`~fabric_optics.fitting.spec.FINE_FIELDS`, ``--mc-trend``) take a
first-order term from Monte Carlo runs themselves. ``--max-runs`` counts Monte Carlo runs (the start's included);
every run is checkpointed (:class:`~fabric_optics.fitting.state.MCState`) and ``--resume`` replays them.

Re-weighted runs. When every free parameter is a dye's (``--free dye``), a run after a traced one is not traced
again: the traced run's rays are re-weighted to the new dye (:mod:`simulate.raytrace.reweight`, correlated
sampling: the same ray paths, each event's weight the new table's over the probability the trace used), which
costs the new dye's table walk and a replay instead of the trace. It is kept while its error stays near a trace's
(:func:`reweight_accepted`); otherwise the run is traced (and recorded) again. ``--mc-retrace``
(``mc_retrace=True``) traces every run.

Public objects: :func:`run_mc_fit`, :class:`MCFitProblem`, :class:`Surrogate`, :func:`correction`,
:func:`run_monte_carlo`, :data:`DEFAULT_MC_RUNS`. The design's reasons and measured behaviour:
docs/notes/fit-trust.md ("The Monte Carlo fit").

References
----------
Bandler, Cheng, Dakroury, Mohamed, Bakr, Madsen and Sondergaard, "Space mapping: the state of the art", IEEE Trans.
Microwave Theory Tech. 52(1), 337-361 (2004). Koziel, Bandler and Madsen, "A space mapping framework for engineering
optimization: theory and implementation", IEEE MTT 54(10), 3721-3730 (2006). Bakr, Bandler, Biernacki, Chen and
Madsen, "A trust region aggressive space mapping algorithm for EM optimization", IEEE MTT 46(12), 2412-2425 (1998).
Nocedal and Wright, "Numerical Optimization", 2nd ed., 17.1 (the quadratic penalty method).
"""

from __future__ import annotations

import hashlib
import json
import logging
import math
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from fabric_optics import paths
from fabric_optics.fitting.errors import FitError
from fabric_optics.fitting.outputs import FitResult
from fabric_optics.fitting.problem import FitProblem, mixed_model
from fabric_optics.fitting.search import finish_fit, search_fit
from fabric_optics.fitting.start import knot_indices
from fabric_optics.fitting.state import MCRun, MCState
from fabric_optics.fitting.uncertainty import (
    NOISE_DRAWS,
    at_bounds,
    identifiability,
    jacobian,
    propagate,
    u_status,
    uncertainty_parts,
)
from fabric_optics.fitting.verdict import colour_distance, colour_left_off, colour_off
from simulate.config_table import ConfigError
from simulate.montecarlo.accuracy import relative_error
from simulate.products import Geometries, RunSettings, all_threads, check_blend, evaluate

__all__ = ["DEFAULT_MC_RUNS", "INNER_EVALUATIONS", "TINY", "MCFitProblem", "Surrogate", "correction",
           "run_monte_carlo", "run_mc_fit"]

log = logging.getLogger(__name__)

#: ``--max-runs`` default: Monte Carlo runs, the start's included
DEFAULT_MC_RUNS = 5
#: consecutive backtracking steps (half the step from the best run) after a run that did not improve
MAX_HALVINGS = 1
#: summation evaluations of each surrogate fit (fabric_optics.fitting.search.run_fit's budget)
INNER_EVALUATIONS = 400
#: below this share of the geometry's spectral peak of the summation the correction is additive
TINY = 0.05
#: a fine parameter's finite-difference step: this share of its value, at least FINE_STEP_SPAN of its bounds
FINE_STEP = 0.25
FINE_STEP_SPAN = 0.05
#: the surrogate fit holds a fine parameter within this many steps of the centre (the trust region)
FINE_TRUST = 2.0
#: with the colour first, the surrogate's colour is held within this share of the colour tolerance (the Monte
#: Carlo at the proposal differs from the surrogate's prediction by its noise and the correction's error)
COLOUR_MARGIN = 0.5
#: the colour weight's factor from one surrogate fit to the next while its colour is outside the margin
COLOUR_WEIGHT_STEP = 10.0
#: the largest colour weight of a surrogate fit, as a multiple of the problem's
MAX_COLOUR_WEIGHT_FACTOR = 1000.0
#: a re-weighted run's relative error over the target (or the traced run's, where larger), at most
#: (:func:`reweight_accepted`)
REWEIGHT_ERROR_FACTOR = 1.25
#: a re-weighted run's ray error over the traced run's at the same rays, at most (:func:`reweight_accepted`)
REWEIGHT_MAX_SPREAD = 2.0



def correction(s: np.ndarray, mc: np.ndarray, tiny: float = TINY) -> tuple[np.ndarray, np.ndarray]:
    """``(c, d)`` ``[G, L]`` with ``MC = S c + d``.

    Multiplicative where ``S > tiny max_lambda S`` of its geometry, additive elsewhere (module docstring).

    Parameters
    ----------
    s : numpy.ndarray
        The summation's radiance coefficients (geometries x wavelengths).
    mc : numpy.ndarray
        The Monte Carlo's at the same points.
    tiny : float, default TINY
        Share of the geometry's spectral peak below which the correction is additive.

    Returns
    -------
    c, d : numpy.ndarray
        The multiplicative (1 where additive) and additive (0 where multiplicative) corrections.
    """
    s = np.asarray(s, float)
    mc = np.asarray(mc, float)
    peak = np.max(np.abs(s), axis=1, keepdims=True)
    ratio = (s > tiny * peak) & (s > 0.0)
    c = np.where(ratio, mc / np.where(ratio, s, 1.0), 1.0)
    d = np.where(ratio, 0.0, mc - s)
    return c, d


class MCFitProblem(FitProblem):
    """The coarse model of the Monte Carlo fit.

    The summation of the config (a structured one for a felt or a weave), whose free parameters may include those
    only the Monte Carlo sees (:data:`FINE_FIELDS`).
    """

    def __init__(self, config: Any, measured: Any, free: list, *, method: str = "mc", mc_trend: Sequence[str] = (),
                 mc_retrace: bool = False, **settings: Any) -> None:
        if method != "mc":
            raise FitError(f"MCFitProblem fits the Monte Carlo (method 'mc'), got {method!r}")
        try:    # a blend: the felt's Monte Carlo traces it (one radius, index and slope); the woven one does not
            check_blend(config, "mc")
        except ConfigError as exc:
            raise FitError(f"--method mc: {exc}") from None
        super().__init__(config, measured, free, method="summation", fine_capable=True, **settings)
        names = [p.name for p in self.free]
        expanded: list[str] = []
        for name in mc_trend:
            try:
                full = paths.expand(name, self._doc)
            except paths.PathError as exc:
                raise FitError(f"--mc-trend {exc}") from None
            for path in full:
                if path not in names:
                    raise FitError(f"--mc-trend {name}: not a free parameter of this fit (free: {', '.join(names)}); "
                                   "name a parameter given to --free")
                expanded.append(path)
        #: free parameters (config paths) whose trend comes from the Monte Carlo although the summation sees them
        self.mc_trend = tuple(expanded)
        #: every Monte Carlo run traced, none re-weighted from an earlier one (module docstring)
        self.mc_retrace = bool(mc_retrace)
        #: the ``reuse`` of :func:`run_monte_carlo` when not given: the fit's last traced run (:func:`run_mc_fit`)
        self.mc_reuse: dict | None = None

    def reweights_runs(self) -> bool:
        """Whether the fit's runs may be re-weighted from a traced one (module docstring).

        Every free parameter a dye's and ``mc_retrace`` off.
        """
        return not self.mc_retrace and bool(self.free) and all(p.kind == "dye" for p in self.free)

    def fine_indices(self) -> list[int]:
        """The parameters whose trend comes from Monte Carlo runs: the fine ones and ``mc_trend``."""
        return [j for j, p in enumerate(self.free) if p.kind == "fine" or p.name in self.mc_trend]

    def fine_step(self, j: int, x: np.ndarray) -> float:
        """The finite-difference step of fine parameter ``j`` at ``x`` (module docstring).

        Parameters
        ----------
        j : int
            The fine parameter's index among the free parameters.
        x : numpy.ndarray
            The point, one value per free parameter.

        Returns
        -------
        float
            The step, negative where a forward step would leave the upper bound.
        """
        p = self.free[j]
        h = max(FINE_STEP * abs(float(x[j])), FINE_STEP_SPAN * (p.high - p.low))
        return -h if x[j] + h > p.high else h

    def identity(self) -> str:
        """The problem's identity, its checkpoints' key: the summation's, the method, the target, the trends."""
        doc = [super().identity(), "mc", self.target_rel_err] + ([sorted(self.mc_trend)] if self.mc_trend else [])
        return hashlib.sha256(json.dumps(doc).encode()).hexdigest()


class Surrogate:
    """The summation corrected to the Monte Carlo at a centre ``x_k`` (module docstring).

    An objective a search fits like a :class:`~fabric_optics.fitting.problem.FitProblem`, whose caches and counters
    it shares.

    Built by :meth:`at` (the correction that makes it equal the Monte Carlo values there); ``slope``: the Monte
    Carlo's own first-order term ``{j: D_j}`` in the parameters whose trend the summation lacks; ``colour_weight``
    the objective's (a surrogate fit that puts the colour first raises it); ``bounds`` the fit's (the fine
    parameters held near the centre). Immutable: a runner makes a new one for what it varies.
    """

    def __init__(self, base: MCFitProblem, centre: np.ndarray, corr: tuple, slope: dict | None = None, *,
                 colour_weight: float | None = None, bounds: tuple[np.ndarray, np.ndarray] | None = None) -> None:
        self._base = base
        self._centre = np.asarray(centre, float).copy()
        self._corr = corr
        self._slope = slope or None
        self._colour_weight = base.colour_weight if colour_weight is None else float(colour_weight)
        self._bounds = bounds

    @classmethod
    def at(cls, base: MCFitProblem, x: np.ndarray, mc_beta: np.ndarray, mc_u: np.ndarray,
           slope: dict | None = None, **kwargs: Any) -> Surrogate:
        """The surrogate equal to ``mc_beta`` (standard error ``mc_u``) at ``x``.

        Parameters
        ----------
        base : MCFitProblem
            The Monte Carlo fit.
        x : numpy.ndarray
            The centre, one value per free parameter.
        mc_beta, mc_u : numpy.ndarray
            The Monte Carlo run at ``x``: radiance coefficients and standard errors (geometries x
            wavelengths).
        slope : dict, optional
            The Monte Carlo's first-order term ``{j: D_j}`` (class docstring).
        **kwargs : Any
            ``colour_weight`` and ``bounds`` (class docstring).

        Returns
        -------
        Surrogate
            The surrogate.
        """
        s, _ = base.model(x)
        c, d = correction(s, mc_beta)
        return cls(base, x, (c, d, np.asarray(mc_u, float)), slope, **kwargs)

    def varied(self, **kwargs: Any) -> Surrogate:
        """The same surrogate with another ``colour_weight`` or ``bounds``.

        Parameters
        ----------
        **kwargs : Any
            ``colour_weight`` or ``bounds`` (class docstring).

        Returns
        -------
        Surrogate
            A new surrogate; this one is unchanged.
        """
        args = {"colour_weight": self._colour_weight, "bounds": self._bounds, **kwargs}
        return Surrogate(self._base, self._centre, self._corr, self._slope, **args)

    def __getattr__(self, name: str) -> Any:
        # everything but the model and the objective's weight is the coarse model's (its caches and counters)
        return getattr(self._base, name)

    colour_weight = property(lambda self: self._colour_weight)
    low = property(lambda self: self._base.low if self._bounds is None else self._bounds[0])
    high = property(lambda self: self._base.high if self._bounds is None else self._bounds[1])

    def holds_colour(self, colour_weight: float | None = None) -> bool:
        """Whether the objective holds the colour (the summation's rule at the surrogate's colour weight).

        Parameters
        ----------
        colour_weight : float, optional
            The weight of the colour terms (default: the surrogate's).

        Returns
        -------
        bool
            Whether the colour hold's terms are in the residual vector.
        """
        return self._base.holds_colour(self._colour_weight if colour_weight is None else colour_weight)

    def model_at_host(self, config: Any, mu_host: np.ndarray,
                      mc_noise: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """The surrogate at host absorption ``mu_host``: the summation's value with the correction applied.

        The colour start (:func:`fabric_optics.fitting.start.inverted_start`) reads the model through this, so
        the Monte Carlo fit inverts the measured colour through its own surrogate.

        Parameters
        ----------
        config : SimulationConfig
            The config of one fiber (one population).
        mu_host : numpy.ndarray
            The host absorption coefficient at each wavelength (1/um).
        mc_noise : numpy.ndarray, optional
            Standard normal draws passed to the summation.

        Returns
        -------
        beta, u_beta : numpy.ndarray
            The corrected radiance coefficients and the Monte Carlo run's standard errors (geometries x
            wavelengths).
        """
        beta, _ = self._base.model_at_host(config, mu_host, mc_noise)
        c, d, mc_u = self._corr
        return beta * c + d, mc_u

    def model(self, x: np.ndarray, mc_noise: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """``beta, u_beta`` ``[G, L]`` of the surrogate at ``x``: the summation with the correction applied.

        Parameters
        ----------
        x : numpy.ndarray
            One value per free parameter, in its physical units.
        mc_noise : numpy.ndarray, optional
            Standard normal draws passed to the summation.

        Returns
        -------
        beta, u_beta : numpy.ndarray
            The radiance coefficients and the Monte Carlo run's standard errors.
        """
        xs = np.asarray(x, float)
        if self._slope is not None:
            # the summation held at the centre in the parameters whose trend is the Monte Carlo's
            xs = xs.copy()
            for j in self._slope:
                xs[j] = self._centre[j]
        # a blend: its populations' surrogates mixed by share (the correction is affine: the mix's own)
        out, mc_u = mixed_model(self._base.config_at(xs), self._base.wavelengths_nm, self.model_at_host, mc_noise)
        if self._slope is not None:
            for j, Dj in self._slope.items():
                out = out + Dj * (float(x[j]) - float(self._centre[j]))
        return out, mc_u

    def residuals(self, x: np.ndarray, measured: Any = None, mc_noise: np.ndarray | None = None) -> np.ndarray:
        """The residual vector of the surrogate at ``x`` (the summation's residuals of its model values).

        Parameters
        ----------
        x : numpy.ndarray
            One value per free parameter, in its physical units.
        measured : Dataset, optional
            A noise draw of the measurement with its rows (default: the measurement itself).
        mc_noise : numpy.ndarray, optional
            Standard normal draws passed to the summation.

        Returns
        -------
        numpy.ndarray
            The residual vector, at the surrogate's colour weight.
        """
        beta, u = self.model(x, mc_noise)
        return self._base.residuals_of_model(beta, u, measured, colour_weight=self._colour_weight)


def _key(x: np.ndarray) -> tuple:
    return tuple(np.round(np.asarray(x, float), 12).tolist())


def reweight_accepted(info: dict, target_rel_err: float, traced_rel_err: float) -> bool:
    """Whether a re-weighted run (:func:`simulate.raytrace.reweight.reweighted_beta`'s ``info``) replaces a trace.

    Its relative standard error (rays and table, computed from the re-weighted rays as a trace computes its own)
    is at most :data:`REWEIGHT_ERROR_FACTOR` times the run's target, or the traced run's own error where that is
    larger (a felt's table and realisations put a trace at the target slightly above it): a re-weighted run then
    carries at most 25 % more error than a trace -- what a trace of 64 % of the rays would -- at a fraction of
    its cost, and its ``u_beta`` says so to the fit's uncertainty. And its ray error is at most
    :data:`REWEIGHT_MAX_SPREAD` times the traced run's at the same rays (an effective sample of at least a quarter
    of the rays): beyond that the weights' tails make the error's own estimate unsure. Measured over the dyes a
    fit explores: docs/notes/reweighted-mc.md.

    Parameters
    ----------
    info : dict
        The re-weighted run's ``info`` (``rel_err``, ``spread``).
    target_rel_err : float
        The runs' target relative standard error.
    traced_rel_err : float
        The relative standard error of the traced run it was re-weighted from.

    Returns
    -------
    bool
        Whether the re-weighted run is used.
    """
    spread = float(info.get("spread", math.inf))
    return (float(info["rel_err"]) <= REWEIGHT_ERROR_FACTOR * max(float(target_rel_err), float(traced_rel_err))
            and math.isfinite(spread) and spread <= REWEIGHT_MAX_SPREAD)


def run_monte_carlo(problem: MCFitProblem, x: np.ndarray, *, progress: bool = False,
                    reuse: dict | None = None) -> MCRun:
    """The woven/felt Monte Carlo (``simulate fabric --method mc``) at the measured geometries for ``x``.

    ``reuse`` (a dict the caller keeps across runs that differ in their dyes alone, :meth:`MCFitProblem.reweights_runs`;
    default ``problem.mc_reuse``): the last traced run's ray events; the run is re-weighted from them when
    :func:`reweight_accepted`, else traced and recorded there. ``reuse["last"]`` then says how the run was made.

    Parameters
    ----------
    problem : MCFitProblem
        The Monte Carlo fit.
    x : numpy.ndarray
        One value per free parameter, in its physical units.
    progress : bool, default False
        Show the trace's progress bar.
    reuse : dict, optional
        The ray events kept across runs (see above).

    Returns
    -------
    MCRun
        The run's values, cost and figures against the measurement.
    """
    if reuse is None:
        reuse = getattr(problem, "mc_reuse", None)
    config = problem.config_at(x)
    wl = problem.wavelengths_nm
    g = problem.geometries
    geoms = Geometries(*(g[c].to_numpy(float) for c in ("theta_i", "phi_i", "theta_o", "phi_o")))
    t0 = time.perf_counter()
    beta: np.ndarray | None = None
    rays = 0
    if reuse is not None and reuse.get("record"):
        from simulate.products import reweighted_estimate

        try:
            b, u, info = reweighted_estimate(reuse["record"], config, wl)
        except ValueError as exc:
            log.info("mc run not re-weighted (%s): traced", exc)
            reuse["last"] = {"reweighted": False, "reason": str(exc)}
        else:
            ok = reweight_accepted(info, problem.target_rel_err, reuse["rel_err"])
            reuse["last"] = {"reweighted": ok, "from_run": reuse.get("run"), "rel_err": info["rel_err"],
                             "spread": info["spread"], "seconds": time.perf_counter() - t0}
            if ok:
                beta, u_beta, rays = b, u, int(info["rays"])
    if beta is None:
        record: dict | None = {} if reuse is not None else None
        est = evaluate("mc", config, config.fiber(wl), geoms, wl,
                       RunSettings(target=problem.target_rel_err, seed=int(problem.seed or 0),
                                   threads=all_threads(problem.threads), progress=progress, record=record))
        beta, u_beta, rays = np.asarray(est.beta, float), np.asarray(est.u_beta, float), int(est.info.get("rays", 0))
        if reuse is not None:
            reuse.setdefault("last", {"reweighted": False})
            reuse.update(record=record if record else None, rel_err=float(relative_error(beta, u_beta)),
                         run=reuse.get("next"))
    fig = problem.residual_model().evaluate(beta, u_beta)
    r = fig.vector(problem.colour_weight, problem.level_weight)
    return MCRun(x=np.asarray(x, float).copy(), beta=np.asarray(beta, float), u_beta=np.asarray(u_beta, float),
                 seconds=time.perf_counter() - t0, rays=rays,
                 rel_err=float(relative_error(beta, u_beta)), objective=float(r @ r),
                 nrmse=float(fig.nrmse), dh=float(getattr(fig, "dh", math.nan)), ds=float(getattr(fig, "ds", math.nan)))


def _colour_first(problem: MCFitProblem) -> bool:
    """Whether the fit puts the colour first (module docstring, "The colour first").

    Free dye knots, a colour weight above zero and a measurement with a colour.
    """
    return (problem.colour_weight > 0 and bool(knot_indices([p.name for p in problem.free]))
            and problem.residual_model().has_colour)


def _better(run: MCRun, best: MCRun, colour_first: bool) -> bool:
    """Whether ``run`` replaces ``best``.

    The lower Monte Carlo objective; with the colour first, a run within the colour tolerance beats one outside it,
    and of two outside it the nearer the measured colour wins (the rule of the colour start,
    :func:`fabric_optics.fitting.search.run_fit`).
    """
    if colour_first:
        a, b = colour_off(run.dh, run.ds), colour_off(best.dh, best.ds)
        if a > 1.0 or b > 1.0:
            return a < b
    return run.objective < best.objective


def _surrogate_fit(surrogate: Surrogate, x: np.ndarray, colour_first: bool, noise_draws: int = NOISE_DRAWS,
                   **kwargs: Any) -> tuple[FitResult, list[float], Surrogate]:
    """The surrogate fit of one iteration from ``x``, the colour weights it used and the surrogate it kept.

    Fitted at the problem's colour weight; with the colour first and the surrogate's colour further than
    :data:`COLOUR_MARGIN` tolerances from the measured, fitted again from that point with the weight
    :data:`COLOUR_WEIGHT_STEP` times larger, up to :data:`MAX_COLOUR_WEIGHT_FACTOR` times the problem's. Only the
    kept (last) fit's uncertainty is computed: the searches at the smaller weights only lead to its start.
    """
    w0 = surrogate.colour_weight
    weights = [w0]
    bounds = (surrogate.low, surrogate.high)
    search = search_fit(surrogate, start=x, bounds=bounds, out=None, invert_start=True, **kwargs)
    while (colour_first and colour_distance(surrogate, search.x) > COLOUR_MARGIN
           and surrogate.colour_weight * COLOUR_WEIGHT_STEP <= MAX_COLOUR_WEIGHT_FACTOR * w0 * (1 + 1e-9)):
        surrogate = surrogate.varied(colour_weight=surrogate.colour_weight * COLOUR_WEIGHT_STEP)
        weights.append(surrogate.colour_weight)
        log.info("surrogate colour %.3g tolerances off: fitted again at colour weight %g",
                 colour_distance(surrogate, search.x), surrogate.colour_weight)
        search = search_fit(surrogate, start=search.x.copy(), bounds=bounds, out=None, invert_start=True, **kwargs)
    return finish_fit(surrogate, search, noise_draws=noise_draws), weights, surrogate


def _uncertainty(problem: MCFitProblem, x: np.ndarray, beta: np.ndarray, u_beta: np.ndarray, draws: int,
                 slope: dict | None, data: bool = True) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict]:
    """``(J, cov_data, cov_mc, rule)`` at ``x``, through the surrogate equal to the Monte Carlo there.

    :func:`~fabric_optics.fitting.uncertainty.propagate` of the surrogate equal to the Monte Carlo
    ``beta, u_beta`` at ``x``: the Monte Carlo part perturbs the correction by the run's standard errors
    (the summation's own table noise cancels in ``S(x)/S(x*)`` to first order); ``data=False``: the Monte
    Carlo part only.
    """
    surrogate = Surrogate.at(problem, x, beta, u_beta, slope)
    r0 = surrogate.residuals(x)
    J = jacobian(problem, x, r0, surrogate.residuals)

    def mc_residuals(rng: np.random.Generator) -> np.ndarray:
        drawn = Surrogate.at(problem, x, beta + u_beta * rng.standard_normal(beta.shape), u_beta, slope)
        return drawn.residuals(x)

    cov_data, cov_mc, rule = propagate(problem, x, r0, J, surrogate.residuals, mc_residuals, draws, data=data)
    return J, cov_data, cov_mc, rule


@dataclass
class _Search:
    """The Monte Carlo fit's loop state (:func:`run_mc_fit`): the runs made, the best, the Monte Carlo trend."""

    problem: MCFitProblem
    state: MCState
    colour_first: bool
    progress: bool
    echo: Callable[[str], None]
    runs: list[MCRun] = field(default_factory=list)
    #: every run by its parameters (the outputs' datasets are the runs at the start and at the result)
    by_x: dict[tuple, MCRun] = field(default_factory=dict)
    iterations: list[dict] = field(default_factory=list)
    best: MCRun | None = None
    halvings: int = 0
    fine_runs: int = 0
    #: ``{j: D_j}``: the Monte Carlo's first-order term in the parameters whose trend the summation lacks
    slope: dict | None = None
    def run(self, k: int, x: np.ndarray) -> tuple[MCRun, bool, dict]:
        """Monte Carlo run ``k`` at ``x``.

        From the checkpoint, or made (traced or re-weighted) and checkpointed; and how it was made
        (``{"reweighted": bool, ...}``, empty when read from the checkpoint).
        """
        run = self.state.run(k, x)
        cached = run is not None
        how: dict = {}
        if run is None:
            reuse = self.problem.mc_reuse
            if reuse is not None:
                reuse.pop("last", None)
                reuse["next"] = k
            run = run_monte_carlo(self.problem, x, progress=self.progress)
            how = dict(reuse.get("last") or {}) if reuse is not None else {}
            self.state.put_run(k, run)
        return run, cached, how

    def fine_trend(self, k: int, x: np.ndarray, run: MCRun, fine: list[int]) -> None:
        """The fine parameters' trend from the Monte Carlo itself (module docstring): one run per parameter."""
        problem = self.problem
        D = {}
        for j in fine:
            h = problem.fine_step(j, x)
            xj = x.copy()
            xj[j] += h
            fr = self.state.fine_run(k, j, xj)
            fr_cached = fr is not None
            if fr is None:
                fr = run_monte_carlo(problem, xj, progress=self.progress)
                self.state.put_fine_run(k, j, fr)
            self.fine_runs += 1
            self.by_x[_key(xj)] = fr
            D[j] = (fr.beta - run.beta) / h
            self.iterations[-1].setdefault("fine_runs", []).append(
                {"parameter": problem.free[j].name, "h": h, **fr.record(), "cached": fr_cached})
            self.echo(f"mc run {k}, trend in {problem.free[j].name} ({xj[j]:.4g}): "
                      + _line(k, fr, None, fr_cached).split(": ", 1)[1])
            assert self.best is not None
            if _better(fr, self.best, self.colour_first):
                self.best, self.halvings = fr, 0
        self.slope = D

    def propose(self, x: np.ndarray, run: MCRun, fine: list[int], *, starts: int, noise_draws: int,
                inner_evaluations: int) -> dict:
        """The surrogate fit from run ``run`` at ``x`` and its proposal (module docstring).

        The colour start through the surrogate (free dye knots: the measured colour inverted through the
        summation corrected to this run; the search starts from it or from ``x``, the better), the colour held
        within the margin by raising its weight, the fine parameters held near ``x``.
        """
        problem = self.problem
        t1 = time.perf_counter()
        ev0 = problem.counters.evaluations
        low, high = problem.low.copy(), problem.high.copy()
        for j in fine:
            reach = FINE_TRUST * abs(problem.fine_step(j, x))
            low[j], high[j] = max(problem.low[j], x[j] - reach), min(problem.high[j], x[j] + reach)
        surrogate = Surrogate.at(problem, x, run.beta, run.u_beta, self.slope, bounds=(low, high))
        res, weights, surrogate = _surrogate_fit(surrogate, x.copy(), self.colour_first,
                                                 max_evaluations=inner_evaluations, starts=starts,
                                                 progress=self.progress, noise_draws=noise_draws)
        # the proposal's Monte Carlo part: the surrogate's noise (the run's u_beta) at the proposal
        b_prop, u_b_prop = surrogate.model(res.x)
        _, _, cov_prop, _ = _uncertainty(problem, res.x, b_prop, u_b_prop, noise_draws, self.slope, data=False)
        u_prop = np.sqrt(np.nan_to_num(res.u_data) ** 2 + np.maximum(np.diag(cov_prop), 0.0))
        fig_prop = problem.residual_model().evaluate(b_prop)
        return {"kind": "surrogate fit", "x": res.x.tolist(), "u": u_prop.tolist(),
                "surrogate_objective": res.objective, "start_note": res.info.get("start_note", ""),
                "colour_weights": weights, "surrogate_nrmse": float(fig_prop.nrmse),
                "surrogate_dh": float(getattr(fig_prop, "dh", math.nan)),
                "surrogate_ds": float(getattr(fig_prop, "ds", math.nan)),
                "surrogate_evaluations": problem.counters.evaluations - ev0,
                "seconds": time.perf_counter() - t1,
                "notes": [n for n in res.warnings if not n.startswith(("the search stopped", "colour left off"))]}


def run_mc_fit(problem: MCFitProblem, *, out: Path | None = None, resume: bool = False,
               max_runs: int = DEFAULT_MC_RUNS, starts: int = 1, progress: bool = False,
               noise_draws: int = NOISE_DRAWS, inner_evaluations: int = INNER_EVALUATIONS,
               echo: Callable[[str], None] | None = None, **refused: Any) -> FitResult:
    """Fit the Monte Carlo to ``problem.measured`` by output space mapping (module docstring).

    ``max_runs``: Monte Carlo runs in all (the start's included, >= 2). The result's ``info["iterations"]`` lists
    the runs; its model values are the Monte Carlo runs at the start and at the result.

    Parameters
    ----------
    problem : MCFitProblem
        The Monte Carlo fit.
    out : Path, optional
        The ``--out`` folder its state and runs are kept in (None: none kept).
    resume : bool, default False
        Continue the interrupted fit in ``out``.
    max_runs : int, default DEFAULT_MC_RUNS
        Monte Carlo runs in all.
    starts : int, default 1
        Starts of each surrogate fit (:func:`fabric_optics.fitting.search.run_fit`).
    progress : bool, default False
        Show progress bars.
    noise_draws : int, default NOISE_DRAWS
        Noise draws of each part of the uncertainty.
    inner_evaluations : int, default INNER_EVALUATIONS
        Summation evaluations of each surrogate fit.
    echo : callable, optional
        Receives one line per run (default: standard error).
    **refused : Any
        Any other keyword (``max_evaluations`` among them) is refused.

    Returns
    -------
    FitResult
        The fit.

    Raises
    ------
    FitError
        For fewer than 2 runs, ``resume`` without ``out``, or a state that cannot be resumed.
    TypeError
        For another keyword.
    """
    if refused:
        name = next(iter(refused))
        if name == "max_evaluations":
            raise TypeError("run_mc_fit(max_evaluations=...): the Monte Carlo fit's budget counts Monte Carlo runs; "
                            "pass max_runs=")
        raise TypeError(f"run_mc_fit() got an unexpected keyword argument {name!r}")
    if max_runs < 2:
        raise FitError(f"--max-runs {max_runs}: --method mc needs at least 2 Monte Carlo runs "
                       "(the start and one proposal)")
    t0 = time.perf_counter()
    problem.use_checkpoint(out)
    start = problem.start.copy()
    state = MCState(out, problem.identity(), (len(problem.geometries), problem.wavelengths_nm.size))
    if resume:
        if out is None:
            raise FitError("--resume needs the output directory of the interrupted fit (--out)")
        state.load(problem)
    S = _Search(problem, state, _colour_first(problem), progress, echo or _stderr)
    problem.mc_reuse = {} if problem.reweights_runs() else None
    x = start.copy()
    stop = ""
    surrogate_evals = 0
    inner_notes: list[str] = []
    u_prev: np.ndarray | None = None
    fine = problem.fine_indices()
    for k in range(max_runs):
        run, cached, how = S.run(k, x)
        dx = None if not S.runs else float(np.max(np.abs(x - S.runs[-1].x)))
        S.runs.append(run)
        S.by_x[_key(x)] = run
        S.iterations.append({"k": k, **run.record(), "cached": cached, **({"made": how} if how else {}),
                             "dx": None if not k else (x - S.runs[-2].x).tolist()})
        S.echo(_line(k, run, dx, cached) + (f", re-weighted from run {how.get('from_run')}"
                                            if how.get("reweighted") else ""))
        if S.best is None or _better(run, S.best, S.colour_first):
            before, S.best, S.halvings = S.best, run, 0
            if before is not None and u_prev is not None and np.all(np.abs(run.x - before.x) <= u_prev):
                stop = f"converged: every parameter step of run {k} is within its standard uncertainty"
                break
        else:
            S.halvings += 1
            if S.halvings > MAX_HALVINGS or (u_prev is not None and np.all(np.abs(run.x - S.best.x) <= 2 * u_prev)):
                stop = (f"the Monte Carlo objective did not decrease at run {k} ({run.objective:.5g} >= "
                        f"{S.best.objective:.5g}, the best run's) and a shorter step would be within the "
                        "uncertainty or was tried: the best run is kept")
                break
        used = len(S.runs) + S.fine_runs
        if used >= max_runs:
            stop = f"the budget of Monte Carlo runs is spent (--max-runs {max_runs})"
            break
        prop = state.proposal(k)
        if prop is None and run is not S.best:
            # backtrack: half the step from the best run (the correction stays the best run's)
            prop = {"kind": "backtrack", "x": (S.best.x + 0.5 * (run.x - S.best.x)).tolist(),
                    "u": (u_prev if u_prev is not None else np.zeros(x.size)).tolist(), "surrogate_evaluations": 0}
            state.put_proposal(k, prop)
        if fine and (prop is None or prop.get("kind") == "surrogate fit"):
            if prop is None and used + len(fine) + 1 > max_runs:
                stop = (f"the budget of Monte Carlo runs is spent (--max-runs {max_runs}): "
                        f"{max_runs - used} left, the trend in the {len(fine)} parameter(s) only the "
                        "Monte Carlo sees and the proposal need " f"{len(fine) + 1}")
                break
            S.fine_trend(k, x, run, fine)
        if prop is None:
            prop = S.propose(x, run, fine, starts=starts, noise_draws=noise_draws,
                             inner_evaluations=inner_evaluations)
            state.put_proposal(k, prop)
        surrogate_evals += int(prop["surrogate_evaluations"])
        inner_notes = list(prop.get("notes") or inner_notes)
        S.iterations[-1]["proposal"] = prop
        x = np.clip(np.asarray(prop["x"], float), problem.low, problem.high)
        u_prev = np.asarray(prop["u"], float)
    problem.mc_reuse = None       # the traced run's events: not kept past the fit
    return _finish(S, start, fine, inner_notes, noise_draws,
                   {"stop": stop, "message": stop, "starts": starts, "max_runs": max_runs,
                    "surrogate_evaluations": surrogate_evals, "seconds": time.perf_counter() - t0, "resumed": resume})


def _finish(S: _Search, start: np.ndarray, fine: list[int], inner_notes: list[str], noise_draws: int,
            run: dict) -> FitResult:
    """The result at the best run: its uncertainty through the surrogate there, the warnings, fit.json's info."""
    problem = S.problem
    stop = run["stop"]
    best = S.best
    assert best is not None
    J, cov_data, cov_mc, u_rule = _uncertainty(problem, best.x, best.beta, best.u_beta, noise_draws, S.slope)
    cov, u, u_data, u_mc, u_notes = uncertainty_parts(cov_data, cov_mc)
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov / np.outer(u, u)
    corr[~np.isfinite(corr)] = 0.0
    bound_notes, ident_notes = at_bounds(problem, best.x), identifiability(problem, J, u)
    notes = bound_notes + ident_notes + u_notes + ([u_rule["note"]] if "note" in u_rule else [])
    left_off = colour_left_off(problem, best.dh, best.ds, method="mc")
    if left_off:
        notes.append(left_off)
    notes += [f"last surrogate fit: {n}" for n in inner_notes if n not in notes]
    if fine:
        notes.append("the uncertainty of " + ", ".join(problem.free[j].name for j in fine) + " is a lower bound: "
                     "the Monte Carlo noise of its finite-difference trend is not in it")
    info = _info(S, J, u_rule, u_status(problem, bound_notes, ident_notes), run)
    first, last = S.by_x[_key(start)], S.by_x[_key(best.x)]
    return FitResult(method="mc", names=tuple(p.name for p in problem.free), x=best.x.copy(), start=start.copy(),
                     objective=best.objective, objective_start=S.runs[0].objective, u=u, u_data=u_data, u_mc=u_mc,
                     correlation=corr, warnings=notes, info=info, stop=stop,
                     model_start=(first.beta, first.u_beta), model_fit=(last.beta, last.u_beta))


def _stderr(text: str) -> None:
    print(text, file=sys.stderr, flush=True)


def _info(S: _Search, J: np.ndarray, u_rule: dict, u_status: list[str], run: dict) -> dict:
    """fit.json's ``info`` of a Monte Carlo fit (``run``: its stop, starts, budget, counts and time)."""
    problem, runs, iterations, best = S.problem, S.runs, S.iterations, S.best
    assert best is not None
    fine_records = [f for it in iterations for f in it.get("fine_runs", [])]
    done = sum(1 for it in iterations if not it["cached"]) + sum(1 for f in fine_records if not f["cached"])
    span = problem.high - problem.low
    counts = problem.counters
    return {
        "optimiser": "output space mapping (Bandler et al. 2004; Koziel et al. 2006): the structured summation "
                     "corrected to the Monte Carlo, fitted by scipy.optimize.least_squares (trf)",
        "correction": f"multiplicative MC/S per (geometry, wavelength); additive MC - S where S <= {TINY} of the "
                      "geometry's spectral peak",
        "stop": run["stop"], "message": run["message"], "starts": run["starts"],
        "evaluations": len(runs) + S.fine_runs, "max_evaluations": run["max_runs"],
        "evaluations_meaning": "Monte Carlo runs", "mc_runs": len(runs) + S.fine_runs, "mc_runs_done": done,
        "fine_trend_runs": S.fine_runs,
        "mc_reweighted_runs": sum(1 for it in iterations if it.get("made", {}).get("reweighted")),
        "mc_retrace": problem.mc_retrace,
        "mc_seconds": float(sum(r.seconds for it, r in zip(iterations, runs, strict=True) if not it["cached"])
                            + sum(f["seconds"] for f in fine_records if not f["cached"])),
        "surrogate_evaluations": run["surrogate_evaluations"], "summation_walks": counts.walks,
        "walks": counts.walks + done, "walk_seconds": counts.walk_seconds,
        "reweighted": counts.reweights, "seconds": run["seconds"], "resumed": run["resumed"],
        "best_run": next((i for i, r in enumerate(runs) if r is best), None),
        "best_x": best.x.tolist(), "iterations": iterations, "notes": list(problem.notes),
        "start_note": "the first Monte Carlo run is at the config's values (a Monte Carlo preset such as "
                      "green-felt-mc, or a summation fit's fitted.toml); with free dye knots every surrogate fit "
                      "starts from the measured colour inverted through the surrogate (the summation corrected to "
                      "the run), or from the run's own values when they score better",
        "singular_values": np.linalg.svd(J * span[None, :], compute_uv=False).tolist(),
        "target_rel_err": problem.target_rel_err,
        "uncertainty": u_rule, "u_status": u_status,
    }


def _line(k: int, run: MCRun, dx: float | None, cached: bool) -> str:
    step = "" if dx is None else f", max |dx| {dx:.3g}"
    how = "read from the checkpoint" if cached else f"{run.seconds:.1f} s"
    return (f"mc run {k}: NRMSE {run.nrmse:.4f}, dh {run.dh:+.4f}, ds {run.ds:+.4f}, objective {run.objective:.5g}"
            f"{step} ({how}, rel. error {run.rel_err:.3g})")
