"""The ring dye's check (docs/scripts/dye_depth_check.py): the note's command runs on a tiny budget, its closed form is
the straight-chord geometry, and it does not overwrite its output."""

from __future__ import annotations

import importlib.util
import json
import math
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def _script():
    spec = importlib.util.spec_from_file_location("dye_depth_check", ROOT / "docs" / "scripts" / "dye_depth_check.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules["dye_depth_check"] = module
    spec.loader.exec_module(module)
    return module


def test_the_closed_form_is_the_chord_geometry():
    """Index-matched (no refraction, no Fresnel): the mean of exp(-mu L_dyed) over the impact parameter b; a ring as
    deep as the fiber is the uniform dye (L = 2 sqrt(1 - b^2)), a core of radius 0 is clear, an opaque fiber lets
    nothing out."""
    s = _script()
    import numpy as np

    b = (np.arange(200_000) + 0.5) / 200_000 * 2.0 - 1.0
    assert s.annulus(1.0, 0.7, 0.0, "ring") == pytest.approx(float(np.mean(np.exp(-0.7 * 2 * np.sqrt(1 - b * b)))),
                                                             rel=1e-6)
    assert s.annulus(1.0, 0.7, 0.0, "core") == pytest.approx(1.0)
    # a ring of depth 1 - a: the chord minus its part inside radius a
    a = 0.5
    inner = 2 * np.sqrt(np.clip(a * a - b * b, 0, None))
    expected = float(np.mean(np.exp(-0.7 * (2 * np.sqrt(1 - b * b) - inner))))
    assert s.annulus(1.0, 0.7, a, "ring") == pytest.approx(expected, rel=1e-6)
    assert s.annulus(1.5, 1e9, 0.0, "ring") == pytest.approx(0.0, abs=1e-12)
    assert 0.0 < s.annulus(1.5, 0.0, a, "ring") < 1.0 and not math.isnan(s.annulus(1.5, 0.7, a, "core"))


def test_the_notes_command_runs_on_a_tiny_budget(tmp_path, capsys):
    s = _script()
    out = tmp_path / "d.json"
    s.main(["--json", str(out), "--shell-target", "0.05", "--mc-target", "0.2", "--methods", ""])
    report = json.loads(out.read_text())
    assert [r["profile"] for r in report["shell"]] == ["ring", "ring", "core", "core"]
    for r in report["shell"]:
        assert abs(r["z"]) < 4 and r["table"] > r["uniform_closed_form"]
    assert len(report["mc"]["z"]) == 2 and report["fits"] == []
    assert "closed form" in capsys.readouterr().out
    with pytest.raises(SystemExit) as e:
        s.main(["--json", str(out)])
    assert e.value.code == 2


@pytest.mark.slow
def test_the_monte_carlo_fit_recovers_a_ring_dyes_depth():
    """The felt Monte Carlo's fit (each run traced at its depth, not re-weighted): a measurement the felt Monte
    Carlo made with the dye in a ring 3 um deep (+1 % noise) is fitted back from 1.2 um within 3 of its reported
    uncertainties, its objective falling, and the start lies beyond that."""
    r = _script().mc_fit(truth=3.0, start=1.2, target=0.2)
    assert r["objective"] < r["objective_start"]
    assert 0 < r["u_um"] < 1.0, r
    assert abs(r["fitted_um"] - 3.0) < 3 * r["u_um"], r
    assert abs(1.2 - 3.0) > 3 * r["u_um"], r
