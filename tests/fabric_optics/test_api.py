"""The Python interface (:mod:`fabric_optics.api`): typed errors, refusals, and the figures it
returns, checked against hand-computed values (fixtures/analytic/README.md) and against the
library functions it wraps."""

from __future__ import annotations

import math
import shutil
from pathlib import Path

import numpy as np
import pytest

import fabric_optics as fo
from gonio.data.dataset import read_dataset as library_read
from simulate.config_table import ConfigError

ROOT = Path(__file__).resolve().parents[2]
ANALYTIC = ROOT / "fixtures" / "analytic"


def test_a_bad_preset_is_an_input_error_naming_it_with_the_library_error_as_cause():
    with pytest.raises(fo.InputError, match="no-such-felt") as info:
        fo.load_config("no-such-felt")
    assert isinstance(info.value, ValueError) and isinstance(info.value, fo.ToolkitError)
    assert isinstance(info.value.__cause__, ConfigError)


def test_a_bad_plan_and_a_bad_method_are_input_errors():
    with pytest.raises(fo.InputError, match="no-such-plan"):
        fo.load_plan("no-such-plan")
    with pytest.raises(fo.InputError, match="method 'exact'"):
        fo.simulate("red-cotton", plan="quick", method="exact")
    with pytest.raises(fo.InputError, match="method 'auto'"):
        fo.fit("red-cotton", ANALYTIC / "measured_red", "rms_slope", "unused-out", method="auto")


def test_a_loaded_config_or_plan_passes_through_unchanged():
    cfg = fo.load_config("red-cotton")
    assert fo.load_config(cfg) is cfg and cfg.name == "red-cotton"
    plan = fo.load_plan("quick")
    assert fo.load_plan(plan) is plan


def test_write_dataset_refuses_an_existing_folder_without_force(tmp_path):
    ds = fo.read_dataset(ANALYTIC / "measured_red")
    out = tmp_path / "copy"
    fo.write_dataset(ds, out)
    with pytest.raises(fo.OutputExistsError, match="force=True"):
        fo.write_dataset(ds, out)
    (tmp_path / "notes").mkdir()
    (tmp_path / "notes" / "notes.txt").write_text("mine")
    with pytest.raises(fo.OutputExistsError):
        fo.write_dataset(ds, tmp_path / "notes")
    assert (tmp_path / "notes" / "notes.txt").read_text() == "mine"
    fo.write_dataset(ds, out, force=True)
    again = library_read(out)
    assert np.array_equal(again.table["beta"].to_numpy(), ds.table["beta"].to_numpy())


def test_check_of_a_scaled_copy_passes_and_of_the_lambertian_model_fails_with_the_hand_computed_nrmse():
    """sim_scaled is 3.7 x the measurement: zero curve error after normalisation, but 3.7 times off in level
    (fails the level check unless allowed); sim_lambert's overall NRMSE is 0.499089 by the fixture's hand
    computation."""
    measured = ANALYTIC / "measured_red"
    scaled = fo.check(fo.compare(measured, ANALYTIC / "sim_scaled"))
    assert not scaled.passed and scaled.failures() == ["level ratio max(k_Y, 1/k_Y)"]
    assert scaled.figures[0][1] < 1e-9
    assert math.isclose(scaled.figures[-1][1], 3.7, rel_tol=1e-6)
    assert fo.check(fo.compare(measured, ANALYTIC / "sim_scaled"), max_level_ratio=4.0).passed
    comparison = fo.compare(measured, [ANALYTIC / "sim_scaled", ANALYTIC / "sim_lambert"])
    lambert_name = list(comparison.simulated)[1]
    verdict = fo.check(comparison, name=lambert_name)
    assert not verdict.passed and "overall NRMSE" in verdict.failures()
    assert math.isclose(verdict.figures[0][1], 0.499089, abs_tol=2e-6)
    assert "FAIL overall NRMSE = 0.4991" in verdict.summary()
    loose = fo.check(comparison, name=lambert_name, max_nrmse=0.5, max_hue_diff=1.0, max_sat_diff=1.0,
                     max_level_ratio=10.0)
    assert loose.passed
    with pytest.raises(fo.InputError, match="no simulation named"):
        fo.check(comparison, name="nothing")


def test_a_dataset_folder_that_is_not_one_is_an_input_error(tmp_path):
    shutil.copytree(ANALYTIC / "measured_red", tmp_path / "broken")
    (tmp_path / "broken" / "meta.json").write_text("{not json")
    with pytest.raises(fo.InputError, match="meta.json"):
        fo.read_dataset(tmp_path / "broken")


def test_simulate_is_the_library_evaluation_with_the_config_and_plan_resolved():
    """The interface adds nothing to the model: the same call of simulate.virtual.fabric_dataset
    on the loaded config and plan gives the same values."""
    from gonio.acquisition.plan import load_plan
    from simulate.config import load_config
    from simulate.virtual import fabric_dataset

    ours = fo.simulate("red-cotton", plan="quick", method="classic", target_rel_err=0.2, seed=3, threads=1)
    theirs = fabric_dataset(load_config("red-cotton"), load_plan("quick"), "classic", target_rel_err=0.2, seed=3,
                            threads=1)
    assert len(ours) == len(theirs) > 0
    assert np.array_equal(ours.table["beta"].to_numpy(), theirs.table["beta"].to_numpy())


def test_export_refuses_an_existing_file_and_bounds_the_grid(tmp_path):
    target = tmp_path / "x.bsdf"
    target.write_bytes(b"user's file")
    ds = fo.read_dataset(ANALYTIC / "measured_red")
    with pytest.raises(fo.OutputExistsError):
        fo.export_bsdf(ds, target)
    assert target.read_bytes() == b"user's file"
    with pytest.raises(fo.InputError, match="incidences=1000"):
        fo.export_bsdf(ds, tmp_path / "y.bsdf", incidences=1000)
    assert not (tmp_path / "y.bsdf").exists()
