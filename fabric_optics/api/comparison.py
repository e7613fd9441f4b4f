"""Comparing simulations with a measurement, judging the comparison, and writing the report.

These are the functions behind ``compare check`` (:func:`compare`, then :func:`check` and its
:class:`Verdict`) and ``compare report`` (:func:`write_report`).
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

from compare.comparison import Comparison
from compare.metrics import DEFAULT_MAX_HUE_DIFF, DEFAULT_MAX_LEVEL_RATIO, DEFAULT_MAX_NRMSE, DEFAULT_MAX_SAT_DIFF
from compare.normalise import DEFAULT_WINDOW_DEG
from fabric_optics import validate as _v
from fabric_optics.api.loading import as_dataset, refuse_existing
from fabric_optics.errors import InputError, typed_errors
from gonio.data.dataset import Dataset

__all__ = ["Comparison", "Verdict", "check", "compare", "write_report"]


@typed_errors
def compare(measured: str | os.PathLike | Dataset, simulated: Dataset | str | os.PathLike
            | Sequence[Dataset | str | os.PathLike], *, window_deg: float = DEFAULT_WINDOW_DEG,
            illuminant: str = "D65") -> Comparison:
    """Compare simulations with a measurement: curve errors and the colour match.

    Each simulation is normalised to the measurement at the normal direction, so that the shapes of
    the curves are compared apart from the absolute level (which is compared on its own where the
    measurement is absolute). This is what `compare report` and `compare check` compute.

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
        A dataset that cannot be read, datasets that share no geometry or wavelength, an empty list
        of simulations, or a `window_deg` or `illuminant` out of range.

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
    return compare_datasets(as_dataset(measured), [as_dataset(s) for s in sims], window_deg=window_deg,
                            illuminant=illuminant)


@dataclass(frozen=True)
class Verdict:
    """The pass/fail judgement of one simulation against the measurement (`compare check`), made by `check`.

    A verdict keeps each judged figure beside its limit, so that a caller (or `compare check`'s
    output) sees by how much a figure passed or failed, not only whether.

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
        """Whether every figure is within its limit (`compare check` exits 0); a NaN fails.

        Returns
        -------
        bool
            True when no figure exceeds its limit.
        """
        return all(value <= limit for _, value, limit, _ in self.figures)

    def failures(self) -> list[str]:
        """The labels of the figures beyond their limits (empty when `passed`).

        Returns
        -------
        list of str
            The failed figures' labels, e.g. `["overall NRMSE"]`.
        """
        return [label for label, value, limit, _ in self.figures if not value <= limit]

    def summary(self) -> str:
        """The lines `compare check` prints: each figure with `ok` or `FAIL` and its limit.

        Returns
        -------
        str
            One line naming the simulation and the measurement, then the notes, then one line per
            judged figure, then the NRMSE per incidence.
        """
        lines = [f"'{self.name}' against '{self.measured}'"]
        lines += [f"  note: {n}" for n in self.notes]
        for label, value, limit, unit in self.figures:
            ok = value <= limit
            lines.append(f"  {'ok  ' if ok else 'FAIL'} {label} = {value:.4g}{unit} ({'<=' if ok else 'exceeds'} "
                         f"{limit:g})")
        lines += [f"       NRMSE at incidence {a} deg = {v:.4g}" for a, v in self.curves.items()]
        return "\n".join(lines)


@typed_errors
def check(comparison: Comparison, *, name: str | None = None, max_nrmse: float = DEFAULT_MAX_NRMSE,
          max_hue_diff: float = DEFAULT_MAX_HUE_DIFF, max_sat_diff: float = DEFAULT_MAX_SAT_DIFF,
          max_level_ratio: float = DEFAULT_MAX_LEVEL_RATIO) -> Verdict:
    """Judge one simulation of a comparison against thresholds (`compare check`).

    The defaults are the thresholds `compare check` uses; the colour is judged only where the
    measurement has a colour and the level only where it is absolute.

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
        `comparison` is not a Comparison, has no simulation called `name`, or a threshold is negative.

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


@typed_errors
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
    OutputBusyError
        Another writer is writing `out` now.
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
    """Write the report once `write_report` has checked its arguments and claimed its folder.

    A report of the measurement alone, of a sweep folder, or of models compared with the
    measurement (with the sections of fits, the seed sample and renders).
    """
    from compare.comparison import compare_datasets
    from compare.report import Section
    from compare.report import write_report as _write_report
    from compare.sweep import is_sweep_dir, write_sweep_report

    if renders is not None and not Path(renders).is_dir():
        raise InputError(f"renders {renders}: not a folder (make one with `compare render FILE.bsdf ... --out DIR`)")
    if renders is not None and not models:
        raise InputError("renders: the renders are set beside a simulation; give a model too")
    refuse_existing(out_dir, force)
    meas = as_dataset(measured)
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
    comparison = compare_datasets(meas, [as_dataset(m) for m in models], window_deg=window_deg, illuminant=illuminant)
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
        sections.append(seed_sample_section(as_dataset(seed_sample)))
    return sections
