"""gonio.instrument tables: register map helpers, geometry, command table, framing and the parser."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gonio import instrument as P
from gonio.data import geometry as G

# --- Modbus data -----------------------------------------------------------------------------

@pytest.mark.parametrize("value, regs", [
    (0, (0, 0)), (1, (0, 1)), (-1, (0xFFFF, 0xFFFF)), (85000, (0x0001, 0x4C08)),
    (-85000, (0xFFFE, 0xB3F8)),                 # 2**32 - 85000 = 0xFFFEB3F8
    (2**31 - 1, (0x7FFF, 0xFFFF)), (-2**31, (0x8000, 0x0000)),
])
def test_int32_packing_by_hand(value, regs):
    assert P.int32_to_registers(value) == regs
    assert P.registers_to_int32(*regs) == value


@given(st.integers(-2**31, 2**31 - 1))
def test_int32_round_trip(v):
    hi, lo = P.int32_to_registers(v)
    assert 0 <= hi <= 0xFFFF and 0 <= lo <= 0xFFFF
    assert P.registers_to_int32(hi, lo) == v


def test_int32_out_of_range():
    with pytest.raises(ValueError):
        P.int32_to_registers(2**31)
    with pytest.raises(ValueError):
        P.registers_to_int32(0x10000, 0)


def test_register_map_addresses():
    assert [P.axis_target_address(a) for a in range(4)] == [100, 120, 140, 160]
    assert P.axis_velocity_address(2) == 142 and P.axis_command_address(3) == 163
    assert P.axis_status_address(1) == 122 and P.axis_fault_address(1) == 123
    with pytest.raises(ValueError):
        P.axis_target_address(4)
    assert P.FIRMWARE_VERSION == 0x0104 and P.UNIT_ID == 1


def test_soft_limits():
    assert P.within_soft_limits(0, 0) and P.within_soft_limits(0, 85000)
    assert not P.within_soft_limits(0, -1) and not P.within_soft_limits(0, 85001)
    assert P.within_soft_limits(1, -85000) and not P.within_soft_limits(1, -85001)
    assert P.within_soft_limits(3, 360000) and not P.within_soft_limits(2, 180001)


def test_rtu_settings_on_pty_drop_parity():
    assert P.rtu_serial_settings("/dev/ttyUSB0")["parity"] == "E"
    assert P.rtu_serial_settings("/dev/pts/3") == {"baudrate": 19200, "bytesize": 8, "parity": "N", "stopbits": 1}


# --- geometry ------------------------------------------------------------------------------------

def test_beam_block_in_plane_boundary():
    assert G.beam_blocked(0, 0, 0)                 # normal/normal
    assert G.beam_blocked(0, 4.999, 77)
    assert not G.beam_blocked(0, 5.0, 77)          # exactly 5 deg is allowed
    assert not G.beam_blocked(30, -25, 0)
    assert G.beam_blocked(30, -26, 0) and G.beam_blocked(30, -34, 0)
    assert not G.beam_blocked(30, -35, 0)
    assert not G.beam_blocked(30, 30, 0)           # mirror side is 60 deg away


def test_beam_block_out_of_plane_3d():
    # both at zenith 30 deg, azimuths 10 deg apart: cos g = cos^2 30 + sin^2 30 cos 10 -> g = 4.995 deg
    g = math.degrees(math.acos(0.75 + 0.25 * math.cos(math.radians(10.0))))
    assert g < 5 and G.beam_blocked(30, -30, 10)
    g2 = math.degrees(math.acos(0.75 + 0.25 * math.cos(math.radians(10.1))))
    assert g2 > 5 and not G.beam_blocked(30, -30, 10.1)
    assert G.source_detector_angle_deg(30, -30, 10) == pytest.approx(g, abs=1e-9)


def test_axes_to_fabric_conventions():
    from gonio.data import signed_angle

    for s in (-60.0, -10.0, 0.0, 20.0, 70.0):
        for rot in (0.0, 90.0, 300.0):
            ti, pi_, to, po = G.axes_to_fabric(40.0, s, 0.0, rot)
            assert (ti, pi_, to) == (40.0, rot, abs(s))
            assert signed_angle(ti, pi_, to, po) == pytest.approx(s)


@given(st.floats(0, 85), st.floats(0, 359.9), st.floats(0.01, 85), st.floats(0, 359.99))
def test_fabric_axes_round_trip(ti, pi_, to, po):
    src, det, plane, rot = G.fabric_to_axes(ti, pi_, to, po)
    assert 0 <= plane < 180 + 1e-9 and -85 <= det <= 85
    ti2, pi2, to2, po2 = G.axes_to_fabric(src, det, plane, rot)
    assert ti2 == pytest.approx(ti) and to2 == pytest.approx(to)
    assert math.cos(math.radians(po2 - po)) == pytest.approx(1.0, abs=1e-9)
    assert math.cos(math.radians(pi2 - pi_)) == pytest.approx(1.0, abs=1e-9)


# --- head command table ---------------------------------------------------------------------------

@pytest.mark.parametrize("key, value", [
    ("*IDN?", None), ("*RST", None), ("WAVE", 550.0), ("WAVE", 380.0), ("WAVE?", None), ("BW?", None),
    ("SHUTTER", "OPEN"), ("SHUTTER", "CLOSE"), ("SHUTTER?", None), ("ITIME", 1), ("ITIME", 10000),
    ("ITIME?", None), ("GAIN", 3), ("GAIN?", None), ("READ?", 10), ("TEMP?", None),
    ("SYST:ERR?", None), ("CHK", "ON"), ("CHK", "OFF"),
])
def test_command_table_round_trip(key, value):
    cmd = P.HEAD_COMMANDS[key]
    line = cmd.format(value)
    assert line.endswith(b"\n")
    found, parsed = P.match_command(line.decode().rstrip("\n"))
    assert found is cmd
    assert parsed == value


@pytest.mark.parametrize("line", ["WAVE 379.9", "WAVE 780.1", "ITIME 0", "ITIME 10001", "GAIN 4",
                                  "GAIN -1", "READ? 0", "WAVE 1e999"])
def test_out_of_range_is_102(line):
    with pytest.raises(P.ParameterOutOfRangeError) as err:
        P.match_command(line)
    assert err.value.code == 102


@pytest.mark.parametrize("line", ["FOO", "wave 550", "WAVE", "SHUTTER HALF", "CHK MAYBE", "*IDN", ""])
def test_unknown_is_101(line):
    with pytest.raises(P.UnknownCommandError):
        P.match_command(line)


def test_format_refuses_bad_values():
    with pytest.raises(ValueError):
        P.HEAD_COMMANDS["GAIN"].format(7)
    with pytest.raises(ValueError):
        P.HEAD_COMMANDS["WAVE?"].format(3)


# --- framing and the parser -------------------------------------------------------------------------

@pytest.mark.parametrize("payload, hh", [(b"OK", "04"), (b"1", "31"), (b"AB", "03"),
                                         (b"550.0", "2E"), (b"", "00")])
def test_checksum_by_hand(payload, hh):
    # "550.0": 0x35 ^ 0x35 ^ 0x30 ^ 0x2E ^ 0x30 = 0x2E
    assert P.checksum(payload) == hh


def test_format_response():
    assert P.format_response("OK", chk=False) == b"OK\r\n"
    assert P.format_response("OK", chk=True) == b"OK*04\r\n"


def test_parse_good_lines():
    assert P.parse_response(b"OK\r\n", False, "ok") is None
    assert P.parse_response(b"OK*04\r\n", True, "ok") is None
    assert P.parse_response(b"550.0*2E\r\n", True, "float") == 550.0
    r = P.parse_response(b"1234.500,12.300,10,1\r\n", False, "reading")
    assert r == P.Reading(1234.5, 12.3, 10, 1) and r.saturated and not r.lamp_unstable and not r.good
    assert r.stderr_counts == pytest.approx(12.3 / math.sqrt(10))
    assert P.parse_response(b"KIAM,GPS-1,X1,2.3\r\n", False, "idn") == P.Identity("KIAM", "GPS-1", "X1", "2.3")
    assert P.parse_response(b'0,"No error"\r\n', False, "error_entry") == P.ErrorEntry(0, "No error")
    assert P.parse_response(b"CLOSED\r\n", False, "word") == "CLOSED"
    assert P.parse_response(b"100\r\n", False, "int") == 100


def test_parse_errors():
    with pytest.raises(P.NoResponse):
        P.parse_response(b"", False)
    with pytest.raises(P.TruncatedResponse):
        P.parse_response(b"1234.5,1", False, "reading")
    with pytest.raises(P.GarbledResponse):
        P.parse_response(b"12\xb7\xfe.5,1.0,10,0\r\n", False, "reading")
    with pytest.raises(P.GarbledResponse):
        P.parse_response(b"12.5,1.0,10\r\n", False, "reading")
    with pytest.raises(P.GarbledResponse):
        P.parse_response(b"OK\r\n", False, "reading")
    with pytest.raises(P.ChecksumError):
        P.parse_response(b"OK*05\r\n", True, "ok")
    with pytest.raises(P.ChecksumError):
        P.parse_response(b"OK\r\n", True, "ok")
    with pytest.raises(P.BusyError) as busy:
        P.parse_response(b"ERR 103,Busy\r\n", False, "reading")
    assert busy.value.code == 103 and busy.value.transient
    with pytest.raises(P.LampOffError) as lamp:
        P.parse_response(P.format_response("ERR 201,Lamp off", True), True, "reading")
    assert not lamp.value.transient
    with pytest.raises(P.GarbledResponse):
        P.parse_response(b"ERR 103,Lamp off\r\n", False)       # message does not match the code
    with pytest.raises(P.GarbledResponse):
        P.parse_response(b"ERR 999,Whatever\r\n", False)


@settings(max_examples=400, deadline=None)
@given(st.binary(max_size=300), st.booleans(),
       st.sampled_from(["text", "ok", "float", "int", "word", "idn", "reading", "error_entry"]))
def test_parser_fuzz_only_protocol_errors(data, chk, expect):
    try:
        P.parse_response(data, chk, expect)
    except P.ProtocolError:
        pass


@settings(max_examples=300, deadline=None)
@given(st.floats(0, 70000), st.floats(0, 5000), st.integers(1, 1000), st.integers(0, 3), st.booleans())
def test_reading_round_trip(mean, std, n, flags, chk):
    line = P.format_response(f"{mean:.3f},{std:.3f},{n},{flags}", chk)
    r = P.parse_response(line, chk, "reading")
    assert r.n == n and r.flags == flags
    assert r.mean_counts == pytest.approx(mean, abs=1e-3) and r.std_counts == pytest.approx(std, abs=1e-3)


def test_all_error_codes_map_to_classes():
    for code, message in P.HEAD_ERRORS.items():
        with pytest.raises(P.HeadError) as err:
            P.parse_response(P.format_response(f"ERR {code},{message}", False), False)
        assert err.value.code == code and err.value.message == message
        assert type(err.value) is type(P.head_error(code))
    assert np.all([P.GAIN_FACTORS[i] == 4 ** i for i in P.GAIN_STEPS])


def test_docstring_examples_run():
    import doctest

    import gonio.mock.faults
    from gonio.instrument import head_framing, links, modbus_map

    for module in (modbus_map, head_framing, links, gonio.mock.faults):
        result = doctest.testmod(module)
        assert result.failed == 0 and result.attempted > 0
