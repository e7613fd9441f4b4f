"""Dropped Modbus links and axis-fault recovery, with deterministic triggers.

Status polling while axes move or home takes a number of requests that depends on timing, so a
``modbus_drop=@N`` is only used where the request sequence up to N is fixed (the session start,
up to and including the first status poll of homing), and every such test asserts which request
the mock dropped. Drops of move commands are made by a transport wrapper that picks the request
by its content. Recovery from axis faults is checked against the mock's controller state.
"""

from __future__ import annotations

import logging

import pytest

from gonio import instrument as P
from gonio.instrument import AxisFaultError, MotionController, RetryPolicy
from gonio.instrument.transport import LinkLost, ModbusTransport
from gonio.mock import MockInstrument
from gonio.mock.motion import AxisState as MockAxis

SEED = 21

# the mock's Modbus fault opportunities at the start of a session, in order (fixed: no polling
# before): firmware, status, owner read and claim, lamp coil, sample slot, enable, HOME_ALL,
# first homing poll (the shutter is closed by the head, its owner, not by the coil). Every
# request is one opportunity, a coil write (fc 5) included (the dropped request is asserted
# below, so a change shows at once).
START = [(4, P.IR_FIRMWARE), (4, P.IR_STATUS), (3, P.HR_OWNER), (16, P.HR_OWNER),
         (5, P.COIL_LAMP), (16, P.HR_SAMPLE_SLOT), (16, P.HR_CONTROL), (16, P.HR_CONTROL),
         (4, P.axis_actual_address(0))]
ENABLE, HOME_ALL, HOMING_POLL = 7, 8, 9


def _plan(drv, tmp_path):
    return drv.write_plan(tmp_path, "drops", incidence=(0, 45), in_plane=(-30, 20, 50),
                          wavelengths=(450, 550, 650), readings=8)


def _clean_csv(drv, tmp_path) -> bytes:
    plan = _plan(drv, tmp_path)
    with MockInstrument(sample="lambert:0.5", speed="fast", seed=SEED) as mock:
        res = drv.run(mock, plan, tmp_path / "clean", timeout_s=1.0)
    assert res.status == "complete", res.message
    return (tmp_path / "clean" / "radiance.csv").read_bytes()


@pytest.mark.parametrize("n", [ENABLE, HOME_ALL, HOMING_POLL],
                         ids=["enable", "home-all", "homing-poll"])
@pytest.mark.parametrize("executed", [True, False], ids=["executed", "not-executed"])
def test_drop_at_session_start_and_during_homing(drv, tmp_path, caplog, n, executed):
    """A drop at the enable write, at HOME_ALL or at the first homing poll, executed or not:
    one reconnection, no other retry (an executed HOME_ALL is not sent again, so no busy
    refusal and no second homing), and the data of a clean session."""
    plan = _plan(drv, tmp_path)
    with caplog.at_level(logging.INFO, logger="gonio.instrument"), \
            MockInstrument(sample="lambert:0.5", speed="fast", seed=SEED,
                           faults=f"modbus_drop=@{n}") as mock:
        mock.frontend.drop_executed = executed
        res = drv.run(mock, plan, tmp_path / "run", timeout_s=1.0)
        dropped = mock.stats["modbus_dropped"]
    assert dropped == [START[n - 1] + (executed,)], dropped      # the intended request
    assert res.status == "complete", res.message
    assert res.retries == {"modbus_link_lost": 1}, res.retries
    resent_checked = [r.getMessage() for r in caplog.records
                      if "executed although unanswered" in r.getMessage()]
    if n == HOME_ALL:
        assert len(resent_checked) == (1 if executed else 0), resent_checked
        assert all("home all" in m for m in resent_checked)
    assert (tmp_path / "run" / "radiance.csv").read_bytes() == _clean_csv(drv, tmp_path)


class _ScriptedDrop:
    """Wraps a Modbus transport: the first request ``match(request)`` selects gets no answer (a
    dropped connection), after being passed to the controller (``executed``) or not;
    ``on_drop()`` runs at the drop (e.g. the controller reboots). ``sent`` lists every request
    that reached the controller."""

    def __init__(self, inner, match, executed: bool, on_drop=None):
        self.inner, self.match, self.executed, self.on_drop = inner, match, executed, on_drop
        self.channel, self.url, self.timeout_s = inner.channel, inner.url, inner.timeout_s
        self.fired = False
        self.sent: list[dict] = []

    def exchange(self, request):
        if not self.fired and self.match(request):
            self.fired = True
            if self.executed:
                self.sent.append(request)
                self.inner.exchange(request)
            self.inner.close()
            if self.on_drop is not None:
                self.on_drop()
            raise LinkLost("modbus", "connection closed by the peer (test)")
        self.sent.append(request)
        return self.inner.exchange(request)

    def reconnect(self):
        self.inner.reconnect()

    def close(self):
        self.inner.close()


def _is_move(axis):
    return lambda r: r["fn"] == "write_registers" and r["address"] == P.axis_target_address(axis)


@pytest.fixture
def mock():
    with MockInstrument(sample="lambert:0.5", speed="fast", seed=SEED) as m:
        m.links = []
        yield m
        for link in m.links:
            link.close()


def _motion(mock, match, executed, on_drop=None):
    link = _ScriptedDrop(ModbusTransport(mock.modbus_url, timeout_s=2.0), match, executed, on_drop)
    mock.links.append(link)
    retry = RetryPolicy(base_s=0.001)
    return MotionController(link, retry), link, retry


@pytest.mark.parametrize("executed", [True, False], ids=["executed", "not-executed"])
def test_dropped_move_resent_only_when_not_executed(mock, caplog, executed):
    motion, link, retry = _motion(mock, _is_move(1), executed)
    motion.home()
    with caplog.at_level(logging.INFO, logger="gonio.instrument"):
        motion.move_to((0, 30, 0, 0), 60)
    moves = [r for r in link.sent if _is_move(1)(r)]
    assert link.fired and len(moves) == 1          # executed: not re-sent; else: sent once more
    logged = any("executed although unanswered" in r.getMessage() for r in caplog.records)
    assert logged is executed
    assert retry.counts == {"modbus_link_lost": 1}
    assert mock.controller.positions_mdeg()[1] == 30000
    assert all(ax.fault == 0 for ax in mock.controller.axes)


def _power_cycle(controller):
    """The controller reboots: axes not homed, drives disabled, registers at power-on values."""
    def reboot():
        controller.axes[:] = [MockAxis(a, float(ax.position), target=int(round(ax.position)))
                              for a, ax in enumerate(controller.axes)]
        controller.enabled = False
    return reboot


def test_move_never_resent_to_an_axis_that_lost_its_homing(mock):
    """The link drops at a move and the controller comes back un-homed: the move is not sent
    (it would latch fault 3); not-homed is reported, and stop/reset/home/move recovers."""
    motion, link, retry = _motion(mock, _is_move(0), executed=False,
                                  on_drop=_power_cycle(mock.controller))
    motion.home()
    with pytest.raises(AxisFaultError) as err:
        motion.move_to((20, 45, 0, 0), 60)
    assert err.value.code == P.AxisFault.NOT_HOMED and err.value.axis == 0
    assert not [r for r in link.sent if _is_move(0)(r)]          # never sent to an un-homed axis
    assert all(ax.fault == 0 for ax in mock.controller.axes)     # nothing latched
    # the engine's recovery: every axis at rest, recoverable faults reset, home, move again
    assert motion.clear_faults("re-home") == []
    motion.home()
    motion.move_to((20, 45, 0, 0), 60)
    assert mock.controller.positions_mdeg()[0] == 20000
    assert retry.counts == {"modbus_link_lost": 1}


def test_fault_recovery_stops_every_axis_before_the_reset(mock):
    """Every move faults half way (axis_fault rate 1): the wait reports the first faulted axis
    while the others may still be moving; clear_faults stops them and waits at rest, so no
    fault appears after the reset and HOME_ALL is accepted."""
    mock.controller.faults = type(mock.faults)("axis_fault=1", seed=SEED)
    link = ModbusTransport(mock.modbus_url, timeout_s=2.0)
    mock.links.append(link)
    motion = MotionController(link, RetryPolicy(base_s=0.001))
    motion.home()
    with pytest.raises(AxisFaultError) as err:
        motion.move_to((40, -60, 90, 200), 60)
    assert err.value.code == P.AxisFault.FOLLOWING_ERROR
    faulted = motion.clear_faults("re-home")
    assert err.value.axis in faulted
    ctl = mock.controller
    assert all(ax.motion is None and ax.fault == 0 for ax in ctl.axes)
    assert not ctl.homing()
    mock.controller.faults = None
    motion.home()
    assert all(ax.homed and ax.fault == 0 for ax in ctl.axes)
    motion.move_to((40, -60, 90, 200), 60)
    assert ctl.positions_mdeg() == (40000, -60000, 90000, 200000)


def test_unrecoverable_fault_is_not_reset(mock):
    """A latched beam-block fault is never reset blindly: clear_faults raises and leaves it."""
    link = ModbusTransport(mock.modbus_url, timeout_s=2.0)
    mock.links.append(link)
    motion = MotionController(link, RetryPolicy(base_s=0.001))
    motion.home()
    mock.controller.axes[1].fault = int(P.AxisFault.BEAM_BLOCK)
    with pytest.raises(AxisFaultError) as err:
        motion.clear_faults("re-home")
    assert err.value.code == P.AxisFault.BEAM_BLOCK and err.value.axis == 1
    assert mock.controller.axes[1].fault == P.AxisFault.BEAM_BLOCK
