"""The two tasks of the Python interface that the command lines had alone: importing a measurement
(`fabric_optics.import_measurement`, every format of `gonio import`) and writing the report
(`fabric_optics.write_report`, `compare report`). The command lines call the same functions: their outputs
are the same datasets and the same metrics."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import fabric_optics as fo
from fabric_optics.cli.compare import main as compare_main
from fabric_optics.cli.gonio import main as gonio_main
from gonio.data.formats.merl import write_merl

ROOT = Path(__file__).resolve().parents[2]
FELT = ROOT / "fixtures" / "real" / "acrylic_felt_green_rgb.bsdf"
ANALYTIC = ROOT / "fixtures" / "analytic"


def test_every_format_of_gonio_import_is_importable():
    assert fo.IMPORT_FORMATS == ("rgl-bsdf", "pgii", "merl")


def test_an_rgl_file_imports_as_the_command_line_imports_it(tmp_path):
    felt = fo.import_measurement(FELT, tmp_path / "api", plan="quick")
    assert gonio_main(["import", "rgl-bsdf", str(FELT), "--plan", "quick", "--out", str(tmp_path / "cli")]) == 0
    cli = fo.read_dataset(tmp_path / "cli")
    assert felt.is_rgb and set(felt.table["theta_i"]) == {0.0, 45.0}          # the quick plan's incidences
    np.testing.assert_array_equal(fo.read_dataset(tmp_path / "api").table["beta"], cli.table["beta"])
    # a second import into the same folder is refused, and replaced with force
    with pytest.raises(fo.OutputExistsError, match="force=True"):
        fo.import_measurement(FELT, tmp_path / "api", plan="quick")
    fo.import_measurement(FELT, tmp_path / "api", plan="quick", force=True)


def test_the_measured_plan_follows_the_files_own_incidences():
    felt = fo.import_measurement(FELT, plan="measured")
    assert sorted(set(np.round(felt.table["theta_i"], 2))) == [0.0, 27.76, 40.03, 50.16, 59.52, 68.77, 78.56]
    with pytest.raises(fo.InputError, match="plan 'measured'"):
        fo.import_measurement(ANALYTIC / "measured_red" / "radiance.csv", format="pgii", plan="measured")


def test_a_merl_table_imports_with_its_channel_ratios(tmp_path):
    def f_r(theta_h, theta_d, phi_d):
        base = 0.2 + 0.5 * np.cos(theta_h) ** 8 + 0.05 * np.cos(theta_d)
        return np.stack([base, 0.8 * base, 0.5 * base], axis=-1) / np.pi

    table = fo.import_measurement(write_merl(tmp_path / "a.binary", f_r)).table   # format from the suffix
    red, green = (table[table["channel"] == c]["beta"].to_numpy() for c in "RG")
    np.testing.assert_allclose(green, 0.8 * red, rtol=1e-12)


def test_pgii_files_need_their_format_and_give_pi_f_r(tmp_path):
    text = ('#sample_name "test felt"\n#intheta 30\n#format: theta phi BSDF\n'
            "0 0 0.1\n20 0 0.2\n160 0 0.3\n")
    (tmp_path / "a.txt").write_text(text)
    with pytest.raises(fo.InputError, match="format: cannot tell"):
        fo.import_measurement(tmp_path / "a.txt")
    ds = fo.import_measurement([tmp_path / "a.txt"], format="pgii")
    np.testing.assert_allclose(np.sort(ds.table["beta"].to_numpy()), np.pi * np.array([0.1, 0.2, 0.3]))
    with pytest.raises(fo.InputError, match=r"scale=-1: must be in \(0, inf\]"):
        fo.import_measurement(tmp_path / "a.txt", format="pgii", scale=-1)
    with pytest.raises(fo.InputError, match=r"white_reflectance=1.5: must be in \(0, 1\]"):
        fo.import_measurement(tmp_path / "a.txt", format="pgii", white_reflectance=1.5)
    with pytest.raises(fo.InputError, match="format='csv': choose one of 'rgl-bsdf', 'pgii', 'merl'"):
        fo.import_measurement(tmp_path / "a.txt", format="csv")


def test_write_report_writes_what_compare_report_writes(tmp_path, capsys):
    report = fo.write_report(ANALYTIC / "measured_red", ANALYTIC / "sim_lambert", out=tmp_path / "api")
    assert report == tmp_path / "api" / "report.html" and report.is_file()
    assert compare_main(["report", str(ANALYTIC / "measured_red"), str(ANALYTIC / "sim_lambert"),
                         "--out", str(tmp_path / "cli")]) == 0
    api_metrics, cli_metrics = (json.loads((tmp_path / d / "metrics.json").read_text()) for d in ("api", "cli"))
    assert api_metrics == cli_metrics
    # the curve error it holds is the comparison's
    comparison = fo.compare(ANALYTIC / "measured_red", ANALYTIC / "sim_lambert")
    name = next(iter(comparison.simulated))
    assert api_metrics["overall"][name]["nrmse"] == pytest.approx(comparison.overall[name].nrmse)
    assert f"{name}: overall RMSE" in capsys.readouterr().out
    with pytest.raises(fo.OutputExistsError, match="force=True"):
        fo.write_report(ANALYTIC / "measured_red", ANALYTIC / "sim_lambert", out=tmp_path / "api")
    with pytest.raises(fo.InputError, match="renders"):
        fo.write_report(ANALYTIC / "measured_red", out=tmp_path / "r", renders=tmp_path)
