"""Link settings of the two buses: Modbus TCP/RTU framing parameters and the head's serial line.

The driver's transports (:mod:`gonio.instrument.transport`) and the mock's servers
(:mod:`gonio.mock.servers`) both read these, so both ends of a link always agree.

References
----------
docs/instrument.md (the protocol contract of this project).
"""

from __future__ import annotations

__all__ = ["UNIT_ID", "MODBUS_TCP_PORT", "RTU_BAUDRATE", "RTU_BYTESIZE", "RTU_PARITY", "RTU_STOPBITS",
           "HEAD_BAUDRATE", "is_pseudo_terminal", "rtu_serial_settings"]

UNIT_ID = 1
"""Modbus unit (device) id of the motion controller."""
MODBUS_TCP_PORT = 502
RTU_BAUDRATE = 19200
RTU_BYTESIZE = 8
RTU_PARITY = "E"
RTU_STOPBITS = 1
HEAD_BAUDRATE = 115200
"""The photometer head's RS-232 line: 115200 baud, 8N1."""


def is_pseudo_terminal(port: str) -> bool:
    """True for a pseudo-terminal device path (``/dev/pts/N``, ``/dev/ptyXX``, ``/dev/ttypXX``).

    Examples
    --------
    >>> is_pseudo_terminal("/dev/pts/5"), is_pseudo_terminal("/dev/ttyUSB0")
    (True, False)
    """
    return str(port).startswith(("/dev/pts/", "/dev/pty", "/dev/ttyp"))


def rtu_serial_settings(port: str) -> dict:
    """Serial settings (pyserial keyword arguments) of the Modbus RTU line on ``port``.

    19200 baud, 8 data bits, even parity, 1 stop bit - except on a pseudo-terminal, which has no
    parity bit: recent Linux kernels refuse ``PARENB`` on a pty (``termios.error`` EINVAL), so
    both ends of a pty use parity ``"N"`` (the framing on a pty is byte-exact anyway). The driver
    and the mock both call this, so they always agree.

    Examples
    --------
    >>> rtu_serial_settings("/dev/ttyUSB0")["parity"], rtu_serial_settings("/dev/pts/3")["parity"]
    ('E', 'N')
    """
    parity = "N" if is_pseudo_terminal(port) else RTU_PARITY
    return {"baudrate": RTU_BAUDRATE, "bytesize": RTU_BYTESIZE, "parity": parity, "stopbits": RTU_STOPBITS}
