"""The two instrument devices, declared over transports from the tables of :mod:`gonio.protocol`.

PyMeasure habit: a device class is mostly a list of named controls mapping to the instrument's
query/set commands (the command table lives once, in :mod:`gonio.protocol`, shared with the mock);
behaviour is a few methods; :meth:`shutdown` always leaves the instrument safe.

- :class:`PhotometerHead` (ASCII over a :class:`~gonio.transport.SerialTransport`):
  ``idn``, ``wavelength_nm``, ``itime_ms``, ``gain``, ``shutter_open``, ``temperature_c``,
  ``bandwidth_nm``, :meth:`~PhotometerHead.read`, :meth:`~PhotometerHead.measure` (set + read as
  one retryable unit), checksum mode, :meth:`~PhotometerHead.error_queue`.
- :class:`MotionController` (Modbus over a :class:`~gonio.transport.ModbusTransport`):
  :meth:`~MotionController.enable`, :meth:`~MotionController.home`,
  :meth:`~MotionController.move_to` (waits for in-position), :meth:`~MotionController.stop`,
  status and fault decoding, lamp and shutter coils, the reference slot (sample changer).

Retries (:class:`RetryPolicy`) are bounded with exponential backoff
``delay_k = min(base_s * factor**k, max_s)`` and counted per kind in a shared
:class:`collections.Counter` (kinds: :data:`RETRY_KINDS`). What is not transient raises
:class:`DeviceError`, whose message names the device, the command and the code.

Unanswered writes: a Modbus request that got no answer (timeout, dropped connection) may or may
not have been executed. Reads and idempotent writes (coils, CONTROL, the sample slot) are simply
sent again after reconnecting. ``HOME_ALL`` is first checked (every axis' COMMAND is HOME and it is
homing or homed at rest): re-sent during homing it would be refused as busy and then restart the
homing. A move command is first checked against the controller:
after reconnecting, the axis' TARGET, VELOCITY and COMMAND registers and its state are read back,
and the move is re-issued unless the controller shows that very move under way or done (or
faulted: the wait reports the fault) - it is never assumed to have happened; and it is never
re-sent to an axis that is no longer homed (a controller that rebooted behind the dropped link):
that is reported as fault 3 (not homed) and the engine re-homes.

Claiming the instrument: a session writes a random owner token into the controller's OWNER
registers (:meth:`MotionController.claim`) and checks it before every move to a point and before
journaling each point and the calibration (:meth:`MotionController.check_owner`); when another
client has written its own token, :class:`InstrumentTaken` (a :class:`DeviceError`) stops the
session safely and what was measured since the last check is not kept. :meth:`shutdown` clears
the token if it is still ours. The engine also reads the shutter back after each point's
readings: a shutter closed under the session (another client's safe stop) discards the point. The head's serial line is opened exclusively where the platform
supports it (:class:`gonio.transport.SerialTransport`), so a second client on the same line is
refused at once.

Axis-fault recovery (:meth:`MotionController.clear_faults`): stop all, wait until no axis moves
(an axis still moving when another one faulted may fault after a reset), read every FAULT code,
reset only :data:`RECOVERABLE_FAULTS` (anything else raises: the engine stops safely), then home.
"""

from __future__ import annotations

import collections
import itertools
import logging
import math
import time
from dataclasses import dataclass, field
from typing import Callable

from gonio import protocol
from gonio.calibration import pooled_mean
from gonio.protocol import AxisFault, AxisStatus, Control, SampleSlot
from gonio.transport import LinkLost, LinkTimeout, ModbusExceptionResponse

__all__ = ["DeviceError", "AxisFaultError", "InstrumentTaken", "RetryPolicy", "Measurement", "PhotometerHead",
           "MotionController", "RETRY_KINDS", "RECOVERABLE_FAULTS", "AxisState"]

log = logging.getLogger(__name__)

#: Retry counter kinds (keys of the counter stored in a run's meta).
#: ``link_lost`` is the head's link, ``modbus_link_lost`` the motion controller's (a dropped
#: Modbus TCP connection, re-established by :meth:`gonio.transport.ModbusTransport.reconnect`).
RETRY_KINDS = ("serial_timeout", "serial_garbled", "serial_truncated", "serial_checksum",
               "head_busy", "lamp_unstable", "modbus_busy", "modbus_no_response", "link_lost",
               "axis_fault", "modbus_link_lost")

#: Axis faults the driver may reset (CONTROL bit3) and recover from by re-homing: a following
#: error (transient) and "not homed" (a move that reached an axis which had lost its homing).
#: A beam-block fault (4) means the driver commanded a forbidden geometry: never reset blindly.
RECOVERABLE_FAULTS = (int(AxisFault.FOLLOWING_ERROR), int(AxisFault.NOT_HOMED))
_HOME_ATTEMPTS = 3

_FRAMING_KIND = {
    protocol.NoResponse: "serial_timeout",
    protocol.TruncatedResponse: "serial_truncated",
    protocol.ChecksumError: "serial_checksum",
    protocol.GarbledResponse: "serial_garbled",
    protocol.BusyError: "head_busy",
}


class DeviceError(RuntimeError):
    """A device refused a command or kept failing: ``device``, ``command``, ``code``."""

    def __init__(self, device: str, command: str, message: str, code: int | None = None,
                 transient: bool = False):
        self.device, self.command, self.code, self.transient = device, command, code, transient
        super().__init__(f"{device}: {command}: {message}")


class AxisFaultError(DeviceError):
    """An axis latched a fault (``code``: :class:`gonio.protocol.AxisFault`)."""

    def __init__(self, axis: int, code: int, command: str):
        self.axis = axis
        try:
            name = AxisFault(code).name.lower().replace("_", " ")
        except ValueError:
            name = "unknown fault"
        super().__init__("motion controller", command,
                         f"axis {axis} ({protocol.AXES[axis].name}) fault {code} ({name})", code)


class InstrumentTaken(DeviceError):
    """Another client wrote its owner token into the controller: the instrument is not ours."""

    def __init__(self, ours: int, found: int, what: str):
        self.ours, self.found = ours, found
        super().__init__("motion controller", what,
                         f"another client took the instrument (owner token {found:#010x}, ours "
                         f"{ours:#010x}); nothing measured after that is kept")


@dataclass
class RetryPolicy:
    """Bounded retries with exponential backoff; ``sleep`` is injectable (replay: no wait)."""

    attempts: int = 6
    base_s: float = 0.005
    factor: float = 2.0
    max_s: float = 0.25
    sleep: Callable[[float], None] = time.sleep
    counts: collections.Counter = field(default_factory=collections.Counter)

    def delay(self, k: int) -> float:
        """Backoff before retry number ``k`` (0-based)."""
        return min(self.base_s * self.factor**k, self.max_s)

    def count(self, kind: str) -> None:
        """Count one retry of ``kind``."""
        self.counts[kind] += 1


@dataclass(frozen=True)
class Measurement:
    """A usable head reading: mean and standard error (counts), ``n``, or saturated."""

    mean: float
    sem: float
    n: int
    saturated: bool = False


class _Control:
    """A named head setting: ``get`` query and ``set`` command keys of ``HEAD_COMMANDS``."""

    def __init__(self, get: str | None, set_: str | None, doc: str,
                 to_wire: Callable | None = None, from_wire: Callable | None = None):
        self.get, self.set_, self.__doc__ = get, set_, doc
        self.to_wire, self.from_wire = to_wire, from_wire

    def __set_name__(self, owner, name):
        self.name = name

    def __get__(self, obj, owner=None):
        if obj is None:
            return self
        if self.get is None:
            raise AttributeError(f"{self.name} is write-only")
        v = obj.query(self.get)
        return self.from_wire(v) if self.from_wire else v

    def __set__(self, obj, value):
        if self.set_ is None:
            raise AttributeError(f"{self.name} is read-only")
        obj.query(self.set_, self.to_wire(value) if self.to_wire else value)


class PhotometerHead:
    """The spectro-photometer head (INSTRUMENT.md), over a line transport.

    Parameters
    ----------
    transport : object with ``exchange(bytes) -> bytes``, ``reconnect()``, ``close()``.
    retry : shared :class:`RetryPolicy` (its counter collects the retries).
    checksum : turn checksum mode on at :meth:`connect` (recommended).
    """

    name = "photometer head"

    wavelength_nm = _Control("WAVE?", "WAVE", "Monochromator wavelength, 380.0..780.0 nm.",
                             to_wire=lambda v: float(round(float(v), 1)))
    bandwidth_nm = _Control("BW?", None, "Spectral bandwidth, nm (read-only).")
    itime_ms = _Control("ITIME?", "ITIME", "Integration time, 1..10000 ms.", to_wire=int)
    gain = _Control("GAIN?", "GAIN", "Amplifier gain step 0..3 (x1, x4, x16, x64).", to_wire=int)
    shutter_open = _Control("SHUTTER?", "SHUTTER", "Source shutter: True when open.",
                            to_wire=lambda v: "OPEN" if v else "CLOSE",
                            from_wire=lambda w: w == "OPEN")
    temperature_c = _Control("TEMP?", None, "Detector temperature, deg C (read-only).")

    def __init__(self, transport, retry: RetryPolicy | None = None, *, checksum: bool = True):
        self.transport = transport
        self.retry = retry or RetryPolicy()
        self.want_checksum = checksum
        self.chk = False
        self.identity: protocol.Identity | None = None
        # settings the head is known to hold (WAVE, ITIME, GAIN, SHUTTER), since the last
        # forget_settings(); anything unusual (a resync, a reconnect, *RST) forgets them
        self._known: dict[str, object] = {}

    # --- low level ------------------------------------------------------------------------
    def _exchange_once(self, cmd: protocol.HeadCommand, value, timeout_s: float | None = None):
        line = cmd.format(value)
        raw = (self.transport.exchange(line) if timeout_s is None
               else self.transport.exchange(line, timeout_s=timeout_s))
        chk = self.chk or (cmd.key == "CHK" and value == "ON")
        if cmd.key == "CHK" and value == "OFF":
            chk = False
        return protocol.parse_response(raw, chk=chk, expect=cmd.response)

    def query(self, key: str, value=None):
        """Send one command of the table and return its parsed reply, retrying what is transient."""
        cmd = protocol.HEAD_COMMANDS[key]
        try:
            cmd.format(value)
        except ValueError as exc:
            raise DeviceError(self.name, cmd.syntax, f"invalid parameter {value!r}: {exc}") from None
        out = self._retrying(lambda: self._exchange_once(cmd, value), self._describe(key, value))
        if key in _SETTINGS:
            self._known[key] = value
        elif key == "*RST":
            self._known.clear()
        return out

    def forget_settings(self) -> None:
        """Forget the settings the head is known to hold: the next :meth:`measure` sends all."""
        self._known.clear()

    @staticmethod
    def _describe(key: str, value) -> str:
        return key if value is None else f"{key} {value}"

    def _retrying(self, action: Callable, what: str):
        last: Exception | None = None
        for k in range(self.retry.attempts):
            try:
                return action()
            except protocol.HeadError as exc:
                if not exc.transient:
                    raise DeviceError(self.name, what, f"ERR {exc.code} ({exc.message})",
                                      exc.code) from None
                last = exc
                self.retry.count("head_busy")
            except protocol.ProtocolError as exc:
                last = exc
                self.retry.count(_FRAMING_KIND.get(type(exc), "serial_garbled"))
                # silence or a reply without its checksum may mean the head's link was reset
                # (checksum mode off): resynchronise and restore the checksum mode
                self._resync(restore=isinstance(exc, (protocol.NoResponse, protocol.ChecksumError)))
            except LinkLost as exc:
                last = exc
                self.retry.count("link_lost")
                self._reconnect()
            self.retry.sleep(self.retry.delay(k))
        raise DeviceError(self.name, what, f"no valid response after {self.retry.attempts} "
                                           f"attempts (last: {last})", transient=True)

    def _resync(self, restore: bool = False) -> None:
        """After a bad line, drop anything late still on the wire (and restore CHK ON)."""
        self._known.clear()
        drain = getattr(self.transport, "drain", None)
        if drain is not None:
            try:
                drain()
            except LinkLost:
                self._reconnect()
                return
        if restore:
            self._restore_checksum()

    def _restore_checksum(self) -> None:
        if not self.want_checksum:
            return
        try:
            self._exchange_once(protocol.HEAD_COMMANDS["CHK"], "ON")
            self.chk = True
        except protocol.ProtocolError as exc:
            # a fault on this reply is a retry like any other: count it (the next command
            # resynchronises again), or the counts fall short of the faults that happened
            if not isinstance(exc, protocol.HeadError):
                self.retry.count(_FRAMING_KIND.get(type(exc), "serial_garbled"))
            elif exc.transient:
                self.retry.count("head_busy")
            log.info("photometer head: CHK ON while resynchronising failed: %s", exc)
        except LinkLost as exc:
            self.retry.count("link_lost")
            log.info("photometer head: CHK ON while resynchronising failed: %s", exc)

    def _reconnect(self) -> None:
        self._known.clear()
        try:
            self.transport.reconnect()
        except LinkLost as exc:
            log.warning("photometer head: reconnect failed: %s", exc)
            return
        # a new connection may be a fresh session of the head: restore the checksum mode
        self._restore_checksum()

    # --- behaviour ------------------------------------------------------------------------
    def connect(self) -> protocol.Identity:
        """Checksum mode on (when wanted), identify; returns the identity."""
        if self.want_checksum:
            self.query("CHK", "ON")
            self.chk = True
        self.identity = self.query("*IDN?")
        return self.identity

    @property
    def idn(self) -> str:
        """``maker,model,serial,firmware`` from ``*IDN?``."""
        i = self.identity or self.query("*IDN?")
        return f"{i.maker},{i.model},{i.serial},{i.firmware}"

    def set_checksum(self, on: bool) -> None:
        """Turn checksum mode on or off."""
        self.query("CHK", "ON" if on else "OFF")
        self.chk = on

    def reset(self) -> None:
        """``*RST``: wavelength, integration time, gain to defaults; shutter closed."""
        self.query("*RST")

    def error_queue(self) -> list[protocol.ErrorEntry]:
        """Drain ``SYST:ERR?`` (oldest first) until it reports no error."""
        out = []
        for _ in range(protocol.ERROR_QUEUE_LENGTH + 1):
            e = self.query("SYST:ERR?")
            if e.code == 0:
                break
            out.append(e)
        return out

    def read(self, n: int) -> protocol.Reading:
        """``READ? n`` -> :class:`gonio.protocol.Reading` (mean, std, n, flags)."""
        return self.query("READ?", int(n))

    def measure(self, wavelength_nm: float, itime_ms: int, gain: int, n: int,
                repetitions: int = 1, shutter_open: bool | None = None) -> Measurement:
        """Set (shutter,) wavelength, integration time and gain, then read: one retryable unit.

        ``repetitions`` readings ``READ? n`` are pooled (:func:`gonio.calibration.pooled_mean`).
        ``WAVE`` is always sent; ``ITIME``, ``GAIN`` and ``SHUTTER`` only when the head is not
        known to hold the value already (see :meth:`forget_settings`: the engine forgets at the
        start of every point, so every point issues the same commands in a resumed run as in an
        uninterrupted one). Each setting command is retried on its own; a transient failure of
        ``READ?`` (framing, busy, lamp unstable, dropped link) repeats the whole unit with every
        setting re-sent, so the retried reading is taken in exactly the state of a first attempt.
        ``ERR 301`` (overload) and the saturation flag give ``saturated=True``; other errors
        raise :class:`DeviceError`.
        """
        what = f"measure {wavelength_nm:g} nm, {itime_ms} ms, gain {gain}, n {n}"
        # a READ? takes n integration times: allow for it (at real speed) beyond the link timeout
        base = getattr(self.transport, "timeout_s", 1.0)
        read_timeout = base + 1.2 * n * itime_ms / 1000.0

        setters = [("WAVE", float(round(wavelength_nm, 1))), ("ITIME", int(itime_ms)),
                   ("GAIN", int(gain))]
        if shutter_open is not None:
            setters.insert(0, ("SHUTTER", "OPEN" if shutter_open else "CLOSE"))

        attempt = [0]

        def unit():
            # setters are idempotent: each is retried on its own; a failed READ? repeats the unit
            # with every setting re-sent. WAVE is always sent: it starts the head's repetition
            # count afresh, so a reading depends on the state only, never on what came before.
            first = attempt[0] == 0
            attempt[0] += 1
            for key, value in setters:
                if first and key != "WAVE" and self._known.get(key, _UNKNOWN) == value:
                    continue
                self.query(key, value)
            got = []
            for _ in range(repetitions):
                try:
                    r = self._exchange_once(protocol.HEAD_COMMANDS["READ?"], int(n),
                                            timeout_s=read_timeout)
                except protocol.DetectorOverloadError:
                    return Measurement(math.nan, math.nan, int(n), saturated=True)
                if r.lamp_unstable:
                    raise _LampUnstable()
                if r.saturated:
                    return Measurement(r.mean_counts, r.stderr_counts, r.n, saturated=True)
                got.append(r)
            if len(got) == 1:
                return Measurement(got[0].mean_counts, got[0].stderr_counts, got[0].n)
            mean, sem, total = pooled_mean([r.mean_counts for r in got],
                                           [r.std_counts for r in got], [r.n for r in got])
            return Measurement(mean, sem, total)

        for k in range(self.retry.attempts):
            try:
                return self._retrying(unit, what)
            except _LampUnstable:
                self.retry.count("lamp_unstable")
                self.retry.sleep(self.retry.delay(k))
        raise DeviceError(self.name, what, f"lamp unstable in {self.retry.attempts} readings",
                          transient=True)

    def shutdown(self) -> None:
        """Close the shutter (best effort, never raises)."""
        try:
            self.query("SHUTTER", "CLOSE")
        except Exception as exc:  # noqa: BLE001 - shutdown must not raise
            log.warning("photometer head: closing the shutter failed: %s", exc)


_SETTINGS = ("WAVE", "ITIME", "GAIN", "SHUTTER")
_UNKNOWN = object()


class _LampUnstable(Exception):
    """Internal: a reading flagged lamp-unstable (retried by :meth:`PhotometerHead.measure`)."""


@dataclass(frozen=True)
class AxisState:
    """Decoded axis input registers."""

    position_mdeg: int
    status: AxisStatus
    fault: int


class MotionController:
    """The four-axis motion controller (INSTRUMENT.md register map, via :mod:`gonio.protocol`).

    Parameters
    ----------
    transport : object with ``exchange(dict) -> dict``, ``reconnect()``, ``close()``.
    retry : shared :class:`RetryPolicy`.
    poll_s : status polling interval while waiting for motion.
    move_timeout_s : longest wait for an axis to reach its target.
    busy_timeout_s : longest backoff spent on exception 6 (busy) for one request.
    """

    name = "motion controller"

    def __init__(self, transport, retry: RetryPolicy | None = None, *, poll_s: float = 0.001,
                 move_timeout_s: float = 120.0, busy_timeout_s: float = 30.0):
        self.transport = transport
        self.busy_timeout_s = busy_timeout_s
        self.retry = retry or RetryPolicy()
        self.poll_s = poll_s
        self.move_timeout_s = move_timeout_s
        self.clock: Callable[[], float] = time.monotonic
        self._velocity_cdeg_s: list[int | None] = [None] * protocol.N_AXES
        self._target_mdeg: list[int | None] = [None] * protocol.N_AXES
        self.owner_token: int | None = None

    # --- low level ------------------------------------------------------------------------
    def call(self, request: dict, what: str, *,
             took_effect: Callable[[], bool] | None = None) -> dict:
        """One Modbus request with retries (busy, no response, dropped link).

        Exception 6 (busy, e.g. still homing after an earlier session) is retried for up to
        ``busy_timeout_s`` of backoff; the other transient failures ``retry.attempts`` times.
        After an unanswered attempt (timeout, dropped link) and the reconnection,
        ``took_effect()`` (when given) asks the controller whether the request was executed
        anyway; if so it is not sent again and ``{}`` is returned.
        """
        last: Exception | None = None
        k = 0
        busy_waited = 0.0
        unanswered = False
        while k < self.retry.attempts:
            if unanswered and took_effect is not None and took_effect():
                log.info("motion controller: %s: executed although unanswered; not sent again", what)
                return {}
            try:
                return self.transport.exchange(request)
            except ModbusExceptionResponse as exc:
                if exc.code != protocol.ModbusException.DEVICE_BUSY:
                    name = _exception_name(exc.code)
                    raise DeviceError(self.name, what, f"Modbus exception {exc.code} ({name})",
                                      exc.code) from None
                last = exc
                self.retry.count("modbus_busy")
                delay = self.retry.delay(k)
                if busy_waited + delay <= self.busy_timeout_s:
                    busy_waited += delay
                    self.retry.sleep(delay)
                    k = min(k + 1, self.retry.attempts - 2)   # keep retrying while busy
                    continue
            except LinkTimeout as exc:
                last, unanswered = exc, True
                self.retry.count("modbus_no_response")
                self._reconnect()
            except LinkLost as exc:
                last, unanswered = exc, True
                self.retry.count("modbus_link_lost")
                log.info("motion controller: %s: %s; reconnecting", what, exc)
                self._reconnect()
            self.retry.sleep(self.retry.delay(k))
            k += 1
        raise DeviceError(self.name, what, f"no valid response after {self.retry.attempts} "
                                           f"attempts (last: {last})", transient=True)

    def _reconnect(self) -> None:
        try:
            self.transport.reconnect()
        except LinkLost as exc:
            log.warning("motion controller: reconnect failed: %s", exc)

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

    # --- status ---------------------------------------------------------------------------
    def firmware(self) -> str:
        """Firmware version, e.g. ``"1.4"``."""
        v = self.read_input(protocol.IR_FIRMWARE, 1, "read firmware")[0]
        return f"{v >> 8}.{v & 0xFF}"

    def status(self) -> protocol.ControllerStatus:
        """CONTROLLER STATUS bits."""
        return protocol.ControllerStatus(self.read_input(protocol.IR_STATUS, 1, "read status")[0])

    def check_safe_to_move(self) -> protocol.ControllerStatus:
        """Refuse to start when the interlock is open or the emergency stop is pressed."""
        st = self.status()
        if st & protocol.ControllerStatus.EMERGENCY_STOP:
            raise DeviceError(self.name, "read status", "emergency stop pressed: release it, "
                                                        "then start again")
        if st & protocol.ControllerStatus.INTERLOCK_OPEN:
            raise DeviceError(self.name, "read status", "safety interlock open: close the "
                                                        "enclosure, then start again")
        return st

    def axis(self, a: int) -> AxisState:
        """ACTUAL position, STATUS and FAULT of axis ``a``."""
        r = self.read_input(protocol.axis_actual_address(a), 4, f"read axis {a}")
        return AxisState(protocol.registers_to_int32(r[0], r[1]), AxisStatus(r[2]), r[3])

    def positions_deg(self) -> tuple[float, ...]:
        """Actual positions of every axis, degrees."""
        return tuple(protocol.mdeg_to_deg(self.axis(a).position_mdeg) for a in range(protocol.N_AXES))

    # --- commands -------------------------------------------------------------------------
    def enable(self) -> None:
        """Enable the drives."""
        self.write(protocol.HR_CONTROL, [Control.ENABLE], "enable drives")

    def reset_fault(self) -> None:
        """Clear every latched axis fault (drives stay enabled)."""
        self.write(protocol.HR_CONTROL, [Control.ENABLE | Control.RESET_FAULT], "reset fault")

    def stop(self) -> None:
        """Stop every axis (accepted even while homing)."""
        self.write(protocol.HR_CONTROL, [Control.ENABLE | Control.STOP_ALL], "stop all")

    def home(self) -> None:
        """Enable, home every axis and wait until all are homed and at rest.

        ``HOME_ALL`` is refused (exception 4) while an axis holds a latched fault: the faults
        are then cleared with :meth:`clear_faults` (drives stopped first; only recoverable
        faults are reset, anything else raises) and homing is commanded again, a bounded number
        of times. An unanswered ``HOME_ALL`` is checked (:meth:`_homing_taken`) before it is
        sent again, so homing is not restarted when the controller took it.
        """
        self.enable()
        for k in range(_HOME_ATTEMPTS):
            try:
                self.write(protocol.HR_CONTROL, [Control.ENABLE | Control.HOME_ALL], "home all",
                           took_effect=self._homing_taken)
                break
            except DeviceError as exc:
                if exc.code != protocol.ModbusException.DEVICE_FAILURE or k + 1 == _HOME_ATTEMPTS:
                    raise
                log.warning("motion controller: home all refused (an axis holds a fault); "
                            "clearing the faults")
                self.clear_faults("home all")
        self._target_mdeg = list(protocol.HOME_POSITIONS_MDEG)
        self._wait(range(protocol.N_AXES), "home all", homing=True)

    def _homing_taken(self) -> bool:
        """Did the controller take an unanswered ``HOME_ALL``?

        True when every axis' COMMAND register holds HOME and the axis is homing (moving, not
        homed: a move needs a homed axis) or homed and at rest at its home position.
        """
        for a in range(protocol.N_AXES):
            cmd = self.read_holding(protocol.axis_command_address(a), 1,
                                    f"home all: re-read axis {a} command")[0]
            if cmd != protocol.AxisCommand.HOME:
                return False
            st = self.axis(a)
            homing = bool(st.status & AxisStatus.MOVING) and not st.status & AxisStatus.HOMED
            homed = (bool(st.status & AxisStatus.HOMED) and not st.status & AxisStatus.MOVING
                     and abs(st.position_mdeg - protocol.HOME_POSITIONS_MDEG[a])
                     <= protocol.IN_POSITION_TOLERANCE_MDEG)
            if not (homing or homed):
                return False
        return True

    def clear_faults(self, what: str) -> list[int]:
        """Bring every axis to rest and reset the latched faults that can be cleared safely.

        Drives are stopped first (``STOP_ALL``) and the axes polled until none is moving: an
        axis still moving when another faulted could latch its own fault after the reset.
        Then every axis' FAULT code is read; following error and not homed
        (:data:`RECOVERABLE_FAULTS`) are reset (CONTROL bit3), any other latched fault raises
        :class:`AxisFaultError` (the engine stops safely). Returns the faulted axes.
        """
        self.stop()
        deadline = self.clock() + self.move_timeout_s
        while True:
            states = [self.axis(a) for a in range(protocol.N_AXES)]
            if not any(st.status & AxisStatus.MOVING for st in states):
                break
            if self.clock() > deadline:
                raise DeviceError(self.name, what, f"axes still moving {self.move_timeout_s:g} s "
                                                   "after stop all")
            self.retry.sleep(self.poll_s)
        faulted = [a for a, st in enumerate(states) if st.fault or st.status & AxisStatus.FAULT]
        for a in faulted:
            if states[a].fault not in RECOVERABLE_FAULTS:
                raise AxisFaultError(a, states[a].fault, what)
        if faulted:
            log.info("motion controller: %s: resetting faults of axes %s (codes %s)", what, faulted,
                     [states[a].fault for a in faulted])
            self.reset_fault()
        self.forget_targets()
        return faulted

    def set_lamp(self, on: bool) -> None:
        """Lamp coil."""
        self.write_coil(protocol.COIL_LAMP, on, "lamp " + ("on" if on else "off"))

    def shutter_is_open(self, what: str = "read shutter") -> bool:
        """The shutter coil (the same shutter as the head's ``SHUTTER``)."""
        return bool(self.call({"fn": "read_coils", "address": protocol.COIL_SHUTTER, "count": 1},
                              what)["bits"][0])

    def set_shutter(self, open_: bool) -> None:
        """Shutter coil (the same shutter as the head's SHUTTER command)."""
        self.write_coil(protocol.COIL_SHUTTER, open_, "shutter " + ("open" if open_ else "close"))

    def claim(self, token: int) -> None:
        """Write our owner token into the OWNER registers (:data:`gonio.protocol.HR_OWNER`).

        A token already there (another client's, or a killed session's) is taken over and
        logged: the other client notices at its next :meth:`check_owner` and stops.
        """
        found = protocol.registers_to_owner(*self.read_holding(protocol.HR_OWNER, 2, "read owner"))
        if found not in (0, token):
            log.warning("motion controller: the instrument was claimed by another client (owner "
                        "token %#010x); taking it over (a session still running there stops)",
                        found)
        self.write(protocol.HR_OWNER, list(protocol.owner_to_registers(token)), "claim")
        self.owner_token = token

    def check_owner(self, what: str) -> None:
        """Raise :class:`InstrumentTaken` when the OWNER registers no longer hold our token."""
        if self.owner_token is None:
            return
        found = protocol.registers_to_owner(*self.read_holding(protocol.HR_OWNER, 2,
                                                                f"{what}: check owner"))
        if found != self.owner_token:
            raise InstrumentTaken(self.owner_token, found, what)

    def release(self) -> None:
        """Clear the OWNER registers if they still hold our token (best effort, never raises)."""
        token, self.owner_token = self.owner_token, None
        if token is None:
            return
        try:
            found = protocol.registers_to_owner(*self.read_holding(protocol.HR_OWNER, 2,
                                                                    "read owner"))
            if found == token:
                self.write(protocol.HR_OWNER, [0, 0], "release")
        except Exception as exc:  # noqa: BLE001 - part of shutdown, must not raise
            log.warning("motion controller: releasing the instrument failed: %s", exc)

    def set_slot(self, slot: SampleSlot) -> None:
        """Put the sample or the white reference standard in the beam (sample changer)."""
        self.write(protocol.HR_SAMPLE_SLOT, [int(slot)], f"slot {SampleSlot(slot).name.lower()}")

    def move_to(self, axes_deg, velocity_deg_s: float) -> None:
        """Move the axes to ``axes_deg`` (4 values, degrees) and wait until in position.

        Only axes whose target changed are commanded (one write per axis: target, velocity,
        move command). Raises :class:`AxisFaultError` when an axis faults.
        """
        v = int(round(velocity_deg_s * 100))
        v = min(max(v, protocol.VELOCITY_RANGE_CDEG_S[0]), protocol.VELOCITY_RANGE_CDEG_S[1])
        moving = []
        what = "move to (" + ", ".join(f"{x:g}" for x in axes_deg) + ")"
        targets = [protocol.deg_to_mdeg(d) for d in axes_deg]
        changed = [a for a in range(protocol.N_AXES)
                   if targets[a] != self._target_mdeg[a] or v != self._velocity_cdeg_s[a]]
        for a in self._safe_order(changed, targets, what):
            mdeg = targets[a]
            hi, lo = protocol.int32_to_registers(mdeg)
            try:
                self.write(protocol.axis_target_address(a), [hi, lo, v, protocol.AxisCommand.MOVE],
                           f"{what}: axis {a}",
                           took_effect=lambda a=a, mdeg=mdeg: self._move_taken(a, mdeg, v, what))
            except DeviceError as exc:
                if exc.code != protocol.ModbusException.DEVICE_FAILURE:
                    raise
                # exception 4: the axis holds a latched fault; report it with its code
                self._target_mdeg[a] = None
                raise AxisFaultError(a, self.axis(a).fault, what) from None
            self._target_mdeg[a] = mdeg
            self._velocity_cdeg_s[a] = v
            moving.append(a)
        self._wait(moving, what)

    def _move_taken(self, a: int, mdeg: int, velocity: int, what: str) -> bool:
        """Did the controller take the move of axis ``a`` to ``mdeg`` (an unanswered write)?

        True when its TARGET, VELOCITY and COMMAND registers hold this move and the axis is
        moving, in position at the target, or faulted (the wait then reports the fault). An
        axis that is neither homed nor moving (the controller lost its homing) is never sent a
        move: :class:`AxisFaultError` with code 3 (not homed) is raised instead, so the engine
        re-homes.
        """
        hr = self.read_holding(protocol.axis_target_address(a), 4, f"{what}: re-read axis {a}")
        st = self.axis(a)
        if not st.status & AxisStatus.HOMED and not st.status & AxisStatus.MOVING:
            # the controller lost its homing (a power glitch behind the dropped link): a move
            # sent now would only latch fault 3; report it, the engine re-homes
            if not st.fault:
                log.warning("motion controller: %s: axis %d not homed after the link came back",
                            what, a)
                self._target_mdeg[a] = None
                raise AxisFaultError(a, int(AxisFault.NOT_HOMED), what)
            return True     # latched fault: the wait reports it
        if (protocol.registers_to_int32(hr[0], hr[1]) != mdeg or hr[2] != velocity
                or hr[3] != protocol.AxisCommand.MOVE):
            return False
        if st.fault or st.status & AxisStatus.FAULT or st.status & AxisStatus.MOVING:
            return True
        return (bool(st.status & AxisStatus.IN_POSITION)
                and abs(st.position_mdeg - mdeg) <= protocol.IN_POSITION_TOLERANCE_MDEG)

    def _safe_order(self, changed: list[int], targets: list[int], what: str) -> list[int]:
        """Order the axis commands so that no intermediate destination is in the beam-block zone.

        The controller checks each move command against the destinations of all axes, so
        commanding the source before the detector could be refused although the final geometry
        is allowed. Unknown current targets (after a fault) are taken as the new ones.
        """
        current = [t if t is not None else targets[a] for a, t in enumerate(self._target_mdeg)]
        for order in itertools.permutations(changed):
            dest = list(current)
            ok = True
            for a in order:
                dest[a] = targets[a]
                if protocol.beam_blocked(*(protocol.mdeg_to_deg(d) for d in dest[:3])):
                    ok = False
                    break
            if ok:
                return list(order)
        raise DeviceError(self.name, what, "destination is in the beam-block zone (the detector "
                                           "would be within 5 deg of the source direction)",
                          int(AxisFault.BEAM_BLOCK))

    def _wait(self, axes, what: str, homing: bool = False) -> None:
        deadline = self.clock() + self.move_timeout_s
        pending = list(axes)
        while pending:
            still = []
            for a in pending:
                st = self.axis(a)
                if st.status & AxisStatus.FAULT or st.fault:
                    self._target_mdeg[a] = None
                    raise AxisFaultError(a, st.fault, what)
                done = bool(st.status & AxisStatus.HOMED) and not st.status & AxisStatus.MOVING
                if not homing:
                    done = done and bool(st.status & AxisStatus.IN_POSITION)
                if not done:
                    still.append(a)
            pending = still
            if pending:
                if self.clock() > deadline:
                    raise DeviceError(self.name, what, f"axes {pending} not in position after "
                                                       f"{self.move_timeout_s:g} s")
                self.retry.sleep(self.poll_s)

    def forget_targets(self) -> None:
        """Forget the commanded targets (after a fault or re-homing, every axis is re-sent)."""
        self._target_mdeg = [None] * protocol.N_AXES
        self._velocity_cdeg_s = [None] * protocol.N_AXES

    def shutdown(self) -> None:
        """Leave the instrument safe: shutter closed, drives stopped (best effort, never raises)."""
        for action, what in ((lambda: self.set_shutter(False), "closing the shutter"),
                             (self.stop, "stopping the drives")):
            try:
                action()
            except Exception as exc:  # noqa: BLE001 - shutdown must not raise
                log.warning("motion controller: %s failed: %s", what, exc)
        self.release()


def _exception_name(code: int) -> str:
    try:
        return protocol.ModbusException(code).name.lower().replace("_", " ")
    except ValueError:
        return "unknown exception"
