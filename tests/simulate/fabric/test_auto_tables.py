"""``--method auto`` reads the method-errors table of the config's structure kind."""

from __future__ import annotations

import json
import logging
import math
from importlib import resources
from pathlib import Path

import pytest

from gonio.acquisition.plan import load_plan
from simulate.config import load_config
from simulate.fabric import auto
from fabric_optics.bench import method_errors

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
    for study in method_errors.STUDIES.values():
        assert auto.TABLES[study["kind"]] == study["file"]
    assert set(auto.TABLES) == {s["kind"] for s in method_errors.STUDIES.values()}


@pytest.mark.parametrize("study", sorted(method_errors.STUDIES))
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
                 for a, b, c, e in zip(g["theta_i"], g["theta_o"], g["phi_o"], g["phi_i"])}
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
