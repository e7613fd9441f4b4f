"""The colour hold of the classic and summation fits' objective (fabric_optics.fitting.problem.colour_hold)."""

from __future__ import annotations

import numpy as np
import pytest

from fabric_optics.fitting.search import run_fit
from fabric_optics.fitting.spec import COLOUR_HOLD_FROM, COLOUR_HOLD_WEIGHT, COLOUR_TOLERANCE, colour_hold, parse_free
from fabric_optics.fitting.verdict import colour_left_off

from .conftest import measurement, sibling

TOL_H, TOL_S = COLOUR_TOLERANCE


def test_hold_is_zero_inside_and_grows_beyond_its_start():
    assert np.all(colour_hold(0.0, 0.0) == 0.0)
    assert np.all(colour_hold(-0.99 * COLOUR_HOLD_FROM * TOL_H, 0.99 * COLOUR_HOLD_FROM * TOL_S) == 0.0)
    r = colour_hold(-2.0 * TOL_H, 3.0 * TOL_S)
    assert r == pytest.approx(np.sqrt(COLOUR_HOLD_WEIGHT) * np.array([2.0 - COLOUR_HOLD_FROM, 3.0 - COLOUR_HOLD_FROM]))


@pytest.fixture(scope="module")
def torn(base_problem):
    """A measurement whose colour and curves want different dyes: at normal incidence the classic model
    with a strong red dye (band peak 2 /um), at the oblique incidences the same model nearly undyed
    (0.05 /um), scaled to the normal incidence's mean spectrum. The colour is exactly reachable (peak 2)."""
    free = parse_free(["fiber.dye.bands[0].peak_per_um=0.05:3,rms_slope=0.1:0.8"], base_problem.config)
    model = sibling(base_problem, base_problem.measured, free)
    g = model.geometries
    pale, red = model.model(np.array([0.05, 0.3]))[0], model.model(np.array([2.0, 0.3]))[0]
    oblique = g["theta_i"].to_numpy() > 10.0
    beta = red.copy()
    beta[oblique] = pale[oblique] * red[~oblique].mean(axis=0) / pale[~oblique].mean(axis=0)
    return sibling(base_problem, measurement(lambda g_, wl: beta, None, geometries=g), free)


def _fit(problem, hold: bool):
    p = sibling(problem, problem.measured, problem.free, hold_colour=hold)
    r = run_fit(p, noise_draws=0, invert_start=False)
    fig = p.residual_model().evaluate(p.model(r.x)[0])
    return p, r, fig


def test_weighted_colour_alone_ends_off_the_hold_ends_on_it(torn):
    """At --colour-weight 1 the curve error wins without the hold (the colour left off, and the verdict
    says the hold is off); with it the fit ends within the tolerance, at a larger curve error."""
    p0, _, free_fig = _fit(torn, hold=False)
    assert abs(free_fig.dh) > TOL_H or abs(free_fig.ds) > TOL_S
    assert "--no-colour-hold" in colour_left_off(p0, float(free_fig.dh), float(free_fig.ds))
    p1, r1, held = _fit(torn, hold=True)
    assert abs(held.dh) <= TOL_H and abs(held.ds) <= TOL_S
    assert held.nrmse > free_fig.nrmse   # the colour costs curve error: the hold, not a better optimum, moved it
    assert colour_left_off(p1, float(held.dh), float(held.ds)) == ""
    assert r1.info["status"][0] > 0      # converged (scipy's status), not stopped by the budget


def test_hold_does_not_move_a_fit_that_ends_on_the_colour(base_problem):
    """Data the model reproduces (its own values): the objective with and without the hold is the same
    at the solution, and the fit recovers the point either way."""
    free = parse_free(["fiber.dye.bands[0].peak_per_um=0.05:3,rms_slope=0.1:0.8"], base_problem.config)
    model = sibling(base_problem, base_problem.measured, free)
    x_true = np.array([1.2, 0.35])
    own = sibling(base_problem, measurement(lambda g, wl: model.model(x_true)[0], None,
                                            geometries=model.geometries), free)
    _, r0, _ = _fit(own, hold=False)
    _, r1, _ = _fit(own, hold=True)
    assert r1.x == pytest.approx(r0.x, rel=1e-4)
    assert r1.x == pytest.approx(x_true, rel=1e-3)


def test_held_problem_states_it_and_its_identity_differs(torn):
    p = sibling(torn, torn.measured, torn.free)
    assert not p.holds_colour()
    ident = p.identity()
    p = sibling(torn, torn.measured, torn.free, hold_colour=True)
    assert p.holds_colour() and p.identity() != ident
    assert p.residuals(p.start).size == torn.residuals(p.start).size + 2   # the two hold entries
    p = sibling(torn, torn.measured, torn.free, hold_colour=True, colour_weight=0.0)
    assert not p.holds_colour()   # no colour in the objective: nothing to hold


@pytest.mark.parametrize("method, hold, weight, says", [
    ("classic", True, 1.0, ["as near as the classic model comes", "does not help", "--method summation"]),
    ("summation", True, 1.0, ["as near as the summation model comes", "does not help", "--method mc"]),
    ("classic", False, 1.0, ["--no-colour-hold", "drop the option"]),
    ("summation", True, 0.0, ["--colour-weight 0"]),
])
def test_left_off_says_what_helps_for_the_objective_it_had(base_problem, method, hold, weight, says):
    """Knots (any colour) and the colour held: the model's limit, not a larger weight; the hold off or
    the colour without weight: that setting. No walk (the verdict reads the settings only)."""
    from fabric_optics.fitting.problem import FitProblem
    from fabric_optics.fitting.start import knots_config

    config = knots_config(base_problem.config, base_problem.wavelengths_nm)
    p = FitProblem(config, base_problem.measured, parse_free(["dye,rms_slope"], config), method=method,
                   colour_weight=weight, hold_colour=hold, target_rel_err=0.1, seed=5)
    line = colour_left_off(p, 0.0, -0.1)
    assert line.startswith("colour left off") and all(s in line for s in says), line
    assert colour_left_off(p, 0.01, -0.02) == ""   # within the tolerance: nothing to say
    assert p.counters.walks == 0
