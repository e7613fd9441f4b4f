"""Every fault kind fires at its trigger / rate, deterministically for a seed, and never
corrupts a reading reported as good."""

import socket

import numpy as np
import pytest
import serial
from umodbus import exceptions as ux
from umodbus.client import tcp as umb

from gonio import instrument as P
from gonio.mock import FaultSpecError, MockInstrument, parse_faults
from gonio.mock.faults import FaultInjector


def test_spec_syntax():
    rules = parse_faults("garbled=0.25, busy=@3,axis_fault=1")
    assert rules["garbled"].rate == 0.25 and rules["busy"].at == 3 and rules["axis_fault"].rate == 1.0
    for bad in ("nonsense=0.1", "busy=2", "busy=@0", "busy", "busy=0.1,busy=0.2", "garbled=-0.1"):
        with pytest.raises(FaultSpecError):
            parse_faults(bad)
    assert parse_faults(None) == {} and parse_faults("") == {}


def test_rates_are_deterministic_and_binomial():
    a, b, c = (FaultInjector("garbled=0.3", seed=s) for s in (5, 5, 6))
    n = 2000
    seq_a = [a.fires("garbled") for _ in range(n)]
    seq_b = [b.fires("garbled") for _ in range(n)]
    seq_c = [c.fires("garbled") for _ in range(n)]
    assert seq_a == seq_b and seq_a != seq_c
    sigma = np.sqrt(n * 0.3 * 0.7)
    assert abs(sum(seq_a) - 0.3 * n) < 4 * sigma
    assert a.stats["garbled"] == sum(seq_a)
    t = FaultInjector("busy=@4", seed=0)
    assert [t.fires("busy") for _ in range(8)] == [False, False, False, True, False, False, False, False]


class _ManualClock:
    """A controller clock the test advances by hand."""

    def __init__(self):
        self.t = 1000.0

    def __call__(self):
        return self.t


def _head(tools, m, timeout=0.3):
    return tools.HeadClient(m.serial_url, timeout=timeout)


def test_serial_timeout_busy_garbled_truncated(tools):
    spec = "serial_timeout=@2,busy=@4,garbled=@5,truncated=@6"
    with MockInstrument(modbus="tcp", serial="socket", faults=spec) as m:
        h = _head(tools, m)
        assert h.ask("WAVE?", "float") == 550.0                     # 1: fine
        assert h.raw("WAVE 600") == b""                              # 2: no answer ...
        assert h.ask("WAVE?", "float") == 550.0                      # 3: ... and not executed
        with pytest.raises(P.BusyError):                             # 4
            h.ask("WAVE 600", "ok")
        line = h.raw("*IDN?")                                        # 5: garbled, terminator kept
        assert line.endswith(b"\r\n")
        with pytest.raises(P.GarbledResponse):
            P.parse_response(line, False, "idn")
        line = h.raw("*IDN?")                                        # 6: truncated
        with pytest.raises(P.TruncatedResponse):
            P.parse_response(line, False, "idn")
        assert h.ask("SYST:ERR?", "error_entry") == P.ErrorEntry(103, "Busy")
        assert m.stats["faults"] == {"serial_timeout": 1, "busy": 1, "garbled": 1, "truncated": 1}
        h.close()


def test_checksum_fault_only_in_checksum_mode(tools):
    with MockInstrument(modbus="tcp", serial="socket", faults="checksum=@2") as m:
        h = _head(tools, m)
        assert h.raw("WAVE?") == b"550.0\r\n"                        # CHK OFF: no opportunity
        assert h.raw("CHK ON") == b"OK*04\r\n"                       # opportunity 1 (has *HH)
        with pytest.raises(P.ChecksumError):
            h.ask("WAVE?", "float", chk=True)                        # opportunity 2
        assert h.ask("WAVE?", "float", chk=True) == 550.0
        h.close()


def test_drop_socket_closes_connection_and_resets_link(tools):
    with MockInstrument(modbus="tcp", serial="socket", faults="drop=@2") as m:
        h = _head(tools, m)
        assert h.raw("CHK ON") == b"OK*04\r\n"
        with pytest.raises(serial.SerialException, match="disconnected"):
            h.raw("WAVE?")                                           # connection closed, no answer
        h.close()
        h2 = _head(tools, m)                                         # the driver reconnects
        assert h2.raw("WAVE?") == b"550.0\r\n"                       # CHK reverted to OFF
        assert m.stats["faults"] == {"drop": 1}
        h2.close()


def test_drop_pty_goes_silent_then_answers(tools):
    with MockInstrument(modbus="tcp", serial="pty", faults="drop=@1") as m:
        h = _head(tools, m)
        assert h.raw("WAVE?") == b""
        assert h.raw("WAVE?") == b"550.0\r\n"
        h.close()


def test_lamp_fault_flags_reading(tools):
    with MockInstrument(modbus="tcp", serial="socket", faults="lamp=@2") as m:
        mb, h = tools.UmbClient(m.modbus_url), _head(tools, m)
        tools.prepare(mb)
        assert h.ask("READ? 5", "reading").flags == 0
        r = h.ask("READ? 5", "reading")
        assert r.lamp_unstable and not r.good
        assert h.ask("READ? 5", "reading").flags == 0
        mb.close()
        h.close()


def test_modbus_busy_and_noresponse(tools):
    with MockInstrument(modbus="tcp", serial="socket", faults="modbus_busy=@2,modbus_noresponse=@4") as m:
        mb = tools.UmbClient(m.modbus_url, timeout=0.3)
        assert mb.read_input(P.IR_FIRMWARE, 1) == [0x0104]           # 1
        with pytest.raises(ux.ServerDeviceBusyError):                # 2
            mb.read_input(P.IR_FIRMWARE, 1)
        assert mb.read_input(P.IR_FIRMWARE, 1) == [0x0104]           # 3
        with pytest.raises(socket.timeout):                          # 4: dropped
            mb.read_input(P.IR_FIRMWARE, 1)
        mb.close()
        assert m.stats["faults"] == {"modbus_busy": 1, "modbus_noresponse": 1}


@pytest.mark.parametrize("write", ["coil", "register"])
def test_a_single_write_is_one_fault_opportunity(tools, write):
    """pymodbus' simulator completes a single write (fc 5 coil, fc 6 register) by calling the
    action a second time to read the value back: that is the same request, one opportunity, and
    ``modbus_busy=@2`` hits the request after it (faults docstring: one opportunity per request)."""
    with MockInstrument(modbus="tcp", serial="socket", faults="modbus_busy=@2") as m:
        mb = tools.UmbClient(m.modbus_url, timeout=0.3)
        if write == "coil":
            mb.call(umb.write_single_coil(slave_id=P.UNIT_ID, address=P.COIL_LAMP, value=1))   # 1
        else:
            mb.write_one(P.HR_SAMPLE_SLOT, 1)                                                # 1
        assert m.faults.opportunities["modbus_busy"] == 1 and m.frontend.requests == 1
        with pytest.raises(ux.ServerDeviceBusyError):                                      # 2
            mb.read_input(P.IR_FIRMWARE, 1)
        mb.close()
        assert m.stats["faults"] == {"modbus_busy": 1}
        assert m.controller.lamp_on if write == "coil" else m.controller.slot == 1


def test_axis_fault_mid_move(tools):
    with MockInstrument(modbus="tcp", serial="socket", faults="axis_fault=@2") as m:
        mb = tools.UmbClient(m.modbus_url)
        mb.home()
        mb.move(3, 100000)                                           # move 1: fine
        mb.wait_idle()
        assert mb.actual(3) == 100000
        mb.move(3, 300000)                                           # move 2: following error
        mb.wait_idle()
        assert mb.fault(3) == P.AxisFault.FOLLOWING_ERROR
        assert mb.status(3) & P.AxisStatus.FAULT and not mb.status(3) & P.AxisStatus.IN_POSITION
        assert 100000 < mb.actual(3) < 300000                        # stopped half way
        mb.write_one(P.HR_CONTROL, P.Control.ENABLE | P.Control.RESET_FAULT)
        mb.move(3, 300000)
        mb.wait_idle()
        assert mb.actual(3) == 300000
        mb.close()


def _readings_with_retries(tools, faults, seed=4):
    """A retrying client: keeps only replies that parse and are flagged good."""
    out, retries = [], 0
    with MockInstrument(sample="red-cotton", modbus="tcp", serial="socket", faults=faults, seed=seed) as m:
        mb = tools.UmbClient(m.modbus_url)
        tools.prepare(mb)
        h = _head(tools, m, timeout=0.3)
        for wl in (450.0, 550.0, 650.0):
            while True:
                try:
                    h.ask(f"WAVE {wl}", "ok")
                    break
                except P.ProtocolError:
                    retries += 1
                    h.port.reset_input_buffer()
            for _ in range(3):
                while True:
                    try:
                        r = h.ask("READ? 3", "reading")
                        if r.good:
                            out.append(r)
                            break
                    except P.ProtocolError:
                        pass
                    retries += 1
                    h.port.reset_input_buffer()
        stats = m.stats
        h.close()
        mb.close()
    return out, retries, stats


def test_faults_never_corrupt_good_readings(tools):
    clean, r0, _ = _readings_with_retries(tools, None)
    faulty, r1, stats = _readings_with_retries(tools, "garbled=0.2,busy=0.15,truncated=0.1,serial_timeout=0.1,lamp=0.2")
    assert r0 == 0 and r1 > 0 and sum(stats["faults"].values()) == r1
    assert faulty == clean                                           # bit-identical physics


def test_rate_faults_end_to_end_deterministic_for_a_seed(tools):
    spec = "garbled=0.25,truncated=0.15,busy=0.2,checksum=0.2,lamp=0.3,serial_timeout=0.1"

    def transcript(seed):
        with MockInstrument(sample="lambert:0.5", modbus="tcp", serial="socket", faults=spec, seed=seed) as m:
            mb = tools.UmbClient(m.modbus_url)
            tools.prepare(mb)
            h = _head(tools, m, timeout=0.3)
            lines = [h.raw("CHK ON")]
            for i in range(30):
                lines.append(h.raw("READ? 2" if i % 2 else f"WAVE {500 + i}"))
                h.port.reset_input_buffer()
            stats = m.stats["faults"]
            h.close()
            mb.close()
        return lines, stats

    a, stats_a = transcript(21)
    b, stats_b = transcript(21)
    c, _ = transcript(22)
    assert a == b and stats_a == stats_b and a != c
    assert {"garbled", "truncated", "busy", "checksum"} <= set(stats_a)


def _mbap_read_input(transaction: int, address: int, count: int) -> bytes:
    """A Modbus TCP request frame built by hand (MBAP header + PDU, function 4)."""
    import struct
    return struct.pack(">HHHBBHH", transaction, 0, 6, P.UNIT_ID, 4, address, count)


def test_modbus_drop_tcp_closes_the_connection_at_the_request(tools):
    with MockInstrument(modbus="tcp", serial="socket", faults="modbus_drop=@3", seed=2) as m:
        host, port = m.modbus_url[len("tcp://"):].rsplit(":", 1)
        sock = socket.create_connection((host, int(port)), timeout=2.0)
        for k in (1, 2):
            sock.sendall(_mbap_read_input(k, P.IR_FIRMWARE, 1))
            reply = sock.recv(256)
            assert reply[-2:] == b"\x01\x04", reply                 # firmware 1.4
        sock.sendall(_mbap_read_input(3, P.IR_FIRMWARE, 1))
        assert sock.recv(256) == b""                                # 3: EOF, no answer
        sock.close()
        mb = tools.UmbClient(m.modbus_url)                          # new connections: served
        assert mb.read_input(P.IR_FIRMWARE, 1) == [0x0104]
        assert mb.read_input(P.IR_FIRMWARE, 1) == [0x0104]          # once only (@3)
        mb.close()
        assert m.stats["faults"] == {"modbus_drop": 1}
        assert m.stats["modbus_drops"] == 1 and m.stats["modbus_requests"] == 5


def _dropped_write_took_effect(tools, seed: int) -> bool:
    with MockInstrument(modbus="tcp", serial="socket", faults="modbus_drop=@1", seed=seed) as m:
        mb = tools.UmbClient(m.modbus_url, timeout=1.0)
        with pytest.raises(ValueError):                             # umodbus: empty reply (EOF)
            mb.write_one(P.HR_SAMPLE_SLOT, int(P.SampleSlot.WHITE_REFERENCE))
        mb.close()
        mb = tools.UmbClient(m.modbus_url, timeout=1.0)
        slot = mb.read_holding(P.HR_SAMPLE_SLOT, 1)[0]
        mb.close()
        assert m.controller.slot == slot
        return slot == int(P.SampleSlot.WHITE_REFERENCE)


def test_modbus_drop_tcp_write_may_or_may_not_have_been_executed(tools):
    outcomes = [_dropped_write_took_effect(tools, seed) for seed in range(8)]
    assert any(outcomes) and not all(outcomes), outcomes          # both cases occur
    assert [_dropped_write_took_effect(tools, s) for s in (0, 1, 2)] == outcomes[:3]  # per seed


def test_modbus_drop_rtu_is_a_silent_interface(tools):
    import minimalmodbus

    with MockInstrument(modbus="rtu", serial="pty", faults="modbus_drop=@2", speed="real") as m:
        # the silent window is measured on the controller's clock: frozen here, advanced below,
        # so the requests land inside / after it whatever the machine's load
        clock = _ManualClock()
        m.controller.now = clock
        path = m.modbus_url[len("rtu://"):]
        inst = minimalmodbus.Instrument(path, P.UNIT_ID)
        for key, value in P.rtu_serial_settings(path).items():
            setattr(inst.serial, key, value)
        inst.serial.timeout = 10.0                                            # answers: no hurry
        assert inst.read_register(P.IR_FIRMWARE, functioncode=4) == 0x0104      # 1
        inst.serial.timeout = 0.15                                            # no answer ever comes
        with pytest.raises(minimalmodbus.NoResponseError):
            inst.read_register(P.IR_FIRMWARE, functioncode=4)                 # 2: dropped
        clock.t += 0.49                                                       # still silent
        with pytest.raises(minimalmodbus.NoResponseError):                    # ignored: silent
            inst.write_register(P.HR_SAMPLE_SLOT, int(P.SampleSlot.WHITE_REFERENCE))
        clock.t += 0.01                                                       # 0.5 s at real speed
        inst.serial.timeout = 10.0
        assert inst.read_register(P.IR_FIRMWARE, functioncode=4) == 0x0104
        assert inst.read_register(P.HR_SAMPLE_SLOT, functioncode=3) == int(P.SampleSlot.SAMPLE)
        inst.serial.close()
        assert m.stats["faults"] == {"modbus_drop": 1}
        assert m.stats["modbus_requests"] == 4           # the ignored request never reached it


def test_a_new_kind_leaves_the_other_streams_unchanged():
    a = FaultInjector("modbus_busy=0.3,modbus_noresponse=0.2", seed=9)
    b = FaultInjector("modbus_busy=0.3,modbus_noresponse=0.2,modbus_drop=0.4", seed=9)
    for _ in range(200):
        b.fires("modbus_drop")
        assert a.fires("modbus_busy") == b.fires("modbus_busy")
        assert a.fires("modbus_noresponse") == b.fires("modbus_noresponse")
