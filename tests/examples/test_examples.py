"""The three runnable examples of ``examples/``, run on reduced budgets (their own options), and
their printed figures checked against the datasets they wrote."""

from __future__ import annotations

import json
import re
import runpy
from pathlib import Path

import numpy as np
import pytest

import fabric_optics as fo
from compare.comparison import compare_datasets
from gonio.data.dataset import read_dataset
from tests.compare.test_demo_pipeline import PLAN

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


def _main(name: str):
    return runpy.run_path(str(EXAMPLES / name), run_name="example")["main"]


#: the example's red-cotton plan reduced for the test: the demo pipeline test's reduced plan (a 20 nm grid over the
#: visible for colour, ASTM E308; the four incidences with 8 of the 14 in-plane angles, the colour geometry and the
#: normalisation's neighbours of the normal kept), with the example's sample
REDUCED_PLAN = PLAN.replace('name = "green acrylic felt"', 'name = "red cotton"')


#: two incidences of the red-cotton plan (the normal's neighbours on both sides, the colour geometry), 20 nm
SMALL_PLAN = REDUCED_PLAN.replace("incidence_deg = [0, 30, 45, 60]", "incidence_deg = [0, 45]")


def test_refit_felt_dye_refuses_an_earlier_run_in_one_line_before_measuring(tmp_path, capsys):
    (tmp_path / "fit").mkdir()
    (tmp_path / "fit" / "fit.json").write_text("{}")
    assert _main("refit_felt_dye.py")([str(tmp_path), "--wavelengths", "450,550,650"]) == 2
    err = capsys.readouterr().err
    assert "pass --force" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "measured").exists()


def test_mock_vs_simulation_prints_the_verdict_of_the_datasets_it_wrote(tmp_path, capsys):
    plan = tmp_path / "plan.toml"
    plan.write_text(REDUCED_PLAN)
    code = _main("mock_vs_simulation.py")([str(tmp_path), "--target-rel-err", "0.2", "--plan", str(plan)])
    out = capsys.readouterr().out
    measured, simulated = read_dataset(tmp_path / "measured"), read_dataset(tmp_path / "simulated")
    assert measured.meta["kind"] == "measured" and simulated.meta["kind"] == "simulated"
    nrmse = compare_datasets(measured, [simulated]).overall
    printed = float(re.search(r"overall NRMSE = ([0-9.]+)", out).group(1))
    assert printed == pytest.approx(next(iter(nrmse.values())).nrmse, rel=1e-3)
    assert code == (0 if printed <= 0.1 and "FAIL" not in out else 1)
    # a FAIL on the curves alone is the stand-in's shape, and the script says so
    verdict = fo.check(fo.compare(measured, simulated))
    assert ("expected: the mock holds an analytic stand-in" in out) == (verdict.failures() == ["overall NRMSE"])

    # a second run into the same folder: one line, nothing touched; with --force: replaced
    before = (tmp_path / "measured" / "radiance.csv").read_bytes()
    assert _main("mock_vs_simulation.py")([str(tmp_path), "--target-rel-err", "0.2", "--plan", str(plan)]) == 2
    err = capsys.readouterr().err
    assert "pass --force" in err and len(err.strip().splitlines()) == 1
    assert (tmp_path / "measured" / "radiance.csv").read_bytes() == before
    small = tmp_path / "small.toml"                    # a smaller plan, so that the replacement shows
    small.write_text(SMALL_PLAN)
    _main("mock_vs_simulation.py")([str(tmp_path), "--target-rel-err", "0.3", "--plan", str(small), "--force"])
    assert set(read_dataset(tmp_path / "measured").table["theta_i"]) == {0.0, 45.0}
    assert set(read_dataset(tmp_path / "simulated").table["theta_i"]) == {0.0, 45.0}


@pytest.mark.slow   # three fabric methods end to end (about 40 s); the bench's own tests cover the rows
def test_methods_speed_error_writes_one_row_per_method(tmp_path, capsys):
    out_json = tmp_path / "methods.json"
    assert _main("methods_speed_error.py")(["--target-rel-err", "0.2", "--json", str(out_json)]) == 0
    rows = {r["method"]: r for r in json.loads(out_json.read_text())["runs"]}
    assert set(rows) == {"mc", "summation", "classic"}
    assert rows["mc"]["nrmse_vs_mc"] == 0.0 and 0 < rows["mc"]["rel_err"] <= 0.2
    for name in ("summation", "classic"):
        assert np.isfinite(rows[name]["nrmse_vs_mc"]) and rows[name]["nrmse_vs_mc"] > 0
        assert rows[name]["seconds"] > 0
    printed = capsys.readouterr().out
    assert all(name in printed for name in rows)


@pytest.mark.slow   # a felt fit end to end (about 70 s); tests/fabric_optics/fitting cover the fit
@pytest.mark.timeout(900)
def test_refit_felt_dye_prints_the_figures_of_its_fit(tmp_path, capsys):
    assert _main("refit_felt_dye.py")([str(tmp_path), "--max-evaluations", "3", "--target-rel-err", "0.2",
                                       "--wavelengths", "450,550,650"]) == 0
    summary = json.loads((tmp_path / "fit" / "fit.json").read_text())
    out = capsys.readouterr().out
    for key in ("start", "fitted"):
        printed = float(re.search(rf"{key}: NRMSE ([0-9.]+)", out).group(1))
        assert printed == pytest.approx(summary[key]["nrmse"], abs=1e-4)
    assert (tmp_path / "fit" / "fitted.toml").is_file()
    assert read_dataset(tmp_path / "fit" / "fitted").wavelengths_nm.tolist() == [450.0, 550.0, 650.0]
