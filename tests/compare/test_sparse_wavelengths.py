"""A comparison on a few wavelengths (450, 550, 650 nm): the curves and their errors are compared and reported,
and the colour is not stated, saying why (compare.colourmatch.colour_refusal); a grid of samples at most 50 nm
apart (400..700 nm at 50 nm) gets its colour from the spectrum interpolated to 5 nm."""

from __future__ import annotations

import json

import numpy as np
import pytest

from compare.colourmatch import colour_refusal, luminance_weights
from compare.comparison import compare_datasets
from compare.report import write_report

THREE = np.array([450.0, 550.0, 650.0])


def _pair(h, wavelengths):
    meas = h.dataset(h.in_plane_table(h.red_lobe, wavelengths=wavelengths))
    sim = h.dataset(h.in_plane_table(lambda t, s, wl: 0.8 * h.red_lobe(t, s, wl), wavelengths=wavelengths),
                    kind="simulated", name="sim")
    return meas, sim


def test_three_wavelengths_compare_curves_and_say_why_there_is_no_colour(h, tmp_path, caplog):
    meas, sim = _pair(h, THREE)
    with caplog.at_level("WARNING", logger="compare"):
        comparison = compare_datasets(meas, [sim])
    assert comparison.colour is None
    assert any("no colour (H, S, V) is stated" in r.getMessage() and "(450, 550, 650 nm) are up to 100 nm apart"
               in r.getMessage() for r in caplog.records)
    # the curves are compared: a simulation 0.8 x the measurement is normalised onto it per wavelength
    assert comparison.overall["sim"].nrmse < 1e-9
    report = write_report(comparison, tmp_path / "r")
    text = report.read_text()
    assert "No colour statement (no H, S, V): the compared wavelengths (450, 550, 650 nm) are up to 100 nm" in text
    figures = sorted(p.name for p in (tmp_path / "r" / "figures").iterdir())
    assert figures == ["factor.png", "inplane_450nm.png", "inplane_550nm.png", "inplane_650nm.png",
                       "inplane_luminance.png"]
    metrics = json.loads((tmp_path / "r" / "metrics.json").read_text())
    assert metrics["colour"] == {} and "up to 100 nm apart" in metrics["colour_note"]
    assert metrics["curves"]["sim"] and metrics["overall"]["sim"]["nrmse"] == pytest.approx(0.0, abs=1e-9)


def test_compare_report_on_three_wavelengths_exits_0_with_a_warning(h, tmp_path, capsys, caplog):
    meas, sim = _pair(h, THREE)
    from gonio.data import write_dataset

    write_dataset(meas, tmp_path / "m")
    write_dataset(sim, tmp_path / "s")
    status, out, err = h.run_cli(["report", tmp_path / "m", tmp_path / "s", "--out", tmp_path / "r"], capsys)
    assert status == 0 and "report:" in out and "Traceback" not in err
    assert any("no colour (H, S, V) is stated" in r.getMessage() for r in caplog.records)   # the warning line


def test_the_rule_states_colour_on_an_astm_grid_or_samples_at_most_50_nm_apart():
    assert colour_refusal(np.arange(400.0, 701.0, 50.0)) is None          # interpolated to 5 nm
    assert colour_refusal(np.arange(390.0, 711.0, 10.0)) is None          # ASTM E308 as it is
    assert colour_refusal(np.arange(480.0, 581.0, 20.0)) is None          # a narrow 20 nm grid, as before
    assert colour_refusal([400.0, 430.0, 470.0, 520.0, 560.0, 610.0, 650.0, 700.0]) is None   # uneven, <= 50 nm
    assert "up to 150 nm apart" in colour_refusal([400.0, 550.0, 700.0])
    assert "up to 60 nm apart" in colour_refusal([400.0, 460.0, 500.0])


def test_luminance_on_a_coarse_grid_is_the_interpolated_spectrum_s(h):
    """Y of a spectrum given at 450/550/650 is the Y of that spectrum interpolated linearly to 5 nm."""
    fine = np.arange(450.0, 651.0, 5.0)
    beta = np.array([0.2, 0.5, 0.9])
    y_coarse = luminance_weights(THREE) @ beta
    y_fine = luminance_weights(fine) @ np.interp(fine, THREE, beta)
    assert y_coarse == pytest.approx(y_fine, rel=1e-12)
    assert luminance_weights(THREE).sum() == pytest.approx(1.0, abs=1e-9)     # the white diffuser: Y = 1


def test_a_50_nm_comparison_gets_its_colour_from_the_interpolated_spectrum(h):
    meas, sim = _pair(h, np.arange(400.0, 701.0, 50.0))
    comparison = compare_datasets(meas, [sim])
    assert comparison.colour is not None and comparison.colour_note == ""
    # the measured colour of the red dye: hue near red (h within 0.1 turn of 0)
    h_meas = comparison.colour.measured.h
    assert min(h_meas, 1.0 - h_meas) < 0.1
