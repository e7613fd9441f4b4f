r"""The photometer head's command table: constants, typed replies, errors and the command rows.

RS-232 115200 8N1 (or a socket), ASCII. Commands end with ``\n`` (a preceding ``\r`` is
accepted); each command gets exactly one response line ending ``\r\n``: a value, ``OK`` or
``ERR <code>,<message>`` (framing and parsing: :mod:`gonio.instrument.head_framing`).
``*RST`` restores wavelength, integration time, gain and closes the shutter; it does not change
the checksum mode. Every ``ERR`` is also queued (oldest first, at most 16) for ``SYST:ERR?``.

``READ? <n>`` answers ``<mean_counts>,<std_counts>,<n>,<flags>`` (flags bit0 saturated: any reading
>= 60000 counts; bit1 lamp unstable - do not use the value). With the shutter open and the lamp
off it answers ``ERR 201,Lamp off``; a grossly overloaded detector (expected signal >=
:data:`OVERLOAD_COUNTS`) answers ``ERR 301,Detector overload`` (treat like saturation: reduce
the integration time or the gain).

:data:`HEAD_COMMANDS` is read by the driver (:class:`gonio.instrument.head.PhotometerHead`
formats every command from its row), by the mock head (:mod:`gonio.mock.head` matches every
received line against the same rows with :func:`match_command`) and by the generated protocol
document (``docs/instrument.md``).

References
----------
docs/instrument.md (the protocol contract).
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable
from dataclasses import dataclass

__all__ = [
    "IDN_MAKER", "IDN_MODEL", "SATURATION_COUNTS", "ADC_MAX_COUNTS", "OVERLOAD_COUNTS",
    "ITIME_RANGE_MS", "GAIN_STEPS", "GAIN_FACTORS", "WAVE_RANGE_NM", "READ_N_RANGE", "ERROR_QUEUE_LENGTH",
    "FLAG_SATURATED", "FLAG_LAMP_UNSTABLE", "HEAD_ERRORS",
    "HeadCommand", "HEAD_COMMANDS", "match_command",
    "Reading", "Identity", "ErrorEntry",
    "ProtocolError", "NoResponse", "GarbledResponse", "TruncatedResponse", "ChecksumError",
    "ChecksumMissing",
    "HeadError", "UnknownCommandError", "ParameterOutOfRangeError", "BusyError", "LampOffError",
    "DetectorOverloadError", "head_error",
]

IDN_MAKER = "KIAM"
IDN_MODEL = "GPS-1"
SATURATION_COUNTS = 60000
"""A reading at or above this is saturated (READ? flag bit0)."""
ADC_MAX_COUNTS = 65535
"""Single readings clip here (16-bit converter)."""
OVERLOAD_COUNTS = 1_000_000
"""Expected signal (counts) at or above which READ? answers ERR 301 instead of a reading."""
ITIME_RANGE_MS = (1, 10000)
GAIN_STEPS = (0, 1, 2, 3)
GAIN_FACTORS = (1, 4, 16, 64)
"""Amplifier gain factor of each GAIN step."""
WAVE_RANGE_NM = (380.0, 780.0)
READ_N_RANGE = (1, 1000)
ERROR_QUEUE_LENGTH = 16
FLAG_SATURATED = 0x1
FLAG_LAMP_UNSTABLE = 0x2

HEAD_ERRORS: dict[int, str] = {
    101: "Unknown command",
    102: "Parameter out of range",
    103: "Busy",
    201: "Lamp off",
    301: "Detector overload",
}
"""Error code -> message, exactly as on the wire (``ERR <code>,<message>``)."""


# --- exceptions --------------------------------------------------------------------------------

class ProtocolError(Exception):
    """A head response that cannot be used. ``transient`` says whether a retry may help."""

    transient = True


class NoResponse(ProtocolError):
    """Nothing came back before the timeout (an empty read)."""


class GarbledResponse(ProtocolError):
    """The line is not a valid response (bad bytes, bad format, wrong value type)."""


class TruncatedResponse(ProtocolError):
    r"""The line ended without its ``\r\n`` terminator."""


class ChecksumError(ProtocolError):
    """Checksum mode is on and the ``*HH`` suffix is missing or wrong."""


class ChecksumMissing(ChecksumError):
    """Checksum mode is on and a complete, printable reply has no ``*HH`` at all.

    The head answered in checksum-off mode (its link was reset): not a corrupted line.
    """


class HeadError(ProtocolError):
    """The head answered ``ERR <code>,<message>``."""

    transient = False
    code = 0

    def __init__(self, code: int, message: str):
        self.code = code
        self.message = message
        super().__init__(f"ERR {code},{message}")


class UnknownCommandError(HeadError):
    """ERR 101."""


class ParameterOutOfRangeError(HeadError):
    """ERR 102."""


class BusyError(HeadError):
    """ERR 103: transient, retry after a short wait."""

    transient = True


class LampOffError(HeadError):
    """ERR 201: switch the lamp on (coil 0) or close the shutter."""


class DetectorOverloadError(HeadError):
    """ERR 301: reduce integration time or gain."""


_ERROR_CLASSES: dict[int, type[HeadError]] = {
    101: UnknownCommandError, 102: ParameterOutOfRangeError, 103: BusyError,
    201: LampOffError, 301: DetectorOverloadError,
}


def head_error(code: int) -> HeadError:
    """The exception instance for a known head error code (message from :data:`HEAD_ERRORS`)."""
    return _ERROR_CLASSES[code](code, HEAD_ERRORS[code])


# --- typed values ------------------------------------------------------------------------------

@dataclass(frozen=True)
class Reading:
    """A ``READ?`` result: mean and standard deviation of ``n`` readings, in counts."""

    mean_counts: float
    std_counts: float
    n: int
    flags: int

    @property
    def saturated(self) -> bool:
        """Whether the head flagged the reading as saturated."""
        return bool(self.flags & FLAG_SATURATED)

    @property
    def lamp_unstable(self) -> bool:
        """Whether the head flagged its lamp as unstable during the reading."""
        return bool(self.flags & FLAG_LAMP_UNSTABLE)

    @property
    def good(self) -> bool:
        """No flag set: the value may be used."""
        return self.flags == 0

    @property
    def stderr_counts(self) -> float:
        """Standard error of the mean, ``std / sqrt(n)``."""
        return self.std_counts / math.sqrt(self.n)


@dataclass(frozen=True)
class Identity:
    """A ``*IDN?`` result."""

    maker: str
    model: str
    serial: str
    firmware: str


@dataclass(frozen=True)
class ErrorEntry:
    """A ``SYST:ERR?`` result (code 0 = no error)."""

    code: int
    message: str


# --- command table -----------------------------------------------------------------------------

def _float_in(lo: float, hi: float) -> Callable[[str], float]:
    def conv(text: str) -> float:
        v = float(text)
        if not (math.isfinite(v) and lo <= v <= hi):
            raise ValueError(f"{text} not in {lo}..{hi}")
        return round(v, 1)
    return conv


def _int_in(lo: int, hi: int) -> Callable[[str], int]:
    def conv(text: str) -> int:
        v = int(text)
        if not lo <= v <= hi:
            raise ValueError(f"{text} not in {lo}..{hi}")
        return v
    return conv


_NUM = r"([+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?)"
_INT = r"([+-]?\d+)"


@dataclass(frozen=True)
class HeadCommand:
    """One row of the head's command table.

    Attributes
    ----------
    key : the table key, also the canonical spelling (``"WAVE"``, ``"WAVE?"``, ``"READ?"``).
    syntax : human-readable syntax, e.g. ``"WAVE <nm>"``.
    pattern : regular expression matched (``fullmatch``, case-sensitive) against the command line
        without its terminator; group 1, if any, is the parameter.
    convert : parameter validator/converter (raises ValueError when out of range) or None.
    response : kind of the reply, usable as ``expect`` of :func:`parse_response`:
        ``"ok"``, ``"float"``, ``"int"``, ``"word"``, ``"idn"``, ``"reading"``, ``"error_entry"``.
    changes_state : True when the command changes the measurement state (resets the mock's
        repetition counter).
    doc : meaning.
    """

    key: str
    syntax: str
    pattern: re.Pattern[str]
    convert: Callable[[str], object] | None
    response: str
    changes_state: bool
    doc: str

    def format(self, value: object = None) -> bytes:
        r"""The command line (with ``\n``) for ``value``, validated against the table.

        Raises ValueError when the value is out of range or missing/superfluous.
        """
        if self.convert is None:
            if value is not None:
                raise ValueError(f"{self.key} takes no parameter")
            line = self.key
        else:
            if value is None:
                raise ValueError(f"{self.syntax}: parameter missing")
            text = f"{value:.1f}" if isinstance(value, float) else str(value)
            self.convert(text)
            line = f"{self.key} {text}"
        if not self.pattern.fullmatch(line):
            raise ValueError(f"{line!r} does not match {self.syntax}")
        return line.encode("ascii") + b"\n"


def _cmd(key: str, syntax: str, regex: str, convert, response: str, changes: bool, doc: str) -> HeadCommand:
    return HeadCommand(key, syntax, re.compile(regex), convert, response, changes, doc)


HEAD_COMMANDS: dict[str, HeadCommand] = {c.key: c for c in (
    _cmd("*IDN?", "*IDN?", r"\*IDN\?", None, "idn", False, "identity: KIAM,GPS-1,<serial>,<firmware>"),
    _cmd("*RST", "*RST", r"\*RST", None, "ok", True,
         "reset wavelength (550.0), integration time (100 ms), gain (0), shutter closed"),
    _cmd("WAVE", "WAVE <nm>", r"WAVE " + _NUM, _float_in(*WAVE_RANGE_NM), "ok", True,
         "set the monochromator wavelength, 380.0..780.0 nm (0.1 nm steps)"),
    _cmd("WAVE?", "WAVE?", r"WAVE\?", None, "float", False, "wavelength in nm"),
    _cmd("BW?", "BW?", r"BW\?", None, "float", False, "spectral bandwidth in nm"),
    _cmd("SHUTTER", "SHUTTER OPEN|CLOSE", r"SHUTTER (OPEN|CLOSE)", lambda t: t, "ok", True,
         "open/close the source shutter (same shutter as coil 1)"),
    _cmd("SHUTTER?", "SHUTTER?", r"SHUTTER\?", None, "word", False, "OPEN or CLOSED"),
    _cmd("ITIME", "ITIME <ms>", r"ITIME " + _INT, _int_in(*ITIME_RANGE_MS), "ok", True,
         "integration time, 1..10000 ms"),
    _cmd("ITIME?", "ITIME?", r"ITIME\?", None, "int", False, "integration time in ms"),
    _cmd("GAIN", "GAIN <0..3>", r"GAIN " + _INT, _int_in(0, 3), "ok", True,
         "amplifier gain step: 0..3 -> x1, x4, x16, x64"),
    _cmd("GAIN?", "GAIN?", r"GAIN\?", None, "int", False, "gain step"),
    _cmd("READ?", "READ? <n>", r"READ\? " + _INT, _int_in(*READ_N_RANGE), "reading", False,
         "average of n readings: <mean_counts>,<std_counts>,<n>,<flags>"),
    _cmd("TEMP?", "TEMP?", r"TEMP\?", None, "float", False, "detector temperature, deg C"),
    _cmd("SYST:ERR?", "SYST:ERR?", r"SYST:ERR\?", None, "error_entry", False,
         'oldest queued error <code>,"<message>"; 0,"No error" when empty'),
    _cmd("CHK", "CHK ON|OFF", r"CHK (ON|OFF)", lambda t: t, "ok", False,
         "checksum mode; the reply to CHK ON already carries *HH"),
)}


def match_command(line: str) -> tuple[HeadCommand, object]:
    """Find the table row of a command line (terminator stripped) and convert its parameter.

    Returns
    -------
    (command, value) : value is None for commands without a parameter.

    Raises
    ------
    UnknownCommandError : no row matches (ERR 101).
    ParameterOutOfRangeError : the row matches but the parameter is invalid (ERR 102).
    """
    for cmd in HEAD_COMMANDS.values():
        m = cmd.pattern.fullmatch(line)
        if m is None:
            continue
        if cmd.convert is None:
            return cmd, None
        try:
            return cmd, cmd.convert(m.group(1))
        except (ValueError, OverflowError):
            raise head_error(102) from None
    raise head_error(101)


