"""The fit's verdict: is the fitted colour within the tolerance of the measured one, and what helps if not.

A fit whose colour is further from the measured than :data:`~fabric_optics.fitting.spec.COLOUR_TOLERANCE` fails:
its outputs are written and labelled failing (fit.json ``verdict``; ``simulate fit`` exits 3). The line says what
helps for the fit's free parameters and model (why each: docs/notes/fit-trust.md, "The fits on the measured plan").

Public objects: :func:`colour_left_off`, :func:`colour_distance`, :func:`uncertainty_text`.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from fabric_optics.fitting.spec import COLOUR_TOLERANCE

__all__ = ["colour_left_off", "colour_distance", "colour_off", "uncertainty_text", "COLOUR_LEFT_OFF"]

#: how a colour-left-off warning begins (fit.json ``warnings``; the CLI prints it once, as the verdict)
COLOUR_LEFT_OFF = "colour left off"


def colour_off(dh: float, ds: float) -> float:
    """``max(|dh|/tol_h, |ds|/tol_s)`` (:data:`COLOUR_TOLERANCE`): <= 1 within the tolerance; 0 without a colour.

    Parameters
    ----------
    dh, ds : float
        Hue (turns) and saturation differences, simulated minus measured; NaN without a colour.

    Returns
    -------
    float
        The larger of the two differences in units of its tolerance.
    """
    if not (math.isfinite(dh) and math.isfinite(ds)):
        return 0.0
    return max(abs(dh) / COLOUR_TOLERANCE[0], abs(ds) / COLOUR_TOLERANCE[1])


def colour_distance(problem: Any, x: np.ndarray) -> float:
    """``max(|dh|/tol_h, |ds|/tol_s)`` of the model at ``x`` (:data:`COLOUR_TOLERANCE`).

    <= 1 within the tolerance; 0 for a measurement without colour.

    Parameters
    ----------
    problem : FitProblem or Surrogate
        The fit.
    x : numpy.ndarray
        One value per free parameter, in its physical units.

    Returns
    -------
    float
        The larger of the two differences in units of its tolerance.
    """
    fig = problem.residual_model().evaluate(problem.model(x)[0])
    if not fig.has_colour:
        return 0.0
    dh_max, ds_max = COLOUR_TOLERANCE
    return max(abs(float(fig.dh)) / dh_max, abs(float(fig.ds)) / ds_max)


def colour_left_off(problem: Any, dh: float, ds: float, method: str | None = None) -> str:
    """One line when the colour ``(dh, ds)`` is further from the measured than :data:`COLOUR_TOLERANCE`.

    The line says what helps for this fit's free parameters and method; ``""`` within the tolerance, or
    without a colour.

    Parameters
    ----------
    problem : FitProblem
        The fit (its config, free parameters and weights).
    dh, ds : float
        Hue (turns) and saturation differences, simulated minus measured; NaN without a colour.
    method : str, optional
        The fit's method (default: the problem's).

    Returns
    -------
    str
        The line, or ``""``.
    """
    if not (math.isfinite(dh) and math.isfinite(ds)):
        return ""
    dh_max, ds_max = COLOUR_TOLERANCE
    if abs(dh) <= dh_max and abs(ds) <= ds_max:
        return ""
    method = method or problem.method
    # a blend: the first of its populations' dyes that cannot take every colour (one fiber: its dye)
    dyes = [c.dye for _, c in problem.config.population_configs()]
    dye = next((d for d in dyes if d is None or d.curve != "knots"), dyes[0])
    if not any(p.kind == "dye" for p in problem.free):
        helps = ("the dye is fixed: free it (--free dye, a blend's --free populations.NAME.dye; with --dye knots it "
                 "can take any colour)" if problem.config.populations else
                 "the dye is fixed: free it (--free dye; with --dye knots it can take any colour)")
    elif problem.colour_weight <= 0:
        helps = "--colour-weight 0 leaves the colour out of the objective: give it a weight (the default 1)"
    elif method != "mc" and not problem.holds_colour():
        helps = ("the colour hold is off (--no-colour-hold): without it the curve error outweighs the colour; "
                 "drop the option")
    elif dye is None or dye.curve != "knots":
        helps = (f"the {dye.curve if dye is not None else 'absent'} dye cannot take every colour: --dye knots "
                 "(8 knots started from the measured colour)")
    elif method == "mc":
        helps = ("more Monte Carlo runs (--resume --max-runs N: each run corrects the surrogate's colour "
                 "again), or start from the summation's fit of the same data (its fitted.toml as CONFIG)")
    else:
        helps = (f"the objective held the colour to the tolerance and this is as near as the {method} model comes "
                 "with these free parameters: a larger --colour-weight does not help; "
                 + (_SUMMATION_LIMIT if method == "summation" else _CLASSIC_LIMIT))
    return (f"{COLOUR_LEFT_OFF}: the fitted model's hue differs by {dh:+.3f} turn and its saturation by {ds:+.3f} "
            f"from the measurement (tolerance |dh| <= {dh_max} turn, |ds| <= {ds_max}); {helps}")


#: what helps a classic or summation fit whose held colour stays off (measured: docs/notes/fit-trust.md, "The fits on
#: the measured plan")
_CLASSIC_LIMIT = ("the classic model is a carpet of fibers with one surface term: free more of its parameters, or fit "
                  "the summation (--method summation)")
_SUMMATION_LIMIT = ("free more parameters (volume_fraction), or fit the Monte Carlo (--method mc), which carries the "
                    "forward transport through clear fibers the summation's layers lack (they stay desaturated)")


def colour_left_off_at(problem: Any, x: np.ndarray) -> list[str]:
    """The fitted colour further from the measured than :data:`COLOUR_TOLERANCE` (:func:`colour_left_off`).

    Parameters
    ----------
    problem : FitProblem or Surrogate
        The fit.
    x : numpy.ndarray
        One value per free parameter, in its physical units.

    Returns
    -------
    list of str
        The line of :func:`colour_left_off`, or empty.
    """
    fig = problem.residual_model().evaluate(problem.model(x)[0])
    if not fig.has_colour:
        return []
    note = colour_left_off(problem, float(fig.dh), float(fig.ds))
    return [note] if note else []


def uncertainty_text(u: float, status: str = "") -> str:
    """``+- u`` for a parameter whose uncertainty is a number.

    Its status (at a bound, not identifiable) or ``(no uncertainty)`` otherwise -- never a number for those.

    Parameters
    ----------
    u : float
        The parameter's standard uncertainty.
    status : str, default ""
        Its status (:func:`fabric_optics.fitting.uncertainty.u_status`); ``""`` when ``u`` is a number.

    Returns
    -------
    str
        The text.
    """
    if status:
        return f"({status}: no uncertainty)"
    if not math.isfinite(float(u)):
        return "(no uncertainty)"
    return f"+- {float(u):.2g}"


