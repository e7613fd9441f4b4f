"""Mock motion controller: four axes with velocity, settling, homing and the controller rules.

The state is evaluated lazily from a monotonic clock: a move started at ``t0`` from ``x0`` to
``x1`` at velocity ``v`` (scaled by the speed factor) is at::

    x(t) = x0 + sign(x1 - x0) * min(v (t - t0), |x1 - x0|)            while moving
    x(t) = x1 + o * (1 - (t - t_arrive) / t_settle)                    while settling

with a settling overshoot ``o`` of up to 20 mdeg in the direction of motion; afterwards
``x = x1`` exactly and the axis is in position (``|x - target| <= 5 mdeg``). Homing takes
:data:`HOMING_TIME_S` and ends at :data:`gonio.protocol.HOME_POSITIONS_MDEG`. The rules of
:mod:`gonio.protocol` (not homed -> fault 3, soft limits -> exception 3, beam block -> fault 4 +
exception 3, busy while homing -> exception 6, faulted axis -> exception 4, drives disabled ->
exception 3) are enforced in :meth:`MotionController.write_holding`.

:class:`ModbusFrontend` maps register reads and writes of the pymodbus ``SimDevice`` action
callback onto the controller; pymodbus' own register storage is only a mirror refreshed on
every access. It also injects the Modbus faults (see :mod:`gonio.mock.faults`); a dropped link
(``modbus_drop``) is handed to the transport through the frontend's ``drop_link`` hook (TCP:
close the connection that carried the request, :mod:`gonio.mock.servers`), or, over RTU, makes
the controller's serial interface ignore requests for :data:`LINK_SILENCE_S` (times the speed
factor).
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field
from typing import Callable

from gonio import protocol as P
from gonio.mock.faults import MODBUS_FAULT_ORDER, FaultInjector

__all__ = ["HOMING_TIME_S", "SETTLE_TIME_S", "LINK_SILENCE_S", "SPEED_FACTORS", "INTEGRATION_FACTORS",
           "AxisState", "MotionController", "ModbusFrontend", "ModbusRefusal", "DropRequest"]

log = logging.getLogger(__name__)

HOMING_TIME_S = 1.5
SETTLE_TIME_S = 0.2
SETTLE_OVERSHOOT_MDEG = 20
LINK_SILENCE_S = 0.5
"""After a ``modbus_drop`` over RTU the controller ignores requests this long (times speed)."""
SPEED_FACTORS = {"fast": 0.01, "real": 1.0}
"""Multiplier of every motion time (and of the head's link re-initialisation) per ``--speed``."""
INTEGRATION_FACTORS = {"fast": 0.001, "real": 1.0}
"""Multiplier of the head's integration time (how long ``READ? n`` takes) per ``--speed``."""


class ModbusRefusal(Exception):
    """A request the controller answers with a Modbus exception ``code``."""

    def __init__(self, code: int, why: str):
        super().__init__(why)
        self.code = int(code)


class DropRequest(Exception):
    """The request is dropped without an answer (fault modbus_noresponse)."""


@dataclass
class AxisState:
    """One axis: positions in mdeg, times in seconds of the controller clock."""

    index: int
    position: float
    target: int = 0
    velocity: int = P.DEFAULT_VELOCITY_CDEG_S
    command: int = 0
    homed: bool = False
    fault: int = 0
    # active motion: (t0, x0, x1, t_arrive, t_end, kind "move"|"home", t_fault or None)
    motion: tuple | None = None
    moved: bool = False        # a move completed (in-position meaningful)

    def destination(self) -> int:
        """Where the axis will stand: the end of its motion, or where it is."""
        return int(self.motion[2]) if self.motion is not None else int(round(self.position))


@dataclass
class MotionController:
    """The controller's state machine. ``now`` is a callable clock (seconds)."""

    time_scale: float = 0.01
    faults: FaultInjector | None = None
    now: Callable[[], float] = time.monotonic
    on_state_change: Callable[[], None] | None = None
    axes: list[AxisState] = field(default_factory=list)
    enabled: bool = False
    slot: int = 0
    owner: int = 0
    lamp_on: bool = False
    shutter_open: bool = False

    def __post_init__(self):
        if not self.axes:
            self.axes = [AxisState(a, float(P.HOME_POSITIONS_MDEG[a]), target=P.HOME_POSITIONS_MDEG[a])
                         for a in range(P.N_AXES)]

    # --- evaluation ------------------------------------------------------------------------
    def update(self) -> None:
        """Advance every axis to the current time."""
        t = self.now()
        for ax in self.axes:
            if ax.motion is None:
                continue
            t0, x0, x1, t_arrive, t_end, kind, t_fault = ax.motion
            if t_fault is not None and t >= t_fault:
                ax.position = self._position_at(ax, t_fault)
                ax.motion = None
                ax.fault = P.AxisFault.FOLLOWING_ERROR
                log.info("axis %d: following error at %.0f mdeg (injected fault)", ax.index, ax.position)
                continue
            if t >= t_end:
                ax.position = float(x1)
                ax.motion = None
                if kind == "home":
                    ax.homed = True
                    ax.target = int(x1)
                ax.moved = True
            else:
                ax.position = self._position_at(ax, t)

    def _position_at(self, ax: AxisState, t: float) -> float:
        t0, x0, x1, t_arrive, t_end, kind, _ = ax.motion
        if t >= t_arrive:
            d = x1 - x0
            over = min(SETTLE_OVERSHOOT_MDEG, abs(d)) * (1 if d >= 0 else -1)
            frac = (t - t_arrive) / max(t_end - t_arrive, 1e-12)
            return x1 + over * max(0.0, 1.0 - frac)
        return x0 + (x1 - x0) * (t - t0) / max(t_arrive - t0, 1e-12)

    def homing(self) -> bool:
        return any(ax.motion is not None and ax.motion[5] == "home" for ax in self.axes)

    def positions_mdeg(self) -> tuple[int, int, int, int]:
        self.update()
        return tuple(int(round(ax.position)) for ax in self.axes)  # type: ignore[return-value]

    def axis_status(self, a: int) -> int:
        ax = self.axes[a]
        s = 0
        if ax.homed:
            s |= P.AxisStatus.HOMED
        if ax.motion is not None:
            s |= P.AxisStatus.MOVING
        elif ax.homed and abs(ax.position - ax.target) <= P.IN_POSITION_TOLERANCE_MDEG:
            s |= P.AxisStatus.IN_POSITION
        if ax.fault:
            s |= P.AxisStatus.FAULT
        spec = P.AXES[a]
        if ax.position >= spec.max_mdeg:
            s |= P.AxisStatus.PLUS_LIMIT
        if ax.position <= spec.min_mdeg:
            s |= P.AxisStatus.MINUS_LIMIT
        return int(s)

    def controller_status(self) -> int:
        s = 0
        if any(ax.fault for ax in self.axes):
            s |= P.ControllerStatus.ANY_FAULT
        elif self.enabled and all(ax.homed for ax in self.axes) and not self.homing():
            s |= P.ControllerStatus.READY
        return int(s)

    # --- register images ---------------------------------------------------------------------
    def holding_image(self) -> dict[int, int]:
        img = {P.HR_CONTROL: int(P.Control.ENABLE) if self.enabled else 0, P.HR_SAMPLE_SLOT: self.slot}
        img[P.HR_OWNER], img[P.HR_OWNER + 1] = P.owner_to_registers(self.owner)
        for a, ax in enumerate(self.axes):
            hi, lo = P.int32_to_registers(ax.target)
            base = P.axis_target_address(a)
            img.update({base: hi, base + 1: lo, base + 2: ax.velocity, base + 3: ax.command})
        return img

    def input_image(self) -> dict[int, int]:
        self.update()
        img = {P.IR_STATUS: self.controller_status(), P.IR_FIRMWARE: P.FIRMWARE_VERSION}
        for a, ax in enumerate(self.axes):
            hi, lo = P.int32_to_registers(int(round(ax.position)))
            base = P.axis_actual_address(a)
            img.update({base: hi, base + 1: lo, base + 2: self.axis_status(a), base + 3: int(ax.fault)})
        return img

    # --- writes ----------------------------------------------------------------------------
    def _changed(self) -> None:
        if self.on_state_change is not None:
            self.on_state_change()

    def write_holding(self, address: int, values: list[int]) -> None:
        """Apply a holding-register write atomically (all checks first), or raise ModbusRefusal."""
        self.update()
        regs = {address + i: int(v) & 0xFFFF for i, v in enumerate(values)}
        if self.homing():
            ctl = regs.get(P.HR_CONTROL)
            if not (len(regs) == 1 and ctl is not None and ctl & P.Control.STOP_ALL):
                raise ModbusRefusal(P.ModbusException.DEVICE_BUSY, "homing in progress")
        # validate everything before changing anything
        new_targets: dict[int, int] = {}
        new_velocities: dict[int, int] = {}
        commands: dict[int, int] = {}
        if P.HR_SAMPLE_SLOT in regs and regs[P.HR_SAMPLE_SLOT] not in {s.value for s in P.SampleSlot}:
            raise ModbusRefusal(P.ModbusException.ILLEGAL_VALUE,
                                f"sample slot {regs[P.HR_SAMPLE_SLOT]} unknown")
        for a, ax in enumerate(self.axes):
            base = P.axis_target_address(a)
            if base in regs or base + 1 in regs:
                hi0, lo0 = P.int32_to_registers(ax.target)
                tgt = P.registers_to_int32(regs.get(base, hi0), regs.get(base + 1, lo0))
                if base in regs and base + 1 in regs and not P.within_soft_limits(a, tgt):
                    raise ModbusRefusal(P.ModbusException.ILLEGAL_VALUE,
                                        f"axis {a} target {tgt} mdeg outside the soft limits")
                new_targets[a] = tgt
            if base + 2 in regs:
                v = regs[base + 2]
                if not P.VELOCITY_RANGE_CDEG_S[0] <= v <= P.VELOCITY_RANGE_CDEG_S[1]:
                    raise ModbusRefusal(P.ModbusException.ILLEGAL_VALUE,
                                        f"axis {a} velocity {v} out of range")
                new_velocities[a] = v
            if base + 3 in regs:
                c = regs[base + 3]
                if c not in (P.AxisCommand.NONE, P.AxisCommand.MOVE, P.AxisCommand.HOME, P.AxisCommand.STOP):
                    raise ModbusRefusal(P.ModbusException.ILLEGAL_VALUE, f"axis {a} command {c} unknown")
                commands[a] = c
        ctl = regs.get(P.HR_CONTROL)
        if ctl is not None and ctl & ~0xF:
            raise ModbusRefusal(P.ModbusException.ILLEGAL_VALUE, f"CONTROL value {ctl:#x} has unknown bits")
        # pre-check the commands with the new targets (so a refused write changes nothing)
        targets = [new_targets.get(a, ax.target) for a, ax in enumerate(self.axes)]
        enabled_after = bool(ctl & P.Control.ENABLE) if ctl is not None else self.enabled
        for a, c in commands.items():
            ax = self.axes[a]
            if c in (P.AxisCommand.MOVE, P.AxisCommand.HOME):
                if not enabled_after:
                    raise ModbusRefusal(P.ModbusException.ILLEGAL_VALUE, "drives disabled (CONTROL bit0)")
                if ax.fault:
                    raise ModbusRefusal(P.ModbusException.DEVICE_FAILURE,
                                        f"axis {a} in fault {ax.fault}: reset first")
            if c == P.AxisCommand.MOVE and ax.homed and not P.within_soft_limits(a, targets[a]):
                raise ModbusRefusal(P.ModbusException.ILLEGAL_VALUE,
                                    f"axis {a} target {targets[a]} mdeg outside the soft limits")
        if ctl is not None and ctl & P.Control.HOME_ALL:
            if not enabled_after:
                raise ModbusRefusal(P.ModbusException.ILLEGAL_VALUE, "drives disabled (CONTROL bit0)")
            if any(ax.fault for ax in self.axes) and not ctl & P.Control.RESET_FAULT:
                raise ModbusRefusal(P.ModbusException.DEVICE_FAILURE, "axis fault: reset first")
        # apply
        for a, tgt in new_targets.items():
            self.axes[a].target = tgt
        for a, v in new_velocities.items():
            self.axes[a].velocity = v
        if P.HR_OWNER in regs or P.HR_OWNER + 1 in regs:
            hi0, lo0 = P.owner_to_registers(self.owner)
            self.owner = P.registers_to_owner(regs.get(P.HR_OWNER, hi0), regs.get(P.HR_OWNER + 1, lo0))
        if P.HR_SAMPLE_SLOT in regs:
            self.slot = regs[P.HR_SAMPLE_SLOT]
            self._changed()
        if ctl is not None:
            self._control(ctl)
        for a, c in commands.items():
            self._command(a, c)

    def _control(self, ctl: int) -> None:
        self.enabled = bool(ctl & P.Control.ENABLE)
        if ctl & P.Control.RESET_FAULT:
            for ax in self.axes:
                ax.fault = 0
        if ctl & P.Control.STOP_ALL or not self.enabled:
            for ax in self.axes:
                self._stop(ax)
        if ctl & P.Control.HOME_ALL:
            for ax in self.axes:
                self._start_home(ax)
            self._changed()

    def _stop(self, ax: AxisState) -> None:
        if ax.motion is not None:
            self.update()
            kind = ax.motion[5] if ax.motion is not None else None
            ax.motion = None
            if kind == "home":
                ax.homed = False

    def _start_home(self, ax: AxisState) -> None:
        t = self.now()
        x1 = float(P.HOME_POSITIONS_MDEG[ax.index])
        dur = HOMING_TIME_S * self.time_scale
        ax.homed = False
        ax.command = P.AxisCommand.HOME
        ax.motion = (t, ax.position, x1, t + 0.8 * dur, t + dur, "home", None)

    def _command(self, a: int, c: int) -> None:
        ax = self.axes[a]
        ax.command = c
        if c == P.AxisCommand.STOP:
            self._stop(ax)
        elif c == P.AxisCommand.HOME:
            self._start_home(ax)
            self._changed()
        elif c == P.AxisCommand.MOVE:
            self._move(ax)

    def _move(self, ax: AxisState) -> None:
        a = ax.index
        if not ax.homed:
            ax.fault = P.AxisFault.NOT_HOMED
            log.info("axis %d: move refused, not homed (fault 3)", a)
            return
        dest = [other.destination() for other in self.axes]
        dest[a] = ax.target
        if P.beam_blocked(P.mdeg_to_deg(dest[0]), P.mdeg_to_deg(dest[1]), P.mdeg_to_deg(dest[2])):
            ax.fault = P.AxisFault.BEAM_BLOCK
            log.info("axis %d: move to %d mdeg refused, beam-block zone (fault 4)", a, ax.target)
            raise ModbusRefusal(P.ModbusException.ILLEGAL_VALUE, "beam-block zone")
        t = self.now()
        x0 = ax.position
        x1 = float(ax.target)
        dist = abs(x1 - x0)
        v_mdeg_s = ax.velocity * 10.0
        t_arrive = t + dist / v_mdeg_s * self.time_scale
        t_end = t_arrive + (SETTLE_TIME_S * self.time_scale if dist > 0 else 0.0)
        t_fault = None
        if self.faults is not None and self.faults.fires("axis_fault"):
            t_fault = t + 0.5 * (t_arrive - t) if dist > 0 else t
        ax.motion = (t, x0, x1, t_arrive, t_end, "move", t_fault)
        ax.moved = False
        self._changed()

    def write_coils(self, address: int, bits: list[bool]) -> None:
        """Lamp and shutter coils (refused with exception 6 while homing, like every write)."""
        self.update()
        if self.homing():
            raise ModbusRefusal(P.ModbusException.DEVICE_BUSY, "homing in progress")
        for i, b in enumerate(bits):
            addr = address + i
            if addr == P.COIL_LAMP:
                self.lamp_on = bool(b)
            elif addr == P.COIL_SHUTTER:
                self.shutter_open = bool(b)
        self._changed()

    def coil_image(self) -> list[bool]:
        return [self.lamp_on, self.shutter_open]


class ModbusFrontend:
    """The pymodbus ``SimDevice`` of the controller, with fault injection and statistics.

    Parameters
    ----------
    controller : the controller model.
    faults : the fault injector (None: no faults).
    link : ``"tcp"`` or ``"rtu"``: how a ``modbus_drop`` shows (see :mod:`gonio.mock.faults`).

    ``drop_link`` (set by the TCP server) is called inside the action of a request hit by
    ``modbus_drop`` and closes the connection that carried it; ``requests`` counts the requests
    that reached the controller (those ignored during an RTU silence excluded), ``drops`` the
    links dropped and ``dropped`` lists each dropped request as ``(function code, address,
    executed)`` (so a test can check which request a ``modbus_drop=@N`` hit); ``writes`` counts
    the write requests executed (refused ones included). ``drop_executed``
    (tests; None = the seeded draw) forces whether a request dropped over TCP was executed; the
    draw is made anyway, so the other decisions do not change.
    """

    def __init__(self, controller: MotionController, faults: FaultInjector | None = None,
                 link: str = "tcp"):
        if link not in ("tcp", "rtu"):
            raise ValueError(f"link must be 'tcp' or 'rtu', not {link!r}")
        self.controller = controller
        self.faults = faults
        self.link = link
        self.requests = 0
        self.writes = 0
        self.drops = 0
        self.dropped: list[tuple[int, int, bool]] = []
        self.drop_executed: bool | None = None
        self.silent_until = -math.inf
        self.drop_link: Callable[[], None] | None = None

    def device(self):
        """Build the ``pymodbus.simulator.SimDevice`` (non-shared blocks: c, d, h, i)."""
        from pymodbus.simulator import DataType, SimData, SimDevice

        coils = [SimData(0, values=[False] * 16, datatype=DataType.BITS)]
        discrete = [SimData(0, values=[False] * 16, datatype=DataType.BITS)]
        holding = [SimData(start, count=count, values=0, datatype=DataType.REGISTERS)
                   for start, count in P.HOLDING_REGISTER_RANGES]
        inputs = [SimData(start, count=count, values=0, datatype=DataType.REGISTERS)
                  for start, count in P.INPUT_REGISTER_RANGES]
        return SimDevice(id=P.UNIT_ID, simdata=(coils, discrete, holding, inputs), action=self.action)

    def _decide(self) -> tuple[str | None, bool]:
        """Draw every Modbus kind for one request: ``(fault or None, executed before a drop)``.

        All three kinds are drawn on every request (so each decision depends on the request
        count only); ``modbus_drop`` wins over ``modbus_noresponse`` over ``modbus_busy`` and the
        losers are not counted as injected.
        """
        f = self.faults
        if f is None:
            return None, False
        fired = [k for k in MODBUS_FAULT_ORDER if f.fires(k)]
        for k in fired[1:]:
            f.stats[k] -= 1
        if not fired:
            return None, False
        executed = False
        if fired[0] == "modbus_drop" and self.link == "tcp":
            executed = bool(f.rng("modbus_drop").random() < 0.5)   # always drawn
            if self.drop_executed is not None:
                executed = self.drop_executed
        return fired[0], executed

    def _drop(self, fc: int, address: int, executed: bool):
        """Drop the link now (no answer); returns the exception pymodbus treats as 'no answer'."""
        from pymodbus.exceptions import NoSuchIdException

        self.drops += 1
        self.dropped.append((int(fc), int(address), bool(executed)))
        if self.link == "tcp":
            log.info("modbus fc %d @%d: connection closed (injected modbus_drop, request %s)",
                     fc, address, "executed" if executed else "not executed")
            if self.drop_link is not None:
                self.drop_link()
        else:
            self.silent_until = self.controller.now() + LINK_SILENCE_S * self.controller.time_scale
            log.info("modbus fc %d @%d: serial interface silent (injected modbus_drop)", fc, address)
        return NoSuchIdException("link dropped (injected modbus_drop)")

    async def action(self, fc: int, start: int, address: int, count: int, regs: list[int], values):
        """pymodbus simulator action: runs on every request before pymodbus touches ``regs``."""
        from pymodbus.constants import ExcCodes
        from pymodbus.exceptions import NoSuchIdException

        if self.link == "rtu" and self.controller.now() < self.silent_until:
            # re-initialising after a dropped link: the request is not seen at all
            raise NoSuchIdException("serial interface re-initialising (injected modbus_drop)")
        self.requests += 1
        fault, executed = self._decide()
        if fault == "modbus_drop" and not executed:
            raise self._drop(fc, address, executed)
        if fault == "modbus_noresponse":
            log.info("modbus fc %d @%d: dropped (injected fault)", fc, address)
            raise NoSuchIdException("request dropped (injected modbus_noresponse)")
        if fault == "modbus_busy":
            log.info("modbus fc %d @%d: exception 6 (injected fault)", fc, address)
            return ExcCodes.DEVICE_BUSY
        result = self._execute(fc, start, address, count, regs, values)
        if fault == "modbus_drop":
            raise self._drop(fc, address, executed)
        return result

    def _execute(self, fc: int, start: int, address: int, count: int, regs: list[int], values):
        from pymodbus.constants import ExcCodes

        ctl = self.controller
        if values is not None:
            self.writes += 1
        try:
            if fc in (1, 5, 15):                       # coils
                if address + count > P.N_COILS:
                    return ExcCodes.ILLEGAL_ADDRESS
                if values is not None:
                    ctl.write_coils(address, [bool(v) for v in values])
                self._fill_bits(regs, ctl.coil_image())
            elif fc == 2:
                return ExcCodes.ILLEGAL_ADDRESS        # no discrete inputs
            elif fc == 4:
                self._fill(regs, start, ctl.input_image())
            elif fc in (3, 6, 16):
                if values is not None:
                    # pymodbus stores (and echoes) the written values; every later read is
                    # refilled from the controller, so self-clearing CONTROL bits read back clear
                    ctl.write_holding(address, [int(v) for v in values])
                self._fill(regs, start, ctl.holding_image())
            else:
                return ExcCodes.ILLEGAL_FUNCTION
        except ModbusRefusal as exc:
            log.info("modbus fc %d @%d: exception %d (%s)", fc, address, exc.code, exc)
            return ExcCodes(exc.code)
        return None

    @staticmethod
    def _fill(regs: list[int], start: int, image: dict[int, int]) -> None:
        for addr, val in image.items():
            i = addr - start
            if 0 <= i < len(regs):
                regs[i] = val & 0xFFFF

    @staticmethod
    def _fill_bits(regs: list[int], bits: list[bool]) -> None:
        from pymodbus.simulator.simutils import SimUtils

        padded = list(bits) + [False] * (16 - len(bits))
        regs[0] = SimUtils.bitsToRegisters(padded)[0]
