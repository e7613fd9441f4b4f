"""Crafted and careless inputs to the command lines: one line naming the file or field, exit 2 (130 for
an interrupt), never a traceback; text from a dataset printed escaped; a full disk names the file."""

from __future__ import annotations

import errno
import json
import os
import shutil
from pathlib import Path

import pytest

import fabric_optics as fo
from fabric_optics import validate
from fabric_optics.cli import compare as compare_cli
from fabric_optics.cli import gonio as gonio_cli
from fabric_optics.cli import simulate as simulate_cli
from fabric_optics.errors import as_toolkit_error, interrupt_of
from gonio.data.printable import printable

ROOT = Path(__file__).resolve().parents[2]
FELT = ROOT / "fixtures" / "real" / "acrylic_felt_green_rgb.bsdf"
MEASURED = ROOT / "fixtures" / "analytic" / "measured_red"
SIM = ROOT / "fixtures" / "analytic" / "sim_scaled"


def _one_line(err: str, prefix: str) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(prefix), err
    assert "Traceback" not in err
    return lines[0]


# --- a .bsdf whose vndf table is copied onto another incidence ---------------------------------

def test_a_vndf_table_copied_onto_another_incidence_is_one_line_naming_it(tmp_path, capsys):
    from gonio.data.bsdf_export import write_tensor_file
    from gonio.data.formats.tensor import read_tensor_file

    fields = read_tensor_file(FELT, lambda headers: None)
    vndf = fields["vndf"].copy()
    vndf[:, 3] = vndf[:, -1]                         # the grazing table at the fourth incidence (50.2 deg)
    crafted = tmp_path / "copied.bsdf"
    write_tensor_file(crafted, {**fields, "vndf": vndf})
    assert gonio_cli.main(["import", "rgl-bsdf", str(crafted), "--out", str(tmp_path / "o")]) == 2
    line = _one_line(capsys.readouterr().err, "gonio import: ")
    assert str(crafted) in line and "'vndf'" in line and "50.16 deg" in line
    assert not (tmp_path / "o").exists()


# --- plans nested 5000 deep ----------------------------------------------------------------------

def test_a_plan_nested_5000_deep_is_one_line_in_check_plan_plan_and_load_plan(tmp_path, capsys):
    plan = tmp_path / "deep.toml"
    plan.write_text('name = "deep"\n[geometry]\nincidence_deg = ' + "[" * 5000 + "]" * 5000 + "\n")
    assert gonio_cli.main(["check-plan", "--plan", str(plan)]) == 2
    assert "nested too deeply for a plan" in _one_line(capsys.readouterr().err, "gonio check-plan: ")
    assert simulate_cli.main(["fabric", "red-cotton", "--method", "classic", "--plan", str(plan),
                              "--out", str(tmp_path / "f")]) == 2
    assert str(plan) in _one_line(capsys.readouterr().err, "simulate fabric: error: --plan: ")
    with pytest.raises(fo.InputError, match="nested too deeply"):
        fo.load_plan(plan)


# --- compare report --fit with a hand-edited fit.json ---------------------------------------------

_FIT = {"method": "classic", "config": "red-cotton", "start": {"nrmse": 0.2},
        "fitted": {"nrmse": 0.1, "dh": 0.01, "ds": -0.02},
        "parameters": [{"name": "rms_slope", "start": 0.3, "value": 0.2, "u": 0.01, "low": 0.05, "high": 0.6}],
        "warnings": [], "info": {"evaluations": 6}}


@pytest.mark.parametrize("edit,field", [
    ({"start": [0.2]}, "'start'"),
    ({"fitted": {"nrmse": 0.1, "dh": "0.01", "ds": 0.0}}, "'fitted.dh'"),
    ({"fitted": {"nrmse": "low"}}, "'fitted.nrmse'"),
    ({"parameters": [[0.2, 0.3]]}, "'parameters[0]'"),
    ({"parameters": {"rms_slope": 0.2}}, "no parameters list"),
    ({"warnings": 3}, "'warnings'"),
    ({"info": "fast"}, "'info'"),
    ({"info": {"notes": "x"}}, "'info.notes'"),
    ({"uncertainty": [1]}, "'uncertainty'"),
    (None, "nested too deeply"),
    ("[]", "no parameters list"),
])
def test_a_hand_edited_fit_json_is_one_line(tmp_path, capsys, edit, field):
    fit = tmp_path / "fit"
    fit.mkdir()
    if edit is None:
        text = "[" * 100_000 + "]" * 100_000
    elif isinstance(edit, str):
        text = edit
    else:
        text = json.dumps({**_FIT, **edit})
    (fit / "fit.json").write_text(text)
    out = tmp_path / "report"
    assert compare_cli.main(["report", str(MEASURED), str(SIM), "--fit", str(fit), "--out", str(out)]) == 2
    line = _one_line(capsys.readouterr().err, "compare report: error: ")
    assert field in line and str(fit) in line
    assert not out.exists() or not any(out.iterdir())


# --- simulate fit on a measurement too large -------------------------------------------------------

def test_a_fit_refuses_a_measurement_beyond_the_row_bound_naming_the_file_and_the_limit(tmp_path, capsys,
                                                                                        monkeypatch):
    assert validate.MAX_MEASUREMENT_ROWS < 10**6                 # a 10^6-row measurement is refused
    rows = len(fo.read_dataset(MEASURED))
    monkeypatch.setattr(validate, "MAX_MEASUREMENT_ROWS", rows - 1)
    out = tmp_path / "fit"
    assert simulate_cli.main(["fit", "red-cotton", str(MEASURED), "--free", "rms_slope", "--method", "classic",
                              "--out", str(out), "--no-progress"]) == 2
    line = _one_line(capsys.readouterr().err, "simulate fit: error: MEASURED")
    assert str(MEASURED) in line and f"{rows:,} rows" in line and f"at most {rows - 1:,}" in line
    assert not out.exists()
    with pytest.raises(fo.InputError, match=f"at most {rows - 1:,}"):
        fo.fit("red-cotton", MEASURED, "rms_slope", tmp_path / "api-fit", method="classic")
    assert not (tmp_path / "api-fit").exists()


# --- Ctrl-C inside compiled code: a SystemError wrapping the KeyboardInterrupt ---------------------

def _interrupt_in_compiled_code():
    try:
        raise KeyboardInterrupt
    except KeyboardInterrupt as exc:
        # what CPython raises when a C function returns with the interrupt set
        raise SystemError("<built-in function mie> returned a result with an exception set") from exc


def test_an_interrupt_wrapped_in_a_system_error_is_the_interrupt():
    with pytest.raises(SystemError) as info:
        _interrupt_in_compiled_code()
    assert isinstance(interrupt_of(info.value), KeyboardInterrupt)
    assert isinstance(as_toolkit_error(info.value), KeyboardInterrupt)
    assert interrupt_of(SystemError("a real one")) is None
    assert interrupt_of(ValueError("x")) is None


def test_ctrl_c_in_the_compiled_mie_code_during_a_fit_exits_130_interrupted(tmp_path, capsys, monkeypatch):
    """The fit's search stands in for the compiled Mie code: the registry's classic runner raises what CPython
    raises when a C function returns with the interrupt set."""
    import dataclasses

    from fabric_optics.fitting.methods import METHODS

    monkeypatch.setitem(METHODS, "classic", dataclasses.replace(
        METHODS["classic"], run=lambda *a, **k: _interrupt_in_compiled_code()))
    out = tmp_path / "fit"
    code = simulate_cli.main(["fit", "red-cotton", str(MEASURED), "--free", "radius", "--method", "classic",
                              "--out", str(out), "--no-progress"])
    err = capsys.readouterr().err
    assert code == 130 and "simulate fit: interrupted" in err and "SystemError" not in err, err
    slab = simulate_cli.PROGRAM.by_name["slab"]
    monkeypatch.setitem(simulate_cli.PROGRAM.by_name, "slab",
                        dataclasses.replace(slab, run=lambda args: _interrupt_in_compiled_code()))
    assert simulate_cli.main(["slab", "--mua", "0.1", "--mus", "1", "--g", "0", "--n", "1.5", "--thickness", "1",
                              "--photons", "10", "--json"]) == 130
    assert capsys.readouterr().err.strip() == "simulate slab: interrupted"


# --- terminal escapes in a dataset's text ----------------------------------------------------------

FORGED = "red\x1b[2J\x1b[H\x1b[32mALL CHECKS PASSED\x1b[0m\u202e"


def test_printable_escapes_control_and_format_characters_only():
    assert printable("plain name, 45 deg") == "plain name, 45 deg"
    assert printable(FORGED) == "red\\x1b[2J\\x1b[H\\x1b[32mALL CHECKS PASSED\\x1b[0m\\u202e"
    assert printable("a\nb") == "a\\x0ab" and printable("a\nb", newlines=True) == "a\nb"
    assert printable("Å ü 日本") == "Å ü 日本"


def test_compare_check_prints_a_crafted_sample_name_escaped(tmp_path, capsys):
    measured = tmp_path / "m"
    shutil.copytree(MEASURED, measured)
    meta = json.loads((measured / "meta.json").read_text())
    meta["sample"]["name"] = FORGED
    (measured / "meta.json").write_text(json.dumps(meta))
    compare_cli.main(["check", str(measured), str(SIM)])
    out, err = capsys.readouterr()
    assert "\x1b" not in out + err and "\u202e" not in out + err
    assert "red\\x1b[2J" in out


# --- a full disk names the file ---------------------------------------------------------------------

@pytest.fixture
def full_disk(monkeypatch):
    def fsync(fd):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
    monkeypatch.setattr(os, "fsync", fsync)


@pytest.mark.parametrize("command", ["truth", "import", "demo", "bench-driver"])
def test_a_full_disk_in_gonio_names_the_file(tmp_path, capsys, full_disk, command):
    out = tmp_path / "out"
    argv = {"truth": ["truth", "lambert:0.5", "--plan", "quick", "--out", str(out)],
            "import": ["import", "rgl-bsdf", str(FELT), "--out", str(out)],
            "demo": ["demo", "--plan", "quick", "--out", str(out), "--no-progress"],
            "bench-driver": ["bench-driver", "--plan", "quick", "--repeats", "1", "--out", str(out / "b.json")],
            }[command]
    if command == "bench-driver":
        out.mkdir()
    assert gonio_cli.main(argv) == 2
    err = capsys.readouterr().err
    line = err.strip().splitlines()[-1]
    assert "Traceback" not in err and "No space left on device" in line, err
    named = line.rsplit("(", 1)[1].rstrip(")")           # the file: in the output (the benchmark's runs: a
    assert os.path.isabs(named) and Path(named).name, line    # temporary folder of their own)
    assert named.startswith(f"{out}/") or (command == "bench-driver" and Path(named).name == "journal.jsonl")


def test_a_full_disk_through_the_api_is_a_typed_error_naming_the_file(tmp_path, full_disk):
    ds = fo.read_dataset(MEASURED)
    with pytest.raises(fo.FileSystemError) as info:
        fo.write_dataset(ds, tmp_path / "d")
    assert info.value.filename == str(tmp_path / "d" / "radiance.csv")
    assert not (tmp_path / "d" / "radiance.csv").exists()
