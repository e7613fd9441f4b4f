"""The [weave] config table (preset / wif / matrix, dimensions) and ``simulate weave``."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from fabric_optics.cli.simulate import main
from simulate.config import ConfigError, load_config, parse_config, weave_from_config
from simulate.geometry.weave import DEFAULT_HEIGHT_UM, DEFAULT_SPACING_UM, DEFAULT_WIDTH_UM, PRESETS

DATA = Path(__file__).parent / "data"

BASE = """
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


def _config(tmp_path, weave="", name="cfg.toml"):
    path = tmp_path / name
    path.write_text(BASE + ("[weave]\n" + weave if weave else ""))
    return path


def test_red_cotton_still_loads_with_its_dict_and_weave():
    cfg = load_config("red-cotton")
    assert cfg.weave == {"matrix": [[1, 0], [0, 1]], "spacing_um": 300.0, "width_um": 250.0, "height_um": 100.0}
    w = weave_from_config(cfg)
    assert w.matrix.tolist() == [[1, 0], [0, 1]]
    assert (w.spacing_um, w.width_um, w.height_um, w.crimp, w.points_per_span, w.sides) == (
        300.0, 250.0, 100.0, 1.0, 16, 48)


def test_no_weave_table_is_the_plain_weave_with_the_defaults(tmp_path):
    cfg = load_config(_config(tmp_path))
    assert cfg.weave == {}
    w = weave_from_config(cfg)
    assert w.matrix.tolist() == PRESETS["plain"]
    assert (w.spacing_um, w.width_um, w.height_um) == (DEFAULT_SPACING_UM, DEFAULT_WIDTH_UM, DEFAULT_HEIGHT_UM)
    assert (DEFAULT_SPACING_UM, DEFAULT_WIDTH_UM, DEFAULT_HEIGHT_UM) == (300.0, 250.0, 100.0)


def test_preset_and_all_dimensions(tmp_path):
    path = _config(tmp_path, 'preset = "satin"\nspacing_um = 200\nwidth_um = 180\nheight_um = 60\n'
                             'crimp = 0.7\npoints_per_span = 4\nsides = 10\n')
    cfg = load_config(path)
    assert cfg.weave == {"preset": "satin", "spacing_um": 200.0, "width_um": 180.0, "height_um": 60.0,
                         "crimp": 0.7, "points_per_span": 4, "sides": 10}
    w = weave_from_config(path)           # a path works too
    assert w.matrix.tolist() == PRESETS["satin"]
    assert (w.crimp, w.points_per_span, w.sides) == (0.7, 4, 10)


def test_wif_is_resolved_against_the_config_folder(tmp_path, monkeypatch):
    (tmp_path / "patterns").mkdir()
    shutil.copy(DATA / "twill.wif", tmp_path / "patterns" / "twill.wif")
    path = _config(tmp_path, 'wif = "patterns/twill.wif"\n')
    monkeypatch.chdir(DATA)               # not the config's folder
    cfg = load_config(path)
    assert cfg.weave["wif"] == str(tmp_path / "patterns" / "twill.wif")
    assert weave_from_config(cfg).matrix.tolist() == [[1, 0, 0, 1], [1, 1, 0, 0], [0, 1, 1, 0], [0, 0, 1, 1]]


@pytest.mark.parametrize("weave,message", [
    ('preset = "twill"\nmatrix = [[1, 0], [0, 1]]\n',
     "cfg.toml: weave.preset cannot be combined with weave.matrix: give at most one of matrix, preset and wif"),
    ('preset = "twill"\nwif = "x.wif"\n', "cfg.toml: weave.wif cannot be combined with weave.preset"),
    ('preset = "basket"\n', "cfg.toml: weave.preset must be one of plain, twill, satin, got \"basket\""),
    ('wif = "missing.wif"\n', "cfg.toml: weave.wif file not found: "),
    ("crimp = 0\n", "cfg.toml: weave.crimp must be a number > 0 and <= 1, got 0"),
    ("crimp = 1.2\n", "cfg.toml: weave.crimp must be a number > 0 and <= 1"),
    ("sides = 2\n", "cfg.toml: weave.sides must be an integer in [3, 100000], got 2"),
    ("points_per_span = 1.5\n", "cfg.toml: weave.points_per_span must be an integer"),
    ("spacing = 300\n", "cfg.toml: weave.spacing is not a known field"),
    ("matrix = [[1, 2], [0, 1]]\n", "cfg.toml: weave.matrix must be a rectangular list of rows of 0/1"),
])
def test_bad_weave_table_is_a_config_error_naming_the_field(tmp_path, weave, message):
    with pytest.raises(ConfigError) as exc:
        load_config(_config(tmp_path, weave))
    assert message in str(exc.value), str(exc.value)


@pytest.mark.parametrize("weave,message", [
    ("spacing_um = 200\n", "cfg.toml: weave: weave width_um (250) must be <= spacing_um (200)"),
    ("matrix = [[1, 1], [0, 1]]\n", "cfg.toml: weave: weave matrix: warp row 0 never interlaces (all 1)"),
])
def test_bad_geometry_is_a_config_error_naming_the_file(tmp_path, weave, message):
    cfg = load_config(_config(tmp_path, weave))
    with pytest.raises(ConfigError) as exc:
        weave_from_config(cfg)
    assert message in str(exc.value), str(exc.value)


def test_bad_wif_through_a_config_names_both_files(tmp_path):
    (tmp_path / "bad.wif").write_text("[WIF]\n[WEAVING]\nShafts=2\nTreadles=1\n[THREADING]\n1=1\n2=3\n")
    cfg = load_config(_config(tmp_path, 'wif = "bad.wif"\n'))
    with pytest.raises(ConfigError, match=r"cfg\.toml: weave: bad\.wif, line 7: \[THREADING\] thread 2 "
                                          r"references shaft 3"):
        weave_from_config(cfg)


def test_parse_config_without_a_file_resolves_wif_against_the_working_directory(tmp_path, monkeypatch):
    shutil.copy(DATA / "plain.wif", tmp_path / "plain.wif")
    monkeypatch.chdir(tmp_path)
    cfg = parse_config(BASE + '[weave]\nwif = "plain.wif"\n')
    assert weave_from_config(cfg).matrix.tolist() == [[1, 0], [0, 1]]


# ------------------------------------------------------------------------------------------
# simulate weave


def _one_error_line(capsys):
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("simulate weave: error: "), err
    return lines[0]


@pytest.mark.parametrize("suffix", [".ply", ".obj"])
def test_cli_writes_the_mesh(tmp_path, capsys, suffix):
    import trimesh

    path = _config(tmp_path, 'preset = "twill"\npoints_per_span = 3\nsides = 6\n')
    out = tmp_path / f"mesh{suffix}"
    assert main(["weave", str(path), "--out", str(out)]) == 0
    assert f"wrote {out} (" in capsys.readouterr().out
    back = trimesh.load(out, process=False)
    # 8 yarns x (3 x 4 + 1) x (6 + 1) vertices, 8 x 2 x 12 x 6 faces
    assert (len(back.vertices), len(back.faces)) == (8 * 13 * 7, 8 * 2 * 12 * 6)


def test_cli_with_a_preset_config_name(tmp_path):
    assert main(["weave", "red-cotton", "--out", str(tmp_path / "red.ply")]) == 0
    assert (tmp_path / "red.ply").stat().st_size > 0


def test_cli_refuses_to_overwrite_without_force(tmp_path, capsys):
    out = tmp_path / "mesh.ply"
    out.write_text("keep me")
    assert main(["weave", "red-cotton", "--out", str(out)]) == 2
    assert "exists; pass --force to replace it, or choose a new name" in _one_error_line(capsys)
    assert out.read_text() == "keep me"
    assert main(["weave", "red-cotton", "--out", str(out), "--force"]) == 0
    assert out.read_bytes().startswith(b"ply")


@pytest.mark.parametrize("weave,out_name,fragment", [
    ('preset = "basket"\n', "m.ply", "cfg.toml: weave.preset must be one of plain, twill, satin"),
    ("spacing_um = 100\n", "m.ply", "cfg.toml: weave: weave width_um (250) must be <= spacing_um (100)"),
    ('wif = "bad.wif"\n', "m.ply", "bad.wif, line 7: [THREADING] thread 2 references shaft 3"),
    ("", "m.stl", "--out "),
    ("", "no/such/dir/m.ply", "cannot write the mesh"),
])
def test_cli_bad_input_is_one_line_and_exit_2(tmp_path, capsys, weave, out_name, fragment):
    (tmp_path / "bad.wif").write_text("[WIF]\n[WEAVING]\nShafts=2\nTreadles=1\n[THREADING]\n1=1\n2=3\n")
    path = _config(tmp_path, weave)
    assert main(["weave", str(path), "--out", str(tmp_path / out_name)]) == 2
    assert fragment in _one_error_line(capsys)


def test_cli_missing_config_is_exit_2(tmp_path, capsys):
    assert main(["weave", str(tmp_path / "nope.toml"), "--out", str(tmp_path / "m.ply")]) == 2
    assert "nope.toml" in _one_error_line(capsys)
    assert not (tmp_path / "m.ply").exists()
