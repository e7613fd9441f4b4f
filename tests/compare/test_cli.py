"""The command line: report files, HTML escaping, metrics.json keys, check verdicts, bad inputs."""

from __future__ import annotations

import base64
import contextlib
import html
import io
import json
import logging
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from fabric_optics.cli.compare import main
from gonio.data import read_dataset, write_dataset

XSS = "<script>alert(1)</script>"
XSS2 = "<img src=x onerror=alert(2)>"
SIM_NAMES = {"scaled model", "lambertian model", "grey model", "lambertian model (2)"}
COLOUR_KEYS = {"h", "s", "v", "blue_red", "green_red"}


def _quiet_main(argv):
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        status = main([str(a) for a in argv])
    return status, out.getvalue(), err.getvalue()


@pytest.fixture(scope="module")
def report(tmp_path_factory, h):
    """One report over the analytic fixtures, the measured one renamed to an XSS string."""
    root = tmp_path_factory.mktemp("report")
    measured = read_dataset(h.FIXTURES / "measured_red")
    meta = dict(measured.meta)
    meta["sample"] = {"name": XSS, "description": XSS2}
    measured.meta = meta
    meas_dir = write_dataset(measured, root / "meas<b>bold</b>")
    lambert_copy = shutil.copytree(h.FIXTURES / "sim_lambert", root / "lambert_copy")
    sims = [h.FIXTURES / n for n in ("sim_scaled", "sim_lambert", "sim_grey")] + [lambert_copy]
    out = root / "out"
    status, stdout, stderr = _quiet_main(["report", meas_dir, *sims, "--out", out])
    return dict(status=status, stdout=stdout, stderr=stderr, out=out)


def test_report_writes_the_three_outputs(report):
    assert report["status"] == 0, report["stderr"]
    out = report["out"]
    assert (out / "report.html").is_file() and (out / "metrics.json").is_file()
    names = sorted(p.name for p in (out / "figures").glob("*.png"))
    assert names == ["colour_strips.png", "factor.png", "inplane_450nm.png", "inplane_550nm.png",
                     "inplane_650nm.png", "inplane_luminance.png", "spectrum.png", "swatches.png"]
    assert f"report: {out / 'report.html'}" in report["stdout"]


def test_report_is_self_contained_and_embeds_every_figure(report):
    text = (report["out"] / "report.html").read_text(encoding="utf-8")
    for png in (report["out"] / "figures").glob("*.png"):
        data = png.read_bytes()
        assert data.startswith(b"\x89PNG")
        assert base64.b64encode(data).decode() in text, png.name
    assert "http://" not in text and "https://" not in text
    assert text.count("src='data:image/png;base64,") == 8


def test_user_strings_are_escaped_in_the_html(report):
    text = (report["out"] / "report.html").read_text(encoding="utf-8")
    assert XSS not in text and XSS2 not in text and "<b>bold</b>" not in text
    assert html.escape(XSS) in text
    assert html.escape(XSS2) in text
    assert html.escape("meas<b>bold</b>") in text
    assert "<script" not in text.lower()


def test_metrics_json_has_exactly_the_contract_keys(report):
    m = json.loads((report["out"] / "metrics.json").read_text())
    assert set(m) == {"normalisation", "curves", "overall", "colour", "shape", "software"}
    assert set(m["software"]) == {"package", "version", "commit"}
    assert set(m["normalisation"]) == {"method", "factor", "normal_value", "level"}
    assert set(m["normalisation"]["factor"]) == SIM_NAMES
    for f in m["normalisation"]["factor"].values():
        assert set(f) == {"per_wavelength", "u_per_wavelength", "median", "luminance"}
        assert len(f["per_wavelength"]) == 33 and "390" in f["per_wavelength"]
    assert set(m["normalisation"]["normal_value"]) == SIM_NAMES | {"measured"}
    assert set(m["curves"]) == SIM_NAMES and set(m["overall"]) == SIM_NAMES
    for per_angle in m["curves"].values():
        assert set(per_angle) == {"0", "30", "45", "60"}
        for e in per_angle.values():
            assert set(e) == {"rmse", "nrmse", "max_abs", "max_abs_at"}
            assert {"theta_i", "phi_i", "theta_o", "phi_o", "wavelength_nm"} <= set(e["max_abs_at"])
    for e in m["overall"].values():
        assert set(e) == {"rmse", "nrmse"}
    assert set(m["colour"]) == SIM_NAMES | {"geometry", "measured"}
    assert set(m["colour"]["geometry"]) == {"theta_i", "phi_i", "theta_o", "phi_o", "s"}
    assert set(m["colour"]["measured"]) == COLOUR_KEYS
    for name in SIM_NAMES:
        assert set(m["colour"][name]) == COLOUR_KEYS | {"dh", "ds", "dv"}
    # the renamed copy carries the same figures as the original
    assert m["overall"]["lambertian model (2)"] == m["overall"]["lambertian model"]


@pytest.mark.parametrize("sim, extra, status, shown", [
    ("sim_scaled", [], 1, "FAIL level ratio max(k_Y, 1/k_Y) = 3.7"),     # the shape matches, the level does not
    ("sim_scaled", ["--max-level-ratio", "4"], 0, "ok   overall NRMSE"),
    ("sim_lambert", [], 1, "FAIL overall NRMSE = 0.4991"),
    ("sim_lambert", ["--max-nrmse", "0.6", "--max-sat-diff", "0.3", "--max-level-ratio", "10"], 0,
     "ok   |saturation"),
    ("sim_lambert", ["--max-nrmse", "0.45", "--max-sat-diff", "0.3"], 1, "FAIL overall NRMSE"),
    ("sim_lambert", ["--max-nrmse", "0.6", "--max-sat-diff", "0.25"], 1,
     "FAIL |saturation difference| = 0.2535"),
    ("sim_grey", ["--max-nrmse", "1", "--max-sat-diff", "1", "--max-hue-diff", "0.3", "--max-level-ratio", "10"], 0,
     "ok   |hue difference| = 0.2196"),
    ("sim_grey", ["--max-nrmse", "1", "--max-sat-diff", "1", "--max-hue-diff", "0.2"], 1,
     "FAIL |hue difference| = 0.2196 turns of the hue circle (exceeds 0.2)"),
])
def test_check_verdicts(h, sim, extra, status, shown):
    code, out, err = _quiet_main(["check", h.FIXTURES / "measured_red", h.FIXTURES / sim, *extra])
    assert code == status, out + err
    assert shown in out


def _good_pair(h, tmp_path):
    meas = write_dataset(read_dataset(h.FIXTURES / "measured_red"), tmp_path / "meas")
    sim = write_dataset(read_dataset(h.FIXTURES / "sim_lambert"), tmp_path / "sim")
    return meas, sim


def _edit_csv(path: Path, fn):
    lines = (path / "radiance.csv").read_text().splitlines()
    (path / "radiance.csv").write_text("\n".join(fn(lines)) + "\n")


def _bad_missing_column(h, d):
    h.unprotect(d)
    _edit_csv(d, lambda ls: [",".join(x.split(",")[:6] + x.split(",")[7:]) for x in ls])
    return "missing column(s) u_beta"


def _bad_nan(h, d):
    h.unprotect(d)
    _edit_csv(d, lambda ls: ls[:5] + [",".join(ls[5].split(",")[:5] + ["nan"]
                                               + ls[5].split(",")[6:])] + ls[6:])
    return "column 'beta': value 'nan' is not a finite number"


def _bad_duplicate(h, d):
    h.unprotect(d)
    _edit_csv(d, lambda ls: ls + [ls[3]])
    return "duplicate geometry"


def _bad_schema(h, d):
    meta = json.loads((d / "meta.json").read_text())
    meta["schema"] = "radiance-dataset/99"
    (d / "meta.json").write_text(json.dumps(meta))
    return "unknown schema 'radiance-dataset/99'"


def _bad_empty(h, d):
    h.unprotect(d)
    (d / "radiance.csv").write_text("")
    return "radiance.csv: file is empty"


def _bad_wavelengths(h, d):
    ds = read_dataset(d)
    table = ds.table.copy()
    table["wavelength_nm"] += 400.0
    from gonio.data import make_dataset
    write_dataset(make_dataset(table, ds.meta), d)
    return "wavelength grids cannot be reconciled"


def _bad_one_sided(h, d):
    ds = read_dataset(d)
    table = ds.to_frame()
    table = table[~((table["theta_i"] == 0) & (table["s"] < 0))].drop(columns="s")
    from gonio.data import make_dataset
    write_dataset(make_dataset(table, ds.meta), d)
    return "found source side s < 0: []"


def _bad_header_only(h, d):
    h.unprotect(d)
    _edit_csv(d, lambda ls: ls[:1])
    return "no data rows"


def _bad_missing_dir(h, d):
    shutil.rmtree(d)
    return "no such dataset directory"


def _bad_deep_meta(h, d):
    text = (d / "meta.json").read_text().rstrip()
    (d / "meta.json").write_text(text[:-1] + ', "x": ' + "[" * 100000 + "]" * 100000 + "}")
    return "meta.json: nested too deeply"


def _bad_fifo(h, d):
    os.unlink(d / "radiance.csv")
    os.mkfifo(d / "radiance.csv")
    return "radiance.csv: is a FIFO (named pipe), not a regular file"


def _bad_huge_u(h, d):
    h.unprotect(d)
    _edit_csv(d, lambda ls: ls[:5] + [",".join(ls[5].split(",")[:6] + ["1e308"]
                                               + ls[5].split(",")[7:])] + ls[6:])
    return "column 'u_beta': value 1e+308 is not a plausible standard uncertainty"


def _bad_huge_beta(h, d):
    h.unprotect(d)
    _edit_csv(d, lambda ls: [ls[0]] + [",".join(x.split(",")[:5] + ["1e308"] + x.split(",")[6:])
                                       for x in ls[1:]])
    return "column 'beta': value 1e+308 is not a plausible radiance coefficient"


BAD = {"deep meta": _bad_deep_meta, "every beta 1e308": _bad_huge_beta, "FIFO": _bad_fifo, "huge u_beta": _bad_huge_u,
       "missing column": _bad_missing_column, "NaN": _bad_nan, "duplicate": _bad_duplicate,
       "unknown schema": _bad_schema, "empty file": _bad_empty,
       "mismatched wavelengths": _bad_wavelengths, "one-sided normal": _bad_one_sided,
       "missing directory": _bad_missing_dir, "header only": _bad_header_only}


@pytest.mark.parametrize("command", ["check", "report"])
@pytest.mark.parametrize("which", ["measured", "simulated"])
@pytest.mark.parametrize("kind", sorted(BAD))
def test_bad_input_exits_2_with_a_clear_message(h, tmp_path, kind, which, command):
    meas, sim = _good_pair(h, tmp_path)
    target = meas if which == "measured" else sim
    expected = BAD[kind](h, target)
    argv = [command, meas, sim] + (["--out", tmp_path / "out"] if command == "report" else [])
    code, out, err = _quiet_main(argv)
    assert code == 2, out + err
    assert err.startswith(f"compare {command}: error: ") and err.count("\n") == 1, err
    assert expected in err
    if kind not in ("mismatched wavelengths",):
        assert str(target) in err  # names the dataset
    assert "Traceback" not in err
    assert not (tmp_path / "out" / "report.html").exists()


def test_usage_errors_and_help(h, capsys):
    assert h.run_cli(["--help"], capsys)[0] == 0
    status, out, _ = h.run_cli(["check", "--help"], capsys)
    assert status == 0 and "--max-nrmse" in out and "default 0.1" in out
    assert h.run_cli([], capsys)[0] == 2
    assert h.run_cli(["report", h.FIXTURES / "measured_red"], capsys)[0] == 2
    status, _, err = h.run_cli(["check", h.FIXTURES / "measured_red", h.FIXTURES / "sim_scaled",
                                "--max-nrmse", "-1"], capsys)
    assert status == 2 and "must be a number >= 0" in err


def test_console_script_reports_bad_input_without_traceback(h, tmp_path):
    meas, sim = _good_pair(h, tmp_path)
    _bad_schema(h, sim)
    exe = Path(sys.executable).with_name("compare")
    proc = subprocess.run([str(exe), "check", str(meas), str(sim)], capture_output=True,
                          text=True, timeout=900)
    assert proc.returncode == 2
    assert "unknown schema" in proc.stderr and "Traceback" not in proc.stderr
    assert proc.stderr.count("\n") == 1


@pytest.mark.parametrize("which, expected", [
    ("measured", "has 1 wavelength(s); a comparison needs a spectrum of at least 3"),
    ("simulated", "wavelength grids cannot be reconciled"),
])
def test_single_point_dataset_is_refused(h, tmp_path, capsys, which, expected):
    from gonio.data import make_dataset

    meas, sim = _good_pair(h, tmp_path)
    target = meas if which == "measured" else sim
    ds = read_dataset(target)
    write_dataset(make_dataset(ds.table.iloc[:1], ds.meta), target)
    status, out, err = h.run_cli(["check", meas, sim], capsys)
    assert status == 2 and expected in err and str(target) in err


def test_report_into_a_file_is_an_input_error(h, tmp_path, capsys):
    blocker = tmp_path / "taken"
    blocker.write_text("not a directory")
    status, out, err = h.run_cli(["report", h.FIXTURES / "measured_red",
                                  h.FIXTURES / "sim_scaled", "--out", blocker], capsys)
    assert status == 2 and str(blocker) in err and "Traceback" not in err


def _incomplete(h, tmp_path, measured=17, planned=53):
    ds = read_dataset(h.FIXTURES / "measured_red")
    ds.meta = {**ds.meta, "provenance": {**ds.meta["provenance"], "complete": False,
                                         "points_measured": measured, "points_planned": planned}}
    return write_dataset(ds, tmp_path / "incomplete")


def test_check_refuses_an_incomplete_measurement_saying_what_is_missing(h, tmp_path):
    meas = _incomplete(h, tmp_path)
    code, out, err = _quiet_main(["check", meas, h.FIXTURES / "sim_scaled"])
    assert code == 1, out + err
    assert "FAIL measured dataset 'analytic red lobe'" in out
    assert "17 of 53 planned points measured (36 = 68% missing)" in out
    assert "--allow-incomplete" in out and "ok   overall" not in out
    code, out, err = _quiet_main(["check", meas, h.FIXTURES / "sim_scaled", "--allow-incomplete",
                                  "--max-level-ratio", "4"])
    assert code == 0, out + err
    assert "note: measured dataset 'analytic red lobe'" in out and "ok   overall NRMSE" in out


def test_report_of_an_incomplete_measurement_has_a_banner(h, tmp_path):
    meas = _incomplete(h, tmp_path)
    code, out, err = _quiet_main(["report", meas, h.FIXTURES / "sim_scaled", "--out",
                                  tmp_path / "rep"])
    assert code == 0, out + err
    text = (tmp_path / "rep" / "report.html").read_text()
    assert "class='banner'" in text
    assert "Incomplete data" in text and "17 of 53 planned points measured" in text


def test_report_of_a_complete_measurement_has_no_banner(h, report):
    """The module's report (complete datasets, none the measured itself) has none of the banners above."""
    assert read_dataset(h.FIXTURES / "measured_red").complete
    assert report["status"] == 0, report["stderr"]
    assert "class='banner'" not in (report["out"] / "report.html").read_text(encoding="utf-8")


def test_report_of_a_dataset_against_itself_has_a_banner(h, tmp_path):
    code, out, err = _quiet_main(["report", h.FIXTURES / "measured_red",
                                  h.FIXTURES / "measured_red", "--out", tmp_path / "rep"])
    assert code == 0, out + err
    text = (tmp_path / "rep" / "report.html").read_text()
    assert "<p class='banner'>" in text and "is the measured dataset itself (the same directory)" \
        in html.unescape(text)


@pytest.mark.parametrize("how", ["same directory", "copy"])
def test_comparing_a_dataset_with_itself_warns(h, tmp_path, caplog, how):
    meas = h.FIXTURES / "measured_red"
    other = meas if how == "same directory" else shutil.copytree(meas, tmp_path / "copy")
    with caplog.at_level(logging.WARNING, logger="compare"):
        code, out, err = _quiet_main(["check", meas, other])
    assert code == 0
    expected = "the same directory" if how == "same directory" else "the same radiance.csv content"
    assert any("with itself" in r.getMessage() and expected in r.getMessage()
               for r in caplog.records), caplog.text
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="compare"):
        _quiet_main(["check", meas, h.FIXTURES / "sim_scaled"])
    assert not any("with itself" in r.getMessage() for r in caplog.records)
