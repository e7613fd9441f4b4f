"""One clear line instead of a traceback or a wrong message: the `gonio` command line,
the mock's command line and the links. Every user error: one line naming what and what to do,
exit 2, no traceback."""

from __future__ import annotations

import errno
import json
import os
import signal
import socket
import subprocess
import sys

import pytest

from fabric_optics.cli.gonio import main
from gonio.acquisition.journal import read_journal
from gonio.acquisition.record import reseal
from gonio.data import read_dataset
from gonio.instrument.transport import parse_modbus_url
from gonio.mock import MockInstrument
from gonio.mock.cli import main as mock_main

FIXTURES = __import__("pathlib").Path(__file__).parents[3] / "fixtures" / "recorded"


def _last_line(err: str) -> str:
    lines = [ln for ln in err.strip().splitlines() if ln.strip()]
    assert lines, "nothing on stderr"
    assert "Traceback" not in err, err
    return lines[-1]


@pytest.mark.parametrize("value", ["-1", "0", "nan", "inf", "1e308", "soon"])
def test_timeout_must_be_a_finite_positive_number_of_seconds(tmp_path, capsys, value):
    argv = ["acquire", "--plan", "quick", "--modbus", "tcp://127.0.0.1:1", "--serial", "x",
            "--out", str(tmp_path / "o"), f"--timeout={value}"]
    assert main(argv) == 2
    line = _last_line(capsys.readouterr().err)
    assert "--timeout" in line and "seconds" in line, line
    assert not (tmp_path / "o").exists()


def test_a_huge_plan_is_refused_with_its_size(tmp_path, capsys):
    """3e7 measurements (300 incidences x 100,000 observation angles) ended in MemoryError."""
    plan = tmp_path / "huge.toml"
    incidence = [round(k * 0.25, 2) for k in range(300)]
    plan.write_text(f'[sample]\nname = "x"\n[wavelengths]\nlist_nm = [550]\n[geometry]\n'
                    f'incidence_deg = {incidence}\n'
                    'in_plane = {start = -60, stop = 69.9987, step = 0.0013}\n')
    assert main(["check-plan", "--plan", str(plan)]) == 2
    line = _last_line(capsys.readouterr().err)
    assert str(plan) in line and "30,000,000 measurements" in line and "at most 1,000,000" in line
    assert "split" in line


def test_a_directory_as_plan_says_it_is_a_directory(tmp_path, capsys):
    assert main(["check-plan", "--plan", str(tmp_path)]) == 2
    line = _last_line(capsys.readouterr().err)
    assert "is a directory" in line and "no such plan file" not in line


def test_demo_out_a_file_fails_before_starting_the_mock(tmp_path, capsys, monkeypatch):
    import gonio.mock

    def no_mock(*a, **k):
        raise AssertionError("the mock was started before --out was validated")

    monkeypatch.setattr(gonio.mock, "MockInstrument", no_mock)
    target = tmp_path / "file"
    target.write_text("x")
    assert main(["demo", "--out", str(target), "--plan", "quick", "--no-progress"]) == 2
    line = _last_line(capsys.readouterr().err)
    assert f"--out {target}: is a file" in line
    assert target.read_text() == "x"


def test_replay_with_another_plan_names_the_recorded_plan(tmp_path, capsys):
    assert main(["replay", str(FIXTURES / "quick-lambert.jsonl"),
                 "--plan", str(FIXTURES / "red-cotton-small.toml"), "--out", str(tmp_path / "r")]) == 2
    line = _last_line(capsys.readouterr().err)
    assert "recorded with plan 'quick'" in line and "red-cotton-small.toml" in line
    assert "replay: replay:" not in line and not (tmp_path / "r").exists()


def test_replay_mismatch_says_replay_once(tmp_path, capsys):
    src = (FIXTURES / "quick-lambert.jsonl").read_text().splitlines()
    k = next(i for i, ln in enumerate(src) if '"WAVE 500.0\\n"' in ln)
    src[k] = src[k].replace("WAVE 500.0", "WAVE 501.0")
    bad = tmp_path / "edited.jsonl"
    bad.write_text(reseal("\n".join(src) + "\n"))     # chain recomputed: the replay must notice
    assert main(["replay", str(bad), "--plan", "quick", "--out", str(tmp_path / "r")]) == 1
    err = capsys.readouterr().err
    assert "gonio replay: request" in err and "replay: replay:" not in err


def test_a_malformed_last_transcript_line_is_not_the_end(tmp_path, capsys):
    src = (FIXTURES / "quick-lambert.jsonl").read_text().splitlines()
    bad = tmp_path / "bad.jsonl"
    bad.write_text("\n".join(src[:-1] + ['{"i": 1, "ch": "serial", oops']) + "\n")
    assert main(["replay", str(bad), "--plan", "quick", "--out", str(tmp_path / "r")]) == 2
    line = _last_line(capsys.readouterr().err)
    assert f"the last line {len(src)}: not valid JSON" in line and "corrupt" in line
    # a torn last line (no newline: the recording was killed while writing it) is still accepted
    torn = tmp_path / "torn.jsonl"
    torn.write_text("\n".join(src) + "\n" + '{"i": 99999, "ch": "ser')
    assert main(["replay", str(torn), "--plan", "quick", "--out", str(tmp_path / "t")]) == 0


def _hostport(url: str) -> str:
    return url.split("://", 1)[1]


@pytest.mark.parametrize("modbus,serial", [("tcp", "socket"), ("rtu", "pty")])
def test_swapped_links_are_named_at_connect_time(tmp_path, capsys, modbus, serial):
    with MockInstrument(sample="lambert:0.5", modbus=modbus, serial=serial, seed=1) as mock:
        if modbus == "tcp":
            wrong_modbus = "tcp://" + _hostport(mock.serial_url)
            wrong_serial = "socket://" + _hostport(mock.modbus_url)
        else:
            wrong_modbus = "rtu://" + mock.serial_url
            wrong_serial = mock.modbus_url[len("rtu://"):]
        out = tmp_path / "run"
        code = main(["acquire", "--plan", "quick", "--modbus", wrong_modbus, "--serial", wrong_serial,
                     "--out", str(out), "--timeout", "0.5", "--no-progress"])
        line = _last_line(capsys.readouterr().err)
        assert code == 2, line
        assert "links look swapped" in line and wrong_modbus in line and wrong_serial in line
        assert not (out / "journal.jsonl").exists()
        # the same URLs the right way round work
        assert main(["acquire", "--plan", "quick", "--modbus", mock.modbus_url, "--serial", mock.serial_url,
                     "--out", str(out), "--no-progress"]) == 0


def test_disk_full_names_the_file_and_how_to_continue(tmp_path, capsys, monkeypatch, drv):
    plan = drv.write_plan(tmp_path, "full", incidence=(0, 30), in_plane=(-30, 20),
                          wavelengths=(500,), readings=8, geometry_extra="skip_blocked = true")
    real_fsync, calls = os.fsync, {"n": 0}

    def fsync_until_full(fd):
        calls["n"] += 1
        if calls["n"] > 4:      # start, calibration records and a point or two, then full
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return real_fsync(fd)

    out = tmp_path / "run"
    with MockInstrument(sample="lambert:0.5", speed="fast", seed=3) as mock:
        argv = ["acquire", "--plan", str(plan), "--modbus", mock.modbus_url, "--serial", mock.serial_url,
                "--out", str(out), "--no-progress"]
        monkeypatch.setattr(os, "fsync", fsync_until_full)
        assert main(argv) == 2
        monkeypatch.setattr(os, "fsync", real_fsync)
        line = _last_line(capsys.readouterr().err)
        assert "No space left on device" in line and str(out) in line
        kept = len(read_journal(out / "journal.jsonl").of_type("point"))
        assert f"the {kept} points measured so far are kept in {out / 'journal.jsonl'}" in line
        resume = line.split("continue with: ", 1)[1]
        assert resume.endswith(f"--out {out} --resume")
        assert main(resume.split()[1:]) == 0            # the printed command works as printed
    assert read_dataset(out).meta["provenance"]["complete"] is True


def test_mock_on_a_port_in_use_is_one_line(capsys):
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        assert mock_main(["--modbus", f"tcp://127.0.0.1:{port}"]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "Traceback" not in err
        assert f"--modbus tcp://127.0.0.1:{port}: cannot listen there" in err and "port 0" in err
        assert mock_main(["--serial", f"socket://127.0.0.1:{port}"]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and f"--serial socket://127.0.0.1:{port}" in err


def test_ipv6_loopback_endpoints_are_urls_acquire_accepts(tmp_path, drv):
    plan = drv.write_plan(tmp_path, "six", incidence=(0,), in_plane=(20,), wavelengths=(500,),
                          readings=8)
    with MockInstrument(sample="lambert:0.5", modbus="tcp://[::1]:0", serial="socket://[::1]:0",
                        seed=2) as mock:
        assert mock.modbus_url.startswith("tcp://[::1]:") and mock.serial_url.startswith("socket://[::1]:")
        assert parse_modbus_url(mock.modbus_url)["host"] == "::1"
        assert main(["acquire", "--plan", str(plan), "--modbus", mock.modbus_url, "--serial",
                     mock.serial_url, "--out", str(tmp_path / "run"), "--no-progress"]) == 0


def test_mock_prints_no_frames_without_verbose():
    """Garbage on the Modbus port: pymodbus logs the raw frame; the mock shows it with -v only."""
    proc = subprocess.Popen([sys.executable, "-m", "gonio.mock", "--modbus", "tcp", "--serial",
                             "socket"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        urls = json.loads(proc.stdout.readline())
        host, port = _hostport(urls["modbus"]).rsplit(":", 1)
        with socket.create_connection((host, int(port)), timeout=5) as s:
            s.sendall(b"\x00\x01\x00\x00\x00\x03\x01\x63\x00garbage\r\n")
            s.settimeout(2.0)
            try:
                s.recv(100)          # an exception reply, or the connection closed
            except (TimeoutError, OSError):
                pass
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 0
    assert err == "", err
