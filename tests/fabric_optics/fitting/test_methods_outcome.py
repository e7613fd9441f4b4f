"""One registry of fit methods read by the API and the command line; the typed outcome of a fit, its verdict as a
warning in the Python API; the Monte Carlo fit's budget named for what it counts."""

from __future__ import annotations

import dataclasses
import inspect
import warnings
from pathlib import Path

import numpy as np
import pytest

from fabric_optics import api
from fabric_optics.fitting.errors import FitError
from fabric_optics.fitting.methods import DEFAULT_METHOD, METHODS
from fabric_optics.fitting.outputs import FitResult
from simulate.products import MODELS

from .conftest import measurement


def _parser_fit_action(dest: str):
    from fabric_optics.cli.simulate import build_parser

    parser = build_parser()
    sub = next(a for a in parser._actions if a.dest == "command")
    fit = sub.choices["fit"]
    return next(a for a in fit._actions if a.dest == dest)


def test_the_cli_and_the_api_read_the_registry():
    method = _parser_fit_action("method")
    assert tuple(method.choices) == tuple(METHODS) == api.FIT_METHODS
    assert set(METHODS) <= set(MODELS)
    assert method.default == DEFAULT_METHOD
    assert inspect.signature(api.fit).parameters["method"].default == DEFAULT_METHOD
    assert inspect.signature(api.prepare_fit).parameters["method"].default == DEFAULT_METHOD
    for m in METHODS.values():   # every budget a method names is a flag of the command line and a runner keyword
        assert _parser_fit_action(m.budget).option_strings == [m.flag]
        assert m.budget in inspect.signature(m.run).parameters


def test_a_budget_of_another_method_is_refused_naming_what_it_counts(red_cotton, tmp_path):
    data = measurement(lambda g, wl: np.full((len(g), wl.size), 0.3), None)
    with pytest.raises(api.InputError, match="max_runs is not the classic fit's budget: it counts model evaluations"):
        api.prepare_fit(red_cotton, data, "rms_slope", tmp_path / "f", method="classic", max_runs=3)


def test_run_mc_fit_refuses_its_old_budget_keyword_in_one_line():
    from fabric_optics.fitting.spacemapping import run_mc_fit

    from .test_resume_state import _mc_problem

    with pytest.raises(TypeError) as err:
        run_mc_fit(_mc_problem(), max_evaluations=3)
    assert "counts Monte Carlo runs; pass max_runs=" in str(err.value) and "\n" not in str(err.value)
    with pytest.raises(FitError, match="at least 2 Monte Carlo runs"):
        run_mc_fit(_mc_problem(), max_runs=1)


def test_a_fit_that_fails_or_never_moves_warns_and_says_so_in_its_outcome(red_cotton, tmp_path):
    """A grey measurement fitted with red cotton's RMS slope alone: the colour cannot follow (the fit fails), and
    with a budget of one evaluation the search never leaves its start; both are FitWarnings, the outcome says
    ``passed`` False with the colour-left-off line among its warnings, and the outputs are written."""
    grey = measurement(lambda g, wl: np.full((len(g), wl.size), 0.3), None)
    with pytest.warns(api.FitWarning) as caught:
        outcome = api.fit(red_cotton, grey, "rms_slope=0.1:0.8", tmp_path / "f", method="classic", max_evaluations=1,
                          target_rel_err=0.2)
    said = [str(w.message) for w in caught]
    assert any("failed: colour left off" in s for s in said) and any("never moved" in s for s in said), said
    assert outcome.passed is False and outcome.summary["verdict"]["passed"] is False
    assert any(w.startswith("colour left off") for w in outcome.warnings)
    assert isinstance(outcome.result, FitResult) and outcome.result.method == "classic"
    assert (tmp_path / "f" / "fit.json").is_file() and (tmp_path / "f" / "fitted.toml").is_file()


def test_the_result_has_one_shape_and_is_frozen():
    fields = [f.name for f in dataclasses.fields(FitResult)]
    assert fields[:2] == ["method", "names"] and {"x", "u", "warnings", "info", "stop"} <= set(fields)
    r = FitResult(method="classic", names=("a",), x=np.zeros(1), start=np.zeros(1), objective=0.0, objective_start=0.0,
                  u=np.zeros(1), u_data=np.zeros(1), u_mc=np.zeros(1), correlation=np.eye(1), warnings=[], info={})
    with pytest.raises(dataclasses.FrozenInstanceError):
        r.method = "mc"  # type: ignore[misc]
    assert r.passed and not r.moved


def test_the_fit_specification_is_frozen(red_cotton):
    from fabric_optics.fitting.problem import FitProblem
    from fabric_optics.fitting.spec import parse_free

    data = measurement(lambda g, wl: np.full((len(g), wl.size), 0.3), None)
    p = FitProblem(red_cotton, data, parse_free(["rms_slope"], red_cotton), method="classic")
    with pytest.raises(dataclasses.FrozenInstanceError):
        p.spec.colour_weight = 2.0  # type: ignore[misc]
    with pytest.raises(AttributeError):
        p.colour_weight = 2.0  # type: ignore[misc]
    with pytest.raises(ValueError):
        p.start[0] = 0.5             # the start and bounds are read-only arrays
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert p.counters.evaluations == 0 and p.counters.walks == 0


def test_a_fit_of_a_blend_it_cannot_fit_is_refused_in_one_line_naming_the_config(tmp_path):
    """A blend whose populations differ in more than dye and share (here the radius) is not fitted: one walk must
    serve every population. Every method refuses it before any walk, naming the file (the Monte Carlo fit: the
    woven Monte Carlo traces one radius)."""
    import fabric_optics as fo

    cfg = tmp_path / "blend.toml"
    text = (Path("simulate/configs/red-cotton.toml").read_text(encoding="utf-8")
            + '\n[[populations]]\nname = "pale"\nshare = 0.5\n[populations.fiber]\nradius_um = 5.0\n'
            + '[[populations]]\nname = "dark"\nshare = 0.5\n'
            + '[populations.fiber.dye]\nwavelength_nm = [400, 700]\nmu_a_per_um = [0.2, 0.2]\n')
    cfg.write_text(text, encoding="utf-8")
    why = {"classic": "'pale' and 'dark' differ in fiber.radius_um", "summation": "differ in fiber.radius_um",
           "mc": "the woven Monte Carlo traces one fiber.radius_um for every population, got 5 and 10"}
    for method in ("classic", "summation", "mc"):
        with pytest.raises(fo.InputError, match=r"blend\.toml: populations: .*" + why[method]) as exc:
            fo.fit(cfg, "fixtures/analytic/measured_red", ["rms_slope"], tmp_path / f"out-{method}",
                   method=method)
        assert "\n" not in str(exc.value)
        assert not (tmp_path / f"out-{method}" / "fit.json").exists()
