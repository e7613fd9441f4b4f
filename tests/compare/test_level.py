"""The absolute level, which the per-wavelength normalisation hides: judged by ``compare check`` (a model
scaled by 2 fails ``--max-level-ratio``, the unscaled one passes), reported in metrics.json and in words."""

from __future__ import annotations

import contextlib
import io
import json

import pytest

from compare.comparison import compare_datasets
from compare.metrics import DEFAULT_MAX_LEVEL_RATIO
from fabric_optics.cli.compare import main
from gonio.data import make_dataset, new_meta, read_dataset, write_dataset


def _run(argv):
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        status = main([str(a) for a in argv])
    return status, out.getvalue(), err.getvalue()


@pytest.fixture(scope="module")
def pair(tmp_path_factory, h):
    """The analytic measurement and models of the same shape: itself, scaled by 2 and by 1/2."""
    root = tmp_path_factory.mktemp("level")
    measured = read_dataset(h.FIXTURES / "measured_red")
    meas_dir = write_dataset(measured, root / "measured")
    dirs = {}
    for name, factor in (("same", 1.0), ("double", 2.0), ("half", 0.5)):
        table = measured.table.copy()
        table["beta"] = factor * table["beta"]
        table["u_beta"] = 0.001 * table["beta"]
        ds = make_dataset(table, new_meta("simulated", {"name": f"model x{factor:g}"}))
        dirs[name] = write_dataset(ds, root / name)
    return meas_dir, dirs


@pytest.mark.parametrize("which, status", [("same", 0), ("double", 1), ("half", 1)])
def test_check_judges_the_level(pair, which, status):
    meas, dirs = pair
    code, out, err = _run(["check", meas, dirs[which]])
    assert code == status, out + err
    assert "ok   overall NRMSE" in out            # the shape matches in every case
    if status:
        assert "FAIL level ratio max(k_Y, 1/k_Y) = 2 " in out
        assert "matches in shape but not in level" in out
        assert ("2.00 times darker" if which == "half" else "2.00 times brighter") in out
    else:
        assert "ok   level ratio max(k_Y, 1/k_Y) = 1 " in out and "is at the measured level" in out


def test_the_threshold_is_an_option(pair):
    meas, dirs = pair
    assert 1.0 < DEFAULT_MAX_LEVEL_RATIO < 2.0
    code, out, _ = _run(["check", meas, dirs["double"], "--max-level-ratio", "2.5"])
    assert code == 0 and "ok   level ratio" in out


def test_level_figures_in_metrics(pair):
    meas, dirs = pair
    c = compare_datasets(read_dataset(meas), [read_dataset(dirs["double"])])
    level = c.metrics()["normalisation"]["level"]["model x2"]
    assert level["k"] == pytest.approx(0.5, rel=1e-9) and level["ratio"] == pytest.approx(2.0, rel=1e-9)
    assert level["spread"] == pytest.approx(1.0, abs=1e-9) and level["cv"] == pytest.approx(0.0, abs=1e-9)
    assert level["judged"] is True


def test_a_relative_measurement_is_not_judged_on_level(pair, tmp_path):
    meas, dirs = pair
    m = read_dataset(meas)
    m.meta["relative"] = True
    rel = write_dataset(m, tmp_path / "relative")
    code, out, _ = _run(["check", rel, dirs["double"]])
    assert code == 0, out
    assert "level ratio" not in out and "its level is not judged" in out


def test_the_report_says_shape_but_not_level_in_words(pair, tmp_path):
    meas, dirs = pair
    code, out, err = _run(["report", meas, dirs["same"], dirs["double"], "--out", tmp_path / "r"])
    assert code == 0, err
    text = (tmp_path / "r" / "report.html").read_text(encoding="utf-8")
    assert "matches in shape, not in level" in text
    assert "&#x27;model x2&#x27; matches in shape but not in level" in text
    assert text.count("matches in shape but not in level") == 1     # the unscaled model is at the level
    doc = json.loads((tmp_path / "r" / "metrics.json").read_text())
    assert doc["normalisation"]["level"]["model x1"]["ratio"] == pytest.approx(1.0)
