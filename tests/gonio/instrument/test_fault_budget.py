"""The adaptive retry budget: a session with every fault kind of the mock at 0.1
completes; the retry counters equal the faults injected, kind by kind; a move's wait is bounded
(injected clock) and a takeover during it is noticed at once."""

from __future__ import annotations

import pytest

from gonio.data import read_dataset
from gonio.instrument import RetryPolicy
from gonio.instrument.errors import DeviceError, InstrumentTaken
from gonio.instrument.modbus_map import HOLDING, INPUT, MODBUS_MAP, AxisStatus
from gonio.instrument.motion import MotionController
from gonio.instrument.retry import Failure, LinkStats
from gonio.mock import MockInstrument
from gonio.mock.faults import FAULT_KINDS

SEED = 1
#: mock fault kind -> the driver's retry counter (a drop of the head's socket link is a lost
#: link; on a pseudo-terminal it is silence, see test_faults.MATRIX)
COUNTER = {"drop": "link_lost", "serial_timeout": "serial_timeout", "busy": "head_busy",
           "garbled": "serial_garbled", "truncated": "serial_truncated",
           "checksum": "serial_checksum", "lamp": "lamp_unstable", "modbus_busy": "modbus_busy",
           "modbus_noresponse": "modbus_no_response", "axis_fault": "axis_fault",
           "modbus_drop": "modbus_link_lost"}
#: kinds whose fault is a silence: a reply late beyond the link timeout on a loaded machine
#: looks the same, so these can only be counted at least as often as injected
SILENT = ("serial_timeout", "modbus_noresponse")


def _plan(drv, tmp_path, wavelengths=(450, 650)):
    return drv.write_plan(tmp_path, "budget", incidence=(0, 45), in_plane=(-30, 50),
                          wavelengths=wavelengths, readings=4)


def _run(drv, tmp_path, spec, name, timeout_s, wavelengths=(450, 650)):
    plan = _plan(drv, tmp_path, wavelengths)
    with MockInstrument(sample="lambert:0.5", serial="socket", speed="fast", seed=SEED,
                        faults=spec) as mock:
        res = drv.run(mock, plan, tmp_path / name, timeout_s=timeout_s)
        injected = dict(mock.stats["faults"])
    return res, injected


def test_every_fault_kind_at_0_1_completes_with_the_clean_data(drv, tmp_path):
    """About 47 % of the head's exchanges fail: six attempts per command ran out before the
    adaptive budget; now the run completes and its numbers equal a clean run's."""
    clean, _ = _run(drv, tmp_path, None, "clean", 0.2, (550,))
    assert clean.exit_code == 0
    spec = ",".join(f"{k}=0.1" for k in FAULT_KINDS)
    res, injected = _run(drv, tmp_path, spec, "faulted", 0.2, (550,))
    assert res.status == "complete", res.message
    assert len([k for k, n in injected.items() if n]) >= 9, injected
    for kind, n in injected.items():
        counted = res.retries.get(COUNTER[kind], 0)
        if kind in SILENT:
            assert counted >= n, (kind, counted, n)
        else:
            assert counted == n, (kind, counted, n)
    assert ((tmp_path / "faulted" / "radiance.csv").read_bytes()
            == (tmp_path / "clean" / "radiance.csv").read_bytes())
    ds = read_dataset(tmp_path / "faulted")
    assert ds.meta["provenance"]["retries"] == res.retries


def test_retry_counters_equal_the_faults_injected_per_kind(drv, tmp_path):
    """Every kind that is not a silence, at 0.1 at once, each counted exactly once per fault
    (an axis fault per faulted axis, busy as busy even when the head's checksum mode was reset,
    a lamp flag only when the reply reached the driver)."""
    spec = ",".join(f"{k}=0.1" for k in FAULT_KINDS if k not in SILENT + ("truncated",))
    res, injected = _run(drv, tmp_path, spec, "run", 2.0)
    assert res.status == "complete", res.message
    assert sum(injected.values()) > 40
    assert {COUNTER[k]: n for k, n in injected.items() if n} == {
        k: n for k, n in res.retries.items() if k != "checksum_mode_lost"}


def test_attempts_grow_with_the_observed_fault_rate_and_are_bounded():
    policy = RetryPolicy()
    assert policy.attempts_for("serial") == 6
    policy.links["serial"] = LinkStats(attempts=1000, failures=470)
    assert policy.attempts_for("serial") == 19           # 0.47 ** 19 < 1e-6 < 0.47 ** 18
    assert 0.47 ** 19 < 1e-6 < 0.47 ** 18
    policy.links["serial"] = LinkStats(attempts=1000, failures=990)
    assert policy.attempts_for("serial") == 40           # bounded
    assert policy.attempts_for("modbus") == 6            # the other link is unaffected


def _failing(n_failures: int, kind: str = "serial_garbled"):
    calls = [0]

    def attempt():
        calls[0] += 1
        if calls[0] <= n_failures:
            raise ValueError("bad line")
        return "ok"

    return attempt, (lambda exc: Failure(kind) if isinstance(exc, ValueError) else None), calls


def test_a_burst_on_one_link_gets_more_attempts_and_backs_off_on_that_link_only():
    slept: list[float] = []
    policy = RetryPolicy(sleep=slept.append)
    attempt, classify, calls = _failing(10)
    # ten failures in a row: beyond the base six attempts, granted as the rate estimate rises
    assert policy.run(attempt, classify, device="d", what="w", link="serial") == "ok"
    assert calls[0] == 11 and policy.counts["serial_garbled"] == 10
    assert slept == [min(0.005 * 2 ** k, 0.25) for k in range(10)]
    slept.clear()
    attempt, classify, _ = _failing(1, "modbus_busy")
    policy.run(attempt, classify, device="d", what="w", link="modbus")
    assert slept == [0.005]                                 # a fresh link starts at the base
    # without a link (a wrapper around retried commands): the base budget, no statistics
    attempt, classify, _ = _failing(10)
    with pytest.raises(DeviceError, match="after 6 attempts"):
        RetryPolicy(sleep=lambda s: None).run(attempt, classify, device="d", what="w")


def test_the_point_budget_stops_a_point_that_keeps_failing():
    policy = RetryPolicy(sleep=lambda s: None)
    budget = policy.begin_point()
    assert budget == 20 + -(-4 * 50 * 0.05 // 0.95)        # prior rate 5 %, 50 attempts
    with pytest.raises(DeviceError, match=f"{budget} retries spent on one point"):
        for _ in range(budget + 1):
            policy.count("serial_garbled")
    # a new point starts a new budget
    policy.begin_point()
    policy.count("serial_garbled")


class _StuckController:
    """A Modbus transport whose axes never arrive (moving forever); OWNER settable."""

    def __init__(self):
        self.owner = 7
        self.channel, self.url = "modbus", "fake://stuck"
        self.words: dict[tuple[str, int], int] = {}
        for a in range(4):
            self._put(INPUT, "AXIS_STATUS", a, int(AxisStatus.HOMED | AxisStatus.MOVING))
            self._put(INPUT, "ACTUAL", a, 0)
            self._put(INPUT, "FAULT", a, 0)

    def _put(self, table, name, axis, value):
        reg = MODBUS_MAP[name]
        for k, w in enumerate(reg.encode(value)):
            self.words[(table, reg.address_of(axis) + k)] = w

    def exchange(self, request, timeout_s=None):
        fn = request["fn"]
        if fn in ("write_registers", "write_coil"):
            return {}
        table = INPUT if fn == "read_input_registers" else HOLDING
        self._put(HOLDING, "OWNER", None, self.owner)
        return {"registers": [self.words.get((table, request["address"] + k), 0)
                              for k in range(request["count"])]}

    def reconnect(self):
        pass

    def close(self):
        pass


def _stuck_motion(link):
    now = [0.0]
    retry = RetryPolicy(sleep=lambda s: now.__setitem__(0, now[0] + s))
    motion = MotionController(link, retry, poll_s=0.05, move_timeout_s=30.0)
    motion.clock = lambda: now[0]
    motion.owner_token = 7
    return motion, now


def test_a_move_that_never_arrives_ends_at_the_wait_limit():
    motion, now = _stuck_motion(_StuckController())
    motion._target_mdeg = [0, 0, 0, 0]
    with pytest.raises(DeviceError, match=r"not at rest in position after 30 s .*--wait-timeout"):
        motion.move_to((10, 20, 0, 0), 20.0)                # 20 deg at 20 deg/s: 1 s of travel
    assert 30.0 < now[0] < 30.2
    # a slow move is given the time it needs: 160 deg at 1 deg/s, 1.5 x 160 s + 5 s
    motion, now = _stuck_motion(_StuckController())
    motion._target_mdeg = [0, -80000, 0, 0]
    with pytest.raises(DeviceError, match="after 245 s"):
        motion.move_to((0, 80, 0, 0), 1.0)
    assert 245.0 < now[0] < 245.2


def test_every_write_is_validated_by_its_register_row_before_it_is_sent():
    """One validation path: a descriptor's write and a group's (a move) alike."""
    link = _StuckController()
    sent = []
    link_exchange = link.exchange
    link.exchange = lambda request, timeout_s=None: sent.append(request) or link_exchange(request)
    motion, _ = _stuck_motion(link)
    motion._target_mdeg, motion._velocity_cdeg_s = [0] * 4, [1000] * 4   # only axis 1 moves
    with pytest.raises(DeviceError, match="TARGET: 180000 mdeg outside the soft limits"):
        motion.move_to((0, 180, 0, 0), 10.0)
    with pytest.raises(DeviceError, match="SAMPLE_SLOT"):
        motion.sample_slot = 7
    with pytest.raises(DeviceError, match="VELOCITY"):
        motion.velocity_cdeg_s[0] = 0
    assert sent == []


def test_a_takeover_during_a_move_is_noticed_within_a_second():
    link = _StuckController()
    motion, now = _stuck_motion(link)
    motion._target_mdeg = [0, 0, 0, 0]
    link.owner = 0xBEEF                         # another client claims the instrument
    with pytest.raises(InstrumentTaken):
        motion.move_to((10, 20, 0, 0), 20.0)
    assert 1.0 <= now[0] < 1.1
