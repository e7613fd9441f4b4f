"""Journal (checkpoint) and measurement equation."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gonio.acquisition.calibration import CalibrationError, load_white_standard, parse_white_standard, radiance_factor
from gonio.acquisition.journal import Journal, JournalError, check_consistency, parse_journal, read_journal
from gonio.stats import pooled_mean

_START = {"type": "start", "plan": "p", "plan_sha256": "a", "standard_sha256": "b", "time": 1.0}


def _point(i):
    return {"type": "point", "index": i, "axes_deg": [0, 10.0 * i, 0, 0],
            "geometry": [0, 0, 10.0 * i, 180], "calibration": 0,
            "readings": [{"wavelength_nm": 500.0, "itime_ms": 10, "gain": 0, "mean": 1234.5,
                          "sem": 1.5, "n": 8, "ranging": 0}]}


def test_round_trip_and_fsynced_lines(tmp_path):
    j, content = Journal.open(tmp_path / "j.jsonl")
    assert content.records == [] and not content.torn
    j.append(_START)
    for i in range(3):
        j.append(_point(i))
    j.close()
    data = (tmp_path / "j.jsonl").read_bytes()
    assert data.count(b"\n") == 4 and data.endswith(b"\n")
    c = read_journal(tmp_path / "j.jsonl")
    assert [r["type"] for r in c.records] == ["start", "point", "point", "point"]
    assert c.records[2] == _point(1)


@pytest.mark.parametrize("cut", [1, 10, 40, -2])
def test_torn_last_line_is_detected_and_cut(tmp_path, cut):
    path = tmp_path / "j.jsonl"
    j, _ = Journal.open(path)
    j.append(_START)
    j.append(_point(0))
    j.append(_point(1))
    j.close()
    data = path.read_bytes()
    last_start = data.rstrip(b"\n").rfind(b"\n") + 1
    path.write_bytes(data[:last_start + cut] if cut > 0 else data[:cut])
    c = read_journal(path)
    assert c.torn
    assert [r.get("index") for r in c.of_type("point")] == [0]
    j, c2 = Journal.open(path)                  # the torn line is removed before appending
    j.append(_point(1))
    j.close()
    assert read_journal(path).records == [_START, _point(0), _point(1)]


def test_complete_last_record_without_newline_is_kept(tmp_path):
    path = tmp_path / "j.jsonl"
    path.write_bytes((json.dumps(_START) + "\n" + json.dumps(_point(0))).encode())
    c = read_journal(path)
    assert c.torn and c.missing_newline and len(c.records) == 2
    j, _ = Journal.open(path)
    j.append(_point(1))
    j.close()
    assert len(read_journal(path).records) == 3


@pytest.mark.parametrize("middle,msg", [
    (b"{not json}", "line 2: not a valid JSON record"),
    (b'{"type": "point"}', "line 2: missing field 'index'"),
    (b'{"type": "bogus"}', "line 2: unknown record type"),
    (b'[1, 2]', "line 2: a record must be a JSON object"),
    (b'{"type":"event","what":NaN}', "line 2: not a valid JSON record"),
    (b'{"type":"event","what":"x","v":1e400}', "line 2: a number is not finite"),
])
def test_corruption_before_the_end_is_an_error_naming_the_line(tmp_path, middle, msg):
    path = tmp_path / "j.jsonl"
    path.write_bytes(json.dumps(_START).encode() + b"\n" + middle + b"\n"
                     + json.dumps(_point(0)).encode() + b"\n")
    with pytest.raises(JournalError, match=msg):
        read_journal(path)


def test_refuses_non_finite_values(tmp_path):
    j, _ = Journal.open(tmp_path / "j.jsonl")
    bad = _point(0)
    bad["readings"][0]["mean"] = math.nan
    with pytest.raises(ValueError):
        j.append(bad)
    j.close()


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=400))
def test_fuzz_journal_reader_bytes(raw):
    try:
        c = parse_journal(raw, "fuzz.jsonl")
    except JournalError as exc:
        assert str(exc).startswith("fuzz.jsonl")
    else:
        assert all(isinstance(r, dict) and "type" in r for r in c.records)


_JSONISH = st.recursive(st.one_of(st.none(), st.booleans(), st.integers(), st.text(max_size=5),
                                  st.floats(allow_nan=False), st.just(10**400)),
                        lambda c: st.one_of(st.lists(c, max_size=4),
                                            st.dictionaries(st.sampled_from(
                                                ["type", "index", "geometry", "readings", "what",
                                                 "axes_deg", "calibration", "mean", "n"]), c,
                                                max_size=6)), max_leaves=20)


@settings(max_examples=300, deadline=None)
@given(st.lists(_JSONISH, max_size=5), st.booleans())
def test_fuzz_journal_reader_records(items, newline):
    raw = b"\n".join(json.dumps(x).encode() for x in items) + (b"\n" if newline else b"")
    try:
        content = parse_journal(raw, "fuzz.jsonl")
        check_consistency(content.records, "fuzz.jsonl")
    except JournalError as exc:
        assert str(exc).startswith("fuzz.jsonl: ")


def test_consistency_of_points_and_calibrations():
    cal = {"type": "calibration", "id": 0, "time": 1.0, "plan_sha256": "a", "standard_sha256": "b",
           "idn": "x", "darks": [{"itime_ms": 10, "gain": 0, "mean": 200.0, "sem": 1.0, "n": 8}],
           "reference": [{"wavelength_nm": 500.0, "itime_ms": 10, "gain": 0, "mean": 3e4,
                          "sem": 5.0, "n": 8}]}
    check_consistency([_START, cal, _point(0)])
    with pytest.raises(JournalError, match="line 2: point refers to calibration 0"):
        check_consistency([_START, _point(0), cal])
    other = _point(1)
    other["readings"][0]["itime_ms"] = 20
    with pytest.raises(JournalError, match="line 3: a reading has no dark"):
        check_consistency([_START, cal, other])
    with pytest.raises(JournalError, match="exactly one start record"):
        check_consistency([cal, _START])


def test_radiance_factor_against_direct_evaluation_and_numeric_propagation():
    args = dict(signal=20000.0, u_signal=15.0, dark=220.0, u_dark=2.0, itime_ms=50, gain_factor=4,
                theta_o_deg=60.0, ref_signal=40000.0, u_ref_signal=20.0, ref_dark=210.0,
                u_ref_dark=1.5, ref_itime_ms=100, ref_gain_factor=1, ref_theta_o_deg=45.0,
                beta_ref=0.99, u_beta_ref=0.004)
    beta, u = radiance_factor(**args)
    direct = (0.99 * ((20000 - 220) / (50 * 4)) / ((40000 - 210) / 100)
              * math.cos(math.radians(45)) / math.cos(math.radians(60)))
    assert beta == pytest.approx(direct, rel=1e-12)
    # numeric first-order propagation over the five uncertain inputs
    var = 0.0
    for x, ux in (("signal", "u_signal"), ("dark", "u_dark"), ("ref_signal", "u_ref_signal"),
                  ("ref_dark", "u_ref_dark"), ("beta_ref", "u_beta_ref")):
        h = args[ux] * 1e-3
        plus = dict(args, **{x: args[x] + h})
        minus = dict(args, **{x: args[x] - h})
        d = (radiance_factor(**plus)[0] - radiance_factor(**minus)[0]) / (2 * h)
        var += (d * args[ux]) ** 2
    assert u == pytest.approx(math.sqrt(var), rel=1e-6)


def test_radiance_factor_recovers_a_forward_model_and_is_vectorised():
    rng = np.random.default_rng(0)
    beta_true = rng.uniform(0.01, 1.5, 50)
    theta_o = rng.uniform(0, 80, 50)
    K, t, G, tr, Gr, bref = 300.0, 20.0, 16.0, 100.0, 1.0, 0.99
    S = 200 + K * t * G * beta_true * np.cos(np.radians(theta_o))
    Sr = 200 + K * tr * Gr * bref * np.cos(np.radians(45))
    beta, u = radiance_factor(S, 0, 200, 0, t, G, theta_o, Sr, 0, 200, 0, tr, Gr, 45, bref, 0.0)
    np.testing.assert_allclose(beta, beta_true, rtol=1e-12)
    assert np.all(u == 0)


def test_pooled_mean_equals_the_statistics_of_the_concatenated_data():
    rng = np.random.default_rng(1)
    parts = [rng.normal(100, 5, 8), rng.normal(102, 5, 8), rng.normal(99, 5, 8)]
    mean, sem, n = pooled_mean([p.mean() for p in parts], [p.std(ddof=1) for p in parts], [8] * 3)
    allx = np.concatenate(parts)
    assert n == 24 and mean == pytest.approx(allx.mean())
    assert sem == pytest.approx(allx.std(ddof=1) / math.sqrt(24))


def test_white_standard_table(tmp_path):
    std = load_white_standard("spectralon")
    b, u = std.at([380, 555, 780])
    np.testing.assert_allclose(b, 0.99)
    assert np.all(u > 0)
    with pytest.raises(CalibrationError, match="calibrated over 380..780 nm only"):
        std.at([370])
    p = tmp_path / "s.csv"
    p.write_text("wavelength_nm,beta_ref,u_beta_ref\n400,0.9,0.01\n500,0.95,0.01\n")
    assert load_white_standard("s.csv", base=tmp_path).at(450)[0] == pytest.approx(0.925)
    for text, msg in [("a,b,c\n1,2,3\n", "header"),
                      ("wavelength_nm,beta_ref,u_beta_ref\n400,x,0.1\n500,1,0.1\n", "row 2"),
                      ("wavelength_nm,beta_ref,u_beta_ref\n500,1,0.1\n400,1,0.1\n", "increase"),
                      ("wavelength_nm,beta_ref,u_beta_ref\n400,-1,0.1\n500,1,0.1\n", "beta_ref > 0")]:
        with pytest.raises(CalibrationError, match=msg):
            parse_white_standard(text.encode(), "t.csv")
    with pytest.raises(CalibrationError, match="no such white standard"):
        load_white_standard("nonexistent")


def test_retry_totals_sum_every_session_killed_ones_included(tmp_path):
    from gonio.acquisition.reduce import retry_totals

    start = {"type": "start", "plan": "p", "plan_sha256": "a", "standard_sha256": "b", "time": 0}
    point = {"type": "point", "index": 0, "axes_deg": [0, 45, 0, 0], "geometry": [0, 0, 45, 0],
             "calibration": 0, "readings": []}
    records = [start,
               dict(point, retries={"head_busy": 2}),
               dict(point, retries={"head_busy": 3, "modbus_link_lost": 1}),   # then SIGKILL
               {"type": "event", "what": "resume", "time": 1},
               {"type": "event", "what": "resume", "time": 2},                 # killed at once
               dict(point, retries={"modbus_link_lost": 4}),
               {"type": "event", "what": "session_end", "retries": {"modbus_link_lost": 5,
                                                                    "serial_timeout": 1}}]
    assert retry_totals(records) == ({"head_busy": 3, "modbus_link_lost": 6, "serial_timeout": 1}, 3)
    # journals written before the per-point counts: only the session_end events, as before
    old = [start, point, {"type": "event", "what": "session_end", "retries": {"link_lost": 2}},
           {"type": "event", "what": "resume", "time": 1}, point,
           {"type": "event", "what": "session_end", "retries": {"link_lost": 1}}]
    assert retry_totals(old) == ({"link_lost": 3}, 2)
    # the counts are validated like every field
    j, _ = Journal.open(tmp_path / "j.jsonl")
    with pytest.raises(ValueError, match="retries"):
        j.append(dict(point, retries={"head_busy": -1}))
    j.close()
    with pytest.raises(JournalError, match="retries"):
        parse_journal(json.dumps(dict(point, retries=[1])).encode() + b"\n"
                      + json.dumps(start).encode() + b"\n")
