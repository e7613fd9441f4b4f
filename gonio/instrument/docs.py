r"""The protocol document's tables, generated from the code's tables (so they cannot drift).

``docs/instrument.md`` holds prose written by hand and sections between markers::

    <!-- BEGIN GENERATED: NAME -->
    ...
    <!-- END GENERATED: NAME -->

whose content :func:`render` regenerates from :data:`GENERATORS` (``axes``, ``registers``,
``commands``, ``errors``). A test fails when the committed document differs from the rendered
one; ``python -m gonio.instrument.docs docs/instrument.md`` rewrites it after a table changed.

Examples
--------
>>> print(render("<!-- BEGIN GENERATED: errors -->\n<!-- END GENERATED: errors -->").splitlines()[2])
|---|---|
"""

from __future__ import annotations

import re
import sys
from collections.abc import Callable
from pathlib import Path

from gonio.instrument.head_commands import HEAD_COMMANDS, HEAD_ERRORS
from gonio.instrument.modbus_map import AXES, AXIS_BLOCK_BASE, AXIS_BLOCK_STRIDE, MODBUS_MAP

__all__ = ["axes_table", "register_table", "command_table", "error_table", "GENERATORS", "render", "main"]

_ACCESS = {"rw": "read/write", "r": "read-only"}


def _cell(text: str) -> str:
    text = text.replace("|", "\\|")
    # outside code spans, <serial> would read as an HTML tag
    return text if text.startswith("`") else text.replace("<", "&lt;")


def _table(header: list[str], rows: list[list[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(_cell(c) for c in row) + " |" for row in rows]
    return "\n".join(lines)


def axes_table() -> str:
    """The axes: index, name, meaning, soft limits."""
    return _table(["axis", "name", "meaning", "soft limits (deg)"],
                  [[str(a.index), f"`{a.name}`", a.meaning, f"{a.min_mdeg / 1000:g} .. {a.max_mdeg / 1000:g}"]
                   for a in AXES])


def register_table() -> str:
    """The register map: one row per register (per-axis rows at ``base + stride * axis``)."""
    rows = []
    for r in MODBUS_MAP.values():
        address = (f"{AXIS_BLOCK_BASE} + {AXIS_BLOCK_STRIDE}a + {r.address}" if r.per_axis
                   else str(r.address))
        kind = getattr(r.kind, "__name__", "")
        rows.append([f"`{r.name}`", r.table, address, str(r.words), r.type + (f" ({kind})" if kind else ""),
                     _ACCESS[r.access], "yes" if r.validator is not None else "", r.doc])
    return _table(["name", "table", "address", "words", "type", "access", "validated", "meaning"], rows)


def command_table() -> str:
    """The head's command set: syntax, reply kind, whether it changes the measurement state."""
    return _table(["command", "reply", "changes state", "meaning"],
                  [[f"`{c.syntax}`", c.response, "yes" if c.changes_state else "", c.doc]
                   for c in HEAD_COMMANDS.values()])


def error_table() -> str:
    """The head's error codes, as on the wire (``ERR <code>,<message>``)."""
    return _table(["code", "message"], [[str(code), msg] for code, msg in HEAD_ERRORS.items()])


GENERATORS: dict[str, Callable[[], str]] = {
    "axes": axes_table, "registers": register_table, "commands": command_table, "errors": error_table}
"""Name of a generated section -> the function that writes it."""

_SECTION = re.compile(r"(<!-- BEGIN GENERATED: (\w+) -->\n)(.*?)(<!-- END GENERATED: \2 -->)", re.S)


def render(text: str) -> str:
    """``text`` with every generated section's content regenerated from the tables."""
    def fill(m: re.Match) -> str:
        name = m.group(2)
        if name not in GENERATORS:
            raise ValueError(f"unknown generated section {name!r} (known: {', '.join(GENERATORS)})")
        return m.group(1) + GENERATORS[name]() + "\n" + m.group(4)
    return _SECTION.sub(fill, text)


def main(argv: list[str] | None = None) -> int:
    """Rewrite the generated sections of the documents named on the command line."""
    for name in (sys.argv[1:] if argv is None else argv):
        path = Path(name)
        text = path.read_text(encoding="utf-8")
        new = render(text)
        if new != text:
            path.write_text(new, encoding="utf-8")
            print(f"{path}: generated tables updated")
    return 0


if __name__ == "__main__":
    sys.exit(main())
