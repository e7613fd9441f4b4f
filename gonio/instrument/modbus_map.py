"""The motion controller's Modbus register map, as one table of rows.

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

:data:`MODBUS_MAP` maps a register's name to its :class:`Register` row: table (coil, holding,
input), address (or offset inside an axis block ``100 + 20 a``), number of 16-bit words, value
type, access and the validator the controller applies to a written value. The driver's devices
(:mod:`gonio.instrument.motion`, through the descriptors of :mod:`gonio.instrument.registers`),
the mock controller (:mod:`gonio.mock.motion`) and the generated protocol document
(``docs/instrument.md``, :mod:`gonio.instrument.docs`) all read this one table: adding a register
is adding a row.

Controller rules (enforced by the controller / mock; the driver avoids triggering them):

- drives must be enabled (CONTROL bit0) for a move or homing, otherwise exception 3;
- while any axis is homing, every *write* except a CONTROL write with the stop-all bit answers
  exception 6 (device busy); reads are always served, so status can be polled;
- a move of an axis that was never homed is refused: the write is acknowledged, nothing moves,
  and the axis latches fault 3 (not homed);
- a move to a target outside the soft limits answers exception 3 (illegal data value); a TARGET
  write carrying both words of an out-of-limit value is refused the same way (not stored);
  every other written value the row's validator refuses answers exception 3 too;
- a move whose destination would bring the detector within 5 degrees of the source direction
  (:func:`gonio.data.geometry.beam_blocked`) latches fault 4 on that axis and answers exception 3;
  nothing moves;
- a move of an axis with a latched fault answers exception 4 (reset the fault first: CONTROL
  bit3, which clears every axis fault);
- an axis is in position when ``|actual - target| <= 5 mdeg`` after its move and settling.

Power-on state: drives disabled, axes not homed, lamp off, shutter closed, slot 0 (sample).
The shutter coil and the head's ``SHUTTER`` command act on the same source shutter.

References
----------
docs/instrument.md (the protocol contract); Modbus Application Protocol Specification V1.1b3
(exception codes); docs/physics.md section 1 (frames and angles).
"""

from __future__ import annotations

import enum
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

__all__ = [
    "FIRMWARE_VERSION", "Axis", "AXES", "N_AXES", "HOME_POSITIONS_MDEG", "IN_POSITION_TOLERANCE_MDEG",
    "DEFAULT_VELOCITY_CDEG_S", "VELOCITY_RANGE_CDEG_S", "AXIS_BLOCK_BASE", "AXIS_BLOCK_STRIDE",
    "Control", "ControllerStatus", "AxisStatus", "AxisFault", "AxisCommand", "SampleSlot",
    "ModbusException", "exception_name",
    "Register", "MODBUS_MAP", "COIL", "HOLDING", "INPUT", "register_blocks",
    "HR_CONTROL", "HR_SAMPLE_SLOT", "HR_OWNER", "IR_STATUS", "IR_FIRMWARE", "COIL_LAMP", "COIL_SHUTTER",
    "N_COILS", "HOLDING_REGISTER_RANGES", "INPUT_REGISTER_RANGES",
    "axis_target_address", "axis_velocity_address", "axis_command_address",
    "axis_actual_address", "axis_status_address", "axis_fault_address",
    "int32_to_registers", "registers_to_int32", "owner_to_registers", "registers_to_owner",
    "deg_to_mdeg", "mdeg_to_deg", "within_soft_limits",
]

FIRMWARE_VERSION = 0x0104
"""Input register FIRMWARE: firmware 1.4."""


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
AXIS_BLOCK_BASE = 100
AXIS_BLOCK_STRIDE = 20


# --- bit fields and codes ---------------------------------------------------------------------

# One line a code table: the wire values are the contract (docs/instrument.md lists them).

#: CONTROL holding register bits (bits 1..3 are commands, cleared by the controller).
Control = enum.IntFlag("Control", {"ENABLE": 0x1, "HOME_ALL": 0x2, "STOP_ALL": 0x4, "RESET_FAULT": 0x8})
#: CONTROLLER STATUS input register bits (READY: drives enabled, every axis homed, no fault,
#: nothing homing).
ControllerStatus = enum.IntFlag("ControllerStatus", {"READY": 0x1, "INTERLOCK_OPEN": 0x2,
                                                     "EMERGENCY_STOP": 0x4, "ANY_FAULT": 0x8})
#: Axis FAULT codes.
AxisFault = enum.IntEnum("AxisFault", {"NONE": 0, "FOLLOWING_ERROR": 1, "LIMIT": 2, "NOT_HOMED": 3,
                                       "BEAM_BLOCK": 4})
#: Axis COMMAND register values (the register reads back the last command).
AxisCommand = enum.IntEnum("AxisCommand", {"NONE": 0, "MOVE": 1, "HOME": 2, "STOP": 3})
#: SAMPLE_SLOT holding register (sample changer): what sits in the beam.
SampleSlot = enum.IntEnum("SampleSlot", {"SAMPLE": 0, "WHITE_REFERENCE": 1})
#: Modbus exception codes used by the controller.
ModbusException = enum.IntEnum("ModbusException", {"ILLEGAL_FUNCTION": 1, "ILLEGAL_ADDRESS": 2,
                                                   "ILLEGAL_VALUE": 3, "DEVICE_FAILURE": 4,
                                                   "DEVICE_BUSY": 6})


class AxisStatus(enum.IntFlag):
    """Axis STATUS input register bits."""

    HOMED = 0x1
    MOVING = 0x2         # also set while homing and settling
    IN_POSITION = 0x4
    FAULT = 0x8
    PLUS_LIMIT = 0x10    # actual position at (or beyond) the upper soft limit
    MINUS_LIMIT = 0x20   # actual position at (or beyond) the lower soft limit


def exception_name(code: int) -> str:
    """Readable name of a Modbus exception code.

    Examples
    --------
    >>> exception_name(6), exception_name(9)
    ('device busy', 'unknown exception')
    """
    try:
        return ModbusException(code).name.lower().replace("_", " ")
    except ValueError:
        return "unknown exception"


# --- word packing -----------------------------------------------------------------------------

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


def owner_to_registers(token: int) -> tuple[int, int]:
    """Pack an owner token (0 .. 2**32 - 1) into the OWNER registers, high word first.

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


def deg_to_mdeg(angle_deg: float) -> int:
    """Degrees to integer millidegrees (rounded half away from zero).

    Examples
    --------
    >>> deg_to_mdeg(-12.3455)
    -12346
    """
    return int(math.copysign(math.floor(abs(angle_deg) * 1000.0 + 0.5), angle_deg))


def mdeg_to_deg(position_mdeg: int) -> float:
    """Integer millidegrees to degrees."""
    return int(position_mdeg) / 1000.0


def _check_axis(a: int) -> int:
    if not 0 <= int(a) < N_AXES:
        raise ValueError(f"axis index {a!r} not in 0..{N_AXES - 1}")
    return int(a)


def within_soft_limits(axis: int, position_mdeg: int) -> bool:
    """True when ``position_mdeg`` is inside axis ``axis``'s soft limits (limits included)."""
    return AXES[_check_axis(axis)].within_limits(position_mdeg)


# --- the table --------------------------------------------------------------------------------

COIL, HOLDING, INPUT = "coil", "holding", "input"
_TYPES = ("bool", "uint16", "int32", "uint32")
_WORDS = {"bool": 1, "uint16": 1, "int32": 2, "uint32": 2}

#: A validator: (value, axis or None) -> why the controller refuses it, or None.
Validator = Callable[[int, "int | None"], "str | None"]


def _member_of(kind: type[enum.IntEnum]) -> Validator:
    def check(value: int, axis: int | None) -> str | None:
        return None if value in {int(m) for m in kind} else f"{value} is not a {kind.__name__}"
    return check


def _bits_of(kind: type[enum.IntFlag]) -> Validator:
    known = 0
    for m in kind:
        known |= int(m)

    def check(value: int, axis: int | None) -> str | None:
        return None if not value & ~known else f"value {value:#x} has unknown bits"
    return check


def _in_range(lo: int, hi: int, unit: str) -> Validator:
    def check(value: int, axis: int | None) -> str | None:
        return None if lo <= value <= hi else f"{value} {unit} out of range {lo}..{hi}"
    return check


def _soft_limits(value: int, axis: int | None) -> str | None:
    ax = AXES[_check_axis(axis if axis is not None else -1)]
    if ax.within_limits(value):
        return None
    return f"{value} mdeg outside the soft limits {ax.min_mdeg}..{ax.max_mdeg}"


@dataclass(frozen=True)
class Register:
    """One row of the register map.

    Attributes
    ----------
    name : the register's name (the key of :data:`MODBUS_MAP`).
    table : ``"coil"``, ``"holding"`` or ``"input"``.
    address : the address; for a per-axis register the offset inside the axis block
        (:meth:`address_of` adds ``AXIS_BLOCK_BASE + AXIS_BLOCK_STRIDE * axis``).
    type : ``"bool"`` (a coil), ``"uint16"``, ``"int32"`` or ``"uint32"`` (two words, high first).
    access : ``"rw"`` or ``"r"``.
    doc : meaning (units, bits), as in the generated protocol document.
    per_axis : one register per axis.
    kind : the enum or flag class the value decodes to (None: a plain integer).
    validator : the controller's check of a written value (None: any value of the type).
    """

    name: str
    table: str
    address: int
    type: str
    access: str
    doc: str
    per_axis: bool = False
    kind: Callable[[int], Any] | None = None
    validator: Validator | None = None

    def __post_init__(self) -> None:
        if self.table not in (COIL, HOLDING, INPUT) or self.type not in _TYPES:
            raise ValueError(f"register {self.name}: bad table {self.table!r} or type {self.type!r}")

    @property
    def words(self) -> int:
        """Number of 16-bit registers (1 for a coil)."""
        return _WORDS[self.type]

    def address_of(self, axis: int | None = None) -> int:
        """The absolute address (of axis ``axis`` for a per-axis register)."""
        if not self.per_axis:
            if axis is not None:
                raise ValueError(f"{self.name} is not a per-axis register")
            return self.address
        if axis is None:
            raise ValueError(f"{self.name} is a per-axis register: give the axis")
        return AXIS_BLOCK_BASE + AXIS_BLOCK_STRIDE * _check_axis(axis) + self.address

    def encode(self, value: int) -> list[int]:
        """The register words of ``value`` (high word first).

        Examples
        --------
        >>> MODBUS_MAP["TARGET"].encode(-1)
        [65535, 65535]
        """
        if self.type == "int32":
            return list(int32_to_registers(value))
        if self.type == "uint32":
            return list(owner_to_registers(value))
        if self.type == "bool":
            return [int(bool(value))]
        if not 0 <= int(value) <= 0xFFFF:
            raise ValueError(f"{self.name}: {value!r} not in 0..65535")
        return [int(value)]

    def decode(self, words: list[int]):
        """The value of the register words (an instance of :attr:`kind` when it has one).

        Examples
        --------
        >>> MODBUS_MAP["AXIS_STATUS"].decode([5])
        <AxisStatus.HOMED|IN_POSITION: 5>
        """
        if self.type == "int32":
            value = registers_to_int32(words[0], words[1])
        elif self.type == "uint32":
            value = registers_to_owner(words[0], words[1])
        elif self.type == "bool":
            return bool(words[0])
        else:
            value = int(words[0])
        return self.kind(value) if self.kind is not None else value

    def refusal(self, value: int, axis: int | None = None) -> str | None:
        """Why the controller refuses to store ``value`` here (exception 3), or None."""
        if self.validator is None:
            return None
        why = self.validator(int(value), axis)
        if why is None:
            return None
        where = f"axis {axis} " if self.per_axis else ""
        return f"{where}{self.name}: {why}"


def _table(*rows: Register) -> dict[str, Register]:
    out: dict[str, Register] = {}
    for r in rows:
        if r.name in out:
            raise ValueError(f"register {r.name} defined twice")
        out[r.name] = r
    return out


MODBUS_MAP: dict[str, Register] = _table(
    # name          table    addr  type      access doc
    Register("CONTROL", HOLDING, 0, "uint16", "rw",
             "bit0 enable drives, bit1 home all, bit2 stop all, bit3 reset fault "
             "(bits 1..3 are commands, self-clearing)", kind=Control, validator=_bits_of(Control)),
    Register("SAMPLE_SLOT", HOLDING, 10, "uint16", "rw",
             "sample changer: 0 the sample, 1 the white reference standard in the beam "
             "(this project's addition)", kind=SampleSlot, validator=_member_of(SampleSlot)),
    Register("OWNER", HOLDING, 20, "uint32", "rw",
             "owner token of the client driving the instrument, 0 = unclaimed (this project's "
             "addition; plain storage)"),
    Register("TARGET", HOLDING, 0, "int32", "rw", "axis target position, mdeg", per_axis=True,
             validator=_soft_limits),
    Register("VELOCITY", HOLDING, 2, "uint16", "rw", "axis velocity, centideg/s", per_axis=True,
             validator=_in_range(*VELOCITY_RANGE_CDEG_S, "centideg/s")),
    Register("COMMAND", HOLDING, 3, "uint16", "rw", "axis command: 1 move to target, 2 home, 3 stop",
             per_axis=True, kind=AxisCommand, validator=_member_of(AxisCommand)),
    Register("STATUS", INPUT, 0, "uint16", "r",
             "controller status: bit0 ready, bit1 interlock open, bit2 emergency stop, "
             "bit3 any fault", kind=ControllerStatus),
    Register("FIRMWARE", INPUT, 1, "uint16", "r", "firmware version (0x0104 = 1.4)"),
    Register("ACTUAL", INPUT, 0, "int32", "r", "axis actual position, mdeg", per_axis=True),
    Register("AXIS_STATUS", INPUT, 2, "uint16", "r",
             "axis status: bit0 homed, bit1 moving, bit2 in position, bit3 fault, bit4 + limit, "
             "bit5 - limit", per_axis=True, kind=AxisStatus),
    Register("FAULT", INPUT, 3, "uint16", "r",
             "axis fault code: 0 none, 1 following error, 2 limit, 3 not homed, 4 beam-block zone",
             per_axis=True),
    Register("LAMP", COIL, 0, "bool", "rw", "lamp on"),
    Register("SHUTTER", COIL, 1, "bool", "rw", "source shutter open (the head's SHUTTER too)"),
)
"""The register map: name -> :class:`Register` (see the module docstring)."""


def register_blocks(table: str) -> tuple[tuple[int, int], ...]:
    """``(start, count)`` of every defined block of ``table``, contiguous rows merged.

    Other addresses answer exception 2 (illegal address).

    Examples
    --------
    >>> register_blocks(HOLDING)[:4]
    ((0, 1), (10, 1), (20, 2), (100, 4))
    """
    spans = sorted((r.address_of(a), r.words)
                   for r in MODBUS_MAP.values() if r.table == table
                   for a in (range(N_AXES) if r.per_axis else (None,)))
    out: list[list[int]] = []
    for start, count in spans:
        if out and out[-1][0] + out[-1][1] == start:
            out[-1][1] += count
        else:
            out.append([start, count])
    return tuple((s, c) for s, c in out)


# Addresses by their conventional names, derived from the table (the mock, tests and tools
# address registers directly; the driver goes through the descriptors).
HR_CONTROL, HR_SAMPLE_SLOT, HR_OWNER = (MODBUS_MAP[n].address for n in ("CONTROL", "SAMPLE_SLOT", "OWNER"))
IR_STATUS, IR_FIRMWARE = (MODBUS_MAP[n].address for n in ("STATUS", "FIRMWARE"))
COIL_LAMP, COIL_SHUTTER = (MODBUS_MAP[n].address for n in ("LAMP", "SHUTTER"))
N_COILS = sum(1 for r in MODBUS_MAP.values() if r.table == COIL)
HOLDING_REGISTER_RANGES = register_blocks(HOLDING)
"""(start, count) of every defined holding register block; other addresses answer exception 2."""
INPUT_REGISTER_RANGES = register_blocks(INPUT)
"""(start, count) of every defined input register block; other addresses answer exception 2."""
# the absolute address of a per-axis row for axis ``a``: ``axis_target_address(a)``
axis_target_address, axis_velocity_address, axis_command_address = (
    MODBUS_MAP[n].address_of for n in ("TARGET", "VELOCITY", "COMMAND"))
axis_actual_address, axis_status_address, axis_fault_address = (
    MODBUS_MAP[n].address_of for n in ("ACTUAL", "AXIS_STATUS", "FAULT"))
