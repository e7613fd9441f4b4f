"""The Python interface of fabric-optics: what the command lines do, as functions.

Load a config or plan, measure on the mock instrument or import a measurement, simulate a fabric at
a plan's geometries, compare datasets and judge the comparison, write the report, fit config
parameters to a measurement, read and write datasets, export to a renderer. Every function returns
the project's own objects (a `Dataset` holds a pandas table in `.table` and its metadata in
`.meta`), raises `InputError` (a `ToolkitError`) for bad input instead of exiting, and shows a
progress bar only when `progress=True`. The tutorial "Python, from measurement to report" runs a
whole chain.

Examples
--------
>>> import fabric_optics as fo
>>> fo.load_config("red-cotton").name
'red-cotton'
>>> fo.load_config("no-such-preset")
Traceback (most recent call last):
...
fabric_optics.api.InputError: ...no-such-preset...
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from compare.comparison import Comparison
from compare.metrics import DEFAULT_MAX_HUE_DIFF, DEFAULT_MAX_LEVEL_RATIO, DEFAULT_MAX_NRMSE, DEFAULT_MAX_SAT_DIFF
from compare.normalise import DEFAULT_WINDOW_DEG
from gonio.acquisition.plan import Plan
from gonio.data.dataset import Dataset
from gonio.data.formats import FORMATS
from gonio.data.outputs import OutputRefused
from gonio.data.outputs import refuse_existing as _refuse_output
from gonio.data.outputs import refuse_run_folder as _refuse_run_folder
from simulate.config import SimulationConfig
from fabric_optics import validate as _v
from fabric_optics.errors import (FileSystemError, InputError, InternalError, OutputBusyError,
                                  OutputExistsError, ToolkitError, typed_errors)
from fabric_optics.fitting.errors import FitWarning
from fabric_optics.fitting.methods import DEFAULT_METHOD, METHODS

if TYPE_CHECKING:
    from fabric_optics.fitting.outputs import FitResult

__all__ = [
    "ToolkitError", "InputError", "OutputExistsError", "OutputBusyError", "FileSystemError", "InternalError",
    "load_config", "load_plan", "read_dataset", "write_dataset",
    "measure_on_mock", "truth", "simulate", "compare", "check", "Verdict", "fit", "prepare_fit", "FitJob",
    "FitOutcome", "FitWarning", "export_bsdf", "import_measurement", "write_report", "Comparison",
    "FABRIC_METHODS", "FIT_METHODS", "IMPORT_FORMATS",
]

FABRIC_METHODS = ("summation", "classic", "mc", "auto")
"""The fabric models `simulate` takes (`method=`): summation over the fabric's fibers, the classic Lambert +
Cook-Torrance model, Monte Carlo ray tracing of the fabric, or per geometry the cheapest within the target."""
FIT_METHODS = tuple(METHODS)
"""The models a fit can adjust, from the fit's method registry (`fabric_optics.fitting.methods.METHODS`); `auto`
is not one: its choice changes between evaluations."""


#: Every function below raises only :class:`ToolkitError` subclasses (:mod:`fabric_optics.errors`)
_typed_errors = typed_errors


@_typed_errors
def load_config(config: str | os.PathLike | SimulationConfig) -> SimulationConfig:
    """A simulation config: a preset, a TOML file, or a config already loaded.

    Parameters
    ----------
    config : str, path or SimulationConfig
        A preset name (`"red-cotton"`, `"green-felt"`, `"green-felt-mc"`, ...), the path of a config
        TOML file (docs: config schema), or a config already loaded (returned as is).

    Returns
    -------
    SimulationConfig
        The validated config (`.name`, `.wavelengths_nm`, `.target_rel_err`, ...).

    Raises
    ------
    InputError
        No such preset or file, or a field that is invalid (the message names it).

    Examples
    --------
    >>> import fabric_optics as fo
    >>> cfg = fo.load_config("red-cotton")
    >>> cfg.name, len(cfg.wavelengths_nm) > 0
    ('red-cotton', True)
    """
    from simulate.config import load_config as _load

    if isinstance(config, SimulationConfig):
        return config
    _v.path("config", config)
    return _load(config if isinstance(config, (str, Path)) else Path(config))


@_typed_errors
def load_plan(plan: str | os.PathLike | Plan = "red-cotton") -> Plan:
    """An acquisition plan: the geometries to measure (or simulate) and the wavelengths.

    Parameters
    ----------
    plan : str, path or Plan
        A preset name (`"red-cotton"`, `"green-felt"`, ...; docs: plans), the path of a plan TOML
        file, or a plan already loaded (returned as is).

    Returns
    -------
    Plan
        The validated plan; `plan.geometries()` is its table of geometries.

    Raises
    ------
    InputError
        No such preset or file, or a field that is invalid (the message names it).

    Examples
    --------
    >>> import fabric_optics as fo
    >>> plan = fo.load_plan("red-cotton")
    >>> plan.name, sorted(plan.geometries()["theta_i"].unique().tolist())
    ('red-cotton', [0.0, 30.0, 45.0, 60.0])
    """
    from gonio.acquisition.plan import load_plan as _load

    if isinstance(plan, Plan):
        return plan
    _v.path("plan", plan)
    return _load(plan if isinstance(plan, (str, Path)) else Path(plan))


def _dataset(data: str | os.PathLike | Dataset) -> Dataset:
    return data if isinstance(data, Dataset) else read_dataset(data)


@_typed_errors
def read_dataset(path: str | os.PathLike) -> Dataset:
    """Read a radiance-coefficient dataset folder (`radiance.csv` and `meta.json`; docs: dataset format).

    Parameters
    ----------
    path : str or path
        The dataset folder.

    Returns
    -------
    Dataset
        The dataset: `.table` (pandas), `.meta` (dict), `.name`, `.kind`, `.wavelengths_nm`.

    Raises
    ------
    InputError
        No such folder, or a file that is not a valid dataset (the message names file and field).

    Examples
    --------
    >>> import fabric_optics as fo
    >>> measured = fo.read_dataset("fixtures/analytic/measured_red")
    >>> measured.kind, len(measured) > 0
    ('measured', True)
    """
    from gonio.data.dataset import read_dataset as _read

    _v.path("path", path)
    return _read(path)


@_typed_errors
def write_dataset(dataset: Dataset, path: str | os.PathLike, *, force: bool = False) -> Path:
    """Write `dataset` as a dataset folder (`radiance.csv`, `meta.json`), each file atomically.

    Parameters
    ----------
    dataset : Dataset
        What to write.
    path : str or path
        The folder; created when missing.
    force : bool, default False
        Replace an existing non-empty folder's dataset.

    Returns
    -------
    Path
        The folder written.

    Raises
    ------
    OutputExistsError
        `path` exists and is not empty, and `force` is False.

    Examples
    --------
    >>> import tempfile
    >>> from pathlib import Path
    >>> import fabric_optics as fo
    >>> out = Path(tempfile.mkdtemp()) / "truth"
    >>> fo.write_dataset(fo.truth("lambert:0.5"), out).name
    'truth'
    >>> fo.write_dataset(fo.truth("lambert:0.5"), out)
    Traceback (most recent call last):
    ...
    fabric_optics.api.OutputExistsError: ...the folder is not empty; pass force=True to replace its output, or choose a new folder
    """
    from gonio.data.dataset import write_dataset as _write

    if not isinstance(dataset, Dataset):
        raise InputError(f"dataset: expected a Dataset, got {type(dataset).__name__}")
    out = _v.out_path("path", path)
    _v.flag("force", force)
    with _v.claimed("path", out):
        _refuse_existing(out, force, "path", run_folder=True)
        return _write(dataset, out)


@_typed_errors
def simulate(config: str | os.PathLike | SimulationConfig, plan: str | os.PathLike | Plan = "red-cotton",
             method: str = "summation", *, target_rel_err: float | None = None, seed: int | None = None,
             threads: int | None = None, max_photons: int | None = None, measurable_only: bool = False,
             progress: bool = False, max_seconds: float = 0.0) -> Dataset:
    """Simulate a fabric's radiance coefficient at a plan's geometries and wavelengths (`simulate fabric`).

    Parameters
    ----------
    config : str, path or SimulationConfig
        The fabric: a preset name, a config TOML file or a loaded config (`load_config`).
    plan : str, path or Plan, default "red-cotton"
        Where to evaluate it: a plan preset, a plan TOML file or a loaded plan (`load_plan`).
    method : str, default "summation"
        One of `FABRIC_METHODS`: `"summation"` (over the fabric's fibers), `"classic"` (Lambert +
        Cook-Torrance), `"mc"` (Monte Carlo ray tracing of the fabric) or `"auto"` (per geometry the
        cheapest method whose error is within the target).
    target_rel_err : float, optional
        Relative standard error the Monte Carlo aims at; the config's by default.
    seed : int, optional
        Random seed (the config's by default); the same seed gives the same numbers with any
        number of threads.
    threads : int, optional
        Worker threads; `0` uses every core numba may; the config's by default.
    max_photons : int, optional
        Upper bound on the photons of each Monte Carlo walk; the config's by default.
    measurable_only : bool, default False
        Leave out the plan's geometries the instrument cannot measure (the beam-blocked zone).
    progress : bool, default False
        Show a progress bar.
    max_seconds : float, default 0.0
        Refuse a run estimated to take longer (0: the built-in bound of one day).

    Returns
    -------
    Dataset
        A simulated dataset; `u_beta` is the Monte Carlo's standard error, `meta["provenance"]`
        records the config, the method and the software that made it.

    Raises
    ------
    InputError
        An unknown method, config or plan, or a run refused by its cost estimate.

    Examples
    --------
    The `quick` plan (incidences 0 and 45 deg, three observation angles, six wavelengths) and the
    classic model, the quickest (a few seconds):

    >>> import fabric_optics as fo
    >>> sim = fo.simulate("red-cotton", plan="quick", method="classic")
    >>> sim.kind, len(sim), sim.wavelengths_nm.tolist()
    ('simulated', 36, [400.0, 450.0, 500.0, 550.0, 600.0, 650.0])
    """
    from simulate.virtual import fabric_dataset

    if method not in FABRIC_METHODS:
        raise InputError(f"method {method!r}: choose one of {', '.join(FABRIC_METHODS)}")
    _v.rel_err("target_rel_err", target_rel_err)
    _v.seed("seed", seed)
    _v.threads("threads", threads)
    _v.integer("max_photons", max_photons, 1, 10**15, none=True)
    _v.flag("measurable_only", measurable_only)
    _v.flag("progress", progress)
    _v.number("max_seconds", max_seconds, 0.0)
    config, plan = load_config(config), load_plan(plan)
    _v.cost(config, plan.wavelengths_nm, target_rel_err, max_photons)
    return fabric_dataset(config, plan, method, target_rel_err=target_rel_err, seed=seed,
                          threads=threads, max_photons=max_photons, measurable_only=measurable_only,
                          progress=progress, max_seconds=max_seconds)


@_typed_errors
def compare(measured: str | os.PathLike | Dataset, simulated: Dataset | str | os.PathLike
            | Sequence[Dataset | str | os.PathLike], *, window_deg: float = DEFAULT_WINDOW_DEG,
            illuminant: str = "D65") -> Comparison:
    """Compare simulations with a measurement: each normalised to it at the normal direction, then
    curve errors and the colour match (what `compare report` and `compare check` compute).

    Parameters
    ----------
    measured : Dataset or path
        The measurement (a dataset or its folder).
    simulated : Dataset, path, or a sequence of them
        One simulation or several, each a dataset or its folder.
    window_deg : float, default 5
        Largest |s| of the normal-incidence points used to estimate the measurement at the
        normal direction.
    illuminant : str, default "D65"
        Illuminant of the colour match.

    Returns
    -------
    Comparison
        `.overall[name].nrmse` (the overall curve error of each simulation by name),
        `.curves[name][incidence]` (per incidence), `.colour` (the HSV colour match, None for a
        photometric measurement), `.level(name)` (the absolute level), `.metrics()` (every figure,
        as `metrics.json` holds them); judge it with `check`.

    Raises
    ------
    InputError
        A dataset that cannot be read, or datasets that share no geometry or wavelength.

    Examples
    --------
    >>> import fabric_optics as fo
    >>> comparison = fo.compare("fixtures/analytic/measured_red", "fixtures/analytic/sim_lambert")
    >>> name = next(iter(comparison.simulated))
    >>> round(comparison.overall[name].nrmse, 3) > 0
    True
    """
    from compare.comparison import compare_datasets

    _v.number("window_deg", window_deg, 0.0, 90.0, lo_open=True)
    _v.illuminant("illuminant", illuminant)
    if not isinstance(measured, Dataset):
        _v.path("measured", measured)
    if not isinstance(simulated, (Dataset, str, os.PathLike)):
        if not isinstance(simulated, (list, tuple)):
            raise InputError(f"simulated={simulated!r}: expected a dataset, a dataset folder or a list of them")
        if not simulated:
            raise InputError("simulated: no dataset; give at least one")
        for k, sim in enumerate(simulated):
            if not isinstance(sim, Dataset):
                _v.path(f"simulated[{k}]", sim)
    elif not isinstance(simulated, Dataset):
        _v.path("simulated", simulated)
    sims = [simulated] if isinstance(simulated, (Dataset, str, os.PathLike)) else list(simulated)
    return compare_datasets(_dataset(measured), [_dataset(s) for s in sims], window_deg=window_deg,
                            illuminant=illuminant)


@dataclass(frozen=True)
class Verdict:
    """The pass/fail judgement of one simulation against the measurement (`compare check`), made by `check`.

    Attributes
    ----------
    name : str
        The simulation judged.
    measured : str
        The measurement's name.
    figures : list of (str, float, float, str)
        `(label, value, limit, unit)` of every figure judged: the overall NRMSE, and where the colour
        is known the |hue difference| and |saturation difference|, and the absolute level for an
        absolute measurement. A NaN value fails.
    curves : dict of str to float
        The NRMSE per incidence angle (informative, not judged).
    notes : list of str
        What a reader must know about how the data were compared.
    """

    name: str
    measured: str
    figures: list[tuple[str, float, float, str]]
    curves: dict[str, float] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)

    @property
    def passed(self) -> bool:
        """True when every figure is within its limit (`compare check` exits 0); a NaN fails."""
        return all(value <= limit for _, value, limit, _ in self.figures)

    def failures(self) -> list[str]:
        """The labels of the figures beyond their limits (empty when `passed`)."""
        return [label for label, value, limit, _ in self.figures if not value <= limit]

    def summary(self) -> str:
        """The lines `compare check` prints: each figure with `ok` or `FAIL` and its limit."""
        lines = [f"'{self.name}' against '{self.measured}'"]
        lines += [f"  note: {n}" for n in self.notes]
        for label, value, limit, unit in self.figures:
            ok = value <= limit
            lines.append(f"  {'ok  ' if ok else 'FAIL'} {label} = {value:.4g}{unit} ({'<=' if ok else 'exceeds'} "
                         f"{limit:g})")
        lines += [f"       NRMSE at incidence {a} deg = {v:.4g}" for a, v in self.curves.items()]
        return "\n".join(lines)


@_typed_errors
def check(comparison: Comparison, *, name: str | None = None, max_nrmse: float = DEFAULT_MAX_NRMSE,
          max_hue_diff: float = DEFAULT_MAX_HUE_DIFF, max_sat_diff: float = DEFAULT_MAX_SAT_DIFF,
          max_level_ratio: float = DEFAULT_MAX_LEVEL_RATIO) -> Verdict:
    """Judge one simulation of a comparison against thresholds (`compare check`).

    Parameters
    ----------
    comparison : Comparison
        What `compare` returned.
    name : str, optional
        The simulation to judge; the first of the comparison by default.
    max_nrmse : float, default 0.10
        Largest overall NRMSE of the normalised curves.
    max_hue_diff : float, default 0.02
        Largest |hue difference|, in turns of the hue circle (judged where the colour is known).
    max_sat_diff : float, default 0.05
        Largest |saturation difference| (judged where the colour is known).
    max_level_ratio : float, default 1.5
        Largest `max(k_Y, 1/k_Y)`, the absolute level against the measurement's (not judged for a
        relative measurement).

    Returns
    -------
    Verdict
        `.passed`, `.failures()`, `.summary()` (the lines `compare check` prints).

    Raises
    ------
    InputError
        `comparison` has no simulation called `name`.

    Examples
    --------
    >>> import fabric_optics as fo
    >>> comparison = fo.compare("fixtures/analytic/measured_red", "fixtures/analytic/sim_lambert")
    >>> verdict = fo.check(comparison)
    >>> verdict.passed, verdict.failures()[0]
    (False, 'overall NRMSE')
    """
    if not isinstance(comparison, Comparison):
        raise InputError(f"comparison: expected a Comparison (from compare()), got {type(comparison).__name__}")
    _v.text("name", name, none=True)
    for arg, value in (("max_nrmse", max_nrmse), ("max_hue_diff", max_hue_diff), ("max_sat_diff", max_sat_diff),
                       ("max_level_ratio", max_level_ratio)):
        _v.number(arg, value, 0.0)
    name = name if name is not None else next(iter(comparison.simulated))
    if name not in comparison.simulated:
        raise InputError(f"no simulation named {name!r} in the comparison ({', '.join(comparison.simulated)})")
    figures = [("overall NRMSE", comparison.overall[name].nrmse, max_nrmse, "")]
    if comparison.colour is not None:
        sc = comparison.colour.simulated[name]
        figures += [("|hue difference|", abs(sc.dh), max_hue_diff, " turns of the hue circle"),
                    ("|saturation difference|", abs(sc.ds), max_sat_diff, "")]
    level = comparison.level(name)
    if level.judged:
        figures.append(("level ratio max(k_Y, 1/k_Y)", level.ratio, max_level_ratio,
                        f" (k_Y {level.k:.3g}, k(lambda) spread {level.spread:.3g})"))
    return Verdict(name=name, measured=comparison.measured.name, figures=figures,
                   curves={a: e.nrmse for a, e in comparison.curves[name].items()}, notes=list(comparison.notes()))


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
    """A fit checked and ready to run (:func:`prepare_fit`): ``problem`` (its ``wavelengths_nm``,
    ``config``, ...), the output folder ``out`` and the ``budget`` (what the method's budget counts: model
    evaluations, or Monte Carlo runs of the ``mc`` fit). :meth:`run` searches, writes ``out`` and returns the
    outcome."""

    problem: Any
    out: Path
    method: str
    budget: int
    starts: int
    resume: bool
    #: "ready", "search", "writing" (the outputs being put in place) or "done"
    phase: str = "ready"

    @_typed_errors
    def run(self, *, progress: bool = False) -> FitOutcome:
        """Search, write the outputs and return the outcome. A fit that fails (its colour left off) or never moved
        from its start warns (:class:`FitWarning`); its outputs are written all the same."""
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


@_typed_errors
def prepare_fit(config: str | os.PathLike | SimulationConfig, measured: str | os.PathLike | Dataset,
                free: str | Sequence[str], out: str | os.PathLike, *, method: str = DEFAULT_METHOD,
                dye: str = "config", max_evaluations: int | None = None, max_runs: int | None = None,
                target_rel_err: float | None = None, seed: int | None = None, threads: int | None = None,
                colour_weight: float = 1.0, wavelengths_nm: Sequence[float] | None = None,
                mc_trend: Sequence[str] = (), starts: int = 1, resume: bool = False,
                force: bool = False, absolute: bool = False, colour_hold: bool = True,
                mc_retrace: bool = False) -> FitJob:
    """Everything :func:`fit` checks before its search (arguments as :func:`fit`): the config, the
    measurement, the free parameters and their bounds, the output folder. Nothing is written."""
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
    data = _dataset(measured)
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
        _refuse_existing(out_dir, force, ask="resume=True to continue a fit there or force=True")
    budget = budgets[fit_method.budget]
    return FitJob(problem=problem, out=out_dir, method=method,
                  budget=fit_method.default_budget if budget is None else budget, starts=starts, resume=resume)


@_typed_errors
def fit(config: str | os.PathLike | SimulationConfig, measured: str | os.PathLike | Dataset,
        free: str | Sequence[str], out: str | os.PathLike, *, method: str = DEFAULT_METHOD, dye: str = "config",
        max_evaluations: int | None = None, max_runs: int | None = None, target_rel_err: float | None = None,
        seed: int | None = None, threads: int | None = None, colour_weight: float = 1.0,
        wavelengths_nm: Sequence[float] | None = None, mc_trend: Sequence[str] = (), starts: int = 1,
        resume: bool = False, force: bool = False, progress: bool = False, absolute: bool = False,
        colour_hold: bool = True, mc_retrace: bool = False) -> FitOutcome:
    """Fit parameters of a fabric model to a measurement (`simulate fit`).

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
    target_rel_err, seed : optional
        The first Monte Carlo walk's relative error and the seed (the config's by default).
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
    data = _dataset(measured)
    _v.measurement_rows(f"measured ({data.path or data.name})", len(data))
    with _v.claimed("out", _v.out_path("out", out)):     # one writer of the fit's folder
        return prepare_fit(config, data, free, out, method=method, dye=dye, max_evaluations=max_evaluations,
                           max_runs=max_runs, target_rel_err=target_rel_err, seed=seed, threads=threads,
                           colour_weight=colour_weight, wavelengths_nm=wavelengths_nm, mc_trend=mc_trend,
                           starts=starts, resume=resume, force=force, absolute=absolute,
                           colour_hold=colour_hold, mc_retrace=mc_retrace).run(progress=progress)


@_typed_errors
def export_bsdf(source: str | os.PathLike | SimulationConfig | Dataset, path: str | os.PathLike, *,
                method: str = "summation", wavelengths_nm: Sequence[float] | None = None, rgb: bool = False,
                resolution: int = 64, incidences: int = 16, target_rel_err: float | None = None,
                seed: int | None = None, threads: int | None = None, max_photons: int | None = None,
                check_pairs: int = 0, anisotropic: int = 0, azimuths: int = 5, description: str | None = None,
                provenance: dict | None = None, force: bool = False, progress: bool = False) -> Any:
    """Write an RGL `.bsdf` file (Mitsuba 3's `measured` material, pbrt-v4) of a fabric model or a dataset.

    Parameters
    ----------
    source : str, path, SimulationConfig or Dataset
        A fabric (a preset, a config TOML file or a loaded config), evaluated by `method`; or a
        dataset, its values interpolated (and extrapolated where it has no data: the rule is in
        the result's `.provenance["coverage"]`).
    path : str or path
        The `.bsdf` file to write.
    method : str, default "summation"
        For a fabric: `"summation"`, `"classic"` or `"mc"`.
    wavelengths_nm : sequence of float, optional
        For a fabric: the file's wavelengths, increasing (the config's by default).
    rgb : bool, default False
        For a fabric: an RGB file instead of a spectral one.
    resolution : int, default 64
        Values per axis of the tabulation (4 to 256).
    incidences : int, default 16
        Incidence nodes (2 to 64).
    target_rel_err, seed, threads, max_photons : optional
        The Monte Carlo budget of a fabric, as in `simulate`.
    check_pairs : int, default 0
        Measure the tabulation error at that many random direction pairs (more model evaluations).
    anisotropic : int, default 0
        1, 2 or 4: keep the model's anisotropy with `azimuths` incidence azimuths over
        360/`anisotropic` degrees; 0: isotropic.
    azimuths : int, default 5
        Incidence azimuths of an anisotropic file.
    description : str, optional
        The file's description (a dataset's).
    provenance : dict, optional
        Merged into the provenance written into a dataset's file.
    force : bool, default False
        Replace an existing file.
    progress : bool, default False
        Show a progress bar.

    Returns
    -------
    ExportResult
        `.path`, `.evaluations`, `.valid_fraction`, `.error` (with `check_pairs`), `.provenance`.

    Raises
    ------
    OutputExistsError
        `path` exists and `force` is False.
    InputError
        A resolution, incidence count, method or anisotropy out of range.

    Examples
    --------
    >>> import tempfile
    >>> from pathlib import Path
    >>> import fabric_optics as fo
    >>> measured = fo.read_dataset("fixtures/analytic/measured_red")
    >>> result = fo.export_bsdf(measured, Path(tempfile.mkdtemp()) / "red.bsdf", resolution=8, incidences=4)
    >>> Path(result.path).name, result.provenance["coverage"]["incidences_deg"]
    ('red.bsdf', [0.0, 30.0, 45.0, 60.0])
    """
    out = _v.out_path("path", path, file=True)
    _v.choice("method", method, ("summation", "classic", "mc"))
    _v.wavelengths("wavelengths_nm", wavelengths_nm)
    for arg, value in (("rgb", rgb), ("force", force), ("progress", progress)):
        _v.flag(arg, value)
    _v.integer("resolution", resolution, 4, 256)
    _v.integer("incidences", incidences, 2, 64)
    _v.rel_err("target_rel_err", target_rel_err)
    _v.seed("seed", seed)
    _v.threads("threads", threads)
    _v.integer("max_photons", max_photons, 1, 10**15, none=True)
    _v.integer("check_pairs", check_pairs, 0, _v.MAX_CHECK_PAIRS)
    _v.choice("anisotropic", anisotropic, (0, 1, 2, 4))
    _v.integer("azimuths", azimuths, 3, _v.MAX_AZIMUTHS)
    _v.text("description", description, none=True)
    if provenance is not None and not isinstance(provenance, dict):
        raise InputError(f"provenance: expected a dict, got {type(provenance).__name__}")
    if not isinstance(source, (Dataset, SimulationConfig, str, os.PathLike)):
        raise InputError(f"source: expected a config, preset name, path or Dataset, got {type(source).__name__}")
    with _v.claimed("path", out, file=True):
        return _export_bsdf(source, out, method=method, wavelengths_nm=wavelengths_nm, rgb=rgb,
                            resolution=resolution, incidences=incidences, target_rel_err=target_rel_err, seed=seed,
                            threads=threads, max_photons=max_photons, check_pairs=check_pairs,
                            anisotropic=anisotropic, azimuths=azimuths, description=description,
                            provenance=provenance, force=force, progress=progress)


def _export_bsdf(source: str | os.PathLike | SimulationConfig | Dataset, out: Path, *, method: str,
                 wavelengths_nm: Sequence[float] | None, rgb: bool, resolution: int, incidences: int,
                 target_rel_err: float | None, seed: int | None, threads: int | None, max_photons: int | None,
                 check_pairs: int, anisotropic: int, azimuths: int, description: str | None,
                 provenance: dict | None, force: bool, progress: bool) -> Any:
    _refuse_existing(out, force, "path", file=True)
    if isinstance(source, Dataset):
        from gonio.data.bsdf_dataset import dataset_brdf, dataset_nodes
        from gonio.data.bsdf_export import export_bsdf as _export

        beta, rule = dataset_brdf(source)
        return _export(beta, out, wavelengths_nm=None if source.is_rgb else source.wavelengths_nm,
                       theta_i_deg=dataset_nodes(rule, incidences), res=resolution,
                       description=description or f"{source.name} (fabric-optics export of a measured dataset)",
                       provenance={"dataset": source.name, **(provenance or {}), "coverage": rule})
    from simulate.export import export_model

    if method not in ("summation", "classic", "mc"):
        raise InputError(f"method {method!r}: choose one of summation, classic, mc")
    if anisotropic not in (0, 1, 2, 4):
        raise InputError(f"anisotropic {anisotropic}: choose 0 (isotropic), 1, 2 or 4")
    if threads == 0:        # 0 = all that numba allows, as in simulate()
        import numba

        threads = int(numba.config.NUMBA_NUM_THREADS)
    config = load_config(source)
    _v.cost(config, config.wavelengths_nm if wavelengths_nm is None else wavelengths_nm, target_rel_err, max_photons)
    return export_model(config, method, out, wavelengths_nm=wavelengths_nm, rgb=rgb, res=resolution,
                        incidences=incidences, target_rel_err=target_rel_err, seed=seed, threads=threads,
                        max_photons=max_photons, check_pairs=check_pairs, reduction=anisotropic, n_phi_i=azimuths,
                        progress=progress)


@_typed_errors
def measure_on_mock(out: str | os.PathLike, *, sample: str = "red-cotton", plan: str | os.PathLike | Plan | None = None,
                    seed: int = 0, force: bool = False, progress: bool = False) -> Dataset:
    """Measure a plan on the embedded mock goniophotometer, through the real driver and protocols (`gonio demo`).

    The mock serves Modbus TCP and a serial line on loopback; the driver calibrates against the
    white standard and measures every point of the plan, writing the run's journal and the
    dataset into `out`.

    Parameters
    ----------
    out : str or path
        The run folder (journal and dataset).
    sample : str, default "red-cotton"
        What the mock holds: `"red-cotton"` (an analytic stand-in with the published colour of red
        cotton), `"lambert:RHO"`, a dataset folder, or an RGL `.bsdf` file such as
        `fixtures/real/acrylic_felt_green_rgb.bsdf`.
    plan : str, path or Plan, optional
        The plan; by default the red-cotton plan's geometry, named after the sample.
    seed : int, default 0
        Seed of the mock's noise.
    force : bool, default False
        Replace an earlier demo's folder (another acquisition's run folder is never replaced).
    progress : bool, default False
        Show a progress bar.

    Returns
    -------
    Dataset
        The measured dataset, as written in `out`.

    Raises
    ------
    OutputExistsError
        `out` holds an earlier output and `force` is False, or holds another acquisition's run.
    InputError
        An unknown sample or plan.

    Examples
    --------
    The `quick` plan takes about a second (the red-cotton plan about 25 s: the mock's settle
    times are real):

    >>> import tempfile
    >>> from pathlib import Path
    >>> import fabric_optics as fo
    >>> out = Path(tempfile.mkdtemp()) / "measured"
    >>> measured = fo.measure_on_mock(out, sample="red-cotton", plan="quick")
    >>> measured.kind, len(measured), (out / "radiance.csv").is_file()
    ('measured', 36, True)
    """
    from gonio.demo import run_demo
    from gonio.mock.samples import SampleError

    out = _v.out_path("out", out)
    _v.text("sample", sample, max_len=4096)
    _v.integer("seed", seed, 0, _v.MAX_SEED)
    _v.flag("force", force)
    _v.flag("progress", progress)
    plan_obj = load_plan("red-cotton" if plan is None else plan)
    with _v.claimed("out", out):
        try:
            run_demo(out, plan_obj, seed=seed, force=force, progress=progress, sample=sample,
                     name_from_sample=plan is None and sample != "red-cotton")
        except SampleError as exc:
            raise InputError(f"sample {sample!r}: {exc}") from exc
        except OutputRefused as exc:
            raise OutputExistsError(str(exc)) from exc
    return read_dataset(out)


@_typed_errors
def truth(sample: str, plan: str | os.PathLike | Plan = "red-cotton") -> Dataset:
    """The mock sample's true radiance coefficient at a plan's geometries: what a perfect measurement
    of it gives (`gonio truth`), to check an acquisition against.

    Parameters
    ----------
    sample : str
        A mock sample, as `measure_on_mock` takes it.
    plan : str, path or Plan, default "red-cotton"
        The geometries and wavelengths.

    Returns
    -------
    Dataset
        The sample's values, without instrument noise.

    Raises
    ------
    InputError
        An unknown sample or plan.

    Examples
    --------
    >>> import fabric_optics as fo
    >>> truth = fo.truth("lambert:0.5", plan="red-cotton")
    >>> float(truth.table["beta"].min()), float(truth.table["beta"].max())
    (0.5, 0.5)
    """
    from gonio.mock.samples import SampleError
    from gonio.mock.truth import truth_dataset

    _v.text("sample", sample, max_len=4096)
    try:
        return truth_dataset(sample, load_plan(plan))
    except SampleError as exc:
        raise InputError(f"sample {sample!r}: {exc}") from exc


IMPORT_FORMATS: tuple[str, ...] = tuple(FORMATS)
"""The file formats `import_measurement` reads (`gonio import FORMAT`): `"rgl-bsdf"` (RGL `.bsdf` tensor
files), `"pgii"` (PAB pgII text files, one incidence each), `"merl"` (MERL binary tables)."""
_SUFFIX_FORMATS = {".bsdf": "rgl-bsdf", ".binary": "merl"}


def _refuse_existing(out: Path, force: bool, what: str = "out", *, ask: str = "force=True",
                     file: bool = False, run_folder: bool = False) -> None:
    """An existing file, or a folder holding anything (hidden files aside), only with `force`; `run_folder`:
    a run folder never (the output rule of every writer, `gonio.data.outputs`)."""
    try:
        if run_folder:
            _refuse_run_folder(out, option=what, ask=ask)
        _refuse_output(out, force=force, option=what, ask=ask, file=file)
    except OutputRefused as exc:
        raise OutputExistsError(str(exc)) from None


@_typed_errors
def import_measurement(path: str | os.PathLike | Sequence[str | os.PathLike], out: str | os.PathLike | None = None,
                       *, force: bool = False, format: str | None = None, plan: str | os.PathLike | Plan | None = None,
                       scale: float | None = None, white: str | os.PathLike | None = None,
                       white_reflectance: float = 0.99, keep_grazing: bool = False) -> Dataset:
    """Import a measurement made elsewhere as a radiance-coefficient dataset (`gonio import`).

    Parameters
    ----------
    path : str, path, or a sequence of them
        The file, or the files of one measurement (pgII: one file per incidence).
    out : str or path, optional
        Also write the dataset into this folder (as `gonio import --out` does).
    force : bool, default False
        Replace what `out` holds.
    format : str, optional
        One of `IMPORT_FORMATS`: `"rgl-bsdf"` (RGL `.bsdf` tensor files, RGB or spectral), `"pgii"`
        (PAB pgII text files) or `"merl"` (MERL `.binary` tables). Inferred from a `.bsdf` or
        `.binary` suffix; required for pgII files.
    plan : str, path or Plan, optional
        For the tabulated formats (rgl-bsdf, merl): evaluate the file at this plan's geometries;
        `"measured"` (rgl-bsdf only): the file's own measured incidences and its retro-reflection
        rings. By default in-plane curves (at an RGL file's own incidences).
    scale : float, optional
        pgII files in detector current (uA): f_r per uA, making absolute values; without it (and
        without `white`) the dataset is relative.
    white : str or path, optional
        pgII: a pgII file of a diffuse white standard measured with the same detector (absolute values).
    white_reflectance : float, default 0.99
        The hemispherical reflectance of that standard.
    keep_grazing : bool, default False
        Keep incidences at 89 deg and beyond (the RGL files' last node is an extrapolation; dropped
        with a note by default).

    Returns
    -------
    Dataset
        The imported dataset (RGB files give a dataset with a `channel` column).

    Raises
    ------
    InputError
        An unknown or uninferable format, a malformed file (the message names file and line or
        offset), a non-positive `scale`, a `white_reflectance` outside (0, 1].
    OutputExistsError
        `out` holds something and `force` is False.

    Examples
    --------
    The real green felt of the RGL database, at its own incidences:

    >>> import fabric_optics as fo
    >>> felt = fo.import_measurement("fixtures/real/acrylic_felt_green_rgb.bsdf")
    >>> felt.is_rgb, sorted(felt.table["channel"].unique())
    (True, ['B', 'G', 'R'])
    """
    from gonio.acquisition.plan import MEASURED, measured_plan
    from gonio.data.formats import import_files

    if isinstance(path, (str, os.PathLike)):
        paths = [_v.path("path", path)]
    elif isinstance(path, (list, tuple)) and 0 < len(path) <= 1000:
        paths = [_v.path(f"path[{k}]", p) for k, p in enumerate(path)]
    else:
        raise InputError(f"path={path!r}: give a file or a list of 1 to 1000 files")
    if format is not None:
        _v.choice("format", format, IMPORT_FORMATS)
    _v.number("scale", scale, 0.0, lo_open=True, none=True)
    _v.number("white_reflectance", white_reflectance, 0.0, 1.0, lo_open=True)
    _v.path("white", white, none=True)
    _v.flag("force", force)
    _v.flag("keep_grazing", keep_grazing)
    if out is not None:
        _v.out_path("out", out)
    fmt = format if format is not None else _SUFFIX_FORMATS.get(Path(paths[0]).suffix.lower())
    if fmt is None:
        raise InputError(f"format: cannot tell the format of {paths[0]} from its name; pass format= one of "
                         f"{', '.join(IMPORT_FORMATS)}")
    if fmt not in IMPORT_FORMATS:
        raise InputError(f"format {fmt!r}: choose one of {', '.join(IMPORT_FORMATS)}")
    geometries = None
    if plan is not None:
        if plan == MEASURED:
            if not (str(paths[0]).endswith(".bsdf") and Path(paths[0]).is_file()):
                raise InputError(f"plan {MEASURED!r}: follows the measured incidences of an RGL .bsdf file, but "
                                 f"{paths[0]} is not one; give a .bsdf file or a plan")
            geometries = measured_plan(Path(paths[0])).geometries(measurable_only=True)
        else:
            geometries = load_plan(plan).geometries()
    if out is None:
        return import_files(fmt, paths, geometries, scale=scale, white=white, white_reflectance=white_reflectance,
                            keep_grazing=keep_grazing)
    out_dir = _v.out_path("out", out)
    with _v.claimed("out", out_dir):     # one writer of the dataset's folder, from its check to its last rename
        _refuse_existing(out_dir, force)
        dataset = import_files(fmt, paths, geometries, scale=scale, white=white,
                               white_reflectance=white_reflectance, keep_grazing=keep_grazing)
        from gonio.data.dataset import write_dataset as _write
        from gonio.data.outputs import WRITTEN_BY

        dataset.meta[WRITTEN_BY] = "gonio import"
        _write(dataset, out_dir)
    return dataset


@_typed_errors
def write_report(measured: str | os.PathLike | Dataset, *models: str | os.PathLike | Dataset,
                 out: str | os.PathLike, force: bool = False, fits: Sequence[str | os.PathLike] = (),
                 seed_sample: str | os.PathLike | Dataset | None = None, renders: str | os.PathLike | None = None,
                 svg: bool = False, window_deg: float = DEFAULT_WINDOW_DEG, illuminant: str = "D65") -> Path:
    """Write the comparison report of models against a measurement (`compare report`).

    The report is `report.html` (self-contained: figures embedded), `metrics.json` (every number of
    the page, and the version and commit that wrote it) and `figures/*.png`, written together.

    Parameters
    ----------
    measured : Dataset or path
        The measurement.
    *models : Dataset or path
        The simulations (datasets or their folders), or one `simulate sweep` folder. None: a report
        of the measurement alone (curves, colour strips, colour table).
    out : str or path
        The report's folder: new or empty, or (with `force`) holding anything.
    force : bool, default False
        Write into a folder that holds something (a previous report's files are replaced, other
        files kept).
    fits : sequence of paths, default ()
        `simulate fit` output folders (their `fit.json`): a table of the fitted parameters with
        their uncertainties.
    seed_sample : Dataset or path, optional
        A simulated red-cotton dataset judged against the published colour of red cotton.
    renders : path, optional
        A `compare render` folder, its sheet embedded (needs a model).
    svg : bool, default False
        Also write every figure as `figures/*.svg`.
    window_deg : float, default 5
        Largest |s| of the normal-incidence points used to estimate the measurement at the normal.
    illuminant : str, default "D65"
        Illuminant of the colour match.

    Returns
    -------
    Path
        The path of `report.html`.

    Raises
    ------
    OutputExistsError
        `out` holds something and `force` is False.
    InputError
        A dataset that cannot be read or compared, `renders` that is not a folder or given without
        a model, a sweep folder beside other models.

    Examples
    --------
    >>> import tempfile
    >>> from pathlib import Path
    >>> import fabric_optics as fo
    >>> out = Path(tempfile.mkdtemp()) / "report"
    >>> report = fo.write_report("fixtures/analytic/measured_red", "fixtures/analytic/sim_lambert", out=out)
    >>> report.name, sorted(p.name for p in out.iterdir())
    ('report.html', ['figures', 'metrics.json', 'report.html'])
    """
    if not isinstance(measured, Dataset):
        _v.path("measured", measured)
    for k, model in enumerate(models):
        if not isinstance(model, Dataset):
            _v.path(f"models[{k}]", model)
    if not isinstance(fits, (list, tuple)):
        raise InputError(f"fits={fits!r}: expected a list of `simulate fit` output folders")
    for k, fit_dir in enumerate(fits):
        _v.path(f"fits[{k}]", fit_dir)
    if seed_sample is not None and not isinstance(seed_sample, Dataset):
        seed_dir = _v.path("seed_sample", seed_sample)
        if seed_dir is None or not seed_dir.is_dir():
            raise InputError(f"seed_sample={os.fspath(seed_sample)!r}: no such dataset folder; give a simulated "
                             "red-cotton dataset (simulate fabric red-cotton ... --out DIR)")
    _v.path("renders", renders, none=True)
    out_dir = _v.out_path("out", out)
    _v.flag("force", force)
    _v.flag("svg", svg)
    _v.number("window_deg", window_deg, 0.0, 90.0, lo_open=True)
    _v.illuminant("illuminant", illuminant)
    with _v.claimed("out", out_dir):     # one writer of the report's folder, from its check to its last rename
        return _write_report_claimed(measured, models, out_dir, force=force, fits=fits, seed_sample=seed_sample,
                                     renders=renders, svg=svg, window_deg=window_deg, illuminant=illuminant)


def _write_report_claimed(measured: str | os.PathLike | Dataset, models: Sequence[str | os.PathLike | Dataset],
                          out_dir: Path, *, force: bool, fits: Sequence[str | os.PathLike],
                          seed_sample: str | os.PathLike | Dataset | None, renders: str | os.PathLike | None,
                          svg: bool, window_deg: float, illuminant: str) -> Path:
    """`write_report` once its arguments are checked and its folder claimed."""
    from compare.comparison import compare_datasets
    from compare.report import Section
    from compare.report import write_report as _write_report
    from compare.sweep import is_sweep_dir, write_sweep_report

    if renders is not None and not Path(renders).is_dir():
        raise InputError(f"renders {renders}: not a folder (make one with `compare render FILE.bsdf ... --out DIR`)")
    if renders is not None and not models:
        raise InputError("renders: the renders are set beside a simulation; give a model too")
    _refuse_existing(out_dir, force)
    meas = _dataset(measured)
    if not models:
        from compare.inspect import write_dataset_report

        return write_dataset_report(meas, out_dir, svg=svg, force=force)
    if any(not isinstance(m, Dataset) and is_sweep_dir(Path(m)) for m in models):
        if len(models) > 1:
            raise InputError("models: a sweep folder must be the only model (write_report(measured, sweep_dir, ...))")
        sweep = models[0]
        assert not isinstance(sweep, Dataset)
        return write_sweep_report(meas, Path(sweep), out_dir, svg=svg, force=force, window_deg=window_deg,
                                  illuminant=illuminant)
    comparison = compare_datasets(meas, [_dataset(m) for m in models], window_deg=window_deg, illuminant=illuminant)
    sections = _report_sections(meas, comparison, fits, seed_sample)
    if renders is not None:
        from compare.render import render_section

        sections.append(Section("renders", render_section(renders), before=None))
    return _write_report(comparison, out_dir, svg=svg, force=force, sections=sections)


def _report_sections(measured: Dataset, comparison: Comparison, fits: Sequence[str | os.PathLike],
                     seed_sample: str | os.PathLike | Dataset | None) -> list:
    """What was measured (when the dataset says), the fits' parameters and the seed sample's colour check."""
    from compare.report.fits import fits_section
    from compare.report.samples import measured_sample_section, seed_sample_section

    sections = [s for s in [measured_sample_section(measured)] if s is not None]
    if fits:
        sections.append(fits_section([str(f) for f in fits], comparison.simulated))
    if seed_sample is not None:
        sections.append(seed_sample_section(_dataset(seed_sample)))
    return sections
