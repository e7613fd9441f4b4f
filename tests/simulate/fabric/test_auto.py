"""``--method auto``: the cheapest method whose studied error is within the target, per geometry."""

from __future__ import annotations

import numpy as np
import pytest

from simulate.fabric import auto as methods

STUDY = {
    "provenance": {"command": "test"},
    "geometries": [
        {"theta_i": 0.0, "theta_o": 10.0, "rel_phi_o": 0.0, "classic": 0.02, "summation": 0.01, "mc_rel_se": 0.01},
        {"theta_i": 0.0, "theta_o": 40.0, "rel_phi_o": 0.0, "classic": 0.20, "summation": 0.04, "mc_rel_se": 0.01},
        {"theta_i": 0.0, "theta_o": 70.0, "rel_phi_o": 0.0, "classic": 0.30, "summation": 0.25, "mc_rel_se": 0.01},
    ],
}


def test_cheapest_within_target_per_geometry():
    theta_o = np.array([10.0, 40.0, 70.0, 12.0, 40.0])
    phi_o = np.array([0.0, 0.0, 0.0, 0.0, 90.0])       # the last: 40 deg away from any studied direction
    zeros = np.zeros(5)
    got, prov = methods.choose(zeros, zeros, theta_o, phi_o, 0.05, errors=STUDY)
    assert list(got) == ["classic", "summation", "mc", "classic", "mc"]
    assert prov == {"command": "test"}
    got, _ = methods.choose(zeros, zeros, theta_o, phi_o, 0.015, errors=STUDY)
    assert list(got) == ["summation", "mc", "mc", "summation", "mc"]
    # an incidence the study does not have: the reference method
    got, _ = methods.choose(np.array([30.0]), np.zeros(1), np.array([10.0]), np.zeros(1), 1.0, errors=STUDY)
    assert list(got) == ["mc"]


def test_the_shipped_study_covers_the_red_cotton_plan():
    study = methods.load_errors()
    assert len(study["geometries"]) == 56 and study["provenance"]["reference"] == "woven Monte Carlo"
    for row in study["geometries"]:
        assert 0.0 <= row["classic"] < 5 and 0.0 <= row["summation"] < 5 and 0 < row["mc_rel_se"] < 0.05


@pytest.mark.parametrize("target", [0.001, 10.0])
def test_the_extremes_pick_one_method(target):
    study = methods.load_errors()
    g = study["geometries"]
    ti = np.array([r["theta_i"] for r in g])
    to = np.array([r["theta_o"] for r in g])
    po = np.array([r["rel_phi_o"] for r in g])
    got, _ = methods.choose(ti, np.zeros_like(ti), to, po, target)
    assert set(got) == ({"mc"} if target < 0.01 else {"classic"})
