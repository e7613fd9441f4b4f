"""Plan reader: schema, defaults, presets, geometry convention, refusals, ordering, fuzzing."""

from __future__ import annotations

from itertools import pairwise

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fabric_optics.cli.gonio import main
from gonio.acquisition.plan import PlanError, load_plan, parse_plan, preset_names
from gonio.data import geometry as G


def test_presets_load_by_name_and_meet_the_contract():
    assert {"red-cotton", "quick"} <= set(preset_names())
    rc = load_plan("red-cotton")
    assert rc.incidence_deg == [0, 30, 45, 60]
    assert rc.in_plane_deg == [float(x) for x in range(-60, 71, 10)]
    np.testing.assert_allclose(rc.wavelengths_nm, np.arange(390, 711, 10))
    assert rc.reference_deg == (0.0, 45.0)
    quick = load_plan("quick")
    assert quick.n_measurements <= 40
    assert quick.check().ok and not quick.check().blocked


def test_defaults(tmp_path):
    p = tmp_path / "p.toml"
    p.write_text('[sample]\nname = "x"\n[geometry]\nincidence_deg = [30]\nin_plane_deg = [10]\n')
    plan = load_plan(p)
    np.testing.assert_allclose(plan.wavelengths_nm, np.arange(390, 711, 10))
    assert plan.reference_deg == (0.0, 45.0) and plan.white_standard == "spectralon"
    assert plan.rotation_deg == [0.0] and plan.name == "p"
    assert plan.acquisition.ladder()[0] == (plan.acquisition.itime_ms, plan.acquisition.gain)


def test_geometry_follows_the_in_plane_convention():
    plan = parse_plan(b'[sample]\nname="x"\n[geometry]\nincidence_deg=[30]\nin_plane_deg=[-20,0,40]\n'
                      b'sample_rotation_deg=[0,90]\ndirections_deg=[[45,90],[45,270]]\n')
    g = plan.geometries()
    rows = {tuple(r) for r in g.itertuples(index=False)}
    # s >= 0: phi_o = phi_i + 180; s < 0: phi_o = phi_i; the rotation reading is phi_i
    assert (30, 0, 20, 0) in rows and (30, 0, 40, 180) in rows and (30, 0, 0, 180) in rows
    assert (30, 90, 20, 90) in rows and (30, 90, 40, 270) in rows
    # out of plane: phi_o - phi_i = 90 and 270
    assert (30, 0, 45, 90) in rows and (30, 0, 45, 270) in rows and (30, 90, 45, 0) in rows
    for p in plan.points():
        assert G.axes_to_fabric(*p.axes_deg) == pytest.approx((p.theta_i, p.phi_i, p.theta_o, p.phi_o))


@pytest.mark.parametrize("text,field", [
    ("", "sample"),
    ('[sample]\nname=""\n[geometry]\nincidence_deg=[0]\nin_plane_deg=[10]', "sample.name"),
    ('[sample]\nname="x"\n', "geometry"),
    ('[sample]\nname="x"\n[geometry]\nincidence_deg=[0]', "geometry.in_plane_deg"),
    ('[sample]\nname="x"\n[geometry]\nincidence_deg=["a"]\nin_plane_deg=[1]', "geometry.incidence_deg"),
    ('[sample]\nname="x"\n[geometry]\nincidence_deg=[0]\nin_plane_deg=[1]\nfoo=1', "geometry.foo"),
    ('[sample]\nname="x"\n[wavelengths]\nlist_nm=[300]\n[geometry]\nincidence_deg=[0]\nin_plane_deg=[1]',
     "wavelengths.list_nm"),
    ('[sample]\nname="x"\n[wavelengths]\nstart_nm=500\nstop_nm=400\nstep_nm=10\n[geometry]\n'
     'incidence_deg=[0]\nin_plane_deg=[1]', "wavelengths.stop_nm"),
    ('[sample]\nname="x"\n[geometry]\nincidence_deg=[0]\nin_plane_deg=[1]\n[acquisition]\ngain=7',
     "acquisition.gain"),
    ('[sample]\nname="x"\n[geometry]\nincidence_deg=[0]\nin_plane_deg=[1]\n[acquisition]\nitime_ms=2.5',
     "acquisition.itime_ms"),
    ('[sample]\nname="x"\n[geometry]\nincidence_deg=[0]\nin_plane_deg=[1]\n[calibration]\n'
     'reference_deg=[0]', "calibration.reference_deg"),
    ('[sample\n', None),
])
def test_errors_name_the_file_and_field(tmp_path, text, field):
    p = tmp_path / "bad.toml"
    p.write_text(text)
    with pytest.raises(PlanError) as info:
        load_plan(p)
    msg = str(info.value)
    assert msg.startswith(str(p))
    if field:
        assert f"'{field}'" in msg
    else:
        assert "invalid TOML" in msg


def test_missing_plan_names_the_presets(tmp_path):
    with pytest.raises(PlanError, match="no such plan file.*red-cotton"):
        load_plan(tmp_path / "nope.toml")


def _refusing_plan(tmp_path):
    p = tmp_path / "refuse.toml"
    p.write_text('[sample]\nname="x"\n[geometry]\nincidence_deg=[30, 88]\n'
                 'in_plane_deg=[-32, -28, -25, 10, 87]\n')
    return p


def test_check_lists_blocked_and_out_of_limit_points(tmp_path):
    chk = load_plan(_refusing_plan(tmp_path)).check()
    blocked = {(p.source_deg, p.detector_deg) for p in chk.blocked}
    assert blocked == {(30.0, -32.0), (30.0, -28.0)}        # within 5 deg; -25 is exactly 5: allowed
    bad = {(p.source_deg, p.detector_deg) for p, _ in chk.out_of_limits}
    assert bad == {(30.0, 87.0)} | {(88.0, s) for s in (-32.0, -28.0, -25.0, 10.0, 87.0)}
    assert all("outside the soft limits" in why for _, why in chk.out_of_limits)
    assert {(p.source_deg, p.detector_deg) for p in chk.ordered} == {(30.0, -25.0), (30.0, 10.0)}
    assert not chk.ok


def test_check_plan_cli_exit_status(tmp_path, capsys):
    assert main(["check-plan", "--plan", "quick"]) == 0
    assert main(["check-plan", "--plan", "red-cotton"]) == 0          # blocked points expected (skip_blocked)
    out = capsys.readouterr().out
    assert "beam-block zone (expected, skipped): 3 geometries" in out
    assert main(["check-plan", "--plan", str(_refusing_plan(tmp_path))]) == 1
    out = capsys.readouterr().out
    assert "REFUSED" in out and "theta_i=30 phi_i=0 theta_o=28 phi_o=0" in out
    assert "source_zenith at 88 deg outside the soft limits 0..85 deg" in out
    assert main(["check-plan", "--plan", str(tmp_path / "missing.toml")]) == 2


def test_order_is_serpentine_and_estimate_grows_with_work():
    plan = load_plan("red-cotton")
    chk = plan.check()
    by_incidence = {}
    for p in chk.ordered:
        by_incidence.setdefault(p.source_deg, []).append(p.detector_deg)
    dirs = [np.sign(np.diff(v)).mean() for _, v in sorted(by_incidence.items())]
    assert dirs == [1.0, -1.0, 1.0, -1.0]
    total_detector_travel = sum(abs(a.detector_deg - b.detector_deg)
                                for a, b in pairwise(chk.ordered))
    assert total_detector_travel <= 4 * 130 + 3 * 20
    quick = load_plan("quick").check()
    assert 0 < quick.estimated_s < chk.estimated_s


_KEYS = st.sampled_from(["name", "sample", "wavelengths", "geometry", "acquisition", "calibration",
                         "incidence_deg", "in_plane_deg", "in_plane", "list_nm", "start_nm",
                         "stop_nm", "step_nm", "itime_ms", "gain", "readings", "reference_deg",
                         "directions_deg", "skip_blocked", "white_standard", "start", "stop", "step"])
_LEAF = st.one_of(st.integers(-10**6, 10**6), st.integers(), st.floats(allow_nan=True, allow_infinity=True),
                  st.text(max_size=8), st.booleans(),
                  st.lists(st.one_of(st.integers(-200, 900), st.floats(-1e3, 1e3), st.integers(),
                                     st.floats()), max_size=6))
_TREE = st.recursive(_LEAF, lambda c: st.one_of(st.lists(c, max_size=3),
                                                st.dictionaries(_KEYS, c, max_size=5)),
                     max_leaves=25)


def _to_toml(d: dict) -> str:
    import json
    lines, tables = [], []
    for k, v in d.items():
        if isinstance(v, dict):
            tables.append((k, v))
        else:
            lines.append(f"{k} = {json.dumps(v) if not isinstance(v, bool) else str(v).lower()}")
    for k, v in tables:
        lines.append(f"[{k}]")
        for kk, vv in v.items():
            lines.append(f"{kk} = {json.dumps(vv) if not isinstance(vv, bool) else str(vv).lower()}")
    return "\n".join(lines)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.dictionaries(_KEYS, _TREE, max_size=6))
def test_fuzz_plan_reader_structured(doc):
    try:
        plan = parse_plan(_to_toml(doc), "fuzz.toml")
    except PlanError as exc:
        assert str(exc).startswith("fuzz.toml")
    else:
        assert len(plan.points()) >= 1 and len(plan.wavelengths_nm) >= 1


@settings(max_examples=150, deadline=None)
@given(st.binary(max_size=300))
def test_fuzz_plan_reader_bytes(raw):
    try:
        parse_plan(raw, "fuzz.toml")
    except PlanError as exc:
        assert "fuzz.toml" in str(exc)


def test_geometries_for_simulation_include_unmeasurable_ones():
    plan = load_plan("red-cotton")
    g_all = plan.geometries()
    g_ok = plan.geometries(measurable_only=True)
    assert list(g_all.columns) == ["theta_i", "phi_i", "theta_o", "phi_o"]
    assert len(g_all) == 4 * 14 and len(g_ok) == len(g_all) - 3
    assert ((g_all.theta_i == 0) & (g_all.theta_o == 0)).sum() == 1
    assert ((g_ok.theta_i == 0) & (g_ok.theta_o == 0)).sum() == 0
