"""What a fit writes: its typed result (:class:`FitResult`) and the one serialiser of it, :func:`write_outputs`.

Every method's runner returns a :class:`FitResult` of the same shape; :func:`write_outputs` writes, in ``DIR``,
``fitted.toml`` (the fitted config, ready for ``simulate fabric``), ``initial/`` and ``fitted/`` (datasets of the
model at the start and at the fitted parameters, at the measured geometries), ``report/`` (``compare report`` of
the measurement, initial and fitted) and ``fit.json`` (parameters, uncertainties, correlations, objective,
verdict, warnings, counts, times; read by ``compare report --fit``).

The outputs are written together: first all of them into a hidden folder ``DIR/.outputs-XXXXXXXX.tmp/``, then
moved into place, ``fit.json`` first, with Ctrl-C held back during the moves (milliseconds). An interrupt or a full
disk while they are written leaves the previous outputs as they were; ``fitted.toml`` is never there without its
``fit.json``.

Public objects: :class:`FitResult`, :func:`write_outputs`, :data:`OUTPUT_NAMES`, :data:`EXIT_COLOUR_OFF`.
"""

from __future__ import annotations

import contextlib
import json
import logging
import math
import os
import shutil
import signal
import tempfile
import threading
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from compare import report as compare_report
from compare.comparison import compare_datasets
from compare.errors import CompareError
from fabric_optics.fitting.spec import COLOUR_HOLD_FROM, COLOUR_HOLD_WEIGHT, COLOUR_TOLERANCE, GENERATOR
from fabric_optics.fitting.verdict import COLOUR_LEFT_OFF, colour_left_off, uncertainty_text
from gonio.data.dataset import atomic_write, write_dataset
from simulate.montecarlo.accuracy import REL_ERR_DEFINITION, relative_error
from simulate.provenance import jsonable, software_versions

__all__ = ["FitResult", "write_outputs", "OUTPUT_NAMES", "EXIT_COLOUR_OFF"]

log = logging.getLogger(__name__)

#: exit status of ``simulate fit`` whose fitted colour is left off: its outputs are written, fit.json's
#: ``verdict`` says ``passed: false`` (2 stays bad input, 130 an interrupt)
EXIT_COLOUR_OFF = 3


@dataclass(frozen=True)
class FitResult:
    """A finished fit, the same shape for every method (:mod:`fabric_optics.fitting.methods`).

    ``x`` the fitted values of the free parameters ``names`` (the best point the method evaluated), ``start`` the
    config's, ``objective``/``objective_start`` the objective there; ``u`` the standard uncertainties (``u_data``
    from the measurement's noise, ``u_mc`` from the model's Monte Carlo error; NaN where a parameter has none),
    ``correlation`` their correlation matrix; ``warnings`` one line each (a search stopped by its budget, a
    parameter at a bound or not identifiable, the colour left off); ``stop`` why the search ended; ``info`` the
    method's record for fit.json (counts, times, its iterations); ``model_start``/``model_fit`` the model's
    ``(beta, u_beta)`` ``[G, L]`` at the start and at ``x`` (the Monte Carlo fit's: its runs there).
    """

    method: str
    names: tuple[str, ...]
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
    stop: str = ""
    model_start: tuple[np.ndarray, np.ndarray] | None = field(default=None, repr=False)
    model_fit: tuple[np.ndarray, np.ndarray] | None = field(default=None, repr=False)

    @property
    def passed(self) -> bool:
        """Whether the fitted colour is within the tolerance of the measured (no colour-left-off warning)."""
        return not any(w.startswith(COLOUR_LEFT_OFF) for w in self.warnings)

    @property
    def moved(self) -> bool:
        """Whether the result differs from the start at all (a search that never moved is worth a warning)."""
        return not np.array_equal(np.asarray(self.x, float), np.asarray(self.start, float))


def _summary(comparison) -> dict:
    name = next(iter(comparison.frames))
    level = comparison.level(name)
    out = {"nrmse": float(comparison.overall[name].nrmse), "level_k": level.k, "level_ratio": level.ratio,
           "k_spread": level.spread}
    if comparison.colour is not None:
        c = comparison.colour.simulated[name]
        out.update(dh=float(c.dh), ds=float(c.ds), h=float(c.colour.h), s=float(c.colour.s))
    return out


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


def write_outputs(problem: Any, result: FitResult, out: Path) -> dict:
    """fitted.toml, initial/ and fitted/ datasets, report/ and fit.json in ``out``; returns fit.json.

    All are written into a hidden folder of ``out`` first and then moved into place together (module
    docstring): an exception or an interrupt while writing leaves ``out``'s previous outputs unchanged. The
    datasets are the result's model values (:attr:`FitResult.model_start`, :attr:`FitResult.model_fit`), or the
    problem's model at its start and result when the result has none.

    Parameters
    ----------
    problem : FitProblem
        The fit.
    result : FitResult
        Its result.
    out : Path
        The ``--out`` folder (it exists).

    Returns
    -------
    dict
        The content of fit.json.

    Raises
    ------
    OSError
        When the outputs cannot be written, naming ``out``; its previous outputs are unchanged.
    """
    prov = {"command": GENERATOR, "config": problem.config.provenance(), "seed": problem.seed,
            "versions": software_versions()}
    method = result.method
    b0, u0 = result.model_start if result.model_start is not None else problem.model(result.start)
    b1, u1 = result.model_fit if result.model_fit is not None else problem.model(result.x)
    rel_err = {"start": relative_error(b0, u0), "fitted": relative_error(b1, u1), "definition": REL_ERR_DEFINITION}
    initial = problem.dataset(b0, u0, "initial", {**prov, "rel_err": rel_err["start"],
                                                  "rel_err_definition": REL_ERR_DEFINITION}, method=method)
    fitted = problem.dataset(b1, u1, "fitted", {**prov, "rel_err": rel_err["fitted"],
                                                "rel_err_definition": REL_ERR_DEFINITION,
                                                "fitted": {p.name: float(v) for p, v in zip(problem.free, result.x, strict=True)}},
                             method=method)
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
        lines = [f"{problem.config.name} fitted by `simulate fit` ({method} model) to {problem.measured.source}"]
        fig1 = problem.residual_model().evaluate(b1, u1)
        off = colour_left_off(problem, float(getattr(fig1, "dh", math.nan)), float(getattr(fig1, "ds", math.nan)),
                              method=method)
        if off:
            lines.append(f"FAILED: {off}")
        status = result.info.get("u_status") or [""] * len(problem.free)
        lines.append("free parameters (value +- standard uncertainty):")
        lines += [f"  {p.name} = {v:.6g} {uncertainty_text(uu, st)}"
                  for p, v, uu, st in zip(problem.free, result.x, result.u, status, strict=True)]
        rule = result.info.get("uncertainty") or {}
        if rule.get("data") == "residual":
            lines.append(f"  (no measurement uncertainty: u scaled by the residual, s^2 = SSR/(n - p) = "
                         f"{rule['s2']:.3g})" if rule.get("s2") is not None else "  (no measurement uncertainty and "
                         "no degree of freedom: no u)")
        atomic_write(stage / "fitted.toml", problem.fitted_toml(result.x, "\n".join(lines)).encode("utf-8"))
        comparison = compare_datasets(problem.measured, [initial, fitted])
        try:
            compare_report.write_report(comparison, stage / "report", force=True)
        except CompareError as exc:   # the report's own one-line failure (a full disk): its cause
            if isinstance(exc.__cause__, OSError):
                raise exc.__cause__ from None
            raise
        c0 = _summary(problem.compare(initial))
        c1 = _summary(problem.compare(fitted))
        left_off = colour_left_off(problem, c1.get("dh", math.nan), c1.get("ds", math.nan), method=method)
        dh_max, ds_max = COLOUR_TOLERANCE
        verdict = {"passed": not left_off,
                   "colour": "left off" if left_off else ("ok" if "dh" in c1 else "no colour"),
                   "tolerance": {"dh_turn": dh_max, "ds": ds_max}, "exit_status": EXIT_COLOUR_OFF if left_off else 0}
        if left_off:
            verdict["why"] = left_off
        doc = {
            "generator": GENERATOR, "method": method, "config": problem.config.name,
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
                                                           result.u_mc, status, strict=True)],
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
