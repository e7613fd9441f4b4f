"""The mock photometer head over a pseudo-terminal and over a loopback socket."""

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gonio import instrument as P
from gonio.mock import MockInstrument


@pytest.fixture(params=["pty", "socket"])
def both(request, tools):
    with MockInstrument(sample="lambert:0.5", modbus="tcp", serial=request.param, seed=3) as m:
        head = tools.HeadClient(m.serial_url)
        mb = tools.UmbClient(m.modbus_url)
        yield m, head, mb
        head.close()
        mb.close()


def test_commands_over_both_transports(both):
    m, head, mb = both
    assert m.serial_url.startswith("/dev/") or m.serial_url.startswith("socket://127.0.0.1:")
    idn = head.ask("*IDN?", "idn")
    assert (idn.maker, idn.model) == ("KIAM", "GPS-1")
    assert head.raw("WAVE 612.5") == b"OK\r\n"
    assert head.ask("WAVE?", "float") == 612.5
    assert head.raw("ITIME 50\r\n") == b"OK\r\n"                      # \r\n accepted
    assert head.ask("ITIME?", "int") == 50
    assert head.ask("GAIN 2", "ok") is None and head.ask("GAIN?", "int") == 2
    assert head.ask("SHUTTER?", "word") == "CLOSED"
    assert head.ask("BW?", "float") > 0 and isinstance(head.ask("TEMP?", "float"), float)
    r = head.ask("READ? 5", "reading")                               # shutter closed: dark only
    assert r.n == 5 and r.flags == 0 and 0 < r.mean_counts < 1000
    assert head.raw("FOO") == b"ERR 101,Unknown command\r\n"
    assert head.raw("WAVE 900") == b"ERR 102,Parameter out of range\r\n"
    assert head.ask("SYST:ERR?", "error_entry") == P.ErrorEntry(101, "Unknown command")
    assert head.ask("SYST:ERR?", "error_entry") == P.ErrorEntry(102, "Parameter out of range")
    assert head.ask("SYST:ERR?", "error_entry") == P.ErrorEntry(0, "No error")
    assert head.ask("*RST", "ok") is None and head.ask("WAVE?", "float") == 550.0


def test_checksum_mode(both):
    m, head, mb = both
    line = head.raw("CHK ON")
    assert line == b"OK*04\r\n"                                       # the reply to CHK ON has *HH
    line = head.raw("WAVE?")
    assert line == b"550.0*2E\r\n"
    assert P.parse_response(head.raw("READ? 3"), chk=True, expect="reading").n == 3
    err = head.raw("NOPE")
    body = err[:-2]
    assert body[:-3] == b"ERR 101,Unknown command" and body[-3:-2] == b"*"
    x = 0
    for b in body[:-3]:
        x ^= b
    assert int(body[-2:], 16) == x
    assert head.raw("CHK OFF") == b"OK\r\n"


def test_exactly_one_line_per_command(both):
    m, head, mb = both
    head.port.write(b"*IDN?\nWAVE 500\nWAVE?\n\n")                   # blank line is not a command
    lines = [head.port.readline() for _ in range(3)]
    assert lines[1:] == [b"OK\r\n", b"500.0\r\n"]
    head.port.timeout = 0.1
    assert head.port.readline() == b""


def test_lamp_off_and_overload(both):
    m, head, mb = both
    mb.home()
    assert head.raw("SHUTTER OPEN") == b"OK\r\n"
    assert head.raw("READ? 1") == b"ERR 201,Lamp off\r\n"
    mb.write_coils(P.COIL_LAMP, [True])
    assert head.raw("ITIME 10000") == b"OK\r\n" and head.raw("GAIN 3") == b"OK\r\n"
    assert head.raw("READ? 1") == b"ERR 301,Detector overload\r\n"
    head.raw("GAIN 0")
    head.raw("ITIME 1000")
    r = head.ask("READ? 2", "reading")
    assert r.saturated                                                 # >= 60000 counts


def test_long_line_and_binary_are_101(both):
    m, head, mb = both
    assert head.raw(b"\xff\xfe\n") == b"ERR 101,Unknown command\r\n"
    assert head.raw(b"A" * 300 + b"\n") == b"ERR 101,Unknown command\r\n"
    assert head.raw("*IDN?").startswith(b"KIAM")


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=120).filter(lambda b: b"\n" not in b))
def test_any_line_gets_exactly_one_parseable_reply(line):
    """Without faults, every line (terminator stripped) gets one reply the driver's parser accepts."""
    from gonio.mock.head import PhotometerHead
    from gonio.mock.motion import MotionController
    from gonio.mock.samples import LambertSample

    head = PhotometerHead(MotionController(), LambertSample(0.5), integration_scale=0.0)
    reply = head.handle_line(line)
    assert reply.data is not None and reply.data.endswith(b"\r\n") and reply.data.count(b"\n") == 1
    try:
        P.parse_response(reply.data, chk=False)
    except P.HeadError as exc:
        assert exc.code in P.HEAD_ERRORS


def test_pty_reopen_like_a_reconnecting_driver(tools):
    with MockInstrument(modbus="tcp", serial="pty") as m:
        for _ in range(3):
            h = tools.HeadClient(m.serial_url)
            assert h.raw("WAVE?") == b"550.0\r\n"
            h.close()
