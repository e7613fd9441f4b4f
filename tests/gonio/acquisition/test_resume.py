"""Kill -9 and resume: the final dataset equals an uninterrupted run's; torn last line."""

from __future__ import annotations

import contextlib
import json
import logging
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from gonio.acquisition.journal import read_journal
from gonio.data import read_dataset
from gonio.mock import MockInstrument

SEED = 7


def _gonio(*args):
    return [sys.executable, "-m", "fabric_optics.cli.gonio", *map(str, args)]


@pytest.fixture
def mock_process():
    proc = subprocess.Popen(_gonio("mock", "--sample", "lambert:0.5", "--seed", SEED,
                                   "--serial", "pty"),
                            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    try:
        line = proc.stdout.readline()
        urls = json.loads(line)
        urls["pid"] = proc.pid
        yield urls
    finally:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(5)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        proc.stdout.close()


def _acquire(urls, plan, out, *extra):
    return _gonio("acquire", "--plan", plan, "--modbus", urls["modbus"], "--serial", urls["serial"],
                  "--out", out, "--seed", SEED, "--timeout", "0.3", "--no-progress", *extra)


def _points(out: Path):
    return [tuple(r["geometry"]) for r in read_journal(out / "journal.jsonl").of_type("point")]


@contextlib.contextmanager
def _instrument_frozen(pid: int):
    """SIGSTOP the mock process: the session cannot measure past the state just observed while
    the test signals it (at most the point whose last answer is already on the wire)."""
    os.kill(pid, signal.SIGSTOP)
    try:
        yield
    finally:
        os.kill(pid, signal.SIGCONT)


def _wait_for_points(proc, out: Path, n: int, deadline_s: float = 120.0) -> int:
    """Poll the journal (never a fixed sleep) until it holds ``n`` points or the run ends."""
    t_end = time.monotonic() + deadline_s
    while time.monotonic() < t_end and proc.poll() is None:
        if (out / "journal.jsonl").exists() and len(_points(out)) >= n:
            break
        time.sleep(0.01)
    return len(_points(out)) if (out / "journal.jsonl").exists() else 0


def test_sigkill_after_observed_points_then_resume_equals_uninterrupted(drv, tmp_path, mock_process):
    """Deterministic kills: each session is killed once the journal holds the next target count
    of points (the instrument frozen meanwhile), then the last --resume completes the run."""
    plan = drv.write_plan(tmp_path, "kill", incidence=(0, 30, 60), in_plane=(-50, -10, 20, 50),
                          wavelengths=(450, 500, 550, 600, 650), itime_ms=100, readings=50)
    ref = tmp_path / "ref"
    done = subprocess.run(_acquire(mock_process, plan, ref), capture_output=True, text=True, timeout=900)
    assert done.returncode == 0, done.stderr
    assert len(_points(ref)) == 12
    out = tmp_path / "killed"
    kills = []
    for k, target in enumerate((1, 4, 7, 10)):
        proc = subprocess.Popen(_acquire(mock_process, plan, out, *(["--resume"] if k else [])),
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        seen = _wait_for_points(proc, out, target)
        with _instrument_frozen(mock_process["pid"]):
            proc.send_signal(signal.SIGKILL)
            rc = proc.wait()
        kills.append((target, seen, rc, len(_points(out))))
        assert rc == -signal.SIGKILL and target <= seen < 12, kills
    final = subprocess.run(_acquire(mock_process, plan, out, "--resume"), capture_output=True,
                           text=True, timeout=900)
    assert final.returncode == 0, final.stderr
    points = _points(out)
    assert len(points) == len(set(points)) == 12, kills      # none lost, none duplicated
    assert (out / "radiance.csv").read_bytes() == (ref / "radiance.csv").read_bytes()
    assert read_dataset(out).meta["provenance"]["complete"] is True


@pytest.mark.slow
def test_sigkill_at_random_moments_then_resume_equals_uninterrupted(drv, tmp_path, mock_process):
    """Many kills at random moments (timing-dependent by design: `make test-slow`)."""
    plan = drv.write_plan(tmp_path, "kill", incidence=(0, 30, 60), in_plane=(-50, -10, 20, 50),
                          wavelengths=(450, 500, 550, 600, 650), itime_ms=100, readings=50)
    ref = tmp_path / "ref"
    t0 = time.monotonic()
    done = subprocess.run(_acquire(mock_process, plan, ref), capture_output=True, text=True, timeout=900)
    duration = time.monotonic() - t0
    assert done.returncode == 0, done.stderr
    n_total = len(_points(ref))
    assert n_total == 12

    rng = np.random.default_rng(2024)
    out = tmp_path / "killed"
    kills: list = []
    for k in range(20):
        args = _acquire(mock_process, plan, out, *(["--resume"] if k else []))
        proc = subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        delay = float(rng.uniform(0.4, max(1.0, duration)))
        try:
            proc.wait(delay)
        except subprocess.TimeoutExpired:
            proc.send_signal(signal.SIGKILL)
            proc.wait()
        kills.append((round(delay, 2), proc.returncode, len(_points(out)) if (out / "journal.jsonl").exists() else 0))
    final = subprocess.run(_acquire(mock_process, plan, out, "--resume"), capture_output=True,
                           text=True, timeout=900)
    assert final.returncode == 0, final.stderr
    print("duration", duration, "kills (delay, returncode, points journaled)", kills)
    assert any(rc == -signal.SIGKILL for _, rc, _ in kills), kills
    points = _points(out)
    assert len(points) == len(set(points)) == n_total, kills      # none lost, none duplicated
    assert (out / "radiance.csv").read_bytes() == (ref / "radiance.csv").read_bytes()
    meta = read_dataset(out).meta
    assert meta["provenance"]["complete"] is True
    assert meta["sample"] == read_dataset(ref).meta["sample"]


def test_torn_last_line_is_measured_again(drv, tmp_path):
    plan = drv.write_plan(tmp_path, "torn", incidence=(0, 45), in_plane=(-30, 20),
                          wavelengths=(450, 550), readings=8)
    with MockInstrument(sample="lambert:0.5", speed="fast", seed=SEED) as mock:
        ref, out = tmp_path / "ref", tmp_path / "run"
        assert drv.run(mock, plan, ref).exit_code == 0
        assert drv.run(mock, plan, out).exit_code == 0
        journal = out / "journal.jsonl"
        lines = journal.read_bytes().split(b"\n")
        last_point = max(i for i, ln in enumerate(lines) if b'"type":"point"' in ln)
        torn_geometry = tuple(json.loads(lines[last_point])["geometry"])
        # the crash happened while this point's line was being written
        journal.write_bytes(b"\n".join(lines[:last_point]) + b"\n" + lines[last_point][:37])
        assert read_journal(journal).torn
        (out / "radiance.csv").unlink()
        res = drv.run(mock, plan, out, resume=True)
        assert res.exit_code == 0
    content = read_journal(journal)
    events = [r for r in content.of_type("event") if r["what"] == "resume"]
    assert events and events[-1]["torn_last_line"] is True and events[-1]["points_done"] == 3
    assert _points(out).count(torn_geometry) == 1 and len(_points(out)) == 4
    reuse = [r for r in content.of_type("event") if r["what"] == "calibration_reused"]
    assert reuse, "a fresh calibration of the same plan and standard is reused"
    assert (out / "radiance.csv").read_bytes() == (ref / "radiance.csv").read_bytes()


def _clocked_run(mock, plan_path, out, now: float, resume: bool):
    """A session whose wall clock reads ``now`` (the engine's injected clock: no waiting)."""
    from gonio.acquisition.plan import load_plan
    from gonio.acquisition.session import run_session
    from gonio.instrument import RetryPolicy
    from gonio.instrument.transport import ModbusTransport, SerialTransport

    return run_session(load_plan(plan_path), ModbusTransport(mock.modbus_url, timeout_s=0.3),
                       SerialTransport(mock.serial_url, timeout_s=0.3), out, resume=resume,
                       progress=False, seed=mock.seed, retry=RetryPolicy(base_s=0.002),
                       clock=lambda: now)


@pytest.mark.parametrize("age_min,reused", [(29.0, True), (31.0, False)])
def test_stale_calibration_is_measured_again(drv, tmp_path, caplog, age_min, reused):
    """The calibration's age is the engine's clock at resume minus the journaled time: 29 min
    with a 30 min limit is reused, 31 min is measured again (and says why)."""
    plan = drv.write_plan(tmp_path, "stale", incidence=(0,), in_plane=(20, 40),
                          wavelengths=(500,), readings=8, extra="calibration_max_age_min = 30")
    t0 = 1.7e9
    with MockInstrument(sample="lambert:0.5", speed="fast", seed=SEED) as mock:
        out = tmp_path / "run"
        assert _clocked_run(mock, plan, out, t0, resume=False).exit_code == 0
        journal = out / "journal.jsonl"
        lines = journal.read_bytes().split(b"\n")
        last_point = max(i for i, ln in enumerate(lines) if b'"type":"point"' in ln)
        journal.write_bytes(b"\n".join(lines[:last_point]) + b"\n")
        with caplog.at_level(logging.INFO, logger="gonio"):
            assert _clocked_run(mock, plan, out, t0 + 60 * age_min, resume=True).exit_code == 0
    cals = read_journal(journal).of_type("calibration")
    points = read_journal(journal).of_type("point")
    if reused:
        assert [c["id"] for c in cals] == [0] and [p["calibration"] for p in points] == [0, 0]
        assert "calibration 0 reused from the journal" in caplog.text
    else:
        assert [c["id"] for c in cals] == [0, 1] and [p["calibration"] for p in points] == [0, 1]
        assert cals[1]["time"] == t0 + 60 * age_min
        assert "calibration measured again: it is 31 min old (limit 30 min)" in caplog.text


def test_resume_refuses_a_journal_of_another_plan(drv, tmp_path):
    from fabric_optics.cli.gonio import main
    p1 = drv.write_plan(tmp_path, "one", incidence=(0,), in_plane=(20,), wavelengths=(500,))
    p2 = drv.write_plan(tmp_path, "two", incidence=(0,), in_plane=(30,), wavelengths=(500,))
    with MockInstrument(sample="lambert:0.5", speed="fast", seed=SEED) as mock:
        out = tmp_path / "run"
        assert drv.run(mock, p1, out).exit_code == 0
        args = ["--modbus", mock.modbus_url, "--serial", mock.serial_url, "--out", str(out),
                "--no-progress"]
        assert main(["acquire", "--plan", str(p2), *args, "--resume"]) == 2
        assert main(["acquire", "--plan", str(p1), *args]) == 2          # journal there, no --resume
        assert main(["acquire", "--plan", str(p1), *args, "--resume"]) == 0   # nothing left: rewrites


def test_a_session_that_cannot_reach_the_head_leaves_a_resumable_journal(drv, tmp_path):
    from gonio.acquisition.plan import load_plan
    from gonio.acquisition.session import run_session
    from gonio.instrument import RetryPolicy
    from gonio.instrument.transport import ModbusTransport, SerialTransport

    plan = drv.write_plan(tmp_path, "dead", incidence=(0,), in_plane=(20,), wavelengths=(500,))
    out = tmp_path / "run"
    with MockInstrument(sample="lambert:0.5", speed="fast", seed=SEED) as mock:
        dead = SerialTransport(str(tmp_path / "no-such-tty"), timeout_s=0.05)
        # backoff capped at 2 ms (default 0.25 s): the dead link's 40 attempts per command, without the waits
        res = run_session(load_plan(plan), ModbusTransport(mock.modbus_url, timeout_s=0.2), dead,
                          out, progress=False, retry=RetryPolicy(base_s=0.001, max_s=0.002))
        assert res.status == "stopped" and res.points_measured == 0
        assert "photometer head" in res.message and res.dataset_path is None
        assert mock.controller.shutter_open is False
        res = drv.run(mock, plan, out, resume=True)
        assert res.status == "complete" and res.points_measured == 1
    assert read_dataset(out).meta["instrument"]["idn"].startswith("KIAM,GPS-1")


def test_retry_counts_of_a_killed_session_survive_the_resume(drv, tmp_path):
    """SIGKILL a faulted session after some points, resume: the meta's retries sum both sessions
    (the killed one's from its last checkpoint), not only the session that ended."""
    faults = "modbus_drop=0.05,busy=0.05"
    mock = subprocess.Popen(_gonio("mock", "--sample", "lambert:0.5", "--seed", SEED, "--serial",
                                   "pty", "--faults", faults),
                            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    try:
        urls = json.loads(mock.stdout.readline())
        plan = drv.write_plan(tmp_path, "killret", incidence=(0, 30, 60),
                              in_plane=(-50, -10, 20, 50), wavelengths=(450, 550, 650),
                              itime_ms=1000, readings=40)
        out = tmp_path / "run"
        proc = subprocess.Popen(_acquire(urls, plan, out), stdout=subprocess.DEVNULL,
                                stderr=subprocess.DEVNULL)
        t_end = time.monotonic() + 60
        while time.monotonic() < t_end and proc.poll() is None:
            if (out / "journal.jsonl").exists() and len(_points(out)) >= 3:
                break
            time.sleep(0.01)
        with _instrument_frozen(mock.pid):
            proc.send_signal(signal.SIGKILL)
            assert proc.wait() == -signal.SIGKILL, "the session ended before it could be killed"
        records = read_journal(out / "journal.jsonl").records
        assert not any(r.get("what") == "session_end" for r in records)
        killed = [r for r in records if r["type"] == "point"][-1]["retries"]
        assert sum(killed.values()) > 0, "no retry before the kill: raise the fault rates"
        final = subprocess.run(_acquire(urls, plan, out, "--resume"), capture_output=True,
                               text=True, timeout=900)
        assert final.returncode == 0, final.stderr
    finally:
        mock.send_signal(signal.SIGINT)
        try:
            mock.wait(5)
        except subprocess.TimeoutExpired:
            mock.kill()
            mock.wait()
        mock.stdout.close()
    records = read_journal(out / "journal.jsonl").records
    ends = [r for r in records if r.get("what") == "session_end"]
    assert len(ends) == 1
    expected = {k: killed.get(k, 0) + ends[0]["retries"].get(k, 0)
                for k in set(killed) | set(ends[0]["retries"])}
    prov = read_dataset(out).meta["provenance"]
    assert prov["retries"] == expected and prov["sessions"] == 2
    assert len(_points(out)) == len(set(_points(out))) == 12
