"""The virtual goniophotometer: datasets at a plan's geometries (fake fiber, exact values)."""

from __future__ import annotations

import numpy as np
import pytest

from gonio.acquisition.plan import load_plan, parse_plan
from gonio.data.dataset import read_dataset, write_dataset
from simulate import fabric as fab
from simulate.config import load_config
from simulate.virtual import GENERATOR, fabric_dataset

from .conftest import PHOTONS, REL_ERR, carpet_config, fake_R, fake_rho, fake_surface

SMALL_PLAN = """
name = "small"
[sample]
name = "test fabric"
[wavelengths]
list_nm = [450, 550, 650]
[geometry]
incidence_deg = [0, 40]
sample_rotation_deg = [0, 30]
in_plane_deg = [-20, 0, 20, 50]
directions_deg = [[30, 90]]
skip_blocked = true
"""


def _keyed(frame):
    cols = ["theta_i", "phi_i", "theta_o", "phi_o"]
    return {tuple(np.round(r, 6)) for r in frame[cols].to_numpy()}


def test_summation_dataset_has_the_plan_geometries_and_exact_values(fake_fiber, tmp_path):
    config = carpet_config()
    plan = parse_plan(SMALL_PLAN, "small.toml")
    ds = fabric_dataset(config, plan, "summation", seed=7)
    write_dataset(ds, tmp_path / "sum")
    back = read_dataset(tmp_path / "sum")  # validates
    assert back.kind == "simulated"
    np.testing.assert_array_equal(back.wavelengths_nm, [450.0, 550.0, 650.0])
    assert _keyed(back.geometries()) == _keyed(plan.geometries())
    # ONE volume_brdf call, only the unique pairs, only the plan's wavelengths, the seed passed on
    assert len(fake_fiber.volume_calls) == 1
    call = fake_fiber.volume_calls[0]
    np.testing.assert_array_equal(call["wavelengths_nm"], [450.0, 550.0, 650.0])
    assert call["seed"] == 7 and call["method"] == config.route
    assert call["w_in"].shape[0] < 2 * len(plan.geometries())
    # values: beta = pi/cos_i * 1/2 sum_k (R_surf + R_vol)(M_k w_i, M_k w_o), by the direct route
    t = back.table
    w_i = fab.directions_deg(t["theta_i"], t["phi_i"])
    w_o = fab.directions_deg(t["theta_o"], t["phi_o"])

    def R_B(a, b):
        return fake_R(a, b, t["wavelength_nm"].to_numpy()) + fake_surface(a, b)[:, None]

    expected = np.diagonal(fab.summation_beta(R_B, w_i, w_o))  # each row at its own wavelength
    np.testing.assert_allclose(t["beta"], expected, rtol=1e-8)
    assert np.all(t["u_beta"] > 0) and np.all(t["n"] == PHOTONS)
    prov = back.meta["provenance"]
    assert prov["seed"] == 7 and prov["photons"] == PHOTONS
    assert prov["config"]["name"] == "red-cotton" and "[fiber]" in prov["config"]["text"]
    assert prov["plan"]["name"] == "small" and prov["beam_blocked"] == "simulated"
    # the one relative error (u over each geometry's spectral peak) is never above the pointwise
    # u / beta, which the fake holds at REL_ERR per fiber value
    assert 0 < prov["rel_err"] <= REL_ERR + 1e-12 and "peak" in prov["rel_err_definition"]
    assert prov["fiber_info"]["array"] == [0, 1, 2]
    assert back.meta["model"]["generator"] == GENERATOR


def test_measurable_only_skips_the_beam_blocked_points(fake_fiber):
    plan = parse_plan(SMALL_PLAN, "small.toml")
    ds = fabric_dataset(carpet_config(), plan, "summation", measurable_only=True)
    assert _keyed(ds.geometries()) == _keyed(plan.geometries(measurable_only=True))
    assert len(plan.check().blocked) > 0
    assert len(ds.geometries()) == len(plan.geometries()) - len(plan.check().blocked)


def test_classic_dataset_is_rho_plus_pi_f_ct(fake_fiber, tmp_path):
    config = load_config("red-cotton")
    plan = load_plan("red-cotton")
    ds = fabric_dataset(config, plan, "classic", seed=3)
    write_dataset(ds, tmp_path / "classic")
    back = read_dataset(tmp_path / "classic")
    assert _keyed(back.geometries()) == _keyed(plan.geometries())
    np.testing.assert_array_equal(back.wavelengths_nm, plan.wavelengths_nm)
    assert len(fake_fiber.albedo_calls) == 1 and fake_fiber.albedo_calls[0]["seed"] == 3
    assert not fake_fiber.volume_calls
    t = back.table
    w_i = fab.directions_deg(t["theta_i"], t["phi_i"])
    w_o = fab.directions_deg(t["theta_o"], t["phi_o"])
    from simulate.optics.microfacet import cook_torrance

    expected = fake_rho(t["wavelength_nm"]) + np.pi * cook_torrance(w_i, w_o, config.rms_slope, config.n_host)
    np.testing.assert_allclose(t["beta"], expected, rtol=1e-8)
    np.testing.assert_allclose(t["u_beta"], REL_ERR * fake_rho(t["wavelength_nm"]), rtol=1e-8)
    np.testing.assert_allclose(back.meta["model"]["rho_d"], fake_rho(plan.wavelengths_nm))


def test_unknown_method_is_refused(fake_fiber):
    with pytest.raises(ValueError, match="summation, classic, mc"):
        fabric_dataset(load_config("red-cotton"), load_plan("red-cotton"), "woven")


def test_the_sample_is_the_plans_only_when_the_plan_is_made_for_the_config(fake_fiber):
    """`--plan` lends a plan's geometries; a plan of another name does not name the sample simulated."""
    import dataclasses

    config = carpet_config()                                  # "red-cotton"
    plan = parse_plan(SMALL_PLAN, "small.toml")               # "small", sample "test fabric"
    lent = fabric_dataset(config, plan, "summation", seed=7).meta["sample"]
    assert lent["name"] == "red-cotton: summation model" and "test fabric" not in lent["name"]
    assert lent["material"] == config.description and lent["geometry_from"] == "small"
    own = fabric_dataset(dataclasses.replace(config, name="small"), plan, "summation", seed=7).meta["sample"]
    assert own["name"] == "test fabric: summation model (small)" and "geometry_from" not in own
    assert own["simulated_from"] == "small" and lent["simulated_from"] == "red-cotton"
