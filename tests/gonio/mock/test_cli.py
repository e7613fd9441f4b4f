"""``python -m gonio.mock`` / ``gonio.mock.cli.main``: one JSON line, SIGTERM -> 0, loopback only."""

import json
import os
import signal
import subprocess
import sys

import pytest

from gonio.mock.cli import main

#: how long the mock may take to exit after the signal: its own shutdown is bounded by 12 s (the servers' stop
#: 5 s, the event loop's thread 5 s, the serial bridge's thread 2 s), which a loaded machine can use up; a mock
#: that does not exit at all still fails
STOP_TIMEOUT_S = 60


def test_subprocess_prints_one_json_line_and_exits_0_on_sigterm(tools):
    proc = subprocess.Popen([sys.executable, "-m", "gonio.mock", "--modbus", "tcp://127.0.0.1:0",
                             "--serial", "socket://127.0.0.1:0", "--sample", "lambert:0.3", "--seed", "5",
                             "--faults", "busy=@99"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        line = proc.stdout.readline()
        endpoints = json.loads(line)
        assert set(endpoints) == {"modbus", "serial"}
        assert endpoints["modbus"].startswith("tcp://127.0.0.1:")
        assert endpoints["serial"].startswith("socket://127.0.0.1:")
        head = tools.HeadClient(endpoints["serial"])
        assert head.raw("*IDN?").startswith(b"KIAM,GPS-1,")
        head.close()
        mb = tools.UmbClient(endpoints["modbus"])
        assert mb.read_input(1, 1) == [0x0104]
        mb.close()
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=STOP_TIMEOUT_S)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, err
    assert out == ""                                    # nothing after the one JSON line


def test_subprocess_rtu_and_pty(tools):
    proc = subprocess.Popen([sys.executable, "-m", "gonio.mock", "--modbus", "rtu", "--serial", "pty"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        endpoints = json.loads(proc.stdout.readline())
        assert endpoints["modbus"].startswith("rtu:///dev/") and os.path.exists(endpoints["modbus"][6:])
        head = tools.HeadClient(endpoints["serial"])
        assert head.raw("WAVE?") == b"550.0\r\n"
        head.close()
        proc.send_signal(signal.SIGINT)
        proc.communicate(timeout=STOP_TIMEOUT_S)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0


@pytest.mark.parametrize("argv, needle", [
    (["--modbus", "tcp://0.0.0.0:5020"], "loopback"),
    (["--modbus", "tcp://192.168.1.10:502"], "loopback"),
    (["--serial", "socket://10.1.2.3:4000"], "loopback"),
    (["--serial", "socket://example.com:4000"], "loopback"),
    (["--modbus", "udp://127.0.0.1:5"], "--modbus"),
    (["--faults", "bogus=1"], "unknown kind"),
    (["--sample", "/no/such/dir"], "unknown sample"),
    (["--speed", "warp"], ""),
])
def test_usage_errors_exit_2(argv, needle, capsys):
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert needle in err and "Traceback" not in err
