"""Devices: clear errors (device, command, code), a plain pymodbus SimDevice peer, head controls."""

from __future__ import annotations

import asyncio
import threading

import pytest

from gonio import instrument as P
from gonio.instrument import AxisFaultError, DeviceError, MotionController, PhotometerHead, RetryPolicy
from gonio.instrument.transport import LinkLost, ModbusTransport, SerialTransport, parse_modbus_url
from gonio.mock import MockInstrument


@pytest.fixture
def mock():
    with MockInstrument(sample="lambert:0.5", speed="fast", seed=1) as m:
        m.links = []
        yield m
        for link in m.links:
            link.close()


def _devices(m):
    retry = RetryPolicy(base_s=0.001)
    serial_link = SerialTransport(m.serial_url, timeout_s=0.3)
    modbus = ModbusTransport(m.modbus_url, timeout_s=0.3)
    m.links += [serial_link, modbus]
    return PhotometerHead(serial_link, retry), MotionController(modbus, retry)


def test_head_controls_round_trip(mock):
    head, _ = _devices(mock)
    ident = head.connect()
    assert (ident.maker, ident.model) == ("KIAM", "GPS-1")
    assert head.chk is True
    head.wavelength_nm = 612.34
    assert head.wavelength_nm == pytest.approx(612.3)
    head.itime_ms = 250
    assert head.itime_ms == 250
    head.gain = 2
    assert head.gain == 2
    head.shutter_open = True
    assert head.shutter_open is True
    head.shutter_open = False
    assert head.shutter_open is False
    assert head.error_queue() == []
    head.set_checksum(False)
    assert head.chk is False and head.gain == 2


def test_head_err_line_names_device_command_and_code(mock):
    head, motion = _devices(mock)
    head.connect()
    motion.set_lamp(False)
    head.shutter_open = True
    with pytest.raises(DeviceError) as info:
        head.read(4)
    err = info.value
    assert err.code == 201 and err.device == "photometer head" and err.command == "READ? 4"
    assert "photometer head: READ? 4: ERR 201 (Lamp off)" == str(err)
    # the error was queued by the head too
    assert [e.code for e in head.error_queue()] == [201]


def test_head_refuses_out_of_range_parameter_before_sending(mock):
    head, _ = _devices(mock)
    head.connect()
    before = mock.head.commands
    with pytest.raises(DeviceError, match=r"photometer head: WAVE <nm>: invalid parameter 900"):
        head.wavelength_nm = 900
    assert mock.head.commands == before


def test_modbus_exception_names_device_command_and_code(mock):
    _, motion = _devices(mock)
    motion.home()
    # bypass the plan checks: a raw target beyond the soft limits is refused by the controller
    hi, lo = P.int32_to_registers(90_000)
    with pytest.raises(DeviceError) as info:
        motion.write(P.axis_target_address(0), [hi, lo, 2000, P.AxisCommand.MOVE], "move source to 90")
    assert info.value.code == 3
    assert str(info.value) == ("motion controller: move source to 90: "
                               "Modbus exception 3 (illegal value)")


def test_move_before_homing_is_an_axis_fault(mock):
    _, motion = _devices(mock)
    motion.enable()
    with pytest.raises(AxisFaultError) as info:
        motion.move_to((10, 45, 0, 0), 50)
    assert info.value.axis == 0 and info.value.code == P.AxisFault.NOT_HOMED
    assert "axis 0 (source_zenith) fault 3 (not homed)" in str(info.value)


def test_move_waits_in_position_and_orders_axes_around_the_beam(mock):
    _, motion = _devices(mock)
    motion.home()
    motion.move_to((30, 40, 0, 0), 60)
    assert motion.positions_deg() == (30.0, 40.0, 0.0, 0.0)
    # source to 60 while the detector goes to -30: commanding the source first with the detector
    # still at its old destination would be fine, but (60, -60) is blocked: the driver refuses
    with pytest.raises(DeviceError, match="beam-block zone"):
        motion.move_to((60, -60, 0, 0), 60)
    # from (30, -50) to (50, -20): source first would pass (50, -50) -> 0 deg apart (blocked);
    # the driver moves the detector first
    motion.move_to((30, -50, 0, 0), 60)
    motion.move_to((50, -20, 0, 0), 60)
    assert motion.positions_deg()[:2] == (50.0, -20.0)
    assert mock.controller.axes[0].fault == 0


def test_shutdown_leaves_the_instrument_safe(mock):
    head, motion = _devices(mock)
    head.connect()
    motion.home()
    motion.set_lamp(True)
    motion.set_shutter(True)
    motion.move_to((0, 45, 90, 0), 1)            # a slow move, still running
    motion.write(P.axis_target_address(2), [*P.int32_to_registers(180_000), 100, 1], "slow move")
    head.shutdown()
    motion.shutdown()
    assert mock.controller.shutter_open is False
    assert all(ax.motion is None for ax in mock.controller.axes)


def test_modbus_url_parsing():
    assert parse_modbus_url("tcp://127.0.0.1:5020") == {"kind": "tcp", "host": "127.0.0.1", "port": 5020}
    assert parse_modbus_url("tcp://localhost")["port"] == 502
    rtu = parse_modbus_url("rtu:///dev/ttyUSB0")
    assert rtu["device"] == "/dev/ttyUSB0" and rtu["parity"] == "E" and rtu["baudrate"] == 19200
    assert parse_modbus_url("rtu:///dev/ttyUSB0?parity=N&baudrate=9600")["baudrate"] == 9600
    for bad in ("udp://x:1", "tcp://", "rtu://", "tcp://h:notaport", "rtu:///d?parity=X"):
        with pytest.raises(ValueError):
            parse_modbus_url(bad)


# --- a plain pymodbus simulator peer (not the project's mock) --------------------------------

class _SimController:
    """Minimal register-map device: moves are instantaneous, homing sets every axis home."""

    def __init__(self):
        self.pos = list(P.HOME_POSITIONS_MDEG)
        self.homed = False
        self.coils = [False, False]
        self.log = []
        self.status_extra = 0

    def device(self):
        from pymodbus.simulator import DataType, SimData, SimDevice
        holding = [SimData(s, count=c, values=0, datatype=DataType.REGISTERS)
                   for s, c in P.HOLDING_REGISTER_RANGES]
        inputs = [SimData(s, count=c, values=0, datatype=DataType.REGISTERS)
                  for s, c in P.INPUT_REGISTER_RANGES]
        coils = [SimData(0, values=[False] * 16, datatype=DataType.BITS)]
        discrete = [SimData(0, values=[False] * 16, datatype=DataType.BITS)]
        return SimDevice(id=1, simdata=(coils, discrete, holding, inputs), action=self.action)

    async def action(self, fc, start, address, count, regs, values):
        from pymodbus.constants import ExcCodes
        self.log.append((fc, address, None if values is None else list(values)))
        if fc == 16 and values is not None:
            if address == P.HR_CONTROL and values[0] & P.Control.HOME_ALL:
                self.pos, self.homed = list(P.HOME_POSITIONS_MDEG), True
            for a in range(P.N_AXES):
                if address == P.axis_target_address(a):
                    target = P.registers_to_int32(values[0], values[1])
                    if not P.within_soft_limits(a, target):
                        return ExcCodes.ILLEGAL_VALUE
                    if values[3] == P.AxisCommand.MOVE:
                        self.pos[a] = target
        elif fc == 5 and values is not None:
            self.coils[address] = bool(values[0])
        elif fc == 4:
            image = {P.IR_STATUS: (1 if self.homed else 0) | self.status_extra,
                     P.IR_FIRMWARE: 0x0203}
            for a in range(P.N_AXES):
                hi, lo = P.int32_to_registers(self.pos[a])
                b = P.axis_actual_address(a)
                st = (P.AxisStatus.HOMED | P.AxisStatus.IN_POSITION) if self.homed else 0
                image.update({b: hi, b + 1: lo, b + 2: int(st), b + 3: 0})
            for addr, v in image.items():
                if 0 <= addr - start < len(regs):
                    regs[addr - start] = v
        return None


@pytest.fixture
def simdevice():
    from pymodbus.server import ModbusTcpServer
    sim = _SimController()
    loop = asyncio.new_event_loop()
    ready = threading.Event()
    box = {}

    async def start():
        server = ModbusTcpServer(sim.device(), address=("127.0.0.1", 0))
        await server.serve_forever(background=True)
        box["server"] = server
        box["port"] = server.transport.sockets[0].getsockname()[1]
        ready.set()

    thread = threading.Thread(target=lambda: (asyncio.set_event_loop(loop),
                                              loop.run_until_complete(start()),
                                              loop.run_forever()), daemon=True)
    thread.start()
    assert ready.wait(10)
    yield sim, f"tcp://127.0.0.1:{box['port']}"
    asyncio.run_coroutine_threadsafe(box["server"].shutdown(), loop).result(5)
    loop.call_soon_threadsafe(loop.stop)
    thread.join(5)
    loop.close()


def test_driver_talks_to_a_plain_pymodbus_simdevice(simdevice):
    sim, url = simdevice
    motion = MotionController(ModbusTransport(url, timeout_s=0.5), RetryPolicy(base_s=0.001))
    assert motion.firmware() == "2.3"
    motion.home()
    motion.move_to((30, -45, 10, 90), 20)
    assert sim.pos == [30_000, -45_000, 10_000, 90_000]
    assert motion.positions_deg() == (30.0, -45.0, 10.0, 90.0)
    motion.set_lamp(True)
    motion.set_shutter(True)
    assert sim.coils == [True, True]
    motion.transport.close()
    motion.transport.open()
    # one write per moving axis: target (2 registers, high word first), velocity, command
    writes = [v for fc, a, v in sim.log if fc == 16 and a == P.axis_target_address(1)]
    assert writes[-1] == [0xFFFF, (-45_000) & 0xFFFF, 2000, 1]
    with pytest.raises(DeviceError, match=r"Modbus exception 3 \(illegal value\)"):
        motion.write(P.axis_target_address(1), [*P.int32_to_registers(95_000), 100, 1], "too far")
    motion.shutdown()
    # the drives are stopped; the shutter is the head's to close (its one owner), not the
    # controller's: the coil is left as it was
    control = [v for fc, a, v in sim.log if fc == 16 and a == P.HR_CONTROL]
    assert control[-1][0] & P.Control.STOP_ALL
    assert sim.coils[1] is True
    motion.transport.close()


@pytest.mark.parametrize("bit,needle", [(P.ControllerStatus.INTERLOCK_OPEN, "interlock open"),
                                        (P.ControllerStatus.EMERGENCY_STOP, "emergency stop")])
def test_open_interlock_or_emergency_stop_refuses_to_start(simdevice, bit, needle):
    sim, url = simdevice
    motion = MotionController(ModbusTransport(url, timeout_s=0.5), RetryPolicy(base_s=0.001))
    assert motion.check_safe_to_move() == P.ControllerStatus(0)
    sim.status_extra = int(bit)
    with pytest.raises(DeviceError, match=f"motion controller: read status: .*{needle}"):
        motion.check_safe_to_move()
    motion.transport.close()


class _DropOnce:
    """Wraps a Modbus transport: the first move command of ``axis`` gets no answer - a dropped
    connection - after being passed to the controller (``executed``) or not."""

    def __init__(self, inner, axis: int, executed: bool):
        self.inner, self.axis, self.executed = inner, axis, executed
        self.channel, self.url, self.timeout_s = inner.channel, inner.url, inner.timeout_s
        self.fired = False
        self.moves_sent = 0
        self.reconnects = 0

    def exchange(self, request):
        is_move = (request["fn"] == "write_registers"
                   and request["address"] == P.axis_target_address(self.axis))
        if is_move and not self.fired:
            self.fired = True
            if self.executed:
                self.moves_sent += 1
                self.inner.exchange(request)
            self.inner.close()
            raise LinkLost("modbus", "connection closed by the peer (test)")
        if is_move:
            self.moves_sent += 1
        return self.inner.exchange(request)

    def reconnect(self):
        self.reconnects += 1
        self.inner.reconnect()

    def close(self):
        self.inner.close()


@pytest.mark.parametrize("executed", [True, False])
def test_unanswered_move_is_checked_then_reissued_only_if_needed(mock, executed):
    modbus = _DropOnce(ModbusTransport(mock.modbus_url, timeout_s=0.3), axis=3, executed=executed)
    mock.links.append(modbus)
    retry = RetryPolicy(base_s=0.001)
    motion = MotionController(modbus, retry)
    motion.home()
    motion.move_to((0, 45, 0, 120), 60)
    assert modbus.fired and modbus.reconnects == 1
    assert retry.counts["modbus_link_lost"] == 1
    # the controller was asked; the move is sent again only when it had not been taken
    assert modbus.moves_sent == 1
    assert mock.controller.positions_mdeg()[3] == 120000
    assert motion.axis(3).status & P.AxisStatus.IN_POSITION


def test_modbus_reconnect_retries_with_bounded_backoff():
    """A refused connection is retried with min(base * 2**k, max) delays, then LinkLost."""
    import socket

    with socket.socket() as s:                   # a loopback port with nobody listening
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    slept = []
    link = ModbusTransport(f"tcp://127.0.0.1:{port}", timeout_s=0.2, reconnect_attempts=5,
                           reconnect_base_s=0.01, reconnect_max_s=0.03, sleep=slept.append)
    with pytest.raises(LinkLost, match="5 attempts"):
        link.reconnect()
    assert slept == [0.01, 0.02, 0.03, 0.03]
