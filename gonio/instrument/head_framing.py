r"""Framing of the photometer head's lines and the parser of its responses.

In checksum mode (``CHK ON``) every response is ``<payload>*HH\r\n`` with ``HH`` = XOR of all
bytes of ``<payload>`` (every byte before the ``*``), two upper-case hex digits. The reply to
``CHK ON`` already carries a checksum; the reply to ``CHK OFF`` does not.

:func:`parse_response` turns one raw line into the typed value its command's row announces
(:attr:`gonio.instrument.head_commands.HeadCommand.response`), or raises the
:class:`~gonio.instrument.head_commands.ProtocolError` that says what is wrong with it; it never
raises anything else, whatever the bytes (fuzzed with hypothesis in the tests). The mock head
frames its replies with :func:`format_response`.

References
----------
docs/instrument.md (the protocol contract).
"""

from __future__ import annotations

import math
import re

from gonio.instrument.head_commands import (
    HEAD_ERRORS,
    READ_N_RANGE,
    ChecksumError,
    ChecksumMissing,
    ErrorEntry,
    GarbledResponse,
    Identity,
    NoResponse,
    Reading,
    TruncatedResponse,
    head_error,
)

__all__ = ["LINE_TERMINATOR", "checksum", "format_response", "parse_response", "RESPONSE_KINDS"]

LINE_TERMINATOR = b"\r\n"
"""Every response line ends so (commands end with ``\\n``)."""


def checksum(line_bytes: bytes) -> str:
    """XOR of all bytes of ``line_bytes`` as two upper-case hex digits.

    ``line_bytes`` is the payload, i.e. every byte before the ``*``.

    Examples
    --------
    >>> checksum(b"OK")          # 0x4F ^ 0x4B = 0x04
    '04'
    >>> checksum(b"")
    '00'
    """
    x = 0
    for b in bytes(line_bytes):
        x ^= b
    return f"{x:02X}"


def format_response(payload: str | bytes, chk: bool) -> bytes:
    r"""A complete response line: payload, ``*HH`` when ``chk``, and ``\r\n``."""
    p = payload.encode("ascii") if isinstance(payload, str) else bytes(payload)
    if chk:
        p = p + b"*" + checksum(p).encode("ascii")
    return p + LINE_TERMINATOR


_PRINTABLE = re.compile(rb"[\x20-\x7e]*")
_ERR = re.compile(r"ERR (\d{3}),([^,*]+)")
_FLOAT = re.compile(r"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?")
_INTRE = re.compile(r"[+-]?\d{1,12}")
_READING = re.compile(r"([^,]+),([^,]+),([^,]+),([^,]+)")
_ERRENTRY = re.compile(r'([+-]?\d{1,6}),"([^"]*)"')
_IDN = re.compile(r"([^,]+),([^,]+),([^,]+),([^,]+)")
_WORD = re.compile(r"[A-Z]{1,16}")
RESPONSE_KINDS = ("text", "ok", "float", "int", "word", "idn", "reading", "error_entry")
"""The reply kinds :func:`parse_response` knows (``expect``)."""


def _as_float(text: str, what: str) -> float:
    if len(text) > 40 or not _FLOAT.fullmatch(text):
        raise GarbledResponse(f"expected a number for {what}, got {text!r}")
    v = float(text)
    if not math.isfinite(v):
        raise GarbledResponse(f"non-finite number for {what}: {text!r}")
    return v


def _as_int(text: str, what: str) -> int:
    if not _INTRE.fullmatch(text):
        raise GarbledResponse(f"expected an integer for {what}, got {text!r}")
    return int(text)


def parse_response(line: bytes, chk: bool, expect: str = "text"):  # noqa: C901
    r"""Parse one head response line (as read, terminator included) into a typed value.

    Parameters
    ----------
    line : bytes
        The raw bytes read up to and including ``\r\n`` (an empty ``bytes`` = timeout).
    chk : bool
        Whether checksum mode is on (then ``*HH`` is required and verified).
    expect : str
        The reply kind (:attr:`HeadCommand.response`): ``"text"`` (str), ``"ok"`` (None),
        ``"float"``, ``"int"``, ``"word"`` (str), ``"idn"`` (:class:`Identity`), ``"reading"``
        (:class:`Reading`), ``"error_entry"`` (:class:`ErrorEntry`).

    Raises
    ------
    NoResponse, TruncatedResponse, GarbledResponse, ChecksumError
        Framing problems (transient).
    HeadError
        A subclass: the head answered ``ERR <code>,<message>`` (:class:`BusyError` is transient);
        an unknown code or a message not matching it is a GarbledResponse. Nothing else is raised,
        whatever the bytes (ValueError for an unknown ``expect``).

    Examples
    --------
    >>> parse_response(b"OK*04\r\n", chk=True, expect="ok") is None
    True
    >>> parse_response(b"1234.50,12.30,10,0\r\n", chk=False, expect="reading").mean_counts
    1234.5
    """
    if expect not in RESPONSE_KINDS:
        raise ValueError(f"unknown expect {expect!r}; one of {RESPONSE_KINDS}")
    try:
        line = bytes(line)
    except (TypeError, ValueError):
        raise GarbledResponse(f"not bytes: {type(line).__name__}") from None
    if not line:
        raise NoResponse("no response (timeout)")
    if not line.endswith(LINE_TERMINATOR):
        raise TruncatedResponse(f"response without \\r\\n terminator: {line[:80]!r}")
    body = line[:-2]
    if not _PRINTABLE.fullmatch(body):
        raise GarbledResponse(f"non-printable bytes in response: {line[:80]!r}")
    text = body.decode("ascii")
    if chk:
        if len(text) < 3 or text[-3] != "*":
            raise ChecksumMissing(f"checksum mode on but no *HH in {text[:80]!r}")
        payload, hh = text[:-3], text[-2:]
        if hh != checksum(payload.encode("ascii")):
            raise ChecksumError(f"bad checksum *{hh} (expected *{checksum(payload.encode('ascii'))}) "
                                f"in {text[:80]!r}")
    else:
        payload = text
    if payload.startswith("ERR"):
        m = _ERR.fullmatch(payload)
        if m is None:
            raise GarbledResponse(f"malformed error response {payload[:80]!r}")
        code, message = int(m.group(1)), m.group(2)
        if HEAD_ERRORS.get(code) != message:
            raise GarbledResponse(f"unknown error code/message {payload[:80]!r}")
        raise head_error(code)
    if "*" in payload:
        raise GarbledResponse(f"unexpected '*' in response {payload[:80]!r}")
    if not payload:
        raise GarbledResponse("empty response line")
    if expect == "text":
        return payload
    if expect == "ok":
        if payload != "OK":
            raise GarbledResponse(f"expected OK, got {payload[:80]!r}")
        return None
    if expect == "float":
        return _as_float(payload, "value")
    if expect == "int":
        return _as_int(payload, "value")
    if expect == "word":
        if not _WORD.fullmatch(payload):
            raise GarbledResponse(f"expected a word, got {payload[:80]!r}")
        return payload
    if expect == "idn":
        m = _IDN.fullmatch(payload)
        if m is None:
            raise GarbledResponse(f"expected maker,model,serial,firmware, got {payload[:80]!r}")
        return Identity(*m.groups())
    if expect == "error_entry":
        m = _ERRENTRY.fullmatch(payload)
        if m is None:
            raise GarbledResponse(f'expected <code>,"<message>", got {payload[:80]!r}')
        return ErrorEntry(int(m.group(1)), m.group(2))
    # reading
    m = _READING.fullmatch(payload)
    if m is None:
        raise GarbledResponse(f"expected <mean>,<std>,<n>,<flags>, got {payload[:80]!r}")
    mean = _as_float(m.group(1), "mean_counts")
    std = _as_float(m.group(2), "std_counts")
    n = _as_int(m.group(3), "n")
    flags = _as_int(m.group(4), "flags")
    if std < 0 or not READ_N_RANGE[0] <= n <= READ_N_RANGE[1] or not 0 <= flags <= 3:
        raise GarbledResponse(f"reading fields out of range in {payload[:80]!r}")
    return Reading(mean, std, n, flags)

