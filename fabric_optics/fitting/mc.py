r"""``simulate fit CONFIG MEASURED --method mc``: the woven/felt Monte Carlo fitted by output space mapping.

The Monte Carlo of ``simulate fabric --method mc`` (:mod:`simulate.woven`: rays through the felt's or
the weave's fibers, a BSSRDF yarn table per dye) costs tens of seconds per evaluation and is noisy,
so it cannot be the objective of a least-squares search (hundreds of evaluations, finite-difference
Jacobians). It is fitted through a cheap model that shares its parameters.

Design: output space mapping
----------------------------
Bandler, Cheng, Dakroury, Mohamed, Bakr, Madsen and Sondergaard, "Space mapping: the state of the
art", IEEE Trans. Microwave Theory Tech. 52(1), 337-361 (2004); Koziel, Bandler and Madsen, "A space
mapping framework for engineering optimization: theory and implementation", IEEE MTT 54(10),
3721-3730 (2006) (output space mapping, section III). The **coarse model** is the structured
summation of the same config (:class:`fabric_optics.fitting.problem.FitProblem` with ``method="summation"``:
its exit tables walked once, any dye read from their absorption nodes, no photon per evaluation);
the **fine model** is the Monte Carlo at fixed seeds. Iterate ``k = 0, 1, ...``:

1. run the Monte Carlo at ``x_k`` (seed of the config or ``--seed``, target ``--target-rel-err``);
2. form the output correction at ``x_k`` per (geometry, wavelength)::

       multiplicative  c = MC(x_k) / S(x_k)     where S(x_k) > TINY * max_lambda S(x_k)  (that geometry)
       additive        d = MC(x_k) - S(x_k)     elsewhere (a value near zero: a ratio would be noise)

   so the surrogate ``s_k(x) = S(x) c + d`` equals the Monte Carlo at ``x_k`` exactly (its standard
   error is the Monte Carlo's) and follows the summation's trend around it. ``TINY`` = 0.05 of the
   geometry's spectral peak (:data:`TINY`), the convention of the relative error of
   :func:`simulate.montecarlo.accuracy.relative_error`;
3. fit ``s_k`` to the measurement with the summation fit itself (:func:`fabric_optics.fitting.driver.run_fit`: the
   same objective ``NRMSE^2 + w_c (dh^2 + ds^2)``, trust-region search from ``x_k``, its walk
   re-used: no photon walked after the first iteration; with free dye knots the colour first, below)
   -> ``x_{k+1}`` with uncertainties;
4. run the Monte Carlo at ``x_{k+1}``. It is accepted when its Monte Carlo objective is below the best
   run's (with the colour first: when it is nearer the measured colour, below); the fit has converged when every parameter step ``|x_{k+1} - x_k|`` is within its standard
   uncertainty (the Monte Carlo cannot tell the two points apart). A run that does not improve is
   followed by one backtracking step, half the step from the best run (:data:`MAX_HALVINGS`; the
   trust-region idea of Bakr, Bandler, Biernacki, Chen and Madsen, "A trust region aggressive space
   mapping algorithm for EM optimization", IEEE MTT 46(12), 2412-2425 (1998), in its simplest form);
   the fit stops when that one does not improve either, or when half the step is within the
   uncertainty, or when the budget of Monte Carlo runs is spent.

The result is the Monte-Carlo-evaluated point of lowest Monte Carlo objective (never a point the
Monte Carlo did not see). The design does not need the two models to agree: only their *trend* in
the free parameters is borrowed from the summation, their level (a felt Monte Carlo ~16 % low for
absorbing fibers, the summation's missing forward sheen) is the correction's. Limit, stated by
Koziel et al.: the fixed point of a zero-order output correction is the fine model's optimum only
when the two models' Jacobians agree; a dye shifts both models through the same absorption table,
so the trend agrees well, and the Monte Carlo objective decides which point is kept.

The colour first
----------------
With free dye knots (and a colour weight above zero, a measurement with a colour) the fit puts the colour
first, as :func:`fabric_optics.fitting.driver.colour_left_off` judges it (a fit left off in colour fails):

* each surrogate fit whose colour (the surrogate's, at its result) is further than :data:`COLOUR_MARGIN` of
  :data:`fabric_optics.fitting.driver.COLOUR_TOLERANCE` from the measured one is fitted again from its result
  with the colour weight :data:`COLOUR_WEIGHT_STEP` times larger, up to :data:`MAX_COLOUR_WEIGHT_FACTOR` times the
  problem's (the quadratic penalty method, Nocedal and Wright, "Numerical Optimization", 2nd ed., 17.1: the
  colour tolerance as a constraint). The margin leaves room for the Monte Carlo at the proposal to differ from
  the surrogate's prediction. The proposal records the weights (``colour_weights``) and the surrogate's NRMSE,
  ``dh`` and ``ds`` there; the Monte Carlo runs and the result are scored at the problem's weight;
* of two runs, one within the colour tolerance is the better whatever the objectives, of two outside it the
  nearer the measured colour (in tolerances), of two within it the lower objective (the rule of the colour
  start). The backtracking and the convergence test follow this order.

Why: a measurement whose curves and colour no dye of the model matches at once. On the green felt's file
with its channels permuted (docs/notes/fit-trust.md) the surrogate predicts the Monte Carlo's colour at its
proposals within 0.003 turn, yet its optimum at colour weight 1 is itself 0.1 turn off in hue (NRMSE 0.19):
the curve error pays for the colour, and more runs only confirm that optimum.

Common random numbers: every Monte Carlo run uses the same seeds -- the BSSRDF yarn tables the same
photons per row (fixed by the target), the ray tracer the stream ``(seed, chunk)`` for chunk ``c``
(:func:`simulate.woven.integrator.trace`), so two runs share their rays up to the last block of
four chunks its accuracy control adds -- and the felt the same fiber placement. The difference of
two runs' objectives is then far less noisy than each.

A felt is a random realisation. The felt's fibers are placed by the seed (:func:`simulate.nonwoven.felt.felt_mesh`),
so a fixed seed fits the same realisations at every run (each table half traced on its own, at 8 azimuths:
:mod:`simulate.woven.estimate`, "A felt"). Before that (one realisation, one azimuth) two other seeds at
the same parameters differed by 6-16 % RMS in ``beta`` while the run's ``u_beta`` said ~0.9 %; the
fit's improvement carried over to both (objective -17 % and -22 %, seed 0's -19 %). ``u_beta`` now holds
the spread between realisations, so ``u_mc`` includes it.

Uncertainties
-------------
At the final point ``x*`` the correction is formed from the Monte Carlo at ``x*`` (the surrogate
equals it there) and the result is linearised with the surrogate's Jacobian ``J`` (finite
differences as :func:`fabric_optics.fitting.driver.jacobian`): ``u_data`` from 64 noise draws of the measurement's
``u_beta`` through the whole objective, ``u_mc`` from 64 draws of the Monte Carlo's ``u_beta`` at
``x*`` (the correction perturbed, the summation's own table noise cancels in ``S(x)/S(x*)`` to
first order), ``u = sqrt(u_data^2 + u_mc^2)`` -- the fields of the summation fit's ``fit.json``.

Parameters only the Monte Carlo sees
------------------------------------
The boundary's roughness for transmitted light (:data:`fabric_optics.fitting.problem.FINE_FIELDS`, docs/physics.md 3)
does not exist in the summation (it walks the smooth boundary), so a zero-order correction has no trend
to borrow for it: its surrogate Jacobian would be zero and the search would never move it. For these
*fine* parameters the surrogate takes its first-order term from the Monte Carlo itself -- the first-order
output space mapping of Koziel, Bandler and Madsen (2006, section III: the correction matching the fine
model's Jacobian), restricted to the parameters the coarse model cannot see::

    s_k(x) = S(x) c + d + sum_j D_j (x_j - x_k,j),     D_j = (MC(x_k + h_j e_j) - MC(x_k)) / h_j

one Monte Carlo run per fine parameter at each centre whose proposal is fitted (common random numbers:
the same seeds, felt and rays, so the difference is far less noisy than either run; ``h_j`` =
:data:`FINE_STEP` of the value, at least :data:`FINE_STEP_SPAN` of the bounds, backwards at the upper
bound). A linear term is trusted only near its centre: in the surrogate fit the fine parameters are held
within :data:`FINE_TRUST` steps of ``x_k`` (a trust region; the Monte Carlo objective then decides, as
for every proposal). These runs are Monte Carlo runs of the budget (``--max-runs``), are
checkpointed like the others (``mc-runs/run-K-dJ.npz``, listed under their centre in ``mc-state.json``)
and are candidates for the result like every run. The Monte Carlo's noise in ``D_j`` is not in ``u_mc``
(which perturbs the correction's level only): the fine parameters' uncertainties are a lower bound, and
the notes say so.

``--mc-trend NAME,...`` (:attr:`MCFitProblem.mc_trend`) treats free parameters the summation does see the
same way, for where the two models' trends disagree -- the felt's volume fraction, whose summation trend
points the other way (``simulate/configs/green-felt-mc.toml``'s header): the surrogate then holds the
summation at the centre in those parameters and takes their trend from the Monte Carlo alone.

Budget, progress, interrupt, resume
-----------------------------------
``--max-runs N`` (for ``--method mc``; the older ``--max-evaluations N`` means the same) counts
**Monte Carlo runs** (the start's included; default :data:`DEFAULT_MC_RUNS`, at least 2: the start and one
proposal); each surrogate fit has its own budget of :data:`INNER_EVALUATIONS` summation evaluations (table reads, no photon). One line per
Monte Carlo run on stderr (its NRMSE, dh, ds, objective, seconds) plus the Monte Carlo's and the
surrogate fit's progress bars. Every finished Monte Carlo run is written at once to
``DIR/mc-runs/run-K.npz`` (atomically) and listed in ``DIR/mc-state.json`` with its figures and,
once fitted, the proposal it led to; ``--resume`` replays that list (no run, no surrogate fit done
again) and continues with the first missing step; a state of another fit (config, measurement,
free parameters, seed, target) is refused. The summation's exit tables are walked again on resume
(~1-2 min on the felt: they are not on disk). Ctrl-C stops within the current Monte Carlo batch and
says what is kept (exit 130).

Outputs: as the other methods (:func:`fabric_optics.fitting.driver.write_outputs`): ``fitted.toml``, ``initial/``
(the Monte Carlo at the start), ``fitted/`` (the Monte Carlo at the fitted point: the run of the
search itself, not a new one), ``report/``, ``fit.json`` (``method = "mc"``; ``info.iterations``:
per Monte Carlo run ``x``, NRMSE, dh, ds, objective, the step ``dx``, seconds and the proposal it led
to; ``info.evaluations`` = Monte Carlo runs, ``info.walks`` = the summation's walks plus the Monte Carlo
runs made by this invocation, ``info.surrogate_evaluations`` = summation evaluations, no photon).
"""

from __future__ import annotations

import hashlib
import json
import logging
import math
import re
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

from fabric_optics.fitting.problem import FitError, FitProblem
from fabric_optics.fitting.state import write_json_atomic

__all__ = ["MC_STATE", "MC_RUNS_DIR", "DEFAULT_MC_RUNS", "INNER_EVALUATIONS", "TINY", "MCFitProblem", "MCRun",
           "correction", "run_mc_fit", "write_mc_outputs", "left_behind"]

log = logging.getLogger(__name__)

MC_STATE = "mc-state.json"
MC_RUNS_DIR = "mc-runs"
MC_SCHEMA = "simulate-fit-mc-state/1"
#: ``--max-runs`` default: Monte Carlo runs, the start's included
DEFAULT_MC_RUNS = 5
#: consecutive backtracking steps (half the step from the best run) after a run that did not improve
MAX_HALVINGS = 1
#: summation evaluations of each surrogate fit (fabric_optics.fitting.driver.run_fit's budget)
INNER_EVALUATIONS = 400
#: below this share of the geometry's spectral peak of the summation the correction is additive
TINY = 0.05
#: a fine parameter's finite-difference step: this share of its value, at least FINE_STEP_SPAN of its bounds
FINE_STEP = 0.25
FINE_STEP_SPAN = 0.05
#: the surrogate fit holds a fine parameter within this many steps of the centre (the trust region)
FINE_TRUST = 2.0
_NOISE_DRAWS = 64
#: with the colour first, the surrogate's colour is held within this share of the colour tolerance (the Monte
#: Carlo at the proposal differs from the surrogate's prediction by its noise and the correction's error)
COLOUR_MARGIN = 0.5
#: the colour weight's factor from one surrogate fit to the next while its colour is outside the margin
COLOUR_WEIGHT_STEP = 10.0
#: the largest colour weight of a surrogate fit, as a multiple of the problem's
MAX_COLOUR_WEIGHT_FACTOR = 1000.0


def correction(s: np.ndarray, mc: np.ndarray, tiny: float = TINY) -> tuple[np.ndarray, np.ndarray]:
    """``(c, d)`` ``[G, L]`` with ``MC = S c + d``: multiplicative where ``S > tiny max_lambda S`` of its
    geometry, additive elsewhere (module docstring)."""
    s = np.asarray(s, float)
    mc = np.asarray(mc, float)
    peak = np.max(np.abs(s), axis=1, keepdims=True)
    ratio = (s > tiny * peak) & (s > 0.0)
    c = np.where(ratio, mc / np.where(ratio, s, 1.0), 1.0)
    d = np.where(ratio, 0.0, mc - s)
    return c, d


@dataclass
class MCRun:
    """One Monte Carlo run of the fit at parameters ``x`` and its figures against the measurement."""

    x: np.ndarray
    beta: np.ndarray
    u_beta: np.ndarray
    seconds: float
    rays: int
    rel_err: float
    objective: float
    nrmse: float
    dh: float
    ds: float

    def record(self) -> dict:
        return {"x": self.x.tolist(), "seconds": self.seconds, "rays": self.rays, "rel_err": self.rel_err,
                "objective": self.objective, "nrmse": self.nrmse, "dh": self.dh, "ds": self.ds}


@dataclass
class MCFitProblem(FitProblem):
    """The summation fit problem with an output correction towards the Monte Carlo (module docstring).

    ``method`` is ``"summation"`` inside (the coarse model's machinery); :attr:`fine` names the fine one.
    """

    fine: str = "mc"
    #: ``(c, d, u)`` of the current correction (None: the plain summation)
    corr: tuple | None = None
    #: while writing the outputs: the Monte Carlo runs by parameters (:func:`write_mc_outputs`)
    fine_runs: dict | None = None
    #: the Monte Carlo runs of the last :func:`run_mc_fit`, by parameters
    mc_runs: dict = field(default_factory=dict)
    #: ``(centre x, {j: D_j [G, L]})``: the Monte Carlo's first-order term (module docstring)
    slope: tuple | None = None
    #: free parameters (config paths) whose trend comes from the Monte Carlo although the summation sees them
    #: (``--mc-trend``; module docstring)
    mc_trend: tuple = ()

    def __post_init__(self) -> None:
        self.method = "summation"
        self.fine_capable = True
        super().__post_init__()
        from fabric_optics import paths

        names = [p.name for p in self.free]
        expanded: list[str] = []
        for name in self.mc_trend:
            try:
                full = paths.expand(name, self._doc)
            except paths.PathError as exc:
                raise FitError(f"--mc-trend {exc}") from None
            for path in full:
                if path not in names:
                    raise FitError(f"--mc-trend {name}: not a free parameter of this fit (free: {', '.join(names)}); "
                                   "name a parameter given to --free")
                expanded.append(path)
        self.mc_trend = tuple(expanded)

    def fine_indices(self) -> list[int]:
        """The parameters whose trend comes from Monte Carlo runs: the fine ones and ``mc_trend``."""
        return [j for j, p in enumerate(self.free) if p.kind == "fine" or p.name in self.mc_trend]

    def fine_step(self, j: int, x: np.ndarray) -> float:
        """The finite-difference step of fine parameter ``j`` at ``x`` (module docstring)."""
        p = self.free[j]
        h = max(FINE_STEP * abs(float(x[j])), FINE_STEP_SPAN * (p.high - p.low))
        return -h if x[j] + h > p.high else h

    def identity(self) -> str:
        doc = [super().identity(), "mc", self.target_rel_err] + ([sorted(self.mc_trend)] if self.mc_trend else [])
        return hashlib.sha256(json.dumps(doc).encode()).hexdigest()

    def set_correction(self, x: np.ndarray, mc_beta: np.ndarray, mc_u: np.ndarray) -> None:
        """The correction that makes the surrogate equal ``mc_beta`` (standard error ``mc_u``) at ``x``."""
        self.corr = None
        s, _ = self.model(x)
        c, d = correction(s, mc_beta)
        self.corr = (c, d, np.asarray(mc_u, float))
        if self.slope is not None:
            self.slope = (np.asarray(x, float).copy(), self.slope[1])

    def model_at_host(self, config: Any, mu_host: np.ndarray,
                      mc_noise: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """The surrogate at host absorption ``mu_host``: the summation's value with the correction applied
        (the plain summation while there is none). The colour start (:func:`fabric_optics.fitting.start.inverted_start`)
        reads the model through this, so the Monte Carlo fit inverts the measured colour through its own
        surrogate."""
        beta, u = super().model_at_host(config, mu_host, mc_noise)
        if self.corr is None:
            return beta, u
        c, d, mc_u = self.corr
        return beta * c + d, mc_u

    def model(self, x: np.ndarray, mc_noise: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        if self.fine_runs is not None:
            run = self.fine_runs[_key(x)]
            return run.beta, run.u_beta
        if self.corr is None:
            return super().model(x, mc_noise)
        xs = np.asarray(x, float)
        if self.slope is not None:
            # the summation held at the centre in the parameters whose trend is the Monte Carlo's
            xs = xs.copy()
            for j in self.slope[1]:
                xs[j] = self.slope[0][j]
        out, mc_u = super().model(xs, mc_noise)   # corrected by model_at_host
        if self.slope is not None:
            centre, D = self.slope
            for j, Dj in D.items():
                out = out + Dj * (float(x[j]) - float(centre[j]))
        return out, mc_u


def _key(x: np.ndarray) -> tuple:
    return tuple(np.round(np.asarray(x, float), 12).tolist())


def run_monte_carlo(problem: MCFitProblem, x: np.ndarray, *, progress: bool = False) -> MCRun:
    """The woven/felt Monte Carlo (``simulate fabric --method mc``) at the measured geometries for ``x``."""
    from simulate.montecarlo.accuracy import relative_error
    from simulate.products import Geometries, RunSettings, all_threads, evaluate

    config = problem.config_at(x)
    wl = problem.wavelengths_nm
    g = problem.geometries
    geoms = Geometries(*(g[c].to_numpy(float) for c in ("theta_i", "phi_i", "theta_o", "phi_o")))
    t0 = time.perf_counter()
    est = evaluate("mc", config, config.fiber(wl), geoms, wl,
                   RunSettings(target=problem.target_rel_err, seed=int(problem.seed or 0),
                               threads=all_threads(problem.threads), progress=progress))
    fig = problem.residual_model().evaluate(est.beta, est.u_beta)
    r = fig.vector(problem.colour_weight, problem.level_weight)
    return MCRun(x=np.asarray(x, float).copy(), beta=np.asarray(est.beta, float), u_beta=np.asarray(est.u_beta, float),
                 seconds=time.perf_counter() - t0, rays=int(est.info.get("rays", 0)),
                 rel_err=float(relative_error(est.beta, est.u_beta)), objective=float(r @ r),
                 nrmse=float(fig.nrmse), dh=float(getattr(fig, "dh", math.nan)), ds=float(getattr(fig, "ds", math.nan)))


# ------------------------------------------------------------------------------------------
# checkpoint

#: the most Monte Carlo runs a state may list (the budget's runs and their trend runs)
MAX_STATE_RUNS = 1000
#: the largest run file read back (a run's two tables: tens of kB on a real plan)
MAX_RUN_BYTES = 64_000_000
_RUN_FILE = re.compile(r"run-[0-9]{1,4}(-d[0-9]{1,3})?\.npz")


def _check_record(path: Path, field: str, rec: Any, problem: MCFitProblem, reach: float = 0.0) -> None:
    """One run record of the state (its point within the bounds widened by ``reach`` spans, figures, file)."""
    from fabric_optics.fitting.state import refuse, check_number, check_point

    if not isinstance(rec, dict):
        refuse(path, f"field {field!r} is not an object")
    for name in ("x", "file", "seconds", "rays", "rel_err", "objective", "nrmse", "dh", "ds"):
        if name not in rec:
            refuse(path, f"field '{field}.{name}' is missing")
    span = problem.high - problem.low
    check_point(path, f"{field}.x", rec["x"], [p.name for p in problem.free], problem.low - reach * span,
                problem.high + reach * span)
    if not isinstance(rec["file"], str) or not _RUN_FILE.fullmatch(rec["file"]):
        refuse(path, f"field '{field}.file' is {json.dumps(rec['file'])[:40]}, not a run file name (run-K.npz)")
    check_number(path, f"{field}.seconds", rec["seconds"], low=0.0)
    check_number(path, f"{field}.rays", rec["rays"], low=0, integer=True)
    check_number(path, f"{field}.objective", rec["objective"], low=0.0)
    for name in ("rel_err", "nrmse", "dh", "ds"):
        check_number(path, f"{field}.{name}", rec[name], allow_nan=True)


def _check_iterations(path: Path, its: Any, problem: MCFitProblem) -> None:
    """``mc-state.json``'s ``iterations`` (:mod:`fabric_optics.fitting.state`: refused, naming the field, unless every
    run and proposal is one of this fit's)."""
    from fabric_optics.fitting.state import refuse, check_number, check_point

    if not isinstance(its, list):
        refuse(path, f"field 'iterations' is {json.dumps(its)[:40]}, not a list of runs")
    if len(its) > MAX_STATE_RUNS:
        refuse(path, f"field 'iterations' lists {len(its)} runs, more than {MAX_STATE_RUNS}")
    names = [p.name for p in problem.free]
    for k, rec in enumerate(its):
        _check_record(path, f"iterations[{k}]", rec, problem)
        fine = rec.get("fine_runs")
        if fine is not None:
            if not isinstance(fine, dict) or len(fine) > len(names):
                refuse(path, f"field 'iterations[{k}].fine_runs' is not an object of at most {len(names)} runs")
            for j, fr in fine.items():
                if not (j.isdigit() and int(j) < len(names)):
                    refuse(path, f"field 'iterations[{k}].fine_runs' names parameter {j!r}, not one of 0..{len(names) - 1}")
                _check_record(path, f"iterations[{k}].fine_runs.{j}", fr, problem, reach=1.0)
        prop = rec.get("proposal")
        if prop is not None:
            where = f"iterations[{k}].proposal"
            if not isinstance(prop, dict) or prop.get("kind") not in ("surrogate fit", "backtrack"):
                refuse(path, f"field {where!r} is not a proposal (kind 'surrogate fit' or 'backtrack')")
            for name in ("x", "u", "surrogate_evaluations"):
                if name not in prop:
                    refuse(path, f"field '{where}.{name}' is missing")
            check_point(path, f"{where}.x", prop["x"], names, problem.low, problem.high)
            u = prop["u"]
            if not isinstance(u, list) or len(u) != len(names):
                refuse(path, f"field '{where}.u' is not a list of {len(names)} uncertainties")
            for j, v in enumerate(u):
                check_number(path, f"{where}.u[{j}]", v, low=0.0, allow_nan=True)
            check_number(path, f"{where}.surrogate_evaluations", prop["surrogate_evaluations"], low=0,
                         high=10**9, integer=True)
            notes = prop.get("notes", [])
            if not isinstance(notes, list) or not all(isinstance(n, str) for n in notes):
                refuse(path, f"field '{where}.notes' is not a list of texts")


class _State:
    """``DIR/mc-state.json`` and ``DIR/mc-runs/`` (module docstring)."""

    def __init__(self, out: Path | None, identity: str, shape: tuple | None = None):
        self.out = out
        self.identity = identity
        #: ``(geometries, wavelengths)`` of a run's table (None: not checked)
        self.shape = shape
        self.iterations: list[dict] = []

    def load(self, problem: MCFitProblem | None = None) -> None:
        """The finished runs of ``DIR/mc-state.json``, checked field by field against ``problem``'s free
        parameters (:mod:`fabric_optics.fitting.state`: a malformed or out-of-bounds state is refused, not repaired)."""
        from fabric_optics.fitting.state import read_state_json

        assert self.out is not None
        path = self.out / MC_STATE
        doc = read_state_json(path)
        if doc is None:
            raise FitError(f"--resume: nothing to resume in {self.out}: no {MC_STATE} (no Monte Carlo run of "
                           "this fit had finished); run without --resume")
        if doc.get("schema") != MC_SCHEMA or doc.get("identity") != self.identity:
            raise FitError(f"--resume: {path} belongs to a different fit (config, measurement, free parameters, "
                           "seed or --target-rel-err differ); use a new --out or drop --resume")
        its = doc.get("iterations")
        if problem is not None:
            _check_iterations(path, its, problem)
        self.iterations = list(its or [])

    def save(self) -> None:
        if self.out is not None:
            write_json_atomic(self.out / MC_STATE, {"schema": MC_SCHEMA, "identity": self.identity,
                                                   "iterations": self.iterations})

    def run(self, k: int, x: np.ndarray) -> MCRun | None:
        """Run ``k`` from the checkpoint if it was made at ``x``."""
        if self.out is None or k >= len(self.iterations):
            return None
        rec = self.iterations[k]
        if not np.allclose(rec["x"], x, rtol=0.0, atol=1e-12):
            return None
        return self._load(rec)

    def _load(self, rec: dict) -> MCRun | None:
        """The run ``rec`` names, or None (it is run again) when its file is missing, unreadable, not a regular
        file of at most :data:`MAX_RUN_BYTES`, or holds arrays that are not two equal, finite tables."""
        import os
        import stat

        path = self.out / MC_RUNS_DIR / rec["file"]  # type: ignore[operator]
        try:
            st = os.stat(path)
            if not stat.S_ISREG(st.st_mode) or st.st_size > MAX_RUN_BYTES:
                log.warning("%s is not a Monte Carlo run of this fit (not a regular file of at most %d bytes): run "
                            "again", path, MAX_RUN_BYTES)
                return None
            with np.load(path) as z:
                beta, u = np.asarray(z["beta"], float).copy(), np.asarray(z["u_beta"], float).copy()
        except (OSError, ValueError, KeyError, TypeError):
            return None
        if beta.ndim != 2 or beta.shape != u.shape or not (np.all(np.isfinite(beta)) and np.all(np.isfinite(u))) \
                or (self.shape is not None and beta.shape != self.shape):
            log.warning("%s does not hold a finite Monte Carlo table of this fit's shape: run again", path)
            return None
        return MCRun(x=np.asarray(rec["x"], float), beta=beta, u_beta=u, seconds=rec["seconds"], rays=rec["rays"],
                     rel_err=rec["rel_err"], objective=rec["objective"], nrmse=rec["nrmse"], dh=rec["dh"],
                     ds=rec["ds"])

    def _store(self, name: str, run: MCRun) -> dict:
        rec = run.record()
        if self.out is not None:
            import os

            from fabric_optics.fitting.state import remove_quietly, write_failed

            d = self.out / MC_RUNS_DIR
            rec["file"] = f"{name}.npz"
            tmp = d / f".{name}.tmp.npz"
            try:
                d.mkdir(parents=True, exist_ok=True)
                np.savez(tmp, x=run.x, beta=run.beta, u_beta=run.u_beta)
                os.replace(tmp, d / rec["file"])
            except OSError as exc:
                remove_quietly(tmp)
                raise FitError(write_failed(d / rec["file"], exc)) from None
            except BaseException:
                remove_quietly(tmp)
                raise
        return rec

    def put_run(self, k: int, run: MCRun) -> None:
        del self.iterations[k:]
        self.iterations.append(self._store(f"run-{k}", run))
        self.save()

    def fine_run(self, k: int, j: int, x: np.ndarray) -> MCRun | None:
        """Fine parameter ``j``'s finite-difference run about centre ``k`` from the checkpoint, if made at ``x``."""
        if self.out is None or k >= len(self.iterations):
            return None
        rec = (self.iterations[k].get("fine_runs") or {}).get(str(j))
        if rec is None or not np.allclose(rec["x"], x, rtol=0.0, atol=1e-12):
            return None
        return self._load(rec)

    def put_fine_run(self, k: int, j: int, run: MCRun) -> None:
        self.iterations[k].setdefault("fine_runs", {})[str(j)] = self._store(f"run-{k}-d{j}", run)
        self.save()

    def proposal(self, k: int) -> dict | None:
        return self.iterations[k].get("proposal") if k < len(self.iterations) else None

    def put_proposal(self, k: int, proposal: dict) -> None:
        self.iterations[k]["proposal"] = proposal
        self.save()


def left_behind(out: Path) -> str:
    """What an interrupted Monte Carlo fit left in ``out`` (only what exists)."""
    from fabric_optics.fitting.state import read_state_json

    try:
        its = (read_state_json(out / MC_STATE) or {}).get("iterations") or []
    except FitError:
        its = []
    if not isinstance(its, list):
        its = []
    if its:
        props = sum(1 for it in its if isinstance(it, dict) and it.get("proposal"))
        return (f"{len(its)} finished Monte Carlo run(s) and {props} proposal(s) fitted from them are in "
                f"{out / MC_STATE} and {out / MC_RUNS_DIR} (continue with --resume)")
    return "no Monte Carlo run had finished: nothing was saved (run again without --resume)"


# ------------------------------------------------------------------------------------------
# the fit


def _uncertainty(problem: MCFitProblem, x: np.ndarray, beta: np.ndarray, u_beta: np.ndarray, draws: int,
                 data: bool = True) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict]:
    """``(J, cov_data, cov_mc, rule)`` at ``x`` with the correction formed from the Monte Carlo ``beta, u_beta``
    there (module docstring); ``data=False``: the Monte Carlo part only (``cov_data`` zero). A measurement
    without ``u_beta`` gets the data part scaled by the residual (:func:`fabric_optics.fitting.driver.residual_covariance`)."""
    from compare.errors import CompareError
    from gonio.data.dataset import make_dataset
    from fabric_optics.fitting.driver import jacobian, measurement_has_u, residual_scaled_draws

    problem.set_correction(x, beta, u_beta)
    r0 = problem.residuals(x)
    J = jacobian(problem, x, r0, problem.residuals)
    pinv = np.linalg.pinv(J)
    rng = np.random.default_rng(20260101 + int(problem.seed or 0))
    meas = problem.measured
    dp_data, dp_mc, refused = [np.zeros(x.size)], [np.zeros(x.size)], 0
    with_u = measurement_has_u(meas)
    for _ in range(draws if data and with_u else 0):
        table = meas.table.copy()
        table["beta"] = table["beta"] + rng.standard_normal(len(table)) * table["u_beta"]
        try:
            dp_data.append(-pinv @ (problem.residuals(x, measured=make_dataset(table, meas.meta)) - r0))
        except CompareError:
            refused += 1
    for _ in range(draws):
        problem.set_correction(x, beta + u_beta * rng.standard_normal(beta.shape), u_beta)
        try:
            dp_mc.append(-pinv @ (problem.residuals(x) - r0))
        except CompareError:
            # a noisy Monte Carlo (a loose --target-rel-err) can put a draw's normal/normal value at or
            # below zero; it cannot be normalised and is left out, as in fabric_optics.fitting.driver.run_fit
            refused += 1
    problem.set_correction(x, beta, u_beta)
    if refused:
        log.warning("%d of %d noise draws left out of the uncertainty: their normal/normal value was not positive",
                    refused, (2 if data else 1) * draws)
    # the leading zero row stands for a part not drawn (data=False: no data part); a part drawn whose draws
    # were all refused could not be estimated: all-NaN (fabric_optics.fitting.driver.uncertainty_parts says so)
    unknown = np.full((x.size, x.size), np.nan)
    cov = [unknown if attempted and len(dp) == 1 else np.atleast_2d(np.cov(np.array(dp[1:] or dp).T, bias=True))
           for dp, attempted in ((dp_data, data and with_u and draws > 0), (dp_mc, draws > 0))]
    rule: dict = {"data": "u_beta", "rule": "the measurement's u_beta propagated by noise draws"}
    if data and not with_u:
        cov[0], rule = residual_scaled_draws(problem, x, r0, J, rng, draws)
    return J, cov[0], cov[1], rule


def _colour_first(problem: MCFitProblem) -> bool:
    """Whether the fit puts the colour first (module docstring, "The colour first"): free dye knots, a colour
    weight above zero and a measurement with a colour."""
    from fabric_optics.fitting.start import knot_indices

    return (problem.colour_weight > 0 and bool(knot_indices([p.name for p in problem.free]))
            and problem.residual_model().has_colour)


def _colour_off(dh: float, ds: float) -> float:
    """``max(|dh|/tol_h, |ds|/tol_s)`` (:data:`fabric_optics.fitting.driver.COLOUR_TOLERANCE`); 0 without a colour."""
    from fabric_optics.fitting.driver import COLOUR_TOLERANCE

    if not (math.isfinite(dh) and math.isfinite(ds)):
        return 0.0
    return max(abs(dh) / COLOUR_TOLERANCE[0], abs(ds) / COLOUR_TOLERANCE[1])


def _better(run: MCRun, best: MCRun, colour_first: bool) -> bool:
    """Whether ``run`` replaces ``best``: the lower Monte Carlo objective; with the colour first, a run within
    the colour tolerance beats one outside it, and of two outside it the nearer the measured colour wins (the
    rule of the colour start, :func:`fabric_optics.fitting.driver.run_fit`)."""
    if colour_first:
        a, b = _colour_off(run.dh, run.ds), _colour_off(best.dh, best.ds)
        if a > 1.0 or b > 1.0:
            return a < b
    return run.objective < best.objective


def _surrogate_fit(problem: MCFitProblem, colour_first: bool, noise_draws: int = _NOISE_DRAWS,
                   **kwargs: Any) -> tuple[Any, list[float]]:
    """The surrogate fit of one iteration and the colour weights it used (module docstring, "The colour
    first"): fitted at the problem's colour weight; with the colour first and the surrogate's colour further
    than :data:`COLOUR_MARGIN` tolerances from the measured, fitted again from that point with the weight
    :data:`COLOUR_WEIGHT_STEP` times larger, up to :data:`MAX_COLOUR_WEIGHT_FACTOR` times the problem's. Only the
    kept (last) fit's uncertainty is computed (:func:`fabric_optics.fitting.driver.finish_fit`): the searches at the
    smaller weights only lead to its start."""
    from fabric_optics.fitting.driver import colour_distance, finish_fit, search_fit

    w0 = problem.colour_weight
    start = problem.start.copy()
    weights = [w0]
    try:
        search = search_fit(problem, out=None, invert_start=True, **kwargs)
        while (colour_first and colour_distance(problem, search.x) > COLOUR_MARGIN
               and problem.colour_weight * COLOUR_WEIGHT_STEP <= MAX_COLOUR_WEIGHT_FACTOR * w0 * (1 + 1e-9)):
            problem.colour_weight *= COLOUR_WEIGHT_STEP
            weights.append(problem.colour_weight)
            problem.start = search.x.copy()
            log.info("surrogate colour %.3g tolerances off: fitted again at colour weight %g",
                     colour_distance(problem, search.x), problem.colour_weight)
            search = search_fit(problem, out=None, invert_start=True, **kwargs)
        res = finish_fit(problem, search, noise_draws=noise_draws)
    finally:
        problem.colour_weight = w0
        problem.start = start
    return res, weights


def _line(k: int, run: MCRun, dx: float | None, cached: bool) -> str:
    step = "" if dx is None else f", max |dx| {dx:.3g}"
    how = "read from the checkpoint" if cached else f"{run.seconds:.1f} s"
    return (f"mc run {k}: NRMSE {run.nrmse:.4f}, dh {run.dh:+.4f}, ds {run.ds:+.4f}, objective {run.objective:.5g}"
            f"{step} ({how}, rel. error {run.rel_err:.3g})")


def run_mc_fit(problem: MCFitProblem, *, out: Path | None = None, resume: bool = False,
               max_evaluations: int = DEFAULT_MC_RUNS, starts: int = 1, progress: bool = False,
               noise_draws: int = _NOISE_DRAWS, inner_evaluations: int = INNER_EVALUATIONS,
               echo: Callable[[str], None] | None = None, **unused: Any):
    """Fit the Monte Carlo to ``problem.measured`` by output space mapping (module docstring).

    ``max_evaluations``: Monte Carlo runs in all (the start's included, >= 2). Returns a
    :class:`fabric_optics.fitting.driver.FitResult` whose ``info["iterations"]`` lists the runs.
    """
    from fabric_optics.fitting.driver import (FitResult, at_bounds, colour_left_off, identifiability,
                                              u_status, uncertainty_parts)

    if max_evaluations < 2:
        raise FitError(f"--max-runs {max_evaluations}: --method mc needs at least 2 Monte Carlo runs "
                       "(the start and one proposal)")
    if echo is None:
        def echo(text: str) -> None:
            print(text, file=sys.stderr, flush=True)
    t0 = time.perf_counter()
    problem.out = out
    start = problem.start.copy()
    state = _State(out, problem.identity(), (len(problem.geometries), problem.wavelengths_nm.size))
    if resume:
        if out is None:
            raise FitError("--resume needs the output directory of the interrupted fit (--out)")
        state.load(problem)
    runs: list[MCRun] = []
    iterations: list[dict] = []
    x = start.copy()
    stop = ""
    surrogate_evals = 0
    inner_notes: list[str] = []
    u_prev: np.ndarray | None = None
    best: MCRun | None = None
    halvings = 0
    fine = problem.fine_indices()
    fine_runs = 0
    problem.slope = None
    colour_first = _colour_first(problem)
    try:
        for k in range(max_evaluations):
            run = state.run(k, x)
            cached = run is not None
            if run is None:
                run = run_monte_carlo(problem, x, progress=progress)
                state.put_run(k, run)
            dx = None if not runs else float(np.max(np.abs(x - runs[-1].x)))
            runs.append(run)
            problem.mc_runs[_key(x)] = run
            iterations.append({"k": k, **run.record(), "cached": cached,
                               "dx": None if not k else (x - runs[-2].x).tolist()})
            echo(_line(k, run, dx, cached))
            if best is None or _better(run, best, colour_first):
                before, best, halvings = best, run, 0
                if before is not None and u_prev is not None and np.all(np.abs(run.x - before.x) <= u_prev):
                    stop = f"converged: every parameter step of run {k} is within its standard uncertainty"
                    break
            else:
                halvings += 1
                if halvings > MAX_HALVINGS or (u_prev is not None and np.all(np.abs(run.x - best.x) <= 2 * u_prev)):
                    stop = (f"the Monte Carlo objective did not decrease at run {k} ({run.objective:.5g} >= "
                            f"{best.objective:.5g}, the best run's) and a shorter step would be within the "
                            "uncertainty or was tried: the best run is kept")
                    break
            used = len(runs) + fine_runs
            if used >= max_evaluations:
                stop = f"the budget of Monte Carlo runs is spent (--max-runs {max_evaluations})"
                break
            prop = state.proposal(k)
            if prop is None and run is not best:
                # backtrack: half the step from the best run (the correction stays the best run's)
                prop = {"kind": "backtrack", "x": (best.x + 0.5 * (run.x - best.x)).tolist(),
                        "u": (u_prev if u_prev is not None else np.zeros(x.size)).tolist(), "surrogate_evaluations": 0}
                state.put_proposal(k, prop)
            if fine and (prop is None or prop.get("kind") == "surrogate fit"):
                # the fine parameters' trend from the Monte Carlo itself (module docstring)
                if prop is None and used + len(fine) + 1 > max_evaluations:
                    stop = (f"the budget of Monte Carlo runs is spent (--max-runs {max_evaluations}): "
                            f"{max_evaluations - used} left, the trend in the {len(fine)} parameter(s) only the "
                            "Monte Carlo sees and the proposal need " f"{len(fine) + 1}")
                    break
                D = {}
                for j in fine:
                    h = problem.fine_step(j, x)
                    xj = x.copy()
                    xj[j] += h
                    fr = state.fine_run(k, j, xj)
                    fr_cached = fr is not None
                    if fr is None:
                        fr = run_monte_carlo(problem, xj, progress=progress)
                        state.put_fine_run(k, j, fr)
                    fine_runs += 1
                    problem.mc_runs[_key(xj)] = fr
                    D[j] = (fr.beta - run.beta) / h
                    iterations[-1].setdefault("fine_runs", []).append(
                        {"parameter": problem.free[j].name, "h": h, **fr.record(), "cached": fr_cached})
                    echo(f"mc run {k}, trend in {problem.free[j].name} ({xj[j]:.4g}): "
                         + _line(k, fr, None, fr_cached).split(": ", 1)[1])
                    if _better(fr, best, colour_first):
                        best, halvings = fr, 0
                problem.slope = (x.copy(), D)
            if prop is None:
                problem.set_correction(x, run.beta, run.u_beta)
                problem.start = x.copy()
                t1 = time.perf_counter()
                ev0 = problem.evaluations
                low, high = problem.low.copy(), problem.high.copy()
                for j in fine:
                    reach = FINE_TRUST * abs(problem.fine_step(j, x))
                    problem.low[j], problem.high[j] = max(low[j], x[j] - reach), min(high[j], x[j] + reach)
                try:
                    # the colour start through the surrogate (free dye knots): the measured colour inverted through
                    # the summation corrected to this run; the search starts from it or from x_k, the better; the
                    # colour held within the margin by raising its weight (module docstring, "The colour first")
                    res, weights = _surrogate_fit(problem, colour_first, max_evaluations=inner_evaluations,
                                                  starts=starts, progress=progress, noise_draws=noise_draws)
                finally:
                    problem.low, problem.high = low, high
                # the proposal's Monte Carlo part: the surrogate's noise (the run's u_beta) at the proposal
                b_prop, u_b_prop = problem.model(res.x)
                _, _, cov_prop, _ = _uncertainty(problem, res.x, b_prop, u_b_prop, noise_draws, data=False)
                u_prop = np.sqrt(np.nan_to_num(res.u_data) ** 2 + np.maximum(np.diag(cov_prop), 0.0))
                fig_prop = problem.residual_model().evaluate(b_prop)
                prop = {"kind": "surrogate fit", "x": res.x.tolist(), "u": u_prop.tolist(),
                        "surrogate_objective": res.objective, "start_note": res.info.get("start_note", ""),
                        "colour_weights": weights, "surrogate_nrmse": float(fig_prop.nrmse),
                        "surrogate_dh": float(getattr(fig_prop, "dh", math.nan)),
                        "surrogate_ds": float(getattr(fig_prop, "ds", math.nan)),
                        "surrogate_evaluations": problem.evaluations - ev0, "seconds": time.perf_counter() - t1,
                        "notes": [n for n in res.warnings
                                  if not n.startswith(("the search stopped", "colour left off"))]}
                state.put_proposal(k, prop)
            surrogate_evals += int(prop["surrogate_evaluations"])
            inner_notes = list(prop.get("notes") or inner_notes)
            iterations[-1]["proposal"] = prop
            x = np.clip(np.asarray(prop["x"], float), problem.low, problem.high)
            u_prev = np.asarray(prop["u"], float)
        assert best is not None
        J, cov_data, cov_mc, u_rule = _uncertainty(problem, best.x, best.beta, best.u_beta, noise_draws)
    finally:
        problem.start = start
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
    fine_records = [f for it in iterations for f in it.get("fine_runs", [])]
    done = sum(1 for it in iterations if not it["cached"]) + sum(1 for f in fine_records if not f["cached"])
    span = problem.high - problem.low
    info = {
        "optimiser": "output space mapping (Bandler et al. 2004; Koziel et al. 2006): the structured summation "
                     "corrected to the Monte Carlo, fitted by scipy.optimize.least_squares (trf)",
        "correction": f"multiplicative MC/S per (geometry, wavelength); additive MC - S where S <= {TINY} of the "
                      "geometry's spectral peak",
        "stop": stop, "message": stop, "starts": starts,
        "evaluations": len(runs) + fine_runs, "max_evaluations": max_evaluations,
        "evaluations_meaning": "Monte Carlo runs", "mc_runs": len(runs) + fine_runs, "mc_runs_done": done,
        "fine_trend_runs": fine_runs,
        "mc_seconds": float(sum(r.seconds for it, r in zip(iterations, runs) if not it["cached"])
                            + sum(f["seconds"] for f in fine_records if not f["cached"])),
        "surrogate_evaluations": surrogate_evals, "summation_walks": problem.walks,
        "walks": problem.walks + done, "walk_seconds": problem.walk_seconds,
        "reweighted": problem.reweights, "seconds": time.perf_counter() - t0, "resumed": resume,
        "best_run": next((i for i, r in enumerate(runs) if r is best), None),
        "best_x": best.x.tolist(), "iterations": iterations, "notes": list(problem.notes),
        "start_note": "the first Monte Carlo run is at the config's values (a Monte Carlo preset such as "
                      "green-felt-mc, or a summation fit's fitted.toml); with free dye knots every surrogate fit "
                      "starts from the measured colour inverted through the surrogate (the summation corrected to "
                      "the run), or from the run's own values when they score better",
        "singular_values": np.linalg.svd(J * span[None, :], compute_uv=False).tolist(),
        "target_rel_err": problem.target_rel_err,
        "uncertainty": u_rule, "u_status": u_status(problem, bound_notes, ident_notes),
    }
    return FitResult(x=best.x.copy(), start=start.copy(), objective=best.objective, objective_start=runs[0].objective,
                     u=u, u_data=u_data, u_mc=u_mc, correlation=corr, warnings=notes, info=info)


def write_mc_outputs(problem: MCFitProblem, result: Any, out: Path) -> dict:
    """The outputs of :func:`fabric_optics.fitting.driver.write_outputs`, the datasets being the Monte Carlo runs of the fit at
    the start and at the fitted point (the search's own runs, not run again)."""
    from fabric_optics.fitting.driver import write_outputs

    problem.fine_runs = problem.mc_runs
    problem.method = "mc"
    try:
        return write_outputs(problem, result, out)
    finally:
        problem.method = "summation"
        problem.fine_runs = None
