"""One name, one syntax, one default per concept across gonio, simulate and compare (the table in
fabric_optics.cli.common), read from the parsers the programs use."""

from __future__ import annotations

import argparse
from pathlib import Path

import pytest

from fabric_optics.cli import common, inventory
from fabric_optics.cli.compare import main as compare_main
from fabric_optics.cli.gonio import main as gonio_main
from fabric_optics.cli.simulate import main as simulate_main

COMMANDS = {name: p for name, p, _ in inventory.commands()}
ANALYTIC = Path(__file__).parents[2] / "fixtures" / "analytic"


def _visible(p: argparse.ArgumentParser) -> dict[str, argparse.Action]:
    return {s: a for a in p._actions if a.help != argparse.SUPPRESS for s in a.option_strings}


def test_every_program_and_subcommand_is_listed():
    assert {c.split()[0] for c in COMMANDS} == {"gonio", "simulate", "compare"}
    assert len(COMMANDS) == 21
    assert {"gonio mock", "gonio bench-driver", "simulate fit", "compare render"} <= set(COMMANDS)


def test_one_spelling_per_concept():
    inv = inventory.inventory()
    assert {k: len(v) for k, v in inv["spellings"].items()} == {k: 1 for k in inv["spellings"]}, inv["spellings"]
    assert inv["spellings"]["plan"] == ["--plan"]
    assert inv["spellings"]["measured dataset"] == ["positional MEASURED"]
    assert inv["spellings"]["fiber route"] == ["--route"]
    assert inv["spellings"]["Monte Carlo runs of a fit"] == ["--max-runs"]
    assert inv["hidden_flags"] == []


def test_every_writer_has_out_and_force():
    inv = inventory.inventory()
    assert inv["writers"] == 16 and inv["writers_without_force"] == []


@pytest.mark.parametrize("name", sorted(c for c in COMMANDS if "--plan" in _visible(COMMANDS[c])))
def test_plan_default(name):
    action = _visible(COMMANDS[name])["--plan"]
    required = name in ("gonio acquire", "gonio replay", "gonio truth", "gonio check-plan")
    optional = name in ("gonio import", "gonio demo")        # import: the file's geometries; demo: by --sample
    assert action.metavar == "PLAN"
    assert action.default == (None if required or optional else common.DEFAULT_PLAN)
    assert ("required" in action.help) == required


def test_threads_target_seed_wavelengths_defaults():
    for name, p in COMMANDS.items():
        opts = _visible(p)
        if "--threads" in opts:
            assert opts["--threads"].default == (1 if name == "simulate sweep" else 0), name
            assert "results do not depend on it" in opts["--threads"].help
        if "--target-rel-err" in opts:
            assert opts["--target-rel-err"].default is None, name
            assert "default: the config's target_rel_err" in opts["--target-rel-err"].help, name
        if "--seed" in opts and name.startswith("simulate") and name != "simulate slab":
            assert opts["--seed"].default is None and "the config's" in opts["--seed"].help, name
        if "--wavelengths" in opts:
            assert opts["--wavelengths"].type is common.wavelengths_arg, name
        if "--method" in opts:
            assert "nee" not in opts["--method"].choices, name        # the fabric model only


def test_progress_where_a_bar_can_appear():
    with_bar = {"gonio acquire", "gonio demo", "simulate fabric", "simulate fiber", "simulate fit",
                "simulate sweep", "simulate export"}
    assert {n for n, p in COMMANDS.items() if "--no-progress" in _visible(p)} == with_bar


@pytest.mark.parametrize("main, before, after", [
    (gonio_main, ["-v", "check-plan", "--plan", "quick"], ["check-plan", "--plan", "quick", "-v"]),
    (compare_main, ["-v", "check", str(ANALYTIC / "measured_red"), str(ANALYTIC / "sim_scaled")],
     ["check", str(ANALYTIC / "measured_red"), str(ANALYTIC / "sim_scaled"), "--verbose"]),
])
def test_verbose_before_or_after_the_subcommand_runs_the_same(main, before, after, capsys):
    code_before = main(before)
    out_before = capsys.readouterr().out
    code_after = main(after)
    assert (code_after, capsys.readouterr().out) == (code_before, out_before)


@pytest.mark.parametrize("argv", [["-v", "weave", "red-cotton", "--out", "m.ply"],
                                  ["weave", "red-cotton", "--out", "m.ply", "-v"],
                                  ["weave", "-v", "red-cotton", "--out", "m.ply"]])
def test_verbose_position_in_simulate(argv):
    from fabric_optics.cli.simulate import build_parser

    assert build_parser().parse_args(argv).verbose is True
    assert build_parser().parse_args(["weave", "red-cotton", "--out", "m.ply"]).verbose is False


@pytest.mark.parametrize("main, argv, needle", [
    (gonio_main, ["export", "fixtures/analytic/measured_red", "--incidences", "1000", "--out", "x.bsdf"],
     "argument --incidences: must be an integer in [2, 64], got '1000'"),
    (gonio_main, ["export", "fixtures/analytic/measured_red", "--resolution", "3", "--out", "x.bsdf"],
     "argument --resolution: must be an integer in [4, 256]"),
    (gonio_main, ["check-plan"], "--plan PLAN is required"),
    (gonio_main, ["truth", "red-cotton", "--out", "o"], "--plan PLAN is required"),
])
def test_bounds_are_one_line(main, argv, needle, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    argv = [str(Path(__file__).parents[2] / a) if a.startswith("fixtures/") else a for a in argv]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and needle in err, err
    assert not (tmp_path / "x.bsdf").exists() and not (tmp_path / "o").exists()


def test_renders_without_a_simulation_or_missing_are_refused(tmp_path, capsys):
    measured = str(Path(__file__).parents[2] / "fixtures/analytic/measured_red")
    sim = str(Path(__file__).parents[2] / "fixtures/analytic/sim_scaled")
    renders = tmp_path / "renders"
    renders.mkdir()
    assert compare_main(["report", measured, "--renders", str(renders), "--out", str(tmp_path / "r")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "give a SIMULATED dataset too" in err
    for argv in ([measured], [measured, sim]):
        assert compare_main(["report", *argv, "--renders", str(tmp_path / "none"), "--out", str(tmp_path / "r")]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "--renders" in err and "not a folder" in err
    assert not (tmp_path / "r").exists()


def test_inventory_script_prints_the_counts(capsys):
    assert inventory.main([]) == 0
    out = capsys.readouterr().out
    assert "subcommands: 21" in out and "plan: 1 spelling: --plan" in out


def test_gonio_exposes_its_three_parsers():
    from fabric_optics.cli.gonio import build_parsers

    parsers = build_parsers()
    assert set(parsers) == {"gonio", "gonio mock", "gonio bench-driver"}
    assert all(isinstance(p, argparse.ArgumentParser) for p in parsers.values())
    assert simulate_main is not None
