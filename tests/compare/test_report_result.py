"""The report says its result first: which model is closest to the measurement and by how much on curve
and colour, whether any meets the threshold, and what the threshold means -- before any table."""

from __future__ import annotations

import re

import pytest

from compare.comparison import compare_datasets
from compare.metrics import DEFAULT_MAX_HUE_DIFF, DEFAULT_MAX_NRMSE, DEFAULT_MAX_SAT_DIFF
from compare.report import write_report
from compare.report.page import TRUTH_MODEL, result_sentences
from gonio.data import make_dataset, new_meta, read_dataset

from .conftest import FIXTURES


@pytest.fixture(scope="module")
def fixtures():
    return {name: read_dataset(FIXTURES / name) for name in ("measured_red", "sim_scaled", "sim_lambert", "sim_grey")}


def _sentences(measured, simulated):
    comparison = compare_datasets(measured, simulated)
    return comparison, result_sentences(comparison, comparison.metrics())


def test_the_closest_model_its_distance_and_the_verdict(fixtures):
    comparison, s = _sentences(fixtures["measured_red"], [fixtures["sim_grey"], fixtures["sim_lambert"],
                                                          fixtures["sim_scaled"]])
    metrics = comparison.metrics()
    assert len(s) == 3
    # the scaled model is the measurement times 3.7: after normalisation it is exact
    assert s[0].startswith("Closest to the measurement is 'scaled model'")
    nrmse_lambert = metrics["overall"]["lambertian model"]["nrmse"]
    assert abs(nrmse_lambert - 0.499089) < 1e-5                       # fixtures/analytic/README.md, by hand
    assert "next: 'lambertian model', NRMSE 0.499" in s[0]
    assert "0.000 turn in hue and 0.000 in saturation" in s[0]
    assert s[1] == "'scaled model' meets the threshold."
    assert f"{DEFAULT_MAX_NRMSE:g}" in s[2] and f"{DEFAULT_MAX_HUE_DIFF:g} turn" in s[2] \
        and f"{DEFAULT_MAX_SAT_DIFF:g}" in s[2]


def test_none_meets_the_threshold(fixtures):
    comparison, s = _sentences(fixtures["measured_red"], [fixtures["sim_grey"], fixtures["sim_lambert"]])
    metrics = comparison.metrics()
    # the lambertian model has the measurement's colour, the grey one none: lambertian is closest
    assert s[0].startswith("Closest to the measurement is 'lambertian model': its curves are off by an "
                           "overall NRMSE of 0.499")
    dh, ds = metrics["colour"]["lambertian model"]["dh"], metrics["colour"]["lambertian model"]["ds"]
    assert f"{dh:+.3f}" in s[0] or round(dh, 3) == 0
    assert f"{ds:+.3f}" in s[0] or round(ds, 3) == 0
    assert s[1] == "No model meets the threshold."


def test_one_model(fixtures):
    _, s = _sentences(fixtures["measured_red"], [fixtures["sim_lambert"]])
    assert s[0].startswith("The only model, 'lambertian model'") and "next:" not in s[0]
    assert s[1] == "It does not meet the threshold."


def test_the_mock_truth_is_not_ranked_as_a_model(fixtures):
    measured = fixtures["measured_red"]
    truth = make_dataset(measured.table.copy(), new_meta("simulated", {"name": "truth"}, {"name": TRUTH_MODEL},
                                                         {}, created="2026-01-01T00:00:00+00:00"))
    _, s = _sentences(measured, [truth, fixtures["sim_lambert"], fixtures["sim_grey"]])
    assert "'truth'" not in s[0] and "lambertian model" in s[0]


def test_the_result_comes_before_any_table(fixtures, tmp_path):
    comparison = compare_datasets(fixtures["measured_red"], [fixtures["sim_lambert"], fixtures["sim_grey"]])
    write_report(comparison, tmp_path / "report")
    page = (tmp_path / "report" / "report.html").read_text(encoding="utf-8")
    result = page.index("<section class='result'")
    assert result < page.index("<table") and result < page.index("<h2>")
    paragraph = re.sub(r"<[^>]+>", "", page[result:page.index("</section>", result)])
    assert "Closest to the measurement is" in paragraph and "No model meets the threshold." in paragraph
    assert "The threshold" in paragraph


def test_no_result_when_only_the_truth_is_compared(fixtures):
    measured = fixtures["measured_red"]
    truth = make_dataset(measured.table.copy(), new_meta("simulated", {"name": "truth"}, {"name": TRUTH_MODEL},
                                                         {}, created="2026-01-01T00:00:00+00:00"))
    _, s = _sentences(measured, [truth])
    assert s == []
