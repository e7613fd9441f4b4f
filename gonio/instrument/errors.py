"""What the devices raise: one error a device reports to its caller, and its two special cases.

A :class:`DeviceError` names the device, the command and (when the instrument gave one) the code,
so that the command line can print one line that says what failed and where.
"""

from __future__ import annotations

from gonio.instrument.modbus_map import AXES, AxisFault

__all__ = ["DeviceError", "AxisFaultError", "InstrumentTaken"]


class DeviceError(RuntimeError):
    """A device refused a command or kept failing: ``device``, ``command``, ``code``."""

    def __init__(self, device: str, command: str, message: str, code: int | None = None,
                 transient: bool = False):
        self.device, self.command, self.code, self.transient = device, command, code, transient
        super().__init__(f"{device}: {command}: {message}")


class AxisFaultError(DeviceError):
    """An axis latched a fault (``code``: :class:`gonio.instrument.modbus_map.AxisFault`)."""

    def __init__(self, axis: int, code: int, command: str):
        self.axis = axis
        try:
            name = AxisFault(code).name.lower().replace("_", " ")
        except ValueError:
            name = "unknown fault"
        super().__init__("motion controller", command,
                         f"axis {axis} ({AXES[axis].name}) fault {code} ({name})", code)


class InstrumentTaken(DeviceError):
    """Another client wrote its owner token into the controller: the instrument is not ours."""

    def __init__(self, ours: int, found: int, what: str):
        self.ours, self.found = ours, found
        super().__init__("motion controller", what,
                         f"another client took the instrument (owner token {found:#010x}, ours "
                         f"{ours:#010x}); nothing measured after that is kept")
