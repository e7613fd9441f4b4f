"""The spectro-photometer head, declared over its command table.

PyMeasure habit: the head is mostly a list of named settings (:class:`Setting` descriptors), each
mapping a name to the query and set commands of
:data:`gonio.instrument.head_commands.HEAD_COMMANDS` - ``wavelength_nm``, ``itime_ms``, ``gain``,
``shutter_open``, ``temperature_c``, ``bandwidth_nm`` -; behaviour is a few methods:
:meth:`~PhotometerHead.connect`, :meth:`~PhotometerHead.read`, :meth:`~PhotometerHead.measure`
(set + read as one retryable unit), checksum mode, :meth:`~PhotometerHead.error_queue` and
:meth:`~PhotometerHead.shutdown`, which always closes the shutter.

Retries go through the shared :class:`~gonio.instrument.retry.RetryPolicy`: framing faults
(silence, truncated, garbled, bad checksum) resynchronise the line, a busy head is asked again,
a dropped link is reconnected (and checksum mode restored); what is not transient raises
:class:`~gonio.instrument.errors.DeviceError` naming the command and the code. The head's serial
line is opened exclusively where the platform supports it
(:class:`gonio.instrument.transport.SerialTransport`), so a second client on the same line is
refused at once.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from gonio.instrument.errors import DeviceError
from gonio.instrument.head_commands import (
    ERROR_QUEUE_LENGTH,
    HEAD_COMMANDS,
    BusyError,
    ChecksumError,
    ChecksumMissing,
    DetectorOverloadError,
    ErrorEntry,
    GarbledResponse,
    HeadCommand,
    HeadError,
    Identity,
    NoResponse,
    ProtocolError,
    Reading,
    TruncatedResponse,
)
from gonio.instrument.head_framing import parse_response
from gonio.instrument.retry import Failure, RetryPolicy
from gonio.instrument.transport import LineTransport, LinkLost
from gonio.stats import pooled_mean

__all__ = ["PhotometerHead", "Setting", "Measurement"]

log = logging.getLogger(__name__)

_FRAMING_KIND = {
    ChecksumMissing: "checksum_mode_lost",
    NoResponse: "serial_timeout",
    TruncatedResponse: "serial_truncated",
    ChecksumError: "serial_checksum",
    GarbledResponse: "serial_garbled",
    BusyError: "head_busy",
}
_SETTINGS = ("WAVE", "ITIME", "GAIN", "SHUTTER")
_UNKNOWN = object()


@dataclass(frozen=True)
class Measurement:
    """A usable head reading: mean and standard error (counts), ``n``, or saturated."""

    mean: float
    sem: float
    n: int
    saturated: bool = False


class _LampUnstable(Exception):
    """Internal: a reading flagged lamp-unstable (retried by :meth:`PhotometerHead.measure`)."""


class Setting:
    """A named head setting: ``get`` query and ``set`` command keys of ``HEAD_COMMANDS``.

    ``to_wire`` converts an assigned value to the command's parameter, ``from_wire`` the
    query's reply to the attribute's value.
    """

    def __init__(self, get: str | None, set_: str | None, doc: str,
                 to_wire: Callable | None = None, from_wire: Callable | None = None):
        for key in (get, set_):
            if key is not None and key not in HEAD_COMMANDS:
                raise ValueError(f"{key!r} is not a command of the head's table")
        self.get, self.set_, self.__doc__ = get, set_, doc
        self.to_wire, self.from_wire = to_wire, from_wire
        self.name = ""

    def __set_name__(self, owner, name: str) -> None:
        self.name = name

    def __get__(self, obj, owner=None):
        if obj is None:
            return self
        if self.get is None:
            raise AttributeError(f"{self.name} is write-only")
        v = obj.query(self.get)
        return self.from_wire(v) if self.from_wire else v

    def __set__(self, obj, value) -> None:
        if self.set_ is None:
            raise AttributeError(f"{self.name} is read-only")
        obj.query(self.set_, self.to_wire(value) if self.to_wire else value)

    def wire(self, value) -> Any:
        """The set command's parameter for ``value``."""
        return self.to_wire(value) if self.to_wire else value


class PhotometerHead:
    """The spectro-photometer head (docs/instrument.md), over a line transport.

    Parameters
    ----------
    transport : the serial link (:class:`~gonio.instrument.transport.LineTransport`).
    retry : shared :class:`~gonio.instrument.retry.RetryPolicy` (its counter collects the retries).
    checksum : turn checksum mode on at :meth:`connect` (recommended).
    """

    name = "photometer head"

    wavelength_nm = Setting("WAVE?", "WAVE", "Monochromator wavelength, 380.0..780.0 nm.",
                            to_wire=lambda v: float(round(float(v), 1)))
    bandwidth_nm = Setting("BW?", None, "Spectral bandwidth, nm (read-only).")
    itime_ms = Setting("ITIME?", "ITIME", "Integration time, 1..10000 ms.", to_wire=int)
    gain = Setting("GAIN?", "GAIN", "Amplifier gain step 0..3 (x1, x4, x16, x64).", to_wire=int)
    shutter_open = Setting("SHUTTER?", "SHUTTER", "Source shutter: True when open.",
                           to_wire=lambda v: "OPEN" if v else "CLOSE",
                           from_wire=lambda w: w == "OPEN")
    temperature_c = Setting("TEMP?", None, "Detector temperature, deg C (read-only).")

    def __init__(self, transport: LineTransport, retry: RetryPolicy | None = None, *,
                 checksum: bool = True):
        self.transport = transport
        self.retry = retry or RetryPolicy()
        self.want_checksum = checksum
        self.chk = False
        self.identity: Identity | None = None
        self._unchecked_error = False       # the last ERR reply came without its *HH
        # settings the head is known to hold (WAVE, ITIME, GAIN, SHUTTER), since the last
        # forget_settings(); anything unusual (a resync, a reconnect, *RST) forgets them
        self._known: dict[str, object] = {}

    # --- low level ------------------------------------------------------------------------
    def _exchange_once(self, cmd: HeadCommand, value, timeout_s: float | None = None):
        line = cmd.format(value)
        raw = (self.transport.exchange(line) if timeout_s is None
               else self.transport.exchange(line, timeout_s=timeout_s))
        chk = self.chk or (cmd.key == "CHK" and value == "ON")
        if cmd.key == "CHK" and value == "OFF":
            chk = False
        self._unchecked_error = False
        try:
            return parse_response(raw, chk=chk, expect=cmd.response)
        except ChecksumMissing:
            # a complete reply without *HH: the head answers in checksum-off mode (its link
            # was reset, or it did not execute CHK ON). An error it reported so is that error
            # (busy: counted as busy, and the checksum mode restored before the next attempt)
            try:
                parse_response(raw, chk=False, expect=cmd.response)
            except HeadError:
                self._unchecked_error = not (cmd.key == "CHK" and value == "ON")
                raise
            except ProtocolError:
                pass
            raise

    def _classify(self, what: str) -> Callable[[Exception], Failure | None]:
        """How a failed exchange is retried (see the module docstring)."""
        def classify(exc: Exception) -> Failure | None:
            if isinstance(exc, HeadError):
                if not exc.transient:
                    raise DeviceError(self.name, what, f"ERR {exc.code} ({exc.message})",
                                      exc.code) from None
                if self._unchecked_error:       # answered in checksum-off mode: restore it
                    return Failure("head_busy", recover=lambda: self._resync(restore=True))
                return Failure("head_busy")
            if isinstance(exc, ProtocolError):
                # silence or a reply without its checksum may mean the head's link was reset
                # (checksum mode off): resynchronise and restore the checksum mode
                restore = isinstance(exc, (NoResponse, ChecksumError))
                return Failure(_FRAMING_KIND.get(type(exc), "serial_garbled"),
                               recover=lambda: self._resync(restore=restore))
            if isinstance(exc, LinkLost):
                return Failure("link_lost", recover=self._reconnect)
            return None
        return classify

    def _retrying(self, action: Callable, what: str):
        return self.retry.run(action, self._classify(what), device=self.name, what=what,
                              link="serial")

    def query(self, key: str, value=None):
        """Send one command of the table and return its parsed reply, retrying what is transient."""
        cmd = HEAD_COMMANDS[key]
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

    def _resync(self, restore: bool = False) -> None:
        """After a bad line, drop anything late still on the wire (and restore CHK ON)."""
        self._known.clear()
        try:
            self.transport.drain()
        except LinkLost:
            self._reconnect()
            return
        if restore:
            self._restore_checksum()

    def _restore_checksum(self) -> None:
        if not self.want_checksum:
            return
        try:
            self._exchange_once(HEAD_COMMANDS["CHK"], "ON")
            self.chk = True
        except ProtocolError as exc:
            # a fault on this reply is a retry like any other: count it (the next command
            # resynchronises again), or the counts fall short of the faults that happened
            if not isinstance(exc, HeadError):
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
    def connect(self) -> Identity:
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

    def error_queue(self) -> list[ErrorEntry]:
        """Drain ``SYST:ERR?`` (oldest first) until it reports no error."""
        out = []
        for _ in range(ERROR_QUEUE_LENGTH + 1):
            e = self.query("SYST:ERR?")
            if e.code == 0:
                break
            out.append(e)
        return out

    def read(self, n: int) -> Reading:
        """``READ? n`` -> :class:`~gonio.instrument.head_commands.Reading` (mean, std, n, flags)."""
        return self.query("READ?", int(n))

    def measure(self, wavelength_nm: float, itime_ms: int, gain: int, n: int,
                repetitions: int = 1, shutter_open: bool | None = None) -> Measurement:
        """Set (shutter,) wavelength, integration time and gain, then read: one retryable unit.

        ``repetitions`` readings ``READ? n`` are pooled (:func:`gonio.stats.pooled_mean`).
        ``WAVE`` is always sent; ``ITIME``, ``GAIN`` and ``SHUTTER`` only when the head is not
        known to hold the value already (see :meth:`forget_settings`: the engine forgets at the
        start of every point, so every point issues the same commands in a resumed run as in an
        uninterrupted one). Each setting command is retried on its own; a transient failure of
        ``READ?`` (framing, busy, lamp unstable, dropped link) repeats the whole unit with every
        setting re-sent, so the retried reading is taken in exactly the state of a first attempt.
        ``ERR 301`` (overload) and the saturation flag give ``saturated=True``; other errors
        raise :class:`~gonio.instrument.errors.DeviceError`.
        """
        what = f"measure {wavelength_nm:g} nm, {itime_ms} ms, gain {gain}, n {n}"
        # a READ? takes n integration times: allow for it (at real speed) beyond the link timeout
        read_timeout = self.transport.timeout_s + 1.2 * n * itime_ms / 1000.0

        setters = [("WAVE", type(self).wavelength_nm.wire(wavelength_nm)),
                   ("ITIME", type(self).itime_ms.wire(itime_ms)), ("GAIN", type(self).gain.wire(gain))]
        if shutter_open is not None:
            setters.insert(0, ("SHUTTER", type(self).shutter_open.wire(shutter_open)))

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
                    r = self._exchange_once(HEAD_COMMANDS["READ?"], int(n), timeout_s=read_timeout)
                except DetectorOverloadError:
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

        def lamp(exc: Exception) -> Failure | None:
            return Failure("lamp_unstable") if isinstance(exc, _LampUnstable) else None

        # the lamp-unstable retries wrap the framing retries of one unit: the same policy, twice
        return self.retry.run(lambda: self._retrying(unit, what), lamp, device=self.name, what=what,
                              exhausted=f"lamp unstable in {self.retry.attempts} readings")

    def shutdown(self) -> bool:
        """Close the shutter (best effort, never raises); False when that failed."""
        try:
            self.shutter_open = False
            return True
        except Exception as exc:  # noqa: BLE001 - shutdown must not raise
            log.warning("photometer head: closing the shutter failed: %s", exc)
            return False
