"""The driver benchmark (``gonio bench-driver``): driver overhead against the fast mock, and replay.

The driver's own time is the wall time minus the time spent waiting inside transport exchanges
(the device and the link) and in deliberate sleeps (polling, settling, backoff): parsing,
journaling (one fsync per point), dataset writing and bookkeeping. Each repeat runs the plan live
twice (once recording) and replays the recording (no device at all). Medians are reported:
these machines are noisy.
"""

from __future__ import annotations

import statistics
import tempfile
import time
from pathlib import Path
from typing import Any

from gonio.acquisition.plan import Plan
from gonio.acquisition.record import load_transcript
from gonio.acquisition.session import replay_session, run_session
from gonio.instrument import RetryPolicy
from gonio.instrument.transport import ModbusTransport, SerialTransport

__all__ = ["bench_driver"]


class _TimedLink:
    """Transport wrapper accumulating the time spent waiting in ``exchange``."""

    def __init__(self, inner):
        self.inner = inner
        self.channel, self.url = inner.channel, inner.url
        self.timeout_s = getattr(inner, "timeout_s", 1.0)
        self.waited = 0.0
        self.count = 0

    def exchange(self, request: Any, timeout_s: float | None = None) -> Any:
        kw = {} if timeout_s is None else {"timeout_s": timeout_s}
        t = time.perf_counter()
        try:
            return self.inner.exchange(request, **kw)
        finally:
            self.waited += time.perf_counter() - t
            self.count += 1

    def __getattr__(self, name):
        return getattr(self.inner, name)


def _bench_once(plan: Plan, out: Path, record: Path | None = None) -> dict:
    from gonio.mock import MockInstrument

    slept = [0.0]

    def sleep(s: float) -> None:
        t = time.perf_counter()
        time.sleep(s)
        slept[0] += time.perf_counter() - t

    with MockInstrument(sample="red-cotton", speed="fast", seed=0) as mock:
        modbus_url, serial_url = mock.urls()
        modbus = _TimedLink(ModbusTransport(modbus_url, timeout_s=1.0))
        serial_link = _TimedLink(SerialTransport(serial_url, timeout_s=1.0))
        t0 = time.perf_counter()
        result = run_session(plan, modbus, serial_link, out, seed=0, progress=False,
                             retry=RetryPolicy(sleep=sleep), record=record)
        wall = time.perf_counter() - t0
    rows = result.points_measured * len(plan.wavelengths_nm)
    driver = wall - modbus.waited - serial_link.waited - slept[0]
    return {"wall_s": wall, "in_exchanges_s": modbus.waited + serial_link.waited,
            "sleeping_s": slept[0], "driver_s": driver, "points": result.points_measured,
            "rows": rows, "exchanges": modbus.count + serial_link.count,
            "driver_ms_per_point": 1000 * driver / max(result.points_measured, 1),
            "driver_ms_per_row": 1000 * driver / max(rows, 1)}


def bench_driver(plan: Plan, repeats: int = 3) -> dict:
    """Run the benchmark; returns the report (a JSON-able dict of medians)."""
    runs, replays = [], []
    with tempfile.TemporaryDirectory() as tmp:
        for k in range(repeats):
            runs.append(_bench_once(plan, Path(tmp) / f"run{k}"))
            record = Path(tmp) / f"t{k}.jsonl"
            _bench_once(plan, Path(tmp) / f"rec{k}", record)
            t0 = time.perf_counter()
            result = replay_session(load_transcript(record), plan, Path(tmp) / f"replay{k}")
            replays.append(time.perf_counter() - t0)
            if result.exit_code != 0:
                raise RuntimeError("bench: the replay did not reproduce the run")

    def med(key):
        return statistics.median(r[key] for r in runs)

    rows = runs[0]["rows"]
    return {"plan": plan.name, "repeats": repeats, "points": runs[0]["points"], "rows": rows,
            "exchanges": runs[0]["exchanges"],
            "median_wall_s": med("wall_s"), "median_in_exchanges_s": med("in_exchanges_s"),
            "median_sleeping_s": med("sleeping_s"),
            "median_driver_ms_per_point": med("driver_ms_per_point"),
            "median_driver_ms_per_row": med("driver_ms_per_row"),
            "median_replay_s": statistics.median(replays),
            "replay_ms_per_row": 1000 * statistics.median(replays) / max(rows, 1),
            "target": "driver overhead <= 2 ms per point; demo plan <= 30 s"}
