"""``--method auto`` reads the method-errors table of the config's structure kind."""

from __future__ import annotations

import json
import logging
import math
from importlib import resources
from pathlib import Path

import numpy as np
import pytest

from fabric_optics.bench import method_errors
from gonio.acquisition.plan import load_plan
from simulate import products
from simulate.config import load_config, parse_config
from simulate.fabric import auto

CONFIGS = Path(auto.__file__).resolve().parents[1] / "configs"


def _table(summation: float, classic: float) -> dict:
    """A stand-in table: one geometry (normal incidence, observation 30 deg) with the given errors."""
    return {"provenance": {"study": "stand-in"},
            "geometries": [{"theta_i": 0.0, "theta_o": 30.0, "rel_phi_o": 0.0, "mc_rel_se": 0.001,
                            "summation": summation, "classic": classic}]}


def _without_structure(tmp_path: Path) -> Path:
    text = (CONFIGS / "red-cotton.toml").read_text()
    head, _, rest = text.partition("\n[structure]")
    # drop the [structure] section up to the next table
    tail = rest[rest.index("\n[", 1):] if "\n[" in rest[1:] else ""
    path = tmp_path / "plain.toml"
    path.write_text(head + tail)
    return path


def test_the_table_follows_the_structure_kind(tmp_path):
    assert auto.table_for(load_config("red-cotton")) == "method-errors.json"
    assert auto.table_for(load_config("green-felt")) == "method-errors-felt.json"
    assert auto.table_for(load_config("green-felt-mc")) == "method-errors-felt.json"
    plain = load_config(_without_structure(tmp_path))
    assert plain.structure is None and auto.table_for(plain) is None


def test_a_felt_config_gets_the_felt_table(monkeypatch):
    # stand-ins: the woven table allows the classic model at this geometry, the felt table only the summation
    stand_ins = {"method-errors.json": _table(summation=0.001, classic=0.001),
                 "method-errors-felt.json": _table(summation=0.04, classic=0.5)}
    monkeypatch.setattr(auto, "load_errors", lambda path=None, name="method-errors.json": stand_ins[name])
    felt, woven = load_config("green-felt"), load_config("red-cotton")
    geo = ([0.0], [0.0], [30.0], [0.0])
    assert auto.choose(*geo, 0.05, errors=auto.errors_for(felt))[0].tolist() == ["summation"]
    assert auto.choose(*geo, 0.01, errors=auto.errors_for(felt))[0].tolist() == ["mc"]
    assert auto.choose(*geo, 0.01, errors=auto.errors_for(woven))[0].tolist() == ["classic"]


def test_a_config_of_no_studied_kind_gets_the_monte_carlo_with_the_reason(tmp_path, caplog):
    plain = load_config(_without_structure(tmp_path))
    with caplog.at_level(logging.WARNING, logger="simulate.fabric.auto"):
        errors = auto.errors_for(plain)
    lines = [r.getMessage() for r in caplog.records]
    assert len(lines) == 1 and "no [structure] table" in lines[0] and "Monte Carlo at every geometry" in lines[0]
    # even a huge target: an unknown error is not a small one
    names, prov = auto.choose([0.0, 30.0], [0.0, 0.0], [30.0, 10.0], [0.0, 180.0], 10.0, errors=errors)
    assert names.tolist() == ["mc", "mc"] and prov["reason"] == lines[0] and prov["table"] is None


def test_every_studied_kind_has_its_shipped_table():
    shipped = [s for s in method_errors.STUDIES.values() if s["file"]]
    for study in shipped:
        assert (auto.BLEND_TABLES if "populations" in study else auto.TABLES)[study["kind"]] == study["file"]
    assert set(auto.TABLES) == {s["kind"] for s in shipped if "populations" not in s}
    assert set(auto.BLEND_TABLES) == {s["kind"] for s in shipped if "populations" in s}


def _blend(tmp_path: Path, study: str = "green-felt-blend") -> Path:
    return method_errors.blend_config(study, tmp_path)


def _spread_table(spread: float, summation: float = 0.04) -> dict:
    t = _table(summation=summation, classic=0.5)
    t["provenance"].update(dye_spread=spread, table="stand-in blend table")
    return t


def test_a_felt_blend_within_the_study_reads_the_blend_table(tmp_path, monkeypatch, caplog):
    blend = load_config(_blend(tmp_path))
    assert auto.table_for(blend) == "method-errors-felt-blend.json"
    # the blend table says the summation at 4 %, the one-population felt table only the Monte Carlo
    stand_ins = {"method-errors-felt.json": _table(summation=0.5, classic=0.5),
                 "method-errors-felt-blend.json": _spread_table(auto.dye_spread(blend))}
    monkeypatch.setattr(auto, "load_errors", lambda path=None, name="method-errors.json": stand_ins[name])
    with caplog.at_level(logging.WARNING, logger="simulate.fabric.auto"):
        errors = auto.errors_for(blend)
    assert not caplog.records
    names, prov = auto.choose([0.0], [0.0], [30.0], [0.0], 0.05, errors=errors)
    assert names.tolist() == ["summation"] and prov["config_dye_spread"] == pytest.approx(auto.dye_spread(blend))
    # its one-population felt still reads the felt's own table
    assert auto.choose([0.0], [0.0], [30.0], [0.0], 0.05, errors=auto.errors_for(load_config("green-felt-mc")))[0] \
        .tolist() == ["mc"]


def test_the_shipped_blend_table_holds_its_blends_spread(tmp_path):
    blend = load_config(_blend(tmp_path))
    errors = auto.errors_for(blend)
    prov = errors["provenance"]
    assert prov["table"] == "method-errors-felt-blend.json" and prov["blend"] == "blend-red-x2"
    assert prov["dye_spread"] == pytest.approx(auto.dye_spread(blend)) and prov["populations"].count("[[populations]]") == 2


def test_a_blend_beyond_the_studied_spread_gets_the_monte_carlo_with_the_reason(tmp_path, caplog):
    wider = load_config(_blend(tmp_path, "green-felt-blend-x10"))
    studied = auto.load_errors(name="method-errors-felt-blend.json")["provenance"]["dye_spread"]
    assert auto.dye_spread(wider) > studied
    with caplog.at_level(logging.WARNING, logger="simulate.fabric.auto"):
        errors = auto.errors_for(wider)
    lines = [r.getMessage() for r in caplog.records]
    assert len(lines) == 1 and "dye spread" in lines[0] and "Monte Carlo at every geometry" in lines[0]
    names, prov = auto.choose([0.0, 30.0], [0.0, 0.0], [30.0, 10.0], [0.0, 180.0], 10.0, errors=errors)
    assert names.tolist() == ["mc", "mc"] and prov["reason"] == lines[0]


def test_a_blend_whose_populations_differ_in_more_than_their_dye_gets_the_monte_carlo(tmp_path, caplog):
    path = _blend(tmp_path)
    within = auto.dye_spread(load_config(path))
    path.write_text(path.read_text() + "[populations.particles]\nn = 2.7\nk = 0.0\nradius_um = 0.1\n"
                    "volume_fraction = 0.002\n")
    other = load_config(path)
    assert auto.dye_spread(other) == within        # the same dyes: only the scatterers put it outside
    with caplog.at_level(logging.WARNING, logger="simulate.fabric.auto"):
        errors = auto.errors_for(other)
    lines = [r.getMessage() for r in caplog.records]
    assert len(lines) == 1 and "differ in particles" in lines[0] and "'red-clear' and 'red-x2'" in lines[0]
    assert errors["geometries"] == []


def test_the_dye_spread_is_the_populations_spread_of_transmittance():
    """Two uniform dyes of 0.01 and 0.05 /um in fibers of radius r: transmittances exp(-mu pi r / 2), so the
    50/50 spread is half their difference; a ring 2 um deep holds the dye over its area / 2 r."""
    from simulate.config import parse_config

    head = ('name = "t"\n[fiber]\nradius_um = 8.0\nn_host = 1.5\n[fiber.dye]\nwavelength_nm = [400, 700]\nmu_a_per_um = [0.01, 0.01]\n'
            "[particles]\nn = 1.6\nk = 0.0\nradius_um = 0.1\nvolume_fraction = 0.001\n[surface]\nrms_slope = 0.3\n"
            "[structure]\nkind = \"nonwoven\"\n")

    def pop(name, share, mu, extra=""):
        return (f'[[populations]]\nname = "{name}"\nshare = {share}\n[populations.fiber]\n{extra}'
                f"[populations.fiber.dye]\nwavelength_nm = [400, 700]\nmu_a_per_um = [{mu}, {mu}]\n")

    one = parse_config(head, "t.toml")
    assert auto.dye_spread(one) == 0.0
    same = parse_config(head + pop("a", 0.5, 0.01) + pop("b", 0.5, 0.01), "t.toml")
    assert auto.dye_spread(same) == 0.0
    two = parse_config(head + pop("a", 0.5, 0.01) + pop("b", 0.5, 0.05), "t.toml")
    t1, t2 = math.exp(-0.01 * math.pi * 8.0 / 2), math.exp(-0.05 * math.pi * 8.0 / 2)
    assert auto.dye_spread(two) == pytest.approx(abs(t1 - t2) / 2, rel=1e-12)
    shares = parse_config(head + pop("a", 0.25, 0.01) + pop("b", 0.75, 0.05), "t.toml")
    assert auto.dye_spread(shares) == pytest.approx(math.sqrt(0.25 * 0.75) * abs(t1 - t2), rel=1e-12)
    ring = parse_config(head + pop("a", 0.5, 0.01) + pop("b", 0.5, 0.05, 'dye_profile = "ring"\ndye_depth_um = 2.0\n'),
                        "t.toml")
    t2r = math.exp(-0.05 * math.pi * (64.0 - 36.0) / 16.0)
    assert auto.dye_spread(ring) == pytest.approx(abs(t1 - t2r) / 2, rel=1e-12)


@pytest.mark.parametrize("study", sorted(k for k, v in method_errors.STUDIES.items() if v["file"]))
def test_the_shipped_table_is_its_commands(study):
    st = method_errors.STUDIES[study]
    d = json.loads(resources.files("simulate.configs").joinpath(st["file"]).read_text())
    prov = d["provenance"]
    assert prov["config"] == st["config"] and prov["plan"] == st["plan"] and prov["reference"] == st["reference"]
    assert prov["command"].startswith("python -m fabric_optics.bench.method_errors")
    if study != "red-cotton":
        assert f"--study {study}" in prov["command"] and prov["kind"] == st["kind"]
        # the Monte Carlo's own error is stated: its rays reach the target, its tables' noise adds to it
        assert prov["target_rel_err"] == st["target"] and prov["mc_stop"] == "target"
        assert 0 < prov["mc_rel_err"] < 1.5 * prov["target_rel_err"]
    # one row per geometry of the study's plan, each with both models' departures
    g = load_plan(st["plan"]).geometries()
    plan_keys = {(round(a, 6), round(b, 6), round((c - e) % 360.0, 6))
                 for a, b, c, e in zip(g["theta_i"], g["theta_o"], g["phi_o"], g["phi_i"], strict=True)}
    rows = d["geometries"]
    assert {(round(r["theta_i"], 6), round(r["theta_o"], 6), round(r["rel_phi_o"], 6)) for r in rows} == plan_keys
    assert len(rows) == len(plan_keys)
    for r in rows:
        for m in ("summation", "classic", "mc_rel_se"):
            assert math.isfinite(r[m]) and r[m] >= 0


def test_errors_from_report_names_its_study():
    geo = [{"theta_i": 0.0, "theta_o": 30.0, "rel_phi_o": 0.0, "departure": 0.1, "mc_rel_se": 0.01}]
    report = {"target": 0.03, "departure": {"summation": {"geometries": geo}, "classic": {"geometries": geo}}}
    prov = method_errors.errors_from_report(report, "green-felt")["provenance"]
    assert (prov["study"], prov["kind"], prov["config"], prov["plan"]) == ("green-felt", "nonwoven",
                                                                            "green-felt-mc", "green-felt")
    assert prov["target_rel_err"] == 0.03


def test_the_study_does_not_overwrite_its_output(tmp_path, capsys):
    out = tmp_path / "t.json"
    out.write_text("{}")
    with pytest.raises(SystemExit) as e:
        method_errors.main(["--study", "green-felt", "--out", str(out)])
    assert e.value.code == 2 and "exists; pass --force" in capsys.readouterr().err
    assert out.read_text() == "{}"
    with pytest.raises(SystemExit) as e:
        method_errors.main(["--study", "no-such-fabric"])
    assert e.value.code == 2


def test_simulate_bench_writes_the_felt_table(tmp_path, capsys, monkeypatch):
    from fabric_optics.cli.simulate import main

    calls = []

    def stand_in(study, target=None, threads=None):
        calls.append((study, target))
        return {}, _table(0.02, 0.3), ["stand-in line"]

    monkeypatch.setattr(method_errors, "run", stand_in)
    assert main(["bench", "--study", "method-errors-felt", "--quick", "--out", str(tmp_path / "b")]) == 0
    assert calls == [("green-felt", 0.1)]
    assert json.loads((tmp_path / "b" / "method-errors-felt.json").read_text()) == _table(0.02, 0.3)
    assert "stand-in line" in capsys.readouterr().out
    assert main(["bench", "--study", "method-errors-felt-blend", "--quick", "--out", str(tmp_path / "c")]) == 0
    assert calls[-1] == ("green-felt-blend", 0.1)
    assert json.loads((tmp_path / "c" / "method-errors-felt-blend.json").read_text()) == _table(0.02, 0.3)
    assert main(["bench", "--study", "method-errors-woven-blend", "--quick", "--out", str(tmp_path / "d")]) == 0
    assert calls[-1] == ("red-cotton-blend", 0.1)
    assert json.loads((tmp_path / "d" / "method-errors-woven-blend.json").read_text()) == _table(0.02, 0.3)


def test_a_blend_study_traces_its_config_with_its_populations(tmp_path, monkeypatch):
    """The blend study's runs load the preset with the study's [[populations]] appended; its table records them
    and their dye spread."""
    traced = []

    def child(target, method="mc", seed=None, threads=None, config="", plan_name=""):
        traced.append(load_config(config))
        return {"wall_seconds": 1.0, "rel_err": 0.03, "info": {"stop": "target"}, "table": {}}

    monkeypatch.setattr(method_errors, "in_child", child)
    monkeypatch.setattr(method_errors, "model_datasets", lambda config, plan: traced.append(load_config(config)) or {})
    monkeypatch.setattr(method_errors, "departure", lambda report: {})
    _, errors, _ = method_errors.run("green-felt-blend", target=0.1)
    assert [[p.name for p in c.populations] for c in traced] == [["red-clear", "red-x2"]] * 2
    base = load_config("green-felt-mc")
    assert traced[0].structure == base.structure and traced[0].particles.volume_fraction == base.particles.volume_fraction
    prov = errors["provenance"]
    assert prov["populations"] == method_errors.BLEND_RED_X2 and prov["dye_spread"] == auto.dye_spread(traced[0])
    assert "--study green-felt-blend" in prov["command"]


def test_against_measures_a_tables_departures_from_another(tmp_path, capsys):
    """Two geometries: the summation's departures +0.04 and +0.02 above the base's, each geometry's references
    with errors 0.03 and 0.04 (so 0.05 together): mean +0.03 +- 0.05 sqrt(2) / 2, z 0.8 and 0.4."""
    def row(ti, summation, classic, se):
        return {"theta_i": ti, "theta_o": 30.0, "rel_phi_o": 0.0, "mc_rel_se": se, "summation": summation,
                "classic": classic}

    base = {"geometries": [row(0.0, 0.30, 0.2, 0.03), row(30.0, 0.40, 0.2, 0.03), row(45.0, 0.9, 0.9, 0.03)]}
    table = {"geometries": [row(0.0, 0.34, 0.2, 0.04), row(30.0, 0.42, 0.2, 0.04)]}
    c = method_errors.against(table, base)
    assert c["geometries"] == 2
    s = c["summation"]
    assert s["mean_difference"] == pytest.approx(0.03) and s["median_difference"] == pytest.approx(0.03)
    assert s["se_of_mean"] == pytest.approx(0.05 * math.sqrt(2) / 2) and s["mean_z"] == pytest.approx(0.6)
    assert s["beyond_3_se"] == 0 and c["classic"]["mean_difference"] == pytest.approx(0.0)
    paths = [tmp_path / "t.json", tmp_path / "b.json"]
    for p, t in zip(paths, (table, base), strict=True):
        p.write_text(json.dumps(t))
    method_errors.main(["--compare", str(paths[0]), str(paths[1]), "--json", str(tmp_path / "c.json")])
    assert "summation: departure +0.030 on average" in capsys.readouterr().out
    assert json.loads((tmp_path / "c.json").read_text())["summation"]["mean_z"] == pytest.approx(0.6)


def _departures(name: str) -> dict:
    """A shipped table's departures by geometry."""
    rows = auto.load_errors(name=name)["geometries"]
    return {(r["theta_i"], r["theta_o"], r["rel_phi_o"]): r for r in rows}


def test_a_woven_blend_within_the_study_picks_per_geometry_from_the_woven_departures(tmp_path, caplog):
    """Red cotton as the studied blend: no line logged, its table names the woven blend study and its spread, and at
    each geometry auto takes the cheapest model whose departure in the one-population woven table (the study found
    the blend's the same) is within the target -- the summation where it is, the Monte Carlo elsewhere."""
    blend = load_config(_blend(tmp_path, "red-cotton-blend"))
    assert auto.table_for(blend) == "method-errors-woven-blend.json"
    with caplog.at_level(logging.WARNING, logger="simulate.fabric.auto"):
        errors = auto.errors_for(blend)
    assert not caplog.records
    prov = errors["provenance"]
    assert prov["table"] == "method-errors.json" and prov["blend_study"]["table"] == "method-errors-woven-blend.json"
    assert prov["blend_study"]["dye_spread"] == pytest.approx(auto.dye_spread(blend))
    assert prov["config_dye_spread"] == pytest.approx(auto.dye_spread(blend))
    rows = _departures("method-errors.json")
    keys = sorted(rows)
    ti, to, po = (np.array([k[c] for k in keys]) for c in range(3))
    target = 0.05
    names, _ = auto.choose(ti, np.zeros(ti.size), to, po, target, errors=errors)
    expected = ["classic" if rows[k]["classic"] <= target else "summation" if rows[k]["summation"] <= target else "mc"
                for k in keys]
    assert names.tolist() == expected
    assert {"summation", "mc"} <= set(expected)         # the target splits the plan: the check sees both branches
    products.check_blend(blend, "auto")                  # the Monte Carlo it chooses elsewhere takes the blend


def test_a_woven_blend_reads_the_one_population_departures_not_the_studys(tmp_path, monkeypatch):
    """Stand-ins: the woven blend study allows nothing cheaper than the Monte Carlo, the one-population woven table
    the summation; a woven blend within the study reads the latter, a felt blend its own study."""
    blend = load_config(_blend(tmp_path, "red-cotton-blend"))
    felt = load_config(_blend(tmp_path, "green-felt-blend"))
    stand_ins = {"method-errors.json": _table(summation=0.04, classic=0.5),
                 "method-errors-woven-blend.json": _spread_table(auto.dye_spread(blend), summation=0.5),
                 "method-errors-felt.json": _table(summation=0.04, classic=0.5),
                 "method-errors-felt-blend.json": _spread_table(auto.dye_spread(felt), summation=0.5)}
    monkeypatch.setattr(auto, "load_errors", lambda path=None, name="method-errors.json": json.loads(
        json.dumps(stand_ins[name])))
    geo = ([0.0], [0.0], [30.0], [0.0])
    assert auto.choose(*geo, 0.05, errors=auto.errors_for(blend))[0].tolist() == ["summation"]
    assert auto.choose(*geo, 0.05, errors=auto.errors_for(felt))[0].tolist() == ["mc"]


def test_the_woven_blend_studys_summation_departs_as_the_one_populations():
    """Why a woven blend reads the one-population woven table: at every geometry of the plan the shipped blend
    study's summation departure and the one-population table's differ by no more than their references' errors
    allow (none beyond 3 standard errors, their mean within 3 standard errors of 0)."""
    blend = auto.load_errors(name="method-errors-woven-blend.json")
    one = auto.load_errors(name="method-errors.json")
    c = method_errors.against(blend, one)
    assert c["geometries"] == len(one["geometries"]) == len(blend["geometries"])
    s = c["summation"]
    assert s["beyond_3_se"] == 0 and abs(s["mean_difference"]) < 3 * s["se_of_mean"]


def test_the_shipped_woven_blend_study_holds_its_blends_spread(tmp_path):
    blend = load_config(_blend(tmp_path, "red-cotton-blend"))
    prov = auto.load_errors(name="method-errors-woven-blend.json")["provenance"]
    assert prov["blend"] == "blend-red-x3" and prov["populations"] == method_errors.BLEND_RED_COTTON_X3
    assert prov["dye_spread"] == pytest.approx(auto.dye_spread(blend))
    # the populations differ in their dye only: the woven Monte Carlo takes them
    assert [p.name for p in blend.populations] == ["red", "red-x3"] and auto.blend_outside(blend, {
        "provenance": prov}) is None


def test_a_woven_blend_beyond_the_studied_spread_gets_the_monte_carlo_with_the_reason(tmp_path, caplog):
    """The blend of red cotton and its dye x10 absorbs more differently than the study's: the Monte Carlo at every
    geometry, even where the woven table allows the summation at a huge target, with that line logged."""
    wider = load_config(_blend(tmp_path, "red-cotton-blend-x10"))
    studied = auto.load_errors(name="method-errors-woven-blend.json")["provenance"]["dye_spread"]
    assert auto.dye_spread(wider) > studied
    with caplog.at_level(logging.WARNING, logger="simulate.fabric.auto"):
        errors = auto.errors_for(wider)
    lines = [r.getMessage() for r in caplog.records]
    assert len(lines) == 1 and "dye spread" in lines[0] and "method-errors-woven-blend.json" in lines[0]
    assert lines[0].endswith("the Monte Carlo at every geometry")
    geo = (np.array([0.0, 45.0]), np.zeros(2), np.array([10.0, 30.0]), np.zeros(2))
    chosen, prov = auto.choose(*geo, 0.5, errors)
    assert list(chosen) == ["mc", "mc"] and prov["reason"] == lines[0]
    assert set(auto.choose(*geo, 0.5)[0]) != {"mc"}      # where the woven table would have allowed a cheaper model
    products.check_blend(wider, "auto")


def test_a_woven_blend_whose_populations_differ_in_their_scatterers_gets_the_monte_carlo(caplog):
    text = (CONFIGS / "red-cotton.toml").read_text() + (
        '\n[[populations]]\nname = "a"\nshare = 0.5\n[[populations]]\nname = "b"\nshare = 0.5\n'
        "[populations.particles]\nn = 2.7\nk = 0.0\nradius_um = 0.1\nvolume_fraction = 0.02\n")
    cfg = parse_config(text, "woven-blend.toml")
    assert auto.dye_spread(cfg) == 0.0                   # one dye: only the scatterers put it outside
    with caplog.at_level(logging.WARNING, logger="simulate.fabric.auto"):
        errors = auto.errors_for(cfg)
    reason = errors["provenance"]["reason"]
    assert errors["geometries"] == [] and "differ in particles ('a' and 'b')" in reason and reason in caplog.text


def test_simulate_fabric_auto_on_a_woven_blend_takes_the_summation_where_the_woven_table_allows(tmp_path):
    """The command on the studied woven blend at incidence 0, observation 60 deg either side, 3 %: the woven
    table's summation departures there are within it, so every geometry is the summation's (no Monte Carlo run),
    and the dataset's meta names the table read and the blend study that allowed it."""
    from fabric_optics.cli.simulate import main

    cfg = _blend(tmp_path, "red-cotton-blend")
    plan = tmp_path / "tiny.toml"
    plan.write_text('[sample]\nname = "tiny"\n[wavelengths]\nlist_nm = [550, 650]\n[geometry]\nincidence_deg = [0]\n'
                    "in_plane_deg = [-60, 60]\n")
    rows = _departures("method-errors.json")
    target = 0.03
    assert all(rows[(0.0, 60.0, az)]["summation"] <= target for az in (0.0, 180.0))
    out = tmp_path / "out"
    assert main(["fabric", str(cfg), "--method", "auto", "--target-rel-err", str(target), "--plan", str(plan),
                 "--out", str(out), "--no-progress"]) == 0
    model = json.loads((out / "meta.json").read_text())["model"]
    assert model["method_per_geometry"] == ["summation", "summation"]
    assert model["method_errors"]["table"] == "method-errors.json"
    assert model["method_errors"]["blend_study"]["table"] == "method-errors-woven-blend.json"
