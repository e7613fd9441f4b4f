"""Mock motion controller: four axes with velocity, settling, homing and the controller rules.

The state is evaluated lazily from a monotonic clock: a move started at ``t0`` from ``x0`` to
``x1`` at velocity ``v`` (scaled by the speed factor) is at::

    x(t) = x0 + sign(x1 - x0) * min(v (t - t0), |x1 - x0|)            while moving
    x(t) = x1 + o * (1 - (t - t_arrive) / t_settle)                    while settling

with a settling overshoot ``o`` of up to 20 mdeg in the direction of motion; afterwards
``x = x1`` exactly and the axis is in position (``|x - target| <= 5 mdeg``). Homing takes
:data:`HOMING_TIME_S` and ends at :data:`gonio.instrument.modbus_map.HOME_POSITIONS_MDEG`. The rules of
:mod:`gonio.instrument.modbus_map` (not homed -> fault 3, soft limits -> exception 3, beam block -> fault 4 +
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
from collections.abc import Callable
from dataclasses import dataclass, field

from gonio.data import geometry as G
from gonio.instrument import links as LK
from gonio.instrument import modbus_map as MM
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


_SINGLE_WRITES = (5, 6)
"""Function codes pymodbus' simulator completes with a read-back call of the action."""


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
    velocity: int = MM.DEFAULT_VELOCITY_CDEG_S
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
            self.axes = [AxisState(a, float(MM.HOME_POSITIONS_MDEG[a]), target=MM.HOME_POSITIONS_MDEG[a])
                         for a in range(MM.N_AXES)]

    # --- evaluation ------------------------------------------------------------------------
    def update(self) -> None:
        """Advance every axis to the current time."""
        t = self.now()
        for ax in self.axes:
            motion = ax.motion
            if motion is None:
                continue
            t0, x0, x1, t_arrive, t_end, kind, t_fault = motion
            if t_fault is not None and t >= t_fault:
                ax.position = self._position_at(motion, t_fault)
                ax.motion = None
                ax.fault = MM.AxisFault.FOLLOWING_ERROR
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
                ax.position = self._position_at(motion, t)

    @staticmethod
    def _position_at(motion: tuple, t: float) -> float:
        """An axis's position (mdeg) at time ``t`` of its ``motion`` (:attr:`AxisState.motion`)."""
        t0, x0, x1, t_arrive, t_end, kind, _ = motion
        if t >= t_arrive:
            d = x1 - x0
            over = min(SETTLE_OVERSHOOT_MDEG, abs(d)) * (1 if d >= 0 else -1)
            frac = (t - t_arrive) / max(t_end - t_arrive, 1e-12)
            return x1 + over * max(0.0, 1.0 - frac)
        return x0 + (x1 - x0) * (t - t0) / max(t_arrive - t0, 1e-12)

    def homing(self) -> bool:
        """Whether any axis is homing."""
        return any(ax.motion is not None and ax.motion[5] == "home" for ax in self.axes)

    def positions_mdeg(self) -> tuple[int, int, int, int]:
        """The four axis positions, millidegrees, brought up to date."""
        self.update()
        return tuple(int(round(ax.position)) for ax in self.axes)  # type: ignore[return-value]

    def axis_status(self, a: int) -> int:
        """The status word of axis ``a`` (the register map's status bits)."""
        ax = self.axes[a]
        s = 0
        if ax.homed:
            s |= MM.AxisStatus.HOMED
        if ax.motion is not None:
            s |= MM.AxisStatus.MOVING
        elif ax.homed and abs(ax.position - ax.target) <= MM.IN_POSITION_TOLERANCE_MDEG:
            s |= MM.AxisStatus.IN_POSITION
        if ax.fault:
            s |= MM.AxisStatus.FAULT
        spec = MM.AXES[a]
        if ax.position >= spec.max_mdeg:
            s |= MM.AxisStatus.PLUS_LIMIT
        if ax.position <= spec.min_mdeg:
            s |= MM.AxisStatus.MINUS_LIMIT
        return int(s)

    def controller_status(self) -> int:
        """The controller's status word (the register map's controller bits)."""
        s = 0
        if any(ax.fault for ax in self.axes):
            s |= MM.ControllerStatus.ANY_FAULT
        elif self.enabled and all(ax.homed for ax in self.axes) and not self.homing():
            s |= MM.ControllerStatus.READY
        return int(s)

    # --- register images ---------------------------------------------------------------------
    def register_values(self) -> dict[tuple[str, int | None], int]:
        """The value of every register of the map, keyed ``(name, axis or None)``.

        Evaluated as the state stands (call :meth:`update` first for the current time).
        """
        values: dict[tuple[str, int | None], int] = {
            ("CONTROL", None): int(MM.Control.ENABLE) if self.enabled else 0,
            ("SAMPLE_SLOT", None): self.slot, ("OWNER", None): self.owner,
            ("STATUS", None): self.controller_status(), ("FIRMWARE", None): MM.FIRMWARE_VERSION,
            ("LAMP", None): int(self.lamp_on), ("SHUTTER", None): int(self.shutter_open)}
        for a, ax in enumerate(self.axes):
            values.update({("TARGET", a): ax.target, ("VELOCITY", a): ax.velocity,
                           ("COMMAND", a): ax.command, ("ACTUAL", a): int(round(ax.position)),
                           ("AXIS_STATUS", a): self.axis_status(a), ("FAULT", a): int(ax.fault)})
        return values

    def _image(self, table: str) -> dict[int, int]:
        """Address -> word of every register of ``table``, encoded by its row of the map."""
        img: dict[int, int] = {}
        for (name, axis), value in self.register_values().items():
            row = MM.MODBUS_MAP[name]
            if row.table == table:
                start = row.address_of(axis)
                img.update({start + k: w for k, w in enumerate(row.encode(value))})
        return img

    def holding_image(self) -> dict[int, int]:
        """The holding registers' values by address."""
        return self._image(MM.HOLDING)

    def input_image(self) -> dict[int, int]:
        """The input registers' values by address, brought up to date."""
        self.update()
        return self._image(MM.INPUT)

    # --- writes ----------------------------------------------------------------------------
    def _changed(self) -> None:
        if self.on_state_change is not None:
            self.on_state_change()

    def write_holding(self, address: int, values: list[int]) -> None:  # noqa: C901
        """Apply a holding-register write atomically (all checks first), or raise ModbusRefusal."""
        self.update()
        regs = {address + i: int(v) & 0xFFFF for i, v in enumerate(values)}
        if self.homing():
            ctl = regs.get(MM.HR_CONTROL)
            if not (len(regs) == 1 and ctl is not None and ctl & MM.Control.STOP_ALL):
                raise ModbusRefusal(MM.ModbusException.DEVICE_BUSY, "homing in progress")
        # validate everything before changing anything
        new_targets: dict[int, int] = {}
        new_velocities: dict[int, int] = {}
        commands: dict[int, int] = {}
        self._refuse_invalid(MM.MODBUS_MAP["SAMPLE_SLOT"], regs.get(MM.HR_SAMPLE_SLOT))
        for a, ax in enumerate(self.axes):
            base = MM.axis_target_address(a)
            if base in regs or base + 1 in regs:
                hi0, lo0 = MM.int32_to_registers(ax.target)
                tgt = MM.registers_to_int32(regs.get(base, hi0), regs.get(base + 1, lo0))
                if base in regs and base + 1 in regs:
                    self._refuse_invalid(MM.MODBUS_MAP["TARGET"], tgt, a)
                new_targets[a] = tgt
            velocity_at = MM.axis_velocity_address(a)
            if velocity_at in regs:
                self._refuse_invalid(MM.MODBUS_MAP["VELOCITY"], regs[velocity_at], a)
                new_velocities[a] = regs[velocity_at]
            command_at = MM.axis_command_address(a)
            if command_at in regs:
                self._refuse_invalid(MM.MODBUS_MAP["COMMAND"], regs[command_at], a)
                commands[a] = regs[command_at]
        ctl = regs.get(MM.HR_CONTROL)
        self._refuse_invalid(MM.MODBUS_MAP["CONTROL"], ctl)
        # pre-check the commands with the new targets (so a refused write changes nothing)
        targets = [new_targets.get(a, ax.target) for a, ax in enumerate(self.axes)]
        enabled_after = bool(ctl & MM.Control.ENABLE) if ctl is not None else self.enabled
        for a, c in commands.items():
            ax = self.axes[a]
            if c in (MM.AxisCommand.MOVE, MM.AxisCommand.HOME):
                if not enabled_after:
                    raise ModbusRefusal(MM.ModbusException.ILLEGAL_VALUE, "drives disabled (CONTROL bit0)")
                if ax.fault:
                    raise ModbusRefusal(MM.ModbusException.DEVICE_FAILURE,
                                        f"axis {a} in fault {ax.fault}: reset first")
            if c == MM.AxisCommand.MOVE and ax.homed:
                self._refuse_invalid(MM.MODBUS_MAP["TARGET"], targets[a], a)
        if ctl is not None and ctl & MM.Control.HOME_ALL:
            if not enabled_after:
                raise ModbusRefusal(MM.ModbusException.ILLEGAL_VALUE, "drives disabled (CONTROL bit0)")
            if any(ax.fault for ax in self.axes) and not ctl & MM.Control.RESET_FAULT:
                raise ModbusRefusal(MM.ModbusException.DEVICE_FAILURE, "axis fault: reset first")
        # apply
        for a, tgt in new_targets.items():
            self.axes[a].target = tgt
        for a, v in new_velocities.items():
            self.axes[a].velocity = v
        if MM.HR_OWNER in regs or MM.HR_OWNER + 1 in regs:
            hi0, lo0 = MM.owner_to_registers(self.owner)
            self.owner = MM.registers_to_owner(regs.get(MM.HR_OWNER, hi0), regs.get(MM.HR_OWNER + 1, lo0))
        if MM.HR_SAMPLE_SLOT in regs:
            self.slot = regs[MM.HR_SAMPLE_SLOT]
            self._changed()
        if ctl is not None:
            self._control(ctl)
        for a, c in commands.items():
            self._command(a, c)

    @staticmethod
    def _refuse_invalid(row: MM.Register, value: int | None, axis: int | None = None) -> None:
        """Exception 3 for a written value the register's row refuses (None: not written)."""
        if value is not None and (why := row.refusal(value, axis)) is not None:
            raise ModbusRefusal(MM.ModbusException.ILLEGAL_VALUE, why)

    def _control(self, ctl: int) -> None:
        self.enabled = bool(ctl & MM.Control.ENABLE)
        if ctl & MM.Control.RESET_FAULT:
            for ax in self.axes:
                ax.fault = 0
        if ctl & MM.Control.STOP_ALL or not self.enabled:
            for ax in self.axes:
                self._stop(ax)
        if ctl & MM.Control.HOME_ALL:
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
        x1 = float(MM.HOME_POSITIONS_MDEG[ax.index])
        dur = HOMING_TIME_S * self.time_scale
        ax.homed = False
        ax.command = MM.AxisCommand.HOME
        ax.motion = (t, ax.position, x1, t + 0.8 * dur, t + dur, "home", None)

    def _command(self, a: int, c: int) -> None:
        ax = self.axes[a]
        ax.command = c
        if c == MM.AxisCommand.STOP:
            self._stop(ax)
        elif c == MM.AxisCommand.HOME:
            self._start_home(ax)
            self._changed()
        elif c == MM.AxisCommand.MOVE:
            self._move(ax)

    def _move(self, ax: AxisState) -> None:
        a = ax.index
        if not ax.homed:
            ax.fault = MM.AxisFault.NOT_HOMED
            log.info("axis %d: move refused, not homed (fault 3)", a)
            return
        dest = [other.destination() for other in self.axes]
        dest[a] = ax.target
        if G.beam_blocked(MM.mdeg_to_deg(dest[0]), MM.mdeg_to_deg(dest[1]), MM.mdeg_to_deg(dest[2])):
            ax.fault = MM.AxisFault.BEAM_BLOCK
            log.info("axis %d: move to %d mdeg refused, beam-block zone (fault 4)", a, ax.target)
            raise ModbusRefusal(MM.ModbusException.ILLEGAL_VALUE, "beam-block zone")
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
            raise ModbusRefusal(MM.ModbusException.DEVICE_BUSY, "homing in progress")
        for i, b in enumerate(bits):
            addr = address + i
            if addr == MM.COIL_LAMP:
                self.lamp_on = bool(b)
            elif addr == MM.COIL_SHUTTER:
                self.shutter_open = bool(b)
        self._changed()

    def coil_image(self) -> list[bool]:
        """The coils' values, by coil number."""
        img = self._image(MM.COIL)
        return [bool(img[k]) for k in range(MM.N_COILS)]


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
        self.drop_link: Callable[[], object] | None = None

    def device(self):
        """Build the ``pymodbus.simulator.SimDevice`` (non-shared blocks: c, d, h, i)."""
        from pymodbus.simulator import DataType, SimData, SimDevice

        coils = [SimData(0, values=[False] * 16, datatype=DataType.BITS)]
        discrete = [SimData(0, values=[False] * 16, datatype=DataType.BITS)]
        holding = [SimData(start, count=count, values=0, datatype=DataType.REGISTERS)
                   for start, count in MM.HOLDING_REGISTER_RANGES]
        inputs = [SimData(start, count=count, values=0, datatype=DataType.REGISTERS)
                  for start, count in MM.INPUT_REGISTER_RANGES]
        return SimDevice(id=LK.UNIT_ID, simdata=(coils, discrete, holding, inputs), action=self.action)

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
        """Pymodbus simulator action: runs on every request before pymodbus touches ``regs``."""
        from pymodbus.constants import ExcCodes
        from pymodbus.exceptions import NoSuchIdException

        if values is None and fc in _SINGLE_WRITES:
            # pymodbus answers a single write by reading the value back through this action
            # again: the same request, not a second fault opportunity (nor a second request)
            return self._execute(fc, start, address, count, regs, None)
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
                if address + count > MM.N_COILS:
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
