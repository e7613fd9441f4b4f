"""``simulate bench --study NAME``: the documented studies, run on a tiny budget."""

from __future__ import annotations

import json

from fabric_optics.bench import felt as felt_study
from fabric_optics.cli.simulate import main


def test_the_felt_study_through_the_command(tmp_path, capsys, monkeypatch):
    """The felt study on a tiny budget: its JSON and its lines; the deposited felt has no buried fiber surface,
    and clearer fibers return more light in both models (beyond their standard errors)."""
    real = felt_study.run_felt_study

    def tiny(*, quick: bool = False, **kw):
        assert quick
        return real(quick=True, layers=2, target_rel_err=0.2, **kw)

    monkeypatch.setattr(felt_study, "run_felt_study", tiny)
    assert main(["bench", "--study", "felt", "--quick", "--out", str(tmp_path / "b")]) == 0
    out = capsys.readouterr().out
    report = json.loads((tmp_path / "b" / "felt.json").read_text())
    assert report["study"] == "felt" and report["felt"]["buried_surface_fraction"] == 0.0
    rows = {r["mu_a_per_um"]: r for r in report["rows"]}
    assert sorted(rows) == [0.0, 0.01]
    for key in ("mc", "summation"):
        dark, clear = rows[0.01], rows[0.0]
        assert dark[key] > 0 and clear[key] - dark[key] > 2 * (clear["u_" + key] + dark["u_" + key]), key
    assert out.count("felt MC") == 2 and "fiber surface inside another fiber 0.0000" in out


def test_an_unknown_study_is_a_usage_error(tmp_path, capsys):
    code = main(["bench", "--study", "nope", "--out", str(tmp_path / "b")])
    assert code == 2 and "invalid choice: 'nope'" in capsys.readouterr().err
