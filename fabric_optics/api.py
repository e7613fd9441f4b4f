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

import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from compare.comparison import Comparison
from compare.metrics import DEFAULT_MAX_HUE_DIFF, DEFAULT_MAX_LEVEL_RATIO, DEFAULT_MAX_NRMSE, DEFAULT_MAX_SAT_DIFF
from compare.normalise import DEFAULT_WINDOW_DEG
from gonio.acquisition.plan import Plan
from gonio.data.dataset import Dataset
from simulate.config import SimulationConfig

from fabric_optics import validate as _v
from fabric_optics.errors import (FileSystemError, InputError, InternalError, OutputBusyError,
                                  OutputExistsError, ToolkitError, typed_errors)

if TYPE_CHECKING:
    from fabric_optics.fitting.driver import FitResult

__all__ = [
    "ToolkitError", "InputError", "OutputExistsError", "OutputBusyError", "FileSystemError", "InternalError",
    "load_config", "load_plan", "read_dataset", "write_dataset",
    "measure_on_mock", "truth", "simulate", "compare", "check", "Verdict", "fit", "prepare_fit", "FitJob",
    "FitOutcome", "export_bsdf",
    "FABRIC_METHODS", "FIT_METHODS",
]

#: The fabric models (``method=``): summation over the fabric's fibers, the classic Lambert +
#: Cook-Torrance model, Monte Carlo ray tracing of the fabric's model, or per geometry the
#: cheapest whose error is within the target.
FABRIC_METHODS = ("summation", "classic", "mc", "auto")
#: The models a fit can adjust (``auto`` is not one: its choice changes between evaluations).
FIT_METHODS = ("summation", "classic", "mc")


#: Every function below raises only :class:`ToolkitError` subclasses (:mod:`fabric_optics.errors`)
_typed_errors = typed_errors


@_typed_errors
def load_config(config: str | os.PathLike | SimulationConfig) -> SimulationConfig:
    """A simulation config: a preset name (``"red-cotton"``, ``"green-felt"``, ...), a TOML path,
    or a config already loaded (returned as is)."""
    from simulate.config import load_config as _load

    if isinstance(config, SimulationConfig):
        return config
    _v.path("config", config)
    return _load(config if isinstance(config, (str, Path)) else Path(config))


@_typed_errors
def load_plan(plan: str | os.PathLike | Plan = "red-cotton") -> Plan:
    """An acquisition plan (the geometries and wavelengths): a preset name or a TOML path."""
    from gonio.acquisition.plan import load_plan as _load

    if isinstance(plan, Plan):
        return plan
    _v.path("plan", plan)
    return _load(plan if isinstance(plan, (str, Path)) else Path(plan))


def _dataset(data: str | os.PathLike | Dataset) -> Dataset:
    return data if isinstance(data, Dataset) else read_dataset(data)


@_typed_errors
def read_dataset(path: str | os.PathLike) -> Dataset:
    """A radiance-coefficient dataset folder (``radiance.csv`` + ``meta.json``, docs: dataset format)."""
    from gonio.data.dataset import read_dataset as _read

    _v.path("path", path)
    return _read(path)


@_typed_errors
def write_dataset(dataset: Dataset, path: str | os.PathLike, *, force: bool = False) -> Path:
    """Write ``dataset`` as a folder. An existing non-empty folder is replaced only with
    ``force=True`` (:class:`OutputExistsError` otherwise); the write is atomic per file."""
    from gonio.data.dataset import write_dataset as _write
    from gonio.data.outputs import JOURNAL_NAME, is_run_folder

    if not isinstance(dataset, Dataset):
        raise InputError(f"dataset: expected a Dataset, got {type(dataset).__name__}")
    out = _v.out_path("path", path)
    _v.flag("force", force)
    with _v.claimed("path", out):
        if is_run_folder(out):
            raise OutputExistsError(f"{out}: is a run folder (it holds {JOURNAL_NAME}; its dataset is rebuilt from "
                                    "that journal): choose another path (a run folder is never replaced, not even "
                                    "with force=True)")
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
    """Each simulation normalised to the measurement at the normal direction and compared with it:
    curve errors (``.overall``, ``.curves``) and the colour match (``.colour``)."""
    from compare.comparison import compare_datasets

    _v.number("window_deg", window_deg, 0.0, 90.0, lo_open=True)
    _v.text("illuminant", illuminant, max_len=64)
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


@_typed_errors
def check(comparison: Comparison, *, name: str | None = None, max_nrmse: float = DEFAULT_MAX_NRMSE,
          max_hue_diff: float = DEFAULT_MAX_HUE_DIFF, max_sat_diff: float = DEFAULT_MAX_SAT_DIFF,
          max_level_ratio: float = DEFAULT_MAX_LEVEL_RATIO) -> Verdict:
    """Judge one simulation of ``comparison`` (the first unless ``name``) against thresholds:
    overall NRMSE, and where the colour is known, |hue difference| (turns) and |saturation difference|;
    the absolute level (``max(k_Y, 1/k_Y)``) unless the measurement is relative (``compare check``)."""
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
    """A finished fit: the fitted config (``config``, also in ``out/fitted.toml``), the summary
    written to ``out/fit.json`` (``summary``: parameters with uncertainties, the figures before
    and after) and the optimiser's result (``result``)."""

    out: Path
    summary: dict
    result: FitResult
    config: SimulationConfig


@dataclass
class FitJob:
    """A fit checked and ready to run (:func:`prepare_fit`): ``problem`` (its ``wavelengths_nm``,
    ``config``, ...), the output folder ``out`` and the ``budget`` (model evaluations, or Monte
    Carlo runs of the ``mc`` fit). :meth:`run` searches, writes ``out`` and returns the outcome."""

    problem: Any
    out: Path
    method: str
    budget: int
    starts: int
    resume: bool
    _run: Callable[..., Any]
    _write: Callable[..., dict]
    #: "ready", "search", "writing" (the outputs being put in place) or "done"
    phase: str = "ready"

    @_typed_errors
    def run(self, *, progress: bool = False) -> FitOutcome:
        from simulate.config import load_config as _load

        self.out.mkdir(parents=True, exist_ok=True)
        self.phase = "search"
        result = self._run(self.problem, out=self.out, resume=self.resume, max_evaluations=self.budget,
                           starts=self.starts, progress=progress)
        self.phase = "writing"      # the outputs are put in place together: an interrupt changes none of them
        summary = self._write(self.problem, result, self.out)
        self.phase = "done"
        return FitOutcome(out=self.out, summary=summary, result=result, config=_load(self.out / "fitted.toml"))


@_typed_errors
def prepare_fit(config: str | os.PathLike | SimulationConfig, measured: str | os.PathLike | Dataset,
                free: str | Sequence[str], out: str | os.PathLike, *, method: str = "summation",
                dye: str = "config", max_evaluations: int | None = None, max_runs: int | None = None,
                target_rel_err: float | None = None, seed: int | None = None, threads: int | None = None,
                colour_weight: float = 1.0, wavelengths_nm: Sequence[float] | None = None,
                mc_trend: Sequence[str] = (), starts: int = 1, resume: bool = False,
                force: bool = False, absolute: bool = False, colour_hold: bool = True) -> FitJob:
    """Everything :func:`fit` checks before its search (arguments as :func:`fit`): the config, the
    measurement, the free parameters and their bounds, the output folder. Nothing is written."""
    import numpy as np

    from fabric_optics.fitting.driver import DEFAULT_MAX_EVALUATIONS, parse_free
    from fabric_optics.fitting.mc import DEFAULT_MC_RUNS
    from fabric_optics.fitting.methods import method_runner
    from fabric_optics.fitting.start import knots_config

    if method not in FIT_METHODS:
        raise InputError(f"method {method!r}: choose one of {', '.join(FIT_METHODS)}")
    if mc_trend and method != "mc":
        raise InputError(f"mc_trend is for method 'mc' (the {method} fit has no Monte Carlo runs)")
    if max_runs is not None and method != "mc":
        raise InputError(f"max_runs counts the Monte Carlo runs of method 'mc'; the {method} fit counts "
                         "max_evaluations")
    if max_evaluations is not None and method == "mc":
        raise InputError("max_evaluations counts the model evaluations of the summation and classic fits; "
                         "the mc fit counts max_runs")
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
    problem_class, run_fit, write_outputs = method_runner(method)
    extra: dict[str, Any] = {"mc_trend": tuple(mc_trend)} if mc_trend else {}
    problem = problem_class(cfg, data, parse_free(names, cfg), method=method, colour_weight=colour_weight,
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
    budget = max_runs if method == "mc" else max_evaluations
    if budget is None:
        budget = DEFAULT_MC_RUNS if method == "mc" else DEFAULT_MAX_EVALUATIONS
    return FitJob(problem=problem, out=out_dir, method=method, budget=budget, starts=starts, resume=resume,
                  _run=run_fit, _write=write_outputs)


@_typed_errors
def fit(config: str | os.PathLike | SimulationConfig, measured: str | os.PathLike | Dataset,
        free: str | Sequence[str], out: str | os.PathLike, *, method: str = "summation", dye: str = "config",
        max_evaluations: int | None = None, max_runs: int | None = None, target_rel_err: float | None = None,
        seed: int | None = None, threads: int | None = None, colour_weight: float = 1.0,
        wavelengths_nm: Sequence[float] | None = None, mc_trend: Sequence[str] = (), starts: int = 1,
        resume: bool = False, force: bool = False, progress: bool = False, absolute: bool = False,
        colour_hold: bool = True) -> FitOutcome:
    """Fit the ``free`` parameters of ``config`` (names as ``simulate fit --free``: ``"dye,rms_slope"``
    or ``["dye", "rms_slope=0.1:0.5"]``) to ``measured`` by ``method`` (one of :data:`FIT_METHODS`).

    ``dye="knots"`` replaces the config's dye by knots started from the measured colour.
    ``max_evaluations`` bounds the model evaluations of the summation and classic fits, ``max_runs``
    the Monte Carlo runs of the ``mc`` fit. ``target_rel_err`` (the first Monte Carlo walk's) and
    ``seed`` default to the config's. Everything is written to ``out`` (resumable with
    ``resume=True``); an existing output there is replaced only with ``force=True``. ``absolute=True``:
    the measurement is absolutely calibrated, its level is fitted too (``simulate fit --absolute``).
    ``colour_hold=False``: the classic and summation fits weigh the colour by ``colour_weight`` only, without
    holding it within the tolerance (``simulate fit --no-colour-hold``).
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
                       ("colour_hold", colour_hold)):
        _v.flag(arg, value)
    data = _dataset(measured)
    _v.measurement_rows(f"measured ({data.path or data.name})", len(data))
    with _v.claimed("out", _v.out_path("out", out)):     # one writer of the fit's folder
        return prepare_fit(config, data, free, out, method=method, dye=dye, max_evaluations=max_evaluations,
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
    if out.exists() and not force:
        raise OutputExistsError(f"{out}: exists; pass force=True to replace it")
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
    """Measure ``plan`` on the embedded mock goniophotometer holding ``sample`` (``red-cotton``, the
    analytic stand-in; ``lambert:RHO``; a dataset folder; or an RGL ``.bsdf`` file such as
    ``fixtures/real/acrylic_felt_green_rgb.bsdf``) through the real driver and protocols, as
    ``gonio demo`` does; returns the measured dataset written in ``out``. Without ``plan`` the
    red-cotton plan's geometry is used, named after the sample."""
    from gonio.data.outputs import OutputRefused
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
    """The mock sample's true radiance coefficient at ``plan``'s geometries (no instrument noise):
    what a perfect measurement of ``sample`` gives (``gonio truth``)."""
    from gonio.mock.samples import SampleError
    from gonio.mock.truth import truth_dataset

    _v.text("sample", sample, max_len=4096)
    try:
        return truth_dataset(sample, load_plan(plan))
    except SampleError as exc:
        raise InputError(f"sample {sample!r}: {exc}") from exc
