"""Every old spelling parses to what its new spelling parses to, and says so in one line on stderr."""

from __future__ import annotations

import argparse
from pathlib import Path

import pytest

from fabric_optics.cli import common
from fabric_optics.cli.gonio import build_parser as gonio_parser
from fabric_optics.cli.simulate import build_parser as simulate_parser


def _parse(parser: argparse.ArgumentParser, argv: list[str], capsys) -> tuple[dict, str]:
    ns = common.clean(parser.parse_args(argv))
    return vars(ns), capsys.readouterr().err


#: (parser, old argv, new argv, the deprecation line)
CASES = [
    (gonio_parser, ["acquire", "quick", "--modbus", "tcp://h:1", "--serial", "pty", "--out", "o"],
     ["acquire", "--plan", "quick", "--modbus", "tcp://h:1", "--serial", "pty", "--out", "o"],
     "gonio acquire: the positional PLAN is deprecated; use --plan PLAN (same meaning)"),
    (gonio_parser, ["replay", "t.jsonl", "quick", "--out", "o"], ["replay", "t.jsonl", "--plan", "quick", "--out", "o"],
     "gonio replay: the positional PLAN is deprecated; use --plan PLAN (same meaning)"),
    (gonio_parser, ["truth", "red-cotton", "quick", "--out", "o"],
     ["truth", "red-cotton", "--plan", "quick", "--out", "o"],
     "gonio truth: the positional PLAN is deprecated; use --plan PLAN (same meaning)"),
    (gonio_parser, ["check-plan", "quick", "--list"], ["check-plan", "--plan", "quick", "--list"],
     "gonio check-plan: the positional PLAN is deprecated; use --plan PLAN (same meaning)"),
    (gonio_parser, ["import", "rgl-bsdf", "f.bsdf", "--geometry", "quick", "--out", "o"],
     ["import", "rgl-bsdf", "f.bsdf", "--plan", "quick", "--out", "o"],
     "gonio import: --geometry is deprecated; use --plan (same meaning)"),
    (simulate_parser, ["fabric", "red-cotton", "--method", "classic", "--geometry", "quick", "--out", "o"],
     ["fabric", "red-cotton", "--method", "classic", "--plan", "quick", "--out", "o"],
     "simulate fabric: --geometry is deprecated; use --plan (same meaning)"),
    (simulate_parser, ["sweep", "red-cotton", "--param", "rms_slope=0.2,0.3", "--geometry", "quick", "--out", "o"],
     ["sweep", "red-cotton", "--param", "rms_slope=0.2,0.3", "--plan", "quick", "--out", "o"],
     "simulate sweep: --geometry is deprecated; use --plan (same meaning)"),
    (simulate_parser, ["sweep", "red-cotton", "--param", "rms_slope=0.2,0.3", "--measured", "m", "--out", "o"],
     ["sweep", "red-cotton", "m", "--param", "rms_slope=0.2,0.3", "--out", "o"],
     "simulate sweep: --measured is deprecated; use the positional MEASURED (same meaning)"),
    (simulate_parser, ["fiber", "red-cotton", "--method", "beam", "--out", "o"],
     ["fiber", "red-cotton", "--route", "beam", "--out", "o"],
     "simulate fiber: --method is deprecated; use --route (same meaning)"),
]


@pytest.mark.parametrize("build, old, new, line", CASES, ids=[c[3].split(":")[0] + " " + c[3].split(": ")[1].split(" is")[0]
                                                              for c in CASES])
def test_old_spelling_parses_as_the_new_one_with_one_line(build, old, new, line, capsys):
    parser = build()
    new_ns, new_err = _parse(parser, new, capsys)
    old_ns, old_err = _parse(build(), old, capsys)
    assert new_err == ""
    assert old_err == line + "\n"
    assert old_ns == new_ns


def test_an_old_spelling_given_twice_says_it_once(capsys):
    ns, err = _parse(simulate_parser(), ["fabric", "red-cotton", "--method", "classic", "--geometry", "a",
                                         "--geometry", "quick", "--out", "o"], capsys)
    assert err.count("\n") == 1 and ns["plan"] == "quick"


def test_plan_given_both_ways_is_refused(capsys):
    with pytest.raises(SystemExit) as info:
        gonio_parser().parse_args(["check-plan", "--plan", "quick", "red-cotton"])
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "give the plan once" in err


def test_max_evaluations_with_mc_is_max_runs(monkeypatch, tmp_path, capsys):
    """``simulate fit --method mc --max-evaluations N`` gives its line and the fit the new spelling
    would run (the API's arguments are compared; the fit itself is not run)."""
    from fabric_optics import api
    from fabric_optics.cli.simulate import main

    calls = []

    def prepare_fit(*args, **kwargs):
        calls.append((args[1].name, args[2:], kwargs))
        raise api.InputError("stop here")

    monkeypatch.setattr(api, "prepare_fit", prepare_fit)
    measured = str(Path(__file__).parents[2] / "fixtures" / "recorded" / "quick-lambert")
    base = ["fit", "red-cotton", measured, "--method", "mc", "--free", "dye", "--out", str(tmp_path / "o")]
    assert main(base + ["--max-runs", "3"]) == 2
    new_err = capsys.readouterr().err
    assert main(base + ["--max-evaluations", "3"]) == 2
    old_err = capsys.readouterr().err
    assert new_err == "simulate fit: error: stop here\n"
    assert old_err == ("simulate fit: --max-evaluations with --method mc is deprecated; use --max-runs "
                       "(same meaning)\n" + new_err)
    assert len(calls) == 2 and calls[0] == calls[1] and calls[0][2]["max_runs"] == 3
    assert calls[0][2]["max_evaluations"] is None


def test_max_runs_belongs_to_the_mc_fit(capsys):
    from fabric_optics.cli.simulate import main

    assert main(["fit", "red-cotton", "m", "--free", "dye", "--max-runs", "3", "--out", "o"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--max-runs counts the Monte Carlo runs of --method mc" in err
