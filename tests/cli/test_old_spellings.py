"""Spellings the command lines do not have are refused: one usage line on stderr, exit 2.

Each has one spelling (:mod:`fabric_optics.cli.common`): ``--plan`` (no positional PLAN, no
``--geometry``), the positional MEASURED of ``simulate sweep``, ``simulate fiber --route`` and
``simulate fit --method mc --max-runs``.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from fabric_optics.cli.gonio import build_parser as gonio_parser
from fabric_optics.cli.simulate import build_parser as simulate_parser

#: (parser, argv with an old spelling, the spelling named in the error)
CASES = [
    (gonio_parser, ["acquire", "quick", "--modbus", "tcp://h:1", "--serial", "pty", "--out", "o"], "quick"),
    (gonio_parser, ["replay", "t.jsonl", "quick", "--out", "o"], "quick"),
    (gonio_parser, ["truth", "red-cotton", "quick", "--out", "o"], "quick"),
    (gonio_parser, ["check-plan", "quick", "--list"], "quick"),
    (gonio_parser, ["import", "rgl-bsdf", "f.bsdf", "--geometry", "quick", "--out", "o"], "--geometry"),
    (simulate_parser, ["fabric", "red-cotton", "--method", "classic", "--geometry", "quick", "--out", "o"],
     "--geometry"),
    (simulate_parser, ["sweep", "red-cotton", "--param", "rms_slope=0.2,0.3", "--measured", "m", "--out", "o"],
     "--measured"),
    (simulate_parser, ["fiber", "red-cotton", "--method", "beam", "--out", "o"], "--method"),
]


@pytest.mark.parametrize("build, argv, named", CASES, ids=[" ".join(c[1][:1] + [c[2]]) for c in CASES])
def test_an_old_spelling_is_one_usage_line(build, argv, named, capsys):
    with pytest.raises(SystemExit) as info:
        build().parse_args(argv)
    assert info.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 or err[0].startswith("usage:"), err
    assert "unrecognized arguments" in err[-1] and named in err[-1]


def test_max_evaluations_with_mc_is_refused(monkeypatch, tmp_path, capsys):
    """``simulate fit --method mc --max-evaluations N`` names --max-runs, before any fit is prepared."""
    from fabric_optics import api
    from fabric_optics.cli.simulate import main

    calls = []
    monkeypatch.setattr(api, "prepare_fit", lambda *a, **k: calls.append(a))
    measured = str(Path(__file__).parents[2] / "fixtures" / "recorded" / "quick-lambert")
    argv = ["fit", "red-cotton", measured, "--method", "mc", "--free", "dye", "--out", str(tmp_path / "o"),
            "--max-evaluations", "3"]
    assert main(argv) == 2
    assert capsys.readouterr().err == ("simulate fit: error: --max-evaluations 3: --method mc counts Monte Carlo "
                                       "runs; give --max-runs N instead\n")
    assert calls == []
