"""The one output rule (gonio.data.outputs): every gonio command that writes replaces its own
previous output, anything else only with --force, and a run folder never."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from fabric_optics.cli.gonio import main
from gonio.data import read_dataset
from gonio.data.outputs import OutputRefused, check_output
from gonio.mock import MockInstrument

RECORDED = Path(__file__).parents[3] / "fixtures" / "recorded"


def _snapshot(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir()) if p.is_file()}


def _one_line(capsys, needle: str) -> str:
    err = capsys.readouterr().err.strip()
    assert "Traceback" not in err
    line = err.splitlines()[-1]
    assert needle in line, line
    return line


@pytest.fixture(scope="module")
def run_folder(tmp_path_factory) -> Path:
    """A finished run folder (journal, radiance.csv, meta.json) of the quick plan."""
    run = tmp_path_factory.mktemp("outputs") / "run"
    assert main(["demo", "--plan", "quick", "--no-progress", "--out", str(run)]) == 0
    (run / ".gonio-demo.json").unlink()      # no longer a demo's: a run like any other
    return run


def _truth(out: Path, *extra: str) -> int:
    return main(["truth", "lambert:0.4", "--plan", "quick", "--out", str(out), *extra])


def test_check_output_rule_per_kind(tmp_path, run_folder):
    ds = tmp_path / "ds"
    ds.mkdir()
    check_output(ds, "dataset", writer="gonio truth")                   # empty: fine
    (ds / "meta.json").write_text(json.dumps({"written_by": "gonio import"}))
    with pytest.raises(OutputRefused, match="did not write"):
        check_output(ds, "dataset", writer="gonio truth")
    check_output(ds, "dataset", writer="gonio truth", force=True)
    check_output(ds, "dataset", writer="gonio import")                  # its own previous output
    for kind in ("dataset", "run"):
        with pytest.raises(OutputRefused, match="never replaced, not even with --force"):
            check_output(run_folder, kind, writer="gonio truth", force=True)
    check_output(run_folder, "run", writer="gonio acquire", resume=True)
    with pytest.raises(OutputRefused, match="never replaced, not even with --force"):
        check_output(run_folder / "journal.jsonl", "file", writer="x", force=True)
    with pytest.raises(OutputRefused, match="is a folder"):
        check_output(ds, "file", writer="x", force=True)


def test_truth_replaces_its_own_output_only_with_force(tmp_path, capsys, run_folder):
    out = tmp_path / "truth"
    assert _truth(out) == 0
    capsys.readouterr()
    assert _truth(out) == 2                                 # re-running the command: refused
    _one_line(capsys, "pass --force")
    assert _truth(out, "--force") == 0                      # replaced with --force
    assert read_dataset(out).meta["written_by"] == "gonio truth"
    # a dataset another command wrote: refused, untouched; replaced with --force
    imported = tmp_path / "imported"
    assert main(["import", "rgl-bsdf", str(Path(__file__).parents[3] / "fixtures" / "real"
                                          / "acrylic_felt_green_rgb.bsdf"),
                 "--out", str(imported)]) == 0
    before = _snapshot(imported)
    capsys.readouterr()
    assert _truth(imported) == 2
    _one_line(capsys, "that `gonio truth` did not write")
    assert _snapshot(imported) == before
    assert _truth(imported, "--force") == 0
    assert read_dataset(imported).meta["written_by"] == "gonio truth"
    # a run folder: never, not even with --force
    before = _snapshot(run_folder)
    assert _truth(run_folder, "--force") == 2
    _one_line(capsys, "is a run folder")
    assert _snapshot(run_folder) == before


def test_import_refuses_a_dataset_it_did_not_write(tmp_path, capsys):
    out = tmp_path / "truth"
    assert _truth(out) == 0
    before = _snapshot(out)
    felt = str(Path(__file__).parents[3] / "fixtures" / "real" / "acrylic_felt_green_rgb.bsdf")
    capsys.readouterr()
    assert main(["import", "rgl-bsdf", felt, "--out", str(out)]) == 2
    _one_line(capsys, "that `gonio import` did not write")
    assert _snapshot(out) == before
    assert main(["import", "rgl-bsdf", felt, "--out", str(out), "--force"]) == 0


def test_bench_driver_never_replaces_a_run_journal(tmp_path, capsys, monkeypatch, run_folder):
    import gonio.bench

    calls = []
    monkeypatch.setattr(gonio.bench, "bench_driver",
                        lambda plan, repeats: calls.append(plan) or {"plan": plan.name})
    journal = run_folder / "journal.jsonl"
    before = journal.read_bytes()
    for extra in ([], ["--force"]):
        assert main(["bench-driver", "--plan", "quick", "--out", str(journal), *extra]) == 2
        _one_line(capsys, "a run folder's files are never replaced")
    assert journal.read_bytes() == before and not calls       # refused before the benchmark
    # a file the user wrote, or its own previous report: only with --force
    mine = tmp_path / "notes.json"
    mine.write_text("mine\n")
    assert main(["bench-driver", "--plan", "quick", "--out", str(mine)]) == 2
    _one_line(capsys, "did not write it")
    assert mine.read_text() == "mine\n"
    report = tmp_path / "driver.json"
    assert main(["bench-driver", "--plan", "quick", "--out", str(report)]) == 0
    capsys.readouterr()
    assert main(["bench-driver", "--plan", "quick", "--out", str(report)]) == 2
    _one_line(capsys, "pass --force")
    assert main(["bench-driver", "--plan", "quick", "--out", str(report), "--force"]) == 0
    assert json.loads(report.read_text())["written_by"] == "gonio bench-driver"
    assert main(["bench-driver", "--plan", "quick", "--out", str(mine), "--force"]) == 0
    assert json.loads(mine.read_text())["plan"] == "quick"


def test_acquire_and_replay_refuse_a_dataset_they_did_not_write(drv, tmp_path, capsys):
    out = tmp_path / "simulated"
    assert _truth(out) == 0
    before = _snapshot(out)
    capsys.readouterr()
    # refused before any link is opened (port 9 answers nothing: that error would differ)
    acquire = ["acquire", "--plan", "quick", "--modbus", "tcp://127.0.0.1:9", "--serial",
               "socket://127.0.0.1:9", "--out", str(out), "--no-progress"]
    assert main(acquire) == 2
    _one_line(capsys, "that `gonio acquire` did not write")
    assert main(["replay", str(RECORDED / "quick-lambert.jsonl"), "--plan", "quick", "--out", str(out)]) == 2
    _one_line(capsys, "that `gonio replay` did not write")
    assert _snapshot(out) == before
    # the library refuses it too (checked again under the run folder's lock); --force replaces
    plan = drv.write_plan(tmp_path, incidence=(0,), in_plane=(-30, 30), wavelengths=(550,),
                          readings=4)
    with MockInstrument(sample="lambert:0.5", speed="fast", seed=1) as mock:
        with pytest.raises(OutputRefused):
            drv.run(mock, plan, out)
        assert _snapshot(out) == before and not (out / "journal.jsonl").exists()
        from gonio.acquisition.plan import load_plan
        from gonio.acquisition.session import run_session
        from gonio.instrument import RetryPolicy
        from gonio.instrument.transport import ModbusTransport, SerialTransport
        res = run_session(load_plan(plan), ModbusTransport(mock.modbus_url, timeout_s=0.5),
                          SerialTransport(mock.serial_url, timeout_s=0.5), out, progress=False,
                          retry=RetryPolicy(base_s=0.002), force=True)
    assert res.exit_code == 0
    assert read_dataset(out).kind == "measured"
