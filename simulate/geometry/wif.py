"""Weaving Information File (WIF 1.1) drawdowns as weave matrices.

References
----------
Ravi Nielsen et al., *Weaving Information File (WIF) Specification*, version 1.1, 20 April 1997.
"""

from __future__ import annotations

import os
import re
import stat
from pathlib import Path
from typing import Any

import numpy as np

from simulate.geometry.weave import MAX_TRIANGLES, MAX_WEAVE_CELLS, Weave, WeaveError

__all__ = ["MAX_WIF_BYTES", "read_wif", "weave_from_wif"]

#: Largest WIF file read (16 MiB). The largest drawdown accepted (:data:`MAX_WEAVE_CELLS`
#: crossings) written as a lift plan naming every raised shaft takes about 1 MB; the bound keeps a
#: huge or endless file (``/dev/zero``) from being read whole. Only regular files are read (a FIFO
#: would block).
MAX_WIF_BYTES = 16 * 2**20


_SECTION = re.compile(r"^\[([^\]]+)\]$")
_TRUE = ("true", "yes", "on", "1")
_FALSE = ("false", "no", "off", "0")


class _Wif:
    """The sections of a WIF file, keys lower-cased, each value with its line number."""

    def __init__(self, path: Path):
        self.name = path.name
        try:
            st = os.stat(path)
            if not stat.S_ISREG(st.st_mode):
                raise WeaveError(f"{path}: is not a regular file; a WIF file is a text file")
            if st.st_size > MAX_WIF_BYTES:
                raise WeaveError(f"{path}: {st.st_size:,} bytes; a WIF file is read only up to "
                                 f"{MAX_WIF_BYTES:,} bytes (16 MiB)")
            with open(path, "rb") as handle:
                raw = handle.read(MAX_WIF_BYTES + 1)
        except OSError as exc:
            raise WeaveError(f"{path}: cannot read the WIF file ({exc.strerror or exc})") from None
        if len(raw) > MAX_WIF_BYTES:   # grew while being read
            raise WeaveError(f"{path}: longer than {MAX_WIF_BYTES:,} bytes (16 MiB), the most a WIF file is read")
        try:
            text = raw.decode("utf-8-sig")
        except UnicodeDecodeError:  # WIF predates UTF-8: old files are Windows-1252 / Latin-1
            text = raw.decode("latin-1")
        self.sections: dict[str, list[tuple[str, str, int]]] = {}
        self.header_line: dict[str, int] = {}
        current: str | None = None
        for number, line in enumerate(text.splitlines(), start=1):
            line = line.split(";", 1)[0].strip()  # ';' starts a comment
            if not line:
                continue
            header = _SECTION.match(line)
            if header:
                current = header.group(1).strip().lower()
                self.sections.setdefault(current, [])
                self.header_line.setdefault(current, number)
            elif "=" in line:
                if current is None:
                    raise self.error(number, f"{line!r} comes before any [SECTION] header")
                key, value = line.split("=", 1)
                self.sections[current].append((key.strip().lower(), value.strip(), number))
            else:
                raise self.error(number, f"cannot parse {line!r} (expected [SECTION] or key=value)")
        if "wif" not in self.sections:
            raise WeaveError(f"{self.name}: no [WIF] section; not a Weaving Information File")

    def error(self, line: int | None, message: str) -> WeaveError:
        return WeaveError(f"{self.name}, line {line}: {message}" if line else f"{self.name}: {message}")

    def has(self, section: str) -> bool:
        return section in self.sections

    def table(self, section: str) -> dict[str, tuple[str, int]]:
        if section not in self.sections:
            raise self.error(None, f"no [{section.upper()}] section (needed for the drawdown)")
        out: dict[str, tuple[str, int]] = {}
        for key, value, line in self.sections[section]:
            if key in out:
                raise self.error(line, f"[{section.upper()}] {key} repeated (first on line {out[key][1]})")
            out[key] = (value, line)
        return out

    def integer(self, section: str, key: str, least: int = 1) -> int | None:
        entry = self.table(section).get(key)
        if entry is None:
            return None
        value, line = entry
        try:
            number = int(value)
        except ValueError:
            raise self.error(line, f"[{section.upper()}] {key} must be an integer, got {value!r}") from None
        if number < least:
            raise self.error(line, f"[{section.upper()}] {key} must be >= {least}, got {number}")
        return number

    def boolean(self, section: str, key: str, default: bool) -> bool:
        entry = self.table(section).get(key) if self.has(section) else None
        if entry is None:
            return default
        value, line = entry
        if value.lower() in _TRUE:
            return True
        if value.lower() in _FALSE:
            return False
        raise self.error(line, f"[{section.upper()}] {key} must be true or false, got {value!r}")

    def lists(self, section: str, what: str, count: int | None, item: str, limit: int,
              limit_name: str) -> dict[int, tuple[set[int], int]]:
        """``number = a, b, c`` lines of a section: ``{number: ({a, b, c}, line)}``, range-checked."""
        out: dict[int, tuple[set[int], int]] = {}
        for key, (value, line) in self.table(section).items():
            try:
                number = int(key)
            except ValueError:
                raise self.error(line, f"[{section.upper()}] key {key!r} must be a {what} number") from None
            if number < 1 or (count is not None and number > count):
                bound = f" (1..{count})" if count is not None else " (>= 1)"
                raise self.error(line, f"[{section.upper()}] {what} {number} out of range{bound}")
            items: set[int] = set()
            for part in filter(None, (p.strip() for p in value.split(","))):
                try:
                    k = int(part)
                except ValueError:
                    raise self.error(line, f"[{section.upper()}] {what} {number}: {item} {part!r} "
                                           f"is not a number") from None
                if not 1 <= k <= limit:
                    raise self.error(line, f"[{section.upper()}] {what} {number} references {item} {k}, "
                                           f"but {limit_name}={limit}")
                items.add(k)
            out[number] = (items, line)
        return out


def read_wif(path: str | Path) -> np.ndarray:
    r"""The drawdown of a WIF 1.1 file as a weave matrix (rows = warp threads, columns = picks).

    Warp thread ``j`` (``j + 1`` in the file) raised on pick ``i`` -- it shows on the face, over
    the weft -- gives ``matrix[j, i] = 1``. Read: ``[WEAVING] Shafts`` (and ``Treadles``, ``Rising
    Shed``, default true: the tie-up and lift plan name the shafts that rise, else those that
    sink), ``[WARP] Threads`` and ``[WEFT] Threads`` (else the largest thread/pick number),
    ``[THREADING] thread = shaft(s)`` and either ``[LIFTPLAN] pick = shafts`` (used when present)
    or ``[TIEUP] treadle = shafts`` with ``[TREADLING] pick = treadle(s)``. Section and key names
    are case-insensitive; ``;`` starts a comment; other sections are ignored.

    Raises
    ------
    WeaveError
        One line naming the file and, where there is one, the line number.

    Examples
    --------
    >>> from pathlib import Path
    >>> p = Path(getfixture("tmp_path")) / "plain.wif"
    >>> _ = p.write_text("[WIF]\nVersion=1.1\n[WEAVING]\nShafts=2\nTreadles=2\n[WARP]\nThreads=2\n"
    ...                  "[WEFT]\nThreads=2\n[THREADING]\n1=1\n2=2\n[TIEUP]\n1=1\n2=2\n"
    ...                  "[TREADLING]\n1=1\n2=2\n")
    >>> read_wif(p).tolist()
    [[1, 0], [0, 1]]
    """
    wif = _Wif(Path(path))
    shafts = wif.integer("weaving", "shafts")
    if shafts is None:
        raise wif.error(wif.header_line["weaving"], "[WEAVING] has no Shafts= entry")
    rising = wif.boolean("weaving", "rising shed", True)
    n_warp = wif.integer("warp", "threads") if wif.has("warp") else None
    n_weft = wif.integer("weft", "threads") if wif.has("weft") else None
    threading = wif.lists("threading", "thread", n_warp, "shaft", shafts, "[WEAVING] Shafts")

    if wif.has("liftplan"):
        lifts = wif.lists("liftplan", "pick", n_weft, "shaft", shafts, "[WEAVING] Shafts")
        picks = {p: items for p, (items, _) in lifts.items()}
    elif wif.has("tieup") or wif.has("treadling"):
        treadles = wif.integer("weaving", "treadles")
        if treadles is None:
            raise wif.error(wif.header_line["weaving"], "[WEAVING] has no Treadles= entry (needed for [TIEUP])")
        tieup = wif.lists("tieup", "treadle", treadles, "shaft", shafts, "[WEAVING] Shafts")
        treadling = wif.lists("treadling", "pick", n_weft, "treadle", treadles, "[WEAVING] Treadles")
        picks = {p: set().union(*(tieup.get(t, (set(), 0))[0] for t in items))
                 for p, (items, _) in treadling.items()}
    else:
        raise wif.error(None, "no [LIFTPLAN] and no [TIEUP] + [TREADLING] sections (needed for the drawdown)")

    n_warp = n_warp or max(threading, default=0)
    n_weft = n_weft or max(picks, default=0)
    if n_warp == 0 or n_weft == 0:
        raise wif.error(None, "the drawdown is empty (no threaded warp thread or no pick)")
    if n_warp * n_weft > MAX_WEAVE_CELLS:
        raise wif.error(None, f"the drawdown has {n_warp:,} warp threads x {n_weft:,} picks = "
                              f"{n_warp * n_weft:,} crossings; at most {MAX_WEAVE_CELLS:,} (the largest repeat "
                              f"whose coarsest mesh stays within {MAX_TRIANGLES:,} triangles)")
    matrix = np.zeros((n_warp, n_weft), dtype=np.int8)
    for pick in range(1, n_weft + 1):
        listed = picks.get(pick, set())
        for thread, (on, _) in threading.items():
            # rising shed: the listed shafts rise; sinking shed: the others (a shaft of the
            # thread's that is not listed), without building the set of all shafts
            if (on & listed) if rising else (on - listed):
                matrix[thread - 1, pick - 1] = 1
    return matrix


def weave_from_wif(path: str | Path, **params: Any) -> Weave:
    """A :class:`Weave` of a WIF file's drawdown (:func:`read_wif`); ``params`` are the other fields.

    A drawdown that is not a valid weave (a thread that never interlaces) is a :class:`WeaveError`
    naming the file; rows and columns count from 0 (row ``j`` = warp thread ``j + 1``).
    """
    matrix = read_wif(path)
    try:
        return Weave(matrix, **params)
    except WeaveError as exc:
        raise WeaveError(f"{Path(path).name}: {exc} (row j = warp thread j + 1, column i = pick i + 1)") from None
