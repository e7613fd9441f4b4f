"""Studies ``simulate bench --study NAME`` runs: documented measurements a user repeats on their machine.

Each study writes ``OUT/NAME.json`` and prints its figures; ``quick`` runs it on a small budget.

* ``felt`` (:mod:`fabric_optics.bench.felt`): the felt Monte Carlo against the felt's structured
  summation, per fiber absorption.
* ``method-errors-felt`` (:mod:`fabric_optics.bench.method_errors`): where the summation and the
  classic model depart from the felt Monte Carlo on the green felt; ``OUT/method-errors-felt.json`` is
  the table ``simulate fabric --method auto`` reads for a felt (shipped as
  ``simulate/configs/method-errors-felt.json``). ``quick``: the Monte Carlo at 10 %.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Callable

__all__ = ["STUDIES", "run_study"]


def _felt(quick: bool) -> tuple[dict[str, Any], list[str]]:
    from fabric_optics.bench.felt import felt_study_lines, run_felt_study

    report = run_felt_study(quick=quick)
    return report, felt_study_lines(report)


def _method_errors_felt(quick: bool) -> tuple[dict[str, Any], list[str]]:
    from fabric_optics.bench.method_errors import run

    _, errors, lines = run("green-felt", target=0.1 if quick else None)
    return errors, lines


#: name -> ``(one-line description, run(quick) -> (report, lines))``
STUDIES: dict[str, tuple[str, Callable[[bool], tuple[dict[str, Any], list[str]]]]] = {
    "felt": ("the felt Monte Carlo against the felt summation, per fiber absorption", _felt),
    "method-errors-felt": ("where the summation and classic depart from the felt Monte Carlo "
                           "(the --method auto table of a felt)", _method_errors_felt),
}


def run_study(name: str, out: Path, quick: bool = False) -> list[str]:
    """Run study ``name``, write ``out/NAME.json`` and return its lines of text."""
    _, run = STUDIES[name]
    report, lines = run(quick)
    (Path(out) / f"{name}.json").write_text(json.dumps(report, indent=2))
    return lines
