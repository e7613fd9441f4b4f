"""The mock goniophotometer in one object: motion controller + photometer head + transports.

``MockInstrument`` runs a Modbus server (TCP on loopback, or RTU over a pseudo-terminal pair)
built on ``pymodbus.simulator.SimDevice`` and the photometer head (on a pseudo-terminal or a
loopback socket) in a background thread with its own asyncio event loop. Both share one
:class:`gonio.mock.motion.MotionController`, so the head knows the geometry, lamp, shutter and
sample slot when it computes counts.

Example
-------
>>> from gonio.mock import MockInstrument
>>> with MockInstrument(sample="lambert:0.5") as mock:          # doctest: +SKIP
...     print(mock.modbus_url, mock.serial_url)
tcp://127.0.0.1:40123 /dev/pts/7
"""

from __future__ import annotations

import asyncio
import ipaddress
import logging
import socket
import threading
from typing import Any
from urllib.parse import urlsplit

import numpy as np

from gonio.instrument import links as LK
from gonio.mock.faults import FaultInjector
from gonio.mock.head import PhotometerHead
from gonio.mock.motion import INTEGRATION_FACTORS, SPEED_FACTORS, ModbusFrontend, MotionController
from gonio.mock.samples import make_sample, reference_beta
from gonio.mock.servers import (
    PtyBridge,
    drop_current_modbus_connection,
    make_dropping_tcp_server,
    serve_head_pty,
    serve_head_socket,
)

__all__ = ["MockInstrument", "MockConfigError", "parse_modbus_option", "parse_serial_option"]

log = logging.getLogger(__name__)


class MockConfigError(ValueError):
    """A bad mock option (non-loopback address, unknown scheme, ...): a user error."""


def _loopback_host(host: str | None, what: str) -> str:
    if host in (None, ""):
        return "127.0.0.1"
    if host == "localhost":
        return "127.0.0.1"
    try:
        ip = ipaddress.ip_address(host)
    except ValueError:
        raise MockConfigError(f"{what}: host {host!r} is not a loopback address; the mock binds "
                              f"to loopback only (use 127.0.0.1)") from None
    if not ip.is_loopback:
        raise MockConfigError(f"{what}: {host} is not a loopback address; the mock binds to "
                              f"loopback only (use 127.0.0.1)")
    return str(ip)


def _url_host(host: str) -> str:
    """A host as it appears in a URL: an IPv6 address in brackets (``[::1]``)."""
    return f"[{host}]" if ":" in host else host


def _check_port_free(host: str, port: int, option: str, scheme: str) -> None:
    """Refuse a port another program already listens on (one line, before any server starts)."""
    if port == 0:
        return
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    with socket.socket(family, socket.SOCK_STREAM) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind((host, port))
        except OSError as exc:
            raise MockConfigError(f"{option} {scheme}://{_url_host(host)}:{port}: cannot listen "
                                  f"there ({exc.strerror}); pick another port, or port 0 for a "
                                  "free one") from None


def _parse_link_option(value: str, option: str, local: str, network: str) -> tuple[str, str, int]:
    """``local``, ``network`` or ``network://127.0.0.1:PORT`` -> ``(kind, host, port)``."""
    if value == local:
        return local, "", 0
    if value == network:
        return network, "127.0.0.1", 0
    parts = urlsplit(value)
    if parts.scheme != network:
        expected = (f"{network}://127.0.0.1:PORT or {local}" if option == "--modbus"
                    else f"{local} or {network}://127.0.0.1:PORT")
        raise MockConfigError(f"{option} {value!r}: expected {expected}")
    try:
        port = parts.port or 0
    except ValueError:
        raise MockConfigError(f"{option} {value!r}: bad port") from None
    return network, _loopback_host(parts.hostname, option), port


def parse_modbus_option(value: str) -> tuple[str, str, int]:
    """``"tcp"``, ``"tcp://127.0.0.1:PORT"`` or ``"rtu"`` -> ``(kind, host, port)``."""
    return _parse_link_option(value, "--modbus", "rtu", "tcp")


def parse_serial_option(value: str) -> tuple[str, str, int]:
    """``"pty"``, ``"socket"`` or ``"socket://127.0.0.1:PORT"`` -> ``(kind, host, port)``."""
    return _parse_link_option(value, "--serial", "pty", "socket")


class MockInstrument:
    """Mock goniophotometer on real protocol endpoints (loopback / pseudo-terminals only).

    Parameters
    ----------
    sample : ``"lambert:RHO"``, ``"red-cotton"`` or a radiance-coefficient dataset directory.
    modbus : ``"tcp"`` (ephemeral port), ``"tcp://127.0.0.1:PORT"`` or ``"rtu"`` (pty pair).
    serial : ``"pty"``, ``"socket"`` (ephemeral port) or ``"socket://127.0.0.1:PORT"``.
    faults : ``--faults`` SPEC (see :mod:`gonio.mock.faults`) or None.
    speed : ``"fast"`` (motion times x0.01, integration times x0.001) or ``"real"``.
    seed : seeds the noise and the fault decisions.

    Attributes (after :meth:`start`)
    --------------------------------
    modbus_url : ``"tcp://127.0.0.1:PORT"`` or ``"rtu:///dev/pts/N"``.
    serial_url : ``"/dev/pts/N"`` or ``"socket://127.0.0.1:PORT"``.
    sample : the truth object (``.beta(theta_i, phi_i, theta_o, phi_o, wavelength_nm)``).
    controller, head : the device models (for tests).
    """

    def __init__(self, sample: str = "lambert:0.5", modbus: str = "tcp", serial: str = "pty",
                 faults: str | None = None, speed: str = "fast", seed: int = 0):
        if speed not in SPEED_FACTORS:
            raise MockConfigError(f"--speed {speed!r}: expected fast or real")
        self._modbus = parse_modbus_option(modbus)
        self._serial = parse_serial_option(serial)
        self.sample = make_sample(sample)
        self.sample_spec = sample
        self.seed = int(seed)
        self.speed = speed
        self.time_scale = SPEED_FACTORS[speed]
        self.faults = FaultInjector(faults, self.seed)
        self.controller = MotionController(time_scale=self.time_scale, faults=self.faults)
        self.head = PhotometerHead(self.controller, self.sample, seed=self.seed, faults=self.faults,
                                   time_scale=self.time_scale, integration_scale=INTEGRATION_FACTORS[speed])
        self.frontend = ModbusFrontend(self.controller, self.faults, link=self._modbus[0])
        self.modbus_url: str | None = None
        self.serial_url: str | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None
        self._ready = threading.Event()
        self._error: BaseException | None = None
        self._closers: list = []
        self._bridge: PtyBridge | None = None

    # --- public API ---------------------------------------------------------------------------
    @property
    def stats(self) -> dict[str, Any]:
        """What the mock served: faults per kind, Modbus requests, dropped links, head commands.

        The dropped requests are listed as ``(function code, address, executed)``.
        """
        return {"faults": {k: int(v) for k, v in self.faults.stats.items() if v},
                "modbus_requests": self.frontend.requests, "modbus_writes": self.frontend.writes,
                "modbus_drops": self.frontend.drops,
                "modbus_dropped": list(self.frontend.dropped),
                "head_commands": self.head.commands}

    @staticmethod
    def reference_beta(wavelength_nm) -> np.ndarray:
        """Calibrated radiance factor of the mock white standard."""
        return reference_beta(wavelength_nm)

    def start(self) -> MockInstrument:
        """Start the servers in a background thread; returns when both endpoints are up."""
        if self._thread is not None:
            return self
        self._thread = threading.Thread(target=self._run, name="gonio-mock", daemon=True)
        self._thread.start()
        self._ready.wait(10.0)
        if self._error is not None:
            self._thread.join(2.0)
            self._thread = None
            self._loop = None
            if self._bridge is not None:
                self._bridge.stop()
                self._bridge = None
            raise self._error
        if not self._ready.is_set():
            raise RuntimeError("mock instrument did not start within 10 s")
        log.info("mock instrument: modbus %s, serial %s, sample %s", self.modbus_url, self.serial_url,
                 self.sample.name)
        return self

    def stop(self) -> None:
        """Stop the servers and the thread (idempotent)."""
        if self._loop is None or self._thread is None:
            return
        try:
            fut = asyncio.run_coroutine_threadsafe(self._shutdown(), self._loop)
            fut.result(5.0)
        except Exception as exc:  # noqa: BLE001 - shutdown is best-effort
            log.warning("mock shutdown: %s", exc)
        self._loop.call_soon_threadsafe(self._loop.stop)
        self._thread.join(5.0)
        self._thread = None
        if self._bridge is not None:
            self._bridge.stop()
            self._bridge = None

    def urls(self) -> tuple[str, str]:
        """The endpoints of the started mock.

        Returns
        -------
        (str, str)
            ``(modbus_url, serial_url)``, the addresses a driver connects to.

        Raises
        ------
        RuntimeError
            If the mock has not been started (:meth:`start`).
        """
        if self.modbus_url is None or self.serial_url is None:
            raise RuntimeError("mock instrument: not started (call start() or use it in a with block)")
        return self.modbus_url, self.serial_url

    def __enter__(self) -> MockInstrument:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    # --- event loop ---------------------------------------------------------------------------
    def _run(self) -> None:
        loop = asyncio.new_event_loop()
        self._loop = loop
        asyncio.set_event_loop(loop)
        try:
            loop.run_until_complete(self._startup())
        except BaseException as exc:  # noqa: BLE001 - reported to start()
            self._error = exc
            self._ready.set()
            loop.close()
            return
        self._ready.set()
        try:
            loop.run_forever()
        finally:
            pending = asyncio.all_tasks(loop)
            for task in pending:
                task.cancel()
            if pending:
                loop.run_until_complete(asyncio.gather(*pending, return_exceptions=True))
            loop.close()

    async def _startup(self) -> None:
        from pymodbus import FramerType
        from pymodbus.server import ModbusSerialServer

        lock = asyncio.Lock()
        kind, host, port = self._modbus
        device = self.frontend.device()
        if kind == "tcp":
            _check_port_free(host, port, "--modbus", "tcp")
            server = make_dropping_tcp_server(device, address=(host, port), ignore_missing_devices=True)
            self.frontend.drop_link = drop_current_modbus_connection
            try:
                await server.serve_forever(background=True)
            except RuntimeError:    # pymodbus: "Could not start listen" (a race with another program)
                raise MockConfigError(f"--modbus tcp://{_url_host(host)}:{port}: cannot listen "
                                      "there; pick another port, or port 0 for a free one") from None
            bound = server.transport.sockets[0].getsockname()[1]
            self.modbus_url = f"tcp://{_url_host(host)}:{bound}"
        else:
            self._bridge = PtyBridge().start()
            path = self._bridge.server_path
            server = ModbusSerialServer(device, framer=FramerType.RTU, port=path,
                                        **LK.rtu_serial_settings(path), ignore_missing_devices=True)
            await server.serve_forever(background=True)
            self.modbus_url = f"rtu://{self._bridge.client_path}"
        self._closers.append(server.shutdown)
        skind, shost, sport = self._serial
        if skind == "pty":
            path, close = await serve_head_pty(self.head, lock)
            self.serial_url = path

            async def aclose() -> None:
                close()
            self._closers.append(aclose)
        else:
            _check_port_free(shost, sport, "--serial", "socket")
            bound, close = await serve_head_socket(self.head, lock, shost, sport)
            self.serial_url = f"socket://{_url_host(shost)}:{bound}"
            self._closers.append(close)

    async def _shutdown(self) -> None:
        for closer in reversed(self._closers):
            try:
                await asyncio.wait_for(closer(), 3.0)
            except Exception as exc:  # noqa: BLE001 - best-effort
                log.warning("mock shutdown step failed: %s", exc)
        self._closers.clear()
