"""The acquisition journal: an append-only JSON Lines checkpoint, fsynced per record.

The engine (:mod:`gonio.acquisition.engine`) emits one record per event to the journal writer
(:class:`gonio.acquisition.subscribers.JournalWriter`), which appends it and calls ``fsync`` before it
starts the next point, so after a crash (even ``SIGKILL`` or a power cut) the journal holds every
point that was measured, plus at most one torn last line. Records (one JSON object a line):

``start``        ``{"type": "start", "plan": name, "plan_sha256", "standard_sha256", "time", "session"}``
``calibration``  ``{"type": "calibration", "id", "time", "plan_sha256", "standard_sha256", "idn",
                 "darks": [step...], "reference": [reading...], "reference_deg", "retries"}`` -
                 dark per auto-ranging step and the white standard per wavelength
``point``        ``{"type": "point", "index", "axes_deg": [4], "geometry": [theta_i, phi_i, theta_o,
                 phi_o], "calibration", "readings": [reading...], "saturated_nm": [...],
                 "retries"}`` - one geometry, every wavelength (those saturated at every setting
                 are listed, not stored)
``event``        ``{"type": "event", "what": str, ...}`` - resume, retries, safe stop, completion

``retries`` (optional: journals written before it existed lack it) is the session's cumulative
retry counter at that checkpoint, ``{kind: count}`` (:data:`gonio.instrument.retry.RETRY_KINDS`), so the
counts of a session killed before its ``session_end`` event are not lost
(:func:`gonio.acquisition.reduce.retry_totals`).

A *reading* is ``{"wavelength_nm", "itime_ms", "gain", "mean", "sem", "n", "ranging"}`` (raw
counts; the radiance factor is computed from the journal when the dataset is written, so a
dataset can always be rebuilt from its journal).

Reading (:func:`read_journal`) validates every record and raises :class:`JournalError` naming the
file and line for a corrupt record anywhere but at the end; a last line without its newline or
that does not parse is reported as *torn* (the point it held is measured again on resume) and
:meth:`Journal.open` truncates it before appending.

Integrity (the transcripts' chain, :mod:`gonio.acquisition.record`): every line ends with
``"h"``, chaining it to everything before it, ``h_k = SHA-256(h_{k-1} + body_k)`` (hex digests;
``body_k`` is the line's exact text without its ``,"h":"..."`` field), where ``h_0`` is the
SHA-256 of the bytes before the first chained line (of nothing, for a journal written with the
chain). A reading edited after it was journaled (a mean multiplied by 10) breaks the chain at
that line: :func:`read_journal` raises :class:`JournalIntegrityError` naming the line, and
``gonio acquire --resume`` stops with that one line (exit 2) instead of merging the edited
point into the dataset. A kill leaves at most a torn last line, which fails to parse (the chain
is never partly written: a line and its hash are one ``write``), so crash-safety is unchanged.

Journals without the chain (no ``"h"`` on their first line) stay readable: their lines
are read unchecked (:attr:`JournalContent.unchained_lines` counts them and
``--resume`` says so in its log); records appended to such a journal are chained, with ``h_0``
the SHA-256 of the old lines, so from then on an edit of an old line is detected too. Once a
journal has a chained line, every later line must be chained. The chain detects edits and
corruption; it does not authenticate (anyone can recompute it).
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, BinaryIO

__all__ = ["JournalError", "JournalIntegrityError", "JournalContent", "Journal", "read_journal", "parse_journal",
           "check_consistency", "RECORD_TYPES"]


class JournalError(ValueError):
    """The journal is corrupt or belongs to another run (message names the file and line)."""


class JournalIntegrityError(JournalError):
    """A journal line fails its integrity chain (edited or corrupted after it was written)."""


_SEALED = re.compile(rb'(.*),"h":"([0-9a-f]{64})"\}')


def _chain(previous: str, body: bytes) -> str:
    return hashlib.sha256(previous.encode("ascii") + body).hexdigest()


def _seal(previous: str, record: dict) -> tuple[bytes, str]:
    """``(line, h)``: the record's JSON text with its chained hash (no newline)."""
    body = json.dumps(record, separators=(",", ":"), allow_nan=False).encode()
    h = _chain(previous, body)
    return body[:-1] + b',"h":"' + h.encode("ascii") + b'"}', h


_NUM = (int, float)
_READING = {"wavelength_nm": _NUM, "itime_ms": _NUM, "gain": int, "mean": _NUM, "sem": _NUM,
            "n": int}
_DARK = {"itime_ms": _NUM, "gain": int, "mean": _NUM, "sem": _NUM, "n": int}
_SCHEMA: dict[str, dict[str, Any]] = {
    "start": {"plan": str, "plan_sha256": str, "standard_sha256": str, "time": _NUM},
    "calibration": {"id": int, "time": _NUM, "plan_sha256": str, "standard_sha256": str,
                    "idn": str, "darks": list, "reference": list},
    "point": {"index": int, "axes_deg": list, "geometry": list, "calibration": int,
              "readings": list},
    "event": {"what": str},
}
RECORD_TYPES = tuple(_SCHEMA)
"""The journal's record types (the engine's documents that are journaled)."""


def _reject_constant(name: str):
    raise ValueError(f"non-finite number {name}")


def _check_fields(rec: dict, spec: dict[str, Any], where: str) -> None:
    for key, typ in spec.items():
        if key not in rec:
            raise JournalError(f"{where}: missing field '{key}'")
        v = rec[key]
        if isinstance(v, bool) or not isinstance(v, typ):
            raise JournalError(f"{where}: field '{key}' has the wrong type ({type(v).__name__})")


def _validate(rec: Any, where: str) -> dict:  # noqa: C901
    if not isinstance(rec, dict):
        raise JournalError(f"{where}: a record must be a JSON object")
    if not _finite(rec):
        raise JournalError(f"{where}: a number is not finite or too large")
    kind = rec.get("type")
    if not isinstance(kind, str) or kind not in _SCHEMA:
        raise JournalError(f"{where}: unknown record type {kind!r}")
    _check_fields(rec, _SCHEMA[kind], where)
    if "retries" in rec:
        counts = rec["retries"]
        if not isinstance(counts, dict) or not all(
                isinstance(v, int) and not isinstance(v, bool) and v >= 0 for v in counts.values()):
            raise JournalError(f"{where}: field 'retries' must map retry kinds to counts >= 0")
    if kind == "calibration":
        for k, d in enumerate(rec["darks"]):
            if not isinstance(d, dict):
                raise JournalError(f"{where}: darks[{k}] must be an object")
            _check_fields(d, _DARK, f"{where}: darks[{k}]")
        for k, r in enumerate(rec["reference"]):
            if not isinstance(r, dict):
                raise JournalError(f"{where}: reference[{k}] must be an object")
            _check_fields(r, _READING, f"{where}: reference[{k}]")
    elif kind == "point":
        for name, n in (("axes_deg", 4), ("geometry", 4)):
            vals = rec[name]
            if len(vals) != n or any(isinstance(x, bool) or not isinstance(x, _NUM) for x in vals):
                raise JournalError(f"{where}: field '{name}' must be {n} numbers")
        for k, r in enumerate(rec["readings"]):
            if not isinstance(r, dict):
                raise JournalError(f"{where}: readings[{k}] must be an object")
            _check_fields(r, _READING, f"{where}: readings[{k}]")
    return rec


@dataclass
class JournalContent:
    """Records read from a journal; ``torn`` when the last line was incomplete."""

    records: list[dict] = field(default_factory=list)
    torn: bool = False
    good_bytes: int = 0
    missing_newline: bool = False
    #: records before the chain started (journals written before it existed), read unchecked
    unchained_lines: int = 0
    #: the chain's last hash: what the next appended record chains from
    head: str = hashlib.sha256(b"").hexdigest()

    def of_type(self, kind: str) -> list[dict]:
        """Records of one type, in journal order."""
        return [r for r in self.records if r["type"] == kind]


def parse_journal(data: bytes, name: str = "journal.jsonl") -> JournalContent:
    """Parse journal bytes.

    Raises :class:`JournalError` for anything but a torn last line (:class:`JournalIntegrityError`
    for a line that breaks the integrity chain).
    """
    out = JournalContent()
    pos = 0
    lineno = 0
    head: str | None = None          # None until the first chained line
    while pos < len(data):
        lineno += 1
        end = data.find(b"\n", pos)
        final = end < 0
        line = data[pos:] if final else data[pos:end]
        where = f"{name}: line {lineno}"
        sealed = _SEALED.fullmatch(line)
        body = line
        if sealed is not None:
            body = sealed.group(1) + b"}"
            previous = head if head is not None else hashlib.sha256(data[:pos]).hexdigest()
            h = _chain(previous, body)
            if sealed.group(2).decode("ascii") != h:
                raise JournalIntegrityError(
                    f"{where}: integrity check failed (SHA-256 chain broken): this record or "
                    "one before it was edited after it was journaled; the journal cannot be "
                    "trusted: restore the original or start a new run (choose a new --out)")
        elif head is not None and not final:
            raise JournalIntegrityError(f"{where}: no integrity hash although the lines before "
                                        "have one: the record was edited or inserted after it "
                                        "was journaled; restore the original or choose a new "
                                        "--out")
        try:
            rec = _validate(json.loads(body.decode("utf-8"), parse_constant=_reject_constant), where)
        except JournalError:
            if final:
                out.torn = True
                break
            raise
        except (ValueError, RecursionError, UnicodeDecodeError) as exc:
            if final:
                out.torn = True
                break
            raise JournalError(f"{where}: not a valid JSON record ({exc})") from None
        if sealed is None and head is not None:     # a complete final line without its hash
            raise JournalIntegrityError(f"{where}: no integrity hash although the lines before "
                                        "have one: the record was edited after it was "
                                        "journaled; restore the original or choose a new --out")
        if sealed is not None:
            head = h
        else:
            out.unchained_lines += 1
        out.records.append(rec)
        if final:
            # a complete record that only lacks its newline: kept, the newline is added on open
            out.torn = True
            out.missing_newline = True
            out.good_bytes = len(data)
            break
        pos = end + 1
        out.good_bytes = pos
    if head is None:     # no chained line yet: the chain will start from what is kept
        kept = data[:out.good_bytes] + (b"\n" if out.missing_newline else b"")
        head = hashlib.sha256(kept).hexdigest()
    out.head = head
    return out


def check_consistency(records: list[dict], name: str = "journal.jsonl") -> None:
    """Cross-record checks; raises :class:`JournalError`.

    One start record first; every point refers to an earlier calibration holding a dark for each of its (integration time, gain) settings and a white
    reference for each of its wavelengths.
    """
    if not records:
        return
    if records[0]["type"] != "start" or sum(r["type"] == "start" for r in records) != 1:
        raise JournalError(f"{name}: a journal starts with exactly one start record")
    cals: dict[int, tuple[set, set]] = {}
    for k, r in enumerate(records, start=1):
        if r["type"] == "calibration":
            cals[r["id"]] = ({(d["itime_ms"], d["gain"]) for d in r["darks"]},
                             {float(x["wavelength_nm"]) for x in r["reference"]})
        elif r["type"] == "point":
            if r["calibration"] not in cals:
                raise JournalError(f"{name}: line {k}: point refers to calibration "
                                   f"{r['calibration']}, which is not before it")
            darks, refs = cals[r["calibration"]]
            for x in r["readings"]:
                if (x["itime_ms"], x["gain"]) not in darks or float(x["wavelength_nm"]) not in refs:
                    raise JournalError(f"{name}: line {k}: a reading has no dark or white "
                                       f"reference in calibration {r['calibration']}")


def read_journal(path: str | os.PathLike) -> JournalContent:
    """Read and validate a journal file (see :func:`parse_journal`)."""
    p = Path(path)
    try:
        data = p.read_bytes()
    except FileNotFoundError:
        return JournalContent()
    except OSError as exc:
        raise JournalError(f"{p}: cannot read the journal ({exc.strerror})") from None
    return parse_journal(data, str(p))


def _finite(obj: Any) -> bool:
    """Every number finite (floats) and within 64 bits (integers), recursively."""
    if isinstance(obj, bool):
        return True
    if isinstance(obj, int):
        return abs(obj) < 2**63
    if isinstance(obj, float):
        return math.isfinite(obj)
    if isinstance(obj, dict):
        return all(_finite(v) for v in obj.values())
    if isinstance(obj, (list, tuple)):
        return all(_finite(v) for v in obj)
    return True


class Journal:
    """Append-only writer of the journal.

    Every :meth:`append` is chained (see the module's *Integrity*), flushed and fsynced before it
    returns.
    """

    def __init__(self, path: str | os.PathLike):
        self.path = Path(path)
        self._fh: BinaryIO | None = None
        self._head = hashlib.sha256(b"").hexdigest()

    @classmethod
    def open(cls, path: str | os.PathLike) -> tuple[Journal, JournalContent]:
        """Open for appending after reading what is there; a torn last line is cut off first.

        A last record complete but for its newline is kept (the newline is added).
        """
        j = cls(path)
        content = read_journal(j.path)
        j.path.parent.mkdir(parents=True, exist_ok=True)
        fh = open(j.path, "ab")
        if content.torn:
            fh.truncate(content.good_bytes)
            fh.seek(0, os.SEEK_END)
            if content.missing_newline:
                fh.write(b"\n")
            fh.flush()
            os.fsync(fh.fileno())
        j._fh = fh
        j._head = content.head
        return j, content

    def append(self, record: dict) -> None:
        """Write one record as a JSON line, flush and fsync (the checkpoint)."""
        if self._fh is None:
            raise RuntimeError("journal is not open")
        try:
            _validate(record, f"{self.path}: new record")
        except JournalError as exc:
            raise ValueError(f"not a valid journal record: {exc}") from None
        line, self._head = _seal(self._head, record)
        try:
            self._fh.write(line + b"\n")
            self._fh.flush()
            os.fsync(self._fh.fileno())
        except OSError as exc:       # a full disk: name the journal (a torn last line is cut off on resume)
            raise OSError(exc.errno, exc.strerror or str(exc), str(self.path)) from None

    def close(self) -> None:
        """Close the file (idempotent)."""
        if self._fh is not None:
            self._fh.close()
            self._fh = None
