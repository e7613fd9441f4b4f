"""The fit of each ``--method``: the classic and summation models' (:mod:`.driver`) and the Monte Carlo's (:mod:`.mc`)."""

from __future__ import annotations

from collections.abc import Callable

from fabric_optics.fitting.driver import run_fit, write_outputs
from fabric_optics.fitting.mc import MCFitProblem, run_mc_fit, write_mc_outputs
from fabric_optics.fitting.problem import FitProblem

__all__ = ["method_runner"]


def method_runner(method: str) -> tuple[type, Callable, Callable]:
    """``(problem class, run, write outputs)`` of a fit ``--method`` (``classic``, ``summation`` or ``mc``)."""
    if method == "mc":
        return MCFitProblem, run_mc_fit, write_mc_outputs
    return FitProblem, run_fit, write_outputs
