"""TOML text read as untrusted input: the one reader of the configs' and plans' TOML.

:func:`tomllib.loads` recurses once per nested array or inline table, so a file nesting a few
thousand of them exhausts the interpreter's stack (``RecursionError``); bytes that are not UTF-8
raise a ``UnicodeDecodeError``. :func:`loads` turns both, and invalid TOML, into the caller's own
error class with one line naming the file.
"""

from __future__ import annotations

import tomllib
from typing import Any

__all__ = ["loads"]


def loads(raw: bytes | str, file: str, error: type[Exception], kind: str, max_levels: int) -> dict[str, Any]:
    """The TOML document ``raw`` (the file ``file``, a ``kind`` such as "plan") as a dict.

    Raises ``error`` (one argument, the message) for text that is not UTF-8, invalid TOML, or arrays
    and inline tables nested too deeply to be read (the schema of a ``kind`` nests at most
    ``max_levels`` levels).
    """
    if isinstance(raw, str):
        raw = raw.encode("utf-8", errors="surrogatepass")
    try:
        return tomllib.loads(raw.decode("utf-8"))
    except (UnicodeDecodeError, UnicodeEncodeError):
        raise error(f"{file}: not UTF-8 text; a {kind} is a TOML file") from None
    except tomllib.TOMLDecodeError as exc:
        raise error(f"{file}: invalid TOML: {exc}") from None
    except RecursionError:      # tomllib recurses once per nested array or inline table
        raise error(f"{file}: arrays or inline tables nested too deeply for a {kind} (the schema "
                    f"nests at most {max_levels} levels)") from None
