"""The Python interface of fabric-optics: what the command lines do, as functions.

Load a config or plan, simulate a fabric at a plan's geometries, compare datasets and judge the
comparison, fit config parameters to a measurement, read and write datasets, export to a renderer.
Every function returns the project's own objects (a :class:`gonio.data.dataset.Dataset` holds a
pandas table in ``.table`` and its metadata in ``.meta``), raises :class:`InputError` (a
:class:`ToolkitError`) for bad input instead of exiting, and shows a progress bar only when
``progress=True``.

>>> import fabric_optics as fo
>>> cfg = fo.load_config("red-cotton")
>>> cfg.name
'red-cotton'
>>> fo.load_config("no-such-preset")
Traceback (most recent call last):
...
fabric_optics.api.InputError: ...no-such-preset...

A whole chain (see ``examples/``)::

    measured = fo.read_dataset("demo-out/measured")
    sim = fo.simulate("red-cotton", plan="red-cotton", method="summation", target_rel_err=0.03)
    verdict = fo.check(fo.compare(measured, sim))
    print(verdict.summary())
"""

from __future__ import annotations

import functools
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

from compare.comparison import Comparison
from compare.errors import CompareError
from compare.metrics import DEFAULT_MAX_HUE_DIFF, DEFAULT_MAX_LEVEL_RATIO, DEFAULT_MAX_NRMSE, DEFAULT_MAX_SAT_DIFF
from compare.normalise import DEFAULT_WINDOW_DEG
from gonio.acquisition.plan import Plan, PlanError
from gonio.data.dataset import Dataset
from gonio.data.schema import DatasetError
from simulate.config import SimulationConfig
from simulate.config_table import ConfigError
from simulate.fabric.summation import FabricError
from fabric_optics.fitting.errors import FitError, FitWarning
from fabric_optics.fitting.methods import DEFAULT_METHOD, METHODS

if TYPE_CHECKING:
    from fabric_optics.fitting.outputs import FitResult

__all__ = [
    "ToolkitError", "InputError", "OutputExistsError",
    "load_config", "load_plan", "read_dataset", "write_dataset",
    "measure_on_mock", "truth", "simulate", "compare", "check", "Verdict", "fit", "prepare_fit", "FitJob",
    "FitOutcome", "FitWarning", "export_bsdf",
    "FABRIC_METHODS", "FIT_METHODS",
]

#: The fabric models (``method=``): summation over the fabric's fibers, the classic Lambert +
#: Cook-Torrance model, Monte Carlo ray tracing of the fabric's model, or per geometry the
#: cheapest whose error is within the target.
FABRIC_METHODS = ("summation", "classic", "mc", "auto")
#: The models a fit can adjust (:data:`fabric_optics.fitting.methods.METHODS`; ``auto`` is not one: its choice
#: changes between evaluations).
FIT_METHODS = tuple(METHODS)


class ToolkitError(Exception):
    """Base of the errors this interface raises."""


class InputError(ToolkitError, ValueError):
    """A config, plan, dataset, parameter or value that cannot be used; the message names it and
    says what to do. The library's own error is kept as ``__cause__``."""


class OutputExistsError(ToolkitError, FileExistsError):
    """The output path holds something already and ``force`` was not given."""


_INPUT_ERRORS: tuple[type[Exception], ...] = (ConfigError, PlanError, DatasetError, FabricError, CompareError)
_F = TypeVar("_F", bound=Callable[..., Any])


def _typed_errors(fn: _F) -> _F:
    """Re-raise the libraries' input errors as :class:`InputError` (the original as ``__cause__``)."""
    @functools.wraps(fn)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        try:
            return fn(*args, **kwargs)
        except ToolkitError:
            raise
        except _INPUT_ERRORS + (FitError,) as exc:
            raise InputError(str(exc)) from exc
    return wrapper  # type: ignore[return-value]


@_typed_errors
def load_config(config: str | os.PathLike | SimulationConfig) -> SimulationConfig:
    """A simulation config: a preset name (``"red-cotton"``, ``"green-felt"``, ...), a TOML path,
    or a config already loaded (returned as is)."""
    from simulate.config import load_config as _load

    if isinstance(config, SimulationConfig):
        return config
    return _load(config if isinstance(config, (str, Path)) else Path(config))


@_typed_errors
def load_plan(plan: str | os.PathLike | Plan = "red-cotton") -> Plan:
    """An acquisition plan (the geometries and wavelengths): a preset name or a TOML path."""
    from gonio.acquisition.plan import load_plan as _load

    if isinstance(plan, Plan):
        return plan
    return _load(plan if isinstance(plan, (str, Path)) else Path(plan))


def _dataset(data: str | os.PathLike | Dataset) -> Dataset:
    return data if isinstance(data, Dataset) else read_dataset(data)


@_typed_errors
def read_dataset(path: str | os.PathLike) -> Dataset:
    """A radiance-coefficient dataset folder (``radiance.csv`` + ``meta.json``, docs: dataset format)."""
    from gonio.data.dataset import read_dataset as _read

    return _read(path)


@_typed_errors
def write_dataset(dataset: Dataset, path: str | os.PathLike, *, force: bool = False) -> Path:
    """Write ``dataset`` as a folder. An existing non-empty folder is replaced only with
    ``force=True`` (:class:`OutputExistsError` otherwise); the write is atomic per file."""
    from gonio.data.dataset import write_dataset as _write

    out = Path(path)
    if out.exists() and not force and (not out.is_dir() or any(out.iterdir())):
        raise OutputExistsError(f"{out}: exists; pass force=True to replace it")
    return _write(dataset, out)


@_typed_errors
def simulate(config: str | os.PathLike | SimulationConfig, plan: str | os.PathLike | Plan = "red-cotton",
             method: str = "summation", *, target_rel_err: float | None = None, seed: int | None = None,
             threads: int | None = None, max_photons: int | None = None, measurable_only: bool = False,
             progress: bool = False, max_seconds: float = 0.0) -> Dataset:
    """The fabric's radiance coefficient at ``plan``'s geometries and wavelengths by ``method``
    (one of :data:`FABRIC_METHODS`), as a simulated dataset (``u_beta`` is its Monte Carlo error).

    ``target_rel_err``, ``seed``, ``threads`` and ``max_photons`` default to the config's;
    ``threads=0`` uses every core numba may.
    """
    from simulate.virtual import fabric_dataset

    if method not in FABRIC_METHODS:
        raise InputError(f"method {method!r}: choose one of {', '.join(FABRIC_METHODS)}")
    return fabric_dataset(load_config(config), load_plan(plan), method, target_rel_err=target_rel_err, seed=seed,
                          threads=threads, max_photons=max_photons, measurable_only=measurable_only,
                          progress=progress, max_seconds=max_seconds)


@_typed_errors
def compare(measured: str | os.PathLike | Dataset, simulated: Dataset | str | os.PathLike
            | Sequence[Dataset | str | os.PathLike], *, window_deg: float = DEFAULT_WINDOW_DEG,
            illuminant: str = "D65") -> Comparison:
    """Each simulation normalised to the measurement at the normal direction and compared with it:
    curve errors (``.overall``, ``.curves``) and the colour match (``.colour``)."""
    from compare.comparison import compare_datasets

    sims = [simulated] if isinstance(simulated, (Dataset, str, os.PathLike)) else list(simulated)
    return compare_datasets(_dataset(measured), [_dataset(s) for s in sims], window_deg=window_deg,
                            illuminant=illuminant)


@dataclass(frozen=True)
class Verdict:
    """A pass/fail judgement of one simulation against the measurement (``compare check``)."""

    name: str
    measured: str
    #: (label, value, limit, unit) of every figure judged; a NaN value fails
    figures: list[tuple[str, float, float, str]]
    curves: dict[str, float] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)

    @property
    def passed(self) -> bool:
        return all(value <= limit for _, value, limit, _ in self.figures)

    def failures(self) -> list[str]:
        return [label for label, value, limit, _ in self.figures if not value <= limit]

    def summary(self) -> str:
        """The lines ``compare check`` prints."""
        lines = [f"'{self.name}' against '{self.measured}'"]
        lines += [f"  note: {n}" for n in self.notes]
        for label, value, limit, unit in self.figures:
            ok = value <= limit
            lines.append(f"  {'ok  ' if ok else 'FAIL'} {label} = {value:.4g}{unit} ({'<=' if ok else 'exceeds'} "
                         f"{limit:g})")
        lines += [f"       NRMSE at incidence {a} deg = {v:.4g}" for a, v in self.curves.items()]
        return "\n".join(lines)


def check(comparison: Comparison, *, name: str | None = None, max_nrmse: float = DEFAULT_MAX_NRMSE,
          max_hue_diff: float = DEFAULT_MAX_HUE_DIFF, max_sat_diff: float = DEFAULT_MAX_SAT_DIFF,
          max_level_ratio: float = DEFAULT_MAX_LEVEL_RATIO) -> Verdict:
    """Judge one simulation of ``comparison`` (the first unless ``name``) against thresholds:
    overall NRMSE, and where the colour is known, |hue difference| (turns) and |saturation difference|;
    the absolute level (``max(k_Y, 1/k_Y)``) unless the measurement is relative (``compare check``)."""
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
    """A finished fit: the fitted config (``config``, also in ``out/fitted.toml``), the typed result (``result``:
    parameters, uncertainties, warnings, counts), the summary written to ``out/fit.json`` (``summary``), whether it
    passed (``passed``: its colour within the tolerance) and its ``warnings`` (one line each)."""

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
                force: bool = False, absolute: bool = False, colour_hold: bool = True) -> FitJob:
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
    problem = fit_method.problem(cfg, data, parse_free(names, cfg), method=method, colour_weight=colour_weight,
                                 level_weight=1.0 if absolute else 0.0, hold_colour=colour_hold and method != "mc",
                                 target_rel_err=cfg.target_rel_err if target_rel_err is None else target_rel_err,
                                 seed=seed, threads=threads or None, wavelengths_nm=wavelengths, **extra)
    problem.precheck()
    out_dir = Path(out)
    if out_dir.exists() and not out_dir.is_dir():
        raise InputError(f"{out_dir}: exists and is not a folder; choose a folder")
    if out_dir.is_dir() and any(out_dir.iterdir()) and not (resume or force):
        raise OutputExistsError(f"{out_dir}: exists and is not empty; pass resume=True to continue a fit there "
                                "or force=True to replace it")
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
        colour_hold: bool = True) -> FitOutcome:
    """Fit the ``free`` parameters of ``config`` (names as ``simulate fit --free``: ``"dye,rms_slope"``
    or ``["dye", "rms_slope=0.1:0.5"]``) to ``measured`` by ``method`` (one of :data:`FIT_METHODS`, default
    ``"classic"`` as on the command line).

    ``dye="knots"`` replaces the config's dye by knots started from the measured colour.
    ``max_evaluations`` bounds the model evaluations of the summation and classic fits, ``max_runs``
    the Monte Carlo runs of the ``mc`` fit. ``target_rel_err`` (the first Monte Carlo walk's) and
    ``seed`` default to the config's. Everything is written to ``out`` (resumable with
    ``resume=True``); an existing output there is replaced only with ``force=True``. ``absolute=True``:
    the measurement is absolutely calibrated, its level is fitted too (``simulate fit --absolute``).
    ``colour_hold=False``: the classic and summation fits weigh the colour by ``colour_weight`` only, without
    holding it within the tolerance (``simulate fit --no-colour-hold``). A fit whose colour is left off, or that
    never moved from its start, warns with :class:`FitWarning` (``outcome.passed``, ``outcome.warnings``).
    """
    return prepare_fit(config, measured, free, out, method=method, dye=dye, max_evaluations=max_evaluations,
                       max_runs=max_runs, target_rel_err=target_rel_err, seed=seed, threads=threads,
                       colour_weight=colour_weight, wavelengths_nm=wavelengths_nm, mc_trend=mc_trend,
                       starts=starts, resume=resume, force=force, absolute=absolute,
                       colour_hold=colour_hold).run(progress=progress)


@_typed_errors
def export_bsdf(source: str | os.PathLike | SimulationConfig | Dataset, path: str | os.PathLike, *,
                method: str = "summation", wavelengths_nm: Sequence[float] | None = None, rgb: bool = False,
                resolution: int = 64, incidences: int = 16, target_rel_err: float | None = None,
                seed: int | None = None, threads: int | None = None, max_photons: int | None = None,
                check_pairs: int = 0, anisotropic: int = 0, azimuths: int = 5, description: str | None = None,
                provenance: dict | None = None, force: bool = False, progress: bool = False) -> Any:
    """Write an RGL ``.bsdf`` file (Mitsuba 3's ``measured`` plugin, pbrt-v4) of a fabric model
    (``source`` a config or preset, evaluated by ``method``) or of a dataset (``source`` a
    :class:`~gonio.data.dataset.Dataset`: its values interpolated). Returns the export's result
    (its path and tabulation figures; ``.provenance["coverage"]``: a dataset's rule for the
    directions it does not cover).

    ``check_pairs``: measure the tabulation error at that many random direction pairs (more model
    evaluations); ``anisotropic`` 1, 2 or 4: keep the model's anisotropy with ``azimuths``
    incidence azimuths over 360/``anisotropic`` deg. ``description`` and ``provenance`` (merged)
    are written into a dataset's file."""
    out = Path(path)
    if out.exists() and not force:
        raise OutputExistsError(f"{out}: exists; pass force=True to replace it")
    if not 4 <= resolution <= 256:
        raise InputError(f"resolution {resolution}: choose 4..256 values per axis")
    if not 2 <= incidences <= 64:
        raise InputError(f"incidences {incidences}: choose 2..64 incidence nodes")
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
    return export_model(load_config(source), method, out, wavelengths_nm=wavelengths_nm, rgb=rgb, res=resolution,
                        incidences=incidences, target_rel_err=target_rel_err, seed=seed, threads=threads,
                        max_photons=max_photons, check_pairs=check_pairs, reduction=anisotropic, n_phi_i=azimuths,
                        progress=progress)


@_typed_errors
def measure_on_mock(out: str | os.PathLike, *, sample: str = "red-cotton", plan: str | os.PathLike | Plan | None = None,
                    seed: int = 0, force: bool = False, progress: bool = False) -> Dataset:
    """Measure ``plan`` on the embedded mock goniophotometer holding ``sample`` (``red-cotton``, the
    analytic stand-in; ``lambert:RHO``; a dataset folder; or an RGL ``.bsdf`` file such as
    ``fixtures/real/acrylic_felt_green_rgb.bsdf``) through the real driver and protocols, as
    ``gonio demo`` does; returns the measured dataset written in ``out``. Without ``plan`` the
    red-cotton plan's geometry is used, named after the sample."""
    from gonio.data.outputs import OutputRefused
    from gonio.demo import run_demo
    from gonio.mock.samples import SampleError

    plan_obj = load_plan("red-cotton" if plan is None else plan)
    try:
        run_demo(Path(out), plan_obj, seed=seed, force=force, progress=progress, sample=sample,
                 name_from_sample=plan is None and sample != "red-cotton")
    except SampleError as exc:
        raise InputError(f"sample {sample!r}: {exc}") from exc
    except OutputRefused as exc:
        raise OutputExistsError(str(exc)) from exc
    return read_dataset(out)


@_typed_errors
def truth(sample: str, plan: str | os.PathLike | Plan = "red-cotton") -> Dataset:
    """The mock sample's true radiance coefficient at ``plan``'s geometries (no instrument noise):
    what a perfect measurement of ``sample`` gives (``gonio truth``)."""
    from gonio.mock.samples import SampleError
    from gonio.mock.truth import truth_dataset

    try:
        return truth_dataset(sample, load_plan(plan))
    except SampleError as exc:
        raise InputError(f"sample {sample!r}: {exc}") from exc
