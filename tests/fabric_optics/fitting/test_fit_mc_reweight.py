"""The Monte Carlo fit's re-weighted runs (fabric_optics.fitting.spacemapping.run_monte_carlo with ``reuse``): with
only dye parameters free, a run after a traced one is re-weighted from its record while the re-weighting is accurate
enough (reweight_accepted), traced (and recorded) otherwise; --mc-retrace and any other free parameter trace every
run. The tracer and the re-weighting are stood in for here (what they compute: tests/simulate/raytrace/test_reweight_mc.py)."""

from __future__ import annotations

import numpy as np
import pytest

from fabric_optics.fitting import spacemapping as fit_mc
from fabric_optics.fitting.spacemapping import MCFitProblem, reweight_accepted, run_monte_carlo
from fabric_optics.fitting.spec import parse_free
from simulate import products
from simulate.products import FabricEstimate

from .test_fit_mc import FREE, WL6, _felt, _flat


@pytest.fixture()
def stand_ins(monkeypatch):
    """``evaluate`` and ``reweighted_estimate`` stood in for: each trace fills its record with its number; each
    re-weighting returns the next of ``answers`` (its relative error and spread) and the record it was given."""
    calls: dict = {"traced": [], "reweighted": [], "answers": []}

    def evaluate(method, config, fiber, geoms, wl, settings):
        calls["traced"].append(settings.record is not None)
        if settings.record is not None:
            settings.record["trace"] = len(calls["traced"])
        beta = np.full((geoms.theta_i.size, wl.size), 0.3)
        return FabricEstimate(beta, 0.01 * beta, np.ones(beta.shape, int), 1, {"rays": 1000})

    def reweighted_estimate(record, config, wl):
        calls["reweighted"].append(record["trace"])
        rel, spread = calls["answers"].pop(0)
        beta = np.full((len(problem_of[0].geometries), wl.size), 0.25)
        return beta, rel * beta, {"rel_err": rel, "spread": spread, "rays": 1000}

    problem_of: list = []
    monkeypatch.setattr(fit_mc, "evaluate", evaluate)
    monkeypatch.setattr(products, "reweighted_estimate", reweighted_estimate)
    return calls, problem_of


def _problem(free=FREE, **kw):
    cfg = _felt(-1.0, -2.0)
    return MCFitProblem(cfg, _flat(WL6), parse_free([free], cfg), target_rel_err=0.04, seed=1, wavelengths_nm=WL6,
                        **kw)


def test_runs_are_re_weighted_while_accurate_and_traced_otherwise(stand_ins):
    calls, problem_of = stand_ins
    problem = _problem()
    problem_of.append(problem)
    assert problem.reweights_runs()
    x = problem.start.copy()
    reuse: dict = {}
    # the traced run's relative error is 0.01, the target 0.04: a re-weighting within 1.25 x 0.04 is kept
    calls["answers"] = [(0.045, 1.3), (0.06, 1.3), (0.03, 2.5), (0.02, 1.1)]
    first = run_monte_carlo(problem, x, reuse=reuse)
    assert calls["traced"] == [True] and reuse["record"] == {"trace": 1} and first.rel_err == pytest.approx(0.01)
    kept = run_monte_carlo(problem, x + 0.1, reuse=reuse)
    assert reuse["last"]["reweighted"] and kept.rel_err == pytest.approx(0.045) and len(calls["traced"]) == 1
    np.testing.assert_allclose(kept.beta, 0.25)
    # too large an error: traced again (and recorded: the next re-weighting starts from that trace)
    refused = run_monte_carlo(problem, x + 0.2, reuse=reuse)
    assert not reuse["last"]["reweighted"] and calls["traced"] == [True, True] and refused.rel_err == pytest.approx(0.01)
    # the weights too spread (an effective sample below a quarter of the rays): traced again
    run_monte_carlo(problem, x + 0.3, reuse=reuse)
    assert not reuse["last"]["reweighted"] and len(calls["traced"]) == 3
    run_monte_carlo(problem, x + 0.4, reuse=reuse)
    assert reuse["last"]["reweighted"] and calls["reweighted"] == [1, 1, 2, 3]


def test_retrace_or_a_parameter_besides_the_dye_traces_every_run(stand_ins):
    assert not _problem(mc_retrace=True).reweights_runs()
    assert not _problem(FREE + ",surface.rms_slope").reweights_runs()
    assert _problem().reweights_runs()


def test_the_rule_is_the_target_widened_by_a_quarter_and_a_bounded_spread():
    assert reweight_accepted({"rel_err": 0.0374, "spread": 1.9}, 0.03, 0.02)
    assert not reweight_accepted({"rel_err": 0.0376, "spread": 1.0}, 0.03, 0.02)
    # a trace that stopped above its target (a budget): the re-weighting is held to the trace's own error
    assert reweight_accepted({"rel_err": 0.06, "spread": 1.0}, 0.03, 0.05)
    assert not reweight_accepted({"rel_err": 0.01, "spread": 2.1}, 0.03, 0.02)
    assert not reweight_accepted({"rel_err": 0.01, "spread": float("nan")}, 0.03, 0.02)


def test_mc_retrace_is_for_the_monte_carlo_fit(tmp_path, capsys):
    from fabric_optics.cli.simulate import main
    from gonio.data import write_dataset

    write_dataset(_flat(WL6), tmp_path / "m")
    code = main(["fit", "green-felt", str(tmp_path / "m"), "--method", "summation", "--free", "dye", "--out",
                 str(tmp_path / "f"), "--no-progress", "--mc-retrace"])
    err = capsys.readouterr().err
    assert code == 2 and "--mc-retrace is for --method mc" in err and len(err.strip().splitlines()) == 1, err
