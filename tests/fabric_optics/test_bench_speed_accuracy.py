"""``simulate bench --study speed-accuracy`` on a tiny budget: the chart's data shows what it claims.

Not a timing test: it checks that the Monte Carlo's achieved error (two seeds' difference, the
target's definition) falls as the target tightens, beyond a few of its sampling spreads, and that
the report splits the cost as the chart draws it.
"""

from __future__ import annotations

import json
import math

import simulate.raytrace.estimate as E
from fabric_optics.bench import speed_accuracy as sa
from fabric_optics.cli.simulate import main


def test_achieved_error_falls_as_the_target_tightens(tmp_path, capsys, monkeypatch):
    real = sa.run_speed_accuracy
    shipped_floor = E.PILE_TABLE["min_photons"]

    def tiny(*, quick: bool = False, **kw):
        assert quick
        return real(fabrics={"red cotton": (0.4, 0.04)}, wavelengths=3, step=2, in_process=True)

    monkeypatch.setattr(sa, "run_speed_accuracy", tiny)
    assert main(["bench", "--study", "speed-accuracy", "--quick", "--out", str(tmp_path / "b")]) == 0
    report = json.loads((tmp_path / "b" / "speed-accuracy.json").read_text())
    assert (tmp_path / "b" / "speed-accuracy.png").stat().st_size > 0
    loose, tight = report["fabrics"]["red cotton"]["runs"]
    assert (loose["target"], tight["target"]) == (0.4, 0.04)
    # a tenfold tighter target: the achieved error falls, by more than 3 of its sampling spreads
    gap = loose["achieved_error"] - tight["achieved_error"]
    assert gap > 3 * math.hypot(loose["achieved_error_se"], tight["achieved_error_se"]), (loose, tight)
    # with no floor the tighter target builds a larger table
    assert tight["table_photons_per_row"] > loose["table_photons_per_row"]
    for r in (loose, tight):
        assert math.isclose(r["marginal_seconds"], r["table_seconds"] + r["trace_seconds"])
        assert r["setup_seconds"] >= 0 and r["startup_seconds"] >= 0
    floors = report["fabrics"]["red cotton"]["model_floors"]
    assert 0 < floors["summation"] < floors["classic"] < 1
    assert E.PILE_TABLE["min_photons"] == shipped_floor        # the study's floor did not leak
    assert "target 0.04" in capsys.readouterr().out


def test_achieved_error_of_two_runs():
    """Two runs that differ by d at every value: each run's error is d / sqrt 2 of the peak."""
    key = {"theta_i": [0.0, 0.0], "phi_i": [0.0, 0.0], "theta_o": [10.0, 10.0], "phi_o": [180.0, 180.0],
           "wavelength_nm": [500.0, 600.0]}
    a = {**key, "beta": [1.0, 0.5]}
    b = {**key, "beta": [1.2, 0.7]}
    err, se = sa.achieved_error(a, b)
    assert math.isclose(err, 0.2 / math.sqrt(2) / 1.1)
    assert math.isclose(se, err / 2.0)
