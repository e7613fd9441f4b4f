"""The fit's methods as one registry: name, problem, runner, budget (its name and default).

The API (:func:`fabric_optics.api.fit`), the command line's ``--method`` choices and its budget flags read
:data:`METHODS`; a method's name is one of the fabric models of :data:`simulate.products.MODELS` (``auto`` is not
one: its choice changes between evaluations). :data:`DEFAULT_METHOD` is the default everywhere.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from fabric_optics.fitting.outputs import FitResult
from fabric_optics.fitting.problem import FitProblem
from fabric_optics.fitting.search import DEFAULT_MAX_EVALUATIONS, run_fit
from fabric_optics.fitting.spacemapping import DEFAULT_MC_RUNS, MCFitProblem, run_mc_fit
from simulate.products import MODELS

__all__ = ["FitMethod", "METHODS", "DEFAULT_METHOD", "method_of"]


@dataclass(frozen=True)
class FitMethod:
    """One fit method of the registry: its problem, its runner and its budget.

    ``problem`` builds its problem (the arguments of :class:`~fabric_optics.fitting.problem.FitProblem`),
    ``run(problem, out=, resume=, starts=, progress=, **{budget: n})`` fits it; ``budget`` names the runner's
    keyword and, dashed, the command line's flag.
    """

    name: str
    problem: Callable[..., Any]
    run: Callable[..., FitResult]
    budget: str
    default_budget: int
    #: what the budget counts (messages)
    counts: str
    summary: str

    @property
    def flag(self) -> str:
        """The command line's budget flag (``--max-evaluations``, ``--max-runs``)."""
        return "--" + self.budget.replace("_", "-")


METHODS: dict[str, FitMethod] = {
    "classic": FitMethod("classic", FitProblem, run_fit, "max_evaluations", DEFAULT_MAX_EVALUATIONS,
                         "model evaluations", "the classic model (a carpet of fibers and one surface term)"),
    "summation": FitMethod("summation", FitProblem, run_fit, "max_evaluations", DEFAULT_MAX_EVALUATIONS,
                           "model evaluations", "the summation over the fabric's fibers (structured with [structure])"),
    "mc": FitMethod("mc", MCFitProblem, run_mc_fit, "max_runs", DEFAULT_MC_RUNS, "Monte Carlo runs",
                    "the woven/felt Monte Carlo, by output space mapping through the summation"),
}
assert set(METHODS) <= set(MODELS), "a fit method must be one of the fabric models"

#: The default method of ``simulate fit`` and :func:`fabric_optics.api.fit`: the classic model, the cheapest (one
#: walk, then table reads); the summation and the Monte Carlo are asked for by name.
DEFAULT_METHOD = "classic"


def method_of(name: str) -> FitMethod:
    """The registry's method ``name`` (:class:`KeyError` for another name: the caller says what to do).

    Parameters
    ----------
    name : str
        The method's name (``--method``).

    Returns
    -------
    FitMethod
        The method.

    Raises
    ------
    KeyError
        For a name the registry does not hold.
    """
    return METHODS[name]
