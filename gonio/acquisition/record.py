"""Recording and replay of the instrument links (JSON Lines transcripts).

A transcript is a JSON Lines file. The first line is a header::

    {"type": "header", "format": "gonio-transcript/2", "created": ISO-8601, "seed": N|null,
     "modbus": URL, "serial": URL, "plan": name, "plan_sha256": hex, "owner_token": N,
     "software": {...}}

then one line per message, in the order they crossed the links::

    {"i": k, "t": seconds since the start, "ch": "serial"|"modbus", "dir": "tx"|"rx", "payload": ...,
     "h": hex}

Integrity: ``h`` chains every line to the ones before it, ``h_k = SHA-256(h_{k-1} + body_k)``
(hex digests; ``body_k`` is the line's exact text without its ``,"h":"..."`` field, and ``h_1``
chains from the SHA-256 of the header line), so a transcript killed mid-recording is still a
valid prefix, while an edited line (an edited reply with a recomputed ``*HH`` checksum, an
edited header) breaks the chain at that line: :func:`load_transcript` raises
:class:`TranscriptIntegrityError` naming it and ``gonio replay`` exits 1. The chain detects
edits and corruption, it does not authenticate (anyone can recompute it: :func:`reseal`).

Every request (``tx``) is followed by its response (``rx``). Serial payloads are the raw line
bytes as a string (bytes 0..255 mapped one-to-one to code points, i.e. latin-1), so garbled,
truncated and empty (timeout) answers are kept exactly; Modbus payloads are the request dict of
:class:`gonio.instrument.transport.ModbusTransport` and its response dict. Link events are requests too:
``{"op": "reconnect"}`` and ``{"op": "drain"}`` (serial resynchronisation after a bad line).
Failures are responses: ``{"error": "timeout"|"link_lost", "message": ...}`` and
``{"exception": CODE}`` (a Modbus exception).

:class:`RecordingTransport` wraps a live transport and writes the transcript;
:class:`ReplayTransport` stands in for a transport and answers each request with the recorded
response, raising :class:`ReplayMismatch` (request index, expected, got) at the first request
that differs. Replay never sleeps and never depends on timing: the driver's decisions depend on
responses only, so the same driver reproduces the same requests.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import time
from pathlib import Path
from typing import Any

from gonio.instrument.transport import (
    LineTransport,
    LinkLost,
    LinkTimeout,
    ModbusExceptionResponse,
    RequestTransport,
    TransportError,
)

__all__ = ["TRANSCRIPT_FORMAT", "TranscriptError", "TranscriptIntegrityError", "ReplayMismatch",
           "TranscriptWriter", "reseal",
           "RecordingTransport", "Transcript", "ReplayTransport", "load_transcript"]

TRANSCRIPT_FORMAT = "gonio-transcript/2"
_HASHED_LINE = re.compile(r'(.*),"h":"([0-9a-f]{64})"\}')


class TranscriptError(ValueError):
    """The transcript file is missing or invalid (message names the file and line)."""


class TranscriptIntegrityError(TranscriptError):
    """A transcript line fails its integrity check (edited or corrupted after recording)."""


def _chain(previous: str, body: str) -> str:
    return hashlib.sha256((previous + body).encode("utf-8")).hexdigest()


def _sealed(previous: str, body: str) -> tuple[str, str]:
    """``(line, h)``: the message's JSON text ``body`` with its chained hash appended."""
    h = _chain(previous, body)
    return body[:-1] + ',"h":"' + h + '"}', h


def reseal(text: str) -> str:
    """Recompute the integrity chain of a transcript's text.

    For tests and repair tools: an edited transcript then loads as if recorded so.
    """
    lines = text.splitlines()
    out = [lines[0]]
    h = hashlib.sha256(lines[0].encode("utf-8")).hexdigest()
    for line in lines[1:]:
        m = json.loads(line)
        m.pop("h", None)
        sealed, h = _sealed(h, json.dumps(m, separators=(",", ":")))
        out.append(sealed)
    return "\n".join(out) + "\n"


class ReplayMismatch(Exception):
    """The driver sent a request that differs from the transcript's (first difference only)."""

    def __init__(self, index: int, channel: str, expected: Any, got: Any, line: int | None = None):
        self.index, self.channel, self.expected, self.got = index, channel, expected, got
        where = f"request {index}" + (f" (transcript line {line})" if line else "")
        want = (f"{expected['ch']} {_show(expected)}" if isinstance(expected, dict)
                else str(expected))
        super().__init__(f"replay: {where} differs: expected {want}, "
                         f"the driver sent {channel} {_show(got)}")


def _show(v: Any) -> str:
    if isinstance(v, dict) and "payload" in v:
        v = v["payload"]
    s = json.dumps(v) if not isinstance(v, str) else repr(v)
    return s if len(s) <= 200 else s[:200] + "..."


def _encode(channel: str, payload: Any) -> Any:
    if isinstance(payload, (bytes, bytearray)):
        return bytes(payload).decode("latin-1")
    return payload


def _error_payload(exc: TransportError) -> dict:
    if isinstance(exc, ModbusExceptionResponse):
        return {"exception": exc.code}
    if isinstance(exc, LinkTimeout):
        return {"error": "timeout", "message": str(exc)}
    return {"error": "link_lost", "message": str(exc)}


class TranscriptWriter:
    """Append transcript lines (flushed per line, so a killed run leaves a usable prefix)."""

    def __init__(self, path: str | os.PathLike, header: dict):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        try:    # a new file only: an existing file (a transcript, a journal) is never replaced
            self._fh = open(self.path, "x", encoding="utf-8")
        except FileExistsError:
            raise TranscriptError(f"{self.path}: the file exists; --record writes a new "
                                  "transcript: choose a new file name") from None
        self._t0 = time.monotonic()
        self._i = 0
        line = json.dumps({"type": "header", "format": TRANSCRIPT_FORMAT, **header})
        self._h = hashlib.sha256(line.encode("utf-8")).hexdigest()
        self._fh.write(line + "\n")
        self._fh.flush()

    def write(self, channel: str, direction: str, payload: Any) -> None:
        """One message line."""
        rec = {"i": self._i, "t": round(time.monotonic() - self._t0, 6), "ch": channel,
               "dir": direction, "payload": payload}
        line, self._h = _sealed(self._h, json.dumps(rec, separators=(",", ":")))
        self._fh.write(line + "\n")
        self._fh.flush()
        self._i += 1

    def close(self) -> None:
        """Close the transcript file."""
        if not self._fh.closed:
            self._fh.close()


class RecordingTransport:
    """Wrap a transport; record every request and response (same interface as the transport)."""

    def __init__(self, inner: LineTransport | RequestTransport, writer: TranscriptWriter):
        self.inner: Any = inner
        self.writer = writer
        self.channel = inner.channel
        self.url = inner.url
        # a Modbus link has no per-line timeout; the head reads it from its line transport
        self.timeout_s = float(getattr(inner, "timeout_s", 1.0))

    def _do(self, request_payload: Any, call):
        self.writer.write(self.channel, "tx", request_payload)
        try:
            result = call()
        except TransportError as exc:
            self.writer.write(self.channel, "rx", _error_payload(exc))
            raise
        return result

    def exchange(self, request: Any, timeout_s: float | None = None) -> Any:
        # a per-command timeout exists on the line transport only (a long READ?)
        """Exchange on the inner transport and record the request and its reply (or its error)."""
        kw = {} if timeout_s is None else {"timeout_s": timeout_s}
        out = self._do(_encode(self.channel, request), lambda: self.inner.exchange(request, **kw))
        self.writer.write(self.channel, "rx", _encode(self.channel, out))
        return out

    def reconnect(self) -> None:
        """Reconnect the inner transport, recorded."""
        self._do({"op": "reconnect"}, self.inner.reconnect)
        self.writer.write(self.channel, "rx", {"ok": True})

    def drain(self) -> bytes:
        """Drain the inner transport's input, recorded with what was dropped."""
        out = self._do({"op": "drain"}, self.inner.drain)
        self.writer.write(self.channel, "rx", {"dropped": _encode(self.channel, out)})
        return out

    def open(self) -> None:
        """Open the inner transport."""
        self.inner.open()

    def close(self) -> None:
        """Close the inner transport."""
        self.inner.close()


class Transcript:
    """A loaded transcript with one replay cursor shared by both channels."""

    def __init__(self, header: dict, messages: list[dict], name: str):
        self.header, self.messages, self.name = header, messages, name
        self.pos = 0
        self.requests = 0
        self.mismatch: ReplayMismatch | None = None

    def _fail(self, exc: ReplayMismatch):
        if self.mismatch is None:
            self.mismatch = exc
        raise self.mismatch

    def answer(self, channel: str, payload: Any) -> Any:
        """The recorded response to ``payload`` on ``channel``; :class:`ReplayMismatch` if it differs."""
        if self.mismatch is not None:
            raise self.mismatch
        index = self.requests
        self.requests += 1
        if self.pos >= len(self.messages):
            self._fail(ReplayMismatch(index, channel, "<the transcript ends>", payload))
        tx = self.messages[self.pos]
        if tx["dir"] != "tx" or tx["ch"] != channel or tx["payload"] != payload:
            self._fail(ReplayMismatch(index, channel, tx, payload, line=self.pos + 2))
        if self.pos + 1 >= len(self.messages) or self.messages[self.pos + 1]["dir"] != "rx":
            self._fail(ReplayMismatch(index, channel, "<a response, but the transcript ends>", payload))
        rx = self.messages[self.pos + 1]
        self.pos += 2
        return rx["payload"]

    def finish(self) -> None:
        """Raise :class:`ReplayMismatch` if the driver stopped before the transcript's end."""
        if self.mismatch is not None:
            raise self.mismatch
        if self.pos < len(self.messages):
            tx = self.messages[self.pos]
            self._fail(ReplayMismatch(self.requests, tx.get("ch", "?"), tx, "<no further request>",
                                      line=self.pos + 2))


def load_transcript(path: str | os.PathLike) -> Transcript:  # noqa: C901
    """Read and validate a transcript file; raises :class:`TranscriptError`."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
        lines = text.splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise TranscriptError(f"{p}: cannot read the transcript ({exc})") from None
    if not lines:
        raise TranscriptError(f"{p}: empty file, not a transcript")
    try:
        header = json.loads(lines[0])
    except (ValueError, RecursionError):
        raise TranscriptError(f"{p}: line 1: not a transcript header") from None
    if isinstance(header, dict) and header.get("format") == "gonio-transcript/1":
        raise TranscriptError(f"{p}: line 1: a gonio-transcript/1 file has no integrity check; "
                              f"record it again (this gonio replays {TRANSCRIPT_FORMAT})")
    if not isinstance(header, dict) or header.get("format") != TRANSCRIPT_FORMAT:
        raise TranscriptError(f"{p}: line 1: not a {TRANSCRIPT_FORMAT} header")
    token = header.get("owner_token", 0)
    if isinstance(token, bool) or not isinstance(token, int) or not 0 <= token < 2**32:
        raise TranscriptError(f"{p}: line 1: owner_token must be an integer 0 .. 2**32 - 1")
    messages = []
    h = hashlib.sha256(lines[0].encode("utf-8")).hexdigest()
    for k, line in enumerate(lines[1:], start=2):
        sealed = _HASHED_LINE.fullmatch(line)
        if sealed is None:
            if k == len(lines) and not text.endswith("\n"):
                break   # a torn last line (recording killed mid-write, no newline): ignore it
            try:
                json.loads(line)
            except (ValueError, RecursionError):
                what = "the last line" if k == len(lines) else "line"
                raise TranscriptError(f"{p}: {what} {k}: not valid JSON (a complete line, not one "
                                      "torn by a killed recording): the transcript is corrupt") from None
            raise TranscriptIntegrityError(f"{p}: line {k}: no integrity hash; the transcript "
                                           "was edited or corrupted after recording")
        body = sealed.group(1) + "}"
        h_expected = _chain(h, body)
        if sealed.group(2) != h_expected:
            raise TranscriptIntegrityError(
                f"{p}: line {k}: integrity check failed (SHA-256 chain broken): this line or "
                "the header was edited after recording")
        h = h_expected
        try:
            m = json.loads(body)
        except (ValueError, RecursionError):
            raise TranscriptError(f"{p}: line {k}: not valid JSON") from None
        if (not isinstance(m, dict) or m.get("dir") not in ("tx", "rx")
                or m.get("ch") not in ("serial", "modbus") or "payload" not in m):
            raise TranscriptError(f"{p}: line {k}: expected a message with ch, dir and payload")
        payload = m["payload"]
        if m["ch"] == "serial" and isinstance(payload, str):
            if any(ord(c) > 255 for c in payload):
                raise TranscriptError(f"{p}: line {k}: a serial payload holds bytes 0..255 only")
        elif not isinstance(payload, dict):
            raise TranscriptError(f"{p}: line {k}: the payload must be "
                                  + ("a string or an object" if m["ch"] == "serial" else "an object"))
        messages.append(m)
    return Transcript(header, messages, str(p))


class ReplayTransport:
    """A transport answering from a :class:`Transcript` (same interface as the live ones)."""

    #: the recorded link's timeout does not matter: a replay never waits
    timeout_s = 1.0

    def __init__(self, transcript: Transcript, channel: str):
        self.transcript = transcript
        self.channel = channel
        self.url = transcript.header.get(channel, f"replay:{channel}")

    def _raise_error(self, resp: Any) -> None:
        if isinstance(resp, dict):
            if "exception" in resp:
                raise ModbusExceptionResponse(self._last_request, int(resp["exception"]))
            if resp.get("error") == "timeout":
                raise LinkTimeout(self.channel, resp.get("message", "no response (recorded)"))
            if resp.get("error") == "link_lost":
                raise LinkLost(self.channel, resp.get("message", "link lost (recorded)"))

    def exchange(self, request: Any, timeout_s: float | None = None) -> Any:
        """The recorded reply to ``request`` (or its recorded error), checked against the transcript."""
        self._last_request = request if isinstance(request, dict) else {}
        resp = self.transcript.answer(self.channel, _encode(self.channel, request))
        if self.channel == "serial":
            if isinstance(resp, dict):
                self._raise_error(resp)
                raise TranscriptError(f"{self.transcript.name}: the recorded response to request "
                                      f"{self.transcript.requests - 1} is not a line: {resp!r:.80}")
            return str(resp).encode("latin-1")
        if isinstance(resp, dict) and ("exception" in resp or "error" in resp):
            self._raise_error(resp)
        return self._checked_modbus_response(request, resp)

    def _checked_modbus_response(self, request: dict, resp: Any) -> dict:
        fn = request.get("fn", "")
        key = {"read_holding_registers": "registers", "read_input_registers": "registers",
               "read_coils": "bits"}.get(fn)
        ok = isinstance(resp, dict)
        if ok and key is not None:
            values = resp.get(key)
            ok = (isinstance(values, list) and len(values) == int(request.get("count", -1))
                  and all(isinstance(v, bool) if key == "bits"
                          else (isinstance(v, int) and not isinstance(v, bool) and 0 <= v <= 0xFFFF)
                          for v in values))
        if not ok:
            raise TranscriptError(f"{self.transcript.name}: the recorded response to request "
                                  f"{self.transcript.requests - 1} ({fn}) is malformed: {resp!r:.80}")
        return resp

    def reconnect(self) -> None:
        """Replay a recorded reconnect (its recorded error, if any)."""
        self._raise_error(self.transcript.answer(self.channel, {"op": "reconnect"}))

    def drain(self) -> bytes:
        """The input a recorded drain dropped."""
        resp = self.transcript.answer(self.channel, {"op": "drain"})
        self._raise_error(resp)
        return str(resp.get("dropped", "")).encode("latin-1") if isinstance(resp, dict) else b""

    def open(self) -> None:
        """Nothing to open: a replay has no link."""
        pass

    def close(self) -> None:
        """Nothing to close: a replay has no link."""
        pass
