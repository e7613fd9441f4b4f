"""One retry policy for both devices: bounded attempts, exponential backoff, counted per kind.

``delay_k = min(base_s * factor**k, max_s)`` before retry ``k`` (0-based). A device describes
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
import time
from dataclasses import dataclass, field
from typing import Callable, TypeVar

from gonio.instrument.errors import DeviceError

__all__ = ["RETRY_KINDS", "Failure", "RetryPolicy"]

log = logging.getLogger(__name__)

T = TypeVar("T")

#: Retry counter kinds (keys of the counter stored in a run's meta).
#: ``link_lost`` is the head's link, ``modbus_link_lost`` the motion controller's (a dropped
#: Modbus TCP connection, re-established by the transport's ``reconnect``).
RETRY_KINDS = ("serial_timeout", "serial_garbled", "serial_truncated", "serial_checksum",
               "head_busy", "lamp_unstable", "modbus_busy", "modbus_no_response", "link_lost",
               "axis_fault", "modbus_link_lost")


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
class RetryPolicy:
    """Bounded retries with exponential backoff; ``sleep`` is injectable (replay: no wait)."""

    attempts: int = 6
    base_s: float = 0.005
    factor: float = 2.0
    max_s: float = 0.25
    sleep: Callable[[float], None] = time.sleep
    counts: collections.Counter = field(default_factory=collections.Counter)

    def delay(self, k: int) -> float:
        """Backoff before retry number ``k`` (0-based).

        Examples
        --------
        >>> [RetryPolicy().delay(k) for k in (0, 1, 10)]
        [0.005, 0.01, 0.25]
        """
        return min(self.base_s * self.factor**k, self.max_s)

    def count(self, kind: str) -> None:
        """Count one retry of ``kind``."""
        self.counts[kind] += 1

    def run(self, attempt: Callable[[], T], classify: Callable[[Exception], Failure | None], *,
            device: str, what: str, took_effect: Callable[[], bool] | None = None,
            busy_timeout_s: float = 0.0, executed: T | None = None,
            exhausted: str | None = None) -> T:
        """Call ``attempt`` until it succeeds, retrying the failures ``classify`` accepts.

        Parameters
        ----------
        attempt : one try; its return value is returned.
        classify : maps an exception of ``attempt`` to a :class:`Failure` (retry it) or None
            (not transient: re-raised at once; a classifier may also raise its own error).
        device, what : named in the :class:`DeviceError` raised when the attempts run out.
        took_effect : asked before re-sending after an unanswered attempt; True means the device
            executed the request anyway, and ``executed`` is returned without sending it again.
        busy_timeout_s : total backoff spent waiting out :attr:`Failure.busy` answers before they
            count against the attempts.
        exhausted : the message when the attempts run out (default: "no valid response ...").

        Raises
        ------
        DeviceError : ``transient=True``, after :attr:`attempts` failed attempts.
        """
        last: Exception | None = None
        k = 0
        busy_waited = 0.0
        unanswered = False
        while k < self.attempts:
            if unanswered and took_effect is not None and took_effect():
                log.info("%s: %s: executed although unanswered; not sent again", device, what)
                return executed  # type: ignore[return-value]
            try:
                return attempt()
            except Exception as exc:
                failure = classify(exc)
                if failure is None:
                    raise
                last = exc
                self.count(failure.kind)
                unanswered = unanswered or failure.unanswered
                delay = self.delay(k)
                if failure.busy and busy_waited + delay <= busy_timeout_s:
                    # busy (e.g. still homing after an earlier session): keep waiting, bounded
                    # by time rather than by attempts
                    busy_waited += delay
                    self.sleep(delay)
                    k = min(k + 1, self.attempts - 2)
                    continue
                if failure.recover is not None:
                    failure.recover()
            self.sleep(self.delay(k))
            k += 1
        raise DeviceError(device, what, exhausted or f"no valid response after {self.attempts} "
                                                     f"attempts (last: {last})", transient=True)
