"""Studies ``simulate bench --study NAME`` runs: documented measurements a user repeats on their machine.

Each study writes ``OUT/NAME.json`` and prints its figures; ``quick`` runs it on a small budget.

* ``felt`` (:mod:`fabric_optics.bench.felt`): the felt Monte Carlo against the felt's structured
  summation, per fiber absorption.
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


#: name -> ``(one-line description, run(quick) -> (report, lines))``
STUDIES: dict[str, tuple[str, Callable[[bool], tuple[dict[str, Any], list[str]]]]] = {
    "felt": ("the felt Monte Carlo against the felt summation, per fiber absorption", _felt),
}


def run_study(name: str, out: Path, quick: bool = False) -> list[str]:
    """Run study ``name``, write ``out/NAME.json`` and return its lines of text."""
    _, run = STUDIES[name]
    report, lines = run(quick)
    (Path(out) / f"{name}.json").write_text(json.dumps(report, indent=2))
    return lines
