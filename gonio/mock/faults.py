r"""Fault injection for the mock instrument (``gonio mock --faults SPEC``).

Syntax
------
``SPEC`` is a comma-separated list of ``kind=RATE`` or ``kind=@N`` items, e.g.
``garbled=0.05,busy=@3,axis_fault=@2``:

- ``kind=RATE`` (``0 <= RATE <= 1``): the fault fires at each opportunity with probability RATE;
- ``kind=@N`` (``N >= 1``): the fault fires once, at the N-th opportunity of that kind.

Each kind has its own opportunity counter and its own random stream (Philox keyed by
``(seed, kind)``); one uniform number is drawn per opportunity whether or not it fires, so the
decisions depend only on the seed and the sequence of requests - never on timing.

Kinds and their opportunities
-----------------------------
Head (one opportunity per command line received; a line hit by several kinds gets the first in
this order: drop, serial_timeout, busy, garbled, truncated, checksum):

``serial_timeout``  no answer at all; the command is not executed.
``busy``            ``ERR 103,Busy`` (queued for SYST:ERR?); the command is not executed.
``garbled``         the command is executed but bytes 0x80..0xFF (never valid ASCII) replace part
                    of the reply; the ``\r\n`` terminator is kept.
``truncated``       the reply is cut and sent without its terminator.
``checksum``        the reply carries a wrong ``*HH`` (one opportunity per reply sent in checksum
                    mode that no other fault hit, the reply to ``CHK ON`` included).
``drop``            the link drops: no answer; on a socket the client connection is closed, on a
                    pseudo-terminal the head ignores input for a short re-initialisation time.
                    Either way the head's link settings revert (CHK OFF, error queue cleared);
                    measurement settings are kept. The driver reconnects and re-sends CHK ON.
``lamp``            (one opportunity per ``READ?`` with the shutter open that returns a reading,
                    whatever else happens to the reply) the readings are perturbed and the reply
                    is flagged lamp unstable (flags bit1). Dark readings are never affected.
                    Counted in ``stats`` only when no other fault hit the reply (a garbled,
                    truncated or bad-checksum reply hides the flag from the driver).

Motion controller (one opportunity per Modbus request for the three request kinds; a request
hit by several kinds gets the first in this order: modbus_drop, modbus_noresponse, modbus_busy):

``modbus_busy``        answered with exception 6 (device busy); not executed.
``modbus_noresponse``  the request is dropped without an answer; not executed.
``modbus_drop``        the link drops at this request, which gets no answer.
                       Modbus TCP: the server closes the client's connection (the transport of
                       the connection that carried the request; the client reads EOF) - after
                       executing the request or before, one draw of the kind's own stream
                       (probability 1/2 each), so a driver can never assume that an unanswered
                       write did, or did not, take effect. New connections are accepted at once.
                       Modbus RTU (a serial line has no connection to close): the equivalent of
                       a controller whose serial interface re-initialises - the request is not
                       executed and every request arriving in the next
                       :data:`gonio.mock.motion.LINK_SILENCE_S` (times the speed factor) is
                       ignored without an answer; those ignored requests are no opportunities
                       (they never reach the controller), so the decisions still depend only on
                       the sequence of requests the controller sees.
``axis_fault``         (one opportunity per accepted move command) the axis stops half way
                       with fault 1 (following error); CONTROL bit3 resets it.

Faults never corrupt a reading reported as good (:class:`FaultInjector`).
"""

from __future__ import annotations

import re
from collections import Counter
from dataclasses import dataclass

import numpy as np

__all__ = ["FAULT_KINDS", "HEAD_FAULT_ORDER", "MODBUS_FAULT_ORDER", "FaultRule", "FaultSpecError",
           "parse_faults", "FaultInjector"]

HEAD_FAULT_ORDER = ("drop", "serial_timeout", "busy", "garbled", "truncated", "checksum")
# the index of a kind keys its random stream: new kinds are appended, never inserted
FAULT_KINDS = HEAD_FAULT_ORDER + ("lamp", "modbus_busy", "modbus_noresponse", "axis_fault",
                                  "modbus_drop")
MODBUS_FAULT_ORDER = ("modbus_drop", "modbus_noresponse", "modbus_busy")
_FAULT_DOMAIN = 0x6661756C


class FaultSpecError(ValueError):
    """A malformed ``--faults`` specification (a user error)."""


@dataclass(frozen=True)
class FaultRule:
    """One fault kind: fires with probability ``rate``, or once at opportunity ``at`` (1-based)."""

    kind: str
    rate: float | None = None
    at: int | None = None

    def __str__(self) -> str:
        return f"{self.kind}=@{self.at}" if self.at is not None else f"{self.kind}={self.rate:g}"


_ITEM = re.compile(r"([a-z_]+)=(@\d+|[0-9]*\.?[0-9]+(?:[eE][+-]?\d+)?)")


def parse_faults(spec: str | None) -> dict[str, FaultRule]:
    """Parse a ``--faults`` SPEC into ``{kind: FaultRule}``.

    Raises
    ------
    FaultSpecError : unknown kind, bad value, repeated kind.

    Examples
    --------
    >>> parse_faults("garbled=0.1,busy=@3")["busy"].at
    3
    """
    rules: dict[str, FaultRule] = {}
    if spec is None or not spec.strip():
        return rules
    for item in spec.split(","):
        item = item.strip()
        m = _ITEM.fullmatch(item)
        if m is None:
            raise FaultSpecError(f"--faults item {item!r}: expected kind=RATE or kind=@N "
                                 f"(kinds: {', '.join(FAULT_KINDS)})")
        kind, value = m.groups()
        if kind not in FAULT_KINDS:
            raise FaultSpecError(f"--faults: unknown kind {kind!r} (kinds: {', '.join(FAULT_KINDS)})")
        if kind in rules:
            raise FaultSpecError(f"--faults: kind {kind!r} given twice")
        if value.startswith("@"):
            at = int(value[1:])
            if at < 1:
                raise FaultSpecError(f"--faults {item!r}: the trigger count N must be >= 1")
            rules[kind] = FaultRule(kind, at=at)
        else:
            rate = float(value)
            if not 0.0 <= rate <= 1.0:
                raise FaultSpecError(f"--faults {item!r}: the rate must be in 0..1")
            rules[kind] = FaultRule(kind, rate=rate)
    return rules


class FaultInjector:
    """Deterministic fault decisions per kind, from the seed and the sequence of opportunities.

    ``stats`` counts the faults injected per kind.

    A faulted exchange never advances the head's repetition counter (its readings are discarded),
    so a session that retries through faults measures exactly the numbers of a clean session:
    faults never corrupt a reading that is reported as good. Modbus faults never touch it either: a
    Modbus request changes the head's state only through the controller (a move, a coil, the sample
    slot), and repeating such a request (after a drop that did execute it) resets the counter to the
    same zero.
    """

    def __init__(self, spec: str | dict[str, FaultRule] | None, seed: int = 0):
        self.rules = parse_faults(spec) if not isinstance(spec, dict) else dict(spec)
        self.seed = int(seed)
        self.opportunities: Counter[str] = Counter()
        self.stats: Counter[str] = Counter()
        self._rngs = {k: np.random.Generator(np.random.Philox(np.random.SeedSequence(
            [_FAULT_DOMAIN, self.seed & 0xFFFFFFFFFFFFFFFF, FAULT_KINDS.index(k)])))
            for k in self.rules}

    def active(self, kind: str) -> bool:
        """Whether the spec names the fault ``kind``."""
        return kind in self.rules

    def fires(self, kind: str) -> bool:
        """Count one opportunity of ``kind`` and decide whether the fault fires (and count it)."""
        rule = self.rules.get(kind)
        if rule is None:
            return False
        self.opportunities[kind] += 1
        u = float(self._rngs[kind].random())
        if rule.at is not None:
            hit = self.opportunities[kind] == rule.at
        else:       # a rule of parse_faults has a rate where it has no trigger count
            hit = rule.rate is not None and u < rule.rate
        if hit:
            self.stats[kind] += 1
        return hit

    def rng(self, kind: str) -> np.random.Generator:
        """The stream of ``kind`` (for the fault's own details, e.g. which bytes to garble)."""
        return self._rngs[kind]

    def head_fault(self) -> str | None:
        """Decide the fault of one head command line (None = none), checksum excepted.

        Every active kind is drawn; the checksum kind is decided after the command ran, for
        replies sent in checksum mode that no other fault hit.
        """
        fired = [k for k in HEAD_FAULT_ORDER if k != "checksum" and self.fires(k)]
        if len(fired) > 1:      # only the first is injected; do not count the others
            for k in fired[1:]:
                self.stats[k] -= 1
        return fired[0] if fired else None
