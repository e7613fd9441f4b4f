"""`gonio truth`: the mock sample's known answer, written at a plan's measurable geometries."""

from __future__ import annotations

import numpy as np

from fabric_optics.cli.gonio import main
from gonio.acquisition.plan import load_plan
from gonio.data import read_dataset
from gonio.mock.samples import RedCottonSample


def test_lambert_truth_is_flat_on_the_plan_geometries(tmp_path, capsys):
    assert main(["truth", "lambert:0.37", "--plan", "quick", "--out", str(tmp_path / "t")]) == 0
    ds = read_dataset(tmp_path / "t")
    plan = load_plan("quick")
    assert ds.kind == "simulated"
    np.testing.assert_array_equal(ds.table["beta"], 0.37)
    np.testing.assert_array_equal(ds.wavelengths_nm, np.sort(plan.wavelengths_nm))
    expected = plan.geometries(measurable_only=True)
    assert len(ds.geometries()) == len(expected.drop_duplicates())
    assert "quick" in capsys.readouterr().out


def test_red_cotton_truth_matches_the_sample(tmp_path):
    assert main(["truth", "red-cotton", "--plan", "red-cotton", "--out", str(tmp_path / "t")]) == 0
    t = read_dataset(tmp_path / "t").table
    expected = RedCottonSample().beta(t.theta_i, t.phi_i, t.theta_o, t.phi_o, t.wavelength_nm)
    np.testing.assert_allclose(t["beta"], expected, rtol=1e-9)
    # the beam-blocked normal/normal geometry is never in the truth either
    assert not ((t.theta_i == 0) & (t.theta_o == 0)).any()


def test_unknown_sample_is_a_usage_error(tmp_path, capsys):
    assert main(["truth", "velvet", "--plan", "quick", "--out", str(tmp_path / "t")]) == 2
    assert "unknown sample 'velvet'" in capsys.readouterr().err
    assert not (tmp_path / "t").exists()
