"""``simulate fabric`` and ``simulate fiber``: outputs, and one line + exit 2 on every bad input."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from fabric_optics.cli.simulate import main
from gonio.data.dataset import read_dataset
from simulate.fiber.tables import JSON_NAME, NPZ_NAME, read_fiber_table

from .conftest import fake_R

GOOD_CONFIG = """
[fiber]
radius_um = 8.0
n_host = 1.557
[medium]
mu_s = 1.0
mu_a = 0.01
g = 0.8
[surface]
rms_slope = 0.3
"""


def _one_error_line(capsys, command="fabric"):
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith(f"simulate {command}: error: "), err
    assert "Traceback" not in err
    return lines[0]


@pytest.fixture
def cfg(tmp_path):
    path = tmp_path / "good.toml"
    path.write_text(GOOD_CONFIG)
    return path


def test_fabric_writes_a_dataset_and_overwrites_only_its_own_output(fake_fiber, tmp_path, capsys, carpet_path):
    out = tmp_path / "sim"
    assert main(["fabric", str(carpet_path), "--method", "summation", "--out", str(out), "--seed", "5",
                 "--target-rel-err", "0.05"]) == 0
    assert "wrote" in capsys.readouterr().out
    ds = read_dataset(out)
    assert ds.meta["provenance"]["seed"] == 5 and ds.meta["provenance"]["target_rel_err"] == 0.05
    assert fake_fiber.volume_calls[0]["target_rel_err"] == 0.05
    # a previous simulate output is replaced with --force only
    assert main(["fabric", "red-cotton", "--method", "classic", "--out", str(out)]) == 2
    assert "pass --force" in _one_error_line(capsys)
    assert main(["fabric", "red-cotton", "--method", "classic", "--out", str(out), "--force"]) == 0
    assert read_dataset(out).meta["model"]["method"] == "classic"


def test_fabric_with_a_plan_path_and_measurable_only(fake_fiber, tmp_path, cfg):
    from gonio.acquisition.plan import load_plan

    out = tmp_path / "q"
    plan = load_plan("quick")
    assert main(["fabric", str(cfg), "--method", "summation", "--out", str(out), "--plan", "quick",
                 "--measurable-only"]) == 0
    assert len(read_dataset(out).geometries()) == len(plan.geometries(measurable_only=True))


@pytest.mark.parametrize("argv_tail,fragment", [
    (["--method", "summation", "--out", "{out}", "--plan", "no-such-plan"], "--plan"),
    (["--method", "summation", "--out", "{out}", "--target-rel-err", "2"], "--target-rel-err"),
    (["--method", "summation", "--out", "{out}", "--target-rel-err", "abc"], "--target-rel-err"),
    (["--method", "bssrdf", "--out", "{out}"], "--method"),
    (["--method", "summation", "--out", "{out}", "--seed", "-1"], "--seed"),
    (["--method", "summation", "--out", "{out}", "--threads", "-1"], "--threads"),   # 0 = all
    (["--method", "summation"], "--out"),
])
def test_fabric_bad_arguments_exit_2_with_one_line(fake_fiber, tmp_path, capsys, argv_tail, fragment):
    argv = ["fabric", "red-cotton"] + [a.replace("{out}", str(tmp_path / "o")) for a in argv_tail]
    with pytest.raises(SystemExit) as info:
        code = main(argv)
        raise SystemExit(code)
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and fragment in err and "Traceback" not in err


def test_fabric_bad_config_field_names_the_field(fake_fiber, tmp_path, capsys):
    bad = tmp_path / "red.toml"
    bad.write_text(GOOD_CONFIG.replace("radius_um = 8.0", 'radius_um = "abc"'))
    assert main(["fabric", str(bad), "--method", "classic", "--out", str(tmp_path / "o")]) == 2
    line = _one_error_line(capsys)
    assert 'red.toml: fiber.radius_um must be a number > 0' in line and '"abc"' in line
    assert not (tmp_path / "o").exists()


def test_fabric_missing_config(fake_fiber, tmp_path, capsys):
    assert main(["fabric", str(tmp_path / "none.toml"), "--method", "classic", "--out", str(tmp_path / "o")]) == 2
    assert "no such config file" in _one_error_line(capsys)


def test_fabric_refuses_a_foreign_non_empty_directory(fake_fiber, tmp_path, capsys, cfg):
    out = tmp_path / "thesis"
    out.mkdir()
    (out / "chapter1.tex").write_text("precious")
    assert main(["fabric", str(cfg), "--method", "classic", "--out", str(out)]) == 2
    assert "refusing to overwrite" in _one_error_line(capsys)
    assert (out / "chapter1.tex").read_text() == "precious" and not (out / "meta.json").exists()
    # a measured dataset is not a previous simulate output either
    measured = tmp_path / "measured"
    measured.mkdir()
    (measured / "meta.json").write_text(json.dumps({"kind": "measured"}))
    assert main(["fabric", str(cfg), "--method", "classic", "--out", str(measured)]) == 2
    _one_error_line(capsys)
    afile = tmp_path / "file"
    afile.write_text("x")
    assert main(["fabric", str(cfg), "--method", "classic", "--out", str(afile)]) == 2
    assert "not a directory" in _one_error_line(capsys)


def test_fabric_plan_with_grazing_incidence_is_an_input_error(fake_fiber, tmp_path, capsys, cfg):
    plan = tmp_path / "grazing.toml"
    plan.write_text('[sample]\nname = "x"\n[wavelengths]\nlist_nm = [500, 600]\n'
                    '[geometry]\nincidence_deg = [90]\nin_plane_deg = [10]\n')
    code = main(["fabric", str(cfg), "--method", "summation", "--out", str(tmp_path / "o"),
                 "--plan", str(plan)])
    assert code == 2
    _one_error_line(capsys)


def test_fiber_table_grid_values_and_sidecar(fake_fiber, tmp_path, capsys, cfg):
    out = tmp_path / "table"
    assert main(["fiber", str(cfg), "--out", str(out), "--step-deg", "30", "--phi-step-deg", "45",
                 "--route", "beam"]) == 0
    arrays, sidecar = read_fiber_table(out)
    assert sidecar["format"] == "fiber-brdf-table/1"
    np.testing.assert_array_equal(arrays["theta_in_deg"], [15, 45, 75, 105, 135, 165])
    np.testing.assert_array_equal(arrays["phi_in_deg"], [0, 45, 90])
    np.testing.assert_array_equal(arrays["theta_out_deg"], [15, 45, 75])
    np.testing.assert_array_equal(arrays["phi_out_deg"], np.arange(0, 360, 45))
    shape = (6, 3, 3, 8, 33)
    assert arrays["R"].shape == shape and arrays["u_R"].shape == shape
    assert fake_fiber.volume_calls[0]["method"] == "beam"
    # one entry checked against the fake: theta_in 105 (from below B's plane), phi_in 45
    from simulate.fabric import directions_deg

    w_in = directions_deg(105.0, 45.0)[None]
    w_out = directions_deg(45.0, 270.0)[None]
    expected = fake_R(w_in, w_out, arrays["wavelength_nm"])[0]
    np.testing.assert_allclose(arrays["R_vol"][3, 1, 1, 6], expected, rtol=1e-12)
    assert np.all(arrays["R_surf"][3:] == 0)  # no surface reflection from below the tangent plane
    np.testing.assert_allclose(arrays["R"], arrays["R_vol"] + arrays["R_surf"][..., None])
    assert sidecar["provenance"]["method"] == "beam" and sidecar["grid"]["step_deg"] == 30
    assert (out / NPZ_NAME).is_file() and (out / JSON_NAME).is_file()
    # its own previous output is replaced with --force; a bad grid step is a usage error
    assert main(["fiber", str(cfg), "--out", str(out), "--step-deg", "30", "--phi-step-deg", "90", "--force"]) == 0
    capsys.readouterr()
    assert main(["fiber", str(cfg), "--out", str(out), "--step-deg", "7"]) == 2
    assert "--step-deg" in _one_error_line(capsys, "fiber")


def test_console_script_has_no_traceback_on_a_user_error(tmp_path):
    bad = tmp_path / "red.toml"
    bad.write_text(GOOD_CONFIG.replace("n_host = 1.557", "n_host = -2"))
    proc = subprocess.run([sys.executable, "-m", "fabric_optics.cli.simulate", "fabric", str(bad), "--method", "classic",
                           "--out", str(tmp_path / "o")], capture_output=True, text=True, timeout=900)
    assert proc.returncode == 2
    assert proc.stderr.strip() == ("simulate fabric: error: red.toml: fiber.n_host must be a number >= 1 "
                                   "and <= 4, got -2")


def test_a_seed_beyond_the_streams_range_is_one_line(capsys, tmp_path):
    # per-batch streams are derived as seed * 1_000_003 + ... in 64-bit integers
    code = main(["fabric", "red-cotton", "--method", "classic", "--out", str(tmp_path / "o"),
                 "--seed", "100000000000000"])
    assert code == 2          # a usage error: main returns argparse's status
    line = _one_error_line(capsys)
    assert "--seed" in line
