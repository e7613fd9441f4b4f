"""One acquisition session: the devices on two links, the engine and its subscribers, locked.

:func:`run_session` is what ``gonio acquire``, ``gonio demo`` and ``gonio replay`` run: it locks
the run directory (:class:`gonio.acquisition.rundir.RunDirLock`), optionally records both links
(:class:`gonio.acquisition.record.RecordingTransport`), builds the two devices over the links
with one shared :class:`~gonio.instrument.retry.RetryPolicy`, and runs the
:class:`~gonio.acquisition.engine.Engine` with its subscribers (the journal, the progress display,
the dataset writer). SIGTERM stops the run like Ctrl-C (exit status 130).
:func:`replay_session` runs the same driver against a recorded transcript.
"""

from __future__ import annotations

import contextlib
import dataclasses
import datetime as _dt
import secrets
import signal
import time
from collections.abc import Callable, Sequence
from pathlib import Path

from gonio.acquisition.engine import Engine, Interrupted, RunResult
from gonio.acquisition.plan import Plan
from gonio.acquisition.record import RecordingTransport, ReplayTransport, Transcript, TranscriptError, TranscriptWriter
from gonio.acquisition.rundir import RunDirLock, owned_by_run
from gonio.acquisition.subscribers import DatasetWriter, ProgressReporter, Subscriber
from gonio.data.outputs import check_output
from gonio.instrument import MotionController, PhotometerHead, RetryPolicy
from gonio.instrument.motion import DEFAULT_WAIT_TIMEOUT_S
from gonio.instrument.transport import LineTransport, RequestTransport

__all__ = ["run_session", "replay_session", "check_run_output", "ReplayClock"]


def _software() -> dict:
    from gonio.version import software
    return software()


def run_session(plan: Plan, modbus: RequestTransport, serial_link: LineTransport, out: Path, *,
                resume: bool = False, seed: int | None = None, record: Path | None = None,
                progress: bool | None = None, retry: RetryPolicy | None = None,
                created: str | None = None, clock: Callable[[], float] = time.time,
                owner_token: int | None = None, force: bool = False,
                writer: str = "gonio acquire", wait_timeout_s: float | None = None,
                subscribers: Sequence[Subscriber] = ()) -> RunResult:
    """Run one acquisition on two transports (live, recording or replaying).

    With ``record`` the transports are wrapped in
    :class:`~gonio.acquisition.record.RecordingTransport` writing to that file (a new file,
    never one of the run directory's own). The run directory is locked for the whole session.
    ``owner_token`` is the session's claim on the instrument (default: a new random token;
    replay passes the recorded one, 0 claims nothing). ``created`` stamps the dataset (default:
    the journal's start time). ``out`` must be writable by the rule of
    :func:`gonio.data.outputs.check_output` (checked once the lock is held; ``force`` and ``writer``
    are its arguments): a run folder only with ``resume``, a folder holding
    another dataset only with ``force``. ``wait_timeout_s`` bounds the wait for a move and for a
    controller that answers busy (:data:`gonio.instrument.motion.DEFAULT_WAIT_TIMEOUT_S`).
    ``subscribers`` receive every document after the journal, the progress display and the dataset
    writer (the live view, :class:`gonio.acquisition.live.LiveView`: the dataset is on disk when it
    gets ``stop``).
    """
    if record is not None and owned_by_run(out, record):
        raise TranscriptError(f"--record {record}: that is a file of the run directory {out}; "
                              "record the transcript elsewhere")
    check_run_output(out, writer=writer, force=force, resume=resume)
    lock = RunDirLock.acquire(out)
    try:
        # again under the lock: another session may have written there meanwhile
        check_output(out, "run", writer=writer, force=force, resume=resume)
        return _locked_session(plan, modbus, serial_link, out, resume=resume, seed=seed,
                               record=record, progress=progress, retry=retry, created=created,
                               clock=clock, owner_token=owner_token, wait_timeout_s=wait_timeout_s,
                               subscribers=subscribers)
    finally:
        lock.release()


def check_run_output(out: Path, *, writer: str, force: bool = False, resume: bool = False) -> None:
    """What :func:`run_session` checks first, for a command line to check before it opens any link.

    A run folder locked by another session (:class:`RunDirLocked`), then the output rule
    (:func:`gonio.data.outputs.check_output`).
    """
    if Path(out).is_dir():
        RunDirLock.acquire(out).release()
    check_output(out, "run", writer=writer, force=force, resume=resume)


def _locked_session(plan, modbus, serial_link, out, *, resume, seed, record, progress, retry,
                    created, clock, owner_token, wait_timeout_s, subscribers=()) -> RunResult:
    if owner_token is None:
        owner_token = secrets.randbelow(2**32 - 1) + 1
    writer = None
    if record is not None:
        created = created or _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds")
        writer = TranscriptWriter(record, {"created": created, "seed": seed,
                                           "modbus": modbus.url, "serial": serial_link.url,
                                           "plan": plan.name, "plan_sha256": plan.sha256,
                                           "owner_token": owner_token, "software": _software()})
        modbus = RecordingTransport(modbus, writer)
        serial_link = RecordingTransport(serial_link, writer)
    retry = retry or RetryPolicy()
    head = PhotometerHead(serial_link, retry)
    wait = DEFAULT_WAIT_TIMEOUT_S if wait_timeout_s is None else wait_timeout_s
    motion = MotionController(modbus, retry, poll_s=0.001 if retry.sleep is time.sleep else 0.0,
                              move_timeout_s=wait, busy_timeout_s=wait)
    engine = Engine(plan, head, motion, retry, out, resume=resume, seed=seed, clock=clock,
                    owner_token=owner_token)
    dataset = DatasetWriter(out, plan, engine.standard, seed=seed, created=created,
                            links={"modbus": modbus.url, "serial": serial_link.url})
    engine.subscribers += [ProgressReporter(plan.name, progress), dataset, *subscribers]
    previous = None
    try:
        previous = signal.signal(signal.SIGTERM, _raise_interrupted)
    except ValueError:      # not the main thread
        previous = None
    try:
        return dataclasses.replace(engine.run(), dataset_path=dataset.path)
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)
        if writer is not None:
            writer.close()
        for link in (modbus, serial_link):
            with contextlib.suppress(Exception):
                link.close()


def _raise_interrupted(signum, frame):
    raise Interrupted(f"signal {signum}")


class ReplayClock:
    """Wall clock of a replay: the recording's start, so journals carry no replay-time stamps."""

    def __init__(self, created: str | None):
        try:
            self.t = _dt.datetime.fromisoformat(created).timestamp() if created else 0.0
        except ValueError:
            self.t = 0.0

    def __call__(self) -> float:
        """The recording's start (seconds since the epoch), the same on every call."""
        return self.t


def replay_session(transcript: Transcript, plan: Plan, out: Path, *, force: bool = False) -> RunResult:
    """Run the driver with ``plan`` against ``transcript``, writing the dataset in ``out``.

    Raises :class:`~gonio.acquisition.record.ReplayMismatch` at the first request that differs
    from the recording (or when the driver stops before the transcript's end), and
    :class:`~gonio.acquisition.record.TranscriptError` when the transcript was recorded with
    another plan.
    """
    header = transcript.header
    if header.get("plan_sha256") not in (None, plan.sha256):
        raise TranscriptError(f"{transcript.name} was recorded with plan '{header.get('plan')}' "
                              f"(sha256 {str(header.get('plan_sha256'))[:12]}...), not with "
                              f"{plan.path} (plan '{plan.name}', sha256 {plan.sha256[:12]}...): "
                              "replay it with the plan file it was recorded with")
    result = run_session(plan, ReplayTransport(transcript, "modbus"), ReplayTransport(transcript, "serial"),
                         out, seed=header.get("seed"), progress=False,
                         retry=RetryPolicy(sleep=lambda s: None), created=header.get("created"),
                         clock=ReplayClock(header.get("created")),
                         owner_token=int(header.get("owner_token") or 0), force=force,
                         writer="gonio replay")
    transcript.finish()
    return result
