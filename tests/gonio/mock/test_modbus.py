"""The mock motion controller speaks real Modbus: independent clients (umodbus over TCP,
minimalmodbus over the RTU pseudo-terminal) and the controller rules of docs/instrument.md."""

import time

import minimalmodbus
import pytest
from umodbus import exceptions as ux

from gonio import instrument as P
from gonio.mock import MockInstrument


def test_firmware_status_and_target_register(mb):
    status, firmware = mb.read_input(P.IR_STATUS, 2)
    assert firmware == 0x0104
    assert status == 0                                 # drives disabled, not homed, no fault
    hi, lo = P.int32_to_registers(-12345)
    mb.write(P.axis_target_address(1), [hi, lo])
    assert mb.read_holding(P.axis_target_address(1), 2) == [hi, lo]
    assert mb.read_holding(P.axis_velocity_address(1), 1) == [P.DEFAULT_VELOCITY_CDEG_S]


def test_undefined_address_is_exception_2(mb):
    with pytest.raises(ux.IllegalDataAddressError):
        mb.read_input(50, 1)
    with pytest.raises(ux.IllegalDataAddressError):
        mb.read_holding(104, 1)


def test_home_then_move_reaches_target_in_position(mb):
    mb.home()
    assert mb.read_input(P.IR_STATUS, 1)[0] & P.ControllerStatus.READY
    for a in range(4):
        assert mb.actual(a) == P.HOME_POSITIONS_MDEG[a]
        assert mb.status(a) & P.AxisStatus.HOMED
    assert mb.read_holding(P.HR_CONTROL, 1) == [P.Control.ENABLE]      # command bits self-clear
    mb.move(0, 30000, velocity_cdeg_s=100)             # 30 deg at 1 deg/s: 0.3 s at fast speed
    st = mb.status(0)
    assert st & P.AxisStatus.MOVING and not st & P.AxisStatus.IN_POSITION
    mb.wait_idle()
    assert mb.actual(0) == 30000
    assert mb.status(0) & P.AxisStatus.IN_POSITION
    mb.move(1, -60000)                                 # negative positions, source side
    mb.wait_idle()
    assert mb.actual(1) == -60000 and mb.fault(1) == 0


class ManualClock:
    """The controller's clock, advanced by the test: motion states at exact instants, whatever
    the machine's load (the mock evaluates every motion lazily from ``controller.now``)."""

    def __init__(self, t: float = 1000.0):
        self.t = t

    def __call__(self) -> float:
        return self.t

    def advance(self, dt: float) -> None:
        self.t += dt


def test_motion_takes_time_at_the_axis_velocity(tools):
    with MockInstrument(modbus="tcp", serial="socket", speed="real") as m:
        clock = m.controller.now = ManualClock()
        mb = tools.UmbClient(m.modbus_url)
        mb.write_one(P.HR_CONTROL, P.Control.ENABLE | P.Control.HOME_ALL)
        clock.advance(1.49)                                      # homing takes 1.5 s at real speed
        assert mb.status(0) & P.AxisStatus.MOVING and not mb.status(0) & P.AxisStatus.HOMED
        clock.advance(0.02)
        assert not mb.status(0) & P.AxisStatus.MOVING and mb.status(0) & P.AxisStatus.HOMED
        hi, lo = P.int32_to_registers(30000)
        mb.write(P.axis_target_address(3), [hi, lo, 6000, P.AxisCommand.MOVE])    # 60 deg/s
        clock.advance(0.1)
        assert mb.actual(3) == 6000                              # 0.1 s at 60 deg/s
        assert mb.status(3) & P.AxisStatus.MOVING
        clock.advance(0.39)
        assert mb.actual(3) == 29400 and mb.status(3) & P.AxisStatus.MOVING
        clock.advance(0.01 + 1.0)                                # arrived, settled
        assert mb.actual(3) == 30000 and not mb.status(3) & P.AxisStatus.MOVING
        assert mb.status(3) & P.AxisStatus.IN_POSITION
        mb.close()


def test_move_before_homing_is_fault_3(mb):
    mb.write_one(P.HR_CONTROL, P.Control.ENABLE)
    mb.move(0, 10000)                                  # acknowledged, but refused
    assert mb.fault(0) == P.AxisFault.NOT_HOMED
    assert mb.status(0) & P.AxisStatus.FAULT
    assert mb.read_input(P.IR_STATUS, 1)[0] & P.ControllerStatus.ANY_FAULT
    assert mb.actual(0) == 0
    with pytest.raises(ux.ServerDeviceFailureError):   # latched: reset first
        mb.move(0, 10000)
    mb.write_one(P.HR_CONTROL, P.Control.ENABLE | P.Control.RESET_FAULT)
    assert mb.fault(0) == 0


def test_outside_soft_limits_is_exception_3(mb):
    mb.home()
    with pytest.raises(ux.IllegalDataValueError):
        mb.move(0, 85001)
    with pytest.raises(ux.IllegalDataValueError):
        mb.move(1, -90000)
    assert mb.actual(0) == 0 and mb.fault(0) == 0
    assert mb.read_holding(P.axis_target_address(0), 2) == [0, 0]     # refused write not stored


def test_beam_block_is_fault_4_and_exception_3(mb):
    mb.home()                                          # source 0, detector +45
    with pytest.raises(ux.IllegalDataValueError):
        mb.move(1, 3000)                               # 3 deg from the source direction
    assert mb.fault(1) == P.AxisFault.BEAM_BLOCK
    assert mb.actual(1) == 45000
    mb.write_one(P.HR_CONTROL, P.Control.ENABLE | P.Control.RESET_FAULT)
    mb.move(1, 5000)                                   # exactly 5 deg is allowed
    mb.wait_idle()
    assert mb.actual(1) == 5000 and mb.fault(1) == 0


def test_exception_6_while_homing(tools):
    with MockInstrument(modbus="tcp", serial="socket", speed="real") as m:
        m.controller.now = ManualClock()                         # frozen: homing never ends
        mb = tools.UmbClient(m.modbus_url)
        mb.write_one(P.HR_CONTROL, P.Control.ENABLE | P.Control.HOME_ALL)
        assert mb.status(0) & P.AxisStatus.MOVING      # reads are served while homing
        with pytest.raises(ux.ServerDeviceBusyError):
            mb.move(0, 10000)
        with pytest.raises(ux.ServerDeviceBusyError):
            mb.write_coils(P.COIL_LAMP, [True])
        mb.write_one(P.HR_CONTROL, P.Control.ENABLE | P.Control.STOP_ALL)     # stop is accepted
        assert not mb.status(0) & P.AxisStatus.HOMED
        assert not mb.status(0) & P.AxisStatus.MOVING
        mb.close()


def test_drives_disabled_refuse_homing(mb):
    with pytest.raises(ux.IllegalDataValueError):
        mb.write_one(P.HR_CONTROL, P.Control.HOME_ALL)


def test_coils_and_sample_slot(mb):
    mb.write_coils(P.COIL_LAMP, [True, True])
    assert mb.call(__import__("umodbus.client.tcp", fromlist=["x"]).read_coils(
        slave_id=1, starting_address=0, quantity=2)) == [1, 1]
    mb.write_one(P.HR_SAMPLE_SLOT, P.SampleSlot.WHITE_REFERENCE)
    assert mb.read_holding(P.HR_SAMPLE_SLOT, 1) == [1]
    with pytest.raises(ux.IllegalDataValueError):
        mb.write_one(P.HR_SAMPLE_SLOT, 7)


def test_rtu_over_pty_with_minimalmodbus():
    with MockInstrument(modbus="rtu", serial="pty") as m:
        assert m.modbus_url.startswith("rtu:///dev/")
        path = m.modbus_url[len("rtu://"):]
        inst = minimalmodbus.Instrument(path, P.UNIT_ID)
        for key, value in P.rtu_serial_settings(path).items():
            setattr(inst.serial, key, value)
        inst.serial.timeout = 1.0
        assert inst.read_register(P.IR_FIRMWARE, functioncode=4) == 0x0104
        inst.write_register(P.HR_CONTROL, P.Control.ENABLE | P.Control.HOME_ALL)
        _wait_idle_rtu(inst)
        assert inst.read_long(P.axis_actual_address(1), functioncode=4, signed=True) == 45000
        inst.write_long(P.axis_target_address(0), 20000, signed=True)
        assert inst.read_long(P.axis_target_address(0), functioncode=3, signed=True) == 20000
        inst.write_register(P.axis_command_address(0), P.AxisCommand.MOVE)
        _wait_idle_rtu(inst)
        assert inst.read_long(P.axis_actual_address(0), functioncode=4, signed=True) == 20000
        assert inst.read_register(P.axis_status_address(0), functioncode=4) & P.AxisStatus.IN_POSITION
        with pytest.raises(minimalmodbus.IllegalRequestError):
            inst.write_long(P.axis_target_address(1), -86000, signed=True)
        inst.serial.close()


def _wait_idle_rtu(inst, deadline_s: float = 30.0) -> None:
    """Poll the axes' MOVING bits (a generous deadline, never a fixed sleep)."""
    t_end = time.monotonic() + deadline_s
    while time.monotonic() < t_end:
        if not any(inst.read_register(P.axis_status_address(a), functioncode=4) & P.AxisStatus.MOVING
                   for a in range(P.N_AXES)):
            return
        time.sleep(0.01)
    raise AssertionError("axes still moving")
