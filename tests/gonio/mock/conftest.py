"""Shared helpers of the mock tests: independent Modbus clients (umodbus over TCP, minimalmodbus
over RTU) and a bare pyserial client for the head."""

from __future__ import annotations

import socket
import time

import pytest
import serial
from umodbus.client import tcp as umb

from gonio import instrument as P
from gonio.mock import MockInstrument


class UmbClient:
    """umodbus over a loopback TCP socket (independent of pymodbus)."""

    def __init__(self, url: str, timeout: float = 2.0):
        host, port = url[len("tcp://"):].rsplit(":", 1)
        self.sock = socket.create_connection((host, int(port)), timeout=timeout)

    def call(self, message):
        return umb.send_message(message, self.sock)

    def read_input(self, addr, count):
        return self.call(umb.read_input_registers(slave_id=P.UNIT_ID, starting_address=addr, quantity=count))

    def read_holding(self, addr, count):
        return self.call(umb.read_holding_registers(slave_id=P.UNIT_ID, starting_address=addr, quantity=count))

    def write(self, addr, values):
        return self.call(umb.write_multiple_registers(slave_id=P.UNIT_ID, starting_address=addr, values=list(values)))

    def write_one(self, addr, value):
        return self.call(umb.write_single_register(slave_id=P.UNIT_ID, address=addr, value=value))

    def write_coils(self, addr, bits):
        return self.call(umb.write_multiple_coils(slave_id=P.UNIT_ID, starting_address=addr, values=[int(b) for b in bits]))

    def actual(self, a):
        return P.registers_to_int32(*self.read_input(P.axis_actual_address(a), 2))

    def status(self, a):
        return self.read_input(P.axis_status_address(a), 1)[0]

    def fault(self, a):
        return self.read_input(P.axis_fault_address(a), 1)[0]

    def move(self, a, mdeg, velocity_cdeg_s=P.DEFAULT_VELOCITY_CDEG_S):
        hi, lo = P.int32_to_registers(mdeg)
        return self.write(P.axis_target_address(a), [hi, lo, velocity_cdeg_s, P.AxisCommand.MOVE])

    def wait_idle(self, timeout=30.0):
        t_end = time.monotonic() + timeout
        while time.monotonic() < t_end:
            if not any(self.status(a) & P.AxisStatus.MOVING for a in range(P.N_AXES)):
                return
            time.sleep(0.005)
        raise AssertionError("axes still moving")

    def home(self):
        self.write_one(P.HR_CONTROL, P.Control.ENABLE | P.Control.HOME_ALL)
        self.wait_idle()

    def close(self):
        self.sock.close()


class HeadClient:
    """A bare pyserial client: one command line out, one raw response line back."""

    def __init__(self, url: str, timeout: float = 2.0):
        self.port = serial.serial_for_url(url, timeout=timeout)

    def raw(self, command: str | bytes) -> bytes:
        data = command.encode() if isinstance(command, str) else command
        self.port.write(data if data.endswith(b"\n") else data + b"\n")
        return self.port.readline()

    def ask(self, command: str, expect: str = "text", chk: bool = False):
        return P.parse_response(self.raw(command), chk=chk, expect=expect)

    def close(self):
        self.port.close()


@pytest.fixture
def mock():
    with MockInstrument(sample="lambert:0.5", modbus="tcp", serial="socket", seed=7) as m:
        yield m


@pytest.fixture
def mb(mock):
    c = UmbClient(mock.modbus_url)
    yield c
    c.close()


@pytest.fixture
def head(mock):
    h = HeadClient(mock.serial_url)
    yield h
    h.close()


def prepare(mb: UmbClient, lamp=True, shutter=True):
    """Home, lamp and shutter: ready for readings at the home geometry (0/45)."""
    mb.home()
    mb.write_coils(P.COIL_LAMP, [lamp, shutter])


@pytest.fixture
def tools():
    """The helper classes, for tests that build their own mocks."""
    import types

    return types.SimpleNamespace(UmbClient=UmbClient, HeadClient=HeadClient, prepare=prepare)
