"""Wire protocols of the goniophotometer, as data: the single source of truth.

Both the driver (``gonio.devices``) and the mock (``gonio.mock``) import this module, so they
cannot drift apart. It holds no I/O: only constants, tables, packing helpers, the geometry of the
axes and the ASCII response parser.

Motion controller (Modbus TCP or RTU 19200 8E1, unit id 1)
----------------------------------------------------------
Four axes; positions are signed 32-bit integers in millidegrees, two registers, high word first.

====  ==================  =====================================================  ===============
 a    name                meaning                                                soft limits
====  ==================  =====================================================  ===============
 0    ``source_zenith``   incidence angle ``theta_i``                            0 .. 85 deg
 1    ``detector_zenith`` signed observation angle ``s`` (+ = mirror side)       -85 .. +85 deg
 2    ``detector_plane``  azimuth of the detector plane from the plane of        0 .. 180 deg
                          incidence
 3    ``sample_rotation`` sample rotation about its normal; the reading equals   0 .. 360 deg
                          ``phi_i``, the source azimuth in the fabric frame
====  ==================  =====================================================  ===============

Holding registers: 0 CONTROL (bit0 enable drives, bit1 home all, bit2 stop all, bit3 reset
fault; bits 1..3 are self-clearing commands), 10 SAMPLE_SLOT (sample changer: 0 = the sample,
1 = the white reference standard; this project's addition to the register map), 20 (+1) OWNER
(a 32-bit token, high word first, 0 = unclaimed: the client driving the instrument writes its
token and checks it at every point, so a session notices when another client takes the
instrument; this project's addition, plain read/write storage on the controller), and per axis
``100 + 20a`` (+1) TARGET int32 mdeg, ``+2`` VELOCITY centideg/s, ``+3`` COMMAND (1 move to target,
2 home, 3 stop). Input registers: 0 CONTROLLER STATUS, 1 firmware (0x0104), per axis ``100 + 20a``
(+1) ACTUAL int32 mdeg, ``+2`` axis STATUS, ``+3`` FAULT code. Coils: 0 lamp on, 1 shutter open.
The shutter coil and the head's ``SHUTTER`` command act on the same source shutter.

Controller rules (enforced by the controller / mock; the driver should avoid triggering them):

- drives must be enabled (CONTROL bit0) for a move or homing, otherwise exception 3;
- while any axis is homing, every *write* except a CONTROL write with the stop-all bit answers
  exception 6 (device busy); reads are always served, so status can be polled;
- a move of an axis that was never homed is refused: the write is acknowledged, nothing moves,
  and the axis latches fault 3 (not homed);
- a move to a target outside the soft limits answers exception 3 (illegal data value); a TARGET
  write carrying both words of an out-of-limit value is refused the same way (not stored);
- a move whose destination would bring the detector within 5 degrees of the source direction
  (:func:`beam_blocked`) latches fault 4 on that axis and answers exception 3; nothing moves;
- a move of an axis with a latched fault answers exception 4 (reset the fault first: CONTROL
  bit3, which clears every axis fault);
- an axis is in position when ``|actual - target| <= 5 mdeg`` after its move and settling.

Power-on state: drives disabled, axes not homed, lamp off, shutter closed, slot 0 (sample).

Photometer head (RS-232 115200 8N1 or a socket, ASCII)
------------------------------------------------------
Commands end with ``\\n`` (a preceding ``\\r`` is accepted); each command gets exactly one
response line ending ``\\r\\n``: a value, ``OK`` or ``ERR <code>,<message>``. In checksum mode
(``CHK ON``) every response is ``<payload>*HH\\r\\n`` with ``HH`` = XOR of all bytes of
``<payload>`` (every byte before the ``*``), two upper-case hex digits. The reply to ``CHK ON``
already carries a checksum; the reply to ``CHK OFF`` does not. ``*RST`` restores wavelength,
integration time, gain and closes the shutter; it does not change the checksum mode.
Every ``ERR`` is also queued (oldest first, at most 16) for ``SYST:ERR?``.

``READ? <n>`` answers ``<mean_counts>,<std_counts>,<n>,<flags>`` (flags bit0 saturated: any reading
>= 60000 counts; bit1 lamp unstable - do not use the value). With the shutter open and the lamp
off it answers ``ERR 201,Lamp off``; a grossly overloaded detector (expected signal >=
:data:`OVERLOAD_COUNTS`) answers ``ERR 301,Detector overload`` (treat like saturation: reduce
the integration time or the gain).

References
----------
INSTRUMENT.md of this project (the protocol contract); Modbus Application Protocol
Specification V1.1b3 (exception codes); PHYSICS.md section 1 (frames and angles).
"""

from __future__ import annotations

import enum
import math
import re
from dataclasses import dataclass
from typing import Callable

from gonio.data.geometry import (BEAM_BLOCK_MIN_ANGLE_DEG, axes_to_fabric, beam_blocked,
                                  detector_direction, fabric_to_axes,
                                  source_detector_angle_deg, source_direction)

__all__ = [
    # Modbus
    "UNIT_ID", "MODBUS_TCP_PORT", "RTU_BAUDRATE", "RTU_BYTESIZE", "RTU_PARITY", "RTU_STOPBITS",
    "FIRMWARE_VERSION", "is_pseudo_terminal", "rtu_serial_settings", "Axis", "AXES", "N_AXES",
    "HOME_POSITIONS_MDEG", "IN_POSITION_TOLERANCE_MDEG",
    "DEFAULT_VELOCITY_CDEG_S", "VELOCITY_RANGE_CDEG_S", "BEAM_BLOCK_MIN_ANGLE_DEG",
    "HR_CONTROL", "HR_SAMPLE_SLOT", "HR_OWNER", "owner_to_registers", "registers_to_owner",
    "IR_STATUS", "IR_FIRMWARE", "AXIS_BLOCK_BASE", "AXIS_BLOCK_STRIDE",
    "axis_target_address", "axis_velocity_address", "axis_command_address",
    "axis_actual_address", "axis_status_address", "axis_fault_address",
    "HOLDING_REGISTER_RANGES", "INPUT_REGISTER_RANGES",
    "Control", "ControllerStatus", "AxisStatus", "AxisFault", "AxisCommand", "SampleSlot",
    "ModbusException", "COIL_LAMP", "COIL_SHUTTER", "N_COILS",
    "int32_to_registers", "registers_to_int32", "within_soft_limits", "deg_to_mdeg", "mdeg_to_deg",
    "detector_direction", "source_direction", "source_detector_angle_deg", "beam_blocked",
    "axes_to_fabric", "fabric_to_axes",
    # Head
    "HEAD_BAUDRATE", "LINE_TERMINATOR", "IDN_MAKER", "IDN_MODEL",
    "SATURATION_COUNTS", "ADC_MAX_COUNTS", "OVERLOAD_COUNTS",
    "ITIME_RANGE_MS", "GAIN_STEPS", "GAIN_FACTORS", "WAVE_RANGE_NM", "READ_N_RANGE", "ERROR_QUEUE_LENGTH",
    "FLAG_SATURATED", "FLAG_LAMP_UNSTABLE", "HEAD_ERRORS",
    "HeadCommand", "HEAD_COMMANDS", "match_command", "checksum", "format_response", "parse_response",
    "Reading", "Identity", "ErrorEntry",
    "ProtocolError", "NoResponse", "GarbledResponse", "TruncatedResponse", "ChecksumError",
    "HeadError", "UnknownCommandError", "ParameterOutOfRangeError", "BusyError", "LampOffError",
    "DetectorOverloadError", "head_error",
]

# ============================================================================================
# Motion controller (Modbus)
# ============================================================================================

UNIT_ID = 1
"""Modbus unit (device) id of the motion controller."""
MODBUS_TCP_PORT = 502
RTU_BAUDRATE = 19200
RTU_BYTESIZE = 8
RTU_PARITY = "E"
RTU_STOPBITS = 1
FIRMWARE_VERSION = 0x0104
"""Input register 1: firmware 1.4."""


def is_pseudo_terminal(port: str) -> bool:
    """True for a pseudo-terminal device path (``/dev/pts/N``, ``/dev/ptyXX``, ``/dev/ttypXX``)."""
    return str(port).startswith(("/dev/pts/", "/dev/pty", "/dev/ttyp"))


def rtu_serial_settings(port: str) -> dict:
    """Serial settings (pyserial keyword arguments) of the Modbus RTU line on ``port``.

    19200 baud, 8 data bits, even parity, 1 stop bit - except on a pseudo-terminal, which has no
    parity bit: recent Linux kernels refuse ``PARENB`` on a pty (``termios.error`` EINVAL), so
    both ends of a pty use parity ``"N"`` (the framing on a pty is byte-exact anyway). The driver
    and the mock both call this, so they always agree.
    """
    parity = "N" if is_pseudo_terminal(port) else RTU_PARITY
    return {"baudrate": RTU_BAUDRATE, "bytesize": RTU_BYTESIZE, "parity": parity, "stopbits": RTU_STOPBITS}


@dataclass(frozen=True)
class Axis:
    """One motion axis: index, name, meaning and soft limits (millidegrees, inclusive)."""

    index: int
    name: str
    meaning: str
    min_mdeg: int
    max_mdeg: int

    def within_limits(self, position_mdeg: int) -> bool:
        """True when ``position_mdeg`` lies inside the soft limits (limits included)."""
        return self.min_mdeg <= int(position_mdeg) <= self.max_mdeg


AXES: tuple[Axis, ...] = (
    Axis(0, "source_zenith", "incidence angle theta_i", 0, 85_000),
    Axis(1, "detector_zenith", "signed observation angle s in the detector plane (+ = mirror side)",
         -85_000, 85_000),
    Axis(2, "detector_plane", "azimuth of the detector plane relative to the plane of incidence",
         0, 180_000),
    Axis(3, "sample_rotation", "sample rotation about its normal = phi_i (source azimuth in the "
         "fabric frame)", 0, 360_000),
)
N_AXES = len(AXES)
HOME_POSITIONS_MDEG: tuple[int, ...] = (0, 45_000, 0, 0)
"""Where each axis stands after homing (the 0/45 reference geometry, clear of the beam)."""
IN_POSITION_TOLERANCE_MDEG = 5
DEFAULT_VELOCITY_CDEG_S = 2000
"""Power-on VELOCITY of every axis: 20 deg/s."""
VELOCITY_RANGE_CDEG_S = (1, 6000)
"""Accepted VELOCITY register values (centideg/s); others answer exception 3."""

# --- register addresses ----------------------------------------------------------------------
HR_CONTROL = 0
HR_SAMPLE_SLOT = 10
HR_OWNER = 20
"""Two holding registers: the owner token (uint32, high word first; 0 = unclaimed)."""
IR_STATUS = 0
IR_FIRMWARE = 1
AXIS_BLOCK_BASE = 100
AXIS_BLOCK_STRIDE = 20


def _check_axis(a: int) -> int:
    if not 0 <= int(a) < N_AXES:
        raise ValueError(f"axis index {a!r} not in 0..{N_AXES - 1}")
    return int(a)


def axis_target_address(a: int) -> int:
    """Holding register of axis ``a``'s TARGET (int32 mdeg, high word here, low word at +1)."""
    return AXIS_BLOCK_BASE + AXIS_BLOCK_STRIDE * _check_axis(a)


def axis_velocity_address(a: int) -> int:
    """Holding register of axis ``a``'s VELOCITY (centideg/s)."""
    return axis_target_address(a) + 2


def axis_command_address(a: int) -> int:
    """Holding register of axis ``a``'s COMMAND (:class:`AxisCommand`)."""
    return axis_target_address(a) + 3


def axis_actual_address(a: int) -> int:
    """Input register of axis ``a``'s ACTUAL position (int32 mdeg, high word first)."""
    return AXIS_BLOCK_BASE + AXIS_BLOCK_STRIDE * _check_axis(a)


def axis_status_address(a: int) -> int:
    """Input register of axis ``a``'s STATUS (:class:`AxisStatus` bits)."""
    return axis_actual_address(a) + 2


def axis_fault_address(a: int) -> int:
    """Input register of axis ``a``'s FAULT code (:class:`AxisFault`)."""
    return axis_actual_address(a) + 3


HOLDING_REGISTER_RANGES: tuple[tuple[int, int], ...] = (
    (HR_CONTROL, 1), (HR_SAMPLE_SLOT, 1), (HR_OWNER, 2),
    *((axis_target_address(a), 4) for a in range(N_AXES)),
)
"""(start, count) of every defined holding register block; other addresses answer exception 2."""
INPUT_REGISTER_RANGES: tuple[tuple[int, int], ...] = (
    (IR_STATUS, 2), *((axis_actual_address(a), 4) for a in range(N_AXES)),
)
"""(start, count) of every defined input register block; other addresses answer exception 2."""


class Control(enum.IntFlag):
    """CONTROL holding register bits (bits 1..3 are commands, cleared by the controller)."""

    ENABLE = 0x1
    HOME_ALL = 0x2
    STOP_ALL = 0x4
    RESET_FAULT = 0x8


class ControllerStatus(enum.IntFlag):
    """CONTROLLER STATUS input register bits."""

    READY = 0x1          # drives enabled, every axis homed, no fault, nothing homing
    INTERLOCK_OPEN = 0x2
    EMERGENCY_STOP = 0x4
    ANY_FAULT = 0x8


class AxisStatus(enum.IntFlag):
    """Axis STATUS input register bits."""

    HOMED = 0x1
    MOVING = 0x2         # also set while homing and settling
    IN_POSITION = 0x4
    FAULT = 0x8
    PLUS_LIMIT = 0x10    # actual position at (or beyond) the upper soft limit
    MINUS_LIMIT = 0x20   # actual position at (or beyond) the lower soft limit


class AxisFault(enum.IntEnum):
    """Axis FAULT codes."""

    NONE = 0
    FOLLOWING_ERROR = 1
    LIMIT = 2
    NOT_HOMED = 3
    BEAM_BLOCK = 4


class AxisCommand(enum.IntEnum):
    """Axis COMMAND register values (the register reads back the last command)."""

    NONE = 0
    MOVE = 1
    HOME = 2
    STOP = 3


class SampleSlot(enum.IntEnum):
    """SAMPLE_SLOT holding register (sample changer): what sits in the beam."""

    SAMPLE = 0
    WHITE_REFERENCE = 1


class ModbusException(enum.IntEnum):
    """Modbus exception codes used by the controller."""

    ILLEGAL_FUNCTION = 1
    ILLEGAL_ADDRESS = 2
    ILLEGAL_VALUE = 3
    DEVICE_FAILURE = 4
    DEVICE_BUSY = 6


COIL_LAMP = 0
COIL_SHUTTER = 1
N_COILS = 2


def owner_to_registers(token: int) -> tuple[int, int]:
    """Pack an owner token (1 .. 2**32 - 1) into the OWNER registers, high word first.

    Examples
    --------
    >>> owner_to_registers(0x12345678)
    (4660, 22136)
    """
    if not 0 <= int(token) < 2**32:
        raise ValueError(f"owner token {token!r} not in 0 .. 2**32 - 1")
    return (int(token) >> 16) & 0xFFFF, int(token) & 0xFFFF


def registers_to_owner(high: int, low: int) -> int:
    """Unpack the OWNER registers into the token.

    Examples
    --------
    >>> registers_to_owner(4660, 22136) == 0x12345678
    True
    """
    return ((int(high) & 0xFFFF) << 16) | (int(low) & 0xFFFF)


def int32_to_registers(value: int) -> tuple[int, int]:
    """Pack a signed 32-bit integer into two 16-bit registers, high word first.

    Examples
    --------
    >>> int32_to_registers(-1)
    (65535, 65535)
    >>> int32_to_registers(85000)
    (1, 19464)
    """
    v = int(value)
    if not -(1 << 31) <= v < (1 << 31):
        raise ValueError(f"{value!r} does not fit a signed 32-bit integer")
    u = v & 0xFFFFFFFF
    return (u >> 16) & 0xFFFF, u & 0xFFFF


def registers_to_int32(high: int, low: int) -> int:
    """Unpack two 16-bit registers (high word first) into a signed 32-bit integer.

    Examples
    --------
    >>> registers_to_int32(65535, 65535)
    -1
    >>> registers_to_int32(1, 19464)
    85000
    """
    for w in (high, low):
        if not 0 <= int(w) <= 0xFFFF:
            raise ValueError(f"register value {w!r} not in 0..65535")
    u = (int(high) << 16) | int(low)
    return u - (1 << 32) if u & 0x80000000 else u


def deg_to_mdeg(angle_deg: float) -> int:
    """Degrees to integer millidegrees (rounded half away from zero)."""
    return int(math.copysign(math.floor(abs(angle_deg) * 1000.0 + 0.5), angle_deg))


def mdeg_to_deg(position_mdeg: int) -> float:
    """Integer millidegrees to degrees."""
    return int(position_mdeg) / 1000.0


def within_soft_limits(axis: int, position_mdeg: int) -> bool:
    """True when ``position_mdeg`` is inside axis ``axis``'s soft limits (limits included)."""
    return AXES[_check_axis(axis)].within_limits(position_mdeg)


# --- geometry of the axes: gonio.data.geometry (shared with the dataset layer) ------------------

# ============================================================================================
# Photometer head (ASCII)
# ============================================================================================

HEAD_BAUDRATE = 115200
LINE_TERMINATOR = b"\r\n"
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
    """The line ended without its ``\\r\\n`` terminator."""


class ChecksumError(ProtocolError):
    """Checksum mode is on and the ``*HH`` suffix is missing or wrong."""


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
        return bool(self.flags & FLAG_SATURATED)

    @property
    def lamp_unstable(self) -> bool:
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
        """The command line (with ``\\n``) for ``value``, validated against the table.

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


# --- framing -----------------------------------------------------------------------------------

def checksum(line_bytes: bytes) -> str:
    """XOR of all bytes of ``line_bytes`` as two upper-case hex digits.

    ``line_bytes`` is the payload, i.e. every byte before the ``*``.

    Examples
    --------
    >>> checksum(b"OK")          # 0x4F ^ 0x4B = 0x04
    '04'
    >>> checksum(b"")
    '00'
    """
    x = 0
    for b in bytes(line_bytes):
        x ^= b
    return f"{x:02X}"


def format_response(payload: str | bytes, chk: bool) -> bytes:
    """A complete response line: payload, ``*HH`` when ``chk``, and ``\\r\\n``."""
    p = payload.encode("ascii") if isinstance(payload, str) else bytes(payload)
    if chk:
        p = p + b"*" + checksum(p).encode("ascii")
    return p + LINE_TERMINATOR


_PRINTABLE = re.compile(rb"[\x20-\x7e]*")
_ERR = re.compile(r"ERR (\d{3}),([^,*]+)")
_FLOAT = re.compile(r"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?")
_INTRE = re.compile(r"[+-]?\d{1,12}")
_READING = re.compile(r"([^,]+),([^,]+),([^,]+),([^,]+)")
_ERRENTRY = re.compile(r'([+-]?\d{1,6}),"([^"]*)"')
_IDN = re.compile(r"([^,]+),([^,]+),([^,]+),([^,]+)")
_WORD = re.compile(r"[A-Z]{1,16}")
_EXPECT = ("text", "ok", "float", "int", "word", "idn", "reading", "error_entry")


def _as_float(text: str, what: str) -> float:
    if len(text) > 40 or not _FLOAT.fullmatch(text):
        raise GarbledResponse(f"expected a number for {what}, got {text!r}")
    v = float(text)
    if not math.isfinite(v):
        raise GarbledResponse(f"non-finite number for {what}: {text!r}")
    return v


def _as_int(text: str, what: str) -> int:
    if not _INTRE.fullmatch(text):
        raise GarbledResponse(f"expected an integer for {what}, got {text!r}")
    return int(text)


def parse_response(line: bytes, chk: bool, expect: str = "text"):
    """Parse one head response line (as read, terminator included) into a typed value.

    Parameters
    ----------
    line : the raw bytes read up to and including ``\\r\\n`` (an empty ``bytes`` = timeout).
    chk : whether checksum mode is on (then ``*HH`` is required and verified).
    expect : the reply kind (:attr:`HeadCommand.response`): ``"text"`` (any payload, returned
        as str), ``"ok"`` (returns None), ``"float"``, ``"int"``, ``"word"`` (str),
        ``"idn"`` (:class:`Identity`), ``"reading"`` (:class:`Reading`),
        ``"error_entry"`` (:class:`ErrorEntry`).

    Raises
    ------
    NoResponse, TruncatedResponse, GarbledResponse, ChecksumError : framing problems (transient).
    HeadError subclass : the head answered ``ERR <code>,<message>`` (:class:`BusyError` is
        transient, the others are not). An ERR line with an unknown code or a message that does
        not match the code is reported as GarbledResponse.

    Never raises anything else, whatever the bytes (ValueError for an unknown ``expect``).

    Examples
    --------
    >>> parse_response(b"OK*04\\r\\n", chk=True, expect="ok") is None
    True
    >>> parse_response(b"1234.50,12.30,10,0\\r\\n", chk=False, expect="reading").mean_counts
    1234.5
    """
    if expect not in _EXPECT:
        raise ValueError(f"unknown expect {expect!r}; one of {_EXPECT}")
    try:
        line = bytes(line)
    except (TypeError, ValueError):
        raise GarbledResponse(f"not bytes: {type(line).__name__}") from None
    if not line:
        raise NoResponse("no response (timeout)")
    if not line.endswith(LINE_TERMINATOR):
        raise TruncatedResponse(f"response without \\r\\n terminator: {line[:80]!r}")
    body = line[:-2]
    if not _PRINTABLE.fullmatch(body):
        raise GarbledResponse(f"non-printable bytes in response: {line[:80]!r}")
    text = body.decode("ascii")
    if chk:
        if len(text) < 3 or text[-3] != "*":
            raise ChecksumError(f"checksum mode on but no *HH in {text[:80]!r}")
        payload, hh = text[:-3], text[-2:]
        if hh != checksum(payload.encode("ascii")):
            raise ChecksumError(f"bad checksum *{hh} (expected *{checksum(payload.encode('ascii'))}) "
                                f"in {text[:80]!r}")
    else:
        payload = text
    if payload.startswith("ERR"):
        m = _ERR.fullmatch(payload)
        if m is None:
            raise GarbledResponse(f"malformed error response {payload[:80]!r}")
        code, message = int(m.group(1)), m.group(2)
        if HEAD_ERRORS.get(code) != message:
            raise GarbledResponse(f"unknown error code/message {payload[:80]!r}")
        raise _ERROR_CLASSES[code](code, message)
    if "*" in payload:
        raise GarbledResponse(f"unexpected '*' in response {payload[:80]!r}")
    if not payload:
        raise GarbledResponse("empty response line")
    if expect == "text":
        return payload
    if expect == "ok":
        if payload != "OK":
            raise GarbledResponse(f"expected OK, got {payload[:80]!r}")
        return None
    if expect == "float":
        return _as_float(payload, "value")
    if expect == "int":
        return _as_int(payload, "value")
    if expect == "word":
        if not _WORD.fullmatch(payload):
            raise GarbledResponse(f"expected a word, got {payload[:80]!r}")
        return payload
    if expect == "idn":
        m = _IDN.fullmatch(payload)
        if m is None:
            raise GarbledResponse(f"expected maker,model,serial,firmware, got {payload[:80]!r}")
        return Identity(*m.groups())
    if expect == "error_entry":
        m = _ERRENTRY.fullmatch(payload)
        if m is None:
            raise GarbledResponse(f'expected <code>,"<message>", got {payload[:80]!r}')
        return ErrorEntry(int(m.group(1)), m.group(2))
    # reading
    m = _READING.fullmatch(payload)
    if m is None:
        raise GarbledResponse(f"expected <mean>,<std>,<n>,<flags>, got {payload[:80]!r}")
    mean = _as_float(m.group(1), "mean_counts")
    std = _as_float(m.group(2), "std_counts")
    n = _as_int(m.group(3), "n")
    flags = _as_int(m.group(4), "flags")
    if std < 0 or not READ_N_RANGE[0] <= n <= READ_N_RANGE[1] or not 0 <= flags <= 3:
        raise GarbledResponse(f"reading fields out of range in {payload[:80]!r}")
    return Reading(mean, std, n, flags)

