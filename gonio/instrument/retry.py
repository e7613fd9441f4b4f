"""One retry policy for both devices: an adaptive, bounded budget, per-link backoff, counted per kind.

Adaptive budget (a fixed number of attempts runs out on a noisy link that still works; the
mock's measured fault rates: docs/instrument.md, "Retries: an adaptive, bounded budget"):

- **Per link** (``"serial"``, ``"modbus"``) the policy keeps the outcomes of every attempt and
  estimates the link's fault rate ``p = (failures + 0.5) / (attempts + 10)`` (a prior of 5 %
  worth ten attempts, so a healthy link starts at the base budget). A command gets
  ``n = ceil(log(target_failure) / log(p))`` attempts (the number that leaves a chance below
  ``target_failure`` = 1e-6 that a command fails at that rate), never fewer than ``attempts``
  (6) and never more than ``max_attempts`` (40: a link failing more than ~70 % of the time is
  broken, not noisy). ``n`` is re-evaluated after each failure, so a burst raises it at once.
- **Backoff per link**: ``delay = min(base_s * factor**streak, max_s)``, ``streak`` the link's
  consecutive failures before this one (a success resets it): a flapping link backs off, the
  other link does not.
- **Per point**: :meth:`RetryPolicy.begin_point` (the engine calls it before every point) sets
  a budget of retries for the point, ``20 + ceil(4 E p / (1 - p))`` with ``E`` the attempts of
  the previous point and ``p`` the rate over both links, at most ``max_point_retries`` (2000):
  four times the failures expected at the observed rate, so a point of a noisy but working
  instrument always completes while a point that keeps failing stops the session safely
  (resumable) instead of retrying for ever.

Everything depends on the sequence of outcomes only, never on time, so a replay makes the same
decisions. ``delay_k = min(base_s * factor**k, max_s)`` (:meth:`RetryPolicy.delay`). A device describes
what a failure means with a :class:`Failure` (its counter kind, how to recover before the next
attempt, whether the request may have been executed, whether it is a "busy" answer worth waiting
out) and hands the attempt to :meth:`RetryPolicy.run`; the policy owns the loop, the counting and
the waiting, so the head and the motion controller retry in exactly one way. The counter
(``counts``, kinds :data:`RETRY_KINDS`) is shared by the devices of a session and ends up in the
run's meta (``provenance.retries``).

``sleep`` is injectable: a replay passes a no-op, so replaying never waits.
"""

from __future__ import annotations

import collections
import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TypeVar

from gonio.instrument.errors import DeviceError

__all__ = ["RETRY_KINDS", "Failure", "LinkStats", "RetryPolicy"]

log = logging.getLogger(__name__)

T = TypeVar("T")

#: Retry counter kinds (keys of the counter stored in a run's meta).
#: ``link_lost`` is the head's link, ``modbus_link_lost`` the motion controller's (a dropped
#: Modbus TCP connection, re-established by the transport's ``reconnect``).
#: ``checksum_mode_lost`` is not a line fault: a complete reply without ``*HH``, the head
#: answering in checksum-off mode after its link was reset (a consequence of a drop whose
#: checksum restore failed); the mode is restored and the command repeated.
RETRY_KINDS = ("serial_timeout", "serial_garbled", "serial_truncated", "serial_checksum",
               "head_busy", "lamp_unstable", "modbus_busy", "modbus_no_response", "link_lost",
               "axis_fault", "modbus_link_lost", "checksum_mode_lost")


@dataclass(frozen=True)
class Failure:
    """How a device classifies one failed attempt (returned by its classifier).

    Attributes
    ----------
    kind : the retry counter kind (:data:`RETRY_KINDS`).
    recover : run before the backoff (reconnect, resynchronise); None: nothing to do.
    unanswered : the request got no answer and may have been executed anyway (then the
        ``took_effect`` check of :meth:`RetryPolicy.run` is asked before sending it again).
    busy : the device answered "busy": waited out for up to ``busy_timeout_s`` of backoff without
        using up the attempts.
    """

    kind: str
    recover: Callable[[], None] | None = None
    unanswered: bool = False
    busy: bool = False


@dataclass
class LinkStats:
    """Outcomes of the attempts on one link (see the module's adaptive budget)."""

    attempts: int = 0
    failures: int = 0
    streak: int = 0

    def rate(self) -> float:
        """Estimated fault rate, with a prior of 5 % worth ten attempts."""
        return (self.failures + 0.5) / (self.attempts + 10)

    def record(self, ok: bool) -> None:
        """Count one attempt: a success resets the streak of failures, a failure extends it."""
        self.attempts += 1
        if ok:
            self.streak = 0
        else:
            self.failures += 1
            self.streak += 1


@dataclass
class RetryPolicy:
    """Adaptive bounded retries, per-link backoff, a per-point budget.

    ``sleep`` is injectable (replay: no wait). See the module docstring for the rules.
    """

    attempts: int = 6
    base_s: float = 0.005
    factor: float = 2.0
    max_s: float = 0.25
    sleep: Callable[[float], None] = time.sleep
    counts: collections.Counter = field(default_factory=collections.Counter)
    max_attempts: int = 40
    target_failure: float = 1e-6
    max_point_retries: int = 2000
    links: dict[str, LinkStats] = field(default_factory=dict)
    point_budget: int | None = None
    _point_start: int = field(default=0, init=False, repr=False)
    _point_attempts: int = field(default=0, init=False, repr=False)

    def delay(self, k: int) -> float:
        """Backoff before retry number ``k`` (0-based).

        Examples
        --------
        >>> [RetryPolicy().delay(k) for k in (0, 1, 10)]
        [0.005, 0.01, 0.25]
        """
        return min(self.base_s * self.factor**k, self.max_s)

    def link(self, name: str) -> LinkStats:
        """The outcome statistics of link ``name``."""
        return self.links.setdefault(name, LinkStats())

    def attempts_for(self, link: str) -> int:
        """Attempts a command on ``link`` gets at its observed fault rate (module docstring).

        Examples
        --------
        >>> p = RetryPolicy()
        >>> p.attempts_for("serial")                    # prior rate 5 %
        6
        >>> p.links["serial"] = LinkStats(attempts=1000, failures=470)
        >>> p.attempts_for("serial")                    # 47 %: 1e-6 needs 19 attempts
        19
        """
        p = min(self.link(link).rate(), 0.999)
        n = math.ceil(math.log(self.target_failure) / math.log(p))
        return max(self.attempts, min(self.max_attempts, n))

    def total(self) -> int:
        """Retries counted so far (every kind)."""
        return sum(self.counts.values())

    def begin_point(self) -> int:
        """Start a point's retry budget (module docstring); returns the budget."""
        attempts = sum(s.attempts for s in self.links.values())
        failures = sum(s.failures for s in self.links.values())
        previous = attempts - self._point_attempts
        self._point_attempts = attempts
        p = min((failures + 0.5) / (attempts + 10), 0.99)
        self.point_budget = min(self.max_point_retries,
                                20 + math.ceil(4 * max(previous, 50) * p / (1 - p)))
        self._point_start = self.total()
        return self.point_budget

    def count(self, kind: str) -> None:
        """Count one retry of ``kind``; :class:`DeviceError` when the point's budget is spent."""
        self.counts[kind] += 1
        if self.point_budget is not None and self.total() - self._point_start > self.point_budget:
            budget, self.point_budget = self.point_budget, None
            raise DeviceError("instrument", "retry budget of the point",
                              f"{budget} retries spent on one point (last: {kind}); the links "
                              "fail more than the observed fault rate allows",
                              transient=True)

    def run(self, attempt: Callable[[], T], classify: Callable[[Exception], Failure | None], *,
            device: str, what: str, took_effect: Callable[[], bool] | None = None,
            busy_timeout_s: float = 0.0, executed: T | None = None,
            exhausted: str | None = None, link: str | None = None) -> T:
        """Call ``attempt`` until it succeeds, retrying the failures ``classify`` accepts.

        Parameters
        ----------
        attempt : callable
            One try; its return value is returned.
        classify : callable
            Maps an exception of ``attempt`` to a :class:`Failure` (retry it) or None (not
            transient: re-raised at once; a classifier may also raise its own error).
        device, what : str
            Named in the :class:`DeviceError` raised when the attempts run out.
        took_effect : callable, optional
            Asked before re-sending after an unanswered attempt; True means the device executed the
            request anyway, and ``executed`` is returned without sending it again.
        busy_timeout_s : float
            Total backoff spent waiting out :attr:`Failure.busy` answers before they count against
            the attempts.
        executed : optional
            What is returned when ``took_effect`` says the request was executed.
        exhausted : str, optional
            The message when the attempts run out (default: "no valid response ...").
        link : str, optional
            The link whose statistics this command feeds and whose fault rate sets its attempts and
            backoff (None: the base ``attempts``, backoff by attempt number, no statistics - for a
            retry wrapped around other retried commands).

        Raises
        ------
        DeviceError
            ``transient=True``, after the attempts ran out.
        """
        stats = self.link(link) if link is not None else None
        last: Exception | None = None
        k = 0
        busy_waited = 0.0
        unanswered = False
        while k < (self.attempts_for(link) if link is not None else self.attempts):
            if unanswered and took_effect is not None and took_effect():
                log.info("%s: %s: executed although unanswered; not sent again", device, what)
                return executed  # type: ignore[return-value]
            try:
                out = attempt()
            except Exception as exc:
                failure = classify(exc)
                if failure is None:
                    raise
                last = exc
                delay = self.delay(stats.streak if stats is not None else k)
                if stats is not None:
                    stats.record(ok=False)
                self.count(failure.kind)
                unanswered = unanswered or failure.unanswered
                if failure.busy and delay > 0 and busy_waited + delay <= busy_timeout_s:
                    # busy (e.g. still homing after an earlier session): keep waiting, bounded
                    # by time rather than by attempts
                    busy_waited += delay
                    self.sleep(delay)
                    continue
                if failure.recover is not None:
                    failure.recover()
                self.sleep(delay)
                k += 1
                continue
            if stats is not None:
                stats.record(ok=True)
            return out
        raise DeviceError(device, what, exhausted or f"no valid response after {k} attempts "
                                                     f"(last: {last})", transient=True)
