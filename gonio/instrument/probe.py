"""Opening the two links and telling them apart: whether each endpoint is the device it should be.

:func:`open_links` connects both transports and identifies both endpoints (one request each);
only when neither answers as it should are the two URLs tried the other way round, so swapped
URLs are reported at once instead of retrying the wrong protocol for half a minute. A probe lost
to a slow or faulty link never produces that message (it needs two answers).
"""

from __future__ import annotations

import contextlib

from gonio.instrument.modbus_map import IR_FIRMWARE
from gonio.instrument.transport import LinkLost, ModbusTransport, SerialTransport, TransportError, parse_modbus_url

__all__ = ["LinkSetupError", "open_links"]


class LinkSetupError(ValueError):
    """A link cannot be used: a bad URL, an unreachable device, swapped links (one line)."""


def open_links(modbus_url: str, serial_url: str, timeout_s: float = 1.0
               ) -> tuple[ModbusTransport, SerialTransport]:
    """Open the Modbus and serial links and check they are not swapped.

    Raises
    ------
    LinkSetupError : the message names the option (``--modbus``, ``--serial``) concerned.
    """
    try:
        parse_modbus_url(modbus_url)
    except ValueError as exc:
        raise LinkSetupError(f"--modbus {exc}") from None
    modbus = ModbusTransport(modbus_url, timeout_s=timeout_s)
    serial_link = SerialTransport(serial_url, timeout_s=timeout_s)
    for link, opt in ((modbus, "--modbus"), (serial_link, "--serial")):
        try:
            link.open()
        except LinkLost as exc:
            raise LinkSetupError(f"{opt}: cannot reach the device: {exc} (is it on and is the URL "
                                 "right? `gonio mock` starts a mock)") from None
    _check_not_swapped(modbus, serial_link, modbus_url, serial_url, timeout_s)
    return modbus, serial_link


def _answers_modbus(link: ModbusTransport) -> bool:
    """Whether the endpoint answers a Modbus read of the controller's firmware register."""
    try:
        link.exchange({"fn": "read_input_registers", "address": IR_FIRMWARE, "count": 1})
        return True
    except (TransportError, OSError, ValueError):
        return False


def _answers_head(link: SerialTransport) -> bool:
    """Whether the endpoint answers ``*IDN?`` with a line of text (the photometer head does)."""
    try:
        with contextlib.suppress(TransportError, OSError):
            link.drain()
        reply = link.exchange(b"*IDN?\n")
    except (TransportError, OSError, ValueError):
        return False
    text = bytes(reply or b"").strip()
    return bool(text) and all(32 <= b < 127 for b in text) and text.count(b",") >= 2


def _as_serial_url(modbus_url: str) -> str | None:
    if modbus_url.startswith("tcp://"):
        return "socket://" + modbus_url[len("tcp://"):]
    if modbus_url.startswith("rtu://"):
        return modbus_url[len("rtu://"):]
    return None


def _as_modbus_url(serial_url: str) -> str | None:
    if serial_url.startswith("socket://"):
        return "tcp://" + serial_url[len("socket://"):]
    if serial_url.startswith("/"):
        return "rtu://" + serial_url
    return None


def _check_not_swapped(modbus: ModbusTransport, serial_link: SerialTransport, modbus_url: str,
                       serial_url: str, timeout_s: float) -> None:
    if _answers_modbus(modbus) or _answers_head(serial_link):
        return
    as_serial, as_modbus = _as_serial_url(modbus_url), _as_modbus_url(serial_url)
    if as_serial is None or as_modbus is None:
        return
    # the probes open the same devices the other way round; a serial device is opened
    # exclusively (by SerialTransport and by pymodbus), so ours are released first (they
    # reopen at their next exchange)
    for link in (modbus, serial_link):
        link.close()
    probe_head = SerialTransport(as_serial, timeout_s=timeout_s)
    probe_modbus = ModbusTransport(as_modbus, timeout_s=timeout_s)
    try:
        # an RTU server that has just read the head's text resynchronises on the next frame
        swapped = _answers_head(probe_head) and (_answers_modbus(probe_modbus)
                                                 or _answers_modbus(probe_modbus))
    finally:
        for link in (probe_head, probe_modbus):
            with contextlib.suppress(Exception):
                link.close()
    if swapped:
        raise LinkSetupError(f"the links look swapped: --modbus {modbus_url} answers like the "
                             f"photometer head and --serial {serial_url} like the motion "
                             f"controller; exchange the two URLs")
