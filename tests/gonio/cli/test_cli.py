"""The `gonio` command line: usage errors (exit 2, one line), mock dispatch, demo, Ctrl-C."""

from __future__ import annotations

import json
import re
import signal
import socket
import subprocess
import sys
import time

import pytest

from fabric_optics.cli.gonio import main
from gonio.acquisition.journal import read_journal
from gonio.data import read_dataset


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_help_and_mock_dispatch(capsys):
    assert main(["--help"]) == 0
    out = capsys.readouterr().out
    for cmd in ("mock", "acquire", "replay", "check-plan", "demo", "truth", "import",
                "bench-driver"):
        assert re.search(rf"\n    {cmd}\s", out), cmd     # an entry of the command list each
    assert main(["bench-driver", "--help"]) == 0
    assert "--repeats" in capsys.readouterr().out
    assert main(["mock", "--help"]) == 0
    mock_help = " ".join(capsys.readouterr().out.split())
    assert "--faults" in mock_help and "RGL .bsdf file" in mock_help
    assert main([]) == 2


@pytest.mark.parametrize("argv,needle", [
    (["acquire", "--plan", "quick", "--modbus", "udp://x", "--serial", "/dev/null", "--out", "o"], "--modbus"),
    (["acquire", "--plan", "quick", "--modbus", "tcp://127.0.0.1:{port}", "--serial", "/dev/null",
      "--out", "o"], "cannot reach the device"),
    (["acquire", "--plan", "quick", "--modbus", "tcp://127.0.0.1:1", "--serial", "/nonexistent/tty",
      "--out", "o"], "cannot reach the device"),
    (["acquire", "--plan", "nosuchplan", "--modbus", "tcp://127.0.0.1:1", "--serial", "x", "--out", "o"],
     "no such plan file"),
    (["acquire", "--plan", "quick", "--serial", "x", "--out", "o"], "required"),
    (["check-plan"], "required"),
])
def test_usage_errors_exit_2_with_one_line(tmp_path, capsys, argv, needle):
    argv = [a.replace("{port}", str(_free_port())).replace("o", str(tmp_path / "o"))
            if a == "o" or "{port}" in a else a for a in argv]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert needle in err
    assert "Traceback" not in err


def test_demo_with_a_small_plan(tmp_path, capsys):
    out = tmp_path / "demo"
    assert main(["demo", "--out", str(out), "--plan", "quick", "--no-progress"]) == 0
    text = capsys.readouterr().out
    assert f"dataset in {out}" in text
    ds = read_dataset(out)
    assert len(ds.table) == 36 and ds.meta["sample"]["name"] == "quick check sample"
    # a second demo into the same folder is refused without --force and replaces the first with it
    assert main(["demo", "--out", str(out), "--plan", "quick", "--no-progress"]) == 2
    assert "pass --force" in capsys.readouterr().err
    assert main(["demo", "--out", str(out), "--plan", "quick", "--no-progress", "--force"]) == 0


def _default_sigint() -> None:
    """In the child before exec: SIGINT back to its default disposition. A test runner started
    in the background (``cmd &`` without job control) ignores SIGINT, the children inherit that,
    and Python then installs no KeyboardInterrupt handler - the signal would be lost."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def test_sigint_stops_safely_keeping_points(drv, tmp_path):
    from gonio.instrument import MotionController, RetryPolicy
    from gonio.instrument.transport import ModbusTransport

    plan = drv.write_plan(tmp_path, "int", incidence=(0, 30, 60), in_plane=(-50, -10, 20, 50),
                          wavelengths=(450, 500, 550, 600, 650), itime_ms=200, readings=100)
    mock = subprocess.Popen([sys.executable, "-m", "fabric_optics.cli.gonio", "mock", "--sample", "lambert:0.5",
                             "--serial", "socket"], stdout=subprocess.PIPE,
                            stderr=subprocess.DEVNULL, text=True, preexec_fn=_default_sigint)
    try:
        urls = json.loads(mock.stdout.readline())
        out = tmp_path / "run"
        proc = subprocess.Popen([sys.executable, "-m", "fabric_optics.cli.gonio", "acquire", "--plan", str(plan),
                                 "--modbus", urls["modbus"], "--serial", urls["serial"],
                                 "--out", str(out), "--no-progress"],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                preexec_fn=_default_sigint)
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:          # wait for two journaled points
            if (out / "journal.jsonl").exists() and len(
                    read_journal(out / "journal.jsonl").of_type("point")) >= 2:
                break
            time.sleep(0.05)
        # freeze the instrument, then interrupt: the session cannot measure past this state
        # (at most the point whose last answer is already on the wire), wherever it is
        mock.send_signal(signal.SIGSTOP)
        try:
            at_stop = len(read_journal(out / "journal.jsonl").of_type("point"))
            proc.send_signal(signal.SIGINT)
        finally:
            mock.send_signal(signal.SIGCONT)
        _, err = proc.communicate(timeout=120)
        assert proc.returncode == 130, err
        assert "Traceback" not in err
        final = err.strip().splitlines()[-1]
        assert final.startswith("gonio acquire: interrupted") and final.count("kept") == 1, err
        assert err.count("kept") == 1, err  # said once, in the final line (not also by the engine's log)
        assert f"--out {out} --resume" in final and f"gonio acquire --plan {plan}" in final, final
        kept = len(read_journal(out / "journal.jsonl").of_type("point"))
        assert 2 <= at_stop <= kept <= at_stop + 1 and kept < 12, (at_stop, kept)
        assert len(read_dataset(out).table) == 5 * kept
        # the instrument is safe: shutter coil off, no axis moving
        motion = MotionController(ModbusTransport(urls["modbus"], timeout_s=1.0), RetryPolicy())
        bits = motion.call({"fn": "read_coils", "address": 0, "count": 2}, "read coils")["bits"]
        assert bits[1] is False
        assert all(not motion.axis(a).status & 0x2 for a in range(4))
        motion.transport.close()
    finally:
        mock.send_signal(signal.SIGINT)
        mock.wait(10)
        mock.stdout.close()


def test_unwritable_output_is_a_usage_error(tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    assert main(["demo", "--out", str(blocker / "sub"), "--plan", "quick", "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "gonio demo:" in err and "Traceback" not in err
