"""The four-axis motion controller, declared over the register map.

The registers are attributes (descriptors of :mod:`gonio.instrument.registers`, one per row of
:data:`gonio.instrument.modbus_map.MODBUS_MAP`), and the methods use them: a register that
travels alone is read and written through its descriptor (``self.owner``, ``self.lamp``,
``type(self).control.write(...)`` where the context or an unanswered-write check is passed),
registers that travel together in one request through their declared group (an axis' inputs
``ACTUAL, AXIS_STATUS, FAULT``; a move's ``TARGET, VELOCITY, COMMAND``). Every write, either way,
is validated by its row of the map before it is sent
(:meth:`gonio.instrument.registers.ModbusDevice.write_rows`). Behaviour is a few methods:
:meth:`~MotionController.enable`, :meth:`~MotionController.home`,
:meth:`~MotionController.move_to` (waits for in-position), :meth:`~MotionController.stop`,
:meth:`~MotionController.clear_faults`, the owner claim and :meth:`~MotionController.shutdown`,
which always leaves the instrument safe.

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
client has written its own token, :class:`~gonio.instrument.errors.InstrumentTaken` stops the
session safely and what was measured since the last check is not kept. :meth:`shutdown` clears
the token if it is still ours.

Axis-fault recovery (:meth:`MotionController.clear_faults`): stop all, wait until no axis moves
(an axis still moving when another one faulted may fault after a reset), read every FAULT code,
reset only :data:`RECOVERABLE_FAULTS` (anything else raises: the engine stops safely), then home.
"""

from __future__ import annotations

import functools
import itertools
import logging
import time
from collections.abc import Callable
from dataclasses import dataclass

from gonio.data.geometry import beam_blocked
from gonio.instrument.errors import AxisFaultError, DeviceError, InstrumentTaken
from gonio.instrument.modbus_map import (
    HOME_POSITIONS_MDEG,
    IN_POSITION_TOLERANCE_MDEG,
    N_AXES,
    VELOCITY_RANGE_CDEG_S,
    AxisCommand,
    AxisFault,
    AxisStatus,
    Control,
    ControllerStatus,
    ModbusException,
    SampleSlot,
    deg_to_mdeg,
    mdeg_to_deg,
)
from gonio.instrument.registers import Coil, HoldingRegister, InputRegister, ModbusDevice
from gonio.instrument.retry import RetryPolicy
from gonio.instrument.transport import RequestTransport

__all__ = ["MotionController", "AxisState", "RECOVERABLE_FAULTS", "DEFAULT_WAIT_TIMEOUT_S"]

log = logging.getLogger(__name__)

#: Axis faults the driver may reset (CONTROL bit3) and recover from by re-homing: a following
#: error (transient) and "not homed" (a move that reached an axis which had lost its homing).
#: A beam-block fault (4) means the driver commanded a forbidden geometry: never reset blindly.
RECOVERABLE_FAULTS = (int(AxisFault.FOLLOWING_ERROR), int(AxisFault.NOT_HOMED))
_HOME_ATTEMPTS = 3
#: Longest wait for a move or homing to end (s), unless the move itself needs longer at its
#: velocity (then 1.5 times its travel time plus 5 s): a 180-degree travel at 20 deg/s takes 9 s.
#: Waiting longer means another client is driving the instrument (without claiming it: a claim
#: is noticed within ``owner_check_s``) or a drive is stuck.
DEFAULT_WAIT_TIMEOUT_S = 60.0
_AXIS_INPUTS = ("ACTUAL", "AXIS_STATUS", "FAULT")
_AXIS_MOVE = ("TARGET", "VELOCITY", "COMMAND")


@dataclass(frozen=True)
class AxisState:
    """Decoded axis input registers."""

    position_mdeg: int
    status: AxisStatus
    fault: int


class MotionController(ModbusDevice):
    """The four-axis motion controller (docs/instrument.md register map).

    Parameters
    ----------
    transport : the Modbus link (:class:`~gonio.instrument.transport.RequestTransport`).
    retry : shared :class:`~gonio.instrument.retry.RetryPolicy`.
    poll_s : status polling interval while waiting for motion.
    move_timeout_s : longest wait for the axes of one move (or homing) to come to rest in
        position (:data:`DEFAULT_WAIT_TIMEOUT_S`; ``gonio acquire --wait-timeout``).
    busy_timeout_s : longest backoff spent on exception 6 (busy) for one request (the same
        limit from the command line: a controller kept busy by another client).
    owner_check_s : while waiting for motion, the owner token is checked this often.
    """

    name = "motion controller"

    # the register map, one attribute per row (per-axis rows index by axis: target_mdeg[2])
    control, sample_slot, owner = HoldingRegister.rows("CONTROL", "SAMPLE_SLOT", "OWNER")
    target_mdeg, velocity_cdeg_s, axis_command = HoldingRegister.rows("TARGET", "VELOCITY", "COMMAND")
    controller_status, firmware_word = InputRegister.rows("STATUS", "FIRMWARE")
    actual_mdeg, axis_status, axis_fault = InputRegister.rows("ACTUAL", "AXIS_STATUS", "FAULT")
    lamp, shutter = Coil.rows("LAMP", "SHUTTER")

    def __init__(self, transport: RequestTransport, retry: RetryPolicy | None = None, *,
                 poll_s: float = 0.001, move_timeout_s: float | None = None,
                 busy_timeout_s: float = 30.0, owner_check_s: float = 1.0):
        super().__init__(transport, retry, busy_timeout_s=busy_timeout_s)
        self.poll_s = poll_s
        self.move_timeout_s = DEFAULT_WAIT_TIMEOUT_S if move_timeout_s is None else move_timeout_s
        self.owner_check_s = owner_check_s
        self.clock: Callable[[], float] = time.monotonic
        self._velocity_cdeg_s: list[int | None] = [None] * N_AXES
        self._target_mdeg: list[int | None] = [None] * N_AXES
        self.owner_token: int | None = None

    # --- status ---------------------------------------------------------------------------
    def firmware(self) -> str:
        """Firmware version, e.g. ``"1.4"``."""
        v = self.firmware_word
        return f"{v >> 8}.{v & 0xFF}"

    def status(self) -> ControllerStatus:
        """CONTROLLER STATUS bits."""
        return self.controller_status

    def check_safe_to_move(self) -> ControllerStatus:
        """Refuse to start when the interlock is open or the emergency stop is pressed."""
        st = self.status()
        if st & ControllerStatus.EMERGENCY_STOP:
            raise DeviceError(self.name, "read status", "emergency stop pressed: release it, "
                                                        "then start again")
        if st & ControllerStatus.INTERLOCK_OPEN:
            raise DeviceError(self.name, "read status", "safety interlock open: close the "
                                                        "enclosure, then start again")
        return st

    def axis(self, a: int) -> AxisState:
        """ACTUAL position, STATUS and FAULT of axis ``a``."""
        r = self.read_rows(_AXIS_INPUTS, a, f"read axis {a}")
        return AxisState(r["ACTUAL"], r["AXIS_STATUS"], r["FAULT"])

    def positions_deg(self) -> tuple[float, ...]:
        """Actual positions of every axis, degrees."""
        return tuple(mdeg_to_deg(self.axis(a).position_mdeg) for a in range(N_AXES))

    # --- commands -------------------------------------------------------------------------
    def _control(self, bits: Control, what: str, took_effect: Callable[[], bool] | None = None) -> None:
        type(self).control.write(self, int(bits), None, what, took_effect=took_effect)

    def enable(self) -> None:
        """Enable the drives."""
        self._control(Control.ENABLE, "enable drives")

    def reset_fault(self) -> None:
        """Clear every latched axis fault (drives stay enabled)."""
        self._control(Control.ENABLE | Control.RESET_FAULT, "reset fault")

    def stop(self) -> None:
        """Stop every axis (accepted even while homing)."""
        self._control(Control.ENABLE | Control.STOP_ALL, "stop all")

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
                self._control(Control.ENABLE | Control.HOME_ALL, "home all", took_effect=self._homing_taken)
                break
            except DeviceError as exc:
                if exc.code != ModbusException.DEVICE_FAILURE or k + 1 == _HOME_ATTEMPTS:
                    raise
                log.warning("motion controller: home all refused (an axis holds a fault); "
                            "clearing the faults")
                self.clear_faults("home all")
        self._target_mdeg = list(HOME_POSITIONS_MDEG)
        self._wait(range(N_AXES), "home all", homing=True)

    def _homing_taken(self) -> bool:
        """Whether the controller took an unanswered ``HOME_ALL``.

        True when every axis' COMMAND register holds HOME and the axis is homing (moving, not
        homed: a move needs a homed axis) or homed and at rest at its home position.
        """
        for a in range(N_AXES):
            cmd = type(self).axis_command.read(self, a, f"home all: re-read axis {a} command")
            if cmd != AxisCommand.HOME:
                return False
            st = self.axis(a)
            homing = bool(st.status & AxisStatus.MOVING) and not st.status & AxisStatus.HOMED
            homed = (bool(st.status & AxisStatus.HOMED) and not st.status & AxisStatus.MOVING
                     and abs(st.position_mdeg - HOME_POSITIONS_MDEG[a]) <= IN_POSITION_TOLERANCE_MDEG)
            if not (homing or homed):
                return False
        return True

    def clear_faults(self, what: str) -> list[int]:
        """Bring every axis to rest and reset the latched faults that can be cleared safely.

        Drives are stopped first (``STOP_ALL``) and the axes polled until none is moving: an
        axis still moving when another faulted could latch its own fault after the reset.
        Then every axis' FAULT code is read; following error and not homed
        (:data:`RECOVERABLE_FAULTS`) are reset (CONTROL bit3), any other latched fault raises
        :class:`~gonio.instrument.errors.AxisFaultError` (the engine stops safely). Returns the
        faulted axes.
        """
        self.stop()
        deadline = self.clock() + self.move_timeout_s
        while True:
            states = [self.axis(a) for a in range(N_AXES)]
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
        type(self).lamp.write(self, on, None, "lamp " + ("on" if on else "off"))

    def shutter_is_open(self, what: str = "read shutter") -> bool:
        """The shutter coil (the same shutter as the head's ``SHUTTER``)."""
        return type(self).shutter.read(self, None, what)

    def set_shutter(self, open_: bool) -> None:
        """Shutter coil (the same shutter as the head's SHUTTER command).

        One owner of the shutter: the photometer head (its ``SHUTTER`` command, part of each
        measurement unit). A session reads this coil only as a witness (a shutter closed under a
        point by another client) and writes it only as the fallback of a safe stop whose head
        link failed (:meth:`gonio.acquisition.engine.Engine.run`).
        """
        type(self).shutter.write(self, open_, None, "shutter " + ("open" if open_ else "close"))

    def _read_owner(self, what: str) -> int:
        return type(self).owner.read(self, None, what)

    def claim(self, token: int) -> None:
        """Write our owner token into the OWNER registers.

        A token already there (another client's, or a killed session's) is taken over and
        logged: the other client notices at its next :meth:`check_owner` and stops.
        """
        found = self._read_owner("read owner")
        if found not in (0, token):
            log.warning("motion controller: the instrument was claimed by another client (owner "
                        "token %#010x); taking it over (a session still running there stops)",
                        found)
        type(self).owner.write(self, token, None, "claim")
        self.owner_token = token

    def check_owner(self, what: str) -> None:
        """Raise :class:`~gonio.instrument.errors.InstrumentTaken` unless OWNER holds our token."""
        if self.owner_token is None:
            return
        found = self._read_owner(f"{what}: check owner")
        if found != self.owner_token:
            raise InstrumentTaken(self.owner_token, found, what)

    def release(self) -> None:
        """Clear the OWNER registers if they still hold our token (best effort, never raises)."""
        token, self.owner_token = self.owner_token, None
        if token is None:
            return
        try:
            if self._read_owner("read owner") == token:
                type(self).owner.write(self, 0, None, "release")
        except Exception as exc:  # noqa: BLE001 - part of shutdown, must not raise
            log.warning("motion controller: releasing the instrument failed: %s", exc)

    def set_slot(self, slot: SampleSlot) -> None:
        """Put the sample or the white reference standard in the beam (sample changer)."""
        type(self).sample_slot.write(self, int(slot), None, f"slot {SampleSlot(slot).name.lower()}")

    def move_to(self, axes_deg, velocity_deg_s: float) -> None:
        """Move the axes to ``axes_deg`` (4 values, degrees) and wait until in position.

        Only axes whose target changed are commanded (one write per axis: target, velocity,
        move command). Raises :class:`~gonio.instrument.errors.AxisFaultError` when an axis
        faults.
        """
        v = int(round(velocity_deg_s * 100))
        v = min(max(v, VELOCITY_RANGE_CDEG_S[0]), VELOCITY_RANGE_CDEG_S[1])
        moving = []
        what = "move to (" + ", ".join(f"{x:g}" for x in axes_deg) + ")"
        targets = [deg_to_mdeg(d) for d in axes_deg]
        changed = [a for a in range(N_AXES)
                   if targets[a] != self._target_mdeg[a] or v != self._velocity_cdeg_s[a]]
        # travel (deg) of the longest commanded axis; an unknown start counts a full turn
        starts = [self._target_mdeg[a] for a in changed]
        travel = max((abs(targets[a] - start) / 1000.0 if start is not None else 360.0
                      for a, start in zip(changed, starts, strict=True)), default=0.0)
        for a in self._safe_order(changed, targets, what):
            mdeg = targets[a]
            try:
                self.write_rows(dict(zip(_AXIS_MOVE, (mdeg, v, AxisCommand.MOVE), strict=True)), a,
                                f"{what}: axis {a}",
                                took_effect=functools.partial(self._move_taken, a, mdeg, v, what))
            except DeviceError as exc:
                if exc.code != ModbusException.DEVICE_FAILURE:
                    raise
                # exception 4: the axis holds a latched fault; report it with its code
                self._target_mdeg[a] = None
                raise AxisFaultError(a, self.axis(a).fault, what) from None
            self._target_mdeg[a] = mdeg
            self._velocity_cdeg_s[a] = v
            moving.append(a)
        self._wait(moving, what, travel_s=travel / (v / 100.0))

    def _move_taken(self, a: int, mdeg: int, velocity: int, what: str) -> bool:
        """Whether the controller took the move of axis ``a`` to ``mdeg`` (an unanswered write).

        True when its TARGET, VELOCITY and COMMAND registers hold this move and the axis is
        moving, in position at the target, or faulted (the wait then reports the fault). An
        axis that is neither homed nor moving (the controller lost its homing) is never sent a
        move: :class:`~gonio.instrument.errors.AxisFaultError` with code 3 (not homed) is raised
        instead, so the engine re-homes.
        """
        hr = self.read_rows(_AXIS_MOVE, a, f"{what}: re-read axis {a}")
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
        if hr["TARGET"] != mdeg or hr["VELOCITY"] != velocity or hr["COMMAND"] != AxisCommand.MOVE:
            return False
        if st.fault or st.status & AxisStatus.FAULT or st.status & AxisStatus.MOVING:
            return True
        return (bool(st.status & AxisStatus.IN_POSITION)
                and abs(st.position_mdeg - mdeg) <= IN_POSITION_TOLERANCE_MDEG)

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
                if beam_blocked(*(mdeg_to_deg(d) for d in dest[:3])):
                    ok = False
                    break
            if ok:
                return list(order)
        raise DeviceError(self.name, what, "destination is in the beam-block zone (the detector "
                                           "would be within 5 deg of the source direction)",
                          int(AxisFault.BEAM_BLOCK))

    def _wait(self, axes, what: str, homing: bool = False, travel_s: float = 0.0) -> None:
        """Poll until ``axes`` are at rest in position (homed, with ``homing``).

        Bounded: the owner token is checked every :attr:`owner_check_s` of :attr:`clock` time
        (another client that takes the instrument mid-move stops the session at once:
        :class:`~gonio.instrument.errors.InstrumentTaken`), and the wait ends after
        :attr:`move_timeout_s` (``gonio acquire --wait-timeout``), or 1.5 ``travel_s`` + 5 s
        when the move needs longer, with a :class:`~gonio.instrument.errors.DeviceError` that
        says so.
        """
        start = self.clock()
        limit = max(self.move_timeout_s, 1.5 * travel_s + 5.0)
        deadline = start + limit
        next_owner_check = start + self.owner_check_s
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
                now = self.clock()
                if now >= next_owner_check:
                    self.check_owner(what)
                    next_owner_check = now + self.owner_check_s
                if now > deadline:
                    raise DeviceError(self.name, what, f"axes {pending} not at rest in position "
                                                       f"after {limit:g} s (the wait "
                                                       "limit, --wait-timeout): another client "
                                                       "may be moving the instrument, or a drive "
                                                       "is stuck")
                self.retry.sleep(self.poll_s)

    def forget_targets(self) -> None:
        """Forget the commanded targets (after a fault or re-homing, every axis is re-sent)."""
        self._target_mdeg = [None] * N_AXES
        self._velocity_cdeg_s = [None] * N_AXES

    def shutdown(self) -> None:
        """Leave the drives safe: stopped, and the claim released (best effort, never raises).

        The shutter is not the controller's to close: the photometer head owns it (see
        :meth:`set_shutter`).
        """
        try:
            self.stop()
        except Exception as exc:  # noqa: BLE001 - shutdown must not raise
            log.warning("motion controller: stopping the drives failed: %s", exc)
        self.release()
