"""Declarative access to Modbus registers: descriptors over the rows of the register map.

PyMeasure habit: a device class is mostly a list of named controls. A
:class:`Coil`, :class:`HoldingRegister` or :class:`InputRegister` attribute names a row of
:data:`gonio.instrument.modbus_map.MODBUS_MAP`; reading the attribute reads the register and
decodes it, assigning writes it after the row's validator accepted the value. A per-axis
register reads and writes per axis: ``controller.velocity[2] = 500``.

:class:`ModbusDevice` is the base of such a device: one request with the shared
:class:`~gonio.instrument.retry.RetryPolicy` (:meth:`ModbusDevice.call`), and reads and writes
of contiguous rows in one request (:meth:`ModbusDevice.read_rows`, :meth:`ModbusDevice.write_rows`),
which the device's methods use where several registers travel together (an axis' target,
velocity and command in one write).

Examples
--------
>>> class Lamp(ModbusDevice):
...     lamp = Coil("LAMP")
>>> Lamp.lamp.register.address, Lamp.lamp.register.table
(0, 'coil')
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Any

from gonio.instrument.errors import DeviceError
from gonio.instrument.modbus_map import COIL, HOLDING, INPUT, MODBUS_MAP, ModbusException, Register, exception_name
from gonio.instrument.retry import Failure, RetryPolicy
from gonio.instrument.transport import LinkLost, LinkTimeout, ModbusExceptionResponse, RequestTransport

__all__ = ["ModbusDevice", "Coil", "HoldingRegister", "InputRegister"]

log = logging.getLogger(__name__)

_READ_FN = {COIL: "read_coils", HOLDING: "read_holding_registers", INPUT: "read_input_registers"}


class ModbusDevice:
    """A device over a :class:`~gonio.instrument.transport.RequestTransport` with retries.

    Parameters
    ----------
    transport : the Modbus link.
    retry : the shared retry policy (its counter collects the retries).
    busy_timeout_s : longest backoff spent on exception 6 (busy) for one request.
    """

    name = "modbus device"

    def __init__(self, transport: RequestTransport, retry: RetryPolicy | None = None, *,
                 busy_timeout_s: float = 30.0):
        self.transport = transport
        self.retry = retry or RetryPolicy()
        self.busy_timeout_s = busy_timeout_s

    # --- one request ----------------------------------------------------------------------
    def call(self, request: dict, what: str, *,
             took_effect: Callable[[], bool] | None = None) -> dict:
        """One Modbus request with retries (busy, no response, dropped link).

        Exception 6 (busy, e.g. still homing after an earlier session) is retried for up to
        ``busy_timeout_s`` of backoff; the other transient failures as many times as the
        adaptive budget of the ``"modbus"`` link allows (:mod:`gonio.instrument.retry`).
        After an unanswered attempt (timeout, dropped link) and the reconnection,
        ``took_effect()`` (when given) asks the controller whether the request was executed
        anyway; if so it is not sent again and ``{}`` is returned.
        """
        def classify(exc: Exception) -> Failure | None:
            if isinstance(exc, ModbusExceptionResponse):
                if exc.code != ModbusException.DEVICE_BUSY:
                    raise DeviceError(self.name, what, f"Modbus exception {exc.code} "
                                                       f"({exception_name(exc.code)})", exc.code) from None
                return Failure("modbus_busy", busy=True)
            if isinstance(exc, LinkTimeout):
                return Failure("modbus_no_response", recover=self._reconnect, unanswered=True)
            if isinstance(exc, LinkLost):
                log.info("%s: %s: %s; reconnecting", self.name, what, exc)
                return Failure("modbus_link_lost", recover=self._reconnect, unanswered=True)
            return None

        return self.retry.run(lambda: self.transport.exchange(request), classify, device=self.name,
                              what=what, took_effect=took_effect,
                              busy_timeout_s=self.busy_timeout_s, executed={}, link="modbus")

    def _reconnect(self) -> None:
        try:
            self.transport.reconnect()
        except LinkLost as exc:
            log.warning("%s: reconnect failed: %s", self.name, exc)

    # --- raw registers ----------------------------------------------------------------------
    def read_input(self, address: int, count: int, what: str) -> list[int]:
        """Read input registers."""
        return self.call({"fn": "read_input_registers", "address": address, "count": count},
                         what)["registers"]

    def read_holding(self, address: int, count: int, what: str) -> list[int]:
        """Read holding registers."""
        return self.call({"fn": "read_holding_registers", "address": address, "count": count},
                         what)["registers"]

    def write(self, address: int, values: list[int], what: str, *,
              took_effect: Callable[[], bool] | None = None) -> None:
        """Write holding registers (``took_effect``: see :meth:`call`)."""
        self.call({"fn": "write_registers", "address": address, "values": [int(v) for v in values]},
                  what, took_effect=took_effect)

    def write_coil(self, address: int, value: bool, what: str) -> None:
        """Write one coil."""
        self.call({"fn": "write_coil", "address": address, "value": bool(value)}, what)

    # --- rows of the register map ---------------------------------------------------------
    @staticmethod
    def _span(names: tuple[str, ...], axis: int | None) -> tuple[list[Register], int, int]:
        rows = [MODBUS_MAP[n] for n in names]
        start = rows[0].address_of(axis)
        address = start
        for r in rows:
            if r.table != rows[0].table or r.address_of(axis) != address:
                raise ValueError(f"registers {names} are not contiguous in one table")
            address += r.words
        return rows, start, address - start

    def read_rows(self, names: tuple[str, ...], axis: int | None, what: str) -> dict[str, Any]:
        """Read contiguous rows (of axis ``axis`` when per-axis) in one request, decoded."""
        rows, start, count = self._span(names, axis)
        request = {"fn": _READ_FN[rows[0].table], "address": start, "count": count}
        reply = self.call(request, what)
        words = reply["bits"] if rows[0].table == COIL else reply["registers"]
        out, k = {}, 0
        for r in rows:
            out[r.name] = r.decode(list(words[k:k + r.words]))
            k += r.words
        return out

    def write_rows(self, values: dict[str, int], axis: int | None, what: str, *,
                   took_effect: Callable[[], bool] | None = None) -> None:
        """Write contiguous rows (in the order given) in one request.

        A coil is written alone (``write_coil``); holding registers together
        (``write_registers``). Every value is first validated by its row of the register map
        (:meth:`~gonio.instrument.modbus_map.Register.refusal`: what the controller would refuse
        with exception 3 is refused here, nothing sent): the one validation path of every write,
        a descriptor's or a group's.
        """
        rows, start, _ = self._span(tuple(values), axis)
        for r in rows:
            if r.access != "rw":
                raise ValueError(f"{r.name} is read-only")
            why = r.refusal(int(values[r.name]), axis)
            if why is not None:     # refused here: the controller would answer exception 3
                raise DeviceError(self.name, what, why, int(ModbusException.ILLEGAL_VALUE))
        if rows[0].table == COIL:
            if len(rows) != 1:
                raise ValueError("one coil per write")
            self.write_coil(start, bool(values[rows[0].name]), what)
            return
        if rows[0].table != HOLDING:
            raise ValueError(f"{rows[0].name} is read-only")
        words = [w for r in rows for w in r.encode(values[r.name])]
        self.write(start, words, what, took_effect=took_effect)


class _PerAxis:
    """``device.register[axis]`` access of a per-axis register descriptor."""

    def __init__(self, device: ModbusDevice, control: _RegisterControl):
        self.device, self.control = device, control

    def __getitem__(self, axis: int):
        return self.control.read(self.device, axis)

    def __setitem__(self, axis: int, value) -> None:
        self.control.write(self.device, value, axis)


class _RegisterControl:
    """A named register of a :class:`ModbusDevice` (see the module docstring)."""

    table = ""

    def __init__(self, register: str, doc: str | None = None):
        self.register = MODBUS_MAP[register]
        if self.register.table != self.table:
            raise ValueError(f"{register} is a {self.register.table} register, not a {self.table}")
        self.__doc__ = doc or self.register.doc
        self.attr = register.lower()

    def __set_name__(self, owner, name: str) -> None:
        self.attr = name

    @classmethod
    def rows(cls, *registers: str) -> tuple[_RegisterControl, ...]:
        """One descriptor per named row, to unpack into class attributes."""
        return tuple(cls(r) for r in registers)

    def read(self, device: ModbusDevice, axis: int | None, what: str | None = None):
        """The register's decoded value (``what``: the context named in an error)."""
        where = f" of axis {axis}" if axis is not None else ""
        return device.read_rows((self.register.name,), axis,
                                what or f"read {self.attr}{where}")[self.register.name]

    def write(self, device: ModbusDevice, value, axis: int | None, what: str | None = None, *,
              took_effect: Callable[[], bool] | None = None) -> None:
        """Write the register, validated by :meth:`ModbusDevice.write_rows`.

        ``took_effect``: see :meth:`ModbusDevice.call`.
        """
        if self.register.access != "rw":
            raise AttributeError(f"{self.attr} is read-only")
        where = f" of axis {axis}" if axis is not None else ""
        device.write_rows({self.register.name: value}, axis, what or f"write {self.attr}{where}",
                          took_effect=took_effect)

    def __get__(self, obj, owner=None):
        if obj is None:
            return self
        return _PerAxis(obj, self) if self.register.per_axis else self.read(obj, None)

    def __set__(self, obj, value) -> None:
        if self.register.per_axis:
            raise AttributeError(f"{self.attr} is per axis: assign {self.attr}[axis] = value")
        self.write(obj, value, None)


class Coil(_RegisterControl):
    """A coil of the register map (read/write, a bool)."""

    table = COIL


class HoldingRegister(_RegisterControl):
    """A holding register of the register map (read/write, validated by its row)."""

    table = HOLDING


class InputRegister(_RegisterControl):
    """An input register of the register map (read-only)."""

    table = INPUT
