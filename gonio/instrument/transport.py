r"""Transports: a line-oriented serial link and a Modbus client link, knowing nothing of devices.

Each transport has one primitive, ``exchange(request) -> response``, plus ``open``, ``close``
and ``reconnect``; the two interfaces are typed protocols, :class:`LineTransport` and
:class:`RequestTransport`. Devices (:mod:`gonio.instrument.head`, :mod:`gonio.instrument.motion`)
build requests from the protocol tables and interpret responses; a recording wrapper or a
replaying fake (:mod:`gonio.acquisition.record`) can stand in for a transport because nothing
else crosses these interfaces.

- :class:`SerialTransport` (``channel = "serial"``): ``exchange(b"WAVE 550\n")`` writes the
  command line and returns the raw response bytes up to and including ``\r\n`` - or what arrived
  before the timeout (``b""`` for no answer, a truncated line otherwise); the caller parses with
  :func:`gonio.instrument.head_framing.parse_response`. URLs are anything ``serial.serial_for_url`` opens: a
  device path (``/dev/ttyUSB0``, a pty ``/dev/pts/5``) or ``socket://127.0.0.1:PORT``.
- :class:`ModbusTransport` (``channel = "modbus"``): ``exchange({"fn": "read_input_registers",
  "address": 100, "count": 4})`` returns ``{"registers": [...]}``, ``{"bits": [...]}`` or ``{}``
  for writes, and raises :class:`ModbusExceptionResponse` (with the Modbus exception code),
  :class:`LinkTimeout` (no response) or :class:`LinkLost` (connection dropped or refused). URLs:
  ``tcp://HOST:PORT`` (pymodbus ``ModbusTcpClient``) or ``rtu://DEVICE`` (``ModbusSerialClient``,
  RTU framing, :func:`gonio.instrument.links.rtu_serial_settings`: 19200 8E1, parity N on a
  pseudo-terminal, unless ``?baudrate=..&parity=..`` says otherwise).

pymodbus's own retries are disabled (``retries=0``): the device layer owns the retry policy, so
retries are counted and recorded.

A Modbus TCP connection closed by the server (or the network) shows as pymodbus'
``ConnectionException`` on the request in flight (the client reads EOF): :meth:`ModbusTransport.exchange`
closes the client and raises :class:`LinkLost`; the request may or may not have been executed.
:meth:`ModbusTransport.reconnect` then connects again, retrying a refused connection with bounded
exponential backoff ``delay_k = min(base_s * 2**k, max_s)`` for ``reconnect_attempts`` attempts
(a controller rebooting after a power glitch takes a moment to listen again).
"""

from __future__ import annotations

import logging
import time
import urllib.parse
from collections.abc import Callable
from typing import Any, Protocol

import serial
from pymodbus import FramerType
from pymodbus.client import ModbusSerialClient, ModbusTcpClient
from pymodbus.exceptions import ConnectionException, ModbusException, ModbusIOException

from gonio.instrument import links
from gonio.instrument.head_framing import LINE_TERMINATOR
from gonio.instrument.modbus_map import exception_name

__all__ = ["TransportError", "LinkTimeout", "LinkLost", "ModbusExceptionResponse", "LineTransport",
           "RequestTransport", "SerialTransport", "ModbusTransport", "parse_modbus_url",
           "MODBUS_FUNCTIONS"]

log = logging.getLogger(__name__)

#: Modbus client calls a request may name, with the request fields each takes.
MODBUS_FUNCTIONS = {
    "read_holding_registers": ("address", "count"),
    "read_input_registers": ("address", "count"),
    "read_coils": ("address", "count"),
    "write_registers": ("address", "values"),
    "write_coil": ("address", "value"),
}


class TransportError(Exception):
    """A link-level failure. ``channel`` names the link ("serial" or "modbus")."""

    def __init__(self, channel: str, message: str):
        self.channel = channel
        super().__init__(f"{channel}: {message}")


class LinkTimeout(TransportError):
    """No response before the timeout (transient)."""


class LinkLost(TransportError):
    """The connection dropped or could not be (re)established."""


class ModbusExceptionResponse(TransportError):
    """The server answered a request with a Modbus exception (``code``: 1..11)."""

    def __init__(self, request: dict, code: int):
        self.request = dict(request)
        self.code = int(code)
        super().__init__("modbus", f"{request.get('fn')} at {request.get('address')}: "
                                   f"exception {self.code} ({exception_name(self.code)})")


class LineTransport(Protocol):
    """What the photometer head needs of its link (serial line, socket, recording, replay).

    ``exchange`` sends one command line and returns the raw response line (``b""`` when nothing
    came back before ``timeout_s``, or the link's own timeout); ``drain`` discards anything late
    still on the wire; ``reconnect`` closes and opens again. Link failures raise
    :class:`LinkLost`.
    """

    channel: str
    url: str
    timeout_s: float

    def exchange(self, line: bytes, /, timeout_s: float | None = None) -> bytes:
        """Send one command line and return the reply line (terminator included)."""
        ...

    def drain(self) -> bytes:
        """Discard pending input; return what was dropped."""
        ...

    def reconnect(self) -> None:
        """Close and open the link again."""
        ...

    def open(self) -> None:
        """Open the link."""
        ...

    def close(self) -> None:
        """Close the link."""
        ...


class RequestTransport(Protocol):
    """What the motion controller needs of its link (Modbus client, recording, replay).

    ``exchange`` executes one request dict (:data:`MODBUS_FUNCTIONS`) and returns the response
    dict, or raises :class:`ModbusExceptionResponse`, :class:`LinkTimeout` or :class:`LinkLost`.
    """

    channel: str
    url: str

    def exchange(self, request: dict, /) -> dict:
        """Send one Modbus request and return its response."""
        ...

    def reconnect(self) -> None:
        """Close and open the link again."""
        ...

    def open(self) -> None:
        """Open the link."""
        ...

    def close(self) -> None:
        """Close the link."""
        ...


def parse_modbus_url(url: str) -> dict[str, Any]:
    """Split a Modbus URL into client settings.

    ``tcp://HOST[:PORT]`` (default port 502) or ``rtu://DEVICE[?baudrate=N&parity=E&stopbits=1]``
    (``rtu:///dev/pts/5`` -> device ``/dev/pts/5``). Raises ValueError with the accepted forms.
    """
    parts = urllib.parse.urlsplit(url)
    if parts.scheme == "tcp":
        if not parts.hostname:
            raise ValueError(f"{url}: expected tcp://HOST:PORT")
        try:
            port = parts.port or links.MODBUS_TCP_PORT
        except ValueError:
            raise ValueError(f"{url}: bad port; expected tcp://HOST:PORT") from None
        return {"kind": "tcp", "host": parts.hostname, "port": port}
    if parts.scheme == "rtu":
        device = (parts.netloc + parts.path) if parts.netloc else parts.path
        if not device:
            raise ValueError(f"{url}: expected rtu://DEVICE, e.g. rtu:///dev/ttyUSB0")
        q = urllib.parse.parse_qs(parts.query)
        line = links.rtu_serial_settings(device)     # 19200 8E1; parity N on a pty
        try:
            baud = int(q.get("baudrate", [line["baudrate"]])[0])
            stopbits = int(q.get("stopbits", [line["stopbits"]])[0])
        except ValueError:
            raise ValueError(f"{url}: baudrate and stopbits must be integers") from None
        parity = q.get("parity", [line["parity"]])[0]
        if parity not in ("N", "E", "O"):
            raise ValueError(f"{url}: parity must be N, E or O")
        return {"kind": "rtu", "device": device, "baudrate": baud, "parity": parity,
                "stopbits": stopbits}
    raise ValueError(f"{url}: unsupported Modbus URL; use tcp://HOST:PORT or rtu://DEVICE")


class SerialTransport:
    """Line-oriented serial link over ``serial.serial_for_url`` (see the module docstring).

    Parameters
    ----------
    url : device path or pyserial URL (``socket://HOST:PORT``).
    timeout_s : how long to wait for a complete response line.
    baudrate : line speed (ignored by sockets and ptys).
    """

    channel = "serial"

    def __init__(self, url: str, *, timeout_s: float = 1.0, baudrate: int = links.HEAD_BAUDRATE):
        self.url = url
        self.timeout_s = float(timeout_s)
        self.baudrate = baudrate
        self._port: serial.SerialBase | None = None
        self._buf = bytearray()

    def open(self) -> None:
        """Open the port (no-op when open); raises :class:`LinkLost` when it cannot."""
        if self._port is not None:
            return
        # a device path is opened exclusively (flock on POSIX): a second client on the line is
        # refused at once instead of interleaving its commands with ours; URL handlers
        # (socket://) have no such notion
        exclusive = {} if "://" in self.url else {"exclusive": True}
        try:
            self._port = serial.serial_for_url(self.url, baudrate=self.baudrate,
                                               timeout=min(0.05, self.timeout_s),
                                               write_timeout=self.timeout_s, **exclusive)
        except (serial.SerialException, OSError, ValueError) as exc:
            raise LinkLost(self.channel, f"cannot open {self.url}: {exc}") from None
        self._buf.clear()

    def close(self) -> None:
        """Close the port (idempotent)."""
        if self._port is not None:
            try:
                self._port.close()
            except (serial.SerialException, OSError):
                pass
            self._port = None
        self._buf.clear()

    def reconnect(self) -> None:
        """Close and open again (drops anything buffered)."""
        self.close()
        self.open()

    def _read_some(self, deadline: float) -> bytes:
        # the port's own timeout is a short poll slice (changing it costs a tcsetattr)
        port = self._port
        assert port is not None
        if deadline - time.monotonic() <= 0:
            return b""
        return port.read(max(1, port.in_waiting))

    def drain(self, quiet_s: float = 0.02) -> bytes:
        """Discard input until the line has been quiet for ``quiet_s`` (after a bad response)."""
        self.open()
        dropped = bytes(self._buf)
        self._buf.clear()
        try:
            while True:
                chunk = self._read_some(time.monotonic() + quiet_s)
                if not chunk:
                    return dropped
                dropped += chunk
        except (serial.SerialException, OSError) as exc:
            self.close()
            raise LinkLost(self.channel, f"{self.url}: {exc}") from None

    def exchange(self, line: bytes, timeout_s: float | None = None) -> bytes:
        """Send one command line, return the raw response (``b""`` when nothing came back).

        ``timeout_s`` overrides the link's timeout for this command (e.g. a long ``READ?``).
        """
        self.open()
        port = self._port
        assert port is not None
        try:
            if self._buf or port.in_waiting:
                stale = bytes(self._buf) + port.read(port.in_waiting)
                self._buf.clear()
                log.debug("serial: discarding stale input %r", stale)
            port.write(line)
            deadline = time.monotonic() + (self.timeout_s if timeout_s is None else timeout_s)
            while True:
                k = self._buf.find(LINE_TERMINATOR)
                if k >= 0:
                    out = bytes(self._buf[:k + 2])
                    del self._buf[:k + 2]
                    return out
                chunk = self._read_some(deadline)
                if not chunk:
                    if time.monotonic() >= deadline:
                        out = bytes(self._buf)
                        self._buf.clear()
                        return out
                    continue
                self._buf += chunk
        except (serial.SerialException, OSError) as exc:
            self.close()
            raise LinkLost(self.channel, f"{self.url}: {exc}") from None


class ModbusTransport:
    """Modbus client link (pymodbus 3.16 sync clients, TCP or RTU); see the module docstring."""

    channel = "modbus"

    def __init__(self, url: str, *, device_id: int = links.UNIT_ID, timeout_s: float = 1.0,
                 reconnect_attempts: int = 6, reconnect_base_s: float = 0.01,
                 reconnect_max_s: float = 0.5, sleep: Callable[[float], None] = time.sleep):
        self.url = url
        self.settings = parse_modbus_url(url)
        self.device_id = device_id
        self.timeout_s = float(timeout_s)
        self.reconnect_attempts = max(1, int(reconnect_attempts))
        self.reconnect_base_s = float(reconnect_base_s)
        self.reconnect_max_s = float(reconnect_max_s)
        self.sleep = sleep
        self.reconnects = 0          # successful reconnections (for logs and tests)
        self._client: ModbusTcpClient | ModbusSerialClient | None = None

    def _make_client(self):
        s = self.settings
        if s["kind"] == "tcp":
            return ModbusTcpClient(s["host"], port=s["port"], timeout=self.timeout_s, retries=0,
                                   reconnect_delay=0)
        return ModbusSerialClient(s["device"], framer=FramerType.RTU, baudrate=s["baudrate"],
                                  bytesize=links.RTU_BYTESIZE, parity=s["parity"],
                                  stopbits=s["stopbits"], timeout=self.timeout_s, retries=0,
                                  reconnect_delay=0)

    def open(self) -> None:
        """Connect (no-op when connected); raises :class:`LinkLost` when the server is unreachable."""
        if self._client is not None and self._client.connected:
            return
        if self._client is None:
            self._client = self._make_client()
        if not self._client.connect():
            self._client.close()
            self._client = None
            raise LinkLost(self.channel, f"cannot connect to {self.url}")

    def close(self) -> None:
        """Disconnect (idempotent)."""
        if self._client is not None:
            self._client.close()
            self._client = None

    def reconnect(self) -> None:
        """Drop the connection and connect again (also flushes late responses).

        A refused connection is retried with bounded backoff (see the module docstring); raises
        :class:`LinkLost` when every attempt failed.
        """
        last: LinkLost | None = None
        for k in range(self.reconnect_attempts):
            self.close()
            try:
                self.open()
            except LinkLost as exc:
                last = exc
                if k + 1 < self.reconnect_attempts:
                    delay = min(self.reconnect_base_s * 2.0**k, self.reconnect_max_s)
                    log.info("modbus: reconnect attempt %d failed (%s); next in %.3f s", k + 1, exc,
                             delay)
                    self.sleep(delay)
                continue
            self.reconnects += 1
            if k:
                log.info("modbus: reconnected to %s after %d attempts", self.url, k + 1)
            return
        assert last is not None
        raise LinkLost(self.channel, f"{last} ({self.reconnect_attempts} attempts)")

    def exchange(self, request: dict) -> dict:
        """Execute one request (see :data:`MODBUS_FUNCTIONS`); see the module docstring."""
        fn = request.get("fn")
        if fn not in MODBUS_FUNCTIONS:
            raise ValueError(f"unknown Modbus request {request!r}")
        self.open()
        client = self._client
        assert client is not None
        address = int(request["address"])
        try:
            if fn == "write_registers":
                rr = client.write_registers(address, [int(v) for v in request["values"]],
                                            device_id=self.device_id)
            elif fn == "write_coil":
                rr = client.write_coil(address, bool(request["value"]), device_id=self.device_id)
            else:
                rr = getattr(client, fn)(address, count=int(request["count"]),
                                         device_id=self.device_id)
        except ModbusIOException as exc:
            raise LinkTimeout(self.channel, f"{fn} at {address}: no response ({exc})") from None
        except ConnectionException as exc:
            self.close()
            raise LinkLost(self.channel, f"{self.url}: {exc}") from None
        except (ModbusException, OSError) as exc:
            self.close()
            raise LinkLost(self.channel, f"{self.url}: {exc}") from None
        if rr.isError():
            code = getattr(rr, "exception_code", None)
            if code is None:
                raise LinkTimeout(self.channel, f"{fn} at {address}: {rr}")
            raise ModbusExceptionResponse(request, code)
        if fn in ("read_holding_registers", "read_input_registers"):
            regs = [int(v) for v in rr.registers[: int(request["count"])]]
            if len(regs) != int(request["count"]):
                raise LinkTimeout(self.channel, f"{fn} at {address}: short response {regs}")
            return {"registers": regs}
        if fn == "read_coils":
            return {"bits": [bool(b) for b in rr.bits[: int(request["count"])]]}
        return {}
