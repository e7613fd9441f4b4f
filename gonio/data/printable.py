r"""Text from a file, made safe to print on a terminal: the one sanitising helper of the command lines.

A dataset's name, its sample's name and the notes it carries come from files anyone may write. Printed
raw, an escape sequence in them (``ESC [ 2 J``, colours, a cursor move, a bidirectional override)
would act on the user's terminal: clear the screen, forge a green "passed". :func:`printable`
replaces every control and format character by its visible escape (``\x1b``, ``\u202e``).
"""

from __future__ import annotations

import unicodedata

__all__ = ["printable"]


def _escape(ch: str) -> str:
    code = ord(ch)
    return f"\\x{code:02x}" if code < 0x100 else (f"\\u{code:04x}" if code < 0x10000 else f"\\U{code:08x}")


def printable(text: object, *, newlines: bool = False) -> str:
    r"""Give ``str(text)`` with every control (Cc) and format (Cf) character escaped.

    As in ``\x1b``; ``newlines=True`` keeps ``\n`` (a text of several lines printed as such).
    """
    s = str(text)
    if s.isprintable():
        return s
    return "".join(ch if (ch == "\n" and newlines) or ch == " " or unicodedata.category(ch) not in ("Cc", "Cf", "Zl", "Zp")
                   else _escape(ch) for ch in s)
