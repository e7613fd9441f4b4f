"""Studies ``simulate bench --study NAME`` runs: documented measurements a user repeats on their machine.

Each study writes ``OUT/NAME.json`` and prints its figures; ``quick`` runs it on a small budget.

* ``felt`` (:mod:`fabric_optics.bench.felt`): the felt Monte Carlo against the felt's structured
  summation, per fiber absorption.
* ``method-errors-felt`` (:mod:`fabric_optics.bench.method_errors`): where the summation and the
  classic model depart from the felt Monte Carlo on the green felt; ``OUT/method-errors-felt.json`` is
  the table ``simulate fabric --method auto`` reads for a felt (shipped as
  ``simulate/configs/method-errors-felt.json``). ``quick``: the Monte Carlo at 10 %.
* ``method-errors-felt-blend``: the same on the green felt as a blend of two populations of different dyes;
  ``OUT/method-errors-felt-blend.json`` is the table ``--method auto`` reads for a felt blend within its dye
  spread (shipped as ``simulate/configs/method-errors-felt-blend.json``). ``quick``: the Monte Carlo at 10 %.
* ``method-errors-woven-blend``: where the summation and the classic model depart from the woven Monte Carlo on
  red cotton as a blend of two populations of one dye at two strengths; ``OUT/method-errors-woven-blend.json``
  is the study that bounds the woven blends ``--method auto`` reads the woven table for (shipped as
  ``simulate/configs/method-errors-woven-blend.json``). ``quick``: the Monte Carlo at 10 %.
* ``speed-accuracy`` (:mod:`fabric_optics.bench.speed_accuracy`): the Monte Carlo's achieved error
  against its marginal cost, red cotton and the felt, with the fixed costs apart and the cheaper
  models' floors; also writes ``OUT/speed-accuracy.png``. ``quick``: every other target.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

__all__ = ["STUDIES", "run_study"]


def _felt(quick: bool) -> tuple[dict[str, Any], list[str]]:
    from fabric_optics.bench.felt import felt_study_lines, run_felt_study

    report = run_felt_study(quick=quick)
    return report, felt_study_lines(report)


def _method_errors_felt(quick: bool) -> tuple[dict[str, Any], list[str]]:
    from fabric_optics.bench.method_errors import run

    _, errors, lines = run("green-felt", target=0.1 if quick else None)
    return errors, lines


def _method_errors_felt_blend(quick: bool) -> tuple[dict[str, Any], list[str]]:
    from fabric_optics.bench.method_errors import run

    _, errors, lines = run("green-felt-blend", target=0.1 if quick else None)
    return errors, lines


def _method_errors_woven_blend(quick: bool) -> tuple[dict[str, Any], list[str]]:
    from fabric_optics.bench.method_errors import run

    _, errors, lines = run("red-cotton-blend", target=0.1 if quick else None)
    return errors, lines


def _speed_accuracy(quick: bool) -> tuple[dict[str, Any], list[str]]:
    from fabric_optics.bench.speed_accuracy import run_speed_accuracy, study_lines

    report = run_speed_accuracy(quick=quick)
    return report, study_lines(report)


def _speed_accuracy_chart(report: dict[str, Any], out: Path) -> None:
    from fabric_optics.bench.speed_accuracy import chart

    chart(report, out / "speed-accuracy.png")


#: name -> ``(one-line description, run(quick) -> (report, lines))``
STUDIES: dict[str, tuple[str, Callable[[bool], tuple[dict[str, Any], list[str]]]]] = {
    "felt": ("the felt Monte Carlo against the felt summation, per fiber absorption", _felt),
    "method-errors-felt": ("where the summation and classic depart from the felt Monte Carlo "
                           "(the --method auto table of a felt)", _method_errors_felt),
    "method-errors-felt-blend": ("the same for a felt blended from two differently dyed populations "
                                 "(the --method auto table of a felt blend)", _method_errors_felt_blend),
    "method-errors-woven-blend": ("where the summation and classic depart from the woven Monte Carlo of red "
                                  "cotton blended from two populations of one dye at two strengths (the --method "
                                  "auto study of a woven blend)", _method_errors_woven_blend),
    "speed-accuracy": ("the Monte Carlo's achieved error against its marginal cost, fixed costs apart, "
                       "red cotton and the felt", _speed_accuracy),
}
#: the studies that also draw a chart: name -> draw(report, out)
CHARTS: dict[str, Callable[[dict[str, Any], Path], None]] = {"speed-accuracy": _speed_accuracy_chart}


def run_study(name: str, out: Path, quick: bool = False) -> list[str]:
    """Run study ``name``, write ``out/NAME.json`` and return its lines of text."""
    _, run = STUDIES[name]
    report, lines = run(quick)
    (Path(out) / f"{name}.json").write_text(json.dumps(report, indent=2))
    if name in CHARTS:
        CHARTS[name](report, Path(out))
    return lines
