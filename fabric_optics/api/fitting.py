"""Fitting a fabric model's parameters to a measurement (``simulate fit``): the arguments checked, the job run.

The search itself is :mod:`fabric_optics.fitting`; this module checks the arguments, claims the
output folder, builds the fit's problem from the method registry
(:data:`fabric_optics.fitting.methods.METHODS`) and returns the outcome.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from fabric_optics import validate as _v
from fabric_optics.api.loading import as_dataset, load_config, refuse_existing
from fabric_optics.errors import InputError, typed_errors
from fabric_optics.fitting.errors import FitWarning
from fabric_optics.fitting.methods import DEFAULT_METHOD, METHODS
from gonio.data.dataset import Dataset
from simulate.config import SimulationConfig

if TYPE_CHECKING:
    from fabric_optics.fitting.outputs import FitResult

__all__ = ["FIT_METHODS", "FitJob", "FitOutcome", "FitWarning", "fit", "prepare_fit"]


FIT_METHODS = tuple(METHODS)
"""The models a fit can adjust, from the fit's method registry (`fabric_optics.fitting.methods.METHODS`); `auto`
is not one: its choice changes between evaluations."""


@dataclass
class FitOutcome:
    """A finished fit, as `fit` returns it.

    Attributes
    ----------
    out : Path
        The fit's folder.
    summary : dict
        What `out/fit.json` holds (the one serialiser of the fit's result wrote both).
    result : FitResult
        The typed result: parameter names, start and fitted values, uncertainties (the measurement's and the
        Monte Carlo's parts), correlation, objective, warnings and counts.
    config : SimulationConfig
        The fitted config (also `out/fitted.toml`).
    passed : bool
        The fitted colour is within the tolerance.
    warnings : list of str
        One line each: a bound reached, a budget spent, the colour left off.
    """

    out: Path
    summary: dict
    result: FitResult
    config: SimulationConfig
    passed: bool
    warnings: list[str]


@dataclass
class FitJob:
    """A fit checked and ready to run, as :func:`prepare_fit` returns it.

    Preparing and running are apart so that a caller (the command line) can report on the fit (its
    wavelengths, its budget) before the search starts. :meth:`run` searches, writes ``out`` and
    returns the outcome.

    Attributes
    ----------
    problem : FitProblem or MCFitProblem
        The fit's problem, from the method registry (its ``wavelengths_nm``, ``config``, ...).
    out : Path
        The fit's output folder.
    method : str
        The fit's method, one of `FIT_METHODS`.
    budget : int
        What the method's budget counts: model evaluations (``classic``, ``summation``) or Monte
        Carlo runs (``mc``).
    starts : int
        Independent starts of the search; the best is kept.
    resume : bool
        Continue a fit stopped in ``out`` from its checkpoints.
    phase : str, default "ready"
        ``"ready"``, ``"search"``, ``"writing"`` (the outputs being put in place) or ``"done"``: where
        an interrupted run stopped.
    """

    problem: Any
    out: Path
    method: str
    budget: int
    starts: int
    resume: bool
    #: "ready", "search", "writing" (the outputs being put in place) or "done"
    phase: str = "ready"

    @typed_errors
    def run(self, *, progress: bool = False) -> FitOutcome:
        """Search, write the outputs and return the outcome.

        The outputs are put in place together once the search is over, so an interrupt leaves the
        checkpoints (for ``resume``) and none of the outputs half-written.

        Parameters
        ----------
        progress : bool, default False
            Show a progress bar.

        Returns
        -------
        FitOutcome
            The fitted config, the typed result, what ``fit.json`` holds, the verdict and the warnings.

        Raises
        ------
        InputError
            A checkpoint in ``out`` that cannot be trusted, or a model the fit cannot evaluate.
        FileSystemError
            ``out`` cannot be written.

        Warns
        -----
        FitWarning
            The fitted colour is off by more than the tolerance, or the search never moved from its
            start; the outputs are written all the same.
        """
        import warnings

        from fabric_optics.fitting.outputs import write_outputs
        from simulate.config import load_config as _load

        method = METHODS[self.method]
        self.out.mkdir(parents=True, exist_ok=True)
        self.phase = "search"
        result = method.run(self.problem, out=self.out, resume=self.resume, starts=self.starts, progress=progress,
                            **{method.budget: self.budget})
        self.phase = "writing"      # the outputs are put in place together: an interrupt changes none of them
        summary = write_outputs(self.problem, result, self.out)
        self.phase = "done"
        passed = bool((summary.get("verdict") or {}).get("passed", True))
        if not passed:
            warnings.warn(f"fit in {self.out} failed: {summary['verdict'].get('why', 'colour left off')}",
                          FitWarning, stacklevel=3)
        if not result.moved:
            warnings.warn(f"fit in {self.out}: the search never moved from its start ({result.stop or 'converged'})",
                          FitWarning, stacklevel=3)
        return FitOutcome(out=self.out, summary=summary, result=result, config=_load(self.out / "fitted.toml"),
                          passed=passed, warnings=list(result.warnings))


@typed_errors
def prepare_fit(config: str | os.PathLike | SimulationConfig, measured: str | os.PathLike | Dataset,
                free: str | Sequence[str], out: str | os.PathLike, *, method: str = DEFAULT_METHOD,
                dye: str = "config", max_evaluations: int | None = None, max_runs: int | None = None,
                target_rel_err: float | None = None, seed: int | None = None, threads: int | None = None,
                colour_weight: float = 1.0, wavelengths_nm: Sequence[float] | None = None,
                mc_trend: Sequence[str] = (), starts: int = 1, resume: bool = False,
                force: bool = False, absolute: bool = False, colour_hold: bool = True,
                mc_retrace: bool = False) -> FitJob:
    """Check a fit and build its problem without searching: what :func:`fit` does before its search.

    The config, the measurement, the free parameters and their bounds, the budget and the output
    folder are checked and the fit's problem is built from the method registry; nothing is written
    and the output folder is not claimed (:func:`fit` claims it). A caller that wants to see the
    fit before it runs (its wavelengths, its budget) prepares it, then calls :meth:`FitJob.run`.

    Parameters
    ----------
    config : str, path or SimulationConfig
        The start: a preset name, a config TOML file or a loaded config.
    measured : str, path or Dataset
        The measurement (a dataset or its folder).
    free : str or sequence of str
        The parameters to fit, as :func:`fit` takes them (`"dye,rms_slope"`, `["rms_slope=0.1:0.5"]`).
    out : str or path
        The fit's folder (checked here, written by :meth:`FitJob.run`).
    method : str, default "classic"
        One of `FIT_METHODS`.
    dye : str, default "config"
        `"config"` keeps the config's dye; `"knots"` replaces it by knots started from the measured colour.
    max_evaluations : int, optional
        Model evaluations of the classic and summation fits (their default budget when None).
    max_runs : int, optional
        Monte Carlo runs of the `mc` fit (its default budget when None).
    target_rel_err : float, optional
        The first Monte Carlo walk's relative error (the config's by default).
    seed : int, optional
        The random seed (the config's by default).
    threads : int, optional
        Threads of the walks (all cores by default).
    colour_weight : float, default 1.0
        Weight of the colour match in the objective.
    wavelengths_nm : sequence of float, optional
        The model's wavelengths (the measurement's by default).
    mc_trend : sequence of str, default ()
        For `mc`: parameters whose trend the surrogate borrows from the summation.
    starts : int, default 1
        Independent starts of the search; the best is kept.
    resume : bool, default False
        Continue a fit stopped in `out` from its checkpoints (`out` may then hold a fit).
    force : bool, default False
        Replace what `out` holds.
    absolute : bool, default False
        The measurement is absolutely calibrated: its level is fitted too.
    colour_hold : bool, default True
        The classic and summation fits hold the colour within the tolerance; False weighs it by
        `colour_weight` only.
    mc_retrace : bool, default False
        For `mc`: trace every Monte Carlo run instead of re-weighting runs from a traced one.

    Returns
    -------
    FitJob
        The fit, ready to run: `.problem`, `.out`, `.method`, `.budget`.

    Raises
    ------
    InputError
        An unknown method or dye, a budget or Monte Carlo option that is not the method's, a bad
        config, measurement or free parameter (the message names it), `out` a file.
    OutputExistsError
        `out` holds something and neither `force` nor `resume` was given.

    Examples
    --------
    >>> import tempfile
    >>> from pathlib import Path
    >>> import fabric_optics as fo
    >>> out = Path(tempfile.mkdtemp()) / "fit"
    >>> job = fo.prepare_fit("red-cotton", "fixtures/analytic/measured_red", "rms_slope", out, max_evaluations=6)
    >>> job.method, job.budget, job.phase, out.exists()
    ('classic', 6, 'ready', False)
    """
    import numpy as np

    from fabric_optics.fitting.spec import parse_free
    from fabric_optics.fitting.start import knots_config

    if method not in METHODS:
        raise InputError(f"method {method!r}: choose one of {', '.join(FIT_METHODS)}")
    fit_method = METHODS[method]
    if mc_trend and method != "mc":
        raise InputError(f"mc_trend is for method 'mc' (the {method} fit has no Monte Carlo runs)")
    budgets = {"max_evaluations": max_evaluations, "max_runs": max_runs}
    for name, value in budgets.items():
        if value is not None and name != fit_method.budget:
            raise InputError(f"{name} is not the {method} fit's budget: it counts {fit_method.counts} "
                             f"({fit_method.budget})")
    cfg = load_config(config)
    data = as_dataset(measured)
    wavelengths = None if wavelengths_nm is None else np.asarray(wavelengths_nm, dtype=float)
    if dye == "knots":
        spectral = "channel" not in data.table.columns
        cfg = knots_config(cfg, wavelengths if wavelengths is not None else
                           (data.wavelengths_nm if spectral else cfg.wavelengths_nm))
    elif dye != "config":
        raise InputError(f"dye {dye!r}: choose 'config' or 'knots'")
    names = [free] if isinstance(free, str) else list(free)
    extra: dict[str, Any] = {"mc_trend": tuple(mc_trend)} if mc_trend else {}
    if mc_retrace:
        if method != "mc":
            raise InputError(f"mc_retrace is for method 'mc' (the {method} fit has no Monte Carlo runs)")
        extra["mc_retrace"] = True
    problem = fit_method.problem(cfg, data, parse_free(names, cfg), method=method, colour_weight=colour_weight,
                                 level_weight=1.0 if absolute else 0.0, hold_colour=colour_hold and method != "mc",
                                 target_rel_err=cfg.target_rel_err if target_rel_err is None else target_rel_err,
                                 seed=seed, threads=threads or None, wavelengths_nm=wavelengths, **extra)
    problem.precheck()
    out_dir = Path(out)
    if out_dir.exists() and not out_dir.is_dir():
        raise InputError(f"{out_dir}: exists and is not a folder; choose a folder")
    if not resume:
        refuse_existing(out_dir, force, ask="resume=True to continue a fit there or force=True")
    budget = budgets[fit_method.budget]
    return FitJob(problem=problem, out=out_dir, method=method,
                  budget=fit_method.default_budget if budget is None else budget, starts=starts, resume=resume)


@typed_errors
def fit(config: str | os.PathLike | SimulationConfig, measured: str | os.PathLike | Dataset,
        free: str | Sequence[str], out: str | os.PathLike, *, method: str = DEFAULT_METHOD, dye: str = "config",
        max_evaluations: int | None = None, max_runs: int | None = None, target_rel_err: float | None = None,
        seed: int | None = None, threads: int | None = None, colour_weight: float = 1.0,
        wavelengths_nm: Sequence[float] | None = None, mc_trend: Sequence[str] = (), starts: int = 1,
        resume: bool = False, force: bool = False, progress: bool = False, absolute: bool = False,
        colour_hold: bool = True, mc_retrace: bool = False) -> FitOutcome:
    """Fit parameters of a fabric model to a measurement (`simulate fit`).

    The arguments are checked, the output folder is claimed for this writer, the fit is prepared
    (:func:`prepare_fit`) and run (:meth:`FitJob.run`). The search minimises the curve error of the
    normalised curves and, unless `colour_hold` is off, holds the fitted colour within the tolerance.

    Parameters
    ----------
    config : str, path or SimulationConfig
        The start: a preset name, a config TOML file or a loaded config.
    measured : str, path or Dataset
        The measurement (a dataset or its folder).
    free : str or sequence of str
        The parameters to fit, named as `simulate fit --free` names them: `"dye,rms_slope"` or
        `["dye", "rms_slope=0.1:0.5"]` (a range after `=`); a blend's populations by name,
        `"populations.green.dye,populations.green.share"` (docs/how-to/fit.md, "Blends").
    out : str or path
        The fit's folder: `fit.json`, `fitted.toml`, the `initial/` and `fitted/` datasets, a report and the
        checkpoints that `resume` reads.
    method : str, default "classic"
        One of `FIT_METHODS`: `"classic"`, `"summation"` or `"mc"` (the Monte Carlo by output space mapping).
    dye : str, default "config"
        `"knots"` replaces the config's dye by knots started from the measured colour (a blend: each
        population's own dye).
    max_evaluations : int, optional
        Model evaluations of the classic and summation fits (their default budget when None).
    max_runs : int, optional
        Monte Carlo runs of the `mc` fit (its default budget when None).
    target_rel_err : float, optional
        The first Monte Carlo walk's relative error (the config's by default).
    seed : int, optional
        The random seed (the config's by default).
    threads : int, optional
        Threads of the walks (all cores by default).
    colour_weight : float, default 1.0
        Weight of the colour match in the objective.
    wavelengths_nm : sequence of float, optional
        The model's wavelengths (the measurement's by default).
    mc_trend : sequence of str, default ()
        For `mc`: parameters whose trend the surrogate borrows from the summation.
    mc_retrace : bool, default False
        For `mc`: trace every Monte Carlo run (with only dye parameters free, a run after a traced one is
        otherwise re-weighted from its rays while that is as accurate as a trace).
    starts : int, default 1
        Independent starts of the search; the best is kept.
    resume : bool, default False
        Continue a fit stopped in `out` from its checkpoints.
    force : bool, default False
        Replace what `out` holds.
    progress : bool, default False
        Show a progress bar.
    absolute : bool, default False
        The measurement is absolutely calibrated: its level is fitted too (`simulate fit --absolute`).
    colour_hold : bool, default True
        The classic and summation fits hold the colour within the tolerance; False weighs it by
        `colour_weight` only (`simulate fit --no-colour-hold`).

    Returns
    -------
    FitOutcome
        `.config` (the fitted config), `.result` (parameters, uncertainties, warnings, counts), `.summary`
        (what `fit.json` holds), `.passed` and `.warnings`.

    Raises
    ------
    InputError
        A bad argument, config, measurement or free parameter (the message names it), a fibre blend, a
        measurement beyond the row bound, a checkpoint that cannot be trusted.
    OutputExistsError
        `out` holds a fit and neither `force` nor `resume` was given; `OutputBusyError` when another writer
        holds it.

    Warns
    -----
    FitWarning
        The fitted colour is off by more than the tolerance, or the search never moved from its start; the
        outputs are written all the same and `outcome.passed` says so.

    Examples
    --------
    >>> import tempfile, warnings
    >>> from pathlib import Path
    >>> import fabric_optics as fo
    >>> out = Path(tempfile.mkdtemp()) / "fit"
    >>> with warnings.catch_warnings(record=True):
    ...     outcome = fo.fit("red-cotton", "fixtures/analytic/measured_red", "rms_slope", out,
    ...                      max_evaluations=6, target_rel_err=0.2, seed=1)
    >>> outcome.result.names, outcome.result.x[0] < outcome.result.start[0]
    (('surface.rms_slope',), True)
    >>> sorted(p.name for p in out.iterdir() if not p.name.startswith("."))
    ['fit-state.json', 'fit.json', 'fitted', 'fitted.toml', 'initial', 'report', 'walks']
    """
    _v.integer("max_evaluations", max_evaluations, 1, 10**6, none=True)
    _v.integer("max_runs", max_runs, 2, 10**4, none=True)
    _v.rel_err("target_rel_err", target_rel_err)
    _v.seed("seed", seed)
    _v.threads("threads", threads)
    _v.number("colour_weight", colour_weight, 0.0)
    _v.wavelengths("wavelengths_nm", wavelengths_nm)
    _v.integer("starts", starts, 1, 1000)
    for arg, value in (("resume", resume), ("force", force), ("progress", progress), ("absolute", absolute),
                       ("colour_hold", colour_hold), ("mc_retrace", mc_retrace)):
        _v.flag(arg, value)
    data = as_dataset(measured)
    _v.measurement_rows(f"measured ({data.path or data.name})", len(data))
    with _v.claimed("out", _v.out_path("out", out)):     # one writer of the fit's folder
        return prepare_fit(config, data, free, out, method=method, dye=dye, max_evaluations=max_evaluations,
                           max_runs=max_runs, target_rel_err=target_rel_err, seed=seed, threads=threads,
                           colour_weight=colour_weight, wavelengths_nm=wavelengths_nm, mc_trend=mc_trend,
                           starts=starts, resume=resume, force=force, absolute=absolute,
                           colour_hold=colour_hold, mc_retrace=mc_retrace).run(progress=progress)
